// The guidance a run's config asks for (include/matlaber/pipeline.h): score distillation with a
// Stable Diffusion checkpoint, or image guidance from a views folder.
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"
#include "matlaber/caption.h"
#include "matlaber/guidance_image.h"
#include "matlaber/guidance_sds.h"
#include "matlaber/log.h"
#include "matlaber/pipeline.h"
#include "matlaber/sd_model.h"
#include "matlaber/sds.h"

// SDS keeps the models alive beside the guidance: wrap the guidance's destroy.
typedef struct {
    mlb_guidance* inner;
    mlb_sd_model* model;
    mlb_sd_model* appearance_model;   // NULL: the appearance stage is guided by `model` too
} sds_owner;

static mlb_status owner_sample(mlb_guidance* g, mlb_stage stage, long step, mlb_view* views) {
    sds_owner* o = g->impl;
    return o->inner->sample_views(o->inner, stage, step, views);
}

static mlb_status owner_loss(mlb_guidance* g, mlb_stage stage, long step, const mlb_view* views, int n,
                             const float* images, int H, int W, float* dimages, double* loss) {
    sds_owner* o = g->impl;
    return mlb_guidance_loss_part(o->inner, NULL, stage, step, views, g->part_first, n, g->part_total, images, H, W, dimages,
                                  loss);
}

static mlb_status owner_loss_on(mlb_guidance* g, const struct mlb_backend* be, mlb_stage stage, long step,
                                const mlb_view* views, int n, const float* images, int H, int W, float* dimages,
                                double* loss) {
    sds_owner* o = g->impl;
    return mlb_guidance_loss_part(o->inner, be, stage, step, views, g->part_first, n, g->part_total, images, H, W, dimages,
                                  loss);
}

static mlb_status owner_score(mlb_guidance* g, mlb_stage stage, const mlb_view* views, int n, const float* images, int H,
                              int W, const int* t_range, double* per_view) {
    sds_owner* o = g->impl;
    return o->inner->score(o->inner, stage, views, n, images, H, W, t_range, per_view);
}

static void owner_destroy(mlb_guidance* g) {
    sds_owner* o = g->impl;
    mlb_guidance_free(o->inner);
    mlb_sd_model_free(o->model);
    mlb_sd_model_free(o->appearance_model);
    free(o);
    free(g);
}

static mlb_status make_sds(const mlb_pipeline_config* c, const mlb_backend* be, mlb_guidance** out) {
    mlb_sd_model *model = NULL, *app_model = NULL;
    mlb_sd_model_options mo = mlb_sd_model_default_options();
    if (be) {
        mo.device = be->device;
        mo.precision = be->precision;
    }
    if (c->tokenizer[0]) mo.tokenizer_path = c->tokenizer;
    mlb_log(MLB_LOG_INFO, "loading %s", c->model);
    mlb_status s = mlb_sd_model_load(c->model, &mo, &model);
    if (s) return s;
    // a second model for the appearance stage (docs/pipeline.md, "A model per stage")
    if (c->appearance_model[0] && strcmp(c->appearance_model, c->model)) {
        mlb_log(MLB_LOG_INFO, "loading %s for the appearance stage", c->appearance_model);
        s = mlb_sd_model_load(c->appearance_model, &mo, &app_model);
        if (s) { mlb_sd_model_free(model); return mlb_fail_context(s, "the appearance stage's model"); }
    }
    mlb_guidance_sds_config gc = mlb_guidance_sds_default();
    gc.prompt = c->caption[0] ? c->caption : c->prompt;   // the view suffixes follow it
    if (c->negative[0]) gc.negative_geometry = gc.negative_appearance = c->negative;
    gc.views = c->views;
    gc.latent_iters = c->latent_iters >= 0 ? c->latent_iters : c->geometry_iters / 3;
    gc.latent_size = c->latent_size;
    if (c->geometry_t_min > 0) gc.geometry_opt.t_min = c->geometry_t_min;
    if (c->geometry_t_max_end > 0) {
        gc.geometry_opt.t_max_end = c->geometry_t_max_end;
        gc.geometry_opt.anneal_steps = c->geometry_iters;
    }
    if (c->appearance_t_max_end > 0) {
        gc.appearance_opt.t_max_end = c->appearance_t_max_end;
        gc.appearance_opt.anneal_steps = c->appearance_iters;
    }
    gc.view_prompts = c->view_prompts;
    gc.geometry_opt.guidance_scale = (float)c->guidance_scale;
    gc.appearance_opt.guidance_scale = (float)(c->appearance_guidance_scale > 0 ? c->appearance_guidance_scale : c->guidance_scale);
    gc.n_envs = c->n_envs;
    gc.orbit.fixed_env = c->fixed_env;
    gc.seed = c->seed;
    mlb_guidance* inner = NULL;
    s = mlb_guidance_sds_create_staged(model, app_model ? app_model : model, &gc, &inner);
    if (s) { mlb_sd_model_free(model); mlb_sd_model_free(app_model); return s; }
    mlb_sd_model_drop_text(model);   // the embeddings are cached: free the text encoder's memory
    if (app_model) mlb_sd_model_drop_text(app_model);
    mlb_guidance* g = calloc(1, sizeof *g);
    sds_owner* o = calloc(1, sizeof *o);
    if (!g || !o) {
        free(g); free(o);
        mlb_guidance_free(inner);
        mlb_sd_model_free(model);
        mlb_sd_model_free(app_model);
        return mlb_fail(MLB_ERR_NOMEM, "guidance: out of memory");
    }
    o->inner = inner;
    o->model = model;
    o->appearance_model = app_model;
    *g = *inner;   // kind, n_views
    g->sample_views = owner_sample;
    g->loss = owner_loss;
    g->loss_on = o->inner->loss_on ? owner_loss_on : NULL;
    g->score = owner_score;
    g->destroy = owner_destroy;
    g->impl = o;
    *out = g;
    return MLB_OK;
}

mlb_status mlb_pipeline_read_prompt(mlb_pipeline_config* c) {
    c->caption[0] = 0;
    if (strcmp(c->guidance, "sds") || !c->prompt[0]) return MLB_OK;
    if (!mlb_sd_model_is_own(c->model) && !(c->appearance_model[0] && mlb_sd_model_is_own(c->appearance_model)))
        return MLB_OK;   // Stable Diffusion reads any prompt
    mlb_caption_reading r;
    MLB_TRY(mlb_caption_read(c->prompt, &r));
    if (r.view != MLB_SDS_VIEW_NONE)
        return mlb_fail(MLB_ERR_ARG, "'%s' names a view ('%s'): the run adds each view's own to the caption; drop it "
                                     "from the prompt", c->prompt, mlb_sds_view_suffix(r.view) + 2);
    if (r.normal_map)
        return mlb_fail(MLB_ERR_ARG, "'%s' asks for a normal map: the geometry stage adds that to its own model's "
                                     "caption where the model was trained with it; drop it from the prompt", c->prompt);
    snprintf(c->caption, sizeof c->caption, "%s", r.caption);
    if (strcmp(c->caption, c->prompt))
        mlb_log(MLB_LOG_INFO, "the prompt '%s' read as '%s' (the project's own model)", c->prompt, c->caption);
    return MLB_OK;
}

mlb_status mlb_pipeline_make_guidance(const mlb_pipeline_config* c, const mlb_backend* be, mlb_guidance** out,
                                      mlb_views** views_out) {
    *out = NULL;
    if (views_out) *views_out = NULL;
    if (!strcmp(c->guidance, "sds")) return make_sds(c, be, out);
    if (!views_out) return mlb_fail(MLB_ERR_ARG, "image guidance: the caller must keep the views");
    mlb_views* v = calloc(1, sizeof *v);
    if (!v) return mlb_fail(MLB_ERR_NOMEM, "guidance: out of memory");
    mlb_status s = mlb_views_load(v, c->views_dir, c->res);
    mlb_guidance_images_config ic = mlb_guidance_images_default();
    ic.views_per_step = c->views;
    ic.seed = c->seed;
    if (!s) s = mlb_guidance_images_create(v, &ic, out);
    if (s) {
        mlb_views_free(v);
        free(v);
        return s;
    }
    *views_out = v;
    return MLB_OK;
}

void mlb_pipeline_free_views(mlb_views* v) {
    if (!v) return;
    mlb_views_free(v);
    free(v);
}
