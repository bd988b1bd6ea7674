// The differentiable appearance renderer of the appearance stage (paper §3.4, docs/appearance.md):
// a FIXED mesh (the geometry stage's surface) shaded with the material network's BRDF under a
// rotated environment light of the run's pool, and the material smoothness regulariser.
//
// One render of n views (one optimisation step):
//   per view: clip = view_proj · pos → rasterize at S = res·ss → interpolate world position and
//             vertex normal per pixel → normalise the normal and turn it towards the camera (two-
//             sided, as mlb_render_shaded) → v = (eye − p)/|eye − p|
//   all views at once: k = material_net(p) at every covered pixel of every view (ONE batch; of
//             the part's views with a part set)
//   per view: split-sum shading (shade.h, Fresnel a->fresnel) under lights[view.env] rotated about
//             +y by view.env_rotation_deg (absolute: the light's own rotation is replaced) →
//             c = sRGB(clamp(L, 0, 1)) → [c·m, m] with m the 0/1 coverage (composite over black)
//             → antialias (colour and coverage together) → box downsample by ss
//   images [n, res, res, 4] = [sRGB colour · coverage, coverage]: the guidance.h convention.
// The clamp before sRGB: a displayed or VAE-encoded image cannot be brighter than white; pixels
// brighter than 1 in linear radiance (sun highlights) pass no gradient, as torch.clamp.
// Only the material receives gradients: the mesh, the cameras and the lights are constants.
//
// Exists as float (plain names) and double (_f64: the finite-difference tests run the whole
// chain in double; the envlight's texels stay float). Results do not depend on the thread count.
#ifndef MATLABER_APPEARANCE_H
#define MATLABER_APPEARANCE_H
#include <stdint.h>
#include "matlaber/backend_f64.h"
#include "matlaber/envmap.h"
#include "matlaber/error.h"
#include "matlaber/guidance.h"
#include "matlaber/material_net.h"
#include "matlaber/mesh.h"
#include "matlaber/shade.h"

#define MLB_APPEARANCE_DECLARE(R, N)                                                                  \
    /* The renderer's buffers, reused from step to step. Zero-initialise; mlb_appearance_free. */     \
    typedef struct {                                                                                 \
        mlb_fresnel fresnel;                     /* 0 = MLB_FRESNEL_PAPER (the paper's Fresnel) */     \
        struct N(mlb_appearance_state)* state;   /* private: the last render, kept for backward */    \
        /* A part of the step's views (dist.h: one micro-batch of a process's share): the render,   \
           the material network's forward and the backward cover views [part_first, part_first +   \
           part_count) only, their samples in one batch; the other views' images are left as they   \
           are. No collectives: the pipeline sums the parts' parameter gradients (docs/pipeline.md). \
           part_count 0: every view, -1: none. */                                                    \
        int part_first, part_count;                                                                  \
        /* The op table the whole render runs on, its buffers allocated there (NULL: the CPU's;   \
           the double build's is backend_f64.h's, the CPU's only): rasterize, the samples' gather,  \
           the material network (a net on a device must be on this table's; a net on the host needs \
           the CPU's), the shading, the composite and their backwards (docs/appearance.md). */       \
        const N(mlb_backend)* be;                                                                    \
        /* Set by the caller before the render: the renders stay on the table, t_images [n, res,    \
           res, 4] (images may be NULL then), for a guidance that reads them there (guidance.h      \
           loss_on) and adds its gradient into t_dimages (the part's views zeroed by the render)    \
           for mlb_appearance_backward_table. Filled by the render; on be's device. */              \
        int images_on_table;                                                                         \
        R *t_images, *t_dimages;                                                                     \
    } N(mlb_appearance);                                                                             \
    void N(mlb_appearance_free)(N(mlb_appearance)* a);   /* safe on a zeroed struct */               \
    /* Renders n views of mesh (positions, faces; vertex normals, computed when absent) with the      \
       material net: images [n, res, res, 4] (above). lights[views[i].env] must exist for every i.     \
       keep_for_backward: the net's forward cache holds this render's points (material_net_forward) \
       and mlb_appearance_backward may follow; 0: the net (on the host) is evaluated without         \
       touching its cache.                                                                           \
       The mesh and the lights must stay unchanged until the backward. */                           \
    mlb_status N(mlb_appearance_render)(N(mlb_appearance)* a, N(mlb_material_net)* net, const mlb_mesh* mesh, \
                                        const mlb_envlight* const* lights, const mlb_view* views, int n, int res, \
                                        int ss, R* images, int keep_for_backward);                  \
    /* dimages [n, res, res, 4] (of the last render, kept) → net->grads += ∂(Σ dimages·images)/∂params. \
       The net's cache must still be the render's (no material_net_forward in between). */          \
    mlb_status N(mlb_appearance_backward)(N(mlb_appearance)* a, N(mlb_material_net)* net, const R* dimages); \
    /* The same with the image gradient in a->t_dimages (a render with images_on_table). */           \
    mlb_status N(mlb_appearance_backward_table)(N(mlb_appearance)* a, N(mlb_material_net)* net);      \
    /* The last render's surface points [*n, 3] (covered samples of its views, view-major; NULL when  \
       none), on the render's table (a->be: host memory for the CPU's). Valid until the next render. */ \
    const R* N(mlb_appearance_points)(const N(mlb_appearance)* a, int* n);                           \
    /* Material smoothness (paper §3.4, nvdiffrec):                                                   \
         L = weight · mean_i (1/3) Σ_{c in kd} |k_c(x_i) − k_c(x_i + ε_i)|                             \
           + weight_spec · mean_i (1/4) Σ_{c in ks, kr} |k_c(x_i) − k_c(x_i + ε_i)|,  ε_i ~ N(0, σ² I)   \
       over pts [n,3] (world units), ε from Philox (seed, stream 0x5A17, index step·2^32 + 3i + c).    \
       The paper smooths kd only (weight_spec 0); nvdiffrec also smooths its specular texture, and   \
       noisy ks/roughness is what shows as speckle in relighting (docs/pipeline.md).                 \
       nvdiffrec's weight is 0.03 with sigma 0.01 (0.5% of the default 2.1 grid box). backward != 0: \
       net->grads += ∂L/∂params. Runs material_net_forward on 2n points, so it REPLACES the net's     \
       forward cache: call it after mlb_appearance_backward. *loss (may be NULL) receives L. */      \
    mlb_status N(mlb_material_smoothness)(N(mlb_material_net)* net, const R* pts, int n, double sigma,      \
                                          double weight, double weight_spec, uint64_t seed, long step,       \
                                          int backward, double* loss);                               \
    /* The term's share of points [first, first + count) of the n pts: its scales are the whole      \
       term's (1/n), its noise the whole term's for those points, so the shares of a partition give  \
       the whole loss and gradient as a sum (in another order: the whole is the one-share case).   \
       count 0: nothing (*loss 0). */                                                                \
    mlb_status N(mlb_material_smoothness_part)(N(mlb_material_net)* net, const R* pts, int n, int first,  \
                                               int count, double sigma, double weight,                  \
                                               double weight_spec, uint64_t seed, long step,           \
                                               int backward, double* loss);                             \
    /* The material prior's support (latent mode): score distillation at a high guidance scale     \
       pushes the codes far outside what the prior was trained on (|z| of its data: 99% below 4.2), \
       where the frozen decoder's sigmoids saturate (kd 1 or 0, roughness at its floor). Over the   \
       points [first, first + count) of pts [n,3]:                                                  \
         L = weight · (1/n) Σ_i max(0, |z(x_i)| − radius)²                                          \
       0 inside the ball. backward != 0: net->grads += ∂L/∂params. Replaces the net's forward       \
       cache, as the smoothness term does. *loss (may be NULL) receives L. */                       \
    mlb_status N(mlb_material_latent_support_part)(N(mlb_material_net)* net, const R* pts, int n, int first, \
                                                   int count, double radius, double weight,          \
                                                   int backward, double* loss);                      \
    /* Per-pixel material maps of one view for previews and evaluation (no gradients, the net's     \
       cache untouched): rasterize at res, evaluate the net at the covered pixels, antialias, and   \
       write (each may be NULL) kd [res,res,3], ks [res,res,3], kr [res,res] and the shading normal \
       [res,res,3] (world space, unit, turned towards the camera), all linear and premultiplied by  \
       the antialiased coverage (background 0). The raster ops run on table be (NULL: the CPU's);    \
       the mesh and the maps are host buffers, so be is the CPU's for now (docs/cuda.md "The        \
       renderer on the op table"). */                                                                \
    mlb_status N(mlb_appearance_maps)(const N(mlb_backend)* be, const N(mlb_material_net)* net,       \
                                      const mlb_mesh* mesh, const mlb_view* view, int res, R* kd_img, \
                                      R* ks_img, R* kr_img, R* normal_img);

#define MLB_APPEARANCE_F32(name) name
#define MLB_APPEARANCE_F64(name) name##_f64
MLB_APPEARANCE_DECLARE(float, MLB_APPEARANCE_F32)
MLB_APPEARANCE_DECLARE(double, MLB_APPEARANCE_F64)
#undef MLB_APPEARANCE_F32
#undef MLB_APPEARANCE_F64

#endif
