// Image guidance: target images of a multi-view data set as the guidance of a step
// (include/matlaber/guidance_image.h, docs/guidance_images.md).
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/guidance_image.h"
#include "matlaber/rng.h"

enum { STREAM_GUIDANCE_IMAGES = 0x1A6E };

typedef struct {
    const mlb_views* data;
    mlb_guidance_images_config cfg;
} images_impl;

mlb_guidance_images_config mlb_guidance_images_default(void) {
    mlb_guidance_images_config c;
    memset(&c, 0, sizeof c);
    c.views_per_step = 4;
    c.seed = 1;
    c.w_mask = 1;
    c.w_normal = 1;
    c.w_rgb = 1;
    c.w_mask_appearance = 0;
    return c;
}

static mlb_status images_sample(mlb_guidance* g, mlb_stage stage, long step, mlb_view* views) {
    images_impl* im = g->impl;
    const mlb_views* d = im->data;
    int n = d->n, k = g->n_views;
    if (step < 0) return mlb_fail(MLB_ERR_ARG, "image guidance: step %ld is negative", step);
    if (stage != MLB_STAGE_GEOMETRY && stage != MLB_STAGE_APPEARANCE) return mlb_fail(MLB_ERR_ARG, "image guidance: unknown stage %d", (int)stage);
    int32_t* perm = malloc(sizeof(int32_t) * (size_t)n);
    if (!perm) return mlb_fail(MLB_ERR_NOMEM, "image guidance: out of memory");
    for (int i = 0; i < n; i++) perm[i] = i;
    if (k < n)   // partial Fisher–Yates: position i takes a uniform pick of the n − i left
        for (int i = 0; i < k; i++) {
            uint64_t index = (uint64_t)step * (uint64_t)k + (uint64_t)i;
            int j = i + (int)mlb_rng_below(im->cfg.seed, STREAM_GUIDANCE_IMAGES + (uint64_t)stage, index, (uint32_t)(n - i));
            int32_t t = perm[i]; perm[i] = perm[j]; perm[j] = t;
        }
    for (int i = 0; i < k; i++) {
        int t = perm[i];
        mlb_view* v = &views[i];
        memset(v, 0, sizeof *v);
        v->cam = d->cams[t];
        v->azimuth_deg = d->cams[t].azimuth_deg;
        v->elevation_deg = d->cams[t].elevation_deg;
        v->radius = d->cams[t].radius;
        v->env = d->meta.views[t].env;
        v->env_rotation_deg = (float)d->meta.views[t].env_rotation_deg;
        v->target = t;
    }
    free(perm);
    return MLB_OK;
}

static mlb_status images_loss(mlb_guidance* g, mlb_stage stage, long step, const mlb_view* views, int n,
                              const float* images, int H, int W, float* dimages, double* loss) {
    images_impl* im = g->impl;
    const mlb_views* d = im->data;
    if (n < 1 || !views || !images || !loss) return mlb_fail(MLB_ERR_ARG, "image guidance: %d views, or missing buffers", n);
    if (H != d->res || W != d->res)
        return mlb_fail(MLB_ERR_ARG, "image guidance: renders are %dx%d, the targets %dx%d (load the views at the render size)", W, H,
                        d->res, d->res);
    double wc, wm;
    const float* targets;
    if (stage == MLB_STAGE_GEOMETRY) {
        // without normal maps, the mask channel of the colour images is the only target
        wc = d->has_normals ? im->cfg.w_normal : 0;
        wm = im->cfg.w_mask;
        targets = d->has_normals ? d->normals : d->images;
    } else if (stage == MLB_STAGE_APPEARANCE) {
        wc = im->cfg.w_rgb;
        wm = im->cfg.w_mask_appearance;
        targets = d->images;
    } else {
        return mlb_fail(MLB_ERR_ARG, "image guidance: unknown stage %d", (int)stage);
    }
    for (int v = 0; v < n; v++)
        if (views[v].target < 0 || views[v].target >= d->n)
            return mlb_fail(MLB_ERR_ARG, "image guidance: view %d has target %d (the data set has %d)", v, views[v].target, d->n);
    size_t P = (size_t)H * W;
    // a part of a step (guidance.h) is normalised by the whole step's views
    int n_step = g->part_total > 0 ? g->part_total : n;
    double norm = 1.0 / ((double)n_step * (double)P), total = 0;
    double* rows = malloc(sizeof(double) * (size_t)H);   // per-row sums, added in order: thread-count independent
    if (!rows) return mlb_fail(MLB_ERR_NOMEM, "image guidance: out of memory");
    for (int v = 0; v < n; v++) {
        const float* ov = images + 4 * P * (size_t)v;
        const float* tv = targets + 4 * P * (size_t)views[v].target;
        float* dv = dimages ? dimages + 4 * P * (size_t)v : NULL;
#pragma omp parallel for schedule(static) if (P >= 16384)
        for (int y = 0; y < H; y++) {
            double sum = 0;
            for (size_t p = (size_t)y * W; p < (size_t)(y + 1) * W; p++) {
                const float *o = ov + 4 * p, *t = tv + 4 * p;
                double e0 = (double)o[0] - t[0], e1 = (double)o[1] - t[1], e2 = (double)o[2] - t[2], e3 = (double)o[3] - t[3];
                sum += wc * (e0 * e0 + e1 * e1 + e2 * e2) + wm * e3 * e3;
                if (dv) {
                    float* dd = dv + 4 * p;
                    dd[0] += (float)(2 * wc * norm * e0);
                    dd[1] += (float)(2 * wc * norm * e1);
                    dd[2] += (float)(2 * wc * norm * e2);
                    dd[3] += (float)(2 * wm * norm * e3);
                }
            }
            rows[y] = sum;
        }
        for (int y = 0; y < H; y++) total += rows[y];
    }
    free(rows);
    *loss = total * norm;
    if (!isfinite(*loss)) return mlb_fail(MLB_ERR_NUMERIC, "image guidance: the loss is not finite (step %ld)", step);
    return MLB_OK;
}

static void images_destroy(mlb_guidance* g) {
    if (!g) return;
    free(g->impl);
    free(g);
}

mlb_status mlb_guidance_images_create(const mlb_views* data, const mlb_guidance_images_config* c, mlb_guidance** out) {
    *out = NULL;
    if (!data || data->n < 1 || !data->images || !data->cams)
        return mlb_fail(MLB_ERR_ARG, "image guidance: no data set (load one with mlb_views_load)");
    mlb_guidance_images_config cfg = c ? *c : mlb_guidance_images_default();
    if (cfg.views_per_step < 1)
        return mlb_fail(MLB_ERR_ARG, "image guidance: views per step %d must be >= 1", cfg.views_per_step);
    if (!(cfg.w_mask >= 0) || !(cfg.w_normal >= 0) || !(cfg.w_rgb >= 0) || !(cfg.w_mask_appearance >= 0) || !isfinite(cfg.w_mask) ||
        !isfinite(cfg.w_normal) || !isfinite(cfg.w_rgb) || !isfinite(cfg.w_mask_appearance))
        return mlb_fail(MLB_ERR_ARG, "image guidance: weights must be finite and >= 0");
    mlb_guidance* g = calloc(1, sizeof *g);
    images_impl* im = calloc(1, sizeof *im);
    if (!g || !im) { free(g); free(im); return mlb_fail(MLB_ERR_NOMEM, "image guidance: out of memory"); }
    im->data = data;
    im->cfg = cfg;
    g->kind = "images";
    g->n_views = cfg.views_per_step < data->n ? cfg.views_per_step : data->n;
    g->sample_views = images_sample;
    g->loss = images_loss;
    g->destroy = images_destroy;
    g->impl = im;
    *out = g;
    return MLB_OK;
}
