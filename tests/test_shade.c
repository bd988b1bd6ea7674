// Split-sum shading: the LUT against reference.md's check values, finite-difference checks of every
// input of the shading backward (in double, through the very code the float path runs), sRGB, and
// the split sum against a brute-force Monte-Carlo integration of the rendering equation.
#include "test.h"
#include <omp.h>
#include "matlaber/brdf.h"
#include "matlaber/envmap.h"
#include "matlaber/rng.h"
#include "matlaber/shade.h"

#define PI 3.14159265358979323846

static double dot3(const double a[3], const double b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
static double lum3(const double* p) { return 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]; }

static void rand_dir(uint64_t i, double d[3]) {
    double z = 2 * mlb_rng_uniform_f64(9, 1, i) - 1, ph = 2 * PI * mlb_rng_uniform_f64(9, 2, i), r = sqrt(1 - z * z);
    d[0] = r * cos(ph), d[1] = z, d[2] = r * sin(ph);
}

// ---------------------------------------------------------------- LUT

TEST(lut_check_values) {
    const float* lut = mlb_splitsum_lut();
    REQUIRE(lut);
    struct { int row, col; double b0, b1; } ref[4] = {{128, 128, 0.8343, 0.0219}, {200, 64, 0.7020, 0.0243}, {0, 0, 0.0097, 0.9902},
                                                       {255, 255, 0.3093, 0.0}};
    for (int i = 0; i < 4; i++) {
        const float* t = lut + ((size_t)ref[i].row * MLB_LUT_SIZE + ref[i].col) * 2;
        printf("  (%3d, %3d): B0 %.4f B1 %.4f   reference %.4f %.4f\n", ref[i].row, ref[i].col, t[0], t[1], ref[i].b0, ref[i].b1);
        CHECK_CLOSE(t[0], ref[i].b0, 0, 1e-3);
        CHECK_CLOSE(t[1], ref[i].b1, 0, 1e-3);
    }
    double lo = 1, hi = 0;
    for (int i = 0; i < MLB_LUT_SIZE * MLB_LUT_SIZE; i++) {
        lo = fmin(lo, fmin(lut[2 * i], lut[2 * i + 1]));
        hi = fmax(hi, lut[2 * i] + lut[2 * i + 1]);   // the albedo of GGX with F = 1 is at most 1
    }
    CHECK(lo >= 0 && hi <= 1.0005);
    // the cached table is the computed one, and every thread gets the same table
    float* fresh = malloc((size_t)MLB_LUT_SIZE * MLB_LUT_SIZE * 2 * sizeof(float));
    REQUIRE(fresh && mlb_splitsum_lut_compute(fresh) == MLB_OK);
    CHECK(memcmp(fresh, lut, (size_t)MLB_LUT_SIZE * MLB_LUT_SIZE * 2 * sizeof(float)) == 0);
    free(fresh);
    int same = 1;
#pragma omp parallel num_threads(2) reduction(& : same)
    same = mlb_splitsum_lut() == lut;
    CHECK(same);
}

TEST(lut_lookup) {
    const float* lut = mlb_splitsum_lut();
    REQUIRE(lut);
    double b[2], dn[2], dr[2];
    mlb_splitsum_lookup(lut, (37 + 0.5) / 256, (201 + 0.5) / 256, b, NULL, NULL);   // texel centres hit texels
    CHECK_CLOSE(b[0], lut[(201 * 256 + 37) * 2], 1e-6, 0);
    CHECK_CLOSE(b[1], lut[(201 * 256 + 37) * 2 + 1], 1e-6, 0);
    mlb_splitsum_lookup(lut, 0, 0.5, b, dn, NULL);   // n.v clamped: the first column, no gradient
    CHECK_CLOSE(b[0], 0.5 * (lut[(127 * 256) * 2] + lut[(128 * 256) * 2]), 1e-6, 0);
    CHECK(dn[0] == 0 && dn[1] == 0);
    const double h = 1e-7;
    double worst = 0;
    for (int i = 0; i < 200; i++) {
        double nv = 0.01 + 0.98 * mlb_rng_uniform_f64(10, 1, i), r = 0.01 + 0.98 * mlb_rng_uniform_f64(10, 2, i), p[2], m[2];
        if (floor(nv * 256 - 0.5 + 1e-6) != floor(nv * 256 - 0.5 - 1e-6) || floor(r * 256 - 0.5 + 1e-6) != floor(r * 256 - 0.5 - 1e-6))
            continue;
        mlb_splitsum_lookup(lut, nv, r, b, dn, dr);
        mlb_splitsum_lookup(lut, nv + h, r, p, NULL, NULL);
        mlb_splitsum_lookup(lut, nv - h, r, m, NULL, NULL);
        for (int k = 0; k < 2; k++) worst = fmax(worst, fabs((p[k] - m[k]) / (2 * h) - dn[k]) / (1 + fabs(dn[k])));
        mlb_splitsum_lookup(lut, nv, r + h, p, NULL, NULL);
        mlb_splitsum_lookup(lut, nv, r - h, m, NULL, NULL);
        for (int k = 0; k < 2; k++) worst = fmax(worst, fabs((p[k] - m[k]) / (2 * h) - dr[k]) / (1 + fabs(dr[k])));
    }
    CHECK(worst < 1e-6);
}

// ---------------------------------------------------------------- shading

typedef struct {
    double kd[3], ks[3], kr, n[3], v[3];
} point;

static void rand_point(uint64_t i, point* p) {
    for (int c = 0; c < 3; c++) p->kd[c] = mlb_rng_uniform_f64(11, c, i), p->ks[c] = mlb_rng_uniform_f64(11, 3 + c, i);
    p->kr = 0.1 + 0.85 * mlb_rng_uniform_f64(11, 6, i);
    rand_dir(1000 + i, p->n);
    double t[3];   // a view direction at a random angle to n, n.v in [0.15, 0.95]
    rand_dir(2000 + i, t);
    double tn = dot3(t, p->n);
    for (int k = 0; k < 3; k++) t[k] -= tn * p->n[k];
    double tl = sqrt(dot3(t, t)), c = 0.15 + 0.8 * mlb_rng_uniform_f64(11, 7, i), s = sqrt(1 - c * c);
    for (int k = 0; k < 3; k++) p->v[k] = c * p->n[k] + s * t[k] / tl;
}

// Everything piecewise in the shading (texel cells of every lookup, mip level, LUT cell, clamps,
// the Fresnel branch), so that a finite-difference stencil that crosses a kink can be skipped.
static void signature(const mlb_envlight* L, const point* p, long sig[64]) {
    int k = 0;
    double nv = dot3(p->n, p->v), r[3], lr[3], ln[3], x, y;
    int f;
    for (int i = 0; i < 3; i++) r[i] = 2 * nv * p->n[i] - p->v[i];
    mlb_rotate_y(lr, r, -(double)L->rotation);
    mlb_rotate_y(ln, p->n, -(double)L->rotation);
    mlb_cube_dir_to_texel(ln, L->irr_size, &f, &x, &y);
    sig[k++] = f, sig[k++] = (long)floor(x), sig[k++] = (long)floor(y);
    for (int l = 0; l < L->n_levels; l++) {
        mlb_cube_dir_to_texel(lr, L->size[l], &f, &x, &y);
        sig[k++] = f, sig[k++] = (long)floor(x), sig[k++] = (long)floor(y);
    }
    sig[k++] = (long)floor(mlb_envlight_mip(L, p->kr, NULL)), sig[k++] = p->kr < 0.5, sig[k++] = p->kr < 0.08;
    sig[k++] = (long)floor(nv * 256 - 0.5), sig[k++] = (long)floor(p->kr * 256 - 0.5), sig[k++] = nv < 1e-4, sig[k++] = nv > 1;
    for (int c = 0; c < 3; c++) sig[k++] = 1 - p->kr > p->ks[c];
    while (k < 64) sig[k++] = 0;
}

static double shade1(const mlb_envlight* L, const point* p, const double g[3], mlb_fresnel fm) {
    double out[3];
    mlb_shade_forward_f64(out, p->kd, p->ks, &p->kr, p->n, p->v, 1, L, fm);
    return dot3(out, g);
}

static double* field(point* p, int k) {   // input k of 13: kd 0-2, ks 3-5, kr 6, n 7-9, v 10-12
    return k < 3 ? &p->kd[k] : k < 6 ? &p->ks[k - 3] : k == 6 ? &p->kr : k < 10 ? &p->n[k - 7] : &p->v[k - 10];
}

TEST(shading_gradients) {
    mlb_envmap env;
    REQUIRE(mlb_envmap_named(&env, "sky", 32) == MLB_OK);
    mlb_envlight L;
    mlb_envlight_options o = {.face_size = 16, .min_size = 4};
    REQUIRE(mlb_envlight_build(&L, &env, &o) == MLB_OK);
    mlb_envlight_set_rotation(&L, 0.4f);
    const double h = 1e-6;
    const char* names[13] = {"kd.r", "kd.g", "kd.b", "ks.r", "ks.g", "ks.b", "kr", "n.x", "n.y", "n.z", "v.x", "v.y", "v.z"};
    for (int fm = 0; fm < 2; fm++) {
        double worst[13] = {0};
        int checked[13] = {0};
        for (int i = 0; i < 150; i++) {
            point p;
            rand_point(i, &p);
            double g[3] = {mlb_rng_normal_f64(12, 0, i), mlb_rng_normal_f64(12, 1, i), mlb_rng_normal_f64(12, 2, i)};
            double gkd[3] = {0}, gks[3] = {0}, gkr = 0, gn[3] = {0}, gv[3] = {0};
            REQUIRE(mlb_shade_backward_f64(gkd, gks, &gkr, gn, gv, g, p.kd, p.ks, &p.kr, p.n, p.v, 1, &L, (mlb_fresnel)fm) == MLB_OK);
            double an[13] = {gkd[0], gkd[1], gkd[2], gks[0], gks[1], gks[2], gkr, gn[0], gn[1], gn[2], gv[0], gv[1], gv[2]};
            for (int k = 0; k < 13; k++) {
                point pp = p, pm = p;
                *field(&pp, k) += h, *field(&pm, k) -= h;
                long sp[64], sm[64];
                signature(&L, &pp, sp);
                signature(&L, &pm, sm);
                if (memcmp(sp, sm, sizeof sp) != 0) continue;
                double fd = (shade1(&L, &pp, g, (mlb_fresnel)fm) - shade1(&L, &pm, g, (mlb_fresnel)fm)) / (2 * h);
                worst[k] = fmax(worst[k], fabs(fd - an[k]) / (1 + fabs(an[k])));
                checked[k]++;
            }
        }
        printf("  %s Fresnel, worst relative error of d/d input (checks):\n   ", fm ? "Schlick" : "paper");
        for (int k = 0; k < 13; k++) {
            printf(" %s %.1e (%d)", names[k], worst[k], checked[k]);
            CHECK_MSG(checked[k] > 120 && worst[k] < 1e-6, "%s: %d checks, worst %g", names[k], checked[k], worst[k]);
        }
        printf("\n");
    }
    mlb_envlight_free(&L);
    mlb_envmap_free(&env);
}

TEST(shading_api) {
    mlb_envmap env;
    REQUIRE(mlb_envmap_named(&env, "studio", 32) == MLB_OK);
    mlb_envlight L;
    mlb_envlight_options o = {.face_size = 16, .min_size = 4};
    REQUIRE(mlb_envlight_build(&L, &env, &o) == MLB_OK);
    enum { N = 1000 };
    float *kd = malloc(N * 3 * 4), *ks = malloc(N * 3 * 4), *kr = malloc(N * 4), *n = malloc(N * 3 * 4), *v = malloc(N * 3 * 4);
    float *out = malloc(N * 3 * 4), *out2 = malloc(N * 3 * 4), *g = malloc(N * 3 * 4);
    float* grads[2][5];
    for (int t = 0; t < 2; t++)
        for (int q = 0; q < 5; q++) grads[t][q] = calloc(N * 3, 4);
    REQUIRE(kd && ks && kr && n && v && out && out2 && g);
    double worst = 0;
    for (int i = 0; i < N; i++) {
        point p;
        rand_point(i, &p);
        for (int c = 0; c < 3; c++)
            kd[3 * i + c] = (float)p.kd[c], ks[3 * i + c] = (float)p.ks[c], n[3 * i + c] = (float)p.n[c], v[3 * i + c] = (float)p.v[c],
                    g[3 * i + c] = (float)mlb_rng_normal_f64(13, c, i);
        kr[i] = (float)p.kr;
    }
    int saved = omp_get_max_threads();
    for (int t = 0; t < 2; t++) {
        omp_set_num_threads(t + 1);
        REQUIRE(mlb_shade_forward(t ? out2 : out, kd, ks, kr, n, v, N, &L, MLB_FRESNEL_PAPER) == MLB_OK);
        REQUIRE(mlb_shade_backward(grads[t][0], grads[t][1], grads[t][2], grads[t][3], grads[t][4], g, kd, ks, kr, n, v, N, &L,
                                   MLB_FRESNEL_PAPER) == MLB_OK);
    }
    omp_set_num_threads(saved);
    CHECK(memcmp(out, out2, N * 3 * 4) == 0);   // thread count does not matter
    for (int q = 0; q < 5; q++) CHECK(memcmp(grads[0][q], grads[1][q], (q == 2 ? N : N * 3) * 4) == 0);
    for (int i = 0; i < N; i++) {   // float entry points = the double ones on the same (float) inputs
        double a[3], b[3], c3[3], d[3], e[3], r = kr[i], o64[3];
        for (int c = 0; c < 3; c++) a[c] = kd[3 * i + c], b[c] = ks[3 * i + c], d[c] = n[3 * i + c], e[c] = v[3 * i + c];
        mlb_shade_forward_f64(o64, a, b, &r, d, e, 1, &L, MLB_FRESNEL_PAPER);
        for (int c = 0; c < 3; c++) worst = fmax(worst, fabs(out[3 * i + c] - o64[c]) / (1e-3 + fabs(o64[c])));
        (void)c3;
    }
    CHECK(worst < 1e-6);
    // backward accumulates, and every gradient may be NULL
    REQUIRE(mlb_shade_backward(grads[1][0], NULL, NULL, NULL, grads[1][4], g, kd, ks, kr, n, v, N, &L, MLB_FRESNEL_PAPER) == MLB_OK);
    CHECK_CLOSE(grads[1][0][17], 2 * grads[0][0][17], 1e-6, 1e-9);
    CHECK_CLOSE(grads[1][4][29], 2 * grads[0][4][29], 1e-6, 1e-9);
    CHECK(grads[1][2][5] == grads[0][2][5]);
    CHECK(mlb_shade_backward(NULL, NULL, NULL, NULL, NULL, g, kd, ks, kr, n, v, N, &L, MLB_FRESNEL_SCHLICK) == MLB_OK);
    CHECK(mlb_shade_forward(out, kd, ks, kr, n, v, 0, &L, MLB_FRESNEL_PAPER) == MLB_OK);
    // hostile values do not crash (NaN in, NaN or 0 out)
    kd[0] = NAN, n[3] = NAN, v[7] = INFINITY, kr[2] = NAN;
    CHECK(mlb_shade_forward(out, kd, ks, kr, n, v, 3, &L, MLB_FRESNEL_PAPER) == MLB_OK);
    CHECK(mlb_shade_backward(grads[0][0], grads[0][1], grads[0][2], grads[0][3], grads[0][4], g, kd, ks, kr, n, v, 3, &L,
                             MLB_FRESNEL_PAPER) == MLB_OK);
    mlb_envlight empty = {0};
    CHECK(mlb_shade_forward(out, kd, ks, kr, n, v, N, &empty, MLB_FRESNEL_PAPER) == MLB_ERR_ARG);
    CHECK(mlb_shade_forward(out, kd, ks, kr, n, v, -1, &L, MLB_FRESNEL_PAPER) == MLB_ERR_ARG);
    for (int t = 0; t < 2; t++)
        for (int q = 0; q < 5; q++) free(grads[t][q]);
    free(kd), free(ks), free(kr), free(n), free(v), free(out), free(out2), free(g);
    mlb_envlight_free(&L);
    mlb_envmap_free(&env);
}

// The formula itself under a constant map (every lookup is exactly the radiance), and the
// reflection convention under the sun.
TEST(shading_formula) {
    const float* lut = mlb_splitsum_lut();
    mlb_envmap env;
    REQUIRE(lut && mlb_envmap_named(&env, "white", 16) == MLB_OK);
    mlb_envmap_scale(&env, 3.0f);
    mlb_envlight L;
    mlb_envlight_options o = {.face_size = 16, .min_size = 4};
    REQUIRE(mlb_envlight_build(&L, &env, &o) == MLB_OK);
    for (int i = 0; i < 50; i++) {
        point p;
        rand_point(50 + i, &p);
        double out[2][3], nv = dot3(p.n, p.v), b[2];
        mlb_splitsum_lookup(lut, nv, p.kr, b, NULL, NULL);
        mlb_shade_forward_f64(out[0], p.kd, p.ks, &p.kr, p.n, p.v, 1, &L, MLB_FRESNEL_PAPER);
        mlb_shade_forward_f64(out[1], p.kd, p.ks, &p.kr, p.n, p.v, 1, &L, MLB_FRESNEL_SCHLICK);
        for (int c = 0; c < 3; c++) {
            double f0 = p.ks[c], F = f0 + (fmax(1 - p.kr, f0) - f0) * pow(1 - nv, 5);
            CHECK_CLOSE(out[0][c], 3 * (p.kd[c] + F * b[0] + b[1]), 1e-5, 0);
            CHECK_CLOSE(out[1][c], 3 * (p.kd[c] + f0 * b[0] + b[1]), 1e-5, 0);
        }
    }
    mlb_envlight_free(&L);
    mlb_envmap_free(&env);
    // a mirror-like metal on a floor (n = +y) reflects the sun when v is the sun's mirror image
    REQUIRE(mlb_envmap_named(&env, "sky", 128) == MLB_OK);
    mlb_envlight_options o2 = {.face_size = 64, .min_size = 8};
    REQUIRE(mlb_envlight_build(&L, &env, &o2) == MLB_OK);
    double el = 40 * PI / 180, az = PI / 4;
    double sun[3] = {cos(el) * sin(az), sin(el), -cos(el) * cos(az)}, mirror[3] = {-sun[0], sun[1], -sun[2]};
    double away[3] = {sun[0], sun[1], sun[2]};
    point p = {{0, 0, 0}, {1, 1, 1}, 0.1, {0, 1, 0}, {0}};
    double hi[3], lo[3];
    memcpy(p.v, mirror, sizeof mirror);
    mlb_shade_forward_f64(hi, p.kd, p.ks, &p.kr, p.n, p.v, 1, &L, MLB_FRESNEL_PAPER);
    memcpy(p.v, away, sizeof away);
    mlb_shade_forward_f64(lo, p.kd, p.ks, &p.kr, p.n, p.v, 1, &L, MLB_FRESNEL_PAPER);
    printf("  chrome floor: %.1f looking at the sun's reflection, %.3f looking away\n", lum3(hi), lum3(lo));
    CHECK(lum3(hi) > 100 * lum3(lo));
    mlb_envlight_free(&L);
    mlb_envmap_free(&env);
}

TEST(srgb) {
    float x[6] = {0, 0.002f, 0.0031308f, 0.01f, 0.5f, 1.0f}, y[6], d[6] = {0}, one[6] = {1, 1, 1, 1, 1, 1};
    mlb_srgb_forward(y, x, 6);
    for (int i = 0; i < 6; i++) CHECK_CLOSE(y[i], mlb_linear_to_srgb(x[i]), 1e-6, 1e-7);
    CHECK_CLOSE(y[5], 1.0, 0, 1e-6);
    CHECK_CLOSE(y[4], 1.055 * pow(0.5, 1 / 2.4) - 0.055, 1e-6, 0);
    mlb_srgb_backward(d, one, x, 6);
    CHECK_CLOSE(d[1], 12.92, 1e-6, 0);
    for (int i = 3; i < 6; i++) {   // away from the kink at 0.0031308
        double h = 1e-3 * x[i], fp = 1.055 * pow(x[i] + h, 1 / 2.4) - 0.055, fm = 1.055 * pow(x[i] - h, 1 / 2.4) - 0.055;
        CHECK_CLOSE(d[i], (fp - fm) / (2 * h), 1e-5, 0);
    }
}

// ---------------------------------------------------------------- Monte-Carlo ground truth

// Sphere points seen by a camera looking along -z (v = +z): normals tilted from v by acos(n.v)
// towards up, right, down and left.
enum { N_NV = 3, N_AZ = 4, N_PTS = N_NV * N_AZ };
static const double NV[N_NV] = {0.9, 0.6, 0.3};

static void sphere_point(int i, double n[3], double v[3]) {
    double c = NV[i / N_AZ], s = sqrt(1 - c * c), a = (i % N_AZ) * PI / 2;
    v[0] = 0, v[1] = 0, v[2] = 1;
    n[0] = s * sin(a), n[1] = s * cos(a), n[2] = c;
}

typedef struct {
    double mean, max, err_hi_nv, err_lo_nv, max_sem;   // relative errors; at n.v = 0.9 and 0.3; MC stderr
    double or_mean, or_max, impl_mean, impl_max;       // oracle vs truth; cube split sum vs oracle
} cell;

// The split sum without any discretization: kd E/pi + (F0 B0 + B1) P, with E and P (the lobe
// max(l.r, 0) D(r.h), N = V = R, over the whole sphere, no cone) summed over the map's pixels with
// their exact solid angles, and B0, B1 integrated at (n.v, kr) itself. Its distance to the truth is
// the approximation's own error; the cube's distance to it is the implementation's.
static void oracle(const mlb_envmap* env, const float k[7], const double n[3], const double v[3], mlb_fresnel fm, double out[3]) {
    double nv = dot3(n, v), r[3], a2 = pow(k[6], 4), ps[3] = {0, 0, 0}, pw = 0, e[3] = {0, 0, 0}, b0, b1;
    for (int i = 0; i < 3; i++) r[i] = 2 * nv * n[i] - v[i];
    for (int j = 0; j < env->h; j++) {
        double sa = 2 * PI / env->w * (cos(PI * j / env->h) - cos(PI * (j + 1) / env->h));
        for (int q = 0; q < env->w; q++) {
            double d[3], dl[3];
            mlb_latlong_uv_to_dir((q + 0.5) / env->w, (j + 0.5) / env->h, dl);
            mlb_rotate_y(d, dl, env->rotation);
            const float* p = env->data + ((size_t)j * env->w + q) * 3;
            double c = dot3(d, r), cn = dot3(d, n);
            if (c > 0) {
                double dd = 0.5 * (1 + c) * (a2 - 1) + 1, w = c * a2 / (dd * dd) * sa;
                for (int ch = 0; ch < 3; ch++) ps[ch] += w * p[ch];
                pw += w;
            }
            if (cn > 0)
                for (int ch = 0; ch < 3; ch++) e[ch] += p[ch] * cn * sa / PI;
        }
    }
    mlb_splitsum_integrate(nv, k[6], &b0, &b1);
    for (int ch = 0; ch < 3; ch++) {
        double f0 = k[3 + ch], F = fm == MLB_FRESNEL_PAPER ? f0 + (fmax(1 - k[6], f0) - f0) * pow(1 - nv, 5) : f0;
        out[ch] = k[ch] * e[ch] + (F * b0 + b1) * ps[ch] / pw;
    }
}

// Relative error of the split sum against the Monte-Carlo truth at every sphere point for one material.
static cell compare(const mlb_envmap* env, const mlb_envmap_sampler* smp, const mlb_envlight* L, const float k[7], mlb_fresnel fm,
                    int samples, uint64_t stream) {
    cell c = {0};
    double err[N_PTS], sem[N_PTS], oerr[N_PTS], ierr[N_PTS];
#pragma omp parallel for schedule(dynamic)
    for (int i = 0; i < N_PTS; i++) {
        double n[3], v[3], truth[3], se[3], ss[3], orc[3];
        sphere_point(i, n, v);
        mlb_shade_reference(truth, se, k, n, v, env, smp, samples, 77, stream * 64 + i);
        double kd[3] = {k[0], k[1], k[2]}, ks[3] = {k[3], k[4], k[5]}, kr = k[6];
        mlb_shade_forward_f64(ss, kd, ks, &kr, n, v, 1, L, fm);
        oracle(env, k, n, v, fm, orc);
        err[i] = fabs(lum3(ss) - lum3(truth)) / lum3(truth);
        oerr[i] = fabs(lum3(orc) - lum3(truth)) / lum3(truth);
        ierr[i] = fabs(lum3(ss) - lum3(orc)) / lum3(orc);
        sem[i] = lum3(se) / lum3(truth);
    }
    for (int i = 0; i < N_PTS; i++) {
        c.mean += err[i] / N_PTS;
        c.max = fmax(c.max, err[i]);
        c.or_mean += oerr[i] / N_PTS;
        c.or_max = fmax(c.or_max, oerr[i]);
        c.impl_mean += ierr[i] / N_PTS;
        c.impl_max = fmax(c.impl_max, ierr[i]);
        c.max_sem = fmax(c.max_sem, sem[i]);
        if (i / N_AZ == 0) c.err_hi_nv += err[i] / N_AZ;
        if (i / N_AZ == N_NV - 1) c.err_lo_nv += err[i] / N_AZ;
    }
    return c;
}

static const double KR[] = {0.1, 0.2, 0.3, 0.5, 0.7, 1.0};
static const double F0[] = {0.04, 0.5, 1.0};
static const double KD[] = {0.0, 0.5};
enum { N_KR = 6, N_F0 = 3, N_KD = 2 };

// The table of mean / max relative error over the sphere points, per roughness (rows) and
// (kd, F0) (columns). Returns the worst cell and the grand mean.
static void table(const char* title, const mlb_envmap* env, const mlb_envlight* L, mlb_fresnel fm, int samples, cell* worst,
                  double* grand_mean, cell out[N_KR][N_KD * N_F0]) {
    mlb_envmap_sampler smp;
    if (mlb_envmap_sampler_build(&smp, env) != MLB_OK) return;
    printf("\n  %s: split sum vs Monte Carlo, relative error of luminance, mean / max over %d sphere points\n", title, N_PTS);
    printf("  | kr   |");
    for (int d = 0; d < N_KD; d++)
        for (int f = 0; f < N_F0; f++) printf(" kd %.1f F0 %.2f |", KD[d], F0[f]);
    printf("\n  |------|");
    for (int q = 0; q < N_KD * N_F0; q++) printf("-----------------|");
    printf("\n");
    *worst = (cell){0};
    *grand_mean = 0;
    double rows[N_KR][4] = {{0}};
    for (int r = 0; r < N_KR; r++) {
        printf("  | %.2f |", KR[r]);
        for (int d = 0; d < N_KD; d++)
            for (int f = 0; f < N_F0; f++) {
                float k[7] = {(float)KD[d], (float)KD[d], (float)KD[d], (float)F0[f], (float)F0[f], (float)F0[f], (float)KR[r]};
                cell c = compare(env, &smp, L, k, fm, samples, (uint64_t)(r * 16 + d * 4 + f));
                out[r][d * N_F0 + f] = c;
                printf("  %5.1f%% / %5.1f%% |", 100 * c.mean, 100 * c.max);
                worst->mean = fmax(worst->mean, c.mean);
                worst->max = fmax(worst->max, c.max);
                worst->max_sem = fmax(worst->max_sem, c.max_sem);
                worst->or_mean = fmax(worst->or_mean, c.or_mean), worst->or_max = fmax(worst->or_max, c.or_max);
                worst->impl_mean = fmax(worst->impl_mean, c.impl_mean), worst->impl_max = fmax(worst->impl_max, c.impl_max);
                rows[r][0] += c.or_mean / (N_KD * N_F0), rows[r][1] = fmax(rows[r][1], c.or_max);
                rows[r][2] += c.impl_mean / (N_KD * N_F0), rows[r][3] = fmax(rows[r][3], c.impl_max);
                *grand_mean += c.mean / (N_KR * N_KD * N_F0);
            }
        printf("\n");
    }
    printf("  largest Monte-Carlo standard error: %.2f%%; grand mean error %.2f%%\n", 100 * worst->max_sem, 100 * *grand_mean);
    printf("  where it comes from, mean / max over all materials per roughness:\n");
    printf("  | kr   | undiscretised split sum vs truth | cube split sum vs undiscretised |\n");
    printf("  |------|----------------------------------|---------------------------------|\n");
    for (int r = 0; r < N_KR; r++)
        printf("  | %.2f |                %5.1f%% / %5.1f%% |               %5.1f%% / %5.1f%% |\n", KR[r], 100 * rows[r][0],
               100 * rows[r][1], 100 * rows[r][2], 100 * rows[r][3]);
    mlb_envmap_sampler_free(&smp);
}

// A constant environment: irradiance and prefiltered radiance are exactly the map's radiance, so
// the split sum (with the Fresnel it was built for, F0 B0 + B1) is exact up to the LUT's
// quadrature and bilinear interpolation: a tight bound. (Roughness 1 itself lies half a texel
// beyond the LUT's last texel centre, 255.5/256, where the lookup clamps: up to 0.6% there.)
TEST(split_sum_exact_for_constant_light) {
    mlb_envmap env;
    REQUIRE(mlb_envmap_named(&env, "white", 32) == MLB_OK);
    mlb_envmap_scale(&env, 2.0f);
    mlb_envlight L;
    mlb_envlight_options o = {.face_size = 32, .min_size = 4};
    REQUIRE(mlb_envlight_build(&L, &env, &o) == MLB_OK);
    mlb_envmap_sampler smp;
    REQUIRE(mlb_envmap_sampler_build(&smp, &env) == MLB_OK);
    double worst = 0, worst_sem = 0;
    const double nvs[4] = {0.95, 0.7, 0.4, 0.15}, krs[4] = {0.1, 0.3, 0.6, 0.95};
    for (int a = 0; a < 4; a++)
        for (int b = 0; b < 4; b++)
            for (int m = 0; m < 2; m++) {
                float k[7] = {0, 0, 0, 1, 1, 1, (float)krs[b]};
                if (m) k[0] = k[1] = k[2] = 0.5f, k[3] = k[4] = k[5] = 0.04f;
                double s = sqrt(1 - nvs[a] * nvs[a]), n[3] = {0, 1, 0}, v[3] = {s, nvs[a], 0}, truth[3], se[3], ss[3];
                double kd[3] = {k[0], k[1], k[2]}, ks[3] = {k[3], k[4], k[5]}, kr = k[6];
                REQUIRE(mlb_shade_reference(truth, se, k, n, v, &env, &smp, 16384, 5, (uint64_t)(a * 8 + b * 2 + m)) == MLB_OK);
                mlb_shade_forward_f64(ss, kd, ks, &kr, n, v, 1, &L, MLB_FRESNEL_SCHLICK);
                worst = fmax(worst, fabs(ss[1] - truth[1]) / truth[1]);
                worst_sem = fmax(worst_sem, se[1] / truth[1]);
            }
    printf("  constant light: worst relative error %.5f (Monte-Carlo standard error up to %.5f)\n", worst, worst_sem);
    CHECK(worst < 2e-3 && worst_sem < 1e-3);
    mlb_envmap_sampler_free(&smp);
    mlb_envlight_free(&L);
    mlb_envmap_free(&env);
}

// A smooth, non-constant light (CIE overcast sky over a darker ground): the error is the split
// sum's own (the lobe taken as symmetric about the reflection direction and the light pulled out
// of the integral). It grows towards grazing view and with roughness, where the true lobe leans
// off the reflection direction and is clipped by the horizon. Cube with exact texel solid angles,
// so that the texel weights of reference.md (measured separately) add nothing.
TEST(split_sum_vs_monte_carlo) {
    mlb_envmap env;
    REQUIRE(mlb_envmap_named(&env, "overcast", 128) == MLB_OK);
    mlb_envmap_set_rotation(&env, 0.5f);
    mlb_envlight L;
    mlb_envlight_options o = {.face_size = 128, .min_size = 16, .reference_weights = 0};
    REQUIRE(mlb_envlight_build(&L, &env, &o) == MLB_OK);
    static cell t[N_KR][N_KD * N_F0];
    cell worst;
    double grand;
    table("overcast, Schlick F0 B0 + B1 (the split sum of the reference BRDF)", &env, &L, MLB_FRESNEL_SCHLICK, 2048, &worst, &grand, t);
    CHECK(worst.max_sem < 0.01);   // the truth is accurate enough to measure errors of a few percent
    // the implementation: the cube split sum within 3% (mean) / 5% (max) of the undiscretised one
    // (worst at kr = 0.7, blended from the levels prefiltered at 0.5 and 1.0)
    printf("  cube vs undiscretised: worst cell mean %.2f%%, max %.2f%%\n", 100 * worst.impl_mean, 100 * worst.impl_max);
    CHECK(worst.impl_mean < 0.03 && worst.impl_max < 0.05);
    // the total, which is the approximation's own error (it matches the undiscretised split sum's):
    // 3.9% on average, 14% mean / 42% max in the worst cell (roughness 1, grazing)
    CHECK(grand < 0.05);
    CHECK(worst.mean < 0.18);
    CHECK(worst.max < 0.50);
    CHECK(fabs(worst.or_max - worst.max) < 0.05);
    double hi = 0, lo = 0, smooth = 0, rough = 0;   // where the error lives
    for (int r = 0; r < N_KR; r++)
        for (int q = 0; q < N_KD * N_F0; q++) {
            hi += t[r][q].err_hi_nv, lo += t[r][q].err_lo_nv;
            if (r == 0) smooth += t[r][q].mean;
            if (r == N_KR - 1) rough += t[r][q].mean;
        }
    printf("  mean error at n.v = 0.9: %.2f%%, at n.v = 0.3: %.2f%%; at kr = 0.1: %.2f%%, at kr = 1: %.2f%%\n",
           100 * hi / (N_KR * N_KD * N_F0), 100 * lo / (N_KR * N_KD * N_F0), 100 * smooth / (N_KD * N_F0), 100 * rough / (N_KD * N_F0));
    CHECK(lo > hi);
    CHECK(rough > smooth);
    // The paper's Fresnel (F, not F0, multiplies B0) against the same truth, and the cube with
    // reference.md's texel weights: reported, not bounded (they are not the split sum's error).
    table("overcast, paper Fresnel F B0 + B1", &env, &L, MLB_FRESNEL_PAPER, 2048, &worst, &grand, t);
    mlb_envlight R;
    o.reference_weights = 1;
    REQUIRE(mlb_envlight_build(&R, &env, &o) == MLB_OK);
    table("overcast, Schlick, reference.md texel weights", &env, &R, MLB_FRESNEL_SCHLICK, 2048, &worst, &grand, t);
    mlb_envlight_free(&R);
    mlb_envlight_free(&L);
    mlb_envmap_free(&env);
}

// Sharp light (a sun; soft boxes): reported for the record. The trilinear blend of two prefiltered
// levels is not the lobe of the roughness in between, and a sun makes that visible.
TEST(split_sum_under_sharp_light) {
    const char* names[2] = {"sky", "studio"};
    for (int e = 0; e < 2; e++) {
        mlb_envmap env;
        REQUIRE(mlb_envmap_named(&env, names[e], 128) == MLB_OK);
        mlb_envlight L;
        mlb_envlight_options o = {.face_size = 128, .min_size = 16, .reference_weights = 0};
        REQUIRE(mlb_envlight_build(&L, &env, &o) == MLB_OK);
        static cell t[N_KR][N_KD * N_F0];
        cell worst;
        double grand;
        char title[64];
        snprintf(title, sizeof title, "%s, Schlick", names[e]);
        table(title, &env, &L, MLB_FRESNEL_SCHLICK, 2048, &worst, &grand, t);
        CHECK(worst.max_sem < 0.1);
        mlb_envlight_free(&L);
        mlb_envmap_free(&env);
    }
}

// The gradient to surface positions: through the view direction, checked by central differences.
TEST(view_direction_backward_to_positions) {
    enum { N = 5 };
    double p[3 * N], dv[3 * N], eye[3] = {0.3, 1.1, 3.0}, v[3 * N], dp[3 * N] = {0};
    for (int i = 0; i < 3 * N; i++) { p[i] = 0.4 * sin(1.7 * i + 0.3); dv[i] = cos(2.3 * i + 0.1); }
    mlb_view_dirs_f64(v, p, eye, N);
    for (int i = 0; i < N; i++) CHECK_CLOSE(v[3 * i] * v[3 * i] + v[3 * i + 1] * v[3 * i + 1] + v[3 * i + 2] * v[3 * i + 2], 1, 1e-12, 0);
    mlb_view_dirs_backward_f64(dp, dv, p, eye, N);
    double h = 1e-6;
    for (int i = 0; i < 3 * N; i++) {
        double keep = p[i], vp[3 * N], vm[3 * N], Lp = 0, Lm = 0;
        p[i] = keep + h; mlb_view_dirs_f64(vp, p, eye, N);
        p[i] = keep - h; mlb_view_dirs_f64(vm, p, eye, N);
        p[i] = keep;
        for (int j = 0; j < 3 * N; j++) { Lp += dv[j] * vp[j]; Lm += dv[j] * vm[j]; }
        CHECK_CLOSE(dp[i], (Lp - Lm) / (2 * h), 1e-7, 1e-9);
    }
}

int main(void) {
    RUN(lut_check_values);
    RUN(lut_lookup);
    RUN(shading_gradients);
    RUN(shading_api);
    RUN(shading_formula);
    RUN(srgb);
    RUN(split_sum_exact_for_constant_light);
    RUN(split_sum_vs_monte_carlo);
    RUN(split_sum_under_sharp_light);
    RUN(view_direction_backward_to_positions);
    return test_summary();
}
