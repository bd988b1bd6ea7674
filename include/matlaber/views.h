// Multi-view image data sets (docs/views.md): a folder DIR holding DIR/cameras.json and, per view,
// an RGBA image (sRGB colour, alpha = mask), an optional normal map, a camera and the environment
// light it was taken under. The image guidance (guidance_image.h) fits a shape and its materials
// to such a folder; `matlaber render --views-out DIR` writes one from a mesh.
//
// Loaded images are channels-last float [n, res, res, 4] with colour premultiplied by alpha, the
// layout of the guidance interface (guidance.h):
//   images  [n, res, res, 4] = [sRGB colour · α, α]        (sRGB as stored, not linearised)
//   normals [n, res, res, 4] = [normal · α, α]             (world space, (2·rgb − 1) of the file)
#ifndef MATLABER_VIEWS_H
#define MATLABER_VIEWS_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/envmap.h"
#include "matlaber/error.h"
#include "matlaber/mesh.h"
#include "matlaber/progress.h"
#include "matlaber/raster.h"
#include "matlaber/render.h"

#define MLB_VIEWS_FORMAT "matlaber-views"
#define MLB_VIEWS_VERSION 1
#define MLB_VIEWS_MAX_VIEWS 10000            // views in one file
#define MLB_VIEWS_MAX_ENVS 64                // environments in one file
#define MLB_VIEWS_MAX_SIZE 4096              // image width / height, and res
#define MLB_VIEWS_MAX_JSON ((size_t)8 << 20)    // bytes of cameras.json (~4x what 10000 views need)
#define MLB_VIEWS_MAX_BYTES ((size_t)8 << 30)   // bytes of the loaded float images (images + normals)
#define MLB_VIEWS_PATH_MAX 256               // bytes of a relative path (with the NUL)

// A view as the file describes it.
typedef struct {
    char image[MLB_VIEWS_PATH_MAX];    // RGBA PNG, relative to DIR (required)
    char normal[MLB_VIEWS_PATH_MAX];   // normal-map PNG relative to DIR, "" when none
    int orbit;                         // 1: orbit camera; 0: camera_to_world
    double azimuth_deg, elevation_deg, radius, target[3];   // orbit (raster.h: mlb_camera_orbit)
    double camera_to_world[16];        // row-major, OpenGL camera (x right, y up, looks down −z)
    double fovy_deg;                   // vertical field of view (0, 180)
    double near_z, far_z;              // optional in the file: default 0.1, 100
    int env;                           // index into the environment list, −1 when none
    double env_rotation_deg;           // rotation of that environment about +y (envmap.h)
} mlb_views_entry;

// An environment of the list: a built-in name, or a file relative to DIR with a radiance scale.
typedef struct {
    char name[64];                     // built-in ("sky", "overcast", "studio", "white") or ""
    char file[MLB_VIEWS_PATH_MAX];     // relative to DIR, or ""
    double scale;                      // radiance scale (file only; 1 for a built-in)
} mlb_views_env;

// The contents of cameras.json.
typedef struct {
    int n_views, n_envs;
    mlb_views_entry* views;   // [n_views]
    mlb_views_env* envs;      // [n_envs]
} mlb_views_meta;

// Parses and checks DIR/cameras.json (not the images): missing keys, wrong types, non-finite
// numbers, out-of-range values, paths that are absolute or leave DIR ("..") are errors naming the
// file and the JSON path: "DIR/cameras.json: views[3].fovy_deg: not a number".
mlb_status mlb_views_meta_read(mlb_views_meta* out, const char* dir);
// Writes DIR/cameras.json atomically (after the same checks the reader makes).
mlb_status mlb_views_meta_write(const char* dir, const mlb_views_meta* m);
void mlb_views_meta_free(mlb_views_meta* m);
// The camera of an entry (aspect 1). Orbit entries go through mlb_camera_orbit; camera_to_world
// entries must have an orthonormal rotation (within 1e-3) and last row (0, 0, 0, 1): the view
// matrix is its inverse, the eye its translation, the target the point 1 unit ahead, and the
// camera's azimuth / elevation / radius are those of the eye seen from the origin.
mlb_status mlb_views_entry_camera(mlb_camera* cam, const mlb_views_entry* e);

// A loaded data set.
typedef struct {
    int n, res;               // views, image size (square)
    int src_size;             // the files' image size
    int has_normals;          // every view has a normal map
    float* images;            // [n, res, res, 4] sRGB·α, α
    float* normals;           // [n, res, res, 4] normal·α, α; NULL unless has_normals
    mlb_camera* cams;         // [n]
    mlb_views_meta meta;      // the file's entries and environment list
    char dir[4096];
} mlb_views;

// Loads DIR: cameras.json, then every image, resampled to res × res (res 0: the files' size) —
// a box filter when the file is an integer multiple of res, bilinear otherwise (pixel centres
// aligned, edges clamped), both on premultiplied values. Images must be square and all the same
// size; a normal map, when a view has one, the size of its image; either every view has a normal
// map or none. Errors name the file.
mlb_status mlb_views_load(mlb_views* out, const char* dir, int res);
void mlb_views_free(mlb_views* v);
// Opens environment i of the list (a built-in at `height` rows, 0 = default; a file relative to
// the data set's folder, times its scale).
mlb_status mlb_views_open_env(const mlb_views* v, int i, mlb_envmap* env, int height);
// out[res, res, c] from in[h, w, c] by the rule above (box for integer factors, else bilinear).
mlb_status mlb_views_resample(float* out, int res, const float* in, int w, int h, int c);

// ---- conversions between renders and stored images ----
// A linear render [n_pix, 4] (premultiplied linear colour over black, α) → the guidance's
// appearance target [sRGB(clamp(colour / α, 0, 1)) · α, α]; 0 where α = 0. out may alias rgba.
void mlb_views_linear_to_target(float* out, const float* rgba, size_t n_pix);
// out [height, width, 4] = the appearance target of a shaded render (render.h), the convention of
// the appearance renderer (appearance.h): mlb_render_shaded at width·s × height·s (s = p->supersample,
// black background, no supersampling inside), mlb_views_linear_to_target per fine pixel, then the
// s × s box filter of [sRGB·α, α]. p's background and supersample fields are overridden.
mlb_status mlb_views_render_target(const mlb_render_params* p, float* out);
// Writes a target image [h, w, 4] = [sRGB·α, α] as an 8-bit RGBA PNG: straight sRGB colour
// clamp(value / α, 0, 1) (written as is: it already is sRGB), α; atomically.
mlb_status mlb_views_write_color_png(const char* path, const float* rgba, int w, int h);
// Writes a [normal · α, α] image [h, w, 4] as a 16-bit RGBA PNG: rgb = (normal + 1) / 2, α.
mlb_status mlb_views_write_normal_png(const char* path, const float* nrm, int w, int h);

// ---- rendering a data set from a mesh ----
typedef struct {
    const mlb_mesh* mesh;       // placed in the unit sphere
    const float* k;             // per-vertex BRDF [V, 7], or NULL: k_const
    float k_const[7];
    int n_views;                // default 24
    int res;                    // image size, default 256
    int supersample;            // default 2
    int cube;                   // pre-integrated cube face size, default 512
    const char* const* envs;    // environment names (built-in) or files; n_envs >= 1
    int n_envs;
    float env_scale;            // radiance scale of file environments (default 1)
    double radius;              // camera distance, default 3
    double fovy_deg;            // default 40
    double el_min, el_max;      // elevation band in degrees, default −30, 75
    uint64_t seed;              // azimuth offset, environments, rotations; default 1
    int normals;                // 1 (default): write normal maps
    int fixed_rotation;         // 1: every environment unrotated (the single fixed light of the ablation)
    mlb_fresnel fresnel;        // default MLB_FRESNEL_PAPER
} mlb_views_render_config;

mlb_views_render_config mlb_views_render_default(void);
// The camera distribution of view i of n: a golden-angle (Fibonacci) spiral, equal-area in the
// elevation band: sin(el) = sin(el_min) + (i + 0.5)/n (sin(el_max) − sin(el_min)),
// az = offset + i · 137.5077…° (wrapped to [−180, 180)), offset = 360 U(seed, stream, 0);
// env = ⌊n_envs U⌋ and rotation = 360 U per view (Philox stream 0x71E5, index 1 + i; 0 with
// fixed_rotation).
void mlb_views_render_pose(const mlb_views_render_config* c, int i, double* az, double* el, int* env,
                           double* rotation_deg);
// Renders c->n_views views into DIR (created): view_XXX.png (mlb_views_render_target: split-sum
// shading under the view's rotated environment, sRGB, α = coverage), normal_XXX.png, the
// environment files copied into DIR, and cameras.json last. progress may be NULL.
mlb_status mlb_views_render(const char* dir, const mlb_views_render_config* c, mlb_progress* progress);

#endif
