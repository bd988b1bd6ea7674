// Random-weight UNets in the diffusers and original single-file layouts (unet_random.h).
// The tensors are the schema's walk (unet_schema.c), the loader's too; the name translation
// mirrors unet_load.c's tensor_name(); tests/test_sd_tiny.c loads both layouts and checks they agree
// bit for bit.
#include "matlaber/unet_random.h"
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/fileio.h"
#include "matlaber/half.h"
#include "matlaber/rng.h"
#include "unet_schema.h"

#define LDM_PREFIX "model.diffusion_model."
#define UNET_RANDOM_STREAM 0x0E7000000000ull

static mlb_unet_config base_config(void) {
    mlb_unet_config c;
    memset(&c, 0, sizeof c);
    c.in_channels = c.out_channels = 4;
    c.n_levels = 4;
    c.layers_per_block = 2;
    c.attn[0] = c.attn[1] = c.attn[2] = 1;
    c.norm_groups = 32;
    c.norm_eps = 1e-5f;
    c.transformer_norm_eps = 1e-6f;
    c.layer_norm_eps = 1e-5f;
    c.flip_sin_to_cos = 1;
    c.freq_shift = 0;
    c.layout = MLB_UNET_LAYOUT_DIFFUSERS;
    return c;
}

mlb_unet_config mlb_unet_tiny_config(int sd2) {
    mlb_unet_config c = base_config();
    int bo[4] = {32, 32, 64, 64};
    for (int i = 0; i < 4; i++) {
        c.block_out[i] = bo[i];
        c.heads[i] = sd2 ? bo[i] / 8 : 8;
    }
    c.mid_heads = 8;
    c.context_dim = sd2 ? 48 : 32;
    c.time_embed_dim = 4 * bo[0];
    c.linear_projection = sd2 ? 1 : 0;
    c.sd2 = sd2 ? 1 : 0;
    return c;
}

mlb_unet_config mlb_unet_sd15_config(void) {
    mlb_unet_config c = base_config();
    int bo[4] = {320, 640, 1280, 1280};
    for (int i = 0; i < 4; i++) { c.block_out[i] = bo[i]; c.heads[i] = 8; }
    c.mid_heads = 8;
    c.context_dim = 768;
    c.time_embed_dim = 1280;
    return c;
}

// Heads as one number (uniform), a head width (uniform), or neither (0 both).
static void heads_summary(const mlb_unet_config* c, int* heads, int* width) {
    int top = c->n_levels - 1, h = c->mid_heads, w = c->block_out[top] / c->mid_heads;
    int same_h = 1, same_w = c->block_out[top] % c->mid_heads == 0;
    for (int i = 0; i < c->n_levels; i++) {
        if (!c->attn[i]) continue;
        if (c->heads[i] != h) same_h = 0;
        if (c->block_out[i] % c->heads[i] || c->block_out[i] / c->heads[i] != w) same_w = 0;
    }
    *heads = same_h ? h : 0;
    *width = same_w ? w : 0;
}

mlb_status mlb_unet_config_check(const mlb_unet_config* c) {
    if (!c) return mlb_fail(MLB_ERR_ARG, "UNet config: NULL");
    if (c->n_levels < 2 || c->n_levels > MLB_UNET_MAX_LEVELS)
        return mlb_fail(MLB_ERR_ARG, "UNet config: n_levels = %d outside 2..%d", c->n_levels, MLB_UNET_MAX_LEVELS);
    if (c->layers_per_block < 1 || c->layers_per_block > MLB_UNET_MAX_LAYERS)
        return mlb_fail(MLB_ERR_ARG, "UNet config: layers_per_block = %d outside 1..%d", c->layers_per_block, MLB_UNET_MAX_LAYERS);
    if (c->in_channels < 1 || c->out_channels < 1 || c->context_dim < 1 || c->time_embed_dim < 1)
        return mlb_fail(MLB_ERR_ARG, "UNet config: in/out channels, context_dim and time_embed_dim must be positive");
    if (c->norm_groups < 1) return mlb_fail(MLB_ERR_ARG, "UNet config: norm_groups = %d", c->norm_groups);
    if (c->block_out[0] % 2) return mlb_fail(MLB_ERR_ARG, "UNet config: block_out[0] = %d is odd", c->block_out[0]);
    for (int i = 0; i < c->n_levels; i++) {
        if (c->block_out[i] < 1 || c->block_out[i] % c->norm_groups)
            return mlb_fail(MLB_ERR_ARG, "UNet config: block_out[%d] = %d is not a positive multiple of the %d groups", i,
                            c->block_out[i], c->norm_groups);
        if (c->attn[i] && (c->heads[i] < 1 || c->block_out[i] % c->heads[i]))
            return mlb_fail(MLB_ERR_ARG, "UNet config: heads[%d] = %d does not divide %d channels", i, c->heads[i], c->block_out[i]);
    }
    int top = c->n_levels - 1;
    if (c->mid_heads < 1 || c->block_out[top] % c->mid_heads)
        return mlb_fail(MLB_ERR_ARG, "UNet config: mid_heads = %d does not divide %d channels", c->mid_heads, c->block_out[top]);
    if (c->attn[top] && c->heads[top] != c->mid_heads)
        return mlb_fail(MLB_ERR_ARG, "UNet config: heads[%d] = %d differs from mid_heads = %d (no config can say that)", top,
                        c->heads[top], c->mid_heads);
    return MLB_OK;
}

// ---- the tensor list (the schema's walk, unet_schema.c) ---------------------------------------------
typedef struct {
    mlb_unet_tensor_spec* out;
    size_t cap, n;
} spec_list;

static mlb_status add(void* ctx, const unet_schema_tensor* t) {
    spec_list* L = ctx;
    if (L->out && L->n < L->cap) {
        mlb_unet_tensor_spec* s = &L->out[L->n];
        memset(s, 0, sizeof *s);
        size_t k = strlen(t->name);
        if (k >= sizeof s->name) k = sizeof s->name - 1;
        memcpy(s->name, t->name, k);
        s->name[k] = 0;
        s->ndim = t->ndim;
        s->n = 1;
        for (int i = 0; i < t->ndim; i++) { s->shape[i] = t->shape[i]; s->n *= (size_t)t->shape[i]; }
    }
    L->n++;
    return MLB_OK;
}

mlb_status mlb_unet_tensor_specs(const mlb_unet_config* c, mlb_unet_tensor_spec* out, size_t cap, size_t* count) {
    MLB_TRY(mlb_unet_config_check(c));
    spec_list L = {out, cap, 0};
    MLB_TRY(unet_schema_walk(c, NULL, add, &L));
    if (count) *count = L.n;
    return MLB_OK;
}

// ---- names: diffusers -> original (ldm) layout; the loader uses this too ---------------------------------------------------------------
static const char* res_part(const char* rest, char* buf, size_t cap) {
    static const char* map[][2] = {{"norm1.", "in_layers.0."}, {"conv1.", "in_layers.2."},
                                   {"time_emb_proj.", "emb_layers.1."}, {"norm2.", "out_layers.0."},
                                   {"conv2.", "out_layers.3."}, {"conv_shortcut.", "skip_connection."}};
    for (size_t i = 0; i < sizeof map / sizeof map[0]; i++) {
        size_t n = strlen(map[i][0]);
        if (!strncmp(rest, map[i][0], n)) { snprintf(buf, cap, "%s%s", map[i][1], rest + n); return buf; }
    }
    snprintf(buf, cap, "%s", rest);
    return buf;
}

void mlb_unet_ldm_name(const mlb_unet_config* c, const char* d, char* out, size_t cap) {
    int L = c->layers_per_block, i, j, n = 0;
    char r[256];
    if (!strncmp(d, "time_embedding.linear_1.", 24)) snprintf(out, cap, LDM_PREFIX "time_embed.0.%s", d + 24);
    else if (!strncmp(d, "time_embedding.linear_2.", 24)) snprintf(out, cap, LDM_PREFIX "time_embed.2.%s", d + 24);
    else if (!strncmp(d, "conv_in.", 8)) snprintf(out, cap, LDM_PREFIX "input_blocks.0.0.%s", d + 8);
    else if (!strncmp(d, "conv_norm_out.", 14)) snprintf(out, cap, LDM_PREFIX "out.0.%s", d + 14);
    else if (!strncmp(d, "conv_out.", 9)) snprintf(out, cap, LDM_PREFIX "out.2.%s", d + 9);
    else if (sscanf(d, "down_blocks.%d.resnets.%d.%n", &i, &j, &n) == 2 && n)
        snprintf(out, cap, LDM_PREFIX "input_blocks.%d.0.%s", 1 + i * (L + 1) + j, res_part(d + n, r, sizeof r));
    else if (sscanf(d, "down_blocks.%d.attentions.%d.%n", &i, &j, &n) == 2 && n)
        snprintf(out, cap, LDM_PREFIX "input_blocks.%d.1.%s", 1 + i * (L + 1) + j, d + n);
    else if (sscanf(d, "down_blocks.%d.downsamplers.0.conv.%n", &i, &n) == 1 && n)
        snprintf(out, cap, LDM_PREFIX "input_blocks.%d.0.op.%s", 1 + i * (L + 1) + L, d + n);
    else if (sscanf(d, "mid_block.resnets.%d.%n", &i, &n) == 1 && n)
        snprintf(out, cap, LDM_PREFIX "middle_block.%d.%s", i ? 2 : 0, res_part(d + n, r, sizeof r));
    else if (!strncmp(d, "mid_block.attentions.0.", 23)) snprintf(out, cap, LDM_PREFIX "middle_block.1.%s", d + 23);
    else if (sscanf(d, "up_blocks.%d.resnets.%d.%n", &i, &j, &n) == 2 && n)
        snprintf(out, cap, LDM_PREFIX "output_blocks.%d.0.%s", i * (L + 1) + j, res_part(d + n, r, sizeof r));
    else if (sscanf(d, "up_blocks.%d.attentions.%d.%n", &i, &j, &n) == 2 && n)
        snprintf(out, cap, LDM_PREFIX "output_blocks.%d.1.%s", i * (L + 1) + j, d + n);
    else if (sscanf(d, "up_blocks.%d.upsamplers.0.conv.%n", &i, &n) == 1 && n) {
        int lvl = c->n_levels - 1 - i;
        int has_attn = lvl >= 0 && lvl < MLB_UNET_MAX_LEVELS && c->attn[lvl];
        snprintf(out, cap, LDM_PREFIX "output_blocks.%d.%d.conv.%s", i * (L + 1) + L, has_attn ? 2 : 1, d + n);
    } else snprintf(out, cap, LDM_PREFIX "%s", d);
}

// ---- values -----------------------------------------------------------------------------------------------

void mlb_unet_random_values(const mlb_unet_tensor_spec* s, size_t i, uint64_t seed, float gain, float* out) {
    uint64_t stream = UNET_RANDOM_STREAM + i;
    const char* last = strrchr(s->name, '.');
    int is_norm = s->ndim == 1 && (strstr(s->name, "norm") != NULL);
    if (s->ndim >= 2) {
        double fan_in = 1;
        for (int k = 1; k < s->ndim; k++) fan_in *= (double)s->shape[k];
        mlb_rng_fill_normal(out, s->n, seed, stream, 0, 0.0f, (float)(gain / sqrt(fan_in)));
    } else {
        mlb_rng_fill_normal(out, s->n, seed, stream, 0, 0.0f, 0.05f);
        if (is_norm && last && mlb_ends_with(s->name, ".weight"))
            for (size_t k = 0; k < s->n; k++) out[k] += 1.0f;
    }
}

mlb_unet_random_options mlb_unet_random_default_options(void) {
    mlb_unet_random_options o = {MLB_UNET_LAYOUT_DIFFUSERS, MLB_DT_F32, 0, 1.0f, NULL};
    return o;
}

static void json_ints(char* buf, size_t cap, const int* v, int n) {
    size_t k = 0;
    k += (size_t)snprintf(buf + k, cap - k, "[");
    for (int i = 0; i < n && k < cap; i++) k += (size_t)snprintf(buf + k, cap - k, "%s%d", i ? ", " : "", v[i]);
    if (k < cap) snprintf(buf + k, cap - k, "]");
}

mlb_status mlb_unet_write_config_json(const mlb_unet_config* c, const char* path) {
    char bo[128], heads[128], down[512] = "", up[512] = "";
    int H, Wd;
    heads_summary(c, &H, &Wd);
    json_ints(bo, sizeof bo, c->block_out, c->n_levels);
    if (H) snprintf(heads, sizeof heads, "%d", H);
    else {
        int h[MLB_UNET_MAX_LEVELS];
        for (int i = 0; i < c->n_levels; i++) h[i] = c->attn[i] ? c->heads[i] : c->mid_heads;
        json_ints(heads, sizeof heads, h, c->n_levels);
    }
    for (int i = 0; i < c->n_levels; i++) {
        size_t k = strlen(down), m = strlen(up);
        snprintf(down + k, sizeof down - k, "%s\"%s\"", i ? ", " : "", c->attn[i] ? "CrossAttnDownBlock2D" : "DownBlock2D");
        snprintf(up + m, sizeof up - m, "%s\"%s\"", i ? ", " : "",
                 c->attn[c->n_levels - 1 - i] ? "CrossAttnUpBlock2D" : "UpBlock2D");
    }
    FILE* f = fopen(path, "w");
    if (!f) return mlb_fail(MLB_ERR_IO, "%s: cannot create the UNet config.json", path);
    fprintf(f, "{\n  \"_class_name\": \"UNet2DConditionModel\",\n  \"act_fn\": \"silu\",\n"
               "  \"attention_head_dim\": %s,\n  \"block_out_channels\": %s,\n  \"center_input_sample\": false,\n"
               "  \"cross_attention_dim\": %d,\n  \"down_block_types\": [%s],\n  \"flip_sin_to_cos\": %s,\n"
               "  \"freq_shift\": %g,\n  \"in_channels\": %d,\n  \"layers_per_block\": %d,\n"
               "  \"mid_block_type\": \"UNetMidBlock2DCrossAttn\",\n  \"norm_eps\": %g,\n  \"norm_num_groups\": %d,\n"
               "  \"out_channels\": %d,\n  \"prediction_type\": \"%s\",\n  \"sample_size\": 64,\n"
               "  \"up_block_types\": [%s],\n  \"use_linear_projection\": %s\n}\n",
            heads, bo, c->context_dim, down, c->flip_sin_to_cos ? "true" : "false", (double)c->freq_shift,
            c->in_channels, c->layers_per_block, (double)c->norm_eps, c->norm_groups, c->out_channels,
            c->v_prediction ? "v_prediction" : "epsilon", up, c->linear_projection ? "true" : "false");
    int bad = ferror(f);
    if (fclose(f) || bad) return mlb_fail(MLB_ERR_IO, "%s: write failed", path);
    return MLB_OK;
}

static mlb_status ldm_config_json(const mlb_unet_config* c, char* buf, size_t cap) {
    int H, Wd;
    heads_summary(c, &H, &Wd);
    char heads[64], mult[128], ares[128];
    if (H) snprintf(heads, sizeof heads, "\"num_heads\": %d", H);
    else if (Wd) snprintf(heads, sizeof heads, "\"num_head_channels\": %d", Wd);
    else return mlb_fail(MLB_ERR_ARG, "UNet config: neither the heads nor the head width are the same at every level "
                         "(the single-file ldm_config cannot say it)");
    int m[MLB_UNET_MAX_LEVELS], a[MLB_UNET_MAX_LEVELS], na = 0;
    for (int i = 0; i < c->n_levels; i++) {
        m[i] = c->block_out[i] / c->block_out[0];
        if (c->attn[i]) a[na++] = 1 << i;
    }
    json_ints(mult, sizeof mult, m, c->n_levels);
    json_ints(ares, sizeof ares, a, na);
    snprintf(buf, cap,
             "{\"model\": {\"target\": \"ldm.models.diffusion.ddpm.LatentDiffusion\", \"params\": {"
             "\"parameterization\": \"%s\", \"scale_factor\": 0.18215, \"unet_config\": {"
             "\"target\": \"ldm.modules.diffusionmodules.openaimodel.UNetModel\", \"params\": {"
             "\"image_size\": 64, \"in_channels\": %d, \"out_channels\": %d, \"model_channels\": %d, "
             "\"attention_resolutions\": %s, \"num_res_blocks\": %d, \"channel_mult\": %s, %s, "
             "\"use_spatial_transformer\": true, \"use_linear_in_transformer\": %s, \"transformer_depth\": 1, "
             "\"context_dim\": %d, \"legacy\": false}}}}}",
             c->v_prediction ? "v" : "eps", c->in_channels, c->out_channels, c->block_out[0], ares, c->layers_per_block,
             mult, heads, c->linear_projection ? "true" : "false", c->context_dim);
    return MLB_OK;
}

mlb_status mlb_unet_write_random(const mlb_unet_config* c, const mlb_unet_random_options* opt, const char* path) {
    if (!c || !path) return mlb_fail(MLB_ERR_ARG, "mlb_unet_write_random: NULL argument");
    mlb_unet_random_options o = opt ? *opt : mlb_unet_random_default_options();
    if (o.dtype != MLB_DT_F32 && o.dtype != MLB_DT_F16 && o.dtype != MLB_DT_BF16)
        return mlb_fail(MLB_ERR_ARG, "mlb_unet_write_random: dtype %s (F32, F16 or BF16)", mlb_dtype_name(o.dtype));
    if (o.layout != MLB_UNET_LAYOUT_DIFFUSERS && o.layout != MLB_UNET_LAYOUT_LDM)
        return mlb_fail(MLB_ERR_ARG, "mlb_unet_write_random: unknown layout %d", (int)o.layout);
    size_t n = 0;
    MLB_TRY(mlb_unet_tensor_specs(c, NULL, 0, &n));
    char ldm_cfg[2048];
    if (o.layout == MLB_UNET_LAYOUT_LDM) MLB_TRY(ldm_config_json(c, ldm_cfg, sizeof ldm_cfg));
    mlb_unet_tensor_spec* specs = calloc(n, sizeof *specs);
    mlb_st_entry* ents = calloc(n, sizeof *ents);
    char (*names)[200] = calloc(n, sizeof *names);
    void** data = calloc(n, sizeof *data);
    float* tmp = NULL;
    mlb_status s = MLB_OK;
    if (!specs || !ents || !names || !data) { s = mlb_fail(MLB_ERR_NOMEM, "out of memory for the UNet tensor list"); goto done; }
    mlb_unet_tensor_specs(c, specs, n, &n);
    size_t maxn = 0;
    for (size_t i = 0; i < n; i++) if (specs[i].n > maxn) maxn = specs[i].n;
    if (o.dtype != MLB_DT_F32 && !(tmp = malloc(maxn * sizeof(float)))) { s = mlb_fail(MLB_ERR_NOMEM, "out of memory"); goto done; }
    size_t es = mlb_dtype_size(o.dtype);
    for (size_t i = 0; i < n; i++) {
        data[i] = malloc(specs[i].n * es);
        if (!data[i]) { s = mlb_fail(MLB_ERR_NOMEM, "out of memory for UNet tensor '%s'", specs[i].name); goto done; }
        float* v = o.dtype == MLB_DT_F32 ? (float*)data[i] : tmp;
        mlb_unet_random_values(&specs[i], i, o.seed, o.gain, v);
        uint16_t* h = (uint16_t*)data[i];
        if (o.dtype == MLB_DT_F16) for (size_t k = 0; k < specs[i].n; k++) h[k] = mlb_f32_to_f16(v[k]);
        else if (o.dtype == MLB_DT_BF16) for (size_t k = 0; k < specs[i].n; k++) h[k] = mlb_f32_to_bf16(v[k]);
        if (o.layout == MLB_UNET_LAYOUT_LDM) mlb_unet_ldm_name(c, specs[i].name, names[i], sizeof names[i]);
        else snprintf(names[i], sizeof names[i], "%s", specs[i].name);
        ents[i].name = names[i];
        ents[i].dtype = o.dtype;
        ents[i].ndim = specs[i].ndim;
        ents[i].shape = specs[i].shape;
        ents[i].data = data[i];
    }
    mlb_st_meta meta[2] = {{"format", "pt"}, {"ldm_config", ldm_cfg}};
    s = mlb_st_write(path, ents, n, meta, o.layout == MLB_UNET_LAYOUT_LDM ? 2 : 1);
    if (s == MLB_OK && o.layout == MLB_UNET_LAYOUT_DIFFUSERS && o.config_json_path) s = mlb_unet_write_config_json(c, o.config_json_path);
done:
    if (data) for (size_t i = 0; i < n; i++) free(data[i]);
    free(data); free(names); free(ents); free(specs); free(tmp);
    return s;
}
