// CUDA kernels against their CPU versions on the same random inputs: Adam/AdamW, linear forward and
// backward at every GEMM precision, the activations, layer norm and group norm (forward, backward). Skips (exit 77, "no
// CUDA device: ...") when this build has no CUDA part or the machine has no GPU;
// scripts/gpu-parity.sh runs it on a GPU machine.
//
// Bounds (relative L2 error ||gpu - cpu|| / ||cpu||, from the unit roundoff u of the arithmetic):
//   fp32 GEMM: different summation orders, error ~ sqrt(K) u32 ~ 1e-6 -> 1e-5
//   tf32 and fp16 operands: u = 2^-11 per operand, two operands, random signs -> ~7e-4 -> 3e-3
//   bf16 operands: u = 2^-8 -> ~5.5e-3 -> 2e-2
//   elementwise float formulas (same expressions, CUDA's libm within 2 ulp of glibc's) -> 1e-5
//   norms: statistics in double both sides, one rounding of xhat -> 1e-6; backward: float products
//   before the double sums, FMA contraction on the GPU -> 1e-5
#include "cuda_test_util.h"
#include "matlaber/conv_ops.h"
#include "matlaber/nn.h"
#include "matlaber/transformer_ops.h"

TEST(adam_update_matches_cpu) {
    REQUIRE_GPU();
    enum { N = 100003 };   // not a multiple of the block size
    static float p_cpu[N], p_gpu[N], g[N], m_cpu[N], v_cpu[N], m_gpu[N], v_gpu[N];
    uint64_t seed = test_seed();
    for (int i = 0; i < N; i++) {
        p_cpu[i] = p_gpu[i] = mlb_rng_normal(seed, 1, i);
        m_cpu[i] = v_cpu[i] = m_gpu[i] = v_gpu[i] = 0;
    }
    float *dp = dev_floats(p_gpu, N), *dg = dev_floats(NULL, N), *dm = dev_floats(m_gpu, N), *dv = dev_floats(v_gpu, N);
    REQUIRE(dp && dg && dm && dv);
    for (int decoupled = 0; decoupled <= 1; decoupled++) {
        mlb_adam_config cfg = {.lr = 1e-2, .beta1 = 0.9, .beta2 = 0.99, .eps = 1e-15, .weight_decay = 0.05, .decoupled = decoupled};
        for (long t = 1; t <= 5; t++) {
            for (int i = 0; i < N; i++) g[i] = mlb_rng_normal(seed + 1, (uint64_t)t + 10 * decoupled, i);
            REQUIRE(mlb_cuda_copy_to_device(dg, g, sizeof g) == MLB_OK);
            REQUIRE(mlb_cuda_adam_update(dp, dg, dm, dv, N, &cfg, t) == MLB_OK);
            adam_update(p_cpu, g, m_cpu, v_cpu, N, &cfg, t);
        }
    }
    REQUIRE(host_floats(p_gpu, dp, N));
    double worst = 0;
    for (int i = 0; i < N; i++) {
        CHECK(isfinite(p_gpu[i]));
        worst = fmax(worst, fabs((double)p_gpu[i] - p_cpu[i]) / (fabs(p_cpu[i]) + 1e-3));
    }
    printf("  worst relative difference %.2e over %d parameters\n", worst, N);
    CHECK(worst < 1e-5);
    mlb_cuda_free(dp); mlb_cuda_free(dg); mlb_cuda_free(dm); mlb_cuda_free(dv);
}

// Forward and backward of one linear layer at one precision, against the CPU in float.
static void linear_case(int B, int C, int OC, int with_bias, mlb_gemm_precision prec, double tol, uint64_t seed) {
    size_t nin = (size_t)B * C, nw = (size_t)OC * C, nout = (size_t)B * OC;
    float *in = host_alloc(nin), *w = host_alloc(nw), *b = host_alloc(OC), *dout = host_alloc(nout);
    float *out_c = host_alloc(nout), *out_g = host_alloc(nout);
    float *din_c = host_alloc(nin), *din_g = host_alloc(nin), *dw_c = host_alloc(nw), *dw_g = host_alloc(nw);
    float *db_c = host_alloc(OC), *db_g = host_alloc(OC);
    fill_uniform(in, nin, seed, 1, -1, 1);
    fill_uniform(w, nw, seed, 2, -0.5f, 0.5f);
    fill_uniform(b, OC, seed, 3, -1, 1);
    fill_uniform(dout, nout, seed, 4, -1, 1);
    // backward accumulates: start the gradients from a nonzero value on both sides
    fill_uniform(din_c, nin, seed, 5, -1, 1);
    fill_uniform(dw_c, nw, seed, 6, -1, 1);
    fill_uniform(db_c, OC, seed, 7, -1, 1);
    float *d_in = dev_floats(in, nin), *d_w = dev_floats(w, nw), *d_b = dev_floats(b, OC), *d_dout = dev_floats(dout, nout);
    float *d_out = dev_floats(NULL, nout), *d_din = dev_floats(din_c, nin), *d_dw = dev_floats(dw_c, nw),
          *d_db = dev_floats(db_c, OC);
    char what[128];
    if (!(d_in && d_w && d_b && d_dout && d_out && d_din && d_dw && d_db)) {
        CHECK_MSG(0, "device allocation: %s", mlb_last_error());
        goto done;
    }
    linear_forward(out_c, in, w, with_bias ? b : NULL, B, C, OC);
    linear_backward(din_c, dw_c, db_c, dout, in, w, B, C, OC);
    CHECK_MSG(mlb_cuda_linear_forward(d_out, d_in, d_w, with_bias ? d_b : NULL, B, C, OC, prec) == MLB_OK, "%s", mlb_last_error());
    CHECK_MSG(mlb_cuda_linear_backward(d_din, d_dw, d_db, d_dout, d_in, d_w, B, C, OC, prec) == MLB_OK, "%s", mlb_last_error());
    if (!host_floats(out_g, d_out, nout) || !host_floats(din_g, d_din, nin) || !host_floats(dw_g, d_dw, nw) ||
        !host_floats(db_g, d_db, OC)) {
        CHECK_MSG(0, "copy back: %s", mlb_last_error());
        goto done;
    }
    snprintf(what, sizeof what, "linear %s %dx%dx%d%s out", mlb_gemm_precision_name(prec), B, C, OC, with_bias ? "+b" : "");
    CHECK_PARITY(what, out_g, out_c, nout, tol);
    snprintf(what, sizeof what, "linear %s %dx%dx%d din", mlb_gemm_precision_name(prec), B, C, OC);
    CHECK_PARITY(what, din_g, din_c, nin, tol);
    snprintf(what, sizeof what, "linear %s %dx%dx%d dweight", mlb_gemm_precision_name(prec), B, C, OC);
    CHECK_PARITY(what, dw_g, dw_c, nw, tol);
    snprintf(what, sizeof what, "linear %s %dx%dx%d dbias", mlb_gemm_precision_name(prec), B, C, OC);
    CHECK_PARITY(what, db_g, db_c, OC, 1e-6);   // float sums in double on both sides
done:
    mlb_cuda_free(d_in); mlb_cuda_free(d_w); mlb_cuda_free(d_b); mlb_cuda_free(d_dout);
    mlb_cuda_free(d_out); mlb_cuda_free(d_din); mlb_cuda_free(d_dw); mlb_cuda_free(d_db);
    free(in); free(w); free(b); free(dout); free(out_c); free(out_g); free(din_c); free(din_g);
    free(dw_c); free(dw_g); free(db_c); free(db_g);
}

TEST(linear_matches_cpu) {
    REQUIRE_GPU();
    uint64_t seed = test_seed();
    const mlb_gemm_precision precs[4] = {MLB_GEMM_FP32, MLB_GEMM_TF32, MLB_GEMM_FP16, MLB_GEMM_BF16};
    const double tols[4] = {1e-5, 3e-3, 3e-3, 2e-2};
    for (int p = 0; p < 4; p++) {
        linear_case(37, 61, 29, 1, precs[p], tols[p], seed + 10 * p);        // odd sizes
        linear_case(256, 320, 1280, 0, precs[p], tols[p], seed + 10 * p + 1); // UNet-like
        linear_case(1, 768, 3, 1, precs[p], tols[p], seed + 10 * p + 2);     // a single row
    }
}

TEST(activations_match_cpu) {
    REQUIRE_GPU();
    enum { N = 20011 };
    static float x[N], dout[N], f_c[N], f_g[N], d1_c[N], d1_g[N], din_c[N], din_g[N];
    uint64_t seed = test_seed();
    // mostly |x| < 6, plus the tails and exact values where branches switch
    fill_uniform(x, N, seed, 20, -6, 6);
    const float special[] = {0.0f, -0.0f, 1e-30f, -1e-30f, 20.0f, -20.0f, 88.0f, -88.0f, 1e4f, -1e4f, 30.5f, -17.3f};
    for (int i = 0; i < (int)(sizeof special / sizeof special[0]); i++) x[i] = special[i];
    fill_uniform(dout, N, seed, 21, -1, 1);
    float *dx = dev_floats(x, N), *dd = dev_floats(dout, N), *df = dev_floats(NULL, N), *dd1 = dev_floats(NULL, N),
          *ddin = dev_floats(NULL, N);
    REQUIRE(dx && dd && df && dd1 && ddin);
    for (int a = 0; a < MLB_ACT_COUNT; a++) {
        mlb_activation act = (mlb_activation)a;
        fill_uniform(din_c, N, seed, 22 + a, -1, 1);
        REQUIRE(mlb_cuda_copy_to_device(ddin, din_c, sizeof din_c) == MLB_OK);
        for (int i = 0; i < N; i++) { f_c[i] = mlb_act(act, x[i]); d1_c[i] = mlb_act_d1(act, x[i]); }
        activation_backward(din_c, dout, x, N, act);
        REQUIRE(mlb_cuda_activation_forward_d1(df, dd1, dx, N, act) == MLB_OK);
        REQUIRE(mlb_cuda_activation_backward(ddin, dd, dx, N, act) == MLB_OK);
        REQUIRE(host_floats(f_g, df, N) && host_floats(d1_g, dd1, N) && host_floats(din_g, ddin, N));
        char what[96];
        snprintf(what, sizeof what, "%s f", mlb_activation_name(act));
        CHECK_PARITY(what, f_g, f_c, N, 1e-5);
        snprintf(what, sizeof what, "%s f'", mlb_activation_name(act));
        CHECK_PARITY(what, d1_g, d1_c, N, 1e-5);
        snprintf(what, sizeof what, "%s backward", mlb_activation_name(act));
        CHECK_PARITY(what, din_g, din_c, N, 1e-5);
        // elementwise too: a wrong tail is invisible in the L2 norm of the whole array
        int worst = 0;
        double we = 0;
        for (int i = 0; i < N; i++) {
            double e = fabs((double)f_g[i] - f_c[i]) / (fabs(f_c[i]) + 1e-6);
            if (e > we) we = e, worst = i;
        }
        CHECK_MSG(we < 1e-4, "%s: f(%g) = %g on the GPU, %g on the CPU", mlb_activation_name(act), x[worst], f_g[worst], f_c[worst]);
    }
    // the forward without d1, in place (out aliases in)
    REQUIRE(mlb_cuda_activation_forward(dx, dx, N, MLB_ACT_SILU) == MLB_OK);
    REQUIRE(host_floats(f_g, dx, N));
    activation_forward(f_c, x, N, MLB_ACT_SILU);
    CHECK_PARITY("silu in place", f_g, f_c, N, 1e-5);
    mlb_cuda_free(dx); mlb_cuda_free(dd); mlb_cuda_free(df); mlb_cuda_free(dd1); mlb_cuda_free(ddin);
}

TEST(layernorm_matches_cpu) {
    REQUIRE_GPU();
    uint64_t seed = test_seed();
    const int shapes[3][2] = {{77, 768}, {300, 320}, {5, 33}};
    for (int s = 0; s < 3; s++) {
        int N = shapes[s][0], C = shapes[s][1];
        size_t n = (size_t)N * C;
        float *x = host_alloc(n), *w = host_alloc(C), *b = host_alloc(C), *o_c = host_alloc(n), *o_g = host_alloc(n);
        float *m_c = host_alloc(N), *r_c = host_alloc(N), *m_g = host_alloc(N), *r_g = host_alloc(N);
        fill_uniform(x, n, seed, 30 + s, -3, 5);   // offset mean: the two-pass variance matters
        fill_uniform(w, C, seed, 40 + s, 0.5f, 1.5f);
        fill_uniform(b, C, seed, 50 + s, -1, 1);
        float *dx = dev_floats(x, n), *dw = dev_floats(w, C), *db = dev_floats(b, C), *dout = dev_floats(NULL, n),
              *dm = dev_floats(NULL, N), *dr = dev_floats(NULL, N);
        REQUIRE(dx && dw && db && dout && dm && dr);
        layernorm_forward(o_c, m_c, r_c, x, w, b, N, C, 1e-5f);
        REQUIRE(mlb_cuda_layernorm_forward(dout, dm, dr, dx, dw, db, N, C, 1e-5f) == MLB_OK);
        REQUIRE(host_floats(o_g, dout, n) && host_floats(m_g, dm, N) && host_floats(r_g, dr, N));
        CHECK_PARITY("layernorm out", o_g, o_c, n, 1e-6);
        CHECK_PARITY("layernorm mean", m_g, m_c, N, 1e-6);
        CHECK_PARITY("layernorm rstd", r_g, r_c, N, 1e-6);
        {   // backward onto random starting gradients, each side with its own forward statistics
            float *go = host_alloc(n), *dx_c = host_alloc(n), *dx_g = host_alloc(n), *dw_c = host_alloc(C), *dw_g = host_alloc(C),
                  *db_c = host_alloc(C), *db_g = host_alloc(C);
            fill_uniform(go, n, seed, 90 + s, -1, 1);
            fill_uniform(dx_c, n, seed, 93 + s, -1, 1);
            fill_uniform(dw_c, C, seed, 96 + s, -1, 1);
            fill_uniform(db_c, C, seed, 99 + s, -1, 1);
            float *d_go = dev_floats(go, n), *d_dx = dev_floats(dx_c, n), *d_dw = dev_floats(dw_c, C), *d_db = dev_floats(db_c, C);
            REQUIRE(d_go && d_dx && d_dw && d_db);
            layernorm_backward(dx_c, dw_c, db_c, go, x, w, m_c, r_c, N, C);
            REQUIRE(mlb_cuda_layernorm_backward(d_dx, d_dw, d_db, d_go, dx, dw, dm, dr, N, C) == MLB_OK);
            REQUIRE(host_floats(dx_g, d_dx, n) && host_floats(dw_g, d_dw, C) && host_floats(db_g, d_db, C));
            CHECK_PARITY("layernorm backward din", dx_g, dx_c, n, 1e-5);
            CHECK_PARITY("layernorm backward dweight", dw_g, dw_c, C, 1e-5);
            CHECK_PARITY("layernorm backward dbias", db_g, db_c, C, 1e-6);
            mlb_cuda_free(d_go); mlb_cuda_free(d_dx); mlb_cuda_free(d_dw); mlb_cuda_free(d_db);
            free(go); free(dx_c); free(dx_g); free(dw_c); free(dw_g); free(db_c); free(db_g);
        }
        // no weight/bias, in place
        layernorm_forward(o_c, NULL, NULL, x, NULL, NULL, N, C, 1e-5f);
        REQUIRE(mlb_cuda_layernorm_forward(dx, NULL, NULL, dx, NULL, NULL, N, C, 1e-5f) == MLB_OK);
        REQUIRE(host_floats(o_g, dx, n));
        CHECK_PARITY("layernorm in place, no affine", o_g, o_c, n, 1e-6);
        mlb_cuda_free(dx); mlb_cuda_free(dw); mlb_cuda_free(db); mlb_cuda_free(dout); mlb_cuda_free(dm); mlb_cuda_free(dr);
        free(x); free(w); free(b); free(o_c); free(o_g); free(m_c); free(r_c); free(m_g); free(r_g);
    }
}

TEST(groupnorm_matches_cpu) {
    REQUIRE_GPU();
    uint64_t seed = test_seed();
    // N, C, HW, G: a UNet block at 64^2 (G = 32), odd sizes, one group
    const int shapes[3][4] = {{2, 320, 64 * 64, 32}, {3, 12, 37, 3}, {1, 8, 1000, 1}};
    for (int s = 0; s < 3; s++) {
        int N = shapes[s][0], C = shapes[s][1], HW = shapes[s][2], G = shapes[s][3];
        size_t n = (size_t)N * C * HW;
        float *x = host_alloc(n), *w = host_alloc(C), *b = host_alloc(C), *o_c = host_alloc(n), *o_g = host_alloc(n);
        float *m_c = host_alloc((size_t)N * G), *r_c = host_alloc((size_t)N * G), *m_g = host_alloc((size_t)N * G),
              *r_g = host_alloc((size_t)N * G);
        fill_uniform(x, n, seed, 60 + s, -2, 4);
        fill_uniform(w, C, seed, 70 + s, 0.5f, 1.5f);
        fill_uniform(b, C, seed, 80 + s, -1, 1);
        float *dx = dev_floats(x, n), *dw = dev_floats(w, C), *db = dev_floats(b, C), *dout = dev_floats(NULL, n),
              *dm = dev_floats(NULL, (size_t)N * G), *dr = dev_floats(NULL, (size_t)N * G);
        REQUIRE(dx && dw && db && dout && dm && dr);
        for (int a = 0; a < 2; a++) {
            mlb_activation act = a ? MLB_ACT_SILU : MLB_ACT_IDENTITY;
            REQUIRE(groupnorm_forward(o_c, m_c, r_c, x, w, b, N, C, HW, G, 1e-6f, act) == MLB_OK);
            REQUIRE(mlb_cuda_groupnorm_forward(dout, dm, dr, dx, dw, db, N, C, HW, G, 1e-6f, act) == MLB_OK);
            REQUIRE(host_floats(o_g, dout, n) && host_floats(m_g, dm, (size_t)N * G) && host_floats(r_g, dr, (size_t)N * G));
            char what[96];
            snprintf(what, sizeof what, "groupnorm %dx%dx%d G%d %s", N, C, HW, G, mlb_activation_name(act));
            CHECK_PARITY(what, o_g, o_c, n, 1e-6);
            CHECK_PARITY("groupnorm mean", m_g, m_c, (size_t)N * G, 1e-6);
            CHECK_PARITY("groupnorm rstd", r_g, r_c, (size_t)N * G, 1e-6);
            // backward onto random starting gradients
            float *go = host_alloc(n), *dx_c = host_alloc(n), *dx_g = host_alloc(n), *dw_c = host_alloc(C), *dw_g = host_alloc(C),
                  *db_c = host_alloc(C), *db_g = host_alloc(C);
            fill_uniform(go, n, seed, 110 + s, -1, 1);
            fill_uniform(dx_c, n, seed, 113 + s, -1, 1);
            fill_uniform(dw_c, C, seed, 116 + s, -1, 1);
            fill_uniform(db_c, C, seed, 119 + s, -1, 1);
            float *d_go = dev_floats(go, n), *d_dx = dev_floats(dx_c, n), *d_dw = dev_floats(dw_c, C), *d_db = dev_floats(db_c, C);
            REQUIRE(d_go && d_dx && d_dw && d_db);
            REQUIRE(groupnorm_backward(dx_c, dw_c, db_c, go, x, w, b, m_c, r_c, N, C, HW, G, act) == MLB_OK);
            REQUIRE(mlb_cuda_groupnorm_backward(d_dx, d_dw, d_db, d_go, dx, dw, db, dm, dr, N, C, HW, G, act) == MLB_OK);
            REQUIRE(host_floats(dx_g, d_dx, n) && host_floats(dw_g, d_dw, C) && host_floats(db_g, d_db, C));
            snprintf(what, sizeof what, "groupnorm backward din (%s)", mlb_activation_name(act));
            CHECK_PARITY(what, dx_g, dx_c, n, 1e-5);
            CHECK_PARITY("groupnorm backward dweight", dw_g, dw_c, C, 1e-5);
            CHECK_PARITY("groupnorm backward dbias", db_g, db_c, C, 1e-5);
            mlb_cuda_free(d_go); mlb_cuda_free(d_dx); mlb_cuda_free(d_dw); mlb_cuda_free(d_db);
            free(go); free(dx_c); free(dx_g); free(dw_c); free(dw_g); free(db_c); free(db_g);
        }
        mlb_cuda_free(dx); mlb_cuda_free(dw); mlb_cuda_free(db); mlb_cuda_free(dout); mlb_cuda_free(dm); mlb_cuda_free(dr);
        free(x); free(w); free(b); free(o_c); free(o_g); free(m_c); free(r_c); free(m_g); free(r_g);
    }
}

int main(void) {
    RUN(adam_update_matches_cpu);
    RUN(linear_matches_cpu);
    RUN(activations_match_cpu);
    RUN(layernorm_matches_cpu);
    RUN(groupnorm_matches_cpu);
    return test_summary();
}
