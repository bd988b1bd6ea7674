// Symmetric Chamfer distance between two triangle meshes (include/matlaber/geometry.h): n
// area-uniform samples on each mesh, each one's distance to the other mesh's triangles (exact
// point-to-triangle distance, brute force O(n·F) with bounding-box culling: mlb_mesh_distance),
// averaged both ways. Reported also relative to the target's bounding-box diagonal.
#include <math.h>
#include <stdlib.h>
#include "matlaber/geometry.h"

enum { STREAM_CHAMFER_A = 0xC4A1, STREAM_CHAMFER_B = 0xC4A2 };

static mlb_status one_side(const mlb_mesh* from, const mlb_mesh* to, int n, uint64_t seed, uint64_t stream, double* mean,
                           double* max) {
    float* p = malloc(sizeof(float) * 3 * (size_t)n);
    float* d = malloc(sizeof(float) * (size_t)n);
    if (!p || !d) { free(p); free(d); return mlb_fail(MLB_ERR_NOMEM, "chamfer: out of memory"); }
    mlb_status s = mlb_mesh_sample_surface(from, p, n, seed, stream);
    if (!s) {
        mlb_mesh_distance(to, p, d, n);
        double sum = 0, mx = 0;
        for (int i = 0; i < n; i++) { sum += d[i]; if (d[i] > mx) mx = d[i]; }   // fixed order
        *mean = sum / n;
        *max = mx;
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
    r->chamfer = 0.5 * (r->a_to_b + r->b_to_a);
    float lo[3], hi[3];
    mlb_mesh_bounds(b, lo, hi);
    double d2 = 0;
    for (int k = 0; k < 3; k++) d2 += ((double)hi[k] - lo[k]) * ((double)hi[k] - lo[k]);
    r->diag = sqrt(d2);
    r->relative = r->diag > 0 ? r->chamfer / r->diag : INFINITY;
    return MLB_OK;
}
