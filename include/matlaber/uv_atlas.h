// UV atlas of a triangle mesh, written by the project (docs/uv_atlas.md):
//   1. charts: region growing over edge-adjacent faces; a face joins a chart when its normal is within
//      `max_angle_deg` of the chart's axis (the area-weighted mean normal, refined twice);
//   2. parameterisation: orthographic projection of each chart onto the plane normal to its axis.
//      Every face then has positive UV area (its normal is < 90° from the axis) and its stretch is
//      bounded by construction: Γ = 1/cos θ ≤ 1/cos(max_angle), γ = 1 (θ = face-to-axis angle).
//      A chart whose projection overlaps itself (a helical ramp; rare) is cut in two along the
//      surface (the first half of a breadth-first order from a far face), recursively, until none
//      overlaps; a chart of 32 faces or more whose area is under 0.6 × its convex hull's (an
//      annulus, a C shape) is cut the same way, since it would waste its rectangle in the packing;
//   3. packing: each chart rotated to its minimum-area bounding rectangle (height ≤ width), all at
//      one texel density, with `gutter` texels (at `texture_size`) kept free around each chart.
//      First rectangles, skyline-packed (bottom-left) by decreasing height, give a density that
//      surely fits; then a horizon ("Tetris", Lévy et al. 2002) packer that drops each chart, in
//      one of four quarter turns, onto per-column height profiles (its real outline, not its
//      rectangle) raises the density by bisection as far as it still fits.
// A face given again (the same welded corners in the same turn) shares its first copy's chart and
// UVs. The work is near-linear in faces: the overlap check is bounded per face (a chart that would
// need more is cut), slivers join charts breadth-first, and more charts than the gutter leaves room
// for ((texture_size / 2·gutter)², 16384 at the defaults) are an error before any packing.
// Charts are projection charts, so they need not be discs (a torus' top band is an annulus and
// projects injectively); what matters is that each projects without overlap, which is checked.
// Vertices are split at chart seams: the output mesh has one vertex per (input vertex, chart),
// and vert_src maps each back. Faces keep the input's order and winding.
// UV convention: u right, v up (OBJ); texel (x, y) of a size×size image, row y counted from the
// top, has its centre at u = (x + 0.5)/size, v = 1 − (y + 0.5)/size. glTF writers store 1 − v.
#ifndef MATLABER_UV_ATLAS_H
#define MATLABER_UV_ATLAS_H
#include <stdint.h>
#include "matlaber/error.h"
#include "matlaber/mesh.h"

// A face whose smallest height (2·area / longest edge) is below this × the bounding-box diagonal
// is degenerate: 1e-5 of the diagonal is 1/100 texel at 1024² and still ~10 float ulps in uv.
#define MLB_UV_DEGENERATE_REL 1e-5
// Past this many charts the horizon packer is skipped and the rectangles' packing kept: it scans
// the atlas' columns for every chart, and so many charts are small ones that gain little by it.
#define MLB_UV_HORIZON_MAX_CHARTS 4096

typedef struct {
    int texture_size;      // resolution the gutter is measured at; default 1024
    int gutter;            // texels kept free around each chart (so 2·gutter between charts); default 4
    float max_angle_deg;   // chart normal cone half-angle, in (0, 80]; default 40
} mlb_uv_options;

typedef struct {
    mlb_mesh mesh;         // pos [V,3], normal [V,3] (input's, else area-weighted), uv [V,2] in [0,1], faces [F,3]
    int32_t* vert_src;     // [V] the input vertex each vertex copies
    int32_t* face_chart;   // [F] chart of each face, 0..n_charts-1
    int n_charts;
    int texture_size;      // from the options
} mlb_uv_mesh;

typedef struct {
    int n_charts;
    int n_verts;              // after the seam split
    int n_faces;
    int n_degenerate;         // faces thinner than MLB_UV_DEGENERATE_REL × the bbox diagonal (a
                              // marching-tets sliver, a collapsed face): too thin for float uvs to
                              // keep a positive area; they join a neighbouring chart, and their uv
                              // area may be zero (or −0 ulp)
    int n_split;              // charts cut because their projection overlapped itself
    int n_cut;                // charts cut because they were far from convex (area < 0.6 × hull area)
    double utilisation;       // Σ face UV area (the square's fraction covered by triangles)
    double stretch_l2;        // Sander et al. 2001, area-weighted, with the atlas scaled to the
    double stretch_linf;      //   surface's total area (1 = isometric); over non-degenerate faces
    double texels_per_unit;   // texels (at texture_size) per world unit of length
} mlb_uv_stats;

mlb_uv_options mlb_uv_default(void);
// Unwraps `in` (positions and faces; normals used when present). Errors: MLB_ERR_ARG (bad mesh or
// options, a non-finite position, an empty mesh), MLB_ERR_NOMEM, MLB_ERR_NUMERIC (the charts do
// not fit even at a vanishing density: more charts than the gutter allows at texture_size).
// opt and stats may be NULL. *out is overwritten; on error it is left zeroed.
mlb_status mlb_uv_unwrap(const mlb_mesh* in, const mlb_uv_options* opt, mlb_uv_mesh* out, mlb_uv_stats* stats);
void mlb_uv_mesh_free(mlb_uv_mesh* m);   // safe on a zeroed struct
// Utilisation, stretch and counts of a uv mesh (n_split, n_cut and texels_per_unit are left 0).
void mlb_uv_measure(const mlb_uv_mesh* m, mlb_uv_stats* stats);

#endif
