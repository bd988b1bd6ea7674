// The differentiable appearance renderer and the material smoothness regulariser
// (include/matlaber/appearance.h, docs/appearance.md). Dual-compiled (float / double _f64), see
// core/real.h.
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/appearance.h"
#include "matlaber/mt_ops.h"
#include "matlaber/raster.h"
#include "matlaber/rng.h"
#include "core/real.h"
#include "nn/table_ops.h"

#define STREAM_SMOOTH 0x5A17
enum { ATTR_C = 6, MAX_LIGHTS = 64 };   // per vertex: position 3, normal 3

// ---- growable host scratch ------------------------------------------------------------------------
typedef struct { void* p; size_t cap; } abuf;
static void* abuf_get(abuf* b, size_t bytes) {
    if (bytes > b->cap || !b->p) {
        free(b->p);
        b->p = malloc(bytes ? bytes : 1);
        b->cap = b->p ? bytes : 0;
    }
    return b->p;
}

// host scratch, then the buffers on the render's table (int32 ones cast from real)
enum { H_ATTR, H_POS, H_ADJ, H_NORMALS, H_START, H_LIGHTS, H_KEYS, H_MESH_POS, H_MESH_FACES, H_MESH_NORMAL, H_COUNT };
enum {
    D_ATTR, D_POS, D_CLIP, D_FACES, D_ADJ, D_TRI, D_BARY, D_DEPTH, D_COLOR, D_WEIGHTS, D_AA, D_PIX, D_OUT, D_DOUT, D_INDEX,
    D_WHERE, D_PTS, D_NRM, D_VDIR, D_K, D_KD, D_KS, D_KR, D_RGB,
    D_DAA, D_DCOLOR, D_DRGB, D_DKD, D_DKS, D_DKR, D_DK, D_COUNT
};

struct FN(mlb_appearance_state) {
    abuf h[H_COUNT];
    FN(tbuf) d[D_COUNT];
    const FN(mlb_backend)* tb;            // the table d[] was allocated on
    // the last render
    int kept, n_views, res, ss, V, F, n_points;
    int v0, v1;                           // the views rendered: [v0, v1) (a part, or all)
    int32_t *adj, *tri, *where, *start;   // on the table but start [n_views + 1] (host): first sample of each view
    int32_t* faces;
    // The mesh on the table (pos, attr, faces, adj) is the one of the host copies H_MESH_*: a render
    // of the same mesh (the appearance stage's every step) uploads nothing of it again.
    int mesh_on_table, mesh_has_normal;
    real* pos;                            // [V,3] on the table: the views' clip coordinates are made there
    real *clip, *depth, *color, *weights; // per view: [V,4], [P], [P,4], [P,2]
    real *pts, *nrm, *vdir, *kd, *ks, *kr, *rgb;
    mlb_envlight* lights;                 // [n_views] (host): copies with the view's rotation
    const mlb_envlight** light_keys;      // [n_views] (host): the lights they are copies of
    int n_handles;                        // the lights made usable on the table, keyed by address
    const mlb_envlight* handle_key[MAX_LIGHTS];
    void* handle[MAX_LIGHTS];
};

// The render's table (NULL: the CPU's)
static const FN(mlb_backend)* FN(render_table)(const FN(mlb_appearance)* a) {
    return a->be ? a->be : FN(mlb_backend_cpu)();
}

static void FN(release_table)(struct FN(mlb_appearance_state)* s) {
    if (!s->tb) return;
    for (int i = 0; i < D_COUNT; i++) FN(tbuf_free)(s->tb, &s->d[i]);
    for (int i = 0; i < s->n_handles; i++) s->tb->light_free(s->handle[i]);
    s->n_handles = 0;
    s->tb = NULL;
    s->mesh_on_table = 0;
}

void FN(mlb_appearance_free)(FN(mlb_appearance)* a) {
    struct FN(mlb_appearance_state)* s = a->state;
    if (s) {
        FN(release_table)(s);
        for (int i = 0; i < H_COUNT; i++) free(s->h[i].p);
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
static mlb_status FN(mesh_attr)(abuf* normals, const mlb_mesh* mesh, real* attr) {
    const float* vn = mesh->normal;
    if (!vn) {   // a shallow copy gets the normals; the caller's mesh stays as it is
        mlb_mesh tmp = *mesh;
        tmp.normal = NULL;
        MLB_TRY(mlb_mesh_compute_normals(&tmp));
        float* keep = abuf_get(normals, sizeof(float) * 3 * (size_t)mesh->n_verts);
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

// 1 when mesh is the one already on the table (the same numbers, not merely the same address).
static int FN(mesh_is_on_table)(const struct FN(mlb_appearance_state)* s, const mlb_mesh* mesh) {
    size_t V = (size_t)mesh->n_verts, F = (size_t)mesh->n_faces;
    return s->mesh_on_table && s->V == mesh->n_verts && s->F == mesh->n_faces &&
           s->mesh_has_normal == (mesh->normal != NULL) && !memcmp(s->h[H_MESH_POS].p, mesh->pos, sizeof(float) * 3 * V) &&
           !memcmp(s->h[H_MESH_FACES].p, mesh->faces, sizeof(int32_t) * 3 * F) &&
           (!mesh->normal || !memcmp(s->h[H_MESH_NORMAL].p, mesh->normal, sizeof(float) * 3 * V));
}

// The mesh's positions, attributes [V,6], faces and edge topology on the table, and the host copies
// that recognise it next time.
static mlb_status FN(mesh_to_table)(struct FN(mlb_appearance_state)* s, const mlb_mesh* mesh) {
    const FN(mlb_backend)* tb = s->tb;
    int V = mesh->n_verts, F = mesh->n_faces;
    s->mesh_on_table = 0;
    real* attr_h = abuf_get(&s->h[H_ATTR], sizeof(real) * ATTR_C * (size_t)V);
    real* pos_h = abuf_get(&s->h[H_POS], sizeof(real) * 3 * (size_t)V);
    int32_t* adj_h = abuf_get(&s->h[H_ADJ], sizeof(int32_t) * 3 * (size_t)F);
    float* key_pos = abuf_get(&s->h[H_MESH_POS], sizeof(float) * 3 * (size_t)V);
    int32_t* key_faces = abuf_get(&s->h[H_MESH_FACES], sizeof(int32_t) * 3 * (size_t)F);
    float* key_normal = mesh->normal ? abuf_get(&s->h[H_MESH_NORMAL], sizeof(float) * 3 * (size_t)V) : NULL;
    if (!attr_h || !pos_h || !adj_h || !key_pos || !key_faces || (mesh->normal && !key_normal))
        return mlb_fail(MLB_ERR_NOMEM, "appearance render: out of memory");
    MLB_TRY(FN(mesh_attr)(&s->h[H_NORMALS], mesh, attr_h));
    for (size_t i = 0; i < 3 * (size_t)V; i++) pos_h[i] = (real)mesh->pos[i];
    MLB_TRY(mlb_edge_topology(adj_h, mesh->faces, F, V));
    real* attr = FN(tbuf_get)(tb, &s->d[D_ATTR], ATTR_C * (size_t)V);
    s->pos = FN(tbuf_get)(tb, &s->d[D_POS], 3 * (size_t)V);
    s->faces = (int32_t*)FN(tbuf_get)(tb, &s->d[D_FACES], 3 * (size_t)F);
    s->adj = (int32_t*)FN(tbuf_get)(tb, &s->d[D_ADJ], 3 * (size_t)F);
    if (!attr || !s->pos || !s->faces || !s->adj)
        return mlb_fail(MLB_ERR_NOMEM, "appearance render: out of memory on the %s (a mesh of %d vertices)",
                        mlb_device_name(tb->device), V);
    MLB_TRY(tb->upload(attr, attr_h, ATTR_C * (size_t)V));
    MLB_TRY(tb->upload(s->pos, pos_h, 3 * (size_t)V));
    MLB_TRY(FN(t_upload_i32)(tb, s->faces, mesh->faces, 3 * (size_t)F));
    MLB_TRY(FN(t_upload_i32)(tb, s->adj, adj_h, 3 * (size_t)F));
    memcpy(key_pos, mesh->pos, sizeof(float) * 3 * (size_t)V);
    memcpy(key_faces, mesh->faces, sizeof(int32_t) * 3 * (size_t)F);
    if (mesh->normal) memcpy(key_normal, mesh->normal, sizeof(float) * 3 * (size_t)V);
    s->mesh_has_normal = mesh->normal != NULL;
    s->V = V;
    s->F = F;
    s->mesh_on_table = 1;
    return MLB_OK;
}

static mlb_status FN(check_mesh)(const mlb_mesh* mesh, int res, int ss, const char* who) {
    if (!mesh || !mesh->pos || !mesh->faces || mesh->n_verts < 1 || mesh->n_faces < 1)
        return mlb_fail(MLB_ERR_ARG, "%s: empty mesh", who);
    if (res < 1 || ss < 1 || (long)res * ss > MLB_RASTER_MAX_SIZE)
        return mlb_fail(MLB_ERR_ARG, "%s: size %d at supersampling %d (the render must be 1..%d pixels)", who, res, ss,
                        MLB_RASTER_MAX_SIZE);
    return MLB_OK;
}

// The handle of `light` on the render's table, made on first use (kept for the state's life).
static mlb_status FN(light_handle)(struct FN(mlb_appearance_state)* s, const mlb_envlight* light, void** handle) {
    for (int i = 0; i < s->n_handles; i++)
        if (s->handle_key[i] == light) { *handle = s->handle[i]; return MLB_OK; }
    if (s->n_handles == MAX_LIGHTS) return mlb_fail(MLB_ERR_ARG, "appearance: more than %d environment lights", MAX_LIGHTS);
    MLB_TRY(s->tb->light_upload(&s->handle[s->n_handles], light));
    s->handle_key[s->n_handles] = light;
    *handle = s->handle[s->n_handles++];
    return MLB_OK;
}

// The split-sum shading of views [s->v0, s->v1): the table's shade under each view's light turned
// by its rotation.
static mlb_status FN(shade_views)(struct FN(mlb_appearance_state)* s, const mlb_envlight* const* lights,
                                  const mlb_view* views, mlb_fresnel fresnel) {
    for (int v = s->v0; v < s->v1; v++) {
        s->lights[v] = *lights[views[v].env];
        mlb_envlight_set_rotation(&s->lights[v], (float)(views[v].env_rotation_deg * (M_PI / 180.0)));
        int j0 = s->start[v], m = s->start[v + 1] - j0;
        size_t o = (size_t)j0;
        if (m == 0) continue;
        void* h;
        MLB_TRY(FN(light_handle)(s, s->light_keys[v], &h));
        MLB_TRY(s->tb->shade(s->rgb + 3 * o, s->kd + 3 * o, s->ks + 3 * o, s->kr + o, s->nrm + 3 * o, s->vdir + 3 * o, m,
                             h, s->lights[v].rotation, fresnel));
    }
    return MLB_OK;
}

// dkd, dks, dkr (zeroed by the caller) += the shading's gradients from drgb, views [v0, v1).
static mlb_status FN(shade_views_backward)(struct FN(mlb_appearance_state)* s, real* dkd, real* dks, real* dkr,
                                           const real* drgb, mlb_fresnel fresnel) {
    for (int v = s->v0; v < s->v1; v++) {
        int j0 = s->start[v], m = s->start[v + 1] - j0;
        size_t o = (size_t)j0;
        if (m == 0) continue;
        void* h;
        MLB_TRY(FN(light_handle)(s, s->light_keys[v], &h));
        MLB_TRY(s->tb->shade_backward(dkd + 3 * o, dks + 3 * o, dkr + o, NULL, NULL, drgb + 3 * o, s->kd + 3 * o,
                                      s->ks + 3 * o, s->kr + o, s->nrm + 3 * o, s->vdir + 3 * o, m, h,
                                      s->lights[v].rotation, fresnel));
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

// The material of the N samples, k [N,7] on the table: the net on the table's device runs there,
// a net on the host runs on the samples in place (the CPU's table: host memory).
static mlb_status FN(material_of_samples)(struct FN(mlb_appearance_state)* s, FN(mlb_material_net)* net, real* k,
                                          int N, int keep) {
    const FN(mlb_backend)* nb = FN(mlb_field_backend)(net);   // (a double net is on the host)
    if (nb) {
        if (nb->device != s->tb->device)
            return mlb_fail(MLB_ERR_ARG, "appearance render: the material network is on the %s, the render on the %s",
                            mlb_device_name(nb->device), mlb_device_name(s->tb->device));
        if (!keep) return mlb_fail(MLB_ERR_ARG, "appearance render: a render without backward needs the network on the host");
        return FN(mlb_field_forward_on_device)(net, k, s->pts, N);
    }
    if (s->tb->device != MLB_DEVICE_CPU)
        return mlb_fail(MLB_ERR_ARG, "appearance render: the material network is on the host, the render on the %s",
                        mlb_device_name(s->tb->device));
    if (keep) return FN(material_net_forward)(net, k, NULL, s->pts, N);
    return FN(material_net_eval)(net, s->pts, (size_t)N, k, NULL);
}

mlb_status FN(mlb_appearance_render)(FN(mlb_appearance)* a, FN(mlb_material_net)* net, const mlb_mesh* mesh,
                                     const mlb_envlight* const* lights, const mlb_view* views, int n, int res, int ss,
                                     real* images, int keep_for_backward) {
    if (a->state) a->state->kept = 0;   // a failed render leaves nothing to backpropagate
    MLB_TRY(FN(check_mesh)(mesh, res, ss, "appearance render"));
    if (n < 1 || !views || !lights || (!images && !a->images_on_table))
        return mlb_fail(MLB_ERR_ARG, "appearance render: %d views, or a NULL argument", n);
    for (int v = 0; v < n; v++)
        if (views[v].env < 0 || !lights[views[v].env])
            return mlb_fail(MLB_ERR_ARG, "appearance render: view %d asks for environment %d, which is not loaded", v, views[v].env);
    if (!a->state) {
        a->state = calloc(1, sizeof *a->state);
        if (!a->state) return mlb_fail(MLB_ERR_NOMEM, "appearance render: out of memory");
    }
    struct FN(mlb_appearance_state)* s = a->state;
    const FN(mlb_backend)* tb = FN(render_table)(a);
    if (s->tb != tb) FN(release_table)(s);   // buffers of another device
    s->tb = tb;
    s->kept = 0;
    s->n_points = 0;
    int S = res * ss, V = mesh->n_verts, F = mesh->n_faces;
    size_t P = (size_t)S * S, nv = (size_t)n, p = (size_t)res * res;
    FN(part_range)(a, n, &s->v0, &s->v1);
    size_t nr = (size_t)(s->v1 - s->v0);   // the views rendered
    if (P * nr >= (size_t)INT32_MAX)       // the coverage scan's indices are int32
        return mlb_fail(MLB_ERR_ARG, "appearance render: %zu views of %dx%d pixels are too many for one render", nr, S, S);
    // the mesh on the table once (the stage renders one mesh every step); the views' clip
    // coordinates are made there from it
    s->start = abuf_get(&s->h[H_START], sizeof(int32_t) * (nv + 1));
    s->lights = abuf_get(&s->h[H_LIGHTS], sizeof(mlb_envlight) * nv);
    s->light_keys = abuf_get(&s->h[H_KEYS], sizeof(mlb_envlight*) * nv);
    if (!s->start || !s->lights || !s->light_keys) return mlb_fail(MLB_ERR_NOMEM, "appearance render: out of memory");
    if (!FN(mesh_is_on_table)(s, mesh)) MLB_TRY(FN(mesh_to_table)(s, mesh));
    real* attr = s->d[D_ATTR].p;
    s->clip = FN(tbuf_get)(tb, &s->d[D_CLIP], 4 * (size_t)V * nv);
    s->tri = (int32_t*)FN(tbuf_get)(tb, &s->d[D_TRI], P * nv);
    real* bary = FN(tbuf_get)(tb, &s->d[D_BARY], 2 * P * nv);
    s->depth = FN(tbuf_get)(tb, &s->d[D_DEPTH], P * nv);
    s->color = FN(tbuf_get)(tb, &s->d[D_COLOR], 4 * P * nv);
    s->weights = FN(tbuf_get)(tb, &s->d[D_WEIGHTS], 2 * P * nv);
    real* aa = FN(tbuf_get)(tb, &s->d[D_AA], 4 * P);
    real* pix = FN(tbuf_get)(tb, &s->d[D_PIX], ATTR_C * P);
    real* out = FN(tbuf_get)(tb, &s->d[D_OUT], 4 * p * nv);   // every view's render [n, res, res, 4]
    real* dout = FN(tbuf_get)(tb, &s->d[D_DOUT], 4 * p * nv);
    int32_t* index = (int32_t*)FN(tbuf_get)(tb, &s->d[D_INDEX], P * nr + 1);
    if (!s->clip || !s->tri || !bary || !s->depth || !s->color || !s->weights || !aa ||
        !pix || !out || !dout || !index)
        return mlb_fail(MLB_ERR_NOMEM, "appearance render: out of memory on the %s (%d views at %dx%d)",
                        mlb_device_name(tb->device), n, S, S);
    s->n_views = n;
    s->res = res;
    s->ss = ss;

    // rasterize every view of the part; each covered pixel's sample index from the scan of the
    // coverage over the part's views (view-major, pixel order); the other views have no samples
    for (int v = s->v0; v < s->v1; v++) {
        s->light_keys[v] = lights[views[v].env];
        MLB_TRY(tb->transform_points(s->clip + 4 * (size_t)V * v, s->pos, V, views[v].cam.view_proj.m));
        MLB_TRY(tb->rasterize(s->tri + P * v, bary + 2 * P * v, s->depth + P * v, s->clip + 4 * (size_t)V * v,
                                 V, s->faces, F, S, S));
    }
    MLB_TRY(tb->covered_flags(index, s->tri + P * s->v0, P * nr));
    MLB_TRY(tb->scan_i32(index, index, (int)(P * nr)));
    // the views' first samples: 0 up to the part's first view, the scan at each later view's first
    // pixel (one value read per rendered view), the total after the part
    for (int v = 0; v <= n; v++) {
        if (v <= s->v0) { s->start[v] = 0; continue; }
        if (v > s->v1) { s->start[v] = s->start[s->v1]; continue; }
        MLB_TRY(FN(t_download_i32)(tb, &s->start[v], index + P * (size_t)(v - s->v0), 1));
    }
    int N = s->start[n];
    if ((size_t)N > (size_t)INT32_MAX / 8) return mlb_fail(MLB_ERR_ARG, "appearance render: too many samples (%d)", N);
    size_t NN = N ? (size_t)N : 1;
    s->where = (int32_t*)FN(tbuf_get)(tb, &s->d[D_WHERE], NN);
    s->pts = FN(tbuf_get)(tb, &s->d[D_PTS], 3 * NN);
    s->nrm = FN(tbuf_get)(tb, &s->d[D_NRM], 3 * NN);
    s->vdir = FN(tbuf_get)(tb, &s->d[D_VDIR], 3 * NN);
    real* k = FN(tbuf_get)(tb, &s->d[D_K], 7 * NN);
    s->kd = FN(tbuf_get)(tb, &s->d[D_KD], 3 * NN);
    s->ks = FN(tbuf_get)(tb, &s->d[D_KS], 3 * NN);
    s->kr = FN(tbuf_get)(tb, &s->d[D_KR], NN);
    s->rgb = FN(tbuf_get)(tb, &s->d[D_RGB], 3 * NN);
    if (!s->where || !s->pts || !s->nrm || !s->vdir || !k || !s->kd || !s->ks || !s->kr || !s->rgb)
        return mlb_fail(MLB_ERR_NOMEM, "appearance render: out of memory on the %s (%d samples)", mlb_device_name(tb->device), N);

    // surface points, normals and view directions of every covered sample
    for (int v = s->v0; v < s->v1; v++) {
        const int32_t* tri = s->tri + P * v;
        const double* eye = views[v].cam.eye;
        MLB_TRY(tb->interpolate(pix, attr, V, ATTR_C, tri, bary + 2 * P * v, s->faces, F, S, S));
        MLB_TRY(tb->gather_samples(s->pts, s->nrm, s->vdir, s->where, pix, tri, index + P * (size_t)(v - s->v0), (int)P,
                         eye[0], eye[1], eye[2]));
    }
    s->n_points = N;

    // the material of every sample of the part in one batch, split into kd, ks, kr
    if (N > 0) {
        MLB_TRY(FN(material_of_samples)(s, net, k, N, keep_for_backward));
        MLB_TRY(tb->copy_rows(s->kd, 3, k, 7, 3, NN));
        MLB_TRY(tb->copy_rows(s->ks, 3, k + 3, 7, 3, NN));
        MLB_TRY(tb->copy_rows(s->kr, 1, k + 6, 7, 1, NN));
    }

    // shade; then sRGB, composite, antialias, downsample: per view
    MLB_TRY(FN(shade_views)(s, lights, views, a->fresnel));
    for (int v = s->v0; v < s->v1; v++) {
        int j0 = s->start[v], m = s->start[v + 1] - j0;
        real* color = s->color + 4 * P * v;
        MLB_TRY(tb->zero(color, 4 * P));
        if (m > 0) MLB_TRY(tb->composite_srgb(color, s->rgb + 3 * (size_t)j0, s->where + j0, m));
        real* outv = out + 4 * p * v;
        real* dst = ss == 1 ? outv : aa;
        MLB_TRY(tb->antialias(dst, s->weights + 2 * P * v, color, 4, s->tri + P * v, s->depth + P * v,
                                 s->clip + 4 * (size_t)V * v, V, s->faces, s->adj, F, S, S));
        if (ss > 1) MLB_TRY(tb->downsample_box(outv, aa, res, res, 4, ss));
        if (images) MLB_TRY(tb->download(images + 4 * p * v, outv, 4 * p));
    }
    a->t_images = out;
    a->t_dimages = dout;
    if (a->images_on_table && s->v1 > s->v0)
        MLB_TRY(tb->zero(dout + 4 * p * s->v0, 4 * p * (size_t)(s->v1 - s->v0)));
    s->kept = keep_for_backward != 0;
    return MLB_OK;
}

static mlb_status FN(appearance_backward)(FN(mlb_appearance)* a, FN(mlb_material_net)* net, const real* dimages,
                                          const real* t_dimages);

mlb_status FN(mlb_appearance_backward)(FN(mlb_appearance)* a, FN(mlb_material_net)* net, const real* dimages) {
    if (!dimages) return mlb_fail(MLB_ERR_ARG, "appearance backward: NULL dimages");
    return FN(appearance_backward)(a, net, dimages, NULL);
}

mlb_status FN(mlb_appearance_backward_table)(FN(mlb_appearance)* a, FN(mlb_material_net)* net) {
    if (!a->images_on_table || !a->t_dimages)
        return mlb_fail(MLB_ERR_ARG, "appearance backward: no render kept its images on the table");
    return FN(appearance_backward)(a, net, NULL, a->t_dimages);
}

// The image gradient from the host (dimages, uploaded a view at a time) or on the table (t_dimages).
static mlb_status FN(appearance_backward)(FN(mlb_appearance)* a, FN(mlb_material_net)* net, const real* dimages,
                                          const real* t_dimages) {
    struct FN(mlb_appearance_state)* s = a->state;
    if (!s || !s->kept) return mlb_fail(MLB_ERR_ARG, "appearance backward: no render kept for backward");
    int N = s->n_points, S = s->res * s->ss, V = s->V, F = s->F;
    if (N == 0) return MLB_OK;   // nothing covered: no material was seen
    if (net->n != N)
        return mlb_fail(MLB_ERR_ARG, "appearance backward: the material network's cache holds %d points, the render %d "
                                     "(another forward ran in between)", net->n, N);
    const FN(mlb_backend)* tb = s->tb;
    size_t P = (size_t)S * S, p = (size_t)s->res * s->res, NN = (size_t)N;
    real* dout_all = s->d[D_DOUT].p;   // [n, res, res, 4]: each view's dimage, uploaded or given there
    real* daa = s->ss > 1 ? FN(tbuf_get)(tb, &s->d[D_DAA], 4 * P) : NULL;
    real* dcolor = FN(tbuf_get)(tb, &s->d[D_DCOLOR], 4 * P);
    real* drgb = FN(tbuf_get)(tb, &s->d[D_DRGB], 3 * NN);
    real* dkd = FN(tbuf_get)(tb, &s->d[D_DKD], 3 * NN);
    real* dks = FN(tbuf_get)(tb, &s->d[D_DKS], 3 * NN);
    real* dkr = FN(tbuf_get)(tb, &s->d[D_DKR], NN);
    real* dk = FN(tbuf_get)(tb, &s->d[D_DK], 7 * NN);
    if ((s->ss > 1 && !daa) || !dcolor || !drgb || !dkd || !dks || !dkr || !dk)
        return mlb_fail(MLB_ERR_NOMEM, "appearance backward: out of memory on the %s", mlb_device_name(tb->device));
    MLB_TRY(tb->zero(drgb, 3 * NN));
    MLB_TRY(tb->zero(dkd, 3 * NN));
    MLB_TRY(tb->zero(dks, 3 * NN));
    MLB_TRY(tb->zero(dkr, NN));
    for (int v = s->v0; v < s->v1; v++) {
        const real* dout = (t_dimages ? t_dimages : dout_all) + 4 * p * v;
        if (!t_dimages) MLB_TRY(tb->upload(dout_all + 4 * p * v, dimages + 4 * p * v, 4 * p));
        const real* dimg = dout;
        if (s->ss > 1) {
            MLB_TRY(tb->zero(daa, 4 * P));
            MLB_TRY(tb->downsample_box_backward(daa, dout, s->res, s->res, 4, s->ss));
            dimg = daa;
        }
        MLB_TRY(tb->zero(dcolor, 4 * P));
        MLB_TRY(tb->antialias_backward(dcolor, NULL, dimg, s->weights + 2 * P * v, s->color + 4 * P * v,
                                          4, s->tri + P * v, s->depth + P * v, s->clip + 4 * (size_t)V * v, V, s->faces,
                                          s->adj, F, S, S));
        // colour = sRGB(clamp(L)) at covered samples (the coverage channel does not depend on the material)
        int j0 = s->start[v], m = s->start[v + 1] - j0;
        if (m > 0) MLB_TRY(tb->composite_srgb_backward(drgb + 3 * (size_t)j0, dcolor, s->rgb + 3 * (size_t)j0, s->where + j0, m));
    }
    MLB_TRY(FN(shade_views_backward)(s, dkd, dks, dkr, drgb, a->fresnel));
    MLB_TRY(tb->copy_rows(dk, 7, dkd, 3, 3, NN));
    MLB_TRY(tb->copy_rows(dk + 3, 7, dks, 3, 3, NN));
    MLB_TRY(tb->copy_rows(dk + 6, 7, dkr, 1, 1, NN));
    if (FN(mlb_field_backend)(net)) return FN(mlb_field_backward_on_device)(net, dk);
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

mlb_status FN(mlb_material_latent_support_part)(FN(mlb_material_net)* net, const real* pts, int n, int first,
                                                int count, double radius, double weight, int backward, double* loss) {
    if (loss) *loss = 0;
    if (n < 1 || !pts) return mlb_fail(MLB_ERR_ARG, "material support: %d points", n);
    if (first < 0 || count < 0 || first > n - count)
        return mlb_fail(MLB_ERR_ARG, "material support: points [%d, %d) of %d", first, first + count, n);
    if (!(radius >= 0) || !isfinite(radius) || !isfinite(weight))
        return mlb_fail(MLB_ERR_ARG, "material support: radius %g, weight %g", radius, weight);
    if (net->cfg.mode != MLB_MATERIAL_LATENT) return mlb_fail(MLB_ERR_ARG, "material support: a direct-mode net has no codes");
    if (count == 0) return MLB_OK;
    size_t nn = (size_t)count;
    real* z = malloc(sizeof(real) * 4 * nn);   // [count, 4]
    if (!z) return mlb_fail(MLB_ERR_NOMEM, "material support: out of memory (%d points)", count);
    mlb_status st = FN(material_net_forward)(net, NULL, z, pts + 3 * (size_t)first, count);
    if (!st) {
        double sum = 0;
        for (size_t i = 0; i < nn; i++) {
            real* zi = z + 4 * i;
            double r = sqrt((double)zi[0] * zi[0] + (double)zi[1] * zi[1] + (double)zi[2] * zi[2] + (double)zi[3] * zi[3]);
            double over = r > radius ? r - radius : 0;
            sum += over * over;
            // dL/dz_i = weight/n · 2 (r − radius) z_i / r outside the ball, 0 inside (in place: z_i read first)
            double g = over > 0 ? weight / n * 2 * over / r : 0;
            for (int d = 0; d < 4; d++) zi[d] = (real)(g * zi[d]);
        }
        if (loss) *loss = weight / n * sum;
        if (backward) st = FN(field_backward_latent)(net, NULL, z, NULL);
    }
    free(z);
    return st;
}

mlb_status FN(mlb_appearance_maps)(const FN(mlb_backend)* be, const FN(mlb_material_net)* net, const mlb_mesh* mesh,
                                   const mlb_view* view, int res, real* kd_img, real* ks_img, real* kr_img,
                                   real* normal_img) {
    MLB_TRY(FN(check_mesh)(mesh, res, 1, "appearance maps"));
    const FN(mlb_backend)* tb = be ? be : FN(mlb_backend_cpu)();
    enum { C = 11 };   // kd 3, ks 3, kr 1, normal 3, coverage 1
    int V = mesh->n_verts, F = mesh->n_faces;
    size_t P = (size_t)res * res;
    abuf normals = {0};
    real* pos = malloc(sizeof(real) * 3 * (size_t)V);
    real* attr = malloc(sizeof(real) * ATTR_C * (size_t)V);
    real* clip = malloc(sizeof(real) * 4 * (size_t)V);
    int32_t* adj = malloc(sizeof(int32_t) * 3 * (size_t)F);
    int32_t* tri = malloc(sizeof(int32_t) * P);
    real* bary = malloc(sizeof(real) * 2 * P);
    real* depth = malloc(sizeof(real) * P);
    real* pix = malloc(sizeof(real) * ATTR_C * P);
    real* img = malloc(sizeof(real) * C * P);
    real* aa = malloc(sizeof(real) * C * P);
    real *pts = NULL, *nrm = NULL, *vdir = NULL, *k = NULL;
    int32_t *where = NULL, *index = malloc(sizeof(int32_t) * (P + 1));
    mlb_status s = (pos && attr && clip && adj && tri && bary && depth && pix && img && aa && index)
                       ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "appearance maps: out of memory (%dx%d)", res, res);
    if (!s) s = FN(mesh_attr)(&normals, mesh, attr);
    if (!s) s = mlb_edge_topology(adj, mesh->faces, F, V);
    if (!s) {
        for (size_t i = 0; i < 3 * (size_t)V; i++) pos[i] = (real)mesh->pos[i];
        FN(mlb_transform_points)(clip, pos, V, &view->cam.view_proj);
        s = tb->rasterize(tri, bary, depth, clip, V, mesh->faces, F, res, res);
    }
    if (!s) s = tb->interpolate(pix, attr, V, ATTR_C, tri, bary, mesh->faces, F, res, res);
    size_t N = 0;
    if (!s) {   // the covered pixels' samples, as the render gathers them
        mlb_covered_flags(index, tri, (long)P);
        mlb_scan_i32(index, index, (int)P);
        N = (size_t)index[P];
        pts = malloc(sizeof(real) * 3 * (N ? N : 1));
        nrm = malloc(sizeof(real) * 3 * (N ? N : 1));
        vdir = malloc(sizeof(real) * 3 * (N ? N : 1));
        k = malloc(sizeof(real) * 7 * (N ? N : 1));
        where = malloc(sizeof(int32_t) * (N ? N : 1));
        if (!pts || !nrm || !vdir || !k || !where) s = mlb_fail(MLB_ERR_NOMEM, "appearance maps: out of memory");
    }
    if (!s) {
        FN(mlb_gather_samples)(pts, nrm, vdir, where, pix, tri, index, (int)P, view->cam.eye[0], view->cam.eye[1],
                           view->cam.eye[2]);
        if (N) s = FN(material_net_eval)(net, pts, N, k, NULL);
    }
    if (!s) {
        memset(img, 0, sizeof(real) * C * P);
        for (size_t j = 0; j < N; j++) {
            real* o = img + C * (size_t)where[j];
            memcpy(o, k + 7 * j, sizeof(real) * 7);
            memcpy(o + 7, nrm + 3 * j, sizeof(real) * 3);
            o[10] = 1;
        }
        s = tb->antialias(aa, NULL, img, C, tri, depth, clip, V, mesh->faces, adj, F, res, res);
    }
    if (!s) {
        for (size_t i = 0; i < P; i++) {
            const real* o = aa + C * i;
            for (int c = 0; c < 3; c++) {
                if (kd_img) kd_img[3 * i + c] = o[c];
                if (ks_img) ks_img[3 * i + c] = o[3 + c];
                if (normal_img) normal_img[3 * i + c] = o[7 + c];
            }
            if (kr_img) kr_img[i] = o[6];
        }
    }
    free(normals.p);
    free(pos); free(attr); free(clip); free(adj); free(tri); free(bary); free(depth); free(pix); free(img); free(aa);
    free(pts); free(nrm); free(vdir); free(k); free(where); free(index);
    return s;
}
