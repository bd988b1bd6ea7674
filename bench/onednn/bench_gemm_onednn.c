// oneDNN's bf16 matmul (bf16 operands, fp32 result) on bench_gemm's shapes, to compare with
// mlb_gemm_bf16 (docs/ops.md, docs/benchmarks.md). Built only when CMake finds oneDNN (Debian's
// libdnnl-dev); the program itself does not link it. Two rates per shape: the matmul alone on
// operands already in bf16, and with the fp32 -> bf16 conversion of both operands counted (what
// mlb_gemm_bf16 does inside its packing, as the program's weights and activations are fp32).
// GFLOP/s, best of 3 after a warm-up, on all OpenMP threads. Usage: bench_gemm_onednn
#include <omp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <oneapi/dnnl/dnnl.h>
#include "matlaber/progress.h"
#include "matlaber/rng.h"

#define CK(x) do { dnnl_status_t s_ = (x); if (s_ != dnnl_success) { \
    fprintf(stderr, "bench_gemm_onednn: oneDNN error %d in %s\n", (int)s_, #x); exit(1); } } while (0)

static uint16_t to_bf16(float f) {   // nearest even (no NaN in these inputs)
    uint32_t u;
    memcpy(&u, &f, 4);
    return (uint16_t)((u + 0x7fffu + ((u >> 16) & 1)) >> 16);
}

int main(void) {
    static const int shapes[][3] = {{320, 4096, 2880}, {640, 1024, 5760}, {1280, 256, 11520}, {4096, 320, 320},
                                    {4096, 4096, 40},  {4096, 1280, 320}, {128, 65536, 1152}, {65536, 32, 32},
                                    {32, 32, 65536}};
    dnnl_engine_t eng;
    dnnl_stream_t st;
    CK(dnnl_engine_create(&eng, dnnl_cpu, 0));
    CK(dnnl_stream_create(&st, eng, dnnl_stream_default_flags));
    const dnnl_version_t* v = dnnl_version();
    printf("bench_gemm_onednn: oneDNN %d.%d.%d, %d threads\n\n", v->major, v->minor, v->patch, omp_get_max_threads());
    printf("| shape (M x N x K) | oneDNN bf16 GFLOP/s | with the conversion | implementation |\n|---|---:|---:|---|\n");
    for (size_t s = 0; s < sizeof shapes / sizeof shapes[0]; s++) {
        const int M = shapes[s][0], N = shapes[s][1], K = shapes[s][2];
        dnnl_memory_desc_t a_md, b_md, c_md;
        dnnl_dims_t ad = {M, K}, bd = {K, N}, cd = {M, N};
        CK(dnnl_memory_desc_init_by_tag(&a_md, 2, ad, dnnl_bf16, dnnl_ab));
        CK(dnnl_memory_desc_init_by_tag(&b_md, 2, bd, dnnl_bf16, dnnl_ab));
        CK(dnnl_memory_desc_init_by_tag(&c_md, 2, cd, dnnl_f32, dnnl_ab));
        dnnl_matmul_desc_t md;
        CK(dnnl_matmul_desc_init(&md, &a_md, &b_md, NULL, &c_md));
        dnnl_primitive_desc_t pd;
        CK(dnnl_primitive_desc_create(&pd, &md, NULL, eng, NULL));
        const char* impl = "?";
        dnnl_primitive_desc_query(pd, dnnl_query_impl_info_str, 0, &impl);
        dnnl_primitive_t prim;
        CK(dnnl_primitive_create(&prim, pd));
        size_t na = (size_t)M * K, nb = (size_t)K * N;
        uint16_t *a = malloc(2 * na), *b = malloc(2 * nb);
        float *fa = malloc(4 * na), *fb = malloc(4 * nb), *c = malloc(4 * (size_t)M * N);
        if (!a || !b || !fa || !fb || !c) return 1;
        mlb_rng_fill_uniform(fa, na, 1, 1, 0, -1, 1);
        mlb_rng_fill_uniform(fb, nb, 1, 2, 0, -1, 1);
        dnnl_memory_t am, bm, cm;
        CK(dnnl_memory_create(&am, &a_md, eng, a));
        CK(dnnl_memory_create(&bm, &b_md, eng, b));
        CK(dnnl_memory_create(&cm, &c_md, eng, c));
        dnnl_exec_arg_t args[3] = {{DNNL_ARG_SRC, am}, {DNNL_ARG_WEIGHTS, bm}, {DNNL_ARG_DST, cm}};
        double best = 1e30, best_all = 1e30;
        for (int r = 0; r < 4; r++) {
            double t0 = mlb_now_seconds();
#pragma omp parallel for schedule(static)
            for (size_t i = 0; i < na; i++) a[i] = to_bf16(fa[i]);
#pragma omp parallel for schedule(static)
            for (size_t i = 0; i < nb; i++) b[i] = to_bf16(fb[i]);
            double t1 = mlb_now_seconds();
            CK(dnnl_primitive_execute(prim, st, 3, args));
            CK(dnnl_stream_wait(st));
            double t2 = mlb_now_seconds();
            if (r && t2 - t1 < best) best = t2 - t1;
            if (r && t2 - t0 < best_all) best_all = t2 - t0;
        }
        double gf = 2.0 * M * N * K / 1e9;
        printf("| %d x %d x %d | %.1f | %.1f | %s |\n", M, N, K, gf / best, gf / best_all, impl);
        fflush(stdout);
        dnnl_primitive_destroy(prim);
        dnnl_primitive_desc_destroy(pd);
        dnnl_memory_destroy(am); dnnl_memory_destroy(bm); dnnl_memory_destroy(cm);
        free(a); free(b); free(fa); free(fb); free(c);
    }
    dnnl_stream_destroy(st);
    dnnl_engine_destroy(eng);
    return 0;
}
