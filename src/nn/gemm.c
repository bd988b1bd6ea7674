// The one GEMM of the CPU code: C = alpha·op(A)·op(B) + beta·C (row-major), whose result does not
// depend on the thread count, on any CPU and any BLAS build, by construction.
//
// Why: OpenBLAS splits a GEMM over its threads, and on some kernel families (Haswell, Zen) the
// pieces round differently from the whole, so 1 and 2 threads gave different bits. Here
// the output is cut into shards whose boundaries depend on (M, N, K) only; each shard is one BLAS
// call on one thread (OpenBLAS is kept single-threaded), and OpenMP threads take whole shards. The
// threads change who computes a shard, never what it computes. A shard cut along K (the outputs are
// too few to share) writes its partial product to scratch, and the partials are added in shard
// order. Dual-compiled (float / double _f64) like ops.c; the float pass also has mlb_gemm_bf16, the
// same shards over the bf16 kernel of gemm_bf16.c.
#include <stdint.h>
#include <stdlib.h>
#include <omp.h>
#include <pthread.h>
#include "matlaber/nn.h"
#include "core/real.h"
#include "nn/gemm_bf16.h"

#ifdef MLB_F64
#define BLAS_GEMM cblas_dgemm
#else
#define BLAS_GEMM cblas_sgemm
#endif

// A shard is worth a thread hand-off above this many multiply-adds (~0.1 ms on one core).
#define GEMM_SHARD_MIN_WORK ((int64_t)1 << 22)
// At most this many shards (a power of two: an even split over 1, 2, 4, 8, 16 threads).
#define GEMM_MAX_SHARDS 32
// Shards cut along M or N are at least this wide (and a multiple of GEMM_ALIGN) so that each one's
// repacking of the other operand stays a few percent of its work.
#define GEMM_MIN_BLOCK 256
#define GEMM_ALIGN 16
// The K cut is used only while the partial products stay this small (values of M·N per shard).
#define GEMM_MAX_PARTIAL ((int64_t)1 << 16)

typedef enum { CUT_NONE, CUT_M, CUT_N, CUT_K } gemm_cut;

// Shards for a shape: how to cut, the block length and the shard count. Shape only.
static gemm_cut FN(gemm_plan)(int M, int N, int K, int* block, int* count) {
    int64_t work = (int64_t)M * N * K;
    int64_t want = work / GEMM_SHARD_MIN_WORK;
    int shards = 1;
    while (shards * 2 <= GEMM_MAX_SHARDS && shards * 2 <= want) shards *= 2;
    *block = 0;
    *count = 1;
    if (shards < 2) return CUT_NONE;
    // Cut the longer of M and N (the shard repacks the other operand once: the longer its own
    // side, the smaller that share); K only when both are too short to share.
    int along = M >= N ? M : N;
    gemm_cut cut = M >= N ? CUT_M : CUT_N;
    if (along < 2 * GEMM_MIN_BLOCK) {
        if ((int64_t)M * N > GEMM_MAX_PARTIAL || K < 2 * GEMM_MIN_BLOCK) return CUT_NONE;
        along = K;
        cut = CUT_K;
    }
    while (shards > 1 && along / shards < GEMM_MIN_BLOCK) shards /= 2;
    if (shards < 2) return CUT_NONE;
    int b = (along + shards - 1) / shards;
    b = (b + GEMM_ALIGN - 1) / GEMM_ALIGN * GEMM_ALIGN;
    *block = b;
    *count = (along + b - 1) / b;
    return *count > 1 ? cut : CUT_NONE;
}

int FN(mlb_gemm_shards)(int M, int N, int K, char* along) {
    int block, count;
    gemm_cut cut = M > 0 && N > 0 && K > 0 ? FN(gemm_plan)(M, N, K, &block, &count) : CUT_NONE;
    if (along) *along = "-MNK"[cut];
    return cut == CUT_NONE ? 1 : count;
}

static pthread_once_t blas_single_thread_once = PTHREAD_ONCE_INIT;
static void blas_single_thread(void) { openblas_set_num_threads(1); }

// One shard: op(A)·op(B) of the sub-blocks starting a_off and b_off elements into A and B.
typedef void (*FN(shard_fn))(int ta, int tb, int M, int N, int K, real alpha, const real* A, size_t a_off, int lda,
                             const real* B, size_t b_off, int ldb, real beta, real* C, int ldc);

static void FN(blas_call)(int ta, int tb, int M, int N, int K, real alpha, const real* A, size_t a_off, int lda,
                          const real* B, size_t b_off, int ldb, real beta, real* C, int ldc) {
    BLAS_GEMM(CblasRowMajor, ta ? CblasTrans : CblasNoTrans, tb ? CblasTrans : CblasNoTrans, M, N, K, alpha,
              A + a_off, lda, B + b_off, ldb, beta, C, ldc);
}

// call: one shard's product on the calling thread (BLAS, or in the float pass the bf16 kernel).
static void FN(gemm_sharded)(FN(shard_fn) call, int ta, int tb, int M, int N, int K, real alpha, const real* A,
                             int lda, const real* B, int ldb, real beta, real* C, int ldc) {
    if (M <= 0 || N <= 0) return;
    // OpenBLAS's own threads would split a shard again (per thread count): keep it at one. The
    // first call anywhere does it once, before any thread's first BLAS call (a caller whose every
    // GEMM runs inside its own parallel region, like the BRDF training's shards, would otherwise
    // leave OpenBLAS at its default of one thread per core, busy-waiting against the OpenMP
    // threads: 2 cores trained no faster than 1). Later changes are undone outside parallel
    // regions, where no other thread is inside OpenBLAS.
    pthread_once(&blas_single_thread_once, blas_single_thread);
    if (!omp_in_parallel() && openblas_get_num_threads() != 1) openblas_set_num_threads(1);
    if (K <= 0 || alpha == 0) {   // no product: C = beta·C (BLAS rejects lda = 0 for K = 0)
        for (int i = 0; i < M; i++)
            for (int j = 0; j < N; j++) C[(size_t)i * ldc + j] = beta == 0 ? (real)0 : beta * C[(size_t)i * ldc + j];
        return;
    }
    int block, count;
    gemm_cut cut = FN(gemm_plan)(M, N, K, &block, &count);
    real* partial = NULL;
    if (cut == CUT_K) {
        partial = malloc(sizeof(real) * (size_t)count * M * N);
        if (!partial) cut = CUT_NONE;   // a few hundred KB at most; never seen, and still thread-independent
    }
    if (cut == CUT_NONE) {
        call(ta, tb, M, N, K, alpha, A, 0, lda, B, 0, ldb, beta, C, ldc);
        return;
    }
#pragma omp parallel for schedule(static)
    for (int s = 0; s < count; s++) {
        size_t lo = (size_t)s * block;
        if (cut == CUT_M) {
            int m = M - (int)lo < block ? M - (int)lo : block;
            call(ta, tb, m, N, K, alpha, A, ta ? lo : lo * lda, lda, B, 0, ldb, beta, C + lo * ldc, ldc);
        } else if (cut == CUT_N) {
            int n = N - (int)lo < block ? N - (int)lo : block;
            call(ta, tb, M, n, K, alpha, A, 0, lda, B, tb ? lo * ldb : lo, ldb, beta, C + lo, ldc);
        } else {
            int k = K - (int)lo < block ? K - (int)lo : block;
            call(ta, tb, M, N, k, (real)1, A, ta ? lo * lda : lo, lda, B, tb ? lo : lo * ldb, ldb, (real)0,
                 partial + (size_t)s * M * N, N);
        }
    }
    if (cut != CUT_K) return;
    // C = beta·C + alpha·(P_0 + P_1 + ...), each element summed in shard order.
    int64_t mn = (int64_t)M * N;
#pragma omp parallel for schedule(static) if (mn * count >= 65536)
    for (int i = 0; i < M; i++)
        for (int j = 0; j < N; j++) {
            size_t e = (size_t)i * N + j;
            real sum = partial[e];
            for (int s = 1; s < count; s++) sum += partial[(size_t)s * mn + e];
            real* c = C + (size_t)i * ldc + j;
            *c = beta == 0 ? alpha * sum : beta * *c + alpha * sum;
        }
    free(partial);
}

void FN(mlb_gemm)(int ta, int tb, int M, int N, int K, real alpha, const real* A, int lda, const real* B, int ldb,
                  real beta, real* C, int ldc) {
    FN(gemm_sharded)(FN(blas_call), ta, tb, M, N, K, alpha, A, lda, B, ldb, beta, C, ldc);
}

#ifndef MLB_F64
// The bf16 kernel's shard: both operands fp32, rounded to bf16 as they are packed.
static void bf16_shard(int ta, int tb, int M, int N, int K, float alpha, const float* A, size_t a_off, int lda,
                       const float* B, size_t b_off, int ldb, float beta, float* C, int ldc) {
    mlb_bf16_operand a = {A, a_off, lda, NULL, NULL, NULL}, b = {B, b_off, ldb, NULL, NULL, NULL};
    mlb_gemm_bf16_kernel(ta, tb, M, N, K, alpha, &a, &b, beta, C, ldc);
}

void mlb_gemm_bf16(int ta, int tb, int M, int N, int K, float alpha, const float* A, int lda, const float* B,
                   int ldb, float beta, float* C, int ldc) {
    if (!mlb_gemm_bf16_native()) {   // no AVX-512 BF16 here (or forced off): the fp32 GEMM (the callers say so)
        mlb_gemm(ta, tb, M, N, K, alpha, A, lda, B, ldb, beta, C, ldc);
        return;
    }
    gemm_sharded(bf16_shard, ta, tb, M, N, K, alpha, A, lda, B, ldb, beta, C, ldc);
}

#endif
