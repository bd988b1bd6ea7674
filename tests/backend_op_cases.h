// The cases of tests/test_backend_ops.c, one pair per op of include/matlaber/backend_ops.def:
//   setup_<op>(c, d, trial)  declares the op's buffers and draws its shape (trial 0: every size 1,
//                            later trials ragged sizes: primes, 2^k +- 1, anything up to a cap)
//   call_<op>(be, p, c)      runs be-><op> on the buffers p, which live on be's device
// The test's op loop is generated from the op list, so an op without its pair does not build.
// Buffers are declared in the order the call passes them; p[i] is the i-th declared.
#ifndef MATLABER_BACKEND_OP_CASES_H
#define MATLABER_BACKEND_OP_CASES_H
#include "cuda_test_util.h"
#include "matlaber/backend.h"
#include "matlaber/envmap.h"
#include "matlaber/transformer_ops.h"

// How an output is bounded; the numbers are in test_backend_ops.c's header.
// B_BITS: an int32 buffer (face ids), compared bit for bit on every table.
typedef enum { B_EXACT, B_ELEM, B_SUMS, B_SHADE, B_SHADE_GRAD, B_GEMM, B_GEMM3, B_BITS } bound_class;
// IN: read. OUT: written (NaN before, so a value not written shows). ACC: accumulated (+=; random
// before, the increments are compared). NUL: passed as NULL (an optional output or input).
typedef enum { IN, OUT, ACC, NUL } role;
typedef struct {
    const char* name;
    size_t n;
    role r;
    float lo, hi;   // IN and ACC start uniform in [lo, hi)
    bound_class cls;
} buf;

enum { MAXB = 12 };
typedef struct op_case op_case;
struct op_case {
    int nb;
    buf b[MAXB];
    int s[10];   // the op's sizes and flags, named per op
    float f;     // eps, rotation
    mlb_activation act;
    mlb_conv2d cv;
    mlb_hashgrid hg;
    mlb_adam_config adam;
    char shape[160];                              // for the messages
    void (*prep)(const op_case* c, float** h);    // derived inputs (a forward's statistics), on the host
};

static int add_buf(op_case* c, const char* name, size_t n, role r, float lo, float hi, bound_class cls) {
    c->b[c->nb] = (buf){name, n, r, lo, hi, cls};
    return c->nb++;
}
#define IN_(name, n, lo, hi) add_buf(c, name, n, IN, lo, hi, B_EXACT)
#define OUT_(name, n, cls) add_buf(c, name, n, OUT, 0, 0, cls)
#define ACC_(name, n, cls) add_buf(c, name, n, ACC, -1, 1, cls)
// an optional buffer: NULL when `null`
#define OPT_OUT(name, n, cls, null) add_buf(c, name, n, (null) ? NUL : OUT, 0, 0, cls)
#define OPT_ACC(name, n, cls, null) add_buf(c, name, n, (null) ? NUL : ACC, -1, 1, cls)
#define OPT_IN(name, n, lo, hi, null) add_buf(c, name, n, (null) ? NUL : IN, lo, hi, B_EXACT)

// ---- shapes ----
typedef struct {
    uint64_t seed, stream, i;
} draw;
static int pick(draw* d, int lo, int hi) {   // uniform in [lo, hi]
    int r = lo + (int)(mlb_rng_uniform_f64(d->seed, d->stream, d->i++) * (hi - lo + 1));
    return r > hi ? hi : r;
}
// 1 on trial 0; else half the time an awkward size (not a multiple of 8, 16 or 32), else any in [1, max]
static int dim(draw* d, int trial, int max) {
    static const int awkward[] = {1, 2, 3, 5, 7, 9, 13, 15, 17, 31, 33, 63, 65, 127, 129, 255, 257};
    if (trial == 0) return 1;
    if (pick(d, 0, 1)) {
        int k;
        do k = awkward[pick(d, 0, 16)]; while (k > max);
        return k;
    }
    return pick(d, 1, max);
}

// ---- memory ----
// alloc and release: a buffer of the table's own, in and out by copies (and one of 0 floats)
static void setup_alloc(op_case* c, draw* d, int t) {
    int n = dim(d, t, 5000);
    IN_("src", n, -1, 1);
    OUT_("dst", n, B_EXACT);
    snprintf(c->shape, sizeof c->shape, "n %d", n);
}
static mlb_status call_alloc(const mlb_backend* be, float** p, const op_case* c) {
    size_t n = c->b[0].n;
    float *q, *z;
    MLB_TRY(be->alloc(&z, 0));
    be->release(z);
    MLB_TRY(be->alloc(&q, n));
    mlb_status s = be->copy(q, p[0], n);
    if (s == MLB_OK) s = be->copy(p[1], q, n);
    be->release(q);
    return s;
}
#define setup_release setup_alloc
#define call_release call_alloc
// upload and download: a round trip through host memory
#define setup_upload setup_alloc
static mlb_status call_upload(const mlb_backend* be, float** p, const op_case* c) {
    size_t n = c->b[0].n;
    float* h = malloc(n * sizeof(float));
    if (!h) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    mlb_status s = be->download(h, p[0], n);
    if (s == MLB_OK) s = be->upload(p[1], h, n);
    free(h);
    return s;
}
#define setup_download setup_upload
#define call_download call_upload
static void setup_zero(op_case* c, draw* d, int t) {
    int n = dim(d, t, 5000);
    c->s[0] = pick(d, 0, n - 1);       // offset
    c->s[1] = pick(d, 0, n - c->s[0]);  // count (0 too)
    ACC_("p", n, B_EXACT);
    snprintf(c->shape, sizeof c->shape, "n %d at %d of %d", c->s[1], c->s[0], n);
}
static mlb_status call_zero(const mlb_backend* be, float** p, const op_case* c) {
    return be->zero(p[0] + c->s[0], c->s[1]);
}
static void setup_copy(op_case* c, draw* d, int t) {
    int n = dim(d, t, 5000);
    c->s[0] = pick(d, 0, n - 1);
    c->s[1] = pick(d, 0, n - c->s[0]);
    IN_("src", c->s[1] ? c->s[1] : 1, -1, 1);
    ACC_("dst", n, B_EXACT);
    snprintf(c->shape, sizeof c->shape, "n %d at %d of %d", c->s[1], c->s[0], n);
}
static mlb_status call_copy(const mlb_backend* be, float** p, const op_case* c) {
    return be->copy(p[1] + c->s[0], p[0], c->s[1]);
}
static void setup_copy_rows(op_case* c, draw* d, int t) {
    int rows = dim(d, t, 60), width = dim(d, t, 70);
    c->s[0] = rows, c->s[1] = width;
    c->s[2] = width + pick(d, 0, 5);   // spitch
    c->s[3] = width + pick(d, 0, 5);   // dpitch
    IN_("src", (size_t)rows * c->s[2], -1, 1);
    ACC_("dst", (size_t)rows * c->s[3], B_EXACT);
    snprintf(c->shape, sizeof c->shape, "%d rows of %d, pitches %d -> %d", rows, width, c->s[2], c->s[3]);
}
static mlb_status call_copy_rows(const mlb_backend* be, float** p, const op_case* c) {
    return be->copy_rows(p[1], c->s[3], p[0], c->s[2], c->s[1], c->s[0]);
}

// ---- linear and conv ----
static void setup_linear(op_case* c, draw* d, int t) {
    int B = dim(d, t, 70), C = dim(d, t, 130), OC = dim(d, t, 70);
    c->s[0] = B, c->s[1] = C, c->s[2] = OC;
    IN_("in", (size_t)B * C, -1, 1);
    IN_("w", (size_t)OC * C, -0.5f, 0.5f);
    OPT_IN("b", OC, -1, 1, t % 2);
    OUT_("out", (size_t)B * OC, B_GEMM);
    snprintf(c->shape, sizeof c->shape, "B %d C %d OC %d%s", B, C, OC, t % 2 ? " no bias" : "");
}
static mlb_status call_linear(const mlb_backend* be, float** p, const op_case* c) {
    return be->linear(be, p[3], p[0], p[1], p[2], c->s[0], c->s[1], c->s[2]);
}
static void setup_linear_backward(op_case* c, draw* d, int t) {
    int B = dim(d, t, 70), C = dim(d, t, 130), OC = dim(d, t, 70);
    c->s[0] = B, c->s[1] = C, c->s[2] = OC;
    OPT_ACC("din", (size_t)B * C, B_GEMM, t == 3);
    ACC_("dw", (size_t)OC * C, B_GEMM);
    OPT_ACC("db", OC, B_SUMS, t == 2);
    IN_("dout", (size_t)B * OC, -1, 1);
    IN_("in", (size_t)B * C, -1, 1);
    IN_("w", (size_t)OC * C, -0.5f, 0.5f);
    snprintf(c->shape, sizeof c->shape, "B %d C %d OC %d", B, C, OC);
}
static mlb_status call_linear_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->linear_backward(be, p[0], p[1], p[2], p[3], p[4], p[5], c->s[0], c->s[1], c->s[2]);
}
// A valid convolution: kernel 1, 2 or 3, stride 1 or 2, padding 0 or 1 per side (asymmetric too)
static mlb_conv2d draw_conv(draw* d, int t) {
    for (int tries = 0;; tries++) {
        int K = t == 0 ? 1 : pick(d, 1, 3);
        mlb_conv2d cv = mlb_conv2d_make(t ? pick(d, 1, 2) : 1, dim(d, t, 9), dim(d, t, 13), dim(d, t, 13),
                                        dim(d, t, 9), K, t ? pick(d, 1, 2) : 1, 0);
        if (t) cv.pad_top = pick(d, 0, 1), cv.pad_left = pick(d, 0, 1), cv.pad_bottom = pick(d, 0, 1),
               cv.pad_right = pick(d, 0, 1);
        if (mlb_conv2d_check(&cv) == MLB_OK || tries > 50) return cv;
    }
}
static void conv_shape(op_case* c) {
    const mlb_conv2d* v = &c->cv;
    snprintf(c->shape, sizeof c->shape, "N %d C %d %dx%d -> OC %d, %dx%d s%d pad %d,%d,%d,%d", v->N, v->C, v->H, v->W,
             v->OC, v->KH, v->KW, v->stride_h, v->pad_top, v->pad_left, v->pad_bottom, v->pad_right);
}
static size_t conv_out_n(const mlb_conv2d* v) {
    return (size_t)v->N * v->OC * mlb_conv2d_out_h(v) * mlb_conv2d_out_w(v);
}
static void setup_conv2d(op_case* c, draw* d, int t) {
    c->cv = draw_conv(d, t);
    const mlb_conv2d* v = &c->cv;
    IN_("in", (size_t)v->N * v->C * v->H * v->W, -1, 1);
    IN_("w", (size_t)v->OC * v->C * v->KH * v->KW, -0.3f, 0.3f);
    OPT_IN("b", v->OC, -1, 1, t % 2);
    OUT_("out", conv_out_n(v), B_GEMM);
    conv_shape(c);
}
static mlb_status call_conv2d(const mlb_backend* be, float** p, const op_case* c) {
    return be->conv2d(be, p[3], p[0], p[1], p[2], &c->cv);
}
static void setup_conv2d_backward(op_case* c, draw* d, int t) {
    c->cv = draw_conv(d, t);
    const mlb_conv2d* v = &c->cv;
    size_t nin = (size_t)v->N * v->C * v->H * v->W, nw = (size_t)v->OC * v->C * v->KH * v->KW;
    OPT_ACC("din", nin, B_GEMM, t == 3);
    ACC_("dw", nw, B_GEMM);
    OPT_ACC("db", v->OC, B_SUMS, t == 2);
    IN_("dout", conv_out_n(v), -1, 1);
    IN_("in", nin, -1, 1);
    IN_("w", nw, -0.3f, 0.3f);
    conv_shape(c);
}
static mlb_status call_conv2d_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->conv2d_backward(be, p[0], p[1], p[2], p[3], p[4], p[5], &c->cv);
}

// ---- norms ----
// groupnorm and its backward: s = N, C, HW, G
static void draw_groupnorm(op_case* c, draw* d, int t) {
    int N = dim(d, t, 3), G = t ? pick(d, 1, 4) : 1, C = G * dim(d, t, 9), HW = dim(d, t, 70);
    c->s[0] = N, c->s[1] = C, c->s[2] = HW, c->s[3] = G;
    c->f = 1e-5f;
    c->act = (mlb_activation)(t ? pick(d, 0, MLB_ACT_COUNT - 1) : MLB_ACT_SILU);
    snprintf(c->shape, sizeof c->shape, "N %d C %d HW %d G %d act %d", N, C, HW, G, (int)c->act);
}
static void setup_groupnorm(op_case* c, draw* d, int t) {
    draw_groupnorm(c, d, t);
    size_t n = (size_t)c->s[0] * c->s[1] * c->s[2], ng = (size_t)c->s[0] * c->s[3];
    OUT_("out", n, B_ELEM);
    OPT_OUT("mean", ng, B_ELEM, t == 2);
    OPT_OUT("rstd", ng, B_ELEM, t == 2);
    IN_("in", n, -2, 3);
    OPT_IN("w", c->s[1], 0.5f, 1.5f, t == 3);
    OPT_IN("b", c->s[1], -1, 1, t == 3);
}
static mlb_status call_groupnorm(const mlb_backend* be, float** p, const op_case* c) {
    return be->groupnorm(p[0], p[1], p[2], p[3], p[4], p[5], c->s[0], c->s[1], c->s[2], c->s[3], c->f, c->act);
}
static void prep_groupnorm_backward(const op_case* c, float** h) {   // mean, rstd of the forward
    float* y = malloc(c->b[4].n * sizeof(float));
    groupnorm_forward(y, h[7], h[8], h[4], h[5], h[6], c->s[0], c->s[1], c->s[2], c->s[3], c->f, c->act);
    free(y);
}
static void setup_groupnorm_backward(op_case* c, draw* d, int t) {
    draw_groupnorm(c, d, t);
    size_t n = (size_t)c->s[0] * c->s[1] * c->s[2], ng = (size_t)c->s[0] * c->s[3];
    OPT_ACC("din", n, B_SUMS, t == 3);
    OPT_ACC("dw", c->s[1], B_SUMS, t == 2);
    OPT_ACC("db", c->s[1], B_SUMS, t == 2);
    IN_("dout", n, -1, 1);
    IN_("in", n, -2, 3);
    IN_("w", c->s[1], 0.5f, 1.5f);
    IN_("b", c->s[1], -1, 1);
    IN_("mean", ng, 0, 0);
    IN_("rstd", ng, 0, 0);
    c->prep = prep_groupnorm_backward;
}
static mlb_status call_groupnorm_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->groupnorm_backward(p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], c->s[0], c->s[1], c->s[2],
                                  c->s[3], c->act);
}
// layer norms: s = N, C
static void draw_layernorm(op_case* c, draw* d, int t) {
    c->s[0] = dim(d, t, 70), c->s[1] = dim(d, t, 300), c->f = 1e-5f;
    snprintf(c->shape, sizeof c->shape, "N %d C %d", c->s[0], c->s[1]);
}
static void setup_layernorm(op_case* c, draw* d, int t) {
    draw_layernorm(c, d, t);
    size_t n = (size_t)c->s[0] * c->s[1];
    OUT_("out", n, B_ELEM);
    IN_("in", n, -2, 3);
    IN_("w", c->s[1], 0.5f, 1.5f);
    IN_("b", c->s[1], -1, 1);
}
static mlb_status call_layernorm(const mlb_backend* be, float** p, const op_case* c) {
    return be->layernorm(p[0], p[1], p[2], p[3], c->s[0], c->s[1], c->f);
}
static void setup_layernorm_stats(op_case* c, draw* d, int t) {
    draw_layernorm(c, d, t);
    size_t n = (size_t)c->s[0] * c->s[1];
    OUT_("out", n, B_ELEM);
    OPT_OUT("mean", c->s[0], B_ELEM, t == 2);
    OPT_OUT("rstd", c->s[0], B_ELEM, t == 3);
    IN_("in", n, -2, 3);
    IN_("w", c->s[1], 0.5f, 1.5f);
    IN_("b", c->s[1], -1, 1);
}
static mlb_status call_layernorm_stats(const mlb_backend* be, float** p, const op_case* c) {
    return be->layernorm_stats(p[0], p[1], p[2], p[3], p[4], p[5], c->s[0], c->s[1], c->f);
}
static void prep_layernorm_backward(const op_case* c, float** h) {
    float* y = malloc(c->b[4].n * sizeof(float));
    layernorm_forward(y, h[6], h[7], h[4], h[5], NULL, c->s[0], c->s[1], c->f);
    free(y);
}
static void setup_layernorm_backward(op_case* c, draw* d, int t) {
    draw_layernorm(c, d, t);
    size_t n = (size_t)c->s[0] * c->s[1];
    OPT_ACC("din", n, B_SUMS, t == 3);
    OPT_ACC("dw", c->s[1], B_SUMS, t == 2);
    OPT_ACC("db", c->s[1], B_SUMS, t == 2);
    IN_("dout", n, -1, 1);
    IN_("in", n, -2, 3);
    IN_("w", c->s[1], 0.5f, 1.5f);
    IN_("mean", c->s[0], 0, 0);
    IN_("rstd", c->s[0], 0, 0);
    c->prep = prep_layernorm_backward;
}
static mlb_status call_layernorm_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->layernorm_backward(p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], c->s[0], c->s[1]);
}

// ---- attention: s = B, Tq, Tk, C, NH, ldq, ldkv ----
// (one key, Tk = 1, makes dq and dk exactly zero: each side's rounding noise is then judged
// against the floor of test_backend_ops.c's error)
static void draw_sdpa(op_case* c, draw* d, int t) {
    int B = t ? pick(d, 1, 2) : 1, NH = t ? pick(d, 1, 3) : 1, hd = dim(d, t, 40), C = NH * hd;
    int Tq = dim(d, t, 70), Tk = dim(d, t, 70);
    if (t == 3) hd = 72, C = NH * hd;   // wider than the 64 of the SD heads
    int ldq = C + (t ? pick(d, 0, 3) : 0), ldkv = C + (t ? pick(d, 0, 3) : 0);
    int* s = c->s;
    s[0] = B, s[1] = Tq, s[2] = Tk, s[3] = C, s[4] = NH, s[5] = ldq, s[6] = ldkv;
    snprintf(c->shape, sizeof c->shape, "B %d Tq %d Tk %d C %d NH %d ldq %d ldkv %d", B, Tq, Tk, C, NH, ldq, ldkv);
}
static void setup_sdpa(op_case* c, draw* d, int t) {
    draw_sdpa(c, d, t);
    const int* s = c->s;
    IN_("q", (size_t)s[0] * s[1] * s[5], -1, 1);
    IN_("k", (size_t)s[0] * s[2] * s[6], -1, 1);
    IN_("v", (size_t)s[0] * s[2] * s[6], -1, 1);
    OUT_("out", (size_t)s[0] * s[1] * s[3], B_GEMM);
    OPT_OUT("lse", (size_t)s[0] * s[4] * s[1], B_GEMM, t == 2);
}
static mlb_status call_sdpa(const mlb_backend* be, float** p, const op_case* c) {
    const int* s = c->s;
    return be->sdpa(be, p[3], p[4], p[0], p[1], p[2], s[0], s[1], s[2], s[3], s[4], s[5], s[6]);
}
static void prep_sdpa_backward(const op_case* c, float** h) {   // out and lse of the forward
    const int* s = c->s;
    sdpa_forward(h[4], h[5], h[6], h[7], h[8], s[0], s[1], s[2], s[3], s[4], s[5], s[6], NULL);
}
static void setup_sdpa_backward(op_case* c, draw* d, int t) {
    draw_sdpa(c, d, t);
    const int* s = c->s;
    size_t nq = (size_t)s[0] * s[1] * s[5], nkv = (size_t)s[0] * s[2] * s[6], no = (size_t)s[0] * s[1] * s[3];
    OPT_ACC("dq", nq, B_GEMM3, t == 2);
    ACC_("dk", nkv, B_GEMM3);
    OPT_ACC("dv", nkv, B_GEMM3, t == 3);
    IN_("dout", no, -1, 1);
    IN_("out", no, 0, 0);
    IN_("lse", (size_t)s[0] * s[4] * s[1], 0, 0);
    IN_("q", nq, -1, 1);
    IN_("k", nkv, -1, 1);
    IN_("v", nkv, -1, 1);
    c->prep = prep_sdpa_backward;
}
static mlb_status call_sdpa_backward(const mlb_backend* be, float** p, const op_case* c) {
    const int* s = c->s;
    return be->sdpa_backward(be, p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], s[0], s[1], s[2], s[3], s[4],
                             s[5], s[6]);
}

// ---- self-attention with the causal mask (the text encoder's): s = B, T, C, NH, ld, causal, fused ----
// Fused trials read q, k and v from one [B, T, ld >= 3C] buffer at offsets 0, C, 2C (the encoder's
// qkv), the others from three [B, T, ld >= C] buffers. Causal on all trials but 2; several heads
// from trial 1 on. CUDA's online softmax sums in another order than the CPU's rows (B_SUMS).
static void setup_attention(op_case* c, draw* d, int t) {
    int B = t ? pick(d, 1, 3) : 1, NH = t ? pick(d, 2, 4) : 1, hd = dim(d, t, 40), C = NH * hd, T = dim(d, t, 80);
    int causal = t != 2, fused = t % 2 == 1, ld = (fused ? 3 * C : C) + (t ? pick(d, 0, 3) : 0);
    int* s = c->s;
    s[0] = B, s[1] = T, s[2] = C, s[3] = NH, s[4] = ld, s[5] = causal, s[6] = fused;
    size_t nt = (size_t)B * T;
    OUT_("out", nt * C, B_SUMS);
    if (fused) {
        IN_("qkv", nt * ld, -1.5f, 1.5f);
    } else {
        IN_("q", nt * ld, -1.5f, 1.5f);
        IN_("k", nt * ld, -1.5f, 1.5f);
        IN_("v", nt * ld, -1, 1);
    }
    snprintf(c->shape, sizeof c->shape, "B %d T %d C %d NH %d ld %d%s%s", B, T, C, NH, ld, causal ? " causal" : "",
             fused ? " fused" : "");
}
static mlb_status call_attention(const mlb_backend* be, float** p, const op_case* c) {
    const int* s = c->s;
    const float *q = p[1], *k = s[6] ? p[1] + s[2] : p[2], *v = s[6] ? p[1] + 2 * s[2] : p[3];
    return be->attention(p[0], q, k, v, s[4], s[0], s[1], s[2], s[3], s[5]);
}

// ---- token + position embedding: s = B, T, C, V; tokens an int32 buffer drawn in [0, V) ----
static void prep_embedding(const op_case* c, float** h) {
    for (size_t i = 0; i < c->b[1].n; i++) {
        int32_t id = (int32_t)h[1][i];
        if (id >= c->s[3]) id = c->s[3] - 1;
        memcpy(&h[1][i], &id, sizeof id);
    }
}
static void setup_embedding(op_case* c, draw* d, int t) {
    int B = dim(d, t, 3), T = dim(d, t, 80), C = dim(d, t, 100), V = dim(d, t, 300);
    int* s = c->s;
    s[0] = B, s[1] = T, s[2] = C, s[3] = V;
    OUT_("out", (size_t)B * T * C, B_EXACT);
    IN_("tokens", (size_t)B * T, 0, (float)V);
    IN_("wte", (size_t)V * C, -1, 1);
    OPT_IN("wpe", (size_t)(T + 2) * C, -1, 1, t == 2);   // more positions than T, as CLIP's 77
    c->prep = prep_embedding;
    snprintf(c->shape, sizeof c->shape, "B %d T %d C %d V %d%s", B, T, C, V, t == 2 ? " no wpe" : "");
}
static mlb_status call_embedding(const mlb_backend* be, float** p, const op_case* c) {
    const int* s = c->s;
    return be->embedding(p[0], (const int32_t*)p[1], p[2], p[3], s[0], s[1], s[2], s[3]);
}

#endif
