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
// The step is split into a forward (renders every view, keeps the buffers) and a backward from
// any image gradient (mlb_geofit_forward / _backward): the guided geometry stage drives it with a
// guidance (mlb_geometry_guided_step). Every GEMM is mlb_gemm and every sum runs in a fixed
// order, so a step is bitwise the same on any thread count.
// The step functions exist in float (plain names) and double (_f64, for finite-difference tests).
#ifndef MATLABER_GEOMETRY_FIT_H
#define MATLABER_GEOMETRY_FIT_H
#include <stdint.h>
#include "matlaber/backend_f64.h"
#include "matlaber/dmtet.h"
#include "matlaber/error.h"
#include "matlaber/geometry.h"
#include "matlaber/guidance.h"
#include "matlaber/mesh.h"
#include "matlaber/progress.h"
#include "matlaber/raster.h"

// The SDF sign regulariser's weight over a fit of `iters` steps (reference.md §3): `start` at step
// 0, falling linearly to `end` at frac·iters and kept there. The one definition the image fit
// (mlb_geofit_config) and the pipeline's geometry stage (mlb_pipeline_config) both embed.
typedef struct {
    double start;         // the weight at step 0, default 0.2
    double end;           // ... reached at frac·iters and kept, default 0.01
    double frac;          // default 0.25
} mlb_sdf_reg_schedule;
mlb_sdf_reg_schedule mlb_sdf_reg_default(void);
// λ(it) = start + (end − start)·min(1, it / (frac·iters)); `end` throughout when frac·iters is 0.
double mlb_sdf_reg_weight(const mlb_sdf_reg_schedule* r, long it, long iters);

typedef struct {
    int iters;            // Adam steps, default 300
    int views;            // cameras per step, default 2
    int res;              // image size (square), default 64
    int ss;               // supersampling factor (render at res·ss, box-downsample), default 1
    int cells;            // tet-grid cells per axis, default 32 (the "64" grid)
    double lr;            // Adam learning rate (mlb_geometry_adam), default 1e-2
    double w_normal;      // weight of the normal channels, default 1
    double w_mask;        // weight of the mask channel, default 1
    mlb_sdf_reg_schedule sdf_reg;   // the SDF regulariser's weight over the iters (mlb_sdf_reg_default)
    double radius;        // camera distance, default 3
    double fovy_deg;      // default 45
    double el_min, el_max;   // elevation range in degrees, default −10, 45
    uint64_t seed;        // camera seed, default 1
} mlb_geofit_config;

mlb_geofit_config mlb_geofit_default(void);
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
    /* What one forward keeps for its backward (and for previews / the final mesh). Zero-initialise \
       it ({0}), pass it to every forward and backward, free it with mlb_geofit_state_free. The  \
       fields are the step's internals: read surf (the extracted surface), images, n, res, ss.  */ \
    typedef struct {                                                                                \
        int ok;                      /* a forward is held: backward may run */                      \
        int n, res, ss, S;           /* views, output size, supersampling, S = res·ss */             \
        int n_grid;                  /* grid vertices of the last forward */                        \
        const mlb_tetgrid* grid;     /* borrowed from the forward */                               \
        N(mlb_mt_surface) surf;      /* the extracted surface of the last forward: its sizes; the   \
                                        arrays stay on the table, mlb_geofit_state_mesh brings them \
                                        down */                                                       \
        mlb_mat4* vp;                /* [n] the views' world → clip matrices */                    \
        R* images;                   /* [n, res, res, 4] the renders of the last forward */        \
        R *gv, *sdf, *deform;        /* [G,3], [G], [G,3]: the host's side of the grid's buffers on \
                                        the table (the grid's vertices; the network's outputs when \
                                        it is on the host) */                                        \
        /* on the table's device (be): */                                                            \
        int32_t* tri;                /* [n,S,S] */                                                  \
        R *bary, *depth, *img, *weights; /* [n,S,S,2], [n,S,S], [n,S,S,4], [n,S,S,2] */             \
        R *aa, *daa, *dimg, *dbary;  /* per-view scratch [S,S,4], [S,S,4], [S,S,4], [S,S,2] */      \
        struct N(geofit_table)* tab; /* private: the table's buffers and the table they are on */   \
        R *dsdf, *ddeform;           /* [G], [G,3]: their gradients, for a network on the host */   \
        R* pieces;                   /* [n, M, 6]: each view's share of the surface's gradients,   \
                                        on the host for the gather across processes */             \
        size_t cap_grid, cap_surf, cap_px, cap_views, cap_pieces;   /* allocated sizes */          \
        /* Set by the caller before the forward: this process renders views [part_first,            \
           part_first + part_count) only (dist.h; the others' images stay 0) and the backward       \
           gathers every view's piece from the other ranks, which hold whole batches of             \
           part_batch views (mlb_dist_share_batches; 0: one batch). part_count 0: every view (no    \
           gathers), -1: none. */                                                                   \
        int part_first, part_count, part_batch;                                                     \
        /* Set by the caller before the forward: the op table marching tets and the views' \
           rasterize, interpolate, antialias and their backwards run on (NULL: the CPU's,          \
           mlb_backend_cpu), with every per-pixel buffer there, and the surface's normals, clip     \
           coordinates, the edge topology and the gradients: the surface stays there (st->surf      \
           has its sizes), the images come down and the dimages go up unless images_on_table; the   \
           views' gradient pieces cross only between processes; mt holds marching tets' buffers   \
           there (the state's own). The double build's table is backend_f64.h's (the CPU's only),  \
           the grid's passes included. stats->coverage is measured on tables whose                  \
           buffers are host memory (the CPU's; else 0: it would need every face id on the host). */ \
        const N(mlb_backend)* be;                                                                   \
        mlb_mt_device* mt;                                                                          \
        /* Set by the caller before the forward: the renders stay on the table (t_images; st->images \
           is filled only when the forward is asked for images) for a guidance that reads them     \
           there (guidance.h loss_on), which adds its gradient into t_dimages (zeroed by the       \
           forward) for mlb_geofit_backward_table. [n, res, res, 4] each, on be's device.          */ \
        int images_on_table;                                                                        \
        R *t_images, *t_dimages;                                                                    \
    } N(mlb_geofit_state);                                                                          \
    void N(mlb_geofit_state_free)(N(mlb_geofit_state)* st);   /* safe on a zeroed state */          \
    /* The network's surface (on grid g, deformation tanh(d)/(2·cells)) seen by cams[v], v < n:      \
       images[v·res·res·4 ...] (may be NULL; the renders are in st->images either way) = [normal,    \
       mask] as mlb_geofit_render_mesh draws them. Keeps every view's buffers in st, and the        \
       network's forward cache (run nothing else on net before the backward). g is borrowed until \
       the backward. stats: n_verts, n_faces, coverage, reg (the unweighted SDF regulariser);       \
       img = loss = 0 (the caller's loss). An empty surface is an MLB_ERR_ARG error.              */ \
    mlb_status N(mlb_geofit_forward)(N(mlb_geofit_state)* st, N(mlb_geometry_net)* net, const mlb_tetgrid* g, \
                                     const mlb_camera* cams, int n, int res, int ss,                \
                                     R* images, mlb_geofit_stats* stats);                           \
    /* net->grads += ∂(Σ dimages·images + reg_weight·sdf_reg)/∂params for the last forward;          \
       dimages [n, res, res, 4] may be NULL (regulariser only). May repeat (gradients add).       */ \
    mlb_status N(mlb_geofit_backward)(N(mlb_geofit_state)* st, N(mlb_geometry_net)* net, const R* dimages, \
                                      double reg_weight);                                           \
    /* The same with the image gradient in st->t_dimages, on the table (images_on_table).       */ \
    mlb_status N(mlb_geofit_backward_table)(N(mlb_geofit_state)* st, N(mlb_geometry_net)* net, double reg_weight); \
    /* out[res, res, 4] = [normal, mask] of a float mesh (normals: area-weighted vertex normals)  \
       seen by cam: rasterize at res·ss, interpolate, antialias, downsample, with the raster ops of  \
       table be (NULL: the CPU's): the mesh, its normals and out stay host buffers, so be is the    \
       CPU's for now (docs/cuda.md). Each op allocates its own scratch (no mlb_raster_ctx).    */ \
    mlb_status N(mlb_geofit_render_mesh)(const N(mlb_backend)* be, R* out,                           \
                                         const mlb_mesh* m, const mlb_camera* cam, int res, int ss); \
    /* The L2 loss of the network's surface against targets[v·res·res·4] seen by cams[v],          \
       v < n_views, with regulariser weight reg_weight (forward + loss + backward above).          \
       backward != 0: net->grads += ∂L/∂params (zero them first). An empty surface is an error.  */ \
    mlb_status N(mlb_geofit_loss)(N(mlb_geometry_net)* net, const mlb_tetgrid* g,                  \
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

// One step of the geometry stage with any guidance (float): geometry_net_zero_grad → forward of
// the n = g->n_views views (views[v].cam) at res·ss → g->loss(MLB_STAGE_GEOMETRY, step) on the
// [n, res, res, 4] renders → backward (guidance gradient + reg_weight·sdf_reg). The caller then
// updates (geometry_net_update). stats: img = the guidance loss, reg, loss = img + reg_weight·reg,
// surface size, coverage hash. images_out (may be NULL) [n, res, res, 4] receives the renders
// (previews); the surface of this step stays in st->surf (mlb_geofit_state_mesh).
mlb_status mlb_geometry_guided_step(mlb_geofit_state* st, mlb_geometry_net* net, const mlb_tetgrid* grid,
                                    mlb_guidance* g, long step, const mlb_view* views, int res,
                                    int ss, double reg_weight, mlb_geofit_stats* stats, float* images_out);
// The surface of the state's last forward as a float mesh (positions and faces; MLB_ERR_ARG when
// no forward is held).
mlb_status mlb_geofit_state_mesh(const mlb_geofit_state* st, mlb_mesh* out);

#endif
