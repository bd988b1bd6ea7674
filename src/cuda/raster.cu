// The rasterizer's ops on the GPU, with raster.h's contracts (nvdiffrast's rasterize, interpolate
// and antialias, forward and backward): the CPU's own maths (render/raster_math.h,
// render/antialias_math.h) in float. This file is compiled with -fmad=false (CMakeLists.txt) so
// that no multiply-add is fused: the setup, depths, barycentrics, interpolated values, antialias's
// blend weights, blends and colour gradients are the CPU's float bits.
//
// rasterize: a pass per vertex (outcode, snap), a pass per face (setup; faces that cross a clip
// plane or the guard band clipped into their own polygon slot), a warp per chunk of 256 pixels of a
// face's box (a face's chunks counted and scanned first, so a big face spreads over many warps)
// testing coverage exactly (integer edge functions, top-left rule) and keeping per pixel the
// smallest (depth, face id) as one 64-bit atomicMin (so ties go to the lower id, as on the CPU,
// whatever the order the warps run in), and a pass per pixel resolving the winner's barycentrics
// and depth. (The CPU bins faces into tiles instead; a GPU profile decides whether that pays here.)
// antialias: per face its orientation and silhouette edges, per pixel its two pairs' weights,
// then per pixel the blend (or its colour gradient) gathered from its four pairs.
// The gradients summed over pixels (dclip, dattr) go into double accumulators by atomicAdd and are
// rounded once to float: the CPU sums per face in pixel order, so they agree to the rounding of a
// double sum. Indices are trusted as the CPU entry points check them (rasterize and interpolate
// skip faces with a vertex out of range rather than read it; antialias reads adj as given).
#include <math.h>
#include <string.h>
#include "common.cuh"
extern "C" {
#include "matlaber/raster.h"
}
typedef float real;
#include "render/antialias_math.h"   // and render/raster_math.h

// Carves one scratch allocation into aligned parts.
static char* carve(char** cur, size_t bytes) {
    char* p = *cur;
    *cur += (bytes + 255) / 256 * 256;
    return p;
}

// ---- rasterize ----
__global__ void raster_vertex_kernel(vrec* vr, const float* clip, int V, int W, int H, double G) {
    for (int v = blockIdx.x * blockDim.x + threadIdx.x; v < V; v += gridDim.x * blockDim.x) {
        setup_vertex(&vr[v], clip, v, W, H, G);
    }
}

__device__ __forceinline__ int face_ok(const int32_t* faces, int t, int V) {
    const int32_t* f = faces + 3 * (size_t)t;
    return f[0] >= 0 && f[0] < V && f[1] >= 0 && f[1] < V && f[2] >= 0 && f[2] < V;
}

// Face t's setup; a face to clip gets polygon slot t.
__global__ void raster_setup_kernel(tsetup* S, tpoly* polys, const float* clip, const int32_t* faces, const vrec* vr,
                                    int V, int F, int W, int H, double G) {
    for (int t = blockIdx.x * blockDim.x + threadIdx.x; t < F; t += gridDim.x * blockDim.x) {
        if (!face_ok(faces, t, V)) {
            S[t].x0 = S[t].y0 = 1, S[t].x1 = S[t].y1 = 0, S[t].poly = -1;
            continue;
        }
        if (setup_triangle(&S[t], t, clip, faces, vr, W, H)) {
            S[t].poly = t;
            setup_clipped(&S[t], &polys[t], t, clip, faces, G, W, H);
        }
    }
}

// (depth, face) as one key whose unsigned order is the CPU's: smaller depth first, then lower id.
// -0 is made +0 (the CPU compares them equal and lets the id decide).
__device__ __forceinline__ unsigned long long depth_key(float d, int t) {
    if (d == 0.0f) d = 0.0f;
    unsigned u = __float_as_uint(d);
    u = (u & 0x80000000u) ? ~u : (u | 0x80000000u);
    return ((unsigned long long)u << 32) | (unsigned)t;
}
#define EMPTY_KEY 0xffffffffffffffffull

// The coverage work in chunks of a face's pixel box, a warp each, so that a face covering many
// pixels spreads over many warps instead of holding one (and small faces cost one warp, as
// before). chunks[t] = face t's chunk count (0: it draws nothing); their scan numbers the chunks.
enum { COVER_CHUNK = 256 };   // pixels per warp: 8 a lane
// A face's pixels per chunk: COVER_CHUNK, or more where F faces of such boxes would number 2^31
// chunks (the scan is int32)
__device__ __forceinline__ long long cover_chunk_size(long long n, int F) {
    long long most = 2147483647LL / (F > 0 ? F : 1);   // chunks a face may have
    return n <= most * COVER_CHUNK ? COVER_CHUNK : (n + most - 1) / most;
}
__global__ void raster_chunks_kernel(int32_t* chunks, const tsetup* S, const tpoly* polys, int F) {
    for (int t = blockIdx.x * blockDim.x + threadIdx.x; t < F; t += gridDim.x * blockDim.x) {
        const tsetup* s = &S[t];
        if (box_empty(s) || (s->poly >= 0 && polys[s->poly].n < 3)) {
            chunks[t] = 0;
            continue;
        }
        long long n = (long long)(s->x1 - s->x0 + 1) * (s->y1 - s->y0 + 1), cs = cover_chunk_size(n, F);
        chunks[t] = (int32_t)((n + cs - 1) / cs);
    }
}

// A warp per chunk: its face is the last t with chunk_off[t] <= c (that face has the chunk: faces
// without one share the next face's offset); its lanes walk the chunk's pixels of the face's box.
// The winner per pixel is one 64-bit atomicMin, so the work's order does not change the result.
__global__ void raster_cover_kernel(unsigned long long* key, const tsetup* S, const tpoly* polys,
                                    const int32_t* chunk_off, int F, int W) {
    const int lane = threadIdx.x & 31;
    const long long warps = (long long)gridDim.x * (blockDim.x / 32);
    const long long total = chunk_off[F];
    for (long long c = ((long long)blockIdx.x * blockDim.x + threadIdx.x) / 32; c < total; c += warps) {
        int lo = 0, hi = F - 1;
        while (lo < hi) {
            int mid = lo + (hi - lo + 1) / 2;
            if (chunk_off[mid] <= c) lo = mid;
            else hi = mid - 1;
        }
        const int t = lo;
        const tsetup* s = &S[t];
        int bw = s->x1 - s->x0 + 1;
        long long n = (long long)bw * (s->y1 - s->y0 + 1);
        long long cs = cover_chunk_size(n, F), first = (c - chunk_off[t]) * cs, end = first + cs < n ? first + cs : n;
        for (long long i = first + lane; i < end; i += 32) {
            int x = s->x0 + (int)(i % bw), y = s->y0 + (int)(i / bw);
            int64_t Px = (int64_t)x * SUB + HALF_SUB, Py = (int64_t)y * SUB + HALF_SUB;
            int cov = s->poly >= 0 ? poly_covers(&polys[s->poly], Px, Py) : tri_covers(s->X, s->Y, Px, Py);
            if (!cov) continue;
            float d = depth_at(s, x, y);
            if (!(d < INFINITY)) continue;   // NaN and +inf never beat the CPU's +inf start
            atomicMin(&key[(size_t)y * W + x], depth_key(d, t));
        }
    }
}

// The winner's barycentrics from clip space and its depth, per pixel (the CPU's resolve).
__global__ void raster_resolve_kernel(int32_t* tri, float* bary, float* depth, const unsigned long long* key,
                                      const tsetup* S, const float* clip, const int32_t* faces, int W, int H) {
    const int n_pix = W * H;
    for (int p = blockIdx.x * blockDim.x + threadIdx.x; p < n_pix; p += gridDim.x * blockDim.x) {
        unsigned long long k = key[p];
        int t = k == EMPTY_KEY ? -1 : (int)(unsigned)(k & 0xffffffffu);
        int x = p % W, y = p / W;
        tri[p] = t;
        if (t < 0) {
            if (bary) bary[2 * (size_t)p] = bary[2 * (size_t)p + 1] = 0;
            if (depth) depth[p] = 0;
            continue;
        }
        rast_resolve(bary ? bary + 2 * (size_t)p : NULL, clip, faces, t, x, y, W, H);
        if (depth) depth[p] = depth_at(&S[t], x, y);
    }
}

static mlb_status check_size(const char* fn, int V, int F, int H, int W) {
    if (H < 1 || W < 1 || H > MLB_RASTER_MAX_SIZE || W > MLB_RASTER_MAX_SIZE)
        return mlb_fail(MLB_ERR_ARG, "%s: image %d x %d (each side 1 to %d)", fn, W, H, MLB_RASTER_MAX_SIZE);
    if (V < 0 || F < 0) return mlb_fail(MLB_ERR_ARG, "%s: bad mesh (%d vertices, %d faces)", fn, V, F);
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_rasterize(int32_t* tri, float* bary, float* depth, const float* clip, int V,
                                         const int32_t* faces, int F, int H, int W) {
    MLB_TRY(check_size("mlb_cuda_rasterize", V, F, H, W));
    if (!tri) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_rasterize: tri (the output face ids) is NULL");
    double G = guard_band(W, H);
    size_t n_pix = (size_t)H * W;
    size_t n_sums = mlb_cuda_scan_i32_sums(F);
    size_t bytes = ((size_t)V * sizeof(vrec) + 256) + ((size_t)F * sizeof(tsetup) + 256) +
                   ((size_t)F * sizeof(tpoly) + 256) + (n_pix * sizeof(unsigned long long) + 256) +
                   (((size_t)F + 1) * sizeof(int32_t) + 256) + (n_sums * sizeof(int32_t) + 256);
    void* scratch;
    MLB_TRY(mlb_cuda_scratch(&scratch, bytes));
    char* cur = (char*)scratch;
    vrec* vr = (vrec*)carve(&cur, (size_t)V * sizeof(vrec));
    tsetup* S = (tsetup*)carve(&cur, (size_t)F * sizeof(tsetup));
    tpoly* polys = (tpoly*)carve(&cur, (size_t)F * sizeof(tpoly));
    unsigned long long* key = (unsigned long long*)carve(&cur, n_pix * sizeof(unsigned long long));
    int32_t* chunk_off = (int32_t*)carve(&cur, ((size_t)F + 1) * sizeof(int32_t));   // counts, then their scan
    int32_t* scan_sums = (int32_t*)carve(&cur, n_sums * sizeof(int32_t));
    MLB_CUDA_CHECK(cudaMemsetAsync(key, 0xff, n_pix * sizeof(unsigned long long), 0));
    if (V > 0) {
        raster_vertex_kernel<<<mlb_grid(V, 256), 256>>>(vr, clip, V, W, H, G);
        MLB_CUDA_LAUNCHED("raster_vertex_kernel");
    }
    if (F > 0) {
        raster_setup_kernel<<<mlb_grid(F, 128), 128>>>(S, polys, clip, faces, vr, V, F, W, H, G);
        MLB_CUDA_LAUNCHED("raster_setup_kernel");
        raster_chunks_kernel<<<mlb_grid(F, 256), 256>>>(chunk_off, S, polys, F);
        MLB_CUDA_LAUNCHED("raster_chunks_kernel");
        MLB_TRY(mlb_cuda_scan_i32_into(chunk_off, chunk_off, F, scan_sums));
        raster_cover_kernel<<<mlb_grid((size_t)F * 32, 256), 256>>>(key, S, polys, chunk_off, F, W);
        MLB_CUDA_LAUNCHED("raster_cover_kernel");
    }
    raster_resolve_kernel<<<mlb_grid(n_pix, 256), 256>>>(tri, bary, depth, key, S, clip, faces, W, H);
    MLB_CUDA_LAUNCHED("raster_resolve_kernel");
    return MLB_OK;
}

// ---- rasterize backward: each pixel's (dbary, ddepth) through its face's edge functions ----
__global__ void raster_backward_kernel(double* acc, const float* dbary, const float* ddepth, const int32_t* tri,
                                       const float* clip, int V, const int32_t* faces, int F, int W, int H) {
    const int n_pix = W * H;
    for (int p = blockIdx.x * blockDim.x + threadIdx.x; p < n_pix; p += gridDim.x * blockDim.x) {
        int t = tri[p];
        if (t < 0 || t >= F || !face_ok(faces, t, V)) continue;
        real v[3][4];
        rast_load_tri(v, clip, faces, t);
        tri_moments m;
        memset(&m, 0, sizeof m);
        pixel_moments(&m, v, dbary, ddepth, p, W, H);
        double G[3][4];
        moments_to_grad(G, &m, v);
        for (int i = 0; i < 3; i++)
            for (int c = 0; c < 4; c++)
                if (G[i][c] != 0) atomicAdd(&acc[4 * (size_t)faces[3 * (size_t)t + i] + c], G[i][c]);
    }
}

// out[i] += (float)acc[i]: the double sums rounded once.
__global__ void add_rounded_kernel(float* out, const double* acc, size_t n) {
    for (size_t i = blockIdx.x * (size_t)blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x)
        out[i] += (float)acc[i];
}

extern "C" mlb_status mlb_cuda_rasterize_backward(float* dclip, const float* dbary, const float* ddepth,
                                                  const int32_t* tri, const float* clip, int V, const int32_t* faces,
                                                  int F, int H, int W) {
    MLB_TRY(check_size("mlb_cuda_rasterize_backward", V, F, H, W));
    if (!dclip || (!dbary && !ddepth) || V == 0) return MLB_OK;
    if (!tri) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_rasterize_backward: tri is NULL");
    size_t n = 4 * (size_t)V, n_pix = (size_t)H * W;
    double* acc;
    MLB_TRY(mlb_cuda_scratch((void**)&acc, n * sizeof(double)));
    MLB_CUDA_CHECK(cudaMemsetAsync(acc, 0, n * sizeof(double), 0));
    raster_backward_kernel<<<mlb_grid(n_pix, 128), 128>>>(acc, dbary, ddepth, tri, clip, V, faces, F, W, H);
    MLB_CUDA_LAUNCHED("raster_backward_kernel");
    add_rounded_kernel<<<mlb_grid(n, 256), 256>>>(dclip, acc, n);
    MLB_CUDA_LAUNCHED("add_rounded_kernel");
    return MLB_OK;
}

// ---- interpolate ----
__global__ void interpolate_kernel(float* out, const float* attr, int V, int C, const int32_t* tri, const float* bary,
                                   const int32_t* faces, int F, int n_pix) {
    for (int p = blockIdx.x * blockDim.x + threadIdx.x; p < n_pix; p += gridDim.x * blockDim.x) {
        int t = tri[p];
        if (t >= F || (t >= 0 && !face_ok(faces, t, V))) t = -1;
        rast_interpolate_pixel(out + (size_t)p * C, attr, C, t, bary + 2 * (size_t)p, faces);
    }
}

extern "C" mlb_status mlb_cuda_interpolate(float* out, const float* attr, int V, int C, const int32_t* tri,
                                           const float* bary, const int32_t* faces, int F, int H, int W) {
    MLB_TRY(check_size("mlb_cuda_interpolate", V, F, H, W));
    if (C < 1) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_interpolate: %d channels (need at least 1)", C);
    int n_pix = H * W;
    interpolate_kernel<<<mlb_grid(n_pix, 128), 128>>>(out, attr, V, C, tri, bary, faces, F, n_pix);
    MLB_CUDA_LAUNCHED("interpolate_kernel");
    return MLB_OK;
}

// dbary per pixel (the CPU's double sums, one thread per pixel: its bits); dattr into double
// accumulators, rounded once.
__global__ void interpolate_backward_kernel(double* acc, float* dbary, const float* dout, const float* attr, int V,
                                            int C, const int32_t* tri, const float* bary, const int32_t* faces, int F,
                                            int n_pix) {
    for (int p = blockIdx.x * blockDim.x + threadIdx.x; p < n_pix; p += gridDim.x * blockDim.x) {
        int t = tri[p];
        if (t < 0 || t >= F || !face_ok(faces, t, V)) continue;
        const int32_t* f = faces + 3 * (size_t)t;
        const real* d = dout + (size_t)p * C;
        if (dbary) rast_interpolate_dbary(dbary + 2 * (size_t)p, d, attr, C, t, faces);
        if (acc) {
            double b[3];
            b[0] = bary[2 * (size_t)p], b[1] = bary[2 * (size_t)p + 1], b[2] = 1.0 - b[0] - b[1];
            for (int i = 0; i < 3; i++)
                for (int c = 0; c < C; c++)
                    if (d[c] != 0) atomicAdd(&acc[(size_t)f[i] * C + c], b[i] * d[c]);
        }
    }
}

extern "C" mlb_status mlb_cuda_interpolate_backward(float* dattr, float* dbary, const float* dout, const float* attr,
                                                    int V, int C, const int32_t* tri, const float* bary,
                                                    const int32_t* faces, int F, int H, int W) {
    MLB_TRY(check_size("mlb_cuda_interpolate_backward", V, F, H, W));
    if (C < 1) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_interpolate_backward: %d channels (need at least 1)", C);
    if (!dattr && !dbary) return MLB_OK;
    int n_pix = H * W;
    size_t n = (size_t)V * C;
    double* acc = NULL;
    if (dattr && n > 0) {
        MLB_TRY(mlb_cuda_scratch((void**)&acc, n * sizeof(double)));
        MLB_CUDA_CHECK(cudaMemsetAsync(acc, 0, n * sizeof(double), 0));
    }
    interpolate_backward_kernel<<<mlb_grid(n_pix, 128), 128>>>(acc, dbary, dout, attr, V, C, tri, bary, faces, F,
                                                               n_pix);
    MLB_CUDA_LAUNCHED("interpolate_backward_kernel");
    if (acc) {
        add_rounded_kernel<<<mlb_grid(n, 256), 256>>>(dattr, acc, n);
        MLB_CUDA_LAUNCHED("add_rounded_kernel");
    }
    return MLB_OK;
}

// ---- antialias ----
__global__ void aa_sign_kernel(int8_t* fsign, const float* clip, const int32_t* faces, int F) {
    for (int t = blockIdx.x * blockDim.x + threadIdx.x; t < F; t += gridDim.x * blockDim.x)
        fsign[t] = (int8_t)face_sign(t, clip, faces);
}

__global__ void aa_silhouette_kernel(uint8_t* sil, const int8_t* fsign, const float* clip, const int32_t* faces,
                                     const int32_t* adj, int F) {
    for (int t = blockIdx.x * blockDim.x + threadIdx.x; t < F; t += gridDim.x * blockDim.x)
        sil[t] = (uint8_t)(is_silhouette(t, 0, clip, faces, adj, fsign) | is_silhouette(t, 1, clip, faces, adj, fsign) << 1 |
                           is_silhouette(t, 2, clip, faces, adj, fsign) << 2);
}

// wgt [H,W,2]: the weights of each pixel's pairs with its right and lower neighbours
__global__ void aa_weight_kernel(float* wgt, const int32_t* tri, const float* depth, const float* clip,
                                 const int32_t* faces, const int32_t* adj, const uint8_t* sil, int H, int W) {
    const int n_pix = W * H;
    for (int p = blockIdx.x * blockDim.x + threadIdx.x; p < n_pix; p += gridDim.x * blockDim.x)
        for (int dir = 0; dir < 2; dir++)
            wgt[2 * (size_t)p + dir] = aa_pair_weight(p % W, p / W, dir, tri, depth, clip, faces, adj, sil, H, W);
}

__global__ void aa_blend_kernel(float* out, const float* wgt, const float* color, int C, int H, int W) {
    const int n_pix = W * H;
    for (int p = blockIdx.x * blockDim.x + threadIdx.x; p < n_pix; p += gridDim.x * blockDim.x)
        aa_blend_pixel(out, wgt, color, C, p % W, p / W, H, W);
}

__global__ void aa_dcolor_kernel(float* dcolor, const float* wgt, const float* dout, int C, int H, int W) {
    const int n_pix = W * H;
    for (int p = blockIdx.x * blockDim.x + threadIdx.x; p < n_pix; p += gridDim.x * blockDim.x)
        aa_dcolor_pixel(dcolor, wgt, dout, C, p % W, p / W, H, W);
}

// The blended pairs' position gradients into double accumulators acc [V,4] (few pairs blend: the
// silhouettes).
__global__ void aa_dclip_kernel(double* acc, const float* wgt, const float* dout, const float* color, int C,
                                const int32_t* tri, const float* depth, const float* clip, const int32_t* faces,
                                const int32_t* adj, int H, int W) {
    const int n_pix = W * H;
    for (int p = blockIdx.x * blockDim.x + threadIdx.x; p < n_pix; p += gridDim.x * blockDim.x)
        for (int dir = 0; dir < 2; dir++) {
            float w = wgt[2 * (size_t)p + dir];
            if (w == 0 || w == 0.5f || w == -0.5f) continue;   // nothing, or tau clamped
            aa_pair r;
            int j, k;
            double gj[3], gk[3];
            if (!aa_eval(&r, p, dir ? p + W : p + 1, tri, depth, clip, faces, adj, NULL, H, W) || r.clamped) continue;
            if (!aa_pair_position_grad(&j, &k, gj, gk, &r, dout, color, C, clip, faces, H, W)) continue;
            atomicAdd(&acc[4 * (size_t)j], gj[0]), atomicAdd(&acc[4 * (size_t)j + 1], gj[1]);
            atomicAdd(&acc[4 * (size_t)j + 3], gj[2]);
            atomicAdd(&acc[4 * (size_t)k], gk[0]), atomicAdd(&acc[4 * (size_t)k + 1], gk[1]);
            atomicAdd(&acc[4 * (size_t)k + 3], gk[2]);
        }
}

// The pair weights of (tri, depth, clip, adj) into wgt, with sil and fsign as scratch.
static mlb_status aa_weights(float* wgt, uint8_t* sil, int8_t* fsign, const int32_t* tri, const float* depth,
                             const float* clip, const int32_t* faces, const int32_t* adj, int F, int H, int W) {
    if (F > 0) {
        aa_sign_kernel<<<mlb_grid(F, 256), 256>>>(fsign, clip, faces, F);
        MLB_CUDA_LAUNCHED("aa_sign_kernel");
        aa_silhouette_kernel<<<mlb_grid(F, 256), 256>>>(sil, fsign, clip, faces, adj, F);
        MLB_CUDA_LAUNCHED("aa_silhouette_kernel");
    }
    aa_weight_kernel<<<mlb_grid((size_t)H * W, 128), 128>>>(wgt, tri, depth, clip, faces, adj, sil, H, W);
    MLB_CUDA_LAUNCHED("aa_weight_kernel");
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_antialias(float* out, float* weights, const float* color, int C, const int32_t* tri,
                                         const float* depth, const float* clip, int V, const int32_t* faces,
                                         const int32_t* adj, int F, int H, int W) {
    MLB_TRY(check_size("mlb_cuda_antialias", V, F, H, W));
    if (C < 1) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_antialias: %d channels (need at least 1)", C);
    if (!out || out == color) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_antialias: out is NULL or aliases color");
    size_t n_pix = (size_t)H * W;
    void* scratch;
    MLB_TRY(mlb_cuda_scratch(&scratch, (2 * n_pix * sizeof(float) + 256) + 2 * ((size_t)F + 256)));
    char* cur = (char*)scratch;
    float* wgt = (float*)carve(&cur, 2 * n_pix * sizeof(float));
    int8_t* fsign = (int8_t*)carve(&cur, (size_t)F);
    uint8_t* sil = (uint8_t*)carve(&cur, (size_t)F);
    if (weights) wgt = weights;
    MLB_TRY(aa_weights(wgt, sil, fsign, tri, depth, clip, faces, adj, F, H, W));
    aa_blend_kernel<<<mlb_grid(n_pix, 128), 128>>>(out, wgt, color, C, H, W);
    MLB_CUDA_LAUNCHED("aa_blend_kernel");
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_antialias_backward(float* dcolor, float* dclip, const float* dout, const float* weights,
                                                  const float* color, int C, const int32_t* tri, const float* depth,
                                                  const float* clip, int V, const int32_t* faces, const int32_t* adj,
                                                  int F, int H, int W) {
    MLB_TRY(check_size("mlb_cuda_antialias_backward", V, F, H, W));
    if (C < 1) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_antialias_backward: %d channels (need at least 1)", C);
    if (!dcolor && !dclip) return MLB_OK;
    if (!dout) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_antialias_backward: dout is NULL");
    size_t n_pix = (size_t)H * W, n = 4 * (size_t)V;
    void* scratch;
    MLB_TRY(mlb_cuda_scratch(&scratch, (2 * n_pix * sizeof(float) + 256) + 2 * ((size_t)F + 256) +
                                           (n * sizeof(double) + 256)));
    char* cur = (char*)scratch;
    float* w = (float*)carve(&cur, 2 * n_pix * sizeof(float));
    int8_t* fsign = (int8_t*)carve(&cur, (size_t)F);
    uint8_t* sil = (uint8_t*)carve(&cur, (size_t)F);
    double* acc = (double*)carve(&cur, n * sizeof(double));
    const float* wgt = weights;
    if (!wgt) {   // recompute the forward's pair weights
        MLB_TRY(aa_weights(w, sil, fsign, tri, depth, clip, faces, adj, F, H, W));
        wgt = w;
    }
    if (dcolor) {
        aa_dcolor_kernel<<<mlb_grid(n_pix, 128), 128>>>(dcolor, wgt, dout, C, H, W);
        MLB_CUDA_LAUNCHED("aa_dcolor_kernel");
    }
    if (dclip && n > 0) {
        MLB_CUDA_CHECK(cudaMemsetAsync(acc, 0, n * sizeof(double), 0));
        aa_dclip_kernel<<<mlb_grid(n_pix, 128), 128>>>(acc, wgt, dout, color, C, tri, depth, clip, faces, adj, H, W);
        MLB_CUDA_LAUNCHED("aa_dclip_kernel");
        add_rounded_kernel<<<mlb_grid(n, 256), 256>>>(dclip, acc, n);
        MLB_CUDA_LAUNCHED("add_rounded_kernel");
    }
    return MLB_OK;
}

// ---- the surface's clip coordinates: raster_math.h's per-vertex transform, in double ----
__global__ void transform_points_kernel(float* clip, const float* pos, int V, mlb_mat4 m) {
    for (int v = blockIdx.x * blockDim.x + threadIdx.x; v < V; v += gridDim.x * blockDim.x)
        rast_transform_point(clip + 4 * (size_t)v, pos + 3 * (size_t)v, m.m);
}
__global__ void transform_points_backward_kernel(float* dpos, const float* dclip, int V, mlb_mat4 m) {
    for (int v = blockIdx.x * blockDim.x + threadIdx.x; v < V; v += gridDim.x * blockDim.x)
        rast_transform_point_backward(dpos + 3 * (size_t)v, dclip + 4 * (size_t)v, m.m);
}
extern "C" mlb_status mlb_cuda_transform_points(float* clip, const float* pos, int V, const double* m) {
    if (V < 0 || !m) return mlb_fail(MLB_ERR_ARG, "transform_points: %d vertices%s", V, m ? "" : ", no matrix");
    if (!V) return MLB_OK;
    mlb_mat4 M;
    memcpy(M.m, m, sizeof M.m);
    transform_points_kernel<<<mlb_grid((size_t)V, 256), 256>>>(clip, pos, V, M);
    MLB_CUDA_LAUNCHED("transform_points_kernel");
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_transform_points_backward(float* dpos, const float* dclip, int V, const double* m) {
    if (V < 0 || !m) return mlb_fail(MLB_ERR_ARG, "transform_points_backward: %d vertices%s", V, m ? "" : ", no matrix");
    if (!V || !dpos) return MLB_OK;
    mlb_mat4 M;
    memcpy(M.m, m, sizeof M.m);
    transform_points_backward_kernel<<<mlb_grid((size_t)V, 256), 256>>>(dpos, dclip, V, M);
    MLB_CUDA_LAUNCHED("transform_points_backward_kernel");
    return MLB_OK;
}
