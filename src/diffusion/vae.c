// The SD VAE (vae.h, docs/vae.md): parameter layout, encoder forward (optionally caching what its
// backward needs), encoder backward to the image, decoder forward. Dual-compiled (float / double
// _f64) like the other MLB_DUAL_SOURCES (core/real.h); loading lives in vae_load.c (float only).
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"
#include "matlaber/conv_ops.h"
#include "matlaber/nn.h"
#include "matlaber/vae.h"
#include "core/real.h"

#define VAE_PARALLEL_MIN 32768
#define LOGVAR_MIN (-30.0)
#define LOGVAR_MAX 20.0

typedef FN(mlb_vae) vae_t;
typedef FN(mlb_vae_resnet) resnet_t;
typedef FN(mlb_vae_attn) attn_t;

// ---- the ops ---------------------------------------------------------------------------------------
// The float build runs every op through a backend table (backend.h): the CPU's, or CUDA's for a
// model moved with mlb_vae_use_device, whose buffers (weights, scratch, cache) then all live on the
// GPU. The double build (finite-difference references) calls the CPU ops directly. Either way the
// code below is written once.
#ifdef MLB_F64
typedef const void* vae_ops;
#define CPU_OPS NULL
#define MODEL_OPS(v) NULL
static mlb_device ops_device(vae_ops be) { (void)be; return MLB_DEVICE_CPU; }
static mlb_status op_alloc(vae_ops be, real** p, size_t n) {
    (void)be;
    *p = malloc((n ? n : 1) * sizeof(real));
    return *p ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "out of memory for %.1f MB", n * (double)sizeof(real) / 1e6);
}
static void op_release(vae_ops be, void* p) { (void)be; free(p); }
static mlb_status op_zero(vae_ops be, real* y, size_t n) { (void)be; memset(y, 0, n * sizeof(real)); return MLB_OK; }
static mlb_status op_copy(vae_ops be, real* y, const real* x, size_t n) { (void)be; memcpy(y, x, n * sizeof(real)); return MLB_OK; }
static mlb_status op_upload(vae_ops be, real* dev, const real* host, size_t n) { return op_copy(be, dev, host, n); }
static mlb_status op_download(vae_ops be, real* host, const real* dev, size_t n) { return op_copy(be, host, dev, n); }
static vae_ops ops_of(mlb_device d) { (void)d; return NULL; }
static mlb_status op_add(vae_ops be, real* y, const real* x, size_t n) {
    (void)be;
#pragma omp parallel for schedule(static) if (n >= VAE_PARALLEL_MIN)
    for (size_t i = 0; i < n; i++) y[i] += x[i];
    return MLB_OK;
}
static mlb_status op_conv(vae_ops be, real* out, const real* in, const real* w, const real* b, mlb_conv2d cv) {
    (void)be;
    return conv2d_forward_f64(out, in, w, b, &cv, NULL);
}
static mlb_status op_conv_bwd(vae_ops be, real* din, const real* dout, const real* w, mlb_conv2d cv) {
    (void)be;
    return conv2d_backward_f64(din, NULL, NULL, dout, NULL, w, &cv, NULL);
}
static mlb_status op_gn(vae_ops be, real* out, real* mean, real* rstd, const real* in, const real* w, const real* b,
                        int N, int C, int HW, int G, real eps, mlb_activation act) {
    (void)be;
    return groupnorm_forward_f64(out, mean, rstd, in, w, b, N, C, HW, G, eps, act);
}
static mlb_status op_gn_bwd(vae_ops be, real* din, const real* dout, const real* in, const real* w, const real* b,
                            const real* mean, const real* rstd, int N, int C, int HW, int G, mlb_activation act) {
    (void)be;
    return groupnorm_backward_f64(din, NULL, NULL, dout, in, w, b, mean, rstd, N, C, HW, G, act);
}
static mlb_status op_linear(vae_ops be, real* out, const real* in, const real* w, const real* b, int B, int C, int OC) {
    (void)be;
    linear_forward_f64(out, in, w, b, B, C, OC);
    return MLB_OK;
}
static mlb_status op_linear_bwd(vae_ops be, real* din, const real* dout, const real* w, int B, int C, int OC) {
    (void)be;
    linear_backward_f64(din, NULL, NULL, dout, NULL, w, B, C, OC);
    return MLB_OK;
}
static mlb_status op_sdpa(vae_ops be, real* out, real* lse, const real* qkv, int N, int T, int C) {
    (void)be;
    return sdpa_forward_f64(out, lse, qkv, qkv + C, qkv + 2 * C, N, T, T, C, 1, 3 * C, 3 * C, NULL);
}
static mlb_status op_sdpa_bwd(vae_ops be, real* dqkv, const real* dout, const real* out, const real* lse,
                              const real* qkv, int N, int T, int C) {
    (void)be;
    return sdpa_backward_f64(dqkv, dqkv + C, dqkv + 2 * C, dout, out, lse, qkv, qkv + C, qkv + 2 * C, N, T, T, C, 1,
                             3 * C, 3 * C, NULL);
}
static mlb_status op_transpose(vae_ops be, real* out, const real* in, int N, int R, int S, int acc) {
    (void)be;
    transpose_last2_f64(out, in, N, R, S, acc);
    return MLB_OK;
}
static mlb_status op_upsample(vae_ops be, real* out, const real* in, int N, int C, int H, int W) {
    (void)be;
    upsample_nearest2x_forward_f64(out, in, N, C, H, W);
    return MLB_OK;
}
#else
typedef const mlb_backend* vae_ops;
#define CPU_OPS mlb_backend_cpu()
// the CPU ops a model without a mirror runs: fp32, or bf16 after mlb_vae_use_device(v, CPU, BF16)
#define MODEL_OPS(v) ((v)->mirror_ops ? (v)->mirror_ops : mlb_backend_cpu())
static mlb_device ops_device(vae_ops be) { return be->device; }
static mlb_status op_alloc(vae_ops be, real** p, size_t n) { return be->alloc(p, n); }
static void op_release(vae_ops be, void* p) { be->release(p); }
static mlb_status op_zero(vae_ops be, real* y, size_t n) { return be->zero(y, n); }
static mlb_status op_copy(vae_ops be, real* y, const real* x, size_t n) { return be->copy(y, x, n); }
static mlb_status op_upload(vae_ops be, real* dev, const real* host, size_t n) { return be->upload(dev, host, n); }
static mlb_status op_download(vae_ops be, real* host, const real* dev, size_t n) { return be->download(host, dev, n); }
static vae_ops ops_of(mlb_device d) { return mlb_backend_for(d, MLB_GEMM_FP32); }
static mlb_status op_add(vae_ops be, real* y, const real* x, size_t n) { return be->add(y, x, n); }
static mlb_status op_conv(vae_ops be, real* out, const real* in, const real* w, const real* b, mlb_conv2d cv) {
    return be->conv2d(be, out, in, w, b, &cv);
}
static mlb_status op_conv_bwd(vae_ops be, real* din, const real* dout, const real* w, mlb_conv2d cv) {
    return be->conv2d_backward(be, din, NULL, NULL, dout, NULL, w, &cv);
}
static mlb_status op_gn(vae_ops be, real* out, real* mean, real* rstd, const real* in, const real* w, const real* b,
                        int N, int C, int HW, int G, real eps, mlb_activation act) {
    return be->groupnorm(out, mean, rstd, in, w, b, N, C, HW, G, eps, act);
}
static mlb_status op_gn_bwd(vae_ops be, real* din, const real* dout, const real* in, const real* w, const real* b,
                            const real* mean, const real* rstd, int N, int C, int HW, int G, mlb_activation act) {
    return be->groupnorm_backward(din, NULL, NULL, dout, in, w, b, mean, rstd, N, C, HW, G, act);
}
static mlb_status op_linear(vae_ops be, real* out, const real* in, const real* w, const real* b, int B, int C, int OC) {
    return be->linear(be, out, in, w, b, B, C, OC);
}
static mlb_status op_linear_bwd(vae_ops be, real* din, const real* dout, const real* w, int B, int C, int OC) {
    return be->linear_backward(be, din, NULL, NULL, dout, NULL, w, B, C, OC);
}
static mlb_status op_sdpa(vae_ops be, real* out, real* lse, const real* qkv, int N, int T, int C) {
    return be->sdpa(be, out, lse, qkv, qkv + C, qkv + 2 * C, N, T, T, C, 1, 3 * C, 3 * C);
}
static mlb_status op_sdpa_bwd(vae_ops be, real* dqkv, const real* dout, const real* out, const real* lse,
                              const real* qkv, int N, int T, int C) {
    return be->sdpa_backward(be, dqkv, dqkv + C, dqkv + 2 * C, dout, out, lse, qkv, qkv + C, qkv + 2 * C, N, T, T, C,
                             1, 3 * C, 3 * C);
}
static mlb_status op_transpose(vae_ops be, real* out, const real* in, int N, int R, int S, int acc) {
    return be->transpose_last2(out, in, N, R, S, acc);
}
static mlb_status op_upsample(vae_ops be, real* out, const real* in, int N, int C, int H, int W) {
    return be->upsample_nearest2x(out, in, N, C, H, W);
}
#endif

// ---- parameter layout ------------------------------------------------------------------------------
typedef struct { real* p; size_t n; } carver;   // p NULL: count only
static real* FN(take)(carver* c, size_t n) {
    real* r = c->p ? c->p + c->n : NULL;
    c->n += n;
    return r;
}

static void FN(carve_resnet)(carver* c, resnet_t* r, int cin, int cout) {
    r->cin = cin;
    r->cout = cout;
    r->norm1_w = FN(take)(c, cin); r->norm1_b = FN(take)(c, cin);
    r->conv1_w = FN(take)(c, (size_t)cout * cin * 9); r->conv1_b = FN(take)(c, cout);
    r->norm2_w = FN(take)(c, cout); r->norm2_b = FN(take)(c, cout);
    r->conv2_w = FN(take)(c, (size_t)cout * cout * 9); r->conv2_b = FN(take)(c, cout);
    r->short_w = r->short_b = NULL;
    if (cin != cout) { r->short_w = FN(take)(c, (size_t)cout * cin); r->short_b = FN(take)(c, cout); }
}

static void FN(carve_attn)(carver* c, attn_t* a, int C) {
    a->C = C;
    a->norm_w = FN(take)(c, C); a->norm_b = FN(take)(c, C);
    a->qkv_w = FN(take)(c, (size_t)3 * C * C); a->qkv_b = FN(take)(c, (size_t)3 * C);
    a->proj_w = FN(take)(c, (size_t)C * C); a->proj_b = FN(take)(c, C);
}

// Channels of encoder level l's block j (input) and of decoder up block i's block j.
static int enc_cin(const mlb_vae_config* g, int l, int j) { return j > 0 ? g->block_out[l] : g->block_out[l > 0 ? l - 1 : 0]; }
static int dec_cout(const mlb_vae_config* g, int i) { return g->block_out[g->n_levels - 1 - i]; }
static int dec_cin(const mlb_vae_config* g, int i, int j) {
    return j > 0 ? dec_cout(g, i) : g->block_out[g->n_levels - (i > 0 ? i : 1)];
}

static size_t FN(carve_all)(vae_t* v, real* base) {
    const mlb_vae_config* g = &v->cfg;
    const int L = g->n_levels, R = g->layers_per_block, z = g->latent_channels, top = g->block_out[L - 1];
    carver c = {base, 0};
    v->enc_conv_in_w = FN(take)(&c, (size_t)g->block_out[0] * g->in_channels * 9);
    v->enc_conv_in_b = FN(take)(&c, g->block_out[0]);
    for (int l = 0; l < L; l++) {
        for (int j = 0; j < R; j++) FN(carve_resnet)(&c, &v->enc_res[l][j], enc_cin(g, l, j), g->block_out[l]);
        if (l < L - 1) {
            v->enc_down_w[l] = FN(take)(&c, (size_t)g->block_out[l] * g->block_out[l] * 9);
            v->enc_down_b[l] = FN(take)(&c, g->block_out[l]);
        }
    }
    FN(carve_resnet)(&c, &v->enc_mid_res[0], top, top);
    if (g->mid_attention) FN(carve_attn)(&c, &v->enc_mid_attn, top);
    FN(carve_resnet)(&c, &v->enc_mid_res[1], top, top);
    v->enc_norm_out_w = FN(take)(&c, top); v->enc_norm_out_b = FN(take)(&c, top);
    v->enc_conv_out_w = FN(take)(&c, (size_t)2 * z * top * 9); v->enc_conv_out_b = FN(take)(&c, 2 * z);
    v->quant_w = FN(take)(&c, (size_t)4 * z * z); v->quant_b = FN(take)(&c, 2 * z);
    v->post_quant_w = FN(take)(&c, (size_t)z * z); v->post_quant_b = FN(take)(&c, z);
    v->dec_conv_in_w = FN(take)(&c, (size_t)top * z * 9); v->dec_conv_in_b = FN(take)(&c, top);
    FN(carve_resnet)(&c, &v->dec_mid_res[0], top, top);
    if (g->mid_attention) FN(carve_attn)(&c, &v->dec_mid_attn, top);
    FN(carve_resnet)(&c, &v->dec_mid_res[1], top, top);
    for (int i = 0; i < L; i++) {
        for (int j = 0; j <= R; j++) FN(carve_resnet)(&c, &v->dec_res[i][j], dec_cin(g, i, j), dec_cout(g, i));
        if (i < L - 1) {
            v->dec_up_w[i] = FN(take)(&c, (size_t)dec_cout(g, i) * dec_cout(g, i) * 9);
            v->dec_up_b[i] = FN(take)(&c, dec_cout(g, i));
        }
    }
    v->dec_norm_out_w = FN(take)(&c, g->block_out[0]); v->dec_norm_out_b = FN(take)(&c, g->block_out[0]);
    v->dec_conv_out_w = FN(take)(&c, (size_t)g->out_channels * g->block_out[0] * 9);
    v->dec_conv_out_b = FN(take)(&c, g->out_channels);
    return c.n;
}

// A model of cfg with zeroed parameters in the memory of be's device.
static mlb_status FN(create_on)(vae_ops be, const mlb_vae_config* cfg, vae_t** out) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "VAE: NULL output");
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

mlb_status FN(mlb_vae_create)(const mlb_vae_config* cfg, vae_t** out) { return FN(create_on)(CPU_OPS, cfg, out); }

void FN(mlb_vae_free)(vae_t* v) {
    if (!v) return;
    FN(mlb_vae_free)(v->mirror);
    op_release(ops_of(v->device), v->params);
    free(v);
}

// 3x3 same conv, 1x1 conv, and the downsample (pad 0,0,1,1 then a stride-2 3x3 conv).
static mlb_conv2d conv3_desc(int N, int C, int H, int W, int OC) { return mlb_conv2d_make(N, C, H, W, OC, 3, 1, 1); }
static mlb_conv2d conv1_desc(int N, int C, int H, int W, int OC) { return mlb_conv2d_make(N, C, H, W, OC, 1, 1, 0); }
static mlb_conv2d down_desc(int N, int C, int H, int W) {
    mlb_conv2d cv = {N, C, H, W, C, 3, 3, 2, 2, 0, 0, 1, 1};
    return cv;
}


// Sizes a pass needs: the largest activation (elements for the batch), the largest conv
// workspace, and the mid block's token count.
typedef struct { size_t act, ws; int T; } vae_plan;

static void plan_conv(vae_plan* p, mlb_conv2d cv) {
    size_t w = conv2d_workspace_size(&cv);
    if (w > p->ws) p->ws = w;
}
static void plan_act(vae_plan* p, int N, int C, int H, int W) {
    size_t a = (size_t)N * C * H * W;
    if (a > p->act) p->act = a;
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

// ---- ResNet block and attention ------------------------------------------------------------------
// x [N, cin, H, W] -> out [N, cout, H, W]. h1 receives conv1's output, st [4, N, G] the two norms'
// mean/rstd; t is scratch of the larger channel count.
static mlb_status FN(resnet_fwd)(vae_ops be, const resnet_t* r, const mlb_vae_config* g, const real* x, real* out,
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

// dout [N, cout, H, W] -> dx [N, cin, H, W] (overwritten), from the block's input x, h1 and st.
static mlb_status FN(resnet_bwd)(vae_ops be, const resnet_t* r, const mlb_vae_config* g, const real* x, const real* h1,
                                 const real* st, const real* dout, real* dx, real* t1, real* t2, int N, int H, int W) {
    const int G = g->norm_groups, HW = H * W;
    const size_t NG = (size_t)N * G, nin = (size_t)N * r->cin * HW, nout = (size_t)N * r->cout * HW;
    MLB_TRY(op_zero(be, t1, nout));
    MLB_TRY(op_conv_bwd(be, t1, dout, r->conv2_w, conv3_desc(N, r->cout, H, W, r->cout)));
    MLB_TRY(op_zero(be, t2, nout));
    MLB_TRY(op_gn_bwd(be, t2, t1, h1, r->norm2_w, r->norm2_b, st + 2 * NG, st + 3 * NG, N, r->cout, HW, G,
                      MLB_ACT_SILU));
    MLB_TRY(op_zero(be, t1, nin));
    MLB_TRY(op_conv_bwd(be, t1, t2, r->conv1_w, conv3_desc(N, r->cin, H, W, r->cout)));
    MLB_TRY(op_zero(be, dx, nin));
    MLB_TRY(op_gn_bwd(be, dx, t1, x, r->norm1_w, r->norm1_b, st, st + NG, N, r->cin, HW, G, MLB_ACT_SILU));
    if (r->short_w) return op_conv_bwd(be, dx, dout, r->short_w, conv1_desc(N, r->cin, H, W, r->cout));
    return op_add(be, dx, dout, nout);
}

// Buffers of the mid attention: tok [N*T, C] scratch; qkv [N*T, 3C], o [N*T, C], lse [N, T] and
// st [2, N, G] kept for the backward (in the cache or in scratch).
typedef struct { real *tok, *qkv, *o, *lse, *st; } att_bufs;

// x [N, C, T] -> out [N, C, T] = x + proj(attn(qkv(gn(x)))); t is scratch [N, C, T].
static mlb_status FN(attn_fwd)(vae_ops be, const attn_t* a, const mlb_vae_config* g, const real* x, real* out, real* t,
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

// dout [N, C, T] -> dx [N, C, T] (overwritten). Scratch: t [N, C, T], tok and tok2 [N*T, C],
// dqkv [N*T, 3C].
static mlb_status FN(attn_bwd)(vae_ops be, const attn_t* a, const mlb_vae_config* g, const real* x, att_bufs b,
                               const real* dout, real* dx, real* t, real* tok2, real* dqkv, int N, int T) {
    const int C = a->C, G = g->norm_groups;
    const size_t NG = (size_t)N * G, n = (size_t)N * C * T;
    MLB_TRY(op_copy(be, dx, dout, n));   // the residual
    MLB_TRY(op_transpose(be, b.tok, dout, N, C, T, 0));
    MLB_TRY(op_zero(be, tok2, n));
    MLB_TRY(op_linear_bwd(be, tok2, b.tok, a->proj_w, N * T, C, C));
    MLB_TRY(op_zero(be, dqkv, 3 * n));
    MLB_TRY(op_sdpa_bwd(be, dqkv, tok2, b.o, b.lse, b.qkv, N, T, C));
    MLB_TRY(op_zero(be, b.tok, n));
    MLB_TRY(op_linear_bwd(be, b.tok, dqkv, a->qkv_w, N * T, C, 3 * C));
    MLB_TRY(op_transpose(be, t, b.tok, N, T, C, 0));
    return op_gn_bwd(be, dx, t, x, a->norm_w, a->norm_b, b.st, b.st + NG, N, C, T, G, MLB_ACT_IDENTITY);
}

// ---- the encoder's cache ---------------------------------------------------------------------------
typedef struct {
    real *res_x[MLB_VAE_MAX_LEVELS][MLB_VAE_MAX_LAYERS], *res_h1[MLB_VAE_MAX_LEVELS][MLB_VAE_MAX_LAYERS];
    real* res_st[MLB_VAE_MAX_LEVELS][MLB_VAE_MAX_LAYERS];
    real *mid_x[2], *mid_h1[2], *mid_st[2];
    real *att_x, *att_qkv, *att_o, *att_lse, *att_st;
    real *out_x, *out_st;
    real* moments;
} enc_rec;

static size_t FN(enc_layout)(const mlb_vae_config* g, int N, int H, int W, real* buf, enc_rec* r) {
    carver c = {buf, 0};
    const int L = g->n_levels, top = g->block_out[L - 1];
    const size_t NG = (size_t)N * g->norm_groups;
    for (int l = 0; l < L; l++) {
        size_t px = (size_t)N * H * W;
        for (int j = 0; j < g->layers_per_block; j++) {
            r->res_x[l][j] = FN(take)(&c, px * enc_cin(g, l, j));
            r->res_h1[l][j] = FN(take)(&c, px * g->block_out[l]);
            r->res_st[l][j] = FN(take)(&c, 4 * NG);
        }
        if (l < L - 1) { H /= 2; W /= 2; }
    }
    const size_t T = (size_t)H * W, n = (size_t)N * top * T;
    for (int k = 0; k < 2; k++) {
        r->mid_x[k] = FN(take)(&c, n);
        r->mid_h1[k] = FN(take)(&c, n);
        r->mid_st[k] = FN(take)(&c, 4 * NG);
    }
    r->att_x = r->att_qkv = r->att_o = r->att_lse = r->att_st = NULL;
    if (g->mid_attention) {
        r->att_x = FN(take)(&c, n);
        r->att_qkv = FN(take)(&c, 3 * n);
        r->att_o = FN(take)(&c, n);
        r->att_lse = FN(take)(&c, (size_t)N * T);
        r->att_st = FN(take)(&c, 2 * NG);
    }
    r->out_x = FN(take)(&c, n);
    r->out_st = FN(take)(&c, 2 * NG);
    r->moments = FN(take)(&c, (size_t)N * 2 * g->latent_channels * T);
    return c.n;
}

size_t FN(mlb_vae_cache_size)(const mlb_vae_config* cfg, int N, int H, int W) {
    if (!cfg || mlb_vae_config_check(cfg) || N < 1 || mlb_vae_latent_size(cfg, H) < 1 || mlb_vae_latent_size(cfg, W) < 1) {
        mlb_clear_error();
        return 0;
    }
    enc_rec r;
    return FN(enc_layout)(cfg, N, H, W, NULL, &r) + FN(enc_scratch)(cfg, N, H, W);
}

void FN(mlb_vae_cache_free)(FN(mlb_vae_cache)* cache) {
    if (!cache) return;
    op_release(ops_of(cache->device), cache->buf);
    memset(cache, 0, sizeof *cache);
}

// A host view of n values at x on be's device: x itself on the CPU, else a copy in *tmp (the caller
// frees *tmp, NULL when nothing was copied).
static mlb_status FN(host_view)(vae_ops be, const real* x, size_t n, real** tmp, const real** view) {
    *tmp = NULL;
    *view = x;
    if (ops_device(be) == MLB_DEVICE_CPU) return MLB_OK;
    if (!(*tmp = malloc(n * sizeof(real)))) return mlb_fail(MLB_ERR_NOMEM, "VAE: out of memory for a host copy");
    *view = *tmp;
    return op_download(be, *tmp, x, n);
}

static mlb_status FN(check_size)(const vae_t* v, const char* what, int N, int H, int W) {
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
    const mlb_device dev = ops_device(be);
    enc_rec rec;
    size_t kept = 0;   // with a cache: the values its backward reads; the scratch follows them
    if (cache) {
        kept = FN(enc_layout)(g, N, H, W, NULL, &rec);
        size_t need = kept + FN(enc_scratch)(g, N, H, W);
        cache->N = 0;   // invalid until this forward completes
        if (cache->capacity < need || cache->device != dev) {
            op_release(ops_of(cache->device), cache->buf);
            cache->buf = NULL;
            cache->capacity = 0;
            cache->device = dev;
            if (op_alloc(be, &cache->buf, need) != MLB_OK)
                return mlb_fail_context(MLB_ERR_NOMEM, "VAE encoder: the backward cache (%.1f MB)",
                                        need * (double)sizeof(real) / 1e6);
            cache->capacity = need;
        }
        FN(enc_layout)(g, N, H, W, cache->buf, &rec);
    }
    vae_plan p = enc_plan(g, N, H, W);
    const size_t nT = (size_t)N * p.T * top;
    size_t total = FN(enc_scratch_of)(g, N, H, W, cache ? ENC_FORWARD_CACHED : ENC_FORWARD);
    real* scratch = cache ? cache->buf + kept : NULL;
    if (!cache && op_alloc(be, &scratch, total) != MLB_OK)
        return mlb_fail_context(MLB_ERR_NOMEM, "VAE encoder: %.1f MB of scratch", total * (double)sizeof(real) / 1e6);
    real* P0 = scratch;
    real* P1 = P0 + p.act;
    real* Tb = P1 + p.act;
    real* Hs = cache ? NULL : Tb + p.act;
    real* st = Tb + p.act * (cache ? 1 : 2);
    real* ab = st + 4 * NG;
    att_bufs A = {ab, NULL, NULL, NULL, NULL};
    if (g->mid_attention) {
        A.qkv = cache ? rec.att_qkv : ab + nT;
        A.o = cache ? rec.att_o : ab + 4 * nT;
        A.lse = cache ? rec.att_lse : ab + 5 * nT;
        A.st = cache ? rec.att_st : st;
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
            else if (l < L - 1) nxt = OTHER(cur);
            else nxt = cache ? rec.mid_x[0] : OTHER(cur);
            s = FN(resnet_fwd)(be, &v->enc_res[l][j], g, cur, nxt, cache ? rec.res_h1[l][j] : Hs, Tb,
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
        real* nxt = g->mid_attention ? (cache ? rec.att_x : OTHER(cur)) : (cache ? rec.mid_x[1] : OTHER(cur));
        s = FN(resnet_fwd)(be, &v->enc_mid_res[0], g, cur, nxt, cache ? rec.mid_h1[0] : Hs, Tb,
                           cache ? rec.mid_st[0] : st, N, h, w);
        cur = nxt;
    }
    if (!s && g->mid_attention) {
        real* nxt = cache ? rec.mid_x[1] : OTHER(cur);
        s = FN(attn_fwd)(be, &v->enc_mid_attn, g, cur, nxt, Tb, A, N, T);
        cur = nxt;
    }
    if (!s) {
        real* nxt = cache ? rec.out_x : OTHER(cur);
        s = FN(resnet_fwd)(be, &v->enc_mid_res[1], g, cur, nxt, cache ? rec.mid_h1[1] : Hs, Tb,
                           cache ? rec.mid_st[1] : st, N, h, w);
        cur = nxt;
    }
    if (!s) {
        real* ost = cache ? rec.out_st : st;
        s = op_gn(be, Tb, ost, ost + NG, cur, v->enc_norm_out_w, v->enc_norm_out_b, N, top, T, g->norm_groups,
                  (real)g->norm_eps, MLB_ACT_SILU);
    }
    real* moments = cache ? rec.moments : Tb;
    if (!s) s = op_conv(be, OTHER(cur), Tb, v->enc_conv_out_w, v->enc_conv_out_b, conv3_desc(N, top, h, w, 2 * z));
    if (!s) s = op_conv(be, moments, OTHER(cur), v->quant_w, v->quant_b, conv1_desc(N, 2 * z, h, w, 2 * z));
#undef OTHER
    const size_t zn = (size_t)z * T;
    real* tmp = NULL;
    const real* mh = NULL;
    if (!s && (mean || logvar)) s = FN(host_view)(be, moments, (size_t)N * 2 * zn, &tmp, &mh);
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
        if (cache) { cache->N = N; cache->H = H; cache->W = W; }
    }
    free(tmp);
    if (!cache) op_release(be, scratch);
    return s;
}

mlb_status FN(mlb_vae_encode)(const vae_t* v, const real* image, int N, int H, int W, real* mean, real* logvar,
                              FN(mlb_vae_cache)* cache) {
    MLB_TRY(FN(check_size)(v, "encoder", N, H, W));
    if (!image) return mlb_fail(MLB_ERR_ARG, "VAE encoder: NULL image");
#ifndef MLB_F64
    if (v->mirror) {   // mlb_vae_use_device: the image crosses once, the cache stays on the device
        vae_ops be = v->mirror_ops;
        size_t n = (size_t)N * v->cfg.in_channels * H * W;
        real* d;
        MLB_TRY(op_alloc(be, &d, n));
        mlb_status s = op_upload(be, d, image, n);
        if (!s) s = FN(encode_core)(be, v->mirror, d, N, H, W, mean, logvar, cache);
        op_release(be, d);
        return s;
    }
#endif
    return FN(encode_core)(MODEL_OPS(v), v, image, N, H, W, mean, logvar, cache);
}

// On the ops of be: the cache and dimage live on be's device; dmean and dlogvar on the host.
static mlb_status FN(encode_backward_core)(vae_ops be, const vae_t* v, const FN(mlb_vae_cache)* cache,
                                           const real* dmean, const real* dlogvar, real* dimage) {
    const mlb_vae_config* g = &v->cfg;
    const int N = cache->N, H = cache->H, W = cache->W;
    const int L = g->n_levels, R = g->layers_per_block, z = g->latent_channels, top = g->block_out[L - 1];
    const size_t NG = (size_t)N * g->norm_groups;
    enc_rec rec;
    const size_t kept = FN(enc_layout)(g, N, H, W, NULL, &rec);
    if (kept + FN(enc_scratch)(g, N, H, W) > cache->capacity)
        return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: the cache is smaller than its forward needed (another "
                        "model's cache?)");
    if (cache->device != ops_device(be))
        return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: the cache is on the %s, the model's ops on the other "
                        "device", mlb_device_name(cache->device));
    FN(enc_layout)(g, N, H, W, cache->buf, &rec);
    vae_plan p = enc_plan(g, N, H, W);
    const size_t nT = (size_t)N * p.T * top;
    real* D0 = cache->buf + kept;   // the cache's scratch (FN(enc_scratch))
    real* D1 = D0 + p.act;
    real* T1 = D1 + p.act;
    real* T2 = T1 + p.act;
    real* ab = T2 + p.act;
    att_bufs A = {ab, rec.att_qkv, rec.att_o, rec.att_lse, rec.att_st};
    int hs[MLB_VAE_MAX_LEVELS], wsz[MLB_VAE_MAX_LEVELS];
    hs[0] = H; wsz[0] = W;
    for (int l = 1; l < L; l++) { hs[l] = hs[l - 1] / 2; wsz[l] = wsz[l - 1] / 2; }
    const int h = hs[L - 1], w = wsz[L - 1], T = h * w;
    const size_t zn = (size_t)z * T, nm = (size_t)N * 2 * zn;
    // d(moments), on the host: the mean half, and the logvar half where the clamp passes it
    real *mtmp = NULL, *d = ops_device(be) == MLB_DEVICE_CPU ? T1 : malloc(nm * sizeof(real));
    const real* mh = NULL;
    mlb_status s = d ? FN(host_view)(be, rec.moments, nm, &mtmp, &mh) : mlb_fail(MLB_ERR_NOMEM, "VAE: out of memory");
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
#define OTHER(x) ((x) == D0 ? D1 : D0)
    if (!s) s = op_zero(be, D0, nm);
    if (!s) s = op_conv_bwd(be, D0, T1, v->quant_w, conv1_desc(N, 2 * z, h, w, 2 * z));
    if (!s) s = op_zero(be, T2, nT);
    if (!s) s = op_conv_bwd(be, T2, D0, v->enc_conv_out_w, conv3_desc(N, top, h, w, 2 * z));
    real* cur = D1;
    if (!s) s = op_zero(be, D1, nT);
    if (!s)
        s = op_gn_bwd(be, D1, T2, rec.out_x, v->enc_norm_out_w, v->enc_norm_out_b, rec.out_st, rec.out_st + NG, N, top,
                      T, g->norm_groups, MLB_ACT_SILU);
    if (!s) {
        s = FN(resnet_bwd)(be, &v->enc_mid_res[1], g, rec.mid_x[1], rec.mid_h1[1], rec.mid_st[1], cur, OTHER(cur), T1,
                           T2, N, h, w);
        cur = OTHER(cur);
    }
    if (!s && g->mid_attention) {
        s = FN(attn_bwd)(be, &v->enc_mid_attn, g, rec.att_x, A, cur, OTHER(cur), T1, ab + nT, ab + 2 * nT, N, T);
        cur = OTHER(cur);
    }
    if (!s) {
        s = FN(resnet_bwd)(be, &v->enc_mid_res[0], g, rec.mid_x[0], rec.mid_h1[0], rec.mid_st[0], cur, OTHER(cur), T1,
                           T2, N, h, w);
        cur = OTHER(cur);
    }
    for (int l = L - 1; l >= 0 && !s; l--) {
        if (l < L - 1) {
            real* nxt = OTHER(cur);
            s = op_zero(be, nxt, (size_t)N * g->block_out[l] * hs[l] * wsz[l]);
            if (!s) s = op_conv_bwd(be, nxt, cur, v->enc_down_w[l], down_desc(N, g->block_out[l], hs[l], wsz[l]));
            cur = nxt;
        }
        for (int j = R - 1; j >= 0 && !s; j--) {
            s = FN(resnet_bwd)(be, &v->enc_res[l][j], g, rec.res_x[l][j], rec.res_h1[l][j], rec.res_st[l][j], cur,
                               OTHER(cur), T1, T2, N, hs[l], wsz[l]);
            cur = OTHER(cur);
        }
    }
#undef OTHER
    if (!s) s = op_conv_bwd(be, dimage, cur, v->enc_conv_in_w, conv3_desc(N, g->in_channels, H, W, g->block_out[0]));
    return s;
}

mlb_status FN(mlb_vae_encode_backward)(const vae_t* v, const FN(mlb_vae_cache)* cache, const real* dmean,
                                       const real* dlogvar, real* dimage) {
    if (!v || !cache) return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: NULL model or cache");
    if (cache->N < 1 || !cache->buf)
        return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: the cache holds no forward (run mlb_vae_encode with this "
                        "cache first)");
    if (!dimage) return mlb_fail(MLB_ERR_ARG, "VAE encoder backward: NULL image gradient");
#ifndef MLB_F64
    if (v->mirror) {   // dimage (+=) crosses both ways
        vae_ops be = v->mirror_ops;
        size_t n = (size_t)cache->N * v->cfg.in_channels * cache->H * cache->W;
        real* d;
        MLB_TRY(op_alloc(be, &d, n));
        mlb_status s = op_upload(be, d, dimage, n);
        if (!s) s = FN(encode_backward_core)(be, v->mirror, cache, dmean, dlogvar, d);
        if (!s) s = op_download(be, dimage, d, n);
        op_release(be, d);
        return s;
    }
#endif
    return FN(encode_backward_core)(MODEL_OPS(v), v, cache, dmean, dlogvar, dimage);
}

// ---- decoder ---------------------------------------------------------------------------------------
// On the ops of be: zin and image live on be's device.
static mlb_status FN(decode_core)(vae_ops be, const vae_t* v, const real* zin, int N, int h, int w, real* image) {
    const mlb_vae_config* g = &v->cfg;
    const int L = g->n_levels, R = g->layers_per_block, z = g->latent_channels, top = g->block_out[L - 1];
    const size_t NG = (size_t)N * g->norm_groups;
    vae_plan p = dec_plan(g, N, h, w);
    const size_t nT = (size_t)N * p.T * top;
    size_t att = g->mid_attention ? nT * 5 + (size_t)N * p.T : 0;
    size_t total = p.act * 4 + att + 4 * NG;
    real* scratch;
    if (op_alloc(be, &scratch, total) != MLB_OK)
        return mlb_fail_context(MLB_ERR_NOMEM, "VAE decoder: %.1f MB of scratch", total * (double)sizeof(real) / 1e6);
    real* P0 = scratch;
    real* P1 = P0 + p.act;
    real* Tb = P1 + p.act;
    real* Hs = Tb + p.act;
    real* st = Hs + p.act;
    real* ab = st + 4 * NG;
    att_bufs A = {ab, ab + nT, ab + 4 * nT, ab + 5 * nT, st};
#define OTHER(x) ((x) == P0 ? P1 : P0)
    mlb_status s = op_conv(be, P0, zin, v->post_quant_w, v->post_quant_b, conv1_desc(N, z, h, w, z));
    if (!s) s = op_conv(be, P1, P0, v->dec_conv_in_w, v->dec_conv_in_b, conv3_desc(N, z, h, w, top));
    real* cur = P1;
    if (!s) { s = FN(resnet_fwd)(be, &v->dec_mid_res[0], g, cur, OTHER(cur), Hs, Tb, st, N, h, w); cur = OTHER(cur); }
    if (!s && g->mid_attention) { s = FN(attn_fwd)(be, &v->dec_mid_attn, g, cur, OTHER(cur), Tb, A, N, h * w); cur = OTHER(cur); }
    if (!s) { s = FN(resnet_fwd)(be, &v->dec_mid_res[1], g, cur, OTHER(cur), Hs, Tb, st, N, h, w); cur = OTHER(cur); }
    for (int i = 0; i < L && !s; i++) {
        for (int j = 0; j <= R && !s; j++) {
            s = FN(resnet_fwd)(be, &v->dec_res[i][j], g, cur, OTHER(cur), Hs, Tb, st, N, h, w);
            cur = OTHER(cur);
        }
        if (i < L - 1 && !s) {
            int c = dec_cout(g, i);
            s = op_upsample(be, Tb, cur, N, c, h, w);
            h *= 2;
            w *= 2;
            if (!s) s = op_conv(be, OTHER(cur), Tb, v->dec_up_w[i], v->dec_up_b[i], conv3_desc(N, c, h, w, c));
            cur = OTHER(cur);
        }
    }
#undef OTHER
    if (!s)
        s = op_gn(be, Tb, NULL, NULL, cur, v->dec_norm_out_w, v->dec_norm_out_b, N, g->block_out[0], h * w,
                  g->norm_groups, (real)g->norm_eps, MLB_ACT_SILU);
    if (!s)
        s = op_conv(be, image, Tb, v->dec_conv_out_w, v->dec_conv_out_b, conv3_desc(N, g->block_out[0], h, w, g->out_channels));
    op_release(be, scratch);
    return s;
}

mlb_status FN(mlb_vae_decode)(const vae_t* v, const real* zin, int N, int h, int w, real* image) {
    if (!v) return mlb_fail(MLB_ERR_ARG, "VAE decoder: NULL model");
    const mlb_vae_config* g = &v->cfg;
    const int L = g->n_levels, z = g->latent_channels;
    if (N < 1 || h < 1 || w < 1 || (int64_t)h << (L - 1) > 65536 || (int64_t)w << (L - 1) > 65536)
        return mlb_fail(MLB_ERR_ARG, "VAE decoder: bad latent shape [%d, %d, %d, %d]", N, z, h, w);
    MLB_TRY(FN(check_size)(v, "decoder", N, h << (L - 1), w << (L - 1)));
    if (!zin || !image) return mlb_fail(MLB_ERR_ARG, "VAE decoder: NULL latent or image");
#ifndef MLB_F64
    if (v->mirror) {
        vae_ops be = v->mirror_ops;
        size_t nz = (size_t)N * z * h * w, ni = (size_t)N * g->out_channels * (h << (L - 1)) * (w << (L - 1));
        real* d;
        MLB_TRY(op_alloc(be, &d, nz + ni));
        mlb_status s = op_upload(be, d, zin, nz);
        if (!s) s = FN(decode_core)(be, v->mirror, d, N, h, w, d + nz);
        if (!s) s = op_download(be, image, d + nz, ni);
        op_release(be, d);
        return s;
    }
#endif
    return FN(decode_core)(MODEL_OPS(v), v, zin, N, h, w, image);
}

#ifndef MLB_F64
mlb_status mlb_vae_use_device(mlb_vae* v, mlb_device d, mlb_gemm_precision prec) {
    if (!v) return mlb_fail(MLB_ERR_ARG, "mlb_vae_use_device: NULL VAE");
    mlb_vae_free(v->mirror);
    v->mirror = NULL;
    // on the CPU no copy: only bf16 changes the ops (fp16 and tf32 are GPU formats: fp32 here)
    v->mirror_ops = d == MLB_DEVICE_CPU && prec == MLB_GEMM_BF16 ? mlb_backend_for(d, prec) : NULL;
    if (d == MLB_DEVICE_CPU) return MLB_OK;
    if (v->device != MLB_DEVICE_CPU) return mlb_fail(MLB_ERR_ARG, "mlb_vae_use_device: the VAE must be on the CPU");
    vae_ops be = mlb_backend_for(d, prec);
    vae_t* m;
    mlb_status s = FN(create_on)(be, &v->cfg, &m);
    if (!s) {
        s = op_upload(be, m->params, v->params, v->n_params);
        if (s) mlb_vae_free(m);
    }
    if (s) return mlb_fail_context(s, "moving the VAE (%zu parameters) to the %s", v->n_params, mlb_device_name(d));
    v->mirror = m;
    v->mirror_ops = be;
    return MLB_OK;
}
#endif
