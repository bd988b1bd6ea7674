// Editing a latent-mode asset's material in the prior's latent space, on the CPU, as the viewer's
// editor does it in its shader (viewer/latent.js, docs/export.md "Latent codes"): the codes beside
// a .glb (latent_export.h) changed texel by texel, decoded by the prior's decoder into new kd / ks /
// roughness maps, and written as a new asset. `matlaber serve` saves a page's edit with it.
#ifndef MATLABER_LATENT_EDIT_H
#define MATLABER_LATENT_EDIT_H
#include <stddef.h>
#include "matlaber/error.h"
#include "matlaber/nn.h"

// A .glb's sidecars read back: the decoder (its parameters owned here) and the codes.
typedef struct {
    mlb_mlp dec;          // 4 -> ... -> 7, biases, sigmoid output (as latent_export.h writes it)
    float* params;        // dec's parameters
    float* z;             // [size, size, 4], row 0 the top row
    int size;
} mlb_latent_asset;

// Reads NAME.decoder.json and NAME.latent.bin beside glb_path. Both are checked as hostile input
// (format, layer sizes, the weights' counts, every number finite, the .bin's exact length); an
// error names the file and the problem. On error *a is left zeroed.
mlb_status mlb_latent_asset_read(const char* glb_path, mlb_latent_asset* a);
void mlb_latent_asset_free(mlb_latent_asset* a);

// One edit. A texel is in the region when radius < 0 (the whole asset) or when its code is within
// radius (Euclidean distance) of pick; there its code z becomes (1 - t) z + t target + offset (t 0:
// an offset alone), elsewhere it is kept.
typedef struct {
    float offset[4];
    float radius;
    float pick[4];
    float t;
    float target[4];
} mlb_latent_edit;

// 1 when the code z[4] is in e's region.
int mlb_latent_edit_in_region(const mlb_latent_edit* e, const float* z);
// z [n, 4] edited in place; returns the texels in the region.
size_t mlb_latent_edit_apply(const mlb_latent_edit* e, float* z, size_t n);
// The mean code of z [n, 4] (in double).
void mlb_latent_mean(const float* z, size_t n, float mean[4]);
// z [n, 4] decoded by a's decoder: kd [n, 3], ks [n, 3], kr [n] in the prior's ranges.
mlb_status mlb_latent_decode(const mlb_latent_asset* a, const float* z, size_t n, float* kd, float* ks, float* kr);

// The asset src_glb with its codes edited by e: out_glb (the mesh read back from src_glb, the
// decoded maps) with its own sidecars (the edited codes and the same decoder, so it can be edited
// again), and, when out_obj is not NULL, the OBJ + MTL + PNG set of the same maps. in_region
// (may be NULL) gets the texels the edit changed.
mlb_status mlb_latent_edit_export(const char* src_glb, const mlb_latent_edit* e, const char* out_glb, const char* out_obj,
                                  size_t* in_region);

#endif
