// Marching tetrahedra's passes (include/matlaber/mt_ops.h): each a loop of the per-element
// functions of marching_tets_math.h, which cuda/marching_tets.cu runs as kernels. Every output has
// a fixed place (the scans give it), so the parallel loops give the same bits on any thread count.
// Dual-compiled (float / double _f64), see core/real.h.
#include <stddef.h>
#include "matlaber/mt_ops.h"
#include "core/real.h"
#include "marching_tets_math.h"

#define MT_PARALLEL_MIN 4096

#ifndef MLB_F64
// In 64 fixed chunks (their sums, the sums' scan, then each chunk's own): integers, so the result is
// the sequential scan's on any thread count. Each chunk reads a value before writing its place, so
// out may be in.
#define SCAN_CHUNKS 64
void mlb_scan_i32(int32_t* out, const int32_t* in, int n) {
    int32_t part[SCAN_CHUNKS];
#pragma omp parallel for schedule(static) if (n >= 16 * MT_PARALLEL_MIN)
    for (int c = 0; c < SCAN_CHUNKS; c++) {
        int32_t s = 0;
        for (int64_t i = (int64_t)n * c / SCAN_CHUNKS; i < (int64_t)n * (c + 1) / SCAN_CHUNKS; i++) s += in[i];
        part[c] = s;
    }
    int32_t total = 0;
    for (int c = 0; c < SCAN_CHUNKS; c++) {
        int32_t s = part[c];
        part[c] = total;
        total += s;
    }
#pragma omp parallel for schedule(static) if (n >= 16 * MT_PARALLEL_MIN)
    for (int c = 0; c < SCAN_CHUNKS; c++) {
        int32_t acc = part[c];
        for (int64_t i = (int64_t)n * c / SCAN_CHUNKS; i < (int64_t)n * (c + 1) / SCAN_CHUNKS; i++) {
            int32_t x = in[i];
            out[i] = acc;
            acc += x;
        }
    }
    out[n] = total;
}
#endif

void FN(mlb_mt_count)(int32_t* tet_nf, int32_t* slot_nv, const real* sdf, const int32_t* tets, int T, int cells) {
    const int n = cells + 1, V = n * n * n;
#pragma omp parallel for schedule(static) if (T >= MT_PARALLEL_MIN)
    for (int t = 0; t < T; t++) tet_nf[t] = mt_num_tri(mt_case(sdf, tets + 4 * (size_t)t));
#pragma omp parallel for schedule(static) if (V >= MT_PARALLEL_MIN)
    for (int v = 0; v < V; v++) mt_count_slots(slot_nv, sdf, v, n);
}

void FN(mlb_mt_emit)(real* verts, int32_t* vedge, real* weight, int32_t* faces, const real* pos, const real* sdf,
                     const int32_t* tets, int T, int cells, const int32_t* tet_off, const int32_t* slot_off) {
    const int n = cells + 1, V = n * n * n;
#pragma omp parallel for schedule(static) if (V >= MT_PARALLEL_MIN)
    for (int v = 0; v < V; v++) mt_emit_slots(verts, vedge, weight, pos, sdf, v, n, slot_off);
#pragma omp parallel for schedule(static) if (T >= MT_PARALLEL_MIN)
    for (int t = 0; t < T; t++) {
        int cnt = tet_off[t + 1] - tet_off[t];
        if (!cnt) continue;
        const int32_t* tv = tets + 4 * (size_t)t;
        mt_emit_faces(faces, tv, mt_case(sdf, tv), tet_off[t], cnt, slot_off, n);
    }
}

void FN(mlb_mt_backward)(real* dpos, real* dsdf, const real* dverts, const real* weight, const int32_t* vedge, int nv,
                         const real* pos, const real* sdf) {
    // Sequential: output vertices share grid vertices, and a fixed order keeps results exact.
    for (int i = 0; i < nv; i++) {
        int32_t a = vedge[2 * i], b = vedge[2 * i + 1];
        const real* gv = dverts + 3 * (size_t)i;
        if (dpos)
            for (int d = 0; d < 3; d++) {
                dpos[3 * (size_t)a + d] += weight[2 * i] * gv[d];
                dpos[3 * (size_t)b + d] += weight[2 * i + 1] * gv[d];
            }
        if (dsdf) {
            real ta, tb;
            mt_sdf_terms(&ta, &tb, gv, pos, sdf, a, b);
            dsdf[a] += ta;
            dsdf[b] -= tb;
        }
    }
}

void FN(mlb_mt_backward_gather)(real* dpos, real* dsdf, const real* dverts, const real* weight, const real* pos,
                                const real* sdf, const int32_t* slot_off, int cells) {
    const int n = cells + 1, V = n * n * n;
#pragma omp parallel for schedule(static) if (V >= MT_PARALLEL_MIN)
    for (int v = 0; v < V; v++) mt_backward_vertex(dpos, dsdf, v, dverts, weight, pos, sdf, slot_off, n);
}

// ---- DMTet's deformation and the SDF sign regulariser ----
#define MT_CHUNKS 64   // fixed reduction shards: sums do not depend on the thread count

void FN(mlb_mt_deform)(real* out, const real* grid, const real* deform, int n_verts, real grid_res) {
    size_t n = 3 * (size_t)n_verts;
#pragma omp parallel for schedule(static) if (n >= MT_PARALLEL_MIN)
    for (size_t i = 0; i < n; i++) out[i] = grid[i] + R_TANH(deform[i]) / grid_res;
}

void FN(mlb_mt_deform_backward)(real* dgrid, real* ddeform, const real* dout, const real* deform, int n_verts,
                                real grid_res) {
    size_t n = 3 * (size_t)n_verts;
#pragma omp parallel for schedule(static) if (n >= MT_PARALLEL_MIN)
    for (size_t i = 0; i < n; i++) {
        if (dgrid) dgrid[i] += dout[i];
        if (ddeform) {
            real th = R_TANH(deform[i]);
            ddeform[i] += dout[i] * (1 - th * th) / grid_res;
        }
    }
}

// ---- SDF sign regulariser: evaluated per vertex over its (up to 14) grid neighbours, so both the
// loss and the gradient are gathers (no scatter), in a fixed order. ----
static real FN(sdf_reg_sum)(const real* sdf, int cells, int64_t* n_edges) {
    const int V = (cells + 1) * (cells + 1) * (cells + 1);
    double part[MT_CHUNKS];
    int64_t cnt[MT_CHUNKS];
#pragma omp parallel for schedule(static) if (V >= MT_PARALLEL_MIN)
    for (int c = 0; c < MT_CHUNKS; c++) {
        int lo = (int)((int64_t)V * c / MT_CHUNKS), hi = (int)((int64_t)V * (c + 1) / MT_CHUNKS);
        double s = 0;
        int64_t m = 0;
        for (int v = lo; v < hi; v++) {
            int nl;
            s += mt_reg_terms(sdf, v, cells, 0, &nl);
            m += nl;
        }
        part[c] = s;
        cnt[c] = m;
    }
    double s = 0;
    int64_t m = 0;
    for (int c = 0; c < MT_CHUNKS; c++) { s += part[c]; m += cnt[c]; }
    *n_edges = m;
    return (real)s;
}

real FN(mlb_mt_sdf_reg)(const real* sdf, int cells) {
    int64_t m;
    real s = FN(sdf_reg_sum)(sdf, cells, &m);
    return m ? s / (real)m : 0;
}

void FN(mlb_mt_sdf_reg_backward)(real* dsdf, const real* sdf, int cells, real dloss) {
    int64_t m;
    FN(sdf_reg_sum)(sdf, cells, &m);   // the edge count (the loss is a mean over edges)
    if (!m) return;
    real scale = dloss / (real)m;
    const int V = (cells + 1) * (cells + 1) * (cells + 1);
#pragma omp parallel for schedule(static) if (V >= MT_PARALLEL_MIN)
    for (int v = 0; v < V; v++) {
        int nl;
        dsdf[v] += scale * mt_reg_terms(sdf, v, cells, 1, &nl);
    }
}
