// Internal to src/export/uv_*.c: the charts and the geometry helpers of uv_charts.c, the packers
// and the convex hull of uv_pack.c.
#ifndef MATLABER_UV_INTERNAL_H
#define MATLABER_UV_INTERNAL_H

#include <stdint.h>
#include "matlaber/uv_atlas.h"

static inline double mlb_uv_dot3(const double* a, const double* b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

// An orthonormal basis (t1, t2) with t1 × t2 = n (n unit).
void mlb_uv_plane_basis(const double* n, double* t1, double* t2);

// The triangle's smallest height (2·area / longest edge; 0 when all corners coincide) and its
// un-normalised normal c = (q1 − q0) × (q2 − q0).
double mlb_uv_face_height(const float* const q[3], double* c);

// A face's corners (through weld, when not NULL) turned so that the smallest comes first (the
// winding kept): two faces with the same key are one surface given twice.
typedef struct { int32_t v[3], face; } mlb_uv_face_key;
// fk [F]: the keys of faces [F,3], sorted by corners, then face.
void mlb_uv_face_keys(const int32_t* faces, const int32_t* weld, int F, mlb_uv_face_key* fk);

typedef struct {
    int32_t* faces;
    int n, cap;
    double axis[3];      // the projection direction
} mlb_uv_chart;

typedef struct {
    mlb_uv_chart* v;
    int n, cap;
    uint8_t* degen;      // [F] 1: thinner than MLB_UV_DEGENERATE_REL × the bbox diagonal
    int32_t* dup;        // [F] the earlier face it repeats (whose chart it shares), -1 none
    int n_split, n_cut;  // charts cut for an overlap, for poor convexity
} mlb_uv_charts;

// Cuts the mesh (checked by mlb_uv_unwrap) into charts whose faces lie within acos(cos_max) of
// their axis and whose projections along it do not overlap. Every face is in one chart. 1, or 0
// when out of memory (L zeroed).
int mlb_uv_make_charts(const mlb_mesh* in, double cos_max, mlb_uv_charts* L);
void mlb_uv_charts_free(mlb_uv_charts* L);   // safe on a zeroed struct

typedef struct {
    const double* tri;   // [n_tri, 3, 2] the chart's triangles in its local frame (world units, min corner 0)
    int n_tri;
    double w, h;         // the local frame's extent
} mlb_uv_pack_chart;

typedef struct {
    double x, y;         // texel offset of the rotated chart's local origin in the atlas
    int rot;             // quarter turns counter-clockwise: local (a, b) → r0 (a, b), r1 (h − b, a),
                         // r2 (w − a, h − b), r3 (b, w − a) (a, b, w, h in texels); all keep orientation
} mlb_uv_pack_place;

// Packs the charts (in `order`) at density s texels per world unit into size × size texels, each
// kept `gutter` texels from the others and from the border. 1: all fit (out filled when not
// NULL), 0: they do not, -1: out of memory.
int mlb_uv_pack_horizon(const mlb_uv_pack_chart* c, const int* order, int n, double s, int gutter, int size,
                        mlb_uv_pack_place* out);

// Skyline packing (bottom-left) of rectangles (wh[i]·s + 2g) in `ord` order into size × size:
// 1 when all fit, pos [n,2] (lower-left corners, when not NULL). sky, tmp: scratch [2n + 4] each.
typedef struct { double x, y, w; } mlb_uv_sky_seg;
int mlb_uv_pack_skyline(const double* wh, const int* ord, int n, double s, double g, double size, double* pos,
                        mlb_uv_sky_seg* sky, mlb_uv_sky_seg* tmp);
// Convex hull (Andrew's monotone chain) of p [n,2] (sorted in place): hull [n + 1, 2]
// counter-clockwise; returns its size.
int mlb_uv_convex_hull(double* p, int n, double* hull);

#endif
