// test_backend_ops's cases for the rasterizer's ops (backend_op_cases.h says how a case is made).
// Integer buffers (faces, tri) travel as floats holding int32 bits: drawn uniform, then rewritten
// by the case's prep; an int32 output is compared bit for bit (B_BITS).
#ifndef MATLABER_BACKEND_OP_CASES_RASTER_H
#define MATLABER_BACKEND_OP_CASES_RASTER_H
#include "backend_op_cases.h"
#include "matlaber/raster.h"

// s = V, F, H, W (and C for interpolate)
static void draw_mesh(op_case* c, draw* d, int t) {
    c->s[0] = t ? pick(d, 3, 60) : 3;
    c->s[1] = dim(d, t, 90);
    c->s[2] = dim(d, t, 45);
    c->s[3] = dim(d, t, 45);
    c->s[4] = dim(d, t, 5);
    snprintf(c->shape, sizeof c->shape, "V %d F %d %dx%d C %d", c->s[0], c->s[1], c->s[3], c->s[2], c->s[4]);
}
static void set_i32(float* dst, int32_t v) { memcpy(dst, &v, sizeof v); }
// faces: random vertices of V (u in [0, 1) -> index), so faces overlap and some repeat (depth ties)
static void prep_faces(float* f, int F, int V) {
    for (int i = 0; i < 3 * F; i++) {
        int k = (int)(f[i] * V);
        set_i32(f + i, k < 0 ? 0 : k >= V ? V - 1 : k);
    }
}
// clip from uniforms in [-1, 1): mostly inside the view (|x|, |y| <= 1.1 w, |z| <= 0.9 w, w in
// [0.5, 1.5]); every fifth vertex behind the camera and every seventh past the near plane, so some
// faces are clipped.
static void prep_clip(float* p, int V) {
    for (int v = 0; v < V; v++) {
        float* r = p + 4 * v;
        float w = 1.0f + 0.5f * r[3];
        r[0] = 1.1f * r[0] * w, r[1] = 1.1f * r[1] * w, r[2] = 0.9f * r[2] * w, r[3] = w;
        if (v % 5 == 4) r[3] = -0.5f * w;
        else if (v % 7 == 6) r[2] = -1.5f * w;
    }
}
// tri: face ids in [-1, F) (empty pixels too)
static void prep_tri(float* t, int n, int F) {
    for (int i = 0; i < n; i++) {
        int k = (int)(t[i] * (F + 1)) - 1;
        set_i32(t + i, k < -1 ? -1 : k >= F ? F - 1 : k);
    }
}

// rasterize: tri, bary, depth, clip, faces
static void prep_rasterize(const op_case* c, float** h) {
    prep_clip(h[3], c->s[0]);
    prep_faces(h[4], c->s[1], c->s[0]);
}
static void setup_rasterize(op_case* c, draw* d, int t) {
    draw_mesh(c, d, t);
    size_t n = (size_t)c->s[2] * c->s[3];
    OUT_("tri", n, B_BITS);
    OPT_OUT("bary", 2 * n, B_EXACT, t == 2);
    OPT_OUT("depth", n, B_EXACT, t == 3);
    IN_("clip", 4 * (size_t)c->s[0], -1, 1);
    IN_("faces", 3 * (size_t)c->s[1], 0, 1);
    c->prep = prep_rasterize;
}
static mlb_status call_rasterize(const mlb_backend* be, float** p, const op_case* c) {
    return be->rasterize((int32_t*)p[0], p[1], p[2], p[3], c->s[0], (const int32_t*)p[4], c->s[1], c->s[2], c->s[3]);
}

// rasterize_backward: dclip, dbary, ddepth, tri, clip, faces
static void prep_rasterize_backward(const op_case* c, float** h) {
    prep_tri(h[3], c->s[2] * c->s[3], c->s[1]);
    prep_clip(h[4], c->s[0]);
    prep_faces(h[5], c->s[1], c->s[0]);
}
static void setup_rasterize_backward(op_case* c, draw* d, int t) {
    draw_mesh(c, d, t);
    size_t n = (size_t)c->s[2] * c->s[3];
    ACC_("dclip", 4 * (size_t)c->s[0], B_SUMS);
    OPT_IN("dbary", 2 * n, -1, 1, t == 2);
    OPT_IN("ddepth", n, -1, 1, t == 3);
    IN_("tri", n, 0, 1);
    IN_("clip", 4 * (size_t)c->s[0], -1, 1);
    IN_("faces", 3 * (size_t)c->s[1], 0, 1);
    c->prep = prep_rasterize_backward;
}
static mlb_status call_rasterize_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->rasterize_backward(p[0], p[1], p[2], (const int32_t*)p[3], p[4], c->s[0], (const int32_t*)p[5], c->s[1],
                                  c->s[2], c->s[3]);
}

// interpolate: out, attr, tri, bary, faces
static void prep_interpolate(const op_case* c, float** h) {
    prep_tri(h[2], c->s[2] * c->s[3], c->s[1]);
    prep_faces(h[4], c->s[1], c->s[0]);
}
static void setup_interpolate(op_case* c, draw* d, int t) {
    draw_mesh(c, d, t);
    size_t n = (size_t)c->s[2] * c->s[3];
    OUT_("out", n * c->s[4], B_EXACT);
    IN_("attr", (size_t)c->s[0] * c->s[4], -1, 1);
    IN_("tri", n, 0, 1);
    IN_("bary", 2 * n, 0, 1);
    IN_("faces", 3 * (size_t)c->s[1], 0, 1);
    c->prep = prep_interpolate;
}
static mlb_status call_interpolate(const mlb_backend* be, float** p, const op_case* c) {
    return be->interpolate(p[0], p[1], c->s[0], c->s[4], (const int32_t*)p[2], p[3], (const int32_t*)p[4], c->s[1],
                           c->s[2], c->s[3]);
}

// interpolate_backward: dattr, dbary, dout, attr, tri, bary, faces
static void prep_interpolate_backward(const op_case* c, float** h) {
    prep_tri(h[4], c->s[2] * c->s[3], c->s[1]);
    prep_faces(h[6], c->s[1], c->s[0]);
}
static void setup_interpolate_backward(op_case* c, draw* d, int t) {
    draw_mesh(c, d, t);
    size_t n = (size_t)c->s[2] * c->s[3];
    OPT_ACC("dattr", (size_t)c->s[0] * c->s[4], B_SUMS, t == 2);
    OPT_ACC("dbary", 2 * n, B_EXACT, t == 3);
    IN_("dout", n * c->s[4], -1, 1);
    IN_("attr", (size_t)c->s[0] * c->s[4], -1, 1);
    IN_("tri", n, 0, 1);
    IN_("bary", 2 * n, 0, 1);
    IN_("faces", 3 * (size_t)c->s[1], 0, 1);
    c->prep = prep_interpolate_backward;
}
static mlb_status call_interpolate_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->interpolate_backward(p[0], p[1], p[2], p[3], c->s[0], c->s[4], (const int32_t*)p[4], p[5],
                                    (const int32_t*)p[6], c->s[1], c->s[2], c->s[3]);
}

// antialias: a rasterized random mesh (tri and depth from the CPU's mlb_rasterize, adj from
// mlb_edge_topology, made on the host by the prep so every table gets the same ones)
static void prep_aa_mesh(const op_case* c, float* tri, float* depth, float* clip, float* faces, float* adj) {
    int V = c->s[0], F = c->s[1], H = c->s[2], W = c->s[3];
    prep_clip(clip, V);
    prep_faces(faces, F, V);
    mlb_status s = mlb_edge_topology((int32_t*)adj, (const int32_t*)faces, F, V);
    if (s == MLB_OK) s = mlb_rasterize(NULL, (int32_t*)tri, NULL, depth, NULL, clip, V, (const int32_t*)faces, F, H, W);
    (void)s;   // valid by construction; the op then fails visibly if not
}
// out, weights, color, tri, depth, clip, faces, adj
static void prep_antialias(const op_case* c, float** h) { prep_aa_mesh(c, h[3], h[4], h[5], h[6], h[7]); }
static void setup_antialias(op_case* c, draw* d, int t) {
    draw_mesh(c, d, t);
    size_t n = (size_t)c->s[2] * c->s[3];
    OUT_("out", n * c->s[4], B_EXACT);
    OPT_OUT("weights", 2 * n, B_EXACT, t == 2);
    IN_("color", n * c->s[4], -1, 1);
    IN_("tri", n, 0, 1);
    IN_("depth", n, 0, 1);
    IN_("clip", 4 * (size_t)c->s[0], -1, 1);
    IN_("faces", 3 * (size_t)c->s[1], 0, 1);
    IN_("adj", 3 * (size_t)c->s[1], 0, 1);
    c->prep = prep_antialias;
}
static mlb_status call_antialias(const mlb_backend* be, float** p, const op_case* c) {
    return be->antialias(p[0], p[1], p[2], c->s[4], (const int32_t*)p[3], p[4], p[5], c->s[0], (const int32_t*)p[6],
                         (const int32_t*)p[7], c->s[1], c->s[2], c->s[3]);
}
// dcolor, dclip, dout, weights, color, tri, depth, clip, faces, adj; weights (when given) the
// forward's, computed here on the CPU
static void prep_antialias_backward(const op_case* c, float** h) {
    prep_aa_mesh(c, h[5], h[6], h[7], h[8], h[9]);
    if (!h[3]) return;
    float* out = malloc((size_t)c->s[2] * c->s[3] * c->s[4] * sizeof(float));
    if (out)
        (void)mlb_antialias(NULL, out, h[3], h[4], c->s[4], (const int32_t*)h[5], h[6], h[7], c->s[0],
                            (const int32_t*)h[8], (const int32_t*)h[9], c->s[1], c->s[2], c->s[3]);
    free(out);
}
static void setup_antialias_backward(op_case* c, draw* d, int t) {
    draw_mesh(c, d, t);
    size_t n = (size_t)c->s[2] * c->s[3];
    OPT_ACC("dcolor", n * c->s[4], B_EXACT, t == 2);
    OPT_ACC("dclip", 4 * (size_t)c->s[0], B_SUMS, t == 3);
    IN_("dout", n * c->s[4], -1, 1);
    OPT_IN("weights", 2 * n, 0, 1, t == 1);
    IN_("color", n * c->s[4], -1, 1);
    IN_("tri", n, 0, 1);
    IN_("depth", n, 0, 1);
    IN_("clip", 4 * (size_t)c->s[0], -1, 1);
    IN_("faces", 3 * (size_t)c->s[1], 0, 1);
    IN_("adj", 3 * (size_t)c->s[1], 0, 1);
    c->prep = prep_antialias_backward;
}
static mlb_status call_antialias_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->antialias_backward(p[0], p[1], p[2], p[3], p[4], c->s[4], (const int32_t*)p[5], p[6], p[7], c->s[0],
                                  (const int32_t*)p[8], (const int32_t*)p[9], c->s[1], c->s[2], c->s[3]);
}

#endif
