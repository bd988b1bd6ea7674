// Symmetric Chamfer distance between two triangle meshes (include/matlaber/geometry.h): n
// area-uniform samples on each mesh, each one's exact distance to the other mesh's triangles
// (mlb_mesh_distance, through a BVH), averaged both ways. Reported also relative to the target's
// bounding-box diagonal. mlb_chamfer_many: one mesh against many targets, the same numbers.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include "matlaber/geometry.h"

enum { STREAM_CHAMFER_A = 0xC4A1, STREAM_CHAMFER_B = 0xC4A2 };

static void side_stats(const float* d, int n, double* mean, double* max) {
    double sum = 0, mx = 0;
    for (int i = 0; i < n; i++) { sum += d[i]; if (d[i] > mx) mx = d[i]; }   // fixed order
    *mean = sum / n;
    *max = mx;
}

static void finish(mlb_chamfer_result* r, const mlb_mesh* b) {
    r->chamfer = 0.5 * (r->a_to_b + r->b_to_a);
    float lo[3], hi[3];
    mlb_mesh_bounds(b, lo, hi);
    double d2 = 0;
    for (int k = 0; k < 3; k++) d2 += ((double)hi[k] - lo[k]) * ((double)hi[k] - lo[k]);
    r->diag = sqrt(d2);
    r->relative = r->diag > 0 ? r->chamfer / r->diag : INFINITY;
}

static mlb_status one_side(const mlb_mesh* from, const mlb_mesh* to, int n, uint64_t seed, uint64_t stream, double* mean,
                           double* max) {
    float* p = malloc(sizeof(float) * 3 * (size_t)n);
    float* d = malloc(sizeof(float) * (size_t)n);
    if (!p || !d) { free(p); free(d); return mlb_fail(MLB_ERR_NOMEM, "chamfer: out of memory"); }
    mlb_status s = mlb_mesh_sample_surface(from, p, n, seed, stream);
    if (!s) {
        mlb_mesh_distance(to, p, d, n);
        side_stats(d, n, mean, max);
    }
    free(p);
    free(d);
    return s;
}

mlb_status mlb_chamfer(const mlb_mesh* a, const mlb_mesh* b, int n, uint64_t seed, mlb_chamfer_result* r) {
    if (n < 1) return mlb_fail(MLB_ERR_ARG, "chamfer: %d samples", n);
    if (!a || !b || a->n_faces < 1 || b->n_faces < 1) return mlb_fail(MLB_ERR_ARG, "chamfer: empty mesh");
    mlb_status s = one_side(a, b, n, seed, STREAM_CHAMFER_A, &r->a_to_b, &r->max_a_to_b);
    if (!s) s = one_side(b, a, n, seed, STREAM_CHAMFER_B, &r->b_to_a, &r->max_b_to_a);
    if (s) return mlb_fail_context(s, "chamfer distance");
    finish(r, b);
    return MLB_OK;
}

mlb_status mlb_chamfer_many(const mlb_mesh* a, const mlb_mesh* b, const mlb_mesh_bvh* b_bvh, int m, int n, uint64_t seed,
                            mlb_chamfer_result* r) {
    if (n < 1 || m < 1) return mlb_fail(MLB_ERR_ARG, "chamfer: %d samples, %d targets", n, m);
    if (!a || !b || a->n_faces < 1) return mlb_fail(MLB_ERR_ARG, "chamfer: empty mesh");
    for (int j = 0; j < m; j++)
        if (b[j].n_faces < 1) return mlb_fail(MLB_ERR_ARG, "chamfer: target %d is an empty mesh", j);
    // a's side, once: its samples (as mlb_chamfer draws them) and its BVH
    float* pa = malloc(sizeof(float) * 3 * (size_t)n);
    if (!pa) return mlb_fail(MLB_ERR_NOMEM, "chamfer: out of memory");
    mlb_status s = mlb_mesh_sample_surface(a, pa, n, seed, STREAM_CHAMFER_A);
    if (s) { free(pa); return mlb_fail_context(s, "chamfer distance"); }
    mlb_mesh_bvh ba;
    int have_ba = mlb_mesh_bvh_build(&ba, a) == MLB_OK;   // without it, mlb_mesh_distance (the same numbers)
    // The targets over the threads, each target's work on one (the distance calls' own parallel
    // loops run single inside this region): one region instead of 4m short ones.
    int bad = m;   // the first target that failed, and why
    mlb_status bad_status = MLB_OK;
    char bad_msg[512] = "";
#pragma omp parallel
    {
        float* pb = malloc(sizeof(float) * 3 * (size_t)n);
        float* d = malloc(sizeof(float) * (size_t)n);
#pragma omp for schedule(dynamic, 1)
        for (int j = 0; j < m; j++) {
            mlb_status st = pb && d ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "chamfer: out of memory");
            if (!st) {
                if (b_bvh) mlb_mesh_bvh_distance(&b_bvh[j], pa, d, n);
                else mlb_mesh_distance(&b[j], pa, d, n);
                side_stats(d, n, &r[j].a_to_b, &r[j].max_a_to_b);
                st = mlb_mesh_sample_surface(&b[j], pb, n, seed, STREAM_CHAMFER_B);
            }
            if (!st) {
                if (have_ba) mlb_mesh_bvh_distance(&ba, pb, d, n);
                else mlb_mesh_distance(a, pb, d, n);
                side_stats(d, n, &r[j].b_to_a, &r[j].max_b_to_a);
                finish(&r[j], &b[j]);
            }
            if (st) {
#pragma omp critical(chamfer_many_error)
                if (j < bad) { bad = j; bad_status = st; snprintf(bad_msg, sizeof bad_msg, "%s", mlb_last_error()); }
            }
        }
        free(pb);
        free(d);
    }
    if (have_ba) mlb_mesh_bvh_free(&ba);
    free(pa);
    if (bad < m) return mlb_fail(bad_status, "chamfer distance to target %d: %s", bad, bad_msg);
    return MLB_OK;
}
