// UNet forward (see unet.h, docs/unet.md). Activations live in one arena allocated per call:
// two feature maps of the largest size, the skip stack and the transformer scratch. The walk and
// its blocks also run the training forward (unet_train.h), which keeps their outputs on a tape
// instead of overwriting them: the same ops in the same order, so the same bits.
#include "matlaber/unet.h"
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"
#include "unet_internal.h"

static mlb_status conv(const mlb_backend* be, float* out, const float* in, const float* w, const float* b, int N,
                       int C, int H, int W, int OC, int K, int stride, int pad) {
    mlb_conv2d cv = mlb_conv2d_make(N, C, H, W, OC, K, stride, pad);
    return be->conv2d(be, out, in, w, b, &cv);
}

// out [N, cout, H, W] = resnet(x [N, cin, H, W]); out must not overlap x. With a tape, h1 (conv1 +
// time) is kept and gn2 normalises out of place; without, in place in ws->tb.
mlb_status unet_resnet_fwd(const mlb_backend* be, const mlb_unet* u, const mlb_unet_resnet* r, float* out,
                           const float* x, int N, int H, int W, unet_ws* ws, unet_res_tape* rt) {
    const mlb_unet_config* c = &u->cfg;
    int HW = H * W, G = c->norm_groups;
    float* h1 = rt ? rt->h1 : ws->tb;
    MLB_TRY(be->groupnorm(ws->ta, rt ? rt->m1 : NULL, rt ? rt->r1 : NULL, x, r->norm1_w, r->norm1_b, N, r->cin, HW, G,
                          c->norm_eps, MLB_ACT_SILU));
    MLB_TRY(conv(be, h1, ws->ta, r->conv1_w, r->conv1_b, N, r->cin, H, W, r->cout, 3, 1, 1));
    MLB_TRY(be->linear(be, ws->tvec, ws->emb_silu, r->temb_w, r->temb_b, N, c->time_embed_dim, r->cout));
    MLB_TRY(be->add_channel(h1, ws->tvec, N, r->cout, HW));
    MLB_TRY(be->groupnorm(ws->tb, rt ? rt->m2 : NULL, rt ? rt->r2 : NULL, h1, r->norm2_w, r->norm2_b, N, r->cout, HW,
                          G, c->norm_eps, MLB_ACT_SILU));
    MLB_TRY(conv(be, out, ws->tb, r->conv2_w, r->conv2_b, N, r->cout, H, W, r->cout, 3, 1, 1));
    size_t n = (size_t)N * r->cout * HW;
    if (r->skip_w) {
        MLB_TRY(conv(be, ws->ta, x, r->skip_w, r->skip_b, N, r->cin, H, W, r->cout, 1, 1, 0));
        return be->add(out, ws->ta, n);
    }
    return be->add(out, x, n);
}

// xo [N, C, H, W] = xi + transformer(xi, context [N, Tc, D]); xo == xi in place. Without a tape the
// residual stream is updated in place in ws->tok; with one, each stage's stream is a new tape slot
// (a copy, then the same add) and q/k/v, the attention outputs, lse and GEGLU's input are kept.
mlb_status unet_attn_fwd(const mlb_backend* be, const mlb_unet* u, const mlb_unet_transformer* a, float* xo,
                         const float* xi, const float* ctx, int N, int H, int W, int Tc, unet_ws* ws,
                         unet_attn_tape* at) {
    const mlb_unet_config* c = &u->cfg;
    int C = a->C, T = H * W, D = c->context_dim, NT = N * T;
    size_t nt = (size_t)NT * C;
    float* tok = at ? at->tok[0] : ws->tok;
#define NEXT_TOK(i) do { if (at) { MLB_TRY(be->copy(at->tok[i], tok, nt)); tok = at->tok[i]; } } while (0)
#define LN_STATS(i) at ? at->lm[i] : NULL, at ? at->lr[i] : NULL
    MLB_TRY(be->groupnorm(ws->ta, at ? at->m : NULL, at ? at->r : NULL, xi, a->norm_w, a->norm_b, N, C, T,
                          c->norm_groups, c->transformer_norm_eps, MLB_ACT_IDENTITY));
    MLB_TRY(be->transpose_last2(ws->ln, ws->ta, N, C, T, 0));                        // [N, T, C]
    MLB_TRY(be->linear(be, tok, ws->ln, a->proj_in_w, a->proj_in_b, NT, C, C));
    // self-attention
    float *q = at ? at->q1 : ws->q, *k = at ? at->k1 : ws->k, *v = at ? at->v1 : ws->v, *att = at ? at->o1 : ws->att;
    MLB_TRY(be->layernorm_stats(ws->ln, LN_STATS(0), tok, a->ln1_w, a->ln1_b, NT, C, c->layer_norm_eps));
    MLB_TRY(be->linear(be, q, ws->ln, a->q1, NULL, NT, C, C));
    MLB_TRY(be->linear(be, k, ws->ln, a->k1, NULL, NT, C, C));
    MLB_TRY(be->linear(be, v, ws->ln, a->v1, NULL, NT, C, C));
    MLB_TRY(be->sdpa(be, att, at ? at->lse1 : NULL, q, k, v, N, T, T, C, a->heads, C, C));
    MLB_TRY(be->linear(be, ws->tmp, att, a->o1_w, a->o1_b, NT, C, C));
    NEXT_TOK(1);
    MLB_TRY(be->add(tok, ws->tmp, nt));
    // cross-attention
    if (at) q = at->q2, k = at->k2, v = at->v2, att = at->o2;
    MLB_TRY(be->layernorm_stats(ws->ln, LN_STATS(1), tok, a->ln2_w, a->ln2_b, NT, C, c->layer_norm_eps));
    MLB_TRY(be->linear(be, q, ws->ln, a->q2, NULL, NT, C, C));
    MLB_TRY(be->linear(be, k, ctx, a->k2, NULL, N * Tc, D, C));
    MLB_TRY(be->linear(be, v, ctx, a->v2, NULL, N * Tc, D, C));
    MLB_TRY(be->sdpa(be, att, at ? at->lse2 : NULL, q, k, v, N, T, Tc, C, a->heads, C, C));
    MLB_TRY(be->linear(be, ws->tmp, att, a->o2_w, a->o2_b, NT, C, C));
    NEXT_TOK(2);
    MLB_TRY(be->add(tok, ws->tmp, nt));
    // GEGLU feed-forward: [h | gate] = W1 ln3(x); x += W2 (h * gelu(gate))
    float* ff = at ? at->ff : ws->ff;
    MLB_TRY(be->layernorm_stats(ws->ln, LN_STATS(2), tok, a->ln3_w, a->ln3_b, NT, C, c->layer_norm_eps));
    MLB_TRY(be->linear(be, ff, ws->ln, a->ff1_w, a->ff1_b, NT, C, 8 * C));
    MLB_TRY(be->geglu(ws->gg, ff, NT, 4 * C));
    MLB_TRY(be->linear(be, ws->tmp, ws->gg, a->ff2_w, a->ff2_b, NT, 4 * C, C));
    NEXT_TOK(3);
    MLB_TRY(be->add(tok, ws->tmp, nt));
#undef NEXT_TOK
#undef LN_STATS
    // proj_out, back to NCHW, plus the residual
    MLB_TRY(be->linear(be, ws->ln, tok, a->proj_out_w, a->proj_out_b, NT, C, C));
    if (xo != xi) MLB_TRY(be->copy(xo, xi, nt));
    return be->transpose_last2(xo, ws->ln, N, T, C, 1);
}

// The observer sees host memory: a device tensor is copied down first (debugging only).
static mlb_status report(const mlb_backend* be, mlb_unet_debug_fn fn, void* user, const char* name, const float* d,
                         size_t n) {
    if (!fn) return MLB_OK;
    if (be->device == MLB_DEVICE_CPU) {
        fn(user, name, d, n);
        return MLB_OK;
    }
    float* h = malloc(n * sizeof(float));
    if (!h) return mlb_fail(MLB_ERR_NOMEM, "UNet forward: out of memory for the observer's copy of %s", name);
    mlb_status s = be->download(h, d, n);
    if (s == MLB_OK) fn(user, name, h, n);
    free(h);
    return s;
}

static mlb_status forward_on(const mlb_backend* be, const mlb_unet* u, float* out, const float* x, const float* t,
                             const float* context, int N, int H, int W, int Tc, mlb_unet_debug_fn debug,
                             void* debug_user);

mlb_status mlb_unet_forward(const mlb_backend* be, const mlb_unet* u, float* out, const float* x, const float* t,
                            const float* context, int N, int H, int W, int Tc, mlb_unet_debug_fn debug,
                            void* debug_user) {
    if (be) return forward_on(be, u, out, x, t, context, N, H, W, Tc, debug, debug_user);
    if (!u || !u->mirror)   // on the CPU: its fp32 ops, or the bf16 ones (mlb_unet_use_device)
        return forward_on(u && u->mirror_ops ? u->mirror_ops : mlb_backend_cpu(), u, out, x, t, context, N, H, W, Tc,
                          debug, debug_user);
    // on the mirror's device: x, context and out staged in one device buffer (allocated per call,
    // as the activations are: small beside them)
    if (!out || !x || !t || !context || N < 1 || H < 1 || W < 1 || Tc < 1)
        return mlb_fail(MLB_ERR_ARG, "UNet forward: NULL argument or empty shape");
    const mlb_unet* du = u->mirror;
    be = u->mirror_ops;
    size_t nx = (size_t)N * du->cfg.in_channels * H * W, nc = (size_t)N * Tc * du->cfg.context_dim;
    size_t no = (size_t)N * du->cfg.out_channels * H * W;
    float* stage;
    MLB_TRY(be->alloc(&stage, nx + nc + no));
    float *dx = stage, *dc = dx + nx, *dout = dc + nc;
    mlb_status s = be->upload(dx, x, nx);
    if (s == MLB_OK) s = be->upload(dc, context, nc);
    if (s == MLB_OK) s = forward_on(be, du, dout, dx, t, dc, N, H, W, Tc, debug, debug_user);
    if (s == MLB_OK) s = be->download(out, dout, no);
    be->release(stage);
    return s;
}

// The timestep sinusoid (float32, as diffusers): f_i = exp(-ln(10000) * i / (half - shift)).
void unet_time_proj(const mlb_unet_config* c, const float* t, int N, float* out) {
    int C0 = c->block_out[0], half = C0 / 2;
    for (int b = 0; b < N; b++)
        for (int i = 0; i < half; i++) {
            float e = (float)(-log(10000.0)) * (float)i;
            e = e / ((float)half - c->freq_shift);
            float a = t[b] * expf(e);
            float cs = (float)cos((double)a), sn = (float)sin((double)a);
            out[(size_t)b * C0 + i] = c->flip_sin_to_cos ? cs : sn;
            out[(size_t)b * C0 + half + i] = c->flip_sin_to_cos ? sn : cs;
        }
}

mlb_status unet_check(const mlb_backend* be, const mlb_unet* u, int N, int H, int W, int Tc) {
    if (u->device != be->device)
        return mlb_fail(MLB_ERR_ARG, "UNet forward: the weights are on the %s, the ops on the %s (mlb_unet_to_device)",
                        mlb_device_name(u->device), mlb_device_name(be->device));
    // weights stored in 16 bits run on their own table only, fp32 weights on any other
    const mlb_backend* stored_ops = u->bf16_weights ? mlb_backend_cpu_bf16_stored()
                                  : u->f16_weights  ? mlb_backend_cpu_f16_stored() : NULL;
    int be_stored = be == mlb_backend_cpu_bf16_stored() || be == mlb_backend_cpu_f16_stored();
    if (stored_ops ? be != stored_ops : be_stored)
        return mlb_fail(MLB_ERR_ARG, "UNet forward: weights stored in %s, ops for weights in %s",
                        u->bf16_weights ? "bf16" : u->f16_weights ? "f16" : "fp32",
                        be == mlb_backend_cpu_bf16_stored() ? "bf16" : be == mlb_backend_cpu_f16_stored() ? "f16" : "fp32");
    int n = u->cfg.n_levels, f = 1 << (n - 1);
    if (N < 1 || H < 1 || W < 1 || Tc < 1)
        return mlb_fail(MLB_ERR_ARG, "UNet forward: batch %d, latent %dx%d, context length %d must be positive", N, H, W, Tc);
    if (H % f || W % f)
        return mlb_fail(MLB_ERR_ARG, "UNet forward: latent %dx%d is not a multiple of %d (%d downsamplings)", H, W, f, n - 1);
    return MLB_OK;
}

void unet_sizes_of(const mlb_unet_config* c, int N, int H, int W, int Tc, unet_sizes* s) {
    int n = c->n_levels, NL = c->layers_per_block, C0 = c->block_out[0];
    s->cmax = C0;
    s->fmax = s->amax = 0;
    s->skip_total = (size_t)N * C0 * H * W;
    for (int l = 0; l < n; l++) {
        size_t hw = (size_t)(H >> l) * (W >> l);
        int cl = c->block_out[l], cn = c->block_out[l < n - 1 ? l + 1 : l], cp = c->block_out[l > 0 ? l - 1 : 0];
        if (cl > s->cmax) s->cmax = cl;
        int cat = (cl > cn ? cl : cn) + (cl > cp ? cl : cp);   // widest concat at this resolution
        size_t fl = (size_t)N * hw * (size_t)(cat > cl ? cat : cl);
        if (fl > s->fmax) s->fmax = fl;
        if (c->attn[l] || l == n - 1) {
            size_t al = (size_t)N * hw * cl;
            if (al > s->amax) s->amax = al;
        }
        s->skip_total += (size_t)N * hw * cl * (size_t)(NL + (l < n - 1));
    }
    s->kv = (size_t)N * Tc * s->cmax;
}

mlb_status unet_walk(const mlb_backend* be, const mlb_unet* u, float* out, const float* x, const float* t,
                     const float* ctx, int N, int H, int W, int Tc, mlb_unet_debug_fn debug, void* debug_user,
                     unet_ws* ws, float* h, float* h2, float* skips, float* emb, float* tproj, mlb_unet_tape* tp) {
    const mlb_unet_config* c = &u->cfg;
    int n = c->n_levels, NL = c->layers_per_block, TE = c->time_embed_dim, C0 = c->block_out[0];
    if (tp) emb = tp->emb, tproj = tp->tproj;
    float* tproj_host = malloc((size_t)N * C0 * sizeof(float));
    if (!tproj_host) return mlb_fail(MLB_ERR_NOMEM, "UNet forward: out of memory");
    mlb_status s = MLB_OK;
#define CK(e) do { if ((s = (e)) != MLB_OK) goto done; } while (0)
    unet_time_proj(c, t, N, tproj_host);
    CK(be->upload(tproj, tproj_host, (size_t)N * C0));
    CK(report(be, debug, debug_user, "time_proj", tproj, (size_t)N * C0));
    // e1 = time1(tproj), s1 = silu(e1), emb = time2(s1), emb_silu = silu(emb): in place without a tape
    float *e1 = tp ? tp->e1 : ws->emb_silu, *s1 = tp ? tp->s1 : ws->emb_silu;
    CK(be->linear(be, e1, tproj, u->time1_w, u->time1_b, N, C0, TE));
    CK(be->activation(s1, e1, (size_t)N * TE, MLB_ACT_SILU));
    CK(be->linear(be, emb, s1, u->time2_w, u->time2_b, N, TE, TE));
    CK(report(be, debug, debug_user, "time_embedding", emb, (size_t)N * TE));
    CK(be->activation(ws->emb_silu, emb, (size_t)N * TE, MLB_ACT_SILU));

    // skip stack: copies without a tape, the tape's own slots with one
    float* sp[1 + MLB_UNET_MAX_LEVELS * (MLB_UNET_MAX_LAYERS + 1)];
    int sc[1 + MLB_UNET_MAX_LEVELS * (MLB_UNET_MAX_LAYERS + 1)], ns = 0;
    float* stop = skips;
    int ch = C0, hh = H, ww = W;
    float *cur = h2, *dst;   // cur: the current activation; without a tape h and h2 alternate
#define OTHER(p_) ((p_) == h ? h2 : h)
#define DST(slot_) (tp ? (slot_) : OTHER(cur))
#define PUSH() do { size_t m_ = (size_t)N * ch * hh * ww; \
                    if (tp) sp[ns] = cur; else { CK(be->copy_rows(stop, m_, cur, m_, m_, 1)); sp[ns] = stop; stop += m_; } \
                    sc[ns++] = ch; } while (0)
    char name[64];
    dst = DST(tp->conv_in);
    CK(conv(be, dst, x, u->conv_in_w, u->conv_in_b, N, c->in_channels, H, W, C0, 3, 1, 1));
    cur = dst;
    CK(report(be, debug, debug_user, "conv_in", cur, (size_t)N * C0 * H * W));
    PUSH();
    for (int i = 0; i < n; i++) {
        for (int j = 0; j < NL; j++) {
            dst = DST(tp->down_res[i][j]);
            CK(unet_resnet_fwd(be, u, &u->down_res[i][j], dst, cur, N, hh, ww, ws, tp ? &tp->down_rt[i][j] : NULL));
            cur = dst;
            ch = u->down_res[i][j].cout;
            if (c->attn[i]) {
                dst = tp ? tp->down_attn[i][j] : cur;
                CK(unet_attn_fwd(be, u, &u->down_attn[i][j], dst, cur, ctx, N, hh, ww, Tc, ws,
                                 tp ? &tp->down_at[i][j] : NULL));
                cur = dst;
            }
            PUSH();
        }
        if (i < n - 1) {
            dst = DST(tp->down_conv[i]);
            CK(conv(be, dst, cur, u->down_conv[i].w, u->down_conv[i].b, N, ch, hh, ww, ch, 3, 2, 1));
            cur = dst;
            hh /= 2;
            ww /= 2;
            PUSH();
        }
        snprintf(name, sizeof name, "down_blocks.%d", i);
        CK(report(be, debug, debug_user, name, cur, (size_t)N * ch * hh * ww));
    }
    dst = DST(tp->mid_res[0]);
    CK(unet_resnet_fwd(be, u, &u->mid_res[0], dst, cur, N, hh, ww, ws, tp ? &tp->mid_rt[0] : NULL));
    cur = dst;
    dst = tp ? tp->mid_attn : cur;
    CK(unet_attn_fwd(be, u, &u->mid_attn, dst, cur, ctx, N, hh, ww, Tc, ws, tp ? &tp->mid_at : NULL));
    cur = dst;
    dst = DST(tp->mid_res[1]);
    CK(unet_resnet_fwd(be, u, &u->mid_res[1], dst, cur, N, hh, ww, ws, tp ? &tp->mid_rt[1] : NULL));
    cur = dst;
    CK(report(be, debug, debug_user, "mid_block", cur, (size_t)N * ch * hh * ww));
    for (int i = 0; i < n; i++) {
        int lvl = n - 1 - i;
        for (int j = 0; j <= NL; j++) {
            // concat [h | skip] along channels
            int sk = sc[--ns];
            size_t hw = (size_t)hh * ww;
            float* cat = DST(tp->up_cat[i][j]);
            CK(be->copy_rows(cat, (ch + sk) * hw, cur, ch * hw, ch * hw, N));
            CK(be->copy_rows(cat + ch * hw, (ch + sk) * hw, sp[ns], sk * hw, sk * hw, N));
            dst = tp ? tp->up_res[i][j] : OTHER(cat);
            CK(unet_resnet_fwd(be, u, &u->up_res[i][j], dst, cat, N, hh, ww, ws, tp ? &tp->up_rt[i][j] : NULL));
            cur = dst;
            ch = u->up_res[i][j].cout;
            if (c->attn[lvl]) {
                dst = tp ? tp->up_attn[i][j] : cur;
                CK(unet_attn_fwd(be, u, &u->up_attn[i][j], dst, cur, ctx, N, hh, ww, Tc, ws,
                                 tp ? &tp->up_at[i][j] : NULL));
                cur = dst;
            }
        }
        if (i < n - 1) {
            float* up = tp ? ws->ta : OTHER(cur);   // the upsampled map: recomputed by the backward
            CK(be->upsample_nearest2x(up, cur, N, ch, hh, ww));
            hh *= 2;
            ww *= 2;
            dst = tp ? tp->up_conv[i] : OTHER(up);
            CK(conv(be, dst, up, u->up_conv[i].w, u->up_conv[i].b, N, ch, hh, ww, ch, 3, 1, 1));
            cur = dst;
        }
        snprintf(name, sizeof name, "up_blocks.%d", i);
        CK(report(be, debug, debug_user, name, cur, (size_t)N * ch * hh * ww));
    }
    if (tp) tp->hf = cur;
    float* gn = tp ? ws->ta : OTHER(cur);
    CK(be->groupnorm(gn, tp ? tp->out_m : NULL, tp ? tp->out_r : NULL, cur, u->norm_out_w, u->norm_out_b, N, ch, H * W,
                     c->norm_groups, c->norm_eps, MLB_ACT_IDENTITY));
    CK(report(be, debug, debug_user, "conv_norm_out", gn, (size_t)N * ch * H * W));
    CK(be->activation(gn, gn, (size_t)N * ch * H * W, MLB_ACT_SILU));
    CK(conv(be, out, gn, u->conv_out_w, u->conv_out_b, N, ch, H, W, c->out_channels, 3, 1, 1));
#undef PUSH
#undef DST
#undef OTHER
#undef CK
done:
    free(tproj_host);
    return s;
}

static mlb_status forward_on(const mlb_backend* be, const mlb_unet* u, float* out, const float* x, const float* t,
                             const float* context, int N, int H, int W, int Tc, mlb_unet_debug_fn debug,
                             void* debug_user) {
    if (!be || !u || !out || !x || !t || !context) return mlb_fail(MLB_ERR_ARG, "UNet forward: NULL argument");
    MLB_TRY(unet_check(be, u, N, H, W, Tc));
    const mlb_unet_config* c = &u->cfg;
    int TE = c->time_embed_dim, C0 = c->block_out[0];
    unet_sizes z;
    unet_sizes_of(c, N, H, W, Tc, &z);
    size_t fmax = z.fmax, amax = z.amax, kv = z.kv;
    size_t total = 4 * fmax + z.skip_total + 5 * amax + 2 * (amax > kv ? amax : kv) + 8 * amax + 4 * amax +
                   (size_t)N * TE * 2 + (size_t)N * z.cmax + (size_t)N * C0;
    float* arena;
    if (be->alloc(&arena, total) != MLB_OK)
        return mlb_fail_context(MLB_ERR_NOMEM, "UNet forward: %.1f MB of activations on the %s", total * 4.0 / 1e6,
                                mlb_device_name(be->device));
    float* p = arena;
#define TAKE(n_) (p += (n_), p - (n_))
    unet_ws ws;
    float* h = TAKE(fmax);
    float* h2 = TAKE(fmax);
    ws.ta = TAKE(fmax);
    ws.tb = TAKE(fmax);
    float* skips = TAKE(z.skip_total);
    ws.tok = TAKE(amax); ws.ln = TAKE(amax); ws.q = TAKE(amax); ws.att = TAKE(amax); ws.tmp = TAKE(amax);
    ws.k = TAKE(amax > kv ? amax : kv); ws.v = TAKE(amax > kv ? amax : kv);
    ws.ff = TAKE(8 * amax); ws.gg = TAKE(4 * amax);
    ws.emb_silu = TAKE((size_t)N * TE);
    float* emb = TAKE((size_t)N * TE);
    ws.tvec = TAKE((size_t)N * z.cmax);
    float* tproj = TAKE((size_t)N * C0);
#undef TAKE
    mlb_status s = unet_walk(be, u, out, x, t, context, N, H, W, Tc, debug, debug_user, &ws, h, h2, skips, emb, tproj,
                             NULL);
    be->release(arena);
    return s;
}
