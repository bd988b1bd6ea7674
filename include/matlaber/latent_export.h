// A latent-mode asset's editable material (docs/export.md, "Latent codes"): beside NAME.glb,
//   NAME.latent.bin     the latent codes baked over the .glb's UV atlas: size × size texels of 4
//                       float32 (little-endian), row 0 the top row, as the kd texture's;
//   NAME.decoder.json   the BRDF prior's frozen decoder, exactly as mlb_material_decode applies it:
//                       the layers (weight [out][in] row-major, bias [out]), the hidden and output
//                       activations, k = lo + (hi - lo) · sigmoid(last layer), and the .bin's name,
//                       size and per-channel min / max.
// The viewer decodes (codes + an offset) in a shader; decoding a texel's code with the JSON gives
// the BRDF the .glb's textures hold there (before their 8-bit encoding).
#ifndef MATLABER_LATENT_EXPORT_H
#define MATLABER_LATENT_EXPORT_H
#include "matlaber/error.h"
#include "matlaber/nn.h"

// glb_path must end in .glb; z [size, size, 4]. The .bin is written first, then the .json (the
// file readers look for), each atomically. dec: a 4 -> ... -> 7 MLP with biases, sigmoid output.
mlb_status mlb_latent_export(const char* glb_path, const mlb_mlp* dec, const float* z, int size);
// Removes NAME.latent.bin and NAME.decoder.json beside glb_path when present (a direct-mode
// export over an earlier latent one leaves no stale editor behind).
void mlb_latent_export_remove(const char* glb_path);
// The sidecar names for glb_path ("x/a.glb" -> "x/a.decoder.json", "x/a.latent.bin"); 0 on success.
int mlb_latent_export_paths(const char* glb_path, char* json, char* bin, size_t cap);

#endif
