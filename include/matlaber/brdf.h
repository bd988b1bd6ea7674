// Materials and material data for the latent BRDF auto-encoder (MATLABER §3.3).
// A material sample is k = (kd rgb, ks rgb, kr): diffuse albedo, specular albedo F0 (both linear
// RGB) and perceptual roughness r (the renderer's GGX alpha is r^2). This header holds the
// conventions, a growable set of samples, the loaders for real SVBRDF maps and the built-in
// procedural distribution; the auto-encoder itself lives in brdf_ae.h. See docs/materials.md.
#ifndef MATLABER_BRDF_H
#define MATLABER_BRDF_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/error.h"

#define MLB_BRDF_DIM 7
#define MLB_KR_MIN 0.08f   // the renderer's minimum roughness (its specular mip chain starts there)

// ---- conventions ----
// Exact piecewise sRGB transfer functions (IEC 61966-2-1), for c in [0, 1].
float mlb_srgb_to_linear(float c);   // c <= 0.04045 ? c/12.92 : ((c+0.055)/1.055)^2.4
float mlb_linear_to_srgb(float c);   // c <= 0.0031308 ? 12.92c : 1.055 c^(1/2.4) - 0.055
// 1 when every value is finite, kd and ks lie in [0, 1] and kr in [MLB_KR_MIN, 1].
int mlb_brdf_valid(const float k[MLB_BRDF_DIM]);
// Moves k into the valid ranges (NaN becomes the lower bound); returns how many values changed.
int mlb_brdf_clamp(float k[MLB_BRDF_DIM]);

// ---- a set of samples: n rows of MLB_BRDF_DIM floats ----
typedef struct {
    size_t begin, count;   // rows [begin, begin + count) of the set
    char* name;            // where they came from (a folder, a file, "procedural seed=...")
} mlb_brdf_source;

typedef struct {
    float* k;                  // n rows of MLB_BRDF_DIM floats
    size_t n, capacity;        // rows used / allocated
    mlb_brdf_source* sources;  // optional provenance, one entry per loaded block
    size_t n_sources, cap_sources;
} mlb_brdf_set;                // zero-initialise before first use: mlb_brdf_set s = {0};

mlb_status mlb_brdf_set_reserve(mlb_brdf_set* s, size_t rows);   // capacity >= rows
// Appends `rows` rows copied from k (rows * MLB_BRDF_DIM floats).
mlb_status mlb_brdf_set_append(mlb_brdf_set* s, const float* k, size_t rows);
// Appends `rows` uninitialised rows and points *dst at the first, for filling in place.
mlb_status mlb_brdf_set_extend(mlb_brdf_set* s, size_t rows, float** dst);
// Records that rows [begin, s->n) came from `name` (copied).
mlb_status mlb_brdf_set_note_source(mlb_brdf_set* s, size_t begin, const char* name);
// The source name of a row, or NULL when none was recorded.
const char* mlb_brdf_set_source_of(const mlb_brdf_set* s, size_t row);
// Drops rows from `n` on (and the provenance entries that start there); used to undo a failed load.
void mlb_brdf_set_truncate(mlb_brdf_set* s, size_t n);
void mlb_brdf_set_free(mlb_brdf_set* s);   // back to all zeros

// ---- loaders for real SVBRDF maps ----
typedef struct {
    size_t max_pixels_per_map;  // 0: every (valid) pixel; else that many, uniformly without replacement
    uint64_t seed;              // drives the pixel choice: the i-th map found uses stream i
    float mask_threshold;       // a pixel is kept when mask > threshold; 0 (default) drops mask == 0 only
} mlb_brdf_load_options;        // NULL or zero-initialised = defaults

// `path` may be
//  (a) a TwoShotBRDF sample folder: diffuse.png, specular.png (sRGB), roughness.png (first channel,
//      linear), optional mask.png (first channel times alpha when present);
//  (b) a metallic/roughness texture folder: a base colour map (albedo / basecolor / base_color /
//      color / diffuse ..., .png/.jpg/.jpeg, sRGB), a roughness map, an optional metallic map
//      (absent: 0): kd = base(1-m), ks = 0.04(1-m) + base m, kr = roughness;
//  (c) an image of 4 square tiles left to right, normal | diffuse | roughness | specular
//      (Deschaintre et al.; diffuse and specular sRGB, roughness first channel linear);
//  (d) a folder holding any of these at any depth (names sorted bytewise, dot-files skipped).
// kr is clamped into [MLB_KR_MIN, 1]. Rows are appended to `out`; on failure `out` is left as it
// was and the message names the file. Finding nothing, or no valid pixel, is an error.
mlb_status mlb_brdf_load_path(mlb_brdf_set* out, const char* path, const mlb_brdf_load_options* opt);
// The individual layouts, for callers that know what they have (map_index picks the RNG stream).
mlb_status mlb_brdf_load_twoshot(mlb_brdf_set* out, const char* folder, const mlb_brdf_load_options* opt, uint64_t map_index);
mlb_status mlb_brdf_load_pbr(mlb_brdf_set* out, const char* folder, const mlb_brdf_load_options* opt, uint64_t map_index);
mlb_status mlb_brdf_load_tiles(mlb_brdf_set* out, const char* file, const mlb_brdf_load_options* opt, uint64_t map_index);

// ---- the built-in procedural distribution (default training data) ----
// Material classes and families of the generator; see docs/materials.md for the numbers.
typedef enum {
    MLB_MAT_DIELECTRIC = 0,   // F0 = ((n-1)/(n+1))^2 from a real refractive index, achromatic
    MLB_MAT_METAL = 1,        // F0 from measured complex indices (reference.md §1), kd ~ 0
    MLB_MAT_AUTHORED = 2,     // artist-style maps: specular level, partial metalness, baked cavity
    MLB_MAT_MIXED = 3,        // label only: a pixel blended from several materials or effects
} mlb_material_class;

typedef enum {
    MLB_FAM_GOLD, MLB_FAM_SILVER, MLB_FAM_COPPER, MLB_FAM_ALUMINIUM,
    MLB_FAM_IRON, MLB_FAM_CHROMIUM, MLB_FAM_NICKEL, MLB_FAM_TITANIUM,
    MLB_FAM_WOOD, MLB_FAM_STONE, MLB_FAM_POLISHED_STONE, MLB_FAM_CERAMIC, MLB_FAM_PAINT,
    MLB_FAM_PLASTIC, MLB_FAM_RUBBER, MLB_FAM_FABRIC, MLB_FAM_SKIN, MLB_FAM_LEAF, MLB_FAM_GLASS,
    MLB_FAM_GEM, MLB_FAM_WATER, MLB_FAM_BRIGHT, MLB_FAM_DARK, MLB_FAM_RUST, MLB_FAM_PATINA,
    MLB_FAM_AUTHORED,
    MLB_FAM_COUNT
} mlb_material_family;

const char* mlb_brdf_family_name(int family);    // "gold", ..., NULL when out of range
mlb_material_class mlb_brdf_family_class(int family);
// The measured F0 of a metal family (1) or 0 when `family` is not a metal.
int mlb_brdf_metal_f0(int family, float f0[3]);

// Appends n_samples rows drawn from the procedural distribution. Sample i is a pure function of
// (seed, i): the result does not depend on the thread count, and a shorter run is a prefix of a
// longer one with the same seed.
mlb_status mlb_brdf_procedural(mlb_brdf_set* out, size_t n_samples, uint64_t seed);
// The same rows plus, per row, its class (mlb_material_class; MIXED where no single material
// holds 99% of the pixel) and family (mlb_material_family of the dominant material); either
// array may be NULL.
mlb_status mlb_brdf_procedural_labeled(mlb_brdf_set* out, size_t n_samples, uint64_t seed, uint8_t* cls,
                                       uint8_t* family);

#endif
