// Split-sum shading of the 7-d BRDF under a pre-integrated environment light (MATLABER §3.4,
// reference.md §2), its backward, linear -> sRGB, and a brute-force Monte-Carlo ground truth.
//
//   L = kd * Irradiance(n) + (F * B0(n.v, kr) + B1(n.v, kr)) * Prefiltered(reflect(v, n), kr)
//   reflect(v, n) = 2 (n.v) n - v                          (the mirror direction of the view vector)
//   F = F0 + (max(1 - kr, F0) - F0) (1 - n.v)^5            (the paper's roughness-aware Fresnel)
// with F0 = ks per channel, v the unit direction from the surface to the camera, n the unit
// normal, n.v clamped to [1e-4, 1] in the LUT and the Fresnel term. Conventions: docs/lighting.md.
#ifndef MATLABER_SHADE_H
#define MATLABER_SHADE_H
#include <stddef.h>
#include <stdint.h>
#include <math.h>
#include "matlaber/envmap.h"
#include "matlaber/error.h"

// ---- the split-sum LUT ----
// 256 x 256 x 2 floats, [row = roughness kr][col = n.v][B0, B1], texel centres (i + 0.5) / 256:
// the directional albedo of GGX (alpha = kr^2, height-correlated Smith G) split into the parts
// multiplying F0 and 1 under Schlick's Fresnel F0 + (1 - F0)(1 - v.h)^5.
#define MLB_LUT_SIZE 256
// The table, computed on first use (thread-safe, once per process, ~0.3 s on 2 cores); NULL when
// allocation failed (message set). Never freed.
const float* mlb_splitsum_lut(void);
// Computes the table into out[256 * 256 * 2] (always, no cache).
mlb_status mlb_splitsum_lut_compute(float* out);
// One entry at any (n.v, roughness) by the same quadrature: B0 and B1.
void mlb_splitsum_integrate(double nv, double roughness, double* b0, double* b1);
// Bilinear lookup (clamped to the texel centres at the borders), n.v clamped to >= 1e-4; optional
// derivatives of (B0, B1) with respect to n.v and to roughness (0 where clamped).
void mlb_splitsum_lookup(const float* lut, double nv, double roughness, double b[2], double db_dnv[2], double db_dr[2]);

// ---- shading ----
typedef enum {
    MLB_FRESNEL_PAPER = 0,    // F = F0 + (max(1 - kr, F0) - F0)(1 - n.v)^5 multiplies B0 (MATLABER)
    MLB_FRESNEL_SCHLICK = 1,  // F = F0 multiplies B0 (nvdiffrec; the split sum of Schlick's Fresnel)
} mlb_fresnel;

// N points. kd, ks, n, v: [N, 3]; kr: [N]; out: [N, 3] linear radiance. n and v are used as given
// (unit vectors expected; the gradients below are the partial derivatives of the formula as
// written, so a caller that normalises upstream backpropagates through its normalisation).
// Parallel over points (OpenMP), deterministic.
mlb_status mlb_shade_forward(float* out, const float* kd, const float* ks, const float* kr, const float* n, const float* v, int N,
                             const mlb_envlight* light, mlb_fresnel fresnel);
// Accumulates (+=) dL/dkd [N,3], dL/dks [N,3], dL/dkr [N], dL/dn [N,3], dL/dv [N,3] from dout [N,3];
// any gradient may be NULL. Recomputes the lookups instead of caching them (they cost less than
// storing the ~20 intermediate values a point would need).
mlb_status mlb_shade_backward(float* dkd, float* dks, float* dkr, float* dn, float* dv, const float* dout, const float* kd,
                              const float* ks, const float* kr, const float* n, const float* v, int N, const mlb_envlight* light,
                              mlb_fresnel fresnel);
// The same in double precision end to end (the texels stay float): the finite-difference tests.
mlb_status mlb_shade_forward_f64(double* out, const double* kd, const double* ks, const double* kr, const double* n,
                                 const double* v, int N, const mlb_envlight* light, mlb_fresnel fresnel);
mlb_status mlb_shade_backward_f64(double* dkd, double* dks, double* dkr, double* dn, double* dv, const double* dout,
                                  const double* kd, const double* ks, const double* kr, const double* n, const double* v, int N,
                                  const mlb_envlight* light, mlb_fresnel fresnel);

// ---- linear -> sRGB ----
// out = x <= 0.0031308 ? 12.92 x : 1.055 x^(1/2.4) - 0.055 (no clamping; out may alias in);
// backward: din += dout * d out / d x.
// View directions v = (eye - p) / |eye - p| for N surface points p [N,3], and the backward that
// turns the shading's dv into the gradient to the positions (accumulated): the split sum depends
// on position only through v.
void mlb_view_dirs(float* v, const float* p, const double eye[3], int N);
void mlb_view_dirs_backward(float* dp, const float* dv, const float* p, const double eye[3], int N);
void mlb_view_dirs_f64(double* v, const double* p, const double eye[3], int N);
void mlb_view_dirs_backward_f64(double* dp, const double* dv, const double* p, const double eye[3], int N);
void mlb_srgb_forward(float* out, const float* in, size_t n);
// One linear value clamped to [0, 1], then encoded (what an 8-bit sRGB image shows).
static inline float mlb_srgb_encode(float x) {
    x = x < 0 ? 0 : x > 1 ? 1 : x;
    return x <= 0.0031308f ? 12.92f * x : 1.055f * powf(x, 1.0f / 2.4f) - 0.055f;
}
void mlb_srgb_backward(float* din, const float* dout, const float* in, size_t n);

// ---- Monte-Carlo ground truth ----
// Radiance leaving a surface point towards v, by brute-force integration of the rendering
// equation over the lat-long map itself (bilinear, rotation applied; no prefiltering, no LUT):
//   L = integral over n.l > 0 of (kd / pi + D G2 F / (4 n.v n.l)) L_env(l) n.l dl
// with GGX D (alpha = kr^2), height-correlated Smith G2 and Schlick's Fresnel
// F = F0 + (1 - F0)(1 - v.h)^5, F0 = ks (the physically based reference; see docs/lighting.md).
// At least n_samples directions from each of three strategies (cosine, GGX visible normals, the
// map's luminance), combined with the balance heuristic; 16 independent batches, each stratified
// on a jittered q x q grid (q = ceil(sqrt(n_samples / 16))); Philox (seed, stream). stderr_out (may
// be NULL) is the standard error from the spread of the batches. n.v must be > 0.
mlb_status mlb_shade_reference(double out[3], double stderr_out[3], const float k[7], const double n[3], const double v[3],
                               const mlb_envmap* env, const mlb_envmap_sampler* sampler, int n_samples, uint64_t seed,
                               uint64_t stream);

#endif
