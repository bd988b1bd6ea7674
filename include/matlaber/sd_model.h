// A whole Stable Diffusion model (docs/sds.md): CLIP tokenizer, text encoder, UNet and VAE loaded
// together, the float32 noise schedule, prompt encoding, DDIM sampling with classifier-free
// guidance (the `matlaber sd txt2img` path) and latent decoding.
//
// Sources: a diffusers model folder (tokenizer/, text_encoder/, unet/, vae/, scheduler/) or one
// single-file checkpoint (.safetensors with model.diffusion_model.*, cond_stage_model.* and
// first_stage_model.* tensors) plus a tokenizer path. Pickle files (.ckpt, .bin, .pt, .pth) are
// refused with a conversion hint. v-prediction comes from the options, else from the configs:
// diffusers unet/config.json or scheduler/scheduler_config.json `prediction_type`, or the single
// file's ldm_config `parameterization`.
#ifndef MATLABER_SD_MODEL_H
#define MATLABER_SD_MODEL_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/device.h"
#include "matlaber/error.h"
#include "matlaber/progress.h"
#include "matlaber/text_encoder.h"
#include "matlaber/tokenizer.h"
#include "matlaber/unet.h"
#include "matlaber/vae.h"

typedef struct {
    const char* tokenizer_path;   // NULL: <folder>/tokenizer where it exists, else $MATLABER_TOKENIZER (a single file needs one)
    int v_prediction;             // -1: from the configs (default), 0: epsilon, 1: v-prediction
    int load_text_encoder;        // 1 (default); 0 to skip it (and the tokenizer)
    int load_vae;                 // 1 (default)
    mlb_device device;            // where the UNet and the VAE run (default: the CPU; the program passes --device)
    mlb_gemm_precision precision; // their GEMMs' operands (default fp32; the program passes --precision)
} mlb_sd_model_options;

#define MLB_SD_SUFFIX_MAX 64
// 1 when s can be a model's geometry suffix: at most MLB_SD_SUFFIX_MAX - 1 printable ASCII
// characters, no quote or backslash (it is written into JSON as it is).
int mlb_sd_geometry_suffix_ok(const char* s);

typedef struct {
    mlb_tokenizer* tokenizer;     // NULL when not loaded
    mlb_text_encoder* text;       // NULL when not loaded
    mlb_unet* unet;
    mlb_vae* vae;                 // NULL when not loaded
    int v_prediction;             // 1: the UNet predicts v
    int pad_id;                   // 49407 (SD1) or 0 (SD2)
    float scaling_factor;         // latent = VAE mean * scaling_factor (0.18215)
    float alphas_cumprod[1000];   // diffusers' float32 values (what the DDIM/SDS references use)
    char source[600];             // what was loaded
    // What the model's captions of normal renders add after the object (the project's own models:
    // ", normal map"; sd_train.h MLB_SD_GEOMETRY_SUFFIX): a folder's model_index.json
    // "_matlaber_geometry_suffix"; "" for any other model. The geometry stage's guidance appends it.
    char geometry_suffix[MLB_SD_SUFFIX_MAX];
} mlb_sd_model;

// 1 when path is a model folder of the project's own (matlaber sd train: model_index.json has the
// key "_matlaber", sd_folder.h), trained on the catalogue's captions alone (caption.h); 0 for any
// other folder or file, or one that cannot be read.
int mlb_sd_model_is_own(const char* path);

mlb_sd_model_options mlb_sd_model_default_options(void);   // NULL, -1, 1, 1, the CPU, fp32
// *out is NULL on failure; the message names the file and the tensor or key.
mlb_status mlb_sd_model_load(const char* path, const mlb_sd_model_options* opt, mlb_sd_model** out);
void mlb_sd_model_free(mlb_sd_model* m);   // NULL is fine
// Frees the tokenizer and text encoder once the prompts are encoded (saves their memory).
void mlb_sd_model_drop_text(mlb_sd_model* m);
// Frees the UNet once sampling is done, before the VAE decodes (txt2img: the decoder's activations at
// 512² then share the memory with the VAE alone, not with SD 1.5's 1.7-3.4 GB of UNet weights).
void mlb_sd_model_drop_unet(mlb_sd_model* m);

// The text conditioning of one prompt: out [77, text width] (tokenised with the model's padding).
mlb_status mlb_sd_model_encode_prompt(const mlb_sd_model* m, const char* prompt, float* out);
int mlb_sd_model_context_width(const mlb_sd_model* m);   // text width (768 SD1, 1024 SD2)

// DDIM (eta 0, leading spacing, steps_offset 1, set_alpha_to_one 0) with classifier-free guidance
// eps = eps_u + cfg (eps_c - eps_u); uncond and cond contexts are [Tc, Dc] each (one image, N = 1).
// latent [4, h, w]: in x_T, out the final latent. ac: alphas_cumprod [1000] (float32 values).
// v_prediction converts the UNet's v to eps first. trace_eps / trace_latents (may be NULL) receive
// [steps, 4, h, w]: the guided eps and the latent after each step. progress may be NULL.
// steps in 1..MLB_DDIM_MAX_STEPS: with steps_offset 1 a 1000th step would be timestep 1000 of 0..999.
#define MLB_DDIM_MAX_STEPS 999
mlb_status mlb_sd_ddim_sample(const mlb_unet* unet, const float* ac, int v_prediction, const float* ctx_uncond,
                              const float* ctx_cond, int Tc, float* latent, int h, int w, int steps, float cfg,
                              float* trace_eps, float* trace_latents, mlb_progress* progress);
// image [3, 8h, 8w] (nominally [-1, 1], unclamped) = vae.decode(latent [4, h, w] / scaling_factor).
mlb_status mlb_sd_decode_latent(const mlb_vae* vae, float scaling_factor, const float* latent, int h, int w,
                                float* image);

#endif
