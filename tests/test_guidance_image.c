// Image guidance (guidance_image.h): the loss against the targets (analytic value, finite
// differences of its gradient, accumulation), the stage conventions, and the views a step draws
// (distinct, deterministic, uniform, the targets' own cameras and lights).
#include "matlaber/geometry_fit.h"
#include "matlaber/goblet.h"
#include "matlaber/guidance_image.h"
#include "matlaber/render.h"
#include "test.h"

enum { N = 5, RES = 6 };
#define PIX (RES * RES)

// A data set in memory: N views at RES, values on a 1/256 grid (so that x ± 1/256 is exact in float).
static void make_views(mlb_views* v, int with_normals) {
    memset(v, 0, sizeof *v);
    v->n = N; v->res = RES; v->src_size = RES; v->has_normals = with_normals;
    v->images = malloc(sizeof(float) * 4 * PIX * N);
    v->normals = with_normals ? malloc(sizeof(float) * 4 * PIX * N) : NULL;
    v->cams = calloc(N, sizeof(mlb_camera));
    v->meta.n_views = N;
    v->meta.n_envs = 2;
    v->meta.views = calloc(N, sizeof(mlb_views_entry));
    v->meta.envs = calloc(2, sizeof(mlb_views_env));
    for (int i = 0; i < 4 * PIX * N; i++) {
        v->images[i] = (float)((i * 97 + 13) % 256) / 256.0f;
        if (with_normals) v->normals[i] = (float)((i * 61 + 5) % 256) / 128.0f - 1.0f;
    }
    for (int i = 0; i < N; i++) {
        mlb_camera_orbit(&v->cams[i], 70.0 * i - 150, 10.0 * i - 5, 3, NULL, 40, 1, 0.1, 100);
        v->meta.views[i].orbit = 1;
        v->meta.views[i].env = i % 2;
        v->meta.views[i].env_rotation_deg = 30.0 * i;
    }
}

static double loss_of(mlb_guidance* g, mlb_stage stage, const mlb_view* views, int n, const float* img, float* d) {
    double L = -1;
    mlb_status s = g->loss(g, stage, 3, views, n, img, RES, RES, d, &L);
    return s ? NAN : L;
}

TEST(loss_value_and_gradient) {
    mlb_views v;
    make_views(&v, 1);
    mlb_guidance_images_config c = mlb_guidance_images_default();
    c.views_per_step = 2;
    c.w_mask = 0.5; c.w_normal = 2; c.w_rgb = 3; c.w_mask_appearance = 0.25;
    mlb_guidance* g;
    REQUIRE(mlb_guidance_images_create(&v, &c, &g) == MLB_OK);
    CHECK(strcmp(g->kind, "images") == 0 && g->n_views == 2);
    mlb_view views[2];
    REQUIRE(g->sample_views(g, MLB_STAGE_APPEARANCE, 3, views) == MLB_OK);
    // renders = targets + a constant offset per channel: the loss is known in closed form
    float* img = malloc(sizeof(float) * 4 * PIX * 2);
    float* d = calloc(4 * PIX * 2, sizeof(float));
    const double off[4] = {0.25, -0.5, 0.125, 0.375};
    for (int stage = 0; stage < 2; stage++) {
        const float* t = stage == 0 ? v.normals : v.images;
        for (int k = 0; k < 2; k++)
            for (int p = 0; p < 4 * PIX; p++) img[4 * PIX * k + p] = t[4 * PIX * views[k].target + p] + (float)off[p % 4];
        double wc = stage == 0 ? 2 : 3, wm = stage == 0 ? 0.5 : 0.25;
        double expect = wc * (off[0] * off[0] + off[1] * off[1] + off[2] * off[2]) + wm * off[3] * off[3];
        CHECK_CLOSE(loss_of(g, (mlb_stage)stage, views, 2, img, NULL), expect, 1e-6, 0);
    }
    // finite differences of the appearance loss at random renders (exact for a quadratic: the
    // perturbation 1/256 is exact in float and the loss is summed in double)
    for (int p = 0; p < 4 * PIX * 2; p++) img[p] = (float)((p * 53 + 7) % 256) / 256.0f;
    for (int stage = 0; stage < 2; stage++) {
        memset(d, 0, sizeof(float) * 4 * PIX * 2);
        loss_of(g, (mlb_stage)stage, views, 2, img, d);
        double worst = 0;
        for (int p = 0; p < 4 * PIX * 2; p += 7) {
            float x = img[p];
            const float h = 1.0f / 256;
            img[p] = x + h;
            double lp = loss_of(g, (mlb_stage)stage, views, 2, img, NULL);
            img[p] = x - h;
            double lm = loss_of(g, (mlb_stage)stage, views, 2, img, NULL);
            img[p] = x;
            double fd = (lp - lm) / (2.0 * h);
            worst = fmax(worst, fabs(fd - d[p]) / (fabs(fd) + 1e-6));
        }
        CHECK_MSG(worst < 1e-5, "stage %d: relative gradient error %g", stage, worst);
    }
    // backward accumulates
    float* d2 = malloc(sizeof(float) * 4 * PIX * 2);
    for (int p = 0; p < 4 * PIX * 2; p++) d2[p] = 1;
    memset(d, 0, sizeof(float) * 4 * PIX * 2);
    loss_of(g, MLB_STAGE_APPEARANCE, views, 2, img, d);
    loss_of(g, MLB_STAGE_APPEARANCE, views, 2, img, d2);
    int acc = 1;
    for (int p = 0; p < 4 * PIX * 2; p++) acc &= fabsf(d2[p] - (1 + d[p])) <= 1e-6f;
    CHECK(acc);
    // argument errors
    double L;
    CHECK(g->loss(g, MLB_STAGE_APPEARANCE, 0, views, 2, img, RES + 1, RES, NULL, &L) == MLB_ERR_ARG);
    mlb_view bad = views[0];
    bad.target = N;
    CHECK(g->loss(g, MLB_STAGE_APPEARANCE, 0, &bad, 1, img, RES, RES, NULL, &L) == MLB_ERR_ARG);
    img[5] = NAN;
    CHECK(g->loss(g, MLB_STAGE_APPEARANCE, 0, views, 2, img, RES, RES, NULL, &L) == MLB_ERR_NUMERIC);
    free(img); free(d); free(d2);
    mlb_guidance_free(g);
    mlb_views_free(&v);
}

// Without normal maps the geometry stage compares the masks (alpha of the colour images) only.
TEST(geometry_without_normals_uses_the_mask) {
    mlb_views v;
    make_views(&v, 0);
    mlb_guidance* g;
    REQUIRE(mlb_guidance_images_create(&v, NULL, &g) == MLB_OK);
    CHECK(g->n_views == 4);
    mlb_view views[4];
    REQUIRE(g->sample_views(g, MLB_STAGE_GEOMETRY, 0, views) == MLB_OK);
    float* img = malloc(sizeof(float) * 4 * PIX);
    for (int p = 0; p < PIX; p++) {
        for (int c = 0; c < 3; c++) img[4 * p + c] = 0.9f;   // any normal: not compared
        img[4 * p + 3] = v.images[4 * PIX * views[0].target + 4 * p + 3] + 0.5f;
    }
    float* d = calloc(4 * PIX, sizeof(float));
    CHECK_CLOSE(loss_of(g, MLB_STAGE_GEOMETRY, views, 1, img, d), 0.25, 1e-6, 0);   // w_mask 1 · 0.5²
    CHECK(d[0] == 0 && d[1] == 0 && d[2] == 0);
    CHECK_CLOSE(d[3], 2 * 0.5 / PIX, 1e-6, 0);
    free(img); free(d);
    mlb_guidance_free(g);
    mlb_views_free(&v);
}

TEST(sample_views) {
    mlb_views v;
    make_views(&v, 1);
    mlb_guidance_images_config c = mlb_guidance_images_default();
    c.views_per_step = 2;
    c.seed = 11;
    mlb_guidance *g, *g2;
    REQUIRE(mlb_guidance_images_create(&v, &c, &g) == MLB_OK);
    REQUIRE(mlb_guidance_images_create(&v, &c, &g2) == MLB_OK);
    int count[N] = {0}, differ_stage = 0, pairs[N][N] = {{0}};
    const int steps = 5000;
    for (long step = 0; step < steps; step++) {
        mlb_view a[2], b[2], s[2];
        REQUIRE(g->sample_views(g, MLB_STAGE_GEOMETRY, step, a) == MLB_OK);
        REQUIRE(g2->sample_views(g2, MLB_STAGE_GEOMETRY, step, b) == MLB_OK);   // same (seed, stage, step): same views
        REQUIRE(g->sample_views(g, MLB_STAGE_APPEARANCE, step, s) == MLB_OK);
        if (a[0].target != b[0].target || a[1].target != b[1].target) { CHECK_MSG(0, "step %ld not deterministic", step); break; }
        if (a[0].target == a[1].target) { CHECK_MSG(0, "step %ld: repeated target", step); break; }
        differ_stage += a[0].target != s[0].target || a[1].target != s[1].target;
        for (int k = 0; k < 2; k++) count[a[k].target]++;
        pairs[a[0].target][a[1].target]++;
        if (step == 17) {   // the view carries its target's camera and light
            for (int k = 0; k < 2; k++) {
                int t = a[k].target;
                CHECK(memcmp(&a[k].cam, &v.cams[t], sizeof(mlb_camera)) == 0);
                CHECK(a[k].env == t % 2 && a[k].env_rotation_deg == 30.0f * t);
                CHECK(a[k].azimuth_deg == v.cams[t].azimuth_deg && a[k].elevation_deg == v.cams[t].elevation_deg && a[k].radius == 3);
            }
        }
    }
    CHECK(differ_stage > steps / 2);   // the stages draw independently
    // uniform: each target 2/5 of the steps (binomial sd ~ 35), each ordered pair 1/20 (sd ~ 15)
    for (int t = 0; t < N; t++) CHECK_MSG(abs(count[t] - 2 * steps / N) < 200, "target %d drawn %d times", t, count[t]);
    for (int i = 0; i < N; i++)
        for (int j = 0; j < N; j++)
            if (i != j) CHECK_MSG(abs(pairs[i][j] - steps / 20) < 90, "pair (%d, %d) drawn %d times", i, j, pairs[i][j]);
    // another seed draws other views
    c.seed = 12;
    mlb_guidance* g3;
    REQUIRE(mlb_guidance_images_create(&v, &c, &g3) == MLB_OK);
    int same = 0;
    for (long step = 0; step < 100; step++) {
        mlb_view a[2], b[2];
        g->sample_views(g, MLB_STAGE_GEOMETRY, step, a);
        g3->sample_views(g3, MLB_STAGE_GEOMETRY, step, b);
        same += a[0].target == b[0].target && a[1].target == b[1].target;
    }
    CHECK(same < 30);   // 1/20 expected
    // views_per_step >= n: every view, in order
    c.views_per_step = 50;
    mlb_guidance* all;
    REQUIRE(mlb_guidance_images_create(&v, &c, &all) == MLB_OK);
    CHECK(all->n_views == N);
    mlb_view w[N];
    REQUIRE(all->sample_views(all, MLB_STAGE_APPEARANCE, 9, w) == MLB_OK);
    for (int i = 0; i < N; i++) CHECK(w[i].target == i);
    CHECK(all->sample_views(all, MLB_STAGE_APPEARANCE, -1, w) == MLB_ERR_ARG);
    c.views_per_step = 0;
    mlb_guidance* none;
    CHECK(mlb_guidance_images_create(&v, &c, &none) == MLB_ERR_ARG && none == NULL);
    mlb_guidance_free(g); mlb_guidance_free(g2); mlb_guidance_free(g3); mlb_guidance_free(all);
    mlb_views_free(&v);
}

// End to end with a rendered data set: renders of the very goblet the data set shows have
// (almost) zero loss in both stages, renders of another shape do not.
TEST(goblet_data_set) {
    const char* dir = test_tmpdir("guidance_goblet");
    REQUIRE(dir);
    mlb_mesh m, sphere;
    REQUIRE(mlb_goblet_mesh(&m, 32) == MLB_OK);
    REQUIRE(mlb_mesh_uv_sphere(&sphere, 0.7f, 32, 16) == MLB_OK);
    float* k = malloc(sizeof(float) * 7 * m.n_verts);
    mlb_goblet_materials(&m, k);
    const char* envs[] = {"overcast"};
    mlb_views_render_config c = mlb_views_render_default();
    c.mesh = &m; c.k = k; c.n_views = 3; c.res = 24; c.supersample = 1; c.cube = 64; c.envs = envs; c.n_envs = 1;
    REQUIRE(mlb_views_render(dir, &c, NULL) == MLB_OK);
    mlb_views v;
    REQUIRE(mlb_views_load(&v, dir, 0) == MLB_OK);
    mlb_guidance* g;
    mlb_guidance_images_config gc = mlb_guidance_images_default();
    gc.views_per_step = 2;
    gc.w_mask_appearance = 1;
    REQUIRE(mlb_guidance_images_create(&v, &gc, &g) == MLB_OK);
    mlb_view views[2];
    REQUIRE(g->sample_views(g, MLB_STAGE_GEOMETRY, 4, views) == MLB_OK);
    size_t P = 24 * 24;
    float* img = malloc(sizeof(float) * 4 * P * 2);
    float* lin = malloc(sizeof(float) * 4 * P);
    double L_same, L_other, L_app;
    for (int i = 0; i < 2; i++) REQUIRE(mlb_geofit_render_mesh(NULL, img + 4 * P * i, &m, &views[i].cam, 24, 1) == MLB_OK);
    REQUIRE(g->loss(g, MLB_STAGE_GEOMETRY, 4, views, 2, img, 24, 24, NULL, &L_same) == MLB_OK);
    for (int i = 0; i < 2; i++) REQUIRE(mlb_geofit_render_mesh(NULL, img + 4 * P * i, &sphere, &views[i].cam, 24, 1) == MLB_OK);
    REQUIRE(g->loss(g, MLB_STAGE_GEOMETRY, 4, views, 2, img, 24, 24, NULL, &L_other) == MLB_OK);
    printf("  geometry loss: the goblet %.3g, a sphere %.3g\n", L_same, L_other);
    CHECK(L_same < 1e-8);       // 16-bit normal maps
    CHECK(L_other > 0.02);
    // appearance: the view's own light and rotation
    mlb_envmap em = {0};
    mlb_envlight el = {0};
    mlb_envlight_options lo = {.face_size = 64};
    REQUIRE(mlb_views_open_env(&v, 0, &em, 0) == MLB_OK);
    REQUIRE(mlb_envlight_build(&el, &em, &lo) == MLB_OK);
    REQUIRE(g->sample_views(g, MLB_STAGE_APPEARANCE, 4, views) == MLB_OK);
    for (int i = 0; i < 2; i++) {
        REQUIRE(views[i].env == 0);
        float r = views[i].env_rotation_deg * (float)M_PI / 180;
        mlb_envmap_set_rotation(&em, r);
        mlb_envlight_set_rotation(&el, r);
        mlb_render_params p;
        memset(&p, 0, sizeof p);
        p.mesh = &m; p.k = k; p.light = &el; p.env = &em; p.background = MLB_BG_COLOR; p.camera = views[i].cam;
        p.width = p.height = 24; p.supersample = 1; p.fresnel = MLB_FRESNEL_PAPER;
        REQUIRE(mlb_render_shaded(&p, lin) == MLB_OK);
        mlb_views_linear_to_target(img + 4 * P * i, lin, P);
    }
    REQUIRE(g->loss(g, MLB_STAGE_APPEARANCE, 4, views, 2, img, 24, 24, NULL, &L_app) == MLB_OK);
    printf("  appearance loss of the goblet under its own light: %.3g\n", L_app);
    CHECK(L_app < 4 * (1.0 / 255) * (1.0 / 255));   // 8-bit quantisation of 4 channels
    mlb_envmap_free(&em);
    mlb_envlight_free(&el);
    free(img); free(lin); free(k);
    mlb_guidance_free(g);
    mlb_views_free(&v);
    mlb_mesh_free(&m);
    mlb_mesh_free(&sphere);
}

int main(void) {
    RUN(loss_value_and_gradient);
    RUN(geometry_without_normals_uses_the_mask);
    RUN(sample_views);
    RUN(goblet_data_set);
    return test_summary();
}
