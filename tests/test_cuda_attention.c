// The flash-style CUDA attention against attention_forward (CPU, softmax sums in double) on random
// q, k, v: fused qkv (ld = 3C) and separate buffers, causal and not, head widths 32..512 (CLIP 64,
// UNet 40/80/160, the VAE's single 512-wide head). Skips without a GPU.
// Bound: fp32 arithmetic, online softmax (exp of score - running max, rescaled per tile): relative
// error ~ u32 * (a few operations per key) ~ 1e-6; 1e-5 on the relative L2 error.
#include "cuda_test_util.h"
#include "matlaber/transformer_ops.h"

static void attention_case(int B, int T, int C, int NH, int fused, int causal, float qscale, uint64_t seed) {
    int ld = fused ? 3 * C : C;
    size_t n_in = (size_t)B * T * ld, n_out = (size_t)B * T * C;
    float *q = host_alloc(n_in), *k = fused ? q + C : host_alloc(n_in), *v = fused ? q + 2 * C : host_alloc(n_in);
    fill_uniform(q, n_in, seed, 1, -qscale, qscale);
    if (!fused) {
        fill_uniform(k, n_in, seed, 2, -qscale, qscale);
        fill_uniform(v, n_in, seed, 3, -1, 1);
    }
    float *out_c = host_alloc(n_out), *out_g = host_alloc(n_out);
    float *dq = dev_floats(q, n_in), *dk = fused ? NULL : dev_floats(k, n_in), *dv = fused ? NULL : dev_floats(v, n_in);
    float* dout = dev_floats(NULL, n_out);
    char what[128];
    snprintf(what, sizeof what, "attention B%d T%d C%d NH%d%s%s", B, T, C, NH, fused ? " fused" : "", causal ? " causal" : "");
    if (!dq || !dout || (!fused && (!dk || !dv))) {
        CHECK_MSG(0, "device allocation: %s", mlb_last_error());
        goto done;
    }
    CHECK(attention_forward(out_c, NULL, q, k, v, ld, B, T, C, NH, causal) == MLB_OK);
    mlb_status st = fused ? mlb_cuda_attention_forward(dout, dq, dq + C, dq + 2 * C, ld, B, T, C, NH, causal)
                          : mlb_cuda_attention_forward(dout, dq, dk, dv, ld, B, T, C, NH, causal);
    CHECK_MSG(st == MLB_OK, "%s: %s", what, mlb_last_error());
    if (st != MLB_OK) goto done;
    if (!host_floats(out_g, dout, n_out)) {
        CHECK_MSG(0, "copy back: %s", mlb_last_error());
        goto done;
    }
    CHECK_PARITY(what, out_g, out_c, n_out, 1e-5);
done:
    mlb_cuda_free(dq); mlb_cuda_free(dk); mlb_cuda_free(dv); mlb_cuda_free(dout);
    free(q);
    if (!fused) { free(k); free(v); }
    free(out_c); free(out_g);
}

TEST(attention_matches_cpu) {
    REQUIRE_GPU();
    uint64_t seed = test_seed();
    attention_case(2, 77, 768, 12, 1, 1, 1.0f, seed + 1);      // CLIP text encoder: causal, fused qkv, hd 64
    attention_case(2, 300, 320, 8, 0, 0, 1.0f, seed + 2);      // UNet level 1 (hd 40), not a multiple of the tile
    attention_case(1, 257, 640, 8, 0, 0, 1.0f, seed + 3);      // hd 80
    attention_case(1, 130, 1280, 8, 1, 0, 1.0f, seed + 4);     // hd 160
    attention_case(1, 100, 512, 1, 0, 0, 0.3f, seed + 5);      // the VAE's single head, hd 512
    attention_case(3, 33, 96, 3, 0, 1, 1.0f, seed + 6);        // hd 32, causal, odd T
    attention_case(1, 1, 64, 2, 0, 0, 1.0f, seed + 7);         // a single token
    attention_case(1, 64, 64, 1, 0, 0, 8.0f, seed + 8);        // large scores: the running max matters
    attention_case(1, 40, 50, 2, 0, 1, 1.0f, seed + 9);        // odd head width 25
}

TEST(attention_rejects_bad_shapes) {
    REQUIRE_GPU();
    float* d = dev_floats(NULL, 64);
    REQUIRE(d);
    CHECK(mlb_cuda_attention_forward(d, d, d, d, 10, 1, 2, 10, 3, 0) == MLB_ERR_ARG);    // C % NH
    CHECK(mlb_cuda_attention_forward(d, d, d, d, 8, 1, 2, 10, 2, 0) == MLB_ERR_ARG);     // ld < C
    CHECK(mlb_cuda_attention_forward(d, d, d, d, 1024, 1, 0, 1024, 1, 0) == MLB_OK);     // T = 0: nothing
    mlb_cuda_free(d);
}

int main(void) {
    RUN(attention_matches_cpu);
    RUN(attention_rejects_bad_shapes);
    return test_summary();
}
