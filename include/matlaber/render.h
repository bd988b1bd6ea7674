// Shaded rendering of a mesh with a 7-d BRDF under an environment light (paper §3.4): rasterize,
// interpolate position / normal / material, split-sum shading, background, antialias, supersample.
// The forward pass the render, relight and swatch commands use; the pipeline's differentiable
// version builds on the same pieces (raster.h, shade.h).
#ifndef MATLABER_RENDER_H
#define MATLABER_RENDER_H
#include "matlaber/envmap.h"
#include "matlaber/mesh.h"
#include "matlaber/raster.h"
#include "matlaber/shade.h"

typedef enum { MLB_BG_COLOR = 0, MLB_BG_ENV = 1 } mlb_background;

// The material at n points: pos [n,3] → k [n,7] = (kd rgb, ks rgb, roughness). E.g. a wrapper of
// mlb_material_eval(net, pos, n, k) with user = the net.
typedef mlb_status (*mlb_material_fn)(void* user, const float* pos, size_t n, float* k);

typedef struct {
    const mlb_mesh* mesh;          // normals are computed when the mesh has none
    const float* k;                // per-vertex BRDF [V,7] (kd rgb, ks rgb, kr), or NULL:
    float k_const[7];              //   one material for the whole mesh
    mlb_material_fn material;      // when set, the BRDF at each pixel's own surface point instead of
    void* material_user;           //   k / k_const: what a baked asset shows (a per-vertex BRDF blurs
                                   //   material edges into the triangles' sawtooth)
    const mlb_envlight* light;     // rotation already set
    const mlb_envmap* env;         // for MLB_BG_ENV (same rotation as the light)
    mlb_background background;
    float bg_color[3];             // linear RGB for MLB_BG_COLOR
    mlb_camera camera;
    int width, height;
    int supersample;               // render at s x the size and box-filter down (default 1)
    mlb_fresnel fresnel;
} mlb_render_params;

// out [height, width, 4]: linear RGB and coverage alpha (antialiased). Two-sided: a back face is
// shaded with its normal flipped toward the camera.
mlb_status mlb_render_shaded(const mlb_render_params* p, float* out);

#endif
