// The geometry network of MATLABER / Fantasia3D (reference.md §3, docs/geometry_init.md): a
// multiresolution hash encoding of the point (the grid box [−0.5, 0.5]^3 × scale mapped to [0,1]^3)
// feeds an MLP (32 wide, 2 hidden layers, ReLU, no bias) with 4 outputs: the SDF (negative inside)
// and a deformation (xyz, applied as tanh(d)/grid_res by dmtet_deform_forward). Its SDF is
// initialised by 400 Adam steps of MSE against an analytic or mesh signed distance
// (mlb_geometry_fit_shape), then extracted with marching tets (mlb_geometry_extract).
//
// The network exists as float (plain names) and double (name_f64, for the finite-difference tests).
// Parameters live in one allocation: [hash table | MLP weights]; grads/Adam moments the same layout.
// Backward ACCUMULATES into net->grads (zero them with geometry_net_zero_grad once per step).
#ifndef MATLABER_GEOMETRY_H
#define MATLABER_GEOMETRY_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/dmtet.h"
#include "matlaber/error.h"
#include "matlaber/field.h"
#include "matlaber/hashgrid.h"
#include "matlaber/mesh.h"
#include "matlaber/nn.h"
#include "matlaber/progress.h"
#include "matlaber/safetensors.h"

// The geometry network is a field (field.h) of kind MLB_FIELD_GEOMETRY: config, layout, cache,
// optimiser state and files are the field's (mlb_geometry_net is an mlb_field).
typedef mlb_field_config mlb_geometry_config;
typedef mlb_field mlb_geometry_net;
typedef mlb_field_f64 mlb_geometry_net_f64;

mlb_geometry_config mlb_geometry_default(void);
// Adam for hash-grid networks (reference.md §4): betas (0.9, 0.99), eps 1e-15, no weight decay.
mlb_adam_config mlb_geometry_adam(double lr);

#define MLB_GEOMETRY_DECLARE(R, N)                                                                   \
    /* Allocates and initialises (table U(±1e-4), Glorot MLP weights) from cfg->seed (kind set to  \
       geometry whatever cfg says). */                                                              \
    mlb_status N(geometry_net_init)(N(mlb_geometry_net)* net, const mlb_geometry_config* cfg);      \
    void N(geometry_net_free)(N(mlb_geometry_net)* net);   /* safe on a zeroed net */              \
    void N(geometry_net_zero_grad)(N(mlb_geometry_net)* net);                                       \
    /* pos[n,3] in world units (the grid box); sdf[n] and deform[n,3] (either may be NULL).         \
       Caches what backward needs (MLB_ERR_NOMEM when the cache cannot grow). */                   \
    mlb_status N(geometry_net_forward)(N(mlb_geometry_net)* net, R* sdf, R* deform, const R* pos, int n); \
    /* grads += ∂(Σ dsdf·sdf + Σ ddeform·deform)/∂params over the last forward's n points;          \
       dsdf[n], ddeform[n,3] (either may be NULL = zero). */                                        \
    mlb_status N(geometry_net_backward)(N(mlb_geometry_net)* net, const R* dsdf, const R* ddeform); \
    /* One Adam step over all parameters with net->grads (net->step += 1). */                       \
    mlb_status N(geometry_net_update)(N(mlb_geometry_net)* net, const mlb_adam_config* adam);

#define MLB_GEOMETRY_F32(name) name
#define MLB_GEOMETRY_F64(name) name##_f64
MLB_GEOMETRY_DECLARE(float, MLB_GEOMETRY_F32)
MLB_GEOMETRY_DECLARE(double, MLB_GEOMETRY_F64)
#undef MLB_GEOMETRY_F32
#undef MLB_GEOMETRY_F64

// ---- files (float network) -------------------------------------------------------------------
// Tensors "encoding.table" [entries, F] and "mlp.N.weight" [out, in]; metadata holds the config
// ("geometry.levels", ".features", ".table_size", ".base_res", ".per_level_scale", ".hidden",
// ".n_hidden", ".scale") plus the caller's extra entries (NULL/0 for none).
mlb_status mlb_geometry_save(const mlb_geometry_net* net, const char* path, const mlb_st_meta* extra, size_t n_extra);
// Reads the config from the metadata, then the weights; *net is overwritten (zeroed on failure).
mlb_status mlb_geometry_load(mlb_geometry_net* net, const char* path);

// SDF and deformation at the grid vertices, v = v_grid + tanh(d)/(2·cells), marching tets: a float
// mesh with faces and positions (no normals). An empty surface is an MLB_ERR_ARG error ("no surface").
// Marching tets runs on the op table be (mlb_mt_device_forward; NULL: the CPU's): the network stays
// on the host, its SDF and positions go to be's device.
mlb_status mlb_geometry_extract(const mlb_backend* be, mlb_geometry_net* net, const mlb_tetgrid* grid, mlb_mesh* out);

// ---- shapes and their signed distance (shape_init.c) ---------------------------------------
typedef enum { MLB_SHAPE_ELLIPSOID = 0, MLB_SHAPE_CYLINDER, MLB_SHAPE_MESH, MLB_SHAPE_TORUS, MLB_SHAPE_BOX, MLB_SHAPE_CUP } mlb_shape_kind;
typedef struct {
    mlb_shape_kind kind;
    float radii[3];        // ellipsoid semi-axes
    float cyl_radius;      // capped cylinder about the y axis, y ∈ [−h/2, h/2]
    float cyl_height;
    float torus_major, torus_minor;   // torus in the xy plane (hole along z, facing the front camera)
    float box_center[3], box_half[3];   // box: centre and half-extents along x, y, z
    float cup_radius, cup_wall, cup_center_y;   // cup: the lower half of a spherical shell of mid radius
                                                // cup_radius and half-thickness cup_wall, centred at y
    mlb_mesh mesh;         // MLB_SHAPE_MESH: owned copy (positions + faces), already placed
    double mesh_area;      // total area (for sampling)
} mlb_shape;

// Ellipsoid with semi-axes scale·(1, 1, 1)·axes (axes NULL = 1, 1, 1); reference: radius 1 × scale.
void mlb_shape_ellipsoid(mlb_shape* s, float scale, const float* axes);
// Capped cylinder of radius 0.75·scale and height 0.8·scale about y (reference.md §3).
void mlb_shape_cylinder(mlb_shape* s, float scale);
// Torus in the xy plane about the z axis (its hole faces the front camera at azimuth 0): major
// radius 0.6·scale·0.8/0.9, minor 0.3·scale·0.8/0.9 (outer radius 0.8·scale, the scale of a mesh init).
// A genus-1 start: score distillation closes a hole through silhouette gradients, but has no
// gradient that opens one in a genus-0 surface (docs/pipeline.md, Init).
void mlb_shape_torus(mlb_shape* s, float scale);
// A flat slab (a box) placed high, like a table top: x ±0.9, y 0.25..0.4, z ±0.55 times
// k = 0.8·scale/|(0.9, 0.4, 0.55)| (the box (±0.9, ±0.4, ±0.55) it sits in has its corners at
// radius 0.8·scale, a mesh init's size): 1.28 x 0.11 x 0.78 at y 0.18..0.28 at scale 1. From it
// the geometry stage grows legs down, where from the ellipsoid the tiny preset loses a table's
// surface, and from the same plate at mid-height it lost every stool (docs/pipeline.md, Init).
void mlb_shape_slab(mlb_shape* s, float scale);
// A cup: the lower half of a spherical shell, open at the top: mid radius 0.6·k, wall 0.2·k thick,
// the sphere's centre at y = 0.3·k, so the cup spans y −0.4·k..0.4·k, with k = 0.8·scale/|(0.7, 0.4)|
// (its rim's outer corner at radius 0.8·scale, a mesh init's size). Like the torus, a topology the
// geometry stage cannot make from the ellipsoid: it has no gradient that opens a cavity in a closed
// surface, so a bowl from the ellipsoid stays a closed lens (docs/benchmarks.md).
void mlb_shape_cup(mlb_shape* s, float scale);
// The built-in shape called `name` ("ellipsoid": radius scale, "cylinder", "torus", "slab", "cup") into *s:
// 1, or 0 (s untouched) when name is none of them (a file, say).
int mlb_shape_builtin(mlb_shape* s, const char* name, float scale);
// A copy of m normalised to the unit sphere (mlb_mesh_normalize_unit_sphere), times scale.
mlb_status mlb_shape_from_mesh(mlb_shape* s, const mlb_mesh* m, float scale);
void mlb_shape_free(mlb_shape* s);   // safe on a zeroed shape
// Signed distance (negative inside) at p[n,3]. Analytic shapes: exact for the cylinder; for the
// ellipsoid the first-order estimate (|q|−1)·|q|/|∇|q|| with q = p/radii (exact for a sphere,
// vanishes on the surface, sign always right). Meshes: unsigned distance (mlb_mesh_distance) with
// the sign of the generalised winding number (O(n·F)).
// Parallel over points.
void mlb_shape_sdf(const mlb_shape* s, const float* p, float* out, int n);
// n points on the surface (Philox (seed, stream)): area-uniform for meshes and the cylinder,
// direction-uniform on the ellipsoid (area-uniform for a sphere).
void mlb_shape_surface_samples(const mlb_shape* s, float* p, int n, uint64_t seed, uint64_t stream);

// Generalised winding number of a triangle soup at p[n,3]: Σ_f Ω_f(p)/(4π), Ω the signed solid
// angle (Van Oosterom–Strackee). 1 inside, 0 outside a closed CCW mesh; degrades gracefully near
// holes. O(n·F).
void mlb_mesh_winding_number(const mlb_mesh* m, const float* p, double* out, int n);
// Unsigned distance from p[n,3] to the triangles: sqrt of the minimum of mlb_point_triangle_dist2
// over the triangles, as float; the same bits whatever the thread count. Builds a BVH per call
// (O(F log F), then about O(log F) per point; mlb_mesh_bvh_* below to reuse one). INFINITY
// everywhere for a mesh without triangles, NaN for a point with a NaN coordinate; triangles with a
// non-finite coordinate are left out. Parallel over points.
void mlb_mesh_distance(const mlb_mesh* m, const float* p, float* out, int n);
// Squared distance from p to triangle (a, b, c) (Ericson's closest-point regions), in double. The
// closest point stays inside the triangle's bounding box (what makes box pruning exact, mesh_bvh.c);
// a numerically degenerate triangle (zero area, a sliver) measures to its nearest edge point.
double mlb_point_triangle_dist2(const double p[3], const float* a, const float* b, const float* c);

// ---- triangle BVH for the distance (mesh_bvh.c) ----------------------------------------------
// Binned SAH split on the longest axis of the centroids (the median where it cannot tell), leaves
// of <= 4 triangles, one flat node array.
typedef struct {
    float lo[3], hi[3];   // bounds of the triangles below
    int32_t first;        // leaf: first triangle in tri; inner node: left child (right = first + 1)
    int32_t count;        // leaf: its triangles (> 0); inner node: 0
} mlb_bvh_node;
typedef struct {
    int n_nodes, n_tris;  // n_tris: the mesh's triangles with finite coordinates (the rest left out)
    int depth;            // levels, the root's included
    mlb_bvh_node* nodes;  // [n_nodes], the root first; NULL when n_tris = 0
    float* tri;           // [n_tris, 9] corners, in leaf order
    int32_t* face;        // [n_tris]: each one's face in the mesh
} mlb_mesh_bvh;
// Copies what it needs: the mesh may change or go afterwards. MLB_ERR_NOMEM, or MLB_ERR_ARG beyond
// 2^29 faces; *b zeroed on failure.
mlb_status mlb_mesh_bvh_build(mlb_mesh_bvh* b, const mlb_mesh* m);
void mlb_mesh_bvh_free(mlb_mesh_bvh* b);   // safe on a zeroed one
// Minimum of mlb_point_triangle_dist2 over the triangles (exactly: pruning never changes it);
// INFINITY without triangles, NaN when q has a NaN coordinate.
double mlb_mesh_bvh_dist2(const mlb_mesh_bvh* b, const double q[3]);
// mlb_mesh_distance with a built BVH: out[i] = (float)sqrt(dist2(p_i)). Parallel over points.
void mlb_mesh_bvh_distance(const mlb_mesh_bvh* b, const float* p, float* out, int n);
// The same, and face[i]: the mesh face nearest p_i (the lowest-numbered in leaf order of those at
// that distance; -1 without triangles). face may be NULL.
void mlb_mesh_bvh_nearest_faces(const mlb_mesh_bvh* b, const float* p, float* out, int32_t* face, int n);
// n area-uniform points on the mesh's triangles (Philox (seed, stream)); MLB_ERR_ARG for zero area.
mlb_status mlb_mesh_sample_surface(const mlb_mesh* m, float* p, int n, uint64_t seed, uint64_t stream);
// The same on the triangles f with mask[f] != 0 (mask NULL: all, bitwise mlb_mesh_sample_surface),
// and each point's triangle in face[i] (face may be NULL). MLB_ERR_ARG when they have no area.
mlb_status mlb_mesh_sample_faces(const mlb_mesh* m, const uint8_t* mask, float* p, int32_t* face, int n, uint64_t seed,
                                 uint64_t stream);

// ---- the SDF initialisation ------------------------------------------------------------------
typedef struct {
    int iters;          // Adam steps, default 400
    int batch;          // points per step, default 12288 (a third each: surface, jittered, uniform)
    double lr;          // default 1e-2
    float jitter;       // std of the surface jitter, default 0.05
    int pool;           // points drawn (and their SDF computed) once per kind, default 32768
    uint64_t seed;      // sampling seed, default 1
} mlb_shape_fit_config;

mlb_shape_fit_config mlb_shape_fit_default(void);
// Fits the network's SDF output to the shape's signed distance by MSE (deformation untouched).
// final_loss (may be NULL) receives the mean MSE of the last 10 steps. progress may be NULL.
mlb_status mlb_geometry_fit_shape(mlb_geometry_net* net, const mlb_shape* shape, const mlb_shape_fit_config* cfg,
                                  mlb_progress* progress, double* final_loss);

// ---- Chamfer distance (chamfer.c) ------------------------------------------------------------
typedef struct {
    double a_to_b, b_to_a;   // mean point-to-surface distance of samples on a to b's triangles, and back
    double chamfer;          // (a_to_b + b_to_a) / 2
    double diag;             // the target's (b's) bounding-box diagonal
    double relative;         // chamfer / diag
    double max_a_to_b, max_b_to_a;   // the largest sample distances (one-sided Hausdorff estimates)
} mlb_chamfer_result;
// Symmetric Chamfer distance between meshes a and b (the target): n samples on each, area-uniform
// (Philox seed), exact distances to the other mesh's triangles (mlb_mesh_distance). The same bits
// for any thread count.
mlb_status mlb_chamfer(const mlb_mesh* a, const mlb_mesh* b, int n, uint64_t seed, mlb_chamfer_result* r);
// r[j] = mlb_chamfer(a, &b[j], n, seed), bit for bit, for the m targets b[0..m): a's samples and
// BVH made once, the targets shared out over the threads (one parallel region: many short ones
// cost more than the work on busy cores). b_bvh: NULL, or the targets' BVHs (mlb_mesh_bvh_build of
// each b[j]) when they are measured against often. The first failing target's error, naming it.
mlb_status mlb_chamfer_many(const mlb_mesh* a, const mlb_mesh* b, const mlb_mesh_bvh* b_bvh, int m, int n, uint64_t seed,
                            mlb_chamfer_result* r);

// ---- surface agreement (surface_compare.c) ---------------------------------------------------
#define MLB_SURFACE_MAX_PARTS 4
typedef struct {
    double normal_deg;       // mean angle (degrees) between the asset's shading normal (area-weighted
                             //   vertex normals of its positions, interpolated) at n area-uniform
                             //   samples and the face normal of the truth's nearest face, either way
                             //   round (0..90: a thin wall's two sides are both the truth)
    double accuracy;         // 95th percentile of the samples' distances to the truth / diag
    double completeness;     // 95th percentile of distances from n samples on the truth to the asset / diag
    double part_completeness[MLB_SURFACE_MAX_PARTS];   // the same on part k + 1's faces alone (n samples
                             //   there); NAN for a part the truth's faces do not carry
    double diag;             // the truth's bounding-box diagonal
} mlb_surface_result;
// The asset's surface against the truth's: part NULL, or a label per truth face (0: no part,
// 1..n_parts: a named part). Philox (seed); the same bits for any thread count.
mlb_status mlb_surface_compare(const mlb_mesh* asset, const mlb_mesh* truth, const uint8_t* part, int n_parts, int n,
                               uint64_t seed, mlb_surface_result* r);

#endif
