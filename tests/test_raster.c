// Tests of the rasterizer's geometry (src/render/camera.c, rasterize.c): camera matrices, exact
// watertightness (coverage counted on grids, fans and closed meshes), the fill rule, coverage
// area, perspective-correct barycentrics and depth against ray-plane intersections, near-plane
// clipping, thread-count independence, topology and errors. The finite-difference checks of the
// backwards are in test_raster_grad.c. docs/raster.md describes the method.
#include "test.h"
#include "raster_test_util.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"
#include <omp.h>
#include <string.h>

#define SEED 20261121u

// ---- coverage truth --------------------------------------------------------------------------------
typedef struct { double x, y; } pt;

static double seg_dist(pt a, pt b, double x, double y) {
    double dx = b.x - a.x, dy = b.y - a.y, l2 = dx * dx + dy * dy;
    double t = l2 > 0 ? ((x - a.x) * dx + (y - a.y) * dy) / l2 : 0;
    if (t < 0) t = 0;
    if (t > 1) t = 1;
    double ex = a.x + t * dx - x, ey = a.y + t * dy - y;
    return sqrt(ex * ex + ey * ey);
}
static int poly_inside(const pt* p, int n, double x, double y) {   // even-odd
    int in = 0;
    for (int i = 0, j = n - 1; i < n; j = i++)
        if ((p[i].y > y) != (p[j].y > y) && x < (p[j].x - p[i].x) * (y - p[i].y) / (p[j].y - p[i].y) + p[i].x) in = !in;
    return in;
}
// Every pixel centre farther than tol from the polygon's boundary must be covered exactly once
// inside and never outside; centres within tol at most once. Returns the number of pixels inside.
static int check_counts(const int32_t* count, int H, int W, const pt* poly, int n, double tol) {
    int inside = 0, bad = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            double cx = x + 0.5, cy = y + 0.5, d = INFINITY;
            for (int i = 0; i < n; i++) d = fmin(d, seg_dist(poly[i], poly[(i + 1) % n], cx, cy));
            int c = count[y * W + x], want;
            if (d <= tol) {
                if (c <= 1) continue;
                want = -1;
            } else {
                want = poly_inside(poly, n, cx, cy);
                inside += want;
                if (c == want) continue;
            }
            if (bad++ < 8)
                printf("  %s: pixel (%d, %d) covered %d times, expected %s\n", test_case_name, x, y, c,
                       want < 0 ? "at most 1 (on the boundary)" : want ? "1" : "0");
            test_case_failed = 1;
        }
    return inside;
}

static void count_both_precisions(int32_t* count, const double* clip, int V, const int32_t* f, int F, int H, int W,
                                  int* ok) {
    int32_t* c32 = malloc(sizeof(int32_t) * H * W);
    float* cf = rt_to_float(clip, 4 * (size_t)V);
    *ok = mlb_raster_coverage_count_f64(NULL, count, clip, V, f, F, H, W) == MLB_OK &&
          mlb_raster_coverage_count(NULL, c32, cf, V, f, F, H, W) == MLB_OK;
    // the vertices used here are exact in float too: both precisions must count alike
    if (*ok && memcmp(c32, count, sizeof(int32_t) * H * W) != 0) {
        printf("  %s: float and double coverage differ\n", test_case_name);
        test_case_failed = 1;
    }
    free(c32);
    free(cf);
}

// ---- cameras -----------------------------------------------------------------------------------------
static void apply(const mlb_mat4* m, const double p[4], double r[4]) {
    for (int i = 0; i < 4; i++) r[i] = m->m[4 * i] * p[0] + m->m[4 * i + 1] * p[1] + m->m[4 * i + 2] * p[2] + m->m[4 * i + 3] * p[3];
}

TEST(camera_matrices) {
    mlb_mat4 P;
    REQUIRE(mlb_perspective(&P, 40, 1.5, 0.1, 100) == MLB_OK);
    double t = tan(20 * M_PI / 180), r[4];
    double pn[4] = {0, 0, -0.1, 1}, pf[4] = {0, 0, -100, 1}, pc[4] = {t * 7 * 1.5, -t * 7, -7, 1};
    apply(&P, pn, r);
    CHECK_CLOSE(r[3], 0.1, 1e-12, 0);
    CHECK_CLOSE(r[2] / r[3], -1, 1e-12, 1e-12);
    apply(&P, pf, r);
    CHECK_CLOSE(r[2] / r[3], 1, 1e-12, 1e-12);
    apply(&P, pc, r);   // the image's right-bottom corner at distance 7
    CHECK_CLOSE(r[3], 7, 1e-12, 0);
    CHECK_CLOSE(r[0] / r[3], 1, 1e-12, 1e-12);
    CHECK_CLOSE(r[1] / r[3], -1, 1e-12, 1e-12);

    mlb_mat4 V;
    double eye[3] = {1, 2, 3}, target[3] = {0, 0.5, 0}, up[3] = {0, 1, 0};
    REQUIRE(mlb_look_at(&V, eye, target, up) == MLB_OK);
    double pe[4] = {1, 2, 3, 1}, pt4[4] = {0, 0.5, 0, 1};
    apply(&V, pe, r);
    CHECK(fabs(r[0]) + fabs(r[1]) + fabs(r[2]) < 1e-12);
    apply(&V, pt4, r);
    CHECK(fabs(r[0]) + fabs(r[1]) < 1e-12);
    CHECK_CLOSE(r[2], -sqrt(1 + 2.25 + 9), 1e-12, 0);
    for (int i = 0; i < 3; i++)   // orthonormal rotation
        for (int j = 0; j < 3; j++) {
            double d = 0;
            for (int k = 0; k < 3; k++) d += V.m[4 * i + k] * V.m[4 * j + k];
            CHECK_CLOSE(d, i == j, 0, 1e-12);
        }

    mlb_camera cam;
    REQUIRE(mlb_camera_orbit(&cam, 0, 0, 3, NULL, 45, 1, 0.1, 100) == MLB_OK);
    CHECK(fabs(cam.eye[0]) < 1e-12 && fabs(cam.eye[1]) < 1e-12 && fabs(cam.eye[2] - 3) < 1e-12);
    double o[4] = {0, 0, 0, 1}, upp[4] = {0, 0.1, 0, 1}, rightp[4] = {0.1, 0, 0, 1};
    apply(&cam.view_proj, o, r);
    CHECK(fabs(r[0]) < 1e-12 && fabs(r[1]) < 1e-12);
    CHECK_CLOSE(r[3], 3, 1e-12, 0);
    apply(&cam.view_proj, upp, r);
    CHECK(r[1] > 0);   // world up is up on the image
    apply(&cam.view_proj, rightp, r);
    CHECK(r[0] > 0);   // seen from +z, +x is to the right
    REQUIRE(mlb_camera_orbit(&cam, 90, 0, 3, NULL, 45, 1, 0.1, 100) == MLB_OK);
    CHECK(fabs(cam.eye[0] - 3) < 1e-12 && fabs(cam.eye[2]) < 1e-12);
    double tg[3] = {0.2, -0.1, 0.3};
    REQUIRE(mlb_camera_orbit(&cam, -150, 35, 3, tg, 30, 1.25, 0.1, 100) == MLB_OK);
    double az = -150 * M_PI / 180, el = 35 * M_PI / 180;
    CHECK_CLOSE(cam.eye[0], tg[0] + 3 * cos(el) * sin(az), 0, 1e-12);
    CHECK_CLOSE(cam.eye[1], tg[1] + 3 * sin(el), 0, 1e-12);
    CHECK_CLOSE(cam.eye[2], tg[2] + 3 * cos(el) * cos(az), 0, 1e-12);
    double tg4[4] = {tg[0], tg[1], tg[2], 1};
    apply(&cam.view_proj, tg4, r);
    CHECK(fabs(r[0]) < 1e-12 && fabs(r[1]) < 1e-12);
    CHECK_CLOSE(r[3], 3, 1e-12, 0);
    for (int s = -1; s <= 1; s += 2) {   // straight down / up
        REQUIRE(mlb_camera_orbit(&cam, 20, 90 * s, 3, NULL, 45, 1, 0.1, 100) == MLB_OK);
        apply(&cam.view_proj, o, r);
        CHECK(fabs(r[0]) < 1e-12 && fabs(r[1]) < 1e-12);
    }
    CHECK(mlb_perspective(&P, 0, 1, 0.1, 10) == MLB_ERR_ARG);
    CHECK(mlb_perspective(&P, 45, 1, 1, 1) == MLB_ERR_ARG);
    CHECK(mlb_perspective(&P, 45, -1, 0.1, 10) == MLB_ERR_ARG);
    CHECK(mlb_camera_orbit(&cam, 0, 0, 0, NULL, 45, 1, 0.1, 10) == MLB_ERR_ARG);
    CHECK(mlb_camera_orbit(&cam, 0, 95, 3, NULL, 45, 1, 0.1, 10) == MLB_ERR_ARG);
    CHECK(mlb_look_at(&V, eye, eye, up) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "mlb_look_at") != NULL);
}

// ---- watertightness -----------------------------------------------------------------------------------
// A grid of nc × nc cells over [lo, hi]² (pixel coordinates), vertices on multiples of 1/256 px
// (so snapping leaves them exact and the expected coverage is exact); interior vertices jittered
// by up to `jit` px; each cell split along a random diagonal.
static int make_grid(double** clip, int32_t** faces, int* F, int nc, double lo, double hi, double jit, int H, int W,
                     uint64_t stream) {
    int nv = nc + 1, V = nv * nv;
    *clip = malloc(sizeof(double) * 4 * V);
    *faces = malloc(sizeof(int32_t) * 6 * nc * nc);
    for (int i = 0; i < nv; i++)
        for (int j = 0; j < nv; j++) {
            double x = lo + (hi - lo) * j / nc, y = lo + (hi - lo) * i / nc;
            if (i > 0 && i < nc && j > 0 && j < nc) {
                x += jit * (2 * mlb_rng_uniform_f64(SEED, stream, 2 * (i * nv + j)) - 1);
                y += jit * (2 * mlb_rng_uniform_f64(SEED, stream, 2 * (i * nv + j) + 1) - 1);
            }
            x = round(x * 256) / 256;
            y = round(y * 256) / 256;
            rt_pixel_to_clip(*clip + 4 * (i * nv + j), x, y, H, W, 0.1 * mlb_rng_uniform_f64(SEED, stream + 1, i * nv + j));
        }
    int k = 0;
    for (int i = 0; i < nc; i++)
        for (int j = 0; j < nc; j++) {
            int a = i * nv + j, b = a + 1, c = a + nv, d = c + 1;
            int32_t* f = *faces + 6 * k++;
            if (mlb_rng_uniform_f64(SEED, stream + 2, i * nc + j) < 0.5) {
                f[0] = a; f[1] = c; f[2] = d; f[3] = a; f[4] = d; f[5] = b;
            } else {
                f[0] = a; f[1] = c; f[2] = b; f[3] = b; f[4] = c; f[5] = d;
            }
        }
    *F = 2 * nc * nc;
    return V;
}

TEST(watertight_grid) {
    int H = 80, W = 72;
    int32_t* count = malloc(sizeof(int32_t) * H * W);
    struct { int nc; double jit; } cases[] = {{32, 0}, {16, 0}, {31, 0.4}, {60, 0.2}};   // jitter < cell / 4: no folds
    // {32, 0}: vertices and cell diagonals exactly on pixel centres (every tie of the fill rule)
    for (size_t c = 0; c < sizeof cases / sizeof *cases; c++) {
        double *clip, lo = 4.5, hi = 68.5;
        int32_t* faces;
        int F, ok;
        int V = make_grid(&clip, &faces, &F, cases[c].nc, lo, hi, cases[c].jit, H, W, 10 + 3 * c);
        count_both_precisions(count, clip, V, faces, F, H, W, &ok);
        REQUIRE(ok);
        pt poly[4] = {{lo, lo}, {hi, lo}, {hi, hi}, {lo, hi}};
        int inside = check_counts(count, H, W, poly, 4, 1e-9);
        CHECK(inside == 63 * 63);
        // the rasterizer itself leaves no hole inside
        int32_t* tri = malloc(sizeof(int32_t) * H * W);
        REQUIRE(mlb_rasterize_f64(NULL, tri, NULL, NULL, NULL, clip, V, faces, F, H, W) == MLB_OK);
        int holes = 0;
        for (int y = 5; y < 68; y++)
            for (int x = 5; x < 68; x++) holes += tri[y * W + x] < 0;
        CHECK(holes == 0);
        free(tri);
        free(clip);
        free(faces);
    }
    free(count);
}

// Fans: many triangles around one vertex. The outer ring is the polygon whose inside must be
// covered exactly once.
TEST(watertight_fan) {
    int H = 128, W = 128;
    int32_t* count = malloc(sizeof(int32_t) * H * W);
    pt* ring = malloc(sizeof(pt) * 400);
    for (int variant = 0; variant < 3; variant++) {
        double cx, cy;
        int n;
        if (variant < 2) {   // a circle of 100 or 173 points, centre on / off a pixel centre
            cx = variant == 0 ? 64.5 : 61.0 + 77.0 / 256;
            cy = variant == 0 ? 60.5 : 66.0 + 13.0 / 256;
            n = variant == 0 ? 100 : 173;
            for (int k = 0; k < n; k++) {
                double a = 2 * M_PI * k / n + 0.01;
                ring[k].x = round((cx + 50 * cos(a)) * 256) / 256;
                ring[k].y = round((cy + 50 * sin(a)) * 256) / 256;
            }
        } else {   // a square of pixel centres: every spoke passes through pixel centres
            cx = 64.5; cy = 64.5; n = 0;
            for (int s = 0; s < 4; s++)   // the sides clockwise on screen, 60 points each
                for (int k = 0; k < 60; k++) {
                    int u = -30 + k;
                    ring[n].x = cx + (s == 0 ? u : s == 1 ? 30 : s == 2 ? -u : -30);
                    ring[n].y = cy + (s == 0 ? -30 : s == 1 ? u : s == 2 ? 30 : -u);
                    n++;
                }
        }
        double* clip = malloc(sizeof(double) * 4 * (n + 1));
        int32_t* faces = malloc(sizeof(int32_t) * 3 * n);
        rt_pixel_to_clip(clip, cx, cy, H, W, 0);
        for (int k = 0; k < n; k++) {
            rt_pixel_to_clip(clip + 4 * (k + 1), ring[k].x, ring[k].y, H, W, 0.9 * k / n);
            faces[3 * k] = 0; faces[3 * k + 1] = k + 1; faces[3 * k + 2] = (k + 1) % n + 1;
        }
        int ok;
        count_both_precisions(count, clip, n + 1, faces, n, H, W, &ok);
        REQUIRE(ok);
        int inside = check_counts(count, H, W, ring, n, 1e-9);
        CHECK(inside > 3000);
        CHECK(count[(int)cy * W + (int)cx] == 1);   // the pixel at (or next to) the shared vertex
        free(clip);
        free(faces);
    }
    free(ring);
    free(count);
}

// A jittered grid on a tilted plane seen in perspective (w varies, vertices anywhere): pixels
// away from the projected outer boundary are covered exactly once.
TEST(watertight_perspective) {
    int H = 96, W = 112, nc = 40, nv = nc + 1;
    mlb_camera cam;
    REQUIRE(mlb_camera_orbit(&cam, 25, 30, 2.6, NULL, 40, (double)W / H, 0.1, 50) == MLB_OK);
    double* pos = malloc(sizeof(double) * 3 * nv * nv);
    for (int i = 0; i < nv; i++)
        for (int j = 0; j < nv; j++) {
            double u = -0.8 + 1.6 * j / nc, v = -0.8 + 1.6 * i / nc;
            if (i > 0 && i < nc && j > 0 && j < nc) {
                u += 0.2 * 1.6 / nc * (2 * mlb_rng_uniform_f64(SEED, 40, 2 * (i * nv + j)) - 1);
                v += 0.2 * 1.6 / nc * (2 * mlb_rng_uniform_f64(SEED, 40, 2 * (i * nv + j) + 1) - 1);
            }
            double* p = pos + 3 * (i * nv + j);   // the plane y = 0.3 x + 0.2 z
            p[0] = u; p[2] = v; p[1] = 0.3 * u + 0.2 * v;
        }
    int32_t* faces = malloc(sizeof(int32_t) * 6 * nc * nc);
    for (int i = 0, k = 0; i < nc; i++)
        for (int j = 0; j < nc; j++, k++) {
            int a = i * nv + j, b = a + 1, c = a + nv, d = c + 1;
            int32_t f[6] = {a, c, d, a, d, b};
            memcpy(faces + 6 * k, f, sizeof f);
        }
    double* clip = rt_project(pos, nv * nv, &cam.view_proj);
    int32_t* count = malloc(sizeof(int32_t) * H * W);
    REQUIRE(mlb_raster_coverage_count_f64(NULL, count, clip, nv * nv, faces, 2 * nc * nc, H, W) == MLB_OK);
    pt quad[4];
    int corners[4] = {0, nc, nv * nv - 1, nc * nv};
    for (int k = 0; k < 4; k++) {
        const double* c = clip + 4 * corners[k];
        quad[k].x = (c[0] / c[3] * 0.5 + 0.5) * W;
        quad[k].y = (0.5 - c[1] / c[3] * 0.5) * H;
    }
    int inside = check_counts(count, H, W, quad, 4, 0.01);
    CHECK(inside > 1500);
    free(pos); free(faces); free(clip); free(count);
}

// A closed mesh drawn from both sides: every ray from the camera crosses its surface an even
// number of times, so every pixel must be covered an even number of times (a hole or a double
// cover on any edge, in any of the layers, makes some count odd).
TEST(watertight_closed_mesh) {
    double* pos;
    int32_t* faces;
    int F;
    int V = rt_sphere(&pos, &faces, &F, 80, 125, 0.08);   // 19750 faces
    int H = 160, W = 192;
    int32_t* count = malloc(sizeof(int32_t) * H * W);
    for (int view = 0; view < 3; view++) {
        mlb_camera cam;
        REQUIRE(mlb_camera_orbit(&cam, -170 + 113 * view, -10 + 25 * view, 3, NULL, 30 + 7 * view, (double)W / H, 0.1, 50) == MLB_OK);
        double* clip = rt_project(pos, V, &cam.view_proj);
        float* cf = rt_to_float(clip, 4 * (size_t)V);
        for (int prec = 0; prec < 2; prec++) {
            mlb_status st = prec ? mlb_raster_coverage_count(NULL, count, cf, V, faces, F, H, W)
                                 : mlb_raster_coverage_count_f64(NULL, count, clip, V, faces, F, H, W);
            REQUIRE(st == MLB_OK);
            int odd = 0, covered = 0;
            for (int p = 0; p < H * W; p++) {
                odd += count[p] & 1;
                covered += count[p] > 0;
            }
            CHECK_MSG(odd == 0, "view %d, %s: %d pixels with an odd count", view, prec ? "float" : "double", odd);
            CHECK(covered > H * W / 8);
        }
        free(clip);
        free(cf);
    }
    free(pos);
    free(faces);
    free(count);
}

// An irregular floor grid under the camera that reaches behind it and far to the sides: most of
// its faces are clipped (near plane, guard band; rows at w = 0.002 put x/w near 10^4), and two
// faces that share an edge must still cover each pixel centre exactly once.
TEST(watertight_clipped_grid) {
    int H = 72, W = 64;
    mlb_mat4 proj;   // the camera at the origin looking down -z: clip = proj · [p, 1]
    REQUIRE(mlb_perspective(&proj, 70, (double)W / H, 0.001, 100) == MLB_OK);
    double zs[] = {1, 0.3, 0.0, -0.002, -0.01, -0.1, -0.5, -1, -2, -4, -8, -16};
    double xs[] = {-20, -10, -5, -2, -1, -0.5, 0.1, 0.5, 1, 2, 5, 10, 20};
    int nz = 12, nx = 13, V = nz * nx;
    double* pos = malloc(sizeof(double) * 3 * V);
    for (int i = 0; i < nz; i++)
        for (int j = 0; j < nx; j++) {
            double* p = pos + 3 * (i * nx + j);
            p[0] = xs[j]; p[1] = -0.5; p[2] = zs[i];
        }
    int32_t* faces = malloc(sizeof(int32_t) * 6 * (nz - 1) * (nx - 1));
    int F = 0;
    for (int i = 0; i + 1 < nz; i++)
        for (int j = 0; j + 1 < nx; j++) {
            int a = i * nx + j, b = a + 1, c = a + nx, d = c + 1;
            int32_t f[6] = {a, b, d, a, d, c};
            if ((i + j) % 2) { f[2] = c; f[3] = b; f[4] = d; f[5] = c; }   // the other diagonal
            memcpy(faces + 3 * F, f, sizeof f);
            F += 2;
        }
    double* clip = rt_project(pos, V, &proj);
    int32_t* count = malloc(sizeof(int32_t) * H * W);
    REQUIRE(mlb_raster_coverage_count_f64(NULL, count, clip, V, faces, F, H, W) == MLB_OK);
    double t = tan(35 * M_PI / 180), aspect = (double)W / H;
    int inside = 0, bad = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            double dx = ((2.0 * x + 1) / W - 1) * t * aspect, dy = (1 - (2.0 * y + 1) / H) * t;
            int want = 0;
            if (dy < 0) {
                double d = -0.5 / dy, hx = d * dx, hz = -d;   // hit of the ray (dx, dy, -1) with y = -0.5
                double m = fmin(fmin(hx + 20, 20 - hx), fmin(hz + 16, 1 - hz));
                if (fabs(m) < 1e-3) continue;   // on the grid's outline
                want = m > 0;
            }
            inside += want;
            if (count[y * W + x] != want && bad++ < 6) {
                printf("  pixel (%d, %d): covered %d times, expected %d\n", x, y, count[y * W + x], want);
                test_case_failed = 1;
            }
        }
    CHECK(inside > H * W / 4);
    int n_near = 0, n_guard = 0;   // many faces really needed clipping, a few at the guard band
    double G = 262144.0 / (W > H ? W : H) - 1;   // rasterize.c
    for (int f = 0; f < F; f++) {
        int near = 0, guard = 0;
        for (int k = 0; k < 3; k++) {
            const double* c = clip + 4 * faces[3 * f + k];
            near |= c[2] < -c[3];
            guard |= c[2] >= -c[3] && fabs(c[0]) > G * c[3];
        }
        n_near += near;
        n_guard += guard;
    }
    CHECK(n_near > F / 5);
    CHECK(n_guard >= 4);
    free(pos); free(faces); free(clip); free(count);
}

TEST(fill_rule) {
    // A square from (1.5, 1.5) to (5.5, 5.5) (pixel centres on all four sides and on the
    // diagonal), as two triangles in either winding: the top and left sides belong to it,
    // the bottom and right ones do not, so exactly pixels 1..4 × 1..4 are drawn, each once.
    int H = 8, W = 8;
    double clip[16];
    rt_pixel_to_clip(clip, 1.5, 1.5, H, W, 0);
    rt_pixel_to_clip(clip + 4, 5.5, 1.5, H, W, 0);
    rt_pixel_to_clip(clip + 8, 5.5, 5.5, H, W, 0);
    rt_pixel_to_clip(clip + 12, 1.5, 5.5, H, W, 0);
    int32_t fa[2][6] = {{0, 1, 2, 0, 2, 3}, {0, 2, 1, 0, 3, 2}};
    int32_t count[64], tri[64];
    for (int w = 0; w < 2; w++) {
        REQUIRE(mlb_raster_coverage_count_f64(NULL, count, clip, 4, fa[w], 2, H, W) == MLB_OK);
        REQUIRE(mlb_rasterize_f64(NULL, tri, NULL, NULL, NULL, clip, 4, fa[w], 2, H, W) == MLB_OK);
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                int want = x >= 1 && x <= 4 && y >= 1 && y <= 4;
                CHECK_MSG(count[y * W + x] == want, "winding %d pixel (%d, %d): %d", w, x, y, count[y * W + x]);
                CHECK((tri[y * W + x] >= 0) == want);
            }
    }
}

// ---- coverage area, interpolation and depth -----------------------------------------------------------
static double shoelace(const pt* p, int n) {
    double a = 0;
    for (int i = 0; i < n; i++) a += p[i].x * p[(i + 1) % n].y - p[(i + 1) % n].x * p[i].y;
    return fabs(a) / 2;
}

TEST(quad_area) {
    int H = 512, W = 512;
    int32_t* tri = malloc(sizeof(int32_t) * H * W);
    int32_t faces[6] = {0, 1, 2, 0, 2, 3};
    for (int c = 0; c < 2; c++) {
        double clip[16];
        pt q[4];
        if (c == 0) {   // a rotated rectangle in the image plane
            double ang = 0.37, cx = 250.3, cy = 261.7, hw = 170.2, hh = 95.9;
            double dx[4] = {-hw, hw, hw, -hw}, dy[4] = {-hh, -hh, hh, hh};
            for (int k = 0; k < 4; k++) {
                q[k].x = cx + cos(ang) * dx[k] - sin(ang) * dy[k];
                q[k].y = cy + sin(ang) * dx[k] + cos(ang) * dy[k];
                rt_pixel_to_clip(clip + 4 * k, q[k].x, q[k].y, H, W, 0.2);
            }
        } else {   // a square in 3D, in perspective: its image is the quadrilateral of its projected corners
            mlb_camera cam;
            REQUIRE(mlb_camera_orbit(&cam, 35, 25, 3, NULL, 38, 1, 0.1, 100) == MLB_OK);
            // sides a ⟂ b on a plane with normal nn, about 40 degrees from the view direction
            double nn[3] = {0.92, 0.12, 0.74}, a[3] = {-nn[2], 0, nn[0]}, b[3], sq[12];
            b[0] = nn[1] * a[2] - nn[2] * a[1]; b[1] = nn[2] * a[0] - nn[0] * a[2]; b[2] = nn[0] * a[1] - nn[1] * a[0];
            double la = sqrt(a[0] * a[0] + a[2] * a[2]), lb = sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
            for (int i = 0; i < 3; i++) { a[i] *= 0.62 / la; b[i] *= 0.45 / lb; }
            double sa[4] = {-1, 1, 1, -1}, sb[4] = {-1, -1, 1, 1};
            for (int k = 0; k < 4; k++)
                for (int i = 0; i < 3; i++) sq[3 * k + i] = 0.1 + sa[k] * a[i] + sb[k] * b[i];
            mlb_transform_points_f64(clip, sq, 4, &cam.view_proj);
            for (int k = 0; k < 4; k++) {
                q[k].x = (clip[4 * k] / clip[4 * k + 3] * 0.5 + 0.5) * W;
                q[k].y = (0.5 - clip[4 * k + 1] / clip[4 * k + 3] * 0.5) * H;
            }
        }
        for (int k = 0; k < 4; k++) REQUIRE(q[k].x > 0 && q[k].x < W && q[k].y > 0 && q[k].y < H);
        REQUIRE(mlb_rasterize_f64(NULL, tri, NULL, NULL, NULL, clip, 4, faces, 2, H, W) == MLB_OK);
        int n = 0;
        for (int p = 0; p < H * W; p++) n += tri[p] >= 0;
        double area = shoelace(q, 4), perim = 0;
        for (int k = 0; k < 4; k++) perim += hypot(q[(k + 1) % 4].x - q[k].x, q[(k + 1) % 4].y - q[k].y);
        // lattice points in a convex region: area ± O(perimeter); in practice far below the bound
        CHECK_MSG(fabs(n - area) < 0.005 * perim + 1, "case %d: %d pixels, area %.2f, perimeter %.1f", c, n, area, perim);
        CHECK_MSG(area > 0.15 * H * W, "case %d: area %g", c, area);
    }
    free(tri);
}

// World-space ray through the centre of pixel (x, y).
static void pixel_ray(const mlb_camera* cam, int x, int y, int H, int W, double d[3]) {
    double fx = (2.0 * x + 1) / W - 1, fy = 1 - (2.0 * y + 1) / H, t = tan(cam->fovy_deg * M_PI / 360);
    double dv[3] = {fx * t * cam->aspect, fy * t, -1};
    for (int c = 0; c < 3; c++) d[c] = cam->view.m[c] * dv[0] + cam->view.m[4 + c] * dv[1] + cam->view.m[8 + c] * dv[2];
}

// A tilted plane in perspective: interpolated world positions and depth match the ray-plane
// intersection at every pixel (perspective-correct barycentrics), in double and in float.
TEST(perspective_plane) {
    int H = 96, W = 128;
    mlb_camera cam;
    REQUIRE(mlb_camera_orbit(&cam, 30, 20, 3, NULL, 40, (double)W / H, 0.1, 100) == MLB_OK);
    double n[3] = {0.3, 0.8, 0.52}, p0[3] = {0.1, -0.2, 0.05};
    // a big triangle on the plane n·(x - p0) = 0
    double u[3] = {0.8, -0.3, 0}, v[3];
    u[2] = -(n[0] * u[0] + n[1] * u[1]) / n[2];
    v[0] = n[1] * u[2] - n[2] * u[1]; v[1] = n[2] * u[0] - n[0] * u[2]; v[2] = n[0] * u[1] - n[1] * u[0];
    double pos[9];
    double cu[3] = {-1.5, 1.6, -0.2}, cv[3] = {-1.1, -0.9, 1.8};
    for (int k = 0; k < 3; k++)
        for (int c = 0; c < 3; c++) pos[3 * k + c] = p0[c] + cu[k] * u[c] + cv[k] * v[c];
    int32_t faces[3] = {0, 1, 2};
    double clip[12];
    mlb_transform_points_f64(clip, pos, 3, &cam.view_proj);
    float clipf[12], posf[9];
    for (int i = 0; i < 12; i++) clipf[i] = (float)clip[i];
    for (int i = 0; i < 9; i++) posf[i] = (float)pos[i];
    int32_t* tri = malloc(sizeof(int32_t) * H * W);
    double* bary = malloc(sizeof(double) * 2 * H * W);
    double* depth = malloc(sizeof(double) * H * W);
    double* out = malloc(sizeof(double) * 3 * H * W);
    float* baryf = malloc(sizeof(float) * 2 * H * W);
    float* depthf = malloc(sizeof(float) * H * W);
    float* outf = malloc(sizeof(float) * 3 * H * W);
    int32_t* trif = malloc(sizeof(int32_t) * H * W);
    REQUIRE(mlb_rasterize_f64(NULL, tri, bary, depth, NULL, clip, 3, faces, 1, H, W) == MLB_OK);
    REQUIRE(mlb_interpolate_f64(out, pos, 3, 3, tri, bary, faces, 1, H, W) == MLB_OK);
    REQUIRE(mlb_rasterize(NULL, trif, baryf, depthf, NULL, clipf, 3, faces, 1, H, W) == MLB_OK);
    REQUIRE(mlb_interpolate(outf, posf, 3, 3, trif, baryf, faces, 1, H, W) == MLB_OK);
    int covered = 0;
    double err = 0, errd = 0, errf = 0, errdf = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            int p = y * W + x;
            if (tri[p] < 0) continue;
            covered++;
            double d[3], X[3], c4[4], X4[4];
            pixel_ray(&cam, x, y, H, W, d);
            double t = (n[0] * (p0[0] - cam.eye[0]) + n[1] * (p0[1] - cam.eye[1]) + n[2] * (p0[2] - cam.eye[2])) /
                       (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]);
            for (int c = 0; c < 3; c++) X[c] = X4[c] = cam.eye[c] + t * d[c];
            X4[3] = 1;
            apply(&cam.view_proj, X4, c4);
            for (int c = 0; c < 3; c++) err = fmax(err, fabs(out[3 * p + c] - X[c]));
            errd = fmax(errd, fabs(depth[p] - c4[2] / c4[3]));
            if (trif[p] == tri[p]) {
                for (int c = 0; c < 3; c++) errf = fmax(errf, fabs(outf[3 * p + c] - X[c]));
                errdf = fmax(errdf, fabs(depthf[p] - c4[2] / c4[3]));
            }
        }
    CHECK_MSG(covered > 2000, "covered %d", covered);
    CHECK_MSG(err < 1e-10 && errd < 1e-12, "double: position error %g, depth error %g", err, errd);
    CHECK_MSG(errf < 2e-5 && errdf < 1e-6, "float: position error %g, depth error %g", errf, errdf);
    free(tri); free(bary); free(depth); free(out); free(baryf); free(depthf); free(outf); free(trif);
}

// Ray-triangle intersection (Möller-Trumbore): distance t along d, barycentrics (u, v).
static int ray_tri(const double o[3], const double d[3], const double* a, const double* b, const double* c, double* t,
                   double* u, double* v) {
    double e1[3], e2[3], s[3], p[3], q[3];
    for (int k = 0; k < 3; k++) { e1[k] = b[k] - a[k]; e2[k] = c[k] - a[k]; s[k] = o[k] - a[k]; }
    p[0] = d[1] * e2[2] - d[2] * e2[1]; p[1] = d[2] * e2[0] - d[0] * e2[2]; p[2] = d[0] * e2[1] - d[1] * e2[0];
    double det = e1[0] * p[0] + e1[1] * p[1] + e1[2] * p[2];
    if (fabs(det) < 1e-300) return 0;
    *u = (s[0] * p[0] + s[1] * p[1] + s[2] * p[2]) / det;
    q[0] = s[1] * e1[2] - s[2] * e1[1]; q[1] = s[2] * e1[0] - s[0] * e1[2]; q[2] = s[0] * e1[1] - s[1] * e1[0];
    *v = (d[0] * q[0] + d[1] * q[1] + d[2] * q[2]) / det;
    *t = (e2[0] * q[0] + e2[1] * q[1] + e2[2] * q[2]) / det;
    return 1;
}

// Triangles that reach behind the camera or cross the near plane: drawn exactly where the ray
// meets them in front of the near plane, with the right interpolated position.
TEST(near_plane_clipping) {
    int H = 72, W = 96;
    mlb_camera cam;   // at (0, 0.3, 3) looking at (0, 0.3, 0): view depth = 3 - z
    double tg[3] = {0, 0.3, 0};
    REQUIRE(mlb_camera_orbit(&cam, 0, 0, 3, tg, 60, (double)W / H, 0.5, 40) == MLB_OK);
    double pos[] = {
        -20, -0.5, -20, 20, -0.5, -20, 20, -0.5, 20, -20, -0.5, 20,   // a floor reaching behind the camera
        -0.9, 0.9, 2.75, 0.8, 1.3, 0.5, 0.2, 0.2, 1.0,                // a triangle crossing the near plane (depth 0.25)
        -0.6, 0.0, 3.0, 0.9, 0.6, 3.0, 0.4, -0.4, 1.5,                // one with two vertices at w = 0
        -0.5, 0.1, 1.3, 5000, 0.9, 1.6, -0.2, 0.6, 1.2,               // one reaching far beyond the guard band
    };
    int32_t faces[] = {0, 1, 2, 0, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12};
    int V = 13, F = 5;
    double* clip = rt_project(pos, V, &cam.view_proj);
    CHECK(clip[4 * 2 + 3] < 0 && clip[4 * 4 + 3] < cam.near_z && fabs(clip[4 * 7 + 3]) < 1e-12);
    CHECK(clip[4 * 11] / clip[4 * 11 + 3] > 262144.0 / W);   // outside the guard band (rasterize.c)
    int32_t* tri = malloc(sizeof(int32_t) * H * W);
    double* bary = malloc(sizeof(double) * 2 * H * W);
    double* out = malloc(sizeof(double) * 3 * H * W);
    REQUIRE(mlb_rasterize_f64(NULL, tri, bary, NULL, NULL, clip, V, faces, F, H, W) == MLB_OK);
    REQUIRE(mlb_interpolate_f64(out, pos, V, 3, tri, bary, faces, F, H, W) == MLB_OK);
    int checked = 0, cut = 0, bad = 0;
    double err = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            int p = y * W + x;
            double d[3];
            pixel_ray(&cam, x, y, H, W, d);   // |d| has view-space z = -1: t is the view depth
            double best = INFINITY, margin = INFINITY, X[3] = {0, 0, 0};
            int want = -1;
            for (int f = 0; f < F; f++) {
                double t, u, v;
                if (!ray_tri(cam.eye, d, pos + 3 * faces[3 * f], pos + 3 * faces[3 * f + 1], pos + 3 * faces[3 * f + 2], &t, &u, &v))
                    continue;
                double m = fmin(fmin(u, v), 1 - u - v);   // inside when m > 0
                if (!(t > 0)) continue;
                double mz = fmin(t - cam.near_z, cam.far_z - t) / t;
                double mt = f == 4 ? 1e-7 : 1e-3;   // face 4 is 5000 long: its barycentrics are tiny
                if (m > -mt && m < mt) margin = 0;
                if (fabs(mz) < 1e-3 && m > 0) margin = 0;
                if (m > 0 && t > 0 && t < cam.near_z && f >= 2) cut++;
                if (m > 0 && mz > 0 && t < best) {
                    best = t; want = f;
                    for (int c = 0; c < 3; c++) X[c] = cam.eye[c] + t * d[c];
                }
            }
            if (margin == 0) continue;   // within a hair of an edge, the near or the far plane
            checked++;
            // faces 0 and 1 (the floor) are one surface: either may own a pixel on their diagonal
            int got = tri[p], same = got == want || (got >= 0 && want >= 0 && got < 2 && want < 2);
            if (!same) {
                if (bad++ < 6) printf("  pixel (%d, %d): face %d, expected %d\n", x, y, got, want);
                test_case_failed = 1;
            } else if (got >= 0)
                for (int c = 0; c < 3; c++) err = fmax(err, fabs(out[3 * p + c] - X[c]));
        }
    CHECK(checked > H * W * 9 / 10);
    CHECK(cut > 20);   // the near plane really cut something away
    int n4 = 0;
    for (int p = 0; p < H * W; p++) n4 += tri[p] == 4;
    CHECK(n4 > 300);   // the face clipped at the guard band is really drawn
    CHECK_MSG(err < 1e-9, "interpolated position error %g", err);
    free(clip); free(tri); free(bary); free(out);
}

TEST(backfacing_and_ties) {
    int H = 16, W = 16;
    double clip[] = {-0.8, -0.8, 0.5, 1, 0.8, -0.8, 0.5, 1, 0, 0.8, 0.5, 1,   // counter-clockwise in NDC
                     -0.5, -0.9, 0.2, 1, 0, 0.6, 0.2, 1, 0.5, -0.9, 0.2, 1};   // clockwise, nearer
    int32_t faces[] = {0, 1, 2, 3, 4, 5, 0, 1, 2};   // face 2 = face 0 again
    int32_t tri[256];
    uint8_t back[256];
    double depth[256];
    REQUIRE(mlb_rasterize_f64(NULL, tri, NULL, depth, back, clip, 6, faces, 3, H, W) == MLB_OK);
    int n0 = 0, n1 = 0;
    for (int p = 0; p < H * W; p++) {
        CHECK(tri[p] != 2);   // equal depth: the lower id wins
        if (tri[p] == 0) { n0++; CHECK(back[p] == 0); CHECK_CLOSE(depth[p], 0.5, 0, 1e-12); }
        if (tri[p] == 1) { n1++; CHECK(back[p] == 1); CHECK_CLOSE(depth[p], 0.2, 0, 1e-12); }
        if (tri[p] < 0) CHECK(back[p] == 0 && depth[p] == 0);
    }
    CHECK(n0 > 10 && n1 > 10);
    // the faces in another order draw the same picture, ids renamed (old 0 is now 1 and old 1 is 0;
    // the duplicate, now 2, still loses to its twin)
    int32_t faces2[] = {3, 4, 5, 0, 1, 2, 0, 1, 2}, tri2[256];
    REQUIRE(mlb_rasterize_f64(NULL, tri2, NULL, NULL, NULL, clip, 6, faces2, 3, H, W) == MLB_OK);
    for (int p = 0; p < H * W; p++) CHECK(tri2[p] == (tri[p] < 0 ? -1 : 1 - tri[p]));
}

// ---- determinism -----------------------------------------------------------------------------------------
typedef struct {
    int32_t* tri;
    float *bary, *depth, *normal, *aa, *dclip, *dattr, *dcolor;
    uint8_t* back;
} frame;

static void render_frame(frame* fr, const float* clip, const float* attr, int V, const int32_t* faces, const int32_t* opp,
                         int F, int H, int W, mlb_raster_ctx* ctx, int* ok) {
    size_t n = (size_t)H * W;
    fr->tri = malloc(sizeof(int32_t) * n); fr->back = malloc(n);
    fr->bary = malloc(sizeof(float) * 2 * n); fr->depth = malloc(sizeof(float) * n);
    fr->normal = malloc(sizeof(float) * 3 * n); fr->aa = malloc(sizeof(float) * 3 * n);
    fr->dclip = calloc(4 * (size_t)V, sizeof(float)); fr->dattr = calloc(3 * (size_t)V, sizeof(float));
    fr->dcolor = calloc(3 * n, sizeof(float));
    float* dbary = calloc(2 * n, sizeof(float));
    float* dout = malloc(sizeof(float) * 3 * n);
    float* wgt = malloc(sizeof(float) * 2 * n);
    for (size_t i = 0; i < 3 * n; i++) dout[i] = mlb_rng_normal(SEED, 77, i);
    *ok = mlb_rasterize(ctx, fr->tri, fr->bary, fr->depth, fr->back, clip, V, faces, F, H, W) == MLB_OK &&
          mlb_interpolate(fr->normal, attr, V, 3, fr->tri, fr->bary, faces, F, H, W) == MLB_OK &&
          mlb_antialias(ctx, fr->aa, wgt, fr->normal, 3, fr->tri, fr->depth, clip, V, faces, opp, F, H, W) == MLB_OK &&
          mlb_antialias_backward(ctx, fr->dcolor, fr->dclip, dout, wgt, fr->normal, 3, fr->tri, fr->depth, clip, V, faces, opp, F, H, W) == MLB_OK &&
          mlb_interpolate_backward(ctx, fr->dattr, dbary, fr->dcolor, attr, V, 3, fr->tri, fr->bary, faces, F, H, W) == MLB_OK &&
          mlb_rasterize_backward(ctx, fr->dclip, dbary, fr->depth, fr->tri, clip, V, faces, F, H, W) == MLB_OK;
    free(dbary);
    free(dout);
    free(wgt);
}
static void free_frame(frame* f) {
    free(f->tri); free(f->back); free(f->bary); free(f->depth); free(f->normal); free(f->aa);
    free(f->dclip); free(f->dattr); free(f->dcolor);
}

TEST(thread_determinism) {
    double* pos;
    int32_t* faces;
    int F;
    int V = rt_sphere(&pos, &faces, &F, 100, 200, 0.1);   // 39600 faces
    int H = 200, W = 232;
    mlb_camera cam;
    REQUIRE(mlb_camera_orbit(&cam, 40, 20, 3, NULL, 35, (double)W / H, 0.1, 50) == MLB_OK);
    double* clipd = rt_project(pos, V, &cam.view_proj);
    float* clip = rt_to_float(clipd, 4 * (size_t)V);
    float* attr = rt_to_float(pos, 3 * (size_t)V);
    int32_t* opp = malloc(sizeof(int32_t) * 3 * F);
    REQUIRE(mlb_edge_topology(opp, faces, F, V) == MLB_OK);
    int saved = mlb_get_threads();
    frame fr[3];
    int ok[3];
    mlb_raster_ctx* ctx = mlb_raster_ctx_create();
    for (int k = 0; k < 3; k++) {
        mlb_set_threads(k == 0 ? 1 : k == 1 ? 2 : 3);
        render_frame(&fr[k], clip, attr, V, faces, opp, F, H, W, k == 2 ? NULL : ctx, &ok[k]);
    }
    mlb_set_threads(saved);
    mlb_raster_ctx_free(ctx);
    REQUIRE(ok[0] && ok[1] && ok[2]);
    size_t n = (size_t)H * W;
    int covered = 0;
    for (size_t p = 0; p < n; p++) covered += fr[0].tri[p] >= 0;
    CHECK(covered > (int)n / 5);
    for (int k = 1; k < 3; k++) {
        CHECK(memcmp(fr[0].tri, fr[k].tri, sizeof(int32_t) * n) == 0);
        CHECK(memcmp(fr[0].back, fr[k].back, n) == 0);
        CHECK(memcmp(fr[0].bary, fr[k].bary, sizeof(float) * 2 * n) == 0);
        CHECK(memcmp(fr[0].depth, fr[k].depth, sizeof(float) * n) == 0);
        CHECK(memcmp(fr[0].aa, fr[k].aa, sizeof(float) * 3 * n) == 0);
        CHECK(memcmp(fr[0].dcolor, fr[k].dcolor, sizeof(float) * 3 * n) == 0);
        CHECK(memcmp(fr[0].dattr, fr[k].dattr, sizeof(float) * 3 * V) == 0);
        CHECK(memcmp(fr[0].dclip, fr[k].dclip, sizeof(float) * 4 * V) == 0);
    }
    int blended = 0;
    for (size_t i = 0; i < 3 * n; i++) blended += fr[0].aa[i] != fr[0].normal[i];
    CHECK(blended > 100);
    for (int k = 0; k < 3; k++) free_frame(&fr[k]);
    free(pos); free(faces); free(clipd); free(clip); free(attr); free(opp);
}

// ---- antialias semantics (its gradients are checked in test_raster_grad.c) ------------------------------
// An axis-aligned rectangle's mask, antialiased: along a straight edge the blend equals the
// pixel's exact coverage, so away from the corners every row and column sums to the exact width.
TEST(antialias_coverage) {
    int H = 40, W = 64;
    double x0 = 10.3, x1 = 50.7, y0 = 5.6, y1 = 30.2;
    double clip[16];
    rt_pixel_to_clip(clip, x0, y0, H, W, 0);
    rt_pixel_to_clip(clip + 4, x1, y0, H, W, 0);
    rt_pixel_to_clip(clip + 8, x1, y1, H, W, 0);
    rt_pixel_to_clip(clip + 12, x0, y1, H, W, 0);
    int32_t faces[6] = {0, 1, 2, 0, 2, 3}, opp[6], tri[40 * 64];
    double depth[40 * 64], mask[40 * 64], aa[40 * 64];
    REQUIRE(mlb_edge_topology(opp, faces, 2, 4) == MLB_OK);
    REQUIRE(mlb_rasterize_f64(NULL, tri, NULL, depth, NULL, clip, 4, faces, 2, H, W) == MLB_OK);
    mlb_coverage_mask_f64(mask, tri, H * W);
    REQUIRE(mlb_antialias_f64(NULL, aa, NULL, mask, 1, tri, depth, clip, 4, faces, opp, 2, H, W) == MLB_OK);
    for (int y = 8; y < 28; y++) {
        double s = 0;
        for (int x = 0; x < W; x++) s += aa[y * W + x];
        CHECK_CLOSE(s, x1 - x0, 0, 1e-12);
    }
    for (int x = 13; x < 48; x++) {
        double s = 0;
        for (int y = 0; y < H; y++) s += aa[y * W + x];
        CHECK_CLOSE(s, y1 - y0, 0, 1e-12);
    }
    CHECK_CLOSE(aa[15 * W + 10], 0.7, 0, 1e-12);   // the edge at 10.3 covers 0.7 of pixel 10
    CHECK_CLOSE(aa[15 * W + 50], 0.7, 0, 1e-12);
    CHECK_CLOSE(aa[30 * W + 20], 0.2, 0, 1e-12);   // 30.2: pixel 30 is outside, its top 0.2 covered
}

// Only silhouettes blend: not the diagonal of a quad (two faces sharing an edge, both facing
// the camera), not the edges between front faces of a closed mesh; only pixels next to the
// background do on a convex one.
TEST(antialias_silhouettes) {
    int H = 48, W = 48;
    double clip[16];
    rt_pixel_to_clip(clip, 6.2, 5.7, H, W, 0.1);
    rt_pixel_to_clip(clip + 4, 41.3, 8.1, H, W, 0.1);
    rt_pixel_to_clip(clip + 8, 40.6, 42.9, H, W, 0.1);
    rt_pixel_to_clip(clip + 12, 7.4, 39.2, H, W, 0.1);
    int32_t faces[6] = {0, 1, 2, 0, 2, 3}, opp[6], tri[48 * 48];
    double depth[48 * 48], col[48 * 48], aa[48 * 48];
    REQUIRE(mlb_edge_topology(opp, faces, 2, 4) == MLB_OK);
    REQUIRE(mlb_rasterize_f64(NULL, tri, NULL, depth, NULL, clip, 4, faces, 2, H, W) == MLB_OK);
    for (int p = 0; p < H * W; p++) col[p] = tri[p] < 0 ? 0 : 1 + tri[p];   // a colour per face
    REQUIRE(mlb_antialias_f64(NULL, aa, NULL, col, 1, tri, depth, clip, 4, faces, opp, 2, H, W) == MLB_OK);
    int diag = 0, rim = 0;
    for (int y = 1; y < H - 1; y++)
        for (int x = 1; x < W - 1; x++) {
            int p = y * W + x, bg = tri[p - 1] < 0 || tri[p + 1] < 0 || tri[p - W] < 0 || tri[p + W] < 0 || tri[p] < 0;
            if (bg) rim += aa[p] != col[p];
            else diag += aa[p] != col[p];
        }
    CHECK(diag == 0);
    CHECK(rim > 60);

    double* pos;
    int32_t* sf;
    int F;
    int V = rt_sphere(&pos, &sf, &F, 30, 48, 0);
    int32_t* sopp = malloc(sizeof(int32_t) * 3 * F);
    REQUIRE(mlb_edge_topology(sopp, sf, F, V) == MLB_OK);
    for (int i = 0; i < 3 * F; i++) CHECK(sopp[i] >= 0);   // closed
    mlb_camera cam;
    REQUIRE(mlb_camera_orbit(&cam, 10, 30, 3, NULL, 45, 1, 0.1, 50) == MLB_OK);
    double* sclip = rt_project(pos, V, &cam.view_proj);
    double* n3 = malloc(sizeof(double) * 3 * H * W);
    double* a3 = malloc(sizeof(double) * 3 * H * W);
    double bary[2 * 48 * 48];
    REQUIRE(mlb_rasterize_f64(NULL, tri, bary, depth, NULL, sclip, V, sf, F, H, W) == MLB_OK);
    REQUIRE(mlb_interpolate_f64(n3, pos, V, 3, tri, bary, sf, F, H, W) == MLB_OK);
    REQUIRE(mlb_antialias_f64(NULL, a3, NULL, n3, 3, tri, depth, sclip, V, sf, sopp, F, H, W) == MLB_OK);
    int inner = 0, outline = 0;
    for (int y = 1; y < H - 1; y++)
        for (int x = 1; x < W - 1; x++) {
            int p = y * W + x, bg = tri[p - 1] < 0 || tri[p + 1] < 0 || tri[p - W] < 0 || tri[p + W] < 0 || tri[p] < 0;
            int changed = a3[3 * p] != n3[3 * p] || a3[3 * p + 1] != n3[3 * p + 1] || a3[3 * p + 2] != n3[3 * p + 2];
            if (bg) outline += changed;
            else inner += changed;
        }
    CHECK_MSG(inner == 0, "%d pixels inside the sphere's outline blended", inner);
    CHECK_MSG(outline > 40, "only %d pixels on the outline blended", outline);
    free(pos); free(sf); free(sopp); free(sclip); free(n3); free(a3);
}

// ---- topology and errors ---------------------------------------------------------------------------------
TEST(edge_topology) {
    // octahedron: closed, every edge shared by two faces
    int32_t oct[] = {0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5};
    int32_t adj[24];
    REQUIRE(mlb_edge_topology(adj, oct, 8, 6) == MLB_OK);
    for (int f = 0; f < 8; f++)
        for (int e = 0; e < 3; e++) {
            int a = oct[3 * f + (e + 1) % 3], b = oct[3 * f + (e + 2) % 3], g = adj[3 * f + e];
            REQUIRE(g >= 0 && g < 8 && g != f);
            int ha = 0, hb = 0;   // the face across holds the edge's two vertices
            for (int k = 0; k < 3; k++) { ha |= oct[3 * g + k] == a; hb |= oct[3 * g + k] == b; }
            CHECK(ha && hb);
        }
    int32_t quad[] = {0, 1, 2, 0, 2, 3}, aq[6];
    REQUIRE(mlb_edge_topology(aq, quad, 2, 4) == MLB_OK);
    // face 0 = (0,1,2): its edge opposite corner 1, (2,0), is shared with face 1, and face 1's
    // edge opposite corner 2, (0,2), with face 0; the others are boundary edges
    CHECK(aq[0] == -1 && aq[1] == 1 && aq[2] == -1);
    CHECK(aq[3] == -1 && aq[4] == -1 && aq[5] == 0);
    int32_t badf[] = {0, 1, 7};
    CHECK(mlb_edge_topology(aq, badf, 1, 4) == MLB_ERR_ARG);
    // crowded random meshes (edges shared by many faces, faces on repeated vertices) against the
    // rule by brute force: the lowest other face holding both ends, -1 for a degenerate edge
    for (int t = 0; t < 4; t++) {
        int V = 3 + 4 * t, F = 40 + 50 * t, bad = 0;
        int32_t *fc = malloc(sizeof(int32_t) * 3 * F), *ad = malloc(sizeof(int32_t) * 3 * F);
        REQUIRE(fc && ad);
        for (int i = 0; i < 3 * F; i++) fc[i] = (int32_t)(mlb_rng_uniform_f64(21, t, i) * V);
        REQUIRE(mlb_edge_topology(ad, fc, F, V) == MLB_OK);
        for (int f = 0; f < F; f++)
            for (int e = 0; e < 3; e++) {
                int a = fc[3 * f + (e + 1) % 3], b = fc[3 * f + (e + 2) % 3], want = -1;
                for (int g = 0; g < F && a != b && want < 0; g++) {
                    int ha = 0, hb = 0;
                    for (int k = 0; k < 3; k++) { ha |= fc[3 * g + k] == a; hb |= fc[3 * g + k] == b; }
                    if (g != f && ha && hb) want = g;
                }
                bad += ad[3 * f + e] != want;
            }
        CHECK_MSG(bad == 0, "V %d F %d: %d edges off the rule", V, F, bad);
        free(fc), free(ad);
    }
}

TEST(errors) {
    double clip[12] = {0, 0, 0, 1, 1, 0, 0, 1, 0, 1, 0, 1};
    int32_t faces[3] = {0, 1, 3}, good[3] = {0, 1, 2}, tri[16];
    double bary[32], out[16], attr[3] = {1, 2, 3};
    CHECK(mlb_rasterize_f64(NULL, tri, NULL, NULL, NULL, clip, 3, faces, 1, 4, 4) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "face 0") != NULL);
    CHECK(mlb_rasterize_f64(NULL, tri, NULL, NULL, NULL, clip, 3, good, 1, 0, 4) == MLB_ERR_ARG);
    CHECK(mlb_rasterize_f64(NULL, tri, NULL, NULL, NULL, clip, 3, good, 1, 4, MLB_RASTER_MAX_SIZE + 1) == MLB_ERR_ARG);
    CHECK(mlb_rasterize_f64(NULL, NULL, NULL, NULL, NULL, clip, 3, good, 1, 4, 4) == MLB_ERR_ARG);
    REQUIRE(mlb_rasterize_f64(NULL, tri, bary, NULL, NULL, clip, 3, good, 1, 4, 4) == MLB_OK);
    tri[5] = 4;   // a face id the mesh does not have
    CHECK(mlb_interpolate_f64(out, attr, 3, 1, tri, bary, good, 1, 4, 4) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "pixel 5") != NULL);
    CHECK(mlb_interpolate_f64(out, attr, 3, 0, tri, bary, good, 1, 4, 4) == MLB_ERR_ARG);
    double dclip[12] = {0}, dbary[32] = {0};
    CHECK(mlb_rasterize_backward_f64(NULL, dclip, dbary, NULL, tri, clip, 3, good, 1, 4, 4) == MLB_ERR_ARG);
    // non-finite and degenerate input draws nothing and fails nothing
    double nan_clip[12] = {NAN, 0, 0, 1, 1, 0, 0, 1, 0, 1, 0, 1};
    REQUIRE(mlb_rasterize_f64(NULL, tri, NULL, NULL, NULL, nan_clip, 3, good, 1, 4, 4) == MLB_OK);
    int drawn = 0;
    for (int p = 0; p < 16; p++) drawn += tri[p] >= 0;
    CHECK(drawn == 0);
    double zero_clip[12] = {0};
    REQUIRE(mlb_rasterize_f64(NULL, tri, NULL, NULL, NULL, zero_clip, 3, good, 1, 4, 4) == MLB_OK);
    for (int p = 0; p < 16; p++) CHECK(tri[p] == -1);
    REQUIRE(mlb_rasterize_f64(NULL, tri, NULL, NULL, NULL, clip, 0, NULL, 0, 4, 4) == MLB_OK);   // empty mesh
}

int main(void) {
    RUN(camera_matrices);
    RUN(watertight_grid);
    RUN(watertight_fan);
    RUN(watertight_perspective);
    RUN(watertight_closed_mesh);
    RUN(watertight_clipped_grid);
    RUN(fill_rule);
    RUN(quad_area);
    RUN(perspective_plane);
    RUN(near_plane_clipping);
    RUN(backfacing_and_ties);
    RUN(thread_determinism);
    RUN(antialias_coverage);
    RUN(antialias_silhouettes);
    RUN(edge_topology);
    RUN(errors);
    return test_summary();
}
