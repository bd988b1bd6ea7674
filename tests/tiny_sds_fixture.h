// Shared by tests (not itself a test): a tiny random UNet (levels 32, 32, 64, 64, one layer per
// block, attention at the third level only), the tiny VAE of test_sd_tiny, SD's schedule and random
// embeddings per view prompt, for SDS guidance with no weights from outside.
#ifndef MATLABER_TINY_SDS_FIXTURE_H
#define MATLABER_TINY_SDS_FIXTURE_H
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>
#include "matlaber/rng.h"
#include "matlaber/schedule.h"
#include "matlaber/sds.h"
#include "matlaber/unet_random.h"
#include "matlaber/vae.h"

// The UNet is written to dir and loaded back (the loaders' path), then its files removed.
static inline mlb_unet* tiny_unet(const char* dir) {
    mlb_unet_config c = mlb_unet_tiny_config(0);
    c.layers_per_block = 1;
    c.attn[0] = c.attn[1] = 0;
    c.attn[2] = 1;
    c.attn[3] = 0;
    char w[512], cj[512];
    snprintf(w, sizeof w, "%s/unet.safetensors", dir);
    snprintf(cj, sizeof cj, "%s/config.json", dir);
    mlb_unet_random_options o = mlb_unet_random_default_options();
    o.seed = 9;
    o.config_json_path = cj;
    mlb_unet* u = NULL;
    if (mlb_unet_write_random(&c, &o, w) || mlb_unet_load(w, NULL, &u)) printf("  %s\n", mlb_last_error());
    unlink(w);
    unlink(cj);
    return u;
}
static inline mlb_vae* tiny_vae(void) {
    mlb_vae_config vc = mlb_vae_sd_config();
    int bo[4] = {32, 32, 64, 64};
    for (int i = 0; i < 4; i++) vc.block_out[i] = bo[i];
    mlb_vae* v = NULL;
    if (mlb_vae_create(NULL, &vc, &v)) return NULL;
    mlb_vae_init_random(v, 3, 1.0f);
    return v;
}

enum { TC = 5 };
typedef struct {
    mlb_unet* unet;
    mlb_vae* vae;
    float ac[1000];
    float cond[MLB_SDS_N_VIEWS][TC * 32];   // a different embedding per view prompt
    float unc[2][TC * 32];                  // geometry / appearance negatives
} fixture;

// The models (in dir's files for a moment), the schedule and the embeddings; 0 on failure.
static inline int fixture_init(fixture* f, const char* dir) {
    f->unet = tiny_unet(dir);
    f->vae = tiny_vae();
    if (!f->unet || !f->vae) return 0;
    if (mlb_schedule_alphas_cumprod_f32(f->ac, 1000, MLB_SD_BETA_START, MLB_SD_BETA_END) != MLB_OK) return 0;
    for (int v = 0; v < MLB_SDS_N_VIEWS; v++) mlb_rng_fill_normal(f->cond[v], TC * 32, 4, 10 + v, 0, 0, 1);
    mlb_rng_fill_normal(f->unc[0], TC * 32, 4, 20, 0, 0, 1);
    mlb_rng_fill_normal(f->unc[1], TC * 32, 4, 21, 0, 0, 1);
    return 1;
}
static inline void fixture_free(fixture* f) {
    mlb_vae_free(f->vae);
    mlb_unet_free(f->unet);
}

// An SDS object with the fixture's embeddings (stage's negative) and options o.
static inline mlb_sds* make_sds(const fixture* f, int stage, const mlb_sds_options* o) {
    mlb_sds* s = NULL;
    if (mlb_sds_create(f->unet, f->vae, 0.18215f, f->ac, 0, o, &s)) return NULL;
    for (int v = 0; v < MLB_SDS_N_VIEWS; v++) mlb_sds_set_cond(s, v, f->cond[v], TC);
    mlb_sds_set_uncond(s, f->unc[stage], TC);
    return s;
}
#endif
