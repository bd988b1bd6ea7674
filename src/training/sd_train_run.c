// The whole `matlaber sd train` run (include/matlaber/sd_train.h): data, text side, VAE, latent
// scale, UNet, the model folder. The optimiser state the two loops share: sd_train_params.c.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/fileio.h"
#include "matlaber/log.h"
#include "matlaber/progress.h"
#include "matlaber/sd_folder.h"
#include "matlaber/unet_random.h"
#include "sd_train_internal.h"

// ---- the run -------------------------------------------------------------------------------------
// The UNet's initial weights: the random-weight writer's values (unet_random.h), the last conv zeroed
// so that the first prediction is 0 (the loss starts at E eps^2 = 1, not above).
static void unet_init(mlb_unet* u, uint64_t seed) {
    size_t n = 0, off = 0;
    if (mlb_unet_tensor_specs(&u->cfg, NULL, 0, &n)) return;
    mlb_unet_tensor_spec* sp = calloc(n, sizeof *sp);
    if (!sp) return;
    mlb_unet_tensor_specs(&u->cfg, sp, n, &n);
    for (size_t i = 0; i < n; i++) {
        mlb_unet_random_values(&sp[i], i, seed, 1.0f, u->params + off);
        off += sp[i].n;
    }
    free(sp);
    size_t nw = (size_t)u->cfg.out_channels * u->cfg.block_out[0] * 9;
    memset(u->conv_out_w, 0, nw * sizeof(float));
    memset(u->conv_out_b, 0, (size_t)u->cfg.out_channels * sizeof(float));
}

// Mean 0 and the standard deviation of the appearance latents -> the scale that gives them unit
// variance, as SD's 0.18215 does for its VAE.
static float latent_scale(const float* z, size_t n) {
    double s = 0, s2 = 0;
    for (size_t i = 0; i < n; i++) { s += z[i]; s2 += (double)z[i] * z[i]; }
    double mean = s / (double)n, var = s2 / (double)n - mean * mean;
    return var > 1e-12 ? (float)(1.0 / sqrt(var)) : 1.0f;
}

// The options that decide a run's bits, one "name value" per line: written by a first run into
// train/options.txt, compared by --resume, which continues only with the same ones (a resume with
// another step count, batch or data set would quietly be another training). The time limit is not
// among them (a cut run's totals are in its states), nor the precision (docs/sd_train.md).
static void options_text(const mlb_sd_train_config* c, char* out, size_t cap) {
    snprintf(out, cap,
             "res %d\nimages %d\nseed %llu\ninit %s\n"
             "text %d %d %d %d %llu\nvae %d %d %d %d x%d groups %d\nunet %d %d %d x%d groups %d\n"
             "vae_steps %d\nvae_batch %d\nvae_lr %.17g\nvae_kl %.17g\n"
             "unet_steps %d\nunet_batch %d\nunet_lr %.17g\n"
             "p_uncond %.9g\np_no_view %.9g\np_geo %.9g\np_latent %.9g\nunet_dtype %d\n",
             c->res, c->n_images, (unsigned long long)c->seed, c->init_dir ? c->init_dir : "-",
             c->text.width, c->text.layers, c->text.heads, c->text.mlp, (unsigned long long)c->text.seed,
             c->vae.block_out[0], c->vae.block_out[1], c->vae.block_out[2], c->vae.block_out[3], c->vae.n_levels,
             c->vae.norm_groups, c->unet.block_out[0], c->unet.block_out[1], c->unet.block_out[2], c->unet.n_levels,
             c->unet.norm_groups, c->vae_steps, c->vae_batch, c->vae_lr, c->vae_kl, c->unet_steps, c->unet_batch,
             c->unet_lr, (double)c->p_uncond, (double)c->p_no_view, (double)c->p_geo, (double)c->p_latent,
             (int)c->unet_dtype);
}

static mlb_status check_or_write_options(const mlb_sd_train_config* c) {
    char path[4200], now[2048];
    snprintf(path, sizeof path, "%s/train/options.txt", c->out_dir);
    options_text(c, now, sizeof now);
    if (!c->resume || !mlb_is_file(path)) {
        if (c->resume) mlb_log(MLB_LOG_WARN, "sd train: %s missing (a run from before it was written): the options are not checked", path);
        return mlb_write_file_atomic(path, now, strlen(now));
    }
    char* was = NULL;
    size_t n = 0;
    MLB_TRY(mlb_read_file(path, &was, &n, 1 << 16));
    mlb_status s = MLB_OK;
    const char *a = was, *b = now;   // was is NUL-terminated by mlb_read_file
    while (!s && (*a || *b)) {
        size_t la = strcspn(a, "\n"), lb = strcspn(b, "\n");
        if (la != lb || memcmp(a, b, la))
            s = mlb_fail(MLB_ERR_ARG, "%s: the first run had \"%.*s\", this one \"%.*s\": --resume continues only with "
                         "the first run's options", path, (int)(la > 200 ? 200 : la), a, (int)(lb > 200 ? 200 : lb), b);
        a += la + (a[la] == '\n');
        b += lb + (b[lb] == '\n');
    }
    free(was);
    return s;
}

// The run's two models: host copies (initial values, the files written), the device's, their
// gradients, and each one's optimiser state.
typedef struct {
    mlb_vae *hv, *dv, *gv;
    mlb_unet *hu, *du, *gu;
    mlb_train_params PV, PU;
    float init_scale;   // the scale a UNet from --init was trained at; 0 without --init
} sd_run;

static void run_free(const mlb_backend* be, sd_run* r) {
    mlb_train_params_free(be, &r->PV);
    mlb_train_params_free(be, &r->PU);
    mlb_vae_free(r->hv); mlb_vae_free(r->dv); mlb_vae_free(r->gv);
    mlb_unet_free(r->hu); mlb_unet_free(r->du); mlb_unet_free(r->gu);
}

// The VAE: --init's weights (its scale kept aside, the training's at 1) or random ones.
static mlb_status run_vae(const mlb_backend* be, const mlb_sd_train_config* c, sd_run* r) {
    char p[4200];
    mlb_vae_config vc = c->vae;
    vc.scaling_factor = 1.0f;
    if (c->init_dir) {
        snprintf(p, sizeof p, "%s/vae", c->init_dir);
        MLB_TRY(mlb_vae_load(p, NULL, &r->hv));
        r->init_scale = r->hv->cfg.scaling_factor;
        vc = r->hv->cfg;
        vc.scaling_factor = r->hv->cfg.scaling_factor = 1.0f;
    } else {
        MLB_TRY(mlb_vae_create(NULL, &vc, &r->hv));
        mlb_vae_init_random(r->hv, c->seed, 1.0f);
    }
    MLB_TRY(mlb_vae_create(be, &vc, &r->dv));
    MLB_TRY(mlb_vae_create(be, &vc, &r->gv));
    MLB_TRY(be->upload(r->dv->params, r->hv->params, r->hv->n_params));
    MLB_TRY(mlb_train_params_init(be, &r->PV, c->out_dir, "vae", 0, r->dv->params, r->gv->params, r->dv->n_params,
                                  c->vae_steps));
    r->PV.vae = r->dv;
    r->PV.vae_grads = r->gv;
    return MLB_OK;
}

// The UNet likewise (its text width checked against the text encoder's).
static mlb_status run_unet(const mlb_backend* be, const mlb_sd_train_config* c, sd_run* r) {
    char p[4200];
    mlb_unet_config uc = c->unet;
    if (c->init_dir) {
        snprintf(p, sizeof p, "%s/unet", c->init_dir);
        MLB_TRY(mlb_unet_load(p, NULL, &r->hu));
        uc = r->hu->cfg;
        if (uc.context_dim != c->text.width)
            return mlb_fail(MLB_ERR_ARG, "sd train: --init %s: its UNet attends to %d-wide text, the text encoder is %d wide",
                            c->init_dir, uc.context_dim, c->text.width);
    } else {
        MLB_TRY(mlb_unet_create(&uc, MLB_DEVICE_CPU, &r->hu));
        unet_init(r->hu, c->seed + 1);
    }
    if (be->device != MLB_DEVICE_CPU) MLB_TRY(mlb_unet_to_device(r->hu, be->device, &r->du));
    mlb_unet* u = r->du ? r->du : r->hu;
    MLB_TRY(mlb_unet_create(&uc, be->device, &r->gu));
    MLB_TRY(mlb_train_params_init(be, &r->PU, c->out_dir, "unet", 1, u->params, r->gu->params, u->n_params, c->unet_steps));
    r->PU.unet = u;
    r->PU.unet_grads = r->gu;
    return MLB_OK;
}

// --resume: the states that exist; *stage and *step say where the log is cut (the later phase's).
static mlb_status run_resume(const mlb_backend* be, sd_run* r, int* stage, long* step) {
    mlb_status a = mlb_train_params_load(be, &r->PV);
    if (a != MLB_OK && a != MLB_ERR_NOT_FOUND) return a;
    mlb_status b = mlb_train_params_load(be, &r->PU);
    if (b != MLB_OK && b != MLB_ERR_NOT_FOUND) return b;
    if (b == MLB_OK) *stage = 1, *step = r->PU.step;
    else if (a == MLB_OK) *stage = 0, *step = r->PV.step;
    else *stage = 0;
    mlb_log(MLB_LOG_INFO, "sd train: resuming at VAE step %ld, UNet step %ld", r->PV.step, r->PU.step);
    return MLB_OK;
}

// The trained VAE's latents of every image, in both forms, scaled, and the VAE written with the
// scale: a UNet continued over an untouched VAE keeps the scale it learned at; otherwise this
// data's (a few tenths of a percent apart between renders of the catalogue).
static mlb_status run_latents(const mlb_backend* be, const mlb_sd_train_config* c, const mlb_sd_dataset* d, sd_run* r,
                              float* lat_rgb, float* lat_geo) {
    size_t nl = (size_t)d->n * 4 * d->lat * d->lat;
    MLB_TRY(mlb_sd_encode_dataset(be, r->dv, d, lat_rgb, lat_geo));
    float sf = r->init_scale > 0.0f && r->PV.total == 0 ? r->init_scale : latent_scale(lat_rgb, nl);
    for (size_t i = 0; i < nl; i++) { lat_rgb[i] *= sf; lat_geo[i] *= sf; }
    r->hv->cfg.scaling_factor = sf;
    mlb_log(MLB_LOG_INFO, "sd train: latent scale %.5f (the appearance latents' standard deviation is %.4f)", sf, 1.0 / sf);
    char p[4200], w[4300], cj[4300];
    snprintf(p, sizeof p, "%s/vae", c->out_dir);
    MLB_TRY(mlb_mkdir_p(p));
    snprintf(w, sizeof w, "%s/diffusion_pytorch_model.safetensors", p);
    snprintf(cj, sizeof cj, "%s/config.json", p);
    return mlb_vae_save(r->hv, w, MLB_VAE_LAYOUT_DIFFUSERS, NULL, cj);
}

mlb_status mlb_sd_train(const mlb_backend* be, const mlb_sd_train_config* c) {
    MLB_TRY(mlb_sd_train_check(c));
    char p[4200];
    snprintf(p, sizeof p, "%s/train", c->out_dir);
    MLB_TRY(mlb_mkdir_p(p));
    MLB_TRY(check_or_write_options(c));
    double t0 = mlb_now_seconds();
    mlb_sd_dataset d;
    mlb_progress pr;
    mlb_progress_begin(&pr, stderr, "render", c->n_images, "image");
    MLB_TRY(mlb_sd_dataset_render(&d, c->n_images, c->res, c->seed, &pr));
    mlb_progress_end(&pr, NULL);
    mlb_log(MLB_LOG_INFO, "sd train: %d catalogue images at %dx%d rendered in %.1f s", d.n, d.res, d.res, mlb_now_seconds() - t0);
    float* captions = NULL;
    sd_run r = {0};
    mlb_losslog* log = NULL;
    float *lat_rgb = NULL, *lat_geo = NULL;
    size_t nl = (size_t)d.n * 4 * d.lat * d.lat;
    mlb_status s = mlb_sd_train_text(c, &captions);
    if (!s) s = run_vae(be, c, &r);
    if (!s) s = run_unet(be, c, &r);
    int rstage = -1;   // where the loss log is cut: -1 a fresh run
    long rstep = 0;
    if (!s && c->resume) s = run_resume(be, &r, &rstage, &rstep);
    const char* col[1] = {"loss"};
    snprintf(p, sizeof p, "%s/train/loss.csv", c->out_dir);
    if (!s) s = mlb_losslog_open(&log, p, col, 1, rstage, rstep);
    if (c->time_limit > 0) {
        double left = c->time_limit - (mlb_now_seconds() - t0);
        r.PV.deadline = mlb_now_seconds() + 0.25 * (left > 0 ? left : 0);
        r.PU.deadline = t0 + c->time_limit - 15.0;   // the latents, the files
    }
    if (!s && r.PV.step < r.PV.total) s = mlb_sd_train_vae(be, c, &d, &r.PV, log);
    if (!s && r.PV.step == r.PV.total && rstage < 1) s = mlb_train_params_save(be, &r.PV);
    int stopped = !s && r.PV.step < r.PV.total;
    if (!s) s = be->download(r.hv->params, r.dv->params, r.hv->n_params);
    if (!s && !stopped && (!(lat_rgb = malloc(nl * sizeof(float))) || !(lat_geo = malloc(nl * sizeof(float)))))
        s = mlb_fail(MLB_ERR_NOMEM, "sd train: out of memory for the latents");
    if (!s && !stopped) s = run_latents(be, c, &d, &r, lat_rgb, lat_geo);
    if (!s && !stopped && r.PU.step < r.PU.total) s = mlb_sd_train_unet(be, c, &d, lat_rgb, lat_geo, captions, &r.PU, log);
    if (!s && !stopped) stopped = r.PU.step < r.PU.total;
    if (!s && !stopped) s = mlb_train_params_save(be, &r.PU);
    if (!s && stopped) {
        mlb_log(MLB_LOG_INFO, "sd train: stopped after VAE step %ld, UNet step %ld: continue with --resume", r.PV.step, r.PU.step);
        goto finish;
    }
    if (!s && r.du) s = be->download(r.hu->params, r.du->params, r.hu->n_params);
    snprintf(p, sizeof p, "%s/unet", c->out_dir);
    if (!s) s = mlb_unet_save_folder(r.hu, p, c->unet_dtype);
    if (!s) s = mlb_sd_write_index(c->out_dir, MLB_SD_GEOMETRY_SUFFIX);
finish:;
    mlb_losslog_close(log);
    char png[4300];
    snprintf(p, sizeof p, "%s/train/loss.csv", c->out_dir);
    snprintf(png, sizeof png, "%s/train/loss.png", c->out_dir);
    static const char* const phases[2] = {"VAE (MSE + KL)", "UNet (noise MSE)"};
    if (!s) s = mlb_losslog_plot_named(p, png, phases, 2);
    if (!s && !stopped) {
        char dur[32];
        mlb_log(MLB_LOG_INFO, "sd train: %s written in %s (VAE %d steps, UNet %d steps on the %s)", c->out_dir,
                mlb_format_duration(mlb_now_seconds() - t0, dur, sizeof dur), (int)r.PV.total, (int)r.PU.total,
                mlb_device_name(be->device));
    }
    run_free(be, &r);
    free(lat_rgb); free(lat_geo); free(captions);
    mlb_sd_dataset_free(&d);
    return s;
}
