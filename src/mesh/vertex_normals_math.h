// Area-weighted vertex normals' maths, written once for both devices (MLB_HD, core/hd.h): the
// C loops of mesh/vertex_normals.c and the kernels of cuda/marching_tets.cu run these functions,
// over the scalar `real` the includer defines, without fused multiply-adds (so both give the
// same bits).
//
//   m_v = sum over the faces f at v of (b - a) x (c - a),  normal_v = m_v / |m_v|  ((0,0,1) at |m| = 0)
//   backward: dm_v = (I - N N^T) dN / |m|; per face dn = the sum of dm at its corners, then
//   n = u x w gives du = w x dn, dw = dn x u: corner a gets -(du + dw), b gets du, c gets dw.
//
// The scatter form (a loop over faces adding into the vertices, in face order) and the gather
// form (a loop over vertices reading their faces from the table vertex_faces makes, in face
// order) add the same terms in the same order: the same bits.
#ifndef MATLABER_VERTEX_NORMALS_MATH_H
#define MATLABER_VERTEX_NORMALS_MATH_H
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include "core/hd.h"

MLB_HD real vn_sqrt(real x) { return sizeof(real) == sizeof(float) ? (real)sqrtf((float)x) : (real)sqrt((double)x); }

// The face's edges u = b - a, w = c - a and its area-weighted normal n = u x w.
MLB_HD void vn_face_cross(const real* pos, const int32_t* f, real u[3], real w[3], real n[3]) {
    const real *a = pos + 3 * (size_t)f[0], *b = pos + 3 * (size_t)f[1], *c = pos + 3 * (size_t)f[2];
    for (int d = 0; d < 3; d++) { u[d] = b[d] - a[d]; w[d] = c[d] - a[d]; }
    n[0] = u[1] * w[2] - u[2] * w[1];
    n[1] = u[2] * w[0] - u[0] * w[2];
    n[2] = u[0] * w[1] - u[1] * w[0];
}

// normal (3) of the sum m (3)
MLB_HD void vn_normalize(real* o, const real* m) {
    real len = vn_sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
    if (len > 0) {
        real x = m[0] / len, y = m[1] / len, z = m[2] / len;
        o[0] = x; o[1] = y; o[2] = z;
    } else {
        o[0] = 0; o[1] = 0; o[2] = 1;
    }
}

// dm (3) of vertex v from its sum m (3) and the normal's gradient g (3)
MLB_HD void vn_dm(real* o, const real* m, const real* g) {
    real len = vn_sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
    if (!(len > 0)) { o[0] = o[1] = o[2] = 0; return; }
    real nx = m[0] / len, ny = m[1] / len, nz = m[2] / len;
    real dot = nx * g[0] + ny * g[1] + nz * g[2];
    o[0] = (g[0] - dot * nx) / len;
    o[1] = (g[1] - dot * ny) / len;
    o[2] = (g[2] - dot * nz) / len;
}

// The face's terms for its corners: du, dw from dn (the sum of the corners' dm); corner 0 gets
// -(du + dw), corner 1 du, corner 2 dw.
MLB_HD void vn_face_terms(const real* pos, const int32_t* fv, const real dn[3], real du[3], real dw[3]) {
    real u[3], w[3], n[3];
    vn_face_cross(pos, fv, u, w, n);
    du[0] = w[1] * dn[2] - w[2] * dn[1]; du[1] = w[2] * dn[0] - w[0] * dn[2]; du[2] = w[0] * dn[1] - w[1] * dn[0];
    dw[0] = dn[1] * u[2] - dn[2] * u[1]; dw[1] = dn[2] * u[0] - dn[0] * u[2]; dw[2] = dn[0] * u[1] - dn[1] * u[0];
}
MLB_HD void vn_corner_add(real* dp, int corner, const real du[3], const real dw[3]) {
    for (int d = 0; d < 3; d++) {
        if (corner == 0) dp[d] -= du[d] + dw[d];
        else if (corner == 1) dp[d] += du[d];
        else dp[d] += dw[d];
    }
}

// ---- the gather form: vertex v reads its entries vf[off[v] .. off[v+1]) = 3 f + corner, in face order ----

// sum (3) and normal (3, may be NULL) of vertex v
MLB_HD void vn_gather_normal(real* sum, real* normal, const real* pos, const int32_t* faces, const int32_t* off,
                             const int32_t* vf, int v) {
    real m[3] = {0, 0, 0};
    for (int32_t e = off[v]; e < off[v + 1]; e++) {
        real u[3], w[3], n[3];
        vn_face_cross(pos, faces + 3 * (size_t)(vf[e] / 3), u, w, n);
        for (int d = 0; d < 3; d++) m[d] += n[d];
    }
    if (sum) { sum[0] = m[0]; sum[1] = m[1]; sum[2] = m[2]; }
    if (normal) vn_normalize(normal, m);
}

// dpos (3) of vertex v += its faces' terms; dm recomputed per corner from sum and dnormal
MLB_HD void vn_gather_backward(real* dp, const real* dnormal, const real* sum, const real* pos, const int32_t* faces,
                               const int32_t* off, const int32_t* vf, int v) {
    real acc[3] = {dp[0], dp[1], dp[2]};
    for (int32_t e = off[v]; e < off[v + 1]; e++) {
        const int32_t* fv = faces + 3 * (size_t)(vf[e] / 3);
        real dn[3] = {0, 0, 0}, du[3], dw[3];
        for (int c = 0; c < 3; c++) {
            real dm[3];
            vn_dm(dm, sum + 3 * (size_t)fv[c], dnormal + 3 * (size_t)fv[c]);
            for (int d = 0; d < 3; d++) dn[d] += dm[d];
        }
        vn_face_terms(pos, fv, dn, du, dw);
        vn_corner_add(acc, vf[e] % 3, du, dw);
    }
    dp[0] = acc[0]; dp[1] = acc[1]; dp[2] = acc[2];
}

// The face sharing face f's edge opposite its corner e (vertices f[e+1], f[e+2], mod 3): the lowest
// other face holding both ends (a face holding two distinct vertices has the edge between them),
// -1 on a boundary or a degenerate edge; raster.h mlb_edge_topology's rule, read from the lower
// end's face list (ascending face order, so the first match is the lowest).
MLB_HD int32_t vn_edge_partner(const int32_t* faces, const int32_t* off, const int32_t* vf, int f, int e) {
    int32_t a = faces[3 * (size_t)f + (e + 1) % 3], b = faces[3 * (size_t)f + (e + 2) % 3];
    if (a == b) return -1;
    int32_t lo = a < b ? a : b, hi = a < b ? b : a;
    for (int32_t k = off[lo]; k < off[lo + 1]; k++) {
        int32_t f2 = vf[k] / 3;
        if (f2 == f) continue;
        const int32_t* g = faces + 3 * (size_t)f2;
        if (g[0] == hi || g[1] == hi || g[2] == hi) return f2;
    }
    return -1;
}

#endif
