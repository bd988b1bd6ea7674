// Deformable marching tetrahedra (DMTet; reference.md §3, docs/geometry.md).
//   - mlb_tetgrid: a conforming tet grid over [−0.5, 0.5]^3 × scale, `cells` cube cells per axis,
//     each split into the 6 Kuhn tets of reference.md §3 (all share the cell's main diagonal), every
//     tet positively oriented (det(b−a, c−a, d−a) > 0). Vertex (i, j, k) has index
//     i + n·(j + n·k), n = cells + 1. The "64" grid of the papers is cells = 32 (grid_res = 64),
//     "128" is cells = 64. Every grid edge joins a vertex p to p + o for o ∈ {0,1}^3 \ {0}.
//   - Marching tets over SDF values at the (deformed) grid vertices, negative inside: one output
//     vertex per grid edge whose ends differ in occupancy (sdf > 0), placed at
//     v = (p_a·(−s_b) + p_b·s_a) / (s_a − s_b), faces counter-clockwise seen from outside.
//   - The deformation v = v_grid + tanh(d) / grid_res, the SDF sign regulariser and area-weighted
//     vertex normals, with backward.
// Functions over `real` exist as float (plain name) and double (name_f64). Backward functions
// ACCUMULATE (+=); any gradient buffer may be NULL.
#ifndef MATLABER_DMTET_H
#define MATLABER_DMTET_H
#include <stdint.h>
#include "matlaber/error.h"
#include "matlaber/mesh.h"
#include "matlaber/mt_ops.h"   // the surface's vertex normals

typedef struct {
    int cells;          // cube cells per axis
    float scale;        // grid spans [−0.5, 0.5]^3 × scale
    int n_verts, n_tets, n_edges;
    float* verts;       // [n_verts, 3]
    int32_t* tets;      // [n_tets, 4], positively oriented
    int32_t* edges;     // [n_edges, 2], every unique grid edge (a < b), ordered by (a, offset code)
} mlb_tetgrid;

// cells in 1..512, scale > 0. Deterministic.
mlb_status mlb_tetgrid_create(mlb_tetgrid* g, int cells, float scale);
void mlb_tetgrid_free(mlb_tetgrid* g);   // safe on a zeroed grid
// A sparse id in [0, 7·n_verts) of the grid edge (a, b): 7·min(a,b) + code − 1, code = the
// 3-bit offset between the ends; −1 when (a, b) is not a grid edge.
int64_t mlb_tetgrid_edge_id(const mlb_tetgrid* g, int32_t a, int32_t b);

// Marching tetrahedra tables (reference.md §3).
extern const int mlb_mt_num_triangles[16];
extern const int mlb_mt_triangle_table[16][6];
extern const int mlb_mt_tet_edges[6][2];

// The surface extracted by marching tets, with what backward needs.
#define MLB_DMTET_DECLARE(R, N)                                                                      \
    typedef struct {                                                                                \
        int n_verts, n_faces;                                                                       \
        R* pos;              /* [n_verts, 3] */                                                     \
        int32_t* faces;      /* [n_faces, 3], CCW seen from outside */                              \
        int32_t* edge;       /* [n_verts, 2] the grid vertices (a, b), a < b, of each vertex */     \
        R* weight;           /* [n_verts, 2] v = weight0·p_a + weight1·p_b */                       \
    } N(mlb_mt_surface);                                                                            \
    void N(mt_surface_free)(N(mlb_mt_surface)* s);                                                  \
    /* pos[V,3] (deformed) grid positions, sdf[V]; topology from g. Deterministic output order:   \
       vertices by edge id, faces by tet then table order. */                                     \
    mlb_status N(marching_tets_forward)(N(mlb_mt_surface)* out, const mlb_tetgrid* g,               \
                                        const R* pos, const R* sdf);                                \
    /* dpos[V,3] += ∂v/∂p · dverts, dsdf[V] += ∂v/∂s · dverts for dverts[n_verts,3] */              \
    void N(marching_tets_backward)(R* dpos, R* dsdf, const N(mlb_mt_surface)* s, const R* pos,     \
                                   const R* sdf, const R* dverts);                                  \
    /* A float mesh (positions and faces; no normals or uvs) copied from the surface. */           \
    mlb_status N(mt_surface_to_mesh)(const N(mlb_mt_surface)* s, mlb_mesh* m);                      \
    /* out[V,3] = grid[V,3] + tanh(deform[V,3]) / grid_res */                                       \
    void N(dmtet_deform_forward)(R* out, const R* grid, const R* deform, int n_verts, R grid_res);   \
    /* ddeform += dout·(1 − tanh²)/grid_res; dgrid += dout */                                      \
    void N(dmtet_deform_backward)(R* dgrid, R* ddeform, const R* dout, const R* deform, int n_verts, \
                                  R grid_res);                                                      \
    /* SDF sign regulariser (nvdiffrec): over grid edges whose ends differ in occupancy (sdf > 0), \
       mean BCE_logits(s_a, s_b > 0) + mean BCE_logits(s_b, s_a > 0); 0 without such edges. */     \
    R N(sdf_reg_forward)(const mlb_tetgrid* g, const R* sdf);                                       \
    void N(sdf_reg_backward)(R* dsdf, const mlb_tetgrid* g, const R* sdf, R dloss);


#define MLB_DMTET_F32(name) name
#define MLB_DMTET_F64(name) name##_f64
MLB_DMTET_DECLARE(float, MLB_DMTET_F32)
MLB_DMTET_DECLARE(double, MLB_DMTET_F64)
#undef MLB_DMTET_F32
#undef MLB_DMTET_F64

// Marching tets through an op table (backend.h; the double twins for the double CPU table are in
// src/geometry/mt_device_f64.h): marching_tets_forward and _backward with
// the passes of backend_ops.def on the table's device (count, scan_i32, emit, backward). The handle
// (*d NULL at first) keeps the grid's tets and the last forward's buffers on the device; the grid g
// must stay unchanged while it is used. With the CPU table the results are marching_tets_forward's
// and _backward's bits. `where` says where a call's buffers are:
//   MLB_MT_HOST   host buffers in and out (uploaded and downloaded by the call);
//   MLB_MT_TABLE  on the table's device (the geometry fit's deformed grid and surface gradients):
//                 the forward's surface stays there, `out` gets its sizes only (n_verts, n_faces;
//                 no arrays), mlb_mt_device_surface_host the rest.
typedef struct mlb_backend mlb_backend;
typedef struct mlb_mt_device mlb_mt_device;
typedef enum { MLB_MT_HOST = 0, MLB_MT_TABLE = 1 } mlb_mt_place;
// pos [V,3] (deformed grid positions), sdf [V] → the surface
mlb_status mlb_mt_device_forward(mlb_mt_device** d, const mlb_backend* be, mlb_mt_surface* out,
                                 const mlb_tetgrid* g, const float* pos, const float* sdf, mlb_mt_place where);
// dpos [V,3] +=, dsdf [V] += (either may be NULL) for dverts [n_verts,3] of the last forward
mlb_status mlb_mt_device_backward(mlb_mt_device* d, float* dpos, float* dsdf, const float* dverts, mlb_mt_place where);
// The last forward's surface where it was made: verts [n_verts,3], faces [n_faces,3] (int32) on the
// table's device (what came down into the host surface), valid until the next forward
mlb_status mlb_mt_device_surface(const mlb_mt_device* d, const float** verts, const int32_t** faces);
// The last forward's surface brought to the host: *out (zeroed first; mt_surface_free it)
mlb_status mlb_mt_device_surface_host(const mlb_mt_device* d, mlb_mt_surface* out);
void mlb_mt_device_free(mlb_mt_device* d);   // safe on NULL

#endif
