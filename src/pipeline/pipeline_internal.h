// The pipeline's run state and its outputs (pipeline_output.c), used by the loop (pipeline.c). The
// dependency goes one way: pipeline_output.c calls nothing in pipeline.c.
#ifndef MATLABER_PIPELINE_INTERNAL_H
#define MATLABER_PIPELINE_INTERNAL_H
#include "matlaber/appearance.h"
#include "matlaber/backend.h"
#include "matlaber/brdf_ae.h"
#include "matlaber/dmtet.h"
#include "matlaber/envmap.h"
#include "matlaber/geometry.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/pipeline.h"
#include "matlaber/raster.h"
#include "matlaber/run.h"

// The appearance stage's fixed scene: the extracted mesh (with normals) and the environment pool.
typedef struct {
    mlb_mesh mesh;
    int n_envs;
    mlb_envmap maps[MLB_PIPELINE_MAX_ENVS];
    mlb_envlight lights[MLB_PIPELINE_MAX_ENVS];
    const mlb_envlight* light_ptrs[MLB_PIPELINE_MAX_ENVS];
} pipeline_scene;

typedef struct pipeline_run {
    const char* dir;
    const mlb_pipeline_config* c;
    mlb_guidance* g;
    const mlb_views* views;   // image guidance's data set, or NULL
    int resume;
    mlb_progress* progress;
    mlb_losslog* log;
    mlb_geometry_net geo;
    mlb_tetgrid grid;
    const mlb_backend* be;   // the op table the stages' marching tets and raster ops run on
    const mlb_backend* field_be;   // the stages' table (CUDA fp32 on a GPU), NULL: the host
    mlb_material_net mat;
    const mlb_brdf_ae* prior;   // the BRDF prior the material network was made from (latent mode)
    pipeline_scene scene;
    long geometry_start;
    long steps_this_run;   // for stop_after
    long stage_counted;    // steps of a stage that counts them itself (the material start's scores)
    int stopped;           // stop_after reached
    mlb_pipeline_result result;
    // The appearance stage's first `steps` steps from mat as it is (metal: at the metal start's rate),
    // with no checkpoint, preview, loss row or progress: the material start's tie-break. A callback
    // set by pipeline.c, so that the material start (below it) runs the stage without calling up.
    mlb_status (*appearance_trial)(struct pipeline_run* r, int metal, long steps);
} pipeline_run;

// The table the stages render on: the GPU's on a GPU run (the per-pixel buffers and marching tets
// there, docs/cuda.md "The stages on the table"), else the CPU's
static inline const mlb_backend* pipeline_stage_table(const pipeline_run* r) { return r->field_be ? r->field_be : r->be; }

// The run's progress in stages (progress.h), in this order
enum { PIPELINE_SHAPE_START, PIPELINE_GEOMETRY, PIPELINE_MATERIAL_START, PIPELINE_APPEARANCE, PIPELINE_EXPORT, PIPELINE_STAGES };
// The two start stages' sizes, which their own files know (pipeline_init.c, material_start.c):
// the caller passes them in, so that the outputs never call up into the stages.
typedef struct { long shape_steps; int material_steps, material_views; } pipeline_start_sizes;
// pipeline_output.c: begins p with the run's stages, their steps and their estimated costs
void pipeline_progress_plan(pipeline_run* r, mlb_progress* p, int paint, const pipeline_start_sizes* starts);
// pipeline_init.c: the shape start's steps (the fits' steps of every candidate); material_start.c:
// the material start's (an archetype scored is a step) and the views each is scored on
long pipeline_shape_start_steps(const mlb_pipeline_config* c);
int pipeline_material_start_steps(const pipeline_run* r);
int pipeline_material_start_views(const pipeline_run* r);

// pipeline_output.c
// Several processes (dist.h): a step fails on every rank when it failed on one, so that none is
// left waiting in a collective the others never reach. s as it was where every rank got MLB_OK.
mlb_status pipeline_agree(mlb_status s);

// geometry_step.c
// The hash grid's active levels at geometry step it (coarse-to-fine; 0 = all).
int pipeline_active_levels_at(const mlb_pipeline_config* c, const mlb_geometry_net* net, long it);
// Geometry step `it` of the run's schedule (the hash grid's active levels, the step's views, the
// regulariser's weight, every rank agreeing on the outcome), then the Adam update when it worked.
// images: the step's renders for a preview, or NULL. The stage and --init auto's look-ahead both
// step through it. On a failure st->surf tells whether marching tets found no surface.
mlb_status pipeline_geometry_step(pipeline_run* r, mlb_geofit_state* st, const mlb_adam_config* adam, long it,
                                  mlb_view* views, mlb_geofit_stats* stats, float* images);

// appearance_step.c
// The appearance stage's buffers and this process's share of a step's view batches (dist.h).
#define PIPELINE_SMOOTH_POINTS 4096   // surface points of the material smoothness term per step
typedef struct {
    mlb_appearance app;                     // the renderer's state, on the run's stage table
    const mlb_backend* atb;                 // that table (the CPU's when the run has none)
    mlb_view* views;                        // [n] the step's views
    float *images, *dimages;                // [n, res, res, 4] renders and their gradients (host)
    float* pts;                             // [PIPELINE_SMOOTH_POINTS, 3] the step's smoothness points
    float* mine;                            // [bc, n_params] this process's batches' gradients, or NULL
    double* losses;                         // [2, nb] per batch: guidance, smoothness
    size_t img;                             // floats of one render
    int n, k, nb;                           // views, views per batch, batches
    int v0, cnt, b0, bc;                    // this process's views and batches
    int smooth_on, support_on, sum_grads;
} pipeline_appearance;
// After the material network is on its device (the gradients' layout depends on it); a failed
// begin leaves a to pipeline_appearance_end.
mlb_status pipeline_appearance_begin(pipeline_run* r, pipeline_appearance* a);
void pipeline_appearance_end(pipeline_appearance* a);
// Appearance step `it`: every rank agreeing on the outcome, then the AdamW update. preview: the
// step's renders into a->images on every process. *loss, *smooth: the step's summed losses.
mlb_status pipeline_appearance_step(pipeline_run* r, pipeline_appearance* a, const mlb_adam_config* adam, long it,
                                    int preview, double* loss, double* smooth);

// pipeline_init.c
// Fits net to the starting shape `init` ("ellipsoid", "cylinder", "torus", "slab", "cup" or an OBJ file) in the
// hash grid's first active_levels levels (0: all). Adam's moments and step are zero after it.
// progress (NULL: none): the fit's steps, after its step_offset.
mlb_status pipeline_init_shape(mlb_geometry_net* net, const mlb_pipeline_config* c, const char* init, int active_levels,
                               mlb_progress* progress);

// shape_fits.c: the built-in shapes' fits kept for the process's next run (mlb_pipeline_keep_shape_fits).
// key: a 128-bit hash of all a fit depends on (the network's state before it, the config's fields
// that enter it, the shape, the levels). recall: 1 and net->params set as the fit left them, or 0.
void pipeline_shape_fit_key(const mlb_geometry_net* net, const mlb_pipeline_config* c, const char* init, int levels,
                            uint64_t key[2]);
int pipeline_shape_fit_recall(const uint64_t key[2], mlb_geometry_net* net, double* loss);
void pipeline_shape_fit_keep(const uint64_t key[2], const mlb_geometry_net* net, double loss);
// A network's state (parameters, Adam's moments, step), kept before something is tried on it and put
// back after: keep [3, n_params].
void pipeline_field_keep(const mlb_field* f, float* keep, long* step);
void pipeline_field_restore(mlb_field* f, const float* keep, long step);
// Mean and standard error of the paired differences a[k] - b[k] over n per-view scores (se infinite
// for n < 2): how --init auto and the material start tell a real win from the views' noise.
void pipeline_paired_difference(const double* a, const double* b, int n, double* mean, double* se);
// The views of a stage's first steps, for scoring renders as the stage will see them: whole steps,
// at least `want` views, at most MLB_SDS_MAX_BATCH (one step at least); the appearance stage's with
// their lights fixed as the stage fixes them. *views: malloc'd, n_views of them.
mlb_status pipeline_first_views(pipeline_run* r, mlb_stage stage, int want, mlb_view** views, int* n_views);
// --init auto[:A,B,..]: fits r->geo to the candidate the guidance scores best for the prompt.
mlb_status pipeline_choose_init(pipeline_run* r, int active_levels);

// pipeline_output.c
// out = dir/rel
void pipeline_path(char* out, size_t cap, const char* dir, const char* rel);
// The (stage, step) a resumed run restarts from, read from its checkpoints.
mlb_status pipeline_resume_point(const char* dir, int* stage, long* step);
// SDS with --fixed-env: environment 0, never rotated (image guidance keeps the targets' lights);
// a view without an environment (−1) is lit by environment 0.
mlb_status pipeline_fix_env(pipeline_run* r, mlb_view* views, int n);

// material_start.c
// material_start 1 with a guidance that scores: the material network's start is the material
// archetype the guidance scores best when that is a metal, else left at the prior's centre
// (docs/pipeline.md, "Material start"). Before the network goes to a device. *metal: 1 when it
// started from a metal (the stage then refines it at metal_start_lr_scale times the rate).
mlb_status pipeline_material_start(pipeline_run* r, int* metal);
// previews/<stage>_<step>.png: the step's renders side by side.
mlb_status pipeline_preview(pipeline_run* r, mlb_stage stage, long step, const float* images, int n);
void pipeline_progress(pipeline_run* r, long done, double loss, int faces);
// Counts a step against stop_after; 1 when the run must stop now (as if killed: no checkpoint).
int pipeline_should_stop(pipeline_run* r);
// final/: mesh.obj (+ kd, ks, roughness as vertex colours), geometry and material networks, renders.
mlb_status pipeline_write_final(pipeline_run* r);
// An OBJ with optional per-vertex colours [V,3] ("v x y z r g b"), written atomically.
mlb_status pipeline_write_obj(const char* path, const mlb_mesh* m, const float* colors, const char* comment);

#endif
