// Multiresolution hash encoding (reference.md §4): forward, backward to the table and to the
// input positions. Dual-compiled (float / double _f64), see core/real.h.
#include <math.h>
#include <string.h>
#include "matlaber/hashgrid.h"
#include "matlaber/rng.h"
#include "core/real.h"

#define HG_PARALLEL_MIN 1024
#ifdef MLB_F64
#define HG_FLOOR floor
#else
#define HG_FLOOR floorf
#endif

#ifndef MLB_F64
mlb_hashgrid_config mlb_hashgrid_default(void) {
    mlb_hashgrid_config c = {16, 2, 1u << 19, 16, 0.0};
    mlb_hashgrid_set_span(&c, MLB_HASHGRID_DEFAULT_LEVELS, MLB_HASHGRID_DEFAULT_BASE_RES, MLB_HASHGRID_DEFAULT_MAX_RES);
    return c;
}

void mlb_hashgrid_set_span(mlb_hashgrid_config* c, int levels, int base_res, int max_res) {
    c->n_levels = levels;
    c->base_res = base_res;
    c->per_level_scale = levels > 1 ? exp(log((double)max_res / base_res) / (levels - 1)) : 1.0;
}

uint32_t mlb_hashgrid_index(const uint32_t pos[3], uint32_t res, uint32_t level_size, int dense) {
    if (dense) {
        uint64_t i = (uint64_t)pos[0] + (uint64_t)res * (pos[1] + (uint64_t)res * pos[2]);
        return (uint32_t)(i % level_size);
    }
    uint32_t h = pos[0] ^ (pos[1] * 2654435761u) ^ (pos[2] * 805459861u);
    return h % level_size;
}
#endif

mlb_status FN(hashgrid_init)(FN(mlb_hashgrid)* g, const mlb_hashgrid_config* cfg, real* params) {
    if (cfg->n_levels < 1 || cfg->n_levels > MLB_HASHGRID_MAX_LEVELS)
        return mlb_fail(MLB_ERR_ARG, "hash grid: %d levels, expected 1..%d", cfg->n_levels, MLB_HASHGRID_MAX_LEVELS);
    if (cfg->n_features < 1 || cfg->n_features > MLB_HASHGRID_MAX_FEATURES)
        return mlb_fail(MLB_ERR_ARG, "hash grid: %d features per level, expected 1..%d", cfg->n_features,
                        MLB_HASHGRID_MAX_FEATURES);
    if (cfg->table_size < 1) return mlb_fail(MLB_ERR_ARG, "hash grid: table size must be positive");
    if (cfg->base_res < 1) return mlb_fail(MLB_ERR_ARG, "hash grid: base resolution %d must be positive", cfg->base_res);
    if (!(cfg->per_level_scale >= 1.0 && cfg->per_level_scale <= 16.0))
        return mlb_fail(MLB_ERR_ARG, "hash grid: per-level scale %g outside [1, 16]", cfg->per_level_scale);
    memset(g, 0, sizeof *g);
    g->cfg = *cfg;
    g->out_dim = cfg->n_levels * cfg->n_features;
    size_t off = 0;
    for (int l = 0; l < cfg->n_levels; l++) {
        double s = exp2(l * log2(cfg->per_level_scale)) * cfg->base_res - 1.0;
        double r = ceil(s) + 1.0;
        if (r > 2097151.0) return mlb_fail(MLB_ERR_ARG, "hash grid: level %d resolution %.0f too large", l, r);
        g->scale[l] = s;
        g->res[l] = (uint32_t)r;
        double cube = r * r * r;
        g->dense[l] = cube <= (double)cfg->table_size;
        g->level_size[l] = g->dense[l] ? (uint32_t)cube : cfg->table_size;
        g->offset[l] = off;
        off += g->level_size[l];
    }
    g->offset[cfg->n_levels] = off;
    g->n_params = off * (size_t)cfg->n_features;
    g->params = params;
    return MLB_OK;
}

void FN(hashgrid_init_params)(FN(mlb_hashgrid)* g, uint64_t seed) {
    size_t n = g->n_params;
#pragma omp parallel for schedule(static) if (n >= HG_PARALLEL_MIN)
    for (size_t i = 0; i < n; i++)
        g->params[i] = (real)(-1e-4 + 2e-4 * mlb_rng_uniform_f64(seed, 0x4A54, i));
}

// The 8 corners of point x in level l: table entry (not value) indices, weights, and per axis
// the fractional position t_d and the level scale (for the position derivatives).
typedef struct {
    uint32_t idx[8];
    real w[8];
    real t[3];
} corners;

static inline void level_corners(const FN(mlb_hashgrid)* g, int l, const real* x, corners* c) {
    real s = (real)g->scale[l];
    uint32_t base[3];
    for (int d = 0; d < 3; d++) {
        real xd = x[d];
        xd = xd >= 0 ? (xd > 1 ? 1 : xd) : 0;   // clamp; NaN reads corner 0
        real p = s * xd + (real)0.5;
        real fl = HG_FLOOR(p);
        base[d] = (uint32_t)fl;
        c->t[d] = p - fl;
    }
    // Corner indices without a division per corner (same values as mlb_hashgrid_index).
    const uint32_t size = g->level_size[l];
    if (g->dense[l]) {
        const uint64_t r = g->res[l], b0 = base[0] + r * (base[1] + r * base[2]);
        for (int k = 0; k < 8; k++) {
            uint64_t i = b0 + (k & 1) + ((k >> 1) & 1) * r + ((k >> 2) & 1) * r * r;
            c->idx[k] = i < size ? (uint32_t)i : (uint32_t)(i % size);
        }
    } else {
        uint32_t h[3][2];
        const uint32_t prime[3] = {1u, 2654435761u, 805459861u};
        for (int d = 0; d < 3; d++) { h[d][0] = base[d] * prime[d]; h[d][1] = (base[d] + 1) * prime[d]; }
        const int pow2 = (size & (size - 1)) == 0;
        for (int k = 0; k < 8; k++) {
            uint32_t v = h[0][k & 1] ^ h[1][(k >> 1) & 1] ^ h[2][(k >> 2) & 1];
            c->idx[k] = pow2 ? v & (size - 1) : v % size;
        }
    }
    for (int k = 0; k < 8; k++)
        c->w[k] = ((k & 1) ? c->t[0] : 1 - c->t[0]) * (((k >> 1) & 1) ? c->t[1] : 1 - c->t[1]) *
                  (((k >> 2) & 1) ? c->t[2] : 1 - c->t[2]);
}

// Level-major loops (all points of one level, then the next): one level's table at a time stays
// in cache, about 2x faster than visiting all levels per point.
void FN(hashgrid_forward)(const FN(mlb_hashgrid)* g, real* out, const real* x, int N) {
    const int L = g->cfg.n_levels, F = g->cfg.n_features, D = g->out_dim;
#pragma omp parallel if (N >= HG_PARALLEL_MIN)
    for (int l = 0; l < L; l++) {
        const real* table = g->params + g->offset[l] * F;
#pragma omp for schedule(static)
        for (int i = 0; i < N; i++) {
            corners c;
            level_corners(g, l, x + 3 * (size_t)i, &c);
            real acc[MLB_HASHGRID_MAX_FEATURES] = {0};
            for (int k = 0; k < 8; k++) {
                const real* e = table + (size_t)c.idx[k] * F;
                for (int f = 0; f < F; f++) acc[f] += c.w[k] * e[f];
            }
            for (int f = 0; f < F; f++) out[(size_t)i * D + l * F + f] = acc[f];
        }
    }
}

void FN(hashgrid_backward)(const FN(mlb_hashgrid)* g, real* dparams, real* dx, const real* dout,
                           const real* x, int N) {
    const int L = g->cfg.n_levels, F = g->cfg.n_features, D = g->out_dim;
    if (dparams) {
        // One level per task: each level's entries are disjoint, and within a level the points are
        // summed in index order, so the result does not depend on the thread count.
#pragma omp parallel for schedule(dynamic, 1) if ((size_t)N * L >= HG_PARALLEL_MIN)
        for (int l = 0; l < L; l++) {
            real* table = dparams + g->offset[l] * F;
            for (int i = 0; i < N; i++) {
                corners c;
                level_corners(g, l, x + 3 * (size_t)i, &c);
                const real* go = dout + (size_t)i * D + l * F;
                for (int k = 0; k < 8; k++) {
                    real* e = table + (size_t)c.idx[k] * F;
                    for (int f = 0; f < F; f++) e[f] += c.w[k] * go[f];
                }
            }
        }
    }
    if (dx) {
        // dx[i] += level contributions in level order: deterministic for any thread count.
#pragma omp parallel if (N >= HG_PARALLEL_MIN)
        for (int l = 0; l < L; l++) {
            const real* table = g->params + g->offset[l] * F;
            const real s = (real)g->scale[l];
#pragma omp for schedule(static)
            for (int i = 0; i < N; i++) {
                const real* xi = x + 3 * (size_t)i;
                corners c;
                level_corners(g, l, xi, &c);
                const real* go = dout + (size_t)i * D + l * F;
                real ge[8];   // dL/dw_k
                for (int k = 0; k < 8; k++) {
                    const real* e = table + (size_t)c.idx[k] * F;
                    real acc = 0;
                    for (int f = 0; f < F; f++) acc += go[f] * e[f];
                    ge[k] = acc;
                }
                // w_k = Π_d (bit_d(k) ? t_d : 1 − t_d), ∂t_d/∂x_d = s: differences along each axis,
                // weighted by the other two axes' factors.
                const real t0 = c.t[0], t1 = c.t[1], t2 = c.t[2], u0 = 1 - t0, u1 = 1 - t1, u2 = 1 - t2;
                real gx[3];
                gx[0] = s * (u1 * u2 * (ge[1] - ge[0]) + t1 * u2 * (ge[3] - ge[2]) + u1 * t2 * (ge[5] - ge[4]) +
                             t1 * t2 * (ge[7] - ge[6]));
                gx[1] = s * (u0 * u2 * (ge[2] - ge[0]) + t0 * u2 * (ge[3] - ge[1]) + u0 * t2 * (ge[6] - ge[4]) +
                             t0 * t2 * (ge[7] - ge[5]));
                gx[2] = s * (u0 * u1 * (ge[4] - ge[0]) + t0 * u1 * (ge[5] - ge[1]) + u0 * t1 * (ge[6] - ge[2]) +
                             t0 * t1 * (ge[7] - ge[3]));
                for (int d = 0; d < 3; d++)
                    if (xi[d] >= 0 && xi[d] <= 1) dx[3 * (size_t)i + d] += gx[d];   // clamped outside
            }
        }
    }
}
