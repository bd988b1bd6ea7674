// Baking a material field into kd / ks / roughness textures over a UV atlas: UV-space
// rasterisation with conservative coverage, one batched material evaluation, breadth-first
// dilation. See bake.h.
#include "matlaber/bake.h"
#include <math.h>
#include <stdlib.h>
#include <string.h>

// NaN-free min/max without libm calls (the inputs here are finite or ±INFINITY)
#define MIN2(a, b) ((a) < (b) ? (a) : (b))
#define MAX2(a, b) ((a) > (b) ? (a) : (b))

void mlb_baked_free(mlb_baked* b) {
    if (!b) return;
    free(b->kd);
    free(b->ks);
    free(b->roughness);
    free(b->mask);
    free(b->face);
    memset(b, 0, sizeof *b);
}

// Closest point of segment p→q to c: returns squared distance, *t the parameter in [0,1].
static double seg_closest(const double* p, const double* q, const double* c, double* t) {
    double dx = q[0] - p[0], dy = q[1] - p[1];
    double l2 = dx * dx + dy * dy;
    double s = l2 > 0 ? ((c[0] - p[0]) * dx + (c[1] - p[1]) * dy) / l2 : 0;
    s = s < 0 ? 0 : s > 1 ? 1 : s;
    double ex = p[0] + s * dx - c[0], ey = p[1] + s * dy - c[1];
    *t = s;
    return ex * ex + ey * ey;
}

#define CONSERVATIVE_R 0.7072   // half a texel diagonal (sqrt(2)/2, rounded up)

// The x extent of triangle P (texel units; a segment or a point when degenerate) within rows
// y0 <= y <= y1: the min and max x of its edges clipped to the band. 0 when it misses the band.
static int band_extent(const double P[3][2], double y0, double y1, double* xlo, double* xhi) {
    double lo = INFINITY, hi = -INFINITY;
    for (int i = 0; i < 3; i++) {
        const double *p = P[i], *q = P[(i + 1) % 3];
        double t0 = 0, t1 = 1, dy = q[1] - p[1];
        if (dy != 0) {
            double ta = (y0 - p[1]) / dy, tb = (y1 - p[1]) / dy;
            t0 = MAX2(t0, MIN2(ta, tb));
            t1 = MIN2(t1, MAX2(ta, tb));
        } else if (p[1] < y0 || p[1] > y1) continue;
        if (t0 > t1) continue;
        double xa = p[0] + t0 * (q[0] - p[0]), xb = p[0] + t1 * (q[0] - p[0]);
        lo = MIN2(lo, MIN2(xa, xb));
        hi = MAX2(hi, MAX2(xa, xb));
    }
    *xlo = lo;
    *xhi = hi;
    return lo <= hi;
}

// A uv triangle's corners turned so that the smallest comes first (the winding kept): a face whose
// uv triangle another face already has covers the same texels, and the first face keeps them.
typedef struct { float uv[6]; int32_t face; } uv_key;
static int uv_key_cmp(const void* x, const void* y) {
    const uv_key *a = x, *b = y;
    int c = memcmp(a->uv, b->uv, sizeof a->uv);
    return c ? c : (a->face > b->face) - (a->face < b->face);
}

// Texels visited per texel of the texture (and per face) before baking gives up: UVs stacked this
// many layers deep hold one surface point per texel and many that cannot be seen.
#define BAKE_WORK_PER_TEXEL 64
#define BAKE_WORK_PER_FACE 64

static mlb_status check_bake_args(const mlb_uv_mesh* m, int size, mlb_material_fn fn, const mlb_baked* out) {
    if (!m || !out || !fn) return mlb_fail(MLB_ERR_ARG, "mlb_bake: NULL mesh, output or material function");
    const mlb_mesh* M = &m->mesh;
    if (!M->pos || !M->uv || !M->faces || M->n_verts <= 0 || M->n_faces <= 0)
        return mlb_fail(MLB_ERR_ARG, "mlb_bake: the mesh needs positions, uvs and faces (%d vertices, %d faces)",
                        M->n_verts, M->n_faces);
    if (size < 1 || size > 16384) return mlb_fail(MLB_ERR_ARG, "mlb_bake: texture size %d (need 1..16384)", size);
    for (size_t i = 0; i < 3 * (size_t)M->n_faces; i++)
        if (M->faces[i] < 0 || M->faces[i] >= M->n_verts)
            return mlb_fail(MLB_ERR_ARG, "mlb_bake: face %zu uses vertex %d, mesh has %d", i / 3, (int)M->faces[i], M->n_verts);
    for (size_t i = 0; i < 2 * (size_t)M->n_verts; i++)
        if (!isfinite(M->uv[i])) return mlb_fail(MLB_ERR_ARG, "mlb_bake: vertex %zu has a non-finite uv", i / 2);
    return MLB_OK;
}

// same[f] = 1 when an earlier face has f's uv triangle (uv_key). 0 when out of memory.
static int mark_repeated_uvs(const mlb_mesh* M, uint8_t* same) {
    uv_key* keys = malloc(sizeof *keys * (size_t)M->n_faces);
    if (!keys) return 0;
    for (int f = 0; f < M->n_faces; f++) {
        const int32_t* t = M->faces + 3 * (size_t)f;
        float c[3][2];
        for (int i = 0; i < 3; i++) memcpy(c[i], M->uv + 2 * (size_t)t[i], sizeof c[i]);
        int r = 0;
        for (int i = 1; i < 3; i++)
            if (memcmp(c[i], c[r], sizeof c[i]) < 0) r = i;
        for (int i = 0; i < 3; i++) memcpy(keys[f].uv + 2 * i, c[(r + i) % 3], sizeof c[0]);
        keys[f].face = f;
    }
    qsort(keys, (size_t)M->n_faces, sizeof *keys, uv_key_cmp);
    for (int i = 1; i < M->n_faces; i++) same[keys[i].face] = !memcmp(keys[i].uv, keys[i - 1].uv, sizeof keys[i].uv);
    free(keys);
    return 1;
}

// The texture being rasterised: per texel the distance (texels) to the face that holds it (0: its
// centre is inside), that face and the barycentrics of the texel's point on it.
typedef struct {
    int size;
    float* best;     // [N]
    float* bary;     // [N,3]
    int32_t* face;   // [N], -1 none
} raster;

// Texel (x, y) against face f's texel-space triangle P (twice its signed area area2): inside, it
// goes to the first face that covers its centre; outside but within CONSERVATIVE_R of the
// boundary, to the nearest face, at the closest boundary point.
static void cover_texel(raster* R, const double P[3][2], double area2, int f, int x, int y) {
    double c[2] = {x + 0.5, y + 0.5};
    size_t t = (size_t)y * R->size + x;
    double b[3];
    int inside = 0;
    if (area2 != 0) {
        for (int i = 0; i < 3; i++) {
            const double *p = P[(i + 1) % 3], *q = P[(i + 2) % 3];
            b[i] = ((q[0] - p[0]) * (c[1] - p[1]) - (q[1] - p[1]) * (c[0] - p[0])) / area2;
        }
        inside = b[0] >= 0 && b[1] >= 0 && b[2] >= 0;
    }
    if (inside) {
        if (R->best[t] > 0) {
            R->best[t] = 0;
            R->face[t] = f;
            for (int i = 0; i < 3; i++) R->bary[3 * t + i] = (float)b[i];
        }
        return;
    }
    // outside: the closest point on the boundary
    double dmin = INFINITY, bb[3] = {0, 0, 0};
    for (int i = 0; i < 3; i++) {
        double s;
        double d = seg_closest(P[i], P[(i + 1) % 3], c, &s);
        if (d < dmin) {
            dmin = d;
            bb[0] = bb[1] = bb[2] = 0;
            bb[i] = 1 - s;
            bb[(i + 1) % 3] = s;
        }
    }
    double d = sqrt(dmin);
    if (d <= CONSERVATIVE_R && d < R->best[t]) {
        R->best[t] = (float)d;
        R->face[t] = f;
        for (int i = 0; i < 3; i++) R->bary[3 * t + i] = (float)bb[i];
    }
}

// Face f rasterised in texel coordinates: x = u·size, y = (1 − v)·size; each row over the face's
// own extent in it (a sliver across the texture is a few texels a row, not its bounding box).
// *work counts rows and texels visited; 0 when it passes budget.
static int rasterise_face(raster* R, const mlb_mesh* M, int f, size_t* work, size_t budget) {
    const int size = R->size;
    double P[3][2];
    for (int i = 0; i < 3; i++) {
        int v = M->faces[3 * (size_t)f + i];
        P[i][0] = (double)M->uv[2 * (size_t)v] * size;
        P[i][1] = (1.0 - (double)M->uv[2 * (size_t)v + 1]) * size;
    }
    double area2 = (P[1][0] - P[0][0]) * (P[2][1] - P[0][1]) - (P[2][0] - P[0][0]) * (P[1][1] - P[0][1]);
    double x0 = MIN2(P[0][0], MIN2(P[1][0], P[2][0])) - CONSERVATIVE_R, x1 = MAX2(P[0][0], MAX2(P[1][0], P[2][0])) + CONSERVATIVE_R;
    double y0 = MIN2(P[0][1], MIN2(P[1][1], P[2][1])) - CONSERVATIVE_R, y1 = MAX2(P[0][1], MAX2(P[1][1], P[2][1])) + CONSERVATIVE_R;
    int ix0 = (int)floor(x0 - 0.5), ix1 = (int)ceil(x1 - 0.5), iy0 = (int)floor(y0 - 0.5), iy1 = (int)ceil(y1 - 0.5);
    if (ix0 < 0) ix0 = 0;
    if (iy0 < 0) iy0 = 0;
    if (ix1 > size - 1) ix1 = size - 1;
    if (iy1 > size - 1) iy1 = size - 1;
    for (int y = iy0; y <= iy1; y++) {
        double xlo, xhi;
        (*work)++;
        if (!band_extent(P, y + 0.5 - CONSERVATIVE_R, y + 0.5 + CONSERVATIVE_R, &xlo, &xhi)) continue;
        int rx0 = (int)floor(xlo - CONSERVATIVE_R - 0.5), rx1 = (int)ceil(xhi + CONSERVATIVE_R - 0.5);
        rx0 = MAX2(rx0, ix0);
        rx1 = MIN2(rx1, ix1);
        *work += rx1 >= rx0 ? (size_t)(rx1 - rx0 + 1) : 0;
        if (*work > budget) return 0;
        for (int x = rx0; x <= rx1; x++) cover_texel(R, P, area2, f, x, y);
    }
    return 1;
}

// The covered texels in row-major order (cov [n]) and their surface points (pos [n,3]); sets mask.
static size_t gather_covered(const mlb_mesh* M, const raster* R, mlb_baked* out, int32_t* cov, float* pos) {
    const size_t N = (size_t)R->size * R->size;
    size_t n = 0;
    for (size_t t = 0; t < N; t++) {
        if (out->face[t] < 0) continue;
        const int32_t* fc = M->faces + 3 * (size_t)out->face[t];
        for (int c = 0; c < 3; c++) {
            double p = 0;
            for (int i = 0; i < 3; i++) p += (double)R->bary[3 * t + i] * M->pos[3 * (size_t)fc[i] + c];
            pos[3 * n + c] = (float)p;
        }
        out->mask[t] = 1;
        cov[n++] = (int32_t)t;
    }
    return n;
}

// The material k [n,7] (kd, ks, roughness) into the covered texels; mean [7] its average, which
// the texels no dilation reaches take. Fails on a value that is not finite.
static mlb_status store_material(const float* k, const int32_t* cov, const float* pos, size_t n, mlb_baked* out, double mean[7]) {
    for (int c = 0; c < 7; c++) mean[c] = 0;
    for (size_t i = 0; i < n; i++) {
        for (int c = 0; c < 7; c++) {
            if (!isfinite(k[7 * i + c]))
                return mlb_fail(MLB_ERR_NUMERIC, "mlb_bake: the material is not finite at texel %d (position %g %g %g)",
                                (int)cov[i], (double)pos[3 * i], (double)pos[3 * i + 1], (double)pos[3 * i + 2]);
            mean[c] += k[7 * i + c];
        }
        size_t t = (size_t)cov[i];
        for (int c = 0; c < 3; c++) { out->kd[3 * t + c] = k[7 * i + c]; out->ks[3 * t + c] = k[7 * i + 3 + c]; }
        out->roughness[t] = k[7 * i + 6];
    }
    for (int c = 0; c < 7; c++) mean[c] = n ? mean[c] / n : 0;
    return MLB_OK;
}

// Breadth-first dilation from the n covered texels cov (up to `dilate` texels away; all the way
// when negative, none when 0): a texel takes its first reached neighbour's values. The texels
// left unreached take the mean. queue, dist: scratch [size²].
static void dilate_texels(mlb_baked* out, int size, const int32_t* cov, size_t n, int dilate, const double mean[7],
                          int32_t* queue, int32_t* dist) {
    const size_t N = (size_t)size * size;
    size_t qn = 0;
    for (size_t t = 0; t < N; t++) dist[t] = out->mask[t] ? 0 : -1;
    for (size_t i = 0; i < n; i++) queue[qn++] = cov[i];
    static const int dx[8] = {-1, 1, 0, 0, -1, 1, -1, 1}, dy[8] = {0, 0, -1, 1, -1, -1, 1, 1};
    int n_dil = 0;
    if (dilate != 0)
        for (size_t qi = 0; qi < qn; qi++) {
            int t = queue[qi], x = t % size, y = t / size;
            if (dilate > 0 && dist[t] >= dilate) continue;
            for (int j = 0; j < 8; j++) {
                int xx = x + dx[j], yy = y + dy[j];
                if (xx < 0 || yy < 0 || xx >= size || yy >= size) continue;
                size_t u = (size_t)yy * size + xx;
                if (dist[u] >= 0) continue;
                dist[u] = dist[t] + 1;
                for (int c = 0; c < 3; c++) { out->kd[3 * u + c] = out->kd[3 * (size_t)t + c]; out->ks[3 * u + c] = out->ks[3 * (size_t)t + c]; }
                out->roughness[u] = out->roughness[t];
                out->face[u] = out->face[t];
                queue[qn++] = (int32_t)u;
                n_dil++;
            }
        }
    out->n_dilated = n_dil;
    for (size_t t = 0; t < N; t++) {
        if (dist[t] >= 0) continue;
        for (int c = 0; c < 3; c++) { out->kd[3 * t + c] = (float)mean[c]; out->ks[3 * t + c] = (float)mean[3 + c]; }
        out->roughness[t] = (float)mean[6];
    }
}

mlb_status mlb_bake(const mlb_uv_mesh* m, int size, mlb_material_fn fn, void* user, int dilate, mlb_baked* out) {
    if (out) memset(out, 0, sizeof *out);
    MLB_TRY(check_bake_args(m, size, fn, out));
    const mlb_mesh* M = &m->mesh;
    const size_t N = (size_t)size * size;
    mlb_status st = MLB_OK;
    raster R = {size, malloc(sizeof(float) * N), malloc(sizeof(float) * 3 * N), NULL};
    int32_t* cov = NULL;
    float *pos = NULL, *k = NULL;
    uint8_t* same = calloc((size_t)M->n_faces, 1);   // [F] 1: an earlier face has this uv triangle
    int32_t* queue = NULL;
    int32_t* dist = NULL;
    out->size = size;
    out->kd = malloc(sizeof(float) * 3 * N);
    out->ks = malloc(sizeof(float) * 3 * N);
    out->roughness = malloc(sizeof(float) * N);
    out->mask = calloc(N, 1);
    out->face = malloc(sizeof(int32_t) * N);
    R.face = out->face;
    if (!R.best || !R.bary || !out->kd || !out->ks || !out->roughness || !out->mask || !out->face || !same) goto nomem;
    for (size_t i = 0; i < N; i++) { R.best[i] = INFINITY; out->face[i] = -1; }
    if (!mark_repeated_uvs(M, same)) goto nomem;

    // rasterise every face but those whose uv triangle an earlier face has
    const size_t budget = BAKE_WORK_PER_TEXEL * N + BAKE_WORK_PER_FACE * (size_t)M->n_faces;
    size_t work = 0;
    for (int f = 0; f < M->n_faces; f++)
        if (!same[f] && !rasterise_face(&R, M, f, &work, budget)) {
            st = mlb_fail(MLB_ERR_UNSUPPORTED, "mlb_bake: the faces' UVs lie on one another more than %d layers deep "
                          "in the %d² texture (a texel holds one point of the surface): give the mesh an atlas "
                          "(paint --uv atlas)", BAKE_WORK_PER_TEXEL, size);
            goto done;
        }

    // gather the covered texels, evaluate the material once
    size_t n = 0;
    for (size_t t = 0; t < N; t++) n += out->face[t] >= 0;
    cov = malloc(sizeof *cov * (n ? n : 1));
    pos = malloc(sizeof *pos * 3 * (n ? n : 1));
    k = malloc(sizeof *k * 7 * (n ? n : 1));
    if (!cov || !pos || !k) goto nomem;
    n = gather_covered(M, &R, out, cov, pos);
    out->n_covered = (int)n;
    if (n) {
        st = fn(user, pos, n, k);
        if (st != MLB_OK) { mlb_fail_context(st, "baking"); goto done; }
    }
    double mean[7];
    if ((st = store_material(k, cov, pos, n, out, mean)) != MLB_OK) goto done;

    queue = malloc(sizeof *queue * N);
    dist = malloc(sizeof *dist * N);
    if (!queue || !dist) goto nomem;
    dilate_texels(out, size, cov, n, dilate, mean, queue, dist);
    goto done;

nomem:
    st = mlb_fail(MLB_ERR_NOMEM, "mlb_bake: out of memory for a %d² texture", size);
done:
    if (st != MLB_OK) mlb_baked_free(out);
    free(R.best); free(R.bary); free(cov); free(pos); free(k); free(queue); free(dist); free(same);
    return st;
}

// mlb_bake_codes rides on mlb_bake: the 4 channels travel in kd (3) and ks's first, so coverage,
// points and dilation are mlb_bake's own, not a second copy of them.
typedef struct { mlb_material_fn zfn; void* user; } codes_fn;

static mlb_status codes_as_material(void* user, const float* pos, size_t n, float* k) {
    const codes_fn* c = user;
    float* z = malloc(sizeof(float) * 4 * (n ? n : 1));
    if (!z) return mlb_fail(MLB_ERR_NOMEM, "out of memory for %zu codes", n);
    mlb_status st = c->zfn(c->user, pos, n, z);
    if (st == MLB_OK)
        for (size_t i = 0; i < n; i++) {
            for (int j = 0; j < 4; j++) k[7 * i + j] = z[4 * i + j];
            for (int j = 4; j < 7; j++) k[7 * i + j] = 0;
        }
    free(z);
    return st;
}

mlb_status mlb_bake_codes(const mlb_uv_mesh* m, int size, mlb_material_fn zfn, void* user, int dilate, float* z) {
    if (!zfn || !z) return mlb_fail(MLB_ERR_ARG, "mlb_bake_codes: NULL function or output");
    codes_fn c = {zfn, user};
    mlb_baked b;
    MLB_TRY(mlb_bake(m, size, codes_as_material, &c, dilate, &b));
    for (size_t t = 0; t < (size_t)size * size; t++) {
        for (int j = 0; j < 3; j++) z[4 * t + j] = b.kd[3 * t + j];
        z[4 * t + 3] = b.ks[3 * t];
    }
    mlb_baked_free(&b);
    return MLB_OK;
}
