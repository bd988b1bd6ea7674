// Image guidance (guidance.h, docs/guidance_images.md): the renders of a step are compared with
// the target images of a multi-view data set (views.h) seen by the same cameras under the same
// lights. Used for fitting to photographs / renders, and for tests that need no diffusion weights.
//
// Loss of one step over its n views (images [n, H, W, 4], H = W = the data set's res), the
// convention of mlb_geofit_loss: summed over channels, averaged over pixels and views,
//   geometry:    L = Σ_v Σ_p (w_normal Σ_{c<3} (o_c − t_c)² + w_mask (o_3 − t_3)²) / (n H W)
//                with t = the view's [normal·α, α] (w_normal counts only when the data set has
//                normal maps; without them only the mask is compared)
//   appearance:  L = Σ_v Σ_p (w_rgb Σ_{c<3} (o_c − t_c)² + w_mask_appearance (o_3 − t_3)²) / (n H W)
//                with t = the view's [sRGB·α, α]
// and ∂L/∂o = 2 w (o − t) / (n H W), accumulated (+=) into dimages.
#ifndef MATLABER_GUIDANCE_IMAGE_H
#define MATLABER_GUIDANCE_IMAGE_H
#include <stdint.h>
#include "matlaber/guidance.h"
#include "matlaber/views.h"

typedef struct {
    int views_per_step;          // distinct target views per step (all when >= the data set's n); default 4
    uint64_t seed;               // default 1
    double w_mask;               // geometry stage: mask channel, default 1
    double w_normal;             // geometry stage: normal channels, default 1 (needs normal maps)
    double w_rgb;                // appearance stage: colour channels, default 1
    double w_mask_appearance;    // appearance stage: mask channel, default 0
} mlb_guidance_images_config;

mlb_guidance_images_config mlb_guidance_images_default(void);

// A guidance over `data` (borrowed: it must outlive the guidance). kind "images", n_views =
// min(views_per_step, data->n). sample_views draws the step's targets without repetition by a
// partial Fisher–Yates shuffle driven by Philox (seed, stream 0x1A6E + stage, index step·n_views + i)
// (all views in order 0..n−1 when views_per_step >= n), and fills each mlb_view with the target's
// camera, its azimuth / elevation / radius, environment index (into data->meta.envs; −1 when the
// view has none) and rotation. loss takes the images of those views in the same order.
mlb_status mlb_guidance_images_create(const mlb_views* data, const mlb_guidance_images_config* c, mlb_guidance** out);

#endif
