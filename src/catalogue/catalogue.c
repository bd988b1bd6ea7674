// The catalogue's names, materials, held-out pairs, captions and samples (include/matlaber/catalogue.h,
// docs/catalogue.md). Shapes: catalogue_shapes.c; the renderer: catalogue_render.c.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/cameras.h"
#include "matlaber/catalogue.h"
#include "matlaber/render.h"
#include "matlaber/rng.h"
#include "matlaber/sds.h"
#include "catalogue_internal.h"

// ---- classes ----
static const char* const CLASS_NAMES[MLB_CATALOGUE_N_CLASSES] = {
    "goblet", "vase", "bowl", "mug", "bottle", "mushroom", "table", "stool", "lamp", "ring", "teapot"};
static const int CLASS_SYMMETRIC[MLB_CATALOGUE_N_CLASSES] = {1, 1, 1, 0, 1, 1, 0, 0, 1, 0, 0};

int mlb_catalogue_n_classes(void) { return MLB_CATALOGUE_N_CLASSES; }
const char* mlb_catalogue_class_name(int c) { return c >= 0 && c < MLB_CATALOGUE_N_CLASSES ? CLASS_NAMES[c] : NULL; }
int mlb_catalogue_class_symmetric(int c) { return c >= 0 && c < MLB_CATALOGUE_N_CLASSES ? CLASS_SYMMETRIC[c] : 0; }
// The stool (three legs, one to the front) is not measured: mirrored in z its legs are six around,
// which an asset with legs or a skirt all around matches better than three, two-faced or not (every
// stool of the 88-prompt run, docs/benchmarks.md).
static const int CLASS_MIRROR_AXIS[MLB_CATALOGUE_N_CLASSES] = {-1, -1, -1, 0, -1, -1, -1, -1, -1, -1, 0};
int mlb_catalogue_class_mirror_axis(int c) { return c >= 0 && c < MLB_CATALOGUE_N_CLASSES ? CLASS_MIRROR_AXIS[c] : -1; }
const char* mlb_catalogue_class_list(void) {
    return "goblet, vase, bowl, mug, bottle, mushroom, table, stool, lamp, ring, teapot";
}

mlb_status mlb_catalogue_class_parse(const char* name, int* c) {
    for (int i = 0; name && i < MLB_CATALOGUE_N_CLASSES; i++)
        if (!strcmp(name, CLASS_NAMES[i])) { *c = i; return MLB_OK; }
    return mlb_fail(MLB_ERR_ARG, "unknown class '%s' (one of %s)", name ? name : "(null)", mlb_catalogue_class_list());
}

// ---- materials (linear; metals: kd ~ 0, ks = F0 of the metal, reference.md §1 / goblet.c) ----
typedef struct { const char* name; float k[7]; int metal; } material;
static const material MATERIALS[MLB_CATALOGUE_N_MATERIALS] = {
    {"gold",   {0.01f, 0.01f, 0.01f, 1.000f, 0.766f, 0.336f, 0.25f}, 1},
    {"silver", {0.01f, 0.01f, 0.01f, 0.972f, 0.960f, 0.915f, 0.20f}, 1},
    {"copper", {0.01f, 0.01f, 0.01f, 0.955f, 0.638f, 0.538f, 0.30f}, 1},
    {"red",    {0.55f, 0.04f, 0.03f, 0.04f, 0.04f, 0.04f, 0.15f}, 0},    // red glaze
    {"blue",   {0.02f, 0.06f, 0.45f, 0.04f, 0.04f, 0.04f, 0.15f}, 0},    // cobalt glaze (the goblet's)
    {"white",  {0.80f, 0.80f, 0.78f, 0.04f, 0.04f, 0.04f, 0.60f}, 0},    // matte white plastic
    {"stone",  {0.35f, 0.33f, 0.30f, 0.03f, 0.03f, 0.03f, 0.90f}, 0},    // rough grey stone
    {"green",  {0.05f, 0.35f, 0.10f, 0.04f, 0.04f, 0.04f, 0.20f}, 0},    // green glaze
};

int mlb_catalogue_n_materials(void) { return MLB_CATALOGUE_N_MATERIALS; }
const char* mlb_catalogue_material_name(int m) { return m >= 0 && m < MLB_CATALOGUE_N_MATERIALS ? MATERIALS[m].name : NULL; }
const float* mlb_catalogue_material_brdf(int m) { return m >= 0 && m < MLB_CATALOGUE_N_MATERIALS ? MATERIALS[m].k : NULL; }
int mlb_catalogue_material_metal(int m) { return m >= 0 && m < MLB_CATALOGUE_N_MATERIALS ? MATERIALS[m].metal : 0; }
const char* mlb_catalogue_material_list(void) { return "gold, silver, copper, red, blue, white, stone, green"; }

mlb_status mlb_catalogue_material_parse(const char* name, int* m) {
    for (int i = 0; name && i < MLB_CATALOGUE_N_MATERIALS; i++)
        if (!strcmp(name, MATERIALS[i].name)) { *m = i; return MLB_OK; }
    return mlb_fail(MLB_ERR_ARG, "unknown material '%s' (one of %s)", name ? name : "(null)", mlb_catalogue_material_list());
}

// ---- held out: one material per class, stepping by 3 so the pairs spread over the materials ----
int mlb_catalogue_held_out(int c, int m) {
    if (c < 0 || c >= MLB_CATALOGUE_N_CLASSES || m < 0 || m >= MLB_CATALOGUE_N_MATERIALS) return 0;
    return m == (3 * c + 1) % MLB_CATALOGUE_N_MATERIALS;
}
int mlb_catalogue_n_held_out(void) { return MLB_CATALOGUE_N_CLASSES; }

// ---- captions ----
void mlb_catalogue_caption(int c, int m, int view, char* out, size_t cap) {
    if (!out || !cap) return;
    const char *cn = mlb_catalogue_class_name(c), *mn = mlb_catalogue_material_name(m);
    snprintf(out, cap, "a %s %s%s", mn ? mn : "?", cn ? cn : "?", mlb_sds_view_suffix(view));
}

void mlb_catalogue_sample_caption(const mlb_catalogue_sample* s, char* out, size_t cap) {
    mlb_catalogue_caption(s->cls, s->mat, mlb_sds_view_for(s->view.azimuth_deg, s->view.elevation_deg), out, cap);
}

// ---- samples ----
#define SAMPLE_STREAM 0xCA7A5A00ull

mlb_status mlb_catalogue_sample_draw(mlb_catalogue_sample* out, uint64_t seed, uint64_t index, int n_envs,
                                     int allow_held_out) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "mlb_catalogue_sample_draw: NULL sample");
    if (n_envs < 1 || n_envs > MLB_CATALOGUE_MAX_ENVS)
        return mlb_fail(MLB_ERR_ARG, "catalogue sample: %d environments (1..%d)", n_envs, MLB_CATALOGUE_MAX_ENVS);
    if (index > (uint64_t)0x7fffffff) return mlb_fail(MLB_ERR_ARG, "catalogue sample: index %llu too large", (unsigned long long)index);
    memset(out, 0, sizeof *out);
    // the pair: uniform over the allowed class x material pairs (row-major order)
    int n_ok = 0, pairs[MLB_CATALOGUE_N_CLASSES * MLB_CATALOGUE_N_MATERIALS];
    for (int c = 0; c < MLB_CATALOGUE_N_CLASSES; c++)
        for (int m = 0; m < MLB_CATALOGUE_N_MATERIALS; m++)
            if (allow_held_out || !mlb_catalogue_held_out(c, m)) pairs[n_ok++] = c * MLB_CATALOGUE_N_MATERIALS + m;
    mlb_u32x4 w = mlb_rng_words(seed, SAMPLE_STREAM, index);
    int p = pairs[mlb_rng_below(seed, SAMPLE_STREAM + 1, index, (uint32_t)n_ok)];
    out->cls = p / MLB_CATALOGUE_N_MATERIALS;
    out->mat = p % MLB_CATALOGUE_N_MATERIALS;
    out->shape_seed = ((uint64_t)w.v[0] << 32 | w.v[1]) | 1;   // never 0 (the canonical shape)
    mlb_orbit_config o = mlb_orbit_default();
    o.n_envs = n_envs;
    return mlb_orbit_sample(&out->view, &o, seed, MLB_STAGE_APPEARANCE, (long)index, 0);
}
