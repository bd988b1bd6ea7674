// Shaded forward rendering: raster.h + shade.h put together (see render.h).
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/render.h"

enum { ATTR_C = 13 };   // per vertex: position 3, normal 3, BRDF 7

// World-space direction through pixel (px, py) of a perspective camera (raster.h conventions:
// row 0 at the top, centres at +0.5).
static void camera_ray(const mlb_camera* c, int W, int H, double px, double py, double d[3]) {
    double t = tan(c->fovy_deg * M_PI / 360.0);
    double x = ((2.0 * px + 1.0) / W - 1.0) * t * c->aspect;
    double y = (1.0 - (2.0 * py + 1.0) / H) * t;
    // rows 0, 1, 2 of the view rotation are the camera's right, up and back axes in world space
    const double* m = c->view.m;
    double n = 0;
    for (int i = 0; i < 3; i++) {
        d[i] = x * m[i] + y * m[4 + i] - m[8 + i];
        n += d[i] * d[i];
    }
    n = sqrt(n);
    for (int i = 0; i < 3; i++) d[i] /= n;
}

// The material field at the n covered pixels' surface points (pix rows, packed by where) into
// kd [n,3], ks [n,3], kr [n].
static mlb_status pixel_material(const mlb_render_params* p, const float* pix, const int32_t* where, int n, float* kd,
                                 float* ks, float* kr) {
    float* pos = malloc(sizeof(float) * 3 * (size_t)(n ? n : 1));
    float* k = malloc(sizeof(float) * 7 * (size_t)(n ? n : 1));
    mlb_status st = (pos && k) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "render: out of memory for %d pixels' material", n);
    for (int i = 0; !st && i < n; i++) memcpy(pos + 3 * (size_t)i, pix + ATTR_C * (size_t)where[i], sizeof(float) * 3);
    if (!st && n) st = p->material(p->material_user, pos, (size_t)n, k);
    for (int i = 0; !st && i < n; i++) {
        memcpy(kd + 3 * (size_t)i, k + 7 * (size_t)i, sizeof(float) * 3);
        memcpy(ks + 3 * (size_t)i, k + 7 * (size_t)i + 3, sizeof(float) * 3);
        kr[i] = k[7 * (size_t)i + 6];
    }
    free(pos);
    free(k);
    return st;
}

mlb_status mlb_render_shaded(const mlb_render_params* p, float* out) {
    const mlb_mesh* mesh = p->mesh;
    if (!mesh || !p->light || p->width < 1 || p->height < 1)
        return mlb_fail(MLB_ERR_ARG, "render: missing mesh or light, or size %dx%d", p->width, p->height);
    if (p->background == MLB_BG_ENV && !p->env) return mlb_fail(MLB_ERR_ARG, "render: environment background needs the map");
    int s = p->supersample > 0 ? p->supersample : 1;
    int W = p->width * s, H = p->height * s, V = mesh->n_verts, F = mesh->n_faces;
    if (W > MLB_RASTER_MAX_SIZE || H > MLB_RASTER_MAX_SIZE)
        return mlb_fail(MLB_ERR_ARG, "render: %dx%d at supersampling %d exceeds %d pixels", p->width, p->height, s,
                        MLB_RASTER_MAX_SIZE);
    size_t npix = (size_t)W * H;
    float* clip = malloc(sizeof(float) * 4 * (size_t)V);
    float* attr = malloc(sizeof(float) * ATTR_C * (size_t)V);
    float* normals = NULL;
    int32_t* tri = malloc(sizeof(int32_t) * npix);
    int32_t* adj = malloc(sizeof(int32_t) * 3 * (size_t)F);
    float* bary = malloc(sizeof(float) * 2 * npix);
    float* depth = malloc(sizeof(float) * npix);
    uint8_t* back = malloc(npix);
    float* pix = malloc(sizeof(float) * ATTR_C * npix);
    float* color = malloc(sizeof(float) * 4 * npix);
    float* aa = malloc(sizeof(float) * 4 * npix);
    // shading inputs of the covered pixels, packed
    float *kd = malloc(sizeof(float) * 3 * npix), *ks = malloc(sizeof(float) * 3 * npix);
    float *kr = malloc(sizeof(float) * npix), *nn = malloc(sizeof(float) * 3 * npix);
    float *vv = malloc(sizeof(float) * 3 * npix), *rgb = malloc(sizeof(float) * 3 * npix);
    int32_t* where = malloc(sizeof(int32_t) * npix);
    mlb_raster_ctx* ctx = mlb_raster_ctx_create();
    mlb_status st = MLB_OK;
    if (!clip || !attr || !tri || !adj || !bary || !depth || !back || !pix || !color || !aa || !kd || !ks || !kr ||
        !nn || !vv || !rgb || !where || !ctx) {
        st = mlb_fail(MLB_ERR_NOMEM, "render: out of memory for %dx%d pixels", W, H);
        goto done;
    }
    const float* vn = mesh->normal;
    if (!vn) {   // normals for a shallow copy; the caller's mesh stays as it is
        mlb_mesh tmp = *mesh;
        tmp.normal = NULL;
        if ((st = mlb_mesh_compute_normals(&tmp))) goto done;
        vn = normals = tmp.normal;
    }
    for (int i = 0; i < V; i++) {
        float* a = attr + (size_t)ATTR_C * i;
        memcpy(a, mesh->pos + 3 * (size_t)i, sizeof(float) * 3);
        memcpy(a + 3, vn + 3 * (size_t)i, sizeof(float) * 3);
        memcpy(a + 6, p->k && !p->material ? p->k + 7 * (size_t)i : p->k_const, sizeof(float) * 7);
    }
    mlb_transform_points(clip, mesh->pos, V, &p->camera.view_proj);
    if ((st = mlb_rasterize(ctx, tri, bary, depth, back, clip, V, mesh->faces, F, H, W))) goto done;
    if ((st = mlb_interpolate(pix, attr, V, ATTR_C, tri, bary, mesh->faces, F, H, W))) goto done;

    // shade every covered pixel
    int n = 0;
    for (size_t i = 0; i < npix; i++) {
        if (tri[i] < 0) continue;
        const float* a = pix + ATTR_C * i;
        double v[3], nrm[3], ln = 0, lv = 0, dot = 0;
        for (int c = 0; c < 3; c++) {
            v[c] = p->camera.eye[c] - a[c];
            nrm[c] = a[3 + c];
            lv += v[c] * v[c];
            ln += nrm[c] * nrm[c];
        }
        lv = sqrt(lv); ln = sqrt(ln);
        if (!(lv > 0) || !(ln > 0)) { nrm[0] = v[0]; nrm[1] = v[1]; nrm[2] = v[2]; ln = lv; }
        for (int c = 0; c < 3; c++) { v[c] /= lv; nrm[c] /= ln; dot += v[c] * nrm[c]; }
        double flip = dot < 0 ? -1 : 1;   // two-sided: shade the side the camera sees
        for (int c = 0; c < 3; c++) {
            vv[3 * n + c] = (float)v[c];
            nn[3 * n + c] = (float)(flip * nrm[c]);
            kd[3 * n + c] = a[6 + c];
            ks[3 * n + c] = a[9 + c];
        }
        kr[n] = a[12];
        where[n++] = (int32_t)i;
    }
    if (p->material && (st = pixel_material(p, pix, where, n, kd, ks, kr))) goto done;
    if ((st = mlb_shade_forward(rgb, kd, ks, kr, nn, vv, n, p->light, p->fresnel))) goto done;
    // background, then the shaded pixels, alpha = coverage; antialias blends across silhouettes
#pragma omp parallel for schedule(static)
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            float* o = color + 4 * ((size_t)y * W + x);
            if (p->background == MLB_BG_ENV) {
                double d[3], c[3];
                camera_ray(&p->camera, W, H, x, y, d);
                mlb_envmap_lookup(p->env, d, c);
                for (int k = 0; k < 3; k++) o[k] = (float)c[k];
            } else {
                for (int k = 0; k < 3; k++) o[k] = p->bg_color[k];
            }
            o[3] = 0;
        }
    for (int i = 0; i < n; i++) {
        float* o = color + 4 * (size_t)where[i];
        for (int c = 0; c < 3; c++) o[c] = rgb[3 * i + c];
        o[3] = 1;
    }
    if ((st = mlb_edge_topology(adj, mesh->faces, F, V))) goto done;
    if ((st = mlb_antialias(ctx, aa, NULL, color, 4, tri, depth, clip, V, mesh->faces, adj, F, H, W))) goto done;
    mlb_downsample_box(out, aa, p->height, p->width, 4, s);   // H, W here are the output size
done:
    free(clip); free(attr); free(normals); free(tri); free(adj); free(bary); free(depth); free(back); free(pix);
    free(color); free(aa); free(kd); free(ks); free(kr); free(nn); free(vv); free(rgb); free(where);
    mlb_raster_ctx_free(ctx);
    return st;
}
