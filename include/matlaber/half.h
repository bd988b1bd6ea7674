// IEEE float16 (binary16) and bfloat16 <-> float32 conversions, bit patterns as uint16_t.
// Down-conversions round to nearest, ties to even; overflow gives +-inf; subnormals are kept
// (float16) and flushed to nothing only when they round to zero. NaNs keep their sign and the
// top payload bits and come out quiet (as the x86 F16C and ARM instructions do).
// Up-conversions are exact (every float16/bfloat16 value is a float32 value).
#ifndef MATLABER_HALF_H
#define MATLABER_HALF_H
#include <stddef.h>
#include <stdint.h>

float mlb_f16_to_f32(uint16_t h);
uint16_t mlb_f32_to_f16(float f);
float mlb_bf16_to_f32(uint16_t h);
uint16_t mlb_f32_to_bf16(float f);

// Arrays. `src` may be unaligned (it is read with memcpy), so these accept pointers straight
// into a safetensors mapping. dst and src must not overlap.
void mlb_f16_to_f32_array(float* dst, const void* src, size_t n);   // F16C where the CPU has it, threaded
void mlb_f16_to_f32_array_scalar(float* dst, const void* src, size_t n);   // the portable loop (tests)
void mlb_f32_to_f16_array(void* dst, const float* src, size_t n);
void mlb_bf16_to_f32_array(float* dst, const void* src, size_t n);
void mlb_f32_to_bf16_array(void* dst, const float* src, size_t n);

#endif
