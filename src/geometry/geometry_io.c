// The geometry network's configuration defaults and files (save, load, surface extraction);
// the network itself is src/geometry/geometry_net.c.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/geometry.h"

mlb_geometry_config mlb_geometry_default(void) {
    mlb_geometry_config c;
    c.enc = mlb_hashgrid_default();
    c.hidden = 32;
    c.n_hidden = 2;
    c.scale = 2.1f;
    c.seed = 1;
    return c;
}

mlb_adam_config mlb_geometry_adam(double lr) {
    mlb_adam_config a = {.lr = lr, .beta1 = 0.9, .beta2 = 0.99, .eps = 1e-15, .weight_decay = 0, .decoupled = 0};
    return a;
}

// ---- files -----------------------------------------------------------------------------------

mlb_status mlb_geometry_save(const mlb_geometry_net* net, const char* path, const mlb_st_meta* extra, size_t n_extra) {
    const mlb_geometry_config* c = &net->cfg;
    mlb_st_entry e[1 + MLB_MLP_MAX_LAYERS];
    int64_t shapes[1 + MLB_MLP_MAX_LAYERS][2];
    char names[MLB_MLP_MAX_LAYERS][32];
    shapes[0][0] = (int64_t)net->enc.offset[c->enc.n_levels];
    shapes[0][1] = c->enc.n_features;
    e[0] = (mlb_st_entry){"encoding.table", MLB_DT_F32, 2, shapes[0], net->params};
    for (int l = 0; l < net->mlp.n_layers; l++) {
        snprintf(names[l], sizeof names[l], "mlp.%d.weight", l);
        shapes[1 + l][0] = net->mlp.dims[l + 1];
        shapes[1 + l][1] = net->mlp.dims[l];
        e[1 + l] = (mlb_st_entry){names[l], MLB_DT_F32, 2, shapes[1 + l], net->mlp.weight[l]};
    }
    char v[8][64];
    snprintf(v[0], 64, "%d", c->enc.n_levels);
    snprintf(v[1], 64, "%d", c->enc.n_features);
    snprintf(v[2], 64, "%u", c->enc.table_size);
    snprintf(v[3], 64, "%d", c->enc.base_res);
    snprintf(v[4], 64, "%.17g", c->enc.per_level_scale);
    snprintf(v[5], 64, "%d", c->hidden);
    snprintf(v[6], 64, "%d", c->n_hidden);
    snprintf(v[7], 64, "%.9g", (double)c->scale);
    static const char* keys[8] = {"geometry.levels", "geometry.features", "geometry.table_size", "geometry.base_res",
                                  "geometry.per_level_scale", "geometry.hidden", "geometry.n_hidden", "geometry.scale"};
    size_t nm = 8 + n_extra;
    mlb_st_meta* meta = malloc(sizeof *meta * nm);
    if (!meta) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    for (int i = 0; i < 8; i++) meta[i] = (mlb_st_meta){keys[i], v[i]};
    for (size_t i = 0; i < n_extra; i++) meta[8 + i] = extra[i];
    mlb_status s = mlb_st_write(path, e, 1 + (size_t)net->mlp.n_layers, meta, nm);
    free(meta);
    return s;
}

static mlb_status meta_number(const mlb_safetensors* st, const char* key, double lo, double hi, double* out) {
    const char* t = mlb_st_metadata(st, key);
    if (!t) return mlb_fail(MLB_ERR_FORMAT, "%s: not a geometry network (metadata '%s' missing)", mlb_st_path(st), key);
    char* end;
    double v = strtod(t, &end);
    if (end == t || *end || !(v >= lo && v <= hi))
        return mlb_fail(MLB_ERR_FORMAT, "%s: metadata '%s' = '%s' is not a number in [%g, %g]", mlb_st_path(st), key, t, lo, hi);
    *out = v;
    return MLB_OK;
}

mlb_status mlb_geometry_load(mlb_geometry_net* net, const char* path) {
    memset(net, 0, sizeof *net);
    mlb_safetensors* st;
    mlb_status s = mlb_st_open(&st, path);
    if (s) return s;
    mlb_geometry_config c = mlb_geometry_default();
    double v[8];
    static const char* keys[8] = {"geometry.levels", "geometry.features", "geometry.table_size", "geometry.base_res",
                                  "geometry.per_level_scale", "geometry.hidden", "geometry.n_hidden", "geometry.scale"};
    static const double lo[8] = {1, 1, 1, 1, 1.0, 1, 1, 1e-6}, hi[8] = {MLB_HASHGRID_MAX_LEVELS, MLB_HASHGRID_MAX_FEATURES,
                                                                          4294967295.0, 1 << 20, 16, 4096, MLB_MLP_MAX_LAYERS - 1, 1e6};
    for (int i = 0; i < 8 && !s; i++) s = meta_number(st, keys[i], lo[i], hi[i], &v[i]);
    if (s) { mlb_st_close(st); return s; }
    c.enc.n_levels = (int)v[0];
    c.enc.n_features = (int)v[1];
    c.enc.table_size = (uint32_t)v[2];
    c.enc.base_res = (int)v[3];
    c.enc.per_level_scale = v[4];
    c.hidden = (int)v[5];
    c.n_hidden = (int)v[6];
    c.scale = (float)v[7];
    s = geometry_net_init(net, &c);
    if (s) { mlb_st_close(st); return mlb_fail_context(s, "%s", path); }
    int64_t shape[2] = {(int64_t)net->enc.offset[c.enc.n_levels], c.enc.n_features};
    s = mlb_st_expect(st, "encoding.table", 2, shape);
    if (!s) s = mlb_st_read_f32(st, "encoding.table", net->params, net->n_enc);
    for (int l = 0; l < net->mlp.n_layers && !s; l++) {
        char name[32];
        snprintf(name, sizeof name, "mlp.%d.weight", l);
        int64_t ws[2] = {net->mlp.dims[l + 1], net->mlp.dims[l]};
        s = mlb_st_expect(st, name, 2, ws);
        if (!s) s = mlb_st_read_f32(st, name, net->mlp.weight[l], (size_t)ws[0] * (size_t)ws[1]);
    }
    mlb_st_close(st);
    if (s) geometry_net_free(net);
    return s;
}

// ---- extraction --------------------------------------------------------------------------------

mlb_status mlb_geometry_extract(mlb_geometry_net* net, const mlb_tetgrid* grid, mlb_mesh* out) {
    memset(out, 0, sizeof *out);
    size_t V = (size_t)grid->n_verts;
    float* sdf = malloc(sizeof(float) * V);
    float* deform = malloc(sizeof(float) * 3 * V);
    float* pos = malloc(sizeof(float) * 3 * V);
    mlb_status s = (sdf && deform && pos) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "out of memory (%zu grid vertices)", V);
    if (!s) s = geometry_net_forward(net, sdf, deform, grid->verts, grid->n_verts);
    mlb_mt_surface surf = {0};
    if (!s) {
        dmtet_deform_forward(pos, grid->verts, deform, grid->n_verts, (float)(2 * grid->cells));
        s = marching_tets_forward(&surf, grid, pos, sdf);
    }
    if (!s && surf.n_faces == 0) s = mlb_fail(MLB_ERR_ARG, "no surface: the SDF has the same sign at every grid vertex");
    if (!s) s = mt_surface_to_mesh(&surf, out);
    mt_surface_free(&surf);
    free(sdf);
    free(deform);
    free(pos);
    return s;
}

