// Marching tetrahedra's ops on the GPU (mt_ops.h's contracts, backend_ops.def): the CPU's own
// per-element maths (mesh/marching_tets_math.h) in float, one thread per tet and per grid vertex
// (its seven edge slots), compiled with -fmad=false (CMakeLists.txt) so that vertex positions,
// weights and the gradients are the CPU's float bits. The surface's size is the caller's business:
// count, then scan_i32 (exact integers, here on the device), then emit into buffers sized by the
// totals. The backward gathers per grid vertex instead of scattering per surface vertex: each
// output has one writer, and its terms are added in the CPU's order (mt_backward_vertex), so no
// atomics.
#include "common.cuh"
typedef float real;
#define R_EXP expf
#define R_LOG1P log1pf
#define R_FABS fabsf
#include "mesh/marching_tets_math.h"

// ---- count ----
__global__ void mt_count_kernel(int32_t* tet_nf, int32_t* slot_nv, const float* sdf, const int32_t* tets, int T,
                                int V, int n) {
    for (int i = blockIdx.x * blockDim.x + threadIdx.x; i < (V > T ? V : T); i += gridDim.x * blockDim.x) {
        if (i < T) tet_nf[i] = mt_num_tri(mt_case(sdf, tets + 4 * (size_t)i));
        if (i < V) mt_count_slots(slot_nv, sdf, i, n);
    }
}

static mlb_status mt_check(int T, int cells) {
    if (T < 0 || cells < 1 || cells > 512) return mlb_fail(MLB_ERR_ARG, "marching tets: %d tets, %d cells", T, cells);
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_marching_tets_count(int32_t* tet_nf, int32_t* slot_nv, const float* sdf,
                                                   const int32_t* tets, int T, int cells) {
    MLB_TRY(mt_check(T, cells));
    const int n = cells + 1, V = n * n * n;
    mt_count_kernel<<<mlb_grid((size_t)(V > T ? V : T), 256), 256>>>(tet_nf, slot_nv, sdf, tets, T, V, n);
    MLB_CUDA_LAUNCHED("marching tets count");
    return MLB_OK;
}

// ---- scan: tiles of SCAN_TILE values, one per thread ----
#define SCAN_TILE 1024

// The exclusive scan of x over the block (SCAN_TILE threads); *total gets the block's sum. Warp
// shuffles, then the warps' sums scanned by the first warp.
__device__ int32_t block_exclusive_scan(int32_t x, int32_t* total) {
    __shared__ int32_t warp_sum[SCAN_TILE / 32];
    const int lane = threadIdx.x & 31, wid = threadIdx.x >> 5;
    int32_t incl = x;
    for (int o = 1; o < 32; o <<= 1) {
        int32_t y = __shfl_up_sync(0xffffffffu, incl, o);
        if (lane >= o) incl += y;
    }
    if (lane == 31) warp_sum[wid] = incl;
    __syncthreads();
    if (wid == 0) {
        int32_t w = warp_sum[lane];   // SCAN_TILE / 32 == 32 warps
        for (int o = 1; o < 32; o <<= 1) {
            int32_t y = __shfl_up_sync(0xffffffffu, w, o);
            if (lane >= o) w += y;
        }
        warp_sum[lane] = w;   // inclusive over the warps
    }
    __syncthreads();
    int32_t r = (wid ? warp_sum[wid - 1] : 0) + incl - x;
    *total = warp_sum[SCAN_TILE / 32 - 1];
    __syncthreads();   // warp_sum may be written again by the caller's next call
    return r;
}

__global__ void scan_tile_sums_kernel(int32_t* sums, const int32_t* in, int n) {
    long long i = (long long)blockIdx.x * SCAN_TILE + threadIdx.x;
    int32_t total;
    block_exclusive_scan(i < n ? in[i] : 0, &total);
    if (threadIdx.x == 0) sums[blockIdx.x] = total;
}
// One block: sums[0..nb) becomes its exclusive scan, tile after tile with a carry.
__global__ void scan_sums_kernel(int32_t* sums, int nb) {
    int32_t carry = 0;
    for (int base = 0; base < nb; base += SCAN_TILE) {
        int i = base + threadIdx.x;
        int32_t total, x = i < nb ? sums[i] : 0;
        int32_t e = block_exclusive_scan(x, &total);
        if (i < nb) sums[i] = carry + e;
        carry += total;
    }
}
// Each tile's own scan plus the tiles before it; the thread of the last value writes the total.
// Every tile reads only its own values before writing them, so out may be in.
__global__ void scan_tiles_kernel(int32_t* out, const int32_t* in, int n, const int32_t* sums) {
    long long i = (long long)blockIdx.x * SCAN_TILE + threadIdx.x;
    int32_t total, x = i < n ? in[i] : 0;
    int32_t e = block_exclusive_scan(x, &total) + sums[blockIdx.x];
    if (i < n) out[i] = e;
    if (i == n - 1) out[n] = e + x;
}
__global__ void scan_zero_kernel(int32_t* out) { out[0] = 0; }

size_t mlb_cuda_scan_i32_sums(int n) { return n > 0 ? (size_t)((n + SCAN_TILE - 1) / SCAN_TILE) : 1; }

mlb_status mlb_cuda_scan_i32_into(int32_t* out, const int32_t* in, int n, int32_t* sums) {
    if (n < 0) return mlb_fail(MLB_ERR_ARG, "scan of %d values", n);
    if (n == 0) {
        scan_zero_kernel<<<1, 1>>>(out);
        MLB_CUDA_LAUNCHED("scan");
        return MLB_OK;
    }
    int nb = (int)mlb_cuda_scan_i32_sums(n);
    scan_tile_sums_kernel<<<nb, SCAN_TILE>>>(sums, in, n);
    MLB_CUDA_LAUNCHED("scan tile sums");
    scan_sums_kernel<<<1, SCAN_TILE>>>(sums, nb);
    MLB_CUDA_LAUNCHED("scan sums");
    scan_tiles_kernel<<<nb, SCAN_TILE>>>(out, in, n, sums);
    MLB_CUDA_LAUNCHED("scan tiles");
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_scan_i32(int32_t* out, const int32_t* in, int n) {
    if (n < 0) return mlb_fail(MLB_ERR_ARG, "scan of %d values", n);
    int32_t* sums;
    MLB_TRY(mlb_cuda_scratch((void**)&sums, mlb_cuda_scan_i32_sums(n) * sizeof(int32_t)));
    return mlb_cuda_scan_i32_into(out, in, n, sums);
}

// ---- emit ----
__global__ void mt_emit_kernel(float* verts, int32_t* vedge, float* weight, int32_t* faces, const float* pos,
                               const float* sdf, const int32_t* tets, int T, int V, int n, const int32_t* tet_off,
                               const int32_t* slot_off) {
    for (int i = blockIdx.x * blockDim.x + threadIdx.x; i < (V > T ? V : T); i += gridDim.x * blockDim.x) {
        if (i < V) mt_emit_slots(verts, vedge, weight, pos, sdf, i, n, slot_off);
        if (i < T) {
            int cnt = tet_off[i + 1] - tet_off[i];
            const int32_t* tv = tets + 4 * (size_t)i;
            if (cnt) mt_emit_faces(faces, tv, mt_case(sdf, tv), tet_off[i], cnt, slot_off, n);
        }
    }
}

extern "C" mlb_status mlb_cuda_marching_tets_emit(float* verts, int32_t* vedge, float* weight, int32_t* faces,
                                                  const float* pos, const float* sdf, const int32_t* tets, int T,
                                                  int cells, const int32_t* tet_off, const int32_t* slot_off) {
    MLB_TRY(mt_check(T, cells));
    const int n = cells + 1, V = n * n * n;
    mt_emit_kernel<<<mlb_grid((size_t)(V > T ? V : T), 256), 256>>>(verts, vedge, weight, faces, pos, sdf, tets, T, V,
                                                                     n, tet_off, slot_off);
    MLB_CUDA_LAUNCHED("marching tets emit");
    return MLB_OK;
}

// ---- backward: a thread per grid vertex ----
__global__ void mt_backward_kernel(float* dpos, float* dsdf, const float* dverts, const float* weight,
                                   const float* pos, const float* sdf, const int32_t* slot_off, int n) {
    const int V = n * n * n;
    for (int v = blockIdx.x * blockDim.x + threadIdx.x; v < V; v += gridDim.x * blockDim.x)
        mt_backward_vertex(dpos, dsdf, v, dverts, weight, pos, sdf, slot_off, n);
}

extern "C" mlb_status mlb_cuda_marching_tets_backward(float* dpos, float* dsdf, const float* dverts,
                                                      const float* weight, const int32_t* vedge, int nv,
                                                      const float* pos, const float* sdf, const int32_t* slot_off,
                                                      int cells) {
    (void)vedge;   // the gather finds each vertex's edge from its slot
    MLB_TRY(mt_check(0, cells));
    if (nv <= 0 || (!dpos && !dsdf)) return MLB_OK;
    const int n = cells + 1;
    mt_backward_kernel<<<mlb_grid((size_t)n * n * n, 256), 256>>>(dpos, dsdf, dverts, weight, pos, sdf, slot_off, n);
    MLB_CUDA_LAUNCHED("marching tets backward");
    return MLB_OK;
}

// ---- DMTet's deformation and the SDF sign regulariser (dmtet.h's maths; this file has no fused
// multiply-adds, but tanhf and expf are CUDA's, so these are within a few ulp of the CPU) ----
__global__ void deform_kernel(float* out, const float* grid, const float* deform, size_t n, float grid_res) {
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x)
        out[i] = grid[i] + tanhf(deform[i]) / grid_res;
}
__global__ void deform_backward_kernel(float* ddeform, const float* dout, const float* deform, size_t n, float grid_res) {
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        float th = tanhf(deform[i]);
        ddeform[i] += dout[i] * (1 - th * th) / grid_res;
    }
}
extern "C" mlb_status mlb_cuda_dmtet_deform(float* out, const float* grid, const float* deform, int n_verts,
                                            float grid_res) {
    if (n_verts < 0) return mlb_fail(MLB_ERR_ARG, "dmtet_deform: %d vertices", n_verts);
    size_t n = 3 * (size_t)n_verts;
    if (!n) return MLB_OK;
    deform_kernel<<<mlb_grid(n, 256), 256>>>(out, grid, deform, n, grid_res);
    MLB_CUDA_LAUNCHED("deform_kernel");
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_dmtet_deform_backward(float* ddeform, const float* dout, const float* deform, int n_verts,
                                                     float grid_res) {
    if (n_verts < 0) return mlb_fail(MLB_ERR_ARG, "dmtet_deform_backward: %d vertices", n_verts);
    size_t n = 3 * (size_t)n_verts;
    if (!n || !ddeform) return MLB_OK;
    deform_backward_kernel<<<mlb_grid(n, 256), 256>>>(ddeform, dout, deform, n, grid_res);
    MLB_CUDA_LAUNCHED("deform_backward_kernel");
    return MLB_OK;
}

enum { REG_THREADS = 256 };
// per block: the sum of its vertices' terms (double) and their lower-end edge count
__global__ void sdf_reg_partial_kernel(double* sums, long long* counts, const float* sdf, int V, int cells) {
    __shared__ double s_sum[REG_THREADS];
    __shared__ long long s_cnt[REG_THREADS];
    int v = blockIdx.x * REG_THREADS + threadIdx.x, nl = 0;
    double t = 0;
    if (v < V) t = (double)mt_reg_terms(sdf, v, cells, 0, &nl);
    s_sum[threadIdx.x] = t;
    s_cnt[threadIdx.x] = nl;
    __syncthreads();
    for (int h = REG_THREADS / 2; h > 0; h >>= 1) {
        if ((int)threadIdx.x < h) { s_sum[threadIdx.x] += s_sum[threadIdx.x + h]; s_cnt[threadIdx.x] += s_cnt[threadIdx.x + h]; }
        __syncthreads();
    }
    if (threadIdx.x == 0) { sums[blockIdx.x] = s_sum[0]; counts[blockIdx.x] = s_cnt[0]; }
}
// the blocks in order: out = (float)(sum) / m, scale = dloss / m (either may be NULL)
__global__ void sdf_reg_total_kernel(float* out, float* scale, const double* sums, const long long* counts, int nb,
                                     float dloss) {
    double s = 0;
    long long m = 0;
    for (int b = 0; b < nb; b++) { s += sums[b]; m += counts[b]; }
    if (out) *out = m ? (float)s / (float)m : 0.0f;
    if (scale) *scale = m ? dloss / (float)m : 0.0f;
}
__global__ void sdf_reg_backward_kernel(float* dsdf, const float* sdf, int V, int cells, const float* scale) {
    int v = blockIdx.x * blockDim.x + threadIdx.x;
    if (v >= V) return;
    int nl;
    dsdf[v] += *scale * mt_reg_terms(sdf, v, cells, 1, &nl);
}
// The partial sums into scratch; *sums, *counts, *tail (2 floats) point into it.
static mlb_status sdf_reg_partials(const float* sdf, int cells, int* nb_out, double** sums, long long** counts, float** tail) {
    if (cells < 1 || cells > 512) return mlb_fail(MLB_ERR_ARG, "sdf_reg: %d cells", cells);
    int n = cells + 1, V = n * n * n, nb = (V + REG_THREADS - 1) / REG_THREADS;
    char* scratch;
    MLB_TRY(mlb_cuda_scratch((void**)&scratch, (size_t)nb * (sizeof(double) + sizeof(long long)) + 2 * sizeof(float)));
    *sums = (double*)scratch;
    *counts = (long long*)(scratch + (size_t)nb * sizeof(double));
    *tail = (float*)(scratch + (size_t)nb * (sizeof(double) + sizeof(long long)));
    sdf_reg_partial_kernel<<<nb, REG_THREADS>>>(*sums, *counts, sdf, V, cells);
    MLB_CUDA_LAUNCHED("sdf_reg_partial_kernel");
    *nb_out = nb;
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_sdf_reg(float* out, const float* sdf, int cells) {
    int nb;
    double* sums;
    long long* counts;
    float* tail;
    MLB_TRY(sdf_reg_partials(sdf, cells, &nb, &sums, &counts, &tail));
    sdf_reg_total_kernel<<<1, 1>>>(out, NULL, sums, counts, nb, 0.0f);
    MLB_CUDA_LAUNCHED("sdf_reg_total_kernel");
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_sdf_reg_backward(float* dsdf, const float* sdf, int cells, float dloss) {
    if (!dsdf) return MLB_OK;
    int nb;
    double* sums;
    long long* counts;
    float* tail;
    MLB_TRY(sdf_reg_partials(sdf, cells, &nb, &sums, &counts, &tail));
    sdf_reg_total_kernel<<<1, 1>>>(NULL, tail, sums, counts, nb, dloss);
    MLB_CUDA_LAUNCHED("sdf_reg_total_kernel");
    int n = cells + 1, V = n * n * n;
    sdf_reg_backward_kernel<<<(V + 255) / 256, 256>>>(dsdf, sdf, V, cells, tail);
    MLB_CUDA_LAUNCHED("sdf_reg_backward_kernel");
    return MLB_OK;
}

// ---- the surface's vertex normals (mt_ops.h's gather passes over mesh/vertex_normals_math.h) ----
// vertex_faces: per-vertex counts by atomics (integers: exact), their scan, a fill through atomic
// cursors (any order), then each vertex's short list sorted: the CPU's face order, bit for bit.
#include "mesh/vertex_normals_math.h"
__global__ void vf_count_kernel(int32_t* count, const int32_t* faces, int n) {
    for (int i = blockIdx.x * blockDim.x + threadIdx.x; i < n; i += gridDim.x * blockDim.x) atomicAdd(&count[faces[i]], 1);
}
__global__ void vf_fill_kernel(int32_t* vf, int32_t* cursor, const int32_t* off, const int32_t* faces, int n) {
    for (int i = blockIdx.x * blockDim.x + threadIdx.x; i < n; i += gridDim.x * blockDim.x) {
        int v = faces[i];
        vf[off[v] + atomicAdd(&cursor[v], 1)] = i;
    }
}
__global__ void vf_sort_kernel(int32_t* vf, const int32_t* off, int V) {
    for (int v = blockIdx.x * blockDim.x + threadIdx.x; v < V; v += gridDim.x * blockDim.x)
        for (int32_t a = off[v] + 1; a < off[v + 1]; a++) {   // insertion sort: a handful of entries
            int32_t x = vf[a], b = a - 1;
            for (; b >= off[v] && vf[b] > x; b--) vf[b + 1] = vf[b];
            vf[b + 1] = x;
        }
}
extern "C" mlb_status mlb_cuda_vertex_faces(int32_t* off, int32_t* vf, const int32_t* faces, int F, int V) {
    if (F < 0 || V < 0 || (long long)F * 3 > INT32_MAX) return mlb_fail(MLB_ERR_ARG, "vertex_faces: %d faces, %d vertices", F, V);
    int n = 3 * F;
    MLB_CUDA_CHECK(cudaMemsetAsync(off, 0, sizeof(int32_t) * ((size_t)V + 1)));
    if (n) {
        vf_count_kernel<<<mlb_grid((size_t)n, 256), 256>>>(off, faces, n);
        MLB_CUDA_LAUNCHED("vf_count_kernel");
    }
    MLB_TRY(mlb_cuda_scan_i32(off, off, V));   // in place: off[V] the total, 3 F
    if (!n) return MLB_OK;
    int32_t* cursor;
    MLB_TRY(mlb_cuda_scratch((void**)&cursor, sizeof(int32_t) * ((size_t)V + 1)));
    MLB_CUDA_CHECK(cudaMemsetAsync(cursor, 0, sizeof(int32_t) * ((size_t)V + 1)));
    vf_fill_kernel<<<mlb_grid((size_t)n, 256), 256>>>(vf, cursor, off, faces, n);
    MLB_CUDA_LAUNCHED("vf_fill_kernel");
    vf_sort_kernel<<<mlb_grid((size_t)V, 256), 256>>>(vf, off, V);
    MLB_CUDA_LAUNCHED("vf_sort_kernel");
    return MLB_OK;
}
__global__ void edge_topology_kernel(int32_t* adj, const int32_t* faces, int F, const int32_t* off, const int32_t* vf) {
    for (long long i = blockIdx.x * (long long)blockDim.x + threadIdx.x; i < 3LL * F; i += (long long)gridDim.x * blockDim.x)
        adj[i] = vn_edge_partner(faces, off, vf, (int)(i / 3), (int)(i % 3));
}
extern "C" mlb_status mlb_cuda_edge_topology(int32_t* adj, const int32_t* faces, int F, const int32_t* off,
                                             const int32_t* vf) {
    if (F < 0) return mlb_fail(MLB_ERR_ARG, "edge_topology: %d faces", F);
    if (!F) return MLB_OK;
    edge_topology_kernel<<<mlb_grid(3 * (size_t)F, 256), 256>>>(adj, faces, F, off, vf);
    MLB_CUDA_LAUNCHED("edge_topology_kernel");
    return MLB_OK;
}
__global__ void vertex_normals_kernel(float* normal, float* sum, const float* pos, int V, const int32_t* faces,
                                      const int32_t* off, const int32_t* vf) {
    for (int v = blockIdx.x * blockDim.x + threadIdx.x; v < V; v += gridDim.x * blockDim.x)
        vn_gather_normal(sum ? sum + 3 * (size_t)v : NULL, normal + 3 * (size_t)v, pos, faces, off, vf, v);
}
__global__ void vertex_normals_backward_kernel(float* dpos, const float* dnormal, const float* sum, const float* pos,
                                               int V, const int32_t* faces, const int32_t* off, const int32_t* vf) {
    for (int v = blockIdx.x * blockDim.x + threadIdx.x; v < V; v += gridDim.x * blockDim.x)
        vn_gather_backward(dpos + 3 * (size_t)v, dnormal, sum, pos, faces, off, vf, v);
}
extern "C" mlb_status mlb_cuda_vertex_normals(float* normal, float* sum, const float* pos, int V, const int32_t* faces,
                                              const int32_t* off, const int32_t* vf) {
    if (V < 0) return mlb_fail(MLB_ERR_ARG, "vertex_normals: %d vertices", V);
    if (!V) return MLB_OK;
    vertex_normals_kernel<<<mlb_grid((size_t)V, 256), 256>>>(normal, sum, pos, V, faces, off, vf);
    MLB_CUDA_LAUNCHED("vertex_normals_kernel");
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_vertex_normals_backward(float* dpos, const float* dnormal, const float* sum,
                                                       const float* pos, int V, const int32_t* faces,
                                                       const int32_t* off, const int32_t* vf) {
    if (V < 0) return mlb_fail(MLB_ERR_ARG, "vertex_normals_backward: %d vertices", V);
    if (!V || !dpos) return MLB_OK;
    vertex_normals_backward_kernel<<<mlb_grid((size_t)V, 256), 256>>>(dpos, dnormal, sum, pos, V, faces, off, vf);
    MLB_CUDA_LAUNCHED("vertex_normals_backward_kernel");
    return MLB_OK;
}
