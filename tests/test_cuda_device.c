// Device selection and the CUDA error paths. Runs everywhere: without the CUDA part, without a
// driver or GPU (the clear errors), and with a GPU (selection succeeds, errors name file:line).
#include "cuda_test_util.h"

TEST(select_cpu_and_unknown_names) {
    mlb_device d = MLB_DEVICE_CUDA;
    CHECK(mlb_device_select("cpu", &d) == MLB_OK && d == MLB_DEVICE_CPU && mlb_device_current() == MLB_DEVICE_CPU);
    CHECK(mlb_device_select("tpu", &d) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "tpu") != NULL);
    CHECK(mlb_device_select("cuda:", &d) == MLB_ERR_ARG);
    CHECK(mlb_device_select("cuda:x", &d) == MLB_ERR_ARG);
    CHECK(mlb_device_select("cudax", &d) == MLB_ERR_ARG);
    CHECK(strcmp(mlb_device_name(MLB_DEVICE_CUDA), "cuda") == 0 && strcmp(mlb_device_name(MLB_DEVICE_CPU), "cpu") == 0);
}

TEST(missing_gpu_is_a_clear_error) {
    int n = 0;
    if (mlb_cuda_compiled() && mlb_cuda_probe(&n) == MLB_OK && mlb_cuda_init(0) == MLB_OK) SKIP("a GPU is present");
    mlb_device d;
    CHECK(mlb_device_parse("cuda", &d) == MLB_ERR_DEVICE);
    CHECK(strstr(mlb_last_error(), "--device cpu") != NULL);
    CHECK(mlb_device_select("cuda", &d) == MLB_ERR_DEVICE);
    const char* msg = mlb_last_error();
    printf("  --device cuda: %s\n", msg);
    CHECK(strstr(msg, "--device cuda") != NULL);
    if (!mlb_cuda_compiled()) CHECK(strstr(msg, "built without CUDA") != NULL);
    else CHECK(strstr(msg, "cudaGetDeviceCount") != NULL);   // CUDA's own error, with the call that gave it
    CHECK(mlb_device_select("cuda:1", &d) == MLB_ERR_DEVICE);
    CHECK(mlb_device_select("auto", &d) == MLB_OK && d == MLB_DEVICE_CPU);
    CHECK(mlb_device_option("cpu", &d) == MLB_OK && d == MLB_DEVICE_CPU);
    setenv("MATLABER_DEVICE", "cuda", 1);
    CHECK(mlb_device_option(NULL, &d) == MLB_ERR_DEVICE);
    setenv("MATLABER_DEVICE", "cpu", 1);
    CHECK(mlb_device_option(NULL, &d) == MLB_OK && d == MLB_DEVICE_CPU);
    unsetenv("MATLABER_DEVICE");
    CHECK(mlb_device_option(NULL, &d) == MLB_OK && d == MLB_DEVICE_CPU);   // auto
    CHECK(mlb_device_option("cuda", &d) == MLB_ERR_DEVICE);
}

TEST(cuda_calls_without_gpu_fail_cleanly) {
    int n = 0;
    if (mlb_cuda_compiled() && mlb_cuda_probe(&n) == MLB_OK && mlb_cuda_init(0) == MLB_OK) SKIP("a GPU is present");
    void* p = (void*)1;
    CHECK(mlb_cuda_malloc(&p, 1024) == MLB_ERR_DEVICE);
    CHECK(p == NULL);
    const char* msg = mlb_last_error();
    printf("  mlb_cuda_malloc: %s\n", msg);
    if (mlb_cuda_compiled()) CHECK(strstr(msg, "cudaMalloc") != NULL && strstr(msg, ".cu:") != NULL);   // file:line: call
    else CHECK(strstr(msg, "built without CUDA") != NULL);
    float x = 0;
    CHECK(mlb_cuda_activation_forward(&x, &x, 1, MLB_ACT_RELU) != MLB_OK || mlb_cuda_sync() != MLB_OK);
    CHECK(mlb_cuda_free(NULL) == MLB_OK);
    char desc[64];
    CHECK(mlb_cuda_describe(0, desc, sizeof desc) == MLB_ERR_DEVICE);
}

TEST(gpu_present_selects_and_describes) {
    REQUIRE_GPU();
    mlb_device d;
    CHECK(mlb_device_select("cuda", &d) == MLB_OK && d == MLB_DEVICE_CUDA && mlb_device_current() == MLB_DEVICE_CUDA);
    CHECK(mlb_device_select("auto", &d) == MLB_OK && d == MLB_DEVICE_CUDA);
    char desc[256];
    CHECK(mlb_cuda_describe(0, desc, sizeof desc) == MLB_OK);
    printf("  cuda:0: %s\n", desc);
    int n = mlb_cuda_device_count();
    char name[32];
    snprintf(name, sizeof name, "cuda:%d", n);
    CHECK(mlb_device_select(name, &d) == MLB_ERR_DEVICE);   // one past the last GPU
    CHECK(strstr(mlb_last_error(), "visible") != NULL);
    // a launch error is reported at the op, naming the kernel: an absurd shape
    CHECK(mlb_cuda_attention_forward(NULL, NULL, NULL, NULL, 10, 1, 4, 20, 3, 0) == MLB_ERR_ARG);
    // an impossible allocation names cudaMalloc and CUDA's message
    void* p;
    CHECK(mlb_cuda_malloc(&p, (size_t)1 << 50) == MLB_ERR_DEVICE);
    CHECK(strstr(mlb_last_error(), "cudaMalloc") != NULL);
    printf("  1 PiB: %s\n", mlb_last_error());
    CHECK(mlb_device_select("cpu", &d) == MLB_OK);
}

int main(void) {
    RUN(select_cpu_and_unknown_names);
    RUN(missing_gpu_is_a_clear_error);
    RUN(cuda_calls_without_gpu_fail_cleanly);
    RUN(gpu_present_selects_and_describes);
    return test_summary();
}
