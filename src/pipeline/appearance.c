// The differentiable appearance renderer and the material smoothness regulariser
// (include/matlaber/appearance.h, docs/appearance.md). Dual-compiled (float / double _f64), see
// core/real.h.
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/appearance.h"
#include "matlaber/raster.h"
#include "matlaber/rng.h"
#include "core/real.h"
#include "nn/raster_table.h"
#include "appearance_device.h"

#ifdef MLB_F64
#define SHADE_FORWARD mlb_shade_forward_f64
#define SHADE_BACKWARD mlb_shade_backward_f64
#else
#define SHADE_FORWARD mlb_shade_forward
#define SHADE_BACKWARD mlb_shade_backward
#endif

#define STREAM_SMOOTH 0x5A17
enum { ATTR_C = 6 };   // per vertex: position 3, normal 3

// ---- linear → sRGB with the clamp to [0, 1] ------------------------------------------------------
static inline real FN(srgb_clamped)(real x) {
    if (!(x > 0)) return 0;   // (NaN too)
    if (x >= 1) return 1;
    return x <= (real)0.0031308 ? (real)12.92 * x : (real)1.055 * R_POW(x, (real)(1.0 / 2.4)) - (real)0.055;
}
// d srgb_clamped / dx (0 where clamped)
static inline real FN(srgb_clamped_d)(real x) {
    if (!(x > 0) || x >= 1) return 0;
    return x <= (real)0.0031308 ? (real)12.92 : (real)(1.055 / 2.4) * R_POW(x, (real)(1.0 / 2.4 - 1.0));
}

// ---- growable scratch ----------------------------------------------------------------------------
typedef struct { void* p; size_t cap; } abuf;
static void* abuf_get(abuf* b, size_t bytes) {
    if (bytes > b->cap || !b->p) {
        free(b->p);
        b->p = malloc(bytes ? bytes : 1);
        b->cap = b->p ? bytes : 0;
    }
    return b->p;
}

enum {
    B_ATTR, B_POS, B_NORMALS, B_CLIP, B_ADJ, B_TRI, B_BARY, B_DEPTH, B_COLOR, B_WEIGHTS, B_AA, B_PIX, B_WHERE, B_START,
    B_PTS, B_NRM, B_VDIR, B_K, B_KD, B_KS, B_KR, B_RGB, B_LIGHTS,
    B_DAA, B_DCOLOR, B_DRGB, B_DKD, B_DKS, B_DKR, B_DK, B_COUNT
};

struct FN(mlb_appearance_state) {
    abuf b[B_COUNT];
    mlb_raster_ctx* ctx;                  // the double pass's raster scratch (the float one goes through a->be)
    // the last render
    int kept, n_views, res, ss, V, F, n_points;
    int v0, v1;                           // the views rendered: [v0, v1) (a part, or all)
    const int32_t* faces;
    int32_t *adj, *tri, *where, *start;   // start [n_views + 1]: first point of each view
    real *clip, *depth, *color, *weights; // per view: [V,4], [P], [P,4], [P,2]
    real *pts, *nrm, *vdir, *kd, *ks, *kr, *rgb;
    mlb_envlight* lights;                 // [n_views]: copies with the view's rotation
    appearance_device* dev;               // the shading on the material network's device (float)
};

void FN(mlb_appearance_free)(FN(mlb_appearance)* a) {
    struct FN(mlb_appearance_state)* s = a->state;
    if (s) {
        for (int i = 0; i < B_COUNT; i++) free(s->b[i].p);
        mlb_raster_ctx_free(s->ctx);
        appearance_device_free(s->dev);
        free(s);
    }
    a->state = NULL;
}

const real* FN(mlb_appearance_points)(const FN(mlb_appearance)* a, int* n) {
    const struct FN(mlb_appearance_state)* s = a->state;
    *n = s ? s->n_points : 0;
    return s && s->n_points ? s->pts : NULL;
}

// Vertex attributes [V,6] = (position, normal) of the mesh in real; normals computed when absent.
static mlb_status FN(mesh_attr)(struct FN(mlb_appearance_state)* s, const mlb_mesh* mesh, real* attr) {
    const float* vn = mesh->normal;
    if (!vn) {   // a shallow copy gets the normals; the caller's mesh stays as it is
        mlb_mesh tmp = *mesh;
        tmp.normal = NULL;
        MLB_TRY(mlb_mesh_compute_normals(&tmp));
        float* keep = abuf_get(&s->b[B_NORMALS], sizeof(float) * 3 * (size_t)mesh->n_verts);
        if (!keep) { free(tmp.normal); return mlb_fail(MLB_ERR_NOMEM, "appearance: out of memory"); }
        memcpy(keep, tmp.normal, sizeof(float) * 3 * (size_t)mesh->n_verts);
        free(tmp.normal);
        vn = keep;
    }
    for (size_t i = 0; i < (size_t)mesh->n_verts; i++)
        for (int c = 0; c < 3; c++) {
            attr[ATTR_C * i + c] = (real)mesh->pos[3 * i + c];
            attr[ATTR_C * i + 3 + c] = (real)vn[3 * i + c];
        }
    return MLB_OK;
}

// Surface point, unit normal turned towards the eye and unit view direction of an interpolated
// pixel a = (position, normal): the computation of mlb_render_shaded, in double.
static void FN(pixel_geometry)(const real* a, const double eye[3], real* p, real* nrm, real* v) {
    double vv[3], nn[3], lv = 0, ln = 0, dot = 0;
    for (int c = 0; c < 3; c++) {
        vv[c] = eye[c] - (double)a[c];
        nn[c] = (double)a[3 + c];
        lv += vv[c] * vv[c];
        ln += nn[c] * nn[c];
    }
    lv = sqrt(lv);
    ln = sqrt(ln);
    if (!(lv > 0) || !(ln > 0)) { nn[0] = vv[0]; nn[1] = vv[1]; nn[2] = vv[2]; ln = lv; }
    if (!(lv > 0)) { lv = ln = 1; vv[0] = nn[0] = 0; vv[1] = nn[1] = 0; vv[2] = nn[2] = 1; }
    for (int c = 0; c < 3; c++) { vv[c] /= lv; nn[c] /= ln; dot += vv[c] * nn[c]; }
    double flip = dot < 0 ? -1 : 1;   // two-sided: shade the side the camera sees
    for (int c = 0; c < 3; c++) {
        p[c] = a[c];
        nrm[c] = (real)(flip * nn[c]);
        v[c] = (real)vv[c];
    }
}

static mlb_status FN(check_mesh)(const mlb_mesh* mesh, int res, int ss, const char* who) {
    if (!mesh || !mesh->pos || !mesh->faces || mesh->n_verts < 1 || mesh->n_faces < 1)
        return mlb_fail(MLB_ERR_ARG, "%s: empty mesh", who);
    if (res < 1 || ss < 1 || (long)res * ss > MLB_RASTER_MAX_SIZE)
        return mlb_fail(MLB_ERR_ARG, "%s: size %d at supersampling %d (the render must be 1..%d pixels)", who, res, ss,
                        MLB_RASTER_MAX_SIZE);
    return MLB_OK;
}

// The split-sum shading of every view's samples: on the material network's device when it has one
// (float build), else per view on the CPU.
// Views [s->v0, s->v1) (this process's part). The device path sees the part as a render of its own
// (starts relative to the part's first point).
static mlb_status FN(shade_views)(struct FN(mlb_appearance_state)* s, const FN(mlb_material_net)* net,
                                  const mlb_envlight* const* lights, const mlb_view* views, mlb_fresnel fresnel) {
    int v0 = s->v0, v1 = s->v1;
    for (int v = v0; v < v1; v++) {
        s->lights[v] = *lights[views[v].env];
        mlb_envlight_set_rotation(&s->lights[v], (float)(views[v].env_rotation_deg * (M_PI / 180.0)));
    }
#ifndef MLB_F64
    if (net->dev) {
        int m = v1 - v0;
        const mlb_envlight* source[m > 0 ? m : 1];
        int32_t rel[m + 1];
        for (int v = 0; v < m; v++) source[v] = lights[views[v0 + v].env];
        for (int v = 0; v <= m; v++) rel[v] = s->start[v0 + v] - s->start[v0];
        size_t o = (size_t)s->start[v0];
        return appearance_device_shade(&s->dev, mlb_field_backend(net), s->rgb + 3 * o, s->kd + 3 * o, s->ks + 3 * o,
                                       s->kr + o, s->nrm + 3 * o, s->vdir + 3 * o, rel, m, s->lights + v0, source, fresnel);
    }
#else
    (void)net;
#endif
    for (int v = v0; v < v1; v++) {
        int j0 = s->start[v], m = s->start[v + 1] - j0;
        size_t o = (size_t)j0;
        if (m > 0)
            MLB_TRY(SHADE_FORWARD(s->rgb + 3 * o, s->kd + 3 * o, s->ks + 3 * o, s->kr + o, s->nrm + 3 * o, s->vdir + 3 * o, m,
                                  &s->lights[v], fresnel));
    }
    return MLB_OK;
}

// dkd, dks, dkr (zeroed by the caller) += the shading's gradients from drgb, the rendered views.
static mlb_status FN(shade_views_backward)(struct FN(mlb_appearance_state)* s, const FN(mlb_material_net)* net,
                                           real* dkd, real* dks, real* dkr, const real* drgb, mlb_fresnel fresnel) {
#ifndef MLB_F64
    if (net->dev) {
        size_t o = (size_t)s->start[s->v0];
        return appearance_device_shade_backward(s->dev, dkd + 3 * o, dks + 3 * o, dkr + o, drgb + 3 * o);
    }
#else
    (void)net;
#endif
    for (int v = s->v0; v < s->v1; v++) {
        int j0 = s->start[v], m = s->start[v + 1] - j0;
        size_t o = (size_t)j0;
        if (m > 0)
            MLB_TRY(SHADE_BACKWARD(dkd + 3 * o, dks + 3 * o, dkr + o, NULL, NULL, drgb + 3 * o, s->kd + 3 * o, s->ks + 3 * o,
                                   s->kr + o, s->nrm + 3 * o, s->vdir + 3 * o, m, &s->lights[v], fresnel));
    }
    return MLB_OK;
}

// The views rendered: [*v0, *v1) of n (all unless the caller set a part).
static void FN(part_range)(const FN(mlb_appearance)* a, int n, int* v0, int* v1) {
    *v0 = 0;
    *v1 = n;
    if (a->part_count > 0 && a->part_first >= 0 && a->part_first + a->part_count <= n) {
        *v0 = a->part_first;
        *v1 = a->part_first + a->part_count;
    } else if (a->part_count < 0) {   // a rank with no view of this step
        *v0 = *v1 = a->part_first >= 0 && a->part_first < n ? a->part_first : n;
    }
}

mlb_status FN(mlb_appearance_render)(FN(mlb_appearance)* a, FN(mlb_material_net)* net, const mlb_mesh* mesh,
                                     const mlb_envlight* const* lights, const mlb_view* views, int n, int res, int ss,
                                     real* images, int keep_for_backward) {
    if (a->state) a->state->kept = 0;   // a failed render leaves nothing to backpropagate
    MLB_TRY(FN(check_mesh)(mesh, res, ss, "appearance render"));
    if (n < 1 || !views || !lights || !images) return mlb_fail(MLB_ERR_ARG, "appearance render: %d views, or a NULL argument", n);
    for (int v = 0; v < n; v++)
        if (views[v].env < 0 || !lights[views[v].env])
            return mlb_fail(MLB_ERR_ARG, "appearance render: view %d asks for environment %d, which is not loaded", v, views[v].env);
    if (!a->state) {
        a->state = calloc(1, sizeof *a->state);
        if (!a->state) return mlb_fail(MLB_ERR_NOMEM, "appearance render: out of memory");
    }
    struct FN(mlb_appearance_state)* s = a->state;
    s->kept = 0;
    s->n_points = 0;
    if (!s->ctx && !(s->ctx = mlb_raster_ctx_create())) return mlb_fail(MLB_ERR_NOMEM, "appearance render: out of memory");
    int S = res * ss, V = mesh->n_verts, F = mesh->n_faces;
    size_t P = (size_t)S * S, nv = (size_t)n;
    real* attr = abuf_get(&s->b[B_ATTR], sizeof(real) * ATTR_C * (size_t)V);
    s->clip = abuf_get(&s->b[B_CLIP], sizeof(real) * 4 * (size_t)V * nv);
    s->adj = abuf_get(&s->b[B_ADJ], sizeof(int32_t) * 3 * (size_t)F);
    s->tri = abuf_get(&s->b[B_TRI], sizeof(int32_t) * P * nv);
    real* bary = abuf_get(&s->b[B_BARY], sizeof(real) * 2 * P * nv);
    s->depth = abuf_get(&s->b[B_DEPTH], sizeof(real) * P * nv);
    s->color = abuf_get(&s->b[B_COLOR], sizeof(real) * 4 * P * nv);
    s->weights = abuf_get(&s->b[B_WEIGHTS], sizeof(real) * 2 * P * nv);
    real* aa = abuf_get(&s->b[B_AA], sizeof(real) * 4 * P);
    real* pix = abuf_get(&s->b[B_PIX], sizeof(real) * ATTR_C * P);
    s->start = abuf_get(&s->b[B_START], sizeof(int32_t) * (nv + 1));
    s->lights = abuf_get(&s->b[B_LIGHTS], sizeof(mlb_envlight) * nv);
    if (!attr || !s->clip || !s->adj || !s->tri || !bary || !s->depth || !s->color || !s->weights || !aa || !pix || !s->start ||
        !s->lights)
        return mlb_fail(MLB_ERR_NOMEM, "appearance render: out of memory (%d views at %dx%d)", n, S, S);
    real* pos = abuf_get(&s->b[B_POS], sizeof(real) * 3 * (size_t)V);
    if (!pos) return mlb_fail(MLB_ERR_NOMEM, "appearance render: out of memory");
    MLB_TRY(FN(mesh_attr)(s, mesh, attr));
    for (size_t i = 0; i < 3 * (size_t)V; i++) pos[i] = (real)mesh->pos[i];
    MLB_TRY(mlb_edge_topology(s->adj, mesh->faces, F, V));
    s->faces = mesh->faces;
    s->V = V;
    s->F = F;
    s->n_views = n;
    s->res = res;
    s->ss = ss;

    // rasterize every view of the part, count the covered samples (the other views have none)
    FN(part_range)(a, n, &s->v0, &s->v1);
    int32_t* counts = s->start + 1;   // counts[v], then made into starts in place
    memset(s->start, 0, sizeof(int32_t) * (nv + 1));
    for (int v = s->v0; v < s->v1; v++) {
        real* clip = s->clip + 4 * (size_t)V * v;
        FN(mlb_transform_points)(clip, pos, V, &views[v].cam.view_proj);
        int32_t* tri = s->tri + P * v;
        MLB_TRY(FN(rt_rasterize)(a->be, s->ctx, tri, bary + 2 * P * v, s->depth + P * v, clip, V, mesh->faces, F, S, S));
        int32_t c = 0;
        for (size_t i = 0; i < P; i++) c += tri[i] >= 0;
        counts[v] = c;
    }
    size_t total = 0;
    for (int v = 0; v < n; v++) {
        total += (size_t)counts[v];
        if (total > (size_t)INT32_MAX / 8) return mlb_fail(MLB_ERR_ARG, "appearance render: too many samples (%zu)", total);
    }
    for (int v = 0; v < n; v++) s->start[v + 1] += s->start[v];
    int N = (int)total;
    size_t NN = total ? total : 1;
    s->where = abuf_get(&s->b[B_WHERE], sizeof(int32_t) * NN);
    s->pts = abuf_get(&s->b[B_PTS], sizeof(real) * 3 * NN);
    s->nrm = abuf_get(&s->b[B_NRM], sizeof(real) * 3 * NN);
    s->vdir = abuf_get(&s->b[B_VDIR], sizeof(real) * 3 * NN);
    real* k = abuf_get(&s->b[B_K], sizeof(real) * 7 * NN);
    s->kd = abuf_get(&s->b[B_KD], sizeof(real) * 3 * NN);
    s->ks = abuf_get(&s->b[B_KS], sizeof(real) * 3 * NN);
    s->kr = abuf_get(&s->b[B_KR], sizeof(real) * NN);
    s->rgb = abuf_get(&s->b[B_RGB], sizeof(real) * 3 * NN);
    if (!s->where || !s->pts || !s->nrm || !s->vdir || !k || !s->kd || !s->ks || !s->kr || !s->rgb)
        return mlb_fail(MLB_ERR_NOMEM, "appearance render: out of memory (%d samples)", N);

    // surface points, normals and view directions of every covered sample, view-major
    for (int v = s->v0; v < s->v1; v++) {
        const int32_t* tri = s->tri + P * v;
        MLB_TRY(FN(rt_interpolate)(a->be, pix, attr, V, ATTR_C, tri, bary + 2 * P * v, mesh->faces, F, S, S));
        int j = s->start[v];
        for (size_t i = 0; i < P; i++) {
            if (tri[i] < 0) continue;
            FN(pixel_geometry)(pix + ATTR_C * i, views[v].cam.eye, s->pts + 3 * (size_t)j, s->nrm + 3 * (size_t)j,
                               s->vdir + 3 * (size_t)j);
            s->where[j++] = (int32_t)i;
        }
    }
    s->n_points = N;

    // the material of every sample of the part in one batch
    if (N > 0) {
        if (keep_for_backward) MLB_TRY(FN(material_net_forward)(net, k, NULL, s->pts, N));
        else MLB_TRY(FN(material_net_eval)(net, s->pts, (size_t)N, k, NULL));
    }
    for (int i = 0; i < N; i++) {
        for (int c = 0; c < 3; c++) {
            s->kd[3 * (size_t)i + c] = k[7 * (size_t)i + c];
            s->ks[3 * (size_t)i + c] = k[7 * (size_t)i + 3 + c];
        }
        s->kr[i] = k[7 * (size_t)i + 6];
    }

    // shade; then sRGB, composite, antialias, downsample: per view
    MLB_TRY(FN(shade_views)(s, net, lights, views, a->fresnel));
    size_t p = (size_t)res * res;
    for (int v = s->v0; v < s->v1; v++) {
        int j0 = s->start[v], m = s->start[v + 1] - j0;
        real* color = s->color + 4 * P * v;
        memset(color, 0, sizeof(real) * 4 * P);
        for (int j = j0; j < j0 + m; j++) {
            real* c = color + 4 * (size_t)s->where[j];
            for (int ch = 0; ch < 3; ch++) c[ch] = FN(srgb_clamped)(s->rgb[3 * (size_t)j + ch]);
            c[3] = 1;
        }
        real* clip = s->clip + 4 * (size_t)V * v;
        real* out = images + 4 * p * v;
        real* dst = ss == 1 ? out : aa;
        MLB_TRY(FN(rt_antialias)(a->be, s->ctx, dst, s->weights + 2 * P * v, color, 4, s->tri + P * v, s->depth + P * v,
                                 clip, V, mesh->faces, s->adj, F, S, S));
        if (ss > 1) FN(mlb_downsample_box)(out, aa, res, res, 4, ss);
    }
    s->kept = keep_for_backward != 0;
    return MLB_OK;
}

mlb_status FN(mlb_appearance_backward)(FN(mlb_appearance)* a, FN(mlb_material_net)* net, const real* dimages) {
    struct FN(mlb_appearance_state)* s = a->state;
    if (!s || !s->kept) return mlb_fail(MLB_ERR_ARG, "appearance backward: no render kept for backward");
    int N = s->n_points, n = s->n_views, S = s->res * s->ss, V = s->V, F = s->F;
    if (N == 0) return MLB_OK;   // nothing covered: no material was seen
    if (net->n != N)
        return mlb_fail(MLB_ERR_ARG, "appearance backward: the material network's cache holds %d points, the render %d "
                                     "(another forward ran in between)", net->n, N);
    size_t P = (size_t)S * S, p = (size_t)s->res * s->res, NN = (size_t)N;
    real* daa = s->ss > 1 ? abuf_get(&s->b[B_DAA], sizeof(real) * 4 * P) : NULL;
    real* dcolor = abuf_get(&s->b[B_DCOLOR], sizeof(real) * 4 * P);
    real* drgb = abuf_get(&s->b[B_DRGB], sizeof(real) * 3 * NN);
    real* dkd = abuf_get(&s->b[B_DKD], sizeof(real) * 3 * NN);
    real* dks = abuf_get(&s->b[B_DKS], sizeof(real) * 3 * NN);
    real* dkr = abuf_get(&s->b[B_DKR], sizeof(real) * NN);
    real* dk = abuf_get(&s->b[B_DK], sizeof(real) * 7 * NN);
    if ((s->ss > 1 && !daa) || !dcolor || !drgb || !dkd || !dks || !dkr || !dk)
        return mlb_fail(MLB_ERR_NOMEM, "appearance backward: out of memory");
    memset(dkd, 0, sizeof(real) * 3 * NN);
    memset(dks, 0, sizeof(real) * 3 * NN);
    memset(dkr, 0, sizeof(real) * NN);
    (void)n;
    for (int v = s->v0; v < s->v1; v++) {
        const real* dout = dimages + 4 * p * v;
        if (s->ss > 1) {
            memset(daa, 0, sizeof(real) * 4 * P);
            FN(mlb_downsample_box_backward)(daa, dout, s->res, s->res, 4, s->ss);
            dout = daa;
        }
        memset(dcolor, 0, sizeof(real) * 4 * P);
        MLB_TRY(FN(rt_antialias_backward)(a->be, s->ctx, dcolor, NULL, dout, s->weights + 2 * P * v, s->color + 4 * P * v,
                                          4, s->tri + P * v, s->depth + P * v, s->clip + 4 * (size_t)V * v, V, s->faces,
                                          s->adj, F, S, S));
        // colour = sRGB(clamp(L)) at covered samples (the coverage channel does not depend on the material)
        for (int j = s->start[v]; j < s->start[v + 1]; j++)
            for (int c = 0; c < 3; c++)
                drgb[3 * (size_t)j + c] = dcolor[4 * (size_t)s->where[j] + c] * FN(srgb_clamped_d)(s->rgb[3 * (size_t)j + c]);
    }
    MLB_TRY(FN(shade_views_backward)(s, net, dkd, dks, dkr, drgb, a->fresnel));
    for (int i = 0; i < N; i++) {
        for (int c = 0; c < 3; c++) {
            dk[7 * (size_t)i + c] = dkd[3 * (size_t)i + c];
            dk[7 * (size_t)i + 3 + c] = dks[3 * (size_t)i + c];
        }
        dk[7 * (size_t)i + 6] = dkr[i];
    }
    return FN(material_net_backward)(net, dk, NULL);
}

mlb_status FN(mlb_material_smoothness)(FN(mlb_material_net)* net, const real* pts, int n, double sigma, double weight,
                                       double weight_spec, uint64_t seed, long step, int backward, double* loss) {
    return FN(mlb_material_smoothness_part)(net, pts, n, 0, n, sigma, weight, weight_spec, seed, step, backward, loss);
}

// The points [first, first + count) of the n: the whole term's scales (1/n) and noise indices, so
// that the parts of a partition add up to the whole (the same code, and bits, for the whole).
mlb_status FN(mlb_material_smoothness_part)(FN(mlb_material_net)* net, const real* pts, int n, int first, int count,
                                            double sigma, double weight, double weight_spec, uint64_t seed, long step,
                                            int backward, double* loss) {
    if (loss) *loss = 0;
    if (n < 1 || n > INT32_MAX / 2 || !pts) return mlb_fail(MLB_ERR_ARG, "material smoothness: %d points", n);
    if (first < 0 || count < 0 || first > n - count)
        return mlb_fail(MLB_ERR_ARG, "material smoothness: points [%d, %d) of %d", first, first + count, n);
    if (!(sigma >= 0) || !isfinite(sigma) || !isfinite(weight) || !isfinite(weight_spec))
        return mlb_fail(MLB_ERR_ARG, "material smoothness: sigma %g, weights %g, %g", sigma, weight, weight_spec);
    if (count == 0) return MLB_OK;
    size_t nn = (size_t)count;
    pts += 3 * (size_t)first;
    real* x = malloc(sizeof(real) * 6 * nn);    // [2·count, 3]: the points, then the jittered points
    real* k = malloc(sizeof(real) * 14 * nn);   // [2·count, 7]
    if (!x || !k) { free(x); free(k); return mlb_fail(MLB_ERR_NOMEM, "material smoothness: out of memory (%d points)", count); }
    uint64_t base = ((uint64_t)step << 32) + 3 * (uint64_t)first;
    for (size_t i = 0; i < 3 * nn; i++) {
        x[i] = pts[i];
        x[3 * nn + i] = pts[i] + (real)(sigma * mlb_rng_normal_f64(seed, STREAM_SMOOTH, base + i));
    }
    mlb_status st = FN(material_net_forward)(net, k, NULL, x, 2 * count);
    if (!st) {
        // channel c's scale: weight / 3n for kd (0-2), weight_spec / 4n for ks and kr (3-6)
        const double scale_kd = weight / (3.0 * n), scale_spec = weight_spec / (4.0 * n);
        const int nc = weight_spec != 0 ? 7 : 3;
        double sum_kd = 0, sum_spec = 0;
        for (size_t i = 0; i < nn; i++)
            for (int c = 0; c < nc; c++) {
                double d = fabs((double)k[7 * i + c] - (double)k[7 * (nn + i) + c]);
                if (c < 3) sum_kd += d;
                else sum_spec += d;
            }
        if (loss) *loss = scale_kd * sum_kd + scale_spec * sum_spec;
        if (backward) {
            // d|a − b| = sign(a − b) (0 at a = b); channels without a weight get 0. In place: each
            // pair (i, n + i) is read before it is overwritten.
            for (size_t i = 0; i < nn; i++)
                for (int c = 0; c < 7; c++) {
                    double scale = c < 3 ? scale_kd : scale_spec;
                    real d = k[7 * i + c] - k[7 * (nn + i) + c];
                    real g = (real)(c >= nc ? 0 : d > 0 ? scale : d < 0 ? -scale : 0);
                    k[7 * i + c] = g;
                    k[7 * (nn + i) + c] = -g;
                }
            st = FN(material_net_backward)(net, k, NULL);
        }
    }
    free(x);
    free(k);
    return st;
}

#ifndef MLB_F64
mlb_status mlb_appearance_maps(const mlb_material_net* net, const mlb_mesh* mesh, const mlb_view* view, int res,
                               float* kd_img, float* ks_img, float* kr_img, float* normal_img) {
    return mlb_appearance_maps_on(NULL, net, mesh, view, res, kd_img, ks_img, kr_img, normal_img);
}

mlb_status mlb_appearance_maps_on(const mlb_backend* be, const mlb_material_net* net, const mlb_mesh* mesh,
                                  const mlb_view* view, int res, float* kd_img, float* ks_img, float* kr_img,
                                  float* normal_img) {
    MLB_TRY(check_mesh(mesh, res, 1, "appearance maps"));
    enum { C = 11 };   // kd 3, ks 3, kr 1, normal 3, coverage 1
    int V = mesh->n_verts, F = mesh->n_faces;
    size_t P = (size_t)res * res;
    struct mlb_appearance_state st;   // only for its normals buffer
    memset(&st, 0, sizeof st);
    float* attr = malloc(sizeof(float) * ATTR_C * (size_t)V);
    float* clip = malloc(sizeof(float) * 4 * (size_t)V);
    int32_t* adj = malloc(sizeof(int32_t) * 3 * (size_t)F);
    int32_t* tri = malloc(sizeof(int32_t) * P);
    float* bary = malloc(sizeof(float) * 2 * P);
    float* depth = malloc(sizeof(float) * P);
    float* pix = malloc(sizeof(float) * ATTR_C * P);
    float* img = malloc(sizeof(float) * C * P);
    float* aa = malloc(sizeof(float) * C * P);
    float *pts = NULL, *k = NULL;
    int32_t* where = NULL;
    mlb_status s = (attr && clip && adj && tri && bary && depth && pix && img && aa)
                       ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "appearance maps: out of memory (%dx%d)", res, res);
    if (!s) s = mesh_attr(&st, mesh, attr);
    if (!s) s = mlb_edge_topology(adj, mesh->faces, F, V);
    if (!s) {
        mlb_transform_points(clip, mesh->pos, V, &view->cam.view_proj);
        s = rt_rasterize(be, NULL, tri, bary, depth, clip, V, mesh->faces, F, res, res);
    }
    if (!s) s = rt_interpolate(be, pix, attr, V, ATTR_C, tri, bary, mesh->faces, F, res, res);
    size_t N = 0;
    for (size_t i = 0; !s && i < P; i++) N += tri[i] >= 0;
    if (!s) {
        pts = malloc(sizeof(float) * 3 * (N ? N : 1));
        k = malloc(sizeof(float) * 7 * (N ? N : 1));
        where = malloc(sizeof(int32_t) * (N ? N : 1));
        if (!pts || !k || !where) s = mlb_fail(MLB_ERR_NOMEM, "appearance maps: out of memory");
    }
    if (!s) {
        memset(img, 0, sizeof(float) * C * P);
        size_t j = 0;
        for (size_t i = 0; i < P; i++) {
            if (tri[i] < 0) continue;
            float v[3];
            pixel_geometry(pix + ATTR_C * i, view->cam.eye, pts + 3 * j, img + C * i + 7, v);
            where[j++] = (int32_t)i;
        }
        if (N) s = material_net_eval(net, pts, N, k, NULL);
    }
    if (!s) {
        for (size_t j = 0; j < N; j++) {
            float* o = img + C * (size_t)where[j];
            memcpy(o, k + 7 * j, sizeof(float) * 7);
            o[10] = 1;
        }
        s = rt_antialias(be, NULL, aa, NULL, img, C, tri, depth, clip, V, mesh->faces, adj, F, res, res);
    }
    if (!s) {
        for (size_t i = 0; i < P; i++) {
            const float* o = aa + C * i;
            for (int c = 0; c < 3; c++) {
                if (kd_img) kd_img[3 * i + c] = o[c];
                if (ks_img) ks_img[3 * i + c] = o[3 + c];
                if (normal_img) normal_img[3 * i + c] = o[7 + c];
            }
            if (kr_img) kr_img[i] = o[6];
        }
    }
    free(st.b[B_NORMALS].p);
    free(attr); free(clip); free(adj); free(tri); free(bary); free(depth); free(pix); free(img); free(aa);
    free(pts); free(k); free(where);
    return s;
}
#endif
