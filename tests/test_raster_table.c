// The stages' rasterizer calls go through the op table they are handed (docs/cuda.md "The
// stages on the table"): a copy of the CPU table that counts its raster ops is given to the geometry
// fit's state, the appearance renderer and the final renders' _on functions. Each op must be called
// through it, and the results must be the bits of the same call with NULL (the CPU table).
#include <stdint.h>
#include "matlaber/appearance.h"
#include "matlaber/backend.h"
#include "matlaber/geometry.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/rng.h"
#include "appearance_test_util.h"
#include "guarded_table.h"
#include "matlaber/guidance_sds.h"
#include "tiny_sds_fixture.h"
#include "material_test_util.h"
#include "test.h"

enum { OP_RAST, OP_RAST_B, OP_INTERP, OP_INTERP_B, OP_AA, OP_AA_B, OP_COUNT };
static int calls[OP_COUNT];
static size_t uploaded;   // floats that went up through the table
static mlb_backend spy;

static mlb_status spy_upload(float* dst, const float* src, size_t n) {
    uploaded += n;
    return mlb_backend_cpu()->upload(dst, src, n);
}
static mlb_status spy_rasterize(int32_t* tri, float* bary, float* depth, const float* clip, int V, const int32_t* faces,
                                int F, int H, int W) {
    calls[OP_RAST]++;
    return mlb_backend_cpu()->rasterize(tri, bary, depth, clip, V, faces, F, H, W);
}
static mlb_status spy_rasterize_backward(float* dclip, const float* dbary, const float* ddepth, const int32_t* tri,
                                         const float* clip, int V, const int32_t* faces, int F, int H, int W) {
    calls[OP_RAST_B]++;
    return mlb_backend_cpu()->rasterize_backward(dclip, dbary, ddepth, tri, clip, V, faces, F, H, W);
}
static mlb_status spy_interpolate(float* out, const float* attr, int V, int C, const int32_t* tri, const float* bary,
                                  const int32_t* faces, int F, int H, int W) {
    calls[OP_INTERP]++;
    return mlb_backend_cpu()->interpolate(out, attr, V, C, tri, bary, faces, F, H, W);
}
static mlb_status spy_interpolate_backward(float* dattr, float* dbary, const float* dout, const float* attr, int V,
                                           int C, const int32_t* tri, const float* bary, const int32_t* faces, int F,
                                           int H, int W) {
    calls[OP_INTERP_B]++;
    return mlb_backend_cpu()->interpolate_backward(dattr, dbary, dout, attr, V, C, tri, bary, faces, F, H, W);
}
static mlb_status spy_antialias(float* out, float* weights, const float* color, int C, const int32_t* tri,
                                const float* depth, const float* clip, int V, const int32_t* faces, const int32_t* adj,
                                int F, int H, int W) {
    calls[OP_AA]++;
    return mlb_backend_cpu()->antialias(out, weights, color, C, tri, depth, clip, V, faces, adj, F, H, W);
}
static mlb_status spy_antialias_backward(float* dcolor, float* dclip, const float* dout, const float* weights,
                                         const float* color, int C, const int32_t* tri, const float* depth,
                                         const float* clip, int V, const int32_t* faces, const int32_t* adj, int F,
                                         int H, int W) {
    calls[OP_AA_B]++;
    return mlb_backend_cpu()->antialias_backward(dcolor, dclip, dout, weights, color, C, tri, depth, clip, V, faces,
                                                 adj, F, H, W);
}

static const mlb_backend* spy_table(void) {
    spy = *mlb_backend_cpu();
    spy.rasterize = spy_rasterize;
    spy.rasterize_backward = spy_rasterize_backward;
    spy.interpolate = spy_interpolate;
    spy.interpolate_backward = spy_interpolate_backward;
    spy.antialias = spy_antialias;
    spy.antialias_backward = spy_antialias_backward;
    spy.upload = spy_upload;
    memset(calls, 0, sizeof calls);
    uploaded = 0;
    return &spy;
}

static int same(const void* a, const void* b, size_t bytes) { return memcmp(a, b, bytes) == 0; }

// One geometry forward + backward of a small ellipsoid-fitted network on table `be` (NULL: the
// CPU's) into img and grads; the loss is ½|img − 0.5|² of the CPU's image (dimg, written on t 0).
enum { G_RES = 24, G_SS = 2, G_VIEWS = 3 };
typedef struct {
    mlb_geometry_net net;
    mlb_tetgrid g;
    mlb_camera cams[G_VIEWS];
    size_t m;
    float* dimg;
} geometry_case;
static void geometry_case_init(geometry_case* k) {
    memset(k, 0, sizeof *k);
    mlb_geometry_config c = mlb_geometry_default();
    c.enc = (mlb_hashgrid_config){4, 2, 256, 4, 1.5};
    c.hidden = 8;
    REQUIRE(geometry_net_init(&k->net, &c) == MLB_OK);
    mlb_shape sh;
    float axes[3] = {1.0f, 0.8f, 0.9f};
    mlb_shape_ellipsoid(&sh, 0.8f, axes);
    mlb_shape_fit_config fc = mlb_shape_fit_default();
    fc.iters = 60; fc.batch = 1024; fc.pool = 2048;
    REQUIRE(mlb_geometry_fit_shape(&k->net, &sh, &fc, NULL, NULL) == MLB_OK);
    mlb_shape_free(&sh);
    REQUIRE(mlb_tetgrid_create(&k->g, 8, c.scale) == MLB_OK);
    for (int v = 0; v < G_VIEWS; v++)
        REQUIRE(mlb_camera_orbit(&k->cams[v], 40.0 + 110 * v, 25.0 - 20 * v, 3.0, NULL, 45.0, 1.0, 0.1, 100.0) == MLB_OK);
    k->m = (size_t)G_VIEWS * G_RES * G_RES * 4;
    k->dimg = malloc(sizeof(float) * k->m);
}
static void geometry_case_run(geometry_case* k, const mlb_backend* be, int first, float* img, float* grads) {
    mlb_geofit_state st;
    memset(&st, 0, sizeof st);
    st.be = be;
    geometry_net_zero_grad(&k->net);
    REQUIRE(mlb_geofit_forward(&st, &k->net, &k->g, k->cams, G_VIEWS, G_RES, G_SS, img, NULL) == MLB_OK);
    if (first)
        for (size_t i = 0; i < k->m; i++) k->dimg[i] = img[i] - 0.5f;
    REQUIRE(mlb_geofit_backward(&st, &k->net, k->dimg, 0.1) == MLB_OK);
    memcpy(grads, k->net.grads, sizeof(float) * k->net.n_params);
    mlb_geofit_state_free(&st);
}
static void geometry_case_free(geometry_case* k) {
    free(k->dimg);
    mlb_tetgrid_free(&k->g);
    geometry_net_free(&k->net);
}

TEST(geometry_stage_calls_the_table) {
    const mlb_backend* be = spy_table();
    geometry_case k;
    geometry_case_init(&k);
    size_t m = k.m, np = k.net.n_params;
    float *img[2] = {malloc(sizeof(float) * m), malloc(sizeof(float) * m)};
    float *grads[2] = {malloc(sizeof(float) * np), malloc(sizeof(float) * np)};
    for (int t = 0; t < 2; t++) geometry_case_run(&k, t ? be : NULL, t == 0, img[t], grads[t]);   // t 1: the spy
    CHECK(same(img[0], img[1], sizeof(float) * m));
    CHECK(same(grads[0], grads[1], sizeof(float) * np));
    for (int op = 0; op < OP_COUNT; op++) CHECK(calls[op] == G_VIEWS);
    // the final normal maps
    enum { RES = G_RES, SS = G_SS };
    mlb_mesh sphere = {0};
    REQUIRE(mlb_mesh_uv_sphere(&sphere, 0.8f, 24, 12) == MLB_OK);
    memset(calls, 0, sizeof calls);
    REQUIRE(mlb_geofit_render_mesh(NULL, img[0], &sphere, &k.cams[0], RES, SS) == MLB_OK);
    REQUIRE(mlb_geofit_render_mesh(be, img[1], &sphere, &k.cams[0], RES, SS) == MLB_OK);
    CHECK(same(img[0], img[1], sizeof(float) * RES * RES * 4));
    CHECK(calls[OP_RAST] == 1 && calls[OP_INTERP] == 1 && calls[OP_AA] == 1);
    mlb_mesh_free(&sphere);
    for (int t = 0; t < 2; t++) { free(img[t]); free(grads[t]); }
    geometry_case_free(&k);
}

// The geometry step on a table whose buffers the host cannot touch outside its ops
// (guarded_table.h): marching tets and every view's raster buffers stay there (a host access ends
// the test with SIGSEGV), the bits are the CPU table's, and every buffer is given back.
TEST(geometry_stage_stays_on_its_table) {
    geometry_case k;
    geometry_case_init(&k);
    size_t m = k.m, np = k.net.n_params;
    float *img[2] = {malloc(sizeof(float) * m), malloc(sizeof(float) * m)};
    float *grads[2] = {malloc(sizeof(float) * np), malloc(sizeof(float) * np)};
    long ops = guard_ops;
    for (int t = 0; t < 2; t++) geometry_case_run(&k, t ? guarded_table() : NULL, t == 0, img[t], grads[t]);
    CHECK(same(img[0], img[1], sizeof(float) * m));
    CHECK(same(grads[0], grads[1], sizeof(float) * np));
    CHECK(guard_ops - ops > 10 * G_VIEWS);
    // the network there too (the pipeline's geometry stage on a GPU): the field's device path, whose
    // arithmetic is the host's to rounding
    REQUIRE(mlb_field_use_device(&k.net, guarded_table()) == MLB_OK);
    geometry_case_run(&k, guarded_table(), 0, img[1], grads[1]);
    REQUIRE(mlb_field_sync_host(&k.net) == MLB_OK);
    memcpy(grads[1], k.net.grads, sizeof(float) * np);
    REQUIRE(mlb_field_leave_device(&k.net) == MLB_OK);
    CHECK_PARITY("images, the network on the table", img[1], img[0], m, 1e-6);
    CHECK_PARITY("gradients, the network on the table", grads[1], grads[0], np, 1e-4);
    CHECK_MSG(guard_n == 0, "%d buffers of the table left", guard_n);
    for (int t = 0; t < 2; t++) { free(img[t]); free(grads[t]); }
    geometry_case_free(&k);
}

// A small latent-mode material network over a random prior, its hash table drawn at random; 0 on failure.
static int small_material_net(mlb_material_net* net, mlb_brdf_ae* prior) {
    if (!random_prior(prior)) return 0;
    mlb_material_config c = mlb_material_default();
    c.enc = (mlb_hashgrid_config){8, 2, 1 << 12, 4, 1.5};
    c.hidden = 16;
    c.seed = 11;
    if (material_net_init(net, &c, prior) != MLB_OK) return 0;
    for (size_t i = 0; i < net->n_enc; i++) net->params[i] = 0.3f * mlb_rng_normal(21, 0, i);
    return 1;
}

// The appearance tests' scene: a welded sphere under two lights, and a small material network.
static int painted_scene_init(scene* sc, mlb_brdf_ae* prior, mlb_material_net* net) {
    return scene_init(sc, 32, 16) && small_material_net(net, prior);
}
static void painted_scene_free(scene* sc, mlb_brdf_ae* prior, mlb_material_net* net) {
    material_net_free(net);
    brdf_ae_free(prior);
    scene_free(sc);
}

TEST(appearance_calls_the_table) {
    const mlb_backend* be = spy_table();
    scene sc;
    mlb_brdf_ae prior;
    mlb_material_net net;
    REQUIRE(painted_scene_init(&sc, &prior, &net));
    enum { N = 3, RES = 24, SS = 2 };
    mlb_view views[N];
    make_views(views, N);
    size_t m = (size_t)N * RES * RES * 4;
    float *img[2] = {malloc(sizeof(float) * m), malloc(sizeof(float) * m)}, *dimg = malloc(sizeof(float) * m);
    float* grads = malloc(sizeof(float) * net.n_params);
    for (int t = 0; t < 2; t++) {
        mlb_appearance app;
        memset(&app, 0, sizeof app);
        app.be = t ? be : NULL;
        material_net_zero_grad(&net);
        REQUIRE(mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, N, RES, SS, img[t], 1) == MLB_OK);
        if (t == 0)
            for (size_t i = 0; i < m; i++) dimg[i] = img[0][i] - 0.3f;
        REQUIRE(mlb_appearance_backward(&app, &net, dimg) == MLB_OK);
        if (t == 0) memcpy(grads, net.grads, sizeof(float) * net.n_params);
        mlb_appearance_free(&app);
    }
    CHECK(same(img[0], img[1], sizeof(float) * m));
    CHECK(same(grads, net.grads, sizeof(float) * net.n_params));
    CHECK(calls[OP_RAST] == N && calls[OP_INTERP] == N && calls[OP_AA] == N && calls[OP_AA_B] == N);
    CHECK(calls[OP_RAST_B] == 0 && calls[OP_INTERP_B] == 0);   // the mesh is fixed: no geometry gradient
    // the final material maps
    size_t p = (size_t)RES * RES;
    float* maps[2] = {malloc(sizeof(float) * p * 10), malloc(sizeof(float) * p * 10)};
    memset(calls, 0, sizeof calls);
    for (int t = 0; t < 2; t++)
        REQUIRE(mlb_appearance_maps(t ? be : NULL, &net, &sc.mesh, &views[1], RES, maps[t], maps[t] + 3 * p,
                                       maps[t] + 6 * p, maps[t] + 7 * p) == MLB_OK);
    CHECK(same(maps[0], maps[1], sizeof(float) * p * 10));
    CHECK(calls[OP_RAST] == 1 && calls[OP_INTERP] == 1 && calls[OP_AA] == 1);
    free(maps[0]); free(maps[1]);
    free(img[0]); free(img[1]); free(dimg); free(grads);
    painted_scene_free(&sc, &prior, &net);
}

// The appearance stage renders one mesh every step: it goes up once, the views' clip coordinates are
// made on the table, and a later render of the same mesh uploads nothing; a changed mesh (the same
// sizes, one vertex moved) goes up again and renders as it would in a fresh renderer.
TEST(appearance_keeps_its_mesh_on_the_table) {
    const mlb_backend* be = spy_table();
    scene sc;
    mlb_brdf_ae prior;
    mlb_material_net net;
    REQUIRE(painted_scene_init(&sc, &prior, &net));
    enum { N = 3, RES = 24 };
    mlb_view views[N];
    make_views(views, N);
    size_t m = (size_t)N * RES * RES * 4;
    float *first = malloc(sizeof(float) * m), *again = malloc(sizeof(float) * m), *fresh = malloc(sizeof(float) * m);
    mlb_appearance app, other;
    memset(&app, 0, sizeof app);
    memset(&other, 0, sizeof other);
    app.be = other.be = be;
    REQUIRE(mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, N, RES, 1, first, 0) == MLB_OK);
    size_t mesh_floats = (size_t)sc.mesh.n_verts * 9 + (size_t)sc.mesh.n_faces * 6;   // pos, attr, faces, adj
    CHECK_MSG(uploaded == mesh_floats, "first render uploaded %zu floats, the mesh is %zu", uploaded, mesh_floats);
    uploaded = 0;
    REQUIRE(mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, N, RES, 1, again, 0) == MLB_OK);
    CHECK_MSG(uploaded == 0, "a second render of the same mesh uploaded %zu floats", uploaded);
    CHECK(same(first, again, sizeof(float) * m));
    sc.mesh.pos[3 * 5 + 1] += 0.05f;   // the same sizes, another mesh
    REQUIRE(mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, N, RES, 1, again, 0) == MLB_OK);
    CHECK(uploaded == mesh_floats);
    REQUIRE(mlb_appearance_render(&other, &net, &sc.mesh, sc.ptr, views, N, RES, 1, fresh, 0) == MLB_OK);
    CHECK(same(again, fresh, sizeof(float) * m));
    CHECK(!same(first, again, sizeof(float) * m));
    mlb_appearance_free(&app);
    mlb_appearance_free(&other);
    free(first); free(again); free(fresh);
    painted_scene_free(&sc, &prior, &net);
}

// Score distillation on the renders where they are (guidance.h loss_on): the geometry step with a tiny
// random SDS model on the guarded table, in the latent phase (step 0) and the VAE's (step 1), keeps
// every render and its gradient there and gives the bits of the CPU's step whose renders come down
// to the guidance (loss, not loss_on): images, loss and gradients; then the appearance render, its guidance and backward the same way (the material network on
// the table in both runs: its device path rounds otherwise than the host's).
static char tmpdir[256];
TEST(guided_steps_stay_on_their_table) {
    static fixture f;
    REQUIRE(fixture_init(&f, tmpdir));
    mlb_guidance_sds_config gc = mlb_guidance_sds_default();
    gc.views = G_VIEWS;
    gc.latent_iters = 1;
    gc.latent_size = 8;
    gc.seed = 3;
    gc.n_envs = 2;
    gc.geometry_opt.guidance_scale = gc.appearance_opt.guidance_scale = 7.5f;
    mlb_guidance* g = NULL;
    REQUIRE(mlb_guidance_sds_create_from(make_sds(&f, 0, NULL), make_sds(&f, 1, NULL), &gc, &g) == MLB_OK);
    REQUIRE(g->loss_on != NULL);
    mlb_guidance host = *g;   // the same guidance without loss_on: the renders come down to it
    host.loss_on = NULL;
    geometry_case k;
    geometry_case_init(&k);
    enum { RES = 64 };
    size_t m = (size_t)G_VIEWS * RES * RES * 4, np = k.net.n_params;
    float *img[2] = {malloc(sizeof(float) * m), malloc(sizeof(float) * m)};
    float *grads[2] = {malloc(sizeof(float) * np), malloc(sizeof(float) * np)};
    mlb_view views[G_VIEWS];
    for (long step = 0; step < 2; step++) {
        REQUIRE(g->sample_views(g, MLB_STAGE_GEOMETRY, step, views) == MLB_OK);
        double loss[2];
        long ops = guard_ops;
        for (int t = 0; t < 2; t++) {
            mlb_geofit_state st;
            memset(&st, 0, sizeof st);
            st.be = t ? guarded_table() : NULL;
            mlb_geofit_stats stats;
            REQUIRE(mlb_geometry_guided_step(&st, &k.net, &k.g, t ? g : &host, step, views, RES, 1, 0.1, &stats,
                                             img[t]) == MLB_OK);
            CHECK(st.images_on_table == t);
            loss[t] = stats.loss;
            memcpy(grads[t], k.net.grads, sizeof(float) * np);
            mlb_geofit_state_free(&st);
        }
        printf("  geometry step %ld (%s): loss %.6g / %.6g, %ld guarded ops\n", step, step ? "VAE phase" : "latent phase",
               loss[0], loss[1], guard_ops - ops);
        CHECK(loss[0] == loss[1] && loss[0] > 0);
        CHECK(guard_ops - ops > 200);   // the render, the guidance's models and arithmetic went through the table
        CHECK(same(img[0], img[1], sizeof(float) * m));
        CHECK(same(grads[0], grads[1], sizeof(float) * np));
    }
    geometry_case_free(&k);

    scene sc;
    mlb_brdf_ae prior;
    mlb_material_net net;
    REQUIRE(painted_scene_init(&sc, &prior, &net));
    REQUIRE(mlb_field_use_device(&net, guarded_table()) == MLB_OK);
    make_views(views, G_VIEWS);
    float* dimg = malloc(sizeof(float) * m);
    float* agrads[2] = {malloc(sizeof(float) * net.n_params), malloc(sizeof(float) * net.n_params)};
    double aloss[2];
    long aops[2];
    for (int t = 0; t < 2; t++) {
        aops[t] = guard_ops;   // t 0: the renders come down to the host guidance; t 1: they stay
        mlb_appearance app;
        memset(&app, 0, sizeof app);
        app.be = guarded_table();
        app.images_on_table = t;
        material_net_zero_grad(&net);
        REQUIRE(mlb_appearance_render(&app, &net, &sc.mesh, sc.ptr, views, G_VIEWS, RES, 1, t ? NULL : img[0], 1) == MLB_OK);
        if (t) {
            REQUIRE(mlb_guidance_loss_batches(g, app.be, MLB_STAGE_APPEARANCE, 4, views, G_VIEWS, 0, G_VIEWS, app.t_images,
                                              RES, RES, app.t_dimages, &aloss[t]) == MLB_OK);
            REQUIRE(mlb_appearance_backward_table(&app, &net) == MLB_OK);
        } else {
            memset(dimg, 0, sizeof(float) * m);
            REQUIRE(mlb_guidance_loss_batches(g, NULL, MLB_STAGE_APPEARANCE, 4, views, G_VIEWS, 0, G_VIEWS, img[0], RES,
                                              RES, dimg, &aloss[t]) == MLB_OK);
            REQUIRE(mlb_appearance_backward(&app, &net, dimg) == MLB_OK);
        }
        aops[t] = guard_ops - aops[t];
        REQUIRE(mlb_field_grads_get(&net, agrads[t]) == MLB_OK);
        mlb_appearance_free(&app);
    }
    printf("  appearance: loss %.6g / %.6g, %ld / %ld guarded ops\n", aloss[0], aloss[1], aops[0], aops[1]);
    CHECK(aloss[0] == aloss[1] && aloss[0] > 0);
    CHECK(aops[1] > aops[0] + 200);   // on the table, the guidance's models ran there too
    CHECK(same(agrads[0], agrads[1], sizeof(float) * net.n_params));
    REQUIRE(mlb_field_leave_device(&net) == MLB_OK);
    free(dimg); free(agrads[0]); free(agrads[1]);
    painted_scene_free(&sc, &prior, &net);
    for (int t = 0; t < 2; t++) { free(img[t]); free(grads[t]); }
    mlb_guidance_free(g);
    CHECK_MSG(guard_n == 0, "%d buffers of the table left", guard_n);
    fixture_free(&f);
}

int main(void) {
    const char* base = getenv("TMPDIR");
    snprintf(tmpdir, sizeof tmpdir, "%s/mlb_raster_table_XXXXXX", base && *base ? base : "/tmp");
    if (!mkdtemp(tmpdir)) { printf("cannot create a temporary folder\n"); return 1; }
    RUN(geometry_stage_calls_the_table);
    RUN(geometry_stage_stays_on_its_table);
    RUN(appearance_calls_the_table);
    RUN(appearance_keeps_its_mesh_on_the_table);
    RUN(guided_steps_stay_on_their_table);
    rmdir(tmpdir);
    return test_summary();
}
