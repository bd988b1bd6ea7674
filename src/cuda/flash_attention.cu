// Scaled dot-product attention fused on the tensor cores (fp16/bf16 operands, fp32 accumulation):
// the [Tq, Tk] scores never reach memory, nor shared memory. sdpa_forward's contract (conv_ops.h),
// taken by mlb_cuda_sdpa_forward at fp16/bf16 for head widths up to 128 (docs/cuda.md).
//
// q and k are first split into heads in the operand type, [B*NH, Tp, hdp], and v transposed per head,
// [B*NH, hdp, Tp], all padded with zeros to whole tiles (Tp a multiple of 64 for keys and 128 for
// queries, hdp of 16), so the loads need no bounds, padded keys give finite scores that the softmax
// masks, and every operand fragment below is one 32-bit load. A block takes 64 (four warps) or 128
// (eight warps: K and V read half as often; mlb_cuda_flash_rows) query rows of one (image, head),
// 16 rows per warp, and walks the keys in tiles of 64 (K and V^T in shared memory). Per warp, with the
// m16n8k16 MMA (PTX ISA, "Matrix fragments for mma.m16n8k16"; lane = 4 g + t holds rows g and g + 8):
//   S [16, 64] = Q K^T        in registers (8 accumulator tiles); Q's fragments loaded once
//   online softmax            the row max over the quad of lanes sharing a row (two shuffles), base 2:
//                             m' = max(m, s c), P = 2^(s c - m'), l = l 2^(m - m') + sum P
//   O [16, hdp] = O 2^(m - m') + P V    P's accumulators repacked as the A operand in registers
// then O / l goes to out [B, Tq, C] (the heads merged on the way) and lse = (m + log2 l) ln 2.
#include <cuda_bf16.h>
#include <cuda_fp16.h>
#include <math.h>
#include "common.cuh"
#include "gemm_ops.cuh"

namespace {
constexpr int BK = 64;                           // keys per tile
constexpr int QPAD = 128;                        // query rows are padded to a multiple of the larger block
constexpr int MAX_HD = 128;                      // wider heads: the O accumulators would spill
constexpr int LDV = BK + 8;                      // a row of V^T in shared memory (16-bit values)
}   // namespace

// out [BH, Tp, hdp] of T from in [B, T, ld] (head h at column h*hd), zeros outside T x hd;
// transposed: out [BH, hdp, Tp] (v, so that P V's B fragments are pairs of adjacent keys)
template <typename T>
__global__ void split_heads_padded_kernel(T* out, const float* in, int B, int T_, int Tp, int NH, int hd, int hdp,
                                          int ld, int transposed) {
    const size_t n = (size_t)B * NH * Tp * hdp;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        int d, t;
        size_t bh;
        if (transposed) {
            t = (int)(i % Tp);
            d = (int)(i / Tp % hdp);
            bh = i / ((size_t)Tp * hdp);
        } else {
            d = (int)(i % hdp);
            t = (int)(i / hdp % Tp);
            bh = i / ((size_t)Tp * hdp);
        }
        const int h = (int)(bh % NH), b = (int)(bh / NH);
        float v = 0.0f;
        if (t < T_ && d < hd) v = in[((size_t)b * T_ + t) * ld + (size_t)h * hd + d];
        out[i] = to_operand<T>(v);
    }
}

__device__ __forceinline__ uint32_t ld32(const void* p) { return *(const uint32_t*)p; }
template <typename T> __device__ __forceinline__ uint32_t pack2(float lo, float hi);
template <> __device__ __forceinline__ uint32_t pack2<__half>(float lo, float hi) {
    __half2 h = __floats2half2_rn(lo, hi);
    return *(uint32_t*)&h;
}
template <> __device__ __forceinline__ uint32_t pack2<__nv_bfloat16>(float lo, float hi) {
    __nv_bfloat162 h = __floats2bfloat162_rn(lo, hi);
    return *(uint32_t*)&h;
}
// d[4] += A[16x16] B[16x8], fp32 accumulation; TYPE: the PTX name of T (f16, bf16)
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 800
#define MMA16816(TYPE)                                                                                           \
    asm volatile("mma.sync.aligned.m16n8k16.row.col.f32." TYPE "." TYPE ".f32 {%0,%1,%2,%3}, {%4,%5,%6,%7}, "   \
                 "{%8,%9}, {%0,%1,%2,%3};\n"                                                                     \
                 : "+f"(d[0]), "+f"(d[1]), "+f"(d[2]), "+f"(d[3])                                               \
                 : "r"(a[0]), "r"(a[1]), "r"(a[2]), "r"(a[3]), "r"(b0), "r"(b1))
#else
#define MMA16816(TYPE)
#endif
template <typename T> __device__ __forceinline__ void mma16816(float* d, const uint32_t* a, uint32_t b0, uint32_t b1);
template <> __device__ __forceinline__ void mma16816<__half>(float* d, const uint32_t* a, uint32_t b0, uint32_t b1) {
    MMA16816("f16");
}
template <> __device__ __forceinline__ void mma16816<__nv_bfloat16>(float* d, const uint32_t* a, uint32_t b0,
                                                                     uint32_t b1) {
    MMA16816("bf16");
}
#undef MMA16816

template <typename T, int HDP, int WARPS>
__global__ void __launch_bounds__(32 * WARPS)
    flash_forward_kernel(float* out, float* lse, const T* qh, const T* kh, const T* vt, int NH, int Tq, int Tqp,
                         int Tk, int Tkp, int hd, int C, float scale_log2) {
    constexpr int LDK = HDP + 8;   // a row of K in shared memory
    constexpr int CH = HDP / 8;    // 16-byte chunks per row of K
    constexpr int THREADS = 32 * WARPS, BQ = 16 * WARPS;
    __shared__ __align__(16) T sK[BK * LDK];
    __shared__ __align__(16) T sV[HDP * LDV];
    const int warp = threadIdx.x >> 5, lane = threadIdx.x & 31, g = lane >> 2, t = lane & 3;
    const int bh = blockIdx.y, q0 = blockIdx.x * BQ;

    // this warp's Q fragments, straight from global memory (read once)
    const T* qw = qh + ((size_t)bh * Tqp + q0 + warp * 16) * HDP;
    uint32_t qf[HDP / 16][4];
#pragma unroll
    for (int ks = 0; ks < HDP / 16; ks++) {
        qf[ks][0] = ld32(qw + g * HDP + ks * 16 + 2 * t);
        qf[ks][1] = ld32(qw + (g + 8) * HDP + ks * 16 + 2 * t);
        qf[ks][2] = ld32(qw + g * HDP + ks * 16 + 8 + 2 * t);
        qf[ks][3] = ld32(qw + (g + 8) * HDP + ks * 16 + 8 + 2 * t);
    }
    float o[HDP / 8][4];
#pragma unroll
    for (int dn = 0; dn < HDP / 8; dn++) o[dn][0] = o[dn][1] = o[dn][2] = o[dn][3] = 0.0f;
    float m0 = -INFINITY, m1 = -INFINITY, l0 = 0.0f, l1 = 0.0f;   // rows g and g + 8 (l: this lane's columns)

    const int tiles = (Tk + BK - 1) / BK;
    for (int kt = 0; kt < tiles; kt++) {
        __syncthreads();   // every warp is done with the last tile's sK and sV
        const T* kb = kh + ((size_t)bh * Tkp + (size_t)kt * BK) * HDP;
        for (int i = threadIdx.x; i < BK * CH; i += THREADS) {
            const int r = i / CH, c = i % CH;
            *(uint4*)(sK + r * LDK + c * 8) = *(const uint4*)(kb + (size_t)r * HDP + c * 8);
        }
        const T* vb = vt + (size_t)bh * HDP * Tkp + (size_t)kt * BK;
        for (int i = threadIdx.x; i < HDP * (BK / 8); i += THREADS) {
            const int r = i / (BK / 8), c = i % (BK / 8);
            *(uint4*)(sV + r * LDV + c * 8) = *(const uint4*)(vb + (size_t)r * Tkp + c * 8);
        }
        __syncthreads();
        // S = Q K^T: 8 tiles of 8 keys; K's row (key 8j + g) holds the B fragment's adjacent pair
        float s[BK / 8][4];
#pragma unroll
        for (int j = 0; j < BK / 8; j++) {
            s[j][0] = s[j][1] = s[j][2] = s[j][3] = 0.0f;
            const T* kr = sK + (8 * j + g) * LDK + 2 * t;
#pragma unroll
            for (int ks = 0; ks < HDP / 16; ks++) mma16816<T>(s[j], qf[ks], ld32(kr + ks * 16), ld32(kr + ks * 16 + 8));
        }
        // scale to base 2, mask the keys past Tk, row max over the quad
        const int kbase = kt * BK;
        float mx0 = -INFINITY, mx1 = -INFINITY;
#pragma unroll
        for (int j = 0; j < BK / 8; j++)
#pragma unroll
            for (int e = 0; e < 2; e++) {
                const int ok = kbase + 8 * j + 2 * t + e < Tk;
                s[j][e] = ok ? s[j][e] * scale_log2 : -INFINITY;
                s[j][2 + e] = ok ? s[j][2 + e] * scale_log2 : -INFINITY;
                mx0 = fmaxf(mx0, s[j][e]);
                mx1 = fmaxf(mx1, s[j][2 + e]);
            }
        mx0 = fmaxf(mx0, __shfl_xor_sync(0xffffffffu, mx0, 1));
        mx0 = fmaxf(mx0, __shfl_xor_sync(0xffffffffu, mx0, 2));
        mx1 = fmaxf(mx1, __shfl_xor_sync(0xffffffffu, mx1, 1));
        mx1 = fmaxf(mx1, __shfl_xor_sync(0xffffffffu, mx1, 2));
        const float mn0 = fmaxf(m0, mx0), mn1 = fmaxf(m1, mx1);   // finite: key kbase is always valid
        const float a0 = exp2f(m0 - mn0), a1 = exp2f(m1 - mn1);     // 0 on the first tile
        m0 = mn0;
        m1 = mn1;
        l0 *= a0;
        l1 *= a1;
#pragma unroll
        for (int dn = 0; dn < HDP / 8; dn++) {
            o[dn][0] *= a0; o[dn][1] *= a0;
            o[dn][2] *= a1; o[dn][3] *= a1;
        }
        // P, repacked: S tiles 2kk and 2kk + 1 are the A fragment of key step kk
        uint32_t pf[BK / 16][4];
#pragma unroll
        for (int j = 0; j < BK / 8; j++) {
            const float p00 = exp2f(s[j][0] - mn0), p01 = exp2f(s[j][1] - mn0);
            const float p10 = exp2f(s[j][2] - mn1), p11 = exp2f(s[j][3] - mn1);
            l0 += p00 + p01;
            l1 += p10 + p11;
            pf[j / 2][(j % 2) * 2 + 0] = pack2<T>(p00, p01);
            pf[j / 2][(j % 2) * 2 + 1] = pack2<T>(p10, p11);
        }
        // O += P V: V^T's row (dimension 8 dn + g) holds the B fragment's adjacent keys
#pragma unroll
        for (int dn = 0; dn < HDP / 8; dn++) {
            const T* vr = sV + (8 * dn + g) * LDV + 2 * t;
#pragma unroll
            for (int kk = 0; kk < BK / 16; kk++) mma16816<T>(o[dn], pf[kk], ld32(vr + kk * 16), ld32(vr + kk * 16 + 8));
        }
    }
    l0 += __shfl_xor_sync(0xffffffffu, l0, 1);
    l0 += __shfl_xor_sync(0xffffffffu, l0, 2);
    l1 += __shfl_xor_sync(0xffffffffu, l1, 1);
    l1 += __shfl_xor_sync(0xffffffffu, l1, 2);
    const int b = bh / NH, h = bh % NH, r0 = q0 + warp * 16 + g, r1 = r0 + 8;
    const float inv0 = 1.0f / l0, inv1 = 1.0f / l1;
#pragma unroll
    for (int dn = 0; dn < HDP / 8; dn++) {
        const int d = 8 * dn + 2 * t;
        if (r0 < Tq) {
            float* o0 = out + ((size_t)b * Tq + r0) * C + (size_t)h * hd;
            if (d < hd) o0[d] = o[dn][0] * inv0;
            if (d + 1 < hd) o0[d + 1] = o[dn][1] * inv0;
        }
        if (r1 < Tq) {
            float* o1 = out + ((size_t)b * Tq + r1) * C + (size_t)h * hd;
            if (d < hd) o1[d] = o[dn][2] * inv1;
            if (d + 1 < hd) o1[d + 1] = o[dn][3] * inv1;
        }
    }
    if (lse && t == 0) {
        if (r0 < Tq) lse[(size_t)bh * Tq + r0] = (m0 + log2f(l0)) * 0.6931471805599453f;
        if (r1 < Tq) lse[(size_t)bh * Tq + r1] = (m1 + log2f(l1)) * 0.6931471805599453f;
    }
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
    int dev, major = 0;
    if (cudaGetDevice(&dev) != cudaSuccess || cudaDeviceGetAttribute(&major, cudaDevAttrComputeCapabilityMajor, dev)) {
        (void)cudaGetLastError();
        return 0;
    }
    return major >= 8;   // mma.m16n8k16 with bf16: sm_80 on
}

static int g_flash_rows = 0;   // query rows per block: 64 or 128; 0: from $MLB_FLASH_ROWS, else 64
extern "C" void mlb_cuda_flash_rows(int rows) { g_flash_rows = rows == 128 ? 128 : 64; }

template <typename T, int HDP>
static mlb_status flash_launch(float* out, float* lse, const T* qh, const T* kh, const T* vt, int B, int NH, int Tq,
                               int Tqp, int Tk, int Tkp, int hd, int C) {
    if (!g_flash_rows) {
        const char* e = getenv("MLB_FLASH_ROWS");
        g_flash_rows = e && atoi(e) == 128 ? 128 : 64;
    }
    const float scale_log2 = 1.4426950408889634f / sqrtf((float)hd);
    if (g_flash_rows == 128) {
        flash_forward_kernel<T, HDP, 8><<<dim3(Tqp / 128, B * NH), 256>>>(out, lse, qh, kh, vt, NH, Tq, Tqp, Tk, Tkp,
                                                                           hd, C, scale_log2);
    } else {
        flash_forward_kernel<T, HDP, 4><<<dim3(Tqp / 64, B * NH), 128>>>(out, lse, qh, kh, vt, NH, Tq, Tqp, Tk, Tkp, hd,
                                                                          C, scale_log2);
    }
    MLB_CUDA_LAUNCHED("flash_forward_kernel");
    return MLB_OK;
}

template <typename T>
static mlb_status flash_run(float* out, float* lse, const float* q, const float* k, const float* v, int B, int Tq,
                            int Tk, int C, int NH, int ldq, int ldkv) {
    const int hd = C / NH, hdp = (hd + 15) / 16 * 16, Tqp = (Tq + QPAD - 1) / QPAD * QPAD, Tkp = (Tk + BK - 1) / BK * BK;
    const size_t nq = (size_t)B * NH * Tqp * hdp, nkv = (size_t)B * NH * Tkp * hdp;
    const size_t q_bytes = round_up(nq * sizeof(T)), kv_bytes = round_up(nkv * sizeof(T));
    void* base;
    MLB_TRY(mlb_cuda_scratch(&base, q_bytes + 2 * kv_bytes));
    T* qh = (T*)base;
    T* kh = (T*)((char*)base + q_bytes);
    T* vt = (T*)((char*)base + q_bytes + kv_bytes);
    split_heads_padded_kernel<T><<<mlb_grid(nq, 256), 256>>>(qh, q, B, Tq, Tqp, NH, hd, hdp, ldq, 0);
    MLB_CUDA_LAUNCHED("split_heads_padded_kernel");
    split_heads_padded_kernel<T><<<mlb_grid(nkv, 256), 256>>>(kh, k, B, Tk, Tkp, NH, hd, hdp, ldkv, 0);
    MLB_CUDA_LAUNCHED("split_heads_padded_kernel");
    split_heads_padded_kernel<T><<<mlb_grid(nkv, 256), 256>>>(vt, v, B, Tk, Tkp, NH, hd, hdp, ldkv, 1);
    MLB_CUDA_LAUNCHED("split_heads_padded_kernel");
    switch (hdp) {
#define HDP_CASE(n) case n: return flash_launch<T, n>(out, lse, qh, kh, vt, B, NH, Tq, Tqp, Tk, Tkp, hd, C);
        HDP_CASE(16) HDP_CASE(32) HDP_CASE(48) HDP_CASE(64) HDP_CASE(80) HDP_CASE(96) HDP_CASE(112) HDP_CASE(128)
#undef HDP_CASE
    }
    return mlb_fail(MLB_ERR_ARG, "flash attention: head width %d (at most %d)", hd, MAX_HD);
}

mlb_status mlb_cuda_flash_sdpa(float* out, float* lse, const float* q, const float* k, const float* v, int B, int Tq,
                               int Tk, int C, int NH, int ldq, int ldkv, mlb_gemm_precision prec) {
    if (prec == MLB_GEMM_FP16) return flash_run<__half>(out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv);
    return flash_run<__nv_bfloat16>(out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv);
}
