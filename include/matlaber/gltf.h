// glTF 2.0 reading (.gltf with its buffers, or .glb) into a triangle mesh (matlaber/mesh.h), for
// `matlaber paint --mesh` (docs/paint.md, docs/files.md). Only geometry is read:
//  - The default scene (`scene`, else scenes[0]) is walked from its root nodes; every mesh a node
//    holds is placed with the node's world transform (matrix, or translation · rotation · scale,
//    composed down the tree) and all of them are merged into one mesh. A file without scenes
//    uses the nodes no other node names as a child; a file without nodes, every mesh untransformed.
//  - Primitives of mode 4 (triangles), 5 (strip) and 6 (fan), indexed (uint8/16/32) or not, become
//    triangles; points and lines (modes 0-3) have no surface and are skipped (info->n_skipped).
//    A mirroring transform (negative determinant) reverses the winding, as the spec says.
//  - POSITION (float VEC3) is required; NORMAL (float or normalized byte/short VEC3, transformed by
//    the inverse transpose) and TEXCOORD_0 (float or normalized unsigned byte/short VEC2, v flipped
//    to the OBJ convention: v = 1 - v_gltf) are kept only when every primitive has them
//    (info->uv_dropped / normals_dropped say otherwise). Other attributes, materials, images,
//    skins, morph targets and animations are ignored.
//  - A vertex is one of an accessor's elements, as the file has them (no welding); vertices no
//    triangle uses are dropped; order is otherwise kept, so a .glb from mlb_export_glb reads back
//    as the mesh it was written from (positions and faces bitwise, UVs within 6e-8).
//  - Buffers: the .glb's BIN chunk, base64 data: URIs, or files beside the .gltf named by a relative
//    URI (percent-decoded) that stays inside the file's folder (no "..", no absolute path, no scheme;
//    the resolved path, links followed, must be under the folder).
// The file is hostile input: every index, count, offset, stride and length is checked before use
// (with overflow-safe arithmetic), so a malformed file ends in MLB_ERR_FORMAT (or UNSUPPORTED for a
// well-formed feature not read: sparse accessors, Draco, glTF 1.0) with a message naming the file
// and the element: "m.glb: accessors[3]: 120 elements of 12 bytes do not fit bufferViews[1] (1000 bytes)".
// On any error *out is left zeroed.
#ifndef MATLABER_GLTF_H
#define MATLABER_GLTF_H
#include <stddef.h>
#include "matlaber/error.h"
#include "matlaber/mesh.h"

#define MLB_GLTF_MAX_BYTES ((size_t)1 << 30)        // the file plus the buffers it reads
#define MLB_GLTF_MAX_TRIANGLES ((size_t)1 << 26)    // after merging every instance
#define MLB_GLTF_MAX_DEPTH 256                      // node tree depth

typedef struct {
    size_t max_bytes;       // 0 = MLB_GLTF_MAX_BYTES
    size_t max_triangles;   // 0 = MLB_GLTF_MAX_TRIANGLES (MLB_ERR_UNSUPPORTED when exceeded)
    int drop_uv;            // 1: do not keep TEXCOORD_0
    int drop_normals;       // 1: do not keep NORMAL
} mlb_gltf_options;

typedef struct {
    int binary;             // 1: a .glb
    int n_meshes;           // meshes in the file
    int n_instances;        // meshes placed by the scene's nodes (one mesh under two nodes counts twice)
    int n_primitives;       // triangle primitives read, over all instances
    int n_skipped;          // point and line primitives skipped
    int n_mirrored;         // instances whose transform mirrors (winding reversed)
    int n_unused;           // vertices no triangle uses (dropped)
    int uv_dropped;         // 1: some primitives had TEXCOORD_0 and others not; the mesh has none
    int normals_dropped;    // 1: the same for NORMAL
} mlb_gltf_info;

// Reads `path` (.glb or .gltf: told by the content, not the name). opt and info may be NULL.
mlb_status mlb_gltf_load(const char* path, mlb_mesh* out, const mlb_gltf_options* opt, mlb_gltf_info* info);
// The same from memory; `name` stands for the file in messages; `dir` is the folder external buffers
// are read from (NULL: external buffers are refused).
mlb_status mlb_gltf_parse(const unsigned char* data, size_t n, const char* name, const char* dir, mlb_mesh* out,
                          const mlb_gltf_options* opt, mlb_gltf_info* info);

#endif
