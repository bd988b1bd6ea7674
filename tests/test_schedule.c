// The noise schedule and the DDIM scheduler against ../shared/data/sd_reference (ref_schedule,
// ref_ddim_sd1: the DDIM update alone, fed the reference's guided eps).
#include "test.h"
#include "matlaber/sd_model.h"
#include "matlaber/safetensors.h"
#include "matlaber/schedule.h"

static mlb_safetensors* open_ref(const char* file) {
    const char* d = test_shared_data();
    if (!d) return NULL;
    char p[4096];
    snprintf(p, sizeof p, "%s/sd_reference/%s", d, file);
    mlb_safetensors* st = NULL;
    if (mlb_st_open(&st, p) != MLB_OK) return NULL;
    return st;
}

static void read_f64(const mlb_safetensors* st, const char* name, double* out, size_t n) {
    const mlb_st_tensor* t = mlb_st_find(st, name);
    if (t && t->dtype == MLB_DT_F64 && t->nelem == n) memcpy(out, t->data, n * sizeof(double));
    else for (size_t i = 0; i < n; i++) out[i] = NAN;
}

TEST(alphas_cumprod_vs_reference) {
    mlb_safetensors* st = open_ref("ref_schedule.safetensors");
    if (!st) SKIP("no sd_reference/ref_schedule.safetensors");
    static double ac[1000], betas[1000], rac[1000], rbetas[1000];
    static float ac32[1000], rac32[1000];
    REQUIRE(mlb_schedule_alphas_cumprod(ac, betas, 1000, MLB_SD_BETA_START, MLB_SD_BETA_END) == MLB_OK);
    REQUIRE(mlb_schedule_alphas_cumprod_f32(ac32, 1000, MLB_SD_BETA_START, MLB_SD_BETA_END) == MLB_OK);
    read_f64(st, "alphas_cumprod_f64", rac, 1000);
    read_f64(st, "betas_f64", rbetas, 1000);
    REQUIRE(mlb_st_read_f32(st, "alphas_cumprod_diffusers_f32", rac32, 1000) == MLB_OK);
    double eb = 0, ea = 0, e32 = 0;
    for (int i = 0; i < 1000; i++) {
        eb = fmax(eb, fabs(betas[i] - rbetas[i]) / rbetas[i]);
        ea = fmax(ea, fabs(ac[i] - rac[i]) / rac[i]);
        e32 = fmax(e32, fabs((double)ac32[i] - rac32[i]) / rac32[i]);
    }
    printf("  max rel err: betas %.3g, alphas_cumprod f64 %.3g, f32 (diffusers) %.3g\n", eb, ea, e32);
    CHECK(eb <= 1e-14);
    CHECK(ea <= 1e-13);
    CHECK(e32 <= 3e-6);   // not bit-exact: torch's vectorised float32 kernels round differently
    mlb_st_close(st);
}

TEST(schedule_bad_args) {
    double ac[4];
    CHECK(mlb_schedule_alphas_cumprod(ac, NULL, 1, 0.1, 0.2) == MLB_ERR_ARG);
    CHECK(mlb_schedule_alphas_cumprod(ac, NULL, 4, 0.1, 1.5) == MLB_ERR_ARG);
    int ts[8];
    CHECK(mlb_ddim_timesteps(ts, 0, 1000, 1) == MLB_ERR_ARG);
    CHECK(mlb_ddim_timesteps(ts, 1001, 1000, 1) == MLB_ERR_ARG);
    CHECK(mlb_ddim_timesteps(ts, 1000, 1000, 1) == MLB_ERR_ARG);   // 999 + 1 = 1000 is past the end
    float x = 1, e = 0, y;
    CHECK(mlb_ddim_step(&y, NULL, &x, &e, 1, 0.0, 0.5) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "DDIM step") != NULL);
}

TEST(ddim_timesteps) {
    int ts[50];
    REQUIRE(mlb_ddim_timesteps(ts, 4, 1000, 1) == MLB_OK);
    CHECK(ts[0] == 751 && ts[1] == 501 && ts[2] == 251 && ts[3] == 1);
    CHECK(mlb_ddim_prev_timestep(1, 4, 1000) == -249);
    REQUIRE(mlb_ddim_timesteps(ts, 50, 1000, 1) == MLB_OK);
    CHECK(ts[0] == 981 && ts[49] == 1 && ts[1] == 961);
    // the most steps the sampler takes (MLB_DDIM_MAX_STEPS): every timestep 999..1, none past the end
    int all[MLB_DDIM_MAX_STEPS];
    REQUIRE(mlb_ddim_timesteps(all, MLB_DDIM_MAX_STEPS, 1000, 1) == MLB_OK);
    CHECK(all[0] == 999 && all[MLB_DDIM_MAX_STEPS - 1] == 1);
    // and the sampler says 1000 is past it before touching its arguments' contents
    float ac[1000] = {0}, x[1] = {0};
    mlb_unet u;
    memset(&u, 0, sizeof u);
    CHECK(mlb_sd_ddim_sample(&u, ac, 0, x, x, 1, x, 1, 1, 1000, 1.0f, NULL, NULL, NULL) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "DDIM steps 1000 outside 1..999") != NULL);
    mlb_safetensors* st = open_ref("ref_ddim_sd1.safetensors");
    if (!st) return;
    const mlb_st_tensor* t = mlb_st_find(st, "timesteps");
    REQUIRE(t && t->dtype == MLB_DT_I64 && t->nelem == 4);
    int64_t r[4];
    memcpy(r, t->data, sizeof r);
    REQUIRE(mlb_ddim_timesteps(ts, 4, 1000, 1) == MLB_OK);
    for (int i = 0; i < 4; i++) CHECK(ts[i] == r[i]);
    mlb_st_close(st);
}

// The DDIM update alone: latents_after_step[i] = step(latents_after_step[i-1] (noise for i = 0),
// eps_guided[i]) with diffusers' float32 alphas_cumprod (as the reference) and with our float64 ones.
TEST(ddim_step_vs_reference) {
    mlb_safetensors* st = open_ref("ref_ddim_sd1.safetensors");
    if (!st) SKIP("no sd_reference/ref_ddim_sd1.safetensors");
    enum { N = 4 * 16 * 16 };
    static float noise[N], eps[4 * N], lat[4 * N], out[N];
    REQUIRE(mlb_st_read_f32(st, "noise", noise, N) == MLB_OK);
    REQUIRE(mlb_st_read_f32(st, "debug.eps_guided", eps, 4 * N) == MLB_OK);
    REQUIRE(mlb_st_read_f32(st, "debug.latents_after_step", lat, 4 * N) == MLB_OK);
    static double ac64[1000], ac32d[1000];
    static float ac32[1000];
    REQUIRE(mlb_schedule_alphas_cumprod(ac64, NULL, 1000, MLB_SD_BETA_START, MLB_SD_BETA_END) == MLB_OK);
    REQUIRE(mlb_schedule_alphas_cumprod_f32(ac32, 1000, MLB_SD_BETA_START, MLB_SD_BETA_END) == MLB_OK);
    for (int i = 0; i < 1000; i++) ac32d[i] = ac32[i];
    int ts[4];
    REQUIRE(mlb_ddim_timesteps(ts, 4, 1000, 1) == MLB_OK);
    for (int which = 0; which < 2; which++) {
        const double* ac = which ? ac64 : ac32d;
        double maxerr = 0, maxref = 0;
        for (int s = 0; s < 4; s++) {
            const float* x = s ? lat + (size_t)(s - 1) * N : noise;
            int tp = mlb_ddim_prev_timestep(ts[s], 4, 1000);
            REQUIRE(mlb_ddim_step(out, NULL, x, eps + (size_t)s * N, N, ac[ts[s]], mlb_ddim_alpha_prev(ac, tp, 0)) ==
                    MLB_OK);
            for (int i = 0; i < N; i++) {
                maxerr = fmax(maxerr, fabs(out[i] - lat[(size_t)s * N + i]));
                maxref = fmax(maxref, fabs(lat[(size_t)s * N + i]));
            }
        }
        printf("  DDIM step (%s alphas_cumprod): max abs err %.3g (max |latent| %.3g)\n",
               which ? "float64" : "diffusers float32", maxerr, maxref);
        CHECK(maxerr <= (which ? 1e-4 : 2e-5));
    }
    mlb_st_close(st);
}

TEST(guidance_and_v_prediction) {
    float u[3] = {1, 2, 3}, c[3] = {2, 2, 1}, o[3];
    mlb_cfg_combine(o, u, c, 3, 7.5f);
    CHECK_CLOSE(o[0], 8.5, 0, 1e-6);
    CHECK_CLOSE(o[1], 2.0, 0, 1e-6);
    CHECK_CLOSE(o[2], -12.0, 0, 1e-6);
    // v = sqrt(a) eps - sqrt(1-a) x0 and x_t = sqrt(a) x0 + sqrt(1-a) eps round-trip.
    double a = 0.3;
    float x0[2] = {0.5f, -1.0f}, e[2] = {0.25f, 2.0f}, xt[2], v[2], e2[2], x02[2];
    mlb_add_noise(xt, x0, e, 2, a);
    for (int i = 0; i < 2; i++) v[i] = (float)(sqrt(a) * e[i] - sqrt(1 - a) * x0[i]);
    mlb_v_to_eps(e2, v, xt, 2, a);
    mlb_v_to_x0(x02, v, xt, 2, a);
    for (int i = 0; i < 2; i++) {
        CHECK_CLOSE(e2[i], e[i], 0, 1e-6);
        CHECK_CLOSE(x02[i], x0[i], 0, 1e-6);
    }
    // A DDIM step to ac_prev = ac_t returns x_t; the predicted x0 matches.
    float xp[2], p0[2];
    REQUIRE(mlb_ddim_step(xp, p0, xt, e, 2, a, a) == MLB_OK);
    for (int i = 0; i < 2; i++) {
        CHECK_CLOSE(xp[i], xt[i], 0, 1e-6);
        CHECK_CLOSE(p0[i], x0[i], 0, 1e-6);
    }
}

int main(void) {
    RUN(alphas_cumprod_vs_reference);
    RUN(schedule_bad_args);
    RUN(ddim_timesteps);
    RUN(ddim_step_vs_reference);
    RUN(guidance_and_v_prediction);
    return test_summary();
}
