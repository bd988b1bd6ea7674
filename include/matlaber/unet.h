// The Stable Diffusion UNet (diffusers UNet2DConditionModel / ldm openaimodel UNetModel; reference.md
// §6, docs/unet.md): eps (or v) = unet(latent x [N, in, H, W], timestep t [N], context [N, Tc, Dc]).
//
//   t -> sinusoid [cos | sin] (block_out[0] wide, max period 10000) -> linear, SiLU, linear = emb
//   conv_in -> down levels (layers_per_block x [ResNet (+ Transformer2D)] + stride-2 3x3 conv except
//   the last) -> mid (ResNet, Transformer2D, ResNet) -> up levels (layers_per_block + 1 x
//   [concat skip, ResNet (+ Transformer2D)] + nearest 2x upsample and 3x3 conv except the last) ->
//   GroupNorm + SiLU -> conv_out.
//   ResNet: x' = conv2(silu(gn2(conv1(silu(gn1(x))) + lin(silu(emb))))) + skip(x), GroupNorm eps norm_eps.
//   Transformer2D: GroupNorm (eps 1e-6) -> proj_in (1x1 conv SD1 / linear SD2; the same numbers) ->
//   tokens: x += attn1(ln1 x); x += attn2(ln2 x, context); x += W2 (h * gelu(gate)) with
//   [h | gate] = W1 ln3 x (GEGLU) -> proj_out -> + residual. q/k/v without bias.
//
// Loading: diffusers model folders (unet/ inside), unet folders (config.json +
// diffusion_pytorch_model.safetensors), a diffusers-layout .safetensors (config from
// <name>.config.json or config.json beside it) and single-file checkpoints (`model.diffusion_model.*`
// ldm names; heads from the `ldm_config` metadata). The structure (levels, widths, layers, which
// levels have attention, context width, linear projection) comes from the tensor shapes; the
// config gives the heads and norm settings. Without a config: SD2 (context 1024) -> head width 64,
// else 8 heads. F32/F16/BF16 weights are converted to float32 once. A missing tensor is
// MLB_ERR_NOT_FOUND and a mis-shaped one MLB_ERR_FORMAT, the message naming it and the file.
#ifndef MATLABER_UNET_H
#define MATLABER_UNET_H
#include <stddef.h>
#include "matlaber/device.h"
#include "matlaber/error.h"
#include "matlaber/safetensors.h"

#define MLB_UNET_MAX_LEVELS 6
#define MLB_UNET_MAX_LAYERS 4   // ResNets per down level (up levels hold one more)

typedef enum { MLB_UNET_LAYOUT_DIFFUSERS = 1, MLB_UNET_LAYOUT_LDM } mlb_unet_layout;

typedef struct {
    int in_channels, out_channels;          // 4, 4
    int n_levels;                           // len(block_out_channels) (4)
    int block_out[MLB_UNET_MAX_LEVELS];     // SD: 320, 640, 1280, 1280
    int layers_per_block;                   // 2
    int attn[MLB_UNET_MAX_LEVELS];          // 1: the level's blocks hold a Transformer2D (SD: 1,1,1,0)
    int heads[MLB_UNET_MAX_LEVELS];         // attention heads per level (down order; up uses the mirror)
    int mid_heads;                          // heads of the mid block's transformer
    int context_dim;                        // cross-attention key width (768 SD1, 1024 SD2)
    int time_embed_dim;                     // 1280 (4 x block_out[0])
    int linear_projection;                  // 1: proj_in/out are Linear (SD2), 0: 1x1 convs (SD1)
    int norm_groups;                        // 32
    float norm_eps;                         // ResNet GroupNorm eps (1e-5)
    float transformer_norm_eps;             // Transformer2D GroupNorm eps (1e-6)
    float layer_norm_eps;                   // LayerNorm eps in the transformer blocks (1e-5)
    int flip_sin_to_cos;                    // 1: [cos | sin]
    float freq_shift;                       // 0
    int v_prediction;                       // 1 when the config says so (ldm parameterization "v")
    int sd2;                                // 1 when the context is 1024 wide or linear projection is used
    mlb_unet_layout layout;                 // the layout it was loaded from
} mlb_unet_config;

// The parameters (float32, pointers into one buffer; weights [out, in] or [out, in, kh, kw]).
typedef struct {
    int cin, cout;
    float *norm1_w, *norm1_b, *conv1_w, *conv1_b;   // GroupNorm(cin), 3x3 conv cin -> cout
    float *temb_w, *temb_b;                         // [cout, time_embed_dim]
    float *norm2_w, *norm2_b, *conv2_w, *conv2_b;   // GroupNorm(cout), 3x3 conv cout -> cout
    float *skip_w, *skip_b;                         // 1x1 conv cin -> cout, NULL when cin == cout
} mlb_unet_resnet;

typedef struct {
    int C, heads;
    float *norm_w, *norm_b;                  // GroupNorm(C), eps transformer_norm_eps
    float *proj_in_w, *proj_in_b;            // [C, C] (a 1x1 conv's weight is the same numbers)
    float *ln1_w, *ln1_b, *q1, *k1, *v1, *o1_w, *o1_b;     // self-attention, q/k/v [C, C]
    float *ln2_w, *ln2_b, *q2, *k2, *v2, *o2_w, *o2_b;     // cross-attention, k/v [C, context_dim]
    float *ln3_w, *ln3_b, *ff1_w, *ff1_b, *ff2_w, *ff2_b;  // GEGLU: ff1 [8C, C], ff2 [C, 4C]
    float *proj_out_w, *proj_out_b;          // [C, C]
} mlb_unet_transformer;

typedef struct {
    float *w, *b;                            // 3x3 conv C -> C
} mlb_unet_conv;

struct mlb_unet {
    mlb_unet_config cfg;
    mlb_device device;                              // where params live (CPU unless mlb_unet_to_device)
    float* params;                                  // with bf16/f16_weights: ndim >= 2 tensors hold 16-bit values
    size_t n_params;                                // parameters (not floats of storage)
    int bf16_weights;                               // mlb_unet_options.bf16_weights, when it took effect
    int f16_weights;                                // mlb_unet_options.f16_weights, when it took effect
    float *time1_w, *time1_b, *time2_w, *time2_b;   // [TE, block_out[0]], [TE, TE]
    float *conv_in_w, *conv_in_b;                   // [block_out[0], in, 3, 3]
    mlb_unet_resnet down_res[MLB_UNET_MAX_LEVELS][MLB_UNET_MAX_LAYERS];
    mlb_unet_transformer down_attn[MLB_UNET_MAX_LEVELS][MLB_UNET_MAX_LAYERS];
    mlb_unet_conv down_conv[MLB_UNET_MAX_LEVELS];   // stride 2, pad 1 (all but the last level)
    mlb_unet_resnet mid_res[2];
    mlb_unet_transformer mid_attn;
    // up blocks in diffusers order: up level i mirrors down level n_levels - 1 - i
    mlb_unet_resnet up_res[MLB_UNET_MAX_LEVELS][MLB_UNET_MAX_LAYERS + 1];
    mlb_unet_transformer up_attn[MLB_UNET_MAX_LEVELS][MLB_UNET_MAX_LAYERS + 1];
    mlb_unet_conv up_conv[MLB_UNET_MAX_LEVELS];     // after a nearest 2x upsample (all but the last)
    float *norm_out_w, *norm_out_b, *conv_out_w, *conv_out_b;
    // mlb_unet_use_device: a copy on the GPU that mlb_unet_forward runs on (NULL: the CPU), and the
    // ops it runs with (without a mirror: NULL for the CPU's fp32 ops, or the CPU's bf16 table)
    struct mlb_unet* mirror;
    const struct mlb_backend* mirror_ops;
};
typedef struct mlb_unet mlb_unet;

typedef struct {
    const char* config_path;   // a diffusers config.json; NULL: look beside the weights
    // 1: keep the linear and conv weights in bf16 (half the memory: 1.7 instead of 3.4 GB for SD 1.5)
    // and run on the CPU's bf16 ops for good (mlb_backend_cpu_bf16_stored: the same bits as
    // mlb_unet_use_device(u, MLB_DEVICE_CPU, MLB_GEMM_BF16) on fp32 weights). Needs AVX-512 BF16:
    // elsewhere the weights load in fp32 (said in the log) and bf16_weights stays 0 in the UNet.
    int bf16_weights;
    // 1: keep the linear and conv weights as the IEEE half values the file stores (half the memory)
    // and run on the CPU's fp32 ops, each call widening its weight (mlb_backend_cpu_f16_stored: the
    // same bits as fp32 weights). Only when every such weight is F16 in the file (else fp32, said in
    // the log: rounding F32 weights would change the results); ignored with bf16_weights in effect.
    // No backward, no other device.
    int f16_weights;
} mlb_unet_options;

// How the program loads a UNet that is to run on device d at GEMM precision prec (sd_model.c and the
// benches): on the CPU, bf16 weights where it computes bf16 natively, else the file's F16 weights
// kept half; elsewhere fp32 (config_path NULL).
mlb_unet_options mlb_unet_options_for(mlb_device d, mlb_gemm_precision prec);

// `path`: see above. opt may be NULL. *out is NULL on failure.
mlb_status mlb_unet_load(const char* path, const mlb_unet_options* opt, mlb_unet** out);
// The same from an open file (diffusers or ldm names, detected); config_path a config.json or NULL
// (then the ldm_config metadata when present).
mlb_status mlb_unet_from_st(const mlb_safetensors* st, const char* config_path, mlb_unet** out);
// The same with options (opt->config_path as config_path above; opt may be NULL).
mlb_status mlb_unet_from_st_opt(const mlb_safetensors* st, const mlb_unet_options* opt, mlb_unet** out);
void mlb_unet_free(mlb_unet* u);   // NULL is fine; frees device weights on their device
// A UNet of configuration c with its parameters allocated (not initialised) on device d, the
// pointers carved in the loader's order (so params matches a loaded UNet's params element for
// element). MLB_ERR_ARG for a bad configuration, MLB_ERR_NOMEM / MLB_ERR_DEVICE.
mlb_status mlb_unet_create(const mlb_unet_config* c, mlb_device d, mlb_unet** out);
// From now on mlb_unet_forward (host buffers) runs on device d with GEMM operands at precision
// prec: the weights are copied there once, the inputs and
// the output cross per call (a few hundred KB for SD's latents). MLB_DEVICE_CPU undoes it; with
// MLB_GEMM_BF16 the CPU's linear, conv and attention GEMMs then take bf16 operands (backend.h; the
// weights stay fp32: mlb_unet_options.bf16_weights keeps them in bf16 at load), any other prec
// is the CPU's fp32.
mlb_status mlb_unet_use_device(mlb_unet* u, mlb_device d, mlb_gemm_precision prec);
// A copy of the CPU UNet src with its weights on device d (one upload of params).
mlb_status mlb_unet_to_device(const mlb_unet* src, mlb_device d, mlb_unet** out);
const mlb_unet_config* mlb_unet_get_config(const mlb_unet* u);
size_t mlb_unet_param_count(const mlb_unet* u);

// Optional observer of intermediate tensors (named as the diffusers modules: "time_proj",
// "time_embedding", "conv_in", "down_blocks.I", "mid_block", "up_blocks.I", "conv_norm_out"),
// called with the [N, ...] activation and its element count.
typedef void (*mlb_unet_debug_fn)(void* user, const char* name, const float* data, size_t n);

// out [N, out_channels, H, W] = unet(x [N, in_channels, H, W], t [N] (timesteps, may be fractional),
// context [N, Tc, context_dim]). H and W must be multiples of 2^(n_levels - 1). The same bits on any
// thread count (every GEMM is mlb_gemm, every reduction runs in a fixed order; tests/test_sd_tiny.c).
// MLB_ERR_ARG for bad shapes, MLB_ERR_NOMEM.
// On the ops of `be` (backend.h): u must be on be->device (mlb_unet_to_device), and out, x and
// context in that device's memory; t stays on the host. The observer receives host copies.
// be NULL: the buffers are on the host and the model picks its ops: the CPU table, or after
// mlb_unet_use_device that device's (the inputs and the output cross per call).
struct mlb_backend;
mlb_status mlb_unet_forward(const struct mlb_backend* be, const mlb_unet* u, float* out, const float* x,
                            const float* t, const float* context, int N, int H, int W, int Tc,
                            mlb_unet_debug_fn debug, void* debug_user);

#endif
