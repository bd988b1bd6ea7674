// libFuzzer target for the OBJ reader (not part of the CMake build). Every input goes through
// mlb_obj_parse. A rejected input must leave a zeroed mesh and a message naming the buffer; an
// accepted one must keep the reader's promises (at least one triangle, indices in range, finite
// values, info consistent with the mesh), and the mesh utilities must then work on it: normals of
// unit length, bounds ordered, the unit-sphere fit inside radius 1. A broken promise aborts.
//
// Build and run (clang with libFuzzer, as scripts/fuzz.sh does for the safetensors target):
//   srcs="src/io/obj.c src/mesh/mesh.c src/core/error.c src/core/fileio.c"
//   flags="-std=c11 -D_GNU_SOURCE -g -O1 -Iinclude -fno-omit-frame-pointer"
//   san="-fsanitize=address,undefined -fno-sanitize-recover=all"
//   clang $flags $san -fsanitize=fuzzer fuzz/fuzz_obj.c $srcs -lm -o fuzz_obj
//   clang $flags $san -DMLB_FUZZ_SEED fuzz/fuzz_obj.c $srcs -lm -o seed_obj && ./seed_obj CORPUS
//   ./fuzz_obj -max_total_time=300 -max_len=4096 -timeout=10 -rss_limit_mb=2048 -dict=obj.dict CORPUS
// Built with -DMLB_FUZZ_SEED the same file is a small program that writes seed files into the
// folder given as its argument.
#include "matlaber/mesh.h"
#include "matlaber/obj.h"
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PROMISE(cond) do { if (!(cond)) { fprintf(stderr, "broken promise: %s\n", #cond); abort(); } } while (0)

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    mlb_mesh m;
    mlb_obj_info info;
    mlb_obj_options opt = {0};
    opt.max_triangles = 1u << 20;   // keeps memory bounded for pathological fans
    mlb_status s = mlb_obj_parse((const char*)data, size, "fuzz", &m, &opt, &info);
    if (s != MLB_OK) {
        PROMISE(m.n_verts == 0 && m.n_faces == 0 && !m.pos && !m.uv && !m.normal && !m.faces);
        PROMISE(strncmp(mlb_last_error(), "fuzz: ", 6) == 0);
        return 0;
    }
    PROMISE(m.n_faces >= 1 && m.n_verts >= 1 && m.n_verts <= 3 * m.n_faces);
    PROMISE(m.pos && m.faces && info.n_triangles == m.n_faces && info.n_polygons >= 1);
    PROMISE(info.n_polygons <= m.n_faces && m.n_faces <= (int)opt.max_triangles);
    PROMISE(!(m.uv && info.uv_dropped) && !(m.normal && info.normals_dropped));
    for (int i = 0; i < 3 * m.n_faces; i++) PROMISE(m.faces[i] >= 0 && m.faces[i] < m.n_verts);
    for (int i = 0; i < 3 * m.n_verts; i++) PROMISE(isfinite(m.pos[i]));
    if (m.uv) for (int i = 0; i < 2 * m.n_verts; i++) PROMISE(isfinite(m.uv[i]));
    if (m.normal) for (int i = 0; i < 3 * m.n_verts; i++) PROMISE(isfinite(m.normal[i]));
    // every vertex is used by some face (vertices are made from face corners)
    unsigned char* used = calloc((size_t)m.n_verts, 1);
    PROMISE(used);
    for (int i = 0; i < 3 * m.n_faces; i++) used[m.faces[i]] = 1;
    for (int i = 0; i < m.n_verts; i++) PROMISE(used[i]);
    free(used);

    float lo[3], hi[3];
    mlb_mesh_bounds(&m, lo, hi);
    for (int k = 0; k < 3; k++) PROMISE(lo[k] <= hi[k]);
    s = mlb_mesh_compute_normals(&m);
    PROMISE(s == MLB_OK);   // finite positions, indices in range: cannot fail but for memory
    for (int i = 0; i < m.n_verts; i++) {
        const float* n = m.normal + 3 * i;
        double l = sqrt((double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2]);
        PROMISE(fabs(l - 1) < 1e-5);
    }
    mlb_mesh_normalize_unit_sphere(&m);
    for (int i = 0; i < m.n_verts; i++) {
        const float* p = m.pos + 3 * i;
        PROMISE(isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2]));
        // the fit works in double, so even extents near FLT_MAX (or subnormal ones) land inside
        PROMISE(sqrt((double)p[0] * p[0] + (double)p[1] * p[1] + (double)p[2] * p[2]) <= 1.0 + 1e-6);
    }
    mlb_mesh_free(&m);
    return 0;
}

#ifdef MLB_FUZZ_SEED
static int put(const char* dir, const char* name, const char* text) {
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE* f = fopen(path, "wb");
    if (!f) { perror(path); return 0; }
    fputs(text, f);
    return fclose(f) == 0;
}

int main(int argc, char** argv) {
    if (argc != 2) { fprintf(stderr, "usage: %s CORPUS_DIR\n", argv[0]); return 2; }
    const char* d = argv[1];
    int ok = 1;
    ok &= put(d, "seed_tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    ok &= put(d, "seed_cube.obj",
              "# cube\nmtllib c.mtl\no c\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
              "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 -1\nvn 0 0 1\nvn 0 -1 0\nvn 0 1 0\nvn -1 0 0\nvn 1 0 0\n"
              "usemtl m\ns 1\ng side\nf 1/1/1 4/4/1 3/3/1 2/2/1\nf 5/1/2 6/2/2 7/3/2 8/4/2\nf 1/1/3 2/2/3 6/3/3 5/4/3\n"
              "f 4/1/4 8/2/4 7/3/4 3/4/4\nf 1/1/5 5/2/5 8/3/5 4/4/5\nf 2/1/6 3/2/6 7/3/6 6/4/6\n");
    ok &= put(d, "seed_negative.obj",
              "v 0 0 0\r\nv 1 0 0\r\nv 1 1 0\r\nv 0 1 0\r\nvt 0 0\r\nvt 1 1\r\nvn 0 0 1\r\n"
              "f -4/-2/-1 -3/-1/-1 -2/-2/-1 -1/-1/-1\r\n");
    ok &= put(d, "seed_forms.obj",
              "\xEF\xBB\xBFv 1e-3 -2.5E+2 .5 1.0\nv 4 5 6 0.1 0.2 0.3\nv -0 +1 3\nvt 0.25 0.75 0\nvt 0.5\nvn 0 0 1\n"
              "vp 1 2\nl 1 2\np 1\nf 1//1 2//1 3//1\nf 1/1 2/2 3/1\nf 1 2 \\\n 3 # trailing\n");
    ok &= put(d, "seed_numbers.obj",
              "v 0.348799 -0.334989 -0.083233\nv 3.4028234e38 -1.17549435e-38 1e-45\nv 123456789012345678 0.1 7\n"
              "f 1 2 3\n");
    return ok ? 0 : 1;
}
#endif
