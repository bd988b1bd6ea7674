// test_backend_ops's cases for the surface's clip coordinates and vertex normals (backend_op_cases.h
// says how a case is made). Meshes as the rasterizer's cases draw them (backend_op_cases_raster.h:
// random vertices, so faces overlap, repeat a vertex or have no area, and some vertices belong to
// no face); off and vf from the host's mlb_vertex_faces. Every output has a bound of 0 on every
// table: the CUDA kernels run the CPU's maths (render/raster_math.h, mesh/vertex_normals_math.h)
// without fused multiply-adds, and the gathers add in the CPU's face order.
#ifndef MATLABER_BACKEND_OP_CASES_SURFACE_H
#define MATLABER_BACKEND_OP_CASES_SURFACE_H
#include "backend_op_cases.h"
#include "backend_op_cases_mt.h"
#include "backend_op_cases_raster.h"
#include "matlaber/mt_ops.h"

// A view-projection matrix of the case's own: a perspective look-at from s[2] (an angle index)
static mlb_mat4 surface_matrix(const op_case* c) {
    double a = 0.37 * c->s[2], eye[3] = {2.5 * cos(a), 0.8 - 0.1 * c->s[2], 2.5 * sin(a)};
    double target[3] = {0.1, 0, -0.05}, up[3] = {0, 1, 0};
    mlb_mat4 view, proj, none = {{0}};
    if (mlb_look_at(&view, eye, target, up) != MLB_OK || mlb_perspective(&proj, 45.0 + c->s[2], 1.0, 0.1, 10.0) != MLB_OK)
        return none;
    return mlb_mat4_mul(&proj, &view);
}

// transform_points(_backward): s = V, -, angle
static void draw_points(op_case* c, draw* d, int t) {
    c->s[0] = t == 3 ? 0 : dim(d, t, 5000), c->s[2] = pick(d, 0, 9);
    snprintf(c->shape, sizeof c->shape, "V %d, view %d", c->s[0], c->s[2]);
}
static void setup_transform_points(op_case* c, draw* d, int t) {
    draw_points(c, d, t);
    OUT_("clip", 4 * at_least_1(c->s[0]), B_EXACT);
    IN_("pos", 3 * at_least_1(c->s[0]), -1, 1);
}
static mlb_status call_transform_points(const mlb_backend* be, float** p, const op_case* c) {
    return be->transform_points(p[0], p[1], c->s[0], surface_matrix(c).m);
}
static void setup_transform_points_backward(op_case* c, draw* d, int t) {
    draw_points(c, d, t);
    OPT_ACC("dpos", 3 * at_least_1(c->s[0]), B_EXACT, t == 2);
    IN_("dclip", 4 * at_least_1(c->s[0]), -1, 1);
}
static mlb_status call_transform_points_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->transform_points_backward(p[0], p[1], c->s[0], surface_matrix(c).m);
}

// vertex_faces, vertex_normals(_backward): s = V, F
static void draw_surface(op_case* c, draw* d, int t) {
    c->s[0] = t ? pick(d, 1, 700) : 1;
    c->s[1] = t == 3 ? 0 : t ? dim(d, t, 1500) : 1;
    snprintf(c->shape, sizeof c->shape, "V %d F %d", c->s[0], c->s[1]);
}
// faces, off and vf as the next inputs, their first index kept in s[2]; prep_surface draws the faces
// and makes off and vf from them with the host's mlb_vertex_faces
static void surface_inputs(op_case* c) {
    c->s[2] = IN_("faces", 3 * at_least_1(c->s[1]), 0, 1);
    IN_("off", (size_t)c->s[0] + 1, 0, 1);
    IN_("vf", 3 * at_least_1(c->s[1]), 0, 1);
}
static void prep_surface(const op_case* c, float** h) {
    float *faces = h[c->s[2]], *off = h[c->s[2] + 1], *vf = h[c->s[2] + 2];
    prep_faces(faces, c->s[1], c->s[0]);
    if (mlb_vertex_faces((int32_t*)off, (int32_t*)vf, (const int32_t*)faces, c->s[1], c->s[0]) != MLB_OK)
        abort();   // (prep_faces keeps every vertex in range: it cannot fail)
}

// vertex_faces: off, vf, faces
static void prep_vertex_faces(const op_case* c, float** h) { prep_faces(h[2], c->s[1], c->s[0]); }
static void setup_vertex_faces(op_case* c, draw* d, int t) {
    draw_surface(c, d, t);
    OUT_("off", (size_t)c->s[0] + 1, B_BITS);
    OUT_("vf", 3 * at_least_1(c->s[1]), B_BITS);
    IN_("faces", 3 * at_least_1(c->s[1]), 0, 1);
    c->prep = prep_vertex_faces;
}
static mlb_status call_vertex_faces(const mlb_backend* be, float** p, const op_case* c) {
    return be->vertex_faces((int32_t*)p[0], (int32_t*)p[1], (const int32_t*)p[2], c->s[1], c->s[0]);
}

// edge_topology: adj, faces, off, vf (faces on few vertices: many shared and non-manifold edges)
static void setup_edge_topology(op_case* c, draw* d, int t) {
    draw_surface(c, d, t);
    if (t == 1) {   // a crowded mesh
        c->s[0] = 1 + c->s[0] % 9;
        snprintf(c->shape, sizeof c->shape, "V %d F %d", c->s[0], c->s[1]);
    }
    OUT_("adj", 3 * at_least_1(c->s[1]), B_BITS);
    surface_inputs(c);
    c->prep = prep_surface;
}
static mlb_status call_edge_topology(const mlb_backend* be, float** p, const op_case* c) {
    return be->edge_topology((int32_t*)p[0], (const int32_t*)p[1], c->s[1], (const int32_t*)p[2], (const int32_t*)p[3]);
}

// vertex_normals: normal, sum (NULL on trial 2), pos, faces, off, vf
static void setup_vertex_normals(op_case* c, draw* d, int t) {
    draw_surface(c, d, t);
    OUT_("normal", 3 * (size_t)c->s[0], B_EXACT);
    OPT_OUT("sum", 3 * (size_t)c->s[0], B_EXACT, t == 2);
    IN_("pos", 3 * (size_t)c->s[0], -1, 1);
    surface_inputs(c);
    c->prep = prep_surface;
}
static mlb_status call_vertex_normals(const mlb_backend* be, float** p, const op_case* c) {
    return be->vertex_normals(p[0], p[1], p[2], c->s[0], (const int32_t*)p[3], (const int32_t*)p[4],
                              (const int32_t*)p[5]);
}

// vertex_normals_backward: dpos (NULL on trial 2: nothing happens), dnormal, sum (the forward's), pos, faces, off, vf
static void prep_vertex_normals_backward(const op_case* c, float** h) {
    prep_surface(c, h);
    float* normal = malloc(sizeof(float) * 3 * (size_t)c->s[0]);
    if (normal) vertex_normals_forward(normal, h[2], h[3], c->s[0], (const int32_t*)h[4], c->s[1]);
    free(normal);
}
static void setup_vertex_normals_backward(op_case* c, draw* d, int t) {
    draw_surface(c, d, t);
    OPT_ACC("dpos", 3 * (size_t)c->s[0], B_EXACT, t == 2);
    IN_("dnormal", 3 * (size_t)c->s[0], -1, 1);
    IN_("sum", 3 * (size_t)c->s[0], -1, 1);
    IN_("pos", 3 * (size_t)c->s[0], -1, 1);
    surface_inputs(c);
    c->prep = prep_vertex_normals_backward;
}
static mlb_status call_vertex_normals_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->vertex_normals_backward(p[0], p[1], p[2], p[3], c->s[0], (const int32_t*)p[4], (const int32_t*)p[5],
                                       (const int32_t*)p[6]);
}
#endif
