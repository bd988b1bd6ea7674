// The appearance stage's starting material (docs/pipeline.md, "Material start"), chosen by the
// guidance's model as --init auto chooses the starting shape (pipeline_init.c).
//
// The material network starts at the prior's centre: its hash features are ~1e-4, so every point's
// latent code is about the last layer's bias, 0, which decodes to a grey dielectric. From there score
// distillation finds a dielectric's colour by itself, but it seldom crosses to a metal, which needs
// kd down and ks up together: with the tiny model, silver missed the metal call on 10 of 11
// prompts (white, or a bluish diffuse over the specular) although the model's score prefers a
// metal's renders for "a silver ..." (docs/pipeline.md, "Material start"). So the surface is rendered in a few
// uniform archetypes, metals and dielectrics of the primary tints (generic: no catalogue material),
// each scored by the guidance (guidance.h, score) on the first appearance steps' views; when a metal
// scores best, the network starts from it (its last layer's bias set to that material), else from
// the centre as before, bit for bit. The dielectric archetypes are there so that a colour the
// prompt asks for ("a red mug") is not credited to the only tinted candidate, a warm metal.
// The scores of similar archetypes are close and 8 views are few: when the best metal and the best
// dielectric are within CLOSE_Z standard errors, those two are scored again on CLOSE_VIEWS views.
// Where they still tie (within TIE_Z standard errors), more views do not help: on a gold table the
// warm metal and the warm glaze stay level on 128 views, as the grey metal and the white glaze on a
// white bowl (docs/pipeline.md, "Material start"). What the archetypes cannot tell
// apart, the stage's own results can: the first TRIAL_STEPS steps are run from each of the two
// starts, and the start whose result the guidance scores higher is taken.
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
enum {
    N_ARCH = sizeof ARCHETYPES / sizeof *ARCHETYPES,
    START_VIEWS = 8,
    CLOSE_VIEWS = 32,
    LATENT_FIT_ITERS = 20,
    TRIAL_STEPS = 20
};
// A metal / dielectric split closer than this many standard errors of the paired per-view
// differences on the first START_VIEWS views is decided on CLOSE_VIEWS views; one still within
// TIE_Z of them there, by trials of the stage.
#define CLOSE_Z 2.0
#define TIE_Z 1.0
// The timesteps the archetypes are scored at: the middle of the schedule, 375..525. At large t the
// noised render keeps only its mean colour, and the model cannot tell a metal from a glaze of the
// same tint (per timestep, over the benchmark's 88 prompts: at 620 and 860 the picks are near
// chance, at 380 the warm metal wins 8 of 11 copper prompts and the grey metal 10 of 11 silver ones);
// at small t the metals read as glazes again (at 200, with the appearance model, 16 of 27 metal
// prompts' best archetype is a metal, at 400 26; docs/pipeline.md, "Material start").
static const int SCORE_T[2] = {350, 550};

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

// Renders archetype code (the last layer's bias; its weights are 0), or the network as it is (code
// NULL), on views [0, n) and scores them: pv[n], the guidance's per-view scores.
static mlb_status score_archetype(pipeline_run* r, mlb_appearance* app, const float* code, const mlb_view* views, int n,
                                  float* images, double* pv) {
    const mlb_pipeline_config* c = r->c;
    mlb_mlp* mlp = &r->mat.mlp;
    const int L = mlp->n_layers - 1, per = r->g->n_views;
    size_t img = (size_t)c->res * c->res * 4;
    if (code) memcpy(mlp->bias[L], code, sizeof(float) * (size_t)mlp->dims[L + 1]);
    mlb_status s = MLB_OK;
    for (int v = 0; !s && v < n; v += per)   // a step's views per render
        s = mlb_appearance_render(app, &r->mat, &r->scene.mesh, r->scene.light_ptrs, views + v, per, c->res, c->ss,
                                  images + img * (size_t)v, 0);
    return s ? s : r->g->score(r->g, MLB_STAGE_APPEARANCE, views, n, images, c->res, c->res, SCORE_T, pv);
}

// Scores items[0..count) (archetype indices; code NULL: the network as it is, count 1) on views
// [0, n), shared over the processes (dist.h): each renders and scores its block alone, every rank
// gets every row of pv [count, n] (the same bits as one process's).
static mlb_status score_shared(pipeline_run* r, mlb_appearance* app, float (*code)[7], const int* items, int count,
                               const mlb_view* views, int n, float* images, double* pv) {
    int first, mine;
    mlb_dist_share(count, &first, &mine);
    int was = mlb_dist_solo(1);
    mlb_status s = MLB_OK;
    for (int i = first; !s && i < first + mine; i++) {
        s = score_archetype(r, app, code ? code[items[i]] : NULL, views, n, images, pv + (size_t)i * n);
        mlb_progress_update(r->progress, ++r->stage_counted, NULL);   // (rank 0's share: the others have none)
    }
    mlb_dist_solo(was);
    s = pipeline_agree(s);
    return s ? s : mlb_dist_allgather_items(pv + (size_t)first * n, pv, count, sizeof(double) * (size_t)n);
}

static double row_mean(const double* x, int n) {
    double m = 0;
    for (int k = 0; k < n; k++) m += x[k] / n;
    return m;
}

// A tie between archetypes pair[0] (a metal) and pair[1] (a dielectric): the stage's first
// TRIAL_STEPS steps from each start (the metal's bias, or the prior's centre as the network came),
// each result scored on the n views; the network is left as it came. *winner: pair[0] or pair[1].
static mlb_status trial_starts(pipeline_run* r, mlb_appearance* app, float (*code)[7], const int pair[2],
                               const mlb_view* views, int n, float* images, double* pv, int* winner) {
    mlb_material_net* net = &r->mat;
    mlb_mlp* mlp = &net->mlp;
    const int L = mlp->n_layers - 1, O = mlp->dims[L + 1];
    float* keep = malloc(sizeof(float) * net->n_params * 3);   // parameters, Adam's moments
    if (!keep) return mlb_fail(MLB_ERR_NOMEM, "material start: out of memory for a trial");
    long step;
    pipeline_field_keep(net, keep, &step);
    double mean[2] = {0, 0};
    mlb_status s = MLB_OK;
    for (int k = 0; !s && k < 2; k++) {
        if (k == 0) memcpy(mlp->bias[L], code[pair[0]], sizeof(float) * (size_t)O);
        s = r->appearance_trial(r, k == 0, TRIAL_STEPS);
        if (!s) s = score_shared(r, app, NULL, NULL, 1, views, n, images, pv);
        if (!s) mean[k] = row_mean(pv, n);
        pipeline_field_restore(net, keep, step);
    }
    free(keep);
    if (s) return s;
    *winner = mean[0] > mean[1] ? pair[0] : pair[1];
    mlb_log(MLB_LOG_INFO, "material start: a tie; after %d steps from each start, on %d views: from the %s %+.5f, from the prior's centre %+.5f; best: the %s",
            TRIAL_STEPS, n, ARCHETYPES[pair[0]].name, mean[0], mean[1], *winner == pair[0] ? ARCHETYPES[pair[0]].name : "prior's centre");
    return MLB_OK;
}

int pipeline_material_start_steps(const pipeline_run* r) { return r->c->material_start && r->g->score ? N_ARCH : 0; }

int pipeline_material_start_views(const pipeline_run* r) {
    int per = r->g->n_views > 0 ? r->g->n_views : 1;
    return (START_VIEWS + per - 1) / per * per;
}

mlb_status pipeline_material_start(pipeline_run* r, int* metal) {
    const mlb_pipeline_config* c = r->c;
    mlb_guidance* g = r->g;
    mlb_material_net* net = &r->mat;
    *metal = 0;
    if (!c->material_start || !g->score) return MLB_OK;   // image guidance has no score: the centre
    mlb_mlp* mlp = &net->mlp;
    const int L = mlp->n_layers - 1, O = mlp->dims[L + 1], I = mlp->dims[L];
    r->stage_counted = 0;
    if (!mlp->bias[L] || O > 7)
        return mlb_fail(MLB_ERR_ARG, "material start: the network's last layer is not 4 or 7 outputs with a bias");
    mlb_view* views = NULL;
    int n_all = 0, per = g->n_views;
    MLB_TRY(pipeline_first_views(r, MLB_STAGE_APPEARANCE, CLOSE_VIEWS, &views, &n_all));
    int n = (START_VIEWS + per - 1) / per * per;   // the first look: the first steps' views, at least START_VIEWS
    if (n > n_all) n = n_all;
    size_t img = (size_t)c->res * c->res * 4, nw = (size_t)O * I;
    float* images = malloc(sizeof(float) * img * (size_t)n_all);
    float* weight = malloc(sizeof(float) * nw);   // the layer as initialised, restored after
    float bias[7], code[N_ARCH][7];
    double* pv = malloc(sizeof(double) * (size_t)n * N_ARCH);   // [N_ARCH, n] per-view scores
    double* pv2 = malloc(sizeof(double) * (size_t)n_all * 2);  // [2, n_all]: the close call's second look
    mlb_status s = images && weight && pv && pv2 ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "material start: out of memory");
    if (!s) {
        memcpy(weight, mlp->weight[L], sizeof(float) * nw);
        memcpy(bias, mlp->bias[L], sizeof(float) * (size_t)O);
        memset(mlp->weight[L], 0, sizeof(float) * nw);   // the output: the bias at every point
    }
    mlb_appearance app;   // renders on the host: the scores read host images (guidance.h)
    memset(&app, 0, sizeof app);
    int all[N_ARCH];
    for (int a = 0; a < N_ARCH; a++) all[a] = a;
    for (int a = 0; !s && a < N_ARCH; a++) s = archetype_bias(net, r->prior, ARCHETYPES[a].k, code[a]);
    if (!s) s = score_shared(r, &app, code, all, N_ARCH, views, n, images, pv);
    int best = 0;
    double sc[N_ARCH];
    char line[1024];
    if (!s) {
        for (int a = 0; a < N_ARCH; a++) {
            sc[a] = row_mean(pv + (size_t)a * n, n);
            if (sc[a] > sc[best]) best = a;
        }
        int len = snprintf(line, sizeof line, "material start: the prompt's score on %d views:", n);
        for (int a = 0; a < N_ARCH && len < (int)sizeof line; a++)
            len += snprintf(line + len, sizeof line - (size_t)len, " %s %+.5f;", ARCHETYPES[a].name, sc[a]);
        mlb_log(MLB_LOG_INFO, "%s best: the %s", line, ARCHETYPES[best].name);
    }
    // A close call between the best metal and the best dielectric (their paired difference within
    // CLOSE_Z standard errors) is looked at again on more views: those two only
    int pair[2] = {-1, -1}, tie = 0;   // best metal, best dielectric
    for (int a = 0; !s && a < N_ARCH; a++) {
        int k = ARCHETYPES[a].metal ? 0 : 1;
        if (pair[k] < 0 || sc[a] > sc[pair[k]]) pair[k] = a;
    }
    if (!s && n_all > n && pair[0] >= 0 && pair[1] >= 0) {
        double m, se;
        pipeline_paired_difference(pv + (size_t)pair[0] * n, pv + (size_t)pair[1] * n, n, &m, &se);
        if (fabs(m) < CLOSE_Z * se) {
            mlb_progress_stage_steps(r->progress, N_ARCH + 2);
            s = score_shared(r, &app, code, pair, 2, views, n_all, images, pv2);
            if (!s) {
                double m0 = row_mean(pv2, n_all), m1 = row_mean(pv2 + n_all, n_all);
                best = m0 > m1 ? pair[0] : pair[1];
                double m2, se2;
                pipeline_paired_difference(pv2, pv2 + n_all, n_all, &m2, &se2);
                tie = fabs(m2) < TIE_Z * se2;
                mlb_log(MLB_LOG_INFO, "material start: a close call (the %s - the %s %+.5f +- %.5f); on %d views: the %s %+.5f, the %s %+.5f (%+.5f +- %.5f); %s%s",
                        ARCHETYPES[pair[0]].name, ARCHETYPES[pair[1]].name, m, se, n_all, ARCHETYPES[pair[0]].name, m0,
                        ARCHETYPES[pair[1]].name, m1, m2, se2, tie ? "a tie" : "best: the ", tie ? "" : ARCHETYPES[best].name);
            }
        }
    }
    if (weight) {   // the network as it came, then the chosen start
        memcpy(mlp->weight[L], weight, sizeof(float) * nw);
        memcpy(mlp->bias[L], bias, sizeof(float) * (size_t)O);
    }
    if (!s && tie) mlb_progress_stage_steps(r->progress, N_ARCH + 4);   // the trials' scores
    if (!s && tie) s = trial_starts(r, &app, code, pair, views, n_all, images, pv2, &best);
    mlb_appearance_free(&app);
    if (!s) {
        *metal = ARCHETYPES[best].metal;
        if (*metal) memcpy(mlp->bias[L], code[best], sizeof(float) * (size_t)O);
        mlb_log(MLB_LOG_INFO, "material start: from the %s", *metal ? ARCHETYPES[best].name : "prior's centre");
    }
    free(views);
    free(images);
    free(weight);
    free(pv);
    free(pv2);
    return s ? mlb_fail_context(s, "material start") : MLB_OK;
}
