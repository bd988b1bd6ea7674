// Score-distillation guidance (guidance.h's interface over sds.h; docs/guidance.md, reference.md §7,
// paper §3.1/§3.4): random orbit cameras (cameras.h) and Stable Diffusion's score on the renders.
//
// loss(stage, step, views, images [n, H, W, 4] channels-last):
//   geometry, step < latent_iters: images → area resize to 64×64 → channels-first [n, 4, 64, 64]
//       used directly as the latent (Fantasia3D's [normal, mask] latent), weighting DreamFusion;
//   geometry, later: the normal map as a colour, (normal + 1)/2 composited over black =
//       (normal·mask + mask)/2 → [n, 3, H, W] → VAE encoder → SDS (geometry_opt's weighting);
//   appearance: channels 0..2 (sRGB premultiplied, over black) → [n, 3, H, W] → VAE → SDS.
// Prompts (view_prompts, default on): "<prompt>, front / side / back / overhead view" by each view's
// azimuth and elevation (mlb_sds_view_for), one embedding per direction; off: the plain prompt;
// the geometry stage's prompt carries the model's geometry_suffix before the view ("<prompt>, normal
// map, front view" for the project's own models, sd_model.h; nothing for SD 1.x / 2.x);
// unconditional embedding = the stage's negative prompt. The SDS noise / t seed is
// seed·2 + stage (geometry 0, appearance 1) and the step. dimages += ∂loss/∂images (channels-last);
// loss = the SDS loss (0.5 Σ grad² / n).
#ifndef MATLABER_GUIDANCE_SDS_H
#define MATLABER_GUIDANCE_SDS_H
#include <stdint.h>
#include "matlaber/cameras.h"
#include "matlaber/error.h"
#include "matlaber/guidance.h"
#include "matlaber/image_convert.h"   // mlb_area_resize_nhwc_to_nchw (sd_dataset.c, tests)
#include "matlaber/sd_model.h"
#include "matlaber/sds.h"

#define MLB_GUIDANCE_LATENT_SIZE 64   // the geometry stage's early latent: 64×64

typedef struct {
    const char* prompt;
    const char* negative_geometry;     // "low quality"
    const char* negative_appearance;   // "shadow, oversaturated, low quality, unrealistic"
    int views;                         // views per step, 9
    int latent_iters;                  // geometry steps fed as 64² [normal, mask] latents, 1000
    int latent_size;                   // those latents' size: 0 = MLB_GUIDANCE_LATENT_SIZE (64, SD at 512²);
                                       // the VAE's latent of the render for a smaller model (res / 8)
    int view_prompts;                  // 1: the prompt's view-dependent variants (default); 0: plain
    mlb_sds_options geometry_opt;      // scale 100, t 20..500, weighting fantasia0 (its seed is ignored)
    mlb_sds_options appearance_opt;    // scale 100, t 20..980, weighting fantasia0 (its seed is ignored)
    mlb_orbit_config orbit;            // mlb_orbit_default()
    int n_envs;                        // > 0: overrides orbit.n_envs (the environment pool size)
    uint64_t seed;                     // cameras and SDS noise, 0
} mlb_guidance_sds_config;

mlb_guidance_sds_config mlb_guidance_sds_default(void);
// Encodes the prompts with the model's text encoder (view-dependent prompts, both negatives); the
// model's UNet and VAE are borrowed (they must outlive the guidance; the text encoder may be
// dropped afterwards). The strings are copied.
mlb_status mlb_guidance_sds_create(const mlb_sd_model* model, const mlb_guidance_sds_config* c, mlb_guidance** out);
// The same with one model per stage: the geometry stage's normal renders guided by geometry_model
// (with its geometry_suffix), the appearance stage's shaded renders and its score (the material
// start) by appearance_model; the same model twice is mlb_guidance_sds_create, bit for bit.
mlb_status mlb_guidance_sds_create_staged(const mlb_sd_model* geometry_model, const mlb_sd_model* appearance_model,
                                          const mlb_guidance_sds_config* c, mlb_guidance** out);
// From two SDS objects whose embeddings are already set (tests, callers with their own
// embeddings): geometry and appearance are OWNED by the guidance from the call on (freed on
// failure too); their options are replaced by c's geometry_opt / appearance_opt (seeds as above).
// c->prompt and the negatives are not used.
mlb_status mlb_guidance_sds_create_from(mlb_sds* geometry, mlb_sds* appearance, const mlb_guidance_sds_config* c,
                                        mlb_guidance** out);

#endif
