// float16 / bfloat16 <-> float32 by bit manipulation: portable, no F16C needed, exact rounding; the
// float16 -> float32 array conversion also in F16C's 8 lanes where the CPU has them (the same values).
#include "matlaber/half.h"
#include <string.h>
#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#include "matlaber/cpu.h"
#endif

static uint32_t f32_bits(float f) { uint32_t u; memcpy(&u, &f, 4); return u; }
static float bits_f32(uint32_t u) { float f; memcpy(&f, &u, 4); return f; }

float mlb_f16_to_f32(uint16_t h) {
    uint32_t sign = (uint32_t)(h & 0x8000u) << 16;
    uint32_t exp = (h >> 10) & 0x1Fu;
    uint32_t mant = h & 0x3FFu;
    if (exp == 0x1F)   // inf, or NaN made quiet with its payload kept
        return bits_f32(sign | 0x7F800000u | (mant ? (0x400000u | (mant << 13)) : 0));
    if (exp == 0) {
        if (mant == 0) return bits_f32(sign);
        // Subnormal: value = mant * 2^-24, exact in float32 (mant < 2^10).
        float v = (float)mant * 0x1p-24f;
        return sign ? -v : v;
    }
    return bits_f32(sign | ((exp + 112u) << 23) | (mant << 13));   // rebias 15 -> 127
}

uint16_t mlb_f32_to_f16(float f) {
    uint32_t u = f32_bits(f);
    uint16_t sign = (uint16_t)((u >> 16) & 0x8000u);
    uint32_t exp = (u >> 23) & 0xFFu;
    uint32_t mant = u & 0x7FFFFFu;
    if (exp == 0xFF) {
        if (!mant) return sign | 0x7C00u;
        return sign | 0x7E00u | (uint16_t)(mant >> 13);   // quiet NaN, top payload bits
    }
    int e = (int)exp - 127 + 15;   // float16 biased exponent
    if (e >= 0x1F) return sign | 0x7C00u;   // certainly overflows, even before rounding
    uint32_t sig, shift;
    if (e >= 1) {   // normal result: 11-bit significand, drop 13 bits
        sig = mant | 0x800000u;
        shift = 13;
    } else {   // subnormal (or zero) result: drop 13 + (1 - e) bits
        if (e < -10) return sign;   // below half the smallest subnormal (2^-25): rounds to 0
        sig = mant | 0x800000u;     // exp >= 102 here, so the input is a normal float32
        shift = (uint32_t)(14 - e);
        e = 0;
    }
    uint32_t kept = sig >> shift;
    uint32_t rest = sig & ((1u << shift) - 1);
    uint32_t half = 1u << (shift - 1);
    if (rest > half || (rest == half && (kept & 1))) kept++;
    // For normals kept includes the implicit bit (0x400): adding it to (e-1)<<10 sets the
    // exponent to e, and a carry out of the significand bumps the exponent (up to inf: 0x7C00).
    // For subnormals a carry to 0x400 lands exactly on the smallest normal.
    uint32_t r = e ? ((uint32_t)(e - 1) << 10) + kept : kept;
    return sign | (uint16_t)r;
}

float mlb_bf16_to_f32(uint16_t h) {
    uint32_t u = (uint32_t)h << 16;
    if ((u & 0x7F800000u) == 0x7F800000u && (u & 0x7FFFFFu)) u |= 0x400000u;   // quiet NaN
    return bits_f32(u);
}

uint16_t mlb_f32_to_bf16(float f) {
    uint32_t u = f32_bits(f);
    if ((u & 0x7F800000u) == 0x7F800000u && (u & 0x7FFFFFu))
        return (uint16_t)((u >> 16) | 0x40u);   // quiet NaN; never rounds into inf
    // Round to nearest even on the 16 dropped bits; a carry may reach the exponent, and from
    // the largest finite values up to inf, which is the correct rounding.
    u += 0x7FFFu + ((u >> 16) & 1u);
    return (uint16_t)(u >> 16);
}

static void f16_to_f32_scalar(float* dst, const unsigned char* s, size_t n) {
    for (size_t i = 0; i < n; i++) { uint16_t h; memcpy(&h, s + 2 * i, 2); dst[i] = mlb_f16_to_f32(h); }
}

#if defined(__x86_64__) || defined(__i386__)
// F16C's VCVTPH2PS, 8 values an instruction: the same values as the scalar conversion (both exact;
// NaNs quieted alike; test_safetensors' f16_array_matches_scalar checks every bit pattern). Where
// a model's F16 weights stay F16 in memory and are widened per call (mlb_unet_options.f16_weights)
// this runs over every weight of every UNet forward.
__attribute__((target("avx,f16c"))) static void f16_to_f32_f16c(float* dst, const unsigned char* s, size_t n) {
    size_t i = 0;
    for (; i + 8 <= n; i += 8) _mm256_storeu_ps(dst + i, _mm256_cvtph_ps(_mm_loadu_si128((const __m128i*)(s + 2 * i))));
    f16_to_f32_scalar(dst + i, s + 2 * i, n - i);
}

static int has_f16c(void) {
    static int known = -1;   // read once; a race only writes the same value
    int v = __atomic_load_n(&known, __ATOMIC_RELAXED);
    if (v < 0) {
        mlb_cpu_info f;
        mlb_cpu_detect(&f);
        v = f.f16c;
        __atomic_store_n(&known, v, __ATOMIC_RELAXED);
    }
    return v;
}
#endif

void mlb_f16_to_f32_array_scalar(float* dst, const void* src, size_t n) { f16_to_f32_scalar(dst, src, n); }

// Large arrays in parallel blocks (a UNet's largest weight is 13M values).
#define HALF_BLOCK ((size_t)1 << 18)
void mlb_f16_to_f32_array(float* dst, const void* src, size_t n) {
    const unsigned char* s = src;
    long blocks = (long)((n + HALF_BLOCK - 1) / HALF_BLOCK);
#pragma omp parallel for schedule(static) if (blocks > 1)
    for (long b = 0; b < blocks; b++) {
        size_t lo = (size_t)b * HALF_BLOCK, m = n - lo < HALF_BLOCK ? n - lo : HALF_BLOCK;
#if defined(__x86_64__) || defined(__i386__)
        if (has_f16c()) { f16_to_f32_f16c(dst + lo, s + 2 * lo, m); continue; }
#endif
        f16_to_f32_scalar(dst + lo, s + 2 * lo, m);
    }
}
void mlb_f32_to_f16_array(void* dst, const float* src, size_t n) {
    unsigned char* d = dst;
    for (size_t i = 0; i < n; i++) { uint16_t h = mlb_f32_to_f16(src[i]); memcpy(d + 2 * i, &h, 2); }
}
void mlb_bf16_to_f32_array(float* dst, const void* src, size_t n) {
    const unsigned char* s = src;
    for (size_t i = 0; i < n; i++) { uint16_t h; memcpy(&h, s + 2 * i, 2); dst[i] = mlb_bf16_to_f32(h); }
}
void mlb_f32_to_bf16_array(void* dst, const float* src, size_t n) {
    unsigned char* d = dst;
    for (size_t i = 0; i < n; i++) { uint16_t h = mlb_f32_to_bf16(src[i]); memcpy(d + 2 * i, &h, 2); }
}
