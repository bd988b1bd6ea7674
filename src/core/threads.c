// "--threads N" is the OpenMP thread count. OpenBLAS (Debian's pthread build) keeps a pool of its
// own, which stays at one thread: mlb_gemm (src/nn/gemm.c) shares a GEMM out over OpenMP in
// shards fixed by the shape, so that the thread count never changes a result.
#include "matlaber/threads.h"
#include "matlaber/cpu.h"
#include <cblas.h>
#include <malloc.h>
#include <omp.h>
#include <stdlib.h>
#include <unistd.h>

void mlb_set_threads(int n) {
    if (n < 1) n = 1;
    omp_set_num_threads(n);
    openblas_set_num_threads(1);
}

int mlb_get_threads(void) { return omp_get_max_threads(); }

const char* mlb_blas_corename(void) { return openblas_get_corename(); }
const char* mlb_blas_config(void) { return openblas_get_config(); }

const char* mlb_blas_better_coretype(void) {
    const char* env = getenv("OPENBLAS_CORETYPE");
    if (env && *env) return NULL;   // the user chose
    mlb_cpu_info cpu;
    mlb_cpu_detect(&cpu);
    return mlb_blas_coretype_for(openblas_get_corename(), &cpu);
}

// The processes of this job on this node, as the launcher tells them (Open MPI's mpirun, MPICH's
// hydra, Slurm's srun with --ntasks-per-node); 1 when none does.
static long local_processes(void) {
    static const char* const names[] = {"OMPI_COMM_WORLD_LOCAL_SIZE", "MPI_LOCALNRANKS", "SLURM_NTASKS_PER_NODE"};
    for (size_t i = 0; i < sizeof names / sizeof *names; i++) {
        const char* v = getenv(names[i]);
        char* end;
        long n = v ? strtol(v, &end, 10) : 0;
        if (v && end != v && n > 0) return n;
    }
    return 1;
}

void mlb_runtime_restart(char** argv) {
    if (getenv("MATLABER_REEXEC")) return;
    const char* core = mlb_blas_better_coretype();
    // Idle OpenMP threads sleep at once (passive) only where processes share the node's cores; alone,
    // libgomp's default short spin before sleeping is faster: a goblet on 2 threads 45 s against 54 s,
    // a UNet training step 0.89x (alternating pairs on a 2-core Xeon; docs/vae.md).
    int set_wait = !getenv("OMP_WAIT_POLICY") && !getenv("GOMP_SPINCOUNT") && local_processes() > 1;
    if (!core && !set_wait) return;
    if (core) setenv("OPENBLAS_CORETYPE", core, 1), setenv("MATLABER_BLAS_CHOSEN", "1", 1);
    if (set_wait) setenv("OMP_WAIT_POLICY", "passive", 1);
    setenv("MATLABER_REEXEC", "1", 1);
    execv("/proc/self/exe", argv);   // returns only on failure: carry on as we are
}

// A generation allocates and frees the same large buffers step after step (activations of tens of
// MB). glibc serves those above its mmap threshold (dynamic, at most 32 MB) from fresh mappings and
// gives the top of the heap back beyond 128 KB, so every step pays page faults and zeroing in the
// kernel for memory it had a moment ago. Kept in the heap instead: 0.98x the time of a `tiny`
// goblet on one thread (side by side on a 2-core Xeon). The user's own MALLOC_* / GLIBC_TUNABLES
// settings are kept.
void mlb_runtime_tune_malloc(void) {
    if (getenv("MALLOC_MMAP_THRESHOLD_") || getenv("MALLOC_TRIM_THRESHOLD_") || getenv("GLIBC_TUNABLES")) return;
    mallopt(M_MMAP_THRESHOLD, 256 << 20);
    mallopt(M_TRIM_THRESHOLD, 1 << 30);
}
