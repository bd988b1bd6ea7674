// The latent BRDF auto-encoder (paper §3.3): encoder 7 -> 4 (mean, log-variance), decoder 4 -> 7
// with outputs mapped into the valid BRDF ranges, trained with
//   L = L_r + lambda_kl L_KL + lambda_s L_s + lambda_c L_c      (reference.md §1).
// Model and loss exist in float and double (_f64), see core/real.h; training, files and
// evaluation use the float model. Design notes: docs/brdf_prior.md.
#ifndef MATLABER_BRDF_AE_H
#define MATLABER_BRDF_AE_H
#include <stdint.h>
#include "matlaber/brdf.h"
#include "matlaber/nn.h"
#include "matlaber/progress.h"
#include "matlaber/safetensors.h"

// The decoder's output map k = lo + (hi − lo)·sigmoid(·): kd, ks ∈ [0, 1], kr ∈ [MLB_KR_MIN, 1]
// (shared by the auto-encoder and the material network's direct mode).
static const double mlb_brdf_range_lo[7] = {0, 0, 0, 0, 0, 0, MLB_KR_MIN};
static const double mlb_brdf_range_hi[7] = {1, 1, 1, 1, 1, 1, 1};

#define MLB_LATENT_DIM 4

typedef struct {
    int hidden;              // width of the hidden layers (default 64)
    int depth;               // hidden layers per network (default 3)
    mlb_activation act;      // hidden activation (default SiLU: smooth, so the decoder's Jacobian is too)
} mlb_brdf_ae_config;

// The interpolation smoothness term L_s, with t_n = dD(z_n)/dalpha along a pair's path and
// c_n = D(z_i) - D(z_j) the chord between its decoded ends (docs/brdf_prior.md):
typedef enum {
    MLB_BRDF_SMOOTH_SPEED = 0,   // mean_n |t_n|^2: reference.md's formula; its floor |c_n|^2 pulls decoded ends together
    MLB_BRDF_SMOOTH_BEND = 1,    // mean_n |t_n - c_n|^2: zero exactly on straight constant-speed paths, no pull on the ends
} mlb_brdf_smooth_form;

typedef struct {
    double lambda_kl, lambda_s, lambda_c;   // 2e-4, 0.02, 1e-4 (the paper: 0.05 with the speed form)
    mlb_brdf_smooth_form smooth_form;
    int n_alpha;                            // interpolation weights alpha = j / (n_alpha - 1), j = 0..n_alpha-1
    int sample_latent;                      // 1: z = mu + sigma * eps (training); 0: z = mu
} mlb_brdf_loss_config;

mlb_brdf_ae_config mlb_brdf_ae_default_config(void);
mlb_brdf_loss_config mlb_brdf_loss_default_config(void);

#define MLB_REAL float
#define MLB_FN(name) name
#include "matlaber/brdf_ae_api.inc"
#undef MLB_REAL
#undef MLB_FN
#define MLB_REAL double
#define MLB_FN(name) name##_f64
#include "matlaber/brdf_ae_api.inc"
#undef MLB_REAL
#undef MLB_FN

// ---- files (float model) ------------------------------------------------------------------
// safetensors with tensors encoder.L.weight [out,in], encoder.L.bias [out], decoder.L.* and
// metadata: format, hidden, depth, activation, kr_min, plus the caller's (command, data, ...).
mlb_status mlb_brdf_ae_save(const mlb_brdf_ae* ae, const char* path, const mlb_st_meta* extra, size_t n_extra);
mlb_status mlb_brdf_ae_load(mlb_brdf_ae* ae, const char* path);
// From an opened file (also the built-in prior, opened from memory).
mlb_status mlb_brdf_ae_from_safetensors(mlb_brdf_ae* ae, const mlb_safetensors* st);
// The default prior: the file named by $MATLABER_PRIOR when set, else the prior built into the
// program (models/brdf_prior.safetensors at build time). *source names what was used.
mlb_status mlb_brdf_ae_load_default(mlb_brdf_ae* ae, char* source, size_t source_size);

// ---- training (float model) -----------------------------------------------------------------
typedef struct {
    int epochs;            // 30
    int batch;             // 256
    double lr;             // 1e-3: the first step's learning rate
    double lr_final;       // 1e-5: the last step's, reached by a cosine decay; <= 0: constant lr
    double weight_decay;   // AdamW decoupled decay (0.01)
    double beta1, beta2, eps;
    uint64_t seed;
    mlb_brdf_loss_config loss;
    // After the joint epochs: the encoder alone (decoder frozen, z = mu, reconstruction only),
    // which closes most of the gap between D(mu(k)) and the refined latent (docs/brdf_prior.md)
    int encoder_epochs;    // 5 (0: none)
    double encoder_lr;     // 1e-3, cosine to 1% of it
} mlb_brdf_train_config;

typedef struct {
    int epoch;
    int encoder_only;                   // an epoch of the encoder phase
    double loss, l_r, l_kl, l_s, l_c;   // means over the epoch
    double seconds, samples_per_second;
} mlb_brdf_epoch_stats;

typedef void (*mlb_brdf_epoch_callback)(const mlb_brdf_epoch_stats* stats, void* user);

mlb_brdf_train_config mlb_brdf_train_default_config(void);
// data: n rows of 7 floats. Deterministic in cfg->seed whatever the thread count.
mlb_status mlb_brdf_ae_train(mlb_brdf_ae* ae, const float* data, size_t n, const mlb_brdf_train_config* cfg,
                             mlb_progress* progress, mlb_brdf_epoch_callback on_epoch, void* user);

// ---- evaluation -----------------------------------------------------------------------------
typedef struct {
    size_t n;                       // samples evaluated
    double rmse[7], rmse_all;       // auto-encoder reconstruction D(mu(k)), linear units
    double fit_rmse[7], fit_rmse_all;   // D(z*) with z* refined from mu(k) (brdf_ae_fit_latent): what the
                                        // decoder can reach, as a material field that picks z does
    double pca_rmse[7], pca_rmse_all;   // best linear 4-d code of the same data (PCA-4 fitted on it)
    double pca_explained;           // share of variance PCA-4 explains
    int has_train_pca;              // the prior carries the PCA-4 of its training data:
    double train_pca_rmse[7], train_pca_rmse_all;   // that linear code applied to this data
    double kl;                      // mean KL(q(z|k) || N(0, I))
    long interp_paths, interp_points, interp_valid;   // decoded BRDFs along random latent paths
    double interp_valid_share;
    double interp_path_ratio;       // mean (length of decoded path) / (distance of its ends); 1 = straight
    double mean_sigma;              // mean posterior std over latent dims
} mlb_brdf_eval_result;

mlb_status mlb_brdf_ae_evaluate(const mlb_brdf_ae* ae, const float* data, size_t n, uint64_t seed,
                                mlb_brdf_eval_result* out);
// PCA-k of data (n x 7; double precision, LAPACK): mean[7] and components [k,7] (unit rows,
// largest variance first); *explained = share of the variance the k components hold.
mlb_status mlb_pca_fit(const float* data, size_t n, int k, float mean[7], float* components, double* explained);
// Per-channel and overall RMSE of reconstructing data through a k-component linear code.
void mlb_pca_rmse(const float* data, size_t n, int k, const float mean[7], const float* components, double rmse[7],
                  double* rmse_all);

#endif
