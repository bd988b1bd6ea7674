// Measuring a generated asset against the catalogue's truth (include/matlaber/text3d.h): shape by
// relative Chamfer distance to every class, material by the median BRDF on the surface, relighting
// by mlb_eval_relight against the best-fitting truth instance. The benchmark loop: text3d_bench.c.
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/catalogue.h"
#include "matlaber/evaluate.h"
#include "matlaber/geometry.h"
#include "matlaber/text3d.h"

int mlb_text3d_is_metal(const float k[7]) {
    double kd = ((double)k[0] + k[1] + k[2]) / 3.0, ks = ((double)k[3] + k[4] + k[5]) / 3.0;
    return ks > MLB_TEXT3D_METAL_KS && kd < MLB_TEXT3D_METAL_KD;
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
    mlb_text3d_measure_config m = {.chamfer_samples = 2000, .chamfer_seed = 7, .relight_views = 4, .relight_res = 128};
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
    // shape: the best seed of every class; the nearest class names what the asset looks like. All
    // classes x seeds in one call (the asset's samples and BVH made once, the truths' BVHs are the
    // truth's, the targets shared out over the threads).
    int nt = t->n_classes * t->n_seeds;
    mlb_chamfer_result* cr = malloc(sizeof(mlb_chamfer_result) * (size_t)nt);
    if (!cr) return mlb_fail(MLB_ERR_NOMEM, "text3d measure: out of memory");
    mlb_status s = mlb_chamfer_many(mesh, t->meshes, t->bvh, nt, mc->chamfer_samples, mc->chamfer_seed, cr);
    if (s) { free(cr); return mlb_fail_context(s, "text3d measure: shape"); }
    out->nearest = -1;
    for (int c = 0; c < t->n_classes; c++) {
        out->chamfer[c] = INFINITY;
        for (int seed = 0; seed < t->n_seeds; seed++) {
            const mlb_chamfer_result* r = &cr[c * t->n_seeds + seed];
            if (r->relative < out->chamfer[c]) { out->chamfer[c] = r->relative; out->best_seed[c] = (uint64_t)seed; }
        }
        if (out->nearest < 0 || out->chamfer[c] < out->chamfer[out->nearest]) out->nearest = c;
    }
    free(cr);
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
    // relighting against the truth instance: prompted class, its best seed, the true material
    const mlb_mesh* tm = &t->meshes[cls * t->n_seeds + (int)out->best_seed[cls]];
    s = measure_janus(mesh, tm, mlb_catalogue_class_mirror_axis(cls), mc, out);
    if (s) return s;
    float* tk = malloc(sizeof(float) * 7 * (size_t)tm->n_verts);
    if (!tk) return mlb_fail(MLB_ERR_NOMEM, "text3d measure: out of memory");
    for (int i = 0; i < tm->n_verts; i++) memcpy(tk + 7 * (size_t)i, truth_brdf, sizeof(float) * 7);
    s = mlb_eval_relight(tm, tk, mesh, k, light, mc->relight_views, 30.0, mc->relight_res, &out->relight_psnr, NULL);
    free(tk);
    return s ? mlb_fail_context(s, "text3d measure: relighting") : MLB_OK;
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
