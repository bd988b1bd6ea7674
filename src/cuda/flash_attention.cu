// Scaled dot-product attention fused on the tensor cores (fp16/bf16 operands, fp32 accumulation):
// the [Tq, Tk] scores never reach device memory. sdpa_forward's contract (conv_ops.h), taken by
// mlb_cuda_sdpa_forward at fp16/bf16 for head widths up to 256 (docs/cuda.md).
//
// q, k, v are first split into heads in the operand type, padded with zeros to whole tiles:
// [B*NH, Tp, hdp] with Tp a multiple of 64 and hdp of 16, so the tile loads need no bounds and
// padded keys give finite scores that the softmax masks. A block takes 64 query rows of one
// (image, head), four warps of 16 rows each, and walks the keys in tiles of 64:
//   S_w [16, 64] = Q_w K^T             wmma 16x16x16, into the warp's float tile in shared memory
//   online softmax per row              two lanes per row (columns interleaved), base-2 exponent:
//                                       m' = max(m, max_j s_j c), P = 2^(s c - m'), l = l 2^(m - m') + sum P
//   O_w = O_w 2^(m - m') + P V          O kept in shared memory as float
// then O / l goes to out [B, Tq, C] (the heads merged on the way) and lse = (m + log2 l) ln 2.
// Shared memory: (3 * 64 (hdp + 8)) 16-bit values + 4 warps x (16 x 68 floats + 16 x 72 16-bit
// + 16 (hdp + 4) floats): 61 KB at hdp 48, 190 KB at 256.
#include <cuda_bf16.h>
#include <cuda_fp16.h>
#include <math.h>
#include <mma.h>
#include "common.cuh"
#include "gemm_ops.cuh"

namespace {
constexpr int BQ = 64, BK = 64, WARPS = 4, THREADS = 32 * WARPS;
constexpr int SLD = BK + 4;   // a warp's score tile, floats per row (a multiple of 4, as wmma needs)
constexpr int PLD = BK + 8;   // a warp's probabilities, 16-bit values per row (a multiple of 8)
constexpr int MAX_HD = 256;

struct flash_layout {
    int ld, old;   // rows of Q/K/V in 16-bit values, rows of O in floats
    size_t bytes;
};
flash_layout layout_of(int hdp) {
    flash_layout L;
    L.ld = hdp + 8;
    L.old = hdp + 4;
    L.bytes = (size_t)3 * BQ * L.ld * 2 + (size_t)WARPS * 16 * (SLD * 4 + PLD * 2 + L.old * 4);
    return L;
}
}   // namespace

// out [BH, Tp, hdp] of T from in [B, T, ld] (head h at column h*hd), zeros outside T x hd
template <typename T>
__global__ void split_heads_padded_kernel(T* out, const float* in, int B, int T_, int Tp, int NH, int hd, int hdp,
                                          int ld) {
    const size_t n = (size_t)B * NH * Tp * hdp;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        const int d = (int)(i % hdp);
        const size_t rt = i / hdp;
        const int t = (int)(rt % Tp);
        const size_t bh = rt / Tp;
        const int h = (int)(bh % NH), b = (int)(bh / NH);
        float v = 0.0f;
        if (t < T_ && d < hd) v = in[((size_t)b * T_ + t) * ld + (size_t)h * hd + d];
        out[i] = to_operand<T>(v);
    }
}

template <typename T>
__global__ void __launch_bounds__(THREADS)
    flash_forward_kernel(float* out, float* lse, const T* qh, const T* kh, const T* vh, int NH, int Tq, int Tqp,
                         int Tk, int Tkp, int hd, int hdp, int C, float scale_log2) {
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 800
    using namespace nvcuda;
    extern __shared__ __align__(128) unsigned char smem[];
    const int ld = hdp + 8, old = hdp + 4, chunks = hdp / 8;   // 16-byte chunks per row
    T* sQ = (T*)smem;
    T* sK = sQ + BQ * ld;
    T* sV = sK + BK * ld;
    float* sS = (float*)(sV + BK * ld);
    T* sP = (T*)(sS + WARPS * 16 * SLD);
    float* sO = (float*)(sP + WARPS * 16 * PLD);
    const int warp = threadIdx.x >> 5, lane = threadIdx.x & 31;
    const int bh = blockIdx.y, q0 = blockIdx.x * BQ;
    float* sSw = sS + warp * 16 * SLD;
    T* sPw = sP + warp * 16 * PLD;
    float* sOw = sO + warp * 16 * old;

    const T* qb = qh + ((size_t)bh * Tqp + q0) * hdp;
    for (int i = threadIdx.x; i < BQ * chunks; i += THREADS) {
        const int r = i / chunks, c = i % chunks;
        *(uint4*)(sQ + r * ld + c * 8) = *(const uint4*)(qb + (size_t)r * hdp + c * 8);
    }
    for (int i = lane; i < 16 * old; i += 32) sOw[i] = 0.0f;
    const int row = lane >> 1, half = lane & 1;   // this lane's row of the warp's 16, and its columns' parity
    float m = -INFINITY, l = 0.0f;

    const int tiles = (Tk + BK - 1) / BK;
    for (int kt = 0; kt < tiles; kt++) {
        __syncthreads();   // every warp is done with the last tile's K and V (and Q is in place)
        const T* kb = kh + ((size_t)bh * Tkp + (size_t)kt * BK) * hdp;
        const T* vb = vh + ((size_t)bh * Tkp + (size_t)kt * BK) * hdp;
        for (int i = threadIdx.x; i < BK * chunks; i += THREADS) {
            const int r = i / chunks, c = i % chunks;
            *(uint4*)(sK + r * ld + c * 8) = *(const uint4*)(kb + (size_t)r * hdp + c * 8);
            *(uint4*)(sV + r * ld + c * 8) = *(const uint4*)(vb + (size_t)r * hdp + c * 8);
        }
        __syncthreads();
        // S_w = Q_w K^T: K's rows read as a column-major [hdp, 64] operand
        for (int n = 0; n < BK / 16; n++) {
            wmma::fragment<wmma::accumulator, 16, 16, 16, float> acc;
            wmma::fill_fragment(acc, 0.0f);
            for (int kk = 0; kk < hdp / 16; kk++) {
                wmma::fragment<wmma::matrix_a, 16, 16, 16, T, wmma::row_major> a;
                wmma::fragment<wmma::matrix_b, 16, 16, 16, T, wmma::col_major> b;
                wmma::load_matrix_sync(a, sQ + warp * 16 * ld + kk * 16, ld);
                wmma::load_matrix_sync(b, sK + n * 16 * ld + kk * 16, ld);
                wmma::mma_sync(acc, a, b, acc);
            }
            wmma::store_matrix_sync(sSw + n * 16, acc, SLD, wmma::mem_row_major);
        }
        __syncwarp();
        // online softmax over this tile: columns 2j + half, keys past Tk masked
        const float* srow = sSw + row * SLD;
        const int valid = Tk - kt * BK;
        float mx = -INFINITY;
        for (int j = 0; j < BK / 2; j++) {
            const int c = 2 * j + half;
            if (c < valid) mx = fmaxf(mx, srow[c]);
        }
        mx = fmaxf(mx, __shfl_xor_sync(0xffffffffu, mx, 1));
        const float m_new = fmaxf(m, mx * scale_log2);
        const float alpha = exp2f(m - m_new);   // 0 on the first tile (m = -inf)
        float sum = 0.0f;
        T* prow = sPw + row * PLD;
        for (int j = 0; j < BK / 2; j++) {
            const int c = 2 * j + half;
            const float p = c < valid ? exp2f(srow[c] * scale_log2 - m_new) : 0.0f;
            prow[c] = to_operand<T>(p);
            sum += p;
        }
        sum += __shfl_xor_sync(0xffffffffu, sum, 1);
        l = l * alpha + sum;
        m = m_new;
        float* orow = sOw + row * old;
        for (int d = half; d < hdp; d += 2) orow[d] *= alpha;
        __syncwarp();
        // O_w += P_w V
        for (int dn = 0; dn < hdp / 16; dn++) {
            wmma::fragment<wmma::accumulator, 16, 16, 16, float> acc;
            wmma::load_matrix_sync(acc, sOw + dn * 16, old, wmma::mem_row_major);
            for (int kk = 0; kk < BK / 16; kk++) {
                wmma::fragment<wmma::matrix_a, 16, 16, 16, T, wmma::row_major> a;
                wmma::fragment<wmma::matrix_b, 16, 16, 16, T, wmma::row_major> b;
                wmma::load_matrix_sync(a, sPw + kk * 16, PLD);
                wmma::load_matrix_sync(b, sV + kk * 16 * ld + dn * 16, ld);
                wmma::mma_sync(acc, a, b, acc);
            }
            wmma::store_matrix_sync(sOw + dn * 16, acc, old, wmma::mem_row_major);
        }
        __syncwarp();
    }
    const int t = q0 + warp * 16 + row;
    if (t < Tq) {
        const int b = bh / NH, h = bh % NH;
        const float inv = 1.0f / l;
        float* o = out + ((size_t)b * Tq + t) * C + (size_t)h * hd;
        const float* orow = sOw + row * old;
        for (int d = half; d < hd; d += 2) o[d] = orow[d] * inv;
        if (lse && !half) lse[(size_t)bh * Tq + t] = (m + log2f(l)) * 0.6931471805599453f;
    }
#endif
}

static int g_flash_on = -1;   // -1: from $MLB_FLASH on first use (0 turns it off)
extern "C" void mlb_cuda_use_flash(int on) { g_flash_on = on ? 1 : 0; }

int mlb_cuda_flash_usable(int B, int Tq, int hd, int NH, mlb_gemm_precision prec) {
    if (g_flash_on < 0) {
        const char* e = getenv("MLB_FLASH");
        g_flash_on = !(e && e[0] == '0');
    }
    if (!g_flash_on || !is_half(prec) || hd < 1 || hd > MAX_HD || (long long)B * NH > 65535 || Tq > (1 << 30))
        return 0;   // grid.y holds (image, head)
    int dev, major = 0, optin = 0;
    if (cudaGetDevice(&dev) != cudaSuccess || cudaDeviceGetAttribute(&major, cudaDevAttrComputeCapabilityMajor, dev) ||
        cudaDeviceGetAttribute(&optin, cudaDevAttrMaxSharedMemoryPerBlockOptin, dev)) {
        (void)cudaGetLastError();
        return 0;
    }
    return major >= 8 && layout_of((hd + 15) / 16 * 16).bytes <= (size_t)optin;   // bf16 wmma: sm_80 on
}

template <typename T>
static mlb_status flash_run(float* out, float* lse, const float* q, const float* k, const float* v, int B, int Tq,
                            int Tk, int C, int NH, int ldq, int ldkv) {
    const int hd = C / NH, hdp = (hd + 15) / 16 * 16, Tqp = (Tq + BQ - 1) / BQ * BQ, Tkp = (Tk + BK - 1) / BK * BK;
    const size_t nq = (size_t)B * NH * Tqp * hdp, nkv = (size_t)B * NH * Tkp * hdp;
    const size_t q_bytes = round_up(nq * sizeof(T)), kv_bytes = round_up(nkv * sizeof(T));
    void* base;
    MLB_TRY(mlb_cuda_scratch(&base, q_bytes + 2 * kv_bytes));
    T* qh = (T*)base;
    T* kh = (T*)((char*)base + q_bytes);
    T* vh = (T*)((char*)base + q_bytes + kv_bytes);
    split_heads_padded_kernel<T><<<mlb_grid(nq, 256), 256>>>(qh, q, B, Tq, Tqp, NH, hd, hdp, ldq);
    MLB_CUDA_LAUNCHED("split_heads_padded_kernel");
    split_heads_padded_kernel<T><<<mlb_grid(nkv, 256), 256>>>(kh, k, B, Tk, Tkp, NH, hd, hdp, ldkv);
    MLB_CUDA_LAUNCHED("split_heads_padded_kernel");
    split_heads_padded_kernel<T><<<mlb_grid(nkv, 256), 256>>>(vh, v, B, Tk, Tkp, NH, hd, hdp, ldkv);
    MLB_CUDA_LAUNCHED("split_heads_padded_kernel");
    const flash_layout L = layout_of(hdp);
    if (L.bytes > 48 * 1024)   // past the default limit: opt in (per device, so on every call; it costs ~1 us)
        MLB_CUDA_CHECK(cudaFuncSetAttribute(flash_forward_kernel<T>, cudaFuncAttributeMaxDynamicSharedMemorySize,
                                            (int)L.bytes));
    const float scale_log2 = 1.4426950408889634f / sqrtf((float)hd);
    dim3 grid(Tqp / BQ, B * NH);
    flash_forward_kernel<T><<<grid, THREADS, L.bytes>>>(out, lse, qh, kh, vh, NH, Tq, Tqp, Tk, Tkp, hd, hdp, C,
                                                        scale_log2);
    MLB_CUDA_LAUNCHED("flash_forward_kernel");
    return MLB_OK;
}

mlb_status mlb_cuda_flash_sdpa(float* out, float* lse, const float* q, const float* k, const float* v, int B, int Tq,
                               int Tk, int C, int NH, int ldq, int ldkv, mlb_gemm_precision prec) {
    if (prec == MLB_GEMM_FP16) return flash_run<__half>(out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv);
    return flash_run<__nv_bfloat16>(out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv);
}
