// The two-stage pipeline's loop (include/matlaber/pipeline.h, docs/pipeline.md): shape init,
// geometry stage, appearance stage, checkpoints and resume. Outputs: pipeline_output.c.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include "matlaber/brdf_ae.h"
#include "matlaber/dist.h"
#include "matlaber/dmtet.h"
#include "matlaber/envmap.h"
#include "matlaber/fileio.h"
#include "matlaber/geometry.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/log.h"
#include "matlaber/obj.h"
#include "matlaber/paint.h"
#include "matlaber/pipeline.h"
#include "matlaber/progress.h"
#include "matlaber/run_textured.h"
#include "matlaber/run.h"
#include "matlaber/safetensors.h"
#include "pipeline/pipeline_internal.h"

// ---- optimiser state: one safetensors file per stage -----------------------------------------
// A field's "params", "adam_m", "adam_v" as flat F32 [n] and the steps taken and the stage's learning
// rate in the metadata. Exact floats, so a resumed run continues bitwise from where the checkpoint
// was taken (the rate is the run's own: a metal start lowers the appearance stage's, material_start.c).
static mlb_status pipeline_state_save(const char* path, const mlb_field* f, long step, double lr, const char* stage) {
    size_t n = f->n_params;
    mlb_ckpt_tensor t[3] = {{"params", f->params, 1, {(int64_t)n}},
                            {"adam_m", f->adam_m, 1, {(int64_t)n}},
                            {"adam_v", f->adam_v, 1, {(int64_t)n}}};
    mlb_ckpt_meta meta = {0};
    mlb_status s = mlb_ckpt_meta_set_i64(&meta, "step", step);
    if (!s) s = mlb_ckpt_meta_set(&meta, "stage", stage);
    if (!s) s = mlb_ckpt_meta_set_f64(&meta, "lr", lr);
    if (!s) s = mlb_checkpoint_save(path, t, 3, &meta);
    mlb_ckpt_meta_free(&meta);
    return s;
}

// Into f (params, moments and its step counter); *lr left as it is when the checkpoint has none
// (a checkpoint written by a build that did not store the rate: its rate was always the config's).
static mlb_status pipeline_state_load(const char* path, mlb_field* f, double* lr, const char* stage) {
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
    if (!s && mlb_ckpt_meta_get(&meta, "lr")) {
        double v = 0;
        s = mlb_ckpt_meta_get_f64(&meta, "lr", &v);
        if (!s && !(v > 0 && isfinite(v))) s = mlb_fail(MLB_ERR_FORMAT, "%s: learning rate %g is not a positive number", path, v);
        if (!s) *lr = v;
    }
    mlb_ckpt_meta_free(&meta);
    if (!s) f->step = (long)k;
    return s;
}

// ---- several processes (dist.h) ------------------------------------------------------------------
// Rank 0's parameters, moments and step to every rank.
static mlb_status pipeline_field_bcast(mlb_field* f) {
    if (mlb_dist_size() < 2) return MLB_OK;
    size_t n = f->n_params * sizeof(float);
    int64_t step = f->step;
    mlb_status s = mlb_dist_bcast(f->params, n, 0);
    if (!s) s = mlb_dist_bcast(f->adam_m, n, 0);
    if (!s) s = mlb_dist_bcast(f->adam_v, n, 0);
    if (!s) s = mlb_dist_bcast(&step, sizeof step, 0);
    f->step = (long)step;
    return s;
}

// Every rank computes the same step from the same numbers; on machines whose BLAS kernels round
// differently the replicas would drift apart. At each checkpoint they compare a hash of their
// parameters (8 bytes each) and stop the run if any differs.
static mlb_status pipeline_check_replicas(const mlb_field* f, long it) {
    int size = mlb_dist_size();
    if (size < 2) return MLB_OK;
    uint64_t h = 1469598103934665603ull;
    const unsigned char* b = (const unsigned char*)f->params;
    for (size_t i = 0; i < f->n_params * sizeof(float); i++) h = (h ^ b[i]) * 1099511628211ull;
    uint64_t* all = malloc(sizeof(uint64_t) * (size_t)size);
    if (!all) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    mlb_status s = mlb_dist_allgather_items(&h, all, size, sizeof(uint64_t));
    for (int r = 1; !s && r < size; r++)
        if (all[r] != all[0])
            s = mlb_fail(MLB_ERR_NUMERIC, "step %ld: the parameters of rank %d differ from rank 0's (processes on CPUs whose "
                                          "BLAS kernels round differently? run every rank on one kind of CPU)", it + 1, r);
    free(all);
    return s;
}

// ---- shared helpers ----------------------------------------------------------------------------
// The appearance stage's environments: the views' own (image guidance) or the config's pool, read
// when the run starts (before its folder is made: a file that is not an environment map ends the
// run with nothing written); their lights are built when the stage needs them.
static mlb_status pipeline_scene_open(pipeline_scene* sc, const mlb_pipeline_config* c, const mlb_views* views) {
    memset(sc, 0, sizeof *sc);
    int from_views = views && views->meta.n_envs > 0;
    int n = from_views ? views->meta.n_envs : c->n_envs;
    if (n > MLB_PIPELINE_MAX_ENVS)
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: %d environments (at most %d)", views->dir, n, MLB_PIPELINE_MAX_ENVS);
    mlb_status s = MLB_OK;
    for (int i = 0; !s && i < n; i++) {
        s = from_views ? mlb_views_open_env(views, i, &sc->maps[i], c->env_height)
                       : mlb_envmap_open(&sc->maps[i], c->envs[i], 1.0f, c->env_height, NULL);
        if (s) s = mlb_fail_context(s, "environment %d (%s)", i, from_views ? "of the views" : c->envs[i]);
        sc->n_envs = i + 1;
    }
    return s;
}

static mlb_status pipeline_scene_lights(pipeline_scene* sc, const mlb_pipeline_config* c) {
    mlb_envlight_options opt;
    memset(&opt, 0, sizeof opt);   // zero fields take the defaults
    opt.face_size = c->cube_size;
    mlb_status s = MLB_OK;
    for (int i = 0; !s && i < sc->n_envs; i++) {
        s = mlb_envlight_build(&sc->lights[i], &sc->maps[i], &opt);
        if (s) s = mlb_fail_context(s, "environment %d (%s)", i, sc->maps[i].name);
        sc->light_ptrs[i] = &sc->lights[i];
    }
    return s;
}

// A resumed run's checkpoints, opened and checked (finite, as every load checks) before anything in
// its folder changes: a damaged checkpoint ends the command with the run as it was.
static mlb_status pipeline_check_checkpoints(const char* dir) {
    static const char* const rel[2] = {"checkpoints/geometry.safetensors", "checkpoints/appearance.safetensors"};
    for (int k = 0; k < 2; k++) {
        char path[MLB_PIPELINE_PATH + 64];
        pipeline_path(path, sizeof path, dir, rel[k]);
        if (access(path, F_OK) != 0) continue;   // not there yet (anything there is read: a pipe is refused)
        mlb_safetensors* st = NULL;
        MLB_TRY(mlb_st_open(&st, path));
        mlb_status s = MLB_OK;
        for (size_t i = 0; !s && i < mlb_st_count(st); i++) s = mlb_st_check_finite(st, mlb_st_tensor_at(st, i));
        mlb_st_close(st);
        if (s) return s;
    }
    return MLB_OK;
}

// A fresh run's --init shapes that are files (one, or auto:A,B,..'s), read and checked before its
// folder is made; the fit reads them again when the geometry stage starts.
static mlb_status pipeline_check_init(const mlb_pipeline_config* c) {
    char list[MLB_PIPELINE_PATH];
    snprintf(list, sizeof list, "%s", mlb_pipeline_init_is_auto(c->init) ? (c->init[4] == ':' ? c->init + 5 : "") : c->init);
    for (char *save = NULL, *tok = strtok_r(list, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
        mlb_shape probe;
        memset(&probe, 0, sizeof probe);
        int builtin = !strcmp(tok, "ellipsoid") || mlb_shape_builtin(&probe, tok, 1.0f);
        mlb_shape_free(&probe);
        if (builtin) continue;
        mlb_mesh m;
        mlb_status s = mlb_obj_load(tok, &m);
        if (!s) s = mlb_shape_from_mesh(&probe, &m, 0.8f);
        mlb_shape_free(&probe);
        mlb_mesh_free(&m);
        if (s) return mlb_fail_context(s, "--init %s", tok);
    }
    return MLB_OK;
}

static void pipeline_scene_free(pipeline_scene* sc) {
    for (int i = 0; i < sc->n_envs; i++) {
        mlb_envlight_free(&sc->lights[i]);
        mlb_envmap_free(&sc->maps[i]);
    }
    mlb_mesh_free(&sc->mesh);
    memset(sc, 0, sizeof *sc);
}

static const char* const LOG_COLUMNS[] = {"guidance", "regulariser", "faces"};

static int preview_at(const mlb_pipeline_config* c, long it) { return c->preview_every > 0 && (it + 1) % c->preview_every == 0; }

// A stage's steps per second and what the processes spent in collectives (docs/benchmarks.md,
// "Several processes on one asset"): a log line at the stage's end.
typedef struct { double t0, cpu0; mlb_dist_stats d0; mlb_cuda_transfers x0; } stage_clock;
static double cpu_seconds(void) { return (double)clock() / CLOCKS_PER_SEC; }   // this process, every thread
static stage_clock stage_clock_start(void) {
    return (stage_clock){mlb_now_seconds(), cpu_seconds(), mlb_dist_stats_get(), mlb_cuda_transfers_get()};
}
static void stage_clock_report(const stage_clock* k, const char* stage, long steps) {
    if (steps < 1) return;
    mlb_cuda_transfers x = mlb_cuda_transfers_get();
    if (x.copies > k->x0.copies && mlb_dist_rank() == 0)   // a GPU run: what crossed the bus per step
        mlb_log(MLB_LOG_INFO, "%s stage: host <-> GPU per step: %.0f bytes up, %.0f bytes down in %.1f copies", stage,
                (double)(x.up_bytes - k->x0.up_bytes) / steps, (double)(x.down_bytes - k->x0.down_bytes) / steps,
                (double)(x.copies - k->x0.copies) / steps);
    double t = mlb_now_seconds() - k->t0;
    mlb_dist_stats d = mlb_dist_stats_get();
    // per process: the stages' own CPU time (outside the collectives) and the wall time inside them
    double mine[2] = {(cpu_seconds() - k->cpu0 - (d.cpu_seconds - k->d0.cpu_seconds)) / steps,
                      (d.seconds - k->d0.seconds) / steps};
    double bytes = (double)(d.bytes - k->d0.bytes) / steps;
    int size = mlb_dist_size();
    double all[2 * 64];
    double work_max = mine[0], work_min = mine[0];
    if (size > 1 && size <= 64 && mlb_dist_allgather_items(mine, all, size, sizeof mine) == MLB_OK)
        for (int r = 0; r < size; r++) {
            work_max = all[2 * r] > work_max ? all[2 * r] : work_max;
            work_min = all[2 * r] < work_min ? all[2 * r] : work_min;
        }
    char least[64] = "";
    if (size > 1) snprintf(least, sizeof least, "; the least busy %.3f", work_min);
    if (mlb_dist_rank() == 0)
        mlb_log(MLB_LOG_INFO,
                "%s stage: %ld steps in %.2f s (%.3f steps/s) on %d process%s: work %.3f CPU s per step (the busiest "
                "process%s), rank 0 %.1f ms per step in collectives (waiting included), %.0f bytes received per step",
                stage, steps, t, steps / t, size, size > 1 ? "es" : "", work_max, least, 1e3 * mine[1], bytes);
}

// ---- what both stages share: their optimiser state, resume and the end of a step ----------------
typedef struct {
    mlb_stage stage;
    const char* name;            // "geometry" / "appearance": checkpoint file and metadata
    mlb_field* field;            // the stage's network: parameters, Adam moments, step counter
    double lr;                   // its learning rate: the config's, or (appearance) lowered by a metal start
    long iters;                  // the stage's length
    char ckpt[MLB_PIPELINE_PATH + 64];
} stage_state;

static stage_state stage_of(pipeline_run* r, mlb_stage stage) {
    stage_state ss;
    if (stage == MLB_STAGE_GEOMETRY) {
        ss = (stage_state){stage, "geometry", &r->geo, r->c->geometry_lr, r->c->geometry_iters, {0}};
    } else {
        ss = (stage_state){stage, "appearance", &r->mat, r->c->appearance_lr, r->c->appearance_iters, {0}};
    }
    char rel[64];
    snprintf(rel, sizeof rel, "checkpoints/%s.safetensors", ss.name);
    pipeline_path(ss.ckpt, sizeof ss.ckpt, r->dir, rel);
    return ss;
}

// On resume with a checkpoint: loads it (ss->lr: the rate it was taken at), *start = its step, *found = 1.
// Several processes: rank 0 reads the checkpoint and sends it to the others (no shared file system
// needed for the checkpoints; a run saved by N processes resumes on M).
static mlb_status stage_resume(pipeline_run* r, stage_state* ss, long* start, int* found) {
    *start = 0;
    int head[2] = {r->resume && mlb_is_file(ss->ckpt), MLB_OK};
    if (head[0] && mlb_dist_rank() == 0) head[1] = pipeline_state_load(ss->ckpt, ss->field, &ss->lr, ss->name);
    mlb_status s = mlb_dist_bcast(head, sizeof head, 0);
    if (!s && head[1]) s = mlb_dist_rank() == 0 ? (mlb_status)head[1] : mlb_fail(MLB_ERR_IO, "rank 0 could not read %s", ss->ckpt);
    *found = head[0];
    if (s || !*found) return s;
    s = pipeline_field_bcast(ss->field);
    if (!s) s = mlb_dist_bcast(&ss->lr, sizeof ss->lr, 0);
    if (s) return s;
    *start = ss->field->step;
    mlb_log(MLB_LOG_INFO, "resuming the %s stage at step %ld", ss->name, *start);
    return MLB_OK;
}

// After the optimiser step of iteration it: log row, preview, checkpoint (every checkpoint_every
// steps and at the stage's end), progress. *stop = 1 when stop_after is reached.
static mlb_status stage_end_of_step(pipeline_run* r, stage_state* ss, long it, const double row[3], const float* images,
                                    int n_views, int* stop) {
    const mlb_pipeline_config* c = r->c;
    const int writer = mlb_dist_rank() == 0;   // rank 0 writes the run folder; every rank keeps the same state
    mlb_status s = writer ? mlb_losslog_append(r->log, ss->stage, it, row) : MLB_OK;
    if (ss->stage == MLB_STAGE_GEOMETRY) {
        r->result.geometry_loss = row[0];
        r->result.geometry_steps++;
    } else {
        r->result.appearance_loss = row[0];
        r->result.appearance_steps++;
    }
    if (!s && writer && preview_at(c, it)) s = pipeline_preview(r, ss->stage, it, images, n_views);
    if ((it + 1) % c->checkpoint_every == 0 || it + 1 == ss->iters) {
        mlb_status hs = mlb_field_sync_host(ss->field);   // from the GPU (nothing to do on the host)
        mlb_status rs = pipeline_check_replicas(ss->field, it);   // (a collective: every rank, whatever s)
        if (!s) s = hs ? hs : rs;
        if (!s && writer) s = pipeline_state_save(ss->ckpt, ss->field, it + 1, ss->lr, ss->name);
    }
    if (writer) pipeline_progress(r, it + 1, row[0], (int)row[2]);
    s = pipeline_agree(s);
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
        int levels = pipeline_active_levels_at(c, net, 0);
        mlb_progress_enter(r->progress, PIPELINE_SHAPE_START, 0);
        s = mlb_pipeline_init_is_auto(c->init) ? pipeline_choose_init(r, levels)
                                                  : pipeline_init_shape(net, c, c->init, levels, r->progress);
        if (s) return s;
        // the optimiser starts fresh after the initialisation, which is checkpointed as step 0
        memset(net->adam_m, 0, sizeof(float) * net->n_params);
        memset(net->adam_v, 0, sizeof(float) * net->n_params);
        net->step = 0;
        s = mlb_dist_rank() == 0 ? pipeline_state_save(ss.ckpt, net, 0, ss.lr, ss.name) : MLB_OK;
        s = pipeline_agree(s);
        if (s) return s;
    }
    r->geometry_start = start;
    if (start >= c->geometry_iters) return MLB_OK;
    mlb_progress_enter(r->progress, PIPELINE_GEOMETRY, start);

    mlb_adam_config adam = mlb_geometry_adam(ss.lr);
    int n = r->g->n_views;
    size_t img = (size_t)c->res * c->res * 4;
    mlb_view* views = calloc((size_t)n, sizeof *views);
    float* images = malloc(sizeof(float) * img * (size_t)n);
    mlb_geofit_state st;
    memset(&st, 0, sizeof st);
    st.be = pipeline_stage_table(r);
    if (!views || !images) s = mlb_fail(MLB_ERR_NOMEM, "geometry stage: out of memory");
    // the geometry network, its optimiser and its cache on the stages' table's GPU: only the grid's
    // SDF and deformation come down and their gradients go up (the checkpoints sync the host copy)
    if (!s && r->field_be) {
        s = mlb_field_use_device(net, r->field_be);
        if (!s) mlb_log(MLB_LOG_INFO, "geometry stage: geometry network, renderer and marching tets on the GPU");
    }
    stage_clock clock = stage_clock_start();
    for (long it = start; !s && it < c->geometry_iters; it++) {
        mlb_geofit_stats stats;
        s = pipeline_geometry_step(r, &st, &adam, it, views, &stats, preview_at(c, it) ? images : NULL);
        if (s) { s = mlb_fail_context(s, "geometry stage, step %ld", it); break; }
        double row[3] = {stats.img, stats.reg, stats.n_faces};
        int stop = 0;
        s = stage_end_of_step(r, &ss, it, row, images, n, &stop);
        if (stop) break;
    }
    stage_clock_report(&clock, "geometry", r->result.geometry_steps);
    net->active_levels = 0;   // the surface the appearance stage and the outputs use: every level
    mlb_status left = mlb_field_leave_device(net);   // the host copy is the result
    if (!s) s = left;
    mlb_geofit_state_free(&st);
    free(views);
    free(images);
    return s;
}

// ---- appearance stage --------------------------------------------------------------------------
// trial: NULL for the stage itself; else the first trial->steps steps from the network as it is (a
// material start's tie, material_start.c), with no material start, checkpoint, preview, loss row or
// progress: only r->mat changes.
typedef struct {
    long steps;
    int metal;   // the start is a metal: the metal start's rate
} appearance_trial;

static mlb_status appearance_stage(pipeline_run* r, const appearance_trial* trial) {
    const mlb_pipeline_config* c = r->c;
    mlb_material_net* net = &r->mat;
    stage_state ss = stage_of(r, MLB_STAGE_APPEARANCE);
    long start = 0, end = c->appearance_iters;
    int found = 0;
    mlb_status s = trial ? MLB_OK : stage_resume(r, &ss, &start, &found);
    if (s) return s;
    if (trial && trial->steps < end) end = trial->steps;
    if (start >= end) return MLB_OK;

    int metal = trial ? trial->metal : 0;
    if (!trial && start == 0) {   // before the network goes to a device
        mlb_progress_enter(r->progress, PIPELINE_MATERIAL_START, 0);
        s = pipeline_material_start(r, &metal);
    }
    if (!s && !trial) mlb_progress_enter(r->progress, PIPELINE_APPEARANCE, start);
    if (metal) {
        ss.lr *= c->metal_start_lr_scale;
        if (!trial) mlb_log(MLB_LOG_INFO, "appearance stage: refining the metal start at learning rate %g", ss.lr);
    }
    mlb_adam_config adam = mlb_material_adam(ss.lr);
    if (!s && r->field_be) {
        s = mlb_field_use_device(net, r->field_be);
        if (!s && !trial) mlb_log(MLB_LOG_INFO, "appearance stage: renderer, material network and shading on the GPU");
    }
    pipeline_appearance a = {0};
    if (!s) s = pipeline_appearance_begin(r, &a);
    stage_clock clock = stage_clock_start();
    for (long it = start; !s && it < end; it++) {
        const int preview = !trial && preview_at(c, it);
        double loss = 0, smooth = 0;
        s = pipeline_appearance_step(r, &a, &adam, it, preview, &loss, &smooth);
        if (s) { s = mlb_fail_context(s, "appearance stage, step %ld", it); break; }
        if (trial) continue;
        double row[3] = {loss, smooth, r->scene.mesh.n_faces};
        int stop = 0;
        s = stage_end_of_step(r, &ss, it, row, a.images, a.n, &stop);
        if (stop) break;
    }
    if (!trial) stage_clock_report(&clock, "appearance", r->result.appearance_steps);
    pipeline_appearance_end(&a);
    mlb_status left = mlb_field_leave_device(net);   // the host copy is the result
    return s ? s : left;
}

static mlb_status appearance_trial_run(pipeline_run* r, int metal, long steps) {
    appearance_trial t = {steps, metal};
    return appearance_stage(r, &t);
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
                            const mlb_backend* be, int resume, mlb_progress* progress, mlb_pipeline_result* result) {
    mlb_status s = mlb_pipeline_validate(c_in);
    if (s) return s;
    mlb_pipeline_config pc = *c_in;   // a fresh paint run fills in its frame
    const mlb_pipeline_config* c = &pc;
    const int paint = pc.paint_mesh[0] != 0;
    mlb_mesh input;
    memset(&input, 0, sizeof input);
    if (paint) {
        // every process loads the mesh (and finds the same frame: the load is deterministic), as each
        // reads config.json and the model; a failure on one ends the run on all (no collective waits)
        s = pipeline_agree(paint_open(dir, &pc, resume, &input));
        if (s) {
            mlb_mesh_free(&input);
            return s;
        }
    }
    pipeline_run r;
    memset(&r, 0, sizeof r);
    // every input the run reads is read before its folder is made or changed: the environments, the
    // --init files, a resumed run's checkpoints, the BRDF prior (a failure here leaves nothing
    // behind; docs/files.md)
    mlb_brdf_ae prior;
    memset(&prior, 0, sizeof prior);
    s = pipeline_scene_open(&r.scene, c, views);
    if (!s && !resume && !paint) s = pipeline_check_init(c);
    if (!s && resume && mlb_dist_rank() == 0) s = pipeline_check_checkpoints(dir);
    if (!s) {
        char source[256];
        s = mlb_brdf_ae_load_default(&prior, source, sizeof source);
    }
    s = pipeline_agree(s);
    if (s) {
        pipeline_scene_free(&r.scene);
        brdf_ae_free(&prior);
        mlb_mesh_free(&input);
        return s;
    }
    r.dir = dir;
    r.c = c;
    r.g = g;
    r.appearance_trial = appearance_trial_run;
    g->view_batch = c->view_batch;   // the guidance's calls: micro-batches of the config's size
    r.views = views;
    r.resume = resume;
    r.progress = progress;
    char path[MLB_PIPELINE_PATH + 64];
    // Several processes (dist.h): rank 0 alone creates and writes the run folder; the others hold
    // the same networks and take the same steps
    const int writer = mlb_dist_rank() == 0;
    if (!writer) progress = r.progress = NULL;
    if (writer) {
        if (resume) s = mlb_run_check_resume(dir);
        else {
            s = mlb_run_create(dir, c->overwrite);
            if (!s) {
                pipeline_path(path, sizeof path, dir, "config.json");
                s = mlb_pipeline_config_save(c, path);
            }
        }
        const char* subdirs[] = {"checkpoints", "previews", "final", "input"};   // input: paint's mesh
        for (int i = 0; !s && i < 3 + paint; i++) {
            pipeline_path(path, sizeof path, dir, subdirs[i]);
            s = mlb_mkdir_p(path);
        }
        if (!s && paint && !resume) {   // the run's own copy of the mesh, for resume and export
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
        if (!s && mlb_dist_size() > 1) {
            int n = g->n_views, k = mlb_guidance_batch(g, n), nb = (n + k - 1) / k, size = mlb_dist_size();
            mlb_log(nb < size ? MLB_LOG_WARN : MLB_LOG_INFO,
                    "%d processes: %d views per step in %d batch%s of up to %d (--view-batch), whole batches to each "
                    "process%s", size, n, nb, nb == 1 ? "" : "es", k,
                    nb < size ? ": some have none and only repeat the networks' part (a smaller --view-batch splits the views)"
                              : "");
        }
    }
    s = pipeline_agree(s);
    mlb_geometry_config gc = mlb_geometry_default();
    gc.seed = c->seed + 1;
    if (c->hash_log2 > 0) gc.enc.table_size = 1u << c->hash_log2;
    mlb_pipeline_geometry_hash(c, &gc.enc);
    if (!s && !paint) s = geometry_net_init(&r.geo, &gc);
    if (!s && !paint) s = mlb_tetgrid_create(&r.grid, mlb_pipeline_cells(c), gc.scale);
    // The final renders and the extraction run on the CPU's table (host meshes in, host images out);
    // the stages on field_be's when there is one (pipeline_stage_table)
    r.be = mlb_backend_cpu();
    // The caller's device: on a GPU the material network, its AdamW and the shading run there, in
    // fp32 whatever the table's precision (the MLPs are small)
    r.field_be = be && be->device == MLB_DEVICE_CUDA ? mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32) : NULL;
    if (!s && progress) {
        pipeline_start_sizes starts = {pipeline_shape_start_steps(r.c), pipeline_material_start_steps(&r),
                                       pipeline_material_start_views(&r)};
        pipeline_progress_plan(&r, progress, paint, &starts);
    }

    if (!s && !paint) s = geometry_stage(&r);
    int geometry_done = !s && !r.stopped;
    // the fixed mesh of the appearance stage: the geometry network's surface, extracted (and
    // smoothed: surface_smooth), or the painted mesh in the generation frame
    if (geometry_done) s = pipeline_scene_lights(&r.scene, c);
    if (!s && geometry_done && paint) s = paint_scene_mesh(c, &input, &r.scene.mesh);
    if (!s && geometry_done && !paint) s = mlb_geometry_extract(r.be, &r.geo, &r.grid, &r.scene.mesh);
    if (!s && geometry_done && !paint) s = mlb_mesh_smooth_taubin(&r.scene.mesh, c->surface_smooth, 0.5f, -0.53f);
    if (!s && geometry_done && !paint) s = mlb_mesh_compute_normals(&r.scene.mesh);
    if (!s && geometry_done) {
        mlb_material_config mc = mlb_material_default();
        mc.mode = c->material;
        mc.seed = c->seed + 2;
        mc.scale = gc.scale;
        mc.enc.table_size = gc.enc.table_size;
        s = material_net_init(&r.mat, &mc, &prior);
        r.prior = &prior;
        if (!s) s = appearance_stage(&r, NULL);
    }
    if (!s && geometry_done && !r.stopped) {
        mlb_progress_enter(progress, PIPELINE_EXPORT, 0);
        s = writer ? pipeline_write_final(&r) : MLB_OK;
        mlb_progress_update(progress, 1, NULL);
        if (!s && writer && c->export_texture > 0) {   // the same as `matlaber export RUN_DIR -o final/asset.glb`
            mlb_log(MLB_LOG_INFO, "writing %s/final/asset.glb (%d² textures)", dir, c->export_texture);
            pipeline_path(path, sizeof path, dir, "final/asset.glb");
            s = mlb_run_export_glb(dir, c->export_texture, path);
            if (s)   // the run itself is complete (final/): say how to get the asset anyway
                s = mlb_fail_context(s, "writing %s (the run is complete; `matlaber export %s --texture-size N -o "
                                        "FILE.glb` retries with another size)", path, dir);
        }
        if (!s && writer && c->export_texture > 0) mlb_progress_update(progress, 2, NULL);
        s = pipeline_agree(s);   // the others wait for rank 0's final/
        if (!s) r.result.finished = 1;
    }
    if (progress && !s) mlb_progress_end(progress, r.result.finished ? "done" : "stopped");
    r.result.n_verts = r.scene.mesh.n_verts;
    r.result.n_faces = r.scene.mesh.n_faces;
    if (result) *result = r.result;
    brdf_ae_free(&prior);
    material_net_free(&r.mat);
    pipeline_scene_free(&r.scene);
    mlb_tetgrid_free(&r.grid);
    geometry_net_free(&r.geo);
    mlb_mesh_free(&input);
    if (r.log) mlb_losslog_close(r.log);
    if (!s && writer) {
        pipeline_path(path, sizeof path, dir, "loss.csv");
        char png[MLB_PIPELINE_PATH + 64];
        pipeline_path(png, sizeof png, dir, "loss.png");
        s = mlb_losslog_plot(path, png);
    }
    return s;
}
