// The latent BRDF auto-encoder: the MLP's forward-mode tangent and its backward, and the full
// loss (reconstruction + KL + smoothness through the decoder Jacobian + cyclic) checked against
// central finite differences in double precision.
#include "test.h"
#include <omp.h>
#include "matlaber/brdf.h"
#include "matlaber/brdf_ae.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"

static void random_fill_f64(double* x, size_t n, uint64_t stream, double scale) {
    for (size_t i = 0; i < n; i++) x[i] = scale * mlb_rng_normal_f64(7, stream, i);
}

// L(params, in, tin) = sum(wo * out) + sum(wt * tout) for an MLP with a smooth activation.
static double mlp_functional(mlb_mlp_f64* mlp, mlb_mlp_cache_f64* c, const double* in, const double* tin,
                             const double* wo, const double* wt, int B) {
    const double* out = mlp_forward_f64(mlp, c, in, B);
    int n = B * mlp->dims[mlp->n_layers];
    double L = 0;
    for (int i = 0; i < n; i++) L += wo[i] * out[i];
    const double* tout = mlp_jvp_forward_f64(mlp, c, tin, B);
    for (int i = 0; i < n; i++) L += wt[i] * tout[i];
    return L;
}

TEST(mlp_jvp_matches_finite_differences) {
    int dims[4] = {4, 9, 7, 7};
    mlb_activation acts[3] = {MLB_ACT_SILU, MLB_ACT_TANH, MLB_ACT_SOFTPLUS};
    for (int a = 0; a < 3; a++) {
        mlb_mlp_f64 mlp;
        size_t np = mlp_param_count_f64(3, dims, 1);
        double* params = malloc(sizeof(double) * np);
        random_fill_f64(params, np, 1, 0.5);
        REQUIRE(mlp_init_f64(&mlp, 3, dims, 1, acts[a], MLB_ACT_SIGMOID, params) == MLB_OK);
        enum { B = 5 };
        double in[B * 4], tin[B * 4], wo[B * 7], wt[B * 7];
        random_fill_f64(in, B * 4, 2, 1.0);
        random_fill_f64(tin, B * 4, 3, 1.0);
        random_fill_f64(wo, B * 7, 4, 1.0);
        random_fill_f64(wt, B * 7, 5, 1.0);
        mlb_mlp_cache_f64 c;
        REQUIRE(mlp_cache_alloc_f64(&c, &mlp, B) == MLB_OK);
        // the tangent equals the directional derivative of the output
        const double* out0 = mlp_forward_f64(&mlp, &c, in, B);
        double saved[B * 7];
        memcpy(saved, out0, sizeof saved);
        const double* tout = mlp_jvp_forward_f64(&mlp, &c, tin, B);
        double tcopy[B * 7];
        memcpy(tcopy, tout, sizeof tcopy);
        double h = 1e-6, xp[B * 4], xm[B * 4], op[B * 7];
        for (int i = 0; i < B * 4; i++) { xp[i] = in[i] + h * tin[i]; xm[i] = in[i] - h * tin[i]; }
        memcpy(op, mlp_forward_f64(&mlp, &c, xp, B), sizeof op);
        const double* om = mlp_forward_f64(&mlp, &c, xm, B);
        for (int i = 0; i < B * 7; i++) CHECK_CLOSE(tcopy[i], (op[i] - om[i]) / (2 * h), 1e-6, 1e-9);
        // backward of a functional of (out, tout) to params, in and tin
        double* dparams = calloc(np, sizeof(double));
        double din[B * 4] = {0}, dtin[B * 4] = {0};
        mlp_functional(&mlp, &c, in, tin, wo, wt, B);
        mlp_jvp_backward_f64(&mlp, &c, dparams, din, dtin, wo, wt, in, tin, B);
        for (size_t i = 0; i < np; i++) {
            double keep = params[i];
            params[i] = keep + h; double Lp = mlp_functional(&mlp, &c, in, tin, wo, wt, B);
            params[i] = keep - h; double Lm = mlp_functional(&mlp, &c, in, tin, wo, wt, B);
            params[i] = keep;
            CHECK_CLOSE(dparams[i], (Lp - Lm) / (2 * h), 1e-5, 1e-8);
        }
        for (int i = 0; i < B * 4; i++) {
            double keep = in[i];
            in[i] = keep + h; double Lp = mlp_functional(&mlp, &c, in, tin, wo, wt, B);
            in[i] = keep - h; double Lm = mlp_functional(&mlp, &c, in, tin, wo, wt, B);
            in[i] = keep;
            CHECK_CLOSE(din[i], (Lp - Lm) / (2 * h), 1e-5, 1e-8);
            keep = tin[i];
            tin[i] = keep + h; Lp = mlp_functional(&mlp, &c, in, tin, wo, wt, B);
            tin[i] = keep - h; Lm = mlp_functional(&mlp, &c, in, tin, wo, wt, B);
            tin[i] = keep;
            CHECK_CLOSE(dtin[i], (Lp - Lm) / (2 * h), 1e-5, 1e-8);
        }
        free(dparams);
        free(params);
        mlp_cache_free_f64(&c);
    }
}

static void random_brdfs_f64(double* k, int B, uint64_t stream) {
    for (int i = 0; i < B * 7; i++) {
        double u = mlb_rng_uniform_f64(11, stream, i);
        k[i] = (i % 7 == 6) ? MLB_KR_MIN + (1 - MLB_KR_MIN) * u : u;
    }
}

// Every loss term switched on with weights large enough to matter in the check.
static mlb_brdf_loss_config strong_terms(void) {
    mlb_brdf_loss_config lc = mlb_brdf_loss_default_config();
    lc.lambda_kl = 0.3; lc.lambda_s = 0.7; lc.lambda_c = 0.5; lc.n_alpha = 4;
    return lc;
}

TEST(loss_gradient_matches_finite_differences) {
    mlb_brdf_ae_config cfg = {.hidden = 6, .depth = 2, .act = MLB_ACT_SILU};
    mlb_brdf_ae_f64 ae;
    REQUIRE(brdf_ae_init_f64(&ae, &cfg, 3) == MLB_OK);
    // larger weights than the init so every nonlinearity is exercised
    for (size_t i = 0; i < ae.n_params; i++) ae.params[i] = 0.6 * mlb_rng_normal_f64(5, 1, i);
    enum { B = 6 };
    double k[B * 7];
    random_brdfs_f64(k, B, 1);
    mlb_brdf_work_f64 w;
    REQUIRE(brdf_work_alloc_f64(&w, &ae, B) == MLB_OK);
    mlb_brdf_loss_config configs[3] = {strong_terms(), mlb_brdf_loss_default_config(), strong_terms()};
    configs[2].smooth_form = MLB_BRDF_SMOOTH_BEND;
    for (int ci = 0; ci < 3; ci++) {
        mlb_brdf_loss_config lc = configs[ci];
        mlb_brdf_losses_f64 L;
        memset(ae.grads, 0, sizeof(double) * ae.n_params);
        REQUIRE(brdf_ae_loss_f64(&ae, &w, k, B, &lc, 9, 4, ae.grads, &L) == MLB_OK);
        CHECK(L.l_r > 0 && L.l_kl > 0 && L.l_s > 0 && L.l_c > 0);
        double h = 1e-6, worst = 0;
        for (size_t i = 0; i < ae.n_params; i++) {
            double keep = ae.params[i];
            mlb_brdf_losses_f64 Lp, Lm;
            ae.params[i] = keep + h; brdf_ae_loss_f64(&ae, &w, k, B, &lc, 9, 4, NULL, &Lp);
            ae.params[i] = keep - h; brdf_ae_loss_f64(&ae, &w, k, B, &lc, 9, 4, NULL, &Lm);
            ae.params[i] = keep;
            double fd = (Lp.total - Lm.total) / (2 * h);
            double err = fabs(ae.grads[i] - fd) / (fabs(fd) + 1e-6);
            if (err > worst) worst = err;
            // atol: the central difference's own rounding, ~1e-16 |L| / h
            CHECK_CLOSE(ae.grads[i], fd, 1e-5, 1e-9 + 1e-9 * fabs(L.total));
        }
        printf("  config %d: %zu parameters, worst relative error %.2e\n", ci, ae.n_params, worst);
    }
    brdf_work_free_f64(&w);
    brdf_ae_free_f64(&ae);
}

// Each term's gradient on its own: a term with a zero weight must contribute nothing, so checking
// the total with one weight at a time isolates a wrong term.
TEST(each_loss_term_gradient) {
    mlb_brdf_ae_config cfg = {.hidden = 5, .depth = 1, .act = MLB_ACT_TANH};
    mlb_brdf_ae_f64 ae;
    REQUIRE(brdf_ae_init_f64(&ae, &cfg, 4) == MLB_OK);
    for (size_t i = 0; i < ae.n_params; i++) ae.params[i] = 0.8 * mlb_rng_normal_f64(6, 1, i);
    enum { B = 4 };
    double k[B * 7];
    random_brdfs_f64(k, B, 2);
    mlb_brdf_work_f64 w;
    REQUIRE(brdf_work_alloc_f64(&w, &ae, B) == MLB_OK);
    // the last row is the smoothness term alone in its bend form
    double weights[5][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {0, 1, 0}};
    for (int t = 0; t < 5; t++) {
        mlb_brdf_loss_config lc = mlb_brdf_loss_default_config();
        lc.lambda_kl = weights[t][0]; lc.lambda_s = weights[t][1]; lc.lambda_c = weights[t][2];
        if (t == 4) lc.smooth_form = MLB_BRDF_SMOOTH_BEND;
        mlb_brdf_losses_f64 L;
        memset(ae.grads, 0, sizeof(double) * ae.n_params);
        REQUIRE(brdf_ae_loss_f64(&ae, &w, k, B, &lc, 2, 0, ae.grads, &L) == MLB_OK);
        double h = 1e-6;
        for (size_t i = 0; i < ae.n_params; i++) {
            double keep = ae.params[i];
            mlb_brdf_losses_f64 Lp, Lm;
            ae.params[i] = keep + h; brdf_ae_loss_f64(&ae, &w, k, B, &lc, 2, 0, NULL, &Lp);
            ae.params[i] = keep - h; brdf_ae_loss_f64(&ae, &w, k, B, &lc, 2, 0, NULL, &Lm);
            ae.params[i] = keep;
            CHECK_CLOSE(ae.grads[i], (Lp.total - Lm.total) / (2 * h), 1e-5, 1e-9);
        }
    }
    brdf_work_free_f64(&w);
    brdf_ae_free_f64(&ae);
}

// The smoothness term is the squared derivative of the decoded BRDF along the interpolation:
// compare tk_n with a finite difference of D(z_n(alpha)) in alpha.
TEST(smoothness_term_is_derivative_along_alpha) {
    mlb_brdf_ae_config cfg = {.hidden = 8, .depth = 2, .act = MLB_ACT_SILU};
    mlb_brdf_ae_f64 ae;
    REQUIRE(brdf_ae_init_f64(&ae, &cfg, 5) == MLB_OK);
    enum { B = 8 };
    double k[B * 7];
    random_brdfs_f64(k, B, 3);
    mlb_brdf_work_f64 w;
    REQUIRE(brdf_work_alloc_f64(&w, &ae, B) == MLB_OK);
    mlb_brdf_loss_config lc = mlb_brdf_loss_default_config();
    mlb_brdf_losses_f64 L;
    REQUIRE(brdf_ae_loss_f64(&ae, &w, k, B, &lc, 1, 0, NULL, &L) == MLB_OK);
    double h = 1e-6;
    for (int i = 0; i < B; i++) {
        int j = (i + 1) % B;
        double zp[4], zm[4], kp[7], km[7];
        for (int d = 0; d < 4; d++) {
            double zi = w.z[i * 4 + d], zj = w.z[j * 4 + d], a = w.alpha[i];
            zp[d] = (a + h) * zi + (1 - a - h) * zj;
            zm[d] = (a - h) * zi + (1 - a + h) * zj;
        }
        brdf_ae_decode_f64(&ae, zp, 1, kp);
        brdf_ae_decode_f64(&ae, zm, 1, km);
        for (int c = 0; c < 7; c++) CHECK_CLOSE(w.tk_n[i * 7 + c], (kp[c] - km[c]) / (2 * h), 1e-6, 1e-10);
    }
    // the bend form: |tk_n - (D(z_i) - D(z_j))|^2 with the ends decoded here, not read from the work
    lc.smooth_form = MLB_BRDF_SMOOTH_BEND;
    REQUIRE(brdf_ae_loss_f64(&ae, &w, k, B, &lc, 1, 0, NULL, &L) == MLB_OK);
    double ends[B * 7], bend = 0;
    brdf_ae_decode_f64(&ae, w.z, B, ends);
    for (int i = 0; i < B; i++)
        for (int c = 0; c < 7; c++) {
            double d = w.tk_n[i * 7 + c] - (ends[i * 7 + c] - ends[((i + 1) % B) * 7 + c]);
            bend += d * d / B;
        }
    CHECK_CLOSE(L.l_s, bend, 1e-12, 1e-15);
    brdf_work_free_f64(&w);
    brdf_ae_free_f64(&ae);
}

TEST(float_and_double_models_agree) {
    mlb_brdf_ae_config cfg = mlb_brdf_ae_default_config();
    mlb_brdf_ae ae;
    mlb_brdf_ae_f64 ae64;
    REQUIRE(brdf_ae_init(&ae, &cfg, 8) == MLB_OK);
    REQUIRE(brdf_ae_init_f64(&ae64, &cfg, 8) == MLB_OK);
    for (size_t i = 0; i < ae.n_params; i++) CHECK_CLOSE(ae.params[i], ae64.params[i], 1e-6, 1e-7);
    enum { B = 32 };
    double k64[B * 7];
    float k[B * 7];
    random_brdfs_f64(k64, B, 4);
    for (int i = 0; i < B * 7; i++) k[i] = (float)k64[i];
    for (size_t i = 0; i < ae.n_params; i++) ae64.params[i] = ae.params[i];
    mlb_brdf_work w; mlb_brdf_work_f64 w64;
    REQUIRE(brdf_work_alloc(&w, &ae, B) == MLB_OK);
    REQUIRE(brdf_work_alloc_f64(&w64, &ae64, B) == MLB_OK);
    mlb_brdf_loss_config lc = mlb_brdf_loss_default_config();
    mlb_brdf_losses L; mlb_brdf_losses_f64 L64;
    memset(ae.grads, 0, sizeof(float) * ae.n_params);
    memset(ae64.grads, 0, sizeof(double) * ae64.n_params);
    REQUIRE(brdf_ae_loss(&ae, &w, k, B, &lc, 3, 1, ae.grads, &L) == MLB_OK);
    REQUIRE(brdf_ae_loss_f64(&ae64, &w64, k64, B, &lc, 3, 1, ae64.grads, &L64) == MLB_OK);
    CHECK_CLOSE(L.total, L64.total, 1e-4, 1e-7);
    double gmax = 0;
    for (size_t i = 0; i < ae.n_params; i++) gmax = fmax(gmax, fabs(ae64.grads[i]));
    for (size_t i = 0; i < ae.n_params; i++) CHECK_CLOSE(ae.grads[i], ae64.grads[i], 1e-3, 1e-4 * gmax);
    brdf_work_free(&w); brdf_work_free_f64(&w64);
    brdf_ae_free(&ae); brdf_ae_free_f64(&ae64);
}

TEST(decoded_brdfs_are_valid_for_any_latent) {
    mlb_brdf_ae_config cfg = mlb_brdf_ae_default_config();
    mlb_brdf_ae ae;
    REQUIRE(brdf_ae_init(&ae, &cfg, 2) == MLB_OK);
    for (size_t i = 0; i < ae.n_params; i++) ae.params[i] *= 3;   // wilder than any trained model
    enum { N = 2000 };
    float* z = malloc(sizeof(float) * 4 * N);
    float* kk = malloc(sizeof(float) * 7 * N);
    for (int i = 0; i < 4 * N; i++) z[i] = 10 * mlb_rng_normal(1, 2, i);
    REQUIRE(brdf_ae_decode(&ae, z, N, kk) == MLB_OK);
    int valid = 0;
    for (int i = 0; i < N; i++) valid += mlb_brdf_valid(kk + 7 * i);
    CHECK(valid == N);
    free(z); free(kk);
    brdf_ae_free(&ae);
}

static void train_small_with(int threads, int encoder_epochs, float* params_out, size_t* n_out, size_t* n_enc_out,
                             double* loss_out, double* refined_out) {
    mlb_set_threads(threads);
    mlb_brdf_ae_config cfg = {.hidden = 16, .depth = 2, .act = MLB_ACT_SILU};
    mlb_brdf_ae ae;
    brdf_ae_init(&ae, &cfg, 1);
    enum { N = 3000 };
    float* data = malloc(sizeof(float) * 7 * N);
    for (int i = 0; i < N; i++) {   // a 2-parameter family: albedo grey level and roughness
        float g = mlb_rng_uniform(4, 1, i), r = mlb_rng_uniform(4, 2, i);
        for (int c = 0; c < 3; c++) { data[7 * i + c] = 0.1f + 0.8f * g; data[7 * i + 3 + c] = 0.04f; }
        data[7 * i + 6] = MLB_KR_MIN + (1 - MLB_KR_MIN) * r;
    }
    mlb_brdf_train_config tc = mlb_brdf_train_default_config();
    tc.epochs = 12; tc.batch = 64; tc.lr = 3e-3; tc.encoder_epochs = encoder_epochs;
    mlb_brdf_ae_train(&ae, data, N, &tc, NULL, NULL, NULL);
    mlb_brdf_eval_result r;
    mlb_brdf_ae_evaluate(&ae, data, N, 1, &r);
    memcpy(params_out, ae.params, sizeof(float) * ae.n_params);
    *n_out = ae.n_params;
    if (n_enc_out) *n_enc_out = ae.n_enc_params;
    *loss_out = r.rmse_all;
    if (refined_out) *refined_out = r.fit_rmse_all;
    free(data);
    brdf_ae_free(&ae);
}

static void train_small(int threads, float* params_out, size_t* n_out, double* loss_out) {
    train_small_with(threads, mlb_brdf_train_default_config().encoder_epochs, params_out, n_out, NULL, loss_out, NULL);
}

// The encoder phase after the joint epochs leaves the decoder (the prior the appearance stage
// uses) bitwise as the joint epochs left it, and closes most of the gap between the one-pass
// encode-decode error and what the decoder reaches with a refined latent.
TEST(encoder_phase_freezes_the_decoder_and_closes_the_gap) {
    static float joint[20000], refit[20000];
    size_t n1, n2, n_enc;
    double rmse_joint, rmse_refit, reach;
    train_small_with(2, 0, joint, &n1, &n_enc, &rmse_joint, &reach);
    train_small_with(2, 40, refit, &n2, NULL, &rmse_refit, NULL);
    REQUIRE(n1 == n2 && n_enc < n1);
    CHECK(memcmp(joint + n_enc, refit + n_enc, sizeof(float) * (n1 - n_enc)) == 0);
    CHECK(memcmp(joint, refit, sizeof(float) * n_enc) != 0);
    printf("  encode-decode rmse %.4f after the joint epochs, %.4f after the encoder's; refined latent %.4f\n",
           rmse_joint, rmse_refit, reach);
    CHECK(rmse_refit - reach < 0.6 * (rmse_joint - reach));   // measured: half of the gap closed
}

TEST(training_learns_and_is_deterministic_across_thread_counts) {
    static float p1[20000], p2[20000];
    size_t n1, n2;
    double rmse1, rmse2;
    train_small(1, p1, &n1, &rmse1);
    train_small(2, p2, &n2, &rmse2);
    REQUIRE(n1 == n2 && n1 < 20000);
    CHECK(memcmp(p1, p2, sizeof(float) * n1) == 0);
    printf("  rmse after training %.4f\n", rmse1);
    CHECK(rmse1 < 0.03);   // the data has 2 degrees of freedom; an untrained decoder is ~0.3 off
}

// Latent refinement recovers a code the decoder can reach: decode a known z, start from a perturbed
// code, and the Levenberg-Marquardt fit must reproduce the BRDF to near machine precision.
TEST(latent_fit_recovers_reachable_brdfs) {
    mlb_brdf_ae_config cfg = {.hidden = 16, .depth = 2, .act = MLB_ACT_SILU};
    mlb_brdf_ae_f64 ae;
    REQUIRE(brdf_ae_init_f64(&ae, &cfg, 12) == MLB_OK);
    enum { N = 64 };
    double z_true[N * 4], z[N * 4], k[N * 7], k_fit[N * 7];
    for (int i = 0; i < N * 4; i++) {
        z_true[i] = mlb_rng_normal_f64(3, 1, i);
        z[i] = z_true[i] + 0.3 * mlb_rng_normal_f64(3, 2, i);
    }
    REQUIRE(brdf_ae_decode_f64(&ae, z_true, N, k) == MLB_OK);
    REQUIRE(brdf_ae_decode_f64(&ae, z, N, k_fit) == MLB_OK);
    double before = 0, after = 0;
    for (int i = 0; i < N * 7; i++) before = fmax(before, fabs(k_fit[i] - k[i]));
    REQUIRE(brdf_ae_fit_latent_f64(&ae, k, N, z, 40) == MLB_OK);
    REQUIRE(brdf_ae_decode_f64(&ae, z, N, k_fit) == MLB_OK);
    for (int i = 0; i < N * 7; i++) after = fmax(after, fabs(k_fit[i] - k[i]));
    printf("  largest BRDF error: %.2e before, %.2e after the fit\n", before, after);
    CHECK(before > 1e-3);
    CHECK(after < 1e-9);
    brdf_ae_free_f64(&ae);
}

int main(void) {
    RUN(mlp_jvp_matches_finite_differences);
    RUN(loss_gradient_matches_finite_differences);
    RUN(each_loss_term_gradient);
    RUN(smoothness_term_is_derivative_along_alpha);
    RUN(float_and_double_models_agree);
    RUN(decoded_brdfs_are_valid_for_any_latent);
    RUN(latent_fit_recovers_reachable_brdfs);
    RUN(training_learns_and_is_deterministic_across_thread_counts);
    RUN(encoder_phase_freezes_the_decoder_and_closes_the_gap);
    return test_summary();
}
