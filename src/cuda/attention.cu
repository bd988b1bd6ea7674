// Flash-style multi-head self-attention forward: the contract of attention_forward
// (transformer_ops.h) without the probability matrix. Keys and values stream through shared
// memory in tiles of 32; every query row keeps a running maximum, a running sum and its output
// accumulator (the online softmax), so memory is O(T hd), never O(T^2).
//
// Block: ATT_WARPS warps, one query row each, all sharing the K/V tiles of one (batch, head).
// Lane j of a warp scores key s0 + j (a full dot product over hd from shared memory; the K rows
// are padded to an odd stride so the 32 lanes hit 32 banks), the warp agrees on the tile maximum
// by shuffles, and each lane accumulates NE = ceil(hd / 32) output elements (e = lane + 32 i).
// CUDA cores in fp32; a tensor-core (mma) version is the next step (docs/cuda.md).
#include <math.h>
#include "common.cuh"

#define ATT_WARPS 8
#define ATT_TILE 32

template <int NE>
__global__ void __launch_bounds__(ATT_WARPS * 32) attention_kernel(float* out, const float* q, const float* k,
                                                                   const float* v, int ld, int T, int C, int NH,
                                                                   int hd, int causal, float scale) {
    extern __shared__ float smem[];
    const int ks = (hd % 2 == 0) ? hd + 1 : hd;   // odd stride: conflict-free column reads
    float* Ks = smem;                              // [ATT_TILE][ks]
    float* Vs = Ks + ATT_TILE * ks;                // [ATT_TILE][hd]
    float* Qs = Vs + ATT_TILE * hd;                // [ATT_WARPS][hd]
    const int warp = threadIdx.x >> 5, lane = threadIdx.x & 31;
    const int bh = blockIdx.y, b = bh / NH, h = bh % NH;
    const int t0 = blockIdx.x * ATT_WARPS, t = t0 + warp;
    const int valid_row = t < T;
    const size_t head = (size_t)h * hd;
    const float* qb = q + (size_t)b * T * ld + head;
    const float* kb = k + (size_t)b * T * ld + head;
    const float* vb = v + (size_t)b * T * ld + head;

    for (int e = lane; e < hd; e += 32) Qs[warp * hd + e] = valid_row ? qb[(size_t)t * ld + e] : 0.0f;
    float acc[NE];
#pragma unroll
    for (int i = 0; i < NE; i++) acc[i] = 0.0f;
    float m_run = -INFINITY, l_run = 0.0f;
    int kend = T;
    if (causal) kend = min(T, t0 + ATT_WARPS);   // the last row of the block sees keys <= its index
    for (int s0 = 0; s0 < kend; s0 += ATT_TILE) {
        __syncthreads();   // the previous tile (and Qs on the first pass) is done with
        for (int idx = threadIdx.x; idx < ATT_TILE * hd; idx += blockDim.x) {
            int r = idx / hd, c = idx - r * hd, s = s0 + r;
            float kv = 0.0f, vv = 0.0f;
            if (s < T) {
                kv = kb[(size_t)s * ld + c];
                vv = vb[(size_t)s * ld + c];
            }
            Ks[r * ks + c] = kv;
            Vs[r * hd + c] = vv;
        }
        __syncthreads();
        // score of key s0 + lane
        const int s = s0 + lane;
        float score = -INFINITY;
        if (s < T && (!causal || s <= t)) {
            const float* qr = Qs + warp * hd;
            const float* kr = Ks + lane * ks;
            float d = 0.0f;
            for (int e = 0; e < hd; e++) d = fmaf(qr[e], kr[e], d);
            score = d * scale;
        }
        float m_tile = score;
        for (int o = 16; o > 0; o >>= 1) m_tile = fmaxf(m_tile, __shfl_xor_sync(0xffffffffu, m_tile, o));
        const float m_new = fmaxf(m_run, m_tile);
        if (m_new == -INFINITY) continue;   // every key so far masked (a padding row): nothing to add
        const float p = expf(score - m_new);   // 0 for masked keys
        const float corr = expf(m_run - m_new);   // 0 on the first tile
        float psum = p;
        for (int o = 16; o > 0; o >>= 1) psum += __shfl_xor_sync(0xffffffffu, psum, o);
        l_run = l_run * corr + psum;
        m_run = m_new;
#pragma unroll
        for (int i = 0; i < NE; i++) acc[i] *= corr;
        const int jmax = min(ATT_TILE, T - s0);
        for (int j = 0; j < jmax; j++) {
            const float pj = __shfl_sync(0xffffffffu, p, j);
            const float* vr = Vs + j * hd;
#pragma unroll
            for (int i = 0; i < NE; i++) {
                int e = lane + 32 * i;
                if (e < hd) acc[i] = fmaf(pj, vr[e], acc[i]);
            }
        }
    }
    if (!valid_row) return;
    const float inv = 1.0f / l_run;
    float* o = out + ((size_t)b * T + t) * C + head;
#pragma unroll
    for (int i = 0; i < NE; i++) {
        int e = lane + 32 * i;
        if (e < hd) o[e] = acc[i] * inv;
    }
}

template <int NE>
static mlb_status launch(float* out, const float* q, const float* k, const float* v, int ld, int B, int T, int C, int NH,
                         int hd, int causal) {
    const int ks = (hd % 2 == 0) ? hd + 1 : hd;
    size_t bytes = sizeof(float) * ((size_t)ATT_TILE * ks + (size_t)ATT_TILE * hd + (size_t)ATT_WARPS * hd);
    int dev, optin = 0;
    MLB_CUDA_CHECK(cudaGetDevice(&dev));
    MLB_CUDA_CHECK(cudaDeviceGetAttribute(&optin, cudaDevAttrMaxSharedMemoryPerBlockOptin, dev));
    if (bytes > (size_t)optin)
        return mlb_fail(MLB_ERR_UNSUPPORTED, "mlb_cuda_attention_forward: head width %d needs %zu bytes of shared memory, "
                        "the GPU allows %d", hd, bytes, optin);
    if (bytes > 48 * 1024)
        MLB_CUDA_CHECK(cudaFuncSetAttribute(attention_kernel<NE>, cudaFuncAttributeMaxDynamicSharedMemorySize, (int)bytes));
    dim3 grid((unsigned)((T + ATT_WARPS - 1) / ATT_WARPS), (unsigned)(B * NH));
    attention_kernel<NE><<<grid, ATT_WARPS * 32, bytes>>>(out, q, k, v, ld, T, C, NH, hd, causal,
                                                         (float)(1.0 / sqrt((double)hd)));
    MLB_CUDA_LAUNCHED("attention_kernel");
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_attention_forward(float* out, const float* q, const float* k, const float* v, int ld, int B,
                                                 int T, int C, int NH, int causal) {
    if (B < 0 || T < 0 || C <= 0 || NH <= 0 || C % NH != 0 || ld < C)
        return mlb_fail(MLB_ERR_ARG, "mlb_cuda_attention_forward: bad shape B %d T %d C %d NH %d ld %d "
                        "(C must be a multiple of NH, ld >= C)", B, T, C, NH, ld);
    if (B == 0 || T == 0) return MLB_OK;
    if ((size_t)B * NH > 65535) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_attention_forward: B*NH = %zu > 65535", (size_t)B * NH);
    const int hd = C / NH;
    if (hd <= 64) return launch<2>(out, q, k, v, ld, B, T, C, NH, hd, causal);
    if (hd <= 128) return launch<4>(out, q, k, v, ld, B, T, C, NH, hd, causal);
    if (hd <= 160) return launch<5>(out, q, k, v, ld, B, T, C, NH, hd, causal);
    if (hd <= 256) return launch<8>(out, q, k, v, ld, B, T, C, NH, hd, causal);
    if (hd <= 512) return launch<16>(out, q, k, v, ld, B, T, C, NH, hd, causal);
    return mlb_fail(MLB_ERR_UNSUPPORTED, "mlb_cuda_attention_forward: head width %d > 512", hd);
}
