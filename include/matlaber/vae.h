// The Stable Diffusion VAE (AutoencoderKL; reference.md §6, docs/vae.md): the encoder from an
// image to the latent distribution (mean, logvar), its backward to the image (score distillation
// differentiates through it, reference.md §7) and to the weights, and the decoder from a latent to
// an image with its backward (training a VAE: docs/vae.md "Training backward").
//
//   encoder: conv_in -> n_levels x (layers_per_block ResNet blocks [+ downsample: pad (0,1,0,1),
//            stride-2 3x3 conv]) -> mid (ResNet, single-head self-attention, ResNet) ->
//            GroupNorm + SiLU -> conv_out (2z channels) -> quant_conv (1x1) -> [mean | logvar],
//            logvar clamped to [-30, 20]
//   decoder: post_quant_conv (1x1) -> conv_in -> mid -> n_levels x (layers_per_block + 1 ResNet
//            blocks [+ nearest 2x upsample + 3x3 conv]) -> GroupNorm + SiLU -> conv_out
//   ResNet block: x + conv2(silu(gn2(conv1(silu(gn1(x)))))), x through a 1x1 conv when the
//   channel count changes. GroupNorm: norm_groups groups, eps 1e-6.
//
// SCALING. Everything here is the RAW VAE: mlb_vae_encode returns the raw mean (the UNet's latent
// is mean * scaling_factor, 0.18215 for SD 1.x/2.x), and mlb_vae_decode takes the raw z (the
// caller passes unet_latent / scaling_factor). Images are NCHW in [-1, 1] (a [0, 1] render enters
// as 2x - 1; the caller does that map and its factor 2 in the gradient).
//
// Loading reads diffusers VAE folders (config.json + diffusion_pytorch_model.safetensors),
// diffusers model folders (vae/ inside), single-file checkpoints with `first_stage_model.*` names
// (CompVis/Stability layout) and stand-alone ldm VAE files (`encoder.down.0...` names); tensors in
// F32, F16 or BF16 are converted to float32 once. The model lives in one float buffer; a double
// copy (mlb_vae_to_f64) runs the same code in double for finite-difference tests.
#ifndef MATLABER_VAE_H
#define MATLABER_VAE_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/device.h"
#include "matlaber/error.h"
#include "matlaber/safetensors.h"

#define MLB_VAE_MAX_LEVELS 6
#define MLB_VAE_MAX_LAYERS 4   // ResNet blocks per encoder level (decoder levels hold one more)

typedef struct {
    int in_channels;                      // image channels into the encoder (3)
    int out_channels;                     // image channels out of the decoder (3)
    int latent_channels;                  // z (4); the encoder emits 2z channels: mean | logvar
    int n_levels;                         // len(block_out_channels) (4); n_levels - 1 down/upsamplings
    int block_out[MLB_VAE_MAX_LEVELS];    // channels per level, encoder order (SD: 128, 256, 512, 512)
    int layers_per_block;                 // ResNet blocks per encoder level (2)
    int norm_groups;                      // GroupNorm groups (32)
    float norm_eps;                       // GroupNorm eps (1e-6)
    float scaling_factor;                 // latent scale (0.18215), informational: never applied here
    int mid_attention;                    // 1: the mid blocks hold self-attention (every SD VAE)
} mlb_vae_config;

// The SD 1.x / 2.x VAE: 3 -> (128, 256, 512, 512) -> 4, 2 layers, 32 groups, eps 1e-6, 0.18215.
mlb_vae_config mlb_vae_sd_config(void);
// MLB_OK, or MLB_ERR_ARG naming the bad field ("VAE config: block_out[1] = 48 is not a multiple
// of the 32 groups").
mlb_status mlb_vae_config_check(const mlb_vae_config* cfg);
// Latent height/width for an image height/width: each of the n_levels - 1 downsamplings maps
// h -> floor(h / 2). 0 when the image is smaller than 2^(n_levels - 1).
int mlb_vae_latent_size(const mlb_vae_config* cfg, int image_size);

typedef enum {
    MLB_VAE_LAYOUT_DIFFUSERS = 1,   // encoder.down_blocks.0.resnets.0.norm1.weight, ...; attention [C, C]
    MLB_VAE_LAYOUT_LDM,             // encoder.down.0.block.0.norm1.weight, ...; attention [C, C, 1, 1]
} mlb_vae_layout;

typedef struct {
    const char* config_path;   // a diffusers config.json to use; NULL: look beside the weights
    int norm_groups;           // 0: config.json's norm_num_groups, else 32
} mlb_vae_options;

// The model types, in float (mlb_vae) and double (mlb_vae_f64), and the functions over them.
#define MLB_REAL float
#define MLB_FN(name) name
#include "matlaber/vae_api.inc"
#undef MLB_REAL
#undef MLB_FN
#define MLB_REAL double
#define MLB_FN(name) name##_f64
#include "matlaber/vae_api.inc"
#undef MLB_REAL
#undef MLB_FN

// From now on mlb_vae_encode / _encode_backward / _decode / _decode_backward with be NULL (host
// buffers) run on device d with GEMM operands at prec: the weights are copied there once (v->mirror,
// its table v->mirror_ops); the caches stay there; images, latents and gradients cross per call.
// MLB_DEVICE_CPU undoes it; with MLB_GEMM_BF16 the CPU's conv and linear GEMMs then take bf16
// operands (backend.h), any other prec is the CPU's fp32. Float models only (no device has a
// double table).
mlb_status mlb_vae_use_device(mlb_vae* v, mlb_device d, mlb_gemm_precision prec);

// ---- loading (float) ------------------------------------------------------------------------------
// `path`: a diffusers vae/ folder, a diffusers model folder (vae/ inside), a single-file checkpoint
// (.safetensors with first_stage_model.* tensors) or a VAE .safetensors file in either layout (a
// diffusers one takes its config from opt->config_path, else <name>.config.json beside
// <name>.safetensors, else config.json in its folder; none is needed: the sizes come from the
// tensor shapes and the groups default to 32). Pickle files (.ckpt, .bin, .pt, .pth) are refused
// with a hint. A missing tensor is MLB_ERR_NOT_FOUND and a mis-shaped one MLB_ERR_FORMAT, the
// message naming the tensor and the file; a config that disagrees with the shapes is MLB_ERR_FORMAT
// naming the key. opt may be NULL. *out is NULL on failure.
mlb_status mlb_vae_load(const char* path, const mlb_vae_options* opt, mlb_vae** out);
// The same from an open file (e.g. the single file the UNet and text encoder are read from).
// config_path: a diffusers config.json or NULL (then opt->config_path; for single files the
// `ldm_config` metadata is read when present).
mlb_status mlb_vae_from_st(const mlb_safetensors* st, const char* config_path, const mlb_vae_options* opt,
                           mlb_vae** out);
// A double-precision copy (same configuration, every weight converted exactly).
mlb_status mlb_vae_to_f64(const mlb_vae* vae, mlb_vae_f64** out);
// Deterministic random weights (Philox stream `seed`): conv/linear weights N(0, gain^2 / fan_in),
// biases N(0, 0.05^2), norm weights 1 + N(0, 0.05^2), norm biases N(0, 0.05^2). For tests and
// benchmarks (a VAE of real size without the real file).
void mlb_vae_init_random(mlb_vae* vae, uint64_t seed, float gain);

// ---- the tensors of a layout (for writers and tests) ----------------------------------------------
typedef struct {
    char name[128];            // without a prefix, e.g. "decoder.up.3.block.0.conv1.weight"
    int ndim;
    int64_t shape[4];
    const float* data;         // into the model's buffer
    size_t n;                  // elements
} mlb_vae_tensor;
size_t mlb_vae_tensor_count(const mlb_vae* vae);
// Tensor i (0 <= i < count) in `layout`'s names and shapes. MLB_ERR_ARG past the end.
mlb_status mlb_vae_tensor_at(const mlb_vae* vae, size_t i, mlb_vae_layout layout, mlb_vae_tensor* out);
// Writes every tensor as F32 with mlb_st_write, names prefixed by `prefix` (NULL: none; e.g.
// "first_stage_model." for a single file), and for MLB_VAE_LAYOUT_DIFFUSERS also a config.json
// beside it when config_json_path is given (NULL: none).
mlb_status mlb_vae_save(const mlb_vae* vae, const char* path, mlb_vae_layout layout, const char* prefix,
                        const char* config_json_path);

#endif
