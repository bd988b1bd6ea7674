// End-to-end geometry fit to silhouettes and normal maps (include/matlaber/geometry_fit.h,
// docs/geometry_fit.md): defaults, cameras and the fit loop; the differentiable step is
// geometry_fit.c.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"
#include "matlaber/dist.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/rng.h"

enum { STREAM_GEOFIT_CAMERA = 0x6F17 };


mlb_geofit_config mlb_geofit_default(void) {
    mlb_geofit_config c;
    memset(&c, 0, sizeof c);
    c.iters = 300;
    c.views = 2;
    c.res = 64;
    c.ss = 1;
    c.cells = 32;
    c.lr = 1e-2;
    c.w_normal = 1.0;
    c.w_mask = 1.0;
    c.sdf_reg = mlb_sdf_reg_default();
    c.radius = MLB_ORBIT_RADIUS;
    c.fovy_deg = MLB_ORBIT_FOVY_MAX;
    c.el_min = MLB_ORBIT_EL_MIN;
    c.el_max = MLB_ORBIT_EL_MAX;
    c.seed = 1;
    return c;
}

mlb_sdf_reg_schedule mlb_sdf_reg_default(void) {
    mlb_sdf_reg_schedule r = {0.2, 0.01, 0.25};
    return r;
}

double mlb_sdf_reg_weight(const mlb_sdf_reg_schedule* r, long it, long iters) {
    double span = r->frac * iters;
    double t = span > 0 ? it / span : 1.0;
    if (t > 1) t = 1;
    return r->start + (r->end - r->start) * t;
}

mlb_status mlb_geofit_camera(mlb_camera* cam, const mlb_geofit_config* c, int it, int view) {
    mlb_u32x4 w = mlb_rng_words(c->seed, STREAM_GEOFIT_CAMERA, (uint64_t)it * (uint64_t)c->views + (uint64_t)view);
    double az = -180.0 + 360.0 * mlb_u32_to_unit(w.v[0]);
    double el = c->el_min + (c->el_max - c->el_min) * mlb_u32_to_unit(w.v[1]);
    return mlb_camera_orbit(cam, az, el, c->radius, NULL, c->fovy_deg, 1.0, MLB_ORBIT_NEAR, MLB_ORBIT_FAR);
}

static mlb_status check_config(const mlb_geofit_config* c) {
    if (c->iters < 0 || c->views < 1 || c->views > 64 || c->res < 4 || c->ss < 1 || c->ss > 8 ||
        c->res * c->ss > MLB_RASTER_MAX_SIZE || c->cells < 1 || c->cells > 512 || !(c->lr > 0) ||
        !(c->sdf_reg.frac >= 0) || !(c->radius > 0))
        return mlb_fail(MLB_ERR_ARG, "geometry fit: bad config (iters %d, views %d, res %d, ss %d, cells %d, lr %g)",
                        c->iters, c->views, c->res, c->ss, c->cells, c->lr);
    return MLB_OK;
}

mlb_status mlb_geometry_fit_images(mlb_geometry_net* net, const mlb_mesh* target, const mlb_geofit_config* c,
                                   mlb_progress* progress, mlb_geofit_step_fn step_fn, void* user,
                                   mlb_geofit_stats* last) {
    mlb_status s = check_config(c);
    if (s) return s;
    if (!target || target->n_faces < 1 || target->n_verts < 3) return mlb_fail(MLB_ERR_ARG, "geometry fit: empty target mesh");
    size_t img = (size_t)c->res * c->res * 4;
    float* targets = malloc(sizeof(float) * img * (size_t)c->views);
    mlb_camera* cams = malloc(sizeof(mlb_camera) * (size_t)c->views);
    mlb_tetgrid g = {0};
    if (!targets || !cams) s = mlb_fail(MLB_ERR_NOMEM, "geometry fit: out of memory");
    if (!s) s = mlb_tetgrid_create(&g, c->cells, net->cfg.scale);
    mlb_adam_config adam = mlb_geometry_adam(c->lr);
    mlb_geofit_stats st;
    memset(&st, 0, sizeof st);
    for (int it = 0; !s && it < c->iters; it++) {
        for (int v = 0; !s && v < c->views; v++) {
            s = mlb_geofit_camera(&cams[v], c, it, v);
            if (!s) s = mlb_geofit_render_mesh(NULL, targets + img * (size_t)v, target, &cams[v], c->res, c->ss);
        }
        if (s) break;
        geometry_net_zero_grad(net);
        s = mlb_geofit_loss(net, &g, cams, c->views, targets, c->res, c->ss, c->w_normal, c->w_mask,
                            mlb_sdf_reg_weight(&c->sdf_reg, it, c->iters), 1, &st);
        if (s) { s = mlb_fail_context(s, "geometry fit, step %d", it); break; }
        geometry_net_update(net, &adam);
        if (progress) {
            char buf[64];
            snprintf(buf, sizeof buf, "loss %.4g, %d faces", st.loss, st.n_faces);
            mlb_progress_update(progress, it + 1, buf);
        }
        if (step_fn && step_fn(user, it, &st)) break;
    }
    if (last) *last = st;
    mlb_tetgrid_free(&g);
    free(cams);
    free(targets);
    return s;
}


mlb_status mlb_geofit_state_mesh(const mlb_geofit_state* st, mlb_mesh* out) {
    if (!st || !st->ok || !out) return mlb_fail(MLB_ERR_ARG, "geometry step: no surface held (run a forward first)");
    if (st->surf.pos || !st->mt) return mt_surface_to_mesh(&st->surf, out);
    mlb_mt_surface host;   // the surface stayed on the table (mlb_mt_device_forward, MLB_MT_TABLE): down now
    MLB_TRY(mlb_mt_device_surface_host(st->mt, &host));
    mlb_status s = mt_surface_to_mesh(&host, out);
    mt_surface_free(&host);
    return s;
}

mlb_status mlb_geometry_guided_step(mlb_geofit_state* st, mlb_geometry_net* net, const mlb_tetgrid* grid,
                                    mlb_guidance* g, long step, const mlb_view* views, int res, int ss, double reg_weight,
                                    mlb_geofit_stats* stats, float* images_out) {
    mlb_geofit_stats local;
    if (!stats) stats = &local;
    memset(stats, 0, sizeof *stats);
    if (!st || !net || !grid || !g || !g->loss || !views || g->n_views < 1)
        return mlb_fail(MLB_ERR_ARG, "geometry step: bad arguments (NULL state, network, grid, guidance or views)");
    int n = g->n_views;
    // This process's views (dist.h): whole micro-batches of g->view_batch views, one guidance call
    // each (the same calls on any number of processes); the backward gathers the rest
    const int k = mlb_guidance_batch(g, n), nb = (n + k - 1) / k;
    int v0 = 0, cnt = n;
    mlb_dist_share_batches(n, k, &v0, &cnt);
    st->part_first = v0;
    st->part_count = mlb_dist_size() > 1 ? (cnt > 0 ? cnt : -1) : 0;
    st->part_batch = k;
    // A guidance that reads renders where they are (loss_on) gets them on the stage's table: no
    // image crosses to the host, only the previews when asked
    const mlb_backend* tb = st->be ? st->be : mlb_backend_cpu();
    st->images_on_table = g->loss_on != NULL;
    mlb_camera* cams = malloc(sizeof(mlb_camera) * (size_t)n);
    size_t img = (size_t)res * res * 4, N = (size_t)n * img;
    float* dimages = st->images_on_table ? NULL : calloc(N ? N : 1, sizeof(float));
    double* losses = calloc((size_t)nb, sizeof(double));   // one per batch
    mlb_status s = cams && (dimages || st->images_on_table) && losses ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "geometry step: out of memory");
    if (!s) {
        for (int v = 0; v < n; v++) cams[v] = views[v].cam;
        geometry_net_zero_grad(net);
        s = mlb_geofit_forward(st, net, grid, cams, n, res, ss, NULL, stats);
    }
    if (!s && st->images_on_table)
        s = mlb_guidance_loss_batches(g, tb, MLB_STAGE_GEOMETRY, step, views, n, v0, cnt, st->t_images, res, res,
                                      st->t_dimages, losses);
    else if (!s)
        s = mlb_guidance_loss_batches(g, NULL, MLB_STAGE_GEOMETRY, step, views, n, v0, cnt, st->images, res, res, dimages,
                                      losses);
    // every rank takes part in the gathers whatever happened here; a failure is agreed on at the step's end
    if (st->part_count != 0) {   // the batches' losses, shared as the batches are
        mlb_status gs = mlb_dist_allgather_items(losses + v0 / k, losses, nb, sizeof(double));
        if (!s) s = gs;
    }
    if (!s || st->ok) {
        mlb_status bs = st->images_on_table ? mlb_geofit_backward_table(st, net, reg_weight)
                                            : mlb_geofit_backward(st, net, dimages, reg_weight);
        if (!s) s = bs;
    }
    if (images_out && st->ok) {   // previews: every view's render (gathered only when asked)
        if (st->images_on_table && cnt > 0) {   // this process's views come down
            mlb_status ds = tb->download(st->images + img * (size_t)v0, st->t_images + img * (size_t)v0, img * (size_t)cnt);
            if (!s) s = ds;
        }
        mlb_status gs = st->part_count != 0 ? mlb_dist_allgather_batches(st->images + img * (size_t)v0, st->images, n, k,
                                                                         img * sizeof(float))
                                            : MLB_OK;
        if (!s) s = gs;
        memcpy(images_out, st->images, sizeof(float) * N);
    }
    if (!s) {
        double loss = 0;
        for (int b = 0; b < nb; b++) loss += losses[b];   // in view order
        stats->img = loss;
        stats->loss = loss + reg_weight * stats->reg;
    } else
        s = mlb_fail_context(s, "geometry step %ld", step);
    free(cams);
    free(dimages);
    free(losses);
    return s;
}
