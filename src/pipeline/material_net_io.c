// The material network's defaults, inference entry points and files (float network); the network
// itself is src/pipeline/material_net.c (dual-compiled).
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/material_net.h"

mlb_material_config mlb_material_default(void) {
    mlb_material_config c;
    memset(&c, 0, sizeof c);
    c.enc = mlb_hashgrid_default();
    c.hidden = 32;
    c.n_hidden = 2;
    c.scale = 2.1f;
    c.mode = MLB_MATERIAL_LATENT;
    c.seed = 1;
    return c;
}

const char* mlb_material_mode_name(mlb_material_mode m) {
    return m == MLB_MATERIAL_LATENT ? "latent" : m == MLB_MATERIAL_DIRECT ? "direct" : "?";
}

mlb_status mlb_material_mode_parse(const char* text, mlb_material_mode* out) {
    if (text && !strcmp(text, "latent")) { *out = MLB_MATERIAL_LATENT; return MLB_OK; }
    if (text && !strcmp(text, "direct")) { *out = MLB_MATERIAL_DIRECT; return MLB_OK; }
    return mlb_fail(MLB_ERR_ARG, "material mode '%s': expected 'latent' or 'direct'", text ? text : "(null)");
}

mlb_adam_config mlb_material_adam(double lr) {
    mlb_adam_config a = {.lr = lr, .beta1 = 0.9, .beta2 = 0.99, .eps = 1e-15, .weight_decay = 0, .decoupled = 1};
    return a;
}

mlb_status mlb_material_eval(const mlb_material_net* net, const float* pos, size_t n, float* k) {
    return material_net_eval(net, pos, n, k, NULL);
}

mlb_status mlb_material_eval_latent(const mlb_material_net* net, const float* pos, size_t n, float* z) {
    if (net->cfg.mode != MLB_MATERIAL_LATENT) return mlb_fail(MLB_ERR_ARG, "material network: direct mode has no latent codes");
    return material_net_eval(net, pos, n, NULL, z);
}

mlb_status mlb_material_decode(const mlb_material_net* net, const float* z, size_t n, float* k) {
    return material_net_decode(net, z, n, k);
}

// ---- files -----------------------------------------------------------------------------------

enum { N_KEYS = 8 };
static const char* const config_keys[N_KEYS] = {"material.levels",   "material.features",        "material.table_size",
                                                "material.base_res", "material.per_level_scale", "material.hidden",
                                                "material.n_hidden", "material.scale"};

mlb_status mlb_material_save(const mlb_material_net* net, const char* path, int with_optimizer) {
    const mlb_material_config* c = &net->cfg;
    enum { MAX_E = 3 + 4 * MLB_MLP_MAX_LAYERS };
    mlb_st_entry e[MAX_E];
    int64_t shapes[MAX_E][2];
    char names[MAX_E][40];
    size_t ne = 0;
    shapes[0][0] = (int64_t)net->enc.offset[c->enc.n_levels];
    shapes[0][1] = c->enc.n_features;
    e[ne++] = (mlb_st_entry){"encoding.table", MLB_DT_F32, 2, shapes[0], net->params};
    const mlb_mlp* nets[2] = {&net->mlp, &net->dec};
    const char* prefix[2] = {"mlp", "decoder"};
    for (int m = 0; m < (c->mode == MLB_MATERIAL_LATENT ? 2 : 1); m++) {
        const mlb_mlp* p = nets[m];
        for (int l = 0; l < p->n_layers; l++) {
            snprintf(names[ne], sizeof names[ne], "%s.%d.weight", prefix[m], l);
            shapes[ne][0] = p->dims[l + 1];
            shapes[ne][1] = p->dims[l];
            e[ne] = (mlb_st_entry){names[ne], MLB_DT_F32, 2, shapes[ne], p->weight[l]};
            ne++;
            snprintf(names[ne], sizeof names[ne], "%s.%d.bias", prefix[m], l);
            shapes[ne][0] = p->dims[l + 1];
            e[ne] = (mlb_st_entry){names[ne], MLB_DT_F32, 1, shapes[ne], p->bias[l]};
            ne++;
        }
    }
    if (with_optimizer) {
        shapes[ne][0] = (int64_t)net->n_params;
        e[ne] = (mlb_st_entry){"adam.m", MLB_DT_F32, 1, shapes[ne], net->adam_m};
        ne++;
        shapes[ne][0] = (int64_t)net->n_params;
        e[ne] = (mlb_st_entry){"adam.v", MLB_DT_F32, 1, shapes[ne], net->adam_v};
        ne++;
    }
    char v[N_KEYS + 4][64];
    snprintf(v[0], 64, "%d", c->enc.n_levels);
    snprintf(v[1], 64, "%d", c->enc.n_features);
    snprintf(v[2], 64, "%u", c->enc.table_size);
    snprintf(v[3], 64, "%d", c->enc.base_res);
    snprintf(v[4], 64, "%.17g", c->enc.per_level_scale);
    snprintf(v[5], 64, "%d", c->hidden);
    snprintf(v[6], 64, "%d", c->n_hidden);
    snprintf(v[7], 64, "%.9g", (double)c->scale);
    mlb_st_meta meta[N_KEYS + 8];
    size_t nm = 0;
    for (int i = 0; i < N_KEYS; i++) meta[nm++] = (mlb_st_meta){config_keys[i], v[i]};
    snprintf(v[N_KEYS + 3], 64, "%llu", (unsigned long long)c->seed);
    meta[nm++] = (mlb_st_meta){"material.seed", v[N_KEYS + 3]};
    meta[nm++] = (mlb_st_meta){"format", "matlaber material network"};
    meta[nm++] = (mlb_st_meta){"material.mode", mlb_material_mode_name(c->mode)};
    if (c->mode == MLB_MATERIAL_LATENT) {
        snprintf(v[N_KEYS], 64, "%d", net->dec.dims[1]);
        snprintf(v[N_KEYS + 1], 64, "%d", net->dec.n_layers - 1);
        meta[nm++] = (mlb_st_meta){"material.decoder_hidden", v[N_KEYS]};
        meta[nm++] = (mlb_st_meta){"material.decoder_depth", v[N_KEYS + 1]};
        meta[nm++] = (mlb_st_meta){"material.decoder_activation", mlb_activation_name(net->dec.hidden_act)};
    }
    if (with_optimizer) {
        snprintf(v[N_KEYS + 2], 64, "%ld", net->step);
        meta[nm++] = (mlb_st_meta){"material.step", v[N_KEYS + 2]};
    }
    mlb_status s = mlb_st_write(path, e, ne, meta, nm);
    return s ? mlb_fail_context(s, "saving the material network") : MLB_OK;
}

// A metadata number in [lo, hi]; integral when `integer`.
static mlb_status meta_number(const mlb_safetensors* st, const char* key, double lo, double hi, int integer, double* out) {
    const char* t = mlb_st_metadata(st, key);
    if (!t) return mlb_fail(MLB_ERR_FORMAT, "%s: not a material network (metadata '%s' missing)", mlb_st_path(st), key);
    char* end;
    double v = strtod(t, &end);
    if (end == t || *end || !(v >= lo && v <= hi) || (integer && v != floor(v)))
        return mlb_fail(MLB_ERR_FORMAT, "%s: metadata '%s' = '%s' is not %s in [%g, %g]", mlb_st_path(st), key, t,
                        integer ? "an integer" : "a number", lo, hi);
    *out = v;
    return MLB_OK;
}

// Reads tensor `name` of exactly the shape {d0[, d1]} into out.
static mlb_status read_tensor(const mlb_safetensors* st, const char* name, int ndim, int64_t d0, int64_t d1, float* out) {
    int64_t shape[2] = {d0, d1};
    MLB_TRY(mlb_st_expect(st, name, ndim, shape));
    return mlb_st_read_f32(st, name, out, (size_t)d0 * (size_t)(ndim == 2 ? d1 : 1));
}

// Checks that the file holds prefix.l.weight [dims[l+1], dims[l]] and prefix.l.bias [dims[l+1]]
// for l < n_layers and nothing at layer n_layers, before anything of that size is allocated.
static mlb_status expect_mlp(const mlb_safetensors* st, const char* prefix, int n_layers, const int* dims) {
    char name[40];
    for (int l = 0; l < n_layers; l++) {
        int64_t w[2] = {dims[l + 1], dims[l]}, b[1] = {dims[l + 1]};
        snprintf(name, sizeof name, "%s.%d.weight", prefix, l);
        MLB_TRY(mlb_st_expect(st, name, 2, w));
        snprintf(name, sizeof name, "%s.%d.bias", prefix, l);
        MLB_TRY(mlb_st_expect(st, name, 1, b));
    }
    snprintf(name, sizeof name, "%s.%d.weight", prefix, n_layers);
    if (mlb_st_find(st, name))
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' is beyond the %d layers the metadata describes", mlb_st_path(st), name,
                        n_layers);
    return MLB_OK;
}

static mlb_status load_from(mlb_material_net* net, const mlb_safetensors* st) {
    const char* path = mlb_st_path(st);
    mlb_material_config c = mlb_material_default();
    double v[N_KEYS];
    static const double lo[N_KEYS] = {1, 1, 1, 1, 1.0, 1, 1, 1e-6};
    static const double hi[N_KEYS] = {MLB_HASHGRID_MAX_LEVELS, MLB_HASHGRID_MAX_FEATURES, 4294967295.0, 1 << 20, 16, 4096,
                                      MLB_MLP_MAX_LAYERS - 1, 1e6};
    static const int integer[N_KEYS] = {1, 1, 1, 1, 0, 1, 1, 0};
    for (int i = 0; i < N_KEYS; i++) MLB_TRY(meta_number(st, config_keys[i], lo[i], hi[i], integer[i], &v[i]));
    const char* seed = mlb_st_metadata(st, "material.seed");
    if (seed) {   // optional (the weights are in the file); a full 64-bit integer
        char* end;
        c.seed = strtoull(seed, &end, 10);
        if (end == seed || *end || seed[0] == '-')
            return mlb_fail(MLB_ERR_FORMAT, "%s: metadata 'material.seed' = '%s' is not an unsigned integer", path, seed);
    }
    const char* mode = mlb_st_metadata(st, "material.mode");
    if (!mode) return mlb_fail(MLB_ERR_FORMAT, "%s: not a material network (metadata 'material.mode' missing)", path);
    if (mlb_material_mode_parse(mode, &c.mode))
        return mlb_fail(MLB_ERR_FORMAT, "%s: metadata 'material.mode' = '%s' is not 'latent' or 'direct'", path, mode);
    c.enc.n_levels = (int)v[0];
    c.enc.n_features = (int)v[1];
    c.enc.table_size = (uint32_t)v[2];
    c.enc.base_res = (int)v[3];
    c.enc.per_level_scale = v[4];
    c.hidden = (int)v[5];
    c.n_hidden = (int)v[6];
    c.scale = (float)v[7];
    // Every tensor's shape follows from the metadata: check them all against the file before
    // allocating anything, so that a hostile header cannot ask for gigabytes.
    mlb_hashgrid g;
    mlb_status s = hashgrid_init(&g, &c.enc, NULL);
    if (s) return mlb_fail_context(s, "%s", path);
    int64_t table_shape[2] = {(int64_t)g.offset[c.enc.n_levels], c.enc.n_features};
    MLB_TRY(mlb_st_expect(st, "encoding.table", 2, table_shape));
    int dims[MLB_MLP_MAX_LAYERS + 1], nl = c.n_hidden + 1;
    dims[0] = g.out_dim;
    for (int l = 1; l < nl; l++) dims[l] = c.hidden;
    dims[nl] = c.mode == MLB_MATERIAL_LATENT ? MLB_LATENT_DIM : 7;
    MLB_TRY(expect_mlp(st, "mlp", nl, dims));
    const mlb_st_tensor* am = mlb_st_find(st, "adam.m");
    const mlb_st_tensor* av = mlb_st_find(st, "adam.v");
    if (!am != !av)
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' is missing (the optimizer state needs both adam.m and adam.v)", path,
                        am ? "adam.v" : "adam.m");
    mlb_brdf_ae prior;
    memset(&prior, 0, sizeof prior);
    if (c.mode == MLB_MATERIAL_LATENT) {   // a stand-in prior of the decoder's shape; its weights come from the file
        double dh, dd;
        MLB_TRY(meta_number(st, "material.decoder_hidden", 1, 4096, 1, &dh));
        MLB_TRY(meta_number(st, "material.decoder_depth", 1, MLB_MLP_MAX_LAYERS - 1, 1, &dd));
        const char* act = mlb_st_metadata(st, "material.decoder_activation");
        mlb_brdf_ae_config dc = mlb_brdf_ae_default_config();
        dc.hidden = (int)dh;
        dc.depth = (int)dd;
        if (!act || mlb_activation_parse(act, &dc.act))
            return mlb_fail(MLB_ERR_FORMAT, "%s: metadata 'material.decoder_activation' missing or unknown ('%s')", path,
                            act ? act : "");
        int ddims[MLB_MLP_MAX_LAYERS + 1];
        ddims[0] = MLB_LATENT_DIM;
        for (int l = 1; l <= dc.depth; l++) ddims[l] = dc.hidden;
        ddims[dc.depth + 1] = 7;
        MLB_TRY(expect_mlp(st, "decoder", dc.depth + 1, ddims));
        MLB_TRY(brdf_ae_init(&prior, &dc, 0));
    } else if (mlb_st_find(st, "decoder.0.weight")) {
        return mlb_fail(MLB_ERR_FORMAT, "%s: a direct-mode network with a decoder (tensor 'decoder.0.weight')", path);
    }
    s = material_net_init(net, &c, c.mode == MLB_MATERIAL_LATENT ? &prior : NULL);
    brdf_ae_free(&prior);
    if (s) return mlb_fail_context(s, "%s", path);
    s = mlb_st_read_f32(st, "encoding.table", net->params, net->n_enc);
    mlb_mlp* nets[2] = {&net->mlp, &net->dec};
    const char* prefix[2] = {"mlp", "decoder"};
    for (int m = 0; m < (c.mode == MLB_MATERIAL_LATENT ? 2 : 1) && !s; m++) {
        mlb_mlp* p = nets[m];
        for (int l = 0; l < p->n_layers && !s; l++) {
            char name[40];
            snprintf(name, sizeof name, "%s.%d.weight", prefix[m], l);
            s = read_tensor(st, name, 2, p->dims[l + 1], p->dims[l], p->weight[l]);
            snprintf(name, sizeof name, "%s.%d.bias", prefix[m], l);
            if (!s) s = read_tensor(st, name, 1, p->dims[l + 1], 0, p->bias[l]);
        }
    }
    if (s || !am) return s;
    double step;
    MLB_TRY(meta_number(st, "material.step", 0, 9007199254740992.0, 1, &step));
    MLB_TRY(read_tensor(st, "adam.m", 1, (int64_t)net->n_params, 0, net->adam_m));
    MLB_TRY(read_tensor(st, "adam.v", 1, (int64_t)net->n_params, 0, net->adam_v));
    for (size_t i = 0; i < net->n_params; i++)
        if (!(net->adam_v[i] >= 0))
            return mlb_fail(MLB_ERR_FORMAT, "%s: tensor 'adam.v' holds a negative or NaN value at index %zu", path, i);
    net->step = (long)step;
    return MLB_OK;
}

mlb_status mlb_material_load(mlb_material_net* net, const char* path) {
    memset(net, 0, sizeof *net);
    mlb_safetensors* st;
    MLB_TRY(mlb_st_open(&st, path));
    mlb_status s = load_from(net, st);
    mlb_st_close(st);
    if (s) material_net_free(net);
    return s;
}
