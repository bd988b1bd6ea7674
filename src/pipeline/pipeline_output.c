// What a run writes besides checkpoints: previews, progress, the final asset and its renders, and
// reading a finished run back (include/matlaber/pipeline.h, docs/runs.md).
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "matlaber/dist.h"
#include "matlaber/fileio.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/image_write.h"
#include "matlaber/obj.h"
#include "matlaber/plot.h"
#include "matlaber/raster.h"
#include "matlaber/safetensors.h"
#include "matlaber/shade.h"
#include "matlaber/log.h"
#include "pipeline/pipeline_internal.h"

void pipeline_path(char* out, size_t cap, const char* dir, const char* rel) { snprintf(out, cap, "%s/%s", dir, rel); }

static long checkpoint_step(const char* path) {
    mlb_safetensors* st = NULL;
    if (mlb_st_open(&st, path)) return -1;
    const char* t = mlb_st_metadata(st, "step");
    char* end = NULL;
    long step = t ? strtol(t, &end, 10) : -1;
    if (t && *end) step = -1;
    mlb_st_close(st);
    return step;
}

mlb_status pipeline_resume_point(const char* dir, int* stage, long* step) {
    char path[MLB_PIPELINE_PATH + 64];
    pipeline_path(path, sizeof path, dir, "checkpoints/appearance.safetensors");
    *stage = 0;
    *step = 0;
    if (mlb_is_file(path)) {
        long k = checkpoint_step(path);
        if (k < 0) return mlb_fail(MLB_ERR_FORMAT, "%s: unreadable checkpoint", path);
        *stage = MLB_STAGE_APPEARANCE;
        *step = k;
        return MLB_OK;
    }
    pipeline_path(path, sizeof path, dir, "checkpoints/geometry.safetensors");
    if (mlb_is_file(path)) {
        long k = checkpoint_step(path);
        if (k < 0) return mlb_fail(MLB_ERR_FORMAT, "%s: unreadable checkpoint", path);
        *step = k;
    }
    return MLB_OK;
}

mlb_status pipeline_fix_env(pipeline_run* r, mlb_view* views, int n) {
    int fixed = r->c->fixed_env && strcmp(r->c->guidance, "sds") == 0;
    for (int i = 0; i < n; i++) {
        if (fixed || views[i].env < 0) {
            views[i].env = 0;
            views[i].env_rotation_deg = fixed ? 0 : views[i].env_rotation_deg;
        }
        if (views[i].env >= r->scene.n_envs)
            return mlb_fail(MLB_ERR_ARG, "view %d asks for environment %d of %d", i, views[i].env, r->scene.n_envs);
    }
    return MLB_OK;
}

// [n, res, res, 4] stage images → a displayable RGB row: normals as (n + 1)/2 over black (the
// convention SDS sees), colours as they are (already sRGB).
static void display_rgb(float* rgb, const float* img, size_t pixels, mlb_stage stage) {
    for (size_t i = 0; i < pixels; i++) {
        for (int k = 0; k < 3; k++) {
            float v = img[4 * i + k];
            rgb[3 * i + k] = stage == MLB_STAGE_GEOMETRY ? 0.5f * (v + img[4 * i + 3]) : v;
        }
    }
}

mlb_status pipeline_preview(pipeline_run* r, mlb_stage stage, long step, const float* images, int n) {
    int res = r->c->res;
    size_t p = (size_t)res * res;
    float* tiles = malloc(sizeof(float) * p * 3 * (size_t)n);
    if (!tiles) return mlb_fail(MLB_ERR_NOMEM, "preview: out of memory");
    for (int v = 0; v < n; v++) display_rgb(tiles + p * 3 * (size_t)v, images + p * 4 * (size_t)v, p, stage);
    char rel[64], path[MLB_PIPELINE_PATH + 64];
    snprintf(rel, sizeof rel, "previews/%s_%06ld.png", stage == MLB_STAGE_GEOMETRY ? "geometry" : "appearance", step + 1);
    pipeline_path(path, sizeof path, r->dir, rel);
    mlb_status s = mlb_image_grid_write(path, tiles, n, res, res, 3, n < 5 ? n : (n + 1) / 2, NULL);
    free(tiles);
    return s;
}

void pipeline_progress(pipeline_run* r, long done, double loss, int faces) {
    if (!r->progress) return;
    char buf[64];
    snprintf(buf, sizeof buf, "loss %.4g, %d faces", loss, faces);
    mlb_progress_update(r->progress, done, buf);
}

// The cost of a step of each stage relative to a geometry step's, for the ETA before a stage has
// run (progress.h). Both guided stages are one guidance call per view per step, and that call
// dominates; a material start's step scores one archetype on its views at two timesteps with no
// backward pass; the export renders and bakes once. The shape start's fit steps cost what the
// grid does, not what the model does: nothing predicts them (no ETA while it runs).
// Rough, from the project's own model at its preset (128², 4 views) and at 32², 1 view on a busy
// 2-core machine: an appearance step 1.1-2.8 geometry steps' wall time (0.5-1.7 their CPU time),
// an archetype's score 2-3 per view (docs/usage.md, "Progress").
#define COST_APPEARANCE 2.2     // shading, the material network and its smoothness term besides
#define COST_SCORE_VIEW 2.5     // an archetype's score, per view, against a guided step's view
#define COST_EXPORT 2.0         // the final renders and a small bake; a 1024² bake 3 more (per step)

void pipeline_progress_plan(pipeline_run* r, mlb_progress* p, int paint, const pipeline_start_sizes* starts) {
    const mlb_pipeline_config* c = r->c;
    const char* names[PIPELINE_STAGES] = {"shape start", "geometry", "material start", "appearance", "export"};
    int views = r->g->n_views > 0 ? r->g->n_views : 1, scored = starts->material_views;
    long steps[PIPELINE_STAGES] = {paint ? 0 : starts->shape_steps, paint ? 0 : c->geometry_iters,
                                   starts->material_steps, c->appearance_iters, 1 + (c->export_texture > 0)};
    double tex = c->export_texture / 1024.0;
    double cost[PIPELINE_STAGES] = {0, 1.0, COST_SCORE_VIEW * scored / views, COST_APPEARANCE, COST_EXPORT + 3.0 * tex * tex};
    long total = 0;
    for (int i = 0; i < PIPELINE_STAGES; i++) total += steps[i];
    mlb_progress_begin(p, stderr, paint ? "paint" : strcmp(c->guidance, "images") ? "generate" : "fit", total, "step");
    // the losses are numbers for whoever tunes a run: shown where asked for (--log-level debug)
    p->show_status = mlb_log_get_level() <= MLB_LOG_DEBUG;
    mlb_progress_plan(p, PIPELINE_STAGES, names, steps, cost);
    mlb_progress_stage_may_grow(p, PIPELINE_MATERIAL_START);   // a close call rescores on 32 views
}

mlb_status pipeline_agree(mlb_status s) {
    if (mlb_dist_size() < 2) return s;
    int any = mlb_dist_max_int(s != MLB_OK);
    if (!s && any) s = mlb_fail(MLB_ERR_IO, "another process of this run failed (its message is above)");
    return s;
}

int pipeline_should_stop(pipeline_run* r) {
    r->steps_this_run++;
    if (r->c->stop_after > 0 && r->steps_this_run >= r->c->stop_after) r->stopped = 1;
    return r->stopped;
}

mlb_status pipeline_write_obj(const char* path, const mlb_mesh* m, const float* colors, const char* comment) {
    mlb_atomic_file af;
    mlb_status s = mlb_atomic_open(&af, path);
    if (s) return s;
    fprintf(af.f, "# matlaber: %s\n", comment ? comment : "mesh");
    for (int i = 0; i < m->n_verts; i++) {
        const float* p = m->pos + 3 * (size_t)i;
        if (colors) {
            const float* c = colors + 3 * (size_t)i;
            fprintf(af.f, "v %.7g %.7g %.7g %.5f %.5f %.5f\n", p[0], p[1], p[2], c[0], c[1], c[2]);
        } else {
            fprintf(af.f, "v %.7g %.7g %.7g\n", p[0], p[1], p[2]);
        }
    }
    if (m->normal)
        for (int i = 0; i < m->n_verts; i++) {
            const float* n = m->normal + 3 * (size_t)i;
            fprintf(af.f, "vn %.6g %.6g %.6g\n", n[0], n[1], n[2]);
        }
    for (int f = 0; f < m->n_faces; f++) {
        const int32_t* t = m->faces + 3 * (size_t)f;
        if (m->normal)
            fprintf(af.f, "f %d//%d %d//%d %d//%d\n", t[0] + 1, t[0] + 1, t[1] + 1, t[1] + 1, t[2] + 1, t[2] + 1);
        else
            fprintf(af.f, "f %d %d %d\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    return mlb_atomic_commit(&af);
}

// The final renders: four views around the asset (azimuth 0, 90, 180, 270, elevation 15), each as
// normals, shaded under the pool's first environment, and the kd / ks / roughness maps.
enum { FINAL_VIEWS = 4 };

static mlb_status write_final_renders(pipeline_run* r) {
    const mlb_pipeline_config* c = r->c;
    int res = c->res < 512 ? c->res : 512;
    size_t p = (size_t)res * res;
    mlb_view views[FINAL_VIEWS];
    memset(views, 0, sizeof views);
    mlb_status s = MLB_OK;
    for (int v = 0; !s && v < FINAL_VIEWS; v++) {
        views[v].azimuth_deg = 90.0 * v;
        views[v].elevation_deg = 15;
        views[v].radius = MLB_ORBIT_RADIUS;
        views[v].target = -1;
        s = mlb_camera_orbit(&views[v].cam, views[v].azimuth_deg, views[v].elevation_deg, MLB_ORBIT_RADIUS, NULL,
                             MLB_ORBIT_FOVY_MAX, 1.0, MLB_ORBIT_NEAR, MLB_ORBIT_FAR);
    }
    float* shaded = malloc(sizeof(float) * p * 4 * FINAL_VIEWS);
    float* normal = malloc(sizeof(float) * p * 4);
    float* maps = malloc(sizeof(float) * p * 10);   // kd 3, ks 3, kr 1, normal 3
    float* sheet = malloc(sizeof(float) * p * 3 * 5 * FINAL_VIEWS);   // rows: normal, shaded, kd, ks, kr
    mlb_appearance app;
    memset(&app, 0, sizeof app);
    app.be = r->be;
    if (!shaded || !normal || !maps || !sheet) s = mlb_fail(MLB_ERR_NOMEM, "final renders: out of memory");
    if (!s) s = mlb_appearance_render(&app, &r->mat, &r->scene.mesh, r->scene.light_ptrs, views, FINAL_VIEWS, res, 2, shaded, 0);
    char path[MLB_PIPELINE_PATH + 64], rel[64];
    for (int v = 0; !s && v < FINAL_VIEWS; v++) {
        float* row = sheet;   // tile index = kind * FINAL_VIEWS + v
        s = mlb_geofit_render_mesh(r->be, normal, &r->scene.mesh, &views[v].cam, res, 2);
        if (!s) s = mlb_appearance_maps(r->be, &r->mat, &r->scene.mesh, &views[v], res, maps, maps + 3 * p, maps + 6 * p, maps + 7 * p);
        if (s) break;
        display_rgb(row + p * 3 * (0 * FINAL_VIEWS + v), normal, p, MLB_STAGE_GEOMETRY);
        display_rgb(row + p * 3 * (1 * FINAL_VIEWS + v), shaded + p * 4 * v, p, MLB_STAGE_APPEARANCE);
        for (size_t i = 0; i < p; i++) {
            for (int k = 0; k < 3; k++) {
                row[p * 3 * (2 * FINAL_VIEWS + v) + 3 * i + k] = mlb_srgb_encode(maps[3 * i + k]);
                row[p * 3 * (3 * FINAL_VIEWS + v) + 3 * i + k] = mlb_srgb_encode(maps[3 * p + 3 * i + k]);
                row[p * 3 * (4 * FINAL_VIEWS + v) + 3 * i + k] = maps[6 * p + i];
            }
        }
        snprintf(rel, sizeof rel, "final/normal_%d.png", v);
        pipeline_path(path, sizeof path, r->dir, rel);
        float* rgba = normal;   // normals in (n + 1)/2 with the mask as alpha
        for (size_t i = 0; i < p; i++)
            for (int k = 0; k < 3; k++) rgba[4 * i + k] = 0.5f * (rgba[4 * i + k] + rgba[4 * i + 3]);
        s = mlb_image_write_png(path, rgba, res, res, 4, NULL);
        snprintf(rel, sizeof rel, "final/shaded_%d.png", v);
        pipeline_path(path, sizeof path, r->dir, rel);
        if (!s) s = mlb_image_write_png(path, shaded + p * 4 * v, res, res, 4, NULL);
        static const char* names[3] = {"kd", "ks", "roughness"};
        for (int m = 0; !s && m < 3; m++) {
            snprintf(rel, sizeof rel, "final/%s_%d.png", names[m], v);
            pipeline_path(path, sizeof path, r->dir, rel);
            s = mlb_image_write_png(path, row + p * 3 * ((2 + m) * FINAL_VIEWS + v), res, res, 3, NULL);
        }
    }
    if (!s) {
        const char* labels[5 * FINAL_VIEWS];
        static const char* kinds[5] = {"normal", "shaded", "kd", "ks", "roughness"};
        for (int k = 0; k < 5; k++)
            for (int v = 0; v < FINAL_VIEWS; v++) labels[k * FINAL_VIEWS + v] = kinds[k];
        pipeline_path(path, sizeof path, r->dir, "final/views.png");
        s = mlb_image_grid_write(path, sheet, 5 * FINAL_VIEWS, res, res, 3, FINAL_VIEWS, labels);
    }
    mlb_appearance_free(&app);
    free(shaded); free(normal); free(maps); free(sheet);
    return s;
}

mlb_status pipeline_write_final(pipeline_run* r) {
    const mlb_mesh* m = &r->scene.mesh;
    char path[MLB_PIPELINE_PATH + 64];
    char cells[32];
    snprintf(cells, sizeof cells, "%d", mlb_pipeline_cells(r->c));
    mlb_st_meta meta[1] = {{"geometry.grid_cells", cells}};
    pipeline_path(path, sizeof path, r->dir, "final/geometry.safetensors");
    mlb_status s = r->c->paint_mesh[0] ? MLB_OK : mlb_geometry_save(&r->geo, path, meta, 1);   // paint: no geometry network
    pipeline_path(path, sizeof path, r->dir, "final/material.safetensors");
    if (!s) s = mlb_material_save(&r->mat, path, 0);
    size_t V = (size_t)m->n_verts;
    float* k = malloc(sizeof(float) * V * 7);
    float* col = malloc(sizeof(float) * V * 3);
    if (!s && (!k || !col)) s = mlb_fail(MLB_ERR_NOMEM, "final mesh: out of memory");
    if (!s) s = mlb_material_eval(&r->mat, m->pos, V, k);
    // mesh.obj carries kd as vertex colours (sRGB-encoded, as viewers expect 8-bit-like colours);
    // the same mesh with ks and with the roughness (linear, grey) beside it.
    static const char* files[3] = {"final/mesh.obj", "final/mesh_ks.obj", "final/mesh_roughness.obj"};
    static const char* what[3] = {"mesh with kd (diffuse albedo, sRGB) as vertex colours",
                                  "mesh with ks (specular albedo F0, sRGB) as vertex colours",
                                  "mesh with the roughness (linear) as grey vertex colours"};
    for (int f = 0; !s && f < 3; f++) {
        for (size_t i = 0; i < V; i++)
            for (int c = 0; c < 3; c++) col[3 * i + c] = f == 2 ? k[7 * i + 6] : mlb_srgb_encode(k[7 * i + 3 * f + c]);
        pipeline_path(path, sizeof path, r->dir, files[f]);
        s = pipeline_write_obj(path, m, col, what[f]);
    }
    free(k);
    free(col);
    if (!s) s = write_final_renders(r);
    return s;
}

// ---- reading a finished run -------------------------------------------------------------------
mlb_status mlb_run_asset_load(mlb_run_asset* a, const char* dir) {
    memset(a, 0, sizeof *a);
    char path[MLB_PIPELINE_PATH + 64];
    mlb_status s = MLB_OK;
    a->config = mlb_pipeline_default();
    pipeline_path(path, sizeof path, dir, "config.json");
    int has_config = access(path, F_OK) == 0;   // anything there is read (a pipe or a folder is refused, naming it)
    if (has_config) s = mlb_pipeline_config_load(&a->config, path);   // optional: the asset is final/
    pipeline_path(path, sizeof path, dir, "final/mesh.obj");
    if (!s && !mlb_is_file(path))
        s = has_config ? mlb_fail(MLB_ERR_NOT_FOUND, "%s: the run has not finished (no final/mesh.obj); continue it with --resume", dir)
                       : mlb_fail(MLB_ERR_NOT_FOUND, "%s: not a run folder (no config.json, no final/mesh.obj)", dir);
    if (!s) s = mlb_obj_load(path, &a->mesh);
    if (!s && !a->mesh.normal) s = mlb_mesh_compute_normals(&a->mesh);
    pipeline_path(path, sizeof path, dir, "final/material.safetensors");
    if (!s) s = mlb_material_load(&a->material, path);
    if (s) mlb_run_asset_free(a);
    return s;
}

void mlb_run_asset_free(mlb_run_asset* a) {
    mlb_mesh_free(&a->mesh);
    material_net_free(&a->material);
    memset(a, 0, sizeof *a);
}

mlb_status mlb_run_asset_vertex_brdf(const mlb_run_asset* a, float* k) {
    return mlb_material_eval(&a->material, a->mesh.pos, (size_t)a->mesh.n_verts, k);
}

mlb_status mlb_run_asset_material(void* user, const float* pos, size_t n, float* k) {
    const mlb_run_asset* a = user;
    return mlb_material_eval(&a->material, pos, n, k);
}
