// UNet loading: layout detection, diffusers -> ldm name translation, configuration from config.json
// or the ldm_config metadata, and the parameters: float32, or the linear and conv weights in bf16
// (see unet.h, docs/unet.md).
#include "matlaber/unet.h"
#include "matlaber/backend.h"
#include "matlaber/unet_random.h"
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include "matlaber/fileio.h"
#include "matlaber/log.h"
#include "matlaber/sd_files.h"
#include "unet_schema.h"

#define UNET_CONFIG_MAX (1 << 20)
#define LDM_PREFIX "model.diffusion_model."


// ---- names ----------------------------------------------------------------------------------------
// The file's name for a diffusers-layout name: mlb_unet_ldm_name (unet_random.c) is the one mapping
// to the original layout, shared by the loader and the writer of random models.
static void tensor_name(char* out, size_t cap, const mlb_unet* u, const char* d) {
    if (u->cfg.layout != MLB_UNET_LAYOUT_LDM) { snprintf(out, cap, "%s", d); return; }
    mlb_unet_ldm_name(&u->cfg, d, out, cap);
}

static const mlb_st_tensor* find_d(const mlb_safetensors* st, const mlb_unet* u, const char* d) {
    char name[512];
    tensor_name(name, sizeof name, u, d);
    return mlb_st_find(st, name);
}

static mlb_status need(const mlb_safetensors* st, const mlb_unet* u, const char* d, const mlb_st_tensor** t) {
    *t = find_d(st, u, d);
    if (*t) return MLB_OK;
    char name[512];
    tensor_name(name, sizeof name, u, d);
    return mlb_fail(MLB_ERR_NOT_FOUND, "%s: UNet tensor '%s' is missing", mlb_st_path(st), name);
}

// ---- structure from the tensor shapes ----------------------------------------------------------------
static mlb_status infer_structure(const mlb_safetensors* st, mlb_unet* u) {
    mlb_unet_config* c = &u->cfg;
    const char* path = mlb_st_path(st);
    const mlb_st_tensor* t;
    if (c->layout == MLB_UNET_LAYOUT_LDM) {   // layers_per_block: the first input block with a downsampler
        int k = 1;
        char name[128];
        for (; k < 64; k++) {
            snprintf(name, sizeof name, LDM_PREFIX "input_blocks.%d.0.op.weight", k);
            if (mlb_st_find(st, name)) break;
        }
        if (k == 64 || k < 2)
            return mlb_fail(MLB_ERR_FORMAT, "%s: no UNet downsampler (" LDM_PREFIX "input_blocks.N.0.op) found", path);
        c->layers_per_block = k - 1;
    }
    MLB_TRY(need(st, u, "conv_in.weight", &t));
    if (t->ndim != 4) return mlb_fail(MLB_ERR_FORMAT, "%s: UNet conv_in weight is not 4-D", path);
    c->in_channels = (int)t->shape[1];
    MLB_TRY(need(st, u, "conv_out.weight", &t));
    c->out_channels = (int)t->shape[0];
    MLB_TRY(need(st, u, "time_embedding.linear_1.weight", &t));
    c->time_embed_dim = (int)t->shape[0];
    char d[256];
    if (c->layout != MLB_UNET_LAYOUT_LDM) {
        int L = 0;
        for (; L <= MLB_UNET_MAX_LAYERS; L++) {
            snprintf(d, sizeof d, "down_blocks.0.resnets.%d.conv1.weight", L);
            if (!find_d(st, u, d)) break;
        }
        if (L < 1 || L > MLB_UNET_MAX_LAYERS)
            return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: %d ResNets in down_blocks.0 (1..%d supported)", path, L,
                            MLB_UNET_MAX_LAYERS);
        c->layers_per_block = L;
    }
    if (c->layers_per_block > MLB_UNET_MAX_LAYERS)
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: %d ResNets per level (at most %d supported)", path,
                        c->layers_per_block, MLB_UNET_MAX_LAYERS);
    int n = 0;
    for (; n < MLB_UNET_MAX_LEVELS + 1; n++) {
        snprintf(d, sizeof d, "down_blocks.%d.resnets.0.conv1.weight", n);
        t = find_d(st, u, d);
        if (!t) break;
        if (n == MLB_UNET_MAX_LEVELS)
            return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: more than %d UNet levels", path, MLB_UNET_MAX_LEVELS);
        c->block_out[n] = (int)t->shape[0];
        snprintf(d, sizeof d, "down_blocks.%d.attentions.0.norm.weight", n);
        c->attn[n] = find_d(st, u, d) != NULL;
    }
    if (n < 2) return mlb_fail(MLB_ERR_FORMAT, "%s: found %d UNet levels (need at least 2)", path, n);
    c->n_levels = n;
    MLB_TRY(need(st, u, "mid_block.attentions.0.transformer_blocks.0.attn2.to_k.weight", &t));
    if (t->ndim != 2) return mlb_fail(MLB_ERR_FORMAT, "%s: the mid block's attn2.to_k weight is not 2-D", path);
    c->context_dim = (int)t->shape[1];
    MLB_TRY(need(st, u, "mid_block.attentions.0.proj_in.weight", &t));
    c->linear_projection = t->ndim == 2;
    c->sd2 = c->context_dim == 1024 || c->linear_projection;
    return MLB_OK;
}

// ---- configuration --------------------------------------------------------------------------------
typedef struct {
    int heads[MLB_UNET_MAX_LEVELS], n_heads;   // heads per level (diffusers semantics), count given
    int head_channels;                        // ldm num_head_channels (> 0: heads = C / it)
    int groups, v_pred, flip, has_flip;
    double eps, shift;
} unet_cfg_file;

static int pos_int(const cJSON* v) { return cJSON_IsNumber(v) && v->valuedouble >= 1 && v->valuedouble < 1e9 && v->valuedouble == floor(v->valuedouble); }

static mlb_status read_heads(const cJSON* v, unet_cfg_file* f, const char* src, const char* key) {
    if (pos_int(v)) { f->heads[0] = (int)v->valuedouble; f->n_heads = 1; return MLB_OK; }
    if (cJSON_IsArray(v)) {
        int n = 0;
        for (const cJSON* e = v->child; e; e = e->next) {
            if (!pos_int(e) || n >= MLB_UNET_MAX_LEVELS) return mlb_fail(MLB_ERR_FORMAT, "%s: '%s' is not a list of up to %d positive integers", src, key, MLB_UNET_MAX_LEVELS);
            f->heads[n++] = (int)e->valuedouble;
        }
        f->n_heads = n;
        return MLB_OK;
    }
    return mlb_fail(MLB_ERR_FORMAT, "%s: '%s' is not a positive integer or a list of them", src, key);
}

static mlb_status parse_config_json(const char* path, unet_cfg_file* f) {
    cJSON* root;
    MLB_TRY(mlb_json_read_file(path, UNET_CONFIG_MAX, &root));
    if (!cJSON_IsObject(root)) { cJSON_Delete(root); return mlb_fail(MLB_ERR_FORMAT, "%s: not a JSON object", path); }
    mlb_status s = MLB_OK;
    const cJSON* v = cJSON_GetObjectItemCaseSensitive(root, "num_attention_heads");
    const char* key = "num_attention_heads";
    if (!v || cJSON_IsNull(v)) { v = cJSON_GetObjectItemCaseSensitive(root, "attention_head_dim"); key = "attention_head_dim"; }
    if (v && !cJSON_IsNull(v)) s = read_heads(v, f, path, key);   // diffusers: attention_head_dim = heads
    if (s == MLB_OK && (v = cJSON_GetObjectItemCaseSensitive(root, "norm_num_groups")) != NULL) {
        if (!pos_int(v)) s = mlb_fail(MLB_ERR_FORMAT, "%s: 'norm_num_groups' is not a positive integer", path);
        else f->groups = (int)v->valuedouble;
    }
    if (s == MLB_OK && (v = cJSON_GetObjectItemCaseSensitive(root, "norm_eps")) != NULL) {
        if (!cJSON_IsNumber(v) || !(v->valuedouble > 0 && v->valuedouble < 1)) s = mlb_fail(MLB_ERR_FORMAT, "%s: 'norm_eps' is not a number in (0, 1)", path);
        else f->eps = v->valuedouble;
    }
    if (s == MLB_OK && (v = cJSON_GetObjectItemCaseSensitive(root, "flip_sin_to_cos")) != NULL && cJSON_IsBool(v)) {
        f->flip = cJSON_IsTrue(v);
        f->has_flip = 1;
    }
    if (s == MLB_OK && (v = cJSON_GetObjectItemCaseSensitive(root, "freq_shift")) != NULL && cJSON_IsNumber(v)) f->shift = v->valuedouble;
    if (s == MLB_OK && (v = cJSON_GetObjectItemCaseSensitive(root, "prediction_type")) != NULL && cJSON_IsString(v))
        f->v_pred = !strcmp(v->valuestring, "v_prediction");
    cJSON_Delete(root);
    return s;
}

static mlb_status parse_ldm_config(const mlb_safetensors* st, unet_cfg_file* f) {
    int bad;
    cJSON* root = mlb_sd_ldm_config(st, &bad);
    if (bad) return mlb_fail(MLB_ERR_FORMAT, "%s: ldm_config metadata is not valid JSON", mlb_st_path(st));
    if (!root) return MLB_OK;
    mlb_status s = MLB_OK;
    const cJSON* un = mlb_json_find(root, "unet_config");
    const cJSON* p = un ? cJSON_GetObjectItemCaseSensitive(un, "params") : NULL;
    const cJSON* v;
    if (p && (v = cJSON_GetObjectItemCaseSensitive(p, "num_head_channels")) != NULL && pos_int(v))
        f->head_channels = (int)v->valuedouble;
    else if (p && (v = cJSON_GetObjectItemCaseSensitive(p, "num_heads")) != NULL && pos_int(v))
        s = read_heads(v, f, mlb_st_path(st), "ldm_config num_heads");
    const cJSON* par = mlb_json_find(root, "parameterization");
    if (cJSON_IsString(par)) f->v_pred = !strcmp(par->valuestring, "v");
    cJSON_Delete(root);
    return s;
}

// ---- parameters -------------------------------------------------------------------------------------
typedef struct {
    mlb_unet* u;
    const mlb_safetensors* st;
    int pass;     // 0: count, 1: carve and read, 2: carve only
    size_t n;     // parameters
    size_t slots; // floats of storage (fewer than n with bf16 weights)
    float* p;
    float* tmp;   // bf16 weights: one tensor read in fp32 before rounding (the largest one)
    size_t tmp_n;
    int as_linear; // the weights registered now run as linear layers whatever their dimensions
    int not_f16;   // f16 weights asked for: linear/conv weights the file does not store as F16 (pass 0)
} loader;

// With bf16 weights the linear ([OC, C], or [OC, C, 1, 1] run as linear) and conv ([OC, C, KH, KW])
// weights are rounded to bf16 and packed for the bf16 kernel (mlb_bf16_pack_linear_weight / _conv_weight: uint32_t words of two
// bf16 values, about n / 2 floats of storage), so that no call packs them again.
// With f16 weights (all of them F16 in the file) the same weights are kept as the file's uint16_t
// values, (n + 1) / 2 floats of storage, for mlb_backend_cpu_f16_stored to widen per call.
static mlb_status reg(loader* L, float** dst, const char* d, int ndim, int64_t a, int64_t b, int64_t c, int64_t e) {
    int64_t shape[4] = {a, b, c, e};
    size_t n = 1;
    for (int i = 0; i < ndim; i++) n *= (size_t)shape[i];
    int half = L->u->bf16_weights && (ndim == 2 || ndim == 4), linear = ndim == 2 || L->as_linear;
    int f16 = L->u->f16_weights && (ndim == 2 || ndim == 4);
    int K = half ? (int)(n / (size_t)a) : 0;   // the conv's C·KH·KW or the linear's C
    size_t slots = f16 ? (n + 1) / 2
                 : !half ? n : linear ? mlb_bf16_linear_weight_words((int)a, K) : mlb_bf16_conv_weight_words((int)a, K);
    char name[512];
    if (L->pass == 0) {
        L->n += n;
        L->slots += slots;
        if (half && n > L->tmp_n) L->tmp_n = n;
        if (f16) {
            tensor_name(name, sizeof name, L->u, d);
            const mlb_st_tensor* t = mlb_st_find(L->st, name);
            if (!t || t->dtype != MLB_DT_F16) L->not_f16++;
        }
        return MLB_OK;
    }
    *dst = L->p;
    L->p += slots;
    if (L->pass == 2) return MLB_OK;
    tensor_name(name, sizeof name, L->u, d);
    MLB_TRY(mlb_st_expect(L->st, name, ndim, shape));
    if (f16) return mlb_st_read_raw(L->st, name, MLB_DT_F16, *dst, n * sizeof(uint16_t));
    if (!half) return mlb_st_read_f32(L->st, name, *dst, n);
    MLB_TRY(mlb_st_read_f32(L->st, name, L->tmp, n));
    if (linear) mlb_bf16_pack_linear_weight((uint32_t*)*dst, L->tmp, (int)a, K);   // the CPU has it: checked
    else mlb_bf16_pack_conv_weight((uint32_t*)*dst, L->tmp, (int)a, K);               // before the walk
    return MLB_OK;
}

// The schema's walk (unet_schema.c) registers every tensor in the buffer's order.
static mlb_status visit(void* ctx, const unet_schema_tensor* t) {
    loader* L = ctx;
    L->as_linear = t->as_linear;
    return reg(L, t->slot, t->name, t->ndim, t->shape[0], t->shape[1], t->shape[2], t->shape[3]);
}

static mlb_status walk(loader* L) { return unet_schema_walk(&L->u->cfg, L->u, visit, L); }

static mlb_status heads_for(const mlb_unet_config* c, const unet_cfg_file* f, int level, int C, int* out,
                            const char* path) {
    int h;
    if (f->head_channels > 0) h = C / f->head_channels;
    else if (f->n_heads > 0) h = f->heads[f->n_heads == 1 ? 0 : (level < f->n_heads ? level : f->n_heads - 1)];
    else h = c->context_dim == 1024 ? C / 64 : 8;   // the real models: SD2 head width 64, SD1 8 heads
    if (h < 1 || C % h)
        return mlb_fail(MLB_ERR_FORMAT, "%s: %d attention heads do not divide the %d channels of UNet level %d",
                        path, h, C, level);
    *out = h;
    return MLB_OK;
}

mlb_status mlb_unet_from_st(const mlb_safetensors* st, const char* config_path, mlb_unet** out) {
    mlb_unet_options o = {config_path, 0, 0};
    return mlb_unet_from_st_opt(st, &o, out);
}

mlb_status mlb_unet_from_st_opt(const mlb_safetensors* st, const mlb_unet_options* opt, mlb_unet** out) {
    const char* config_path = opt ? opt->config_path : NULL;
    if (!out) return mlb_fail(MLB_ERR_ARG, "mlb_unet_from_st: NULL output");
    *out = NULL;
    mlb_unet* u = calloc(1, sizeof *u);
    if (!u) return mlb_fail(MLB_ERR_NOMEM, "out of memory for the UNet");
    mlb_unet_config* c = &u->cfg;
    mlb_status s = MLB_OK;
    loader L = {u, st, 0, 0, 0, NULL, NULL, 0, 0, 0};
    if (mlb_st_find(st, LDM_PREFIX "input_blocks.0.0.weight")) c->layout = MLB_UNET_LAYOUT_LDM;
    else if (mlb_st_find(st, "conv_in.weight")) c->layout = MLB_UNET_LAYOUT_DIFFUSERS;
    else { s = mlb_fail(MLB_ERR_FORMAT, "%s: no UNet found (neither 'conv_in.weight' nor '" LDM_PREFIX "input_blocks.0.0.weight')", mlb_st_path(st)); goto fail; }
    if ((s = infer_structure(st, u)) != MLB_OK) goto fail;
    unet_cfg_file f;
    memset(&f, 0, sizeof f);
    f.flip = 1;
    if (config_path) s = parse_config_json(config_path, &f);
    else if (c->layout == MLB_UNET_LAYOUT_LDM) s = parse_ldm_config(st, &f);
    if (s != MLB_OK) goto fail;
    const char* cfg_src = config_path ? config_path : mlb_st_path(st);
    c->norm_groups = f.groups ? f.groups : 32;
    c->norm_eps = f.eps > 0 ? (float)f.eps : 1e-5f;
    c->transformer_norm_eps = 1e-6f;
    c->layer_norm_eps = 1e-5f;
    c->flip_sin_to_cos = f.flip;
    c->freq_shift = (float)f.shift;
    c->v_prediction = f.v_pred;
    for (int i = 0; i < c->n_levels; i++) {
        if (c->block_out[i] % c->norm_groups) { s = mlb_fail(MLB_ERR_FORMAT, "%s: UNet level %d has %d channels, not a multiple of %d groups", cfg_src, i, c->block_out[i], c->norm_groups); goto fail; }
        if (c->attn[i] && (s = heads_for(c, &f, i, c->block_out[i], &c->heads[i], cfg_src)) != MLB_OK) goto fail;
    }
    if ((s = heads_for(c, &f, c->n_levels - 1, c->block_out[c->n_levels - 1], &c->mid_heads, cfg_src)) != MLB_OK) goto fail;
    if (c->block_out[0] % 2) { s = mlb_fail(MLB_ERR_FORMAT, "%s: odd time-projection width %d", cfg_src, c->block_out[0]); goto fail; }
    if (opt && opt->bf16_weights) {
        if (mlb_bf16_packing_available()) u->bf16_weights = 1;
        else mlb_log(MLB_LOG_INFO, "%s: bf16 weights asked for, but this CPU has no AVX-512 BF16: loading fp32", mlb_st_path(st));
    }
    u->f16_weights = opt && opt->f16_weights && !u->bf16_weights;
    if ((s = walk(&L)) != MLB_OK) goto fail;
    if (u->f16_weights && L.not_f16) {   // widening F32 weights to keep them half would round them
        mlb_log(MLB_LOG_INFO, "%s: %d linear/conv weights are not F16 in the file: the UNet's weights load in fp32",
                mlb_st_path(st), L.not_f16);
        u->f16_weights = 0;
        L.n = L.slots = L.tmp_n = 0;
        if ((s = walk(&L)) != MLB_OK) goto fail;
    }
    u->n_params = L.n;
    u->params = malloc(L.slots * sizeof(float));
    L.tmp = L.tmp_n ? malloc(L.tmp_n * sizeof(float)) : NULL;
    if (!u->params || (L.tmp_n && !L.tmp)) { s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for the UNet's %zu parameters", mlb_st_path(st), L.n); goto fail; }
    L.pass = 1;
    L.p = u->params;
    if ((s = walk(&L)) != MLB_OK) goto fail;
    free(L.tmp);
    if (u->bf16_weights) u->mirror_ops = mlb_backend_cpu_bf16_stored();
    if (u->f16_weights) u->mirror_ops = mlb_backend_cpu_f16_stored();
    *out = u;
    return MLB_OK;
fail:
    free(L.tmp);
    mlb_unet_free(u);
    return s;
}

// A model folder, the unet/ folder (either with .safetensors or the fp16 variant's
// .fp16.safetensors) or one file; pickles refused, as for the other components.
mlb_status mlb_unet_load(const char* path, const mlb_unet_options* opt, mlb_unet** out) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "mlb_unet_load: NULL output");
    *out = NULL;
    mlb_sd_component c;
    MLB_TRY(mlb_sd_component_open("UNet", path, "unet", "diffusion_pytorch_model", opt ? opt->config_path : NULL, &c));
    if (!c.config && mlb_st_find(c.st, "conv_in.weight")) {   // a diffusers file: a config beside it
        mlb_sd_config_beside(mlb_st_path(c.st), c.buf, sizeof c.buf);
        if (c.buf[0]) c.config = c.buf;
    }
    mlb_unet_options o = {c.config, opt ? opt->bf16_weights : 0, opt ? opt->f16_weights : 0};
    mlb_status s = mlb_unet_from_st_opt(c.st, &o, out);
    mlb_st_close(c.st);
    return s;
}

void mlb_unet_free(mlb_unet* u) {
    if (!u) return;
    mlb_unet_free(u->mirror);
    mlb_backend_for(u->device, MLB_GEMM_FP32)->release(u->params);
    free(u);
}

mlb_status mlb_unet_create(const mlb_unet_config* c, mlb_device d, mlb_unet** out) {
    if (!c || !out) return mlb_fail(MLB_ERR_ARG, "mlb_unet_create: NULL argument");
    *out = NULL;
    MLB_TRY(mlb_unet_config_check(c));
    mlb_unet* u = calloc(1, sizeof *u);
    if (!u) return mlb_fail(MLB_ERR_NOMEM, "out of memory for the UNet");
    u->cfg = *c;
    u->device = d;
    loader L = {u, NULL, 0, 0, 0, NULL, NULL, 0, 0, 0};
    mlb_status s = walk(&L);
    if (s == MLB_OK) {
        u->n_params = L.n;
        s = mlb_backend_for(d, MLB_GEMM_FP32)->alloc(&u->params, L.n);
    }
    if (s == MLB_OK) {
        L.pass = 2;
        L.p = u->params;
        s = walk(&L);
    }
    if (s != MLB_OK) {
        mlb_unet_free(u);
        return mlb_fail_context(s, "UNet of %zu parameters on the %s", L.n, mlb_device_name(d));
    }
    *out = u;
    return MLB_OK;
}

mlb_unet_options mlb_unet_options_for(mlb_device d, mlb_gemm_precision prec) {
    mlb_unet_options o = {NULL, 0, 0};
    if (d != MLB_DEVICE_CPU) return o;
    o.bf16_weights = prec == MLB_GEMM_BF16 && mlb_gemm_bf16_native();
    o.f16_weights = !o.bf16_weights;
    return o;
}

mlb_status mlb_unet_to_device(const mlb_unet* src, mlb_device d, mlb_unet** out) {
    if (!src || !out) return mlb_fail(MLB_ERR_ARG, "mlb_unet_to_device: NULL argument");
    if (src->device != MLB_DEVICE_CPU) return mlb_fail(MLB_ERR_ARG, "mlb_unet_to_device: the source must be on the CPU");
    if (src->bf16_weights || src->f16_weights)
        return mlb_fail(MLB_ERR_UNSUPPORTED, "mlb_unet_to_device: the UNet keeps its weights in %s; load it in fp32",
                        src->bf16_weights ? "bf16" : "f16");
    MLB_TRY(mlb_unet_create(&src->cfg, d, out));
    mlb_status s = mlb_backend_for(d, MLB_GEMM_FP32)->upload((*out)->params, src->params, src->n_params);
    if (s != MLB_OK) {
        mlb_unet_free(*out);
        *out = NULL;
    }
    return s;
}

const mlb_unet_config* mlb_unet_get_config(const mlb_unet* u) { return u ? &u->cfg : NULL; }
size_t mlb_unet_param_count(const mlb_unet* u) { return u ? u->n_params : 0; }

mlb_status mlb_unet_use_device(mlb_unet* u, mlb_device d, mlb_gemm_precision prec) {
    if (!u) return mlb_fail(MLB_ERR_ARG, "mlb_unet_use_device: NULL UNet");
    if (u->bf16_weights) {   // no fp32 weights to run on anything else
        if (d == MLB_DEVICE_CPU && prec == MLB_GEMM_BF16) return MLB_OK;
        return mlb_fail(MLB_ERR_UNSUPPORTED, "this UNet keeps its weights in bf16 (loaded with bf16_weights): it runs "
                        "only on the CPU in bf16; load it again for %s on the %s", mlb_gemm_precision_name(prec),
                        mlb_device_name(d));
    }
    if (u->f16_weights) {   // the CPU's fp32 ops (its bf16 ones are fp32 without AVX-512 BF16)
        if (d == MLB_DEVICE_CPU && (prec != MLB_GEMM_BF16 || !mlb_gemm_bf16_native())) return MLB_OK;
        return mlb_fail(MLB_ERR_UNSUPPORTED, "this UNet keeps its weights in f16 (loaded with f16_weights): it runs "
                        "only on the CPU in fp32; load it again for %s on the %s", mlb_gemm_precision_name(prec),
                        mlb_device_name(d));
    }
    mlb_unet_free(u->mirror);
    u->mirror = NULL;
    // on the CPU no copy: only bf16 changes the ops (fp16 and tf32 are GPU formats: fp32 here)
    u->mirror_ops = d == MLB_DEVICE_CPU && prec == MLB_GEMM_BF16 ? mlb_backend_for(d, prec) : NULL;
    if (d == MLB_DEVICE_CPU) return MLB_OK;
    if (u->device != MLB_DEVICE_CPU) return mlb_fail(MLB_ERR_ARG, "mlb_unet_use_device: the UNet must be on the CPU");
    MLB_TRY(mlb_unet_to_device(u, d, &u->mirror));
    u->mirror_ops = mlb_backend_for(d, prec);
    return MLB_OK;
}
