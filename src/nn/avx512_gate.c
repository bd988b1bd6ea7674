// The one switch between the CPU's scalar fp32 loops and their AVX-512 versions (avx512_gate.h).
#include <stdlib.h>
#include <string.h>
#include "matlaber/cpu.h"
#include "nn/avx512_gate.h"

static int force_scalar = -1;   // -1: not read yet ($MATLABER_CPU_AVX512)

void mlb_avx512_force_scalar(int on) { force_scalar = on ? 1 : 0; }

int mlb_avx512_kernels(void) {
#if defined(__x86_64__) && defined(__GNUC__) && (__GNUC__ >= 10 || defined(__clang__))
    static int cpu_has = -1;
    if (cpu_has < 0) {
        mlb_cpu_info f;
        mlb_cpu_detect(&f);
        cpu_has = f.avx512f && f.avx512bw && f.avx512vl && f.avx512dq;
    }
    if (force_scalar < 0) {
        const char* e = getenv("MATLABER_CPU_AVX512");
        force_scalar = e && (!strcmp(e, "0") || !strcmp(e, "off"));
    }
    return cpu_has && !force_scalar;
#else
    return 0;
#endif
}
