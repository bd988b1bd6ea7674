// matlaber: material-aware text-to-3D with a latent BRDF prior. The command-line program;
// one file per command group (cmd_*.c).
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "cli.h"
#include "matlaber/cpu.h"
#include "matlaber/device.h"
#include "matlaber/dist.h"
#include "matlaber/fileio.h"
#include "matlaber/log.h"
#include "matlaber/nn.h"
#include "matlaber/progress.h"
#include "matlaber/threads.h"

#define MATLABER_VERSION "0.1.0"

// generate --prompts FILE: the batch of prompts (cmd_prompts.c), which runs generate per prompt
static int names_prompts(int argc, char** argv) {
    for (int i = 1; i < argc; i++)
        if (!strcmp(argv[i], "--prompts") || !strncmp(argv[i], "--prompts=", 10)) return 1;
    return 0;
}

// relight takes a mesh (--mesh FILE.obj) or a finished run (RUN_DIR, a folder with config.json).
static int names_run_dir(int argc, char** argv) {
    for (int i = 1; i < argc; i++) {
        char path[4096];
        snprintf(path, sizeof path, "%s/config.json", argv[i]);
        if (argv[i][0] != '-' && mlb_is_dir(argv[i]) && mlb_is_file(path)) return 1;
    }
    return 0;
}

static void usage(FILE* out) {
    fprintf(out,
            "matlaber %s: material-aware text-to-3D with a latent BRDF auto-encoder\n\n"
            "usage: matlaber [--log-level debug|info|warn|error|quiet] [--threads N] [--device D] [--precision P]\n"
            "                [--progress text|json] <command> [options]\n\n"
            "commands:\n"
            "  demo            text to 3D with the project's own model (\"a gold goblet\"), measured against the\n"
            "                  catalogue's truth; demo --fit: the image-fitting demo\n"
            "  generate        text to 3D with materials: -p PROMPT [-m SD_MODEL] -o RUN_DIR (the paper)\n"
            "  fit             the same two stages fitted to multi-view images (no weights): --views DIR\n"
            "  paint           the appearance stage alone on your mesh: --mesh FILE.obj -p PROMPT -o RUN_DIR\n"
            "  brdf train      train a latent BRDF auto-encoder (the material prior)\n"
            "  brdf eval       reconstruction error vs PCA-4, KL, validity along interpolations\n"
            "  brdf encode     BRDF (kd, ks, kr) -> latent code\n"
            "  brdf decode     latent code -> BRDF\n"
            "  brdf interp     decoded BRDFs along a latent path\n"
            "  sd txt2img      text -> image with a Stable Diffusion checkpoint or the project's own model\n"
            "  sd train        train the project's own small text-to-image model on the catalogue (docs/sd_train.md)\n"
            "  sd tokenize     text -> the 77 CLIP token ids of the SD text encoders\n"
            "  geometry        init the DMTet geometry network from a shape; extract its surface\n"
            "  render          a mesh with one material under an environment light\n"
            "  catalogue       procedural objects x materials of known truth: list, export, render\n"
            "  bench text3d    text to 3D against the catalogue's truth: shape, material, relighting\n"
            "  relight         a mesh or a finished run while the light turns (PNG frames, MP4 with ffmpeg)\n"
            "  interp          on run A's geometry, A's material field to B's in latent space\n"
            "  export          a finished run as glTF (.glb) or OBJ + MTL with baked PBR textures\n"
            "  view            a static three.js page of a run (environments, light rotation, map toggles)\n"
            "  serve           a local web app and API: prompts in, live progress, assets out (docs/server.md)\n"
            "  device          list compute devices\n"
            "  version         print the version\n\n"
            "global options:\n"
            MLB_DEVICE_OPTION_HELP
            "                  (on a GPU the Stable Diffusion UNet and VAE run there, in 'sd txt2img' and\n"
            "                  'generate', and the appearance stage's material network and shading; the\n"
            "                  rest still runs on the CPU in this version: docs/cuda.md)\n"
            MLB_PRECISION_OPTION_HELP
            "  --progress text|json  json: progress as one JSON object per line on stderr instead of the bar, and\n"
            "                  errors as {\"event\":\"error\",...} (for programs driving matlaber: docs/paint.md)\n\n"
            "'matlaber <command> --help' describes each command.\n",
            MATLABER_VERSION);
}

// The program restarts itself once with the runtime settings OpenBLAS and OpenMP read at load
// (mlb_runtime_restart, threads.h): OpenBLAS pointed at the kernels this CPU can run, and, where
// several processes of an MPI job share the node, OMP_WAIT_POLICY=passive, so that idle OpenMP
// threads leave the cores to the others. A process alone keeps libgomp's short spin: once OpenBLAS
// had threads of its own, which that spin starved (the VAE ran 8-35x slower on 2 cores;
// docs/vae.md); GEMMs now run on OpenMP threads (mlb_gemm), and the spin saves the wake-ups.
static int run_command(int argc, char** argv);

// Under mpirun / srun every process runs the same command (docs/pipeline.md, "Many processes"):
// MPI starts before the command and ends after it; a failure on one rank ends them all.
int main(int argc, char** argv) {
    mlb_runtime_restart(argv);
    mlb_runtime_tune_malloc();
    mlb_log_set_sink(mlb_log_file_sink, stderr);
    if (mlb_dist_init(&argc, &argv) != MLB_OK) return cli_fail(MLB_ERR_UNSUPPORTED, "matlaber");
    int rc = run_command(argc, argv);
    if (rc != 0 && mlb_dist_world_size() > 1 && !cli_rc_agreed) {
        fflush(stdout);
        fflush(stderr);
        mlb_dist_abort(rc);
    }
    mlb_dist_finalize();
    return rc;
}

static int run_command(int argc, char** argv) {
    int i = 1, device_given = 0;
    // global options before the command
    while (i < argc && strncmp(argv[i], "--", 2) == 0) {
        if (strcmp(argv[i], "--help") == 0 || strcmp(argv[i], "-h") == 0) { usage(stdout); return 0; }
        if (strcmp(argv[i], "--version") == 0) { printf("matlaber %s\n", MATLABER_VERSION); return 0; }
        if (i + 1 >= argc) return cli_usage_error("", "option %s needs a value", argv[i]);
        if (strcmp(argv[i], "--log-level") == 0) {
            mlb_log_level level;
            if (mlb_log_level_parse(argv[i + 1], &level) != 0)
                return cli_usage_error("", "unknown log level '%s' (debug, info, warn, error, quiet)", argv[i + 1]);
            mlb_log_set_level(level);
        } else if (strcmp(argv[i], "--device") == 0) {
            mlb_device d;
            mlb_status s = mlb_device_option(argv[i + 1], &d);
            if (s == MLB_ERR_ARG) return cli_usage_error("", "%s", mlb_last_error());
            if (s != MLB_OK) return cli_fail(s, "--device");
            device_given = 1;
        } else if (strcmp(argv[i], "--precision") == 0) {
            mlb_gemm_precision p;
            if (mlb_gemm_precision_parse(argv[i + 1], &p) != MLB_OK) return cli_usage_error("", "%s", mlb_last_error());
            mlb_set_gemm_precision(p);
        } else if (strcmp(argv[i], "--progress") == 0) {
            if (strcmp(argv[i + 1], "json") == 0) mlb_progress_set_json(stderr);
            else if (strcmp(argv[i + 1], "text") != 0) return cli_usage_error("", "--progress: expected text or json");
        } else if (strcmp(argv[i], "--threads") == 0) {
            long n;
            if (cli_parse_long(argv[i + 1], 1, 1024, &n) != 0) return cli_usage_error("", "--threads: expected 1..1024");
            mlb_set_threads((int)n);
        } else {
            fprintf(stderr, "matlaber: unknown option '%s'\n\n", argv[i]);
            usage(stderr);
            return EXIT_USAGE;
        }
        i += 2;
    }
    if (i >= argc) { usage(stderr); return EXIT_USAGE; }
    // ranks other than 0 say only what goes wrong (rank 0 reports for the run)
    if (mlb_dist_world_rank() > 0 && mlb_log_get_level() < MLB_LOG_WARN) mlb_log_set_level(MLB_LOG_WARN);
    if (!device_given) {
        mlb_device d;
        mlb_status s = mlb_device_option(NULL, &d);   // $MATLABER_DEVICE, else auto
        if (s) return cli_fail(s, "$MATLABER_DEVICE");
    }
    // asked for by name where the CPU cannot: said once here (a preset's own bf16 falls back quietly)
    if (mlb_gemm_precision_chosen() && mlb_gemm_precision_current() == MLB_GEMM_BF16 &&
        mlb_device_current() == MLB_DEVICE_CPU && !mlb_gemm_bf16_native()) {
        mlb_cpu_info cpu;
        mlb_cpu_detect(&cpu);
        mlb_log(MLB_LOG_WARN, "--precision bf16: %s; the CPU computes in fp32",
                cpu.avx512_bf16 ? "off ($MATLABER_CPU_BF16)" : "this CPU has no AVX-512 BF16");
    }
    const char* cmd = argv[i];
    int sub_argc = argc - i;
    char** sub_argv = argv + i;
    int rc = cli_check_args(sub_argc, sub_argv);   // no argument is cut: a longer one is refused here
    if (rc) return rc;
    if (strcmp(cmd, "brdf") == 0) return cmd_brdf(sub_argc, sub_argv);
    if (strcmp(cmd, "catalogue") == 0) return cmd_catalogue(sub_argc, sub_argv);
    if (strcmp(cmd, "bench") == 0) return cmd_bench(sub_argc, sub_argv);
    if (strcmp(cmd, "demo") == 0) return cmd_demo(sub_argc, sub_argv);
    if (strcmp(cmd, "geometry") == 0) return cmd_geometry(sub_argc, sub_argv);
    if (strcmp(cmd, "render") == 0) return cmd_render(sub_argc, sub_argv);
    if (strcmp(cmd, "relight") == 0)
        return names_run_dir(sub_argc, sub_argv) ? cmd_relight_run(sub_argc, sub_argv) : cmd_relight(sub_argc, sub_argv);
    if (strcmp(cmd, "generate") == 0)
        return names_prompts(sub_argc, sub_argv) ? generate_prompts_main(sub_argc, sub_argv) : cmd_generate(sub_argc, sub_argv);
    if (strcmp(cmd, "fit") == 0) return cmd_fit(sub_argc, sub_argv);
    if (strcmp(cmd, "paint") == 0) return cmd_paint(sub_argc, sub_argv);
    if (strcmp(cmd, "interp") == 0) return cmd_interp(sub_argc, sub_argv);
    if (strcmp(cmd, "export") == 0) return cmd_export(sub_argc, sub_argv);
    if (strcmp(cmd, "view") == 0) return cmd_view(sub_argc, sub_argv);
    if (strcmp(cmd, "serve") == 0) return cmd_serve(sub_argc, sub_argv);
    if (strcmp(cmd, "device") == 0) return cmd_device(sub_argc, sub_argv);
    if (strcmp(cmd, "sd") == 0) return cmd_sd(sub_argc, sub_argv);
    if (strcmp(cmd, "version") == 0) { printf("matlaber %s\n", MATLABER_VERSION); return 0; }
    if (strcmp(cmd, "help") == 0) { usage(stdout); return 0; }
    fprintf(stderr, "matlaber: unknown command '%s'\n\n", cmd);
    usage(stderr);
    return EXIT_USAGE;
}
