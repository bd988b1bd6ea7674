// The material network of the appearance stage (paper §3.4): a multiresolution hash encoding of the
// surface point (the grid box [−0.5, 0.5]^3 × scale mapped to [0,1]^3) feeds a small MLP that
// predicts, per point,
//   latent mode (the paper):  a latent code z ∈ R^4, decoded by the FROZEN decoder of the BRDF prior
//                             into k = (kd, ks, kr) — the material space of brdf_ae.h;
//   direct mode (ablation):   the 7-d BRDF itself, through the same sigmoid-and-affine output map as
//                             the decoder (kd, ks ∈ [0, 1], kr ∈ [0.08, 1]), without the prior.
// Only the encoding and the MLP are trained (AdamW); the decoder's weights are a copy of the prior's,
// kept inside the network (and its file) so that a run is self-contained.
//
// Exists as float (plain names) and double (name_f64, for the finite-difference tests), like
// geometry.h. Backward ACCUMULATES into net->grads. The MLPs run over fixed 1024-row shards with
// single-threaded GEMMs (OpenMP over shards, shard gradients summed in order), so forward, backward
// and eval are bitwise the same on any thread count. Design and numbers: docs/appearance.md.
#ifndef MATLABER_MATERIAL_NET_H
#define MATLABER_MATERIAL_NET_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/backend.h"
#include "matlaber/brdf_ae.h"
#include "matlaber/error.h"
#include "matlaber/hashgrid.h"
#include "matlaber/nn.h"
#include "matlaber/safetensors.h"

typedef enum { MLB_MATERIAL_LATENT = 0, MLB_MATERIAL_DIRECT = 1 } mlb_material_mode;

typedef struct {
    mlb_hashgrid_config enc;   // default: 16 levels × 2 features, T = 2^19, base resolution 16
    int hidden;                // MLP width, default 32
    int n_hidden;              // hidden layers, default 2
    float scale;               // grid box [−0.5, 0.5]^3 × scale, default 2.1 (the geometry's)
    mlb_material_mode mode;    // default MLB_MATERIAL_LATENT
    uint64_t seed;             // initialisation seed, default 1
} mlb_material_config;

mlb_material_config mlb_material_default(void);
const char* mlb_material_mode_name(mlb_material_mode m);          // "latent" / "direct"
mlb_status mlb_material_mode_parse(const char* text, mlb_material_mode* out);
// AdamW of the appearance stage (reference.md §7): betas (0.9, 0.99), eps 1e-15, weight decay 0.
mlb_adam_config mlb_material_adam(double lr);

#define MLB_MATERIAL_DECLARE(R, N)                                                                  \
    typedef struct {                                                                               \
        mlb_material_config cfg;                                                                   \
        N(mlb_hashgrid) enc;                                                                       \
        N(mlb_mlp) mlp;              /* L·F → hidden^n_hidden → 4 (latent) or 7 (direct) */        \
        N(mlb_mlp) dec;              /* latent mode: the prior's decoder 4 → … → 7 (frozen) */     \
        size_t n_enc, n_mlp, n_params;                                                             \
        R* params;                   /* [n_params]: table then MLP (the trained parameters) */     \
        R* grads;                                                                                   \
        R* adam_m;                                                                                  \
        R* adam_v;                                                                                  \
        R* dec_params;               /* the decoder's weights (not trained) */                      \
        long step;                   /* optimiser steps taken */                                    \
        /* forward cache of the last forward's n points */                                          \
        int n, capacity;                                                                            \
        R *x, *feat, *out, *k, *dfeat, *dout, *dk;                                                 \
        N(mlb_mlp_cache) cache, dec_cache;                                                         \
        R* shard_grads;              /* [shards, n_mlp]: the MLP's gradient per batch shard */      \
        struct mlb_material_device* dev; /* mlb_material_net_use_device (float only); NULL: the CPU */ \
    } N(mlb_material_net);                                                                         \
    /* Latent mode needs the prior (its decoder is copied); direct mode ignores it (may be NULL). */ \
    mlb_status N(material_net_init)(N(mlb_material_net)* net, const mlb_material_config* cfg,     \
                                    const mlb_brdf_ae* prior);                                     \
    void N(material_net_free)(N(mlb_material_net)* net);      /* safe on a zeroed net */          \
    void N(material_net_zero_grad)(N(mlb_material_net)* net);                                      \
    /* pos [n,3] world units → k [n,7] (kd rgb, ks rgb, kr); z [n,4] (latent mode, may be NULL).    \
       Caches what backward needs. */                                                              \
    mlb_status N(material_net_forward)(N(mlb_material_net)* net, R* k, R* z, const R* pos, int n);  \
    /* grads += ∂(Σ dk·k)/∂params over the last forward's points. dpos (may be NULL) += ∂/∂pos. */  \
    mlb_status N(material_net_backward)(N(mlb_material_net)* net, const R* dk, R* dpos);           \
    mlb_status N(material_net_update)(N(mlb_material_net)* net, const mlb_adam_config* adam);      \
    /* Inference without the net's cache (thread-safe, chunked): pos [n,3] → k [n,7] and, latent   \
       mode, z [n,4] (either may be NULL; z in direct mode is MLB_ERR_ARG). */                      \
    mlb_status N(material_net_eval)(const N(mlb_material_net)* net, const R* pos, size_t n, R* k, R* z); \
    /* Latent mode: the frozen decoder, z [n,4] → k [n,7] (MLB_ERR_ARG in direct mode). */          \
    mlb_status N(material_net_decode)(const N(mlb_material_net)* net, const R* z, size_t n, R* k);

#define MLB_MATERIAL_F32(name) name
#define MLB_MATERIAL_F64(name) name##_f64
MLB_MATERIAL_DECLARE(float, MLB_MATERIAL_F32)
MLB_MATERIAL_DECLARE(double, MLB_MATERIAL_F64)
#undef MLB_MATERIAL_F32
#undef MLB_MATERIAL_F64

// ---- on a device (float nets; src/pipeline/material_net_device.c) ----
// Moves the trained parameters, their gradients, the Adam moments and the frozen decoder to the
// device of `be` (backend.h), where material_net_forward/backward/zero_grad/update then run, the
// hash grid and the MLPs over the whole batch (no shards). Points and k still cross as host arrays.
// While there, the host's params, grads, adam_m and adam_v are behind: mlb_material_net_sync_host
// brings them up to date (checkpoints, the end of a stage); eval refuses a net whose host copy is
// behind. The CPU table is allowed (the same code on host memory: the CPU tests of this path).
mlb_status mlb_material_net_use_device(mlb_material_net* net, const mlb_backend* be);
// Copies params, grads, adam_m and adam_v from the device to the host arrays (no-op on the host).
mlb_status mlb_material_net_sync_host(mlb_material_net* net);
// Syncs and frees the device copy: the net is a host net again.
mlb_status mlb_material_net_leave_device(mlb_material_net* net);
// The table the net runs on: NULL for a host net.
const mlb_backend* mlb_material_net_backend(const mlb_material_net* net);

// Inference without touching the net's cache (thread-safe, chunked): pos [n,3] → k [n,7].
mlb_status mlb_material_eval(const mlb_material_net* net, const float* pos, size_t n, float* k);
// Latent mode: the codes z [n,4] at pos (MLB_ERR_ARG in direct mode).
mlb_status mlb_material_eval_latent(const mlb_material_net* net, const float* pos, size_t n, float* z);
// Decodes latent codes with the net's frozen decoder: z [n,4] → k [n,7].
mlb_status mlb_material_decode(const mlb_material_net* net, const float* z, size_t n, float* k);

// Files: tensors "encoding.table", "mlp.N.weight"/"mlp.N.bias", "decoder.N.weight"/".bias" (latent
// mode) and, with_optimizer, "adam.m", "adam.v" plus metadata "material.step"; the config in
// metadata ("material.mode", ".levels", ".features", ".table_size", ".base_res", ".per_level_scale",
// ".hidden", ".n_hidden", ".scale"). Written atomically.
mlb_status mlb_material_save(const mlb_material_net* net, const char* path, int with_optimizer);
// *net overwritten (zeroed on failure); optimizer state restored when present.
mlb_status mlb_material_load(mlb_material_net* net, const char* path);

#endif
