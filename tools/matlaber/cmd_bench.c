// matlaber bench text3d: text to 3D against known truth (include/matlaber/text3d.h,
// docs/benchmarks.md). Every catalogue caption "a {material} {class}" (or a subset) is generated
// with one fixed preset into a normal run folder and measured: shape against every class, the
// material against its 7 numbers, relighting under a light no run saw.
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cli.h"
#include "matlaber/caption.h"
#include "matlaber/catalogue.h"
#include "matlaber/dist.h"
#include "matlaber/log.h"
#include "matlaber/text3d.h"

static const cli_option options[] = {
    {"classes", 1, 'c', "A,B,..", "the classes to prompt (default all)"},
    {"materials", 1, 'M', "X,Y,..", "the materials to prompt (default all)"},
    {"pairs", 1, 'p', "C:M,..", "these class:material prompts instead (e.g. vase:gold,table:red)"},
    {"phrasing", 1, 'P', "K|mixed", "each caption written in held-out form K (1..5: \"A golden goblet.\", \"a goblet made of\n"
                                    "                           gold\", ...) or a form per pair (mixed); default 0, the catalogue's"},
    {"preset", 1, 'Q', "NAME", "the generation preset (default tiny)"},
    {"model", 1, 'm', "PATH", "Stable Diffusion folder or file (default the project's own model, as generate)"},
    {"appearance-model", 1, 'y', "PATH", "another model for the appearance stage (generate's --appearance-model)"},
    {"seed", 1, 's', "S", "the runs' seed (default 0)"},
    {"steps-scale", 1, 'S', "F", "both stages' steps times F, at least 1 each (quick runs; default 1)"},
    {"material", 1, 'a', "latent|direct", "the material network's output (direct: the no-prior ablation)"},
    {"fixed-env", 0, 'F', NULL, "ablation: one light, never rotated"},
    {"no-view-prompts", 0, 'W', NULL, "ablation: one prompt for every view"},
    {"init", 1, 'I', "SHAPE", "the starting shape (generate's --init; default the preset's: auto for tiny)"},
    {"set", 1, 'D', "KEY=VALUE", "a key of the runs' config.json over the preset (generate's --set; repeatable)"},
    {"shape-seeds", 1, 'K', "K", "truth shapes per class, seeds 0..K-1 (default 8): the fit's starts"},
    {"shape-fit", 1, 'f', "N", "rounds of the shape-parameter fit from the best seed (default 64; 0: best seed only)"},
    {"relight-env", 1, 'e', "NAME|FILE", "the unseen relighting light (default white)"},
    {"out", 1, 'o', "DIR", "the run folders, DIR/<class>_<material> (default bench-text3d); a rerun resumes"},
    {"json", 1, 'j', "FILE", "the table and summary as JSON"},
    {"sheet", 1, 'G', "FILE.png", "a contact sheet: each prompt's truth beside its asset (docs/images/text3d.png)"},
    {"sheet-env", 1, 'E', "NAME|FILE", "the contact sheet's light (default studio)"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

// "a,b" into idx[] by parse(); at most MLB_TEXT3D_MAX_CLASSES. 0 on success.
static int parse_list(const char* text, int* idx, int* n, mlb_status (*parse)(const char*, int*)) {
    char buf[1024];
    snprintf(buf, sizeof buf, "%s", text);
    *n = 0;
    for (char* tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
        if (*n >= MLB_TEXT3D_MAX_CLASSES || parse(tok, &idx[*n])) return -1;
        (*n)++;
    }
    return *n ? 0 : -1;
}

// "vase:gold,table:red" into the config's pairs. 0 on success.
static int parse_pairs(const char* text, mlb_text3d_bench_config* bc) {
    char buf[4096];
    if (snprintf(buf, sizeof buf, "%s", text) >= (int)sizeof buf) return -1;
    bc->n_pairs = 0;
    for (char* tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
        char* colon = strchr(tok, ':');
        if (!colon || bc->n_pairs >= MLB_TEXT3D_MAX_PAIRS) return -1;
        *colon = 0;
        if (mlb_catalogue_class_parse(tok, &bc->pair_class[bc->n_pairs]) ||
            mlb_catalogue_material_parse(colon + 1, &bc->pair_material[bc->n_pairs]))
            return -1;
        bc->n_pairs++;
    }
    return bc->n_pairs ? 0 : -1;
}

static int bench_text3d(int argc, char** argv) {
    const char* cmd = "bench text3d";
    mlb_text3d_bench_config bc = mlb_text3d_bench_default();
    const char *preset = "tiny", *model = NULL, *appearance_model = NULL, *json = NULL, *init = NULL, *sheet = NULL;
    const char* sheet_env = "studio";
    long v;
    double x, scale = 1.0;
    uint64_t seed = 0;
    mlb_material_mode material = MLB_MATERIAL_LATENT;
    int fixed_env = 0, view_prompts = 1;
    const struct option* table = cli_getopt_table(options);
    optind = 1;
    int opt;
    while ((opt = getopt_long(argc, argv, "hm:o:s:", table, NULL)) != -1) {
        switch (opt) {
        case 'c':
            if (parse_list(optarg, bc.classes, &bc.n_classes, mlb_catalogue_class_parse)) return cli_usage_error(cmd, "--classes: %s", mlb_last_error());
            break;
        case 'M':
            if (parse_list(optarg, bc.materials, &bc.n_materials, mlb_catalogue_material_parse)) return cli_usage_error(cmd, "--materials: %s", mlb_last_error());
            break;
        case 'p':
            if (parse_pairs(optarg, &bc)) return cli_usage_error(cmd, "--pairs: expected class:material,... (%s)", mlb_last_error());
            break;
        case 'P':
            if (!strcmp(optarg, "mixed")) mlb_caption_set_bench_phrasing(MLB_CAPTION_PHRASING_MIXED);
            else if (cli_parse_long(optarg, 0, MLB_CAPTION_N_PHRASINGS, &v))
                return cli_usage_error(cmd, "--phrasing: expected 0..%d or mixed", MLB_CAPTION_N_PHRASINGS);
            else mlb_caption_set_bench_phrasing((int)v);
            break;
        case 'Q': preset = optarg; break;
        case 'm': model = optarg; break;
        case 'y': appearance_model = optarg; break;
        case 's': if (cli_parse_long(optarg, 0, 0x7fffffffffffffffL, &v)) return cli_usage_error(cmd, "--seed: expected a non-negative integer"); seed = (uint64_t)v; break;
        case 'S': if (cli_parse_double(optarg, 1e-6, 100, &x)) return cli_usage_error(cmd, "--steps-scale: expected a number in (0, 100]"); scale = x; break;
        case 'a': if (mlb_material_mode_parse(optarg, &material)) return cli_usage_error(cmd, "--material: expected latent or direct"); break;
        case 'F': fixed_env = 1; break;
        case 'W': view_prompts = 0; break;
        case 'I': init = optarg; break;
        case 'D':
            if (bc.n_set == MLB_TEXT3D_MAX_SET) return cli_usage_error(cmd, "--set: at most %d", MLB_TEXT3D_MAX_SET);
            bc.set[bc.n_set++] = optarg;
            break;
        case 'K': if (cli_parse_long(optarg, 1, 1024, &v)) return cli_usage_error(cmd, "--shape-seeds: expected 1..1024"); bc.n_seeds = (int)v; break;
        case 'f': if (cli_parse_long(optarg, 0, 1000, &v)) return cli_usage_error(cmd, "--shape-fit: expected 0..1000"); bc.measure.fit_rounds = (int)v; break;
        case 'e': bc.relight_env = optarg; break;
        case 'o': bc.out_dir = optarg; break;
        case 'j': json = optarg; break;
        case 'G': sheet = optarg; break;
        case 'E': sheet_env = optarg; break;
        case 'h':
            printf("usage: matlaber bench text3d [--classes A,B] [--materials X,Y] | [--pairs C:M,..] [-o DIR] [--json FILE] [options]\n\n"
                   "Text to 3D against known truth: every catalogue prompt \"a {material} {class}\" (seen and held-out\n"
                   "pairs, docs/catalogue.md) is generated with one preset into DIR/<class>_<material> (a normal run:\n"
                   "export and view take it; a finished one is reused, a stopped one resumed) and measured: Chamfer\n"
                   "distance (relative to the truth's diagonal) to the best-fitting member of every class (the best\n"
                   "of K shape seeds, then its shape parameters fitted; class right when the prompted one is nearest),\n"
                   "the median BRDF on the surface against the material's (RMSE over the 7 numbers; metal when mean\n"
                   "ks > %.2f and mean kd < %.2f), and relighting PSNR against the prompted class's best-fitting\n"
                   "member in the true material under a light no run saw; against that member, the surface: normal\n"
                   "error (degrees), completeness and accuracy (95th percentiles of the distances), each thin part's\n"
                   "completeness (legs, handles, stems, spout, shade, the ring's hole); and the colour (which material\n"
                   "it reads as). --sheet draws every prompt's truth beside its asset.\n"
                   "Writes DIR/report.md. On several processes (mpirun -n 2 matlaber --threads 1 bench text3d) each\n"
                   "process takes every other prompt, with the same numbers; times: docs/benchmarks.md.\n\n",
                   MLB_TEXT3D_METAL_KS, MLB_TEXT3D_METAL_KD);
            cli_print_options(stdout, options);
            return 0;
        default: return cli_usage_error(cmd, "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error(cmd, "unexpected argument '%s'", argv[optind]);
    if (!model) {   // the project's own models, as generate takes them
        model = cli_default_model();
        if (!appearance_model) appearance_model = cli_default_appearance_model();
    }
    if (!model) return cli_usage_error(cmd, "--model is required: the project's own model is not there (docs/sd_train.md)");
    mlb_status s = mlb_text3d_base_config(&bc.base, preset, model, seed, scale, material, fixed_env, view_prompts);
    if (!s && appearance_model) {
        if (strlen(appearance_model) >= sizeof bc.base.appearance_model)
            return cli_usage_error(cmd, "--appearance-model: a path of at most %zu bytes", sizeof bc.base.appearance_model - 1);
        snprintf(bc.base.appearance_model, sizeof bc.base.appearance_model, "%s", appearance_model);
    }
    if (!s && init) {
        if (strlen(init) >= sizeof bc.base.init) return cli_usage_error(cmd, "--init: a path of at most %zu bytes", sizeof bc.base.init - 1);
        snprintf(bc.base.init, sizeof bc.base.init, "%s", init);
    }
    for (int i = 0; !s && i < bc.n_set; i++) s = mlb_pipeline_config_set(&bc.base, bc.set[i]);
    if (!s && bc.n_set) {   // ranges: with a prompt, as a run would check them
        mlb_pipeline_config t = bc.base;
        snprintf(t.prompt, sizeof t.prompt, "a gold goblet");
        s = mlb_pipeline_validate(&t);
    }
    if (s) return cli_usage_error(cmd, "%s", mlb_last_error());
    bc.progress = mlb_log_get_level() <= MLB_LOG_INFO;
    bc.be = cli_run_backend(bc.base.precision);   // --device, and the preset's own precision as generate takes it
    if (bc.n_pairs && (bc.n_classes || bc.n_materials)) return cli_usage_error(cmd, "--pairs replaces --classes and --materials");
    int cap = bc.n_pairs ? bc.n_pairs
                         : (bc.n_classes ? bc.n_classes : mlb_catalogue_n_classes()) *
                               (bc.n_materials ? bc.n_materials : mlb_catalogue_n_materials());
    mlb_text3d_row* rows = calloc((size_t)cap, sizeof *rows);
    if (!rows) return cli_fail(mlb_fail(MLB_ERR_NOMEM, "out of memory"), cmd);
    int n = 0;
    mlb_text3d_summary sum;
    s = mlb_text3d_bench_run(&bc, rows, &n, &sum);   // on several processes: every row on every one
    const int lead = mlb_dist_world_rank() == 0;       // which alone prints and writes the JSON
    if (n && lead) {
        printf("\n");
        mlb_text3d_print(stdout, &bc, rows, n, &sum);
    }
    mlb_status sj = json && n && lead ? mlb_text3d_write_json(json, &bc, rows, n, &sum) : MLB_OK;
    // the sheet: the materials of one class a line when the prompts are the cross product
    int cols = bc.n_pairs ? (n < 8 ? n : 8) : (bc.n_materials ? bc.n_materials : mlb_catalogue_n_materials());
    if (!sj && sheet && n && lead) sj = mlb_text3d_sheet_write(sheet, rows, n, sheet_env, bc.base.env_height, bc.base.cube_size, 128, cols);
    free(rows);
    cli_rc_agreed = !sj;   // the run's status is agreed by every process (a failed JSON is rank 0's own)
    if (s) return cli_fail(s, cmd);
    if (sj) return cli_fail(sj, cmd);
    if (lead) printf("\nreport: %s/report.md%s%s%s%s\n", bc.out_dir, json ? ", JSON: " : "", json ? json : "",
                     sheet ? ", contact sheet: " : "", sheet ? sheet : "");
    return 0;
}

int cmd_bench(int argc, char** argv) {
    if (argc >= 2 && !strcmp(argv[1], "text3d")) return bench_text3d(argc - 1, argv + 1);
    if (argc >= 2 && (!strcmp(argv[1], "--help") || !strcmp(argv[1], "-h"))) {
        printf("usage: matlaber bench text3d [options]   text to 3D against the catalogue's known truth\n");
        return 0;
    }
    return cli_usage_error("bench", "expected a benchmark: text3d");
}
