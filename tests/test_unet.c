// The UNet against ../shared/data/sd_reference: SD1 and SD2 tiny models in the diffusers and the
// single-file (ldm) layouts, stage by stage (debug.*), non-square latents, F16 weights, errors,
// and a 4-step DDIM with guidance 7.5 (UNet + scheduler) against ref_ddim_sd1.
#include "test.h"
#include "matlaber/safetensors.h"
#include "matlaber/schedule.h"
#include "matlaber/unet.h"
#include "matlaber/backend.h"
#include "matlaber/rng.h"
#include "matlaber/unet_random.h"

static const char* ref_path(const char* file) {   // 4 rotating buffers: several may be live at once
    static char bufs[4][4096];
    static int k;
    char* p = bufs[k++ & 3];
    const char* d = test_shared_data();
    if (!d) return NULL;
    snprintf(p, 4096, "%s/sd_reference/%s", d, file);
    struct stat s;
    return stat(p, &s) == 0 ? p : NULL;
}

static float* read_all(const mlb_safetensors* st, const char* name, size_t* n) {
    const mlb_st_tensor* t = mlb_st_find(st, name);
    if (!t) return NULL;
    float* b = malloc(t->nelem * sizeof(float));
    if (!b || mlb_st_read_f32(st, name, b, t->nelem) != MLB_OK) { free(b); return NULL; }
    if (n) *n = t->nelem;
    return b;
}

static float* read_t(const mlb_safetensors* st, const char* name, int* N) {   // I64 timesteps as float
    const mlb_st_tensor* t = mlb_st_find(st, name);
    if (!t || t->dtype != MLB_DT_I64) return NULL;
    float* b = malloc(t->nelem * sizeof(float));
    for (size_t i = 0; i < t->nelem; i++) {
        int64_t v;
        memcpy(&v, (const char*)t->data + 8 * i, 8);
        b[i] = (float)v;
    }
    *N = (int)t->nelem;
    return b;
}

static double max_abs_diff(const float* a, const float* b, size_t n) {
    double m = 0;
    for (size_t i = 0; i < n; i++) {
        double d = fabs((double)a[i] - b[i]);
        if (!(d <= m)) m = isnan(d) ? INFINITY : d;
    }
    return m;
}

typedef struct { const mlb_safetensors* ref; double worst; int checked; } dbg_ctx;
static void on_debug(void* user, const char* name, const float* data, size_t n) {
    dbg_ctx* d = user;
    char rn[128];
    snprintf(rn, sizeof rn, "debug.%s", name);
    size_t m = 0;
    float* r = read_all(d->ref, rn, &m);
    if (!r) { printf("  (no reference %s)\n", rn); return; }
    if (m != n) { printf("  %s: %zu values, reference %zu\n", rn, n, m); d->worst = INFINITY; free(r); return; }
    double e = max_abs_diff(data, r, n);
    if (e > 1e-4) printf("  %s: max abs err %.3g\n", rn, e);
    if (e > d->worst) d->worst = e;
    d->checked++;
    free(r);
}

// eps (with the debug stages), eps_nonsquare, eps_8x8 for one model against one reference file.
static void check_model(const mlb_unet* u, const char* ref_file, const char* label, float* eps_out) {
    mlb_safetensors* ref = NULL;
    REQUIRE(mlb_st_open(&ref, ref_path(ref_file)) == MLB_OK);
    const mlb_unet_config* c = mlb_unet_get_config(u);
    int N = 0, N2 = 0, N3 = 0;
    size_t nx, nctx;
    float *x = read_all(ref, "x", &nx), *ctx = read_all(ref, "context", &nctx), *t = read_t(ref, "t", &N);
    float* eps = read_all(ref, "eps", NULL);
    REQUIRE(x && ctx && t && eps);
    int H = 16, W = 16, Tc = (int)(nctx / ((size_t)N * c->context_dim));
    float* out = malloc(nx * sizeof(float));
    dbg_ctx d = {ref, 0, 0};
    REQUIRE(mlb_unet_forward(NULL, u, out, x, t, ctx, N, H, W, Tc, on_debug, &d) == MLB_OK);
    double e = max_abs_diff(out, eps, nx);
    printf("  %s: eps max abs err %.3g (stages: %d checked, worst %.3g)\n", label, e, d.checked, d.worst);
    CHECK(e <= 1e-4);
    CHECK(d.checked == 13 && d.worst <= 1e-4);
    if (eps_out) memcpy(eps_out, out, nx * sizeof(float));
    // non-square 16x24
    float *xn = read_all(ref, "x_nonsquare", NULL), *cn = read_all(ref, "context_nonsquare", NULL);
    float *tn = read_t(ref, "t_nonsquare", &N2), *en = read_all(ref, "eps_nonsquare", NULL);
    REQUIRE(xn && cn && tn && en);
    float* on = malloc((size_t)N2 * 4 * 16 * 24 * sizeof(float));
    REQUIRE(mlb_unet_forward(NULL, u, on, xn, tn, cn, N2, 16, 24, Tc, NULL, NULL) == MLB_OK);
    double en_err = max_abs_diff(on, en, (size_t)N2 * 4 * 16 * 24);
    // 8x8 (ill-conditioned: the deepest level is 1x1)
    float *x8 = read_all(ref, "x_8x8", NULL), *e8 = read_all(ref, "eps_8x8", NULL);
    REQUIRE(x8 && e8);
    float* o8 = malloc((size_t)N * 4 * 64 * sizeof(float));
    REQUIRE(mlb_unet_forward(NULL, u, o8, x8, t, ctx, N, 8, 8, Tc, NULL, NULL) == MLB_OK);
    double e8_err = max_abs_diff(o8, e8, (size_t)N * 4 * 64);
    printf("  %s: eps_nonsquare max abs err %.3g, eps_8x8 %.3g\n", label, en_err, e8_err);
    CHECK(en_err <= 1e-4);
    CHECK(e8_err <= 1e-2);
    (void)N3;
    free(x); free(ctx); free(t); free(eps); free(out); free(xn); free(cn); free(tn); free(en); free(on);
    free(x8); free(e8); free(o8);
    mlb_st_close(ref);
}

static float sd1_eps_diffusers[2 * 4 * 16 * 16], sd2_eps_diffusers[2 * 4 * 16 * 16];

TEST(sd1_diffusers_folder) {
    const char* p = ref_path("sd1_diffusers");
    if (!p) SKIP("no sd_reference/sd1_diffusers");
    mlb_unet* u = NULL;
    REQUIRE(mlb_unet_load(p, NULL, &u) == MLB_OK);
    const mlb_unet_config* c = mlb_unet_get_config(u);
    CHECK(c->layout == MLB_UNET_LAYOUT_DIFFUSERS && !c->sd2 && !c->linear_projection);
    CHECK(c->n_levels == 4 && c->block_out[2] == 64 && c->layers_per_block == 2 && c->context_dim == 32);
    CHECK(c->attn[0] && c->attn[2] && !c->attn[3] && c->heads[0] == 8 && c->mid_heads == 8 && c->time_embed_dim == 128);
    CHECK(mlb_unet_param_count(u) == 2446788);
    check_model(u, "ref_unet_sd1.safetensors", "SD1 diffusers", sd1_eps_diffusers);
    mlb_unet_free(u);
}

TEST(sd1_single_file) {
    const char* p = ref_path("sd1_tiny.safetensors");
    if (!p) SKIP("no sd_reference/sd1_tiny.safetensors");
    mlb_unet* u = NULL;
    REQUIRE(mlb_unet_load(p, NULL, &u) == MLB_OK);
    CHECK(mlb_unet_get_config(u)->layout == MLB_UNET_LAYOUT_LDM);
    static float e[2 * 4 * 16 * 16];
    check_model(u, "ref_unet_sd1.safetensors", "SD1 single file", e);
    CHECK(max_abs_diff(e, sd1_eps_diffusers, sizeof e / sizeof e[0]) == 0);   // the same weights, the same code
    mlb_unet_free(u);
}

TEST(sd2_diffusers_file) {
    const char* p = ref_path("unet_sd2.diffusers.safetensors");
    if (!p) SKIP("no sd_reference/unet_sd2.diffusers.safetensors");
    mlb_unet* u = NULL;
    REQUIRE(mlb_unet_load(p, NULL, &u) == MLB_OK);
    const mlb_unet_config* c = mlb_unet_get_config(u);
    CHECK(c->sd2 && c->linear_projection && c->context_dim == 48);
    CHECK(c->heads[0] == 4 && c->heads[2] == 8 && c->mid_heads == 8);
    check_model(u, "ref_unet_sd2.safetensors", "SD2 diffusers", sd2_eps_diffusers);
    mlb_unet_free(u);
}

TEST(sd2_single_file) {
    const char* p = ref_path("sd2_tiny.safetensors");
    if (!p) SKIP("no sd_reference/sd2_tiny.safetensors");
    mlb_unet* u = NULL;
    REQUIRE(mlb_unet_load(p, NULL, &u) == MLB_OK);
    const mlb_unet_config* c = mlb_unet_get_config(u);
    CHECK(c->layout == MLB_UNET_LAYOUT_LDM && c->sd2 && c->heads[0] == 4 && c->mid_heads == 8);
    static float e[2 * 4 * 16 * 16];
    check_model(u, "ref_unet_sd2.safetensors", "SD2 single file", e);
    CHECK(max_abs_diff(e, sd2_eps_diffusers, sizeof e / sizeof e[0]) == 0);
    mlb_unet_free(u);
}

TEST(sd1_f16_weights) {
    const char* p = ref_path("sd1_tiny.f16.safetensors");
    const char* r = ref_path("ref_sd1_halfweights.safetensors");
    if (!p || !r) SKIP("no sd_reference/sd1_tiny.f16.safetensors or ref_sd1_halfweights");
    mlb_unet* u = NULL;
    REQUIRE(mlb_unet_load(p, NULL, &u) == MLB_OK);
    mlb_safetensors *ref = NULL, *half = NULL;
    REQUIRE(mlb_st_open(&ref, ref_path("ref_unet_sd1.safetensors")) == MLB_OK);
    REQUIRE(mlb_st_open(&half, r) == MLB_OK);
    int N = 0;
    float *x = read_all(ref, "x", NULL), *ctx = read_all(ref, "context", NULL), *t = read_t(ref, "t", &N);
    float* want = read_all(half, "f16.unet_eps", NULL);
    REQUIRE(x && ctx && t && want);
    static float out[2 * 4 * 16 * 16];
    REQUIRE(mlb_unet_forward(NULL, u, out, x, t, ctx, N, 16, 16, 77, NULL, NULL) == MLB_OK);
    double e = max_abs_diff(out, want, sizeof out / sizeof out[0]);
    printf("  SD1 F16 weights: eps max abs err %.3g vs f16.unet_eps\n", e);
    CHECK(e <= 1e-4);
    free(x); free(ctx); free(t); free(want);
    mlb_st_close(ref);
    mlb_st_close(half);
    mlb_unet_free(u);
}

TEST(errors) {
    mlb_unet* u = NULL;
    CHECK(mlb_unet_load("/nonexistent/unet.safetensors", NULL, &u) != MLB_OK && u == NULL);
    CHECK(mlb_unet_load("/nonexistent/model.ckpt", NULL, &u) == MLB_ERR_NOT_FOUND);
    // an existing pickle: refused unread, with the way out (sd_files.c, as for the other components)
    const char* ckpt = "tmp_unet_model.ckpt";
    FILE* f = fopen(ckpt, "wb");
    REQUIRE(f);
    fputs("x", f);
    fclose(f);
    CHECK(mlb_unet_load(ckpt, NULL, &u) == MLB_ERR_UNSUPPORTED && u == NULL);
    CHECK_MSG(strstr(mlb_last_error(), "UNet tmp_unet_model.ckpt: pickle checkpoints run code"), "%s", mlb_last_error());
    remove(ckpt);
    const char* p = ref_path("sd1_diffusers/unet/diffusion_pytorch_model.safetensors");
    if (!p) return;
    // A file with one tensor dropped / one reshaped: the error names the tensor and the file.
    mlb_safetensors* st = NULL;
    REQUIRE(mlb_st_open(&st, p) == MLB_OK);
    size_t n = mlb_st_count(st);
    mlb_st_entry* e = calloc(n, sizeof *e);
    int64_t (*shapes)[8] = calloc(n, sizeof *shapes);
    const char* dir = test_tmpdir("unet");
    REQUIRE(dir);
    char out[4096];
    for (int mode = 0; mode < 2; mode++) {
        size_t k = 0;
        for (size_t i = 0; i < n; i++) {
            const mlb_st_tensor* t = mlb_st_tensor_at(st, i);
            int target = !strcmp(t->name, "up_blocks.1.attentions.2.transformer_blocks.0.attn2.to_v.weight");
            if (target && mode == 0) continue;
            e[k].name = t->name;
            e[k].dtype = t->dtype;
            e[k].ndim = t->ndim;
            memcpy(shapes[k], t->shape, sizeof shapes[k]);
            if (target) { shapes[k][0] = t->shape[1]; shapes[k][1] = t->shape[0]; }   // transposed
            e[k].shape = shapes[k];
            e[k].data = t->data;
            k++;
        }
        snprintf(out, sizeof out, "%s/broken%d.safetensors", dir, mode);
        REQUIRE(mlb_st_write(out, e, k, NULL, 0) == MLB_OK);
        mlb_unet_options opt = {ref_path("sd1_diffusers/unet/config.json"), 0, 0};
        mlb_status s = mlb_unet_load(out, &opt, &u);
        CHECK(s == (mode == 0 ? MLB_ERR_NOT_FOUND : MLB_ERR_FORMAT) && u == NULL);
        CHECK(strstr(mlb_last_error(), "up_blocks.1.attentions.2.transformer_blocks.0.attn2.to_v.weight") != NULL);
        CHECK(strstr(mlb_last_error(), "broken") != NULL);
        printf("  %s\n", mlb_last_error());
    }
    free(e);
    free(shapes);
    mlb_st_close(st);
    // bad latent size
    REQUIRE(mlb_unet_load(ref_path("sd1_diffusers"), NULL, &u) == MLB_OK);
    float x[4 * 12 * 12] = {0}, t1 = 10, ctx[77 * 32] = {0}, o[4 * 12 * 12];
    CHECK(mlb_unet_forward(NULL, u, o, x, &t1, ctx, 1, 12, 12, 77, NULL, NULL) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "multiple of 8") != NULL);
    mlb_unet_free(u);
}

// 4-step DDIM, CFG 7.5, SD1: UNet on [uncond, cond] then the scheduler, against ref_ddim_sd1.
TEST(ddim_sd1_cfg) {
    const char* rp = ref_path("ref_ddim_sd1.safetensors");
    const char* mp = ref_path("sd1_diffusers");
    if (!rp || !mp) SKIP("no sd_reference DDIM reference or SD1 model");
    mlb_unet* u = NULL;
    REQUIRE(mlb_unet_load(mp, NULL, &u) == MLB_OK);
    mlb_safetensors* ref = NULL;
    REQUIRE(mlb_st_open(&ref, rp) == MLB_OK);
    enum { M = 4 * 16 * 16 };
    float *ctx = read_all(ref, "context", NULL), *noise = read_all(ref, "noise", NULL);
    float *final = read_all(ref, "latent_final", NULL), *eg_ref = read_all(ref, "debug.eps_guided", NULL);
    REQUIRE(ctx && noise && final && eg_ref);
    static double ac[1000];
    static float ac32[1000];
    REQUIRE(mlb_schedule_alphas_cumprod_f32(ac32, 1000, MLB_SD_BETA_START, MLB_SD_BETA_END) == MLB_OK);
    for (int i = 0; i < 1000; i++) ac[i] = ac32[i];
    int ts[4];
    REQUIRE(mlb_ddim_timesteps(ts, 4, 1000, 1) == MLB_OK);
    static float lat[M], x2[2 * M], e2[2 * M], eg[M];
    memcpy(lat, noise, sizeof lat);
    double eg_err = 0;
    for (int s = 0; s < 4; s++) {
        memcpy(x2, lat, sizeof lat);
        memcpy(x2 + M, lat, sizeof lat);
        float tt[2] = {(float)ts[s], (float)ts[s]};
        REQUIRE(mlb_unet_forward(NULL, u, e2, x2, tt, ctx, 2, 16, 16, 77, NULL, NULL) == MLB_OK);
        mlb_cfg_combine(eg, e2, e2 + M, M, 7.5f);   // context = [uncond, cond]
        double e = max_abs_diff(eg, eg_ref + (size_t)s * M, M);
        if (e > eg_err) eg_err = e;
        int tp = mlb_ddim_prev_timestep(ts[s], 4, 1000);
        REQUIRE(mlb_ddim_step(lat, NULL, lat, eg, M, ac[ts[s]], mlb_ddim_alpha_prev(ac, tp, 0)) == MLB_OK);
    }
    double e = max_abs_diff(lat, final, M);
    printf("  DDIM 4 steps CFG 7.5: eps_guided max abs err %.3g, latent_final max abs err %.3g\n", eg_err, e);
    CHECK(e <= 1e-3);
    free(ctx); free(noise); free(final); free(eg_ref);
    mlb_st_close(ref);
    mlb_unet_free(u);
}

// The forward written once against backend.h: on the CPU table, with a UNet made by
// mlb_unet_create + mlb_unet_to_device, it gives exactly the bits of mlb_unet_forward on the loaded
// UNet (the carve order is the loader's: the copied parameters land on the same tensors). Needs no
// shared data. The GPU side of the same forward: tests/test_cuda_unet.c.
TEST(forward_on_cpu_table_is_bitwise) {
    mlb_unet_config cfg = mlb_unet_tiny_config(0);
    char path[600];
    snprintf(path, sizeof path, "%s/random_sd1.safetensors", test_tmpdir("unet"));
    mlb_unet_random_options o = mlb_unet_random_default_options();
    o.seed = 5;
    mlb_unet *u = NULL, *c = NULL;
    CHECK_MSG(mlb_unet_write_random(&cfg, &o, path) == MLB_OK, "%s", mlb_last_error());
    CHECK_MSG(mlb_unet_load(path, NULL, &u) == MLB_OK, "%s", mlb_last_error());
    if (!u) return;
    CHECK_MSG(mlb_unet_to_device(u, MLB_DEVICE_CPU, &c) == MLB_OK, "%s", mlb_last_error());
    if (!c) { mlb_unet_free(u); return; }
    CHECK(c->device == MLB_DEVICE_CPU && c->n_params == u->n_params);
    CHECK(c->down_attn[1][1].ff2_w - c->params == u->down_attn[1][1].ff2_w - u->params);
    CHECK(c->conv_out_b - c->params == u->conv_out_b - u->params);
    const int N = 2, H = 16, W = 8, Tc = 5;
    size_t nx = (size_t)N * 4 * H * W, nc = (size_t)N * Tc * cfg.context_dim;
    float *x = malloc(nx * 4), *ctx = malloc(nc * 4), *a = malloc(nx * 4), *b = malloc(nx * 4), t[2] = {1.0f, 640.0f};
    for (size_t i = 0; i < nx; i++) x[i] = (float)mlb_rng_uniform_f64(9, 1, i) * 2 - 1;
    for (size_t i = 0; i < nc; i++) ctx[i] = (float)mlb_rng_uniform_f64(9, 2, i) * 2 - 1;
    CHECK(mlb_unet_forward(NULL, u, a, x, t, ctx, N, H, W, Tc, NULL, NULL) == MLB_OK);
    CHECK(mlb_unet_forward(mlb_backend_cpu(), c, b, x, t, ctx, N, H, W, Tc, NULL, NULL) == MLB_OK);
    CHECK_MSG(!memcmp(a, b, nx * 4), "the CPU table's forward differs from mlb_unet_forward");
    double s = 0;
    for (size_t i = 0; i < nx; i++) s += fabs(a[i]);
    CHECK(isfinite(s) && s > 0);
    // the CUDA table with CPU weights is refused (either device mismatch, or no GPU in this build)
    CHECK(mlb_unet_forward(mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32), c, b, x, t, ctx, N, H, W, Tc, NULL,
                              NULL) != MLB_OK);
    // without a GPU, use_device fails cleanly and the UNet stays on the CPU
    if (mlb_cuda_device_count() == 0) {
        CHECK(mlb_unet_use_device(u, MLB_DEVICE_CUDA, MLB_GEMM_FP16) == MLB_ERR_DEVICE && !u->mirror);
        CHECK(mlb_unet_forward(NULL, u, b, x, t, ctx, N, H, W, Tc, NULL, NULL) == MLB_OK && !memcmp(a, b, nx * 4));
    }
    free(x); free(ctx); free(a); free(b);
    mlb_unet_free(c);
    mlb_unet_free(u);
}

int main(void) {
    RUN(sd1_diffusers_folder);
    RUN(sd1_single_file);
    RUN(sd2_diffusers_file);
    RUN(sd2_single_file);
    RUN(sd1_f16_weights);
    RUN(errors);
    RUN(ddim_sd1_cfg);
    RUN(forward_on_cpu_table_is_bitwise);
    return test_summary();
}
