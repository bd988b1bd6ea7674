// The split-sum shading maths, written once for both devices: the CPU computes it in double
// (src/render/cubemap.c, splitsum_lut.c, shade.c), the GPU in float (src/cuda/shade.cu). Cube-map
// faces and the seamless bilinear lookup with its Jacobian, the mip level of a roughness, the
// prefiltered and irradiance lookups under a rotated light, the split-sum LUT lookup, and one
// shaded point with its backward. Functions over buffers, no state.
//
// The includer picks the scalar: define MLB_SM_SINGLE for float (the GPU), nothing for double.
// Each translation unit includes this once, with one scalar. MLB_HD (core/hd.h) marks the
// functions __host__ __device__ under nvcc, static inline in C.
#ifndef MATLABER_SHADE_MATH_H
#define MATLABER_SHADE_MATH_H
#include <math.h>
#include <stddef.h>
#include "matlaber/envmap.h"   // MLB_CUBE_MAX_LEVELS
#include "matlaber/shade.h"    // MLB_LUT_SIZE
#include "core/hd.h"


#ifdef MLB_SM_SINGLE
typedef float sm_real;
#define SM_FLOOR floorf
#define SM_FABS fabsf
#else
typedef double sm_real;
#define SM_FLOOR floor
#define SM_FABS fabs
#endif

// A light as the lookups see it: the prefiltered levels, the irradiance cube, the split-sum LUT
// (all in the memory of the device that shades) and the world -> map rotation about +y as
// (c, s) = (cos, -sin) of the light's angle.
typedef struct {
    int n_levels;
    int size[MLB_CUBE_MAX_LEVELS];
    const float* spec[MLB_CUBE_MAX_LEVELS];   // [6][size][size][3]
    int irr_size;
    const float* irr;                         // [6][irr_size][irr_size][3]
    const float* lut;                         // [MLB_LUT_SIZE][MLB_LUT_SIZE][2]
    sm_real c, s;
} sm_light;

#ifndef MLB_SM_SINGLE
// The CPU's view of a built light (lut may be NULL when only the cube lookups are wanted). The
// rotation's cos/sin are the cached ones unless `rotation` was assigned directly.
static inline sm_light sm_light_of(const mlb_envlight* light, const float* lut) {
    sm_light L;
    L.n_levels = light->n_levels;
    for (int l = 0; l < MLB_CUBE_MAX_LEVELS; l++) L.size[l] = light->size[l], L.spec[l] = light->spec[l];
    L.irr_size = light->irr_size;
    L.irr = light->irr;
    L.lut = lut;
    if (light->rotation == light->rot_cached) {
        L.c = light->rot_cos;
        L.s = -light->rot_sin;
    } else {
        L.c = cos((double)light->rotation);
        L.s = -sin((double)light->rotation);
    }
    return L;
}
#endif

// ---- cube faces: face f has major axis ma (sign sg), fx along iu (sign su), fy along iv (sign sv).
// Closed forms of the tables {0,0,1,1,2,2}, {1,-1,...}, ... so that device code needs no table.
MLB_HD int sm_ma(int f) { return f >> 1; }
MLB_HD sm_real sm_sg(int f) { return f & 1 ? -1 : 1; }
MLB_HD int sm_iu(int f) { return f < 2 ? 2 : 0; }
MLB_HD sm_real sm_su(int f) { return f == 0 || f == 5 ? -1 : 1; }
MLB_HD int sm_iv(int f) { return f == 2 || f == 3 ? 2 : 1; }
MLB_HD sm_real sm_sv(int f) { return f == 2 ? 1 : -1; }

MLB_HD int sm_clampi(int v, int lo, int hi) { return v < lo ? lo : v > hi ? hi : v; }

MLB_HD int sm_dir_face(const sm_real d[3]) {
    sm_real ax = SM_FABS(d[0]), ay = SM_FABS(d[1]), az = SM_FABS(d[2]);
    if (ax >= ay && ax >= az) return d[0] >= 0 ? 0 : 1;
    if (ay >= az) return d[1] >= 0 ? 2 : 3;
    return d[2] >= 0 ? 4 : 5;
}

MLB_HD const float* sm_texel(const float* cube, int n, int f, int x, int y) {
    return cube + (((size_t)f * n + y) * n + x) * 3;
}

// (x, y) with exactly one coordinate one step outside [0, n): the texel across that edge. The
// point where the texel row meets the cube edge is projected onto the neighbouring face; the
// edge texel there has the same position along the edge (the grids of two faces agree on it).
MLB_HD const float* sm_texel_across(const float* cube, int n, int f, int x, int y) {
    int out_x = x < 0 || x >= n;
    sm_real fx = out_x ? (x < 0 ? (sm_real)-1 : (sm_real)1) : 2 * (x + (sm_real)0.5) / n - 1;
    sm_real fy = out_x ? 2 * (y + (sm_real)0.5) / n - 1 : (y < 0 ? (sm_real)-1 : (sm_real)1);
    sm_real p[3];
    p[sm_ma(f)] = sm_sg(f);
    p[sm_iu(f)] = sm_su(f) * fx;
    p[sm_iv(f)] = sm_sv(f) * fy;
    int ax = out_x ? sm_iu(f) : sm_iv(f);
    int g = 2 * ax + (p[ax] < 0);
    int tx = (int)SM_FLOOR((sm_su(g) * p[sm_iu(g)] + 1) * (sm_real)0.5 * n);
    int ty = (int)SM_FLOOR((sm_sv(g) * p[sm_iv(g)] + 1) * (sm_real)0.5 * n);
    return sm_texel(cube, n, g, sm_clampi(tx, 0, n - 1), sm_clampi(ty, 0, n - 1));
}

// Texel (x, y) of face f, across an edge when outside; at a cube corner the mean of the three
// texels there, written to `corner`.
MLB_HD const float* sm_fetch(const float* cube, int n, int f, int x, int y, float corner[3]) {
    int ix = x >= 0 && x < n, iy = y >= 0 && y < n;
    if (ix && iy) return sm_texel(cube, n, f, x, y);
    if (ix || iy) return sm_texel_across(cube, n, f, x, y);
    int cx = sm_clampi(x, 0, n - 1), cy = sm_clampi(y, 0, n - 1);
    const float* a = sm_texel(cube, n, f, cx, cy);
    const float* b = sm_texel_across(cube, n, f, x, cy);
    const float* c = sm_texel_across(cube, n, f, cx, y);
    for (int k = 0; k < 3; k++) corner[k] = (a[k] + b[k] + c[k]) / 3.0f;
    return corner;
}

// Seamless bilinear lookup of direction d in one cube level [6][n][n][3]; jac (may be NULL):
// d rgb[c] / d d[k]. The zero vector, NaN or Inf give black and a zero Jacobian.
MLB_HD void sm_cube_sample(const float* cube, int n, const sm_real d[3], sm_real rgb[3], sm_real (*jac)[3]) {
    int f = sm_dir_face(d);
    sm_real m = SM_FABS(d[sm_ma(f)]);
    sm_real fx = sm_su(f) * d[sm_iu(f)] / m, fy = sm_sv(f) * d[sm_iv(f)] / m;
    if (!(m > 0) || !(SM_FABS(fx) <= 1) || !(SM_FABS(fy) <= 1)) {
        rgb[0] = rgb[1] = rgb[2] = 0;
        if (jac)
            for (int c = 0; c < 3; c++) jac[c][0] = jac[c][1] = jac[c][2] = 0;
        return;
    }
    sm_real px = (fx + 1) * (sm_real)0.5 * n - (sm_real)0.5, py = (fy + 1) * (sm_real)0.5 * n - (sm_real)0.5;
    sm_real x0f = SM_FLOOR(px), y0f = SM_FLOOR(py), tx = px - x0f, ty = py - y0f;
    int x0 = (int)x0f, y0 = (int)y0f;
    float cb[4][3];
    const float* t00 = sm_fetch(cube, n, f, x0, y0, cb[0]);
    const float* t01 = sm_fetch(cube, n, f, x0 + 1, y0, cb[1]);
    const float* t10 = sm_fetch(cube, n, f, x0, y0 + 1, cb[2]);
    const float* t11 = sm_fetch(cube, n, f, x0 + 1, y0 + 1, cb[3]);
    for (int c = 0; c < 3; c++)
        rgb[c] = (1 - ty) * ((1 - tx) * t00[c] + tx * t01[c]) + ty * ((1 - tx) * t10[c] + tx * t11[c]);
    if (!jac) return;
    // d px / d dir: px = (su d[iu] / |d[ma]| + 1) n/2 - 1/2
    sm_real h = (sm_real)0.5 * n, sg = d[sm_ma(f)] >= 0 ? (sm_real)1 : (sm_real)-1;
    sm_real dpx[3] = {0, 0, 0}, dpy[3] = {0, 0, 0};
    dpx[sm_iu(f)] = h * sm_su(f) / m;
    dpx[sm_ma(f)] = -h * fx * sg / m;
    dpy[sm_iv(f)] = h * sm_sv(f) / m;
    dpy[sm_ma(f)] = -h * fy * sg / m;
    for (int c = 0; c < 3; c++) {
        sm_real gx = (1 - ty) * (t01[c] - t00[c]) + ty * (t11[c] - t10[c]);
        sm_real gy = (1 - tx) * (t10[c] - t00[c]) + tx * (t11[c] - t01[c]);
        for (int k = 0; k < 3; k++) jac[c][k] = gx * dpx[k] + gy * dpy[k];
    }
}

// ---- the light: rotation, mip level, lookups ----------------------------------------------------
// World -> map: d_local = R_y(-rotation) d, with (c, s) = (cos, -sin) of the rotation.
MLB_HD void sm_to_local(sm_real c, sm_real s, const sm_real d[3], sm_real out[3]) {
    out[0] = c * d[0] + s * d[2];
    out[1] = d[1];
    out[2] = -s * d[0] + c * d[2];
}

// A Jacobian in map space back to world space: jac_world = jac_local R.
MLB_HD void sm_jac_to_world(sm_real (*jac)[3], sm_real c, sm_real s) {
    for (int ch = 0; ch < 3; ch++) {
        sm_real j0 = jac[ch][0], j2 = jac[ch][2];
        jac[ch][0] = j0 * c - j2 * s;
        jac[ch][2] = j0 * s + j2 * c;
    }
}

// The (fractional) prefiltered level of roughness r: 0 up to 0.08, linear to level L-2 at 0.5,
// then to the last level (the diffuse-like one) at 1; *dm = d level / d r.
MLB_HD sm_real sm_envlight_mip(int n_levels, sm_real r, sm_real* dm) {
    sm_real l2 = (sm_real)(n_levels - 2), m, d;
    if (!(r > (sm_real)0.08)) {   // (NaN too)
        m = 0;
        d = 0;
    } else if (r < (sm_real)0.5) {
        m = (r - (sm_real)0.08) / (sm_real)0.42 * l2;
        d = l2 / (sm_real)0.42;
    } else {
        m = ((r >= 1 ? (sm_real)1 : r) - (sm_real)0.5) / (sm_real)0.5 + l2;
        d = r < 1 ? (sm_real)2 : (sm_real)0;
    }
    if (dm) *dm = d;
    return m;
}

// Prefiltered radiance around world direction dir at roughness r, trilinear over the levels;
// jac_dir d rgb / d dir and jac_r d rgb / d r when not NULL.
MLB_HD void sm_envlight_specular(const sm_light* L, const sm_real dir[3], sm_real roughness, sm_real rgb[3],
                                 sm_real (*jac_dir)[3], sm_real* jac_r) {
    sm_real d[3], dm;
    sm_to_local(L->c, L->s, dir, d);
    sm_real m = sm_envlight_mip(L->n_levels, roughness, &dm);
    int nl = L->n_levels;
    int m0 = (int)SM_FLOOR(m);
    if (m0 < 0) m0 = 0;
    if (m0 > nl - 1) m0 = nl - 1;
    int m1 = m0 + 1 < nl ? m0 + 1 : m0;
    sm_real t = m0 == m1 ? 0 : m - m0;
    sm_real v0[3], v1[3] = {0, 0, 0}, j0[3][3], j1[3][3];
    sm_cube_sample(L->spec[m0], L->size[m0], d, v0, jac_dir ? j0 : NULL);
    if (m1 != m0) sm_cube_sample(L->spec[m1], L->size[m1], d, v1, jac_dir ? j1 : NULL);
    else v1[0] = v0[0], v1[1] = v0[1], v1[2] = v0[2];
    for (int ch = 0; ch < 3; ch++) rgb[ch] = (1 - t) * v0[ch] + t * v1[ch];
    if (jac_r)
        for (int ch = 0; ch < 3; ch++) jac_r[ch] = m1 != m0 ? (v1[ch] - v0[ch]) * dm : 0;
    if (jac_dir) {
        for (int ch = 0; ch < 3; ch++)
            for (int k = 0; k < 3; k++) jac_dir[ch][k] = m1 != m0 ? (1 - t) * j0[ch][k] + t * j1[ch][k] : j0[ch][k];
        sm_jac_to_world(jac_dir, L->c, L->s);
    }
}

// Cosine-weighted irradiance around world normal n; jac_n d rgb / d n when not NULL.
MLB_HD void sm_envlight_diffuse(const sm_light* L, const sm_real n[3], sm_real rgb[3], sm_real (*jac_n)[3]) {
    sm_real d[3];
    sm_to_local(L->c, L->s, n, d);
    sm_cube_sample(L->irr, L->irr_size, d, rgb, jac_n);
    if (jac_n) sm_jac_to_world(jac_n, L->c, L->s);
}

// The split-sum LUT at (n.v, roughness): b = (scale, bias) of F0, bilinear, clamped to the table;
// the derivatives are zero where the clamp holds the coordinate.
MLB_HD void sm_splitsum_lookup(const float* lut, sm_real nv, sm_real roughness, sm_real b[2], sm_real* db_dnv,
                               sm_real* db_dr) {
    const int n = MLB_LUT_SIZE;
    if (!(nv >= (sm_real)1e-4)) nv = (sm_real)1e-4;   // (NaN too)
    sm_real px = nv * n - (sm_real)0.5, py = roughness * n - (sm_real)0.5;
    int gx = px > 0 && px < n - 1, gy = py > 0 && py < n - 1;   // inside: the gradient is not clamped away
    if (!(px > 0)) px = 0;
    if (px > n - 1) px = n - 1;
    if (!(py > 0)) py = 0;
    if (py > n - 1) py = n - 1;
    int x0 = (int)px, y0 = (int)py;
    if (x0 > n - 2) x0 = n - 2;
    if (y0 > n - 2) y0 = n - 2;
    sm_real tx = px - x0, ty = py - y0;
    const float* r0 = lut + ((size_t)y0 * n + x0) * 2;
    const float* r1 = r0 + (size_t)n * 2;
    for (int k = 0; k < 2; k++) {
        sm_real t00 = r0[k], t01 = r0[2 + k], t10 = r1[k], t11 = r1[2 + k];
        b[k] = (1 - ty) * ((1 - tx) * t00 + tx * t01) + ty * ((1 - tx) * t10 + tx * t11);
        if (db_dnv) db_dnv[k] = gx ? ((1 - ty) * (t01 - t00) + ty * (t11 - t10)) * n : 0;
        if (db_dr) db_dr[k] = gy ? ((1 - tx) * (t10 - t00) + tx * (t11 - t01)) * n : 0;
    }
}

// ---- one shaded point -------------------------------------------------------------------------
// out = kd irr(n) + (F B0 + B1) spec(r, kr), r = 2 (n.v) n - v, F = ks or, with the paper's
// Fresnel, ks + (1 - kr - ks)(1 - n.v)^5 where 1 - kr > ks. With g == NULL only out is computed;
// otherwise the gradients of sum_c g[c] out[c] are added to the non-NULL d* arguments.
MLB_HD void sm_shade_point(const sm_light* L, int paper_fresnel, const sm_real kd[3], const sm_real ks[3], sm_real kr,
                           const sm_real n[3], const sm_real v[3], sm_real out[3], const sm_real* g, sm_real* dkd,
                           sm_real* dks, sm_real* dkr, sm_real* dn, sm_real* dv) {
    sm_real nv = n[0] * v[0] + n[1] * v[1] + n[2] * v[2];
    sm_real nvc = nv < (sm_real)1e-4 ? (sm_real)1e-4 : nv > 1 ? (sm_real)1 : nv;
    sm_real dnvc = nv > (sm_real)1e-4 && nv < 1 ? (sm_real)1 : (sm_real)0;
    sm_real r[3];
    for (int k = 0; k < 3; k++) r[k] = 2 * nv * n[k] - v[k];
    sm_real irr[3], spec[3], jirr[3][3], jsd[3][3], jsr[3], B[2], dBnv[2], dBr[2];
    sm_envlight_diffuse(L, n, irr, g ? jirr : NULL);
    sm_envlight_specular(L, r, kr, spec, g ? jsd : NULL, g ? jsr : NULL);
    sm_splitsum_lookup(L->lut, nv, kr, B, g ? dBnv : NULL, g ? dBr : NULL);
    sm_real x = 1 - nvc, x5 = x * x * x * x * x, dx5 = -5 * x * x * x * x * dnvc;   // d x^5 / d nv
    sm_real d_r[3] = {0, 0, 0}, d_kr = 0, d_nv = 0, dB0 = 0, dB1 = 0, d_n[3] = {0, 0, 0};
    for (int c = 0; c < 3; c++) {
        sm_real f0 = ks[c], F = f0, dF_f0 = 1, dF_kr = 0, dF_nv = 0;
        if (paper_fresnel && 1 - kr > f0) {
            F = f0 + (1 - kr - f0) * x5;
            dF_f0 = 1 - x5;
            dF_kr = -x5;
            dF_nv = (1 - kr - f0) * dx5;
        }
        sm_real sfac = F * B[0] + B[1];
        out[c] = kd[c] * irr[c] + sfac * spec[c];
        if (!g) continue;
        sm_real gc = g[c];
        if (dkd) dkd[c] += gc * irr[c];
        sm_real dirr = gc * kd[c], dspec = gc * sfac, dS = gc * spec[c], dF = dS * B[0];
        for (int k = 0; k < 3; k++) {
            d_n[k] += dirr * jirr[c][k];
            d_r[k] += dspec * jsd[c][k];
        }
        d_kr += dspec * jsr[c] + dF * dF_kr;
        dB0 += dS * F;
        dB1 += dS;
        if (dks) dks[c] += dF * dF_f0;
        d_nv += dF * dF_nv;
    }
    if (!g) return;
    d_nv += dB0 * dBnv[0] + dB1 * dBnv[1];
    d_kr += dB0 * dBr[0] + dB1 * dBr[1];
    if (dkr) *dkr += d_kr;
    sm_real rn = d_r[0] * n[0] + d_r[1] * n[1] + d_r[2] * n[2];   // r = 2 (n.v) n - v
    for (int k = 0; k < 3; k++) {
        if (dn) dn[k] += d_n[k] + 2 * v[k] * rn + 2 * nv * d_r[k] + d_nv * v[k];
        if (dv) dv[k] += 2 * n[k] * rn - d_r[k] + d_nv * n[k];
    }
}

#endif
