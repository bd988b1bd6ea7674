// The catalogue's names, materials, held-out pairs, captions, samples and renderer
// (include/matlaber/catalogue.h, docs/catalogue.md). Shapes: catalogue_shapes.c.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/cameras.h"
#include "matlaber/catalogue.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/render.h"
#include "matlaber/rng.h"
#include "matlaber/sds.h"
#include "matlaber/views.h"
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

// ---- the renderer ----
struct mlb_catalogue_renderer {
    mlb_catalogue_render_config c;
    int n_envs;
    mlb_envmap maps[MLB_CATALOGUE_MAX_ENVS];
    mlb_envlight lights[MLB_CATALOGUE_MAX_ENVS];
    mlb_raster_ctx* ctx;
    float* rgba;                  // [res, res, 4] scratch
    int mesh_cls;                 // the cached mesh: class (−1 none) and seed
    uint64_t mesh_seed;
    mlb_mesh mesh;
};

mlb_catalogue_render_config mlb_catalogue_render_default(void) {
    mlb_catalogue_render_config c;
    memset(&c, 0, sizeof c);
    c.res = 128;
    c.supersample = 1;
    c.envs[0] = "sky", c.envs[1] = "studio", c.envs[2] = "overcast";   // pipeline_config.c's pool, in order
    c.n_envs = 3;
    c.env_height = 256;
    c.cube_size = 128;
    return c;
}

void mlb_catalogue_renderer_free(mlb_catalogue_renderer* r) {
    if (!r) return;
    for (int i = 0; i < MLB_CATALOGUE_MAX_ENVS; i++) {
        mlb_envlight_free(&r->lights[i]);
        mlb_envmap_free(&r->maps[i]);
    }
    mlb_raster_ctx_free(r->ctx);
    free(r->rgba);
    mlb_mesh_free(&r->mesh);
    free(r);
}

mlb_status mlb_catalogue_renderer_create(mlb_catalogue_renderer** out, const mlb_catalogue_render_config* cfg) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "mlb_catalogue_renderer_create: NULL output");
    *out = NULL;
    mlb_catalogue_render_config c = cfg ? *cfg : mlb_catalogue_render_default();
    if (c.res < 8 || c.res > 2048) return mlb_fail(MLB_ERR_ARG, "catalogue renderer: res %d (8..2048)", c.res);
    if (c.supersample < 1 || c.supersample > 4) return mlb_fail(MLB_ERR_ARG, "catalogue renderer: supersample %d (1..4)", c.supersample);
    if (c.n_envs < 1 || c.n_envs > MLB_CATALOGUE_MAX_ENVS)
        return mlb_fail(MLB_ERR_ARG, "catalogue renderer: %d environments (1..%d)", c.n_envs, MLB_CATALOGUE_MAX_ENVS);
    mlb_catalogue_renderer* r = calloc(1, sizeof *r);
    if (!r) return mlb_fail(MLB_ERR_NOMEM, "catalogue renderer: out of memory");
    r->c = c;
    r->mesh_cls = -1;
    r->ctx = mlb_raster_ctx_create();
    r->rgba = malloc(sizeof(float) * 4 * (size_t)c.res * c.res);
    mlb_status s = r->ctx && r->rgba ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "catalogue renderer: out of memory");
    mlb_envlight_options opt = {0};
    opt.face_size = c.cube_size;
    for (int i = 0; !s && i < c.n_envs; i++) {
        if (!c.envs[i]) { s = mlb_fail(MLB_ERR_ARG, "catalogue renderer: environment %d is NULL", i); break; }
        s = mlb_envmap_open(&r->maps[i], c.envs[i], 1.0f, c.env_height, NULL);
        if (!s) s = mlb_envlight_build(&r->lights[i], &r->maps[i], &opt);
        if (s) s = mlb_fail_context(s, "catalogue renderer: environment %d (%s)", i, c.envs[i]);
        r->c.envs[i] = NULL;   // the caller's strings are not kept
        r->n_envs = i + 1;
    }
    if (s) { mlb_catalogue_renderer_free(r); return s; }
    *out = r;
    return MLB_OK;
}

int mlb_catalogue_renderer_res(const mlb_catalogue_renderer* r) { return r ? r->c.res : 0; }
int mlb_catalogue_renderer_n_envs(const mlb_catalogue_renderer* r) { return r ? r->n_envs : 0; }

mlb_status mlb_catalogue_render(mlb_catalogue_renderer* r, const mlb_catalogue_sample* smp, float* rgb, float* normal) {
    if (!r || !smp) return mlb_fail(MLB_ERR_ARG, "mlb_catalogue_render: NULL argument");
    const float* k = mlb_catalogue_material_brdf(smp->mat);
    if (!k) return mlb_fail(MLB_ERR_ARG, "catalogue render: material %d out of range 0..%d", smp->mat, MLB_CATALOGUE_N_MATERIALS - 1);
    if (smp->view.env < 0 || smp->view.env >= r->n_envs)
        return mlb_fail(MLB_ERR_ARG, "catalogue render: environment %d of %d", smp->view.env, r->n_envs);
    if (r->mesh_cls != smp->cls || r->mesh_seed != smp->shape_seed) {
        mlb_mesh_free(&r->mesh);
        r->mesh_cls = -1;
        MLB_TRY(mlb_catalogue_mesh(smp->cls, smp->shape_seed, &r->mesh));
        r->mesh_cls = smp->cls;
        r->mesh_seed = smp->shape_seed;
    }
    int res = r->c.res;
    size_t P = (size_t)res * res;
    if (rgb) {
        // a shallow copy of the light: its own rotation, the shared pre-integrated cubes
        mlb_envlight light = r->lights[smp->view.env];
        mlb_envlight_set_rotation(&light, (float)(smp->view.env_rotation_deg * M_PI / 180.0));
        mlb_render_params p;
        memset(&p, 0, sizeof p);
        p.mesh = &r->mesh;
        memcpy(p.k_const, k, sizeof p.k_const);
        p.light = &light;
        p.camera = smp->view.cam;
        p.width = p.height = res;
        p.supersample = r->c.supersample;
        p.fresnel = MLB_FRESNEL_PAPER;
        MLB_TRY(mlb_views_render_target(&p, r->rgba));
        for (size_t i = 0; i < P; i++)   // [res, res, 4] → [3, res, res]
            for (int ch = 0; ch < 3; ch++) rgb[ch * P + i] = r->rgba[4 * i + ch];
    }
    if (normal) MLB_TRY(mlb_geofit_render_mesh(r->ctx, normal, &r->mesh, &smp->view.cam, res, r->c.supersample));
    return MLB_OK;
}
