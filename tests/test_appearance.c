// The differentiable appearance renderer: finite differences in double of the whole chain
// (material net → split-sum shading under two rotated environments → sRGB → composite →
// antialias → downsample), agreement with mlb_render_shaded for a constant material, a fit that
// recovers a constant material from renders, thread-count independence, the material maps and the
// material smoothness regulariser (value and finite differences).
#include <stdint.h>
#include "matlaber/appearance.h"
#include "matlaber/brdf.h"
#include "matlaber/geometry.h"
#include "matlaber/render.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"
#include "appearance_test_util.h"
#include "guarded_table.h"
#include "material_test_util.h"
#include "test.h"

static mlb_material_config small_config(mlb_material_mode mode) {
    mlb_material_config c = mlb_material_default();
    c.enc = (mlb_hashgrid_config){6, 2, 1024, 4, 1.6};
    c.hidden = 16;
    c.n_hidden = 2;
    c.seed = 3;
    c.mode = mode;
    return c;
}


// Direct-mode net whose output is the constant material k (last layer: zero weights, bias logit).
static void set_constant(mlb_material_net* net, const float k[7]) {
    int L = net->mlp.n_layers - 1;
    memset(net->mlp.weight[L], 0, sizeof(float) * net->mlp.dims[L] * net->mlp.dims[L + 1]);
    for (int c = 0; c < 7; c++) {
        double lo = c == 6 ? MLB_KR_MIN : 0, s = (k[c] - lo) / (1 - lo);
        net->mlp.bias[L][c] = (float)log(s / (1 - s));
    }
}

static double srgb1(double x) {
    x = x < 0 ? 0 : x > 1 ? 1 : x;
    return x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1 / 2.4) - 0.055;
}

TEST(fd_whole_chain_f64) {
    scene sc;
    REQUIRE(scene_init(&sc, 16, 8));
    printf("  mesh: %d faces, %d vertices\n", sc.mesh.n_faces, sc.mesh.n_verts);
    mlb_brdf_ae prior;
    REQUIRE(random_prior(&prior));
    for (int mode = 0; mode < 2; mode++) {
        mlb_material_config c = small_config((mlb_material_mode)mode);
        mlb_material_net_f64 net;
        REQUIRE(material_net_init_f64(&net, &c, &prior) == MLB_OK);
        randomize_f64(&net, 21);
        enum { n = 2, res = 32 };
        int ss = mode ? 1 : 2;   // latent at ss 2 (downsample path), direct at ss 1
        mlb_view views[n];
        make_views(views, n);
        size_t m = (size_t)n * res * res * 4;
        double* img = malloc(sizeof(double) * m);
        double* w = malloc(sizeof(double) * m);
        for (size_t i = 0; i < m; i++) w[i] = mlb_rng_normal_f64(5, 0, i);
        mlb_appearance_f64 app;
        memset(&app, 0, sizeof app);
        REQUIRE(mlb_appearance_render_f64(&app, &net, &sc.mesh, sc.ptr, views, n, res, ss, img, 1) == MLB_OK);
        int np;
        mlb_appearance_points_f64(&app, &np);
        printf("  %s: %d samples\n", mlb_material_mode_name(c.mode), np);
        CHECK(np > 200);
        double cov = 0, bright = 0;
        for (size_t i = 0; i < m / 4; i++) { cov += img[4 * i + 3]; bright += img[4 * i]; }
        CHECK(cov > 100 && bright > 10);   // something visible and lit
        material_net_zero_grad_f64(&net);
        REQUIRE(mlb_appearance_backward_f64(&app, &net, w) == MLB_OK);
        // the 6 table entries and 6 MLP values of largest gradient
        size_t pick[12];
        int np2 = 12;
        test_top_grads(net.grads, net.n_enc, net.n_params, 6, pick);
        const double h = 1e-6;
        double worst = 0;
        for (int q = 0; q < np2; q++) {
            size_t i = pick[q];
            double keep = net.params[i], L[2];
            for (int sgn = 0; sgn < 2; sgn++) {
                net.params[i] = keep + (sgn ? -h : h);
                REQUIRE(mlb_appearance_render_f64(&app, &net, &sc.mesh, sc.ptr, views, n, res, ss, img, 0) == MLB_OK);
                L[sgn] = 0;
                for (size_t j = 0; j < m; j++) L[sgn] += w[j] * img[j];
            }
            net.params[i] = keep;
            double fd = (L[0] - L[1]) / (2 * h), g = net.grads[i];
            double err = fabs(fd - g) / (fabs(fd) + 1e-12);
            if (err > worst) worst = err;
            CHECK_MSG(fabs(fd - g) <= 1e-6 * fabs(fd) + 1e-7, "%s param %zu: fd %.10g, backward %.10g", mlb_material_mode_name(c.mode),
                      i, fd, g);
        }
        printf("  %s: worst relative error %.2e over %d parameters\n", mlb_material_mode_name(c.mode), worst, np2);
        mlb_appearance_free_f64(&app);
        material_net_free_f64(&net);
        free(img);
        free(w);
    }
    brdf_ae_free(&prior);
    scene_free(&sc);
}

// A constant material rendered by mlb_render_shaded (linear, antialiased over black) and by the
// appearance renderer (sRGB before antialiasing): the coverage is the same everywhere, the colour
// where no silhouette blends (sRGB of the shaded colour; the blends differ by design: the appearance
// renderer blends sRGB values, mlb_render_shaded linear ones).
TEST(matches_render_shaded) {
    scene sc;
    REQUIRE(scene_init(&sc, 48, 24));
    mlb_material_config c = small_config(MLB_MATERIAL_DIRECT);
    mlb_material_net net;
    REQUIRE(material_net_init(&net, &c, NULL) == MLB_OK);
    const float k[7] = {0.6f, 0.35f, 0.2f, 0.04f, 0.04f, 0.04f, 0.45f};
    set_constant(&net, k);
    enum { n = 2, res = 48 };
    mlb_view views[n];
    make_views(views, n);
    size_t p = (size_t)res * res;
    float* img = malloc(sizeof(float) * p * 4 * n);
    float* ref = malloc(sizeof(float) * p * 4);
    mlb_appearance app;
    memset(&app, 0, sizeof app);
    REQUIRE(mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, n, res, 1, img, 0) == MLB_OK);
    double worst_interior = 0, worst_alpha = 0;
    int interior = 0;
    for (int v = 0; v < n; v++) {
        mlb_envlight light = sc.light[views[v].env];
        mlb_envlight_set_rotation(&light, (float)(views[v].env_rotation_deg * M_PI / 180));
        mlb_render_params rp = {.mesh = &sc.mesh, .light = &light, .background = MLB_BG_COLOR, .camera = views[v].cam,
                                .width = res, .height = res, .supersample = 1, .fresnel = MLB_FRESNEL_PAPER};
        memcpy(rp.k_const, k, sizeof k);
        REQUIRE(mlb_render_shaded(&rp, ref) == MLB_OK);
        const float* o = img + p * 4 * v;
        for (size_t i = 0; i < p; i++) {
            double da = fabs(o[4 * i + 3] - ref[4 * i + 3]);
            if (da > worst_alpha) worst_alpha = da;
            if (ref[4 * i + 3] == 1 && o[4 * i + 3] == 1) {
                interior++;
                for (int ch = 0; ch < 3; ch++) {
                    double d = fabs(o[4 * i + ch] - srgb1(ref[4 * i + ch]));
                    if (d > worst_interior) worst_interior = d;
                }
            }
        }
    }
    printf("  %d interior pixels: max |sRGB difference| %.3g; max coverage difference %.3g\n", interior, worst_interior,
           worst_alpha);
    CHECK(interior > 1000);
    CHECK(worst_alpha < 1e-6);
    CHECK(worst_interior < 2e-5);
    // the material maps of the same net: the constant material inside, 0 outside
    float* maps = malloc(sizeof(float) * p * 10);
    REQUIRE(mlb_appearance_maps(NULL, &net, &sc.mesh, &views[0], res, maps, maps + 3 * p, maps + 6 * p, maps + 7 * p) == MLB_OK);
    int inside = 0;
    for (size_t i = 0; i < p; i++) {
        float a = img[4 * i + 3];   // view 0's coverage
        if (a == 1) {
            inside++;
            for (int ch = 0; ch < 3; ch++) {
                CHECK_CLOSE(maps[3 * i + ch], k[ch], 1e-5, 1e-6);
                CHECK_CLOSE(maps[3 * p + 3 * i + ch], k[3 + ch], 1e-5, 1e-6);
            }
            CHECK_CLOSE(maps[6 * p + i], k[6], 1e-5, 1e-6);
            const float* nn = maps + 7 * p + 3 * i;
            CHECK_CLOSE(nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2], 1, 1e-4, 0);
        } else if (a == 0) {
            CHECK(maps[3 * i] == 0 && maps[6 * p + i] == 0);
        }
    }
    CHECK(inside > 500);
    free(maps);
    mlb_appearance_free(&app);
    material_net_free(&net);
    free(img);
    free(ref);
    scene_free(&sc);
}

// Targets: a constant material rendered by mlb_render_shaded (converted to [sRGB·α, α]); the net
// (direct and latent mode, from their initial state) is fitted by Adam on the L2 image loss.
static void fit(mlb_material_mode mode, const float* k_target, int iters, double* first, double* last, double kd_err[3]) {
    scene sc;
    mlb_brdf_ae prior;
    char source[1024];
    if (!scene_init(&sc, 32, 16) || mlb_brdf_ae_load_default(&prior, source, sizeof source)) { *first = *last = NAN; return; }
    mlb_material_config c = small_config(mode);
    mlb_material_net net;
    if (material_net_init(&net, &c, &prior)) { *first = *last = NAN; return; }
    enum { n = 2, res = 32 };
    size_t p = (size_t)res * res;
    float* target = malloc(sizeof(float) * p * 4 * n);
    float* img = malloc(sizeof(float) * p * 4 * n);
    float* dimg = malloc(sizeof(float) * p * 4 * n);
    mlb_appearance app;
    memset(&app, 0, sizeof app);
    mlb_adam_config adam = mlb_material_adam(2e-2);
    for (int it = 0; it < iters; it++) {
        mlb_view views[n];
        for (int v = 0; v < n; v++) {   // cameras and rotations change every step
            memset(&views[v], 0, sizeof views[v]);
            views[v].env = v % 2;
            views[v].env_rotation_deg = 360.0f * mlb_rng_uniform(7, 1, 2 * it + v);
            mlb_camera_orbit(&views[v].cam, 360.0 * mlb_rng_uniform(7, 0, 2 * it + v), 15, 2.6, NULL, 45, 1, 0.1, 100);
            mlb_envlight light = sc.light[views[v].env];
            mlb_envlight_set_rotation(&light, (float)(views[v].env_rotation_deg * M_PI / 180));
            mlb_render_params rp = {.mesh = &sc.mesh, .light = &light, .camera = views[v].cam, .width = res, .height = res,
                                    .supersample = 1};
            memcpy(rp.k_const, k_target, sizeof rp.k_const);
            mlb_render_shaded(&rp, target + p * 4 * v);
            for (size_t i = 0; i < p; i++) {
                float* t = target + p * 4 * v + 4 * i;
                float a = t[3];
                for (int ch = 0; ch < 3; ch++) t[ch] = a > 0 ? (float)(srgb1(t[ch] / a) * a) : 0;
            }
        }
        material_net_zero_grad(&net);
        if (mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, n, res, 1, img, 1)) break;
        double L = 0;
        for (size_t i = 0; i < p * 4 * n; i++) {
            double d = img[i] - target[i];
            L += d * d / (p * n);
            dimg[i] = (float)(2 * d / (p * n));
        }
        if (it == 0) *first = L;
        *last = L;
        if (mlb_appearance_backward(&app, &net, dimg)) break;
        material_net_update(&net, &adam);
    }
    // the fitted kd at points on the sphere
    enum { m = 256 };
    float pts[3 * m], k[7 * m];
    mlb_mesh_sample_surface(&sc.mesh, pts, m, 3, 0);
    mlb_material_eval(&net, pts, m, k);
    for (int ch = 0; ch < 3; ch++) {
        double e = 0;
        for (int i = 0; i < m; i++) e += fabs(k[7 * i + ch] - k_target[ch]) / m;
        kd_err[ch] = e;
    }
    mlb_appearance_free(&app);
    material_net_free(&net);
    brdf_ae_free(&prior);
    free(target); free(img); free(dimg);
    scene_free(&sc);
}

static mlb_status net_material(void* user, const float* pos, size_t n, float* k) {
    return mlb_material_eval(user, pos, n, k);
}

// A varying material (a random net) rendered by mlb_render_shaded with the field evaluated at every
// pixel (render.h's material callback) is the appearance renderer's image where no silhouette blends;
// the same net evaluated at the vertices and interpolated is not (the blur a baked asset does not have).
TEST(pixel_material_matches_appearance) {
    scene sc;
    REQUIRE(scene_init(&sc, 12, 6));   // coarse: a vertex-interpolated field differs visibly from the field
    mlb_material_config c = small_config(MLB_MATERIAL_DIRECT);
    c.enc.base_res = 8;
    mlb_material_net net;
    REQUIRE(material_net_init(&net, &c, NULL) == MLB_OK);
    for (size_t i = 0; i < net.n_enc; i++) net.params[i] = 0.5f * mlb_rng_normal(5, 1, i);   // a field that varies
    enum { n = 2, res = 48 };
    mlb_view views[n];
    make_views(views, n);
    size_t p = (size_t)res * res, V = (size_t)sc.mesh.n_verts;
    float* img = malloc(sizeof(float) * p * 4 * n);
    float* ref = malloc(sizeof(float) * p * 4);
    float* kv = malloc(sizeof(float) * 7 * V);
    REQUIRE(mlb_material_eval(&net, sc.mesh.pos, V, kv) == MLB_OK);
    mlb_appearance app;
    memset(&app, 0, sizeof app);
    REQUIRE(mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, n, res, 1, img, 0) == MLB_OK);
    double worst[2] = {0, 0};   // per pixel, per vertex
    int interior = 0;
    for (int per_vertex = 0; per_vertex < 2; per_vertex++)
        for (int v = 0; v < n; v++) {
            mlb_envlight light = sc.light[views[v].env];
            mlb_envlight_set_rotation(&light, (float)(views[v].env_rotation_deg * M_PI / 180));
            mlb_render_params rp = {.mesh = &sc.mesh, .light = &light, .background = MLB_BG_COLOR, .camera = views[v].cam,
                                    .width = res, .height = res, .supersample = 1, .fresnel = MLB_FRESNEL_PAPER};
            if (per_vertex) rp.k = kv;
            else rp.material = net_material, rp.material_user = &net;
            REQUIRE(mlb_render_shaded(&rp, ref) == MLB_OK);
            const float* o = img + p * 4 * v;
            for (size_t i = 0; i < p; i++) {
                if (!(ref[4 * i + 3] == 1 && o[4 * i + 3] == 1)) continue;
                interior += !per_vertex;
                for (int ch = 0; ch < 3; ch++) {
                    double d = fabs(o[4 * i + ch] - srgb1(ref[4 * i + ch]));
                    if (d > worst[per_vertex]) worst[per_vertex] = d;
                }
            }
        }
    printf("  %d interior pixels: max |sRGB difference| %.3g with the field per pixel, %.3g per vertex\n", interior,
           worst[0], worst[1]);
    CHECK(interior > 1000);
    CHECK(worst[0] < 2e-5);
    CHECK(worst[1] > 1e-2);
    free(img);
    free(ref);
    free(kv);
    mlb_appearance_free(&app);
    material_net_free(&net);
    scene_free(&sc);
}

TEST(fit_constant_material) {
    // direct mode: any material; latent mode: a material the trained prior decodes (an encoded one)
    const float target[7] = {0.7f, 0.3f, 0.15f, 0.04f, 0.04f, 0.04f, 0.5f};
    for (int mode = 0; mode < 2; mode++) {
        double first = NAN, last = NAN, e[3];
        fit((mlb_material_mode)mode, target, 100, &first, &last, e);
        if (isnan(first)) SKIP("no BRDF prior built in");
        printf("  %s: image loss %.4g -> %.4g; mean |kd - target| %.3f %.3f %.3f\n", mode ? "direct" : "latent", first, last, e[0],
               e[1], e[2]);
        CHECK(last < 0.05 * first);
        for (int ch = 0; ch < 3; ch++) CHECK(e[ch] < 0.06);
    }
}

TEST(thread_count_independent) {
    scene sc;
    REQUIRE(scene_init(&sc, 32, 16));
    mlb_brdf_ae prior;
    REQUIRE(random_prior(&prior));
    mlb_material_config c = small_config(MLB_MATERIAL_LATENT);
    enum { n = 2, res = 40 };
    mlb_view views[n];
    make_views(views, n);
    size_t m = (size_t)n * res * res * 4;
    float *img[2], *grads[2], *dimg = malloc(sizeof(float) * m);
    for (size_t i = 0; i < m; i++) dimg[i] = mlb_rng_normal(8, 0, i);
    int threads = mlb_get_threads();
    for (int t = 0; t < 2; t++) {
        mlb_set_threads(t ? 2 : 1);
        mlb_material_net net;
        REQUIRE(material_net_init(&net, &c, &prior) == MLB_OK);
        for (size_t i = 0; i < net.n_enc; i++) net.params[i] = 0.3f * mlb_rng_normal(9, 0, i);
        img[t] = malloc(sizeof(float) * m);
        grads[t] = malloc(sizeof(float) * net.n_params);
        mlb_appearance app;
        memset(&app, 0, sizeof app);
        REQUIRE(mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, n, res, 2, img[t], 1) == MLB_OK);
        material_net_zero_grad(&net);
        REQUIRE(mlb_appearance_backward(&app, &net, dimg) == MLB_OK);
        memcpy(grads[t], net.grads, sizeof(float) * net.n_params);
        if (t) {
            CHECK(memcmp(img[0], img[1], sizeof(float) * m) == 0);
            CHECK(memcmp(grads[0], grads[1], sizeof(float) * net.n_params) == 0);
        }
        // errors: a view asking for a light that is not there; backward without a kept render
        mlb_view bad = views[0];
        bad.env = 1;
        const mlb_envlight* one[2] = {sc.ptr[0], NULL};
        CHECK(mlb_appearance_render(&app, &net, &sc.mesh, one, &bad, 1, res, 1, img[t], 0) == MLB_ERR_ARG);
        CHECK(mlb_appearance_backward(&app, &net, dimg) == MLB_ERR_ARG);
        mlb_appearance_free(&app);
        mlb_appearance_free(&app);
        material_net_free(&net);
    }
    mlb_set_threads(threads);
    for (int t = 0; t < 2; t++) { free(img[t]); free(grads[t]); }
    free(dimg);
    brdf_ae_free(&prior);
    scene_free(&sc);
}

// A random latent-mode net over a random prior, and n points in the box (the regularisers' tests).
static void random_latent_net(mlb_brdf_ae* prior, mlb_material_net_f64* net, uint64_t seed, double* pts, int n) {
    REQUIRE(random_prior(prior));
    mlb_material_config c = small_config(MLB_MATERIAL_LATENT);
    REQUIRE(material_net_init_f64(net, &c, prior) == MLB_OK);
    randomize_f64(net, seed);
    for (int i = 0; i < 3 * n; i++) pts[i] = (mlb_rng_uniform_f64(seed + 2, 0, i) - 0.5) * 1.5;
}

// Central differences of loss(net) over the 8 parameters of largest gradient (4 table, 4 MLP)
// against net->grads, which the caller's backward has just filled.
static void fd_top_grads(mlb_material_net_f64* net, double (*loss)(mlb_material_net_f64*, const void*), const void* ctx) {
    const double h = 1e-7;
    size_t pick[8];
    test_top_grads(net->grads, net->n_enc, net->n_params, 4, pick);
    for (int q = 0; q < 8; q++) {
        size_t i = pick[q];
        double keep = net->params[i];
        net->params[i] = keep + h;
        double Lp = loss(net, ctx);
        net->params[i] = keep - h;
        double Lm = loss(net, ctx);
        net->params[i] = keep;
        double fd = (Lp - Lm) / (2 * h);
        CHECK_MSG(fabs(fd - net->grads[i]) <= 1e-6 * fabs(fd) + 1e-10, "param %zu: fd %.10g, backward %.10g", i, fd, net->grads[i]);
        CHECK(net->grads[i] != 0);
    }
}

typedef struct { const double* pts; int n; double sigma, weight, wspec, radius; } reg_args;
static double smoothness_loss(mlb_material_net_f64* net, const void* ctx) {
    const reg_args* a = ctx;
    double L = NAN;
    CHECK(mlb_material_smoothness_f64(net, a->pts, a->n, a->sigma, a->weight, a->wspec, 42, 7, 0, &L) == MLB_OK);
    return L;
}
static double support_loss(mlb_material_net_f64* net, const void* ctx) {
    const reg_args* a = ctx;
    double L = NAN;
    CHECK(mlb_material_latent_support_part_f64(net, a->pts, a->n, 0, a->n, a->radius, a->weight, 0, &L) == MLB_OK);
    return L;
}

TEST(smoothness) {
    mlb_brdf_ae prior;
    mlb_material_net_f64 net;
    enum { n = 50 };
    double pts[3 * n];
    random_latent_net(&prior, &net, 4, pts, n);
    const double sigma = 0.05, weight = 0.03, wspec = 0.02;
    double L;
    material_net_zero_grad_f64(&net);
    REQUIRE(mlb_material_smoothness_f64(&net, pts, n, sigma, weight, wspec, 42, 7, 1, &L) == MLB_OK);
    // the value from its definition, with the jitter drawn the documented way
    double x[3 * n], xj[3 * n], k0[7 * n], k1[7 * n];
    for (int i = 0; i < 3 * n; i++) {
        x[i] = pts[i];
        xj[i] = pts[i] + sigma * mlb_rng_normal_f64(42, 0x5A17, ((uint64_t)7 << 32) + i);
    }
    REQUIRE(material_net_eval_f64(&net, x, n, k0, NULL) == MLB_OK);
    REQUIRE(material_net_eval_f64(&net, xj, n, k1, NULL) == MLB_OK);
    double ref_kd = 0, ref_spec = 0;
    for (int i = 0; i < n; i++)
        for (int ch = 0; ch < 7; ch++) *(ch < 3 ? &ref_kd : &ref_spec) += fabs(k0[7 * i + ch] - k1[7 * i + ch]);
    CHECK_CLOSE(L, weight / (3.0 * n) * ref_kd + wspec / (4.0 * n) * ref_spec, 1e-12, 0);
    CHECK(L > 0 && ref_spec > 0);
    double Lkd;   // the paper's kd-only term alone
    REQUIRE(mlb_material_smoothness_f64(&net, pts, n, sigma, weight, 0, 42, 7, 0, &Lkd) == MLB_OK);
    CHECK_CLOSE(Lkd, weight / (3.0 * n) * ref_kd, 1e-12, 0);
    // another step draws another jitter; sigma 0 gives 0
    double L2, L0;
    REQUIRE(mlb_material_smoothness_f64(&net, pts, n, sigma, weight, wspec, 42, 8, 0, &L2) == MLB_OK);
    CHECK(L2 != L);
    REQUIRE(mlb_material_smoothness_f64(&net, pts, n, 0, weight, wspec, 42, 8, 0, &L0) == MLB_OK);
    CHECK(L0 == 0);
    // finite differences over the parameters of largest gradient
    material_net_zero_grad_f64(&net);
    REQUIRE(mlb_material_smoothness_f64(&net, pts, n, sigma, weight, wspec, 42, 7, 1, &L) == MLB_OK);
    fd_top_grads(&net, smoothness_loss, &(reg_args){pts, n, sigma, weight, wspec, 0});
    CHECK(mlb_material_smoothness_f64(&net, pts, 0, sigma, weight, wspec, 42, 7, 0, &L) == MLB_ERR_ARG);
    // shares of the points (the pipeline's per-batch shares): the whole's loss and gradient as sums;
    // the one share of every point is the whole, bit for bit
    double* whole = malloc(sizeof(double) * net.n_params);
    double* parts = calloc(net.n_params, sizeof(double));
    REQUIRE(whole && parts);
    material_net_zero_grad_f64(&net);
    REQUIRE(mlb_material_smoothness_f64(&net, pts, n, sigma, weight, wspec, 42, 7, 1, &L) == MLB_OK);
    memcpy(whole, net.grads, sizeof(double) * net.n_params);
    double Lsum = 0, Lone;
    const int cut[4] = {0, 17, 17, n};   // an empty share included
    for (int q = 0; q < 3; q++) {
        double Lq;
        material_net_zero_grad_f64(&net);
        REQUIRE(mlb_material_smoothness_part_f64(&net, pts, n, cut[q], cut[q + 1] - cut[q], sigma, weight, wspec, 42, 7, 1,
                                                 &Lq) == MLB_OK);
        Lsum += Lq;
        for (size_t i = 0; i < net.n_params; i++) parts[i] += net.grads[i];
    }
    CHECK_CLOSE(Lsum, L, 1e-12, 0);
    double worst = 0;
    for (size_t i = 0; i < net.n_params; i++) worst = fmax(worst, fabs(parts[i] - whole[i]));
    CHECK_MSG(worst < 1e-12, "shares' gradients differ from the whole's by %g", worst);
    material_net_zero_grad_f64(&net);
    REQUIRE(mlb_material_smoothness_part_f64(&net, pts, n, 0, n, sigma, weight, wspec, 42, 7, 1, &Lone) == MLB_OK);
    CHECK(Lone == L && !memcmp(net.grads, whole, sizeof(double) * net.n_params));
    CHECK(mlb_material_smoothness_part_f64(&net, pts, n, 40, 11, sigma, weight, wspec, 42, 7, 0, &L) == MLB_ERR_ARG);
    free(whole);
    free(parts);
    material_net_free_f64(&net);
    brdf_ae_free(&prior);
}

// The prior's support term: its value from the definition, 0 inside the ball, finite differences
// of its gradient, shares adding up to the whole, and the errors.
TEST(latent_support) {
    mlb_brdf_ae prior;
    mlb_material_net_f64 net;
    enum { n = 60 };
    double pts[3 * n], z[4 * n], r[n];
    random_latent_net(&prior, &net, 5, pts, n);
    REQUIRE(material_net_eval_f64(&net, pts, n, NULL, z) == MLB_OK);
    double rmin = INFINITY, rmax = 0;
    for (int i = 0; i < n; i++) {
        r[i] = sqrt(z[4 * i] * z[4 * i] + z[4 * i + 1] * z[4 * i + 1] + z[4 * i + 2] * z[4 * i + 2] + z[4 * i + 3] * z[4 * i + 3]);
        rmin = fmin(rmin, r[i]), rmax = fmax(rmax, r[i]);
    }
    REQUIRE(rmax > rmin);
    const double radius = 0.5 * (rmin + rmax), weight = 3.0;   // some points inside, some outside
    double ref = 0;
    int outside = 0;
    for (int i = 0; i < n; i++)
        if (r[i] > radius) ref += (r[i] - radius) * (r[i] - radius), outside++;
    CHECK(outside > 0 && outside < n);
    double L;
    material_net_zero_grad_f64(&net);
    REQUIRE(mlb_material_latent_support_part_f64(&net, pts, n, 0, n, radius, weight, 1, &L) == MLB_OK);
    CHECK_CLOSE(L, weight / n * ref, 1e-12, 0);
    fd_top_grads(&net, support_loss, &(reg_args){pts, n, 0, weight, 0, radius});
    // shares add up to the whole
    double* whole = malloc(sizeof(double) * net.n_params);
    REQUIRE(whole);
    memcpy(whole, net.grads, sizeof(double) * net.n_params);
    material_net_zero_grad_f64(&net);
    double La, Lb;
    REQUIRE(mlb_material_latent_support_part_f64(&net, pts, n, 0, 23, radius, weight, 1, &La) == MLB_OK);
    REQUIRE(mlb_material_latent_support_part_f64(&net, pts, n, 23, n - 23, radius, weight, 1, &Lb) == MLB_OK);
    CHECK_CLOSE(La + Lb, L, 1e-12, 0);
    double worst = 0;
    for (size_t i = 0; i < net.n_params; i++) worst = fmax(worst, fabs(net.grads[i] - whole[i]));
    CHECK_MSG(worst < 1e-12, "shares' gradients differ from the whole's by %g", worst);
    // every code inside the ball: no loss, no gradient
    material_net_zero_grad_f64(&net);
    REQUIRE(mlb_material_latent_support_part_f64(&net, pts, n, 0, n, rmax * 1.01, weight, 1, &L) == MLB_OK);
    CHECK(L == 0);
    size_t nonzero = 0;
    for (size_t i = 0; i < net.n_params; i++) nonzero += net.grads[i] != 0;
    CHECK(nonzero == 0);
    CHECK(mlb_material_latent_support_part_f64(&net, pts, n, 40, 21, radius, weight, 0, &L) == MLB_ERR_ARG);
    CHECK(mlb_material_latent_support_part_f64(&net, pts, n, 0, n, -1, weight, 0, &L) == MLB_ERR_ARG);
    CHECK(mlb_material_latent_support_part_f64(&net, pts, n, 0, n, radius, NAN, 0, &L) == MLB_ERR_ARG);
    free(whole);
    material_net_free_f64(&net);
    // a direct-mode net has no codes
    mlb_material_net_f64 direct;
    mlb_material_config cd = small_config(MLB_MATERIAL_DIRECT);
    REQUIRE(material_net_init_f64(&direct, &cd, &prior) == MLB_OK);
    CHECK(mlb_material_latent_support_part_f64(&direct, pts, n, 0, n, radius, weight, 1, &L) == MLB_ERR_ARG);
    material_net_free_f64(&direct);
    brdf_ae_free(&prior);
}

// The material network, its optimiser and the shading on the CPU table's "device" (the code the GPU
// runs, on host memory) agree with the host path; test_cuda_material runs it on a GPU.
TEST(device_twin_on_cpu_table) { appearance_twin_check(mlb_backend_cpu(), 3, 48, 2, 3, 1e-5); }

// The render and its network on one device: a network on the host with another device's table, a
// network on the table's device rendered without backward (its host copy is behind), or a network
// on another device are refused with a clear error, and nothing is kept for a backward.
TEST(render_and_network_on_one_device) {
    scene sc;
    REQUIRE(scene_init(&sc, 16, 8));
    mlb_brdf_ae prior;
    REQUIRE(random_prior(&prior));
    mlb_material_config c = mlb_material_default();
    c.enc = (mlb_hashgrid_config){4, 2, 1 << 10, 4, 1.5};
    c.hidden = 8;
    mlb_material_net net;
    REQUIRE(material_net_init(&net, &c, &prior) == MLB_OK);
    mlb_view views[2];
    make_views(views, 2);
    enum { RES = 16 };
    float img[2 * RES * RES * 4], dimg[2 * RES * RES * 4] = {0};
    mlb_backend other = *guarded_table();   // host-addressable buffers, but called another device
    other.device = MLB_DEVICE_CUDA;
    mlb_appearance app;
    memset(&app, 0, sizeof app);
    app.be = &other;
    CHECK(mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, 2, RES, 1, img, 1) == MLB_ERR_ARG);
    CHECK_MSG(strstr(mlb_last_error(), "on the host, the render on the cuda") != NULL, "%s", mlb_last_error());
    CHECK(mlb_appearance_backward(&app, &net, dimg) == MLB_ERR_ARG);
    mlb_appearance_free(&app);
    REQUIRE(mlb_field_use_device(&net, guarded_table()) == MLB_OK);
    memset(&app, 0, sizeof app);
    app.be = &other;   // the network on the CPU's device, the render on "cuda"
    CHECK(mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, 2, RES, 1, img, 1) == MLB_ERR_ARG);
    CHECK_MSG(strstr(mlb_last_error(), "the material network is on the cpu, the render on the cuda") != NULL, "%s",
              mlb_last_error());
    mlb_appearance_free(&app);
    memset(&app, 0, sizeof app);
    app.be = guarded_table();
    CHECK(mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, 2, RES, 1, img, 0) == MLB_ERR_ARG);
    CHECK_MSG(strstr(mlb_last_error(), "without backward needs the network on the host") != NULL, "%s", mlb_last_error());
    CHECK(mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, 2, RES, 1, img, 1) == MLB_OK);
    CHECK(mlb_appearance_backward(&app, &net, dimg) == MLB_OK);
    mlb_appearance_free(&app);
    REQUIRE(mlb_field_leave_device(&net) == MLB_OK);
    CHECK_MSG(guard_n == 0, "%d buffers of the table left", guard_n);
    material_net_free(&net);
    brdf_ae_free(&prior);
    scene_free(&sc);
}

// The render, its backward and the network on a table whose buffers the host cannot touch outside
// its ops (guarded_table.h): a host access would end the test with SIGSEGV; the results are the
// CPU table's, checked against the host path as above; every buffer given back at the end.
TEST(render_stays_on_its_table) {
    const mlb_backend* g = guarded_table();
    long ops = guard_ops;
    appearance_twin_check(g, 3, 32, 2, 2, 1e-5);
    CHECK(guard_ops - ops > 100);
    CHECK_MSG(guard_n == 0, "%d buffers of the table left", guard_n);
}

int main(void) {
    RUN(fd_whole_chain_f64);
    RUN(matches_render_shaded);
    RUN(pixel_material_matches_appearance);
    RUN(fit_constant_material);
    RUN(thread_count_independent);
    RUN(smoothness);
    RUN(latent_support);
    RUN(device_twin_on_cpu_table);
    RUN(render_stays_on_its_table);
    RUN(render_and_network_on_one_device);
    return test_summary();
}
