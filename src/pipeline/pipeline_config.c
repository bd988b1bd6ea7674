// The pipeline's settings: defaults (paper §4, reference.md §7), validation and config.json.
#include <cjson/cJSON.h>
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/device.h"
#include "matlaber/fileio.h"
#include "matlaber/json_why.h"
#include "matlaber/pipeline.h"

mlb_pipeline_config mlb_pipeline_default(void) {
    mlb_pipeline_config c;
    memset(&c, 0, sizeof c);
    snprintf(c.guidance, sizeof c.guidance, "sds");
    c.guidance_scale = 100.0;
    c.latent_iters = -1;   // → geometry_iters / 3
    c.view_prompts = 1;
    c.seed = 0;
    c.views = 9;
    c.res = 512;
    c.ss = 1;
    c.geometry_iters = 3000;
    c.geometry_lr = 1e-3;
    c.grid = 128;
    snprintf(c.init, sizeof c.init, "ellipsoid");
    c.init_iters = 400;
    c.sdf_reg = mlb_sdf_reg_default();
    c.appearance_iters = 2000;
    c.appearance_lr = 1e-2;
    c.metal_start_lr_scale = 1;
    c.material = MLB_MATERIAL_LATENT;
    c.w_mat = 0.03;
    c.w_mat_spec = 0.1;         // docs/pipeline.md: demo albedo +2.2 dB, relighting +0.35 dB
    c.coarse_to_fine = 0.5;     // docs/pipeline.md: demo Chamfer 0.00167 -> 0.00117
    c.mat_sigma = 0.01;
    c.material_support_radius = 4.2;   // 99% of the built-in prior's data codes (docs/appearance.md)
    c.n_envs = 3;
    snprintf(c.envs[0], sizeof c.envs[0], "sky");
    snprintf(c.envs[1], sizeof c.envs[1], "studio");
    snprintf(c.envs[2], sizeof c.envs[2], "overcast");
    c.fixed_env = 0;
    c.env_height = 256;
    c.cube_size = 128;
    c.export_texture = 1024;
    c.checkpoint_every = 100;
    c.preview_every = 100;
    c.stop_after = 0;
    c.paint_keep_uv = 1;
    return c;
}

mlb_status mlb_pipeline_preset(mlb_pipeline_config* c, const char* name) {
    if (!strcmp(name, "paper")) return MLB_OK;   // the defaults are the paper's
    if (!strcmp(name, "tiny")) {
        // The project's own model (models/matlaber-tiny, `sd train`): 128² renders, 16² latents in
        // both geometry phases, a few views per step; docs/sd_train.md.
        c->views = 4;
        c->res = 128;
        c->latent_size = 16;
        c->latent_iters = 0;      // the model never saw raw [normal, mask] latents: VAE phase from the start
        // Measured on "a gold goblet" (docs/sd_train.md): grid 64 and t from 20 shred the surface
        // into spikes; grid 32 (16 cells per axis for a 128² render) and t >= 150 give a goblet
        // 120 + 60 steps: on gold goblet / mug the same class, Chamfer (0.0215 / 0.025) and metal calls
        // as 240 + 120, in half the time (docs/sd_train.md, "Text to 3D with it")
        c->geometry_iters = 120;
        c->appearance_iters = 60;
        c->grid = 32;
        c->hash_log2 = 16;        // 16 cells per axis need no 2^19-entry tables: dense Adam was 14% of a step
        // The geometry network's hash grid no finer than the grid's 16 cells: with the paper's levels
        // (16..4096) every grid vertex has its own SDF and the guidance's noise crumples the surface
        // (22 prompts: median normal error 30.1 -> 21.7°; docs/geometry.md, "Smoothness")
        c->geometry_hash_levels = 8;
        c->geometry_hash_base_res = 4;
        c->geometry_hash_max_res = 16;
        c->geometry_t_min = 150;
        c->init_iters = 100;
        // The model picks the start (docs/pipeline.md, Init): a ring from the torus (a hole cannot
        // open from the ellipsoid), everything else from the ellipsoid as before. A fixed torus won
        // both rings but turned the green teapot into a vase (docs/pipeline.md, "Init"). Grid 32:
        // 48 and 64 keep a table's surface alive but shredded.
        snprintf(c->init, sizeof c->init, "auto");
        // 10 in the geometry stage: the shapes nearer their class (on 22 prompts, every class in gold
        // and red: Chamfer lower on 17, mean -0.0013; docs/sd_train.md, "Text to 3D with it"). It
        // washed gold out only while both stages shared one scale.
        c->guidance_scale = 10.0;
        // The appearance stage at 20 paints gold as a saturated yellow diffuse on most shapes (a mug,
        // vase, teapot: kd 0.8, ks 0.02); at 100 (the paper's) they come out metal and every material's
        // RMSE drops, dielectrics stay dielectric (metal calls 0.57 -> 0.75 on 28 prompts)
        c->appearance_guidance_scale = 100.0;
        // From the prior's centre (a dielectric) score distillation finds a dielectric's colour but
        // seldom crosses to a metal: silver missed the metal call on 10 of 11 prompts. The
        // model's own score picks the start (docs/pipeline.md, "Material start")
        c->material_start = 1;
        // and refines it at a tenth of the rate: at 0.01 the metal starts' kd grew in noisy tinted
        // spots on 6 of 13 and 2 went back to a diffuse (metal kept on 5); at 0.001 on all 13, with
        // material RMSE 0.248 -> 0.071 (docs/pipeline.md, "Material start"). Every run
        // that does not start from a metal keeps 0.01: gold crosses to a metal only at that rate.
        c->metal_start_lr_scale = 0.1;
        // At guidance scale 100 score distillation drives some dielectrics' codes to |z| 8..28, far
        // outside the prior's data (99% within 4.2), where its decoder saturates: kd 1 or 0,
        // roughness at its floor (a red bowl black). Held inside: on the 7 such of 22 prompts the
        // colour read right 6 -> 7, relighting better on all 7 (docs/appearance.md, "The prior's support")
        c->material_support = 100;
        c->env_height = 128;
        c->cube_size = 64;
        c->checkpoint_every = 50;
        c->preview_every = 50;
        // the UNet's and VAE's GEMMs in bf16 where the CPU has it (fp32 elsewhere): a step 0.37 -> 0.20 s
        snprintf(c->precision, sizeof c->precision, "bf16");
        return MLB_OK;
    }
    if (strcmp(name, "cpu") != 0)
        return mlb_fail(MLB_ERR_ARG, "--preset: '%s' is not one of %s", name, MLB_PIPELINE_PRESETS);
    // Sized with bench_pipeline --sd15 --precision bf16 on 2 cores of an AMD EPYC (docs/pipeline.md,
    // "Presets"): one view per step; a latent-phase step (the SD 1.5 UNet at 64², batch 2) costs
    // ~11.3 s, a 256² VAE-phase geometry or appearance step ~5.1 s (UNet at 32² 2.3 s + the VAE
    // encoder's forward and backward ~2.8 s): ~42 minutes of steps, the rest of the hour a margin.
    c->views = 1;
    c->res = 256;
    c->geometry_iters = 180;      // the first third in the latent phase (64² normal-map latents)
    c->appearance_iters = 240;
    c->grid = 64;                 // 32 cells per axis: a 256² render resolves no finer surface
    c->init_iters = 200;
    c->env_height = 128;
    c->cube_size = 64;
    c->checkpoint_every = 10;     // ~2 minutes of work between checkpoints
    c->preview_every = 20;
    snprintf(c->precision, sizeof c->precision, "bf16");
    return MLB_OK;
}

int mlb_pipeline_cells(const mlb_pipeline_config* c) { return c->grid / 2 > 0 ? c->grid / 2 : 1; }

// The geometry hash grid's levels, coarsest and finest resolution, each 0 as the default's (the paper's).
static void geometry_hash_span(const mlb_pipeline_config* c, int* levels, int* base_res, int* max_res) {
    *levels = c->geometry_hash_levels ? c->geometry_hash_levels : MLB_HASHGRID_DEFAULT_LEVELS;
    *base_res = c->geometry_hash_base_res ? c->geometry_hash_base_res : MLB_HASHGRID_DEFAULT_BASE_RES;
    *max_res = c->geometry_hash_max_res ? c->geometry_hash_max_res : MLB_HASHGRID_DEFAULT_MAX_RES;
}

// All 0: the default's span again, the same bits as mlb_hashgrid_default's (test_pipeline).
void mlb_pipeline_geometry_hash(const mlb_pipeline_config* c, mlb_hashgrid_config* enc) {
    int levels, base_res, max_res;
    geometry_hash_span(c, &levels, &base_res, &max_res);
    mlb_hashgrid_set_span(enc, levels, base_res, max_res);
}

int mlb_pipeline_init_is_auto(const char* init) { return !strncmp(init, "auto", 4) && (init[4] == 0 || init[4] == ':'); }

// The paint keys' default, +0 to the bit: a config.json without paint_mesh does not store them, so a
// -0 there would not read back (found by fuzz_config).
static int plus_zero(double x) { return x == 0 && !signbit(x); }

int mlb_prompt_is_blank(const char* p) {
    for (; p && *p; p++)
        if (!isspace((unsigned char)*p)) return 0;
    return 1;
}

mlb_status mlb_pipeline_validate(const mlb_pipeline_config* c) {
    const char* bad = NULL;
    mlb_gemm_precision prec;
    int span_levels, span_base, span_max;
    geometry_hash_span(c, &span_levels, &span_base, &span_max);
    if (strcmp(c->guidance, "sds") && strcmp(c->guidance, "images")) bad = "guidance must be \"sds\" or \"images\"";
    else if (!strcmp(c->guidance, "sds") && !c->model[0]) bad = "score distillation needs a model (-m)";
    else if (!strcmp(c->guidance, "sds") && mlb_prompt_is_blank(c->prompt)) bad = "a prompt is required (score distillation reads one)";
    else if (!strcmp(c->guidance, "images") && !c->views_dir[0]) bad = "image guidance needs a views folder (--views)";
    else if (strcmp(c->guidance, "sds") && c->appearance_model[0])
        bad = "appearance_model is a model for score distillation: image guidance (--views) has none";
    else if (c->views < 1 || c->views > 64) bad = "views per step must be in 1..64";
    else if (c->view_batch < 0 || c->view_batch > 64) bad = "view_batch must be 0 (all of a step's views in one call) or 1..64";
    else if (c->res < 16 || c->res > 2048 || c->res % 8) bad = "--res must be a multiple of 8 in 16..2048";
    else if (c->ss < 1 || c->ss > 4 || c->res * c->ss > 4096) bad = "supersampling must be 1..4 (res x ss <= 4096)";
    else if (c->geometry_iters < 0 || c->appearance_iters < 0 || c->geometry_iters > MLB_PIPELINE_MAX_ITERS ||
             c->appearance_iters > MLB_PIPELINE_MAX_ITERS)
        bad = "iteration counts (geometry_iters, appearance_iters) must be in 0..10000000";
    else if (c->latent_iters < -1 || c->latent_iters > MLB_PIPELINE_MAX_ITERS)
        bad = "latent_iters must be in 0..10000000 (-1: a third of the geometry steps)";
    else if (c->latent_size != 0 && (c->latent_size < 8 || c->latent_size > MLB_PIPELINE_MAX_LATENT || c->latent_size % 8))
        bad = "latent_size must be 0 (64) or a multiple of 8 in 8..256";
    else if (c->grid < 8 || c->grid > 512) bad = "--grid must be in 8..512";
    else if (!(c->geometry_lr >= MLB_PIPELINE_LR_MIN && c->geometry_lr <= MLB_PIPELINE_LR_MAX) ||
             !(c->appearance_lr >= MLB_PIPELINE_LR_MIN && c->appearance_lr <= MLB_PIPELINE_LR_MAX))
        bad = "learning rates (geometry_lr, appearance_lr) must be in [1e-9, 10]";
    else if (c->init_iters < 0 || c->init_iters > MLB_PIPELINE_MAX_INIT_ITERS) bad = "init_iters must be in 0..1000000";
    else if (c->hash_log2 != 0 && (c->hash_log2 < 10 || c->hash_log2 > 24)) bad = "hash_table_log2 must be 0 (19) or 10..24";
    else if (c->geometry_hash_levels < 0 || c->geometry_hash_levels > MLB_HASHGRID_MAX_LEVELS)
        bad = "geometry_hash_levels must be 0 (16) or 1..32";
    else if (c->geometry_hash_base_res < 0 || c->geometry_hash_base_res == 1 || c->geometry_hash_base_res > 4096 ||
             c->geometry_hash_max_res < 0 || c->geometry_hash_max_res == 1 || c->geometry_hash_max_res > 4096)
        bad = "geometry_hash_base_res and geometry_hash_max_res must be 0 (16 and 4096) or 2..4096";
    else if (span_max < span_base)
        bad = "geometry_hash_max_res must not be below geometry_hash_base_res";
    else if (span_levels == 1 && span_max != span_base)
        bad = "one hash-grid level (geometry_hash_levels 1) has one resolution: geometry_hash_max_res = geometry_hash_base_res";
    else if (c->geometry_t_min < 0 || c->geometry_t_min > 500) bad = "geometry_t_min must be in 0..500 (0: the guidance's 20)";
    else if (c->geometry_t_max_end != 0 && (c->geometry_t_max_end < (c->geometry_t_min ? c->geometry_t_min : 20) || c->geometry_t_max_end > 999))
        bad = "geometry_t_max_end must be 0 (no annealing) or between the smallest timestep and 999";
    else if (c->appearance_t_max_end != 0 && (c->appearance_t_max_end < 20 || c->appearance_t_max_end > 999))
        bad = "appearance_t_max_end must be 0 (no annealing) or in 20..999";
    else if (!(c->coarse_to_fine >= 0 && c->coarse_to_fine <= 1)) bad = "coarse-to-fine: a fraction of the geometry steps in [0, 1]";
    else if (c->surface_smooth < 0 || c->surface_smooth > 1000) bad = "surface_smooth: 0..1000 rounds";
    else if (!(c->sdf_reg.start >= 0) || !(c->sdf_reg.end >= 0) || !(c->sdf_reg.frac >= 0)) bad = "regulariser weights must be >= 0";
    else if (!(c->sdf_reg.start <= 1e6) || !(c->sdf_reg.end <= 1e6) || !(c->sdf_reg.frac <= 1e6))
        bad = "regulariser weights must be <= 1e6";
    else if (!(c->w_mat >= 0 && c->w_mat <= MLB_PIPELINE_MAX_WEIGHT) || !(c->w_mat_spec >= 0 && c->w_mat_spec <= MLB_PIPELINE_MAX_WEIGHT) ||
             !(c->mat_sigma > 0 && c->mat_sigma <= 1))
        bad = "material smoothness: weights in [0, 100] and sigma in (0, 1]";
    else if (c->n_envs < 1 || c->n_envs > MLB_PIPELINE_MAX_ENVS) bad = "the environment pool needs 1..8 entries";
    else if (c->env_height < 16 || c->env_height > 4096) bad = "environment height must be in 16..4096";
    else if (c->cube_size < 64 || c->cube_size > 1024 || (c->cube_size & (c->cube_size - 1)))
        bad = "cube size must be a power of two in 64..1024";
    else if (c->checkpoint_every < 1 || c->checkpoint_every > MLB_PIPELINE_MAX_ITERS) bad = "checkpoint_every must be in 1..10000000";
    else if (c->preview_every < 0 || c->preview_every > MLB_PIPELINE_MAX_ITERS) bad = "preview_every must be in 0..10000000";
    else if (c->fixed_env != 0 && c->fixed_env != 1) bad = "fixed_env must be 0 or 1";
    else if (c->view_prompts != 0 && c->view_prompts != 1) bad = "view_prompts must be 0 or 1";
    else if (c->material_start != 0 && c->material_start != 1)
        bad = "material_start must be 0 (the prior's centre) or 1 (the model picks among archetypes)";
    else if (!(c->metal_start_lr_scale > 0) || !(c->metal_start_lr_scale <= 1))
        bad = "metal_start_lr_scale must be in (0, 1]";
    else if (!(c->material_support >= 0 && c->material_support <= 1e6) ||
             !(c->material_support_radius > 0 && c->material_support_radius <= 100))
        bad = "material_support must be in [0, 1e6] and material_support_radius in (0, 100]";
    else if (!(c->guidance_scale >= 0 && c->guidance_scale <= MLB_PIPELINE_MAX_SCALE))
        bad = "the guidance scale (--guidance-scale, guidance_scale) must be in [0, 10000]";
    else if (!(c->appearance_guidance_scale >= 0 && c->appearance_guidance_scale <= MLB_PIPELINE_MAX_SCALE))
        bad = "the appearance guidance scale (--appearance-guidance-scale, appearance_guidance_scale) must be in [0, 10000] "
              "(0: the guidance scale's)";
    else if (!strcmp(c->init, "")) bad = "--init must be ellipsoid, cylinder, torus, slab, cup, auto[:A,B,..] or an OBJ file";
    else if (mlb_pipeline_init_is_auto(c->init) && c->init[4] == ':' &&
             (!c->init[5] || strstr(c->init, ",,") || c->init[strlen(c->init) - 1] == ','))
        bad = "--init auto:A,B,..: the candidates are names or OBJ files separated by commas, none empty";
    else if (mlb_pipeline_init_is_auto(c->init) && strcmp(c->guidance, "sds") != 0)
        bad = "--init auto picks the shape by the diffusion model's score: it needs SDS guidance (a prompt), not images";
    else if (c->export_texture < 0 || c->export_texture > 16384) bad = "export texture size must be 0 (none) or 1..16384";
    else if (c->precision[0] && mlb_gemm_precision_parse(c->precision, &prec) != MLB_OK)
        bad = "precision must be empty (the program's) or one of --precision's names";
    else if (c->paint_mesh[0] && c->geometry_iters != 0) bad = "a paint run has no geometry stage (geometry_iters 0)";
    else if (c->paint_keep_uv != 0 && c->paint_keep_uv != 1) bad = "paint_keep_uv must be 0 or 1";
    else if (!c->paint_mesh[0] && (c->paint_keep_uv != 1 || !plus_zero(c->paint_scale) ||
                                   !plus_zero(c->paint_centre[0]) || !plus_zero(c->paint_centre[1]) ||
                                   !plus_zero(c->paint_centre[2])))
        bad = "paint_keep_uv, paint_centre_* and paint_scale belong to paint runs (paint_mesh)";
    else if (!(c->paint_scale >= 0) || !isfinite(c->paint_scale) || !isfinite(c->paint_centre[0]) ||
             !isfinite(c->paint_centre[1]) || !isfinite(c->paint_centre[2]))
        bad = "the paint frame (paint_centre_*, paint_scale) must be finite, the scale >= 0";
    if (bad) return mlb_fail(MLB_ERR_ARG, "pipeline config: %s", bad);
    for (int i = 0; i < c->n_envs; i++)
        if (!c->envs[i][0]) return mlb_fail(MLB_ERR_ARG, "pipeline config: environment %d is empty", i);
    return MLB_OK;
}

// ---- config.json -------------------------------------------------------------------------------
// One table drives both directions so that a field cannot be saved and forgotten on load.
typedef enum { F_STR, F_INT, F_LONG_U64, F_DOUBLE, F_MATERIAL } field_kind;
// optional: a key that older run folders lack; missing, it keeps the default, which is what those
// runs ran with (so an old run resumes as it started). Each optional key's comment says that value.
typedef struct { const char* key; field_kind kind; size_t offset; size_t size; int optional; double legacy; } field;
#define FLD(k, kind, member) {k, kind, offsetof(mlb_pipeline_config, member), sizeof(((mlb_pipeline_config*)0)->member), 0, 0}
// legacy: the value a run written before the key existed ran with (numbers only)
#define FLD_OPT(k, kind, member, legacy) \
    {k, kind, offsetof(mlb_pipeline_config, member), sizeof(((mlb_pipeline_config*)0)->member), 1, legacy}
static const field FIELDS[] = {
    FLD("guidance", F_STR, guidance),           FLD("prompt", F_STR, prompt),
    FLD("negative", F_STR, negative),           FLD("model", F_STR, model),
    FLD("views_dir", F_STR, views_dir),         FLD("guidance_scale", F_DOUBLE, guidance_scale),
    FLD("latent_iters", F_INT, latent_iters),   FLD("seed", F_LONG_U64, seed),
    FLD("views", F_INT, views),                 FLD("res", F_INT, res),
    FLD("supersample", F_INT, ss),              FLD("geometry_iters", F_INT, geometry_iters),
    FLD("geometry_lr", F_DOUBLE, geometry_lr),  FLD("grid", F_INT, grid),
    FLD("init", F_STR, init),                   FLD("init_iters", F_INT, init_iters),
    FLD("sdf_reg_start", F_DOUBLE, sdf_reg.start), FLD("sdf_reg_end", F_DOUBLE, sdf_reg.end),
    FLD("sdf_reg_frac", F_DOUBLE, sdf_reg.frac), FLD("appearance_iters", F_INT, appearance_iters),
    FLD("appearance_lr", F_DOUBLE, appearance_lr), FLD("material", F_MATERIAL, material),
    FLD("material_smoothness", F_DOUBLE, w_mat), FLD("material_smoothness_sigma", F_DOUBLE, mat_sigma),
    FLD("fixed_env", F_INT, fixed_env),         FLD("env_height", F_INT, env_height),
    FLD("cube_size", F_INT, cube_size),         FLD("checkpoint_every", F_INT, checkpoint_every),
    FLD("preview_every", F_INT, preview_every),
    FLD_OPT("view_prompts", F_INT, view_prompts, 1),                  // missing: always on
    FLD_OPT("coarse_to_fine", F_DOUBLE, coarse_to_fine, 0),           // missing: off
    FLD_OPT("material_smoothness_specular", F_DOUBLE, w_mat_spec, 0), // missing: kd only
    FLD_OPT("export_texture", F_INT, export_texture, 0),              // missing: no .glb
    FLD_OPT("latent_size", F_INT, latent_size, 0),                    // missing: 64
    FLD_OPT("geometry_t_min", F_INT, geometry_t_min, 0),              // missing: 20
    FLD_OPT("hash_table_log2", F_INT, hash_log2, 0),                  // missing: 2^19
    FLD_OPT("geometry_hash_levels", F_INT, geometry_hash_levels, 0),  // missing: 16
    FLD_OPT("geometry_hash_base_res", F_INT, geometry_hash_base_res, 0),  // missing: 16
    FLD_OPT("geometry_hash_max_res", F_INT, geometry_hash_max_res, 0),    // missing: 4096
    FLD_OPT("view_batch", F_INT, view_batch, 0),                      // missing: one call a step
    FLD_OPT("precision", F_STR, precision, 0),                        // missing: the program's
    FLD_OPT("appearance_guidance_scale", F_DOUBLE, appearance_guidance_scale, 0),  // missing: guidance_scale
    FLD_OPT("tokenizer", F_STR, tokenizer, 0),                        // missing: none (folders only)
    FLD_OPT("geometry_t_max_end", F_INT, geometry_t_max_end, 0),      // missing: no annealing
    FLD_OPT("appearance_t_max_end", F_INT, appearance_t_max_end, 0),  // missing: no annealing
    FLD_OPT("material_start", F_INT, material_start, 0),              // missing: the prior's centre
    FLD_OPT("metal_start_lr_scale", F_DOUBLE, metal_start_lr_scale, 1),  // missing: the same rate
    FLD_OPT("material_support", F_DOUBLE, material_support, 0),      // missing: off
    FLD_OPT("material_support_radius", F_DOUBLE, material_support_radius, 4.2),
    FLD_OPT("appearance_model", F_STR, appearance_model, 0),          // missing: the model's
    FLD_OPT("surface_smooth", F_INT, surface_smooth, 0),              // missing: the surface as extracted
    FLD_OPT("caption", F_STR, caption, 0),                            // written when set; missing: the prompt as typed
    // paint runs only (written when paint_mesh is set)
    FLD_OPT("paint_mesh", F_STR, paint_mesh, 0),
    FLD_OPT("paint_keep_uv", F_INT, paint_keep_uv, 1),
    FLD_OPT("paint_centre_x", F_DOUBLE, paint_centre[0], 0),
    FLD_OPT("paint_centre_y", F_DOUBLE, paint_centre[1], 0),
    FLD_OPT("paint_centre_z", F_DOUBLE, paint_centre[2], 0),
    FLD_OPT("paint_scale", F_DOUBLE, paint_scale, 0),
};
#undef FLD
#undef FLD_OPT
#define N_FIELDS (sizeof FIELDS / sizeof *FIELDS)

// A double as the shortest decimal that reads back as the same bits (cJSON prints 15 digits when
// they come within an epsilon: 0.8888888888888888 was saved as 0.888888888888889, and a resumed run
// read another number than the one it started with).
static void add_double(cJSON* root, const char* key, double v) {
    char buf[40];
    for (int digits = 15; digits <= 17; digits++) {
        snprintf(buf, sizeof buf, "%.*g", digits, v);
        if (strtod(buf, NULL) == v) break;
    }
    cJSON_AddRawToObject(root, key, buf);
}

char* mlb_pipeline_config_text(const mlb_pipeline_config* c) {
    cJSON* root = cJSON_CreateObject();
    if (!root) return NULL;
    cJSON_AddStringToObject(root, "format", "matlaber-run");
    cJSON_AddNumberToObject(root, "version", 1);
    for (size_t i = 0; i < N_FIELDS; i++) {
        const field* f = &FIELDS[i];
        const char* p = (const char*)c + f->offset;
        if (!c->paint_mesh[0] && !strncmp(f->key, "paint_", 6)) continue;   // generate and fit runs: as before
        if (!c->caption[0] && !strcmp(f->key, "caption")) continue;          // the prompt as typed: as before
        switch (f->kind) {
        case F_STR: cJSON_AddStringToObject(root, f->key, p); break;
        case F_INT: cJSON_AddNumberToObject(root, f->key, *(const int*)p); break;
        case F_LONG_U64: {   // JSON numbers are doubles: a 64-bit seed goes as a decimal string
            char buf[32];
            snprintf(buf, sizeof buf, "%llu", (unsigned long long)*(const uint64_t*)p);
            cJSON_AddStringToObject(root, f->key, buf);
            break;
        }
        case F_DOUBLE: add_double(root, f->key, *(const double*)p); break;
        case F_MATERIAL: cJSON_AddStringToObject(root, f->key, mlb_material_mode_name(*(const mlb_material_mode*)p)); break;
        }
    }
    cJSON* envs = cJSON_AddArrayToObject(root, "envs");
    for (int i = 0; envs && i < c->n_envs; i++) cJSON_AddItemToArray(envs, cJSON_CreateString(c->envs[i]));
    char* text = cJSON_Print(root);
    cJSON_Delete(root);
    if (!text) return NULL;
    size_t n = strlen(text);
    char* out = malloc(n + 2);   // with a final newline, ours to free()
    if (out) {
        memcpy(out, text, n);
        memcpy(out + n, "\n", 2);
    }
    cJSON_free(text);
    return out;
}

mlb_status mlb_pipeline_config_save(const mlb_pipeline_config* c, const char* path) {
    char* text = mlb_pipeline_config_text(c);
    if (!text) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path);
    mlb_status s = mlb_write_file_atomic(path, text, strlen(text));
    free(text);
    return s;
}

// One field's value from its JSON item into p (config.json's types; `where` names the file or option).
static mlb_status parse_field(const field* f, const cJSON* it, char* p, const char* where) {
    int want_string = f->kind == F_STR || f->kind == F_LONG_U64 || f->kind == F_MATERIAL;
    if (want_string ? !cJSON_IsString(it) : !cJSON_IsNumber(it))
        return mlb_fail(MLB_ERR_FORMAT, "%s: \"%s\" must be a %s", where, f->key, want_string ? "string" : "number");
    switch (f->kind) {
    case F_STR:
        if (strlen(it->valuestring) >= f->size) return mlb_fail(MLB_ERR_FORMAT, "%s: \"%s\" is too long", where, f->key);
        snprintf(p, f->size, "%s", it->valuestring);
        return MLB_OK;
    case F_INT:
        if (it->valuedouble != floor(it->valuedouble) || !isfinite(it->valuedouble))
            return mlb_fail(MLB_ERR_FORMAT, "%s: \"%s\" must be an integer", where, f->key);
        if (!(fabs(it->valuedouble) < 2e9))
            return mlb_fail(MLB_ERR_FORMAT, "%s: \"%s\" = %.17g is out of range", where, f->key, it->valuedouble);
        *(int*)p = (int)it->valuedouble;
        return MLB_OK;
    case F_LONG_U64: {
        char* end = NULL;
        errno = 0;
        unsigned long long v = strtoull(it->valuestring, &end, 10);
        if (!isdigit((unsigned char)it->valuestring[0]) || *end)
            return mlb_fail(MLB_ERR_FORMAT, "%s: \"%s\" must be a decimal integer string", where, f->key);
        if (errno == ERANGE)   // strtoull would give 2^64 - 1 in its place
            return mlb_fail(MLB_ERR_FORMAT, "%s: \"%s\" is more than 18446744073709551615", where, f->key);
        *(uint64_t*)p = (uint64_t)v;
        return MLB_OK;
    }
    case F_DOUBLE:
        if (!isfinite(it->valuedouble)) return mlb_fail(MLB_ERR_FORMAT, "%s: \"%s\" is not finite", where, f->key);
        *(double*)p = it->valuedouble;
        return MLB_OK;
    case F_MATERIAL:
        if (mlb_material_mode_parse(it->valuestring, (mlb_material_mode*)p))
            return mlb_fail(MLB_ERR_FORMAT, "%s: \"%s\" must be \"latent\" or \"direct\"", where, f->key);
        return MLB_OK;
    }
    return MLB_OK;
}

static const field* find_field(const char* key) {
    for (size_t i = 0; i < N_FIELDS; i++)
        if (!strcmp(FIELDS[i].key, key)) return &FIELDS[i];
    return NULL;
}

mlb_status mlb_pipeline_config_set(mlb_pipeline_config* c, const char* assignment) {
    const char* eq = strchr(assignment, '=');
    char key[64];
    if (!eq || eq == assignment || (size_t)(eq - assignment) >= sizeof key)
        return mlb_fail(MLB_ERR_ARG, "--set %s: expected KEY=VALUE with a config.json key", assignment);
    memcpy(key, assignment, (size_t)(eq - assignment));
    key[eq - assignment] = 0;
    const char* text = eq + 1;
    if (!strcmp(key, "envs")) {   // the pool: names or files, comma-separated, none empty
        mlb_pipeline_config t = *c;
        t.n_envs = 0;
        for (const char* p = text;; p++) {
            size_t n = strcspn(p, ",");
            if (!n || n >= sizeof t.envs[0] || t.n_envs == MLB_PIPELINE_MAX_ENVS)
                return mlb_fail(MLB_ERR_ARG, "--set %s: 1..%d names or files, comma-separated, none empty", assignment,
                                MLB_PIPELINE_MAX_ENVS);
            snprintf(t.envs[t.n_envs++], sizeof t.envs[0], "%.*s", (int)n, p);
            p += n;
            if (!*p) break;
        }
        *c = t;
        return MLB_OK;
    }
    const field* f = find_field(key);
    if (!f) return mlb_fail(MLB_ERR_ARG, "--set %s: \"%s\" is not a key of config.json (docs/pipeline.md)", assignment, key);
    cJSON* it;
    if (f->kind == F_INT || f->kind == F_DOUBLE) {
        char* end = NULL;
        double v = strtod(text, &end);
        if (!text[0] || *end) return mlb_fail(MLB_ERR_ARG, "--set %s: \"%s\" must be a number", assignment, key);
        it = cJSON_CreateNumber(v);
    } else
        it = cJSON_CreateString(text);
    if (!it) return mlb_fail(MLB_ERR_NOMEM, "--set: out of memory");
    mlb_pipeline_config t = *c;
    mlb_status s = parse_field(f, it, (char*)&t + f->offset, "--set");   // ranges: when the run validates
    cJSON_Delete(it);
    if (s) return mlb_fail_context(s, "--set %s", assignment);
    *c = t;
    return MLB_OK;
}

const char* mlb_pipeline_config_differs(const mlb_pipeline_config* a, const mlb_pipeline_config* b,
                                        const char* const* ignore) {
    for (size_t i = 0; i < N_FIELDS; i++) {
        const field* f = &FIELDS[i];
        int skip = 0;
        for (const char* const* k = ignore; k && *k && !skip; k++) skip = !strcmp(*k, f->key);
        const char *p = (const char*)a + f->offset, *q = (const char*)b + f->offset;
        if (!skip && (f->kind == F_STR ? strcmp(p, q) != 0 : memcmp(p, q, f->size) != 0)) return f->key;
    }
    if (a->n_envs != b->n_envs) return "envs";
    for (int i = 0; i < a->n_envs; i++)
        if (strcmp(a->envs[i], b->envs[i])) return "envs";
    return NULL;
}

mlb_status mlb_pipeline_config_load(mlb_pipeline_config* out, const char* path) {
    char* text = NULL;
    size_t n = 0;
    mlb_status s = mlb_read_file(path, &text, &n, MLB_PIPELINE_CONFIG_MAX);
    if (s) return s;
    s = mlb_pipeline_config_parse(out, text, n, path);
    free(text);
    return s;
}

mlb_status mlb_pipeline_config_parse(mlb_pipeline_config* out, const char* text, size_t n, const char* path) {
    cJSON* root = cJSON_ParseWithLength(text, n);
    if (!root || !cJSON_IsObject(root)) {
        char why[96];
        if (!root) mlb_json_why(text, n, why, sizeof why);
        cJSON_Delete(root);
        return mlb_fail(MLB_ERR_FORMAT, "%s: not a JSON object%s%s%s", path, root ? "" : " (", root ? "" : why, root ? "" : ")");
    }
    mlb_status s = MLB_OK;
    mlb_pipeline_config c = mlb_pipeline_default();
    const cJSON* fmt = cJSON_GetObjectItemCaseSensitive(root, "format");
    if (!cJSON_IsString(fmt) || strcmp(fmt->valuestring, "matlaber-run") != 0)
        s = mlb_fail(MLB_ERR_FORMAT, "%s: \"format\" is not \"matlaber-run\"", path);
    for (size_t i = 0; !s && i < N_FIELDS; i++) {
        const field* f = &FIELDS[i];
        const cJSON* it = cJSON_GetObjectItemCaseSensitive(root, f->key);
        char* p = (char*)&c + f->offset;
        if (!it && f->optional) {   // a run from before the key: what it ran with, not today's default
            if (f->kind == F_DOUBLE) *(double*)p = f->legacy;
            else if (f->kind == F_INT) *(int*)p = (int)f->legacy;
            continue;
        }
        if (!it) { s = mlb_fail(MLB_ERR_FORMAT, "%s: missing \"%s\"", path, f->key); break; }
        s = parse_field(f, it, p, path);
    }
    const cJSON* envs = cJSON_GetObjectItemCaseSensitive(root, "envs");
    if (!s && !cJSON_IsArray(envs)) s = mlb_fail(MLB_ERR_FORMAT, "%s: \"envs\" must be an array of strings", path);
    if (!s) {
        int n_envs = cJSON_GetArraySize(envs);
        if (n_envs < 1 || n_envs > MLB_PIPELINE_MAX_ENVS)
            s = mlb_fail(MLB_ERR_FORMAT, "%s: \"envs\" must hold 1..%d names", path, MLB_PIPELINE_MAX_ENVS);
        c.n_envs = n_envs;
        for (int i = 0; !s && i < n_envs; i++) {
            const cJSON* e = cJSON_GetArrayItem(envs, i);
            if (!cJSON_IsString(e) || strlen(e->valuestring) >= sizeof c.envs[i])
                s = mlb_fail(MLB_ERR_FORMAT, "%s: envs[%d] must be a string (name or file)", path, i);
            else snprintf(c.envs[i], sizeof c.envs[i], "%s", e->valuestring);
        }
    }
    cJSON_Delete(root);
    if (!s) s = mlb_pipeline_validate(&c);
    if (s) return mlb_fail_context(s, "%s", path);
    *out = c;
    return MLB_OK;
}
