// Measures of a fitted asset against the truth (include/matlaber/evaluate.h).
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"
#include "matlaber/evaluate.h"
#include "matlaber/geometry.h"
#include "matlaber/raster.h"
#include "matlaber/render.h"
#include "matlaber/shade.h"

// Evaluation views: azimuths all round, elevations −15°, 20°, 50° in turn (what target views show).
static const double EVAL_ELEVATIONS[3] = {-15, 20, 50};

// View v of n_views: azimuth azimuth0_deg + 360°·v/n, the elevations in turn, the project's orbit radius and widest fovy (raster.h).
static mlb_status eval_camera(mlb_camera* cam, double azimuth0_deg, int v, int n_views) {
    return mlb_camera_orbit(cam, azimuth0_deg + 360.0 * v / n_views, EVAL_ELEVATIONS[v % 3], MLB_ORBIT_RADIUS, NULL,
                            MLB_ORBIT_FOVY_MAX, 1.0, MLB_ORBIT_NEAR, MLB_ORBIT_FAR);
}

// out [res², D] = the vertex attribute attr [V, D] of mesh m seen by cam, per pixel; tri [res²] gets
// each pixel's face (−1: background). clip [V, 4], bary [res², 2], depth [res²]: scratch. Through
// table be (NULL: the CPU's); the measures read tri and out on the host, so their callers pass NULL.
static mlb_status eval_interpolate(const mlb_backend* be, float* out, const float* attr, int D, const mlb_mesh* m,
                                   const mlb_camera* cam, int res, float* clip, int32_t* tri, float* bary,
                                   float* depth) {
    if (!be) be = mlb_backend_cpu();
    mlb_transform_points(clip, m->pos, m->n_verts, &cam->view_proj);
    mlb_status s = be->rasterize(tri, bary, depth, clip, m->n_verts, m->faces, m->n_faces, res, res);
    if (!s) s = be->interpolate(out, attr, m->n_verts, D, tri, bary, m->faces, m->n_faces, res, res);
    return s;
}

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
    mlb_status s = (clip && tri && bary && depth && pos && pts && k) ? MLB_OK
                                                                     : mlb_fail(MLB_ERR_NOMEM, "albedo evaluation: out of memory");
    double se = 0;
    size_t count = 0;
    for (int v = 0; !s && v < n_views; v++) {
        mlb_camera cam;
        s = eval_camera(&cam, 0, v, n_views);
        if (!s) s = eval_interpolate(NULL, pos, fit->pos, 3, fit, &cam, res, clip, tri, bary, depth);
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
    free(clip); free(tri); free(bary); free(depth); free(pos); free(pts); free(k);
    return s;
}

mlb_status mlb_eval_normals(const mlb_mesh* truth, const mlb_mesh* fit, int n_views, int res, double* mean_deg,
                            size_t* covered) {
    if (n_views < 1 || res < 8) return mlb_fail(MLB_ERR_ARG, "normal evaluation: %d views at %d px", n_views, res);
    const mlb_mesh* meshes[2] = {truth, fit};
    size_t P = (size_t)res * res, vmax = 0;
    for (int i = 0; i < 2; i++)
        if ((size_t)meshes[i]->n_verts > vmax) vmax = (size_t)meshes[i]->n_verts;
    float* own[2] = {NULL, NULL};   // area-weighted normals of a mesh that has none
    const float* nrm[2] = {NULL, NULL};
    float* clip = malloc(sizeof(float) * 4 * vmax);
    int32_t* tri = malloc(sizeof(int32_t) * P);
    float* bary = malloc(sizeof(float) * 2 * P);
    float* depth = malloc(sizeof(float) * P);
    float* n2 = malloc(sizeof(float) * 6 * P);
    mlb_status s = (clip && tri && bary && depth && n2) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "normal evaluation: out of memory");
    for (int i = 0; !s && i < 2; i++) {
        nrm[i] = meshes[i]->normal;
        if (nrm[i]) continue;
        mlb_mesh view = *meshes[i];   // shares pos and faces; gets normals of its own
        view.normal = NULL;
        s = mlb_mesh_compute_normals(&view);
        nrm[i] = own[i] = view.normal;
    }
    double sum = 0;
    size_t count = 0;
    for (int v = 0; !s && v < n_views; v++) {
        mlb_camera cam;
        s = eval_camera(&cam, 0, v, n_views);
        // both meshes' interpolated normals; a pixel counts where both cover it (the background
        // interpolates to zero, and so may a degenerate blend: both are left out)
        for (int i = 0; !s && i < 2; i++) {
            s = eval_interpolate(NULL, n2 + 3 * P * i, nrm[i], 3, meshes[i], &cam, res, clip, tri, bary, depth);
            for (size_t p = 0; !s && p < P; p++)
                if (tri[p] < 0) memset(n2 + 3 * (P * i + p), 0, sizeof(float) * 3);
        }
        for (size_t p = 0; !s && p < P; p++) {
            const float *a = n2 + 3 * p, *b = n2 + 3 * (P + p);
            double la = (double)a[0] * a[0] + (double)a[1] * a[1] + (double)a[2] * a[2];
            double lb = (double)b[0] * b[0] + (double)b[1] * b[1] + (double)b[2] * b[2];
            if (!(la > 0) || !(lb > 0)) continue;
            double d = ((double)a[0] * b[0] + (double)a[1] * b[1] + (double)a[2] * b[2]) / sqrt(la * lb);
            sum += acos(d > 1 ? 1 : d < -1 ? -1 : d) * (180.0 / M_PI);
            count++;
        }
    }
    if (!s && count == 0) s = mlb_fail(MLB_ERR_ARG, "normal evaluation: no pixel is covered by both meshes");
    if (!s && mean_deg) *mean_deg = sum / (double)count;
    if (!s && covered) *covered = count;
    free(own[0]); free(own[1]); free(clip); free(tri); free(bary); free(depth); free(n2);
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
                            mlb_material_fn fit_material, void* fit_user, const mlb_envlight* light, int n_views, double azimuth0_deg, int res, double* psnr,
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
            rp.material = which ? fit_material : NULL;
            rp.material_user = which ? fit_user : NULL;
            rp.light = light;
            rp.background = MLB_BG_COLOR;
            rp.width = rp.height = res;
            rp.supersample = 2;
            rp.fresnel = MLB_FRESNEL_PAPER;
            s = eval_camera(&rp.camera, azimuth0_deg, v, n_views);
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
