// Training the project's own small diffusion model (include/matlaber/sd_train.h, docs/sd_train.md):
// configuration, the text side, the UNet's noise-prediction loop, state files and the model folder.
// The VAE's loop is in sd_train_vae.c; the two share the parameter-set helpers of sd_train_internal.h.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/catalogue.h"
#include "matlaber/fileio.h"
#include "matlaber/log.h"
#include "matlaber/progress.h"
#include "matlaber/rng.h"
#include "matlaber/schedule.h"
#include "matlaber/sd_model.h"
#include "matlaber/sds.h"
#include "matlaber/text_encoder.h"
#include "matlaber/tokenizer.h"
#include "matlaber/unet_random.h"
#include "matlaber/unet_train.h"
#include "sd_train_internal.h"

#define STREAM_PICK 0x5D7A000ull      // which sample a batch row takes
#define STREAM_T 0x5D7A100ull         // its timestep
#define STREAM_NOISE 0x5D7A200ull     // its noise
#define STREAM_KIND 0x5D7A300ull      // appearance / geometry / latent phase; caption dropping

mlb_sd_train_config mlb_sd_train_default(void) {
    mlb_sd_train_config c;
    memset(&c, 0, sizeof c);
    c.out_dir = NULL;
    c.res = 128;
    c.n_images = 8000;
    c.seed = 1;
    c.text = (mlb_text_encoder_shape){0, 64, 1, 4, 256, 11};
    mlb_vae_config v = mlb_vae_sd_config();
    v.n_levels = 4;
    v.block_out[0] = 32; v.block_out[1] = 64; v.block_out[2] = 64; v.block_out[3] = 64;
    v.layers_per_block = 1;
    v.norm_groups = 16;
    v.scaling_factor = 1.0f;   // set from the data after the VAE is trained
    c.vae = v;
    c.vae_steps = 3000;
    c.vae_batch = 16;
    c.vae_lr = 1e-3;
    c.vae_kl = 1e-4;
    mlb_unet_config u = mlb_unet_tiny_config(0);   // SD1's settings (norms, eps, sinusoid), then the sizes
    memset(u.attn, 0, sizeof u.attn);
    memset(u.heads, 0, sizeof u.heads);
    u.n_levels = 3;
    u.block_out[0] = 64; u.block_out[1] = 128; u.block_out[2] = 128;
    u.layers_per_block = 1;
    u.attn[0] = 1; u.attn[1] = 1; u.attn[2] = 0;
    u.heads[0] = u.heads[1] = u.heads[2] = 4;
    u.mid_heads = 4;
    u.context_dim = c.text.width;
    u.time_embed_dim = 256;
    c.unet = u;
    c.unet_steps = 20000;
    c.unet_batch = 32;
    c.unet_lr = 5e-4;
    c.p_uncond = 0.1f;
    c.p_no_view = 0.2f;
    c.p_geo = 0.35f;
    c.p_latent = 0.0f;   // see docs/sd_train.md: the tiny preset's geometry starts in the VAE phase
    c.checkpoint_every = 500;
    c.unet_dtype = MLB_DT_F16;
    c.resume = 0;
    return c;
}

mlb_status mlb_sd_train_check(const mlb_sd_train_config* c) {
    if (!c || !c->out_dir || !c->out_dir[0]) return mlb_fail(MLB_ERR_ARG, "sd train: no output folder");
    if (c->res < 16 || c->res % 8 || c->res > 512) return mlb_fail(MLB_ERR_ARG, "sd train: --res %d (16..512, a multiple of 8)", c->res);
    if (c->n_images < 1) return mlb_fail(MLB_ERR_ARG, "sd train: --images %d must be positive", c->n_images);
    if (c->vae_steps < 0 || c->unet_steps < 0 || c->vae_batch < 1 || c->unet_batch < 1)
        return mlb_fail(MLB_ERR_ARG, "sd train: steps (%d, %d) must be >= 0 and batches (%d, %d) >= 1", c->vae_steps,
                        c->unet_steps, c->vae_batch, c->unet_batch);
    if (!(c->vae_lr > 0) || !(c->unet_lr > 0) || !(c->vae_kl >= 0))
        return mlb_fail(MLB_ERR_ARG, "sd train: learning rates must be > 0 and the KL weight >= 0");
    if (!(c->p_uncond >= 0 && c->p_no_view >= 0 && c->p_geo >= 0 && c->p_latent >= 0 && c->p_uncond <= 1 &&
          c->p_no_view <= 1 && c->p_geo + c->p_latent <= 1))
        return mlb_fail(MLB_ERR_ARG, "sd train: probabilities out of range");
    if (c->unet.context_dim != c->text.width)
        return mlb_fail(MLB_ERR_ARG, "sd train: the UNet attends to %d-wide text, the text encoder is %d wide", c->unet.context_dim,
                        c->text.width);
    if (mlb_vae_latent_size(&c->vae, c->res) * 8 != c->res || c->vae.n_levels != 4)
        return mlb_fail(MLB_ERR_ARG, "sd train: the VAE must downsample 8x (4 levels), as SD's");
    MLB_TRY(mlb_vae_config_check(&c->vae));
    MLB_TRY(mlb_unet_config_check(&c->unet));
    if ((c->res / 8) % (1 << (c->unet.n_levels - 1)))
        return mlb_fail(MLB_ERR_ARG, "sd train: latent %d is not a multiple of %d (the UNet's downsamplings)", c->res / 8,
                        1 << (c->unet.n_levels - 1));
    if (c->checkpoint_every < 1) return mlb_fail(MLB_ERR_ARG, "sd train: checkpoint interval %d", c->checkpoint_every);
    return MLB_OK;
}

// ---- the text side -------------------------------------------------------------------------------
// Every word the captions use, and those of the guidance's default negative prompts.
static int caption_words(const char** w, int cap) {
    static const char* fixed[] = {"a", "front", "side", "back", "overhead", "view", "low", "quality", "shadow",
                                  "oversaturated", "unrealistic"};
    int n = 0;
    for (size_t i = 0; i < sizeof fixed / sizeof fixed[0] && n < cap; i++) w[n++] = fixed[i];
    for (int c = 0; c < mlb_catalogue_n_classes() && n < cap; c++) w[n++] = mlb_catalogue_class_name(c);
    for (int m = 0; m < mlb_catalogue_n_materials() && n < cap; m++) w[n++] = mlb_catalogue_material_name(m);
    return n;
}

// The unconditional prompts: the empty one (txt2img's) and the guidance's default negatives
// (guidance_sds.h), so that the stock SDS settings read as "no caption" to this model too.
static const char* const UNCOND[MLB_SD_N_UNCOND] = {"", "low quality", "shadow, oversaturated, low quality, unrealistic"};

mlb_status mlb_sd_train_text(const mlb_sd_train_config* c, float** table) {
    char p[4200];
    const char* words[128];
    int nw = caption_words(words, 128);
    snprintf(p, sizeof p, "%s/tokenizer", c->out_dir);
    MLB_TRY(mlb_sd_write_tokenizer(p, words, nw));
    mlb_tokenizer* tok = NULL;
    MLB_TRY(mlb_tokenizer_load(p, &tok));
    mlb_text_encoder_shape ts = c->text;
    ts.vocab = mlb_tokenizer_vocab_size(tok);
    snprintf(p, sizeof p, "%s/text_encoder", c->out_dir);
    mlb_text_encoder* te = NULL;
    mlb_status s = mlb_text_encoder_write_random(p, &ts);
    if (!s) s = mlb_text_encoder_load(p, NULL, &te);
    int count = mlb_sd_caption_count(), W = ts.width, T = MLB_CLIP_CONTEXT;
    float* tab = s ? NULL : malloc((size_t)(count + MLB_SD_N_UNCOND) * T * W * sizeof(float));
    if (!s && !tab) s = mlb_fail(MLB_ERR_NOMEM, "sd train: out of memory for the caption table");
    int ids[MLB_CLIP_CONTEXT];
    char text[256];
    for (int k = 0; !s && k < count + MLB_SD_N_UNCOND; k++) {
        if (k >= count) snprintf(text, sizeof text, "%s", UNCOND[k - count]);
        else mlb_sd_caption_text(k, text, sizeof text);
        s = mlb_tokenizer_encode(tok, text, ids, T, mlb_tokenizer_eos(tok), NULL);
        // no op table in scope (mlb_sd_train_unet's comes later): the CPU's fp32 table, so the
        // caption table is the same whichever device trains the UNet
        if (!s) s = mlb_text_encoder_forward(mlb_backend_cpu(), te, ids, 1, T, tab + (size_t)k * T * W, NULL, 0);
    }
    mlb_text_encoder_free(te);
    mlb_tokenizer_free(tok);
    if (s) { free(tab); return mlb_fail_context(s, "sd train: the text encoder"); }
    *table = tab;
    return MLB_OK;
}

// ---- one UNet batch ------------------------------------------------------------------------------
// Row b of step `step`: a sample, its kind (appearance / geometry / latent phase), its caption row,
// timestep and noise; x_t and the target noise [4, h, w] on the host.
static void unet_example(const mlb_sd_train_config* c, const mlb_sd_dataset* d, const float* lat_rgb, const float* lat_geo,
                         const float* ac, long step, int b, float* xt, float* eps, float* t, int* caption) {
    uint64_t row = (uint64_t)step * (uint64_t)c->unet_batch + (uint64_t)b;
    int i = (int)mlb_rng_below(c->seed, STREAM_PICK, row, (uint32_t)d->n);
    mlb_u32x4 r = mlb_rng_words(c->seed, STREAM_KIND, row);
    double u_kind = mlb_u32_to_unit(r.v[0]), u_drop = mlb_u32_to_unit(r.v[1]), u_view = mlb_u32_to_unit(r.v[2]);
    size_t L = (size_t)4 * d->lat * d->lat;
    int geometry = u_kind < c->p_latent + c->p_geo;
    const float* z = u_kind < c->p_latent ? d->lat_geo + (size_t)i * L : geometry ? lat_geo + (size_t)i * L : lat_rgb + (size_t)i * L;
    int tt = (int)mlb_rng_below(c->seed, STREAM_T, row, 1000);
    float a = ac[tt], sa = sqrtf(a), sb = sqrtf(1.0f - a);
    for (size_t k = 0; k < L; k++) {
        eps[k] = mlb_rng_normal(c->seed, STREAM_NOISE, row * L + k);
        xt[k] = sa * z[k] + sb * eps[k];
    }
    *t = (float)tt;
    if (u_drop < c->p_uncond) *caption = mlb_sd_caption_count() + (int)(mlb_u32_to_unit(r.v[3]) * MLB_SD_N_UNCOND);
    else *caption = mlb_sd_caption_index(d->cls[i], d->mat[i], u_view < c->p_no_view ? MLB_SDS_VIEW_NONE : d->view[i], geometry);
}

mlb_status mlb_sd_train_unet(const mlb_backend* be, const mlb_sd_train_config* c, const mlb_sd_dataset* d,
                             const float* lat_rgb, const float* lat_geo, const float* captions, mlb_train_params* P,
                             mlb_losslog* log) {
    const mlb_unet* u = P->unet;
    int B = c->unet_batch, h = d->lat, W = c->text.width, T = MLB_CLIP_CONTEXT;
    size_t L = (size_t)4 * h * h, TW = (size_t)T * W;
    float ac[MLB_SD_TRAIN_STEPS];
    MLB_TRY(mlb_schedule_alphas_cumprod_f32(ac, MLB_SD_TRAIN_STEPS, MLB_SD_BETA_START, MLB_SD_BETA_END));
    mlb_unet_tape* tape = NULL;
    MLB_TRY(mlb_unet_tape_create(be, u, B, h, h, T, &tape));
    float *hx = malloc(B * L * sizeof(float)), *heps = malloc(B * L * sizeof(float)), *hout = malloc(B * L * sizeof(float));
    float* ht = malloc(B * sizeof(float));
    float *dx = NULL, *dctx = NULL, *dout = NULL, *dcap = NULL;
    int* cap = malloc(B * sizeof(int));
    mlb_status s = hx && heps && hout && ht && cap ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "UNet training: out of memory");
    size_t ncap = (size_t)(mlb_sd_caption_count() + MLB_SD_N_UNCOND) * TW;
    if (!s) s = be->alloc(&dx, B * L * 2);   // x_t, then dL/dout
    if (!s) s = be->alloc(&dctx, B * TW);
    if (!s) s = be->alloc(&dout, B * L);
    if (!s) s = be->alloc(&dcap, ncap);
    if (!s) s = be->upload(dcap, captions, ncap);
    mlb_progress pr;
    mlb_progress_begin(&pr, stderr, "UNet", P->total, "step");
    pr.base = P->step;   // a resumed run: its rate and ETA count this run's steps only
    double ema = -1;
    long first = P->step, stop = c->stop_after > 0 ? c->stop_after - c->vae_steps : -1;
    double t_phase = mlb_now_seconds();
    for (long step = P->step; !s && step < P->total && !(stop >= 0 && step >= stop); step++) {
        if (P->deadline > 0 && step == first + 20) P->total = mlb_train_fit_steps(P->total, first, step, t_phase, P->deadline - t_phase);
        for (int b = 0; b < B; b++) unet_example(c, d, lat_rgb, lat_geo, ac, step, b, hx + b * L, heps + b * L, ht + b, cap + b);
        s = be->upload(dx, hx, B * L);
        for (int b = 0; b < B && !s; b++) s = be->copy(dctx + b * TW, dcap + (size_t)cap[b] * TW, TW);
        if (!s) s = be->zero(P->grads, P->n);
        if (!s) s = mlb_unet_forward_train(be, u, tape, dout, dx, ht, dctx, B, h, h, T);
        if (!s) s = be->download(hout, dout, B * L);
        if (s) break;
        // loss = mean (out - eps)^2; dL/dout = 2 (out - eps) / (B L)
        double loss = 0;
        for (size_t k = 0; k < B * L; k++) {
            double e = (double)hout[k] - heps[k];
            loss += e * e;
            hout[k] = (float)(2.0 * e / (double)(B * L));
        }
        loss /= (double)(B * L);
        s = be->upload(dx + B * L, hout, B * L);
        if (!s) s = mlb_unet_backward(be, u, tape, dx + B * L, P->unet_grads, NULL, NULL);
        if (!s) s = mlb_train_params_step(be, P, c->unet_lr, step, P->total);
        if (s) break;
        P->step = step + 1;
        ema = ema < 0 ? loss : 0.98 * ema + 0.02 * loss;
        if (!s) s = mlb_losslog_append(log, P->stage, step, &loss);
        char st[64];
        snprintf(st, sizeof st, "loss %.4f", ema);
        pr.total = P->total;
        mlb_progress_update(&pr, step + 1, st);
        if (P->step % c->checkpoint_every == 0 && P->step < P->total) s = mlb_train_params_save(be, P);
    }
    if (!s) mlb_progress_end(&pr, NULL);
    if (!s && P->step < P->total) s = mlb_train_params_save(be, P);   // stopped early
    mlb_unet_tape_free(tape);
    be->release(dx); be->release(dctx); be->release(dout); be->release(dcap);
    free(hx); free(heps); free(hout); free(ht); free(cap);
    return s;
}
