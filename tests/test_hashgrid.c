// Multiresolution hash encoding: layout, dense vs hashed indexing, corner lookups, finite-difference
// checks of the backward (double), and bitwise determinism across thread counts.
#include <stdint.h>
#include "matlaber/hashgrid.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"
#include "test.h"

TEST(default_layout) {
    mlb_hashgrid_config c = mlb_hashgrid_default();
    CHECK(c.n_levels == 16 && c.n_features == 2 && c.table_size == (1u << 19) && c.base_res == 16);
    CHECK_CLOSE(c.per_level_scale, 1.4472692374403782, 1e-12, 0);
    mlb_hashgrid g;
    REQUIRE(hashgrid_init(&g, &c, NULL) == MLB_OK);
    CHECK(g.out_dim == 32);
    CHECK_CLOSE(g.scale[0], 15.0, 1e-12, 0);
    CHECK(g.res[0] == 16 && g.level_size[0] == 4096 && g.dense[0]);
    CHECK_CLOSE(g.scale[15], 4095.0, 1e-9, 0);   // 16·(4096/16) − 1
    CHECK(g.res[15] == 4096);
    // res^3 <= 2^19 <=> res <= 80: levels 0..4 (res 16, 24, 34, 49, 71) dense, 5.. (res 102) hashed
    int n_dense = 0;
    for (int l = 0; l < 16; l++) n_dense += g.dense[l];
    CHECK(n_dense == 5);
    CHECK(g.res[4] == 71 && g.dense[4] && g.res[5] == 102 && !g.dense[5]);
    CHECK(g.level_size[5] == (1u << 19));
    CHECK(g.n_params == g.offset[16] * 2);
    CHECK(g.offset[1] == 4096 && g.offset[2] == 4096 + 24 * 24 * 24);
    mlb_hashgrid_config bad = c;
    bad.n_levels = 0;
    CHECK(hashgrid_init(&g, &bad, NULL) == MLB_ERR_ARG);
}

TEST(dense_vs_hashed_index) {
    // The same level (res 16) dense in a 2^13 table, hashed in a 2^10 one.
    mlb_hashgrid_config c = {1, 2, 8192, 16, 1.5};
    mlb_hashgrid g;
    REQUIRE(hashgrid_init(&g, &c, NULL) == MLB_OK);
    CHECK(g.res[0] == 16 && g.dense[0] && g.level_size[0] == 4096);
    c.table_size = 1024;
    REQUIRE(hashgrid_init(&g, &c, NULL) == MLB_OK);
    CHECK(!g.dense[0] && g.level_size[0] == 1024);
    uint32_t p[3] = {1, 2, 3};
    CHECK(mlb_hashgrid_index(p, 16, 4096, 1) == 1 + 16 * 2 + 256 * 3);
    uint64_t h = (1ull ^ ((2ull * 2654435761ull) & 0xffffffffull) ^ ((3ull * 805459861ull) & 0xffffffffull));
    CHECK(mlb_hashgrid_index(p, 16, 1024, 0) == (uint32_t)(h % 1024));
    uint32_t q[3] = {15, 15, 15};
    CHECK(mlb_hashgrid_index(q, 16, 4096, 1) == 4095);
    uint32_t top[3] = {16, 0, 0};   // the corner past the top face wraps (mod res^3), as tiny-cuda-nn does
    CHECK(mlb_hashgrid_index(top, 16, 4096, 1) == 16);
}

// A point whose level-0 grid position is exactly (px, py, pz) reads that corner's entry alone.
TEST(corner_lookup) {
    for (int hashed = 0; hashed < 2; hashed++) {
        mlb_hashgrid_config c = {1, 2, hashed ? 512u : 8192u, 16, 1.5};
        mlb_hashgrid_f64 g;
        REQUIRE(hashgrid_init_f64(&g, &c, NULL) == MLB_OK);
        double* t = malloc(sizeof(double) * g.n_params);
        for (size_t i = 0; i < g.n_params; i++) t[i] = (double)i;   // entry e holds (2e, 2e+1)
        g.params = t;
        const double s = 15.0;
        double x[6] = {(3 - 0.5) / s, (5 - 0.5) / s, (7 - 0.5) / s,   // corner (3, 5, 7)
                       (3.5 - 0.5) / s, (5 - 0.5) / s, (7 - 0.5) / s};  // halfway to (4, 5, 7)
        double out[4];
        hashgrid_forward_f64(&g, out, x, 2);
        uint32_t a[3] = {3, 5, 7}, b[3] = {4, 5, 7};
        uint32_t ia = mlb_hashgrid_index(a, 16, g.level_size[0], g.dense[0]);
        uint32_t ib = mlb_hashgrid_index(b, 16, g.level_size[0], g.dense[0]);
        if (!hashed) CHECK(ia == 3 + 16 * 5 + 256 * 7);
        CHECK_CLOSE(out[0], 2.0 * ia, 0, 1e-9);
        CHECK_CLOSE(out[1], 2.0 * ia + 1, 0, 1e-9);
        CHECK_CLOSE(out[2], (2.0 * ia + 2.0 * ib) / 2, 0, 1e-9);
        CHECK_CLOSE(out[3], (2.0 * ia + 1 + 2.0 * ib + 1) / 2, 0, 1e-9);
        free(t);
    }
}

// The encoding against a direct transcription of reference.md §4 (level by level, corner by corner,
// through mlb_hashgrid_index), dense and hashed levels, power-of-two and other table sizes.
TEST(forward_matches_reference) {
    for (int variant = 0; variant < 2; variant++) {
        mlb_hashgrid_config c = {6, 3, variant ? 3000u : 4096u, 5, 1.6};
        mlb_hashgrid_f64 g;
        REQUIRE(hashgrid_init_f64(&g, &c, NULL) == MLB_OK);
        double* t = malloc(sizeof(double) * g.n_params);
        for (size_t i = 0; i < g.n_params; i++) t[i] = mlb_rng_normal_f64(9, 1, i);
        g.params = t;
        enum { N = 200 };
        double x[3 * N], out[N * 18];
        for (int i = 0; i < 3 * N; i++) x[i] = mlb_rng_uniform_f64(9, 2, i);
        x[0] = 1.0; x[1] = 0.0; x[2] = 1.0;   // the faces of the cube
        hashgrid_forward_f64(&g, out, x, N);
        int n_dense = 0;
        for (int l = 0; l < 6; l++) n_dense += g.dense[l];
        CHECK(n_dense > 0 && n_dense < 6);
        for (int i = 0; i < N; i++)
            for (int l = 0; l < 6; l++) {
                double s = pow(2.0, l * log2(1.6)) * 5 - 1;
                uint32_t res = (uint32_t)ceil(s) + 1;
                int dense = (double)res * res * res <= c.table_size;
                uint32_t size = dense ? res * res * res : c.table_size;
                double ref[3] = {0, 0, 0};
                for (int k = 0; k < 8; k++) {
                    uint32_t pos[3];
                    double w = 1;
                    for (int d = 0; d < 3; d++) {
                        double p = s * x[3 * i + d] + 0.5, fl = floor(p);
                        pos[d] = (uint32_t)fl + ((k >> d) & 1);
                        w *= ((k >> d) & 1) ? p - fl : 1 - (p - fl);
                    }
                    uint32_t idx = mlb_hashgrid_index(pos, res, size, dense);
                    for (int f = 0; f < 3; f++) ref[f] += w * t[(g.offset[l] + idx) * 3 + f];
                }
                for (int f = 0; f < 3; f++) CHECK_CLOSE(out[i * 18 + l * 3 + f], ref[f], 1e-12, 1e-12);
            }
        free(t);
    }
}

// Points whose every level position is at least `margin` from a cell face (FD stays in one cell).
static void interior_points(const mlb_hashgrid_f64* g, double* x, int N, uint64_t seed, double margin) {
    uint64_t idx = 0;
    for (int i = 0; i < N; i++) {
        for (;;) {
            int ok = 1;
            for (int d = 0; d < 3; d++) x[3 * i + d] = 0.02 + 0.96 * mlb_rng_uniform_f64(seed, 1, idx++);
            for (int l = 0; l < g->cfg.n_levels; l++)
                for (int d = 0; d < 3; d++) {
                    double p = g->scale[l] * x[3 * i + d] + 0.5, t = p - floor(p);
                    if (t < margin || t > 1 - margin) ok = 0;
                }
            if (ok) break;
        }
    }
}

TEST(backward_finite_differences) {
    mlb_hashgrid_config c = {4, 2, 256, 3, 1.7};   // levels 0, 1 dense (res 3, 6), 2, 3 hashed (res 9, 14)
    mlb_hashgrid_f64 g;
    REQUIRE(hashgrid_init_f64(&g, &c, NULL) == MLB_OK);
    CHECK(g.dense[0] && !g.dense[3]);
    double* t = malloc(sizeof(double) * g.n_params);
    double* dt = calloc(g.n_params, sizeof(double));
    g.params = t;
    for (size_t i = 0; i < g.n_params; i++) t[i] = mlb_rng_normal_f64(3, 2, i);   // O(1) so dx is sizeable
    enum { N = 6 };
    double x[3 * N], dx[3 * N] = {0}, out[N * 8], r[N * 8];
    interior_points(&g, x, N, 5, 0.02);
    for (int i = 0; i < N * 8; i++) r[i] = mlb_rng_normal_f64(7, 3, i);
    hashgrid_backward_f64(&g, dt, dx, r, x, N);
    const double h = 1e-6;
    double max_err = 0;
#define LOSS(res) do { hashgrid_forward_f64(&g, out, x, N); res = 0; for (int i_ = 0; i_ < N * 8; i_++) res += out[i_] * r[i_]; } while (0)
    for (size_t i = 0; i < g.n_params; i += 3) {
        double keep = t[i], lp, lm;
        t[i] = keep + h; LOSS(lp);
        t[i] = keep - h; LOSS(lm);
        t[i] = keep;
        double fd = (lp - lm) / (2 * h);
        CHECK_CLOSE(dt[i], fd, 1e-6, 1e-8);
        if (fabs(dt[i] - fd) > max_err) max_err = fabs(dt[i] - fd);
    }
    for (int i = 0; i < 3 * N; i++) {
        double keep = x[i], lp, lm;
        x[i] = keep + h; LOSS(lp);
        x[i] = keep - h; LOSS(lm);
        x[i] = keep;
        CHECK_CLOSE(dx[i], (lp - lm) / (2 * h), 1e-6, 1e-7);
    }
#undef LOSS
    // Accumulation: a second backward doubles the gradients.
    double keep0 = dx[0];
    hashgrid_backward_f64(&g, NULL, dx, r, x, N);
    CHECK_CLOSE(dx[0], 2 * keep0, 1e-12, 1e-15);
    free(t);
    free(dt);
}

TEST(deterministic_across_threads) {
    mlb_hashgrid_config c = {8, 2, 1u << 12, 16, 1.5};
    mlb_hashgrid g;
    REQUIRE(hashgrid_init(&g, &c, NULL) == MLB_OK);
    float* t = malloc(sizeof(float) * g.n_params);
    g.params = t;
    hashgrid_init_params(&g, 11);
    for (size_t i = 0; i < g.n_params; i++) CHECK(t[i] >= -1e-4f && t[i] <= 1e-4f);
    const int N = 20000, D = g.out_dim;
    float* x = malloc(sizeof(float) * 3 * N);
    float* r = malloc(sizeof(float) * N * D);
    mlb_rng_fill_uniform(x, 3 * (size_t)N, 1, 1, 0, 0.f, 1.f);
    mlb_rng_fill_normal(r, (size_t)N * D, 1, 2, 0, 0.f, 1.f);
    float* out[2]; float* dt[2]; float* dx[2];
    int saved = mlb_get_threads();
    for (int k = 0; k < 2; k++) {
        mlb_set_threads(k + 1);
        out[k] = malloc(sizeof(float) * N * D);
        dt[k] = calloc(g.n_params, sizeof(float));
        dx[k] = calloc(3 * (size_t)N, sizeof(float));
        hashgrid_forward(&g, out[k], x, N);
        hashgrid_backward(&g, dt[k], dx[k], r, x, N);
    }
    mlb_set_threads(saved);
    CHECK(memcmp(out[0], out[1], sizeof(float) * N * D) == 0);
    CHECK(memcmp(dt[0], dt[1], sizeof(float) * g.n_params) == 0);
    CHECK(memcmp(dx[0], dx[1], sizeof(float) * 3 * N) == 0);
    for (int k = 0; k < 2; k++) { free(out[k]); free(dt[k]); free(dx[k]); }
    free(x); free(r); free(t);
}

int main(void) {
    RUN(default_layout);
    RUN(dense_vs_hashed_index);
    RUN(corner_lookup);
    RUN(forward_matches_reference);
    RUN(backward_finite_differences);
    RUN(deterministic_across_threads);
    return test_summary();
}
