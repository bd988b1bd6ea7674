// MLB_HD marks the functions of a header that both the C sources and the CUDA kernels include, so
// that maths is written once for both devices (render/shade_math.h, render/raster_math.h): static
// inline in C, __host__ __device__ under nvcc.
#ifndef MATLABER_HD_H
#define MATLABER_HD_H
#ifdef __CUDACC__
#define MLB_HD static inline __host__ __device__
#else
#define MLB_HD static inline
#endif
#endif
