// The scalar type of the dual sources (CMakeLists.txt: MLB_DUAL_SOURCES). Compiled once as float
// (plain names) and once with MLB_F64 as double (names suffixed _f64), so that one piece of code
// serves training (float) and the finite-difference tests (double).
#ifndef MATLABER_REAL_H
#define MATLABER_REAL_H
#include <math.h>
#include <cblas.h>

#ifdef MLB_F64
typedef double real;
#define FN(name) name##_f64
#define R_EXP exp
#define R_LOG log
#define R_LOG1P log1p
#define R_TANH tanh
#define R_SQRT sqrt
#define R_FABS fabs
#define R_ERF erf
#define R_POW pow
#else
typedef float real;
#define FN(name) name
#define R_EXP expf
#define R_LOG logf
#define R_LOG1P log1pf
#define R_TANH tanhf
#define R_SQRT sqrtf
#define R_FABS fabsf
#define R_ERF erff
#define R_POW powf
#endif

// Every GEMM of the dual sources goes through the thread-count independent one (src/nn/gemm.c).
#define GEMM FN(mlb_gemm)
// Its signature: ops that may run their GEMM at another precision (conv, linear: the float pass's
// *_bf16 variants pass mlb_gemm_bf16) take one of these.
typedef void (*FN(mlb_gemm_fn))(int ta, int tb, int M, int N, int K, real alpha, const real* A, int lda,
                                const real* B, int ldb, real beta, real* C, int ldc);

#endif
