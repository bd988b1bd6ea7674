// The Stable Diffusion text encoders (reference.md §6, docs/text_encoder.md): 77 CLIP tokens ->
// the conditioning [B, 77, W] the UNet cross-attends to.
//   SD1: CLIP ViT-L/14 text (W 768, 12 layers, 12 heads, quick_gelu); output = last layer + final LN.
//   SD2: OpenCLIP ViT-H text (W 1024, 24 layers, 16 heads, exact GELU); output = penultimate layer
//        + ln_final.
// Both are pre-LN transformers with a causal mask and LayerNorm eps 1e-5 (config.json may say
// otherwise). Loading reads single-file checkpoints (CompVis/Stability layout, HF CLIP or OpenCLIP
// names), diffusers text_encoder/ folders (config.json + model.safetensors) and diffusers model
// folders; weights in F32, F16 or BF16 are converted to float32 once.
#ifndef MATLABER_TEXT_ENCODER_H
#define MATLABER_TEXT_ENCODER_H
#include <stddef.h>
#include "matlaber/device.h"
#include "matlaber/error.h"
#include "matlaber/nn.h"
#include "matlaber/safetensors.h"

typedef enum {
    MLB_TEXT_AUTO = 0,   // options only: detect
    MLB_TEXT_SD1,        // quick_gelu, output of the last layer + final LayerNorm
    MLB_TEXT_SD2,        // exact GELU, output of the penultimate layer + ln_final
} mlb_text_variant;

typedef enum {
    MLB_TEXT_LAYOUT_LDM_CLIP = 1,   // single file, HF CLIP names: cond_stage_model.transformer.text_model.*
    MLB_TEXT_LAYOUT_OPENCLIP,       // single file, OpenCLIP names: cond_stage_model.model.*
    MLB_TEXT_LAYOUT_DIFFUSERS,      // CLIPTextModel state dict: text_model.* (+ config.json)
} mlb_text_layout;

typedef struct {
    mlb_text_variant variant;   // MLB_TEXT_AUTO: from the names / config.json hidden_act
    int n_heads;                // 0: from config.json, else ldm_config metadata, else width / 64
    int skip_last;              // -1: the variant's rule; k >= 0: output of stored layer L - k (+ final LN)
    const char* config_path;    // diffusers config.json to use; NULL: look beside the weights
} mlb_text_encoder_options;

// One pre-LN block: x += out_proj(attn(ln_1(x))); x += fc2(act(fc1(ln_2(x)))).
typedef struct {
    float *ln1_w, *ln1_b;     // [W]
    float *qkv_w, *qkv_b;     // [3W, W], [3W]: q rows, then k, then v (OpenCLIP's in_proj layout)
    float *q_w, *k_w, *v_w;   // [W, W] each: views into qkv_w
    float *q_b, *k_b, *v_b;   // [W] each: views into qkv_b
    float *out_w, *out_b;     // [W, W], [W]
    float *ln2_w, *ln2_b;     // [W]
    float *fc1_w, *fc1_b;     // [M, W], [M]   (OpenCLIP mlp.c_fc)
    float *fc2_w, *fc2_b;     // [W, M], [W]   (OpenCLIP mlp.c_proj)
} mlb_text_layer;

typedef struct {
    mlb_text_variant variant;
    mlb_text_layout layout;
    int vocab;                 // rows of the token embedding (49408 for the real models)
    int n_ctx;                 // rows of the position embedding (77): the longest sequence
    int width;                 // W
    int n_heads;               // head width = W / n_heads
    int mlp;                   // M, the MLP's hidden width
    int n_layers_stored;       // layers of the checkpoint (config.json's num_hidden_layers when given)
    int n_layers;              // layers run = n_layers_stored - skip_last (only these are loaded)
    int skip_last;
    mlb_activation act;        // MLB_ACT_QUICK_GELU (SD1) or MLB_ACT_GELU (SD2)
    float ln_eps;
    float* token_embedding;    // [vocab, W]
    float* position_embedding; // [n_ctx, W]
    mlb_text_layer* layers;    // [n_layers]
    float *ln_final_w, *ln_final_b;   // [W]
    float* params;             // one float32 buffer holding every tensor above
    mlb_device device;         // where params lives: the CPU unless mlb_text_encoder_to_device
    size_t n_params;
    char heads_from[32];       // "option", "config.json", "ldm_config", "width/64"
    char source[1200];         // what was loaded: file, layout, sizes
} mlb_text_encoder;

mlb_text_encoder_options mlb_text_encoder_default_options(void);   // AUTO, 0, -1, NULL

// `path`: a single-file checkpoint (.safetensors), a diffusers text_encoder/ folder, a diffusers
// model folder (text_encoder/ inside), or a CLIPTextModel model.safetensors file (its config from
// opt->config_path, else <name>.config.json for <name>.safetensors, else config.json beside it).
// opt may be NULL (defaults). Pickle checkpoints (.ckpt, .bin, .pt, .pth) are refused with a hint
// on converting them. *out is NULL on failure; the message names the file and the tensor.
mlb_status mlb_text_encoder_load(const char* path, const mlb_text_encoder_options* opt, mlb_text_encoder** out);
// The same from an open safetensors file (e.g. the single file the UNet is also read from).
// config_path: a diffusers config.json or NULL (opt->config_path is used when this is NULL).
mlb_status mlb_text_encoder_from_st(const mlb_safetensors* st, const char* config_path,
                                    const mlb_text_encoder_options* opt, mlb_text_encoder** out);
void mlb_text_encoder_free(mlb_text_encoder* te);   // NULL is fine; frees device weights on their device
// A copy of the CPU encoder src with its weights on device d (one upload of params), for
// mlb_text_encoder_forward with that device's table. MLB_ERR_NOMEM / MLB_ERR_DEVICE.
mlb_status mlb_text_encoder_to_device(const mlb_text_encoder* src, mlb_device d, mlb_text_encoder** out);

// The padding token the variant's tokenizer uses: 49407 (SD1) or 0 (SD2).
int mlb_text_encoder_pad_id(const mlb_text_encoder* te);
const char* mlb_text_variant_name(mlb_text_variant v);   // "auto", "sd1", "sd2"
mlb_status mlb_text_variant_parse(const char* name, mlb_text_variant* out);

// tokens [B, T] (T <= n_ctx, normally 77) -> out [B, T, W]: the conditioning, on the ops of `be`
// (backend.h; NULL: the CPU's fp32 table, whose results are those of the CPU ops called directly,
// bit for bit). te must be on be->device (mlb_text_encoder_to_device; the CPU tables use the host
// weights as they are); tokens, out and states stay on the host (the tokens are checked there, the
// rest crosses once). The CPU's bf16 table runs the linear layers on bf16 operands (the attention
// stays fp32); its bf16-stored table is refused (these weights are fp32).
// Also the residual stream before the final LayerNorm: states [n_states, B, T, W] with states[0] =
// token + position embeddings and states[i] = output of layer i (as transformers'
// hidden_states). n_states <= n_layers + 1; states may be NULL (n_states ignored).
// Deterministic (the same bits on any thread count); safe to call from several threads at once
// (the model is read-only; scratch is allocated per call). MLB_ERR_ARG for a token outside the
// vocabulary or T > n_ctx.
struct mlb_backend;
mlb_status mlb_text_encoder_forward(const struct mlb_backend* be, const mlb_text_encoder* te, const int* tokens, int B,
                                    int T, float* out, float* states, int n_states);

#endif
