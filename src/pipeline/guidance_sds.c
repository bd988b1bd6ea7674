// Score-distillation guidance (include/matlaber/guidance_sds.h, docs/guidance.md): orbit cameras,
// the conversions of the [n, H, W, 4] renders to what Stable Diffusion sees, and back.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/guidance_sds.h"
#include "matlaber/log.h"

typedef struct {
    mlb_sds* geo;                 // geometry: negative_geometry, geometry_opt
    mlb_sds* app;                 // appearance: negative_appearance, appearance_opt
    mlb_guidance_sds_config c;    // (string fields not kept)
    float* x;                     // [n, C, h, w] the converted images
    float* dx;                    // [n, C, h, w] their gradient
    size_t cap;                   // floats in x and dx
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

// ---- area resize ---------------------------------------------------------------------------------
void mlb_area_resize_nhwc_to_nchw(float* dst, const float* src, int n, int H, int W, int C, int h, int w) {
    for (int b = 0; b < n; b++)
        for (int y = 0; y < h; y++) {
            int y0 = (int)((long)y * H / h), y1 = (int)(((long)(y + 1) * H + h - 1) / h);
            for (int x = 0; x < w; x++) {
                int x0 = (int)((long)x * W / w), x1 = (int)(((long)(x + 1) * W + w - 1) / w);
                double inv = 1.0 / ((double)(y1 - y0) * (x1 - x0));
                for (int c = 0; c < C; c++) {
                    double s = 0;
                    for (int yy = y0; yy < y1; yy++)
                        for (int xx = x0; xx < x1; xx++) s += src[(((size_t)b * H + yy) * W + xx) * C + c];
                    dst[(((size_t)b * C + c) * h + y) * w + x] = (float)(s * inv);
                }
            }
        }
}

void mlb_area_resize_nhwc_to_nchw_backward(float* dsrc, const float* ddst, int n, int H, int W, int C, int h, int w) {
    for (int b = 0; b < n; b++)
        for (int y = 0; y < h; y++) {
            int y0 = (int)((long)y * H / h), y1 = (int)(((long)(y + 1) * H + h - 1) / h);
            for (int x = 0; x < w; x++) {
                int x0 = (int)((long)x * W / w), x1 = (int)(((long)(x + 1) * W + w - 1) / w);
                double inv = 1.0 / ((double)(y1 - y0) * (x1 - x0));
                for (int c = 0; c < C; c++) {
                    float g = (float)(ddst[(((size_t)b * C + c) * h + y) * w + x] * inv);
                    for (int yy = y0; yy < y1; yy++)
                        for (int xx = x0; xx < x1; xx++) dsrc[(((size_t)b * H + yy) * W + xx) * C + c] += g;
                }
            }
        }
}

// ---- the interface -------------------------------------------------------------------------------
static mlb_status sds_sample_views(mlb_guidance* g, mlb_stage stage, long step, mlb_view* views) {
    sds_guidance* s = g->impl;
    for (int v = 0; v < g->n_views; v++) MLB_TRY(mlb_orbit_sample(&views[v], &s->c.orbit, s->c.seed, (int)stage, step, v));
    return MLB_OK;
}

// images [n, H, W, 4] of `stage` at `step` → s->x [n, *C, *h, *w], what the model sees: [normal,
// mask] resized to latents in the latent phase, 0.5 (normal + mask) (geometry) or the colour
// (appearance) otherwise; vids[n] the views' prompts. Grows s->x and s->dx as needed.
static mlb_status to_model_input(sds_guidance* s, mlb_stage stage, long step, const mlb_view* views, int n,
                                 const float* images, int H, int W, int* vids, int* Cp, int* hp, int* wp) {
    if (!images || !views || n < 1 || n > MLB_SDS_MAX_BATCH || H < 1 || W < 1)
        return mlb_fail(MLB_ERR_ARG, "SDS guidance: bad batch (%d views of %dx%d)", n, W, H);
    if (stage != MLB_STAGE_GEOMETRY && stage != MLB_STAGE_APPEARANCE) return mlb_fail(MLB_ERR_ARG, "SDS guidance: stage %d", (int)stage);
    int latent = stage == MLB_STAGE_GEOMETRY && step < s->c.latent_iters;
    const int L = s->c.latent_size > 0 ? s->c.latent_size : MLB_GUIDANCE_LATENT_SIZE;
    int C = latent ? 4 : 3, h = latent ? L : H, w = latent ? L : W;
    size_t P = (size_t)h * w, N = (size_t)n * C * P, HW = (size_t)H * W;
    if (N > s->cap) {
        free(s->x);
        free(s->dx);
        s->x = malloc(N * sizeof(float));
        s->dx = malloc(N * sizeof(float));
        s->cap = s->x && s->dx ? N : 0;
        if (!s->cap) return mlb_fail(MLB_ERR_NOMEM, "SDS guidance: out of memory (%d views of %dx%d)", n, W, H);
    }
    for (int b = 0; b < n; b++)
        vids[b] = s->c.view_prompts ? mlb_sds_view_for(views[b].azimuth_deg, views[b].elevation_deg) : MLB_SDS_VIEW_NONE;
    if (latent) mlb_area_resize_nhwc_to_nchw(s->x, images, n, H, W, 4, L, L);
    else
        for (int b = 0; b < n; b++)
            for (size_t i = 0; i < HW; i++) {
                const float* px = images + ((size_t)b * HW + i) * 4;
                for (int c = 0; c < 3; c++)
                    s->x[((size_t)b * 3 + c) * HW + i] = stage == MLB_STAGE_GEOMETRY ? 0.5f * (px[c] + px[3]) : px[c];
            }
    *Cp = C;
    *hp = h;
    *wp = w;
    return MLB_OK;
}

static mlb_status sds_loss(mlb_guidance* g, mlb_stage stage, long step, const mlb_view* views, int n, const float* images,
                           int H, int W, float* dimages, double* loss) {
    sds_guidance* s = g->impl;
    int vids[MLB_SDS_MAX_BATCH], C, h, w;
    MLB_TRY(to_model_input(s, stage, step, views, n, images, H, W, vids, &C, &h, &w));
    int latent = C == 4;
    const int L = h;
    size_t N = (size_t)n * C * h * w, HW = (size_t)H * W;
    mlb_sds* sds = stage == MLB_STAGE_GEOMETRY ? s->geo : s->app;
    mlb_sds_options* opt = mlb_sds_options_of(sds);
    mlb_sds_weighting keep = opt->weighting;
    if (latent) opt->weighting = MLB_SDS_W_DREAMFUSION;   // Fantasia3D's latent phase
    if (dimages) memset(s->dx, 0, N * sizeof(float));
    mlb_sds_input in = {s->x, n, C, h, w, vids, step, NULL, NULL, g->part_first, g->part_total};
    float l = 0;
    mlb_status st = mlb_sds_step(sds, &in, dimages ? s->dx : NULL, &l, NULL);
    opt->weighting = keep;
    if (st) return mlb_fail_context(st, "SDS guidance (%s stage, step %ld)", stage == MLB_STAGE_GEOMETRY ? "geometry" : "appearance", step);
    if (loss) *loss = (double)l;
    if (!dimages) return MLB_OK;
    // dx [n, C, h, w] → dimages [n, H, W, 4] (+=)
    if (latent) mlb_area_resize_nhwc_to_nchw_backward(dimages, s->dx, n, H, W, 4, L, L);
    else
        for (int b = 0; b < n; b++)
            for (size_t i = 0; i < HW; i++) {
                float* d = dimages + ((size_t)b * HW + i) * 4;
                for (int c = 0; c < 3; c++) {
                    float gx = s->dx[((size_t)b * 3 + c) * HW + i];
                    if (stage == MLB_STAGE_GEOMETRY) { d[c] += 0.5f * gx; d[3] += 0.5f * gx; }
                    else d[c] += gx;
                }
            }
    return MLB_OK;
}

// The diffusion classifier's score (guidance.h): SCORE_DRAWS timesteps per view, spread evenly over
// the stage's range, noise from a step number no run reaches, so every call draws the same.
#define SCORE_DRAWS 4
#define SCORE_STEP (1L << 40)
static mlb_status sds_score(mlb_guidance* g, mlb_stage stage, const mlb_view* views, int n, const float* images, int H,
                            int W, double* per_view) {
    sds_guidance* s = g->impl;
    int vids[MLB_SDS_MAX_BATCH], C, h, w, lc, lh, lw, t[MLB_SDS_MAX_BATCH];
    MLB_TRY(to_model_input(s, stage, 0, views, n, images, H, W, vids, &C, &h, &w));
    mlb_sds* sds = stage == MLB_STAGE_GEOMETRY ? s->geo : s->app;
    const mlb_sds_options* opt = stage == MLB_STAGE_GEOMETRY ? &s->c.geometry_opt : &s->c.appearance_opt;
    MLB_TRY(mlb_sds_latent_shape(sds, C, h, w, &lc, &lh, &lw));
    // the renders are encoded once (the first draw's latents), the later draws take those latents
    // as they are: the same bits as encoding every time
    float* z = malloc(sizeof(float) * (size_t)lc * n * lh * lw);
    if (!z) return mlb_fail(MLB_ERR_NOMEM, "SDS guidance: out of memory scoring %d renders", n);
    double ec[MLB_SDS_MAX_BATCH], eu[MLB_SDS_MAX_BATCH];
    for (int b = 0; b < n; b++) per_view[b] = 0;
    mlb_status st = MLB_OK;
    for (int j = 0; !st && j < SCORE_DRAWS; j++) {
        for (int b = 0; b < n; b++) t[b] = opt->t_min + (int)((opt->t_max - opt->t_min) * (j + 0.5) / SCORE_DRAWS);
        mlb_sds_input in = {j ? z : s->x, n, j ? lc : C, j ? lh : h, j ? lw : w, vids, SCORE_STEP + j, t, NULL, 0, 0};
        mlb_sds_trace tr = {0};
        tr.latent = j ? NULL : z;
        tr.err_cond = ec;
        tr.err_uncond = eu;
        st = mlb_sds_step(sds, &in, NULL, NULL, &tr);
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
        free(s->x);
        free(s->dx);
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
        const mlb_sds_options* q = o2[k];
        if (q->t_min < 0 || q->t_max > 999 || q->t_min > q->t_max || !isfinite(q->guidance_scale) ||
            (unsigned)q->weighting > MLB_SDS_W_FANTASIA2)
            return mlb_fail(MLB_ERR_ARG, "SDS guidance: %s options: t range [%d, %d] (within 0..999), scale %g, weighting %d",
                            k ? "appearance" : "geometry", q->t_min, q->t_max, (double)q->guidance_scale, (int)q->weighting);
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
    g->score = sds_score;
    g->destroy = sds_destroy;
    g->impl = s;
    *out = g;
    return MLB_OK;
}

mlb_status mlb_guidance_sds_create(const mlb_sd_model* model, const mlb_guidance_sds_config* c, mlb_guidance** out) {
    if (out) *out = NULL;
    if (!model || !c || !out) return mlb_fail(MLB_ERR_ARG, "mlb_guidance_sds_create: NULL argument");
    if (!c->prompt || !c->prompt[0]) return mlb_fail(MLB_ERR_ARG, "SDS guidance: no prompt");
    MLB_TRY(check_config(c));
    mlb_sds *geo = NULL, *app = NULL;
    int vp = c->view_prompts != 0;
    // the geometry stage's normal renders get the model's caption for them (sd_model.h geometry_suffix)
    char* geo_prompt = malloc(strlen(c->prompt) + MLB_SD_SUFFIX_MAX);
    if (!geo_prompt) return mlb_fail(MLB_ERR_NOMEM, "SDS guidance: out of memory");
    sprintf(geo_prompt, "%s%s", c->prompt, model->geometry_suffix);
    if (model->geometry_suffix[0]) mlb_log(MLB_LOG_INFO, "geometry prompt: \"%s\" (the model's caption of normal renders)", geo_prompt);
    mlb_status st = mlb_sds_create_from_model(model, geo_prompt, c->negative_geometry, vp, &c->geometry_opt, &geo);
    free(geo_prompt);
    if (!st) st = mlb_sds_create_from_model(model, c->prompt, c->negative_appearance, vp, &c->appearance_opt, &app);
    if (st) {
        mlb_sds_free(geo);
        mlb_sds_free(app);
        return mlb_fail_context(st, "SDS guidance for \"%s\"", c->prompt);
    }
    return mlb_guidance_sds_create_from(geo, app, c, out);
}
