// The UNet's backward (unet_train.h): the forward's walk (unet.c) in reverse over the tape, each
// block's backward against the op table. Gradient maps live in the tape's scratch: g[0], g[1] (the
// current activation's gradient and the next, swapped), g[2] (an up ResNet's concat gradient), s[]
// (a block's inner gradients), dskip (each skip's gradient, written by the up path, added back on
// the down path where the skip was pushed).
#include <stdlib.h>
#include <string.h>
#include "unet_internal.h"

static mlb_status conv_bwd(const mlb_backend* be, float* din, float* dw, float* db, const float* dout, const float* in,
                           const float* w, int N, int C, int H, int W, int OC, int K, int stride, int pad) {
    mlb_conv2d cv = mlb_conv2d_make(N, C, H, W, OC, K, stride, pad);
    return be->conv2d_backward(be, din, dw, db, dout, in, w, &cv);
}

// dx [N, cin, H, W] += d resnet(x) given dout [N, cout, H, W]; gr += the block's parameter gradients;
// tp->demb_s += d silu(emb). out = conv2(silu(gn2(h1))) + skip(x), h1 = conv1(silu(gn1(x))) + temb.
static mlb_status resnet_bwd(const mlb_backend* be, const mlb_unet* u, const mlb_unet_resnet* r, mlb_unet_resnet* gr,
                             const unet_res_tape* rt, const float* x, const float* dout, float* dx, int N, int H, int W,
                             mlb_unet_tape* tp) {
    const mlb_unet_config* c = &u->cfg;
    int HW = H * W, G = c->norm_groups, cin = r->cin, cout = r->cout;
    size_t nin = (size_t)N * cin * HW, nout = (size_t)N * cout * HW;
    float *a = tp->s[0], *da = tp->s[1], *dh1 = tp->s[2];
    if (r->skip_w)
        MLB_TRY(conv_bwd(be, dx, gr->skip_w, gr->skip_b, dout, x, r->skip_w, N, cin, H, W, cout, 1, 1, 0));
    else
        MLB_TRY(be->add(dx, dout, nout));
    // conv2 over a2 = silu(gn2(h1)), recomputed (one elementwise pass; the tape keeps h1 only)
    MLB_TRY(be->groupnorm(a, NULL, NULL, rt->h1, r->norm2_w, r->norm2_b, N, cout, HW, G, c->norm_eps, MLB_ACT_SILU));
    MLB_TRY(be->zero(da, nout));
    MLB_TRY(conv_bwd(be, da, gr->conv2_w, gr->conv2_b, dout, a, r->conv2_w, N, cout, H, W, cout, 3, 1, 1));
    MLB_TRY(be->zero(dh1, nout));
    MLB_TRY(be->groupnorm_backward(dh1, gr->norm2_w, gr->norm2_b, da, rt->h1, r->norm2_w, r->norm2_b, rt->m2, rt->r2, N,
                                   cout, HW, G, MLB_ACT_SILU));
    // the time term: h1[n, c, :] += temb(silu emb)[n, c]
    MLB_TRY(be->zero(tp->dtvec, (size_t)N * cout));
    MLB_TRY(be->add_channel_backward(tp->dtvec, dh1, N, cout, HW));
    MLB_TRY(be->linear_backward(be, tp->demb_s, gr->temb_w, gr->temb_b, tp->dtvec, tp->es, r->temb_w, N,
                                c->time_embed_dim, cout));
    // conv1 over a1 = silu(gn1(x)), recomputed
    MLB_TRY(be->groupnorm(a, NULL, NULL, x, r->norm1_w, r->norm1_b, N, cin, HW, G, c->norm_eps, MLB_ACT_SILU));
    MLB_TRY(be->zero(da, nin));
    MLB_TRY(conv_bwd(be, da, gr->conv1_w, gr->conv1_b, dh1, a, r->conv1_w, N, cin, H, W, cout, 3, 1, 1));
    return be->groupnorm_backward(dx, gr->norm1_w, gr->norm1_b, da, x, r->norm1_w, r->norm1_b, rt->m1, rt->r1, N, cin,
                                  HW, G, MLB_ACT_SILU);
}

// One attention sublayer of a transformer block: tok_out = tok_in + o(sdpa(ln(tok_in) Wq, kv Wk, kv Wv)).
typedef struct {
    const float *ln_w, *ln_b, *wq, *wk, *wv, *o_w;               // weights
    float *g_ln_w, *g_ln_b, *g_wq, *g_wk, *g_wv, *g_o_w, *g_o_b;  // their gradients
    const float *tok_in, *lm, *lr, *q, *k, *v, *o, *lse;         // the tape
} attn_sub;

// dtok [NT, C] = d tok_out on entry, += d tok_in through the sublayer on return. kv: the context
// [N, Tk, Dk] of a cross-attention (dkv += its gradient, may be NULL), or NULL for a self-attention
// (kv = ln(tok_in), Tk = T, Dk = C). ln(tok_in) is recomputed into tp->ws.ln.
static mlb_status attn_sub_bwd(const mlb_backend* be, const attn_sub* s, float* dtok, const float* kv, float* dkv,
                               int N, int T, int Tk, int Dk, int C, int NH, float eps, mlb_unet_tape* tp) {
    const int NT = N * T;
    const size_t nt = (size_t)NT * C, nkv = (size_t)N * Tk * C;
    float *dln = tp->dln, *datt = tp->datt, *dq = tp->dq, *dk = tp->dk, *dv = tp->dv, *ln = tp->ws.ln;
    MLB_TRY(be->zero(datt, nt));
    MLB_TRY(be->linear_backward(be, datt, s->g_o_w, s->g_o_b, dtok, s->o, s->o_w, NT, C, C));
    MLB_TRY(be->zero(dq, nt));
    MLB_TRY(be->zero(dk, nkv));
    MLB_TRY(be->zero(dv, nkv));
    MLB_TRY(be->sdpa_backward(be, dq, dk, dv, datt, s->o, s->lse, s->q, s->k, s->v, N, T, Tk, C, NH, C, C));
    MLB_TRY(be->layernorm_stats(ln, NULL, NULL, s->tok_in, s->ln_w, s->ln_b, NT, C, eps));
    MLB_TRY(be->zero(dln, nt));
    MLB_TRY(be->linear_backward(be, dln, s->g_wq, NULL, dq, ln, s->wq, NT, C, C));
    if (!kv) { kv = ln; dkv = dln; }   // self-attention: k and v see ln(tok_in) too
    MLB_TRY(be->linear_backward(be, dkv, s->g_wk, NULL, dk, kv, s->wk, N * Tk, Dk, C));
    MLB_TRY(be->linear_backward(be, dkv, s->g_wv, NULL, dv, kv, s->wv, N * Tk, Dk, C));
    return be->layernorm_backward(dtok, s->g_ln_w, s->g_ln_b, dln, s->tok_in, s->ln_w, s->lm, s->lr, NT, C);
}

// dxi [N, C, H, W] += d transformer(xi) given dy = dL/dxo (xo = xi + T(xi)); dctx += (may be NULL).
// dxi must not overlap dy.
static mlb_status attn_bwd(const mlb_backend* be, const mlb_unet* u, const mlb_unet_transformer* a,
                           mlb_unet_transformer* ga, const unet_attn_tape* at, const float* xi, const float* dy,
                           float* dxi, const float* ctx, float* dctx, int N, int H, int W, int Tc, mlb_unet_tape* tp) {
    const mlb_unet_config* c = &u->cfg;
    int C = a->C, T = H * W, D = c->context_dim, NT = N * T, NH = a->heads;
    size_t nt = (size_t)NT * C;
    unet_ws* ws = &tp->ws;
    float *dtok = tp->dtok, *dln = tp->dln, *datt = tp->datt;
    float eps = c->layer_norm_eps;
    MLB_TRY(be->add(dxi, dy, nt));   // the residual
    // proj_out: xo += transpose(tok3 Wo + b)
    MLB_TRY(be->transpose_last2(datt, dy, N, C, T, 0));   // [N, T, C]
    MLB_TRY(be->zero(dtok, nt));
    MLB_TRY(be->linear_backward(be, dtok, ga->proj_out_w, ga->proj_out_b, datt, at->tok[3], a->proj_out_w, NT, C, C));
    // feed-forward: tok3 = tok2 + W2 geglu(W1 ln3(tok2)); dtok carries through the residual
    MLB_TRY(be->geglu(ws->gg, at->ff, NT, 4 * C));
    MLB_TRY(be->zero(tp->dgg, 4 * nt));
    MLB_TRY(be->linear_backward(be, tp->dgg, ga->ff2_w, ga->ff2_b, dtok, ws->gg, a->ff2_w, NT, 4 * C, C));
    MLB_TRY(be->zero(tp->dff, 8 * nt));
    MLB_TRY(be->geglu_backward(tp->dff, tp->dgg, at->ff, NT, 4 * C));
    MLB_TRY(be->layernorm_stats(ws->ln, NULL, NULL, at->tok[2], a->ln3_w, a->ln3_b, NT, C, eps));
    MLB_TRY(be->zero(dln, nt));
    MLB_TRY(be->linear_backward(be, dln, ga->ff1_w, ga->ff1_b, tp->dff, ws->ln, a->ff1_w, NT, C, 8 * C));
    MLB_TRY(be->layernorm_backward(dtok, ga->ln3_w, ga->ln3_b, dln, at->tok[2], a->ln3_w, at->lm[2], at->lr[2], NT, C));
    // cross-attention: tok2 = tok1 + o2(sdpa(ln2(tok1) Wq, ctx Wk, ctx Wv))
    attn_sub cross = {a->ln2_w, a->ln2_b, a->q2, a->k2, a->v2, a->o2_w, ga->ln2_w, ga->ln2_b, ga->q2, ga->k2, ga->v2,
                      ga->o2_w, ga->o2_b, at->tok[1], at->lm[1], at->lr[1], at->q2, at->k2, at->v2, at->o2, at->lse2};
    MLB_TRY(attn_sub_bwd(be, &cross, dtok, ctx, dctx, N, T, Tc, D, C, NH, eps, tp));
    // self-attention: tok1 = tok0 + o1(sdpa(q, k, v)), q/k/v = ln1(tok0) W
    attn_sub self = {a->ln1_w, a->ln1_b, a->q1, a->k1, a->v1, a->o1_w, ga->ln1_w, ga->ln1_b, ga->q1, ga->k1, ga->v1,
                     ga->o1_w, ga->o1_b, at->tok[0], at->lm[0], at->lr[0], at->q1, at->k1, at->v1, at->o1, at->lse1};
    MLB_TRY(attn_sub_bwd(be, &self, dtok, NULL, NULL, N, T, T, C, C, NH, eps, tp));
    // proj_in over the tokens of gn(xi), recomputed
    MLB_TRY(be->groupnorm(ws->ta, NULL, NULL, xi, a->norm_w, a->norm_b, N, C, T, c->norm_groups,
                          c->transformer_norm_eps, MLB_ACT_IDENTITY));
    MLB_TRY(be->transpose_last2(ws->ln, ws->ta, N, C, T, 0));
    MLB_TRY(be->zero(dln, nt));
    MLB_TRY(be->linear_backward(be, dln, ga->proj_in_w, ga->proj_in_b, dtok, ws->ln, a->proj_in_w, NT, C, C));
    MLB_TRY(be->transpose_last2(ws->ta, dln, N, T, C, 0));   // back to [N, C, T]
    return be->groupnorm_backward(dxi, ga->norm_w, ga->norm_b, ws->ta, xi, a->norm_w, a->norm_b, at->m, at->r, N, C, T,
                                  c->norm_groups, MLB_ACT_IDENTITY);
}

mlb_status mlb_unet_backward(const mlb_backend* be, const mlb_unet* u, const mlb_unet_tape* tape, const float* dout,
                             mlb_unet* g, float* dx, float* dctx) {
    if (!be || !u || !tape || !dout || !g) return mlb_fail(MLB_ERR_ARG, "UNet backward: NULL argument");
    mlb_unet_tape* tp = (mlb_unet_tape*)tape;   // its scratch is written; the activations are not
    if (!tp->ready) return mlb_fail(MLB_ERR_ARG, "UNet backward: no forward_train on this tape");
    if (tp->device != be->device || u->device != be->device || g->device != be->device || u->bf16_weights ||
        g->bf16_weights || u->f16_weights || g->f16_weights)
        return mlb_fail(MLB_ERR_ARG, "UNet backward: the UNet, its gradients, the tape and the ops must be on one device, in fp32");
    if (memcmp(&tp->cfg, &u->cfg, sizeof u->cfg) || memcmp(&g->cfg, &u->cfg, sizeof u->cfg))
        return mlb_fail(MLB_ERR_ARG, "UNet backward: the tape or the gradients belong to another configuration");
    const mlb_unet_config* c = &u->cfg;
    int N = tp->N, H = tp->H, W = tp->W, Tc = tp->Tc;
    int n = c->n_levels, NL = c->layers_per_block, G = c->norm_groups, TE = c->time_embed_dim, C0 = c->block_out[0];
    const float* ctx = tp->ctx;
    float *dcur = tp->g[0], *dnext = tp->g[1], *dcat = tp->g[2];
#define SWAP() do { float* t_ = dcur; dcur = dnext; dnext = t_; } while (0)
    // the skip gradients, laid out as the forward pushed the skips
    float* dsp[1 + MLB_UNET_MAX_LEVELS * (MLB_UNET_MAX_LAYERS + 1)];
    int ns = 0;
    {
        float* q = tp->dskip;
        size_t hw = (size_t)H * W;
        dsp[ns++] = q, q += (size_t)N * C0 * hw;
        for (int i = 0; i < n; i++) {
            for (int j = 0; j < NL; j++) dsp[ns++] = q, q += (size_t)N * c->block_out[i] * hw;
            if (i < n - 1) hw /= 4, dsp[ns++] = q, q += (size_t)N * c->block_out[i] * hw;
        }
    }
    int nskips = ns;
    MLB_TRY(be->zero(tp->demb_s, (size_t)N * TE));

    // out = conv_out(silu(gn(hf)))
    int HW = H * W, ch = C0, hh = H, ww = W;
    float *a = tp->s[0], *da = tp->s[1];
    MLB_TRY(be->groupnorm(a, NULL, NULL, tp->hf, u->norm_out_w, u->norm_out_b, N, C0, HW, G, c->norm_eps, MLB_ACT_IDENTITY));
    MLB_TRY(be->activation(a, a, (size_t)N * C0 * HW, MLB_ACT_SILU));
    MLB_TRY(be->zero(da, (size_t)N * C0 * HW));
    MLB_TRY(conv_bwd(be, da, g->conv_out_w, g->conv_out_b, dout, a, u->conv_out_w, N, C0, H, W, c->out_channels, 3, 1, 1));
    MLB_TRY(be->zero(dcur, (size_t)N * C0 * HW));
    MLB_TRY(be->groupnorm_backward(dcur, g->norm_out_w, g->norm_out_b, da, tp->hf, u->norm_out_w, u->norm_out_b,
                                   tp->out_m, tp->out_r, N, C0, HW, G, MLB_ACT_SILU));

    // up path, last level first: the forward popped the skips from the top, so in reverse they come
    // back from the bottom
    int up = 0;
    for (int i = n - 1; i >= 0; i--) {
        int lvl = n - 1 - i;
        ch = c->block_out[lvl];
        if (i < n - 1) {   // cur = up_conv(upsample(prev)), prev at half the resolution
            float* prev = c->attn[lvl] ? tp->up_attn[i][NL] : tp->up_res[i][NL];
            MLB_TRY(be->upsample_nearest2x(tp->ws.ta, prev, N, ch, hh / 2, ww / 2));
            MLB_TRY(be->zero(a, (size_t)N * ch * hh * ww));
            MLB_TRY(conv_bwd(be, a, g->up_conv[i].w, g->up_conv[i].b, dcur, tp->ws.ta, u->up_conv[i].w, N, ch, hh, ww,
                             ch, 3, 1, 1));
            hh /= 2;
            ww /= 2;
            MLB_TRY(be->zero(dnext, (size_t)N * ch * hh * ww));
            MLB_TRY(be->upsample_nearest2x_backward(dnext, a, N, ch, hh, ww));
            SWAP();
        }
        size_t hw = (size_t)hh * ww;
        for (int j = NL; j >= 0; j--) {
            if (c->attn[lvl]) {
                MLB_TRY(be->zero(dnext, (size_t)N * ch * hw));
                MLB_TRY(attn_bwd(be, u, &u->up_attn[i][j], &g->up_attn[i][j], &tp->up_at[i][j], tp->up_res[i][j], dcur,
                                 dnext, ctx, dctx, N, hh, ww, Tc, tp));
                SWAP();
            }
            const mlb_unet_resnet* r = &u->up_res[i][j];
            int chp = j == 0 && i > 0 ? c->block_out[lvl + 1] : ch, sk = r->cin - chp;   // [h | skip] widths
            MLB_TRY(be->zero(dcat, (size_t)N * r->cin * hw));
            MLB_TRY(resnet_bwd(be, u, r, &g->up_res[i][j], &tp->up_rt[i][j], tp->up_cat[i][j], dcur, dcat, N, hh, ww, tp));
            MLB_TRY(be->copy_rows(dcur, chp * hw, dcat, r->cin * hw, chp * hw, N));
            MLB_TRY(be->copy_rows(dsp[up++], sk * hw, dcat + chp * hw, r->cin * hw, sk * hw, N));
        }
    }
    // mid: resnet, transformer, resnet
    ch = c->block_out[n - 1];
    size_t hw = (size_t)hh * ww, m = (size_t)N * ch * hw;
    const float* down_last = c->attn[n - 1] ? tp->down_attn[n - 1][NL - 1] : tp->down_res[n - 1][NL - 1];
    MLB_TRY(be->zero(dnext, m));
    MLB_TRY(resnet_bwd(be, u, &u->mid_res[1], &g->mid_res[1], &tp->mid_rt[1], tp->mid_attn, dcur, dnext, N, hh, ww, tp));
    SWAP();
    MLB_TRY(be->zero(dnext, m));
    MLB_TRY(attn_bwd(be, u, &u->mid_attn, &g->mid_attn, &tp->mid_at, tp->mid_res[0], dcur, dnext, ctx, dctx, N, hh, ww,
                     Tc, tp));
    SWAP();
    MLB_TRY(be->zero(dnext, m));
    MLB_TRY(resnet_bwd(be, u, &u->mid_res[0], &g->mid_res[0], &tp->mid_rt[0], down_last, dcur, dnext, N, hh, ww, tp));
    SWAP();
    // down path, last level first; each pushed skip adds its gradient where it was pushed
    int k = nskips - 1;
    for (int i = n - 1; i >= 0; i--) {
        ch = c->block_out[i];
        if (i < n - 1) {   // cur = down_conv(last block's output), stride 2
            MLB_TRY(be->add(dcur, dsp[k--], (size_t)N * ch * hh * ww));
            const float* in = c->attn[i] ? tp->down_attn[i][NL - 1] : tp->down_res[i][NL - 1];
            MLB_TRY(be->zero(dnext, (size_t)N * ch * hh * ww * 4));
            MLB_TRY(conv_bwd(be, dnext, g->down_conv[i].w, g->down_conv[i].b, dcur, in, u->down_conv[i].w, N, ch,
                             2 * hh, 2 * ww, ch, 3, 2, 1));
            SWAP();
            hh *= 2;
            ww *= 2;
        }
        hw = (size_t)hh * ww;
        for (int j = NL - 1; j >= 0; j--) {
            MLB_TRY(be->add(dcur, dsp[k--], (size_t)N * ch * hw));
            if (c->attn[i]) {
                MLB_TRY(be->zero(dnext, (size_t)N * ch * hw));
                MLB_TRY(attn_bwd(be, u, &u->down_attn[i][j], &g->down_attn[i][j], &tp->down_at[i][j],
                                 tp->down_res[i][j], dcur, dnext, ctx, dctx, N, hh, ww, Tc, tp));
                SWAP();
            }
            const float* xin = j > 0 ? (c->attn[i] ? tp->down_attn[i][j - 1] : tp->down_res[i][j - 1])
                                     : (i > 0 ? tp->down_conv[i - 1] : tp->conv_in);
            const mlb_unet_resnet* r = &u->down_res[i][j];
            MLB_TRY(be->zero(dnext, (size_t)N * r->cin * hw));
            MLB_TRY(resnet_bwd(be, u, r, &g->down_res[i][j], &tp->down_rt[i][j], xin, dcur, dnext, N, hh, ww, tp));
            SWAP();
        }
    }
    MLB_TRY(be->add(dcur, dsp[k], (size_t)N * C0 * H * W));   // conv_in's output was skip 0
    MLB_TRY(conv_bwd(be, dx, g->conv_in_w, g->conv_in_b, dcur, tp->x, u->conv_in_w, N, c->in_channels, H, W, C0, 3, 1, 1));
    // the time MLP: emb_silu = silu(emb), emb = time2(s1), s1 = silu(e1), e1 = time1(sinusoid)
    size_t ne = (size_t)N * TE;
    MLB_TRY(be->zero(tp->demb, ne));
    MLB_TRY(be->activation_backward(tp->demb, tp->demb_s, tp->emb, ne, MLB_ACT_SILU));
    MLB_TRY(be->zero(tp->ds1, ne));
    MLB_TRY(be->linear_backward(be, tp->ds1, g->time2_w, g->time2_b, tp->demb, tp->s1, u->time2_w, N, TE, TE));
    MLB_TRY(be->zero(tp->demb_s, ne));   // now d e1
    MLB_TRY(be->activation_backward(tp->demb_s, tp->ds1, tp->e1, ne, MLB_ACT_SILU));
    return be->linear_backward(be, NULL, g->time1_w, g->time1_b, tp->demb_s, tp->tproj, u->time1_w, N, C0, TE);
#undef SWAP
}
