// The CUDA split-sum shading forward and backward against mlb_shade_forward/backward (CPU, double
// arithmetic from the same float texels) on random materials, normals and view directions, both
// Fresnel modes, a rotated light. Skips without a GPU.
// Bound: the GPU computes in float. The function is continuous (seamless bilinear cube lookups,
// linear mip blend, clamped LUT), so float rounding of the lookup coordinates (~1e-7 of a face,
// times texel gradients) moves the result by ~1e-6 relative; 1e-4 on the relative L2 error, and
// 1e-3 of the largest value elementwise. The gradients contain the bilinear lookups' slopes, which
// jump at texel boundaries: a point whose float and double coordinates fall on two sides of one takes
// a different slope, so only the relative L2 error is bounded, by 1e-3 (the kernel body compiled
// for the host gave 1.5e-6 over 200 000 points).
#include "cuda_test_util.h"
#include "matlaber/envmap.h"
#include "matlaber/shade.h"

static void unit(float* d, uint64_t seed, uint64_t stream, uint64_t i) {
    double a[3], l;
    do {
        for (int k = 0; k < 3; k++) a[k] = mlb_rng_normal_f64(seed, stream, 3 * i + k);
        l = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        seed++;
    } while (l < 1e-6);
    for (int k = 0; k < 3; k++) d[k] = (float)(a[k] / l);
}

TEST(shading_matches_cpu) {
    REQUIRE_GPU();
    uint64_t seed = test_seed();
    mlb_envmap env;
    REQUIRE(mlb_envmap_named(&env, "sky", 64) == MLB_OK);
    mlb_envlight L;
    mlb_envlight_options o = {.face_size = 64, .min_size = 8};
    REQUIRE(mlb_envlight_build(&L, &env, &o) == MLB_OK);
    mlb_envlight_set_rotation(&L, 0.7f);
    mlb_cuda_envlight dl;
    REQUIRE(mlb_cuda_envlight_upload(&dl, &L) == MLB_OK);
    enum { N = 50000 };
    float *kd = host_alloc(3 * N), *ks = host_alloc(3 * N), *kr = host_alloc(N), *n = host_alloc(3 * N), *v = host_alloc(3 * N);
    float *out_c = host_alloc(3 * N), *out_g = host_alloc(3 * N);
    fill_uniform(kd, 3 * N, seed, 1, 0, 1);
    fill_uniform(ks, 3 * N, seed, 2, 0, 1);
    fill_uniform(kr, N, seed, 3, 0, 1.05f);   // past 1: the clamped last mip
    for (int i = 0; i < N; i++) {
        unit(n + 3 * i, seed, 4, i);
        unit(v + 3 * i, seed + 7, 5, i);
        if (i % 4 == 0)   // most real views face the surface: make a quarter have n.v > 0 for sure
            for (int k = 0; k < 3; k++) v[3 * i + k] = n[3 * i + k];
    }
    float *d_kd = dev_floats(kd, 3 * N), *d_ks = dev_floats(ks, 3 * N), *d_kr = dev_floats(kr, N), *d_n = dev_floats(n, 3 * N),
          *d_v = dev_floats(v, 3 * N), *d_out = dev_floats(NULL, 3 * N);
    REQUIRE(d_kd && d_ks && d_kr && d_n && d_v && d_out);
    for (int fm = 0; fm < 2; fm++) {
        mlb_fresnel fr = fm ? MLB_FRESNEL_SCHLICK : MLB_FRESNEL_PAPER;
        REQUIRE(mlb_shade_forward(out_c, kd, ks, kr, n, v, N, &L, fr) == MLB_OK);
        CHECK_MSG(mlb_cuda_shade_forward(d_out, d_kd, d_ks, d_kr, d_n, d_v, N, &dl, fr) == MLB_OK, "%s", mlb_last_error());
        REQUIRE(host_floats(out_g, d_out, 3 * N));
        CHECK_PARITY(fm ? "shade forward (Schlick)" : "shade forward (paper Fresnel)", out_g, out_c, 3 * (size_t)N, 1e-4);
        cmp_result r = compare(out_g, out_c, 3 * (size_t)N);
        CHECK_MSG(r.max_abs <= 1e-3 * r.ref_max, "max abs error %.3e of max %.3e", r.max_abs, r.ref_max);

        // backward: accumulate onto random starting gradients on both sides
        float* gc[5];
        float* gg[5];
        float* dg[5];
        size_t sz[5] = {3 * (size_t)N, 3 * (size_t)N, N, 3 * (size_t)N, 3 * (size_t)N};
        const char* names[5] = {"dkd", "dks", "dkr", "dn", "dv"};
        for (int j = 0; j < 5; j++) {
            gc[j] = host_alloc(sz[j]);
            gg[j] = host_alloc(sz[j]);
            fill_uniform(gc[j], sz[j], seed, 10 + j, -1, 1);
            dg[j] = dev_floats(gc[j], sz[j]);
            REQUIRE(dg[j]);
        }
        float* gout = host_alloc(3 * N);
        fill_uniform(gout, 3 * N, seed, 20, -1, 1);
        float* d_gout = dev_floats(gout, 3 * N);
        REQUIRE(d_gout);
        REQUIRE(mlb_shade_backward(gc[0], gc[1], gc[2], gc[3], gc[4], gout, kd, ks, kr, n, v, N, &L, fr) == MLB_OK);
        CHECK_MSG(mlb_cuda_shade_backward(dg[0], dg[1], dg[2], dg[3], dg[4], d_gout, d_kd, d_ks, d_kr, d_n, d_v, N, &dl, fr) ==
                  MLB_OK, "%s", mlb_last_error());
        for (int j = 0; j < 5; j++) {
            REQUIRE(host_floats(gg[j], dg[j], sz[j]));
            char what[64];
            snprintf(what, sizeof what, "shade backward %s (%s)", names[j], fm ? "Schlick" : "paper");
            CHECK_PARITY(what, gg[j], gc[j], sz[j], 1e-3);
            mlb_cuda_free(dg[j]);
            free(gc[j]);
            free(gg[j]);
        }
        mlb_cuda_free(d_gout);
        free(gout);
    }
    mlb_cuda_free(d_kd); mlb_cuda_free(d_ks); mlb_cuda_free(d_kr); mlb_cuda_free(d_n); mlb_cuda_free(d_v); mlb_cuda_free(d_out);
    free(kd); free(ks); free(kr); free(n); free(v); free(out_c); free(out_g);
    mlb_cuda_envlight_free(&dl);
    mlb_envlight_free(&L);
    mlb_envmap_free(&env);
}

int main(void) {
    RUN(shading_matches_cpu);
    return test_summary();
}
