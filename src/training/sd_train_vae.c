// The VAE's training loop (include/matlaber/sd_train.h): reconstruction + KL on appearance and
// geometry images, the ops on the backend's device, the losses on the host.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/progress.h"
#include "matlaber/rng.h"
#include "sd_train_internal.h"

#define STREAM_VAE_PICK 0x5D7B000ull    // which sample and which form (appearance / geometry)
#define STREAM_VAE_NOISE 0x5D7B100ull   // the reparameterisation noise

// Image b of a batch as the VAE sees it: 2 x - 1 of the appearance or the geometry image.
static void vae_image(const mlb_sd_dataset* d, int i, int geo, float* x) {
    size_t n = (size_t)3 * d->res * d->res;
    const uint8_t* src = (geo ? d->geo : d->rgb) + (size_t)i * n;
    for (size_t k = 0; k < n; k++) x[k] = (float)src[k] * (2.0f / 255.0f) - 1.0f;
}

mlb_status mlb_sd_train_vae(const mlb_backend* be, const mlb_sd_train_config* c, const mlb_sd_dataset* d,
                            mlb_train_params* P, mlb_losslog* log) {
    const mlb_vae* v = P->vae;
    int B = c->vae_batch, R = d->res, h = d->lat;
    size_t NI = (size_t)B * 3 * R * R, NZ = (size_t)B * 4 * h * h;
    float* hx = malloc(NI * sizeof(float));
    float* hr = malloc(NI * sizeof(float));
    float* hz = malloc(5 * NZ * sizeof(float));   // mean, logvar, eps, z / dz, dlogvar
    float *dimg = NULL, *dz = NULL, *drec = NULL;
    mlb_vae_cache ec = {0};
    mlb_vae_dec_cache dc = {0};
    mlb_status s = hx && hr && hz ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "VAE training: out of memory");
    if (!s) s = be->alloc(&dimg, NI);
    if (!s) s = be->alloc(&drec, NI);
    if (!s) s = be->alloc(&dz, NZ);   // z, then dL/dz
    ec.train = 1;                     // keep what the weight gradients need
    float *mu = hz, *lv = hz + NZ, *eps = hz + 2 * NZ, *zz = hz + 3 * NZ, *dlv = hz + 4 * NZ;
    mlb_progress pr;
    mlb_progress_begin(&pr, stderr, "VAE", P->total, "step");
    pr.base = P->step;   // a resumed run: its rate and ETA count this run's steps only
    double ema = -1;
    long first = P->step;
    double t_phase = mlb_now_seconds();
    for (long step = P->step; !s && step < P->total && !(c->stop_after > 0 && step >= c->stop_after); step++) {
        if (P->deadline > 0 && step == first + 20) P->total = mlb_train_fit_steps(P->total, first, step, t_phase, P->deadline - t_phase);
        for (int b = 0; b < B; b++) {
            uint64_t row = (uint64_t)step * B + b;
            int i = (int)mlb_rng_below(c->seed, STREAM_VAE_PICK, 2 * row, (uint32_t)d->n);
            int geo = (int)mlb_rng_below(c->seed, STREAM_VAE_PICK, 2 * row + 1, 2);
            vae_image(d, i, geo, hx + (size_t)b * 3 * R * R);
        }
        s = be->upload(dimg, hx, NI);
        if (!s) s = be->zero(P->grads, P->n);
        if (!s) s = mlb_vae_encode(be, v, dimg, B, R, R, mu, lv, &ec);   // mean, logvar to the host
        if (s) break;
        // z = mean + exp(logvar / 2) eps
        double kl = 0;
        for (size_t k = 0; k < NZ; k++) {
            eps[k] = mlb_rng_normal(c->seed, STREAM_VAE_NOISE, (uint64_t)step * NZ + k);
            zz[k] = mu[k] + expf(0.5f * lv[k]) * eps[k];
            kl += 0.5 * ((double)mu[k] * mu[k] + exp((double)lv[k]) - 1.0 - lv[k]);
        }
        kl /= (double)NZ;
        s = be->upload(dz, zz, NZ);
        if (!s) s = mlb_vae_decode(be, v, dz, B, h, h, drec, &dc);
        if (!s) s = be->download(hr, drec, NI);
        if (s) break;
        double rec = 0;
        for (size_t k = 0; k < NI; k++) {
            double e = (double)hr[k] - hx[k];
            rec += e * e;
            hr[k] = (float)(2.0 * e / (double)NI);
        }
        rec /= (double)NI;
        // decoder backward: dL/dz over z on the device
        s = be->upload(drec, hr, NI);
        if (!s) s = be->zero(dz, NZ);
        if (!s) s = mlb_vae_decode_backward(be, v, &dc, drec, dz, (mlb_vae*)P->vae_grads);
        if (!s) s = be->download(zz, dz, NZ);
        if (s) break;
        // dmean = dz + w mu / NZ; dlogvar = dz eps exp(lv/2) / 2 + w (exp(lv) - 1) / (2 NZ)
        double w = c->vae_kl;
        for (size_t k = 0; k < NZ; k++) {
            float e = expf(0.5f * lv[k]);
            dlv[k] = 0.5f * zz[k] * eps[k] * e + (float)(w * 0.5 * ((double)e * e - 1.0) / (double)NZ);
            mu[k] = zz[k] + (float)(w * mu[k] / (double)NZ);
        }
        s = mlb_vae_encode_backward(be, v, &ec, mu, dlv, NULL, (mlb_vae*)P->vae_grads);
        if (!s) s = mlb_train_params_step(be, P, c->vae_lr, step, P->total);
        if (s) break;
        P->step = step + 1;
        double loss = rec + w * kl;
        ema = ema < 0 ? rec : 0.98 * ema + 0.02 * rec;
        s = mlb_losslog_append(log, P->stage, step, &loss);
        char st[64];
        snprintf(st, sizeof st, "mse %.5f", ema);
        pr.total = P->total;
        mlb_progress_update(&pr, step + 1, st);
        if (!s && P->step % c->checkpoint_every == 0 && P->step < P->total) s = mlb_train_params_save(be, P);
    }
    if (!s) mlb_progress_end(&pr, NULL);
    if (!s && P->step < P->total) s = mlb_train_params_save(be, P);   // stopped early
    mlb_vae_cache_free(&ec);
    mlb_vae_dec_cache_free(&dc);
    be->release(dimg); be->release(drec); be->release(dz);
    free(hx); free(hr); free(hz);
    return s;
}

mlb_status mlb_sd_encode_dataset(const mlb_backend* be, const mlb_vae* v, const mlb_sd_dataset* d, float* lat_rgb,
                                 float* lat_geo) {
    const int B = 32;
    int R = d->res, h = d->lat;
    size_t ni = (size_t)3 * R * R, nz = (size_t)4 * h * h;
    float* hx = malloc(B * ni * sizeof(float));
    float* dimg = NULL;
    mlb_status s = hx ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "encoding the training set: out of memory");
    if (!s) s = be->alloc(&dimg, B * ni);
    mlb_progress pr;   // minutes on a CPU: 2 x n encoder forwards
    mlb_progress_begin(&pr, stderr, "latents", 2L * d->n, "image");
    for (int geo = 0; geo < 2 && !s; geo++)
        for (int i0 = 0; i0 < d->n && !s; i0 += B) {
            int nb = d->n - i0 < B ? d->n - i0 : B;
            for (int b = 0; b < nb; b++) vae_image(d, i0 + b, geo, hx + b * ni);
            s = be->upload(dimg, hx, nb * ni);
            if (!s) s = mlb_vae_encode(be, v, dimg, nb, R, R, (geo ? lat_geo : lat_rgb) + (size_t)i0 * nz, NULL, NULL);
            mlb_progress_update(&pr, (long)geo * d->n + i0 + nb, NULL);
        }
    if (!s) mlb_progress_end(&pr, NULL);
    be->release(dimg);
    free(hx);
    return s;
}
