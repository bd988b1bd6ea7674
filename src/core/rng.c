// Philox4x32-10 (Salmon, Moraes, Dror, Shaw: "Parallel random numbers: as easy as 1, 2, 3", SC'11).
#include "matlaber/rng.h"
#include <math.h>

#define PHILOX_M0 0xD2511F53u
#define PHILOX_M1 0xCD9E8D57u
#define PHILOX_W0 0x9E3779B9u   // golden ratio
#define PHILOX_W1 0xBB67AE85u   // sqrt(3) - 1

mlb_u32x4 mlb_philox4x32_10(const uint32_t counter[4], const uint32_t key[2]) {
    uint32_t c0 = counter[0], c1 = counter[1], c2 = counter[2], c3 = counter[3];
    uint32_t k0 = key[0], k1 = key[1];
    for (int round = 0; round < 10; round++) {
        uint64_t p0 = (uint64_t)PHILOX_M0 * c0, p1 = (uint64_t)PHILOX_M1 * c2;
        uint32_t hi0 = (uint32_t)(p0 >> 32), lo0 = (uint32_t)p0;
        uint32_t hi1 = (uint32_t)(p1 >> 32), lo1 = (uint32_t)p1;
        c0 = hi1 ^ c1 ^ k0;
        c1 = lo1;
        c2 = hi0 ^ c3 ^ k1;
        c3 = lo0;
        k0 += PHILOX_W0;
        k1 += PHILOX_W1;
    }
    mlb_u32x4 r = {{c0, c1, c2, c3}};
    return r;
}

mlb_u32x4 mlb_rng_words(uint64_t seed, uint64_t stream, uint64_t index) {
    uint32_t ctr[4] = {(uint32_t)index, (uint32_t)(index >> 32), (uint32_t)stream, (uint32_t)(stream >> 32)};
    uint32_t key[2] = {(uint32_t)seed, (uint32_t)(seed >> 32)};
    return mlb_philox4x32_10(ctr, key);
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
    mlb_u32x4 w = mlb_rng_words(seed, stream, index);
    double u1 = ((double)w.v[0] + 0.5) * (1.0 / 4294967296.0);   // (0, 1): log is finite
    double u2 = (double)w.v[1] * (1.0 / 4294967296.0);
    return sqrt(-2.0 * log(u1)) * cos(2.0 * M_PI * u2);
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
