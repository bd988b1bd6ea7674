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

// ---- vertex normals: sequential scatters over faces (cheap next to the rest, and exact order) ----
static void face_cross(const real* pos, const int32_t* f, real u[3], real w[3], real n[3]) {
    const real *a = pos + 3 * (size_t)f[0], *b = pos + 3 * (size_t)f[1], *c = pos + 3 * (size_t)f[2];
    for (int d = 0; d < 3; d++) { u[d] = b[d] - a[d]; w[d] = c[d] - a[d]; }
    n[0] = u[1] * w[2] - u[2] * w[1];
    n[1] = u[2] * w[0] - u[0] * w[2];
    n[2] = u[0] * w[1] - u[1] * w[0];
}

void FN(vertex_normals_forward)(real* normal, real* sum, const real* pos, int n_verts, const int32_t* faces,
                                int n_faces) {
    real* m = sum ? sum : normal;   // accumulate in place when no cache is wanted
    memset(m, 0, sizeof(real) * 3 * (size_t)n_verts);
    for (int f = 0; f < n_faces; f++) {
        real u[3], w[3], n[3];
        face_cross(pos, faces + 3 * (size_t)f, u, w, n);
        for (int c = 0; c < 3; c++)
            for (int d = 0; d < 3; d++) m[3 * (size_t)faces[3 * (size_t)f + c] + d] += n[d];
    }
    for (int v = 0; v < n_verts; v++) {
        const real* mv = m + 3 * (size_t)v;
        real len = R_SQRT(mv[0] * mv[0] + mv[1] * mv[1] + mv[2] * mv[2]);
        real* o = normal + 3 * (size_t)v;
        if (len > 0) {
            real x = mv[0] / len, y = mv[1] / len, z = mv[2] / len;
            o[0] = x; o[1] = y; o[2] = z;
        } else {
            o[0] = 0; o[1] = 0; o[2] = 1;
        }
    }
}

mlb_status FN(vertex_normals_backward)(real* dpos, const real* dnormal, const real* sum, const real* pos, int n_verts,
                                 const int32_t* faces, int n_faces) {
    // dm_v = (I − N Nᵀ) dN / |m|, then per face dn = Σ_corners dm, and n = u × w gives
    // du = w × dn, dw = dn × u; a gets −(du + dw), b gets du, c gets dw.
    real* dm = malloc(sizeof(real) * 3 * (size_t)(n_verts ? n_verts : 1));
    if (!dm) return mlb_fail(MLB_ERR_NOMEM, "vertex normals: out of memory for %d vertices", n_verts);
    for (int v = 0; v < n_verts; v++) {
        const real* mv = sum + 3 * (size_t)v;
        const real* g = dnormal + 3 * (size_t)v;
        real len = R_SQRT(mv[0] * mv[0] + mv[1] * mv[1] + mv[2] * mv[2]);
        real* o = dm + 3 * (size_t)v;
        if (!(len > 0)) { o[0] = o[1] = o[2] = 0; continue; }
        real nx = mv[0] / len, ny = mv[1] / len, nz = mv[2] / len;
        real dot = nx * g[0] + ny * g[1] + nz * g[2];
        o[0] = (g[0] - dot * nx) / len;
        o[1] = (g[1] - dot * ny) / len;
        o[2] = (g[2] - dot * nz) / len;
    }
    for (int f = 0; f < n_faces; f++) {
        const int32_t* fv = faces + 3 * (size_t)f;
        real u[3], w[3], n[3], dn[3] = {0, 0, 0};
        face_cross(pos, fv, u, w, n);
        for (int c = 0; c < 3; c++)
            for (int d = 0; d < 3; d++) dn[d] += dm[3 * (size_t)fv[c] + d];
        real du[3] = {w[1] * dn[2] - w[2] * dn[1], w[2] * dn[0] - w[0] * dn[2], w[0] * dn[1] - w[1] * dn[0]};
        real dw[3] = {dn[1] * u[2] - dn[2] * u[1], dn[2] * u[0] - dn[0] * u[2], dn[0] * u[1] - dn[1] * u[0]};
        for (int d = 0; d < 3; d++) {
            dpos[3 * (size_t)fv[0] + d] -= du[d] + dw[d];
            dpos[3 * (size_t)fv[1] + d] += du[d];
            dpos[3 * (size_t)fv[2] + d] += dw[d];
        }
    }
    free(dm);
    return MLB_OK;
}
