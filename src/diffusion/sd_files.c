// Locating a Stable Diffusion component's files (sd_files.h), shared by the component loaders.
#include <errno.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <cjson/cJSON.h>
#include "matlaber/fileio.h"
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

const cJSON* mlb_json_find(const cJSON* node, const char* key) {
    for (const cJSON* c = node ? node->child : NULL; c; c = c->next) {
        if (c->string && !strcmp(c->string, key)) return c;
        const cJSON* r = mlb_json_find(c, key);
        if (r) return r;
    }
    return NULL;
}
