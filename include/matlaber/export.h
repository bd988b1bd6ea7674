// Writers for textured assets (MATLABER's outputs): Wavefront OBJ + MTL with PNG
// textures, glTF 2.0 binary (.glb) with a PBR material, and a static three.js viewer folder.
// The kd / ks / roughness -> MTL and glTF mappings, their caveats and the viewer's files are in
// docs/export.md.
//
// The input is a mesh with one uv per vertex and three square textures, all linear:
//   uv in the OBJ convention: u to the right, v UP; texture row 0 is the TOP of the image, so the
//   texel (x, y) (y counted from the top row) covers u in [x, x+1]/S, v in [1-(y+1)/S, 1-y/S].
//   (glTF's TEXCOORD_0 has v down: the glTF writer stores (u, 1 - v).)
// Every writer goes through mlb_atomic_open/commit; a call that fails removes the files it had
// already written, so no half-written asset is left behind. Errors name the file and the problem.
#ifndef MATLABER_EXPORT_H
#define MATLABER_EXPORT_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/error.h"

typedef struct {   // a textured asset ready to write (nothing is owned: the caller's buffers)
    int n_verts, n_faces;
    const float* pos;       // [V, 3]
    const float* normal;    // [V, 3] or NULL (then area-weighted vertex normals are computed)
    const float* uv;        // [V, 2] OBJ convention (v up), see above
    const int32_t* faces;   // [F, 3] counter-clockwise seen from outside, 0-based
    int tex_size;           // S: the textures are S x S
    const float* kd;        // [S, S, 3] diffuse albedo, linear RGB in [0, 1], row 0 = top
    const float* ks;        // [S, S, 3] specular albedo F0, linear RGB in [0, 1]
    const float* kr;        // [S, S]    roughness (GGX alpha = kr^2), in [0, 1]
    const char* name;       // material / mesh name; NULL = "matlaber"
} mlb_asset;

// Checks sizes, index bounds and that every number is finite (textures also in [0, 1] up to
// 1e-6 outside, NaN refused); the message says which array and element.
mlb_status mlb_asset_check(const mlb_asset* a);

// ---- glTF 2.0 binary ----
// One mesh, one triangle primitive (POSITION with min/max, NORMAL unit length, TEXCOORD_0,
// uint32 indices), one material:
//   pbrMetallicRoughness.baseColorTexture          = kd           (sRGB PNG, embedded)
//   pbrMetallicRoughness.metallicFactor            = 0
//   pbrMetallicRoughness.metallicRoughnessTexture  = (R 1, G kr, B 0) (linear PNG), roughnessFactor 1
//   KHR_materials_specular.specularColorTexture    = ks           (sRGB PNG)
//   KHR_materials_specular.specularColorFactor     = (25, 25, 25), specularFactor 1
// so that glTF's dielectric F0 = min(0.04 * specularColorFactor * specularColorTexture, 1) equals
// ks exactly (docs/export.md explains the choice). Textures are 8-bit PNGs encoded exactly as
// mlb_image_write_png does (NaN -> 0, clamp, exact sRGB curve, round half up).
mlb_status mlb_export_glb(const char* path, const mlb_asset* a);
// The same file into memory (*data malloc'd, *n bytes); for callers that embed or test it.
mlb_status mlb_export_glb_memory(const mlb_asset* a, unsigned char** data, size_t* n);

// ---- Wavefront OBJ + MTL ----
// path "dir/name.obj" writes dir/name.obj (v, vt, vn, f v/vt/vn, mtllib, usemtl), dir/name.mtl and
// the textures dir/name_kd.png (sRGB), dir/name_ks.png (sRGB) and dir/name_roughness.png (grey,
// linear). The MTL: Kd 1 1 1, Ks 1 1 1, Ns from the mean roughness, map_Kd, map_Ks, and the PBR
// extension keys Pr 1, map_Pr, Pm 0. Textures, then MTL, then the OBJ: an OBJ that exists names
// complete files; on failure every file this call wrote is removed.
mlb_status mlb_export_obj(const char* path, const mlb_asset* a);

// 8-bit PNG encoding into memory, the same encoding as mlb_image_write_png (srgb: 1 = linear
// values encoded with the sRGB curve and an sRGB chunk; 0 = as is). c = 1..4.
mlb_status mlb_png_encode_memory(const float* data, int w, int h, int c, int srgb, unsigned char** out, size_t* n);

// ---- the static viewer ----
// Writes a self-contained static page into `dir` (created if missing):
//   dir/index.html, dir/viewer.js        copied from the viewer source folder (the repository's viewer/)
//   dir/lib/three/...                    three.js's module build and the addons the page imports
//                                        (GLTFLoader, HDRLoader, OrbitControls and their imports),
//                                        copied from the viewer source folder's node_modules/three,
//                                        which scripts/build.sh installs with npm
//   dir/asset.glb                        the asset
//   dir/env/<name>.hdr                   the environments (built-in maps, Radiance RGBE, turned so
//                                        that three.js sees the same world directions as our renderer)
//   dir/viewer.json                      the list of environments and the asset's name, and
//                                        "decoder" when the folder has the latent editor's files:
//   dir/asset.decoder.json, asset.latent.bin  a latent-mode asset's codes and decoder
//                                        (latent_export.h), copied from beside the .glb or written
//                                        by the caller's write_glb
// The page uses ES modules and fetch(), which browsers refuse from file:// URLs: serve the folder,
// e.g. `python3 -m http.server -d DIR 8000`, and open http://localhost:8000/. Nothing is loaded
// from the network.
typedef struct {
    const char* source_dir;    // the viewer source folder; NULL: search (mlb_viewer_find_source)
    const char* const* envs;   // built-in environment names, NULL-terminated; NULL: sky, studio, overcast
    int env_height;            // rows of the written maps (width 2x); 0 = 256
    const char* title;         // page title; NULL = "matlaber asset"
} mlb_viewer_options;

// Finds the viewer source folder: `hint` if not NULL, else $MATLABER_VIEWER_DIR, else viewer/ or
// share/matlaber/viewer beside or above the running executable (/proc/self/exe), else the
// compile-time MLB_VIEWER_DIR if defined, else the viewer/ folder of the source tree this library was
// compiled from. A folder qualifies when it holds index.html, viewer.js and
// node_modules/three/build/three.module.js. The chosen folder goes to out[n].
mlb_status mlb_viewer_find_source(const char* hint, char* out, size_t n);
// From an existing .glb file (copied) ...
mlb_status mlb_viewer_write(const char* dir, const char* glb_path, const mlb_viewer_options* opt);
// ... or from an asset (written as dir/asset.glb).
mlb_status mlb_viewer_write_asset(const char* dir, const mlb_asset* a, const mlb_viewer_options* opt);
// ... or with dir/asset.glb (and, for a latent-mode asset, its sidecars) written by write_glb(path, ctx).
mlb_status mlb_viewer_write_with(const char* dir, const mlb_viewer_options* opt,
                                 mlb_status (*write_glb)(const char* path, const void* ctx), const void* ctx);
// The same folder without dir/asset.glb: the page, three.js and the environments, for a server that
// puts each asset beside them (matlaber serve, docs/server.md).
mlb_status mlb_viewer_write_page(const char* dir, const mlb_viewer_options* opt);

#endif
