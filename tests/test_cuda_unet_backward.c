// CUDA parity of the UNet's training path (unet_train.h): the op table's ops that only the backward
// uses (layernorm with statistics and its backward, GEGLU's, the 2x upsample's and add_channel's
// backwards) and a whole tiny UNet's forward_train + backward (every parameter's gradient, dx,
// dctx), CUDA's table against the CPU's, at fp32 and tf32. Skips without a GPU.
#include "cuda_test_util.h"
#include "matlaber/backend.h"
#include "matlaber/unet_random.h"
#include "matlaber/unet_train.h"

static const mlb_backend* cpu(void) { return mlb_backend_cpu(); }
static const mlb_backend* gpu(mlb_gemm_precision p) { return mlb_backend_for(MLB_DEVICE_CUDA, p); }

static float* up(const float* h, size_t n) { return dev_floats(h, n); }
static float* zeros_dev(size_t n) {
    float* d = dev_floats(NULL, n);
    if (d && mlb_cuda_memset(d, 0, n * sizeof(float)) != MLB_OK) { mlb_cuda_free(d); return NULL; }
    return d;
}

TEST(glue_backward_ops) {
    REQUIRE_GPU();
    uint64_t seed = test_seed();
    const mlb_backend* g = gpu(MLB_GEMM_FP32);
    // layernorm with statistics, then its backward: 37 rows of 48 (ragged against any block size)
    int N = 37, C = 48;
    size_t n = (size_t)N * C;
    float *x = host_alloc(n), *w = host_alloc(C), *b = host_alloc(C), *dy = host_alloc(n);
    fill_uniform(x, n, seed, 1, -2, 3);
    fill_uniform(w, C, seed, 2, 0.5f, 1.5f);
    fill_uniform(b, C, seed, 3, -0.2f, 0.2f);
    fill_uniform(dy, n, seed, 4, -1, 1);
    float *y = host_alloc(n), *mu = host_alloc(N), *rs = host_alloc(N), *dx = host_alloc(n), *dw = host_alloc(C), *db = host_alloc(C);
    REQUIRE(cpu()->layernorm_stats(y, mu, rs, x, w, b, N, C, 1e-5f) == MLB_OK);
    REQUIRE(cpu()->layernorm_backward(dx, dw, db, dy, x, w, mu, rs, N, C) == MLB_OK);
    float *gx = up(x, n), *gw = up(w, C), *gb = up(b, C), *gdy = up(dy, n), *gy = dev_floats(NULL, n), *gmu = dev_floats(NULL, N),
          *grs = dev_floats(NULL, N), *gdx = zeros_dev(n), *gdw = zeros_dev(C), *gdb = zeros_dev(C);
    REQUIRE(gx && gw && gb && gdy && gy && gmu && grs && gdx && gdw && gdb);
    REQUIRE(g->layernorm_stats(gy, gmu, grs, gx, gw, gb, N, C, 1e-5f) == MLB_OK);
    REQUIRE(g->layernorm_backward(gdx, gdw, gdb, gdy, gx, gw, gmu, grs, N, C) == MLB_OK);
    float *hy = host_alloc(n), *hmu = host_alloc(N), *hrs = host_alloc(N), *hdx = host_alloc(n), *hdw = host_alloc(C), *hdb = host_alloc(C);
    REQUIRE(host_floats(hy, gy, n) && host_floats(hmu, gmu, N) && host_floats(hrs, grs, N) && host_floats(hdx, gdx, n) &&
            host_floats(hdw, gdw, C) && host_floats(hdb, gdb, C));
    CHECK_PARITY("layernorm_stats out", hy, y, n, 1e-6);
    CHECK_PARITY("layernorm_stats mean", hmu, mu, N, 1e-6);
    CHECK_PARITY("layernorm_stats rstd", hrs, rs, N, 1e-6);
    CHECK_PARITY("layernorm_backward dx", hdx, dx, n, 1e-5);
    CHECK_PARITY("layernorm_backward dw", hdw, dw, C, 1e-5);
    CHECK_PARITY("layernorm_backward db", hdb, db, C, 1e-5);
    // GEGLU backward: 29 rows, C4 = 40 (accumulating into a nonzero din)
    int R = 29, C4 = 40;
    size_t ni = (size_t)R * 2 * C4, no = (size_t)R * C4;
    float *gi = host_alloc(ni), *go = host_alloc(no), *gdin = host_alloc(ni);
    fill_uniform(gi, ni, seed, 5, -3, 3);
    fill_uniform(go, no, seed, 6, -1, 1);
    fill_uniform(gdin, ni, seed, 7, -0.5f, 0.5f);
    float *dgi = up(gi, ni), *dgo = up(go, no), *dgdin = up(gdin, ni), *hgdin = host_alloc(ni);
    REQUIRE(dgi && dgo && dgdin);
    REQUIRE(cpu()->geglu_backward(gdin, go, gi, R, C4) == MLB_OK);
    REQUIRE(g->geglu_backward(dgdin, dgo, dgi, R, C4) == MLB_OK);
    REQUIRE(host_floats(hgdin, dgdin, ni));
    CHECK_PARITY("geglu_backward (+=)", hgdin, gdin, ni, 1e-6);
    // upsample 2x backward: [3, 5, 7, 9] from [3, 5, 14, 18]; add_channel backward: [3, 5] from [3, 5, 63]
    int UN = 3, UC = 5, UH = 7, UW = 9;
    size_t nd = (size_t)UN * UC * UH * UW, nu = 4 * nd;
    float *ud = host_alloc(nu), *us = host_alloc(nd), *hus = host_alloc(nd);
    fill_uniform(ud, nu, seed, 8, -1, 1);
    fill_uniform(us, nd, seed, 9, -1, 1);
    float *dud = up(ud, nu), *dus = up(us, nd);
    REQUIRE(dud && dus);
    REQUIRE(cpu()->upsample_nearest2x_backward(us, ud, UN, UC, UH, UW) == MLB_OK);
    REQUIRE(g->upsample_nearest2x_backward(dus, dud, UN, UC, UH, UW) == MLB_OK);
    REQUIRE(host_floats(hus, dus, nd));
    CHECK_PARITY("upsample_nearest2x_backward (+=)", hus, us, nd, 1e-6);
    int HW = UH * UW;
    float *cv = host_alloc(UN * UC), *hcv = host_alloc(UN * UC);
    fill_uniform(cv, UN * UC, seed, 10, -1, 1);
    float* dcv = up(cv, UN * UC);
    REQUIRE(dcv);
    REQUIRE(cpu()->add_channel_backward(cv, us, UN, UC, HW) == MLB_OK);
    REQUIRE(g->add_channel_backward(dcv, dus, UN, UC, HW) == MLB_OK);
    REQUIRE(host_floats(hcv, dcv, UN * UC));
    CHECK_PARITY("add_channel_backward (+=)", hcv, cv, UN * UC, 1e-6);
    float* hf[] = {x, w, b, dy, y, mu, rs, dx, dw, db, hy, hmu, hrs, hdx, hdw, hdb, gi, go, gdin, hgdin, ud, us, hus, cv, hcv};
    for (size_t i = 0; i < sizeof hf / sizeof hf[0]; i++) free(hf[i]);
    float* df[] = {gx, gw, gb, gdy, gy, gmu, grs, gdx, gdw, gdb, dgi, dgo, dgdin, dud, dus, dcv};
    for (size_t i = 0; i < sizeof df / sizeof df[0]; i++) mlb_cuda_free(df[i]);
}

// forward_train + backward of L = sum(out * r) on be for a UNet whose weights are `host`'s
static mlb_status grads_on(const mlb_backend* be, const mlb_unet* host, const float* x, const float* t, const float* ctx,
                           const float* r, int N, int H, int Tc, float* out, float* grads, float* dx, float* dctx) {
    const mlb_unet_config* c = &host->cfg;
    size_t nx = (size_t)N * c->in_channels * H * H, nc = (size_t)N * Tc * c->context_dim, no = (size_t)N * c->out_channels * H * H;
    mlb_unet *u = NULL, *g = NULL;
    mlb_unet_tape* tape = NULL;
    float *bx = NULL, *bc = NULL, *bo = NULL, *br = NULL, *bdx = NULL, *bdc = NULL;
    mlb_status s = be->device == MLB_DEVICE_CPU ? MLB_OK : mlb_unet_to_device(host, be->device, &u);
    const mlb_unet* m = u ? u : host;
    if (!s) s = mlb_unet_create(c, be->device, &g);
    if (!s) s = be->zero(g->params, g->n_params);
    if (!s) s = mlb_unet_tape_create(be, m, N, H, H, Tc, &tape);
    if (!s) s = be->alloc(&bx, nx);
    if (!s) s = be->alloc(&bc, nc);
    if (!s) s = be->alloc(&bo, no);
    if (!s) s = be->alloc(&br, no);
    if (!s) s = be->alloc(&bdx, nx);
    if (!s) s = be->alloc(&bdc, nc);
    if (!s) s = be->upload(bx, x, nx);
    if (!s) s = be->upload(bc, ctx, nc);
    if (!s) s = be->upload(br, r, no);
    if (!s) s = be->zero(bdx, nx);
    if (!s) s = be->zero(bdc, nc);
    if (!s) s = mlb_unet_forward_train(be, m, tape, bo, bx, t, bc, N, H, H, Tc);
    if (!s) s = mlb_unet_backward(be, m, tape, br, g, bdx, bdc);
    if (!s) s = be->download(out, bo, no);
    if (!s) s = be->download(grads, g->params, g->n_params);
    if (!s) s = be->download(dx, bdx, nx);
    if (!s) s = be->download(dctx, bdc, nc);
    float* bufs[] = {bx, bc, bo, br, bdx, bdc};
    for (int i = 0; i < 6; i++) be->release(bufs[i]);
    mlb_unet_tape_free(tape);
    mlb_unet_free(g);
    mlb_unet_free(u);
    return s;
}

static void unet_case(int sd2, mlb_gemm_precision prec, double tol) {
    uint64_t seed = test_seed();
    mlb_unet_config c = mlb_unet_tiny_config(sd2);
    mlb_unet* u = NULL;
    REQUIRE(mlb_unet_create(&c, MLB_DEVICE_CPU, &u) == MLB_OK);
    size_t ns = 0, off = 0;
    REQUIRE(mlb_unet_tensor_specs(&c, NULL, 0, &ns) == MLB_OK);
    mlb_unet_tensor_spec* sp = calloc(ns, sizeof *sp);
    REQUIRE(sp);
    mlb_unet_tensor_specs(&c, sp, ns, &ns);
    for (size_t i = 0; i < ns; i++) { mlb_unet_random_values(&sp[i], i, seed, 1.0f, u->params + off); off += sp[i].n; }
    free(sp);
    int N = 2, H = 16, Tc = 7;
    size_t nx = (size_t)N * c.in_channels * H * H, nc = (size_t)N * Tc * c.context_dim, no = (size_t)N * c.out_channels * H * H;
    float *x = host_alloc(nx), *ctx = host_alloc(nc), *r = host_alloc(no), t[2] = {17.0f, 803.0f};
    fill_uniform(x, nx, seed, 11, -1.5f, 1.5f);
    fill_uniform(ctx, nc, seed, 12, -1, 1);
    fill_uniform(r, no, seed, 13, -1, 1);
    float *o1 = host_alloc(no), *o2 = host_alloc(no), *g1 = host_alloc(u->n_params), *g2 = host_alloc(u->n_params);
    float *x1 = host_alloc(nx), *x2 = host_alloc(nx), *c1 = host_alloc(nc), *c2 = host_alloc(nc);
    REQUIRE(grads_on(cpu(), u, x, t, ctx, r, N, H, Tc, o1, g1, x1, c1) == MLB_OK);
    mlb_status s = grads_on(gpu(prec), u, x, t, ctx, r, N, H, Tc, o2, g2, x2, c2);
    CHECK_MSG(s == MLB_OK, "GPU training pass: %s", mlb_last_error());
    if (s == MLB_OK) {
        char what[64];
        snprintf(what, sizeof what, "%s %s out", sd2 ? "SD2" : "SD1", mlb_gemm_precision_name(prec));
        CHECK_PARITY(what, o2, o1, no, tol);
        snprintf(what, sizeof what, "%s %s d params (%zu)", sd2 ? "SD2" : "SD1", mlb_gemm_precision_name(prec), u->n_params);
        CHECK_PARITY(what, g2, g1, u->n_params, tol);
        snprintf(what, sizeof what, "%s %s dx", sd2 ? "SD2" : "SD1", mlb_gemm_precision_name(prec));
        CHECK_PARITY(what, x2, x1, nx, tol);
        snprintf(what, sizeof what, "%s %s dctx", sd2 ? "SD2" : "SD1", mlb_gemm_precision_name(prec));
        CHECK_PARITY(what, c2, c1, nc, tol);
    }
    float* hf[] = {x, ctx, r, o1, o2, g1, g2, x1, x2, c1, c2};
    for (size_t i = 0; i < sizeof hf / sizeof hf[0]; i++) free(hf[i]);
    mlb_unet_free(u);
}

// fp32: the same arithmetic in another order (1e-4); tf32: 10-bit mantissas in every GEMM (2e-2, as
// the forward's whole-UNet bound in test_cuda_unet)
TEST(unet_backward_sd1_fp32) { REQUIRE_GPU(); unet_case(0, MLB_GEMM_FP32, 1e-4); }
TEST(unet_backward_sd2_fp32) { REQUIRE_GPU(); unet_case(1, MLB_GEMM_FP32, 1e-4); }
TEST(unet_backward_sd1_tf32) { REQUIRE_GPU(); unet_case(0, MLB_GEMM_TF32, 2e-2); }

int main(void) {
    RUN(glue_backward_ops);
    RUN(unet_backward_sd1_fp32);
    RUN(unet_backward_sd2_fp32);
    RUN(unet_backward_sd1_tf32);
    return test_summary();
}
