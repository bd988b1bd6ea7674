// The SD VAE (vae.h, docs/vae.md): parameter layout, the ResNet and attention blocks (forward and
// backward, shared with the decoder), encoder forward (optionally caching what its backward needs),
// encoder backward to the image and, given a gradient model, to the weights. The decoder is in
// vae_decoder.c, the op wrappers in vae_internal.h. Dual-compiled (float / double _f64) like the
// other MLB_DUAL_SOURCES (core/real.h); loading lives in vae_load.c (float only).
#include "core/real.h"
#include "diffusion/vae_internal.h"

// ---- parameter layout ------------------------------------------------------------------------------
static void FN(carve_resnet)(carver* c, resnet_t* r, int cin, int cout) {
    r->cin = cin;
    r->cout = cout;
    r->norm1_w = vae_take(c, cin); r->norm1_b = vae_take(c, cin);
    r->conv1_w = vae_take(c, (size_t)cout * cin * 9); r->conv1_b = vae_take(c, cout);
    r->norm2_w = vae_take(c, cout); r->norm2_b = vae_take(c, cout);
    r->conv2_w = vae_take(c, (size_t)cout * cout * 9); r->conv2_b = vae_take(c, cout);
    r->short_w = r->short_b = NULL;
    if (cin != cout) { r->short_w = vae_take(c, (size_t)cout * cin); r->short_b = vae_take(c, cout); }
}

static void FN(carve_attn)(carver* c, attn_t* a, int C) {
    a->C = C;
    a->norm_w = vae_take(c, C); a->norm_b = vae_take(c, C);
    a->qkv_w = vae_take(c, (size_t)3 * C * C); a->qkv_b = vae_take(c, (size_t)3 * C);
    a->proj_w = vae_take(c, (size_t)C * C); a->proj_b = vae_take(c, C);
}

static size_t FN(carve_all)(vae_t* v, real* base) {
    const mlb_vae_config* g = &v->cfg;
    const int L = g->n_levels, R = g->layers_per_block, z = g->latent_channels, top = g->block_out[L - 1];
    carver c = {base, 0};
    v->enc_conv_in_w = vae_take(&c, (size_t)g->block_out[0] * g->in_channels * 9);
    v->enc_conv_in_b = vae_take(&c, g->block_out[0]);
    for (int l = 0; l < L; l++) {
        for (int j = 0; j < R; j++) FN(carve_resnet)(&c, &v->enc_res[l][j], enc_cin(g, l, j), g->block_out[l]);
        if (l < L - 1) {
            v->enc_down_w[l] = vae_take(&c, (size_t)g->block_out[l] * g->block_out[l] * 9);
            v->enc_down_b[l] = vae_take(&c, g->block_out[l]);
        }
    }
    FN(carve_resnet)(&c, &v->enc_mid_res[0], top, top);
    if (g->mid_attention) FN(carve_attn)(&c, &v->enc_mid_attn, top);
    FN(carve_resnet)(&c, &v->enc_mid_res[1], top, top);
    v->enc_norm_out_w = vae_take(&c, top); v->enc_norm_out_b = vae_take(&c, top);
    v->enc_conv_out_w = vae_take(&c, (size_t)2 * z * top * 9); v->enc_conv_out_b = vae_take(&c, 2 * z);
    v->quant_w = vae_take(&c, (size_t)4 * z * z); v->quant_b = vae_take(&c, 2 * z);
    v->post_quant_w = vae_take(&c, (size_t)z * z); v->post_quant_b = vae_take(&c, z);
    v->dec_conv_in_w = vae_take(&c, (size_t)top * z * 9); v->dec_conv_in_b = vae_take(&c, top);
    FN(carve_resnet)(&c, &v->dec_mid_res[0], top, top);
    if (g->mid_attention) FN(carve_attn)(&c, &v->dec_mid_attn, top);
    FN(carve_resnet)(&c, &v->dec_mid_res[1], top, top);
    for (int i = 0; i < L; i++) {
        for (int j = 0; j <= R; j++) FN(carve_resnet)(&c, &v->dec_res[i][j], dec_cin(g, i, j), dec_cout(g, i));
        if (i < L - 1) {
            v->dec_up_w[i] = vae_take(&c, (size_t)dec_cout(g, i) * dec_cout(g, i) * 9);
            v->dec_up_b[i] = vae_take(&c, dec_cout(g, i));
        }
    }
    v->dec_norm_out_w = vae_take(&c, g->block_out[0]); v->dec_norm_out_b = vae_take(&c, g->block_out[0]);
    v->dec_conv_out_w = vae_take(&c, (size_t)g->out_channels * g->block_out[0] * 9);
    v->dec_conv_out_b = vae_take(&c, g->out_channels);
    return c.n;
}

mlb_status FN(mlb_vae_create)(vae_ops be, const mlb_vae_config* cfg, vae_t** out) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "VAE: NULL output");
    if (!be) be = CPU_OPS;
    *out = NULL;
    MLB_TRY(mlb_vae_config_check(cfg));
    vae_t* v = calloc(1, sizeof *v);
    if (!v) return mlb_fail(MLB_ERR_NOMEM, "VAE: out of memory");
    v->cfg = *cfg;
    v->device = ops_device(be);
    v->n_params = FN(carve_all)(v, NULL);
    mlb_status s = op_alloc(be, &v->params, v->n_params);
    if (!s) s = op_zero(be, v->params, v->n_params);
    if (s) {
        size_t n = v->n_params;
        FN(mlb_vae_free)(v);
        return mlb_fail_context(s, "VAE: %zu parameters (%.1f MB) on the %s", n,
                                n * (double)sizeof(real) / 1e6, mlb_device_name(ops_device(be)));
    }
    FN(carve_all)(v, v->params);
    *out = v;
    return MLB_OK;
}

void FN(mlb_vae_free)(vae_t* v) {
    if (!v) return;
    FN(mlb_vae_free)(v->mirror);
    op_release(ops_of(v->device), v->params);
    free(v);
}

static vae_plan enc_plan(const mlb_vae_config* g, int N, int H, int W) {
    vae_plan p = {0, 0, 0};
    const int L = g->n_levels;
    plan_conv(&p, conv3_desc(1, g->in_channels, H, W, g->block_out[0]));
    for (int l = 0; l < L; l++) {
        for (int j = 0; j < g->layers_per_block; j++) {
            int cin = enc_cin(g, l, j), c = g->block_out[l];
            plan_act(&p, N, cin > c ? cin : c, H, W);
            plan_conv(&p, conv3_desc(1, cin, H, W, c));
            plan_conv(&p, conv3_desc(1, c, H, W, c));
        }
        if (l < L - 1) { plan_conv(&p, down_desc(1, g->block_out[l], H, W)); H /= 2; W /= 2; }
    }
    plan_conv(&p, conv3_desc(1, g->block_out[L - 1], H, W, 2 * g->latent_channels));
    plan_act(&p, N, 2 * g->latent_channels, H, W);
    p.T = H * W;
    return p;
}

// Scratch values of the encoder's forward (no cache: 4 activations, the attention's 5 token buffers;
// with one: 3 and 1, the rest are in the cache) and of its backward (4 and 5).
enum { ENC_FORWARD, ENC_FORWARD_CACHED, ENC_BACKWARD };
static size_t FN(enc_scratch_of)(const mlb_vae_config* g, int N, int H, int W, int pass) {
    vae_plan p = enc_plan(g, N, H, W);
    const size_t nT = (size_t)N * p.T * g->block_out[g->n_levels - 1], NG = (size_t)N * g->norm_groups;
    if (pass == ENC_BACKWARD) return p.act * 4 + (g->mid_attention ? nT * 5 : 0);
    const int cached = pass == ENC_FORWARD_CACHED;
    return p.act * (cached ? 3 : 4) + (g->mid_attention ? nT * (cached ? 1 : 5) + (size_t)N * p.T : 0) + 4 * NG;
}

// What a cache keeps after the forward's values: the scratch of the forward with it and of its
// backward, the larger of the two (so that an SDS loop's steps do not map and fault in fresh pages).
static size_t FN(enc_scratch)(const mlb_vae_config* g, int N, int H, int W) {
    size_t fwd = FN(enc_scratch_of)(g, N, H, W, ENC_FORWARD_CACHED), bwd = FN(enc_scratch_of)(g, N, H, W, ENC_BACKWARD);
    return fwd > bwd ? fwd : bwd;
}

// ---- ResNet block and attention (vae_internal.h says what each takes) ----------------------------
mlb_status FN(vae_resnet_fwd)(vae_ops be, const resnet_t* r, const mlb_vae_config* g, const real* x, real* out,
                              real* h1, real* t, real* st, int N, int H, int W) {
    const int G = g->norm_groups, HW = H * W;
    const size_t NG = (size_t)N * G;
    const real eps = (real)g->norm_eps;
    MLB_TRY(op_gn(be, t, st, st + NG, x, r->norm1_w, r->norm1_b, N, r->cin, HW, G, eps, MLB_ACT_SILU));
    MLB_TRY(op_conv(be, h1, t, r->conv1_w, r->conv1_b, conv3_desc(N, r->cin, H, W, r->cout)));
    MLB_TRY(op_gn(be, t, st + 2 * NG, st + 3 * NG, h1, r->norm2_w, r->norm2_b, N, r->cout, HW, G, eps, MLB_ACT_SILU));
    MLB_TRY(op_conv(be, out, t, r->conv2_w, r->conv2_b, conv3_desc(N, r->cout, H, W, r->cout)));
    size_t n = (size_t)N * r->cout * HW;
    if (r->short_w) {
        MLB_TRY(op_conv(be, t, x, r->short_w, r->short_b, conv1_desc(N, r->cin, H, W, r->cout)));
        return op_add(be, out, t, n);
    }
    return op_add(be, out, x, n);
}

// The weight gradients need each conv's input: silu(gn(.)) is recomputed from the kept x and h1 with
// the forward's op (the same bits), into scratch (t2 for conv2's, dx for conv1's, before dx is due).
mlb_status FN(vae_resnet_bwd)(vae_ops be, const resnet_t* r, resnet_t* gr, const mlb_vae_config* g, const real* x,
                              const real* h1, const real* st, const real* dout, real* dx, real* t1, real* t2, int N,
                              int H, int W) {
    const int G = g->norm_groups, HW = H * W;
    const size_t NG = (size_t)N * G, nin = (size_t)N * r->cin * HW, nout = (size_t)N * r->cout * HW;
    const real eps = (real)g->norm_eps;
    if (gr) MLB_TRY(op_gn(be, t2, NULL, NULL, h1, r->norm2_w, r->norm2_b, N, r->cout, HW, G, eps, MLB_ACT_SILU));
    MLB_TRY(op_zero(be, t1, nout));
    MLB_TRY(op_conv_bwd(be, t1, GRAD(gr, conv2_w), GRAD(gr, conv2_b), dout, t2, r->conv2_w,
                        conv3_desc(N, r->cout, H, W, r->cout)));
    MLB_TRY(op_zero(be, t2, nout));
    MLB_TRY(op_gn_bwd(be, t2, GRAD(gr, norm2_w), GRAD(gr, norm2_b), t1, h1, r->norm2_w, r->norm2_b, st + 2 * NG,
                      st + 3 * NG, N, r->cout, HW, G, MLB_ACT_SILU));
    if (gr) MLB_TRY(op_gn(be, dx, NULL, NULL, x, r->norm1_w, r->norm1_b, N, r->cin, HW, G, eps, MLB_ACT_SILU));
    MLB_TRY(op_zero(be, t1, nin));
    MLB_TRY(op_conv_bwd(be, t1, GRAD(gr, conv1_w), GRAD(gr, conv1_b), t2, dx, r->conv1_w,
                        conv3_desc(N, r->cin, H, W, r->cout)));
    MLB_TRY(op_zero(be, dx, nin));
    MLB_TRY(op_gn_bwd(be, dx, GRAD(gr, norm1_w), GRAD(gr, norm1_b), t1, x, r->norm1_w, r->norm1_b, st, st + NG, N,
                      r->cin, HW, G, MLB_ACT_SILU));
    if (r->short_w)
        return op_conv_bwd(be, dx, GRAD(gr, short_w), GRAD(gr, short_b), dout, x, r->short_w,
                           conv1_desc(N, r->cin, H, W, r->cout));
    return op_add(be, dx, dout, nout);
}

mlb_status FN(vae_attn_fwd)(vae_ops be, const attn_t* a, const mlb_vae_config* g, const real* x, real* out, real* t,
                            att_bufs b, int N, int T) {
    const int C = a->C, G = g->norm_groups;
    const size_t NG = (size_t)N * G, n = (size_t)N * C * T;
    MLB_TRY(op_gn(be, t, b.st, b.st + NG, x, a->norm_w, a->norm_b, N, C, T, G, (real)g->norm_eps, MLB_ACT_IDENTITY));
    MLB_TRY(op_transpose(be, b.tok, t, N, C, T, 0));
    MLB_TRY(op_linear(be, b.qkv, b.tok, a->qkv_w, a->qkv_b, N * T, C, 3 * C));
    MLB_TRY(op_sdpa(be, b.o, b.lse, b.qkv, N, T, C));
    MLB_TRY(op_linear(be, b.tok, b.o, a->proj_w, a->proj_b, N * T, C, C));
    MLB_TRY(op_copy(be, out, x, n));
    return op_transpose(be, out, b.tok, N, T, C, 1);
}

// proj's input (o) is kept; qkv's (the normalised tokens) is recomputed for its weight gradient.
mlb_status FN(vae_attn_bwd)(vae_ops be, const attn_t* a, attn_t* ga, const mlb_vae_config* g, const real* x,
                            att_bufs b, const real* dout, real* dx, real* t, real* tok2, real* dqkv, int N, int T) {
    const int C = a->C, G = g->norm_groups;
    const size_t NG = (size_t)N * G, n = (size_t)N * C * T;
    MLB_TRY(op_copy(be, dx, dout, n));   // the residual
    MLB_TRY(op_transpose(be, b.tok, dout, N, C, T, 0));
    MLB_TRY(op_zero(be, tok2, n));
    MLB_TRY(op_linear_bwd(be, tok2, GRAD(ga, proj_w), GRAD(ga, proj_b), b.tok, b.o, a->proj_w, N * T, C, C));
    MLB_TRY(op_zero(be, dqkv, 3 * n));
    MLB_TRY(op_sdpa_bwd(be, dqkv, tok2, b.o, b.lse, b.qkv, N, T, C));
    if (ga) {   // tok2 = the tokens qkv saw
        MLB_TRY(op_gn(be, t, NULL, NULL, x, a->norm_w, a->norm_b, N, C, T, G, (real)g->norm_eps, MLB_ACT_IDENTITY));
        MLB_TRY(op_transpose(be, tok2, t, N, C, T, 0));
    }
    MLB_TRY(op_zero(be, b.tok, n));
    MLB_TRY(op_linear_bwd(be, b.tok, GRAD(ga, qkv_w), GRAD(ga, qkv_b), dqkv, tok2, a->qkv_w, N * T, C, 3 * C));
    MLB_TRY(op_transpose(be, t, b.tok, N, T, C, 0));
    return op_gn_bwd(be, dx, GRAD(ga, norm_w), GRAD(ga, norm_b), t, x, a->norm_w, a->norm_b, b.st, b.st + NG, N, C, T,
                     G, MLB_ACT_IDENTITY);
}

// ---- the encoder's cache ---------------------------------------------------------------------------
typedef struct {
    real *res_x[MLB_VAE_MAX_LEVELS][MLB_VAE_MAX_LAYERS], *res_h1[MLB_VAE_MAX_LEVELS][MLB_VAE_MAX_LAYERS];
    real* res_st[MLB_VAE_MAX_LEVELS][MLB_VAE_MAX_LAYERS];
    mid_rec mid;
    real *out_x, *out_st;
    real* moments;
    // a training cache's (cache->train) inputs of the convs the values above do not give: the image
    // (conv_in), each downsampling's and quant_conv's; NULL otherwise
    real *image, *down_in[MLB_VAE_MAX_LEVELS], *quant_in;
} enc_rec;

// The cache's values for a forward of [N, *, H, W] (train: with the weight gradients' inputs), after
// which the scratch follows; buf NULL: count only.
static size_t FN(enc_layout)(const mlb_vae_config* g, int N, int H, int W, int train, real* buf, enc_rec* r) {
    const int H0 = H, W0 = W;
    carver c = {buf, 0};
    const int L = g->n_levels, top = g->block_out[L - 1];
    const size_t NG = (size_t)N * g->norm_groups;
    for (int l = 0; l < L; l++) {
        size_t px = (size_t)N * H * W;
        for (int j = 0; j < g->layers_per_block; j++) {
            r->res_x[l][j] = vae_take(&c, px * enc_cin(g, l, j));
            r->res_h1[l][j] = vae_take(&c, px * g->block_out[l]);
            r->res_st[l][j] = vae_take(&c, 4 * NG);
        }
        if (l < L - 1) { H /= 2; W /= 2; }
    }
    const size_t T = (size_t)H * W, n = (size_t)N * top * T;
    vae_take_mid(&c, g, N, T, &r->mid);
    r->out_x = vae_take(&c, n);
    r->out_st = vae_take(&c, 2 * NG);
    r->moments = vae_take(&c, (size_t)N * 2 * g->latent_channels * T);
    r->image = r->quant_in = NULL;
    memset(r->down_in, 0, sizeof r->down_in);
    if (train) {
        r->image = vae_take(&c, (size_t)N * g->in_channels * H0 * W0);
        for (int l = 0, h = H0, w = W0; l < L - 1; l++, h /= 2, w /= 2)
            r->down_in[l] = vae_take(&c, (size_t)N * g->block_out[l] * h * w);
        r->quant_in = vae_take(&c, (size_t)N * 2 * g->latent_channels * T);
    }
    return c.n;
}

size_t FN(mlb_vae_cache_size)(const mlb_vae_config* cfg, int N, int H, int W) {
    if (!cfg || mlb_vae_config_check(cfg) || N < 1 || mlb_vae_latent_size(cfg, H) < 1 || mlb_vae_latent_size(cfg, W) < 1) {
        mlb_clear_error();
        return 0;
    }
    enc_rec r;
    return FN(enc_layout)(cfg, N, H, W, 0, NULL, &r) + FN(enc_scratch)(cfg, N, H, W);
}

void FN(mlb_vae_cache_free)(FN(mlb_vae_cache)* cache) {
    if (!cache) return;
    op_release(ops_of(cache->device), cache->buf);
    memset(cache, 0, sizeof *cache);
}

mlb_status FN(vae_host_view)(vae_ops be, const real* x, size_t n, real** tmp, const real** view) {
    *tmp = NULL;
    *view = x;
    if (ops_device(be) == MLB_DEVICE_CPU) return MLB_OK;
    if (!(*tmp = malloc(n * sizeof(real)))) return mlb_fail(MLB_ERR_NOMEM, "VAE: out of memory for a host copy");
    *view = *tmp;
    return op_download(be, *tmp, x, n);
}

mlb_status FN(vae_check_size)(const vae_t* v, const char* what, int N, int H, int W) {
    if (!v) return mlb_fail(MLB_ERR_ARG, "VAE %s: NULL model", what);
    int m = 1 << (v->cfg.n_levels - 1);
    if (N < 1 || H < m || W < m)
        return mlb_fail(MLB_ERR_ARG, "VAE %s: image [%d, %d, %d, %d] is too small: height and width must be at least %d",
                        what, N, v->cfg.in_channels, H, W, m);
    int cmax = 0;
    for (int l = 0; l < v->cfg.n_levels; l++) if (v->cfg.block_out[l] > cmax) cmax = v->cfg.block_out[l];
    if ((int64_t)cmax * H * W > INT32_MAX / 2 || (int64_t)N * H * W > INT32_MAX / 2)
        return mlb_fail(MLB_ERR_ARG, "VAE %s: image [%d, %d, %d, %d] is too large", what, N, v->cfg.in_channels, H, W);
    return MLB_OK;
}

// ---- encoder ---------------------------------------------------------------------------------------
// On the ops of be: image and the cache live on be's device; mean and logvar on the host.
static mlb_status FN(encode_core)(vae_ops be, const vae_t* v, const real* image, int N, int H, int W, real* mean,
                                  real* logvar, FN(mlb_vae_cache)* cache) {
    const mlb_vae_config* g = &v->cfg;
    const int L = g->n_levels, R = g->layers_per_block, z = g->latent_channels, top = g->block_out[L - 1];
    const size_t NG = (size_t)N * g->norm_groups;
    enc_rec rec;
    size_t kept = 0;   // with a cache: the values its backward reads; the scratch follows them
    const int train = cache && cache->train;
    if (cache) {
        kept = FN(enc_layout)(g, N, H, W, train, NULL, &rec);
        size_t need = kept + FN(enc_scratch)(g, N, H, W);
        cache->N = 0;   // invalid until this forward completes
        MLB_TRY(vae_cache_reserve(be, &cache->buf, &cache->capacity, &cache->device, need, "encoder"));
        FN(enc_layout)(g, N, H, W, train, cache->buf, &rec);
        if (train) MLB_TRY(op_copy(be, rec.image, image, (size_t)N * g->in_channels * H * W));
    }
    vae_plan p = enc_plan(g, N, H, W);
    const size_t nT = (size_t)N * p.T * top;
    size_t total = FN(enc_scratch_of)(g, N, H, W, cache ? ENC_FORWARD_CACHED : ENC_FORWARD);
    real* scratch;
    MLB_TRY(vae_scratch(be, cache ? cache->buf : NULL, kept, total, &scratch, "encoder"));
    real* P0 = scratch;
    real* P1 = P0 + p.act;
    real* Tb = P1 + p.act;
    real* Hs = cache ? NULL : Tb + p.act;
    real* st = Tb + p.act * (cache ? 1 : 2);
    real* ab = st + 4 * NG;
    att_bufs A = {ab, NULL, NULL, NULL, NULL};
    if (g->mid_attention) {
        A.qkv = cache ? rec.mid.att_qkv : ab + nT;
        A.o = cache ? rec.mid.att_o : ab + 4 * nT;
        A.lse = cache ? rec.mid.att_lse : ab + 5 * nT;
        A.st = cache ? rec.mid.att_st : st;
    }
#define OTHER(x) ((x) == P0 ? P1 : P0)
    mlb_status s = MLB_OK;
    real* cur = cache ? rec.res_x[0][0] : P0;
    int h = H, w = W;
    s = op_conv(be, cur, image, v->enc_conv_in_w, v->enc_conv_in_b, conv3_desc(N, g->in_channels, H, W, g->block_out[0]));
    for (int l = 0; l < L && !s; l++) {
        for (int j = 0; j < R && !s; j++) {
            real* nxt;
            if (j < R - 1) nxt = cache ? rec.res_x[l][j + 1] : OTHER(cur);
            else if (l < L - 1) nxt = train ? rec.down_in[l] : OTHER(cur);
            else nxt = cache ? rec.mid.x[0] : OTHER(cur);
            s = FN(vae_resnet_fwd)(be, &v->enc_res[l][j], g, cur, nxt, cache ? rec.res_h1[l][j] : Hs, Tb,
                               cache ? rec.res_st[l][j] : st, N, h, w);
            cur = nxt;
        }
        if (l < L - 1 && !s) {
            real* nxt = cache ? rec.res_x[l + 1][0] : OTHER(cur);
            s = op_conv(be, nxt, cur, v->enc_down_w[l], v->enc_down_b[l], down_desc(N, g->block_out[l], h, w));
            cur = nxt;
            h /= 2;
            w /= 2;
        }
    }
    const int T = h * w;
    if (!s) {   // mid: ResNet, attention, ResNet
        real* nxt = g->mid_attention ? (cache ? rec.mid.att_x : OTHER(cur)) : (cache ? rec.mid.x[1] : OTHER(cur));
        s = FN(vae_resnet_fwd)(be, &v->enc_mid_res[0], g, cur, nxt, cache ? rec.mid.h1[0] : Hs, Tb,
                           cache ? rec.mid.st[0] : st, N, h, w);
        cur = nxt;
    }
    if (!s && g->mid_attention) {
        real* nxt = cache ? rec.mid.x[1] : OTHER(cur);
        s = FN(vae_attn_fwd)(be, &v->enc_mid_attn, g, cur, nxt, Tb, A, N, T);
        cur = nxt;
    }
    if (!s) {
        real* nxt = cache ? rec.out_x : OTHER(cur);
        s = FN(vae_resnet_fwd)(be, &v->enc_mid_res[1], g, cur, nxt, cache ? rec.mid.h1[1] : Hs, Tb,
                           cache ? rec.mid.st[1] : st, N, h, w);
        cur = nxt;
    }
    if (!s) {
        real* ost = cache ? rec.out_st : st;
        s = op_gn(be, Tb, ost, ost + NG, cur, v->enc_norm_out_w, v->enc_norm_out_b, N, top, T, g->norm_groups,
                  (real)g->norm_eps, MLB_ACT_SILU);
    }
    real* moments = cache ? rec.moments : Tb;
    real* qin = train ? rec.quant_in : OTHER(cur);
    if (!s) s = op_conv(be, qin, Tb, v->enc_conv_out_w, v->enc_conv_out_b, conv3_desc(N, top, h, w, 2 * z));
    if (!s) s = op_conv(be, moments, qin, v->quant_w, v->quant_b, conv1_desc(N, 2 * z, h, w, 2 * z));
#undef OTHER
    const size_t zn = (size_t)z * T;
    real* tmp = NULL;
    const real* mh = NULL;
    if (!s && (mean || logvar)) s = FN(vae_host_view)(be, moments, (size_t)N * 2 * zn, &tmp, &mh);
    if (!s) {
        for (int n = 0; n < N && (mean || logvar); n++) {
            const real* m = mh + (size_t)n * 2 * zn;
            if (mean) memcpy(mean + (size_t)n * zn, m, zn * sizeof(real));
            if (logvar)
                for (size_t i = 0; i < zn; i++) {
                    real lv = m[zn + i];
                    logvar[(size_t)n * zn + i] = lv < (real)LOGVAR_MIN ? (real)LOGVAR_MIN : lv > (real)LOGVAR_MAX ? (real)LOGVAR_MAX : lv;
                }
        }
        if (cache) { cache->N = N; cache->H = H; cache->W = W; cache->train_kept = train; }
    }
    free(tmp);
    if (!cache) op_release(be, scratch);
    return s;
}

mlb_status FN(vae_check_on)(vae_ops be, const vae_t* v, const char* what) {
    if (!v) return mlb_fail(MLB_ERR_ARG, "VAE %s: NULL model", what);
    if (v->device != ops_device(be))
        return mlb_fail(MLB_ERR_ARG, "VAE %s: the model is on the %s, the backend runs on the %s (pass v->mirror "
                        "after mlb_vae_use_device)", what, mlb_device_name(v->device), mlb_device_name(ops_device(be)));
    return MLB_OK;
}

mlb_status FN(mlb_vae_encode)(vae_ops be, const vae_t* v, const real* image, int N, int H, int W, real* mean,
                              real* logvar, FN(mlb_vae_cache)* cache) {
    if (be) MLB_TRY(FN(vae_check_on)(be, v, "encoder"));
    MLB_TRY(FN(vae_check_size)(v, "encoder", N, H, W));
    if (!image) return mlb_fail(MLB_ERR_ARG, "VAE encoder: NULL image");
    if (be) return FN(encode_core)(be, v, image, N, H, W, mean, logvar, cache);
    if (v->mirror) {   // mlb_vae_use_device: the image crosses once, the cache stays on the device
        be = v->mirror_ops;
        size_t n = (size_t)N * v->cfg.in_channels * H * W;
        real* d;
        MLB_TRY(op_alloc(be, &d, n));
        mlb_status s = op_upload(be, d, image, n);
        if (!s) s = FN(encode_core)(be, v->mirror, d, N, H, W, mean, logvar, cache);
        op_release(be, d);
        return s;
    }
    return FN(encode_core)(MODEL_OPS(v), v, image, N, H, W, mean, logvar, cache);
}

mlb_status FN(mlb_vae_encode_mean)(vae_ops be, const vae_t* v, const real* image, int N, int H, int W, real* mean,
                                   FN(mlb_vae_cache)* cache) {
    if (!image || !mean || !cache) return mlb_fail(MLB_ERR_ARG, "VAE encoder: NULL image, mean or cache");
    if (!be) return FN(mlb_vae_encode)(NULL, v, image, N, H, W, mean, NULL, cache);
    MLB_TRY(FN(mlb_vae_encode)(be, v, image, N, H, W, NULL, NULL, cache));
    enc_rec rec;
    FN(enc_layout)(&v->cfg, N, H, W, cache->train_kept, cache->buf, &rec);
    size_t zn = (size_t)v->cfg.latent_channels * mlb_vae_latent_size(&v->cfg, H) * mlb_vae_latent_size(&v->cfg, W);
    return be->copy_rows(mean, zn, rec.moments, 2 * zn, zn, (size_t)N);   // the moments' mean halves
}

// On the ops of be: the cache, dimage (may be NULL) and gr (NULL: no weight gradients) live on be's
// device; dmean and dlogvar on the host. gr's convs need inputs only a training cache keeps.
static mlb_status FN(encode_backward_core)(vae_ops be, const vae_t* v, const FN(mlb_vae_cache)* cache,
                                           const real* dmean, const real* dlogvar, real* dimage, vae_t* gr,
                                           const real* dmean_dev) {
    const mlb_vae_config* g = &v->cfg;
    const int N = cache->N, H = cache->H, W = cache->W;
    const int L = g->n_levels, R = g->layers_per_block, z = g->latent_channels, top = g->block_out[L - 1];
    const size_t NG = (size_t)N * g->norm_groups;
    enc_rec rec;
    if (gr && !cache->train_kept)
        return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: weight gradients need a training cache (set "
                        "cache->train = 1 before mlb_vae_encode)");
    const size_t kept = FN(enc_layout)(g, N, H, W, cache->train_kept, NULL, &rec);
    if (kept + FN(enc_scratch)(g, N, H, W) > cache->capacity)
        return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: the cache is smaller than its forward needed (another "
                        "model's cache?)");
    if (cache->device != ops_device(be))
        return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: the cache is on the %s, the model's ops on the other "
                        "device", mlb_device_name(cache->device));
    FN(enc_layout)(g, N, H, W, cache->train_kept, cache->buf, &rec);
    vae_plan p = enc_plan(g, N, H, W);
    const size_t nT = (size_t)N * p.T * top;
    real* D0 = cache->buf + kept;   // the cache's scratch (FN(enc_scratch))
    real* D1 = D0 + p.act;
    real* T1 = D1 + p.act;
    real* T2 = T1 + p.act;
    real* ab = T2 + p.act;
    att_bufs A = {ab, rec.mid.att_qkv, rec.mid.att_o, rec.mid.att_lse, rec.mid.att_st};
    int hs[MLB_VAE_MAX_LEVELS], wsz[MLB_VAE_MAX_LEVELS];
    hs[0] = H; wsz[0] = W;
    for (int l = 1; l < L; l++) { hs[l] = hs[l - 1] / 2; wsz[l] = wsz[l - 1] / 2; }
    const int h = hs[L - 1], w = wsz[L - 1], T = h * w;
    const size_t zn = (size_t)z * T, nm = (size_t)N * 2 * zn;
    // d(moments), on the host: the mean half, and the logvar half where the clamp passes it; or, with
    // dmean on the device (float), [dmean, 0] made there
    real *mtmp = NULL, *d = NULL;
    const real* mh = NULL;
    mlb_status s = MLB_OK;
    if (dmean_dev) {
        s = op_zero(be, T1, nm);
        if (!s) s = be->copy_rows(T1, 2 * zn, dmean_dev, zn, zn, (size_t)N);
    } else {
        d = ops_device(be) == MLB_DEVICE_CPU ? T1 : malloc(nm * sizeof(real));
        s = d ? FN(vae_host_view)(be, rec.moments, nm, &mtmp, &mh) : mlb_fail(MLB_ERR_NOMEM, "VAE: out of memory");
        if (!s) {
            for (int n = 0; n < N; n++) {
                real* dn = d + (size_t)n * 2 * zn;
                const real* m = mh + (size_t)n * 2 * zn;
                for (size_t i = 0; i < zn; i++) {
                    dn[i] = dmean ? dmean[(size_t)n * zn + i] : 0;
                    real lv = m[zn + i];
                    dn[zn + i] = dlogvar && lv >= (real)LOGVAR_MIN && lv <= (real)LOGVAR_MAX ? dlogvar[(size_t)n * zn + i] : 0;
                }
            }
            if (d != T1) s = op_upload(be, T1, d, nm);
        }
        free(mtmp);
        if (d != T1) free(d);
    }
#define OTHER(x) ((x) == D0 ? D1 : D0)
    if (!s) s = op_zero(be, D0, nm);
    if (!s)
        s = op_conv_bwd(be, D0, GRAD(gr, quant_w), GRAD(gr, quant_b), T1, rec.quant_in, v->quant_w,
                        conv1_desc(N, 2 * z, h, w, 2 * z));
    if (!s && gr)   // conv_out's input, recomputed into D1 (free until its gradient)
        s = op_gn(be, D1, NULL, NULL, rec.out_x, v->enc_norm_out_w, v->enc_norm_out_b, N, top, T, g->norm_groups,
                  (real)g->norm_eps, MLB_ACT_SILU);
    if (!s) s = op_zero(be, T2, nT);
    if (!s)
        s = op_conv_bwd(be, T2, GRAD(gr, enc_conv_out_w), GRAD(gr, enc_conv_out_b), D0, D1, v->enc_conv_out_w,
                        conv3_desc(N, top, h, w, 2 * z));
    real* cur = D1;
    if (!s) s = op_zero(be, D1, nT);
    if (!s)
        s = op_gn_bwd(be, D1, GRAD(gr, enc_norm_out_w), GRAD(gr, enc_norm_out_b), T2, rec.out_x, v->enc_norm_out_w,
                      v->enc_norm_out_b, rec.out_st, rec.out_st + NG, N, top, T, g->norm_groups, MLB_ACT_SILU);
    if (!s) {
        s = FN(vae_resnet_bwd)(be, &v->enc_mid_res[1], GRAD(gr, enc_mid_res + 1), g, rec.mid.x[1], rec.mid.h1[1],
                               rec.mid.st[1], cur, OTHER(cur), T1, T2, N, h, w);
        cur = OTHER(cur);
    }
    if (!s && g->mid_attention) {
        s = FN(vae_attn_bwd)(be, &v->enc_mid_attn, gr ? &gr->enc_mid_attn : NULL, g, rec.mid.att_x, A, cur, OTHER(cur), T1,
                             ab + nT, ab + 2 * nT, N, T);
        cur = OTHER(cur);
    }
    if (!s) {
        s = FN(vae_resnet_bwd)(be, &v->enc_mid_res[0], GRAD(gr, enc_mid_res), g, rec.mid.x[0], rec.mid.h1[0],
                               rec.mid.st[0], cur, OTHER(cur), T1, T2, N, h, w);
        cur = OTHER(cur);
    }
    for (int l = L - 1; l >= 0 && !s; l--) {
        if (l < L - 1) {
            real* nxt = OTHER(cur);
            s = op_zero(be, nxt, (size_t)N * g->block_out[l] * hs[l] * wsz[l]);
            if (!s)
                s = op_conv_bwd(be, nxt, GRAD(gr, enc_down_w[l]), GRAD(gr, enc_down_b[l]), cur, rec.down_in[l],
                                v->enc_down_w[l], down_desc(N, g->block_out[l], hs[l], wsz[l]));
            cur = nxt;
        }
        for (int j = R - 1; j >= 0 && !s; j--) {
            s = FN(vae_resnet_bwd)(be, &v->enc_res[l][j], GRAD(gr, enc_res[l] + j), g, rec.res_x[l][j],
                                   rec.res_h1[l][j], rec.res_st[l][j], cur, OTHER(cur), T1, T2, N, hs[l], wsz[l]);
            cur = OTHER(cur);
        }
    }
#undef OTHER
    if (!s && (dimage || gr))
        s = op_conv_bwd(be, dimage, GRAD(gr, enc_conv_in_w), GRAD(gr, enc_conv_in_b), cur, rec.image,
                        v->enc_conv_in_w, conv3_desc(N, g->in_channels, H, W, g->block_out[0]));
    return s;
}

mlb_status FN(mlb_vae_encode_backward)(vae_ops be, const vae_t* v, const FN(mlb_vae_cache)* cache, const real* dmean,
                                       const real* dlogvar, real* dimage, vae_t* grads) {
    if (!v || !cache) return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: NULL model or cache");
    if (cache->N < 1 || !cache->buf)
        return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: the cache holds no forward (run mlb_vae_encode with this "
                        "cache first)");
    if (!dimage && !grads) return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: NULL image gradient and gradient model");
    if (be) {
        MLB_TRY(FN(vae_check_on)(be, v, "encoder backward"));
        MLB_TRY(FN(vae_check_grads)(be, v, grads, "encoder backward"));
        return FN(encode_backward_core)(be, v, cache, dmean, dlogvar, dimage, grads, NULL);
    }
    if (v->mirror) {   // dimage and host grads cross; the weight gradients are summed on the device, added once
        be = v->mirror_ops;
        size_t n = dimage ? (size_t)cache->N * v->cfg.in_channels * cache->H * cache->W : 0;
        vae_t* gd = NULL;
        real* d = NULL;
        MLB_TRY(FN(vae_check_grads)(CPU_OPS, v, grads, "encoder backward"));
        if (grads) MLB_TRY(FN(mlb_vae_create)(be, &v->cfg, &gd));
        mlb_status s = n ? op_alloc(be, &d, n) : MLB_OK;
        if (!s && n) s = op_upload(be, d, dimage, n);
        if (!s) s = FN(encode_backward_core)(be, v->mirror, cache, dmean, dlogvar, d, gd, NULL);
        if (!s && n) s = op_download(be, dimage, d, n);
        if (!s && gd) s = FN(vae_grads_add_from_device)(be, grads, gd);
        if (d) op_release(be, d);
        FN(mlb_vae_free)(gd);
        return s;
    }
    MLB_TRY(FN(vae_check_grads)(MODEL_OPS(v), v, grads, "encoder backward"));
    return FN(encode_backward_core)(MODEL_OPS(v), v, cache, dmean, dlogvar, dimage, grads, NULL);
}

mlb_status FN(mlb_vae_encode_backward_mean)(vae_ops be, const vae_t* v, const FN(mlb_vae_cache)* cache,
                                            const real* dmean, real* dimage) {
    if (!dmean) return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: NULL dmean");
    if (!be) return FN(mlb_vae_encode_backward)(NULL, v, cache, dmean, NULL, dimage, NULL);
    if (!v || !cache || cache->N < 1 || !cache->buf)
        return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: NULL model, or the cache holds no forward");
    MLB_TRY(FN(vae_check_on)(be, v, "encoder backward"));
    return FN(encode_backward_core)(be, v, cache, NULL, NULL, dimage, NULL, dmean);
}

mlb_status FN(vae_check_grads)(vae_ops be, const vae_t* v, const vae_t* grads, const char* what) {
    if (!grads) return MLB_OK;
    if (grads == v || grads->n_params != v->n_params || memcmp(&grads->cfg, &v->cfg, sizeof v->cfg) != 0)
        return mlb_fail(MLB_ERR_ARG, "VAE %s: the gradient model is not a second model of the same configuration "
                        "(%zu and %zu parameters)", what, grads->n_params, v->n_params);
    if (grads->device != ops_device(be))
        return mlb_fail(MLB_ERR_ARG, "VAE %s: the gradient model is on the %s, the call runs on the %s", what,
                        mlb_device_name(grads->device), mlb_device_name(ops_device(be)));
    return MLB_OK;
}

mlb_status FN(vae_grads_add_from_device)(vae_ops be, vae_t* grads, const vae_t* gd) {
    real* h = malloc(gd->n_params * sizeof(real));
    if (!h) return mlb_fail(MLB_ERR_NOMEM, "VAE: out of memory for the weight gradients' host copy");
    mlb_status s = op_download(be, h, gd->params, gd->n_params);
    if (!s)
        for (size_t i = 0; i < gd->n_params; i++) grads->params[i] += h[i];
    free(h);
    return s;
}
