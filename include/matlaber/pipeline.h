// The two-stage material-aware pipeline (paper §3.4, §4; docs/pipeline.md):
//   shape init (ellipsoid / cylinder / mesh) → geometry stage (DMTet, guidance on [normal, mask]
//   renders) → fixed mesh → appearance stage (hash-grid material network → latent z → frozen BRDF
//   decoder → split-sum shading under a pool of environments, one drawn and rotated per view and
//   step; guidance on the sRGB renders; material smoothness) → the asset.
// The guidance (guidance.h) is either score distillation with Stable Diffusion or image guidance.
// A run lives in a directory (docs/runs.md): config.json, checkpoints/, loss.csv + loss.png,
// previews/, final/. Every random draw is a counter-based function of (seed, stage, step), and the
// checkpoints hold the optimiser state, so a resumed run ends bitwise where an uninterrupted one does
// (on any thread count; with the same BLAS kernels, i.e. on the same kind of CPU).
#ifndef MATLABER_PIPELINE_H
#define MATLABER_PIPELINE_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/error.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/guidance.h"
#include "matlaber/material_net.h"
#include "matlaber/mesh.h"
#include "matlaber/progress.h"
#include "matlaber/views.h"

struct mlb_backend;   // backend.h: the op table a run's models and stages are given

#define MLB_PIPELINE_MAX_ENVS 8
// Every text field (prompts, paths, names) holds at most MLB_PIPELINE_PATH - 1 bytes: longer text is
// refused naming the option or key, never cut (docs/files.md, "What each input may be").
#define MLB_PIPELINE_PATH 1024
// The ranges the command-line options and config.json share (mlb_pipeline_validate checks them for
// both: --set and a run's config.json take nothing the options refuse)
#define MLB_PIPELINE_MAX_ITERS 10000000       // geometry / appearance steps, checkpoint and preview intervals
#define MLB_PIPELINE_MAX_INIT_ITERS 1000000   // steps of the shape initialisation
#define MLB_PIPELINE_LR_MIN 1e-9              // learning rates
#define MLB_PIPELINE_LR_MAX 10.0
#define MLB_PIPELINE_MAX_SCALE 1e4            // guidance scales
#define MLB_PIPELINE_MAX_WEIGHT 100.0         // material smoothness weights
#define MLB_PIPELINE_MAX_LATENT 256           // latent_size: 0 (64) or a multiple of 8 up to this (a 2048² render / 8)

typedef struct {
    char guidance[16];            // "sds" or "images"
    char prompt[MLB_PIPELINE_PATH];     // sds, as typed
    char caption[128];            // sds: what the project's own models read it as ("a gold goblet";
                                  // mlb_pipeline_read_prompt), encoded in its place; "": the prompt
    char negative[MLB_PIPELINE_PATH];   // sds: replaces both stages' default negative prompts when set
    char model[MLB_PIPELINE_PATH];      // sds: the Stable Diffusion checkpoint (file or folder)
    char appearance_model[MLB_PIPELINE_PATH];   // sds: another one for the appearance stage ("": model)
    char tokenizer[MLB_PIPELINE_PATH];  // sds: the CLIP tokenizer of a single-file checkpoint ("": the folder's or $MATLABER_TOKENIZER)
    char views_dir[MLB_PIPELINE_PATH];  // images: the views folder (docs/views.md)
    double guidance_scale;        // sds: 100
    double appearance_guidance_scale;   // sds appearance stage: 0 = guidance_scale
    int latent_iters;             // sds geometry: steps fed as 64² [normal, mask] latents (default: iters / 3)
    int latent_size;              // sds geometry: their size, 0 = 64 (SD at 512²); the tiny preset: res / 8
    int geometry_t_min;           // sds geometry: the smallest timestep drawn, 0 = the guidance's (20)
    int view_prompts;             // sds: ", front view" etc. by the camera (1, default); 0: one prompt
    uint64_t seed;                // 0
    int views;                    // views per step: 9
    int view_batch;               // views per guidance call: the step's views in micro-batches of this
                                  // many, each handed whole to one process (dist.h); 0 = all in one call.
                                  // The bits depend on it (SD rounds differently per batch size), never
                                  // on the number of processes
    int res;                      // render size: 512
    int ss;                       // supersampling: 1
    // geometry stage
    int geometry_iters;           // 3000
    double geometry_lr;           // 1e-3 (AdamW, betas 0.9/0.99, eps 1e-15)
    int grid;                     // DMTet grid as Fantasia3D names it (128 → 64 cells per axis)
    int hash_log2;                // both networks' hash tables: 2^hash_log2 entries per hashed level, 0 = 19 (the paper's)
    int geometry_hash_levels;     // the geometry network's hash grid: levels (0 = 16, the paper's),
    int geometry_hash_base_res;   // its coarsest resolution (0 = 16)
    int geometry_hash_max_res;    // and its finest (0 = 4096): at most about the grid's cells keeps
                                  // the SDF smooth between the grid's vertices (docs/geometry.md)
    char init[MLB_PIPELINE_PATH]; // "ellipsoid", "cylinder", "torus", "slab", "cup", an OBJ file, or "auto" / "auto:A,B,.." (the
                                  // candidate the model scores best: docs/pipeline.md, Init)
    int init_iters;               // SDF initialisation steps: 400
    int geometry_t_max_end;       // the geometry stage's largest SDS timestep falls linearly from 500 to
                                  // this over the stage (0: 500 throughout)
    int appearance_t_max_end;     // the same for the appearance stage, from 980 (0: 980 throughout)
    double coarse_to_fine;        // hash-grid levels unlocked from 4 to all over this fraction of the
                                  // geometry steps (0: all levels from the start)
    mlb_sdf_reg_schedule sdf_reg; // the SDF regulariser's weight over the stage (geometry_fit.h: 0.2 → 0.01 by 25%)
    int surface_smooth;           // rounds of Taubin smoothing (0.5, -0.53) of the extracted surface, the
                                  // appearance stage's and the outputs' mesh (0: as extracted)
    // appearance stage
    int appearance_iters;         // 2000
    int material_start;           // 1: the model picks the start among material archetypes (a metal's, or
                                  // the prior's centre: docs/pipeline.md, "Material start"); 0: the
                                  // prior's centre (the default; the tiny preset's is 1). SDS guidance only.
    double metal_start_lr_scale;  // after a metal start the appearance stage's learning rate is
                                  // appearance_lr times this (1; the tiny preset's 0.1)
    double appearance_lr;         // 1e-2
    mlb_material_mode material;   // latent (the paper) or direct (ablation)
    double w_mat;                 // material smoothness weight (kd): 0.03
    double w_mat_spec;            // the same on ks and roughness: 0 (the paper smooths kd only)
    double mat_sigma;             // its offset std in world units: 0.01
    double material_support;      // weight of the prior's support term on the codes (latent mode;
                                  // appearance.h): 0, off (the paper; the tiny preset's 100)
    double material_support_radius; // |z| beyond which it acts: 4.2 (99% of the prior's data inside)
    int n_envs;                   // the environment pool (sds; image guidance uses the views' own)
    char envs[MLB_PIPELINE_MAX_ENVS][MLB_PIPELINE_PATH];
    int fixed_env;                // 1: environment 0 only, never rotated (Fantasia3D's setting)
    int env_height;               // lat-long height of built-in environments: 256
    int cube_size;                // pre-integrated cube face size: 128
    // paint (`matlaber paint`, docs/paint.md): the appearance stage alone on a given mesh
    char paint_mesh[MLB_PIPELINE_PATH]; // the input mesh as named ("" = not a paint run); the run keeps an
                                  // exact copy in RUN_DIR/input/mesh.obj and reads only that on resume
    int paint_keep_uv;            // 1: the texture is baked on the mesh's own UVs (default); 0: an atlas
    double paint_centre[3];       // the generation frame of the mesh: p' = (p - centre) * scale; filled
    double paint_scale;           //   in by mlb_pipeline_run when the run starts (0 before)
    // run
    int export_texture;           // > 0: the run ends by writing final/asset.glb with textures of this
                                  // size (generate: 1024; fit: 0 = none; `matlaber export` does it later)
    char precision[8];            // "" (the program's --precision) or a --precision name: the GEMMs'
                                  // operands when the program was not given --precision (cpu preset: bf16)
    int checkpoint_every;         // steps between checkpoints: 100
    int preview_every;            // steps between preview renders: 100 (0 = none)
    long stop_after;              // stop (without a final checkpoint, as if killed) after this many steps
                                  // of this invocation; 0 = run to the end. Not saved in config.json.
    int overwrite;                // a new run may replace an earlier run in the same folder (not saved)
} mlb_pipeline_config;

mlb_pipeline_config mlb_pipeline_default(void);
// A named set of settings over the defaults (docs/pipeline.md, "Presets"): "paper" (the defaults:
// the paper's schedule, 9 views at 512², for a GPU) or "cpu" (1 view, 256² renders, a short
// schedule sized by measurement to finish within an hour on 2 cores with SD 1.5 and AVX-512 BF16
// (about 1.5 h where the CPU lacks it and computes fp32), bf16 GEMMs,
// frequent checkpoints). MLB_ERR_ARG naming the presets for any other name.
mlb_status mlb_pipeline_preset(mlb_pipeline_config* c, const char* name);
#define MLB_PIPELINE_PRESETS "paper, cpu, tiny"
// The grid's cells per axis for --grid G (G / 2, as Fantasia3D's "128" = 64 cells).
int mlb_pipeline_cells(const mlb_pipeline_config* c);
// The geometry network's hash-grid span as the config sets it (geometry_hash_*; 0: the default's).
void mlb_pipeline_geometry_hash(const mlb_pipeline_config* c, mlb_hashgrid_config* enc);
mlb_status mlb_pipeline_validate(const mlb_pipeline_config* c);
// 1 when the prompt is empty or only white space (refused where it is read: "a prompt is required")
int mlb_prompt_is_blank(const char* prompt);
// 1 when init is "auto" or "auto:A,B,..": the model picks the start among candidates.
int mlb_pipeline_init_is_auto(const char* init);
// config.json of a run (every field but stop_after); reading checks types and ranges.
mlb_status mlb_pipeline_config_save(const mlb_pipeline_config* c, const char* path);
// The text config.json holds (malloc'd, free() it); NULL when out of memory.
char* mlb_pipeline_config_text(const mlb_pipeline_config* c);
mlb_status mlb_pipeline_config_load(mlb_pipeline_config* c, const char* path);
// The same from memory (path names the text in errors); c is left as it was on error.
mlb_status mlb_pipeline_config_parse(mlb_pipeline_config* c, const char* text, size_t n, const char* path);
#define MLB_PIPELINE_CONFIG_MAX (1 << 20)   // bytes of a config.json
// One config.json key from "KEY=VALUE" (the CLI's --set; numbers and strings as config.json has
// them, "envs" as names comma-separated): MLB_ERR_ARG naming the key when it is unknown or the value
// has the wrong type; c is unchanged then. Ranges are checked by mlb_pipeline_validate.
mlb_status mlb_pipeline_config_set(mlb_pipeline_config* c, const char* assignment);
// The first config.json key whose values differ between a and b ("envs" for the pool), skipping the
// keys of `ignore` (NULL-terminated, may be NULL); NULL when every other saved setting is the same.
const char* mlb_pipeline_config_differs(const mlb_pipeline_config* a, const mlb_pipeline_config* b,
                                        const char* const* ignore);

typedef struct {
    double geometry_loss, appearance_loss;   // the last step's guidance losses
    long geometry_steps, appearance_steps;   // steps done by this invocation
    int n_verts, n_faces;                    // the final mesh
    int finished;                            // 1 when both stages are complete and final/ is written
} mlb_pipeline_result;

// Runs (or, resume != 0, continues) the run in dir. The guidance is created by the caller from the
// config (or by mlb_pipeline_make_guidance) and borrowed. views: image guidance's data set (its
// environments are the appearance stage's lights), NULL for SDS (the config's pool). be: where the
// stages run, the caller's choice (the program's --device): a GPU's table puts the material
// network, its AdamW, the shading and the per-pixel buffers on that GPU, in fp32 whatever its
// precision (the networks are small); NULL or a CPU table keeps them on the CPU. The final renders
// and the extraction run on the CPU either way. progress may be NULL.
mlb_status mlb_pipeline_run(const char* dir, const mlb_pipeline_config* c, mlb_guidance* g, const mlb_views* views,
                            const struct mlb_backend* be, int resume, mlb_progress* progress,
                            mlb_pipeline_result* result);
// A process that runs several generations (bench text3d, generate --prompts) fits the same
// starting shapes for each one with a seed (--init auto: four, ~7% of a `tiny` generation). With
// bytes > 0 the fits of the built-in shapes are kept (their parameters, at most `bytes`, the oldest
// dropped first) and a repeat takes them: the same bits as fitting again (src/pipeline/shape_fits.c).
// 0 (the default) keeps none and frees what is kept. Not thread-safe: call it between runs.
void mlb_pipeline_keep_shape_fits(size_t bytes);
#define MLB_PIPELINE_KEEP_FITS_BYTES ((size_t)256 << 20)
// Reads c->prompt for the project's own models (caption.h): when c->model or c->appearance_model
// is one of them (sd_model.h, mlb_sd_model_is_own) c->caption becomes the prompt's canonical
// caption, or MLB_ERR_ARG names the words they never saw; otherwise c->caption is "" and the prompt
// goes as typed. A caption naming a view is refused: the guidance adds the views' own. Called for
// a new run before anything is made; a resumed run keeps its config's caption.
mlb_status mlb_pipeline_read_prompt(mlb_pipeline_config* c);
// Creates the guidance a config asks for: SDS (loads the model; the guidance owns it) or images
// (loads the views folder at c->res into *views_out, which the caller frees with
// mlb_pipeline_free_views after the guidance). be: the device and GEMM precision the SDS models run
// at (be->device, be->precision), the caller's choice; NULL: the CPU in fp32.
mlb_status mlb_pipeline_make_guidance(const mlb_pipeline_config* c, const struct mlb_backend* be, mlb_guidance** out,
                                      mlb_views** views_out);
void mlb_pipeline_free_views(mlb_views* v);

// ---- a finished run (final/) -----------------------------------------------------------------
typedef struct {
    mlb_mesh mesh;                  // final/mesh.obj (positions, faces, normals)
    mlb_material_net material;      // final/material.safetensors
    mlb_pipeline_config config;     // config.json when present, else the defaults
} mlb_run_asset;
mlb_status mlb_run_asset_load(mlb_run_asset* a, const char* dir);
void mlb_run_asset_free(mlb_run_asset* a);
// Per-vertex BRDF [V,7] of the asset's mesh (the material field at the vertices).
mlb_status mlb_run_asset_vertex_brdf(const mlb_run_asset* a, float* k);
// The material field as an mlb_material_fn (user = the const mlb_run_asset*), at points of final/mesh.obj's
// frame: for renders that show each pixel's own material, as the baked asset does.
mlb_status mlb_run_asset_material(void* user, const float* pos, size_t n, float* k);

#endif
