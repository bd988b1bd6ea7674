// What the CPU can execute, read at run time (cpuid and the OS's saved-state mask), and the OpenBLAS
// kernel family that follows from it.
#ifndef MATLABER_CPU_H
#define MATLABER_CPU_H
#include <stddef.h>

typedef struct {
    char model[64];   // the brand string ("AMD EPYC 9R14 ..."), "unknown" when the CPU has none
    char vendor[16];  // "GenuineIntel", "AuthenticAMD", ...
    int family, model_id;   // display family and model (family 25 = AMD Zen 3/4, 26 = Zen 5)
    // Instruction sets usable here: the CPU has them and the OS saves their registers.
    int avx2, fma, f16c, avx512f, avx512bw, avx512vl, avx512dq, avx512cd, avx512_bf16, avx512_fp16;
    int amx_tile, amx_bf16;   // AMX tiles (Linux must also grant them per process: arch_prctl)
} mlb_cpu_info;

// Fills *info for this machine (zeros and "unknown" on a non-x86 build).
void mlb_cpu_detect(mlb_cpu_info* info);
// Short list of the features above that are present, e.g. "avx2 fma avx512f ... avx512_bf16".
void mlb_cpu_feature_string(const mlb_cpu_info* info, char* buf, size_t size);

// The OpenBLAS kernel family best suited to a CPU with these features, when `current` (what
// OpenBLAS picked) is a weaker one; NULL when current is as good (or unknown to this table).
// Follows the features, not OpenBLAS's list of CPU names: Debian's 0.3.21 picks Haswell kernels
// on AMD Zen 5 and SSE3 (Prescott) on Sapphire Rapids, 2x and 2.5x slower than what they can run.
const char* mlb_blas_coretype_for(const char* current, const mlb_cpu_info* info);
#endif
