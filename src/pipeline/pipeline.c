// The two-stage pipeline's loop (include/matlaber/pipeline.h, docs/pipeline.md): shape init,
// geometry stage, appearance stage, checkpoints and resume. Outputs: pipeline_output.c.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/brdf_ae.h"
#include "matlaber/dmtet.h"
#include "matlaber/envmap.h"
#include "matlaber/fileio.h"
#include "matlaber/geometry.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/log.h"
#include "matlaber/obj.h"
#include "matlaber/paint.h"
#include "matlaber/pipeline.h"
#include "matlaber/run_textured.h"
#include "matlaber/run.h"
#include "matlaber/safetensors.h"
#include "pipeline/pipeline_internal.h"

// ---- optimiser state: one safetensors file per stage -----------------------------------------
// A field's "params", "adam_m", "adam_v" as flat F32 [n] and the steps taken in the metadata. Exact
// floats, so a resumed run continues bitwise from where the checkpoint was taken.
static mlb_status pipeline_state_save(const char* path, const mlb_field* f, long step, const char* stage) {
    size_t n = f->n_params;
    mlb_ckpt_tensor t[3] = {{"params", f->params, 1, {(int64_t)n}},
                            {"adam_m", f->adam_m, 1, {(int64_t)n}},
                            {"adam_v", f->adam_v, 1, {(int64_t)n}}};
    mlb_ckpt_meta meta = {0};
    mlb_status s = mlb_ckpt_meta_set_i64(&meta, "step", step);
    if (!s) s = mlb_ckpt_meta_set(&meta, "stage", stage);
    if (!s) s = mlb_checkpoint_save(path, t, 3, &meta);
    mlb_ckpt_meta_free(&meta);
    return s;
}

// Into f (params, moments and its step counter).
static mlb_status pipeline_state_load(const char* path, mlb_field* f, const char* stage) {
    size_t n = f->n_params;
    mlb_ckpt_tensor t[3] = {{"params", f->params, 1, {(int64_t)n}},
                            {"adam_m", f->adam_m, 1, {(int64_t)n}},
                            {"adam_v", f->adam_v, 1, {(int64_t)n}}};
    mlb_ckpt_meta meta = {0};
    mlb_status s = mlb_checkpoint_load(path, t, 3, &meta);
    int64_t k = 0;
    const char* st = s ? NULL : mlb_ckpt_meta_get(&meta, "stage");
    if (!s && (!st || strcmp(st, stage) != 0)) s = mlb_fail(MLB_ERR_FORMAT, "%s: not a %s checkpoint", path, stage);
    if (!s) s = mlb_ckpt_meta_get_i64(&meta, "step", &k);
    if (!s && k < 0) s = mlb_fail(MLB_ERR_FORMAT, "%s: negative step %lld", path, (long long)k);
    mlb_ckpt_meta_free(&meta);
    if (!s) f->step = (long)k;
    return s;
}

// ---- shared helpers ----------------------------------------------------------------------------
// The appearance stage's lights: the views' own environments (image guidance) or the config's pool.
static mlb_status pipeline_scene_init(pipeline_scene* sc, const mlb_pipeline_config* c, const mlb_views* views) {
    memset(sc, 0, sizeof *sc);
    mlb_envlight_options opt;
    memset(&opt, 0, sizeof opt);   // zero fields take the defaults
    opt.face_size = c->cube_size;
    int from_views = views && views->meta.n_envs > 0;
    int n = from_views ? views->meta.n_envs : c->n_envs;
    if (n > MLB_PIPELINE_MAX_ENVS)
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: %d environments (at most %d)", views->dir, n, MLB_PIPELINE_MAX_ENVS);
    mlb_status s = MLB_OK;
    for (int i = 0; !s && i < n; i++) {
        s = from_views ? mlb_views_open_env(views, i, &sc->maps[i], c->env_height)
                       : mlb_envmap_open(&sc->maps[i], c->envs[i], 1.0f, c->env_height, NULL);
        if (!s) s = mlb_envlight_build(&sc->lights[i], &sc->maps[i], &opt);
        if (s) s = mlb_fail_context(s, "environment %d (%s)", i, from_views ? "of the views" : c->envs[i]);
        sc->n_envs = i + 1;
        sc->light_ptrs[i] = &sc->lights[i];
    }
    return s;
}

// Coarse-to-fine hash grid: the first COARSE_LEVELS levels from the start, one more level at a time
// until all are active at coarse_to_fine × geometry_iters (0: all levels from the start). 0 = all.
#define COARSE_LEVELS 4
static int active_levels_at(const mlb_pipeline_config* c, const mlb_geometry_net* net, long it) {
    const int L = net->enc.cfg.n_levels;
    const double span = c->coarse_to_fine * c->geometry_iters;
    if (!(span > 0) || L <= COARSE_LEVELS) return 0;
    long a = COARSE_LEVELS + (long)((double)(L - COARSE_LEVELS) * it / span);
    return a >= L ? 0 : (int)a;
}

static void pipeline_scene_free(pipeline_scene* sc) {
    for (int i = 0; i < sc->n_envs; i++) {
        mlb_envlight_free(&sc->lights[i]);
        mlb_envmap_free(&sc->maps[i]);
    }
    mlb_mesh_free(&sc->mesh);
    memset(sc, 0, sizeof *sc);
}

static mlb_status init_shape(mlb_geometry_net* net, const mlb_pipeline_config* c, mlb_progress* progress) {
    mlb_shape shape;
    memset(&shape, 0, sizeof shape);
    mlb_status s = MLB_OK;
    if (!strcmp(c->init, "ellipsoid")) {
        // a sphere of radius 0.5 (semi-axes 0.5): inside every target placed in the unit sphere, so
        // the geometry stage grows it outward (docs/pipeline.md, Init)
        const float axes[3] = {0.5f, 0.5f, 0.5f};
        mlb_shape_ellipsoid(&shape, 1.0f, axes);
    } else if (!strcmp(c->init, "cylinder")) {
        mlb_shape_cylinder(&shape, 1.0f);
    } else {
        mlb_mesh m;
        memset(&m, 0, sizeof m);
        s = mlb_obj_load(c->init, &m);
        if (!s) s = mlb_shape_from_mesh(&shape, &m, 0.8f);
        mlb_mesh_free(&m);
        if (s) return mlb_fail_context(s, "--init %s", c->init);
    }
    mlb_shape_fit_config fc = mlb_shape_fit_default();
    fc.iters = c->init_iters;
    fc.seed = c->seed + 1;
    double final_loss = 0;
    net->active_levels = active_levels_at(c, net, 0);   // the initial shape in the levels step 0 sees
    s = mlb_geometry_fit_shape(net, &shape, &fc, progress, &final_loss);
    net->active_levels = 0;
    mlb_shape_free(&shape);
    if (!s) mlb_log(MLB_LOG_INFO, "shape init (%s): SDF MSE %.3g after %d steps", c->init, final_loss, fc.iters);
    return s;
}

static double reg_weight(const mlb_pipeline_config* c, long it) {
    double span = c->reg_frac * c->geometry_iters;
    double t = span > 0 ? it / span : 1.0;
    if (t > 1) t = 1;
    return c->reg_start + (c->reg_end - c->reg_start) * t;
}

static const char* const LOG_COLUMNS[] = {"guidance", "regulariser", "faces"};

// ---- what both stages share: their optimiser state, resume and the end of a step ----------------
typedef struct {
    mlb_stage stage;
    const char* name;            // "geometry" / "appearance": checkpoint file and metadata
    mlb_field* field;            // the stage's network: parameters, Adam moments, step counter
    long iters;                  // the stage's length
    long progress_offset;        // steps of the stages before this one
    char ckpt[MLB_PIPELINE_PATH + 64];
} stage_state;

static stage_state stage_of(pipeline_run* r, mlb_stage stage) {
    stage_state ss;
    if (stage == MLB_STAGE_GEOMETRY) {
        ss = (stage_state){stage, "geometry", &r->geo, r->c->geometry_iters, 0, {0}};
    } else {
        ss = (stage_state){stage, "appearance", &r->mat, r->c->appearance_iters, r->c->geometry_iters, {0}};
    }
    char rel[64];
    snprintf(rel, sizeof rel, "checkpoints/%s.safetensors", ss.name);
    pipeline_path(ss.ckpt, sizeof ss.ckpt, r->dir, rel);
    return ss;
}

// On resume with a checkpoint: loads it, *start = its step, *found = 1.
static mlb_status stage_resume(pipeline_run* r, stage_state* ss, long* start, int* found) {
    *start = 0;
    *found = r->resume && mlb_is_file(ss->ckpt);
    if (!*found) return MLB_OK;
    mlb_status s = pipeline_state_load(ss->ckpt, ss->field, ss->name);
    if (s) return s;
    *start = ss->field->step;
    // the progress rate (and so the ETA) counts only the steps this invocation takes
    if (r->progress && r->result.geometry_steps + r->result.appearance_steps == 0) r->progress->base = ss->progress_offset + *start;
    mlb_log(MLB_LOG_INFO, "resuming the %s stage at step %ld", ss->name, *start);
    return MLB_OK;
}

// After the optimiser step of iteration it: log row, preview, checkpoint (every checkpoint_every
// steps and at the stage's end), progress. *stop = 1 when stop_after is reached.
static mlb_status stage_end_of_step(pipeline_run* r, stage_state* ss, long it, const double row[3], const float* images,
                                    int n_views, int* stop) {
    const mlb_pipeline_config* c = r->c;
    mlb_status s = mlb_losslog_append(r->log, ss->stage, it, row);
    if (ss->stage == MLB_STAGE_GEOMETRY) {
        r->result.geometry_loss = row[0];
        r->result.geometry_steps++;
    } else {
        r->result.appearance_loss = row[0];
        r->result.appearance_steps++;
    }
    if (!s && c->preview_every > 0 && (it + 1) % c->preview_every == 0) s = pipeline_preview(r, ss->stage, it, images, n_views);
    if (!s && ((it + 1) % c->checkpoint_every == 0 || it + 1 == ss->iters)) {
        s = mlb_field_sync_host(ss->field);   // from the GPU (nothing to do on the host)
        if (!s) s = pipeline_state_save(ss->ckpt, ss->field, it + 1, ss->name);
    }
    pipeline_progress(r, ss->progress_offset + it + 1, row[0], (int)row[2]);
    *stop = !s && pipeline_should_stop(r);
    return s;
}

// ---- geometry stage ----------------------------------------------------------------------------
static mlb_status geometry_stage(pipeline_run* r) {
    const mlb_pipeline_config* c = r->c;
    mlb_geometry_net* net = &r->geo;
    stage_state ss = stage_of(r, MLB_STAGE_GEOMETRY);
    long start = 0;
    int found = 0;
    mlb_status s = stage_resume(r, &ss, &start, &found);
    if (s) return s;
    if (!found) {
        s = init_shape(net, c, NULL);
        if (s) return s;
        // the optimiser starts fresh after the initialisation, which is checkpointed as step 0
        memset(net->adam_m, 0, sizeof(float) * net->n_params);
        memset(net->adam_v, 0, sizeof(float) * net->n_params);
        net->step = 0;
        s = pipeline_state_save(ss.ckpt, net, 0, ss.name);
        if (s) return s;
    }
    r->geometry_start = start;
    if (start >= c->geometry_iters) return MLB_OK;

    mlb_adam_config adam = mlb_geometry_adam(c->geometry_lr);
    int n = r->g->n_views;
    size_t img = (size_t)c->res * c->res * 4;
    mlb_view* views = calloc((size_t)n, sizeof *views);
    float* images = malloc(sizeof(float) * img * (size_t)n);
    mlb_geofit_state st;
    memset(&st, 0, sizeof st);
    if (!views || !images) s = mlb_fail(MLB_ERR_NOMEM, "geometry stage: out of memory");
    for (long it = start; !s && it < c->geometry_iters; it++) {
        net->active_levels = active_levels_at(c, net, it);
        s = r->g->sample_views(r->g, MLB_STAGE_GEOMETRY, it, views);
        mlb_geofit_stats stats;
        if (!s) s = mlb_geometry_guided_step(&st, net, &r->grid, r->ctx, r->g, it, views, c->res, c->ss, reg_weight(c, it),
                                             &stats, images);
        if (s) { s = mlb_fail_context(s, "geometry stage, step %ld", it); break; }
        geometry_net_update(net, &adam);
        double row[3] = {stats.img, stats.reg, stats.n_faces};
        int stop = 0;
        s = stage_end_of_step(r, &ss, it, row, images, n, &stop);
        if (stop) break;
    }
    net->active_levels = 0;   // the surface the appearance stage and the outputs use: every level
    mlb_geofit_state_free(&st);
    free(views);
    free(images);
    return s;
}

// ---- appearance stage --------------------------------------------------------------------------
static mlb_status appearance_stage(pipeline_run* r) {
    const mlb_pipeline_config* c = r->c;
    mlb_material_net* net = &r->mat;
    stage_state ss = stage_of(r, MLB_STAGE_APPEARANCE);
    long start = 0;
    int found = 0;
    mlb_status s = stage_resume(r, &ss, &start, &found);
    if (s) return s;
    if (start >= c->appearance_iters) return MLB_OK;
    if (r->progress && r->result.geometry_steps == 0) r->progress->base = ss.progress_offset + start;   // geometry done before

    mlb_adam_config adam = mlb_material_adam(c->appearance_lr);
    const int paint_images = c->paint_mesh[0] && !strcmp(c->guidance, "images");
    int n = r->g->n_views;
    size_t img = (size_t)c->res * c->res * 4;
    mlb_view* views = calloc((size_t)n, sizeof *views);
    float* images = malloc(sizeof(float) * img * (size_t)n);
    float* dimages = malloc(sizeof(float) * img * (size_t)n);
    enum { SMOOTH_POINTS = 4096 };
    float* pts = malloc(sizeof(float) * 3 * SMOOTH_POINTS);
    mlb_appearance app;
    memset(&app, 0, sizeof app);
    if (!views || !images || !dimages || !pts) s = mlb_fail(MLB_ERR_NOMEM, "appearance stage: out of memory");
    // On a GPU the material network, its optimiser and the shading run there (fp32: the MLP is small)
    if (!s && mlb_device_current() == MLB_DEVICE_CUDA) {
        s = mlb_field_use_device(net, mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32));
        if (!s) mlb_log(MLB_LOG_INFO, "appearance stage: material network and shading on the GPU");
    }
    for (long it = start; !s && it < c->appearance_iters; it++) {
        s = r->g->sample_views(r->g, MLB_STAGE_APPEARANCE, it, views);
        if (!s) s = pipeline_fix_env(r, views, n);
        // paint with image guidance: the views were taken of the mesh as given; move their cameras
        // into the frame the mesh was moved into (SDS cameras are the frame's own)
        for (int i = 0; !s && paint_images && i < n; i++) s = mlb_paint_frame_camera(c->paint_centre, c->paint_scale, &views[i].cam);
        material_net_zero_grad(net);
        if (!s) s = mlb_appearance_render(&app, net, &r->scene.mesh, r->scene.light_ptrs, views, n, c->res, c->ss, images, 1);
        double loss = 0, smooth = 0;
        if (!s) {
            memset(dimages, 0, sizeof(float) * img * (size_t)n);
            s = r->g->loss(r->g, MLB_STAGE_APPEARANCE, it, views, n, images, c->res, c->res, dimages, &loss);
        }
        if (!s) s = mlb_appearance_backward(&app, net, dimages);
        if (!s && (c->w_mat > 0 || c->w_mat_spec > 0)) {
            s = mlb_mesh_sample_surface(&r->scene.mesh, pts, SMOOTH_POINTS, c->seed, 0x5300000000ull + (uint64_t)it);
            if (!s) s = mlb_material_smoothness(net, pts, SMOOTH_POINTS, c->mat_sigma, c->w_mat, c->w_mat_spec, c->seed, it,
                                                1, &smooth);
        }
        if (!s) s = material_net_update(net, &adam);
        if (s) { s = mlb_fail_context(s, "appearance stage, step %ld", it); break; }
        double row[3] = {loss, smooth, r->scene.mesh.n_faces};
        int stop = 0;
        s = stage_end_of_step(r, &ss, it, row, images, n, &stop);
        if (stop) break;
    }
    mlb_appearance_free(&app);
    mlb_status left = mlb_field_leave_device(net);   // the host copy is the result
    if (!s) s = left;
    free(views);
    free(images);
    free(dimages);
    free(pts);
    return s;
}

// ---- the run -----------------------------------------------------------------------------------
// ---- paint: the given mesh instead of the geometry stage -----------------------------------------
// A fresh paint run loads and checks the user's mesh (before anything is written: hostile input ends
// in an error and no folder) and fills in its frame; a resumed one reads the run's own copy.
static mlb_status paint_open(const char* dir, mlb_pipeline_config* pc, int resume, mlb_mesh* input) {
    if (!resume) {
        mlb_paint_mesh_info info;
        mlb_status s = mlb_paint_load_mesh(pc->paint_mesh, pc->paint_keep_uv, input, &info);
        if (!s) s = mlb_paint_frame(input, pc->paint_centre, &pc->paint_scale);
        if (!s)
            mlb_log(MLB_LOG_INFO, "paint: %s: %d vertices, %d faces, %s; frame centre (%.4g, %.4g, %.4g), scale %.4g",
                    pc->paint_mesh, info.n_verts, info.n_faces, info.has_uv ? "its own UVs" : "no UVs (an atlas at export)",
                    pc->paint_centre[0], pc->paint_centre[1], pc->paint_centre[2], pc->paint_scale);
        return s;
    }
    char path[MLB_PIPELINE_PATH + 64];
    pipeline_path(path, sizeof path, dir, "input/mesh.obj");
    mlb_status s = mlb_obj_load(path, input);
    if (!s && !input->normal) s = mlb_mesh_compute_normals(input);
    if (!s && !(pc->paint_scale > 0)) s = mlb_fail(MLB_ERR_FORMAT, "%s/config.json: a paint run without its frame (paint_scale)", dir);
    return s;
}

// The appearance stage's mesh: the input moved into the generation frame (normals unchanged: the
// map is a uniform scale and a shift).
static mlb_status paint_scene_mesh(const mlb_pipeline_config* c, const mlb_mesh* in, mlb_mesh* out) {
    memset(out, 0, sizeof *out);
    size_t V = (size_t)in->n_verts, F = (size_t)in->n_faces;
    out->pos = malloc(sizeof(float) * 3 * V);
    out->normal = malloc(sizeof(float) * 3 * V);
    out->faces = malloc(sizeof(int32_t) * 3 * F);
    if (!out->pos || !out->normal || !out->faces) {
        mlb_mesh_free(out);
        return mlb_fail(MLB_ERR_NOMEM, "paint: out of memory for %zu vertices", V);
    }
    out->n_verts = (int)V;
    out->n_faces = (int)F;
    mlb_paint_to_frame(c->paint_centre, c->paint_scale, in->pos, out->pos, V);
    memcpy(out->normal, in->normal, sizeof(float) * 3 * V);
    memcpy(out->faces, in->faces, sizeof(int32_t) * 3 * F);
    return MLB_OK;
}

mlb_status mlb_pipeline_run(const char* dir, const mlb_pipeline_config* c_in, mlb_guidance* g, const mlb_views* views,
                            int resume, mlb_progress* progress, mlb_pipeline_result* result) {
    mlb_status s = mlb_pipeline_validate(c_in);
    if (s) return s;
    mlb_pipeline_config pc = *c_in;   // a fresh paint run fills in its frame
    const mlb_pipeline_config* c = &pc;
    const int paint = pc.paint_mesh[0] != 0;
    mlb_mesh input;
    memset(&input, 0, sizeof input);
    if (paint) {
        s = paint_open(dir, &pc, resume, &input);
        if (s) return s;
    }
    pipeline_run r;
    memset(&r, 0, sizeof r);
    r.dir = dir;
    r.c = c;
    r.g = g;
    r.views = views;
    r.resume = resume;
    r.progress = progress;
    char path[MLB_PIPELINE_PATH + 64];
    if (resume) s = mlb_run_check_resume(dir);
    else {
        s = mlb_run_create(dir, c->overwrite);
        if (!s) {
            pipeline_path(path, sizeof path, dir, "config.json");
            s = mlb_pipeline_config_save(c, path);
        }
    }
    const char* subdirs[] = {"checkpoints", "previews", "final", "input"};
    for (int i = 0; !s && i < 3 + paint; i++) {
        pipeline_path(path, sizeof path, dir, subdirs[i]);
        s = mlb_mkdir_p(path);
    }
    if (!s && paint && !resume) {
        pipeline_path(path, sizeof path, dir, "input/mesh.obj");
        s = mlb_paint_write_obj(path, &input);
    }
    // where a resumed run restarts: the loss log drops the rows after it
    int resume_stage = -1;   // a fresh log
    long resume_step = 0;
    if (!s && resume) s = pipeline_resume_point(dir, &resume_stage, &resume_step);
    if (!s) {
        pipeline_path(path, sizeof path, dir, "loss.csv");
        s = mlb_losslog_open(&r.log, path, LOG_COLUMNS, 3, resume_stage, resume_step);
    }
    mlb_geometry_config gc = mlb_geometry_default();
    gc.seed = c->seed + 1;
    if (c->hash_log2 > 0) gc.enc.table_size = 1u << c->hash_log2;
    if (!s && !paint) s = geometry_net_init(&r.geo, &gc);
    if (!s && !paint) s = mlb_tetgrid_create(&r.grid, mlb_pipeline_cells(c), gc.scale);
    r.ctx = mlb_raster_ctx_create();
    if (!s && !r.ctx) s = mlb_fail(MLB_ERR_NOMEM, "pipeline: out of memory");
    if (!s && progress)
        mlb_progress_begin(progress, stderr, paint ? "paint" : strcmp(c->guidance, "images") ? "generate" : "fit",
                           (long)c->geometry_iters + c->appearance_iters, "it");

    if (!s && !paint) s = geometry_stage(&r);
    int geometry_done = !s && !r.stopped;
    // the fixed mesh of the appearance stage: the geometry network's surface, extracted, or the
    // painted mesh in the generation frame
    if (geometry_done) s = pipeline_scene_init(&r.scene, c, r.views);
    if (!s && geometry_done && paint) s = paint_scene_mesh(c, &input, &r.scene.mesh);
    if (!s && geometry_done && !paint) s = mlb_geometry_extract(&r.geo, &r.grid, &r.scene.mesh);
    if (!s && geometry_done && !paint) s = mlb_mesh_compute_normals(&r.scene.mesh);
    mlb_brdf_ae prior;
    memset(&prior, 0, sizeof prior);
    if (!s && geometry_done) {
        char source[256];
        s = mlb_brdf_ae_load_default(&prior, source, sizeof source);
        mlb_material_config mc = mlb_material_default();
        mc.mode = c->material;
        mc.seed = c->seed + 2;
        mc.scale = gc.scale;
        mc.enc.table_size = gc.enc.table_size;
        if (!s) s = material_net_init(&r.mat, &mc, &prior);
        if (!s) s = appearance_stage(&r);
    }
    if (!s && geometry_done && !r.stopped) {
        s = pipeline_write_final(&r);
        if (!s && c->export_texture > 0) {   // the same as `matlaber export RUN_DIR -o final/asset.glb`
            mlb_log(MLB_LOG_INFO, "writing %s/final/asset.glb (%d² textures)", dir, c->export_texture);
            pipeline_path(path, sizeof path, dir, "final/asset.glb");
            s = mlb_run_export_glb(dir, c->export_texture, path);
            if (s)   // the run itself is complete (final/): say how to get the asset anyway
                s = mlb_fail_context(s, "writing %s (the run is complete; `matlaber export %s --texture-size N -o "
                                        "FILE.glb` retries with another size)", path, dir);
        }
        if (!s) r.result.finished = 1;
    }
    if (progress && !s) mlb_progress_end(progress, r.result.finished ? "done" : "stopped");
    r.result.n_verts = r.scene.mesh.n_verts;
    r.result.n_faces = r.scene.mesh.n_faces;
    if (result) *result = r.result;
    brdf_ae_free(&prior);
    material_net_free(&r.mat);
    pipeline_scene_free(&r.scene);
    mlb_raster_ctx_free(r.ctx);
    mlb_tetgrid_free(&r.grid);
    geometry_net_free(&r.geo);
    mlb_mesh_free(&input);
    if (r.log) mlb_losslog_close(r.log);
    if (!s) {
        pipeline_path(path, sizeof path, dir, "loss.csv");
        char png[MLB_PIPELINE_PATH + 64];
        pipeline_path(png, sizeof png, dir, "loss.png");
        s = mlb_losslog_plot(path, png);
    }
    return s;
}
