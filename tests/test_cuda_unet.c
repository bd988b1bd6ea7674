// The UNet on the GPU against the CPU: first its new ops one by one (conv2d and attention as
// tensor-core GEMMs, the layout glue), then whole forwards of the tiny random SD1 and SD2 UNets
// through the one forward written against backend.h. Skips without a GPU.
// Bounds (relative L2): fp32 GEMMs 1e-5 per op (sums of up to 5760 products in another order);
// tf32 and fp16 operands 3e-3, bf16 2e-2 (unit roundoff 2^-11 / 2^-8 per operand, test_cuda_parity);
// the layout ops are copies and single float adds: bitwise (0). A whole UNet compounds ~60 layers,
// each normalised: fp32 1e-4, tf32/fp16 1e-2, bf16 5e-2.
#include "cuda_test_util.h"
#include "matlaber/backend.h"
#include "matlaber/unet.h"
#include "matlaber/unet_random.h"

static const char* prec_names[] = {"fp32", "tf32", "fp16", "bf16"};
static const double op_bound[] = {1e-5, 3e-3, 3e-3, 2e-2};
static const double unet_bound[] = {1e-4, 1e-2, 1e-2, 5e-2};

static void conv_case(mlb_conv2d cv, int with_bias, uint64_t seed) {
    size_t n_in = (size_t)cv.N * cv.C * cv.H * cv.W, n_w = (size_t)cv.OC * cv.C * cv.KH * cv.KW;
    size_t n_out = (size_t)cv.N * cv.OC * mlb_conv2d_out_h(&cv) * mlb_conv2d_out_w(&cv);
    float *x = host_alloc(n_in), *w = host_alloc(n_w), *b = host_alloc(cv.OC), *ref = host_alloc(n_out), *got = host_alloc(n_out);
    fill_uniform(x, n_in, seed, 1, -1, 1);
    fill_uniform(w, n_w, seed, 2, -0.3f, 0.3f);
    fill_uniform(b, cv.OC, seed, 3, -1, 1);
    CHECK(conv2d_forward(ref, x, w, with_bias ? b : NULL, &cv, NULL) == MLB_OK);
    float *dx = dev_floats(x, n_in), *dw = dev_floats(w, n_w), *db = dev_floats(b, cv.OC);
    for (int p = 0; p < 4; p++) {
        float* dy = dev_floats(NULL, n_out);
        char what[160];
        snprintf(what, sizeof what, "conv %dx%d s%d pad %d,%d,%d,%d N%d C%d->%d %dx%d %s", cv.KH, cv.KW, cv.stride_h,
                 cv.pad_top, cv.pad_left, cv.pad_bottom, cv.pad_right, cv.N, cv.C, cv.OC, cv.H, cv.W, prec_names[p]);
        mlb_status st = mlb_cuda_conv2d_forward(dy, dx, dw, with_bias ? db : NULL, &cv, (mlb_gemm_precision)p);
        CHECK_MSG(st == MLB_OK, "%s: %s", what, mlb_last_error());
        if (st == MLB_OK && host_floats(got, dy, n_out)) CHECK_PARITY(what, got, ref, n_out, op_bound[p]);
        mlb_cuda_free(dy);
    }
    mlb_cuda_free(dx); mlb_cuda_free(dw); mlb_cuda_free(db);
    free(x); free(w); free(b); free(ref); free(got);
}

static void conv_cases(void);

// Every case on both paths: cuDNN when the build has it (symmetric padding) and the im2col GEMMs.
TEST(conv2d_matches_cpu) {
    REQUIRE_GPU();
    for (int path = mlb_cuda_cudnn_version() ? 0 : 1; path < 2; path++) {
        mlb_cuda_use_cudnn(path == 0);
        printf("  convolutions on %s\n", path == 0 ? "cuDNN" : "the GEMM path");
        conv_cases();
    }
    mlb_cuda_use_cudnn(1);
}

static void conv_cases(void) {
    uint64_t s = test_seed();
    mlb_conv2d a = mlb_conv2d_make(2, 32, 16, 16, 64, 3, 1, 1);   // a UNet 3x3
    conv_case(a, 1, s + 1);
    conv_case(mlb_conv2d_make(3, 24, 17, 15, 24, 3, 2, 1), 1, s + 2);   // stride-2 downsample, odd sizes
    conv_case(mlb_conv2d_make(2, 96, 8, 8, 32, 1, 1, 0), 1, s + 3);     // 1x1 shortcut (the plain GEMM path)
    conv_case(mlb_conv2d_make(1, 4, 12, 12, 8, 3, 1, 1), 0, s + 4);     // conv_in, no bias
    mlb_conv2d v = mlb_conv2d_make(2, 8, 10, 10, 8, 3, 2, 0);            // the VAE's asymmetric pad
    v.pad_bottom = v.pad_right = 1;
    conv_case(v, 1, s + 5);
    mlb_conv2d r = mlb_conv2d_make(1, 5, 9, 11, 7, 3, 1, 0);             // a 5x3 kernel, pads per side
    r.KH = 5; r.pad_top = 2; r.pad_bottom = 1; r.pad_left = 0; r.pad_right = 1; r.stride_w = 2;
    conv_case(r, 1, s + 6);
}

// At fp16/bf16 with heads up to 128 wide both paths: the fused kernel (flash_attention.cu) and the
// batched GEMMs with the row softmax; each writes out and lse, both checked against the CPU.
static void sdpa_case(int B, int Tq, int Tk, int C, int NH, int fused, uint64_t seed) {
    int ldq = fused ? 3 * C : C, ldkv = fused ? 3 * C : C;
    size_t nq = (size_t)B * Tq * ldq, nkv = (size_t)B * Tk * ldkv, no = (size_t)B * Tq * C, nl = (size_t)B * NH * Tq;
    float *q = host_alloc(nq), *k = fused ? q + C : host_alloc(nkv), *v = fused ? q + 2 * C : host_alloc(nkv);
    fill_uniform(q, nq, seed, 1, -1, 1);
    if (!fused) {
        fill_uniform(k, nkv, seed, 2, -1, 1);
        fill_uniform(v, nkv, seed, 3, -1, 1);
    }
    float *ref = host_alloc(no), *got = host_alloc(no), *lse_ref = host_alloc(nl), *lse_got = host_alloc(nl);
    CHECK(sdpa_forward(ref, lse_ref, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL) == MLB_OK);
    float *dq = dev_floats(q, nq), *dk = fused ? dq + C : dev_floats(k, nkv), *dv = fused ? dq + 2 * C : dev_floats(v, nkv);
    for (int p = 0; p < 4; p++) {
        int half = p == MLB_GEMM_FP16 || p == MLB_GEMM_BF16, fusable = half && C / NH <= 128;
        for (int flash = 2 * fusable; flash >= 0; flash--) {   // 2: the fused kernel, 128 rows per block
            mlb_cuda_use_flash(flash > 0);
            mlb_cuda_flash_rows(flash == 2 ? 128 : 64);
            float *dout = dev_floats(NULL, no), *dlse = dev_floats(NULL, nl);
            char what[160];
            snprintf(what, sizeof what, "sdpa B%d Tq%d Tk%d C%d NH%d%s %s%s", B, Tq, Tk, C, NH, fused ? " fused" : "",
                     prec_names[p], fusable ? (flash == 2 ? " fused kernel, 128 rows" : flash ? " fused kernel" : " GEMMs") : "");
            mlb_status st = mlb_cuda_sdpa_forward(dout, dlse, dq, dk, dv, B, Tq, Tk, C, NH, ldq, ldkv, (mlb_gemm_precision)p);
            CHECK_MSG(st == MLB_OK, "%s: %s", what, mlb_last_error());
            if (st == MLB_OK && host_floats(got, dout, no)) CHECK_PARITY(what, got, ref, no, op_bound[p]);
            strncat(what, " lse", sizeof what - strlen(what) - 1);
            if (st == MLB_OK && host_floats(lse_got, dlse, nl)) CHECK_PARITY(what, lse_got, lse_ref, nl, op_bound[p]);
            mlb_cuda_free(dout);
            mlb_cuda_free(dlse);
        }
    }
    mlb_cuda_use_flash(1);
    mlb_cuda_flash_rows(64);
    mlb_cuda_free(dq);
    if (!fused) { mlb_cuda_free(dk); mlb_cuda_free(dv); free(k); free(v); }
    free(q); free(ref); free(got); free(lse_ref); free(lse_got);
}

TEST(sdpa_matches_cpu) {
    REQUIRE_GPU();
    uint64_t s = test_seed();
    sdpa_case(2, 256, 256, 320, 8, 0, s + 11);   // UNet self-attention (hd 40)
    sdpa_case(2, 256, 77, 320, 8, 0, s + 12);    // cross-attention to 77 tokens
    sdpa_case(3, 50, 50, 96, 3, 1, s + 13);      // fused qkv, odd T
    sdpa_case(1, 64, 7, 64, 1, 0, s + 14);       // one wide head, short context
    sdpa_case(1, 1000, 1000, 320, 8, 0, s + 15); // many key tiles, T not a multiple of 64
    sdpa_case(2, 300, 300, 640, 8, 0, s + 16);   // UNet level 2 (hd 80)
    sdpa_case(2, 64, 77, 640, 10, 0, s + 17);    // hd 64 cross-attention, Tk one tile and 13 keys
    sdpa_case(2, 130, 130, 320, 5, 1, s + 18);   // SD 2 heads of 64, fused qkv
    sdpa_case(1, 70, 90, 128, 1, 0, s + 19);     // hd 128: the fused kernel's widest head
    sdpa_case(2, 64, 77, 1280, 8, 0, s + 22);    // hd 160 (UNet level 4): the GEMMs only
    sdpa_case(1, 33, 40, 25, 1, 0, s + 20);      // hd 25, padded to 32
    sdpa_case(1, 20, 70, 24, 2, 0, s + 23);      // hd 12, padded to 16
    sdpa_case(1, 40, 40, 512, 1, 0, s + 21);     // the VAE's one head of 512: the GEMMs only
    float* d = dev_floats(NULL, 64);
    CHECK(mlb_cuda_sdpa_forward(d, NULL, d, d, d, 1, 2, 2, 30, 4, 30, 30, MLB_GEMM_FP32) == MLB_ERR_ARG);   // 4 does not divide 30
    CHECK(mlb_cuda_sdpa_forward(d, NULL, d, d, d, 1, 2, 2, 32, 4, 16, 32, MLB_GEMM_FP32) == MLB_ERR_ARG);   // ldq < C
    mlb_cuda_free(d);
}

// The glue ops must give the CPU's bits: the same single float operation per value.
TEST(layout_ops_bitwise) {
    REQUIRE_GPU();
    uint64_t s = test_seed() + 21;
    const mlb_backend *cpu = mlb_backend_cpu(), *gpu = mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32);
    const int N = 3, C = 40, H = 9, W = 7, HW = H * W;
    size_t n = (size_t)N * C * HW;
    float *x = host_alloc(4 * n), *y = host_alloc(4 * n), *v = host_alloc(N * C), *ref = host_alloc(4 * n), *got = host_alloc(4 * n);
    fill_uniform(x, 4 * n, s, 1, -3, 3);
    fill_uniform(y, 4 * n, s, 2, -3, 3);
    fill_uniform(v, N * C, s, 3, -1, 1);
    float *dx = dev_floats(x, 4 * n), *dy = dev_floats(y, 4 * n), *dv = dev_floats(v, N * C), *dz = dev_floats(NULL, 4 * n);
    struct { const char* what; size_t n_out; } cases[] = {
        {"add", n}, {"add_channel", n}, {"transpose", n}, {"transpose accumulate", n}, {"geglu", (size_t)N * C * (HW / 2)},
        {"upsample 2x", 4 * n}, {"copy_rows (concat)", 2 * n},
    };
    for (int c = 0; c < 7; c++) {
        memcpy(ref, y, 4 * n * sizeof(float));
        CHECK(gpu->upload(dz, y, 4 * n) == MLB_OK);
        for (int side = 0; side < 2; side++) {
            const mlb_backend* be = side ? gpu : cpu;
            float *X = side ? dx : x, *Z = side ? dz : ref, *V = side ? dv : v;
            mlb_status st = MLB_OK;
            switch (c) {
            case 0: st = be->add(Z, X, n); break;
            case 1: st = be->add_channel(Z, V, N, C, HW); break;
            case 2: st = be->transpose_last2(Z, X, N, C, HW, 0); break;
            case 3: st = be->transpose_last2(Z, X, N, HW, C, 1); break;
            case 4: st = be->geglu(Z, X, N * C, HW / 2); break;
            case 5: st = be->upsample_nearest2x(Z, X, N, C, H, W); break;
            case 6: st = be->copy_rows(Z, 2 * C * HW, X, C * HW, C * HW, N);
                    if (st == MLB_OK) st = be->copy_rows(Z + C * HW, 2 * C * HW, X + n, C * HW, C * HW, N);
                    break;
            }
            CHECK_MSG(st == MLB_OK, "%s on the %s: %s", cases[c].what, side ? "GPU" : "CPU", mlb_last_error());
        }
        CHECK(gpu->download(got, dz, cases[c].n_out) == MLB_OK);
        if (c == 4) CHECK_PARITY(cases[c].what, got, ref, cases[c].n_out, 1e-6);   // erff vs libm: a few ulps
        else {
            CHECK_PARITY(cases[c].what, got, ref, cases[c].n_out, 0);
            CHECK_MSG(!memcmp(got, ref, cases[c].n_out * sizeof(float)), "%s: not bitwise equal", cases[c].what);
        }
    }
    mlb_cuda_free(dx); mlb_cuda_free(dy); mlb_cuda_free(dv); mlb_cuda_free(dz);
    free(x); free(y); free(v); free(ref); free(got);
}

// A tiny random UNet written to disk, loaded on the CPU, copied to the GPU; both forwards from the
// same inputs.
static void unet_case(int sd2, uint64_t seed) {
    mlb_unet_config cfg = mlb_unet_tiny_config(sd2);
    char path[600];
    snprintf(path, sizeof path, "%s/unet_sd%d.safetensors", test_tmpdir("cuda_unet"), sd2 ? 2 : 1);
    mlb_unet_random_options o = mlb_unet_random_default_options();
    o.seed = seed;
    mlb_unet *u = NULL, *ud = NULL;
    CHECK_MSG(mlb_unet_write_random(&cfg, &o, path) == MLB_OK, "%s", mlb_last_error());
    CHECK_MSG(mlb_unet_load(path, NULL, &u) == MLB_OK, "%s", mlb_last_error());
    if (!u) return;
    CHECK_MSG(mlb_unet_to_device(u, MLB_DEVICE_CUDA, &ud) == MLB_OK, "%s", mlb_last_error());
    const int N = 2, H = 16, W = 24, Tc = 7, D = cfg.context_dim;
    size_t nx = (size_t)N * cfg.in_channels * H * W, nc = (size_t)N * Tc * D, no = (size_t)N * cfg.out_channels * H * W;
    float *x = host_alloc(nx), *ctx = host_alloc(nc), *ref = host_alloc(no), *got = host_alloc(no), t[2] = {999.0f, 17.5f};
    fill_uniform(x, nx, seed, 1, -1, 1);
    fill_uniform(ctx, nc, seed, 2, -1, 1);
    CHECK(mlb_unet_forward(NULL, u, ref, x, t, ctx, N, H, W, Tc, NULL, NULL) == MLB_OK);
    float *dx = dev_floats(x, nx), *dc = dev_floats(ctx, nc);
    // the weights on the CPU with the GPU's ops is a clear error
    float* dummy = dev_floats(NULL, no);
    CHECK(mlb_unet_forward(mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32), u, dummy, dx, t, dc, N, H, W, Tc, NULL,
                              NULL) == MLB_ERR_ARG);
    for (int p = 0; ud && p < 4; p++) {
        char what[80];
        snprintf(what, sizeof what, "UNet tiny SD%d N%d %dx%d %s", sd2 ? 2 : 1, N, H, W, prec_names[p]);
        float* dout = dev_floats(NULL, no);
        mlb_status st = mlb_unet_forward(mlb_backend_for(MLB_DEVICE_CUDA, (mlb_gemm_precision)p), ud, dout, dx, t,
                                            dc, N, H, W, Tc, NULL, NULL);
        CHECK_MSG(st == MLB_OK, "%s: %s", what, mlb_last_error());
        if (st == MLB_OK && host_floats(got, dout, no)) CHECK_PARITY(what, got, ref, no, unet_bound[p]);
        mlb_cuda_free(dout);
    }
    // mlb_unet_use_device: the host-buffer forward staged through the GPU copy
    if (ud) {
        CHECK_MSG(mlb_unet_use_device(u, MLB_DEVICE_CUDA, MLB_GEMM_FP32) == MLB_OK, "%s", mlb_last_error());
        CHECK(mlb_unet_forward(NULL, u, got, x, t, ctx, N, H, W, Tc, NULL, NULL) == MLB_OK);
        CHECK_PARITY("UNet mlb_unet_use_device(cuda) host buffers", got, ref, no, unet_bound[0]);
        CHECK(mlb_unet_use_device(u, MLB_DEVICE_CPU, MLB_GEMM_FP32) == MLB_OK && !u->mirror);
        CHECK(mlb_unet_forward(NULL, u, got, x, t, ctx, N, H, W, Tc, NULL, NULL) == MLB_OK);
        CHECK_MSG(!memcmp(got, ref, no * sizeof(float)), "back on the CPU: not the CPU's bits");
    }
    mlb_cuda_free(dx); mlb_cuda_free(dc); mlb_cuda_free(dummy);
    mlb_unet_free(ud);
    mlb_unet_free(u);
    free(x); free(ctx); free(ref); free(got);
}

TEST(unet_forward_matches_cpu) {
    REQUIRE_GPU();
    unet_case(0, test_seed() + 31);
    unet_case(1, test_seed() + 32);
}

int main(void) {
    RUN(conv2d_matches_cpu);
    RUN(sdpa_matches_cpu);
    RUN(layout_ops_bitwise);
    RUN(unet_forward_matches_cpu);
    return test_summary();
}
