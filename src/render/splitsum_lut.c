// The split-sum LUT (reference.md §2): for n.v and roughness kr (alpha = kr^2),
//   B0 = integral of (1 - (1 - v.h)^5) G2 (v.h) / ((n.h)(n.v)) over half vectors h ~ D(h)(n.h),
//   B1 = integral of      (1 - v.h)^5  G2 (v.h) / ((n.h)(n.v)),
// restricted to n.l > 0 (l = reflect(-v, h)); G2 = 1 / (1 + Lambda(n.v) + Lambda(n.l)) is the
// height-correlated Smith term. F0 B0 + B1 is then the directional albedo of GGX with Schlick's
// Fresnel.
//
// Deterministic quadrature instead of Monte Carlo, because the integrand is smooth once its one
// kink (n.l = 0) is a limit of integration:
//  - over the azimuth phi of h (0..pi, the integrand is symmetric about the plane of n and v)
//    the midpoint rule, spectrally accurate for smooth periodic integrands; at grazing n.v the
//    inner integral changes quickly near phi = pi/2 (width ~ n.v / sin), so the points are
//    warped there: phi = x + (beta/2) sin 2x, beta = 1 - min(1, 4 n.v / sin);
//  - over the polar angle of h, up to the horizon of l at that phi
//    (n.l = sin(theta_v) cos(phi) sin(2 theta_h) + cos(theta_v) cos(2 theta_h) > 0), Gauss-Legendre
//    in s = -ln(1 - u), u = the GGX CDF of the projected NDF (u = tan^2 / (alpha^2 + tan^2)):
//    the measure becomes e^-s ds and cos^2 theta_h = 1 / (alpha^2 e^s + 1 - alpha^2), resolving
//    both the lobe and its heavy tail for every alpha.
// 24 x 16 points per texel agree with a 64 x 256 reference to 3.2e-4 everywhere (worst at
// n.v < 0.01) and to < 1e-5 for n.v > 0.3; docs/lighting.md.
#include "matlaber/shade.h"
#include <math.h>
#include <omp.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include "render/shade_math.h"

#define PI 3.14159265358979323846
enum { N_THETA = 24, N_PHI = 16 };
#define S_MAX 18.0   // e^-18 = 1.5e-8 of the NDF mass lies beyond

static double gl_x[N_THETA], gl_w[N_THETA];   // Gauss-Legendre on [0, 1]
static pthread_once_t gl_once = PTHREAD_ONCE_INIT;

// The Legendre polynomial P_n(x) (*p, by the three-term recurrence) and its derivative (returned).
static double legendre(int n, double x, double* p) {
    double p0 = 1, p1 = x;
    for (int k = 2; k <= n; k++) {
        double p2 = ((2 * k - 1) * x * p1 - (k - 1) * p0) / k;
        p0 = p1;
        p1 = p2;
    }
    *p = p1;
    return n * (x * p1 - p0) / (x * x - 1);
}

static void gauss_legendre_init(void) {
    const int n = N_THETA;
    for (int i = 0; i < n; i++) {
        double x = cos(PI * (i + 0.75) / (n + 0.5)), p;
        for (int it = 0; it < 100; it++) {   // Newton on P_n's root
            double dp = legendre(n, x, &p);
            double dx = p / dp;
            x -= dx;
            if (fabs(dx) < 1e-15) break;
        }
        double dp = legendre(n, x, &p);
        gl_x[i] = 0.5 * (1 - x);
        gl_w[i] = 1.0 / ((1 - x * x) * dp * dp);   // = (Legendre weight) / 2
    }
}

static double smith_lambda(double a2, double c) {
    double c2 = c * c;
    return 0.5 * (sqrt(1 + a2 * (1 - c2) / c2) - 1);
}

void mlb_splitsum_integrate(double nv, double roughness, double* b0, double* b1) {
    pthread_once(&gl_once, gauss_legendre_init);
    if (nv < 1e-6) nv = 1e-6;
    if (nv > 1) nv = 1;
    double a = roughness * roughness, a2 = a * a;
    double cv = nv, sv = sqrt(1 - nv * nv);
    double lv = smith_lambda(a2, cv);
    double beta = sv > 0 ? 1 - fmin(1.0, 4 * cv / sv) : 0;
    double s0 = 0, s1 = 0;
    for (int j = 0; j < N_PHI; j++) {
        double x = PI * (j + 0.5) / N_PHI;
        double phi = x + 0.5 * beta * sin(2 * x), jac = 1 + beta * cos(2 * x);
        double cp = cos(phi);
        // horizon of l at this phi: theta_h < (atan2(sv cos phi, cv) + pi/2) / 2
        double thmax = 0.5 * (atan2(sv * cp, cv) + PI / 2);
        double smax = S_MAX;
        if (thmax < PI / 2 - 1e-9) {
            double tm = tan(thmax);
            smax = a2 > 0 ? fmin(S_MAX, log1p(tm * tm / a2)) : S_MAX;
        }
        double i0 = 0, i1 = 0;
        for (int i = 0; i < N_THETA; i++) {
            double s = smax * gl_x[i], es = exp(s);
            double c2 = 1 / (a2 * es + 1 - a2), ch = sqrt(c2), sh = sqrt(fmax(0, 1 - c2));
            double hx = sh * cp, hz = ch;
            double vh = sv * hx + cv * hz;
            if (vh <= 0) continue;
            double nl = 2 * vh * hz - cv;
            if (nl <= 0) continue;
            double g = 1 / (1 + lv + smith_lambda(a2, nl));
            double wgt = g * vh / (hz * cv) * gl_w[i] * smax / es;
            double fc = 1 - vh, fc5 = fc * fc * fc * fc * fc;
            i0 += wgt * (1 - fc5);
            i1 += wgt * fc5;
        }
        s0 += i0 * jac;
        s1 += i1 * jac;
    }
    *b0 = s0 / N_PHI;
    *b1 = s1 / N_PHI;
}

mlb_status mlb_splitsum_lut_compute(float* out) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "mlb_splitsum_lut_compute: NULL output");
    pthread_once(&gl_once, gauss_legendre_init);
#pragma omp parallel for schedule(dynamic, 4)
    for (int row = 0; row < MLB_LUT_SIZE; row++)
        for (int col = 0; col < MLB_LUT_SIZE; col++) {
            double b0, b1;
            mlb_splitsum_integrate((col + 0.5) / MLB_LUT_SIZE, (row + 0.5) / MLB_LUT_SIZE, &b0, &b1);
            out[((size_t)row * MLB_LUT_SIZE + col) * 2] = (float)b0;
            out[((size_t)row * MLB_LUT_SIZE + col) * 2 + 1] = (float)b1;
        }
    return MLB_OK;
}

static float* lut_table;
static pthread_once_t lut_once = PTHREAD_ONCE_INIT;

static void lut_init(void) {
    float* t = malloc((size_t)MLB_LUT_SIZE * MLB_LUT_SIZE * 2 * sizeof *t);
    if (t && mlb_splitsum_lut_compute(t) != MLB_OK) {
        free(t);
        t = NULL;
    }
    lut_table = t;
}

const float* mlb_splitsum_lut(void) {
    pthread_once(&lut_once, lut_init);
    if (!lut_table) mlb_fail(MLB_ERR_NOMEM, "split-sum LUT: cannot allocate 512 KiB");
    return lut_table;
}

void mlb_splitsum_lookup(const float* lut, double nv, double roughness, double b[2], double db_dnv[2], double db_dr[2]) {
    sm_splitsum_lookup(lut, nv, roughness, b, db_dnv, db_dr);
}
