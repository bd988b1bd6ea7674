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
