// Compute devices. The CPU is always there; CUDA when the build found nvcc (MLB_HAVE_CUDA) and the
// machine has a GPU. Ops take a device and dispatch to the implementation with the same contract
// (the CUDA ops: matlaber/cuda_ops.h).
#ifndef MATLABER_DEVICE_H
#define MATLABER_DEVICE_H
#include <stddef.h>
#include "matlaber/error.h"

typedef enum { MLB_DEVICE_CPU = 0, MLB_DEVICE_CUDA = 1 } mlb_device;

// The operands of a GPU's GEMMs (linear, conv, attention). On the CPU only bf16 means something:
// the linear, conv and attention GEMMs in bf16 (mlb_gemm_bf16, AVX-512 BF16; fp32 on a CPU without
// it; the SD UNet's weights then kept in bf16); fp16
// and tf32 (GPU formats, and the global default fp16) compute in fp32 there.
typedef enum {
    MLB_GEMM_FP32 = 0,   // plain fp32 (CUDA cores): matches the CPU to ~1e-6 relative
    MLB_GEMM_TF32,       // fp32 operands rounded to tf32 on tensor cores, fp32 accumulation (~3e-4)
    MLB_GEMM_FP16,       // operands converted to fp16, fp32 accumulation (~1e-3; |x| < 65504)
    MLB_GEMM_BF16,       // operands converted to bf16, fp32 accumulation (~5e-3)
} mlb_gemm_precision;
const char* mlb_gemm_precision_name(mlb_gemm_precision p);   // "fp32", "tf32", "fp16", "bf16"
// "fp32" | "tf32" | "fp16" | "bf16" -> *out; MLB_ERR_ARG naming the accepted values otherwise.
mlb_status mlb_gemm_precision_parse(const char* name, mlb_gemm_precision* out);
// The program's --precision, default fp16 (as Stable Diffusion is usually run on GPUs; fp32
// accumulation throughout). Read by the program alone, which passes it down (a table's precision,
// mlb_sd_model_options.precision); nothing in the library reads it.
void mlb_set_gemm_precision(mlb_gemm_precision p);
mlb_gemm_precision mlb_gemm_precision_current(void);
// 1 once mlb_set_gemm_precision was called (the program's --precision): a run's own setting
// (config.json "precision", the cpu preset's bf16) applies only when it was not.
int mlb_gemm_precision_chosen(void);
#define MLB_PRECISION_OPTION_HELP                                                                          \
    "  --precision P   GEMM operands, fp32 accumulation always. GPU: fp16 (default), bf16, tf32 or fp32.\n"   \
    "                  CPU: fp32 (what fp16 and tf32 mean there), or bf16 for the SD UNet's and VAE's\n"      \
    "                  linear, conv and attention GEMMs (AVX-512 BF16; on a CPU without it fp32, said once)\n"

int mlb_cuda_compiled(void);          // 1 when the CUDA part was built
int mlb_cuda_device_count(void);      // 0 when none (or not compiled, or no driver)
// The number of GPUs, or MLB_ERR_DEVICE with the reason there are none: "built without CUDA", or
// CUDA's own error string (no driver, driver older than the runtime, no device).
mlb_status mlb_cuda_probe(int* count);
// "NVIDIA H100 80GB HBM3, 80.0 GiB, sm_90" or the reason there is none
mlb_status mlb_cuda_describe(int index, char* buf, size_t n);
// "cpu" | "cuda" | "auto" (cuda when present). A GPU asked for and missing is MLB_ERR_DEVICE.
// Only parses and probes; mlb_device_select also makes the device current.
mlb_status mlb_device_parse(const char* name, mlb_device* out);
// "cpu" | "cuda" | "cuda:N" | "auto": parses, and for CUDA makes GPU N (default 0) current and
// creates its context (mlb_cuda_init). Errors: MLB_ERR_ARG for an unknown name; MLB_ERR_DEVICE
// "--device cuda: this build has no CUDA part (built without CUDA) ..." or "--device cuda: <CUDA's
// error string>" when the driver or GPU is missing. "auto" falls back to the CPU silently.
mlb_status mlb_device_select(const char* name, mlb_device* out);
// The device the last successful mlb_device_select chose (MLB_DEVICE_CPU before any). Read by the
// program alone, which passes it down; nothing in the library reads it (check_layout).
mlb_device mlb_device_current(void);
const char* mlb_device_name(mlb_device d);   // "cpu" / "cuda"
// For the program's --device option: arg is the option's value, or NULL when the option was not
// given, which means $MATLABER_DEVICE if set, else "auto". Selects as mlb_device_select does.
mlb_status mlb_device_option(const char* arg, mlb_device* out);
#define MLB_DEVICE_OPTION_HELP "  --device D      cpu, cuda, cuda:N or auto (default: $MATLABER_DEVICE, else auto = cuda when a GPU is present)\n"

// Makes GPU `index` current and creates its context (cudaSetDevice + cudaFree(0)): the first
// call that can fail on a machine without a driver, so its error is the CUDA error string.
mlb_status mlb_cuda_init(int index);

// Host <-> device helpers for tests and tools.
mlb_status mlb_cuda_malloc(void** ptr, size_t bytes);
mlb_status mlb_cuda_free(void* ptr);
// mlb_cuda_malloc takes from the device's stream-ordered pool, which keeps freed memory for the
// next request (src/cuda/device.cu); mlb_cuda_trim waits for the device and hands it back to the
// driver (the memory then shows as free to other processes and to cudaMalloc).
mlb_status mlb_cuda_trim(void);
mlb_status mlb_cuda_copy_to_device(void* dst, const void* src, size_t bytes);
mlb_status mlb_cuda_copy_to_host(void* dst, const void* src, size_t bytes);
// What has crossed between host and device through the two calls above since the program began
// (every table upload and download goes through them): bytes each way and the number of copies.
// The pipeline reports them per step of each stage (docs/cuda.md); all 0 without CUDA.
typedef struct {
    unsigned long long up_bytes, down_bytes, copies;
} mlb_cuda_transfers;
mlb_cuda_transfers mlb_cuda_transfers_get(void);

#endif
