// The SD VAE's tensor names in both layouts, loading (diffusers folders and files, single-file
// checkpoints, ldm VAE files), saving, the double copy and random weights (vae.h). Its
// configuration: vae_config.c.
#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include "matlaber/fileio.h"
#include "matlaber/sd_files.h"
#include "matlaber/rng.h"
#include "matlaber/vae.h"

#define VAE_CONFIG_MAX (1 << 20)

// ---- tensor names ----------------------------------------------------------------------------------
enum { VT_CONV, VT_LIN, VT_BIAS, VT_NORM_W, VT_NORM_B };
typedef struct {
    char dn[112], ln[112];   // diffusers and ldm names, no prefix
    int kind, ndim;          // ndim/shape in the diffusers layout (VT_LIN: [C, C]; the ldm file has [C, C, 1, 1])
    int64_t shape[4];
    float* dst;
    size_t n;
} vae_tdesc;

typedef struct {
    vae_tdesc* all;      // every descriptor (when not NULL)
    size_t target;       // else only this one goes to *one
    vae_tdesc* one;
    size_t count;
} emitter;

static void emit(emitter* e, const char* dn, const char* ln, int kind, float* dst, int ndim, int64_t d0, int64_t d1,
                 int64_t d2, int64_t d3) {
    vae_tdesc* t = e->all ? &e->all[e->count] : (e->one && e->count == e->target ? e->one : NULL);
    e->count++;
    if (!t) return;
    snprintf(t->dn, sizeof t->dn, "%s", dn);
    snprintf(t->ln, sizeof t->ln, "%s", ln);
    t->kind = kind;
    t->ndim = ndim;
    int64_t s[4] = {d0, d1, d2, d3};
    t->n = 1;
    for (int i = 0; i < 4; i++) { t->shape[i] = i < ndim ? s[i] : 0; if (i < ndim) t->n *= (size_t)s[i]; }
    t->dst = dst;
}

// Emits `<dp><leaf_d>` / `<lp><leaf_l>`.
static void emit2(emitter* e, const char* dp, const char* lp, const char* leaf_d, const char* leaf_l, int kind,
                  float* dst, int ndim, int64_t d0, int64_t d1, int64_t d2, int64_t d3) {
    char dn[112], ln[112];
    snprintf(dn, sizeof dn, "%s%s", dp, leaf_d);
    snprintf(ln, sizeof ln, "%s%s", lp, leaf_l);
    emit(e, dn, ln, kind, dst, ndim, d0, d1, d2, d3);
}

static void emit_resnet(emitter* e, const char* dp, const char* lp, const mlb_vae_resnet* r) {
    int64_t ci = r->cin, co = r->cout;
    emit2(e, dp, lp, "norm1.weight", "norm1.weight", VT_NORM_W, r->norm1_w, 1, ci, 0, 0, 0);
    emit2(e, dp, lp, "norm1.bias", "norm1.bias", VT_NORM_B, r->norm1_b, 1, ci, 0, 0, 0);
    emit2(e, dp, lp, "conv1.weight", "conv1.weight", VT_CONV, r->conv1_w, 4, co, ci, 3, 3);
    emit2(e, dp, lp, "conv1.bias", "conv1.bias", VT_BIAS, r->conv1_b, 1, co, 0, 0, 0);
    emit2(e, dp, lp, "norm2.weight", "norm2.weight", VT_NORM_W, r->norm2_w, 1, co, 0, 0, 0);
    emit2(e, dp, lp, "norm2.bias", "norm2.bias", VT_NORM_B, r->norm2_b, 1, co, 0, 0, 0);
    emit2(e, dp, lp, "conv2.weight", "conv2.weight", VT_CONV, r->conv2_w, 4, co, co, 3, 3);
    emit2(e, dp, lp, "conv2.bias", "conv2.bias", VT_BIAS, r->conv2_b, 1, co, 0, 0, 0);
    if (r->short_w) {
        emit2(e, dp, lp, "conv_shortcut.weight", "nin_shortcut.weight", VT_CONV, r->short_w, 4, co, ci, 1, 1);
        emit2(e, dp, lp, "conv_shortcut.bias", "nin_shortcut.bias", VT_BIAS, r->short_b, 1, co, 0, 0, 0);
    }
}

static void emit_attn(emitter* e, const char* dp, const char* lp, const mlb_vae_attn* a) {
    int64_t C = a->C;
    size_t CC = (size_t)C * C;
    emit2(e, dp, lp, "group_norm.weight", "norm.weight", VT_NORM_W, a->norm_w, 1, C, 0, 0, 0);
    emit2(e, dp, lp, "group_norm.bias", "norm.bias", VT_NORM_B, a->norm_b, 1, C, 0, 0, 0);
    static const char* dq[] = {"to_q", "to_k", "to_v"};
    static const char* lq[] = {"q", "k", "v"};
    char d[32], l[32];
    for (int i = 0; i < 3; i++) {
        snprintf(d, sizeof d, "%s.weight", dq[i]); snprintf(l, sizeof l, "%s.weight", lq[i]);
        emit2(e, dp, lp, d, l, VT_LIN, a->qkv_w + i * CC, 2, C, C, 0, 0);
        snprintf(d, sizeof d, "%s.bias", dq[i]); snprintf(l, sizeof l, "%s.bias", lq[i]);
        emit2(e, dp, lp, d, l, VT_BIAS, a->qkv_b + i * C, 1, C, 0, 0, 0);
    }
    emit2(e, dp, lp, "to_out.0.weight", "proj_out.weight", VT_LIN, a->proj_w, 2, C, C, 0, 0);
    emit2(e, dp, lp, "to_out.0.bias", "proj_out.bias", VT_BIAS, a->proj_b, 1, C, 0, 0, 0);
}

static void emit_all(emitter* e, const mlb_vae* v) {
    const mlb_vae_config* g = &v->cfg;
    const int L = g->n_levels, R = g->layers_per_block;
    int64_t b0 = g->block_out[0], top = g->block_out[L - 1], z = g->latent_channels;
    char dp[96], lp[96];
    emit(e, "encoder.conv_in.weight", "encoder.conv_in.weight", VT_CONV, v->enc_conv_in_w, 4, b0, g->in_channels, 3, 3);
    emit(e, "encoder.conv_in.bias", "encoder.conv_in.bias", VT_BIAS, v->enc_conv_in_b, 1, b0, 0, 0, 0);
    for (int l = 0; l < L; l++) {
        for (int j = 0; j < R; j++) {
            snprintf(dp, sizeof dp, "encoder.down_blocks.%d.resnets.%d.", l, j);
            snprintf(lp, sizeof lp, "encoder.down.%d.block.%d.", l, j);
            emit_resnet(e, dp, lp, &v->enc_res[l][j]);
        }
        if (l < L - 1) {
            int64_t c = g->block_out[l];
            snprintf(dp, sizeof dp, "encoder.down_blocks.%d.downsamplers.0.conv.", l);
            snprintf(lp, sizeof lp, "encoder.down.%d.downsample.conv.", l);
            emit2(e, dp, lp, "weight", "weight", VT_CONV, v->enc_down_w[l], 4, c, c, 3, 3);
            emit2(e, dp, lp, "bias", "bias", VT_BIAS, v->enc_down_b[l], 1, c, 0, 0, 0);
        }
    }
    for (int side = 0; side < 2; side++) {   // encoder then decoder mid blocks
        const char* d = side ? "decoder" : "encoder";
        const mlb_vae_resnet* mr = side ? v->dec_mid_res : v->enc_mid_res;
        if (side) {
            emit(e, "post_quant_conv.weight", "post_quant_conv.weight", VT_CONV, v->post_quant_w, 4, z, z, 1, 1);
            emit(e, "post_quant_conv.bias", "post_quant_conv.bias", VT_BIAS, v->post_quant_b, 1, z, 0, 0, 0);
            emit(e, "decoder.conv_in.weight", "decoder.conv_in.weight", VT_CONV, v->dec_conv_in_w, 4, top, z, 3, 3);
            emit(e, "decoder.conv_in.bias", "decoder.conv_in.bias", VT_BIAS, v->dec_conv_in_b, 1, top, 0, 0, 0);
        }
        snprintf(dp, sizeof dp, "%s.mid_block.resnets.0.", d);
        snprintf(lp, sizeof lp, "%s.mid.block_1.", d);
        emit_resnet(e, dp, lp, &mr[0]);
        if (g->mid_attention) {
            snprintf(dp, sizeof dp, "%s.mid_block.attentions.0.", d);
            snprintf(lp, sizeof lp, "%s.mid.attn_1.", d);
            emit_attn(e, dp, lp, side ? &v->dec_mid_attn : &v->enc_mid_attn);
        }
        snprintf(dp, sizeof dp, "%s.mid_block.resnets.1.", d);
        snprintf(lp, sizeof lp, "%s.mid.block_2.", d);
        emit_resnet(e, dp, lp, &mr[1]);
        if (!side) {
            emit(e, "encoder.conv_norm_out.weight", "encoder.norm_out.weight", VT_NORM_W, v->enc_norm_out_w, 1, top, 0, 0, 0);
            emit(e, "encoder.conv_norm_out.bias", "encoder.norm_out.bias", VT_NORM_B, v->enc_norm_out_b, 1, top, 0, 0, 0);
            emit(e, "encoder.conv_out.weight", "encoder.conv_out.weight", VT_CONV, v->enc_conv_out_w, 4, 2 * z, top, 3, 3);
            emit(e, "encoder.conv_out.bias", "encoder.conv_out.bias", VT_BIAS, v->enc_conv_out_b, 1, 2 * z, 0, 0, 0);
            emit(e, "quant_conv.weight", "quant_conv.weight", VT_CONV, v->quant_w, 4, 2 * z, 2 * z, 1, 1);
            emit(e, "quant_conv.bias", "quant_conv.bias", VT_BIAS, v->quant_b, 1, 2 * z, 0, 0, 0);
        }
    }
    for (int i = 0; i < L; i++) {
        for (int j = 0; j <= R; j++) {
            snprintf(dp, sizeof dp, "decoder.up_blocks.%d.resnets.%d.", i, j);
            snprintf(lp, sizeof lp, "decoder.up.%d.block.%d.", L - 1 - i, j);
            emit_resnet(e, dp, lp, &v->dec_res[i][j]);
        }
        if (i < L - 1) {
            int64_t c = v->dec_res[i][0].cout;
            snprintf(dp, sizeof dp, "decoder.up_blocks.%d.upsamplers.0.conv.", i);
            snprintf(lp, sizeof lp, "decoder.up.%d.upsample.conv.", L - 1 - i);
            emit2(e, dp, lp, "weight", "weight", VT_CONV, v->dec_up_w[i], 4, c, c, 3, 3);
            emit2(e, dp, lp, "bias", "bias", VT_BIAS, v->dec_up_b[i], 1, c, 0, 0, 0);
        }
    }
    emit(e, "decoder.conv_norm_out.weight", "decoder.norm_out.weight", VT_NORM_W, v->dec_norm_out_w, 1, b0, 0, 0, 0);
    emit(e, "decoder.conv_norm_out.bias", "decoder.norm_out.bias", VT_NORM_B, v->dec_norm_out_b, 1, b0, 0, 0, 0);
    emit(e, "decoder.conv_out.weight", "decoder.conv_out.weight", VT_CONV, v->dec_conv_out_w, 4, g->out_channels, b0, 3, 3);
    emit(e, "decoder.conv_out.bias", "decoder.conv_out.bias", VT_BIAS, v->dec_conv_out_b, 1, g->out_channels, 0, 0, 0);
}

size_t mlb_vae_tensor_count(const mlb_vae* v) {
    if (!v) return 0;
    emitter e = {NULL, 0, NULL, 0};
    emit_all(&e, v);
    return e.count;
}

static void to_public(const vae_tdesc* t, mlb_vae_layout layout, mlb_vae_tensor* out) {
    memset(out, 0, sizeof *out);
    snprintf(out->name, sizeof out->name, "%s", layout == MLB_VAE_LAYOUT_LDM ? t->ln : t->dn);
    out->ndim = t->ndim;
    memcpy(out->shape, t->shape, sizeof out->shape);
    if (layout == MLB_VAE_LAYOUT_LDM && t->kind == VT_LIN) { out->ndim = 4; out->shape[2] = out->shape[3] = 1; }
    out->data = t->dst;
    out->n = t->n;
}

mlb_status mlb_vae_tensor_at(const mlb_vae* v, size_t i, mlb_vae_layout layout, mlb_vae_tensor* out) {
    if (!v || !out) return mlb_fail(MLB_ERR_ARG, "VAE tensor: NULL argument");
    if (layout != MLB_VAE_LAYOUT_DIFFUSERS && layout != MLB_VAE_LAYOUT_LDM)
        return mlb_fail(MLB_ERR_ARG, "VAE tensor: unknown layout %d", (int)layout);
    vae_tdesc t;
    emitter e = {NULL, i, &t, 0};
    emit_all(&e, v);
    if (i >= e.count) return mlb_fail(MLB_ERR_ARG, "VAE tensor %zu: the model has %zu tensors", i, e.count);
    to_public(&t, layout, out);
    return MLB_OK;
}

static mlb_status all_tensors(const mlb_vae* v, vae_tdesc** out, size_t* n) {
    *n = mlb_vae_tensor_count(v);
    *out = calloc(*n, sizeof **out);
    if (!*out) return mlb_fail(MLB_ERR_NOMEM, "VAE: out of memory");
    emitter e = {*out, 0, NULL, 0};
    emit_all(&e, v);
    return MLB_OK;
}

// ---- config.json and ldm_config ------------------------------------------------------------------
typedef struct {
    int in, out, latent, levels, layers, groups, attn;   // 0 / -1 (attn) = absent
    int block_out[MLB_VAE_MAX_LEVELS + 1];
    double scaling;                                      // 0 = absent
    char from[32];
} vae_cfg_file;

static int json_count(const cJSON* v) {   // a whole number in [1, 2^20], else -1
    if (!cJSON_IsNumber(v) || v->valuedouble < 1 || v->valuedouble > (1 << 20) || v->valuedouble != floor(v->valuedouble))
        return -1;
    return (int)v->valuedouble;
}

// Reads integer `key` of object `o` into *dst; an absent key leaves it. A bad value is an error.
static mlb_status json_int(const cJSON* o, const char* key, int* dst, const char* file) {
    const cJSON* v = cJSON_GetObjectItemCaseSensitive(o, key);
    if (!v) return MLB_OK;
    int n = json_count(v);
    if (n < 0) return mlb_fail(MLB_ERR_FORMAT, "%s: '%s' is not a positive integer", file, key);
    *dst = n;
    return MLB_OK;
}

static mlb_status json_int_list(const cJSON* o, const char* key, vae_cfg_file* c, int mult, const char* file) {
    const cJSON* a = cJSON_GetObjectItemCaseSensitive(o, key);
    if (!a) return MLB_OK;
    int n = cJSON_IsArray(a) ? cJSON_GetArraySize(a) : -1;
    if (n < 1 || n > MLB_VAE_MAX_LEVELS)
        return mlb_fail(MLB_ERR_FORMAT, "%s: '%s' is not a list of 1 to %d integers", file, key, MLB_VAE_MAX_LEVELS);
    for (int i = 0; i < n; i++) {
        int v = json_count(cJSON_GetArrayItem(a, i));
        if (v < 0) return mlb_fail(MLB_ERR_FORMAT, "%s: '%s'[%d] is not a positive integer", file, key, i);
        c->block_out[i] = v * mult;
    }
    c->levels = n;
    return MLB_OK;
}

static mlb_status parse_config_json(const char* path, vae_cfg_file* c) {
    cJSON* root;
    MLB_TRY(mlb_json_read_file(path, VAE_CONFIG_MAX, &root));
    mlb_status s = MLB_OK;
    const cJSON* cls = cJSON_GetObjectItemCaseSensitive(root, "_class_name");
    const cJSON* act = cJSON_GetObjectItemCaseSensitive(root, "act_fn");
    const cJSON* attn = cJSON_GetObjectItemCaseSensitive(root, "mid_block_add_attention");
    const cJSON* sf = cJSON_GetObjectItemCaseSensitive(root, "scaling_factor");
    if (!cJSON_IsObject(root)) s = mlb_fail(MLB_ERR_FORMAT, "%s: expected a JSON object", path);
    else if (cJSON_IsString(cls) && strcmp(cls->valuestring, "AutoencoderKL") != 0)
        s = mlb_fail(MLB_ERR_UNSUPPORTED, "%s: _class_name '%s' is not an AutoencoderKL", path, cls->valuestring);
    else if (act && (!cJSON_IsString(act) || strcmp(act->valuestring, "silu") != 0))
        s = mlb_fail(MLB_ERR_UNSUPPORTED, "%s: act_fn must be 'silu'", path);
    if (!s) s = json_int(root, "in_channels", &c->in, path);
    if (!s) s = json_int(root, "out_channels", &c->out, path);
    if (!s) s = json_int(root, "latent_channels", &c->latent, path);
    if (!s) s = json_int(root, "layers_per_block", &c->layers, path);
    if (!s) s = json_int(root, "norm_num_groups", &c->groups, path);
    if (!s) s = json_int_list(root, "block_out_channels", c, 1, path);
    if (!s && attn) {
        if (!cJSON_IsBool(attn)) s = mlb_fail(MLB_ERR_FORMAT, "%s: 'mid_block_add_attention' is not true or false", path);
        else c->attn = cJSON_IsTrue(attn);
    }
    if (!s && sf) {
        if (!cJSON_IsNumber(sf) || !(sf->valuedouble > 0)) s = mlb_fail(MLB_ERR_FORMAT, "%s: 'scaling_factor' is not a positive number", path);
        else c->scaling = sf->valuedouble;
    }
    cJSON_Delete(root);
    snprintf(c->from, sizeof c->from, "config.json");
    return s;
}

// The ldm_config metadata: first_stage_config.params.{embed_dim, ddconfig{ch, ch_mult, ...}} and
// the LatentDiffusion scale_factor. Unparsable or absent metadata is ignored (published files
// carry none); present but wrong values are errors.
static mlb_status parse_ldm_config(const mlb_safetensors* st, vae_cfg_file* c) {
    cJSON* root = mlb_sd_ldm_config(st, NULL);
    if (!root) return MLB_OK;
    const char* file = mlb_st_path(st);
    mlb_status s = MLB_OK;
    const cJSON* fs = mlb_json_find(root, "first_stage_config");
    const cJSON* dd = fs ? mlb_json_find(fs, "ddconfig") : NULL;
    if (dd) {
        int ch = 0;
        s = json_int(dd, "ch", &ch, file);
        if (!s) s = json_int(dd, "in_channels", &c->in, file);
        if (!s) s = json_int(dd, "out_ch", &c->out, file);
        if (!s) s = json_int(dd, "z_channels", &c->latent, file);
        if (!s) s = json_int(dd, "num_res_blocks", &c->layers, file);
        if (!s && ch) s = json_int_list(dd, "ch_mult", c, ch, file);
        const cJSON* ar = cJSON_GetObjectItemCaseSensitive(dd, "attn_resolutions");
        if (!s && cJSON_IsArray(ar) && cJSON_GetArraySize(ar) > 0)
            s = mlb_fail(MLB_ERR_UNSUPPORTED, "%s: ldm_config asks for attention in the VAE's down/up blocks "
                         "(attn_resolutions); only the mid-block attention of the SD VAE is supported", file);
    }
    const cJSON* sf = mlb_json_find(root, "scale_factor");
    if (!s && cJSON_IsNumber(sf) && sf->valuedouble > 0) c->scaling = sf->valuedouble;
    cJSON_Delete(root);
    snprintf(c->from, sizeof c->from, "ldm_config");
    return s;
}

// ---- layout detection and sizes from the shapes ---------------------------------------------------
typedef struct { mlb_vae_layout layout; const char* prefix; } vae_names;

static const mlb_st_tensor* find_pf(const mlb_safetensors* st, const char* prefix, const char* name, char* full,
                                    size_t cap) {
    snprintf(full, cap, "%s%s", prefix, name);
    return mlb_st_find(st, full);
}

static mlb_status detect_layout(const mlb_safetensors* st, vae_names* nm) {
    static const char* prefixes[] = {"first_stage_model.", "", "vae."};
    char full[256];
    for (int i = 0; i < 3; i++) {
        if (find_pf(st, prefixes[i], "encoder.down_blocks.0.resnets.0.conv1.weight", full, sizeof full)) {
            nm->layout = MLB_VAE_LAYOUT_DIFFUSERS; nm->prefix = prefixes[i]; return MLB_OK;
        }
        if (find_pf(st, prefixes[i], "encoder.down.0.block.0.conv1.weight", full, sizeof full)) {
            nm->layout = MLB_VAE_LAYOUT_LDM; nm->prefix = prefixes[i]; return MLB_OK;
        }
    }
    return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no VAE found: expected the tensors first_stage_model.encoder.* (single "
                    "file), encoder.down_blocks.* (diffusers vae) or encoder.down.* (ldm VAE file)", mlb_st_path(st));
}

// Dimension `dim` of tensor `name` (which must exist with `ndim` dimensions).
static mlb_status shape_dim(const mlb_safetensors* st, const vae_names* nm, const char* name, int ndim, int dim,
                            int* out) {
    char full[256];
    const mlb_st_tensor* t = find_pf(st, nm->prefix, name, full, sizeof full);
    if (!t) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no tensor named '%s'", mlb_st_path(st), full);
    if (t->ndim != ndim || t->shape[dim] < 1 || t->shape[dim] > 65536)
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' has %d dimensions, expected %d", mlb_st_path(st), full,
                        t->ndim, ndim);
    *out = (int)t->shape[dim];
    return MLB_OK;
}

static mlb_status config_from_shapes(const mlb_safetensors* st, const vae_names* nm, mlb_vae_config* c) {
    int d = nm->layout == MLB_VAE_LAYOUT_DIFFUSERS;
    char name[160], full[256];
    *c = mlb_vae_sd_config();
    MLB_TRY(shape_dim(st, nm, "encoder.conv_in.weight", 4, 1, &c->in_channels));
    int L = 0;
    for (; L <= MLB_VAE_MAX_LEVELS; L++) {
        snprintf(name, sizeof name, d ? "encoder.down_blocks.%d.resnets.0.conv1.weight" : "encoder.down.%d.block.0.conv1.weight", L);
        if (!find_pf(st, nm->prefix, name, full, sizeof full)) break;
        if (L == MLB_VAE_MAX_LEVELS)
            return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: the VAE has more than %d levels", mlb_st_path(st), MLB_VAE_MAX_LEVELS);
        MLB_TRY(shape_dim(st, nm, name, 4, 0, &c->block_out[L]));
    }
    c->n_levels = L;
    int R = 0;
    for (; R <= MLB_VAE_MAX_LAYERS; R++) {
        snprintf(name, sizeof name, d ? "encoder.down_blocks.0.resnets.%d.conv1.weight" : "encoder.down.0.block.%d.conv1.weight", R);
        if (!find_pf(st, nm->prefix, name, full, sizeof full)) break;
        if (R == MLB_VAE_MAX_LAYERS)
            return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: the VAE has more than %d ResNet blocks per level", mlb_st_path(st),
                            MLB_VAE_MAX_LAYERS);
    }
    c->layers_per_block = R;
    MLB_TRY(shape_dim(st, nm, "post_quant_conv.weight", 4, 0, &c->latent_channels));
    MLB_TRY(shape_dim(st, nm, "decoder.conv_out.weight", 4, 0, &c->out_channels));
    c->mid_attention = find_pf(st, nm->prefix, d ? "encoder.mid_block.attentions.0.group_norm.weight" : "encoder.mid.attn_1.norm.weight",
                               full, sizeof full) != NULL;
    if (find_pf(st, nm->prefix, d ? "encoder.down_blocks.0.attentions.0.group_norm.weight" : "encoder.down.0.attn.0.norm.weight",
                full, sizeof full))
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: tensor '%s': attention inside the VAE's down blocks is not supported "
                        "(only the SD VAE's mid-block attention)", mlb_st_path(st), full);
    return MLB_OK;
}

static mlb_status agree(const char* cfg_file, const char* key, int cfg_value, int weights_value, const char* st_path) {
    if (cfg_value && cfg_value != weights_value)
        return mlb_fail(MLB_ERR_FORMAT, "%s: %s is %d but the weights in %s have %d", cfg_file, key, cfg_value, st_path,
                        weights_value);
    return MLB_OK;
}

static mlb_status apply_config(const vae_cfg_file* f, const char* cfg_name, mlb_vae_config* c, const char* st_path) {
    int ldm = !strcmp(f->from, "ldm_config");
    MLB_TRY(agree(cfg_name, ldm ? "in_channels" : "in_channels", f->in, c->in_channels, st_path));
    MLB_TRY(agree(cfg_name, ldm ? "out_ch" : "out_channels", f->out, c->out_channels, st_path));
    MLB_TRY(agree(cfg_name, ldm ? "z_channels" : "latent_channels", f->latent, c->latent_channels, st_path));
    MLB_TRY(agree(cfg_name, ldm ? "num_res_blocks" : "layers_per_block", f->layers, c->layers_per_block, st_path));
    const char* list = ldm ? "ch * ch_mult" : "block_out_channels";
    if (f->levels && f->levels != c->n_levels)
        return mlb_fail(MLB_ERR_FORMAT, "%s: %s has %d levels but the weights in %s have %d", cfg_name, list, f->levels,
                        st_path, c->n_levels);
    char key[64];
    for (int l = 0; l < f->levels; l++) {
        snprintf(key, sizeof key, "%s[%d]", list, l);
        MLB_TRY(agree(cfg_name, key, f->block_out[l], c->block_out[l], st_path));
    }
    if (f->attn == 1 && !c->mid_attention)
        return mlb_fail(MLB_ERR_NOT_FOUND, "%s: mid_block_add_attention is true but %s holds no mid-block attention",
                        cfg_name, st_path);
    if (f->attn == 0 && c->mid_attention) c->mid_attention = 0;   // diffusers ignores the stored tensors then
    if (f->groups) c->norm_groups = f->groups;
    if (f->scaling > 0) c->scaling_factor = (float)f->scaling;
    return MLB_OK;
}

// ---- loading ---------------------------------------------------------------------------------------

static void fmt_shape(char* buf, size_t cap, int ndim, const int64_t* shape) {
    size_t n = (size_t)snprintf(buf, cap, "[");
    for (int i = 0; i < ndim && n < cap; i++)
        n += (size_t)snprintf(buf + n, cap - n, "%s%lld", i ? ", " : "", (long long)shape[i]);
    if (n < cap) snprintf(buf + n, cap - n, "]");
}

// One tensor: found under the layout's name (diffusers attention also under its pre-0.14 names),
// shape checked (attention matrices as [C, C] or [C, C, 1, 1] in either layout), converted.
static mlb_status load_one(const mlb_safetensors* st, const vae_names* nm, const vae_tdesc* t) {
    static const char* old_new[][2] = {{"to_q.", "query."}, {"to_k.", "key."}, {"to_v.", "value."}, {"to_out.0.", "proj_attn."}};
    const char* base = nm->layout == MLB_VAE_LAYOUT_LDM ? t->ln : t->dn;
    char full[256], have[96], want[96];
    snprintf(full, sizeof full, "%s%s", nm->prefix, base);
    const mlb_st_tensor* x = mlb_st_find(st, full);
    if (!x && nm->layout == MLB_VAE_LAYOUT_DIFFUSERS && strstr(base, ".attentions."))
        for (int i = 0; i < 4 && !x; i++) {
            const char* at = strstr(base, old_new[i][0]);
            if (!at) continue;
            char alt[256];
            snprintf(alt, sizeof alt, "%s%.*s%s%s", nm->prefix, (int)(at - base), base, old_new[i][1],
                     at + strlen(old_new[i][0]));
            if ((x = mlb_st_find(st, alt))) snprintf(full, sizeof full, "%s", alt);
        }
    if (!x) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no tensor named '%s'", mlb_st_path(st), full);
    int ok = x->ndim == t->ndim;
    for (int i = 0; ok && i < t->ndim; i++) ok = x->shape[i] == t->shape[i];
    if (!ok && t->kind == VT_LIN)
        ok = x->ndim == 4 && x->shape[0] == t->shape[0] && x->shape[1] == t->shape[1] && x->shape[2] == 1 && x->shape[3] == 1;
    if (!ok) {
        fmt_shape(have, sizeof have, x->ndim, x->shape);
        fmt_shape(want, sizeof want, t->ndim, t->shape);
        if (t->kind == VT_LIN)
            snprintf(want + strlen(want), sizeof want - strlen(want), " or [%lld, %lld, 1, 1]", (long long)t->shape[0],
                     (long long)t->shape[1]);
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' has shape %s, expected %s", mlb_st_path(st), full, have, want);
    }
    return mlb_st_read_f32(st, full, t->dst, t->n);
}

mlb_status mlb_vae_from_st(const mlb_safetensors* st, const char* config_path, const mlb_vae_options* opt,
                           mlb_vae** out) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "VAE: NULL output");
    *out = NULL;
    if (!st) return mlb_fail(MLB_ERR_ARG, "VAE: NULL safetensors handle");
    if (!config_path && opt) config_path = opt->config_path;
    const char* path = mlb_st_path(st);
    vae_names nm = {MLB_VAE_LAYOUT_DIFFUSERS, ""};
    MLB_TRY(detect_layout(st, &nm));
    mlb_vae_config cfg;
    MLB_TRY(config_from_shapes(st, &nm, &cfg));
    vae_cfg_file f;
    memset(&f, 0, sizeof f);
    f.attn = -1;
    char beside[MLB_SD_PATH_CAP];
    const char* cfg_name = NULL;
    if (!config_path && nm.layout == MLB_VAE_LAYOUT_DIFFUSERS && !nm.prefix[0]) {
        mlb_sd_config_beside(path, beside, sizeof beside);
        if (beside[0]) config_path = beside;
    }
    if (config_path) {
        MLB_TRY(parse_config_json(config_path, &f));
        cfg_name = config_path;
    } else {
        MLB_TRY(parse_ldm_config(st, &f));
        cfg_name = path;
    }
    MLB_TRY(apply_config(&f, cfg_name, &cfg, path));
    if (opt && opt->norm_groups > 0) cfg.norm_groups = opt->norm_groups;
    mlb_status s = mlb_vae_config_check(&cfg);
    if (s) return mlb_fail_context(s, "%s", path);
    mlb_vae* v = NULL;
    MLB_TRY(mlb_vae_create(NULL, &cfg, &v));
    vae_tdesc* all = NULL;
    size_t n = 0;
    s = all_tensors(v, &all, &n);
    for (size_t i = 0; i < n && !s; i++) s = load_one(st, &nm, &all[i]);
    free(all);
    if (s) { mlb_vae_free(v); return s; }
    char levels[96] = "";
    for (int l = 0; l < cfg.n_levels; l++)
        snprintf(levels + strlen(levels), sizeof levels - strlen(levels), "%s%d", l ? ", " : "", cfg.block_out[l]);
    char full[256];
    const mlb_st_tensor* w0 = find_pf(st, nm.prefix, "encoder.conv_in.weight", full, sizeof full);
    snprintf(v->source, sizeof v->source,
             "%s (%s%s%s): channels (%s), %d layers per block, latent %d, %d groups, scaling %g, mid attention %s, "
             "%s weights, config from %s", path, nm.layout == MLB_VAE_LAYOUT_LDM ? "ldm names" : "diffusers names",
             nm.prefix[0] ? ", prefix " : "", nm.prefix, levels, cfg.layers_per_block, cfg.latent_channels,
             cfg.norm_groups, cfg.scaling_factor, cfg.mid_attention ? "yes" : "no",
             w0 ? mlb_dtype_name(w0->dtype) : "?", f.from[0] ? (config_path ? config_path : f.from) : "the shapes");
    *out = v;
    return MLB_OK;
}


mlb_status mlb_vae_load(const char* path, const mlb_vae_options* opt, mlb_vae** out) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "VAE: NULL output");
    *out = NULL;
    mlb_sd_component c;
    MLB_TRY(mlb_sd_component_open("VAE", path, "vae", "diffusion_pytorch_model", opt ? opt->config_path : NULL, &c));
    mlb_status s = mlb_vae_from_st(c.st, c.config, opt, out);
    mlb_st_close(c.st);
    return s;
}

// ---- saving, the double copy, random weights --------------------------------------------------------
mlb_status mlb_vae_save(const mlb_vae* v, const char* path, mlb_vae_layout layout, const char* prefix,
                        const char* config_json_path) {
    if (!v || !path) return mlb_fail(MLB_ERR_ARG, "VAE save: NULL argument");
    if (layout != MLB_VAE_LAYOUT_DIFFUSERS && layout != MLB_VAE_LAYOUT_LDM)
        return mlb_fail(MLB_ERR_ARG, "VAE save: unknown layout %d", (int)layout);
    if (!prefix) prefix = "";
    vae_tdesc* all = NULL;
    size_t n = 0;
    MLB_TRY(all_tensors(v, &all, &n));
    mlb_vae_tensor* pub = calloc(n, sizeof *pub);
    mlb_st_entry* ent = calloc(n, sizeof *ent);
    char (*names)[256] = calloc(n, sizeof *names);
    mlb_status s = MLB_OK;
    if (!pub || !ent || !names) s = mlb_fail(MLB_ERR_NOMEM, "VAE save: out of memory");
    for (size_t i = 0; i < n && !s; i++) {
        to_public(&all[i], layout, &pub[i]);
        snprintf(names[i], sizeof names[i], "%s%s", prefix, pub[i].name);
        ent[i] = (mlb_st_entry){names[i], MLB_DT_F32, pub[i].ndim, pub[i].shape, pub[i].data};
    }
    if (!s) s = mlb_st_write(path, ent, n, NULL, 0);
    if (!s && config_json_path) {
        const mlb_vae_config* c = &v->cfg;
        char json[2048], list[256] = "", down[512] = "", up[512] = "";
        for (int l = 0; l < c->n_levels; l++) {
            snprintf(list + strlen(list), sizeof list - strlen(list), "%s%d", l ? ", " : "", c->block_out[l]);
            snprintf(down + strlen(down), sizeof down - strlen(down), "%s\"DownEncoderBlock2D\"", l ? ", " : "");
            snprintf(up + strlen(up), sizeof up - strlen(up), "%s\"UpDecoderBlock2D\"", l ? ", " : "");
        }
        int len = snprintf(json, sizeof json,
                           "{\n  \"_class_name\": \"AutoencoderKL\",\n  \"act_fn\": \"silu\",\n  \"block_out_channels\": [%s],\n"
                           "  \"down_block_types\": [%s],\n  \"in_channels\": %d,\n  \"latent_channels\": %d,\n"
                           "  \"layers_per_block\": %d,\n  \"mid_block_add_attention\": %s,\n  \"norm_num_groups\": %d,\n"
                           "  \"out_channels\": %d,\n  \"scaling_factor\": %.9g,\n  \"up_block_types\": [%s]\n}\n",
                           list, down, c->in_channels, c->latent_channels, c->layers_per_block,
                           c->mid_attention ? "true" : "false", c->norm_groups, c->out_channels, c->scaling_factor, up);
        s = mlb_write_file_atomic(config_json_path, json, (size_t)len);
    }
    free(all); free(pub); free(ent); free(names);
    return s;
}

mlb_status mlb_vae_to_f64(const mlb_vae* v, mlb_vae_f64** out) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "VAE: NULL output");
    *out = NULL;
    if (!v) return mlb_fail(MLB_ERR_ARG, "VAE: NULL model");
    MLB_TRY(mlb_vae_create_f64(NULL, &v->cfg, out));
    for (size_t i = 0; i < v->n_params; i++) (*out)->params[i] = (double)v->params[i];   // the same layout
    memcpy((*out)->source, v->source, sizeof v->source);
    return MLB_OK;
}

void mlb_vae_init_random(mlb_vae* v, uint64_t seed, float gain) {
    if (!v) return;
    vae_tdesc* all = NULL;
    size_t n = 0;
    if (all_tensors(v, &all, &n)) { mlb_clear_error(); return; }
    for (size_t i = 0; i < n; i++) {
        const vae_tdesc* t = &all[i];
        float mean = 0, std = 0.05f;
        if (t->kind == VT_CONV || t->kind == VT_LIN) std = gain / sqrtf((float)(t->n / (size_t)t->shape[0]));
        if (t->kind == VT_NORM_W) mean = 1;
        mlb_rng_fill_normal(t->dst, t->n, seed, 1000 + i, 0, mean, std);
    }
    free(all);
}
