// A model written in the diffusers folder layout (sd_folder.h) loads back through mlb_sd_model_load,
// the path a user's SD 1.5 takes: the tokenizer makes each word one token, the text encoder and
// UNet hold exactly the written numbers, prompts differing in one word encode differently; the
// index's geometry suffix reaches the geometry stage's prompt.
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "matlaber/fileio.h"
#include "matlaber/guidance_sds.h"
#include "matlaber/rng.h"
#include "matlaber/sd_folder.h"
#include "matlaber/sd_model.h"
#include "matlaber/unet_random.h"
#include "test.h"

static const char* WORDS[] = {"a", "gold", "goblet", "silver", "bowl", "bottle", "copper", "vase", "view", "front",
                              "side", "back", "overhead", "mug", "stone", ","};
#define N_WORDS ((int)(sizeof WORDS / sizeof WORDS[0]))

static char dir[256];

static mlb_unet_config tiny_unet(int context) {
    mlb_unet_config c = mlb_unet_tiny_config(0);
    c.context_dim = context;
    return c;
}

TEST(write_and_load) {
    snprintf(dir, sizeof dir, "/tmp/mlb_sd_folder_%d", (int)getpid());
    char p[512];
    snprintf(p, sizeof p, "%s/tokenizer", dir);
    REQUIRE(mlb_sd_write_tokenizer(p, WORDS, N_WORDS) == MLB_OK);
    mlb_tokenizer* tok = NULL;
    REQUIRE(mlb_tokenizer_load(p, &tok) == MLB_OK);   // merges.txt + vocab.json checked together
    int vocab = mlb_tokenizer_vocab_size(tok);
    CHECK(vocab > 512 + 20 && vocab < 700);
    CHECK(mlb_tokenizer_eos(tok) == vocab - 1);
    // every word of two letters or more is one token, and "</w>" ends it
    for (int i = 0; i < N_WORDS; i++) {
        int* ids = NULL;
        size_t n = 0;
        REQUIRE(mlb_tokenizer_tokenize(tok, WORDS[i], &ids, &n) == MLB_OK);
        CHECK_MSG(n == 1, "'%s' is %zu tokens", WORDS[i], n);
        char want[64];
        snprintf(want, sizeof want, "%s</w>", WORDS[i]);
        if (n == 1) CHECK(!strcmp(mlb_tokenizer_token(tok, ids[0]), want));
        free(ids);
    }
    // text outside the vocabulary still tokenises, byte by byte
    int* ids = NULL;
    size_t n = 0;
    REQUIRE(mlb_tokenizer_tokenize(tok, "a zebra", &ids, &n) == MLB_OK);
    CHECK(n == 1 + 5);
    free(ids);
    mlb_tokenizer_free(tok);

    mlb_text_encoder_shape ts = {vocab, 32, 1, 2, 64, 7};
    snprintf(p, sizeof p, "%s/text_encoder", dir);
    REQUIRE(mlb_text_encoder_write_random(p, &ts) == MLB_OK);
    mlb_unet_config uc = tiny_unet(32);
    mlb_unet* u = NULL;
    REQUIRE(mlb_unet_create(&uc, MLB_DEVICE_CPU, &u) == MLB_OK);
    for (size_t i = 0; i < u->n_params; i++) u->params[i] = (float)((int)(i % 97) - 48) / 256.0f;
    snprintf(p, sizeof p, "%s/unet", dir);
    REQUIRE(mlb_unet_save_folder(u, p, MLB_DT_F32) == MLB_OK);
    // F16: half the file, read back as float32; these values (k / 256, |k| <= 48) are exact in F16
    {
        char p16[600];
        snprintf(p16, sizeof p16, "%s/unet16", dir);
        REQUIRE(mlb_unet_save_folder(u, p16, MLB_DT_F16) == MLB_OK);
        mlb_unet* u16 = NULL;
        REQUIRE(mlb_unet_load(p16, NULL, &u16) == MLB_OK);
        CHECK(u16->n_params == u->n_params && !memcmp(u16->params, u->params, u->n_params * sizeof(float)));
        mlb_unet_free(u16);
        CHECK(mlb_unet_save_folder(u, p16, MLB_DT_I32) == MLB_ERR_ARG);
    }
    mlb_vae_config vc = mlb_vae_sd_config();
    vc.n_levels = 2; vc.block_out[0] = 8; vc.block_out[1] = 8; vc.layers_per_block = 1; vc.norm_groups = 4;
    vc.scaling_factor = 0.5f;
    mlb_vae* v = NULL;
    REQUIRE(mlb_vae_create(NULL, &vc, &v) == MLB_OK);
    mlb_vae_init_random(v, 3, 1.0f);
    snprintf(p, sizeof p, "%s/vae", dir);
    REQUIRE(mlb_mkdir_p(p) == MLB_OK);
    char w[600], cj[600];
    snprintf(w, sizeof w, "%s/diffusion_pytorch_model.safetensors", p);
    snprintf(cj, sizeof cj, "%s/config.json", p);
    REQUIRE(mlb_vae_save(v, w, MLB_VAE_LAYOUT_DIFFUSERS, NULL, cj) == MLB_OK);
    REQUIRE(mlb_sd_write_index(dir, NULL) == MLB_OK);

    mlb_sd_model_options o = mlb_sd_model_default_options();
    o.device = MLB_DEVICE_CPU;
    mlb_sd_model* m = NULL;
    mlb_status st = mlb_sd_model_load(dir, &o, &m);
    REQUIRE(st == MLB_OK);
    CHECK(!strcmp(m->geometry_suffix, ""));   // no key: a user's model, no suffix
    CHECK(m->pad_id == vocab - 1);
    CHECK(m->scaling_factor == 0.5f);
    CHECK(m->unet->n_params == u->n_params);
    CHECK(!memcmp(m->unet->params, u->params, u->n_params * sizeof(float)));
    CHECK(m->vae && m->vae->n_params == v->n_params && !memcmp(m->vae->params, v->params, v->n_params * sizeof(float)));
    // prompts that differ in one word differ in the conditioning from that token on, not before
    float* e1 = malloc(77 * 32 * sizeof(float));
    float* e2 = malloc(77 * 32 * sizeof(float));
    REQUIRE(e1 && e2);
    REQUIRE(mlb_sd_model_encode_prompt(m, "a gold goblet", e1) == MLB_OK);
    REQUIRE(mlb_sd_model_encode_prompt(m, "a silver goblet", e2) == MLB_OK);
    CHECK(!memcmp(e1, e2, 2 * 32 * sizeof(float)));   // <bos> a
    double d = 0;
    for (int i = 2 * 32; i < 77 * 32; i++) d += fabs(e1[i] - e2[i]);
    CHECK(d > 1.0);
    free(e1);
    free(e2);
    mlb_sd_model_free(m);
    // the fp16 variant's names (model.fp16.safetensors, diffusion_pytorch_model.fp16.safetensors in
    // each component's folder): every component found, the same numbers
    static const char* comp[][2] = {{"text_encoder", "model"}, {"unet", "diffusion_pytorch_model"},
                                    {"vae", "diffusion_pytorch_model"}};
    char from[700], to[700];
    for (int i = 0; i < 3; i++) {
        snprintf(from, sizeof from, "%s/%s/%s.safetensors", dir, comp[i][0], comp[i][1]);
        snprintf(to, sizeof to, "%s/%s/%s.fp16.safetensors", dir, comp[i][0], comp[i][1]);
        REQUIRE(rename(from, to) == 0);
    }
    st = mlb_sd_model_load(dir, &o, &m);
    CHECK_MSG(st == MLB_OK, "%s", mlb_last_error());
    if (st == MLB_OK) {
        CHECK(m->unet->n_params == u->n_params && !memcmp(m->unet->params, u->params, u->n_params * sizeof(float)));
        CHECK(m->vae && !memcmp(m->vae->params, v->params, v->n_params * sizeof(float)));
        mlb_sd_model_free(m);
    }
    // a UNet folder with only PyTorch's pickle: refused with the way out, naming the component
    snprintf(p, sizeof p, "%s/unet_pickle", dir);
    REQUIRE(mlb_mkdir_p(p) == MLB_OK);
    snprintf(to, sizeof to, "%s/diffusion_pytorch_model.bin", p);
    REQUIRE(mlb_write_file_atomic(to, "x", 1) == MLB_OK);
    mlb_unet* up = NULL;
    CHECK(mlb_unet_load(p, NULL, &up) == MLB_ERR_UNSUPPORTED);
    CHECK_MSG(strstr(mlb_last_error(), "UNet") && strstr(mlb_last_error(), "convert it to .safetensors"), "%s",
              mlb_last_error());
    for (int i = 0; i < 3; i++) {   // back as the later tests expect them
        snprintf(from, sizeof from, "%s/%s/%s.fp16.safetensors", dir, comp[i][0], comp[i][1]);
        snprintf(to, sizeof to, "%s/%s/%s.safetensors", dir, comp[i][0], comp[i][1]);
        REQUIRE(rename(from, to) == 0);
    }
    mlb_unet_free(u);
    mlb_vae_free(v);
}

// The index's geometry suffix: written, read back, refused when malformed; the guidance puts it on
// the geometry stage's prompt and only there (the same loss as a plain model given the longer prompt).
static int write_text(const char* d, const char* rel, const char* text) {
    char p[600];
    snprintf(p, sizeof p, "%s/%s", d, rel);
    return mlb_write_file_atomic(p, text, strlen(text)) == MLB_OK;
}

static int write_index_text(const char* d, const char* suffix_json) {
    char p[600], text[700];
    snprintf(p, sizeof p, "%s/model_index.json", d);
    snprintf(text, sizeof text, "{\"_class_name\": \"StableDiffusionPipeline\", \"_matlaber_geometry_suffix\": %s}", suffix_json);
    return mlb_write_file_atomic(p, text, strlen(text)) == MLB_OK;
}

// One step's loss of `stage` on a fixed image, the geometry stage guided by geo, the appearance
// stage by app (the same model: mlb_guidance_sds_create); *score (when not NULL) the stage's score.
static double staged_loss(const mlb_sd_model* geo, const mlb_sd_model* app, const char* prompt, mlb_stage stage,
                          double* score) {
    mlb_guidance_sds_config c = mlb_guidance_sds_default();
    c.prompt = prompt;
    c.views = 1;
    c.latent_iters = 0;
    c.seed = 5;
    mlb_guidance* g = NULL;
    if (geo == app ? mlb_guidance_sds_create(geo, &c, &g) : mlb_guidance_sds_create_staged(geo, app, &c, &g)) return -1;
    enum { H = 16 };
    static float img[H * H * 4];
    for (int i = 0; i < H * H; i++)
        for (int ch = 0; ch < 4; ch++) img[4 * i + ch] = ch == 3 ? 1.0f : 0.5f * mlb_rng_uniform(3, ch, i);
    mlb_view view;
    double loss = -1;
    if (g->sample_views(g, stage, 7, &view) || g->loss(g, stage, 7, &view, 1, img, H, H, NULL, &loss)) loss = -1;
    if (score && g->score(g, stage, &view, 1, img, H, H, NULL, score)) loss = -1;
    mlb_guidance_free(g);
    return loss;
}

static double guidance_loss(const mlb_sd_model* m, const char* prompt, mlb_stage stage) {
    return staged_loss(m, m, prompt, stage, NULL);
}

TEST(geometry_suffix) {
    REQUIRE(dir[0]);   // write_and_load's folder, kept for this test
    REQUIRE(mlb_sd_write_index(dir, ", normal map") == MLB_OK);
    mlb_sd_model_options o = mlb_sd_model_default_options();
    o.device = MLB_DEVICE_CPU;
    mlb_sd_model* m = NULL;
    REQUIRE(mlb_sd_model_load(dir, &o, &m) == MLB_OK);
    CHECK(!strcmp(m->geometry_suffix, ", normal map"));
    double geo = guidance_loss(m, "a gold goblet", MLB_STAGE_GEOMETRY);
    double app = guidance_loss(m, "a gold goblet", MLB_STAGE_APPEARANCE);
    m->geometry_suffix[0] = 0;
    double geo_plain = guidance_loss(m, "a gold goblet", MLB_STAGE_GEOMETRY);
    double geo_long = guidance_loss(m, "a gold goblet, normal map", MLB_STAGE_GEOMETRY);
    double app_plain = guidance_loss(m, "a gold goblet", MLB_STAGE_APPEARANCE);
    printf("  geometry loss %.9g with the suffix, %.9g without, %.9g for the longer prompt; appearance %.9g / %.9g\n", geo,
           geo_plain, geo_long, app, app_plain);
    CHECK(geo > 0 && geo_plain > 0 && app > 0);
    CHECK(geo == geo_long);     // the suffix is the prompt's tail on the geometry stage
    CHECK(geo != geo_plain);    // and it changes what the model is asked
    CHECK(app == app_plain);    // the appearance stage keeps the plain prompt
    // A model per stage (docs/pipeline.md): m2 is m with conv_out's bias moved (another prediction)
    // and no suffix. Each stage's loss and score are those of its own model alone, and the
    // geometry prompt carries the geometry model's suffix.
    snprintf(m->geometry_suffix, sizeof m->geometry_suffix, ", normal map");
    mlb_sd_model* m2 = NULL;
    REQUIRE(mlb_sd_model_load(dir, &o, &m2) == MLB_OK);
    m2->geometry_suffix[0] = 0;
    for (int ch = 0; ch < m2->unet->cfg.out_channels; ch++) m2->unet->conv_out_b[ch] += 0.25f;
    double sc_m = 0, sc_m2 = 0, sc_geo_m = 0, sc_geo_st = 0, sc_app_st = 0;
    double geo_m = staged_loss(m, m, "a gold goblet", MLB_STAGE_GEOMETRY, &sc_geo_m);
    double app_m = staged_loss(m, m, "a gold goblet", MLB_STAGE_APPEARANCE, &sc_m);
    double geo_m2 = staged_loss(m2, m2, "a gold goblet", MLB_STAGE_GEOMETRY, NULL);
    double app_m2 = staged_loss(m2, m2, "a gold goblet", MLB_STAGE_APPEARANCE, &sc_m2);
    double geo_st = staged_loss(m, m2, "a gold goblet", MLB_STAGE_GEOMETRY, &sc_geo_st);
    double app_st = staged_loss(m, m2, "a gold goblet", MLB_STAGE_APPEARANCE, &sc_app_st);
    printf("  per stage: geometry %.9g (m %.9g, m2 %.9g), appearance %.9g (m %.9g, m2 %.9g), scores %.9g / %.9g\n",
           geo_st, geo_m, geo_m2, app_st, app_m, app_m2, sc_app_st, sc_m2);
    CHECK(geo_m > 0 && app_m2 > 0 && app_m != app_m2 && geo_m != geo_m2 && sc_m != sc_m2);   // the models differ
    CHECK(geo_m == geo);              // m's geometry loss with its suffix, as above
    CHECK(geo_st == geo_m);           // the geometry stage: m, with m's suffix
    CHECK(app_st == app_m2);          // the appearance stage: m2
    CHECK(sc_app_st == sc_m2 && sc_geo_st == sc_geo_m);   // and each stage's score its model's
    mlb_guidance* g = NULL;
    mlb_guidance_sds_config gc = mlb_guidance_sds_default();
    gc.prompt = "a gold goblet";
    CHECK(mlb_guidance_sds_create_staged(m, NULL, &gc, &g) == MLB_ERR_ARG && !g);
    mlb_sd_model_free(m2);
    mlb_sd_model_free(m);
    // malformed: not a string, too long, a control character; each a format error naming the file
    const char* bad[] = {"42", "\"0123456789012345678901234567890123456789012345678901234567890123456789\"", "\"a\\nb\""};
    for (int i = 0; i < 3; i++) {
        REQUIRE(write_index_text(dir, bad[i]));
        m = NULL;
        CHECK_MSG(mlb_sd_model_load(dir, &o, &m) == MLB_ERR_FORMAT && !m, "suffix %s accepted", bad[i]);
        CHECK(strstr(mlb_last_error(), "model_index.json") != NULL);
    }
    CHECK(mlb_sd_write_index(dir, "a \"quote\"") == MLB_ERR_ARG);
    // an index that is not JSON is refused naming it, not read as a folder without an index
    REQUIRE(write_text(dir, "model_index.json", "{\"_class_name\": \"StableDiffusionPipeline\","));
    m = NULL;
    CHECK(mlb_sd_model_load(dir, &o, &m) == MLB_ERR_FORMAT && !m);
    CHECK_MSG(strstr(mlb_last_error(), "model_index.json") && strstr(mlb_last_error(), "not valid JSON"), "%s", mlb_last_error());
    REQUIRE(mlb_sd_write_index(dir, "") == MLB_OK);
    // the scheduler's prediction type: read when there (an SD 2.x folder says v_prediction), refused
    // when it is one the sampler and the guidance do not compute, or the file is not JSON
    char sched[300];
    snprintf(sched, sizeof sched, "%s/scheduler", dir);
    REQUIRE(mlb_mkdir_p(sched) == MLB_OK);
    const char* pred[] = {"{\"prediction_type\": \"v_prediction\"}", "{\"prediction_type\": \"epsilon\"}",
                          "{\"prediction_type\": \"sample\"}", "{\"prediction_type\": 1}", "[1,"};
    const mlb_status want[] = {MLB_OK, MLB_OK, MLB_ERR_UNSUPPORTED, MLB_ERR_UNSUPPORTED, MLB_ERR_FORMAT};
    for (int i = 0; i < 5; i++) {
        REQUIRE(write_text(dir, "scheduler/scheduler_config.json", pred[i]));
        m = NULL;
        mlb_status st = mlb_sd_model_load(dir, &o, &m);
        CHECK_MSG(st == want[i], "%s: status %d", pred[i], (int)st);
        if (st == MLB_OK) CHECK(m && m->v_prediction == (i == 0));
        else CHECK_MSG(!m && strstr(mlb_last_error(), "scheduler_config.json"), "%s", mlb_last_error());
        mlb_sd_model_free(m);
    }
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf %s", dir);
    CHECK(system(cmd) == 0);
}

TEST(bad_words) {
    const char* bad[] = {"two words"};
    CHECK(mlb_sd_write_tokenizer("/tmp/mlb_sd_folder_bad", bad, 1) == MLB_ERR_ARG);
    const char* one[] = {"a"};
    CHECK(mlb_sd_write_tokenizer("/tmp/mlb_sd_folder_bad", one, 1) == MLB_ERR_ARG);
    mlb_text_encoder_shape ts = {600, 30, 1, 4, 64, 0};   // 30 not a multiple of 4 heads
    CHECK(mlb_text_encoder_write_random("/tmp/mlb_sd_folder_bad", &ts) == MLB_ERR_ARG);
    CHECK(system("rm -rf /tmp/mlb_sd_folder_bad") == 0);
}

int main(void) {
    RUN(write_and_load);
    RUN(geometry_suffix);
    RUN(bad_words);
    return test_summary();
}
