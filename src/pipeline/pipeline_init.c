// The geometry stage's starting shape (docs/pipeline.md, Init): the SDF network fitted to an
// ellipsoid, a cylinder, a torus or the user's mesh, or (--init auto) to whichever of the
// primitives the guidance's model finds most like the prompt.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/geometry_fit.h"
#include "matlaber/log.h"
#include "matlaber/obj.h"
#include "matlaber/sds.h"
#include "pipeline/pipeline_internal.h"

mlb_status pipeline_init_shape(mlb_geometry_net* net, const mlb_pipeline_config* c, const char* init, int active_levels) {
    mlb_shape shape;
    memset(&shape, 0, sizeof shape);
    mlb_status s = MLB_OK;
    if (!strcmp(init, "ellipsoid")) {
        // a sphere of radius 0.5 (semi-axes 0.5): inside every target placed in the unit sphere, so
        // the geometry stage grows it outward (docs/pipeline.md, Init)
        const float axes[3] = {0.5f, 0.5f, 0.5f};
        mlb_shape_ellipsoid(&shape, 1.0f, axes);
    } else if (!strcmp(init, "cylinder")) {
        mlb_shape_cylinder(&shape, 1.0f);
    } else if (!strcmp(init, "torus")) {
        mlb_shape_torus(&shape, 1.0f);
    } else {
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
    double final_loss = 0;
    net->active_levels = active_levels;   // the initial shape in the levels step 0 sees
    s = mlb_geometry_fit_shape(net, &shape, &fc, NULL, &final_loss);
    net->active_levels = 0;
    mlb_shape_free(&shape);
    if (!s) mlb_log(MLB_LOG_INFO, "shape init (%s): SDF MSE %.3g after %d steps", init, final_loss, fc.iters);
    return s;
}

// --init auto: each primitive is fitted and rendered as the geometry stage's first steps see it
// (their views, at least AUTO_VIEWS of them) and scored by the guidance per view (guidance.h,
// score: how much better the prompt explains a render than the unconditional text does). The first
// candidate, the ellipsoid, is the default; another replaces it only when its score beats the
// ellipsoid's by more than AUTO_Z standard errors of the paired per-view differences (the views'
// draws are shared, so the difference is the shapes'), the clearest such win if several do. 3, not
// 2: the views of one shape are not independent draws, and the best of several candidates is
// taken. The chosen one is fitted again from the network's starting state: the same bits as --init
// NAME. No cylinder: the model prefers it for bottles, mugs and bowls, and a bottle from it ended a
// vase (docs/benchmarks.md, "Choosing the starting shape").
#define AUTO_VIEWS 16
#define AUTO_Z 3.0
static const char* const AUTO_CANDIDATES[] = {"ellipsoid", "torus"};
#define N_AUTO (int)(sizeof AUTO_CANDIDATES / sizeof AUTO_CANDIDATES[0])

static mlb_status score_shape(pipeline_run* r, const mlb_view* views, int n, double* per_view) {
    const mlb_pipeline_config* c = r->c;
    mlb_camera* cams = malloc(sizeof(mlb_camera) * (size_t)n);
    if (!cams) return mlb_fail(MLB_ERR_NOMEM, "--init auto: out of memory");
    for (int v = 0; v < n; v++) cams[v] = views[v].cam;
    mlb_geofit_state st;
    memset(&st, 0, sizeof st);
    st.be = r->be;
    mlb_geofit_stats stats;
    mlb_status s = mlb_geofit_forward(&st, &r->geo, &r->grid, r->ctx, cams, n, c->res, c->ss, NULL, &stats);
    if (!s) s = r->g->score(r->g, MLB_STAGE_GEOMETRY, views, n, st.images, c->res, c->res, per_view);
    mlb_geofit_state_free(&st);
    free(cams);
    return s;
}

typedef struct {
    float* p;   // [3, n_params] parameters, Adam's moments
    long step;
} net_state;

static void net_state_put(mlb_geometry_net* net, const net_state* k) {
    const size_t np = net->n_params;
    memcpy(net->params, k->p, sizeof(float) * np);
    memcpy(net->adam_m, k->p + np, sizeof(float) * np);
    memcpy(net->adam_v, k->p + 2 * np, sizeof(float) * np);
    net->step = k->step;
}

mlb_status pipeline_choose_init(pipeline_run* r, int active_levels, const char** chosen) {
    const mlb_pipeline_config* c = r->c;
    mlb_guidance* g = r->g;
    mlb_geometry_net* net = &r->geo;
    *chosen = NULL;
    if (!g->score) return mlb_fail(MLB_ERR_UNSUPPORTED, "--init auto needs score distillation (%s guidance cannot score a shape)", g->kind);
    int per = g->n_views, steps = (AUTO_VIEWS + per - 1) / per, n = steps * per;
    if (n > MLB_SDS_MAX_BATCH) { steps = MLB_SDS_MAX_BATCH / per; n = steps * per; }
    const size_t np = net->n_params;
    mlb_view* views = calloc((size_t)n, sizeof *views);
    double* sc = malloc(sizeof(double) * (size_t)n * N_AUTO);   // [N_AUTO, n] per-view scores
    net_state start = {malloc(sizeof(float) * 3 * np), net->step};
    mlb_status s = views && sc && start.p ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "--init auto: out of memory");
    if (!s) {
        memcpy(start.p, net->params, sizeof(float) * np);
        memcpy(start.p + np, net->adam_m, sizeof(float) * np);
        memcpy(start.p + 2 * np, net->adam_v, sizeof(float) * np);
    }
    for (int k = 0; !s && k < steps; k++) s = g->sample_views(g, MLB_STAGE_GEOMETRY, k, views + (size_t)k * per);
    for (int i = 0; !s && i < N_AUTO; i++) {
        net_state_put(net, &start);
        s = pipeline_init_shape(net, c, AUTO_CANDIDATES[i], active_levels);
        net->active_levels = active_levels;
        if (!s) s = score_shape(r, views, n, sc + (size_t)i * n);
        net->active_levels = 0;
    }
    // the paired differences against the ellipsoid: mean and standard error
    int best = 0;
    double mean[N_AUTO] = {0}, se[N_AUTO] = {0};
    for (int i = 1; !s && i < N_AUTO; i++) {
        double m = 0, v = 0;
        for (int k = 0; k < n; k++) m += sc[(size_t)i * n + k] - sc[k];
        m /= n;
        for (int k = 0; k < n; k++) { double d = sc[(size_t)i * n + k] - sc[k] - m; v += d * d; }
        mean[i] = m;
        se[i] = n > 1 ? sqrt(v / (n - 1) / n) : INFINITY;
        if (mean[i] > AUTO_Z * se[i] && (best == 0 || mean[i] / se[i] > mean[best] / se[best])) best = i;
    }
    if (!s) {
        char line[512];
        int len = 0;
        double m0 = 0;
        for (int k = 0; k < n; k++) m0 += sc[k] / n;
        len += snprintf(line, sizeof line, "ellipsoid %+.5f", m0);
        for (int i = 1; i < N_AUTO && len < (int)sizeof line; i++)
            len += snprintf(line + len, sizeof line - (size_t)len, ", %s %+.5f (%+.5f +- %.5f)", AUTO_CANDIDATES[i],
                            m0 + mean[i], mean[i], se[i]);
        mlb_log(MLB_LOG_INFO, "--init auto: the prompt's score on %d views: %s; starting from the %s", n, line,
                AUTO_CANDIDATES[best]);
        *chosen = AUTO_CANDIDATES[best];
        if (best != N_AUTO - 1) {   // the network holds the last candidate: fit the chosen one again
            net_state_put(net, &start);
            s = pipeline_init_shape(net, c, *chosen, active_levels);
        }
    }
    free(views);
    free(sc);
    free(start.p);
    return s ? mlb_fail_context(s, "--init auto") : MLB_OK;
}
