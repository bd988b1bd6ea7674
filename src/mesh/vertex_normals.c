// Area-weighted vertex normals and their backward (include/matlaber/mt_ops.h), in two forms over
// the maths of vertex_normals_math.h: the scatter form (a loop over the faces, sequential) and the
// gather form of the op tables (a loop over the vertices reading the faces vertex_faces lists at
// each, in face order; parallel, and what the CUDA kernels run). Both add the same terms in the
// same order, so they give the same bits (test_dmtet). Dual-compiled (float / double _f64), see
// core/real.h.
#include <stdlib.h>
#include <string.h>
#include "matlaber/error.h"
#include "matlaber/mt_ops.h"
#include "core/real.h"
#include "vertex_normals_math.h"

#define VN_PARALLEL_MIN 4096

void FN(vertex_normals_forward)(real* normal, real* sum, const real* pos, int n_verts, const int32_t* faces,
                                int n_faces) {
    real* m = sum ? sum : normal;   // accumulate in place when no cache is wanted
    memset(m, 0, sizeof(real) * 3 * (size_t)n_verts);
    for (int f = 0; f < n_faces; f++) {
        real u[3], w[3], n[3];
        vn_face_cross(pos, faces + 3 * (size_t)f, u, w, n);
        for (int c = 0; c < 3; c++)
            for (int d = 0; d < 3; d++) m[3 * (size_t)faces[3 * (size_t)f + c] + d] += n[d];
    }
    for (int v = 0; v < n_verts; v++) vn_normalize(normal + 3 * (size_t)v, m + 3 * (size_t)v);
}

mlb_status FN(vertex_normals_backward)(real* dpos, const real* dnormal, const real* sum, const real* pos, int n_verts,
                                       const int32_t* faces, int n_faces) {
    real* dm = malloc(sizeof(real) * 3 * (size_t)(n_verts ? n_verts : 1));
    if (!dm) return mlb_fail(MLB_ERR_NOMEM, "vertex normals: out of memory for %d vertices", n_verts);
    for (int v = 0; v < n_verts; v++) vn_dm(dm + 3 * (size_t)v, sum + 3 * (size_t)v, dnormal + 3 * (size_t)v);
    for (int f = 0; f < n_faces; f++) {
        const int32_t* fv = faces + 3 * (size_t)f;
        real dn[3] = {0, 0, 0}, du[3], dw[3];
        for (int c = 0; c < 3; c++)
            for (int d = 0; d < 3; d++) dn[d] += dm[3 * (size_t)fv[c] + d];
        vn_face_terms(pos, fv, dn, du, dw);
        for (int c = 0; c < 3; c++) vn_corner_add(dpos + 3 * (size_t)fv[c], c, du, dw);
    }
    free(dm);
    return MLB_OK;
}

#ifndef MLB_F64
mlb_status mlb_vertex_faces(int32_t* off, int32_t* vf, const int32_t* faces, int n_faces, int n_verts) {
    if (n_faces < 0 || n_verts < 0 || (int64_t)n_faces * 3 > INT32_MAX)
        return mlb_fail(MLB_ERR_ARG, "vertex_faces: %d faces, %d vertices", n_faces, n_verts);
    for (int64_t i = 0; i < 3 * (int64_t)n_faces; i++)
        if (faces[i] < 0 || faces[i] >= n_verts)
            return mlb_fail(MLB_ERR_ARG, "vertex_faces: face %lld names vertex %d of %d", (long long)(i / 3),
                            (int)faces[i], n_verts);
    memset(off, 0, sizeof(int32_t) * ((size_t)n_verts + 1));
    for (int64_t i = 0; i < 3 * (int64_t)n_faces; i++) off[faces[i] + 1]++;
    for (int v = 0; v < n_verts; v++) off[v + 1] += off[v];
    // off[v] serves as v's cursor while filling (face order: the loop's), then shifts back by one vertex
    for (int64_t i = 0; i < 3 * (int64_t)n_faces; i++) vf[off[faces[i]]++] = (int32_t)i;
    for (int v = n_verts; v > 0; v--) off[v] = off[v - 1];
    off[0] = 0;
    return MLB_OK;
}

void mlb_edge_partners(int32_t* adj, const int32_t* faces, int n_faces, const int32_t* off, const int32_t* vf) {
#pragma omp parallel for schedule(static) if (n_faces >= VN_PARALLEL_MIN)
    for (int f = 0; f < n_faces; f++)
        for (int e = 0; e < 3; e++) adj[3 * (size_t)f + e] = vn_edge_partner(faces, off, vf, f, e);
}
#endif

void FN(mlb_vertex_normals)(real* normal, real* sum, const real* pos, int n_verts, const int32_t* faces,
                            const int32_t* off, const int32_t* vf) {
#pragma omp parallel for schedule(static) if (n_verts >= VN_PARALLEL_MIN)
    for (int v = 0; v < n_verts; v++)
        vn_gather_normal(sum ? sum + 3 * (size_t)v : NULL, normal + 3 * (size_t)v, pos, faces, off, vf, v);
}

void FN(mlb_vertex_normals_backward)(real* dpos, const real* dnormal, const real* sum, const real* pos, int n_verts,
                                     const int32_t* faces, const int32_t* off, const int32_t* vf) {
    if (!dpos) return;
#pragma omp parallel for schedule(static) if (n_verts >= VN_PARALLEL_MIN)
    for (int v = 0; v < n_verts; v++)
        vn_gather_backward(dpos + 3 * (size_t)v, dnormal, sum, pos, faces, off, vf, v);
}
