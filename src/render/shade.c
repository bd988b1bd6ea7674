// Split-sum shading (MATLABER §3.4) with its backward, linear -> sRGB, and the Monte-Carlo
// ground truth it is checked against. Every point is computed in double from float texels: the
// float entry points convert, the _f64 ones let the finite-difference tests see the exact
// derivative of the implemented function.
#include "matlaber/shade.h"
#include <math.h>
#include <omp.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/rng.h"
#include "render/shade_math.h"

#define PI 3.14159265358979323846

static double dot3(const double a[3], const double b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

// Checks the arguments and makes *L, the light with the split-sum table, for the shading loop.
static mlb_status check_args(const char* fn, int N, const mlb_envlight* light, const void* out, const void* kd, const void* ks,
                             const void* kr, const void* n, const void* v, sm_light* L) {
    if (N < 0) return mlb_fail(MLB_ERR_ARG, "%s: N = %d must be >= 0", fn, N);
    if (!light || !light->irr || light->n_levels < 3) return mlb_fail(MLB_ERR_ARG, "%s: the environment light is not built", fn);
    if (N > 0 && (!out || !kd || !ks || !kr || !n || !v)) return mlb_fail(MLB_ERR_ARG, "%s: NULL input or output buffer", fn);
    const float* lut = mlb_splitsum_lut();
    if (!lut) return mlb_fail_context(MLB_ERR_NOMEM, "%s", fn);
    *L = sm_light_of(light, lut);
    return MLB_OK;
}

mlb_status mlb_shade_forward(float* out, const float* kd, const float* ks, const float* kr, const float* n, const float* v, int N,
                             const mlb_envlight* light, mlb_fresnel fresnel) {
    sm_light L;
    MLB_TRY(check_args("mlb_shade_forward", N, light, out, kd, ks, kr, n, v, &L));
#pragma omp parallel for schedule(static) if (N > 256)
    for (int i = 0; i < N; i++) {
        double a[3], b[3], nn[3], vv[3], o[3];
        for (int k = 0; k < 3; k++) {
            a[k] = kd[3 * i + k], b[k] = ks[3 * i + k], nn[k] = n[3 * i + k], vv[k] = v[3 * i + k];
        }
        sm_shade_point(&L, fresnel == MLB_FRESNEL_PAPER, a, b, kr[i], nn, vv, o, NULL, NULL, NULL, NULL, NULL, NULL);
        for (int k = 0; k < 3; k++) out[3 * i + k] = (float)o[k];
    }
    return MLB_OK;
}

mlb_status mlb_shade_backward(float* dkd, float* dks, float* dkr, float* dn, float* dv, const float* dout, const float* kd,
                              const float* ks, const float* kr, const float* n, const float* v, int N, const mlb_envlight* light,
                              mlb_fresnel fresnel) {
    sm_light L;
    MLB_TRY(check_args("mlb_shade_backward", N, light, dout, kd, ks, kr, n, v, &L));
#pragma omp parallel for schedule(static) if (N > 256)
    for (int i = 0; i < N; i++) {
        double a[3], b[3], nn[3], vv[3], o[3], g[3];
        double ga[3] = {0, 0, 0}, gb[3] = {0, 0, 0}, gr = 0, gn[3] = {0, 0, 0}, gv[3] = {0, 0, 0};
        for (int k = 0; k < 3; k++) {
            a[k] = kd[3 * i + k], b[k] = ks[3 * i + k], nn[k] = n[3 * i + k], vv[k] = v[3 * i + k], g[k] = dout[3 * i + k];
        }
        sm_shade_point(&L, fresnel == MLB_FRESNEL_PAPER, a, b, kr[i], nn, vv, o, g, ga, gb, &gr, gn, gv);
        for (int k = 0; k < 3; k++) {
            if (dkd) dkd[3 * i + k] += (float)ga[k];
            if (dks) dks[3 * i + k] += (float)gb[k];
            if (dn) dn[3 * i + k] += (float)gn[k];
            if (dv) dv[3 * i + k] += (float)gv[k];
        }
        if (dkr) dkr[i] += (float)gr;
    }
    return MLB_OK;
}

mlb_status mlb_shade_forward_f64(double* out, const double* kd, const double* ks, const double* kr, const double* n,
                                 const double* v, int N, const mlb_envlight* light, mlb_fresnel fresnel) {
    sm_light L;
    MLB_TRY(check_args("mlb_shade_forward_f64", N, light, out, kd, ks, kr, n, v, &L));
#pragma omp parallel for schedule(static) if (N > 256)
    for (int i = 0; i < N; i++)
        sm_shade_point(&L, fresnel == MLB_FRESNEL_PAPER, kd + 3 * i, ks + 3 * i, kr[i], n + 3 * i, v + 3 * i, out + 3 * i, NULL, NULL, NULL, NULL,
                    NULL, NULL);
    return MLB_OK;
}

mlb_status mlb_shade_backward_f64(double* dkd, double* dks, double* dkr, double* dn, double* dv, const double* dout,
                                  const double* kd, const double* ks, const double* kr, const double* n, const double* v, int N,
                                  const mlb_envlight* light, mlb_fresnel fresnel) {
    sm_light L;
    MLB_TRY(check_args("mlb_shade_backward_f64", N, light, dout, kd, ks, kr, n, v, &L));
#pragma omp parallel for schedule(static) if (N > 256)
    for (int i = 0; i < N; i++) {
        double o[3];
        sm_shade_point(&L, fresnel == MLB_FRESNEL_PAPER, kd + 3 * i, ks + 3 * i, kr[i], n + 3 * i, v + 3 * i, o, dout + 3 * i,
                    dkd ? dkd + 3 * i : NULL, dks ? dks + 3 * i : NULL, dkr ? dkr + i : NULL, dn ? dn + 3 * i : NULL,
                    dv ? dv + 3 * i : NULL);
    }
    return MLB_OK;
}

// ---------------------------------------------------------------- sRGB

void mlb_srgb_forward(float* out, const float* in, size_t n) {
#pragma omp parallel for schedule(static) if (n > 32768)
    for (size_t i = 0; i < n; i++) {
        float x = in[i];
        out[i] = x <= 0.0031308f ? 12.92f * x : 1.055f * powf(x, 1.0f / 2.4f) - 0.055f;
    }
}

void mlb_srgb_backward(float* din, const float* dout, const float* in, size_t n) {
#pragma omp parallel for schedule(static) if (n > 32768)
    for (size_t i = 0; i < n; i++) {
        float x = in[i];
        din[i] += dout[i] * (x <= 0.0031308f ? 12.92f : (1.055f / 2.4f) * powf(x, 1.0f / 2.4f - 1.0f));
    }
}

// ---------------------------------------------------------------- Monte-Carlo ground truth

static double ggx_d(double a2, double nh) {
    double d = nh * nh * (a2 - 1) + 1;
    return a2 / (PI * d * d);
}

static double smith_lambda(double a2, double c) {
    double c2 = c * c;
    return 0.5 * (sqrt(1 + a2 * (1 - c2) / c2) - 1);
}

// Orthonormal basis (t, b, n) around unit n (Duff et al. 2017).
static void basis(const double n[3], double t[3], double b[3]) {
    double s = n[2] >= 0 ? 1 : -1, a = -1 / (s + n[2]), c = n[0] * n[1] * a;
    t[0] = 1 + s * n[0] * n[0] * a, t[1] = s * c, t[2] = -s * n[0];
    b[0] = c, b[1] = s + n[1] * n[1] * a, b[2] = -n[1];
}

// A visible normal of GGX for view vl (local frame, z = normal) (Heitz 2018).
static void sample_vndf(const double vl[3], double alpha, double u1, double u2, double h[3]) {
    double vh[3] = {alpha * vl[0], alpha * vl[1], vl[2]};
    double len = sqrt(dot3(vh, vh));
    for (int k = 0; k < 3; k++) vh[k] /= len;
    double lsq = vh[0] * vh[0] + vh[1] * vh[1], t1[3] = {1, 0, 0};
    if (lsq > 0) t1[0] = -vh[1] / sqrt(lsq), t1[1] = vh[0] / sqrt(lsq);
    double t2[3] = {vh[1] * t1[2] - vh[2] * t1[1], vh[2] * t1[0] - vh[0] * t1[2], vh[0] * t1[1] - vh[1] * t1[0]};
    double r = sqrt(u1), phi = 2 * PI * u2, p1 = r * cos(phi), p2 = r * sin(phi), s = 0.5 * (1 + vh[2]);
    p2 = (1 - s) * sqrt(fmax(0, 1 - p1 * p1)) + s * p2;
    double p3 = sqrt(fmax(0, 1 - p1 * p1 - p2 * p2)), nh[3];
    for (int k = 0; k < 3; k++) nh[k] = p1 * t1[k] + p2 * t2[k] + p3 * vh[k];
    h[0] = alpha * nh[0], h[1] = alpha * nh[1], h[2] = fmax(1e-9, nh[2]);
    len = sqrt(dot3(h, h));
    for (int k = 0; k < 3; k++) h[k] /= len;
}

mlb_status mlb_shade_reference(double out[3], double stderr_out[3], const float k[7], const double n_in[3], const double v_in[3],
                               const mlb_envmap* env, const mlb_envmap_sampler* sampler, int n_samples, uint64_t seed,
                               uint64_t stream) {
    enum { BATCHES = 16 };
    if (!env || !env->data || !sampler || sampler->w != env->w || sampler->h != env->h)
        return mlb_fail(MLB_ERR_ARG, "mlb_shade_reference: the map and its sampler do not match");
    if (n_samples < BATCHES) return mlb_fail(MLB_ERR_ARG, "mlb_shade_reference: n_samples %d must be >= %d", n_samples, BATCHES);
    double n[3], v[3], ln = sqrt(dot3(n_in, n_in)), lv = sqrt(dot3(v_in, v_in));
    for (int i = 0; i < 3; i++) n[i] = n_in[i] / ln, v[i] = v_in[i] / lv;
    double nv = dot3(n, v);
    if (!(nv > 0)) return mlb_fail(MLB_ERR_ARG, "mlb_shade_reference: n.v = %g, the point is not visible", nv);
    double t[3], b[3];
    basis(n, t, b);
    double vl[3] = {dot3(v, t), dot3(v, b), nv};
    double alpha = fmax(1e-3, (double)k[6] * k[6]), a2 = alpha * alpha;
    double g1v = 1 / (1 + smith_lambda(a2, nv));
    // each batch: q x q samples per strategy, one in each cell of a jittered grid over the first two
    // dimensions (stratification: the variance of a smooth integrand falls faster than 1/N)
    int q = (int)ceil(sqrt((double)((n_samples + BATCHES - 1) / BATCHES)));
    int m = q * q;
    double est[BATCHES][3];
#pragma omp parallel for schedule(static)
    for (int bt = 0; bt < BATCHES; bt++) {
        double acc[3] = {0, 0, 0};
        for (int s = 0; s < 3; s++)
            for (int i = 0; i < m; i++) {
                mlb_u32x4 wd = mlb_rng_words(seed, stream, ((uint64_t)bt * m + i) * 3 + s);
                double u[4];
                for (int c = 0; c < 4; c++) u[c] = mlb_u32_to_unit(wd.v[c]);
                u[0] = (i % q + u[0]) / q, u[1] = (i / q + u[1]) / q;
                double l[3], loc[3];
                if (s == 0) {   // cosine
                    double r = sqrt(u[0]), ph = 2 * PI * u[1];
                    loc[0] = r * cos(ph), loc[1] = r * sin(ph), loc[2] = sqrt(fmax(0, 1 - u[0]));
                } else if (s == 1) {   // GGX visible normals
                    double h[3];
                    sample_vndf(vl, alpha, u[0], u[1], h);
                    double vh = dot3(vl, h);
                    for (int c = 0; c < 3; c++) loc[c] = 2 * vh * h[c] - vl[c];
                }
                if (s < 2)
                    for (int c = 0; c < 3; c++) l[c] = loc[0] * t[c] + loc[1] * b[c] + loc[2] * n[c];
                else
                    mlb_envmap_sampler_sample(sampler, env, u, l);
                double nl = dot3(n, l);
                if (nl <= 0) continue;
                double h[3] = {v[0] + l[0], v[1] + l[1], v[2] + l[2]}, hl = sqrt(dot3(h, h));
                for (int c = 0; c < 3; c++) h[c] /= hl;
                double nh = dot3(n, h), vh = dot3(v, h);
                double D = ggx_d(a2, nh);
                double G2 = 1 / (1 + smith_lambda(a2, nv) + smith_lambda(a2, nl));
                double pc = nl / PI, pg = vh > 0 && nh > 0 ? g1v * D / (4 * nv) : 0;
                double pe = mlb_envmap_sampler_pdf(sampler, env, l);
                double Le[3];
                mlb_envmap_lookup(env, l, Le);
                double fc = pow(1 - fmax(0, vh), 5);
                for (int c = 0; c < 3; c++) {
                    double F = k[3 + c] + (1 - k[3 + c]) * fc;
                    double f = k[c] / PI + D * G2 * F / (4 * nv * nl);
                    acc[c] += f * Le[c] * nl / (pc + pg + pe);
                }
            }
        for (int c = 0; c < 3; c++) est[bt][c] = acc[c] / m;
    }
    for (int c = 0; c < 3; c++) {
        double mean = 0, var = 0;
        for (int bt = 0; bt < BATCHES; bt++) mean += est[bt][c];
        mean /= BATCHES;
        for (int bt = 0; bt < BATCHES; bt++) var += (est[bt][c] - mean) * (est[bt][c] - mean);
        out[c] = mean;
        if (stderr_out) stderr_out[c] = sqrt(var / (BATCHES - 1) / BATCHES);
    }
    return MLB_OK;
}

// ---- view directions: how the shading depends on the surface position --------------------------
// v = (eye - p) / r, r = |eye - p|;  dv/dp = -(I - v v^T) / r, so dp += -(dv - v (v . dv)) / r.
static void view_point(const double p[3], const double eye[3], double v[3], double* r) {
    double d[3] = {eye[0] - p[0], eye[1] - p[1], eye[2] - p[2]};
    *r = sqrt(dot3(d, d));
    double inv = *r > 0 ? 1.0 / *r : 0;
    for (int c = 0; c < 3; c++) v[c] = d[c] * inv;
}

static void view_point_backward(const double p[3], const double eye[3], const double dv[3], double dp[3]) {
    double v[3], r;
    view_point(p, eye, v, &r);
    if (!(r > 0)) { dp[0] = dp[1] = dp[2] = 0; return; }
    double vd = dot3(v, dv);
    for (int c = 0; c < 3; c++) dp[c] = -(dv[c] - v[c] * vd) / r;
}

void mlb_view_dirs(float* v, const float* p, const double eye[3], int N) {
    for (int i = 0; i < N; i++) {
        double pp[3] = {p[3 * i], p[3 * i + 1], p[3 * i + 2]}, vv[3], r;
        view_point(pp, eye, vv, &r);
        for (int c = 0; c < 3; c++) v[3 * i + c] = (float)vv[c];
    }
}

void mlb_view_dirs_backward(float* dp, const float* dv, const float* p, const double eye[3], int N) {
    for (int i = 0; i < N; i++) {
        double pp[3] = {p[3 * i], p[3 * i + 1], p[3 * i + 2]}, d[3] = {dv[3 * i], dv[3 * i + 1], dv[3 * i + 2]}, g[3];
        view_point_backward(pp, eye, d, g);
        for (int c = 0; c < 3; c++) dp[3 * i + c] += (float)g[c];
    }
}

void mlb_view_dirs_f64(double* v, const double* p, const double eye[3], int N) {
    for (int i = 0; i < N; i++) { double r; view_point(p + 3 * i, eye, v + 3 * i, &r); }
}

void mlb_view_dirs_backward_f64(double* dp, const double* dv, const double* p, const double eye[3], int N) {
    for (int i = 0; i < N; i++) {
        double g[3];
        view_point_backward(p + 3 * i, eye, dv + 3 * i, g);
        for (int c = 0; c < 3; c++) dp[3 * i + c] += g[c];
    }
}
