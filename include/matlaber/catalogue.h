// A procedural catalogue of objects and materials whose truth is known (docs/catalogue.md): the
// training data of the project's own small diffusion model and a benchmark for text-to-3D.
//
// Classes: parametric triangle meshes whose shape parameters are drawn from a seed (seed 0 = the
// class's canonical shape, every parameter at the middle of its range). Materials: one 7-d BRDF
// (kd rgb, ks rgb, kr; linear, render.h) over the whole object. Some class x material combinations
// are held out of training (mlb_catalogue_held_out) to measure generalisation.
//
// Frame (the pipeline's generation frame, goblet.h): +y up; the mesh's bounding box is centred at
// the origin and its farthest vertex is at MLB_CATALOGUE_RADIUS (0.9) from it, so the object fills
// the unit sphere the geometry stage starts from. Faces are counter-clockwise seen from outside
// (every component is closed: positive signed volume); area-weighted vertex normals are set.
// Front: the orbit camera at azimuth 0 sits on +z looking towards −z (raster.h: mlb_camera_orbit),
// with +x on the right of its image. Non-symmetric classes are posed for that camera:
//   mug     handle on +x (right of the front view; the azimuth-90 camera sees it head-on)
//   teapot  spout on +x (right of the front view), handle on −x
//   table   long side along x (the front view sees the long side, azimuth 90 the short one)
//   stool   three legs, one pointing to the front (+z): the back view sees two legs in front
//   ring    a torus standing upright, its hole facing the front (axis z)
//
// Images of a render (the stages' own conventions, guidance.h and guidance_sds.c):
//   rgb    [3, res, res] planar, what the APPEARANCE stage hands Stable Diffusion: sRGB of the clamped
//          split-sum shading (shade.h) composited over black = [sRGB(clamp(L,0,1))·α] with α the
//          antialiased coverage (mlb_views_render_target; values in [0, 1]).
//   normal [res, res, 4] channels-last, what the GEOMETRY stage renders (mlb_geofit_render_mesh):
//          [n·α, α] with n the world-space interpolated area-weighted vertex normal (unit at the
//          vertices, not renormalised per pixel), α the antialiased coverage; 0 in the background.
//          The geometry stage's SDS input is then 0.5·(n·α + α) per channel (or the 64² area resize
//          of [n·α, α] in its latent phase).
#ifndef MATLABER_CATALOGUE_H
#define MATLABER_CATALOGUE_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/envmap.h"
#include "matlaber/error.h"
#include "matlaber/guidance.h"
#include "matlaber/mesh.h"

#define MLB_CATALOGUE_RADIUS 0.9f        // distance of the farthest vertex from the origin
#define MLB_CATALOGUE_SEGMENTS 48        // vertices around a lathe (tubes use fewer)
#define MLB_CATALOGUE_MAX_ENVS 8

// ---- classes ----
int mlb_catalogue_n_classes(void);
const char* mlb_catalogue_class_name(int c);        // "goblet", ...; NULL when out of range
int mlb_catalogue_class_symmetric(int c);           // 1: a surface of revolution about +y
// The axis (0 x, 2 z) whose mirror puts a non-symmetric class's one-sided part on the other side
// (the mug's handle, the teapot's spout and handle: x), the shape a two-faced (Janus) asset
// doubles; −1 when the mirror maps the class onto itself (symmetric classes, the table, the ring)
// or tells nothing (the stool: catalogue.c).
int mlb_catalogue_class_mirror_axis(int c);
mlb_status mlb_catalogue_class_parse(const char* name, int* c);   // MLB_ERR_ARG listing the names
const char* mlb_catalogue_class_list(void);          // "goblet, vase, ..."
// The mesh of class c with shape parameters drawn from seed (0: canonical). Deterministic.
mlb_status mlb_catalogue_mesh(int c, uint64_t seed, mlb_mesh* out);
// The same shapes by their parameters: each a fraction u in [0, 1] of its range (values outside
// are clamped), as many as mlb_catalogue_class_n_params(c) (at most MLB_CATALOGUE_MAX_PARAMS; 0
// when c is out of range). mlb_catalogue_seed_params writes the fractions seed draws and returns
// their count, so mlb_catalogue_mesh_params(c, u) is bitwise mlb_catalogue_mesh(c, seed). A fit
// of the class to a mesh (the text-to-3D benchmark's) searches over u.
#define MLB_CATALOGUE_MAX_PARAMS 8
int mlb_catalogue_class_n_params(int c);
int mlb_catalogue_seed_params(int c, uint64_t seed, float u[MLB_CATALOGUE_MAX_PARAMS]);
mlb_status mlb_catalogue_mesh_params(int c, const float* u, mlb_mesh* out);
// Named parts: the thin ones a generation may lose (goblet, mushroom and lamp stems, the lamp's
// shade, table and stool legs, mug and teapot handles, the teapot's spout, the ring's hole: the
// inner half of its tube). Part k of class c is 1..mlb_catalogue_class_n_parts(c) (at most
// MLB_CATALOGUE_MAX_PARTS); mlb_catalogue_mesh_parts is mlb_catalogue_mesh_params with each face's
// part (0: none) in *part ([n_faces], malloc'd: free() it).
#define MLB_CATALOGUE_MAX_PARTS 2
int mlb_catalogue_class_n_parts(int c);
const char* mlb_catalogue_part_name(int c, int k);   // NULL when out of range
mlb_status mlb_catalogue_mesh_parts(int c, const float* u, mlb_mesh* out, uint8_t** part);

// ---- materials ----
int mlb_catalogue_n_materials(void);
const char* mlb_catalogue_material_name(int m);     // "gold", ...; NULL when out of range
const float* mlb_catalogue_material_brdf(int m);    // 7 floats (kd rgb, ks rgb, kr), linear; NULL out of range
int mlb_catalogue_material_metal(int m);            // 1: metal (kd ~ 0, ks = F0 colour); 0: dielectric
mlb_status mlb_catalogue_material_parse(const char* name, int* m);
const char* mlb_catalogue_material_list(void);

// ---- held-out combinations ----
// 1 when (class c, material m) is held out of training. Each class holds out exactly one material,
// m = (3c + 1) mod n_materials, so every class keeps n_materials − 1 training materials and every
// material is held out for at most ceil(n_classes / n_materials) classes.
int mlb_catalogue_held_out(int c, int m);
int mlb_catalogue_n_held_out(void);

// ---- captions ----
// "a gold goblet" + mlb_sds_view_suffix(view) (sds.h: MLB_SDS_VIEW_NONE .. MLB_SDS_VIEW_OVERHEAD),
// the suffixes the SDS guidance appends. Truncated to cap (always terminated when cap > 0).
void mlb_catalogue_caption(int c, int m, int view, char* out, size_t cap);

// ---- samples and their renderer ----
typedef struct {
    int cls, mat;
    uint64_t shape_seed;      // 0: canonical shape
    mlb_view view;            // camera, azimuth, elevation, env (index into the renderer's pool), rotation
} mlb_catalogue_sample;

// Draws sample `index` of data set `seed`: a pure function of (seed, index, n_envs, allow_held_out)
// (Philox: the class x material pair uniform over the allowed pairs, a nonzero shape seed; the view
// is mlb_orbit_sample(mlb_orbit_default() with n_envs, seed, MLB_STAGE_APPEARANCE, step = index,
// view 0): exactly the pipeline's camera and light distribution). Parallel and resumable.
mlb_status mlb_catalogue_sample_draw(mlb_catalogue_sample* out, uint64_t seed, uint64_t index, int n_envs,
                                     int allow_held_out);
// The sample's caption with the view suffix the guidance would use (mlb_sds_view_for(az, el)).
void mlb_catalogue_sample_caption(const mlb_catalogue_sample* s, char* out, size_t cap);

typedef struct {
    int res;                 // image size (default 128)
    int supersample;         // render at res·s and box-filter (default 1, the pipeline's ss)
    const char* envs[MLB_CATALOGUE_MAX_ENVS];   // built-in names or files (default the pipeline's
    int n_envs;              //   pool: sky, studio, overcast)
    int env_height;          // lat-long rows of built-ins (default 256, the pipeline's)
    int cube_size;           // pre-integrated cube face (default 128, the pipeline's)
} mlb_catalogue_render_config;

mlb_catalogue_render_config mlb_catalogue_render_default(void);

typedef struct mlb_catalogue_renderer mlb_catalogue_renderer;
// Opens and pre-integrates every environment once; keeps the last mesh (class, seed) for reuse.
// One renderer serves one thread at a time: give each thread its own.
mlb_status mlb_catalogue_renderer_create(mlb_catalogue_renderer** out, const mlb_catalogue_render_config* c);
void mlb_catalogue_renderer_free(mlb_catalogue_renderer* r);
int mlb_catalogue_renderer_res(const mlb_catalogue_renderer* r);
int mlb_catalogue_renderer_n_envs(const mlb_catalogue_renderer* r);
// rgb [3, res, res] and normal [res, res, 4] as described at the top; either may be NULL.
mlb_status mlb_catalogue_render(mlb_catalogue_renderer* r, const mlb_catalogue_sample* s, float* rgb, float* normal);

#endif
