// Shared by tests/test_material_net.c and tests/test_appearance.c (not itself a test).
#ifndef MATLABER_MATERIAL_TEST_UTIL_H
#define MATLABER_MATERIAL_TEST_UTIL_H
#include "matlaber/material_net.h"
#include "matlaber/rng.h"
#include "cuda_test_util.h"

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

// Two copies of one random network in `mode`, one on the host and one moved to `be`'s device:
// forward (k, z), backward with dpos onto random starting values, and AdamW (eps 1e-4: smooth in the
// gradient) for 3 steps over n points, compared by relative L2 within tol; dpos point by point
// (CHECK_POINTWISE: a ReLU flipped by rounding changes one point's dpos entirely). The loss is
// ½|k − 0.5|² (dk = k − 0.5 from the host's k), a coherent gradient: with random dk the parameter
// gradient would be a sum of n cancelling terms that one flipped point moves by 1/√n.
static inline void material_twin_check(const mlb_backend* be, mlb_material_mode mode, int n, double tol) {
    mlb_brdf_ae prior;
    REQUIRE(random_prior(&prior));
    mlb_material_config c = mlb_material_default();
    c.enc = (mlb_hashgrid_config){6, 2, 1 << 12, 4, 1.6};
    c.hidden = 16;
    c.mode = mode;
    mlb_material_net net[2];
    for (int t = 0; t < 2; t++) {
        REQUIRE(material_net_init(&net[t], &c, &prior) == MLB_OK);
        for (size_t i = 0; i < net[t].n_enc; i++) net[t].params[i] = 0.4f * mlb_rng_normal(31, 0, i);
    }
    REQUIRE(mlb_material_net_use_device(&net[1], be) == MLB_OK);
    size_t N = (size_t)n;
    float *pos = malloc(sizeof(float) * 3 * N), *dk = malloc(sizeof(float) * 7 * N);
    float *k[2], *z[2], *dpos[2];
    for (int t = 0; t < 2; t++) {
        k[t] = malloc(sizeof(float) * 7 * N);
        z[t] = malloc(sizeof(float) * 4 * N);
        dpos[t] = malloc(sizeof(float) * 3 * N);
    }
    for (size_t i = 0; i < 3 * N; i++) pos[i] = 1.6f * (mlb_rng_uniform(32, 0, i) - 0.5f);
    mlb_adam_config adam = mlb_material_adam(1e-2);
    adam.eps = 1e-4;
    int latent = mode == MLB_MATERIAL_LATENT;
    for (int it = 0; it < 3; it++) {
        for (int t = 0; t < 2; t++) {
            for (size_t i = 0; i < 3 * N; i++) dpos[t][i] = mlb_rng_normal(33, 0, i);   // backward accumulates
            material_net_zero_grad(&net[t]);
            REQUIRE(material_net_forward(&net[t], k[t], latent ? z[t] : NULL, pos, n) == MLB_OK);
        }
        for (size_t i = 0; i < 7 * N; i++) dk[i] = k[0][i] - 0.5f;
        for (int t = 0; t < 2; t++) REQUIRE(material_net_backward(&net[t], dk, dpos[t]) == MLB_OK);
        CHECK_PARITY("k", k[1], k[0], 7 * N, tol);
        if (latent) CHECK_PARITY("z", z[1], z[0], 4 * N, tol);
        for (size_t i = 0; i < 3 * N; i++) {   // the increments
            float start = mlb_rng_normal(33, 0, i);
            dpos[0][i] -= start;
            dpos[1][i] -= start;
        }
        CHECK_POINTWISE("dpos", dpos[1], dpos[0], N, 3, 100 * tol, 1e-3);
        REQUIRE(mlb_material_net_sync_host(&net[1]) == MLB_OK);
        CHECK_PARITY("gradient", net[1].grads, net[0].grads, net[0].n_params, 10 * tol);
        for (int t = 0; t < 2; t++) REQUIRE(material_net_update(&net[t], &adam) == MLB_OK);
    }
    REQUIRE(mlb_material_net_sync_host(&net[1]) == MLB_OK);
    CHECK_PARITY("parameters after 3 steps", net[1].params, net[0].params, net[0].n_params, tol);
    CHECK_PARITY("Adam first moments", net[1].adam_m, net[0].adam_m, net[0].n_params, 10 * tol);
    CHECK(net[1].step == 3);
    // synced: eval on the host agrees; a bad point count is the same error on both
    REQUIRE(mlb_material_eval(&net[1], pos, 8, k[1]) == MLB_OK);
    REQUIRE(mlb_material_eval(&net[0], pos, 8, k[0]) == MLB_OK);
    CHECK_PARITY("eval of the synced host copy", k[1], k[0], 7 * 8, tol);
    for (int t = 0; t < 2; t++) CHECK(material_net_forward(&net[t], k[t], NULL, pos, 0) == MLB_ERR_ARG);
    for (int t = 0; t < 2; t++) {
        material_net_free(&net[t]);
        free(k[t]); free(z[t]); free(dpos[t]);
    }
    free(pos); free(dk);
    brdf_ae_free(&prior);
}

#endif
