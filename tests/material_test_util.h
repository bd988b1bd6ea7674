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

// Two copies of one random field (kind; mode for materials), one on the host and one moved to
// `be`'s device: forward (y, z), backward with dpos onto random starting values (latent mode: with a term on
// the codes from the second step, dy NULL in the third), and AdamW (eps
// 1e-4: smooth in the gradient) for 3 steps over n points (the first coarse to fine, 3 of 6 levels), compared by relative L2 within tol;
// dpos point by point (CHECK_POINTWISE: a ReLU flipped by rounding changes one point's dpos
// entirely). The loss is ½|y − 0.5|² (dy = y − 0.5 from the host's y), a coherent gradient: with
// random dy the parameter gradient would be a sum of n cancelling terms that one flipped point
// moves by 1/√n.
static inline void field_twin_check(const mlb_backend* be, mlb_field_kind kind, mlb_material_mode mode, int n, double tol) {
    mlb_brdf_ae prior;
    REQUIRE(random_prior(&prior));
    mlb_field_config c = mlb_material_default();
    c.kind = kind;
    c.enc = (mlb_hashgrid_config){6, 2, 1 << 12, 4, 1.6};
    c.hidden = 16;
    c.mode = mode;
    mlb_field net[2];
    for (int t = 0; t < 2; t++) {
        REQUIRE(field_init(&net[t], &c, &prior) == MLB_OK);
        for (size_t i = 0; i < net[t].n_enc; i++) net[t].params[i] = 0.4f * mlb_rng_normal(31, 0, i);
    }
    REQUIRE(mlb_field_use_device(&net[1], be) == MLB_OK);
    const int D = mlb_field_out_dim(&c), latent = kind == MLB_FIELD_MATERIAL && mode == MLB_MATERIAL_LATENT;
    size_t N = (size_t)n;
    float *pos = malloc(sizeof(float) * 3 * N), *dy = malloc(sizeof(float) * D * N), *dz = malloc(sizeof(float) * 4 * N);
    float *y[2], *z[2], *dpos[2];
    for (int t = 0; t < 2; t++) {
        y[t] = malloc(sizeof(float) * D * N);
        z[t] = malloc(sizeof(float) * 4 * N);
        dpos[t] = malloc(sizeof(float) * 3 * N);
    }
    for (size_t i = 0; i < 3 * N; i++) pos[i] = 1.6f * (mlb_rng_uniform(32, 0, i) - 0.5f);
    mlb_adam_config adam = mlb_material_adam(1e-2);
    adam.eps = 1e-4;
    for (int it = 0; it < 3; it++) {
        for (int t = 0; t < 2; t++) {
            for (size_t i = 0; i < 3 * N; i++) dpos[t][i] = mlb_rng_normal(33, 0, i);   // backward accumulates
            net[t].active_levels = it == 0 ? 3 : 0;   // the first step coarse to fine: 3 of the 6 levels
            field_zero_grad(&net[t]);
            REQUIRE(field_forward(&net[t], y[t], latent ? z[t] : NULL, pos, n) == MLB_OK);
        }
        for (size_t i = 0; i < (size_t)D * N; i++) dy[i] = y[0][i] - 0.5f;
        // latent mode: a term on the codes too (step 1: with dy; step 2: alone, dy NULL)
        for (size_t i = 0; latent && i < 4 * N; i++) dz[i] = 0.1f * z[0][i];
        for (int t = 0; t < 2; t++)
            REQUIRE((latent && it > 0 ? field_backward_latent(&net[t], it == 1 ? dy : NULL, dz, dpos[t])
                                      : field_backward(&net[t], dy, dpos[t])) == MLB_OK);
        CHECK_PARITY("y", y[1], y[0], (size_t)D * N, tol);
        if (latent) CHECK_PARITY("z", z[1], z[0], 4 * N, tol);
        for (size_t i = 0; i < 3 * N; i++) {   // the increments
            float start = mlb_rng_normal(33, 0, i);
            dpos[0][i] -= start;
            dpos[1][i] -= start;
        }
        CHECK_POINTWISE("dpos", dpos[1], dpos[0], N, 3, 100 * tol, 1e-3);
        REQUIRE(mlb_field_sync_host(&net[1]) == MLB_OK);
        CHECK_PARITY("gradient", net[1].grads, net[0].grads, net[0].n_params, 10 * tol);
        if (it == 0) {   // the inactive levels' table entries get no gradient on either path
            size_t first = (size_t)net[0].enc.offset[3] * c.enc.n_features, nonzero = 0;
            for (size_t i = first; i < net[0].n_enc; i++) nonzero += net[0].grads[i] != 0 || net[1].grads[i] != 0;
            CHECK_MSG(nonzero == 0 && first < net[0].n_enc, "%zu gradients of inactive levels are not 0", nonzero);
        }
        for (int t = 0; t < 2; t++) REQUIRE(field_update(&net[t], &adam) == MLB_OK);
    }
    // the host copy is behind after the last update: saving it is refused, nothing is written
    char path[600];
    snprintf(path, sizeof path, "%s/field_%d_%d.safetensors", test_tmpdir("field_twin"), (int)kind, (int)mode);
    remove(path);
    CHECK(mlb_field_save(&net[1], path, 0, NULL, 0) == MLB_ERR_ARG);
    struct stat st;
    CHECK(stat(path, &st) != 0);
    REQUIRE(mlb_field_sync_host(&net[1]) == MLB_OK);
    CHECK(mlb_field_save(&net[1], path, 1, NULL, 0) == MLB_OK);
    CHECK_PARITY("parameters after 3 steps", net[1].params, net[0].params, net[0].n_params, tol);
    CHECK_PARITY("Adam first moments", net[1].adam_m, net[0].adam_m, net[0].n_params, 10 * tol);
    CHECK(net[1].step == 3);
    // synced: eval on the host agrees; a bad point count is the same error on both
    REQUIRE(field_eval(&net[1], pos, 8, y[1], NULL) == MLB_OK);
    REQUIRE(field_eval(&net[0], pos, 8, y[0], NULL) == MLB_OK);
    CHECK_PARITY("eval of the synced host copy", y[1], y[0], (size_t)D * 8, tol);
    for (int t = 0; t < 2; t++) CHECK(field_forward(&net[t], y[t], NULL, pos, 0) == MLB_ERR_ARG);
    // a term on the codes of a field without codes is refused on both paths
    if (!latent)
        for (int t = 0; t < 2; t++) {
            REQUIRE(field_forward(&net[t], y[t], NULL, pos, n) == MLB_OK);
            CHECK(field_backward_latent(&net[t], dy, dy, NULL) == MLB_ERR_ARG);
            CHECK(field_backward_latent(&net[t], NULL, NULL, NULL) == MLB_ERR_ARG);
        }
    for (int t = 0; t < 2; t++) {
        field_free(&net[t]);
        free(y[t]); free(z[t]); free(dpos[t]);
    }
    free(pos); free(dy); free(dz);
    brdf_ae_free(&prior);
}

#endif
