// How closely one triangle mesh's surface follows another's (include/matlaber/geometry.h): what a
// person sees that a mean distance hides. Normal error: at area-uniform samples on the asset, the
// angle between the asset's shading normal there (area-weighted vertex normals made from its
// positions, interpolated: what renders and exports show, and what stored normals cannot hide)
// and the normal of the nearest face of the truth, either way round (a crumpled surface scores high
// where its distance is small; the two sides of a thin wall, a mug's or a bowl's, are both the
// truth, and a surface that runs along the wall between them matches whichever side is nearer). Accuracy and completeness: the 95th percentiles
// of the distances asset -> truth (spikes, drips) and truth -> asset (a missing handle, leg or stem),
// relative to the truth's bounding-box diagonal; completeness again on each labelled part of the
// truth alone (its own samples, so a small part is measured as finely as the whole).
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/geometry.h"

enum { STREAM_SURF_ASSET = 0x5C0A, STREAM_SURF_TRUTH = 0x5C0B, STREAM_SURF_PART = 0x5C10 };

static void face_normal(const mlb_mesh* m, int32_t f, double n[3]) {
    const int32_t* t = m->faces + 3 * (size_t)f;
    const float *a = m->pos + 3 * (size_t)t[0], *b = m->pos + 3 * (size_t)t[1], *c = m->pos + 3 * (size_t)t[2];
    double u[3], v[3];
    for (int k = 0; k < 3; k++) u[k] = (double)b[k] - a[k], v[k] = (double)c[k] - a[k];
    n[0] = u[1] * v[2] - u[2] * v[1], n[1] = u[2] * v[0] - u[0] * v[2], n[2] = u[0] * v[1] - u[1] * v[0];
    double l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (int k = 0; k < 3; k++) n[k] = l > 0 ? n[k] / l : 0;
}

// The vertex normals interpolated at p on face f (barycentric coordinates from the sub-triangles'
// areas), normalised; the face normal where they cancel.
static void shading_normal(const mlb_mesh* m, const float* nrm, int32_t f, const float* p, double n[3]) {
    const int32_t* t = m->faces + 3 * (size_t)f;
    double w[3], sum = 0;
    for (int j = 0; j < 3; j++) {   // the area opposite corner j: the sub-triangle (p, corner j+1, corner j+2)
        const float *b = m->pos + 3 * (size_t)t[(j + 1) % 3], *c = m->pos + 3 * (size_t)t[(j + 2) % 3];
        double u[3], v[3], x[3];
        for (int k = 0; k < 3; k++) u[k] = (double)b[k] - p[k], v[k] = (double)c[k] - p[k];
        x[0] = u[1] * v[2] - u[2] * v[1], x[1] = u[2] * v[0] - u[0] * v[2], x[2] = u[0] * v[1] - u[1] * v[0];
        w[j] = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
        sum += w[j];
    }
    double l = 0;
    for (int k = 0; k < 3; k++) {
        n[k] = 0;
        for (int j = 0; j < 3; j++) n[k] += (sum > 0 ? w[j] / sum : 1.0 / 3) * nrm[3 * (size_t)t[j] + k];
        l += n[k] * n[k];
    }
    if (l > 1e-24) for (int k = 0; k < 3; k++) n[k] /= sqrt(l);
    else face_normal(m, f, n);
}

static int cmp_float(const void* a, const void* b) {
    float x = *(const float*)a, y = *(const float*)b;
    return (x > y) - (x < y);
}

// The q-quantile of d[n] (sorted in place): linear between the two nearest order statistics.
static double quantile(float* d, int n, double q) {
    qsort(d, (size_t)n, sizeof(float), cmp_float);
    double at = q * (n - 1);
    int i = (int)at;
    if (i >= n - 1) return d[n - 1];
    return d[i] + (at - i) * ((double)d[i + 1] - d[i]);
}

static double diagonal(const mlb_mesh* m) {
    float lo[3], hi[3];
    mlb_mesh_bounds(m, lo, hi);
    double d2 = 0;
    for (int k = 0; k < 3; k++) d2 += ((double)hi[k] - lo[k]) * ((double)hi[k] - lo[k]);
    return sqrt(d2);
}

// The 95th percentile of the distances from n samples on truth's faces with mask != 0 to the asset.
static mlb_status completeness(const mlb_mesh* truth, const uint8_t* mask, const mlb_mesh_bvh* asset_bvh, int n,
                               uint64_t seed, uint64_t stream, float* p, float* d, double* out) {
    mlb_status s = mlb_mesh_sample_faces(truth, mask, p, NULL, n, seed, stream);
    if (s) return s;
    mlb_mesh_bvh_distance(asset_bvh, p, d, n);
    *out = quantile(d, n, 0.95);
    return MLB_OK;
}

mlb_status mlb_surface_compare(const mlb_mesh* asset, const mlb_mesh* truth, const uint8_t* part, int n_parts, int n,
                               uint64_t seed, mlb_surface_result* r) {
    memset(r, 0, sizeof *r);
    if (n < 2) return mlb_fail(MLB_ERR_ARG, "surface compare: %d samples (at least 2)", n);
    if (n_parts < 0 || n_parts > MLB_SURFACE_MAX_PARTS)
        return mlb_fail(MLB_ERR_ARG, "surface compare: %d parts (at most %d)", n_parts, MLB_SURFACE_MAX_PARTS);
    if (!asset || !truth || asset->n_faces < 1 || truth->n_faces < 1) return mlb_fail(MLB_ERR_ARG, "surface compare: empty mesh");
    for (int k = 0; k < MLB_SURFACE_MAX_PARTS; k++) r->part_completeness[k] = NAN;
    r->diag = diagonal(truth);
    if (!(r->diag > 0)) return mlb_fail(MLB_ERR_ARG, "surface compare: the truth has no extent");
    float* p = malloc(sizeof(float) * 3 * (size_t)n);
    float* d = malloc(sizeof(float) * (size_t)n);
    int32_t* fa = malloc(sizeof(int32_t) * (size_t)n);
    int32_t* ft = malloc(sizeof(int32_t) * (size_t)n);
    uint8_t* mask = part ? malloc((size_t)truth->n_faces) : NULL;
    mlb_mesh shading = *asset;   // its own area-weighted vertex normals, made below
    shading.normal = NULL;
    mlb_mesh_bvh ta, tb;
    memset(&ta, 0, sizeof ta);
    memset(&tb, 0, sizeof tb);
    mlb_status s = p && d && fa && ft && (mask || !part) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "surface compare: out of memory");
    if (!s) s = mlb_mesh_compute_normals(&shading);
    if (!s) s = mlb_mesh_bvh_build(&ta, asset);
    if (!s) s = mlb_mesh_bvh_build(&tb, truth);
    // asset -> truth: the normals' angle and the accuracy
    if (!s) s = mlb_mesh_sample_faces(asset, NULL, p, fa, n, seed, STREAM_SURF_ASSET);
    if (!s) {
        mlb_mesh_bvh_nearest_faces(&tb, p, d, ft, n);
        double sum = 0;
        for (int i = 0; i < n; i++) {
            double na[3], nt[3];
            shading_normal(asset, shading.normal, fa[i], p + 3 * (size_t)i, na);
            face_normal(truth, ft[i] >= 0 ? ft[i] : 0, nt);
            double c = fabs(na[0] * nt[0] + na[1] * nt[1] + na[2] * nt[2]);
            sum += acos(fmin(c, 1.0));   // a degenerate face (no normal): 90 degrees
        }
        r->normal_deg = sum / n * (180.0 / M_PI);
        r->accuracy = quantile(d, n, 0.95) / r->diag;
    }
    // truth -> asset: the completeness, of the whole and of each part
    if (!s) s = completeness(truth, NULL, &ta, n, seed, STREAM_SURF_TRUTH, p, d, &r->completeness);
    if (!s) r->completeness /= r->diag;
    for (int k = 1; !s && part && k <= n_parts; k++) {
        int any = 0;
        for (int f = 0; f < truth->n_faces; f++) any |= mask[f] = part[f] == k;
        if (!any) continue;   // the part is not on this member: NAN
        s = completeness(truth, mask, &ta, n, seed, STREAM_SURF_PART + (uint64_t)k, p, d, &r->part_completeness[k - 1]);
        if (!s) r->part_completeness[k - 1] /= r->diag;
    }
    mlb_mesh_bvh_free(&ta);
    mlb_mesh_bvh_free(&tb);
    free(shading.normal);
    free(p); free(d); free(fa); free(ft); free(mask);
    return s ? mlb_fail_context(s, "surface compare") : MLB_OK;
}
