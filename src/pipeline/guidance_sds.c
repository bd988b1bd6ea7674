// Score-distillation guidance (include/matlaber/guidance_sds.h, docs/guidance.md): orbit cameras,
// the conversions of the [n, H, W, 4] renders to what Stable Diffusion sees, and back.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/guidance_sds.h"
#include "matlaber/backend.h"
#include "matlaber/log.h"

typedef struct {
    mlb_sds* geo;                 // geometry: negative_geometry, geometry_opt
    mlb_sds* app;                 // appearance: negative_appearance, appearance_opt
    mlb_guidance_sds_config c;    // (string fields not kept)
    float* x;                     // [n, C, h, w] the converted images, in xbe's memory
    float* dx;                    // [n, C, h, w] their gradient
    size_t cap;                   // floats in x and dx
    const mlb_backend* xbe;       // the table that allocated x and dx (NULL: none yet)
} sds_guidance;

mlb_guidance_sds_config mlb_guidance_sds_default(void) {
    mlb_guidance_sds_config c;
    memset(&c, 0, sizeof c);
    c.prompt = NULL;
    c.negative_geometry = "low quality";
    c.negative_appearance = "shadow, oversaturated, low quality, unrealistic";
    c.views = 9;
    c.latent_iters = 1000;
    c.view_prompts = 1;
    c.geometry_opt = mlb_sds_default_options();
    c.geometry_opt.t_min = 20;
    c.geometry_opt.t_max = 500;
    c.geometry_opt.weighting = MLB_SDS_W_FANTASIA1;
    c.appearance_opt = mlb_sds_default_options();
    c.appearance_opt.t_min = 20;
    c.appearance_opt.t_max = 980;
    c.appearance_opt.weighting = MLB_SDS_W_FANTASIA1;
    c.orbit = mlb_orbit_default();
    c.n_envs = 0;
    c.seed = 0;
    return c;
}

// ---- the interface -------------------------------------------------------------------------------
static mlb_status sds_sample_views(mlb_guidance* g, mlb_stage stage, long step, mlb_view* views) {
    sds_guidance* s = g->impl;
    for (int v = 0; v < g->n_views; v++) MLB_TRY(mlb_orbit_sample(&views[v], &s->c.orbit, s->c.seed, (int)stage, step, v));
    return MLB_OK;
}

// x and dx of at least N floats in the memory of be's device (reallocated by another allocator).
static mlb_status buffers_on(sds_guidance* s, const mlb_backend* be, size_t N) {
    if (s->xbe && (s->xbe->alloc != be->alloc || N > s->cap)) {
        s->xbe->release(s->x);
        s->xbe->release(s->dx);
        s->x = s->dx = NULL;
        s->cap = 0;
        s->xbe = NULL;
    }
    if (s->xbe) return MLB_OK;
    mlb_status st = be->alloc(&s->x, N);
    if (!st) st = be->alloc(&s->dx, N);
    if (st) {
        if (s->x) be->release(s->x);
        s->x = NULL;
        return mlb_fail_context(st, "SDS guidance: %zu floats for the model's images", N);
    }
    s->xbe = be;
    s->cap = N;
    return MLB_OK;
}

// The stage's step form: latents ([normal, mask] resized) in the geometry stage's latent phase.
static int latent_phase(const sds_guidance* s, mlb_stage stage, long step) {
    return stage == MLB_STAGE_GEOMETRY && step < s->c.latent_iters;
}

// images [n, H, W, 4] of `stage` at `step` (on be's device) → s->x [n, *C, *h, *w] there, what the
// model sees: [normal, mask] resized to latents in the latent phase, 0.5 (normal + mask)
// (geometry) or the colour (appearance) otherwise; vids[n] the views' prompts.
static mlb_status to_model_input(sds_guidance* s, const mlb_backend* be, mlb_stage stage, long step,
                                 const mlb_view* views, int n, const float* images, int H, int W, int* vids, int* Cp,
                                 int* hp, int* wp) {
    if (!images || !views || n < 1 || n > MLB_SDS_MAX_BATCH || H < 1 || W < 1)
        return mlb_fail(MLB_ERR_ARG, "SDS guidance: bad batch (%d views of %dx%d)", n, W, H);
    if (stage != MLB_STAGE_GEOMETRY && stage != MLB_STAGE_APPEARANCE) return mlb_fail(MLB_ERR_ARG, "SDS guidance: stage %d", (int)stage);
    int latent = latent_phase(s, stage, step);
    const int L = s->c.latent_size > 0 ? s->c.latent_size : MLB_GUIDANCE_LATENT_SIZE;
    int C = latent ? 4 : 3, h = latent ? L : H, w = latent ? L : W;
    MLB_TRY(buffers_on(s, be, (size_t)n * C * h * w));
    for (int b = 0; b < n; b++)
        vids[b] = s->c.view_prompts ? mlb_sds_view_for(views[b].azimuth_deg, views[b].elevation_deg) : MLB_SDS_VIEW_NONE;
    if (latent) MLB_TRY(be->area_resize(s->x, images, n, H, W, 4, L, L));
    else MLB_TRY(be->renders_to_sd(s->x, images, n, H, W, stage == MLB_STAGE_GEOMETRY));
    *Cp = C;
    *hp = h;
    *wp = w;
    return MLB_OK;
}

static mlb_status sds_loss_on(mlb_guidance* g, const mlb_backend* be, mlb_stage stage, long step, const mlb_view* views,
                              int n, const float* images, int H, int W, float* dimages, double* loss) {
    sds_guidance* s = g->impl;
    int vids[MLB_SDS_MAX_BATCH], C, h, w;
    MLB_TRY(to_model_input(s, be, stage, step, views, n, images, H, W, vids, &C, &h, &w));
    int latent = C == 4;
    const int L = h;
    size_t N = (size_t)n * C * h * w;
    mlb_sds* sds = stage == MLB_STAGE_GEOMETRY ? s->geo : s->app;
    mlb_sds_options* opt = mlb_sds_options_of(sds);
    mlb_sds_weighting keep = opt->weighting;
    if (latent) opt->weighting = MLB_SDS_W_DREAMFUSION;   // Fantasia3D's latent phase
    mlb_status st = dimages ? be->zero(s->dx, N) : MLB_OK;
    mlb_sds_input in = {s->x, n, C, h, w, vids, step, NULL, NULL, g->part_first, g->part_total};
    float l = 0;
    if (!st) st = mlb_sds_step(sds, be, &in, dimages ? s->dx : NULL, &l, NULL);
    opt->weighting = keep;
    if (st) return mlb_fail_context(st, "SDS guidance (%s stage, step %ld)", stage == MLB_STAGE_GEOMETRY ? "geometry" : "appearance", step);
    if (loss) *loss = (double)l;
    if (!dimages) return MLB_OK;
    // dx [n, C, h, w] → dimages [n, H, W, 4] (+=)
    if (latent) return be->area_resize_backward(dimages, s->dx, n, H, W, 4, L, L);
    return be->renders_to_sd_backward(dimages, s->dx, n, H, W, stage == MLB_STAGE_GEOMETRY);
}

// Host images: on the CPU where the step's VAE runs there, else up to its device and back.
static mlb_status sds_loss(mlb_guidance* g, mlb_stage stage, long step, const mlb_view* views, int n, const float* images,
                           int H, int W, float* dimages, double* loss) {
    sds_guidance* s = g->impl;
    mlb_sds* sds = stage == MLB_STAGE_GEOMETRY ? s->geo : s->app;
    const mlb_backend* be = mlb_sds_images_table(sds, latent_phase(s, stage, step) ? 4 : 3);
    if (be->device == MLB_DEVICE_CPU) return sds_loss_on(g, mlb_backend_cpu(), stage, step, views, n, images, H, W, dimages, loss);
    if (!images || n < 1 || H < 1 || W < 1) return mlb_fail(MLB_ERR_ARG, "SDS guidance: bad batch (%d views of %dx%d)", n, W, H);
    const size_t N = (size_t)n * H * W * 4;
    float *d = NULL, *dd = NULL;
    mlb_status st = be->alloc(&d, N);
    if (!st) st = be->upload(d, images, N);
    if (!st && dimages) st = be->alloc(&dd, N);
    if (!st && dimages) st = be->upload(dd, dimages, N);
    if (!st) st = sds_loss_on(g, be, stage, step, views, n, d, H, W, dd, loss);
    if (!st && dimages) st = be->download(dimages, dd, N);
    if (d) be->release(d);
    if (dd) be->release(dd);
    return st;
}

// The diffusion classifier's score (guidance.h): SCORE_DRAWS timesteps per view, spread evenly over
// the stage's range or t_range, noise from a step number no run reaches, so every call draws the same.
#define SCORE_DRAWS 4
#define SCORE_STEP (1L << 40)
static mlb_status sds_score(mlb_guidance* g, mlb_stage stage, const mlb_view* views, int n, const float* images, int H,
                            int W, const int* t_range, double* per_view) {
    sds_guidance* s = g->impl;
    int vids[MLB_SDS_MAX_BATCH], C, h, w, lc, lh, lw, t[MLB_SDS_MAX_BATCH];
    MLB_TRY(to_model_input(s, mlb_backend_cpu(), stage, 0, views, n, images, H, W, vids, &C, &h, &w));
    mlb_sds* sds = stage == MLB_STAGE_GEOMETRY ? s->geo : s->app;
    const mlb_sds_options* opt = stage == MLB_STAGE_GEOMETRY ? &s->c.geometry_opt : &s->c.appearance_opt;
    MLB_TRY(mlb_sds_latent_shape(sds, C, h, w, &lc, &lh, &lw));
    const int lo = t_range ? t_range[0] : opt->t_min, hi = t_range ? t_range[1] : opt->t_max;
    if (lo < 0 || hi > 999 || lo > hi) return mlb_fail(MLB_ERR_ARG, "SDS guidance: scoring timesteps [%d, %d] (within 0..999)", lo, hi);
    // the renders are encoded once (the first draw's latents), the later draws take those latents
    // as they are: the same bits as encoding every time
    float* z = malloc(sizeof(float) * (size_t)lc * n * lh * lw);
    if (!z) return mlb_fail(MLB_ERR_NOMEM, "SDS guidance: out of memory scoring %d renders", n);
    double ec[MLB_SDS_MAX_BATCH], eu[MLB_SDS_MAX_BATCH];
    for (int b = 0; b < n; b++) per_view[b] = 0;
    mlb_status st = MLB_OK;
    for (int j = 0; !st && j < SCORE_DRAWS; j++) {
        for (int b = 0; b < n; b++) t[b] = lo + (int)((hi - lo) * (j + 0.5) / SCORE_DRAWS);
        mlb_sds_input in = {j ? z : s->x, n, j ? lc : C, j ? lh : h, j ? lw : w, vids, SCORE_STEP + j, t, NULL, 0, 0};
        mlb_sds_trace tr = {0};
        tr.latent = j ? NULL : z;
        tr.err_cond = ec;
        tr.err_uncond = eu;
        st = mlb_sds_step(sds, NULL, &in, NULL, NULL, &tr);
        for (int b = 0; !st && b < n; b++) per_view[b] += (eu[b] - ec[b]) / SCORE_DRAWS;
    }
    free(z);
    return st ? mlb_fail_context(st, "SDS guidance: scoring %d renders", n) : MLB_OK;
}

static void sds_destroy(mlb_guidance* g) {
    if (!g) return;
    sds_guidance* s = g->impl;
    if (s) {
        mlb_sds_free(s->geo);
        mlb_sds_free(s->app);
        if (s->xbe) {
            s->xbe->release(s->x);
            s->xbe->release(s->dx);
        }
        free(s);
    }
    free(g);
}

static mlb_status check_config(const mlb_guidance_sds_config* c) {
    if (c->views < 1 || c->views > MLB_SDS_MAX_BATCH)
        return mlb_fail(MLB_ERR_ARG, "SDS guidance: %d views per step (1..%d)", c->views, MLB_SDS_MAX_BATCH);
    if (c->latent_iters < 0) return mlb_fail(MLB_ERR_ARG, "SDS guidance: latent_iters %d < 0", c->latent_iters);
    if (c->latent_size < 0 || c->latent_size > 1024) return mlb_fail(MLB_ERR_ARG, "SDS guidance: latent size %d", c->latent_size);
    if (c->n_envs < 0) return mlb_fail(MLB_ERR_ARG, "SDS guidance: n_envs %d < 0", c->n_envs);
    const mlb_sds_options* o2[2] = {&c->geometry_opt, &c->appearance_opt};
    for (int k = 0; k < 2; k++) {
        mlb_status st = mlb_sds_options_check(o2[k]);
        if (st) return mlb_fail_context(st, "SDS guidance: %s options", k ? "appearance" : "geometry");
    }
    mlb_orbit_config o = c->orbit;
    if (c->n_envs > 0) o.n_envs = c->n_envs;
    return mlb_orbit_check(&o);
}

mlb_status mlb_guidance_sds_create_from(mlb_sds* geometry, mlb_sds* appearance, const mlb_guidance_sds_config* c,
                                        mlb_guidance** out) {
    mlb_status st = MLB_OK;
    mlb_guidance* g = NULL;
    sds_guidance* s = NULL;
    if (out) *out = NULL;
    if (!geometry || !appearance || !c || !out) st = mlb_fail(MLB_ERR_ARG, "mlb_guidance_sds_create_from: NULL argument");
    if (!st) st = check_config(c);
    if (!st) {
        g = calloc(1, sizeof *g);
        s = calloc(1, sizeof *s);
        if (!g || !s) st = mlb_fail(MLB_ERR_NOMEM, "out of memory");
    }
    if (st) {
        free(g);
        free(s);
        mlb_sds_free(geometry);
        mlb_sds_free(appearance);
        return st;
    }
    s->geo = geometry;
    s->app = appearance;
    s->c = *c;
    s->c.prompt = s->c.negative_geometry = s->c.negative_appearance = NULL;
    if (c->n_envs > 0) s->c.orbit.n_envs = c->n_envs;
    *mlb_sds_options_of(geometry) = c->geometry_opt;
    mlb_sds_options_of(geometry)->seed = c->seed * 2 + MLB_STAGE_GEOMETRY;
    *mlb_sds_options_of(appearance) = c->appearance_opt;
    mlb_sds_options_of(appearance)->seed = c->seed * 2 + MLB_STAGE_APPEARANCE;
    g->kind = "sds";
    g->n_views = c->views;
    g->sample_views = sds_sample_views;
    g->loss = sds_loss;
    g->loss_on = sds_loss_on;
    g->score = sds_score;
    g->destroy = sds_destroy;
    g->impl = s;
    *out = g;
    return MLB_OK;
}

mlb_status mlb_guidance_sds_create_staged(const mlb_sd_model* geometry_model, const mlb_sd_model* appearance_model,
                                          const mlb_guidance_sds_config* c, mlb_guidance** out) {
    if (out) *out = NULL;
    if (!geometry_model || !appearance_model || !c || !out) return mlb_fail(MLB_ERR_ARG, "mlb_guidance_sds_create: NULL argument");
    if (!c->prompt || !c->prompt[0]) return mlb_fail(MLB_ERR_ARG, "SDS guidance: no prompt");
    MLB_TRY(check_config(c));
    mlb_sds *geo = NULL, *app = NULL;
    int vp = c->view_prompts != 0;
    // the geometry stage's normal renders get the model's caption for them (sd_model.h geometry_suffix)
    char* geo_prompt = malloc(strlen(c->prompt) + MLB_SD_SUFFIX_MAX);
    if (!geo_prompt) return mlb_fail(MLB_ERR_NOMEM, "SDS guidance: out of memory");
    sprintf(geo_prompt, "%s%s", c->prompt, geometry_model->geometry_suffix);
    if (geometry_model->geometry_suffix[0])
        mlb_log(MLB_LOG_INFO, "geometry prompt: \"%s\" (the model's caption of normal renders)", geo_prompt);
    mlb_status st = mlb_sds_create_from_model(geometry_model, geo_prompt, c->negative_geometry, vp, &c->geometry_opt, &geo);
    free(geo_prompt);
    if (!st) st = mlb_sds_create_from_model(appearance_model, c->prompt, c->negative_appearance, vp, &c->appearance_opt, &app);
    if (st) {
        mlb_sds_free(geo);
        mlb_sds_free(app);
        return mlb_fail_context(st, "SDS guidance for \"%s\"", c->prompt);
    }
    return mlb_guidance_sds_create_from(geo, app, c, out);
}

mlb_status mlb_guidance_sds_create(const mlb_sd_model* model, const mlb_guidance_sds_config* c, mlb_guidance** out) {
    return mlb_guidance_sds_create_staged(model, model, c, out);
}
