// Random-weight Stable Diffusion UNets written in the real layouts (docs/unet.md): tiny
// configurations for tests that need no downloaded data, and the full SD 1.5 size for benchmarks.
//
// The tensor list is the one mlb_unet_from_st reads (the same walk, the same shapes) under the
// diffusers names; the original single-file names (`model.diffusion_model.*`) come from the same
// diffusers -> ldm translation the loader applies. Diffusers files get a config.json
// (attention_head_dim, norm_num_groups, norm_eps, ...); single files get the `ldm_config`
// metadata (unet_config.params.num_heads or num_head_channels) the loader reads for the heads.
//
// Values (Philox, stream = the tensor's index in the list): conv/linear weights N(0, gain^2 /
// fan_in), biases N(0, 0.05^2), norm weights 1 + N(0, 0.05^2), norm biases N(0, 0.05^2) — as
// mlb_vae_init_random. The same seed gives the same numbers in both layouts and in every dtype
// before rounding.
#ifndef MATLABER_UNET_RANDOM_H
#define MATLABER_UNET_RANDOM_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/error.h"
#include "matlaber/safetensors.h"
#include "matlaber/unet.h"

// The sd_reference fixture's tiny UNets: block_out (32, 32, 64, 64), 2 layers, attention at levels
// 0-2, groups 32, time embedding 128; sd2 = 0: 8 heads, context 32, conv projections;
// sd2 = 1: head width 8 (heads 4, 4, 8; mid 8), context 48, linear projections.
mlb_unet_config mlb_unet_tiny_config(int sd2);
// SD 1.5: block_out (320, 640, 1280, 1280), 2 layers, attention at 0-2, 8 heads, context 768,
// time embedding 1280, conv projections (859.5 M parameters).
mlb_unet_config mlb_unet_sd15_config(void);
// MLB_OK, or MLB_ERR_ARG naming the field that cannot be written or loaded back.
mlb_status mlb_unet_config_check(const mlb_unet_config* c);

typedef struct {
    char name[160];      // diffusers name, e.g. "down_blocks.0.attentions.1.proj_in.weight"
    int ndim;
    int64_t shape[4];
    size_t n;            // elements
} mlb_unet_tensor_spec;

// Every tensor of the configuration in the loader's order. out may be NULL (count only); at most
// cap are written; *count receives the total. MLB_ERR_ARG for a bad configuration.
mlb_status mlb_unet_tensor_specs(const mlb_unet_config* c, mlb_unet_tensor_spec* out, size_t cap, size_t* count);
// The single-file (ldm) name of a diffusers name: "model.diffusion_model.input_blocks.1.0.in_layers.0.weight".
void mlb_unet_ldm_name(const mlb_unet_config* c, const char* diffusers_name, char* out, size_t cap);

typedef struct {
    mlb_unet_layout layout;        // MLB_UNET_LAYOUT_DIFFUSERS or MLB_UNET_LAYOUT_LDM
    mlb_dtype dtype;               // MLB_DT_F32, MLB_DT_F16 or MLB_DT_BF16
    uint64_t seed;
    float gain;                    // 1 (weights N(0, 1 / fan_in))
    const char* config_json_path;  // diffusers layout: the config.json to write beside (NULL: none)
} mlb_unet_random_options;

mlb_unet_random_options mlb_unet_random_default_options(void);   // diffusers, F32, seed 0, gain 1, NULL
// A diffusers config.json for `c` (what mlb_unet_load reads back: heads, groups, eps, ...).
mlb_status mlb_unet_write_config_json(const mlb_unet_config* c, const char* path);
// Writes the random weights of `c` to `path` with mlb_st_write.
mlb_status mlb_unet_write_random(const mlb_unet_config* c, const mlb_unet_random_options* opt, const char* path);
// The random value tensor i of the list holds (what the written file holds before dtype rounding),
// into out[0 .. spec->n - 1].
void mlb_unet_random_values(const mlb_unet_tensor_spec* spec, size_t i, uint64_t seed, float gain, float* out);

#endif
