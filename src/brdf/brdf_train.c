// Training the latent BRDF auto-encoder: shuffled mini-batches, AdamW, one permutation per epoch
// from the counter RNG, so a seed gives one run on any thread count.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/brdf_ae.h"
#include "matlaber/rng.h"
#include <omp.h>

#define STREAM_SHUFFLE 0x3000

mlb_brdf_ae_config mlb_brdf_ae_default_config(void) {
    mlb_brdf_ae_config c = {.hidden = 64, .depth = 3, .act = MLB_ACT_SILU};
    return c;
}

mlb_brdf_loss_config mlb_brdf_loss_default_config(void) {
    mlb_brdf_loss_config c = {.lambda_kl = 2e-4, .lambda_s = 0.02, .lambda_c = 1e-4, .smooth_form = MLB_BRDF_SMOOTH_BEND,
                              .n_alpha = 8, .sample_latent = 1};
    return c;
}

mlb_brdf_train_config mlb_brdf_train_default_config(void) {
    mlb_brdf_train_config c = {.epochs = 30, .batch = 256, .lr = 1e-3, .lr_final = 1e-5, .weight_decay = 0.01,
                               .beta1 = 0.9, .beta2 = 0.999, .eps = 1e-8, .seed = 1, .encoder_epochs = 5, .encoder_lr = 1e-3,
                               .loss = mlb_brdf_loss_default_config()};
    return c;
}

// A batch is split into TRAIN_SHARDS equal shards whose losses and gradients are computed in
// parallel (one thread each; a shard's GEMMs run on its thread) and summed in a fixed order. The
// result is the mean-over-rows gradient of the whole batch (interpolation pairs form within a
// shard), and it is bitwise the same on any number of threads because the shard count, not the
// thread count, decides the arithmetic.
#define TRAIN_SHARDS 2
// the encoder phase's learning rate decays to this share of cfg->encoder_lr
#define ENCODER_LR_FINAL 0.01

// Cosine decay from lr0 at step 0 to lr1 at step n - 1.
static double cosine_lr(double lr0, double lr1, long step, long n) {
    double t = n > 1 ? (double)step / (double)(n - 1) : 1;
    return lr1 + 0.5 * (lr0 - lr1) * (1 + cos(M_PI * t));
}

mlb_status mlb_brdf_ae_train(mlb_brdf_ae* ae, const float* data, size_t n, const mlb_brdf_train_config* cfg,
                             mlb_progress* progress, mlb_brdf_epoch_callback on_epoch, void* user) {
    if (n < 2 * TRAIN_SHARDS) return mlb_fail(MLB_ERR_ARG, "BRDF training: %zu samples; need at least %d", n, 2 * TRAIN_SHARDS);
    if (n > UINT32_MAX) return mlb_fail(MLB_ERR_ARG, "BRDF training: %zu samples; at most 2^32 - 1", n);
    if (cfg->epochs < 1 || cfg->batch < 2 * TRAIN_SHARDS || !(cfg->lr > 0))
        return mlb_fail(MLB_ERR_ARG, "BRDF training: epochs %d, batch %d, lr %g (need epochs >= 1, batch >= %d, lr > 0)",
                        cfg->epochs, cfg->batch, cfg->lr, 2 * TRAIN_SHARDS);
    if (cfg->encoder_epochs > 0 && !(cfg->encoder_lr > 0))
        return mlb_fail(MLB_ERR_ARG, "BRDF training: %d encoder epochs need a positive encoder learning rate (got %g)",
                        cfg->encoder_epochs, cfg->encoder_lr);
    // the linear baseline of the same training data travels with the prior (see mlb_brdf_ae_evaluate)
    MLB_TRY(mlb_pca_fit(data, n, 4, ae->pca_mean, ae->pca_components, NULL));
    ae->has_pca = 1;
    int B = (size_t)cfg->batch > n ? (int)n : cfg->batch;
    B -= B % TRAIN_SHARDS;
    const int Bs = B / TRAIN_SHARDS;
    size_t steps_per_epoch = n / (size_t)B;   // the incomplete last batch is dropped; each epoch reshuffles
    mlb_brdf_work w[TRAIN_SHARDS];
    float* shard_grads[TRAIN_SHARDS] = {0};
    memset(w, 0, sizeof w);
    float* m = calloc(ae->n_params, sizeof(float));
    float* v = calloc(ae->n_params, sizeof(float));
    float* batch = malloc(sizeof(float) * 7 * (size_t)B);
    uint32_t* perm = malloc(sizeof(uint32_t) * n);
    mlb_status status = MLB_OK;
    int threads = omp_get_max_threads() < TRAIN_SHARDS ? omp_get_max_threads() : TRAIN_SHARDS;
    if (!m || !v || !batch || !perm) { status = mlb_fail(MLB_ERR_NOMEM, "BRDF training: out of memory for %zu samples", n); goto done; }
    for (int sh = 0; sh < TRAIN_SHARDS; sh++) {
        if ((status = brdf_work_alloc(&w[sh], ae, Bs))) goto done;
        if (!(shard_grads[sh] = malloc(sizeof(float) * ae->n_params))) { status = mlb_fail(MLB_ERR_NOMEM, "BRDF training: out of memory"); goto done; }
    }
    mlb_adam_config adam = {.lr = cfg->lr, .beta1 = cfg->beta1, .beta2 = cfg->beta2, .eps = cfg->eps,
                            .weight_decay = cfg->weight_decay, .decoupled = 1};
    // Two phases: the joint loss for cfg->epochs, then cfg->encoder_epochs of the encoder alone
    // (decoder frozen, z = mu, reconstruction only) with fresh moments and its own cosine schedule.
    const int all_epochs = cfg->epochs + (cfg->encoder_epochs > 0 ? cfg->encoder_epochs : 0);
    const long joint_steps = (long)steps_per_epoch * cfg->epochs, encoder_steps = (long)steps_per_epoch * (all_epochs - cfg->epochs);
    mlb_brdf_loss_config encoder_loss = {.lambda_kl = 0, .lambda_s = 0, .lambda_c = 0, .n_alpha = cfg->loss.n_alpha, .sample_latent = 0};
    long step = 0, phase_step = 0;
    if (progress) progress->total = joint_steps + encoder_steps;
    for (int epoch = 0; epoch < all_epochs; epoch++) {
        const int encoder_only = epoch >= cfg->epochs;
        const mlb_brdf_loss_config* loss = encoder_only ? &encoder_loss : &cfg->loss;
        if (epoch == cfg->epochs) {   // the encoder phase starts
            memset(m, 0, sizeof(float) * ae->n_params);
            memset(v, 0, sizeof(float) * ae->n_params);
            phase_step = 0;
            adam.weight_decay = 0;
        }
        double t0 = mlb_now_seconds();
        double sum[5] = {0};
        mlb_rng_permutation(perm, (uint32_t)n, cfg->seed, STREAM_SHUFFLE + (uint64_t)epoch);
        for (size_t s = 0; s < steps_per_epoch; s++) {
            for (int i = 0; i < B; i++) memcpy(batch + 7 * i, data + 7 * (size_t)perm[s * B + i], sizeof(float) * 7);
            mlb_brdf_losses L[TRAIN_SHARDS];
            mlb_status shard_status[TRAIN_SHARDS];
#pragma omp parallel for schedule(static, 1) num_threads(threads)
            for (int sh = 0; sh < TRAIN_SHARDS; sh++) {
                memset(shard_grads[sh], 0, sizeof(float) * ae->n_params);
                shard_status[sh] = brdf_ae_loss(ae, &w[sh], batch + 7 * (size_t)sh * Bs, Bs, loss, cfg->seed,
                                                (uint64_t)step * TRAIN_SHARDS + (uint64_t)sh, shard_grads[sh], &L[sh]);
            }
            for (int sh = 0; sh < TRAIN_SHARDS; sh++)
                if (shard_status[sh]) { status = shard_status[sh]; goto done; }
            double total = 0;
            for (int sh = 0; sh < TRAIN_SHARDS; sh++) total += L[sh].total;
            total /= TRAIN_SHARDS;
            if (!isfinite(total)) {
                status = mlb_fail(MLB_ERR_NUMERIC, "BRDF training diverged at epoch %d step %zu (loss %g); try a lower --lr",
                                  epoch + 1, s, total);
                goto done;
            }
            for (size_t i = 0; i < ae->n_params; i++) {
                float g = 0;
                for (int sh = 0; sh < TRAIN_SHARDS; sh++) g += shard_grads[sh][i];
                ae->grads[i] = g / TRAIN_SHARDS;
            }
            if (encoder_only) {
                memset(ae->grads + ae->n_enc_params, 0, sizeof(float) * (ae->n_params - ae->n_enc_params));
                adam.lr = cosine_lr(cfg->encoder_lr, ENCODER_LR_FINAL * cfg->encoder_lr, phase_step, encoder_steps);
            } else if (cfg->lr_final > 0) {
                adam.lr = cosine_lr(cfg->lr, cfg->lr_final, phase_step, joint_steps);
            }
            step++;
            phase_step++;
            adam_update(ae->params, ae->grads, m, v, ae->n_params, &adam, phase_step);
            for (int sh = 0; sh < TRAIN_SHARDS; sh++) {
                sum[0] += L[sh].total / TRAIN_SHARDS; sum[1] += L[sh].l_r / TRAIN_SHARDS; sum[2] += L[sh].l_kl / TRAIN_SHARDS;
                sum[3] += L[sh].l_s / TRAIN_SHARDS; sum[4] += L[sh].l_c / TRAIN_SHARDS;
            }
            if (progress) {
                char text[96];
                snprintf(text, sizeof text, "%sepoch %d/%d loss %.5f", encoder_only ? "encoder " : "", epoch + 1, all_epochs, sum[0] / (double)(s + 1));
                mlb_progress_update(progress, step, text);
            }
        }
        if (on_epoch) {
            double dt = mlb_now_seconds() - t0, k = (double)steps_per_epoch;
            mlb_brdf_epoch_stats st = {.epoch = epoch + 1, .encoder_only = encoder_only, .loss = sum[0] / k, .l_r = sum[1] / k, .l_kl = sum[2] / k,
                                       .l_s = sum[3] / k, .l_c = sum[4] / k, .seconds = dt,
                                       .samples_per_second = dt > 0 ? k * B / dt : 0};
            on_epoch(&st, user);
        }
    }
done:
    for (int sh = 0; sh < TRAIN_SHARDS; sh++) { brdf_work_free(&w[sh]); free(shard_grads[sh]); }
    free(m); free(v); free(batch); free(perm);
    return status;
}
