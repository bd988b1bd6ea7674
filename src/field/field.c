// The neural field: hash grid → MLP (→ frozen decoder) (include/matlaber/field.h). Dual-compiled
// (float / double _f64), see core/real.h. A field on a device (f->dev) dispatches to its twin
// (src/field/field_device.c; a double field is never there, its twin's entry points say so).
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend_f64.h"
#include "matlaber/brdf.h"
#include "matlaber/field.h"
#include "core/real.h"
#include "field/field_internal.h"

#define K_DIM 7
#define Z_DIM MLB_LATENT_DIM
#define EVAL_CHUNK 4096
// The MLPs run over fixed shards of SHARD rows, in parallel over the shards (a shard's GEMMs run on
// its own thread): the shard boundaries, not the thread count, decide the arithmetic, so forward,
// backward and eval are bitwise the same on any number of threads. EVAL_CHUNK is a multiple of
// SHARD, so eval matches forward.
#define SHARD 1024

// The BRDF auto-encoder's output map k = lo + (hi − lo)·s (brdf_ae.h) applied to sigmoid outputs s.
void FN(field_map_to_ranges)(real* k, const real* s, int n) {
    for (int i = 0; i < n; i++)
        for (int c = 0; c < K_DIM; c++)
            k[(size_t)i * K_DIM + c] = (real)(mlb_brdf_range_lo[c] + (mlb_brdf_range_hi[c] - mlb_brdf_range_lo[c]) * s[(size_t)i * K_DIM + c]);
}

static mlb_status check_config(const mlb_field_config* c) {
    const char* who = c->kind == MLB_FIELD_GEOMETRY ? "geometry network" : "material network";
    if (c->kind != MLB_FIELD_GEOMETRY && c->kind != MLB_FIELD_MATERIAL) return mlb_fail(MLB_ERR_ARG, "field: unknown kind %d", (int)c->kind);
    if (c->hidden < 1 || c->hidden > 4096) return mlb_fail(MLB_ERR_ARG, "%s: hidden width %d not in 1..4096", who, c->hidden);
    if (c->n_hidden < 1 || c->n_hidden > MLB_MLP_MAX_LAYERS - 1)
        return mlb_fail(MLB_ERR_ARG, "%s: %d hidden layers not in 1..%d", who, c->n_hidden, MLB_MLP_MAX_LAYERS - 1);
    if (!(c->scale > 0) || !isfinite(c->scale)) return mlb_fail(MLB_ERR_ARG, "%s: scale must be > 0", who);
    if (c->kind == MLB_FIELD_MATERIAL && c->mode != MLB_MATERIAL_LATENT && c->mode != MLB_MATERIAL_DIRECT)
        return mlb_fail(MLB_ERR_ARG, "%s: unknown mode %d", who, (int)c->mode);
    return MLB_OK;
}

static int FN(latent)(const FN(mlb_field)* f) { return f->cfg.kind == MLB_FIELD_MATERIAL && f->cfg.mode == MLB_MATERIAL_LATENT; }
// The trained MLP's outputs: 4 (geometry, latent codes) or 7 (direct k)
static int FN(mlp_out)(const mlb_field_config* c) {
    return c->kind == MLB_FIELD_MATERIAL && c->mode == MLB_MATERIAL_DIRECT ? K_DIM : 4;
}

static void FN(free_cache)(FN(mlb_field)* f) {
    free(f->x); free(f->feat); free(f->out); free(f->y);
    free(f->dfeat); free(f->dout); free(f->dy); free(f->shard_grads);
    f->x = f->feat = f->out = f->y = f->dfeat = f->dout = f->dy = f->shard_grads = NULL;
    FN(mlp_cache_free)(&f->cache);
    FN(mlp_cache_free)(&f->dec_cache);
    f->capacity = 0;
    f->n = 0;
}

void FN(field_free)(FN(mlb_field)* f) {
    FN(field_device_free)(f->dev);
    free(f->params);
    free(f->grads);
    free(f->adam_m);
    free(f->adam_v);
    free(f->dec_params);
    FN(free_cache)(f);
    memset(f, 0, sizeof *f);
}

mlb_status FN(field_init)(FN(mlb_field)* f, const mlb_field_config* cfg, const mlb_brdf_ae* prior) {
    memset(f, 0, sizeof *f);
    MLB_TRY(check_config(cfg));
    const int latent = cfg->kind == MLB_FIELD_MATERIAL && cfg->mode == MLB_MATERIAL_LATENT;
    const mlb_mlp* pd = prior ? &prior->dec : NULL;
    if (latent) {
        if (!pd || !pd->params) return mlb_fail(MLB_ERR_ARG, "material network: latent mode needs the BRDF prior (its decoder)");
        if (pd->n_layers < 1 || pd->dims[0] != Z_DIM || pd->dims[pd->n_layers] != K_DIM || !pd->has_bias ||
            pd->out_act != MLB_ACT_SIGMOID)
            return mlb_fail(MLB_ERR_ARG, "material network: the prior's decoder is not a %d -> ... -> %d MLP with biases and a sigmoid output",
                            Z_DIM, K_DIM);
    }
    f->cfg = *cfg;
    MLB_TRY(FN(hashgrid_init)(&f->enc, &cfg->enc, NULL));
    // geometry: no biases, linear output (Fantasia3D's SDF/deformation MLP); material: biases,
    // linear latent output or a sigmoid before the ranges (direct)
    const int bias = cfg->kind == MLB_FIELD_MATERIAL;
    const mlb_activation out_act = cfg->kind == MLB_FIELD_MATERIAL && !latent ? MLB_ACT_SIGMOID : MLB_ACT_IDENTITY;
    int dims[MLB_MLP_MAX_LAYERS + 1];
    int nl = cfg->n_hidden + 1;
    dims[0] = f->enc.out_dim;
    for (int l = 1; l < nl; l++) dims[l] = cfg->hidden;
    dims[nl] = FN(mlp_out)(cfg);
    f->n_enc = f->enc.n_params;
    f->n_mlp = FN(mlp_param_count)(nl, dims, bias);
    f->n_params = f->n_enc + f->n_mlp;
    f->params = calloc(f->n_params, sizeof(real));
    f->grads = calloc(f->n_params, sizeof(real));
    f->adam_m = calloc(f->n_params, sizeof(real));
    f->adam_v = calloc(f->n_params, sizeof(real));
    if (!f->params || !f->grads || !f->adam_m || !f->adam_v) {
        size_t np = f->n_params;
        FN(field_free)(f);
        return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory (%zu parameters)", bias ? "material network" : "geometry network", np);
    }
    f->enc.params = f->params;
    mlb_status s = FN(mlp_init)(&f->mlp, nl, dims, bias, MLB_ACT_RELU, out_act, f->params + f->n_enc);
    if (s) { FN(field_free)(f); return s; }
    FN(hashgrid_init_params)(&f->enc, cfg->seed);
    // the weights' random streams (each kind keeps the stream its files were trained with)
    FN(mlp_init_weights)(&f->mlp, cfg->seed, cfg->kind == MLB_FIELD_GEOMETRY ? 0x6E0 : 0x3A7);
    if (latent) {
        size_t nd = mlp_param_count(pd->n_layers, pd->dims, 1);
        f->dec_params = malloc(sizeof(real) * nd);
        if (!f->dec_params) { FN(field_free)(f); return mlb_fail(MLB_ERR_NOMEM, "material network: out of memory"); }
        for (size_t i = 0; i < nd; i++) f->dec_params[i] = (real)pd->params[i];
        s = FN(mlp_init)(&f->dec, pd->n_layers, pd->dims, 1, pd->hidden_act, pd->out_act, f->dec_params);
        if (s) { FN(field_free)(f); return s; }
    }
    return MLB_OK;
}

void FN(field_zero_grad)(FN(mlb_field)* f) {
    if (f->dev) { FN(field_device_zero_grad)(f); return; }   // a failure is reported by the next op
    memset(f->grads, 0, sizeof(real) * f->n_params);
}

static int FN(max_width)(const FN(mlb_mlp)* mlp) {
    int m = 0;
    for (int l = 0; l <= mlp->n_layers; l++) if (mlp->dims[l] > m) m = mlp->dims[l];
    return m;
}

// The rows [start, start + B) of a cache allocated for more rows: every array is row-major.
static FN(mlb_mlp_cache) FN(cache_rows)(const FN(mlb_mlp_cache)* c, const FN(mlb_mlp)* mlp, int start, int B) {
    FN(mlb_mlp_cache) v = *c;
    v.B = 0;
    v.capacity = B;
    v.buffer = NULL;
    for (int l = 0; l < mlp->n_layers; l++) {
        size_t o = (size_t)start * mlp->dims[l + 1];
        v.pre[l] += o; v.post[l] += o; v.d1[l] += o; v.d2[l] += o; v.tpre[l] += o; v.tpost[l] += o;
    }
    for (int i = 0; i < 6; i++) v.scratch[i] += (size_t)start * FN(max_width)(mlp);
    return v;
}

// mlp_forward without the activations' second derivatives (only Jacobian-vector products need
// them) and, when need_d1 = 0 (inference), without the first: the decoder's SiLU layers cost a third
// less. Fills pre, post (and d1) like mlp_forward, so mlp_backward works on the cache.
static void FN(mlp_forward_lean)(const FN(mlb_mlp)* mlp, FN(mlb_mlp_cache)* c, const real* in, int B, int need_d1) {
    c->B = B;
    const real* x = in;
    for (int l = 0; l < mlp->n_layers; l++) {
        int C = mlp->dims[l], OC = mlp->dims[l + 1];
        FN(linear_forward)(c->pre[l], x, mlp->weight[l], mlp->bias[l], B, C, OC);
        FN(activation_forward_derivs)(c->post[l], need_d1 ? c->d1[l] : NULL, NULL, c->pre[l], (size_t)B * OC,
                                      l == mlp->n_layers - 1 ? mlp->out_act : mlp->hidden_act);
        x = c->post[l];
    }
}

// The MLP over shards; returns the output [n, dims[L]] (the cache's last post).
static const real* FN(mlp_forward_sharded)(const FN(mlb_mlp)* mlp, FN(mlb_mlp_cache)* c, const real* in, int n, int need_d1) {
    int ns = (n + SHARD - 1) / SHARD;
#pragma omp parallel for schedule(static) if (ns > 1)
    for (int sh = 0; sh < ns; sh++) {
        int start = sh * SHARD, B = n - start < SHARD ? n - start : SHARD;
        FN(mlb_mlp_cache) v = FN(cache_rows)(c, mlp, start, B);
        FN(mlp_forward_lean)(mlp, &v, in + (size_t)start * mlp->dims[0], B, need_d1);
    }
    c->B = n;
    return c->post[mlp->n_layers - 1];
}

// The backward over the forward's shards: din (overwritten when frozen, else accumulated) and,
// unless frozen, dparams += the shards' gradients summed in shard order.
static void FN(mlp_backward_sharded)(const FN(mlb_mlp)* mlp, FN(mlb_mlp_cache)* c, real* dparams, real* shard_grads,
                                     size_t n_mlp, real* din, const real* dout, const real* in, int n, int frozen) {
    int ns = (n + SHARD - 1) / SHARD;
    int in_dim = mlp->dims[0], out_dim = mlp->dims[mlp->n_layers];
#pragma omp parallel for schedule(static) if (ns > 1)
    for (int sh = 0; sh < ns; sh++) {
        int start = sh * SHARD, B = n - start < SHARD ? n - start : SHARD;
        FN(mlb_mlp_cache) v = FN(cache_rows)(c, mlp, start, B);
        real* dx = din + (size_t)start * in_dim;
        const real* dy = dout + (size_t)start * out_dim;
        if (frozen) {   // the input gradient alone, overwritten
            memset(dx, 0, sizeof(real) * (size_t)B * in_dim);
            FN(mlp_backward)(mlp, &v, NULL, dx, dy, NULL, B);
        } else {
            real* g = shard_grads + (size_t)sh * n_mlp;
            memset(g, 0, sizeof(real) * n_mlp);
            FN(mlp_backward)(mlp, &v, g, dx, dy, in + (size_t)start * in_dim, B);
        }
    }
    if (frozen) return;
#pragma omp parallel for schedule(static) if (n_mlp > 4096)
    for (size_t i = 0; i < n_mlp; i++) {
        real acc = 0;
        for (int sh = 0; sh < ns; sh++) acc += shard_grads[(size_t)sh * n_mlp + i];
        dparams[i] += acc;
    }
}

static mlb_status FN(reserve)(FN(mlb_field)* f, int n) {
    if (n <= f->capacity) return MLB_OK;
    FN(free_cache)(f);
    size_t N = (size_t)n, L = (size_t)f->enc.out_dim, O = (size_t)FN(mlp_out)(&f->cfg);
    f->x = malloc(sizeof(real) * 3 * N);
    f->feat = malloc(sizeof(real) * L * N);
    f->out = malloc(sizeof(real) * O * N);
    f->y = malloc(sizeof(real) * K_DIM * N);
    f->dfeat = malloc(sizeof(real) * L * N);
    f->dout = malloc(sizeof(real) * K_DIM * N);
    f->dy = malloc(sizeof(real) * K_DIM * N);   // also the dx scratch [n,3] of backward
    f->shard_grads = malloc(sizeof(real) * f->n_mlp * ((N + SHARD - 1) / SHARD));
    if (!f->x || !f->feat || !f->out || !f->y || !f->dfeat || !f->dout || !f->dy || !f->shard_grads)
        return mlb_fail(MLB_ERR_NOMEM, "field: out of memory (%d points)", n);
    MLB_TRY(FN(mlp_cache_alloc)(&f->cache, &f->mlp, n));
    if (FN(latent)(f)) MLB_TRY(FN(mlp_cache_alloc)(&f->dec_cache, &f->dec, n));
    f->capacity = n;
    return MLB_OK;
}

// Coarse to fine: the features of levels >= active_levels (and so their gradients) are zero, the
// level-major columns [l·F, (l+1)·F) of every row.
static void FN(mask_levels)(const FN(mlb_field)* f, real* feat, int n) {
    const int L = f->enc.cfg.n_levels, F = f->enc.cfg.n_features, a = f->active_levels;
    if (a <= 0 || a >= L) return;
    for (int i = 0; i < n; i++) memset(feat + (size_t)i * L * F + (size_t)a * F, 0, sizeof(real) * (size_t)(L - a) * F);
}

// The field at n points with the given buffers: x [n,3], feat [n,L·F] → the MLP's output
// (returned: the MLP cache's output) and y [n, out_dim] (may be NULL). Shared by forward (the
// field's own cache) and eval (private buffers).
static const real* FN(run)(const FN(mlb_field)* f, FN(mlb_mlp_cache)* cache, FN(mlb_mlp_cache)* dec_cache, real* x,
                           real* feat, const real* pos, int n, real* y, int need_d1) {
    real inv = (real)(1.0 / f->cfg.scale);
    for (size_t i = 0; i < 3 * (size_t)n; i++) x[i] = pos[i] * inv + (real)0.5;   // the grid box → [0,1]^3
    const FN(mlb_hashgrid) enc = FN(field_active_enc)(f);
    FN(hashgrid_forward)(&enc, feat, x, n);
    FN(mask_levels)(f, feat, n);   // the inactive levels' columns, which the call above did not write
    const real* out = FN(mlp_forward_sharded)(&f->mlp, cache, feat, n, need_d1);
    if (!y) return out;
    if (f->cfg.kind == MLB_FIELD_GEOMETRY) memcpy(y, out, sizeof(real) * 4 * (size_t)n);
    else if (FN(latent)(f)) FN(field_map_to_ranges)(y, FN(mlp_forward_sharded)(&f->dec, dec_cache, out, n, need_d1), n);
    else FN(field_map_to_ranges)(y, out, n);
    return out;
}

mlb_status FN(field_forward)(FN(mlb_field)* f, real* y, real* z, const real* pos, int n) {
    if (n < 1) return mlb_fail(MLB_ERR_ARG, "field: %d points", n);
    if (f->dev) return FN(field_device_forward)(f, y, z, pos, n);
    MLB_TRY(FN(reserve)(f, n));
    f->n = n;
    const int O = FN(mlp_out)(&f->cfg), D = mlb_field_out_dim(&f->cfg);
    const real* out = FN(run)(f, &f->cache, &f->dec_cache, f->x, f->feat, pos, n, f->y, 1);
    memcpy(f->out, out, sizeof(real) * (size_t)O * n);
    if (y) memcpy(y, f->y, sizeof(real) * (size_t)D * n);
    if (z && FN(latent)(f)) memcpy(z, out, sizeof(real) * Z_DIM * (size_t)n);
    return MLB_OK;
}

mlb_status FN(field_backward)(FN(mlb_field)* f, const real* dy, real* dpos) {
    return FN(field_backward_latent)(f, dy, NULL, dpos);
}

mlb_status FN(field_backward_latent)(FN(mlb_field)* f, const real* dy, const real* dz, real* dpos) {
    int n = f->n, L = f->enc.out_dim;
    if (n < 1) return mlb_fail(MLB_ERR_ARG, "field: backward without a forward");
    if ((dz || !dy) && !FN(latent)(f)) return mlb_fail(MLB_ERR_ARG, "field: a gradient at the codes of a field without codes");
    if (f->dev) return FN(field_device_backward)(f, dy, dz, dpos);
    const real* dmlp = dy;   // the gradient at the trained MLP's output
    if (f->cfg.kind == MLB_FIELD_MATERIAL) {
        // ds = dk·(hi − lo): the gradient at the sigmoid outputs (decoder's or the MLP's own)
        real* ds = f->dy;
        for (int i = 0; i < n; i++)
            for (int c = 0; c < K_DIM; c++)
                ds[(size_t)i * K_DIM + c] = dy ? dy[(size_t)i * K_DIM + c] * (real)(mlb_brdf_range_hi[c] - mlb_brdf_range_lo[c]) : 0;
        if (FN(latent)(f)) {   // dz through the frozen decoder, plus the codes' own term
            FN(mlp_backward_sharded)(&f->dec, &f->dec_cache, NULL, NULL, 0, f->dout, ds, NULL, n, 1);
            if (dz)
                for (size_t i = 0; i < Z_DIM * (size_t)n; i++) f->dout[i] += dz[i];
            dmlp = f->dout;
        } else {
            dmlp = ds;
        }
    }
    memset(f->dfeat, 0, sizeof(real) * (size_t)L * n);
    FN(mlp_backward_sharded)(&f->mlp, &f->cache, f->grads + f->n_enc, f->shard_grads, f->n_mlp, f->dfeat, dmlp, f->feat,
                             n, 0);
    FN(mask_levels)(f, f->dfeat, n);
    real* dx = NULL;
    if (dpos) { dx = f->dy; memset(dx, 0, sizeof(real) * 3 * (size_t)n); }   // ds is no longer needed
    const FN(mlb_hashgrid) enc = FN(field_active_enc)(f);   // the masked levels' gradients are zero: skipped
    FN(hashgrid_backward)(&enc, f->grads, dx, f->dfeat, f->x, n);
    if (dpos) {
        real inv = (real)(1.0 / f->cfg.scale);
        for (size_t i = 0; i < 3 * (size_t)n; i++) dpos[i] += dx[i] * inv;
    }
    return MLB_OK;
}

mlb_status FN(field_update)(FN(mlb_field)* f, const mlb_adam_config* adam) {
    if (f->dev) return FN(field_device_update)(f, adam);
    f->step++;
    FN(adam_update)(f->params, f->grads, f->adam_m, f->adam_v, f->n_params, adam, f->step);
    return MLB_OK;
}

mlb_status FN(field_eval)(const FN(mlb_field)* f, const real* pos, size_t n, real* y, real* z) {
    if (z && !FN(latent)(f)) return mlb_fail(MLB_ERR_ARG, "field: latent codes asked of a field without them");
    if (FN(field_device_host_behind)(f))
        return mlb_fail(MLB_ERR_ARG, "field: its parameters on the %s are ahead of the host's copy (mlb_field_sync_host "
                                     "first)", mlb_device_name(FN(mlb_field_backend)(f)->device));
    if (n == 0) return MLB_OK;
    int chunk = n < EVAL_CHUNK ? (int)n : EVAL_CHUNK, L = f->enc.out_dim, D = mlb_field_out_dim(&f->cfg);
    FN(mlb_mlp_cache) c, dc;
    memset(&c, 0, sizeof c);
    memset(&dc, 0, sizeof dc);
    real* x = malloc(sizeof(real) * 3 * (size_t)chunk);
    real* feat = malloc(sizeof(real) * (size_t)L * chunk);
    mlb_status s = (x && feat) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "field: out of memory");
    if (!s) s = FN(mlp_cache_alloc)(&c, &f->mlp, chunk);
    if (!s && FN(latent)(f)) s = FN(mlp_cache_alloc)(&dc, &f->dec, chunk);
    for (size_t start = 0; !s && start < n; start += (size_t)chunk) {
        int B = (int)(n - start < (size_t)chunk ? n - start : (size_t)chunk);
        const real* out = FN(run)(f, &c, &dc, x, feat, pos + 3 * start, B, y ? y + (size_t)D * start : NULL, 0);
        if (z) memcpy(z + (size_t)Z_DIM * start, out, sizeof(real) * (size_t)Z_DIM * B);
    }
    free(x);
    free(feat);
    FN(mlp_cache_free)(&c);
    FN(mlp_cache_free)(&dc);
    return s;
}

mlb_status FN(field_decode)(const FN(mlb_field)* f, const real* z, size_t n, real* k) {
    if (!FN(latent)(f)) return mlb_fail(MLB_ERR_ARG, "material network: a direct-mode network has no decoder");
    if (n == 0) return MLB_OK;
    int chunk = n < EVAL_CHUNK ? (int)n : EVAL_CHUNK;
    FN(mlb_mlp_cache) dc;
    MLB_TRY(FN(mlp_cache_alloc)(&dc, &f->dec, chunk));
    for (size_t start = 0; start < n; start += (size_t)chunk) {
        int B = (int)(n - start < (size_t)chunk ? n - start : (size_t)chunk);
        const real* s = FN(mlp_forward_sharded)(&f->dec, &dc, z + Z_DIM * start, B, 0);
        FN(field_map_to_ranges)(k + K_DIM * start, s, B);
    }
    FN(mlp_cache_free)(&dc);
    return MLB_OK;
}
