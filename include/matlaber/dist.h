// Several processes on one asset or on many (docs/pipeline.md, "Many processes"): the one seam
// between the library and MPI. The stages call these, never MPI itself; a build without MPI gets
// single-process versions (rank 0 of 1, every collective a copy), so the code paths are the same.
//
// How a step is shared: its n views are cut into micro-batches of a fixed size set by the run's
// config (the guidance is called once per batch), and the batches into contiguous blocks, one per
// rank in rank order (mlb_dist_share_batches). Each rank renders and guides its batches; the
// per-view pieces (geometry: gradients at the narrowest point of the chain) and the per-batch losses
// are gathered to every rank in view order (mlb_dist_allgatherv) and summed there in view order, or
// (appearance) each batch's parameter gradient is summed in batch order on every rank
// (mlb_dist_sum_batches), so the sum is the same float for any number of ranks, and every rank then
// takes the same optimiser step.
//
// A "solo" section (mlb_dist_solo) makes the calling rank a group of one: `--prompts` runs one
// whole asset per rank that way.
#ifndef MATLABER_DIST_H
#define MATLABER_DIST_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/error.h"

// Starts MPI when the program was built with it (1 when it was: mlb_dist_built). Without MPI,
// a launcher that started several copies (OMPI_COMM_WORLD_SIZE, PMI_SIZE, PMIX_SIZE or
// SLURM_NTASKS > 1 in the environment) is MLB_ERR_UNSUPPORTED with a message that says so: N
// copies of one run would each write the same folder. Safe to call once; mlb_dist_finalize at exit.
mlb_status mlb_dist_init(int* argc, char*** argv);
void mlb_dist_finalize(void);
// Ends every rank with exit status code (MPI_Abort; exit(code) without MPI).
void mlb_dist_abort(int code);
int mlb_dist_built(void);          // 1: built with MPI
const char* mlb_dist_transport(void);   // "mpi", "mpi+nccl" or "none"

// The current group (the world, or the calling rank alone inside mlb_dist_solo).
int mlb_dist_rank(void);
int mlb_dist_size(void);
int mlb_dist_world_rank(void);
int mlb_dist_world_size(void);
// solo = 1: until solo = 0 the calling rank is a group of one (rank 0 of 1): collectives copy.
// Returns the state before, so that sections nest: int was = mlb_dist_solo(1); ...; mlb_dist_solo(was);
// (--init auto shares its candidates out inside a run that --prompts already made solo).
int mlb_dist_solo(int solo);

// Rank r's share of n items: [*first, *first + *count), contiguous, in rank order, sizes within 1.
void mlb_dist_share_of(int n, int rank, int size, int* first, int* count);
void mlb_dist_share(int n, int* first, int* count);   // this rank's, in the current group
// Rank r's share of n items handed out in whole batches: the items cut into batches of `batch`
// (the last one shorter when batch does not divide n; batch < 1 or >= n: one batch of all n), the
// batches shared as mlb_dist_share_of shares items. [*first, *first + *count): whole batches,
// contiguous, in rank order; none when the rank is left without a batch (fewer batches than ranks).
void mlb_dist_share_batches_of(int n, int batch, int rank, int size, int* first, int* count);
void mlb_dist_share_batches(int n, int batch, int* first, int* count);   // this rank's

// Every rank's block of bytes[r] bytes, concatenated in rank order into all (every rank gets all
// of it). mine holds this rank's bytes[rank] bytes (may alias its place in all).
mlb_status mlb_dist_allgatherv(const void* mine, void* all, const size_t* bytes);
// The same where rank r's block is items [first_r, first_r + count_r) of n items of item_bytes
// each, shared as mlb_dist_share_of shares them: all [n · item_bytes], in item order.
mlb_status mlb_dist_allgather_items(const void* mine, void* all, int n, size_t item_bytes);
// The same for items shared in batches as mlb_dist_share_batches_of shares them.
mlb_status mlb_dist_allgather_batches(const void* mine, void* all, int n, int batch, size_t item_bytes);
// The sum of nb vectors of len floats, one per batch, the batches shared over the ranks as
// mlb_dist_share_of shares nb items: mine [count · len] holds this rank's batches' vectors in batch
// order (NULL or anything when it holds none). out [len] = v_0 + v_1 + ... + v_{nb-1}, added left to
// right (out = v_0 when nb = 1), so the sum is the same float on every rank for any number of ranks.
// The vectors travel in slices of at most MLB_DIST_SUM_SLICE floats each (scratch: nb slices), so
// the memory does not grow with len. out may be mine (this rank's first vector).
#define MLB_DIST_SUM_SLICE ((size_t)1 << 20)
mlb_status mlb_dist_sum_batches(const float* mine, float* out, size_t len, int nb);
mlb_status mlb_dist_bcast(void* buf, size_t bytes, int root);
// The largest of every rank's value (status codes: nonzero anywhere is nonzero everywhere).
int mlb_dist_max_int(int v);
mlb_status mlb_dist_barrier(void);

// Time spent in and bytes received by the collectives above since the last reset (this rank).
typedef struct { double seconds, cpu_seconds; uint64_t bytes; long calls; } mlb_dist_stats;   // cpu: this process's CPU time inside them
mlb_dist_stats mlb_dist_stats_get(void);
void mlb_dist_stats_reset(void);

#endif
