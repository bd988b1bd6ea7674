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

// The first member named `key` in a JSON tree, depth first (diffusers configs and the ldm_config
// metadata of single files nest the fields the loaders need); NULL when absent.
struct cJSON;
const struct cJSON* mlb_json_find(const struct cJSON* node, const char* key);

#endif
