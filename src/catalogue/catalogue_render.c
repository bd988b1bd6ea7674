// The catalogue's renderer (include/matlaber/catalogue.h, docs/catalogue.md): a sample's mesh
// (catalogue_shapes.c) in its material under one of a few environments, as the views' render target
// (colour) and the geometry fit's normal map. Apart from catalogue.c, whose names the shapes take:
// the renderer takes the shapes, so in one file with the names the two would call each other.
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/catalogue.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/render.h"
#include "matlaber/views.h"
#include "catalogue_internal.h"

struct mlb_catalogue_renderer {
    mlb_catalogue_render_config c;
    int n_envs;
    mlb_envmap maps[MLB_CATALOGUE_MAX_ENVS];
    mlb_envlight lights[MLB_CATALOGUE_MAX_ENVS];
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
    r->rgba = malloc(sizeof(float) * 4 * (size_t)c.res * c.res);
    mlb_status s = r->rgba ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "catalogue renderer: out of memory");
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
    if (normal) MLB_TRY(mlb_geofit_render_mesh(NULL, normal, &r->mesh, &smp->view.cam, res, r->c.supersample));
    return MLB_OK;
}
