// Philox4x32-10 (Salmon, Moraes, Dror, Shaw: "Parallel random numbers: as easy as 1, 2, 3", SC'11).
#include "matlaber/rng.h"
#include <math.h>
#include "core/philox.h"

mlb_u32x4 mlb_philox4x32_10(const uint32_t counter[4], const uint32_t key[2]) {
    mlb_u32x4 r;
    mlb_philox_words(((uint64_t)key[1] << 32) | key[0], ((uint64_t)counter[3] << 32) | counter[2],
                     ((uint64_t)counter[1] << 32) | counter[0], r.v);
    return r;
}

mlb_u32x4 mlb_rng_words(uint64_t seed, uint64_t stream, uint64_t index) {
    mlb_u32x4 r;
    mlb_philox_words(seed, stream, index, r.v);
    return r;
}

double mlb_u32_to_unit(uint32_t x) { return (double)x * (1.0 / 4294967296.0); }

double mlb_rng_uniform_f64(uint64_t seed, uint64_t stream, uint64_t index) {
    mlb_u32x4 w = mlb_rng_words(seed, stream, index);
    // 53 bits from two words
    uint64_t bits = ((uint64_t)w.v[0] << 21) ^ ((uint64_t)w.v[1] >> 11);
    return (double)(bits & ((1ull << 53) - 1)) * (1.0 / 9007199254740992.0);
}

float mlb_rng_uniform(uint64_t seed, uint64_t stream, uint64_t index) {
    mlb_u32x4 w = mlb_rng_words(seed, stream, index);
    return (float)(w.v[0] >> 8) * (1.0f / 16777216.0f);   // 24 bits: exactly representable, < 1
}

double mlb_rng_normal_f64(uint64_t seed, uint64_t stream, uint64_t index) {
    return mlb_philox_normal(seed, stream, index);
}

float mlb_rng_normal(uint64_t seed, uint64_t stream, uint64_t index) {
    return (float)mlb_rng_normal_f64(seed, stream, index);
}

uint32_t mlb_rng_below(uint64_t seed, uint64_t stream, uint64_t index, uint32_t n) {
    mlb_u32x4 w = mlb_rng_words(seed, stream, index);
    // 64-bit multiply-shift: the bias is below n / 2^64, far under anything measurable.
    uint64_t x = ((uint64_t)w.v[0] << 32) | w.v[1];
    return (uint32_t)(((unsigned __int128)x * n) >> 64);
}

void mlb_rng_fill_uniform(float* out, size_t n, uint64_t seed, uint64_t stream, uint64_t offset, float lo, float hi) {
#pragma omp parallel for schedule(static) if (n > 65536)
    for (size_t i = 0; i < n; i++) out[i] = lo + (hi - lo) * mlb_rng_uniform(seed, stream, offset + i);
}

void mlb_rng_fill_normal(float* out, size_t n, uint64_t seed, uint64_t stream, uint64_t offset, float mean, float std) {
#pragma omp parallel for schedule(static) if (n > 65536)
    for (size_t i = 0; i < n; i++) out[i] = mean + std * mlb_rng_normal(seed, stream, offset + i);
}

void mlb_rng_permutation(uint32_t* perm, uint32_t n, uint64_t seed, uint64_t stream) {
    for (uint32_t i = 0; i < n; i++) perm[i] = i;
    for (uint32_t i = n; i > 1; i--) {
        uint32_t j = mlb_rng_below(seed, stream, i, i);
        uint32_t t = perm[i - 1]; perm[i - 1] = perm[j]; perm[j] = t;
    }
}
