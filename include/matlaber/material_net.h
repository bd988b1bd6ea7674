// The material network of the appearance stage (paper §3.4): a field (field.h) of kind
// MLB_FIELD_MATERIAL. A multiresolution hash encoding of the surface point feeds a small MLP that
// predicts, per point,
//   latent mode (the paper):  a latent code z ∈ R^4, decoded by the FROZEN decoder of the BRDF prior
//                             into k = (kd, ks, kr) — the material space of brdf_ae.h;
//   direct mode (ablation):   the 7-d BRDF itself, through the same sigmoid-and-affine output map as
//                             the decoder (kd, ks ∈ [0, 1], kr ∈ [0.08, 1]), without the prior.
// Only the encoding and the MLP are trained (AdamW); the decoder's weights are a copy of the prior's,
// kept inside the network (and its file) so that a run is self-contained.
//
// mlb_material_net is an mlb_field: layout, cache, optimiser state, thread-count independence, the
// device path (mlb_field_use_device) and the file format are the field's. Float (plain names) and
// double (name_f64, for the finite-difference tests). Design and numbers: docs/appearance.md.
#ifndef MATLABER_MATERIAL_NET_H
#define MATLABER_MATERIAL_NET_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/brdf_ae.h"
#include "matlaber/error.h"
#include "matlaber/field.h"

typedef mlb_field_config mlb_material_config;
typedef mlb_field mlb_material_net;
typedef mlb_field_f64 mlb_material_net_f64;

// 16 levels × 2 features, T = 2^19, base 16; hidden 32 × 2; scale 2.1 (the geometry's); latent; seed 1
mlb_material_config mlb_material_default(void);
const char* mlb_material_mode_name(mlb_material_mode m);          // "latent" / "direct"
mlb_status mlb_material_mode_parse(const char* text, mlb_material_mode* out);
// AdamW of the appearance stage (reference.md §7): betas (0.9, 0.99), eps 1e-15, weight decay 0.
mlb_adam_config mlb_material_adam(double lr);

#define MLB_MATERIAL_DECLARE(R, N)                                                                  \
    /* Latent mode needs the prior (its decoder is copied); direct mode ignores it (may be NULL).    \
       The kind is set to material whatever cfg says. */                                            \
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

// Inference without touching the net's cache (thread-safe, chunked): pos [n,3] → k [n,7].
mlb_status mlb_material_eval(const mlb_material_net* net, const float* pos, size_t n, float* k);
// Latent mode: the codes z [n,4] at pos (MLB_ERR_ARG in direct mode).
mlb_status mlb_material_eval_latent(const mlb_material_net* net, const float* pos, size_t n, float* z);
// Decodes latent codes with the net's frozen decoder: z [n,4] → k [n,7].
mlb_status mlb_material_decode(const mlb_material_net* net, const float* z, size_t n, float* k);

// Files: the field format (field.h) under the prefix "material": tensors "encoding.table",
// "mlp.N.weight"/"mlp.N.bias", "decoder.N.weight"/".bias" (latent mode) and, with_optimizer,
// "adam.m", "adam.v" plus metadata "material.step"; the config in metadata ("material.mode",
// ".levels", ".features", ".table_size", ".base_res", ".per_level_scale", ".hidden", ".n_hidden",
// ".scale", ".seed"). Written atomically. A net on a device whose host copy is behind is
// MLB_ERR_ARG (mlb_field_sync_host first).
mlb_status mlb_material_save(const mlb_material_net* net, const char* path, int with_optimizer);
// *net overwritten (zeroed on failure); optimizer state restored when present.
mlb_status mlb_material_load(mlb_material_net* net, const char* path);

#endif
