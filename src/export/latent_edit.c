// A latent-mode asset's codes edited and decoded on the CPU (include/matlaber/latent_edit.h).
#include "matlaber/latent_edit.h"
#include <cjson/cJSON.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/brdf_ae.h"
#include "matlaber/export.h"
#include "matlaber/fileio.h"
#include "matlaber/gltf.h"
#include "matlaber/latent_export.h"
#include "matlaber/mesh.h"

#define MAX_DIM 1024   // a layer's width at most (the prior's are tens)

void mlb_latent_asset_free(mlb_latent_asset* a) {
    free(a->params);
    free(a->z);
    memset(a, 0, sizeof *a);
}

// n finite numbers of the array key of o into out
static mlb_status numbers(const char* file, const cJSON* o, const char* key, int l, float* out, int n) {
    const cJSON* v = cJSON_GetObjectItemCaseSensitive(o, key);
    if (!cJSON_IsArray(v) || cJSON_GetArraySize(v) != n)
        return mlb_fail(MLB_ERR_FORMAT, "%s: layers[%d].%s: expected an array of %d numbers", file, l, key, n);
    int i = 0;
    for (const cJSON* x = v->child; x; x = x->next, i++) {
        if (!cJSON_IsNumber(x) || !isfinite(x->valuedouble) || fabs(x->valuedouble) > 1e30)
            return mlb_fail(MLB_ERR_FORMAT, "%s: layers[%d].%s[%d]: not a finite number", file, l, key, i);
        out[i] = (float)x->valuedouble;
    }
    return MLB_OK;
}

static int int_of(const cJSON* o, const char* key, int lo, int hi, int* out) {
    const cJSON* v = cJSON_GetObjectItemCaseSensitive(o, key);
    if (!cJSON_IsNumber(v) || v->valuedouble != floor(v->valuedouble) || v->valuedouble < lo || v->valuedouble > hi) return 1;
    *out = (int)v->valuedouble;
    return 0;
}

static mlb_status parse_decoder(const char* file, const cJSON* root, mlb_latent_asset* a) {
    const cJSON* fmt = cJSON_GetObjectItemCaseSensitive(root, "format");
    if (!cJSON_IsString(fmt) || strcmp(fmt->valuestring, "matlaber-latent-decoder-1"))
        return mlb_fail(MLB_ERR_FORMAT, "%s: not a matlaber-latent-decoder-1 file", file);
    const cJSON* ha = cJSON_GetObjectItemCaseSensitive(root, "hidden_activation");
    const cJSON* oa = cJSON_GetObjectItemCaseSensitive(root, "output_activation");
    mlb_activation hidden, out;
    if (!cJSON_IsString(ha) || mlb_activation_parse(ha->valuestring, &hidden))
        return mlb_fail(MLB_ERR_FORMAT, "%s: hidden_activation: not an activation name", file);
    if (!cJSON_IsString(oa) || mlb_activation_parse(oa->valuestring, &out) || out != MLB_ACT_SIGMOID)
        return mlb_fail(MLB_ERR_FORMAT, "%s: output_activation: expected sigmoid", file);
    const cJSON* layers = cJSON_GetObjectItemCaseSensitive(root, "layers");
    int L = cJSON_IsArray(layers) ? cJSON_GetArraySize(layers) : 0;
    if (L < 1 || L > MLB_MLP_MAX_LAYERS) return mlb_fail(MLB_ERR_FORMAT, "%s: layers: expected 1..%d layers", file, MLB_MLP_MAX_LAYERS);
    int dims[MLB_MLP_MAX_LAYERS + 1];
    for (int l = 0; l < L; l++) {
        const cJSON* ly = cJSON_GetArrayItem(layers, l);
        int in, o;
        if (int_of(ly, "in", 1, MAX_DIM, &in) || int_of(ly, "out", 1, MAX_DIM, &o))
            return mlb_fail(MLB_ERR_FORMAT, "%s: layers[%d]: in and out must be integers 1..%d", file, l, MAX_DIM);
        if (l > 0 && in != dims[l]) return mlb_fail(MLB_ERR_FORMAT, "%s: layers[%d].in %d, but layers[%d].out is %d", file, l, in, l - 1, dims[l]);
        dims[l] = in;
        dims[l + 1] = o;
    }
    if (dims[0] != MLB_LATENT_DIM || dims[L] != 7)
        return mlb_fail(MLB_ERR_FORMAT, "%s: the decoder maps %d -> %d, expected %d -> 7", file, dims[0], dims[L], MLB_LATENT_DIM);
    a->params = malloc(sizeof(float) * mlp_param_count(L, dims, 1));
    if (!a->params) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", file);
    MLB_TRY(mlp_init(&a->dec, L, dims, 1, hidden, out, a->params));
    for (int l = 0; l < L; l++) {
        const cJSON* ly = cJSON_GetArrayItem(layers, l);
        MLB_TRY(numbers(file, ly, "weight", l, a->dec.weight[l], dims[l] * dims[l + 1]));
        MLB_TRY(numbers(file, ly, "bias", l, a->dec.bias[l], dims[l + 1]));
    }
    const cJSON* lat = cJSON_GetObjectItemCaseSensitive(root, "latent");
    if (int_of(lat, "size", 1, 16384, &a->size)) return mlb_fail(MLB_ERR_FORMAT, "%s: latent.size: expected an integer 1..16384", file);
    return MLB_OK;
}

mlb_status mlb_latent_asset_read(const char* glb_path, mlb_latent_asset* a) {
    memset(a, 0, sizeof *a);
    char json[4200], bin[4200];
    if (mlb_latent_export_paths(glb_path, json, bin, sizeof json))
        return mlb_fail(MLB_ERR_ARG, "%s: not a .glb name", glb_path ? glb_path : "(null)");
    char* text = NULL;
    size_t n = 0;
    MLB_TRY(mlb_read_file(json, &text, &n, (size_t)64 << 20));
    cJSON* root = cJSON_ParseWithLength(text, n);
    free(text);
    mlb_status s = root ? parse_decoder(json, root, a) : mlb_fail(MLB_ERR_FORMAT, "%s: not JSON", json);
    cJSON_Delete(root);
    char* raw = NULL;
    const size_t N = (size_t)a->size * (size_t)a->size;
    if (!s) s = mlb_read_file(bin, &raw, &n, 16 * N + 1);
    if (!s && n != 16 * N) s = mlb_fail(MLB_ERR_FORMAT, "%s: %zu bytes, expected %zu (%d² codes of 4 float32)", bin, n, 16 * N, a->size);
    if (!s && !(a->z = malloc(16 * N))) s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", bin);
    for (size_t i = 0; !s && i < 4 * N; i++) {   // little-endian whatever the host
        const unsigned char* b = (const unsigned char*)raw + 4 * i;
        uint32_t u = (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 | (uint32_t)b[3] << 24;
        memcpy(a->z + i, &u, 4);
        if (!isfinite(a->z[i])) s = mlb_fail(MLB_ERR_FORMAT, "%s: code %zu channel %zu is not finite", bin, i / 4, i % 4);
    }
    free(raw);
    if (s) mlb_latent_asset_free(a);
    return s;
}

int mlb_latent_edit_in_region(const mlb_latent_edit* e, const float* z) {
    if (e->radius < 0) return 1;
    float d2 = 0;
    for (int c = 0; c < 4; c++) d2 += (z[c] - e->pick[c]) * (z[c] - e->pick[c]);
    return d2 <= e->radius * e->radius;
}

size_t mlb_latent_edit_apply(const mlb_latent_edit* e, float* z, size_t n) {
    size_t in = 0;
    for (size_t i = 0; i < n; i++) {
        float* v = z + 4 * i;
        if (!mlb_latent_edit_in_region(e, v)) continue;
        for (int c = 0; c < 4; c++) v[c] = (1 - e->t) * v[c] + e->t * e->target[c] + e->offset[c];
        in++;
    }
    return in;
}

void mlb_latent_mean(const float* z, size_t n, float mean[4]) {
    double s[4] = {0, 0, 0, 0};
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < 4; c++) s[c] += z[4 * i + c];
    for (int c = 0; c < 4; c++) mean[c] = n ? (float)(s[c] / (double)n) : 0.0f;
}

mlb_status mlb_latent_decode(const mlb_latent_asset* a, const float* z, size_t n, float* kd, float* ks, float* kr) {
    const int chunk = 4096;
    mlb_mlp_cache cache;
    MLB_TRY(mlp_cache_alloc(&cache, &a->dec, n < (size_t)chunk ? (int)(n ? n : 1) : chunk));
    for (size_t start = 0; start < n; start += (size_t)chunk) {
        int B = (int)(n - start < (size_t)chunk ? n - start : (size_t)chunk);
        const float* s = mlp_forward(&a->dec, &cache, z + 4 * start, B);
        for (int i = 0; i < B; i++) {
            float k[7];   // the prior's ranges, as the material network maps its decoder's output
            for (int c = 0; c < 7; c++)
                k[c] = (float)(mlb_brdf_range_lo[c] + (mlb_brdf_range_hi[c] - mlb_brdf_range_lo[c]) * s[7 * i + c]);
            size_t t = start + (size_t)i;
            memcpy(kd + 3 * t, k, sizeof(float) * 3);
            memcpy(ks + 3 * t, k + 3, sizeof(float) * 3);
            kr[t] = k[6];
        }
    }
    mlp_cache_free(&cache);
    return MLB_OK;
}

mlb_status mlb_latent_edit_export(const char* src_glb, const mlb_latent_edit* e, const char* out_glb, const char* out_obj,
                                  size_t* in_region) {
    mlb_latent_asset a;
    MLB_TRY(mlb_latent_asset_read(src_glb, &a));
    mlb_mesh m;
    mlb_status s = mlb_gltf_load(src_glb, &m, NULL, NULL);
    if (!s && !m.uv) s = mlb_fail(MLB_ERR_FORMAT, "%s: no TEXCOORD_0: not an exported asset", src_glb);
    const size_t N = (size_t)a.size * (size_t)a.size;
    float* maps = s ? NULL : malloc(sizeof(float) * 7 * N);
    if (!s && !maps) s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", src_glb);
    if (!s) {
        size_t in = mlb_latent_edit_apply(e, a.z, N);
        if (in_region) *in_region = in;
        s = mlb_latent_decode(&a, a.z, N, maps, maps + 3 * N, maps + 6 * N);
    }
    mlb_asset out = {0};
    if (!s) {
        out = (mlb_asset){m.n_verts, m.n_faces, m.pos, m.normal, m.uv, m.faces, a.size, maps, maps + 3 * N, maps + 6 * N, "matlaber"};
        s = mlb_export_glb(out_glb, &out);
    }
    if (!s) s = mlb_latent_export(out_glb, &a.dec, a.z, a.size);
    if (!s && out_obj) s = mlb_export_obj(out_obj, &out);
    free(maps);
    mlb_mesh_free(&m);
    mlb_latent_asset_free(&a);
    return s;
}
