// Shared by sd_train.c (text side, UNet loop), sd_train_vae.c (the VAE's loop) and sd_train_run.c
// (the whole run): a model's parameters as one flat vector on the backend's device with its
// gradient and Adam moments, saved to and resumed from a state file (sd_train_params.c).
#ifndef MATLABER_SD_TRAIN_INTERNAL_H
#define MATLABER_SD_TRAIN_INTERNAL_H
#include "matlaber/backend.h"
#include "matlaber/run.h"
#include "matlaber/sd_train.h"

typedef struct {
    const char* name;       // "vae" or "unet": the state file train/<name>.safetensors, the log stage
    int stage;              // 0 VAE, 1 UNet (the loss log's stage column)
    float* params;          // [n] on be's device: the model's own parameter buffer
    float* grads;           // [n] on be's device: the gradient model's buffer
    float *m, *v;           // [n] Adam moments on be's device
    size_t n;
    long step;              // optimiser steps taken
    long total;             // steps of the phase (the learning-rate schedule's length; a time limit may cut it)
    double deadline;        // > 0: mlb_now_seconds() by which the phase should end (the time limit)
    char path[4200];        // the state file
    mlb_unet *unet, *unet_grads;   // the model whose params these are (one of the two pairs)
    const mlb_vae *vae, *vae_grads;
} mlb_train_params;

// Moments zeroed on be's device; params/grads given by the caller (the models' buffers).
mlb_status mlb_train_params_init(const mlb_backend* be, mlb_train_params* P, const char* out_dir, const char* name,
                                 int stage, float* params, float* grads, size_t n, long total);
void mlb_train_params_free(const mlb_backend* be, mlb_train_params* P);
// AdamW (betas 0.9, 0.999, weight decay 0.01 decoupled) with a linear warm-up over the first 2%
// of the steps and a cosine decay to a tenth of lr.
mlb_status mlb_train_params_step(const mlb_backend* be, mlb_train_params* P, double lr, long step, long total);
// With a time limit: after 20 steps of a phase started at time t_phase (step `first`), the
// phase's step count that fits in `budget` seconds (never more than `steps`); else `steps`.
long mlb_train_fit_steps(long steps, long first, long step, double t_phase, double budget);
// params, moments and the step to P->path (atomically; the loss log flushes its rows itself).
mlb_status mlb_train_params_save(const mlb_backend* be, const mlb_train_params* P);
// Back from P->path: MLB_ERR_NOT_FOUND when there is none (a fresh start).
mlb_status mlb_train_params_load(const mlb_backend* be, mlb_train_params* P);

// Writes the tokenizer and the frozen text encoder into the model folder and encodes every caption:
// *table [mlb_sd_caption_count() + MLB_SD_N_UNCOND, 77, W] on the host, the last rows the
// unconditional prompts (the empty one and the guidance's two default negatives).
#define MLB_SD_N_UNCOND 3
mlb_status mlb_sd_train_text(const mlb_sd_train_config* c, float** table);
mlb_status mlb_sd_train_vae(const mlb_backend* be, const mlb_sd_train_config* c, const mlb_sd_dataset* d,
                            mlb_train_params* P, mlb_losslog* log);
// Latents of the whole data set: mean of the encoder on the appearance and geometry images,
// [n, 4, lat, lat] each, raw (unscaled), on the host.
mlb_status mlb_sd_encode_dataset(const mlb_backend* be, const mlb_vae* v, const mlb_sd_dataset* d, float* lat_rgb,
                                 float* lat_geo);
mlb_status mlb_sd_train_unet(const mlb_backend* be, const mlb_sd_train_config* c, const mlb_sd_dataset* d,
                             const float* lat_rgb, const float* lat_geo, const float* captions, mlb_train_params* P,
                             mlb_losslog* log);

#endif
