// The SDS guidance (guidance_sds.h) and the orbit cameras (cameras.h), on a tiny random UNet and VAE
// the test writes itself (no ../shared/data): the area resize (box averages, exact adjoint), the
// cameras (ranges, a pure function of (seed, stage, step, view), jitter, environments), and the
// guidance's loss and image gradient against a direct mlb_sds_step on the converted images in each
// of its three phases (geometry latents, geometry normal map through the VAE, appearance colour),
// view-dependent prompts chosen by azimuth, accumulation, errors; and the same calls on a table
// whose buffers the host cannot touch (guarded_table.h), giving the host call's bits.
#include <stdint.h>
#include <unistd.h>
#include "matlaber/cameras.h"
#include "matlaber/guidance_sds.h"
#include "matlaber/rng.h"
#include "matlaber/schedule.h"
#include "matlaber/unet_random.h"
#include "matlaber/vae.h"
#include "test.h"
#include "guarded_table.h"
#include "tiny_sds_fixture.h"

static char tmpdir[256];

// ---- area resize -------------------------------------------------------------------------------------
TEST(area_resize_values_and_adjoint) {
    // integer factor: 4x6 -> 2x3 (2x2 boxes), C = 2, n = 2
    enum { n = 2, H = 4, W = 6, C = 2 };
    float src[n * H * W * C], dst[n * C * 2 * 3];
    for (int i = 0; i < n * H * W * C; i++) src[i] = (float)(i % 17) - 3.0f * (i % 5);
    mlb_area_resize_nhwc_to_nchw(dst, src, n, H, W, C, 2, 3);
    int bad = 0;
    for (int b = 0; b < n; b++)
        for (int c = 0; c < C; c++)
            for (int y = 0; y < 2; y++)
                for (int x = 0; x < 3; x++) {
                    double s = 0;
                    for (int dy = 0; dy < 2; dy++)
                        for (int dx = 0; dx < 2; dx++) s += src[((b * H + 2 * y + dy) * W + 2 * x + dx) * C + c];
                    bad += fabs(dst[((b * C + c) * 2 + y) * 3 + x] - s / 4) > 1e-6;
                }
    CHECK(bad == 0);
    // non-integer 5 -> 3: output 1 averages rows 1..3 ([floor(5/3), ceil(10/3)) = [1, 4))
    float col[5] = {1, 2, 4, 8, 16}, out[3];
    mlb_area_resize_nhwc_to_nchw(out, col, 1, 5, 1, 1, 3, 1);
    CHECK_CLOSE(out[0], 1.5, 1e-7, 0);
    CHECK_CLOSE(out[1], 14.0 / 3.0, 1e-6, 0);
    CHECK_CLOSE(out[2], 12.0, 1e-7, 0);
    // adjoint: <R x, y> = <x, R^T y> for random x, y (sizes 37x29 -> 8x11, C = 4), and += semantics
    const int h2 = 37, w2 = 29, oh = 8, ow = 11, C4 = 4;
    size_t nx = (size_t)2 * h2 * w2 * C4, ny = (size_t)2 * C4 * oh * ow;
    float *x = malloc(nx * 4), *rx = malloc(ny * 4), *y = malloc(ny * 4), *rty = calloc(nx, 4);
    REQUIRE(x && rx && y && rty);
    mlb_rng_fill_normal(x, nx, 3, 1, 0, 0, 1);
    mlb_rng_fill_normal(y, ny, 3, 2, 0, 0, 1);
    mlb_area_resize_nhwc_to_nchw(rx, x, 2, h2, w2, C4, oh, ow);
    for (size_t i = 0; i < nx; i++) rty[i] = 1.0f;
    mlb_area_resize_nhwc_to_nchw_backward(rty, y, 2, h2, w2, C4, oh, ow);
    double a = 0, b2 = 0;
    for (size_t i = 0; i < ny; i++) a += (double)rx[i] * y[i];
    for (size_t i = 0; i < nx; i++) b2 += (double)x[i] * (rty[i] - 1.0f);
    printf("  <Rx, y> = %.9g, <x, R^T y> = %.9g\n", a, b2);
    CHECK_CLOSE(a, b2, 1e-5, 1e-5);
    free(x); free(rx); free(y); free(rty);
}

// ---- cameras -----------------------------------------------------------------------------------------
TEST(orbit_cameras) {
    mlb_orbit_config c = mlb_orbit_default();
    c.n_envs = 3;
    double az_lo = 1e9, az_hi = -1e9, el_lo = 1e9, el_hi = -1e9, f_lo = 1e9, f_hi = -1e9, jmax = 0, rot_hi = 0;
    int env_count[3] = {0, 0, 0};
    for (long step = 0; step < 300; step++)
        for (int v = 0; v < 3; v++) {
            mlb_view a, b;
            REQUIRE(mlb_orbit_sample(&a, &c, 5, MLB_STAGE_APPEARANCE, step, v) == MLB_OK);
            REQUIRE(mlb_orbit_sample(&b, &c, 5, MLB_STAGE_APPEARANCE, step, v) == MLB_OK);
            CHECK(memcmp(&a, &b, sizeof a) == 0);
            az_lo = fmin(az_lo, a.azimuth_deg); az_hi = fmax(az_hi, a.azimuth_deg);
            el_lo = fmin(el_lo, a.elevation_deg); el_hi = fmax(el_hi, a.elevation_deg);
            f_lo = fmin(f_lo, a.cam.fovy_deg); f_hi = fmax(f_hi, a.cam.fovy_deg);
            CHECK(a.env >= 0 && a.env < 3 && a.target == -1);
            if (a.env >= 0 && a.env < 3) env_count[a.env]++;
            CHECK(a.env_rotation_deg >= 0 && a.env_rotation_deg < 360);
            rot_hi = fmax(rot_hi, a.env_rotation_deg);
            CHECK(a.cam.aspect == 1.0 && a.radius == 3.0);
            // eye − target = radius · (cos el sin az, sin el, cos el cos az); the target is jittered in
            // the image plane only (perpendicular to the view direction), by at most √2·0.05
            double azr = a.azimuth_deg * M_PI / 180, elr = a.elevation_deg * M_PI / 180;
            double d[3] = {cos(elr) * sin(azr), sin(elr), cos(elr) * cos(azr)};
            double dot = 0, len = 0;
            for (int k = 0; k < 3; k++) {
                CHECK(fabs(a.cam.eye[k] - a.cam.target[k] - 3 * d[k]) < 1e-9);
                dot += a.cam.target[k] * d[k];
                len += a.cam.target[k] * a.cam.target[k];
            }
            CHECK(fabs(dot) < 1e-9);
            jmax = fmax(jmax, sqrt(len));
        }
    printf("  azimuth [%.1f, %.1f], elevation [%.1f, %.1f], fovy [%.2f, %.2f], jitter max %.4f, envs %d/%d/%d\n", az_lo, az_hi,
           el_lo, el_hi, f_lo, f_hi, jmax, env_count[0], env_count[1], env_count[2]);
    CHECK(az_lo >= -180 && az_lo < -175 && az_hi <= 180 && az_hi > 175);
    CHECK(el_lo >= -10 && el_lo < -9 && el_hi <= 45 && el_hi > 44);
    CHECK(f_lo >= 25.7 && f_lo < 26.5 && f_hi <= 45 && f_hi > 44);
    CHECK(jmax > 0.03 && jmax <= 0.05 * sqrt(2.0) + 1e-12);
    CHECK(env_count[0] > 200 && env_count[1] > 200 && env_count[2] > 200 && rot_hi > 350);
    // other stage / step / view / seed: other cameras
    mlb_view a, b;
    REQUIRE(mlb_orbit_sample(&a, &c, 5, MLB_STAGE_GEOMETRY, 7, 1) == MLB_OK);
    REQUIRE(mlb_orbit_sample(&b, &c, 5, MLB_STAGE_APPEARANCE, 7, 1) == MLB_OK);
    CHECK(a.azimuth_deg != b.azimuth_deg);
    REQUIRE(mlb_orbit_sample(&b, &c, 5, MLB_STAGE_GEOMETRY, 8, 1) == MLB_OK);
    CHECK(a.azimuth_deg != b.azimuth_deg);
    REQUIRE(mlb_orbit_sample(&b, &c, 5, MLB_STAGE_GEOMETRY, 7, 2) == MLB_OK);
    CHECK(a.azimuth_deg != b.azimuth_deg);
    REQUIRE(mlb_orbit_sample(&b, &c, 6, MLB_STAGE_GEOMETRY, 7, 1) == MLB_OK);
    CHECK(a.azimuth_deg != b.azimuth_deg);
    // the single-environment ablation; no jitter: the target is the origin
    c.fixed_env = 1;
    c.jitter = 0;
    for (int s = 0; s < 20; s++) {
        REQUIRE(mlb_orbit_sample(&a, &c, 5, MLB_STAGE_APPEARANCE, s, 0) == MLB_OK);
        CHECK(a.env == 0 && a.env_rotation_deg == 0.0f);
        CHECK(a.cam.target[0] == 0 && a.cam.target[1] == 0 && a.cam.target[2] == 0);
    }
    // errors
    c.n_envs = 0;
    CHECK(mlb_orbit_sample(&a, &c, 5, 0, 0, 0) == MLB_ERR_ARG && strstr(mlb_last_error(), "n_envs"));
    c = mlb_orbit_default();
    c.fovy_min = 50;
    CHECK(mlb_orbit_sample(&a, &c, 5, 0, 0, 0) == MLB_ERR_ARG && strstr(mlb_last_error(), "fovy"));
    c = mlb_orbit_default();
    CHECK(mlb_orbit_sample(&a, &c, 5, 0, -1, 0) == MLB_ERR_ARG);
    mlb_clear_error();
}

// ---- the guidance ------------------------------------------------------------------------------------
static double max_rel_diff(const float* a, const float* b, size_t n) {
    double m = 0, s = 0;
    for (size_t i = 0; i < n; i++) { m = fmax(m, fabs((double)a[i] - b[i])); s = fmax(s, fabs(b[i])); }
    return m / (s > 0 ? s : 1);
}

// The direct computation of one phase: convert images as the guidance documents, mlb_sds_step on a
// fresh SDS object (same options and seed), convert the gradient back.
static int direct(const fixture* f, const mlb_guidance_sds_config* c, int stage, int latent, long step, const int* vids,
                  const float* images, int n, int H, float* dimages, float* loss) {
    mlb_sds_options o = stage ? c->appearance_opt : c->geometry_opt;
    o.seed = c->seed * 2 + (uint64_t)stage;
    if (latent) o.weighting = MLB_SDS_W_DREAMFUSION;
    mlb_sds* s = make_sds(f, stage, &o);
    if (!s) return 0;
    int C = latent ? 4 : 3, h = latent ? 64 : H;
    size_t P = (size_t)h * h, HW = (size_t)H * H, N = (size_t)n * C * P;
    float *x = malloc(N * 4), *dx = calloc(N, 4);
    for (int b = 0; b < n; b++)
        for (int ch = 0; ch < C; ch++)
            for (int y = 0; y < h; y++)
                for (int xx = 0; xx < h; xx++) {
                    float v;
                    if (latent) {   // H = 2·64: 2x2 box average
                        double sum = 0;
                        for (int dy = 0; dy < 2; dy++)
                            for (int dq = 0; dq < 2; dq++) sum += images[(((size_t)b * H + 2 * y + dy) * H + 2 * xx + dq) * 4 + ch];
                        v = (float)(sum * 0.25);
                    } else {
                        const float* p = images + (((size_t)b * H + y) * H + xx) * 4;
                        v = stage == MLB_STAGE_GEOMETRY ? 0.5f * (p[ch] + p[3]) : p[ch];
                    }
                    x[((size_t)b * C + ch) * P + (size_t)y * h + xx] = v;
                }
    mlb_sds_input in = {x, n, C, h, h, vids, step, NULL, NULL, 0, 0};
    int ok = mlb_sds_step(s, NULL, &in, dx, loss, NULL) == MLB_OK;
    memset(dimages, 0, sizeof(float) * n * HW * 4);
    for (int b = 0; ok && b < n; b++)
        for (int ch = 0; ch < C; ch++)
            for (int y = 0; y < h; y++)
                for (int xx = 0; xx < h; xx++) {
                    float g = dx[((size_t)b * C + ch) * P + (size_t)y * h + xx];
                    if (latent) {
                        for (int dy = 0; dy < 2; dy++)
                            for (int dq = 0; dq < 2; dq++)
                                dimages[(((size_t)b * H + 2 * y + dy) * H + 2 * xx + dq) * 4 + ch] += g * 0.25f;
                    } else if (stage == MLB_STAGE_GEOMETRY) {
                        float* d = dimages + (((size_t)b * H + y) * H + xx) * 4;
                        d[ch] += 0.5f * g;
                        d[3] += 0.5f * g;
                    } else
                        dimages[(((size_t)b * H + y) * H + xx) * 4 + ch] += g;
                }
    free(x); free(dx);
    mlb_sds_free(s);
    return ok;
}

TEST(sds_guidance_matches_direct_step) {
    static fixture f;
    REQUIRE(fixture_init(&f, tmpdir));

    mlb_guidance_sds_config c = mlb_guidance_sds_default();
    CHECK(c.geometry_opt.t_min == 20 && c.geometry_opt.t_max == 500 && c.appearance_opt.t_max == 980);
    CHECK(!strcmp(c.negative_geometry, "low quality"));
    CHECK(!strcmp(c.negative_appearance, "shadow, oversaturated, low quality, unrealistic"));
    c.views = 3;
    c.latent_iters = 10;
    c.seed = 17;
    c.n_envs = 2;
    c.geometry_opt.guidance_scale = 7.5f;
    c.appearance_opt.guidance_scale = 7.5f;
    mlb_guidance* g = NULL;
    REQUIRE(mlb_guidance_sds_create_from(make_sds(&f, 0, NULL), make_sds(&f, 1, NULL), &c, &g) == MLB_OK);
    CHECK(!strcmp(g->kind, "sds") && g->n_views == 3);

    // cameras: the orbit cameras of (seed, stage, step, view)
    mlb_view views[3], again[3];
    REQUIRE(g->sample_views(g, MLB_STAGE_APPEARANCE, 4, views) == MLB_OK);
    REQUIRE(g->sample_views(g, MLB_STAGE_APPEARANCE, 4, again) == MLB_OK);
    CHECK(memcmp(views, again, sizeof views) == 0);
    mlb_orbit_config oc = c.orbit;
    oc.n_envs = 2;
    for (int v = 0; v < 3; v++) {
        mlb_view w;
        REQUIRE(mlb_orbit_sample(&w, &oc, 17, MLB_STAGE_APPEARANCE, 4, v) == MLB_OK);
        CHECK(memcmp(&w, &views[v], sizeof w) == 0);
        CHECK(views[v].env >= 0 && views[v].env < 2);
    }
    // fixed azimuths and elevations: front, side, back prompts (the third view overhead in phase 1)
    views[0].azimuth_deg = 10;
    views[1].azimuth_deg = -100;
    views[2].azimuth_deg = 170;
    views[0].elevation_deg = 30;
    views[1].elevation_deg = -5;
    int vids[3] = {MLB_SDS_VIEW_FRONT, MLB_SDS_VIEW_SIDE, MLB_SDS_VIEW_BACK};
    const int wrong[3] = {MLB_SDS_VIEW_BACK, MLB_SDS_VIEW_SIDE, MLB_SDS_VIEW_FRONT};

    // [n, 128, 128, 4] for the latent phase, [n, 64, 64, 4] for the VAE phases: masks in [0, 1],
    // normals in [-1, 1] times the mask, colours in [0, 1] times the mask
    const int n = 3;
    struct { const char* name; int stage, latent, H; long step; } ph[3] = {
        {"geometry latents (step 3 < 10)", MLB_STAGE_GEOMETRY, 1, 128, 3},
        {"geometry normal map via VAE (step 12)", MLB_STAGE_GEOMETRY, 0, 64, 12},
        {"appearance colour via VAE (step 5)", MLB_STAGE_APPEARANCE, 0, 64, 5},
    };
    for (int k = 0; k < 3; k++) {
        int H = ph[k].H;
        size_t N = (size_t)n * H * H * 4;
        float *img = malloc(N * 4), *dg = calloc(N, 4), *dd = malloc(N * 4), *dw = malloc(N * 4);
        REQUIRE(img && dg && dd && dw);
        for (size_t i = 0; i < N / 4; i++) {
            float m = mlb_rng_uniform(8, 1 + k, i);
            m = m < 0.3f ? 0.0f : m > 0.6f ? 1.0f : m;
            for (int ch = 0; ch < 3; ch++) {
                float u = mlb_rng_uniform(8, 10 + 3 * k + ch, i);
                img[4 * i + ch] = m * (ph[k].stage == MLB_STAGE_GEOMETRY ? 2 * u - 1 : u);
            }
            img[4 * i + 3] = m;
        }
        views[2].elevation_deg = k == 1 ? 70 : 40;
        vids[2] = k == 1 ? MLB_SDS_VIEW_OVERHEAD : MLB_SDS_VIEW_BACK;
        double loss = -1, loss2 = -1;
        float want_loss = -2, wrong_loss = -3;
        REQUIRE(g->loss(g, ph[k].stage, ph[k].step, views, n, img, H, H, dg, &loss) == MLB_OK);
        {   // the same call on a table whose buffers the host cannot touch: the images stay there, and
            // the loss and gradient are the host call's bits
            const mlb_backend* tb = guarded_table();
            float *t_img = NULL, *t_dg = NULL, *back = calloc(N, 4);
            double tloss = -1;
            long ops = guard_ops;
            REQUIRE(back && tb->alloc(&t_img, N) == MLB_OK && tb->alloc(&t_dg, N) == MLB_OK);
            REQUIRE(tb->upload(t_img, img, N) == MLB_OK && tb->zero(t_dg, N) == MLB_OK);
            mlb_status ts = g->loss_on(g, tb, ph[k].stage, ph[k].step, views, n, t_img, H, H, t_dg, &tloss);
            if (ts) printf("  loss_on: %s\n", mlb_last_error());
            REQUIRE(ts == MLB_OK);
            REQUIRE(tb->download(back, t_dg, N) == MLB_OK);
            printf("  %s on the guarded table: %ld ops, loss %s, gradient %s\n", ph[k].name, guard_ops - ops,
                   tloss == loss ? "the same" : "differs", memcmp(back, dg, N * 4) ? "differs" : "the same bits");
            // the VAE's and the UNet's ops went through the table too (a UNet forward alone is ~250)
            CHECK(tloss == loss && memcmp(back, dg, N * 4) == 0 && guard_ops - ops > 200);
            tb->release(t_img);
            tb->release(t_dg);
            free(back);
        }
        REQUIRE(direct(&f, &c, ph[k].stage, ph[k].latent, ph[k].step, vids, img, n, H, dd, &want_loss));
        // (the view prompts are chosen by the same code in every phase: the wrong ones tried once)
        if (k == 0) REQUIRE(direct(&f, &c, ph[k].stage, ph[k].latent, ph[k].step, wrong, img, n, H, dw, &wrong_loss));
        double d = max_rel_diff(dg, dd, N), dwr = k == 0 ? max_rel_diff(dw, dd, N) : 1, gmax = 0;
        for (size_t i = 0; i < N; i++) gmax = fmax(gmax, fabs(dd[i]));
        printf("  %s: loss %.6g (direct %.6g), max|grad| %.3g, rel. diff %.2g", ph[k].name, loss, want_loss, gmax, d);
        if (k == 0) printf("; wrong view prompts: rel. diff %.2g", dwr);
        printf("\n");
        CHECK(gmax > 0);
        CHECK(d <= 1e-6);
        CHECK_CLOSE(loss, want_loss, 1e-6, 0);
        CHECK(dwr > 1e-3);   // the prompts matter: the test can tell them apart
        // the alpha channel gets a gradient in the geometry phases only
        double a3 = 0;
        for (size_t i = 3; i < N; i += 4) a3 = fmax(a3, fabs(dg[i]));
        CHECK(ph[k].stage == MLB_STAGE_GEOMETRY ? a3 > 0 : a3 == 0);
        if (k != 2) { free(img); free(dg); free(dd); free(dw); continue; }
        // += semantics: a second call doubles; loss only without dimages
        REQUIRE(g->loss(g, ph[k].stage, ph[k].step, views, n, img, H, H, dg, &loss2) == MLB_OK);
        int twice = 1;
        for (size_t i = 0; i < N; i++) twice &= fabs(dg[i] - 2 * dd[i]) <= 2e-6 * gmax;
        CHECK(twice && loss2 == loss);
        REQUIRE(g->loss(g, ph[k].stage, ph[k].step, views, n, img, H, H, NULL, &loss2) == MLB_OK);
        CHECK(loss2 == loss);
        free(img); free(dg); free(dd); free(dw);
    }
    // errors: too many views, a VAE-phase image that is not a multiple of 64
    float* img = calloc((size_t)3 * 40 * 40 * 4, 4);
    double l;
    CHECK(g->loss(g, MLB_STAGE_APPEARANCE, 0, views, 3, img, 40, 40, NULL, &l) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "appearance stage") != NULL);
    CHECK(g->loss(g, MLB_STAGE_APPEARANCE, 0, views, 65, img, 40, 40, NULL, &l) == MLB_ERR_ARG);
    free(img);
    mlb_guidance_free(g);
    // view prompts off: every view gets the plain prompt's embedding (view NONE), whatever its camera
    {
        mlb_guidance_sds_config plain = c;
        plain.view_prompts = 0;
        REQUIRE(mlb_guidance_sds_create_from(make_sds(&f, 0, NULL), make_sds(&f, 1, NULL), &plain, &g) == MLB_OK);
        const int H = 64, none[3] = {MLB_SDS_VIEW_NONE, MLB_SDS_VIEW_NONE, MLB_SDS_VIEW_NONE};
        size_t N = (size_t)3 * H * H * 4;
        float *im = malloc(N * 4), *dg = calloc(N, 4), *dd = malloc(N * 4);
        REQUIRE(im && dg && dd);
        for (size_t i = 0; i < N; i++) im[i] = (i & 3) == 3 ? 1.0f : mlb_rng_uniform(8, 40, i);
        double loss = -1;
        float want = -2;
        REQUIRE(g->loss(g, MLB_STAGE_APPEARANCE, 5, views, 3, im, H, H, dg, &loss) == MLB_OK);
        REQUIRE(direct(&f, &plain, MLB_STAGE_APPEARANCE, 0, 5, none, im, 3, H, dd, &want));
        CHECK(max_rel_diff(dg, dd, N) <= 1e-6);
        CHECK_CLOSE(loss, want, 1e-6, 0);
        REQUIRE(direct(&f, &plain, MLB_STAGE_APPEARANCE, 0, 5, vids, im, 3, H, dd, &want));
        CHECK(max_rel_diff(dg, dd, N) > 1e-3);   // the view prompts would have differed
        free(im); free(dg); free(dd);
        mlb_guidance_free(g);
    }
    mlb_guidance_sds_config bad = c;
    bad.views = 0;
    g = (mlb_guidance*)1;
    CHECK(mlb_guidance_sds_create_from(make_sds(&f, 0, NULL), make_sds(&f, 1, NULL), &bad, &g) == MLB_ERR_ARG && !g);
    bad = c;
    bad.geometry_opt.t_max = 1000;
    CHECK(mlb_guidance_sds_create_from(make_sds(&f, 0, NULL), make_sds(&f, 1, NULL), &bad, &g) == MLB_ERR_ARG && !g);
    CHECK(mlb_guidance_sds_create(NULL, &c, &g) == MLB_ERR_ARG);
    mlb_clear_error();
    fixture_free(&f);
}

int main(void) {
    const char* base = getenv("TMPDIR");
    snprintf(tmpdir, sizeof tmpdir, "%s/mlb_guidance_sds_XXXXXX", base && *base ? base : "/tmp");
    if (!mkdtemp(tmpdir)) { printf("cannot create a temporary folder\n"); return 1; }
    RUN(area_resize_values_and_adjoint);
    RUN(orbit_cameras);
    RUN(sds_guidance_matches_direct_step);
    rmdir(tmpdir);
    return test_summary();
}
