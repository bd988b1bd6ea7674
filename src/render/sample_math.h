// The per-sample maths of the appearance renderer, written once for both devices (core/hd.h): the
// surface point, eye-facing unit normal and unit view direction of an interpolated pixel, and the
// clamped linear -> sRGB curve with its derivative. The geometry is computed in double on both.
// The includer picks the scalar: define MLB_SAMPLE_DOUBLE first for double (default float).
#ifndef MATLABER_SAMPLE_MATH_H
#define MATLABER_SAMPLE_MATH_H
#include <math.h>
#include "core/hd.h"
#ifdef MLB_SAMPLE_DOUBLE
typedef double sample_real;
#define SAMPLE_POW pow
#else
typedef float sample_real;
#define SAMPLE_POW powf
#endif

// a = (position, normal) interpolated at a covered pixel; eye the camera's position. Writes the
// point p, the unit normal turned towards the eye (two-sided shading) and the unit direction v to
// the eye. A degenerate normal takes the view direction; a point at the eye looks along +z.
MLB_HD void sample_geometry(const sample_real* a, double ex, double ey, double ez, sample_real* p, sample_real* nrm,
                            sample_real* v) {
    double eye[3] = {ex, ey, ez}, vv[3], nn[3], lv = 0, ln = 0, dot = 0;
    for (int c = 0; c < 3; c++) {
        vv[c] = eye[c] - (double)a[c];
        nn[c] = (double)a[3 + c];
        lv += vv[c] * vv[c];
        ln += nn[c] * nn[c];
    }
    lv = sqrt(lv);
    ln = sqrt(ln);
    if (!(lv > 0) || !(ln > 0)) { nn[0] = vv[0]; nn[1] = vv[1]; nn[2] = vv[2]; ln = lv; }
    if (!(lv > 0)) { lv = ln = 1; vv[0] = nn[0] = 0; vv[1] = nn[1] = 0; vv[2] = nn[2] = 1; }
    for (int c = 0; c < 3; c++) { vv[c] /= lv; nn[c] /= ln; dot += vv[c] * nn[c]; }
    double flip = dot < 0 ? -1 : 1;
    for (int c = 0; c < 3; c++) {
        p[c] = a[c];
        nrm[c] = (sample_real)(flip * nn[c]);
        v[c] = (sample_real)vv[c];
    }
}

// linear -> sRGB with the clamp to [0, 1] (NaN -> 0), and its derivative (0 where clamped)
MLB_HD sample_real srgb_clamped(sample_real x) {
    if (!(x > 0)) return 0;
    if (x >= 1) return 1;
    return x <= (sample_real)0.0031308 ? (sample_real)12.92 * x
                                       : (sample_real)1.055 * SAMPLE_POW(x, (sample_real)(1.0 / 2.4)) - (sample_real)0.055;
}
MLB_HD sample_real srgb_clamped_d(sample_real x) {
    if (!(x > 0) || x >= 1) return 0;
    return x <= (sample_real)0.0031308 ? (sample_real)12.92
                                       : (sample_real)(1.055 / 2.4) * SAMPLE_POW(x, (sample_real)(1.0 / 2.4 - 1.0));
}
#endif
