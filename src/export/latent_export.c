// The latent codes and the prior's decoder beside a .glb (include/matlaber/latent_export.h).
#include "matlaber/latent_export.h"
#include <cjson/cJSON.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "matlaber/brdf_ae.h"
#include "matlaber/fileio.h"

int mlb_latent_export_paths(const char* glb_path, char* json, char* bin, size_t cap) {
    size_t n = glb_path ? strlen(glb_path) : 0;
    if (n < 4 || strcmp(glb_path + n - 4, ".glb") != 0) return 1;
    int stem = (int)(n - 4);
    if (snprintf(json, cap, "%.*s.decoder.json", stem, glb_path) >= (int)cap) return 1;
    if (snprintf(bin, cap, "%.*s.latent.bin", stem, glb_path) >= (int)cap) return 1;
    return 0;
}

void mlb_latent_export_remove(const char* glb_path) {
    char json[4200], bin[4200];
    if (mlb_latent_export_paths(glb_path, json, bin, sizeof json)) return;
    unlink(json);
    unlink(bin);
}

static cJSON* floats(const float* v, int n) {
    cJSON* a = cJSON_CreateArray();
    // float -> double is exact, and cJSON prints a double that reads back to itself
    for (int i = 0; a && i < n; i++) cJSON_AddItemToArray(a, cJSON_CreateNumber((double)v[i]));
    return a;
}

static cJSON* doubles(const double* v, int n) {
    cJSON* a = cJSON_CreateArray();
    for (int i = 0; a && i < n; i++) cJSON_AddItemToArray(a, cJSON_CreateNumber(v[i]));
    return a;
}

static mlb_status write_bin(const char* path, const float* z, size_t count) {
    unsigned char* buf = malloc(4 * (count ? count : 1));
    if (!buf) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path);
    for (size_t i = 0; i < count; i++) {   // little-endian whatever the host
        uint32_t u;
        memcpy(&u, z + i, 4);
        for (int b = 0; b < 4; b++) buf[4 * i + b] = (unsigned char)(u >> (8 * b));
    }
    mlb_status st = mlb_write_file_atomic(path, buf, 4 * count);
    free(buf);
    return st;
}

mlb_status mlb_latent_export(const char* glb_path, const mlb_mlp* dec, const float* z, int size) {
    char json[4200], bin[4200];
    if (!dec || !z || mlb_latent_export_paths(glb_path, json, bin, sizeof json))
        return mlb_fail(MLB_ERR_ARG, "latent export: NULL argument, or %s does not end in .glb", glb_path ? glb_path : "(null)");
    if (size < 1 || size > 16384) return mlb_fail(MLB_ERR_ARG, "latent export: texture size %d", size);
    if (dec->n_layers < 1 || dec->dims[0] != MLB_LATENT_DIM || dec->dims[dec->n_layers] != 7 || !dec->has_bias ||
        dec->out_act != MLB_ACT_SIGMOID)
        return mlb_fail(MLB_ERR_ARG, "latent export: the decoder is not a 4 -> ... -> 7 MLP with biases and a sigmoid output");
    const size_t N = (size_t)size * size;
    float lo[4], hi[4];
    for (int c = 0; c < 4; c++) { lo[c] = INFINITY; hi[c] = -INFINITY; }
    for (size_t t = 0; t < N; t++)
        for (int c = 0; c < 4; c++) {
            float v = z[4 * t + c];
            if (!isfinite(v)) return mlb_fail(MLB_ERR_NUMERIC, "latent export: code %zu channel %d is not finite", t, c);
            lo[c] = v < lo[c] ? v : lo[c];
            hi[c] = v > hi[c] ? v : hi[c];
        }
    cJSON* root = cJSON_CreateObject();
    cJSON_AddStringToObject(root, "format", "matlaber-latent-decoder-1");
    cJSON_AddNumberToObject(root, "latent_dim", MLB_LATENT_DIM);
    cJSON_AddStringToObject(root, "hidden_activation", mlb_activation_name(dec->hidden_act));
    cJSON_AddStringToObject(root, "output_activation", mlb_activation_name(dec->out_act));
    cJSON_AddItemToObject(root, "range_lo", doubles(mlb_brdf_range_lo, 7));
    cJSON_AddItemToObject(root, "range_hi", doubles(mlb_brdf_range_hi, 7));
    cJSON* layers = cJSON_AddArrayToObject(root, "layers");
    for (int l = 0; l < dec->n_layers; l++) {
        cJSON* L = cJSON_CreateObject();
        int in = dec->dims[l], out = dec->dims[l + 1];
        cJSON_AddNumberToObject(L, "in", in);
        cJSON_AddNumberToObject(L, "out", out);
        cJSON_AddItemToObject(L, "weight", floats(dec->weight[l], in * out));
        cJSON_AddItemToObject(L, "bias", floats(dec->bias[l], out));
        cJSON_AddItemToArray(layers, L);
    }
    cJSON* lat = cJSON_AddObjectToObject(root, "latent");
    const char* base = strrchr(bin, '/');
    cJSON_AddStringToObject(lat, "file", base ? base + 1 : bin);
    cJSON_AddNumberToObject(lat, "size", size);
    cJSON_AddNumberToObject(lat, "channels", 4);
    cJSON_AddStringToObject(lat, "type", "float32le");
    cJSON_AddItemToObject(lat, "min", floats(lo, 4));
    cJSON_AddItemToObject(lat, "max", floats(hi, 4));
    char* text = cJSON_PrintUnformatted(root);
    cJSON_Delete(root);
    if (!text) return mlb_fail(MLB_ERR_NOMEM, "latent export: out of memory");
    mlb_status st = write_bin(bin, z, 4 * N);
    if (st == MLB_OK) st = mlb_write_file_atomic(json, text, strlen(text));
    if (st != MLB_OK) unlink(bin);
    free(text);
    return st;
}
