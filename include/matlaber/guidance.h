// Guidance (paper §3.1, design.md): what turns the renders of one optimisation step into a loss
// and its gradient. One interface, two implementations:
//   - score distillation with a Stable Diffusion model (src/pipeline/guidance_sds.c), and
//   - image guidance: renders compared with target images by an image loss
//     (src/pipeline/guidance_image.c), for photographs / renders and for tests without weights.
// The guidance also decides where the cameras and lights of a step are: random orbit cameras and
// a random environment of the pool for SDS, the target images' own cameras and lights for images.
//
// Images crossing this interface are channels-last float [n, H, W, 4], background 0:
//   geometry stage:   [normal (world space, interpolated vertex normals · coverage), coverage]
//   appearance stage: [sRGB colour · coverage (composited over black), coverage]
// so both stages hand the guidance premultiplied colour and an antialiased mask.
#ifndef MATLABER_GUIDANCE_H
#define MATLABER_GUIDANCE_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/error.h"
#include "matlaber/raster.h"

struct mlb_backend;

typedef enum { MLB_STAGE_GEOMETRY = 0, MLB_STAGE_APPEARANCE = 1 } mlb_stage;

// One view of a step.
typedef struct {
    mlb_camera cam;            // aspect 1 (square renders)
    double azimuth_deg;        // orbit azimuth (view-dependent prompts), elevation, radius
    double elevation_deg;
    double radius;
    int env;                   // index into the run's environment pool (appearance stage)
    float env_rotation_deg;    // rotation of that environment about +y
    int target;                // image guidance: index of the target image; −1 otherwise
} mlb_view;

typedef struct mlb_guidance mlb_guidance;
struct mlb_guidance {
    const char* kind;          // "sds" or "images"
    int n_views;               // views per step
    // Fills views[n_views] for iteration `step` of `stage`: a pure function of (seed, stage, step),
    // so a resumed run sees the same cameras.
    mlb_status (*sample_views)(mlb_guidance* g, mlb_stage stage, long step, mlb_view* views);
    // images [n, H, W, 4] of the views above → *loss (the step's guidance loss) and, when dimages is
    // not NULL, dimages [n, H, W, 4] += ∂loss/∂images.
    mlb_status (*loss)(mlb_guidance* g, mlb_stage stage, long step, const mlb_view* views, int n, const float* images,
                       int H, int W, float* dimages, double* loss);
    // Optional (NULL where the guidance reads host images only, as image guidance): loss with images
    // and dimages in the memory of be's device (backend.h), so that a stage whose renders live on a
    // GPU hands them over where they are; with the CPU's table it is loss, bit for bit.
    mlb_status (*loss_on)(mlb_guidance* g, const struct mlb_backend* be, mlb_stage stage, long step,
                          const mlb_view* views, int n, const float* images, int H, int W, float* dimages, double* loss);
    void (*destroy)(mlb_guidance* g);
    // Optional (NULL where the guidance has none, as image guidance): per_view[v] = how much better
    // the prompt explains render v of [n, H, W, 4] (of `stage`, at the form its step 0 uses) than
    // the unconditional text does: E_t,eps[|eps_u - eps|^2 - |eps_c - eps|^2] per latent element, a
    // diffusion classifier's estimate of log p(render | prompt) - log p(render) (up to scale).
    // Fixed timesteps and noise (the same for every call), so two sets of renders compare on the
    // same draws; the timesteps spread over t_range [lo, hi] (NULL: the stage's range). --init auto
    // picks the starting shape by it (docs/pipeline.md, Init), the material start the material.
    mlb_status (*score)(mlb_guidance* g, mlb_stage stage, const mlb_view* views, int n, const float* images, int H,
                        int W, const int* t_range, double* per_view);
    void* impl;
    // Which of the step's views the next loss call covers, for a step guided a part at a time (a
    // micro-batch of views, on whichever rank renders it: dist.h): images[0] is view part_first of
    // a step of part_total views. Random draws are keyed by the view's index in the step, and loss
    // and gradient are normalised by part_total, so the parts' gradients are the whole call's and
    // their losses add up to its loss. part_total 0: the call is the whole step (views 0..n-1).
    int part_first, part_total;
    // Views per loss call (set by the run's config, view_batch): a step's views are guided in
    // micro-batches of this many, and the batches go whole to the processes (dist.h). 0 (or >=
    // n_views): the whole step in one call. The bits depend on it (Stable Diffusion's UNet and VAE
    // round differently at other batch sizes), never on the number of processes.
    int view_batch;
};

// g->loss on views [first, first + n) of a step of `total` views (the fields above, reset after);
// with a table be, g->loss_on with images and dimages on be's device (NULL: host buffers).
static inline mlb_status mlb_guidance_loss_part(mlb_guidance* g, const struct mlb_backend* be, mlb_stage stage,
                                                long step, const mlb_view* views, int first, int n, int total,
                                                const float* images, int H, int W, float* dimages, double* loss) {
    g->part_first = first;
    g->part_total = total;
    mlb_status s = be ? g->loss_on(g, be, stage, step, views, n, images, H, W, dimages, loss)
                      : g->loss(g, stage, step, views, n, images, H, W, dimages, loss);
    g->part_first = g->part_total = 0;
    return s;
}

// The micro-batch size for a step of n views: g->view_batch, or n when it is 0 or larger.
static inline int mlb_guidance_batch(const mlb_guidance* g, int n) {
    return g->view_batch > 0 && g->view_batch < n ? g->view_batch : n;
}

// Guides views [first, first + count) of a step of n views (whole micro-batches: first a multiple
// of the batch size, as mlb_dist_share_batches gives a process its share), one loss call per
// batch. images, dimages [n, H, W, 4]: the whole step's (dimages may be NULL), host buffers, or on
// be's device when be is given (g->loss_on); losses[b] = the loss of batch b of the step's
// ceil(n / batch), written for this range's batches only.
static inline mlb_status mlb_guidance_loss_batches(mlb_guidance* g, const struct mlb_backend* be, mlb_stage stage,
                                                   long step, const mlb_view* views, int n, int first, int count,
                                                   const float* images, int H, int W, float* dimages, double* losses) {
    const int k = mlb_guidance_batch(g, n);
    const size_t img = (size_t)H * W * 4;
    mlb_status s = MLB_OK;
    for (int v = first; !s && v < first + count; v += k) {
        int m = first + count - v < k ? first + count - v : k;
        s = mlb_guidance_loss_part(g, be, stage, step, views + v, v, m, n, images + img * (size_t)v, H, W,
                                   dimages ? dimages + img * (size_t)v : NULL, &losses[v / k]);
    }
    return s;
}

static inline void mlb_guidance_free(mlb_guidance* g) {
    if (g && g->destroy) g->destroy(g);
}

#endif
