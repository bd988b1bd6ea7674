// Environment lighting costs: building the pre-integrated cube map (base cube, mips, GGX prefilter,
// irradiance) at 512^2 and 256^2 faces, computing the split-sum LUT, and split-sum shading
// throughput (points/s), forward and forward + backward, on 1 and 2 threads. Prints a table;
// record results in docs/lighting.md.
//   build/bench/bench_envlight [environment (built-in name or .hdr/.exr path; default sky)]
#include <math.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include "matlaber/envmap.h"
#include "matlaber/progress.h"
#include "matlaber/rng.h"
#include "matlaber/shade.h"

static int fail(void) {
    fprintf(stderr, "bench_envlight: %s\n", mlb_last_error());
    return 1;
}

int main(int argc, char** argv) {
    const char* name = argc > 1 ? argv[1] : "sky";
    mlb_envmap env;
    if (mlb_envmap_open(&env, name, 1.0f, 512, NULL) != MLB_OK) return fail();
    int max_threads = omp_get_max_threads();
    printf("environment %s (%dx%d), %d threads available\n\n", name, env.w, env.h, max_threads);

    printf("| work | threads | seconds |\n|------|--------:|--------:|\n");
    float* lut = malloc((size_t)MLB_LUT_SIZE * MLB_LUT_SIZE * 2 * sizeof(float));
    if (!lut) return 1;
    for (int t = 1; t <= max_threads; t *= 2) {
        omp_set_num_threads(t);
        double t0 = mlb_now_seconds();
        if (mlb_splitsum_lut_compute(lut) != MLB_OK) return fail();
        printf("| split-sum LUT 256x256 (24x16-point quadrature per texel) | %d | %.3f |\n", t, mlb_now_seconds() - t0);
    }
    free(lut);
    omp_set_num_threads(max_threads);
    mlb_envlight light;
    const int faces[2] = {512, 256};
    for (int f = 0; f < 2; f++)
        for (int t = max_threads; t >= 1; t /= 2) {
            if (faces[f] == 512 && t == 1 && max_threads > 1) continue;
            omp_set_num_threads(t);
            mlb_envlight_options o = {.face_size = faces[f]};
            double t0 = mlb_now_seconds();
            if (mlb_envlight_build(&light, &env, &o) != MLB_OK) return fail();
            printf("| environment light %d^2 (cube, %d mips, prefilter, irradiance) | %d | %.3f |\n", faces[f], light.n_levels, t,
                   mlb_now_seconds() - t0);
            mlb_envlight_free(&light);
        }
    omp_set_num_threads(max_threads);
    for (int f = 0; f < 2; f++) {   // the base cube alone (lat-long -> cube resampling)
        float* cube = malloc((size_t)6 * faces[f] * faces[f] * 3 * sizeof(float));
        if (!cube) return 1;
        double t0 = mlb_now_seconds();
        if (mlb_cube_from_envmap(cube, faces[f], &env) != MLB_OK) return fail();
        printf("| of which the base cube %d^2 from the lat-long map | %d | %.3f |\n", faces[f], max_threads, mlb_now_seconds() - t0);
        free(cube);
    }
    {
        mlb_envlight_options o = {.face_size = 256, .exact = 1};
        double t0 = mlb_now_seconds();
        if (mlb_envlight_build(&light, &env, &o) != MLB_OK) return fail();
        double te = mlb_now_seconds() - t0;
        mlb_envlight_free(&light);
        o.exact = 0;
        t0 = mlb_now_seconds();
        if (mlb_envlight_build(&light, &env, &o) != MLB_OK) return fail();
        printf("| environment light 256^2: exact prefilter / tree prefilter | %d | %.3f / %.3f |\n", max_threads, te,
               mlb_now_seconds() - t0);
        mlb_envlight_free(&light);
    }

    // shading throughput
    mlb_envlight_options o = {.face_size = 512};
    if (mlb_envlight_build(&light, &env, &o) != MLB_OK) return fail();
    if (!mlb_splitsum_lut()) return fail();
    // the pixels of a 1024^2 orthographic render of a unit sphere (coherent normals, as in a real
    // frame), with smoothly varying materials
    enum { RES = 1024, NMAX = RES * RES };
    float *kd = malloc(NMAX * 3 * 4), *ks = malloc(NMAX * 3 * 4), *kr = malloc(NMAX * 4), *n = malloc(NMAX * 3 * 4), *v = malloc(NMAX * 3 * 4);
    float *out = malloc(NMAX * 3 * 4), *g = malloc(NMAX * 3 * 4), *gkd = calloc(NMAX * 3, 4), *gks = calloc(NMAX * 3, 4);
    float *gkr = calloc(NMAX, 4), *gn = calloc(NMAX * 3, 4), *gv = calloc(NMAX * 3, 4);
    if (!kd || !ks || !kr || !n || !v || !out || !g || !gkd || !gks || !gkr || !gn || !gv) return 1;
    int N = 0;
    for (int y = 0; y < RES; y++)
        for (int x = 0; x < RES; x++) {
            double px = (x + 0.5) / (RES / 2) - 1, py = 1 - (y + 0.5) / (RES / 2), r2 = px * px + py * py;
            if (r2 >= 1) continue;
            double nn[3] = {px, py, sqrt(1 - r2)};
            for (int k = 0; k < 3; k++) {
                n[3 * N + k] = (float)nn[k], v[3 * N + k] = k == 2 ? 1.0f : 0.0f;
                kd[3 * N + k] = (float)(0.5 + 0.4 * sin(5 * px + k)), ks[3 * N + k] = (float)(0.5 + 0.45 * cos(4 * py + k));
            }
            kr[N] = (float)(0.08 + 0.92 * (0.5 + 0.5 * sin(3 * px) * cos(2 * py)));
            N++;
        }
    mlb_rng_fill_normal(g, (size_t)N * 3, 1, 3, 0, 0, 1);
    printf("\n| shading (512^2 light, %d pixels of a 1024^2 sphere render) | threads | points/s | ns/point |\n|---|--:|--:|--:|\n", N);
    for (int t = 1; t <= max_threads; t *= 2) {
        omp_set_num_threads(t);
        for (int pass = 0; pass < 2; pass++) {
            int reps = 3;
            double t0 = mlb_now_seconds();
            for (int r = 0; r < reps; r++) {
                if (mlb_shade_forward(out, kd, ks, kr, n, v, N, &light, MLB_FRESNEL_PAPER) != MLB_OK) return fail();
                if (pass && mlb_shade_backward(gkd, gks, gkr, gn, gv, g, kd, ks, kr, n, v, N, &light, MLB_FRESNEL_PAPER) != MLB_OK)
                    return fail();
            }
            double dt = (mlb_now_seconds() - t0) / reps;
            printf("| %s | %d | %.3g | %.0f |\n", pass ? "forward + backward" : "forward", t, N / dt, 1e9 * dt / N);
        }
    }
    mlb_envlight_free(&light);
    mlb_envmap_free(&env);
    free(kd), free(ks), free(kr), free(n), free(v), free(out), free(g), free(gkd), free(gks), free(gkr), free(gn), free(gv);
    return 0;
}
