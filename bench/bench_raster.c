// Differentiable rasterizer throughput: milliseconds per 512² frame of a procedural noisy sphere
// (~10k and ~100k faces), forward (rasterize, interpolate normals and positions, antialias the
// normal map + mask) and forward + backward (antialias, both interpolations and rasterize
// backward), on 1 and 2 threads, with a per-stage breakdown. Prints tables; docs/raster.md has
// the recorded numbers.
//   build/bench/bench_raster [frames] [mesh: 0 both (default), 1 ~10k only, 2 ~100k only]
#include <math.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/progress.h"
#include "matlaber/raster.h"
#include "matlaber/threads.h"

// Noisy UV sphere: rings of n_lon vertices at n_lat - 1 latitudes plus two poles, faces
// counter-clockwise from outside; area-weighted normals.
static int make_sphere(float** pos_out, float** nrm_out, int32_t** faces_out, int* n_faces, int n_lat, int n_lon) {
    int V = n_lon * (n_lat - 1) + 2, F = 2 * n_lon * (n_lat - 1);
    float* pos = malloc(sizeof(float) * 3 * V);
    float* nrm = calloc(3 * (size_t)V, sizeof(float));
    int32_t* f = malloc(sizeof(int32_t) * 3 * F);
    for (int i = 1; i < n_lat; i++)
        for (int j = 0; j < n_lon; j++) {
            double th = M_PI * i / n_lat, ph = 2 * M_PI * j / n_lon;
            double r = 1 + 0.06 * sin(7 * th + 0.5) * sin(6 * ph) + 0.03 * sin(19 * th) * cos(17 * ph + 1);
            float* p = pos + 3 * ((i - 1) * n_lon + j);
            p[0] = (float)(r * sin(th) * sin(ph)); p[1] = (float)(r * cos(th)); p[2] = (float)(r * sin(th) * cos(ph));
        }
    int top = V - 2, bot = V - 1;
    pos[3 * top] = 0; pos[3 * top + 1] = 1; pos[3 * top + 2] = 0;
    pos[3 * bot] = 0; pos[3 * bot + 1] = -1; pos[3 * bot + 2] = 0;
#define SV(i, j) (((i) - 1) * n_lon + ((j) % n_lon))
    int k = 0;
    for (int j = 0; j < n_lon; j++) {
        int32_t a[6] = {top, SV(1, j), SV(1, j + 1), bot, SV(n_lat - 1, j + 1), SV(n_lat - 1, j)};
        memcpy(f + 3 * k, a, sizeof a);
        k += 2;
    }
    for (int i = 1; i < n_lat - 1; i++)
        for (int j = 0; j < n_lon; j++) {
            int32_t a[6] = {SV(i, j), SV(i + 1, j), SV(i + 1, j + 1), SV(i, j), SV(i + 1, j + 1), SV(i, j + 1)};
            memcpy(f + 3 * k, a, sizeof a);
            k += 2;
        }
#undef SV
    for (int t = 0; t < F; t++) {   // orient outwards, accumulate normals
        float *p0 = pos + 3 * f[3 * t], *p1 = pos + 3 * f[3 * t + 1], *p2 = pos + 3 * f[3 * t + 2];
        double e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]}, e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
        double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        if (n[0] * (p0[0] + p1[0] + p2[0]) + n[1] * (p0[1] + p1[1] + p2[1]) + n[2] * (p0[2] + p1[2] + p2[2]) < 0) {
            int32_t tmp = f[3 * t + 1]; f[3 * t + 1] = f[3 * t + 2]; f[3 * t + 2] = tmp;
            for (int c = 0; c < 3; c++) n[c] = -n[c];
        }
        for (int c = 0; c < 3; c++)
            for (int q = 0; q < 3; q++) nrm[3 * f[3 * t + q] + c] += (float)n[c];
    }
    for (int v = 0; v < V; v++) {
        float* n = nrm + 3 * v;
        float l = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (l > 0) { n[0] /= l; n[1] /= l; n[2] /= l; }
    }
    *pos_out = pos; *nrm_out = nrm; *faces_out = f; *n_faces = F;
    return V;
}

#define CHECK_OK(x) do { if ((x) != MLB_OK) { fprintf(stderr, "bench_raster: %s\n", mlb_last_error()); exit(1); } } while (0)

enum { ST_RAST, ST_INTERP, ST_AA, ST_AA_B, ST_INTERP_B, ST_RAST_B, ST_N };

static int cmp_double(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return (x > y) - (x < y);
}
static double median(double* x, int n) {   // sorts x
    qsort(x, (size_t)n, sizeof *x, cmp_double);
    return n % 2 ? x[n / 2] : 0.5 * (x[n / 2 - 1] + x[n / 2]);
}
static const char* stage_names[ST_N] = {"rasterize", "interpolate x2", "antialias", "antialias bwd", "interpolate bwd x2", "rasterize bwd"};

int main(int argc, char** argv) {
    int frames = argc > 1 ? atoi(argv[1]) : 20, which = argc > 2 ? atoi(argv[2]) : 0;
    if (frames < 1 || which < 0 || which > 2) { fprintf(stderr, "usage: bench_raster [frames] [0|1|2]\n"); return 2; }
    const int H = 512, W = 512;
    size_t n = (size_t)H * W;
    struct { int lat, lon; } sizes[] = {{50, 100}, {160, 320}};
    printf("differentiable rasterizer, %dx%d, noisy sphere at radius 3, fovy 40, median of %d frames (8 azimuths)\n\n", W, H, frames);
    printf("| faces | threads | forward ms | fwd+bwd ms | covered px | blended pairs |\n");
    printf("|------:|--------:|-----------:|-----------:|-----------:|--------------:|\n");
    double stage_ms[2][2][ST_N] = {{{0}}};
    int max_threads = omp_get_max_threads();
    int32_t* tri = malloc(sizeof(int32_t) * n);
    float *bary = malloc(sizeof(float) * 2 * n), *depth = malloc(sizeof(float) * n);
    float *nimg = malloc(sizeof(float) * 3 * n), *pimg = malloc(sizeof(float) * 3 * n);
    float *col = malloc(sizeof(float) * 4 * n), *aa = malloc(sizeof(float) * 4 * n), *wgt = malloc(sizeof(float) * 2 * n);
    float *dout = malloc(sizeof(float) * 4 * n), *dcol = malloc(sizeof(float) * 4 * n);
    float *dn = malloc(sizeof(float) * 3 * n), *dp = malloc(sizeof(float) * 3 * n), *dbary = malloc(sizeof(float) * 2 * n);
    for (size_t i = 0; i < 4 * n; i++) dout[i] = (float)((i * 2654435761u) % 1000) / 1000.0f - 0.5f;
    for (int si = 0; si < 2; si++) {
        if (which && which != si + 1) continue;
        float *pos, *nrm;
        int32_t* faces;
        int F;
        int V = make_sphere(&pos, &nrm, &faces, &F, sizes[si].lat, sizes[si].lon);
        int32_t* adj = malloc(sizeof(int32_t) * 3 * F);
        CHECK_OK(mlb_edge_topology(adj, faces, F, V));   // warm-up
        double t0 = mlb_now_seconds();
        CHECK_OK(mlb_edge_topology(adj, faces, F, V));
        double topo_ms = 1e3 * (mlb_now_seconds() - t0);
        float *clip = malloc(sizeof(float) * 4 * V), *dclip = malloc(sizeof(float) * 4 * V);
        float *dpos = malloc(sizeof(float) * 3 * V), *dnrm = malloc(sizeof(float) * 3 * V);
        mlb_raster_ctx* ctx = mlb_raster_ctx_create();
        for (int ti = 0; ti < 2; ti++) {
            int threads = ti == 0 ? 1 : (max_threads >= 2 ? 2 : 1);
            mlb_set_threads(threads);
            double* per = malloc(sizeof(double) * frames * (ST_N + 2));   // [quantity][frame]
            long covered = 0, blended = 0;
            for (int fr = -2; fr < frames; fr++) {   // two warm-up frames
                mlb_camera cam;
                CHECK_OK(mlb_camera_orbit(&cam, -180 + 45 * ((fr + 8) % 8), 15, 3, NULL, 40, 1, 0.1, 100));
                mlb_transform_points(clip, pos, V, &cam.view_proj);
                double ts[ST_N + 1];
                ts[0] = mlb_now_seconds();
                CHECK_OK(mlb_rasterize(ctx, tri, bary, depth, NULL, clip, V, faces, F, H, W));
                ts[1] = mlb_now_seconds();
                CHECK_OK(mlb_interpolate(nimg, nrm, V, 3, tri, bary, faces, F, H, W));
                CHECK_OK(mlb_interpolate(pimg, pos, V, 3, tri, bary, faces, F, H, W));
                for (size_t p = 0; p < n; p++) {   // [normal, mask]
                    memcpy(col + 4 * p, nimg + 3 * p, 3 * sizeof(float));
                    col[4 * p + 3] = tri[p] >= 0;
                }
                ts[2] = mlb_now_seconds();
                CHECK_OK(mlb_antialias(ctx, aa, wgt, col, 4, tri, depth, clip, V, faces, adj, F, H, W));
                ts[3] = mlb_now_seconds();
                memset(dcol, 0, sizeof(float) * 4 * n);
                memset(dclip, 0, sizeof(float) * 4 * V);
                CHECK_OK(mlb_antialias_backward(ctx, dcol, dclip, dout, wgt, col, 4, tri, depth, clip, V, faces, adj, F, H, W));
                ts[4] = mlb_now_seconds();
                for (size_t p = 0; p < n; p++) {
                    memcpy(dn + 3 * p, dcol + 4 * p, 3 * sizeof(float));
                    for (int c = 0; c < 3; c++) dp[3 * p + c] = 0.1f * dout[4 * p + c];
                }
                memset(dbary, 0, sizeof(float) * 2 * n);
                memset(dpos, 0, sizeof(float) * 3 * V);
                memset(dnrm, 0, sizeof(float) * 3 * V);
                double tb0 = mlb_now_seconds();
                CHECK_OK(mlb_interpolate_backward(ctx, dnrm, dbary, dn, nrm, V, 3, tri, bary, faces, F, H, W));
                CHECK_OK(mlb_interpolate_backward(ctx, dpos, dbary, dp, pos, V, 3, tri, bary, faces, F, H, W));
                ts[5] = mlb_now_seconds();
                CHECK_OK(mlb_rasterize_backward(ctx, dclip, dbary, NULL, tri, clip, V, faces, F, H, W));
                ts[6] = mlb_now_seconds();
                if (fr < 0) continue;
                double st[ST_N] = {ts[1] - ts[0], ts[2] - ts[1], ts[3] - ts[2], ts[4] - ts[3], ts[5] - tb0, ts[6] - ts[5]};
                for (int k = 0; k < ST_N; k++) per[k * frames + fr] = 1e3 * st[k];
                per[ST_N * frames + fr] = 1e3 * (st[ST_RAST] + st[ST_INTERP] + st[ST_AA]);
                per[(ST_N + 1) * frames + fr] = per[ST_N * frames + fr] + 1e3 * (st[ST_AA_B] + st[ST_INTERP_B] + st[ST_RAST_B]);
                for (size_t p = 0; p < n; p++) {
                    covered += tri[p] >= 0;
                    blended += aa[4 * p + 3] != col[4 * p + 3];
                }
            }
            for (int k = 0; k < ST_N; k++) stage_ms[si][ti][k] = median(per + k * frames, frames);
            double fwd = median(per + ST_N * frames, frames), tot = median(per + (ST_N + 1) * frames, frames);
            free(per);
            printf("| %5dk | %7d | %10.2f | %10.2f | %10ld | %13ld |\n", (F + 500) / 1000, threads, fwd, tot,
                   covered / frames, blended / frames);
            fflush(stdout);
        }
        printf("|       | edge topology (once per mesh): %.2f ms for %d faces |\n", topo_ms, F);
        mlb_raster_ctx_free(ctx);
        free(pos); free(nrm); free(faces); free(adj); free(clip); free(dclip); free(dpos); free(dnrm);
    }
    printf("\nper stage, median ms per frame (1 thread / 2 threads; interpolate = normals + positions;\n"
           "the [normal, mask] packing and gradient copies between stages are not counted)\n\n");
    printf("| stage | ~10k faces | ~100k faces |\n|:--|--:|--:|\n");
    for (int k = 0; k < ST_N; k++)
        printf("| %s | %.2f / %.2f | %.2f / %.2f |\n", stage_names[k], stage_ms[0][0][k], stage_ms[0][1][k], stage_ms[1][0][k],
               stage_ms[1][1][k]);
    free(tri); free(bary); free(depth); free(nimg); free(pimg); free(col); free(aa); free(dout); free(dcol); free(dn); free(dp); free(dbary); free(wgt);
    return 0;
}
