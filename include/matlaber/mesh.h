// Triangle meshes: unified vertex arrays (a vertex is one (position, uv, normal) combination, so
// OBJ corners that differ in uv or normal become separate vertices) and counter-clockwise faces.
#ifndef MATLABER_MESH_H
#define MATLABER_MESH_H
#include <stdint.h>
#include "matlaber/error.h"

typedef struct {
    int n_verts, n_faces;
    float* pos;        // [n_verts, 3]
    float* normal;     // [n_verts, 3] or NULL
    float* uv;         // [n_verts, 2] or NULL
    int32_t* faces;    // [n_faces, 3], counter-clockwise seen from outside
} mlb_mesh;

void mlb_mesh_free(mlb_mesh* m);   // safe on a zeroed mesh
// Area-weighted vertex normals (replaces m->normal).
mlb_status mlb_mesh_compute_normals(mlb_mesh* m);
// Bounding box, and a uniform scale + offset that maps the mesh into the unit sphere at the origin.
// first[i] = the lowest index j with pos[j] bitwise equal to pos[i] (−0 = +0): welds vertices that
// seams or per-face attributes split. A hash map over the position bits, O(n).
mlb_status mlb_mesh_weld_map(const float* pos, int n, int32_t* first);
void mlb_mesh_bounds(const mlb_mesh* m, float lo[3], float hi[3]);
void mlb_mesh_normalize_unit_sphere(mlb_mesh* m);
// The largest distance from c to a vertex (double arithmetic; 0 for a mesh without vertices).
double mlb_mesh_radius_about(const mlb_mesh* m, const double c[3]);
// Taubin smoothing (src/mesh/mesh_smooth.c): `rounds` times, every vertex towards the mean of its
// neighbours by lambda, then by mu (0 < lambda < -mu < 1; Taubin's 0.5 and -0.53 pass noise of a
// few edges' length and keep the size). Positions only: recompute the normals after.
mlb_status mlb_mesh_smooth_taubin(mlb_mesh* m, int rounds, float lambda, float mu);
// A UV sphere at the origin with normals and uvs: `segments` around, `rings` from pole to pole.
mlb_status mlb_mesh_uv_sphere(mlb_mesh* m, float radius, int segments, int rings);

#endif
