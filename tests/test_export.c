// OBJ + MTL and glTF (.glb) writers and the viewer folder (include/matlaber/export.h): the .glb
// parsed back byte by byte (header, chunk types and alignment, JSON, accessors, index and uv data,
// the embedded PNGs decoded and compared with the sRGB / linear codes expected), the OBJ read back
// with the repository's own reader, and errors that leave no file behind.
// With arguments it writes the test asset for the cli tests instead:
//   test_export --write-glb FILE | --write-obj FILE.obj | --write-viewer DIR
//   test_export --write-run DIR   (DIR/final/mesh.obj and a small untrained direct-mode
//                                  DIR/final/material.safetensors, for 'matlaber export / view')
//   test_export --write-latent-viewer DIR   (the viewer folder of such a run in latent mode, with
//                                  its latent codes and decoder, for tests/cli_viewer.sh)
//   test_export --write-latent-run DIR      (that latent-mode run folder, for tests/cli_export.sh)
#include <cjson/cJSON.h>
#include <unistd.h>
#include "matlaber/export.h"
#include "matlaber/fileio.h"
#include "matlaber/gltf.h"
#include "matlaber/image.h"
#include "matlaber/latent_edit.h"
#include "matlaber/latent_export.h"
#include "matlaber/material_net.h"
#include "matlaber/mesh.h"
#include "matlaber/obj.h"
#include "matlaber/run_textured.h"
#include "test.h"

// ---- the test asset: a uv sphere with procedural maps ----
#define TS 64
typedef struct { mlb_mesh m; float kd[TS * TS * 3], ks[TS * TS * 3], kr[TS * TS]; mlb_asset a; } test_asset;

static int make_asset(test_asset* t) {
    memset(t, 0, sizeof *t);
    if (mlb_mesh_uv_sphere(&t->m, 0.8f, 32, 16) != MLB_OK) return 0;
    for (int y = 0; y < TS; y++)
        for (int x = 0; x < TS; x++) {
            size_t i = (size_t)y * TS + x;
            int checker = ((x / 8) + (y / 8)) & 1;
            // kd: a red / blue checker with a green ramp; ks: dielectric 0.04 left, gold right; kr ramp down
            t->kd[3 * i] = checker ? 0.8f : 0.05f;
            t->kd[3 * i + 1] = (float)y / (TS - 1) * 0.5f;
            t->kd[3 * i + 2] = checker ? 0.1f : 0.7f;
            int metal = x >= TS / 2;
            t->ks[3 * i] = metal ? 1.0f : 0.04f;
            t->ks[3 * i + 1] = metal ? 0.766f : 0.04f;
            t->ks[3 * i + 2] = metal ? 0.336f : 0.04f;
            t->kr[i] = 0.1f + 0.8f * (float)y / (TS - 1);
        }
    t->a = (mlb_asset){t->m.n_verts, t->m.n_faces, t->m.pos, t->m.normal, t->m.uv, t->m.faces, TS, t->kd, t->ks, t->kr, "sphere"};
    return 1;
}

static uint32_t rd32(const unsigned char* p) { return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24; }
static int code_srgb(float v) {
    double x = v < 0 ? 0 : v > 1 ? 1 : v;
    x = x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1 / 2.4) - 0.055;
    return (int)(x * 255 + 0.5);
}
static int code_lin(float v) { return (int)((v < 0 ? 0 : v > 1 ? 1 : v) * 255 + 0.5); }

static int json_int(const cJSON* o, const char* key) {
    const cJSON* v = cJSON_GetObjectItemCaseSensitive(o, key);
    return cJSON_IsNumber(v) ? (int)v->valuedouble : -1;
}

// Decodes image `img` (an index into "images") of the glb through a temporary file.
static int glb_image(const cJSON* root, const unsigned char* bin, const char* dir, int img, mlb_image* out) {
    const cJSON* im = cJSON_GetArrayItem(cJSON_GetObjectItem(root, "images"), img);
    const cJSON* bv = cJSON_GetArrayItem(cJSON_GetObjectItem(root, "bufferViews"), json_int(im, "bufferView"));
    if (!bv) return 0;
    char path[4200];
    snprintf(path, sizeof path, "%s/img%d.png", dir, img);
    if (mlb_write_file_atomic(path, bin + json_int(bv, "byteOffset"), (size_t)json_int(bv, "byteLength")) != MLB_OK) return 0;
    return mlb_image_load(out, path, 0) == MLB_OK;
}

TEST(glb_structure) {
    test_asset* t = malloc(sizeof *t);
    REQUIRE(t && make_asset(t));
    const char* dir = test_tmpdir("export_glb");
    REQUIRE(dir);
    char path[4200];
    snprintf(path, sizeof path, "%s/sphere.glb", dir);
    REQUIRE(mlb_export_glb(path, &t->a) == MLB_OK);
    char* data = NULL;
    size_t n = 0;
    REQUIRE(mlb_read_file(path, &data, &n, (size_t)1 << 28) == MLB_OK);
    const unsigned char* p = (const unsigned char*)data;
    // header: magic, version 2, total length = file size
    REQUIRE(n >= 28);
    CHECK(memcmp(p, "glTF", 4) == 0);
    CHECK(rd32(p + 4) == 2);
    CHECK(rd32(p + 8) == n);
    // chunk 0: JSON, length a multiple of 4, padded with spaces
    uint32_t jn = rd32(p + 12);
    CHECK(rd32(p + 16) == 0x4E4F534Au);
    CHECK(jn % 4 == 0);
    REQUIRE(20 + (size_t)jn + 8 <= n);
    char* json = malloc(jn + 1);
    memcpy(json, p + 20, jn);
    json[jn] = 0;
    size_t jl = strlen(json);
    while (jl > 0 && json[jl - 1] == ' ') jl--;
    CHECK(json[jl - 1] == '}');
    // chunk 1: BIN, 4-aligned length, ends the file
    const unsigned char* c1 = p + 20 + jn;
    uint32_t bn = rd32(c1);
    CHECK(rd32(c1 + 4) == 0x004E4942u);
    CHECK(bn % 4 == 0);
    CHECK(20 + (size_t)jn + 8 + bn == n);
    const unsigned char* bin = c1 + 8;
    cJSON* root = cJSON_Parse(json);
    REQUIRE(root);
    CHECK(strcmp(cJSON_GetObjectItem(cJSON_GetObjectItem(root, "asset"), "version")->valuestring, "2.0") == 0);
    CHECK(strcmp(cJSON_GetArrayItem(cJSON_GetObjectItem(root, "extensionsUsed"), 0)->valuestring, "KHR_materials_specular") == 0);
    CHECK(json_int(cJSON_GetArrayItem(cJSON_GetObjectItem(root, "buffers"), 0), "byteLength") == (int)bn);
    // every buffer view inside BIN, 4-aligned
    const cJSON* views = cJSON_GetObjectItem(root, "bufferViews");
    CHECK(cJSON_GetArraySize(views) == 7);
    const cJSON* v;
    cJSON_ArrayForEach(v, views) {
        int off = json_int(v, "byteOffset"), len = json_int(v, "byteLength");
        CHECK(off % 4 == 0 && off >= 0 && len > 0 && (size_t)off + (size_t)len <= bn);
    }
    // accessors: counts, types, POSITION bounds = the mesh's box
    const cJSON* acc = cJSON_GetObjectItem(root, "accessors");
    const cJSON* prim = cJSON_GetArrayItem(cJSON_GetObjectItem(cJSON_GetArrayItem(cJSON_GetObjectItem(root, "meshes"), 0), "primitives"), 0);
    const cJSON* attr = cJSON_GetObjectItem(prim, "attributes");
    const cJSON* pos = cJSON_GetArrayItem(acc, json_int(attr, "POSITION"));
    const cJSON* uva = cJSON_GetArrayItem(acc, json_int(attr, "TEXCOORD_0"));
    const cJSON* ind = cJSON_GetArrayItem(acc, json_int(prim, "indices"));
    REQUIRE(pos && uva && ind && cJSON_GetArrayItem(acc, json_int(attr, "NORMAL")));
    CHECK(json_int(pos, "count") == t->m.n_verts);
    CHECK(json_int(uva, "count") == t->m.n_verts);
    CHECK(json_int(ind, "count") == 3 * t->m.n_faces);
    CHECK(json_int(ind, "componentType") == 5125);
    CHECK(strcmp(cJSON_GetObjectItem(pos, "type")->valuestring, "VEC3") == 0);
    float lo[3], hi[3];
    mlb_mesh_bounds(&t->m, lo, hi);
    for (int k = 0; k < 3; k++) {
        CHECK(cJSON_GetArrayItem(cJSON_GetObjectItem(pos, "min"), k)->valuedouble == (double)lo[k]);
        CHECK(cJSON_GetArrayItem(cJSON_GetObjectItem(pos, "max"), k)->valuedouble == (double)hi[k]);
    }
    CHECK_CLOSE(hi[1], 0.8, 0, 1e-6);   // the sphere's radius
    // index and uv data as written: faces, (u, 1 - v)
    const cJSON* iv = cJSON_GetArrayItem(views, json_int(ind, "bufferView"));
    CHECK(memcmp(bin + json_int(iv, "byteOffset"), t->m.faces, 12 * (size_t)t->m.n_faces) == 0);
    const float* uvs = (const float*)(bin + json_int(cJSON_GetArrayItem(views, json_int(uva, "bufferView")), "byteOffset"));
    int uv_ok = 1;
    for (int i = 0; i < t->m.n_verts; i++)
        uv_ok &= uvs[2 * i] == t->m.uv[2 * i] && uvs[2 * i + 1] == 1.0f - t->m.uv[2 * i + 1];
    CHECK(uv_ok);
    // the material
    const cJSON* mat = cJSON_GetArrayItem(cJSON_GetObjectItem(root, "materials"), 0);
    const cJSON* pbr = cJSON_GetObjectItem(mat, "pbrMetallicRoughness");
    CHECK(cJSON_GetObjectItem(pbr, "metallicFactor")->valuedouble == 0);
    const cJSON* spec = cJSON_GetObjectItem(cJSON_GetObjectItem(mat, "extensions"), "KHR_materials_specular");
    REQUIRE(spec);
    CHECK_CLOSE(0.04 * cJSON_GetArrayItem(cJSON_GetObjectItem(spec, "specularColorFactor"), 0)->valuedouble, 1.0, 1e-12, 0);
    // images: textures -> images; decode and compare codes
    const cJSON* texs = cJSON_GetObjectItem(root, "textures");
    int i_kd = json_int(cJSON_GetArrayItem(texs, json_int(cJSON_GetObjectItem(pbr, "baseColorTexture"), "index")), "source");
    int i_mr = json_int(cJSON_GetArrayItem(texs, json_int(cJSON_GetObjectItem(pbr, "metallicRoughnessTexture"), "index")), "source");
    int i_ks = json_int(cJSON_GetArrayItem(texs, json_int(cJSON_GetObjectItem(spec, "specularColorTexture"), "index")), "source");
    mlb_image kd = {0}, mr = {0}, ks = {0};
    REQUIRE(glb_image(root, bin, dir, i_kd, &kd) && glb_image(root, bin, dir, i_mr, &mr) && glb_image(root, bin, dir, i_ks, &ks));
    CHECK(kd.w == TS && kd.h == TS && kd.c == 3 && mr.c == 3 && ks.c == 3);
    int bad = 0;
    for (int i = 0; i < TS * TS; i++) {
        for (int k = 0; k < 3; k++) {
            bad += (int)lroundf(kd.data[3 * i + k] * 255) != code_srgb(t->kd[3 * i + k]);
            bad += (int)lroundf(ks.data[3 * i + k] * 255) != code_srgb(t->ks[3 * i + k]);
        }
        bad += (int)lroundf(mr.data[3 * i + 1] * 255) != code_lin(t->kr[i]);
        bad += mr.data[3 * i + 2] != 0.0f;   // metallic channel
    }
    CHECK_MSG(bad == 0, "%d texture samples differ from the expected codes", bad);
    mlb_image_free(&kd); mlb_image_free(&mr); mlb_image_free(&ks);
    cJSON_Delete(root);
    free(json);
    free(data);
    mlb_mesh_free(&t->m);
    free(t);
}

TEST(glb_computes_unit_normals) {
    // a single triangle without normals, scaled: normal +z, unit length
    const float pos[9] = {0, 0, 0, 2, 0, 0, 0, 2, 0}, uv[6] = {0, 0, 1, 0, 0, 1};
    const int32_t f[3] = {0, 1, 2};
    float kd[3] = {0.5f, 0.5f, 0.5f}, ks[3] = {0.04f, 0.04f, 0.04f}, kr[1] = {0.5f};
    mlb_asset a = {3, 1, pos, NULL, uv, f, 1, kd, ks, kr, NULL};
    unsigned char* d = NULL;
    size_t n = 0;
    REQUIRE(mlb_export_glb_memory(&a, &d, &n) == MLB_OK);
    uint32_t jn = rd32(d + 12);
    char* json = strndup((const char*)d + 20, jn);
    cJSON* root = cJSON_Parse(json);
    REQUIRE(root);
    const cJSON* views = cJSON_GetObjectItem(root, "bufferViews");
    const cJSON* acc = cJSON_GetObjectItem(root, "accessors");
    int nv = json_int(cJSON_GetArrayItem(acc, 1), "bufferView");
    const float* nrm = (const float*)(d + 28 + jn + json_int(cJSON_GetArrayItem(views, nv), "byteOffset"));
    for (int i = 0; i < 3; i++) { CHECK(nrm[3 * i] == 0 && nrm[3 * i + 1] == 0 && nrm[3 * i + 2] == 1); }
    cJSON_Delete(root);
    free(json);
    free(d);
}

TEST(obj_round_trip) {
    test_asset* t = malloc(sizeof *t);
    REQUIRE(t && make_asset(t));
    const char* dir = test_tmpdir("export_obj");
    REQUIRE(dir);
    char path[4200], p2[4300];
    snprintf(path, sizeof path, "%s/ball.obj", dir);
    REQUIRE(mlb_export_obj(path, &t->a) == MLB_OK);
    mlb_mesh m = {0};
    mlb_obj_info info;
    REQUIRE(mlb_obj_load_ex(path, &m, NULL, &info) == MLB_OK);
    CHECK(strcmp(info.mtllib, "ball.mtl") == 0);
    CHECK(m.n_faces == t->m.n_faces);
    char* used = calloc((size_t)t->m.n_verts, 1);
    int n_used = 0;
    for (int i = 0; i < 3 * t->m.n_faces; i++)
        if (!used[t->m.faces[i]]) { used[t->m.faces[i]] = 1; n_used++; }
    free(used);
    CHECK(m.n_verts == n_used);   // the reader drops the pole copies no face uses
    REQUIRE(m.uv && m.normal);
    // corner by corner: the same position, uv (written with %.9g: exact) and unit normal
    int bad = 0;
    for (int f = 0; f < m.n_faces; f++)
        for (int k = 0; k < 3; k++) {
            int a = t->m.faces[3 * f + k], b = m.faces[3 * f + k];
            for (int j = 0; j < 3; j++) bad += m.pos[3 * b + j] != t->m.pos[3 * a + j];
            for (int j = 0; j < 2; j++) bad += m.uv[2 * b + j] != t->m.uv[2 * a + j];
            for (int j = 0; j < 3; j++) bad += fabsf(m.normal[3 * b + j] - t->m.normal[3 * a + j]) > 1e-6f;
        }
    CHECK_MSG(bad == 0, "%d corner values differ", bad);
    // the MTL names the three textures and the PBR keys
    snprintf(p2, sizeof p2, "%s/ball.mtl", dir);
    char* mtl = NULL;
    size_t n = 0;
    REQUIRE(mlb_read_file(p2, &mtl, &n, 1 << 20) == MLB_OK);
    CHECK(strstr(mtl, "newmtl sphere\n") != NULL);
    CHECK(strstr(mtl, "\nmap_Kd ball_kd.png\n") != NULL);
    CHECK(strstr(mtl, "\nmap_Ks ball_ks.png\n") != NULL);
    CHECK(strstr(mtl, "\nmap_Pr ball_roughness.png\n") != NULL);
    CHECK(strstr(mtl, "\nPm 0\n") != NULL);
    free(mtl);
    // the textures: kd sRGB codes, roughness linear grey
    mlb_image kd = {0}, kr = {0};
    snprintf(p2, sizeof p2, "%s/ball_kd.png", dir);
    REQUIRE(mlb_image_load(&kd, p2, 0) == MLB_OK);
    snprintf(p2, sizeof p2, "%s/ball_roughness.png", dir);
    REQUIRE(mlb_image_load(&kr, p2, 0) == MLB_OK);
    CHECK(kd.c == 3 && kr.c == 1 && kd.w == TS && kr.h == TS);
    bad = 0;
    for (int i = 0; i < TS * TS; i++) {
        for (int k = 0; k < 3; k++) bad += (int)lroundf(kd.data[3 * i + k] * 255) != code_srgb(t->kd[3 * i + k]);
        bad += (int)lroundf(kr.data[i] * 255) != code_lin(t->kr[i]);
    }
    CHECK_MSG(bad == 0, "%d texture samples differ", bad);
    mlb_image_free(&kd); mlb_image_free(&kr);
    mlb_mesh_free(&m);
    mlb_mesh_free(&t->m);
    free(t);
}

static int exists(const char* dir, const char* name) {
    char p[4400];
    snprintf(p, sizeof p, "%s/%s", dir, name);
    return access(p, F_OK) == 0;
}

TEST(errors_leave_nothing) {
    test_asset* t = malloc(sizeof *t);
    REQUIRE(t && make_asset(t));
    const char* dir = test_tmpdir("export_err");
    REQUIRE(dir);
    char path[4200];
    // a face index out of range: refused before anything is written, message names the corner
    int32_t saved = t->m.faces[5];
    t->m.faces[5] = t->m.n_verts;
    snprintf(path, sizeof path, "%s/bad.glb", dir);
    CHECK(mlb_export_glb(path, &t->a) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "face 1 corner 2") != NULL);
    CHECK(!exists(dir, "bad.glb"));
    t->m.faces[5] = saved;
    // NaN in a position
    float px = t->m.pos[7];
    t->m.pos[7] = NAN;
    snprintf(path, sizeof path, "%s/bad.obj", dir);
    CHECK(mlb_export_obj(path, &t->a) == MLB_ERR_NUMERIC);
    CHECK(strstr(mlb_last_error(), "bad.obj") != NULL && strstr(mlb_last_error(), "pos[7]") != NULL);
    t->m.pos[7] = px;
    // roughness outside [0, 1]
    t->kr[3] = 1.5f;
    CHECK(mlb_export_glb(path, &t->a) == MLB_ERR_ARG);
    t->kr[3] = 0.5f;
    // not .obj
    snprintf(path, sizeof path, "%s/bad.txt", dir);
    CHECK(mlb_export_obj(path, &t->a) == MLB_ERR_ARG);
    // the third file cannot be written (a folder is in the way): the two PNGs already written go
    char p2[4300];
    snprintf(p2, sizeof p2, "%s/half_roughness.png", dir);
    REQUIRE(mlb_mkdir_p(p2) == MLB_OK);
    snprintf(path, sizeof path, "%s/half.obj", dir);
    CHECK(mlb_export_obj(path, &t->a) != MLB_OK);
    CHECK(!exists(dir, "half_kd.png") && !exists(dir, "half_ks.png") && !exists(dir, "half.mtl") && !exists(dir, "half.obj"));
    // a missing folder
    snprintf(path, sizeof path, "%s/no/such/dir/x.glb", dir);
    CHECK(mlb_export_glb(path, &t->a) == MLB_ERR_IO);
    CHECK(strstr(mlb_last_error(), "x.glb") != NULL);
    mlb_mesh_free(&t->m);
    free(t);
}

TEST(viewer_folder) {
    char src[4096];
    char hint[4096];
    snprintf(hint, sizeof hint, "%s/viewer", MLB_SOURCE_DIR);
    if (mlb_viewer_find_source(hint, src, sizeof src) != MLB_OK)
        SKIP("no viewer/node_modules/three (scripts/build.sh installs it with npm): %s", mlb_last_error());
    // without a hint the library finds the source tree's viewer/ too
    unsetenv("MATLABER_VIEWER_DIR");
    CHECK(mlb_viewer_find_source(NULL, src, sizeof src) == MLB_OK);
    test_asset* t = malloc(sizeof *t);
    REQUIRE(t && make_asset(t));
    const char* dir = test_tmpdir("export_viewer");
    REQUIRE(dir);
    const char* envs[] = {"sky", "studio", NULL};
    mlb_viewer_options opt = {hint, envs, 32, "test sphere"};
    REQUIRE(mlb_viewer_write_asset(dir, &t->a, &opt) == MLB_OK);
    static const char* files[] = {"index.html", "viewer.js", "viewer.json", "asset.glb", "env/sky.hdr", "env/studio.hdr",
                                  "lib/three/build/three.module.js", "lib/three/examples/jsm/loaders/GLTFLoader.js",
                                  "lib/three/examples/jsm/controls/OrbitControls.js", NULL};
    for (int i = 0; files[i]; i++) CHECK_MSG(exists(dir, files[i]), "%s missing", files[i]);
    CHECK(!exists(dir, "env/overcast.hdr"));
    // an unknown environment is an error naming it
    const char* bad_envs[] = {"moon", NULL};
    opt.envs = bad_envs;
    CHECK(mlb_viewer_write_asset(dir, &t->a, &opt) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "moon") != NULL);
    // a hint that is not a viewer folder
    CHECK(mlb_viewer_find_source(dir, src, sizeof src) == MLB_ERR_NOT_FOUND);
    mlb_mesh_free(&t->m);
    free(t);
}

// A run folder as the pipeline leaves it: final/mesh.obj and final/material.safetensors.
static mlb_status write_run(const char* dir, const mlb_asset* a, mlb_material_mode mode) {
    char path[4200];
    snprintf(path, sizeof path, "%s/final", dir);
    MLB_TRY(mlb_mkdir_p(path));
    snprintf(path, sizeof path, "%s/final/mesh.obj", dir);
    MLB_TRY(mlb_export_obj(path, a));
    mlb_material_config cfg = mlb_material_default();
    cfg.mode = mode;
    cfg.enc.n_levels = 4;
    cfg.enc.table_size = 1u << 12;
    cfg.enc.base_res = 4;
    cfg.hidden = 16;
    mlb_material_net net = {0};
    mlb_brdf_ae prior = {0};
    char source[256];
    mlb_status s = mode == MLB_MATERIAL_LATENT ? mlb_brdf_ae_load_default(&prior, source, sizeof source) : MLB_OK;
    if (!s) s = material_net_init(&net, &cfg, mode == MLB_MATERIAL_LATENT ? &prior : NULL);
    // an untrained net's codes barely vary (a hash table of ±1e-4): scale the table and the last
    // layer so the codes, and the materials, change across the surface (a flipped or shifted
    // latent texture then shows in the viewer's test)
    if (!s && mode == MLB_MATERIAL_LATENT) {
        for (size_t i = 0; i < net.n_enc; i++) net.params[i] *= 5000.0f;
        mlb_mlp* m = &net.mlp;
        int l = m->n_layers - 1;
        for (int i = 0; i < m->dims[l] * m->dims[l + 1]; i++) m->weight[l][i] *= 4.0f;
    }
    snprintf(path, sizeof path, "%s/final/material.safetensors", dir);
    if (!s) s = mlb_material_save(&net, path, 0);
    material_net_free(&net);
    brdf_ae_free(&prior);
    return s;
}

// A latent-mode run's viewer folder, as `matlaber view RUN_DIR` writes it.
static mlb_status write_run_glb(const char* path, const void* ctx) { return mlb_run_textured_write_glb(ctx, path); }
static mlb_status write_latent_viewer(const char* dir, const mlb_asset* a) {
    char run[4200];
    snprintf(run, sizeof run, "%s.run", dir);
    MLB_TRY(write_run(run, a, MLB_MATERIAL_LATENT));
    mlb_run_textured r;
    MLB_TRY(mlb_run_textured_load(&r, run, 64));
    mlb_viewer_options opt = {NULL, NULL, 32, "latent test"};
    mlb_status s = mlb_viewer_write_with(dir, &opt, write_run_glb, &r);
    mlb_run_textured_free(&r);
    return s;
}

// The decoder as the JSON describes it, in double: z [4] -> k [7].
static int json_decode(const cJSON* dec, const float* z, double* k) {
    double a[256], b[256];
    for (int i = 0; i < 4; i++) a[i] = z[i];
    const cJSON* layers = cJSON_GetObjectItem(dec, "layers");
    const char* hidden = cJSON_GetStringValue(cJSON_GetObjectItem(dec, "hidden_activation"));
    int n_layers = cJSON_GetArraySize(layers), out = 0;
    if (!hidden || n_layers < 1) return 0;
    for (int l = 0; l < n_layers; l++) {
        const cJSON* L = cJSON_GetArrayItem(layers, l);
        int in = json_int(L, "in");
        out = json_int(L, "out");
        const cJSON *w = cJSON_GetObjectItem(L, "weight"), *bias = cJSON_GetObjectItem(L, "bias");
        if (in > 256 || out > 256 || cJSON_GetArraySize(w) != in * out || cJSON_GetArraySize(bias) != out) return 0;
        const cJSON* wi = w->child;
        for (int o = 0; o < out; o++) {
            double x = cJSON_GetArrayItem(bias, o)->valuedouble;
            for (int i = 0; i < in; i++, wi = wi->next) x += wi->valuedouble * a[i];
            if (l == n_layers - 1) x = 1 / (1 + exp(-x));   // output_activation: sigmoid (checked below)
            else if (!strcmp(hidden, "silu")) x = x / (1 + exp(-x));
            else if (!strcmp(hidden, "relu")) x = x > 0 ? x : 0;
            else if (!strcmp(hidden, "tanh")) x = tanh(x);
            else return 0;
            b[o] = x;
        }
        memcpy(a, b, sizeof(double) * (size_t)out);
    }
    if (out != 7) return 0;
    const cJSON *lo = cJSON_GetObjectItem(dec, "range_lo"), *hi = cJSON_GetObjectItem(dec, "range_hi");
    for (int c = 0; c < 7; c++) {
        double l0 = cJSON_GetArrayItem(lo, c)->valuedouble, h0 = cJSON_GetArrayItem(hi, c)->valuedouble;
        k[c] = l0 + (h0 - l0) * a[c];
    }
    return 1;
}

// The exported decoder JSON and latent texture give back, at every covered texel, the BRDF the
// .glb's textures were baked from (and mlb_material_decode's), to float rounding.
TEST(latent_sidecars) {
    test_asset* t = malloc(sizeof *t);
    REQUIRE(t && make_asset(t));
    const char* dir = test_tmpdir("export_latent");
    REQUIRE(dir);
    char run[4200], glb[4300], json[4400], bin[4400];
    snprintf(run, sizeof run, "%s/run", dir);
    REQUIRE(write_run(run, &t->a, MLB_MATERIAL_LATENT) == MLB_OK);
    const int S = 32;
    mlb_run_textured r;
    REQUIRE(mlb_run_textured_load(&r, run, S) == MLB_OK);
    REQUIRE(r.latent != NULL);
    snprintf(glb, sizeof glb, "%s/a.glb", dir);
    REQUIRE(mlb_run_textured_write_glb(&r, glb) == MLB_OK);
    REQUIRE(mlb_latent_export_paths(glb, json, bin, sizeof json) == 0);
    char *jtext = NULL, *bdata = NULL;
    size_t jn = 0, bn = 0;
    REQUIRE(mlb_read_file(json, &jtext, &jn, 1 << 24) == MLB_OK);
    REQUIRE(mlb_read_file(bin, &bdata, &bn, 1 << 24) == MLB_OK);
    cJSON* dec = cJSON_ParseWithLength(jtext, jn);
    REQUIRE(dec != NULL);
    const cJSON* lat = cJSON_GetObjectItem(dec, "latent");
    CHECK(json_int(lat, "size") == S && json_int(lat, "channels") == 4);
    CHECK(!strcmp(cJSON_GetStringValue(cJSON_GetObjectItem(lat, "file")), "a.latent.bin"));
    CHECK(!strcmp(cJSON_GetStringValue(cJSON_GetObjectItem(dec, "output_activation")), "sigmoid"));
    CHECK(bn == (size_t)S * S * 16);
    float* z = malloc(sizeof(float) * 4 * (size_t)S * S);
    float* kc = malloc(sizeof(float) * 7 * (size_t)S * S);
    REQUIRE(z && kc);
    const unsigned char* u = (const unsigned char*)bdata;
    for (size_t i = 0; i < 4 * (size_t)S * S && bn == (size_t)S * S * 16; i++) {
        uint32_t v = rd32(u + 4 * i);
        memcpy(z + i, &v, 4);
    }
    CHECK(memcmp(z, r.latent, bn < 4 * sizeof(float) * (size_t)S * S ? bn : 4 * sizeof(float) * (size_t)S * S) == 0);
    REQUIRE(mlb_material_decode(&r.run.material, z, (size_t)S * S, kc) == MLB_OK);
    double worst_baked = 0, worst_decode = 0;
    int covered = 0;
    for (int i = 0; i < S * S; i++) {
        double k[7];
        REQUIRE(json_decode(dec, z + 4 * i, k));
        const double baked[7] = {r.baked.kd[3 * i], r.baked.kd[3 * i + 1], r.baked.kd[3 * i + 2], r.baked.ks[3 * i],
                                 r.baked.ks[3 * i + 1], r.baked.ks[3 * i + 2], r.baked.roughness[i]};
        for (int c = 0; c < 7; c++) {
            worst_decode = fmax(worst_decode, fabs(k[c] - kc[7 * i + c]));
            // every texel, dilated ones too: the codes were dilated as the maps were
            worst_baked = fmax(worst_baked, fabs(k[c] - baked[c]));
        }
        covered += r.baked.mask[i];
    }
    float zlo = INFINITY, zhi = -INFINITY;
    for (int i = 0; i < 4 * S * S; i++) { zlo = fminf(zlo, z[i]); zhi = fmaxf(zhi, z[i]); }
    printf("  latent sidecars: %d covered texels of %d, codes in [%.2f, %.2f]; |json decode - baked| <= %.2g, "
           "|json - mlb_material_decode| <= %.2g\n", covered, S * S, zlo, zhi, worst_baked, worst_decode);
    CHECK(zhi - zlo > 0.5);   // the codes vary: the comparison is not of one constant
    CHECK(covered > S * S / 10);
    CHECK_MSG(worst_baked < 1e-5, "the JSON decoder misses the baked BRDF by %g", worst_baked);
    CHECK_MSG(worst_decode < 1e-5, "the JSON decoder misses mlb_material_decode by %g", worst_decode);
    // a direct-mode export over the same name removes the editor's files
    mlb_run_textured_free(&r);
    REQUIRE(write_run(run, &t->a, MLB_MATERIAL_DIRECT) == MLB_OK);
    REQUIRE(mlb_run_textured_load(&r, run, S) == MLB_OK);
    CHECK(r.latent == NULL);
    REQUIRE(mlb_run_textured_write_glb(&r, glb) == MLB_OK);
    CHECK(!exists(dir, "a.decoder.json") && !exists(dir, "a.latent.bin") && exists(dir, "a.glb"));
    mlb_run_textured_free(&r);
    cJSON_Delete(dec);
    free(jtext); free(bdata); free(z); free(kc);
    mlb_mesh_free(&t->m);
    free(t);
}

// The sidecars read back (latent_edit.h) are the codes and decoder written; an edit changes exactly
// the texels of its region, to the formula; the edited asset's sidecars hold the edited codes.
TEST(latent_edit) {
    test_asset* t = malloc(sizeof *t);
    REQUIRE(t && make_asset(t));
    const char* dir = test_tmpdir("export_latent_edit");
    REQUIRE(dir);
    char run[4200], glb[4300], out[4300], obj[4300], path[4400];
    snprintf(run, sizeof run, "%s/run", dir);
    REQUIRE(write_run(run, &t->a, MLB_MATERIAL_LATENT) == MLB_OK);
    const int S = 32;
    const size_t N = (size_t)S * S;
    mlb_run_textured r;
    REQUIRE(mlb_run_textured_load(&r, run, S) == MLB_OK);
    snprintf(glb, sizeof glb, "%s/a.glb", dir);
    REQUIRE(mlb_run_textured_write_glb(&r, glb) == MLB_OK);
    mlb_latent_asset a;
    REQUIRE(mlb_latent_asset_read(glb, &a) == MLB_OK);
    CHECK(a.size == S);
    CHECK(memcmp(a.z, r.latent, sizeof(float) * 4 * N) == 0);
    float* k = malloc(sizeof(float) * 7 * N);
    float* z = malloc(sizeof(float) * 4 * N);
    REQUIRE(k && z);
    REQUIRE(mlb_latent_decode(&a, a.z, N, k, k + 3 * N, k + 6 * N) == MLB_OK);
    double worst = 0;
    for (size_t i = 0; i < N; i++) {
        for (int c = 0; c < 3; c++) worst = fmax(worst, fabs(k[3 * i + c] - r.baked.kd[3 * i + c]));
        for (int c = 0; c < 3; c++) worst = fmax(worst, fabs(k[3 * N + 3 * i + c] - r.baked.ks[3 * i + c]));
        worst = fmax(worst, fabs(k[6 * N + i] - r.baked.roughness[i]));
    }
    CHECK_MSG(worst < 1e-5, "the decoder read back misses the baked maps by %g", worst);
    // a region: the material at the first covered texel, within a quarter of the codes' spread
    int pick = 0;
    while (pick < S * S && !r.baked.mask[pick]) pick++;
    REQUIRE(pick < S * S);
    float lo = INFINITY, hi = -INFINITY;
    for (size_t i = 0; i < 4 * N; i++) { lo = fminf(lo, a.z[i]); hi = fmaxf(hi, a.z[i]); }
    mlb_latent_edit e = {.offset = {0.5f, 0, -0.25f, 0}, .radius = (hi - lo) / 4, .t = 0.3f};
    memcpy(e.pick, a.z + 4 * pick, sizeof e.pick);
    mlb_latent_mean(a.z, N, e.target);
    memcpy(z, a.z, sizeof(float) * 4 * N);
    size_t in = mlb_latent_edit_apply(&e, z, N);
    size_t seen = 0, wrong = 0;
    for (size_t i = 0; i < N; i++) {
        const float* v = a.z + 4 * i;
        double d2 = 0;
        for (int c = 0; c < 4; c++) d2 += ((double)v[c] - e.pick[c]) * ((double)v[c] - e.pick[c]);
        int inside = sqrt(d2) <= e.radius;
        seen += inside;
        for (int c = 0; c < 4; c++) {
            double want = inside ? (1 - 0.3) * v[c] + 0.3 * e.target[c] + e.offset[c] : v[c];
            wrong += inside ? fabs(z[4 * i + c] - want) > 1e-5 : z[4 * i + c] != v[c];
        }
    }
    printf("  latent edit: %zu of %zu texels within %.3f of texel %d's code\n", in, N, e.radius, pick);
    CHECK(in == seen && in > 0 && in < N);   // a region, neither empty nor everything
    CHECK_MSG(wrong == 0, "%zu channels off the edit's formula", wrong);
    // the whole asset: every texel
    mlb_latent_edit whole = {.offset = {0, 0, 0, 0}, .radius = -1};
    memcpy(z, a.z, sizeof(float) * 4 * N);
    CHECK(mlb_latent_edit_apply(&whole, z, N) == N && memcmp(z, a.z, sizeof(float) * 4 * N) == 0);
    // written as a new asset: its sidecars hold the edited codes, its mesh is the source's
    snprintf(out, sizeof out, "%s/b.glb", dir);
    snprintf(obj, sizeof obj, "%s/b.obj", dir);
    size_t in2 = 0;
    REQUIRE(mlb_latent_edit_export(glb, &e, out, obj, &in2) == MLB_OK);
    CHECK(in2 == in);
    mlb_latent_asset b;
    REQUIRE(mlb_latent_asset_read(out, &b) == MLB_OK);
    memcpy(z, a.z, sizeof(float) * 4 * N);
    mlb_latent_edit_apply(&e, z, N);
    CHECK(b.size == S && memcmp(b.z, z, sizeof(float) * 4 * N) == 0);
    mlb_mesh ma, mb;
    REQUIRE(mlb_gltf_load(glb, &ma, NULL, NULL) == MLB_OK);
    REQUIRE(mlb_gltf_load(out, &mb, NULL, NULL) == MLB_OK);
    CHECK(ma.n_verts == mb.n_verts && ma.n_faces == mb.n_faces &&
          !memcmp(ma.pos, mb.pos, sizeof(float) * 3 * (size_t)ma.n_verts) &&
          !memcmp(ma.faces, mb.faces, sizeof(int32_t) * 3 * (size_t)ma.n_faces));
    CHECK(exists(dir, "b.obj") && exists(dir, "b.mtl") && exists(dir, "b_kd.png") && exists(dir, "b_roughness.png"));
    // hostile sidecars: a .bin one byte short, a layer of the wrong width
    mlb_latent_asset bad;
    snprintf(path, sizeof path, "%s/b.latent.bin", dir);
    REQUIRE(mlb_write_file_atomic(path, b.z, 16 * N - 1) == MLB_OK);
    CHECK(mlb_latent_asset_read(out, &bad) == MLB_ERR_FORMAT && strstr(mlb_last_error(), "b.latent.bin") && bad.z == NULL);
    snprintf(path, sizeof path, "%s/b.decoder.json", dir);
    const char* narrow = "{\"format\":\"matlaber-latent-decoder-1\",\"hidden_activation\":\"relu\","
                         "\"output_activation\":\"sigmoid\",\"layers\":[{\"in\":4,\"out\":7,\"weight\":[1],\"bias\":[]}]}";
    REQUIRE(mlb_write_file_atomic(path, narrow, strlen(narrow)) == MLB_OK);
    CHECK(mlb_latent_asset_read(out, &bad) == MLB_ERR_FORMAT && strstr(mlb_last_error(), "layers[0].weight"));
    mlb_mesh_free(&ma);
    mlb_mesh_free(&mb);
    mlb_latent_asset_free(&a);
    mlb_latent_asset_free(&b);
    mlb_run_textured_free(&r);
    free(k); free(z);
    mlb_mesh_free(&t->m);
    free(t);
}

int main(int argc, char** argv) {
    if (argc == 3) {   // writer mode for tests/cli_export.sh and tests/cli_viewer.sh
        test_asset* t = malloc(sizeof *t);
        if (!t || !make_asset(t)) return 1;
        mlb_status s;
        if (strcmp(argv[1], "--write-glb") == 0) s = mlb_export_glb(argv[2], &t->a);
        else if (strcmp(argv[1], "--write-obj") == 0) s = mlb_export_obj(argv[2], &t->a);
        else if (strcmp(argv[1], "--write-viewer") == 0) s = mlb_viewer_write_asset(argv[2], &t->a, NULL);
        else if (strcmp(argv[1], "--write-run") == 0) s = write_run(argv[2], &t->a, MLB_MATERIAL_DIRECT);
        else if (strcmp(argv[1], "--write-latent-viewer") == 0) s = write_latent_viewer(argv[2], &t->a);
        else if (strcmp(argv[1], "--write-latent-run") == 0) s = write_run(argv[2], &t->a, MLB_MATERIAL_LATENT);
        else { fprintf(stderr, "usage: test_export [--write-glb FILE | --write-obj FILE | --write-viewer DIR]\n"); return 2; }
        if (s != MLB_OK) fprintf(stderr, "test_export: %s\n", mlb_last_error());
        mlb_mesh_free(&t->m);
        free(t);
        return s == MLB_OK ? 0 : 1;
    }
    RUN(glb_structure);
    RUN(glb_computes_unit_normals);
    RUN(obj_round_trip);
    RUN(errors_leave_nothing);
    RUN(viewer_folder);
    RUN(latent_sidecars);
    RUN(latent_edit);
    return test_summary();
}
