// Measuring a generated asset against the catalogue's truth (include/matlaber/text3d.h): shape by
// relative Chamfer distance to every class, material by the median BRDF on the surface, relighting
// by mlb_eval_relight against the best-fitting truth instance. The benchmark loop: text3d_bench.c.
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/catalogue.h"
#include "matlaber/evaluate.h"
#include "matlaber/geometry.h"
#include "matlaber/rng.h"
#include "matlaber/text3d.h"

int mlb_text3d_is_metal(const float k[7]) {
    double kd = ((double)k[0] + k[1] + k[2]) / 3.0, ks = ((double)k[3] + k[4] + k[5]) / 3.0;
    return ks > MLB_TEXT3D_METAL_KS && kd < MLB_TEXT3D_METAL_KD;
}

static double srgb(double v) {
    v = fmin(fmax(v, 0.0), 1.0);
    return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1 / 2.4) - 0.055;
}

// k's colour for the comparison: a metal's specular colour over its largest channel (its hue and
// saturation, not its brightness), a dielectric's diffuse colour; sRGB-encoded.
static void colour_key(const float k[7], int metal, double out[3]) {
    const float* c = metal ? k + 3 : k;
    double mx = fmax(fmax(c[0], c[1]), fmax(c[2], 1e-6f));
    for (int j = 0; j < 3; j++) out[j] = srgb(metal ? c[j] / mx : c[j]);
}

int mlb_text3d_colour_of(const float k[7]) {
    int metal = mlb_text3d_is_metal(k), best = -1;
    double key[3], best_d = INFINITY;
    colour_key(k, metal, key);
    for (int m = 0; m < mlb_catalogue_n_materials(); m++) {
        if (mlb_catalogue_material_metal(m) != metal) continue;
        double ref[3], d = 0;
        colour_key(mlb_catalogue_material_brdf(m), metal, ref);
        for (int j = 0; j < 3; j++) d += (key[j] - ref[j]) * (key[j] - ref[j]);
        if (d < best_d) best_d = d, best = m;
    }
    return best;
}

mlb_status mlb_text3d_truth_create(mlb_text3d_truth* t, int n_seeds) {
    memset(t, 0, sizeof *t);
    int nc = mlb_catalogue_n_classes();
    if (n_seeds < 1 || n_seeds > 1024) return mlb_fail(MLB_ERR_ARG, "text3d truth: %d shape seeds (1..1024)", n_seeds);
    if (nc > MLB_TEXT3D_MAX_CLASSES) return mlb_fail(MLB_ERR_ARG, "text3d truth: %d classes (at most %d)", nc, MLB_TEXT3D_MAX_CLASSES);
    t->meshes = calloc((size_t)nc * n_seeds, sizeof(mlb_mesh));
    t->bvh = calloc((size_t)nc * n_seeds, sizeof(mlb_mesh_bvh));
    if (!t->meshes || !t->bvh) { free(t->meshes); free(t->bvh); memset(t, 0, sizeof *t);
                                 return mlb_fail(MLB_ERR_NOMEM, "text3d truth: out of memory"); }
    t->n_classes = nc;
    t->n_seeds = n_seeds;
    for (int c = 0; c < nc; c++)
        for (int s = 0; s < n_seeds; s++) {
            int i = c * n_seeds + s;
            mlb_status st = mlb_catalogue_mesh(c, (uint64_t)s, &t->meshes[i]);
            if (!st) st = mlb_mesh_bvh_build(&t->bvh[i], &t->meshes[i]);
            if (st) {
                mlb_text3d_truth_free(t);
                return mlb_fail_context(st, "text3d truth: %s seed %d", mlb_catalogue_class_name(c), s);
            }
        }
    return MLB_OK;
}

void mlb_text3d_truth_free(mlb_text3d_truth* t) {
    for (int i = 0; i < t->n_classes * t->n_seeds; i++) {
        if (t->meshes) mlb_mesh_free(&t->meshes[i]);
        if (t->bvh) mlb_mesh_bvh_free(&t->bvh[i]);
    }
    free(t->meshes);
    free(t->bvh);
    memset(t, 0, sizeof *t);
}

mlb_text3d_measure_config mlb_text3d_measure_default(void) {
    mlb_text3d_measure_config m = {.chamfer_samples = 2000, .chamfer_seed = 7, .relight_views = 4, .relight_res = 128,
                                   .fit_rounds = 64, .fit_margin = 1.5, .surface_samples = 4000};
    return m;
}

static int cmp_float(const void* a, const void* b) {
    float x = *(const float*)a, y = *(const float*)b;
    return (x > y) - (x < y);
}

mlb_status mlb_text3d_median_brdf(const float* k, size_t n, float out[7]) {
    if (n == 0) return mlb_fail(MLB_ERR_ARG, "median BRDF: no vertices");
    float* col = malloc(sizeof(float) * n);
    if (!col) return mlb_fail(MLB_ERR_NOMEM, "median BRDF: out of memory");
    for (int j = 0; j < 7; j++) {
        for (size_t i = 0; i < n; i++) col[i] = k[7 * i + j];
        qsort(col, n, sizeof(float), cmp_float);
        out[j] = n % 2 ? col[n / 2] : 0.5f * (col[n / 2 - 1] + col[n / 2]);
    }
    free(col);
    return MLB_OK;
}

// m's mirror image across the plane axis = 0 (winding reversed, so it stays outward); with both
// != 0, m and its mirror image as one mesh. Positions and faces only.
static mlb_status mirrored_mesh(const mlb_mesh* m, int axis, int both, mlb_mesh* out) {
    memset(out, 0, sizeof *out);
    int V = m->n_verts, F = m->n_faces, k = both ? 2 : 1;
    out->pos = malloc(sizeof(float) * 3 * (size_t)V * k);
    out->faces = malloc(sizeof(int32_t) * 3 * (size_t)F * k);
    if (!out->pos || !out->faces) { mlb_mesh_free(out); return mlb_fail(MLB_ERR_NOMEM, "text3d measure: out of memory"); }
    out->n_verts = V * k;
    out->n_faces = F * k;
    float* mp = out->pos + (both ? 3 * (size_t)V : 0);
    int32_t* mf = out->faces + (both ? 3 * (size_t)F : 0);
    int32_t off = both ? V : 0;
    if (both) {
        memcpy(out->pos, m->pos, sizeof(float) * 3 * (size_t)V);
        memcpy(out->faces, m->faces, sizeof(int32_t) * 3 * (size_t)F);
    }
    for (int i = 0; i < V; i++)
        for (int j = 0; j < 3; j++) mp[3 * i + j] = j == axis ? -m->pos[3 * i + j] : m->pos[3 * i + j];
    for (int f = 0; f < F; f++) {
        mf[3 * f + 0] = m->faces[3 * f + 0] + off;
        mf[3 * f + 1] = m->faces[3 * f + 2] + off;
        mf[3 * f + 2] = m->faces[3 * f + 1] + off;
    }
    return MLB_OK;
}

// The Janus part of the scores (text3d.h) against the truth instance tm.
static mlb_status measure_janus(const mlb_mesh* mesh, const mlb_mesh* tm, int axis, const mlb_text3d_measure_config* mc,
                                mlb_text3d_scores* out) {
    out->janus = out->mirrored = -1;
    out->chamfer_truth = out->chamfer_mirror = out->chamfer_both = NAN;
    if (axis < 0) return MLB_OK;
    mlb_mesh target[3] = {*tm};   // T (borrowed), M, T ∪ M: the asset's samples and BVH made once for the three
    mlb_status s = mirrored_mesh(tm, axis, 0, &target[1]);
    if (!s) s = mirrored_mesh(tm, axis, 1, &target[2]);
    mlb_chamfer_result r[3];
    if (!s) s = mlb_chamfer_many(mesh, target, NULL, 3, mc->chamfer_samples, mc->chamfer_seed, r);
    mlb_mesh_free(&target[1]);
    mlb_mesh_free(&target[2]);
    if (s) return mlb_fail_context(s, "text3d measure: the mirror images");
    out->chamfer_truth = r[0].chamfer;
    out->chamfer_mirror = r[1].chamfer;
    out->chamfer_both = r[2].chamfer;
    out->janus = r[2].chamfer < r[0].chamfer && r[2].chamfer < r[1].chamfer;
    out->mirrored = !out->janus && r[1].chamfer < r[0].chamfer;
    return MLB_OK;
}

// Chamfer results r[j] of the asset against class c[j] built with parameters u[j] (j < m),
// samples from seed: the meshes of a fit's round, or of the final measure, built and measured together.
static mlb_status chamfer_params(const mlb_mesh* asset, const int* c, const float (*u)[MLB_CATALOGUE_MAX_PARAMS], int m,
                                 int samples, uint64_t seed, mlb_chamfer_result* r) {
    mlb_mesh* mesh = calloc((size_t)m, sizeof(mlb_mesh));
    mlb_mesh_bvh* bvh = calloc((size_t)m, sizeof(mlb_mesh_bvh));
    mlb_status s = mesh && bvh ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "text3d measure: out of memory");
    for (int j = 0; !s && j < m; j++) {
        s = mlb_catalogue_mesh_params(c[j], u[j], &mesh[j]);
        if (!s) s = mlb_mesh_bvh_build(&bvh[j], &mesh[j]);
    }
    if (!s) s = mlb_chamfer_many(asset, mesh, bvh, m, samples, seed, r);
    for (int j = 0; mesh && bvh && j < m; j++) { mlb_mesh_free(&mesh[j]); mlb_mesh_bvh_free(&bvh[j]); }
    free(mesh);
    free(bvh);
    return s;
}

// A pattern search over class c's shape parameters from u (in place; *rel its relative Chamfer,
// lowered). Every round tries each parameter one step up and down and as many random directions
// of the same length (some parameters only matter together: the frame's scaling to a fixed radius
// makes a mug's radius, height and handle one ridge that single steps cannot climb), all measured
// together, and moves to the nearest shape if it is nearer, else halves the step, from 1/8 of a
// range down to 1/128. Deterministic: the same samples every round, Philox directions, ties to
// the lowest index.
#define FIT_STREAM 0xF17C0000ull
static mlb_status fit_class(const mlb_mesh* asset, int c, const mlb_text3d_measure_config* mc, float u[MLB_CATALOGUE_MAX_PARAMS],
                            double* rel) {
    enum { MAXC = 4 * MLB_CATALOGUE_MAX_PARAMS };
    const int n = mlb_catalogue_class_n_params(c);
    float cand[MAXC][MLB_CATALOGUE_MAX_PARAMS];
    int cc[MAXC];
    mlb_chamfer_result r[MAXC];
    for (int j = 0; j < MAXC; j++) cc[j] = c;
    float step = 0.125f;
    for (int round = 0; round < mc->fit_rounds && step >= 1.0f / 128; round++) {
        int m = 0;
        for (int k = 0; k < 2 * n; k++) {   // ± each parameter
            float v = fminf(fmaxf(u[k / 2] + (k % 2 ? step : -step), 0.0f), 1.0f);
            if (v == u[k / 2]) continue;   // at the range's end
            memcpy(cand[m], u, sizeof cand[m]);
            cand[m++][k / 2] = v;
        }
        for (int d = 0; d < 2 * n; d++) {   // random directions, step long
            float dir[MLB_CATALOGUE_MAX_PARAMS];
            double len = 0;
            for (int k = 0; k < n; k++) {
                dir[k] = mlb_rng_normal(mc->chamfer_seed, FIT_STREAM + (uint64_t)c, ((uint64_t)round * MAXC + (uint64_t)d) * MLB_CATALOGUE_MAX_PARAMS + (uint64_t)k);
                len += (double)dir[k] * dir[k];
            }
            memcpy(cand[m], u, sizeof cand[m]);
            for (int k = 0; k < n; k++) cand[m][k] = fminf(fmaxf(u[k] + step * dir[k] / (float)sqrt(len + 1e-30), 0.0f), 1.0f);
            m++;
        }
        mlb_status s = chamfer_params(asset, cc, (const float(*)[MLB_CATALOGUE_MAX_PARAMS])cand, m, mc->chamfer_samples,
                                      mc->chamfer_seed, r);
        if (s) return mlb_fail_context(s, "text3d measure: fitting a %s", mlb_catalogue_class_name(c));
        int best = -1;
        for (int j = 0; j < m; j++)
            if (r[j].relative < (best < 0 ? *rel : r[best].relative)) best = j;
        if (best < 0) { step *= 0.5f; continue; }
        memcpy(u, cand[best], sizeof cand[best]);
        *rel = r[best].relative;
    }
    return MLB_OK;
}

// The shape part of the scores: the best seed of every class, then the fit of the classes that
// can matter (the prompted one and every one whose best seed is within fit_margin of the nearest),
// then every class's final shape measured again on fresh samples (chamfer_seed + 1), so that the
// numbers reported are not the ones the search was steered by.
static mlb_status measure_shape(const mlb_text3d_truth* t, const mlb_mesh* mesh, int cls, const mlb_text3d_measure_config* mc,
                                mlb_text3d_scores* out) {
    // all classes x seeds in one call (the asset's samples and BVH made once, the truths' BVHs are
    // the truth's, the targets shared out over the threads)
    int nt = t->n_classes * t->n_seeds;
    mlb_chamfer_result* cr = malloc(sizeof(mlb_chamfer_result) * (size_t)nt);
    if (!cr) return mlb_fail(MLB_ERR_NOMEM, "text3d measure: out of memory");
    mlb_status s = mlb_chamfer_many(mesh, t->meshes, t->bvh, nt, mc->chamfer_samples, mc->chamfer_seed, cr);
    if (s) { free(cr); return mlb_fail_context(s, "text3d measure: shape"); }
    double seed_best = INFINITY;
    for (int c = 0; c < t->n_classes; c++) {
        out->chamfer[c] = INFINITY;
        for (int seed = 0; seed < t->n_seeds; seed++) {
            const mlb_chamfer_result* r = &cr[c * t->n_seeds + seed];
            if (r->relative < out->chamfer[c]) { out->chamfer[c] = r->relative; out->best_seed[c] = (uint64_t)seed; }
        }
        mlb_catalogue_seed_params(c, out->best_seed[c], out->shape_u[c]);
        seed_best = fmin(seed_best, out->chamfer[c]);
    }
    free(cr);
    for (int c = 0; c < t->n_classes; c++) {
        out->fitted[c] = mc->fit_rounds > 0 && (c == cls || out->chamfer[c] <= mc->fit_margin * seed_best);
        if (out->fitted[c] && (s = fit_class(mesh, c, mc, out->shape_u[c], &out->chamfer[c]))) return s;
    }
    int all[MLB_TEXT3D_MAX_CLASSES];
    mlb_chamfer_result r[MLB_TEXT3D_MAX_CLASSES];
    for (int c = 0; c < t->n_classes; c++) all[c] = c;
    s = chamfer_params(mesh, all, (const float(*)[MLB_CATALOGUE_MAX_PARAMS])out->shape_u, t->n_classes, mc->chamfer_samples,
                       mc->chamfer_seed + 1, r);
    if (s) return mlb_fail_context(s, "text3d measure: shape");
    for (int c = 0; c < t->n_classes; c++) out->chamfer[c] = r[c].relative;
    return MLB_OK;
}

mlb_status mlb_text3d_measure(const mlb_text3d_truth* t, const mlb_mesh* mesh, const float* k, int cls, int mat,
                              const mlb_envlight* light, const mlb_text3d_measure_config* mc, mlb_text3d_scores* out) {
    memset(out, 0, sizeof *out);
    const float* truth_brdf = mlb_catalogue_material_brdf(mat);
    if (cls < 0 || cls >= t->n_classes || !truth_brdf)
        return mlb_fail(MLB_ERR_ARG, "text3d measure: class %d / material %d out of range", cls, mat);
    if (!mesh || mesh->n_faces < 1) return mlb_fail(MLB_ERR_ARG, "text3d measure: the asset's mesh is empty");
    out->cls = cls;
    out->mat = mat;
    out->held_out = mlb_catalogue_held_out(cls, mat);
    mlb_status s = measure_shape(t, mesh, cls, mc, out);
    if (s) return s;
    out->nearest = 0;
    for (int c = 1; c < t->n_classes; c++)
        if (out->chamfer[c] < out->chamfer[out->nearest]) out->nearest = c;
    out->class_ok = out->nearest == cls;
    out->chamfer_prompted = out->chamfer[cls];
    // material: the median over the vertices (robust to the odd stray texel of a seam)
    s = mlb_text3d_median_brdf(k, (size_t)mesh->n_verts, out->median_k);
    if (s) return s;
    double se = 0;
    for (int j = 0; j < 7; j++) se += ((double)out->median_k[j] - truth_brdf[j]) * ((double)out->median_k[j] - truth_brdf[j]);
    out->material_rmse = sqrt(se / 7.0);
    out->metal_truth = mlb_catalogue_material_metal(mat);
    out->metal_pred = mlb_text3d_is_metal(out->median_k);
    out->metal_ok = out->metal_truth == out->metal_pred;
    out->colour_pred = mlb_text3d_colour_of(out->median_k);
    out->colour_ok = out->colour_pred == mat;
    // the surface and relighting against the truth instance: the prompted class's fitted shape
    // (with its parts), the true material
    mlb_mesh tm;
    uint8_t* part = NULL;
    s = mlb_catalogue_mesh_parts(cls, out->shape_u[cls], &tm, &part);
    if (s) return mlb_fail_context(s, "text3d measure: the truth instance");
    int n_parts = mlb_catalogue_class_n_parts(cls);
    mlb_surface_result sr;
    s = mlb_surface_compare(mesh, &tm, part, n_parts, mc->surface_samples, mc->chamfer_seed, &sr);
    free(part);
    if (!s) {
        out->normal_deg = sr.normal_deg;
        out->accuracy = sr.accuracy;
        out->completeness = sr.completeness;
        out->thin = NAN;
        for (int k = 0; k < MLB_CATALOGUE_MAX_PARTS; k++) {
            out->part_completeness[k] = k < n_parts ? sr.part_completeness[k] : NAN;
            if (k < n_parts && !isnan(out->part_completeness[k]) && !(out->thin >= out->part_completeness[k])) out->thin = out->part_completeness[k];
        }
    }
    if (!s) s = measure_janus(mesh, &tm, mlb_catalogue_class_mirror_axis(cls), mc, out);
    float* tk = NULL;
    if (!s && !(tk = malloc(sizeof(float) * 7 * (size_t)tm.n_verts))) s = mlb_fail(MLB_ERR_NOMEM, "text3d measure: out of memory");
    if (!s) {
        for (int i = 0; i < tm.n_verts; i++) memcpy(tk + 7 * (size_t)i, truth_brdf, sizeof(float) * 7);
        s = mlb_eval_relight(&tm, tk, mesh, k, NULL, NULL, light, mc->relight_views, 30.0, mc->relight_res, &out->relight_psnr, NULL);
        if (s) s = mlb_fail_context(s, "text3d measure: relighting");
    }
    free(tk);
    mlb_mesh_free(&tm);
    return s;
}

mlb_status mlb_text3d_measure_run(const mlb_text3d_truth* t, const char* run_dir, int cls, int mat,
                                  const mlb_envlight* light, const mlb_text3d_measure_config* mc,
                                  mlb_text3d_scores* out) {
    mlb_run_asset a;
    mlb_status s = mlb_run_asset_load(&a, run_dir);
    if (s) return s;
    float* k = malloc(sizeof(float) * 7 * (size_t)a.mesh.n_verts);
    if (!k) s = mlb_fail(MLB_ERR_NOMEM, "text3d measure: out of memory");
    if (!s) s = mlb_run_asset_vertex_brdf(&a, k);
    if (!s) s = mlb_text3d_measure(t, &a.mesh, k, cls, mat, light, mc, out);
    free(k);
    mlb_run_asset_free(&a);
    return s ? mlb_fail_context(s, "%s", run_dir) : MLB_OK;
}
