// The rest of test_backend_ops.c's cases (backend_op_cases.h): the layout and elementwise glue,
// the field networks' ops (activation backward, hash grid, AdamW) and the shading.
#ifndef MATLABER_BACKEND_OP_CASES_GLUE_H
#define MATLABER_BACKEND_OP_CASES_GLUE_H
#include "backend_op_cases.h"

// ---- glue ----
static void setup_activation(op_case* c, draw* d, int t) {
    int n = dim(d, t, 5000);
    c->act = (mlb_activation)(t ? pick(d, 0, MLB_ACT_COUNT - 1) : MLB_ACT_GELU);
    OUT_("out", n, B_ELEM);
    IN_("in", n, -4, 4);
    snprintf(c->shape, sizeof c->shape, "n %d act %d", n, (int)c->act);
}
static mlb_status call_activation(const mlb_backend* be, float** p, const op_case* c) {
    return be->activation(p[0], p[1], c->b[0].n, c->act);
}
static void setup_activation_backward(op_case* c, draw* d, int t) {
    int n = dim(d, t, 5000);
    c->act = (mlb_activation)(t ? pick(d, 0, MLB_ACT_COUNT - 1) : MLB_ACT_GELU);
    ACC_("din", n, B_ELEM);
    IN_("dout", n, -1, 1);
    IN_("in", n, -4, 4);
    snprintf(c->shape, sizeof c->shape, "n %d act %d", n, (int)c->act);
}
static mlb_status call_activation_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->activation_backward(p[0], p[1], p[2], c->b[0].n, c->act);
}
static void setup_add(op_case* c, draw* d, int t) {
    int n = dim(d, t, 10000);
    ACC_("y", n, B_EXACT);
    IN_("x", n, -1, 1);
    snprintf(c->shape, sizeof c->shape, "n %d", n);
}
static mlb_status call_add(const mlb_backend* be, float** p, const op_case* c) { return be->add(p[0], p[1], c->b[0].n); }
// s = N, C, HW (add_channel and its backward)
static void draw_nchw(op_case* c, draw* d, int t) {
    c->s[0] = dim(d, t, 3), c->s[1] = dim(d, t, 40), c->s[2] = dim(d, t, 130);
    snprintf(c->shape, sizeof c->shape, "N %d C %d HW %d", c->s[0], c->s[1], c->s[2]);
}
static void setup_add_channel(op_case* c, draw* d, int t) {
    draw_nchw(c, d, t);
    ACC_("x", (size_t)c->s[0] * c->s[1] * c->s[2], B_EXACT);
    IN_("v", (size_t)c->s[0] * c->s[1], -1, 1);
}
static mlb_status call_add_channel(const mlb_backend* be, float** p, const op_case* c) {
    return be->add_channel(p[0], p[1], c->s[0], c->s[1], c->s[2]);
}
static void setup_add_channel_backward(op_case* c, draw* d, int t) {
    draw_nchw(c, d, t);
    ACC_("dv", (size_t)c->s[0] * c->s[1], B_SUMS);
    IN_("dx", (size_t)c->s[0] * c->s[1] * c->s[2], -1, 1);
}
static mlb_status call_add_channel_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->add_channel_backward(p[0], p[1], c->s[0], c->s[1], c->s[2]);
}
static void setup_transpose_last2(op_case* c, draw* d, int t) {
    int N = dim(d, t, 3), R = dim(d, t, 100), S = dim(d, t, 100);
    c->s[0] = N, c->s[1] = R, c->s[2] = S, c->s[3] = t % 2;   // accumulate on odd trials
    add_buf(c, "out", (size_t)N * R * S, c->s[3] ? ACC : OUT, -1, 1, B_EXACT);
    IN_("in", (size_t)N * R * S, -1, 1);
    snprintf(c->shape, sizeof c->shape, "N %d R %d S %d%s", N, R, S, c->s[3] ? " +=" : "");
}
static mlb_status call_transpose_last2(const mlb_backend* be, float** p, const op_case* c) {
    return be->transpose_last2(p[0], p[1], c->s[0], c->s[1], c->s[2], c->s[3]);
}
// s = rows, C4 (GEGLU and its backward)
static void setup_geglu(op_case* c, draw* d, int t) {
    c->s[0] = dim(d, t, 70), c->s[1] = dim(d, t, 130);
    OUT_("out", (size_t)c->s[0] * c->s[1], B_ELEM);
    IN_("in", (size_t)c->s[0] * 2 * c->s[1], -3, 3);
    snprintf(c->shape, sizeof c->shape, "rows %d C4 %d", c->s[0], c->s[1]);
}
static mlb_status call_geglu(const mlb_backend* be, float** p, const op_case* c) {
    return be->geglu(p[0], p[1], c->s[0], c->s[1]);
}
static void setup_geglu_backward(op_case* c, draw* d, int t) {
    c->s[0] = dim(d, t, 70), c->s[1] = dim(d, t, 130);
    ACC_("din", (size_t)c->s[0] * 2 * c->s[1], B_ELEM);
    IN_("dout", (size_t)c->s[0] * c->s[1], -1, 1);
    IN_("in", (size_t)c->s[0] * 2 * c->s[1], -3, 3);
    snprintf(c->shape, sizeof c->shape, "rows %d C4 %d", c->s[0], c->s[1]);
}
static mlb_status call_geglu_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->geglu_backward(p[0], p[1], p[2], c->s[0], c->s[1]);
}
// s = N, C, H, W of the small side (the 2x upsample and its backward)
static size_t draw_upsample(op_case* c, draw* d, int t) {
    c->s[0] = dim(d, t, 2), c->s[1] = dim(d, t, 9), c->s[2] = dim(d, t, 33), c->s[3] = dim(d, t, 33);
    snprintf(c->shape, sizeof c->shape, "N %d C %d %dx%d", c->s[0], c->s[1], c->s[2], c->s[3]);
    return (size_t)c->s[0] * c->s[1] * c->s[2] * c->s[3];
}
static void setup_upsample_nearest2x(op_case* c, draw* d, int t) {
    size_t n = draw_upsample(c, d, t);
    OUT_("out", 4 * n, B_EXACT);
    IN_("in", n, -1, 1);
}
static mlb_status call_upsample_nearest2x(const mlb_backend* be, float** p, const op_case* c) {
    return be->upsample_nearest2x(p[0], p[1], c->s[0], c->s[1], c->s[2], c->s[3]);
}
static void setup_upsample_nearest2x_backward(op_case* c, draw* d, int t) {
    size_t n = draw_upsample(c, d, t);
    ACC_("din", n, B_ELEM);
    IN_("dout", 4 * n, -1, 1);
}
static mlb_status call_upsample_nearest2x_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->upsample_nearest2x_backward(p[0], p[1], c->s[0], c->s[1], c->s[2], c->s[3]);
}

// ---- the field networks ----
// A small grid: 1-4 levels of 1-4 features, dense and hashed levels (s[0] = points)
static void draw_hashgrid(op_case* c, draw* d, int t) {
    mlb_hashgrid_config cfg = {.n_levels = t ? pick(d, 1, 4) : 1, .n_features = t ? pick(d, 1, 4) : 1,
                               .table_size = 1u << pick(d, 6, 12), .base_res = pick(d, 2, 8),
                               .per_level_scale = 1.3 + 0.1 * pick(d, 0, 7)};
    mlb_status s = hashgrid_init(&c->hg, &cfg, NULL);
    (void)s;   // a valid configuration by construction; the op then fails visibly if not
    c->s[0] = dim(d, t, 500);
    snprintf(c->shape, sizeof c->shape, "N %d, %d levels x %d, T %u, base %d", c->s[0], cfg.n_levels, cfg.n_features,
             cfg.table_size, cfg.base_res);
}
static void setup_hashgrid(op_case* c, draw* d, int t) {
    draw_hashgrid(c, d, t);
    IN_("params", c->hg.n_params, -1, 1);
    OUT_("out", (size_t)c->s[0] * c->hg.out_dim, B_SUMS);
    IN_("x", 3 * (size_t)c->s[0], -0.05f, 1.05f);   // a few outside [0,1]: clamped
}
static mlb_status call_hashgrid(const mlb_backend* be, float** p, const op_case* c) {
    return be->hashgrid(&c->hg, p[0], p[1], p[2], c->s[0]);
}
static void setup_hashgrid_backward(op_case* c, draw* d, int t) {
    draw_hashgrid(c, d, t);
    IN_("params", c->hg.n_params, -1, 1);
    OPT_ACC("dparams", c->hg.n_params, B_SUMS, t == 3);
    OPT_ACC("dx", 3 * (size_t)c->s[0], B_SUMS, t == 2);
    IN_("dout", (size_t)c->s[0] * c->hg.out_dim, -1, 1);
    IN_("x", 3 * (size_t)c->s[0], -0.05f, 1.05f);
}
static mlb_status call_hashgrid_backward(const mlb_backend* be, float** p, const op_case* c) {
    return be->hashgrid_backward(&c->hg, p[0], p[1], p[2], p[3], p[4], c->s[0]);
}
static void setup_adam(op_case* c, draw* d, int t) {
    int n = dim(d, t, 5000);
    c->adam = (mlb_adam_config){.lr = 1e-3 * pick(d, 1, 20), .beta1 = 0.9, .beta2 = 0.99, .eps = 1e-8,
                                .weight_decay = 0.05, .decoupled = pick(d, 0, 1)};
    c->s[0] = pick(d, 1, 20);   // the step t
    ACC_("params", n, B_SUMS);
    IN_("grads", n, -1, 1);
    ACC_("m", n, B_SUMS);
    add_buf(c, "v", n, ACC, 0, 1, B_SUMS);   // a second moment: >= 0
    snprintf(c->shape, sizeof c->shape, "n %d t %d%s", n, c->s[0], c->adam.decoupled ? " decoupled" : "");
}
static mlb_status call_adam(const mlb_backend* be, float** p, const op_case* c) {
    return be->adam(p[0], p[1], p[2], p[3], c->b[0].n, &c->adam, c->s[0]);
}

// ---- shading ----
// One light for every table and trial: a small pre-integrated sky (built once, freed by main).
static mlb_envmap g_env;
static mlb_envlight g_light;
static int g_light_built;
static const mlb_envlight* test_light(void) {
    if (!g_light_built) {
        mlb_envlight_options o = {.face_size = 32, .min_size = 8};
        if (mlb_envmap_named(&g_env, "sky", 32) != MLB_OK || mlb_envlight_build(&g_light, &g_env, &o) != MLB_OK)
            return NULL;
        g_light_built = 1;
    }
    return &g_light;
}
static void free_test_light(void) {
    if (!g_light_built) return;
    mlb_envlight_free(&g_light);
    mlb_envmap_free(&g_env);
    g_light_built = 0;
}
// n and v: unit vectors; a quarter of the views along the normal (most real views face the surface)
static void unit_rows(float* a, int N, int along, const float* n) {
    for (int i = 0; i < N; i++) {
        float* r = a + 3 * i;
        if (n && i % 4 == along) { r[0] = n[3 * i], r[1] = n[3 * i + 1], r[2] = n[3 * i + 2]; continue; }
        double l = sqrt((double)r[0] * r[0] + (double)r[1] * r[1] + (double)r[2] * r[2]);
        if (l < 1e-3) { r[0] = 0, r[1] = 0, r[2] = 1; continue; }
        for (int k = 0; k < 3; k++) r[k] = (float)(r[k] / l);
    }
}
// s = N, fresnel; f = the light's rotation; the inputs kd, ks, kr, n, v at h[first .. first + 4]
static void draw_shade(op_case* c, draw* d, int t) {
    c->s[0] = dim(d, t, 3000), c->s[1] = pick(d, 0, 1), c->f = (float)(0.5 * pick(d, 0, 12));
    snprintf(c->shape, sizeof c->shape, "N %d %s rotation %.1f", c->s[0], c->s[1] ? "Schlick" : "paper", c->f);
}
static void shade_inputs(op_case* c) {
    size_t N = c->s[0];
    IN_("kd", 3 * N, 0, 1);
    IN_("ks", 3 * N, 0, 1);
    IN_("kr", N, 0, 1.05f);   // past 1: the clamped last mip
    IN_("n", 3 * N, -1, 1);
    IN_("v", 3 * N, -1, 1);
}
static void prep_shade_at(const op_case* c, float** h, int first) {
    unit_rows(h[first + 3], c->s[0], -1, NULL);
    unit_rows(h[first + 4], c->s[0], 0, h[first + 3]);
}
static void prep_shade(const op_case* c, float** h) { prep_shade_at(c, h, 1); }
static void setup_shade(op_case* c, draw* d, int t) {
    draw_shade(c, d, t);
    OUT_("out", 3 * (size_t)c->s[0], B_SHADE);
    shade_inputs(c);
    c->prep = prep_shade;
}
static mlb_fresnel case_fresnel(const op_case* c) { return c->s[1] ? MLB_FRESNEL_SCHLICK : MLB_FRESNEL_PAPER; }
// the light made usable on be's device for the one call
static mlb_status call_shade(const mlb_backend* be, float** p, const op_case* c) {
    const mlb_envlight* L = test_light();
    if (!L) return mlb_fail(MLB_ERR_IO, "the test's light could not be built");
    void* h;
    MLB_TRY(be->light_upload(&h, L));
    mlb_status s = be->shade(p[0], p[1], p[2], p[3], p[4], p[5], c->s[0], h, c->f, case_fresnel(c));
    be->light_free(h);
    return s;
}
#define setup_light_upload setup_shade
#define call_light_upload call_shade
#define setup_light_free setup_shade
#define call_light_free call_shade
static void prep_shade_backward(const op_case* c, float** h) { prep_shade_at(c, h, 6); }
static void setup_shade_backward(op_case* c, draw* d, int t) {
    draw_shade(c, d, t);
    size_t N = c->s[0];
    OPT_ACC("dkd", 3 * N, B_SHADE_GRAD, t == 2);
    OPT_ACC("dks", 3 * N, B_SHADE_GRAD, t == 3);
    ACC_("dkr", N, B_SHADE_GRAD);
    OPT_ACC("dn", 3 * N, B_SHADE_GRAD, t == 2);
    ACC_("dv", 3 * N, B_SHADE_GRAD);
    IN_("dout", 3 * N, -1, 1);
    shade_inputs(c);
    c->prep = prep_shade_backward;
}
static mlb_status call_shade_backward(const mlb_backend* be, float** p, const op_case* c) {
    const mlb_envlight* L = test_light();
    if (!L) return mlb_fail(MLB_ERR_IO, "the test's light could not be built");
    void* h;
    MLB_TRY(be->light_upload(&h, L));
    mlb_status s = be->shade_backward(p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10], c->s[0], h,
                                      c->f, case_fresnel(c));
    be->light_free(h);
    return s;
}

#endif
