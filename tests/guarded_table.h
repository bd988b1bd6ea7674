// Shared by tests (not itself a test): a CPU op table whose buffers the host cannot touch outside
// an op, so that a stage handed it proves on a machine without a GPU that it keeps its data on the
// table's device. alloc maps whole pages with no access (PROT_NONE); every wrapped op opens all of
// them for its call and closes them after; upload and download are the only doors. A stage that
// reads or writes a table buffer on the host dies with SIGSEGV at that line. Ops not wrapped here
// fail with MLB_ERR_UNSUPPORTED naming the op (wrap one when a stage starts to use it); the GEMM
// ops are all wrapped. Results are the CPU table's bits.
#ifndef MATLABER_GUARDED_TABLE_H
#define MATLABER_GUARDED_TABLE_H
#include <stdint.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>
#include "matlaber/backend.h"

enum { GUARD_MAX_REGIONS = 4096 };
static struct { void* p; size_t bytes; } guard_region[GUARD_MAX_REGIONS];
static int guard_n;
static long guard_ops;   // ops run through the table (a test can check the stage used it)

static void guard_set(int prot) {
    for (int i = 0; i < guard_n; i++)
        if (mprotect(guard_region[i].p, guard_region[i].bytes, prot) != 0) abort();
}
#define GUARDED(call)                                  \
    do {                                               \
        guard_ops++;                                   \
        guard_set(PROT_READ | PROT_WRITE);             \
        mlb_status guard_st_ = (call);                 \
        guard_set(PROT_NONE);                          \
        return guard_st_;                              \
    } while (0)
#define CPU_ mlb_backend_cpu()

static mlb_status guard_alloc(float** out, size_t n) {
    size_t page = (size_t)sysconf(_SC_PAGESIZE), bytes = ((n ? n : 1) * sizeof(float) + page - 1) / page * page;
    if (guard_n == GUARD_MAX_REGIONS) return mlb_fail(MLB_ERR_NOMEM, "guarded table: more than %d buffers", GUARD_MAX_REGIONS);
    void* p = mmap(NULL, bytes, PROT_NONE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) return mlb_fail(MLB_ERR_NOMEM, "guarded table: mmap of %zu bytes", bytes);
    guard_region[guard_n].p = p, guard_region[guard_n].bytes = bytes;
    guard_n++;
    *out = p;
    return MLB_OK;
}
static void guard_release(void* p) {
    for (int i = 0; p && i < guard_n; i++)
        if (guard_region[i].p == p) {
            munmap(p, guard_region[i].bytes);
            guard_region[i] = guard_region[--guard_n];
            return;
        }
}
static mlb_status guard_upload(float* dst, const float* host, size_t n) { GUARDED(CPU_->upload(dst, host, n)); }
static mlb_status guard_download(float* host, const float* src, size_t n) { GUARDED(CPU_->download(host, src, n)); }
static mlb_status guard_zero(float* p, size_t n) { GUARDED(CPU_->zero(p, n)); }
static mlb_status guard_copy(float* dst, const float* src, size_t n) { GUARDED(CPU_->copy(dst, src, n)); }
static mlb_status guard_copy_rows(float* dst, size_t dpitch, const float* src, size_t spitch, size_t width, size_t rows) {
    GUARDED(CPU_->copy_rows(dst, dpitch, src, spitch, width, rows));
}
static mlb_status guard_activation(float* out, const float* in, size_t n, mlb_activation act) {
    GUARDED(CPU_->activation(out, in, n, act));
}
static mlb_status guard_activation_backward(float* din, const float* dout, const float* in, size_t n, mlb_activation act) {
    GUARDED(CPU_->activation_backward(din, dout, in, n, act));
}
static mlb_status guard_hashgrid(const mlb_hashgrid* g, const float* params, float* out, const float* x, int N) {
    GUARDED(CPU_->hashgrid(g, params, out, x, N));
}
static mlb_status guard_hashgrid_backward(const mlb_hashgrid* g, const float* params, float* dparams, float* dx,
                                          const float* dout, const float* x, int N) {
    GUARDED(CPU_->hashgrid_backward(g, params, dparams, dx, dout, x, N));
}
static mlb_status guard_adam(float* params, const float* grads, float* m, float* v, size_t n, const mlb_adam_config* cfg,
                             long t) {
    GUARDED(CPU_->adam(params, grads, m, v, n, cfg, t));
}
static mlb_status guard_light_upload(void** handle, const mlb_envlight* light) { return CPU_->light_upload(handle, light); }
static void guard_light_free(void* handle) { CPU_->light_free(handle); }
static mlb_status guard_shade(float* out, const float* kd, const float* ks, const float* kr, const float* n,
                              const float* v, int N, const void* handle, float rotation, mlb_fresnel fresnel) {
    GUARDED(CPU_->shade(out, kd, ks, kr, n, v, N, handle, rotation, fresnel));
}
static mlb_status guard_shade_backward(float* dkd, float* dks, float* dkr, float* dn, float* dv, const float* dout,
                                       const float* kd, const float* ks, const float* kr, const float* n,
                                       const float* v, int N, const void* handle, float rotation, mlb_fresnel fresnel) {
    GUARDED(CPU_->shade_backward(dkd, dks, dkr, dn, dv, dout, kd, ks, kr, n, v, N, handle, rotation, fresnel));
}
static mlb_status guard_rasterize(int32_t* tri, float* bary, float* depth, const float* clip, int V,
                                  const int32_t* faces, int F, int H, int W) {
    GUARDED(CPU_->rasterize(tri, bary, depth, clip, V, faces, F, H, W));
}
static mlb_status guard_interpolate(float* out, const float* attr, int V, int C, const int32_t* tri, const float* bary,
                                    const int32_t* faces, int F, int H, int W) {
    GUARDED(CPU_->interpolate(out, attr, V, C, tri, bary, faces, F, H, W));
}
static mlb_status guard_antialias(float* out, float* weights, const float* color, int C, const int32_t* tri,
                                  const float* depth, const float* clip, int V, const int32_t* faces,
                                  const int32_t* adj, int F, int H, int W) {
    GUARDED(CPU_->antialias(out, weights, color, C, tri, depth, clip, V, faces, adj, F, H, W));
}
static mlb_status guard_antialias_backward(float* dcolor, float* dclip, const float* dout, const float* weights,
                                           const float* color, int C, const int32_t* tri, const float* depth,
                                           const float* clip, int V, const int32_t* faces, const int32_t* adj, int F,
                                           int H, int W) {
    GUARDED(CPU_->antialias_backward(dcolor, dclip, dout, weights, color, C, tri, depth, clip, V, faces, adj, F, H, W));
}
static mlb_status guard_marching_tets_count(int32_t* tet_nf, int32_t* slot_nv, const float* sdf, const int32_t* tets,
                                            int T, int cells) {
    GUARDED(CPU_->marching_tets_count(tet_nf, slot_nv, sdf, tets, T, cells));
}
static mlb_status guard_marching_tets_emit(float* verts, int32_t* vedge, float* weight, int32_t* faces, const float* pos,
                                           const float* sdf, const int32_t* tets, int T, int cells,
                                           const int32_t* tet_off, const int32_t* slot_off) {
    GUARDED(CPU_->marching_tets_emit(verts, vedge, weight, faces, pos, sdf, tets, T, cells, tet_off, slot_off));
}
static mlb_status guard_marching_tets_backward(float* dpos, float* dsdf, const float* dverts, const float* weight,
                                               const int32_t* vedge, int nv, const float* pos, const float* sdf,
                                               const int32_t* slot_off, int cells) {
    GUARDED(CPU_->marching_tets_backward(dpos, dsdf, dverts, weight, vedge, nv, pos, sdf, slot_off, cells));
}
static mlb_status guard_rasterize_backward(float* dclip, const float* dbary, const float* ddepth, const int32_t* tri,
                                           const float* clip, int V, const int32_t* faces, int F, int H, int W) {
    GUARDED(CPU_->rasterize_backward(dclip, dbary, ddepth, tri, clip, V, faces, F, H, W));
}
static mlb_status guard_interpolate_backward(float* dattr, float* dbary, const float* dout, const float* attr, int V,
                                             int C, const int32_t* tri, const float* bary, const int32_t* faces, int F,
                                             int H, int W) {
    GUARDED(CPU_->interpolate_backward(dattr, dbary, dout, attr, V, C, tri, bary, faces, F, H, W));
}
static mlb_status guard_dmtet_deform(float* out, const float* grid, const float* deform, int n_verts, float grid_res) {
    GUARDED(CPU_->dmtet_deform(out, grid, deform, n_verts, grid_res));
}
static mlb_status guard_dmtet_deform_backward(float* ddeform, const float* dout, const float* deform, int n_verts,
                                              float grid_res) {
    GUARDED(CPU_->dmtet_deform_backward(ddeform, dout, deform, n_verts, grid_res));
}
static mlb_status guard_sdf_reg(float* out, const float* sdf, int cells) { GUARDED(CPU_->sdf_reg(out, sdf, cells)); }
static mlb_status guard_sdf_reg_backward(float* dsdf, const float* sdf, int cells, float dloss) {
    GUARDED(CPU_->sdf_reg_backward(dsdf, sdf, cells, dloss));
}
static mlb_status guard_scan_i32(int32_t* out, const int32_t* in, int n) { GUARDED(CPU_->scan_i32(out, in, n)); }
static mlb_status guard_covered_flags(int32_t* flags, const int32_t* tri, size_t n) {
    GUARDED(CPU_->covered_flags(flags, tri, n));
}
static mlb_status guard_gather_samples(float* pts, float* nrm, float* vdir, int32_t* where, const float* pix,
                                       const int32_t* tri, const int32_t* index, int P, double ex, double ey, double ez) {
    GUARDED(CPU_->gather_samples(pts, nrm, vdir, where, pix, tri, index, P, ex, ey, ez));
}
static mlb_status guard_composite_srgb(float* color, const float* rgb, const int32_t* where, int m) {
    GUARDED(CPU_->composite_srgb(color, rgb, where, m));
}
static mlb_status guard_composite_srgb_backward(float* drgb, const float* dcolor, const float* rgb,
                                                const int32_t* where, int m) {
    GUARDED(CPU_->composite_srgb_backward(drgb, dcolor, rgb, where, m));
}
static mlb_status guard_downsample_box(float* out, const float* in, int H, int W, int C, int s) {
    GUARDED(CPU_->downsample_box(out, in, H, W, C, s));
}
static mlb_status guard_downsample_box_backward(float* din, const float* dout, int H, int W, int C, int s) {
    GUARDED(CPU_->downsample_box_backward(din, dout, H, W, C, s));
}
static mlb_status guard_affine_columns(float* y, const float* x, size_t n, int C, const double* scale,
                                       const double* shift, int in_float) {
    GUARDED(CPU_->affine_columns(y, x, n, C, scale, shift, in_float));
}
static mlb_status guard_add(float* y, const float* x, size_t n) { GUARDED(CPU_->add(y, x, n)); }
static mlb_status guard_transform_points(float* clip, const float* pos, int V, const double* m) {
    GUARDED(CPU_->transform_points(clip, pos, V, m));
}
static mlb_status guard_transform_points_backward(float* dpos, const float* dclip, int V, const double* m) {
    GUARDED(CPU_->transform_points_backward(dpos, dclip, V, m));
}
static mlb_status guard_vertex_faces(int32_t* off, int32_t* vf, const int32_t* faces, int F, int V) {
    GUARDED(CPU_->vertex_faces(off, vf, faces, F, V));
}
static mlb_status guard_edge_topology(int32_t* adj, const int32_t* faces, int F, const int32_t* off, const int32_t* vf) {
    GUARDED(CPU_->edge_topology(adj, faces, F, off, vf));
}
static mlb_status guard_vertex_normals(float* normal, float* sum, const float* pos, int V, const int32_t* faces,
                                       const int32_t* off, const int32_t* vf) {
    GUARDED(CPU_->vertex_normals(normal, sum, pos, V, faces, off, vf));
}
static mlb_status guard_vertex_normals_backward(float* dpos, const float* dnormal, const float* sum, const float* pos,
                                                int V, const int32_t* faces, const int32_t* off, const int32_t* vf) {
    GUARDED(CPU_->vertex_normals_backward(dpos, dnormal, sum, pos, V, faces, off, vf));
}

static mlb_status guard_area_resize(float* dst, const float* src, int n, int H, int W, int C, int h, int w) {
    GUARDED(CPU_->area_resize(dst, src, n, H, W, C, h, w));
}
static mlb_status guard_area_resize_backward(float* dsrc, const float* ddst, int n, int H, int W, int C, int h, int w) {
    GUARDED(CPU_->area_resize_backward(dsrc, ddst, n, H, W, C, h, w));
}
static mlb_status guard_renders_to_sd(float* x, const float* renders, int n, int H, int W, int normal) {
    GUARDED(CPU_->renders_to_sd(x, renders, n, H, W, normal));
}
static mlb_status guard_renders_to_sd_backward(float* drenders, const float* dx, int n, int H, int W, int normal) {
    GUARDED(CPU_->renders_to_sd_backward(drenders, dx, n, H, W, normal));
}

// the VAE encoder and its backward (the SDS guidance on a table)
static mlb_status guard_groupnorm(float* out, float* mean, float* rstd, const float* in, const float* w, const float* b,
                                  int N, int C, int HW, int G, float eps, mlb_activation act) {
    GUARDED(CPU_->groupnorm(out, mean, rstd, in, w, b, N, C, HW, G, eps, act));
}
static mlb_status guard_groupnorm_backward(float* din, float* dw, float* db, const float* dout, const float* in,
                                           const float* w, const float* b, const float* mean, const float* rstd, int N,
                                           int C, int HW, int G, mlb_activation act) {
    GUARDED(CPU_->groupnorm_backward(din, dw, db, dout, in, w, b, mean, rstd, N, C, HW, G, act));
}
static mlb_status guard_attention(float* out, const float* q, const float* k, const float* v, int ld, int B, int T, int C,
                                  int NH, int causal) {
    GUARDED(CPU_->attention(out, q, k, v, ld, B, T, C, NH, causal));
}
static mlb_status guard_transpose_last2(float* out, const float* in, int N, int R, int S, int accumulate) {
    GUARDED(CPU_->transpose_last2(out, in, N, R, S, accumulate));
}

// the UNet and the SDS step's latent arithmetic
static mlb_status guard_layernorm(float* out, const float* in, const float* w, const float* b, int N, int C, float eps) {
    GUARDED(CPU_->layernorm(out, in, w, b, N, C, eps));
}
static mlb_status guard_add_channel(float* x, const float* v, int N, int C, int HW) { GUARDED(CPU_->add_channel(x, v, N, C, HW)); }
static mlb_status guard_geglu(float* out, const float* in, int rows, int C4) { GUARDED(CPU_->geglu(out, in, rows, C4)); }
static mlb_status guard_upsample_nearest2x(float* out, const float* in, int N, int C, int H, int W) {
    GUARDED(CPU_->upsample_nearest2x(out, in, N, C, H, W));
}
static mlb_status guard_fill_normal(float* out, size_t n, uint64_t seed, uint64_t stream, uint64_t offset) {
    GUARDED(CPU_->fill_normal(out, n, seed, stream, offset));
}
static mlb_status guard_axpby_rows(float* out, const float* x, const float* y, int B, size_t n, const float* a,
                                   const float* c) {
    GUARDED(CPU_->axpby_rows(out, x, y, B, n, a, c));
}
static mlb_status guard_sds_grad(float* eps, float* grad, float* dz, float* sumsq, const float* noise, int B, size_t n,
                                 float scale, const float* w, float div, float mul) {
    GUARDED(CPU_->sds_grad(eps, grad, dz, sumsq, noise, B, n, scale, w, div, mul));
}

static mlb_status guard_layernorm_stats(float* out, float* mean, float* rstd, const float* in, const float* w,
                                        const float* b, int N, int C, float eps) {
    GUARDED(CPU_->layernorm_stats(out, mean, rstd, in, w, b, N, C, eps));
}
// every other op: refused by name; the GEMM ops: the CPU's, guarded
#define MLB_OP(name, cuda_fn, params) \
    __attribute__((unused)) static mlb_status guard_unwrapped_##name params { return mlb_fail(MLB_ERR_UNSUPPORTED, "guarded table: %s is not wrapped", #name); }
#define MLB_GEMM_OP(name, cuda_fn, params, args) \
    static mlb_status guard_##name(const mlb_backend* be, MLB_ARGS params) { (void)be; GUARDED(CPU_->name(CPU_, MLB_ARGS args)); }
#include "matlaber/backend_ops.def"

static const mlb_backend* guarded_table(void) {
    static mlb_backend t;
    t = (mlb_backend){
        .device = MLB_DEVICE_CPU, .precision = MLB_GEMM_FP32,
#define MLB_OP(name, cuda_fn, params) .name = guard_unwrapped_##name,
#define MLB_GEMM_OP(name, cuda_fn, params, args) .name = guard_##name,
#include "matlaber/backend_ops.def"
    };
#define GUARD_USE(name) t.name = guard_##name
    GUARD_USE(alloc); GUARD_USE(release); GUARD_USE(upload); GUARD_USE(download); GUARD_USE(zero); GUARD_USE(copy);
    GUARD_USE(copy_rows); GUARD_USE(activation); GUARD_USE(activation_backward); GUARD_USE(hashgrid);
    GUARD_USE(hashgrid_backward); GUARD_USE(adam); GUARD_USE(light_upload); GUARD_USE(light_free); GUARD_USE(shade);
    GUARD_USE(shade_backward); GUARD_USE(rasterize); GUARD_USE(interpolate); GUARD_USE(antialias);
    GUARD_USE(antialias_backward); GUARD_USE(scan_i32); GUARD_USE(covered_flags); GUARD_USE(gather_samples);
    GUARD_USE(composite_srgb); GUARD_USE(composite_srgb_backward); GUARD_USE(downsample_box);
    GUARD_USE(downsample_box_backward); GUARD_USE(affine_columns); GUARD_USE(marching_tets_count);
    GUARD_USE(marching_tets_emit); GUARD_USE(marching_tets_backward); GUARD_USE(rasterize_backward);
    GUARD_USE(interpolate_backward); GUARD_USE(dmtet_deform); GUARD_USE(dmtet_deform_backward); GUARD_USE(sdf_reg);
    GUARD_USE(sdf_reg_backward); GUARD_USE(add); GUARD_USE(transform_points); GUARD_USE(transform_points_backward);
    GUARD_USE(vertex_faces); GUARD_USE(edge_topology); GUARD_USE(vertex_normals); GUARD_USE(vertex_normals_backward);
    GUARD_USE(area_resize); GUARD_USE(area_resize_backward); GUARD_USE(renders_to_sd); GUARD_USE(renders_to_sd_backward);
    GUARD_USE(groupnorm); GUARD_USE(groupnorm_backward); GUARD_USE(attention); GUARD_USE(transpose_last2);
    GUARD_USE(layernorm); GUARD_USE(add_channel); GUARD_USE(geglu); GUARD_USE(upsample_nearest2x);
    GUARD_USE(axpby_rows); GUARD_USE(fill_normal); GUARD_USE(sds_grad); GUARD_USE(layernorm_stats);
#undef GUARD_USE
    return &t;
}
#undef CPU_
#endif
