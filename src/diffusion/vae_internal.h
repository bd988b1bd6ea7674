// Private to the VAE's sources (vae.c: layout, blocks, encoder; vae_decoder.c: decoder forward and
// backward): the op wrappers both precisions share, shapes, and the blocks' forward/backward.
// Included by dual-compiled sources only (after core/real.h), so `real` and FN() are defined.
#ifndef MATLABER_VAE_INTERNAL_H
#define MATLABER_VAE_INTERNAL_H
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend_f64.h"
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
// Every op runs through an op table: the float pass's backend.h table (the CPU's, or CUDA's for a
// model moved with mlb_vae_use_device, whose buffers (weights, scratch, cache) then all live on the
// GPU), the double pass's backend_f64.h one (the finite-difference references). The code below is
// written once over both.
typedef const FN(mlb_backend)* vae_ops;
#define CPU_OPS FN(mlb_backend_cpu)()
// the CPU ops a model without a mirror runs: fp32, or bf16 after mlb_vae_use_device(v, CPU, BF16)
#define MODEL_OPS(v) ((v)->mirror_ops ? (v)->mirror_ops : FN(mlb_backend_cpu)())
static inline mlb_device ops_device(vae_ops be) { return be->device; }
static inline mlb_status op_alloc(vae_ops be, real** p, size_t n) { return be->alloc(p, n); }
static inline void op_release(vae_ops be, void* p) { be->release(p); }
static inline mlb_status op_zero(vae_ops be, real* y, size_t n) { return be->zero(y, n); }
static inline mlb_status op_copy(vae_ops be, real* y, const real* x, size_t n) { return be->copy(y, x, n); }
static inline mlb_status op_upload(vae_ops be, real* dev, const real* host, size_t n) { return be->upload(dev, host, n); }
static inline mlb_status op_download(vae_ops be, real* host, const real* dev, size_t n) { return be->download(host, dev, n); }
static inline vae_ops ops_of(mlb_device d) { return FN(mlb_backend_for)(d, MLB_GEMM_FP32); }
static inline mlb_status op_add(vae_ops be, real* y, const real* x, size_t n) { return be->add(y, x, n); }
static inline mlb_status op_conv(vae_ops be, real* out, const real* in, const real* w, const real* b, mlb_conv2d cv) {
    return be->conv2d(be, out, in, w, b, &cv);
}
static inline mlb_status op_conv_bwd(vae_ops be, real* din, real* dw, real* db, const real* dout, const real* in,
                                      const real* w, mlb_conv2d cv) {
    return be->conv2d_backward(be, din, dw, db, dout, in, w, &cv);
}
static inline mlb_status op_gn(vae_ops be, real* out, real* mean, real* rstd, const real* in, const real* w, const real* b,
                        int N, int C, int HW, int G, real eps, mlb_activation act) {
    return be->groupnorm(out, mean, rstd, in, w, b, N, C, HW, G, eps, act);
}
static inline mlb_status op_gn_bwd(vae_ops be, real* din, real* dw, real* db, const real* dout, const real* in,
                                    const real* w, const real* b, const real* mean, const real* rstd, int N, int C,
                                    int HW, int G, mlb_activation act) {
    return be->groupnorm_backward(din, dw, db, dout, in, w, b, mean, rstd, N, C, HW, G, act);
}
static inline mlb_status op_linear(vae_ops be, real* out, const real* in, const real* w, const real* b, int B, int C, int OC) {
    return be->linear(be, out, in, w, b, B, C, OC);
}
static inline mlb_status op_linear_bwd(vae_ops be, real* din, real* dw, real* db, const real* dout, const real* in,
                                        const real* w, int B, int C, int OC) {
    return be->linear_backward(be, din, dw, db, dout, in, w, B, C, OC);
}
static inline mlb_status op_sdpa(vae_ops be, real* out, real* lse, const real* qkv, int N, int T, int C) {
    return be->sdpa(be, out, lse, qkv, qkv + C, qkv + 2 * C, N, T, T, C, 1, 3 * C, 3 * C);
}
static inline mlb_status op_sdpa_bwd(vae_ops be, real* dqkv, const real* dout, const real* out, const real* lse,
                              const real* qkv, int N, int T, int C) {
    return be->sdpa_backward(be, dqkv, dqkv + C, dqkv + 2 * C, dout, out, lse, qkv, qkv + C, qkv + 2 * C, N, T, T, C,
                             1, 3 * C, 3 * C);
}
static inline mlb_status op_transpose(vae_ops be, real* out, const real* in, int N, int R, int S, int acc) {
    return be->transpose_last2(out, in, N, R, S, acc);
}
static inline mlb_status op_upsample(vae_ops be, real* out, const real* in, int N, int C, int H, int W) {
    return be->upsample_nearest2x(out, in, N, C, H, W);
}
static inline mlb_status op_upsample_bwd_acc(vae_ops be, real* din, const real* dout, int N, int C, int H, int W) {
    return be->upsample_nearest2x_backward(din, dout, N, C, H, W);
}

// Carving a buffer into tensors: p NULL counts only.
typedef struct { real* p; size_t n; } carver;
static inline real* vae_take(carver* c, size_t n) {
    real* r = c->p ? c->p + c->n : NULL;
    c->n += n;
    return r;
}

// Channels of encoder level l's block j (input) and of decoder up block i's block j.
static inline int enc_cin(const mlb_vae_config* g, int l, int j) { return j > 0 ? g->block_out[l] : g->block_out[l > 0 ? l - 1 : 0]; }
static inline int dec_cout(const mlb_vae_config* g, int i) { return g->block_out[g->n_levels - 1 - i]; }
static inline int dec_cin(const mlb_vae_config* g, int i, int j) {
    return j > 0 ? dec_cout(g, i) : g->block_out[g->n_levels - (i > 0 ? i : 1)];
}

// 3x3 same conv, 1x1 conv, and the downsample (pad 0,0,1,1 then a stride-2 3x3 conv).
static inline mlb_conv2d conv3_desc(int N, int C, int H, int W, int OC) { return mlb_conv2d_make(N, C, H, W, OC, 3, 1, 1); }
static inline mlb_conv2d conv1_desc(int N, int C, int H, int W, int OC) { return mlb_conv2d_make(N, C, H, W, OC, 1, 1, 0); }
static inline mlb_conv2d down_desc(int N, int C, int H, int W) {
    mlb_conv2d cv = {N, C, H, W, C, 3, 3, 2, 2, 0, 0, 1, 1};
    return cv;
}


// Sizes a pass needs: the largest activation (elements for the batch), the largest conv
// workspace, and the mid block's token count.
typedef struct { size_t act, ws; int T; } vae_plan;

static inline void plan_conv(vae_plan* p, mlb_conv2d cv) {
    size_t w = conv2d_workspace_size(&cv);
    if (w > p->ws) p->ws = w;
}
static inline void plan_act(vae_plan* p, int N, int C, int H, int W) {
    size_t a = (size_t)N * C * H * W;
    if (a > p->act) p->act = a;
}

// din [N, C, H, W] = the sum of each 2x2 block of dout [N, C, 2H, 2W] (nearest 2x upsampling's
// backward; written, not accumulated), through the op table's upsample backward. t: unused.
static inline mlb_status op_upsample_bwd(vae_ops be, real* din, const real* dout, real* t, int N, int C, int H, int W) {
    (void)t;
    MLB_TRY(op_zero(be, din, (size_t)N * C * H * W));
    return op_upsample_bwd_acc(be, din, dout, N, C, H, W);
}

// A gradient model's tensor, or NULL (that gradient not wanted).
#define GRAD(gr, field) ((gr) ? (gr)->field : NULL)

// A cache's buffer (buf, capacity, device: the fields both caches have) grown to hold `need` values
// on be's device; on failure it is left empty. `what` ("encoder", "decoder") names the pass.
static inline mlb_status vae_cache_reserve(vae_ops be, real** buf, size_t* capacity, mlb_device* device, size_t need,
                                           const char* what) {
    if (*capacity >= need && *device == ops_device(be)) return MLB_OK;
    op_release(ops_of(*device), *buf);
    *buf = NULL;
    *capacity = 0;
    *device = ops_device(be);
    if (op_alloc(be, buf, need) != MLB_OK)
        return mlb_fail_context(MLB_ERR_NOMEM, "VAE %s: the backward cache (%.1f MB)", what,
                                need * (double)sizeof(real) / 1e6);
    *capacity = need;
    return MLB_OK;
}

// A forward's scratch: in the cache after its `kept` values (cache_buf not NULL), else `total`
// values allocated on be's device, which the caller releases.
static inline mlb_status vae_scratch(vae_ops be, real* cache_buf, size_t kept, size_t total, real** scratch,
                                     const char* what) {
    *scratch = cache_buf ? cache_buf + kept : NULL;
    if (!cache_buf && op_alloc(be, scratch, total) != MLB_OK)
        return mlb_fail_context(MLB_ERR_NOMEM, "VAE %s: %.1f MB of scratch", what, total * (double)sizeof(real) / 1e6);
    return MLB_OK;
}

// ---- shared by vae.c and vae_decoder.c (defined in vae.c) -----------------------------------------
// Buffers of the mid attention: tok [N*T, C] scratch; qkv [N*T, 3C], o [N*T, C], lse [N, T] and
// st [2, N, G] kept for the backward (in the cache or in scratch).
typedef struct { real *tok, *qkv, *o, *lse, *st; } att_bufs;

// What a cache keeps of the mid block (encoder and decoder alike): per ResNet its input, conv1's
// output and the norms' statistics [4, N, G]; the attention's input, qkv, output, log-sum-exp and
// norm statistics (NULL without mid attention).
typedef struct {
    real *x[2], *h1[2], *st[2];
    real *att_x, *att_qkv, *att_o, *att_lse, *att_st;
} mid_rec;

// Carves the mid block's kept tensors for N images of T = h w tokens and `top` channels.
static inline void vae_take_mid(carver* c, const mlb_vae_config* g, int N, size_t T, mid_rec* m) {
    const int top = g->block_out[g->n_levels - 1];
    const size_t NG = (size_t)N * g->norm_groups, n = (size_t)N * top * T;
    for (int k = 0; k < 2; k++) {
        m->x[k] = vae_take(c, n);
        m->h1[k] = vae_take(c, n);
        m->st[k] = vae_take(c, 4 * NG);
    }
    m->att_x = m->att_qkv = m->att_o = m->att_lse = m->att_st = NULL;
    if (g->mid_attention) {
        m->att_x = vae_take(c, n);
        m->att_qkv = vae_take(c, 3 * n);
        m->att_o = vae_take(c, n);
        m->att_lse = vae_take(c, (size_t)N * T);
        m->att_st = vae_take(c, 2 * NG);
    }
}

// x [N, cin, H, W] -> out [N, cout, H, W]. h1 receives conv1's output, st [4, N, G] the two norms'
// mean/rstd; t is scratch of the larger channel count.
mlb_status FN(vae_resnet_fwd)(vae_ops be, const resnet_t* r, const mlb_vae_config* g, const real* x, real* out,
                              real* h1, real* t, real* st, int N, int H, int W);
// dout [N, cout, H, W] -> dx [N, cin, H, W] (overwritten), from the block's input x, h1 and st;
// gr (NULL: none) += the block's weight gradients. t1, t2: scratch of the larger channel count.
mlb_status FN(vae_resnet_bwd)(vae_ops be, const resnet_t* r, resnet_t* gr, const mlb_vae_config* g, const real* x,
                              const real* h1, const real* st, const real* dout, real* dx, real* t1, real* t2, int N,
                              int H, int W);
// x [N, C, T] -> out [N, C, T] = x + proj(attn(qkv(gn(x)))); t is scratch [N, C, T].
mlb_status FN(vae_attn_fwd)(vae_ops be, const attn_t* a, const mlb_vae_config* g, const real* x, real* out, real* t,
                            att_bufs b, int N, int T);
// dout [N, C, T] -> dx [N, C, T] (overwritten); ga (NULL: none) += the weight gradients. Scratch:
// t [N, C, T], tok2 [N*T, C], dqkv [N*T, 3C] (and b.tok).
mlb_status FN(vae_attn_bwd)(vae_ops be, const attn_t* a, attn_t* ga, const mlb_vae_config* g, const real* x,
                            att_bufs b, const real* dout, real* dx, real* t, real* tok2, real* dqkv, int N, int T);
// A host view of n values at x on be's device: x itself on the CPU, else a copy in *tmp (the caller
// frees *tmp, NULL when nothing was copied).
mlb_status FN(vae_host_view)(vae_ops be, const real* x, size_t n, real** tmp, const real** view);
// MLB_OK when v (not NULL) lives where be runs (a call given a table).
mlb_status FN(vae_check_on)(vae_ops be, const vae_t* v, const char* what);
mlb_status FN(vae_check_size)(const vae_t* v, const char* what, int N, int H, int W);
// MLB_OK when grads (may be NULL) can receive v's weight gradients on be's device.
mlb_status FN(vae_check_grads)(vae_ops be, const vae_t* v, const vae_t* grads, const char* what);
// host grads += the device model gd's values (the host API on a mirror sums the weight gradients
// on the device, then adds them here once).
mlb_status FN(vae_grads_add_from_device)(vae_ops be, vae_t* grads, const vae_t* gd);

#endif
