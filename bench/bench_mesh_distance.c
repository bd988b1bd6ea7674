// Point-to-mesh distance: the brute force the library had before its BVH (every triangle, skipped
// by its bounding box, starting from the previous point's nearest) against mlb_mesh_distance (a
// BVH built per call) for a few sizes, then the shape part of a `bench text3d` measure (88
// Chamfer distances, 2000 samples a side) done four ways, and one whole mlb_text3d_measure.
// Every way must give the same bits; the tables say so. Wall seconds (best of the repeats) and the
// process's CPU seconds (all threads), which tell a busy machine from a slow program. Prints tables;
// docs/benchmarks.md has the recorded numbers. Runs as `matlaber` does (mlb_runtime_restart:
// OMP_WAIT_POLICY=passive unless set, so idle threads sleep instead of spinning).
//   build/bench/bench_mesh_distance [--quick]   (--quick: no brute-force text3d row, ~20 s less)
#include <math.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "matlaber/catalogue.h"
#include "matlaber/envmap.h"
#include "matlaber/geometry.h"
#include "matlaber/progress.h"
#include "matlaber/text3d.h"
#include "matlaber/threads.h"

static double cpu_now(void) {
    struct timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

// ---- the brute force before the BVH (src/geometry/shape_init.c at f1866d5, same distance) ----
static void brute_distance(const mlb_mesh* m, const float* p, float* out, int n) {
    int F = m->n_faces;
    float* box = malloc(sizeof(float) * 6 * (size_t)(F > 0 ? F : 1));   // per-triangle [lo3, hi3]
    if (!box) { for (int i = 0; i < n; i++) out[i] = INFINITY; return; }
    for (int f = 0; f < F; f++) {
        const int32_t* t = m->faces + 3 * f;
        for (int k = 0; k < 3; k++) {
            float a = m->pos[3 * t[0] + k], b = m->pos[3 * t[1] + k], c = m->pos[3 * t[2] + k];
            box[6 * f + k] = fminf(a, fminf(b, c));
            box[6 * f + 3 + k] = fmaxf(a, fmaxf(b, c));
        }
    }
    int hint = 0;
#pragma omp parallel for schedule(dynamic, 64) firstprivate(hint)
    for (int i = 0; i < n; i++) {
        double q[3] = {p[3 * i], p[3 * i + 1], p[3 * i + 2]};
        double best = F > 0 ? mlb_point_triangle_dist2(q, m->pos + 3 * m->faces[3 * hint], m->pos + 3 * m->faces[3 * hint + 1],
                                                        m->pos + 3 * m->faces[3 * hint + 2])
                            : INFINITY;
        for (int f = 0; f < F; f++) {
            const float* bx = box + 6 * f;
            double e2 = 0;
            for (int k = 0; k < 3; k++) {
                double e = q[k] < bx[k] ? bx[k] - q[k] : (q[k] > bx[3 + k] ? q[k] - bx[3 + k] : 0);
                e2 += e * e;
            }
            if (e2 >= best) continue;
            const int32_t* t = m->faces + 3 * f;
            double d2 = mlb_point_triangle_dist2(q, m->pos + 3 * t[0], m->pos + 3 * t[1], m->pos + 3 * t[2]);
            if (d2 < best) { best = d2; hint = f; }
        }
        out[i] = (float)sqrt(best);
    }
    free(box);
}

// mlb_chamfer with the brute force (chamfer.c's arithmetic)
static void brute_chamfer(const mlb_mesh* a, const mlb_mesh* b, int n, uint64_t seed, mlb_chamfer_result* r) {
    float* p = malloc(sizeof(float) * 3 * (size_t)n);
    float* d = malloc(sizeof(float) * (size_t)n);
    const mlb_mesh* from[2] = {a, b};
    const mlb_mesh* to[2] = {b, a};
    double mean[2], mx[2];
    for (int side = 0; side < 2; side++) {
        mlb_mesh_sample_surface(from[side], p, n, seed, side ? 0xC4A2 : 0xC4A1);
        brute_distance(to[side], p, d, n);
        double sum = 0, m = 0;
        for (int i = 0; i < n; i++) { sum += d[i]; if (d[i] > m) m = d[i]; }
        mean[side] = sum / n;
        mx[side] = m;
    }
    r->a_to_b = mean[0]; r->max_a_to_b = mx[0];
    r->b_to_a = mean[1]; r->max_b_to_a = mx[1];
    r->chamfer = 0.5 * (r->a_to_b + r->b_to_a);
    float lo[3], hi[3];
    mlb_mesh_bounds(b, lo, hi);
    double d2 = 0;
    for (int k = 0; k < 3; k++) d2 += ((double)hi[k] - lo[k]) * ((double)hi[k] - lo[k]);
    r->diag = sqrt(d2);
    r->relative = r->diag > 0 ? r->chamfer / r->diag : INFINITY;
    free(p);
    free(d);
}

static void cpu_model(char* out, size_t cap) {
    snprintf(out, cap, "unknown");
    FILE* f = fopen("/proc/cpuinfo", "r");
    if (!f) return;
    char line[512];
    while (fgets(line, sizeof line, f))
        if (!strncmp(line, "model name", 10)) {
            char* v = strchr(line, ':');
            if (v) { v += 1 + (v[1] == ' '); v[strcspn(v, "\n")] = 0; snprintf(out, cap, "%s", v); }
            break;
        }
    fclose(f);
}

#define DIE() do { fprintf(stderr, "%s\n", mlb_last_error()); return 1; } while (0)

int main(int argc, char** argv) {
    mlb_runtime_restart(argv);
    int quick = argc > 1 && !strcmp(argv[1], "--quick");
    char cpu[256], load[64] = "?";
    cpu_model(cpu, sizeof cpu);
    FILE* lf = fopen("/proc/loadavg", "r");
    if (lf) { if (fgets(load, sizeof load, lf)) load[strcspn(load, "\n")] = 0; fclose(lf); }
    const char* wait = getenv("OMP_WAIT_POLICY");
    printf("CPU: %s; %d OpenMP threads, OMP_WAIT_POLICY=%s; load average at start: %s\n\n", cpu, omp_get_max_threads(),
           wait ? wait : "(unset)", load);

    // ---- mlb_mesh_distance against the brute force ----
    // targets: UV spheres of radius 0.8 and a catalogue goblet; points: area-uniform samples of a
    // catalogue mug (radius 0.9), as a Chamfer distance draws them
    int mug_class, goblet_class;
    if (mlb_catalogue_class_parse("mug", &mug_class) || mlb_catalogue_class_parse("goblet", &goblet_class)) DIE();
    mlb_mesh mug;
    if (mlb_catalogue_mesh(mug_class, 0, &mug)) DIE();
    struct { const char* name; int seg, rings, n; } rows[] = {
        {"sphere", 32, 16, 2000},  {"sphere", 64, 32, 2000},   {"goblet", 0, 0, 2000},      {"sphere", 128, 64, 2000},
        {"sphere", 256, 128, 2000}, {"goblet", 0, 0, 20000},   {"sphere", 128, 64, 100000},
    };
    printf("| target | faces | points | brute force | BVH build | BVH query | mlb_mesh_distance (build + query) | speed-up | CPU: brute, BVH | same bits |\n");
    printf("|---|---|---|---|---|---|---|---|---|---|\n");
    for (size_t r = 0; r < sizeof rows / sizeof *rows; r++) {
        mlb_mesh m;
        if (rows[r].seg ? mlb_mesh_uv_sphere(&m, 0.8f, rows[r].seg, rows[r].rings) : mlb_catalogue_mesh(goblet_class, 0, &m)) DIE();
        int n = rows[r].n;
        float* p = malloc(sizeof(float) * 3 * (size_t)n);
        float* d0 = malloc(sizeof(float) * (size_t)n);
        float* d1 = malloc(sizeof(float) * (size_t)n);
        if (!p || !d0 || !d1 || mlb_mesh_sample_surface(&mug, p, n, 7, 0xC4A1)) DIE();
        double brute = 1e30, build = 1e30, query = 1e30, total = 1e30, cpu_brute = 0, cpu_total = 0;
        for (int rep = 0; rep < 3; rep++) {
            double c0 = cpu_now(), t0 = mlb_now_seconds();
            brute_distance(&m, p, d0, n);
            double dt = mlb_now_seconds() - t0;
            if (dt < brute) { brute = dt; cpu_brute = cpu_now() - c0; }
            if (dt > 2) break;   // slow enough to be measured once
        }
        for (int rep = 0; rep < 5; rep++) {
            mlb_mesh_bvh b;
            double t0 = mlb_now_seconds();
            if (mlb_mesh_bvh_build(&b, &m)) DIE();
            double t1 = mlb_now_seconds();
            mlb_mesh_bvh_distance(&b, p, d1, n);
            double t2 = mlb_now_seconds();
            mlb_mesh_bvh_free(&b);
            if (t1 - t0 < build) build = t1 - t0;
            if (t2 - t1 < query) query = t2 - t1;
            double c3 = cpu_now(), t3 = mlb_now_seconds();
            mlb_mesh_distance(&m, p, d1, n);
            double dt = mlb_now_seconds() - t3;
            if (dt < total) { total = dt; cpu_total = cpu_now() - c3; }
        }
        printf("| %s | %d | %d | %.1f ms | %.2f ms | %.2f ms | %.2f ms | %.0fx | %.1f ms, %.2f ms | %s |\n", rows[r].name,
               m.n_faces, n, brute * 1e3, build * 1e3, query * 1e3, total * 1e3, brute / total, cpu_brute * 1e3,
               cpu_total * 1e3, memcmp(d0, d1, sizeof(float) * (size_t)n) ? "NO" : "yes");
        fflush(stdout);
        free(p); free(d0); free(d1);
        mlb_mesh_free(&m);
    }

    // ---- the shape part of one text3d measure: the asset against 11 classes x 8 seeds ----
    mlb_text3d_truth truth;
    double t0 = mlb_now_seconds();
    if (mlb_text3d_truth_create(&truth, 8)) DIE();
    double truth_s = mlb_now_seconds() - t0;
    int nt = truth.n_classes * truth.n_seeds, ns = mlb_text3d_measure_default().chamfer_samples;
    uint64_t seed = mlb_text3d_measure_default().chamfer_seed;
    mlb_mesh asset;
    if (mlb_catalogue_mesh(mug_class, 11, &asset)) DIE();   // a mug that is not one of the truth's seeds (0..7)
    long faces = 0;
    for (int j = 0; j < nt; j++) faces += truth.meshes[j].n_faces;
    printf("\nThe shape part of a text3d measure: a catalogue mug (seed 11, %d faces) against %d truth meshes "
           "(%d classes x %d seeds, %ld faces on average), %d samples a side. Truth meshes and their BVHs: %.2f s "
           "(once per invocation).\n\n", asset.n_faces, nt, truth.n_classes, truth.n_seeds, faces / nt, ns, truth_s);
    const char* ways[4] = {"88 x mlb_chamfer, brute force (before)", "88 x mlb_chamfer (a BVH per call)",
                           "mlb_chamfer_many, no truth BVHs", "mlb_chamfer_many with the truth's BVHs (the measure)"};
    mlb_chamfer_result* res[4];
    for (int w = 0; w < 4; w++) if (!(res[w] = malloc(sizeof(mlb_chamfer_result) * nt))) return 1;
    printf("| way | wall | CPU (all threads) | same bits as the first |\n|---|---|---|---|\n");
    int first = quick ? 1 : 0;
    for (int w = first; w < 4; w++) {
        double best = 1e30, cpu_best = 0;
        mlb_chamfer_result* r = res[w];
        for (int rep = 0; rep < (w == 0 ? 1 : 3); rep++) {
            double c0 = cpu_now(), w0 = mlb_now_seconds();
            if (w == 0) for (int j = 0; j < nt; j++) brute_chamfer(&asset, &truth.meshes[j], ns, seed, &r[j]);
            if (w == 1) for (int j = 0; j < nt; j++) { if (mlb_chamfer(&asset, &truth.meshes[j], ns, seed, &r[j])) DIE(); }
            if (w == 2 && mlb_chamfer_many(&asset, truth.meshes, NULL, nt, ns, seed, r)) DIE();
            if (w == 3 && mlb_chamfer_many(&asset, truth.meshes, truth.bvh, nt, ns, seed, r)) DIE();
            double dt = mlb_now_seconds() - w0;
            if (dt < best) { best = dt; cpu_best = cpu_now() - c0; }
        }
        const char* same = w == first ? "(the first)" : memcmp(res[first], r, sizeof(mlb_chamfer_result) * nt) ? "NO" : "yes";
        printf("| %s | %.2f s | %.2f s | %s |\n", ways[w], best, cpu_best, same);
        fflush(stdout);
    }

    // ---- one whole measure (shape + material + relighting under "white" at the tiny preset's size) ----
    mlb_envmap env = {0};
    mlb_envlight light = {0};
    mlb_envlight_options lo;
    memset(&lo, 0, sizeof lo);
    lo.face_size = 64;
    if (mlb_envmap_open(&env, "white", 1.0f, 128, NULL) || mlb_envlight_build(&light, &env, &lo)) DIE();
    float* k = malloc(sizeof(float) * 7 * (size_t)asset.n_verts);
    if (!k) return 1;
    for (int i = 0; i < asset.n_verts; i++) memcpy(k + 7 * (size_t)i, mlb_catalogue_material_brdf(0), sizeof(float) * 7);
    mlb_text3d_measure_config mc = mlb_text3d_measure_default();
    mlb_text3d_scores sc;
    double best = 1e30, cpu_best = 0;
    for (int rep = 0; rep < 3; rep++) {
        double c0 = cpu_now(), w0 = mlb_now_seconds();
        if (mlb_text3d_measure(&truth, &asset, k, mug_class, 0, &light, &mc, &sc)) DIE();
        double dt = mlb_now_seconds() - w0;
        if (dt < best) { best = dt; cpu_best = cpu_now() - c0; }
    }
    printf("\nmlb_text3d_measure, whole (the mug in %s; nearest %s, Chamfer %.4f): %.2f s wall, %.2f s CPU\n",
           mlb_catalogue_material_name(0), mlb_catalogue_class_name(sc.nearest), sc.chamfer_prompted, best, cpu_best);
    free(k);
    for (int w = 0; w < 4; w++) free(res[w]);
    mlb_mesh_free(&asset);
    mlb_mesh_free(&mug);
    mlb_text3d_truth_free(&truth);
    return 0;
}
