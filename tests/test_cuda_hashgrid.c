// The CUDA hash-grid encoding against hashgrid_forward/backward (CPU float) on random points, some
// outside [0,1]^3 (clamped). Skips without a GPU.
// Bounds: the forward does the CPU's float operations in the CPU's order without FMA contraction,
// so it should agree bitwise (checked: max-abs 0, reported); dparams is an atomicAdd scatter (the
// order of the float additions differs) and dx uses FMAs: relative L2 1e-5.
#include "cuda_test_util.h"
#include "matlaber/hashgrid.h"

static void hashgrid_case(const mlb_hashgrid_config* cfg, int N, uint64_t seed, const char* name) {
    mlb_hashgrid g;
    REQUIRE(hashgrid_init(&g, cfg, NULL) == MLB_OK);
    size_t np = g.n_params, D = (size_t)g.out_dim;
    float *params = host_alloc(np), *x = host_alloc(3 * (size_t)N), *dout = host_alloc(N * D);
    float *out_c = host_alloc(N * D), *out_g = host_alloc(N * D);
    float *dp_c = host_alloc(np), *dp_g = host_alloc(np), *dx_c = host_alloc(3 * (size_t)N), *dx_g = host_alloc(3 * (size_t)N);
    fill_uniform(params, np, seed, 1, -1, 1);   // larger than the init's 1e-4: errors stay visible
    fill_uniform(x, 3 * (size_t)N, seed, 2, -0.05f, 1.05f);
    fill_uniform(dout, N * D, seed, 3, -1, 1);
    fill_uniform(dp_c, np, seed, 4, -1, 1);
    fill_uniform(dx_c, 3 * (size_t)N, seed, 5, -1, 1);
    g.params = params;
    float *d_params = dev_floats(params, np), *d_x = dev_floats(x, 3 * (size_t)N), *d_dout = dev_floats(dout, N * D);
    float *d_out = dev_floats(NULL, N * D), *d_dp = dev_floats(dp_c, np), *d_dx = dev_floats(dx_c, 3 * (size_t)N);
    char what[128];
    if (!(d_params && d_x && d_dout && d_out && d_dp && d_dx)) {
        CHECK_MSG(0, "device allocation: %s", mlb_last_error());
        goto done;
    }
    hashgrid_forward(&g, out_c, x, N);
    hashgrid_backward(&g, dp_c, dx_c, dout, x, N);
    CHECK_MSG(mlb_cuda_hashgrid_forward(&g, d_params, d_out, d_x, N) == MLB_OK, "%s", mlb_last_error());
    CHECK_MSG(mlb_cuda_hashgrid_backward(&g, d_params, d_dp, d_dx, d_dout, d_x, N) == MLB_OK, "%s", mlb_last_error());
    if (!host_floats(out_g, d_out, N * D) || !host_floats(dp_g, d_dp, np) || !host_floats(dx_g, d_dx, 3 * (size_t)N)) {
        CHECK_MSG(0, "copy back: %s", mlb_last_error());
        goto done;
    }
    snprintf(what, sizeof what, "hashgrid %s forward", name);
    CHECK_PARITY(what, out_g, out_c, N * D, 1e-6);
    size_t differ = 0;
    for (size_t i = 0; i < N * D; i++) differ += out_g[i] != out_c[i];
    printf("  forward: %zu of %zu values differ bitwise from the CPU\n", differ, N * D);
    snprintf(what, sizeof what, "hashgrid %s dparams", name);
    CHECK_PARITY(what, dp_g, dp_c, np, 1e-5);
    snprintf(what, sizeof what, "hashgrid %s dx", name);
    CHECK_PARITY(what, dx_g, dx_c, 3 * (size_t)N, 1e-5);
done:
    mlb_cuda_free(d_params); mlb_cuda_free(d_x); mlb_cuda_free(d_dout); mlb_cuda_free(d_out); mlb_cuda_free(d_dp);
    mlb_cuda_free(d_dx);
    free(params); free(x); free(dout); free(out_c); free(out_g); free(dp_c); free(dp_g); free(dx_c); free(dx_g);
}

TEST(hashgrid_matches_cpu) {
    REQUIRE_GPU();
    uint64_t seed = test_seed();
    mlb_hashgrid_config def = mlb_hashgrid_default();   // 16 levels x 2, 2^19: dense and hashed levels
    hashgrid_case(&def, 20000, seed + 1, "default");
    mlb_hashgrid_config odd = {6, 3, 3001, 5, 1.7};     // T not a power of two (the modulo path), F = 3
    hashgrid_case(&odd, 5003, seed + 2, "odd");
    mlb_hashgrid_config wide = {4, 8, 1u << 12, 16, 2.0}; // F = 8
    hashgrid_case(&wide, 777, seed + 3, "F8");
}

int main(void) {
    RUN(hashgrid_matches_cpu);
    return test_summary();
}
