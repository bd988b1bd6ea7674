// Score distillation sampling (reference.md §7, docs/sds.md): the guidance that turns Stable
// Diffusion into a gradient on rendered images.
//
//   z     = VAE.encode(2 x - 1).mean * scaling_factor          (x: [B, 3, H, W] renders in [0, 1])
//           or z = x directly for [B, 4, h, w] inputs (Fantasia3D's 64x64 [normal, mask] latents)
//   t_b   ~ U{t_min .. t_max}, eps_b ~ N(0, I)                  (Philox of (seed, step), per element)
//   x_t   = sqrt(ac_t) z + sqrt(1 - ac_t) eps
//   eps^  = eps_u + s (eps_c - eps_u)                           (one UNet call: [cond x B, uncond x B];
//                                                                v-prediction converted to eps)
//   grad  = w(t) (eps^ - eps), non-finite values -> 0
//   loss  = 0.5 sum(grad^2) / B   (= 0.5 |z - stopgrad(z - grad)|^2 / B, so d loss / d z = grad / B)
//   d loss / d x through the VAE encoder backward (and the factor 2 of 2x - 1), ADDED to grad_x.
//
// Weights: DreamFusion 1 - ac_t; Fantasia3D strategy 0: sqrt(ac_t) (1 - ac_t), strategy 1:
// 1 / (1 - ac_t), strategy 2: 0 while step < coarse_iter, then 1.
// View-dependent prompts: "<prompt>, front view" / "side view" / "back view" / "overhead view"
// (mlb_sds_view_for).
#ifndef MATLABER_SDS_H
#define MATLABER_SDS_H
#include <stdint.h>
#include "matlaber/error.h"
#include "matlaber/sd_model.h"

typedef enum {
    MLB_SDS_W_DREAMFUSION = 0,   // 1 - ac_t
    MLB_SDS_W_FANTASIA0,         // sqrt(ac_t) (1 - ac_t)
    MLB_SDS_W_FANTASIA1,         // 1 / (1 - ac_t)
    MLB_SDS_W_FANTASIA2,         // 0 before coarse_iter, 1 after
} mlb_sds_weighting;

enum { MLB_SDS_VIEW_NONE = 0, MLB_SDS_VIEW_FRONT, MLB_SDS_VIEW_SIDE, MLB_SDS_VIEW_BACK, MLB_SDS_VIEW_OVERHEAD,
       MLB_SDS_N_VIEWS };
// Above this elevation (degrees) a view is "overhead" whatever its azimuth (threestudio's 60°).
#define MLB_SDS_OVERHEAD_ELEVATION 60.0
#define MLB_SDS_MAX_BATCH 64

typedef struct {
    float guidance_scale;        // s (100)
    int t_min, t_max;            // inclusive timestep range (20, 980); Fantasia3D geometry: 20, 500
    int t_max_end;               // with anneal_steps > 0: t_max falls linearly to this (>= t_min) at
    long anneal_steps;           //   step anneal_steps and stays there (0: t_max throughout)
    mlb_sds_weighting weighting; // MLB_SDS_W_DREAMFUSION
    long coarse_iter;            // strategy 2 only
    uint64_t seed;               // t and noise are Philox of (seed, step, element)
} mlb_sds_options;

mlb_sds_options mlb_sds_default_options(void);   // 100, 20, 980, DreamFusion, 0, seed 0
// The options' rules, checked once here for every SDS that takes them (mlb_sds_create, and the
// guidance that sets them on its SDS objects): timesteps within 0..999 and ordered, the annealing's
// end within [t_min, 999], a finite guidance scale, a known weighting. MLB_ERR_ARG naming the bad one.
mlb_status mlb_sds_options_check(const mlb_sds_options* o);
const char* mlb_sds_weighting_name(mlb_sds_weighting w);   // "dreamfusion", "fantasia0", ...
mlb_status mlb_sds_weighting_parse(const char* name, mlb_sds_weighting* out);
// The largest timestep drawn at `step`: t_max, or annealed towards t_max_end (options above).
int mlb_sds_t_max_at(const mlb_sds_options* o, long step);
// The weight for a timestep (non-finite -> 0). ac: the float32 alphas_cumprod value.
float mlb_sds_weight(mlb_sds_weighting w, float ac, long step, long coarse_iter);
// front within +-45 deg of azimuth 0, back beyond +-135 deg, else side (degrees, any range).
int mlb_sds_view_for_azimuth(double azimuth_deg);
// The same, but overhead above MLB_SDS_OVERHEAD_ELEVATION (elevation in degrees, 90 = from above).
int mlb_sds_view_for(double azimuth_deg, double elevation_deg);
// The prompt suffix of a view: "", ", front view", ", side view", ", back view", ", overhead view".
const char* mlb_sds_view_suffix(int view);

typedef struct mlb_sds mlb_sds;

// From UNet + VAE (borrowed: they must outlive the object; vae may be NULL when only 4-channel
// latents are given), the schedule and v-prediction flag; embeddings are set separately.
mlb_status mlb_sds_create(const mlb_unet* unet, const mlb_vae* vae, float scaling_factor, const float* alphas_cumprod,
                          int v_prediction, const mlb_sds_options* opt, mlb_sds** out);
// From a loaded model: encodes `prompt` (cond) and `negative` (uncond; NULL or "" = the empty
// prompt) and, when view_dependent, "<prompt>, front view" etc. (every mlb_sds_view_suffix). The
// model's text encoder may be dropped afterwards (mlb_sd_model_drop_text); UNet and VAE stay borrowed.
mlb_status mlb_sds_create_from_model(const mlb_sd_model* m, const char* prompt, const char* negative, int view_dependent,
                                     const mlb_sds_options* opt, mlb_sds** out);
void mlb_sds_free(mlb_sds* s);
// Cached embeddings [Tc, context_dim]: view MLB_SDS_VIEW_NONE is the base prompt (required); a
// view without its own falls back to it. uncond: the unconditional / negative embedding.
mlb_status mlb_sds_set_cond(mlb_sds* s, int view, const float* emb, int Tc);
mlb_status mlb_sds_set_uncond(mlb_sds* s, const float* emb, int Tc);
mlb_sds_options* mlb_sds_options_of(mlb_sds* s);   // to change scale, range, weighting between steps

// Optional intermediate tensors (each may be NULL; [B, 4, h, w] unless stated).
typedef struct {
    float *latent, *noisy_latent, *eps_cond, *eps_uncond, *eps_guided, *grad_latent;
    float* w;   // [B]
    int* t;     // [B]
    // [B] the UNet's denoising errors before guidance: mean over the latent's elements of
    // (eps_cond - eps)^2 and (eps_uncond - eps)^2 (a diffusion classifier's terms: mlb_guidance score)
    double *err_cond, *err_uncond;
} mlb_sds_trace;

typedef struct {
    const float* images;   // [B, C, H, W]: C = 3 renders in [0, 1], or C = 4 latents used as they are
    int B, C, H, W;
    const int* views;      // [B] view per element, or NULL (all MLB_SDS_VIEW_NONE)
    long step;             // the iteration: seeds t and noise, and strategy 2's switch
    const int* t;          // [B] to override the sampled timesteps (tests), or NULL
    const float* noise;    // [B, 4, h, w] to override the sampled noise (tests), or NULL
    int first;             // element b draws t and noise as element first + b of the step (0)
    int total;             // the step's elements: gradient and loss are / total (0: B), so that a
                           // batch split into parts gives the whole batch's gradients
} mlb_sds_input;

// The latent [*c, *h, *w] the UNet sees for a [C, H, W] input (the VAE's for C = 3, the input's own
// for latents; *c the UNet's input channels, c may be NULL); MLB_ERR_ARG naming what does not fit.
mlb_status mlb_sds_latent_shape(const mlb_sds* s, int C, int H, int W, int* c, int* h, int* w);
// grad_images [B, C, H, W] += d loss / d images (may be NULL: loss only, no VAE backward);
// *loss (may be NULL) = 0.5 sum(grad^2) / B. trace may be NULL.
// be NULL: host buffers; where the VAE runs on a GPU (mlb_vae_use_device) the images cross to it
// and the gradient back.
// Else in->images and grad_images are in the memory of be's device (backend.h): the
// images are mapped to 2 x - 1 and encoded, the latent noised, the UNet run, the guidance, the
// weighting and the gradient made, and the gradient taken back through the encoder, all there
// (the VAE and the UNet on their own tables, which must run on be's device; fp32 CPU models run on
// be). Only the timesteps and the noise go up (drawn on the host: Philox) and the loss (three
// floats) comes down; the embeddings go up once (per device, and after mlb_sds_set_*). With the
// CPU's table it is the host buffers' step, bit for bit.
struct mlb_backend;
mlb_status mlb_sds_step(mlb_sds* s, const struct mlb_backend* be, const mlb_sds_input* in, float* grad_images,
                        float* loss, mlb_sds_trace* trace);
// The table whose device mlb_sds_step runs a [B, C, H, W] input on: the VAE's (a GPU, or the CPU's
// bf16 ops) for images, the UNet's for latents (the CPU's where they have none).
const struct mlb_backend* mlb_sds_images_table(const mlb_sds* s, int C);

#endif
