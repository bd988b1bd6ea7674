// Transformer ops (transformer_ops.h): layer norm and attention against naive double-precision
// implementations, the causal mask, a stable softmax, thread-count independence, the layer norm
// backward by finite differences in double, the embedding lookup and the error messages.
#include <omp.h>
#include <stdint.h>
#include "matlaber/error.h"
#include "matlaber/transformer_ops.h"
#include "nn/simd_rows.h"
#include "test.h"

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static double urand(void) {   // xorshift64*, uniform in [-1, 1)
    rng_state ^= rng_state >> 12; rng_state ^= rng_state << 25; rng_state ^= rng_state >> 27;
    return (double)((rng_state * 0x2545f4914f6cdd1dull) >> 11) / 9007199254740992.0 * 2.0 - 1.0;
}
static void fill(float* f, double* d, size_t n, double scale, double offset) {
    for (size_t i = 0; i < n; i++) {
        double v = offset + scale * urand();
        if (f) f[i] = (float)v;
        if (d) d[i] = f ? (double)f[i] : v;
    }
}

// ---- naive references ------------------------------------------------------------------------------
static void naive_layernorm(double* out, const double* in, const double* w, const double* b, int N, int C, double eps) {
    for (int n = 0; n < N; n++) {
        const double* x = in + (size_t)n * C;
        double m = 0, v = 0;
        for (int c = 0; c < C; c++) m += x[c];
        m /= C;
        for (int c = 0; c < C; c++) v += (x[c] - m) * (x[c] - m);
        v /= C;
        for (int c = 0; c < C; c++)
            out[(size_t)n * C + c] = (x[c] - m) / sqrt(v + eps) * (w ? w[c] : 1) + (b ? b[c] : 0);
    }
}

// q, k, v: separate [B,T,C]; p [B,NH,T,T]
static void naive_attention(double* out, double* p, const double* q, const double* k, const double* v, int B, int T,
                            int C, int NH, int causal) {
    int hd = C / NH;
    for (int b = 0; b < B; b++)
        for (int h = 0; h < NH; h++)
            for (int t = 0; t < T; t++) {
                double s[512], mx = -1e300, sum = 0;
                for (int u = 0; u < T; u++) {
                    double dot = 0;
                    for (int i = 0; i < hd; i++)
                        dot += q[((size_t)b * T + t) * C + h * hd + i] * k[((size_t)b * T + u) * C + h * hd + i];
                    s[u] = (causal && u > t) ? -INFINITY : dot / sqrt((double)hd);
                    if (s[u] > mx) mx = s[u];
                }
                for (int u = 0; u < T; u++) { s[u] = exp(s[u] - mx); sum += s[u]; }
                for (int u = 0; u < T; u++) s[u] /= sum;
                for (int i = 0; i < hd; i++) {
                    double o = 0;
                    for (int u = 0; u < T; u++) o += s[u] * v[((size_t)b * T + u) * C + h * hd + i];
                    out[((size_t)b * T + t) * C + h * hd + i] = o;
                }
                if (p) memcpy(p + (((size_t)b * NH + h) * T + t) * T, s, T * sizeof(double));
            }
}

static double max_abs_diff_fd(const float* a, const double* b, size_t n) {
    double m = 0;
    for (size_t i = 0; i < n; i++) { double d = fabs((double)a[i] - b[i]); if (!(d <= m)) m = d; }
    return m;
}

// ---- layer norm --------------------------------------------------------------------------------------
TEST(layernorm_matches_naive) {
    enum { N = 13, C = 37 };
    float x[N * C], w[C], b[C], out[N * C], mean[N], rstd[N];
    double xd[N * C], wd[C], bd[C], ref[N * C];
    fill(x, xd, N * C, 3.0, 100.0);   // a large mean: the two-pass variance must not cancel
    fill(w, wd, C, 0.5, 1.0);
    fill(b, bd, C, 0.3, 0.0);
    layernorm_forward(out, mean, rstd, x, w, b, N, C, 1e-5f);
    naive_layernorm(ref, xd, wd, bd, N, C, 1e-5);
    double err = max_abs_diff_fd(out, ref, N * C);
    printf("  layernorm float vs double: max abs %.3g\n", err);
    CHECK(err < 1e-6);
    for (int n = 0; n < N; n++) {
        double m = 0;
        for (int c = 0; c < C; c++) m += xd[n * C + c];
        CHECK_CLOSE(mean[n], m / C, 1e-6, 0);
    }
    // without affine parameters, and in place
    layernorm_forward(x, NULL, NULL, x, NULL, NULL, N, C, 1e-5f);
    naive_layernorm(ref, xd, NULL, NULL, N, C, 1e-5);
    CHECK(max_abs_diff_fd(x, ref, N * C) < 2e-5);
    // double version
    double outd[N * C];
    layernorm_forward_f64(outd, NULL, NULL, xd, wd, bd, N, C, 1e-5);
    naive_layernorm(ref, xd, wd, bd, N, C, 1e-5);
    double e64 = 0;
    for (int i = 0; i < N * C; i++) e64 = fmax(e64, fabs(outd[i] - ref[i]));
    CHECK(e64 < 1e-12);
}

// The float pass on every SIMD level this CPU has (the rows in 8 or 16 lanes, nn/simd_rows.h, or
// the scalar loop): against the double reference for row lengths around the lanes, with and without
// the affine parameters, in place, a large mean; the same bits on 1 and 2 threads.
TEST(layernorm_rows_every_level) {
    enum { N = 300, CMAX = 130 };
    const int lengths[] = {1, 2, 7, 8, 9, 15, 16, 17, 31, 33, 64, 77, 128, 130};
    float* x = malloc(sizeof(float) * N * CMAX);
    float* out = malloc(sizeof(float) * N * CMAX);
    float* out2 = malloc(sizeof(float) * N * CMAX);
    double* xd = malloc(sizeof(double) * N * CMAX);
    double* ref = malloc(sizeof(double) * N * CMAX);
    float w[CMAX], b[CMAX], mean[N], rstd[N];
    double wd[CMAX], bd[CMAX];
    REQUIRE(x && out && out2 && xd && ref);
    fill(w, wd, CMAX, 0.5, 1.0);
    fill(b, bd, CMAX, 0.3, 0.0);
    int levels = 0;
    for (int level = MLB_SIMD_SCALAR; level <= MLB_SIMD_AVX512; level++) {
        mlb_simd_force(level);
        if ((int)mlb_simd_kernels() != level) break;
        levels++;
        double worst = 0;
        for (size_t li = 0; li < sizeof lengths / sizeof *lengths; li++) {
            const int C = lengths[li];
            fill(x, xd, (size_t)N * C, 3.0, li % 2 ? 100.0 : 0.0);
            for (int affine = 0; affine < 2; affine++) {
                naive_layernorm(ref, xd, affine ? wd : NULL, affine ? bd : NULL, N, C, 1e-5);
                omp_set_num_threads(1);
                layernorm_forward(out, mean, rstd, x, affine ? w : NULL, affine ? b : NULL, N, C, 1e-5f);
                omp_set_num_threads(2);
                layernorm_forward(out2, NULL, NULL, x, affine ? w : NULL, affine ? b : NULL, N, C, 1e-5f);
                CHECK_MSG(!memcmp(out, out2, sizeof(float) * N * C), "level %d, C %d: 1 and 2 threads differ", level, C);
                double err = max_abs_diff_fd(out, ref, (size_t)N * C);
                if (err > worst) worst = err;
                CHECK_MSG(err < 2e-5, "level %d, C %d, affine %d: %.3g from the double reference", level, C, affine, err);
                double m0 = 0;
                for (int c = 0; c < C; c++) m0 += xd[c];
                CHECK_CLOSE(mean[0], m0 / C, 1e-6, 1e-6);
            }
            memcpy(out2, x, sizeof(float) * N * C);
            layernorm_forward(out2, NULL, NULL, out2, w, b, N, C, 1e-5f);   // in place
            layernorm_forward(out, NULL, NULL, x, w, b, N, C, 1e-5f);
            CHECK_MSG(!memcmp(out, out2, sizeof(float) * N * C), "level %d, C %d: in place differs", level, C);
        }
        printf("  level %d: within %.3g of the double reference\n", level, worst);
    }
    CHECK(levels >= 1);
    mlb_simd_force(-1);
    omp_set_num_threads(omp_get_num_procs());
    free(x); free(out); free(out2); free(xd); free(ref);
}

// d/dtheta of L = sum(dout * layernorm(x; w, b)) by central differences, in double.
TEST(layernorm_backward_fd) {
    enum { N = 5, C = 11 };
    double x[N * C], w[C], b[C], dout[N * C], out[N * C], mean[N], rstd[N];
    fill(NULL, x, N * C, 2.0, 0.5);
    fill(NULL, w, C, 0.5, 1.0);
    fill(NULL, b, C, 0.3, 0.0);
    fill(NULL, dout, N * C, 1.0, 0.0);
    double dx[N * C] = {0}, dw[C] = {0}, db[C] = {0};
    layernorm_forward_f64(out, mean, rstd, x, w, b, N, C, 1e-5);
    layernorm_backward_f64(dx, dw, db, dout, x, w, mean, rstd, N, C);
    double* params[3] = {x, w, b};
    double* grads[3] = {dx, dw, db};
    int sizes[3] = {N * C, C, C};
    double worst = 0;
    for (int k = 0; k < 3; k++)
        for (int i = 0; i < sizes[k]; i++) {
            double save = params[k][i], h = 1e-5, lp = 0, lm = 0;
            params[k][i] = save + h;
            layernorm_forward_f64(out, NULL, NULL, x, w, b, N, C, 1e-5);
            for (int j = 0; j < N * C; j++) lp += dout[j] * out[j];
            params[k][i] = save - h;
            layernorm_forward_f64(out, NULL, NULL, x, w, b, N, C, 1e-5);
            for (int j = 0; j < N * C; j++) lm += dout[j] * out[j];
            params[k][i] = save;
            double fd = (lp - lm) / (2 * h), an = grads[k][i];
            double rel = fabs(fd - an) / fmax(1e-3, fabs(fd) + fabs(an));
            if (rel > worst) worst = rel;
        }
    printf("  layernorm backward vs finite differences: max rel %.3g\n", worst);
    CHECK(worst < 1e-7);
    // accumulates: a second call doubles every gradient; NULL gradients are skipped
    double dx2[N * C], dw2[C], db2[C];
    memcpy(dx2, dx, sizeof dx); memcpy(dw2, dw, sizeof dw); memcpy(db2, db, sizeof db);
    layernorm_backward_f64(dx2, dw2, db2, dout, x, w, mean, rstd, N, C);
    int doubled = 1;
    for (int i = 0; i < N * C; i++) doubled &= fabs(dx2[i] - 2 * dx[i]) <= 1e-12 * (1 + fabs(dx[i]));
    for (int i = 0; i < C; i++) doubled &= fabs(dw2[i] - 2 * dw[i]) <= 1e-12 * (1 + fabs(dw[i]));
    for (int i = 0; i < C; i++) doubled &= fabs(db2[i] - 2 * db[i]) <= 1e-12 * (1 + fabs(db[i]));
    CHECK(doubled);
    layernorm_backward_f64(NULL, NULL, db2, dout, x, w, mean, rstd, N, C);
    CHECK_CLOSE(db2[0], 3 * db[0], 1e-12, 1e-14);
    // float version agrees with the double one
    float xf[N * C], wf[C], bf[C], doutf[N * C], outf[N * C], mf[N], rf[N], dxf[N * C] = {0}, dwf[C] = {0}, dbf[C] = {0};
    for (int i = 0; i < N * C; i++) { xf[i] = (float)x[i]; doutf[i] = (float)dout[i]; }
    for (int i = 0; i < C; i++) { wf[i] = (float)w[i]; bf[i] = (float)b[i]; }
    layernorm_forward(outf, mf, rf, xf, wf, bf, N, C, 1e-5f);
    layernorm_backward(dxf, dwf, dbf, doutf, xf, wf, mf, rf, N, C);
    CHECK(max_abs_diff_fd(dxf, dx, N * C) < 1e-4);
    CHECK(max_abs_diff_fd(dwf, dw, C) < 1e-4);
    CHECK(max_abs_diff_fd(dbf, db, C) < 1e-4);
}

// ---- attention ---------------------------------------------------------------------------------------
TEST(attention_matches_naive) {
    enum { B = 2, T = 9, C = 12, NH = 3 };
    float qkv[B * T * 3 * C], q[B * T * C], k[B * T * C], v[B * T * C];
    double qd[B * T * C], kd[B * T * C], vd[B * T * C];
    fill(qkv, NULL, B * T * 3 * C, 1.5, 0.0);
    for (int i = 0; i < B * T; i++)
        for (int c = 0; c < C; c++) {
            q[i * C + c] = qkv[i * 3 * C + c];         qd[i * C + c] = q[i * C + c];
            k[i * C + c] = qkv[i * 3 * C + C + c];     kd[i * C + c] = k[i * C + c];
            v[i * C + c] = qkv[i * 3 * C + 2 * C + c]; vd[i * C + c] = v[i * C + c];
        }
    for (int causal = 0; causal <= 1; causal++) {
        float out_f[B * T * C], out_s[B * T * C], att[B * NH * T * T];
        double ref[B * T * C], pref[B * NH * T * T];
        REQUIRE(attention_forward(out_f, att, qkv, qkv + C, qkv + 2 * C, 3 * C, B, T, C, NH, causal) == MLB_OK);
        REQUIRE(attention_forward(out_s, NULL, q, k, v, C, B, T, C, NH, causal) == MLB_OK);
        naive_attention(ref, pref, qd, kd, vd, B, T, C, NH, causal);
        CHECK(memcmp(out_f, out_s, sizeof out_f) == 0);   // fused and separate layouts: the same bits
        double e = max_abs_diff_fd(out_f, ref, B * T * C), ep = max_abs_diff_fd(att, pref, B * NH * T * T);
        printf("  attention (causal %d) float vs double: out max abs %.3g, probabilities %.3g\n", causal, e, ep);
        CHECK(e < 1e-5);
        CHECK(ep < 1e-6);
        int zeros = 1;
        for (int bh = 0; bh < B * NH; bh++)
            for (int t = 0; t < T; t++)
                for (int u = t + 1; u < T; u++) zeros &= !causal || att[(bh * T + t) * T + u] == 0.0f;
        CHECK(zeros);
        double out_d[B * T * C];
        REQUIRE(attention_forward_f64(out_d, NULL, qd, kd, vd, C, B, T, C, NH, causal) == MLB_OK);
        double e64 = 0;
        for (int i = 0; i < B * T * C; i++) e64 = fmax(e64, fabs(out_d[i] - ref[i]));
        CHECK(e64 < 1e-13);
    }
}

TEST(attention_causal_mask) {
    enum { B = 1, T = 10, C = 8, NH = 2, T0 = 6 };
    float qkv[B * T * 3 * C], out1[B * T * C], out2[B * T * C];
    fill(qkv, NULL, B * T * 3 * C, 1.0, 0.0);
    REQUIRE(attention_forward(out1, NULL, qkv, qkv + C, qkv + 2 * C, 3 * C, B, T, C, NH, 1) == MLB_OK);
    for (int t = T0; t < T; t++)   // change q, k, v of every token from T0 on
        for (int c = 0; c < 3 * C; c++) qkv[t * 3 * C + c] += 0.5f;
    REQUIRE(attention_forward(out2, NULL, qkv, qkv + C, qkv + 2 * C, 3 * C, B, T, C, NH, 1) == MLB_OK);
    CHECK(memcmp(out1, out2, T0 * C * sizeof(float)) == 0);
    CHECK(memcmp(out1 + T0 * C, out2 + T0 * C, (T - T0) * C * sizeof(float)) != 0);
}

TEST(attention_stable_softmax) {
    enum { B = 1, T = 7, C = 4, NH = 1 };
    float q[T * C], k[T * C], v[T * C], out[T * C];
    double qd[T * C], kd[T * C], vd[T * C], ref[T * C];
    fill(q, qd, T * C, 300.0, 0.0);   // scores of ~1e5: exp would overflow without the max shift
    fill(k, kd, T * C, 300.0, 0.0);
    fill(v, vd, T * C, 1.0, 0.0);
    REQUIRE(attention_forward(out, NULL, q, k, v, C, B, T, C, NH, 0) == MLB_OK);
    naive_attention(ref, NULL, qd, kd, vd, B, T, C, NH, 0);
    int finite = 1;
    for (int i = 0; i < T * C; i++) finite &= isfinite(out[i]);
    CHECK(finite);
    CHECK(max_abs_diff_fd(out, ref, T * C) < 1e-5);
}

TEST(attention_thread_independent) {
    enum { B = 2, T = 77, C = 64, NH = 4 };
    size_t n = (size_t)B * T * 3 * C;
    float* qkv = malloc(n * sizeof(float));
    float* o1 = malloc((size_t)B * T * C * sizeof(float));
    float* o4 = malloc((size_t)B * T * C * sizeof(float));
    REQUIRE(qkv && o1 && o4);
    fill(qkv, NULL, n, 1.0, 0.0);
    int saved = omp_get_max_threads();
    omp_set_num_threads(1);
    CHECK(attention_forward(o1, NULL, qkv, qkv + C, qkv + 2 * C, 3 * C, B, T, C, NH, 1) == MLB_OK);
    omp_set_num_threads(4);
    CHECK(attention_forward(o4, NULL, qkv, qkv + C, qkv + 2 * C, 3 * C, B, T, C, NH, 1) == MLB_OK);
    omp_set_num_threads(saved);
    CHECK(memcmp(o1, o4, (size_t)B * T * C * sizeof(float)) == 0);
    free(qkv); free(o1); free(o4);
}

TEST(attention_errors) {
    float buf[64] = {0};
    CHECK(attention_forward(buf, NULL, buf, buf, buf, 10, 1, 2, 10, 3, 1) == MLB_ERR_ARG);
    CHECK(strcmp(mlb_last_error(), "attention: width 10 is not a multiple of the 3 heads") == 0);
    CHECK(attention_forward(buf, NULL, buf, buf, buf, 4, 1, 2, 8, 2, 1) == MLB_ERR_ARG);
    CHECK(strcmp(mlb_last_error(), "attention: token stride 4 is less than the width 8") == 0);
    CHECK(attention_forward(NULL, NULL, NULL, NULL, NULL, 8, 0, 5, 8, 2, 1) == MLB_OK);   // empty batch
}

// ---- embedding ---------------------------------------------------------------------------------------
TEST(embedding_lookup) {
    enum { B = 2, T = 3, C = 4, V = 7 };
    float wte[V * C], wpe[T * C], out[B * T * C];
    fill(wte, NULL, V * C, 1.0, 0.0);
    fill(wpe, NULL, T * C, 1.0, 0.0);
    int tok[B * T] = {0, 6, 3, 2, 2, 5};
    REQUIRE(embedding_forward(out, tok, wte, wpe, B, T, C, V) == MLB_OK);
    int ok = 1;
    for (int b = 0; b < B; b++)
        for (int t = 0; t < T; t++)
            for (int c = 0; c < C; c++)
                ok &= out[(b * T + t) * C + c] == wte[tok[b * T + t] * C + c] + wpe[t * C + c];
    CHECK(ok);
    REQUIRE(embedding_forward(out, tok, wte, NULL, B, T, C, V) == MLB_OK);
    CHECK(out[C] == wte[6 * C]);
    tok[5] = 7;
    CHECK(embedding_forward(out, tok, wte, wpe, B, T, C, V) == MLB_ERR_ARG);
    CHECK(strcmp(mlb_last_error(), "token 7 at [1, 2] is outside the vocabulary [0, 7)") == 0);
    tok[5] = -1;
    CHECK(embedding_forward(out, tok, wte, wpe, B, T, C, V) == MLB_ERR_ARG);
    CHECK(strcmp(mlb_last_error(), "token -1 at [1, 2] is outside the vocabulary [0, 7)") == 0);
}

int main(void) {
    RUN(layernorm_matches_naive);
    RUN(layernorm_rows_every_level);
    RUN(layernorm_backward_fd);
    RUN(attention_matches_naive);
    RUN(attention_causal_mask);
    RUN(attention_stable_softmax);
    RUN(attention_thread_independent);
    RUN(attention_errors);
    RUN(embedding_lookup);
    return test_summary();
}
