// matlaber generate | fit | paint: the two-stage pipeline (docs/pipeline.md) with score distillation
// from a Stable Diffusion checkpoint, or with image guidance from a views folder (no weights); paint
// runs the appearance stage alone on a given mesh (docs/paint.md).
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cli.h"
#include "matlaber/device.h"
#include "matlaber/dist.h"
#include "matlaber/fileio.h"
#include "matlaber/log.h"
#include "matlaber/paint.h"
#include "matlaber/run_textured.h"
#include "matlaber/pipeline.h"
#include "matlaber/views.h"

static const cli_option options[] = {
    {"preset", 1, 'Q', "NAME", "generate: paper (default: the paper's schedule, 9 views at 512², for a GPU), tiny (the\n"
                               "                           project's own model: 4 views at 128², 16² latents) or cpu\n"
                               "                           (1 view at 256², a short schedule, bf16 GEMMs where the CPU has them:\n"
                               "                           sized for SD 1.5 on 2 CPU cores); options after it override it\n"
                               "                           (docs/pipeline.md)"},
    {"prompt", 1, 'p', "TEXT", "generate, paint: the text prompt (the project's own models read only the catalogue's\n"
                               "                           captions, written in any of their usual ways: docs/catalogue.md)"},
    {"model", 1, 'm', "PATH", "generate: Stable Diffusion 1.x/2.x checkpoint (file or diffusers folder); default: the\n"
                              "                           project's own model (models/matlaber-tiny or $MATLABER_MODEL) with --preset tiny"},
    {"appearance-model", 1, 'y', "PATH", "generate, paint: another checkpoint for the appearance stage (default: the --model's;\n"
                                         "                           docs/pipeline.md, \"A model per stage\")"},
    {"negative", 1, 'n', "TEXT", "generate: negative prompt (default: the paper's per stage)"},
    {"views", 1, 'V', "N|DIR", "generate: views per step (default 9); fit: the views folder (docs/views.md)"},
    {"views-per-step", 1, 'v', "N", "fit: views per step (default 4)"},
    {"view-batch", 1, 'B', "K", "views per guidance call (default 0: all of a step's views in one call); under mpirun\n"
                                "                           the batches go whole to the processes: any K gives the same bits on\n"
                                "                           any number of processes, another K other bits (docs/pipeline.md)"},
    {"init", 1, 'I', "SHAPE", "ellipsoid, cylinder, torus (hole to the front), slab (a flat plate), cup (an open shell), auto (the one of ellipsoid, torus, slab and cup the model scores clearly best for the prompt, checked 20 steps ahead; auto:A,B,.. among these names or OBJ files) or FILE.obj (default ellipsoid; the tiny preset auto)"},
    {"init-iters", 1, 'J', "N", "steps of the SDF initialisation to the --init shape (default 400; the cpu preset 200, tiny 100)"},
    {"coarse-to-fine", 1, 'C', "F", "hash-grid levels unlocked from 4 to all over this fraction of the geometry steps (default 0.5; 0 = all at once)"},
    {"spec-smoothness", 1, 'K', "W", "material smoothness weight on ks and roughness (default 0.1; 0 = kd only, as the paper)"},
    {"geometry-iters", 1, 'G', "N", "geometry stage steps (generate 3000, fit 400)"},
    {"appearance-iters", 1, 'A', "N", "appearance stage steps (generate 2000, fit 400)"},
    {"res", 1, 'r', "N", "render size (generate 512, fit 128)"},
    {"grid", 1, 'g', "N", "DMTet grid, Fantasia3D's naming: 128 = 64 cells per axis (generate 128, fit 64)"},
    {"hash-table-log2", 1, 'H', "N", "both hash grids: 2^N entries per hashed level (default 19, the paper's; the tiny preset 16)"},
    {"geometry-lr", 1, 'L', "X", "geometry stage learning rate (generate 1e-3, fit 1e-2)"},
    {"appearance-lr", 1, 'l', "X", "appearance stage learning rate (1e-2)"},
    {"env", 1, 'e', "NAME|FILE", "generate: the environment pool (repeat or comma-separate; default sky,studio,overcast);\n"
                                 "                           fit: the light of views that name none (default sky)"},
    {"fixed-env", 0, 'F', NULL, "generate: the first environment only, never rotated (Fantasia3D's setting)"},
    {"no-view-prompts", 0, 'W', NULL, "generate: one prompt for every view (default: \", front view\" etc. by the camera)"},
    {"material", 1, 'M', "latent|direct", "material network output: the prior's latent (default) or the 7-d BRDF"},
    {"guidance-scale", 1, 'S', "X", "generate: classifier-free guidance scale (100)"},
    {"tokenizer", 1, 'k', "PATH", "generate, paint: the CLIP tokenizer of a single-file checkpoint (the merges .gz, a tokenizer/\n"
                                  "                           folder or a diffusers folder; default $MATLABER_TOKENIZER; a diffusers model has its own)"},
    {"appearance-guidance-scale", 1, 'E', "X", "generate, paint: the appearance stage's, when it differs (default: --guidance-scale's; the tiny preset 100)"},
    {"geometry-t-min", 1, 'U', "T", "generate: the geometry stage's smallest SDS timestep (default 20)"},
    {"seed", 1, 's', "S", "seed of every random draw (default 0)"},
    {"set", 1, 'D', "KEY=VALUE", "any key of the run's config.json (docs/pipeline.md), e.g. geometry_t_max_end=300;\n"
                                 "                           applied in order with the other options (repeatable)"},
    {"export-texture", 1, 'T', "N", "texture size of RUN_DIR/final/asset.glb, written at the end (generate 1024;\n"
                                    "                           fit and 0: none, `matlaber export` makes one later)"},
    {"checkpoint-every", 1, 'c', "N", "steps between checkpoints (default 100)"},
    {"preview-every", 1, 'P', "N", "steps between preview renders, 0 = none (default 100)"},
    {"resume", 1, 'R', "RUN_DIR", "continue a run that was stopped (its config.json is used)"},
    {"stop-after", 1, 'X', "N", "stop after N steps of this invocation, as if killed (testing resume)"},
    {"mesh", 1, 'Y', "FILE", "paint: the mesh to paint, .obj, .glb or .gltf (its vertices, faces and UVs are kept)"},
    {"uv", 1, 'u', "keep|atlas", "paint: bake on the mesh's own UVs (keep, default; an atlas when it has none) or\n"
                                 "                           replace them with the project's atlas (atlas)"},
    {"asset", 1, 'a', "FILE", "paint: also write the result there (.glb, or .obj with .mtl and PNGs beside it)"},
    {"out", 1, 'o', "RUN_DIR", "the run directory (must not exist or be empty); with --prompts the folder of the runs"},
    {"prompts", 1, 'Z', "FILE", "generate: one prompt per line, one run folder each in -o DIR, handed to the processes\n"
                                "                           as they free up (mpirun -n N); finished runs are skipped, stopped\n"
                                "                           ones resumed; ends with a table and DIR/summary.json (docs/pipeline.md)"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

static int add_envs(mlb_pipeline_config* c, const char* text, int* reset) {
    if (*reset) { c->n_envs = 0; *reset = 0; }
    char buf[4096];
    snprintf(buf, sizeof buf, "%s", text);
    for (char* tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
        if (c->n_envs >= MLB_PIPELINE_MAX_ENVS) return -1;
        snprintf(c->envs[c->n_envs++], sizeof c->envs[0], "%s", tok);
    }
    return 0;
}

// fit: config.json names the views folder's environments (the run's lights are the folder's own).
static int envs_from_views(mlb_pipeline_config* c) {
    mlb_views_meta m;
    mlb_status s = mlb_views_meta_read(&m, c->views_dir);
    if (s) return cli_fail(s, "fit");
    if (m.n_envs > MLB_PIPELINE_MAX_ENVS) {
        mlb_views_meta_free(&m);
        return cli_fail(mlb_fail(MLB_ERR_UNSUPPORTED, "%s: %d environments (at most %d)", c->views_dir, m.n_envs,
                                 MLB_PIPELINE_MAX_ENVS), "fit");
    }
    if (m.n_envs > 0) c->n_envs = m.n_envs;
    for (int i = 0; i < m.n_envs; i++)
        snprintf(c->envs[i], sizeof c->envs[i], "%s", m.envs[i].name[0] ? m.envs[i].name : m.envs[i].file);
    mlb_views_meta_free(&m);
    return 0;
}

// --prompts (cmd_prompts.c) runs prompts through run_pipeline without progress bars or the closing
// message (several processes would interleave them)
static int g_batch;
// generate_check_args: the run_pipeline's checks, then return before anything is loaded
static int g_check_only;

int generate_option_arity(const char* name) {
    for (const cli_option* o = options; o->name; o++)
        if (!strcmp(o->name, name)) return o->has_arg;
    return -1;
}


// paint: --asset FILE, the finished run's asset written as .glb or OBJ + MTL (atomically; on failure
// nothing is left).
static int write_asset(const char* dir, int size, const char* asset) {
    mlb_run_textured t;
    mlb_status s = mlb_run_textured_load(&t, dir, size);
    if (!s) s = mlb_ends_with(asset, ".obj") ? mlb_export_obj(asset, &t.asset) : mlb_run_textured_write_glb(&t, asset);
    if (!s) mlb_log(MLB_LOG_INFO, "wrote %s (%d vertices, %d faces, %d² textures)", asset, t.asset.n_verts, t.asset.n_faces, size);
    mlb_run_textured_free(&t);
    return s ? cli_fail(s, "--asset") : 0;
}

enum { MODE_GENERATE, MODE_FIT, MODE_PAINT };

// What a command line says beyond the run's config.
typedef struct {
    const char* preset;         // --preset, or "tiny" with the project's own model
    const char* out;            // -o RUN_DIR
    const char* resume;         // --resume RUN_DIR
    const char* asset;          // paint --asset FILE
    const char* set;            // the last --set (a resumed run refuses it)
    long stop_after;            // --stop-after
    int help;                   // --help was printed: nothing more to do
} run_args;

// fit's defaults over the pipeline's: image guidance on a small, quick schedule.
static void fit_defaults(mlb_pipeline_config* c) {
    snprintf(c->guidance, sizeof c->guidance, "images");
    c->geometry_iters = 400;
    c->appearance_iters = 400;
    c->res = 128;
    c->grid = 64;
    c->views = 4;
    c->geometry_lr = 1e-2;
    c->preview_every = 50;
    c->checkpoint_every = 50;
    c->export_texture = 0;
}

// --preset first, whatever its place: the other options override it. NULL when none is named.
static const char* find_preset(int argc, char** argv) {
    const char* preset = NULL;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--preset") && i + 1 < argc) preset = argv[++i];
        else if (!strncmp(argv[i], "--preset=", 9)) preset = argv[i] + 9;
    }
    return preset;
}

// generate and paint with no -m (nor --resume, --help, or paint's --views DIR): the project's own
// model into c, with its preset unless another is named. 0, or the usage error's exit status.
static int take_own_model(const char* command, int argc, char** argv, int is_paint, mlb_pipeline_config* c,
                          const char** preset) {
    for (int i = 1; i < argc; i++)
        if (!strcmp(argv[i], "-m") || !strcmp(argv[i], "--model") || !strncmp(argv[i], "--model=", 8) ||
            (is_paint && i + 1 < argc && !strcmp(argv[i], "--views") && cli_parse_long(argv[i + 1], 1, 64, &(long){0})) ||
            !strcmp(argv[i], "--resume") || !strncmp(argv[i], "--resume=", 9) || !strcmp(argv[i], "-h") ||
            !strcmp(argv[i], "--help"))
            return 0;
    const char* m = cli_default_model();
    if (!m) return cli_usage_error(command, "-m MODEL is required: no Stable Diffusion weights given and the project's own "
                                   "model is not there (train it: matlaber sd train -o models/%s; docs/sd_train.md)",
                                   MLB_DEFAULT_MODEL);
    const char* am = cli_default_appearance_model();   // --appearance-model, when given, replaces it
    if (strlen(m) > CLI_MAX_ARG || (am && strlen(am) > CLI_MAX_ARG))   // ($MATLABER_MODEL: not an argument)
        return cli_usage_error(command, "$MATLABER_MODEL or $MATLABER_APPEARANCE_MODEL: a path of more than %d bytes",
                               CLI_MAX_ARG);
    snprintf(c->model, sizeof c->model, "%s", m);
    if (am) snprintf(c->appearance_model, sizeof c->appearance_model, "%s", am);
    if (!*preset) *preset = "tiny";
    return 0;
}

static void print_help(int mode) {
    const int is_fit = mode == MODE_FIT, is_paint = mode == MODE_PAINT;
    if (is_paint)
        printf("usage: matlaber paint --mesh FILE.obj|.glb|.gltf -p PROMPT [-m MODEL] -o RUN_DIR [--asset FILE.glb] [options]\n"
               "       matlaber paint --mesh FILE --views DIR -o RUN_DIR                  (image guidance)\n"
               "       matlaber paint --resume RUN_DIR\n\n"
               "The appearance stage alone on a given mesh: its vertices, faces and UVs are kept, it is moved\n"
               "into the generation frame for the cameras (centred, radius 0.9) and a material field is fitted\n"
               "with the same guidance, view prompts, rotating environments and BRDF prior as generate. Without\n"
               "-m the project's own model with --preset tiny. Ends with RUN_DIR/final/asset.glb (kd, ks and\n"
               "roughness baked on the mesh's own UVs, an atlas where it has none, at the original positions)\n"
               "and --asset FILE. Broken meshes are refused with the file and the problem (docs/paint.md).\n\n");
    else if (is_fit)
        printf("usage: matlaber fit --views DIR -o RUN_DIR [options]\n"
               "       matlaber fit --resume RUN_DIR\n\n"
               "Fits a mesh and its material field to multi-view images (no diffusion weights): the two stages\n"
               "of the paper with image guidance: silhouettes and normal maps for the geometry, colour under the\n"
               "views' known environments for the appearance. `matlaber render --views-out DIR` makes such a\n"
               "folder. Outputs: RUN_DIR/final (mesh.obj with kd/ks/roughness vertex colours, networks, renders),\n"
               "loss.csv + loss.png, previews/, checkpoints/ (docs/pipeline.md, docs/runs.md).\n\n");
    else
        printf("usage: matlaber generate -p PROMPT -m MODEL -o RUN_DIR [options]\n"
               "       matlaber generate --resume RUN_DIR\n"
               "       matlaber generate --prompts FILE -o DIR [options]\n"
               "       mpirun -n N matlaber generate ...   (srun -n N under Slurm)\n\n"
               "Text to 3D with materials (the paper): DMTet geometry by score distillation on normal maps, then\n"
               "a hash-grid material network predicting latent BRDF codes, decoded by the frozen BRDF prior and\n"
               "shaded under rotating environments, again by score distillation. Defaults are the paper's\n"
               "(docs/pipeline.md); on a CPU use --preset cpu. Ends with RUN_DIR/final/asset.glb.\n\n"
               "Under mpirun the N processes share one run: each renders and guides its share of every step's\n"
               "views, and the result is bitwise the one process's (a run resumes on any number). With --prompts\n"
               "each process takes the next prompt when it is free. FILE: a prompt per line, optionally after\n"
               "options of this command (\"--seed 3 --name goblet3 a gold goblet\"); # starts a comment.\n\n");
    cli_print_options(stdout, options);
}

// The options over c (the preset already applied), in their order. 0, or the usage error's exit
// status; a->help when --help was printed.
static int parse_options(const char* command, int argc, char** argv, int mode, mlb_pipeline_config* c, run_args* a) {
    const int is_fit = mode == MODE_FIT, is_paint = mode == MODE_PAINT;
    const char* geometry_option = NULL;   // paint: the first geometry-stage option given (refused)
    int appearance_scale_given = 0;
    long v;
    double x;
    int env_reset = 1;
    const struct option* table = cli_getopt_table(options);
    optind = 1;
    int opt;
    while ((opt = getopt_long(argc, argv, "hp:m:n:o:", table, NULL)) != -1) {
        if (is_paint && !geometry_option && strchr("ICGgLU", opt))   // the geometry stage's options
            for (const cli_option* o = options; o->name; o++)
                if (o->val == opt) geometry_option = o->name;
        switch (opt) {
        case 'Q': break;   // applied above
        case 'p':   // checked here, where it is read: a blank prompt would run and fail much later
            if (mlb_prompt_is_blank(optarg))
                return cli_usage_error(command, "a prompt is required: the one given is %s", optarg[0] ? "only spaces" : "empty");
            snprintf(c->prompt, sizeof c->prompt, "%s", optarg);
            break;
        case 'm': snprintf(c->model, sizeof c->model, "%s", optarg); break;
        case 'y':
            if (strlen(optarg) >= sizeof c->appearance_model) return cli_usage_error(command, "--appearance-model: a path of at most %zu bytes", sizeof c->appearance_model - 1);
            snprintf(c->appearance_model, sizeof c->appearance_model, "%s", optarg);
            break;
        case 'n': snprintf(c->negative, sizeof c->negative, "%s", optarg); break;
        case 'V':
            if (is_fit || (is_paint && cli_parse_long(optarg, 1, 64, &v))) {
                snprintf(c->views_dir, sizeof c->views_dir, "%s", optarg);   // paint: image guidance
                snprintf(c->guidance, sizeof c->guidance, "images");
            } else if (cli_parse_long(optarg, 1, 64, &v)) return cli_usage_error(command, "--views: expected 1..64");
            else c->views = (int)v;
            break;
        case 'v': if (cli_parse_long(optarg, 1, 64, &v)) return cli_usage_error(command, "--views-per-step: expected 1..64"); c->views = (int)v; break;
        case 'B': if (cli_parse_long(optarg, 0, 64, &v)) return cli_usage_error(command, "--view-batch: expected 0..64 (0: all views in one call)"); c->view_batch = (int)v; break;
        case 'I': snprintf(c->init, sizeof c->init, "%s", optarg); break;
        case 'J': if (cli_parse_long(optarg, 0, MLB_PIPELINE_MAX_INIT_ITERS, &v)) return cli_usage_error(command, "--init-iters: expected 0..1000000"); c->init_iters = (int)v; break;
        case 'C':
            if (cli_parse_double(optarg, 0, 1, &c->coarse_to_fine)) return cli_usage_error(command, "--coarse-to-fine: expected a fraction in [0, 1]");
            break;
        case 'K':
            if (cli_parse_double(optarg, 0, MLB_PIPELINE_MAX_WEIGHT, &c->w_mat_spec)) return cli_usage_error(command, "--spec-smoothness: expected a weight in [0, 100]");
            break;
        case 'G': if (cli_parse_long(optarg, 0, MLB_PIPELINE_MAX_ITERS, &v)) return cli_usage_error(command, "--geometry-iters: expected 0..10000000"); c->geometry_iters = (int)v; break;
        case 'A': if (cli_parse_long(optarg, 0, MLB_PIPELINE_MAX_ITERS, &v)) return cli_usage_error(command, "--appearance-iters: expected 0..10000000"); c->appearance_iters = (int)v; break;
        case 'r': if (cli_parse_long(optarg, 16, 2048, &v) || v % 8) return cli_usage_error(command, "--res: expected a multiple of 8 in 16..2048"); c->res = (int)v; break;
        case 'g': if (cli_parse_long(optarg, 8, 512, &v)) return cli_usage_error(command, "--grid: expected 8..512"); c->grid = (int)v; break;
        case 'H': if (cli_parse_long(optarg, 10, 24, &v)) return cli_usage_error(command, "--hash-table-log2: expected 10..24"); c->hash_log2 = (int)v; break;
        case 'L': if (cli_parse_double(optarg, MLB_PIPELINE_LR_MIN, MLB_PIPELINE_LR_MAX, &x)) return cli_usage_error(command, "--geometry-lr: expected a number in [1e-9, 10]"); c->geometry_lr = x; break;
        case 'l': if (cli_parse_double(optarg, MLB_PIPELINE_LR_MIN, MLB_PIPELINE_LR_MAX, &x)) return cli_usage_error(command, "--appearance-lr: expected a number in [1e-9, 10]"); c->appearance_lr = x; break;
        case 'e': if (add_envs(c, optarg, &env_reset)) return cli_usage_error(command, "--env: at most %d environments", MLB_PIPELINE_MAX_ENVS); break;
        case 'F': c->fixed_env = 1; break;
        case 'W': c->view_prompts = 0; break;
        case 'M':
            if (mlb_material_mode_parse(optarg, &c->material)) return cli_usage_error(command, "--material: expected latent or direct");
            break;
        case 'U': if (cli_parse_long(optarg, 0, 500, &v)) return cli_usage_error(command, "--geometry-t-min: expected 0..500"); c->geometry_t_min = (int)v; break;
        case 'S':
            // a number here; its range is the config's to check (mlb_pipeline_validate: settle_config)
            if (cli_parse_double(optarg, -HUGE_VAL, HUGE_VAL, &x)) return cli_usage_error(command, "--guidance-scale: expected a number");
            c->guidance_scale = x;
            if (is_paint && !appearance_scale_given) c->appearance_guidance_scale = 0;   // paint's one stage: this scale, not the preset's
            break;
        case 'k':
            if (strlen(optarg) >= sizeof c->tokenizer) return cli_usage_error(command, "--tokenizer: path too long");
            snprintf(c->tokenizer, sizeof c->tokenizer, "%s", optarg);
            break;
        case 'E':   // (its range: as --guidance-scale's)
            if (cli_parse_double(optarg, -HUGE_VAL, HUGE_VAL, &x)) return cli_usage_error(command, "--appearance-guidance-scale: expected a number");
            c->appearance_guidance_scale = x;
            appearance_scale_given = 1;
            break;
        case 'D': if (mlb_pipeline_config_set(c, optarg)) return cli_usage_error(command, "%s", mlb_last_error()); a->set = optarg; break;
        case 's': if (cli_parse_u64(optarg, &c->seed)) return cli_usage_error(command, "--seed: expected an integer in 0..18446744073709551615"); break;
        case 'T': if (cli_parse_long(optarg, 0, 16384, &v)) return cli_usage_error(command, "--export-texture: expected 0..16384"); c->export_texture = (int)v; break;
        case 'c': if (cli_parse_long(optarg, 1, MLB_PIPELINE_MAX_ITERS, &v)) return cli_usage_error(command, "--checkpoint-every: expected 1..10000000"); c->checkpoint_every = (int)v; break;
        case 'P': if (cli_parse_long(optarg, 0, MLB_PIPELINE_MAX_ITERS, &v)) return cli_usage_error(command, "--preview-every: expected 0..10000000"); c->preview_every = (int)v; break;
        case 'R': a->resume = optarg; break;
        case 'X': if (cli_parse_long(optarg, 1, 100000000, &v)) return cli_usage_error(command, "--stop-after: expected >= 1"); a->stop_after = v; break;
        case 'o': a->out = optarg; break;
        case 'Y': if (!is_paint) return cli_usage_error(command, "--mesh is an option of paint"); snprintf(c->paint_mesh, sizeof c->paint_mesh, "%s", optarg); break;
        case 'u':
            if (!is_paint) return cli_usage_error(command, "--uv is an option of paint");
            if (strcmp(optarg, "keep") && strcmp(optarg, "atlas")) return cli_usage_error(command, "--uv: expected keep or atlas");
            c->paint_keep_uv = !strcmp(optarg, "keep");
            break;
        case 'a':
            if (!is_paint) return cli_usage_error(command, "--asset is an option of paint");
            if (!mlb_ends_with(optarg, ".glb") && !mlb_ends_with(optarg, ".obj"))
                return cli_usage_error(command, "--asset %s: the name must end in .glb or .obj", optarg);
            a->asset = optarg;
            break;
        case 'Z': return cli_usage_error(command, "--prompts is an option of generate");
        case 'h':
            print_help(mode);
            a->help = 1;
            return 0;
        default: return cli_usage_error(command, "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error(command, "unexpected argument '%s'", argv[optind]);
    if (geometry_option) return cli_usage_error(command, "--%s: paint has no geometry stage (the mesh is given)", geometry_option);
    return 0;
}

// The run's config made whole and checked before anything is loaded: a resumed run's own
// config.json, or a new run's with what the options left open; validated; the prompt read for the
// project's own models; paint's mesh checked. 0, or the exit status.
static int settle_config(const char* command, int mode, const run_args* a, mlb_pipeline_config* c) {
    const int is_fit = mode == MODE_FIT, is_paint = mode == MODE_PAINT;
    mlb_status s;
    if (a->resume) {
        if (a->out && strcmp(a->out, a->resume) != 0) return cli_usage_error(command, "--resume continues RUN_DIR in place: drop -o");
        if (a->preset || a->set)
            return cli_usage_error(command, "--resume continues with the run's own settings (config.json): drop --%s",
                                   a->preset ? "preset" : "set");
        char path[4096];
        snprintf(path, sizeof path, "%s/config.json", a->resume);
        s = mlb_pipeline_config_load(c, path);
        if (s) return cli_fail(s, "--resume");
        const char* made_by = c->paint_mesh[0] ? "paint" : strcmp(c->guidance, "images") ? "generate" : "fit";
        if (strcmp(made_by, command) != 0)
            return cli_usage_error(command, "%s was made by `matlaber %s`: resume it with that command", a->resume, made_by);
    } else {
        if (!a->out) return cli_usage_error(command, "-o RUN_DIR is required");
        if (is_fit && !c->views_dir[0]) return cli_usage_error(command, "--views DIR is required");
        if (is_paint && !c->paint_mesh[0]) return cli_usage_error(command, "--mesh FILE (.obj, .glb or .gltf) is required");
        int sds = strcmp(c->guidance, "sds") == 0;
        if (!is_fit && sds && !c->prompt[0]) return cli_usage_error(command, "a prompt is required: what to make, as -p TEXT");
        if (!is_fit && sds && !c->model[0]) return cli_usage_error(command, "-m MODEL is required (Stable Diffusion weights you supply)");
        if (is_paint) c->geometry_iters = 0;
        if (!sds) {
            int rc = envs_from_views(c);
            if (rc) return rc;
        }
        if (c->latent_iters < 0) c->latent_iters = c->geometry_iters / 3;
    }
    c->stop_after = a->stop_after;
    s = mlb_pipeline_validate(c);
    if (s) return cli_fail(s, command);
    // the project's own models read only their catalogue's captions: a prompt is read into one
    // before anything is loaded or made, or refused naming the words they never saw
    if (!a->resume && mlb_pipeline_read_prompt(c)) return cli_usage_error(command, "%s", mlb_last_error());
    if (is_paint && !a->resume) {   // the mesh is checked before the model loads (seconds to minutes)
        mlb_mesh m;
        s = mlb_paint_load_mesh(c->paint_mesh, c->paint_keep_uv, &m, NULL);
        mlb_mesh_free(&m);
        if (s) return cli_fail(s, command);
    }
    return 0;
}

// A finished or stopped run's outcome: the result event for programs reading the progress stream,
// and the closing lines.
static void report_outcome(const char* command, const char* dir, const mlb_pipeline_config* c,
                           const mlb_pipeline_result* result, double seconds, const char* asset, int is_paint) {
    FILE* json = mlb_progress_json();
    if (json) {   // the outcome, for programs reading the progress stream
        fprintf(json, "{\"event\":\"result\",\"command\":\"%s\",\"finished\":%s,\"run\":", command,
                result->finished ? "true" : "false");
        mlb_json_write_string(json, dir);
        if (result->finished && c->export_texture > 0) {
            char glb[4200];
            snprintf(glb, sizeof glb, "%s/final/asset.glb", dir);
            fputs(",\"glb\":", json);
            mlb_json_write_string(json, glb);
        }
        if (result->finished && asset) {
            fputs(",\"asset\":", json);
            mlb_json_write_string(json, asset);
        }
        fprintf(json, ",\"vertices\":%d,\"faces\":%d,\"seconds\":%.2f}\n", result->n_verts, result->n_faces, seconds);
        fflush(json);
    }
    if (result->finished && is_paint)
        printf("%s: done in %.1f s: %d vertices, %d faces; last appearance loss %.4g\n"
               "outputs in %s/final (asset.glb, mesh.obj, material.safetensors, renders)%s%s, loss curve in %s/loss.png\n",
               command, seconds, result->n_verts, result->n_faces, result->appearance_loss, dir, asset ? " and " : "",
               asset ? asset : "", dir);
    else if (result->finished)
        printf("%s: done in %.1f s: %d vertices, %d faces; last losses geometry %.4g, appearance %.4g\n"
               "outputs in %s/final (%smesh.obj, material.safetensors, renders), loss curves in %s/loss.png\n",
               command, seconds, result->n_verts, result->n_faces, result->geometry_loss, result->appearance_loss, dir,
               c->export_texture > 0 ? "asset.glb, " : "", dir);
    else
        printf("%s: stopped after %ld + %ld steps (%.1f s); continue with: matlaber %s --resume %s\n", command,
               result->geometry_steps, result->appearance_steps, seconds, command, dir);
}

static int run_pipeline(const char* command, int argc, char** argv, int mode) {
    int rc = cli_check_args(argc, argv);   // (--prompts hands each line's options here)
    if (rc) return rc;
    mlb_pipeline_config c = mlb_pipeline_default();
    if (mode == MODE_FIT) fit_defaults(&c);
    run_args a = {0};
    a.preset = find_preset(argc, argv);
    if (mode != MODE_FIT && (rc = take_own_model(command, argc, argv, mode == MODE_PAINT, &c, &a.preset))) return rc;
    if (a.preset) {
        if (mode == MODE_FIT) return cli_usage_error(command, "--preset is an option of generate and paint");
        if (mlb_pipeline_preset(&c, a.preset)) return cli_usage_error(command, "%s", mlb_last_error());
    }
    if ((rc = parse_options(command, argc, argv, mode, &c, &a)) || a.help) return rc;
    mlb_status s;
    if (a.asset && (s = mlb_check_writable(a.asset))) return cli_fail(s, "--asset");   // before the run, not after it
    if ((rc = settle_config(command, mode, &a, &c))) return rc;
    if (g_check_only) return 0;   // (paint: after the mesh's checks)
    const char* dir = a.resume ? a.resume : a.out;
    mlb_guidance* g = NULL;
    mlb_views* views = NULL;
    const struct mlb_backend* be = cli_run_backend(c.precision);   // --device, and the run's own precision
    s = mlb_pipeline_make_guidance(&c, be, &g, &views);
    if (s) return cli_fail(s, command);
    mlb_progress progress;
    mlb_pipeline_result result;
    double t0 = mlb_now_seconds();
    s = mlb_pipeline_run(dir, &c, g, views, be, a.resume != NULL,
                         !g_batch && (mlb_log_get_level() <= MLB_LOG_INFO || mlb_progress_json()) ? &progress : NULL, &result);
    mlb_guidance_free(g);
    mlb_pipeline_free_views(views);
    if (s) return cli_fail(s, command);
    double seconds = mlb_now_seconds() - t0;
    if (g_batch) return result.finished ? 0 : GENERATE_STOPPED;
    if (mlb_dist_rank() > 0) return 0;   // rank 0 reports (and writes --asset) for every process of the run
    if (result.finished && a.asset) {
        rc = write_asset(dir, c.export_texture > 0 ? c.export_texture : 1024, a.asset);
        if (rc) return rc;
    }
    report_outcome(command, dir, &c, &result, seconds, a.asset, mode == MODE_PAINT);
    return 0;
}

int generate_run_quiet(int argc, char** argv) {
    g_batch = 1;
    int rc = run_pipeline("generate", argc, argv, MODE_GENERATE);
    g_batch = 0;
    return rc;
}

int generate_check_args(int argc, char** argv) {
    g_check_only = 1;
    int paint = !strcmp(argv[0], "paint");
    int rc = run_pipeline(argv[0], argc, argv, paint ? MODE_PAINT : MODE_GENERATE);
    g_check_only = 0;
    return rc;
}

int cmd_generate(int argc, char** argv) { return run_pipeline("generate", argc, argv, MODE_GENERATE); }
int cmd_fit(int argc, char** argv) { return run_pipeline("fit", argc, argv, MODE_FIT); }
int cmd_paint(int argc, char** argv) { return run_pipeline("paint", argc, argv, MODE_PAINT); }
