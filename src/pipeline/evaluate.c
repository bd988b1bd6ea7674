// Measures of a fitted asset against the truth (include/matlaber/evaluate.h).
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/evaluate.h"
#include "matlaber/geometry.h"
#include "matlaber/raster.h"
#include "matlaber/render.h"
#include "matlaber/shade.h"

// Evaluation views: azimuths all round, elevations −15°, 20°, 50° in turn (what target views show).
static const double EVAL_ELEVATIONS[3] = {-15, 20, 50};

double mlb_psnr(const float* a, const float* b, size_t n) {
    double se = 0;
    for (size_t i = 0; i < n; i++) {
        double d = (double)a[i] - (double)b[i];
        se += d * d;
    }
    double mse = n ? se / (double)n : 0;
    return mse > 0 ? 10.0 * log10(1.0 / mse) : INFINITY;
}

mlb_status mlb_eval_albedo(const mlb_mesh* fit, const mlb_material_net* net, mlb_brdf_truth_fn truth, int n_views,
                           int res, double* psnr, double* rmse) {
    if (n_views < 1 || res < 8) return mlb_fail(MLB_ERR_ARG, "albedo evaluation: %d views at %d px", n_views, res);
    size_t P = (size_t)res * res, V = (size_t)fit->n_verts;
    float* clip = malloc(sizeof(float) * 4 * V);
    int32_t* tri = malloc(sizeof(int32_t) * P);
    float* bary = malloc(sizeof(float) * 2 * P);
    float* depth = malloc(sizeof(float) * P);
    float* pos = malloc(sizeof(float) * 3 * P);
    float* pts = malloc(sizeof(float) * 3 * P);
    float* k = malloc(sizeof(float) * 7 * P);
    mlb_raster_ctx* ctx = mlb_raster_ctx_create();
    mlb_status s = (clip && tri && bary && depth && pos && pts && k && ctx) ? MLB_OK
                                                                            : mlb_fail(MLB_ERR_NOMEM, "albedo evaluation: out of memory");
    double se = 0;
    size_t count = 0;
    for (int v = 0; !s && v < n_views; v++) {
        mlb_camera cam;
        s = mlb_camera_orbit(&cam, 360.0 * v / n_views, EVAL_ELEVATIONS[v % 3], 3.0, NULL, 45.0, 1.0, 0.1, 100.0);
        if (s) break;
        mlb_transform_points(clip, fit->pos, fit->n_verts, &cam.view_proj);
        s = mlb_rasterize(ctx, tri, bary, depth, NULL, clip, fit->n_verts, fit->faces, fit->n_faces, res, res);
        if (!s) s = mlb_interpolate(pos, fit->pos, fit->n_verts, 3, tri, bary, fit->faces, fit->n_faces, res, res);
        if (s) break;
        size_t m = 0;
        for (size_t p = 0; p < P; p++)
            if (tri[p] >= 0) memcpy(pts + 3 * m++, pos + 3 * p, sizeof(float) * 3);
        if (m == 0) continue;
        s = mlb_material_eval(net, pts, m, k);
        for (size_t i = 0; !s && i < m; i++) {
            float t[7];
            truth(pts + 3 * i, t);
            for (int c = 0; c < 3; c++) {
                double d = (double)k[7 * i + c] - t[c];
                se += d * d;
            }
        }
        count += 3 * m;
    }
    if (!s && count == 0) s = mlb_fail(MLB_ERR_ARG, "albedo evaluation: the mesh covers no pixel");
    if (!s) {
        double mse = se / (double)count;
        if (psnr) *psnr = mse > 0 ? 10.0 * log10(1.0 / mse) : INFINITY;
        if (rmse) *rmse = sqrt(mse);
    }
    mlb_raster_ctx_free(ctx);
    free(clip); free(tri); free(bary); free(depth); free(pos); free(pts); free(k);
    return s;
}

static void to_srgb_rgb(float* rgb, const float* rgba, size_t pixels) {
    for (size_t i = 0; i < pixels; i++) {
        for (int c = 0; c < 3; c++) {
            // premultiplied linear colour over black: encode, clamp
            rgb[3 * i + c] = mlb_srgb_encode(rgba[4 * i + c]);
        }
    }
}

mlb_status mlb_eval_relight(const mlb_mesh* truth, const float* truth_k, const mlb_mesh* fit, const float* fit_k,
                            const mlb_envlight* light, int n_views, double azimuth0_deg, int res, double* psnr,
                            float* images) {
    if (n_views < 1 || res < 8) return mlb_fail(MLB_ERR_ARG, "relight evaluation: %d views at %d px", n_views, res);
    size_t p = (size_t)res * res;
    float* rgba = malloc(sizeof(float) * p * 4);
    float* rgb = malloc(sizeof(float) * p * 3 * 2 * (size_t)n_views);
    mlb_status s = (rgba && rgb) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "relight evaluation: out of memory");
    for (int which = 0; !s && which < 2; which++) {
        for (int v = 0; !s && v < n_views; v++) {
            mlb_render_params rp;
            memset(&rp, 0, sizeof rp);
            rp.mesh = which ? fit : truth;
            rp.k = which ? fit_k : truth_k;
            rp.light = light;
            rp.background = MLB_BG_COLOR;
            rp.width = rp.height = res;
            rp.supersample = 2;
            rp.fresnel = MLB_FRESNEL_PAPER;
            s = mlb_camera_orbit(&rp.camera, azimuth0_deg + 360.0 * v / n_views, EVAL_ELEVATIONS[v % 3], 3.0, NULL, 45.0,
                                 1.0, 0.1, 100.0);
            if (!s) s = mlb_render_shaded(&rp, rgba);
            if (!s) to_srgb_rgb(rgb + p * 3 * ((size_t)which * n_views + v), rgba, p);
        }
    }
    if (!s && psnr) *psnr = mlb_psnr(rgb, rgb + p * 3 * (size_t)n_views, p * 3 * (size_t)n_views);
    if (!s && images) memcpy(images, rgb, sizeof(float) * p * 3 * 2 * (size_t)n_views);
    free(rgba);
    free(rgb);
    return s;
}
