// Finite-difference checks, in double (the _f64 build of the same code), of every backward of the
// rasterizer: camera transform, interpolate (attributes, barycentrics, and through them the
// clip-space positions), rasterize (barycentrics and depth to positions), antialias (colours and
// the silhouette's positions), the whole chain, box downsampling and compositing; and float
// against double.
//
// Face ids per pixel are piecewise constant in the positions, so a finite difference is only
// meaningful while no pixel changes face: the steps are 1e-6 in clip space (a hundred-thousandth
// of a pixel), and every perturbed render is compared with the unperturbed one; a coordinate whose
// perturbation changes any face id (or the set of blended pixel pairs) is left out, and each test
// requires that almost none is. Inside that region the rendered functional is smooth, and
// analytic and central-difference gradients agree to ~1e-7 relative.
#include "test.h"
#include "raster_test_util.h"
#include <string.h>

#define SEED 20261121u
#define FD_H 1e-6
#define FD_RTOL 1e-6

static int n_checked, n_failed;
static void check_grad(const char* what, int i, double analytic, double fd, double atol) {
    n_checked++;
    if (fabs(analytic - fd) <= FD_RTOL * fabs(fd) + atol && !isnan(analytic)) return;
    if (n_failed++ < 10)
        printf("  %s: %s[%d]: analytic %.12g, finite difference %.12g (atol %g)\n", test_case_name, what, i, analytic, fd, atol);
    test_case_failed = 1;
}
static double* dnormal(size_t n, uint64_t stream, double scale) {
    double* x = malloc(sizeof(double) * (n ? n : 1));
    for (size_t i = 0; i < n; i++) x[i] = scale * mlb_rng_normal_f64(SEED, stream, i);
    return x;
}
static double dot(const double* a, const double* b, size_t n) {
    double s = 0;
    for (size_t i = 0; i < n; i++) s += a[i] * b[i];
    return s;
}

// A small scene in clip space: a hexagonal fan (vertex 0 in the middle) and a triangle through
// every other rim vertex that cuts through it, jittered, with z in [-0.6, 0.6] and w in [1.2, 3]
// (so perspective matters): 7 vertices, 7 faces.
static const int32_t fan_faces[] = {0, 1, 2, 0, 2, 3, 0, 3, 4, 0, 4, 5, 0, 5, 6, 0, 6, 1, 1, 3, 5};
static double* fan_clip(uint64_t stream) {
    double* clip = malloc(sizeof(double) * 4 * 7);
    for (int v = 0; v < 7; v++) {
        double u[5];
        for (int k = 0; k < 5; k++) u[k] = mlb_rng_uniform_f64(SEED, stream, 5 * v + k);
        double a = M_PI / 3 * v + (u[0] - 0.5) * 0.5, r = v ? 0.65 + 0.25 * u[1] : 0.2 * u[1];
        double w = 1.2 + 1.8 * u[3];
        clip[4 * v] = r * cos(a) * w;
        clip[4 * v + 1] = r * sin(a) * w;
        clip[4 * v + 2] = (-0.6 + 1.2 * u[2]) * w;
        clip[4 * v + 3] = w;
    }
    return clip;
}

// ---- camera transform ------------------------------------------------------------------------------
TEST(transform_fd) {
    mlb_camera cam;
    REQUIRE(mlb_camera_orbit(&cam, 70, 15, 3, NULL, 33, 1.3, 0.1, 50) == MLB_OK);
    int V = 7;
    double *pos = dnormal(3 * V, 1, 0.5), *wgt = dnormal(4 * V, 2, 1), clip[28], dpos[21] = {0};
    mlb_transform_points_backward_f64(dpos, wgt, V, &cam.view_proj);
    for (int i = 0; i < 3 * V; i++) {
        double x = pos[i], Lp, Lm;
        pos[i] = x + FD_H; mlb_transform_points_f64(clip, pos, V, &cam.view_proj); Lp = dot(clip, wgt, 4 * V);
        pos[i] = x - FD_H; mlb_transform_points_f64(clip, pos, V, &cam.view_proj); Lm = dot(clip, wgt, 4 * V);
        pos[i] = x;
        check_grad("dpos", i, dpos[i], (Lp - Lm) / (2 * FD_H), 1e-8);
    }
    free(pos); free(wgt);
}

// ---- interpolate + rasterize backward ---------------------------------------------------------------
typedef struct {
    int H, W, V, F, C;
    const int32_t* faces;
    const int32_t* opp;
    double* attr;       // [V, C]
    double* w_out;      // [H, W, C] weights of the interpolated (or antialiased) image
    double* w_depth;    // [H, W] weights of the depth
    double* color;      // [H, W, C] fixed colours (antialias-only functional)
    int mode;           // 0: interpolate + depth; 1: antialias of `color`; 2: antialias of the interpolation
    int32_t* tri;       // [H, W] face ids of the last render
    double *bary, *depth, *img, *aa, *wgt;
} scene;

static void scene_alloc(scene* s) {
    size_t n = (size_t)s->H * s->W;
    s->tri = malloc(sizeof(int32_t) * n);
    s->bary = malloc(sizeof(double) * 2 * n);
    s->depth = malloc(sizeof(double) * n);
    s->img = malloc(sizeof(double) * n * s->C);
    s->aa = malloc(sizeof(double) * n * s->C);
    s->wgt = malloc(sizeof(double) * 2 * n);
}
static void scene_free(scene* s) { free(s->tri); free(s->bary); free(s->depth); free(s->img); free(s->aa); free(s->wgt); }

// The functional L(clip) of the scene's mode; 0 and *ok = 0 on an error.
static double scene_L(scene* s, const double* clip, int* ok) {
    size_t n = (size_t)s->H * s->W;
    *ok = mlb_rasterize_f64(NULL, s->tri, s->bary, s->depth, NULL, clip, s->V, s->faces, s->F, s->H, s->W) == MLB_OK;
    if (s->mode != 1)
        *ok = *ok && mlb_interpolate_f64(s->img, s->attr, s->V, s->C, s->tri, s->bary, s->faces, s->F, s->H, s->W) == MLB_OK;
    if (s->mode == 0) return dot(s->img, s->w_out, n * s->C) + dot(s->depth, s->w_depth, n);
    const double* col = s->mode == 1 ? s->color : s->img;
    *ok = *ok && mlb_antialias_f64(NULL, s->aa, s->wgt, col, s->C, s->tri, s->depth, clip, s->V, s->faces, s->opp, s->F, s->H, s->W) == MLB_OK;
    return dot(s->aa, s->w_out, n * s->C);
}

// Analytic dL/dclip (after scene_L at the same clip).
static int scene_grad(scene* s, const double* clip, double* dclip) {
    size_t n = (size_t)s->H * s->W;
    double* dbary = calloc(2 * n, sizeof(double));
    double* dimg = calloc(n * s->C, sizeof(double));
    int ok = 1;
    const double* dinterp = s->w_out;
    if (s->mode >= 1) {
        const double* col = s->mode == 1 ? s->color : s->img;
        ok = mlb_antialias_backward_f64(NULL, dimg, dclip, s->w_out, s->wgt, col, s->C, s->tri, s->depth, clip, s->V, s->faces,
                                        s->opp, s->F, s->H, s->W) == MLB_OK;
        dinterp = dimg;
    }
    if (s->mode != 1)
        ok = ok && mlb_interpolate_backward_f64(NULL, NULL, dbary, dinterp, s->attr, s->V, s->C, s->tri, s->bary, s->faces,
                                                s->F, s->H, s->W) == MLB_OK &&
             mlb_rasterize_backward_f64(NULL, dclip, dbary, s->mode == 0 ? s->w_depth : NULL, s->tri, clip, s->V, s->faces,
                                        s->F, s->H, s->W) == MLB_OK;
    free(dbary);
    free(dimg);
    return ok;
}

// Central differences over every clip coordinate. Returns the number of coordinates left out
// because a perturbation changed a face id or the antialiased pairs; *n_big counts the checked
// coordinates whose gradient is clearly nonzero.
static int scene_fd(scene* s, double* clip, const double* dclip, int* n_big) {
    size_t n = (size_t)s->H * s->W;
    int ok;
    double L0 = scene_L(s, clip, &ok);
    (void)L0;
    int32_t* tri0 = malloc(sizeof(int32_t) * n);
    memcpy(tri0, s->tri, sizeof(int32_t) * n);
    // which pixels antialias changed (the blended set must not change either)
    uint8_t* blend0 = calloc(n, 1);
    uint8_t* blend = calloc(n, 1);
    const double* col = s->mode == 1 ? s->color : s->img;
    for (size_t p = 0; p < n && s->mode; p++)
        for (int c = 0; c < s->C; c++) blend0[p] |= s->aa[p * s->C + c] != col[p * s->C + c];
    double scale = 0;
    for (size_t i = 0; i < n * s->C; i++) scale += fabs(s->w_out[i]);
    int skipped = 0;
    *n_big = 0;
    for (int i = 0; i < 4 * s->V; i++) {
        double x = clip[i], L[2];
        int same = 1;
        for (int k = 0; k < 2; k++) {
            clip[i] = x + (k ? -FD_H : FD_H);
            L[k] = scene_L(s, clip, &ok);
            if (!ok) { printf("  render failed: %s\n", mlb_last_error()); test_case_failed = 1; }
            same &= memcmp(tri0, s->tri, sizeof(int32_t) * n) == 0;
            if (s->mode) {
                col = s->mode == 1 ? s->color : s->img;
                for (size_t p = 0; p < n; p++) {
                    blend[p] = 0;
                    for (int c = 0; c < s->C; c++) blend[p] |= s->aa[p * s->C + c] != col[p * s->C + c];
                }
                same &= memcmp(blend0, blend, n) == 0;
            }
        }
        clip[i] = x;
        if (!same) { skipped++; continue; }
        double fd = (L[0] - L[1]) / (2 * FD_H);
        check_grad("dclip", i, dclip[i], fd, 1e-9 * (scale + 1));
        if (fabs(fd) > 1e-3 * (scale + 1) / 100) (*n_big)++;
    }
    free(tri0); free(blend0); free(blend);
    return skipped;
}

TEST(interpolate_attr_and_bary_fd) {
    int H = 20, W = 24, V = 7, F = 7, C = 3;
    const int32_t* faces = fan_faces;
    double* clip = fan_clip(10);
    int32_t* tri = malloc(sizeof(int32_t) * H * W);
    double* bary = malloc(sizeof(double) * 2 * H * W);
    REQUIRE(mlb_rasterize_f64(NULL, tri, bary, NULL, NULL, clip, V, faces, F, H, W) == MLB_OK);
    double *attr = dnormal(V * C, 11, 1), *w = dnormal(H * W * C, 12, 1), *out = malloc(sizeof(double) * H * W * C);
    double* dattr = calloc(V * C, sizeof(double));
    double* dbary = calloc(2 * H * W, sizeof(double));
    REQUIRE(mlb_interpolate_backward_f64(NULL, dattr, dbary, w, attr, V, C, tri, bary, faces, F, H, W) == MLB_OK);
    for (int i = 0; i < V * C; i++) {
        double x = attr[i], L[2];
        for (int k = 0; k < 2; k++) {
            attr[i] = x + (k ? -FD_H : FD_H);
            REQUIRE(mlb_interpolate_f64(out, attr, V, C, tri, bary, faces, F, H, W) == MLB_OK);
            L[k] = dot(out, w, H * W * C);
        }
        attr[i] = x;
        check_grad("dattr", i, dattr[i], (L[0] - L[1]) / (2 * FD_H), 1e-8);
    }
    int covered = 0;
    for (int p = 0; p < H * W; p++) {
        if (tri[p] < 0) { CHECK(dbary[2 * p] == 0 && dbary[2 * p + 1] == 0); continue; }
        covered++;
        for (int j = 0; j < 2; j++) {
            double x = bary[2 * p + j], L[2];
            for (int k = 0; k < 2; k++) {
                bary[2 * p + j] = x + (k ? -FD_H : FD_H);
                REQUIRE(mlb_interpolate_f64(out, attr, V, C, tri, bary, faces, F, H, W) == MLB_OK);
                L[k] = dot(out + (size_t)p * C, w + (size_t)p * C, C);
            }
            bary[2 * p + j] = x;
            check_grad("dbary", 2 * p + j, dbary[2 * p + j], (L[0] - L[1]) / (2 * FD_H), 1e-8);
        }
    }
    CHECK(covered > H * W / 4);
    free(clip); free(tri); free(bary); free(attr); free(w); free(out); free(dattr); free(dbary);
}

// Interior gradients: L = <w, interpolate(attr)> + <w_d, depth>, through the barycentrics and
// depth to the clip-space positions.
TEST(interpolate_position_fd) {
    for (int trial = 0; trial < 3; trial++) {
        scene s = {.H = 20, .W = 24, .V = 7, .F = 7, .C = 3, .faces = fan_faces, .mode = 0};
        scene_alloc(&s);
        double* clip = fan_clip(20 + trial);
        s.attr = dnormal(s.V * s.C, 30 + trial, 1);
        s.w_out = dnormal(s.H * s.W * s.C, 40 + trial, 1);
        s.w_depth = dnormal(s.H * s.W, 50 + trial, 1);
        int ok, n_big;
        scene_L(&s, clip, &ok);
        REQUIRE(ok);
        double* dclip = calloc(4 * s.V, sizeof(double));
        REQUIRE(scene_grad(&s, clip, dclip));
        int skipped = scene_fd(&s, clip, dclip, &n_big);
        CHECK_MSG(skipped <= 2, "trial %d: %d of %d coordinates changed coverage", trial, skipped, 4 * s.V);
        CHECK_MSG(n_big >= 3 * s.V, "trial %d: only %d clearly nonzero gradients", trial, n_big);
        free(clip); free(dclip); free(s.attr); free(s.w_out); free(s.w_depth);
        scene_free(&s);
    }
}

// ---- antialias -----------------------------------------------------------------------------------------
// A nearer triangle over a farther quad (two faces sharing an edge, which is not a silhouette)
// over the background, with fixed random colours: the gradient moves the silhouette edges.
static const int32_t aa_faces[] = {0, 1, 2, 0, 2, 3, 4, 5, 6};
static double* aa_clip(uint64_t stream) {
    double base[] = {-0.8, -0.7, 0.3, 1, 0.75, -0.8, 0.3, 1, 0.7, 0.65, 0.3, 1, -0.65, 0.8, 0.3, 1,   // quad
                     -0.4, -0.95, -0.2, 1, 0.95, 0.1, -0.2, 1, -0.3, 0.95, -0.2, 1};                // triangle in front
    double* clip = malloc(sizeof base);
    for (int v = 0; v < 7; v++) {   // jitter, then a perspective w
        double w = 1.3 + 1.2 * mlb_rng_uniform_f64(SEED, stream, 10 * v);
        for (int c = 0; c < 2; c++) clip[4 * v + c] = (base[4 * v + c] + 0.08 * mlb_rng_normal_f64(SEED, stream, 10 * v + 1 + c)) * w;
        clip[4 * v + 2] = base[4 * v + 2] * w;
        clip[4 * v + 3] = w;
    }
    return clip;
}

TEST(antialias_color_fd) {
    int H = 16, W = 20, C = 2, V = 7, F = 3;
    double* clip = aa_clip(60);
    int32_t opp[9], *tri = malloc(sizeof(int32_t) * H * W);
    REQUIRE(mlb_edge_topology(opp, aa_faces, F, V) == MLB_OK);
    double* depth = malloc(sizeof(double) * H * W);
    REQUIRE(mlb_rasterize_f64(NULL, tri, NULL, depth, NULL, clip, V, aa_faces, F, H, W) == MLB_OK);
    double *color = dnormal(H * W * C, 61, 1), *w = dnormal(H * W * C, 62, 1), *out = malloc(sizeof(double) * H * W * C);
    double* dcolor = calloc(H * W * C, sizeof(double));
    REQUIRE(mlb_antialias_backward_f64(NULL, dcolor, NULL, w, NULL, color, C, tri, depth, clip, V, aa_faces, opp, F, H, W) == MLB_OK);
    REQUIRE(mlb_antialias_f64(NULL, out, NULL, color, C, tri, depth, clip, V, aa_faces, opp, F, H, W) == MLB_OK);
    int changed = 0;
    for (int i = 0; i < H * W * C; i++) changed += out[i] != color[i];
    CHECK(changed > 20);
    for (int i = 0; i < H * W * C; i++) {
        double x = color[i], L[2];
        for (int k = 0; k < 2; k++) {
            color[i] = x + (k ? -FD_H : FD_H);
            REQUIRE(mlb_antialias_f64(NULL, out, NULL, color, C, tri, depth, clip, V, aa_faces, opp, F, H, W) == MLB_OK);
            L[k] = dot(out, w, H * W * C);
        }
        color[i] = x;
        check_grad("dcolor", i, dcolor[i], (L[0] - L[1]) / (2 * FD_H), 1e-8);
    }
    free(clip); free(tri); free(depth); free(color); free(w); free(out); free(dcolor);
}

TEST(antialias_position_fd) {
    int32_t opp[9];
    REQUIRE(mlb_edge_topology(opp, aa_faces, 3, 7) == MLB_OK);
    CHECK(opp[1] == 1 && opp[5] == 0);   // the quad's diagonal is shared
    for (int trial = 0; trial < 3; trial++) {
        scene s = {.H = 16, .W = 20, .V = 7, .F = 3, .C = 2, .faces = aa_faces, .opp = opp, .mode = 1};
        scene_alloc(&s);
        double* clip = aa_clip(70 + trial);
        s.color = dnormal(s.H * s.W * s.C, 80 + trial, 1);
        s.w_out = dnormal(s.H * s.W * s.C, 90 + trial, 1);
        int ok, n_big;
        scene_L(&s, clip, &ok);
        REQUIRE(ok);
        double* dclip = calloc(4 * s.V, sizeof(double));
        REQUIRE(scene_grad(&s, clip, dclip));
        for (int v = 0; v < s.V; v++) CHECK(dclip[4 * v + 2] == 0);   // z never moves a silhouette
        int skipped = scene_fd(&s, clip, dclip, &n_big);
        CHECK_MSG(skipped <= 2, "trial %d: %d coordinates changed coverage", trial, skipped);
        // x, y and w of the 6 silhouette vertices (the diagonal's ends are silhouette vertices too)
        CHECK_MSG(n_big >= 12, "trial %d: only %d clearly nonzero gradients", trial, n_big);
        free(clip); free(dclip); free(s.color); free(s.w_out);
        scene_free(&s);
    }
}

// An octahedron (closed: its silhouette is where faces turning towards and away from the camera
// meet) in perspective, plus a triangle in front, colours interpolated from the vertices and then
// antialiased: interior and silhouette gradients together.
TEST(pipeline_fd) {
    int32_t faces[] = {0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5, 6, 7, 8};
    double pos[] = {0.8, 0, 0, -0.8, 0, 0, 0, 0.8, 0, 0, -0.8, 0, 0, 0, 0.8, 0, 0, -0.8,
                    -0.9, -0.7, 1.0, 0.1, -0.8, 1.2, -0.5, 0.2, 1.1};
    for (int trial = 0; trial < 2; trial++) {
        mlb_camera cam;
        REQUIRE(mlb_camera_orbit(&cam, 25 + 40 * trial, 20 - 25 * trial, 3, NULL, 40, 1.2, 0.1, 20) == MLB_OK);
        scene s = {.H = 20, .W = 24, .V = 9, .F = 9, .C = 3, .faces = faces, .mode = 2};
        int32_t opp[27];
        REQUIRE(mlb_edge_topology(opp, faces, s.F, s.V) == MLB_OK);
        s.opp = opp;
        scene_alloc(&s);
        double* clip = rt_project(pos, s.V, &cam.view_proj);
        s.attr = dnormal(s.V * s.C, 100 + trial, 1);
        s.w_out = dnormal(s.H * s.W * s.C, 110 + trial, 1);
        int ok, n_big;
        scene_L(&s, clip, &ok);
        REQUIRE(ok);
        double* dclip = calloc(4 * s.V, sizeof(double));
        REQUIRE(scene_grad(&s, clip, dclip));
        int skipped = scene_fd(&s, clip, dclip, &n_big);
        CHECK_MSG(skipped <= 3, "trial %d: %d coordinates changed coverage", trial, skipped);
        CHECK_MSG(n_big >= 18, "trial %d: only %d clearly nonzero gradients", trial, n_big);
        free(clip); free(dclip); free(s.attr); free(s.w_out);
        scene_free(&s);
    }
}

// ---- supersampling and compositing ---------------------------------------------------------------------
TEST(downsample_fd) {
    int H = 5, W = 4, C = 3, s = 3, n_in = H * s * W * s * C;
    double *in = dnormal(n_in, 120, 1), *w = dnormal(H * W * C, 121, 1), out[60], *din = calloc(n_in, sizeof(double));
    mlb_downsample_box_f64(out, in, H, W, C, s);
    // the mean of the first block, channel 1, by hand
    double m = 0;
    for (int i = 0; i < s; i++)
        for (int j = 0; j < s; j++) m += in[(i * W * s + j) * C + 1];
    CHECK_CLOSE(out[1], m / 9, 1e-14, 1e-14);
    mlb_downsample_box_backward_f64(din, w, H, W, C, s);
    for (int i = 0; i < n_in; i++) {
        double x = in[i], L[2];
        for (int k = 0; k < 2; k++) {
            in[i] = x + (k ? -FD_H : FD_H);
            mlb_downsample_box_f64(out, in, H, W, C, s);
            L[k] = dot(out, w, H * W * C);
        }
        in[i] = x;
        check_grad("din", i, din[i], (L[0] - L[1]) / (2 * FD_H), 1e-8);
    }
    free(in); free(w); free(din);
}

TEST(composite_fd) {
    int n = 37, C = 3;
    for (int per_pixel = 0; per_pixel < 2; per_pixel++) {
        int nb = per_pixel ? n * C : C;
        double *color = dnormal(n * C, 130, 1), *bg = dnormal(nb, 131, 1), *w = dnormal(n * C, 132, 1);
        double* mask = malloc(sizeof(double) * n);
        for (int p = 0; p < n; p++) mask[p] = mlb_rng_uniform_f64(SEED, 133, p);
        double *out = malloc(sizeof(double) * n * C), *dcolor = calloc(n * C, sizeof(double));
        double *dmask = calloc(n, sizeof(double)), *dbg = calloc(nb, sizeof(double));
        mlb_composite_backward_f64(dcolor, dmask, dbg, w, color, mask, bg, per_pixel, n, C);
        double* bufs[3] = {color, mask, bg};
        double* grads[3] = {dcolor, dmask, dbg};
        int sizes[3] = {n * C, n, nb};
        const char* names[3] = {"dcolor", "dmask", "dbg"};
        for (int b = 0; b < 3; b++)
            for (int i = 0; i < sizes[b]; i++) {
                double x = bufs[b][i], L[2];
                for (int k = 0; k < 2; k++) {
                    bufs[b][i] = x + (k ? -FD_H : FD_H);
                    mlb_composite_f64(out, color, mask, bg, per_pixel, n, C);
                    L[k] = dot(out, w, n * C);
                }
                bufs[b][i] = x;
                check_grad(names[b], i, grads[b][i], (L[0] - L[1]) / (2 * FD_H), 1e-8);
            }
        // mask 1 shows the colour, 0 the background
        double m2[2] = {1, 0}, c2[6] = {1, 2, 3, 4, 5, 6}, o2[6], bgc[3] = {7, 8, 9};
        mlb_composite_f64(o2, c2, m2, bgc, 0, 2, 3);
        CHECK(o2[0] == 1 && o2[2] == 3 && o2[3] == 7 && o2[5] == 9);
        free(color); free(bg); free(w); free(mask); free(out); free(dcolor); free(dmask); free(dbg);
    }
    int32_t tri[4] = {-1, 0, 5, -1};
    double mk[4];
    mlb_coverage_mask_f64(mk, tri, 4);
    CHECK(mk[0] == 0 && mk[1] == 1 && mk[2] == 1 && mk[3] == 0);
}

// Render at 2x and downsample: a coverage-weighted edge, and the chain's gradient through the
// downsampling's backward, antialias and interpolation (in double, against finite differences).
TEST(supersampled_pipeline_fd) {
    int32_t faces[] = {0, 1, 2};
    double clip0[] = {-0.7, -0.6, 0, 1.5, 0.8, -0.3, 0, 1.2, -0.1, 0.75, 0, 2.0};
    double clip[12];
    memcpy(clip, clip0, sizeof clip);
    int32_t opp[3];
    REQUIRE(mlb_edge_topology(opp, faces, 1, 3) == MLB_OK);
    int H = 12, W = 14, s = 2, Hs = H * s, Ws = W * s, C = 1;
    // mask antialiased at 2x, downsampled: L = <w, down(aa(mask))>
    double* w = dnormal(H * W, 140, 1);
    int32_t* tri = malloc(sizeof(int32_t) * Hs * Ws);
    double *depth = malloc(sizeof(double) * Hs * Ws), *mask = malloc(sizeof(double) * Hs * Ws);
    double *aa = malloc(sizeof(double) * Hs * Ws), out[168];
    double* dclip = calloc(12, sizeof(double));
    double* daa = calloc(Hs * Ws, sizeof(double));
    double L[2] = {0, 0};
    for (int phase = -1; phase < 12 * 2; phase++) {
        int i = phase / 2, k = phase % 2;
        if (phase >= 0) clip[i] = clip0[i] + (k ? -FD_H : FD_H);
        REQUIRE(mlb_rasterize_f64(NULL, tri, NULL, depth, NULL, clip, 3, faces, 1, Hs, Ws) == MLB_OK);
        mlb_coverage_mask_f64(mask, tri, Hs * Ws);
        REQUIRE(mlb_antialias_f64(NULL, aa, NULL, mask, C, tri, depth, clip, 3, faces, opp, 1, Hs, Ws) == MLB_OK);
        mlb_downsample_box_f64(out, aa, H, W, C, s);
        if (phase < 0) {
            mlb_downsample_box_backward_f64(daa, w, H, W, C, s);
            REQUIRE(mlb_antialias_backward_f64(NULL, NULL, dclip, daa, NULL, mask, C, tri, depth, clip, 3, faces, opp, 1, Hs, Ws) == MLB_OK);
            continue;
        }
        L[k] = dot(out, w, H * W);
        if (k == 1) {
            check_grad("dclip", i, dclip[i], (L[0] - L[1]) / (2 * FD_H), 1e-9);
            clip[i] = clip0[i];
        }
    }
    int big = 0;
    for (int i = 0; i < 12; i++) big += fabs(dclip[i]) > 1e-2;
    CHECK(big >= 6);   // x, y (and w) of all three vertices
    free(w); free(tri); free(depth); free(mask); free(aa); free(dclip); free(daa);
}

// ---- float against double ---------------------------------------------------------------------------------
TEST(float_matches_double) {
    double* pos;
    int32_t* faces;
    int F;
    int V = rt_sphere(&pos, &faces, &F, 40, 60, 0.1);
    mlb_camera cam;
    REQUIRE(mlb_camera_orbit(&cam, -60, 10, 3, NULL, 30, 1, 0.1, 50) == MLB_OK);
    int H = 128, W = 128;
    size_t n = (size_t)H * W;
    double* clip = rt_project(pos, V, &cam.view_proj);
    float* clipf = rt_to_float(clip, 4 * (size_t)V);
    int32_t *tri = malloc(sizeof(int32_t) * n), *trif = malloc(sizeof(int32_t) * n);
    double *bary = malloc(sizeof(double) * 2 * n), *depth = malloc(sizeof(double) * n);
    float *baryf = malloc(sizeof(float) * 2 * n), *depthf = malloc(sizeof(float) * n);
    REQUIRE(mlb_rasterize_f64(NULL, tri, bary, depth, NULL, clip, V, faces, F, H, W) == MLB_OK);
    REQUIRE(mlb_rasterize(NULL, trif, baryf, depthf, NULL, clipf, V, faces, F, H, W) == MLB_OK);
    int differ = 0, covered = 0;
    double eb = 0, ed = 0;
    for (size_t p = 0; p < n; p++) {
        covered += tri[p] >= 0;
        if (tri[p] != trif[p]) { differ++; continue; }
        if (tri[p] < 0) continue;
        eb = fmax(eb, fmax(fabs(bary[2 * p] - baryf[2 * p]), fabs(bary[2 * p + 1] - baryf[2 * p + 1])));
        ed = fmax(ed, fabs(depth[p] - depthf[p]));
    }
    CHECK(covered > (int)n / 5);
    CHECK_MSG(differ <= covered / 200, "%d of %d pixels drew different faces", differ, covered);
    CHECK_MSG(eb < 1e-4 && ed < 1e-6, "barycentric difference %g, depth difference %g", eb, ed);
    free(pos); free(faces); free(clip); free(clipf); free(tri); free(trif); free(bary); free(depth); free(baryf); free(depthf);
}

// A fine closed mesh whose outline faces are thinner than a pixel: the silhouette edges found by
// walking from the pixel's face over its neighbours carry the gradient.
TEST(pipeline_fine_mesh_fd) {
    double* pos;
    int32_t* faces;
    int F;
    int V = rt_sphere(&pos, &faces, &F, 12, 18, 0.05);
    mlb_camera cam;
    REQUIRE(mlb_camera_orbit(&cam, 15, 25, 3, NULL, 42, 1, 0.1, 20) == MLB_OK);
    int32_t* adj = malloc(sizeof(int32_t) * 3 * F);
    REQUIRE(mlb_edge_topology(adj, faces, F, V) == MLB_OK);
    scene s = {.H = 22, .W = 22, .V = V, .F = F, .C = 2, .faces = faces, .opp = adj, .mode = 2};
    scene_alloc(&s);
    double* clip = rt_project(pos, V, &cam.view_proj);
    s.attr = dnormal(V * s.C, 150, 1);
    s.w_out = dnormal(s.H * s.W * s.C, 151, 1);
    int ok, n_big;
    scene_L(&s, clip, &ok);
    REQUIRE(ok);
    double* dclip = calloc(4 * V, sizeof(double));
    REQUIRE(scene_grad(&s, clip, dclip));
    // the silhouette part alone, for the count of outline vertices it moves
    double* dsil = calloc(4 * V, sizeof(double));
    REQUIRE(mlb_antialias_backward_f64(NULL, NULL, dsil, s.w_out, s.wgt, s.img, s.C, s.tri, s.depth, clip, V, faces, adj, F, s.H,
                                       s.W) == MLB_OK);
    int moved = 0;
    for (int v = 0; v < V; v++) moved += dsil[4 * v] != 0 || dsil[4 * v + 1] != 0;
    CHECK_MSG(moved >= 16, "the silhouette moves only %d vertices", moved);
    int skipped = scene_fd(&s, clip, dclip, &n_big);
    CHECK_MSG(skipped <= 4 * V / 50, "%d of %d coordinates changed coverage", skipped, 4 * V);
    CHECK_MSG(n_big >= 100, "only %d clearly nonzero gradients", n_big);
    free(pos); free(faces); free(adj); free(clip); free(dclip); free(dsil); free(s.attr); free(s.w_out);
    scene_free(&s);
}

int main(void) {
    RUN(transform_fd);
    RUN(interpolate_attr_and_bary_fd);
    RUN(interpolate_position_fd);
    RUN(antialias_color_fd);
    RUN(antialias_position_fd);
    RUN(pipeline_fd);
    RUN(pipeline_fine_mesh_fd);
    RUN(downsample_fd);
    RUN(composite_fd);
    RUN(supersampled_pipeline_fd);
    RUN(float_matches_double);
    printf("%d gradient entries checked\n", n_checked);
    return test_summary();
}
