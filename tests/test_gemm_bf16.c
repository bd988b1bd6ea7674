// Tests of mlb_gemm_bf16 (src/nn/gemm_bf16.c, the shards of gemm.c): ragged shapes (M, N, K not
// multiples of the 14 x 32 register tile or of the K pair), every cut of the shard plan, all four
// transpose combinations, padded leading dimensions, alpha and beta (beta = 0 ignores NaN in C).
// Two references per element, both in long double:
//  - the exact product of the operands rounded to bf16 here (nearest even, denormals to zero, as
//    VCVTNE2PS2BF16): only the fp32 sums differ, so |C - ref| <= (K + 2) · 2^-24 · |alpha| · sum|terms|
//    (+ the beta·C term's rounding). This pins every packed operand: one wrong or misplaced value
//    breaks it by orders of magnitude.
//  - the exact product of the fp32 operands, the tolerance a caller gets: per element at most
//    (2^-7 + 2^-16 + (K + 2) · 2^-24) · |alpha| · sum|a·b| (each operand rounded by at most 2^-8
//    relative, so each product by 2^-7 + 2^-16, then the fp32 sums), and over the checked elements an RMS error at most 2^-8 · sqrt(sum (a·b)²), i.e. about
//    2^-8 · sqrt(K) times a typical |a·b| (measured about 0.6 · 2^-8).
// Bitwise the same on 1, 2 and 3 threads. Also sdpa_forward_bf16 (attention on these GEMMs, src/nn/
// attention_bf16.c) against attention in double, per element within the bound its roundings allow,
// and the bf16 convolutions whose GEMM packs straight from the image (src/nn/conv_bf16.c): the bits
// of im2col + mlb_gemm_bf16 (the input gradient: of the flipped conv), 1 and 2 threads alike, each
// element within its bound of the exact conv.
// Skipped (saying why) without AVX-512 BF16; the fp32
// fallback is checked by forcing it. On a CPU with AMX the cases run on its tiles, then again on the
// AVX-512 BF16 kernel.
#include "test.h"
#include "matlaber/conv_ops.h"
#include "matlaber/nn.h"
#include "matlaber/rng.h"
#include <float.h>
#include <omp.h>
#include <stdint.h>

#define SEED 20261126u

typedef struct { int M, N, K; char along; const char* what; } shape;
static const shape shapes[] = {
    {1, 1, 1, '-', "1x1x1"},
    {7, 5, 3, '-', "tiny, odd K"},
    {14, 32, 64, '-', "one whole tile"},
    {15, 33, 1, '-', "a tile and one more row and column, K 1"},
    {29, 95, 517, '-', "ragged everywhere, one call"},
    {1000, 96, 300, 'M', "cut along M"},
    {60, 1500, 301, 'N', "cut along N, odd K"},
    {32, 48, 24000, 'K', "cut along K"},
    {517, 259, 333, 'M', "odd sizes, cut along M"},
    {33, 31, 9001, 'K', "odd sizes, cut along K"},
};
#define N_SHAPES (sizeof shapes / sizeof shapes[0])

static float bf16_round(float x) {
    uint32_t u;
    memcpy(&u, &x, 4);
    if ((u & 0x7f800000u) == 0) u &= 0x80000000u;   // denormal -> signed zero
    else u += 0x7fffu + ((u >> 16) & 1);            // nearest even (no NaN or Inf in these tests)
    u &= 0xffff0000u;
    memcpy(&x, &u, 4);
    return x;
}

static size_t stored(int trans, int R, int C, int ld) { return (size_t)(trans ? C : R) * ld; }
static float at(const float* X, int trans, int ld, int r, int c) {
    return trans ? X[(size_t)c * ld + r] : X[(size_t)r * ld + c];
}

typedef struct { double worst_bf16, worst_fp32, rms_num, rms_den; } stats;

static void run_case(const shape* s, int ta, int tb, float alpha, float beta, stats* st) {
    const int M = s->M, N = s->N, K = s->K;
    const int lda = (ta ? M : K) + 3, ldb = (tb ? K : N) + 5, ldc = N + 2;
    size_t na = stored(ta, M, K, lda), nb = stored(tb, K, N, ldb), nc = (size_t)M * ldc;
    float *A = malloc(sizeof(float) * na), *B = malloc(sizeof(float) * nb), *C0 = malloc(sizeof(float) * nc);
    float *C = malloc(sizeof(float) * nc), *C2 = malloc(sizeof(float) * nc);
    REQUIRE(A && B && C0 && C && C2);
    for (size_t i = 0; i < na; i++) A[i] = (float)mlb_rng_normal_f64(SEED, 1, i);
    for (size_t i = 0; i < nb; i++) B[i] = (float)mlb_rng_normal_f64(SEED, 2, i);
    for (size_t i = 0; i < nc; i++) C0[i] = beta == 0 ? NAN : (float)mlb_rng_normal_f64(SEED, 3, i);
    memcpy(C, C0, sizeof(float) * nc);
    omp_set_num_threads(2);
    mlb_gemm_bf16(ta, tb, M, N, K, alpha, A, lda, B, ldb, beta, C, ldc);
    int bad = 0;   // checked: every 5th row and 3rd column, and the last of each (a wrong offset shows)
    for (int i = 0; i < M && bad < 3; i++)
        for (int j = 0; j < N && bad < 3; j++) {
            if ((i % 5 && i != M - 1) || (j % 3 && j != N - 1)) continue;
            long double sb = 0, mb = 0, sf = 0, mf = 0, sq = 0;
            for (int k = 0; k < K; k++) {
                float a = at(A, ta, lda, i, k), b = at(B, tb, ldb, k, j);
                long double pb = (long double)bf16_round(a) * bf16_round(b), pf = (long double)a * b;
                sb += pb; mb += fabsl(pb); sf += pf; mf += fabsl(pf); sq += pf * pf;
            }
            size_t e = (size_t)i * ldc + j;
            double c0 = beta == 0 ? 0 : C0[e];
            double refb = (double)(alpha * sb + (long double)beta * c0), reff = (double)(alpha * sf + (long double)beta * c0);
            double cterm = 4 * FLT_EPSILON * fabs(beta * c0) + 1e-30;
            double eb = fabs(C[e] - refb) / ((K + 2) * 0x1p-24 * fabs(alpha) * (double)mb + cterm);
            double ef = fabs(C[e] - reff) / ((0x1p-7 + 0x1p-16 + (K + 2) * 0x1p-24) * fabs(alpha) * (double)mf + cterm);
            if (!(eb <= 1) || !(ef <= 1)) {
                printf("  %s ta %d tb %d: C[%d,%d] = %.9g, bf16 operands %.9g, fp32 operands %.9g\n", s->what, ta, tb,
                       i, j, C[e], refb, reff);
                bad++;
            }
            if (eb > st->worst_bf16) st->worst_bf16 = eb;
            if (ef > st->worst_fp32) st->worst_fp32 = ef;
            double d = (C[e] - reff) / alpha;
            st->rms_num += d * d;
            st->rms_den += (double)sq;
        }
    CHECK_MSG(bad == 0, "%s, ta %d, tb %d, alpha %g, beta %g: wrong values", s->what, ta, tb, alpha, beta);
    for (int threads = 1; threads <= 3; threads += 2) {
        memcpy(C2, C0, sizeof(float) * nc);
        omp_set_num_threads(threads);
        mlb_gemm_bf16(ta, tb, M, N, K, alpha, A, lda, B, ldb, beta, C2, ldc);
        CHECK_MSG(memcmp(C, C2, sizeof(float) * nc) == 0, "%s, ta %d, tb %d: %d threads differ from 2", s->what, ta,
                  tb, threads);
    }
    // padding between rows of C is never written
    for (int i = 0; i < M; i++)
        for (int j = N; j < ldc; j++)
            if (beta == 0) CHECK(isnan(C[(size_t)i * ldc + j]));
    free(A); free(B); free(C0); free(C); free(C2);
}

TEST(values_threads_edges) {
    if (!mlb_gemm_bf16_native()) SKIP("this CPU has no AVX-512 BF16 (or $MATLABER_CPU_BF16 is off): fp32 fallback only");
    int max_threads = omp_get_max_threads();
    stats st = {0};
    for (size_t s = 0; s < N_SHAPES; s++) {
        char along = '?';
        mlb_gemm_shards(shapes[s].M, shapes[s].N, shapes[s].K, &along);
        CHECK_MSG(along == shapes[s].along, "%s: cut along %c", shapes[s].what, along);
        for (int t = 0; t < 4; t++) {
            run_case(&shapes[s], t & 1, t >> 1, 0.7f, 1.3f, &st);
            run_case(&shapes[s], t & 1, t >> 1, -1.1f, 0.0f, &st);
        }
    }
    omp_set_num_threads(max_threads);
    double rms = sqrt(st.rms_num / st.rms_den);
    printf("  largest error / bound: bf16-operand reference %.3g, fp32-operand reference %.3g; RMS error %.3g "
           "(2^-8 = %.3g)\n", st.worst_bf16, st.worst_fp32, rms, 0x1p-8);
    CHECK(rms <= 0x1p-8);
    CHECK(rms > 0x1p-12);   // and it is bf16: an fp32 product here would be ~2^-24
}

// linear_forward_bf16 (the weight packed per call, rows cut into tasks) against the exact product
// per element, the same bits on 1 and 2 threads, and linear_forward_bf16_packed on the weight packed
// once (mlb_bf16_pack_linear_weight) giving those bits too. Shapes of the SD UNet's kinds: the time
// embedding (2 rows), the context's keys/values (154 rows, where mlb_gemm_bf16 would cut K), ragged.
TEST(packed_weights) {
    if (!mlb_gemm_bf16_native()) SKIP("this CPU has no AVX-512 BF16 (or $MATLABER_CPU_BF16 is off)");
    static const int lin[][3] = {{1, 1, 1}, {2, 320, 1280}, {154, 768, 320}, {300, 517, 95}, {1000, 64, 33}, {2048, 320, 320}};
    const int max_threads = omp_get_max_threads();
    double worst = 0;
    for (size_t si = 0; si < sizeof lin / sizeof lin[0]; si++) {
        const int B = lin[si][0], C = lin[si][1], OC = lin[si][2];
        float *x = malloc(sizeof(float) * B * C), *w = malloc(sizeof(float) * OC * C), *b = malloc(sizeof(float) * OC);
        float *o1 = malloc(sizeof(float) * B * OC), *o2 = malloc(sizeof(float) * B * OC);
        uint32_t* packed = malloc(sizeof(uint32_t) * mlb_bf16_linear_weight_words(OC, C));
        REQUIRE(x && w && b && o1 && o2 && packed);
        mlb_rng_fill_uniform(x, (size_t)B * C, SEED, 60 + si, 0, -1, 1);
        mlb_rng_fill_uniform(w, (size_t)OC * C, SEED, 60 + si, 1, -1, 1);
        mlb_rng_fill_uniform(b, OC, SEED, 60 + si, 2, -1, 1);
        omp_set_num_threads(1);
        linear_forward_bf16(o1, x, w, b, B, C, OC);
        omp_set_num_threads(2);
        linear_forward_bf16(o2, x, w, b, B, C, OC);
        CHECK_MSG(!memcmp(o1, o2, sizeof(float) * B * OC), "linear %dx%dx%d: 1 and 2 threads differ", B, C, OC);
        CHECK(mlb_bf16_packing_available() && mlb_bf16_pack_linear_weight(packed, w, OC, C) == 1);
        CHECK(linear_forward_bf16_packed(o2, x, packed, b, B, C, OC) == MLB_OK);
        CHECK_MSG(!memcmp(o1, o2, sizeof(float) * B * OC), "linear %dx%dx%d: the packed weight differs", B, C, OC);
        for (int i = 0; i < B; i++)
            for (int j = 0; j < OC; j++) {
                long double sum = b[j], mag = fabsl((long double)b[j]);
                for (int k = 0; k < C; k++) {
                    long double t = (long double)x[(size_t)i * C + k] * w[(size_t)j * C + k];
                    sum += t;
                    mag += fabsl(t);
                }
                double e = (double)fabsl(o1[(size_t)i * OC + j] - sum), bound = (0x1p-7 + 0x1p-16 + (C + 2) * 0x1p-24) * (double)mag;
                CHECK_MSG(e <= bound, "linear %dx%dx%d: out[%d,%d] off by %.3g (bound %.3g)", B, C, OC, i, j, e, bound);
                if (mag > 0 && e / (double)mag > worst) worst = e / (double)mag;
            }
        free(x); free(w); free(b); free(o1); free(o2); free(packed);
    }
    omp_set_num_threads(max_threads);
    printf("  linear, weight packed per call and once: worst error relative to sum|terms| %.3g\n", worst);
    // the packing's rounding: nearest even (1 + 2^-8 is a tie: to 1; 1 + 3·2^-8 to 1 + 2^-6); a [1, 3]
    // weight packs as one 32-column panel: pair word 0 holds k = 0, 1 (low, high half), word 32 k = 2
    float v[3] = {1.0f + 0x1p-8f, 1.0f + 3 * 0x1p-8f, -2.5f};
    uint32_t words[64];
    CHECK(mlb_bf16_linear_weight_words(1, 3) == 64 && mlb_bf16_pack_linear_weight(words, v, 1, 3) == 1);
    CHECK(words[0] == (0x3F82u << 16 | 0x3F80u) && words[32] == 0xC020u && words[1] == 0);
}

// Forced off, it is the fp32 GEMM, bit for bit.
TEST(fallback_is_fp32) {
    const int M = 70, N = 45, K = 130;
    float *A = malloc(sizeof(float) * M * K), *B = malloc(sizeof(float) * K * N);
    float *C1 = malloc(sizeof(float) * M * N), *C2 = malloc(sizeof(float) * M * N);
    REQUIRE(A && B && C1 && C2);
    mlb_rng_fill_uniform(A, (size_t)M * K, SEED, 4, 0, -1, 1);
    mlb_rng_fill_uniform(B, (size_t)K * N, SEED, 5, 0, -1, 1);
    for (int i = 0; i < M * N; i++) C1[i] = C2[i] = (float)i / 7;
    int native = mlb_gemm_bf16_native();
    mlb_gemm_bf16_force_fallback(1);
    CHECK(mlb_gemm_bf16_native() == 0);
    mlb_gemm_bf16(MLB_NOTRANS, MLB_TRANS, M, N, K, 0.5f, A, K, B, K, 2.f, C1, N);
    mlb_gemm(MLB_NOTRANS, MLB_TRANS, M, N, K, 0.5f, A, K, B, K, 2.f, C2, N);
    CHECK(memcmp(C1, C2, sizeof(float) * M * N) == 0);
    mlb_gemm_bf16_force_fallback(!native);   // as it was (off stays off under $MATLABER_CPU_BF16=0)
    CHECK(mlb_gemm_bf16_native() == native);
    if (native) {   // and the kernel again differs from fp32 (by bf16 rounding)
        mlb_gemm_bf16(MLB_NOTRANS, MLB_TRANS, M, N, K, 0.5f, A, K, B, K, 0.f, C1, N);
        mlb_gemm(MLB_NOTRANS, MLB_TRANS, M, N, K, 0.5f, A, K, B, K, 0.f, C2, N);
        CHECK(memcmp(C1, C2, sizeof(float) * M * N) != 0);
    }
    free(A); free(B); free(C1); free(C2);
}

// alpha = 0 scales C only; K = 0 the same (as mlb_gemm).
TEST(alpha_zero_and_empty_k) {
    float A[6] = {INFINITY, 1, 2, 3, 4, 5}, B[6] = {1, 2, 3, 4, 5, 6}, C[4] = {1, 2, 3, 4};
    mlb_gemm_bf16(MLB_NOTRANS, MLB_NOTRANS, 2, 2, 3, 0.f, A, 3, B, 2, 2.f, C, 2);
    CHECK(C[0] == 2 && C[1] == 4 && C[2] == 6 && C[3] == 8);
    C[0] = NAN;
    mlb_gemm_bf16(MLB_NOTRANS, MLB_NOTRANS, 2, 2, 0, 1.f, A, 1, B, 2, 0.f, C, 2);
    CHECK(C[0] == 0 && C[3] == 0);
}

// ---- attention (sdpa_forward_bf16) -----------------------------------------------------------------
// Reference in double, per (batch, head, query): the softmax weights p, lse, out, and the bound of the
// bf16 result. The roundings: q and k to bf16 (2^-8 each) move a score by at most
// eps_s = scale · (2^-7 + 2^-16 + (hd + 2) · 2^-24) · sum_d |q_d k_d|; with E = max_s eps_s every
// weight moves by a factor within e^(±2E); then the weights and v are rounded to bf16 (2^-8 each),
// the fp32 sums over Tk keys ((Tk + 4) · 2^-23 of sum |p v|) and the polynomial exp (< 2e-7):
//   |out - ref| <= sum_s p_s |v_s| · ((e^(2E) - 1)(1 + 2^-6) + 2^-7 + 2^-16 + (Tk + 4) · 2^-23 + 1e-6)
//   |lse - ref| <= E + (Tk + 2) · 2^-24 + 1e-6 + 2^-23 |lse|.
typedef struct { int B, Tq, Tk, C, NH, fused; const char* what; } att_shape;
static const att_shape att_shapes[] = {
    {1, 1, 1, 8, 1, 0, "one query, one key"},
    {2, 70, 77, 96, 8, 0, "cross-attention to 77 tokens, heads of 12"},
    {1, 130, 130, 160, 4, 1, "fused qkv (stride 3C), heads of 40, Tq not a multiple of 64"},
    {2, 64, 7, 128, 2, 0, "heads of 64, 7 keys"},
    {1, 65, 300, 320, 2, 0, "heads of 160"},
    {1, 40, 50, 512, 1, 0, "one head of 512 (the VAE's)"},
    {2, 257, 257, 320, 8, 1, "fused qkv, heads of 40, threaded"},
};

static void att_case(const att_shape* s, double* worst, double* rms_num, double* rms_den) {
    const int B = s->B, Tq = s->Tq, Tk = s->Tk, C = s->C, NH = s->NH, hd = C / NH;
    const int ldq = s->fused ? 3 * C : C, ldkv = ldq;
    size_t nq = (size_t)B * Tq * ldq, nkv = s->fused ? 0 : (size_t)B * Tk * ldkv, no = (size_t)B * Tq * C;
    float *q = malloc(sizeof(float) * (nq + 2 * nkv)), *out = malloc(sizeof(float) * no);
    float *out2 = malloc(sizeof(float) * no), *lse = malloc(sizeof(float) * B * NH * Tq);
    double* p = malloc(sizeof(double) * Tk);
    REQUIRE(q && out && out2 && lse && p);
    mlb_rng_fill_uniform(q, nq + 2 * nkv, SEED, 20 + (uint64_t)(s - att_shapes), 0, -2, 2);
    const float *k = s->fused ? q + C : q + nq, *v = s->fused ? q + 2 * C : q + nq + nkv;
    CHECK(sdpa_forward_bf16(out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv) == MLB_OK);
    const double scale = 1 / sqrt((double)hd), u_prod = 0x1p-7 + 0x1p-16;
    for (int b = 0; b < B; b++)
        for (int h = 0; h < NH; h++)
            for (int t = 0; t < Tq; t++) {
                const float* qt = q + ((size_t)b * Tq + t) * ldq + h * hd;
                double mx = -INFINITY, E = 0, sum = 0;
                for (int j = 0; j < Tk; j++) {
                    const float* kj = k + ((size_t)b * Tk + j) * ldkv + h * hd;
                    double dot = 0, mag = 0;
                    for (int d = 0; d < hd; d++) { dot += (double)qt[d] * kj[d]; mag += fabs((double)qt[d] * kj[d]); }
                    p[j] = scale * dot;
                    double e = scale * (u_prod + (hd + 2) * 0x1p-24) * mag;
                    if (e > E) E = e;
                    if (p[j] > mx) mx = p[j];
                }
                for (int j = 0; j < Tk; j++) { p[j] = exp(p[j] - mx); sum += p[j]; }
                double ref_lse = mx + log(sum), got_lse = lse[((size_t)b * NH + h) * Tq + t];
                double lse_bound = E + (Tk + 2) * 0x1p-24 + 1e-6 + 0x1p-23 * fabs(ref_lse);
                double r = fabs(got_lse - ref_lse) / lse_bound;
                if (r > worst[1]) worst[1] = r;
                double factor = (exp(2 * E) - 1) * (1 + 0x1p-6) + u_prod + (Tk + 4) * 0x1p-23 + 1e-6;
                for (int d = 0; d < hd; d++) {
                    double ref = 0, mag = 0;
                    for (int j = 0; j < Tk; j++) {
                        double vj = v[((size_t)b * Tk + j) * ldkv + h * hd + d];
                        ref += p[j] / sum * vj;
                        mag += p[j] / sum * fabs(vj);
                    }
                    double got = out[((size_t)b * Tq + t) * C + h * hd + d];
                    double e = fabs(got - ref) / (factor * mag);
                    if (!(e <= worst[0])) worst[0] = e;   // NaN sticks
                    *rms_num += (got - ref) * (got - ref);
                    *rms_den += ref * ref;
                }
            }
    // the same bits with lse NULL and on 1, 2 and 3 threads
    int max_threads = omp_get_max_threads();
    for (int threads = 1; threads <= 3; threads++) {
        omp_set_num_threads(threads);
        CHECK(sdpa_forward_bf16(out2, threads == 2 ? NULL : lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv) == MLB_OK);
        CHECK_MSG(memcmp(out, out2, sizeof(float) * no) == 0, "%s: %d threads differ", s->what, threads);
    }
    omp_set_num_threads(max_threads);
    free(q); free(out); free(out2); free(lse); free(p);
}

TEST(attention) {
    if (!mlb_gemm_bf16_native()) SKIP("this CPU has no AVX-512 BF16 (or $MATLABER_CPU_BF16 is off): fp32 fallback only");
    double worst[2] = {0, 0}, num = 0, den = 0;
    for (size_t i = 0; i < sizeof att_shapes / sizeof att_shapes[0]; i++) {
        double w[2] = {0, 0};
        att_case(&att_shapes[i], w, &num, &den);
        printf("  %-58s error / bound: out %.3g, lse %.3g\n", att_shapes[i].what, w[0], w[1]);
        CHECK_MSG(w[0] <= 1 && w[1] <= 1, "%s: out of bounds", att_shapes[i].what);
        for (int j = 0; j < 2; j++) if (w[j] > worst[j]) worst[j] = w[j];
    }
    double rms = sqrt(num / den);
    printf("  RMS error of out %.3g (2^-8 = %.3g)\n", rms, 0x1p-8);
    CHECK(rms <= 0x1p-7 && rms > 0x1p-14);   // bf16, not fp32 (~2^-24)
}

// Forced off, the attention is sdpa_forward's, bit for bit (out and lse).
TEST(attention_fallback_is_fp32) {
    const int B = 2, T = 150, C = 64, NH = 4;
    size_t n = (size_t)B * T * C, nl = (size_t)B * NH * T;
    float *x = malloc(sizeof(float) * 3 * n), *o1 = malloc(sizeof(float) * n), *o2 = malloc(sizeof(float) * n);
    float *l1 = malloc(sizeof(float) * nl), *l2 = malloc(sizeof(float) * nl);
    REQUIRE(x && o1 && o2 && l1 && l2);
    mlb_rng_fill_uniform(x, 3 * n, SEED, 40, 0, -2, 2);
    int native = mlb_gemm_bf16_native();
    mlb_gemm_bf16_force_fallback(1);
    CHECK(sdpa_forward_bf16(o1, l1, x, x + n, x + 2 * n, B, T, T, C, NH, C, C) == MLB_OK);
    CHECK(sdpa_forward(o2, l2, x, x + n, x + 2 * n, B, T, T, C, NH, C, C, NULL) == MLB_OK);
    CHECK(memcmp(o1, o2, sizeof(float) * n) == 0 && memcmp(l1, l2, sizeof(float) * nl) == 0);
    mlb_gemm_bf16_force_fallback(!native);
    // the shape errors are sdpa_forward's
    CHECK(sdpa_forward_bf16(o1, l1, x, x + n, x + 2 * n, B, T, T, C, 3, C, C) == MLB_ERR_ARG);
    CHECK(sdpa_forward_bf16(o1, l1, x, x + n, x + 2 * n, B, T, 0, C, NH, C, C) == MLB_ERR_ARG);
    free(x); free(o1); free(o2); free(l1); free(l2);
}

// ---- convolution: conv2d_forward_bf16 / _packed and conv2d_backward_bf16's input gradient packed
// straight from the image (src/nn/conv_bf16.c) ----------------------------------------------------
// im2col of image x ([C, H, W]) for cv into col[K, OH·OW], written out here in plain loops.
static void test_im2col(float* col, const float* x, const mlb_conv2d* cv) {
    const int OH = mlb_conv2d_out_h(cv), OW = mlb_conv2d_out_w(cv);
    for (int c = 0; c < cv->C; c++)
        for (int i = 0; i < cv->KH; i++)
            for (int j = 0; j < cv->KW; j++)
                for (int y = 0; y < OH; y++)
                    for (int xo = 0; xo < OW; xo++) {
                        int iy = y * cv->stride_h - cv->pad_top + i, ix = xo * cv->stride_w - cv->pad_left + j;
                        float v = iy >= 0 && iy < cv->H && ix >= 0 && ix < cv->W ? x[((size_t)c * cv->H + iy) * cv->W + ix] : 0;
                        col[(((size_t)c * cv->KH + i) * cv->KW + j) * OH * OW + (size_t)y * OW + xo] = v;
                    }
}

// out (+)= conv as im2col + mlb_gemm_bf16 (the sums start from the bias, or from out with accumulate).
static void reference_conv(float* out, const float* in, const float* w, const float* bias, const mlb_conv2d* cv,
                           int accumulate) {
    const int K = cv->C * cv->KH * cv->KW, P = mlb_conv2d_out_h(cv) * mlb_conv2d_out_w(cv);
    float* col = malloc(sizeof(float) * (size_t)K * P);
    for (int n = 0; n < cv->N; n++) {
        float* o = out + (size_t)n * cv->OC * P;
        if (!accumulate)
            for (int oc = 0; oc < cv->OC; oc++)
                for (int p = 0; p < P; p++) o[(size_t)oc * P + p] = bias ? bias[oc] : 0;
        test_im2col(col, in + (size_t)n * cv->C * cv->H * cv->W, cv);
        mlb_gemm_bf16(0, 0, cv->OC, P, K, 1.0f, w, K, col, P, 1.0f, o, P);
    }
    free(col);
}

typedef struct { int N, C, H, W, OC, KH, KW, sh, sw, pt, pl, pb, pr; const char* what; } conv_shape;
static const conv_shape conv_shapes[] = {
    {2, 5, 40, 40, 19, 3, 3, 1, 1, 1, 1, 1, 1, "3x3 same, rows of 40 across 32-pixel panels, 2 images"},
    {1, 3, 7, 9, 16, 3, 3, 1, 1, 1, 1, 1, 1, "rows of 9: several rows per panel"},
    {1, 8, 33, 35, 30, 3, 3, 2, 2, 0, 0, 1, 1, "the VAE's downsample: stride 2, pad right/bottom only"},
    {1, 4, 12, 50, 7, 3, 1, 1, 1, 1, 0, 1, 0, "3x1 kernel"},
    {1, 2, 20, 20, 3, 5, 5, 1, 1, 2, 2, 2, 2, "5x5 same"},
    {1, 6, 21, 23, 5, 3, 3, 1, 1, 0, 0, 0, 0, "3x3 valid (its input gradient pads by 2)"},
    {1, 16, 70, 70, 33, 3, 3, 1, 1, 1, 1, 1, 1, "10 tiles of 512 pixels"},
    {1, 7, 8, 8, 9, 3, 3, 1, 1, 1, 2, 0, 1, "uneven pads"},
    {2, 9, 10, 37, 12, 1, 1, 1, 1, 0, 0, 0, 0, "1x1 (the image is the im2col)"},
    {1, 30, 19, 21, 17, 3, 3, 2, 2, 1, 1, 1, 1, "the UNet's downsample: stride 2, odd left pad, two K blocks"},
    {2, 3, 23, 70, 6, 3, 3, 3, 3, 1, 2, 0, 1, "stride 3, uneven pads"},
    {1, 5, 40, 1, 4, 3, 3, 1, 1, 1, 1, 1, 1, "one column: 32 rows per panel"},
    {1, 4, 9, 9, 5, 1, 1, 2, 2, 0, 0, 0, 0, "1x1 with stride 2"},
    {3, 7, 33, 97, 10, 2, 4, 2, 1, 1, 3, 0, 2, "2x4 kernel, stride 2 down, 1 across, odd row length"},
};

TEST(conv_from_the_image) {
    if (!mlb_gemm_bf16_native()) SKIP("this CPU has no AVX-512 BF16 (or $MATLABER_CPU_BF16 is off)");
    const int max_threads = omp_get_max_threads();
    double worst_fwd = 0, worst_din = 0;
    for (size_t si = 0; si < sizeof conv_shapes / sizeof conv_shapes[0]; si++) {
        const conv_shape* s = &conv_shapes[si];
        const mlb_conv2d cv = {s->N, s->C, s->H, s->W, s->OC, s->KH, s->KW, s->sh, s->sw, s->pt, s->pl, s->pb, s->pr};
        const int OH = mlb_conv2d_out_h(&cv), OW = mlb_conv2d_out_w(&cv), K = s->C * s->KH * s->KW;
        const size_t nin = (size_t)s->N * s->C * s->H * s->W, nout = (size_t)s->N * s->OC * OH * OW, nw = (size_t)s->OC * K;
        float *x = malloc(sizeof(float) * nin), *w = malloc(sizeof(float) * nw), *b = malloc(sizeof(float) * s->OC);
        float *o1 = malloc(sizeof(float) * nout), *o2 = malloc(sizeof(float) * nout), *ref = malloc(sizeof(float) * nout);
        float *d1 = malloc(sizeof(float) * nin), *d2 = malloc(sizeof(float) * nin), *dref = malloc(sizeof(float) * nin);
        uint32_t* wp = malloc(sizeof(uint32_t) * mlb_bf16_conv_weight_words(s->OC, K));
        REQUIRE(x && w && b && o1 && o2 && ref && d1 && d2 && dref && wp);
        mlb_rng_fill_uniform(x, nin, SEED, 70 + si, 0, -1, 1);
        mlb_rng_fill_uniform(w, nw, SEED, 70 + si, 1, -1, 1);
        mlb_rng_fill_uniform(b, s->OC, SEED, 70 + si, 2, -1, 1);
        // forward: the bits of im2col + mlb_gemm_bf16, on 1 and 2 threads, and with the weight packed once
        reference_conv(ref, x, w, b, &cv, 0);
        omp_set_num_threads(1);
        CHECK(conv2d_forward_bf16(o1, x, w, b, &cv, NULL) == MLB_OK);
        omp_set_num_threads(2);
        CHECK(conv2d_forward_bf16(o2, x, w, b, &cv, NULL) == MLB_OK);
        CHECK_MSG(!memcmp(o1, ref, sizeof(float) * nout) && !memcmp(o2, ref, sizeof(float) * nout),
                  "%s: forward differs from im2col + GEMM", s->what);
        CHECK(mlb_bf16_pack_conv_weight(wp, w, s->OC, K) == 1);
        CHECK(conv2d_forward_bf16_packed(o2, x, wp, b, &cv) == MLB_OK);
        CHECK_MSG(!memcmp(o2, ref, sizeof(float) * nout), "%s: forward with the weight packed once differs", s->what);
        // against the exact conv in long double: each product of bf16-rounded operands is within
        // 2^-7 + 2^-16 of the exact one, then the fp32 sums: (K + 2)·2^-24 of sum|terms|
        for (int n = 0; n < s->N; n++)
            for (int oc = 0; oc < s->OC; oc++)
                for (int y = 0; y < OH; y++)
                    for (int xo = 0; xo < OW; xo++) {
                        long double sum = b[oc], mag = fabsl((long double)b[oc]);
                        for (int c = 0; c < s->C; c++)
                            for (int i = 0; i < s->KH; i++)
                                for (int j = 0; j < s->KW; j++) {
                                    int iy = y * s->sh - s->pt + i, ix = xo * s->sw - s->pl + j;
                                    if (iy < 0 || iy >= s->H || ix < 0 || ix >= s->W) continue;
                                    long double t = (long double)w[(((size_t)oc * s->C + c) * s->KH + i) * s->KW + j] *
                                                    x[(((size_t)n * s->C + c) * s->H + iy) * s->W + ix];
                                    sum += t;
                                    mag += fabsl(t);
                                }
                        double e = (double)fabsl(o1[(((size_t)n * s->OC + oc) * OH + y) * OW + xo] - sum);
                        double bound = (0x1p-7 + 0x1p-16 + (K + 2) * 0x1p-24) * (double)mag;
                        CHECK_MSG(e <= bound, "%s: out[%d,%d,%d,%d] off by %.3g (bound %.3g)", s->what, n, oc, y, xo, e, bound);
                        if (mag > 0 && e / (double)mag > worst_fwd) worst_fwd = e / (double)mag;
                    }
        // input gradient, added to what din holds: a stride-1 conv runs as the conv of dout with the
        // weight flipped and transposed (its bits: that conv through im2col + GEMM), a strided one as
        // before; both within the bound of the exact gradient
        float* dout = o1;
        mlb_rng_fill_uniform(dout, nout, SEED, 70 + si, 3, -1, 1);
        mlb_rng_fill_uniform(d1, nin, SEED, 70 + si, 4, -1, 1);
        memcpy(d2, d1, sizeof(float) * nin);
        memcpy(dref, d1, sizeof(float) * nin);
        if (s->sh == 1 && s->sw == 1) {
            float* wt = malloc(sizeof(float) * nw);
            REQUIRE(wt);
            for (int oc = 0; oc < s->OC; oc++)
                for (int c = 0; c < s->C; c++)
                    for (int i = 0; i < s->KH; i++)
                        for (int j = 0; j < s->KW; j++)
                            wt[(((size_t)c * s->OC + oc) * s->KH + (s->KH - 1 - i)) * s->KW + (s->KW - 1 - j)] =
                                w[(((size_t)oc * s->C + c) * s->KH + i) * s->KW + j];
            const mlb_conv2d t = {s->N, s->OC, OH, OW, s->C, s->KH, s->KW, 1, 1, s->KH - 1 - s->pt, s->KW - 1 - s->pl,
                                  s->KH - 1 - s->pb, s->KW - 1 - s->pr};
            CHECK(mlb_conv2d_out_h(&t) == s->H && mlb_conv2d_out_w(&t) == s->W);
            reference_conv(dref, dout, wt, NULL, &t, 1);
            free(wt);
        }
        omp_set_num_threads(1);
        CHECK(conv2d_backward_bf16(d1, NULL, NULL, dout, NULL, w, &cv, NULL) == MLB_OK);
        omp_set_num_threads(2);
        CHECK(conv2d_backward_bf16(d2, NULL, NULL, dout, NULL, w, &cv, NULL) == MLB_OK);
        CHECK_MSG(!memcmp(d1, d2, sizeof(float) * nin), "%s: input gradient differs between 1 and 2 threads", s->what);
        if (s->sh == 1 && s->sw == 1)
            CHECK_MSG(!memcmp(d1, dref, sizeof(float) * nin), "%s: input gradient differs from the flipped conv", s->what);
        double* exact = calloc(nin, sizeof(double));
        double* mag = calloc(nin, sizeof(double));
        REQUIRE(exact && mag);
        for (int n = 0; n < s->N; n++)
            for (int oc = 0; oc < s->OC; oc++)
                for (int y = 0; y < OH; y++)
                    for (int xo = 0; xo < OW; xo++)
                        for (int c = 0; c < s->C; c++)
                            for (int i = 0; i < s->KH; i++)
                                for (int j = 0; j < s->KW; j++) {
                                    int iy = y * s->sh - s->pt + i, ix = xo * s->sw - s->pl + j;
                                    if (iy < 0 || iy >= s->H || ix < 0 || ix >= s->W) continue;
                                    double t = (double)w[(((size_t)oc * s->C + c) * s->KH + i) * s->KW + j] *
                                               dout[(((size_t)n * s->OC + oc) * OH + y) * OW + xo];
                                    size_t e = (((size_t)n * s->C + c) * s->H + iy) * s->W + ix;
                                    exact[e] += t;
                                    mag[e] += fabs(t);
                                }
        float* start = malloc(sizeof(float) * nin);   // what din held before the call
        REQUIRE(start);
        mlb_rng_fill_uniform(start, nin, SEED, 70 + si, 4, -1, 1);
        for (size_t e = 0; e < nin; e++) {
            double err = fabs((double)d1[e] - (start[e] + exact[e]));
            double bound = (0x1p-7 + 0x1p-16 + (s->OC * s->KH * s->KW + 4) * 0x1p-24) * (mag[e] + fabs(start[e])) + 0x1p-24;
            CHECK_MSG(err <= bound, "%s: din[%zu] off by %.3g (bound %.3g)", s->what, e, err, bound);
            if (mag[e] > 0 && err / mag[e] > worst_din) worst_din = err / mag[e];
        }
        free(start); free(exact); free(mag);
        free(x); free(w); free(b); free(o1); free(o2); free(ref); free(d1); free(d2); free(dref); free(wp);
    }
    omp_set_num_threads(max_threads);
    printf("  conv from the image: worst error relative to sum|terms|: forward %.3g, input gradient %.3g (bf16 "
           "operands: up to 2^-7 = %.3g)\n", worst_fwd, worst_din, 0x1p-7);
}

// sdpa_backward_bf16 (sdpa_backward's loop with its five products on the bf16 GEMM) against the
// backward in double on the same fp32 inputs: relative L2 error of dq, dk, dv in (2^-14, 2^-6]
// (bf16 operands: each product ~2^-8 RMS, two products in a row for dq and dk, and dS = P (dP - D)
// cancels: measured 2^-8.6 .. 2^-7.9), the same bits on 1 and 2 threads, and sdpa_backward's bits
// when forced off.
TEST(attention_backward) {
    if (!mlb_gemm_bf16_native()) SKIP("this CPU has no AVX-512 BF16 (or $MATLABER_CPU_BF16 is off)");
    typedef struct { int B, Tq, Tk, C, NH; const char* what; } bshape;
    static const bshape cases[] = {{2, 150, 150, 64, 4, "self-attention, heads of 16"},
                                   {1, 130, 77, 96, 2, "cross-attention to 77 tokens"},
                                   {1, 256, 256, 512, 1, "one head of 512 (the VAE's)"}};
    const int max_threads = omp_get_max_threads();
    double worst = 0, best = 1;
    for (size_t ci = 0; ci < sizeof cases / sizeof cases[0]; ci++) {
        const bshape* c = &cases[ci];
        const size_t nq = (size_t)c->B * c->Tq * c->C, nk = (size_t)c->B * c->Tk * c->C, nl = (size_t)c->B * c->NH * c->Tq;
        float* f = malloc(sizeof(float) * (3 * nq + 2 * nk + nl + 3 * (nq + 2 * nk)));
        double* d = malloc(sizeof(double) * (3 * nq + 2 * nk + nl + nq + 2 * nk));
        REQUIRE(f && d);
        float *q = f, *o = q + nq, *dout = o + nq, *k = dout + nq, *v = k + nk, *lse = v + nk;
        float *g1 = lse + nl, *g2 = g1 + nq + 2 * nk, *g3 = g2 + nq + 2 * nk;   // [dq | dk | dv] each
        double *qd = d, *od = qd + nq, *doutd = od + nq, *kd = doutd + nq, *vd = kd + nk, *lsed = vd + nk, *gd = lsed + nl;
        mlb_rng_fill_uniform(q, nq, SEED, 90 + ci, 0, -2, 2);
        mlb_rng_fill_uniform(k, nk, SEED, 90 + ci, 1, -2, 2);
        mlb_rng_fill_uniform(v, nk, SEED, 90 + ci, 2, -1, 1);
        mlb_rng_fill_uniform(dout, nq, SEED, 90 + ci, 3, -1, 1);
        for (size_t i = 0; i < nq; i++) { qd[i] = q[i]; doutd[i] = dout[i]; }
        for (size_t i = 0; i < nk; i++) { kd[i] = k[i]; vd[i] = v[i]; }
        REQUIRE(sdpa_forward(o, lse, q, k, v, c->B, c->Tq, c->Tk, c->C, c->NH, c->C, c->C, NULL) == MLB_OK);
        REQUIRE(sdpa_forward_f64(od, lsed, qd, kd, vd, c->B, c->Tq, c->Tk, c->C, c->NH, c->C, c->C, NULL) == MLB_OK);
        memset(gd, 0, sizeof(double) * (nq + 2 * nk));
        REQUIRE(sdpa_backward_f64(gd, gd + nq, gd + nq + nk, doutd, od, lsed, qd, kd, vd, c->B, c->Tq, c->Tk, c->C,
                                  c->NH, c->C, c->C, NULL) == MLB_OK);
        memset(g1, 0, sizeof(float) * 3 * (nq + 2 * nk));
        omp_set_num_threads(1);
        CHECK(sdpa_backward_bf16(g1, g1 + nq, g1 + nq + nk, dout, o, lse, q, k, v, c->B, c->Tq, c->Tk, c->C, c->NH,
                                 c->C, c->C, NULL) == MLB_OK);
        omp_set_num_threads(2);
        CHECK(sdpa_backward_bf16(g2, g2 + nq, g2 + nq + nk, dout, o, lse, q, k, v, c->B, c->Tq, c->Tk, c->C, c->NH,
                                 c->C, c->C, NULL) == MLB_OK);
        omp_set_num_threads(max_threads);
        CHECK_MSG(!memcmp(g1, g2, sizeof(float) * (nq + 2 * nk)), "%s: 1 and 2 threads differ", c->what);
        const char* names[3] = {"dq", "dk", "dv"};
        const size_t off[3] = {0, nq, nq + nk}, len[3] = {nq, nk, nk};
        for (int w = 0; w < 3; w++) {
            double num = 0, den = 0;
            for (size_t i = 0; i < len[w]; i++) {
                double e = g1[off[w] + i] - gd[off[w] + i];
                num += e * e;
                den += gd[off[w] + i] * gd[off[w] + i];
            }
            double rel = sqrt(num / den);
            CHECK_MSG(rel > 0x1p-14 && rel <= 0x1p-6, "%s: %s relative L2 error %.3g outside (2^-14, 2^-6]", c->what,
                      names[w], rel);
            if (rel > worst) worst = rel;
            if (rel < best) best = rel;
        }
        memset(g2, 0, sizeof(float) * (nq + 2 * nk));   // the gradients accumulate
        mlb_gemm_bf16_force_fallback(1);   // forced off: sdpa_backward, bit for bit
        CHECK(sdpa_backward_bf16(g2, g2 + nq, g2 + nq + nk, dout, o, lse, q, k, v, c->B, c->Tq, c->Tk, c->C, c->NH,
                                 c->C, c->C, NULL) == MLB_OK);
        mlb_gemm_bf16_force_fallback(0);
        CHECK(sdpa_backward(g3, g3 + nq, g3 + nq + nk, dout, o, lse, q, k, v, c->B, c->Tq, c->Tk, c->C, c->NH, c->C,
                            c->C, NULL) == MLB_OK);
        CHECK_MSG(!memcmp(g2, g3, sizeof(float) * (nq + 2 * nk)), "%s: the fallback is not sdpa_backward's bits", c->what);
        free(f); free(d);
    }
    printf("  attention backward, bf16 GEMMs: relative L2 error of dq/dk/dv %.3g .. %.3g (2^-7 = %.3g)\n", best, worst,
           0x1p-7);
}

// Where the CPU has AMX, the tests above ran its tiles (src/nn/gemm_amx.c) and run again on the
// AVX-512 BF16 kernel (main). Here: the switch is real (a long dot product's fp32 sums round in
// another order on the tiles: some bits differ, none by more than the fp32 sums' bound), a product
// whose A was packed in one mode is packed again after the switch, and $MATLABER_CPU_AMX is read.
TEST(amx_tiles_and_avx512_kernel) {
    if (!mlb_gemm_bf16_native()) SKIP("this CPU has no AVX-512 BF16");
    if (!mlb_gemm_bf16_amx()) SKIP("no AMX here (or $MATLABER_CPU_AMX is off): the AVX-512 BF16 kernel only");
    const int M = 45, N = 70, K = 2000;   // K: blocks of 128 pairs and a tail of 8 pairs
    float *A = malloc(sizeof(float) * M * K), *B = malloc(sizeof(float) * K * N);
    float *C1 = malloc(sizeof(float) * M * N), *C2 = malloc(sizeof(float) * M * N);
    REQUIRE(A && B && C1 && C2);
    mlb_rng_fill_uniform(A, (size_t)M * K, SEED, 6, 0, -1, 1);
    mlb_rng_fill_uniform(B, (size_t)K * N, SEED, 7, 0, -1, 1);
    mlb_gemm_bf16(MLB_NOTRANS, MLB_NOTRANS, M, N, K, 1.f, A, K, B, N, 0.f, C1, N);
    mlb_gemm_bf16_force_amx_off(1);
    CHECK(mlb_gemm_bf16_amx() == 0 && mlb_gemm_bf16_native());
    mlb_gemm_bf16(MLB_NOTRANS, MLB_NOTRANS, M, N, K, 1.f, A, K, B, N, 0.f, C2, N);
    mlb_gemm_bf16_force_amx_off(0);
    CHECK(mlb_gemm_bf16_amx() == 1);
    int differ = 0;
    double worst = 0;
    for (int i = 0; i < M; i++)
        for (int j = 0; j < N; j++) {
            double mag = 0;
            for (int k = 0; k < K; k++) mag += fabs((double)A[(size_t)i * K + k] * B[(size_t)k * N + j]);
            float a = C1[(size_t)i * N + j], b = C2[(size_t)i * N + j];
            differ += memcmp(&a, &b, 4) != 0;
            double e = fabs((double)a - b) / (2 * (K + 2) * 0x1p-24 * mag);   // both within their bound of one sum
            if (e > worst) worst = e;
        }
    printf("  AMX against AVX-512 BF16: %d of %d elements differ; worst difference / the two bounds %.3g\n", differ,
           M * N, worst);
    CHECK(differ > 0);
    CHECK(worst <= 1);
    free(A); free(B); free(C1); free(C2);
}

int main(void) {
    RUN(values_threads_edges);
    RUN(packed_weights);
    RUN(fallback_is_fp32);
    RUN(alpha_zero_and_empty_k);
    RUN(attention);
    RUN(attention_fallback_is_fp32);
    RUN(conv_from_the_image);
    RUN(attention_backward);
    RUN(amx_tiles_and_avx512_kernel);
    if (mlb_gemm_bf16_amx()) {   // the cases above ran on AMX tiles: the AVX-512 BF16 kernel too
        printf("again on the AVX-512 BF16 kernel (AMX off):\n");
        mlb_gemm_bf16_force_amx_off(1);
        RUN(values_threads_edges);
        RUN(packed_weights);
        RUN(attention);
        RUN(conv_from_the_image);
        RUN(attention_backward);
        mlb_gemm_bf16_force_amx_off(0);
    }
    return test_summary();
}
