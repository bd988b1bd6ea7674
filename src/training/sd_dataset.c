// The training set of the project's own diffusion model: catalogue renders in the three forms the
// pipeline hands the guidance (include/matlaber/sd_train.h).
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/catalogue.h"
#include "matlaber/guidance_sds.h"
#include "matlaber/progress.h"
#include "matlaber/sd_train.h"
#include "matlaber/sds.h"

int mlb_sd_caption_count(void) { return 2 * mlb_catalogue_n_classes() * mlb_catalogue_n_materials() * MLB_SDS_N_VIEWS; }

int mlb_sd_caption_index(int cls, int mat, int view, int geometry) {
    int pairs = mlb_catalogue_n_classes() * mlb_catalogue_n_materials();
    return ((geometry ? pairs : 0) + cls * mlb_catalogue_n_materials() + mat) * MLB_SDS_N_VIEWS + view;
}

void mlb_sd_caption_text(int row, char* out, size_t cap) {
    int pairs = mlb_catalogue_n_classes() * mlb_catalogue_n_materials(), view = row % MLB_SDS_N_VIEWS;
    int cm = row / MLB_SDS_N_VIEWS, geometry = cm >= pairs;
    cm %= pairs;
    char base[200];
    mlb_catalogue_caption(cm / mlb_catalogue_n_materials(), cm % mlb_catalogue_n_materials(), MLB_SDS_VIEW_NONE, base, sizeof base);
    snprintf(out, cap, "%s%s%s", base, geometry ? MLB_SD_GEOMETRY_SUFFIX : "", mlb_sds_view_suffix(view));
}

void mlb_sd_dataset_free(mlb_sd_dataset* d) {
    if (!d) return;
    free(d->rgb);
    free(d->geo);
    free(d->lat_geo);
    free(d->cls);
    free(d->mat);
    free(d->view);
    memset(d, 0, sizeof *d);
}

static uint8_t to_byte(float v) {
    v = v < 0 ? 0 : v > 1 ? 1 : v;
    return (uint8_t)lrintf(v * 255.0f);
}

mlb_status mlb_sd_dataset_render(mlb_sd_dataset* d, int n, int res, uint64_t seed, mlb_progress* progress) {
    memset(d, 0, sizeof *d);
    if (n < 1 || res < 8 || res % 8 || res > 1024)
        return mlb_fail(MLB_ERR_ARG, "training set: %d samples at %dx%d (res a multiple of 8, 8..1024)", n, res, res);
    int lat = res / 8;
    size_t P = (size_t)res * res;
    d->n = n;
    d->res = res;
    d->lat = lat;
    d->rgb = malloc((size_t)n * 3 * P);
    d->geo = malloc((size_t)n * 3 * P);
    d->lat_geo = malloc((size_t)n * 4 * lat * lat * sizeof(float));
    d->cls = malloc((size_t)n * sizeof(int));
    d->mat = malloc((size_t)n * sizeof(int));
    d->view = malloc((size_t)n * sizeof(int));
    if (!d->rgb || !d->geo || !d->lat_geo || !d->cls || !d->mat || !d->view) {
        mlb_sd_dataset_free(d);
        return mlb_fail(MLB_ERR_NOMEM, "training set: out of memory for %d samples at %dx%d", n, res, res);
    }
    mlb_catalogue_render_config rc = mlb_catalogue_render_default();
    rc.res = res;
    mlb_status status = MLB_OK;
    long done = 0;
    // one renderer per thread (each pre-integrates the lights once); samples are independent
#pragma omp parallel
    {
        mlb_catalogue_renderer* r = NULL;
        float* rgb = malloc(3 * P * sizeof(float));
        float* nrm = malloc(4 * P * sizeof(float));
        mlb_status s = rgb && nrm ? mlb_catalogue_renderer_create(&r, &rc) : mlb_fail(MLB_ERR_NOMEM, "training set: out of memory");
#pragma omp for schedule(dynamic, 4)
        for (int i = 0; i < n; i++) {
            if (s) continue;
            mlb_catalogue_sample smp;
            s = mlb_catalogue_sample_draw(&smp, seed, (uint64_t)i, mlb_catalogue_renderer_n_envs(r), 0);
            if (!s) s = mlb_catalogue_render(r, &smp, rgb, nrm);
            if (s) continue;
            uint8_t* drgb = d->rgb + (size_t)i * 3 * P;
            uint8_t* dgeo = d->geo + (size_t)i * 3 * P;
            for (size_t k = 0; k < 3 * P; k++) drgb[k] = to_byte(rgb[k]);
            for (size_t p = 0; p < P; p++)
                for (int c = 0; c < 3; c++) dgeo[c * P + p] = to_byte(0.5f * (nrm[p * 4 + c] + nrm[p * 4 + 3]));
            mlb_area_resize_nhwc_to_nchw(d->lat_geo + (size_t)i * 4 * lat * lat, nrm, 1, res, res, 4, lat, lat);
            d->cls[i] = smp.cls;
            d->mat[i] = smp.mat;
            d->view[i] = mlb_sds_view_for(smp.view.azimuth_deg, smp.view.elevation_deg);
#pragma omp atomic
            done++;
            if (progress && (done % 64 == 0)) {
#pragma omp critical(sd_dataset_progress)
                mlb_progress_update(progress, done, NULL);
            }
        }
#pragma omp critical(sd_dataset_status)
        if (s && !status) status = s;
        mlb_catalogue_renderer_free(r);
        free(rgb);
        free(nrm);
    }
    if (status) {
        mlb_sd_dataset_free(d);
        return mlb_fail_context(status, "rendering the training set");
    }
    if (progress) mlb_progress_update(progress, n, NULL);
    return MLB_OK;
}
