// The geometry stage's surface and renderer ops through the op tables (docs/cuda.md), the CPU's
// against CUDA's in the same run: marching tets as the stage calls it (mlb_mt_device_forward and
// _backward: host SDF in, host surface out, so the GPU's figure includes its uploads and
// downloads) on the paper's grid, then the six rasterizer ops on that surface for 9 views at 512²
// on buffers already on the table's device (the stage's per-view work once its buffers live there).
// Per op: the median of `reps` runs after one warm-up, wall clock, each run ending synchronised
// (a download of one value). Surface: a sphere of radius 0.5 with bumps (about the 26k faces of
// a paper-setting run at 64 cells); cameras: the geometry stage's orbit sampler; attributes [normal, 1] (C 4).
// Usage: bench_render_ops [reps] [cells] (defaults 5, 64). Without a GPU only the CPU rows print.
// docs/cuda.md, results in docs/benchmarks.md.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"
#include "matlaber/cameras.h"
#include "matlaber/cpu.h"
#include "matlaber/dmtet.h"
#include "matlaber/progress.h"
#include "matlaber/raster.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"

#define TRY(x) do { if ((x) != MLB_OK) { fprintf(stderr, "bench_render_ops: %s\n", mlb_last_error()); exit(1); } } while (0)
#define VIEWS 9
#define RES 512
#define C 4

static int reps = 5;

static int cmp_double(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return x < y ? -1 : x > y;
}

typedef struct bench bench;
typedef void (*op_fn)(bench* b);
// Median seconds of fn over reps runs after one warm-up; sync (a download of one value) closes each.
static double time_s(op_fn fn, bench* b, const mlb_backend* be, const float* sync_buf) {
    double t[64];
    int n = reps > 64 ? 64 : reps;
    float one;
    fn(b);
    TRY(be->download(&one, sync_buf, 1));
    for (int i = 0; i < n; i++) {
        double t0 = mlb_now_seconds();
        fn(b);
        TRY(be->download(&one, sync_buf, 1));
        t[i] = mlb_now_seconds() - t0;
    }
    qsort(t, n, sizeof t[0], cmp_double);
    return t[n / 2];
}

// ---- marching tets through the table, as the geometry stage calls it
struct bench {
    const mlb_backend* be;
    const mlb_tetgrid* g;
    const float *pos, *sdf, *dverts;
    float *dpos, *dsdf;
    mlb_mt_device* mt;
    mlb_mt_surface surf;
    // the rasterizer's buffers on be's device, per view
    int V, F;
    float *clip[VIEWS], *attr, *faces, *adj;                       // [V,4] per view, [V,C], [F,3], [F,3] int32
    float *tri[VIEWS], *bary[VIEWS], *depth[VIEWS], *img[VIEWS];   // [H,W] int32, [H,W,2], [H,W], [H,W,C]
    float *aa[VIEWS], *weights[VIEWS];                             // [H,W,C], [H,W,2]
    float *daa, *dimg, *dbary, *dclip, *dattr;
};

static void mt_forward(bench* b) {
    mt_surface_free(&b->surf);
    TRY(mlb_mt_device_forward(&b->mt, b->be, &b->surf, b->g, b->pos, b->sdf, MLB_MT_HOST));
}
static void mt_backward(bench* b) { TRY(mlb_mt_device_backward(b->mt, b->dpos, b->dsdf, b->dverts, MLB_MT_HOST)); }

#define RGRID(name, body) \
    static void name(bench* b) { const mlb_backend* be = b->be; for (int v = 0; v < VIEWS; v++) TRY(body); }
RGRID(op_rasterize, be->rasterize((int32_t*)b->tri[v], b->bary[v], b->depth[v], b->clip[v], b->V,
                                  (const int32_t*)b->faces, b->F, RES, RES))
RGRID(op_interpolate, be->interpolate(b->img[v], b->attr, b->V, C, (const int32_t*)b->tri[v], b->bary[v],
                                      (const int32_t*)b->faces, b->F, RES, RES))
RGRID(op_antialias, be->antialias(b->aa[v], b->weights[v], b->img[v], C, (const int32_t*)b->tri[v], b->depth[v],
                                  b->clip[v], b->V, (const int32_t*)b->faces, (const int32_t*)b->adj, b->F, RES, RES))
RGRID(op_antialias_backward, be->antialias_backward(b->dimg, b->dclip, b->daa, b->weights[v], b->img[v], C,
                                                    (const int32_t*)b->tri[v], b->depth[v], b->clip[v], b->V,
                                                    (const int32_t*)b->faces, (const int32_t*)b->adj, b->F, RES, RES))
RGRID(op_interpolate_backward, be->interpolate_backward(b->dattr, b->dbary, b->dimg, b->attr, b->V, C,
                                                        (const int32_t*)b->tri[v], b->bary[v],
                                                        (const int32_t*)b->faces, b->F, RES, RES))
RGRID(op_rasterize_backward, be->rasterize_backward(b->dclip, b->dbary, NULL, (const int32_t*)b->tri[v], b->clip[v],
                                                    b->V, (const int32_t*)b->faces, b->F, RES, RES))
#undef RGRID

static float* dev_upload(const mlb_backend* be, const void* host, size_t n) {
    float* d;
    TRY(be->alloc(&d, n));
    TRY(be->upload(d, (const float*)host, n));
    return d;
}
static float* dev_alloc(const mlb_backend* be, size_t n) {
    float* d;
    TRY(be->alloc(&d, n));
    TRY(be->zero(d, n));
    return d;
}

// One table's rows: marching tets, then the raster ops on its surface. secs[] receives the times.
static void run_table(const mlb_backend* be, const mlb_tetgrid* g, const float* pos, const float* sdf,
                      double secs[8], int* n_faces) {
    bench b = {0};
    b.be = be, b.g = g, b.pos = pos, b.sdf = sdf;
    mt_forward(&b);
    int nv = b.surf.n_verts, nf = b.surf.n_faces;
    *n_faces = nf;
    float* dverts = malloc(3 * (size_t)nv * sizeof(float));
    b.dpos = calloc(3 * (size_t)g->n_verts, sizeof(float));
    b.dsdf = calloc((size_t)g->n_verts, sizeof(float));
    if (!dverts || !b.dpos || !b.dsdf) { fprintf(stderr, "bench_render_ops: out of memory\n"); exit(1); }
    for (size_t i = 0; i < 3 * (size_t)nv; i++) dverts[i] = (float)mlb_rng_uniform_f64(7, 1, i) * 2 - 1;
    b.dverts = dverts;
    // time_s syncs with a download from a table buffer: a one-float buffer for the host-side passes
    float* sync = dev_alloc(be, 1);
    secs[0] = time_s(mt_forward, &b, be, sync);
    secs[1] = time_s(mt_backward, &b, be, sync);

    // the surface on the device: faces, adjacency, [normal, 1] attributes, 9 views' clip positions
    b.V = nv, b.F = nf;
    int32_t* adj = malloc(3 * (size_t)nf * sizeof(int32_t));
    float* attr = malloc((size_t)nv * C * sizeof(float));
    float* clip = malloc(4 * (size_t)nv * sizeof(float));
    if (!adj || !attr || !clip) { fprintf(stderr, "bench_render_ops: out of memory\n"); exit(1); }
    TRY(mlb_edge_topology(adj, b.surf.faces, nf, nv));
    for (int i = 0; i < nv; i++) {
        const float* p = b.surf.pos + 3 * (size_t)i;
        float l = sqrtf(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) + 1e-12f;
        for (int k = 0; k < 3; k++) attr[C * (size_t)i + k] = p[k] / l;
        attr[C * (size_t)i + 3] = 1;
    }
    b.faces = dev_upload(be, b.surf.faces, 3 * (size_t)nf);
    b.adj = dev_upload(be, adj, 3 * (size_t)nf);
    b.attr = dev_upload(be, attr, (size_t)nv * C);
    mlb_orbit_config oc = mlb_orbit_default();
    size_t P = (size_t)RES * RES;
    for (int v = 0; v < VIEWS; v++) {
        mlb_view view;
        TRY(mlb_orbit_sample(&view, &oc, 1, MLB_STAGE_GEOMETRY, 0, v));
        mlb_transform_points(clip, b.surf.pos, nv, &view.cam.view_proj);
        b.clip[v] = dev_upload(be, clip, 4 * (size_t)nv);
        b.tri[v] = dev_alloc(be, P), b.bary[v] = dev_alloc(be, 2 * P), b.depth[v] = dev_alloc(be, P);
        b.img[v] = dev_alloc(be, C * P), b.aa[v] = dev_alloc(be, C * P), b.weights[v] = dev_alloc(be, 2 * P);
    }
    float* daa = malloc(C * P * sizeof(float));
    if (!daa) { fprintf(stderr, "bench_render_ops: out of memory\n"); exit(1); }
    for (size_t i = 0; i < C * P; i++) daa[i] = (float)mlb_rng_uniform_f64(7, 2, i) * 2 - 1;
    b.daa = dev_upload(be, daa, C * P);
    b.dimg = dev_alloc(be, C * P), b.dbary = dev_alloc(be, 2 * P);
    b.dclip = dev_alloc(be, 4 * (size_t)nv), b.dattr = dev_alloc(be, (size_t)nv * C);
    op_fn ops[6] = {op_rasterize, op_interpolate, op_antialias, op_antialias_backward, op_interpolate_backward,
                    op_rasterize_backward};
    for (int k = 0; k < 6; k++) secs[2 + k] = time_s(ops[k], &b, be, sync);

    float** bufs[] = {&b.faces, &b.adj, &b.attr, &b.daa, &b.dimg, &b.dbary, &b.dclip, &b.dattr, &sync};
    for (size_t i = 0; i < sizeof bufs / sizeof bufs[0]; i++) be->release(*bufs[i]);
    for (int v = 0; v < VIEWS; v++) {
        float* per[] = {b.clip[v], b.tri[v], b.bary[v], b.depth[v], b.img[v], b.aa[v], b.weights[v]};
        for (int k = 0; k < 7; k++) be->release(per[k]);
    }
    mlb_mt_device_free(b.mt);
    mt_surface_free(&b.surf);
    free(dverts), free(b.dpos), free(b.dsdf), free(adj), free(attr), free(clip), free(daa);
}

int main(int argc, char** argv) {
    reps = argc > 1 ? atoi(argv[1]) : 5;
    if (reps < 1 || reps > 64) reps = 5;
    int cells = argc > 2 ? atoi(argv[2]) : 64;
    if (cells < 4 || cells > 256) cells = 64;
    mlb_cpu_info cpu;
    mlb_cpu_detect(&cpu);
    mlb_tetgrid g;
    TRY(mlb_tetgrid_create(&g, cells, 2.0f));
    // the SDF: a sphere of radius 0.5 with bumps (positive inside, the stage's convention)
    float* sdf = malloc((size_t)g.n_verts * sizeof(float));
    if (!sdf) { fprintf(stderr, "bench_render_ops: out of memory\n"); return 1; }
    for (int i = 0; i < g.n_verts; i++) {
        const float* p = g.verts + 3 * (size_t)i;
        float r = sqrtf(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
        sdf[i] = 0.5f + 0.04f * sinf(7 * p[0]) * sinf(5 * p[1]) * sinf(6 * p[2]) - r;
    }
    int n_gpu = 0;
    int gpu = mlb_cuda_probe(&n_gpu) == MLB_OK && n_gpu > 0 && mlb_cuda_init(0) == MLB_OK;
    char desc[256] = "no GPU";
    if (gpu) TRY(mlb_cuda_describe(0, desc, sizeof desc));
    printf("bench_render_ops: grid %d cells (%d tets), %d views at %d^2, C %d; median of %d after 1 warm-up, wall clock\n",
           cells, g.n_tets, VIEWS, RES, C, reps);
    printf("CPU: %s, %d threads; GPU: %s\n", cpu.model, mlb_get_threads(), desc);
    const char* names[8] = {"marching tets forward", "marching tets backward", "rasterize", "interpolate", "antialias",
                            "antialias backward", "interpolate backward", "rasterize backward"};
    const char* notes[8] = {"host SDF in, surface out", "host dverts in, dpos/dsdf out", "9 views", "9 views", "9 views",
                            "9 views", "9 views", "9 views"};
    double cpu_s[8], gpu_s[8] = {0};
    int nf_cpu = 0, nf_gpu = 0;
    run_table(mlb_backend_cpu(), &g, g.verts, sdf, cpu_s, &nf_cpu);
    if (gpu) run_table(mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32), &g, g.verts, sdf, gpu_s, &nf_gpu);
    printf("surface: %d faces%s\n", nf_cpu, gpu && nf_gpu != nf_cpu ? " (DIFFERENT ON THE GPU)" : "");
    printf("%-24s %12s %12s %8s  %s\n", "op", "CPU ms", "CUDA ms", "ratio", "");
    double tc = 0, tg = 0;
    for (int k = 0; k < 8; k++) {
        tc += cpu_s[k], tg += gpu_s[k];
        if (gpu)
            printf("%-24s %12.2f %12.3f %8.1f  %s\n", names[k], cpu_s[k] * 1e3, gpu_s[k] * 1e3, cpu_s[k] / gpu_s[k], notes[k]);
        else
            printf("%-24s %12.2f %12s %8s  %s\n", names[k], cpu_s[k] * 1e3, "-", "-", notes[k]);
    }
    if (gpu) printf("%-24s %12.2f %12.3f %8.1f  %s\n", "one geometry step's", tc * 1e3, tg * 1e3, tc / tg, "sum of the above");
    else printf("%-24s %12.2f\n", "one geometry step's", tc * 1e3);
    free(sdf);
    mlb_tetgrid_free(&g);
    return gpu && nf_gpu != nf_cpu;
}
