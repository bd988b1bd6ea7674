// test_backend_ops's cases for the appearance renderer's sample ops (backend_op_cases.h says how a
// case is made; integer buffers travel as floats holding int32 bits, as in the rasterizer's cases)
// and the affine column map. The coverage of gather_samples is drawn from the case's own seed so
// that setup can size the samples; where holds distinct pixels for the composite (each pixel is
// written once) and repeats for its backward (a gather).
#ifndef MATLABER_BACKEND_OP_CASES_SAMPLES_H
#define MATLABER_BACKEND_OP_CASES_SAMPLES_H
#include "backend_op_cases_raster.h"

// pixel i of a coverage drawn with seed: covered (face id >= 0) with probability 0.6; none on
// trial 0's odd seeds, all on even ones
static int32_t sample_tri(int seed, int i) {
    double u = mlb_rng_uniform_f64((uint64_t)seed, 91, (uint64_t)i);
    return u < 0.6 ? (int32_t)(u * 100) : -1;
}
static int sample_count(int seed, int P) {
    int n = 0;
    for (int i = 0; i < P; i++) n += sample_tri(seed, i) >= 0;
    return n;
}

// covered_flags: flags, tri
static void prep_covered_flags(const op_case* c, float** h) { prep_tri(h[1], c->s[0], 7); }
static void setup_covered_flags(op_case* c, draw* d, int t) {
    c->s[0] = dim(d, t, 5000);
    OUT_("flags", c->s[0], B_BITS);
    IN_("tri", c->s[0], 0, 1);
    c->prep = prep_covered_flags;
    snprintf(c->shape, sizeof c->shape, "n %d", c->s[0]);
}
static mlb_status call_covered_flags(const mlb_backend* be, float** p, const op_case* c) {
    return be->covered_flags((int32_t*)p[0], (const int32_t*)p[1], (size_t)c->s[0]);
}

// gather_samples: pts, nrm, vdir, where, pix, tri, index; s = P, seed, N
static const double sample_eye[3] = {0.4, -1.3, 2.2};
static void prep_gather_samples(const op_case* c, float** h) {
    int P = c->s[0], j = 0;
    for (int i = 0; i < P; i++) {
        int32_t t = sample_tri(c->s[1], i);
        set_i32(h[5] + i, t);
        set_i32(h[6] + i, j);
        j += t >= 0;
    }
    // a pixel at the eye and one with a zero normal: the degenerate branches
    if (P > 2) {
        for (int k = 0; k < 3; k++) h[4][6 * 1 + k] = (float)sample_eye[k], h[4][6 * 2 + 3 + k] = 0;
    }
}
static void setup_gather_samples(op_case* c, draw* d, int t) {
    int P = dim(d, t, 3000);
    c->s[0] = P, c->s[1] = pick(d, 1, 1 << 30);
    c->s[2] = sample_count(c->s[1], P);
    size_t N = c->s[2] ? (size_t)c->s[2] : 1;
    OUT_("pts", 3 * N, B_EXACT);
    OUT_("nrm", 3 * N, B_ELEM);
    OUT_("vdir", 3 * N, B_ELEM);
    OUT_("where", N, B_BITS);
    IN_("pix", 6 * (size_t)P, -1, 1);
    IN_("tri", P, 0, 1);
    IN_("index", P, 0, 1);
    c->prep = prep_gather_samples;
    snprintf(c->shape, sizeof c->shape, "P %d, %d covered", P, c->s[2]);
}
static mlb_status call_gather_samples(const mlb_backend* be, float** p, const op_case* c) {
    if (c->s[2] == 0) {   // nothing covered: nothing written (the outputs are compared as written)
        int32_t w = 0;
        float z[3] = {0, 0, 0};
        MLB_TRY(be->upload(p[0], z, 3)); MLB_TRY(be->upload(p[1], z, 3)); MLB_TRY(be->upload(p[2], z, 3));
        memcpy(z, &w, sizeof w);
        MLB_TRY(be->upload(p[3], z, 1));
    }
    return be->gather_samples(p[0], p[1], p[2], (int32_t*)p[3], p[4], (const int32_t*)p[5], (const int32_t*)p[6],
                              c->s[0], sample_eye[0], sample_eye[1], sample_eye[2]);
}

// composite_srgb: color, rgb, where; s = P, m
static void prep_composite_srgb(const op_case* c, float** h) {
    int P = c->s[0], m = c->s[1], step = P / (m ? m : 1);
    for (int j = 0; j < m; j++) set_i32(h[2] + j, P - 1 - j * step);   // distinct pixels
}
static void setup_composite_srgb(op_case* c, draw* d, int t) {
    int P = dim(d, t, 4000), m = pick(d, t ? 0 : 1, P);
    c->s[0] = P, c->s[1] = m;
    ACC_("color", 4 * (size_t)P, B_ELEM);
    IN_("rgb", 3 * (size_t)(m ? m : 1), -0.2f, 1.3f);   // both clamps and the linear toe
    IN_("where", m ? m : 1, 0, 1);
    c->prep = prep_composite_srgb;
    snprintf(c->shape, sizeof c->shape, "P %d, %d samples", P, m);
}
static mlb_status call_composite_srgb(const mlb_backend* be, float** p, const op_case* c) {
    return be->composite_srgb(p[0], p[1], (const int32_t*)p[2], c->s[1]);
}
// composite_srgb_backward: drgb, dcolor, rgb, where (any pixels, repeats too)
static void prep_composite_srgb_backward(const op_case* c, float** h) {
    for (int j = 0; j < c->s[1]; j++) set_i32(h[3] + j, (int32_t)(h[3][j] * c->s[0]) % c->s[0]);
    for (int j = 0; j < 3 * c->s[1]; j++)
        if (j % 11 == 5) h[2][j] = 0.002f;   // the linear toe
}
static void setup_composite_srgb_backward(op_case* c, draw* d, int t) {
    int P = dim(d, t, 4000), m = pick(d, t ? 0 : 1, 3000);
    c->s[0] = P, c->s[1] = m;
    ACC_("drgb", 3 * (size_t)(m ? m : 1), B_ELEM);
    IN_("dcolor", 4 * (size_t)P, -1, 1);
    IN_("rgb", 3 * (size_t)(m ? m : 1), -0.2f, 1.3f);
    IN_("where", m ? m : 1, 0, 1);
    c->prep = prep_composite_srgb_backward;
    snprintf(c->shape, sizeof c->shape, "P %d, %d samples", P, m);
}
static mlb_status call_composite_srgb_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->composite_srgb_backward(p[0], p[1], p[2], (const int32_t*)p[3], c->s[1]);
}

// downsample_box(_backward): s = H, W, C, factor
static void draw_box(op_case* c, draw* d, int t) {
    c->s[0] = dim(d, t, 40), c->s[1] = dim(d, t, 40), c->s[2] = t ? pick(d, 1, 5) : 1, c->s[3] = t ? pick(d, 1, 4) : 1;
    snprintf(c->shape, sizeof c->shape, "%dx%d x %d, factor %d", c->s[1], c->s[0], c->s[2], c->s[3]);
}
static size_t box_in(const op_case* c) { return (size_t)c->s[0] * c->s[3] * c->s[1] * c->s[3] * c->s[2]; }
static void setup_downsample_box(op_case* c, draw* d, int t) {
    draw_box(c, d, t);
    OUT_("out", (size_t)c->s[0] * c->s[1] * c->s[2], B_ELEM);
    IN_("in", box_in(c), -1, 1);
}
static mlb_status call_downsample_box(const mlb_backend* be, float** p, const op_case* c) {
    return be->downsample_box(p[0], p[1], c->s[0], c->s[1], c->s[2], c->s[3]);
}
static void setup_downsample_box_backward(op_case* c, draw* d, int t) {
    draw_box(c, d, t);
    ACC_("din", box_in(c), B_ELEM);
    IN_("dout", (size_t)c->s[0] * c->s[1] * c->s[2], -1, 1);
}
static mlb_status call_downsample_box_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->downsample_box_backward(p[0], p[1], c->s[0], c->s[1], c->s[2], c->s[3]);
}

// area_resize(_backward): s = n, H, W, C, h, w (reductions by integer and by ragged factors, and
// enlargements)
static void draw_resize(op_case* c, draw* d, int t) {
    c->s[0] = t ? pick(d, 1, 3) : 1, c->s[1] = dim(d, t, 70), c->s[2] = dim(d, t, 70), c->s[3] = t ? pick(d, 1, 4) : 1;
    c->s[4] = t ? pick(d, 1, 24) : 1, c->s[5] = t ? pick(d, 1, 24) : 1;
    snprintf(c->shape, sizeof c->shape, "%d x %dx%d x %d -> %dx%d", c->s[0], c->s[2], c->s[1], c->s[3], c->s[5], c->s[4]);
}
static size_t resize_src(const op_case* c) { return (size_t)c->s[0] * c->s[1] * c->s[2] * c->s[3]; }
static size_t resize_dst(const op_case* c) { return (size_t)c->s[0] * c->s[3] * c->s[4] * c->s[5]; }
static void setup_area_resize(op_case* c, draw* d, int t) {
    draw_resize(c, d, t);
    OUT_("dst", resize_dst(c), B_EXACT);
    IN_("src", resize_src(c), -1, 1);
}
static mlb_status call_area_resize(const mlb_backend* be, float** p, const op_case* c) {
    return be->area_resize(p[0], p[1], c->s[0], c->s[1], c->s[2], c->s[3], c->s[4], c->s[5]);
}
static void setup_area_resize_backward(op_case* c, draw* d, int t) {
    draw_resize(c, d, t);
    OPT_ACC("dsrc", resize_src(c), B_EXACT, t == 3);
    IN_("ddst", resize_dst(c), -1, 1);
}
static mlb_status call_area_resize_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->area_resize_backward(p[0], p[1], c->s[0], c->s[1], c->s[2], c->s[3], c->s[4], c->s[5]);
}

// renders_to_sd(_backward): s = n, H, W, normal
static void draw_renders(op_case* c, draw* d, int t) {
    c->s[0] = t ? pick(d, 1, 3) : 1, c->s[1] = dim(d, t, 90), c->s[2] = dim(d, t, 90), c->s[3] = t % 2;
    snprintf(c->shape, sizeof c->shape, "%d x %dx%d, %s", c->s[0], c->s[2], c->s[1], c->s[3] ? "normal" : "colour");
}
static void setup_renders_to_sd(op_case* c, draw* d, int t) {
    draw_renders(c, d, t);
    OUT_("x", (size_t)c->s[0] * 3 * c->s[1] * c->s[2], B_EXACT);
    IN_("renders", (size_t)c->s[0] * 4 * c->s[1] * c->s[2], -1, 1);
}
static mlb_status call_renders_to_sd(const mlb_backend* be, float** p, const op_case* c) {
    return be->renders_to_sd(p[0], p[1], c->s[0], c->s[1], c->s[2], c->s[3]);
}
static void setup_renders_to_sd_backward(op_case* c, draw* d, int t) {
    draw_renders(c, d, t);
    OPT_ACC("drenders", (size_t)c->s[0] * 4 * c->s[1] * c->s[2], B_EXACT, t == 2);
    IN_("dx", (size_t)c->s[0] * 3 * c->s[1] * c->s[2], -1, 1);
}
static mlb_status call_renders_to_sd_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->renders_to_sd_backward(p[0], p[1], c->s[0], c->s[1], c->s[2], c->s[3]);
}

// axpby_rows: out, x, y; s = B, n
static const float rows_a[5] = {0.99f, 0.5f, -1.25f, 0.0625f, 0.031f}, rows_c[5] = {0.14f, 0.866f, 2.0f, 0.998f, -0.7f};
static void setup_axpby_rows(op_case* c, draw* d, int t) {
    c->s[0] = t ? pick(d, 1, 5) : 1, c->s[1] = dim(d, t, 3000);
    OUT_("out", (size_t)c->s[0] * c->s[1], B_EXACT);
    IN_("x", (size_t)c->s[0] * c->s[1], -2, 2);
    IN_("y", (size_t)c->s[0] * c->s[1], -2, 2);
    snprintf(c->shape, sizeof c->shape, "%d rows of %d", c->s[0], c->s[1]);
}
static mlb_status call_axpby_rows(const mlb_backend* be, float** p, const op_case* c) {
    return be->axpby_rows(p[0], p[1], p[2], c->s[0], (size_t)c->s[1], rows_a, rows_c);
}

// fill_normal: out; s = n, offset, 1: the offset plus 2^32 (the counter's high word)
static void setup_fill_normal(op_case* c, draw* d, int t) {
    c->s[0] = dim(d, t, 5000), c->s[1] = t ? pick(d, 0, 100000) : 0, c->s[2] = t == 3;
    OUT_("out", (size_t)c->s[0], B_ELEM);
    snprintf(c->shape, sizeof c->shape, "%d values from %d%s", c->s[0], c->s[1], c->s[2] ? " + 2^32" : "");
}
static mlb_status call_fill_normal(const mlb_backend* be, float** p, const op_case* c) {
    uint64_t offset = (uint64_t)c->s[1] + (c->s[2] ? 1ull << 32 : 0);
    return be->fill_normal(p[0], (size_t)c->s[0], 0x123456789ull, 0x5D5100000007ull, offset);
}

// sds_grad: eps (in place: compared as an increment), grad, dz, sumsq, noise; s = B, n, div 1 or 3
static void setup_sds_grad(op_case* c, draw* d, int t) {
    c->s[0] = t ? pick(d, 1, 5) : 1, c->s[1] = dim(d, t, 3000), c->s[2] = t % 2 ? 3 : 1;
    size_t nall = (size_t)c->s[0] * c->s[1];
    ACC_("eps", 2 * nall, B_EXACT);
    OUT_("grad", nall, B_EXACT);
    OPT_OUT("dz", nall, B_EXACT, t == 2);
    OUT_("sumsq", 3, B_SUMS);
    IN_("noise", nall, -1.5f, 1.5f);
    snprintf(c->shape, sizeof c->shape, "%d rows of %d, dz / %d", c->s[0], c->s[1], c->s[2]);
}
static mlb_status call_sds_grad(const mlb_backend* be, float** p, const op_case* c) {
    static const float w[5] = {1.0f, 0.37f, 12.5f, 0.0f, 2.0f};
    return be->sds_grad(p[0], p[1], p[2], p[3], p[4], c->s[0], (size_t)c->s[1], 7.5f, w, (float)c->s[2],
                        c->s[2] == 1 ? 0.0913f : 1.0f);
}

// affine_columns: y, x; s = n, C, in_float
static void setup_affine_columns(op_case* c, draw* d, int t) {
    c->s[0] = dim(d, t, 3000), c->s[1] = t ? pick(d, 1, 8) : 1, c->s[2] = t % 2;
    OUT_("y", (size_t)c->s[0] * c->s[1], B_ELEM);
    IN_("x", (size_t)c->s[0] * c->s[1], -2, 2);
    snprintf(c->shape, sizeof c->shape, "n %d, %d columns%s", c->s[0], c->s[1], c->s[2] ? ", in float" : "");
}
static mlb_status call_affine_columns(const mlb_backend* be, float** p, const op_case* c) {
    static const double scale[8] = {0.5, -2.0, 1.0 / 3.0, 0.96, 1e-3, 7.25, -0.1, 1.0};
    static const double shift[8] = {0.5, 0.04, -1.0, 0.0, 1e-4, 2.0 / 3.0, 3.0, -0.25};
    return be->affine_columns(p[0], p[1], (size_t)c->s[0], c->s[1], scale, c->s[0] % 3 ? shift : NULL, c->s[2]);
}
#endif
