// Meshes and helpers shared by tests/test_raster*.c (header-only, static functions).
#ifndef MATLABER_RASTER_TEST_UTIL_H
#define MATLABER_RASTER_TEST_UTIL_H
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include "matlaber/raster.h"
#include "matlaber/rng.h"

// A closed sphere-like mesh: rings of n_lon vertices at n_lat - 1 latitudes plus two poles,
// radius 1 + amp · (a sum of sines), faces counter-clockwise seen from outside. 2 n_lon (n_lat - 1)
// faces. pos [V,3] double; returns V, sets *faces (malloc) and *n_faces.
static inline int rt_sphere(double** pos_out, int32_t** faces_out, int* n_faces, int n_lat, int n_lon, double amp) {
    int V = n_lon * (n_lat - 1) + 2, F = 2 * n_lon * (n_lat - 1);
    double* pos = malloc(sizeof(double) * 3 * V);
    int32_t* f = malloc(sizeof(int32_t) * 3 * F);
    for (int i = 1; i < n_lat; i++)
        for (int j = 0; j < n_lon; j++) {
            double th = M_PI * i / n_lat, ph = 2 * M_PI * j / n_lon;
            double r = 1 + amp * (sin(5 * th + 1.3) * sin(4 * ph) + 0.5 * sin(11 * th) * cos(7 * ph + 0.4));
            double* p = pos + 3 * ((i - 1) * n_lon + j);
            p[0] = r * sin(th) * sin(ph); p[1] = r * cos(th); p[2] = r * sin(th) * cos(ph);
        }
    int top = V - 2, bot = V - 1;
    pos[3 * top] = 0; pos[3 * top + 1] = 1; pos[3 * top + 2] = 0;
    pos[3 * bot] = 0; pos[3 * bot + 1] = -1; pos[3 * bot + 2] = 0;
    int k = 0;
#define RT_V(i, j) ((i) - 1) * n_lon + ((j) % n_lon)
    for (int j = 0; j < n_lon; j++) {
        f[3 * k] = top; f[3 * k + 1] = RT_V(1, j); f[3 * k + 2] = RT_V(1, j + 1); k++;
        f[3 * k] = bot; f[3 * k + 1] = RT_V(n_lat - 1, j + 1); f[3 * k + 2] = RT_V(n_lat - 1, j); k++;
    }
    for (int i = 1; i < n_lat - 1; i++)
        for (int j = 0; j < n_lon; j++) {
            int a = RT_V(i, j), b = RT_V(i, j + 1), c = RT_V(i + 1, j), d = RT_V(i + 1, j + 1);
            f[3 * k] = a; f[3 * k + 1] = c; f[3 * k + 2] = d; k++;   // oriented below
            f[3 * k] = a; f[3 * k + 1] = d; f[3 * k + 2] = b; k++;
        }
#undef RT_V
    // Make every face counter-clockwise seen from outside (normal along the centroid direction).
    for (int t = 0; t < F; t++) {
        const double *p0 = pos + 3 * f[3 * t], *p1 = pos + 3 * f[3 * t + 1], *p2 = pos + 3 * f[3 * t + 2];
        double e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]}, e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
        double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        double c[3] = {p0[0] + p1[0] + p2[0], p0[1] + p1[1] + p2[1], p0[2] + p1[2] + p2[2]};
        if (n[0] * c[0] + n[1] * c[1] + n[2] * c[2] < 0) { int32_t tmp = f[3 * t + 1]; f[3 * t + 1] = f[3 * t + 2]; f[3 * t + 2] = tmp; }
    }
    *pos_out = pos;
    *faces_out = f;
    *n_faces = F;
    return V;
}

// clip [V,4] = view_proj · [pos, 1] in double.
static inline double* rt_project(const double* pos, int V, const mlb_mat4* m) {
    double* clip = malloc(sizeof(double) * 4 * (V ? V : 1));
    mlb_transform_points_f64(clip, pos, V, m);
    return clip;
}

static inline float* rt_to_float(const double* x, size_t n) {
    float* r = malloc(sizeof(float) * (n ? n : 1));
    for (size_t i = 0; i < n; i++) r[i] = (float)x[i];
    return r;
}

// Clip coordinates (w = 1, z = zval) of a point given in pixel coordinates (x right, y down).
static inline void rt_pixel_to_clip(double* c, double px, double py, int H, int W, double zval) {
    c[0] = px / W * 2 - 1;
    c[1] = 1 - py / H * 2;
    c[2] = zval;
    c[3] = 1;
}

#endif
