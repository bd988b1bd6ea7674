// Marching tets through an op table (dmtet.h mlb_mt_device_*): the passes of backend_ops.def on the
// table's device. The grid's tets go up once per grid; each forward takes the SDF and positions
// (uploaded from the host, or copied on the device), counts, scans in place, reads the two totals
// back, emits into buffers of the surface's size and, with host buffers, downloads the surface; the
// backward with host buffers uploads the vertex gradient and the caller's dpos/dsdf (the op
// accumulates), runs and downloads them. With the CPU tables the copies are memcpy and the ops are
// mt_ops.h's passes: the bits of marching_tets_forward.
// Dual-compiled (float / double _f64, core/real.h): the double pass runs on the CPU's double table
// (backend_f64.h) for the double geometry fit; geometry/mt_device_f64.h declares it. The handle is
// dmtet.h's mlb_mt_device in both passes (the same layout: pointers and sizes); a handle is made,
// used and freed by the functions of one pass.
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend_f64.h"
#include "matlaber/dmtet.h"
#include "core/real.h"
#include "geometry/mt_device_f64.h"
#include "nn/table_ops.h"

struct mlb_mt_device {
    const FN(mlb_backend)* be;
    const int32_t* grid_tets;       // the host grid whose tets are on the device
    int T, V, cells;
    int64_t S;                      // edge slots, 7 V
    real *tets, *pos, *sdf;         // [T,4] int32, [V,3], [V]
    real *tet_off, *slot_off;       // [T+1], [S+1] int32: the scans of the last forward
    real *dpos, *dsdf;              // [V,3], [V]
    real *verts, *vedge, *weight, *faces, *dverts;   // [nv,3], [nv,2] int32, [nv,2], [nf,3] int32, [nv,3]
    size_t cap_v, cap_f;
    int nv, nf;
};

static void release(const FN(mlb_backend)* be, real** p) {
    if (*p) be->release(*p);
    *p = NULL;
}

void FN(mlb_mt_device_free)(mlb_mt_device* d) {
    if (!d) return;
    const FN(mlb_backend)* be = d->be;
    real** bufs[] = {&d->tets, &d->pos, &d->sdf, &d->tet_off, &d->slot_off, &d->dpos, &d->dsdf,
                     &d->verts, &d->vedge, &d->weight, &d->faces, &d->dverts};
    for (size_t i = 0; i < sizeof bufs / sizeof bufs[0]; i++) release(be, bufs[i]);
    free(d);
}

// The grid's buffers on be's device (again when the grid or the table changed).
static mlb_status grid_on_device(mlb_mt_device** dp, const FN(mlb_backend)* be, const mlb_tetgrid* g) {
    mlb_mt_device* d = *dp;
    if (d && d->be == be && d->grid_tets == g->tets && d->T == g->n_tets && d->cells == g->cells) return MLB_OK;
    FN(mlb_mt_device_free)(d);
    *dp = d = calloc(1, sizeof *d);
    if (!d) return mlb_fail(MLB_ERR_NOMEM, "marching tets: out of memory");
    d->be = be;
    d->T = g->n_tets, d->V = g->n_verts, d->cells = g->cells, d->S = 7 * (int64_t)g->n_verts;
    size_t T = (size_t)d->T, V = (size_t)d->V, S = (size_t)d->S;
    mlb_status s = be->alloc(&d->tets, 4 * T);
    if (!s) s = be->alloc(&d->pos, 3 * V);
    if (!s) s = be->alloc(&d->sdf, V);
    if (!s) s = be->alloc(&d->tet_off, T + 1);
    if (!s) s = be->alloc(&d->slot_off, S + 1);
    if (!s) s = be->alloc(&d->dpos, 3 * V);
    if (!s) s = be->alloc(&d->dsdf, V);
    if (!s) s = FN(t_upload_i32)(be, (int32_t*)d->tets, g->tets, 4 * T);
    if (s) {
        FN(mlb_mt_device_free)(d);
        *dp = NULL;
        return s;
    }
    d->grid_tets = g->tets;
    return MLB_OK;
}

// Surface buffers for nv vertices and nf faces (grown, never shrunk).
static mlb_status surface_on_device(mlb_mt_device* d, size_t nv, size_t nf) {
    const FN(mlb_backend)* be = d->be;
    mlb_status s = MLB_OK;
    if (nv > d->cap_v || !d->verts) {
        release(be, &d->verts), release(be, &d->vedge), release(be, &d->weight), release(be, &d->dverts);
        d->cap_v = 0;
        s = be->alloc(&d->verts, 3 * nv);
        if (!s) s = be->alloc(&d->vedge, 2 * nv);
        if (!s) s = be->alloc(&d->weight, 2 * nv);
        if (!s) s = be->alloc(&d->dverts, 3 * nv);
        if (!s) d->cap_v = nv;
    }
    if (!s && (nf > d->cap_f || !d->faces)) {
        release(be, &d->faces);
        d->cap_f = 0;
        s = be->alloc(&d->faces, 3 * nf);
        if (!s) d->cap_f = nf;
    }
    return s;
}

// The forward from the handle's pos and sdf (on the device)
static mlb_status forward_from_device(mlb_mt_device* d, FN(mlb_mt_surface)* out, int on_device);

// pos and sdf into the handle's buffers (uploaded from the host, or copied on the device), then the forward
mlb_status FN(mlb_mt_device_forward)(mlb_mt_device** dp, const FN(mlb_backend)* be, FN(mlb_mt_surface)* out,
                                     const mlb_tetgrid* g, const real* pos, const real* sdf, mlb_mt_place where) {
    memset(out, 0, sizeof *out);
    MLB_TRY(grid_on_device(dp, be, g));
    mlb_mt_device* d = *dp;
    d->nv = d->nf = 0;
    size_t V = (size_t)d->V;
    const int on_device = where == MLB_MT_TABLE;
    MLB_TRY(on_device ? be->copy(d->pos, pos, 3 * V) : be->upload(d->pos, pos, 3 * V));
    MLB_TRY(on_device ? be->copy(d->sdf, sdf, V) : be->upload(d->sdf, sdf, V));
    return forward_from_device(d, out, on_device);
}

static mlb_status surface_down(const mlb_mt_device* d, FN(mlb_mt_surface)* out);

// out: the host's copy of the surface (on_device: its sizes only; mlb_mt_device_surface_host brings
// the rest when someone needs it)
static mlb_status forward_from_device(mlb_mt_device* d, FN(mlb_mt_surface)* out, int on_device) {
    const FN(mlb_backend)* be = d->be;
    const int T = d->T;
    int32_t *tet_off = (int32_t*)d->tet_off, *slot_off = (int32_t*)d->slot_off;
    MLB_TRY(be->marching_tets_count(tet_off, slot_off, d->sdf, (const int32_t*)d->tets, T, d->cells));
    MLB_TRY(be->scan_i32(tet_off, tet_off, T));
    MLB_TRY(be->scan_i32(slot_off, slot_off, (int)d->S));
    int32_t nf, nv;   // the totals (at most 2 T and S: within int32 for cells <= 512)
    MLB_TRY(FN(t_download_i32)(be, &nf, tet_off + T, 1));
    MLB_TRY(FN(t_download_i32)(be, &nv, slot_off + d->S, 1));
    if (nf > INT32_MAX / 3 || nv > INT32_MAX / 3)
        return mlb_fail(MLB_ERR_ARG, "marching tets: surface too large (%lld faces)", (long long)nf);
    size_t mv = nv ? (size_t)nv : 1, mf = nf ? (size_t)nf : 1;
    MLB_TRY(surface_on_device(d, mv, mf));
    MLB_TRY(be->marching_tets_emit(d->verts, (int32_t*)d->vedge, d->weight, (int32_t*)d->faces, d->pos, d->sdf,
                                   (const int32_t*)d->tets, T, d->cells, tet_off, slot_off));
    d->nv = nv, d->nf = nf;
    if (on_device) {
        out->n_verts = nv;
        out->n_faces = nf;
        return MLB_OK;
    }
    return surface_down(d, out);
}

static mlb_status surface_down(const mlb_mt_device* d, FN(mlb_mt_surface)* out) {
    const FN(mlb_backend)* be = d->be;
    int nv = d->nv, nf = d->nf;
    size_t mv = nv ? (size_t)nv : 1, mf = nf ? (size_t)nf : 1;
    out->pos = malloc(sizeof(real) * 3 * mv);
    out->edge = malloc(sizeof(int32_t) * 2 * mv);
    out->weight = malloc(sizeof(real) * 2 * mv);
    out->faces = malloc(sizeof(int32_t) * 3 * mf);
    if (!out->pos || !out->edge || !out->weight || !out->faces) {
        FN(mt_surface_free)(out);
        return mlb_fail(MLB_ERR_NOMEM, "marching tets: out of memory for %d vertices", nv);
    }
    out->n_verts = nv;
    out->n_faces = nf;
    mlb_status s = be->download(out->pos, d->verts, 3 * (size_t)nv);
    if (!s) s = FN(t_download_i32)(be, out->edge, (const int32_t*)d->vedge, 2 * (size_t)nv);
    if (!s) s = be->download(out->weight, d->weight, 2 * (size_t)nv);
    if (!s) s = FN(t_download_i32)(be, out->faces, (const int32_t*)d->faces, 3 * (size_t)nf);
    if (s) FN(mt_surface_free)(out);
    return s;
}

mlb_status FN(mlb_mt_device_surface_host)(const mlb_mt_device* d, FN(mlb_mt_surface)* out) {
    if (!d || !out) return mlb_fail(MLB_ERR_ARG, "marching tets: no surface made on a table");
    memset(out, 0, sizeof *out);
    return surface_down(d, out);
}

// The op on the device's buffers; host buffers go through the handle's (dverts, dpos, dsdf) and back.
mlb_status FN(mlb_mt_device_backward)(mlb_mt_device* d, real* dpos, real* dsdf, const real* dverts,
                                      mlb_mt_place where) {
    if (!d) return mlb_fail(MLB_ERR_ARG, "marching tets: backward without a forward");
    if (!dpos && !dsdf) return MLB_OK;
    const FN(mlb_backend)* be = d->be;
    if (where == MLB_MT_TABLE)
        return be->marching_tets_backward(dpos, dsdf, dverts, d->weight, (const int32_t*)d->vedge, d->nv, d->pos, d->sdf,
                                          (const int32_t*)d->slot_off, d->cells);
    size_t V = (size_t)d->V;
    MLB_TRY(be->upload(d->dverts, dverts, 3 * (size_t)d->nv));
    if (dpos) MLB_TRY(be->upload(d->dpos, dpos, 3 * V));
    if (dsdf) MLB_TRY(be->upload(d->dsdf, dsdf, V));
    MLB_TRY(FN(mlb_mt_device_backward)(d, dpos ? d->dpos : NULL, dsdf ? d->dsdf : NULL, d->dverts, MLB_MT_TABLE));
    if (dpos) MLB_TRY(be->download(dpos, d->dpos, 3 * V));
    if (dsdf) MLB_TRY(be->download(dsdf, d->dsdf, V));
    return MLB_OK;
}

mlb_status FN(mlb_mt_device_surface)(const mlb_mt_device* d, const real** verts, const int32_t** faces) {
    if (!d) return mlb_fail(MLB_ERR_ARG, "marching tets: no forward");
    *verts = d->verts;
    *faces = (const int32_t*)d->faces;
    return MLB_OK;
}
