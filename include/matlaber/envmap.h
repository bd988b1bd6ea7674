// Environment lighting (MATLABER §3.4, reference.md §2): lat-long HDR environment maps (files or
// built-in procedural skies), their rotation about the vertical axis, importance sampling for the
// Monte-Carlo ground truth, and the pre-integrated cube map the split-sum shading reads: a
// GGX-prefiltered specular mip chain and a diffuse irradiance cube, with seamless trilinear
// lookups that also return gradients. Conventions and numbers: docs/lighting.md.
//
// Directions are world-space, y up. A lat-long map stores radiance for direction v at
//   u = atan2(v.x, -v.z) / (2 pi) + 0.5,   t = acos(v.y) / pi
// (pixel centre (i + 0.5) / w, (j + 0.5) / h; row 0 looks straight up), bilinear, wrapping in u.
#ifndef MATLABER_ENVMAP_H
#define MATLABER_ENVMAP_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/error.h"

// ---- lat-long environment maps ----

// Largest map accepted (pixels): 16384 x 8192, the largest HDRIs in common use (1.6 GB as float RGB).
// Files whose header promises more are refused before anything is allocated.
#define MLB_ENVMAP_MAX_PIXELS ((size_t)16384 * 8192)

typedef struct {
    float* data;       // [h][w][3] linear RGB radiance, row 0 = up (+y); malloc'd
    int w, h;          // w == 2 h
    float rotation;    // radians about +y applied at lookup time (mlb_envmap_set_rotation)
    char name[64];     // built-in name or the file's base name
} mlb_envmap;          // zero-initialise; mlb_envmap_free releases

// What loading found and repaired, and the map's luminance (Rec. 709 weights 0.2126, 0.7152,
// 0.0722) after repair and scaling. mean_luminance is the plain mean over pixels;
// mean_luminance_sphere the solid-angle-weighted mean (the radiance averaged over directions).
typedef struct {
    size_t n_nonfinite;   // NaN / +-Inf samples, replaced by 0
    size_t n_negative;    // negative samples, clamped to 0
    float max_luminance, mean_luminance, mean_luminance_sphere;
} mlb_envmap_info;

// Loads a Radiance .hdr (RGBE, flat or new-style RLE) or OpenEXR file (recognised by content,
// not by name) and multiplies it by `scale` (finite, >= 0). Hostile input is an error naming the
// file: MLB_ERR_IO (missing, unreadable, a folder), MLB_ERR_UNSUPPORTED (neither format; XYZE or
// a flipped Radiance layout), MLB_ERR_FORMAT (corrupt or truncated data, zero size, not 2:1
// width:height), MLB_ERR_ARG (more than MLB_ENVMAP_MAX_PIXELS, bad scale). Repairs, counted in
// *info (may be NULL) and logged as one warning: NaN/Inf samples become 0, negative ones 0.
// An EXR's alpha channel is ignored; a one-channel EXR is used as grey.
mlb_status mlb_envmap_load(mlb_envmap* env, const char* path, float scale, mlb_envmap_info* info);

// Built-in procedural environments, `height` rows (width 2 height; 0 = 512), deterministic:
//   "sky"      clear sky (CIE clear-sky luminance, blue to white at the horizon) with a sun of
//              solid angle 6.8e-5 sr at 40 deg elevation; the sun gives 6/7 of the irradiance of
//              a horizontal plane (sun : sky = 6 : 1); ground of albedo 0.2 below the horizon
//   "overcast" CIE overcast sky, L(theta) = Lz (1 + 2 cos theta) / 3, ground of albedo 0.2
//   "studio"   dark room (0.03) with four soft-box area lights (key, fill, top, rim)
//   "white"    radiance 1 everywhere (the furnace test)
// The outdoor skies are normalised so that a white horizontal Lambertian surface has radiance 1
// (irradiance pi). Numbers and reasons: docs/lighting.md.
mlb_status mlb_envmap_named(mlb_envmap* env, const char* name, int height);
// A built-in name (tried first) or a file path; `height` applies to built-ins, `scale` to both.
// (A file that happens to be called "sky" is reached as "./sky".)
mlb_status mlb_envmap_open(mlb_envmap* env, const char* name_or_path, float scale, int height,
                           mlb_envmap_info* info);
int mlb_envmap_is_builtin(const char* name);
const char* mlb_envmap_builtin_list(void);   // "sky, overcast, studio, white"

// A map from memory (h rows of w RGB floats, copied); the same validation and repairs as loading.
mlb_status mlb_envmap_from_rgb(mlb_envmap* env, const float* rgb, int w, int h, const char* name,
                               mlb_envmap_info* info);
mlb_status mlb_envmap_scale(mlb_envmap* env, float scale);   // multiply radiance; scale finite >= 0
// Checks the invariants (2:1, allocated, every sample finite and >= 0); the message says which.
mlb_status mlb_envmap_validate(const mlb_envmap* env);
void mlb_envmap_stats(const mlb_envmap* env, mlb_envmap_info* info);   // fills the luminance fields
void mlb_envmap_free(mlb_envmap* env);

// Rotation about +y by `radians` (right-handed: +x turns towards -z), applied by rotating the lookup
// direction, never by rebuilding: the radiance arriving from world direction d is the stored map's
// radiance at R_y(-radians) d. Free; the appearance stage calls it every step.
void mlb_envmap_set_rotation(mlb_envmap* env, float radians);
// out = R_y(angle) in (out may alias in).
void mlb_rotate_y(double out[3], const double in[3], double angle);
void mlb_latlong_dir_to_uv(const double dir[3], double* u, double* t);   // the mapping above
void mlb_latlong_uv_to_dir(double u, double t, double dir[3]);
// Radiance from world direction `dir` (any length > 0): rotation, then bilinear lookup.
void mlb_envmap_lookup(const mlb_envmap* env, const double dir[3], double rgb[3]);

// ---- importance sampling of a lat-long map (the Monte-Carlo ground truth) ----
// Pixels are chosen with probability proportional to the largest luminance of their 3x3
// neighbourhood (which bounds the bilinear radiance inside the pixel) x sin(theta) (their share of
// the sphere), then a point uniformly inside the pixel in (u, t).
typedef struct {
    int w, h;
    double* row_cdf;    // [h + 1]
    double* col_cdf;    // [h][w + 1], each row normalised
    double* row_mass;   // [h]   unnormalised row weights
    double total;
} mlb_envmap_sampler;

mlb_status mlb_envmap_sampler_build(mlb_envmap_sampler* s, const mlb_envmap* env);
// Four uniforms in [0, 1) -> a world direction (env's rotation applied); returns its density
// with respect to solid angle (0 when the map is black there).
double mlb_envmap_sampler_sample(const mlb_envmap_sampler* s, const mlb_envmap* env, const double u[4],
                                 double dir[3]);
double mlb_envmap_sampler_pdf(const mlb_envmap_sampler* s, const mlb_envmap* env, const double dir[3]);
void mlb_envmap_sampler_free(mlb_envmap_sampler* s);

// ---- cube maps (reference.md §2) ----
// Faces 0..5 = +X, -X, +Y, -Y, +Z, -Z, each N x N texels stored [face][y][x][3]. Texel (x, y) of
// a face has f = 2 (x + 0.5) / N - 1 (same for y) and direction
//   +X (1, -fy, -fx)  -X (-1, -fy, fx)  +Y (fx, 1, fy)  -Y (fx, -1, -fy)  +Z (fx, -fy, 1)  -Z (-fx, -fy, -1)
// and "solid angle" (atan((x'+1)/H) - atan(x'/H)) (atan((y'+1)/H) - atan(y'/H)), H = N/2,
// x' = |x - H|, y' = |y - H| (nvdiffrec's texel weight. It is not the texel's solid angle: it sums
// to about 6 (pi/2)^2 instead of 4 pi, weighs face corners up to 1.3x too much, and on the low half
// of a face it is the weight of the next texel outwards. Every sum that uses it is normalised by the
// same sum over a constant map, which removes the first error but not the others; see
// mlb_envlight_options.reference_weights and docs/lighting.md.)
void mlb_cube_texel_dir(int face, double x, double y, int n, double dir[3]);   // unit; x, y texel coords
double mlb_cube_texel_solid_angle(int x, int y, int n);         // the formula above
double mlb_cube_texel_solid_angle_exact(int x, int y, int n);   // the true solid angle of the texel
// Face and continuous texel coordinates (centres at integers) of a direction.
void mlb_cube_dir_to_texel(const double dir[3], int n, int* face, double* x, double* y);
// Seamless bilinear lookup in one cube level: the 2x2 footprint continues onto the neighbouring
// face across an edge, and at a cube corner the missing fourth texel is the mean of the three
// that meet there. Optional Jacobian d rgb[c] / d dir[k] (dir need not be unit: the lookup is
// invariant to its length, so the Jacobian is orthogonal to dir).
void mlb_cube_sample(const float* cube, int n, const double dir[3], double rgb[3], double jac[3][3]);
// Base cube from a lat-long map: the bilinear lat-long value at each texel centre (averaged over
// s x s points inside the texel when the map is finer than the cube, so a small bright sun keeps
// its energy). The map's rotation is not baked in. cube: [6][n][n][3].
mlb_status mlb_cube_from_envmap(float* cube, int n, const mlb_envmap* env);

// ---- the pre-integrated environment light ----
#define MLB_CUBE_MAX_LEVELS 14
#define MLB_SPEC_MIN_ROUGHNESS 0.08f   // roughness of specular level 0 (= MLB_KR_MIN)
#define MLB_SPEC_MAX_ROUGHNESS 0.5f    // roughness of level L-2; the last level is at 1.0

typedef struct {
    int face_size;     // base face size (default 512); face_size = min_size * 2^k, k >= 2
    int min_size;      // smallest mip and the irradiance cube (default 16; even)
    float cutoff;      // the prefilter keeps the cone holding this fraction of the GGX weight (0.99)
    float accuracy;    // prefilter tree opening ratio (default 3; larger is slower and closer to exact)
    int exact;         // 1: sum every texel inside the cone at full resolution (slow; for tests)
    int reference_weights;   // 1: weigh texels by reference.md's (nvdiffrec's) formula instead of their
                             // true solid angle (default 0: true solid angle, 5-10x closer to the
                             // integral; docs/lighting.md)
} mlb_envlight_options;   // zero fields take the defaults

typedef struct {
    int n_levels;                              // L
    int size[MLB_CUBE_MAX_LEVELS];             // face size of each level
    float roughness[MLB_CUBE_MAX_LEVELS];      // roughness each level was prefiltered at
    float cone[MLB_CUBE_MAX_LEVELS];           // cut-off cone half-angle of each level (radians)
    float* spec[MLB_CUBE_MAX_LEVELS];          // [6][size][size][3] prefiltered radiance
    int irr_size;                              // = min_size
    float* irr;                                // [6][irr][irr][3] cosine-weighted mean radiance
    float rotation;                            // radians about +y (mlb_envlight_set_rotation)
    float rot_cached;                          // the angle rot_cos/rot_sin belong to (a lookup
    double rot_cos, rot_sin;                   // computes them itself when rotation differs)
} mlb_envlight;        // zero-initialise; mlb_envlight_free releases

// Builds the cube map (face_size), its 2x2-average mip chain down to min_size, prefilters level
// i < L-1 at roughness 0.08 + i/(L-2) (0.5 - 0.08) and the last at 1.0 (GGX, N = V = R, weights
// max(l.r, 0) D(r.h) Omega / 4 normalised by their sum, over the cone that holds `cutoff` of the
// weight), and the irradiance cube from the unfiltered min_size level (sum L max(n.l, 0) Omega
// normalised by sum max(n.l, 0) Omega, so a constant map gives exactly its radiance). Prefilter
// sums above 32^2 run over a quadtree cut (within ~0.5% of the exact sum, 17x faster at 512^2;
// `exact` for the brute-force sum). OpenMP over texels; each texel's sum runs in a fixed order,
// so the result does not depend on the thread count. Copies env->rotation. ~1.4 s at 512^2 on
// 2 cores.
mlb_status mlb_envlight_build(mlb_envlight* light, const mlb_envmap* env, const mlb_envlight_options* opt);
void mlb_envlight_free(mlb_envlight* light);
void mlb_envlight_set_rotation(mlb_envlight* light, float radians);   // as mlb_envmap_set_rotation
// Continuous mip level for a roughness (reference.md §2), and its derivative (0 where clamped).
double mlb_envlight_mip(const mlb_envlight* light, double roughness, double* dmip_dr);
// Prefiltered radiance around world direction `dir` for `roughness`: seamless bilinear in the two
// levels around mlb_envlight_mip, linear between them. Optional Jacobians d rgb / d dir
// ([channel][component]) and d rgb / d roughness.
void mlb_envlight_specular(const mlb_envlight* light, const double dir[3], double roughness, double rgb[3],
                           double jac_dir[3][3], double jac_r[3]);
// Diffuse irradiance (cosine-weighted mean radiance: Lambert radiance = kd * this) for normal n.
void mlb_envlight_diffuse(const mlb_envlight* light, const double n[3], double rgb[3], double jac_n[3][3]);

#endif
