// test_backend_ops's cases for marching tetrahedra's ops (backend_op_cases.h says how a case is
// made): a tet grid of 1 to 5 cells per axis (mlb_tetgrid) and an SDF drawn from the case's own
// seed, so that setup can size the outputs from the surface it will make: ragged (uniform in
// [-1, 1]), all inside (<= 0, zeros included), all outside, and a sphere with noise and exact zeros
// (sdf = 0 is inside). Integer buffers travel as floats holding int32 bits and are compared bit
// for bit; every float output has a bound of 0 on every table (the CUDA kernels run the CPU's
// maths without fused multiply-adds, and the backward adds in the CPU's order).
#ifndef MATLABER_BACKEND_OP_CASES_MT_H
#define MATLABER_BACKEND_OP_CASES_MT_H
#include "backend_op_cases.h"
#include "matlaber/dmtet.h"
#include "matlaber/mt_ops.h"

enum { MT_RAGGED, MT_INSIDE, MT_OUTSIDE, MT_SPHERE };
static const char* mt_mode_name[] = {"ragged", "all inside", "all outside", "sphere with zeros"};

// s = cells, mode, seed, nv, nf, V, T
static void mt_sdf(float* sdf, const op_case* c) {
    int n = c->s[0] + 1, mode = c->s[1];
    for (int v = 0; v < n * n * n; v++) {
        float u = (float)mlb_rng_uniform_f64((uint64_t)c->s[2], 77, (uint64_t)v);
        float x = (float)(v % n) / (n - 1) - 0.5f, y = (float)((v / n) % n) / (n - 1) - 0.5f;
        float z = (float)(v / (n * n)) / (n - 1) - 0.5f;
        switch (mode) {
        case MT_INSIDE: sdf[v] = u < 0.2f ? 0.0f : -u; break;
        case MT_OUTSIDE: sdf[v] = 0.01f + u; break;
        case MT_SPHERE: sdf[v] = u < 0.15f ? 0.0f : sqrtf(x * x + y * y + z * z) - 0.35f + 0.2f * (u - 0.5f); break;
        default: sdf[v] = 2 * u - 1;
        }
    }
}
// The grid's tets, the SDF and the scanned counts (any output pointer may be NULL); 0 on failure.
static int mt_problem(const op_case* c, float* sdf_out, float* tets_out, int32_t* tet_off_out, int32_t* slot_off_out) {
    mlb_tetgrid g;
    if (mlb_tetgrid_create(&g, c->s[0], 1.0f) != MLB_OK) return 0;
    int V = g.n_verts, T = g.n_tets;
    float* sdf = malloc(sizeof(float) * V);
    int32_t* tet_off = malloc(sizeof(int32_t) * (T + 1));
    int32_t* slot_off = malloc(sizeof(int32_t) * (7 * (size_t)V + 1));
    int ok = sdf && tet_off && slot_off;
    if (ok) {
        mt_sdf(sdf, c);
        mlb_mt_count(tet_off, slot_off, sdf, g.tets, T, g.cells);
        mlb_scan_i32(tet_off, tet_off, T);
        mlb_scan_i32(slot_off, slot_off, 7 * V);
        if (sdf_out) memcpy(sdf_out, sdf, sizeof(float) * V);
        if (tets_out) memcpy(tets_out, g.tets, sizeof(int32_t) * 4 * (size_t)T);
        if (tet_off_out) memcpy(tet_off_out, tet_off, sizeof(int32_t) * (T + 1));
        if (slot_off_out) memcpy(slot_off_out, slot_off, sizeof(int32_t) * (7 * (size_t)V + 1));
    }
    free(sdf), free(tet_off), free(slot_off);
    mlb_tetgrid_free(&g);
    return ok;
}
// The shape of trial t in the given mode: cells 1 on trial 0, else 1 to 5; nv and nf of its surface.
static void mt_draw(op_case* c, draw* d, int t, int mode) {
    int cells = t ? pick(d, 1, 5) : 1, n = cells + 1;
    c->s[0] = cells, c->s[1] = mode, c->s[2] = pick(d, 1, 1 << 30);
    c->s[5] = n * n * n, c->s[6] = 6 * cells * cells * cells;
    int32_t* tet_off = malloc(sizeof(int32_t) * (c->s[6] + 1));
    int32_t* slot_off = malloc(sizeof(int32_t) * (7 * (size_t)c->s[5] + 1));
    c->s[3] = c->s[4] = 0;
    if (tet_off && slot_off && mt_problem(c, NULL, NULL, tet_off, slot_off))
        c->s[3] = slot_off[7 * (size_t)c->s[5]], c->s[4] = tet_off[c->s[6]];
    free(tet_off), free(slot_off);
    snprintf(c->shape, sizeof c->shape, "%d cells, %s: %d vertices, %d faces", cells, mt_mode_name[mode], c->s[3],
             c->s[4]);
}
static size_t at_least_1(int n) { return n > 0 ? (size_t)n : 1; }

// marching_tets_count: tet_nf, slot_nv, sdf, tets
static void prep_marching_tets_count(const op_case* c, float** h) { (void)mt_problem(c, h[2], h[3], NULL, NULL); }
static void setup_marching_tets_count(op_case* c, draw* d, int t) {
    mt_draw(c, d, t, t % 4);
    OUT_("tet_nf", c->s[6], B_BITS);
    OUT_("slot_nv", 7 * (size_t)c->s[5], B_BITS);
    IN_("sdf", c->s[5], -1, 1);
    IN_("tets", 4 * (size_t)c->s[6], 0, 1);
    c->prep = prep_marching_tets_count;
}
static mlb_status call_marching_tets_count(const mlb_backend* be, float** p, const op_case* c) {
    return be->marching_tets_count((int32_t*)p[0], (int32_t*)p[1], p[2], (const int32_t*)p[3], c->s[6], c->s[0]);
}

// scan_i32: out [n + 1], in [n] (NULL on odd trials: the scan runs in place on out, which then
// holds the counts); counts 0..7, n up to 70000 (many 1024-value tiles on the GPU)
static void prep_scan_i32(const op_case* c, float** h) {
    float* in = h[1] ? h[1] : h[0];
    for (int i = 0; i < c->s[0]; i++) {
        int32_t k = (int32_t)(mlb_rng_uniform_f64((uint64_t)c->s[1], 78, (uint64_t)i) * 8);
        memcpy(in + i, &k, sizeof k);
    }
}
static void setup_scan_i32(op_case* c, draw* d, int t) {
    c->s[0] = t == 3 ? pick(d, 1025, 70000) : t == 2 ? 0 : dim(d, t, 5000);
    c->s[1] = pick(d, 1, 1 << 30);
    OUT_("out", (size_t)c->s[0] + 1, B_BITS);
    OPT_IN("in", at_least_1(c->s[0]), 0, 1, t % 2);
    c->prep = prep_scan_i32;
    snprintf(c->shape, sizeof c->shape, "n %d%s", c->s[0], t % 2 ? " in place" : "");
}
static mlb_status call_scan_i32(const mlb_backend* be, float** p, const op_case* c) {
    return be->scan_i32((int32_t*)p[0], (const int32_t*)(p[1] ? p[1] : p[0]), c->s[0]);
}

// marching_tets_emit: verts, vedge, weight, faces, pos, sdf, tets, tet_off, slot_off
static void prep_marching_tets_emit(const op_case* c, float** h) {
    (void)mt_problem(c, h[5], h[6], (int32_t*)h[7], (int32_t*)h[8]);
}
static void setup_marching_tets_emit(op_case* c, draw* d, int t) {
    mt_draw(c, d, t, t % 4);
    size_t nv = at_least_1(c->s[3]), nf = at_least_1(c->s[4]);
    OUT_("verts", 3 * nv, B_EXACT);
    OUT_("vedge", 2 * nv, B_BITS);
    OUT_("weight", 2 * nv, B_EXACT);
    OUT_("faces", 3 * nf, B_BITS);
    IN_("pos", 3 * (size_t)c->s[5], -1, 1);
    IN_("sdf", c->s[5], -1, 1);
    IN_("tets", 4 * (size_t)c->s[6], 0, 1);
    IN_("tet_off", (size_t)c->s[6] + 1, 0, 1);
    IN_("slot_off", 7 * (size_t)c->s[5] + 1, 0, 1);
    c->prep = prep_marching_tets_emit;
}
static mlb_status call_marching_tets_emit(const mlb_backend* be, float** p, const op_case* c) {
    return be->marching_tets_emit(p[0], (int32_t*)p[1], p[2], (int32_t*)p[3], p[4], p[5],
                                  (const int32_t*)p[6], c->s[6], c->s[0], (const int32_t*)p[7], (const int32_t*)p[8]);
}

// marching_tets_backward: dpos, dsdf, dverts, weight, vedge, pos, sdf, slot_off; weight and vedge
// from the CPU's emit on the host. Trial 1: dsdf NULL, trial 2: dpos NULL, trial 3 all outside
// (no surface: nothing changes).
static void prep_marching_tets_backward(const op_case* c, float** h) {
    int T = c->s[6];
    size_t nv = at_least_1(c->s[3]), nf = at_least_1(c->s[4]);
    float* tets = malloc(sizeof(float) * 4 * (size_t)T);
    int32_t* tet_off = malloc(sizeof(int32_t) * ((size_t)T + 1));
    float* verts = malloc(sizeof(float) * 3 * nv);
    int32_t* faces = malloc(sizeof(int32_t) * 3 * nf);
    if (tets && tet_off && verts && faces && mt_problem(c, h[6], tets, tet_off, (int32_t*)h[7]))
        mlb_mt_emit(verts, (int32_t*)h[4], h[3], faces, h[5], h[6], (const int32_t*)tets, T, c->s[0], tet_off,
                    (const int32_t*)h[7]);
    free(tets), free(tet_off), free(verts), free(faces);
}
static void setup_marching_tets_backward(op_case* c, draw* d, int t) {
    static const int mode[4] = {MT_RAGGED, MT_RAGGED, MT_SPHERE, MT_OUTSIDE};
    mt_draw(c, d, t, mode[t % 4]);
    size_t nv = at_least_1(c->s[3]);
    OPT_ACC("dpos", 3 * (size_t)c->s[5], B_EXACT, t == 2);
    OPT_ACC("dsdf", c->s[5], B_EXACT, t == 1);
    IN_("dverts", 3 * nv, -1, 1);
    IN_("weight", 2 * nv, 0, 1);
    IN_("vedge", 2 * nv, 0, 1);
    IN_("pos", 3 * (size_t)c->s[5], -1, 1);
    IN_("sdf", c->s[5], -1, 1);
    IN_("slot_off", 7 * (size_t)c->s[5] + 1, 0, 1);
    c->prep = prep_marching_tets_backward;
}
static mlb_status call_marching_tets_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->marching_tets_backward(p[0], p[1], p[2], p[3], (const int32_t*)p[4], c->s[3], p[5], p[6],
                                      (const int32_t*)p[7], c->s[0]);
}

// dmtet_deform(_backward): s = V; f = grid_res (2 cells)
static void draw_deform(op_case* c, draw* d, int t) {
    c->s[0] = dim(d, t, 3000);
    c->f = (float)(2 * (t ? pick(d, 1, 64) : 1));
    snprintf(c->shape, sizeof c->shape, "V %d, grid_res %g", c->s[0], (double)c->f);
}
static void setup_dmtet_deform(op_case* c, draw* d, int t) {
    draw_deform(c, d, t);
    OUT_("out", 3 * (size_t)c->s[0], B_ELEM);
    IN_("grid", 3 * (size_t)c->s[0], -1, 1);
    IN_("deform", 3 * (size_t)c->s[0], -4, 4);
}
static mlb_status call_dmtet_deform(const mlb_backend* be, float** p, const op_case* c) {
    return be->dmtet_deform(p[0], p[1], p[2], c->s[0], c->f);
}
static void setup_dmtet_deform_backward(op_case* c, draw* d, int t) {
    draw_deform(c, d, t);
    ACC_("ddeform", 3 * (size_t)c->s[0], B_ELEM);
    IN_("dout", 3 * (size_t)c->s[0], -1, 1);
    IN_("deform", 3 * (size_t)c->s[0], -4, 4);
}
static mlb_status call_dmtet_deform_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->dmtet_deform_backward(p[0], p[1], p[2], c->s[0], c->f);
}
// sdf_reg(_backward): s = cells (1 to 24), mode (the marching-tets SDFs above: ragged, all inside,
// all outside with no edge to count, a sphere); f = dloss
static void draw_sdf_reg(op_case* c, draw* d, int t) {
    c->s[0] = t ? pick(d, 1, 24) : 1, c->s[1] = t % 4, c->s[2] = pick(d, 1, 1 << 30);
    c->f = 0.25f + (float)pick(d, 0, 8);
    int n = c->s[0] + 1;
    c->s[5] = n * n * n;
    snprintf(c->shape, sizeof c->shape, "%d cells, %s", c->s[0], mt_mode_name[c->s[1]]);
}
static void prep_sdf_reg(const op_case* c, float** h) { mt_sdf(h[1], c); }   // (s[0..2] as mt_sdf reads them)
static void setup_sdf_reg(op_case* c, draw* d, int t) {
    draw_sdf_reg(c, d, t);
    OUT_("out", 1, B_SUMS);
    IN_("sdf", c->s[5], -1, 1);
    c->prep = prep_sdf_reg;
}
static mlb_status call_sdf_reg(const mlb_backend* be, float** p, const op_case* c) {
    return be->sdf_reg(p[0], p[1], c->s[0]);
}
static void prep_sdf_reg_backward(const op_case* c, float** h) { mt_sdf(h[1], c); }
static void setup_sdf_reg_backward(op_case* c, draw* d, int t) {
    draw_sdf_reg(c, d, t);
    ACC_("dsdf", c->s[5], B_ELEM);
    IN_("sdf", c->s[5], -1, 1);
    c->prep = prep_sdf_reg_backward;
}
static mlb_status call_sdf_reg_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->sdf_reg_backward(p[0], p[1], c->s[0], c->f);
}

#endif
