// Marching tetrahedra over a tet grid (reference.md §3) with backward to the SDF values and the
// (deformed) grid positions, made of the passes of mt_ops.h (src/mesh/mt_ops.c, which the op
// tables run too); the DMTet deformation and the SDF sign regulariser.
// Dual-compiled (float / double _f64), see core/real.h.
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/dmtet.h"
#include "matlaber/mt_ops.h"
#include "core/real.h"


void FN(mt_surface_free)(FN(mlb_mt_surface)* s) {
    if (!s) return;
    free(s->pos);
    free(s->faces);
    free(s->edge);
    free(s->weight);
    memset(s, 0, sizeof *s);
}

mlb_status FN(marching_tets_forward)(FN(mlb_mt_surface)* out, const mlb_tetgrid* g, const real* pos,
                                     const real* sdf) {
    // The passes of mt_ops.h on the host: count, scan (in place), emit. The scans number the
    // vertices in grid-edge order and the faces tet by tet, whatever the thread count.
    memset(out, 0, sizeof *out);
    const int T = g->n_tets;
    const int64_t S = 7 * (int64_t)g->n_verts;   // edge slots
    int32_t* slot_off = malloc(sizeof(int32_t) * ((size_t)S + 1));   // slot -> its vertex
    int32_t* tet_off = malloc(sizeof(int32_t) * ((size_t)T + 1));    // tet -> its first face
    if (!slot_off || !tet_off) {
        free(slot_off);
        free(tet_off);
        return mlb_fail(MLB_ERR_NOMEM, "marching tets: out of memory for %d vertices", g->n_verts);
    }
    FN(mlb_mt_count)(tet_off, slot_off, sdf, g->tets, T, g->cells);
    mlb_scan_i32(tet_off, tet_off, T);
    mlb_scan_i32(slot_off, slot_off, (int)S);
    const int32_t nv = slot_off[S], nf = tet_off[T];   // (at most 2 T and S: within int32 for cells <= 512)
    if (nf > INT32_MAX / 3 || nv > INT32_MAX / 3) {
        free(slot_off);
        free(tet_off);
        return mlb_fail(MLB_ERR_ARG, "marching tets: surface too large (%lld faces)", (long long)nf);
    }
    out->n_verts = nv;
    out->n_faces = nf;
    out->pos = malloc(sizeof(real) * 3 * (size_t)(nv ? nv : 1));
    out->edge = malloc(sizeof(int32_t) * 2 * (size_t)(nv ? nv : 1));
    out->weight = malloc(sizeof(real) * 2 * (size_t)(nv ? nv : 1));
    out->faces = malloc(sizeof(int32_t) * 3 * (size_t)(nf ? nf : 1));
    if (!out->pos || !out->edge || !out->weight || !out->faces) {
        free(slot_off);
        free(tet_off);
        FN(mt_surface_free)(out);
        return mlb_fail(MLB_ERR_NOMEM, "marching tets: out of memory for %d vertices", nv);
    }
    FN(mlb_mt_emit)(out->pos, out->edge, out->weight, out->faces, pos, sdf, g->tets, T, g->cells, tet_off, slot_off);
    free(slot_off);
    free(tet_off);
    return MLB_OK;
}

void FN(marching_tets_backward)(real* dpos, real* dsdf, const FN(mlb_mt_surface)* s, const real* pos,
                                const real* sdf, const real* dverts) {
    FN(mlb_mt_backward)(dpos, dsdf, dverts, s->weight, s->edge, s->n_verts, pos, sdf);
}

mlb_status FN(mt_surface_to_mesh)(const FN(mlb_mt_surface)* s, mlb_mesh* m) {
    memset(m, 0, sizeof *m);
    m->pos = malloc(sizeof(float) * 3 * (size_t)(s->n_verts ? s->n_verts : 1));
    m->faces = malloc(sizeof(int32_t) * 3 * (size_t)(s->n_faces ? s->n_faces : 1));
    if (!m->pos || !m->faces) {
        mlb_mesh_free(m);
        return mlb_fail(MLB_ERR_NOMEM, "marching tets: out of memory for a mesh of %d faces", s->n_faces);
    }
    m->n_verts = s->n_verts;
    m->n_faces = s->n_faces;
    for (size_t i = 0; i < 3 * (size_t)s->n_verts; i++) m->pos[i] = (float)s->pos[i];
    memcpy(m->faces, s->faces, sizeof(int32_t) * 3 * (size_t)s->n_faces);
    return MLB_OK;
}

void FN(dmtet_deform_forward)(real* out, const real* grid, const real* deform, int n_verts, real grid_res) {
    FN(mlb_mt_deform)(out, grid, deform, n_verts, grid_res);
}

void FN(dmtet_deform_backward)(real* dgrid, real* ddeform, const real* dout, const real* deform, int n_verts,
                               real grid_res) {
    FN(mlb_mt_deform_backward)(dgrid, ddeform, dout, deform, n_verts, grid_res);
}

// The SDF sign regulariser: mt_ops.h's, over the grid's size
real FN(sdf_reg_forward)(const mlb_tetgrid* g, const real* sdf) { return FN(mlb_mt_sdf_reg)(sdf, g->cells); }

void FN(sdf_reg_backward)(real* dsdf, const mlb_tetgrid* g, const real* sdf, real dloss) {
    FN(mlb_mt_sdf_reg_backward)(dsdf, sdf, g->cells, dloss);
}

