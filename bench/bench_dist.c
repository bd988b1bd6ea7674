// The collectives of dist.h alone (docs/benchmarks.md, "Several processes"): the time of an
// allgather of B bytes in all, cut evenly among the processes, as a step's pieces are.
// Usage: mpirun -n 2 build/bench/bench_dist [BYTES ...]   (default 48000 and 470000: the tiny
// preset's geometry and appearance steps)
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/dist.h"
#include "matlaber/progress.h"

static int cmp_double(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return x < y ? -1 : x > y;
}

int main(int argc, char** argv) {
    if (mlb_dist_init(&argc, &argv)) { fprintf(stderr, "%s\n", mlb_last_error()); return 1; }
    long sizes[16] = {48000, 470000};
    int ns = 2;
    if (argc > 1) { ns = 0; for (int i = 1; i < argc && ns < 16; i++) sizes[ns++] = atol(argv[i]); }
    enum { REPS = 200 };
    for (int k = 0; k < ns; k++) {
        int n = 1000;   // items of B / n bytes each, shared as views are
        size_t item = (size_t)(sizes[k] / n > 0 ? sizes[k] / n : 1);
        char* all = calloc((size_t)n, item);
        int f, c;
        mlb_dist_share(n, &f, &c);
        double t[REPS];
        for (int r = 0; r < REPS; r++) {
            mlb_dist_barrier();
            double t0 = mlb_now_seconds();
            mlb_dist_allgather_items(all + item * (size_t)f, all, n, item);
            t[r] = mlb_now_seconds() - t0;
        }
        qsort(t, REPS, sizeof t[0], cmp_double);
        if (mlb_dist_rank() == 0)
            printf("allgather of %zu bytes over %d processes: median %.1f us, min %.1f us (%d repeats)\n", item * (size_t)n,
                   mlb_dist_size(), 1e6 * t[REPS / 2], 1e6 * t[0], REPS);
        free(all);
    }
    mlb_dist_finalize();
    return 0;
}
