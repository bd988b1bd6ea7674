// Shared by tests/test_material_net.c and tests/test_appearance.c (not itself a test).
#ifndef MATLABER_MATERIAL_TEST_UTIL_H
#define MATLABER_MATERIAL_TEST_UTIL_H
#include "matlaber/material_net.h"
#include "matlaber/rng.h"

// A randomly initialised prior of a small shape (the trained one is not needed for gradients).
static inline int random_prior(mlb_brdf_ae* ae) {
    return brdf_ae_init(ae, &(mlb_brdf_ae_config){16, 2, MLB_ACT_SILU}, 3) == MLB_OK;
}

// Table values of order 1 and random biases, so that every part of the chain carries gradient.
static inline void randomize_f64(mlb_material_net_f64* net, uint64_t seed) {
    for (size_t i = 0; i < net->n_enc; i++) net->params[i] = 0.5 * mlb_rng_normal_f64(seed, 1, i);
    for (int l = 0; l < net->mlp.n_layers; l++)
        for (int j = 0; j < net->mlp.dims[l + 1]; j++) net->mlp.bias[l][j] = 0.3 * mlb_rng_normal_f64(seed, 2, 100 * l + j);
}

#endif
