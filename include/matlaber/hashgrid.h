// Multiresolution hash encoding (Instant-NGP / tiny-cuda-nn; reference.md §4, docs/geometry.md).
// L levels of F features each. Level l has scale s_l = 2^(l·log2(per_level_scale))·base − 1 and
// resolution res_l = ceil(s_l) + 1; a point x ∈ [0,1]^3 sits at pos = s_l·x + 0.5 and reads the 8
// corners of its cell, trilinearly weighted. A level whose res^3 ≤ T entries is dense (index
// Σ_d pos_d·res^d, mod res^3 as tiny-cuda-nn does, so the top face wraps); otherwise the index is
// XOR_d(pos_d·π_d) mod T with π = (1, 2654435761, 805459861) in uint32 arithmetic.
// The table is [Σ_l size_l, F] (level-major); size_l = res_l^3 when dense, else T.
// Every function over `real` exists twice: float (plain name) and double (name_f64).
#ifndef MATLABER_HASHGRID_H
#define MATLABER_HASHGRID_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/error.h"

#define MLB_HASHGRID_MAX_LEVELS 32
#define MLB_HASHGRID_MAX_FEATURES 8
// The default span (Instant-NGP's, the paper's): 16 levels from resolution 16 to 4096
#define MLB_HASHGRID_DEFAULT_LEVELS 16
#define MLB_HASHGRID_DEFAULT_BASE_RES 16
#define MLB_HASHGRID_DEFAULT_MAX_RES 4096

typedef struct {
    int n_levels;            // L (1..32), default 16
    int n_features;          // F per level (1..8), default 2
    uint32_t table_size;     // T entries per hashed level, default 2^19
    int base_res;            // default 16
    double per_level_scale;  // default exp(ln(4096/16)/15) ≈ 1.44727
} mlb_hashgrid_config;

mlb_hashgrid_config mlb_hashgrid_default(void);
// The levels' span: L levels from resolution base_res to max_res, evenly spaced in log scale
// (per_level_scale = (max_res / base_res)^(1/(L-1)); 1 for one level).
void mlb_hashgrid_set_span(mlb_hashgrid_config* c, int levels, int base_res, int max_res);
// The index of integer grid corner pos within a level of resolution res whose table has
// level_size entries; dense selects the dense formula (the caller passes res^3 <= table_size).
uint32_t mlb_hashgrid_index(const uint32_t pos[3], uint32_t res, uint32_t level_size, int dense);

#define MLB_REAL float
#define MLB_FN(name) name
#include "matlaber/hashgrid_api.inc"
#undef MLB_REAL
#undef MLB_FN
#define MLB_REAL double
#define MLB_FN(name) name##_f64
#include "matlaber/hashgrid_api.inc"
#undef MLB_REAL
#undef MLB_FN

#endif
