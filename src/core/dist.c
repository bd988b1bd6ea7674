// Several processes (include/matlaber/dist.h): MPI when the build found it (MLB_HAVE_MPI), else
// one process whose collectives are copies.
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "matlaber/dist.h"
#include "matlaber/log.h"
#include "matlaber/progress.h"
#ifdef MLB_HAVE_MPI
#include <mpi.h>
#endif

static int g_started, g_world_rank, g_world_size = 1, g_solo;
static mlb_dist_stats g_stats;

int mlb_dist_built(void) {
#ifdef MLB_HAVE_MPI
    return 1;
#else
    return 0;
#endif
}

const char* mlb_dist_transport(void) { return mlb_dist_built() ? "mpi" : "none"; }

// The process count a launcher announced (mpirun, srun, hydra), 0 when none did.
static long launcher_size(const char** which) {
    static const char* const vars[] = {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE", "MPI_LOCALNRANKS", "SLURM_NTASKS"};
    *which = NULL;
    for (size_t i = 0; i < sizeof vars / sizeof vars[0]; i++) {
        const char* v = getenv(vars[i]);
        if (v && atol(v) > 0) { *which = vars[i]; return atol(v); }
    }
    return 0;
}

mlb_status mlb_dist_init(int* argc, char*** argv) {
    if (g_started) return MLB_OK;
    g_started = 1;
    const char* which = NULL;
    long n = launcher_size(&which);
    // SLURM_NTASKS is also set inside an allocation that runs one task (sbatch, then plain matlaber):
    // it counts only when this process is one of several tasks of a step (srun sets SLURM_STEP_NUM_TASKS)
    if (n > 0 && which && !strcmp(which, "SLURM_NTASKS")) {
        const char* step = getenv("SLURM_STEP_NUM_TASKS");
        if (!step || atol(step) <= 1) n = 0;
    }
#ifdef MLB_HAVE_MPI
    // Only under a launcher: a plain `matlaber` stays a plain process (no MPI singleton start-up,
    // nothing for the sanitizers' leak checker to find in the MPI library)
    if (n < 1 && !getenv("PMIX_RANK") && !getenv("PMI_RANK")) return MLB_OK;
    // FUNNELED: only the main thread talks to MPI (OpenMP threads compute between the calls)
    int provided = 0, inited = 0;
    MPI_Initialized(&inited);
    if (!inited && MPI_Init_thread(argc, argv, MPI_THREAD_FUNNELED, &provided) != MPI_SUCCESS)
        return mlb_fail(MLB_ERR_IO, "MPI_Init failed");
    MPI_Comm_rank(MPI_COMM_WORLD, &g_world_rank);
    MPI_Comm_size(MPI_COMM_WORLD, &g_world_size);
    return MLB_OK;
#else
    (void)argc;
    (void)argv;
    if (n > 1)
        return mlb_fail(MLB_ERR_UNSUPPORTED,
                        "started as one of %ld processes (%s=%ld), but this matlaber was built without MPI: each "
                        "copy would run the whole job alone and they would overwrite each other's run folders. "
                        "Install OpenMPI (scripts/install-deps.sh) and rebuild (scripts/build.sh), or run one process",
                        n, which, n);
    return MLB_OK;
#endif
}

void mlb_dist_finalize(void) {
#ifdef MLB_HAVE_MPI
    int inited = 0, done = 0;
    MPI_Initialized(&inited);
    MPI_Finalized(&done);
    if (inited && !done) MPI_Finalize();
#endif
}

void mlb_dist_abort(int code) {
#ifdef MLB_HAVE_MPI
    int inited = 0;
    MPI_Initialized(&inited);
    if (inited && g_world_size > 1) MPI_Abort(MPI_COMM_WORLD, code);
#endif
    exit(code);
}

int mlb_dist_world_rank(void) { return g_world_rank; }
int mlb_dist_world_size(void) { return g_world_size; }
int mlb_dist_rank(void) { return g_solo ? 0 : g_world_rank; }
int mlb_dist_size(void) { return g_solo ? 1 : g_world_size; }
int mlb_dist_solo(int solo) {
    int was = g_solo;
    g_solo = solo != 0;
    return was;
}
static int collective(void) { return !g_solo && g_world_size > 1; }
#ifdef MLB_HAVE_MPI
// CPU time of this process (MPI busy-polls while it waits: that time is not the stages' work)
static double cpu_now(void) { return (double)clock() / CLOCKS_PER_SEC; }
#endif

void mlb_dist_share_of(int n, int rank, int size, int* first, int* count) {
    if (size < 1) size = 1;
    long a = (long)n * rank / size, b = (long)n * (rank + 1) / size;
    *first = (int)a;
    *count = (int)(b - a);
}

void mlb_dist_share(int n, int* first, int* count) { mlb_dist_share_of(n, mlb_dist_rank(), mlb_dist_size(), first, count); }

void mlb_dist_share_batches_of(int n, int batch, int rank, int size, int* first, int* count) {
    if (batch < 1 || batch > n) batch = n > 0 ? n : 1;
    int nb = (n + batch - 1) / batch, b0, bc;
    mlb_dist_share_of(nb, rank, size, &b0, &bc);
    long a = (long)b0 * batch, e = (long)(b0 + bc) * batch;   // the last batch may be short
    if (a > n) a = n;
    if (e > n) e = n;
    *first = (int)a;
    *count = (int)(e - a);
}

void mlb_dist_share_batches(int n, int batch, int* first, int* count) {
    mlb_dist_share_batches_of(n, batch, mlb_dist_rank(), mlb_dist_size(), first, count);
}

mlb_dist_stats mlb_dist_stats_get(void) { return g_stats; }
void mlb_dist_stats_reset(void) { memset(&g_stats, 0, sizeof g_stats); }

mlb_status mlb_dist_allgatherv(const void* mine, void* all, const size_t* bytes) {
    int rank = mlb_dist_rank();
    size_t off = 0;
    for (int r = 0; r < rank; r++) off += bytes[r];
    if (!collective()) {
        if (bytes[0] && (const char*)all != (const char*)mine) memmove(all, mine, bytes[0]);
        return MLB_OK;
    }
#ifdef MLB_HAVE_MPI
    int size = mlb_dist_size();
    double t0 = mlb_now_seconds(), c0 = cpu_now();
    int* counts = malloc(sizeof(int) * 2 * (size_t)size);
    if (!counts) return mlb_fail(MLB_ERR_NOMEM, "allgather: out of memory");
    int* displs = counts + size;
    size_t total = 0;
    for (int r = 0; r < size; r++) {
        if (bytes[r] > INT_MAX || total > INT_MAX) { free(counts); return mlb_fail(MLB_ERR_UNSUPPORTED, "allgather: over 2 GB"); }
        counts[r] = (int)bytes[r];
        displs[r] = (int)total;
        total += bytes[r];
    }
    // in place: this rank's block already sits in all
    if ((const char*)all + off != (const char*)mine && bytes[rank]) memmove((char*)all + off, mine, bytes[rank]);
    int rc = MPI_Allgatherv(MPI_IN_PLACE, 0, MPI_BYTE, all, counts, displs, MPI_BYTE, MPI_COMM_WORLD);
    free(counts);
    g_stats.seconds += mlb_now_seconds() - t0;
    g_stats.cpu_seconds += cpu_now() - c0;
    g_stats.bytes += total - bytes[rank];
    g_stats.calls++;
    return rc == MPI_SUCCESS ? MLB_OK : mlb_fail(MLB_ERR_IO, "MPI_Allgatherv failed (%d)", rc);
#else
    return MLB_OK;
#endif
}

mlb_status mlb_dist_allgather_batches(const void* mine, void* all, int n, int batch, size_t item_bytes) {
    int size = mlb_dist_size();
    size_t stack[16] = {0}, *bytes = size <= 16 ? stack : malloc(sizeof(size_t) * (size_t)size);
    if (!bytes) return mlb_fail(MLB_ERR_NOMEM, "allgather: out of memory");
    for (int r = 0; r < size; r++) {
        int f, c;
        mlb_dist_share_batches_of(n, batch, r, size, &f, &c);
        bytes[r] = (size_t)c * item_bytes;
    }
    mlb_status s = mlb_dist_allgatherv(mine, all, bytes);
    if (bytes != stack) free(bytes);
    return s;
}

// batches of 1 are shared as items are
mlb_status mlb_dist_allgather_items(const void* mine, void* all, int n, size_t item_bytes) {
    return mlb_dist_allgather_batches(mine, all, n, 1, item_bytes);
}

// out[i] = v_0[i] + v_1[i] + ... in that order, element by element (the same on any thread count)
static void sum_in_order(float* out, const float* v, size_t stride, size_t len, int nb) {
#pragma omp parallel for schedule(static) if (len > 65536)
    for (size_t i = 0; i < len; i++) {
        float acc = v[i];
        for (int b = 1; b < nb; b++) acc += v[(size_t)b * stride + i];
        out[i] = acc;
    }
}

mlb_status mlb_dist_sum_batches(const float* mine, float* out, size_t len, int nb) {
    if (nb < 1 || !len) return MLB_OK;
    if (!collective()) {   // every batch is here: v_b = mine + b · len
        sum_in_order(out, mine, len, len, nb);
        return MLB_OK;
    }
    int size = mlb_dist_size(), rank = mlb_dist_rank(), b0, bc;
    mlb_dist_share_of(nb, rank, size, &b0, &bc);
    size_t slice = len < MLB_DIST_SUM_SLICE ? len : MLB_DIST_SUM_SLICE;
    float* all = malloc(sizeof(float) * slice * (size_t)nb);   // [nb, slice]: every batch's slice
    size_t* bytes = malloc(sizeof(size_t) * (size_t)size);
    if (!all || !bytes) { free(all); free(bytes); return mlb_fail(MLB_ERR_NOMEM, "gradient sum: out of memory (%d batches)", nb); }
    mlb_status s = MLB_OK;
    for (size_t a = 0; !s && a < len; a += slice) {
        size_t m = len - a < slice ? len - a : slice;
        for (int r = 0; r < size; r++) {
            int f, c;
            mlb_dist_share_of(nb, r, size, &f, &c);
            bytes[r] = sizeof(float) * m * (size_t)c;
        }
        // this rank's slices, packed [bc, m] at its batches' place (read before out's slice is written)
        for (int j = 0; j < bc; j++) memcpy(all + (size_t)(b0 + j) * m, mine + (size_t)j * len + a, sizeof(float) * m);
        s = mlb_dist_allgatherv(all + (size_t)b0 * m, all, bytes);
        if (!s) sum_in_order(out + a, all, m, m, nb);
    }
    free(all);
    free(bytes);
    return s;
}

mlb_status mlb_dist_bcast(void* buf, size_t bytes, int root) {
    if (!collective() || !bytes) return MLB_OK;
#ifdef MLB_HAVE_MPI
    if (bytes > INT_MAX) return mlb_fail(MLB_ERR_UNSUPPORTED, "broadcast: over 2 GB");
    double t0 = mlb_now_seconds(), c0 = cpu_now();
    int rc = MPI_Bcast(buf, (int)bytes, MPI_BYTE, root, MPI_COMM_WORLD);
    g_stats.seconds += mlb_now_seconds() - t0;
    g_stats.cpu_seconds += cpu_now() - c0;
    if (g_world_rank != root) g_stats.bytes += bytes;
    g_stats.calls++;
    return rc == MPI_SUCCESS ? MLB_OK : mlb_fail(MLB_ERR_IO, "MPI_Bcast failed (%d)", rc);
#else
    (void)buf;
    (void)root;
    return MLB_OK;
#endif
}

int mlb_dist_max_int(int v) {
    if (!collective()) return v;
#ifdef MLB_HAVE_MPI
    double t0 = mlb_now_seconds(), c0 = cpu_now();
    int out = v;
    MPI_Allreduce(&v, &out, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
    g_stats.seconds += mlb_now_seconds() - t0;
    g_stats.cpu_seconds += cpu_now() - c0;
    g_stats.bytes += sizeof(int) * (size_t)(g_world_size - 1);
    g_stats.calls++;
    return out;
#else
    return v;
#endif
}

mlb_status mlb_dist_barrier(void) {
    if (!collective()) return MLB_OK;
#ifdef MLB_HAVE_MPI
    return MPI_Barrier(MPI_COMM_WORLD) == MPI_SUCCESS ? MLB_OK : mlb_fail(MLB_ERR_IO, "MPI_Barrier failed");
#else
    return MLB_OK;
#endif
}
