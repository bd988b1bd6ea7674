// The neural field both stages of the method train (reference.md §3, §7; paper §3.3, §3.4): a
// multiresolution hash encoding of a point in the grid box ([−0.5, 0.5]^3 × scale, mapped to
// [0,1]^3) feeds an MLP with ReLU hidden layers. What its outputs mean is the field's kind:
//   geometry (geometry.h): 4 outputs, the SDF and a deformation; no biases, linear output;
//   material (material_net.h), latent mode: a latent code z ∈ R^4, decoded by the BRDF prior's
//     FROZEN decoder (copied into the field) into k = (kd, ks, kr) in the decoder's output ranges;
//   material, direct mode (ablation): k itself, through a sigmoid and the same ranges.
// One allocation holds the trained parameters [hash table | MLP]; grads and Adam moments share the
// layout. Backward ACCUMULATES into grads. The MLPs run over fixed 1024-row shards (OpenMP over
// shards, the shards' gradients summed in order), so every result is bitwise the same on any
// thread count. Coarse to fine: levels >= active_levels give zero features and get no gradient.
//
// Exists as float (plain names) and double (name_f64, for the finite-difference tests). A float
// field can run on another device (field_use_device, src/field/field_device.c); a double one stays
// on the host.
#ifndef MATLABER_FIELD_H
#define MATLABER_FIELD_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/backend.h"
#include "matlaber/brdf_ae.h"
#include "matlaber/error.h"
#include "matlaber/hashgrid.h"
#include "matlaber/nn.h"
#include "matlaber/safetensors.h"

typedef enum { MLB_FIELD_GEOMETRY = 0, MLB_FIELD_MATERIAL = 1 } mlb_field_kind;
typedef enum { MLB_MATERIAL_LATENT = 0, MLB_MATERIAL_DIRECT = 1 } mlb_material_mode;

typedef struct {
    mlb_field_kind kind;
    mlb_hashgrid_config enc;   // default mlb_hashgrid_default(): 16 levels × 2, T = 2^19, base 16
    int hidden;                // MLP width, default 32
    int n_hidden;              // hidden layers, default 2 (n_hidden + 1 linear layers)
    float scale;               // the grid box is [−0.5, 0.5]^3 × scale, default 2.1
    mlb_material_mode mode;    // material fields: latent (default) or direct; geometry ignores it
    uint64_t seed;             // initialisation seed, default 1
} mlb_field_config;

// The output width of a field of this config: 4 (geometry) or 7 (material: k).
static inline int mlb_field_out_dim(const mlb_field_config* c) { return c->kind == MLB_FIELD_GEOMETRY ? 4 : 7; }

#define MLB_FIELD_DECLARE(R, N)                                                                     \
    typedef struct {                                                                               \
        mlb_field_config cfg;                                                                      \
        N(mlb_hashgrid) enc;                                                                       \
        N(mlb_mlp) mlp;              /* L·F → hidden^n_hidden → 4 (geometry, latent) or 7 */       \
        N(mlb_mlp) dec;              /* latent mode: the prior's decoder 4 → … → 7 (frozen) */     \
        size_t n_enc, n_mlp, n_params;                                                             \
        R* params;                   /* [n_params]: table then MLP (the trained parameters) */     \
        R* grads;                                                                                   \
        R* adam_m;                                                                                  \
        R* adam_v;                                                                                  \
        R* dec_params;               /* the decoder's weights (not trained) */                      \
        long step;                   /* optimiser steps taken */                                    \
        int active_levels;           /* coarse to fine: 0 = every level */                          \
        /* forward cache of the last forward's n points */                                          \
        int n, capacity;                                                                            \
        R *x, *feat, *out, *y, *dfeat, *dout, *dy;                                                 \
        N(mlb_mlp_cache) cache, dec_cache;                                                         \
        R* shard_grads;              /* [shards, n_mlp]: the MLP's gradient per batch shard */      \
        struct mlb_field_device* dev; /* field_use_device (float only); NULL: the host */           \
    } N(mlb_field);                                                                                \
    /* Allocates and initialises (table U(±1e-4), Glorot MLP weights, zero biases) from cfg->seed.  \
       A latent-mode material field needs the prior (its decoder is copied); else it may be NULL. */ \
    mlb_status N(field_init)(N(mlb_field)* f, const mlb_field_config* cfg, const mlb_brdf_ae* prior); \
    void N(field_free)(N(mlb_field)* f);       /* safe on a zeroed field */                         \
    void N(field_zero_grad)(N(mlb_field)* f);                                                      \
    /* pos [n,3] in world units → y [n, out_dim] (may be NULL) and, latent mode, the codes z [n,4]   \
       (may be NULL). Caches what backward needs. */                                               \
    mlb_status N(field_forward)(N(mlb_field)* f, R* y, R* z, const R* pos, int n);                  \
    /* grads += ∂(Σ dy·y)/∂params over the last forward's points; dpos (may be NULL) += ∂/∂pos. */ \
    mlb_status N(field_backward)(N(mlb_field)* f, const R* dy, R* dpos);                            \
    /* The same with dz [n,4] (may be NULL) added at the codes (latent mode; MLB_ERR_ARG otherwise): \
       a term on z itself (the material prior's support, appearance.h); dy NULL: no term on y.    */ \
    mlb_status N(field_backward_latent)(N(mlb_field)* f, const R* dy, const R* dz, R* dpos);         \
    mlb_status N(field_update)(N(mlb_field)* f, const mlb_adam_config* adam);                      \
    /* Inference without the field's cache (thread-safe, chunked): y [n, out_dim] and z [n,4]       \
       (either may be NULL; z of a field without codes is MLB_ERR_ARG). */                          \
    mlb_status N(field_eval)(const N(mlb_field)* f, const R* pos, size_t n, R* y, R* z);            \
    /* Latent mode: the frozen decoder, z [n,4] → k [n,7] (MLB_ERR_ARG otherwise). */               \
    mlb_status N(field_decode)(const N(mlb_field)* f, const R* z, size_t n, R* k);

#define MLB_FIELD_F32(name) name
#define MLB_FIELD_F64(name) name##_f64
MLB_FIELD_DECLARE(float, MLB_FIELD_F32)
MLB_FIELD_DECLARE(double, MLB_FIELD_F64)
#undef MLB_FIELD_F32
#undef MLB_FIELD_F64

// ---- on a device (float fields; src/field/field_device.c) ----
// Moves the trained parameters, their gradients, the Adam moments and the frozen decoder to the
// device of `be` (backend.h), where field_forward/backward/zero_grad/update then run, the hash grid
// and the MLPs over the whole batch (no shards). Points and outputs cross as host arrays, or stay
// there (mlb_field_forward_on_device below).
// While there, the host's params, grads, adam_m and adam_v are behind: mlb_field_sync_host brings
// them up to date (checkpoints, the end of a stage); eval refuses a field whose host copy is
// behind. The CPU table is allowed (the same code on host memory: the CPU tests of this path).
// Coarse to fine (active_levels) runs there too: the table's hash grid over the active levels only.
mlb_status mlb_field_use_device(mlb_field* f, const mlb_backend* be);
mlb_status mlb_field_sync_host(mlb_field* f);        // params, grads, adam_m, adam_v to the host
mlb_status mlb_field_leave_device(mlb_field* f);     // syncs and frees the device copy
// The gradients (grads) to a host array and back, from or to the device where the field is there
// (on the host: a copy, nothing when the array is f->grads): the pipeline sums several processes'
// gradients on the host (docs/pipeline.md, "Several processes").
mlb_status mlb_field_grads_get(mlb_field* f, float* out);
mlb_status mlb_field_grads_set(mlb_field* f, const float* in);
const mlb_backend* mlb_field_backend(const mlb_field* f);   // NULL for a field on the host
// The forward and backward of a field on a device over buffers on that device (the appearance
// renderer's samples): pos [n,3] → y [n,7] (material; [n,4] geometry), the cache as
// field_forward's; the backward takes dy there and leaves the points' gradient uncomputed.
// MLB_ERR_ARG for a field on the host.
mlb_status mlb_field_forward_on_device(mlb_field* f, float* y, const float* pos, int n);
mlb_status mlb_field_backward_on_device(mlb_field* f, const float* dy);
// A double field is never on a device (the double pass has only the CPU's double table): its
// mlb_field_backend is NULL and the two calls above are MLB_ERR_UNSUPPORTED. They exist so that the
// models over a field (geometry_fit.c, appearance.c) are written once for both precisions.
typedef struct mlb_backend_f64 mlb_backend_f64;   // backend_f64.h
const mlb_backend_f64* mlb_field_backend_f64(const mlb_field_f64* f);
mlb_status mlb_field_forward_on_device_f64(mlb_field_f64* f, double* y, const double* pos, int n);
mlb_status mlb_field_backward_on_device_f64(mlb_field_f64* f, const double* dy);

// ---- files (float fields; src/field/field_io.c) ----
// Tensors "encoding.table" [entries, F], "mlp.N.weight" [out, in] (and "mlp.N.bias" with biases),
// "decoder.N.weight"/".bias" (latent mode) and, with_optimizer, "adam.m", "adam.v"; the config in
// metadata under `prefix` ("geometry" or "material": prefix.levels, .features, .table_size,
// .base_res, .per_level_scale, .hidden, .n_hidden, .scale, .seed; material: .mode and the
// decoder's .decoder_hidden, .decoder_depth, .decoder_activation; with_optimizer: .step) plus the
// caller's extra entries. Written atomically. A field on a device whose host copy is behind is
// MLB_ERR_ARG (mlb_field_sync_host first).
mlb_status mlb_field_save(const mlb_field* f, const char* path, int with_optimizer, const mlb_st_meta* extra,
                          size_t n_extra);
// Reads a field of `kind` back; every tensor's shape is checked against the metadata before
// anything is allocated. *f is overwritten (zeroed on failure); the optimizer state is restored
// when present.
mlb_status mlb_field_load(mlb_field* f, mlb_field_kind kind, const char* path);

#endif
