// Compute devices. The CPU is always there; CUDA when the build found nvcc (MLB_HAVE_CUDA) and the
// machine has a GPU. Ops take a device and dispatch to the implementation with the same contract.
#ifndef MATLABER_DEVICE_H
#define MATLABER_DEVICE_H
#include <stddef.h>
#include "matlaber/error.h"
#include "matlaber/nn.h"

typedef enum { MLB_DEVICE_CPU = 0, MLB_DEVICE_CUDA = 1 } mlb_device;

int mlb_cuda_compiled(void);          // 1 when the CUDA part was built
int mlb_cuda_device_count(void);      // 0 when none (or not compiled)
// "NVIDIA H100 80GB HBM3, 80.0 GiB, sm_90" or the reason there is none
mlb_status mlb_cuda_describe(int index, char* buf, size_t n);
// "cpu" | "cuda" | "auto" (cuda when present). A GPU asked for and missing is MLB_ERR_DEVICE.
mlb_status mlb_device_parse(const char* name, mlb_device* out);

// AdamW on device buffers (same contract as adam_update); the first CUDA op, used by the parity test.
mlb_status mlb_cuda_adam_update(float* params, const float* grads, float* m, float* v, size_t n,
                                const mlb_adam_config* cfg, long t);
// Host <-> device helpers for tests and tools.
mlb_status mlb_cuda_malloc(void** ptr, size_t bytes);
mlb_status mlb_cuda_free(void* ptr);
mlb_status mlb_cuda_copy_to_device(void* dst, const void* src, size_t bytes);
mlb_status mlb_cuda_copy_to_host(void* dst, const void* src, size_t bytes);

#endif
