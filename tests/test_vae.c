// The SD VAE (vae.h): the tiny fixture VAE in the diffusers layout and inside the SD1/SD2 single
// files gives identical weights and outputs; encoder mean/logvar, decoder output and the encoder's
// input gradient against ref_vae.safetensors (README tolerance 1e-4 absolute); F16 weights and
// BF16 weights (rounded and written here) against ref_sd1_halfweights; the tensor names against
// name_map.json; a tiny random VAE written with mlb_st_write in both layouts, its encoder backward
// by finite differences in double; batching, thread-count independence; error messages.
#include <cjson/cJSON.h>
#include <stdint.h>
#include "matlaber/error.h"
#include "matlaber/fileio.h"
#include "matlaber/half.h"
#include "matlaber/safetensors.h"
#include "matlaber/threads.h"
#include "matlaber/vae.h"
#include "matlaber/device.h"
#include "matlaber/rng.h"
#include "test.h"

#define TOL 1e-4   // README: "VAE mean/logvar/decoded/grad_image ... to about 1e-4 absolute"

static char path_buf[8][1200];
static const char* data_path(int slot, const char* rel) {
    const char* d = test_shared_data();
    if (!d) return NULL;
    snprintf(path_buf[slot], sizeof path_buf[slot], "%s/sd_reference/%s", d, rel);
    struct stat s;
    return stat(path_buf[slot], &s) == 0 ? path_buf[slot] : NULL;
}

// A reference tensor as float (malloc'd); NULL (and a failed check) when missing.
static float* ref_tensor(const mlb_safetensors* st, const char* name, size_t* n) {
    const mlb_st_tensor* t = mlb_st_find(st, name);
    if (!t) return NULL;
    float* out = malloc(t->nelem * sizeof(float));
    if (mlb_st_read_f32(st, name, out, t->nelem) != MLB_OK) { free(out); return NULL; }
    if (n) *n = t->nelem;
    return out;
}

static double max_abs_diff(const float* a, const float* b, size_t n) {
    double m = 0;
    for (size_t i = 0; i < n; i++) { double d = fabs((double)a[i] - b[i]); if (!(d <= m)) m = d; }
    return m;
}
static double max_abs(const float* a, size_t n) {
    double m = 0;
    for (size_t i = 0; i < n; i++) if (fabs(a[i]) > m) m = fabs(a[i]);
    return m;
}

static mlb_vae* load_or_null(const char* path) {
    mlb_vae* v = NULL;
    if (mlb_vae_load(path, NULL, &v) != MLB_OK) { printf("  load %s: %s\n", path, mlb_last_error()); return NULL; }
    return v;
}

// ---- fixtures -------------------------------------------------------------------------------------
TEST(layouts_load_identically) {
    const char* dif = data_path(0, "sd1_diffusers/vae");
    const char* model = data_path(1, "sd1_diffusers");
    const char* sd1 = data_path(2, "sd1_tiny.safetensors");
    const char* sd2 = data_path(3, "sd2_tiny.safetensors");
    if (!dif || !sd1 || !sd2 || !model) SKIP("no ../shared/data/sd_reference");
    mlb_vae *a = load_or_null(dif), *b = load_or_null(sd1), *c = load_or_null(sd2), *d = load_or_null(model);
    REQUIRE(a && b && c && d);
    printf("  %s\n  %s\n", a->source, b->source);
    CHECK(a->cfg.n_levels == 4 && a->cfg.block_out[0] == 32 && a->cfg.block_out[2] == 64 && a->cfg.layers_per_block == 2);
    CHECK(a->cfg.latent_channels == 4 && a->cfg.norm_groups == 32 && fabsf(a->cfg.scaling_factor - 0.18215f) < 1e-7f);
    CHECK(b->cfg.scaling_factor == a->cfg.scaling_factor && a->cfg.mid_attention && b->cfg.mid_attention);
    CHECK(a->n_params == 1399879 && b->n_params == a->n_params && c->n_params == a->n_params);
    CHECK(memcmp(a->params, b->params, a->n_params * sizeof(float)) == 0);
    CHECK(memcmp(a->params, c->params, a->n_params * sizeof(float)) == 0);
    CHECK(memcmp(a->params, d->params, a->n_params * sizeof(float)) == 0);
    // identical outputs (the same weights through the same code)
    float img[3 * 64 * 64], ma[4 * 64], mb[4 * 64];
    for (int i = 0; i < 3 * 64 * 64; i++) img[i] = (float)sin(0.37 * i);
    REQUIRE(mlb_vae_encode(NULL, a, img, 1, 64, 64, ma, NULL, NULL) == MLB_OK);
    REQUIRE(mlb_vae_encode(NULL, b, img, 1, 64, 64, mb, NULL, NULL) == MLB_OK);
    CHECK(memcmp(ma, mb, sizeof ma) == 0);
    mlb_vae_free(a); mlb_vae_free(b); mlb_vae_free(c); mlb_vae_free(d);
}

TEST(names_match_name_map) {
    const char* nm_path = data_path(0, "name_map.json");
    const char* dif = data_path(1, "sd1_diffusers/vae");
    if (!nm_path || !dif) SKIP("no ../shared/data/sd_reference");
    char* text = NULL;
    size_t n = 0;
    REQUIRE(mlb_read_file(nm_path, &text, &n, 1 << 24) == MLB_OK);
    cJSON* root = cJSON_ParseWithLength(text, n);
    free(text);
    REQUIRE(root);
    const cJSON* map = cJSON_GetObjectItemCaseSensitive(root, "vae");
    mlb_vae* v = load_or_null(dif);
    REQUIRE(v && map);
    size_t count = mlb_vae_tensor_count(v);
    CHECK(count == (size_t)cJSON_GetArraySize(map));
    int bad = 0;
    for (size_t i = 0; i < count; i++) {
        mlb_vae_tensor td, tl;
        REQUIRE(mlb_vae_tensor_at(v, i, MLB_VAE_LAYOUT_DIFFUSERS, &td) == MLB_OK);
        REQUIRE(mlb_vae_tensor_at(v, i, MLB_VAE_LAYOUT_LDM, &tl) == MLB_OK);
        const cJSON* want = cJSON_GetObjectItemCaseSensitive(map, td.name);
        char full[200];
        snprintf(full, sizeof full, "first_stage_model.%s", tl.name);
        if (!cJSON_IsString(want) || strcmp(want->valuestring, full) != 0) {
            if (bad++ < 5) printf("  %s -> %s, name_map says %s\n", td.name, full, cJSON_IsString(want) ? want->valuestring : "(absent)");
        }
    }
    CHECK(bad == 0);
    mlb_vae_tensor t;
    CHECK(mlb_vae_tensor_at(v, count, MLB_VAE_LAYOUT_LDM, &t) == MLB_ERR_ARG);
    cJSON_Delete(root);
    mlb_vae_free(v);
}

TEST(encoder_decoder_match_reference) {
    const char* dif = data_path(0, "sd1_diffusers/vae");
    const char* refp = data_path(1, "ref_vae.safetensors");
    if (!dif || !refp) SKIP("no ../shared/data/sd_reference");
    mlb_vae* v = load_or_null(dif);
    mlb_safetensors* ref = NULL;
    REQUIRE(v && mlb_st_open(&ref, refp) == MLB_OK);
    size_t ni, nz, nd, ndn, nzn;
    float *image = ref_tensor(ref, "image", &ni), *mean_ref = ref_tensor(ref, "mean", &nz);
    float *logvar_ref = ref_tensor(ref, "logvar", NULL), *grad_ref = ref_tensor(ref, "grad_image", NULL);
    float *G = ref_tensor(ref, "grad_upstream", NULL), *latent = ref_tensor(ref, "latent", NULL);
    float *dec_ref = ref_tensor(ref, "decoded", &nd), *latent_ns = ref_tensor(ref, "latent_nonsquare", &nzn);
    float* dec_ns_ref = ref_tensor(ref, "decoded_nonsquare", &ndn);
    REQUIRE(image && mean_ref && logvar_ref && grad_ref && G && latent && dec_ref && latent_ns && dec_ns_ref);
    REQUIRE(ni == 3 * 64 * 64 && nz == 4 * 8 * 8 && nd == ni && nzn == 4 * 8 * 12 && ndn == 3 * 64 * 96);
    float mean[256], logvar[256], *dimage = calloc(ni, sizeof(float)), *dec = malloc(ndn * sizeof(float));
    mlb_vae_cache cache = {0};
    REQUIRE(mlb_vae_encode(NULL, v, image, 1, 64, 64, mean, logvar, &cache) == MLB_OK);
    REQUIRE(mlb_vae_encode_backward(NULL, v, &cache, G, NULL, dimage, NULL) == MLB_OK);
    double em = max_abs_diff(mean, mean_ref, nz), el = max_abs_diff(logvar, logvar_ref, nz);
    double eg = max_abs_diff(dimage, grad_ref, ni);
    printf("  encoder mean: max abs %.3g (|ref| max %.3g); logvar: %.3g (%.3g)\n", em, max_abs(mean_ref, nz), el,
           max_abs(logvar_ref, nz));
    printf("  encoder input gradient: max abs %.3g (|ref| max %.3g)\n", eg, max_abs(grad_ref, ni));
    CHECK(em < TOL && el < TOL && eg < TOL);
    // a second backward from the same cache adds the same gradient again (accumulation)
    REQUIRE(mlb_vae_encode_backward(NULL, v, &cache, G, NULL, dimage, NULL) == MLB_OK);
    double e2 = 0;
    for (size_t i = 0; i < ni; i++) e2 = fmax(e2, fabs(dimage[i] - 2 * grad_ref[i]));
    CHECK(e2 < 2 * TOL);
    REQUIRE(mlb_vae_decode(NULL, v, latent, 1, 8, 8, dec, NULL) == MLB_OK);
    double ed = max_abs_diff(dec, dec_ref, nd);
    REQUIRE(mlb_vae_decode(NULL, v, latent_ns, 1, 8, 12, dec, NULL) == MLB_OK);
    double edn = max_abs_diff(dec, dec_ns_ref, ndn);
    printf("  decoder: max abs %.3g (|ref| max %.3g); non-square 8x12: %.3g (%.3g)\n", ed, max_abs(dec_ref, nd), edn,
           max_abs(dec_ns_ref, ndn));
    CHECK(ed < TOL && edn < TOL);
    mlb_vae_cache_free(&cache);
    CHECK(cache.buf == NULL && cache.N == 0);
    free(image); free(mean_ref); free(logvar_ref); free(grad_ref); free(G); free(latent); free(dec_ref);
    free(latent_ns); free(dec_ns_ref); free(dimage); free(dec);
    mlb_st_close(ref);
    mlb_vae_free(v);
}

// The double-precision copy agrees with float and with the reference (the reference is float32).
TEST(double_precision_copy) {
    const char* dif = data_path(0, "sd1_diffusers/vae");
    const char* refp = data_path(1, "ref_vae.safetensors");
    if (!dif || !refp) SKIP("no ../shared/data/sd_reference");
    mlb_vae* v = load_or_null(dif);
    mlb_vae_f64* vd = NULL;
    mlb_safetensors* ref = NULL;
    REQUIRE(v && mlb_vae_to_f64(v, &vd) == MLB_OK && mlb_st_open(&ref, refp) == MLB_OK);
    size_t ni;
    float *image = ref_tensor(ref, "image", &ni), *grad_ref = ref_tensor(ref, "grad_image", NULL);
    float *G = ref_tensor(ref, "grad_upstream", NULL), *mean_ref = ref_tensor(ref, "mean", NULL);
    REQUIRE(image && grad_ref && G && mean_ref);
    double* imd = malloc(ni * sizeof(double));
    double* dd = calloc(ni, sizeof(double));
    double md[256], Gd[256];
    for (size_t i = 0; i < ni; i++) imd[i] = image[i];
    for (int i = 0; i < 256; i++) Gd[i] = G[i];
    mlb_vae_cache_f64 cache = {0};
    REQUIRE(mlb_vae_encode_f64(NULL, vd, imd, 1, 64, 64, md, NULL, &cache) == MLB_OK);
    REQUIRE(mlb_vae_encode_backward_f64(NULL, vd, &cache, Gd, NULL, dd, NULL) == MLB_OK);
    double em = 0, eg = 0;
    for (int i = 0; i < 256; i++) em = fmax(em, fabs(md[i] - mean_ref[i]));
    for (size_t i = 0; i < ni; i++) eg = fmax(eg, fabs(dd[i] - grad_ref[i]));
    printf("  double copy vs float32 reference: mean %.3g, input gradient %.3g\n", em, eg);
    CHECK(em < TOL && eg < TOL);
    mlb_vae_cache_free_f64(&cache);
    free(image); free(grad_ref); free(G); free(mean_ref); free(imd); free(dd);
    mlb_st_close(ref);
    mlb_vae_free(v);
    mlb_vae_free_f64(vd);
}

// F16 single file against its reference; BF16: the F32 single file rounded and written here.
TEST(half_precision_weights) {
    const char* f16 = data_path(0, "sd1_tiny.f16.safetensors");
    const char* f32 = data_path(1, "sd1_tiny.safetensors");
    const char* half = data_path(2, "ref_sd1_halfweights.safetensors");
    const char* refp = data_path(3, "ref_vae.safetensors");
    if (!f16 || !f32 || !half || !refp) SKIP("no ../shared/data/sd_reference");
    mlb_safetensors *h = NULL, *ref = NULL, *src = NULL;
    REQUIRE(mlb_st_open(&h, half) == MLB_OK && mlb_st_open(&ref, refp) == MLB_OK && mlb_st_open(&src, f32) == MLB_OK);
    float *latent = ref_tensor(ref, "latent", NULL), *want16 = ref_tensor(h, "f16.vae_decoded", NULL);
    float* want_bf = ref_tensor(h, "bf16.vae_decoded", NULL);
    REQUIRE(latent && want16 && want_bf);
    float* dec = malloc(3 * 64 * 64 * sizeof(float));
    mlb_vae* v = load_or_null(f16);
    REQUIRE(v);
    CHECK(strstr(v->source, "F16 weights") != NULL);
    REQUIRE(mlb_vae_decode(NULL, v, latent, 1, 8, 8, dec, NULL) == MLB_OK);
    double e16 = max_abs_diff(dec, want16, 3 * 64 * 64);
    mlb_vae_free(v);
    // BF16: every first_stage_model tensor rounded to nearest-even BF16
    size_t nt = mlb_st_count(src), k = 0;
    mlb_st_entry* ent = calloc(nt, sizeof *ent);
    uint16_t** bufs = calloc(nt, sizeof *bufs);
    for (size_t i = 0; i < nt; i++) {
        const mlb_st_tensor* t = mlb_st_tensor_at(src, i);
        if (strncmp(t->name, "first_stage_model.", 18) != 0) continue;
        float* f = malloc(t->nelem * sizeof(float));
        REQUIRE(mlb_st_read_f32(src, t->name, f, t->nelem) == MLB_OK);
        bufs[k] = malloc(t->nelem * 2);
        mlb_f32_to_bf16_array(bufs[k], f, t->nelem);
        free(f);
        ent[k] = (mlb_st_entry){t->name, MLB_DT_BF16, t->ndim, t->shape, bufs[k]};
        k++;
    }
    const char* dir = test_tmpdir("vae");
    REQUIRE(dir);
    char bf_path[1300];
    snprintf(bf_path, sizeof bf_path, "%s/vae_bf16.safetensors", dir);
    REQUIRE(mlb_st_write(bf_path, ent, k, NULL, 0) == MLB_OK);
    for (size_t i = 0; i < k; i++) free(bufs[i]);
    free(bufs); free(ent);
    v = load_or_null(bf_path);
    REQUIRE(v);
    CHECK(strstr(v->source, "BF16 weights") != NULL);
    REQUIRE(mlb_vae_decode(NULL, v, latent, 1, 8, 8, dec, NULL) == MLB_OK);
    double ebf = max_abs_diff(dec, want_bf, 3 * 64 * 64);
    printf("  decoder with F16 weights: max abs %.3g vs f16.vae_decoded; BF16 (%zu tensors rounded here): %.3g vs "
           "bf16.vae_decoded\n", e16, k, ebf);
    CHECK(k == 244);
    CHECK(e16 < TOL && ebf < TOL);
    mlb_vae_free(v);
    free(latent); free(want16); free(want_bf); free(dec);
    mlb_st_close(h); mlb_st_close(ref); mlb_st_close(src);
}

// ---- a tiny random VAE (no shared data needed) ------------------------------------------------------
static mlb_vae_config tiny_config(void) {
    mlb_vae_config c = mlb_vae_sd_config();
    c.n_levels = 2;
    c.block_out[0] = 8;
    c.block_out[1] = 16;
    c.layers_per_block = 1;
    c.norm_groups = 4;
    c.latent_channels = 2;
    return c;
}

static mlb_vae* tiny_vae(void) {
    mlb_vae_config c = tiny_config();
    mlb_vae* v = NULL;
    if (mlb_vae_create(NULL, &c, &v) != MLB_OK) return NULL;
    mlb_vae_init_random(v, 7, 1.0f);
    return v;
}

TEST(tiny_save_and_reload_both_layouts) {
    mlb_vae* v = tiny_vae();
    REQUIRE(v);
    const char* dir = test_tmpdir("vae_tiny");
    REQUIRE(dir);
    char folder[1300], w[1400], cfg[1400], single[1300];
    snprintf(folder, sizeof folder, "%s/model/vae", dir);
    REQUIRE(mlb_mkdir_p(folder) == MLB_OK);
    snprintf(w, sizeof w, "%s/diffusion_pytorch_model.safetensors", folder);
    snprintf(cfg, sizeof cfg, "%s/config.json", folder);
    snprintf(single, sizeof single, "%s/single.safetensors", dir);
    REQUIRE(mlb_vae_save(v, w, MLB_VAE_LAYOUT_DIFFUSERS, NULL, cfg) == MLB_OK);
    REQUIRE(mlb_vae_save(v, single, MLB_VAE_LAYOUT_LDM, "first_stage_model.", NULL) == MLB_OK);
    char model[1300];
    snprintf(model, sizeof model, "%s/model", dir);
    mlb_vae *a = load_or_null(model), *b = NULL;
    mlb_vae_options opt = {NULL, 4};   // ldm files do not record the groups
    REQUIRE(a && mlb_vae_load(single, &opt, &b) == MLB_OK);
    CHECK(a->cfg.norm_groups == 4 && a->cfg.n_levels == 2 && a->cfg.block_out[1] == 16 && a->cfg.latent_channels == 2);
    CHECK(a->n_params == v->n_params && b->n_params == v->n_params);
    CHECK(memcmp(a->params, v->params, v->n_params * sizeof(float)) == 0);
    CHECK(memcmp(b->params, v->params, v->n_params * sizeof(float)) == 0);
    mlb_vae_free(a); mlb_vae_free(b); mlb_vae_free(v);
}

// L = sum(mean * Gm) + sum(logvar * Gl); d L / d image by central differences in double.
TEST(tiny_encoder_backward_fd) {
    mlb_vae* v = tiny_vae();
    mlb_vae_f64* vd = NULL;
    REQUIRE(v && mlb_vae_to_f64(v, &vd) == MLB_OK);
    enum { N = 2, H = 8, W = 6, NI = N * 3 * H * W, NZ = N * 2 * 4 * 3 };
    double img[NI], Gm[NZ], Gl[NZ], m[NZ], l[NZ], dimg[NI];
    for (int i = 0; i < NI; i++) img[i] = sin(1.7 * i + 0.3);
    for (int i = 0; i < NZ; i++) { Gm[i] = cos(0.9 * i); Gl[i] = sin(2.1 * i + 1); }
    mlb_vae_cache_f64 cache = {0};
    REQUIRE(mlb_vae_encode_f64(NULL, vd, img, N, H, W, m, l, &cache) == MLB_OK);
    for (int i = 0; i < NI; i++) dimg[i] = 0.5;
    REQUIRE(mlb_vae_encode_backward_f64(NULL, vd, &cache, Gm, Gl, dimg, NULL) == MLB_OK);
    const double h = 1e-6;
    double err = 0, gmax = 0;
    for (int i = 0; i < NI; i++) {
        double keep = img[i], lp = 0, lm = 0;
        img[i] = keep + h;
        REQUIRE(mlb_vae_encode_f64(NULL, vd, img, N, H, W, m, l, NULL) == MLB_OK);
        for (int j = 0; j < NZ; j++) lp += m[j] * Gm[j] + l[j] * Gl[j];
        img[i] = keep - h;
        REQUIRE(mlb_vae_encode_f64(NULL, vd, img, N, H, W, m, l, NULL) == MLB_OK);
        for (int j = 0; j < NZ; j++) lm += m[j] * Gm[j] + l[j] * Gl[j];
        img[i] = keep;
        double fd = (lp - lm) / (2 * h);
        err = fmax(err, fabs(fd - (dimg[i] - 0.5)) / (1 + fabs(fd)));
        gmax = fmax(gmax, fabs(fd));
    }
    printf("  tiny VAE (8/16 channels, 4 groups, batch 2, 8x6 images): encoder backward vs FD over all %d inputs: "
           "max rel %.3g (|grad| max %.3g)\n", NI, err, gmax);
    CHECK(err < 1e-6);
    // float agrees with double; the batch equals its images one by one
    float imf[NI], mf[NZ], mf1[NZ / 2], df[NI] = {0};
    for (int i = 0; i < NI; i++) imf[i] = (float)img[i];
    float Gmf[NZ], Glf[NZ];
    for (int i = 0; i < NZ; i++) { Gmf[i] = (float)Gm[i]; Glf[i] = (float)Gl[i]; }
    mlb_vae_cache cf = {0};
    REQUIRE(mlb_vae_encode(NULL, v, imf, N, H, W, mf, NULL, &cf) == MLB_OK);
    REQUIRE(mlb_vae_encode_backward(NULL, v, &cf, Gmf, Glf, df, NULL) == MLB_OK);
    REQUIRE(mlb_vae_encode_f64(NULL, vd, img, N, H, W, m, l, NULL) == MLB_OK);
    double ef = 0, egf = 0;
    for (int i = 0; i < NZ; i++) ef = fmax(ef, fabs(mf[i] - m[i]));
    for (int i = 0; i < NI; i++) egf = fmax(egf, fabs(df[i] - (dimg[i] - 0.5)));
    REQUIRE(mlb_vae_encode(NULL, v, imf + NI / 2, 1, H, W, mf1, NULL, NULL) == MLB_OK);
    CHECK(memcmp(mf1, mf + NZ / 2, sizeof mf1) == 0);
    printf("  float vs double: mean %.3g, input gradient %.3g\n", ef, egf);
    CHECK(ef < 1e-5 && egf < 1e-4);
    mlb_vae_cache_free(&cf);
    mlb_vae_cache_free_f64(&cache);
    mlb_vae_free(v);
    mlb_vae_free_f64(vd);
}

TEST(tiny_decoder_and_threads) {
    mlb_vae* v = tiny_vae();
    REQUIRE(v);
    float z[2 * 2 * 3 * 5], a[2 * 3 * 6 * 10], b[2 * 3 * 6 * 10], img[3 * 16 * 16], m1[2 * 64], m2[2 * 64];
    for (int i = 0; i < 60; i++) z[i] = (float)cos(0.7 * i);
    for (int i = 0; i < 3 * 256; i++) img[i] = (float)sin(0.3 * i);
    int threads = mlb_get_threads();
    mlb_set_threads(1);
    REQUIRE(mlb_vae_decode(NULL, v, z, 2, 3, 5, a, NULL) == MLB_OK);
    REQUIRE(mlb_vae_encode(NULL, v, img, 1, 16, 16, m1, NULL, NULL) == MLB_OK);
    mlb_set_threads(2);
    REQUIRE(mlb_vae_decode(NULL, v, z, 2, 3, 5, b, NULL) == MLB_OK);
    REQUIRE(mlb_vae_encode(NULL, v, img, 1, 16, 16, m2, NULL, NULL) == MLB_OK);
    mlb_set_threads(threads);
    CHECK(memcmp(a, b, sizeof a) == 0 && memcmp(m1, m2, sizeof m1) == 0);
    mlb_vae_f64* vd = NULL;
    REQUIRE(mlb_vae_to_f64(v, &vd) == MLB_OK);
    double zd[60], ad[360];
    for (int i = 0; i < 60; i++) zd[i] = z[i];
    REQUIRE(mlb_vae_decode_f64(NULL, vd, zd, 2, 3, 5, ad, NULL) == MLB_OK);
    double e = 0;
    for (int i = 0; i < 360; i++) e = fmax(e, fabs(a[i] - ad[i]));
    printf("  tiny decoder float vs double: %.3g\n", e);
    CHECK(e < 1e-5);
    CHECK(mlb_vae_cache_size(&v->cfg, 1, 16, 16) > 0 && mlb_vae_latent_size(&v->cfg, 17) == 8);
    mlb_vae_free(v);
    mlb_vae_free_f64(vd);
}

// logvar is clamped to [-30, 20] and its gradient stops where the clamp holds; a cache filled by a
// larger forward serves a smaller one.
TEST(tiny_logvar_clamp_and_cache_reuse) {
    mlb_vae* v = tiny_vae();
    REQUIRE(v);
    const int z = v->cfg.latent_channels;
    v->quant_b[z] = 60;        // logvar channel 0: far above 20
    v->quant_b[z + 1] = -90;   // channel 1: far below -30
    float big[3 * 16 * 16], img[3 * 8 * 8], m[2 * 8 * 8], l[2 * 16], G[2 * 16], d1[3 * 64] = {0}, d2[3 * 64] = {0};
    for (int i = 0; i < 3 * 256; i++) big[i] = (float)sin(0.1 * i);
    for (int i = 0; i < 3 * 64; i++) img[i] = (float)cos(0.2 * i);
    for (int i = 0; i < 2 * 16; i++) G[i] = 1;
    mlb_vae_cache c = {0};
    REQUIRE(mlb_vae_encode(NULL, v, big, 1, 16, 16, m, NULL, &c) == MLB_OK);   // latent 8x8
    size_t cap = c.capacity;
    REQUIRE(mlb_vae_encode(NULL, v, img, 1, 8, 8, m, l, &c) == MLB_OK);
    CHECK(c.capacity == cap && c.H == 8 && c.W == 8);
    int clamped = 1;
    for (int i = 0; i < 16; i++) clamped &= l[i] == 20.0f && l[16 + i] == -30.0f;
    CHECK(clamped);
    REQUIRE(mlb_vae_encode_backward(NULL, v, &c, G, G, d1, NULL) == MLB_OK);   // the logvar gradient is stopped
    REQUIRE(mlb_vae_encode_backward(NULL, v, &c, G, NULL, d2, NULL) == MLB_OK);
    CHECK(memcmp(d1, d2, sizeof d1) == 0);
    mlb_vae_cache_free(&c);
    mlb_vae_free(v);
}

// ---- errors ----------------------------------------------------------------------------------------
// Writes `v` in `layout` with tensor `drop` left out and tensor `reshape` given a wrong last dim.
static mlb_status write_altered(const mlb_vae* v, const char* path, mlb_vae_layout layout, const char* prefix,
                                const char* drop, const char* reshape) {
    size_t n = mlb_vae_tensor_count(v), k = 0;
    mlb_vae_tensor* t = calloc(n, sizeof *t);
    mlb_st_entry* e = calloc(n, sizeof *e);
    char (*names)[200] = calloc(n, sizeof *names);
    for (size_t i = 0; i < n; i++) {
        mlb_vae_tensor_at(v, i, layout, &t[i]);
        if (drop && !strcmp(t[i].name, drop)) continue;
        if (reshape && !strcmp(t[i].name, reshape)) t[i].shape[t[i].ndim - 1] -= 2;
        snprintf(names[k], sizeof names[k], "%s%s", prefix, t[i].name);
        e[k] = (mlb_st_entry){names[k], MLB_DT_F32, t[i].ndim, t[i].shape, t[i].data};
        k++;
    }
    mlb_status s = mlb_st_write(path, e, k, NULL, 0);
    free(t); free(e); free(names);
    return s;
}

TEST(error_messages) {
    mlb_vae* v = tiny_vae();
    REQUIRE(v);
    const char* dir = test_tmpdir("vae_err");
    REQUIRE(dir);
    char p[1300], cfg[1300], want[2000];
    mlb_vae* out = NULL;
    mlb_vae_options opt = {NULL, 4};
    // a missing tensor, diffusers layout
    snprintf(p, sizeof p, "%s/missing.safetensors", dir);
    REQUIRE(write_altered(v, p, MLB_VAE_LAYOUT_DIFFUSERS, "", "encoder.mid_block.attentions.0.to_k.bias", NULL) == MLB_OK);
    CHECK(mlb_vae_load(p, &opt, &out) == MLB_ERR_NOT_FOUND && out == NULL);
    snprintf(want, sizeof want, "%s: no tensor named 'encoder.mid_block.attentions.0.to_k.bias'", p);
    CHECK_MSG(!strcmp(mlb_last_error(), want), "%s", mlb_last_error());
    // a mis-shaped tensor, single file
    snprintf(p, sizeof p, "%s/shape.safetensors", dir);
    REQUIRE(write_altered(v, p, MLB_VAE_LAYOUT_LDM, "first_stage_model.", NULL, "decoder.up.0.block.1.conv2.weight") == MLB_OK);
    CHECK(mlb_vae_load(p, &opt, &out) == MLB_ERR_FORMAT);
    snprintf(want, sizeof want, "%s: tensor 'first_stage_model.decoder.up.0.block.1.conv2.weight' has shape "
             "[8, 8, 3, 1], expected [8, 8, 3, 3]", p);
    CHECK_MSG(!strcmp(mlb_last_error(), want), "%s", mlb_last_error());
    // an attention matrix of the wrong size names both accepted shapes
    snprintf(p, sizeof p, "%s/attn.safetensors", dir);
    REQUIRE(write_altered(v, p, MLB_VAE_LAYOUT_DIFFUSERS, "", NULL, "decoder.mid_block.attentions.0.to_out.0.weight") == MLB_OK);
    CHECK(mlb_vae_load(p, &opt, &out) == MLB_ERR_FORMAT);
    snprintf(want, sizeof want, "%s: tensor 'decoder.mid_block.attentions.0.to_out.0.weight' has shape [16, 14], "
             "expected [16, 16] or [16, 16, 1, 1]", p);
    CHECK_MSG(!strcmp(mlb_last_error(), want), "%s", mlb_last_error());
    // a config.json that disagrees with the weights
    snprintf(p, sizeof p, "%s/vae.safetensors", dir);
    snprintf(cfg, sizeof cfg, "%s/vae.config.json", dir);
    REQUIRE(mlb_vae_save(v, p, MLB_VAE_LAYOUT_DIFFUSERS, NULL, NULL) == MLB_OK);
    const char* text = "{\"_class_name\": \"AutoencoderKL\", \"latent_channels\": 4, \"norm_num_groups\": 4}";
    REQUIRE(mlb_write_file_atomic(cfg, text, strlen(text)) == MLB_OK);
    CHECK(mlb_vae_load(p, NULL, &out) == MLB_ERR_FORMAT);
    snprintf(want, sizeof want, "%s: latent_channels is 4 but the weights in %s have 2", cfg, p);
    CHECK_MSG(!strcmp(mlb_last_error(), want), "%s", mlb_last_error());
    text = "{\"_class_name\": \"UNet2DConditionModel\"}";
    REQUIRE(mlb_write_file_atomic(cfg, text, strlen(text)) == MLB_OK);
    CHECK(mlb_vae_load(p, NULL, &out) == MLB_ERR_UNSUPPORTED);
    snprintf(want, sizeof want, "%s: _class_name 'UNet2DConditionModel' is not an AutoencoderKL", cfg);
    CHECK_MSG(!strcmp(mlb_last_error(), want), "%s", mlb_last_error());
    remove(cfg);
    // groups: 32 by default, which 8 channels cannot hold
    CHECK(mlb_vae_load(p, NULL, &out) == MLB_ERR_ARG);
    snprintf(want, sizeof want, "%s: VAE config: block_out[0] = 8 is not a multiple of the 32 groups", p);
    CHECK_MSG(!strcmp(mlb_last_error(), want), "%s", mlb_last_error());
    // not a VAE; pickles; missing paths
    snprintf(p, sizeof p, "%s/other.safetensors", dir);
    float x = 1;
    int64_t one = 1;
    mlb_st_entry e = {"text_model.embeddings.token_embedding.weight", MLB_DT_F32, 1, &one, &x};
    REQUIRE(mlb_st_write(p, &e, 1, NULL, 0) == MLB_OK);
    CHECK(mlb_vae_load(p, NULL, &out) == MLB_ERR_NOT_FOUND);
    snprintf(want, sizeof want, "%s: no VAE found: expected the tensors first_stage_model.encoder.* (single file), "
             "encoder.down_blocks.* (diffusers vae) or encoder.down.* (ldm VAE file)", p);
    CHECK_MSG(!strcmp(mlb_last_error(), want), "%s", mlb_last_error());
    CHECK(mlb_vae_load("/nonexistent/vae.ckpt", NULL, &out) == MLB_ERR_NOT_FOUND);
    snprintf(p, sizeof p, "%s/model.ckpt", dir);
    REQUIRE(mlb_write_file_atomic(p, "x", 1) == MLB_OK);
    CHECK(mlb_vae_load(p, NULL, &out) == MLB_ERR_UNSUPPORTED);
    CHECK(strstr(mlb_last_error(), "pickle checkpoints run code when loaded") != NULL);
    CHECK(mlb_vae_load(dir, NULL, &out) == MLB_ERR_NOT_FOUND);
    // forward/backward misuse
    float img[3 * 4 * 4] = {0}, m[8], d[48];
    CHECK(mlb_vae_encode(NULL, v, img, 1, 1, 4, m, NULL, NULL) == MLB_ERR_ARG);
    CHECK(!strcmp(mlb_last_error(), "VAE encoder: image [1, 3, 1, 4] is too small: height and width must be at least 2"));
    mlb_vae_cache c = {0};
    CHECK(mlb_vae_encode_backward(NULL, v, &c, m, NULL, d, NULL) == MLB_ERR_ARG);
    CHECK(!strcmp(mlb_last_error(), "VAE encoder backward: the cache holds no forward (run mlb_vae_encode with this "
                                    "cache first)"));
    CHECK(mlb_vae_decode(NULL, v, m, 1, 0, 2, d, NULL) == MLB_ERR_ARG);
    CHECK(!strcmp(mlb_last_error(), "VAE decoder: bad latent shape [1, 2, 0, 2]"));
    mlb_vae_config bad = tiny_config();
    bad.block_out[1] = 10;
    mlb_vae* vb = NULL;
    CHECK(mlb_vae_create(NULL, &bad, &vb) == MLB_ERR_ARG && vb == NULL);
    CHECK(!strcmp(mlb_last_error(), "VAE config: block_out[1] = 10 is not a multiple of the 4 groups"));
    mlb_vae_free(v);
}

// mlb_vae_use_device without a GPU: a clear error, and the model stays on the CPU with its bits.
// (With a GPU, tests/test_cuda_vae.c runs the same calls on the device.)
TEST(use_device_without_gpu) {
    if (mlb_cuda_device_count() > 0) SKIP("a GPU is present: tests/test_cuda_vae.c covers it");
    mlb_vae* v = tiny_vae();
    REQUIRE(v);
    const int N = 1, h = 4, w = 6;
    float z[1 * 2 * 4 * 6], a[3 * 8 * 12], b[3 * 8 * 12];
    for (int i = 0; i < N * 2 * h * w; i++) z[i] = (float)mlb_rng_uniform_f64(4, 0, i) * 2 - 1;
    REQUIRE(mlb_vae_decode(NULL, v, z, N, h, w, a, NULL) == MLB_OK);
    CHECK(mlb_vae_use_device(v, MLB_DEVICE_CUDA, MLB_GEMM_FP16) == MLB_ERR_DEVICE);
    CHECK(v->mirror == NULL && v->device == MLB_DEVICE_CPU);
    CHECK(mlb_vae_decode(NULL, v, z, N, h, w, b, NULL) == MLB_OK && !memcmp(a, b, sizeof a));
    CHECK(mlb_vae_use_device(NULL, MLB_DEVICE_CPU, MLB_GEMM_FP32) == MLB_ERR_ARG);
    mlb_vae_free(v);
}

int main(void) {
    RUN(use_device_without_gpu);
    RUN(layouts_load_identically);
    RUN(names_match_name_map);
    RUN(encoder_decoder_match_reference);
    RUN(double_precision_copy);
    RUN(half_precision_weights);
    RUN(tiny_save_and_reload_both_layouts);
    RUN(tiny_encoder_backward_fd);
    RUN(tiny_decoder_and_threads);
    RUN(tiny_logvar_clamp_and_cache_reuse);
    RUN(error_messages);
    return test_summary();
}
