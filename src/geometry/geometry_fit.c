// End-to-end geometry fit: one step's render + loss + backward (include/matlaber/geometry_fit.h,
// docs/geometry_fit.md). Dual-compiled (float / double _f64), see core/real.h.
//   forward:  network at the grid vertices → deform → marching tets → vertex normals → per view:
//             transform → rasterize → interpolate [normal, 1] → antialias → (downsample); every
//             view's buffers are kept in the state.
//   backward: dimages (any image loss) → per view the chain in reverse → surface-vertex and normal
//             gradients → normals → marching tets → deform (+ regulariser) → network.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"
#include "matlaber/dist.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/rng.h"
#include "core/real.h"
#include "nn/table_ops.h"
#include "geometry/mt_device_f64.h"

// The per-pixel buffers and the surface's copies on the state's table (mlb_geofit_state.be)
// (the grid group: the network's outputs, the deformed grid, the regulariser and their gradients)
// (the surface group: normals, attribute, clip coordinates, the faces at each vertex, gradients)
enum { T_TRI, T_BARY, T_DEPTH, T_IMG, T_WEIGHTS, T_AA, T_DAA, T_DIMG, T_DBARY, T_OUT, T_DOUT,
       T_ATTR, T_CLIP, T_ADJ, T_DATTR, T_DCLIP, T_NRM, T_NSUM, T_VOFF, T_VF, T_ONES, T_PIECES, T_DSURF,
       T_GV, T_Y, T_SDF, T_DEFORM, T_GPOS, T_DGPOS, T_DSDF, T_DDEFORM, T_REG, T_COUNT };
struct FN(geofit_table) {
    const FN(mlb_backend)* tb;
    int gv_cells;         // the grid whose vertices T_GV holds (a grid's vertices are its cells and scale)
    float gv_scale;
    FN(tbuf) d[T_COUNT];
};
static void FN(geofit_table_free)(struct FN(geofit_table)* t) {
    if (!t) return;
    for (int i = 0; i < T_COUNT; i++) FN(tbuf_free)(t->tb, &t->d[i]);
    free(t);
}


// One view's buffers at the render size S = res·ss (forward kept for the backward).
typedef struct {
    int32_t* tri;
    real *bary, *depth, *img, *aa, *weights, *out;                   // out: [res,res,4] (aliases aa when ss = 1)
    real *dout, *daa, *dimg, *dbary;
} FN(geofit_view);

static void FN(geofit_view_free)(FN(geofit_view)* v) {
    free(v->tri); free(v->bary); free(v->depth); free(v->img); free(v->aa); free(v->weights);
    if (v->out != v->aa) free(v->out);
    free(v->dout); free(v->daa); free(v->dimg); free(v->dbary);
    memset(v, 0, sizeof *v);
}

static mlb_status FN(geofit_view_alloc)(FN(geofit_view)* v, int res, int ss, int backward) {
    memset(v, 0, sizeof *v);
    size_t S = (size_t)res * ss, P = S * S, p = (size_t)res * res;
    v->tri = malloc(sizeof(int32_t) * P);
    v->bary = malloc(sizeof(real) * P * 2);
    v->depth = malloc(sizeof(real) * P);
    v->img = malloc(sizeof(real) * P * 4);
    v->aa = malloc(sizeof(real) * P * 4);
    v->weights = malloc(sizeof(real) * P * 2);
    v->out = ss == 1 ? v->aa : malloc(sizeof(real) * p * 4);
    int ok = v->tri && v->bary && v->depth && v->img && v->aa && v->weights && v->out;
    if (backward) {
        v->dout = malloc(sizeof(real) * p * 4);
        v->daa = ss == 1 ? NULL : calloc(P * 4, sizeof(real));
        v->dimg = malloc(sizeof(real) * P * 4);
        v->dbary = malloc(sizeof(real) * P * 2);
        ok = ok && v->dout && (ss == 1 || v->daa) && v->dimg && v->dbary;
    }
    if (!ok) { FN(geofit_view_free)(v); return mlb_fail(MLB_ERR_NOMEM, "geometry fit: out of memory (%d px)", res * ss); }
    return MLB_OK;
}

// Forward of one view: attr [V,4] = [normal, 1] at clip [V,4] → v->out [res,res,4].
static mlb_status FN(geofit_view_forward)(const FN(mlb_backend)* be, FN(geofit_view)* v,
                                         const real* attr, const real* clip, int nv, const int32_t* faces,
                                         const int32_t* adj, int nf, int res, int ss) {
    int S = res * ss;
    mlb_status s = be->rasterize(v->tri, v->bary, v->depth, clip, nv, faces, nf, S, S);
    if (!s) s = be->interpolate(v->img, attr, nv, 4, v->tri, v->bary, faces, nf, S, S);
    if (!s) s = be->antialias(v->aa, v->weights, v->img, 4, v->tri, v->depth, clip, nv, faces, adj, nf, S, S);
    if (!s && ss > 1) FN(mlb_downsample_box)(v->out, v->aa, res, res, 4, ss);
    return s;
}

static uint64_t FN(geofit_hash)(uint64_t h, const int32_t* tri, size_t n) {
    for (size_t i = 0; i < n; i++) { h ^= (uint64_t)(uint32_t)tri[i] + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2); }
    return h;
}

mlb_status FN(mlb_geofit_render_mesh)(const FN(mlb_backend)* be, real* out, const mlb_mesh* m, const mlb_camera* cam,
                                     int res, int ss) {
    if (!be) be = FN(mlb_backend_cpu)();
    size_t V = (size_t)m->n_verts;
    real* pos = malloc(sizeof(real) * V * 3);
    real* nrm = malloc(sizeof(real) * V * 3);
    real* attr = malloc(sizeof(real) * V * 4);
    real* clip = malloc(sizeof(real) * V * 4);
    int32_t* adj = malloc(sizeof(int32_t) * 3 * (size_t)m->n_faces);
    FN(geofit_view) v;
    mlb_status s = (pos && nrm && attr && clip && adj) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "geometry fit: out of memory");
    if (!s) s = FN(geofit_view_alloc)(&v, res, ss, 0);
    if (!s) {
        for (size_t i = 0; i < 3 * V; i++) pos[i] = (real)m->pos[i];
        FN(vertex_normals_forward)(nrm, NULL, pos, m->n_verts, m->faces, m->n_faces);
        for (size_t i = 0; i < V; i++) {
            for (int k = 0; k < 3; k++) attr[4 * i + k] = nrm[3 * i + k];
            attr[4 * i + 3] = 1;
        }
        FN(mlb_transform_points)(clip, pos, m->n_verts, &cam->view_proj);
        s = mlb_edge_topology(adj, m->faces, m->n_faces, m->n_verts);
        if (!s) s = FN(geofit_view_forward)(be, &v, attr, clip, m->n_verts, m->faces, adj, m->n_faces, res, ss);
        if (!s) memcpy(out, v.out, sizeof(real) * (size_t)res * res * 4);
        FN(geofit_view_free)(&v);
    }
    free(pos); free(nrm); free(attr); free(clip); free(adj);
    return s;
}


void FN(mlb_geofit_state_free)(FN(mlb_geofit_state)* st) {
    if (!st) return;
    FN(mt_surface_free)(&st->surf);
    FN(mlb_mt_device_free)(st->mt);
    free(st->vp); free(st->images);
    free(st->gv); free(st->sdf); free(st->deform);
    FN(geofit_table_free)(st->tab);
    free(st->dsdf); free(st->ddeform);
    free(st->pieces);
    memset(st, 0, sizeof *st);
}

// Frees *p and allocates n elements of size sz (contents lost). 1 on success.
static int FN(grow)(void** p, size_t n, size_t sz) {
    free(*p);
    *p = malloc(n * sz + 1);
    return *p != NULL;
}

// Buffers for this forward: the grid group when the grid size changed, the pixel group when
// (views, size) changed, the surface group every time (M and F change every step).
// Buffers for this forward: the grid group when the grid size changed, the pixel group (on the
// table) when (views, size) changed, the surface group every time (M and F change every step; its
// table copies grow only).
static mlb_status FN(state_reserve)(FN(mlb_geofit_state)* st, size_t G, int M, int F, int n, int res, int ss) {
    int ok = 1;
    const FN(mlb_backend)* tb = st->be ? st->be : FN(mlb_backend_cpu)();
    if (st->tab && st->tab->tb != tb) {   // buffers of another device
        FN(geofit_table_free)(st->tab);
        st->tab = NULL;
        st->cap_px = 0;
        st->cap_grid = 0;
    }
    if (!st->tab) {
        ok = (st->tab = calloc(1, sizeof *st->tab)) != NULL;
        if (ok) st->tab->tb = tb;
    }
    if (ok && G != st->cap_grid) {
        st->cap_grid = 0;
        ok &= FN(grow)((void**)&st->gv, G * 3, sizeof(real)) & FN(grow)((void**)&st->sdf, G, sizeof(real)) &
              FN(grow)((void**)&st->deform, G * 3, sizeof(real)) & FN(grow)((void**)&st->dsdf, G, sizeof(real)) &
              FN(grow)((void**)&st->ddeform, G * 3, sizeof(real));
        FN(tbuf)* d = st->tab->d;
        st->tab->gv_cells = 0;
        ok = ok && FN(tbuf_get)(tb, &d[T_GV], G * 3) && FN(tbuf_get)(tb, &d[T_Y], G * 4) && FN(tbuf_get)(tb, &d[T_SDF], G) &&
             FN(tbuf_get)(tb, &d[T_DEFORM], G * 3) && FN(tbuf_get)(tb, &d[T_GPOS], G * 3) &&
             FN(tbuf_get)(tb, &d[T_DGPOS], G * 3) && FN(tbuf_get)(tb, &d[T_DSDF], G) &&
             FN(tbuf_get)(tb, &d[T_DDEFORM], G * 3) && FN(tbuf_get)(tb, &d[T_REG], 1);
        if (ok) st->cap_grid = G;
    }
    size_t S = (size_t)res * ss, P = S * S, px = P * (size_t)n;
    if (ok && (S != st->cap_px || (size_t)n != st->cap_views || res != st->res)) {
        st->cap_px = 0;
        st->cap_views = 0;
        size_t p = (size_t)res * res * (size_t)n;
        FN(tbuf)* d = st->tab->d;
        ok &= FN(grow)((void**)&st->vp, (size_t)n, sizeof(mlb_mat4)) & FN(grow)((void**)&st->images, p * 4, sizeof(real));
        ok = ok && (st->tri = (int32_t*)FN(tbuf_get)(tb, &d[T_TRI], px)) && (st->bary = FN(tbuf_get)(tb, &d[T_BARY], px * 2)) &&
             (st->depth = FN(tbuf_get)(tb, &d[T_DEPTH], px)) && (st->img = FN(tbuf_get)(tb, &d[T_IMG], px * 4)) &&
             (st->weights = FN(tbuf_get)(tb, &d[T_WEIGHTS], px * 2)) && (st->aa = FN(tbuf_get)(tb, &d[T_AA], P * 4)) &&
             (st->daa = FN(tbuf_get)(tb, &d[T_DAA], P * 4)) && (st->dimg = FN(tbuf_get)(tb, &d[T_DIMG], P * 4)) &&
             (st->dbary = FN(tbuf_get)(tb, &d[T_DBARY], P * 2)) && (st->t_images = FN(tbuf_get)(tb, &d[T_OUT], p * 4)) &&
             (st->t_dimages = FN(tbuf_get)(tb, &d[T_DOUT], p * 4));
        if (ok) { st->cap_px = S; st->cap_views = (size_t)n; st->res = res; }
    }
    if (ok && M > 0) {   // (M = 0: grid and pixel groups only)
        size_t m = (size_t)M;
        FN(tbuf)* d = st->tab->d;
        ok = ok && FN(tbuf_get)(tb, &d[T_ATTR], m * 4) && FN(tbuf_get)(tb, &d[T_CLIP], m * 4 * (size_t)n) &&
             FN(tbuf_get)(tb, &d[T_ADJ], (size_t)F * 3) && FN(tbuf_get)(tb, &d[T_DATTR], m * 4) &&
             FN(tbuf_get)(tb, &d[T_DCLIP], m * 4) && FN(tbuf_get)(tb, &d[T_NRM], m * 3) &&
             FN(tbuf_get)(tb, &d[T_NSUM], m * 3) && FN(tbuf_get)(tb, &d[T_VOFF], m + 1) &&
             FN(tbuf_get)(tb, &d[T_VF], (size_t)F * 3) && FN(tbuf_get)(tb, &d[T_ONES], m) &&
             FN(tbuf_get)(tb, &d[T_PIECES], m * 6 * (size_t)n) && FN(tbuf_get)(tb, &d[T_DSURF], m * 6);
        st->cap_surf = ok ? m : 0;
    }
    if (!ok) {
        FN(mlb_geofit_state_free)(st);
        return mlb_fail(MLB_ERR_NOMEM, "geometry step: out of memory on the %s (%d views of %d px, %d surface vertices)",
                        mlb_device_name(tb->device), n, res * ss, M);
    }
    return MLB_OK;
}

// The views this process renders: [*v0, *v1) of n (all of them unless the caller set a part).
static void FN(part_range)(const FN(mlb_geofit_state)* st, int n, int* v0, int* v1) {
    *v0 = 0;
    *v1 = n;
    if (st->part_count > 0 && st->part_first >= 0 && st->part_first + st->part_count <= n) {
        *v0 = st->part_first;
        *v1 = st->part_first + st->part_count;
    } else if (st->part_count < 0) {   // a rank with no view of this step
        *v0 = *v1 = st->part_first < n ? st->part_first : n;
    }
}

// The grid's part of a forward on the state's table: the network at the grid vertices (on the
// table's device when it is there, else on the host and its outputs uploaded), the deformation,
// marching tets (through mlb_mt_device: the surface stays on the table, st->surf gets its sizes and
// mlb_geofit_state_mesh brings it down). The SDF stays on the table for the regulariser and the
// backward.
static mlb_status FN(grid_forward)(FN(mlb_geofit_state)* st, FN(mlb_geometry_net)* net, const mlb_tetgrid* g,
                                   real grid_res) {
    const FN(mlb_backend)* tb = st->tab->tb;
    FN(tbuf)* d = st->tab->d;
    size_t G = (size_t)g->n_verts;
    if (st->tab->gv_cells != g->cells || st->tab->gv_scale != g->scale) {   // the grid's vertices go up once
        MLB_TRY(tb->upload(d[T_GV].p, st->gv, 3 * G));
        st->tab->gv_cells = g->cells;
        st->tab->gv_scale = g->scale;
    }
    const FN(mlb_backend)* nb = FN(mlb_field_backend)(net);   // (a double network is on the host)
    if (nb) {
        if (nb->device != tb->device)
            return mlb_fail(MLB_ERR_ARG, "geometry step: the geometry network is on the %s, the step on the %s",
                            mlb_device_name(nb->device), mlb_device_name(tb->device));
        MLB_TRY(FN(mlb_field_forward_on_device)(net, d[T_Y].p, d[T_GV].p, g->n_verts));
        MLB_TRY(tb->copy_rows(d[T_SDF].p, 1, d[T_Y].p, 4, 1, G));
        MLB_TRY(tb->copy_rows(d[T_DEFORM].p, 3, d[T_Y].p + 1, 4, 3, G));
    } else {
        if (tb->device != MLB_DEVICE_CPU)
            return mlb_fail(MLB_ERR_ARG, "geometry step: the geometry network is on the host, the step on the %s",
                            mlb_device_name(tb->device));
        MLB_TRY(FN(geometry_net_forward)(net, st->sdf, st->deform, st->gv, g->n_verts));
        MLB_TRY(tb->upload(d[T_SDF].p, st->sdf, G));
        MLB_TRY(tb->upload(d[T_DEFORM].p, st->deform, 3 * G));
    }
    MLB_TRY(tb->dmtet_deform(d[T_GPOS].p, d[T_GV].p, d[T_DEFORM].p, g->n_verts, grid_res));
    return FN(mlb_mt_device_forward)(&st->mt, tb, &st->surf, g, d[T_GPOS].p, d[T_SDF].p, MLB_MT_TABLE);
}

// The grid's part of the backward from dverts (on the table): marching tets, the deformation and the
// regulariser on the table, then the network (there, or on the host with the gradients brought down).
static mlb_status FN(grid_backward)(FN(mlb_geofit_state)* st, FN(mlb_geometry_net)* net, const mlb_tetgrid* g,
                                    const real* dverts, double reg_weight) {
    const FN(mlb_backend)* tb = st->tab->tb;
    FN(tbuf)* d = st->tab->d;
    size_t G = (size_t)g->n_verts;
    MLB_TRY(tb->zero(d[T_DGPOS].p, 3 * G));
    MLB_TRY(tb->zero(d[T_DSDF].p, G));
    MLB_TRY(tb->zero(d[T_DDEFORM].p, 3 * G));
    MLB_TRY(FN(mlb_mt_device_backward)(st->mt, d[T_DGPOS].p, d[T_DSDF].p, dverts, MLB_MT_TABLE));
    MLB_TRY(tb->dmtet_deform_backward(d[T_DDEFORM].p, d[T_DGPOS].p, d[T_DEFORM].p, g->n_verts, (real)(2 * g->cells)));
    if (reg_weight != 0) MLB_TRY(tb->sdf_reg_backward(d[T_DSDF].p, d[T_SDF].p, g->cells, (real)reg_weight));
    if (FN(mlb_field_backend)(net)) {
        MLB_TRY(tb->copy_rows(d[T_Y].p, 4, d[T_DSDF].p, 1, 1, G));   // dy [G,4], over the forward's y (no longer needed)
        MLB_TRY(tb->copy_rows(d[T_Y].p + 1, 4, d[T_DDEFORM].p, 3, 3, G));
        return FN(mlb_field_backward_on_device)(net, d[T_Y].p);
    }
    MLB_TRY(tb->download(st->dsdf, d[T_DSDF].p, G));
    MLB_TRY(tb->download(st->ddeform, d[T_DDEFORM].p, 3 * G));
    return FN(geometry_net_backward)(net, st->dsdf, st->ddeform);
}

mlb_status FN(mlb_geofit_forward)(FN(mlb_geofit_state)* st, FN(mlb_geometry_net)* net, const mlb_tetgrid* g,
                                 const mlb_camera* cams, int n, int res, int ss, real* images, mlb_geofit_stats* stats) {
    mlb_geofit_stats local;
    if (!stats) stats = &local;
    memset(stats, 0, sizeof *stats);
    if (st) st->ok = 0;
    if (!st || !net || !g || !cams || n < 1 || res < 1 || ss < 1 || (size_t)res * ss > MLB_RASTER_MAX_SIZE)
        return mlb_fail(MLB_ERR_ARG, "geometry step: bad arguments (%d views, res %d, ss %d)", n, res, ss);
    size_t G = (size_t)g->n_verts;
    real grid_res = (real)(2 * g->cells);
    // 1. the network at the grid vertices → deformed grid → marching tets
    FN(mt_surface_free)(&st->surf);
    mlb_status s = FN(state_reserve)(st, G, 0, 0, n, res, ss);
    if (s) return s;
    for (size_t i = 0; i < 3 * G; i++) st->gv[i] = (real)g->verts[i];
    s = FN(grid_forward)(st, net, g, grid_res);
    if (s) return s;
    if (st->surf.n_faces == 0) return mlb_fail(MLB_ERR_ARG, "geometry step: no surface (the SDF has one sign everywhere)");
    int M = st->surf.n_verts, F = st->surf.n_faces;
    s = FN(state_reserve)(st, G, M, F, n, res, ss);
    if (s) return s;
    st->n = n;
    st->res = res;
    st->ss = ss;
    st->S = res * ss;
    st->n_grid = g->n_verts;
    st->grid = g;
    stats->n_verts = M;
    stats->n_faces = F;
    // 2. on the table: the faces at each vertex, the normals, the attribute [normal, 1] and the
    //    edge topology for antialias
    const FN(mlb_backend)* tb = st->tab->tb;
    const int host_memory = tb->alloc == FN(mlb_backend_cpu)()->alloc;   // the table's buffers are the host's
    FN(tbuf)* d = st->tab->d;
    const real* t_pos;
    const int32_t* t_faces;
    MLB_TRY(FN(mlb_mt_device_surface)(st->mt, &t_pos, &t_faces));
    real *t_attr = d[T_ATTR].p, *t_clip = d[T_CLIP].p, *t_nrm = d[T_NRM].p;
    int32_t *t_adj = (int32_t*)d[T_ADJ].p, *t_off = (int32_t*)d[T_VOFF].p, *t_vf = (int32_t*)d[T_VF].p;
    MLB_TRY(tb->vertex_faces(t_off, t_vf, t_faces, F, M));
    MLB_TRY(tb->vertex_normals(t_nrm, d[T_NSUM].p, t_pos, M, t_faces, t_off, t_vf));
    MLB_TRY(FN(t_ones)(tb, d[T_ONES].p, (size_t)M));
    MLB_TRY(tb->copy_rows(t_attr, 4, t_nrm, 3, 3, (size_t)M));
    MLB_TRY(tb->copy_rows(t_attr + 3, 4, d[T_ONES].p, 1, 1, (size_t)M));
    MLB_TRY(tb->edge_topology(t_adj, t_faces, F, t_off, t_vf));
    // 3. every view (of this process's part), buffers kept: the images come down unless they stay
    //    on the table for the guidance (then their gradient starts at 0 there)
    size_t p = (size_t)res * res, S = (size_t)st->S, P = S * S;
    const int download = !st->images_on_table || images;
    if (st->images_on_table) MLB_TRY(tb->zero(st->t_dimages, p * 4 * (size_t)n));
    uint64_t hash = 1469598103934665603ull;
    int v0, v1;
    FN(part_range)(st, n, &v0, &v1);
    if (st->part_count != 0) memset(st->images, 0, sizeof(real) * p * 4 * (size_t)n);
    for (int v = 0; v < n; v++) st->vp[v] = cams[v].view_proj;
    for (int v = v0; v < v1; v++) {
        real* clip = t_clip + (size_t)v * M * 4;
        MLB_TRY(tb->transform_points(clip, t_pos, M, st->vp[v].m));
        int32_t* tri = st->tri + (size_t)v * P;
        real *bary = st->bary + (size_t)v * P * 2, *depth = st->depth + (size_t)v * P, *img = st->img + (size_t)v * P * 4;
        real* weights = st->weights + (size_t)v * P * 2;
        real* t_out = st->t_images + (size_t)v * p * 4;
        real* aa = ss == 1 ? t_out : st->aa;
        int Si = st->S;
        s = tb->rasterize(tri, bary, depth, clip, M, t_faces, F, Si, Si);
        if (!s) s = tb->interpolate(img, t_attr, M, 4, tri, bary, t_faces, F, Si, Si);
        if (!s) s = tb->antialias(aa, weights, img, 4, tri, depth, clip, M, t_faces, t_adj, F, Si, Si);
        if (!s && ss > 1) s = tb->downsample_box(t_out, aa, res, res, 4, ss);
        if (!s && download) s = tb->download(st->images + (size_t)v * p * 4, t_out, 4 * p);
        if (s) return s;
        if (host_memory) hash = FN(geofit_hash)(hash, tri, P);   // the coverage's hash, where tri can be read
    }
    if (!host_memory) hash = 0;
    if (images) memcpy(images, st->images, sizeof(real) * p * 4 * (size_t)n);
    real reg;
    s = tb->sdf_reg(d[T_REG].p, d[T_SDF].p, g->cells);
    if (!s) s = tb->download(&reg, d[T_REG].p, 1);
    if (s) return s;
    stats->reg = (double)reg;
    stats->coverage = hash;
    st->ok = 1;
    return MLB_OK;
}

// The backward with the image gradient on the host (dimages, uploaded a view at a time) or on the
// table (t_dimages); neither: the regulariser only.
static mlb_status FN(geofit_backward)(FN(mlb_geofit_state)* st, FN(mlb_geometry_net)* net, const real* dimages,
                                      const real* t_dimages, double reg_weight);

mlb_status FN(mlb_geofit_backward)(FN(mlb_geofit_state)* st, FN(mlb_geometry_net)* net, const real* dimages,
                                  double reg_weight) {
    return FN(geofit_backward)(st, net, dimages, NULL, reg_weight);
}

mlb_status FN(mlb_geofit_backward_table)(FN(mlb_geofit_state)* st, FN(mlb_geometry_net)* net, double reg_weight) {
    if (!st || !st->ok || !st->images_on_table)
        return mlb_fail(MLB_ERR_ARG, "geometry step: a backward from the table without a forward that kept its images there");
    return FN(geofit_backward)(st, net, NULL, st->t_dimages, reg_weight);
}

static mlb_status FN(geofit_backward)(FN(mlb_geofit_state)* st, FN(mlb_geometry_net)* net, const real* dimages,
                                      const real* t_dimages, double reg_weight) {
    if (!st || !st->ok || !net) return mlb_fail(MLB_ERR_ARG, "geometry step: backward without a forward");
    const mlb_tetgrid* g = st->grid;
    int M = st->surf.n_verts, F = st->surf.n_faces, n = st->n, res = st->res, ss = st->ss, Si = st->S;
    size_t p = (size_t)res * res, P = (size_t)Si * Si;
    mlb_status s = MLB_OK;
    // Each view's share of the surface gradients goes to its own piece [dverts 3M | dnrm 3M] on the
    // table; pieces rendered by other processes are gathered (through the host) and the pieces are
    // added in view order: one process's sums, so any number of processes gives its bits.
    int v0, v1;
    FN(part_range)(st, n, &v0, &v1);
    size_t piece = (size_t)M * 6;
    const int grads = dimages || t_dimages;
    if (grads && st->part_count != 0 && piece * (size_t)n > st->cap_pieces) {
        st->cap_pieces = 0;
        if (!FN(grow)((void**)&st->pieces, piece * (size_t)n, sizeof(real)))
            return mlb_fail(MLB_ERR_NOMEM, "geometry step: out of memory (%d views of %d surface vertices)", n, M);
        st->cap_pieces = piece * (size_t)n;
    }
    const FN(mlb_backend)* tb = st->tab->tb;
    FN(tbuf)* d = st->tab->d;
    const real* t_pos;
    const int32_t* t_faces;
    MLB_TRY(FN(mlb_mt_device_surface)(st->mt, &t_pos, &t_faces));
    real *t_attr = d[T_ATTR].p, *t_clip = d[T_CLIP].p, *t_pieces = d[T_PIECES].p;
    real *t_dattr = d[T_DATTR].p, *t_dclip = d[T_DCLIP].p, *t_dsurf = d[T_DSURF].p;
    const int32_t *t_adj = (const int32_t*)d[T_ADJ].p, *t_off = (const int32_t*)d[T_VOFF].p;
    const int32_t* t_vf = (const int32_t*)d[T_VF].p;
    for (int v = v0; grads && v < v1; v++) {
        const real* t_dout = t_dimages ? t_dimages + (size_t)v * p * 4 : d[T_DOUT].p + (size_t)v * p * 4;
        if (!t_dimages) s = tb->upload(d[T_DOUT].p + (size_t)v * p * 4, dimages + (size_t)v * p * 4, 4 * p);
        const real* daa = t_dout;
        if (!s && ss > 1) {
            s = tb->zero(st->daa, P * 4);
            if (!s) s = tb->downsample_box_backward(st->daa, t_dout, res, res, 4, ss);
            daa = st->daa;
        }
        const real* clip = t_clip + (size_t)v * M * 4;
        const int32_t* tri = st->tri + (size_t)v * P;
        const real *bary = st->bary + (size_t)v * P * 2, *depth = st->depth + (size_t)v * P, *img = st->img + (size_t)v * P * 4;
        const real* weights = st->weights + (size_t)v * P * 2;
        real* pc = t_pieces + piece * (size_t)v;
        if (!s) s = tb->zero(st->dimg, P * 4);
        if (!s) s = tb->zero(st->dbary, P * 2);
        if (!s) s = tb->zero(t_dclip, (size_t)M * 4);
        if (!s) s = tb->zero(t_dattr, (size_t)M * 4);
        if (!s) s = tb->antialias_backward(st->dimg, t_dclip, daa, weights, img, 4, tri, depth, clip, M,
                                             t_faces, t_adj, F, Si, Si);
        if (!s) s = tb->interpolate_backward(t_dattr, st->dbary, st->dimg, t_attr, M, 4, tri, bary,
                                               t_faces, F, Si, Si);
        if (!s) s = tb->rasterize_backward(t_dclip, st->dbary, NULL, tri, clip, M, t_faces, F, Si, Si);
        if (!s) s = tb->zero(pc, (size_t)M * 3);
        if (!s) s = tb->transform_points_backward(pc, t_dclip, M, st->vp[v].m);
        if (!s) s = tb->copy_rows(pc + 3 * (size_t)M, 3, t_dattr, 4, 3, (size_t)M);
        if (s) break;   // (still joins the gather below: the other ranks wait in it)
    }
    if (grads && st->part_count != 0) {   // this process's pieces down, every view's up
        if (!s && v1 > v0) s = tb->download(st->pieces + piece * (size_t)v0, t_pieces + piece * (size_t)v0,
                                              piece * (size_t)(v1 - v0));
        mlb_status g = mlb_dist_allgather_batches(st->pieces + piece * (size_t)v0, st->pieces, n, st->part_batch,
                                                  piece * sizeof(real));
        if (!s) s = g;
        if (!s) s = tb->upload(t_pieces, st->pieces, piece * (size_t)n);
    }
    if (s) return s;
    MLB_TRY(tb->zero(t_dsurf, piece));   // [dverts 3M | dnrm 3M]
    for (int v = 0; grads && v < n; v++) MLB_TRY(tb->add(t_dsurf, t_pieces + piece * (size_t)v, piece));
    MLB_TRY(tb->vertex_normals_backward(t_dsurf, t_dsurf + 3 * (size_t)M, d[T_NSUM].p, t_pos, M, t_faces, t_off, t_vf));
    return FN(grid_backward)(st, net, g, t_dsurf, reg_weight);
}

mlb_status FN(mlb_geofit_loss)(FN(mlb_geometry_net)* net, const mlb_tetgrid* g, const mlb_camera* cams, int n_views,
                              const real* targets, int res, int ss, double w_normal, double w_mask, double reg_weight,
                              int backward, mlb_geofit_stats* stats) {
    mlb_geofit_stats local;
    if (!stats) stats = &local;
    FN(mlb_geofit_state) st;
    memset(&st, 0, sizeof st);
    mlb_status s = FN(mlb_geofit_forward)(&st, net, g, cams, n_views, res, ss, NULL, stats);
    size_t p = (size_t)res * res, N = p * 4 * (size_t)n_views;
    real* dimages = NULL;
    if (!s && backward && !(dimages = malloc(sizeof(real) * N))) s = mlb_fail(MLB_ERR_NOMEM, "geometry fit: out of memory");
    if (!s) {
        double img_loss = 0, norm = 1.0 / ((double)n_views * (double)p);
        for (int v = 0; v < n_views; v++) {   // per view in double, in view order
            double sum = 0;
            for (size_t i = (size_t)v * p * 4; i < (size_t)(v + 1) * p * 4; i++) {
                double d = (double)st.images[i] - (double)targets[i];
                double w = (i & 3) < 3 ? w_normal : w_mask;
                sum += w * d * d;
                if (dimages) dimages[i] = (real)(2.0 * w * d * norm);
            }
            img_loss += sum * norm;
        }
        stats->img = img_loss;
        stats->loss = img_loss + reg_weight * stats->reg;
        if (backward) s = FN(mlb_geofit_backward)(&st, net, dimages, reg_weight);
    }
    free(dimages);
    FN(mlb_geofit_state_free)(&st);
    return s;
}
