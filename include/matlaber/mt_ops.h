// Marching tetrahedra (DMTet's surface extraction, reference.md §3) as passes over plain buffers
// with a fixed output size per pass, the contract of the op tables' marching_tets_* ops
// (backend_ops.def) and the pieces geometry's marching_tets_forward is made of (docs/geometry.md):
//
//   count  per tet its number of triangles, per edge slot 1 when a surface vertex sits on it
//   scan   exclusive prefix sums of both: every tet's first face, every slot's vertex, the totals
//   emit   the vertices (with their edge and weights) and the faces, each at its scanned place
//   backward  the gradient of the vertex positions to the SDF and the (deformed) grid positions
//
// The grid is mlb_tetgrid's (dmtet.h): `cells` cells per axis, V = (cells + 1)^3 vertices, the
// tets [T, 4] it lists; S = 7 V edge slots (src/mesh/marching_tets_math.h: slot 7 a + code - 1 is
// the edge from vertex a in direction code, mlb_tetgrid_edge_id). Occupancy is sdf > 0. Output order
// is fixed by the scans: vertices in grid-edge order, faces tet by tet in table order, whatever the
// device or thread count. Integer buffers are int32 (on a table: allocated through alloc as that
// many floats). Passes over `real` exist as float (plain names) and double (_f64).
#ifndef MATLABER_MT_OPS_H
#define MATLABER_MT_OPS_H
#include <stdint.h>
#include "matlaber/error.h"

// out[i] = in[0] + ... + in[i-1] for i <= n (out has n + 1 values: out[n] is the total). out may be
// in (a buffer of n + 1). The total must fit in int32 (the callers bound it: slots < 2^31).
void mlb_scan_i32(int32_t* out, const int32_t* in, int n);

// The faces at each vertex, for the gather passes: off [V + 1] (v's entries are vf[off[v] ..
// off[v+1])), vf [3 F] = 3 f + the corner of v in face f, in face order. MLB_ERR_ARG names a face
// with a vertex outside [0, V).
mlb_status mlb_vertex_faces(int32_t* off, int32_t* vf, const int32_t* faces, int n_faces, int n_verts);
// adj [F,3]: for the edge of face f opposite its corner e, the lowest other face holding both its
// ends, -1 on a boundary or degenerate edge (raster.h mlb_edge_topology, which is this over
// mlb_vertex_faces' lists), gathered per face from the lists of off and vf.
void mlb_edge_partners(int32_t* adj, const int32_t* faces, int n_faces, const int32_t* off, const int32_t* vf);

#define MLB_MT_OPS_DECLARE(R, N)                                                                       \
    /* tet_nf [T] = the triangles of each tet's case (0, 1 or 2); slot_nv [7 V] = 1 on an edge whose  \
       ends differ in occupancy, else 0 (slots that are no edge too). */                             \
    void N(mlb_mt_count)(int32_t* tet_nf, int32_t* slot_nv, const R* sdf, const int32_t* tets, int T, int cells); \
    /* With tet_off [T + 1] and slot_off [7 V + 1] the scans of count's outputs (nf = tet_off[T],     \
       nv = slot_off[7 V]): verts [nv, 3], vedge [nv, 2] (its edge's ends a < b), weight [nv, 2]    \
       (v = w0 p_a + w1 p_b), faces [nf, 3] (counter-clockwise seen from outside). pos [V, 3] the   \
       deformed grid positions, sdf [V]. */                                                         \
    void N(mlb_mt_emit)(R* verts, int32_t* vedge, R* weight, int32_t* faces, const R* pos, const R* sdf, \
                        const int32_t* tets, int T, int cells, const int32_t* tet_off, const int32_t* slot_off); \
    /* dpos [V, 3] += dverts . dv/dpos, dsdf [V] += dverts . dv/dsdf (either may be NULL) for dverts  \
       [nv, 3]: sequential over the surface vertices, in order (they share grid vertices). */        \
    void N(mlb_mt_backward)(R* dpos, R* dsdf, const R* dverts, const R* weight, const int32_t* vedge, int nv, \
                            const R* pos, const R* sdf);                                              \
    /* The same sums gathered per grid vertex (the CUDA kernel's form, slot_off from the forward):   \
       the same bits as mlb_mt_backward (test_dmtet). */                                            \
    void N(mlb_mt_backward_gather)(R* dpos, R* dsdf, const R* dverts, const R* weight, const R* pos, const R* sdf, \
                                   const int32_t* slot_off, int cells);                            \
    /* DMTet's deformation (dmtet.h dmtet_deform_*): out [V,3] = grid + tanh(deform)/grid_res;   \
       ddeform [V,3] += dout (1 - tanh²(deform))/grid_res, dgrid += dout (either may be NULL). */   \
    void N(mlb_mt_deform)(R* out, const R* grid, const R* deform, int n_verts, R grid_res);        \
    void N(mlb_mt_deform_backward)(R* dgrid, R* ddeform, const R* dout, const R* deform, int n_verts, \
                                   R grid_res);                                                    \
    /* The SDF sign regulariser of a grid of `cells` per axis (dmtet.h sdf_reg_*): the mean BCE over \
       sign-changing grid edges (0 without one), and dsdf [V] += dloss · its gradient: per-vertex \
       gathers (marching_tets_math.h), the sums in double over fixed shards. */                  \
    R N(mlb_mt_sdf_reg)(const R* sdf, int cells);                                                  \
    void N(mlb_mt_sdf_reg_backward)(R* dsdf, const R* sdf, int cells, R dloss);                     \
    /* Area-weighted vertex normals of the surface (src/mesh/vertex_normals.c): m_v = the sum over \
       the faces f at v of (b - a) x (c - a), normal = m / |m| ((0, 0, 1) where |m| = 0); sum [V,3] \
       keeps m for the backward (may be NULL). The scatter form, a loop over the faces: */        \
    void N(vertex_normals_forward)(R* normal, R* sum, const R* pos, int n_verts, const int32_t* faces, \
                                   int n_faces);                                                    \
    /* dpos [V,3] += d normal / d pos . dnormal, with sum from the forward (MLB_ERR_NOMEM: O(V)   \
       scratch) */                                                                                  \
    mlb_status N(vertex_normals_backward)(R* dpos, const R* dnormal, const R* sum, const R* pos, int n_verts, \
                                          const int32_t* faces, int n_faces);                       \
    /* The gather form (the op tables' vertex_normals and _backward, and the CUDA kernels'): per   \
       vertex over the faces mlb_vertex_faces lists at it, in face order; the scatter form's bits, \
       on any thread count. sum may be NULL; dpos NULL does nothing. */                            \
    void N(mlb_vertex_normals)(R* normal, R* sum, const R* pos, int n_verts, const int32_t* faces,  \
                               const int32_t* off, const int32_t* vf);                              \
    void N(mlb_vertex_normals_backward)(R* dpos, const R* dnormal, const R* sum, const R* pos, int n_verts, \
                                        const int32_t* faces, const int32_t* off, const int32_t* vf);

#define MLB_MT_OPS_F32(name) name
#define MLB_MT_OPS_F64(name) name##_f64
MLB_MT_OPS_DECLARE(float, MLB_MT_OPS_F32)
MLB_MT_OPS_DECLARE(double, MLB_MT_OPS_F64)
#undef MLB_MT_OPS_F32
#undef MLB_MT_OPS_F64

#endif
