// Material conventions (sRGB transfer, validity), the growable sample set and the material family
// table shared by the loaders and the procedural generator.
#include "matlaber/brdf.h"
#include <math.h>
#include <stdlib.h>
#include <string.h>

float mlb_srgb_to_linear(float c) {
    if (c <= 0.04045f) return c / 12.92f;
    return powf((c + 0.055f) / 1.055f, 2.4f);
}

float mlb_linear_to_srgb(float c) {
    if (c <= 0.0031308f) return 12.92f * c;
    return 1.055f * powf(c, 1.0f / 2.4f) - 0.055f;
}

int mlb_brdf_valid(const float k[MLB_BRDF_DIM]) {
    for (int i = 0; i < 6; i++)
        if (!(k[i] >= 0.0f && k[i] <= 1.0f)) return 0;   // also false for NaN
    return k[6] >= MLB_KR_MIN && k[6] <= 1.0f;          // +-Inf fail the ranges
}

int mlb_brdf_clamp(float k[MLB_BRDF_DIM]) {
    int changed = 0;
    for (int i = 0; i < MLB_BRDF_DIM; i++) {
        float lo = i == 6 ? MLB_KR_MIN : 0.0f, v = k[i];
        float c = isnan(v) ? lo : (v < lo ? lo : (v > 1.0f ? 1.0f : v));
        if (c != v || isnan(v)) changed++;
        k[i] = c;
    }
    return changed;
}

// ---- sample set ----

mlb_status mlb_brdf_set_reserve(mlb_brdf_set* s, size_t rows) {
    if (!s) return mlb_fail(MLB_ERR_ARG, "brdf set is NULL");
    if (rows <= s->capacity) return MLB_OK;
    if (rows > SIZE_MAX / (MLB_BRDF_DIM * sizeof(float)))
        return mlb_fail(MLB_ERR_NOMEM, "brdf set: %zu rows is too many", rows);
    // Grow geometrically so repeated appends stay linear overall.
    size_t cap = s->capacity ? s->capacity : 1024;
    while (cap < rows) cap = cap > SIZE_MAX / 2 ? rows : cap * 2;
    if (cap > SIZE_MAX / (MLB_BRDF_DIM * sizeof(float))) cap = rows;
    float* k = realloc(s->k, cap * MLB_BRDF_DIM * sizeof(float));
    if (!k) return mlb_fail(MLB_ERR_NOMEM, "brdf set: cannot allocate %zu rows", cap);
    s->k = k;
    s->capacity = cap;
    return MLB_OK;
}

mlb_status mlb_brdf_set_extend(mlb_brdf_set* s, size_t rows, float** dst) {
    if (!s) return mlb_fail(MLB_ERR_ARG, "brdf set is NULL");
    if (rows > SIZE_MAX - s->n) return mlb_fail(MLB_ERR_NOMEM, "brdf set: row count overflows");
    MLB_TRY(mlb_brdf_set_reserve(s, s->n + rows));
    if (dst) *dst = s->k + s->n * MLB_BRDF_DIM;
    s->n += rows;
    return MLB_OK;
}

mlb_status mlb_brdf_set_append(mlb_brdf_set* s, const float* k, size_t rows) {
    if (rows && !k) return mlb_fail(MLB_ERR_ARG, "brdf set append: source rows are NULL");
    float* dst;
    MLB_TRY(mlb_brdf_set_extend(s, rows, &dst));
    if (rows) memcpy(dst, k, rows * MLB_BRDF_DIM * sizeof(float));
    return MLB_OK;
}

mlb_status mlb_brdf_set_note_source(mlb_brdf_set* s, size_t begin, const char* name) {
    if (!s || !name) return mlb_fail(MLB_ERR_ARG, "brdf set note source: NULL argument");
    if (begin > s->n) return mlb_fail(MLB_ERR_ARG, "brdf set note source: begin %zu past %zu rows", begin, s->n);
    if (s->n_sources == s->cap_sources) {
        size_t cap = s->cap_sources ? s->cap_sources * 2 : 16;
        mlb_brdf_source* p = realloc(s->sources, cap * sizeof *p);
        if (!p) return mlb_fail(MLB_ERR_NOMEM, "brdf set: cannot grow the source list");
        s->sources = p;
        s->cap_sources = cap;
    }
    char* copy = strdup(name);
    if (!copy) return mlb_fail(MLB_ERR_NOMEM, "brdf set: cannot copy a source name");
    s->sources[s->n_sources].begin = begin;
    s->sources[s->n_sources].count = s->n - begin;
    s->sources[s->n_sources].name = copy;
    s->n_sources++;
    return MLB_OK;
}

const char* mlb_brdf_set_source_of(const mlb_brdf_set* s, size_t row) {
    if (!s) return NULL;
    // Sources are appended in row order: binary search on begin.
    size_t lo = 0, hi = s->n_sources;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (s->sources[mid].begin <= row) lo = mid + 1;
        else hi = mid;
    }
    if (lo == 0) return NULL;
    const mlb_brdf_source* src = &s->sources[lo - 1];
    return row < src->begin + src->count ? src->name : NULL;
}

void mlb_brdf_set_truncate(mlb_brdf_set* s, size_t n) {
    if (!s || n >= s->n) return;
    s->n = n;
    while (s->n_sources > 0 && s->sources[s->n_sources - 1].begin >= n) {
        free(s->sources[s->n_sources - 1].name);
        s->n_sources--;
    }
    if (s->n_sources > 0) {
        mlb_brdf_source* last = &s->sources[s->n_sources - 1];
        if (last->begin + last->count > n) last->count = n - last->begin;
    }
}

void mlb_brdf_set_free(mlb_brdf_set* s) {
    if (!s) return;
    for (size_t i = 0; i < s->n_sources; i++) free(s->sources[i].name);
    free(s->sources);
    free(s->k);
    memset(s, 0, sizeof *s);
}

// ---- families ----

// Metal F0 in linear RGB, the widely published values listed in reference.md §1 (derived from
// measured complex refractive indices at the sRGB primaries' wavelengths).
static const float metal_f0[8][3] = {
    {1.000f, 0.766f, 0.336f},   // gold
    {0.972f, 0.960f, 0.915f},   // silver
    {0.955f, 0.638f, 0.538f},   // copper
    {0.913f, 0.922f, 0.924f},   // aluminium
    {0.562f, 0.565f, 0.578f},   // iron
    {0.549f, 0.556f, 0.554f},   // chromium
    {0.660f, 0.609f, 0.526f},   // nickel
    {0.542f, 0.497f, 0.449f},   // titanium
};

static const char* const family_names[MLB_FAM_COUNT] = {
    "gold", "silver", "copper", "aluminium", "iron", "chromium", "nickel", "titanium",
    "wood", "stone", "polished stone", "ceramic", "paint", "plastic", "rubber", "fabric", "skin", "leaf",
    "glass", "gemstone", "water", "bright (snow, paper, plaster)", "dark (soil, asphalt, charcoal)", "rust",
    "patina", "authored",
};

const char* mlb_brdf_family_name(int family) {
    return family >= 0 && family < MLB_FAM_COUNT ? family_names[family] : NULL;
}

mlb_material_class mlb_brdf_family_class(int family) {
    if (family >= MLB_FAM_GOLD && family <= MLB_FAM_TITANIUM) return MLB_MAT_METAL;
    if (family == MLB_FAM_AUTHORED) return MLB_MAT_AUTHORED;
    if (family >= 0 && family < MLB_FAM_COUNT) return MLB_MAT_DIELECTRIC;
    return MLB_MAT_MIXED;
}

int mlb_brdf_metal_f0(int family, float f0[3]) {
    if (family < MLB_FAM_GOLD || family > MLB_FAM_TITANIUM) return 0;
    for (int c = 0; c < 3; c++) f0[c] = metal_f0[family][c];
    return 1;
}
