// Painting a given mesh (`matlaber paint`, docs/paint.md): the appearance stage alone on a mesh from
// outside. The mesh is hostile input, so it is loaded through checks that end in a clear error
// naming the file (nothing written) or in a documented repair; its vertices, faces and UVs are kept;
// it is moved into the generation frame for the cameras (centred, farthest vertex at 0.9) and the
// exported asset is baked back onto the original positions.
#ifndef MATLABER_PAINT_H
#define MATLABER_PAINT_H
#include <stddef.h>
#include "matlaber/error.h"
#include "matlaber/material_net.h"
#include "matlaber/mesh.h"
#include "matlaber/raster.h"

#define MLB_PAINT_MAX_FACES (1 << 22)          // 4M triangles: more is refused (the rasteriser's cost)
#define MLB_PAINT_MAX_BYTES ((size_t)1 << 29)  // 512 MiB of mesh file (OBJ text, or glTF and its buffers)
#define MLB_PAINT_RADIUS 0.9                   // the generation frame's radius (catalogue.h)
#define MLB_PAINT_UV_TOL 1e-4                  // UVs this far outside [0, 1] are still accepted (clamped)

typedef struct {
    int n_verts, n_faces;       // of the loaded mesh (the reader's vertices: distinct v/vt/vn corners)
    int has_uv;                 // the mesh keeps the file's UVs
    int n_degenerate;           // faces of zero area (kept: they cover no pixel and no texel)
    int n_normals_repaired;     // vn that were zero-length, replaced by area-weighted normals
    int normals_computed;       // the file had no (complete) vn: area-weighted over welded positions
    int n_polygons_split;       // f with more than 3 corners, fanned
    int n_unused_positions;     // v that no face uses (dropped, as the reader does)
} mlb_paint_mesh_info;

// Loads an OBJ, .glb or .gltf (told by the name's extension; gltf.h) for painting. keep_uv = 1: the
// file's UVs are kept (an error when only some faces have them or when they leave [0, 1]); 0: they
// are dropped (an atlas is made at export).
// Errors (MLB_ERR_FORMAT / UNSUPPORTED / ARG, each naming the file): what the OBJ reader refuses
// (syntax, index out of range, non-finite numbers, files over MLB_PAINT_MAX_BYTES), no faces, more
// than MLB_PAINT_MAX_FACES faces, no face with area, a mesh without extent; for glTF what
// mlb_gltf_load refuses. *out zeroed on error.
mlb_status mlb_paint_load_mesh(const char* path, int keep_uv, mlb_mesh* out, mlb_paint_mesh_info* info);
// The generation frame of a mesh: normalised = (p − centre) · scale, with centre the bounding box's
// centre and scale putting the farthest vertex at MLB_PAINT_RADIUS. Computed in double.
mlb_status mlb_paint_frame(const mlb_mesh* m, double centre[3], double* scale);
// n points [n,3] into the frame (out may equal in).
void mlb_paint_to_frame(const double centre[3], double scale, const float* in, float* out, size_t n);
// A paint run's material field, which lives in the frame, at points of the mesh's own coordinates:
// an mlb_material_fn (render.h) with user = an mlb_framed_material (baking, comparison renders).
typedef struct { const mlb_material_net* net; const double* centre; double scale; } mlb_framed_material;
mlb_status mlb_framed_material_eval(void* user, const float* pos, size_t n, float* k);
// The same for the latent codes [n,4] of a latent-mode field (the viewer's editor).
mlb_status mlb_framed_material_eval_latent(void* user, const float* pos, size_t n, float* z);
// A camera of the mesh's own coordinates (image guidance: the views were taken of the mesh as given)
// moved into the frame with it: eye and target to (p − centre) · scale, near and far times scale, the
// same orientation and field of view, so the image of the moved mesh is the image of the original.
mlb_status mlb_paint_frame_camera(const double centre[3], double scale, mlb_camera* cam);
// An exact copy of a loaded mesh as OBJ (v, vt, vn with 9 significant digits, one vertex per line,
// faces v/vt/vn): read back by mlb_obj_load it gives the same vertices in the same order. Atomic.
mlb_status mlb_paint_write_obj(const char* path, const mlb_mesh* m);

#endif
