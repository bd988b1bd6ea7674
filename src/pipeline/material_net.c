// The material network of the appearance stage: hash grid → MLP → latent z → frozen BRDF decoder
// → k (latent mode), or hash grid → MLP → sigmoid → affine ranges → k (direct mode)
// (include/matlaber/material_net.h, docs/appearance.md). Dual-compiled (float / double _f64),
// see core/real.h.
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/brdf.h"
#include "matlaber/material_net.h"
#include "core/real.h"
#include "material_net_internal.h"

#define K_DIM 7
#define Z_DIM MLB_LATENT_DIM
#define STREAM_INIT_MLP 0x3A7
#define EVAL_CHUNK 4096
// The MLPs run over fixed shards of SHARD rows, in parallel over the shards (a shard's GEMMs run on
// its own thread): the shard boundaries, not the thread count, decide the arithmetic, so forward,
// backward and eval are bitwise the same on any number of threads. EVAL_CHUNK is a multiple of
// SHARD, so eval matches forward.
#define SHARD 1024

// The BRDF auto-encoder's output map k = lo + (hi − lo)·s (brdf_ae.h) applied to sigmoid outputs s.

void FN(material_map_to_ranges)(real* k, const real* s, int n) {
    for (int i = 0; i < n; i++)
        for (int c = 0; c < K_DIM; c++)
            k[(size_t)i * K_DIM + c] = (real)(mlb_brdf_range_lo[c] + (mlb_brdf_range_hi[c] - mlb_brdf_range_lo[c]) * s[(size_t)i * K_DIM + c]);
}

static mlb_status check_config(const mlb_material_config* c) {
    if (c->hidden < 1 || c->hidden > 4096) return mlb_fail(MLB_ERR_ARG, "material network: hidden width %d not in 1..4096", c->hidden);
    if (c->n_hidden < 1 || c->n_hidden > MLB_MLP_MAX_LAYERS - 1)
        return mlb_fail(MLB_ERR_ARG, "material network: %d hidden layers not in 1..%d", c->n_hidden, MLB_MLP_MAX_LAYERS - 1);
    if (!(c->scale > 0) || !isfinite(c->scale)) return mlb_fail(MLB_ERR_ARG, "material network: scale must be > 0");
    if (c->mode != MLB_MATERIAL_LATENT && c->mode != MLB_MATERIAL_DIRECT)
        return mlb_fail(MLB_ERR_ARG, "material network: unknown mode %d", (int)c->mode);
    return MLB_OK;
}

static int FN(out_dim)(const FN(mlb_material_net)* net) { return net->cfg.mode == MLB_MATERIAL_LATENT ? Z_DIM : K_DIM; }

void FN(material_net_free)(FN(mlb_material_net)* net) {
#ifndef MLB_F64
    material_device_free(net->dev);
#endif
    free(net->params);
    free(net->grads);
    free(net->adam_m);
    free(net->adam_v);
    free(net->dec_params);
    free(net->x); free(net->feat); free(net->out); free(net->k);
    free(net->dfeat); free(net->dout); free(net->dk); free(net->shard_grads);
    FN(mlp_cache_free)(&net->cache);
    FN(mlp_cache_free)(&net->dec_cache);
    memset(net, 0, sizeof *net);
}

mlb_status FN(material_net_init)(FN(mlb_material_net)* net, const mlb_material_config* cfg, const mlb_brdf_ae* prior) {
    memset(net, 0, sizeof *net);
    MLB_TRY(check_config(cfg));
    const mlb_mlp* pd = prior ? &prior->dec : NULL;
    if (cfg->mode == MLB_MATERIAL_LATENT) {
        if (!pd || !pd->params) return mlb_fail(MLB_ERR_ARG, "material network: latent mode needs the BRDF prior (its decoder)");
        if (pd->n_layers < 1 || pd->dims[0] != Z_DIM || pd->dims[pd->n_layers] != K_DIM || !pd->has_bias ||
            pd->out_act != MLB_ACT_SIGMOID)
            return mlb_fail(MLB_ERR_ARG, "material network: the prior's decoder is not a %d -> ... -> %d MLP with biases and a sigmoid output",
                            Z_DIM, K_DIM);
    }
    net->cfg = *cfg;
    MLB_TRY(FN(hashgrid_init)(&net->enc, &cfg->enc, NULL));
    int dims[MLB_MLP_MAX_LAYERS + 1];
    int nl = cfg->n_hidden + 1;
    dims[0] = net->enc.out_dim;
    for (int l = 1; l < nl; l++) dims[l] = cfg->hidden;
    dims[nl] = cfg->mode == MLB_MATERIAL_LATENT ? Z_DIM : K_DIM;
    net->n_enc = net->enc.n_params;
    net->n_mlp = FN(mlp_param_count)(nl, dims, 1);
    net->n_params = net->n_enc + net->n_mlp;
    net->params = calloc(net->n_params, sizeof(real));
    net->grads = calloc(net->n_params, sizeof(real));
    net->adam_m = calloc(net->n_params, sizeof(real));
    net->adam_v = calloc(net->n_params, sizeof(real));
    if (!net->params || !net->grads || !net->adam_m || !net->adam_v) {
        size_t np = net->n_params;
        FN(material_net_free)(net);
        return mlb_fail(MLB_ERR_NOMEM, "material network: out of memory (%zu parameters)", np);
    }
    net->enc.params = net->params;
    // ReLU hidden layers (as the geometry network and Fantasia3D's material MLP); the latent
    // output is linear, the direct output a sigmoid followed by the decoder's affine ranges.
    mlb_status s = FN(mlp_init)(&net->mlp, nl, dims, 1, MLB_ACT_RELU,
                                cfg->mode == MLB_MATERIAL_LATENT ? MLB_ACT_IDENTITY : MLB_ACT_SIGMOID, net->params + net->n_enc);
    if (s) { FN(material_net_free)(net); return s; }
    FN(hashgrid_init_params)(&net->enc, cfg->seed);
    FN(mlp_init_weights)(&net->mlp, cfg->seed, STREAM_INIT_MLP);
    if (cfg->mode == MLB_MATERIAL_LATENT) {
        size_t nd = mlp_param_count(pd->n_layers, pd->dims, 1);
        net->dec_params = malloc(sizeof(real) * nd);
        if (!net->dec_params) { FN(material_net_free)(net); return mlb_fail(MLB_ERR_NOMEM, "material network: out of memory"); }
        for (size_t i = 0; i < nd; i++) net->dec_params[i] = (real)pd->params[i];
        s = FN(mlp_init)(&net->dec, pd->n_layers, pd->dims, 1, pd->hidden_act, pd->out_act, net->dec_params);
        if (s) { FN(material_net_free)(net); return s; }
    }
    return MLB_OK;
}

void FN(material_net_zero_grad)(FN(mlb_material_net)* net) {
#ifndef MLB_F64
    if (net->dev) { material_device_zero_grad(net); return; }   // a failure is reported by the next op
#endif
    memset(net->grads, 0, sizeof(real) * net->n_params);
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

// din [B, dims[0]] = ∂(Σ dout·out)/∂in through a cached MLP forward, without weight gradients
// (the frozen decoder). Uses the cache's scratch buffers. din is overwritten.
static void FN(mlp_backward_input)(const FN(mlb_mlp)* mlp, FN(mlb_mlp_cache)* c, real* din, const real* dout, int B) {
    const real* dpost = dout;
    real* bufs[2] = {c->scratch[0], c->scratch[1]};
    real* dpre = c->scratch[2];
    for (int l = mlp->n_layers - 1; l >= 0; l--) {
        int C = mlp->dims[l], OC = mlp->dims[l + 1];
        for (size_t i = 0; i < (size_t)B * OC; i++) dpre[i] = dpost[i] * c->d1[l][i];
        real* dx = l ? bufs[l & 1] : din;
        memset(dx, 0, sizeof(real) * (size_t)B * C);
        FN(linear_backward)(dx, NULL, NULL, dpre, NULL, mlp->weight[l], B, C, OC);
        dpost = dx;
    }
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
        if (frozen) {
            FN(mlp_backward_input)(mlp, &v, dx, dy, B);
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

static mlb_status FN(mat_reserve)(FN(mlb_material_net)* net, int n) {
    if (n <= net->capacity) return MLB_OK;
    int L = net->enc.out_dim, O = FN(out_dim)(net);
    free(net->x); free(net->feat); free(net->out); free(net->k);
    free(net->dfeat); free(net->dout); free(net->dk); free(net->shard_grads);
    FN(mlp_cache_free)(&net->cache);
    FN(mlp_cache_free)(&net->dec_cache);
    net->capacity = 0;
    net->n = 0;
    net->x = malloc(sizeof(real) * 3 * (size_t)n);
    net->feat = malloc(sizeof(real) * (size_t)L * n);
    net->out = malloc(sizeof(real) * (size_t)O * n);
    net->k = malloc(sizeof(real) * K_DIM * (size_t)n);
    net->dfeat = malloc(sizeof(real) * (size_t)L * n);
    net->dout = malloc(sizeof(real) * (size_t)O * n);
    net->dk = malloc(sizeof(real) * K_DIM * (size_t)n);   // also the dx scratch [n,3] of backward
    net->shard_grads = malloc(sizeof(real) * net->n_mlp * (size_t)((n + SHARD - 1) / SHARD));
    if (!net->x || !net->feat || !net->out || !net->k || !net->dfeat || !net->dout || !net->dk || !net->shard_grads)
        return mlb_fail(MLB_ERR_NOMEM, "material network: out of memory (%d points)", n);
    MLB_TRY(FN(mlp_cache_alloc)(&net->cache, &net->mlp, n));
    if (net->cfg.mode == MLB_MATERIAL_LATENT) MLB_TRY(FN(mlp_cache_alloc)(&net->dec_cache, &net->dec, n));
    net->capacity = n;
    return MLB_OK;
}

// The network at n points with the given buffers: x [n,3], feat [n,L·F] → out [n,O] (returned:
// the MLP cache's output), k [n,7] (may be NULL). Shared by forward (the net's own cache) and
// eval (private buffers).
static const real* FN(mat_run)(const FN(mlb_material_net)* net, FN(mlb_mlp_cache)* cache, FN(mlb_mlp_cache)* dec_cache,
                               real* x, real* feat, const real* pos, int n, real* k, int need_d1) {
    real inv = (real)(1.0 / net->cfg.scale);
    for (size_t i = 0; i < 3 * (size_t)n; i++) x[i] = pos[i] * inv + (real)0.5;   // the grid box → [0,1]^3
    FN(hashgrid_forward)(&net->enc, feat, x, n);
    const real* out = FN(mlp_forward_sharded)(&net->mlp, cache, feat, n, need_d1);
    if (!k) return out;
    if (net->cfg.mode == MLB_MATERIAL_LATENT) {
        const real* s = FN(mlp_forward_sharded)(&net->dec, dec_cache, out, n, need_d1);
        FN(material_map_to_ranges)(k, s, n);
    } else {
        FN(material_map_to_ranges)(k, out, n);
    }
    return out;
}

mlb_status FN(material_net_forward)(FN(mlb_material_net)* net, real* k, real* z, const real* pos, int n) {
    if (n < 1) return mlb_fail(MLB_ERR_ARG, "material network: %d points", n);
#ifndef MLB_F64
    if (net->dev) return material_device_forward(net, k, z, pos, n);
#endif
    MLB_TRY(FN(mat_reserve)(net, n));
    net->n = n;
    int O = FN(out_dim)(net);
    const real* out = FN(mat_run)(net, &net->cache, &net->dec_cache, net->x, net->feat, pos, n, net->k, 1);
    memcpy(net->out, out, sizeof(real) * (size_t)O * n);
    if (k) memcpy(k, net->k, sizeof(real) * K_DIM * (size_t)n);
    if (z && net->cfg.mode == MLB_MATERIAL_LATENT) memcpy(z, out, sizeof(real) * Z_DIM * (size_t)n);
    return MLB_OK;
}

mlb_status FN(material_net_backward)(FN(mlb_material_net)* net, const real* dk, real* dpos) {
    int n = net->n, L = net->enc.out_dim;
    if (n < 1) return mlb_fail(MLB_ERR_ARG, "material network: backward without a forward");
#ifndef MLB_F64
    if (net->dev) return material_device_backward(net, dk, dpos);
#endif
    // ds = dk·(hi − lo): the gradient at the sigmoid outputs (decoder's or the MLP's own)
    real* ds = net->dk;
    for (int i = 0; i < n; i++)
        for (int c = 0; c < K_DIM; c++)
            ds[(size_t)i * K_DIM + c] = dk[(size_t)i * K_DIM + c] * (real)(mlb_brdf_range_hi[c] - mlb_brdf_range_lo[c]);
    if (net->cfg.mode == MLB_MATERIAL_LATENT)   // dz through the frozen decoder
        FN(mlp_backward_sharded)(&net->dec, &net->dec_cache, NULL, NULL, 0, net->dout, ds, NULL, n, 1);
    else
        memcpy(net->dout, ds, sizeof(real) * K_DIM * (size_t)n);
    memset(net->dfeat, 0, sizeof(real) * (size_t)L * n);
    FN(mlp_backward_sharded)(&net->mlp, &net->cache, net->grads + net->n_enc, net->shard_grads, net->n_mlp, net->dfeat,
                             net->dout, net->feat, n, 0);
    real* dx = NULL;
    if (dpos) { dx = net->dk; memset(dx, 0, sizeof(real) * 3 * (size_t)n); }   // ds is no longer needed
    FN(hashgrid_backward)(&net->enc, net->grads, dx, net->dfeat, net->x, n);
    if (dpos) {
        real inv = (real)(1.0 / net->cfg.scale);
        for (size_t i = 0; i < 3 * (size_t)n; i++) dpos[i] += dx[i] * inv;
    }
    return MLB_OK;
}

mlb_status FN(material_net_update)(FN(mlb_material_net)* net, const mlb_adam_config* adam) {
#ifndef MLB_F64
    if (net->dev) return material_device_update(net, adam);
#endif
    net->step++;
    FN(adam_update)(net->params, net->grads, net->adam_m, net->adam_v, net->n_params, adam, net->step);
    return MLB_OK;
}

mlb_status FN(material_net_eval)(const FN(mlb_material_net)* net, const real* pos, size_t n, real* k, real* z) {
    if (z && net->cfg.mode != MLB_MATERIAL_LATENT)
        return mlb_fail(MLB_ERR_ARG, "material network: latent codes asked of a direct-mode network");
#ifndef MLB_F64
    if (material_device_host_behind(net))
        return mlb_fail(MLB_ERR_ARG, "material network: its parameters on the %s are ahead of the host's copy "
                                     "(mlb_material_net_sync_host first)", mlb_device_name(mlb_material_net_backend(net)->device));
#endif
    if (n == 0) return MLB_OK;
    int chunk = n < EVAL_CHUNK ? (int)n : EVAL_CHUNK, L = net->enc.out_dim, O = FN(out_dim)(net);
    FN(mlb_mlp_cache) c, dc;
    memset(&c, 0, sizeof c);
    memset(&dc, 0, sizeof dc);
    real* x = malloc(sizeof(real) * 3 * (size_t)chunk);
    real* feat = malloc(sizeof(real) * (size_t)L * chunk);
    mlb_status s = (x && feat) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "material network: out of memory");
    if (!s) s = FN(mlp_cache_alloc)(&c, &net->mlp, chunk);
    if (!s && net->cfg.mode == MLB_MATERIAL_LATENT) s = FN(mlp_cache_alloc)(&dc, &net->dec, chunk);
    for (size_t start = 0; !s && start < n; start += (size_t)chunk) {
        int B = (int)(n - start < (size_t)chunk ? n - start : (size_t)chunk);
        const real* out = FN(mat_run)(net, &c, &dc, x, feat, pos + 3 * start, B, k ? k + K_DIM * start : NULL, 0);
        if (z) memcpy(z + (size_t)O * start, out, sizeof(real) * (size_t)O * B);
    }
    free(x);
    free(feat);
    FN(mlp_cache_free)(&c);
    FN(mlp_cache_free)(&dc);
    return s;
}

mlb_status FN(material_net_decode)(const FN(mlb_material_net)* net, const real* z, size_t n, real* k) {
    if (net->cfg.mode != MLB_MATERIAL_LATENT) return mlb_fail(MLB_ERR_ARG, "material network: a direct-mode network has no decoder");
    if (n == 0) return MLB_OK;
    int chunk = n < EVAL_CHUNK ? (int)n : EVAL_CHUNK;
    FN(mlb_mlp_cache) dc;
    MLB_TRY(FN(mlp_cache_alloc)(&dc, &net->dec, chunk));
    for (size_t start = 0; start < n; start += (size_t)chunk) {
        int B = (int)(n - start < (size_t)chunk ? n - start : (size_t)chunk);
        const real* s = FN(mlp_forward_sharded)(&net->dec, &dc, z + Z_DIM * start, B, 0);
        FN(material_map_to_ranges)(k + K_DIM * start, s, B);
    }
    FN(mlp_cache_free)(&dc);
    return MLB_OK;
}
