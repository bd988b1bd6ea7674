// One guided step of the appearance stage (paper §3.4): the step's views and lights, each of this
// process's view batches rendered, guided and backpropagated through the material network with its
// share of the smoothness term, the batches' gradients and losses summed in batch order across the
// processes, then AdamW. The stage's loop, checkpoints and reports: pipeline.c.
#include <stdlib.h>
#include <string.h>
#include "matlaber/dist.h"
#include "matlaber/log.h"
#include "matlaber/paint.h"
#include "matlaber/shade.h"
#include "pipeline/pipeline_internal.h"

mlb_status pipeline_appearance_begin(pipeline_run* r, pipeline_appearance* a) {
    const mlb_pipeline_config* c = r->c;
    mlb_material_net* net = &r->mat;
    memset(a, 0, sizeof *a);
    a->n = r->g->n_views;
    a->img = (size_t)c->res * c->res * 4;
    a->views = calloc((size_t)a->n, sizeof *a->views);
    a->images = malloc(sizeof(float) * a->img * (size_t)a->n);
    a->dimages = malloc(sizeof(float) * a->img * (size_t)a->n);
    a->pts = malloc(sizeof(float) * 3 * PIPELINE_SMOOTH_POINTS);
    // the renderer, the material network, its optimiser and the shading on the run's field table (a
    // GPU's): only the mesh and the cameras go up, the images come down
    a->app.be = pipeline_stage_table(r);
    // a guidance that reads renders where they are gets them on that table (only previews come down)
    a->app.images_on_table = r->g->loss_on != NULL;
    a->atb = a->app.be ? a->app.be : mlb_backend_cpu();
    if (!a->views || !a->images || !a->dimages || !a->pts) return mlb_fail(MLB_ERR_NOMEM, "appearance stage: out of memory");
    // this process's views (dist.h): whole micro-batches of the config's view_batch views, one
    // guidance call each, the same calls on any number of processes. Each batch is rendered, guided
    // and backpropagated on its own (the material network over its samples only, with its share of
    // the smoothness points), into a gradient of its own; the batches' gradients are then summed in
    // batch order on every process (mlb_dist_sum_batches), so every process takes the same AdamW
    // step and the bits depend on the batch size, not on the number of processes. One batch (the
    // default) on one process is the gradient as it always was: nothing is copied or summed.
    a->k = mlb_guidance_batch(r->g, a->n);
    a->nb = (a->n + a->k - 1) / a->k;
    a->smooth_on = c->w_mat > 0 || c->w_mat_spec > 0;
    a->support_on = c->material_support > 0 && c->material == MLB_MATERIAL_LATENT;
    a->v0 = 0, a->cnt = a->n, a->b0 = 0, a->bc = a->nb;
    mlb_dist_share_batches(a->n, a->k, &a->v0, &a->cnt);
    mlb_dist_share(a->nb, &a->b0, &a->bc);   // the same batches, counted in batches
    a->sum_grads = a->nb > 1 || mlb_dist_size() > 1;
    // this process's batches' gradients [bc, n_params] where they cannot stay in net->grads (one batch
    // on the host: the sum reads it there and writes the total over it)
    const int own_in_place = a->bc == 1 && !mlb_field_backend(net);
    if (a->sum_grads && a->bc > 0 && !own_in_place) {
        a->mine = malloc(sizeof(float) * net->n_params * (size_t)a->bc);
        if (!a->mine)
            return mlb_fail(MLB_ERR_NOMEM, "appearance stage: out of memory (%d gradients of %zu parameters)", a->bc, net->n_params);
    }
    a->losses = calloc(2 * (size_t)a->nb, sizeof(double));   // per batch: guidance, smoothness
    if (!a->losses) return mlb_fail(MLB_ERR_NOMEM, "appearance stage: out of memory");
    // the shading's split-sum table, built once per process on first use (about 0.75 CPU s on the
    // benchmark machine): before the stage's clock, so that its report's work per step is the steps'
    if (!mlb_splitsum_lut()) return mlb_fail_context(MLB_ERR_NOMEM, "appearance stage");
    return MLB_OK;
}

void pipeline_appearance_end(pipeline_appearance* a) {
    mlb_appearance_free(&a->app);
    free(a->views);
    free(a->images);
    free(a->dimages);
    free(a->pts);
    free(a->losses);
    free(a->mine);
    memset(a, 0, sizeof *a);
}

// Batch b of the step (views f .. f+m-1): render, guide, backpropagate, its smoothness share; its
// gradient into a->mine's slot j when the batches are summed from there.
static mlb_status appearance_batch(pipeline_run* r, pipeline_appearance* a, long it, int j) {
    const mlb_pipeline_config* c = r->c;
    mlb_material_net* net = &r->mat;
    const int n = a->n, b = a->b0 + j, f = b * a->k, m = n - f < a->k ? n - f : a->k;
    material_net_zero_grad(net);
    a->app.part_first = f;
    a->app.part_count = m;
    mlb_status s = mlb_appearance_render(&a->app, net, &r->scene.mesh, r->scene.light_ptrs, a->views, n, c->res, c->ss,
                                         a->app.images_on_table ? NULL : a->images, 1);
    if (!s && a->app.images_on_table) {
        s = mlb_guidance_loss_batches(r->g, a->atb, MLB_STAGE_APPEARANCE, it, a->views, n, f, m, a->app.t_images, c->res,
                                      c->res, a->app.t_dimages, a->losses);
        if (!s) s = mlb_appearance_backward_table(&a->app, net);
    } else if (!s) {
        s = mlb_guidance_loss_batches(r->g, NULL, MLB_STAGE_APPEARANCE, it, a->views, n, f, m, a->images, c->res, c->res,
                                      a->dimages, a->losses);
        if (!s) s = mlb_appearance_backward(&a->app, net, a->dimages);
    }
    int p0, pc;
    mlb_dist_share_of(PIPELINE_SMOOTH_POINTS, b, a->nb, &p0, &pc);
    double smooth = 0, support = 0;
    if (!s && a->smooth_on)
        s = mlb_material_smoothness_part(net, a->pts, PIPELINE_SMOOTH_POINTS, p0, pc, c->mat_sigma, c->w_mat, c->w_mat_spec,
                                         c->seed, it, 1, &smooth);
    if (!s && a->support_on)   // the same points: the codes kept inside the prior's support
        s = mlb_material_latent_support_part(net, a->pts, PIPELINE_SMOOTH_POINTS, p0, pc, c->material_support_radius,
                                             c->material_support, 1, &support);
    a->losses[a->nb + b] = smooth + support;   // the regulariser's column
    if (!s && a->mine) s = mlb_field_grads_get(net, a->mine + net->n_params * (size_t)j);
    return s;
}

mlb_status pipeline_appearance_step(pipeline_run* r, pipeline_appearance* a, const mlb_adam_config* adam, long it,
                                    int preview, double* loss, double* smooth) {
    const mlb_pipeline_config* c = r->c;
    mlb_material_net* net = &r->mat;
    const int n = a->n, paint_images = c->paint_mesh[0] && !strcmp(c->guidance, "images");
    mlb_status s = r->g->sample_views(r->g, MLB_STAGE_APPEARANCE, it, a->views);
    if (!s) s = pipeline_fix_env(r, a->views, n);
    // paint with image guidance: the views were taken of the mesh as given; move their cameras
    // into the frame the mesh was moved into (SDS cameras are the frame's own)
    for (int i = 0; !s && paint_images && i < n; i++)
        s = mlb_paint_frame_camera(c->paint_centre, c->paint_scale, &a->views[i].cam);
    if (!s && a->cnt > 0 && !a->app.images_on_table)
        memset(a->dimages + a->img * (size_t)a->v0, 0, sizeof(float) * a->img * (size_t)a->cnt);
    if (!s && (a->smooth_on || a->support_on) && a->bc > 0)   // every process draws the same points, each takes its batches' share
        s = mlb_mesh_sample_surface(&r->scene.mesh, a->pts, PIPELINE_SMOOTH_POINTS, c->seed, 0x5300000000ull + (uint64_t)it);
    for (int j = 0; !s && j < a->bc; j++) s = appearance_batch(r, a, it, j);
    if (!s && a->app.images_on_table && a->cnt > 0 && preview)   // this process's renders down for the previews
        s = a->atb->download(a->images + a->img * (size_t)a->v0, a->app.t_images + a->img * (size_t)a->v0, a->img * (size_t)a->cnt);
    s = pipeline_agree(s);   // the collectives below need every rank
    if (!s && a->sum_grads) {
        s = mlb_dist_sum_batches(a->mine ? a->mine : net->grads, net->grads, net->n_params, a->nb);
        if (!s && mlb_field_backend(net)) s = mlb_field_grads_set(net, net->grads);
    }
    const int nb = a->nb, b0 = a->b0;   // the batches' losses, shared as the batches are
    *loss = *smooth = 0;
    if (!s && mlb_dist_size() > 1) s = mlb_dist_allgather_items(a->losses + b0, a->losses, nb, sizeof(double));
    if (!s && mlb_dist_size() > 1) s = mlb_dist_allgather_items(a->losses + nb + b0, a->losses + nb, nb, sizeof(double));
    for (int b = 0; !s && b < nb; b++) { *loss += a->losses[b]; *smooth += a->losses[nb + b]; }   // in batch order
    if (!s && mlb_dist_size() > 1 && preview)   // previews: every view's render
        s = mlb_dist_allgather_batches(a->images + a->img * (size_t)a->v0, a->images, n, a->k, a->img * sizeof(float));
    if (!s) s = material_net_update(net, adam);
    return pipeline_agree(s);
}
