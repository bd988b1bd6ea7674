// Evaluating a BRDF prior: reconstruction error against the best linear 4-d code (PCA-4 of the
// same data), KL, and whether decoded BRDFs stay valid along random latent interpolations.
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/brdf.h"
#include "matlaber/brdf_ae.h"
#include "matlaber/rng.h"
#include <omp.h>

#define STREAM_EVAL_PAIRS 0x4001
#define STREAM_EVAL_PRIOR 0x4002
#define FIT_ITERS 12

// LAPACK (in OpenBLAS): symmetric eigen-decomposition, eigenvalues ascending.
void dsyev_(const char* jobz, const char* uplo, const int* n, double* a, const int* lda, double* w,
            double* work, const int* lwork, int* info);

mlb_status mlb_pca_fit(const float* data, size_t n, int k, float mean[7], float* components, double* explained) {
    enum { D = 7 };
    if (n < 2 || k < 1 || k > D) return mlb_fail(MLB_ERR_ARG, "PCA: %zu samples, %d components", n, k);
    double mu[D] = {0}, cov[D * D] = {0};
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < D; c++) mu[c] += data[i * D + c];
    for (int c = 0; c < D; c++) mu[c] /= (double)n;
    for (size_t i = 0; i < n; i++)
        for (int a = 0; a < D; a++)
            for (int b = 0; b < D; b++) cov[a * D + b] += (data[i * D + a] - mu[a]) * (data[i * D + b] - mu[b]);
    for (int i = 0; i < D * D; i++) cov[i] /= (double)n;
    double eig[D], work[256];
    int nn = D, lwork = 256, info = 0;
    dsyev_("V", "U", &nn, cov, &nn, eig, work, &lwork, &info);   // column e of cov (column-major) = eigenvector e
    if (info != 0) return mlb_fail(MLB_ERR_NUMERIC, "PCA: LAPACK dsyev failed (info %d)", info);
    double total = 0, top = 0;
    for (int c = 0; c < D; c++) total += eig[c];
    for (int c = D - k; c < D; c++) top += eig[c];
    if (explained) *explained = total > 0 ? top / total : 1;
    for (int c = 0; c < D; c++) mean[c] = (float)mu[c];
    for (int j = 0; j < k; j++)   // largest eigenvalue first
        for (int c = 0; c < D; c++) components[j * D + c] = (float)cov[(D - 1 - j) * D + c];
    return MLB_OK;
}

void mlb_pca_rmse(const float* data, size_t n, int k, const float mean[7], const float* components, double rmse[7],
                  double* rmse_all) {
    enum { D = 7 };
    double sq[D] = {0}, all = 0;
    for (size_t i = 0; i < n; i++) {
        double x[D], r[D];
        for (int c = 0; c < D; c++) { x[c] = (double)data[i * D + c] - mean[c]; r[c] = mean[c]; }
        for (int j = 0; j < k; j++) {
            const float* v = components + j * D;
            double p = 0;
            for (int c = 0; c < D; c++) p += v[c] * x[c];
            for (int c = 0; c < D; c++) r[c] += p * v[c];
        }
        for (int c = 0; c < D; c++) { double d = r[c] - data[i * D + c]; sq[c] += d * d; }
    }
    for (int c = 0; c < D; c++) { rmse[c] = n ? sqrt(sq[c] / (double)n) : 0; all += sq[c]; }
    *rmse_all = n ? sqrt(all / ((double)n * D)) : 0;
}

mlb_status mlb_brdf_ae_evaluate(const mlb_brdf_ae* ae, const float* data, size_t n, uint64_t seed,
                                mlb_brdf_eval_result* r) {
    memset(r, 0, sizeof *r);
    if (n < 2) return mlb_fail(MLB_ERR_ARG, "BRDF evaluation: %zu samples; need at least 2", n);
    r->n = n;
    float* mu = malloc(sizeof(float) * 4 * n);
    float* lv = malloc(sizeof(float) * 4 * n);
    float* rec = malloc(sizeof(float) * 7 * n);
    enum { PATHS = 2000, STEPS = 33 };
    float* zpath = malloc(sizeof(float) * 4 * STEPS);
    float* kpath = malloc(sizeof(float) * 7 * STEPS);
    mlb_status s = MLB_OK;
    if (!mu || !lv || !rec || !zpath || !kpath) { s = mlb_fail(MLB_ERR_NOMEM, "BRDF evaluation: out of memory"); goto done; }
    if ((s = brdf_ae_encode(ae, data, n, mu, lv)) || (s = brdf_ae_decode(ae, mu, n, rec))) goto done;
    double sq[7] = {0}, all = 0, sigma = 0;
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < 7; c++) { double d = (double)rec[i * 7 + c] - data[i * 7 + c]; sq[c] += d * d; }
    for (int c = 0; c < 7; c++) { r->rmse[c] = sqrt(sq[c] / (double)n); all += sq[c]; }
    r->rmse_all = sqrt(all / (7.0 * (double)n));
    // latent codes refined from the encoder's guess, in parallel halves (each call has its own buffers)
    float* zfit = malloc(sizeof(float) * 4 * n);
    if (!zfit) { s = mlb_fail(MLB_ERR_NOMEM, "BRDF evaluation: out of memory"); goto done; }
    memcpy(zfit, mu, sizeof(float) * 4 * n);
    {
        enum { PARTS = 2 };
        mlb_status part_status[PARTS];
#pragma omp parallel for schedule(static, 1) num_threads(PARTS)
        for (int p = 0; p < PARTS; p++) {
            size_t a = n * p / PARTS, b = n * (p + 1) / PARTS;
            part_status[p] = brdf_ae_fit_latent(ae, data + 7 * a, b - a, zfit + 4 * a, FIT_ITERS);
        }
        for (int p = 0; p < PARTS && !s; p++) s = part_status[p];
    }
    if (!s) s = brdf_ae_decode(ae, zfit, n, rec);
    free(zfit);
    if (s) goto done;
    double fsq[7] = {0}, fall = 0;
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < 7; c++) { double d = (double)rec[i * 7 + c] - data[i * 7 + c]; fsq[c] += d * d; }
    for (int c = 0; c < 7; c++) { r->fit_rmse[c] = sqrt(fsq[c] / (double)n); fall += fsq[c]; }
    r->fit_rmse_all = sqrt(fall / (7.0 * (double)n));
    r->kl = kl_normal_forward(mu, lv, (int)(n > 2147483647 ? 2147483647 : n), 4);
    for (size_t i = 0; i < 4 * n; i++) sigma += exp(0.5 * lv[i]);
    r->mean_sigma = sigma / (4.0 * (double)n);
    // PCA-4 fitted on the evaluated data itself: the best linear 4-d code this data has
    float pca_mean[7], pca_comp[4 * 7];
    if ((s = mlb_pca_fit(data, n, 4, pca_mean, pca_comp, &r->pca_explained))) goto done;
    mlb_pca_rmse(data, n, 4, pca_mean, pca_comp, r->pca_rmse, &r->pca_rmse_all);
    // PCA-4 of the training data, when the prior carries it: the same protocol as the auto-encoder
    r->has_train_pca = ae->has_pca;
    if (ae->has_pca) mlb_pca_rmse(data, n, 4, ae->pca_mean, ae->pca_components, r->train_pca_rmse, &r->train_pca_rmse_all);

    // Latent paths: half between encodings of random data pairs, half between draws from N(0, I).
    double ratio_sum = 0;
    long ratio_count = 0;
    for (int p = 0; p < PATHS; p++) {
        float za[4], zb[4];
        if (p % 2 == 0) {
            uint32_t a = mlb_rng_below(seed, STREAM_EVAL_PAIRS, 2 * (uint64_t)p, (uint32_t)(n > UINT32_MAX ? UINT32_MAX : n));
            uint32_t b = mlb_rng_below(seed, STREAM_EVAL_PAIRS, 2 * (uint64_t)p + 1, (uint32_t)(n > UINT32_MAX ? UINT32_MAX : n));
            memcpy(za, mu + 4 * (size_t)a, sizeof za);
            memcpy(zb, mu + 4 * (size_t)b, sizeof zb);
        } else {
            for (int d = 0; d < 4; d++) {
                za[d] = mlb_rng_normal(seed, STREAM_EVAL_PRIOR, 8 * (uint64_t)p + d);
                zb[d] = mlb_rng_normal(seed, STREAM_EVAL_PRIOR, 8 * (uint64_t)p + 4 + d);
            }
        }
        for (int t = 0; t < STEPS; t++) {
            float a = (float)t / (STEPS - 1);
            for (int d = 0; d < 4; d++) zpath[t * 4 + d] = (1 - a) * za[d] + a * zb[d];
        }
        if ((s = brdf_ae_decode(ae, zpath, STEPS, kpath))) goto done;
        double length = 0, ends = 0;
        for (int t = 0; t < STEPS; t++) {
            r->interp_points++;
            r->interp_valid += mlb_brdf_valid(kpath + 7 * t) ? 1 : 0;
            if (t) {
                double d2 = 0;
                for (int c = 0; c < 7; c++) { double d = kpath[7 * t + c] - kpath[7 * (t - 1) + c]; d2 += d * d; }
                length += sqrt(d2);
            }
        }
        for (int c = 0; c < 7; c++) { double d = kpath[7 * (STEPS - 1) + c] - kpath[c]; ends += d * d; }
        ends = sqrt(ends);
        if (ends > 1e-2) { ratio_sum += length / ends; ratio_count++; }
        r->interp_paths++;
    }
    r->interp_valid_share = (double)r->interp_valid / (double)r->interp_points;
    r->interp_path_ratio = ratio_count ? ratio_sum / (double)ratio_count : 1;
done:
    free(mu); free(lv); free(rec); free(zpath); free(kpath);
    return s;
}
