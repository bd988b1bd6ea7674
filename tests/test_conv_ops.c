// Convolution-family ops (conv_ops.h): conv2d against a naive loop (1x1, 3x3, stride 2, asymmetric
// padding, rectangular kernels, several im2col bands), every backward by finite differences in
// double (conv2d, group norm with and without SiLU, upsample, attention), float vs double
// agreement, accumulation, thread-count independence and the error messages.
#include <omp.h>
#include <stdint.h>
#include "matlaber/conv_ops.h"
#include "matlaber/error.h"
#include "matlaber/threads.h"
#include "nn/simd_rows.h"
#include "test.h"

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static double urand(void) {   // xorshift64*, uniform in [-1, 1)
    rng_state ^= rng_state >> 12; rng_state ^= rng_state << 25; rng_state ^= rng_state >> 27;
    return (double)((rng_state * 0x2545f4914f6cdd1dull) >> 11) / 9007199254740992.0 * 2.0 - 1.0;
}
// d = random values; f (if given) = the same rounded to float, and d then holds exactly f.
static void fill(float* f, double* d, size_t n, double scale, double offset) {
    for (size_t i = 0; i < n; i++) {
        double v = offset + scale * urand();
        if (f) f[i] = (float)v;
        if (d) d[i] = f ? (double)f[i] : v;
    }
}
static double* dalloc(size_t n) { return calloc(n ? n : 1, sizeof(double)); }
static float* falloc(size_t n) { return calloc(n ? n : 1, sizeof(float)); }
static double max_abs_fd(const float* a, const double* b, size_t n) {
    double m = 0;
    for (size_t i = 0; i < n; i++) { double d = fabs((double)a[i] - b[i]); if (!(d <= m)) m = d; }
    return m;
}
static double max_abs(const double* a, size_t n) {
    double m = 0;
    for (size_t i = 0; i < n; i++) if (fabs(a[i]) > m) m = fabs(a[i]);
    return m;
}
static double dot(const double* a, const double* b, size_t n) {
    double s = 0;
    for (size_t i = 0; i < n; i++) s += a[i] * b[i];
    return s;
}

// ---- naive conv ----------------------------------------------------------------------------------
static void naive_conv(double* out, const double* in, const double* w, const double* b, const mlb_conv2d* cv) {
    int OH = mlb_conv2d_out_h(cv), OW = mlb_conv2d_out_w(cv);
    for (int n = 0; n < cv->N; n++)
        for (int o = 0; o < cv->OC; o++)
            for (int y = 0; y < OH; y++)
                for (int x = 0; x < OW; x++) {
                    double s = b ? b[o] : 0;
                    for (int c = 0; c < cv->C; c++)
                        for (int i = 0; i < cv->KH; i++)
                            for (int j = 0; j < cv->KW; j++) {
                                int iy = y * cv->stride_h - cv->pad_top + i, ix = x * cv->stride_w - cv->pad_left + j;
                                if (iy < 0 || iy >= cv->H || ix < 0 || ix >= cv->W) continue;
                                s += w[((size_t)(o * cv->C + c) * cv->KH + i) * cv->KW + j] *
                                     in[(((size_t)n * cv->C + c) * cv->H + iy) * cv->W + ix];
                            }
                    out[(((size_t)n * cv->OC + o) * OH + y) * OW + x] = s;
                }
}

static mlb_conv2d conv_case(int N, int C, int H, int W, int OC, int KH, int KW, int sh, int sw, int pt, int pl, int pb,
                            int pr) {
    mlb_conv2d cv = {N, C, H, W, OC, KH, KW, sh, sw, pt, pl, pb, pr};
    return cv;
}

static const mlb_conv2d* conv_cases(int* n) {
    static mlb_conv2d cases[7];
    cases[0] = conv_case(2, 5, 7, 6, 4, 1, 1, 1, 1, 0, 0, 0, 0);   // 1x1 pointwise (plain GEMM)
    cases[1] = conv_case(2, 3, 8, 7, 5, 3, 3, 1, 1, 1, 1, 1, 1);   // 3x3 same
    cases[2] = conv_case(1, 4, 9, 8, 3, 3, 3, 2, 2, 1, 1, 1, 1);   // stride 2, odd height
    cases[3] = conv_case(2, 3, 8, 6, 4, 3, 3, 2, 2, 0, 0, 1, 1);   // the VAE downsample: pad (0,1,0,1)
    cases[4] = conv_case(1, 2, 6, 9, 3, 2, 3, 1, 2, 0, 2, 1, 0);   // rectangular kernel, mixed strides/padding
    cases[5] = conv_case(1, 3, 5, 5, 2, 1, 1, 2, 2, 0, 0, 0, 0);   // 1x1 with stride (im2col path)
    cases[6] = conv_case(1, 2, 4, 4, 3, 5, 5, 1, 1, 2, 2, 2, 2);   // kernel larger than the image
    *n = 7;
    return cases;
}

TEST(conv2d_forward_matches_naive) {
    int nc;
    const mlb_conv2d* cases = conv_cases(&nc);
    double worst_f = 0, worst_d = 0;
    for (int t = 0; t < nc; t++) {
        const mlb_conv2d* cv = &cases[t];
        REQUIRE(mlb_conv2d_check(cv) == MLB_OK);
        size_t ni = (size_t)cv->N * cv->C * cv->H * cv->W, nw = (size_t)cv->OC * cv->C * cv->KH * cv->KW;
        size_t no = (size_t)cv->N * cv->OC * mlb_conv2d_out_h(cv) * mlb_conv2d_out_w(cv);
        float *x = falloc(ni), *w = falloc(nw), *b = falloc(cv->OC), *o = falloc(no);
        double *xd = dalloc(ni), *wd = dalloc(nw), *bd = dalloc(cv->OC), *od = dalloc(no), *ref = dalloc(no);
        fill(x, xd, ni, 1, 0); fill(w, wd, nw, 0.5, 0); fill(b, bd, cv->OC, 0.5, 0);
        naive_conv(ref, xd, wd, bd, cv);
        REQUIRE(conv2d_forward(o, x, w, b, cv, NULL) == MLB_OK);
        REQUIRE(conv2d_forward_f64(od, xd, wd, bd, cv, NULL) == MLB_OK);
        double ef = max_abs_fd(o, ref, no), ed = 0;
        for (size_t i = 0; i < no; i++) ed = fmax(ed, fabs(od[i] - ref[i]));
        CHECK_MSG(ef < 1e-5 && ed < 1e-13, "case %d: float %.3g double %.3g", t, ef, ed);
        worst_f = fmax(worst_f, ef); worst_d = fmax(worst_d, ed);
        // caller workspace and no bias
        float* ws = falloc(conv2d_workspace_size(cv));
        REQUIRE(conv2d_forward(o, x, w, NULL, cv, ws) == MLB_OK);
        naive_conv(ref, xd, wd, NULL, cv);
        CHECK(max_abs_fd(o, ref, no) < 1e-5);
        free(ws); free(x); free(w); free(b); free(o); free(xd); free(wd); free(bd); free(od); free(ref);
    }
    printf("  conv2d vs naive over %d shapes: float max abs %.3g, double %.3g\n", nc, worst_f, worst_d);
}

// Several im2col bands (the band holds ~4M elements): 64 channels, 3x3, 96 columns -> 75 rows per band.
TEST(conv2d_many_bands_and_threads) {
    mlb_conv2d cv = conv_case(1, 64, 160, 96, 8, 3, 3, 1, 1, 1, 1, 1, 1);
    size_t ni = (size_t)64 * 160 * 96, nw = (size_t)8 * 64 * 9, no = (size_t)8 * 160 * 96;
    CHECK(conv2d_workspace_size(&cv) < (size_t)64 * 9 * 160 * 96);   // banded, not the whole image
    float *x = falloc(ni), *w = falloc(nw), *o1 = falloc(no), *o2 = falloc(no);
    double *xd = dalloc(ni), *wd = dalloc(nw), *ref = dalloc(no);
    fill(x, xd, ni, 1, 0); fill(w, wd, nw, 0.1, 0);
    naive_conv(ref, xd, wd, NULL, &cv);
    int threads = mlb_get_threads();
    mlb_set_threads(1);
    REQUIRE(conv2d_forward(o1, x, w, NULL, &cv, NULL) == MLB_OK);
    float *dx1 = falloc(ni), *dw1 = falloc(nw), *dx2 = falloc(ni), *dw2 = falloc(nw);
    REQUIRE(conv2d_backward(dx1, dw1, NULL, o1, x, w, &cv, NULL) == MLB_OK);
    mlb_set_threads(2);
    REQUIRE(conv2d_forward(o2, x, w, NULL, &cv, NULL) == MLB_OK);
    REQUIRE(conv2d_backward(dx2, dw2, NULL, o1, x, w, &cv, NULL) == MLB_OK);
    mlb_set_threads(threads);
    double e = max_abs_fd(o1, ref, no);
    printf("  3 bands: float vs naive max abs %.3g (|ref| max %.3g)\n", e, max_abs(ref, no));
    CHECK(e < 1e-4);
    CHECK(memcmp(o1, o2, no * sizeof(float)) == 0);
    CHECK(memcmp(dx1, dx2, ni * sizeof(float)) == 0);
    CHECK(memcmp(dw1, dw2, nw * sizeof(float)) == 0);
    free(x); free(w); free(o1); free(o2); free(xd); free(wd); free(ref); free(dx1); free(dw1); free(dx2); free(dw2);
}

// L = sum(out * R); gradients by central differences in double.
TEST(conv2d_backward_fd) {
    int nc;
    const mlb_conv2d* cases = conv_cases(&nc);
    double worst = 0;
    for (int t = 0; t < nc; t++) {
        const mlb_conv2d* cv = &cases[t];
        size_t ni = (size_t)cv->N * cv->C * cv->H * cv->W, nw = (size_t)cv->OC * cv->C * cv->KH * cv->KW;
        size_t no = (size_t)cv->N * cv->OC * mlb_conv2d_out_h(cv) * mlb_conv2d_out_w(cv);
        double *x = dalloc(ni), *w = dalloc(nw), *b = dalloc(cv->OC), *R = dalloc(no), *o = dalloc(no);
        double *dx = dalloc(ni), *dw = dalloc(nw), *db = dalloc(cv->OC);
        fill(NULL, x, ni, 1, 0); fill(NULL, w, nw, 0.5, 0); fill(NULL, b, cv->OC, 0.5, 0); fill(NULL, R, no, 1, 0);
        // accumulation: start from 1 and subtract it afterwards
        for (size_t i = 0; i < ni; i++) dx[i] = 1;
        for (size_t i = 0; i < nw; i++) dw[i] = 1;
        for (int i = 0; i < cv->OC; i++) db[i] = 1;
        REQUIRE(conv2d_backward_f64(dx, dw, db, R, x, w, cv, NULL) == MLB_OK);
        const double h = 1e-6;
        double err = 0;
        struct { double* p; double* g; size_t n; } groups[3] = {{x, dx, ni}, {w, dw, nw}, {b, db, (size_t)cv->OC}};
        for (int gi = 0; gi < 3; gi++)
            for (size_t i = 0; i < groups[gi].n; i++) {
                double keep = groups[gi].p[i];
                groups[gi].p[i] = keep + h;
                conv2d_forward_f64(o, x, w, b, cv, NULL);
                double lp = dot(o, R, no);
                groups[gi].p[i] = keep - h;
                conv2d_forward_f64(o, x, w, b, cv, NULL);
                double lm = dot(o, R, no);
                groups[gi].p[i] = keep;
                double fd = (lp - lm) / (2 * h), an = groups[gi].g[i] - 1;
                err = fmax(err, fabs(fd - an) / (1 + fabs(fd)));
            }
        CHECK_MSG(err < 1e-7, "case %d: relative error %.3g", t, err);
        worst = fmax(worst, err);
        free(x); free(w); free(b); free(R); free(o); free(dx); free(dw); free(db);
    }
    printf("  conv2d backward vs finite differences (double), %d shapes: max rel %.3g\n", nc, worst);
}

TEST(conv2d_float_vs_double_backward) {
    mlb_conv2d cv = conv_case(2, 6, 10, 9, 7, 3, 3, 2, 2, 0, 0, 1, 1);
    size_t ni = (size_t)2 * 6 * 10 * 9, nw = (size_t)7 * 6 * 9, no = (size_t)2 * 7 * 5 * 5;
    float *x = falloc(ni), *w = falloc(nw), *R = falloc(no), *dx = falloc(ni), *dw = falloc(nw), *db = falloc(7);
    double *xd = dalloc(ni), *wd = dalloc(nw), *Rd = dalloc(no), *dxd = dalloc(ni), *dwd = dalloc(nw), *dbd = dalloc(7);
    fill(x, xd, ni, 1, 0); fill(w, wd, nw, 0.5, 0); fill(R, Rd, no, 1, 0);
    REQUIRE(conv2d_backward(dx, dw, db, R, x, w, &cv, NULL) == MLB_OK);
    REQUIRE(conv2d_backward_f64(dxd, dwd, dbd, Rd, xd, wd, &cv, NULL) == MLB_OK);
    double ex = max_abs_fd(dx, dxd, ni), ew = max_abs_fd(dw, dwd, nw), eb = max_abs_fd(db, dbd, 7);
    printf("  conv2d backward float vs double: din %.3g, dweight %.3g, dbias %.3g\n", ex, ew, eb);
    CHECK(ex < 1e-5 && ew < 1e-4 && eb < 1e-5);
    free(x); free(w); free(R); free(dx); free(dw); free(db); free(xd); free(wd); free(Rd); free(dxd); free(dwd); free(dbd);
}

// ---- group norm ----------------------------------------------------------------------------------
static void naive_groupnorm(double* out, const double* in, const double* w, const double* b, int N, int C, int HW,
                            int G, double eps, int silu) {
    int Cg = C / G;
    for (int n = 0; n < N; n++)
        for (int g = 0; g < G; g++) {
            const double* x = in + ((size_t)n * C + (size_t)g * Cg) * HW;
            double m = 0, v = 0;
            size_t M = (size_t)Cg * HW;
            for (size_t i = 0; i < M; i++) m += x[i];
            m /= M;
            for (size_t i = 0; i < M; i++) v += (x[i] - m) * (x[i] - m);
            v /= M;
            for (int cc = 0; cc < Cg; cc++)
                for (int p = 0; p < HW; p++) {
                    int c = g * Cg + cc;
                    double y = (x[(size_t)cc * HW + p] - m) / sqrt(v + eps) * (w ? w[c] : 1) + (b ? b[c] : 0);
                    out[((size_t)n * C + c) * HW + p] = silu ? y / (1 + exp(-y)) : y;
                }
        }
}

TEST(groupnorm_forward_and_fd) {
    enum { N = 2, C = 12, HW = 10, G = 4 };
    const size_t n = (size_t)N * C * HW;
    double worst_fd = 0, worst_fwd = 0;
    for (int silu = 0; silu <= 1; silu++)
        for (int affine = 0; affine <= 1; affine++) {
            mlb_activation act = silu ? MLB_ACT_SILU : MLB_ACT_IDENTITY;
            double x[n], w[C], b[C], R[n], o[n], ref[n], dx[n], dw[C], db[C], mean[N * G], rstd[N * G];
            float xf[n], of[n];
            fill(xf, x, n, 2, 5); fill(NULL, w, C, 0.5, 1); fill(NULL, b, C, 0.5, 0); fill(NULL, R, n, 1, 0);
            const double* wp = affine ? w : NULL;
            const double* bp = affine ? b : NULL;
            REQUIRE(groupnorm_forward_f64(o, mean, rstd, x, wp, bp, N, C, HW, G, 1e-6, act) == MLB_OK);
            naive_groupnorm(ref, x, wp, bp, N, C, HW, G, 1e-6, silu);
            for (size_t i = 0; i < n; i++) worst_fwd = fmax(worst_fwd, fabs(o[i] - ref[i]));
            float wf[C], bf[C];
            for (int c = 0; c < C; c++) { wf[c] = (float)w[c]; bf[c] = (float)b[c]; }
            REQUIRE(groupnorm_forward(of, NULL, NULL, xf, affine ? wf : NULL, affine ? bf : NULL, N, C, HW, G, 1e-6f,
                                      act) == MLB_OK);
            CHECK(max_abs_fd(of, ref, n) < 2e-5);
            for (size_t i = 0; i < n; i++) dx[i] = 0.5;
            for (int c = 0; c < C; c++) dw[c] = db[c] = 0.5;
            REQUIRE(groupnorm_backward_f64(dx, affine ? dw : NULL, affine ? db : NULL, R, x, wp, bp, mean, rstd, N, C,
                                           HW, G, act) == MLB_OK);
            const double h = 1e-6;
            double err = 0;
            for (int gi = 0; gi < (affine ? 3 : 1); gi++) {
                double* p = gi == 0 ? x : gi == 1 ? w : b;
                double* g = gi == 0 ? dx : gi == 1 ? dw : db;
                size_t cnt = gi == 0 ? n : C;
                for (size_t i = 0; i < cnt; i++) {
                    double keep = p[i];
                    p[i] = keep + h;
                    groupnorm_forward_f64(o, NULL, NULL, x, wp, bp, N, C, HW, G, 1e-6, act);
                    double lp = dot(o, R, n);
                    p[i] = keep - h;
                    groupnorm_forward_f64(o, NULL, NULL, x, wp, bp, N, C, HW, G, 1e-6, act);
                    double lm = dot(o, R, n);
                    p[i] = keep;
                    double fd = (lp - lm) / (2 * h);
                    err = fmax(err, fabs(fd - (g[i] - 0.5)) / (1 + fabs(fd)));
                }
            }
            CHECK_MSG(err < 1e-7, "silu %d affine %d: relative error %.3g", silu, affine, err);
            worst_fd = fmax(worst_fd, err);
        }
    printf("  group norm: forward vs naive %.3g (double); backward vs FD max rel %.3g\n", worst_fwd, worst_fd);
    CHECK(worst_fwd < 1e-12);
}

// ---- upsample and transpose ----------------------------------------------------------------------
TEST(upsample_and_transpose) {
    enum { N = 2, C = 3, H = 4, W = 5 };
    const size_t n = (size_t)N * C * H * W;
    double x[n], up[4 * n], R[4 * n], dx[n];
    fill(NULL, x, n, 1, 0); fill(NULL, R, 4 * n, 1, 0);
    upsample_nearest2x_forward_f64(up, x, N, C, H, W);
    int ok = 1;
    for (int nc = 0; nc < N * C; nc++)
        for (int y = 0; y < 2 * H; y++)
            for (int xx = 0; xx < 2 * W; xx++)
                ok &= up[((size_t)nc * 2 * H + y) * 2 * W + xx] == x[((size_t)nc * H + y / 2) * W + xx / 2];
    CHECK(ok);
    for (size_t i = 0; i < n; i++) dx[i] = 0.25;
    upsample_nearest2x_backward_f64(dx, R, N, C, H, W);   // linear: the gradient is exact
    double err = 0;
    for (size_t i = 0; i < n; i++) {
        double e = 0;   // d(sum up*R)/dx_i = the sum of R over the 2x2 block that copies x_i
        int nc = (int)(i / (H * W)), y = (int)(i / W % H), xx = (int)(i % W);
        for (int a = 0; a < 2; a++)
            for (int c = 0; c < 2; c++) e += R[((size_t)nc * 2 * H + 2 * y + a) * 2 * W + 2 * xx + c];
        err = fmax(err, fabs(dx[i] - 0.25 - e));
    }
    CHECK(err < 1e-14);
    float xf[n], upf[4 * n];
    fill(xf, NULL, n, 1, 0);
    upsample_nearest2x_forward(upf, xf, N, C, H, W);
    CHECK(upf[2 * W * 2 + 1] == xf[W]);
    // transpose [N, R, S] -> [N, S, R], then add back
    enum { TR = 37, TS = 45 };
    static float a[2 * TR * TS], bt[2 * TR * TS], c2[2 * TR * TS];
    fill(a, NULL, 2 * TR * TS, 1, 0);
    transpose_last2(bt, a, 2, TR, TS, 0);
    ok = 1;
    for (int nn = 0; nn < 2; nn++)
        for (int r = 0; r < TR; r++)
            for (int s = 0; s < TS; s++) ok &= bt[((size_t)nn * TS + s) * TR + r] == a[((size_t)nn * TR + r) * TS + s];
    CHECK(ok);
    for (int i = 0; i < 2 * TR * TS; i++) c2[i] = 1;
    transpose_last2(c2, bt, 2, TS, TR, 1);
    ok = 1;
    for (int i = 0; i < 2 * TR * TS; i++) ok &= c2[i] == 1 + a[i];
    CHECK(ok);
}

// ---- attention -----------------------------------------------------------------------------------
static void naive_sdpa(double* out, const double* q, const double* k, const double* v, int B, int Tq, int Tk, int C,
                       int NH, int ldq, int ldkv) {
    int hd = C / NH;
    double* s = dalloc(Tk);
    for (int b = 0; b < B; b++)
        for (int h = 0; h < NH; h++)
            for (int t = 0; t < Tq; t++) {
                double mx = -1e300, sum = 0;
                for (int u = 0; u < Tk; u++) {
                    double d = 0;
                    for (int i = 0; i < hd; i++)
                        d += q[((size_t)b * Tq + t) * ldq + h * hd + i] * k[((size_t)b * Tk + u) * ldkv + h * hd + i];
                    s[u] = d / sqrt((double)hd);
                    mx = fmax(mx, s[u]);
                }
                for (int u = 0; u < Tk; u++) { s[u] = exp(s[u] - mx); sum += s[u]; }
                for (int i = 0; i < hd; i++) {
                    double o = 0;
                    for (int u = 0; u < Tk; u++) o += s[u] / sum * v[((size_t)b * Tk + u) * ldkv + h * hd + i];
                    out[((size_t)b * Tq + t) * C + h * hd + i] = o;
                }
            }
    free(s);
}

// Self-attention with a fused qkv (stride 3C) and cross-attention with separate buffers; one case
// with more queries than fit one score block (Tk = 1100 -> 953 rows per block).
TEST(sdpa_forward_backward) {
    struct { int B, Tq, Tk, C, NH, fused; } cases[] = {{2, 7, 7, 8, 2, 1}, {1, 5, 9, 12, 3, 0}, {1, 1100, 1100, 4, 1, 1}};
    for (int ci = 0; ci < 3; ci++) {
        int B = cases[ci].B, Tq = cases[ci].Tq, Tk = cases[ci].Tk, C = cases[ci].C, NH = cases[ci].NH;
        int fused = cases[ci].fused;
        int ldq = fused ? 3 * C : C, ldkv = fused ? 3 * C : C;
        size_t nq = (size_t)B * Tq * ldq, nkv = fused ? 0 : (size_t)B * Tk * ldkv, no = (size_t)B * Tq * C;
        double* qbuf = dalloc(nq);
        double* kvbuf = fused ? NULL : dalloc(2 * nkv);
        fill(NULL, qbuf, nq, 1.5, 0);
        if (!fused) fill(NULL, kvbuf, 2 * nkv, 1.5, 0);
        double* q = qbuf;
        double* k = fused ? qbuf + C : kvbuf;
        double* v = fused ? qbuf + 2 * C : kvbuf + nkv;
        double *o = dalloc(no), *ref = dalloc(no), *lse = dalloc((size_t)B * NH * Tq), *R = dalloc(no);
        REQUIRE(sdpa_forward_f64(o, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL) == MLB_OK);
        naive_sdpa(ref, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv);
        double ef = 0;
        for (size_t i = 0; i < no; i++) ef = fmax(ef, fabs(o[i] - ref[i]));
        CHECK_MSG(ef < 1e-13, "case %d forward: %.3g", ci, ef);
        // float agreement
        float* qf = falloc(nq + 2 * nkv);
        float* of = falloc(no);
        for (size_t i = 0; i < nq; i++) qf[i] = (float)qbuf[i];
        for (size_t i = 0; i < 2 * nkv; i++) qf[nq + i] = (float)kvbuf[i];
        // the float pass's softmax every way the CPU has: libm's exp, the AVX2 and the AVX-512 rows
        double eff = 0;
        for (int vec = MLB_SIMD_SCALAR; vec <= MLB_SIMD_AVX512; vec++) {
            mlb_simd_force(vec);
            if ((int)mlb_simd_kernels() != vec) break;
            REQUIRE(sdpa_forward(of, NULL, qf, fused ? qf + C : qf + nq, fused ? qf + 2 * C : qf + nq + nkv, B, Tq,
                                 Tk, C, NH, ldq, ldkv, NULL) == MLB_OK);
            double e = max_abs_fd(of, ref, no);
            CHECK_MSG(e < 1e-5, "case %d float forward (%s softmax): %.3g", ci, mlb_simd_name(vec), e);
            eff = fmax(eff, e);
        }
        mlb_simd_force(-1);
        // backward: L = sum(out * R)
        fill(NULL, R, no, 1, 0);
        double* dqbuf = dalloc(nq);
        double* dkvbuf = fused ? NULL : dalloc(2 * nkv);
        double* dq = dqbuf;
        double* dk = fused ? dqbuf + C : dkvbuf;
        double* dv = fused ? dqbuf + 2 * C : dkvbuf + nkv;
        REQUIRE(sdpa_backward_f64(dq, dk, dv, R, o, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL) == MLB_OK);
        const double h = 1e-6;
        double err = 0;
        int checks = 0;
        for (int which = 0; which < 3; which++) {   // q, k, v entries
            int T = which == 0 ? Tq : Tk, ld = which == 0 ? ldq : ldkv;
            double* base = which == 0 ? q : which == 1 ? k : v;
            double* grad = which == 0 ? dq : which == 1 ? dk : dv;
            int n_try = ci == 2 ? 12 : B * T * C;
            for (int e = 0; e < n_try; e++) {
                int idx = ci == 2 ? (int)((urand() + 1) * 0.5 * (B * T * C)) % (B * T * C) : e;
                size_t at = (size_t)(idx / C) * ld + idx % C;
                double keep = base[at];
                base[at] = keep + h;
                sdpa_forward_f64(o, NULL, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL);
                double lp = dot(o, R, no);
                base[at] = keep - h;
                sdpa_forward_f64(o, NULL, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL);
                double lm = dot(o, R, no);
                base[at] = keep;
                double fd = (lp - lm) / (2 * h);
                err = fmax(err, fabs(fd - grad[at]) / (1 + fabs(fd)));
                checks++;
            }
        }
        printf("  attention case %d (B %d, Tq %d, Tk %d, C %d, %d heads%s): forward %.3g (float %.3g), backward vs FD "
               "max rel %.3g over %d entries\n", ci, B, Tq, Tk, C, NH, fused ? ", fused qkv" : "", ef, eff, err, checks);
        CHECK_MSG(err < 1e-7, "case %d backward: %.3g", ci, err);
        free(qbuf); free(kvbuf); free(o); free(ref); free(lse); free(R); free(qf); free(of); free(dqbuf); free(dkvbuf);
    }
}

// The float pass (its scalar loops, and simd_rows.inc in 8 and 16 lanes where the CPU has them)
// against the double one: forward, input gradient and the affine's gradients, ragged and VAE-sized groups.
TEST(groupnorm_float_paths_vs_double) {
    static const int shapes[][4] = {{2, 12, 10, 4}, {1, 8, 37, 2}, {1, 4, 1, 2}, {2, 64, 4096, 32}, {1, 6, 17, 1}};
    for (int vec = MLB_SIMD_SCALAR; vec <= MLB_SIMD_AVX512; vec++) {
        mlb_simd_force(vec);
        if ((int)mlb_simd_kernels() != vec) {
            printf("  group norm: no %s here, that path not run\n", mlb_simd_name(vec));
            break;
        }
        double worst_fwd = 0, worst_bwd = 0;
        for (size_t si = 0; si < sizeof shapes / sizeof shapes[0]; si++)
            for (int silu = 0; silu <= 1; silu++)
                for (int affine = 0; affine <= 1; affine++) {
                    const int N = shapes[si][0], C = shapes[si][1], HW = shapes[si][2], G = shapes[si][3];
                    const size_t n = (size_t)N * C * HW;
                    mlb_activation act = silu ? MLB_ACT_SILU : MLB_ACT_IDENTITY;
                    double *x = dalloc(n), *o = dalloc(n), *R = dalloc(n), *dx = dalloc(n), *w = dalloc(C), *b = dalloc(C);
                    double *dw = dalloc(C), *db = dalloc(C), *mean = dalloc(N * G), *rstd = dalloc(N * G);
                    float *xf = falloc(n), *of = falloc(n), *Rf = falloc(n), *dxf = falloc(n), *wf = falloc(C),
                          *bf = falloc(C), *dwf = falloc(C), *dbf = falloc(C), *meanf = falloc(N * G), *rstdf = falloc(N * G);
                    fill(xf, x, n, 2, 5); fill(wf, w, C, 0.5, 1); fill(bf, b, C, 0.5, 0); fill(Rf, R, n, 1, 0);
                    const double *wp = affine ? w : NULL, *bp = affine ? b : NULL;
                    const float *wfp = affine ? wf : NULL, *bfp = affine ? bf : NULL;
                    for (size_t i = 0; i < n; i++) { dx[i] = 0.25; dxf[i] = 0.25f; }
                    REQUIRE(groupnorm_forward_f64(o, mean, rstd, x, wp, bp, N, C, HW, G, 1e-6, act) == MLB_OK);
                    REQUIRE(groupnorm_forward(of, meanf, rstdf, xf, wfp, bfp, N, C, HW, G, 1e-6f, act) == MLB_OK);
                    double e = 0;
                    for (size_t i = 0; i < n; i++) e = fmax(e, fabs(of[i] - o[i]) / (1 + fabs(o[i])));
                    for (int i = 0; i < N * G; i++)
                        e = fmax(e, fmax(fabs(meanf[i] - mean[i]) / mean[i], fabs(rstdf[i] - rstd[i]) / rstd[i]));
                    CHECK_MSG(e < 1e-6, "vec %d shape %zu silu %d affine %d: forward %.3g", vec, si, silu, affine, e);
                    worst_fwd = fmax(worst_fwd, e);
                    REQUIRE(groupnorm_backward_f64(dx, affine ? dw : NULL, affine ? db : NULL, R, x, wp, bp, mean, rstd, N,
                                                   C, HW, G, act) == MLB_OK);
                    REQUIRE(groupnorm_backward(dxf, affine ? dwf : NULL, affine ? dbf : NULL, Rf, xf, wfp, bfp, meanf,
                                               rstdf, N, C, HW, G, act) == MLB_OK);
                    // dx = rstd (gy w - mean(gy w) - xhat mean(gy w xhat)) cancels: its rounding scales with
                    // the size of the terms, rstd |dout| |w| (a group of 2 close values has a large rstd)
                    double scale = max_abs(rstd, N * G) * max_abs(R, n) * (affine ? max_abs(w, C) : 1), eb = 0;
                    for (size_t i = 0; i < n; i++) eb = fmax(eb, fabs(dxf[i] - dx[i]) / scale);
                    if (affine) {
                        double sw = max_abs(dw, C), sb = max_abs(db, C);
                        for (int c = 0; c < C; c++) eb = fmax(eb, fmax(fabs(dwf[c] - dw[c]) / sw, fabs(dbf[c] - db[c]) / sb));
                    }
                    CHECK_MSG(eb < 4e-6, "vec %d shape %zu silu %d affine %d: backward %.3g", vec, si, silu, affine, eb);
                    worst_bwd = fmax(worst_bwd, eb);
                    free(x); free(o); free(R); free(dx); free(w); free(b); free(dw); free(db); free(mean); free(rstd);
                    free(xf); free(of); free(Rf); free(dxf); free(wf); free(bf); free(dwf); free(dbf); free(meanf); free(rstdf);
                }
        printf("  group norm, float %s vs double: forward %.3g, backward %.3g (relative)\n", mlb_simd_name(vec),
               worst_fwd, worst_bwd);
    }
    mlb_simd_force(-1);
}

// The vectorised rows' exp (simd_rows.inc) against libm's in double, for every kernel the CPU has:
// ragged lengths, scores down to 100 below the max, where e^x is subnormal and rounded once.
TEST(softmax_rows_vs_double) {
    static const int lengths[] = {1, 7, 8, 9, 17, 203};
    float q[203], p[203];
    for (int i = 0; i < 203; i++) q[i] = -100.0f * (float)((i * 37) % 203) / 202.0f + 0.25f;   // max 0.25 at i 0
    int levels = 0;
    for (int lv = MLB_SIMD_AVX2; lv <= MLB_SIMD_AVX512; lv++) {
        mlb_simd_force(lv);
        if ((int)mlb_simd_kernels() != lv) break;
        levels++;
        double worst = 0;
        for (size_t li = 0; li < sizeof lengths / sizeof lengths[0]; li++) {
            const int n = lengths[li];
            memcpy(p, q, sizeof p);
            float sum, mx = mlb_softmax_row((mlb_simd_level)lv, p, n, &sum);
            CHECK_MSG(mx == 0.25f, "%s n %d: max %g", mlb_simd_name(lv), n, mx);
            double ref_sum = 0;
            for (int i = 0; i < n; i++) {
                double t = exp((double)q[i] - (double)mx);
                ref_sum += t;
                double err = fabs((double)p[i] - t);
                // relative 1e-6 (polynomial 1.3e-7 + the fp32 steps), plus half the smallest subnormal
                CHECK_MSG(err <= 1e-6 * t + 0x1p-150, "%s n %d, i %d: e^%g = %.9g, libm %.9g", mlb_simd_name(lv), n, i,
                          (double)q[i] - mx, p[i], t);
                if (t >= 0x1p-126) worst = fmax(worst, err / t);
            }
            for (int i = n; i < 203; i++) CHECK_MSG(p[i] == q[i], "%s n %d: wrote past the row at %d", mlb_simd_name(lv), n, i);
            CHECK_MSG(fabs(sum - ref_sum) <= 1e-6 * ref_sum, "%s n %d: sum %.9g, libm %.9g", mlb_simd_name(lv), n, sum,
                      ref_sum);
        }
        printf("  softmax rows, %s: exp within %.3g (relative) of libm's over [-100, 0]\n", mlb_simd_name(lv), worst);
    }
    if (!levels) printf("  softmax rows: no AVX2 here, not run\n");
    mlb_simd_force(-1);
}

// GEGLU's rows (simd_rows.inc, Φ from a fit of erfc) against GELU in double with libm's erfc, for
// every kernel the CPU has: forward and both input gradients, ragged rows, gates far into both tails.
TEST(geglu_rows_vs_double) {
    enum { N = 203 };
    float a[N], g[N], d[N], out[N], da[N], dg[N];
    for (int j = 0; j < N; j++) {
        g[j] = -12.0f + 24.0f * (float)((j * 53) % N) / (float)(N - 1);
        a[j] = (0.5f + (float)(j % 7) * 0.25f) * (j % 2 ? -1.0f : 1.0f);   // never 0
        d[j] = 1.0f - (float)(j % 5) * 0.3f;
    }
    int levels = 0;
    for (int lv = MLB_SIMD_AVX2; lv <= MLB_SIMD_AVX512; lv++) {
        mlb_simd_force(lv);
        if ((int)mlb_simd_kernels() != lv) break;
        levels++;
        double wf = 0, wb = 0;
        for (int n = 1; n <= N; n += n < 20 ? 1 : 61) {
            for (int j = 0; j < N; j++) { out[j] = -7; da[j] = 0.5f; dg[j] = -0.25f; }
            mlb_geglu_row((mlb_simd_level)lv, out, a, g, n);
            mlb_geglu_backward_row((mlb_simd_level)lv, da, dg, d, a, g, n);
            for (int j = 0; j < n; j++) {
                double x = g[j], cdf = 0.5 * erfc(-x / sqrt(2.0)), pdf = exp(-0.5 * x * x) / sqrt(2 * M_PI);
                double ef = fabs(out[j] - a[j] * x * cdf) / (fabs(a[j]) * (1 + fabs(x)));
                double eda = fabs(da[j] - (0.5 + d[j] * x * cdf)) / (fabs(d[j]) * (1 + fabs(x)) + 1);
                double edg = fabs(dg[j] - (-0.25 + d[j] * a[j] * (cdf + x * pdf))) / (fabs(d[j] * a[j]) * (1 + fabs(x)) + 1);
                CHECK_MSG(ef < 1e-6 && eda < 1e-6 && edg < 1e-6, "%s n %d gate %g: forward %.3g, da %.3g, dgate %.3g",
                          mlb_simd_name(lv), n, x, ef, eda, edg);
                wf = fmax(wf, ef);
                wb = fmax(wb, fmax(eda, edg));
                // the left tail keeps its relative accuracy (Φ(-12) ~ 2e-33 is a normal float), up to the
                // rounding of the exponent -x²/2 - 1.27 + P(t) (about an ulp of it: 1.5e-6 at x = -5, 9e-6 at -12)
                if (x < 0) CHECK_MSG(fabs(out[j] / (a[j] * x * cdf) - 1) < 4e-7 + 1.2e-7 * 0.5 * x * x,
                                     "%s gate %g: tail %.9g vs %.9g", mlb_simd_name(lv), x, out[j], a[j] * x * cdf);
            }
            for (int j = n; j < N; j++)
                CHECK_MSG(out[j] == -7 && da[j] == 0.5f && dg[j] == -0.25f, "%s n %d: wrote past the row", mlb_simd_name(lv), n);
        }
        printf("  GEGLU rows, %s: forward within %.3g, backward %.3g (relative to the terms) of double\n",
               mlb_simd_name(lv), wf, wb);
    }
    if (!levels) printf("  GEGLU rows: no AVX2 here, not run\n");
    mlb_simd_force(-1);
}

TEST(error_messages) {
    mlb_conv2d cv = conv_case(1, 2, 1, 1, 3, 3, 3, 1, 1, 0, 0, 0, 0);
    float x[2] = {0}, w[54] = {0}, o[27];
    CHECK(conv2d_forward(o, x, w, NULL, &cv, NULL) == MLB_ERR_ARG);
    CHECK(!strcmp(mlb_last_error(), "conv2d: kernel 3x3 does not fit the padded input 1x1 (pad 0,0,0,0)"));
    cv = conv_case(1, 2, 4, 4, 3, 3, 3, 0, 1, 1, 1, 1, 1);
    CHECK(mlb_conv2d_check(&cv) == MLB_ERR_ARG);
    CHECK(!strcmp(mlb_last_error(), "conv2d: stride 0x1 must be at least 1"));
    cv = conv_case(1, 2, 4, 4, 3, 3, 3, 1, 1, -1, 1, 1, 1);
    CHECK(mlb_conv2d_check(&cv) == MLB_ERR_ARG);
    CHECK(!strcmp(mlb_last_error(), "conv2d: negative padding -1,1,1,1 (top, left, bottom, right)"));
    CHECK(conv2d_workspace_size(&cv) == 0);
    CHECK(groupnorm_forward(o, NULL, NULL, x, NULL, NULL, 1, 6, 1, 4, 1e-6f, MLB_ACT_IDENTITY) == MLB_ERR_ARG);
    CHECK(!strcmp(mlb_last_error(), "group norm: 6 channels are not a multiple of the 4 groups"));
    CHECK(sdpa_forward(o, NULL, x, x, x, 1, 1, 1, 6, 4, 6, 6, NULL) == MLB_ERR_ARG);
    CHECK(!strcmp(mlb_last_error(), "attention: width 6 is not a multiple of the 4 heads"));
    CHECK(sdpa_forward(o, NULL, x, x, x, 1, 2, 0, 4, 1, 4, 4, NULL) == MLB_ERR_ARG);
    CHECK(!strcmp(mlb_last_error(), "attention: 2 queries but no keys"));
    mlb_conv2d m = mlb_conv2d_make(2, 3, 8, 8, 4, 3, 2, 1);
    CHECK(m.KH == 3 && m.KW == 3 && m.stride_h == 2 && m.pad_right == 1 && mlb_conv2d_out_h(&m) == 4);
}

int main(void) {
    RUN(conv2d_forward_matches_naive);
    RUN(conv2d_many_bands_and_threads);
    RUN(conv2d_backward_fd);
    RUN(conv2d_float_vs_double_backward);
    RUN(groupnorm_forward_and_fd);
    RUN(groupnorm_float_paths_vs_double);
    RUN(upsample_and_transpose);
    RUN(sdpa_forward_backward);
    RUN(softmax_rows_vs_double);
    RUN(geglu_rows_vs_double);
    RUN(error_messages);
    return test_summary();
}
