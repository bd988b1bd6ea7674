// Every op of every backend table (include/matlaber/backend_ops.def) against the CPU fp32 table on
// the same random inputs. The op loop is generated from the op list, so a new op does not build
// here until it has its case (tests/backend_op_cases*.h: a shape generator and a call).
// Tables: the CPU fp32 table (the reference against itself: every CPU op once, NULL outputs and
// ragged shapes included, which the sanitizer build checks), the CPU bf16 and bf16-stored tables,
// and with a GPU the CUDA tables at fp32, tf32, fp16 and bf16 (without one that case skips;
// scripts/gpu-parity.sh runs this test on a GPU). Each op runs on MLB_OPS_TRIALS shapes (default
// 4): trial 0 with every size 1, then random ragged ones (1, primes, 2^k +- 1 or anything up to a
// cap: never only multiples of 8, 16 or 32); optional outputs are NULL on some trials. The seed is
// $MLB_TEST_SEED (default 1), printed. The attention op is also checked against a naive double
// attention on every table (cpu_/cuda_attention_vs_double). The CPU's double table (backend_f64.h):
// every field set, its attention against the naive one, its DMTet grid ops against dmtet.h's double
// host functions bit for bit (cpu_f64_table, cpu_f64_grid_ops).
//
// Compared: the relative L2 error ||got - ref|| / max(||ref||, 0.5 sqrt(n)) of each output (of
// accumulated outputs, the increments over their random start, so the bound speaks of the gradient
// itself); a value finite on one side only fails. The floor: the inputs are O(1) (uniform within
// +-1 or so), so a term of a sum is about 0.5; where an output cancels to near 0 (a one-element
// product plus a bias, the attention backward over two keys at head width 1) its rounding is
// judged against that scale instead of against the cancelled result. Large outputs (RMS > 0.5)
// are measured purely relatively. Bounds:
//   CPU tables: every op but a GEMM is the fp32 table's own function: 0 (bitwise). GEMM outputs
//     (linear, conv2d, sdpa and their backwards but the bias gradients, summed in double): bf16
//     operands, u = 2^-8: 2e-2, the attention backward 3e-2 (three products chained through bf16
//     copies of P and dS). On a CPU with AVX-512 BF16 also at least 1e-6 over an op's trials: it
//     is bf16 and not the fp32 op in the wrong slot.
//   CUDA tables (the bounds of the parity tests test_cuda_*):
//     copies, adds, the transpose, the upsample: 0 (one thread per value, the CPU's float ops)
//     elementwise with libm functions (fill_normal's log and cos in double), the norms, the
//       upsample's block sums: 1e-5 (CUDA's libm
//       within 2 ulp of glibc's; statistics in double on both sides)
//     sums in another order (hash grid, AdamW, bias gradients, add_channel's backward): 1e-5
//     shading 1e-4, its gradients 1e-3 (float on the GPU, double on the CPU: test_cuda_shade)
//     GEMM outputs by precision: fp32 1e-5, tf32 and fp16 3e-3, bf16 2e-2 (attention backward 3e-2)
//     the causal self-attention (fp32 at every precision, an online softmax): 1e-5; the embedding 0
//     the rasterizer (src/cuda/raster.cu runs the CPU's maths without fused multiply-adds): face
//       ids bit for bit (B_BITS, the share of differing ids), barycentrics, depth, interpolated
//       values and the barycentric gradient 0; the gradients summed over pixels (dclip, dattr) 1e-5.
//       Not yet run on a GPU (docs/cuda.md).
//     the surface's clip coordinates and vertex normals (raster_math.h's transform in double,
//       mesh/vertex_normals_math.h's gathers in face order, no fused multiply-adds): vertex lists
//       bit for bit (B_BITS), clip, normals, sums and both gradients 0. Not yet run on a GPU.
//     marching tets (src/cuda/marching_tets.cu, the CPU's maths without fused multiply-adds, the
//       backward gathered in the CPU's order): counts, scans, vertex edges and faces bit for bit
//       (B_BITS), vertices, weights and both gradients 0. Not yet run on a GPU.
#include "backend_op_cases.h"
#include <string.h>
#include "matlaber/backend_f64.h"
#include "matlaber/dmtet.h"
#include "matlaber/rng.h"
#include "backend_op_cases_glue.h"
#include "backend_op_cases_raster.h"
#include "backend_op_cases_mt.h"
#include "backend_op_cases_samples.h"
#include "backend_op_cases_surface.h"

typedef struct {
    const char* name;
    void (*setup)(op_case* c, draw* d, int trial);
    mlb_status (*call)(const mlb_backend* be, float** p, const op_case* c);
} op_test;
static const op_test op_tests[] = {
#define MLB_OP(name, cuda_fn, params) {#name, setup_##name, call_##name},
#define MLB_GEMM_OP(name, cuda_fn, params, args) {#name, setup_##name, call_##name},
#define MLB_DEVICE_OP(ret, name, params) {#name, setup_##name, call_##name},
#include "matlaber/backend_ops.def"
};
enum { N_OPS = sizeof op_tests / sizeof op_tests[0] };

static const char* prec_name[] = {"fp32", "tf32", "fp16", "bf16"};

static double bound(const mlb_backend* be, bound_class cls) {
    static const double gemm[] = {1e-5, 3e-3, 3e-3, 2e-2}, gemm3[] = {1e-5, 3e-3, 3e-3, 3e-2};
    if (cls == B_GEMM) return gemm[be->precision];
    if (cls == B_GEMM3) return gemm3[be->precision];
    if (be->device == MLB_DEVICE_CPU) return 0;
    switch (cls) {
    case B_ELEM: case B_SUMS: return 1e-5;
    case B_SHADE: return 1e-4;
    case B_SHADE_GRAD: return 1e-3;
    default: return 0;
    }
}

// Relative L2 error of got against ref (of their increments over start, when given), floored as
// the header says; *bad counts values finite on one side only (a NaN on both: an output neither
// side writes, as the poison).
#define TERM_SCALE 0.5
static double rel_l2(const float* got, const float* ref, const float* start, size_t n, size_t* bad) {
    double num = 0, den = 0;
    size_t m = 0;
    *bad = 0;
    for (size_t i = 0; i < n; i++) {
        double g = got[i], r = ref[i];
        if (!isfinite(g) || !isfinite(r)) { *bad += !isfinite(g) != !isfinite(r); continue; }
        if (start) g -= start[i], r -= start[i];
        num += (g - r) * (g - r);
        den += r * r;
        m++;
    }
    double floor2 = TERM_SCALE * TERM_SCALE * (double)m;
    return m ? sqrt(num / (den > floor2 ? den : floor2)) : 0;
}

// The worst of one op's trials on one table
typedef struct {
    double err, bound, ratio;   // the output with the largest err / bound (err when the bound is 0)
    double gemm_max;            // the largest error of a GEMM output
    char what[200];
    int has_gemm;
} worst;

// One trial of one op on table be: the inputs drawn, the reference run on the CPU fp32 table, the
// same call on be's buffers, every output compared.
static void run_trial(const mlb_backend* be, const char* table, int oi, int trial, uint64_t seed, worst* w) {
    const op_test* op = &op_tests[oi];
    op_case c;
    memset(&c, 0, sizeof c);
    draw d = {seed, 1000 + 100 * (uint64_t)oi + trial, 0};
    op->setup(&c, &d, trial);
    float *h[MAXB] = {0}, *r[MAXB] = {0}, *g[MAXB] = {0}, *dev[MAXB] = {0};
    int ok = 1;
    for (int i = 0; i < c.nb; i++) {
        const buf* b = &c.b[i];
        if (b->r == NUL) continue;
        h[i] = host_alloc(b->n), r[i] = host_alloc(b->n), g[i] = host_alloc(b->n);
        if (!h[i] || !r[i] || !g[i]) { ok = 0; continue; }
        if (b->r == OUT)
            for (size_t k = 0; k < b->n; k++) h[i][k] = NAN;
        else
            fill_uniform(h[i], b->n, seed, ((uint64_t)oi << 16) | ((uint64_t)trial << 8) | (uint64_t)i, b->lo, b->hi);
    }
    REQUIRE(ok);
    if (c.prep) c.prep(&c, h);
    for (int i = 0; i < c.nb; i++)
        if (h[i]) memcpy(r[i], h[i], c.b[i].n * sizeof(float));
    mlb_status st = op->call(mlb_backend_cpu(), r, &c);
    CHECK_MSG(st == MLB_OK, "%s reference on %s: %s", op->name, c.shape, mlb_last_error());
    for (int i = 0; i < c.nb && ok; i++)
        if (h[i] && (be->alloc(&dev[i], c.b[i].n) != MLB_OK || be->upload(dev[i], h[i], c.b[i].n) != MLB_OK)) ok = 0;
    if (ok) {
        st = op->call(be, dev, &c);
        CHECK_MSG(st == MLB_OK, "%s %s on %s: %s", table, op->name, c.shape, mlb_last_error());
        ok = st == MLB_OK;
    } else {
        CHECK_MSG(0, "%s %s: buffers on the device: %s", table, op->name, mlb_last_error());
    }
    for (int i = 0; i < c.nb && ok; i++)
        if (h[i] && be->download(g[i], dev[i], c.b[i].n) != MLB_OK) {
            CHECK_MSG(0, "%s %s: download: %s", table, op->name, mlb_last_error());
            ok = 0;
        }
    for (int i = 0; i < c.nb && ok; i++) {
        const buf* b = &c.b[i];
        if (b->r != OUT && b->r != ACC) continue;
        size_t bad = 0;
        double err, bd = bound(be, b->cls);
        if (b->cls == B_BITS) {   // int32 values: the share of them that differ
            size_t diff = 0;
            for (size_t k = 0; k < b->n; k++) diff += memcmp(g[i] + k, r[i] + k, sizeof(float)) != 0;
            err = b->n ? (double)diff / (double)b->n : 0;
        } else {
            err = rel_l2(g[i], r[i], b->r == ACC ? h[i] : NULL, b->n, &bad);
        }
        CHECK_MSG(bad == 0, "%s %s %s on %s: %zu values finite on one side only", table, op->name, b->name, c.shape,
                  bad);
        CHECK_MSG(err <= bd, "%s %s %s on %s: relative L2 error %.3e over %.0e", table, op->name, b->name, c.shape,
                  err, bd);
        double ratio = bd > 0 ? err / bd : err > 0 ? INFINITY : 0;
        if (ratio >= w->ratio) {
            w->err = err, w->bound = bd, w->ratio = ratio;
            snprintf(w->what, sizeof w->what, "%s on %s", b->name, c.shape);
        }
        if (b->cls == B_GEMM || b->cls == B_GEMM3) {
            w->has_gemm = 1;
            if (err > w->gemm_max) w->gemm_max = err;
        }
    }
    for (int i = 0; i < c.nb; i++) {
        if (dev[i]) be->release(dev[i]);
        free(h[i]), free(r[i]), free(g[i]);
    }
}

static int n_trials(void) {
    const char* s = getenv("MLB_OPS_TRIALS");
    int n = s && *s ? atoi(s) : 4;
    return n < 1 ? 1 : n;
}

static void check_table(const mlb_backend* be, const char* table) {
    uint64_t seed = test_seed();
    int trials = n_trials();
    // bf16 for real: the CPU's bf16 kernels when it has AVX-512 BF16 (else they are fp32)
    int bf16_cpu = be->device == MLB_DEVICE_CPU && be->precision == MLB_GEMM_BF16 && mlb_gemm_bf16_native();
    for (int oi = 0; oi < N_OPS; oi++) {
        worst w = {0, 0, -1, 0, "", 0};
        for (int t = 0; t < trials; t++) run_trial(be, table, oi, t, seed, &w);
        printf("  %-9s %-28s rel-L2 %.2e  bound %.0e  worst: %s\n", table, op_tests[oi].name, w.err, w.bound, w.what);
        if (bf16_cpu && w.has_gemm)
            CHECK_MSG(w.gemm_max >= 1e-6, "%s %s: error %.1e of the fp32 result: not bf16", table, op_tests[oi].name,
                      w.gemm_max);
    }
}

// Every field of every table set, from the list, and each table's device and precision.
static void check_complete(const mlb_backend* be, mlb_device dev, mlb_gemm_precision p, const char* t) {
    CHECK_MSG(be->device == dev && be->precision == p, "%s: device %d precision %d", t, be->device, be->precision);
#define MLB_OP(name, cuda_fn, params) CHECK_MSG(be->name != NULL, "%s: %s is NULL", t, #name);
#define MLB_GEMM_OP(name, cuda_fn, params, args) CHECK_MSG(be->name != NULL, "%s: %s is NULL", t, #name);
#define MLB_DEVICE_OP(ret, name, params) CHECK_MSG(be->name != NULL, "%s: %s is NULL", t, #name);
#include "matlaber/backend_ops.def"
}

TEST(tables_complete) {
    check_complete(mlb_backend_cpu(), MLB_DEVICE_CPU, MLB_GEMM_FP32, "cpu fp32");
    check_complete(mlb_backend_for(MLB_DEVICE_CPU, MLB_GEMM_BF16), MLB_DEVICE_CPU, MLB_GEMM_BF16, "cpu bf16");
    check_complete(mlb_backend_cpu_bf16_stored(), MLB_DEVICE_CPU, MLB_GEMM_BF16, "cpu bf16 stored");
    for (int p = MLB_GEMM_FP32; p <= MLB_GEMM_BF16; p++)
        check_complete(mlb_backend_for(MLB_DEVICE_CUDA, (mlb_gemm_precision)p), MLB_DEVICE_CUDA, (mlb_gemm_precision)p,
                       prec_name[p]);
    printf("  %d ops in each of 7 tables\n", (int)N_OPS);
}

TEST(cpu_fp32_table) { check_table(mlb_backend_cpu(), "cpu fp32"); }
TEST(cpu_bf16_table) { check_table(mlb_backend_for(MLB_DEVICE_CPU, MLB_GEMM_BF16), "cpu bf16"); }

// The bf16-stored table: the bf16 table's ops but the linear and conv GEMMs, which read weights
// packed at load (their results the bf16 table's bit for bit) and have no backward.
TEST(cpu_bf16_stored_table) {
    const mlb_backend *st = mlb_backend_cpu_bf16_stored(), *bf = mlb_backend_for(MLB_DEVICE_CPU, MLB_GEMM_BF16);
#define MLB_OP(name, cuda_fn, params) CHECK_MSG(st->name == bf->name, "%s is not the bf16 table's", #name);
#define MLB_DEVICE_OP(ret, name, params) CHECK_MSG(st->name == bf->name, "%s is not the bf16 table's", #name);
#include "matlaber/backend_ops.def"
    CHECK(st->sdpa == bf->sdpa && st->sdpa_backward == bf->sdpa_backward);
    float x[4] = {0}, gw[4] = {0};
    mlb_conv2d cv = mlb_conv2d_make(1, 1, 2, 2, 1, 1, 1, 0);
    CHECK(st->linear_backward(st, x, gw, NULL, x, x, x, 1, 2, 2) == MLB_ERR_UNSUPPORTED);
    CHECK(st->conv2d_backward(st, x, gw, NULL, x, x, x, &cv) == MLB_ERR_UNSUPPORTED);
    if (!mlb_bf16_packing_available()) SKIP("no AVX-512 BF16 here: no packed weights");
    uint64_t seed = test_seed();
    for (int t = 0; t < n_trials(); t++) {
        draw d = {seed, 99, (uint64_t)t * 64};
        int B = dim(&d, t, 70), C = dim(&d, t, 130), OC = dim(&d, t, 70);
        float *in = host_alloc((size_t)B * C), *w = host_alloc((size_t)OC * C), *b = host_alloc(OC);
        float *o1 = host_alloc((size_t)B * OC), *o2 = host_alloc((size_t)B * OC);
        uint32_t* pw = calloc(mlb_bf16_linear_weight_words(OC, C) + 1, sizeof(uint32_t));
        REQUIRE(in && w && b && o1 && o2 && pw);
        fill_uniform(in, (size_t)B * C, seed, 1, -1, 1), fill_uniform(w, (size_t)OC * C, seed, 2, -0.5f, 0.5f);
        fill_uniform(b, OC, seed, 3, -1, 1);
        CHECK(mlb_bf16_pack_linear_weight(pw, w, OC, C));
        CHECK(bf->linear(bf, o1, in, w, b, B, C, OC) == MLB_OK);
        CHECK(st->linear(st, o2, in, (const float*)pw, b, B, C, OC) == MLB_OK);
        CHECK_MSG(!memcmp(o1, o2, (size_t)B * OC * sizeof(float)), "linear B %d C %d OC %d: not the bf16 table's bits",
                  B, C, OC);
        free(in), free(w), free(b), free(o1), free(o2), free(pw);

        mlb_conv2d v = draw_conv(&d, t);
        size_t ni = (size_t)v.N * v.C * v.H * v.W, K = (size_t)v.C * v.KH * v.KW, no = conv_out_n(&v);
        in = host_alloc(ni), w = host_alloc(v.OC * K), b = host_alloc(v.OC), o1 = host_alloc(no), o2 = host_alloc(no);
        pw = calloc(mlb_bf16_conv_weight_words(v.OC, (int)K) + 1, sizeof(uint32_t));
        REQUIRE(in && w && b && o1 && o2 && pw);
        fill_uniform(in, ni, seed, 4, -1, 1), fill_uniform(w, v.OC * K, seed, 5, -0.3f, 0.3f);
        fill_uniform(b, v.OC, seed, 6, -1, 1);
        CHECK(mlb_bf16_pack_conv_weight(pw, w, v.OC, (int)K));
        CHECK(bf->conv2d(bf, o1, in, w, b, &v) == MLB_OK);
        CHECK(st->conv2d(st, o2, in, (const float*)pw, b, &v) == MLB_OK);
        CHECK_MSG(!memcmp(o1, o2, no * sizeof(float)), "conv2d N %d C %d OC %d %dx%d: not the bf16 table's bits", v.N,
                  v.C, v.OC, v.H, v.W);
        free(in), free(w), free(b), free(o1), free(o2), free(pw);
    }
    printf("  packed linear and conv2d: the bf16 table's bits on %d shapes each\n", n_trials());
}

// The attention op of every table against a naive double attention written here (the op loop
// above compares tables with the CPU fp32 one, which cannot catch that op being wrong itself):
// ragged T, several heads, fused and separate q/k/v, causal and not. The scores are O(1), so a
// float result is within a few 1e-7 of the double one; 1e-5 bounds every table (all fp32).
static void naive_attention(double* out, const float* q, const float* k, const float* v, int ld, int B, int T, int C,
                            int NH, int causal) {
    int hd = C / NH;
    double* p = malloc((size_t)T * sizeof(double));
    for (int b = 0; b < B; b++)
        for (int h = 0; h < NH; h++)
            for (int t = 0; t < T; t++) {
                const float* qt = q + ((size_t)b * T + t) * ld + (size_t)h * hd;
                int n = causal ? t + 1 : T;
                double mx = -INFINITY, sum = 0;
                for (int s = 0; s < n; s++) {
                    const float* ks = k + ((size_t)b * T + s) * ld + (size_t)h * hd;
                    double dot = 0;
                    for (int i = 0; i < hd; i++) dot += (double)qt[i] * ks[i];
                    p[s] = dot / sqrt((double)hd);
                    if (p[s] > mx) mx = p[s];
                }
                for (int s = 0; s < n; s++) sum += p[s] = exp(p[s] - mx);
                double* o = out + ((size_t)b * T + t) * C + (size_t)h * hd;
                for (int i = 0; i < hd; i++) {
                    double a = 0;
                    for (int s = 0; s < n; s++) a += p[s] / sum * v[((size_t)b * T + s) * ld + (size_t)h * hd + i];
                    o[i] = a;
                }
            }
    free(p);
}

static void attention_vs_double(const mlb_backend* be, const char* table) {
    static const struct { int B, T, NH, hd, fused, causal; } cases[] = {
        {2, 13, 3, 5, 1, 1}, {1, 77, 4, 16, 1, 1}, {3, 1, 2, 3, 0, 1}, {2, 33, 5, 7, 0, 1}, {1, 29, 3, 9, 1, 0},
    };
    uint64_t seed = test_seed();
    for (int ci = 0; ci < (int)(sizeof cases / sizeof cases[0]); ci++) {
        int B = cases[ci].B, T = cases[ci].T, NH = cases[ci].NH, C = NH * cases[ci].hd, causal = cases[ci].causal;
        int fused = cases[ci].fused, ld = (fused ? 3 * C : C) + 1;
        size_t nin = (size_t)B * T * ld, nout = (size_t)B * T * C;
        float *hq = host_alloc(fused ? nin : 3 * nin), *got = host_alloc(nout), *dq = NULL, *dout = NULL;
        double* ref = malloc(nout * sizeof(double));
        REQUIRE(hq && got && ref);
        fill_uniform(hq, fused ? nin : 3 * nin, seed, 500 + ci, -1.5f, 1.5f);
        const float *q = hq, *k = fused ? hq + C : hq + nin, *v = fused ? hq + 2 * C : hq + 2 * nin;
        naive_attention(ref, q, k, v, ld, B, T, C, NH, causal);
        size_t nbuf = fused ? nin : 3 * nin;
        REQUIRE(be->alloc(&dq, nbuf) == MLB_OK && be->alloc(&dout, nout) == MLB_OK);
        REQUIRE(be->upload(dq, hq, nbuf) == MLB_OK);
        CHECK(be->attention(dout, dq, dq + (k - hq), dq + (v - hq), ld, B, T, C, NH, causal) == MLB_OK);
        REQUIRE(be->download(got, dout, nout) == MLB_OK);
        double e = 0;
        for (size_t i = 0; i < nout; i++) {
            double d = fabs(got[i] - ref[i]);
            if (!(d <= e)) e = d;   // a NaN stays
        }
        CHECK_MSG(e <= 1e-5, "%s attention B %d T %d C %d NH %d%s%s: max abs error %.3e vs double", table, B, T, C, NH,
                  causal ? " causal" : "", fused ? " fused" : "", e);
        printf("  %-9s attention B %d T %2d C %2d NH %d%-7s%-6s max abs vs double %.2e\n", table, B, T, C, NH,
               causal ? " causal" : "", fused ? " fused" : "", e);
        be->release(dq), be->release(dout);
        free(hq), free(got), free(ref);
    }
}

TEST(cpu_attention_vs_double) {
    attention_vs_double(mlb_backend_cpu(), "cpu fp32");
    attention_vs_double(mlb_backend_for(MLB_DEVICE_CPU, MLB_GEMM_BF16), "cpu bf16");
}
TEST(cuda_attention_vs_double) {
    REQUIRE_GPU();
    for (int p = MLB_GEMM_FP32; p <= MLB_GEMM_BF16; p++) {
        char name[16];
        snprintf(name, sizeof name, "cuda %s", prec_name[p]);
        attention_vs_double(mlb_backend_for(MLB_DEVICE_CUDA, (mlb_gemm_precision)p), name);
    }
}

// The CPU's double table (backend_f64.h): every field set, its attention against the naive one in
// double (the same sums in another order: within 1e-12 for O(1) scores), and an op of the list
// without a double implementation failing as unsupported, not crashing.
TEST(cpu_f64_table) {
    const mlb_backend_f64* be = mlb_backend_cpu_f64();
    CHECK(be->device == MLB_DEVICE_CPU && mlb_backend_for_f64(MLB_DEVICE_CPU, MLB_GEMM_BF16) == be);
    CHECK(mlb_backend_for_f64(MLB_DEVICE_CUDA, MLB_GEMM_FP32) == NULL);
#define MLB_OP(name, cuda_fn, params) CHECK_MSG(be->name != NULL, "f64: %s is NULL", #name);
#define MLB_GEMM_OP(name, cuda_fn, params, args) CHECK_MSG(be->name != NULL, "f64: %s is NULL", #name);
#define MLB_DEVICE_OP(ret, name, params) CHECK_MSG(be->name != NULL, "f64: %s is NULL", #name);
#include "matlaber/backend_ops.def"
    enum { B = 2, T = 13, NH = 3, C = 15, LD = 3 * C + 1 };
    size_t nin = (size_t)B * T * LD, nout = (size_t)B * T * C;
    float* hq = host_alloc(nin);
    double *q = NULL, *out = NULL, *ref = malloc(nout * sizeof(double));
    REQUIRE(hq && ref && be->alloc(&q, nin) == MLB_OK && be->alloc(&out, nout) == MLB_OK);
    fill_uniform(hq, nin, test_seed(), 600, -1.5f, 1.5f);
    for (size_t i = 0; i < nin; i++) q[i] = hq[i];
    naive_attention(ref, hq, hq + C, hq + 2 * C, LD, B, T, C, NH, 1);
    CHECK(be->attention(out, q, q + C, q + 2 * C, LD, B, T, C, NH, 1) == MLB_OK);
    double e = 0;
    for (size_t i = 0; i < nout; i++) {
        double d = fabs(out[i] - ref[i]);
        if (!(d <= e)) e = d;
    }
    CHECK_MSG(e <= 1e-12, "f64 attention: max abs error %.3e vs the naive double one", e);
    printf("  f64 table: %d ops, attention max abs vs naive double %.2e\n", (int)N_OPS, e);
    CHECK(be->fill_normal(out, 4, 1, 2, 3) == MLB_ERR_UNSUPPORTED);
    CHECK_MSG(strstr(mlb_last_error(), "fill_normal") != NULL, "f64: the stub's message: %s", mlb_last_error());
    mlb_clear_error();
    be->release(q), be->release(out);
    free(hq), free(ref);
}

// The double table's DMTet grid ops (the deformation, the SDF regulariser, marching tets' count and
// emit around the table's scans, the backward) against dmtet.h's host functions in double, which
// they wrap: the same bits, on grids of 4 and 7 cells (an odd and an even vertex count), gradients
// added onto random values, either marching-tets gradient NULL; a grid size out of range fails as
// an argument error.
static double* dalloc(size_t n) { return malloc((n ? n : 1) * sizeof(double)); }
static void dnormal(double* x, size_t n, uint64_t stream) {
    for (size_t i = 0; i < n; i++) x[i] = mlb_rng_normal_f64(test_seed(), stream, i);
}
TEST(cpu_f64_grid_ops) {
    const mlb_backend_f64* be = mlb_backend_cpu_f64();
    for (int cells = 4; cells <= 7; cells += 3) {
        mlb_tetgrid g;
        REQUIRE(mlb_tetgrid_create(&g, cells, 1.0f) == MLB_OK);
        const int V = g.n_verts, T = g.n_tets;
        const size_t S = 7 * (size_t)V;
        const double res = 2.0 * cells;
        double *grid = dalloc(3 * V), *def = dalloc(3 * V), *pos = dalloc(3 * V), *pos2 = dalloc(3 * V);
        double *dout = dalloc(3 * V), *a1 = dalloc(3 * V), *a2 = dalloc(3 * V), *sdf = dalloc(V);
        double *b1 = dalloc(V), *b2 = dalloc(V);
        int32_t *tet_off = malloc(sizeof(int32_t) * (T + 1)), *slot_off = malloc(sizeof(int32_t) * (S + 1));
        REQUIRE(grid && def && pos && pos2 && dout && a1 && a2 && sdf && b1 && b2 && tet_off && slot_off);
        dnormal(def, 3 * V, 700);
        for (int i = 0; i < 3 * V; i++) grid[i] = g.verts[i], def[i] *= 0.5;
        dnormal(sdf, V, 701);
        for (int v = 0; v < V; v++) {
            const float* p = g.verts + 3 * v;
            sdf[v] = sqrt((double)p[0] * p[0] + (double)p[1] * p[1] + (double)p[2] * p[2]) - 0.3 + 0.1 * sdf[v];
        }
        // the deformation and its backward
        dmtet_deform_forward_f64(pos, grid, def, V, res);
        CHECK(be->dmtet_deform(pos2, grid, def, V, res) == MLB_OK);
        CHECK_MSG(!memcmp(pos, pos2, sizeof(double) * 3 * V), "f64 dmtet_deform, %d cells", cells);
        dnormal(dout, 3 * V, 702), dnormal(a1, 3 * V, 703);
        memcpy(a2, a1, sizeof(double) * 3 * V);
        dmtet_deform_backward_f64(NULL, a1, dout, def, V, res);
        CHECK(be->dmtet_deform_backward(a2, dout, def, V, res) == MLB_OK);
        CHECK_MSG(!memcmp(a1, a2, sizeof(double) * 3 * V), "f64 dmtet_deform_backward, %d cells", cells);
        // the regulariser and its backward
        double reg = NAN, reg0 = sdf_reg_forward_f64(&g, sdf);
        CHECK(be->sdf_reg(&reg, sdf, cells) == MLB_OK);
        CHECK_MSG(reg == reg0 && reg0 > 0, "f64 sdf_reg, %d cells: %.17g, host %.17g", cells, reg, reg0);
        dnormal(b1, V, 704);
        memcpy(b2, b1, sizeof(double) * V);
        sdf_reg_backward_f64(b1, &g, sdf, 0.7);
        CHECK(be->sdf_reg_backward(b2, sdf, cells, 0.7) == MLB_OK);
        CHECK_MSG(!memcmp(b1, b2, sizeof(double) * V), "f64 sdf_reg_backward, %d cells", cells);
        // marching tets: count, the table's scans, emit = marching_tets_forward_f64
        mlb_mt_surface_f64 s;
        REQUIRE(marching_tets_forward_f64(&s, &g, pos, sdf) == MLB_OK);
        const int M = s.n_verts, F = s.n_faces;
        CHECK(be->marching_tets_count(tet_off, slot_off, sdf, g.tets, T, cells) == MLB_OK);
        CHECK(be->scan_i32(tet_off, tet_off, T) == MLB_OK && be->scan_i32(slot_off, slot_off, (int)S) == MLB_OK);
        CHECK_MSG(tet_off[T] == F && slot_off[S] == M && F > 20, "f64 marching tets, %d cells: %d faces, host %d",
                  cells, tet_off[T], F);
        double *verts = dalloc(3 * M), *weight = dalloc(2 * M), *dverts = dalloc(3 * M);
        int32_t *vedge = malloc(sizeof(int32_t) * 2 * M), *faces = malloc(sizeof(int32_t) * 3 * F);
        REQUIRE(verts && weight && dverts && vedge && faces);
        CHECK(be->marching_tets_emit(verts, vedge, weight, faces, pos, sdf, g.tets, T, cells, tet_off, slot_off) ==
              MLB_OK);
        CHECK_MSG(!memcmp(verts, s.pos, sizeof(double) * 3 * M) && !memcmp(weight, s.weight, sizeof(double) * 2 * M) &&
                      !memcmp(vedge, s.edge, sizeof(int32_t) * 2 * M) && !memcmp(faces, s.faces, sizeof(int32_t) * 3 * F),
                  "f64 marching_tets_emit, %d cells", cells);
        // its backward: both gradients, dpos alone, dsdf alone
        dnormal(dverts, 3 * M, 705);
        for (int k = 0; k < 3; k++) {
            dnormal(a1, 3 * V, 706 + k), dnormal(b1, V, 709 + k);
            memcpy(a2, a1, sizeof(double) * 3 * V), memcpy(b2, b1, sizeof(double) * V);
            marching_tets_backward_f64(k != 2 ? a1 : NULL, k != 1 ? b1 : NULL, &s, pos, sdf, dverts);
            CHECK(be->marching_tets_backward(k != 2 ? a2 : NULL, k != 1 ? b2 : NULL, dverts, weight, vedge, M, pos, sdf,
                                             slot_off, cells) == MLB_OK);
            CHECK_MSG(!memcmp(a1, a2, sizeof(double) * 3 * V) && !memcmp(b1, b2, sizeof(double) * V),
                      "f64 marching_tets_backward, %d cells, case %d", cells, k);
        }
        printf("  f64 grid ops, %d cells: %d surface vertices, %d faces, regulariser %.6f, against the host functions\n",
               cells, M, F, reg0);
        mt_surface_free_f64(&s);
        free(grid), free(def), free(pos), free(pos2), free(dout), free(a1), free(a2), free(sdf), free(b1), free(b2);
        free(tet_off), free(slot_off), free(verts), free(weight), free(dverts), free(vedge), free(faces);
        mlb_tetgrid_free(&g);
    }
    double x = 0;
    CHECK(be->sdf_reg(&x, &x, 0) == MLB_ERR_ARG);
    CHECK(be->sdf_reg_backward(&x, &x, 513, 1) == MLB_ERR_ARG);
    CHECK(be->marching_tets_count(NULL, NULL, &x, NULL, 1, 0) == MLB_ERR_ARG);
    mlb_clear_error();
}

TEST(cuda_tables) {
    REQUIRE_GPU();
    for (int p = MLB_GEMM_FP32; p <= MLB_GEMM_BF16; p++) {
        char name[16];
        snprintf(name, sizeof name, "cuda %s", prec_name[p]);
        check_table(mlb_backend_for(MLB_DEVICE_CUDA, (mlb_gemm_precision)p), name);
    }
}

int main(void) {
    RUN(tables_complete);
    RUN(cpu_fp32_table);
    RUN(cpu_bf16_table);
    RUN(cpu_bf16_stored_table);
    RUN(cpu_attention_vs_double);
    RUN(cuda_attention_vs_double);
    RUN(cpu_f64_table);
    RUN(cpu_f64_grid_ops);
    RUN(cuda_tables);
    free_test_light();
    return test_summary();
}
