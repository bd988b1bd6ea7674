// Tests of src/nn/ops.c: every backward against central finite differences in double (the _f64
// variants), activation derivatives against finite differences over a wide range of x, float
// against double, known values, Adam/AdamW against a naive reference, and thread-count
// independence. Method and tolerances: docs/ops.md.
#include "test.h"
#include "matlaber/backend.h"
#include "matlaber/nn.h"
#include "matlaber/rng.h"
#include "nn/simd_rows.h"
#include <cblas.h>
#include <float.h>
#include <omp.h>
#include <stdint.h>

#define SEED 20240611u
#define FD_H 1e-6          // central-difference step (relative to max(1, |x|) for scalar checks)
#define FD_RTOL 1e-7       // relative tolerance of analytic vs FD gradients
#define F32_RTOL 1e-5      // float vs double

static const double fd_points[] = {-1000, -300, -50, -20, -7.5, -3.3, -1.7, -0.9, -0.31, -1e-3,
                                   1e-3, 0.27, 0.8, 1.6, 3.1, 7.9, 21, 49, 310, 1000};
#define N_FD_POINTS (sizeof fd_points / sizeof fd_points[0])

static void fill_normal(double* x, size_t n, uint64_t stream, double scale) {
    for (size_t i = 0; i < n; i++) x[i] = scale * mlb_rng_normal_f64(SEED, stream, i);
}
static void to_float(float* dst, const double* src, size_t n) {
    for (size_t i = 0; i < n; i++) dst[i] = (float)src[i];
}
static void to_double(double* dst, const float* src, size_t n) {
    for (size_t i = 0; i < n; i++) dst[i] = (double)src[i];
}
static double* dalloc(size_t n) { return calloc(n ? n : 1, sizeof(double)); }
static float* falloc(size_t n) { return calloc(n ? n : 1, sizeof(float)); }

// One analytic-vs-FD comparison. atol carries the rounding error of the FD itself
// (~eps |L| / h); a failure prints the first few offenders only.
static int n_grad_checked, n_grad_failed;
static double worst_ratio;   // max |analytic - fd| / tolerance: how much headroom is left
static void check_grad(const char* what, size_t i, double analytic, double fd, double rtol, double atol) {
    n_grad_checked++;
    double tol = rtol * fabs(fd) + atol;
    if (tol > 0) worst_ratio = fmax(worst_ratio, fabs(analytic - fd) / tol);
    if (fabs(analytic - fd) <= tol && !isnan(analytic)) return;
    if (n_grad_failed++ < 10)
        printf("  %s: %s[%zu]: analytic %.12g, finite difference %.12g (rtol %g, atol %g)\n",
               test_case_name, what, i, analytic, fd, rtol, atol);
    test_case_failed = 1;
}

// ---------------------------------------------------------------------------------------------
// linear

// L = sum_i w_i out_i, out = linear(in, weight, bias); *scale = sum_i |w_i out_i| (FD rounding size)
static double linear_functional(const double* in, const double* weight, const double* bias,
                                const double* w, int B, int C, int OC, double* scale) {
    double* out = dalloc((size_t)B * OC);
    linear_forward_f64(out, in, weight, bias, B, C, OC);
    double L = 0, s = 0;
    for (int i = 0; i < B * OC; i++) { L += w[i] * out[i]; s += fabs(w[i] * out[i]); }
    free(out);
    if (scale) *scale = s + 1;
    return L;
}

// The gradient of L wrt every entry of x (in, weight or bias) by central differences vs `grad`.
static void fd_linear_param(const char* what, double* x, size_t n, const double* grad,
                            const double* in, const double* weight, const double* bias,
                            const double* w, int B, int C, int OC) {
    for (size_t k = 0; k < n; k++) {
        double x0 = x[k], sp, sm;
        x[k] = x0 + FD_H; double Lp = linear_functional(in, weight, bias, w, B, C, OC, &sp);
        x[k] = x0 - FD_H; double Lm = linear_functional(in, weight, bias, w, B, C, OC, &sm);
        x[k] = x0;
        double fd = (Lp - Lm) / (2 * FD_H);
        check_grad(what, k, grad[k], fd, FD_RTOL, 64 * DBL_EPSILON * (sp + sm) / (2 * FD_H));
    }
}

TEST(linear_backward_fd) {
    // OC = 70 crosses the 64-column block of the dbias reduction
    const int shapes[][3] = {{4, 5, 3}, {1, 7, 2}, {6, 1, 4}, {3, 4, 70}};
    for (size_t s = 0; s < sizeof shapes / sizeof shapes[0]; s++) {
        int B = shapes[s][0], C = shapes[s][1], OC = shapes[s][2];
        for (int use_bias = 0; use_bias < 2; use_bias++) {
            size_t nin = (size_t)B * C, nw = (size_t)OC * C, nout = (size_t)B * OC;
            double *in = dalloc(nin), *wt = dalloc(nw), *bias = dalloc(OC), *w = dalloc(nout);
            fill_normal(in, nin, 1, 1); fill_normal(wt, nw, 2, 0.5); fill_normal(bias, OC, 3, 1);
            fill_normal(w, nout, 4, 1);
            // gradient buffers pre-filled with nonzero values: backward must add to them
            double *din = dalloc(nin), *dw = dalloc(nw), *db = dalloc(OC);
            double *din0 = dalloc(nin), *dw0 = dalloc(nw), *db0 = dalloc(OC);
            fill_normal(din0, nin, 5, 1); fill_normal(dw0, nw, 6, 1); fill_normal(db0, OC, 7, 1);
            memcpy(din, din0, nin * sizeof(double)); memcpy(dw, dw0, nw * sizeof(double));
            memcpy(db, db0, OC * sizeof(double));
            const double* b = use_bias ? bias : NULL;
            linear_backward_f64(din, dw, db, w, in, wt, B, C, OC);
            for (size_t i = 0; i < nin; i++) din[i] -= din0[i];
            for (size_t i = 0; i < nw; i++) dw[i] -= dw0[i];
            for (int i = 0; i < OC; i++) db[i] -= db0[i];
            fd_linear_param("din", in, nin, din, in, wt, b, w, B, C, OC);
            fd_linear_param("dweight", wt, nw, dw, in, wt, b, w, B, C, OC);
            fd_linear_param("dbias", bias, OC, db, in, wt, bias, w, B, C, OC);
            free(in); free(wt); free(bias); free(w); free(din); free(dw); free(db);
            free(din0); free(dw0); free(db0);
        }
    }
    printf("  %d gradient entries checked, worst error/tolerance %.2g\n", n_grad_checked, worst_ratio);
}

// Every subset of {din, dweight, dbias} may be NULL; the others get the same values as in the full call.
TEST(linear_backward_null) {
    const int B = 5, C = 6, OC = 4;
    double in[30], wt[24], dout[20], full_in[30] = {0}, full_w[24] = {0}, full_b[4] = {0};
    fill_normal(in, 30, 10, 1); fill_normal(wt, 24, 11, 1); fill_normal(dout, 20, 12, 1);
    linear_backward_f64(full_in, full_w, full_b, dout, in, wt, B, C, OC);
    for (int mask = 0; mask < 8; mask++) {
        double gi[30] = {0}, gw[24] = {0}, gb[4] = {0};
        linear_backward_f64(mask & 1 ? gi : NULL, mask & 2 ? gw : NULL, mask & 4 ? gb : NULL,
                            dout, in, wt, B, C, OC);
        if (mask & 1) CHECK(memcmp(gi, full_in, sizeof gi) == 0);
        if (mask & 2) CHECK(memcmp(gw, full_w, sizeof gw) == 0);
        if (mask & 4) CHECK(memcmp(gb, full_b, sizeof gb) == 0);
    }
}

// Forward against a naive triple loop, both variants, with and without bias.
TEST(linear_forward_naive) {
    const int B = 7, C = 13, OC = 5;
    double in[91], wt[65], bias[5];
    fill_normal(in, 91, 20, 1); fill_normal(wt, 65, 21, 1); fill_normal(bias, 5, 22, 1);
    float inf_[91], wtf[65], biasf[5];
    to_float(inf_, in, 91); to_float(wtf, wt, 65); to_float(biasf, bias, 5);
    to_double(in, inf_, 91); to_double(wt, wtf, 65); to_double(bias, biasf, 5);   // same inputs
    for (int use_bias = 0; use_bias < 2; use_bias++) {
        double out[35]; float outf[35];
        linear_forward_f64(out, in, wt, use_bias ? bias : NULL, B, C, OC);
        linear_forward(outf, inf_, wtf, use_bias ? biasf : NULL, B, C, OC);
        for (int b = 0; b < B; b++)
            for (int o = 0; o < OC; o++) {
                double ref = use_bias ? bias[o] : 0, mag = fabs(ref);
                for (int c = 0; c < C; c++) { ref += in[b * C + c] * wt[o * C + c]; mag += fabs(in[b * C + c] * wt[o * C + c]); }
                CHECK_CLOSE(out[b * OC + o], ref, 0, 1e-14 * mag);
                CHECK_CLOSE(outf[b * OC + o], ref, 0, F32_RTOL * mag);
            }
    }
}

// Empty shapes: B = 0 writes nothing; C = 0 gives out = bias and backward adds only to dbias.
TEST(linear_empty_shapes) {
    double out[6] = {9, 9, 9, 9, 9, 9}, bias[3] = {1, 2, 3}, dout[6] = {1, 2, 3, 4, 5, 6};
    linear_forward_f64(out, NULL, NULL, bias, 0, 4, 3);
    CHECK(out[0] == 9 && out[5] == 9);
    linear_forward_f64(out, NULL, NULL, bias, 2, 0, 3);
    for (int i = 0; i < 6; i++) CHECK(out[i] == bias[i % 3]);
    linear_forward_f64(out, NULL, NULL, NULL, 2, 0, 3);
    for (int i = 0; i < 6; i++) CHECK(out[i] == 0);
    double db[3] = {1, 1, 1};
    linear_backward_f64(NULL, NULL, db, dout, NULL, NULL, 2, 0, 3);
    CHECK(db[0] == 6 && db[1] == 8 && db[2] == 10);
}

// Float and double variants agree on the same (float-representable) inputs, forward and backward.
TEST(linear_float_vs_double) {
    const int B = 9, C = 33, OC = 17;
    size_t nin = B * C, nw = OC * C, nout = B * OC;
    double *in = dalloc(nin), *wt = dalloc(nw), *bias = dalloc(OC), *dout = dalloc(nout);
    float *inf_ = falloc(nin), *wtf = falloc(nw), *biasf = falloc(OC), *doutf = falloc(nout);
    fill_normal(in, nin, 30, 1); fill_normal(wt, nw, 31, 1); fill_normal(bias, OC, 32, 1); fill_normal(dout, nout, 33, 1);
    to_float(inf_, in, nin); to_float(wtf, wt, nw); to_float(biasf, bias, OC); to_float(doutf, dout, nout);
    to_double(in, inf_, nin); to_double(wt, wtf, nw); to_double(bias, biasf, OC); to_double(dout, doutf, nout);
    double *out = dalloc(nout), *din = dalloc(nin), *dw = dalloc(nw), *db = dalloc(OC);
    float *outf = falloc(nout), *dinf = falloc(nin), *dwf = falloc(nw), *dbf = falloc(OC);
    linear_forward_f64(out, in, wt, bias, B, C, OC);
    linear_forward(outf, inf_, wtf, biasf, B, C, OC);
    linear_backward_f64(din, dw, db, dout, in, wt, B, C, OC);
    linear_backward(dinf, dwf, dbf, doutf, inf_, wtf, B, C, OC);
    // elementwise relative error is meaningless under cancellation: scale by the summed magnitudes
    for (size_t i = 0; i < nout; i++) CHECK_CLOSE(outf[i], out[i], F32_RTOL, F32_RTOL * sqrt(C));
    for (size_t i = 0; i < nin; i++) CHECK_CLOSE(dinf[i], din[i], F32_RTOL, F32_RTOL * sqrt(OC));
    for (size_t i = 0; i < nw; i++) CHECK_CLOSE(dwf[i], dw[i], F32_RTOL, F32_RTOL * sqrt(B));
    for (int i = 0; i < OC; i++) CHECK_CLOSE(dbf[i], db[i], F32_RTOL, F32_RTOL * sqrt(B));
    free(in); free(wt); free(bias); free(dout); free(inf_); free(wtf); free(biasf); free(doutf);
    free(out); free(din); free(dw); free(db); free(outf); free(dinf); free(dwf); free(dbf);
}

// ---------------------------------------------------------------------------------------------
// activations

// f'(x) against the FD of f, and f''(x) against the FD of f', at points from -1000 to 1000 (0 and
// its h-neighbourhood left out: the kinks of relu, leaky_relu and elu'').
TEST(activation_derivatives_fd) {
    n_grad_checked = n_grad_failed = 0;
    worst_ratio = 0;
    for (int a = 0; a < MLB_ACT_COUNT; a++) {
        char what[64];
        for (size_t k = 0; k < N_FD_POINTS; k++) {
            double x = fd_points[k], h = FD_H * fmax(1, fabs(x));
            double fp = mlb_act_f64(a, x + h), fm = mlb_act_f64(a, x - h);
            double gp = mlb_act_d1_f64(a, x + h), gm = mlb_act_d1_f64(a, x - h);
            double d1 = mlb_act_d1_f64(a, x), d2 = mlb_act_d2_f64(a, x);
            CHECK_MSG(isfinite(mlb_act_f64(a, x)) && isfinite(d1) && isfinite(d2), "%s at %g", mlb_activation_name(a), x);
            // atol: FD rounding (eps |f| / h) plus truncation (h^2 f''' / 6, f''' = O(1))
            snprintf(what, sizeof what, "%s d1 at x=%g", mlb_activation_name(a), x);
            check_grad(what, 0, d1, (fp - fm) / (2 * h), 1e-6, 64 * DBL_EPSILON * (fabs(fp) + fabs(fm)) / (2 * h) + h * h);
            snprintf(what, sizeof what, "%s d2 at x=%g", mlb_activation_name(a), x);
            check_grad(what, 0, d2, (gp - gm) / (2 * h), 1e-6, 64 * DBL_EPSILON * (fabs(gp) + fabs(gm)) / (2 * h) + h * h);
        }
    }
    printf("  %d derivative values checked, worst error/tolerance %.2g\n", n_grad_checked, worst_ratio);
}

// activation_backward: din += dout * f'(in), by FD of L = sum_i w_i f(in_i); din pre-filled; NULL din accepted.
TEST(activation_backward_fd) {
    enum { N = 64 };
    n_grad_checked = n_grad_failed = 0;
    worst_ratio = 0;
    for (int a = 0; a < MLB_ACT_COUNT; a++) {
        double in[N], w[N], din[N], din0[N], out[N];
        fill_normal(in, N, 40 + a, 3); fill_normal(w, N, 60, 1); fill_normal(din0, N, 61, 1);
        memcpy(din, din0, sizeof din);
        activation_backward_f64(din, w, in, N, a);
        activation_backward_f64(NULL, w, in, N, a);
        for (int i = 0; i < N; i++) {
            double x0 = in[i], Lp = 0, Lm = 0, s = 1;
            in[i] = x0 + FD_H; activation_forward_f64(out, in, N, a);
            for (int j = 0; j < N; j++) { Lp += w[j] * out[j]; s += fabs(w[j] * out[j]); }
            in[i] = x0 - FD_H; activation_forward_f64(out, in, N, a);
            for (int j = 0; j < N; j++) Lm += w[j] * out[j];
            in[i] = x0;
            check_grad(mlb_activation_name(a), i, din[i] - din0[i], (Lp - Lm) / (2 * FD_H), 1e-6,
                       64 * DBL_EPSILON * s / FD_H + 1e-11);
        }
        // forward in place (out aliases in) equals out of place
        double a1[N], a2[N];
        activation_forward_f64(a1, in, N, a);
        memcpy(a2, in, sizeof a2);
        activation_forward_f64(a2, a2, N, a);
        CHECK(memcmp(a1, a2, sizeof a1) == 0);
    }
    printf("  %d gradient entries checked, worst error/tolerance %.2g\n", n_grad_checked, worst_ratio);
}

TEST(activation_known_values) {
    CHECK(mlb_act_f64(MLB_ACT_SIGMOID, 0) == 0.5);
    CHECK(mlb_act(MLB_ACT_SIGMOID, 0) == 0.5f);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_SOFTPLUS, 0), log(2.0), 1e-15, 0);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_GELU, 1), 0.8413447460685429, 1e-15, 0);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_GELU_TANH, 1), 0.8411919906082768, 1e-15, 0);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_QUICK_GELU, 1), 0.8457957659328212, 1e-15, 0);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_QUICK_GELU, -2), -2 / (1 + exp(2 * 1.702)), 1e-15, 0);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_SILU, 1), 0.7310585786300049, 1e-15, 0);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_TANH, 0.5), tanh(0.5), 1e-15, 0);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_ELU, -1), exp(-1.0) - 1, 1e-15, 0);
    CHECK(mlb_act_f64(MLB_ACT_ELU, 2) == 2);
    CHECK(mlb_act_f64(MLB_ACT_RELU, -2) == 0 && mlb_act_f64(MLB_ACT_RELU, 2) == 2);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_LEAKY_RELU, -2), -0.02, 1e-15, 0);
    CHECK(mlb_act_f64(MLB_ACT_IDENTITY, -3.5) == -3.5 && mlb_act_d1_f64(MLB_ACT_IDENTITY, 7) == 1);
    // conventions at the kinks
    CHECK(mlb_act_d1_f64(MLB_ACT_RELU, 0) == 0 && mlb_act_d2_f64(MLB_ACT_RELU, 1) == 0);
    CHECK(mlb_act_d1_f64(MLB_ACT_LEAKY_RELU, 0) == 0.01 && mlb_act_d1_f64(MLB_ACT_LEAKY_RELU, 3) == 1);
    CHECK(mlb_act_d1_f64(MLB_ACT_ELU, 0) == 1 && mlb_act_d2_f64(MLB_ACT_ELU, 0) == 1);
    CHECK_CLOSE(mlb_act_d1_f64(MLB_ACT_SIGMOID, 0), 0.25, 1e-15, 0);
    CHECK_CLOSE(mlb_act_d1_f64(MLB_ACT_GELU, 0), 0.5, 1e-15, 0);
    CHECK_CLOSE(mlb_act_d2_f64(MLB_ACT_GELU, 0), 2 / sqrt(2 * M_PI), 1e-15, 0);
    // an invalid activation is loud
    CHECK(isnan(mlb_act_f64(MLB_ACT_COUNT, 1)) && isnan(mlb_act_d1(MLB_ACT_COUNT, 1)));
}

// Stability in the tails: no overflow at |x| = 1e3, and the tiny tail values keep their relative
// accuracy (where s (1 - s) or 1 - tanh^2 would round to 0).
TEST(activation_tails) {
    // f, f', f'' are all finite for finite x (|f(x)| <= |x|, the derivatives are bounded), also
    // where intermediates such as x^3 or x^2 overflow
    static const double big[] = {1e3, 1e30, 1e300};
    for (int a = 0; a < MLB_ACT_COUNT; a++)
        for (int k = 0; k < 3; k++)
            for (int s = -1; s <= 1; s += 2) {
                double x = big[k] * s;
                CHECK_MSG(isfinite(mlb_act_f64(a, x)) && isfinite(mlb_act_d1_f64(a, x)) && isfinite(mlb_act_d2_f64(a, x)),
                          "%s at %g", mlb_activation_name(a), x);
                if (k == 2) continue;   // not a float
                CHECK_MSG(isfinite(mlb_act(a, (float)x)) && isfinite(mlb_act_d1(a, (float)x)) && isfinite(mlb_act_d2(a, (float)x)),
                          "float %s at %g", mlb_activation_name(a), x);
            }
    CHECK(mlb_act_f64(MLB_ACT_SIGMOID, -1e3) == 0 && mlb_act_f64(MLB_ACT_SIGMOID, 1e3) == 1);
    CHECK(mlb_act_f64(MLB_ACT_SOFTPLUS, 1e3) == 1e3 && mlb_act(MLB_ACT_SOFTPLUS, 1e3f) == 1e3f);
    CHECK(mlb_act_f64(MLB_ACT_SOFTPLUS, -1e3) == 0);
    double e40 = exp(-40.0);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_SOFTPLUS, -40), e40, 1e-14, 0);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_SIGMOID, -40), e40, 1e-14, 0);
    CHECK_CLOSE(mlb_act_d1_f64(MLB_ACT_SIGMOID, 40), e40, 1e-14, 0);
    CHECK_CLOSE(mlb_act_d2_f64(MLB_ACT_SIGMOID, 40), -e40, 1e-14, 0);
    CHECK_CLOSE(mlb_act_d1_f64(MLB_ACT_TANH, 20), 4 * e40, 1e-14, 0);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_GELU, -10), -10 * 7.619853024160527e-24, 1e-13, 0);
    // gelu_tanh: 0.5 (1 + tanh u) = 1 / (1 + e^-2u); 1 + tanh u is 0 in double here
    double u = sqrt(2 / M_PI) * (-10 - 0.044715 * 1000);
    CHECK_CLOSE(mlb_act_f64(MLB_ACT_GELU_TANH, -10), -10 / (1 + exp(-2 * u)), 1e-13, 0);
    u = sqrt(2 / M_PI) * (-5 - 0.044715 * 125);
    CHECK_CLOSE(mlb_act(MLB_ACT_GELU_TANH, -5.f), -5 / (1 + exp(-2 * u)), F32_RTOL, 0);
    // float: exp(-30) ~ 9e-14 is far below float's 1 - s resolution
    CHECK_CLOSE(mlb_act_d1(MLB_ACT_SIGMOID, 30.f), exp(-30.0), F32_RTOL, 0);
    CHECK_CLOSE(mlb_act_d1(MLB_ACT_TANH, 15.f), 4 * exp(-30.0), F32_RTOL, 0);
    CHECK_CLOSE(mlb_act_d1(MLB_ACT_SOFTPLUS, -30.f), exp(-30.0), F32_RTOL, 0);
}

// Float and double variants agree to 1e-5 relative, plus the error a few float ulps of x would
// cause through the function's own slope (|x| |f'| 16 eps_float): some values are ill-conditioned
// (gelu_tanh at x = -8 has relative condition number ~ 50).
TEST(activation_float_vs_double) {
    static const float pts[] = {-1000, -100, -30, -20, -8, -5, -3, -1, -0.3f, 0.3f, 1, 3, 8, 20, 30, 100, 1000};
    for (int a = 0; a < MLB_ACT_COUNT; a++)
        for (size_t k = 0; k < sizeof pts / sizeof pts[0]; k++) {
            double x = pts[k], h = 1e-6 * fmax(1, fabs(x));
            double d3 = (mlb_act_d2_f64(a, x + h) - mlb_act_d2_f64(a, x - h)) / (2 * h);
            double ref[3] = {mlb_act_f64(a, x), mlb_act_d1_f64(a, x), mlb_act_d2_f64(a, x)};
            double got[3] = {mlb_act(a, pts[k]), mlb_act_d1(a, pts[k]), mlb_act_d2(a, pts[k])};
            double slope[3] = {ref[1], ref[2], d3};
            for (int d = 0; d < 3; d++) {
                double tol = F32_RTOL * fabs(ref[d]) + 16 * FLT_EPSILON * fabs(x * slope[d]) + 1e-37;
                CHECK_MSG(fabs(got[d] - ref[d]) <= tol, "%s d%d at %g: float %.9g, double %.17g",
                          mlb_activation_name(a), d, x, got[d], ref[d]);
            }
        }
}

TEST(activation_names) {
    for (int a = 0; a < MLB_ACT_COUNT; a++) {
        mlb_activation got = MLB_ACT_COUNT;
        CHECK(mlb_activation_parse(mlb_activation_name(a), &got) == 0 && got == (mlb_activation)a);
    }
    mlb_activation got = MLB_ACT_RELU;
    CHECK(mlb_activation_parse("GELU", &got) == 0 && got == MLB_ACT_GELU);
    CHECK(mlb_activation_parse("swish", &got) == 0 && got == MLB_ACT_SILU);
    CHECK(mlb_activation_parse("linear", &got) == 0 && got == MLB_ACT_IDENTITY);
    got = MLB_ACT_TANH;
    CHECK(mlb_activation_parse("gelu2", &got) != 0 && got == MLB_ACT_TANH);
    CHECK(strstr(mlb_last_error(), "gelu2") != NULL);
    CHECK(mlb_activation_parse(NULL, &got) != 0);
    CHECK(strcmp(mlb_activation_name(MLB_ACT_GELU_TANH), "gelu_tanh") == 0);
    CHECK(strcmp(mlb_activation_name(MLB_ACT_COUNT), "invalid") == 0);
}

// ---------------------------------------------------------------------------------------------
// losses

typedef double (*loss2_fn)(const double*, const double*, size_t);
typedef void (*loss2_bwd)(double*, const double*, const double*, size_t, double);

// dpred (pre-filled) += dloss * dL/dpred against dloss times the FD of the loss.
static void fd_loss2(const char* what, loss2_fn fwd, loss2_bwd bwd) {
    enum { N = 37 };
    const double dloss = 0.731;
    double pred[N], target[N], dpred[N], dpred0[N];
    fill_normal(pred, N, 70, 1); fill_normal(target, N, 71, 1); fill_normal(dpred0, N, 72, 1);
    memcpy(dpred, dpred0, sizeof dpred);
    bwd(dpred, pred, target, N, dloss);
    bwd(NULL, pred, target, N, dloss);   // NULL gradient accepted
    for (int i = 0; i < N; i++) {
        double x0 = pred[i];
        pred[i] = x0 + FD_H; double Lp = fwd(pred, target, N);
        pred[i] = x0 - FD_H; double Lm = fwd(pred, target, N);
        pred[i] = x0;
        check_grad(what, i, dpred[i] - dpred0[i], dloss * (Lp - Lm) / (2 * FD_H), FD_RTOL,
                   64 * DBL_EPSILON * fabs(Lp) / FD_H);
    }
}

TEST(loss_backward_fd) {
    n_grad_checked = n_grad_failed = 0;
    worst_ratio = 0;
    fd_loss2("mse", mse_forward_f64, mse_backward_f64);
    fd_loss2("l1", l1_forward_f64, l1_backward_f64);
    // KL over [B, D]: both inputs
    enum { B = 3, D = 5, N = B * D };
    const double dloss = -1.37;
    double mu[N], lv[N], dmu[N], dlv[N], dmu0[N], dlv0[N];
    fill_normal(mu, N, 80, 1); fill_normal(lv, N, 81, 1);
    fill_normal(dmu0, N, 82, 1); fill_normal(dlv0, N, 83, 1);
    memcpy(dmu, dmu0, sizeof dmu); memcpy(dlv, dlv0, sizeof dlv);
    kl_normal_backward_f64(dmu, dlv, mu, lv, B, D, dloss);
    kl_normal_backward_f64(NULL, NULL, mu, lv, B, D, dloss);
    for (int which = 0; which < 2; which++) {
        double* x = which ? lv : mu;
        for (int i = 0; i < N; i++) {
            double x0 = x[i];
            x[i] = x0 + FD_H; double Lp = kl_normal_forward_f64(mu, lv, B, D);
            x[i] = x0 - FD_H; double Lm = kl_normal_forward_f64(mu, lv, B, D);
            x[i] = x0;
            double analytic = which ? dlv[i] - dlv0[i] : dmu[i] - dmu0[i];
            check_grad(which ? "kl dlogvar" : "kl dmu", i, analytic, dloss * (Lp - Lm) / (2 * FD_H),
                       FD_RTOL, 64 * DBL_EPSILON * fabs(Lp) / FD_H);
        }
    }
    // one of the two KL outputs alone gets the same values
    double only_mu[N] = {0}, both_mu[N] = {0}, both_lv[N] = {0};
    kl_normal_backward_f64(only_mu, NULL, mu, lv, B, D, dloss);
    kl_normal_backward_f64(both_mu, both_lv, mu, lv, B, D, dloss);
    CHECK(memcmp(only_mu, both_mu, sizeof only_mu) == 0);
    printf("  %d gradient entries checked, worst error/tolerance %.2g\n", n_grad_checked, worst_ratio);
}

TEST(loss_known_values) {
    double p[3] = {1, 2, 3}, t[3] = {0, 0, 0};
    CHECK_CLOSE(mse_forward_f64(p, t, 3), 14.0 / 3, 1e-15, 0);
    CHECK_CLOSE(l1_forward_f64(p, t, 3), 2.0, 1e-15, 0);
    CHECK(mse_forward_f64(p, t, 0) == 0 && l1_forward_f64(p, t, 0) == 0);
    // l1 subgradient at pred == target is 0
    double q[3] = {1, 5, -2}, g[3] = {0.5, 0.5, 0.5};
    l1_backward_f64(g, p, q, 3, 3.0);
    CHECK(g[0] == 0.5 && g[1] == 0.5 - 1 && g[2] == 0.5 + 1);
    // KL of the prior itself is exactly 0, with zero gradient
    double z[8] = {0}, dz[8] = {0}, dl[8] = {0};
    CHECK(kl_normal_forward_f64(z, z, 2, 4) == 0);
    CHECK(kl_normal_forward(NULL, NULL, 0, 4) == 0);
    kl_normal_backward_f64(dz, dl, z, z, 2, 4, 1.0);
    for (int i = 0; i < 8; i++) CHECK(dz[i] == 0 && dl[i] == 0);
    // KL(N(3, 2^2) || N(0, 1)) = log(1/sigma) + (sigma^2 + mu^2)/2 - 1/2 = 6 - ln 2 per dimension;
    // two identical rows average to the same, two dimensions sum
    double mu[4] = {3, -3, 3, -3}, lv[4] = {log(4.0), log(4.0), log(4.0), log(4.0)};
    CHECK_CLOSE(kl_normal_forward_f64(mu, lv, 1, 1), 5.306852819440055, 1e-15, 0);
    CHECK_CLOSE(kl_normal_forward_f64(mu, lv, 2, 2), 2 * 5.306852819440055, 1e-15, 0);
    // near logvar = 0 (posterior ~ prior) e^lv - 1 - lv ~ lv^2/2 must not cancel away
    double small_lv = 1e-4, zero = 0;
    double series = 0.5 * (small_lv * small_lv / 2 + pow(small_lv, 3) / 6 + pow(small_lv, 4) / 24);
    CHECK_CLOSE(kl_normal_forward_f64(&zero, &small_lv, 1, 1), series, 1e-12, 0);
    float muf[4] = {3, -3, 3, -3}, lvf[4];
    for (int i = 0; i < 4; i++) lvf[i] = (float)log(4.0);
    CHECK_CLOSE(kl_normal_forward(muf, lvf, 2, 2), 2 * 5.306852819440055, F32_RTOL, 0);
}

TEST(loss_float_vs_double) {
    enum { N = 1000, B = 40, D = 25 };
    double p[N], t[N], gp[N] = {0}, gk[N] = {0}, gl[N] = {0};
    float pf[N], tf[N], gpf[N] = {0}, gkf[N] = {0}, glf[N] = {0};
    fill_normal(p, N, 90, 1); fill_normal(t, N, 91, 1);
    to_float(pf, p, N); to_float(tf, t, N); to_double(p, pf, N); to_double(t, tf, N);
    CHECK_CLOSE(mse_forward(pf, tf, N), mse_forward_f64(p, t, N), F32_RTOL, 0);
    CHECK_CLOSE(l1_forward(pf, tf, N), l1_forward_f64(p, t, N), F32_RTOL, 0);
    CHECK_CLOSE(kl_normal_forward(pf, tf, B, D), kl_normal_forward_f64(p, t, B, D), F32_RTOL, 0);
    mse_backward(gpf, pf, tf, N, 0.3f); mse_backward_f64(gp, p, t, N, (double)0.3f);
    l1_backward(glf, pf, tf, N, 0.3f); l1_backward_f64(gl, p, t, N, (double)0.3f);
    kl_normal_backward(gkf, glf, pf, tf, B, D, 0.3f); kl_normal_backward_f64(gk, gl, p, t, B, D, (double)0.3f);
    for (int i = 0; i < N; i++) {
        CHECK_CLOSE(gpf[i], gp[i], F32_RTOL, 1e-12);
        CHECK_CLOSE(glf[i], gl[i], F32_RTOL, 1e-12);
        CHECK_CLOSE(gkf[i], gk[i], F32_RTOL, 1e-12);
    }
}

// ---------------------------------------------------------------------------------------------
// Adam / AdamW

TEST(adamw_default_config) {
    mlb_adam_config c = mlb_adamw_default(3e-4);
    CHECK(c.lr == 3e-4 && c.beta1 == 0.9 && c.beta2 == 0.999 && c.eps == 1e-8);
    CHECK(c.weight_decay == 0.01 && c.decoupled == 1);
}

// With m = v = 0 the first step is lr * g / (|g| + eps): lr * sign(g) once eps << |g|.
TEST(adam_first_step_is_sign) {
    enum { N = 16 };
    for (int decoupled = 0; decoupled < 2; decoupled++) {
        mlb_adam_config c = {.lr = 1e-2, .beta1 = 0.9, .beta2 = 0.999, .eps = 1e-12,
                             .weight_decay = 0, .decoupled = decoupled};
        double p[N], g[N], m[N] = {0}, v[N] = {0}, p0[N];
        float pf[N], gf[N], mf[N] = {0}, vf[N] = {0}, pf0[N];
        fill_normal(p, N, 100, 1); fill_normal(g, N, 101, 1);
        for (int i = 0; i < N; i++) g[i] *= pow(10, i % 7 - 3);   // |g| from 1e-3 to 1e3
        to_float(pf, p, N); to_float(gf, g, N);
        memcpy(p0, p, sizeof p); memcpy(pf0, pf, sizeof pf);
        adam_update_f64(p, g, m, v, N, &c, 1);
        adam_update(pf, gf, mf, vf, N, &c, 1);
        for (int i = 0; i < N; i++) {
            double want = -c.lr * (g[i] > 0 ? 1 : -1);
            CHECK_CLOSE(p[i] - p0[i], want, 1e-8, 0);
            CHECK_CLOSE(pf[i] - pf0[i], want, 1e-4, 0);   // float rounding of p ~ 1 vs lr = 1e-2
        }
    }
}

// A reference written naively in double over T steps, straight from the formulas.
static void adam_reference(double* p, double* m, double* v, const double* grads_t, size_t n,
                           const mlb_adam_config* c, int T) {
    for (int t = 1; t <= T; t++) {
        const double* gr = grads_t + (size_t)(t - 1) * n;
        for (size_t i = 0; i < n; i++) {
            double g = gr[i];
            if (c->decoupled) p[i] = p[i] - c->lr * c->weight_decay * p[i];
            else g = g + c->weight_decay * p[i];
            m[i] = c->beta1 * m[i] + (1 - c->beta1) * g;
            v[i] = c->beta2 * v[i] + (1 - c->beta2) * g * g;
            double mhat = m[i] / (1 - pow(c->beta1, t)), vhat = v[i] / (1 - pow(c->beta2, t));
            p[i] = p[i] - c->lr * mhat / (sqrt(vhat) + c->eps);
        }
    }
}

TEST(adam_matches_reference) {
    enum { N = 257, T = 10 };
    for (int decoupled = 0; decoupled < 2; decoupled++) {
        mlb_adam_config c = {.lr = 1e-2, .beta1 = 0.9, .beta2 = 0.999, .eps = 1e-8,
                             .weight_decay = 0.1, .decoupled = decoupled};
        static double g[T * N], p[N], m[N], v[N], rp[N], rm[N], rv[N];
        static float gf[T * N], pf[N], mf[N], vf[N];
        fill_normal(g, T * N, 110, 1); fill_normal(p, N, 111, 1);
        to_float(gf, g, T * N); to_float(pf, p, N); to_double(g, gf, T * N); to_double(p, pf, N);
        memset(m, 0, sizeof m); memset(v, 0, sizeof v); memset(mf, 0, sizeof mf); memset(vf, 0, sizeof vf);
        memcpy(rp, p, sizeof p); memset(rm, 0, sizeof rm); memset(rv, 0, sizeof rv);
        for (int t = 1; t <= T; t++) {
            adam_update_f64(p, g + (size_t)(t - 1) * N, m, v, N, &c, t);
            adam_update(pf, gf + (size_t)(t - 1) * N, mf, vf, N, &c, t);
        }
        adam_reference(rp, rm, rv, g, N, &c, T);
        double worst = 0, worstf = 0;
        for (int i = 0; i < N; i++) {
            CHECK_CLOSE(p[i], rp[i], 1e-12, 1e-12);
            CHECK_CLOSE(m[i], rm[i], 1e-12, 1e-15);
            CHECK_CLOSE(v[i], rv[i], 1e-12, 1e-15);
            CHECK_CLOSE(pf[i], rp[i], 1e-6, 1e-6);
            CHECK_CLOSE(mf[i], rm[i], 1e-6, 1e-7);
            CHECK_CLOSE(vf[i], rv[i], 1e-6, 1e-8);
            worst = fmax(worst, fabs(p[i] - rp[i])); worstf = fmax(worstf, fabs(pf[i] - rp[i]));
        }
        printf("  %s: max |p - ref| double %.2e, float %.2e\n", decoupled ? "AdamW" : "Adam-L2", worst, worstf);
    }
}

// AdamW decays decoupled from the gradient: a parameter with g = 0 (and so m = v = 0) shrinks by
// exactly (1 - lr wd) per step, while its neighbours get ordinary steps.
TEST(adamw_decay_is_decoupled) {
    enum { N = 8 };
    mlb_adam_config c = {.lr = 1e-2, .beta1 = 0.9, .beta2 = 0.999, .eps = 1e-8, .weight_decay = 0.1, .decoupled = 1};
    double p[N], g[N], m[N] = {0}, v[N] = {0};
    float pf[N], gf[N], mf[N] = {0}, vf[N] = {0};
    fill_normal(p, N, 120, 1); fill_normal(g, N, 121, 1);
    for (int i = 0; i < N; i += 2) g[i] = 0;
    to_float(pf, p, N); to_float(gf, g, N);
    const double factor = 1 - c.lr * c.weight_decay;
    for (int t = 1; t <= 5; t++) {
        double prev[N]; float prevf[N];
        memcpy(prev, p, sizeof p); memcpy(prevf, pf, sizeof pf);
        adam_update_f64(p, g, m, v, N, &c, t);
        adam_update(pf, gf, mf, vf, N, &c, t);
        for (int i = 0; i < N; i += 2) {
            CHECK(p[i] == prev[i] * factor);
            CHECK(pf[i] == prevf[i] * (float)factor);
        }
        for (int i = 1; i < N; i += 2) CHECK(fabs(p[i] - prev[i] * factor) > 1e-3);   // Adam moved these
    }
}

// Adam-L2 folds wd p into the gradient, which Adam then normalises: with g = 0 its first step is
// ~ lr sign(p), not AdamW's lr wd p.
TEST(adam_l2_differs_from_adamw) {
    enum { N = 8 };
    mlb_adam_config c = {.lr = 1e-2, .beta1 = 0.9, .beta2 = 0.999, .eps = 1e-12, .weight_decay = 0.1, .decoupled = 0};
    double p[N], g[N] = {0}, m[N] = {0}, v[N] = {0}, p0[N];
    fill_normal(p, N, 130, 1);
    memcpy(p0, p, sizeof p);
    adam_update_f64(p, g, m, v, N, &c, 1);
    for (int i = 0; i < N; i++) CHECK_CLOSE(p[i] - p0[i], -c.lr * (p0[i] > 0 ? 1 : -1), 1e-8, 0);
    // over several steps with gradients the two end up at different parameters
    double pa[N], pb[N], ma[N] = {0}, va[N] = {0}, mb[N] = {0}, vb[N] = {0};
    fill_normal(g, N, 131, 1);
    memcpy(pa, p0, sizeof pa); memcpy(pb, p0, sizeof pb);
    mlb_adam_config cw = c;
    cw.decoupled = 1;
    for (int t = 1; t <= 3; t++) {
        adam_update_f64(pa, g, ma, va, N, &c, t);
        adam_update_f64(pb, g, mb, vb, N, &cw, t);
    }
    for (int i = 0; i < N; i++) CHECK(fabs(pa[i] - pb[i]) > 1e-6);
}

// ---------------------------------------------------------------------------------------------
// determinism: 1 and 2 threads give bitwise equal results (elementwise loops, the fixed-order
// dbias reduction, the sequential loss sums; OpenBLAS threads checked the same way)

#define DET_N 100003   // above the parallel threshold, not a multiple of anything
typedef struct {
    float act[DET_N], dact[DET_N], dmse[DET_N], dl1[DET_N], dkl[DET_N], p[DET_N], m[DET_N], v[DET_N];
    float loss[3];
    float out[512 * 96], din[512 * 160], dw[96 * 160], db[96];
} det_result;

static void det_run(det_result* r, const float* x, const float* y, int threads) {
    omp_set_num_threads(threads);
    openblas_set_num_threads(threads);
    memset(r, 0, sizeof *r);
    activation_forward(r->act, x, DET_N, MLB_ACT_GELU);
    activation_backward(r->dact, y, x, DET_N, MLB_ACT_SILU);
    r->loss[0] = mse_forward(x, y, DET_N);
    r->loss[1] = l1_forward(x, y, DET_N);
    r->loss[2] = kl_normal_forward(x, y, 1, DET_N);
    mse_backward(r->dmse, x, y, DET_N, 1.f);
    l1_backward(r->dl1, x, y, DET_N, 1.f);
    kl_normal_backward(r->dkl, r->dkl, x, y, 1, DET_N, 1.f);
    memcpy(r->p, x, sizeof r->p);
    mlb_adam_config c = mlb_adamw_default(1e-3);
    for (int t = 1; t <= 3; t++) adam_update(r->p, y, r->m, r->v, DET_N, &c, t);
    const int B = 512, C = 160, OC = 96;   // x, y reused as in [B,C] / weight [OC,C] / dout [B,OC]
    linear_forward(r->out, x, y, x + 7, B, C, OC);
    linear_backward(r->din, r->dw, r->db, y + 11, x, y, B, C, OC);
}

TEST(determinism_threads) {
    float* x = falloc(DET_N);
    float* y = falloc(DET_N);
    for (int i = 0; i < DET_N; i++) { x[i] = mlb_rng_normal(SEED, 140, i); y[i] = mlb_rng_normal(SEED, 141, i); }
    int max_threads = omp_get_max_threads();
    det_result* r1 = malloc(sizeof *r1);
    det_result* r2 = malloc(sizeof *r2);
    REQUIRE(r1 && r2);
    det_run(r1, x, y, 1);
    det_run(r2, x, y, 2);
    omp_set_num_threads(max_threads);
    openblas_set_num_threads(max_threads);
    CHECK(memcmp(r1->act, r2->act, sizeof r1->act) == 0);
    CHECK(memcmp(r1->dact, r2->dact, sizeof r1->dact) == 0);
    CHECK(memcmp(r1->loss, r2->loss, sizeof r1->loss) == 0);
    CHECK(memcmp(r1->dmse, r2->dmse, sizeof r1->dmse) == 0);
    CHECK(memcmp(r1->dl1, r2->dl1, sizeof r1->dl1) == 0);
    CHECK(memcmp(r1->dkl, r2->dkl, sizeof r1->dkl) == 0);
    CHECK(memcmp(r1->p, r2->p, sizeof r1->p) == 0 && memcmp(r1->v, r2->v, sizeof r1->v) == 0);
    CHECK(memcmp(r1->db, r2->db, sizeof r1->db) == 0);
    CHECK(memcmp(r1->out, r2->out, sizeof r1->out) == 0);
    CHECK(memcmp(r1->din, r2->din, sizeof r1->din) == 0);
    CHECK(memcmp(r1->dw, r2->dw, sizeof r1->dw) == 0);
    free(r1); free(r2); free(x); free(y);
}

// The fused f, f', f'' pass agrees with the scalar functions for every activation, and its
// derivatives agree with finite differences of f (so a fused formula cannot drift from f).
TEST(activation_forward_derivs_matches_scalar) {
    enum { N = 41 };
    double x[N], f[N], d1[N], d2[N];
    for (int i = 0; i < N; i++) x[i] = -40.0 + 2.0 * i + 0.37;
    for (int a = 0; a < MLB_ACT_COUNT; a++) {
        mlb_activation act = (mlb_activation)a;
        activation_forward_derivs_f64(f, d1, d2, x, N, act);
        for (int i = 0; i < N; i++) {
            CHECK_CLOSE(f[i], mlb_act_f64(act, x[i]), 1e-12, 1e-300);
            CHECK_CLOSE(d1[i], mlb_act_d1_f64(act, x[i]), 1e-9, 1e-15);
            CHECK_CLOSE(d2[i], mlb_act_d2_f64(act, x[i]), 1e-9, 1e-15);
            double h = 1e-6;
            double fd1 = (mlb_act_f64(act, x[i] + h) - mlb_act_f64(act, x[i] - h)) / (2 * h);
            if (act != MLB_ACT_RELU && act != MLB_ACT_LEAKY_RELU && act != MLB_ACT_ELU)
                CHECK_CLOSE(d1[i], fd1, 1e-6, 1e-9);
        }
        float xf[N], ff[N], d1f[N], d2f[N];
        for (int i = 0; i < N; i++) xf[i] = (float)x[i];
        activation_forward_derivs(xf, d1f, NULL, xf, N, act);   // in place, d2 not wanted
        for (int i = 0; i < N; i++) { ff[i] = xf[i]; CHECK_CLOSE(ff[i], f[i], 1e-5, 1e-6); CHECK_CLOSE(d1f[i], d1[i], 1e-5, 1e-6); }
        (void)d2f;
    }
}

// SiLU and sigmoid run in blocks: e^-|x| as a row (the vector exponential on a CPU with AVX2 or
// AVX-512, libm's on the scalar level), then their arithmetic as SIMD: bit for bit the per-value loop
// written out here with the same exponential, on every level, over n not a multiple of the block,
// both tails, +-0, subnormals, infinities and NaN, in place and with the derivatives left out, on 1
// and 2 threads; and within a few ulps of libm's loop for finite x (the exponential within 3e-7).
// A NaN only has to stay a NaN: C leaves its sign and payload open, and x86 takes the first
// operand's, which is the compiler's choice of instruction order (a NaN input gives a -NaN in one,
// +NaN in the other).
static int same_bits_or_both_nan(const float* a, const float* b, size_t n) {
    for (size_t i = 0; i < n; i++)
        if (memcmp(&a[i], &b[i], sizeof(float)) && !(isnan(a[i]) && isnan(b[i]))) return 0;
    return 1;
}
// libm: 1 for libm's expf, else the row exponential of `level`.
static void silu_family_reference(float* f, float* d1, float* d2, const float* in, size_t n, int silu, int libm,
                                  mlb_simd_level level) {
    for (size_t i = 0; i < n; i++) {
        float x = in[i], e = -fabsf(x);
        if (libm) e = expf(e);
        else mlb_exp_shifted_row(level, &e, 1, 0.0f);
        float inv = 1.0f / (1.0f + e);
        float s = x >= 0 ? inv : e * inv, sc = x >= 0 ? e * inv : inv;
        if (!silu && isnan(x)) s = x;
        float ds = s * sc, dds = ds * (sc - s);
        f[i] = silu ? x * s : s;
        d1[i] = silu ? s + x * ds : ds;
        d2[i] = silu ? 2.0f * ds + x * dds : dds;
    }
}

TEST(activation_silu_blocks_bitwise) {
    enum { N = 70001 };   // > OPS_PARALLEL_MIN: the parallel blocks, and a ragged last block
    float *x = malloc(sizeof(float) * N), *f = malloc(sizeof(float) * N), *g = malloc(sizeof(float) * N);
    float *h = malloc(sizeof(float) * N), *rf = malloc(sizeof(float) * N), *rg = malloc(sizeof(float) * N);
    float *rh = malloc(sizeof(float) * N), *y = malloc(sizeof(float) * N);
    REQUIRE(x && f && g && h && rf && rg && rh && y);
    mlb_rng_fill_normal(x, N, 7, 3, 0, 0, 12);
    const float special[] = {0.0f, -0.0f, 1e-40f, -1e-40f, INFINITY, -INFINITY, NAN, 88.7f, -88.7f, 104.0f, -104.0f, 1e30f, -1e30f};
    for (size_t i = 0; i < sizeof special / sizeof special[0]; i++) x[i * 997] = special[i];
    int levels = 0;
    for (int level = MLB_SIMD_SCALAR; level <= MLB_SIMD_AVX512; level++) {
        mlb_simd_force(level);
        if ((int)mlb_simd_kernels() != level) break;
        levels++;
        for (int silu = 0; silu < 2; silu++) {
            const mlb_activation act = silu ? MLB_ACT_SILU : MLB_ACT_SIGMOID;
            silu_family_reference(rf, rg, rh, x, N, silu, level == MLB_SIMD_SCALAR, (mlb_simd_level)level);
            for (int threads = 1; threads <= 2; threads++) {
                omp_set_num_threads(threads);
                activation_forward_derivs(f, g, h, x, N, act);
                CHECK_MSG(same_bits_or_both_nan(f, rf, N) && same_bits_or_both_nan(g, rg, N) && same_bits_or_both_nan(h, rh, N),
                          "%s, level %d, %d threads: not the per-value loop's bits", mlb_activation_name(act), level, threads);
                memcpy(y, x, sizeof(float) * N);
                activation_forward_derivs(y, NULL, NULL, y, N, act);   // in place, no derivatives
                CHECK_MSG(same_bits_or_both_nan(y, rf, N), "%s, level %d in place: not the per-value loop's bits",
                          mlb_activation_name(act), level);
            }
            silu_family_reference(rf, rg, rh, x, N, silu, 1, MLB_SIMD_SCALAR);   // libm's
            double worst = 0;
            for (size_t i = 0; i < N; i++) {
                if (!(fabsf(x[i]) < 80)) { CHECK(isnan(x[i]) ? isnan(f[i]) : !isnan(f[i]) || isnan(rf[i])); continue; }
                const float got[3] = {f[i], g[i], h[i]}, want[3] = {rf[i], rg[i], rh[i]};
                for (int k = 0; k < 3; k++) {
                    // relative, and absolute where f'' crosses 0 (its two terms cancel there)
                    double err = fabs((double)got[k] - want[k]) / (2e-6 * fabs((double)want[k]) + 1e-7);
                    if (err > worst) worst = err;
                }
            }
            CHECK_MSG(worst <= 1, "%s, level %d: %.3g times the tolerance (2e-6 relative + 1e-7) from libm's loop",
                      mlb_activation_name(act), level, worst);
            printf("  %s, level %d: within %.2f of the tolerance of libm's loop\n", mlb_activation_name(act), level, worst);
        }
    }
    CHECK(levels >= 1);
    mlb_simd_force(-1);
    omp_set_num_threads(omp_get_num_procs());
    free(x); free(f); free(g); free(h); free(rf); free(rg); free(rh); free(y);
}

// The CPU table's add (y += x: residuals, gradient sums) in 16 or 8 lanes: the scalar loop's bits,
// for every length around the lanes and with y = x.
TEST(add_vector_kernel_bitwise) {
    enum { N = 1000 };
    float x[N], y0[N], y1[N];
    mlb_rng_fill_normal(x, N, 12, 1, 0, 0, 1);
    const float special[] = {0.0f, -0.0f, 1e-40f, INFINITY, -INFINITY, NAN, 3e38f};
    for (size_t i = 0; i < sizeof special / sizeof special[0]; i++) x[i * 37 + 3] = special[i];
    const mlb_backend* be = mlb_backend_for(MLB_DEVICE_CPU, MLB_GEMM_FP32);
    int levels = 0;
    for (int level = MLB_SIMD_AVX2; level <= MLB_SIMD_AVX512; level++) {
        mlb_simd_force(level);
        if ((int)mlb_simd_kernels() != level) break;
        levels++;
        for (int n = 0; n <= 40; n++)
            for (int same = 0; same < 2; same++) {
                for (int i = 0; i < N; i++) y0[i] = y1[i] = x[N - 1 - i];
                const float* a0 = same ? y0 : x + 1;
                const float* a1 = same ? y1 : x + 1;
                size_t len = n == 40 ? N - 1 : (size_t)n;
                mlb_simd_force(MLB_SIMD_SCALAR);
                REQUIRE(be->add(y0, a0, len) == MLB_OK);
                mlb_simd_force(level);
                REQUIRE(be->add(y1, a1, len) == MLB_OK);
                CHECK_MSG(same_bits_or_both_nan(y0, y1, N), "add of %zu values%s in %s: not the scalar loop's bits", len,
                          same ? " (y = x)" : "", mlb_simd_name((mlb_simd_level)level));
            }
    }
    mlb_simd_force(-1);
    if (!levels) printf("  (no AVX2 here: the scalar loop only)\n");
}

// The attention backward's rows (nn/simd_rows.h): e^min(p - c, 0) within 3e-7 of libm's exp (and
// exactly 1 where p - c > 0: rounding past the row's log-sum-exp), the softmax's backward bit for bit
// the scalar loop, every length 0..40, in 8 and 16 lanes where the CPU has them.
TEST(attention_backward_rows) {
    enum { N = 300 };
    float x[N], p[N], g0[N], g1[N];
    mlb_rng_fill_normal(x, N, 21, 1, 0, 0, 4);   // scores around c = 1: most below, some above
    x[5] = -200.0f;   // far under fp32's range
    x[9] = 1.0f;      // exactly c
    const float c = 1.0f, d = 0.375f, scale = 0.17677669f;
    int levels = 0;
    for (int level = MLB_SIMD_AVX2; level <= MLB_SIMD_AVX512; level++) {
        mlb_simd_force(level);
        if ((int)mlb_simd_kernels() != level) break;
        levels++;
        double worst = 0;
        int n_above = 0, above_ok = 1, tail_ok = 1;
        for (int n = 0; n <= 41; n++) {
            const int len = n == 41 ? N : n;
            for (int i = 0; i < N; i++) p[i] = x[i];
            mlb_exp_shifted_row((mlb_simd_level)level, p, len, c);
            for (int i = len; i < N; i++) tail_ok &= p[i] == x[i];   // nothing past the row
            for (int i = 0; i < len; i++) {
                const float shifted = x[i] - c;   // in fp32, as the scalar loop subtracts
                double want = exp((double)shifted);
                if (shifted > 0) {
                    n_above++;
                    above_ok &= p[i] == 1.0f;
                } else if (want > 1e-30) {
                    double e = fabs(p[i] - want) / want;
                    if (e > worst) worst = e;
                } else {
                    tail_ok &= p[i] >= 0 && p[i] < 1e-30f;
                }
            }
            for (int i = 0; i < N; i++) g0[i] = g1[i] = x[N - 1 - i];
            for (int i = 0; i < len; i++) g0[i] = p[i] * (g0[i] - d) * scale;
            mlb_softmax_grad_row((mlb_simd_level)level, g1, p, len, d, scale);
            CHECK_MSG(same_bits_or_both_nan(g0, g1, N), "softmax grad row of %d in %s: not the scalar loop's bits", len,
                      mlb_simd_name((mlb_simd_level)level));
        }
        CHECK_MSG(worst < 3e-7, "%s: e^(p - c) off libm's by %.3g relative", mlb_simd_name((mlb_simd_level)level), worst);
        CHECK_MSG(n_above > 0 && above_ok, "%s: p - c > 0 must give 1 (%d such values)", mlb_simd_name((mlb_simd_level)level),
                  n_above);
        CHECK_MSG(tail_ok, "%s: a value past the row changed, or e^-201 is not ~0", mlb_simd_name((mlb_simd_level)level));
    }
    mlb_simd_force(-1);
    if (!levels) printf("  (no AVX2 here: the scalar loops only)\n");
}

// Adam and the ReLU / identity activations run as 8- or 16-lane kernels where the CPU has them
// (nn/simd_rows.h): bit for bit the scalar loops (the level capped at scalar), for both Adam and
// AdamW over steps 1..3, n not a multiple of the lanes or the blocks, special values, in place, on
// 1 and 2 threads. Checks nothing on a CPU without AVX2 (the scalar loop is then the only one).
TEST(adam_and_relu_vector_kernels_bitwise) {
    enum { N = 70001 };
    float* buf = malloc(sizeof(float) * N * 12);
    REQUIRE(buf);
    float *x = buf, *g = buf + N, *p0 = buf + 2 * N, *m0 = buf + 3 * N, *v0 = buf + 4 * N;
    float *p1 = buf + 5 * N, *m1 = buf + 6 * N, *v1 = buf + 7 * N, *f0 = buf + 8 * N, *d0 = buf + 9 * N;
    float *f1 = buf + 10 * N, *d1 = buf + 11 * N;
    mlb_rng_fill_normal(x, N, 11, 1, 0, 0, 1);
    mlb_rng_fill_normal(g, N, 11, 2, 0, 0, 1e-3f);
    const float special[] = {0.0f, -0.0f, 1e-40f, -1e-40f, INFINITY, -INFINITY, NAN, 1e30f, -1e30f};
    for (size_t i = 0; i < sizeof special / sizeof special[0]; i++) x[i * 991 + 5] = special[i];
    g[17] = 0.0f;
    g[18] = -0.0f;
    g[19] = 1e-30f;
    int levels = 0;
    for (int level = MLB_SIMD_AVX2; level <= MLB_SIMD_AVX512; level++) {
        mlb_simd_force(level);
        if ((int)mlb_simd_kernels() != level) break;
        levels++;
        for (int threads = 1; threads <= 2; threads++) {
            omp_set_num_threads(threads);
            for (int decoupled = 0; decoupled < 2; decoupled++) {
                mlb_adam_config c = {.lr = 3e-3, .beta1 = 0.9, .beta2 = 0.99, .eps = 1e-15, .weight_decay = 0.05,
                                     .decoupled = decoupled};
                memcpy(p0, x, sizeof(float) * N);
                memcpy(p1, x, sizeof(float) * N);
                memset(m0, 0, sizeof(float) * N); memset(v0, 0, sizeof(float) * N);
                memset(m1, 0, sizeof(float) * N); memset(v1, 0, sizeof(float) * N);
                for (long t = 1; t <= 3; t++) {
                    mlb_simd_force(MLB_SIMD_SCALAR);
                    adam_update(p0, g, m0, v0, N, &c, t);
                    mlb_simd_force(level);
                    adam_update(p1, g, m1, v1, N, &c, t);
                }
                CHECK_MSG(same_bits_or_both_nan(p0, p1, N) && same_bits_or_both_nan(m0, m1, N) &&
                              same_bits_or_both_nan(v0, v1, N),
                          "Adam (decoupled %d) in %s on %d threads: not the scalar loop's bits", decoupled,
                          mlb_simd_name((mlb_simd_level)level), threads);
            }
            for (int relu = 0; relu < 2; relu++) {
                const mlb_activation act = relu ? MLB_ACT_RELU : MLB_ACT_IDENTITY;
                float f_short[7], h_short[7];   // f and f'' of a row shorter than the lanes, no f'
                mlb_simd_force(MLB_SIMD_SCALAR);
                activation_forward_derivs(f0, d0, NULL, x, N, act);
                activation_forward_derivs(f_short, NULL, h_short, x, 7, act);
                mlb_simd_force(level);
                activation_forward_derivs(f1, d1, NULL, x, N, act);
                CHECK_MSG(same_bits_or_both_nan(f0, f1, N) && same_bits_or_both_nan(d0, d1, N),
                          "%s in %s: not the scalar loop's bits", mlb_activation_name(act), mlb_simd_name((mlb_simd_level)level));
                float f_vec[7], h_vec[7];
                activation_forward_derivs(f_vec, NULL, h_vec, x, 7, act);
                CHECK(memcmp(f_short, f_vec, sizeof f_vec) == 0 && memcmp(h_short, h_vec, sizeof h_vec) == 0);
                for (int i = 0; i < 7; i++) CHECK(h_vec[i] == 0.0f);
                memcpy(f1, x, sizeof(float) * N);
                activation_forward_derivs(f1, NULL, NULL, f1, N, act);   // in place
                CHECK_MSG(same_bits_or_both_nan(f0, f1, N), "%s in place: not the scalar loop's bits", mlb_activation_name(act));
            }
        }
    }
    mlb_simd_force(-1);
    omp_set_num_threads(omp_get_num_procs());
    printf("  (%d vector levels checked)\n", levels);
    free(buf);
}

int main(void) {
    RUN(linear_backward_fd);
    RUN(linear_backward_null);
    RUN(linear_forward_naive);
    RUN(linear_empty_shapes);
    RUN(linear_float_vs_double);
    RUN(activation_derivatives_fd);
    RUN(activation_backward_fd);
    RUN(activation_known_values);
    RUN(activation_tails);
    RUN(activation_float_vs_double);
    RUN(activation_names);
    RUN(loss_backward_fd);
    RUN(loss_known_values);
    RUN(loss_float_vs_double);
    RUN(adamw_default_config);
    RUN(adam_first_step_is_sign);
    RUN(adam_matches_reference);
    RUN(adamw_decay_is_decoupled);
    RUN(adam_l2_differs_from_adamw);
    RUN(determinism_threads);
    RUN(activation_forward_derivs_matches_scalar);
    RUN(add_vector_kernel_bitwise);
    RUN(attention_backward_rows);
    RUN(adam_and_relu_vector_kernels_bitwise);
    RUN(activation_silu_blocks_bitwise);
    return test_summary();
}
