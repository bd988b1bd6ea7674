// CUDA kernels against their CPU versions, on the same random inputs. Skips (exit 77) when this
// build has no CUDA part or the machine has no GPU; scripts/gpu-parity.sh runs it on a GPU machine.
#include "test.h"
#include "matlaber/device.h"
#include "matlaber/nn.h"
#include "matlaber/rng.h"

TEST(adam_update_matches_cpu) {
    if (!mlb_cuda_compiled()) SKIP("this build has no CUDA part (nvcc not found at build time)");
    if (mlb_cuda_device_count() == 0) SKIP("no GPU visible");
    enum { N = 100003 };   // not a multiple of the block size
    static float p_cpu[N], p_gpu[N], g[N], m_cpu[N], v_cpu[N], m_gpu[N], v_gpu[N];
    for (int i = 0; i < N; i++) {
        p_cpu[i] = p_gpu[i] = mlb_rng_normal(1, 1, i);
        m_cpu[i] = v_cpu[i] = m_gpu[i] = v_gpu[i] = 0;
    }
    float *dp, *dg, *dm, *dv;
    size_t bytes = sizeof(float) * N;
    REQUIRE(mlb_cuda_malloc((void**)&dp, bytes) == MLB_OK && mlb_cuda_malloc((void**)&dg, bytes) == MLB_OK &&
            mlb_cuda_malloc((void**)&dm, bytes) == MLB_OK && mlb_cuda_malloc((void**)&dv, bytes) == MLB_OK);
    REQUIRE(mlb_cuda_copy_to_device(dp, p_gpu, bytes) == MLB_OK && mlb_cuda_copy_to_device(dm, m_gpu, bytes) == MLB_OK &&
            mlb_cuda_copy_to_device(dv, v_gpu, bytes) == MLB_OK);
    for (int decoupled = 0; decoupled <= 1; decoupled++) {
        mlb_adam_config cfg = {.lr = 1e-2, .beta1 = 0.9, .beta2 = 0.99, .eps = 1e-15, .weight_decay = 0.05, .decoupled = decoupled};
        for (long t = 1; t <= 5; t++) {
            for (int i = 0; i < N; i++) g[i] = mlb_rng_normal(2, (uint64_t)t + 10 * decoupled, i);
            REQUIRE(mlb_cuda_copy_to_device(dg, g, bytes) == MLB_OK);
            REQUIRE(mlb_cuda_adam_update(dp, dg, dm, dv, N, &cfg, t) == MLB_OK);
            adam_update(p_cpu, g, m_cpu, v_cpu, N, &cfg, t);
        }
    }
    REQUIRE(mlb_cuda_copy_to_host(p_gpu, dp, bytes) == MLB_OK);
    double worst = 0;
    for (int i = 0; i < N; i++) {
        CHECK(isfinite(p_gpu[i]));
        worst = fmax(worst, fabs((double)p_gpu[i] - p_cpu[i]) / (fabs(p_cpu[i]) + 1e-3));
    }
    printf("  worst relative difference %.2e over %d parameters\n", worst, N);
    CHECK(worst < 1e-5);
    mlb_cuda_free(dp); mlb_cuda_free(dg); mlb_cuda_free(dm); mlb_cuda_free(dv);
}

TEST(missing_gpu_is_a_clear_error) {
    if (mlb_cuda_compiled() && mlb_cuda_device_count() > 0) SKIP("a GPU is present");
    mlb_device d;
    CHECK(mlb_device_parse("cuda", &d) == MLB_ERR_DEVICE);
    CHECK(strstr(mlb_last_error(), "--device cpu") != NULL);
    CHECK(mlb_device_parse("auto", &d) == MLB_OK && d == MLB_DEVICE_CPU);
    CHECK(mlb_device_parse("tpu", &d) == MLB_ERR_ARG);
}

int main(void) {
    RUN(adam_update_matches_cpu);
    RUN(missing_gpu_is_a_clear_error);
    return test_summary();
}
