// CUDA throughput: the two ceilings (GEMM rate at fp32/tf32/fp16/bf16, device-to-device copy
// bandwidth) and the pipeline's hot ops against them: the UNet's flash attention at 4096 tokens,
// group norm and SiLU at the UNet's first level, hash-grid encoding of 2^20 points, split-sum
// shading of 512^2 x 9 pixels. Device events around each op, 3 warm-ups, the median of `reps`
// runs; inputs are random (never zeros). Prints a table; exits 0 with a message when there is no
// GPU. Usage: bench_cuda [reps] (default 10). docs/cuda.md.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/cuda_ops.h"
#include "matlaber/device.h"
#include "matlaber/rng.h"

static int reps = 10;

#define TRY(x) do { if ((x) != MLB_OK) { fprintf(stderr, "bench_cuda: %s\n", mlb_last_error()); exit(1); } } while (0)

static int cmp_double(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return x < y ? -1 : x > y;
}

typedef mlb_status (*op_fn)(void* ctx);
// Median milliseconds of one call of fn (3 warm-ups first).
static double time_ms(op_fn fn, void* ctx) {
    double t[100];
    int n = reps > 100 ? 100 : reps;
    for (int i = 0; i < 3; i++) TRY(fn(ctx));
    TRY(mlb_cuda_sync());
    for (int i = 0; i < n; i++) {
        TRY(mlb_cuda_timer_begin());
        TRY(fn(ctx));
        TRY(mlb_cuda_timer_end(&t[i]));
    }
    qsort(t, n, sizeof t[0], cmp_double);
    return t[n / 2];
}

static float* dev_random(size_t n, uint64_t seed, float lo, float hi) {
    float* d;
    TRY(mlb_cuda_malloc((void**)&d, n * sizeof(float)));
    TRY(mlb_cuda_fill_uniform(d, n, seed, lo, hi));
    return d;
}

static void row(const char* what, const char* shape, double ms, const char* unit, double rate, const char* note) {
    printf("%-26s %-30s %9.3f ms %10.1f %-7s %s\n", what, shape, ms, rate, unit, note ? note : "");
    fflush(stdout);
}

// ---- GEMM
typedef struct { int n; const void *a, *b; float* c; mlb_cuda_dtype t; mlb_gemm_precision p; } gemm_ctx;
static mlb_status gemm_op(void* v) {
    gemm_ctx* g = v;
    return mlb_cuda_gemm(0, 0, g->n, g->n, g->n, 1.0f, g->a, g->n, g->b, g->n, 0.0f, g->c, g->n, g->t, g->p);
}

// ---- copy
typedef struct { void *dst, *src; size_t bytes; } copy_ctx;
static mlb_status copy_op(void* v) { copy_ctx* c = v; return mlb_cuda_copy_d2d(c->dst, c->src, c->bytes); }

// ---- attention
typedef struct { float *out, *q, *k, *v; int B, T, C, NH; } att_ctx;
static mlb_status att_op(void* p) {
    att_ctx* a = p;
    return mlb_cuda_attention_forward(a->out, a->q, a->k, a->v, a->C, a->B, a->T, a->C, a->NH, 0);
}

// ---- scaled dot-product attention at bf16: the fused kernel or the batched GEMMs (mlb_cuda_use_flash)
typedef struct { float *out, *q, *k, *v; int B, Tq, Tk, C, NH; } sdpa_ctx;
static mlb_status sdpa_op(void* p) {
    sdpa_ctx* a = p;
    return mlb_cuda_sdpa_forward(a->out, NULL, a->q, a->k, a->v, a->B, a->Tq, a->Tk, a->C, a->NH, a->C, a->C,
                                 MLB_GEMM_BF16);
}

// ---- group norm + SiLU, SiLU alone
typedef struct { float *out, *in, *w, *b, *mean, *rstd; int N, C, HW, G; } gn_ctx;
static mlb_status gn_op(void* p) {
    gn_ctx* g = p;
    return mlb_cuda_groupnorm_forward(g->out, g->mean, g->rstd, g->in, g->w, g->b, g->N, g->C, g->HW, g->G, 1e-5f, MLB_ACT_SILU);
}
static mlb_status silu_op(void* p) {
    gn_ctx* g = p;
    return mlb_cuda_activation_forward(g->out, g->in, (size_t)g->N * g->C * g->HW, MLB_ACT_SILU);
}

// ---- hash grid
typedef struct { mlb_hashgrid g; float *params, *dparams, *x, *out, *dout, *dx; int N; } hg_ctx;
static mlb_status hg_fwd(void* p) { hg_ctx* h = p; return mlb_cuda_hashgrid_forward(&h->g, h->params, h->out, h->x, h->N); }
static mlb_status hg_bwd(void* p) {
    hg_ctx* h = p;
    return mlb_cuda_hashgrid_backward(&h->g, h->params, h->dparams, h->dx, h->dout, h->x, h->N);
}

// ---- shading
typedef struct { mlb_cuda_envlight L; float *out, *kd, *ks, *kr, *n, *v, *g[5]; int N; } sh_ctx;
static mlb_status sh_op(void* p) {
    sh_ctx* s = p;
    return mlb_cuda_shade_forward(s->out, s->kd, s->ks, s->kr, s->n, s->v, s->N, &s->L, MLB_FRESNEL_PAPER);
}
static mlb_status sh_bwd(void* p) {   // dout = out (any nonzero gradient)
    sh_ctx* s = p;
    return mlb_cuda_shade_backward(s->g[0], s->g[1], s->g[2], s->g[3], s->g[4], s->out, s->kd, s->ks, s->kr, s->n, s->v, s->N,
                                   &s->L, MLB_FRESNEL_PAPER);
}

int main(int argc, char** argv) {
    if (argc > 1) reps = atoi(argv[1]) > 0 ? atoi(argv[1]) : 10;
    mlb_device dev;
    if (mlb_device_select("cuda", &dev) != MLB_OK) {
        printf("bench_cuda: no CUDA device, nothing to measure (%s)\n", mlb_last_error());
        return 0;
    }
    char desc[256];
    TRY(mlb_cuda_describe(0, desc, sizeof desc));
    printf("bench_cuda: %s; median of %d runs after 3 warm-ups, device events\n\n", desc, reps);
    printf("%-26s %-30s %12s %10s\n", "op", "shape", "time", "rate");

    // GEMM: n^3 multiply-adds = 2 n^3 flops
    {
        const int n = 8192;
        size_t nn = (size_t)n * n;
        float *a = dev_random(nn, 1, -1, 1), *b = dev_random(nn, 2, -1, 1), *c = dev_random(nn, 3, -1, 1);
        void *a16, *b16;
        TRY(mlb_cuda_malloc(&a16, nn * 2));
        TRY(mlb_cuda_malloc(&b16, nn * 2));
        const struct { const char* name; mlb_cuda_dtype t; mlb_gemm_precision p; } cases[4] = {
            {"GEMM fp32", MLB_DTYPE_F32, MLB_GEMM_FP32}, {"GEMM tf32", MLB_DTYPE_F32, MLB_GEMM_TF32},
            {"GEMM fp16 (fp32 acc)", MLB_DTYPE_F16, MLB_GEMM_FP16}, {"GEMM bf16 (fp32 acc)", MLB_DTYPE_BF16, MLB_GEMM_BF16}};
        for (int i = 0; i < 4; i++) {
            gemm_ctx g = {n, a, b, c, cases[i].t, cases[i].p};
            if (cases[i].t != MLB_DTYPE_F32) {
                TRY(mlb_cuda_convert(a16, cases[i].t, a, nn));
                TRY(mlb_cuda_convert(b16, cases[i].t, b, nn));
                g.a = a16, g.b = b16;
            }
            double ms = time_ms(gemm_op, &g);
            row(cases[i].name, "8192^3", ms, "TFLOP/s", 2.0 * n * n * (double)n / (ms * 1e-3) / 1e12, "ceiling: matrix rate");
        }
        mlb_cuda_free(a); mlb_cuda_free(b); mlb_cuda_free(c); mlb_cuda_free(a16); mlb_cuda_free(b16);
    }
    // Bandwidth: bytes read + bytes written
    {
        size_t bytes = (size_t)1 << 31;
        float *src = dev_random(bytes / 4, 4, -1, 1), *dst;
        TRY(mlb_cuda_malloc((void**)&dst, bytes));
        copy_ctx c = {dst, src, bytes};
        double ms = time_ms(copy_op, &c);
        row("copy device-to-device", "2 GiB", ms, "GB/s", 2.0 * bytes / (ms * 1e-3) / 1e9, "ceiling: memory bandwidth");
        mlb_cuda_free(src); mlb_cuda_free(dst);
    }
    // Attention: the UNet's first level at a 64^2 latent (4096 tokens, 320 channels, 8 heads of 40),
    // batch 2 (cond + uncond); 4 B NH T^2 hd flops (QK^T and PV); and the deepest level (hd 160).
    {
        const int shapes[2][4] = {{2, 4096, 320, 8}, {2, 256, 1280, 8}};
        for (int s = 0; s < 2; s++) {
            att_ctx a = {0};
            a.B = shapes[s][0], a.T = shapes[s][1], a.C = shapes[s][2], a.NH = shapes[s][3];
            size_t n = (size_t)a.B * a.T * a.C;
            a.q = dev_random(n, 10, -1, 1), a.k = dev_random(n, 11, -1, 1), a.v = dev_random(n, 12, -1, 1);
            TRY(mlb_cuda_malloc((void**)&a.out, n * 4));
            double ms = time_ms(att_op, &a);
            char shape[64];
            snprintf(shape, sizeof shape, "B%d T%d C%d heads %d", a.B, a.T, a.C, a.NH);
            double flops = 4.0 * a.B * (double)a.T * a.T * a.C;
            row("attention (flash, fp32)", shape, ms, "TFLOP/s", flops / (ms * 1e-3) / 1e12, "no T x T matrix");
            mlb_cuda_free(a.q); mlb_cuda_free(a.k); mlb_cuda_free(a.v); mlb_cuda_free(a.out);
        }
    }
    // The UNet's attention at batch 18 (9 views x 2) and a 64^2 latent, bf16 operands: self-attention
    // at the first two levels (hd 40, 80), the first level's cross-attention to 77 tokens and SD 2's
    // heads of 64, fused (flash_attention.cu) against the batched GEMMs with the scores in memory.
    {
        const int shapes[4][4] = {{4096, 4096, 320, 8}, {4096, 77, 320, 8}, {1024, 1024, 640, 8}, {4096, 4096, 320, 5}};
        for (int s = 0; s < 4; s++) {
            sdpa_ctx a = {0};
            a.B = 18, a.Tq = shapes[s][0], a.Tk = shapes[s][1], a.C = shapes[s][2], a.NH = shapes[s][3];
            size_t nq = (size_t)a.B * a.Tq * a.C, nkv = (size_t)a.B * a.Tk * a.C;
            a.q = dev_random(nq, 13, -1, 1), a.k = dev_random(nkv, 14, -1, 1), a.v = dev_random(nkv, 15, -1, 1);
            TRY(mlb_cuda_malloc((void**)&a.out, nq * 4));
            char shape[64];
            snprintf(shape, sizeof shape, "B%d Tq%d Tk%d C%d heads %d", a.B, a.Tq, a.Tk, a.C, a.NH);
            double flops = 4.0 * a.B * (double)a.Tq * a.Tk * a.C;
            for (int flash = 2; flash >= 0; flash--) {   // 2: the fused kernel with 128 query rows per block
                mlb_cuda_use_flash(flash > 0);
                mlb_cuda_flash_rows(flash == 2 ? 128 : 64);
                double ms = time_ms(sdpa_op, &a);
                row(flash == 2 ? "sdpa bf16, fused, 128 rows" : flash ? "sdpa bf16, fused, 64 rows" : "sdpa bf16, batched GEMMs",
                    shape, ms, "TFLOP/s", flops / (ms * 1e-3) / 1e12, flash ? "scores on chip" : "scores through memory");
            }
            mlb_cuda_use_flash(1);
            mlb_cuda_flash_rows(64);
            mlb_cuda_free(a.q); mlb_cuda_free(a.k); mlb_cuda_free(a.v); mlb_cuda_free(a.out);
        }
    }
    // Group norm + SiLU and SiLU alone at the UNet's first level, batch 18 (9 views x 2): bytes = read + write
    {
        gn_ctx g = {0};
        g.N = 18, g.C = 320, g.HW = 64 * 64, g.G = 32;
        size_t n = (size_t)g.N * g.C * g.HW;
        g.in = dev_random(n, 20, -2, 2), g.w = dev_random(g.C, 21, 0.5f, 1.5f), g.b = dev_random(g.C, 22, -1, 1);
        TRY(mlb_cuda_malloc((void**)&g.out, n * 4));
        TRY(mlb_cuda_malloc((void**)&g.mean, (size_t)g.N * g.G * 4));
        TRY(mlb_cuda_malloc((void**)&g.rstd, (size_t)g.N * g.G * 4));
        double ms = time_ms(gn_op, &g);
        row("group norm + SiLU", "18x320x64^2, G32", ms, "GB/s", 2.0 * n * 4 / (ms * 1e-3) / 1e9, "reads x 3 (two-pass stats)");
        ms = time_ms(silu_op, &g);
        row("SiLU", "18x320x64^2", ms, "GB/s", 2.0 * n * 4 / (ms * 1e-3) / 1e9, "");
        mlb_cuda_free(g.in); mlb_cuda_free(g.w); mlb_cuda_free(g.b); mlb_cuda_free(g.out); mlb_cuda_free(g.mean);
        mlb_cuda_free(g.rstd);
    }
    // Hash grid: 2^20 points, the default 16 levels x 2 features, 2^19 entries
    {
        hg_ctx h = {0};
        mlb_hashgrid_config cfg = mlb_hashgrid_default();
        TRY(hashgrid_init(&h.g, &cfg, NULL));
        h.N = 1 << 20;
        size_t D = (size_t)h.g.out_dim;
        h.params = dev_random(h.g.n_params, 30, -1e-4f, 1e-4f);
        TRY(mlb_cuda_malloc((void**)&h.dparams, h.g.n_params * 4));
        TRY(mlb_cuda_memset(h.dparams, 0, h.g.n_params * 4));
        h.x = dev_random(3 * (size_t)h.N, 31, 0, 1);
        h.dout = dev_random(D * h.N, 32, -1, 1);
        TRY(mlb_cuda_malloc((void**)&h.out, D * h.N * 4));
        TRY(mlb_cuda_malloc((void**)&h.dx, 3 * (size_t)h.N * 4));
        double ms = time_ms(hg_fwd, &h);
        row("hash grid forward", "2^20 pts, 16 lv x 2, T 2^19", ms, "Mpt/s", h.N / (ms * 1e-3) / 1e6, "");
        ms = time_ms(hg_bwd, &h);
        row("hash grid backward", "dparams (atomics) + dx", ms, "Mpt/s", h.N / (ms * 1e-3) / 1e6, "");
        mlb_cuda_free(h.params); mlb_cuda_free(h.dparams); mlb_cuda_free(h.x); mlb_cuda_free(h.dout); mlb_cuda_free(h.out);
        mlb_cuda_free(h.dx);
    }
    // Split-sum shading: 9 views of 512^2 pixels, the default 512^2 cube and 16^2 irradiance
    {
        sh_ctx s = {0};
        mlb_envmap env;
        mlb_envlight L;
        mlb_envlight_options o = {0};
        TRY(mlb_envmap_named(&env, "sky", 512));
        TRY(mlb_envlight_build(&L, &env, &o));
        mlb_envlight_set_rotation(&L, 0.3f);
        TRY(mlb_cuda_envlight_upload(&s.L, &L));
        s.N = 512 * 512 * 9;
        size_t n3 = 3 * (size_t)s.N;
        float* host = malloc(n3 * sizeof(float) * 2);
        if (!host) { fprintf(stderr, "bench_cuda: out of memory\n"); return 1; }
        float *nrm = host, *view = host + n3;
        for (int i = 0; i < s.N; i++) {   // normals around +z, views within 60 degrees of them
            double a[3], b[3], la = 0, lb = 0;
            for (int k = 0; k < 3; k++) {
                a[k] = mlb_rng_normal_f64(40, 0, 3 * (uint64_t)i + k) + (k == 2 ? 2 : 0);
                b[k] = a[k] + 0.5 * mlb_rng_normal_f64(41, 0, 3 * (uint64_t)i + k);
                la += a[k] * a[k], lb += b[k] * b[k];
            }
            for (int k = 0; k < 3; k++) nrm[3 * i + k] = (float)(a[k] / sqrt(la)), view[3 * i + k] = (float)(b[k] / sqrt(lb));
        }
        s.kd = dev_random(n3, 42, 0, 1), s.ks = dev_random(n3, 43, 0, 1), s.kr = dev_random(s.N, 44, 0.08f, 1);
        TRY(mlb_cuda_malloc((void**)&s.n, n3 * 4));
        TRY(mlb_cuda_malloc((void**)&s.v, n3 * 4));
        TRY(mlb_cuda_malloc((void**)&s.out, n3 * 4));
        TRY(mlb_cuda_copy_to_device(s.n, nrm, n3 * 4));
        TRY(mlb_cuda_copy_to_device(s.v, view, n3 * 4));
        free(host);
        double ms = time_ms(sh_op, &s);
        row("split-sum shading fwd", "512^2 x 9 px, cube 512, fp32", ms, "Mpx/s", s.N / (ms * 1e-3) / 1e6, "");
        for (int j = 0; j < 5; j++) {
            size_t n = j == 2 ? (size_t)s.N : n3;
            TRY(mlb_cuda_malloc((void**)&s.g[j], n * 4));
            TRY(mlb_cuda_memset(s.g[j], 0, n * 4));
        }
        ms = time_ms(sh_bwd, &s);
        row("split-sum shading bwd", "all 5 gradients", ms, "Mpx/s", s.N / (ms * 1e-3) / 1e6, "");
        for (int j = 0; j < 5; j++) mlb_cuda_free(s.g[j]);
        mlb_cuda_free(s.kd); mlb_cuda_free(s.ks); mlb_cuda_free(s.kr); mlb_cuda_free(s.n); mlb_cuda_free(s.v); mlb_cuda_free(s.out);
        mlb_cuda_envlight_free(&s.L);
        mlb_envlight_free(&L);
        mlb_envmap_free(&env);
    }
    return 0;
}
