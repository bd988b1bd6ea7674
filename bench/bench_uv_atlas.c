// UV atlas and baking throughput: unwrap (charts, overlap check, packing) and bake at 1024² (UV
// rasterisation, one batched evaluation of an analytic material, dilation 16) of marching-tets
// meshes (a bumpy torus, the kind of surface the pipeline extracts) of ~10k and ~50k faces, and of
// the real meshes of ../shared/data when present. Prints a table; results in docs/uv_atlas.md.
//   build/bench/bench_uv_atlas [reps]
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include "matlaber/bake.h"
#include "matlaber/dmtet.h"
#include "matlaber/obj.h"
#include "matlaber/uv_atlas.h"

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);   // the machine is shared: CPU time of this (single-threaded) work
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static mlb_status field_fn(void* user, const float* p, size_t n, float* k) {
    (void)user;
    for (size_t i = 0; i < n; i++, p += 3, k += 7) {
        k[0] = 0.5f + 0.4f * sinf(3 * p[0] + 1);
        k[1] = 0.5f + 0.4f * sinf(3 * p[1]);
        k[2] = 0.5f + 0.4f * cosf(3 * p[2]);
        k[3] = k[4] = k[5] = 0.04f;
        k[6] = 0.5f + 0.3f * sinf(2 * p[2]);
    }
    return MLB_OK;
}

static int make_mt_blob(mlb_mesh* m, int cells) {
    mlb_tetgrid g;
    if (mlb_tetgrid_create(&g, cells, 1.0f) != MLB_OK) return 0;
    float* sdf = malloc(sizeof *sdf * g.n_verts);
    for (int i = 0; i < g.n_verts; i++) {
        const float* p = g.verts + 3 * i;
        double q = sqrt((double)p[0] * p[0] + (double)p[2] * p[2]) - 0.27;
        sdf[i] = (float)(sqrt(q * q + (double)p[1] * p[1]) - 0.11 - 0.03 * sin(5 * atan2(p[2], p[0])));
    }
    mlb_mt_surface s;
    int ok = marching_tets_forward(&s, &g, g.verts, sdf) == MLB_OK && mt_surface_to_mesh(&s, m) == MLB_OK;
    if (ok) mt_surface_free(&s);
    free(sdf);
    mlb_tetgrid_free(&g);
    return ok;
}

static void run(const char* name, const mlb_mesh* m, int reps) {
    mlb_uv_options o = mlb_uv_default();
    double t_unwrap = 1e30, t_bake = 1e30;
    mlb_uv_stats st;
    mlb_baked b;
    memset(&b, 0, sizeof b);
    for (int r = 0; r < reps; r++) {
        mlb_uv_mesh u;
        double t0 = now();
        if (mlb_uv_unwrap(m, &o, &u, &st) != MLB_OK) { fprintf(stderr, "%s: %s\n", name, mlb_last_error()); return; }
        double t1 = now();
        mlb_baked_free(&b);
        if (mlb_bake(&u, 1024, field_fn, NULL, MLB_BAKE_DEFAULT_DILATE, &b) != MLB_OK) {
            fprintf(stderr, "%s: %s\n", name, mlb_last_error());
            mlb_uv_mesh_free(&u);
            return;
        }
        double t2 = now();
        if (t1 - t0 < t_unwrap) t_unwrap = t1 - t0;
        if (t2 - t1 < t_bake) t_bake = t2 - t1;
        mlb_uv_mesh_free(&u);
    }
    printf("| %-14s | %6d | %6d | %5d | %5.3f | %6.4f | %6.4f | %8.1f | %8.1f | %7d |\n", name, st.n_faces, st.n_verts,
           st.n_charts, st.utilisation, st.stretch_l2, st.stretch_linf, 1e3 * t_unwrap, 1e3 * t_bake, b.n_covered);
    mlb_baked_free(&b);
}

int main(int argc, char** argv) {
    int reps = argc > 1 ? atoi(argv[1]) : 3;
    if (reps < 1) reps = 1;
    printf("unwrap (defaults: 1024², gutter 4, cone 40°) and bake at 1024² (dilation 16); best of %d\n\n", reps);
    printf("| mesh           |  faces |  verts | charts| util  | L2     | Linf   | unwrap ms| bake ms  | covered |\n");
    printf("|----------------|--------|--------|-------|-------|--------|--------|----------|----------|---------|\n");
    int cells[2] = {30, 66};
    for (int i = 0; i < 2; i++) {
        mlb_mesh m;
        if (!make_mt_blob(&m, cells[i])) { fprintf(stderr, "mesh: %s\n", mlb_last_error()); return 1; }
        char name[64];
        snprintf(name, sizeof name, "mt torus %d", cells[i]);
        run(name, &m, reps);
        mlb_mesh_free(&m);
    }
    const char* dir = getenv("MLB_SHARED_DATA");
#ifdef MLB_SOURCE_DIR
    char base[4096];
    if (!dir) { snprintf(base, sizeof base, "%s/../shared/data", MLB_SOURCE_DIR); dir = base; }
#endif
    const char* rel[2] = {"meshes/spot/spot.obj", "meshes/bob/bob_tri.obj"};
    const char* nm[2] = {"spot", "bob"};
    for (int i = 0; dir && i < 2; i++) {
        char path[4200];
        snprintf(path, sizeof path, "%s/%s", dir, rel[i]);
        struct stat sb;
        if (stat(path, &sb) != 0) continue;
        mlb_mesh m;
        mlb_obj_options oo = {0};
        oo.drop_uv = oo.drop_normals = 1;
        if (mlb_obj_load_ex(path, &m, &oo, NULL) != MLB_OK) continue;
        run(nm[i], &m, reps);
        mlb_mesh_free(&m);
    }
    return 0;
}
