// End-to-end geometry fit: one step's render + loss + backward (include/matlaber/geometry_fit.h,
// docs/geometry_fit.md). Dual-compiled (float / double _f64), see core/real.h.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/geometry_fit.h"
#include "matlaber/rng.h"
#include "core/real.h"


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
static mlb_status FN(geofit_view_forward)(mlb_raster_ctx* ctx, FN(geofit_view)* v, const real* attr, const real* clip,
                                         int nv, const int32_t* faces, const int32_t* adj, int nf, int res, int ss) {
    int S = res * ss;
    mlb_status s = FN(mlb_rasterize)(ctx, v->tri, v->bary, v->depth, NULL, clip, nv, faces, nf, S, S);
    if (!s) s = FN(mlb_interpolate)(v->img, attr, nv, 4, v->tri, v->bary, faces, nf, S, S);
    if (!s) s = FN(mlb_antialias)(ctx, v->aa, v->weights, v->img, 4, v->tri, v->depth, clip, nv, faces, adj, nf, S, S);
    if (!s && ss > 1) FN(mlb_downsample_box)(v->out, v->aa, res, res, 4, ss);
    return s;
}

static uint64_t FN(geofit_hash)(uint64_t h, const int32_t* tri, size_t n) {
    for (size_t i = 0; i < n; i++) { h ^= (uint64_t)(uint32_t)tri[i] + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2); }
    return h;
}

mlb_status FN(mlb_geofit_render_mesh)(mlb_raster_ctx* ctx, real* out, const mlb_mesh* m, const mlb_camera* cam, int res,
                                     int ss) {
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
        if (!s) s = FN(geofit_view_forward)(ctx, &v, attr, clip, m->n_verts, m->faces, adj, m->n_faces, res, ss);
        if (!s) memcpy(out, v.out, sizeof(real) * (size_t)res * res * 4);
        FN(geofit_view_free)(&v);
    }
    free(pos); free(nrm); free(attr); free(clip); free(adj);
    return s;
}

mlb_status FN(mlb_geofit_loss)(FN(mlb_geometry_net)* net, const mlb_tetgrid* g, mlb_raster_ctx* ctx,
                              const mlb_camera* cams, int n_views, const real* targets, int res, int ss, double w_normal,
                              double w_mask, double reg_weight, int backward, mlb_geofit_stats* st) {
    memset(st, 0, sizeof *st);
    size_t G = (size_t)g->n_verts;
    real grid_res = (real)(2 * g->cells);
    real* gv = malloc(sizeof(real) * G * 3);      // grid vertices in real
    real* sdf = malloc(sizeof(real) * G);
    real* deform = malloc(sizeof(real) * G * 3);
    real* gpos = malloc(sizeof(real) * G * 3);    // deformed grid vertices
    real *nrm = NULL, *nsum = NULL, *attr = NULL, *clip = NULL, *dattr = NULL, *dclip = NULL, *dverts = NULL, *dnrm = NULL;
    real *dgpos = NULL, *dsdf = NULL, *ddeform = NULL;
    int32_t* adj = NULL;
    FN(mlb_mt_surface) surf;
    memset(&surf, 0, sizeof surf);
    FN(geofit_view) v;
    memset(&v, 0, sizeof v);
    mlb_status s = (gv && sdf && deform && gpos) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "geometry fit: out of memory");
    if (!s) {
        for (size_t i = 0; i < 3 * G; i++) gv[i] = (real)g->verts[i];
        s = FN(geometry_net_forward)(net, sdf, deform, gv, g->n_verts);
    }
    if (!s) {
        FN(dmtet_deform_forward)(gpos, gv, deform, g->n_verts, grid_res);
        s = FN(marching_tets_forward)(&surf, g, gpos, sdf);
    }
    if (!s && surf.n_faces == 0) s = mlb_fail(MLB_ERR_ARG, "geometry fit: no surface (the SDF has one sign everywhere)");
    int M = surf.n_verts, F = surf.n_faces;
    if (!s) {
        st->n_verts = M;
        st->n_faces = F;
        nrm = malloc(sizeof(real) * (size_t)M * 3);
        nsum = malloc(sizeof(real) * (size_t)M * 3);
        attr = malloc(sizeof(real) * (size_t)M * 4);
        clip = malloc(sizeof(real) * (size_t)M * 4);
        adj = malloc(sizeof(int32_t) * (size_t)F * 3);
        if (!nrm || !nsum || !attr || !clip || !adj) s = mlb_fail(MLB_ERR_NOMEM, "geometry fit: out of memory (%d faces)", F);
    }
    if (!s && backward) {
        dattr = malloc(sizeof(real) * (size_t)M * 4);
        dclip = malloc(sizeof(real) * (size_t)M * 4);
        dverts = calloc((size_t)M * 3, sizeof(real));
        dnrm = calloc((size_t)M * 3, sizeof(real));
        if (!dattr || !dclip || !dverts || !dnrm) s = mlb_fail(MLB_ERR_NOMEM, "geometry fit: out of memory (%d faces)", F);
    }
    if (!s) {
        FN(vertex_normals_forward)(nrm, nsum, surf.pos, M, surf.faces, F);
        for (int i = 0; i < M; i++) {
            for (int k = 0; k < 3; k++) attr[4 * i + k] = nrm[3 * i + k];
            attr[4 * i + 3] = 1;
        }
        s = mlb_edge_topology(adj, surf.faces, F, M);
    }
    if (!s) s = FN(geofit_view_alloc)(&v, res, ss, backward);
    size_t p = (size_t)res * res, S = (size_t)res * ss, P = S * S;
    double img_loss = 0, norm = 1.0 / ((double)n_views * (double)p);
    uint64_t hash = 1469598103934665603ull;
    for (int view = 0; !s && view < n_views; view++) {
        const mlb_mat4* vp = &cams[view].view_proj;
        FN(mlb_transform_points)(clip, surf.pos, M, vp);
        s = FN(geofit_view_forward)(ctx, &v, attr, clip, M, surf.faces, adj, F, res, ss);
        if (s) break;
        hash = FN(geofit_hash)(hash, v.tri, P);
        const real* t = targets + (size_t)view * p * 4;
        double sum = 0;
        for (size_t i = 0; i < p; i++) {
            for (int c = 0; c < 4; c++) {
                double d = (double)v.out[4 * i + c] - (double)t[4 * i + c];
                double w = c < 3 ? w_normal : w_mask;
                sum += w * d * d;
                if (backward) v.dout[4 * i + c] = (real)(2.0 * w * d * norm);
            }
        }
        img_loss += sum * norm;
        if (!backward) continue;
        const real* daa = v.dout;
        if (ss > 1) {
            memset(v.daa, 0, sizeof(real) * P * 4);
            FN(mlb_downsample_box_backward)(v.daa, v.dout, res, res, 4, ss);
            daa = v.daa;
        }
        memset(v.dimg, 0, sizeof(real) * P * 4);
        memset(v.dbary, 0, sizeof(real) * P * 2);
        memset(dclip, 0, sizeof(real) * (size_t)M * 4);
        memset(dattr, 0, sizeof(real) * (size_t)M * 4);
        int Si = (int)S;
        s = FN(mlb_antialias_backward)(ctx, v.dimg, dclip, daa, v.weights, v.img, 4, v.tri, v.depth, clip, M, surf.faces,
                                      adj, F, Si, Si);
        if (!s) s = FN(mlb_interpolate_backward)(ctx, dattr, v.dbary, v.dimg, attr, M, 4, v.tri, v.bary, surf.faces, F, Si, Si);
        if (!s) s = FN(mlb_rasterize_backward)(ctx, dclip, v.dbary, NULL, v.tri, clip, M, surf.faces, F, Si, Si);
        if (s) break;
        FN(mlb_transform_points_backward)(dverts, dclip, M, vp);
        for (int i = 0; i < M; i++)
            for (int k = 0; k < 3; k++) dnrm[3 * i + k] += dattr[4 * i + k];
    }
    double reg = 0;
    if (!s) {
        reg = (double)FN(sdf_reg_forward)(g, sdf);
        st->img = img_loss;
        st->reg = reg;
        st->loss = img_loss + reg_weight * reg;
        st->coverage = hash;
    }
    if (!s && backward) {
        s = FN(vertex_normals_backward)(dverts, dnrm, nsum, surf.pos, M, surf.faces, F);
        dgpos = calloc(G * 3, sizeof(real));
        dsdf = calloc(G, sizeof(real));
        ddeform = calloc(G * 3, sizeof(real));
        if (!s && (!dgpos || !dsdf || !ddeform)) s = mlb_fail(MLB_ERR_NOMEM, "geometry fit: out of memory");
        if (!s) {
            FN(marching_tets_backward)(dgpos, dsdf, &surf, gpos, sdf, dverts);
            FN(dmtet_deform_backward)(NULL, ddeform, dgpos, deform, g->n_verts, grid_res);
            if (reg_weight != 0) FN(sdf_reg_backward)(dsdf, g, sdf, (real)reg_weight);
            FN(geometry_net_backward)(net, dsdf, ddeform);
        }
    }
    FN(geofit_view_free)(&v);
    FN(mt_surface_free)(&surf);
    free(gv); free(sdf); free(deform); free(gpos);
    free(nrm); free(nsum); free(attr); free(clip); free(adj);
    free(dattr); free(dclip); free(dverts); free(dnrm);
    free(dgpos); free(dsdf); free(ddeform);
    return s;
}

