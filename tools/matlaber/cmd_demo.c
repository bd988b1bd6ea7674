// matlaber demo: the default job. For now (until the text-to-3D pipeline lands): train the default
// BRDF prior from the built-in procedural materials and evaluate it on held-out data, including the
// real SVBRDF maps in ../shared/data/svbrdf when they are there.
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "cli.h"
#include "cmd_brdf.h"
#include "matlaber/fileio.h"
#include "matlaber/log.h"

int cmd_demo(int argc, char** argv) {
    const char* out_dir = "matlaber-demo";
    const char* epochs = NULL;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--help") == 0 || strcmp(argv[i], "-h") == 0) {
            printf("usage: matlaber demo [--epochs N] [--out DIR]\n\n"
                   "Trains the default BRDF prior (procedural materials, the paper's losses and settings),\n"
                   "writes DIR/brdf_prior.safetensors (default DIR: matlaber-demo), and evaluates it on held-out\n"
                   "procedural materials and on the real SVBRDF maps of ../shared/data when present.\n"
                   "It also compares the result with the prior built into the program.\n");
            return 0;
        }
        if (i + 1 >= argc) return cli_usage_error("demo", "option %s needs a value", argv[i]);
        if (strcmp(argv[i], "--epochs") == 0) epochs = argv[++i];
        else if (strcmp(argv[i], "--out") == 0) out_dir = argv[++i];
        else return cli_usage_error("demo", "unknown option '%s'", argv[i]);
    }
    mlb_status s = mlb_mkdir_p(out_dir);
    if (s) return cli_fail(s, "demo");
    char out_path[4096];
    snprintf(out_path, sizeof out_path, "%s/brdf_prior.safetensors", out_dir);
    char* train_argv[8] = {"train", "--out", out_path};
    int train_argc = 3;
    if (epochs) { train_argv[train_argc++] = "--epochs"; train_argv[train_argc++] = (char*)epochs; }
    train_argv[train_argc] = NULL;

    mlb_log(MLB_LOG_INFO, "== 1. training the default BRDF prior (matlaber brdf train%s%s)", epochs ? " --epochs " : "",
            epochs ? epochs : "");
    mlb_brdf_ae ae;
    int rc = brdf_train_main(train_argc, train_argv, out_path, &ae);
    if (rc) return rc;

    printf("\n== 2. held-out procedural materials\n");
    brdf_data_options procedural = {.procedural_samples = 200000, .seed = 1001};
    rc = brdf_eval_run(&ae, out_path, &procedural, 0);
    const char* shared = cli_shared_data();
    if (!rc && shared) {
        // the pooled real maps (six maps of four sources) and TwoShotBRDF, the paper's data set
        static const char* sets[] = {"svbrdf", "svbrdf/twoshotbrdf"};
        for (size_t i = 0; i < sizeof sets / sizeof *sets && !rc; i++) {
            char path[4096];
            snprintf(path, sizeof path, "%s/%s", shared, sets[i]);
            printf("\n== %zu. real SVBRDF maps, never seen in training: %s\n", i + 3, sets[i]);
            brdf_data_options real = {.paths = {path}, .n_paths = 1, .procedural_samples = 0, .pixels_per_map = 65536, .seed = 1001};
            rc = brdf_eval_run(&ae, out_path, &real, 0);
        }
        printf("\n(per-source results and what they mean: docs/brdf_prior.md)\n");
    } else if (!rc) {
        printf("\n(../shared/data not found: skipping the evaluation on real SVBRDF maps)\n");
    }
    if (!rc) {
        mlb_brdf_ae builtin;
        char source[256];
        if (mlb_brdf_ae_load_default(&builtin, source, sizeof source) == MLB_OK) {
            double diff = builtin.n_params == ae.n_params ? 0 : INFINITY;
            for (size_t i = 0; i < ae.n_params && builtin.n_params == ae.n_params; i++)
                diff = fmax(diff, fabs((double)builtin.params[i] - ae.params[i]));
            printf("\nreproducibility: largest parameter difference from the %s: %.3g%s\n", source, diff,
                   diff == 0 ? " (bitwise identical)" : (epochs ? " (trained with other settings)" : ""));
            brdf_ae_free(&builtin);
        }
        printf("\nthe trained prior is in %s\n", out_path);
    }
    brdf_ae_free(&ae);
    return rc;
}
