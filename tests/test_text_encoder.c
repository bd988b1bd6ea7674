// The SD text encoders (text_encoder.h). Without shared data: a tiny random model written by the
// test in every layout and dtype (outputs agree bitwise and with a naive double forward), the
// causal mask, overrides, threads, error messages, the op tables (the CPU fp32 table gives the
// bits of the CPU ops called directly; the bf16 table is within a bound of the double forward). With $MLB_SHARED_DATA: the sd_reference
// fixtures (README there): SD1/SD2 single files and diffusers files vs ref_text_sd1/2, half weights
// vs ref_sd1_halfweights, and the project tokenizer vs the fixtures' tokens.
#include <stdint.h>
#include <unistd.h>
#include "matlaber/backend.h"
#include "matlaber/half.h"
#include "matlaber/safetensors.h"
#include "matlaber/text_encoder.h"
#include "matlaber/threads.h"
#include "matlaber/tokenizer.h"
#include "matlaber/transformer_ops.h"
#include "test.h"
#include "cuda_test_util.h"

// ---- a tiny random model -----------------------------------------------------------------------------
enum { TV = 40, TNC = 12, TW = 16, TNH = 2, TM = 24, TL = 3 };
enum { LN1_W, LN1_B, Q_W, Q_B, K_W, K_B, V_W, V_B, O_W, O_B, LN2_W, LN2_B, FC1_W, FC1_B, FC2_W, FC2_B, NLT };
static const char* HF_LEAF[NLT] = {"layer_norm1.weight", "layer_norm1.bias", "self_attn.q_proj.weight",
    "self_attn.q_proj.bias", "self_attn.k_proj.weight", "self_attn.k_proj.bias", "self_attn.v_proj.weight",
    "self_attn.v_proj.bias", "self_attn.out_proj.weight", "self_attn.out_proj.bias", "layer_norm2.weight",
    "layer_norm2.bias", "mlp.fc1.weight", "mlp.fc1.bias", "mlp.fc2.weight", "mlp.fc2.bias"};
static const char* OC_LEAF[NLT] = {"ln_1.weight", "ln_1.bias", "attn.in_proj_weight", "attn.in_proj_bias", NULL, NULL,
    NULL, NULL, "attn.out_proj.weight", "attn.out_proj.bias", "ln_2.weight", "ln_2.bias", "mlp.c_fc.weight",
    "mlp.c_fc.bias", "mlp.c_proj.weight", "mlp.c_proj.bias"};

typedef struct {
    float tok[TV * TW], pos[TNC * TW], lnf_w[TW], lnf_b[TW];
    float* t[TL][NLT];
    float store[TL][4 * TW * TW + 2 * TM * TW + 12 * TW + TM];
} tiny_model;

static void tensor_dims(int i, int64_t* d0, int64_t* d1) {   // d1 = 0 for vectors
    *d1 = 0;
    switch (i) {
    case Q_W: case K_W: case V_W: case O_W: *d0 = TW; *d1 = TW; break;
    case FC1_W: *d0 = TM; *d1 = TW; break;
    case FC1_B: *d0 = TM; break;
    case FC2_W: *d0 = TW; *d1 = TM; break;
    default: *d0 = TW;
    }
}

static uint64_t rng_state;
static double urand(void) {
    rng_state ^= rng_state >> 12; rng_state ^= rng_state << 25; rng_state ^= rng_state >> 27;
    return (double)((rng_state * 0x2545f4914f6cdd1dull) >> 11) / 9007199254740992.0 * 2.0 - 1.0;
}

static tiny_model* tiny_make(uint64_t seed) {
    tiny_model* m = calloc(1, sizeof *m);
    rng_state = seed * 0x9e3779b97f4a7c15ull + 1;
    for (int i = 0; i < TV * TW; i++) m->tok[i] = (float)urand();
    for (int i = 0; i < TNC * TW; i++) m->pos[i] = (float)(0.3 * urand());
    for (int i = 0; i < TW; i++) { m->lnf_w[i] = (float)(1 + 0.2 * urand()); m->lnf_b[i] = (float)(0.1 * urand()); }
    for (int l = 0; l < TL; l++) {
        float* p = m->store[l];
        for (int i = 0; i < NLT; i++) {
            int64_t d0, d1;
            tensor_dims(i, &d0, &d1);
            size_t n = (size_t)d0 * (d1 ? d1 : 1);
            m->t[l][i] = p;
            for (size_t j = 0; j < n; j++)
                p[j] = (float)(i == LN1_W || i == LN2_W ? 1 + 0.2 * urand() : d1 ? 0.5 * urand() : 0.1 * urand());
            p += n;
        }
    }
    return m;
}

static void tiny_round(tiny_model* m, mlb_dtype dt) {   // weights to the values an F16/BF16 file holds
    float* arrays[4] = {m->tok, m->pos, m->lnf_w, m->lnf_b};
    size_t sizes[4] = {TV * TW, TNC * TW, TW, TW};
    for (int a = 0; a < 5; a++) {
        float* p = a < 4 ? arrays[a] : m->store[0];
        size_t n = a < 4 ? sizes[a] : sizeof m->store / sizeof(float);
        for (size_t i = 0; i < n; i++)
            p[i] = dt == MLB_DT_F16 ? mlb_f16_to_f32(mlb_f32_to_f16(p[i])) : mlb_bf16_to_f32(mlb_f32_to_bf16(p[i]));
    }
}

// ---- writing it in the three layouts -------------------------------------------------------------------
enum { LAY_LDM, LAY_OPENCLIP, LAY_DIFFUSERS };
typedef struct {
    mlb_st_entry e[128];
    char names[128][160];
    int64_t shapes[128][2];
    void* owned[128];
    int n, n_owned;
} entry_list;

static void add_entry(entry_list* L, mlb_dtype dt, const char* name, const float* data, int64_t d0, int64_t d1,
                      const char* omit, const char* halve) {
    if (omit && !strcmp(name, omit)) return;
    int i = L->n++;
    snprintf(L->names[i], sizeof L->names[i], "%s", name);
    L->shapes[i][0] = d0; L->shapes[i][1] = d1;
    if (halve && !strcmp(name, halve)) L->shapes[i][d1 ? 1 : 0] /= 2;   // wrong shape, fewer values
    size_t n = (size_t)L->shapes[i][0] * (d1 ? L->shapes[i][1] : 1);
    const void* out = data;
    if (dt != MLB_DT_F32) {
        uint16_t* h = malloc(n * 2);
        if (dt == MLB_DT_F16) mlb_f32_to_f16_array(h, data, n); else mlb_f32_to_bf16_array(h, data, n);
        L->owned[L->n_owned++] = h;
        out = h;
    }
    L->e[i] = (mlb_st_entry){L->names[i], dt, d1 ? 2 : 1, L->shapes[i], out};
}

// A file in `layout` at `path`; omit/halve name a tensor to leave out / to write with half its last dimension.
static mlb_status tiny_write(const tiny_model* m, int layout, mlb_dtype dt, const char* path, int with_meta,
                             const char* omit, const char* halve) {
    entry_list* L = calloc(1, sizeof *L);
    const char* P = layout == LAY_LDM ? "cond_stage_model.transformer.text_model."
                  : layout == LAY_OPENCLIP ? "cond_stage_model.model." : "text_model.";
    char nm[160];
    int oc = layout == LAY_OPENCLIP;
    snprintf(nm, sizeof nm, "%s%s", P, oc ? "token_embedding.weight" : "embeddings.token_embedding.weight");
    add_entry(L, dt, nm, m->tok, TV, TW, omit, halve);
    snprintf(nm, sizeof nm, "%s%s", P, oc ? "positional_embedding" : "embeddings.position_embedding.weight");
    add_entry(L, dt, nm, m->pos, TNC, TW, omit, halve);
    for (int l = 0; l < TL; l++)
        for (int i = 0; i < NLT; i++) {
            int64_t d0, d1;
            tensor_dims(i, &d0, &d1);
            if (oc && (i == Q_W || i == Q_B)) {   // in_proj = concat(q, k, v)
                size_t n = (size_t)d0 * (d1 ? d1 : 1);
                float* f = malloc(3 * n * sizeof(float));
                for (int j = 0; j < 3; j++) memcpy(f + j * n, m->t[l][i + 2 * j], n * sizeof(float));
                L->owned[L->n_owned++] = f;
                d0 *= 3;
                snprintf(nm, sizeof nm, "%stransformer.resblocks.%d.%s", P, l, OC_LEAF[i]);
                add_entry(L, dt, nm, f, d0, d1, omit, halve);
            } else if (oc && !OC_LEAF[i]) {
                continue;
            } else {
                snprintf(nm, sizeof nm, oc ? "%stransformer.resblocks.%d.%s" : "%sencoder.layers.%d.%s", P, l,
                         oc ? OC_LEAF[i] : HF_LEAF[i]);
                add_entry(L, dt, nm, m->t[l][i], d0, d1, omit, halve);
            }
        }
    snprintf(nm, sizeof nm, "%s%s", P, oc ? "ln_final.weight" : "final_layer_norm.weight");
    add_entry(L, dt, nm, m->lnf_w, TW, 0, omit, halve);
    snprintf(nm, sizeof nm, "%s%s", P, oc ? "ln_final.bias" : "final_layer_norm.bias");
    add_entry(L, dt, nm, m->lnf_b, TW, 0, omit, halve);
    static const int64_t pid_shape[2] = {1, TNC};
    int64_t pid[TNC];
    static const float logit_scale = 4.6f;
    for (int i = 0; i < TNC; i++) pid[i] = i;
    if (layout == LAY_LDM)   // published SD 1.x files carry position_ids (int64)
        L->e[L->n++] = (mlb_st_entry){"cond_stage_model.transformer.text_model.embeddings.position_ids", MLB_DT_I64, 2,
                                      pid_shape, pid};
    if (oc) L->e[L->n++] = (mlb_st_entry){"cond_stage_model.model.logit_scale", MLB_DT_F32, 0, NULL, &logit_scale};
    char cfg[512];
    snprintf(cfg, sizeof cfg, "{\"model\": {\"params\": {\"cond_stage_config\": {\"target\": \"%s\", \"params\": "
             "{\"%s\": {\"%s\": %d}%s}}}}}", oc ? "FrozenOpenCLIPEmbedder" : "FrozenCLIPEmbedder",
             oc ? "tiny_open_clip_text_config" : "tiny_clip_text_config", oc ? "heads" : "num_attention_heads", TNH,
             oc ? ", \"layer\": \"penultimate\"" : "");
    mlb_st_meta meta[2] = {{"format", "pt"}, {"ldm_config", cfg}};
    mlb_status s = mlb_st_write(path, L->e, L->n, meta, with_meta ? 2 : 1);
    for (int i = 0; i < L->n_owned; i++) free(L->owned[i]);
    free(L);
    return s;
}

static int write_text(const char* path, const char* text) {
    FILE* f = fopen(path, "w");
    if (!f) return -1;
    fputs(text, f);
    return fclose(f);
}

// A diffusers model folder dir/text_encoder/{model.safetensors, config.json}.
static mlb_status tiny_write_diffusers(const tiny_model* m, const char* dir, const char* act, int hidden) {
    char p[1200], cfg[600];
    snprintf(p, sizeof p, "mkdir -p '%s/text_encoder'", dir);
    if (system(p) != 0) return MLB_ERR_IO;
    snprintf(p, sizeof p, "%s/text_encoder/model.safetensors", dir);
    MLB_TRY(tiny_write(m, LAY_DIFFUSERS, MLB_DT_F32, p, 0, NULL, NULL));
    snprintf(cfg, sizeof cfg, "{\"architectures\": [\"CLIPTextModel\"], \"hidden_act\": \"%s\", \"hidden_size\": %d, "
             "\"intermediate_size\": %d, \"layer_norm_eps\": 1e-05, \"max_position_embeddings\": %d, \"model_type\": "
             "\"clip_text_model\", \"num_attention_heads\": %d, \"num_hidden_layers\": %d, \"vocab_size\": %d}\n",
             act, hidden, TM, TNC, TNH, TL, TV);
    snprintf(p, sizeof p, "%s/text_encoder/config.json", dir);
    return write_text(p, cfg) == 0 ? MLB_OK : MLB_ERR_IO;
}

// ---- a naive double forward ----------------------------------------------------------------------------
static void naive_ln(double* o, const double* x, const float* w, const float* b) {
    double m = 0, v = 0;
    for (int c = 0; c < TW; c++) m += x[c];
    m /= TW;
    for (int c = 0; c < TW; c++) v += (x[c] - m) * (x[c] - m);
    v /= TW;
    for (int c = 0; c < TW; c++) o[c] = (x[c] - m) / sqrt(v + 1e-5) * w[c] + b[c];
}
static void naive_linear(double* o, const double* x, const float* w, const float* b, int in, int out) {
    for (int j = 0; j < out; j++) {
        double s = b[j];
        for (int i = 0; i < in; i++) s += (double)w[j * in + i] * x[i];
        o[j] = s;
    }
}

// out [B,T,TW] after `layers` layers and the final LN; gelu: exact GELU, else quick_gelu.
static void naive_forward(const tiny_model* m, int layers, int gelu, const int* tok, int B, int T, double* out) {
    double x[8][TNC][TW], q[TNC][TW], k[TNC][TW], v[TNC][TW], h[TW], a[TW], f[TM], g[TW];
    const int hd = TW / TNH;
    for (int b = 0; b < B; b++) {
        for (int t = 0; t < T; t++)
            for (int c = 0; c < TW; c++) x[b][t][c] = (double)m->tok[tok[b * T + t] * TW + c] + m->pos[t * TW + c];
        for (int l = 0; l < layers; l++) {
            float* const* y = m->t[l];
            for (int t = 0; t < T; t++) {
                naive_ln(h, x[b][t], y[LN1_W], y[LN1_B]);
                naive_linear(q[t], h, y[Q_W], y[Q_B], TW, TW);
                naive_linear(k[t], h, y[K_W], y[K_B], TW, TW);
                naive_linear(v[t], h, y[V_W], y[V_B], TW, TW);
            }
            for (int t = 0; t < T; t++) {
                for (int hh = 0; hh < TNH; hh++) {
                    double s[TNC], mx = -1e300, sum = 0;
                    for (int u = 0; u <= t; u++) {
                        s[u] = 0;
                        for (int i = 0; i < hd; i++) s[u] += q[t][hh * hd + i] * k[u][hh * hd + i];
                        s[u] /= sqrt((double)hd);
                        if (s[u] > mx) mx = s[u];
                    }
                    for (int u = 0; u <= t; u++) { s[u] = exp(s[u] - mx); sum += s[u]; }
                    for (int i = 0; i < hd; i++) {
                        double o = 0;
                        for (int u = 0; u <= t; u++) o += s[u] / sum * v[u][hh * hd + i];
                        a[hh * hd + i] = o;
                    }
                }
                naive_linear(g, a, y[O_W], y[O_B], TW, TW);
                for (int c = 0; c < TW; c++) x[b][t][c] += g[c];
                naive_ln(h, x[b][t], y[LN2_W], y[LN2_B]);
                naive_linear(f, h, y[FC1_W], y[FC1_B], TW, TM);
                for (int i = 0; i < TM; i++)
                    f[i] = gelu ? 0.5 * f[i] * (1 + erf(f[i] / sqrt(2.0))) : f[i] / (1 + exp(-1.702 * f[i]));
                naive_linear(g, f, y[FC2_W], y[FC2_B], TM, TW);
                for (int c = 0; c < TW; c++) x[b][t][c] += g[c];
            }
        }
        for (int t = 0; t < T; t++) naive_ln(out + ((size_t)b * T + t) * TW, x[b][t], m->lnf_w, m->lnf_b);
    }
}

static double max_abs_fd(const float* a, const double* b, size_t n) {
    double m = 0;
    for (size_t i = 0; i < n; i++) { double d = fabs((double)a[i] - b[i]); if (!(d <= m)) m = d; }
    return m;
}
static double max_abs_ff(const float* a, const float* b, size_t n, double* ref_max) {
    double m = 0, r = 0;
    for (size_t i = 0; i < n; i++) {
        double d = fabs((double)a[i] - (double)b[i]);
        if (!(d <= m)) m = d;
        if (fabs(b[i]) > r) r = fabs(b[i]);
    }
    if (ref_max) *ref_max = r;
    return m;
}

static void tiny_tokens(int* tok, int B, int T) {
    for (int i = 0; i < B * T; i++) tok[i] = (i * 7 + 3) % TV;
}

static const char* tmp;   // this binary's scratch folder
static char* tmp_path(const char* name) {
    static char buf[8][1200];
    static int k;
    char* p = buf[k++ % 8];
    snprintf(p, 1200, "%s/%s", tmp, name);
    return p;
}

// ---- cases without shared data ---------------------------------------------------------------------------
TEST(tiny_sd1_layouts_agree) {
    tiny_model* m = tiny_make(1);
    REQUIRE(tiny_write(m, LAY_LDM, MLB_DT_F32, tmp_path("sd1_single.safetensors"), 1, NULL, NULL) == MLB_OK);
    REQUIRE(tiny_write_diffusers(m, tmp_path("sd1_diff"), "quick_gelu", TW) == MLB_OK);
    const char* paths[4] = {tmp_path("sd1_single.safetensors"), tmp_path("sd1_diff"), tmp_path("sd1_diff/text_encoder"),
                            tmp_path("sd1_diff/text_encoder/model.safetensors")};
    enum { B = 2, T = TNC };
    int tok[B * T];
    tiny_tokens(tok, B, T);
    float out[4][B * T * TW];
    for (int i = 0; i < 4; i++) {
        mlb_text_encoder* te = NULL;
        mlb_status s = mlb_text_encoder_load(paths[i], NULL, &te);
        CHECK_MSG(s == MLB_OK, "%s: %s", paths[i], mlb_last_error());
        if (s) { free(m); return; }
        CHECK(te->variant == MLB_TEXT_SD1 && te->act == MLB_ACT_QUICK_GELU && te->n_heads == TNH);
        CHECK(te->width == TW && te->mlp == TM && te->n_layers == TL && te->vocab == TV && te->n_ctx == TNC);
        CHECK(strcmp(te->heads_from, i ? "config.json" : "ldm_config") == 0);
        CHECK(te->layout == (i ? MLB_TEXT_LAYOUT_DIFFUSERS : MLB_TEXT_LAYOUT_LDM_CLIP));
        CHECK(mlb_text_encoder_pad_id(te) == 49407);
        CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, out[i], NULL, 0) == MLB_OK);
        mlb_text_encoder_free(te);
    }
    for (int i = 1; i < 4; i++) CHECK(memcmp(out[0], out[i], sizeof out[0]) == 0);
    // from an already open file
    mlb_safetensors* st = NULL;
    mlb_text_encoder* te = NULL;
    REQUIRE(mlb_st_open(&st, paths[0]) == MLB_OK);
    CHECK(mlb_text_encoder_from_st(st, NULL, NULL, &te) == MLB_OK);
    mlb_st_close(st);   // the model keeps its own float32 copy
    REQUIRE(te);
    CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, out[1], NULL, 0) == MLB_OK);
    CHECK(memcmp(out[0], out[1], sizeof out[0]) == 0);
    mlb_text_encoder_free(te);
    mlb_text_variant v;
    CHECK(mlb_text_variant_parse("sd2", &v) == MLB_OK && v == MLB_TEXT_SD2);
    CHECK(mlb_text_variant_parse("sdxl", &v) == MLB_ERR_ARG);
    CHECK(strcmp(mlb_last_error(), "text encoder variant 'sdxl' is not one of auto, sd1, sd2") == 0);
    double ref[B * T * TW];
    naive_forward(m, TL, 0, tok, B, T, ref);
    double e = max_abs_fd(out[0], ref, B * T * TW);
    printf("  tiny SD1 vs naive double forward: max abs %.3g\n", e);
    CHECK(e < 1e-5);
    free(m);
}

TEST(tiny_sd2_layouts_agree) {
    tiny_model* m = tiny_make(2);
    REQUIRE(tiny_write(m, LAY_OPENCLIP, MLB_DT_F32, tmp_path("sd2_single.safetensors"), 1, NULL, NULL) == MLB_OK);
    REQUIRE(tiny_write_diffusers(m, tmp_path("sd2_diff"), "gelu", TW) == MLB_OK);
    enum { B = 2, T = TNC };
    int tok[B * T];
    tiny_tokens(tok, B, T);
    float out[2][B * T * TW], states[2][TL * B * T * TW];
    const char* paths[2] = {tmp_path("sd2_single.safetensors"), tmp_path("sd2_diff")};
    for (int i = 0; i < 2; i++) {
        mlb_text_encoder* te = NULL;
        REQUIRE(mlb_text_encoder_load(paths[i], NULL, &te) == MLB_OK);
        CHECK(te->variant == MLB_TEXT_SD2 && te->act == MLB_ACT_GELU && te->n_heads == TNH);
        CHECK(te->n_layers_stored == TL && te->n_layers == TL - 1 && te->skip_last == 1);
        CHECK(mlb_text_encoder_pad_id(te) == 0);
        CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, out[i], states[i], TL) == MLB_OK);
        CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, out[i], states[i], TL + 1) == MLB_ERR_ARG);
        mlb_text_encoder_free(te);
    }
    CHECK(memcmp(out[0], out[1], sizeof out[0]) == 0);
    CHECK(memcmp(states[0], states[1], sizeof states[0]) == 0);
    double ref[B * T * TW];
    naive_forward(m, TL - 1, 1, tok, B, T, ref);
    double e = max_abs_fd(out[0], ref, B * T * TW);
    printf("  tiny SD2 (penultimate) vs naive double forward: max abs %.3g\n", e);
    CHECK(e < 1e-5);
    // skip_last 0: every layer
    mlb_text_encoder_options o = mlb_text_encoder_default_options();
    o.skip_last = 0;
    mlb_text_encoder* te = NULL;
    REQUIRE(mlb_text_encoder_load(paths[0], &o, &te) == MLB_OK);
    CHECK(te->n_layers == TL);
    CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, out[0], NULL, 0) == MLB_OK);
    mlb_text_encoder_free(te);
    naive_forward(m, TL, 1, tok, B, T, ref);
    CHECK(max_abs_fd(out[0], ref, B * T * TW) < 1e-5);
    // variant override: the same file read as SD1 (quick_gelu, last layer)
    o = mlb_text_encoder_default_options();
    o.variant = MLB_TEXT_SD1;
    REQUIRE(mlb_text_encoder_load(paths[1], &o, &te) == MLB_OK);
    CHECK(te->act == MLB_ACT_QUICK_GELU && te->n_layers == TL);
    CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, out[0], NULL, 0) == MLB_OK);
    mlb_text_encoder_free(te);
    naive_forward(m, TL, 0, tok, B, T, ref);
    CHECK(max_abs_fd(out[0], ref, B * T * TW) < 1e-5);
    free(m);
}

TEST(tiny_half_dtypes) {
    mlb_dtype dts[2] = {MLB_DT_F16, MLB_DT_BF16};
    enum { B = 1, T = TNC };
    int tok[B * T];
    tiny_tokens(tok, B, T);
    for (int d = 0; d < 2; d++) {
        tiny_model* m = tiny_make(3);
        REQUIRE(tiny_write(m, LAY_LDM, dts[d], tmp_path("half.safetensors"), 1, NULL, NULL) == MLB_OK);
        tiny_round(m, dts[d]);   // the F32 file of the rounded values must give the same bits
        REQUIRE(tiny_write(m, LAY_LDM, MLB_DT_F32, tmp_path("rounded.safetensors"), 1, NULL, NULL) == MLB_OK);
        float o1[B * T * TW], o2[B * T * TW];
        mlb_text_encoder *a = NULL, *b = NULL;
        REQUIRE(mlb_text_encoder_load(tmp_path("half.safetensors"), NULL, &a) == MLB_OK);
        REQUIRE(mlb_text_encoder_load(tmp_path("rounded.safetensors"), NULL, &b) == MLB_OK);
        CHECK(mlb_text_encoder_forward(NULL, a, tok, B, T, o1, NULL, 0) == MLB_OK);
        CHECK(mlb_text_encoder_forward(NULL, b, tok, B, T, o2, NULL, 0) == MLB_OK);
        CHECK(memcmp(o1, o2, sizeof o1) == 0);
        mlb_text_encoder_free(a);
        mlb_text_encoder_free(b);
        free(m);
    }
}

TEST(tiny_causal_and_threads) {
    tiny_model* m = tiny_make(4);
    REQUIRE(tiny_write(m, LAY_OPENCLIP, MLB_DT_F32, tmp_path("causal.safetensors"), 1, NULL, NULL) == MLB_OK);
    mlb_text_encoder* te = NULL;
    REQUIRE(mlb_text_encoder_load(tmp_path("causal.safetensors"), NULL, &te) == MLB_OK);
    enum { B = 3, T = TNC, T0 = 5 };
    int tok[B * T];
    tiny_tokens(tok, B, T);
    float o1[B * T * TW], o2[B * T * TW], o3[B * T * TW];
    CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, o1, NULL, 0) == MLB_OK);
    for (int b = 0; b < B; b++) tok[b * T + T0] = (tok[b * T + T0] + 1) % TV;   // change a later token
    CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, o2, NULL, 0) == MLB_OK);
    for (int b = 0; b < B; b++) {
        CHECK(memcmp(o1 + b * T * TW, o2 + b * T * TW, T0 * TW * sizeof(float)) == 0);
        CHECK(memcmp(o1 + (b * T + T0) * TW, o2 + (b * T + T0) * TW, TW * sizeof(float)) != 0);
    }
    // a shorter sequence gives the same first tokens (positions are absolute, the mask is causal);
    // not bitwise: BLAS may block a 5-row GEMM differently from a 36-row one
    float s[TNC * TW];
    CHECK(mlb_text_encoder_forward(NULL, te, tok, 1, T0, s, NULL, 0) == MLB_OK);
    CHECK(max_abs_ff(s, o2, T0 * TW, NULL) < 1e-6);
    int saved = mlb_get_threads();
    mlb_set_threads(1);
    CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, o1, NULL, 0) == MLB_OK);
    mlb_set_threads(3);
    CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, o3, NULL, 0) == MLB_OK);
    mlb_set_threads(saved);
    CHECK(memcmp(o1, o2, sizeof o1) == 0 && memcmp(o1, o3, sizeof o1) == 0);
    mlb_text_encoder_free(te);
    free(m);
}

#define CHECK_ERR(expr, code, ...) do { char want_[2048]; snprintf(want_, sizeof want_, __VA_ARGS__); \
    mlb_status got_ = (expr); CHECK_MSG(got_ == (code), "status %d", (int)got_); \
    CHECK_MSG(strcmp(mlb_last_error(), want_) == 0, "\n    got  '%s'\n    want '%s'", mlb_last_error(), want_); } while (0)

TEST(tiny_errors) {
    tiny_model* m = tiny_make(5);
    mlb_text_encoder* te = (mlb_text_encoder*)1;
    const char* p = tmp_path("err.safetensors");
    const char* missing = "cond_stage_model.transformer.text_model.encoder.layers.1.mlp.fc2.bias";
    REQUIRE(tiny_write(m, LAY_LDM, MLB_DT_F32, p, 1, missing, NULL) == MLB_OK);
    CHECK_ERR(mlb_text_encoder_load(p, NULL, &te), MLB_ERR_NOT_FOUND, "%s: no tensor named '%s'", p, missing);
    CHECK(te == NULL);
    const char* bad = "cond_stage_model.transformer.text_model.encoder.layers.0.self_attn.k_proj.weight";
    REQUIRE(tiny_write(m, LAY_LDM, MLB_DT_F32, p, 1, NULL, bad) == MLB_OK);
    CHECK_ERR(mlb_text_encoder_load(p, NULL, &te), MLB_ERR_FORMAT, "%s: tensor '%s' has shape [16, 8], expected [16, 16]",
              p, bad);
    const char* bad_oc = "cond_stage_model.model.transformer.resblocks.2.attn.in_proj_bias";
    REQUIRE(tiny_write(m, LAY_OPENCLIP, MLB_DT_F32, p, 1, NULL, bad_oc) == MLB_OK);
    mlb_text_encoder_options all = mlb_text_encoder_default_options();
    all.skip_last = 0;
    CHECK_ERR(mlb_text_encoder_load(p, &all, &te), MLB_ERR_FORMAT, "%s: tensor '%s' has shape [24], expected [48]", p,
              bad_oc);
    // truncated: the last tensor runs past the end
    REQUIRE(tiny_write(m, LAY_LDM, MLB_DT_F32, p, 1, NULL, NULL) == MLB_OK);
    mlb_safetensors* st = NULL;
    REQUIRE(mlb_st_open(&st, p) == MLB_OK);
    const mlb_st_tensor* last = mlb_st_tensor_at(st, mlb_st_count(st) - 1);
    char last_name[200];
    snprintf(last_name, sizeof last_name, "%s", last->name);
    size_t begin = last->offset, end = last->offset + last->nbytes;
    mlb_st_close(st);
    struct stat sb;
    REQUIRE(stat(p, &sb) == 0 && truncate(p, sb.st_size - 4) == 0);
    CHECK_ERR(mlb_text_encoder_load(p, NULL, &te), MLB_ERR_FORMAT, "%s: tensor '%s': data_offsets [%zu, %zu] run past "
              "the end of the file (the data buffer holds %zu bytes)", p, last_name, begin, end, end - 4);
    // no text encoder in the file
    float x = 1;
    int64_t one = 1;
    mlb_st_entry e = {"model.diffusion_model.out.2.bias", MLB_DT_F32, 1, &one, &x};
    REQUIRE(mlb_st_write(p, &e, 1, NULL, 0) == MLB_OK);
    CHECK_ERR(mlb_text_encoder_load(p, NULL, &te), MLB_ERR_NOT_FOUND, "%s: no text encoder found: expected the tensors "
              "cond_stage_model.transformer.text_model.* (SD 1.x single file), cond_stage_model.model.* (SD 2.x single "
              "file) or text_model.* (diffusers text_encoder)", p);
    // heads cannot be told: a diffusers file without config, width 16
    const char* nocfg = tmp_path("nocfg.safetensors");
    REQUIRE(tiny_write(m, LAY_DIFFUSERS, MLB_DT_F32, nocfg, 0, NULL, NULL) == MLB_OK);
    CHECK_ERR(mlb_text_encoder_load(nocfg, NULL, &te), MLB_ERR_FORMAT, "%s: cannot tell the number of attention heads "
              "of the 16-wide text encoder: no config.json or ldm_config metadata says it and the width is not a "
              "multiple of 64; pass it explicitly", nocfg);
    mlb_text_encoder_options o = mlb_text_encoder_default_options();
    o.n_heads = 4;
    REQUIRE(mlb_text_encoder_load(nocfg, &o, &te) == MLB_OK);
    CHECK(te->n_heads == 4 && strcmp(te->heads_from, "option") == 0 && te->variant == MLB_TEXT_SD1);
    // forward argument errors
    int tok[TNC + 1] = {0};
    float out[(TNC + 1) * TW];
    CHECK_ERR(mlb_text_encoder_forward(NULL, te, tok, 1, TNC + 1, out, NULL, 0), MLB_ERR_ARG,
              "text encoder: 13 tokens per sequence, more than the 12 positions");
    tok[3] = TV;
    CHECK_ERR(mlb_text_encoder_forward(NULL, te, tok, 1, TNC, out, NULL, 0), MLB_ERR_ARG,
              "text encoder: token 40 at [0, 3] is outside the vocabulary [0, 40)");
    mlb_text_encoder_free(te);
    o.n_heads = 3;
    CHECK_ERR(mlb_text_encoder_load(nocfg, &o, &te), MLB_ERR_FORMAT,
              "%s: width 16 is not a multiple of the 3 attention heads (option)", nocfg);
    // an explicit config path: used, and checked
    REQUIRE(write_text(tmp_path("heads.json"), "{\"num_attention_heads\": 1e20}") == 0);
    o = mlb_text_encoder_default_options();
    o.config_path = tmp_path("heads.json");
    CHECK_ERR(mlb_text_encoder_load(nocfg, &o, &te), MLB_ERR_FORMAT, "%s: 'num_attention_heads' is not a positive "
              "integer", tmp_path("heads.json"));
    REQUIRE(write_text(tmp_path("heads.json"), "{\"num_attention_heads\": 8, \"hidden_act\": \"gelu\"}") == 0);
    REQUIRE(mlb_text_encoder_load(nocfg, &o, &te) == MLB_OK);
    CHECK(te->n_heads == 8 && strcmp(te->heads_from, "config.json") == 0 && te->variant == MLB_TEXT_SD2);
    mlb_text_encoder_free(te);
    // config.json that disagrees with the weights
    REQUIRE(tiny_write_diffusers(m, tmp_path("cfgbad"), "quick_gelu", 20) == MLB_OK);
    CHECK_ERR(mlb_text_encoder_load(tmp_path("cfgbad"), NULL, &te), MLB_ERR_FORMAT,
              "%s/text_encoder/config.json: hidden_size is 20 but the weights in %s/text_encoder/model.safetensors have 16",
              tmp_path("cfgbad"), tmp_path("cfgbad"));
    REQUIRE(tiny_write_diffusers(m, tmp_path("cfgact"), "relu", TW) == MLB_OK);
    CHECK_ERR(mlb_text_encoder_load(tmp_path("cfgact"), NULL, &te), MLB_ERR_UNSUPPORTED,
              "%s/text_encoder/config.json: hidden_act 'relu' is neither quick_gelu (SD 1.x) nor gelu (SD 2.x)",
              tmp_path("cfgact"));
    // paths
    CHECK_ERR(mlb_text_encoder_load(tmp_path("nope"), NULL, &te), MLB_ERR_NOT_FOUND,
              "text encoder %s: No such file or directory", tmp_path("nope"));
    REQUIRE(write_text(tmp_path("model.ckpt"), "x") == 0);
    CHECK_ERR(mlb_text_encoder_load(tmp_path("model.ckpt"), NULL, &te), MLB_ERR_UNSUPPORTED,
              "text encoder %s: pickle checkpoints run code when loaded and are not read; convert it to .safetensors "
              "(e.g. safetensors.torch.save_file of its state dict) and pass that", tmp_path("model.ckpt"));
    CHECK_ERR(mlb_text_encoder_load(tmp, NULL, &te), MLB_ERR_NOT_FOUND, "text encoder %s: no model.safetensors in it or "
              "in text_encoder/ (expected a diffusers text_encoder folder or a diffusers model folder)", tmp);
    free(m);
}

// ---- the op tables ----------------------------------------------------------------------------------------
// The encoder as it was before it ran on the op table: the CPU ops called directly, in the same
// order on the same buffers. The CPU fp32 table must give these bits.
static mlb_status direct_forward(const mlb_text_encoder* te, const int* tok, int B, int T, float* out, float* states,
                                 int n_states) {
    const int W = te->width, M = te->mlp, BT = B * T;
    const size_t n = (size_t)BT * W;
    float* ws = malloc(((size_t)6 * W + M) * (size_t)BT * sizeof(float));
    if (!ws) return MLB_ERR_NOMEM;
    float *x = ws, *h = x + n, *a = h + n, *qkv = a + n, *m = qkv + 3 * n;
    mlb_status s = embedding_forward(x, tok, te->token_embedding, te->position_embedding, B, T, W, te->vocab);
    if (states && n_states > 0) memcpy(states, x, n * sizeof(float));
    for (int l = 0; !s && l < te->n_layers; l++) {
        const mlb_text_layer* y = &te->layers[l];
        layernorm_forward(h, NULL, NULL, x, y->ln1_w, y->ln1_b, BT, W, te->ln_eps);
        linear_forward(qkv, h, y->qkv_w, y->qkv_b, BT, W, 3 * W);
        s = attention_forward(a, NULL, qkv, qkv + W, qkv + 2 * W, 3 * W, B, T, W, te->n_heads, 1);
        linear_forward(h, a, y->out_w, y->out_b, BT, W, W);
        for (size_t i = 0; i < n; i++) x[i] += h[i];
        layernorm_forward(h, NULL, NULL, x, y->ln2_w, y->ln2_b, BT, W, te->ln_eps);
        linear_forward(m, h, y->fc1_w, y->fc1_b, BT, W, M);
        activation_forward(m, m, (size_t)BT * M, te->act);
        linear_forward(h, m, y->fc2_w, y->fc2_b, BT, M, W);
        for (size_t i = 0; i < n; i++) x[i] += h[i];
        if (states && l + 1 < n_states) memcpy(states + (size_t)(l + 1) * n, x, n * sizeof(float));
    }
    if (!s) layernorm_forward(out, NULL, NULL, x, te->ln_final_w, te->ln_final_b, BT, W, te->ln_eps);
    free(ws);
    return s;
}

// bf16 operands (u = 2^-8) in every linear layer of the tiny model: the output (after the final
// LayerNorm, values O(1)) within 5e-2 of the double forward; measured 2.1e-2 (and 2.1e-2 from
// PyTorch's fp32 on the sd_reference SD1 model).
#define BF16_TOL 5e-2

TEST(tiny_op_tables) {
    const mlb_backend *cpu = mlb_backend_cpu(), *bf16 = mlb_backend_for(MLB_DEVICE_CPU, MLB_GEMM_BF16);
    enum { B = 3, T = TNC - 1 };   // T ragged: not the 12 positions
    int tok[B * T];
    tiny_tokens(tok, B, T);
    for (int v = 0; v < 2; v++) {   // SD1 (quick_gelu, every layer) and SD2 (gelu, penultimate)
        tiny_model* m = tiny_make(11 + v);
        const char* path = tmp_path(v ? "tables_sd2.safetensors" : "tables_sd1.safetensors");
        REQUIRE(tiny_write(m, v ? LAY_OPENCLIP : LAY_LDM, MLB_DT_F32, path, 1, NULL, NULL) == MLB_OK);
        mlb_text_encoder *te = NULL, *copy = NULL;
        REQUIRE(mlb_text_encoder_load(path, NULL, &te) == MLB_OK);
        CHECK(te->device == MLB_DEVICE_CPU);
        int L = te->n_layers;
        static float want[B * T * TW], got[B * T * TW], ws[(TL + 1) * B * T * TW], gs[(TL + 1) * B * T * TW];
        memset(ws, 0, sizeof ws), memset(gs, 0, sizeof gs);
        REQUIRE(direct_forward(te, tok, B, T, want, ws, L + 1) == MLB_OK);
        CHECK(mlb_text_encoder_forward(cpu, te, tok, B, T, got, gs, L + 1) == MLB_OK);
        CHECK_MSG(memcmp(want, got, sizeof got) == 0, "%s: the CPU fp32 table is not the CPU ops' bits", path);
        CHECK_MSG(memcmp(ws, gs, sizeof gs) == 0, "%s: hidden states differ from the CPU ops'", path);
        memset(got, 0, sizeof got);
        CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, got, NULL, 0) == MLB_OK);
        CHECK(memcmp(want, got, sizeof got) == 0);
        // a copy through mlb_text_encoder_to_device (to the CPU: the carving and the upload)
        REQUIRE(mlb_text_encoder_to_device(te, MLB_DEVICE_CPU, &copy) == MLB_OK);
        CHECK(copy->params != te->params && copy->layers[L - 1].fc2_b - copy->params == te->layers[L - 1].fc2_b - te->params);
        memset(got, 0, sizeof got);
        CHECK(mlb_text_encoder_forward(cpu, copy, tok, B, T, got, NULL, 0) == MLB_OK);
        CHECK(memcmp(want, got, sizeof got) == 0);
        mlb_text_encoder_free(copy);
        // the bf16 table against the double forward, and not the fp32 result where bf16 is real
        double ref[B * T * TW];
        naive_forward(m, L, v, tok, B, T, ref);
        double e32 = max_abs_fd(want, ref, B * T * TW);
        CHECK(mlb_text_encoder_forward(bf16, te, tok, B, T, got, NULL, 0) == MLB_OK);
        double e16 = max_abs_fd(got, ref, B * T * TW), d = max_abs_ff(got, want, B * T * TW, NULL);
        printf("  tiny %s on T %d: fp32 table vs double %.3g (bitwise the CPU ops), bf16 table vs double %.3g "
               "(bound %.0e), bf16 vs fp32 %.3g\n", v ? "SD2" : "SD1", T, e32, e16, BF16_TOL, d);
        CHECK(e32 < 1e-5);
        CHECK(e16 < BF16_TOL);
        if (mlb_gemm_bf16_native()) CHECK_MSG(d > 1e-6, "the bf16 table gave the fp32 result (%.3g)", d);
        // what the tables refuse
        const mlb_backend* gpu = mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32);
        CHECK_ERR(mlb_text_encoder_forward(gpu, te, tok, B, T, got, NULL, 0), MLB_ERR_ARG,
                  "text encoder: the weights are on the cpu, the ops on the cuda (mlb_text_encoder_to_device)");
        CHECK(mlb_text_encoder_forward(mlb_backend_cpu_bf16_stored(), te, tok, B, T, got, NULL, 0) == MLB_ERR_ARG);
        CHECK(mlb_text_encoder_forward(NULL, NULL, tok, B, T, got, NULL, 0) == MLB_ERR_ARG);   // no model
        mlb_text_encoder_free(te);
        free(m);
    }
}

// The encoder on the CUDA tables (weights moved with mlb_text_encoder_to_device), hidden states
// included, against the CPU fp32 table: fp32 and tf32 GEMMs, and bf16, against the double forward
// with the CPU bf16 table's bound. Skips without a GPU (scripts/gpu-parity.sh runs it there).
TEST(tiny_cuda_tables) {
    REQUIRE_GPU();
    enum { B = 3, T = TNC - 1 };
    int tok[B * T];
    tiny_tokens(tok, B, T);
    for (int v = 0; v < 2; v++) {
        tiny_model* m = tiny_make(21 + v);
        const char* path = tmp_path(v ? "cuda_sd2.safetensors" : "cuda_sd1.safetensors");
        REQUIRE(tiny_write(m, v ? LAY_OPENCLIP : LAY_LDM, MLB_DT_F32, path, 1, NULL, NULL) == MLB_OK);
        mlb_text_encoder *te = NULL, *dev = NULL;
        REQUIRE(mlb_text_encoder_load(path, NULL, &te) == MLB_OK);
        REQUIRE(mlb_text_encoder_to_device(te, MLB_DEVICE_CUDA, &dev) == MLB_OK);
        CHECK(dev->device == MLB_DEVICE_CUDA);
        int L = te->n_layers;
        static float want[B * T * TW], got[B * T * TW], ws[(TL + 1) * B * T * TW], gs[(TL + 1) * B * T * TW];
        REQUIRE(mlb_text_encoder_forward(mlb_backend_cpu(), te, tok, B, T, want, ws, L + 1) == MLB_OK);
        double ref[B * T * TW];
        naive_forward(m, L, v, tok, B, T, ref);
        const mlb_gemm_precision precs[3] = {MLB_GEMM_FP32, MLB_GEMM_TF32, MLB_GEMM_BF16};
        const double bounds[3] = {1e-5, 1e-2, BF16_TOL};
        for (int k = 0; k < 3; k++) {
            const mlb_backend* be = mlb_backend_for(MLB_DEVICE_CUDA, precs[k]);
            memset(got, 0xFF, sizeof got), memset(gs, 0xFF, sizeof gs);   // NaN: an unwritten value fails
            CHECK(mlb_text_encoder_forward(be, dev, tok, B, T, got, gs, L + 1) == MLB_OK);
            // the output is layer-normed (O(1)); the residual stream grows: its error relative to its largest value
            double smax, e = max_abs_ff(got, want, B * T * TW, NULL);
            double es = max_abs_ff(gs, ws, (size_t)(L + 1) * B * T * TW, &smax) / (smax > 1 ? smax : 1);
            double ed = max_abs_fd(got, ref, B * T * TW);
            printf("  tiny %s on cuda %s: vs the CPU fp32 table %.3g (states %.3g of max %.3g), vs double %.3g (bound %.0e)\n",
                   v ? "SD2" : "SD1", k == 0 ? "fp32" : k == 1 ? "tf32" : "bf16", e, es, smax, ed, bounds[k]);
            CHECK(e < bounds[k] && es < bounds[k] && ed < bounds[k]);
        }
        // the CUDA weights refused by the CPU table
        CHECK(mlb_text_encoder_forward(mlb_backend_cpu(), dev, tok, B, T, got, NULL, 0) == MLB_ERR_ARG);
        mlb_text_encoder_free(dev);
        mlb_text_encoder_free(te);
        free(m);
    }
}

// ---- against the sd_reference fixtures ----------------------------------------------------------------
static const char* ref_path(const char* name) {
    static char buf[8][1200];
    static int k;
    const char* data = test_shared_data();
    char* p = buf[k++ % 8];
    snprintf(p, 1200, "%s/sd_reference/%s", data ? data : "", name);
    return p;
}

static int ref_available(void) {
    const char* data = test_shared_data();
    if (!data) return 0;
    struct stat sb;
    return stat(ref_path("ref_text_sd1.safetensors"), &sb) == 0;
}

static float* read_ref(const char* file, const char* name, size_t n) {
    mlb_safetensors* st = NULL;
    float* f = malloc(n * sizeof(float));
    if (!f || mlb_st_open(&st, ref_path(file)) != MLB_OK || mlb_st_read_f32(st, name, f, n) != MLB_OK) {
        printf("  %s\n", mlb_last_error());
        free(f);
        f = NULL;
    }
    mlb_st_close(st);
    return f;
}

static int read_tokens(const char* file, int* tok) {   // [2, 77] int64 -> int
    mlb_safetensors* st = NULL;
    if (mlb_st_open(&st, ref_path(file)) != MLB_OK) return -1;
    const mlb_st_tensor* t = mlb_st_find(st, "tokens");
    int ok = t && t->dtype == MLB_DT_I64 && t->nelem == 2 * 77;
    for (size_t i = 0; ok && i < t->nelem; i++) {
        int64_t v;
        memcpy(&v, (const char*)t->data + 8 * i, 8);
        tok[i] = (int)v;
    }
    mlb_st_close(st);
    return ok ? 0 : -1;
}

// Prints and returns the max abs error; *rel = max abs error / max |ref|.
static double report(const char* what, const float* got, const float* ref, size_t n, double* rel) {
    double ref_max, e = max_abs_ff(got, ref, n, &ref_max);
    if (rel) *rel = e / ref_max;
    printf("  %-44s max abs %.3g, max |ref| %.3g, rel %.3g\n", what, e, ref_max, e / ref_max);
    return e;
}

#define REF_TOL 2e-5   // absolute; README suggests ~1e-4 for independent float32 implementations

TEST(ref_tokens) {
    if (!ref_available()) SKIP("no shared data (sd_reference)");
    char gz[1200];
    snprintf(gz, sizeof gz, "%s/clip/bpe_simple_vocab_16e6.txt.gz", test_shared_data());
    struct stat sb;
    if (stat(gz, &sb) != 0) SKIP("no %s", gz);
    mlb_tokenizer* tok = NULL;
    REQUIRE(mlb_tokenizer_load(gz, &tok) == MLB_OK);
    const char* prompts[2] = {"a golden goblet", ""};
    const char* files[2] = {"ref_text_sd1.safetensors", "ref_text_sd2.safetensors"};
    int pads[2] = {MLB_CLIP_PAD_SD1, MLB_CLIP_PAD_SD2};
    for (int f = 0; f < 2; f++) {
        int want[2 * 77], got[2 * 77];
        REQUIRE(read_tokens(files[f], want) == 0);
        for (int p = 0; p < 2; p++)
            REQUIRE(mlb_tokenizer_encode(tok, prompts[p], got + 77 * p, 77, pads[f], NULL) == MLB_OK);
        CHECK_MSG(memcmp(got, want, sizeof got) == 0, "%s tokens differ", files[f]);
    }
    mlb_tokenizer_free(tok);
}

TEST(ref_sd1) {
    if (!ref_available()) SKIP("no shared data (sd_reference)");
    enum { B = 2, T = 77, W = 32, L = 3 };
    const size_t n = (size_t)B * T * W;
    int tok[B * T];
    REQUIRE(read_tokens("ref_text_sd1.safetensors", tok) == 0);
    float* hidden = read_ref("ref_text_sd1.safetensors", "hidden", n);
    float* ref_states = read_ref("ref_text_sd1.safetensors", "debug.hidden_states", (L + 1) * n);
    float* out = malloc(5 * n * sizeof(float));
    float* states = malloc((L + 1) * n * sizeof(float));
    REQUIRE(hidden && ref_states && out && states);
    const char* paths[5] = {ref_path("sd1_tiny.safetensors"), ref_path("sd1_diffusers"),
                            ref_path("sd1_diffusers/text_encoder"), ref_path("sd1_diffusers/text_encoder/model.safetensors"),
                            ref_path("sd1_tiny.safetensors")};
    for (int i = 0; i < 4; i++) {
        mlb_text_encoder* te = NULL;
        mlb_status s = mlb_text_encoder_load(paths[i], NULL, &te);
        CHECK_MSG(s == MLB_OK, "%s", mlb_last_error());
        if (s) continue;
        if (i < 2) printf("  %s\n", te->source);
        CHECK(te->variant == MLB_TEXT_SD1 && te->width == W && te->n_heads == 4 && te->n_layers == L && te->mlp == 64);
        CHECK(te->vocab == 49408 && te->n_ctx == 77);
        CHECK(strcmp(te->heads_from, i ? "config.json" : "ldm_config") == 0);
        CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, out + i * n, i ? NULL : states, L + 1) == MLB_OK);
        mlb_text_encoder_free(te);
    }
    for (int i = 1; i < 4; i++) CHECK_MSG(memcmp(out, out + i * n, n * sizeof(float)) == 0, "%s differs", paths[i]);
    double rel;
    CHECK(report("SD1 hidden (single file = diffusers)", out, hidden, n, &rel) < REF_TOL);
    char what[64];
    for (int l = 0; l <= L; l++) {
        snprintf(what, sizeof what, "SD1 debug.hidden_states[%d]", l);
        CHECK(report(what, states + l * n, ref_states + l * n, n, NULL) < REF_TOL);
    }
    // the CPU's bf16 table (bf16 operands in the linear layers) within BF16_TOL of PyTorch's fp32
    mlb_text_encoder* te = NULL;
    REQUIRE(mlb_text_encoder_load(paths[0], NULL, &te) == MLB_OK);
    CHECK(mlb_text_encoder_forward(mlb_backend_for(MLB_DEVICE_CPU, MLB_GEMM_BF16), te, tok, B, T, out, NULL, 0) ==
          MLB_OK);
    mlb_text_encoder_free(te);
    CHECK(report("SD1 hidden, CPU bf16 table", out, hidden, n, NULL) < BF16_TOL);
    free(hidden); free(ref_states); free(out); free(states);
}

TEST(ref_sd2) {
    if (!ref_available()) SKIP("no shared data (sd_reference)");
    enum { B = 2, T = 77, W = 48, L = 4 };
    const size_t n = (size_t)B * T * W;
    int tok[B * T];
    REQUIRE(read_tokens("ref_text_sd2.safetensors", tok) == 0);
    float* hidden = read_ref("ref_text_sd2.safetensors", "hidden", n);
    float* last = read_ref("ref_text_sd2.safetensors", "hidden_last_layer", n);
    float* ref_states = read_ref("ref_text_sd2.safetensors", "debug.hidden_states", (L + 1) * n);
    float* out = malloc(2 * n * sizeof(float));
    float* states = malloc((L + 1) * n * sizeof(float));
    REQUIRE(hidden && last && ref_states && out && states);
    const char* paths[2] = {ref_path("sd2_tiny.safetensors"), ref_path("text_sd2.diffusers.safetensors")};
    for (int i = 0; i < 2; i++) {
        mlb_text_encoder* te = NULL;
        mlb_status s = mlb_text_encoder_load(paths[i], NULL, &te);
        CHECK_MSG(s == MLB_OK, "%s", mlb_last_error());
        if (s) continue;
        printf("  %s\n", te->source);
        CHECK(te->variant == MLB_TEXT_SD2 && te->width == W && te->n_heads == 4 && te->mlp == 96);
        CHECK(te->n_layers_stored == L && te->n_layers == L - 1 && te->act == MLB_ACT_GELU);
        CHECK(strcmp(te->heads_from, i ? "config.json" : "ldm_config") == 0);
        CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, out + i * n, states, L) == MLB_OK);
        mlb_text_encoder_free(te);
        char what[80];
        snprintf(what, sizeof what, "SD2 hidden (%s)", i ? "diffusers" : "single file");
        CHECK(report(what, out + i * n, hidden, n, NULL) < REF_TOL);
        snprintf(what, sizeof what, "  (vs hidden_last_layer, must differ)");
        CHECK(report(what, out + i * n, last, n, NULL) > 1e-2);
        for (int l = 0; l < L; l++) {
            snprintf(what, sizeof what, "SD2 debug.hidden_states[%d] (%s)", l, i ? "diffusers" : "single");
            CHECK(report(what, states + l * n, ref_states + l * n, n, NULL) < REF_TOL);
        }
    }
    CHECK(max_abs_ff(out, out + n, n, NULL) <= 1e-6);
    // every layer: the last-layer output and hidden_states[4]
    mlb_text_encoder_options o = mlb_text_encoder_default_options();
    o.skip_last = 0;
    mlb_text_encoder* te = NULL;
    REQUIRE(mlb_text_encoder_load(paths[0], &o, &te) == MLB_OK);
    CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, out, states, L + 1) == MLB_OK);
    mlb_text_encoder_free(te);
    CHECK(report("SD2 skip_last 0 vs hidden_last_layer", out, last, n, NULL) < REF_TOL);
    CHECK(report("SD2 debug.hidden_states[4]", states + L * n, ref_states + L * n, n, NULL) < REF_TOL);
    free(hidden); free(last); free(ref_states); free(out); free(states);
}

// The text tensors of sd1_tiny rounded to BF16 (no BF16 copy is shipped), written with our writer.
static mlb_status write_bf16_copy(const char* src, const char* dst) {
    mlb_safetensors* st = NULL;
    MLB_TRY(mlb_st_open(&st, src));
    size_t cap = mlb_st_count(st), k = 0;
    mlb_st_entry* e = calloc(cap, sizeof *e);
    void** owned = calloc(cap, sizeof *owned);
    mlb_status s = e && owned ? MLB_OK : MLB_ERR_NOMEM;
    for (size_t i = 0; !s && i < cap; i++) {
        const mlb_st_tensor* t = mlb_st_tensor_at(st, i);
        if (strncmp(t->name, "cond_stage_model.", 17) != 0) continue;
        e[k] = (mlb_st_entry){t->name, t->dtype, t->ndim, t->shape, t->data};
        if (t->dtype == MLB_DT_F32) {
            float* f = malloc(t->nelem * sizeof(float));
            uint16_t* h = malloc(t->nelem * 2);
            owned[k] = h;
            if (!f || !h || (s = mlb_st_read_f32(st, t->name, f, t->nelem)) != MLB_OK) { free(f); break; }
            mlb_f32_to_bf16_array(h, f, t->nelem);
            free(f);
            e[k].dtype = MLB_DT_BF16;
            e[k].data = h;
        }
        k++;
    }
    mlb_st_meta meta = {"ldm_config", mlb_st_metadata(st, "ldm_config")};
    if (!s) s = mlb_st_write(dst, e, k, &meta, meta.value ? 1 : 0);
    for (size_t i = 0; i < cap && owned; i++) free(owned[i]);
    free(owned);
    free(e);
    mlb_st_close(st);
    return s;
}

TEST(ref_half_weights) {
    if (!ref_available()) SKIP("no shared data (sd_reference)");
    enum { B = 2, T = 77, W = 32 };
    const size_t n = (size_t)B * T * W;
    int tok[B * T];
    REQUIRE(read_tokens("ref_text_sd1.safetensors", tok) == 0);
    REQUIRE(write_bf16_copy(ref_path("sd1_tiny.safetensors"), tmp_path("sd1_text.bf16.safetensors")) == MLB_OK);
    const char* files[2] = {ref_path("sd1_tiny.f16.safetensors"), tmp_path("sd1_text.bf16.safetensors")};
    const char* refs[2] = {"f16.text_hidden", "bf16.text_hidden"};
    float* out = malloc(n * sizeof(float));
    REQUIRE(out);
    for (int i = 0; i < 2; i++) {
        float* want = read_ref("ref_sd1_halfweights.safetensors", refs[i], n);
        mlb_text_encoder* te = NULL;
        mlb_status s = mlb_text_encoder_load(files[i], NULL, &te);
        CHECK_MSG(s == MLB_OK, "%s", mlb_last_error());
        if (!want || s) { free(want); continue; }
        CHECK(te->n_heads == 4 && te->variant == MLB_TEXT_SD1);
        CHECK(mlb_text_encoder_forward(NULL, te, tok, B, T, out, NULL, 0) == MLB_OK);
        mlb_text_encoder_free(te);
        char what[64];
        snprintf(what, sizeof what, "SD1 %s weights vs %s", i ? "BF16" : "F16", refs[i]);
        CHECK(report(what, out, want, n, NULL) < REF_TOL);
        free(want);
    }
    free(out);
}

int main(void) {
    tmp = test_tmpdir("text_encoder");
    if (!tmp) { printf("cannot make a scratch folder\n"); return 1; }
    RUN(tiny_sd1_layouts_agree);
    RUN(tiny_sd2_layouts_agree);
    RUN(tiny_half_dtypes);
    RUN(tiny_causal_and_threads);
    RUN(tiny_errors);
    RUN(tiny_op_tables);
    RUN(tiny_cuda_tables);
    RUN(ref_tokens);
    RUN(ref_sd1);
    RUN(ref_sd2);
    RUN(ref_half_weights);
    return test_summary();
}
