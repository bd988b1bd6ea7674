// Internal to src/export/uv_*.c: the packers and the convex hull of uv_pack.c.
#ifndef MATLABER_UV_INTERNAL_H
#define MATLABER_UV_INTERNAL_H

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
