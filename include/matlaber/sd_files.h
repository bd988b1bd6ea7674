// Where a Stable Diffusion component's weights are: the path the user gave may be a diffusers model
// folder (with `subdir`/ inside), the component's own folder, or a single .safetensors file.
// Pickle checkpoints (.ckpt .bin .pt .pth) execute code when PyTorch loads them: they are refused
// with a message saying how to convert them.
#ifndef MATLABER_SD_FILES_H
#define MATLABER_SD_FILES_H
#include <stddef.h>
#include "matlaber/error.h"

int mlb_is_pickle_path(const char* path);
// MLB_ERR_UNSUPPORTED naming `what` ("VAE", "text encoder", ...) and the file.
mlb_status mlb_pickle_refusal(const char* what, const char* path);
// Fills weights (the .safetensors to open: `base`.safetensors or `base`.fp16.safetensors in the
// component folder, or `path` itself) and config (the folder's config.json, or "" when none).
// Errors name `what` and `path`: missing path, no weights in the folder, a pickle checkpoint.
mlb_status mlb_sd_component_files(const char* what, const char* path, const char* subdir, const char* base,
                                  char* weights, char* config, size_t cap);

// The config.json beside a single weights file: <name>.config.json for <name>.safetensors, else
// config.json in its folder; "" when neither exists, when `weights` is not a file (e.g. "<memory>")
// or is too long for out (cap - 32 bytes or more; cap at most 4096).
void mlb_sd_config_beside(const char* weights, char* out, size_t cap);

// What every component loader does with the path the user gave: an empty path or one over 1000
// bytes is MLB_ERR_ARG naming `what`; then mlb_sd_component_files and the weights opened.
#define MLB_SD_PATH_CAP 1100
struct mlb_safetensors;
typedef struct {
    struct mlb_safetensors* st;   // the weights, open (close with mlb_st_close)
    const char* config;           // the caller's own config (own_config), else the folder's, else NULL
    char buf[MLB_SD_PATH_CAP];    // where the folder's config path is kept
} mlb_sd_component;
mlb_status mlb_sd_component_open(const char* what, const char* path, const char* subdir, const char* base,
                                 const char* own_config, mlb_sd_component* c);

// *root = the JSON in the file at path (at most max_bytes): MLB_ERR_FORMAT "<path>: not valid
// JSON" when it does not parse; the file's own errors otherwise. Free with cJSON_Delete.
struct cJSON;
mlb_status mlb_json_read_file(const char* path, size_t max_bytes, struct cJSON** root);

// A single file's ldm_config metadata (the inference yaml as JSON) parsed; NULL when the file has
// none or it does not parse (*bad = 1 then, when bad is given). Free with cJSON_Delete.
struct cJSON* mlb_sd_ldm_config(const struct mlb_safetensors* st, int* bad);

// The first member named `key` in a JSON tree, depth first (diffusers configs and the ldm_config
// metadata of single files nest the fields the loaders need); NULL when absent.
const struct cJSON* mlb_json_find(const struct cJSON* node, const char* key);

#endif
