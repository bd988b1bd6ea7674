// The optimiser state shared by the training's two loops (sd_train_internal.h): a model's
// parameters with their gradient and Adam moments on the backend's device, the AdamW step, the
// step count a time limit allows, and the state file. A file of its own, below the loops
// (sd_train.c, sd_train_vae.c) and the run (sd_train_run.c) that all use it, so that the run,
// which calls the loops, is not called back by them.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/fileio.h"
#include "matlaber/log.h"
#include "sd_train_internal.h"

#define STATE_FORMAT "matlaber-sd-train-state"

mlb_status mlb_train_params_init(const mlb_backend* be, mlb_train_params* P, const char* out_dir, const char* name,
                                 int stage, float* params, float* grads, size_t n, long total) {
    P->name = name;
    P->stage = stage;
    P->params = params;
    P->grads = grads;
    P->n = n;
    P->step = 0;
    P->total = total;
    P->m = P->v = NULL;
    snprintf(P->path, sizeof P->path, "%s/train/%s.safetensors", out_dir, name);
    MLB_TRY(be->alloc(&P->m, n));
    MLB_TRY(be->alloc(&P->v, n));
    MLB_TRY(be->zero(P->m, n));
    return be->zero(P->v, n);
}

void mlb_train_params_free(const mlb_backend* be, mlb_train_params* P) {
    be->release(P->m);
    be->release(P->v);
    P->m = P->v = NULL;
}

mlb_status mlb_train_params_step(const mlb_backend* be, mlb_train_params* P, double lr, long step, long total) {
    long warm = total / 50 > 1 ? total / 50 : 1;
    double f = step < warm ? (double)(step + 1) / warm
                           : 0.1 + 0.45 * (1.0 + cos(M_PI * (double)(step - warm) / (double)(total > warm ? total - warm : 1)));
    mlb_adam_config a = mlb_adamw_default(lr * f);
    return be->adam(P->params, P->grads, P->m, P->v, P->n, &a, step + 1);
}

long mlb_train_fit_steps(long steps, long first, long step, double t_phase, double budget) {
    if (!(budget > 0) || step - first < 20) return steps;
    double per = (mlb_now_seconds() - t_phase) / (double)(step - first);
    long fit = first + (long)(budget / per);
    if (fit < step + 1) fit = step + 1;
    if (fit < steps) mlb_log(MLB_LOG_INFO, "sd train: %.1f ms a step: %ld steps fit in the time limit (of %ld asked)", per * 1e3, fit, steps);
    return fit < steps ? fit : steps;
}

// The three vectors through the host (the checkpoint writer reads host memory).
mlb_status mlb_train_params_save(const mlb_backend* be, const mlb_train_params* P) {
    float* h = malloc(3 * P->n * sizeof(float));
    if (!h) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for the training state", P->path);
    mlb_status s = be->download(h, P->params, P->n);
    if (!s) s = be->download(h + P->n, P->m, P->n);
    if (!s) s = be->download(h + 2 * P->n, P->v, P->n);
    mlb_ckpt_tensor t[3] = {{"params", h, 1, {(int64_t)P->n}}, {"adam_m", h + P->n, 1, {(int64_t)P->n}},
                            {"adam_v", h + 2 * P->n, 1, {(int64_t)P->n}}};
    mlb_ckpt_meta meta = {0};
    if (!s) s = mlb_ckpt_meta_set(&meta, "format", STATE_FORMAT);
    if (!s) s = mlb_ckpt_meta_set_i64(&meta, "step", P->step);
    if (!s) s = mlb_ckpt_meta_set_i64(&meta, "total", P->total);
    if (!s) s = mlb_checkpoint_save(P->path, t, 3, &meta);
    mlb_ckpt_meta_free(&meta);
    free(h);
    if (!s) mlb_log(MLB_LOG_DEBUG, "saved %s (step %ld)", P->path, P->step);
    return s;
}

mlb_status mlb_train_params_load(const mlb_backend* be, mlb_train_params* P) {
    if (!mlb_is_file(P->path)) return MLB_ERR_NOT_FOUND;
    float* h = malloc(3 * P->n * sizeof(float));
    if (!h) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for the training state", P->path);
    mlb_ckpt_tensor t[3] = {{"params", h, 1, {(int64_t)P->n}}, {"adam_m", h + P->n, 1, {(int64_t)P->n}},
                            {"adam_v", h + 2 * P->n, 1, {(int64_t)P->n}}};
    mlb_ckpt_meta meta = {0};
    int64_t step = 0;
    mlb_status s = mlb_checkpoint_load(P->path, t, 3, &meta);
    const char* fmt = s ? NULL : mlb_ckpt_meta_get(&meta, "format");
    if (!s && (!fmt || strcmp(fmt, STATE_FORMAT)))
        s = mlb_fail(MLB_ERR_FORMAT, "%s: not a training state of `matlaber sd train`", P->path);
    int64_t total = 0;
    if (!s) s = mlb_ckpt_meta_get_i64(&meta, "step", &step);
    if (!s) s = mlb_ckpt_meta_get_i64(&meta, "total", &total);
    if (!s && total > 0 && total < P->total) P->total = (long)total;   // cut by a time limit
    if (!s && (step < 0 || step > P->total)) s = mlb_fail(MLB_ERR_FORMAT, "%s: step %lld outside 0..%ld", P->path, (long long)step, P->total);
    if (!s) s = be->upload(P->params, h, P->n);
    if (!s) s = be->upload(P->m, h + P->n, P->n);
    if (!s) s = be->upload(P->v, h + 2 * P->n, P->n);
    if (!s) P->step = (long)step;
    mlb_ckpt_meta_free(&meta);
    free(h);
    return s;
}
