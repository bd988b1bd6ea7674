// Geometry throughput: DMTet tet-grid creation, marching tets (forward, backward) and the SDF
// regulariser on a sphere SDF at several grid sizes, and the hash-grid encoding (default
// Instant-NGP config) forward and forward+backward in points/s. Prints tables; results are
// recorded in docs/geometry.md.
//   build/bench/bench_geometry [reps]
#include <math.h>
#include <omp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/dmtet.h"
#include "matlaber/hashgrid.h"
#include "matlaber/progress.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"

// For comparison only: the table gradient parallel over points with atomic adds (not
// deterministic: the summation order depends on the schedule).
static void backward_atomic(const mlb_hashgrid* g, float* dtable, const float* dout, const float* x, int N) {
    const int L = g->cfg.n_levels, F = g->cfg.n_features, D = g->out_dim;
#pragma omp parallel for schedule(static)
    for (int i = 0; i < N; i++)
        for (int l = 0; l < L; l++) {
            float s = (float)g->scale[l], t[3];
            uint32_t base[3];
            for (int d = 0; d < 3; d++) {
                float p = s * x[3 * (size_t)i + d] + 0.5f, fl = floorf(p);
                base[d] = (uint32_t)fl;
                t[d] = p - fl;
            }
            for (int k = 0; k < 8; k++) {
                uint32_t pos[3] = {base[0] + (k & 1), base[1] + ((k >> 1) & 1), base[2] + ((k >> 2) & 1)};
                float w = ((k & 1) ? t[0] : 1 - t[0]) * (((k >> 1) & 1) ? t[1] : 1 - t[1]) * (((k >> 2) & 1) ? t[2] : 1 - t[2]);
                float* e = dtable + (g->offset[l] + mlb_hashgrid_index(pos, g->res[l], g->level_size[l], g->dense[l])) * F;
                for (int f = 0; f < F; f++) {
#pragma omp atomic
                    e[f] += w * dout[(size_t)i * D + l * F + f];
                }
            }
        }
}

// For comparison only: point-parallel over a fixed number of shards, each scattering into its own
// partial table (zeroed first), the partials then summed in shard order (deterministic for any
// thread count, at the cost of shards x the table in memory).
#define SHARDS 2
static void backward_sharded(const mlb_hashgrid* g, float* dtable, float** part, const float* dout, const float* x, int N) {
    const int L = g->cfg.n_levels, F = g->cfg.n_features, D = g->out_dim;
    const size_t P = g->n_params;
#pragma omp parallel for schedule(static)
    for (int sh = 0; sh < SHARDS; sh++) {
        memset(part[sh], 0, sizeof(float) * P);
        for (int i = (int)((int64_t)N * sh / SHARDS); i < (int)((int64_t)N * (sh + 1) / SHARDS); i++)
            for (int l = 0; l < L; l++) {
                float s = (float)g->scale[l], t[3];
                uint32_t base[3];
                for (int d = 0; d < 3; d++) {
                    float p = s * x[3 * (size_t)i + d] + 0.5f, fl = floorf(p);
                    base[d] = (uint32_t)fl;
                    t[d] = p - fl;
                }
                for (int k = 0; k < 8; k++) {
                    uint32_t pos[3] = {base[0] + (k & 1), base[1] + ((k >> 1) & 1), base[2] + ((k >> 2) & 1)};
                    float w = ((k & 1) ? t[0] : 1 - t[0]) * (((k >> 1) & 1) ? t[1] : 1 - t[1]) * (((k >> 2) & 1) ? t[2] : 1 - t[2]);
                    float* e = part[sh] + (g->offset[l] + mlb_hashgrid_index(pos, g->res[l], g->level_size[l], g->dense[l])) * F;
                    for (int f = 0; f < F; f++) e[f] += w * dout[(size_t)i * D + l * F + f];
                }
            }
    }
#pragma omp parallel for schedule(static)
    for (size_t j = 0; j < P; j++) {
        float acc = dtable[j];
        for (int sh = 0; sh < SHARDS; sh++) acc += part[sh][j];
        dtable[j] = acc;
    }
}

#define DIE() do { fprintf(stderr, "%s\n", mlb_last_error()); return 1; } while (0)

int main(int argc, char** argv) {
    int reps = argc > 1 ? atoi(argv[1]) : 5;
    if (reps < 1) { fprintf(stderr, "usage: bench_geometry [reps]\n"); return 2; }
    int max_threads = omp_get_max_threads();
    printf("marching tets on a sphere SDF (r 0.6, grid scale 2.1), best of %d\n\n", reps);
    printf("| cells/axis | grid verts | tets | threads | grid create ms | MT forward ms | MT backward ms | SDF reg fwd+bwd ms | surface verts | faces |\n");
    printf("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    int cells_list[] = {32, 64, 128};
    for (int ci = 0; ci < 3; ci++)
        for (int threads = 1; threads <= max_threads; threads *= 2) {
            mlb_set_threads(threads);
            int cells = cells_list[ci];
            mlb_tetgrid g;
            double t0 = mlb_now_seconds();
            if (mlb_tetgrid_create(&g, cells, 2.1f) != MLB_OK) DIE();
            double t_create = mlb_now_seconds() - t0;
            float* sdf = malloc(sizeof(float) * g.n_verts);
            float* dsdf = calloc(g.n_verts, sizeof(float));
            float* dpos = calloc(3 * (size_t)g.n_verts, sizeof(float));
            for (int v = 0; v < g.n_verts; v++) {
                const float* p = g.verts + 3 * (size_t)v;
                sdf[v] = sqrtf(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) - 0.6f;
            }
            double best_f = 1e30, best_b = 1e30, best_r = 1e30;
            mlb_mt_surface s = {0};
            for (int r = 0; r < reps; r++) {
                mt_surface_free(&s);
                t0 = mlb_now_seconds();
                if (marching_tets_forward(&s, &g, g.verts, sdf) != MLB_OK) DIE();
                double t1 = mlb_now_seconds();
                float* dv = malloc(sizeof(float) * 3 * (size_t)(s.n_verts ? s.n_verts : 1));
                for (size_t i = 0; i < 3 * (size_t)s.n_verts; i++) dv[i] = 1e-3f;
                double t2 = mlb_now_seconds();
                marching_tets_backward(dpos, dsdf, &s, g.verts, sdf, dv);
                double t3 = mlb_now_seconds();
                float loss = sdf_reg_forward(&g, sdf);
                sdf_reg_backward(dsdf, &g, sdf, loss > 0 ? 1.f : 1.f);
                double t4 = mlb_now_seconds();
                free(dv);
                if (t1 - t0 < best_f) best_f = t1 - t0;
                if (t3 - t2 < best_b) best_b = t3 - t2;
                if (t4 - t3 < best_r) best_r = t4 - t3;
            }
            printf("| %d | %d | %d | %d | %.1f | %.2f | %.3f | %.2f | %d | %d |\n", cells, g.n_verts, g.n_tets, threads,
                   1e3 * t_create, 1e3 * best_f, 1e3 * best_b, 1e3 * best_r, s.n_verts, s.n_faces);
            fflush(stdout);
            mt_surface_free(&s);
            free(sdf); free(dsdf); free(dpos);
            mlb_tetgrid_free(&g);
        }

    mlb_hashgrid_config cfg = mlb_hashgrid_default();
    mlb_hashgrid hg;
    if (hashgrid_init(&hg, &cfg, NULL) != MLB_OK) DIE();
    float* table = malloc(sizeof(float) * hg.n_params);
    float* dtable = calloc(hg.n_params, sizeof(float));
    hg.params = table;
    hashgrid_init_params(&hg, 1);
    float* part[SHARDS];
    for (int sh = 0; sh < SHARDS; sh++) part[sh] = malloc(sizeof(float) * hg.n_params);
    printf("\nhash-grid encoding, 16 levels x 2 features, 2^19 entries, base 16 (%zu parameters), best of %d;\n"
           "backward = table gradient (+ input gradient in the last column), table zeroing not included\n\n",
           hg.n_params, reps);
    printf("| points | threads | forward Mpts/s | fwd+bwd(table) Mpts/s | fwd+bwd(table+x) Mpts/s | table bwd alone Mpts/s | atomic table bwd Mpts/s (non-deterministic) | 2-shard partial tables bwd Mpts/s |\n");
    printf("|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    int npts[] = {1 << 16, 1 << 18};
    for (int ni = 0; ni < 2; ni++) {
        int N = npts[ni];
        float* x = malloc(sizeof(float) * 3 * (size_t)N);
        float* out = malloc(sizeof(float) * (size_t)N * hg.out_dim);
        float* dout = malloc(sizeof(float) * (size_t)N * hg.out_dim);
        float* dx = calloc(3 * (size_t)N, sizeof(float));
        mlb_rng_fill_uniform(x, 3 * (size_t)N, 2, 1, 0, 0.f, 1.f);
        mlb_rng_fill_normal(dout, (size_t)N * hg.out_dim, 2, 2, 0, 0.f, 1.f);
        for (int threads = 1; threads <= max_threads; threads *= 2) {
            mlb_set_threads(threads);
            double bf = 1e30, bb = 1e30, bx = 1e30, bt = 1e30, ba = 1e30, bs = 1e30;
            for (int r = 0; r < reps; r++) {
                double t0 = mlb_now_seconds();
                hashgrid_forward(&hg, out, x, N);
                double t1 = mlb_now_seconds();
                hashgrid_backward(&hg, dtable, NULL, dout, x, N);
                double t2 = mlb_now_seconds();
                hashgrid_backward(&hg, dtable, dx, dout, x, N);
                double t3 = mlb_now_seconds();
                if (t1 - t0 < bf) bf = t1 - t0;
                if (t2 - t0 < bb) bb = t2 - t0;
                if ((t1 - t0) + (t3 - t2) < bx) bx = (t1 - t0) + (t3 - t2);
                if (t2 - t1 < bt) bt = t2 - t1;
                double t4 = mlb_now_seconds();
                backward_atomic(&hg, dtable, dout, x, N);
                double t5 = mlb_now_seconds();
                if (t5 - t4 < ba) ba = t5 - t4;
                backward_sharded(&hg, dtable, part, dout, x, N);
                double t6 = mlb_now_seconds();
                if (t6 - t5 < bs) bs = t6 - t5;
            }
            printf("| 2^%d | %d | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f |\n", ni ? 18 : 16, threads, N / bf / 1e6, N / bb / 1e6,
                   N / bx / 1e6, N / bt / 1e6, N / ba / 1e6, N / bs / 1e6);
            fflush(stdout);
        }
        free(x); free(out); free(dout); free(dx);
    }
    for (int sh = 0; sh < SHARDS; sh++) free(part[sh]);
    free(table);
    free(dtable);
    return 0;
}
