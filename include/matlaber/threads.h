// Thread count of the CPU code: OpenMP threads (OpenBLAS stays on one; every GEMM is mlb_gemm).
#ifndef MATLABER_THREADS_H
#define MATLABER_THREADS_H
void mlb_set_threads(int n);   // n >= 1
int mlb_get_threads(void);
// OpenBLAS's kernel family ("Haswell", "SkylakeX", ...) and build configuration.
const char* mlb_blas_corename(void);
const char* mlb_blas_config(void);
// Debian's OpenBLAS 0.3.21 does not know newer CPUs: it falls back to SSE3 "Prescott" kernels on
// Sapphire Rapids (~2.5x slower) and to Haswell's on AMD Zen 5 (~2x). When the CPU's features
// (cpu.h, read at run time) allow a stronger family than the one OpenBLAS picked, this returns it,
// to ask for through $OPENBLAS_CORETYPE (read when OpenBLAS loads, so the program must restart
// itself); NULL when nothing needs doing or the user set $OPENBLAS_CORETYPE.
const char* mlb_blas_better_coretype(void);
// Two settings the OpenMP and OpenBLAS runtimes read only when they load, so a program restarts
// itself once with them (execv of /proc/self/exe, MATLABER_REEXEC=1 marking the second start):
// OpenBLAS pointed at the kernels this CPU can run (above; MATLABER_BLAS_CHOSEN=1 then), and
// OMP_WAIT_POLICY=passive where the launcher says several processes of the job share this node
// (mpirun, srun): libgomp's idle threads would otherwise spin after every loop on cores the others
// need. A process alone keeps libgomp's default (a short spin, then sleep). The user's own settings
// are kept. Returns (doing nothing) when neither is needed or the restart failed.
void mlb_runtime_restart(char** argv);
// glibc's malloc set to keep freed memory (up to 1 GB at the heap's top, blocks up to 256 MB from
// the heap rather than their own mappings): the stages free and allocate the same buffers every
// step. Not when the user set MALLOC_MMAP_THRESHOLD_, MALLOC_TRIM_THRESHOLD_ or GLIBC_TUNABLES.
void mlb_runtime_tune_malloc(void);
#endif
