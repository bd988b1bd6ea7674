// Thread count of the CPU code: OpenMP loops and OpenBLAS's own threads together.
#ifndef MATLABER_THREADS_H
#define MATLABER_THREADS_H
void mlb_set_threads(int n);   // n >= 1
int mlb_get_threads(void);
// OpenBLAS's kernel family ("Haswell", "SkylakeX", ...).
const char* mlb_blas_corename(void);
// Debian's OpenBLAS 0.3.21 does not know newer CPUs (e.g. Sapphire Rapids) and falls back to its
// SSE3 "Prescott" kernels, ~2.5x slower. When that happened on a CPU with AVX2 or AVX-512 this
// returns the kernel family to ask for through $OPENBLAS_CORETYPE (read when OpenBLAS loads, so
// the program must restart itself); NULL when nothing needs doing.
const char* mlb_blas_better_coretype(void);
#endif
