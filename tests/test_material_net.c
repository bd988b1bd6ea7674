// The material network (hash grid → MLP → latent z → frozen BRDF decoder, or → sigmoid → ranges):
// finite differences in double of the parameters and of the positions in both modes, the decoder
// frozen through Adam, the output map equal to the prior's, evaluation without the cache, and the
// file format (bitwise round trip, hostile files).
#include <stdint.h>
#include "matlaber/brdf.h"
#include "matlaber/material_net.h"
#include "matlaber/rng.h"
#include "material_test_util.h"
#include "test.h"

static mlb_material_config small_config(mlb_material_mode mode) {
    mlb_material_config c = mlb_material_default();
    c.enc = (mlb_hashgrid_config){4, 2, 256, 3, 1.7};   // levels 0, 1 dense, 2, 3 hashed
    c.hidden = 8;
    c.n_hidden = 2;
    c.seed = 5;
    c.mode = mode;
    return c;
}


static double loss_f64(mlb_material_net_f64* net, const double* pos, const double* w, int n, double* k) {
    if (material_net_forward_f64(net, k, NULL, pos, n) != MLB_OK) return NAN;
    double L = 0;
    for (int i = 0; i < 7 * n; i++) L += w[i] * k[i];
    return L;
}

static void fd_check(mlb_material_mode mode) {
    mlb_brdf_ae prior;
    REQUIRE(random_prior(&prior));
    mlb_material_config c = small_config(mode);
    mlb_material_net_f64 net;
    REQUIRE(material_net_init_f64(&net, &c, &prior) == MLB_OK);
    randomize_f64(&net, 9);
    enum { n = 40 };
    double pos[3 * n], w[7 * n], k[7 * n], dpos[3 * n] = {0};
    for (int i = 0; i < 3 * n; i++) pos[i] = (mlb_rng_uniform_f64(11, 0, i) - 0.5) * 1.6;
    for (int i = 0; i < 7 * n; i++) w[i] = mlb_rng_normal_f64(11, 1, i);
    double L0 = loss_f64(&net, pos, w, n, k);
    REQUIRE(isfinite(L0));
    for (int i = 0; i < n; i++) {   // valid BRDFs
        CHECK(k[7 * i] >= 0 && k[7 * i] <= 1 && k[7 * i + 4] >= 0 && k[7 * i + 4] <= 1);
        CHECK(k[7 * i + 6] >= MLB_KR_MIN - 1e-7 && k[7 * i + 6] <= 1);
    }
    material_net_zero_grad_f64(&net);
    material_net_backward_f64(&net, w, dpos);
    // parameters: the 6 table entries and 6 MLP values of largest gradient, plus 4 fixed MLP ones
    size_t pick[16];
    int np = 12;
    test_top_grads(net.grads, net.n_enc, net.n_params, 6, pick);
    for (int t = 0; t < 4; t++) pick[np++] = net.n_enc + (net.n_mlp * (2 * t + 1)) / 9;
    const double h = 1e-6;
    double worst = 0;
    for (int q = 0; q < np; q++) {
        size_t i = pick[q];
        double keep = net.params[i];
        net.params[i] = keep + h;
        double Lp = loss_f64(&net, pos, w, n, k);
        net.params[i] = keep - h;
        double Lm = loss_f64(&net, pos, w, n, k);
        net.params[i] = keep;
        double fd = (Lp - Lm) / (2 * h), g = net.grads[i];
        double err = fabs(fd - g) / (fabs(fd) + fabs(g) + 1e-6);
        if (err > worst) worst = err;
        CHECK_MSG(fabs(fd - g) <= 1e-6 + 1e-5 * fabs(fd), "%s param %zu: fd %.10g, backward %.10g", mlb_material_mode_name(mode), i,
                  fd, g);
    }
    // positions: the trilinear weights are smooth inside a cell (a kink only on cell faces)
    for (int q = 0; q < 12; q++) {
        int i = (q * 37) % (3 * n);
        double keep = pos[i];
        pos[i] = keep + h;
        double Lp = loss_f64(&net, pos, w, n, k);
        pos[i] = keep - h;
        double Lm = loss_f64(&net, pos, w, n, k);
        pos[i] = keep;
        double fd = (Lp - Lm) / (2 * h);
        CHECK_MSG(fabs(fd - dpos[i]) <= 1e-5 + 1e-5 * fabs(fd), "%s pos %d: fd %.10g, backward %.10g", mlb_material_mode_name(mode), i,
                  fd, dpos[i]);
    }
    printf("  %s: worst relative parameter error %.2e\n", mlb_material_mode_name(mode), worst);
    material_net_free_f64(&net);
    brdf_ae_free(&prior);
}

TEST(fd_latent_f64) { fd_check(MLB_MATERIAL_LATENT); }
TEST(fd_direct_f64) { fd_check(MLB_MATERIAL_DIRECT); }

TEST(decoder_frozen_and_output_map) {
    mlb_brdf_ae prior;
    char source[1024];
    int builtin = mlb_brdf_ae_load_default(&prior, source, sizeof source) == MLB_OK;
    if (!builtin) REQUIRE(random_prior(&prior));
    mlb_material_config c = small_config(MLB_MATERIAL_LATENT);
    mlb_material_net net;
    REQUIRE(material_net_init(&net, &c, &prior) == MLB_OK);
    size_t nd = prior.n_params - prior.n_enc_params;
    CHECK(memcmp(net.dec_params, prior.params + prior.n_enc_params, sizeof(float) * nd) == 0);
    enum { n = 64 };
    float pos[3 * n], k[7 * n], z[4 * n], k2[7 * n], dk[7 * n];
    for (int i = 0; i < 3 * n; i++) pos[i] = (mlb_rng_uniform(12, 0, i) - 0.5f) * 2.0f;
    for (int i = 0; i < 7 * n; i++) dk[i] = mlb_rng_normal(12, 1, i);
    REQUIRE(material_net_forward(&net, k, z, pos, n) == MLB_OK);
    // the decoder inside the net is the prior's decoder with the prior's output map
    REQUIRE(brdf_ae_decode(&prior, z, n, k2) == MLB_OK);
    CHECK(memcmp(k, k2, sizeof k) == 0);
    REQUIRE(mlb_material_decode(&net, z, n, k2) == MLB_OK);
    CHECK(memcmp(k, k2, sizeof k) == 0);
    for (int i = 0; i < n; i++) CHECK(mlb_brdf_valid(k + 7 * i));
    // eval (no cache) agrees with forward
    float ke[7 * n], ze[4 * n];
    REQUIRE(mlb_material_eval(&net, pos, n, ke) == MLB_OK);
    REQUIRE(mlb_material_eval_latent(&net, pos, n, ze) == MLB_OK);
    for (int i = 0; i < 7 * n; i++) CHECK_CLOSE(ke[i], k[i], 1e-6, 1e-7);
    for (int i = 0; i < 4 * n; i++) CHECK_CLOSE(ze[i], z[i], 1e-6, 1e-7);
    // Adam moves the trained parameters and never the decoder
    float* before = malloc(sizeof(float) * net.n_params);
    memcpy(before, net.params, sizeof(float) * net.n_params);
    mlb_adam_config adam = mlb_material_adam(1e-2);
    CHECK(adam.beta1 == 0.9 && adam.beta2 == 0.99 && adam.eps == 1e-15 && adam.weight_decay == 0);
    for (int it = 0; it < 3; it++) {
        REQUIRE(material_net_forward(&net, k, NULL, pos, n) == MLB_OK);
        material_net_zero_grad(&net);
        material_net_backward(&net, dk, NULL);
        material_net_update(&net, &adam);
    }
    CHECK(net.step == 3);
    CHECK(memcmp(net.dec_params, prior.params + prior.n_enc_params, sizeof(float) * nd) == 0);
    size_t moved_enc = 0, moved_mlp = 0;
    for (size_t i = 0; i < net.n_params; i++)
        if (net.params[i] != before[i]) { if (i < net.n_enc) moved_enc++; else moved_mlp++; }
    CHECK(moved_enc > 0 && moved_mlp == net.n_mlp);
    free(before);
    material_net_free(&net);
    brdf_ae_free(&prior);
}

TEST(config_and_errors) {
    mlb_material_config c = mlb_material_default();
    CHECK(c.hidden == 32 && c.n_hidden == 2 && c.mode == MLB_MATERIAL_LATENT && fabsf(c.scale - 2.1f) < 1e-6f);
    CHECK(c.enc.n_levels == 16 && c.enc.n_features == 2 && c.enc.table_size == (1u << 19) && c.enc.base_res == 16);
    mlb_material_mode m;
    CHECK(mlb_material_mode_parse("direct", &m) == MLB_OK && m == MLB_MATERIAL_DIRECT);
    CHECK(mlb_material_mode_parse("latent", &m) == MLB_OK && m == MLB_MATERIAL_LATENT);
    CHECK(mlb_material_mode_parse("Latent", &m) == MLB_ERR_ARG && strstr(mlb_last_error(), "Latent"));
    CHECK(!strcmp(mlb_material_mode_name(MLB_MATERIAL_DIRECT), "direct"));
    mlb_material_net net;
    c = small_config(MLB_MATERIAL_LATENT);
    CHECK(material_net_init(&net, &c, NULL) == MLB_ERR_ARG && strstr(mlb_last_error(), "prior"));
    c.mode = MLB_MATERIAL_DIRECT;
    REQUIRE(material_net_init(&net, &c, NULL) == MLB_OK);
    CHECK(net.dec_params == NULL && net.mlp.dims[net.mlp.n_layers] == 7);
    float z[4];
    CHECK(mlb_material_eval_latent(&net, (float[3]){0, 0, 0}, 1, z) == MLB_ERR_ARG);
    CHECK(material_net_forward(&net, NULL, NULL, (float[3]){0, 0, 0}, 0) == MLB_ERR_ARG);
    // the direct mode's initial material: sigmoid(bias 0 + tiny table) ≈ the middle of the ranges
    float k[7];
    REQUIRE(mlb_material_eval(&net, (float[3]){0.1f, 0.2f, 0.3f}, 1, k) == MLB_OK);
    CHECK(mlb_brdf_valid(k));
    material_net_free(&net);
    material_net_free(&net);   // safe twice
}

// Writes a copy of the net's file with tensor `drop` left out, or `reshape` given a wrong shape.
static int write_variant(const char* src, const char* dst, const char* drop, const char* reshape, const char* meta_key,
                         const char* meta_value) {
    mlb_safetensors* st;
    if (mlb_st_open(&st, src)) return 0;
    size_t n = mlb_st_count(st), ne = 0, nm = mlb_st_metadata_count(st);
    mlb_st_entry* e = calloc(n, sizeof *e);
    int64_t(*shapes)[MLB_ST_MAX_DIMS] = calloc(n, sizeof *shapes);
    mlb_st_meta* meta = calloc(nm, sizeof *meta);
    for (size_t i = 0; i < n; i++) {
        const mlb_st_tensor* t = mlb_st_tensor_at(st, i);
        if (drop && !strcmp(t->name, drop)) continue;
        memcpy(shapes[ne], t->shape, sizeof shapes[ne]);
        int ndim = t->ndim;
        if (reshape && !strcmp(t->name, reshape)) {   // same bytes, transposed shape (or split)
            if (ndim == 2 && shapes[ne][0] != shapes[ne][1]) { int64_t a = shapes[ne][0]; shapes[ne][0] = shapes[ne][1]; shapes[ne][1] = a; }
            else { ndim = 2; shapes[ne][0] = 1; shapes[ne][1] = (int64_t)t->nelem; }
        }
        e[ne] = (mlb_st_entry){t->name, t->dtype, ndim, shapes[ne], t->data};
        ne++;
    }
    for (size_t i = 0; i < nm; i++) {
        mlb_st_metadata_at(st, i, &meta[i].key, &meta[i].value);
        if (meta_key && !strcmp(meta[i].key, meta_key)) meta[i].value = meta_value;
    }
    int ok = mlb_st_write(dst, e, ne, meta, nm) == MLB_OK;
    mlb_st_close(st);
    free(e); free(shapes); free(meta);
    return ok;
}

TEST(save_load) {
    const char* dir = test_tmpdir("material_net");
    REQUIRE(dir);
    mlb_brdf_ae prior;
    REQUIRE(random_prior(&prior));
    char path[4200], bad[4200];
    snprintf(path, sizeof path, "%s/mat.safetensors", dir);
    snprintf(bad, sizeof bad, "%s/bad.safetensors", dir);
    for (int mode = 0; mode < 2; mode++) {
        mlb_material_config c = small_config((mlb_material_mode)mode);
        c.seed = 0xFFFFFFFFFFFFFFF1ull;   // a full 64-bit seed survives
        mlb_material_net net, back;
        REQUIRE(material_net_init(&net, &c, &prior) == MLB_OK);
        enum { n = 32 };
        float pos[3 * n], k[7 * n], dk[7 * n], k2[7 * n];
        for (int i = 0; i < 3 * n; i++) pos[i] = mlb_rng_uniform(4, 0, i) - 0.5f;
        for (int i = 0; i < 7 * n; i++) dk[i] = mlb_rng_normal(4, 1, i);
        mlb_adam_config adam = mlb_material_adam(1e-2);
        for (int it = 0; it < 2; it++) {
            REQUIRE(material_net_forward(&net, k, NULL, pos, n) == MLB_OK);
            material_net_zero_grad(&net);
            material_net_backward(&net, dk, NULL);
            material_net_update(&net, &adam);
        }
        REQUIRE(mlb_material_save(&net, path, 1) == MLB_OK);
        REQUIRE(mlb_material_load(&back, path) == MLB_OK);
        CHECK(back.cfg.mode == c.mode && back.cfg.seed == c.seed && back.cfg.hidden == c.hidden && back.cfg.scale == c.scale &&
              back.cfg.enc.per_level_scale == c.enc.per_level_scale && back.cfg.enc.table_size == c.enc.table_size);
        CHECK(back.n_params == net.n_params && back.step == 2);
        CHECK(memcmp(back.params, net.params, sizeof(float) * net.n_params) == 0);
        CHECK(memcmp(back.adam_m, net.adam_m, sizeof(float) * net.n_params) == 0);
        CHECK(memcmp(back.adam_v, net.adam_v, sizeof(float) * net.n_params) == 0);
        if (mode == MLB_MATERIAL_LATENT) {
            size_t nd = prior.n_params - prior.n_enc_params;
            CHECK(memcmp(back.dec_params, net.dec_params, sizeof(float) * nd) == 0);
            CHECK(back.dec.hidden_act == MLB_ACT_SILU && back.dec.n_layers == 3);
        }
        REQUIRE(material_net_forward(&net, k, NULL, pos, n) == MLB_OK);
        REQUIRE(material_net_forward(&back, k2, NULL, pos, n) == MLB_OK);
        CHECK(memcmp(k, k2, sizeof k) == 0);
        material_net_free(&back);
        // without the optimizer: step 0, zero moments
        REQUIRE(mlb_material_save(&net, path, 0) == MLB_OK);
        REQUIRE(mlb_material_load(&back, path) == MLB_OK);
        CHECK(back.step == 0 && back.adam_m[0] == 0 && memcmp(back.params, net.params, sizeof(float) * net.n_params) == 0);
        material_net_free(&back);
        REQUIRE(mlb_material_save(&net, path, 1) == MLB_OK);
        material_net_free(&net);

        // hostile files: every error names the file and the tensor or key, and leaves the net zeroed
        struct { const char *drop, *reshape, *key, *value, *expect; } cases[] = {
            {"mlp.1.bias", NULL, NULL, NULL, "mlp.1.bias"},
            {"encoding.table", NULL, NULL, NULL, "encoding.table"},
            {NULL, "mlp.0.weight", NULL, NULL, "mlp.0.weight"},
            {NULL, "encoding.table", NULL, NULL, "encoding.table"},
            {"adam.v", NULL, NULL, NULL, "adam.v"},
            {NULL, "adam.m", NULL, NULL, "adam.m"},
            {NULL, NULL, "material.hidden", "9", "mlp.0.weight"},
            {NULL, NULL, "material.levels", "5000", "material.levels"},
            {NULL, NULL, "material.n_hidden", "1.5", "material.n_hidden"},
            {NULL, NULL, "material.mode", "fancy", "material.mode"},
            {NULL, NULL, "material.table_size", "4294967295", "encoding.table"},
            {mode == MLB_MATERIAL_LATENT ? "decoder.2.weight" : NULL, mode == MLB_MATERIAL_LATENT ? NULL : "mlp.2.bias", NULL, NULL,
             mode == MLB_MATERIAL_LATENT ? "decoder.2.weight" : "mlp.2.bias"},
            {NULL, NULL, mode == MLB_MATERIAL_LATENT ? "material.decoder_hidden" : "material.mode",
             mode == MLB_MATERIAL_LATENT ? "4096" : "latent", mode == MLB_MATERIAL_LATENT ? "decoder.0.weight" : "mlp.2.weight"},
        };
        for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
            REQUIRE(write_variant(path, bad, cases[i].drop, cases[i].reshape, cases[i].key, cases[i].value));
            mlb_material_net x;
            mlb_status s = mlb_material_load(&x, bad);
            CHECK_MSG(s != MLB_OK && strstr(mlb_last_error(), "bad.safetensors") && strstr(mlb_last_error(), cases[i].expect),
                      "case %zu (%s): status %d, message '%s'", i, cases[i].expect, (int)s, mlb_last_error());
            CHECK(x.params == NULL && x.n_params == 0);
            if (mode == 0) printf("  %s\n", mlb_last_error());
        }
    }
    // not a safetensors file at all, and a missing file
    FILE* f = fopen(bad, "wb");
    REQUIRE(f);
    fputs("hello", f);
    fclose(f);
    mlb_material_net x;
    CHECK(mlb_material_load(&x, bad) != MLB_OK && strstr(mlb_last_error(), "bad.safetensors"));
    snprintf(bad, sizeof bad, "%s/none.safetensors", dir);
    CHECK(mlb_material_load(&x, bad) == MLB_ERR_IO || strstr(mlb_last_error(), "none.safetensors"));
    brdf_ae_free(&prior);
}

// The device path (src/field/field_device.c: one batch, no shards, written against an op table) run
// with the CPU's table agrees with the host path; test_cuda_material runs it with CUDA's.
TEST(device_twin_on_cpu_table) {
    field_twin_check(mlb_backend_cpu(), MLB_FIELD_MATERIAL, MLB_MATERIAL_LATENT, 3000, 1e-5);
    field_twin_check(mlb_backend_cpu(), MLB_FIELD_MATERIAL, MLB_MATERIAL_DIRECT, 1500, 1e-5);
    field_twin_check(mlb_backend_cpu(), MLB_FIELD_GEOMETRY, MLB_MATERIAL_LATENT, 2500, 1e-5);
}

TEST(use_device_without_gpu) {
    if (mlb_cuda_device_count() > 0) SKIP("a GPU is present: tests/test_cuda_material.c covers it");
    mlb_material_config c = small_config(MLB_MATERIAL_DIRECT);
    mlb_material_net net;
    REQUIRE(material_net_init(&net, &c, NULL) == MLB_OK);
    float pos[3 * 4] = {0.1f, 0.2f, 0.3f, -0.2f, 0.1f, 0.0f, 0.3f, -0.3f, 0.2f, 0, 0, 0}, a[7 * 4], b[7 * 4];
    REQUIRE(mlb_material_eval(&net, pos, 4, a) == MLB_OK);
    CHECK(mlb_field_use_device(&net, mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32)) == MLB_ERR_DEVICE);
    CHECK(net.dev == NULL && mlb_field_backend(&net) == NULL);
    CHECK(material_net_forward(&net, b, NULL, pos, 4) == MLB_OK && !memcmp(a, b, sizeof a));
    CHECK(mlb_field_use_device(&net, NULL) == MLB_ERR_ARG);
    CHECK(mlb_field_sync_host(&net) == MLB_OK && mlb_field_leave_device(&net) == MLB_OK);
    material_net_free(&net);
}

int main(void) {
    RUN(fd_latent_f64);
    RUN(fd_direct_f64);
    RUN(decoder_frozen_and_output_map);
    RUN(config_and_errors);
    RUN(save_load);
    RUN(device_twin_on_cpu_table);
    RUN(use_device_without_gpu);
    return test_summary();
}
