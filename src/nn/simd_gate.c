// The one switch between the CPU's scalar fp32 loops and their vectorised versions (simd_rows.h).
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/cpu.h"
#include "nn/simd_rows.h"

static int forced = -1;   // the tests' cap, -1: none

void mlb_simd_force(int level) { forced = level; }

const char* mlb_simd_name(mlb_simd_level level) {
    return level == MLB_SIMD_AVX512 ? "AVX-512" : level == MLB_SIMD_AVX2 ? "AVX2" : "scalar";
}

static int env_off(const char* name) {
    const char* e = getenv(name);
    return e && (!strcmp(e, "0") || !strcmp(e, "off"));
}

mlb_simd_level mlb_simd_kernels(void) {
#ifdef MLB_SIMD_X86
    static int best = -1;   // what the CPU and the environment allow, read once
    if (best < 0) {
        mlb_cpu_info f;
        mlb_cpu_detect(&f);
        int lv = MLB_SIMD_SCALAR;
        if (f.avx2 && f.fma && !env_off("MATLABER_CPU_AVX2")) {
            lv = MLB_SIMD_AVX2;
            if (f.avx512f && f.avx512bw && f.avx512vl && f.avx512dq && !env_off("MATLABER_CPU_AVX512"))
                lv = MLB_SIMD_AVX512;
        }
        best = lv;
    }
    return (mlb_simd_level)(forced >= 0 && forced < best ? forced : best);
#else
    return MLB_SIMD_SCALAR;
#endif
}

void mlb_groupnorm_forward_group(mlb_simd_level level, float* out, double* mean, double* rstd, const float* x,
                                 const float* w, const float* b, int Cg, int HW, float eps, int silu) {
#ifdef MLB_SIMD_X86
    if (level == MLB_SIMD_AVX512) mlb_groupnorm_forward_group_avx512(out, mean, rstd, x, w, b, Cg, HW, eps, silu);
    else mlb_groupnorm_forward_group_avx2(out, mean, rstd, x, w, b, Cg, HW, eps, silu);
#else
    (void)level; (void)out; (void)mean; (void)rstd; (void)x; (void)w; (void)b; (void)Cg; (void)HW; (void)eps;
    (void)silu;
    abort();   // mlb_simd_kernels() is scalar here: never called
#endif
}

void mlb_groupnorm_backward_group(mlb_simd_level level, float* dx, double* part, const float* dout, const float* x,
                                  const float* w, const float* b, float mean, float rstd, int Cg, int HW, int silu) {
#ifdef MLB_SIMD_X86
    if (level == MLB_SIMD_AVX512) mlb_groupnorm_backward_group_avx512(dx, part, dout, x, w, b, mean, rstd, Cg, HW, silu);
    else mlb_groupnorm_backward_group_avx2(dx, part, dout, x, w, b, mean, rstd, Cg, HW, silu);
#else
    (void)level; (void)dx; (void)part; (void)dout; (void)x; (void)w; (void)b; (void)mean; (void)rstd; (void)Cg;
    (void)HW; (void)silu;
    abort();
#endif
}

float mlb_softmax_row(mlb_simd_level level, float* p, int n, float* sum) {
#ifdef MLB_SIMD_X86
    return level == MLB_SIMD_AVX512 ? mlb_softmax_row_avx512(p, n, sum) : mlb_softmax_row_avx2(p, n, sum);
#else
    (void)level; (void)p; (void)n; (void)sum;
    abort();
#endif
}

void mlb_geglu_row(mlb_simd_level level, float* out, const float* a, const float* gate, int n) {
#ifdef MLB_SIMD_X86
    if (level == MLB_SIMD_AVX512) mlb_geglu_row_avx512(out, a, gate, n);
    else mlb_geglu_row_avx2(out, a, gate, n);
#else
    (void)level; (void)out; (void)a; (void)gate; (void)n;
    abort();
#endif
}

void mlb_geglu_backward_row(mlb_simd_level level, float* da, float* dgate, const float* dout, const float* a,
                            const float* gate, int n) {
#ifdef MLB_SIMD_X86
    if (level == MLB_SIMD_AVX512) mlb_geglu_backward_row_avx512(da, dgate, dout, a, gate, n);
    else mlb_geglu_backward_row_avx2(da, dgate, dout, a, gate, n);
#else
    (void)level; (void)da; (void)dgate; (void)dout; (void)a; (void)gate; (void)n;
    abort();
#endif
}

void mlb_adam_row(mlb_simd_level level, float* params, const float* grads, float* m, float* v, size_t n,
                  const mlb_adam_consts* k) {
#ifdef MLB_SIMD_X86
    if (level == MLB_SIMD_AVX512) mlb_adam_row_avx512(params, grads, m, v, n, k);
    else mlb_adam_row_avx2(params, grads, m, v, n, k);
#else
    (void)level; (void)params; (void)grads; (void)m; (void)v; (void)n; (void)k;
    abort();
#endif
}

void mlb_relu_row(mlb_simd_level level, float* out, float* d1, float* d2, const float* in, size_t n, int relu) {
#ifdef MLB_SIMD_X86
    if (level == MLB_SIMD_AVX512) mlb_relu_row_avx512(out, d1, d2, in, n, relu);
    else mlb_relu_row_avx2(out, d1, d2, in, n, relu);
#else
    (void)level; (void)out; (void)d1; (void)d2; (void)in; (void)n; (void)relu;
    abort();
#endif
}

void mlb_add_row(mlb_simd_level level, float* y, const float* x, size_t n) {
#ifdef MLB_SIMD_X86
    if (level == MLB_SIMD_AVX512) mlb_add_row_avx512(y, x, n);
    else mlb_add_row_avx2(y, x, n);
#else
    (void)level; (void)y; (void)x; (void)n;
    abort();
#endif
}

void mlb_layernorm_row(mlb_simd_level level, float* o, float* mean, float* rstd, const float* x, const float* w,
                       const float* b, int C, float eps) {
#ifdef MLB_SIMD_X86
    if (level == MLB_SIMD_AVX512) mlb_layernorm_row_avx512(o, mean, rstd, x, w, b, C, eps);
    else mlb_layernorm_row_avx2(o, mean, rstd, x, w, b, C, eps);
#else
    (void)level; (void)o; (void)mean; (void)rstd; (void)x; (void)w; (void)b; (void)C; (void)eps;
    abort();
#endif
}

void mlb_exp_shifted_row(mlb_simd_level level, float* p, int n, float c) {
#ifdef MLB_SIMD_X86
    if (level == MLB_SIMD_AVX512) mlb_exp_shifted_row_avx512(p, n, c);
    else mlb_exp_shifted_row_avx2(p, n, c);
#else
    (void)level; (void)p; (void)n; (void)c;
    abort();
#endif
}

void mlb_softmax_grad_row(mlb_simd_level level, float* g, const float* p, int n, float d, float scale) {
#ifdef MLB_SIMD_X86
    if (level == MLB_SIMD_AVX512) mlb_softmax_grad_row_avx512(g, p, n, d, scale);
    else mlb_softmax_grad_row_avx2(g, p, n, d, scale);
#else
    (void)level; (void)g; (void)p; (void)n; (void)d; (void)scale;
    abort();
#endif
}
