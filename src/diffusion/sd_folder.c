// A Stable Diffusion model written in the diffusers folder layout (include/matlaber/sd_folder.h).
#include "matlaber/sd_folder.h"
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/fileio.h"
#include "matlaber/half.h"
#include "matlaber/rng.h"
#include "matlaber/safetensors.h"
#include "matlaber/tokenizer.h"
#include "matlaber/unet_random.h"

#define TE_STREAM 0x7E57000ull   // + the tensor's index: the text encoder's random values

static mlb_status write_text(const char* path, const char* text) { return mlb_write_file_atomic(path, text, strlen(text)); }

// ---- tokenizer -----------------------------------------------------------------------------------
// The merges of one word: its prefixes grown a character at a time, the last one with "</w>".
// `seen` holds the tokens made so far (one per line of `out`), so shared prefixes merge once.
static mlb_status word_merges(const char* w, char** out, size_t* len, size_t* cap, char*** seen, int* n_seen) {
    size_t n = strlen(w);
    char sym[256], next[16], made[272];
    if (n < 1 || n > 200) return mlb_fail(MLB_ERR_ARG, "tokenizer word '%s': 1..200 bytes", w);
    for (size_t i = 0; i < n; i++)
        if (w[i] <= ' ' || w[i] >= 127) return mlb_fail(MLB_ERR_ARG, "tokenizer word '%s': printable ASCII without spaces", w);
    snprintf(sym, sizeof sym, "%c%s", w[0], n == 1 ? "</w>" : "");
    for (size_t i = 1; i < n; i++) {
        snprintf(next, sizeof next, "%c%s", w[i], i == n - 1 ? "</w>" : "");
        snprintf(made, sizeof made, "%s%s", sym, next);
        int dup = 0;
        for (int k = 0; k < *n_seen && !dup; k++) dup = !strcmp((*seen)[k], made);
        if (!dup) {
            size_t add = strlen(sym) + strlen(next) + 2;
            if (*len + add + 1 > *cap) {
                size_t nc = (*cap + add) * 2;
                char* p = realloc(*out, nc);
                if (!p) return mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory");
                *out = p;
                *cap = nc;
            }
            *len += (size_t)sprintf(*out + *len, "%s %s\n", sym, next);
            char** s2 = realloc(*seen, sizeof(char*) * (size_t)(*n_seen + 1));
            if (!s2) return mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory");
            *seen = s2;
            if (!((*seen)[*n_seen] = strdup(made))) return mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory");
            (*n_seen)++;
        }
        snprintf(sym, sizeof sym, "%s", made);
    }
    return MLB_OK;
}

mlb_status mlb_sd_write_tokenizer(const char* dir, const char* const* words, int n_words) {
    if (!dir || (!words && n_words > 0) || n_words < 0) return mlb_fail(MLB_ERR_ARG, "mlb_sd_write_tokenizer: bad argument");
    MLB_TRY(mlb_mkdir_p(dir));
    size_t cap = 4096, len = 0;
    char* text = malloc(cap);
    char** seen = NULL;
    int n_seen = 0;
    mlb_tokenizer* tok = NULL;
    cJSON* vocab = NULL;
    char* json = NULL;
    mlb_status s = MLB_OK;
    if (!text) return mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory");
    len = (size_t)sprintf(text, "#version: 0.2 (matlaber catalogue vocabulary)\n");
    for (int i = 0; i < n_words && !s; i++) s = word_merges(words[i], &text, &len, &cap, &seen, &n_seen);
    if (!s && n_seen == 0) s = mlb_fail(MLB_ERR_ARG, "tokenizer: the words make no merge (a word of two letters at least)");
    char path[4200];
    snprintf(path, sizeof path, "%s/merges.txt", dir);
    if (!s) s = mlb_write_file_atomic(path, text, len);
    // vocab.json: the tokens the merges give, read back through the loader itself
    if (!s) s = mlb_tokenizer_load(path, &tok);
    if (!s && !(vocab = cJSON_CreateObject())) s = mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory");
    for (int id = 0; !s && id < mlb_tokenizer_vocab_size(tok); id++)
        if (!cJSON_AddNumberToObject(vocab, mlb_tokenizer_token(tok, id), id)) s = mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory");
    if (!s && !(json = cJSON_PrintUnformatted(vocab))) s = mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory");
    snprintf(path, sizeof path, "%s/vocab.json", dir);
    if (!s) s = write_text(path, json);
    free(json);
    cJSON_Delete(vocab);
    mlb_tokenizer_free(tok);
    for (int k = 0; k < n_seen; k++) free(seen[k]);
    free(seen);
    free(text);
    return s;
}

// ---- text encoder --------------------------------------------------------------------------------
mlb_status mlb_text_encoder_write_random(const char* dir, const mlb_text_encoder_shape* sh) {
    if (!dir || !sh || sh->vocab < 3 || sh->width < 1 || sh->layers < 1 || sh->heads < 1 || sh->mlp < 1 ||
        sh->width % sh->heads)
        return mlb_fail(MLB_ERR_ARG, "text encoder: vocabulary %d, width %d, %d layers, %d heads, MLP %d", sh ? sh->vocab : 0,
                        sh ? sh->width : 0, sh ? sh->layers : 0, sh ? sh->heads : 0, sh ? sh->mlp : 0);
    MLB_TRY(mlb_mkdir_p(dir));
    const int64_t V = sh->vocab, W = sh->width, M = sh->mlp, NC = 77;
    // per layer: ln1 w b, q/k/v/out weights and biases, ln2 w b, fc1 w b, fc2 w b
    static const char* leaf[] = {"layer_norm1.weight", "layer_norm1.bias", "self_attn.q_proj.weight", "self_attn.q_proj.bias",
                                 "self_attn.k_proj.weight", "self_attn.k_proj.bias", "self_attn.v_proj.weight",
                                 "self_attn.v_proj.bias", "self_attn.out_proj.weight", "self_attn.out_proj.bias",
                                 "layer_norm2.weight", "layer_norm2.bias", "mlp.fc1.weight", "mlp.fc1.bias",
                                 "mlp.fc2.weight", "mlp.fc2.bias"};
    const int64_t rows[16] = {W, W, W, W, W, W, W, W, W, W, W, W, M, M, W, W};
    const int64_t cols[16] = {0, 0, W, 0, W, 0, W, 0, W, 0, 0, 0, W, 0, M, 0};
    size_t n_ent = 4 + 16 * (size_t)sh->layers;
    mlb_st_entry* ent = calloc(n_ent, sizeof *ent);
    int64_t(*shape)[2] = calloc(n_ent, sizeof *shape);
    char(*name)[96] = calloc(n_ent, sizeof *name);
    float** data = calloc(n_ent, sizeof *data);
    mlb_status s = MLB_OK;
    if (!ent || !shape || !name || !data) { s = mlb_fail(MLB_ERR_NOMEM, "text encoder: out of memory"); goto done; }
    for (size_t i = 0; i < n_ent; i++) {
        int kind;   // 0: norm weight (1), 1: zero, 2: N(0, 1/fan_in), 3: token N(0,1), 4: position N(0, 0.1^2)
        if (i == 0) { snprintf(name[i], 96, "text_model.embeddings.token_embedding.weight"); shape[i][0] = V; shape[i][1] = W; kind = 3; }
        else if (i == 1) { snprintf(name[i], 96, "text_model.embeddings.position_embedding.weight"); shape[i][0] = NC; shape[i][1] = W; kind = 4; }
        else if (i == n_ent - 2) { snprintf(name[i], 96, "text_model.final_layer_norm.weight"); shape[i][0] = W; kind = 0; }
        else if (i == n_ent - 1) { snprintf(name[i], 96, "text_model.final_layer_norm.bias"); shape[i][0] = W; kind = 1; }
        else {
            int l = (int)((i - 2) / 16), j = (int)((i - 2) % 16);
            snprintf(name[i], 96, "text_model.encoder.layers.%d.%s", l, leaf[j]);
            shape[i][0] = rows[j];
            shape[i][1] = cols[j];
            kind = cols[j] ? 2 : (j == 0 || j == 10) ? 0 : 1;
        }
        int nd = shape[i][1] ? 2 : 1;
        size_t n = (size_t)shape[i][0] * (size_t)(nd == 2 ? shape[i][1] : 1);
        if (!(data[i] = malloc(n * sizeof(float)))) { s = mlb_fail(MLB_ERR_NOMEM, "text encoder: out of memory"); goto done; }
        float std = kind == 2 ? 1.0f / sqrtf((float)shape[i][1]) : kind == 3 ? 1.0f : 0.1f;
        if (kind >= 2) mlb_rng_fill_normal(data[i], n, sh->seed, TE_STREAM + i, 0, 0.0f, std);
        else for (size_t k = 0; k < n; k++) data[i][k] = kind == 0 ? 1.0f : 0.0f;
        ent[i] = (mlb_st_entry){name[i], MLB_DT_F32, nd, shape[i], data[i]};
    }
    char path[4200], cfg[1024];
    snprintf(path, sizeof path, "%s/model.safetensors", dir);
    mlb_st_meta meta[1] = {{"format", "pt"}};
    s = mlb_st_write(path, ent, n_ent, meta, 1);
    snprintf(cfg, sizeof cfg,
             "{\n  \"architectures\": [\"CLIPTextModel\"],\n  \"model_type\": \"clip_text_model\",\n"
             "  \"hidden_act\": \"quick_gelu\",\n  \"hidden_size\": %d,\n  \"intermediate_size\": %d,\n"
             "  \"layer_norm_eps\": 1e-05,\n  \"max_position_embeddings\": 77,\n  \"num_attention_heads\": %d,\n"
             "  \"num_hidden_layers\": %d,\n  \"vocab_size\": %d,\n  \"torch_dtype\": \"float32\"\n}\n",
             sh->width, sh->mlp, sh->heads, sh->layers, sh->vocab);
    snprintf(path, sizeof path, "%s/config.json", dir);
    if (!s) s = write_text(path, cfg);
done:
    if (data) for (size_t i = 0; i < n_ent; i++) free(data[i]);
    free(data); free(name); free(shape); free(ent);
    return s;
}

// ---- UNet ----------------------------------------------------------------------------------------
mlb_status mlb_unet_save_folder(const mlb_unet* u, const char* dir, mlb_dtype dtype) {
    if (!u || !dir) return mlb_fail(MLB_ERR_ARG, "mlb_unet_save_folder: NULL argument");
    if (dtype != MLB_DT_F32 && dtype != MLB_DT_F16 && dtype != MLB_DT_BF16)
        return mlb_fail(MLB_ERR_ARG, "mlb_unet_save_folder: dtype %s (F32, F16 or BF16)", mlb_dtype_name(dtype));
    if (u->device != MLB_DEVICE_CPU || u->bf16_weights || u->f16_weights)
        return mlb_fail(MLB_ERR_ARG, "mlb_unet_save_folder: the UNet must be on the host in fp32");
    MLB_TRY(mlb_mkdir_p(dir));
    size_t n = 0;
    MLB_TRY(mlb_unet_tensor_specs(&u->cfg, NULL, 0, &n));
    mlb_unet_tensor_spec* sp = calloc(n, sizeof *sp);
    mlb_st_entry* ent = calloc(n, sizeof *ent);
    uint16_t* half = dtype == MLB_DT_F32 ? NULL : malloc(u->n_params * sizeof(uint16_t));
    if (!sp || !ent || (dtype != MLB_DT_F32 && !half)) {
        free(sp); free(ent); free(half);
        return mlb_fail(MLB_ERR_NOMEM, "UNet save: out of memory");
    }
    if (dtype == MLB_DT_F16) mlb_f32_to_f16_array(half, u->params, u->n_params);
    if (dtype == MLB_DT_BF16) mlb_f32_to_bf16_array(half, u->params, u->n_params);
    mlb_unet_tensor_specs(&u->cfg, sp, n, &n);
    // mlb_unet_create carves the parameters in the loader's order: the specs walk them in turn
    size_t off = 0;
    for (size_t i = 0; i < n; i++) {
        ent[i] = (mlb_st_entry){sp[i].name, dtype, sp[i].ndim, sp[i].shape,
                                half ? (const void*)(half + off) : (const void*)(u->params + off)};
        off += sp[i].n;
    }
    mlb_status s = off == u->n_params ? MLB_OK
                                      : mlb_fail(MLB_ERR_ARG, "UNet save: %zu parameters listed, %zu held", off, u->n_params);
    char path[4200];
    snprintf(path, sizeof path, "%s/diffusion_pytorch_model.safetensors", dir);
    mlb_st_meta meta[1] = {{"format", "pt"}};
    if (!s) s = mlb_st_write(path, ent, n, meta, 1);
    snprintf(path, sizeof path, "%s/config.json", dir);
    if (!s) s = mlb_unet_write_config_json(&u->cfg, path);
    free(sp);
    free(ent);
    free(half);
    return s;
}

// ---- index and scheduler -------------------------------------------------------------------------
mlb_status mlb_sd_write_index(const char* dir, const char* geometry_suffix) {
    if (!dir) return mlb_fail(MLB_ERR_ARG, "mlb_sd_write_index: NULL argument");
    if (!geometry_suffix) geometry_suffix = "";
    if (!mlb_sd_geometry_suffix_ok(geometry_suffix))
        return mlb_fail(MLB_ERR_ARG, "mlb_sd_write_index: the geometry suffix must be at most %d printable ASCII characters "
                                     "without quotes or backslashes", MLB_SD_SUFFIX_MAX - 1);
    char path[4200], extra[MLB_SD_SUFFIX_MAX + 64] = "";
    if (geometry_suffix[0]) snprintf(extra, sizeof extra, "  \"_matlaber_geometry_suffix\": \"%s\",\n", geometry_suffix);
    snprintf(path, sizeof path, "%s/scheduler", dir);
    MLB_TRY(mlb_mkdir_p(path));
    snprintf(path, sizeof path, "%s/model_index.json", dir);
    char text[1024];
    snprintf(text, sizeof text, "{\n  \"_class_name\": \"StableDiffusionPipeline\",\n  \"_matlaber\": \"the project's own model "
                                "(matlaber sd train)\",\n%s  \"scheduler\": [\"diffusers\", \"DDIMScheduler\"],\n"
                                "  \"text_encoder\": [\"transformers\", \"CLIPTextModel\"],\n"
                                "  \"tokenizer\": [\"transformers\", \"CLIPTokenizer\"],\n"
                                "  \"unet\": [\"diffusers\", \"UNet2DConditionModel\"],\n"
                                "  \"vae\": [\"diffusers\", \"AutoencoderKL\"]\n}\n", extra);
    MLB_TRY(write_text(path, text));
    snprintf(path, sizeof path, "%s/scheduler/scheduler_config.json", dir);
    return write_text(path, "{\n  \"_class_name\": \"DDIMScheduler\",\n  \"beta_end\": 0.012,\n"
                            "  \"beta_schedule\": \"scaled_linear\",\n  \"beta_start\": 0.00085,\n"
                            "  \"clip_sample\": false,\n  \"num_train_timesteps\": 1000,\n"
                            "  \"prediction_type\": \"epsilon\",\n  \"set_alpha_to_one\": false,\n"
                            "  \"steps_offset\": 1,\n  \"timestep_spacing\": \"leading\"\n}\n");
}
