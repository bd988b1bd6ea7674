// Counter-based random numbers (Philox4x32-10, Salmon et al. 2011). A value is a pure function
// of (seed, stream, index), so a run is the same on any thread count and, later, on the GPU.
// Streams separate uses (initialisation, shuffling, noise) so they never overlap.
#ifndef MATLABER_RNG_H
#define MATLABER_RNG_H
#include <stddef.h>
#include <stdint.h>

typedef struct { uint32_t v[4]; } mlb_u32x4;

// One Philox4x32-10 block: 128-bit counter (c0 lowest word), 64-bit key (k0 low word).
mlb_u32x4 mlb_philox4x32_10(const uint32_t counter[4], const uint32_t key[2]);

// Four random words for (seed, stream, index): counter = (index lo, index hi, stream lo, stream hi).
mlb_u32x4 mlb_rng_words(uint64_t seed, uint64_t stream, uint64_t index);
double mlb_u32_to_unit(uint32_t x);                                       // [0, 1), 32 bits
float mlb_rng_uniform(uint64_t seed, uint64_t stream, uint64_t index);    // [0, 1)
float mlb_rng_normal(uint64_t seed, uint64_t stream, uint64_t index);     // N(0, 1), Box-Muller
double mlb_rng_uniform_f64(uint64_t seed, uint64_t stream, uint64_t index);
double mlb_rng_normal_f64(uint64_t seed, uint64_t stream, uint64_t index);
uint32_t mlb_rng_below(uint64_t seed, uint64_t stream, uint64_t index, uint32_t n);  // [0, n), unbiased

// out[i] = value at index offset + i; parallel and deterministic.
void mlb_rng_fill_uniform(float* out, size_t n, uint64_t seed, uint64_t stream, uint64_t offset, float lo, float hi);
void mlb_rng_fill_normal(float* out, size_t n, uint64_t seed, uint64_t stream, uint64_t offset, float mean, float std);
// A permutation of 0..n-1 (Fisher-Yates driven by the counter stream).
void mlb_rng_permutation(uint32_t* perm, uint32_t n, uint64_t seed, uint64_t stream);

#endif
