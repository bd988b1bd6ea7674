// The attention's row softmax in 16 fp32 lanes. With the scalar expf of libm the softmax was ~65% of
// a latent-phase step of the sd_reference tiny model (4096 keys at a 64² latent, 4-wide heads: one
// exp per 16 flops of the products); see docs/benchmarks.md.
#include <math.h>
#include "nn/softmax_avx512.h"

#if defined(__x86_64__) && defined(__GNUC__) && (__GNUC__ >= 10 || defined(__clang__))
#include "nn/avx512_math.h"

MLB_AVX512_TARGET float mlb_softmax_row_avx512(float* p, int n, float* sum) {
    __m512 m = _mm512_set1_ps(-INFINITY);
    for (int s = 0; s < n; s += 16) {
        __mmask16 k = mlb_lanes16((size_t)(n - s));
        m = _mm512_mask_max_ps(m, k, m, _mm512_maskz_loadu_ps(k, p + s));
    }
    float mx = _mm512_reduce_max_ps(m);
    const __m512 vm = _mm512_set1_ps(mx);
    __m512 acc = _mm512_setzero_ps();
    for (int s = 0; s < n; s += 16) {
        __mmask16 k = mlb_lanes16((size_t)(n - s));
        __m512 e = mlb_exp_nonpositive_ps(_mm512_sub_ps(_mm512_maskz_loadu_ps(k, p + s), vm));
        e = _mm512_maskz_mov_ps(k, e);
        _mm512_mask_storeu_ps(p + s, k, e);
        acc = _mm512_add_ps(acc, e);
    }
    *sum = _mm512_reduce_add_ps(acc);
    return mx;
}
#else
float mlb_softmax_row_avx512(float* p, int n, float* sum) {   // never called: mlb_avx512_kernels() is 0
    float mx = p[0], s = 0;
    for (int i = 1; i < n; i++) mx = p[i] > mx ? p[i] : mx;
    for (int i = 0; i < n; i++) s += (p[i] = expf(p[i] - mx));
    *sum = s;
    return mx;
}
#endif
