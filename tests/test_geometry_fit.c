// End-to-end geometry fit (docs/geometry_fit.md): an ellipsoid-initialised network fitted to the
// silhouettes and normal maps of a different shape; the full chain's gradient in double; determinism.
#include <stdint.h>
#include "matlaber/geometry.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/obj.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"
#include "test.h"

// A closed, welded lat-long mesh of the star-shaped surface r(d)·d: three lobes around y, a bulge
// towards +y (clearly not an ellipsoid). CCW seen from outside.
static double lobed_radius(double x, double y, double z) {
    double phi = atan2(z, x), st = sqrt(x * x + z * z);
    return 1.0 + 0.3 * cos(3 * phi) * st * st * st + 0.2 * y * y * y;
}

static int lobed_mesh(mlb_mesh* m, int nu, int nv) {
    memset(m, 0, sizeof *m);
    m->n_verts = 2 + nu * (nv - 1);
    m->n_faces = 2 * nu * (nv - 1);
    m->pos = malloc(sizeof(float) * 3 * (size_t)m->n_verts);
    m->faces = malloc(sizeof(int32_t) * 3 * (size_t)m->n_faces);
    if (!m->pos || !m->faces) return 0;
    // vertex 0 = north pole (+y), 1 = south pole, then ring r (1..nv-1), segment j: 2 + (r-1)·nu + j
    for (int r = 0; r <= nv; r++) {
        double th = M_PI * r / nv;
        for (int j = 0; j < nu; j++) {
            double ph = 2 * M_PI * j / nu;
            double d[3] = {sin(th) * cos(ph), cos(th), sin(th) * sin(ph)};
            double rad = lobed_radius(d[0], d[1], d[2]);
            int idx = r == 0 ? 0 : r == nv ? 1 : 2 + (r - 1) * nu + j;
            for (int k = 0; k < 3; k++) m->pos[3 * idx + k] = (float)(rad * d[k]);
            if (r == 0 || r == nv) break;
        }
    }
    int f = 0;
#define RING(r, j) (2 + ((r) - 1) * nu + ((j) % nu))
    for (int j = 0; j < nu; j++) {   // caps; direction chosen so that normals point outward
        int32_t* t = m->faces + 3 * f++;
        t[0] = 0; t[1] = RING(1, j + 1); t[2] = RING(1, j);
        t = m->faces + 3 * f++;
        t[0] = 1; t[1] = RING(nv - 1, j); t[2] = RING(nv - 1, j + 1);
    }
    for (int r = 1; r < nv - 1; r++)
        for (int j = 0; j < nu; j++) {
            int32_t a = RING(r, j), b = RING(r, j + 1), c = RING(r + 1, j), d = RING(r + 1, j + 1);
            int32_t* t = m->faces + 3 * f++;
            t[0] = a; t[1] = b; t[2] = d;
            t = m->faces + 3 * f++;
            t[0] = a; t[1] = d; t[2] = c;
        }
#undef RING
    return f == m->n_faces;
}

// Signed volume (positive for an outward-facing closed mesh).
static double mesh_volume(const mlb_mesh* m) {
    double v = 0;
    for (int f = 0; f < m->n_faces; f++) {
        const float *a = m->pos + 3 * m->faces[3 * f], *b = m->pos + 3 * m->faces[3 * f + 1], *c = m->pos + 3 * m->faces[3 * f + 2];
        v += (a[0] * ((double)b[1] * c[2] - (double)b[2] * c[1]) - a[1] * ((double)b[0] * c[2] - (double)b[2] * c[0]) +
              a[2] * ((double)b[0] * c[1] - (double)b[1] * c[0])) / 6.0;
    }
    return v;
}

static const float SHAPE_SCALE = 0.8f;                        // target and init: inside the sphere of radius 0.8
static const float INIT_AXES[3] = {1.0f, 0.8f, 0.9f};        // the init ellipsoid's semi-axes / SHAPE_SCALE

static int access_ok(const char* path) {
    struct stat st;
    return stat(path, &st) == 0 && S_ISREG(st.st_mode);
}

// spot (normalised to the unit sphere × SHAPE_SCALE) when the shared data has it, else the lobed shape.
static int make_target(mlb_mesh* t, const char** name) {
    const char* data = getenv("MLB_TEST_PROCEDURAL") ? NULL : test_shared_data();   // set it to test the fallback
    char path[4200];
    if (data) {
        snprintf(path, sizeof path, "%s/meshes/spot/spot.obj", data);
        mlb_obj_options o = {0};
        o.drop_uv = 1;
        o.drop_normals = 1;
        if (access_ok(path) && mlb_obj_load_ex(path, t, &o, NULL) == MLB_OK) *name = "spot";
        else data = NULL;
    }
    if (!data) {
        if (!lobed_mesh(t, 96, 48)) return 0;
        *name = "procedural three-lobed shape";
    }
    mlb_mesh_normalize_unit_sphere(t);
    for (int i = 0; i < 3 * t->n_verts; i++) t->pos[i] *= SHAPE_SCALE;
    return 1;
}

// The networks of the test: 8 levels, a 2^14 table (as test_geometry_net's init tests).
static mlb_geometry_config net_config(void) {
    mlb_geometry_config c = mlb_geometry_default();
    c.enc = (mlb_hashgrid_config){8, 2, 1u << 14, 16, 1.5};
    return c;
}

static mlb_geofit_config fit_config(void) {
    mlb_geofit_config c = mlb_geofit_default();
    c.cells = 24;
    c.res = 64;
    c.views = 2;
    c.iters = 300;
    c.lr = 1e-2;
    return c;
}

static int init_ellipsoid(mlb_geometry_net* net) {
    mlb_geometry_config c = net_config();
    if (geometry_net_init(net, &c) != MLB_OK) return 0;
    mlb_shape s;
    mlb_shape_ellipsoid(&s, SHAPE_SCALE, INIT_AXES);
    mlb_shape_fit_config fc = mlb_shape_fit_default();
    fc.iters = 200;
    fc.batch = 3072;
    fc.pool = 4096;
    double loss;
    int ok = mlb_geometry_fit_shape(net, &s, &fc, NULL, &loss) == MLB_OK;
    mlb_shape_free(&s);
    return ok;
}

static double chamfer_rel(mlb_geometry_net* net, int cells, const mlb_mesh* target, int* n_faces) {
    mlb_tetgrid g;
    mlb_mesh m;
    double rel = INFINITY;
    if (mlb_tetgrid_create(&g, cells, net->cfg.scale) != MLB_OK) return rel;
    if (mlb_geometry_extract(NULL, net, &g, &m) == MLB_OK) {
        mlb_chamfer_result r;
        if (mlb_chamfer(&m, target, 20000, 1, &r) == MLB_OK) {
            rel = r.relative;
            printf("  %d faces: chamfer %.5f = %.5f of the diagonal %.3f, max %.4f / %.4f\n", m.n_faces, r.chamfer, r.relative,
                   r.diag, r.max_a_to_b, r.max_b_to_a);
        }
        *n_faces = m.n_faces;
        mlb_mesh_free(&m);
    }
    mlb_tetgrid_free(&g);
    return rel;
}

typedef struct { int n; double loss[4096], img[4096]; } loss_log;

static int log_step(void* user, int it, const mlb_geofit_stats* st) {
    loss_log* l = user;
    if (it < 4096) { l->loss[it] = st->loss; l->img[it] = st->img; l->n = it + 1; }
    return 0;
}

static double mean_of(const double* x, int a, int b) {
    double s = 0;
    for (int i = a; i < b; i++) s += x[i];
    return s / (b - a);
}

TEST(target_mesh) {
    mlb_mesh t;
    const char* name;
    REQUIRE(make_target(&t, &name));
    CHECK(mesh_volume(&t) > 0);
    float lo[3], hi[3];
    mlb_mesh_bounds(&t, lo, hi);
    for (int k = 0; k < 3; k++) CHECK(lo[k] > -SHAPE_SCALE - 1e-4f && hi[k] < SHAPE_SCALE + 1e-4f);
    // the target's render: nonzero coverage and unit-ish normals at covered pixels
    mlb_geofit_config c = fit_config();
    mlb_camera cam;
    REQUIRE(mlb_geofit_camera(&cam, &c, 0, 0) == MLB_OK);
    float* img = malloc(sizeof(float) * 64 * 64 * 4);
    REQUIRE(img);
    REQUIRE(mlb_geofit_render_mesh(NULL, img, &t, &cam, 64, 1) == MLB_OK);
    int covered = 0;
    for (int i = 0; i < 64 * 64; i++) {
        if (img[4 * i + 3] == 1.0f) {
            covered++;
            double n = sqrt(img[4 * i] * img[4 * i] + img[4 * i + 1] * img[4 * i + 1] + img[4 * i + 2] * img[4 * i + 2]);
            CHECK(n > 0.5 && n < 1.0001);
        }
    }
    CHECK(covered > 200);
    free(img);
    mlb_mesh_free(&t);
}

TEST(schedule_and_cameras) {
    mlb_geofit_config c = mlb_geofit_default();
    c.iters = 400;
    CHECK_CLOSE(mlb_sdf_reg_weight(&c.sdf_reg, 0, c.iters), 0.2, 0, 1e-12);
    CHECK_CLOSE(mlb_sdf_reg_weight(&c.sdf_reg, 50, c.iters), 0.105, 0, 1e-12);
    CHECK_CLOSE(mlb_sdf_reg_weight(&c.sdf_reg, 100, c.iters), 0.01, 0, 1e-12);
    CHECK_CLOSE(mlb_sdf_reg_weight(&c.sdf_reg, 399, c.iters), 0.01, 0, 1e-12);
    double el_lo = 90, el_hi = -90, az_lo = 360, az_hi = -360;
    for (int it = 0; it < 200; it++)
        for (int v = 0; v < 2; v++) {
            mlb_camera cam, again;
            REQUIRE(mlb_geofit_camera(&cam, &c, it, v) == MLB_OK);
            REQUIRE(mlb_geofit_camera(&again, &c, it, v) == MLB_OK);
            CHECK(memcmp(&cam, &again, sizeof cam) == 0);
            CHECK_CLOSE(cam.radius, 3.0, 0, 1e-12);
            el_lo = fmin(el_lo, cam.elevation_deg); el_hi = fmax(el_hi, cam.elevation_deg);
            az_lo = fmin(az_lo, cam.azimuth_deg); az_hi = fmax(az_hi, cam.azimuth_deg);
        }
    CHECK(el_lo >= -10 && el_hi <= 45 && el_lo < 0 && el_hi > 40);
    CHECK(az_lo >= -180 && az_hi <= 180 && az_lo < -170 && az_hi > 170);
}

// The whole chain in double: image loss + regulariser w.r.t. network parameters vs central
// differences, on a tiny setup (4 levels, T 256, 8-wide MLP, 6 cells, 2 views of 24 px, 2×
// supersampling). A perturbation that changes any view's coverage is skipped (counted).
TEST(fd_full_chain_f64) {
    mlb_geometry_config c = mlb_geometry_default();
    c.enc = (mlb_hashgrid_config){4, 2, 256, 4, 1.5};
    c.hidden = 8;
    mlb_geometry_net net = {0};
    mlb_geometry_net_f64 nd = {0};
    REQUIRE(geometry_net_init(&net, &c) == MLB_OK);
    REQUIRE(geometry_net_init_f64(&nd, &c) == MLB_OK);
    mlb_shape s;
    mlb_shape_ellipsoid(&s, SHAPE_SCALE, INIT_AXES);
    mlb_shape_fit_config fc = mlb_shape_fit_default();
    fc.iters = 150; fc.batch = 1536; fc.pool = 2048;
    REQUIRE(mlb_geometry_fit_shape(&net, &s, &fc, NULL, NULL) == MLB_OK);
    mlb_shape_free(&s);
    for (size_t i = 0; i < net.n_params; i++) nd.params[i] = net.params[i];
    // a nonzero deformation too, so its path is exercised
    mlb_mesh t;
    const char* name;
    REQUIRE(make_target(&t, &name));
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 6, c.scale) == MLB_OK);
    enum { RES = 24, SS = 2, VIEWS = 2 };
    mlb_geofit_config fcfg = mlb_geofit_default();
    fcfg.views = VIEWS;
    mlb_camera cams[VIEWS];
    double* targets = malloc(sizeof(double) * RES * RES * 4 * VIEWS);
    REQUIRE(targets);
    for (int v = 0; v < VIEWS; v++) {
        REQUIRE(mlb_geofit_camera(&cams[v], &fcfg, 3, v) == MLB_OK);
        REQUIRE(mlb_geofit_render_mesh_f64(NULL, targets + RES * RES * 4 * v, &t, &cams[v], RES, SS) == MLB_OK);
    }
    mlb_geofit_stats st0, sp, sm;
    geometry_net_zero_grad_f64(&nd);
    REQUIRE(mlb_geofit_loss_f64(&nd, &g, cams, VIEWS, targets, RES, SS, 1.0, 1.0, 0.1, 1, &st0) == MLB_OK);
    printf("  %d faces, loss %.6g (img %.6g, reg %.6g)\n", st0.n_faces, st0.loss, st0.img, st0.reg);
    CHECK(st0.n_faces > 20);
    double* grad = malloc(sizeof(double) * nd.n_params);
    REQUIRE(grad);
    memcpy(grad, nd.grads, sizeof(double) * nd.n_params);
    // a second backward doubles the gradient (accumulation)
    REQUIRE(mlb_geofit_loss_f64(&nd, &g, cams, VIEWS, targets, RES, SS, 1.0, 1.0, 0.1, 1, &sp) == MLB_OK);
    double acc = 0;   // (not bitwise: the table backward adds corner by corner into the buffer)
    for (size_t i = 0; i < nd.n_params; i++) acc = fmax(acc, fabs(nd.grads[i] - 2 * grad[i]) / (1e-300 + fabs(grad[i]) + 1e-12));
    CHECK(acc < 1e-9);
    // the parameters with the largest gradients: 8 from the table, 8 from the MLP
    size_t pick[16];
    int np = 16;
    test_top_grads(grad, nd.n_enc, nd.n_params, 8, pick);
    int checked = 0, skipped = 0;
    double worst = 0;
    for (int q = 0; q < np; q++) {
        size_t i = pick[q];
        double x0 = nd.params[i], h = 1e-6 * fmax(1.0, fabs(x0));
        nd.params[i] = x0 + h;
        REQUIRE(mlb_geofit_loss_f64(&nd, &g, cams, VIEWS, targets, RES, SS, 1.0, 1.0, 0.1, 0, &sp) == MLB_OK);
        nd.params[i] = x0 - h;
        REQUIRE(mlb_geofit_loss_f64(&nd, &g, cams, VIEWS, targets, RES, SS, 1.0, 1.0, 0.1, 0, &sm) == MLB_OK);
        nd.params[i] = x0;
        if (sp.coverage != st0.coverage || sm.coverage != st0.coverage || sp.n_faces != st0.n_faces || sm.n_faces != st0.n_faces) {
            skipped++;
            continue;
        }
        double fd = (sp.loss - sm.loss) / (2 * h);
        double err = fabs(fd - grad[i]) / (1e-8 + 1e-4 * fabs(fd) + 1e-4 * fabs(grad[i]));
        if (err > 1) printf("  param %zu (%s): analytic %.9g, fd %.9g\n", i, i < nd.n_enc ? "table" : "mlp", grad[i], fd);
        worst = fmax(worst, err);
        checked++;
    }
    printf("  %d parameters checked (%d skipped: coverage changed), worst error / tolerance %.3g\n", checked, skipped, worst);
    CHECK(checked >= 12);
    CHECK(worst <= 1);
    free(grad);
    free(targets);
    mlb_tetgrid_free(&g);
    mlb_mesh_free(&t);
    geometry_net_free(&net);
    geometry_net_free_f64(&nd);
}

// The end-to-end fit: ellipsoid start → the target's silhouettes and normal maps.
TEST(fit_to_target) {
    mlb_mesh t;
    const char* name;
    REQUIRE(make_target(&t, &name));
    printf("  target: %s (%d faces)\n", name, t.n_faces);
    mlb_geometry_net net = {0};
    REQUIRE(init_ellipsoid(&net));
    mlb_geofit_config c = fit_config();
    int nf = 0;
    double start = chamfer_rel(&net, c.cells, &t, &nf);
    static loss_log log;
    memset(&log, 0, sizeof log);
    mlb_geofit_stats last;
    REQUIRE(mlb_geometry_fit_images(&net, &t, &c, NULL, log_step, &log, &last) == MLB_OK);
    REQUIRE(log.n == c.iters);
    double first = mean_of(log.img, 0, 20), final = mean_of(log.img, c.iters - 20, c.iters);
    printf("  image loss: first 20 steps %.5f, last 20 %.5f; by 50 steps:", first, final);
    for (int i = 0; i + 50 <= c.iters; i += 50) printf(" %.4f", mean_of(log.img, i, i + 50));
    printf("\n");
    double end = chamfer_rel(&net, c.cells, &t, &nf);
    printf("  relative chamfer: start %.5f -> end %.5f\n", start, end);
    CHECK(final < 0.5 * first);
    // h = 2.1/24 = 0.0875; a pixel at the target is 2·3·tan(22.5°)/64 = 0.039. The bound: a sixth
    // of a cell (0.0146, ~0.37 px) over the target's diagonal (docs/geometry_fit.md).
    float lo[3], hi[3];
    mlb_mesh_bounds(&t, lo, hi);
    double diag = sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) + (hi[2] - lo[2]) * (hi[2] - lo[2]));
    double bound = (2.1 / 24) / 6 / diag;
    printf("  bound %.5f\n", bound);
    CHECK_MSG(end < bound, "relative chamfer %g, bound %g", end, bound);
    CHECK_MSG(end < 0.5 * start, "start %g, end %g", start, end);
    geometry_net_free(&net);
    mlb_mesh_free(&t);
}

// Same seed → bitwise the same parameters; another camera seed differs.
TEST(determinism) {
    mlb_mesh t;
    const char* name;
    REQUIRE(make_target(&t, &name));
    mlb_geometry_net a = {0}, b = {0};
    REQUIRE(init_ellipsoid(&a));
    REQUIRE(init_ellipsoid(&b));
    REQUIRE(memcmp(a.params, b.params, sizeof(float) * a.n_params) == 0);
    mlb_geofit_config c = fit_config();
    c.iters = 8;
    // Same thread count, twice: bitwise equal (1 vs 2 threads: threads_bitwise).
    REQUIRE(mlb_geometry_fit_images(&a, &t, &c, NULL, NULL, NULL, NULL) == MLB_OK);
    REQUIRE(mlb_geometry_fit_images(&b, &t, &c, NULL, NULL, NULL, NULL) == MLB_OK);
    CHECK(memcmp(a.params, b.params, sizeof(float) * a.n_params) == 0);
    CHECK(a.step == b.step);
    // a different camera seed gives a different result
    c.seed = 2;
    REQUIRE(mlb_geometry_fit_images(&b, &t, &c, NULL, NULL, NULL, NULL) == MLB_OK);
    CHECK(memcmp(a.params, b.params, sizeof(float) * a.n_params) != 0);
    geometry_net_free(&a);
    geometry_net_free(&b);
    mlb_mesh_free(&t);
}

// The tiny double setup of the FD tests: an ellipsoid-initialised 4-level network copied to double.
static int tiny_net_f64(mlb_geometry_net_f64* nd) {
    mlb_geometry_config c = mlb_geometry_default();
    c.enc = (mlb_hashgrid_config){4, 2, 256, 4, 1.5};
    c.hidden = 8;
    mlb_geometry_net net = {0};
    if (geometry_net_init(&net, &c) != MLB_OK || geometry_net_init_f64(nd, &c) != MLB_OK) return 0;
    mlb_shape s;
    mlb_shape_ellipsoid(&s, SHAPE_SCALE, INIT_AXES);
    mlb_shape_fit_config fc = mlb_shape_fit_default();
    fc.iters = 150; fc.batch = 1536; fc.pool = 2048;
    int ok = mlb_geometry_fit_shape(&net, &s, &fc, NULL, NULL) == MLB_OK;
    mlb_shape_free(&s);
    for (size_t i = 0; i < net.n_params; i++) nd->params[i] = net.params[i];
    geometry_net_free(&net);
    return ok;
}

// L = Σ R·images + λ·reg for the split forward / backward: an external image gradient R (random,
// fixed) through the whole chain, against central differences in double.
static double ext_loss(mlb_geofit_state_f64* st, mlb_geometry_net_f64* nd, const mlb_tetgrid* g, const mlb_camera* cams,
                       int n, int res, int ss, const double* R, double lambda, mlb_geofit_stats* stats) {
    if (mlb_geofit_forward_f64(st, nd, g, cams, n, res, ss, NULL, stats) != MLB_OK) return NAN;
    double L = 0;
    for (size_t i = 0; i < (size_t)n * res * res * 4; i++) L += R[i] * st->images[i];
    return L + lambda * stats->reg;
}

TEST(fd_external_gradient_f64) {
    mlb_geometry_net_f64 nd = {0};
    REQUIRE(tiny_net_f64(&nd));
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 6, nd.cfg.scale) == MLB_OK);
    enum { RES = 20, SS = 2, VIEWS = 3 };
    mlb_geofit_config fcfg = mlb_geofit_default();
    fcfg.views = VIEWS;
    mlb_camera cams[VIEWS];
    for (int v = 0; v < VIEWS; v++) REQUIRE(mlb_geofit_camera(&cams[v], &fcfg, 5, v) == MLB_OK);
    size_t N = (size_t)VIEWS * RES * RES * 4;
    double* R = malloc(sizeof(double) * N);
    double* imgs = malloc(sizeof(double) * N);
    REQUIRE(R && imgs);
    for (size_t i = 0; i < N; i++) R[i] = mlb_rng_normal_f64(11, 1, i) / (double)(RES * RES);
    const double lambda = 0.05;
    mlb_geofit_state_f64 st = {0};
    mlb_geofit_stats s0, sp, sm;
    geometry_net_zero_grad_f64(&nd);
    REQUIRE(mlb_geofit_forward_f64(&st, &nd, &g, cams, VIEWS, RES, SS, imgs, &s0) == MLB_OK);
    CHECK(memcmp(imgs, st.images, sizeof(double) * N) == 0);
    CHECK(s0.n_faces == st.surf.n_faces && s0.n_faces > 20 && s0.img == 0 && s0.reg > 0);
    REQUIRE(mlb_geofit_backward_f64(&st, &nd, R, lambda) == MLB_OK);
    double* grad = malloc(sizeof(double) * nd.n_params);
    REQUIRE(grad);
    memcpy(grad, nd.grads, sizeof(double) * nd.n_params);
    // the renders equal mlb_geofit_loss's (the L2 loss is built on the same forward)
    size_t pick[12];
    int np = 12;
    test_top_grads(grad, nd.n_enc, nd.n_params, 6, pick);
    int checked = 0, skipped = 0;
    double worst = 0;
    for (int q = 0; q < np; q++) {
        size_t i = pick[q];
        double x0 = nd.params[i], h = 1e-6 * fmax(1.0, fabs(x0));
        nd.params[i] = x0 + h;
        double Lp = ext_loss(&st, &nd, &g, cams, VIEWS, RES, SS, R, lambda, &sp);
        nd.params[i] = x0 - h;
        double Lm = ext_loss(&st, &nd, &g, cams, VIEWS, RES, SS, R, lambda, &sm);
        nd.params[i] = x0;
        REQUIRE(isfinite(Lp) && isfinite(Lm));
        if (sp.coverage != s0.coverage || sm.coverage != s0.coverage || sp.n_faces != s0.n_faces || sm.n_faces != s0.n_faces) {
            skipped++;
            continue;
        }
        double fd = (Lp - Lm) / (2 * h);
        double err = fabs(fd - grad[i]) / (1e-8 + 1e-4 * fabs(fd) + 1e-4 * fabs(grad[i]));
        if (err > 1) printf("  param %zu (%s): analytic %.9g, fd %.9g\n", i, i < nd.n_enc ? "table" : "mlp", grad[i], fd);
        worst = fmax(worst, err);
        checked++;
    }
    printf("  %d faces; %d parameters checked (%d skipped), worst error / tolerance %.3g\n", s0.n_faces, checked, skipped, worst);
    CHECK(checked >= 9);
    CHECK(worst <= 1);
    // a backward with no image gradient is the regulariser's alone; without a forward it is an error
    mlb_geofit_state_f64 fresh = {0};
    CHECK(mlb_geofit_backward_f64(&fresh, &nd, R, 0) == MLB_ERR_ARG);
    mlb_geofit_state_free_f64(&st);
    mlb_geofit_state_free_f64(&st);   // safe twice
    free(grad); free(R); free(imgs);
    mlb_tetgrid_free(&g);
    geometry_net_free_f64(&nd);
}

// dst = a copy of src: parameters and Adam state (moments and step count).
static int clone_net(mlb_geometry_net* dst, const mlb_geometry_net* src) {
    if (geometry_net_init(dst, &src->cfg) != MLB_OK) return 0;
    memcpy(dst->params, src->params, sizeof(float) * src->n_params);
    memcpy(dst->adam_m, src->adam_m, sizeof(float) * src->n_params);
    memcpy(dst->adam_v, src->adam_v, sizeof(float) * src->n_params);
    dst->step = src->step;
    return 1;
}

// A guidance that is the fit's own L2 loss (w 1, 1) against fixed targets: the guided step must give
// exactly the gradient of mlb_geofit_loss, and report the same losses. It guides a part of a step
// as guidance.h asks (the step calls it once per micro-batch of views).
typedef struct { const float* targets; int calls; } l2_guidance;
static mlb_status l2_loss(mlb_guidance* g, mlb_stage stage, long step, const mlb_view* views, int n, const float* images,
                          int H, int W, float* dimages, double* loss) {
    l2_guidance* u = g->impl;
    u->calls++;
    if (stage != MLB_STAGE_GEOMETRY) return mlb_fail(MLB_ERR_ARG, "wrong stage");
    size_t p = (size_t)H * W;
    int total = g->part_total > 0 ? g->part_total : n;
    const float* targets = u->targets + (size_t)g->part_first * p * 4;
    double norm = 1.0 / ((double)total * p), L = 0;
    for (int v = 0; v < n; v++) {
        double sum = 0;
        for (size_t i = (size_t)v * p * 4; i < (size_t)(v + 1) * p * 4; i++) {
            double d = (double)images[i] - targets[i];
            sum += d * d;
            if (dimages) dimages[i] += (float)(2.0 * d * norm);
        }
        L += sum * norm;
    }
    *loss = L;
    return MLB_OK;
}

TEST(guided_step_equals_fit_loss) {
    mlb_mesh t;
    const char* name;
    REQUIRE(make_target(&t, &name));
    mlb_geometry_net a = {0}, b = {0};
    REQUIRE(init_ellipsoid(&a));
    REQUIRE(clone_net(&b, &a));
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 16, a.cfg.scale) == MLB_OK);
    enum { RES = 48, VIEWS = 3 };
    mlb_geofit_config c = fit_config();
    c.views = VIEWS;
    mlb_view views[VIEWS];
    mlb_camera cams[VIEWS];
    float* targets = malloc(sizeof(float) * RES * RES * 4 * VIEWS);
    float* shown = malloc(sizeof(float) * RES * RES * 4 * VIEWS);
    REQUIRE(targets && shown);
    for (int v = 0; v < VIEWS; v++) {
        memset(&views[v], 0, sizeof views[v]);
        REQUIRE(mlb_geofit_camera(&cams[v], &c, 7, v) == MLB_OK);
        views[v].cam = cams[v];
        REQUIRE(mlb_geofit_render_mesh(NULL, targets + RES * RES * 4 * v, &t, &cams[v], RES, 1) == MLB_OK);
    }
    l2_guidance u = {targets, 0};
    mlb_guidance gd = {.kind = "l2", .n_views = VIEWS, .loss = l2_loss, .impl = &u};
    mlb_geofit_state st = {0};
    mlb_geofit_stats s1, s2;
    geometry_net_zero_grad(&b);
    REQUIRE(mlb_geofit_loss(&b, &g, cams, VIEWS, targets, RES, 1, 1.0, 1.0, 0.1, 1, &s2) == MLB_OK);
    // micro-batches of views (view_batch): all 3 in one call (0, the default, and 3), 2 + 1, 1 + 1 + 1;
    // this guidance treats views independently, so every batching gives the same bits
    const int batch[4] = {0, 3, 2, 1}, calls[4] = {1, 1, 2, 3};
    for (int i = 0; i < 4; i++) {
        gd.view_batch = batch[i];
        u.calls = 0;
        REQUIRE(mlb_geometry_guided_step(&st, &a, &g, &gd, 3, views, RES, 1, 0.1, &s1, shown) == MLB_OK);
        CHECK_MSG(u.calls == calls[i], "view_batch %d: %d calls", batch[i], u.calls);
        CHECK(memcmp(a.grads, b.grads, sizeof(float) * a.n_params) == 0);
        CHECK(s1.img == s2.img && s1.reg == s2.reg && s1.loss == s2.loss && s1.n_faces == s2.n_faces &&
              s1.coverage == s2.coverage);
        CHECK(memcmp(shown, st.images, sizeof(float) * RES * RES * 4 * VIEWS) == 0);
    }
    gd.view_batch = 0;
    printf("  loss %.6f (img %.6f, reg %.4f), %d faces\n", s1.loss, s1.img, s1.reg, s1.n_faces);
    // the step's surface is the extracted mesh of the network
    mlb_mesh m, e;
    REQUIRE(mlb_geofit_state_mesh(&st, &m) == MLB_OK);
    REQUIRE(mlb_geometry_extract(NULL, &a, &g, &e) == MLB_OK);
    CHECK(m.n_faces == s1.n_faces && m.n_faces == e.n_faces && m.n_verts == e.n_verts);
    CHECK(memcmp(m.faces, e.faces, sizeof(int32_t) * 3 * (size_t)m.n_faces) == 0);
    double dmax = 0;
    for (int i = 0; i < 3 * m.n_verts; i++) dmax = fmax(dmax, fabs(m.pos[i] - e.pos[i]));
    CHECK(dmax < 1e-5);
    // a second step reuses the state
    REQUIRE(mlb_geometry_guided_step(&st, &a, &g, &gd, 4, views, RES, 1, 0.1, &s1, NULL) == MLB_OK);
    mlb_mesh_free(&m);
    mlb_mesh_free(&e);
    mlb_geofit_state_free(&st);
    free(targets); free(shown);
    mlb_tetgrid_free(&g);
    geometry_net_free(&a);
    geometry_net_free(&b);
    mlb_mesh_free(&t);
}

// 1 and 2 threads give bitwise the same parameters after a few fit steps (mlb_gemm and every
// reduction are thread-count independent).
TEST(threads_bitwise) {
    mlb_mesh t;
    const char* name;
    REQUIRE(make_target(&t, &name));
    mlb_geometry_net a = {0}, b = {0};
    REQUIRE(init_ellipsoid(&a));
    REQUIRE(clone_net(&b, &a));
    mlb_geofit_config c = fit_config();
    c.iters = 4;
    int keep = mlb_get_threads();
    mlb_set_threads(1);
    REQUIRE(mlb_geometry_fit_images(&a, &t, &c, NULL, NULL, NULL, NULL) == MLB_OK);
    mlb_set_threads(2);
    REQUIRE(mlb_geometry_fit_images(&b, &t, &c, NULL, NULL, NULL, NULL) == MLB_OK);
    mlb_set_threads(keep);
    size_t diff = 0;
    for (size_t i = 0; i < a.n_params; i++) diff += a.params[i] != b.params[i];
    CHECK_MSG(diff == 0, "%zu of %zu parameters differ between 1 and 2 threads", diff, a.n_params);
    geometry_net_free(&a);
    geometry_net_free(&b);
    mlb_mesh_free(&t);
}

int main(void) {
    RUN(target_mesh);
    RUN(schedule_and_cameras);
    RUN(fd_full_chain_f64);
    RUN(fit_to_target);
    RUN(determinism);
    RUN(fd_external_gradient_f64);
    RUN(guided_step_equals_fit_loss);
    RUN(threads_bitwise);
    return test_summary();
}
