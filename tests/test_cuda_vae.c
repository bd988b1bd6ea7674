// The backward ops the VAE encoder needs on the GPU (conv2d and attention), against the CPU's, at
// every GEMM precision; then a whole random VAE (4 levels, 32..64 channels, mid attention) moved
// with mlb_vae_use_device: encoder forward with its cache, encoder backward, decoder, against the
// CPU (bounds: fp32 1e-4, bf16 5e-2, like the UNet's: ~30 layers, each normalised). Gradients accumulate onto random values on both sides; the comparison is of
// the increments (result - start), so the bound speaks of the gradient itself. Skips without a GPU.
// Bounds (relative L2), as test_cuda_unet: fp32 1e-5 (sums of up to N*OH*OW = 2000 products in
// another order), tf32 / fp16 3e-3, bf16 2e-2 (the attention backward chains three GEMMs through
// bf16 copies of P and dS: 3e-2).
#include "cuda_test_util.h"
#include "matlaber/vae.h"

static const char* prec_names[] = {"fp32", "tf32", "fp16", "bf16"};
static const double bound[] = {1e-5, 3e-3, 3e-3, 2e-2};

// increments of a and b over start, compared
static void check_increment(const char* what, const float* got, const float* ref, const float* start, size_t n,
                            double tol) {
    float *dg = host_alloc(n), *dr = host_alloc(n);
    for (size_t i = 0; i < n; i++) {
        dg[i] = got[i] - start[i];
        dr[i] = ref[i] - start[i];
    }
    CHECK_PARITY(what, dg, dr, n, tol);
    free(dg);
    free(dr);
}

static void conv_bwd_case(mlb_conv2d cv, uint64_t seed) {
    const int OH = mlb_conv2d_out_h(&cv), OW = mlb_conv2d_out_w(&cv);
    size_t ni = (size_t)cv.N * cv.C * cv.H * cv.W, nw = (size_t)cv.OC * cv.C * cv.KH * cv.KW, no = (size_t)cv.N * cv.OC * OH * OW;
    float *x = host_alloc(ni), *w = host_alloc(nw), *dy = host_alloc(no);
    float *dx0 = host_alloc(ni), *dw0 = host_alloc(nw), *db0 = host_alloc(cv.OC);
    float *dx = host_alloc(ni), *dw = host_alloc(nw), *db = host_alloc(cv.OC);
    float *gx = host_alloc(ni), *gw = host_alloc(nw), *gb = host_alloc(cv.OC);
    fill_uniform(x, ni, seed, 1, -1, 1);
    fill_uniform(w, nw, seed, 2, -0.3f, 0.3f);
    fill_uniform(dy, no, seed, 3, -1, 1);
    fill_uniform(dx0, ni, seed, 4, -1, 1);
    fill_uniform(dw0, nw, seed, 5, -1, 1);
    fill_uniform(db0, cv.OC, seed, 6, -1, 1);
    memcpy(dx, dx0, ni * 4); memcpy(dw, dw0, nw * 4); memcpy(db, db0, cv.OC * 4);
    CHECK(conv2d_backward(dx, dw, db, dy, x, w, &cv, NULL) == MLB_OK);
    float *d_x = dev_floats(x, ni), *d_w = dev_floats(w, nw), *d_dy = dev_floats(dy, no);
    for (int p = 0; p < 4; p++) {
        float *d_dx = dev_floats(dx0, ni), *d_dw = dev_floats(dw0, nw), *d_db = dev_floats(db0, cv.OC);
        char what[160];
        mlb_status st = mlb_cuda_conv2d_backward(d_dx, d_dw, d_db, d_dy, d_x, d_w, &cv, (mlb_gemm_precision)p);
        snprintf(what, sizeof what, "conv bwd %dx%d s%d N%d C%d->%d %dx%d %s", cv.KH, cv.KW, cv.stride_h, cv.N, cv.C,
                 cv.OC, cv.H, cv.W, prec_names[p]);
        CHECK_MSG(st == MLB_OK, "%s: %s", what, mlb_last_error());
        if (st == MLB_OK && host_floats(gx, d_dx, ni) && host_floats(gw, d_dw, nw) && host_floats(gb, d_db, cv.OC)) {
            char w2[200];
            snprintf(w2, sizeof w2, "%s din", what);
            check_increment(w2, gx, dx, dx0, ni, bound[p]);
            snprintf(w2, sizeof w2, "%s dweight", what);
            check_increment(w2, gw, dw, dw0, nw, bound[p]);
            snprintf(w2, sizeof w2, "%s dbias", what);
            check_increment(w2, gb, db, db0, cv.OC, 1e-5);   // float sums in double: precision-independent
        }
        mlb_cuda_free(d_dx); mlb_cuda_free(d_dw); mlb_cuda_free(d_db);
    }
    // din alone (the VAE's frozen weights): in may be NULL
    float* d_dx = dev_floats(dx0, ni);
    CHECK(mlb_cuda_conv2d_backward(d_dx, NULL, NULL, d_dy, NULL, d_w, &cv, MLB_GEMM_FP32) == MLB_OK);
    if (host_floats(gx, d_dx, ni)) check_increment("conv bwd din only fp32", gx, dx, dx0, ni, bound[0]);
    mlb_cuda_free(d_dx);
    mlb_cuda_free(d_x); mlb_cuda_free(d_w); mlb_cuda_free(d_dy);
    free(x); free(w); free(dy); free(dx0); free(dw0); free(db0); free(dx); free(dw); free(db); free(gx); free(gw); free(gb);
}

static void conv_bwd_cases(void);

// Every case on both paths: cuDNN's input gradient when the build has it (symmetric padding), the
// im2col GEMMs for the rest.
TEST(conv2d_backward_matches_cpu) {
    REQUIRE_GPU();
    printf("  cuDNN version %d\n", mlb_cuda_cudnn_version());
    for (int path = mlb_cuda_cudnn_version() ? 0 : 1; path < 2; path++) {
        mlb_cuda_use_cudnn(path == 0);
        printf("  convolutions on %s\n", path == 0 ? "cuDNN" : "the GEMM path");
        conv_bwd_cases();
    }
    mlb_cuda_use_cudnn(1);
}

static void conv_bwd_cases(void) {
    uint64_t s = test_seed();
    conv_bwd_case(mlb_conv2d_make(2, 16, 12, 10, 24, 3, 1, 1), s + 1);   // a ResNet 3x3
    mlb_conv2d v = mlb_conv2d_make(3, 8, 11, 13, 8, 3, 2, 0);            // the VAE's downsample
    v.pad_bottom = v.pad_right = 1;
    conv_bwd_case(v, s + 2);
    conv_bwd_case(mlb_conv2d_make(2, 24, 6, 6, 12, 1, 1, 0), s + 3);     // 1x1 shortcut
    mlb_conv2d r = mlb_conv2d_make(1, 3, 9, 7, 5, 3, 1, 0);              // a 5x3 kernel, stride 2 across
    r.KH = 5; r.pad_top = 2; r.pad_bottom = 1; r.pad_right = 1; r.stride_w = 2;
    conv_bwd_case(r, s + 4);
}

static void sdpa_bwd_case(int B, int Tq, int Tk, int C, int NH, int fused, uint64_t seed) {
    const int ld = fused ? 3 * C : C;
    size_t nq = (size_t)B * Tq * ld, nk = (size_t)B * Tk * ld, no = (size_t)B * Tq * C, nl = (size_t)B * NH * Tq;
    float *q = host_alloc(nq), *k = fused ? q : host_alloc(nk), *v = fused ? q : host_alloc(nk);
    fill_uniform(q, nq, seed, 1, -1, 1);
    if (!fused) { fill_uniform(k, nk, seed, 2, -1, 1); fill_uniform(v, nk, seed, 3, -1, 1); }
    const float *qp = q, *kp = fused ? q + C : k, *vp = fused ? q + 2 * C : v;
    float *out = host_alloc(no), *lse = host_alloc(nl), *dout = host_alloc(no);
    fill_uniform(dout, no, seed, 4, -1, 1);
    CHECK(sdpa_forward(out, lse, qp, kp, vp, B, Tq, Tk, C, NH, ld, ld, NULL) == MLB_OK);
    // gradients start random; fused: one dqkv buffer with disjoint columns
    float *g0q = host_alloc(nq), *g0k = fused ? g0q : host_alloc(nk), *g0v = fused ? g0q : host_alloc(nk);
    fill_uniform(g0q, nq, seed, 5, -1, 1);
    if (!fused) { fill_uniform(g0k, nk, seed, 6, -1, 1); fill_uniform(g0v, nk, seed, 7, -1, 1); }
    float *rq = host_alloc(nq), *rk = fused ? rq : host_alloc(nk), *rv = fused ? rq : host_alloc(nk);
    memcpy(rq, g0q, nq * 4);
    if (!fused) { memcpy(rk, g0k, nk * 4); memcpy(rv, g0v, nk * 4); }
    CHECK(sdpa_backward(rq, fused ? rq + C : rk, fused ? rq + 2 * C : rv, dout, out, lse, qp, kp, vp, B, Tq, Tk, C, NH,
                        ld, ld, NULL) == MLB_OK);
    float *d_q = dev_floats(q, nq), *d_k = fused ? d_q : dev_floats(k, nk), *d_v = fused ? d_q : dev_floats(v, nk);
    const float *dqp = d_q, *dkp = fused ? d_q + C : d_k, *dvp = fused ? d_q + 2 * C : d_v;
    float *d_dout = dev_floats(dout, no), *gq = host_alloc(nq), *gk = host_alloc(nk), *gv = host_alloc(nk);
    for (int p = 0; p < 4; p++) {
        char what[160], w2[200];
        snprintf(what, sizeof what, "sdpa bwd B%d Tq%d Tk%d C%d NH%d%s %s", B, Tq, Tk, C, NH, fused ? " fused" : "",
                 prec_names[p]);
        float *d_out = dev_floats(NULL, no), *d_lse = dev_floats(NULL, nl), *glse = host_alloc(nl);
        mlb_status st = mlb_cuda_sdpa_forward(d_out, d_lse, dqp, dkp, dvp, B, Tq, Tk, C, NH, ld, ld, (mlb_gemm_precision)p);
        CHECK_MSG(st == MLB_OK, "%s forward: %s", what, mlb_last_error());
        if (st == MLB_OK && host_floats(glse, d_lse, nl)) {
            snprintf(w2, sizeof w2, "%s lse", what);
            CHECK_PARITY(w2, glse, lse, nl, bound[p]);
        }
        float *e_q = dev_floats(g0q, nq), *e_k = fused ? e_q : dev_floats(g0k, nk), *e_v = fused ? e_q : dev_floats(g0v, nk);
        st = mlb_cuda_sdpa_backward(e_q, fused ? e_q + C : e_k, fused ? e_q + 2 * C : e_v, d_dout, d_out, d_lse, dqp,
                                    dkp, dvp, B, Tq, Tk, C, NH, ld, ld, (mlb_gemm_precision)p);
        CHECK_MSG(st == MLB_OK, "%s: %s", what, mlb_last_error());
        double tol = p == MLB_GEMM_BF16 ? 3e-2 : bound[p];
        if (st == MLB_OK && host_floats(gq, e_q, nq)) {
            snprintf(w2, sizeof w2, fused ? "%s dqkv" : "%s dq", what);
            check_increment(w2, gq, rq, g0q, nq, tol);
        }
        if (!fused && st == MLB_OK && host_floats(gk, e_k, nk) && host_floats(gv, e_v, nk)) {
            snprintf(w2, sizeof w2, "%s dk", what);
            check_increment(w2, gk, rk, g0k, nk, tol);
            snprintf(w2, sizeof w2, "%s dv", what);
            check_increment(w2, gv, rv, g0v, nk, tol);
        }
        mlb_cuda_free(d_out); mlb_cuda_free(d_lse); mlb_cuda_free(e_q);
        if (!fused) { mlb_cuda_free(e_k); mlb_cuda_free(e_v); }
        free(glse);
    }
    mlb_cuda_free(d_q); mlb_cuda_free(d_dout);
    if (!fused) { mlb_cuda_free(d_k); mlb_cuda_free(d_v); free(k); free(v); free(g0k); free(g0v); free(rk); free(rv); }
    free(q); free(out); free(lse); free(dout); free(g0q); free(rq); free(gq); free(gk); free(gv);
}

TEST(sdpa_backward_matches_cpu) {
    REQUIRE_GPU();
    uint64_t s = test_seed() + 100;
    sdpa_bwd_case(2, 256, 256, 64, 1, 1, s + 1);   // the VAE mid block: one head, fused qkv
    sdpa_bwd_case(2, 200, 77, 320, 8, 0, s + 2);   // cross-attention shapes, hd 40
    sdpa_bwd_case(3, 33, 45, 96, 3, 0, s + 3);     // odd sizes, Tq != Tk
}

static void vae_case(mlb_gemm_precision prec, double tol, uint64_t seed) {
    mlb_vae_config c = mlb_vae_sd_config();
    c.n_levels = 4;
    c.block_out[0] = 32; c.block_out[1] = 32; c.block_out[2] = 64; c.block_out[3] = 64;
    c.layers_per_block = 2;
    mlb_vae* v = NULL;
    CHECK_MSG(mlb_vae_create(NULL, &c, &v) == MLB_OK, "%s", mlb_last_error());
    if (!v) return;
    mlb_vae_init_random(v, seed, 1.0f);
    const int N = 2, H = 64, W = 48, h = H / 8, w = W / 8, z = c.latent_channels;
    size_t ni = (size_t)N * 3 * H * W, nz = (size_t)N * z * h * w;
    float *img = host_alloc(ni), *g = host_alloc(nz), *lat = host_alloc(nz), *d0 = host_alloc(ni);
    fill_uniform(img, ni, seed, 1, -1, 1);
    fill_uniform(g, nz, seed, 2, -1, 1);
    fill_uniform(lat, nz, seed, 3, -2, 2);
    fill_uniform(d0, ni, seed, 4, -1, 1);
    float *mc = host_alloc(nz), *lc = host_alloc(nz), *dc = host_alloc(ni), *oc = host_alloc(ni);
    float *mg = host_alloc(nz), *lg = host_alloc(nz), *dg = host_alloc(ni), *og = host_alloc(ni);
    memcpy(dc, d0, ni * 4);
    memcpy(dg, d0, ni * 4);
    mlb_vae_cache cc = {0}, cg = {0};
    CHECK(mlb_vae_encode(NULL, v, img, N, H, W, mc, lc, &cc) == MLB_OK);
    CHECK(mlb_vae_encode_backward(NULL, v, &cc, g, g, dc, NULL) == MLB_OK);
    CHECK(mlb_vae_decode(NULL, v, lat, N, h, w, oc, NULL) == MLB_OK);
    CHECK_MSG(mlb_vae_use_device(v, MLB_DEVICE_CUDA, prec) == MLB_OK, "%s", mlb_last_error());
    char what[120];
    mlb_status st = mlb_vae_encode(NULL, v, img, N, H, W, mg, lg, &cg);
    CHECK_MSG(st == MLB_OK, "encode: %s", mlb_last_error());
    CHECK(cg.device == MLB_DEVICE_CUDA);
    if (st == MLB_OK) {
        snprintf(what, sizeof what, "VAE encode mean %s", prec_names[prec]);
        CHECK_PARITY(what, mg, mc, nz, tol);
        snprintf(what, sizeof what, "VAE encode logvar %s", prec_names[prec]);
        CHECK_PARITY(what, lg, lc, nz, tol);
        st = mlb_vae_encode_backward(NULL, v, &cg, g, g, dg, NULL);
        CHECK_MSG(st == MLB_OK, "backward: %s", mlb_last_error());
        snprintf(what, sizeof what, "VAE encode backward dimage %s", prec_names[prec]);
        if (st == MLB_OK) check_increment(what, dg, dc, d0, ni, tol);
    }
    st = mlb_vae_decode(NULL, v, lat, N, h, w, og, NULL);
    CHECK_MSG(st == MLB_OK, "decode: %s", mlb_last_error());
    snprintf(what, sizeof what, "VAE decode %s", prec_names[prec]);
    if (st == MLB_OK) CHECK_PARITY(what, og, oc, ni, tol);
    // a CPU cache handed to the GPU model is refused; back on the CPU at fp32 the bits are the CPU's
    // again (MLB_DEVICE_CPU with bf16 would select the CPU's bf16 GEMMs: vae.h)
    CHECK(mlb_vae_encode_backward(NULL, v, &cc, g, g, dg, NULL) == MLB_ERR_ARG);
    CHECK(mlb_vae_use_device(v, MLB_DEVICE_CPU, MLB_GEMM_FP32) == MLB_OK && !v->mirror);
    CHECK(mlb_vae_decode(NULL, v, lat, N, h, w, og, NULL) == MLB_OK && !memcmp(og, oc, ni * 4));
    mlb_vae_cache_free(&cc);
    mlb_vae_cache_free(&cg);
    mlb_vae_free(v);
    free(img); free(g); free(lat); free(d0); free(mc); free(lc); free(dc); free(oc); free(mg); free(lg); free(dg); free(og);
}

TEST(vae_matches_cpu) {
    REQUIRE_GPU();
    vae_case(MLB_GEMM_FP32, 1e-4, test_seed() + 200);
    vae_case(MLB_GEMM_BF16, 5e-2, test_seed() + 201);
}

int main(void) {
    RUN(conv2d_backward_matches_cpu);
    RUN(sdpa_backward_matches_cpu);
    RUN(vae_matches_cpu);
    return test_summary();
}
