// Throughput of the appearance stage's render (docs/appearance.md): a ~10k-face UV sphere, the
// default material network (latent mode, 16 levels × 2^19 hash grid, 32×2 MLP, the built-in prior's
// decoder) under the built-in sky, 1 and 4 views at 64², 128² and 512² (ss 1).
// Columns: forward (render, keep_for_backward = 1), forward + backward, and a full step
// (zero_grad + forward + backward + Adam update), in ms of wall-clock time and of process CPU time
// (all threads; on a shared machine the CPU time is the honest measure of the work);
// samples = covered pixels of all views.
// Usage: bench_appearance [threads]
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include "matlaber/appearance.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}
// CPU time of the whole process (all threads): the work done, whatever else runs on the machine
static double cpu(void) {
    struct timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

int main(int argc, char** argv) {
    mlb_runtime_restart(argv);   // the program's runtime settings (threads.h)
    char* end = NULL;
    long threads = argc > 1 ? strtol(argv[1], &end, 10) : 0;
    if (argc > 2 || (argc > 1 && (*end || threads < 1 || threads > 1024))) {
        fprintf(stderr, "usage: bench_appearance [threads]\n");
        return 2;
    }
    if (argc > 1) mlb_set_threads((int)threads);
    mlb_mesh mesh;
    mlb_envmap env;
    mlb_envlight light;
    mlb_brdf_ae prior;
    char source[1024];
    mlb_material_net net;
    mlb_material_config c = mlb_material_default();
    if (mlb_mesh_uv_sphere(&mesh, 0.8f, 100, 51) || mlb_envmap_named(&env, "sky", 512) ||
        mlb_envlight_build(&light, &env, &(mlb_envlight_options){0}) || mlb_brdf_ae_load_default(&prior, source, sizeof source) ||
        material_net_init(&net, &c, &prior)) {
        fprintf(stderr, "bench_appearance: setup failed: %s\n", mlb_last_error());
        return 1;
    }
    const mlb_envlight* lights[1] = {&light};
    mlb_adam_config adam = mlb_material_adam(1e-2);
    printf("appearance render: %d faces, %zu material parameters, %d threads, BLAS kernels %s\n", mesh.n_faces, net.n_params,
           mlb_get_threads(), mlb_blas_corename());
    printf("| res | views | samples | forward ms (cpu) | fwd+bwd ms (cpu) | step ms (cpu) |\n|---|---|---|---|---|---|\n");
    static const int sizes[3] = {64, 128, 512}, counts[2] = {1, 4};
    mlb_appearance app;
    memset(&app, 0, sizeof app);
    {   // warm-up: the split-sum LUT is computed on first use
        mlb_view v0;
        memset(&v0, 0, sizeof v0);
        float* img = malloc(sizeof(float) * 64 * 64 * 4);
        mlb_camera_orbit(&v0.cam, 20, 15, 2.5, NULL, 45, 1, 0.1, 100);
        if (!img || mlb_appearance_render(&app, &net, &mesh, lights, &v0, 1, 64, 1, img, 1)) goto fail;
        free(img);
    }
    for (int si = 0; si < 3; si++)
        for (int ci = 0; ci < 2; ci++) {
            int res = sizes[si], n = counts[ci];
            mlb_view views[4];
            for (int v = 0; v < n; v++) {
                memset(&views[v], 0, sizeof views[v]);
                views[v].env_rotation_deg = 90.0f * v;
                mlb_camera_orbit(&views[v].cam, 90.0 * v + 20, 15, 2.5, NULL, 45, 1, 0.1, 100);
            }
            size_t m = (size_t)n * res * res * 4;
            float* img = malloc(sizeof(float) * m);
            float* dimg = malloc(sizeof(float) * m);
            mlb_rng_fill_normal(dimg, m, 1, 0, 0, 0, 1e-3f);
            double t[3] = {0}, tc[3] = {0};
            int reps[3] = {0}, samples = 0;
            for (int kind = 0; kind < 3; kind++) {
                double t0 = now(), c0 = cpu();
                for (int r = 0; r < 20 && (r < 2 || now() - t0 < 2.0); r++) {
                    if (kind == 2) material_net_zero_grad(&net);
                    if (mlb_appearance_render(&app, &net, &mesh, lights, views, n, res, 1, img, 1)) goto fail;
                    if (kind >= 1 && mlb_appearance_backward(&app, &net, dimg)) goto fail;
                    if (kind == 2) material_net_update(&net, &adam);
                    reps[kind]++;
                }
                t[kind] = (now() - t0) / reps[kind] * 1e3;
                tc[kind] = (cpu() - c0) / reps[kind] * 1e3;
            }
            mlb_appearance_points(&app, &samples);
            printf("| %d | %d | %d | %.1f (%.1f) | %.1f (%.1f) | %.1f (%.1f) |\n", res, n, samples, t[0], tc[0], t[1], tc[1], t[2],
                   tc[2]);
            fflush(stdout);
            free(img);
            free(dimg);
        }
    mlb_appearance_free(&app);
    material_net_free(&net);
    brdf_ae_free(&prior);
    mlb_envlight_free(&light);
    mlb_envmap_free(&env);
    mlb_mesh_free(&mesh);
    return 0;
fail:
    fprintf(stderr, "bench_appearance: %s\n", mlb_last_error());
    return 1;
}
