// UNet forward (see unet.h, docs/unet.md). Activations live in one arena allocated per call:
// two feature maps of the largest size, the skip stack and the transformer scratch.
#include "matlaber/unet.h"
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"

typedef struct {
    float *ta, *tb;                                   // feature-map scratch [N, <= cmax, H, W]
    float *tok, *ln, *q, *k, *v, *att, *tmp, *ff, *gg; // transformer scratch
    float *emb_silu;                                  // [N, TE]
    float *tvec;                                      // [N, cmax]
} unet_ws;

static mlb_status conv(const mlb_backend* be, float* out, const float* in, const float* w, const float* b, int N,
                       int C, int H, int W, int OC, int K, int stride, int pad) {
    mlb_conv2d cv = mlb_conv2d_make(N, C, H, W, OC, K, stride, pad);
    return be->conv2d(be, out, in, w, b, &cv);
}

// out [N, cout, H, W] = resnet(x [N, cin, H, W]); out must not overlap x.
static mlb_status resnet_fwd(const mlb_backend* be, const mlb_unet* u, const mlb_unet_resnet* r, float* out,
                             const float* x, int N, int H, int W, unet_ws* ws) {
    const mlb_unet_config* c = &u->cfg;
    int HW = H * W, G = c->norm_groups;
    MLB_TRY(be->groupnorm(ws->ta, NULL, NULL, x, r->norm1_w, r->norm1_b, N, r->cin, HW, G, c->norm_eps, MLB_ACT_SILU));
    MLB_TRY(conv(be, ws->tb, ws->ta, r->conv1_w, r->conv1_b, N, r->cin, H, W, r->cout, 3, 1, 1));
    MLB_TRY(be->linear(be, ws->tvec, ws->emb_silu, r->temb_w, r->temb_b, N, c->time_embed_dim, r->cout));
    MLB_TRY(be->add_channel(ws->tb, ws->tvec, N, r->cout, HW));
    MLB_TRY(be->groupnorm(ws->tb, NULL, NULL, ws->tb, r->norm2_w, r->norm2_b, N, r->cout, HW, G, c->norm_eps, MLB_ACT_SILU));
    MLB_TRY(conv(be, out, ws->tb, r->conv2_w, r->conv2_b, N, r->cout, H, W, r->cout, 3, 1, 1));
    size_t n = (size_t)N * r->cout * HW;
    if (r->skip_w) {
        MLB_TRY(conv(be, ws->ta, x, r->skip_w, r->skip_b, N, r->cin, H, W, r->cout, 1, 1, 0));
        return be->add(out, ws->ta, n);
    }
    return be->add(out, x, n);
}

// x [N, C, H, W] += transformer(x, context [N, Tc, D]).
static mlb_status attn_fwd(const mlb_backend* be, const mlb_unet* u, const mlb_unet_transformer* a, float* x,
                           const float* ctx, int N, int H, int W, int Tc, unet_ws* ws) {
    const mlb_unet_config* c = &u->cfg;
    int C = a->C, T = H * W, D = c->context_dim, NT = N * T;
    size_t nt = (size_t)NT * C;
    MLB_TRY(be->groupnorm(ws->ta, NULL, NULL, x, a->norm_w, a->norm_b, N, C, T, c->norm_groups, c->transformer_norm_eps,
                          MLB_ACT_IDENTITY));
    MLB_TRY(be->transpose_last2(ws->ln, ws->ta, N, C, T, 0));                        // [N, T, C]
    MLB_TRY(be->linear(be, ws->tok, ws->ln, a->proj_in_w, a->proj_in_b, NT, C, C));
    // self-attention
    MLB_TRY(be->layernorm(ws->ln, ws->tok, a->ln1_w, a->ln1_b, NT, C, c->layer_norm_eps));
    MLB_TRY(be->linear(be, ws->q, ws->ln, a->q1, NULL, NT, C, C));
    MLB_TRY(be->linear(be, ws->k, ws->ln, a->k1, NULL, NT, C, C));
    MLB_TRY(be->linear(be, ws->v, ws->ln, a->v1, NULL, NT, C, C));
    MLB_TRY(be->sdpa(be, ws->att, NULL, ws->q, ws->k, ws->v, N, T, T, C, a->heads, C, C));
    MLB_TRY(be->linear(be, ws->tmp, ws->att, a->o1_w, a->o1_b, NT, C, C));
    MLB_TRY(be->add(ws->tok, ws->tmp, nt));
    // cross-attention
    MLB_TRY(be->layernorm(ws->ln, ws->tok, a->ln2_w, a->ln2_b, NT, C, c->layer_norm_eps));
    MLB_TRY(be->linear(be, ws->q, ws->ln, a->q2, NULL, NT, C, C));
    MLB_TRY(be->linear(be, ws->k, ctx, a->k2, NULL, N * Tc, D, C));
    MLB_TRY(be->linear(be, ws->v, ctx, a->v2, NULL, N * Tc, D, C));
    MLB_TRY(be->sdpa(be, ws->att, NULL, ws->q, ws->k, ws->v, N, T, Tc, C, a->heads, C, C));
    MLB_TRY(be->linear(be, ws->tmp, ws->att, a->o2_w, a->o2_b, NT, C, C));
    MLB_TRY(be->add(ws->tok, ws->tmp, nt));
    // GEGLU feed-forward: [h | gate] = W1 ln3(x); x += W2 (h * gelu(gate))
    MLB_TRY(be->layernorm(ws->ln, ws->tok, a->ln3_w, a->ln3_b, NT, C, c->layer_norm_eps));
    MLB_TRY(be->linear(be, ws->ff, ws->ln, a->ff1_w, a->ff1_b, NT, C, 8 * C));
    MLB_TRY(be->geglu(ws->gg, ws->ff, NT, 4 * C));
    MLB_TRY(be->linear(be, ws->tmp, ws->gg, a->ff2_w, a->ff2_b, NT, 4 * C, C));
    MLB_TRY(be->add(ws->tok, ws->tmp, nt));
    // proj_out, back to NCHW, plus the residual
    MLB_TRY(be->linear(be, ws->ln, ws->tok, a->proj_out_w, a->proj_out_b, NT, C, C));
    return be->transpose_last2(x, ws->ln, N, T, C, 1);
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

mlb_status mlb_unet_forward(const mlb_unet* u, float* out, const float* x, const float* t, const float* context,
                            int N, int H, int W, int Tc, mlb_unet_debug_fn debug, void* debug_user) {
    if (!u || !u->mirror)   // on the CPU: its fp32 ops, or the bf16 ones (mlb_unet_use_device)
        return mlb_unet_forward_on(u && u->mirror_ops ? u->mirror_ops : mlb_backend_cpu(), u, out, x, t, context, N,
                                   H, W, Tc, debug, debug_user);
    // on the mirror's device: x, context and out staged in one device buffer (allocated per call,
    // as the activations are: small beside them)
    if (!out || !x || !t || !context || N < 1 || H < 1 || W < 1 || Tc < 1)
        return mlb_fail(MLB_ERR_ARG, "UNet forward: NULL argument or empty shape");
    const mlb_unet* du = u->mirror;
    const mlb_backend* be = u->mirror_ops;
    size_t nx = (size_t)N * du->cfg.in_channels * H * W, nc = (size_t)N * Tc * du->cfg.context_dim;
    size_t no = (size_t)N * du->cfg.out_channels * H * W;
    float* stage;
    MLB_TRY(be->alloc(&stage, nx + nc + no));
    float *dx = stage, *dc = dx + nx, *dout = dc + nc;
    mlb_status s = be->upload(dx, x, nx);
    if (s == MLB_OK) s = be->upload(dc, context, nc);
    if (s == MLB_OK) s = mlb_unet_forward_on(be, du, dout, dx, t, dc, N, H, W, Tc, debug, debug_user);
    if (s == MLB_OK) s = be->download(out, dout, no);
    be->release(stage);
    return s;
}

mlb_status mlb_unet_forward_on(const mlb_backend* be, const mlb_unet* u, float* out, const float* x, const float* t,
                               const float* context, int N, int H, int W, int Tc, mlb_unet_debug_fn debug,
                               void* debug_user) {
    if (!be || !u || !out || !x || !t || !context) return mlb_fail(MLB_ERR_ARG, "UNet forward: NULL argument");
    if (u->device != be->device)
        return mlb_fail(MLB_ERR_ARG, "UNet forward: the weights are on the %s, the ops on the %s (mlb_unet_to_device)",
                        mlb_device_name(u->device), mlb_device_name(be->device));
    if (u->bf16_weights != (be == mlb_backend_cpu_bf16_stored()))
        return mlb_fail(MLB_ERR_ARG, "UNet forward: weights stored in %s, ops for weights in %s",
                        u->bf16_weights ? "bf16" : "fp32", u->bf16_weights ? "fp32" : "bf16");
    const mlb_unet_config* c = &u->cfg;
    int n = c->n_levels, NL = c->layers_per_block, f = 1 << (n - 1);
    if (N < 1 || H < 1 || W < 1 || Tc < 1)
        return mlb_fail(MLB_ERR_ARG, "UNet forward: batch %d, latent %dx%d, context length %d must be positive", N, H, W, Tc);
    if (H % f || W % f)
        return mlb_fail(MLB_ERR_ARG, "UNet forward: latent %dx%d is not a multiple of %d (%d downsamplings)", H, W, f, n - 1);
    // sizes
    int cmax = c->block_out[0], TE = c->time_embed_dim, C0 = c->block_out[0];
    size_t fmax = 0, amax = 0, skip_total = (size_t)N * C0 * H * W;
    for (int l = 0; l < n; l++) {
        size_t hw = (size_t)(H >> l) * (W >> l);
        int cl = c->block_out[l], cn = c->block_out[l < n - 1 ? l + 1 : l], cp = c->block_out[l > 0 ? l - 1 : 0];
        if (cl > cmax) cmax = cl;
        int cat = (cl > cn ? cl : cn) + (cl > cp ? cl : cp);   // widest concat at this resolution
        size_t fl = (size_t)N * hw * (size_t)(cat > cl ? cat : cl);
        if (fl > fmax) fmax = fl;
        if (c->attn[l] || l == n - 1) {
            size_t al = (size_t)N * hw * cl;
            if (al > amax) amax = al;
        }
        skip_total += (size_t)N * hw * cl * (size_t)(NL + (l < n - 1));
    }
    size_t kv = (size_t)N * Tc * cmax;
    size_t total = 4 * fmax + skip_total + 5 * amax + 2 * (amax > kv ? amax : kv) + 8 * amax + 4 * amax + (size_t)N * TE * 2 +
                   (size_t)N * cmax + (size_t)N * C0;
    float* arena;
    if (be->alloc(&arena, total) != MLB_OK)
        return mlb_fail_context(MLB_ERR_NOMEM, "UNet forward: %.1f MB of activations on the %s", total * 4.0 / 1e6,
                                mlb_device_name(be->device));
    float* tproj_host = malloc((size_t)N * C0 * sizeof(float));
    if (!tproj_host) {
        be->release(arena);
        return mlb_fail(MLB_ERR_NOMEM, "UNet forward: out of memory");
    }
    float* p = arena;
#define TAKE(n_) (p += (n_), p - (n_))
    unet_ws ws;
    float* h = TAKE(fmax);
    float* h2 = TAKE(fmax);
    ws.ta = TAKE(fmax);
    ws.tb = TAKE(fmax);
    float* skips = TAKE(skip_total);
    ws.tok = TAKE(amax); ws.ln = TAKE(amax); ws.q = TAKE(amax); ws.att = TAKE(amax); ws.tmp = TAKE(amax);
    ws.k = TAKE(amax > kv ? amax : kv); ws.v = TAKE(amax > kv ? amax : kv);
    ws.ff = TAKE(8 * amax); ws.gg = TAKE(4 * amax);
    ws.emb_silu = TAKE((size_t)N * TE);
    float* emb = TAKE((size_t)N * TE);
    ws.tvec = TAKE((size_t)N * cmax);
    float* tproj = TAKE((size_t)N * C0);
#undef TAKE
    mlb_status s = MLB_OK;
#define CK(e) do { if ((s = (e)) != MLB_OK) goto done; } while (0)
    // time embedding (float32, as diffusers): f_i = exp(-ln(10000) * i / (half - shift))
    int half = C0 / 2;
    for (int b = 0; b < N; b++)
        for (int i = 0; i < half; i++) {
            float e = (float)(-log(10000.0)) * (float)i;
            e = e / ((float)half - c->freq_shift);
            float a = t[b] * expf(e);
            float cs = (float)cos((double)a), sn = (float)sin((double)a);
            tproj_host[(size_t)b * C0 + i] = c->flip_sin_to_cos ? cs : sn;
            tproj_host[(size_t)b * C0 + half + i] = c->flip_sin_to_cos ? sn : cs;
        }
    CK(be->upload(tproj, tproj_host, (size_t)N * C0));
    CK(report(be, debug, debug_user, "time_proj", tproj, (size_t)N * C0));
    CK(be->linear(be, ws.emb_silu, tproj, u->time1_w, u->time1_b, N, C0, TE));
    CK(be->activation(ws.emb_silu, ws.emb_silu, (size_t)N * TE, MLB_ACT_SILU));
    CK(be->linear(be, emb, ws.emb_silu, u->time2_w, u->time2_b, N, TE, TE));
    CK(report(be, debug, debug_user, "time_embedding", emb, (size_t)N * TE));
    CK(be->activation(ws.emb_silu, emb, (size_t)N * TE, MLB_ACT_SILU));

    // skip stack
    float* sp[1 + MLB_UNET_MAX_LEVELS * (MLB_UNET_MAX_LAYERS + 1)];
    int sc[1 + MLB_UNET_MAX_LEVELS * (MLB_UNET_MAX_LAYERS + 1)], ns = 0;
    float* stop = skips;
    int ch = C0, hh = H, ww = W;
#define PUSH() do { size_t m_ = (size_t)N * ch * hh * ww; CK(be->copy_rows(stop, m_, h, m_, m_, 1)); sp[ns] = stop; \
                    sc[ns++] = ch; stop += m_; } while (0)
#define SWAP() do { float* t_ = h; h = h2; h2 = t_; } while (0)
    char name[64];
    CK(conv(be, h, x, u->conv_in_w, u->conv_in_b, N, c->in_channels, H, W, C0, 3, 1, 1));
    CK(report(be, debug, debug_user, "conv_in", h, (size_t)N * C0 * H * W));
    PUSH();
    for (int i = 0; i < n; i++) {
        for (int j = 0; j < NL; j++) {
            CK(resnet_fwd(be, u, &u->down_res[i][j], h2, h, N, hh, ww, &ws));
            SWAP();
            ch = u->down_res[i][j].cout;
            if (c->attn[i]) CK(attn_fwd(be, u, &u->down_attn[i][j], h, context, N, hh, ww, Tc, &ws));
            PUSH();
        }
        if (i < n - 1) {
            CK(conv(be, h2, h, u->down_conv[i].w, u->down_conv[i].b, N, ch, hh, ww, ch, 3, 2, 1));
            SWAP();
            hh /= 2;
            ww /= 2;
            PUSH();
        }
        snprintf(name, sizeof name, "down_blocks.%d", i);
        CK(report(be, debug, debug_user, name, h, (size_t)N * ch * hh * ww));
    }
    CK(resnet_fwd(be, u, &u->mid_res[0], h2, h, N, hh, ww, &ws));
    SWAP();
    CK(attn_fwd(be, u, &u->mid_attn, h, context, N, hh, ww, Tc, &ws));
    CK(resnet_fwd(be, u, &u->mid_res[1], h2, h, N, hh, ww, &ws));
    SWAP();
    CK(report(be, debug, debug_user, "mid_block", h, (size_t)N * ch * hh * ww));
    for (int i = 0; i < n; i++) {
        int lvl = n - 1 - i;
        for (int j = 0; j <= NL; j++) {
            // concat [h | skip] along channels into h2
            int sk = sc[--ns];
            size_t hw = (size_t)hh * ww;
            CK(be->copy_rows(h2, (ch + sk) * hw, h, ch * hw, ch * hw, N));
            CK(be->copy_rows(h2 + ch * hw, (ch + sk) * hw, sp[ns], sk * hw, sk * hw, N));
            CK(resnet_fwd(be, u, &u->up_res[i][j], h, h2, N, hh, ww, &ws));
            ch = u->up_res[i][j].cout;
            if (c->attn[lvl]) CK(attn_fwd(be, u, &u->up_attn[i][j], h, context, N, hh, ww, Tc, &ws));
        }
        if (i < n - 1) {
            CK(be->upsample_nearest2x(h2, h, N, ch, hh, ww));
            hh *= 2;
            ww *= 2;
            CK(conv(be, h, h2, u->up_conv[i].w, u->up_conv[i].b, N, ch, hh, ww, ch, 3, 1, 1));
        }
        snprintf(name, sizeof name, "up_blocks.%d", i);
        CK(report(be, debug, debug_user, name, h, (size_t)N * ch * hh * ww));
    }
    CK(be->groupnorm(h2, NULL, NULL, h, u->norm_out_w, u->norm_out_b, N, ch, H * W, c->norm_groups, c->norm_eps,
                     MLB_ACT_IDENTITY));
    CK(report(be, debug, debug_user, "conv_norm_out", h2, (size_t)N * ch * H * W));
    CK(be->activation(h2, h2, (size_t)N * ch * H * W, MLB_ACT_SILU));
    CK(conv(be, out, h2, u->conv_out_w, u->conv_out_b, N, ch, H, W, c->out_channels, 3, 1, 1));
#undef PUSH
#undef SWAP
#undef CK
done:
    be->release(arena);
    free(tproj_host);
    return s;
}
