// Differentiable rasterization on the CPU, after nvdiffrast (reference.md §5): cameras, rasterize,
// interpolate, antialias, supersampling and background compositing. Conventions (docs/raster.md):
//   - Matrices are double, row-major (m[4*row + col]) and act on column vectors: clip = P·V·[p, 1].
//   - Clip space is OpenGL's: a point is visible when -w <= z <= w, and NDC = (x, y, z) / w.
//   - Images are [H, W, C] row-major with row 0 at the TOP (NDC y = +1); pixel (px, py) has its
//     centre at NDC ((2 px + 1) / W - 1, 1 - (2 py + 1) / H), i.e. at pixel coordinate +0.5.
//   - Barycentrics are perspective-correct, from clip space without dividing by w:
//     p_i' = (x_i - f_x w_i, y_i - f_y w_i), a0 = p1'×p2', a1 = p2'×p0', a2 = p0'×p1',
//     (b0, b1) = (a0, a1) / (a0 + a1 + a2); a point's attribute is b0 A[i0] + b1 A[i1] + (1-b0-b1) A[i2].
//   - depth is z/w (NDC depth, -1 at the near plane, +1 at the far plane); 0 where nothing is drawn.
//   - Coverage: vertices snapped to 1/256 pixel, exact integer edge functions, top-left fill rule:
//     a pixel centre on an edge shared by two triangles is drawn by exactly one of them. Both sides
//     of every triangle are drawn; the nearest depth wins, equal depth goes to the lower triangle id.
// Every function over `real` exists twice: float (plain name) and double (name_f64), see
// raster_api.inc. Backward functions ACCUMULATE (+=) into gradient buffers, any of which may be NULL.
#ifndef MATLABER_RASTER_H
#define MATLABER_RASTER_H
#include <stdint.h>
#include "matlaber/error.h"

#define MLB_RASTER_MAX_SIZE 16384   // largest image width or height

// ---- matrices and cameras (double precision, shared by both precisions) --------------------------
typedef struct { double m[16]; } mlb_mat4;   // row-major m[4*row + col]; y = M x for column vectors x

mlb_mat4 mlb_mat4_identity(void);
mlb_mat4 mlb_mat4_mul(const mlb_mat4* a, const mlb_mat4* b);   // a·b (b applied first)
// World → view (camera at eye looking at target, `up` roughly up; the camera looks down its -z axis).
mlb_status mlb_look_at(mlb_mat4* view, const double eye[3], const double target[3], const double up[3]);
// View → clip, OpenGL: fovy vertical field of view in degrees (0, 180), aspect = W / H,
// 0 < near < far. A view-space point at distance d in front of the camera gets w = d.
mlb_status mlb_perspective(mlb_mat4* proj, double fovy_deg, double aspect, double near_z, double far_z);

typedef struct {
    double azimuth_deg, elevation_deg, radius;
    double fovy_deg, aspect, near_z, far_z;
    double target[3], eye[3];
    mlb_mat4 view, proj, view_proj;   // view_proj = proj · view: world → clip
} mlb_camera;
// Orbit camera, y up: eye = target + radius·(cos(el) sin(az), sin(el), cos(el) cos(az)).
// Azimuth 0 looks from +z towards -z (the front of an OBJ model), 90 from +x; elevation > 0 is
// above. target may be NULL (the origin). At |elevation| = 90 the view's up vector becomes -z/+z.
mlb_status mlb_camera_orbit(mlb_camera* cam, double azimuth_deg, double elevation_deg, double radius,
                            const double target[3], double fovy_deg, double aspect, double near_z,
                            double far_z);
// The project's orbit, written once: every camera sits MLB_ORBIT_RADIUS from the object's centre
// (objects are scaled into the generation frame, the unit ball); the optimisation's random views
// (cameras.h: mlb_orbit_default; geometry_fit.h: mlb_geofit_default) keep their elevation within
// [MLB_ORBIT_EL_MIN, MLB_ORBIT_EL_MAX] degrees and their vertical field of view within
// [MLB_ORBIT_FOVY_MIN, MLB_ORBIT_FOVY_MAX] (the geometry fit's fixed one: the widest). Every
// camera's clip planes, unless a cameras.json entry names its own, are MLB_ORBIT_NEAR and _FAR.
#define MLB_ORBIT_RADIUS 3.0
#define MLB_ORBIT_EL_MIN (-10.0)
#define MLB_ORBIT_EL_MAX 45.0
#define MLB_ORBIT_FOVY_MIN 25.7
#define MLB_ORBIT_FOVY_MAX 45.0
#define MLB_ORBIT_NEAR 0.1
#define MLB_ORBIT_FAR 100.0

// ---- scratch memory -------------------------------------------------------------------------------
// Buffers the rasterizer, the backwards and antialias reuse from call to call (grown as needed,
// freed with the context). Pass NULL to any function to let it allocate and free its own. A context
// serves one call at a time: give each concurrent caller its own.
typedef struct mlb_raster_ctx mlb_raster_ctx;
mlb_raster_ctx* mlb_raster_ctx_create(void);   // NULL when out of memory
void mlb_raster_ctx_free(mlb_raster_ctx* ctx);   // NULL is fine

// ---- mesh topology for antialias ----------------------------------------------------------------
// adj[F,3]: for the edge of face f opposite its corner e (vertices faces[f, e+1], faces[f, e+2],
// mod 3), the other face that shares that edge, -1 on a boundary edge. Where more than two faces
// share an edge the lowest other face id is used. Depends only on faces: build once per mesh and
// reuse for every view. O(F) time.
mlb_status mlb_edge_topology(int32_t* adj, const int32_t* faces, int n_faces, int n_verts);
// flags[i] = tri[i] >= 0 (the covered pixels; raster_api.inc "samples"), n pixels
void mlb_covered_flags(int32_t* flags, const int32_t* tri, long n);

#define MLB_REAL float
#define MLB_FN(name) name
#include "matlaber/raster_api.inc"
#undef MLB_REAL
#undef MLB_FN
#define MLB_REAL double
#define MLB_FN(name) name##_f64
#include "matlaber/raster_api.inc"
#undef MLB_REAL
#undef MLB_FN

#endif
