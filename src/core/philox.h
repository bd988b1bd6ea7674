// Philox4x32-10 (Salmon, Moraes, Dror, Shaw: "Parallel random numbers: as easy as 1, 2, 3", SC'11)
// and the normal draw built on it, written once for the host (core/rng.c) and the GPU (the
// fill_normal op's kernel), so that the device draws the numbers the host would.
#ifndef MATLABER_PHILOX_H
#define MATLABER_PHILOX_H
#include <math.h>
#include <stdint.h>
#include "core/hd.h"

// The 4 words of counter (index, stream) under key seed.
MLB_HD void mlb_philox_words(uint64_t seed, uint64_t stream, uint64_t index, uint32_t out[4]) {
    uint32_t c0 = (uint32_t)index, c1 = (uint32_t)(index >> 32), c2 = (uint32_t)stream, c3 = (uint32_t)(stream >> 32);
    uint32_t k0 = (uint32_t)seed, k1 = (uint32_t)(seed >> 32);
    for (int round = 0; round < 10; round++) {
        uint64_t p0 = (uint64_t)0xD2511F53u * c0, p1 = (uint64_t)0xCD9E8D57u * c2;
        uint32_t hi0 = (uint32_t)(p0 >> 32), lo0 = (uint32_t)p0;
        uint32_t hi1 = (uint32_t)(p1 >> 32), lo1 = (uint32_t)p1;
        c0 = hi1 ^ c1 ^ k0;
        c1 = lo1;
        c2 = hi0 ^ c3 ^ k1;
        c3 = lo0;
        k0 += 0x9E3779B9u;   // golden ratio
        k1 += 0xBB67AE85u;   // sqrt(3) - 1
    }
    out[0] = c0, out[1] = c1, out[2] = c2, out[3] = c3;
}

// A standard normal from the first two words: Box-Muller in double.
MLB_HD double mlb_philox_normal(uint64_t seed, uint64_t stream, uint64_t index) {
    uint32_t w[4];
    mlb_philox_words(seed, stream, index, w);
    double u1 = ((double)w[0] + 0.5) * (1.0 / 4294967296.0);   // (0, 1): log is finite
    double u2 = (double)w[1] * (1.0 / 4294967296.0);
    return sqrt(-2.0 * log(u1)) * cos(2.0 * 3.14159265358979323846 * u2);
}
#endif
