// Locating a Stable Diffusion component's files (sd_files.h), shared by the component loaders.
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <cjson/cJSON.h>
#include "matlaber/fileio.h"
#include "matlaber/safetensors.h"
#include "matlaber/sd_files.h"

int mlb_is_pickle_path(const char* p) {
    return mlb_ends_with(p, ".ckpt") || mlb_ends_with(p, ".bin") || mlb_ends_with(p, ".pt") || mlb_ends_with(p, ".pth");
}

mlb_status mlb_pickle_refusal(const char* what, const char* p) {
    return mlb_fail(MLB_ERR_UNSUPPORTED, "%s %s: pickle checkpoints run code when loaded and are not read; convert "
                    "it to .safetensors (e.g. safetensors.torch.save_file of its state dict) and pass that", what, p);
}

mlb_status mlb_sd_component_files(const char* what, const char* path, const char* subdir, const char* base,
                                  char* weights, char* config, size_t cap) {
    struct stat sb;
    if (stat(path, &sb) != 0)
        return mlb_fail(errno == ENOENT ? MLB_ERR_NOT_FOUND : MLB_ERR_IO, "%s %s: %s", what, path, strerror(errno));
    config[0] = 0;
    if (!S_ISDIR(sb.st_mode)) {
        if (mlb_is_pickle_path(path)) return mlb_pickle_refusal(what, path);
        snprintf(weights, cap, "%s", path);
        return MLB_OK;
    }
    char dir[4096];
    snprintf(dir, sizeof dir, "%s/%s", path, subdir);
    if (!mlb_is_dir(dir)) snprintf(dir, sizeof dir, "%s", path);
    static const char* suffixes[] = {".safetensors", ".fp16.safetensors"};
    for (int i = 0; i < 2; i++) {
        snprintf(weights, cap, "%s/%s%s", dir, base, suffixes[i]);
        if (mlb_is_file(weights)) {
            snprintf(config, cap, "%s/config.json", dir);
            if (!mlb_is_file(config)) config[0] = 0;
            return MLB_OK;
        }
    }
    snprintf(weights, cap, "%s/%s.bin", dir, strcmp(base, "model") == 0 ? "pytorch_model" : base);
    if (mlb_is_file(weights)) return mlb_pickle_refusal(what, weights);
    return mlb_fail(MLB_ERR_NOT_FOUND, "%s %s: no %s.safetensors in it or in %s/ (expected a diffusers %s folder or a "
                    "diffusers model folder)", what, path, base, subdir, subdir);
}

void mlb_sd_config_beside(const char* weights, char* out, size_t cap) {
    out[0] = 0;
    if (!weights || cap > 4096 || strlen(weights) >= cap - 32 || !mlb_is_file(weights)) return;
    char p[4096];
    if (mlb_ends_with(weights, ".safetensors")) {
        snprintf(p, sizeof p, "%.*s.config.json", (int)(strlen(weights) - strlen(".safetensors")), weights);
        if (mlb_is_file(p)) { snprintf(out, cap, "%s", p); return; }
    }
    const char* slash = strrchr(weights, '/');
    if (slash) snprintf(p, sizeof p, "%.*s/config.json", (int)(slash - weights), weights);
    else snprintf(p, sizeof p, "config.json");
    if (mlb_is_file(p)) snprintf(out, cap, "%s", p);
}

mlb_status mlb_sd_component_open(const char* what, const char* path, const char* subdir, const char* base,
                                 const char* own_config, mlb_sd_component* c) {
    c->st = NULL;
    c->config = NULL;
    if (!path || !*path) return mlb_fail(MLB_ERR_ARG, "%s: empty path", what);
    if (strlen(path) > 1000) return mlb_fail(MLB_ERR_ARG, "%s: path longer than 1000 bytes", what);
    char weights[MLB_SD_PATH_CAP];
    MLB_TRY(mlb_sd_component_files(what, path, subdir, base, weights, c->buf, sizeof weights));
    c->config = own_config ? own_config : c->buf[0] ? c->buf : NULL;
    return mlb_st_open(&c->st, weights);
}

mlb_status mlb_json_read_file(const char* path, size_t max_bytes, cJSON** root) {
    char* text = NULL;
    size_t n = 0;
    *root = NULL;
    MLB_TRY(mlb_read_file(path, &text, &n, max_bytes));
    *root = cJSON_ParseWithLength(text, n);
    free(text);
    return *root ? MLB_OK : mlb_fail(MLB_ERR_FORMAT, "%s: not valid JSON", path);
}

cJSON* mlb_sd_ldm_config(const mlb_safetensors* st, int* bad) {
    const char* meta = mlb_st_metadata(st, "ldm_config");
    cJSON* root = meta ? cJSON_Parse(meta) : NULL;
    if (bad) *bad = meta && !root;
    return root;
}

const cJSON* mlb_json_find(const cJSON* node, const char* key) {
    for (const cJSON* c = node ? node->child : NULL; c; c = c->next) {
        if (c->string && !strcmp(c->string, key)) return c;
        const cJSON* r = mlb_json_find(c, key);
        if (r) return r;
    }
    return NULL;
}
