// The geometry stage's starting shape (docs/pipeline.md, Init): the SDF network fitted to an
// ellipsoid, a cylinder, a torus, a slab or the user's mesh, or (--init auto) to whichever of the
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
    } else if (!mlb_shape_builtin(&shape, init, 1.0f)) {   // cylinder, torus, slab: else a file
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

// --init auto: each candidate is fitted and rendered as the geometry stage's first steps see it
// (their views, at least AUTO_VIEWS of them) and scored by the guidance per view (guidance.h,
// score: how much better the prompt explains a render than the unconditional text does). The first
// candidate (the ellipsoid unless --init auto:A,B,.. names others) is the default; another replaces
// it only when its score beats the first's by more than AUTO_Z standard errors of the paired
// per-view differences (the views' draws are shared, so the difference is the shapes'), the
// clearest such win if several do. 3, not 2: the views of one shape are not independent draws, and
// the best of several candidates is taken. Each fit starts from the network's state as it came, so
// the start is the same bits as --init NAME. No cylinder by default: the model prefers it for
// bottles, mugs and bowls, and a bottle from it ended a vase (docs/benchmarks.md, "Choosing the
// starting shape"). No slab by default either: every table comes out a table from it (1 of 8
// from the ellipsoid) and at seed 0 the model picks it for just the tables and three bowls, but
// other seeds' draws (views, noise) give it mugs and stools too (at seed 3 every mug picks it,
// and a mug from it lost its surface), and on views spread evenly over the orbit a green mug
// takes it at every seed: a look alone cannot tell which start will grow (docs/benchmarks.md,
// "A slab start for tables").
#define AUTO_VIEWS 16
#define AUTO_Z 3.0
#define AUTO_MAX 8
static const char* const AUTO_DEFAULT = "ellipsoid,torus";

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

mlb_status pipeline_choose_init(pipeline_run* r, int active_levels) {
    const mlb_pipeline_config* c = r->c;
    mlb_guidance* g = r->g;
    mlb_geometry_net* net = &r->geo;
    if (!g->score) return mlb_fail(MLB_ERR_UNSUPPORTED, "--init auto needs score distillation (%s guidance cannot score a shape)", g->kind);
    // the candidates: "auto" or "auto:A,B,.." (names or OBJ files)
    char list[MLB_PIPELINE_PATH];
    const char* names[AUTO_MAX];
    int N = 0;
    snprintf(list, sizeof list, "%s", c->init[4] == ':' ? c->init + 5 : AUTO_DEFAULT);
    for (char *save = NULL, *tok = strtok_r(list, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
        if (N == AUTO_MAX) return mlb_fail(MLB_ERR_ARG, "--init %s: more than %d candidates", c->init, AUTO_MAX);
        names[N++] = tok;
    }
    if (N < 1) return mlb_fail(MLB_ERR_ARG, "--init %s: no candidates", c->init);
    int per = g->n_views, steps = (AUTO_VIEWS + per - 1) / per, n = steps * per;
    if (n > MLB_SDS_MAX_BATCH) { steps = MLB_SDS_MAX_BATCH / per; n = steps * per; }
    const size_t np = net->n_params;
    mlb_view* views = calloc((size_t)n, sizeof *views);
    double* sc = malloc(sizeof(double) * (size_t)n * N);   // [N, n] per-view scores
    // the network as it came (parameters, Adam's moments) and the leading candidate's parameters
    float* start = malloc(sizeof(float) * 3 * np);
    float* lead = malloc(sizeof(float) * np);
    const long step0 = net->step;
    mlb_status s = views && sc && start && lead ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "--init auto: out of memory");
    if (!s) {
        memcpy(start, net->params, sizeof(float) * np);
        memcpy(start + np, net->adam_m, sizeof(float) * np);
        memcpy(start + 2 * np, net->adam_v, sizeof(float) * np);
    }
    for (int k = 0; !s && k < steps; k++) s = g->sample_views(g, MLB_STAGE_GEOMETRY, k, views + (size_t)k * per);
    int best = 0;
    double mean[AUTO_MAX] = {0}, se[AUTO_MAX] = {0};
    for (int i = 0; !s && i < N; i++) {
        memcpy(net->params, start, sizeof(float) * np);
        memcpy(net->adam_m, start + np, sizeof(float) * np);
        memcpy(net->adam_v, start + 2 * np, sizeof(float) * np);
        net->step = step0;
        s = pipeline_init_shape(net, c, names[i], active_levels);
        net->active_levels = active_levels;
        if (!s) s = score_shape(r, views, n, sc + (size_t)i * n);
        net->active_levels = 0;
        if (s) break;
        // the paired differences against the first candidate: mean and standard error
        double m = 0, v = 0;
        for (int k = 0; k < n; k++) m += sc[(size_t)i * n + k] - sc[k];
        m /= n;
        for (int k = 0; k < n; k++) { double d = sc[(size_t)i * n + k] - sc[k] - m; v += d * d; }
        mean[i] = m;
        se[i] = n > 1 ? sqrt(v / (n - 1) / n) : INFINITY;
        if (i == 0 || (mean[i] > AUTO_Z * se[i] && (best == 0 || mean[i] / se[i] > mean[best] / se[best]))) {
            best = i;
            memcpy(lead, net->params, sizeof(float) * np);
        }
    }
    if (!s) {
        // the chosen fit as --init NAME leaves it (Adam's state after the fit is dropped by the caller)
        memcpy(net->params, lead, sizeof(float) * np);
        char line[1024];
        int len = 0;
        double m0 = 0;
        for (int k = 0; k < n; k++) m0 += sc[k] / n;
        len += snprintf(line, sizeof line, "%s %+.5f", names[0], m0);
        for (int i = 1; i < N && len < (int)sizeof line; i++)
            len += snprintf(line + len, sizeof line - (size_t)len, ", %s %+.5f (%+.5f +- %.5f)", names[i], m0 + mean[i],
                            mean[i], se[i]);
        mlb_log(MLB_LOG_INFO, "--init auto: the prompt's score on %d views: %s; starting from the %s", n, line, names[best]);
    }
    free(views);
    free(sc);
    free(start);
    free(lead);
    return s ? mlb_fail_context(s, "--init %s", c->init) : MLB_OK;
}
