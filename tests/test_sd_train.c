// `sd train` on a very small model (sd_train.h): the folder it writes loads through
// mlb_sd_model_load; the same bits on 1 and 2 threads; a run stopped and resumed gives the bits of
// one that never stopped, and only with the first run's options; the same with the CPU's bf16 table,
// whose losses track fp32's. (That training learns is shown on the real model: docs/sd_train.md.)
#include <math.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "matlaber/backend.h"
#include "matlaber/catalogue.h"
#include "matlaber/fileio.h"
#include "matlaber/nn.h"
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

// Trains the tiny model on table `be` into root/TAG-one (1 thread), root/TAG-two (2 threads) and
// root/TAG-resumed (stopped inside the VAE's steps and inside the UNet's, resumed to the end), and
// checks that the three folders hold the same bytes.
static void threads_and_resume(const mlb_backend* be, const char* tag) {
    const char* kind[3] = {"one", "two", "resumed"};
    char run[3][64], dir[3][300];
    for (int k = 0; k < 3; k++) {
        snprintf(run[k], sizeof run[k], "%s-%s", tag, kind[k]);
        snprintf(dir[k], sizeof dir[k], "%s/%s", root, run[k]);
    }
    int nt = omp_get_max_threads();
    omp_set_num_threads(1);
    mlb_sd_train_config c = tiny(dir[0]);
    mlb_status s = mlb_sd_train(be, &c);
    omp_set_num_threads(nt > 1 ? nt : 2);
    REQUIRE(s == MLB_OK);
    c = tiny(dir[1]);
    REQUIRE(mlb_sd_train(be, &c) == MLB_OK);
    c = tiny(dir[2]);
    c.stop_after = 3;
    REQUIRE(mlb_sd_train(be, &c) == MLB_OK);
    char a[512], b[512];
    path(a, run[2], "model_index.json");
    CHECK(!mlb_is_file(a));   // unfinished: no index yet
    c.resume = 1;
    c.stop_after = 9;
    REQUIRE(mlb_sd_train(be, &c) == MLB_OK);
    c.stop_after = 0;
    REQUIRE(mlb_sd_train(be, &c) == MLB_OK);
    const char* files[] = {"unet/diffusion_pytorch_model.safetensors", "vae/diffusion_pytorch_model.safetensors",
                           "text_encoder/model.safetensors", "tokenizer/merges.txt", "train/loss.csv"};
    for (int i = 0; i < 5; i++) {
        path(a, run[0], files[i]);
        path(b, run[1], files[i]);
        CHECK_MSG(same_file(a, b), "%s (%s) differs between 1 and 2 threads", files[i], tag);
        path(b, run[2], files[i]);
        CHECK_MSG(same_file(a, b), "%s (%s) differs after stop and resume", files[i], tag);
    }
}

static void make_root(void) {
    if (root[0]) return;
    snprintf(root, sizeof root, "/tmp/mlb_sd_train_%d", (int)getpid());
    if (mlb_mkdir_p(root)) { fprintf(stderr, "cannot make %s\n", root); exit(1); }
}

TEST(train_threads_resume) {
    make_root();
    const mlb_backend* be = mlb_backend_cpu();
    threads_and_resume(be, "fp32");
    if (test_case_failed) return;
    char a[512], b[512], d1[300];
    snprintf(d1, sizeof d1, "%s/fp32-one", root);
    // continued from a model folder over its untouched VAE (--init DIR --vae-steps 0), on new
    // renders: the VAE and its latent scale are the ones the UNet was trained with, to the byte
    char d4[300];
    snprintf(d4, sizeof d4, "%s/continued", root);
    mlb_sd_train_config c = tiny(d4);
    c.init_dir = d1;
    c.vae_steps = 0;
    c.unet_steps = 2;
    c.seed = 7;
    REQUIRE(mlb_sd_train(be, &c) == MLB_OK);
    const char* vae_files[] = {"vae/diffusion_pytorch_model.safetensors", "vae/config.json"};
    for (int i = 0; i < 2; i++) {
        path(a, "fp32-one", vae_files[i]);
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
}

// The losses of stage `stage` (0 VAE, 1 UNet) in DIR/train/loss.csv ("stage,step,loss"), at most cap.
static int stage_losses(const char* dir, int stage, double* out, int cap) {
    char p[512];
    snprintf(p, sizeof p, "%s/train/loss.csv", dir);
    FILE* f = fopen(p, "r");
    if (!f) return 0;
    char line[128];
    int n = 0, st;
    long step;
    double v;
    while (fgets(line, sizeof line, f))
        if (sscanf(line, "%d,%ld,%lf", &st, &step, &v) == 3 && st == stage && n < cap) out[n++] = v;
    fclose(f);
    return n;
}

// The CPU's bf16 table (what `sd train` takes on a CPU with AVX-512 BF16): the same bits on 1 and 2
// threads and across a resume; where the CPU has the instructions the operands are rounded (other
// bits than fp32's) and every loss stays within 2% of fp32's; where it has not, the table is
// fp32's to the byte.
TEST(train_bf16) {
    make_root();
    const mlb_backend* be = mlb_backend_for(MLB_DEVICE_CPU, MLB_GEMM_BF16);
    threads_and_resume(be, "bf16");
    if (test_case_failed) return;
    // the fp32 reference: train_threads_resume's folder when it ran (the same config), else trained here
    char f32[300], b16[300], a[512], b[512];
    snprintf(f32, sizeof f32, "%s/fp32-one", root);
    snprintf(b16, sizeof b16, "%s/bf16-one", root);
    path(a, "fp32-one", "model_index.json");
    if (!mlb_is_file(a)) {
        mlb_sd_train_config c = tiny(f32);
        REQUIRE(mlb_sd_train(mlb_backend_cpu(), &c) == MLB_OK);
    }
    path(a, "fp32-one", "unet/diffusion_pytorch_model.safetensors");
    path(b, "bf16-one", "unet/diffusion_pytorch_model.safetensors");
    if (!mlb_gemm_bf16_native()) {
        printf("  no AVX-512 BF16 here: the bf16 table is fp32's fallback\n");
        CHECK_MSG(same_file(a, b), "the bf16 table's fallback trained other bits than fp32");
        return;
    }
    CHECK_MSG(!same_file(a, b), "bf16 trained the same bits as fp32: the bf16 GEMMs were not used");
    for (int stage = 0; stage < 2; stage++) {
        double l32[64], l16[64];
        int n32 = stage_losses(f32, stage, l32, 64), n16 = stage_losses(b16, stage, l16, 64);
        CHECK(n32 == n16 && n32 == 6);
        double worst = 0;
        for (int i = 0; i < n32 && i < n16; i++) {
            double r = fabs(l16[i] - l32[i]) / fabs(l32[i]);
            if (r > worst) worst = r;
        }
        printf("  %s losses: bf16 within %.2e (relative) of fp32's\n", stage ? "UNet" : "VAE", worst);
        CHECK_MSG(worst < 0.02, "the %s's bf16 losses stray %.3f from fp32's", stage ? "UNet" : "VAE", worst);
    }
}

// --resume with other options than the first run's is refused before any work, naming the option and
// the file, the state untouched; with the first run's it continues.
TEST(resume_needs_the_same_options) {
    make_root();
    char d[300], st[512], opt[512];
    snprintf(d, sizeof d, "%s/options", root);
    mlb_sd_train_config c = tiny(d);
    c.stop_after = 3;
    REQUIRE(mlb_sd_train(mlb_backend_cpu(), &c) == MLB_OK);
    path(st, "options", "train/vae.safetensors");
    path(opt, "options", "train/options.txt");
    size_t n0 = 0, n1 = 0;
    unsigned char* before = slurp(st, &n0);
    REQUIRE(before);
    c.resume = 1;
    c.stop_after = 0;
    c.unet_lr *= 2;
    mlb_status s = mlb_sd_train(mlb_backend_cpu(), &c);
    CHECK(s == MLB_ERR_ARG);
    CHECK_MSG(strstr(mlb_last_error(), "unet_lr") && strstr(mlb_last_error(), "options.txt"), "error: %s", mlb_last_error());
    unsigned char* after = slurp(st, &n1);
    CHECK(after && n0 == n1 && !memcmp(before, after, n0));
    free(after);
    c.unet_lr /= 2;
    c.n_images += 1;
    CHECK(mlb_sd_train(mlb_backend_cpu(), &c) == MLB_ERR_ARG && strstr(mlb_last_error(), "images"));
    c.n_images -= 1;
    CHECK(mlb_sd_train(mlb_backend_cpu(), &c) == MLB_OK);
    path(opt, "options", "model_index.json");
    CHECK(mlb_is_file(opt));
    free(before);
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
    RUN(train_bf16);
    RUN(resume_needs_the_same_options);
    if (root[0]) {
        char cmd[400];
        snprintf(cmd, sizeof cmd, "rm -rf %s", root);
        if (system(cmd) != 0) printf("  could not remove %s\n", root);
    }
    return test_summary();
}
