// The appearance stage's starting material (docs/pipeline.md, "Material start"), chosen by the
// guidance's model as --init auto chooses the starting shape (pipeline_init.c).
//
// The material network starts at the prior's centre: its hash features are ~1e-4, so every point's
// latent code is about the last layer's bias, 0, which decodes to a grey dielectric. From there score
// distillation finds a dielectric's colour by itself, but it seldom crosses to a metal, which needs
// kd down and ks up together: with the tiny model, silver missed the metal call on 10 of 11
// prompts (white, or a bluish diffuse over the specular) although the model's score prefers a
// metal's renders for "a silver ..." (docs/benchmarks.md, "The model picks the starting
// material"). So the surface is rendered in a few
// uniform archetypes, metals and dielectrics of the primary tints (generic: no catalogue material),
// each scored by the guidance (guidance.h, score) on the first appearance steps' views; when a metal
// scores best, the network starts from it (its last layer's bias set to that material), else from
// the centre as before, bit for bit. The dielectric archetypes are there so that a colour the
// prompt asks for ("a red mug") is not credited to the only tinted candidate, a warm metal.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/appearance.h"
#include "matlaber/brdf_ae.h"
#include "matlaber/dist.h"
#include "matlaber/log.h"
#include "pipeline/pipeline_internal.h"

typedef struct {
    const char* name;
    float k[7];   // kd rgb, ks rgb, kr (linear)
    int metal;
} archetype;

static const archetype ARCHETYPES[] = {
    {"grey metal", {0.02f, 0.02f, 0.02f, 0.9f, 0.9f, 0.9f, 0.25f}, 1},
    {"warm metal", {0.02f, 0.02f, 0.02f, 0.95f, 0.7f, 0.45f, 0.3f}, 1},
    {"white glossy", {0.7f, 0.7f, 0.7f, 0.04f, 0.04f, 0.04f, 0.3f}, 0},
    {"grey rough", {0.5f, 0.5f, 0.5f, 0.03f, 0.03f, 0.03f, 0.9f}, 0},
    {"warm glossy", {0.7f, 0.4f, 0.2f, 0.04f, 0.04f, 0.04f, 0.3f}, 0},
    {"red glossy", {0.6f, 0.08f, 0.06f, 0.04f, 0.04f, 0.04f, 0.3f}, 0},
    {"blue glossy", {0.08f, 0.15f, 0.6f, 0.04f, 0.04f, 0.04f, 0.3f}, 0},
    {"green glossy", {0.1f, 0.5f, 0.15f, 0.04f, 0.04f, 0.04f, 0.3f}, 0},
};
enum { N_ARCH = sizeof ARCHETYPES / sizeof *ARCHETYPES, START_VIEWS = 8, LATENT_FIT_ITERS = 20 };
// The timesteps the archetypes are scored at: the middle of the schedule. At large t the noised render
// keeps only its mean colour, and the model cannot tell a metal from a glaze of the same tint (per
// timestep, over the benchmark's 88 prompts: at 620 and 860 the picks are near chance, at 380 the warm
// metal wins 8 of 11 copper prompts and the grey metal 10 of 11 silver ones, at 140 the coppers
// read as glazes again: docs/benchmarks.md, "Scoring at the middle timesteps").
static const int SCORE_T[2] = {150, 550};

// The last layer's bias that makes the network output archetype k everywhere once the layer's
// weights are 0: the latent code the prior decodes to k (latent mode), or the sigmoid's input that
// the output map takes to k (direct mode).
static mlb_status archetype_bias(const mlb_material_net* net, const mlb_brdf_ae* prior, const float* k, float* bias) {
    if (net->cfg.mode == MLB_MATERIAL_LATENT) {
        if (!prior) return mlb_fail(MLB_ERR_ARG, "material start: a latent material network without its prior");
        return brdf_ae_latent_of(prior, k, 1, bias, LATENT_FIT_ITERS);
    }
    for (int i = 0; i < 7; i++) {
        double u = ((double)k[i] - mlb_brdf_range_lo[i]) / (mlb_brdf_range_hi[i] - mlb_brdf_range_lo[i]);
        u = fmin(fmax(u, 1e-4), 1 - 1e-4);
        bias[i] = (float)log(u / (1 - u));
    }
    return MLB_OK;
}

mlb_status pipeline_material_start(pipeline_run* r, int* metal) {
    const mlb_pipeline_config* c = r->c;
    mlb_guidance* g = r->g;
    mlb_material_net* net = &r->mat;
    *metal = 0;
    if (!c->material_start || !g->score) return MLB_OK;   // image guidance has no score: the centre
    mlb_mlp* mlp = &net->mlp;
    const int L = mlp->n_layers - 1, O = mlp->dims[L + 1], I = mlp->dims[L];
    if (!mlp->bias[L] || O > 7)
        return mlb_fail(MLB_ERR_ARG, "material start: the network's last layer is not 4 or 7 outputs with a bias");
    mlb_view* views = NULL;
    int n = 0, per = g->n_views;
    MLB_TRY(pipeline_first_views(r, MLB_STAGE_APPEARANCE, START_VIEWS, &views, &n));
    size_t img = (size_t)c->res * c->res * 4, nw = (size_t)O * I;
    float* images = malloc(sizeof(float) * img * (size_t)n);
    float* weight = malloc(sizeof(float) * nw);   // the layer as initialised, restored after
    float bias[7], code[N_ARCH][7];
    double sc[N_ARCH], *per_view = malloc(sizeof(double) * (size_t)n);
    mlb_status s = images && weight && per_view ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "material start: out of memory");
    if (!s) {
        memcpy(weight, mlp->weight[L], sizeof(float) * nw);
        memcpy(bias, mlp->bias[L], sizeof(float) * (size_t)O);
        memset(mlp->weight[L], 0, sizeof(float) * nw);   // the output: the bias at every point
    }
    mlb_appearance app;   // renders on the host: the scores read host images (guidance.h)
    memset(&app, 0, sizeof app);
    for (int a = 0; !s && a < N_ARCH; a++) s = archetype_bias(net, r->prior, ARCHETYPES[a].k, code[a]);
    // Several processes (dist.h): each renders and scores its share of the archetypes alone, and
    // every rank gets every score (the same bits as one process's)
    int first, count;
    mlb_dist_share(N_ARCH, &first, &count);
    int was = mlb_dist_solo(1);
    for (int a = first; !s && a < first + count; a++) {
        memcpy(mlp->bias[L], code[a], sizeof(float) * (size_t)O);
        for (int v = 0; !s && v < n; v += per)   // a step's views per render
            s = mlb_appearance_render(&app, net, &r->scene.mesh, r->scene.light_ptrs, views + v, per, c->res, c->ss,
                                      images + img * (size_t)v, 0);
        if (!s) s = g->score(g, MLB_STAGE_APPEARANCE, views, n, images, c->res, c->res, SCORE_T, per_view);
        sc[a] = 0;
        for (int v = 0; !s && v < n; v++) sc[a] += per_view[v] / n;
    }
    mlb_dist_solo(was);
    mlb_appearance_free(&app);
    s = pipeline_agree(s);
    if (!s) s = mlb_dist_allgather_items(sc + first, sc, N_ARCH, sizeof(double));
    if (weight) {   // the network as it came, then the chosen start
        memcpy(mlp->weight[L], weight, sizeof(float) * nw);
        memcpy(mlp->bias[L], bias, sizeof(float) * (size_t)O);
    }
    if (!s) {
        int best = 0;
        for (int a = 1; a < N_ARCH; a++)
            if (sc[a] > sc[best]) best = a;
        char line[1024];
        int len = snprintf(line, sizeof line, "material start: the prompt's score on %d views:", n);
        for (int a = 0; a < N_ARCH && len < (int)sizeof line; a++)
            len += snprintf(line + len, sizeof line - (size_t)len, " %s %+.5f;", ARCHETYPES[a].name, sc[a]);
        *metal = ARCHETYPES[best].metal;
        if (*metal) memcpy(mlp->bias[L], code[best], sizeof(float) * (size_t)O);
        mlb_log(MLB_LOG_INFO, "%s best: the %s; starting from the %s", line, ARCHETYPES[best].name,
                *metal ? ARCHETYPES[best].name : "prior's centre");
    }
    free(views);
    free(images);
    free(weight);
    free(per_view);
    return s ? mlb_fail_context(s, "material start") : MLB_OK;
}
