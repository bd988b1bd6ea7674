// End-to-end geometry fit (docs/geometry_fit.md): the geometry network (geometry.h) is fitted to
// multi-view silhouettes and normal maps of a target mesh through the whole differentiable chain
//   network → sdf + deformation at the tet-grid vertices → marching tets → vertex normals →
//   clip space → rasterize → interpolate [normal, 1] → antialias → (box downsample) → L2 image loss
// plus the SDF sign regulariser (weight 0.2 → 0.01 linearly by 25% of the iterations, reference.md
// §3), backward all the way to the network's parameters, and Adam.
//
// Images are [H, W, 4]: world-space interpolated vertex normals (not renormalised) and the coverage
// mask, antialiased together, background 0. The target is rendered with the very same pipeline.
// The loss of one step is
//   L = Σ_views Σ_pixels (w_normal Σ_{c<3} (o_c − t_c)² + w_mask (o_3 − t_3)²) / (views · H · W)
//       + λ(it) · sdf_reg.
// Cameras: orbit (radius 3, fovy 45°, azimuth U(−180, 180), elevation U(−10, 45)) drawn from the
// counter RNG (seed, stream 0x6F17, index it·views + v): the same on any thread count.
// The step functions exist in float (plain names) and double (_f64, for finite-difference tests).
#ifndef MATLABER_GEOMETRY_FIT_H
#define MATLABER_GEOMETRY_FIT_H
#include <stdint.h>
#include "matlaber/dmtet.h"
#include "matlaber/error.h"
#include "matlaber/geometry.h"
#include "matlaber/mesh.h"
#include "matlaber/progress.h"
#include "matlaber/raster.h"

typedef struct {
    int iters;            // Adam steps, default 300
    int views;            // cameras per step, default 2
    int res;              // image size (square), default 64
    int ss;               // supersampling factor (render at res·ss, box-downsample), default 1
    int cells;            // tet-grid cells per axis, default 32 (the "64" grid)
    double lr;            // Adam learning rate (mlb_geometry_adam), default 1e-2
    double w_normal;      // weight of the normal channels, default 1
    double w_mask;        // weight of the mask channel, default 1
    double reg_start;     // SDF regulariser weight at step 0, default 0.2
    double reg_end;       // ... reached at reg_frac·iters and kept, default 0.01
    double reg_frac;      // default 0.25
    double radius;        // camera distance, default 3
    double fovy_deg;      // default 45
    double el_min, el_max;   // elevation range in degrees, default −10, 45
    uint64_t seed;        // camera seed, default 1
} mlb_geofit_config;

mlb_geofit_config mlb_geofit_default(void);
// λ(it) = reg_start + (reg_end − reg_start)·min(1, it / (reg_frac·iters)).
double mlb_geofit_reg_weight(const mlb_geofit_config* c, int it);
// The camera of view v at step it (aspect 1, near 0.1, far 100).
mlb_status mlb_geofit_camera(mlb_camera* cam, const mlb_geofit_config* c, int it, int view);

// What one step measured.
typedef struct {
    double loss;          // img + reg_weight·reg
    double img;           // the image term
    double reg;           // the SDF regulariser (unweighted)
    int n_verts, n_faces; // the extracted surface
    uint64_t coverage;    // a hash of every view's face ids (changes when the coverage changes)
} mlb_geofit_stats;

// Called after every step (may be NULL in the fit). Returning nonzero stops the fit early.
typedef int (*mlb_geofit_step_fn)(void* user, int it, const mlb_geofit_stats* st);

#define MLB_GEOFIT_DECLARE(R, N)                                                                     \
    /* out[res, res, 4] = [normal, mask] of a float mesh (normals: area-weighted vertex normals)  \
       seen by cam: rasterize at res·ss, interpolate, antialias, downsample. ctx may be NULL. */   \
    mlb_status N(mlb_geofit_render_mesh)(mlb_raster_ctx* ctx, R* out, const mlb_mesh* m,            \
                                         const mlb_camera* cam, int res, int ss);                   \
    /* The loss of the network's surface (on grid g, deformation tanh(d)/(2·cells)) against        \
       targets[v·res·res·4] seen by cams[v], v < n_views, with regulariser weight reg_weight.     \
       backward != 0: net->grads += ∂L/∂params (zero them first). An empty surface is an error.  */ \
    mlb_status N(mlb_geofit_loss)(N(mlb_geometry_net)* net, const mlb_tetgrid* g, mlb_raster_ctx* ctx, \
                                  const mlb_camera* cams, int n_views, const R* targets, int res, int ss, \
                                  double w_normal, double w_mask, double reg_weight, int backward,  \
                                  mlb_geofit_stats* st);

#define MLB_GEOFIT_F32(name) name
#define MLB_GEOFIT_F64(name) name##_f64
MLB_GEOFIT_DECLARE(float, MLB_GEOFIT_F32)
MLB_GEOFIT_DECLARE(double, MLB_GEOFIT_F64)
#undef MLB_GEOFIT_F32
#undef MLB_GEOFIT_F64

// The fit: c->iters steps of random views of `target` (a float mesh already placed in the grid
// box; its normals are recomputed), each zero_grad → loss + backward → Adam. The network's
// config decides the encoding; the grid is c->cells cells over net->cfg.scale. progress and
// step_fn may be NULL. last (may be NULL) gets the final step's stats.
mlb_status mlb_geometry_fit_images(mlb_geometry_net* net, const mlb_mesh* target, const mlb_geofit_config* c,
                                   mlb_progress* progress, mlb_geofit_step_fn step_fn, void* user,
                                   mlb_geofit_stats* last);

#endif
