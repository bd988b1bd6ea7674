// The SD VAE's decoder (vae.h, docs/vae.md): the forward, optionally keeping what its backward needs
// (mlb_vae_decode with a cache), and the backward to the latent and the weights. Dual-compiled (float /
// double _f64) like vae.c, whose blocks (vae_internal.h) it shares.
#include "core/real.h"
#include "diffusion/vae_internal.h"

typedef FN(mlb_vae_dec_cache) dec_cache_t;

static vae_plan dec_plan(const mlb_vae_config* g, int N, int h, int w) {
    vae_plan p = {0, 0, h * w};
    const int L = g->n_levels, top = g->block_out[L - 1];
    plan_act(&p, N, top > g->latent_channels ? top : g->latent_channels, h, w);
    plan_conv(&p, conv3_desc(1, g->latent_channels, h, w, top));
    plan_conv(&p, conv3_desc(1, top, h, w, top));
    for (int i = 0; i < L; i++) {
        for (int j = 0; j <= g->layers_per_block; j++) {
            int cin = dec_cin(g, i, j), c = dec_cout(g, i);
            plan_act(&p, N, cin > c ? cin : c, h, w);
            plan_conv(&p, conv3_desc(1, cin, h, w, c));
            plan_conv(&p, conv3_desc(1, c, h, w, c));
        }
        if (i < L - 1) {
            h *= 2; w *= 2;
            plan_act(&p, N, dec_cout(g, i), h, w);
            plan_conv(&p, conv3_desc(1, dec_cout(g, i), h, w, dec_cout(g, i)));
        }
    }
    plan_conv(&p, conv3_desc(1, g->block_out[0], h, w, g->out_channels));
    return p;
}

// ---- the decoder's cache ---------------------------------------------------------------------------
// Every conv's input is kept or recomputable from a kept tensor: the ResNet blocks' inputs, conv1
// outputs and norm statistics (as the encoder's), the latent, post_quant's output, each upsampling's
// low-resolution input (the upsampled map is recomputed) and norm_out's input.
typedef struct {
    real *z, *pq;
    mid_rec mid;
    real *res_x[MLB_VAE_MAX_LEVELS][MLB_VAE_MAX_LAYERS + 1], *res_h1[MLB_VAE_MAX_LEVELS][MLB_VAE_MAX_LAYERS + 1];
    real* res_st[MLB_VAE_MAX_LEVELS][MLB_VAE_MAX_LAYERS + 1];
    real* up_x[MLB_VAE_MAX_LEVELS];
    real *out_x, *out_st;
} dec_rec;

static size_t FN(dec_layout)(const mlb_vae_config* g, int N, int h, int w, real* buf, dec_rec* r) {
    carver c = {buf, 0};
    const int L = g->n_levels, z = g->latent_channels;
    const size_t NG = (size_t)N * g->norm_groups, T = (size_t)h * w;
    r->z = vae_take(&c, (size_t)N * z * T);
    r->pq = vae_take(&c, (size_t)N * z * T);
    vae_take_mid(&c, g, N, T, &r->mid);
    memset(r->up_x, 0, sizeof r->up_x);
    for (int i = 0; i < L; i++) {
        size_t px = (size_t)N * h * w;
        for (int j = 0; j <= g->layers_per_block; j++) {
            r->res_x[i][j] = vae_take(&c, px * dec_cin(g, i, j));
            r->res_h1[i][j] = vae_take(&c, px * dec_cout(g, i));
            r->res_st[i][j] = vae_take(&c, 4 * NG);
        }
        if (i < L - 1) { r->up_x[i] = vae_take(&c, px * dec_cout(g, i)); h *= 2; w *= 2; }
    }
    r->out_x = vae_take(&c, (size_t)N * g->block_out[0] * h * w);
    r->out_st = vae_take(&c, 2 * NG);
    return c.n;
}

// Scratch: the forward without a cache 4 activations and the attention's 5 token buffers (+ lse and
// statistics); the backward 4 activations (two gradients, two temporaries) and 5 token buffers,
// which also serve the cached forward (1 activation, 1 token buffer).
static size_t FN(dec_scratch)(const mlb_vae_config* g, int N, int h, int w, int cached) {
    vae_plan p = dec_plan(g, N, h, w);
    const size_t nT = (size_t)N * p.T * g->block_out[g->n_levels - 1];
    if (cached) return p.act * 4 + (g->mid_attention ? nT * 5 : 0);
    return p.act * 4 + (g->mid_attention ? nT * 5 + (size_t)N * p.T : 0) + 4 * (size_t)N * g->norm_groups;
}

size_t FN(mlb_vae_dec_cache_size)(const mlb_vae_config* cfg, int N, int h, int w) {
    if (!cfg || mlb_vae_config_check(cfg) || N < 1 || h < 1 || w < 1) {
        mlb_clear_error();
        return 0;
    }
    dec_rec r;
    return FN(dec_layout)(cfg, N, h, w, NULL, &r) + FN(dec_scratch)(cfg, N, h, w, 1);
}

void FN(mlb_vae_dec_cache_free)(dec_cache_t* cache) {
    if (!cache) return;
    op_release(ops_of(cache->device), cache->buf);
    memset(cache, 0, sizeof *cache);
}

// ---- forward ---------------------------------------------------------------------------------------
// On the ops of be: zin, image and the cache live on be's device. cache NULL: a forward only. The
// same ops in the same order either way (only where results are written differs), so the image is
// bitwise the same with and without a cache.
static mlb_status FN(decode_core)(vae_ops be, const vae_t* v, const real* zin, int N, int h, int w, real* image,
                                  dec_cache_t* cache) {
    const mlb_vae_config* g = &v->cfg;
    const int L = g->n_levels, R = g->layers_per_block, z = g->latent_channels, top = g->block_out[L - 1];
    const size_t NG = (size_t)N * g->norm_groups;
    const int h0 = h, w0 = w;
    vae_plan p = dec_plan(g, N, h, w);
    const size_t nT = (size_t)N * p.T * top;
    dec_rec rec;
    size_t kept = 0;
    if (cache) {
        kept = FN(dec_layout)(g, N, h, w, NULL, &rec);
        size_t need = kept + FN(dec_scratch)(g, N, h, w, 1);
        cache->N = 0;   // invalid until this forward completes
        MLB_TRY(vae_cache_reserve(be, &cache->buf, &cache->capacity, &cache->device, need, "decoder"));
        FN(dec_layout)(g, N, h, w, cache->buf, &rec);
        MLB_TRY(op_copy(be, rec.z, zin, (size_t)N * z * h * w));
    }
    size_t total = FN(dec_scratch)(g, N, h, w, cache != NULL);
    real* scratch;
    MLB_TRY(vae_scratch(be, cache ? cache->buf : NULL, kept, total, &scratch, "decoder"));
    real* P0 = scratch;
    real* P1 = P0 + p.act;
    real* Tb = P1 + p.act;
    real* Hs = Tb + p.act;
    real* st = Hs + p.act;
    real* ab = st + 4 * NG;   // without a cache; with one the token scratch is the backward's (below)
    att_bufs A = {ab, ab + nT, ab + 4 * nT, ab + 5 * nT, st};
    if (cache) A = (att_bufs){P0 + 4 * p.act, rec.mid.att_qkv, rec.mid.att_o, rec.mid.att_lse, rec.mid.att_st};
#define OTHER(x) ((x) == P0 ? P1 : P0)
#define KEEP(field, fallback) (cache ? rec.field : (fallback))
    real* cur = KEEP(pq, P0);
    mlb_status s = op_conv(be, cur, zin, v->post_quant_w, v->post_quant_b, conv1_desc(N, z, h, w, z));
    real* nxt = KEEP(mid.x[0], P1);
    if (!s) s = op_conv(be, nxt, cur, v->dec_conv_in_w, v->dec_conv_in_b, conv3_desc(N, z, h, w, top));
    cur = nxt;
    if (!s) {
        nxt = g->mid_attention ? KEEP(mid.att_x, OTHER(cur)) : KEEP(mid.x[1], OTHER(cur));
        s = FN(vae_resnet_fwd)(be, &v->dec_mid_res[0], g, cur, nxt, KEEP(mid.h1[0], Hs), Tb, KEEP(mid.st[0], st), N,
                               h, w);
        cur = nxt;
    }
    if (!s && g->mid_attention) {
        nxt = KEEP(mid.x[1], OTHER(cur));
        s = FN(vae_attn_fwd)(be, &v->dec_mid_attn, g, cur, nxt, Tb, A, N, h * w);
        cur = nxt;
    }
    if (!s) {
        nxt = KEEP(res_x[0][0], OTHER(cur));
        s = FN(vae_resnet_fwd)(be, &v->dec_mid_res[1], g, cur, nxt, KEEP(mid.h1[1], Hs), Tb, KEEP(mid.st[1], st), N,
                               h, w);
        cur = nxt;
    }
    for (int i = 0; i < L && !s; i++) {
        for (int j = 0; j <= R && !s; j++) {
            if (j < R) nxt = KEEP(res_x[i][j + 1], OTHER(cur));
            else nxt = i < L - 1 ? KEEP(up_x[i], OTHER(cur)) : KEEP(out_x, OTHER(cur));
            s = FN(vae_resnet_fwd)(be, &v->dec_res[i][j], g, cur, nxt, KEEP(res_h1[i][j], Hs), Tb,
                                   KEEP(res_st[i][j], st), N, h, w);
            cur = nxt;
        }
        if (i < L - 1 && !s) {
            int c = dec_cout(g, i);
            s = op_upsample(be, Tb, cur, N, c, h, w);
            h *= 2;
            w *= 2;
            nxt = KEEP(res_x[i + 1][0], OTHER(cur));
            if (!s) s = op_conv(be, nxt, Tb, v->dec_up_w[i], v->dec_up_b[i], conv3_desc(N, c, h, w, c));
            cur = nxt;
        }
    }
#undef KEEP
#undef OTHER
    if (!s)
        s = op_gn(be, Tb, cache ? rec.out_st : NULL, cache ? rec.out_st + NG : NULL, cur, v->dec_norm_out_w,
                  v->dec_norm_out_b, N, g->block_out[0], h * w, g->norm_groups, (real)g->norm_eps, MLB_ACT_SILU);
    if (!s)
        s = op_conv(be, image, Tb, v->dec_conv_out_w, v->dec_conv_out_b, conv3_desc(N, g->block_out[0], h, w, g->out_channels));
    if (!s && cache) { cache->N = N; cache->h = h0; cache->w = w0; }
    if (!cache) op_release(be, scratch);
    return s;
}

static mlb_status FN(check_latent)(const vae_t* v, int N, int h, int w) {
    if (!v) return mlb_fail(MLB_ERR_ARG, "VAE decoder: NULL model");
    const int L = v->cfg.n_levels;
    if (N < 1 || h < 1 || w < 1 || (int64_t)h << (L - 1) > 65536 || (int64_t)w << (L - 1) > 65536)
        return mlb_fail(MLB_ERR_ARG, "VAE decoder: bad latent shape [%d, %d, %d, %d]", N, v->cfg.latent_channels, h, w);
    return FN(vae_check_size)(v, "decoder", N, h << (L - 1), w << (L - 1));
}

mlb_status FN(mlb_vae_decode)(vae_ops be, const vae_t* v, const real* zin, int N, int h, int w, real* image,
                              dec_cache_t* cache) {
    MLB_TRY(FN(check_latent)(v, N, h, w));
    if (!zin || !image) return mlb_fail(MLB_ERR_ARG, "VAE decoder: NULL latent or image");
    if (be) {
        MLB_TRY(FN(vae_check_on)(be, v, "decoder"));
        return FN(decode_core)(be, v, zin, N, h, w, image, cache);
    }
    if (v->mirror) {   // the latent and the image cross; a cache stays on the device
        const mlb_vae_config* g = &v->cfg;
        const int L = g->n_levels;
        be = v->mirror_ops;
        size_t nz = (size_t)N * g->latent_channels * h * w, ni = (size_t)N * g->out_channels * (h << (L - 1)) * (w << (L - 1));
        real* d;
        MLB_TRY(op_alloc(be, &d, nz + ni));
        mlb_status s = op_upload(be, d, zin, nz);
        if (!s) s = FN(decode_core)(be, v->mirror, d, N, h, w, d + nz, cache);
        if (!s) s = op_download(be, image, d + nz, ni);
        op_release(be, d);
        return s;
    }
    return FN(decode_core)(MODEL_OPS(v), v, zin, N, h, w, image, cache);
}

// ---- backward --------------------------------------------------------------------------------------
// On the ops of be: the cache, dimage, dz (may be NULL, +=) and gr (may be NULL, +=) live on be's
// device. Each conv's input is read from the cache or recomputed with the forward's op (the same
// bits): silu(norm_out(.)) and the upsampled maps.
static mlb_status FN(decode_backward_core)(vae_ops be, const vae_t* v, const dec_cache_t* cache, const real* dimage,
                                           real* dz, vae_t* gr) {
    const mlb_vae_config* g = &v->cfg;
    const int N = cache->N, h0 = cache->h, w0 = cache->w;
    const int L = g->n_levels, R = g->layers_per_block, z = g->latent_channels, top = g->block_out[L - 1];
    const int G = g->norm_groups, b0 = g->block_out[0];
    const size_t NG = (size_t)N * G;
    dec_rec rec;
    const size_t kept = FN(dec_layout)(g, N, h0, w0, NULL, &rec);
    if (kept + FN(dec_scratch)(g, N, h0, w0, 1) > cache->capacity)
        return mlb_fail(MLB_ERR_ARG, "VAE decoder backward: the cache is smaller than its forward needed (another "
                        "model's cache?)");
    if (cache->device != ops_device(be))
        return mlb_fail(MLB_ERR_ARG, "VAE decoder backward: the cache is on the %s, the model's ops on the other "
                        "device", mlb_device_name(cache->device));
    FN(dec_layout)(g, N, h0, w0, cache->buf, &rec);
    vae_plan p = dec_plan(g, N, h0, w0);
    const size_t nT = (size_t)N * p.T * top;
    real* D0 = cache->buf + kept;   // two gradients in turn, two temporaries, the attention's tokens
    real* D1 = D0 + p.act;
    real* T1 = D1 + p.act;
    real* T2 = T1 + p.act;
    real* ab = T2 + p.act;
    att_bufs A = {ab, rec.mid.att_qkv, rec.mid.att_o, rec.mid.att_lse, rec.mid.att_st};
    const int H = h0 << (L - 1), W = w0 << (L - 1);
#define OTHER(x) ((x) == D0 ? D1 : D0)
    mlb_status s = MLB_OK;
    if (gr)   // conv_out's input
        s = op_gn(be, T2, NULL, NULL, rec.out_x, v->dec_norm_out_w, v->dec_norm_out_b, N, b0, H * W, G,
                  (real)g->norm_eps, MLB_ACT_SILU);
    if (!s) s = op_zero(be, T1, (size_t)N * b0 * H * W);
    if (!s)
        s = op_conv_bwd(be, T1, GRAD(gr, dec_conv_out_w), GRAD(gr, dec_conv_out_b), dimage, T2, v->dec_conv_out_w,
                        conv3_desc(N, b0, H, W, g->out_channels));
    real* cur = D0;
    if (!s) s = op_zero(be, cur, (size_t)N * b0 * H * W);
    if (!s)
        s = op_gn_bwd(be, cur, GRAD(gr, dec_norm_out_w), GRAD(gr, dec_norm_out_b), T1, rec.out_x, v->dec_norm_out_w,
                      v->dec_norm_out_b, rec.out_st, rec.out_st + NG, N, b0, H * W, G, MLB_ACT_SILU);
    for (int i = L - 1; i >= 0 && !s; i--) {
        const int hi = h0 << i, wi = w0 << i, c = dec_cout(g, i);
        if (i < L - 1) {   // the upsampling conv at 2x the block's resolution, then the 2x2 sums
            if (gr) s = op_upsample(be, T2, rec.up_x[i], N, c, hi, wi);
            if (!s) s = op_zero(be, T1, (size_t)N * c * 4 * hi * wi);
            if (!s)
                s = op_conv_bwd(be, T1, GRAD(gr, dec_up_w[i]), GRAD(gr, dec_up_b[i]), cur, T2, v->dec_up_w[i],
                                conv3_desc(N, c, 2 * hi, 2 * wi, c));
            if (!s) s = op_upsample_bwd(be, OTHER(cur), T1, T2, N, c, hi, wi);
            cur = OTHER(cur);
        }
        for (int j = R; j >= 0 && !s; j--) {
            s = FN(vae_resnet_bwd)(be, &v->dec_res[i][j], GRAD(gr, dec_res[i] + j), g, rec.res_x[i][j],
                                   rec.res_h1[i][j], rec.res_st[i][j], cur, OTHER(cur), T1, T2, N, hi, wi);
            cur = OTHER(cur);
        }
    }
    if (!s) {
        s = FN(vae_resnet_bwd)(be, &v->dec_mid_res[1], GRAD(gr, dec_mid_res + 1), g, rec.mid.x[1], rec.mid.h1[1],
                               rec.mid.st[1], cur, OTHER(cur), T1, T2, N, h0, w0);
        cur = OTHER(cur);
    }
    if (!s && g->mid_attention) {
        s = FN(vae_attn_bwd)(be, &v->dec_mid_attn, gr ? &gr->dec_mid_attn : NULL, g, rec.mid.att_x, A, cur, OTHER(cur),
                             T1, ab + nT, ab + 2 * nT, N, h0 * w0);
        cur = OTHER(cur);
    }
    if (!s) {
        s = FN(vae_resnet_bwd)(be, &v->dec_mid_res[0], GRAD(gr, dec_mid_res), g, rec.mid.x[0], rec.mid.h1[0],
                               rec.mid.st[0], cur, OTHER(cur), T1, T2, N, h0, w0);
        cur = OTHER(cur);
    }
    real* dpq = OTHER(cur);
    if (!s) s = op_zero(be, dpq, (size_t)N * z * h0 * w0);
    if (!s)
        s = op_conv_bwd(be, dpq, GRAD(gr, dec_conv_in_w), GRAD(gr, dec_conv_in_b), cur, rec.pq, v->dec_conv_in_w,
                        conv3_desc(N, z, h0, w0, top));
    if (!s && (dz || gr))
        s = op_conv_bwd(be, dz, GRAD(gr, post_quant_w), GRAD(gr, post_quant_b), dpq, rec.z, v->post_quant_w,
                        conv1_desc(N, z, h0, w0, z));
#undef OTHER
    return s;
}

mlb_status FN(mlb_vae_decode_backward)(vae_ops be, const vae_t* v, const dec_cache_t* cache, const real* dimage,
                                       real* dz, vae_t* grads) {
    if (!v || !cache || !dimage) return mlb_fail(MLB_ERR_ARG, "VAE decoder backward: NULL model, cache or dimage");
    if (cache->N < 1 || !cache->buf)
        return mlb_fail(MLB_ERR_ARG, "VAE decoder backward: the cache holds no forward (run mlb_vae_decode with "
                        "this cache first)");
    if (be) {
        MLB_TRY(FN(vae_check_on)(be, v, "decoder backward"));
        MLB_TRY(FN(vae_check_grads)(be, v, grads, "decoder backward"));
        return FN(decode_backward_core)(be, v, cache, dimage, dz, grads);
    }
    if (v->mirror) {   // dimage crosses in, dz (+=) both ways; the weight gradients are added once
        const mlb_vae_config* g = &v->cfg;
        const int L = g->n_levels;
        be = v->mirror_ops;
        size_t ni = (size_t)cache->N * g->out_channels * (cache->h << (L - 1)) * (cache->w << (L - 1));
        size_t nz = dz ? (size_t)cache->N * g->latent_channels * cache->h * cache->w : 0;
        vae_t* gd = NULL;
        real* d;
        MLB_TRY(FN(vae_check_grads)(CPU_OPS, v, grads, "decoder backward"));
        if (grads) MLB_TRY(FN(mlb_vae_create)(be, &v->cfg, &gd));
        mlb_status s = op_alloc(be, &d, ni + nz);
        if (s) { FN(mlb_vae_free)(gd); return s; }
        s = op_upload(be, d, dimage, ni);
        if (!s && nz) s = op_upload(be, d + ni, dz, nz);
        if (!s) s = FN(decode_backward_core)(be, v->mirror, cache, d, nz ? d + ni : NULL, gd);
        if (!s && nz) s = op_download(be, dz, d + ni, nz);
        if (!s && gd) s = FN(vae_grads_add_from_device)(be, grads, gd);
        op_release(be, d);
        FN(mlb_vae_free)(gd);
        return s;
    }
    MLB_TRY(FN(vae_check_grads)(MODEL_OPS(v), v, grads, "decoder backward"));
    return FN(decode_backward_core)(MODEL_OPS(v), v, cache, dimage, dz, grads);
}
