// The geometry stage's starting shape (docs/pipeline.md, Init): the SDF network fitted to an
// ellipsoid, a cylinder, a torus, a slab, a cup or the user's mesh, or (--init auto) to whichever of the
// primitives the guidance's model finds most like the prompt.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/dist.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/log.h"
#include "matlaber/obj.h"
#include "matlaber/sds.h"
#include "pipeline/pipeline_internal.h"

// Fits net to the shape, from the network's state as it is.
static mlb_status fit_shape(mlb_geometry_net* net, const mlb_pipeline_config* c, const char* init, int active_levels,
                            mlb_progress* progress, double* final_loss) {
    mlb_shape shape;
    memset(&shape, 0, sizeof shape);
    mlb_status s = MLB_OK;
    if (!strcmp(init, "ellipsoid")) {
        // a sphere of radius 0.5 (semi-axes 0.5): inside every target placed in the unit sphere, so
        // the geometry stage grows it outward (docs/pipeline.md, Init)
        const float axes[3] = {0.5f, 0.5f, 0.5f};
        mlb_shape_ellipsoid(&shape, 1.0f, axes);
    } else if (!mlb_shape_builtin(&shape, init, 1.0f)) {   // cylinder, torus, slab, cup: else a file
        mlb_mesh m;
        memset(&m, 0, sizeof m);
        s = mlb_obj_load(init, &m);
        if (!s) s = mlb_shape_from_mesh(&shape, &m, 0.8f);
        mlb_mesh_free(&m);
        if (s) return mlb_fail_context(s, "--init %s", init);
    }
    mlb_shape_fit_config fc = mlb_shape_fit_default();
    fc.iters = c->init_iters;
    fc.seed = c->seed + 1;
    net->active_levels = active_levels;   // the initial shape in the levels step 0 sees
    s = mlb_geometry_fit_shape(net, &shape, &fc, progress, final_loss);
    net->active_levels = 0;
    mlb_shape_free(&shape);
    return s;
}

mlb_status pipeline_init_shape(mlb_geometry_net* net, const mlb_pipeline_config* c, const char* init, int active_levels,
                               mlb_progress* progress) {
    mlb_shape probe;
    memset(&probe, 0, sizeof probe);
    const int builtin = mlb_shape_builtin(&probe, init, 1.0f);   // an OBJ file could change between two runs
    mlb_shape_free(&probe);
    double final_loss = 0;
    uint64_t key[2];
    if (builtin) pipeline_shape_fit_key(net, c, init, active_levels, key);
    const int kept = builtin && pipeline_shape_fit_recall(key, net, &final_loss);   // a fit this process made before
    if (kept) mlb_progress_update(progress, c->init_iters, NULL);
    if (!kept) {
        MLB_TRY(fit_shape(net, c, init, active_levels, progress, &final_loss));
        if (builtin) pipeline_shape_fit_keep(key, net, final_loss);
    }
    // the optimiser starts fresh after the fit (a kept fit has no moments to give)
    memset(net->adam_m, 0, sizeof(float) * net->n_params);
    memset(net->adam_v, 0, sizeof(float) * net->n_params);
    net->step = 0;
    mlb_log(MLB_LOG_INFO, "shape init (%s): SDF MSE %.3g after %d steps%s", init, final_loss, c->init_iters,
            kept ? " (kept from an earlier run of this process)" : "");
    return MLB_OK;
}

// --init auto: each candidate is fitted and rendered as the geometry stage's first steps see it
// (their views, at least AUTO_VIEWS of them) and scored by the guidance per view (guidance.h,
// score: how much better the prompt explains a render than the unconditional text does). The first
// candidate (the ellipsoid unless --init auto:A,B,.. names others) is the default; another replaces
// it only when its score beats the first's by more than AUTO_Z_START standard errors of the paired
// per-view differences (the views' draws are shared, so the difference is the shapes'), the
// clearest such win if several do. 5, not 2: the views of one shape are not independent draws, the
// best of several candidates is taken, and a shape only partly like the object wins by a few: over
// the 88 catalogue prompts the cup beats the ellipsoid for goblets (a bowl on a stem) by 3.0-4.7
// and a goblet grown from it ends worse, while the clear wins are 5.6-7.6 (slab, tables), 7.6-8.2
// (torus, rings) and 8.2-11.5 (cup, bowls) (docs/pipeline.md, "Init").
//
// A look at the start cannot tell which start will grow: at some seeds the model likes a high
// slab for mugs and stools as well as tables, and a mug from it loses its surface. So when a
// candidate wins, the first and every winner are looked ahead: AUTO_AHEAD steps of the geometry
// stage itself (its views, noise and learning rate, Adam fresh), then scored again on the same
// views. A candidate whose surface vanishes on the way is out; the rule is applied again to the rest
// (the first still alive is the reference) at AUTO_Z: the win is established, the look-ahead asks
// whether it holds (a win shrinks on the way: with an earlier model a table's slab won by 5.6 and
// kept 3.9). Each fit starts from the network's state as it came, and the chosen candidate's fit
// (not its look-ahead) is what the stage starts from, so the start is the same bits as --init NAME.
// No cylinder by default: the model prefers it for bottles, mugs and bowls, and a bottle from it
// ended a vase (docs/pipeline.md, "Look-ahead").
#define AUTO_VIEWS 16
#define AUTO_Z_START 5.0
#define AUTO_Z 3.0
#define AUTO_MAX 8
#define AUTO_AHEAD 20
static const char* const AUTO_DEFAULT = "ellipsoid,torus,slab,cup";

// The guidance's per-view scores of the network's surface; *vanished = 1 (and MLB_OK, no scores)
// when it has none.
static mlb_status score_shape(pipeline_run* r, const mlb_view* views, int n, double* per_view, int* vanished) {
    const mlb_pipeline_config* c = r->c;
    mlb_camera* cams = malloc(sizeof(mlb_camera) * (size_t)n);
    if (!cams) return mlb_fail(MLB_ERR_NOMEM, "--init auto: out of memory");
    for (int v = 0; v < n; v++) cams[v] = views[v].cam;
    mlb_geofit_state st;
    memset(&st, 0, sizeof st);
    st.be = pipeline_stage_table(r);
    mlb_geofit_stats stats;
    mlb_status s = mlb_geofit_forward(&st, &r->geo, &r->grid, cams, n, c->res, c->ss, NULL, &stats);
    *vanished = s && st.surf.n_faces == 0;   // marching tets found no surface
    if (*vanished) s = MLB_OK;
    else if (!s) s = r->g->score(r->g, MLB_STAGE_GEOMETRY, views, n, st.images, c->res, c->res, NULL, per_view);
    mlb_geofit_state_free(&st);
    free(cams);
    return s;
}

// The geometry stage's first `steps` steps from the network's state, Adam fresh; *vanished = 1
// (and MLB_OK) when the surface is gone on the way (after the last step: score_shape says so).
static mlb_status look_ahead(pipeline_run* r, int steps, int* vanished) {
    const long offset = r->progress ? r->progress->step_offset : 0;
    mlb_geometry_net* net = &r->geo;
    memset(net->adam_m, 0, sizeof(float) * net->n_params);
    memset(net->adam_v, 0, sizeof(float) * net->n_params);
    net->step = 0;
    *vanished = 0;
    mlb_adam_config adam = mlb_geometry_adam(r->c->geometry_lr);
    int n = r->g->n_views;
    mlb_view* views = calloc((size_t)n, sizeof *views);
    mlb_geofit_state st;
    memset(&st, 0, sizeof st);
    st.be = pipeline_stage_table(r);
    mlb_status s = views ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "--init auto: out of memory");
    for (long it = 0; !s && it < steps; it++) {
        mlb_geofit_stats stats;
        s = pipeline_geometry_step(r, &st, &adam, it, views, &stats, NULL);
        if (s && st.surf.n_faces == 0) { *vanished = 1; s = MLB_OK; break; }   // marching tets found no surface
        if (r->progress) {
            r->progress->step_offset = offset;
            mlb_progress_update(r->progress, it + 1, NULL);
        }
    }
    net->active_levels = 0;
    mlb_geofit_state_free(&st);
    free(views);
    return s;
}

void pipeline_field_keep(const mlb_field* f, float* keep, long* step) {
    const size_t np = f->n_params;
    memcpy(keep, f->params, sizeof(float) * np);
    memcpy(keep + np, f->adam_m, sizeof(float) * np);
    memcpy(keep + 2 * np, f->adam_v, sizeof(float) * np);
    *step = f->step;
}

void pipeline_field_restore(mlb_field* f, const float* keep, long step) {
    const size_t np = f->n_params;
    memcpy(f->params, keep, sizeof(float) * np);
    memcpy(f->adam_m, keep + np, sizeof(float) * np);
    memcpy(f->adam_v, keep + 2 * np, sizeof(float) * np);
    f->step = step;
}

void pipeline_paired_difference(const double* a, const double* b, int n, double* mean, double* se) {
    double m = 0, v = 0;
    for (int k = 0; k < n; k++) m += a[k] - b[k];
    m /= n;
    for (int k = 0; k < n; k++) { double d = a[k] - b[k] - m; v += d * d; }
    *mean = m;
    *se = n > 1 ? sqrt(v / (n - 1) / n) : INFINITY;
}

// The candidate the rule picks among those with alive[i] (scores sc [N, n]): the clearest that beats
// the reference by more than z standard errors; -1 when none is alive. mean/se: the paired
// differences against the reference, for the log.
static int pick(const double* sc, int N, int n, const int* alive, double z, double* mean, double* se) {
    int ref = -1, best = -1;
    for (int i = 0; i < N && ref < 0; i++)
        if (alive[i]) ref = best = i;
    for (int i = ref + 1; ref >= 0 && i < N; i++) {
        mean[i] = se[i] = NAN;
        if (!alive[i]) continue;
        pipeline_paired_difference(sc + (size_t)i * n, sc + (size_t)ref * n, n, &mean[i], &se[i]);
        if (mean[i] > z * se[i] && (best == ref || mean[i] / se[i] > mean[best] / se[best])) best = i;
    }
    return best;
}

static void log_scores(const char* when, const char* const* names, const double* sc, int N, int n, const int* alive,
                       const int* vanished, const double* mean, const double* se, int best) {
    char line[1024];
    int len = snprintf(line, sizeof line, "--init auto: %s on %d views:", when, n);
    int ref = -1;
    for (int i = 0; i < N && len < (int)sizeof line; i++) {
        if (vanished && vanished[i]) { len += snprintf(line + len, sizeof line - (size_t)len, " %s vanished;", names[i]); continue; }
        if (!alive[i]) continue;
        double m = 0;
        for (int k = 0; k < n; k++) m += sc[(size_t)i * n + k] / n;
        if (ref < 0) { ref = i; len += snprintf(line + len, sizeof line - (size_t)len, " %s %+.5f;", names[i], m); }
        else len += snprintf(line + len, sizeof line - (size_t)len, " %s %+.5f (%+.5f +- %.5f);", names[i], m, mean[i], se[i]);
    }
    if (best >= 0) mlb_log(MLB_LOG_INFO, "%s best: the %s", line, names[best]);
    else mlb_log(MLB_LOG_INFO, "%s none left", line);
}

mlb_status pipeline_first_views(pipeline_run* r, mlb_stage stage, int want, mlb_view** out, int* n_out) {
    mlb_guidance* g = r->g;
    int per = g->n_views, steps = (want + per - 1) / per, n = steps * per;
    if (n > MLB_SDS_MAX_BATCH) { steps = MLB_SDS_MAX_BATCH / per; n = steps * per; }
    mlb_view* views = calloc((size_t)n, sizeof *views);
    mlb_status s = views ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "the first steps' views: out of memory");
    for (int k = 0; !s && k < steps; k++) {
        s = g->sample_views(g, stage, k, views + (size_t)k * per);
        if (!s && stage == MLB_STAGE_APPEARANCE) s = pipeline_fix_env(r, views + (size_t)k * per, per);
    }
    if (s) { free(views); return s; }
    *out = views;
    *n_out = n;
    return MLB_OK;
}

// The candidates of "auto" or "auto:A,B,..": their number (names[] not touched when NULL).
static int auto_candidates(const char* init, char* list, size_t cap, const char** names) {
    snprintf(list, cap, "%s", init[4] == ':' ? init + 5 : AUTO_DEFAULT);
    int N = 0;
    for (char *save = NULL, *tok = strtok_r(list, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
        if (names && N < AUTO_MAX) names[N] = tok;
        N++;
    }
    return N;
}

long pipeline_shape_start_steps(const mlb_pipeline_config* c) {
    char list[MLB_PIPELINE_PATH];
    long n = mlb_pipeline_init_is_auto(c->init) ? auto_candidates(c->init, list, sizeof list, NULL) : 1;
    return n * c->init_iters;   // the look-ahead's steps are added when it runs
}

mlb_status pipeline_choose_init(pipeline_run* r, int active_levels) {
    const mlb_pipeline_config* c = r->c;
    mlb_guidance* g = r->g;
    mlb_geometry_net* net = &r->geo;
    if (!g->score) return mlb_fail(MLB_ERR_UNSUPPORTED, "--init auto needs score distillation (%s guidance cannot score a shape)", g->kind);
    // the candidates: "auto" or "auto:A,B,.." (names or OBJ files)
    char list[MLB_PIPELINE_PATH];
    const char* names[AUTO_MAX];
    int N = auto_candidates(c->init, list, sizeof list, names);
    if (N > AUTO_MAX) return mlb_fail(MLB_ERR_ARG, "--init %s: more than %d candidates", c->init, AUTO_MAX);
    if (N < 1) return mlb_fail(MLB_ERR_ARG, "--init %s: no candidates", c->init);
    const size_t np = net->n_params;
    mlb_view* views = NULL;
    int n = 0;
    mlb_status s = pipeline_first_views(r, MLB_STAGE_GEOMETRY, AUTO_VIEWS, &views, &n);
    if (s) return mlb_fail_context(s, "--init %s", c->init);
    double* sc = malloc(sizeof(double) * (size_t)n * N);   // [N, n] per-view scores
    // the network as it came (parameters, Adam's moments) and every candidate's fitted parameters
    float* start = malloc(sizeof(float) * 3 * np);
    float* fit = malloc(sizeof(float) * np * N);
    long step0 = net->step;
    s = sc && start && fit ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "--init auto: out of memory");
    if (!s) pipeline_field_keep(net, start, &step0);
    int vanished[AUTO_MAX] = {0}, first, count;
    // Several processes (dist.h): each fits and scores its share of the candidates alone, and every
    // rank gets all the fits and scores; a candidate's work is the same bits on any rank, so the
    // choice is that of one process, in about 1/N of its time
    mlb_dist_share(N, &first, &count);
    int was = mlb_dist_solo(1);
    for (int i = first; !s && i < first + count; i++) {
        pipeline_field_restore(net, start, step0);
        if (r->progress) r->progress->step_offset = (long)i * c->init_iters;
        s = pipeline_init_shape(net, c, names[i], active_levels, r->progress);
        if (!s) memcpy(fit + (size_t)i * np, net->params, sizeof(float) * np);
        net->active_levels = active_levels;
        if (!s) s = score_shape(r, views, n, sc + (size_t)i * n, &vanished[i]);   // (a fit with no surface: out)
        net->active_levels = 0;
    }
    mlb_dist_solo(was);
    s = pipeline_agree(s);
    if (!s) s = mlb_dist_allgather_items(fit + (size_t)first * np, fit, N, sizeof(float) * np);
    if (!s) s = mlb_dist_allgather_items(sc + (size_t)first * n, sc, N, sizeof(double) * (size_t)n);
    if (!s) s = mlb_dist_allgather_items(vanished + first, vanished, N, sizeof(int));
    int alive[AUTO_MAX], best = 0;
    double mean[AUTO_MAX], se[AUTO_MAX];
    for (int i = 0; i < N; i++) alive[i] = !vanished[i];
    if (!s) {
        best = pick(sc, N, n, alive, AUTO_Z_START, mean, se);
        log_scores("the prompt's score", names, sc, N, n, alive, vanished, mean, se, best);
    }
    int ref = 0;
    while (ref < N && !alive[ref]) ref++;
    if (!s && best != ref && best >= 0) {   // the reference and every candidate that beat it, looked ahead
        for (int i = ref + 1; i < N; i++) alive[i] = alive[i] && mean[i] > AUTO_Z_START * se[i];
        int contender[AUTO_MAX], nc = 0;   // shared out as the fits were
        for (int i = 0; i < N; i++)
            if (alive[i]) contender[nc++] = i;
        double* csc = malloc(sizeof(double) * (size_t)n * (size_t)nc);   // [nc, n]
        int cvan[AUTO_MAX] = {0};
        if (!csc) s = mlb_fail(MLB_ERR_NOMEM, "--init auto: out of memory");
        mlb_dist_share(nc, &first, &count);
        mlb_progress_stage_steps(r->progress, (long)N * c->init_iters + (long)nc * AUTO_AHEAD);
        was = mlb_dist_solo(1);
        for (int k = first; !s && k < first + count; k++) {
            memcpy(net->params, fit + (size_t)contender[k] * np, sizeof(float) * np);
            if (r->progress) r->progress->step_offset = (long)N * c->init_iters + (long)k * AUTO_AHEAD;
            s = look_ahead(r, AUTO_AHEAD, &cvan[k]);
            if (!s && !cvan[k]) s = score_shape(r, views, n, csc + (size_t)k * n, &cvan[k]);
        }
        mlb_dist_solo(was);
        s = pipeline_agree(s);
        if (!s) s = mlb_dist_allgather_items(csc + (size_t)first * n, csc, nc, sizeof(double) * (size_t)n);
        if (!s) s = mlb_dist_allgather_items(cvan + first, cvan, nc, sizeof(int));
        for (int k = 0; !s && k < nc; k++) {
            int i = contender[k];
            vanished[i] = cvan[k];
            if (vanished[i]) alive[i] = 0;
            else memcpy(sc + (size_t)i * n, csc + (size_t)k * n, sizeof(double) * (size_t)n);
        }
        free(csc);
        if (!s) {
            best = pick(sc, N, n, alive, AUTO_Z, mean, se);
            char when[64];
            snprintf(when, sizeof when, "after %d steps, the score", AUTO_AHEAD);
            log_scores(when, names, sc, N, n, alive, vanished, mean, se, best);
        }
    }
    if (best < 0) best = 0;   // every one vanished: the default, whose stage then says so
    if (!s) {
        // the chosen fit as --init NAME leaves it (Adam's state, the step: the caller starts them fresh)
        memcpy(net->params, fit + (size_t)best * np, sizeof(float) * np);
        net->step = step0;
        mlb_log(MLB_LOG_INFO, "--init auto: starting from the %s", names[best]);
    }
    free(views);
    free(sc);
    free(start);
    free(fit);
    return s ? mlb_fail_context(s, "--init %s", c->init) : MLB_OK;
}
