// Training backward of the VAE (vae.h): the encoder's weight gradients (mlb_vae_encode_backward with
// grads) and the decoder's cached forward and full backward (mlb_vae_decode with a cache,
// mlb_vae_decode_backward), on a tiny random VAE (3 levels, 8/16/16 channels, 4 groups, mid
// attention). In double: every parameter tensor (two entries each: its largest gradient and one
// more) and every image / latent entry against central finite differences. In float: against
// double, decode with a cache == without bitwise, the same bits on 1 and 2 threads, the image
// gradient with grads == the one without.
#include <stdint.h>
#include "matlaber/device.h"
#include "matlaber/error.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"
#include "matlaber/vae.h"
#include "test.h"

enum { N = 2, H = 8, W = 8, LAT = 2, Z = 2, NI = N * 3 * H * W, NZ = N * Z * LAT * LAT };
#define FD_H 1e-6

static mlb_vae_config tiny_config(void) {
    mlb_vae_config c = mlb_vae_sd_config();
    c.n_levels = 3;
    c.block_out[0] = 8;
    c.block_out[1] = 16;
    c.block_out[2] = 16;
    c.layers_per_block = 1;
    c.norm_groups = 4;
    c.latent_channels = Z;
    c.mid_attention = 1;
    return c;
}

static mlb_vae* tiny_vae(void) {
    mlb_vae_config c = tiny_config();
    mlb_vae* v = NULL;
    if (mlb_vae_create(NULL, &c, &v) != MLB_OK) return NULL;
    mlb_vae_init_random(v, 11, 1.0f);
    return v;
}

static double rnd(uint64_t stream, uint64_t i) { return mlb_rng_uniform_f64(stream, 0, i) * 2 - 1; }

// The losses, in double: L_enc = sum(mean * r1) + sum(logvar * r2), L_dec = sum(image * r).
static double r1[NZ], r2[NZ], rimg[NI], img[NI], zlat[NZ];
static double enc_loss(const mlb_vae_f64* v, const double* x) {
    double m[NZ], l[NZ], L = 0;
    if (mlb_vae_encode_f64(NULL, v, x, N, H, W, m, l, NULL) != MLB_OK) return NAN;
    for (int i = 0; i < NZ; i++) L += m[i] * r1[i] + l[i] * r2[i];
    return L;
}
static double dec_loss(const mlb_vae_f64* v, const double* zz) {
    double out[NI], L = 0;
    if (mlb_vae_decode_f64(NULL, v, zz, N, LAT, LAT, out, NULL) != MLB_OK) return NAN;
    for (int i = 0; i < NI; i++) L += out[i] * rimg[i];
    return L;
}

static void setup(void) {
    for (int i = 0; i < NZ; i++) { r1[i] = rnd(1, i); r2[i] = rnd(2, i); zlat[i] = rnd(3, i); }
    for (int i = 0; i < NI; i++) { rimg[i] = rnd(4, i); img[i] = rnd(5, i); }
}

// |fd - g| relative to max(|fd|, 1e-2): below that absolute, since the differences' own rounding
// (~1e-16 |L| / h, about 1e-9 here) would dominate an exact zero such as the attention's key bias
// gradient (the softmax does not see it).
static double rel_err(double fd, double g) { return fabs(fd - g) / fmax(fabs(fd), 1e-2); }

// Central differences of `loss` over two entries of every tensor of the encoder (enc = 1) or the
// decoder (enc = 0), against grads; returns the worst relative error, counts tensors and entries.
static double check_params(mlb_vae* vf, mlb_vae_f64* vd, const mlb_vae_f64* grads, int enc, int* n_tensors,
                           double* worst_abs) {
    double worst = 0;
    *n_tensors = 0;
    *worst_abs = 0;
    for (size_t t = 0; t < mlb_vae_tensor_count(vf); t++) {
        mlb_vae_tensor T;
        if (mlb_vae_tensor_at(vf, t, MLB_VAE_LAYOUT_LDM, &T) != MLB_OK) return INFINITY;
        int is_enc = !strncmp(T.name, "encoder.", 8) || !strncmp(T.name, "quant_conv.", 11);
        if (is_enc != enc) continue;
        size_t off = (size_t)(T.data - vf->params), best = 0;
        for (size_t k = 1; k < T.n; k++)
            if (fabs(grads->params[off + k]) > fabs(grads->params[off + best])) best = k;
        size_t pick[2] = {best, (size_t)(mlb_rng_uniform_f64(9, 0, t) * T.n) % T.n};
        for (int q = 0; q < 2; q++) {
            double* p = vd->params + off + pick[q];
            double keep = *p;
            *p = keep + FD_H;
            double lp = enc ? enc_loss(vd, img) : dec_loss(vd, zlat);
            *p = keep - FD_H;
            double lm = enc ? enc_loss(vd, img) : dec_loss(vd, zlat);
            *p = keep;
            double fd = (lp - lm) / (2 * FD_H), g = grads->params[off + pick[q]];
            double e = rel_err(fd, g);
            if (!(e <= worst)) worst = e;
            if (!(fabs(fd - g) <= *worst_abs)) *worst_abs = fabs(fd - g);
            if (!(e < 1e-6)) printf("  %s[%zu]: fd %.12g, backward %.12g\n", T.name, pick[q], fd, g);
        }
        (*n_tensors)++;
    }
    return worst;
}

// max over tensors of max|a - b| / max|b| (per tensor, so small tensors are judged on their scale;
// at least 1e-3 of the largest gradient, for tensors whose gradient is zero, as the key bias's)
static char worst_name[128];
static double float_vs_double(const mlb_vae* vf, const float* a, const double* b, int enc) {
    double worst = 0, gmax = 0;
    for (size_t k = 0; k < vf->n_params; k++) gmax = fmax(gmax, fabs(b[k]));
    for (size_t t = 0; t < mlb_vae_tensor_count(vf); t++) {
        mlb_vae_tensor T;
        mlb_vae_tensor_at(vf, t, MLB_VAE_LAYOUT_LDM, &T);
        int is_enc = !strncmp(T.name, "encoder.", 8) || !strncmp(T.name, "quant_conv.", 11);
        if (is_enc != enc) continue;
        size_t off = (size_t)(T.data - vf->params);
        double d = 0, m = 1e-3 * gmax;
        for (size_t k = 0; k < T.n; k++) { d = fmax(d, fabs(a[off + k] - b[off + k])); m = fmax(m, fabs(b[off + k])); }
        if (d / m > worst) { worst = d / m; snprintf(worst_name, sizeof worst_name, "%s", T.name); }
    }
    return worst;
}

TEST(encoder_weight_gradients_fd) {
    setup();
    mlb_vae* v = tiny_vae();
    mlb_vae_f64 *vd = NULL, *gd = NULL;
    REQUIRE(v && mlb_vae_to_f64(v, &vd) == MLB_OK && mlb_vae_create_f64(NULL, &v->cfg, &gd) == MLB_OK);
    double m[NZ], l[NZ], dimg[NI] = {0};
    mlb_vae_cache_f64 c = {0};
    c.train = 1;
    REQUIRE(mlb_vae_encode_f64(NULL, vd, img, N, H, W, m, l, &c) == MLB_OK);
    REQUIRE(mlb_vae_encode_backward_f64(NULL, vd, &c, r1, r2, dimg, gd) == MLB_OK);
    int nt;
    double ea, e = check_params(v, vd, gd, 1, &nt, &ea);
    printf("  encoder weights vs FD (double, h %g): %d tensors x 2 entries, max rel %.3g, max abs %.3g\n", FD_H, nt,
           e, ea);
    CHECK(nt >= 30 && e < 1e-6);
    double ei = 0;
    for (int i = 0; i < NI; i++) {
        double keep = img[i];
        img[i] = keep + FD_H;
        double lp = enc_loss(vd, img);
        img[i] = keep - FD_H;
        double lm = enc_loss(vd, img);
        img[i] = keep;
        ei = fmax(ei, rel_err((lp - lm) / (2 * FD_H), dimg[i]));
    }
    printf("  encoder image gradient vs FD over all %d inputs: max rel %.3g\n", NI, ei);
    CHECK(ei < 1e-6);

    // float: against double; dimage bitwise that without grads; threads; a non-training cache
    mlb_vae *g1 = NULL, *g2 = NULL, *other = NULL;
    REQUIRE(mlb_vae_create(NULL, &v->cfg, &g1) == MLB_OK && mlb_vae_create(NULL, &v->cfg, &g2) == MLB_OK);
    float imf[NI], r1f[NZ], r2f[NZ], mf[NZ], d1[NI] = {0}, d2[NI] = {0}, d3[NI] = {0};
    for (int i = 0; i < NI; i++) imf[i] = (float)img[i];
    for (int i = 0; i < NZ; i++) { r1f[i] = (float)r1[i]; r2f[i] = (float)r2[i]; }
    mlb_vae_cache cf = {0};
    cf.train = 1;
    int threads = mlb_get_threads();
    mlb_set_threads(1);
    REQUIRE(mlb_vae_encode(NULL, v, imf, N, H, W, mf, NULL, &cf) == MLB_OK);
    REQUIRE(mlb_vae_encode_backward(NULL, v, &cf, r1f, r2f, d1, g1) == MLB_OK);
    mlb_set_threads(2);
    REQUIRE(mlb_vae_encode(NULL, v, imf, N, H, W, mf, NULL, &cf) == MLB_OK);
    REQUIRE(mlb_vae_encode_backward(NULL, v, &cf, r1f, r2f, d2, g2) == MLB_OK);
    mlb_set_threads(threads);
    CHECK(memcmp(d1, d2, sizeof d1) == 0 && memcmp(g1->params, g2->params, v->n_params * sizeof(float)) == 0);
    REQUIRE(mlb_vae_encode_backward(NULL, v, &cf, r1f, r2f, d3, NULL) == MLB_OK);
    CHECK(memcmp(d1, d3, sizeof d1) == 0);
    double ef = float_vs_double(v, g1->params, gd->params, 1);
    printf("  encoder weight gradients float vs double: max per-tensor relative %.3g (%s)\n", ef, worst_name);
    CHECK(ef < 1e-4);
    mlb_vae_cache cs = {0};   // an SDS cache: no weight gradients, a clear error
    REQUIRE(mlb_vae_encode(NULL, v, imf, N, H, W, mf, NULL, &cs) == MLB_OK);
    CHECK(mlb_vae_encode_backward(NULL, v, &cs, r1f, r2f, NULL, g1) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "train") != NULL);
    mlb_vae_config oc = v->cfg;
    oc.block_out[2] = 32;
    REQUIRE(mlb_vae_create(NULL, &oc, &other) == MLB_OK);
    CHECK(mlb_vae_encode_backward(NULL, v, &cf, r1f, r2f, NULL, other) == MLB_ERR_ARG);
    CHECK(mlb_vae_cache_size(&v->cfg, N, H, W) <= cs.capacity && cf.capacity > cs.capacity);
    mlb_vae_cache_free(&cf);
    mlb_vae_cache_free(&cs);
    mlb_vae_cache_free_f64(&c);
    mlb_vae_free(g1); mlb_vae_free(g2); mlb_vae_free(other);
    mlb_vae_free_f64(gd); mlb_vae_free_f64(vd);
    mlb_vae_free(v);
}

TEST(decoder_backward_fd) {
    setup();
    mlb_vae* v = tiny_vae();
    mlb_vae_f64 *vd = NULL, *gd = NULL;
    REQUIRE(v && mlb_vae_to_f64(v, &vd) == MLB_OK && mlb_vae_create_f64(NULL, &v->cfg, &gd) == MLB_OK);
    double out[NI], out2[NI], dz[NZ] = {0};
    mlb_vae_dec_cache_f64 c = {0};
    REQUIRE(mlb_vae_decode_f64(NULL, vd, zlat, N, LAT, LAT, out, &c) == MLB_OK);
    REQUIRE(mlb_vae_decode_f64(NULL, vd, zlat, N, LAT, LAT, out2, NULL) == MLB_OK);
    CHECK(memcmp(out, out2, sizeof out) == 0);
    REQUIRE(mlb_vae_decode_backward_f64(NULL, vd, &c, rimg, dz, gd) == MLB_OK);
    int nt;
    double ea, e = check_params(v, vd, gd, 0, &nt, &ea);
    printf("  decoder weights vs FD (double, h %g): %d tensors x 2 entries, max rel %.3g, max abs %.3g\n", FD_H, nt,
           e, ea);
    CHECK(nt >= 40 && e < 1e-6);
    double ez = 0;
    for (int i = 0; i < NZ; i++) {
        double keep = zlat[i];
        zlat[i] = keep + FD_H;
        double lp = dec_loss(vd, zlat);
        zlat[i] = keep - FD_H;
        double lm = dec_loss(vd, zlat);
        zlat[i] = keep;
        ez = fmax(ez, rel_err((lp - lm) / (2 * FD_H), dz[i]));
    }
    printf("  decoder latent gradient vs FD over all %d entries: max rel %.3g\n", NZ, ez);
    CHECK(ez < 1e-6);

    // float: decode with a cache == without bitwise, threads, against double, dz NULL / grads NULL
    mlb_vae *g1 = NULL, *g2 = NULL, *g3 = NULL;
    REQUIRE(mlb_vae_create(NULL, &v->cfg, &g1) == MLB_OK && mlb_vae_create(NULL, &v->cfg, &g2) == MLB_OK &&
            mlb_vae_create(NULL, &v->cfg, &g3) == MLB_OK);
    float zf[NZ], rf[NI], a[NI], b[NI], dz1[NZ] = {0}, dz2[NZ] = {0}, dz3[NZ] = {0};
    for (int i = 0; i < NZ; i++) zf[i] = (float)zlat[i];
    for (int i = 0; i < NI; i++) rf[i] = (float)rimg[i];
    mlb_vae_dec_cache cf = {0};
    int threads = mlb_get_threads();
    mlb_set_threads(1);
    REQUIRE(mlb_vae_decode(NULL, v, zf, N, LAT, LAT, a, &cf) == MLB_OK);
    REQUIRE(mlb_vae_decode_backward(NULL, v, &cf, rf, dz1, g1) == MLB_OK);
    mlb_set_threads(2);
    REQUIRE(mlb_vae_decode(NULL, v, zf, N, LAT, LAT, b, NULL) == MLB_OK);
    CHECK(memcmp(a, b, sizeof a) == 0);
    REQUIRE(mlb_vae_decode(NULL, v, zf, N, LAT, LAT, b, &cf) == MLB_OK);
    CHECK(memcmp(a, b, sizeof a) == 0);
    REQUIRE(mlb_vae_decode_backward(NULL, v, &cf, rf, dz2, g2) == MLB_OK);
    mlb_set_threads(threads);
    CHECK(memcmp(dz1, dz2, sizeof dz1) == 0 && memcmp(g1->params, g2->params, v->n_params * sizeof(float)) == 0);
    REQUIRE(mlb_vae_decode_backward(NULL, v, &cf, rf, dz3, NULL) == MLB_OK);   // no weight gradients: same dz
    REQUIRE(mlb_vae_decode_backward(NULL, v, &cf, rf, NULL, g3) == MLB_OK);    // no dz: same weight gradients
    CHECK(memcmp(dz1, dz3, sizeof dz1) == 0 && memcmp(g1->params, g3->params, v->n_params * sizeof(float)) == 0);
    double ef = float_vs_double(v, g1->params, gd->params, 0), ezf = 0, mz = 0;
    for (int i = 0; i < NZ; i++) { ezf = fmax(ezf, fabs(dz1[i] - dz[i])); mz = fmax(mz, fabs(dz[i])); }
    printf("  decoder float vs double: weight gradients max per-tensor relative %.3g (%s), dz %.3g (|dz| max %.3g)\n",
           ef, worst_name, ezf / mz, mz);
    CHECK(ef < 1e-4 && ezf / mz < 1e-5);
    CHECK(mlb_vae_dec_cache_size(&v->cfg, N, LAT, LAT) == cf.capacity);
    mlb_vae_dec_cache empty = {0};
    CHECK(mlb_vae_decode_backward(NULL, v, &empty, rf, dz3, NULL) == MLB_ERR_ARG);
    mlb_vae_dec_cache_free(&cf);
    mlb_vae_dec_cache_free_f64(&c);
    mlb_vae_free(g1); mlb_vae_free(g2); mlb_vae_free(g3);
    mlb_vae_free_f64(gd); mlb_vae_free_f64(vd);
    mlb_vae_free(v);
}

// The float path on a GPU (mlb_vae_use_device, fp32 GEMMs): the same gradients as the CPU's within
// float rounding, the host grads receiving the device's sums.
TEST(gpu_matches_cpu) {
    if (mlb_cuda_device_count() < 1) SKIP("no GPU");
    setup();
    mlb_vae *v = tiny_vae(), *gc = NULL, *gg = NULL;
    REQUIRE(v && mlb_vae_create(NULL, &v->cfg, &gc) == MLB_OK && mlb_vae_create(NULL, &v->cfg, &gg) == MLB_OK);
    float imf[NI], r1f[NZ], r2f[NZ], m[NZ], zf[NZ], rf[NI], a[NI], b[NI];
    float dic[NI] = {0}, dig[NI] = {0}, dzc[NZ] = {0}, dzg[NZ] = {0};
    for (int i = 0; i < NI; i++) { imf[i] = (float)img[i]; rf[i] = (float)rimg[i]; }
    for (int i = 0; i < NZ; i++) { r1f[i] = (float)r1[i]; r2f[i] = (float)r2[i]; zf[i] = (float)zlat[i]; }
    for (int pass = 0; pass < 2; pass++) {   // 0: the CPU, 1: the GPU
        if (pass) REQUIRE(mlb_vae_use_device(v, MLB_DEVICE_CUDA, MLB_GEMM_FP32) == MLB_OK);
        mlb_vae* g = pass ? gg : gc;
        mlb_vae_cache ec = {0};
        ec.train = 1;
        mlb_vae_dec_cache dc = {0};
        REQUIRE(mlb_vae_encode(NULL, v, imf, N, H, W, m, NULL, &ec) == MLB_OK);
        REQUIRE(mlb_vae_encode_backward(NULL, v, &ec, r1f, r2f, pass ? dig : dic, g) == MLB_OK);
        REQUIRE(mlb_vae_decode(NULL, v, zf, N, LAT, LAT, pass ? b : a, &dc) == MLB_OK);
        REQUIRE(mlb_vae_decode_backward(NULL, v, &dc, rf, pass ? dzg : dzc, g) == MLB_OK);
        CHECK(!pass || (ec.device == MLB_DEVICE_CUDA && dc.device == MLB_DEVICE_CUDA));
        mlb_vae_cache_free(&ec);
        mlb_vae_dec_cache_free(&dc);
    }
    double ep = 0, gm = 0, ei = 0, ez = 0, eo = 0;
    for (size_t k = 0; k < v->n_params; k++) gm = fmax(gm, fabs(gc->params[k]));
    for (size_t k = 0; k < v->n_params; k++) ep = fmax(ep, fabs(gc->params[k] - gg->params[k]) / gm);
    for (int i = 0; i < NI; i++) { ei = fmax(ei, fabs(dic[i] - dig[i])); eo = fmax(eo, fabs(a[i] - b[i])); }
    for (int i = 0; i < NZ; i++) ez = fmax(ez, fabs(dzc[i] - dzg[i]));
    printf("  GPU vs CPU: weight gradients %.3g (relative to max %.3g), dimage %.3g, dz %.3g, image %.3g\n", ep, gm,
           ei, ez, eo);
    CHECK(ep < 1e-4 && ei < 1e-4 && ez < 1e-4 && eo < 1e-4);
    mlb_vae_free(gc); mlb_vae_free(gg); mlb_vae_free(v);
}

int main(void) {
    RUN(encoder_weight_gradients_fd);
    RUN(decoder_backward_fd);
    RUN(gpu_matches_cpu);
    return test_summary();
}
