// The latent BRDF auto-encoder: model, loss (reconstruction, KL, interpolation smoothness through
// the decoder's Jacobian, cyclic) and its exact backward. Dual-compiled (float / double _f64).
//
// Per batch k [B,7]:
//   x = 2k - 1;  [mu | logvar] = E(x);  z = mu + exp(logvar/2) eps;  k_hat = map(D(z))
//   pairs (i, j = (i + 1) mod B) of the shuffled batch, alpha_i = (i mod A) / (A - 1):
//   z_n = alpha z_i + (1 - alpha) z_j;  dir = z_i - z_j = dz_n/dalpha
//   k_n = map(D(z_n));  tk_n = J_map J_D(z_n) dir   (forward-mode tangent = dk_n/dalpha)
//   zhat_n = mu(E(2 k_n - 1))
// Each term is a per-sample squared L2 norm averaged over the batch, as the formulas read
// (reference.md §1): L_r = mean_b |k_hat - k|^2, L_KL = mean_b sum_d KL_d, L_s = mean_b |tk_n|^2
// (speed form) or mean_b |tk_n - (k_hat_i - k_hat_j)|^2 (bend form), L_c = mean_b |zhat_n - z_n|^2.
// map(s) = lo + (hi - lo) s puts the decoder's sigmoid outputs into the valid ranges.
#include <stdlib.h>
#include <string.h>
#include "matlaber/brdf.h"
#include "matlaber/brdf_ae.h"
#include "matlaber/rng.h"
#include "core/real.h"

#define K_DIM 7
#define Z_DIM MLB_LATENT_DIM
#define STREAM_INIT_ENC 0x1001
#define STREAM_INIT_DEC 0x1002
#define STREAM_EPS 0x2001


mlb_status FN(brdf_ae_init)(FN(mlb_brdf_ae)* ae, const mlb_brdf_ae_config* cfg, uint64_t seed) {
    memset(ae, 0, sizeof *ae);
    if (cfg->hidden < 1 || cfg->depth < 1 || cfg->depth > MLB_MLP_MAX_LAYERS - 1)
        return mlb_fail(MLB_ERR_ARG, "BRDF auto-encoder: hidden width %d and depth %d (expected >= 1 and 1..%d)",
                        cfg->hidden, cfg->depth, MLB_MLP_MAX_LAYERS - 1);
    ae->config = *cfg;
    int enc_dims[MLB_MLP_MAX_LAYERS + 1], dec_dims[MLB_MLP_MAX_LAYERS + 1];
    int L = cfg->depth + 1;
    enc_dims[0] = K_DIM; dec_dims[0] = Z_DIM;
    for (int l = 1; l < L; l++) enc_dims[l] = dec_dims[l] = cfg->hidden;
    enc_dims[L] = 2 * Z_DIM; dec_dims[L] = K_DIM;
    ae->n_enc_params = FN(mlp_param_count)(L, enc_dims, 1);
    ae->n_params = ae->n_enc_params + FN(mlp_param_count)(L, dec_dims, 1);
    ae->params = calloc(ae->n_params, sizeof(real));
    ae->grads = calloc(ae->n_params, sizeof(real));
    if (!ae->params || !ae->grads) { FN(brdf_ae_free)(ae); return mlb_fail(MLB_ERR_NOMEM, "BRDF auto-encoder: out of memory"); }
    MLB_TRY(FN(mlp_init)(&ae->enc, L, enc_dims, 1, cfg->act, MLB_ACT_IDENTITY, ae->params));
    MLB_TRY(FN(mlp_init)(&ae->dec, L, dec_dims, 1, cfg->act, MLB_ACT_SIGMOID, ae->params + ae->n_enc_params));
    FN(mlp_init_weights)(&ae->enc, seed, STREAM_INIT_ENC);
    FN(mlp_init_weights)(&ae->dec, seed, STREAM_INIT_DEC);
    return MLB_OK;
}

void FN(brdf_ae_free)(FN(mlb_brdf_ae)* ae) {
    free(ae->params);
    free(ae->grads);
    memset(ae, 0, sizeof *ae);
}

mlb_status FN(brdf_work_alloc)(FN(mlb_brdf_work)* w, const FN(mlb_brdf_ae)* ae, int B) {
    memset(w, 0, sizeof *w);
    if (B < 2) return mlb_fail(MLB_ERR_ARG, "BRDF auto-encoder: batch %d too small (need >= 2 for interpolation pairs)", B);
    w->capacity = B;
    // widths of the per-row buffers, in the order they are carved below
    static const int widths[] = {K_DIM, Z_DIM, Z_DIM, Z_DIM, Z_DIM, K_DIM, Z_DIM, Z_DIM, 1, K_DIM, K_DIM, K_DIM, Z_DIM,
                                 K_DIM, K_DIM, K_DIM, 2 * Z_DIM, Z_DIM, Z_DIM, Z_DIM, Z_DIM, Z_DIM, 2 * Z_DIM};
    size_t per_row = 0;
    for (size_t i = 0; i < sizeof widths / sizeof *widths; i++) per_row += widths[i];
    w->buffer = calloc(per_row * (size_t)B, sizeof(real));
    if (!w->buffer) return mlb_fail(MLB_ERR_NOMEM, "BRDF auto-encoder: out of memory for batch %d", B);
    real** slots[] = {&w->x, &w->mu, &w->logvar, &w->eps, &w->z, &w->k_hat, &w->z_n, &w->dir, &w->alpha, &w->k_n,
                      &w->tk_n, &w->x_n, &w->zhat_n, &w->g_s, &w->g_ts, &w->g_x_n, &w->g_mulv, &w->g_mu,
                      &w->g_logvar, &w->g_z, &w->g_zn, &w->g_dir, &w->g_encout};
    real* p = w->buffer;
    for (size_t i = 0; i < sizeof slots / sizeof *slots; i++) { *slots[i] = p; p += (size_t)widths[i] * B; }
    mlb_status s = FN(mlp_cache_alloc)(&w->enc_data, &ae->enc, B);
    if (!s) s = FN(mlp_cache_alloc)(&w->dec_data, &ae->dec, B);
    if (!s) s = FN(mlp_cache_alloc)(&w->enc_interp, &ae->enc, B);
    if (!s) s = FN(mlp_cache_alloc)(&w->dec_interp, &ae->dec, B);
    if (s) FN(brdf_work_free)(w);
    return s;
}

void FN(brdf_work_free)(FN(mlb_brdf_work)* w) {
    FN(mlp_cache_free)(&w->enc_data);
    FN(mlp_cache_free)(&w->dec_data);
    FN(mlp_cache_free)(&w->enc_interp);
    FN(mlp_cache_free)(&w->dec_interp);
    free(w->buffer);
    memset(w, 0, sizeof *w);
}

// [B,8] rows of mu|logvar -> separate [B,4] arrays
static void split_mu_logvar(const real* mulv, real* mu, real* logvar, int B) {
    for (int i = 0; i < B; i++)
        for (int d = 0; d < Z_DIM; d++) {
            mu[i * Z_DIM + d] = mulv[i * 2 * Z_DIM + d];
            if (logvar) logvar[i * Z_DIM + d] = mulv[i * 2 * Z_DIM + Z_DIM + d];
        }
}

static void map_to_ranges(real* k, const real* s, int B) {
    for (int i = 0; i < B; i++)
        for (int c = 0; c < K_DIM; c++)
            k[i * K_DIM + c] = (real)(mlb_brdf_range_lo[c] + (mlb_brdf_range_hi[c] - mlb_brdf_range_lo[c]) * s[i * K_DIM + c]);
}

// The decoded chord of entry n = i * 7 + c of the interpolation batch (pair i, i + 1) in the bend
// form of L_s; 0 in the speed form.
static real smooth_chord(const FN(mlb_brdf_work)* w, const mlb_brdf_loss_config* lc, int n, int B) {
    if (lc->smooth_form != MLB_BRDF_SMOOTH_BEND) return 0;
    int i = n / K_DIM, c = n % K_DIM, j = (i + 1) % B;
    return w->k_hat[i * K_DIM + c] - w->k_hat[j * K_DIM + c];
}

// Forward of the interpolation path: z_n and its derivative along alpha, the decoded k_n, the
// smoothness term and the cyclic re-encoding (w holds what the backward needs).
static void interp_forward(const FN(mlb_brdf_ae)* ae, FN(mlb_brdf_work)* w, const mlb_brdf_loss_config* lc, int B,
                           real* l_s, real* l_c) {
    const int nk = B * K_DIM, nz = B * Z_DIM;
    const int A = lc->n_alpha > 1 ? lc->n_alpha : 2;
    for (int i = 0; i < B; i++) {
        int j = (i + 1) % B;
        real a = (real)(i % A) / (real)(A - 1);
        w->alpha[i] = a;
        for (int d = 0; d < Z_DIM; d++) {
            real zi = w->z[i * Z_DIM + d], zj = w->z[j * Z_DIM + d];
            w->z_n[i * Z_DIM + d] = a * zi + (1 - a) * zj;
            w->dir[i * Z_DIM + d] = zi - zj;
        }
    }
    const real* s_n = FN(mlp_forward)(&ae->dec, &w->dec_interp, w->z_n, B);
    const real* ts_n = FN(mlp_jvp_forward)(&ae->dec, &w->dec_interp, w->dir, B);
    map_to_ranges(w->k_n, s_n, B);
    for (int i = 0; i < nk; i++) w->tk_n[i] = (real)(mlb_brdf_range_hi[i % K_DIM] - mlb_brdf_range_lo[i % K_DIM]) * ts_n[i];
    // L_s = mean_n |tk_n - chord_n|^2 (chord 0 for the speed form); w->g_ts holds dL_s/dtk_n
    // (lambda_s and the output map come in the backward)
    double sum_s = 0;
    for (int i = 0; i < nk; i++) {
        real dev = w->tk_n[i] - smooth_chord(w, lc, i, B);
        sum_s += (double)dev * dev;
        w->g_ts[i] = 2 * dev / B;
    }
    sum_s /= B;
    *l_s = (real)sum_s;
    for (int i = 0; i < nk; i++) w->x_n[i] = 2 * w->k_n[i] - 1;
    const real* mulv_n = FN(mlp_forward)(&ae->enc, &w->enc_interp, w->x_n, B);
    split_mu_logvar(mulv_n, w->zhat_n, NULL, B);
    *l_c = Z_DIM * FN(mse_forward)(w->zhat_n, w->z_n, (size_t)nz);
}

// Backward of interp_forward: adds the cyclic and smoothness terms' parameter gradients into
// g_enc / g_dec and their gradient with respect to the sampled codes into w->g_z.
static void interp_backward(const FN(mlb_brdf_ae)* ae, FN(mlb_brdf_work)* w, const mlb_brdf_loss_config* lc, int B,
                            real* g_enc, real* g_dec) {
    const int nk = B * K_DIM, nz = B * Z_DIM;
    const real lam_c = (real)lc->lambda_c, lam_s = (real)lc->lambda_s;
    // ---- cyclic: d/dzhat_n and the direct d/dz_n
    memset(w->g_encout, 0, sizeof(real) * 2 * nz);
    for (int i = 0; i < B; i++)
        for (int d = 0; d < Z_DIM; d++) {
            real g = lam_c * 2 * (w->zhat_n[i * Z_DIM + d] - w->z_n[i * Z_DIM + d]) / B;
            w->g_encout[i * 2 * Z_DIM + d] = g;
            w->g_zn[i * Z_DIM + d] = -g;
        }
    memset(w->g_x_n, 0, sizeof(real) * nk);
    FN(mlp_backward)(&ae->enc, &w->enc_interp, g_enc, w->g_x_n, w->g_encout, w->x_n, B);
    // x_n = 2 k_n - 1, k_n = lo + (hi - lo) s_n; the smoothness term acts on tk_n = (hi - lo) ts_n
    for (int i = 0; i < nk; i++) {
        real scale = (real)(mlb_brdf_range_hi[i % K_DIM] - mlb_brdf_range_lo[i % K_DIM]);
        w->g_s[i] = 2 * w->g_x_n[i] * scale;
        w->g_ts[i] *= lam_s * scale;
    }
    memset(w->g_dir, 0, sizeof(real) * nz);
    FN(mlp_jvp_backward)(&ae->dec, &w->dec_interp, g_dec, w->g_zn, w->g_dir, w->g_s, w->g_ts, w->z_n, w->dir, B);
    // z_n = alpha z_i + (1 - alpha) z_j, dir = z_i - z_j
    for (int i = 0; i < B; i++) {
        int j = (i + 1) % B;
        real a = w->alpha[i];
        for (int d = 0; d < Z_DIM; d++) {
            real gn = w->g_zn[i * Z_DIM + d], gd = w->g_dir[i * Z_DIM + d];
            w->g_z[i * Z_DIM + d] += a * gn + gd;
            w->g_z[j * Z_DIM + d] += (1 - a) * gn - gd;
        }
    }
}

mlb_status FN(brdf_ae_loss)(const FN(mlb_brdf_ae)* ae, FN(mlb_brdf_work)* w, const real* k, int B,
                            const mlb_brdf_loss_config* lc, uint64_t seed, uint64_t step, real* grads,
                            FN(mlb_brdf_losses)* out) {
    if (B < 2 || B > w->capacity)
        return mlb_fail(MLB_ERR_ARG, "BRDF auto-encoder: batch %d outside 2..%d", B, w->capacity);
    const int nk = B * K_DIM, nz = B * Z_DIM;

    // ---- reconstruction path
    for (int i = 0; i < nk; i++) w->x[i] = 2 * k[i] - 1;
    const real* mulv = FN(mlp_forward)(&ae->enc, &w->enc_data, w->x, B);
    split_mu_logvar(mulv, w->mu, w->logvar, B);
    for (int i = 0; i < nz; i++) {
        // index = step * 2^32 + position: every step and row has its own noise
        w->eps[i] = lc->sample_latent ? (real)mlb_rng_normal_f64(seed, STREAM_EPS, (step << 32) + (uint64_t)i) : 0;
        w->z[i] = w->mu[i] + R_EXP((real)0.5 * w->logvar[i]) * w->eps[i];
    }
    const real* s = FN(mlp_forward)(&ae->dec, &w->dec_data, w->z, B);
    map_to_ranges(w->k_hat, s, B);
    real l_r = K_DIM * FN(mse_forward)(w->k_hat, k, (size_t)nk);   // mean over B of the sum over 7
    real l_kl = FN(kl_normal_forward)(w->mu, w->logvar, B, Z_DIM);

    // ---- interpolation path (skipped when neither term using it counts: the encoder-only phase)
    const int interp = lc->lambda_s != 0 || lc->lambda_c != 0;
    real l_s = 0, l_c = 0;
    if (interp) interp_forward(ae, w, lc, B, &l_s, &l_c);

    out->l_r = l_r; out->l_kl = l_kl; out->l_s = l_s; out->l_c = l_c;
    out->total = (real)(l_r + lc->lambda_kl * l_kl + lc->lambda_s * l_s + lc->lambda_c * l_c);
    if (!grads) return MLB_OK;

    real* g_enc = grads;
    real* g_dec = grads + ae->n_enc_params;
    const real lam_s = (real)lc->lambda_s;

    memset(w->g_z, 0, sizeof(real) * nz);
    if (interp) interp_backward(ae, w, lc, B, g_enc, g_dec);
    // ---- reconstruction: d/dk_hat -> d/ds -> decoder -> d/dz
    memset(w->g_s, 0, sizeof(real) * nk);
    FN(mse_backward)(w->g_s, w->k_hat, k, (size_t)nk, K_DIM);
    if (interp && lc->smooth_form == MLB_BRDF_SMOOTH_BEND)   // chord_n = k_hat_i - k_hat_j, i = n, j = n + 1
        for (int i = 0; i < B; i++) {
            int j = (i + 1) % B;
            for (int c = 0; c < K_DIM; c++) {
                int n = i * K_DIM + c;
                real g = lam_s * 2 * (w->tk_n[n] - smooth_chord(w, lc, n, B)) / B;
                w->g_s[n] -= g;
                w->g_s[j * K_DIM + c] += g;
            }
        }
    for (int i = 0; i < nk; i++) w->g_s[i] *= (real)(mlb_brdf_range_hi[i % K_DIM] - mlb_brdf_range_lo[i % K_DIM]);
    FN(mlp_backward)(&ae->dec, &w->dec_data, g_dec, w->g_z, w->g_s, w->z, B);
    // ---- z = mu + exp(logvar/2) eps, plus the KL term
    for (int i = 0; i < nz; i++) {
        w->g_mu[i] = w->g_z[i];
        w->g_logvar[i] = w->g_z[i] * w->eps[i] * (real)0.5 * R_EXP((real)0.5 * w->logvar[i]);
    }
    FN(kl_normal_backward)(w->g_mu, w->g_logvar, w->mu, w->logvar, B, Z_DIM, (real)lc->lambda_kl);
    for (int i = 0; i < B; i++)
        for (int d = 0; d < Z_DIM; d++) {
            w->g_mulv[i * 2 * Z_DIM + d] = w->g_mu[i * Z_DIM + d];
            w->g_mulv[i * 2 * Z_DIM + Z_DIM + d] = w->g_logvar[i * Z_DIM + d];
        }
    FN(mlp_backward)(&ae->enc, &w->enc_data, g_enc, NULL, w->g_mulv, w->x, B);
    return MLB_OK;
}

#define INFER_CHUNK 4096

mlb_status FN(brdf_ae_encode)(const FN(mlb_brdf_ae)* ae, const real* k, size_t n, real* mu, real* logvar) {
    FN(mlb_mlp_cache) c;
    int chunk = n < INFER_CHUNK ? (int)(n ? n : 1) : INFER_CHUNK;
    MLB_TRY(FN(mlp_cache_alloc)(&c, &ae->enc, chunk));
    real* x = malloc(sizeof(real) * K_DIM * chunk);
    if (!x) { FN(mlp_cache_free)(&c); return mlb_fail(MLB_ERR_NOMEM, "BRDF encoder: out of memory"); }
    for (size_t start = 0; start < n; start += chunk) {
        int B = (int)(n - start < (size_t)chunk ? n - start : (size_t)chunk);
        for (int i = 0; i < B * K_DIM; i++) x[i] = 2 * k[start * K_DIM + i] - 1;
        const real* mulv = FN(mlp_forward)(&ae->enc, &c, x, B);
        split_mu_logvar(mulv, mu + start * Z_DIM, logvar ? logvar + start * Z_DIM : NULL, B);
    }
    free(x);
    FN(mlp_cache_free)(&c);
    return MLB_OK;
}

mlb_status FN(brdf_ae_decode)(const FN(mlb_brdf_ae)* ae, const real* z, size_t n, real* k) {
    FN(mlb_mlp_cache) c;
    int chunk = n < INFER_CHUNK ? (int)(n ? n : 1) : INFER_CHUNK;
    MLB_TRY(FN(mlp_cache_alloc)(&c, &ae->dec, chunk));
    for (size_t start = 0; start < n; start += chunk) {
        int B = (int)(n - start < (size_t)chunk ? n - start : (size_t)chunk);
        const real* s = FN(mlp_forward)(&ae->dec, &c, z + start * Z_DIM, B);
        map_to_ranges(k + start * K_DIM, s, B);
    }
    FN(mlp_cache_free)(&c);
    return MLB_OK;
}

// Solves the symmetric positive definite 4x4 system A x = b by Cholesky; 0 when A is not SPD.
static int solve_spd4(const double A[16], const double b[4], double x[4]) {
    double L[16] = {0};
    for (int i = 0; i < 4; i++)
        for (int j = 0; j <= i; j++) {
            double s = A[i * 4 + j];
            for (int k = 0; k < j; k++) s -= L[i * 4 + k] * L[j * 4 + k];
            if (i == j) { if (!(s > 0)) return 0; L[i * 4 + i] = sqrt(s); }
            else L[i * 4 + j] = s / L[j * 4 + j];
        }
    double y[4];
    for (int i = 0; i < 4; i++) { double s = b[i]; for (int k = 0; k < i; k++) s -= L[i * 4 + k] * y[k]; y[i] = s / L[i * 4 + i]; }
    for (int i = 3; i >= 0; i--) { double s = y[i]; for (int k = i + 1; k < 4; k++) s -= L[k * 4 + i] * x[k]; x[i] = s / L[i * 4 + i]; }
    return 1;
}

// Squared distance |map(D(z)) - k|^2 per row; the decoder cache then holds the forward of z.
static void fit_costs(const FN(mlb_brdf_ae)* ae, FN(mlb_mlp_cache)* c, const real* z, const real* k, int B,
                      real* k_out, double* cost) {
    const real* s = FN(mlp_forward)(&ae->dec, c, z, B);
    map_to_ranges(k_out, s, B);
    for (int i = 0; i < B; i++) {
        double e = 0;
        for (int ch = 0; ch < K_DIM; ch++) { double d = (double)k_out[i * K_DIM + ch] - k[i * K_DIM + ch]; e += d * d; }
        cost[i] = e;
    }
}

mlb_status FN(brdf_ae_fit_latent)(const FN(mlb_brdf_ae)* ae, const real* k, size_t n, real* z, int iters) {
    enum { CHUNK = 1024 };
    int chunk = n < CHUNK ? (int)(n ? n : 1) : CHUNK;
    FN(mlb_mlp_cache) c;
    MLB_TRY(FN(mlp_cache_alloc)(&c, &ae->dec, chunk));
    real* tin = malloc(sizeof(real) * Z_DIM * chunk);
    real* kk = malloc(sizeof(real) * K_DIM * chunk);
    real* zt = malloc(sizeof(real) * Z_DIM * chunk);
    double* jac = malloc(sizeof(double) * K_DIM * Z_DIM * chunk);   // [B][7][4]
    double* cost = malloc(sizeof(double) * 2 * chunk);
    double* lambda = malloc(sizeof(double) * chunk);
    mlb_status status = MLB_OK;
    if (!tin || !kk || !zt || !jac || !cost || !lambda) { status = mlb_fail(MLB_ERR_NOMEM, "BRDF latent fit: out of memory"); goto done; }
    for (size_t start = 0; start < n; start += chunk) {
        int B = (int)(n - start < (size_t)chunk ? n - start : (size_t)chunk);
        real* zb = z + start * Z_DIM;
        const real* kb = k + start * K_DIM;
        for (int i = 0; i < B; i++) lambda[i] = 1e-3;
        for (int it = 0; it < iters; it++) {
            // residual and Jacobian at z: one forward, then a tangent per latent axis
            fit_costs(ae, &c, zb, kb, B, kk, cost);
            for (int d = 0; d < Z_DIM; d++) {
                for (int i = 0; i < B * Z_DIM; i++) tin[i] = (i % Z_DIM) == d;
                const real* ts = FN(mlp_jvp_forward)(&ae->dec, &c, tin, B);
                for (int i = 0; i < B; i++)
                    for (int ch = 0; ch < K_DIM; ch++)
                        jac[(i * K_DIM + ch) * Z_DIM + d] = (mlb_brdf_range_hi[ch] - mlb_brdf_range_lo[ch]) * ts[i * K_DIM + ch];
            }
            // Levenberg-Marquardt step per row: (J^T J + lambda diag) dz = -J^T r
            for (int i = 0; i < B; i++) {
                double A[16] = {0}, g[4] = {0}, dz[4];
                for (int ch = 0; ch < K_DIM; ch++) {
                    const double* row = jac + (i * K_DIM + ch) * Z_DIM;
                    double r = (double)kk[i * K_DIM + ch] - kb[i * K_DIM + ch];
                    for (int a = 0; a < 4; a++) {
                        g[a] += row[a] * r;
                        for (int b2 = 0; b2 < 4; b2++) A[a * 4 + b2] += row[a] * row[b2];
                    }
                }
                for (int a = 0; a < 4; a++) { A[a * 4 + a] += lambda[i] * (A[a * 4 + a] + 1e-9); g[a] = -g[a]; }
                if (!solve_spd4(A, g, dz)) { for (int a = 0; a < 4; a++) dz[a] = 0; }
                for (int a = 0; a < 4; a++) zt[i * Z_DIM + a] = zb[i * Z_DIM + a] + (real)dz[a];
            }
            fit_costs(ae, &c, zt, kb, B, kk, cost + chunk);
            for (int i = 0; i < B; i++) {
                if (cost[chunk + i] < cost[i] && isfinite(cost[chunk + i])) {
                    memcpy(zb + i * Z_DIM, zt + i * Z_DIM, sizeof(real) * Z_DIM);
                    lambda[i] = fmax(lambda[i] / 3, 1e-9);
                } else {
                    lambda[i] = fmin(lambda[i] * 4, 1e9);
                }
            }
        }
    }
done:
    free(tin); free(kk); free(zt); free(jac); free(cost); free(lambda);
    FN(mlp_cache_free)(&c);
    return status;
}

mlb_status FN(brdf_ae_latent_of)(const FN(mlb_brdf_ae)* ae, const real* k, size_t n, real* z, int iters) {
    MLB_TRY(FN(brdf_ae_encode)(ae, k, n, z, NULL));
    return iters > 0 ? FN(brdf_ae_fit_latent)(ae, k, n, z, iters) : MLB_OK;
}
