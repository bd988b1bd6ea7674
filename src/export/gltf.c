// glTF 2.0 binary writer (one mesh, one primitive, one PBR material with KHR_materials_specular),
// the asset check the writers share, and 8-bit PNG encoding into memory. The mapping is in
// include/matlaber/export.h and docs/export.md.
#include "matlaber/export.h"
#include <cjson/cJSON.h>
#include <math.h>
#include <png.h>
#include <setjmp.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/fileio.h"

// ---- the asset check ----

static mlb_status check_finite(const float* x, size_t n, const char* what) {
    for (size_t i = 0; i < n; i++)
        if (!isfinite(x[i])) return mlb_fail(MLB_ERR_NUMERIC, "asset: %s[%zu] is %g (not finite)", what, i, (double)x[i]);
    return MLB_OK;
}

static mlb_status check_unit(const float* x, size_t n, const char* what) {
    for (size_t i = 0; i < n; i++)
        if (!(x[i] >= -1e-6f && x[i] <= 1.0f + 1e-6f))
            return mlb_fail(MLB_ERR_ARG, "asset: texture %s[%zu] = %g is outside [0, 1]", what, i, (double)x[i]);
    return MLB_OK;
}

mlb_status mlb_asset_check(const mlb_asset* a) {
    if (!a) return mlb_fail(MLB_ERR_ARG, "asset: NULL");
    if (a->n_verts < 3 || a->n_faces < 1)
        return mlb_fail(MLB_ERR_ARG, "asset: %d vertices, %d faces (need >= 3 and >= 1)", a->n_verts, a->n_faces);
    if (a->n_verts > (1 << 28) || a->n_faces > (1 << 28))
        return mlb_fail(MLB_ERR_ARG, "asset: %d vertices, %d faces (at most 2^28 each)", a->n_verts, a->n_faces);
    if (!a->pos || !a->uv || !a->faces) return mlb_fail(MLB_ERR_ARG, "asset: NULL positions, uv or faces");
    if (a->tex_size < 1 || a->tex_size > 16384)
        return mlb_fail(MLB_ERR_ARG, "asset: texture size %d (1 to 16384)", a->tex_size);
    if (!a->kd || !a->ks || !a->kr) return mlb_fail(MLB_ERR_ARG, "asset: NULL kd, ks or roughness texture");
    size_t V = (size_t)a->n_verts, F = (size_t)a->n_faces, S2 = (size_t)a->tex_size * (size_t)a->tex_size;
    MLB_TRY(check_finite(a->pos, 3 * V, "pos"));
    MLB_TRY(check_finite(a->uv, 2 * V, "uv"));
    if (a->normal) MLB_TRY(check_finite(a->normal, 3 * V, "normal"));
    for (size_t i = 0; i < 3 * F; i++)
        if (a->faces[i] < 0 || a->faces[i] >= a->n_verts)
            return mlb_fail(MLB_ERR_ARG, "asset: face %zu corner %zu is vertex %d (%d vertices)", i / 3, i % 3,
                            (int)a->faces[i], a->n_verts);
    MLB_TRY(check_unit(a->kd, 3 * S2, "kd"));
    MLB_TRY(check_unit(a->ks, 3 * S2, "ks"));
    MLB_TRY(check_unit(a->kr, S2, "roughness"));
    return MLB_OK;
}

// ---- PNG into memory (the encoding of src/io/image_write.c: NaN -> 0, clamp, exact sRGB, round half up) ----

typedef struct { unsigned char* p; size_t n, cap; int oom; } membuf;

static void mem_write(png_structp png, png_bytep data, png_size_t len) {
    membuf* b = png_get_io_ptr(png);
    if (b->oom) return;
    if (b->n + len > b->cap) {
        size_t cap = b->cap ? b->cap : 4096;
        while (cap < b->n + len) cap *= 2;
        unsigned char* q = realloc(b->p, cap);
        if (!q) { b->oom = 1; png_error(png, "out of memory"); }
        b->p = q;
        b->cap = cap;
    }
    memcpy(b->p + b->n, data, len);
    b->n += len;
}
static void mem_flush(png_structp png) { (void)png; }

typedef struct { char msg[256]; } png_err_box;
static void png_on_error(png_structp png, png_const_charp msg) {
    png_err_box* box = png_get_error_ptr(png);
    if (box) snprintf(box->msg, sizeof box->msg, "%s", msg ? msg : "unknown error");
    png_longjmp(png, 1);
}
static void png_on_warning(png_structp png, png_const_charp msg) { (void)png; (void)msg; }

static unsigned char quantize8(float v, int srgb) {
    double x = v;
    if (!(x > 0)) x = 0;
    if (x > 1) x = 1;
    if (srgb) x = x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1.0 / 2.4) - 0.055;
    unsigned q = (unsigned)(x * 255 + 0.5);
    return (unsigned char)(q > 255 ? 255 : q);
}

static int png_encode_rows(png_structp png, png_infop info, membuf* b, const float* data, int w, int h, int c, int srgb,
                           unsigned char* row) {
    if (setjmp(png_jmpbuf(png))) return 0;
    static const int types[5] = {0, PNG_COLOR_TYPE_GRAY, PNG_COLOR_TYPE_GRAY_ALPHA, PNG_COLOR_TYPE_RGB,
                                 PNG_COLOR_TYPE_RGB_ALPHA};
    png_set_write_fn(png, b, mem_write, mem_flush);
    png_set_IHDR(png, info, (png_uint_32)w, (png_uint_32)h, 8, types[c], PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
                 PNG_FILTER_TYPE_DEFAULT);
    if (srgb) png_set_sRGB_gAMA_and_cHRM(png, info, PNG_sRGB_INTENT_PERCEPTUAL);
    png_write_info(png, info);
    int alpha = (c == 2 || c == 4) ? c - 1 : -1;
    for (int y = 0; y < h; y++) {
        const float* src = data + (size_t)y * (size_t)w * (size_t)c;
        for (size_t i = 0; i < (size_t)w * (size_t)c; i++) row[i] = quantize8(src[i], srgb && (int)(i % (size_t)c) != alpha);
        png_write_row(png, row);
    }
    png_write_end(png, info);
    return 1;
}

mlb_status mlb_png_encode_memory(const float* data, int w, int h, int c, int srgb, unsigned char** out, size_t* n) {
    if (!data || !out || !n) return mlb_fail(MLB_ERR_ARG, "PNG encoding: NULL argument");
    if (w < 1 || h < 1 || c < 1 || c > 4 || (size_t)w * (size_t)h > ((size_t)1 << 28))
        return mlb_fail(MLB_ERR_ARG, "PNG encoding: %dx%d with %d channels", w, h, c);
    *out = NULL;
    *n = 0;
    unsigned char* row = malloc((size_t)w * (size_t)c);
    if (!row) return mlb_fail(MLB_ERR_NOMEM, "PNG encoding: out of memory");
    png_err_box box = {{0}};
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &box, png_on_error, png_on_warning);
    png_infop info = png ? png_create_info_struct(png) : NULL;
    if (!info) {
        png_destroy_write_struct(png ? &png : NULL, NULL);
        free(row);
        return mlb_fail(MLB_ERR_NOMEM, "PNG encoding: cannot create the writer");
    }
    membuf b = {0};
    int ok = png_encode_rows(png, info, &b, data, w, h, c, srgb, row);
    png_destroy_write_struct(&png, &info);
    free(row);
    if (!ok) {
        free(b.p);
        return mlb_fail(b.oom ? MLB_ERR_NOMEM : MLB_ERR_FORMAT, "PNG encoding failed: %s", box.msg);
    }
    *out = b.p;
    *n = b.n;
    return MLB_OK;
}

// ---- glTF ----

#define GLB_MAGIC 0x46546C67u   // "glTF"
#define GLB_JSON 0x4E4F534Au    // "JSON"
#define GLB_BIN 0x004E4942u     // "BIN\0"
#define GL_FLOAT 5126
#define GL_UNSIGNED_INT 5125
#define GL_ARRAY_BUFFER 34962
#define GL_ELEMENT_ARRAY_BUFFER 34963

// Area-weighted vertex normals (zero-area stars get +y), or the given ones, normalised: out [V, 3].
static void unit_normals(const mlb_asset* a, float* out) {
    size_t V = (size_t)a->n_verts;
    if (a->normal) {
        memcpy(out, a->normal, sizeof(float) * 3 * V);
    } else {
        memset(out, 0, sizeof(float) * 3 * V);
        for (int f = 0; f < a->n_faces; f++) {
            const int32_t* t = a->faces + 3 * (size_t)f;
            const float *p0 = a->pos + 3 * (size_t)t[0], *p1 = a->pos + 3 * (size_t)t[1], *p2 = a->pos + 3 * (size_t)t[2];
            float e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]}, e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
            float n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
            for (int k = 0; k < 3; k++)
                for (int j = 0; j < 3; j++) out[3 * (size_t)t[k] + j] += n[j];
        }
    }
    for (size_t i = 0; i < V; i++) {
        float* n = out + 3 * i;
        double l = sqrt((double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2]);
        if (!(l > 1e-20)) { n[0] = 0; n[1] = 1; n[2] = 0; continue; }
        for (int j = 0; j < 3; j++) n[j] = (float)(n[j] / l);
    }
}

typedef struct { unsigned char* p; size_t n, cap; } bin_t;

// Appends `len` bytes (or zeros when src is NULL) at a 4-byte aligned offset; returns the offset or -1.
static long bin_append(bin_t* b, const void* src, size_t len) {
    size_t off = (b->n + 3) & ~(size_t)3;
    size_t end = off + len;
    if (end > b->cap) {
        size_t cap = b->cap ? b->cap : 65536;
        while (cap < end) cap *= 2;
        unsigned char* q = realloc(b->p, cap);
        if (!q) return -1;
        b->p = q;
        b->cap = cap;
    }
    memset(b->p + b->n, 0, off - b->n);
    if (src) memcpy(b->p + off, src, len);
    else memset(b->p + off, 0, len);
    b->n = end;
    return (long)off;
}

static cJSON* num_array(const double* x, int n) {
    cJSON* a = cJSON_CreateArray();
    for (int i = 0; a && i < n; i++) cJSON_AddItemToArray(a, cJSON_CreateNumber(x[i]));
    return a;
}

static void add_view(cJSON* views, long off, size_t len, int target) {
    cJSON* v = cJSON_CreateObject();
    cJSON_AddNumberToObject(v, "buffer", 0);
    cJSON_AddNumberToObject(v, "byteOffset", (double)off);
    cJSON_AddNumberToObject(v, "byteLength", (double)len);
    if (target) cJSON_AddNumberToObject(v, "target", target);
    cJSON_AddItemToArray(views, v);
}

static cJSON* add_accessor(cJSON* accs, int view, int ctype, int count, const char* type) {
    cJSON* a = cJSON_CreateObject();
    cJSON_AddNumberToObject(a, "bufferView", view);
    cJSON_AddNumberToObject(a, "componentType", ctype);
    cJSON_AddNumberToObject(a, "count", count);
    cJSON_AddStringToObject(a, "type", type);
    cJSON_AddItemToArray(accs, a);
    return a;
}

static cJSON* tex_ref(int index) {
    cJSON* t = cJSON_CreateObject();
    cJSON_AddNumberToObject(t, "index", index);
    return t;
}

static void put32(unsigned char* p, uint32_t v) {
    p[0] = (unsigned char)v; p[1] = (unsigned char)(v >> 8); p[2] = (unsigned char)(v >> 16); p[3] = (unsigned char)(v >> 24);
}

// The seven pieces of the BIN chunk, in order: positions, normals, uvs, indices, then the three
// PNG images (bufferViews 0..6; accessors 0..3 read the first four).
enum { GLB_PIECES = 7 };

// The vertex attributes as glTF reads them (unit normals; v flipped: glTF's uv origin is the top
// left) and the three images encoded as PNG: 0 base colour (kd, sRGB), 1 metallic-roughness
// (linear), 2 specular colour (ks, sRGB). nrm [V,3], uv [V,2], mr [S²,3] are the caller's scratch.
static mlb_status encode_pieces(const mlb_asset* a, float* nrm, float* uv, float* mr, unsigned char* png[3], size_t png_n[3]) {
    size_t V = (size_t)a->n_verts, S = (size_t)a->tex_size, S2 = S * S;
    unit_normals(a, nrm);
    for (size_t i = 0; i < V; i++) { uv[2 * i] = a->uv[2 * i]; uv[2 * i + 1] = 1.0f - a->uv[2 * i + 1]; }
    for (size_t i = 0; i < S2; i++) { mr[3 * i] = 1.0f; mr[3 * i + 1] = a->kr[i]; mr[3 * i + 2] = 0.0f; }
    mlb_status st;
    if ((st = mlb_png_encode_memory(a->kd, (int)S, (int)S, 3, 1, &png[0], &png_n[0])) != MLB_OK ||
        (st = mlb_png_encode_memory(mr, (int)S, (int)S, 3, 0, &png[1], &png_n[1])) != MLB_OK ||
        (st = mlb_png_encode_memory(a->ks, (int)S, (int)S, 3, 1, &png[2], &png_n[2])) != MLB_OK)
        return mlb_fail_context(st, "glTF textures");
    return MLB_OK;
}

// The pieces laid one after the other, each at a 4-byte boundary: off[i], len[i] of each.
static mlb_status pack_bin(bin_t* bin, const void* const src[GLB_PIECES], const size_t len[GLB_PIECES], long off[GLB_PIECES]) {
    for (int i = 0; i < GLB_PIECES; i++)
        if ((off[i] = bin_append(bin, src[i], len[i])) < 0) return mlb_fail(MLB_ERR_NOMEM, "glTF: out of memory");
    if (bin_append(bin, NULL, 0) < 0) return mlb_fail(MLB_ERR_NOMEM, "glTF: out of memory");   // pad to 4
    if (bin->n > 0xFFFFFFF0u - 4096) return mlb_fail(MLB_ERR_UNSUPPORTED, "glTF: %zu bytes of data (.glb holds < 4 GiB)", bin->n);
    return MLB_OK;
}

// The positions' bounding box (the POSITION accessor must carry min and max).
static void position_bounds(const mlb_asset* a, double lo[3], double hi[3]) {
    for (int j = 0; j < 3; j++) lo[j] = INFINITY, hi[j] = -INFINITY;
    for (size_t i = 0; i < (size_t)a->n_verts; i++)
        for (int j = 0; j < 3; j++) {
            double x = a->pos[3 * i + j];
            if (x < lo[j]) lo[j] = x;
            if (x > hi[j]) hi[j] = x;
        }
}

// asset, extensionsUsed, scene, scenes, nodes: one scene of one node that holds mesh 0.
static void json_scene(cJSON* root, const char* name) {
    cJSON* asset = cJSON_AddObjectToObject(root, "asset");
    cJSON_AddStringToObject(asset, "version", "2.0");
    cJSON_AddStringToObject(asset, "generator", "matlaber");
    cJSON* used = cJSON_AddArrayToObject(root, "extensionsUsed");
    cJSON_AddItemToArray(used, cJSON_CreateString("KHR_materials_specular"));
    cJSON_AddNumberToObject(root, "scene", 0);
    cJSON* scene = cJSON_CreateObject();
    cJSON_AddItemToArray(cJSON_AddArrayToObject(scene, "nodes"), cJSON_CreateNumber(0));
    cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "scenes"), scene);
    cJSON* node = cJSON_CreateObject();
    cJSON_AddNumberToObject(node, "mesh", 0);
    cJSON_AddStringToObject(node, "name", name);
    cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "nodes"), node);
}

// meshes: one triangle primitive over accessors 0..3 with material 0.
static void json_mesh(cJSON* root, const char* name) {
    cJSON* prim = cJSON_CreateObject();
    cJSON* attr = cJSON_AddObjectToObject(prim, "attributes");
    cJSON_AddNumberToObject(attr, "POSITION", 0);
    cJSON_AddNumberToObject(attr, "NORMAL", 1);
    cJSON_AddNumberToObject(attr, "TEXCOORD_0", 2);
    cJSON_AddNumberToObject(prim, "indices", 3);
    cJSON_AddNumberToObject(prim, "material", 0);
    cJSON_AddNumberToObject(prim, "mode", 4);
    cJSON* mesh = cJSON_CreateObject();
    cJSON_AddStringToObject(mesh, "name", name);
    cJSON_AddItemToArray(cJSON_AddArrayToObject(mesh, "primitives"), prim);
    cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "meshes"), mesh);
}

// materials: metallic-roughness from textures 0 and 1, KHR_materials_specular from texture 2.
static void json_material(cJSON* root, const char* name) {
    cJSON* mat = cJSON_CreateObject();
    cJSON_AddStringToObject(mat, "name", name);
    cJSON* pbr = cJSON_AddObjectToObject(mat, "pbrMetallicRoughness");
    cJSON_AddItemToObject(pbr, "baseColorTexture", tex_ref(0));
    cJSON_AddNumberToObject(pbr, "metallicFactor", 0);
    cJSON_AddNumberToObject(pbr, "roughnessFactor", 1);
    cJSON_AddItemToObject(pbr, "metallicRoughnessTexture", tex_ref(1));
    cJSON* spec = cJSON_AddObjectToObject(cJSON_AddObjectToObject(mat, "extensions"), "KHR_materials_specular");
    cJSON_AddNumberToObject(spec, "specularFactor", 1);
    const double scf[3] = {25, 25, 25};   // 1 / 0.04: F0 = 0.04 * 25 * ks = ks
    cJSON_AddItemToObject(spec, "specularColorFactor", num_array(scf, 3));
    cJSON_AddItemToObject(spec, "specularColorTexture", tex_ref(2));
    cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "materials"), mat);
}

// samplers, textures, images: texture i shows image i, the PNG in bufferView 4 + i.
static void json_textures(cJSON* root) {
    cJSON* samplers = cJSON_AddArrayToObject(root, "samplers");
    cJSON* smp = cJSON_CreateObject();
    cJSON_AddNumberToObject(smp, "magFilter", 9729);    // LINEAR
    cJSON_AddNumberToObject(smp, "minFilter", 9987);    // LINEAR_MIPMAP_LINEAR
    cJSON_AddNumberToObject(smp, "wrapS", 33071);       // CLAMP_TO_EDGE (an atlas does not tile)
    cJSON_AddNumberToObject(smp, "wrapT", 33071);
    cJSON_AddItemToArray(samplers, smp);
    cJSON* textures = cJSON_AddArrayToObject(root, "textures");
    cJSON* images = cJSON_AddArrayToObject(root, "images");
    static const char* image_names[3] = {"kd", "roughness", "ks"};
    for (int i = 0; i < 3; i++) {
        cJSON* t = cJSON_CreateObject();
        cJSON_AddNumberToObject(t, "sampler", 0);
        cJSON_AddNumberToObject(t, "source", i);
        cJSON_AddItemToArray(textures, t);
        cJSON* im = cJSON_CreateObject();
        cJSON_AddStringToObject(im, "name", image_names[i]);
        cJSON_AddNumberToObject(im, "bufferView", 4 + i);
        cJSON_AddStringToObject(im, "mimeType", "image/png");
        cJSON_AddItemToArray(images, im);
    }
}

// bufferViews, accessors, buffers: where each piece lies in the BIN chunk and how it is read.
static void json_buffers(cJSON* root, const mlb_asset* a, const long off[GLB_PIECES], const size_t len[GLB_PIECES], size_t bin_n) {
    int V = a->n_verts;
    double lo[3], hi[3];
    position_bounds(a, lo, hi);
    cJSON* views = cJSON_AddArrayToObject(root, "bufferViews");
    for (int i = 0; i < GLB_PIECES; i++) add_view(views, off[i], len[i], i < 3 ? GL_ARRAY_BUFFER : i == 3 ? GL_ELEMENT_ARRAY_BUFFER : 0);
    cJSON* accs = cJSON_AddArrayToObject(root, "accessors");
    cJSON* pa = add_accessor(accs, 0, GL_FLOAT, V, "VEC3");
    cJSON_AddItemToObject(pa, "min", num_array(lo, 3));
    cJSON_AddItemToObject(pa, "max", num_array(hi, 3));
    add_accessor(accs, 1, GL_FLOAT, V, "VEC3");
    add_accessor(accs, 2, GL_FLOAT, V, "VEC2");
    add_accessor(accs, 3, GL_UNSIGNED_INT, (int)(3 * (size_t)a->n_faces), "SCALAR");
    cJSON* buf = cJSON_CreateObject();
    cJSON_AddNumberToObject(buf, "byteLength", (double)bin_n);
    cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "buffers"), buf);
}

// The .glb container: a 12-byte header, the JSON chunk (padded with spaces to 4 bytes), the BIN chunk.
static mlb_status glb_container(const char* json, const bin_t* bin, unsigned char** data, size_t* n_out) {
    size_t jn = strlen(json), jpad = (jn + 3) & ~(size_t)3;
    size_t total = 12 + 8 + jpad + 8 + bin->n;
    if (total > 0xFFFFFFFFu) return mlb_fail(MLB_ERR_UNSUPPORTED, "glTF: %zu bytes (a .glb holds < 4 GiB)", total);
    unsigned char* out = malloc(total);
    if (!out) return mlb_fail(MLB_ERR_NOMEM, "glTF: out of memory for %zu bytes", total);
    put32(out, GLB_MAGIC);
    put32(out + 4, 2);
    put32(out + 8, (uint32_t)total);
    put32(out + 12, (uint32_t)jpad);
    put32(out + 16, GLB_JSON);
    memcpy(out + 20, json, jn);
    memset(out + 20 + jn, ' ', jpad - jn);
    put32(out + 20 + jpad, (uint32_t)bin->n);
    put32(out + 24 + jpad, GLB_BIN);
    memcpy(out + 28 + jpad, bin->p, bin->n);
    *data = out;
    *n_out = total;
    return MLB_OK;
}

mlb_status mlb_export_glb_memory(const mlb_asset* a, unsigned char** data, size_t* n_out) {
    if (!data || !n_out) return mlb_fail(MLB_ERR_ARG, "glTF: NULL output");
    *data = NULL;
    *n_out = 0;
    MLB_TRY(mlb_asset_check(a));
    size_t V = (size_t)a->n_verts, F = (size_t)a->n_faces, S2 = (size_t)a->tex_size * (size_t)a->tex_size;
    mlb_status st = MLB_OK;
    bin_t bin = {0};
    float *nrm = malloc(sizeof(float) * 3 * V), *uv = malloc(sizeof(float) * 2 * V), *mr = malloc(sizeof(float) * 3 * S2);
    unsigned char* png[3] = {NULL, NULL, NULL};
    size_t png_n[3] = {0, 0, 0};
    cJSON* root = NULL;
    char* json = NULL;
    if (!nrm || !uv || !mr) { st = mlb_fail(MLB_ERR_NOMEM, "glTF: out of memory for %zu vertices", V); goto done; }
    if ((st = encode_pieces(a, nrm, uv, mr, png, png_n)) != MLB_OK) goto done;
    long off[GLB_PIECES];
    const size_t len[GLB_PIECES] = {12 * V, 12 * V, 8 * V, 12 * F, png_n[0], png_n[1], png_n[2]};
    const void* const src[GLB_PIECES] = {a->pos, nrm, uv, a->faces, png[0], png[1], png[2]};
    if ((st = pack_bin(&bin, src, len, off)) != MLB_OK) goto done;

    const char* name = a->name ? a->name : "matlaber";
    root = cJSON_CreateObject();
    json_scene(root, name);
    json_mesh(root, name);
    json_material(root, name);
    json_textures(root);
    json_buffers(root, a, off, len, bin.n);
    json = cJSON_PrintUnformatted(root);
    if (!json) { st = mlb_fail(MLB_ERR_NOMEM, "glTF: out of memory for the JSON"); goto done; }
    st = glb_container(json, &bin, data, n_out);
done:
    free(json);
    cJSON_Delete(root);
    for (int i = 0; i < 3; i++) free(png[i]);
    free(bin.p);
    free(nrm);
    free(uv);
    free(mr);
    return st;
}

mlb_status mlb_export_glb(const char* path, const mlb_asset* a) {
    if (!path) return mlb_fail(MLB_ERR_ARG, "glTF: NULL path");
    unsigned char* data = NULL;
    size_t n = 0;
    mlb_status st = mlb_export_glb_memory(a, &data, &n);
    if (st != MLB_OK) return mlb_fail_context(st, "%s", path);
    st = mlb_write_file_atomic(path, data, n);
    free(data);
    return st;
}
