// Marching tetrahedra over a tet grid (reference.md §3) with backward to the SDF values and the
// (deformed) grid positions; the DMTet deformation and the SDF sign regulariser.
// Dual-compiled (float / double _f64), see core/real.h.
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/dmtet.h"
#include "core/real.h"

#define MT_PARALLEL_MIN 4096
#define MT_CHUNKS 64   // fixed reduction shards: sums do not depend on the thread count

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
    memset(out, 0, sizeof *out);
    const int V = g->n_verts, T = g->n_tets;
    const int64_t E = g->n_edges;
    int32_t* map = malloc(sizeof(int32_t) * 7 * (size_t)V);       // sparse edge id -> output vertex
    int32_t* tet_first = malloc(sizeof(int32_t) * ((size_t)T + 1));   // first face of each tet
    if (!map || !tet_first) {
        free(map);
        free(tet_first);
        return mlb_fail(MLB_ERR_NOMEM, "marching tets: out of memory for %d vertices", V);
    }
    // 1. Count the sign-changing grid edges and the faces of every tet, in fixed chunks (the
    //    numbering below is in edge / tet order whatever the thread count).
    int64_t e_cnt[MT_CHUNKS + 1], t_cnt[MT_CHUNKS + 1];
#pragma omp parallel for schedule(static) if (T >= MT_PARALLEL_MIN)
    for (int c = 0; c < MT_CHUNKS; c++) {
        int64_t m = 0;
        for (int64_t e = E * c / MT_CHUNKS; e < E * (c + 1) / MT_CHUNKS; e++)
            m += (sdf[g->edges[2 * e]] > 0) != (sdf[g->edges[2 * e + 1]] > 0);
        e_cnt[c] = m;
        int64_t f = 0;
        for (int t = (int)((int64_t)T * c / MT_CHUNKS); t < (int)((int64_t)T * (c + 1) / MT_CHUNKS); t++) {
            const int32_t* tv = g->tets + 4 * (size_t)t;
            int occ = (sdf[tv[0]] > 0) | ((sdf[tv[1]] > 0) << 1) | ((sdf[tv[2]] > 0) << 2) | ((sdf[tv[3]] > 0) << 3);
            tet_first[t] = (int32_t)f;   // within the chunk for now
            f += mlb_mt_num_triangles[occ];
        }
        t_cnt[c] = f;
    }
    int64_t nv64 = 0, nf = 0;
    for (int c = 0; c < MT_CHUNKS; c++) {
        int64_t a = e_cnt[c], b = t_cnt[c];
        e_cnt[c] = nv64;
        t_cnt[c] = nf;
        nv64 += a;
        nf += b;
    }
    if (nf > INT32_MAX / 3 || nv64 > INT32_MAX / 3) {
        free(map);
        free(tet_first);
        return mlb_fail(MLB_ERR_ARG, "marching tets: surface too large (%lld faces)", (long long)nf);
    }
    const int32_t nv = (int32_t)nv64;
    tet_first[T] = (int32_t)nf;
    out->n_verts = nv;
    out->n_faces = (int)nf;
    out->pos = malloc(sizeof(real) * 3 * (size_t)(nv ? nv : 1));
    out->edge = malloc(sizeof(int32_t) * 2 * (size_t)(nv ? nv : 1));
    out->weight = malloc(sizeof(real) * 2 * (size_t)(nv ? nv : 1));
    out->faces = malloc(sizeof(int32_t) * 3 * (size_t)(nf ? nf : 1));
    if (!out->pos || !out->edge || !out->weight || !out->faces) {
        free(map);
        free(tet_first);
        FN(mt_surface_free)(out);
        return mlb_fail(MLB_ERR_NOMEM, "marching tets: out of memory for %d vertices", nv);
    }
    // 2. Number the vertices (edge order) and finish the per-tet face offsets. Only ids of
    //    sign-changing edges are written to and read from the map.
#pragma omp parallel for schedule(static) if (T >= MT_PARALLEL_MIN)
    for (int c = 0; c < MT_CHUNKS; c++) {
        int32_t k = (int32_t)e_cnt[c];
        for (int64_t e = E * c / MT_CHUNKS; e < E * (c + 1) / MT_CHUNKS; e++) {
            int32_t a = g->edges[2 * e], b = g->edges[2 * e + 1];
            if ((sdf[a] > 0) == (sdf[b] > 0)) continue;
            map[mlb_tetgrid_edge_id(g, a, b)] = k;
            out->edge[2 * k] = a;
            out->edge[2 * k + 1] = b;
            k++;
        }
        for (int t = (int)((int64_t)T * c / MT_CHUNKS); t < (int)((int64_t)T * (c + 1) / MT_CHUNKS); t++)
            tet_first[t] += (int32_t)t_cnt[c];
    }
    // 3. Vertex positions and interpolation weights.
#pragma omp parallel for schedule(static) if (nv >= MT_PARALLEL_MIN)
    for (int32_t i = 0; i < nv; i++) {
        int32_t a = out->edge[2 * i], b = out->edge[2 * i + 1];
        real sa = sdf[a], sb = sdf[b], den = sa - sb;
        real wa = -sb / den, wb = sa / den;
        out->weight[2 * i] = wa;
        out->weight[2 * i + 1] = wb;
        for (int d = 0; d < 3; d++) out->pos[3 * (size_t)i + d] = wa * pos[3 * (size_t)a + d] + wb * pos[3 * (size_t)b + d];
    }
    // 4. Faces, tet by tet in the table's order.
#pragma omp parallel for schedule(static) if (T >= MT_PARALLEL_MIN)
    for (int t = 0; t < T; t++) {
        int cnt = tet_first[t + 1] - tet_first[t];
        if (!cnt) continue;
        const int32_t* tv = g->tets + 4 * (size_t)t;
        int occ = (sdf[tv[0]] > 0) | ((sdf[tv[1]] > 0) << 1) | ((sdf[tv[2]] > 0) << 2) | ((sdf[tv[3]] > 0) << 3);
        for (int c = 0; c < 3 * cnt; c++) {
            const int* le = mlb_mt_tet_edges[mlb_mt_triangle_table[occ][c]];
            int64_t id = mlb_tetgrid_edge_id(g, tv[le[0]], tv[le[1]]);
            out->faces[3 * (size_t)tet_first[t] + c] = map[id];
        }
    }
    free(map);
    free(tet_first);
    return MLB_OK;
}

void FN(marching_tets_backward)(real* dpos, real* dsdf, const FN(mlb_mt_surface)* s, const real* pos,
                                const real* sdf, const real* dverts) {
    // Sequential: output vertices share grid vertices, and a fixed order keeps results exact.
    for (int i = 0; i < s->n_verts; i++) {
        int32_t a = s->edge[2 * i], b = s->edge[2 * i + 1];
        const real* gv = dverts + 3 * (size_t)i;
        if (dpos)
            for (int d = 0; d < 3; d++) {
                dpos[3 * (size_t)a + d] += s->weight[2 * i] * gv[d];
                dpos[3 * (size_t)b + d] += s->weight[2 * i + 1] * gv[d];
            }
        if (dsdf) {
            // v = (s_a p_b − s_b p_a)/(s_a − s_b): ∂v/∂s_a = s_b (p_a − p_b)/D², ∂v/∂s_b = s_a (p_b − p_a)/D²
            real sa = sdf[a], sb = sdf[b], den = sa - sb, inv2 = 1 / (den * den);
            real dot = 0;
            for (int d = 0; d < 3; d++) dot += gv[d] * (pos[3 * (size_t)a + d] - pos[3 * (size_t)b + d]);
            dsdf[a] += sb * dot * inv2;
            dsdf[b] -= sa * dot * inv2;
        }
    }
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
    size_t n = 3 * (size_t)n_verts;
#pragma omp parallel for schedule(static) if (n >= MT_PARALLEL_MIN)
    for (size_t i = 0; i < n; i++) out[i] = grid[i] + R_TANH(deform[i]) / grid_res;
}

void FN(dmtet_deform_backward)(real* dgrid, real* ddeform, const real* dout, const real* deform, int n_verts,
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
static real bce_logits(real x, real t) {
    return (x > 0 ? x : 0) - x * t + R_LOG1P(R_EXP(-R_FABS(x)));
}

// Sum over vertex v's sign-changing neighbours u of f(s_v, occ_u); returns the edges counted
// with v as the lower end in *n_lower (to count each edge once).
static real vertex_terms(const mlb_tetgrid* g, const real* sdf, int v, int grad, int* n_lower) {
    const int n = g->cells + 1;
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
            else acc += bce_logits(sv, (real)ou);
        }
    }
    *n_lower = cnt;
    return acc;
}

static real sdf_reg_sum(const mlb_tetgrid* g, const real* sdf, int64_t* n_edges) {
    const int V = g->n_verts;
    double part[MT_CHUNKS];
    int64_t cnt[MT_CHUNKS];
#pragma omp parallel for schedule(static) if (V >= MT_PARALLEL_MIN)
    for (int c = 0; c < MT_CHUNKS; c++) {
        int lo = (int)((int64_t)V * c / MT_CHUNKS), hi = (int)((int64_t)V * (c + 1) / MT_CHUNKS);
        double s = 0;
        int64_t m = 0;
        for (int v = lo; v < hi; v++) {
            int nl;
            s += vertex_terms(g, sdf, v, 0, &nl);
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

real FN(sdf_reg_forward)(const mlb_tetgrid* g, const real* sdf) {
    int64_t m;
    real s = sdf_reg_sum(g, sdf, &m);
    return m ? s / (real)m : 0;
}

void FN(sdf_reg_backward)(real* dsdf, const mlb_tetgrid* g, const real* sdf, real dloss) {
    int64_t m;
    sdf_reg_sum(g, sdf, &m);   // the edge count (the loss is a mean over edges)
    if (!m) return;
    real scale = dloss / (real)m;
    const int V = g->n_verts;
#pragma omp parallel for schedule(static) if (V >= MT_PARALLEL_MIN)
    for (int v = 0; v < V; v++) {
        int nl;
        dsdf[v] += scale * vertex_terms(g, sdf, v, 1, &nl);
    }
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
