// Wavefront OBJ reading into a unified triangle mesh (matlaber/mesh.h). docs/files.md lists the
// subset, the repairs and the errors. In short:
//  - v (3 numbers; a 4th w and trailing vertex colours are ignored), vt (1-3 numbers; only u, v
//    are kept, a missing v is 0), vn (3 numbers, kept as written), f with corners v, v/vt, v//vn
//    or v/vt/vn, positive or negative (relative) indices referring to earlier elements.
//  - Polygons with more than 3 corners are split into a fan around their first corner (exact for
//    convex polygons, which is what exporters write).
//  - A vertex of the result is one distinct (position, uv, normal) index triple; vertices appear in
//    the order the faces first use them, and positions no face uses are dropped.
//  - uv (normals) are kept only if every corner of every face has one; otherwise the mesh gets
//    none (info->uv_dropped / normals_dropped say so) and vertices are unified without them.
//  - o, g, s, usemtl, mtllib, l, p and other non-geometry statements are ignored; free-form
//    geometry (curv, curv2, surf) is refused as unsupported, since its geometry would be lost.
// Errors name the file and the line: "path: line 12: vertex index 9 out of range (8 defined)".
// On any error *out is left zeroed: nothing half-built is returned.
#ifndef MATLABER_OBJ_H
#define MATLABER_OBJ_H
#include <stddef.h>
#include "matlaber/error.h"
#include "matlaber/mesh.h"

// Defaults for the limits below (0 in an options field means the default).
#define MLB_OBJ_MAX_BYTES ((size_t)1 << 30)       // 1 GiB file
#define MLB_OBJ_MAX_LINE 65536                     // bytes in one statement (continuations joined)
#define MLB_OBJ_MAX_TRIANGLES ((size_t)1 << 26)   // 67M triangles after triangulation

typedef struct {
    size_t max_bytes;       // refuse larger files (MLB_ERR_UNSUPPORTED); 0 = MLB_OBJ_MAX_BYTES
    size_t max_line;        // refuse longer statements (MLB_ERR_FORMAT); 0 = MLB_OBJ_MAX_LINE
    size_t max_triangles;   // refuse more triangles (MLB_ERR_UNSUPPORTED); 0 = MLB_OBJ_MAX_TRIANGLES
    int drop_uv;            // 1: do not keep uv even when every corner has one
    int drop_normals;       // 1: do not keep vn normals (mlb_mesh_compute_normals can make them)
} mlb_obj_options;

// What was in the file, for callers who want to report or check it. Counts are statements read.
typedef struct {
    int n_lines;                  // lines in the file
    int n_positions, n_texcoords, n_normals;   // v, vt, vn statements
    int n_polygons;               // f statements
    int n_triangles;              // triangles after the fan split (= out->n_faces)
    int n_polygons_split;         // f statements with more than 3 corners
    int n_ignored;                // statements skipped (o, g, s, usemtl, l, p, unknown keywords)
    int n_unused_positions;       // v entries that no face uses (absent from the result)
    int uv_dropped;               // 1: some corners had vt and others not; the mesh has no uv
    int normals_dropped;          // 1: same for vn
    char mtllib[256];             // first mtllib argument ("" when none); truncated if longer
} mlb_obj_info;

// Loads `path` with default options; `out` is overwritten (not freed first).
mlb_status mlb_obj_load(const char* path, mlb_mesh* out);
// Same with options and info (either may be NULL).
mlb_status mlb_obj_load_ex(const char* path, mlb_mesh* out, const mlb_obj_options* opt, mlb_obj_info* info);
// Parses `n` bytes of OBJ text from memory (need not be NUL-terminated); `name` stands for the
// file in messages.
mlb_status mlb_obj_parse(const char* text, size_t n, const char* name, mlb_mesh* out,
                         const mlb_obj_options* opt, mlb_obj_info* info);

#endif
