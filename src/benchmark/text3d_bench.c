// The text-to-3D benchmark loop (include/matlaber/text3d.h): one generation per catalogue caption
// through the same config path as `matlaber generate`, each in a normal run folder (export and view
// take it), skipped when it already finished and resumed when it stopped, then measured (text3d.c).
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/caption.h"
#include "matlaber/catalogue.h"
#include "matlaber/dist.h"
#include "matlaber/fileio.h"
#include "matlaber/log.h"
#include "matlaber/progress.h"
#include "matlaber/run.h"
#include "matlaber/text3d.h"

static int scaled(int n, double f) {
    long v = lround(n * f);
    return v < 1 ? 1 : (int)v;
}

mlb_status mlb_text3d_base_config(mlb_pipeline_config* c, const char* preset, const char* model, uint64_t seed,
                                  double steps_scale, mlb_material_mode material, int fixed_env, int view_prompts) {
    *c = mlb_pipeline_default();
    if (preset && preset[0]) {
        mlb_status s = mlb_pipeline_preset(c, preset);
        if (s) return s;
    }
    if (!(steps_scale > 0 && steps_scale <= 100)) return mlb_fail(MLB_ERR_ARG, "text3d: steps scale %g (expected (0, 100])", steps_scale);
    if (!model || !model[0]) return mlb_fail(MLB_ERR_ARG, "text3d: no model");
    snprintf(c->model, sizeof c->model, "%s", model);
    c->seed = seed;
    c->material = material;
    c->fixed_env = fixed_env ? 1 : 0;
    c->view_prompts = view_prompts ? 1 : 0;
    if (steps_scale != 1.0) {   // quick runs: every stage shorter, none empty
        c->geometry_iters = scaled(c->geometry_iters, steps_scale);
        c->appearance_iters = scaled(c->appearance_iters, steps_scale);
        c->init_iters = scaled(c->init_iters, steps_scale);
        if (c->latent_iters > 0) c->latent_iters = (int)lround(c->latent_iters * steps_scale);
    }
    if (c->latent_iters < 0) c->latent_iters = c->geometry_iters / 3;   // as generate resolves it
    c->export_texture = 0;   // baking is not measured; `matlaber export RUN` makes the .glb
    return MLB_OK;
}

mlb_text3d_bench_config mlb_text3d_bench_default(void) {
    mlb_text3d_bench_config c;
    memset(&c, 0, sizeof c);
    c.out_dir = "bench-text3d";
    c.base = mlb_pipeline_default();
    c.n_seeds = 8;
    c.relight_env = "white";
    c.measure = mlb_text3d_measure_default();
    return c;
}

// A run folder made with other settings than this benchmark's would mix results silently.
static mlb_status check_same(const char* dir, const mlb_pipeline_config* want, const mlb_pipeline_config* have) {
    const char* what = NULL;
    if (strcmp(want->prompt, have->prompt)) what = "prompt";
    else if (want->material != have->material) what = "material network (--material)";
    else if (want->fixed_env != have->fixed_env) what = "--fixed-env";
    else if (want->view_prompts != have->view_prompts) what = "--no-view-prompts";
    else if (want->seed != have->seed) what = "seed";
    else if (strcmp(want->init, have->init)) what = "starting shape (--init)";
    else if (want->geometry_iters != have->geometry_iters || want->appearance_iters != have->appearance_iters)
        what = "step counts (--preset / --steps-scale)";
    else if (want->res != have->res || want->views != have->views || want->grid != have->grid) what = "preset";
    else if (want->guidance_scale != have->guidance_scale || want->appearance_guidance_scale != have->appearance_guidance_scale)
        what = "guidance scale (a run from before the preset's appearance guidance scale: regenerate it)";
    // then any other setting of the generation (--set's keys among them); not the model's path (its
    // spelling may differ) nor what only the run's bookkeeping uses
    static const char* const bookkeeping[] = {"model", "checkpoint_every", "preview_every", "export_texture", "caption", NULL};
    if (!what) what = mlb_pipeline_config_differs(want, have, bookkeeping);
    if (!what) return MLB_OK;
    return mlb_fail(MLB_ERR_ARG, "%s holds a run made with another %s: remove it or give the benchmark another -o", dir, what);
}

static int run_finished(const char* dir) {
    char p[MLB_PIPELINE_PATH + 64];
    snprintf(p, sizeof p, "%s/final/mesh.obj", dir);
    if (!mlb_is_file(p)) return 0;
    snprintf(p, sizeof p, "%s/final/material.safetensors", dir);
    return mlb_is_file(p);
}

// RUN/text3d.json: the generation's seconds and, when it failed, why (kept for a later invocation
// that reuses the run: a deterministic failure is not worth repeating).
static void outcome_save(const char* dir, double seconds, const char* error) {
    char p[MLB_PIPELINE_PATH + 64];
    snprintf(p, sizeof p, "%s/text3d.json", dir);
    cJSON* j = cJSON_CreateObject();
    if (!j) return;
    cJSON_AddNumberToObject(j, "seconds", seconds);
    if (error && error[0]) cJSON_AddStringToObject(j, "error", error);
    if (mlb_run_write_json(p, j)) mlb_log(MLB_LOG_WARN, "could not write %s", p);
    cJSON_Delete(j);
}

// The seconds (NAN when unknown) and the saved error (empty when none).
static double outcome_load(const char* dir, char* error, size_t cap) {
    char p[MLB_PIPELINE_PATH + 64];
    snprintf(p, sizeof p, "%s/text3d.json", dir);
    cJSON* j = NULL;
    double v = NAN;
    error[0] = 0;
    if (mlb_is_file(p) && mlb_run_read_json(p, &j) == MLB_OK) {
        if (mlb_json_get_number(j, "seconds", 0, 1e12, &v, p) != MLB_OK) v = NAN;
        const cJSON* e = cJSON_GetObjectItemCaseSensitive(j, "error");
        if (cJSON_IsString(e)) snprintf(error, cap, "%s", e->valuestring);
    }
    cJSON_Delete(j);
    return v;
}

// A failed generation's row: no asset, so the prompted class is not the nearest (none is) and the
// metal call is wrong; the numbers that need an asset are NAN (the Chamfer infinite).
static void failed_scores(mlb_text3d_scores* sc, int cls, int mat) {
    memset(sc, 0, sizeof *sc);
    sc->cls = cls;
    sc->mat = mat;
    sc->held_out = mlb_catalogue_held_out(cls, mat);
    sc->nearest = -1;
    for (int k = 0; k < MLB_TEXT3D_MAX_CLASSES; k++) sc->chamfer[k] = INFINITY;
    sc->chamfer_prompted = INFINITY;
    for (int j = 0; j < 7; j++) sc->median_k[j] = NAN;
    sc->material_rmse = NAN;
    sc->metal_truth = mlb_catalogue_material_metal(mat);
    sc->metal_pred = !sc->metal_truth;   // no call made: the opposite of the truth, as counted
    sc->relight_psnr = NAN;
    sc->janus = sc->mirrored = -1;
    sc->chamfer_truth = sc->chamfer_mirror = sc->chamfer_both = NAN;
    sc->normal_deg = sc->accuracy = sc->completeness = INFINITY;   // worst in the medians
    for (int k = 0; k < MLB_CATALOGUE_MAX_PARTS; k++)
        sc->part_completeness[k] = k < mlb_catalogue_class_n_parts(cls) ? INFINITY : NAN;
    sc->thin = mlb_catalogue_class_n_parts(cls) ? INFINITY : NAN;
    sc->colour_pred = -1;
    sc->colour_ok = 0;
}

// Generates the prompt into dir: fresh, resumed, or nothing to do when it finished before.
static mlb_status generate_one(const mlb_text3d_bench_config* bc, const mlb_pipeline_config* want, const char* dir,
                               mlb_text3d_row* row) {
    mlb_pipeline_config c = *want;
    int resume = 0;
    mlb_status s = MLB_OK;
    if (mlb_run_exists(dir)) {
        char p[MLB_PIPELINE_PATH + 64];
        snprintf(p, sizeof p, "%s/config.json", dir);
        mlb_pipeline_config have;
        s = mlb_pipeline_config_load(&have, p);
        if (!s) s = check_same(dir, want, &have);
        if (s) return s;
        double seconds = outcome_load(dir, row->error, sizeof row->error);
        if (row->error[0] || run_finished(dir)) {
            row->seconds = seconds;
            row->generated = 0;
            mlb_log(MLB_LOG_INFO, "%s %s before: %s", dir, row->error[0] ? "failed" : "finished",
                    row->error[0] ? row->error : "measuring it");
            return MLB_OK;
        }
        c = have;   // continue with the run's own settings (equal in what matters, checked above)
        resume = 1;
        mlb_log(MLB_LOG_INFO, "%s stopped before: resuming it", dir);
    }
    mlb_guidance* g = NULL;
    mlb_views* views = NULL;
    if (!resume) s = mlb_pipeline_read_prompt(&c);   // what the project's own models read it as
    if (!s) s = mlb_pipeline_make_guidance(&c, bc->be, &g, &views);
    mlb_progress progress;
    mlb_pipeline_result result;
    double t0 = mlb_now_seconds();
    int ran = !s;   // a failure from here on is the generation's own, not the set-up's
    if (!s) s = mlb_pipeline_run(dir, &c, g, views, bc->be, resume, bc->progress ? &progress : NULL, &result);
    mlb_guidance_free(g);
    mlb_pipeline_free_views(views);
    if (!s && !result.finished) s = mlb_fail(MLB_ERR_ARG, "%s: the run stopped before its end", dir);
    row->seconds = mlb_now_seconds() - t0;
    row->generated = 1;
    if (s && ran && mlb_run_exists(dir)) {
        // the run itself failed (the surface vanished, a step went non-finite): a result, not the end
        snprintf(row->error, sizeof row->error, "%s", mlb_last_error());
        mlb_log(MLB_LOG_WARN, "'%s' failed: %s", c.prompt, row->error);
        s = MLB_OK;
    }
    if (s) return mlb_fail_context(s, "generating '%s'", c.prompt);
    outcome_save(dir, row->seconds, row->error);
    return MLB_OK;
}

// Every process's rows to every process: process r ran prompts r, r + N, ... and finished the first
// done_of[r] of them (its rows in rows[] on that process); done[i] = 1 for every row finished by
// any. Rows are plain data (no pointers), so they travel as bytes.
static mlb_status gather_rows(mlb_text3d_row* rows, unsigned char* done, int total, int done_here, int rank,
                              int size) {
    int* done_of = calloc((size_t)size, sizeof *done_of);
    size_t* bytes = calloc((size_t)size, sizeof *bytes);
    mlb_text3d_row* mine = calloc((size_t)done_here + 1, sizeof *mine);
    mlb_text3d_row* all = calloc((size_t)total + 1, sizeof *all);
    mlb_status s = done_of && bytes && mine && all ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "text3d: out of memory gathering rows");
    if (!s) {
        done_of[rank] = done_here;
        s = mlb_dist_allgather_items(&done_of[rank], done_of, size, sizeof(int));
    }
    if (!s) {
        for (int k = 0; k < done_here; k++) mine[k] = rows[rank + k * size];
        for (int r = 0; r < size; r++) bytes[r] = (size_t)done_of[r] * sizeof(mlb_text3d_row);
        s = mlb_dist_allgatherv(mine, all, bytes);
    }
    if (!s) {
        size_t at = 0;
        for (int r = 0; r < size; r++)
            for (int k = 0; k < done_of[r]; k++) {
                rows[r + k * size] = all[at++];
                done[r + k * size] = 1;
            }
    }
    free(done_of); free(bytes); free(mine); free(all);
    return s;
}

mlb_status mlb_text3d_bench_run(const mlb_text3d_bench_config* c, mlb_text3d_row* rows, int* n_rows,
                                mlb_text3d_summary* summary) {
    *n_rows = 0;
    const int rank = mlb_dist_world_rank(), size = mlb_dist_world_size();
    double t0 = mlb_now_seconds();
    int classes[MLB_TEXT3D_MAX_CLASSES], mats[MLB_TEXT3D_MAX_CLASSES];
    int nc = c->n_classes, nm = c->n_materials;
    if (nc < 0 || nc > MLB_TEXT3D_MAX_CLASSES || nm < 0 || nm > MLB_TEXT3D_MAX_CLASSES)
        return mlb_fail(MLB_ERR_ARG, "text3d: %d classes, %d materials", nc, nm);
    if (nc == 0) nc = mlb_catalogue_n_classes();
    if (nm == 0) nm = mlb_catalogue_n_materials();
    if (nc > MLB_TEXT3D_MAX_CLASSES || nm > MLB_TEXT3D_MAX_CLASSES) return mlb_fail(MLB_ERR_ARG, "text3d: catalogue too large");
    for (int i = 0; i < nc; i++) classes[i] = c->n_classes ? c->classes[i] : i;
    for (int i = 0; i < nm; i++) mats[i] = c->n_materials ? c->materials[i] : i;
    if (c->n_pairs < 0 || c->n_pairs > MLB_TEXT3D_MAX_PAIRS) return mlb_fail(MLB_ERR_ARG, "text3d: %d pairs", c->n_pairs);
    for (int i = 0; i < c->n_pairs; i++)
        if (!mlb_catalogue_class_name(c->pair_class[i]) || !mlb_catalogue_material_name(c->pair_material[i]))
            return mlb_fail(MLB_ERR_ARG, "text3d: pair %d out of range", i);
    // prompt i: the i-th pair, or (class i / nm, material i % nm) of the cross product
#define PROMPT_CLASS(i) (c->n_pairs ? c->pair_class[i] : classes[(i) / nm])
#define PROMPT_MAT(i) (c->n_pairs ? c->pair_material[i] : mats[(i) % nm])
    // the metal rule must classify every catalogue material right from its truth, or the metal
    // column would measure the rule rather than the asset
    for (int m = 0; m < mlb_catalogue_n_materials(); m++)
        if (mlb_text3d_is_metal(mlb_catalogue_material_brdf(m)) != mlb_catalogue_material_metal(m))
            return mlb_fail(MLB_ERR_ARG, "text3d: the metal rule misclassifies %s", mlb_catalogue_material_name(m));
    mlb_pipeline_config probe = c->base;   // the prompt is filled per run
    snprintf(probe.prompt, sizeof probe.prompt, "a probe");
    mlb_status s = mlb_pipeline_validate(&probe);
    if (s) return mlb_fail_context(s, "text3d");
    // every prompt and its run folder first: a folder made with other settings fails before any work
    int total = c->n_pairs ? c->n_pairs : nc * nm, n_gen = 0;
    for (int i = 0; !s && i < total; i++) {
        int cls = PROMPT_CLASS(i), mat = PROMPT_MAT(i);
        mlb_text3d_row* row = &rows[i];
        memset(row, 0, sizeof *row);
        // the catalogue's caption (no view suffix), or a held-out phrasing of it (bench --phrasing)
        mlb_caption_phrase(cls, mat, mlb_caption_phrasing_form(mlb_caption_bench_phrasing(), cls, mat), row->prompt,
                           sizeof row->prompt);
        snprintf(row->run_dir, sizeof row->run_dir, "%s/%s_%s", c->out_dir, mlb_catalogue_class_name(cls),
                 mlb_catalogue_material_name(mat));
        if (mlb_run_exists(row->run_dir)) {
            mlb_pipeline_config want = c->base, have;
            snprintf(want.prompt, sizeof want.prompt, "%s", row->prompt);
            char p[MLB_PIPELINE_PATH + 64];
            snprintf(p, sizeof p, "%s/config.json", row->run_dir);
            s = mlb_pipeline_config_load(&have, p);
            if (!s) s = check_same(row->run_dir, &want, &have);
        }
    }
    if (s) return s;
    unsigned char* done = calloc((size_t)total + 1, 1);   // [total]: the rows finished (by any process)
    if (!done) return mlb_fail(MLB_ERR_NOMEM, "text3d: out of memory");   // (before any collective)
    // the relighting light at the runs' own environment resolution (the tiny preset's is small)
    mlb_text3d_truth truth;
    mlb_envmap env = {0};
    mlb_envlight light = {0};
    mlb_envlight_options lo;
    memset(&lo, 0, sizeof lo);
    lo.face_size = c->base.cube_size;
    s = mlb_text3d_truth_create(&truth, c->n_seeds);
    if (!s) s = mlb_envmap_open(&env, c->relight_env, 1.0f, c->base.env_height, NULL);
    if (!s) s = mlb_envlight_build(&light, &env, &lo);
    if (!s && rank == 0) s = mlb_mkdir_p(c->out_dir);
    if (size > 1) {   // every process learns whether the folder exists before any run goes in it
        int bad = mlb_dist_max_int(s != MLB_OK);
        if (bad && !s) s = mlb_fail(MLB_ERR_IO, "text3d: another process could not start");
    }
    // Several processes (mpirun): prompt i goes to process i mod N, which generates it as a group of
    // one (mlb_dist_solo: its views are not split) and measures it; the rows meet on every process
    // afterwards. A run is the same bytes on any number of processes or threads (test_pipeline).
    double gen_wall = 0;
    int done_here = 0, mine = 0;
    for (int i = rank; i < total; i += size) mine++;
    mlb_pipeline_keep_shape_fits(MLB_PIPELINE_KEEP_FITS_BYTES);   // every prompt starts from the same fits
    for (int i = rank; !s && i < total; i += size) {
        int cls = PROMPT_CLASS(i), mat = PROMPT_MAT(i);
        mlb_text3d_row* row = &rows[i];
        if (c->progress) {
            char eta[32], who[32] = "";
            if (n_gen) mlb_format_duration(gen_wall / n_gen * (mine - done_here), eta, sizeof eta);
            else snprintf(eta, sizeof eta, "?");
            if (size > 1) snprintf(who, sizeof who, " (process %d)", rank);
            mlb_log(MLB_LOG_INFO, "== [%d/%d]%s '%s' (%s) into %s; ETA %s", i + 1, total, who, row->prompt,
                    mlb_catalogue_held_out(cls, mat) ? "held out" : "seen", row->run_dir, eta);
        }
        double t1 = mlb_now_seconds();
        mlb_pipeline_config want = c->base;
        snprintf(want.prompt, sizeof want.prompt, "%s", row->prompt);
        int was = mlb_dist_solo(1);
        s = generate_one(c, &want, row->run_dir, row);
        mlb_dist_solo(was);
        if (!s && row->error[0]) failed_scores(&row->scores, cls, mat);
        else if (!s) s = mlb_text3d_measure_run(&truth, row->run_dir, cls, mat, &light, &c->measure, &row->scores);
        if (!s) {
            done_here++;
            done[i] = 1;
            // the ETA from every prompt whose generation time is known (an earlier invocation's too)
            if (row->generated) { n_gen++; gen_wall += mlb_now_seconds() - t1; }
            else if (isfinite(row->seconds)) { n_gen++; gen_wall += row->seconds; }
            if (c->progress && !row->error[0])
                mlb_log(MLB_LOG_INFO, "'%s': nearest %s (Chamfer %.4f to %s), material RMSE %.3f, %s, relit %.2f dB",
                        row->prompt, mlb_catalogue_class_name(row->scores.nearest), row->scores.chamfer_prompted,
                        mlb_catalogue_class_name(cls), row->scores.material_rmse,
                        row->scores.metal_pred ? "metal" : "dielectric", row->scores.relight_psnr);
        }
    }
    if (size > 1) {   // every process gets here, an error or not: the gathers are collective
        mlb_status sg = gather_rows(rows, done, total, done_here, rank, size);
        int bad = mlb_dist_max_int(s != MLB_OK);
        if (!s) s = sg;
        if (bad && !s) s = mlb_fail(MLB_ERR_ARG, "text3d: another process stopped with an error (see its message above)");
    }
    mlb_pipeline_keep_shape_fits(0);
    // the rows done: the prompts before the first that is not
    *n_rows = 0;
    while (*n_rows < total && done[*n_rows]) (*n_rows)++;
    free(done);
#undef PROMPT_CLASS
#undef PROMPT_MAT
    mlb_envlight_free(&light);
    mlb_envmap_free(&env);
    mlb_text3d_truth_free(&truth);
    mlb_text3d_summarise(rows, *n_rows, mlb_now_seconds() - t0, summary);
    if (!s && rank == 0) {   // the report beside the runs
        char p[MLB_PIPELINE_PATH + 64];
        snprintf(p, sizeof p, "%s/report.md", c->out_dir);
        mlb_atomic_file af;
        s = mlb_atomic_open(&af, p);
        if (!s) {
            mlb_text3d_print(af.f, c, rows, *n_rows, summary);
            s = mlb_atomic_commit(&af);
        }
    }
    return s;
}

