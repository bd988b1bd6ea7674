// Tests of mlb_gemm (src/nn/gemm.c): every way it cuts a product (none, rows, columns, the inner
// dimension), each with all four transpose combinations, padded leading dimensions, alpha and beta
// (beta = 0 ignores NaN in C, as BLAS does), against a naive product in long double; and bitwise
// equality over 1, 2 and 3 threads. tests/blas_kernels.sh runs this file again under each OpenBLAS
// kernel family the CPU can execute, so the property is checked on more than the kernels this
// machine would pick.
#include "test.h"
#include "matlaber/nn.h"
#include "matlaber/rng.h"
#include <cblas.h>
#include <float.h>
#include <omp.h>
#include <stdint.h>

#define SEED 20261125u

typedef struct { int M, N, K; char along; const char* what; } shape;
// Work above 2^23 multiply-adds gets at least two shards (GEMM_SHARD_MIN_WORK in gemm.c); `along`
// is checked against mlb_gemm_shards, so a change of the plan cannot leave a cut untested.
static const shape shapes[] = {
    {7, 5, 3, '-', "tiny (one call)"},
    {1000, 96, 300, 'M', "cut along M"},
    {60, 1500, 300, 'N', "cut along N"},
    {32, 48, 24000, 'K', "cut along K"},
    {517, 259, 333, 'M', "odd sizes, cut along M"},
    {33, 31, 9000, 'K', "odd sizes, cut along K"},
};
#define N_SHAPES (sizeof shapes / sizeof shapes[0])

// Stored sizes of op(X)[R, C]: X is [R, C] (ld >= C) or, transposed, [C, R] (ld >= R).
static size_t stored(int trans, int R, int C, int ld) { return (size_t)(trans ? C : R) * ld; }
static double at(const double* X, int trans, int ld, int r, int c) {
    return trans ? X[(size_t)c * ld + r] : X[(size_t)r * ld + c];
}

// One case in double and float: returns through *worst the largest error / bound seen.
static void run_case(const shape* s, int ta, int tb, double alpha, double beta, double* worst) {
    const int M = s->M, N = s->N, K = s->K;
    const int lda = (ta ? M : K) + 3, ldb = (tb ? K : N) + 5, ldc = N + 2;
    size_t na = stored(ta, M, K, lda), nb = stored(tb, K, N, ldb), nc = (size_t)M * ldc;
    double* A = malloc(sizeof(double) * na);
    double* B = malloc(sizeof(double) * nb);
    double* C0 = malloc(sizeof(double) * nc);
    double* Cd = malloc(sizeof(double) * nc);
    float* Af = malloc(sizeof(float) * na);
    float* Bf = malloc(sizeof(float) * nb);
    float* Cf = malloc(sizeof(float) * nc);
    float* Cf2 = malloc(sizeof(float) * nc);
    REQUIRE(A && B && C0 && Cd && Af && Bf && Cf && Cf2);
    for (size_t i = 0; i < na; i++) Af[i] = (float)(A[i] = mlb_rng_normal_f64(SEED, 1, i));
    for (size_t i = 0; i < nb; i++) Bf[i] = (float)(B[i] = mlb_rng_normal_f64(SEED, 2, i));
    for (size_t i = 0; i < nc; i++) C0[i] = beta == 0 ? NAN : mlb_rng_normal_f64(SEED, 3, i);
    // The float inputs are the double ones rounded; the reference uses the rounded values.
    double* Ar = malloc(sizeof(double) * na);
    double* Br = malloc(sizeof(double) * nb);
    REQUIRE(Ar && Br);
    for (size_t i = 0; i < na; i++) Ar[i] = Af[i];
    for (size_t i = 0; i < nb; i++) Br[i] = Bf[i];

    memcpy(Cd, C0, sizeof(double) * nc);
    for (size_t i = 0; i < nc; i++) Cf[i] = (float)C0[i];
    omp_set_num_threads(2);
    mlb_gemm_f64(ta, tb, M, N, K, alpha, A, lda, B, ldb, beta, Cd, ldc);
    mlb_gemm(ta, tb, M, N, K, (float)alpha, Af, lda, Bf, ldb, (float)beta, Cf, ldc);
    int bad = 0;   // checked: every 5th row and 3rd column, and the last of each (a wrong offset shows)
    for (int i = 0; i < M && bad < 3; i++)
        for (int j = 0; j < N && bad < 3; j++) {
            if ((i % 5 && i != M - 1) || (j % 3 && j != N - 1)) continue;
            long double sd = 0, sf = 0, mag = 0;
            for (int k = 0; k < K; k++) {
                sd += (long double)at(A, ta, lda, i, k) * at(B, tb, ldb, k, j);
                sf += (long double)at(Ar, ta, lda, i, k) * at(Br, tb, ldb, k, j);
                mag += fabsl((long double)at(Ar, ta, lda, i, k) * at(Br, tb, ldb, k, j));
            }
            size_t e = (size_t)i * ldc + j;
            double c0 = beta == 0 ? 0 : C0[e];
            double refd = (double)(alpha * sd + beta * c0), reff = (double)(alpha * sf + (double)(float)beta * (float)c0);
            // Rounding bounds of a K-term sum: gamma_K = K·u·(sum of |terms|), plus the C term.
            double bd = 2.0 * K * DBL_EPSILON * fabs(alpha) * (double)mag + 4 * DBL_EPSILON * fabs(beta * c0) + 1e-300;
            double bf = 2.0 * K * FLT_EPSILON * fabs(alpha) * (double)mag + 4 * FLT_EPSILON * fabs(beta * c0) + 1e-30;
            double ed = fabs(Cd[e] - refd) / bd, ef = fabs((double)Cf[e] - reff) / bf;
            if (!(ed <= 1) || !(ef <= 1)) {
                printf("  %s ta %d tb %d: C[%d,%d] double %.17g vs %.17g, float %.9g vs %.9g\n", s->what, ta, tb, i, j,
                       Cd[e], refd, Cf[e], reff);
                bad++;
            }
            if (ed > *worst) *worst = ed;
            if (ef > *worst) *worst = ef;
        }
    CHECK_MSG(bad == 0, "%s, ta %d, tb %d, alpha %g, beta %g: wrong values", s->what, ta, tb, alpha, beta);
    // The thread count never changes a bit: 1 and 3 threads against the 2-thread result above.
    for (int threads = 1; threads <= 3; threads += 2) {
        for (size_t i = 0; i < nc; i++) Cf2[i] = (float)C0[i];
        omp_set_num_threads(threads);
        mlb_gemm(ta, tb, M, N, K, (float)alpha, Af, lda, Bf, ldb, (float)beta, Cf2, ldc);
        CHECK_MSG(memcmp(Cf, Cf2, sizeof(float) * nc) == 0, "%s, ta %d, tb %d: %d threads differ from 2", s->what,
                  ta, tb, threads);
    }
    // Padding between rows of C is never written.
    for (int i = 0; i < M; i++)
        for (int j = N; j < ldc; j++)
            if (beta == 0) CHECK(isnan(Cf[(size_t)i * ldc + j]));
    free(A); free(B); free(C0); free(Cd); free(Af); free(Bf); free(Cf); free(Cf2); free(Ar); free(Br);
}

TEST(values_and_threads_every_cut) {
    int max_threads = omp_get_max_threads();
    double worst = 0;
    for (size_t s = 0; s < N_SHAPES; s++) {
        char along = '?';
        int n = mlb_gemm_shards(shapes[s].M, shapes[s].N, shapes[s].K, &along);
        CHECK_MSG(along == shapes[s].along && (n > 1) == (along != '-'), "%s: %d shards along %c", shapes[s].what, n,
                  along);
        CHECK(mlb_gemm_shards_f64(shapes[s].M, shapes[s].N, shapes[s].K, NULL) == n);
    }
    for (size_t s = 0; s < N_SHAPES; s++)
        for (int t = 0; t < 4; t++) {
            run_case(&shapes[s], t & 1, t >> 1, 0.7, 1.3, &worst);
            run_case(&shapes[s], t & 1, t >> 1, -1.1, 0.0, &worst);
        }
    omp_set_num_threads(max_threads);
    printf("  largest error / rounding bound: %.3g\n", worst);
}

// alpha = 0 scales C only (no product is formed, so Inf in A cannot make NaN); K = 0 the same.
TEST(alpha_zero_and_empty_k) {
    float A[6] = {INFINITY, 1, 2, 3, 4, 5}, B[6] = {1, 2, 3, 4, 5, 6}, C[4] = {1, 2, 3, 4};
    mlb_gemm(MLB_NOTRANS, MLB_NOTRANS, 2, 2, 3, 0.f, A, 3, B, 2, 2.f, C, 2);
    CHECK(C[0] == 2 && C[1] == 4 && C[2] == 6 && C[3] == 8);
    mlb_gemm(MLB_NOTRANS, MLB_NOTRANS, 2, 2, 0, 1.f, A, 1, B, 2, 0.5f, C, 2);
    CHECK(C[0] == 1 && C[1] == 2 && C[2] == 3 && C[3] == 4);
    C[0] = NAN;
    mlb_gemm(MLB_NOTRANS, MLB_NOTRANS, 2, 2, 0, 1.f, A, 1, B, 2, 0.f, C, 2);
    CHECK(C[0] == 0 && C[3] == 0);
}

// A program whose first GEMMs all run inside its own parallel region (the BRDF training's shards)
// must still get a single-threaded OpenBLAS: with its default pool (one thread per core) each
// shard's call spun against the OpenMP threads. Must run before any other GEMM of this process.
TEST(first_gemm_inside_a_parallel_region_keeps_openblas_single_threaded) {
    openblas_set_num_threads(2);   // OpenBLAS's default on a 2-core machine, whatever this one has
    REQUIRE(openblas_get_num_threads() == 2);
    static float A[128 * 64], B[64 * 64], C[2][128 * 64];
    for (int i = 0; i < 128 * 64; i++) A[i] = mlb_rng_uniform(SEED, 7, i);
    for (int i = 0; i < 64 * 64; i++) B[i] = mlb_rng_uniform(SEED, 8, i);
#pragma omp parallel for num_threads(2)
    for (int s = 0; s < 2; s++)
        mlb_gemm(MLB_NOTRANS, MLB_TRANS, 128, 64, 64, 1.f, A, 64, B, 64, 0.f, C[s], 64);
    CHECK(openblas_get_num_threads() == 1);
    CHECK(memcmp(C[0], C[1], sizeof C[0]) == 0);
}

int main(void) {
    RUN(first_gemm_inside_a_parallel_region_keeps_openblas_single_threaded);   // first: see above
    RUN(values_and_threads_every_cut);
    RUN(alpha_zero_and_empty_k);
    return test_summary();
}
