// The UNet's tape (unet_train.h): one allocation carved by the same walk over the configuration
// that sizes it, and the training forward, which is the forward's walk (unet.c) writing there.
#include <stdlib.h>
#include <string.h>
#include "unet_internal.h"

// n floats at base + *used (NULL when only counting)
static float* take(float* base, size_t* used, size_t n) {
    float* r = base ? base + *used : NULL;
    *used += n;
    return r;
}

static void carve_res(unet_res_tape* rt, float* base, size_t* used, int N, int G, int cout, size_t hw) {
    rt->h1 = take(base, used, (size_t)N * cout * hw);
    rt->m1 = take(base, used, (size_t)N * G);
    rt->r1 = take(base, used, (size_t)N * G);
    rt->m2 = take(base, used, (size_t)N * G);
    rt->r2 = take(base, used, (size_t)N * G);
}

static void carve_attn(unet_attn_tape* at, float* base, size_t* used, int N, int G, int C, int heads, size_t T,
                       int Tc) {
    size_t nt = (size_t)N * T * C, kv = (size_t)N * Tc * C, lse = (size_t)N * heads * T;
    at->m = take(base, used, (size_t)N * G);
    at->r = take(base, used, (size_t)N * G);
    for (int i = 0; i < 4; i++) at->tok[i] = take(base, used, nt);
    for (int i = 0; i < 3; i++) {
        at->lm[i] = take(base, used, (size_t)N * T);
        at->lr[i] = take(base, used, (size_t)N * T);
    }
    at->q1 = take(base, used, nt);
    at->k1 = take(base, used, nt);
    at->v1 = take(base, used, nt);
    at->o1 = take(base, used, nt);
    at->lse1 = take(base, used, lse);
    at->q2 = take(base, used, nt);
    at->k2 = take(base, used, kv);
    at->v2 = take(base, used, kv);
    at->o2 = take(base, used, nt);
    at->lse2 = take(base, used, lse);
    at->ff = take(base, used, 8 * nt);
}

size_t unet_tape_carve(mlb_unet_tape* tp, const mlb_unet_config* c, int N, int H, int W, int Tc, float* base) {
    unet_sizes z;
    unet_sizes_of(c, N, H, W, Tc, &z);
    int n = c->n_levels, NL = c->layers_per_block, G = c->norm_groups, TE = c->time_embed_dim, C0 = c->block_out[0];
    size_t u = 0, *used = &u;
#define TAKE(n_) take(base, used, (n_))
    tp->x = TAKE((size_t)N * c->in_channels * H * W);
    tp->ctx = TAKE((size_t)N * Tc * c->context_dim);
    tp->tproj = TAKE((size_t)N * C0);
    tp->e1 = TAKE((size_t)N * TE);
    tp->s1 = TAKE((size_t)N * TE);
    tp->emb = TAKE((size_t)N * TE);
    tp->es = tp->ws.emb_silu = TAKE((size_t)N * TE);
    // the blocks, in the forward's order, with the skip channels as the forward stacks them
    int sc[1 + MLB_UNET_MAX_LEVELS * (MLB_UNET_MAX_LAYERS + 1)], ns = 0, ch = C0;
    size_t hw = (size_t)H * W;
    tp->conv_in = TAKE((size_t)N * C0 * hw);
    sc[ns++] = ch;
    for (int i = 0; i < n; i++) {
        for (int j = 0; j < NL; j++) {
            ch = c->block_out[i];
            tp->down_res[i][j] = TAKE((size_t)N * ch * hw);
            carve_res(&tp->down_rt[i][j], base, used, N, G, ch, hw);
            if (c->attn[i]) {
                tp->down_attn[i][j] = TAKE((size_t)N * ch * hw);
                carve_attn(&tp->down_at[i][j], base, used, N, G, ch, c->heads[i], hw, Tc);
            }
            sc[ns++] = ch;
        }
        if (i < n - 1) {
            hw /= 4;
            tp->down_conv[i] = TAKE((size_t)N * ch * hw);
            sc[ns++] = ch;
        }
    }
    for (int k = 0; k < 2; k++) {
        tp->mid_res[k] = TAKE((size_t)N * ch * hw);
        carve_res(&tp->mid_rt[k], base, used, N, G, ch, hw);
    }
    tp->mid_attn = TAKE((size_t)N * ch * hw);
    carve_attn(&tp->mid_at, base, used, N, G, ch, c->mid_heads, hw, Tc);
    for (int i = 0; i < n; i++) {
        int lvl = n - 1 - i;
        for (int j = 0; j <= NL; j++) {
            int sk = sc[--ns];
            tp->up_cat[i][j] = TAKE((size_t)N * (ch + sk) * hw);
            ch = c->block_out[lvl];
            tp->up_res[i][j] = TAKE((size_t)N * ch * hw);
            carve_res(&tp->up_rt[i][j], base, used, N, G, ch, hw);
            if (c->attn[lvl]) {
                tp->up_attn[i][j] = TAKE((size_t)N * ch * hw);
                carve_attn(&tp->up_at[i][j], base, used, N, G, ch, c->heads[lvl], hw, Tc);
            }
        }
        if (i < n - 1) {
            hw *= 4;
            tp->up_conv[i] = TAKE((size_t)N * ch * hw);
        }
    }
    tp->out_m = TAKE((size_t)N * G);
    tp->out_r = TAKE((size_t)N * G);
    // the forward's scratch (the transformer's q/k/v, attention, stream and GEGLU input live above)
    size_t fmax = z.fmax, amax = z.amax, kvm = amax > z.kv ? amax : z.kv;
    tp->ws.ta = TAKE(fmax);
    tp->ws.tb = TAKE(fmax);
    tp->ws.ln = TAKE(amax);
    tp->ws.tmp = TAKE(amax);
    tp->ws.gg = TAKE(4 * amax);
    tp->ws.tvec = TAKE((size_t)N * z.cmax);
    tp->ws.tok = tp->ws.q = tp->ws.k = tp->ws.v = tp->ws.att = tp->ws.ff = NULL;
    // the backward's
    for (int i = 0; i < 3; i++) tp->g[i] = TAKE(fmax);
    for (int i = 0; i < 3; i++) tp->s[i] = TAKE(fmax);
    tp->dskip = TAKE(z.skip_total);
    tp->dtok = TAKE(amax);
    tp->dln = TAKE(amax);
    tp->datt = TAKE(amax);
    tp->dq = TAKE(amax);
    tp->dk = TAKE(kvm);
    tp->dv = TAKE(kvm);
    tp->dff = TAKE(8 * amax);
    tp->dgg = TAKE(4 * amax);
    tp->demb_s = TAKE((size_t)N * TE);
    tp->demb = TAKE((size_t)N * TE);
    tp->ds1 = TAKE((size_t)N * TE);
    tp->dtvec = TAKE((size_t)N * z.cmax);
#undef TAKE
    return u;
}

size_t mlb_unet_tape_floats(const mlb_unet_config* c, int N, int H, int W, int Tc) {
    int f = c && c->n_levels >= 1 ? 1 << (c->n_levels - 1) : 0;
    if (!f || N < 1 || H < 1 || W < 1 || Tc < 1 || H % f || W % f) return 0;
    mlb_unet_tape tp;
    return unet_tape_carve(&tp, c, N, H, W, Tc, NULL);
}

mlb_status mlb_unet_tape_create(const mlb_backend* be, const mlb_unet* u, int N, int H, int W, int Tc,
                                mlb_unet_tape** out) {
    if (!be || !u || !out) return mlb_fail(MLB_ERR_ARG, "UNet tape: NULL argument");
    *out = NULL;
    size_t n = mlb_unet_tape_floats(&u->cfg, N, H, W, Tc);
    if (!n) return mlb_fail(MLB_ERR_ARG, "UNet tape: batch %d, latent %dx%d, context %d is not a shape the UNet takes", N, H,
                            W, Tc);
    mlb_unet_tape* tp = calloc(1, sizeof *tp);
    if (!tp) return mlb_fail(MLB_ERR_NOMEM, "UNet tape: out of memory");
    if (be->alloc(&tp->arena, n) != MLB_OK) {
        free(tp);
        return mlb_fail_context(MLB_ERR_NOMEM, "UNet tape: %.1f MB on the %s", n * 4.0 / 1e6, mlb_device_name(be->device));
    }
    tp->device = be->device;
    tp->cap = n;
    tp->cfg = u->cfg;
    *out = tp;
    return MLB_OK;
}

void mlb_unet_tape_free(mlb_unet_tape* tape) {
    if (!tape) return;
    mlb_backend_for(tape->device, MLB_GEMM_FP32)->release(tape->arena);
    free(tape);
}

mlb_status mlb_unet_forward_train(const mlb_backend* be, const mlb_unet* u, mlb_unet_tape* tp, float* out,
                                  const float* x, const float* t, const float* ctx, int N, int H, int W, int Tc) {
    if (!be || !u || !tp || !out || !x || !t || !ctx) return mlb_fail(MLB_ERR_ARG, "UNet forward_train: NULL argument");
    MLB_TRY(unet_check(be, u, N, H, W, Tc));
    if (tp->device != be->device || memcmp(&tp->cfg, &u->cfg, sizeof u->cfg))
        return mlb_fail(MLB_ERR_ARG, "UNet forward_train: the tape was made for another UNet or device");
    size_t need = unet_tape_carve(tp, &u->cfg, N, H, W, Tc, NULL);
    if (need > tp->cap)
        return mlb_fail(MLB_ERR_ARG, "UNet forward_train: batch %d, latent %dx%d, context %d needs %zu floats, the tape holds %zu",
                        N, H, W, Tc, need, tp->cap);
    tp->ready = 0;
    unet_tape_carve(tp, &u->cfg, N, H, W, Tc, tp->arena);
    tp->N = N, tp->H = H, tp->W = W, tp->Tc = Tc;
    MLB_TRY(be->copy(tp->x, x, (size_t)N * u->cfg.in_channels * H * W));
    MLB_TRY(be->copy(tp->ctx, ctx, (size_t)N * Tc * u->cfg.context_dim));
    MLB_TRY(unet_walk(be, u, out, tp->x, t, tp->ctx, N, H, W, Tc, NULL, NULL, &tp->ws, NULL, NULL, NULL, NULL, NULL,
                      tp));
    tp->ready = 1;
    return MLB_OK;
}
