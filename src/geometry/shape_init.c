// Shapes for the SDF initialisation (reference.md §3, docs/geometry_init.md): analytic ellipsoid and
// capped cylinder, a user mesh's signed distance (unsigned distance to the triangles, sign from the
// generalised winding number), surface/jittered/uniform sampling, and the 400-step MSE fit.
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/geometry.h"
#include "matlaber/rng.h"

enum { STREAM_SURFACE = 0x5A01, STREAM_JITTER_SURF = 0x5A02, STREAM_JITTER = 0x5A03, STREAM_UNIFORM = 0x5A04,
       STREAM_BATCH = 0x5A05 };

// ---- shapes ----------------------------------------------------------------------------------

void mlb_shape_ellipsoid(mlb_shape* s, float scale, const float* axes) {
    memset(s, 0, sizeof *s);
    s->kind = MLB_SHAPE_ELLIPSOID;
    for (int k = 0; k < 3; k++) s->radii[k] = scale * (axes ? axes[k] : 1.0f);
}

void mlb_shape_cylinder(mlb_shape* s, float scale) {
    memset(s, 0, sizeof *s);
    s->kind = MLB_SHAPE_CYLINDER;
    s->cyl_radius = 0.75f * scale;
    s->cyl_height = 0.8f * scale;
}

void mlb_shape_torus(mlb_shape* s, float scale) {
    memset(s, 0, sizeof *s);
    s->kind = MLB_SHAPE_TORUS;
    s->torus_major = 0.6f * scale * (0.8f / 0.9f);
    s->torus_minor = 0.3f * scale * (0.8f / 0.9f);
}

void mlb_shape_slab(mlb_shape* s, float scale) {
    memset(s, 0, sizeof *s);
    s->kind = MLB_SHAPE_BOX;
    const float half[3] = {0.9f, 0.075f, 0.55f}, center_y = 0.325f, reach_y = 0.4f;
    float k = 0.8f * scale / sqrtf(half[0] * half[0] + reach_y * reach_y + half[2] * half[2]);
    for (int i = 0; i < 3; i++) s->box_half[i] = half[i] * k;
    s->box_center[1] = center_y * k;
}

void mlb_shape_cup(mlb_shape* s, float scale) {
    memset(s, 0, sizeof *s);
    s->kind = MLB_SHAPE_CUP;
    float k = 0.8f * scale / sqrtf(0.7f * 0.7f + 0.4f * 0.4f);   // the rim's outer corner (0.7, 0.4) at 0.8
    s->cup_radius = 0.6f * k;
    s->cup_wall = 0.1f * k;
    s->cup_center_y = 0.3f * k;
}

int mlb_shape_builtin(mlb_shape* s, const char* name, float scale) {
    if (!strcmp(name, "ellipsoid")) mlb_shape_ellipsoid(s, scale, NULL);
    else if (!strcmp(name, "cylinder")) mlb_shape_cylinder(s, scale);
    else if (!strcmp(name, "torus")) mlb_shape_torus(s, scale);
    else if (!strcmp(name, "slab")) mlb_shape_slab(s, scale);
    else if (!strcmp(name, "cup")) mlb_shape_cup(s, scale);
    else return 0;
    return 1;
}

static double tri_area(const float* a, const float* b, const float* c) {
    double u[3], v[3];
    for (int k = 0; k < 3; k++) { u[k] = (double)b[k] - a[k]; v[k] = (double)c[k] - a[k]; }
    double x = u[1] * v[2] - u[2] * v[1], y = u[2] * v[0] - u[0] * v[2], z = u[0] * v[1] - u[1] * v[0];
    return 0.5 * sqrt(x * x + y * y + z * z);
}

mlb_status mlb_shape_from_mesh(mlb_shape* s, const mlb_mesh* m, float scale) {
    memset(s, 0, sizeof *s);
    if (!m || m->n_verts < 3 || m->n_faces < 1) return mlb_fail(MLB_ERR_ARG, "shape mesh: empty mesh");
    s->kind = MLB_SHAPE_MESH;
    s->mesh.n_verts = m->n_verts;
    s->mesh.n_faces = m->n_faces;
    s->mesh.pos = malloc(sizeof(float) * 3 * (size_t)m->n_verts);
    s->mesh.faces = malloc(sizeof(int32_t) * 3 * (size_t)m->n_faces);
    if (!s->mesh.pos || !s->mesh.faces) { mlb_shape_free(s); return mlb_fail(MLB_ERR_NOMEM, "shape mesh: out of memory"); }
    memcpy(s->mesh.pos, m->pos, sizeof(float) * 3 * (size_t)m->n_verts);
    memcpy(s->mesh.faces, m->faces, sizeof(int32_t) * 3 * (size_t)m->n_faces);
    mlb_mesh_normalize_unit_sphere(&s->mesh);
    for (size_t i = 0; i < 3 * (size_t)m->n_verts; i++) s->mesh.pos[i] *= scale;
    for (int f = 0; f < m->n_faces; f++) {
        const int32_t* t = s->mesh.faces + 3 * f;
        s->mesh_area += tri_area(s->mesh.pos + 3 * t[0], s->mesh.pos + 3 * t[1], s->mesh.pos + 3 * t[2]);
    }
    if (!(s->mesh_area > 0)) { mlb_shape_free(s); return mlb_fail(MLB_ERR_ARG, "shape mesh: zero surface area"); }
    return MLB_OK;
}

void mlb_shape_free(mlb_shape* s) {
    if (!s) return;
    mlb_mesh_free(&s->mesh);
    memset(s, 0, sizeof *s);
}

// ---- winding number ------------------------------------------------------------------------

static double dot3(const double* a, const double* b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

void mlb_mesh_winding_number(const mlb_mesh* m, const float* p, double* out, int n) {
#pragma omp parallel for schedule(dynamic, 64)
    for (int i = 0; i < n; i++) {
        double sum = 0;
        for (int f = 0; f < m->n_faces; f++) {
            const int32_t* t = m->faces + 3 * f;
            double a[3], b[3], c[3];
            for (int k = 0; k < 3; k++) {
                a[k] = (double)m->pos[3 * t[0] + k] - p[3 * i + k];
                b[k] = (double)m->pos[3 * t[1] + k] - p[3 * i + k];
                c[k] = (double)m->pos[3 * t[2] + k] - p[3 * i + k];
            }
            double la = sqrt(dot3(a, a)), lb = sqrt(dot3(b, b)), lc = sqrt(dot3(c, c));
            double det = a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) + a[2] * (b[0] * c[1] - b[1] * c[0]);
            double den = la * lb * lc + dot3(a, b) * lc + dot3(b, c) * la + dot3(c, a) * lb;
            sum += 2.0 * atan2(det, den);   // signed solid angle (Van Oosterom & Strackee 1983)
        }
        out[i] = sum / (4.0 * M_PI);
    }
}

// ---- signed distance ---------------------------------------------------------------------------

void mlb_shape_sdf(const mlb_shape* s, const float* p, float* out, int n) {
    if (s->kind == MLB_SHAPE_MESH) {
        mlb_mesh_distance(&s->mesh, p, out, n);
        double* w = malloc(sizeof(double) * (size_t)n);
        if (!w) return;   // distances stay unsigned; only on allocation failure
        mlb_mesh_winding_number(&s->mesh, p, w, n);
        for (int i = 0; i < n; i++) if (w[i] > 0.5) out[i] = -out[i];
        free(w);
        return;
    }
#pragma omp parallel for schedule(static)
    for (int i = 0; i < n; i++) {
        const float* q = p + 3 * i;
        if (s->kind == MLB_SHAPE_ELLIPSOID) {
            // k0 = |q/r|, k1 = |q/r²|: sdf ≈ k0 (k0 − 1) / k1 (first order in the distance)
            double k0 = 0, k1 = 0;
            for (int k = 0; k < 3; k++) {
                double a = q[k] / (double)s->radii[k];
                k0 += a * a;
                k1 += (a / s->radii[k]) * (a / s->radii[k]);
            }
            k0 = sqrt(k0);
            k1 = sqrt(k1);
            out[i] = k1 > 0 ? (float)(k0 * (k0 - 1.0) / k1) : -fminf(s->radii[0], fminf(s->radii[1], s->radii[2]));
        } else if (s->kind == MLB_SHAPE_TORUS) {
            double dq = sqrt((double)q[0] * q[0] + (double)q[1] * q[1]) - s->torus_major;
            out[i] = (float)(sqrt(dq * dq + (double)q[2] * q[2]) - s->torus_minor);
        } else if (s->kind == MLB_SHAPE_BOX) {
            // exact: the distance to the box outside, the (negative) largest face distance inside
            double d[3], out2 = 0, inside = -INFINITY;
            for (int k = 0; k < 3; k++) {
                d[k] = fabs((double)q[k] - s->box_center[k]) - s->box_half[k];
                out2 += d[k] > 0 ? d[k] * d[k] : 0;
                inside = fmax(inside, d[k]);
            }
            out[i] = (float)(sqrt(out2) + fmin(inside, 0.0));
        } else if (s->kind == MLB_SHAPE_CUP) {
            // exact: in the (radial, height) half-plane about the sphere's centre, above the rim's
            // plane the distance to the rim circle (r, 0), below it to the sphere of radius r, less
            // the wall's half-thickness
            double x = sqrt((double)q[0] * q[0] + (double)q[2] * q[2]), y = (double)q[1] - s->cup_center_y;
            double r = s->cup_radius, d = y > 0 ? sqrt((x - r) * (x - r) + y * y) : fabs(sqrt(x * x + y * y) - r);
            out[i] = (float)(d - s->cup_wall);
        } else {
            double dr = sqrt((double)q[0] * q[0] + (double)q[2] * q[2]) - s->cyl_radius;
            double dy = fabs((double)q[1]) - 0.5 * s->cyl_height;
            double inside = fmin(fmax(dr, dy), 0.0);
            double ox = fmax(dr, 0.0), oy = fmax(dy, 0.0);
            out[i] = (float)(inside + sqrt(ox * ox + oy * oy));
        }
    }
}

// ---- sampling ----------------------------------------------------------------------------------

mlb_status mlb_mesh_sample_faces(const mlb_mesh* m, const uint8_t* mask, float* p, int32_t* face, int n, uint64_t seed,
                                 uint64_t stream) {
    int F = m->n_faces;
    double* cdf = malloc(sizeof(double) * (size_t)(F > 0 ? F : 1));
    if (!cdf) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    double total = 0;
    for (int f = 0; f < F; f++) {
        const int32_t* t = m->faces + 3 * f;
        if (!mask || mask[f]) total += tri_area(m->pos + 3 * t[0], m->pos + 3 * t[1], m->pos + 3 * t[2]);
        cdf[f] = total;
    }
    if (!(total > 0)) { free(cdf); return mlb_fail(MLB_ERR_ARG, "mesh sampling: zero surface area"); }
#pragma omp parallel for schedule(static)
    for (int i = 0; i < n; i++) {
        mlb_u32x4 w = mlb_rng_words(seed, stream, (uint64_t)i);
        double u = mlb_u32_to_unit(w.v[0]) * total;
        int lo = 0, hi = F - 1;   // the first face whose running area passes u (a masked face adds none)
        while (lo < hi) { int mid = (lo + hi) / 2; if (cdf[mid] > u) hi = mid; else lo = mid + 1; }
        const int32_t* t = m->faces + 3 * lo;
        double r1 = sqrt(mlb_u32_to_unit(w.v[1])), r2 = mlb_u32_to_unit(w.v[2]);
        double ba = 1 - r1, bb = r1 * (1 - r2), bc = r1 * r2;
        for (int k = 0; k < 3; k++)
            p[3 * i + k] = (float)(ba * m->pos[3 * t[0] + k] + bb * m->pos[3 * t[1] + k] + bc * m->pos[3 * t[2] + k]);
        if (face) face[i] = lo;
    }
    free(cdf);
    return MLB_OK;
}

mlb_status mlb_mesh_sample_surface(const mlb_mesh* m, float* p, int n, uint64_t seed, uint64_t stream) {
    return mlb_mesh_sample_faces(m, NULL, p, NULL, n, seed, stream);
}

void mlb_shape_surface_samples(const mlb_shape* s, float* p, int n, uint64_t seed, uint64_t stream) {
    if (s->kind == MLB_SHAPE_MESH) { mlb_mesh_sample_surface(&s->mesh, p, n, seed, stream); return; }
#pragma omp parallel for schedule(static)
    for (int i = 0; i < n; i++) {
        uint64_t idx = 4 * (uint64_t)i;
        if (s->kind == MLB_SHAPE_ELLIPSOID) {
            double g[3], len = 0;
            for (int k = 0; k < 3; k++) { g[k] = mlb_rng_normal_f64(seed, stream, idx + k); len += g[k] * g[k]; }
            len = sqrt(len);
            if (!(len > 1e-12)) { g[0] = 1; g[1] = g[2] = 0; len = 1; }
            for (int k = 0; k < 3; k++) p[3 * i + k] = (float)(s->radii[k] * g[k] / len);
        } else if (s->kind == MLB_SHAPE_TORUS) {
            // area-uniform: the tube angle v with density ∝ R + r cos v (rejection on a few draws)
            double R = s->torus_major, r = s->torus_minor, u = 0, v = 0;
            for (uint64_t k = 0; k < 16; k++) {
                mlb_u32x4 w = mlb_rng_words(seed, stream, (uint64_t)i * 16 + k);
                u = 2 * M_PI * mlb_u32_to_unit(w.v[0]);
                v = 2 * M_PI * mlb_u32_to_unit(w.v[1]);
                if (mlb_u32_to_unit(w.v[2]) * (R + r) <= R + r * cos(v)) break;
            }
            p[3 * i] = (float)((R + r * cos(v)) * cos(u));
            p[3 * i + 1] = (float)((R + r * cos(v)) * sin(u));
            p[3 * i + 2] = (float)(r * sin(v));
        } else if (s->kind == MLB_SHAPE_BOX) {
            // area-uniform: a face pair by its area, a side by one bit, a point uniform on it
            const float* h = s->box_half;
            double a[3] = {h[1] * (double)h[2], h[0] * (double)h[2], h[0] * (double)h[1]};   // faces normal to x, y, z
            mlb_u32x4 w = mlb_rng_words(seed, stream, (uint64_t)i);
            double u = mlb_u32_to_unit(w.v[0]) * (a[0] + a[1] + a[2]);
            int axis = u < a[0] ? 0 : u < a[0] + a[1] ? 1 : 2, e1 = (axis + 1) % 3, e2 = (axis + 2) % 3;
            const float* c = s->box_center;
            p[3 * i + axis] = c[axis] + ((w.v[3] & 1) ? h[axis] : -h[axis]);
            p[3 * i + e1] = (float)(c[e1] + h[e1] * (2 * mlb_u32_to_unit(w.v[1]) - 1));
            p[3 * i + e2] = (float)(c[e2] + h[e2] * (2 * mlb_u32_to_unit(w.v[2]) - 1));
        } else if (s->kind == MLB_SHAPE_CUP) {
            // area-uniform over its three parts: the outer and inner hemispheres (height uniform on a
            // sphere is area-uniform, Archimedes) and the rim, a half torus (its upper half; tube angle
            // by rejection on the ring radius, as the torus above)
            double r = s->cup_radius, t = s->cup_wall, ro = r + t, ri = r - t;
            double a_out = 2 * M_PI * ro * ro, a_in = 2 * M_PI * ri * ri, a_rim = 2 * M_PI * M_PI * r * t;
            mlb_u32x4 w = mlb_rng_words(seed, stream, (uint64_t)i * 16);
            double u = mlb_u32_to_unit(w.v[0]) * (a_out + a_in + a_rim), phi = 2 * M_PI * mlb_u32_to_unit(w.v[1]);
            double rad, y;
            if (u < a_out + a_in) {
                double R = u < a_out ? ro : ri;
                y = -R * mlb_u32_to_unit(w.v[2]);
                rad = sqrt(fmax(R * R - y * y, 0.0));
            } else {
                double v = 0;
                for (uint64_t k = 1; k < 16; k++) {
                    mlb_u32x4 z = mlb_rng_words(seed, stream, (uint64_t)i * 16 + k);
                    v = M_PI * mlb_u32_to_unit(z.v[0]);
                    if (mlb_u32_to_unit(z.v[1]) * (r + t) <= r + t * cos(v)) break;
                }
                rad = r + t * cos(v);
                y = t * sin(v);
            }
            p[3 * i] = (float)(rad * cos(phi));
            p[3 * i + 1] = (float)(s->cup_center_y + y);
            p[3 * i + 2] = (float)(rad * sin(phi));
        } else {
            double R = s->cyl_radius, H = s->cyl_height;
            double side = 2 * M_PI * R * H, cap = M_PI * R * R;
            mlb_u32x4 w = mlb_rng_words(seed, stream, (uint64_t)i);
            double u = mlb_u32_to_unit(w.v[0]) * (side + 2 * cap);
            double phi = 2 * M_PI * mlb_u32_to_unit(w.v[1]);
            if (u < side) {
                p[3 * i] = (float)(R * cos(phi));
                p[3 * i + 2] = (float)(R * sin(phi));
                p[3 * i + 1] = (float)(H * (mlb_u32_to_unit(w.v[2]) - 0.5));
            } else {
                double r = R * sqrt(mlb_u32_to_unit(w.v[2]));
                p[3 * i] = (float)(r * cos(phi));
                p[3 * i + 2] = (float)(r * sin(phi));
                p[3 * i + 1] = (float)(u < side + cap ? 0.5 * H : -0.5 * H);
            }
        }
    }
}

// ---- the fit -------------------------------------------------------------------------------

mlb_shape_fit_config mlb_shape_fit_default(void) {
    mlb_shape_fit_config c = {.iters = 400, .batch = 12288, .lr = 1e-2, .jitter = 0.05f, .pool = 32768, .seed = 1};
    return c;
}

mlb_status mlb_geometry_fit_shape(mlb_geometry_net* net, const mlb_shape* shape, const mlb_shape_fit_config* cfg,
                                  mlb_progress* progress, double* final_loss) {
    if (cfg->iters < 1 || cfg->batch < 3 || cfg->pool < 1 || !(cfg->lr > 0) || !(cfg->jitter >= 0))
        return mlb_fail(MLB_ERR_ARG, "shape fit: iters %d, batch %d, pool %d, lr %g, jitter %g out of range", cfg->iters,
                        cfg->batch, cfg->pool, cfg->lr, (double)cfg->jitter);
    // Pool of 3·P points: surface, surface + N(0, jitter²), uniform over the grid box; their SDF is
    // computed once (the mesh SDF costs O(F) per point).
    size_t P = (size_t)cfg->pool, B = (size_t)cfg->batch;
    float* pool = malloc(sizeof(float) * 9 * P);
    float* target = malloc(sizeof(float) * 3 * P);
    float* pts = malloc(sizeof(float) * 3 * B);
    float* tgt = malloc(sizeof(float) * B);
    float* sdf = malloc(sizeof(float) * B);
    float* dsdf = malloc(sizeof(float) * B);
    mlb_status s = MLB_OK;
    if (!pool || !target || !pts || !tgt || !sdf || !dsdf) { s = mlb_fail(MLB_ERR_NOMEM, "shape fit: out of memory"); goto out; }
    mlb_shape_surface_samples(shape, pool, (int)P, cfg->seed, STREAM_SURFACE);
    mlb_shape_surface_samples(shape, pool + 3 * P, (int)P, cfg->seed, STREAM_JITTER_SURF);
    float half = 0.5f * net->cfg.scale;
    for (size_t i = 0; i < 3 * P; i++) {
        pool[3 * P + i] += cfg->jitter * mlb_rng_normal(cfg->seed, STREAM_JITTER, i);
        pool[6 * P + i] = half * (2 * mlb_rng_uniform(cfg->seed, STREAM_UNIFORM, i) - 1);
    }
    mlb_shape_sdf(shape, pool, target, (int)(3 * P));
    mlb_adam_config adam = mlb_geometry_adam(cfg->lr);
    double recent = 0;
    int n_recent = 0;
    for (int it = 0; it < cfg->iters; it++) {
        // a third of the batch from each kind, with replacement
        for (size_t b = 0; b < B; b++) {
            size_t kind = b % 3;
            size_t j = kind * P + mlb_rng_below(cfg->seed, STREAM_BATCH, (uint64_t)it * B + b, (uint32_t)P);
            memcpy(pts + 3 * b, pool + 3 * j, sizeof(float) * 3);
            tgt[b] = target[j];
        }
        s = geometry_net_forward(net, sdf, NULL, pts, (int)B);
        if (s) goto out;
        double loss = mse_forward(sdf, tgt, B);
        if (!isfinite(loss)) { s = mlb_fail(MLB_ERR_NUMERIC, "shape fit: loss is %g at step %d", loss, it); goto out; }
        memset(dsdf, 0, sizeof(float) * B);
        mse_backward(dsdf, sdf, tgt, B, 1.0f);
        geometry_net_zero_grad(net);
        geometry_net_backward(net, dsdf, NULL);
        geometry_net_update(net, &adam);
        if (it >= cfg->iters - 10) { recent += loss; n_recent++; }
        if (progress) {
            char st[48];
            snprintf(st, sizeof st, "mse %.3g", loss);
            mlb_progress_update(progress, it + 1, st);
        }
    }
    if (final_loss) *final_loss = n_recent ? recent / n_recent : 0;
out:
    free(pool); free(target); free(pts); free(tgt); free(sdf); free(dsdf);
    return s;
}
