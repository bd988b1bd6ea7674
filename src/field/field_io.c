// Field files (include/matlaber/field.h, "files"): one format for the geometry and the material
// network, the config in metadata under the kind's prefix. Loading treats the file as hostile: every
// tensor's shape follows from the metadata and is checked before anything is allocated.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/field.h"
#include "field/field_internal.h"

enum { N_KEYS = 8 };
static const char* const key_names[N_KEYS] = {"levels", "features", "table_size", "base_res", "per_level_scale",
                                              "hidden", "n_hidden", "scale"};

static const char* prefix_of(mlb_field_kind kind) { return kind == MLB_FIELD_GEOMETRY ? "geometry" : "material"; }
static const char* mode_name(mlb_material_mode m) { return m == MLB_MATERIAL_LATENT ? "latent" : "direct"; }

// The MLP's tensors prefix.l.weight (and .bias) into e from index *ne
static void mlp_entries(const mlb_mlp* p, const char* prefix, mlb_st_entry* e, int64_t (*shapes)[2], char (*names)[40],
                        size_t* ne) {
    for (int l = 0; l < p->n_layers; l++) {
        snprintf(names[*ne], 40, "%s.%d.weight", prefix, l);
        shapes[*ne][0] = p->dims[l + 1];
        shapes[*ne][1] = p->dims[l];
        e[*ne] = (mlb_st_entry){names[*ne], MLB_DT_F32, 2, shapes[*ne], p->weight[l]};
        (*ne)++;
        if (!p->bias[l]) continue;
        snprintf(names[*ne], 40, "%s.%d.bias", prefix, l);
        shapes[*ne][0] = p->dims[l + 1];
        e[*ne] = (mlb_st_entry){names[*ne], MLB_DT_F32, 1, shapes[*ne], p->bias[l]};
        (*ne)++;
    }
}

mlb_status mlb_field_save(const mlb_field* f, const char* path, int with_optimizer, const mlb_st_meta* extra,
                          size_t n_extra) {
    const mlb_field_config* c = &f->cfg;
    if (field_device_host_behind(f))   // the state lives on the device: the caller syncs first
        return mlb_fail(MLB_ERR_ARG, "%s: the field's parameters on the %s are ahead of the host's copy "
                        "(mlb_field_sync_host first)", path, mlb_device_name(mlb_field_backend(f)->device));
    const char* prefix = prefix_of(c->kind);
    enum { MAX_E = 3 + 4 * MLB_MLP_MAX_LAYERS };
    mlb_st_entry e[MAX_E];
    int64_t shapes[MAX_E][2];
    char names[MAX_E][40];
    size_t ne = 0;
    shapes[0][0] = (int64_t)f->enc.offset[c->enc.n_levels];
    shapes[0][1] = c->enc.n_features;
    e[ne++] = (mlb_st_entry){"encoding.table", MLB_DT_F32, 2, shapes[0], f->params};
    mlp_entries(&f->mlp, "mlp", e, shapes, names, &ne);
    const int latent = c->kind == MLB_FIELD_MATERIAL && c->mode == MLB_MATERIAL_LATENT;
    if (latent) mlp_entries(&f->dec, "decoder", e, shapes, names, &ne);
    if (with_optimizer) {
        shapes[ne][0] = (int64_t)f->n_params;
        e[ne++] = (mlb_st_entry){"adam.m", MLB_DT_F32, 1, shapes[ne - 1], f->adam_m};
        shapes[ne][0] = (int64_t)f->n_params;
        e[ne++] = (mlb_st_entry){"adam.v", MLB_DT_F32, 1, shapes[ne - 1], f->adam_v};
    }
    char keys[N_KEYS + 8][48], v[N_KEYS + 8][64];
    snprintf(v[0], 64, "%d", c->enc.n_levels);
    snprintf(v[1], 64, "%d", c->enc.n_features);
    snprintf(v[2], 64, "%u", c->enc.table_size);
    snprintf(v[3], 64, "%d", c->enc.base_res);
    snprintf(v[4], 64, "%.17g", c->enc.per_level_scale);
    snprintf(v[5], 64, "%d", c->hidden);
    snprintf(v[6], 64, "%d", c->n_hidden);
    snprintf(v[7], 64, "%.9g", (double)c->scale);
    size_t nm = 0;
    mlb_st_meta* meta = malloc(sizeof *meta * (N_KEYS + 8 + n_extra));
    if (!meta) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    for (int i = 0; i < N_KEYS; i++) {
        snprintf(keys[i], sizeof keys[i], "%s.%s", prefix, key_names[i]);
        meta[nm++] = (mlb_st_meta){keys[i], v[i]};
    }
    int k = N_KEYS;   // the next free key/value slot
    snprintf(keys[k], sizeof keys[k], "%s.seed", prefix);
    snprintf(v[k], 64, "%llu", (unsigned long long)c->seed);
    meta[nm++] = (mlb_st_meta){keys[k], v[k]};
    k++;
    meta[nm++] = (mlb_st_meta){"format", c->kind == MLB_FIELD_GEOMETRY ? "matlaber geometry network" : "matlaber material network"};
    if (c->kind == MLB_FIELD_MATERIAL) meta[nm++] = (mlb_st_meta){"material.mode", mode_name(c->mode)};
    if (latent) {
        snprintf(v[k], 64, "%d", f->dec.dims[1]);
        meta[nm++] = (mlb_st_meta){"material.decoder_hidden", v[k++]};
        snprintf(v[k], 64, "%d", f->dec.n_layers - 1);
        meta[nm++] = (mlb_st_meta){"material.decoder_depth", v[k++]};
        meta[nm++] = (mlb_st_meta){"material.decoder_activation", mlb_activation_name(f->dec.hidden_act)};
    }
    if (with_optimizer) {
        snprintf(keys[k], sizeof keys[k], "%s.step", prefix);
        snprintf(v[k], 64, "%ld", f->step);
        meta[nm++] = (mlb_st_meta){keys[k], v[k]};
        k++;
    }
    for (size_t i = 0; i < n_extra; i++) meta[nm++] = extra[i];
    // never a NaN on disk: a network that diverged is an error here, not a file that loads as one
    for (size_t i = 0; i < ne; i++) {
        size_t n = (size_t)e[i].shape[0] * (size_t)(e[i].ndim == 2 ? e[i].shape[1] : 1);
        const float* x = e[i].data;
        for (size_t j = 0; j < n; j++)
            if (!isfinite(x[j])) {
                free(meta);
                return mlb_fail(MLB_ERR_NUMERIC, "%s: not written: the %s network's '%s' holds a NaN or an infinity (element %zu "
                                "of %zu): the run diverged", path, prefix, e[i].name, j, n);
            }
    }
    mlb_status s = mlb_st_write(path, e, ne, meta, nm);
    free(meta);
    return s ? mlb_fail_context(s, "saving the %s network", prefix) : MLB_OK;
}

// A metadata number in [lo, hi]; integral when `integer`.
static mlb_status meta_number(const mlb_safetensors* st, const char* prefix, const char* key, double lo, double hi,
                              int integer, double* out) {
    char full[64];
    snprintf(full, sizeof full, "%s.%s", prefix, key);
    const char* t = mlb_st_metadata(st, full);
    if (!t) return mlb_fail(MLB_ERR_FORMAT, "%s: not a %s network (metadata '%s' missing)", mlb_st_path(st), prefix, full);
    char* end;
    double v = strtod(t, &end);
    if (end == t || *end || !(v >= lo && v <= hi) || (integer && v != floor(v)))
        return mlb_fail(MLB_ERR_FORMAT, "%s: metadata '%s' = '%s' is not %s in [%g, %g]", mlb_st_path(st), full, t,
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

// Checks that the file holds prefix.l.weight [dims[l+1], dims[l]] (and prefix.l.bias [dims[l+1]]
// exactly when `bias`) for l < n_layers and nothing at layer n_layers, before anything of that
// size is allocated.
static mlb_status expect_mlp(const mlb_safetensors* st, const char* prefix, int n_layers, const int* dims, int bias) {
    char name[40];
    for (int l = 0; l < n_layers; l++) {
        int64_t w[2] = {dims[l + 1], dims[l]}, b[1] = {dims[l + 1]};
        snprintf(name, sizeof name, "%s.%d.weight", prefix, l);
        MLB_TRY(mlb_st_expect(st, name, 2, w));
        snprintf(name, sizeof name, "%s.%d.bias", prefix, l);
        if (bias) MLB_TRY(mlb_st_expect(st, name, 1, b));
        else if (mlb_st_find(st, name))
            return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': this network has no biases", mlb_st_path(st), name);
    }
    snprintf(name, sizeof name, "%s.%d.weight", prefix, n_layers);
    if (mlb_st_find(st, name))
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' is beyond the %d layers the metadata describes", mlb_st_path(st), name,
                        n_layers);
    return MLB_OK;
}

static mlb_status read_mlp(const mlb_safetensors* st, const char* prefix, mlb_mlp* p) {
    for (int l = 0; l < p->n_layers; l++) {
        char name[40];
        snprintf(name, sizeof name, "%s.%d.weight", prefix, l);
        MLB_TRY(read_tensor(st, name, 2, p->dims[l + 1], p->dims[l], p->weight[l]));
        if (!p->bias[l]) continue;
        snprintf(name, sizeof name, "%s.%d.bias", prefix, l);
        MLB_TRY(read_tensor(st, name, 1, p->dims[l + 1], 0, p->bias[l]));
    }
    return MLB_OK;
}

static mlb_status load_from(mlb_field* f, mlb_field_kind kind, const mlb_safetensors* st) {
    const char* path = mlb_st_path(st);
    const char* prefix = prefix_of(kind);
    mlb_field_config c;
    memset(&c, 0, sizeof c);
    c.kind = kind;
    c.seed = 1;
    double v[N_KEYS];
    static const double lo[N_KEYS] = {1, 1, 1, 1, 1.0, 1, 1, 1e-6};
    static const double hi[N_KEYS] = {MLB_HASHGRID_MAX_LEVELS, MLB_HASHGRID_MAX_FEATURES, 4294967295.0, 1 << 20, 16, 4096,
                                      MLB_MLP_MAX_LAYERS - 1, 1e6};
    static const int integer[N_KEYS] = {1, 1, 1, 1, 0, 1, 1, 0};
    for (int i = 0; i < N_KEYS; i++) MLB_TRY(meta_number(st, prefix, key_names[i], lo[i], hi[i], integer[i], &v[i]));
    char key[48];
    snprintf(key, sizeof key, "%s.seed", prefix);
    const char* seed = mlb_st_metadata(st, key);
    if (seed) {   // optional (the weights are in the file); a full 64-bit integer
        char* end;
        c.seed = strtoull(seed, &end, 10);
        if (end == seed || *end || seed[0] == '-')
            return mlb_fail(MLB_ERR_FORMAT, "%s: metadata '%s' = '%s' is not an unsigned integer", path, key, seed);
    }
    if (kind == MLB_FIELD_MATERIAL) {
        const char* mode = mlb_st_metadata(st, "material.mode");
        if (!mode) return mlb_fail(MLB_ERR_FORMAT, "%s: not a material network (metadata 'material.mode' missing)", path);
        if (!strcmp(mode, "latent")) c.mode = MLB_MATERIAL_LATENT;
        else if (!strcmp(mode, "direct")) c.mode = MLB_MATERIAL_DIRECT;
        else return mlb_fail(MLB_ERR_FORMAT, "%s: metadata 'material.mode' = '%s' is not 'latent' or 'direct'", path, mode);
    }
    c.enc.n_levels = (int)v[0];
    c.enc.n_features = (int)v[1];
    c.enc.table_size = (uint32_t)v[2];
    c.enc.base_res = (int)v[3];
    c.enc.per_level_scale = v[4];
    c.hidden = (int)v[5];
    c.n_hidden = (int)v[6];
    c.scale = (float)v[7];
    const int latent = kind == MLB_FIELD_MATERIAL && c.mode == MLB_MATERIAL_LATENT, bias = kind == MLB_FIELD_MATERIAL;
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
    dims[nl] = kind == MLB_FIELD_MATERIAL && c.mode == MLB_MATERIAL_DIRECT ? 7 : 4;
    MLB_TRY(expect_mlp(st, "mlp", nl, dims, bias));
    const mlb_st_tensor* am = mlb_st_find(st, "adam.m");
    const mlb_st_tensor* av = mlb_st_find(st, "adam.v");
    if (!am != !av)
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' is missing (the optimizer state needs both adam.m and adam.v)", path,
                        am ? "adam.v" : "adam.m");
    mlb_brdf_ae prior;
    memset(&prior, 0, sizeof prior);
    if (latent) {   // a stand-in prior of the decoder's shape; its weights come from the file
        double dh, dd;
        MLB_TRY(meta_number(st, "material", "decoder_hidden", 1, 4096, 1, &dh));
        MLB_TRY(meta_number(st, "material", "decoder_depth", 1, MLB_MLP_MAX_LAYERS - 1, 1, &dd));
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
        MLB_TRY(expect_mlp(st, "decoder", dc.depth + 1, ddims, 1));
        MLB_TRY(brdf_ae_init(&prior, &dc, 0));
    } else if (mlb_st_find(st, "decoder.0.weight")) {
        return mlb_fail(MLB_ERR_FORMAT, "%s: a %s network with a decoder (tensor 'decoder.0.weight')", path,
                        kind == MLB_FIELD_GEOMETRY ? "geometry" : "direct-mode");
    }
    s = field_init(f, &c, latent ? &prior : NULL);
    brdf_ae_free(&prior);
    if (s) return mlb_fail_context(s, "%s", path);
    s = mlb_st_read_f32(st, "encoding.table", f->params, f->n_enc);
    if (!s) s = read_mlp(st, "mlp", &f->mlp);
    if (!s && latent) s = read_mlp(st, "decoder", &f->dec);
    if (s || !am) return s;
    double step;
    MLB_TRY(meta_number(st, prefix, "step", 0, 9007199254740992.0, 1, &step));
    MLB_TRY(read_tensor(st, "adam.m", 1, (int64_t)f->n_params, 0, f->adam_m));
    MLB_TRY(read_tensor(st, "adam.v", 1, (int64_t)f->n_params, 0, f->adam_v));
    for (size_t i = 0; i < f->n_params; i++)
        if (!(f->adam_v[i] >= 0))
            return mlb_fail(MLB_ERR_FORMAT, "%s: tensor 'adam.v' holds a negative or NaN value at index %zu", path, i);
    f->step = (long)step;
    return MLB_OK;
}

mlb_status mlb_field_load(mlb_field* f, mlb_field_kind kind, const char* path) {
    memset(f, 0, sizeof *f);
    mlb_safetensors* st;
    MLB_TRY(mlb_st_open(&st, path));
    mlb_status s = load_from(f, kind, st);
    mlb_st_close(st);
    if (s) field_free(f);
    return s;
}
