// The material network's defaults, inference entry points and files (float network); the network
// itself is src/pipeline/material_net.c (dual-compiled).
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/geometry.h"
#include "matlaber/material_net.h"

// The geometry field's defaults (encoding, MLP, grid box, seed): the two fields differ only in kind.
mlb_material_config mlb_material_default(void) {
    mlb_material_config c = mlb_geometry_default();
    c.kind = MLB_FIELD_MATERIAL;
    c.mode = MLB_MATERIAL_LATENT;
    return c;
}

// The geometry's Adam with the weight decay decoupled (AdamW), as the appearance stage names it.
mlb_adam_config mlb_material_adam(double lr) {
    mlb_adam_config a = mlb_geometry_adam(lr);
    a.decoupled = 1;
    return a;
}

mlb_status mlb_material_eval(const mlb_material_net* net, const float* pos, size_t n, float* k) {
    return material_net_eval(net, pos, n, k, NULL);
}

mlb_status mlb_material_eval_latent(const mlb_material_net* net, const float* pos, size_t n, float* z) {
    if (net->cfg.mode != MLB_MATERIAL_LATENT) return mlb_fail(MLB_ERR_ARG, "material network: direct mode has no latent codes");
    return material_net_eval(net, pos, n, NULL, z);
}

mlb_status mlb_material_decode(const mlb_material_net* net, const float* z, size_t n, float* k) {
    return material_net_decode(net, z, n, k);
}

// ---- files: the field format (src/field/field_io.c) under the prefix "material" ----------------------

mlb_status mlb_material_save(const mlb_material_net* net, const char* path, int with_optimizer) {
    return mlb_field_save(net, path, with_optimizer, NULL, 0);
}

mlb_status mlb_material_load(mlb_material_net* net, const char* path) { return mlb_field_load(net, MLB_FIELD_MATERIAL, path); }
