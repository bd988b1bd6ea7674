// The material network: a field (src/field/field.c) whose outputs are k = (kd, ks, kr), through the
// BRDF prior's frozen decoder (latent mode) or directly (include/matlaber/material_net.h,
// docs/appearance.md). Dual-compiled (float / double _f64), see core/real.h.
#include "matlaber/material_net.h"
#include "core/real.h"

mlb_status FN(material_net_init)(FN(mlb_material_net)* net, const mlb_material_config* cfg, const mlb_brdf_ae* prior) {
    mlb_field_config c = *cfg;
    c.kind = MLB_FIELD_MATERIAL;
    return FN(field_init)(net, &c, prior);
}

void FN(material_net_free)(FN(mlb_material_net)* net) { FN(field_free)(net); }
void FN(material_net_zero_grad)(FN(mlb_material_net)* net) { FN(field_zero_grad)(net); }

mlb_status FN(material_net_forward)(FN(mlb_material_net)* net, real* k, real* z, const real* pos, int n) {
    return FN(field_forward)(net, k, z, pos, n);
}

mlb_status FN(material_net_backward)(FN(mlb_material_net)* net, const real* dk, real* dpos) {
    return FN(field_backward)(net, dk, dpos);
}

mlb_status FN(material_net_update)(FN(mlb_material_net)* net, const mlb_adam_config* adam) {
    return FN(field_update)(net, adam);
}

mlb_status FN(material_net_eval)(const FN(mlb_material_net)* net, const real* pos, size_t n, real* k, real* z) {
    return FN(field_eval)(net, pos, n, k, z);   // z of a direct-mode net: MLB_ERR_ARG
}

mlb_status FN(material_net_decode)(const FN(mlb_material_net)* net, const real* z, size_t n, real* k) {
    return FN(field_decode)(net, z, n, k);
}
