// Score distillation (sds.h) and the whole-model path (sd_model.h): one SDS step with the SD1 tiny
// models against ref_sds_sd1 (its stored image, t and noise; every intermediate tensor and the image
// gradient within the README tolerances), the image gradient's convention (2x - 1, scaling factor,
// 1 / B) by a double-precision finite difference of 0.5 |z(x) - stopgrad(z - grad)|^2 / B through
// the VAE encoder, 4-step DDIM + CFG 7.5 against ref_ddim_sd1 through the sampler `sd txt2img`
// uses, the weights, view selection, RNG determinism and argument errors.
#include <stdint.h>
#include "matlaber/error.h"
#include "matlaber/safetensors.h"
#include "matlaber/schedule.h"
#include "matlaber/sd_model.h"
#include "matlaber/sds.h"
#include "test.h"

static char path_buf[4][1200];
static const char* data_path(int slot, const char* rel) {
    const char* d = test_shared_data();
    if (!d) return NULL;
    snprintf(path_buf[slot], sizeof path_buf[slot], "%s/sd_reference/%s", d, rel);
    struct stat s;
    return stat(path_buf[slot], &s) == 0 ? path_buf[slot] : NULL;
}

static float* ref_tensor(const mlb_safetensors* st, const char* name, size_t* n) {
    const mlb_st_tensor* t = mlb_st_find(st, name);
    if (!t) { printf("  missing reference tensor %s\n", name); return NULL; }
    float* out = malloc(t->nelem * sizeof(float));
    if (mlb_st_read_f32(st, name, out, t->nelem) != MLB_OK) { free(out); return NULL; }
    if (n) *n = t->nelem;
    return out;
}
static int ref_i64(const mlb_safetensors* st, const char* name, int* out, size_t n) {
    const mlb_st_tensor* t = mlb_st_find(st, name);
    if (!t || t->dtype != MLB_DT_I64 || t->nelem != n) return -1;
    for (size_t i = 0; i < n; i++) { int64_t v; memcpy(&v, (const char*)t->data + 8 * i, 8); out[i] = (int)v; }
    return 0;
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
#define CMP(name, ours, ref, n, tol) do { double d_ = max_abs_diff(ours, ref, n); \
    printf("  %-14s max|diff| %.3g (max|ref| %.3g, tol %g)\n", name, d_, max_abs(ref, n), (double)(tol)); \
    CHECK_MSG(d_ <= (tol), "%s differs by %g", name, d_); } while (0)

static mlb_sd_model* model;   // the SD1 tiny diffusers folder, loaded once
static mlb_sd_model* get_model(void) {
    if (model) return model;
    const char* p = data_path(0, "sd1_diffusers");
    if (!p) return NULL;
    if (mlb_sd_model_load(p, NULL, &model) != MLB_OK) { printf("  load: %s\n", mlb_last_error()); return NULL; }
    return model;
}

// ---- without shared data ----------------------------------------------------------------------------
TEST(weights_and_views) {
    CHECK_CLOSE(mlb_sds_weight(MLB_SDS_W_DREAMFUSION, 0.25f, 0, 0), 0.75, 1e-7, 0);
    CHECK_CLOSE(mlb_sds_weight(MLB_SDS_W_FANTASIA0, 0.25f, 0, 0), 0.5 * 0.75, 1e-7, 0);
    CHECK_CLOSE(mlb_sds_weight(MLB_SDS_W_FANTASIA1, 0.25f, 0, 0), 1 / 0.75, 1e-6, 0);
    CHECK(mlb_sds_weight(MLB_SDS_W_FANTASIA1, 1.0f, 0, 0) == 0.0f);   // 1/0 -> 0
    CHECK(mlb_sds_weight(MLB_SDS_W_FANTASIA2, 0.3f, 99, 100) == 0.0f);
    CHECK(mlb_sds_weight(MLB_SDS_W_FANTASIA2, 0.3f, 100, 100) == 1.0f);
    CHECK(mlb_sds_view_for_azimuth(0) == MLB_SDS_VIEW_FRONT && mlb_sds_view_for_azimuth(-45) == MLB_SDS_VIEW_FRONT);
    CHECK(mlb_sds_view_for_azimuth(90) == MLB_SDS_VIEW_SIDE && mlb_sds_view_for_azimuth(-100) == MLB_SDS_VIEW_SIDE);
    CHECK(mlb_sds_view_for_azimuth(180) == MLB_SDS_VIEW_BACK && mlb_sds_view_for_azimuth(-150) == MLB_SDS_VIEW_BACK);
    CHECK(mlb_sds_view_for_azimuth(370) == MLB_SDS_VIEW_FRONT);
    // every range and its boundaries: front |az| <= 45, back |az| >= 135, side between; overhead
    // above 60 degrees of elevation whatever the azimuth
    const struct { double az, el; int want; } cases[] = {
        {45, 0, MLB_SDS_VIEW_FRONT}, {45.001, 0, MLB_SDS_VIEW_SIDE}, {-45, 30, MLB_SDS_VIEW_FRONT},
        {-45.001, 30, MLB_SDS_VIEW_SIDE}, {134.999, -10, MLB_SDS_VIEW_SIDE}, {135, -10, MLB_SDS_VIEW_BACK},
        {-135, 20, MLB_SDS_VIEW_BACK}, {-134.999, 20, MLB_SDS_VIEW_SIDE}, {180, 45, MLB_SDS_VIEW_BACK},
        {10, 60, MLB_SDS_VIEW_FRONT}, {10, 60.001, MLB_SDS_VIEW_OVERHEAD}, {180, 89, MLB_SDS_VIEW_OVERHEAD},
        {-90, 75, MLB_SDS_VIEW_OVERHEAD}, {-90, -75, MLB_SDS_VIEW_SIDE}, {720 + 30, 0, MLB_SDS_VIEW_FRONT}};
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++)
        CHECK_MSG(mlb_sds_view_for(cases[i].az, cases[i].el) == cases[i].want, "azimuth %g, elevation %g: %d, want %d",
                  cases[i].az, cases[i].el, mlb_sds_view_for(cases[i].az, cases[i].el), cases[i].want);
    CHECK(!strcmp(mlb_sds_view_suffix(MLB_SDS_VIEW_OVERHEAD), ", overhead view"));
    CHECK(!strcmp(mlb_sds_view_suffix(MLB_SDS_VIEW_NONE), "") && !strcmp(mlb_sds_view_suffix(99), ""));
    mlb_sds_weighting w;
    CHECK(mlb_sds_weighting_parse("fantasia1", &w) == MLB_OK && w == MLB_SDS_W_FANTASIA1);
    CHECK(mlb_sds_weighting_parse("bogus", &w) == MLB_ERR_ARG && strstr(mlb_last_error(), "bogus"));
    CHECK(!strcmp(mlb_sds_weighting_name(MLB_SDS_W_FANTASIA0), "fantasia0"));
    // the annealed largest timestep: linear from t_max to t_max_end over anneal_steps, then held
    mlb_sds_options a = mlb_sds_default_options();
    a.t_min = 150, a.t_max = 500, a.t_max_end = 250, a.anneal_steps = 120;
    CHECK(mlb_sds_t_max_at(&a, 0) == 500 && mlb_sds_t_max_at(&a, -3) == 500 && mlb_sds_t_max_at(&a, 60) == 375);
    CHECK(mlb_sds_t_max_at(&a, 119) == 252 && mlb_sds_t_max_at(&a, 120) == 250 && mlb_sds_t_max_at(&a, 5000) == 250);
    a.anneal_steps = 0;
    CHECK(mlb_sds_t_max_at(&a, 60) == 500);
}

TEST(load_errors) {
    mlb_sd_model* m = (mlb_sd_model*)1;
    CHECK(mlb_sd_model_load("/nonexistent/model.ckpt", NULL, &m) == MLB_ERR_UNSUPPORTED && m == NULL);
    CHECK(strstr(mlb_last_error(), "safetensors") != NULL);
    CHECK(mlb_sd_model_load("/nonexistent/model.safetensors", NULL, &m) != MLB_OK && m == NULL);
    CHECK(strstr(mlb_last_error(), "/nonexistent/model.safetensors") != NULL);
}

// ---- against ref_sds_sd1 --------------------------------------------------------------------------
TEST(sds_matches_reference) {
    mlb_sd_model* m = get_model();
    const char* rp = data_path(1, "ref_sds_sd1.safetensors");
    if (!m || !rp) SKIP("no ../shared/data/sd_reference");
    mlb_safetensors* ref;
    REQUIRE(mlb_st_open(&ref, rp) == MLB_OK);
    const int B = 2, H = 128, h = 16, Dc = 32, T = 77;
    const size_t n = (size_t)B * 4 * h * h, nimg = (size_t)B * 3 * H * H;
    float *image = ref_tensor(ref, "image", NULL), *noise = ref_tensor(ref, "noise", NULL);
    float *cc = ref_tensor(ref, "context_cond", NULL), *cu = ref_tensor(ref, "context_uncond", NULL);
    float *r_lat = ref_tensor(ref, "latent", NULL), *r_noisy = ref_tensor(ref, "noisy_latent", NULL);
    float *r_ec = ref_tensor(ref, "eps_cond", NULL), *r_eu = ref_tensor(ref, "eps_uncond", NULL);
    float *r_eg = ref_tensor(ref, "eps_guided", NULL), *r_gl = ref_tensor(ref, "grad_latent", NULL);
    float *r_gi = ref_tensor(ref, "grad_image", NULL), *r_w = ref_tensor(ref, "w", NULL), *r_loss = ref_tensor(ref, "loss", NULL);
    int t[2];
    REQUIRE(image && noise && cc && cu && r_lat && r_noisy && r_ec && r_eu && r_eg && r_gl && r_gi && r_w && r_loss);
    REQUIRE(ref_i64(ref, "t", t, 2) == 0);
    printf("  t = %d, %d\n", t[0], t[1]);

    // the model's own prompt encoding gives the reference contexts
    float* emb = malloc((size_t)T * Dc * sizeof(float));
    REQUIRE(mlb_sd_model_encode_prompt(m, "a golden goblet", emb) == MLB_OK);
    CMP("context_cond", emb, cc, (size_t)T * Dc, 1e-4);
    REQUIRE(mlb_sd_model_encode_prompt(m, "", emb) == MLB_OK);
    CMP("context_uncond", emb, cu, (size_t)T * Dc, 1e-4);
    free(emb);

    mlb_sds* s;
    REQUIRE(mlb_sds_create(m->unet, m->vae, m->scaling_factor, m->alphas_cumprod, m->v_prediction, NULL, &s) == MLB_OK);
    REQUIRE(mlb_sds_set_cond(s, MLB_SDS_VIEW_NONE, cc, T) == MLB_OK);
    REQUIRE(mlb_sds_set_uncond(s, cu, T) == MLB_OK);
    float *lat = malloc(n * 4), *noisy = malloc(n * 4), *ec = malloc(n * 4), *eu = malloc(n * 4), *eg = malloc(n * 4),
          *gl = malloc(n * 4), *gi = calloc(nimg, 4), w[2];
    int tt[2];
    double err_c[2], err_u[2];
    mlb_sds_trace tr = {lat, noisy, ec, eu, eg, gl, w, tt, err_c, err_u};
    mlb_sds_input in = {image, B, 3, H, H, NULL, 0, t, noise, 0, 0};
    float loss = 0;
    REQUIRE(mlb_sds_step(s, NULL, &in, gi, &loss, &tr) == MLB_OK);
    CHECK(tt[0] == t[0] && tt[1] == t[1]);
    // the denoising errors (the diffusion classifier's terms) from the reference's eps and the noise
    for (int b = 0; b < B; b++) {
        size_t k = n / B;
        double rc = 0, ru = 0;
        for (size_t i = 0; i < k; i++) {
            double dc = (double)r_ec[b * k + i] - noise[b * k + i], du = (double)r_eu[b * k + i] - noise[b * k + i];
            rc += dc * dc;
            ru += du * du;
        }
        rc /= (double)k;
        ru /= (double)k;
        printf("  element %d: denoising error cond %.6f (reference %.6f), uncond %.6f (%.6f)\n", b, err_c[b], rc, err_u[b], ru);
        CHECK_CLOSE(err_c[b], rc, 1e-4, 1e-4);
        CHECK_CLOSE(err_u[b], ru, 1e-4, 1e-4);
    }
    CMP("w", w, r_w, 2, 3e-7);   // 1 - ac in float: an ulp or two
    CMP("latent", lat, r_lat, n, 1e-4);
    CMP("noisy_latent", noisy, r_noisy, n, 1e-4);
    CMP("eps_cond", ec, r_ec, n, 1e-4);
    CMP("eps_uncond", eu, r_eu, n, 1e-4);
    CMP("eps_guided", eg, r_eg, n, 5e-3);
    CMP("grad_latent", gl, r_gl, n, 5e-3);
    CMP("grad_image", gi, r_gi, nimg, 1e-4);
    printf("  loss %.8g, reference %.8g\n", loss, r_loss[0]);
    CHECK_CLOSE(loss, r_loss[0], 1e-4, 0);

    // gradients accumulate: a second identical step doubles them
    REQUIRE(mlb_sds_step(s, NULL, &in, gi, NULL, NULL) == MLB_OK);
    for (size_t i = 0; i < nimg; i++) gi[i] *= 0.5f;
    CMP("accumulated/2", gi, r_gi, nimg, 1e-4);

    // ---- the image gradient convention by a double finite difference: L(x) = 0.5 sum (sf mean(2x-1)
    // - target)^2 / B with target = z - grad held fixed; dL/dx must equal our grad_image.
    mlb_vae_f64* v64;
    REQUIRE(mlb_vae_to_f64(m->vae, &v64) == MLB_OK);
    double* x = malloc(nimg * sizeof(double));
    double* mean = malloc(n * sizeof(double));
    double* target = malloc(n * sizeof(double));
    for (size_t i = 0; i < nimg; i++) x[i] = 2.0 * image[i] - 1.0;
    REQUIRE(mlb_vae_encode_f64(NULL, v64, x, B, H, H, mean, NULL, NULL) == MLB_OK);
    for (size_t i = 0; i < n; i++) target[i] = m->scaling_factor * mean[i] - gl[i];
    const int probes[6] = {0, 1234, 3 * H * H + 77, 3 * H * H + 2 * H * H + 8191, 40000, 98000};
    double worst = 0, gmax = max_abs(r_gi, nimg);
    for (int k = 0; k < 6; k++) {
        int p = probes[k];
        double L[2];
        for (int sgn = 0; sgn < 2; sgn++) {
            const double eps = 1e-3;   // in image units; x moves by 2 eps
            double x0 = 2.0 * image[p] - 1.0;
            x[p] = x0 + 2.0 * (sgn ? -eps : eps);
            REQUIRE(mlb_vae_encode_f64(NULL, v64, x, B, H, H, mean, NULL, NULL) == MLB_OK);
            x[p] = x0;
            double l = 0;
            for (size_t i = 0; i < n; i++) { double d = m->scaling_factor * mean[i] - target[i]; l += d * d; }
            L[sgn] = 0.5 * l / B;
        }
        double fd = (L[0] - L[1]) / 2e-3;
        double d = fabs(fd - gi[p]);
        if (d > worst) worst = d;
    }
    printf("  finite difference vs grad_image: max|diff| %.3g over 6 pixels (max|grad| %.3g)\n", worst, gmax);
    CHECK(worst <= 1e-5 + 1e-3 * gmax);
    free(x); free(mean); free(target);
    mlb_vae_free_f64(v64);

    free(lat); free(noisy); free(ec); free(eu); free(eg); free(gl); free(gi);
    free(image); free(noise); free(cc); free(cu); free(r_lat); free(r_noisy); free(r_ec); free(r_eu); free(r_eg);
    free(r_gl); free(r_gi); free(r_w); free(r_loss);
    mlb_sds_free(s);
    mlb_st_close(ref);
}

// sampled t and noise: in range, a pure function of (seed, step); latents used directly
TEST(sds_sampling_and_latent_input) {
    mlb_sd_model* m = get_model();
    if (!m) SKIP("no ../shared/data/sd_reference");
    mlb_sds_options o = mlb_sds_default_options();
    o.seed = 7;
    o.t_min = 20;
    o.t_max = 500;
    mlb_sds* s;
    REQUIRE(mlb_sds_create_from_model(m, "a golden goblet", "low quality", 1, &o, &s) == MLB_OK);
    const int B = 3, h = 16;
    const size_t n = (size_t)B * 4 * h * h;
    float* z = malloc(n * 4);
    for (size_t i = 0; i < n; i++) z[i] = (float)sin(0.01 * i);
    float *g1 = calloc(n, 4), *g2 = calloc(n, 4), *gl = malloc(n * 4), l1, l2;
    int t1[3], t2[3], views[3] = {MLB_SDS_VIEW_FRONT, MLB_SDS_VIEW_SIDE, MLB_SDS_VIEW_BACK};
    mlb_sds_trace tr = {0};
    tr.t = t1;
    tr.grad_latent = gl;
    mlb_sds_input in = {z, B, 4, h, h, views, 5, NULL, NULL, 0, 0};
    REQUIRE(mlb_sds_step(s, NULL, &in, g1, &l1, &tr) == MLB_OK);
    tr.t = t2;
    tr.grad_latent = NULL;
    REQUIRE(mlb_sds_step(s, NULL, &in, g2, &l2, &tr) == MLB_OK);
    CHECK(memcmp(g1, g2, n * 4) == 0 && l1 == l2 && !memcmp(t1, t2, sizeof t1));
    for (int b = 0; b < B; b++) CHECK(t1[b] >= 20 && t1[b] <= 500);
    double l = 0, d = 0;   // latent input: grad_images = grad / B, loss = 0.5 |grad|^2 / B
    for (size_t i = 0; i < n; i++) { l += (double)gl[i] * gl[i]; d = fmax(d, fabs(g1[i] - gl[i] / B)); }
    CHECK(d == 0);
    CHECK_CLOSE(l1, 0.5 * l / B, 1e-5, 0);
    in.step = 6;
    REQUIRE(mlb_sds_step(s, NULL, &in, NULL, &l2, &tr) == MLB_OK);
    CHECK(l2 != l1);
    // each view's embedding is the suffixed prompt's: the same step through an SDS object holding
    // only "a golden goblet, <view> view" as its plain prompt gives the same bits
    float* emb = malloc(sizeof(float) * MLB_CLIP_CONTEXT * (size_t)mlb_sd_model_context_width(m));
    float *ga = calloc(n, 4), *gb = calloc(n, 4);
    REQUIRE(emb && ga && gb);
    for (int v = MLB_SDS_VIEW_FRONT; v < MLB_SDS_N_VIEWS; v++) {
        char text[128];
        snprintf(text, sizeof text, "a golden goblet%s", mlb_sds_view_suffix(v));
        mlb_sds* one = NULL;
        REQUIRE(mlb_sds_create(m->unet, m->vae, m->scaling_factor, m->alphas_cumprod, m->v_prediction, &o, &one) == MLB_OK);
        REQUIRE(mlb_sd_model_encode_prompt(m, text, emb) == MLB_OK);
        REQUIRE(mlb_sds_set_cond(one, MLB_SDS_VIEW_NONE, emb, MLB_CLIP_CONTEXT) == MLB_OK);
        REQUIRE(mlb_sd_model_encode_prompt(m, "low quality", emb) == MLB_OK);
        REQUIRE(mlb_sds_set_uncond(one, emb, MLB_CLIP_CONTEXT) == MLB_OK);
        int vv[3] = {v, v, v}, nn[3] = {MLB_SDS_VIEW_NONE, MLB_SDS_VIEW_NONE, MLB_SDS_VIEW_NONE};
        mlb_sds_input a = {z, B, 4, h, h, vv, 5, NULL, NULL, 0, 0}, b = {z, B, 4, h, h, nn, 5, NULL, NULL, 0, 0};
        memset(ga, 0, n * 4);
        memset(gb, 0, n * 4);
        REQUIRE(mlb_sds_step(s, NULL, &a, ga, NULL, NULL) == MLB_OK);
        REQUIRE(mlb_sds_step(one, NULL, &b, gb, NULL, NULL) == MLB_OK);
        CHECK_MSG(memcmp(ga, gb, n * 4) == 0, "view %d: not the embedding of \"%s\"", v, text);
        mlb_sds_free(one);
    }
    free(emb); free(ga); free(gb);
    // errors
    in.C = 5;
    CHECK(mlb_sds_step(s, NULL, &in, NULL, NULL, NULL) == MLB_ERR_ARG && strstr(mlb_last_error(), "channels"));
    in.C = 4; in.H = 12;
    CHECK(mlb_sds_step(s, NULL, &in, NULL, NULL, NULL) == MLB_ERR_ARG);
    // annealed to t_max_end 40 over 5 steps: step 0 draws as without annealing, step 5 within [20, 40]
    mlb_sds_options oa = o;
    oa.t_max_end = 40, oa.anneal_steps = 5;
    mlb_sds* sa = NULL;
    REQUIRE(mlb_sds_create_from_model(m, "a golden goblet", "low quality", 1, &oa, &sa) == MLB_OK);
    int ta[3], tp[3];
    mlb_sds_trace tt = {0};
    in.H = h, in.step = 0, tt.t = ta;
    REQUIRE(mlb_sds_step(sa, NULL, &in, NULL, NULL, &tt) == MLB_OK);
    tt.t = tp;
    REQUIRE(mlb_sds_step(s, NULL, &in, NULL, NULL, &tt) == MLB_OK);
    CHECK(!memcmp(ta, tp, sizeof ta));
    in.step = 5, tt.t = ta;
    REQUIRE(mlb_sds_step(sa, NULL, &in, NULL, NULL, &tt) == MLB_OK);
    for (int b = 0; b < B; b++) CHECK_MSG(ta[b] >= 20 && ta[b] <= 40, "annealed step 5: t %d", ta[b]);
    mlb_sds_free(sa);
    mlb_sds* bad = NULL;
    oa.t_max_end = 10;   // below t_min
    CHECK(mlb_sds_create(m->unet, m->vae, m->scaling_factor, m->alphas_cumprod, 0, &oa, &bad) == MLB_ERR_ARG && !bad);
    o.t_min = 600; o.t_max = 500;
    CHECK(mlb_sds_create(m->unet, m->vae, m->scaling_factor, m->alphas_cumprod, 0, &o, &bad) == MLB_ERR_ARG && !bad);
    free(z); free(g1); free(g2); free(gl);
    mlb_sds_free(s);
}

// ---- DDIM + CFG: the sampler of `sd txt2img` against ref_ddim_sd1 -----------------------------------
TEST(ddim_matches_reference) {
    mlb_sd_model* m = get_model();
    const char* rp = data_path(2, "ref_ddim_sd1.safetensors");
    if (!m || !rp) SKIP("no ../shared/data/sd_reference");
    mlb_safetensors* ref;
    REQUIRE(mlb_st_open(&ref, rp) == MLB_OK);
    float *ctx = ref_tensor(ref, "context", NULL), *lat = ref_tensor(ref, "noise", NULL);
    float *r_final = ref_tensor(ref, "latent_final", NULL), *r_img = ref_tensor(ref, "image_final", NULL);
    float *r_eps = ref_tensor(ref, "debug.eps_guided", NULL), *r_steps = ref_tensor(ref, "debug.latents_after_step", NULL);
    int ts[4], ours[4];
    REQUIRE(ctx && lat && r_final && r_img && r_eps && r_steps && ref_i64(ref, "timesteps", ts, 4) == 0);
    REQUIRE(mlb_ddim_timesteps(ours, 4, 1000, 1) == MLB_OK);
    CHECK(!memcmp(ts, ours, sizeof ts));
    const int h = 16;
    const size_t n = 4 * h * h;
    float *eps = malloc(4 * n * 4), *steps = malloc(4 * n * 4), *img = malloc(3 * 128 * 128 * 4);
    REQUIRE(mlb_sd_ddim_sample(m->unet, m->alphas_cumprod, 0, ctx, ctx + 77 * 32, 77, lat, h, h, 4, 7.5f, eps, steps, NULL) == MLB_OK);
    CMP("eps_guided", eps, r_eps, 4 * n, 1e-3);
    CMP("latents", steps, r_steps, 4 * n, 1e-3);
    CMP("latent_final", lat, r_final, n, 1e-3);
    REQUIRE(mlb_sd_decode_latent(m->vae, m->scaling_factor, lat, h, h, img) == MLB_OK);
    CMP("image_final", img, r_img, 3 * 128 * 128, 2e-4);
    free(eps); free(steps); free(img); free(ctx); free(lat); free(r_final); free(r_img); free(r_eps); free(r_steps);
    mlb_st_close(ref);
}

int main(void) {
    RUN(weights_and_views);
    RUN(load_errors);
    RUN(sds_matches_reference);
    RUN(sds_sampling_and_latent_input);
    RUN(ddim_matches_reference);
    mlb_sd_model_free(model);
    return test_summary();
}
