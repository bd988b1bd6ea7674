// Training throughput of the latent BRDF auto-encoder (samples/s) on this machine, for a few
// model sizes and thread counts. Prints a table; record results in docs/benchmarks.md.
//   build/bench/bench_brdf_train [steps]
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include "matlaber/brdf.h"
#include "matlaber/brdf_ae.h"
#include "matlaber/progress.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"

int main(int argc, char** argv) {
    int steps = argc > 1 ? atoi(argv[1]) : 400;
    if (steps < 1) { fprintf(stderr, "usage: bench_brdf_train [steps]\n"); return 2; }
    mlb_brdf_set set = {0};
    int max_threads = omp_get_max_threads();
    for (int threads = 1; threads <= max_threads; threads *= 2) {   // the data generator first
        mlb_set_threads(threads);
        mlb_brdf_set tmp = {0};
        double t0 = mlb_now_seconds();
        if (mlb_brdf_procedural(&tmp, 1000000, 5) != MLB_OK) { fprintf(stderr, "%s\n", mlb_last_error()); return 1; }
        printf("procedural materials: 1e6 samples in %.3f s on %d thread%s\n", mlb_now_seconds() - t0, threads, threads > 1 ? "s" : "");
        mlb_brdf_set_free(&tmp);
    }
    mlb_set_threads(max_threads);
    if (mlb_brdf_procedural(&set, 200000, 1) != MLB_OK) { fprintf(stderr, "%s\n", mlb_last_error()); return 1; }
    struct { int hidden, depth; } sizes[] = {{32, 2}, {64, 2}, {64, 3}, {128, 3}};
    printf("latent BRDF auto-encoder training, batch 256, %d steps per row, full loss (rec + KL + smooth + cyclic)\n", steps);
    printf("OpenBLAS kernels: %s%s\n\n", mlb_blas_corename(),
           mlb_blas_better_coretype() ? " (slow fallback: rerun with OPENBLAS_CORETYPE set, see threads.h)" : "");
    printf("| hidden | depth | params | threads | samples/s | ms/step | 30 epochs of 400k samples |\n");
    printf("|-------:|------:|-------:|--------:|----------:|--------:|--------------------------:|\n");
    for (size_t i = 0; i < sizeof sizes / sizeof *sizes; i++)
        for (int threads = 1; threads <= max_threads; threads *= 2) {
            mlb_set_threads(threads);
            mlb_brdf_ae_config mc = {.hidden = sizes[i].hidden, .depth = sizes[i].depth, .act = MLB_ACT_SILU};
            mlb_brdf_ae ae;
            brdf_ae_init(&ae, &mc, 1);
            mlb_brdf_train_config tc = mlb_brdf_train_default_config();
            tc.epochs = 1;
            tc.encoder_epochs = 0;   // the joint loss's rate; the encoder phase is a cheaper loss
            size_t n = (size_t)steps * tc.batch;
            if (n > set.n) n = set.n;
            double t0 = mlb_now_seconds();
            if (mlb_brdf_ae_train(&ae, set.k, n, &tc, NULL, NULL, NULL) != MLB_OK) { fprintf(stderr, "%s\n", mlb_last_error()); return 1; }
            double dt = mlb_now_seconds() - t0;
            double sps = (double)(n / tc.batch * tc.batch) / dt;
            char eta[32];
            printf("| %6d | %5d | %6zu | %7d | %9.0f | %7.2f | %25s |\n", mc.hidden, mc.depth, ae.n_params, threads, sps,
                   1e3 * dt / (double)(n / tc.batch), mlb_format_duration(30.0 * 400000 / sps, eta, sizeof eta));
            brdf_ae_free(&ae);
        }
    mlb_brdf_set_free(&set);
    return 0;
}
