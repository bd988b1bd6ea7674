// libFuzzer target for the glTF reader (not part of the CMake build; scripts/fuzz.sh gltf). Every
// input goes through mlb_gltf_parse from memory (external buffers refused). A rejected input must
// leave a zeroed mesh and a message naming the buffer; an accepted one must keep the reader's
// promises: at least one triangle, indices in range, every vertex used, finite values, unit-length
// or zero normals when transformed. A broken promise aborts.
// Built with -DMLB_FUZZ_SEED the same file writes seed files (a .glb from our exporter and a few
// .gltf forms) into the folder given as its argument.
#include "matlaber/export.h"
#include "matlaber/gltf.h"
#include "matlaber/mesh.h"
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PROMISE(cond) do { if (!(cond)) { fprintf(stderr, "broken promise: %s\n", #cond); abort(); } } while (0)

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    mlb_mesh m;
    mlb_gltf_info info;
    mlb_gltf_options opt = {0, 1u << 20, 0, 0};   // bounded memory for instancing bombs
    mlb_status s = mlb_gltf_parse(data, size, "fuzz", NULL, &m, &opt, &info);
    if (s != MLB_OK) {
        PROMISE(m.n_verts == 0 && m.n_faces == 0 && !m.pos && !m.uv && !m.normal && !m.faces);
        PROMISE(strncmp(mlb_last_error(), "fuzz: ", 6) == 0);
        return 0;
    }
    PROMISE(m.n_faces >= 1 && m.n_verts >= 1 && m.pos && m.faces && m.n_faces <= (int)opt.max_triangles);
    PROMISE(info.n_primitives >= 1 && info.n_instances >= 1);
    unsigned char* used = calloc((size_t)m.n_verts, 1);
    PROMISE(used);
    for (int i = 0; i < 3 * m.n_faces; i++) {
        PROMISE(m.faces[i] >= 0 && m.faces[i] < m.n_verts);
        used[m.faces[i]] = 1;
    }
    for (int i = 0; i < m.n_verts; i++) PROMISE(used[i]);
    free(used);
    for (int i = 0; i < 3 * m.n_verts; i++) PROMISE(isfinite(m.pos[i]));
    if (m.uv) for (int i = 0; i < 2 * m.n_verts; i++) PROMISE(isfinite(m.uv[i]));
    if (m.normal) for (int i = 0; i < 3 * m.n_verts; i++) PROMISE(isfinite(m.normal[i]));
    mlb_mesh_free(&m);
    return 0;
}

#ifdef MLB_FUZZ_SEED
static int put(const char* dir, const char* name, const void* data, size_t n) {
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE* f = fopen(path, "wb");
    if (!f) { perror(path); return 0; }
    size_t w = fwrite(data, 1, n, f);
    return (fclose(f) == 0) & (w == n);
}

int main(int argc, char** argv) {
    if (argc != 2) { fprintf(stderr, "usage: %s CORPUS_DIR\n", argv[0]); return 2; }
    const char* d = argv[1];
    int ok = 1;
    // our exporter's .glb of a small sphere with 1x1 textures
    mlb_mesh m;
    if (mlb_mesh_uv_sphere(&m, 1, 6, 4)) return 1;
    float kd[3] = {0.5f, 0.5f, 0.5f}, ks[3] = {0.04f, 0.04f, 0.04f}, kr[1] = {0.5f};
    mlb_asset a = {m.n_verts, m.n_faces, m.pos, m.normal, m.uv, m.faces, 1, kd, ks, kr, "s"};
    unsigned char* glb = NULL;
    size_t n = 0;
    if (mlb_export_glb_memory(&a, &glb, &n)) return 1;
    ok &= put(d, "seed_sphere.glb", glb, n);
    free(glb);
    mlb_mesh_free(&m);
    // a triangle with a base64 buffer (3 float3 positions, uint16 indices), nodes with transforms
    const char* tri =
        "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
        "\"nodes\":[{\"translation\":[1,2,3],\"rotation\":[0,0,0.7071,0.7071],\"scale\":[1,-1,1],\"children\":[1]},{\"mesh\":0,\"matrix\":[1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]}],"
        "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},\"indices\":1,\"mode\":4},{\"attributes\":{\"POSITION\":0},\"mode\":5}]}],"
        "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"},{\"bufferView\":1,\"componentType\":5123,\"count\":3,\"type\":\"SCALAR\"}],"
        "\"bufferViews\":[{\"buffer\":0,\"byteLength\":36},{\"buffer\":0,\"byteOffset\":36,\"byteLength\":6}],"
        "\"buffers\":[{\"byteLength\":42,\"uri\":\"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAABAAIA\"}]}";
    ok &= put(d, "seed_tri.gltf", tri, strlen(tri));
    return ok ? 0 : 1;
}
#endif
