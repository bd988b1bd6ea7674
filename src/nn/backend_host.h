// The op adapters whose work has no real numbers in it (integer topology, scans, coverage flags,
// the light's handle), written once for both CPU tables: MLB_HOST_ADAPTERS(cpu) in backend.c and
// MLB_HOST_ADAPTERS(f64) in backend_f64.c define PREFIX_vertex_faces and the others, static.
#ifndef MATLABER_NN_BACKEND_HOST_H
#define MATLABER_NN_BACKEND_HOST_H
#include "matlaber/error.h"
#include "matlaber/mt_ops.h"
#include "matlaber/raster.h"

#define MLB_HOST_ADAPTERS(P)                                                                                   \
    static mlb_status P##_light_upload(void** handle, const mlb_envlight* light) {                            \
        *handle = (void*)light;                                                                                \
        return MLB_OK;                                                                                         \
    }                                                                                                          \
    static void P##_light_free(void* handle) { (void)handle; }                                                 \
    static mlb_status P##_vertex_faces(int32_t* off, int32_t* vf, const int32_t* faces, int F, int V) {        \
        return mlb_vertex_faces(off, vf, faces, F, V);                                                         \
    }                                                                                                          \
    static mlb_status P##_edge_topology(int32_t* adj, const int32_t* faces, int F, const int32_t* off,         \
                                        const int32_t* vf) {                                                   \
        if (F < 0) return mlb_fail(MLB_ERR_ARG, "edge_topology: %d faces", F);                                 \
        mlb_edge_partners(adj, faces, F, off, vf);                                                             \
        return MLB_OK;                                                                                         \
    }                                                                                                          \
    static mlb_status P##_scan_i32(int32_t* out, const int32_t* in, int n) {                                   \
        if (n < 0) return mlb_fail(MLB_ERR_ARG, "scan of %d values", n);                                       \
        mlb_scan_i32(out, in, n);                                                                              \
        return MLB_OK;                                                                                         \
    }                                                                                                          \
    static mlb_status P##_covered_flags(int32_t* flags, const int32_t* tri, size_t n) {                        \
        mlb_covered_flags(flags, tri, (long)n);                                                                \
        return MLB_OK;                                                                                         \
    }

#endif
