// Cube maps for the split-sum environment light (reference.md §2): conventions, the base cube
// from a lat-long map, the 2x2-average mip chain, the GGX prefilter of every level, the diffuse
// irradiance cube, and seamless trilinear lookups with gradients.
//
// Prefilter cost. Summing every texel of the 99% cone is ~1e10 kernel evaluations for a 512²
// cube (at roughness 0.08 the cone is 0.125 rad, ~3000 texels, around each of 1.6M texels). The
// sum here walks a quadtree over each face instead (a pyramid of the source level whose nodes
// carry summed texel weight, summed weight x radiance and the luminance centroid of their light):
// a node is taken whole when it is far from the lobe centre against its size (angle >=
// accuracy x its angular radius) or small against the lobe (radius <= 0.1 alpha), skipped when it
// lies wholly outside the cone, opened otherwise. A whole node's weight uses the kernel at its
// weight centroid, its light the kernel at the light's centroid (a node holding a small sun is
// weighted where the sun is). Every texel is covered exactly once, so a constant map stays
// constant. The cut is made once per 8x8 tile of output texels, conservatively for all of them,
// into a flat list that each texel of the tile then sums in a vectorised loop. Levels of 32² and
// less are summed exactly. Cost and accuracy against the exact sum: docs/lighting.md.
#include "matlaber/envmap.h"
#include <math.h>
#include <omp.h>
#include <stdlib.h>
#include <string.h>
#include "render/shade_math.h"

#define PI 3.14159265358979323846

// Face f: major axis MA (sign SG), fx along axis IU (sign SU), fy along axis IV (sign SV). The build
// side reads them here; the lookups use their closed forms in render/shade_math.h (shared with the GPU).
static const int MA[6] = {0, 0, 1, 1, 2, 2};
static const double SG[6] = {1, -1, 1, -1, 1, -1};
static const int IU[6] = {2, 2, 0, 0, 0, 0};
static const double SU[6] = {-1, 1, 1, 1, 1, -1};
static const int IV[6] = {1, 1, 2, 2, 1, 1};
static const double SV[6] = {-1, -1, 1, -1, -1, -1};

static void face_point(int f, double fx, double fy, double p[3]) {
    p[MA[f]] = SG[f];
    p[IU[f]] = SU[f] * fx;
    p[IV[f]] = SV[f] * fy;
}

static void normalize3(double d[3]) {
    double l = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (l > 0) d[0] /= l, d[1] /= l, d[2] /= l;
}

void mlb_cube_texel_dir(int face, double x, double y, int n, double dir[3]) {
    face_point(face, 2 * (x + 0.5) / n - 1, 2 * (y + 0.5) / n - 1, dir);
    normalize3(dir);
}

double mlb_cube_texel_solid_angle(int x, int y, int n) {
    if (n < 2) return 4 * PI / 6;
    int H = n / 2;
    double ax = abs(x - H), ay = abs(y - H);
    return (atan((ax + 1) / H) - atan(ax / H)) * (atan((ay + 1) / H) - atan(ay / H));
}

// Solid angle of the face rectangle [0, x] x [0, y] seen from the centre, signed (x, y in face units).
static double sa_rect(double x, double y) { return atan2(x * y, sqrt(x * x + y * y + 1)); }

double mlb_cube_texel_solid_angle_exact(int x, int y, int n) {
    double x0 = 2.0 * x / n - 1, x1 = 2.0 * (x + 1) / n - 1, y0 = 2.0 * y / n - 1, y1 = 2.0 * (y + 1) / n - 1;
    return sa_rect(x1, y1) - sa_rect(x0, y1) - sa_rect(x1, y0) + sa_rect(x0, y0);
}

static double texel_weight(int x, int y, int n, int exact_sa) {
    return exact_sa ? mlb_cube_texel_solid_angle_exact(x, y, n) : mlb_cube_texel_solid_angle(x, y, n);
}

void mlb_cube_dir_to_texel(const double dir[3], int n, int* face, double* x, double* y) {
    int f = sm_dir_face(dir);
    double m = fabs(dir[MA[f]]);
    if (m == 0) m = 1;
    *face = f;
    *x = (SU[f] * dir[IU[f]] / m + 1) * 0.5 * n - 0.5;
    *y = (SV[f] * dir[IV[f]] / m + 1) * 0.5 * n - 0.5;
}

// The seamless lookup is the shading maths' (render/shade_math.h), shared with the GPU.
void mlb_cube_sample(const float* cube, int n, const double d[3], double rgb[3], double jac[3][3]) {
    sm_cube_sample(cube, n, d, rgb, jac);
}

// ---------------------------------------------------------------- building

mlb_status mlb_cube_from_envmap(float* cube, int n, const mlb_envmap* env) {
    if (!cube || n < 1) return mlb_fail(MLB_ERR_ARG, "mlb_cube_from_envmap: bad cube (face size %d)", n);
    MLB_TRY(mlb_envmap_validate(env));
    mlb_envmap flat = *env;   // the rotation is applied at lookup time, never baked in
    flat.rotation = 0;
    // Sub-samples per texel side: enough that the lat-long pixels (pi/h rad) are not skipped.
    int ss = (int)ceil(2.0 * env->h / (PI * n));
    if (ss < 1) ss = 1;
    if (ss > 8) ss = 8;
#pragma omp parallel for schedule(dynamic, 4)
    for (int row = 0; row < 6 * n; row++) {
        int f = row / n, y = row % n;
        for (int x = 0; x < n; x++) {
            double acc[3] = {0, 0, 0};
            for (int a = 0; a < ss; a++)
                for (int b = 0; b < ss; b++) {
                    double d[3], v[3];
                    mlb_cube_texel_dir(f, x - 0.5 + (b + 0.5) / ss, y - 0.5 + (a + 0.5) / ss, n, d);
                    mlb_envmap_lookup(&flat, d, v);
                    for (int c = 0; c < 3; c++) acc[c] += v[c];
                }
            float* o = cube + (((size_t)f * n + y) * n + x) * 3;
            for (int c = 0; c < 3; c++) o[c] = (float)(acc[c] / (ss * ss));
        }
    }
    return MLB_OK;
}

static void pool2x2(float* dst, const float* src, int n) {   // src n x n faces -> dst n/2
    int m = n / 2;
#pragma omp parallel for schedule(static)
    for (int row = 0; row < 6 * m; row++) {
        int f = row / m, y = row % m;
        for (int x = 0; x < m; x++)
            for (int c = 0; c < 3; c++)
                dst[(((size_t)f * m + y) * m + x) * 3 + c] =
                    0.25f * (sm_texel(src, n, f, 2 * x, 2 * y)[c] + sm_texel(src, n, f, 2 * x + 1, 2 * y)[c] +
                             sm_texel(src, n, f, 2 * x, 2 * y + 1)[c] + sm_texel(src, n, f, 2 * x + 1, 2 * y + 1)[c]);
    }
}

// Half-angle of the cone around r that holds `cutoff` of the prefilter weight
// max(cos t, 0) D(h) over the sphere (t = angle between l and r, the half vector at t/2).
static double cone_angle(double a2, double cutoff) {
    enum { M = 200000 };
    double step = (PI / 2) / M, total = 0;
    double* cum = malloc((M + 1) * sizeof *cum);
    if (!cum) return PI / 2;
    cum[0] = 0;
    for (int i = 0; i < M; i++) {
        double t = (i + 0.5) * step, s2 = sin(t / 2) * sin(t / 2), den = s2 + a2 * (1 - s2);
        total += cos(t) * sin(t) / (den * den);
        cum[i + 1] = total;
    }
    double target = cutoff * total, angle = PI / 2;
    for (int i = 0; i < M; i++)
        if (cum[i + 1] >= target) {
            angle = (i + (target - cum[i]) / (cum[i + 1] - cum[i])) * step;
            break;
        }
    free(cum);
    return angle;
}

// The quadtree. Geometry is shared by the six faces: per position, the unit centre direction in
// face-local form (a, b, c) = (fx, fy, 1) / |(fx, fy, 1)| and the summed texel weight om. Levels
// above the texels also carry, per face, the summed om x radiance and the luminance centroid of
// their light: the kernel for the radiance is evaluated there (a node holding a small sun is
// weighted where the sun is, not at the node's centre), the kernel for the normalising weight at
// the geometric centre, so a constant map stays exactly constant.
typedef struct { double a, b, c, wa, wb, wc, om; } geo;   // centre, weight centroid (unit, face-local), om
typedef struct { float dl[3], ol[3]; } lnode;


static void geo_dir(const geo* g, int f, double d[3]) {   // world direction of a node centre on face f
    d[MA[f]] = SG[f] * g->c;
    d[IU[f]] = SU[f] * g->a;
    d[IV[f]] = SV[f] * g->b;
}

static void geo_wdir(const geo* g, int f, double d[3]) {   // ... and of its weight centroid
    d[MA[f]] = SG[f] * g->wc;
    d[IU[f]] = SU[f] * g->wa;
    d[IV[f]] = SV[f] * g->wb;
}

#define CORE 0.1   // nodes of radius <= CORE alpha are small against the lobe anywhere

// Interaction list of one tile of output texels: the tree cut that is valid for every texel of
// the tile. "Fine" entries are source texels (centre, om, om x radiance); "coarse" entries are
// nodes (geometric centre and om for the weight, light centroid and om x radiance for the light).
// Structure of arrays, so that the per-texel loops over it vectorise.
enum { F_X, F_Y, F_Z, F_OM, F_R, F_G, F_B, F_N };
enum { C_X, C_Y, C_Z, C_OM, C_LX, C_LY, C_LZ, C_R, C_G, C_B, C_N };
typedef struct {
    float* f[F_N];
    float* c[C_N];
    int nf, nc, capf, capc;
} ilist;

static int ilist_grow(float** a, int na, int* cap, int need) {
    if (need <= *cap) return 1;
    int nc = *cap ? *cap : 1024;
    while (nc < need) nc *= 2;
    for (int k = 0; k < na; k++) {
        float* p = realloc(a[k], (size_t)nc * sizeof(float));
        if (!p) return 0;
        a[k] = p;
    }
    *cap = nc;
    return 1;
}

static void ilist_free(ilist* l) {
    for (int k = 0; k < F_N; k++) free(l->f[k]);
    for (int k = 0; k < C_N; k++) free(l->c[k]);
}

// The weighted sums for one output texel direction r over a tile's list: acc = (sum w om,
// sum w om L). Blocks of 64 entries are summed in float (vectorised), the blocks in double.
// (Compiled without trapping math so that the masked loops vectorise.)
enum { BLOCK = 64 };
__attribute__((optimize("no-trapping-math"), target_clones("avx2", "default"))) static void tile_sums(const ilist* il, float rx, float ry,
                                                                                                     float rz, float fa2, float cos_cut,
                                                                                                     double acc[4]) {
    double sw = 0, sr = 0, sg = 0, sb = 0;
    const float *X = il->f[F_X], *Y = il->f[F_Y], *Z = il->f[F_Z], *OM = il->f[F_OM];
    const float *R = il->f[F_R], *Gc = il->f[F_G], *B = il->f[F_B];
    for (int k0 = 0; k0 < il->nf; k0 += BLOCK) {
        int k1 = k0 + BLOCK < il->nf ? k0 + BLOCK : il->nf;
        float aw = 0, ar = 0, ag = 0, ab = 0;
#pragma omp simd reduction(+ : aw, ar, ag, ab)
        for (int k = k0; k < k1; k++) {
            float dx = X[k] - rx, dy = Y[k] - ry, dz = Z[k] - rz, d2 = dx * dx + dy * dy + dz * dz;
            float c = 1 - 0.5f * d2, s2 = 0.25f * d2, den = s2 + fa2 * (1 - s2);
            float w = c / (den * den);
            w = c >= cos_cut ? w : 0.0f;
            aw += w * OM[k], ar += w * R[k], ag += w * Gc[k], ab += w * B[k];
        }
        sw += aw, sr += ar, sg += ag, sb += ab;
    }
    const float *CX = il->c[C_X], *CY = il->c[C_Y], *CZ = il->c[C_Z], *COM = il->c[C_OM];
    const float *LX = il->c[C_LX], *LY = il->c[C_LY], *LZ = il->c[C_LZ];
    const float *CR = il->c[C_R], *CG = il->c[C_G], *CB = il->c[C_B];
    for (int k0 = 0; k0 < il->nc; k0 += BLOCK) {
        int k1 = k0 + BLOCK < il->nc ? k0 + BLOCK : il->nc;
        float aw = 0, ar = 0, ag = 0, ab = 0;
#pragma omp simd reduction(+ : aw, ar, ag, ab)
        for (int k = k0; k < k1; k++) {
            float dx = CX[k] - rx, dy = CY[k] - ry, dz = CZ[k] - rz, d2 = dx * dx + dy * dy + dz * dz;
            float c = 1 - 0.5f * d2, s2 = 0.25f * d2, den = s2 + fa2 * (1 - s2);
            float ex = LX[k] - rx, ey = LY[k] - ry, ez = LZ[k] - rz, e2 = ex * ex + ey * ey + ez * ez;
            float cl = 1 - 0.5f * e2, t2 = 0.25f * e2, dl = t2 + fa2 * (1 - t2);
            float g2 = den * den, l2 = dl * dl, inv = 1 / (g2 * l2);   // one division for both kernels
            float wg = c * l2 * inv * COM[k], wl = cl * g2 * inv;
            aw += c >= cos_cut ? wg : 0.0f;
            wl = cl >= cos_cut ? wl : 0.0f;
            ar += wl * CR[k], ag += wl * CG[k], ab += wl * CB[k];
        }
        sw += aw, sr += ar, sg += ag, sb += ab;
    }
    acc[0] = sw, acc[1] = sr, acc[2] = sg, acc[3] = sb;
}

// The quadtree of one specular level: level 0 holds the n x n texels, each level above halves the
// side, up to an odd side, a side of 1 or MAXJ levels. G[j] [s][s] the geometry of level j (shared
// by the faces), T[j] [6][s][s] the light of levels j >= 1.
enum { MAXJ = 16, TILE = 8 };
typedef struct {
    geo* G[MAXJ];
    lnode* T[MAXJ];
    int size[MAXJ], J;
} qtree;

static void tree_free(qtree* q) {
    for (int j = 0; j < q->J; j++) free(q->G[j]), free(q->T[j]);
}

static mlb_status tree_alloc(qtree* q, int n) {
    for (int s = n;; s /= 2) {
        int J = q->J;
        q->size[J] = s;
        q->G[J] = malloc((size_t)s * s * sizeof(geo));
        if (J > 0) q->T[J] = malloc((size_t)6 * s * s * sizeof(lnode));
        q->J++;
        if (!q->G[J] || (J > 0 && !q->T[J])) return mlb_fail(MLB_ERR_NOMEM, "cube prefilter: cannot allocate a %dx%d tree level", s, s);
        if (s % 2 || s == 1 || q->J == MAXJ) break;
    }
    return MLB_OK;
}

// Level j's geometry: the centres, and the summed texel weight and weight centroid of the texels
// below (level 0: each texel's own).
static void tree_geometry(qtree* q, int j, int exact_sa) {
    int s = q->size[j];
    for (int y = 0; y < s; y++)
        for (int x = 0; x < s; x++) {
            geo* g = q->G[j] + (size_t)y * s + x;
            double fx = 2 * (x + 0.5) / s - 1, fy = 2 * (y + 0.5) / s - 1, len = sqrt(fx * fx + fy * fy + 1);
            g->a = fx / len, g->b = fy / len, g->c = 1 / len;
            if (j == 0) {
                g->om = texel_weight(x, y, s, exact_sa);
                g->wa = g->a, g->wb = g->b, g->wc = g->c;
            } else {
                const geo* ch = q->G[j - 1] + (size_t)2 * y * 2 * s + 2 * x;
                const geo* k4[4] = {ch, ch + 1, ch + 2 * s, ch + 2 * s + 1};
                double w[3] = {0, 0, 0};
                g->om = 0;
                for (int c = 0; c < 4; c++) {
                    g->om += k4[c]->om;
                    w[0] += k4[c]->om * k4[c]->wa, w[1] += k4[c]->om * k4[c]->wb, w[2] += k4[c]->om * k4[c]->wc;
                }
                normalize3(w);
                g->wa = w[0], g->wb = w[1], g->wc = w[2];
            }
        }
}

// Level j's light (j >= 1), per face, from its four children: the summed om x radiance and the
// luminance centroid (the node's centre when it holds no light).
static void tree_light(qtree* q, int j, const float* src) {
    int s = q->size[j];
#pragma omp parallel for schedule(static)
    for (int row = 0; row < 6 * s; row++) {
        int f = row / s, y = row % s;
        for (int x = 0; x < s; x++) {
            double ol[3] = {0, 0, 0}, cen[3] = {0, 0, 0}, wsum = 0;
            for (int c = 0; c < 4; c++) {
                int cx = 2 * x + (c & 1), cy = 2 * y + (c >> 1), cs = 2 * s;
                double dl[3], o[3];
                if (j == 1) {
                    const geo* g = q->G[0] + (size_t)cy * cs + cx;
                    const float* l = sm_texel(src, cs, f, cx, cy);
                    geo_dir(g, f, dl);
                    for (int k = 0; k < 3; k++) o[k] = g->om * l[k];
                } else {
                    const lnode* ch = q->T[j - 1] + ((size_t)f * cs + cy) * cs + cx;
                    for (int k = 0; k < 3; k++) dl[k] = ch->dl[k], o[k] = ch->ol[k];
                }
                double w = 0.2126 * o[0] + 0.7152 * o[1] + 0.0722 * o[2];
                wsum += w;
                for (int k = 0; k < 3; k++) ol[k] += o[k], cen[k] += w * dl[k];
            }
            if (!(wsum > 0)) geo_dir(q->G[j] + (size_t)y * s + x, f, cen);
            normalize3(cen);
            lnode* o = q->T[j] + ((size_t)f * s + y) * s + x;
            for (int k = 0; k < 3; k++) o->dl[k] = (float)cen[k], o->ol[k] = (float)ol[k];
        }
    }
}

// The centre cen of the tile of `tile` x `tile` output texels at (x0, y0) of face f of an n x n
// level, and its angular radius (to its farthest corner).
static double tile_bounds(int f, int x0, int y0, int tile, int n, double cen[3]) {
    double rt = 0;
    face_point(f, (2.0 * x0 + tile) / n - 1, (2.0 * y0 + tile) / n - 1, cen);
    normalize3(cen);
    for (int c = 0; c < 4; c++) {
        double cr[3];
        face_point(f, 2.0 * (x0 + (c & 1) * tile) / n - 1, 2.0 * (y0 + (c >> 1) * tile) / n - 1, cr);
        normalize3(cr);
        double a = acos(fmin(1, cen[0] * cr[0] + cen[1] * cr[1] + cen[2] * cr[2]));
        if (a > rt) rt = a;
    }
    return rt;
}

// The tile's interaction list: the cut of every face's tree around the tile centre cen, a node
// pruned when its centre's cosine to cen is below cos_prune of its level, opened when above
// cos_open, taken whole otherwise. 0 when the list could not grow (the walk goes on without it).
static int tile_list(ilist* il, const qtree* q, const float* src, const double cen[3], const double* cos_prune,
                     const double* cos_open) {
    int stack[4 * MAXJ + 64][4];
    int top = q->J - 1, ts = q->size[top], ok = 1;
    il->nf = il->nc = 0;
    for (int g = 0; g < 6; g++) {
        double rf[3] = {SU[g] * cen[IU[g]], SV[g] * cen[IV[g]], SG[g] * cen[MA[g]]};
        for (int root = 0; root < ts * ts; root++) {
            int sp = 0;
            stack[sp][0] = top, stack[sp][1] = root % ts, stack[sp][2] = root / ts, sp++;
            while (sp) {
                sp--;
                int j = stack[sp][0], nx = stack[sp][1], ny = stack[sp][2], s = q->size[j];
                const geo* ge = q->G[j] + (size_t)ny * s + nx;
                double c = ge->a * rf[0] + ge->b * rf[1] + ge->c * rf[2];
                if (c < cos_prune[j]) continue;
                if (c > cos_open[j]) {
                    for (int ch = 3; ch >= 0; ch--) {
                        stack[sp][0] = j - 1, stack[sp][1] = 2 * nx + (ch & 1), stack[sp][2] = 2 * ny + (ch >> 1);
                        sp++;
                    }
                    continue;
                }
                double d[3];
                geo_dir(ge, g, d);
                if (j == 0) {
                    if (!ilist_grow(il->f, F_N, &il->capf, il->nf + 1)) { ok = 0; continue; }
                    const float* l = sm_texel(src, s, g, nx, ny);
                    int k = il->nf++;
                    il->f[F_X][k] = (float)d[0], il->f[F_Y][k] = (float)d[1], il->f[F_Z][k] = (float)d[2];
                    il->f[F_OM][k] = (float)ge->om;
                    il->f[F_R][k] = (float)(ge->om * l[0]), il->f[F_G][k] = (float)(ge->om * l[1]);
                    il->f[F_B][k] = (float)(ge->om * l[2]);
                } else {
                    geo_wdir(ge, g, d);   // the weight at the texels' weight centroid
                    if (!ilist_grow(il->c, C_N, &il->capc, il->nc + 1)) { ok = 0; continue; }
                    const lnode* nd = q->T[j] + ((size_t)g * s + ny) * s + nx;
                    int k = il->nc++;
                    il->c[C_X][k] = (float)d[0], il->c[C_Y][k] = (float)d[1], il->c[C_Z][k] = (float)d[2];
                    il->c[C_OM][k] = (float)ge->om;
                    il->c[C_LX][k] = nd->dl[0], il->c[C_LY][k] = nd->dl[1], il->c[C_LZ][k] = nd->dl[2];
                    il->c[C_R][k] = nd->ol[0], il->c[C_G][k] = nd->ol[1], il->c[C_B][k] = nd->ol[2];
                }
            }
        }
    }
    return ok;
}

// Each output texel of the tile: its weighted mean radiance over the tile's list.
static void tile_shade(float* out, const ilist* il, const qtree* q, int f, int x0, int y0, int tile, float fa2, float cos_cut) {
    int n = q->size[0];
    for (int y = y0; y < y0 + tile; y++)
        for (int x = x0; x < x0 + tile; x++) {
            double rd[3];
            geo_dir(q->G[0] + (size_t)y * n + x, f, rd);
            double acc[4];
            tile_sums(il, (float)rd[0], (float)rd[1], (float)rd[2], fa2, cos_cut, acc);
            double aw = acc[0], ar = acc[1], ag = acc[2], ab = acc[3];
            float* o = out + (((size_t)f * n + y) * n + x) * 3;
            o[0] = aw > 0 ? (float)(ar / aw) : 0, o[1] = aw > 0 ? (float)(ag / aw) : 0, o[2] = aw > 0 ? (float)(ab / aw) : 0;
        }
}

// One specular level: src and out are [6][n][n][3].
static mlb_status prefilter(float* out, const float* src, int n, double rough, double cutoff, double accuracy, int exact,
                            int exact_sa) {
    qtree q = {0};
    mlb_status st = tree_alloc(&q, n);
    if (st != MLB_OK) goto done;
    for (int j = 0; j < q.J; j++) {
        tree_geometry(&q, j, exact_sa);
        if (j > 0) tree_light(&q, j, src);
    }
    double alpha = rough * rough, a2 = alpha * alpha;
    double cone = cone_angle(a2, cutoff);
    float cos_cut = (float)cos(cone), fa2 = (float)a2;
    double rho[MAXJ];
    int whole[MAXJ];   // 1: nodes of this level are taken whole wherever they are
    for (int j = 0; j < q.J; j++) {
        rho[j] = sqrt(2.0) / q.size[j];   // bound on a node's angular radius
        whole[j] = j == 0 || (!exact && rho[j] <= CORE * alpha);
    }
    int tile = n < TILE ? n : TILE, nt = n / tile;
    int fail = 0;
#pragma omp parallel
    {
        ilist il = {0};
#pragma omp for schedule(dynamic, 1)
        for (int tid = 0; tid < 6 * nt * nt; tid++) {
            int f = tid / (nt * nt), ty = tid / nt % nt, tx = tid % nt;
            int x0 = tx * tile, y0 = ty * tile;
            double cen[3];
            double rt = tile_bounds(f, x0, y0, tile, n, cen);
            // per level: prune when the node lies outside the cone for every texel of the tile
            // (angle > cone + rho + rt); open when it is not far enough for some texel
            // (angle - rt < accuracy rho) unless its level is taken whole
            double cos_prune[MAXJ], cos_open[MAXJ];
            for (int j = 0; j < q.J; j++) {
                double ap = cone + rho[j] + rt, ao = accuracy * rho[j] + rt;
                cos_prune[j] = ap >= PI ? -2 : cos(ap);
                cos_open[j] = whole[j] ? 2 : exact || ao >= PI ? -2 : cos(ao);
            }
            if (!tile_list(&il, &q, src, cen, cos_prune, cos_open)) {
#pragma omp atomic write
                fail = 1;
            }
            int failed;
#pragma omp atomic read
            failed = fail;
            if (failed) continue;
            tile_shade(out, &il, &q, f, x0, y0, tile, fa2, cos_cut);
        }
        ilist_free(&il);
    }
    if (fail) st = mlb_fail(MLB_ERR_NOMEM, "cube prefilter: cannot allocate an interaction list");
done:
    tree_free(&q);
    return st;
}

static mlb_status irradiance(float* out, const float* src, int n, int exact_sa) {
    size_t nt = (size_t)6 * n * n;
    double* dir = malloc(nt * 4 * sizeof *dir);
    if (!dir) return mlb_fail(MLB_ERR_NOMEM, "environment light: cannot allocate the irradiance directions");
    for (int f = 0; f < 6; f++)
        for (int y = 0; y < n; y++)
            for (int x = 0; x < n; x++) {
                double* p = dir + (((size_t)f * n + y) * n + x) * 4;
                mlb_cube_texel_dir(f, x, y, n, p);
                p[3] = texel_weight(x, y, n, exact_sa);
            }
#pragma omp parallel for schedule(static)
    for (size_t i = 0; i < nt; i++) {
        const double* nr = dir + i * 4;
        double acc[3] = {0, 0, 0}, wsum = 0;
        for (size_t k = 0; k < nt; k++) {
            const double* l = dir + k * 4;
            double c = nr[0] * l[0] + nr[1] * l[1] + nr[2] * l[2];
            if (c <= 0) continue;
            double w = c * l[3];
            wsum += w;
            for (int ch = 0; ch < 3; ch++) acc[ch] += w * src[k * 3 + ch];
        }
        for (int ch = 0; ch < 3; ch++) out[i * 3 + ch] = (float)(acc[ch] / wsum);
    }
    free(dir);
    return MLB_OK;
}

void mlb_envlight_free(mlb_envlight* light) {
    if (!light) return;
    for (int i = 0; i < MLB_CUBE_MAX_LEVELS; i++) free(light->spec[i]);
    free(light->irr);
    memset(light, 0, sizeof *light);
}

mlb_status mlb_envlight_build(mlb_envlight* light, const mlb_envmap* env, const mlb_envlight_options* opt) {
    if (!light || !env) return mlb_fail(MLB_ERR_ARG, "mlb_envlight_build: NULL argument");
    memset(light, 0, sizeof *light);
    mlb_envlight_options o = {512, 16, 0.99f, 3.0f, 0, 0};
    int exact_solid_angle = 1;   // true solid angles unless reference_weights asks otherwise
    if (opt) {
        if (opt->face_size) o.face_size = opt->face_size;
        if (opt->min_size) o.min_size = opt->min_size;
        if (opt->cutoff != 0) o.cutoff = opt->cutoff;
        if (opt->accuracy != 0) o.accuracy = opt->accuracy;
        o.exact = opt->exact;
        exact_solid_angle = !opt->reference_weights;
    }
    if (o.min_size < 2 || o.min_size % 2 || o.min_size > 8192)
        return mlb_fail(MLB_ERR_ARG, "environment light: min_size %d must be even and in [2, 8192]", o.min_size);
    if (o.face_size < 1 || o.face_size > 8192)
        return mlb_fail(MLB_ERR_ARG, "environment light: face size %d must be in [1, 8192]", o.face_size);
    int L = 1;
    while ((o.min_size << (L - 1)) < o.face_size && L < MLB_CUBE_MAX_LEVELS) L++;
    if ((o.min_size << (L - 1)) != o.face_size || L < 3)
        return mlb_fail(MLB_ERR_ARG, "environment light: face size %d must be min_size (%d) times a power of two >= 4 (at most 2^%d)",
                        o.face_size, o.min_size, MLB_CUBE_MAX_LEVELS - 1);
    if (!(o.cutoff > 0 && o.cutoff <= 1)) return mlb_fail(MLB_ERR_ARG, "environment light: cutoff %g must be in (0, 1]", o.cutoff);
    if (!(o.accuracy >= 1 && o.accuracy <= 1e3))
        return mlb_fail(MLB_ERR_ARG, "environment light: accuracy %g must be in [1, 1000]", o.accuracy);
    MLB_TRY(mlb_envmap_validate(env));
    float* mip[MLB_CUBE_MAX_LEVELS] = {0};
    mlb_status st = MLB_OK;
    light->n_levels = L;
    for (int i = 0; i < L; i++) {
        int s = o.face_size >> i;
        light->size[i] = s;
        light->roughness[i] = i == L - 1 ? 1.0f : (float)(0.08 + (double)i / (L - 2) * (0.5 - 0.08));
        mip[i] = malloc((size_t)6 * s * s * 3 * sizeof(float));
        light->spec[i] = malloc((size_t)6 * s * s * 3 * sizeof(float));
        if (!mip[i] || !light->spec[i]) {
            st = mlb_fail(MLB_ERR_NOMEM, "environment light: cannot allocate a %dx%d cube", s, s);
            goto fail;
        }
    }
    light->irr_size = o.min_size;
    light->irr = malloc((size_t)6 * o.min_size * o.min_size * 3 * sizeof(float));
    if (!light->irr) {
        st = mlb_fail(MLB_ERR_NOMEM, "environment light: cannot allocate the irradiance cube");
        goto fail;
    }
    if ((st = mlb_cube_from_envmap(mip[0], o.face_size, env)) != MLB_OK) goto fail;
    for (int i = 1; i < L; i++) pool2x2(mip[i], mip[i - 1], light->size[i - 1]);
    if ((st = irradiance(light->irr, mip[L - 1], o.min_size, exact_solid_angle)) != MLB_OK) goto fail;
    for (int i = 0; i < L; i++) {
        double rough = light->roughness[i] == 1.0f ? 1.0 : 0.08 + (double)i / (L - 2) * (0.5 - 0.08);
        light->cone[i] = (float)cone_angle(rough * rough * rough * rough, o.cutoff);
        // Levels of 32^2 and less are summed exactly: cheap (<= 2e7 kernel evaluations), and the
        // roughest levels are where a node's midpoint weight would be least accurate.
        st = prefilter(light->spec[i], mip[i], light->size[i], rough, o.cutoff, o.accuracy, o.exact || light->size[i] <= 32,
                       exact_solid_angle);
        if (st != MLB_OK) goto fail;
    }
    for (int i = 0; i < L; i++) free(mip[i]);
    mlb_envlight_set_rotation(light, env->rotation);
    return MLB_OK;
fail:
    for (int i = 0; i < L; i++) free(mip[i]);
    mlb_envlight_free(light);
    return mlb_fail_context(st, "%s", env->name);
}

void mlb_envlight_set_rotation(mlb_envlight* light, float radians) {
    light->rotation = radians;
    light->rot_cached = radians;
    light->rot_cos = cos((double)radians);
    light->rot_sin = sin((double)radians);
}

// ---------------------------------------------------------------- lookups

double mlb_envlight_mip(const mlb_envlight* light, double r, double* dmip_dr) {
    return sm_envlight_mip(light->n_levels, r, dmip_dr);
}

void mlb_envlight_specular(const mlb_envlight* light, const double dir[3], double roughness, double rgb[3], double jac_dir[3][3],
                           double jac_r[3]) {
    sm_light L = sm_light_of(light, NULL);
    sm_envlight_specular(&L, dir, roughness, rgb, jac_dir, jac_r);
}

void mlb_envlight_diffuse(const mlb_envlight* light, const double n[3], double rgb[3], double jac_n[3][3]) {
    sm_light L = sm_light_of(light, NULL);
    sm_envlight_diffuse(&L, n, rgb, jac_n);
}
