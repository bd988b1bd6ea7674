// The CPU tables' ops over host memory, written once over `real` (core/real.h) for the float and
// the double tables: backend.c includes it as float, backend_f64.c as double (MLB_F64 defined
// before its includes: `real` is double, FN(name) is name_f64). Each op is cpu_<name>, static,
// taking the table type FN(mlb_backend) where the op list gives a table. What is precision-specific
// stays in those two files: the float tables' SIMD rows, bf16 GEMMs and stored weights and their
// ops without a double twin, the double table's own add and affine_columns.
#ifndef MATLABER_NN_BACKEND_HOST_H
#define MATLABER_NN_BACKEND_HOST_H
#include <stdlib.h>
#include <string.h>
#include "core/real.h"
#include "matlaber/backend_f64.h"
#include "matlaber/mt_ops.h"
#include "matlaber/raster.h"
#include "matlaber/transformer_ops.h"

// ---- memory: host memory, so uploading and downloading are copies
static mlb_status cpu_alloc(real** out, size_t n) {
    *out = malloc((n ? n : 1) * sizeof(real));
    if (!*out) return mlb_fail(MLB_ERR_NOMEM, "out of memory for %.1f MB", n * (double)sizeof(real) / 1e6);
    return MLB_OK;
}
static void cpu_release(void* p) { free(p); }
static mlb_status cpu_copy(real* dst, const real* src, size_t n) {
    if (n) memcpy(dst, src, n * sizeof(real));
    return MLB_OK;
}
static mlb_status cpu_zero(real* p, size_t n) {
    if (n) memset(p, 0, n * sizeof(real));
    return MLB_OK;
}
#define cpu_upload cpu_copy
#define cpu_download cpu_copy
static mlb_status cpu_copy_rows(real* dst, size_t dpitch, const real* src, size_t spitch, size_t width, size_t rows) {
    for (size_t r = 0; r < rows; r++) memcpy(dst + r * dpitch, src + r * spitch, width * sizeof(real));
    return MLB_OK;
}

// ---- the networks' ops: the CPU functions, their workspaces allocated per call
static mlb_status cpu_linear(const FN(mlb_backend)* be, real* out, const real* in, const real* w, const real* b, int B,
                             int C, int OC) {
    (void)be;
    FN(linear_forward)(out, in, w, b, B, C, OC);
    return MLB_OK;
}
static mlb_status cpu_linear_backward(const FN(mlb_backend)* be, real* din, real* dw, real* db, const real* dout,
                                      const real* in, const real* w, int B, int C, int OC) {
    (void)be;
    FN(linear_backward)(din, dw, db, dout, in, w, B, C, OC);
    return MLB_OK;
}
static mlb_status cpu_conv2d(const FN(mlb_backend)* be, real* out, const real* in, const real* w, const real* b,
                             const mlb_conv2d* cv) {
    (void)be;
    return FN(conv2d_forward)(out, in, w, b, cv, NULL);
}
static mlb_status cpu_conv2d_backward(const FN(mlb_backend)* be, real* din, real* dw, real* db, const real* dout,
                                      const real* in, const real* w, const mlb_conv2d* cv) {
    (void)be;
    return FN(conv2d_backward)(din, dw, db, dout, in, w, cv, NULL);
}
static mlb_status cpu_groupnorm(real* out, real* mean, real* rstd, const real* in, const real* w, const real* b, int N,
                                int C, int HW, int G, real eps, mlb_activation act) {
    return FN(groupnorm_forward)(out, mean, rstd, in, w, b, N, C, HW, G, eps, act);
}
static mlb_status cpu_groupnorm_backward(real* din, real* dw, real* db, const real* dout, const real* in,
                                         const real* w, const real* b, const real* mean, const real* rstd, int N,
                                         int C, int HW, int G, mlb_activation act) {
    return FN(groupnorm_backward)(din, dw, db, dout, in, w, b, mean, rstd, N, C, HW, G, act);
}
static mlb_status cpu_layernorm(real* out, const real* in, const real* w, const real* b, int N, int C, real eps) {
    FN(layernorm_forward)(out, NULL, NULL, in, w, b, N, C, eps);
    return MLB_OK;
}
static mlb_status cpu_layernorm_stats(real* out, real* mean, real* rstd, const real* in, const real* w, const real* b,
                                      int N, int C, real eps) {
    FN(layernorm_forward)(out, mean, rstd, in, w, b, N, C, eps);
    return MLB_OK;
}
static mlb_status cpu_layernorm_backward(real* din, real* dw, real* db, const real* dout, const real* in,
                                         const real* w, const real* mean, const real* rstd, int N, int C) {
    FN(layernorm_backward)(din, dw, db, dout, in, w, mean, rstd, N, C);
    return MLB_OK;
}
static mlb_status cpu_activation(real* out, const real* in, size_t n, mlb_activation act) {
    FN(activation_forward)(out, in, n, act);
    return MLB_OK;
}
static mlb_status cpu_activation_backward(real* din, const real* dout, const real* in, size_t n, mlb_activation act) {
    FN(activation_backward)(din, dout, in, n, act);
    return MLB_OK;
}
static mlb_status cpu_sdpa(const FN(mlb_backend)* be, real* out, real* lse, const real* q, const real* k,
                           const real* v, int B, int Tq, int Tk, int C, int NH, int ldq, int ldkv) {
    (void)be;
    return FN(sdpa_forward)(out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL);
}
static mlb_status cpu_sdpa_backward(const FN(mlb_backend)* be, real* dq, real* dk, real* dv, const real* dout,
                                    const real* out, const real* lse, const real* q, const real* k, const real* v,
                                    int B, int Tq, int Tk, int C, int NH, int ldq, int ldkv) {
    (void)be;
    return FN(sdpa_backward)(dq, dk, dv, dout, out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL);
}
static mlb_status cpu_attention(real* out, const real* q, const real* k, const real* v, int ld, int B, int T, int C,
                                int NH, int causal) {
    return FN(attention_forward)(out, NULL, q, k, v, ld, B, T, C, NH, causal);
}
static mlb_status cpu_add_channel(real* x, const real* v, int N, int C, int HW) {
    for (size_t r = 0; r < (size_t)N * C; r++) {
        real t = v[r], *p = x + r * HW;
        for (int i = 0; i < HW; i++) p[i] += t;
    }
    return MLB_OK;
}
static mlb_status cpu_transpose_last2(real* out, const real* in, int N, int R, int S, int accumulate) {
    FN(transpose_last2)(out, in, N, R, S, accumulate);
    return MLB_OK;
}
static mlb_status cpu_upsample_nearest2x(real* out, const real* in, int N, int C, int H, int W) {
    FN(upsample_nearest2x_forward)(out, in, N, C, H, W);
    return MLB_OK;
}
static mlb_status cpu_upsample_nearest2x_backward(real* din, const real* dout, int N, int C, int H, int W) {
    FN(upsample_nearest2x_backward)(din, dout, N, C, H, W);
    return MLB_OK;
}

// ---- the shading: the light's handle is the light itself, a copy turned per call with
// mlb_envlight_set_rotation (the double table's rotation holds a float's value: exact)
static mlb_status cpu_light_upload(void** handle, const mlb_envlight* light) {
    *handle = (void*)light;
    return MLB_OK;
}
static void cpu_light_free(void* handle) { (void)handle; }
static mlb_envlight cpu_turned(const void* handle, real rotation) {
    mlb_envlight l = *(const mlb_envlight*)handle;
    mlb_envlight_set_rotation(&l, (float)rotation);
    return l;
}
static mlb_status cpu_shade(real* out, const real* kd, const real* ks, const real* kr, const real* n, const real* v,
                            int N, const void* handle, real rotation, mlb_fresnel fresnel) {
    mlb_envlight l = cpu_turned(handle, rotation);
    return FN(mlb_shade_forward)(out, kd, ks, kr, n, v, N, &l, fresnel);
}
static mlb_status cpu_shade_backward(real* dkd, real* dks, real* dkr, real* dn, real* dv, const real* dout,
                                     const real* kd, const real* ks, const real* kr, const real* n, const real* v,
                                     int N, const void* handle, real rotation, mlb_fresnel fresnel) {
    mlb_envlight l = cpu_turned(handle, rotation);
    return FN(mlb_shade_backward)(dkd, dks, dkr, dn, dv, dout, kd, ks, kr, n, v, N, &l, fresnel);
}

// ---- the rasterizer: raster.h's functions with a scratch context of their own per call
static mlb_status cpu_rasterize(int32_t* tri, real* bary, real* depth, const real* clip, int V, const int32_t* faces,
                                int F, int H, int W) {
    return FN(mlb_rasterize)(NULL, tri, bary, depth, NULL, clip, V, faces, F, H, W);
}
static mlb_status cpu_rasterize_backward(real* dclip, const real* dbary, const real* ddepth, const int32_t* tri,
                                         const real* clip, int V, const int32_t* faces, int F, int H, int W) {
    return FN(mlb_rasterize_backward)(NULL, dclip, dbary, ddepth, tri, clip, V, faces, F, H, W);
}
static mlb_status cpu_interpolate(real* out, const real* attr, int V, int C, const int32_t* tri, const real* bary,
                                  const int32_t* faces, int F, int H, int W) {
    return FN(mlb_interpolate)(out, attr, V, C, tri, bary, faces, F, H, W);
}
static mlb_status cpu_interpolate_backward(real* dattr, real* dbary, const real* dout, const real* attr, int V, int C,
                                           const int32_t* tri, const real* bary, const int32_t* faces, int F, int H,
                                           int W) {
    return FN(mlb_interpolate_backward)(NULL, dattr, dbary, dout, attr, V, C, tri, bary, faces, F, H, W);
}
static mlb_status cpu_antialias(real* out, real* weights, const real* color, int C, const int32_t* tri,
                                const real* depth, const real* clip, int V, const int32_t* faces, const int32_t* adj,
                                int F, int H, int W) {
    return FN(mlb_antialias)(NULL, out, weights, color, C, tri, depth, clip, V, faces, adj, F, H, W);
}
static mlb_status cpu_antialias_backward(real* dcolor, real* dclip, const real* dout, const real* weights,
                                         const real* color, int C, const int32_t* tri, const real* depth,
                                         const real* clip, int V, const int32_t* faces, const int32_t* adj, int F,
                                         int H, int W) {
    return FN(mlb_antialias_backward)(NULL, dcolor, dclip, dout, weights, color, C, tri, depth, clip, V, faces, adj,
                                      F, H, W);
}

// ---- the surface: clip coordinates (raster.h), its topology and vertex normals (mt_ops.h); the
// topology, scans and coverage flags are integers, the same in both tables
static mlb_status cpu_transform_points(real* clip, const real* pos, int V, const double* m) {
    mlb_mat4 M;
    memcpy(M.m, m, sizeof M.m);
    FN(mlb_transform_points)(clip, pos, V, &M);
    return MLB_OK;
}
static mlb_status cpu_transform_points_backward(real* dpos, const real* dclip, int V, const double* m) {
    mlb_mat4 M;
    memcpy(M.m, m, sizeof M.m);
    FN(mlb_transform_points_backward)(dpos, dclip, V, &M);
    return MLB_OK;
}
static mlb_status cpu_vertex_faces(int32_t* off, int32_t* vf, const int32_t* faces, int F, int V) {
    return mlb_vertex_faces(off, vf, faces, F, V);
}
static mlb_status cpu_edge_topology(int32_t* adj, const int32_t* faces, int F, const int32_t* off, const int32_t* vf) {
    if (F < 0) return mlb_fail(MLB_ERR_ARG, "edge_topology: %d faces", F);
    mlb_edge_partners(adj, faces, F, off, vf);
    return MLB_OK;
}
static mlb_status cpu_scan_i32(int32_t* out, const int32_t* in, int n) {
    if (n < 0) return mlb_fail(MLB_ERR_ARG, "scan of %d values", n);
    mlb_scan_i32(out, in, n);
    return MLB_OK;
}
static mlb_status cpu_covered_flags(int32_t* flags, const int32_t* tri, size_t n) {
    mlb_covered_flags(flags, tri, (long)n);
    return MLB_OK;
}
static mlb_status cpu_vertex_normals(real* normal, real* sum, const real* pos, int V, const int32_t* faces,
                                     const int32_t* off, const int32_t* vf) {
    FN(mlb_vertex_normals)(normal, sum, pos, V, faces, off, vf);
    return MLB_OK;
}
static mlb_status cpu_vertex_normals_backward(real* dpos, const real* dnormal, const real* sum, const real* pos, int V,
                                              const int32_t* faces, const int32_t* off, const int32_t* vf) {
    FN(mlb_vertex_normals_backward)(dpos, dnormal, sum, pos, V, faces, off, vf);
    return MLB_OK;
}

// ---- DMTet's grid passes: the deformation, the SDF sign regulariser and marching tets, mt_ops.h's
// passes (the backward scatters over the surface vertices in order: it needs vedge, not slot_off)
static mlb_status cpu_dmtet_deform(real* out, const real* grid, const real* deform, int n_verts, real grid_res) {
    FN(mlb_mt_deform)(out, grid, deform, n_verts, grid_res);
    return MLB_OK;
}
static mlb_status cpu_dmtet_deform_backward(real* ddeform, const real* dout, const real* deform, int n_verts,
                                            real grid_res) {
    FN(mlb_mt_deform_backward)(NULL, ddeform, dout, deform, n_verts, grid_res);
    return MLB_OK;
}
static mlb_status cpu_sdf_reg(real* out, const real* sdf, int cells) {
    if (cells < 1 || cells > 512) return mlb_fail(MLB_ERR_ARG, "sdf_reg: %d cells", cells);
    *out = FN(mlb_mt_sdf_reg)(sdf, cells);
    return MLB_OK;
}
static mlb_status cpu_sdf_reg_backward(real* dsdf, const real* sdf, int cells, real dloss) {
    if (cells < 1 || cells > 512) return mlb_fail(MLB_ERR_ARG, "sdf_reg_backward: %d cells", cells);
    FN(mlb_mt_sdf_reg_backward)(dsdf, sdf, cells, dloss);
    return MLB_OK;
}
static mlb_status cpu_marching_tets_count(int32_t* tet_nf, int32_t* slot_nv, const real* sdf, const int32_t* tets,
                                          int T, int cells) {
    if (T < 0 || cells < 1 || cells > 512) return mlb_fail(MLB_ERR_ARG, "marching tets: %d tets, %d cells", T, cells);
    FN(mlb_mt_count)(tet_nf, slot_nv, sdf, tets, T, cells);
    return MLB_OK;
}
static mlb_status cpu_marching_tets_emit(real* verts, int32_t* vedge, real* weight, int32_t* faces, const real* pos,
                                         const real* sdf, const int32_t* tets, int T, int cells,
                                         const int32_t* tet_off, const int32_t* slot_off) {
    if (T < 0 || cells < 1 || cells > 512) return mlb_fail(MLB_ERR_ARG, "marching tets: %d tets, %d cells", T, cells);
    FN(mlb_mt_emit)(verts, vedge, weight, faces, pos, sdf, tets, T, cells, tet_off, slot_off);
    return MLB_OK;
}
static mlb_status cpu_marching_tets_backward(real* dpos, real* dsdf, const real* dverts, const real* weight,
                                             const int32_t* vedge, int nv, const real* pos, const real* sdf,
                                             const int32_t* slot_off, int cells) {
    FN(mlb_mt_backward)(dpos, dsdf, dverts, weight, vedge, nv, pos, sdf);
    return MLB_OK;
}

// ---- the appearance renderer's samples: raster_api.inc's passes
static mlb_status cpu_gather_samples(real* pts, real* nrm, real* vdir, int32_t* where, const real* pix,
                                     const int32_t* tri, const int32_t* index, int P, double ex, double ey, double ez) {
    FN(mlb_gather_samples)(pts, nrm, vdir, where, pix, tri, index, P, ex, ey, ez);
    return MLB_OK;
}
static mlb_status cpu_composite_srgb(real* color, const real* rgb, const int32_t* where, int m) {
    FN(mlb_composite_srgb)(color, rgb, where, m);
    return MLB_OK;
}
static mlb_status cpu_composite_srgb_backward(real* drgb, const real* dcolor, const real* rgb, const int32_t* where,
                                              int m) {
    FN(mlb_composite_srgb_backward)(drgb, dcolor, rgb, where, m);
    return MLB_OK;
}
static mlb_status cpu_downsample_box(real* out, const real* in, int H, int W, int C, int s) {
    FN(mlb_downsample_box)(out, in, H, W, C, s);
    return MLB_OK;
}
static mlb_status cpu_downsample_box_backward(real* din, const real* dout, int H, int W, int C, int s) {
    FN(mlb_downsample_box_backward)(din, dout, H, W, C, s);
    return MLB_OK;
}
#endif
