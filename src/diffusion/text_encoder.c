// The Stable Diffusion text encoders (text_encoder.h, docs/text_encoder.md): loading the three
// layouts (single file with HF CLIP or OpenCLIP names, diffusers CLIPTextModel) and the forward.
#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include "matlaber/backend.h"
#include "matlaber/fileio.h"
#include "matlaber/sd_files.h"
#include "matlaber/text_encoder.h"
#include "matlaber/tokenizer.h"

#define TE_CONFIG_MAX (1 << 20)   // bytes of config.json / ldm_config accepted

// ---- small helpers ------------------------------------------------------------------------------

static void fmt_shape(char* buf, size_t cap, const mlb_st_tensor* t) {
    size_t n = (size_t)snprintf(buf, cap, "[");
    for (int i = 0; i < t->ndim && n < cap; i++)
        n += (size_t)snprintf(buf + n, cap - n, "%s%lld", i ? ", " : "", (long long)t->shape[i]);
    if (n < cap) snprintf(buf + n, cap - n, "]");
}

mlb_text_encoder_options mlb_text_encoder_default_options(void) {
    mlb_text_encoder_options o = {MLB_TEXT_AUTO, 0, -1, NULL};
    return o;
}

const char* mlb_text_variant_name(mlb_text_variant v) {
    switch (v) {
    case MLB_TEXT_AUTO: return "auto";
    case MLB_TEXT_SD1: return "sd1";
    case MLB_TEXT_SD2: return "sd2";
    }
    return "?";
}

mlb_status mlb_text_variant_parse(const char* name, mlb_text_variant* out) {
    if (!name || !out) return mlb_fail(MLB_ERR_ARG, "text encoder variant: NULL argument");
    if (!strcmp(name, "auto")) *out = MLB_TEXT_AUTO;
    else if (!strcmp(name, "sd1")) *out = MLB_TEXT_SD1;
    else if (!strcmp(name, "sd2")) *out = MLB_TEXT_SD2;
    else return mlb_fail(MLB_ERR_ARG, "text encoder variant '%s' is not one of auto, sd1, sd2", name);
    return MLB_OK;
}

int mlb_text_encoder_pad_id(const mlb_text_encoder* te) {
    return te && te->variant == MLB_TEXT_SD2 ? MLB_CLIP_PAD_SD2 : MLB_CLIP_PAD_SD1;
}

// ---- configuration: config.json (diffusers) and the ldm_config metadata (single files) ----------
typedef struct {
    int heads, layers, hidden, inter, n_ctx, vocab;   // 0 = absent
    double eps;                                       // 0 = absent
    char act[32];                                     // "" = absent
    char layer[32];                                   // ldm_config "layer": "last" / "penultimate"
} te_config;

static int is_count(const cJSON* v) {   // a whole number in [1, 2^30] (checked before any cast)
    return cJSON_IsNumber(v) && v->valuedouble >= 1 && v->valuedouble <= (double)(1 << 30) &&
           v->valuedouble == floor(v->valuedouble);
}

static int json_int(const cJSON* o, const char* key, int* out) {
    const cJSON* v = cJSON_GetObjectItemCaseSensitive(o, key);
    if (!v) return 0;
    if (!is_count(v)) return -1;
    *out = (int)v->valuedouble;
    return 1;
}

// Reads the CLIPTextConfig fields that matter; a field of the wrong type is an error naming it.
static mlb_status parse_config_json(const char* path, te_config* cfg) {
    cJSON* root;
    MLB_TRY(mlb_json_read_file(path, TE_CONFIG_MAX, &root));
    mlb_status s = MLB_OK;
    if (!cJSON_IsObject(root)) { s = mlb_fail(MLB_ERR_FORMAT, "%s: expected a JSON object", path); goto done; }
    const cJSON* mt = cJSON_GetObjectItemCaseSensitive(root, "model_type");
    if (cJSON_IsString(mt) && strcmp(mt->valuestring, "clip_text_model") != 0) {
        s = mlb_fail(MLB_ERR_FORMAT, "%s: model_type '%s' is not a CLIP text model (clip_text_model)", path,
                     mt->valuestring);
        goto done;
    }
    static const char* keys[] = {"num_attention_heads", "num_hidden_layers", "hidden_size", "intermediate_size",
                                 "max_position_embeddings", "vocab_size"};
    int* dst[] = {&cfg->heads, &cfg->layers, &cfg->hidden, &cfg->inter, &cfg->n_ctx, &cfg->vocab};
    for (int i = 0; i < 6; i++)
        if (json_int(root, keys[i], dst[i]) < 0) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: '%s' is not a positive integer", path, keys[i]);
            goto done;
        }
    const cJSON* eps = cJSON_GetObjectItemCaseSensitive(root, "layer_norm_eps");
    if (eps) {
        if (!cJSON_IsNumber(eps) || !(eps->valuedouble > 0 && eps->valuedouble < 1)) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: 'layer_norm_eps' is not a number in (0, 1)", path);
            goto done;
        }
        cfg->eps = eps->valuedouble;
    }
    const cJSON* act = cJSON_GetObjectItemCaseSensitive(root, "hidden_act");
    if (act) {
        if (!cJSON_IsString(act) || strlen(act->valuestring) >= sizeof cfg->act) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: 'hidden_act' is not a short string", path);
            goto done;
        }
        strcpy(cfg->act, act->valuestring);
    }
done:
    cJSON_Delete(root);
    return s;
}

// The ldm_config metadata of single files (the inference yaml as JSON): heads and the output layer
// of cond_stage_config. Absent or unparsable metadata leaves cfg untouched (published checkpoints
// carry none); a present but malformed heads entry is an error.
static mlb_status parse_ldm_config(const mlb_safetensors* st, te_config* cfg) {
    cJSON* root = mlb_sd_ldm_config(st, NULL);
    if (!root) return MLB_OK;
    mlb_status s = MLB_OK;
    const cJSON* cond = mlb_json_find(root, "cond_stage_config");
    if (cond) {
        const cJSON* h = mlb_json_find(cond, "num_attention_heads");
        if (!h) h = mlb_json_find(cond, "heads");
        if (h) {
            if (!is_count(h))
                s = mlb_fail(MLB_ERR_FORMAT, "%s: ldm_config metadata: '%s' of cond_stage_config is not a positive "
                             "integer", mlb_st_path(st), h->string);
            else cfg->heads = (int)h->valuedouble;
        }
        const cJSON* l = mlb_json_find(cond, "layer");
        if (!s && cJSON_IsString(l) && strlen(l->valuestring) < sizeof cfg->layer) strcpy(cfg->layer, l->valuestring);
    }
    cJSON_Delete(root);
    return s;
}

// ---- layouts ------------------------------------------------------------------------------------
typedef struct {
    mlb_text_layout layout;
    const char* prefix;
} te_names;

static mlb_status detect_layout(const mlb_safetensors* st, te_names* nm) {
    static const char* openclip[] = {"cond_stage_model.model.", ""};
    static const char* hf[] = {"cond_stage_model.transformer.text_model.", "cond_stage_model.transformer.",
                               "text_model.", ""};
    char name[256];
    for (int i = 0; i < 2; i++) {
        snprintf(name, sizeof name, "%stoken_embedding.weight", openclip[i]);
        if (mlb_st_find(st, name)) { nm->layout = MLB_TEXT_LAYOUT_OPENCLIP; nm->prefix = openclip[i]; return MLB_OK; }
    }
    for (int i = 0; i < 4; i++) {
        snprintf(name, sizeof name, "%sembeddings.token_embedding.weight", hf[i]);
        if (mlb_st_find(st, name)) {
            nm->layout = !strncmp(hf[i], "cond_stage_model.", 17) ? MLB_TEXT_LAYOUT_LDM_CLIP : MLB_TEXT_LAYOUT_DIFFUSERS;
            nm->prefix = hf[i];
            return MLB_OK;
        }
    }
    return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no text encoder found: expected the tensors "
                    "cond_stage_model.transformer.text_model.* (SD 1.x single file), cond_stage_model.model.* "
                    "(SD 2.x single file) or text_model.* (diffusers text_encoder)", mlb_st_path(st));
}

// Tensor names of layer `l` (-1: the model-level tensors) in the detected layout.
enum { N_TOK, N_POS, N_LNF_W, N_LNF_B };   // l = -1
enum { N_LN1_W, N_LN1_B, N_Q_W, N_Q_B, N_K_W, N_K_B, N_V_W, N_V_B, N_QKV_W, N_QKV_B, N_OUT_W, N_OUT_B,
       N_LN2_W, N_LN2_B, N_FC1_W, N_FC1_B, N_FC2_W, N_FC2_B };

static void tensor_name(char* buf, size_t cap, const te_names* nm, int which, int l) {
    static const char* hf_model[] = {"embeddings.token_embedding.weight", "embeddings.position_embedding.weight",
                                     "final_layer_norm.weight", "final_layer_norm.bias"};
    static const char* oc_model[] = {"token_embedding.weight", "positional_embedding", "ln_final.weight",
                                     "ln_final.bias"};
    static const char* hf_layer[] = {"layer_norm1.weight", "layer_norm1.bias", "self_attn.q_proj.weight",
        "self_attn.q_proj.bias", "self_attn.k_proj.weight", "self_attn.k_proj.bias", "self_attn.v_proj.weight",
        "self_attn.v_proj.bias", NULL, NULL, "self_attn.out_proj.weight", "self_attn.out_proj.bias",
        "layer_norm2.weight", "layer_norm2.bias", "mlp.fc1.weight", "mlp.fc1.bias", "mlp.fc2.weight", "mlp.fc2.bias"};
    static const char* oc_layer[] = {"ln_1.weight", "ln_1.bias", NULL, NULL, NULL, NULL, NULL, NULL,
        "attn.in_proj_weight", "attn.in_proj_bias", "attn.out_proj.weight", "attn.out_proj.bias", "ln_2.weight",
        "ln_2.bias", "mlp.c_fc.weight", "mlp.c_fc.bias", "mlp.c_proj.weight", "mlp.c_proj.bias"};
    int oc = nm->layout == MLB_TEXT_LAYOUT_OPENCLIP;
    if (l < 0) {
        snprintf(buf, cap, "%s%s", nm->prefix, (oc ? oc_model : hf_model)[which & 3]);
    } else {
        const char* leaf = (oc ? oc_layer : hf_layer)[which];
        snprintf(buf, cap, "%s%s%d.%s", nm->prefix, oc ? "transformer.resblocks." : "encoder.layers.", l,
                 leaf ? leaf : "?");
    }
}

// Checks the shape (an error naming the tensor and the file) and converts to float32.
static mlb_status load_tensor(const mlb_safetensors* st, const te_names* nm, int which, int l, float* dst,
                              int64_t d0, int64_t d1) {
    char name[256];
    tensor_name(name, sizeof name, nm, which, l);
    int64_t shape[2] = {d0, d1};
    MLB_TRY(mlb_st_expect(st, name, d1 > 0 ? 2 : 1, shape));
    return mlb_st_read_f32(st, name, dst, (size_t)d0 * (size_t)(d1 > 0 ? d1 : 1));
}

// A 2-D tensor's shape, for the sizes the weights decide (vocabulary, width, context, MLP width).
static mlb_status shape2(const mlb_safetensors* st, const te_names* nm, int which, int l, const char* what,
                         int64_t* d0, int64_t* d1) {
    char name[256], sh[128];
    tensor_name(name, sizeof name, nm, which, l);
    const mlb_st_tensor* t = mlb_st_find(st, name);
    if (!t) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no tensor named '%s'", mlb_st_path(st), name);
    if (t->ndim != 2 || t->shape[0] < 1 || t->shape[1] < 1 || t->shape[0] > INT32_MAX / 4 || t->shape[1] > 65536) {
        fmt_shape(sh, sizeof sh, t);
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' has shape %s, expected %s", mlb_st_path(st), name, sh, what);
    }
    *d0 = t->shape[0];
    *d1 = t->shape[1];
    return MLB_OK;
}

static int count_layers(const mlb_safetensors* st, const te_names* nm) {
    char name[256];
    int n = 0;
    for (;; n++) {
        tensor_name(name, sizeof name, nm, N_LN1_W, n);
        if (!mlb_st_find(st, name)) return n;
    }
}

// ---- loading --------------------------------------------------------------------------------------
static mlb_status check_config_size(const char* cfg_path, const char* key, int cfg_value, int weights_value,
                                    const char* st_path) {
    if (cfg_value && cfg_value != weights_value)
        return mlb_fail(MLB_ERR_FORMAT, "%s: %s is %d but the weights in %s have %d", cfg_path, key, cfg_value,
                        st_path, weights_value);
    return MLB_OK;
}

static void carve(float** p, float** dst, size_t n) { *dst = *p; *p += n; }

// The tensors' pointers into te->params (on whichever device it is), in the order the loader fills
// them: te->layers [n_layers] allocated, sizes set.
static void carve_weights(mlb_text_encoder* te) {
    int64_t W = te->width, M = te->mlp, V = te->vocab, NC = te->n_ctx, L = te->n_layers;
    float* p = te->params;
    carve(&p, &te->token_embedding, (size_t)(V * W));
    carve(&p, &te->position_embedding, (size_t)(NC * W));
    carve(&p, &te->ln_final_w, (size_t)W);
    carve(&p, &te->ln_final_b, (size_t)W);
    for (int l = 0; l < L; l++) {
        mlb_text_layer* y = &te->layers[l];
        carve(&p, &y->ln1_w, (size_t)W);
        carve(&p, &y->ln1_b, (size_t)W);
        carve(&p, &y->qkv_w, (size_t)(3 * W * W));
        carve(&p, &y->qkv_b, (size_t)(3 * W));
        carve(&p, &y->out_w, (size_t)(W * W));
        carve(&p, &y->out_b, (size_t)W);
        carve(&p, &y->ln2_w, (size_t)W);
        carve(&p, &y->ln2_b, (size_t)W);
        carve(&p, &y->fc1_w, (size_t)(M * W));
        carve(&p, &y->fc1_b, (size_t)M);
        carve(&p, &y->fc2_w, (size_t)(W * M));
        carve(&p, &y->fc2_b, (size_t)W);
        y->q_w = y->qkv_w; y->k_w = y->qkv_w + W * W; y->v_w = y->qkv_w + 2 * W * W;
        y->q_b = y->qkv_b; y->k_b = y->qkv_b + W;     y->v_b = y->qkv_b + 2 * W;
    }
}

static mlb_status load_weights(mlb_text_encoder* te, const mlb_safetensors* st, const te_names* nm) {
    int64_t W = te->width, M = te->mlp, V = te->vocab, NC = te->n_ctx, L = te->n_layers;
    size_t per_layer = (size_t)(4 * W + 3 * W * W + 3 * W + W * W + W + M * W + M + W * M + W);
    te->n_params = (size_t)(V * W + NC * W + 2 * W) + (size_t)L * per_layer;
    te->params = malloc(te->n_params * sizeof(float));
    te->layers = calloc((size_t)(L > 0 ? L : 1), sizeof(mlb_text_layer));
    if (!te->params || !te->layers)
        return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for the text encoder's %zu parameters (%.1f MB as float32)",
                        mlb_st_path(st), te->n_params, te->n_params * 4.0 / 1e6);
    carve_weights(te);
    MLB_TRY(load_tensor(st, nm, N_TOK, -1, te->token_embedding, V, W));
    MLB_TRY(load_tensor(st, nm, N_POS, -1, te->position_embedding, NC, W));
    for (int l = 0; l < L; l++) {
        mlb_text_layer* y = &te->layers[l];
        MLB_TRY(load_tensor(st, nm, N_LN1_W, l, y->ln1_w, W, 0));
        MLB_TRY(load_tensor(st, nm, N_LN1_B, l, y->ln1_b, W, 0));
        if (nm->layout == MLB_TEXT_LAYOUT_OPENCLIP) {   // in_proj = concat(q, k, v) along the rows
            MLB_TRY(load_tensor(st, nm, N_QKV_W, l, y->qkv_w, 3 * W, W));
            MLB_TRY(load_tensor(st, nm, N_QKV_B, l, y->qkv_b, 3 * W, 0));
        } else {
            MLB_TRY(load_tensor(st, nm, N_Q_W, l, y->q_w, W, W));
            MLB_TRY(load_tensor(st, nm, N_Q_B, l, y->q_b, W, 0));
            MLB_TRY(load_tensor(st, nm, N_K_W, l, y->k_w, W, W));
            MLB_TRY(load_tensor(st, nm, N_K_B, l, y->k_b, W, 0));
            MLB_TRY(load_tensor(st, nm, N_V_W, l, y->v_w, W, W));
            MLB_TRY(load_tensor(st, nm, N_V_B, l, y->v_b, W, 0));
        }
        MLB_TRY(load_tensor(st, nm, N_OUT_W, l, y->out_w, W, W));
        MLB_TRY(load_tensor(st, nm, N_OUT_B, l, y->out_b, W, 0));
        MLB_TRY(load_tensor(st, nm, N_LN2_W, l, y->ln2_w, W, 0));
        MLB_TRY(load_tensor(st, nm, N_LN2_B, l, y->ln2_b, W, 0));
        MLB_TRY(load_tensor(st, nm, N_FC1_W, l, y->fc1_w, M, W));
        MLB_TRY(load_tensor(st, nm, N_FC1_B, l, y->fc1_b, M, 0));
        MLB_TRY(load_tensor(st, nm, N_FC2_W, l, y->fc2_w, W, M));
        MLB_TRY(load_tensor(st, nm, N_FC2_B, l, y->fc2_b, W, 0));
    }
    MLB_TRY(load_tensor(st, nm, N_LNF_W, -1, te->ln_final_w, W, 0));
    MLB_TRY(load_tensor(st, nm, N_LNF_B, -1, te->ln_final_b, W, 0));
    return MLB_OK;
}

// Everything but the weights: layout, sizes, variant, heads, output layer.
static mlb_status configure(mlb_text_encoder* te, const mlb_safetensors* st, const char* cfg_path,
                            const mlb_text_encoder_options* opt, te_names* nm) {
    const char* path = mlb_st_path(st);
    MLB_TRY(detect_layout(st, nm));
    te->layout = nm->layout;
    int64_t V, W, NC, W2, M, W3;
    MLB_TRY(shape2(st, nm, N_TOK, -1, "[vocabulary, width]", &V, &W));
    MLB_TRY(shape2(st, nm, N_POS, -1, "[context, width]", &NC, &W2));
    if (W2 != W) {
        char name[256];
        tensor_name(name, sizeof name, nm, N_POS, -1);
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' has shape [%lld, %lld], expected [%lld, %lld] (the width of "
                        "the token embedding)", path, name, (long long)NC, (long long)W2, (long long)NC, (long long)W);
    }
    int stored = count_layers(st, nm);
    if (stored == 0) {
        char name[256];
        tensor_name(name, sizeof name, nm, N_LN1_W, 0);
        return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no tensor named '%s' (the text encoder has no layers)", path, name);
    }
    MLB_TRY(shape2(st, nm, N_FC1_W, 0, "[mlp width, width]", &M, &W3));
    te->vocab = (int)V; te->width = (int)W; te->n_ctx = (int)NC; te->mlp = (int)M;
    te->ln_eps = 1e-5f;

    // Config: config.json for the diffusers layout, the ldm_config metadata for single files.
    te_config cfg;
    memset(&cfg, 0, sizeof cfg);
    char beside[MLB_SD_PATH_CAP];
    if (!cfg_path && nm->layout == MLB_TEXT_LAYOUT_DIFFUSERS) {
        mlb_sd_config_beside(path, beside, sizeof beside);
        if (beside[0]) cfg_path = beside;
    }
    if (cfg_path) {
        MLB_TRY(parse_config_json(cfg_path, &cfg));
        MLB_TRY(check_config_size(cfg_path, "hidden_size", cfg.hidden, te->width, path));
        MLB_TRY(check_config_size(cfg_path, "intermediate_size", cfg.inter, te->mlp, path));
        MLB_TRY(check_config_size(cfg_path, "vocab_size", cfg.vocab, te->vocab, path));
        MLB_TRY(check_config_size(cfg_path, "max_position_embeddings", cfg.n_ctx, te->n_ctx, path));
        if (cfg.layers > stored)
            return mlb_fail(MLB_ERR_FORMAT, "%s: num_hidden_layers is %d but %s holds %d layers", cfg_path, cfg.layers,
                            path, stored);
        if (cfg.layers) stored = cfg.layers;   // transformers ignores layers past num_hidden_layers
        if (cfg.eps > 0) te->ln_eps = (float)cfg.eps;
    } else if (nm->layout != MLB_TEXT_LAYOUT_DIFFUSERS) {
        MLB_TRY(parse_ldm_config(st, &cfg));
    }
    te->n_layers_stored = stored;

    // Variant: OpenCLIP names => SD2, HF names in a single file => SD1, diffusers => hidden_act.
    mlb_text_variant var = opt->variant;
    if (var == MLB_TEXT_AUTO) {
        if (nm->layout == MLB_TEXT_LAYOUT_OPENCLIP) var = MLB_TEXT_SD2;
        else if (nm->layout == MLB_TEXT_LAYOUT_LDM_CLIP || !cfg.act[0] || !strcmp(cfg.act, "quick_gelu")) var = MLB_TEXT_SD1;
        else if (!strcmp(cfg.act, "gelu")) var = MLB_TEXT_SD2;
        else return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: hidden_act '%s' is neither quick_gelu (SD 1.x) nor gelu "
                             "(SD 2.x)", cfg_path, cfg.act);
    } else if (var != MLB_TEXT_SD1 && var != MLB_TEXT_SD2) {
        return mlb_fail(MLB_ERR_ARG, "text encoder: unknown variant %d", (int)var);
    }
    te->variant = var;
    te->act = var == MLB_TEXT_SD2 ? MLB_ACT_GELU : MLB_ACT_QUICK_GELU;

    // Heads: option, config.json, ldm_config, else the real models' head width of 64.
    if (opt->n_heads > 0) { te->n_heads = opt->n_heads; strcpy(te->heads_from, "option"); }
    else if (cfg.heads) { te->n_heads = cfg.heads; strcpy(te->heads_from, cfg_path ? "config.json" : "ldm_config"); }
    else if (te->width % 64 == 0) { te->n_heads = te->width / 64; strcpy(te->heads_from, "width/64"); }
    else return mlb_fail(MLB_ERR_FORMAT, "%s: cannot tell the number of attention heads of the %d-wide text encoder: "
                         "no config.json or ldm_config metadata says it and the width is not a multiple of 64; pass "
                         "it explicitly", path, te->width);
    if (te->n_heads < 1 || te->width % te->n_heads != 0)
        return mlb_fail(MLB_ERR_FORMAT, "%s: width %d is not a multiple of the %d attention heads (%s)", path,
                        te->width, te->n_heads, te->heads_from);

    // Output layer: option, ldm_config "layer", else the variant's rule. Published diffusers SD 2.x
    // text encoders store 23 of ViT-H's 24 layers (already cut at the penultimate one).
    int skip;
    if (opt->skip_last >= 0) skip = opt->skip_last;
    else if (cfg.layer[0] && !strcmp(cfg.layer, "last")) skip = 0;
    else if (cfg.layer[0] && !strcmp(cfg.layer, "penultimate")) skip = 1;
    else if (cfg.layer[0])
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: ldm_config asks for the text encoder's layer '%s'; only 'last' "
                        "and 'penultimate' are supported", path, cfg.layer);
    else if (var == MLB_TEXT_SD1) skip = 0;
    else skip = (nm->layout == MLB_TEXT_LAYOUT_DIFFUSERS && te->width == 1024 && stored == 23) ? 0 : 1;
    if (skip >= stored)
        return mlb_fail(MLB_ERR_ARG, "%s: skipping the last %d layer(s) leaves none of the %d", path, skip, stored);
    te->skip_last = skip;
    te->n_layers = stored - skip;
    return MLB_OK;
}

mlb_status mlb_text_encoder_from_st(const mlb_safetensors* st, const char* config_path,
                                    const mlb_text_encoder_options* opt, mlb_text_encoder** out) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "text encoder: NULL output");
    *out = NULL;
    if (!st) return mlb_fail(MLB_ERR_ARG, "text encoder: NULL safetensors handle");
    mlb_text_encoder_options o = opt ? *opt : mlb_text_encoder_default_options();
    if (!config_path) config_path = o.config_path;
    struct stat sb;
    if (config_path && stat(config_path, &sb) != 0)
        return mlb_fail(errno == ENOENT ? MLB_ERR_NOT_FOUND : MLB_ERR_IO, "text encoder config %s: %s", config_path,
                        strerror(errno));
    if (config_path && !S_ISREG(sb.st_mode))
        return mlb_fail(MLB_ERR_ARG, "text encoder config %s: not a file", config_path);
    mlb_text_encoder* te = calloc(1, sizeof *te);
    if (!te) return mlb_fail(MLB_ERR_NOMEM, "text encoder: out of memory");
    te_names nm;
    mlb_status s = configure(te, st, config_path, &o, &nm);
    if (!s) s = load_weights(te, st, &nm);
    if (s) { mlb_text_encoder_free(te); return s; }
    static const char* layout_names[] = {"?", "single file, CLIP names", "single file, OpenCLIP names",
                                         "diffusers CLIPTextModel"};
    snprintf(te->source, sizeof te->source,
             "%s (%s): %s, width %d, %d of %d layers, %d heads (%s), MLP %d, %s, vocabulary %d, context %d",
             mlb_st_path(st), layout_names[te->layout], mlb_text_variant_name(te->variant), te->width, te->n_layers,
             te->n_layers_stored, te->n_heads, te->heads_from, te->mlp, mlb_activation_name(te->act), te->vocab,
             te->n_ctx);
    *out = te;
    return MLB_OK;
}


mlb_status mlb_text_encoder_load(const char* path, const mlb_text_encoder_options* opt, mlb_text_encoder** out) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "text encoder: NULL output");
    *out = NULL;
    mlb_sd_component c;
    MLB_TRY(mlb_sd_component_open("text encoder", path, "text_encoder", "model", opt ? opt->config_path : NULL, &c));
    mlb_status s = mlb_text_encoder_from_st(c.st, c.config, opt, out);
    mlb_st_close(c.st);
    return s;
}

void mlb_text_encoder_free(mlb_text_encoder* te) {
    if (!te) return;
    if (te->device == MLB_DEVICE_CPU) free(te->params);
    else mlb_backend_for(te->device, MLB_GEMM_FP32)->release(te->params);
    free(te->layers);
    free(te);
}

mlb_status mlb_text_encoder_to_device(const mlb_text_encoder* src, mlb_device d, mlb_text_encoder** out) {
    if (!src || !out) return mlb_fail(MLB_ERR_ARG, "mlb_text_encoder_to_device: NULL argument");
    *out = NULL;
    if (src->device != MLB_DEVICE_CPU)
        return mlb_fail(MLB_ERR_ARG, "mlb_text_encoder_to_device: the source must be on the CPU");
    const mlb_backend* be = mlb_backend_for(d, MLB_GEMM_FP32);
    mlb_text_encoder* te = malloc(sizeof *te);
    if (!te) return mlb_fail(MLB_ERR_NOMEM, "text encoder: out of memory");
    *te = *src;
    te->device = MLB_DEVICE_CPU;   // until params holds the device's buffer (free frees by it)
    te->params = NULL;
    te->layers = calloc((size_t)(te->n_layers > 0 ? te->n_layers : 1), sizeof(mlb_text_layer));
    mlb_status s = te->layers ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "text encoder: out of memory");
    float* p = NULL;
    if (!s) s = be->alloc(&p, te->n_params);
    if (!s) {
        te->params = p, te->device = d;
        carve_weights(te);
        s = be->upload(te->params, src->params, te->n_params);
    }
    if (s) {
        mlb_text_encoder_free(te);
        return mlb_fail_context(s, "moving the text encoder to the %s", mlb_device_name(d));
    }
    *out = te;
    return MLB_OK;
}

// ---- forward --------------------------------------------------------------------------------------
mlb_status mlb_text_encoder_forward(const mlb_backend* be, const mlb_text_encoder* te, const int* tokens, int B, int T,
                                    float* out, float* states, int n_states) {
    if (!be) be = mlb_backend_cpu();
    if (!te) return mlb_fail(MLB_ERR_ARG, "text encoder: NULL model");
    if (te->device != be->device)
        return mlb_fail(MLB_ERR_ARG, "text encoder: the weights are on the %s, the ops on the %s "
                        "(mlb_text_encoder_to_device)", mlb_device_name(te->device), mlb_device_name(be->device));
    if (be == mlb_backend_cpu_bf16_stored())
        return mlb_fail(MLB_ERR_ARG, "text encoder: its weights are fp32, not packed bf16 (use the CPU's bf16 table)");
    if (B < 0 || T < 0) return mlb_fail(MLB_ERR_ARG, "text encoder: bad shape [%d, %d]", B, T);
    if (T > te->n_ctx)
        return mlb_fail(MLB_ERR_ARG, "text encoder: %d tokens per sequence, more than the %d positions", T, te->n_ctx);
    if (states && (n_states < 0 || n_states > te->n_layers + 1))
        return mlb_fail(MLB_ERR_ARG, "text encoder: %d hidden states asked for; the model has %d (embeddings + %d "
                        "layers)", n_states, te->n_layers + 1, te->n_layers);
    if (B == 0 || T == 0) return MLB_OK;
    if ((int64_t)B * T * (6 * (int64_t)te->width + te->mlp) > INT32_MAX)
        return mlb_fail(MLB_ERR_ARG, "text encoder: batch of %d sequences is too large", B);
    if (!tokens || !out) return mlb_fail(MLB_ERR_ARG, "text encoder: NULL tokens or output");
    const int W = te->width, M = te->mlp, NH = te->n_heads;
    const int BT = B * T;
    const size_t n = (size_t)BT * W;
    // the tokens are checked here, on the host: the device's embedding cannot report one
    for (int i = 0; i < BT; i++)
        if (tokens[i] < 0 || tokens[i] >= te->vocab)
            return mlb_fail(MLB_ERR_ARG, "text encoder: token %d at [%d, %d] is outside the vocabulary [0, %d)",
                            tokens[i], i / T, i % T, te->vocab);
    _Static_assert(sizeof(int) == sizeof(int32_t) && sizeof(int32_t) == sizeof(float), "tokens travel as floats");
    float* ws = NULL;   // on be's device
    MLB_TRY(be->alloc(&ws, ((size_t)6 * W + M + 1) * (size_t)BT));
    float* x = ws;               // [BT, W] residual stream
    float* h = x + n;            // [BT, W] layer norm output / projection output
    float* a = h + n;            // [BT, W] attention output
    float* qkv = a + n;          // [BT, 3W]
    float* m = qkv + 3 * n;      // [BT, M]
    int32_t* tok = (int32_t*)(m + (size_t)BT * M);   // [BT]
    int l = -1;   // the layer running (-1: none), for the error's context
    mlb_status s;
#define CK(e) do { if ((s = (e)) != MLB_OK) goto done; } while (0)
    CK(be->upload((float*)tok, (const float*)tokens, (size_t)BT));
    CK(be->embedding(x, tok, te->token_embedding, te->position_embedding, B, T, W, te->vocab));
    if (states && n_states > 0) CK(be->download(states, x, n));
    for (l = 0; l < te->n_layers; l++) {
        const mlb_text_layer* y = &te->layers[l];
        CK(be->layernorm(h, x, y->ln1_w, y->ln1_b, BT, W, te->ln_eps));
        CK(be->linear(be, qkv, h, y->qkv_w, y->qkv_b, BT, W, 3 * W));
        CK(be->attention(a, qkv, qkv + W, qkv + 2 * W, 3 * W, B, T, W, NH, 1));
        CK(be->linear(be, h, a, y->out_w, y->out_b, BT, W, W));
        CK(be->add(x, h, n));
        CK(be->layernorm(h, x, y->ln2_w, y->ln2_b, BT, W, te->ln_eps));
        CK(be->linear(be, m, h, y->fc1_w, y->fc1_b, BT, W, M));
        CK(be->activation(m, m, (size_t)BT * M, te->act));
        CK(be->linear(be, h, m, y->fc2_w, y->fc2_b, BT, M, W));
        CK(be->add(x, h, n));
        if (states && l + 1 < n_states) CK(be->download(states + (size_t)(l + 1) * n, x, n));
    }
    l = -1;
    CK(be->layernorm(h, x, te->ln_final_w, te->ln_final_b, BT, W, te->ln_eps));
    CK(be->download(out, h, n));
#undef CK
done:
    be->release(ws);
    if (s && l >= 0) return mlb_fail_context(s, "text encoder layer %d", l);
    if (s) return mlb_fail_context(s, "text encoder");
    return MLB_OK;
}
