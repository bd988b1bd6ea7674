// The geometry network: hash grid -> MLP -> (sdf, deform xyz) (include/matlaber/geometry.h,
// docs/geometry_init.md). Dual-compiled (float / double _f64), see core/real.h.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/geometry.h"
#include "core/real.h"

static mlb_status check_config(const mlb_geometry_config* c) {
    if (c->hidden < 1 || c->hidden > 4096) return mlb_fail(MLB_ERR_ARG, "geometry network: hidden width %d not in 1..4096", c->hidden);
    if (c->n_hidden < 1 || c->n_hidden > MLB_MLP_MAX_LAYERS - 1)
        return mlb_fail(MLB_ERR_ARG, "geometry network: %d hidden layers not in 1..%d", c->n_hidden, MLB_MLP_MAX_LAYERS - 1);
    if (!(c->scale > 0) || !isfinite(c->scale)) return mlb_fail(MLB_ERR_ARG, "geometry network: scale must be > 0");
    return MLB_OK;
}

void FN(geometry_net_free)(FN(mlb_geometry_net)* net) {
    free(net->params);
    free(net->grads);
    free(net->adam_m);
    free(net->adam_v);
    free(net->x);
    free(net->feat);
    free(net->dout);
    free(net->dfeat);
    FN(mlp_cache_free)(&net->cache);
    memset(net, 0, sizeof *net);
}

mlb_status FN(geometry_net_init)(FN(mlb_geometry_net)* net, const mlb_geometry_config* cfg) {
    memset(net, 0, sizeof *net);
    mlb_status s = check_config(cfg);
    if (s) return s;
    net->cfg = *cfg;
    s = FN(hashgrid_init)(&net->enc, &cfg->enc, NULL);
    if (s) return s;
    int dims[MLB_MLP_MAX_LAYERS + 1];
    int nl = cfg->n_hidden + 1;
    dims[0] = net->enc.out_dim;
    for (int l = 1; l < nl; l++) dims[l] = cfg->hidden;
    dims[nl] = 4;
    net->n_enc = net->enc.n_params;
    net->n_mlp = FN(mlp_param_count)(nl, dims, 0);
    net->n_params = net->n_enc + net->n_mlp;
    net->params = calloc(net->n_params, sizeof(real));
    net->grads = calloc(net->n_params, sizeof(real));
    net->adam_m = calloc(net->n_params, sizeof(real));
    net->adam_v = calloc(net->n_params, sizeof(real));
    if (!net->params || !net->grads || !net->adam_m || !net->adam_v) {
        size_t np = net->n_params;
        FN(geometry_net_free)(net);
        return mlb_fail(MLB_ERR_NOMEM, "geometry network: out of memory (%zu parameters)", np);
    }
    net->enc.params = net->params;
    s = FN(mlp_init)(&net->mlp, nl, dims, 0, MLB_ACT_RELU, MLB_ACT_IDENTITY, net->params + net->n_enc);
    if (s) { FN(geometry_net_free)(net); return s; }
    FN(hashgrid_init_params)(&net->enc, cfg->seed);
    FN(mlp_init_weights)(&net->mlp, cfg->seed, 0x6E0);
    return MLB_OK;
}

void FN(geometry_net_zero_grad)(FN(mlb_geometry_net)* net) { memset(net->grads, 0, sizeof(real) * net->n_params); }

static mlb_status FN(geo_reserve)(FN(mlb_geometry_net)* net, int n) {
    if (n <= net->capacity) return MLB_OK;
    int L = net->enc.out_dim;
    free(net->x); free(net->feat); free(net->dout); free(net->dfeat);
    FN(mlp_cache_free)(&net->cache);
    net->capacity = 0;
    net->x = malloc(sizeof(real) * 3 * (size_t)n);
    net->feat = malloc(sizeof(real) * (size_t)L * n);
    net->dout = malloc(sizeof(real) * 4 * (size_t)n);
    net->dfeat = malloc(sizeof(real) * (size_t)L * n);
    if (!net->x || !net->feat || !net->dout || !net->dfeat) return mlb_fail(MLB_ERR_NOMEM, "geometry network: out of memory (%d points)", n);
    mlb_status s = FN(mlp_cache_alloc)(&net->cache, &net->mlp, n);
    if (s) return s;
    net->capacity = n;
    return MLB_OK;
}

// Coarse-to-fine: the features of levels >= active_levels (and so their gradients) are zero, the
// level-major columns [l·F, (l+1)·F) of every row.
static void FN(mask_levels)(const FN(mlb_geometry_net)* net, real* feat, int n) {
    const int L = net->enc.cfg.n_levels, F = net->enc.cfg.n_features, a = net->active_levels;
    if (a <= 0 || a >= L) return;
    for (int i = 0; i < n; i++) memset(feat + (size_t)i * L * F + (size_t)a * F, 0, sizeof(real) * (size_t)(L - a) * F);
}

mlb_status FN(geometry_net_forward)(FN(mlb_geometry_net)* net, real* sdf, real* deform, const real* pos, int n) {
    if (n < 1) return mlb_fail(MLB_ERR_ARG, "geometry network: %d points", n);
    mlb_status s = FN(geo_reserve)(net, n);
    if (s) return s;
    net->n = n;
    real inv = (real)(1.0 / net->cfg.scale);
    // x[n,3] = pos/scale + 0.5 ∈ [0,1]^3 (the hash grid clamps points outside the box)
    for (size_t i = 0; i < 3 * (size_t)n; i++) net->x[i] = pos[i] * inv + (real)0.5;
    FN(hashgrid_forward)(&net->enc, net->feat, net->x, n);                  // feat[n, L·F]
    FN(mask_levels)(net, net->feat, n);
    const real* out = FN(mlp_forward)(&net->mlp, &net->cache, net->feat, n);   // out[n, 4]
    for (int i = 0; i < n; i++) {
        if (sdf) sdf[i] = out[4 * i];
        if (deform) for (int d = 0; d < 3; d++) deform[3 * i + d] = out[4 * i + 1 + d];
    }
    return MLB_OK;
}

void FN(geometry_net_backward)(FN(mlb_geometry_net)* net, const real* dsdf, const real* ddeform) {
    int n = net->n;
    for (int i = 0; i < n; i++) {
        net->dout[4 * i] = dsdf ? dsdf[i] : 0;
        for (int d = 0; d < 3; d++) net->dout[4 * i + 1 + d] = ddeform ? ddeform[3 * i + d] : 0;
    }
    memset(net->dfeat, 0, sizeof(real) * (size_t)net->enc.out_dim * n);
    FN(mlp_backward)(&net->mlp, &net->cache, net->grads + net->n_enc, net->dfeat, net->dout, net->feat, n);
    FN(mask_levels)(net, net->dfeat, n);
    FN(hashgrid_backward)(&net->enc, net->grads, NULL, net->dfeat, net->x, n);
}

void FN(geometry_net_update)(FN(mlb_geometry_net)* net, const mlb_adam_config* adam) {
    net->step++;
    FN(adam_update)(net->params, net->grads, net->adam_m, net->adam_v, net->n_params, adam, net->step);
}

