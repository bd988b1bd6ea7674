// The appearance stage's GPU part against the CPU: the material network (hash grid, MLPs, frozen
// decoder, AdamW; and the geometry network, the same field) moved with mlb_field_use_device to
// CUDA's fp32 table, and the renderer's split-sum shading on the GPU, each beside the same computation on the host. Bounds (relative
// L2): 1e-4 for values (the hash grid's sums and cuBLAS's in another order; the GPU shades in float
// where the CPU uses double: test_cuda_shade's 1e-4), 1e-3 for gradients (the table gradient's
// atomic adds in run-dependent order; test_cuda_shade's backward bound). Skips without a GPU.
#include "appearance_test_util.h"
#include "matlaber/backend.h"

TEST(material_net_latent) {
    REQUIRE_GPU();
    field_twin_check(mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32), MLB_FIELD_MATERIAL, MLB_MATERIAL_LATENT, 200000, 1e-4);
}

TEST(material_net_direct) {
    REQUIRE_GPU();
    field_twin_check(mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32), MLB_FIELD_MATERIAL, MLB_MATERIAL_DIRECT, 50000, 1e-4);
}

// The geometry network (no biases, linear output) on the same path (the same field).
TEST(geometry_net) {
    REQUIRE_GPU();
    field_twin_check(mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32), MLB_FIELD_GEOMETRY, MLB_MATERIAL_LATENT, 100000, 1e-4);
}

// 9 views at 128² with 2× supersampling: ~150k shaded samples per step
TEST(appearance_render_and_backward) {
    REQUIRE_GPU();
    appearance_twin_check(mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32), 9, 128, 2, 3, 1e-4);
}

int main(void) {
    RUN(material_net_latent);
    RUN(material_net_direct);
    RUN(geometry_net);
    RUN(appearance_render_and_backward);
    return test_summary();
}
