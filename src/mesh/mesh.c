// Mesh utilities: freeing, area-weighted vertex normals, bounds, fitting into the unit sphere.
#include "matlaber/mesh.h"
#include <math.h>
#include <stdlib.h>
#include <string.h>

void mlb_mesh_free(mlb_mesh* m) {
    if (!m) return;
    free(m->pos);
    free(m->normal);
    free(m->uv);
    free(m->faces);
    memset(m, 0, sizeof *m);
}

static uint32_t float_key(float f) {
    if (f == 0.0f) f = 0.0f;   // -0 and +0 are the same place
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

static uint64_t hash_pos(const float* p) {
    uint64_t h = 0x9E3779B97F4A7C15ull;
    for (int k = 0; k < 3; k++) {
        h ^= float_key(p[k]);
        h *= 0xBF58476D1CE4E5B9ull;
        h ^= h >> 31;
    }
    return h;
}

static int same_pos(const float* a, const float* b) {
    return float_key(a[0]) == float_key(b[0]) && float_key(a[1]) == float_key(b[1]) && float_key(a[2]) == float_key(b[2]);
}

mlb_status mlb_mesh_weld_map(const float* pos, int n, int32_t* first) {
    size_t cap = 16;
    while (cap < 2 * (size_t)n) cap *= 2;
    int32_t* table = malloc(cap * sizeof *table);
    if (!table) return mlb_fail(MLB_ERR_NOMEM, "weld map: out of memory for %d vertices", n);
    memset(table, 0xff, cap * sizeof *table);
    for (int i = 0; i < n; i++) {
        const float* p = pos + 3 * (size_t)i;
        size_t h = (size_t)hash_pos(p) & (cap - 1);
        while (table[h] >= 0 && !same_pos(pos + 3 * (size_t)table[h], p)) h = (h + 1) & (cap - 1);
        if (table[h] < 0) table[h] = i;
        first[i] = table[h];
    }
    free(table);
    return MLB_OK;
}

// Area-weighted normals: every triangle adds its un-normalised cross product (length = twice its
// area) to its three corners. Unified vertices that sit at exactly the same position (the copies
// a uv seam makes) are summed together and share the result, so seams do not crease the shading.
// Sums are in double. A vertex with no area around it (unused, or only in degenerate triangles)
// gets (0, 0, 1).
mlb_status mlb_mesh_compute_normals(mlb_mesh* m) {
    if (!m) return mlb_fail(MLB_ERR_ARG, "mlb_mesh_compute_normals: NULL mesh");
    if (m->n_verts < 0 || m->n_faces < 0 || (m->n_verts && !m->pos) || (m->n_faces && !m->faces))
        return mlb_fail(MLB_ERR_ARG, "mlb_mesh_compute_normals: inconsistent mesh (%d vertices, %d faces)", m->n_verts,
                        m->n_faces);
    size_t nv = (size_t)m->n_verts, nf = (size_t)m->n_faces;
    for (size_t i = 0; i < 3 * nf; i++)
        if (m->faces[i] < 0 || m->faces[i] >= m->n_verts)
            return mlb_fail(MLB_ERR_ARG, "mlb_mesh_compute_normals: face %zu uses vertex %d, mesh has %d", i / 3,
                            (int)m->faces[i], m->n_verts);
    for (size_t i = 0; i < 3 * nv; i++)
        if (!isfinite(m->pos[i]))
            return mlb_fail(MLB_ERR_NUMERIC, "mlb_mesh_compute_normals: vertex %zu has a non-finite position", i / 3);
    if (nv == 0) return MLB_OK;

    // group[i]: the first vertex at the same position as i
    int32_t* group = malloc(nv * sizeof *group);
    double* acc = calloc(3 * nv, sizeof *acc);
    float* out = malloc(3 * nv * sizeof *out);
    mlb_status st = (group && acc && out) ? mlb_mesh_weld_map(m->pos, (int)nv, group)
                                          : mlb_fail(MLB_ERR_NOMEM, "out of memory");
    if (st) {
        free(group); free(acc); free(out);
        return mlb_fail_context(st, "mlb_mesh_compute_normals (%zu vertices)", nv);
    }

    for (size_t f = 0; f < nf; f++) {
        const int32_t* t = m->faces + 3 * f;
        const float *a = m->pos + 3 * (size_t)t[0], *b = m->pos + 3 * (size_t)t[1], *c = m->pos + 3 * (size_t)t[2];
        double e1[3] = {(double)b[0] - a[0], (double)b[1] - a[1], (double)b[2] - a[2]};
        double e2[3] = {(double)c[0] - a[0], (double)c[1] - a[1], (double)c[2] - a[2]};
        double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        for (int k = 0; k < 3; k++) {
            double* d = acc + 3 * (size_t)group[t[k]];
            d[0] += n[0];
            d[1] += n[1];
            d[2] += n[2];
        }
    }
    for (size_t i = 0; i < nv; i++) {
        const double* d = acc + 3 * (size_t)group[i];
        double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        if (len > 0 && isfinite(len)) {
            out[3 * i] = (float)(d[0] / len);
            out[3 * i + 1] = (float)(d[1] / len);
            out[3 * i + 2] = (float)(d[2] / len);
        } else {
            out[3 * i] = 0.0f;
            out[3 * i + 1] = 0.0f;
            out[3 * i + 2] = 1.0f;
        }
    }
    free(group);
    free(acc);
    free(m->normal);
    m->normal = out;
    return MLB_OK;
}

// Over all vertices (used by a face or not); (0,0,0)-(0,0,0) for an empty mesh.
void mlb_mesh_bounds(const mlb_mesh* m, float lo[3], float hi[3]) {
    for (int k = 0; k < 3; k++) lo[k] = hi[k] = 0.0f;
    if (!m || m->n_verts <= 0 || !m->pos) return;
    for (int k = 0; k < 3; k++) lo[k] = hi[k] = m->pos[k];
    for (size_t i = 1; i < (size_t)m->n_verts; i++)
        for (int k = 0; k < 3; k++) {
            float v = m->pos[3 * i + k];
            if (v < lo[k]) lo[k] = v;
            if (v > hi[k]) hi[k] = v;
        }
}

double mlb_mesh_radius_about(const mlb_mesh* m, const double c[3]) {
    double r2 = 0;
    for (size_t i = 0; m && m->pos && i < (size_t)m->n_verts; i++) {
        double d2 = 0;
        for (int k = 0; k < 3; k++) {
            double d = m->pos[3 * i + k] - c[k];
            d2 += d * d;
        }
        if (d2 > r2) r2 = d2;
    }
    return sqrt(r2);
}

// Moves the centre of the bounding box to the origin and scales uniformly so that the farthest
// vertex lies at distance 1 (just inside, after float rounding). Normals are unchanged (a uniform
// scale keeps directions). A mesh whose vertices all coincide is only moved.
void mlb_mesh_normalize_unit_sphere(mlb_mesh* m) {
    if (!m || m->n_verts <= 0 || !m->pos) return;
    float lo[3], hi[3];
    mlb_mesh_bounds(m, lo, hi);
    double c[3];
    for (int k = 0; k < 3; k++) c[k] = 0.5 * ((double)lo[k] + (double)hi[k]);
    size_t nv = (size_t)m->n_verts;
    double r = mlb_mesh_radius_about(m, c);
    // The scale is nudged below 1/r so that rounding to float cannot put a vertex at 1 + 1 ulp.
    double s = r > 0 && isfinite(r) ? (1.0 - 1e-6) / r : 1.0;
    for (size_t i = 0; i < nv; i++)
        for (int k = 0; k < 3; k++) m->pos[3 * i + k] = (float)((m->pos[3 * i + k] - c[k]) * s);
}
