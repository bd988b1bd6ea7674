// The procedural goblet of `matlaber demo` (docs/views.md): a lathe-profiled solid goblet — a cup
// with a shallow dish on top, a stem and a foot — of real materials that change with position.
// It is the ground truth of the image-guided demo: rendered into a views data set, fitted, and the
// fitted surface's albedo compared with mlb_goblet_material at the same points.
//
// Geometry (y up, centred at the origin, every point within 0.9 of it): foot y ∈ [−0.74, −0.56]
// radius 0.45; stem radius 0.12–0.15 (0.24 wide at its waist); cup from y ≈ 0.05 to the rim at
// y = 0.70, outer radius up to 0.53; the top is a dish 0.10 deep inside a 0.15-wide rim. Every
// feature is at least 0.15 wide, more than two cells of the 32-cell tet grid over a 2.1 box.
// Watertight (every edge in exactly two faces), genus 0, counter-clockwise outward faces.
//
// Materials (k = kd rgb, ks rgb, kr; linear), a pure function of position, defined everywhere:
//   gold        y >= 0.10 (the cup):   kd 0.01, ks (1.000, 0.766, 0.336) (reference.md §1), kr 0.25
//   cobalt glaze y < 0.10 (stem, foot): kd (0.02, 0.06, 0.45), ks 0.04, kr 0.15
//   white glaze  y < −0.60 (the foot's rim band): kd (0.80, 0.80, 0.76), ks 0.04, kr 0.15
#ifndef MATLABER_GOBLET_H
#define MATLABER_GOBLET_H
#include "matlaber/error.h"
#include "matlaber/mesh.h"

#define MLB_GOBLET_CUP_Y 0.10f     // gold above, glaze below
#define MLB_GOBLET_BAND_Y -0.60f   // white band below

// The goblet with `segments` vertices around (8..4096; 64 is smooth at 512 px), area-weighted
// vertex normals, no uv.
mlb_status mlb_goblet_mesh(mlb_mesh* out, int segments);
// The material at pos[3] (any point of space).
void mlb_goblet_material(const float* pos, float k[7]);
// k[V, 7] = mlb_goblet_material of every vertex of m (per-vertex materials for rendering).
void mlb_goblet_materials(const mlb_mesh* m, float* k);

#endif
