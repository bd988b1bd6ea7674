// `sd train` on a very small model (sd_train.h): the folder it writes loads through
// mlb_sd_model_load; the same bits on 1 and 2 threads; a run stopped and resumed gives the bits of
// one that never stopped. (That training learns is shown on the real model: docs/sd_train.md.)
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "matlaber/catalogue.h"
#include "matlaber/fileio.h"
#include "matlaber/sds.h"
#include "matlaber/sd_model.h"
#include "matlaber/sd_train.h"
#include "test.h"

static mlb_sd_train_config tiny(const char* dir) {
    mlb_sd_train_config c = mlb_sd_train_default();
    c.out_dir = dir;
    c.res = 32;
    c.n_images = 12;
    c.vae.block_out[0] = 8; c.vae.block_out[1] = 8; c.vae.block_out[2] = 16; c.vae.block_out[3] = 16;
    c.vae.norm_groups = 4;
    c.unet.block_out[0] = 16; c.unet.block_out[1] = 32; c.unet.block_out[2] = 32;
    c.unet.heads[0] = c.unet.heads[1] = c.unet.heads[2] = c.unet.mid_heads = 2;
    c.unet.norm_groups = 8;
    c.unet.time_embed_dim = 32;
    c.text.width = c.unet.context_dim = 16;
    c.text.heads = 2;
    c.text.mlp = 32;
    c.vae_steps = 6;
    c.vae_batch = 2;
    c.unet_steps = 6;
    c.unet_batch = 3;
    c.checkpoint_every = 2;
    return c;
}

static unsigned char* slurp(const char* path, size_t* n) {
    char* d = NULL;
    if (mlb_read_file(path, &d, n, (size_t)1 << 30)) return NULL;
    return (unsigned char*)d;
}

// 1 when the two files hold the same bytes
static int same_file(const char* a, const char* b) {
    size_t na = 0, nb = 0;
    unsigned char *x = slurp(a, &na), *y = slurp(b, &nb);
    int same = x && y && na == nb && !memcmp(x, y, na);
    free(x);
    free(y);
    return same;
}

static char root[256];

static void path(char* out, const char* run, const char* file) { snprintf(out, 512, "%s/%s/%s", root, run, file); }

TEST(train_threads_resume) {
    snprintf(root, sizeof root, "/tmp/mlb_sd_train_%d", (int)getpid());
    REQUIRE(mlb_mkdir_p(root) == MLB_OK);
    const mlb_backend* be = mlb_backend_cpu();
    char d1[300], d2[300], d3[300];
    snprintf(d1, sizeof d1, "%s/one", root);
    snprintf(d2, sizeof d2, "%s/two", root);
    snprintf(d3, sizeof d3, "%s/resumed", root);
    int nt = omp_get_max_threads();
    omp_set_num_threads(1);
    mlb_sd_train_config c = tiny(d1);
    mlb_status s = mlb_sd_train(be, &c);
    omp_set_num_threads(nt > 1 ? nt : 2);
    REQUIRE(s == MLB_OK);
    c = tiny(d2);
    REQUIRE(mlb_sd_train(be, &c) == MLB_OK);
    // stopped twice (inside the VAE's steps and inside the UNet's), resumed to the end
    c = tiny(d3);
    c.stop_after = 3;
    REQUIRE(mlb_sd_train(be, &c) == MLB_OK);
    char a[512], b[512];
    path(a, "resumed", "model_index.json");
    CHECK(!mlb_is_file(a));   // unfinished: no index yet
    c.resume = 1;
    c.stop_after = 9;
    REQUIRE(mlb_sd_train(be, &c) == MLB_OK);
    c.stop_after = 0;
    REQUIRE(mlb_sd_train(be, &c) == MLB_OK);
    const char* files[] = {"unet/diffusion_pytorch_model.safetensors", "vae/diffusion_pytorch_model.safetensors",
                           "text_encoder/model.safetensors", "tokenizer/merges.txt", "train/loss.csv"};
    for (int i = 0; i < 5; i++) {
        path(a, "one", files[i]);
        path(b, "two", files[i]);
        CHECK_MSG(same_file(a, b), "%s differs between 1 and 2 threads", files[i]);
        path(b, "resumed", files[i]);
        CHECK_MSG(same_file(a, b), "%s differs after stop and resume", files[i]);
    }
    // continued from a model folder over its untouched VAE (--init DIR --vae-steps 0), on new
    // renders: the VAE and its latent scale are the ones the UNet was trained with, to the byte
    char d4[300];
    snprintf(d4, sizeof d4, "%s/continued", root);
    c = tiny(d4);
    c.init_dir = d1;
    c.vae_steps = 0;
    c.unet_steps = 2;
    c.seed = 7;
    REQUIRE(mlb_sd_train(be, &c) == MLB_OK);
    const char* vae_files[] = {"vae/diffusion_pytorch_model.safetensors", "vae/config.json"};
    for (int i = 0; i < 2; i++) {
        path(a, "one", vae_files[i]);
        path(b, "continued", vae_files[i]);
        CHECK_MSG(same_file(a, b), "%s changed in a UNet-only continuation", vae_files[i]);
    }
    // the folder is a model the program reads like a user's
    mlb_sd_model_options o = mlb_sd_model_default_options();
    o.device = MLB_DEVICE_CPU;
    mlb_sd_model* m = NULL;
    REQUIRE(mlb_sd_model_load(d1, &o, &m) == MLB_OK);
    CHECK(m->unet->cfg.block_out[0] == 16 && m->vae->cfg.block_out[2] == 16);
    CHECK(m->scaling_factor > 0 && m->scaling_factor != 1.0f);
    CHECK(!strcmp(m->geometry_suffix, MLB_SD_GEOMETRY_SUFFIX));   // the index tells the guidance the captions' form
    float* e = malloc(77 * 16 * sizeof(float));
    REQUIRE(e);
    CHECK(mlb_sd_model_encode_prompt(m, "a gold goblet, front view", e) == MLB_OK);
    free(e);
    mlb_sd_model_free(m);
    char cmd[400];
    snprintf(cmd, sizeof cmd, "rm -rf %s", root);
    CHECK(system(cmd) == 0);
}

// The caption table: one row per (class, material, view, form), the geometry form's text carrying
// the suffix before the view, and sd train's index naming that suffix for the guidance.
TEST(captions) {
    int n = mlb_sd_caption_count(), nc = mlb_catalogue_n_classes(), nm = mlb_catalogue_n_materials();
    CHECK(n == 2 * nc * nm * MLB_SDS_N_VIEWS);
    unsigned char* seen = calloc((size_t)n, 1);
    REQUIRE(seen);
    int ok = 1;
    for (int c = 0; c < nc; c++)
        for (int m = 0; m < nm; m++)
            for (int v = 0; v < MLB_SDS_N_VIEWS; v++)
                for (int g = 0; g < 2; g++) {
                    int k = mlb_sd_caption_index(c, m, v, g);
                    if (k < 0 || k >= n || seen[k]) ok = 0;
                    else seen[k] = 1;
                }
    CHECK(ok);   // a bijection onto the rows
    free(seen);
    // and every row's text its own (the text is read from the row, the inverse of the index)
    char(*texts)[200] = malloc((size_t)n * sizeof *texts);
    REQUIRE(texts);
    int distinct = 1;
    for (int k = 0; k < n; k++) mlb_sd_caption_text(k, texts[k], sizeof texts[k]);
    for (int k = 0; k < n && distinct; k++)
        for (int j = 0; j < k; j++)
            if (!strcmp(texts[j], texts[k])) { distinct = 0; break; }
    CHECK(distinct);
    free(texts);
    int gold = -1, goblet = -1;
    for (int m = 0; m < nm; m++) if (!strcmp(mlb_catalogue_material_name(m), "gold")) gold = m;
    for (int c = 0; c < nc; c++) if (!strcmp(mlb_catalogue_class_name(c), "goblet")) goblet = c;
    REQUIRE(gold >= 0 && goblet >= 0);
    char t[200];
    mlb_sd_caption_text(mlb_sd_caption_index(goblet, gold, MLB_SDS_VIEW_FRONT, 1), t, sizeof t);
    CHECK(!strcmp(t, "a gold goblet, normal map, front view"));
    mlb_sd_caption_text(mlb_sd_caption_index(goblet, gold, MLB_SDS_VIEW_FRONT, 0), t, sizeof t);
    CHECK(!strcmp(t, "a gold goblet, front view"));
    mlb_sd_caption_text(mlb_sd_caption_index(goblet, gold, MLB_SDS_VIEW_NONE, 1), t, sizeof t);
    CHECK(!strcmp(t, "a gold goblet, normal map"));
}

TEST(bad_config) {
    mlb_sd_train_config c = tiny("/tmp/mlb_sd_train_bad");
    c.res = 36;
    CHECK(mlb_sd_train_check(&c) == MLB_ERR_ARG);
    c = tiny("/tmp/mlb_sd_train_bad");
    c.unet.context_dim = 24;
    CHECK(mlb_sd_train_check(&c) == MLB_ERR_ARG);
    c = tiny(NULL);
    CHECK(mlb_sd_train_check(&c) == MLB_ERR_ARG);
}

int main(void) {
    RUN(captions);
    RUN(bad_config);
    RUN(train_threads_resume);
    return test_summary();
}
