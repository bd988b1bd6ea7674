// Marching tetrahedra's maths, written once for both devices (MLB_HD, core/hd.h): the C passes of
// mesh/mt_ops.c and the kernels of cuda/marching_tets.cu run these same functions, one element
// (tet, edge slot, grid vertex) at a time, over the scalar `real` the includer defines.
//
// Edge slots: a grid of n = cells + 1 vertices per axis, vertex (i, j, k) = i + n (j + n k), has
// its edges from a = (i, j, k) to a + (di, dj, dk), (di, dj, dk) in {0,1}^3 \ {0}. Slot
// s = 7 a + code - 1, code = di + 2 dj + 4 dk (mlb_tetgrid_edge_id's sparse id), names each; a slot
// whose far end leaves the grid is no edge. Slots increase with the grid's edge order (g->edges:
// by a, then code), so an exclusive scan of per-slot 0/1 counts numbers the surface's vertices in
// that order: the scan is the map from an edge to its vertex.
#ifndef MATLABER_MARCHING_TETS_MATH_H
#define MATLABER_MARCHING_TETS_MATH_H
#include <stdint.h>
#include "core/hd.h"

// The tables of reference.md §3 (mlb_mt_num_triangles, mlb_mt_triangle_table, mlb_mt_tet_edges in
// geometry/tetgrid.c, which test_dmtet checks these against), packed into integer constants so
// that neither device needs a table in memory: 2 bits per case, 3 bits per triangle-table entry.
#define MT_NUM_TRI 0x16696994u
#define MT_ROW(a, b, c, d, e, f)                                                                     \
    ((uint32_t)(a) | (uint32_t)(b) << 3 | (uint32_t)(c) << 6 | (uint32_t)(d) << 9 | (uint32_t)(e) << 12 | \
     (uint32_t)(f) << 15)
MLB_HD int mt_num_tri(int occ) { return (int)((MT_NUM_TRI >> (2 * occ)) & 3u); }
MLB_HD uint32_t mt_row(int occ) {
    switch (occ) {
    case 1: return MT_ROW(1, 0, 2, 0, 0, 0);
    case 2: return MT_ROW(4, 0, 3, 0, 0, 0);
    case 3: return MT_ROW(1, 4, 2, 1, 3, 4);
    case 4: return MT_ROW(3, 1, 5, 0, 0, 0);
    case 5: return MT_ROW(2, 3, 0, 2, 5, 3);
    case 6: return MT_ROW(1, 4, 0, 1, 5, 4);
    case 7: return MT_ROW(4, 2, 5, 0, 0, 0);
    case 8: return MT_ROW(4, 5, 2, 0, 0, 0);
    case 9: return MT_ROW(4, 1, 0, 4, 5, 1);
    case 10: return MT_ROW(3, 2, 0, 3, 5, 2);
    case 11: return MT_ROW(1, 3, 5, 0, 0, 0);
    case 12: return MT_ROW(4, 1, 2, 4, 3, 1);
    case 13: return MT_ROW(3, 0, 4, 0, 0, 0);
    case 14: return MT_ROW(2, 0, 1, 0, 0, 0);
    default: return 0;   // 0 and 15: no triangle
    }
}
MLB_HD int mt_row_entry(uint32_t row, int i) { return (int)((row >> (3 * i)) & 7u); }
// The corners of the tet's local edge e (0..5): {0,1} {0,2} {0,3} {1,2} {1,3} {2,3}
MLB_HD int mt_edge_lo(int e) { return (int)((0x940u >> (2 * e)) & 3u); }
MLB_HD int mt_edge_hi(int e) { return (int)((0xFB9u >> (2 * e)) & 3u); }

// The tet's case: bit i set when corner i is outside (sdf > 0).
MLB_HD int mt_case(const real* sdf, const int32_t* tv) {
    return (sdf[tv[0]] > 0) | ((sdf[tv[1]] > 0) << 1) | ((sdf[tv[2]] > 0) << 2) | ((sdf[tv[3]] > 0) << 3);
}

// The slot of the grid edge (a, b) (either order; a grid edge, as every tet edge is).
MLB_HD int64_t mt_slot_of(int32_t a, int32_t b, int n) {
    if (a > b) { int32_t t = a; a = b; b = t; }
    int di = b % n - a % n, dj = (b / n) % n - (a / n) % n, dk = b / (n * n) - a / (n * n);
    return 7 * (int64_t)a + (di | (dj << 1) | (dk << 2)) - 1;
}
// The ends a < b of slot s; 0 when the slot is no edge of the grid.
MLB_HD int mt_slot_ends(int64_t s, int n, int32_t* a, int32_t* b) {
    int32_t v = (int32_t)(s / 7);
    int code = (int)(s % 7) + 1;
    int i = v % n, j = (v / n) % n, k = v / (n * n);
    int di = code & 1, dj = (code >> 1) & 1, dk = (code >> 2) & 1;
    if (i + di >= n || j + dj >= n || k + dk >= n) return 0;
    *a = v;
    *b = v + di + n * (dj + n * dk);
    return 1;
}
// The counts of grid vertex v's seven slots (v their lower end), slot_nv[7 v .. 7 v + 6]: 1 on an
// edge whose ends differ in occupancy (it carries a surface vertex), else 0 (no edge past the side).
MLB_HD void mt_count_slots(int32_t* slot_nv, const real* sdf, int32_t v, int n) {
    int i = v % n, j = (v / n) % n, k = v / (n * n);
    int out = sdf[v] > 0;
    for (int code = 1; code < 8; code++) {
        int di = code & 1, dj = (code >> 1) & 1, dk = (code >> 2) & 1;
        int32_t c = 0;
        if (i + di < n && j + dj < n && k + dk < n) c = (sdf[v + di + n * (dj + n * dk)] > 0) != out;
        slot_nv[7 * (int64_t)v + code - 1] = c;
    }
}

// Surface vertex k on the edge (a, b): v = w_a p_a + w_b p_b, w_a = -s_b / (s_a - s_b),
// w_b = s_a / (s_a - s_b). verts [., 3], vedge [., 2], weight [., 2].
MLB_HD void mt_emit_vertex(real* verts, int32_t* vedge, real* weight, const real* pos, const real* sdf, int32_t a,
                           int32_t b, int32_t k) {
    real sa = sdf[a], sb = sdf[b], den = sa - sb;
    real wa = -sb / den, wb = sa / den;
    weight[2 * (size_t)k] = wa;
    weight[2 * (size_t)k + 1] = wb;
    vedge[2 * (size_t)k] = a;
    vedge[2 * (size_t)k + 1] = b;
    for (int d = 0; d < 3; d++) verts[3 * (size_t)k + d] = wa * pos[3 * (size_t)a + d] + wb * pos[3 * (size_t)b + d];
}
// The surface vertices on grid vertex v's seven slots, each at its scanned place.
MLB_HD void mt_emit_slots(real* verts, int32_t* vedge, real* weight, const real* pos, const real* sdf, int32_t v, int n,
                          const int32_t* slot_off) {
    for (int code = 1; code < 8; code++) {
        int64_t s = 7 * (int64_t)v + code - 1;
        int32_t k = slot_off[s];
        if (slot_off[s + 1] == k) continue;   // no vertex (or no edge: counted 0)
        int di = code & 1, dj = (code >> 1) & 1, dk = (code >> 2) & 1;
        mt_emit_vertex(verts, vedge, weight, pos, sdf, v, v + di + n * (dj + n * dk), k);
    }
}
// The cnt faces of the tet with corners tv and case occ, from face `first` on, in table order;
// each corner is the vertex of its edge's slot (slot_off: the exclusive scan of the slot counts).
MLB_HD void mt_emit_faces(int32_t* faces, const int32_t* tv, int occ, int32_t first, int cnt, const int32_t* slot_off,
                          int n) {
    uint32_t row = mt_row(occ);
    for (int c = 0; c < 3 * cnt; c++) {
        int e = mt_row_entry(row, c);
        faces[3 * (size_t)first + c] = slot_off[mt_slot_of(tv[mt_edge_lo(e)], tv[mt_edge_hi(e)], n)];
    }
}

// The SDF gradient of a surface vertex on (a, b) for its gradient g[3]: v = (s_a p_b - s_b p_a)/D,
// D = s_a - s_b, so dv/ds_a = s_b (p_a - p_b)/D^2 and dv/ds_b = s_a (p_b - p_a)/D^2:
// ds_a += *ta, ds_b -= *tb.
MLB_HD void mt_sdf_terms(real* ta, real* tb, const real* g, const real* pos, const real* sdf, int32_t a, int32_t b) {
    real sa = sdf[a], sb = sdf[b], den = sa - sb, inv2 = 1 / (den * den);
    real dot = 0;
    for (int d = 0; d < 3; d++) dot += g[d] * (pos[3 * (size_t)a + d] - pos[3 * (size_t)b + d]);
    *ta = sb * dot * inv2;
    *tb = sa * dot * inv2;
}

// The backward gathered at grid vertex v (the GPU's form: no two threads write one value): the
// terms of every surface vertex on an edge of v, added in increasing vertex order, which is the
// order the CPU's pass over the surface vertices adds them in, so the sums are its bits. The
// vertices of v's edges: those whose lower end u < v (slots below 7v) first, then v's own seven.
MLB_HD void mt_backward_vertex(real* dpos, real* dsdf, int32_t v, const real* dverts, const real* weight,
                               const real* pos, const real* sdf, const int32_t* slot_off, int n) {
    int64_t slot[14];
    int m = 0;
    int i = v % n, j = (v / n) % n, k = v / (n * n);
    for (int code = 1; code < 8; code++) {   // v as the upper end, in increasing slot order
        int di = code & 1, dj = (code >> 1) & 1, dk = (code >> 2) & 1;
        if (i < di || j < dj || k < dk) continue;
        int64_t s = 7 * (int64_t)(v - (di + n * (dj + n * dk))) + code - 1;
        int p = m++;
        while (p > 0 && slot[p - 1] > s) { slot[p] = slot[p - 1]; p--; }
        slot[p] = s;
    }
    for (int code = 1; code < 8; code++) {   // v as the lower end
        int di = code & 1, dj = (code >> 1) & 1, dk = (code >> 2) & 1;
        if (i + di < n && j + dj < n && k + dk < n) slot[m++] = 7 * (int64_t)v + code - 1;
    }
    real acc[3] = {0, 0, 0}, as = 0;
    if (dpos)
        for (int d = 0; d < 3; d++) acc[d] = dpos[3 * (size_t)v + d];
    if (dsdf) as = dsdf[v];
    for (int q = 0; q < m; q++) {
        int32_t kv = slot_off[slot[q]];
        if (slot_off[slot[q] + 1] == kv) continue;   // no surface vertex on this edge
        int32_t a = v, b = v;
        mt_slot_ends(slot[q], n, &a, &b);   // (a listed slot is an edge)
        const real* g = dverts + 3 * (size_t)kv;
        if (dpos) {
            real w = weight[2 * (size_t)kv + (v == a ? 0 : 1)];
            for (int d = 0; d < 3; d++) acc[d] += w * g[d];
        }
        if (dsdf) {
            real ta, tb;
            mt_sdf_terms(&ta, &tb, g, pos, sdf, a, b);
            if (v == a) as += ta;
            else as -= tb;
        }
    }
    if (dpos)
        for (int d = 0; d < 3; d++) dpos[3 * (size_t)v + d] = acc[d];
    if (dsdf) dsdf[v] = as;
}

// ---- the SDF sign regulariser, per grid vertex (geometry/marching_tets.c sdf_reg_*): over v's
// (up to 14) grid neighbours u whose occupancy (sdf > 0) differs from v's, the BCE of s_v against
// occ_u (grad = 0) or its derivative sigmoid(s_v) - occ_u (grad = 1), added in a fixed order;
// *n_lower counts the edges with v as the lower end (each edge once). The includer defines
// R_EXP, R_LOG1P, R_FABS for its `real` (core/real.h does). ----
MLB_HD real mt_bce_logits(real x, real t) { return (x > 0 ? x : 0) - x * t + R_LOG1P(R_EXP(-R_FABS(x))); }
MLB_HD real mt_reg_terms(const real* sdf, int v, int cells, int grad, int* n_lower) {
    const int n = cells + 1;
    int i = v % n, j = (v / n) % n, k = v / (n * n);
    real sv = sdf[v], acc = 0;
    int ov = sv > 0, cnt = 0;
    for (int code = 1; code < 8; code++) {
        int di = code & 1, dj = (code >> 1) & 1, dk = (code >> 2) & 1;
        for (int dir = 1; dir >= -1; dir -= 2) {
            int ii = i + dir * di, jj = j + dir * dj, kk = k + dir * dk;
            if (ii < 0 || jj < 0 || kk < 0 || ii >= n || jj >= n || kk >= n) continue;
            int u = ii + n * (jj + n * kk);
            int ou = sdf[u] > 0;
            if (ou == ov) continue;
            if (dir > 0) cnt++;
            if (grad) acc += 1 / (1 + R_EXP(-sv)) - (real)ou;
            else acc += mt_bce_logits(sv, (real)ou);
        }
    }
    *n_lower = cnt;
    return acc;
}

#endif
