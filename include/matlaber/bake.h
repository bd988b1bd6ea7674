// Baking a material field into textures over a UV atlas (uv_atlas.h; docs/uv_atlas.md).
// Every face is rasterised in UV space at size × size: a texel whose centre lies inside a face
// takes that face; a texel a face only grazes (its centre within half a texel diagonal, 0.71 texel,
// of the face: conservative coverage, so thin triangles are not lost) takes the nearest such face
// and the closest point of it. The 3D position is interpolated there, the material is evaluated
// at all covered texels in one call, and kd, ks (linear; writers encode sRGB) and roughness are
// written. Then the charts are dilated: every empty texel within `dilate` texels (Chebyshev
// distance, breadth-first, 8-neighbours in a fixed order) copies the value of its nearest covered
// texel, so mipmaps do not mix in background; dilate < 0 fills the whole texture that way. Texels
// still empty after that hold the mean of the covered texels.
// Each face is visited row by row over its own extent; a face with an earlier face's uv triangle is
// skipped; UVs stacked more than 64 layers deep are refused (MLB_ERR_UNSUPPORTED), so the work is
// at most 64 × (size² + faces) texels.
// Images are row-major, top row first; texel (x, y) has its centre at uv ((x+0.5)/size, 1 − (y+0.5)/size).
#ifndef MATLABER_BAKE_H
#define MATLABER_BAKE_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/error.h"
#include "matlaber/render.h"   // mlb_material_fn
#include "matlaber/uv_atlas.h"


#define MLB_BAKE_DEFAULT_DILATE 16

typedef struct {
    int size;
    float* kd;          // [size, size, 3] linear
    float* ks;          // [size, size, 3] linear
    float* roughness;   // [size, size, 1]
    uint8_t* mask;      // [size, size] 1 where a face covers the texel (before dilation), else 0
    int32_t* face;      // [size, size] the face whose material the texel holds (covered or dilated), -1 none
    int n_covered;      // texels with mask 1
    int n_dilated;      // texels filled by dilation
} mlb_baked;

// size in 1..16384. Errors: MLB_ERR_ARG (bad mesh/size, NULL fn), MLB_ERR_NOMEM,
// MLB_ERR_UNSUPPORTED (UVs stacked more than 64 layers deep), a failing fn's
// status (with "baking: " in front of its message), MLB_ERR_NUMERIC (fn returned NaN/Inf).
// *out is overwritten; on error it is left zeroed.
mlb_status mlb_bake(const mlb_uv_mesh* m, int size, mlb_material_fn fn, void* user, int dilate, mlb_baked* out);
void mlb_baked_free(mlb_baked* b);   // safe on a zeroed struct

// A 4-channel field (a latent material's codes: zfn(user, pos, n, z) fills z [n,4]) baked exactly
// as mlb_bake bakes the material: the same texels, faces, points and dilation, so texel t of z
// [size, size, 4] is the code whose decoding mlb_bake stores at t. Errors as mlb_bake.
mlb_status mlb_bake_codes(const mlb_uv_mesh* m, int size, mlb_material_fn zfn, void* user, int dilate, float* z);

#endif
