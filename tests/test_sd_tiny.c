// Stable Diffusion pieces on tiny random models the test writes itself (no ../shared/data):
// the fixture-sized UNets (unet_random.h) in the diffusers and the original single-file layouts,
// loaded back to identical parameters and outputs; shapes, determinism over thread counts, errors
// naming a missing or mis-shaped tensor; classifier-free guidance and the SDS weightings against
// hand-computed values; one SDS step on 4-channel latents checked against a direct computation.
#include <stdint.h>
#include <unistd.h>
#include "matlaber/rng.h"
#include "matlaber/schedule.h"
#include "matlaber/sds.h"
#include "matlaber/threads.h"
#include "matlaber/unet.h"
#include "matlaber/unet_random.h"
#include "matlaber/vae.h"
#include "test.h"
#include "tiny_sds_fixture.h"   // tiny_vae

static char tmpdir[256];

static void tmp_path(char* out, size_t cap, const char* name) { snprintf(out, cap, "%s/%s", tmpdir, name); }

// Writes variant sd2 in both layouts (seed 7) and loads both. 0 on success.
static int write_and_load(int sd2, mlb_unet** dif, mlb_unet** ldm) {
    mlb_unet_config c = mlb_unet_tiny_config(sd2);
    char wd[512], cj[512], wl[512];
    tmp_path(wd, sizeof wd, sd2 ? "unet2.diffusers.safetensors" : "unet1.diffusers.safetensors");
    tmp_path(cj, sizeof cj, sd2 ? "unet2.diffusers.config.json" : "unet1.diffusers.config.json");
    tmp_path(wl, sizeof wl, sd2 ? "unet2.ldm.safetensors" : "unet1.ldm.safetensors");
    mlb_unet_random_options o = mlb_unet_random_default_options();
    o.seed = 7;
    o.config_json_path = cj;
    if (mlb_unet_write_random(&c, &o, wd)) { printf("  %s\n", mlb_last_error()); return 1; }
    o.layout = MLB_UNET_LAYOUT_LDM;
    o.config_json_path = NULL;
    if (mlb_unet_write_random(&c, &o, wl)) { printf("  %s\n", mlb_last_error()); return 1; }
    if (mlb_unet_load(wd, NULL, dif)) { printf("  %s\n", mlb_last_error()); return 1; }
    if (mlb_unet_load(wl, NULL, ldm)) { printf("  %s\n", mlb_last_error()); mlb_unet_free(*dif); return 1; }
    return 0;
}

TEST(names_match_the_real_keys) {
    mlb_unet_config c = mlb_unet_tiny_config(0);
    size_t n = 0;
    REQUIRE(mlb_unet_tensor_specs(&c, NULL, 0, &n) == MLB_OK);
    CHECK(n > 300);
    char out[256];
    // keys every SD 1.x single file holds (layers_per_block 2, attention at levels 0-2)
    static const char* pairs[][2] = {
        {"time_embedding.linear_2.bias", "model.diffusion_model.time_embed.2.bias"},
        {"conv_in.weight", "model.diffusion_model.input_blocks.0.0.weight"},
        {"down_blocks.0.resnets.1.conv1.weight", "model.diffusion_model.input_blocks.2.0.in_layers.2.weight"},
        {"down_blocks.0.attentions.0.transformer_blocks.0.attn2.to_k.weight",
         "model.diffusion_model.input_blocks.1.1.transformer_blocks.0.attn2.to_k.weight"},
        {"down_blocks.0.downsamplers.0.conv.weight", "model.diffusion_model.input_blocks.3.0.op.weight"},
        {"down_blocks.2.resnets.0.conv_shortcut.weight", "model.diffusion_model.input_blocks.7.0.skip_connection.weight"},
        {"mid_block.resnets.1.time_emb_proj.weight", "model.diffusion_model.middle_block.2.emb_layers.1.weight"},
        {"mid_block.attentions.0.proj_in.weight", "model.diffusion_model.middle_block.1.proj_in.weight"},
        {"up_blocks.0.upsamplers.0.conv.weight", "model.diffusion_model.output_blocks.2.1.conv.weight"},
        {"up_blocks.1.upsamplers.0.conv.bias", "model.diffusion_model.output_blocks.5.2.conv.bias"},
        {"up_blocks.3.resnets.2.norm2.weight", "model.diffusion_model.output_blocks.11.0.out_layers.0.weight"},
        {"conv_norm_out.bias", "model.diffusion_model.out.0.bias"},
        {"conv_out.weight", "model.diffusion_model.out.2.weight"},
    };
    for (size_t i = 0; i < sizeof pairs / sizeof pairs[0]; i++) {
        mlb_unet_ldm_name(&c, pairs[i][0], out, sizeof out);
        CHECK_MSG(!strcmp(out, pairs[i][1]), "%s -> %s, expected %s", pairs[i][0], out, pairs[i][1]);
    }
    // SD 1.5 at full size: the published parameter count
    mlb_unet_config sd = mlb_unet_sd15_config();
    mlb_unet_tensor_spec* sp = calloc(2000, sizeof *sp);
    REQUIRE(sp);
    REQUIRE(mlb_unet_tensor_specs(&sd, sp, 2000, &n) == MLB_OK);
    size_t total = 0;
    for (size_t i = 0; i < n; i++) total += sp[i].n;
    CHECK(n == 686);
    CHECK_MSG(total == 859520964u, "%zu parameters", total);
    free(sp);
    mlb_unet_config bad = c;
    bad.block_out[1] = 48;
    CHECK(mlb_unet_config_check(&bad) == MLB_ERR_ARG && strstr(mlb_last_error(), "block_out[1]"));
}

static void layouts_identical(int sd2) {
    mlb_unet *a = NULL, *b = NULL;
    REQUIRE(write_and_load(sd2, &a, &b) == 0);
    const mlb_unet_config *ca = mlb_unet_get_config(a), *cb = mlb_unet_get_config(b);
    mlb_unet_config want = mlb_unet_tiny_config(sd2);
    CHECK(ca->layout == MLB_UNET_LAYOUT_DIFFUSERS && cb->layout == MLB_UNET_LAYOUT_LDM);
    for (const mlb_unet_config* c = ca; c; c = c == ca ? cb : NULL) {
        CHECK(c->n_levels == 4 && c->layers_per_block == 2 && c->context_dim == want.context_dim);
        CHECK(c->linear_projection == want.linear_projection && c->time_embed_dim == 128 && c->norm_groups == 32);
        for (int i = 0; i < 4; i++) {
            CHECK(c->block_out[i] == want.block_out[i] && c->attn[i] == want.attn[i]);
            if (c->attn[i]) CHECK_MSG(c->heads[i] == want.heads[i], "level %d: %d heads, want %d", i, c->heads[i], want.heads[i]);
        }
        CHECK(c->mid_heads == want.mid_heads);
        CHECK_CLOSE(c->norm_eps, 1e-5, 0, 1e-12);
    }
    size_t n = 0;
    REQUIRE(mlb_unet_tensor_specs(&want, NULL, 0, &n) == MLB_OK);
    CHECK(a->n_params == b->n_params);
    CHECK(a->n_params > 0 && !memcmp(a->params, b->params, a->n_params * sizeof(float)));
    // the loaded values are the generator's values
    mlb_unet_tensor_spec sp;
    REQUIRE(mlb_unet_tensor_specs(&want, &sp, 1, &n) == MLB_OK);   // time_embedding.linear_1.weight
    float* v = malloc(sp.n * sizeof(float));
    REQUIRE(v);
    mlb_unet_random_values(&sp, 0, 7, 1.0f, v);
    CHECK(!memcmp(v, a->time1_w, sp.n * sizeof(float)));
    free(v);

    const int N = 2, H = 8, W = 8, Tc = 5, D = want.context_dim;
    size_t nx = (size_t)N * 4 * H * W;
    float* x = malloc(nx * sizeof(float));
    float* ctx = malloc((size_t)N * Tc * D * sizeof(float));
    float *o1 = malloc((nx + 8) * sizeof(float)), *o2 = malloc((nx + 8) * sizeof(float)), *o3 = malloc((nx + 8) * sizeof(float));
    REQUIRE(x && ctx && o1 && o2 && o3);
    mlb_rng_fill_normal(x, nx, 11, 1, 0, 0, 1);
    mlb_rng_fill_normal(ctx, (size_t)N * Tc * D, 11, 2, 0, 0, 1);
    float t[2] = {981.0f, 37.0f};
    for (size_t i = nx; i < nx + 8; i++) o1[i] = o2[i] = o3[i] = 12345.0f;   // canary past the output
    int th = mlb_get_threads();
    mlb_set_threads(2);
    CHECK(mlb_unet_forward(NULL, a, o1, x, t, ctx, N, H, W, Tc, NULL, NULL) == MLB_OK);
    CHECK(mlb_unet_forward(NULL, b, o2, x, t, ctx, N, H, W, Tc, NULL, NULL) == MLB_OK);
    CHECK_MSG(!memcmp(o1, o2, nx * sizeof(float)), "diffusers and single-file layouts give different outputs");
    for (size_t i = nx; i < nx + 8; i++) CHECK(o1[i] == 12345.0f && o2[i] == 12345.0f);
    int finite = 1;
    double norm = 0;
    for (size_t i = 0; i < nx; i++) { finite &= isfinite(o1[i]) != 0; norm += (double)o1[i] * o1[i]; }
    CHECK(finite && norm > 0);
    CHECK(memcmp(o1, o1 + nx / 2, nx / 2 * sizeof(float)) != 0);   // the two batch elements differ
    CHECK(mlb_unet_forward(NULL, a, o3, x, t, ctx, N, H, W, Tc, NULL, NULL) == MLB_OK);
    CHECK_MSG(!memcmp(o1, o3, nx * sizeof(float)), "the same call twice differs");
    mlb_set_threads(1);
    CHECK(mlb_unet_forward(NULL, a, o3, x, t, ctx, N, H, W, Tc, NULL, NULL) == MLB_OK);
    CHECK_MSG(!memcmp(o1, o3, nx * sizeof(float)), "1 and 2 threads differ (unet.h promises the same bits)");
    mlb_set_threads(th);
    // a batch of one gives the first element of the batch of two
    CHECK(mlb_unet_forward(NULL, b, o3, x, t, ctx, 1, H, W, Tc, NULL, NULL) == MLB_OK);
    for (size_t i = 0; i < nx / 2; i++) CHECK_CLOSE(o3[i], o1[i], 1e-4, 1e-5);   // GEMM sizes differ: rounding
    // bad shapes: H not a multiple of 8
    CHECK(mlb_unet_forward(NULL, a, o3, x, t, ctx, 1, 12, 12, Tc, NULL, NULL) == MLB_ERR_ARG);
    mlb_clear_error();
    free(x); free(ctx); free(o1); free(o2); free(o3);
    mlb_unet_free(a);
    mlb_unet_free(b);
}

TEST(sd1_layouts_identical) { layouts_identical(0); }
TEST(sd2_layouts_identical) { layouts_identical(1); }

// Copies `src` to `dst` without tensor `drop` (NULL: none) and with a trailing 1 added to `reshape`'s shape.
static int copy_edited(const char* src, const char* dst, const char* drop, const char* reshape) {
    mlb_safetensors* st = NULL;
    if (mlb_st_open(&st, src)) return 1;
    size_t n = mlb_st_count(st), k = 0;
    mlb_st_entry* e = calloc(n, sizeof *e);
    int64_t(*shapes)[MLB_ST_MAX_DIMS] = calloc(n, sizeof *shapes);
    mlb_st_meta meta[4];
    size_t nm = 0;
    for (size_t i = 0; i < mlb_st_metadata_count(st) && nm < 4; i++, nm++)
        mlb_st_metadata_at(st, i, &meta[nm].key, &meta[nm].value);
    for (size_t i = 0; i < n; i++) {
        const mlb_st_tensor* t = mlb_st_tensor_at(st, i);
        if (drop && !strcmp(t->name, drop)) continue;
        memcpy(shapes[k], t->shape, sizeof shapes[k]);
        int nd = t->ndim;
        if (reshape && !strcmp(t->name, reshape) && nd < MLB_ST_MAX_DIMS) shapes[k][nd++] = 1;   // same count, extra dim
        e[k] = (mlb_st_entry){t->name, t->dtype, nd, shapes[k], t->data};
        k++;
    }
    mlb_status s = mlb_st_write(dst, e, k, meta, nm);
    free(e); free(shapes);
    mlb_st_close(st);
    return s != MLB_OK;
}

TEST(missing_and_misshaped_tensors_are_named) {
    mlb_unet_config c = mlb_unet_tiny_config(0);
    char src[512], dst[512], d2[512];
    tmp_path(src, sizeof src, "err.ldm.safetensors");
    tmp_path(dst, sizeof dst, "err.edit.safetensors");
    tmp_path(d2, sizeof d2, "err.diffusers.safetensors");
    mlb_unet_random_options o = mlb_unet_random_default_options();
    o.layout = MLB_UNET_LAYOUT_LDM;
    o.dtype = MLB_DT_F16;   // F16 loads too
    REQUIRE(mlb_unet_write_random(&c, &o, src) == MLB_OK);
    mlb_unet* u = NULL;
    REQUIRE(mlb_unet_load(src, NULL, &u) == MLB_OK);
    mlb_unet_free(u);
    const char* names[] = {"model.diffusion_model.input_blocks.4.1.transformer_blocks.0.attn2.to_v.weight",
                           "model.diffusion_model.output_blocks.8.0.skip_connection.bias",
                           "model.diffusion_model.middle_block.1.transformer_blocks.0.ff.net.2.weight"};
    for (int i = 0; i < 3; i++) {
        REQUIRE(copy_edited(src, dst, names[i], NULL) == 0);
        u = (mlb_unet*)1;
        mlb_status s = mlb_unet_load(dst, NULL, &u);
        CHECK_MSG(s == MLB_ERR_NOT_FOUND && u == NULL, "status %d", (int)s);
        CHECK_MSG(strstr(mlb_last_error(), names[i]) && strstr(mlb_last_error(), dst), "message: %s", mlb_last_error());
        REQUIRE(copy_edited(src, dst, NULL, names[i]) == 0);
        s = mlb_unet_load(dst, NULL, &u);
        CHECK_MSG(s == MLB_ERR_FORMAT && u == NULL, "status %d", (int)s);
        CHECK_MSG(strstr(mlb_last_error(), names[i]) != NULL, "message: %s", mlb_last_error());
    }
    // the diffusers layout names its own names
    o.layout = MLB_UNET_LAYOUT_DIFFUSERS;
    REQUIRE(mlb_unet_write_random(&c, &o, d2) == MLB_OK);
    const char* dn = "up_blocks.2.attentions.1.proj_out.bias";
    REQUIRE(copy_edited(d2, dst, dn, NULL) == 0);
    CHECK(mlb_unet_load(dst, NULL, &u) == MLB_ERR_NOT_FOUND);
    CHECK_MSG(strstr(mlb_last_error(), dn) != NULL, "message: %s", mlb_last_error());
    mlb_clear_error();
}

TEST(cfg_and_weightings_hand_computed) {
    float u[4] = {0.5f, -1.0f, 2.0f, 0.0f}, c[4] = {1.5f, -0.5f, 2.0f, -4.0f}, o[4];
    mlb_cfg_combine(o, u, c, 4, 7.5f);   // u + 7.5 (c - u)
    CHECK(o[0] == 8.0f && o[1] == 2.75f && o[2] == 2.0f && o[3] == -30.0f);
    mlb_cfg_combine(u, u, c, 4, 1.0f);   // scale 1 = cond, aliasing the output
    CHECK(!memcmp(u, c, sizeof c));
    float ac[1000];
    REQUIRE(mlb_schedule_alphas_cumprod_f32(ac, 1000, MLB_SD_BETA_START, MLB_SD_BETA_END) == MLB_OK);
    CHECK_CLOSE(ac[0], 1.0 - 0.00085, 1e-6, 0);
    CHECK_CLOSE(ac[999], 0.004660098513, 1e-5, 0);   // prod (1 - b_i), b = linspace(sqrt .00085, sqrt .012)^2
    int ts[] = {0, 20, 250, 500, 980, 999};
    for (int i = 0; i < 6; i++) {
        double a = ac[ts[i]];
        CHECK_CLOSE(mlb_sds_weight(MLB_SDS_W_DREAMFUSION, ac[ts[i]], 5, 0), 1 - a, 1e-6, 1e-9);
        CHECK_CLOSE(mlb_sds_weight(MLB_SDS_W_FANTASIA0, ac[ts[i]], 5, 0), sqrt(a) * (1 - a), 1e-6, 1e-9);
        CHECK_CLOSE(mlb_sds_weight(MLB_SDS_W_FANTASIA1, ac[ts[i]], 5, 0), 1 / (1 - a), 1e-5, 0);
        CHECK(mlb_sds_weight(MLB_SDS_W_FANTASIA2, ac[ts[i]], 99, 100) == 0.0f);
        CHECK(mlb_sds_weight(MLB_SDS_W_FANTASIA2, ac[ts[i]], 100, 100) == 1.0f);
        CHECK(mlb_sds_weight(MLB_SDS_W_FANTASIA2, ac[ts[i]], 101, 100) == 1.0f);
    }
    // t = 500 by hand (float64 schedule: ac = 0.2763326838)
    CHECK_CLOSE(ac[500], 0.2763326838, 1e-6, 0);
    CHECK_CLOSE(mlb_sds_weight(MLB_SDS_W_DREAMFUSION, ac[500], 0, 0), 0.7236673162, 1e-6, 0);
    CHECK_CLOSE(mlb_sds_weight(MLB_SDS_W_FANTASIA0, ac[500], 0, 0), 0.3804127689, 1e-6, 0);
    CHECK_CLOSE(mlb_sds_weight(MLB_SDS_W_FANTASIA1, ac[500], 0, 0), 1.381850441, 1e-6, 0);
    CHECK_CLOSE(mlb_sds_weight(MLB_SDS_W_FANTASIA1, ac[0], 0, 0), 1176.470588, 1e-4, 0);   // float 1 - ac[0]
    // 1 / (1 - ac) at ac = 1 is infinite: the weight is 0
    CHECK(mlb_sds_weight(MLB_SDS_W_FANTASIA1, 1.0f, 0, 0) == 0.0f);
    mlb_sds_weighting w;
    CHECK(mlb_sds_weighting_parse("fantasia2", &w) == MLB_OK && w == MLB_SDS_W_FANTASIA2);
    CHECK(mlb_sds_weighting_parse("nope", &w) == MLB_ERR_ARG);
    mlb_clear_error();
}

// The direct computation of the SDS latent gradient with the same t and noise.
static void sds_direct(const mlb_unet* u, const float* ac, const float* z, const float* noise, const int* ts, int B, int h,
                       int w, const float* cond, const float* unc, int Tc, float scale, mlb_sds_weighting wt, float* grad) {
    size_t n = (size_t)4 * h * w, nc = (size_t)Tc * u->cfg.context_dim;
    float* x = malloc(2 * B * n * sizeof(float));
    float* e = malloc(2 * B * n * sizeof(float));
    float* ctx = malloc(2 * B * nc * sizeof(float));
    float tt[2 * MLB_SDS_MAX_BATCH];
    for (int b = 0; b < B; b++) {
        mlb_add_noise(x + b * n, z + b * n, noise + b * n, n, ac[ts[b]]);
        memcpy(x + (B + b) * n, x + b * n, n * sizeof(float));
        memcpy(ctx + b * nc, cond, nc * sizeof(float));
        memcpy(ctx + (B + b) * nc, unc, nc * sizeof(float));
        tt[b] = tt[B + b] = (float)ts[b];
    }
    mlb_unet_forward(NULL, u, e, x, tt, ctx, 2 * B, h, w, Tc, NULL, NULL);
    for (int b = 0; b < B; b++) {
        float wb = mlb_sds_weight(wt, ac[ts[b]], 0, 0);
        for (size_t i = 0; i < n; i++) {
            float eu = e[(B + b) * n + i], ec = e[b * n + i];
            float g = wb * ((eu + scale * (ec - eu)) - noise[b * n + i]);
            grad[b * n + i] = isfinite(g) ? g / (float)B : 0.0f;
        }
    }
    free(x); free(e); free(ctx);
}

TEST(sds_step_on_latents_matches_direct) {
    mlb_unet *u = NULL, *ul = NULL;
    REQUIRE(write_and_load(0, &u, &ul) == 0);
    mlb_unet_free(ul);
    mlb_vae* vae = tiny_vae();
    REQUIRE(vae);
    float ac[1000];
    REQUIRE(mlb_schedule_alphas_cumprod_f32(ac, 1000, MLB_SD_BETA_START, MLB_SD_BETA_END) == MLB_OK);
    const int B = 2, h = 8, w = 8, Tc = 6, D = 32;
    size_t n = (size_t)4 * h * w, nall = B * n;
    float *z = malloc(nall * sizeof(float)), *noise = malloc(nall * sizeof(float)), *g = calloc(nall, sizeof(float));
    float *want = malloc(nall * sizeof(float)), *cond = malloc(Tc * D * sizeof(float)), *unc = malloc(Tc * D * sizeof(float));
    float* gl = malloc(nall * sizeof(float));
    REQUIRE(z && noise && g && want && cond && unc && gl);
    mlb_rng_fill_normal(z, nall, 5, 1, 0, 0, 1);
    mlb_rng_fill_normal(noise, nall, 5, 2, 0, 0, 1);
    mlb_rng_fill_normal(cond, Tc * D, 5, 3, 0, 0, 1);
    mlb_rng_fill_normal(unc, Tc * D, 5, 4, 0, 0, 1);
    int ts[2] = {123, 876};
    mlb_sds_weighting wts[4] = {MLB_SDS_W_DREAMFUSION, MLB_SDS_W_FANTASIA0, MLB_SDS_W_FANTASIA1, MLB_SDS_W_FANTASIA2};
    for (int k = 0; k < 4; k++) {
        mlb_sds_options o = mlb_sds_default_options();
        o.guidance_scale = 7.5f;
        o.weighting = wts[k];
        mlb_sds* s = NULL;
        REQUIRE(mlb_sds_create(u, vae, 0.18215f, ac, 0, &o, &s) == MLB_OK);
        REQUIRE(mlb_sds_set_cond(s, MLB_SDS_VIEW_NONE, cond, Tc) == MLB_OK);
        REQUIRE(mlb_sds_set_uncond(s, unc, Tc) == MLB_OK);
        mlb_sds_input in = {z, B, 4, h, w, NULL, 0, ts, noise, 0, 0};
        memset(g, 0, nall * sizeof(float));
        float loss = -1;
        int tr_t[2];
        mlb_sds_trace tr = {0};
        tr.grad_latent = gl;
        tr.t = tr_t;
        CHECK(mlb_sds_step(s, NULL, &in, g, &loss, &tr) == MLB_OK);
        sds_direct(u, ac, z, noise, ts, B, h, w, cond, unc, Tc, 7.5f, wts[k], want);
        CHECK_MSG(!memcmp(g, want, nall * sizeof(float)), "weighting %s: grad != w (eps^ - eps) / B",
                  mlb_sds_weighting_name(wts[k]));
        double l = 0;
        for (size_t i = 0; i < nall; i++) l += (double)gl[i] * gl[i];
        CHECK_CLOSE(loss, 0.5 * l / B, 1e-6, 0);
        CHECK(tr_t[0] == 123 && tr_t[1] == 876);
        if (wts[k] == MLB_SDS_W_FANTASIA2) {   // step 0 < coarse_iter 0 is false: weight 1
            CHECK(loss > 0);
        }
        // the gradient is ADDED to grad_images
        CHECK(mlb_sds_step(s, NULL, &in, g, NULL, NULL) == MLB_OK);
        int ok = 1;
        for (size_t i = 0; i < nall; i++) ok &= g[i] == want[i] + want[i];
        CHECK(ok);
        mlb_sds_free(s);
    }
    // non-finite values are zeroed: a guidance scale that overflows eps^ for most elements
    {
        mlb_sds_options o = mlb_sds_default_options();
        o.guidance_scale = 3e38f;
        mlb_sds* s = NULL;
        REQUIRE(mlb_sds_create(u, NULL, 0.18215f, ac, 0, &o, &s) == MLB_OK);
        REQUIRE(mlb_sds_set_cond(s, 0, cond, Tc) == MLB_OK && mlb_sds_set_uncond(s, unc, Tc) == MLB_OK);
        mlb_sds_input in = {z, B, 4, h, w, NULL, 0, ts, noise, 0, 0};
        memset(g, 0, nall * sizeof(float));
        float loss = -1;
        CHECK(mlb_sds_step(s, NULL, &in, g, &loss, NULL) == MLB_OK);
        sds_direct(u, ac, z, noise, ts, B, h, w, cond, unc, Tc, 3e38f, MLB_SDS_W_DREAMFUSION, want);
        int finite = 1, zeros = 0;
        for (size_t i = 0; i < nall; i++) { finite &= isfinite(g[i]) != 0; zeros += g[i] == 0.0f; }
        CHECK(finite);   // (the loss, a float, may overflow to inf here: sum of ~1e76 squares)
        CHECK_MSG(zeros > 0, "%d zeroed of %zu", zeros, nall);
        CHECK(!memcmp(g, want, nall * sizeof(float)));
        // with no VAE a 3-channel image is refused
        mlb_sds_input im = {z, 1, 3, 64, 64, NULL, 0, NULL, NULL, 0, 0};
        CHECK(mlb_sds_step(s, NULL, &im, NULL, NULL, NULL) == MLB_ERR_ARG);
        mlb_sds_free(s);
        mlb_clear_error();
    }
    // 3-channel renders go through the tiny VAE: a 64x64 image -> 8x8 latent; finite, nonzero gradient
    {
        mlb_sds* s = NULL;
        REQUIRE(mlb_sds_create(u, vae, 0.18215f, ac, 0, NULL, &s) == MLB_OK);
        REQUIRE(mlb_sds_set_cond(s, 0, cond, Tc) == MLB_OK && mlb_sds_set_uncond(s, unc, Tc) == MLB_OK);
        size_t ni = (size_t)3 * 64 * 64;
        float *img = malloc(ni * sizeof(float)), *gi = calloc(ni, sizeof(float));
        REQUIRE(img && gi);
        mlb_rng_fill_uniform(img, ni, 6, 1, 0, 0, 1);
        mlb_sds_input in = {img, 1, 3, 64, 64, NULL, 3, NULL, NULL, 0, 0};
        float loss = -1;
        CHECK(mlb_sds_step(s, NULL, &in, gi, &loss, NULL) == MLB_OK);
        double nrm = 0;
        int finite = 1;
        for (size_t i = 0; i < ni; i++) { finite &= isfinite(gi[i]) != 0; nrm += (double)gi[i] * gi[i]; }
        CHECK(finite && nrm > 0 && loss > 0);
        free(img); free(gi);
        mlb_sds_free(s);
    }
    free(z); free(noise); free(g); free(want); free(cond); free(unc); free(gl);
    mlb_vae_free(vae);
    mlb_unet_free(u);
}

static void remove_tmp(void) {
    const char* names[] = {"unet1.diffusers.safetensors", "unet1.diffusers.config.json", "unet1.ldm.safetensors",
                           "unet2.diffusers.safetensors", "unet2.diffusers.config.json", "unet2.ldm.safetensors",
                           "err.ldm.safetensors", "err.edit.safetensors", "err.diffusers.safetensors"};
    char p[512];
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) { tmp_path(p, sizeof p, names[i]); unlink(p); }
    rmdir(tmpdir);
}

int main(void) {
    const char* base = getenv("TMPDIR");
    snprintf(tmpdir, sizeof tmpdir, "%s/mlb_sd_tiny_XXXXXX", base && *base ? base : "/tmp");
    if (!mkdtemp(tmpdir)) { printf("cannot create a temporary folder\n"); return 1; }
    RUN(names_match_the_real_keys);
    RUN(sd1_layouts_identical);
    RUN(sd2_layouts_identical);
    RUN(missing_and_misshaped_tensors_are_named);
    RUN(cfg_and_weightings_hand_computed);
    RUN(sds_step_on_latents_matches_direct);
    remove_tmp();
    return test_summary();
}
