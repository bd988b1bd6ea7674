// glTF reading (include/matlaber/gltf.h): a .glb from our own exporter reads back as the mesh it was
// written from (positions and faces bitwise, UVs within 6e-8); hand-built .gltf files for every
// form the reader takes (interleaved and strided views, uint8/16/32 indices, normalized texcoords,
// strips, fans, points, node transforms with a mirror, data: URIs, adjacent and sub-folder .bin
// files); external paths that would leave the file's folder; a table of malformed files (each:
// an error naming the file and the problem, nothing returned); and every truncation and many byte
// corruptions of a .glb (run under the ASan build as well: build-asan/tests/test_gltf).
#include "test.h"
#include <stdint.h>
#include <unistd.h>
#include "matlaber/error.h"
#include "matlaber/export.h"
#include "matlaber/gltf.h"
#include "matlaber/mesh.h"
#include "matlaber/rng.h"

static const char* tmp;   // scratch folder

static int write_bytes(const char* path, const void* data, size_t n) {
    FILE* f = fopen(path, "wb");
    if (!f) return 0;
    size_t w = fwrite(data, 1, n, f);
    return fclose(f) == 0 && w == n;
}

static int mesh_is_zero(const mlb_mesh* m) {
    return m->n_verts == 0 && m->n_faces == 0 && !m->pos && !m->normal && !m->uv && !m->faces;
}

static char* base64(const unsigned char* d, size_t n) {
    static const char A[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    char* s = malloc(4 * (n / 3 + 1) + 1);
    size_t o = 0;
    for (size_t i = 0; i < n; i += 3) {
        uint32_t v = (uint32_t)d[i] << 16 | (i + 1 < n ? (uint32_t)d[i + 1] << 8 : 0) | (i + 2 < n ? d[i + 2] : 0);
        s[o++] = A[v >> 18 & 63];
        s[o++] = A[v >> 12 & 63];
        s[o++] = i + 1 < n ? A[v >> 6 & 63] : '=';
        s[o++] = i + 2 < n ? A[v & 63] : '=';
    }
    s[o] = 0;
    return s;
}

// Every vertex used (mlb_mesh_uv_sphere leaves one vertex of each pole row unused).
static void drop_unused(mlb_mesh* m) {
    int32_t* map = malloc(sizeof(int32_t) * (size_t)m->n_verts);
    for (int i = 0; i < m->n_verts; i++) map[i] = -1;
    for (int i = 0; i < 3 * m->n_faces; i++) map[m->faces[i]] = 0;
    int n = 0;
    for (int i = 0; i < m->n_verts; i++) {
        if (map[i] < 0) continue;
        map[i] = n;
        memmove(m->pos + 3 * n, m->pos + 3 * i, 12);
        memmove(m->normal + 3 * n, m->normal + 3 * i, 12);
        memmove(m->uv + 2 * n, m->uv + 2 * i, 8);
        n++;
    }
    for (int i = 0; i < 3 * m->n_faces; i++) m->faces[i] = map[m->faces[i]];
    m->n_verts = n;
    free(map);
}

// A .glb of a UV sphere (moved off the origin, a few UVs at 0, 1 and tiny values) from mlb_export_glb_memory.
static int sphere_glb(mlb_mesh* m, unsigned char** glb, size_t* n) {
    if (mlb_mesh_uv_sphere(m, 1.7f, 24, 12)) return 0;
    drop_unused(m);
    for (int i = 0; i < m->n_verts; i++) { m->pos[3 * i] += 3.25f; m->pos[3 * i + 2] -= 100.0f; }
    m->uv[1] = 1e-9f;   // 1 - (1 - v) rounds: the tolerance below
    m->uv[3] = 0.123456789f;
    float kd[4 * 4 * 3], ks[4 * 4 * 3], kr[16];
    for (int i = 0; i < 48; i++) kd[i] = ks[i] = (float)(i % 7) / 7;
    for (int i = 0; i < 16; i++) kr[i] = 0.5f;
    mlb_asset a = {m->n_verts, m->n_faces, m->pos, m->normal, m->uv, m->faces, 4, kd, ks, kr, "sphere"};
    return mlb_export_glb_memory(&a, glb, n) == MLB_OK;
}

static void check_same(const mlb_mesh* a, const mlb_mesh* b) {
    CHECK(a->n_verts == b->n_verts && a->n_faces == b->n_faces);
    if (a->n_verts != b->n_verts || a->n_faces != b->n_faces) return;
    CHECK(memcmp(a->pos, b->pos, 12 * (size_t)a->n_verts) == 0);
    CHECK(memcmp(a->faces, b->faces, 12 * (size_t)a->n_faces) == 0);
    REQUIRE(a->uv && b->uv && a->normal && b->normal);
    double du = 0, dn = 0;
    for (int i = 0; i < 2 * a->n_verts; i++) du = fmax(du, fabs((double)a->uv[i] - b->uv[i]));
    for (int i = 0; i < 3 * a->n_verts; i++) dn = fmax(dn, fabs((double)a->normal[i] - b->normal[i]));
    CHECK_MSG(du <= 6e-8, "uv differs by %g", du);
    CHECK_MSG(dn <= 1e-6, "normals differ by %g", dn);
}

TEST(round_trip_export) {
    mlb_mesh m, r;
    unsigned char* glb = NULL;
    size_t n = 0;
    REQUIRE(sphere_glb(&m, &glb, &n));
    mlb_gltf_info info;
    mlb_status s = mlb_gltf_parse(glb, n, "mem.glb", NULL, &r, NULL, &info);
    CHECK_MSG(s == MLB_OK, "%s", mlb_last_error());
    if (!s) {
        check_same(&m, &r);
        CHECK(info.binary && info.n_meshes == 1 && info.n_instances == 1 && info.n_primitives == 1 && info.n_unused == 0);
        mlb_mesh_free(&r);
    }
    // and through a file
    char path[4200];
    snprintf(path, sizeof path, "%s/sphere.glb", tmp);
    REQUIRE(write_bytes(path, glb, n));
    s = mlb_gltf_load(path, &r, NULL, NULL);
    CHECK_MSG(s == MLB_OK, "%s", mlb_last_error());
    if (!s) check_same(&m, &r);
    mlb_mesh_free(&r);
    // options: drop uv and normals
    mlb_gltf_options o = {0, 0, 1, 1};
    s = mlb_gltf_parse(glb, n, "mem.glb", NULL, &r, &o, NULL);
    CHECK(s == MLB_OK && !r.uv && !r.normal && r.n_faces == m.n_faces);
    mlb_mesh_free(&r);
    o.drop_uv = o.drop_normals = 0;
    o.max_triangles = (size_t)m.n_faces - 1;
    s = mlb_gltf_parse(glb, n, "mem.glb", NULL, &r, &o, NULL);
    CHECK(s == MLB_ERR_UNSUPPORTED && strstr(mlb_last_error(), "more than") && mesh_is_zero(&r));
    o.max_triangles = 0;
    o.max_bytes = n - 1;
    s = mlb_gltf_parse(glb, n, "mem.glb", NULL, &r, &o, NULL);
    CHECK(s == MLB_ERR_UNSUPPORTED && mesh_is_zero(&r));
    s = mlb_gltf_load(path, &r, &o, NULL);   // a file over the limit: the same status as the OBJ loader's, the path named
    CHECK_MSG(s == MLB_ERR_UNSUPPORTED && strstr(mlb_last_error(), path) && strstr(mlb_last_error(), "more than the") &&
              mesh_is_zero(&r), "%s", mlb_last_error());
    free(glb);
    mlb_mesh_free(&m);
}

// ---- hand-built .gltf files ----

// A quad's data: 4 vertices interleaved (position float3, texcoord ushort2 normalized; stride 16),
// then normals (float3), then uint8 indices 0 1 2 0 2 3, then a uint32 copy of them: 64 + 48 + 6 + 2 + 24 = 144 bytes.
static void quad_buffer(unsigned char* b) {
    memset(b, 0, 144);
    static const float P[4][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
    static const uint16_t T[4][2] = {{0, 65535}, {65535, 65535}, {65535, 0}, {0, 32768}};
    for (int i = 0; i < 4; i++) {
        memcpy(b + 16 * i, P[i], 12);
        memcpy(b + 16 * i + 12, T[i], 4);
        float nz[3] = {0, 0, 1};
        memcpy(b + 64 + 12 * i, nz, 12);
    }
    static const unsigned char I[6] = {0, 1, 2, 0, 2, 3};
    memcpy(b + 112, I, 6);
    for (int i = 0; i < 6; i++) { uint32_t v = I[i]; memcpy(b + 120 + 4 * i, &v, 4); }
}

// The quad's JSON around a buffer uri, with `nodes` and `prim_extra` (inside the primitive).
static char* quad_json(const char* uri, const char* nodes, const char* scenes, const char* prim) {
    char* s = malloc(8192);
    snprintf(s, 8192,
             "{\"asset\":{\"version\":\"2.0\"},%s\"nodes\":[%s],"
             "\"meshes\":[{\"primitives\":[%s]}],"
             "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":4,\"type\":\"VEC3\"},"
             "{\"bufferView\":0,\"byteOffset\":12,\"componentType\":5123,\"normalized\":true,\"count\":4,\"type\":\"VEC2\"},"
             "{\"bufferView\":1,\"componentType\":5126,\"count\":4,\"type\":\"VEC3\"},"
             "{\"bufferView\":2,\"componentType\":5121,\"count\":6,\"type\":\"SCALAR\"},"
             "{\"bufferView\":3,\"componentType\":5125,\"count\":6,\"type\":\"SCALAR\"}],"
             "\"bufferViews\":[{\"buffer\":0,\"byteLength\":64,\"byteStride\":16},{\"buffer\":0,\"byteOffset\":64,\"byteLength\":48},"
             "{\"buffer\":0,\"byteOffset\":112,\"byteLength\":6},{\"buffer\":0,\"byteOffset\":120,\"byteLength\":24}],"
             "\"buffers\":[{\"byteLength\":144,\"uri\":\"%s\"}]}",
             scenes, nodes, prim, uri);
    return s;
}

static char* quad_data_uri(void) {
    unsigned char b[144];
    quad_buffer(b);
    char* b64 = base64(b, 144);
    char* uri = malloc(strlen(b64) + 64);
    sprintf(uri, "data:application/octet-stream;base64,%s", b64);
    free(b64);
    return uri;
}

#define PRIM "{\"attributes\":{\"POSITION\":0,\"TEXCOORD_0\":1,\"NORMAL\":2},\"indices\":3}"

static mlb_status parse_json(const char* json, const char* dir, mlb_mesh* m, mlb_gltf_info* info) {
    return mlb_gltf_parse((const unsigned char*)json, strlen(json), "q.gltf", dir, m, NULL, info);
}

TEST(quad_forms) {
    char* uri = quad_data_uri();
    mlb_mesh m;
    mlb_gltf_info info;
    // one node, untransformed: the quad as written, v flipped, u16 normalized
    char* j = quad_json(uri, "{\"mesh\":0}", "\"scenes\":[{\"nodes\":[0]}],", PRIM);
    mlb_status s = parse_json(j, NULL, &m, &info);
    CHECK_MSG(s == MLB_OK, "%s", mlb_last_error());
    if (!s) {
        CHECK(m.n_verts == 4 && m.n_faces == 2 && m.uv && m.normal && !info.binary);
        CHECK(m.faces[0] == 0 && m.faces[1] == 1 && m.faces[2] == 2 && m.faces[5] == 3);
        CHECK(m.pos[6] == 1 && m.pos[7] == 1 && m.pos[8] == 0);
        CHECK(m.uv[0] == 0 && m.uv[1] == 0 && m.uv[2] == 1 && m.uv[4] == 1 && m.uv[5] == 1);
        CHECK_CLOSE(m.uv[7], 1 - 32768.0 / 65535, 0, 1e-7);
        CHECK(m.normal[2] == 1);
    }
    mlb_mesh_free(&m);
    free(j);
    // uint32 indices, not indexed, strip and fan: the same two triangles (up to the strip's order)
    const char* prims[3] = {"{\"attributes\":{\"POSITION\":0},\"indices\":4}",
                            "{\"attributes\":{\"POSITION\":0},\"indices\":3,\"mode\":6}",
                            "{\"attributes\":{\"POSITION\":0},\"mode\":5}"};
    for (int k = 0; k < 3; k++) {
        j = quad_json(uri, "{\"mesh\":0}", "", prims[k]);   // no scenes: the root nodes
        s = parse_json(j, NULL, &m, NULL);
        CHECK_MSG(s == MLB_OK, "%s", mlb_last_error());
        if (k == 0) CHECK(s == MLB_OK && m.n_faces == 2 && m.faces[3] == 0 && m.faces[4] == 2 && m.faces[5] == 3 && !m.uv);
        if (k == 1) CHECK(s == MLB_OK && m.n_faces == 4);   // a fan over the 6 indices: 4 triangles
        if (k == 2) CHECK(s == MLB_OK && m.n_faces == 2 && m.faces[0] == 0 && m.faces[1] == 1 && m.faces[2] == 2 &&
                          m.faces[3] == 2 && m.faces[4] == 1 && m.faces[5] == 3);   // the odd one flipped
        mlb_mesh_free(&m);
        free(j);
    }
    // points beside triangles are skipped; a primitive without TEXCOORD_0 drops the UVs
    j = quad_json(uri, "{\"mesh\":0}", "", PRIM ",{\"attributes\":{\"POSITION\":0},\"mode\":0},{\"attributes\":{\"POSITION\":0,\"NORMAL\":2},\"indices\":3}");
    s = parse_json(j, NULL, &m, &info);
    CHECK_MSG(s == MLB_OK, "%s", mlb_last_error());
    CHECK(s == MLB_OK && m.n_faces == 4 && m.n_verts == 8 && !m.uv && m.normal && info.uv_dropped && !info.normals_dropped &&
          info.n_skipped == 1 && info.n_primitives == 2);
    mlb_mesh_free(&m);
    free(j);
    free(uri);
}

TEST(node_transforms) {
    char* uri = quad_data_uri();
    mlb_mesh m;
    mlb_gltf_info info;
    // node 0: translate (10, 0, 0), scale 2, child node 1: 90 degrees about +y; node 2: mirrored in x by a matrix.
    // Scene 1 is the default; scene 0 would place nothing.
    char* j = quad_json(uri,
                        "{\"translation\":[10,0,0],\"scale\":[2,2,2],\"children\":[1]},"
                        "{\"rotation\":[0,0.70710678118654752,0,0.70710678118654752],\"mesh\":0},"
                        "{\"matrix\":[-1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,5,1],\"mesh\":0}",
                        "\"scene\":1,\"scenes\":[{\"nodes\":[]},{\"nodes\":[0,2]}],", PRIM);
    mlb_status s = parse_json(j, NULL, &m, &info);
    CHECK_MSG(s == MLB_OK, "%s", mlb_last_error());
    if (!s) {
        CHECK(m.n_verts == 8 && m.n_faces == 4 && info.n_instances == 2 && info.n_mirrored == 1);
        // instance 1: p' = (10,0,0) + 2 R_y(90) p, R_y(90) (x, y, z) = (z, y, -x): vertex 1 (1,0,0) -> (10, 0, -2)
        CHECK_CLOSE(m.pos[3], 10, 0, 1e-5);
        CHECK_CLOSE(m.pos[4], 0, 0, 1e-5);
        CHECK_CLOSE(m.pos[5], -2, 0, 1e-5);
        // its normal (0,0,1) -> (1,0,0), unit length
        CHECK_CLOSE(m.normal[0], 1, 0, 1e-6);
        CHECK_CLOSE(m.normal[2], 0, 0, 1e-6);
        // instance 2: x mirrored, z + 5; the winding reversed so the face still faces its normal
        CHECK(m.pos[12 + 3] == -1 && m.pos[12 + 5] == 5);
        CHECK(m.faces[6] == 4 && m.faces[7] == 6 && m.faces[8] == 5);
        CHECK_CLOSE(m.normal[12 + 2], 1, 0, 1e-6);
        CHECK_CLOSE(m.normal[12 + 0], 0, 0, 1e-6);
    }
    mlb_mesh_free(&m);
    free(j);
    free(uri);
}

TEST(external_buffers) {
    unsigned char b[144];
    quad_buffer(b);
    char path[4200], sub[4200], json_path[4200];
    snprintf(path, sizeof path, "%s/quad data.bin", tmp);
    REQUIRE(write_bytes(path, b, 144));
    snprintf(sub, sizeof sub, "%s/bufs", tmp);
    mkdir(sub, 0777);
    snprintf(path, sizeof path, "%s/bufs/q.bin", tmp);
    REQUIRE(write_bytes(path, b, 144));
    snprintf(path, sizeof path, "%s/../outside.bin", tmp);
    REQUIRE(write_bytes(path, b, 144));
    snprintf(path, sizeof path, "%s/link.bin", tmp);
    char target[4200];
    snprintf(target, sizeof target, "%s/../outside.bin", tmp);
    unlink(path);
    REQUIRE(symlink(target, path) == 0);
    struct { const char* uri; const char* err; } cases[] = {
        {"quad%20data.bin", NULL},                 // percent-decoded, beside the file
        {"bufs/q.bin", NULL},                      // a sub-folder
        {"./bufs/q.bin", NULL},
        {"../outside.bin", "leaves the file's folder"},
        {"bufs/../../outside.bin", "leaves the file's folder"},
        {"%2e%2e/outside.bin", "leaves the file's folder"},
        {"/etc/passwd", "not a relative file name"},
        {"file:///etc/passwd", "not a plain relative file name"},
        {"C:\\\\x.bin", "not a plain relative file name"},
        {"link.bin", "resolves outside the file's folder"},
        {"missing.bin", "No such file"},
        {"bad%zz.bin", "bad % escape"},
        {"a%00b.bin", "not a plain relative file name"},
        {"", "not a relative file name"},
    };
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
        char* j = quad_json(cases[k].uri, "{\"mesh\":0}", "", PRIM);
        snprintf(json_path, sizeof json_path, "%s/q.gltf", tmp);
        REQUIRE(write_bytes(json_path, j, strlen(j)));
        mlb_mesh m;
        mlb_status s = mlb_gltf_load(json_path, &m, NULL, NULL);
        if (!cases[k].err) {
            CHECK_MSG(s == MLB_OK && m.n_faces == 2 && m.uv, "%s: %s", cases[k].uri, mlb_last_error());
        } else {
            CHECK_MSG(s != MLB_OK && mesh_is_zero(&m) && strstr(mlb_last_error(), cases[k].err) &&
                      strstr(mlb_last_error(), "q.gltf"), "%s: status %d, \"%s\"", cases[k].uri, (int)s, mlb_last_error());
        }
        mlb_mesh_free(&m);
        // from memory no external file is read at all
        if (!cases[k].err) {
            s = parse_json(j, NULL, &m, NULL);
            CHECK(s == MLB_ERR_UNSUPPORTED && strstr(mlb_last_error(), "cannot be read from memory"));
        }
        free(j);
    }
    snprintf(path, sizeof path, "%s/../outside.bin", tmp);
    unlink(path);
}

// ---- malformed files: each refused with the file and the problem ----

TEST(malformed) {
    char* uri = quad_data_uri();
    char* good = quad_json(uri, "{\"mesh\":0}", "\"scenes\":[{\"nodes\":[0]}],", PRIM);
    struct { const char* from; const char* to; const char* err; } cases[] = {
        {"\"count\":4,\"type\":\"VEC3\"}", "\"count\":5,\"type\":\"VEC3\"}", "do not fit bufferViews[0]"},
        {"\"count\":4,\"type\":\"VEC3\"}", "\"count\":4294967295,\"type\":\"VEC3\"}", "count is not a whole number"},
        {"\"count\":4,\"type\":\"VEC3\"}", "\"count\":0,\"type\":\"VEC3\"}", "count is 0"},
        {"\"count\":4,\"type\":\"VEC3\"}", "\"count\":3.5,\"type\":\"VEC3\"}", "count is not a whole number"},
        {"\"count\":4,\"type\":\"VEC3\"}", "\"count\":\"4\",\"type\":\"VEC3\"}", "count is not a whole number"},
        {"\"count\":4,\"type\":\"VEC3\"}", "\"count\":4,\"type\":\"MAT4\"}", "is not SCALAR or VEC2-4"},
        {"\"count\":4,\"type\":\"VEC3\"}", "\"count\":4,\"type\":\"VEC2\"}", "POSITION must be a float VEC3"},
        {"\"count\":4,\"type\":\"VEC3\"}", "\"count\":4,\"type\":\"VEC3\",\"sparse\":{}}", "sparse accessors"},
        {"{\"bufferView\":0,\"componentType\":5126", "{\"componentType\":5126", "no bufferView"},
        {"{\"bufferView\":0,\"componentType\":5126", "{\"bufferView\":9,\"componentType\":5126", "bufferViews[9]: out of range"},
        {"{\"bufferView\":0,\"componentType\":5126", "{\"bufferView\":-1,\"componentType\":5126", "bufferView is not a whole number"},
        {"{\"bufferView\":0,\"componentType\":5126", "{\"bufferView\":0,\"byteOffset\":1e300,\"componentType\":5126", "byteOffset is not"},
        {"{\"bufferView\":0,\"componentType\":5126", "{\"bufferView\":0,\"byteOffset\":60,\"componentType\":5126", "do not fit"},
        {"{\"bufferView\":0,\"componentType\":5126", "{\"bufferView\":0,\"componentType\":5124", "componentType 5124"},
        {"\"byteLength\":64,\"byteStride\":16", "\"byteLength\":64,\"byteStride\":8", "byteStride 8 does not suit"},
        {"\"byteLength\":64,\"byteStride\":16", "\"byteLength\":64,\"byteStride\":254", "byteStride is not"},
        {"\"byteLength\":64,\"byteStride\":16", "\"byteLength\":640,\"byteStride\":16", "do not fit buffers[0]"},
        {"\"byteLength\":64,\"byteStride\":16", "\"byteOffset\":18446744073709551615,\"byteLength\":64,\"byteStride\":16", "byteOffset is not"},
        {"{\"byteLength\":144,", "{\"byteLength\":145,", "its data has 144 bytes"},
        {"{\"byteLength\":144,", "{\"byteLength\":0,", "byteLength is 0"},
        {"base64,", "base64,@", "bad base64"},
        {";base64,", ",", "not base64"},
        {"{\"buffer\":0,\"byteLength\":64", "{\"buffer\":1,\"byteLength\":64", "buffers[1]: out of range"},
        {"\"indices\":3}", "\"indices\":2}", "indices must be unsigned"},
        {"\"indices\":3}", "\"indices\":3,\"mode\":7}", "mode is not"},
        {"\"indices\":3}", "\"indices\":99}", "accessors[99]: out of range"},
        {"\"POSITION\":0,", "", "no POSITION"},
        {"\"NORMAL\":2}", "\"NORMAL\":1}", "NORMAL must be a float VEC3"},
        {"{\"bufferView\":1,\"componentType\":5126,\"count\":4", "{\"bufferView\":1,\"componentType\":5126,\"count\":3", "NORMAL has 3 elements"},
        {"{\"bufferView\":2,\"componentType\":5121,\"count\":6", "{\"bufferView\":2,\"componentType\":5121,\"count\":5", "not a multiple of 3"},
        {"\"scenes\":[{\"nodes\":[0]}]", "\"scenes\":[{\"nodes\":[0,0]}]", "reached twice"},
        {"\"scenes\":[{\"nodes\":[0]}]", "\"scenes\":[{\"nodes\":[7]}]", "nodes[7]: out of range"},
        {"\"scenes\":[{\"nodes\":[0]}]", "\"scene\":3,\"scenes\":[{\"nodes\":[0]}]", "scenes[3]: out of range"},
        {"\"nodes\":[{\"mesh\":0}]", "\"nodes\":[{\"mesh\":0,\"children\":[0]}]", "reached twice"},
        {"\"nodes\":[{\"mesh\":0}]", "\"nodes\":[{\"mesh\":4}]", "meshes[4]: out of range"},
        {"\"nodes\":[{\"mesh\":0}]", "\"nodes\":[{\"mesh\":0,\"rotation\":[0,0,0,0]}]", "not a unit quaternion"},
        {"\"nodes\":[{\"mesh\":0}]", "\"nodes\":[{\"mesh\":0,\"matrix\":[1,2]}]", "not an array of 16 numbers"},
        {"\"nodes\":[{\"mesh\":0}]", "\"nodes\":[{\"mesh\":0,\"scale\":[1e300,1e300,1e300]}]", "not finite"},
        {"\"nodes\":[{\"mesh\":0}]", "\"nodes\":[{\"mesh\":0}],\"extensionsRequired\":[\"KHR_draco_mesh_compression\"]", "compressed geometry"},
        {"\"version\":\"2.0\"", "\"version\":\"1.0\"", "only 2.x"},
        {"\"asset\":{\"version\":\"2.0\"}", "\"asset\":7", "no asset.version"},
        {"{\"asset\"", "[{\"asset\"", "not glTF"},
        {"\"meshes\":[{\"primitives\":[", "\"meshes\":[{\"primitives\":[],\"x\":[", "no primitives"},
        {"\"accessors\":[", "\"accessors\":{\"a\":0},\"y\":[", "accessors is not an array"},
    };
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
        const char* at = strstr(good, cases[k].from);
        REQUIRE(at);
        size_t pre = (size_t)(at - good), fl = strlen(cases[k].from), tl = strlen(cases[k].to);
        char* j = malloc(strlen(good) + tl + 1);
        memcpy(j, good, pre);
        memcpy(j + pre, cases[k].to, tl);
        strcpy(j + pre + tl, at + fl);
        mlb_mesh m;
        mlb_status s = parse_json(j, NULL, &m, NULL);
        CHECK_MSG(s != MLB_OK && mesh_is_zero(&m) && strncmp(mlb_last_error(), "q.gltf: ", 8) == 0 &&
                  strstr(mlb_last_error(), cases[k].err), "case %zu (%s): status %d, \"%s\"", k, cases[k].err, (int)s, mlb_last_error());
        mlb_mesh_free(&m);
        free(j);
    }
    // a non-finite position (float bits of +inf) in the buffer
    unsigned char b[144];
    quad_buffer(b);
    uint32_t inf_bits = 0x7F800000u;
    memcpy(b + 16, &inf_bits, 4);
    char* b64 = base64(b, 144);
    char uri2[400];
    snprintf(uri2, sizeof uri2, "data:application/octet-stream;base64,%s", b64);
    char* j = quad_json(uri2, "{\"mesh\":0}", "", PRIM);
    mlb_mesh m;
    mlb_status s = parse_json(j, NULL, &m, NULL);
    CHECK_MSG(s == MLB_ERR_FORMAT && strstr(mlb_last_error(), "accessors[0]: element 1 is not finite"), "%s", mlb_last_error());
    free(j);
    free(b64);
    // an index out of range
    quad_buffer(b);
    b[112 + 4] = 9;
    b64 = base64(b, 144);
    snprintf(uri2, sizeof uri2, "data:application/octet-stream;base64,%s", b64);
    j = quad_json(uri2, "{\"mesh\":0}", "", PRIM);
    s = parse_json(j, NULL, &m, NULL);
    CHECK_MSG(s == MLB_ERR_FORMAT && strstr(mlb_last_error(), "accessors[3]: index 9 (element 4) out of range (4 vertices)"), "%s",
              mlb_last_error());
    free(j);
    free(b64);
    // only points: no faces
    j = quad_json(uri, "{\"mesh\":0}", "", "{\"attributes\":{\"POSITION\":0},\"mode\":0}");
    s = parse_json(j, NULL, &m, NULL);
    CHECK_MSG(s == MLB_ERR_FORMAT && strstr(mlb_last_error(), "no faces"), "%s", mlb_last_error());
    free(j);
    // nodes nested 300 deep
    size_t cap = 300 * 40 + 4096;
    char* nodes = malloc(cap);
    size_t o = 0;
    for (int i = 0; i < 300; i++) o += (size_t)snprintf(nodes + o, cap - o, "%s{\"children\":[%d]}", i ? "," : "", i + 1);
    snprintf(nodes + o, cap - o, ",{\"mesh\":0}");
    j = quad_json(uri, nodes, "\"scenes\":[{\"nodes\":[0]}],", PRIM);
    s = parse_json(j, NULL, &m, NULL);
    CHECK_MSG(s == MLB_ERR_UNSUPPORTED && strstr(mlb_last_error(), "deeper than 256"), "%s", mlb_last_error());
    free(j);
    free(nodes);
    // not glTF at all
    s = mlb_gltf_parse((const unsigned char*)"v 0 0 0\n", 8, "x.gltf", NULL, &m, NULL, NULL);
    CHECK(s == MLB_ERR_FORMAT && strstr(mlb_last_error(), "x.gltf: not glTF"));
    CHECK(strstr(mlb_last_error(), "a JSON syntax error at byte 0") != NULL);
    // JSON nested 200000 deep (past cJSON's 1000 levels, which it refuses without a word): said so
    const size_t D = 200000;
    char* deep = malloc(2 * D + 1);
    REQUIRE(deep);
    memset(deep, '[', D);
    memset(deep + D, ']', D);
    s = mlb_gltf_parse((const unsigned char*)deep, 2 * D, "deep.gltf", NULL, &m, NULL, NULL);
    CHECK_MSG(s == MLB_ERR_FORMAT && strstr(mlb_last_error(), "deep.gltf: not glTF: neither a .glb nor JSON text (JSON nested "
                                                                "more than 1000 levels deep (at byte 1000))"), "%s", mlb_last_error());
    free(deep);
    s = mlb_gltf_load("/nonexistent/y.glb", &m, NULL, NULL);
    CHECK(s != MLB_OK && strstr(mlb_last_error(), "/nonexistent/y.glb") && mesh_is_zero(&m));
    free(good);
    free(uri);
}

// ---- truncated and corrupted .glb files ----

static int accepted, refused;

static void check_one(const unsigned char* d, size_t n) {
    mlb_mesh m;
    mlb_gltf_options o = {0, 1 << 20, 0, 0};
    mlb_status s = mlb_gltf_parse(d, n, "c.glb", NULL, &m, &o, NULL);
    if (s != MLB_OK) {
        refused++;
        if (!mesh_is_zero(&m) || strncmp(mlb_last_error(), "c.glb: ", 7) != 0) {
            CHECK_MSG(0, "refused without its promises: \"%s\"", mlb_last_error());
        }
        return;
    }
    accepted++;
    int bad = m.n_faces < 1 || m.n_verts < 1 || !m.pos || !m.faces;
    for (int i = 0; !bad && i < 3 * m.n_faces; i++) bad |= m.faces[i] < 0 || m.faces[i] >= m.n_verts;
    for (int i = 0; !bad && i < 3 * m.n_verts; i++) bad |= !isfinite(m.pos[i]);
    for (int i = 0; !bad && m.uv && i < 2 * m.n_verts; i++) bad |= !isfinite(m.uv[i]);
    for (int i = 0; !bad && m.normal && i < 3 * m.n_verts; i++) bad |= !isfinite(m.normal[i]);
    CHECK(!bad);
    mlb_mesh_free(&m);
}

TEST(truncated_and_corrupted) {
    mlb_mesh sphere;
    unsigned char* glb = NULL;
    size_t n = 0;
    REQUIRE(sphere_glb(&sphere, &glb, &n));
    mlb_mesh_free(&sphere);
    size_t json_end = 20 + (size_t)(glb[12] | glb[13] << 8 | glb[14] << 16);
    // every truncation: the header's length no longer matches
    int before = refused;
    for (size_t k = 0; k < n; k++) check_one(glb, k);
    CHECK(refused - before == (int)n);
    // corruptions: each byte of the header and the JSON set to a few values; random bytes over the
    // geometry data; random multi-byte damage anywhere
    unsigned char* c = malloc(n);
    static const unsigned char vals[] = {0, 0xFF, '9', '"', '-', '.', '}', ']', 'e', 0x80};
    for (size_t k = 0; k < json_end; k++)
        for (size_t v = 0; v < sizeof vals; v++) {
            memcpy(c, glb, n);
            c[k] = vals[v];
            check_one(c, n);
        }
    for (uint64_t t = 0; t < 3000; t++) {
        memcpy(c, glb, n);
        int hits = 1 + (int)mlb_rng_below(5, 1, t, 8);
        for (int h = 0; h < hits; h++) {
            size_t at = t < 1500 ? json_end + mlb_rng_below(5, 2, 16 * t + h, (uint32_t)(n - json_end))
                                 : mlb_rng_below(5, 3, 16 * t + h, (uint32_t)n);
            c[at] = (unsigned char)mlb_rng_below(5, 4, 16 * t + h, 256);
        }
        check_one(c, n);
    }
    printf("  %d accepted, %d refused (the image data is not read, so damage there is accepted)\n", accepted, refused);
    free(c);
    free(glb);
}

int main(void) {
    tmp = test_tmpdir("gltf");
    if (!tmp) return 1;
    RUN(round_trip_export);
    RUN(quad_forms);
    RUN(node_transforms);
    RUN(external_buffers);
    RUN(malformed);
    RUN(truncated_and_corrupted);
    return test_summary();
}
