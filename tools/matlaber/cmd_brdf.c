// matlaber brdf train | eval | encode | decode | interp: the latent BRDF auto-encoder (paper §3.3).
#include <cjson/cJSON.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "cli.h"
#include "cmd_brdf.h"
#include "matlaber/brdf.h"
#include "matlaber/brdf_ae.h"
#include "matlaber/log.h"

static const char* channel_names[7] = {"kd.r", "kd.g", "kd.b", "ks.r", "ks.g", "ks.b", "kr"};

// ---- data ------------------------------------------------------------------------------------

int brdf_gather_data(const brdf_data_options* o, mlb_brdf_set* set, char* description, size_t desc_size) {
    memset(set, 0, sizeof *set);
    description[0] = 0;
    size_t used = 0;
    // procedural samples: the default without --data; with --data only when asked for
    long n_proc = o->procedural_samples >= 0 ? o->procedural_samples : (o->n_paths ? 0 : o->default_procedural);
    if (n_proc > 0) {
        mlb_status s = mlb_brdf_procedural(set, (size_t)n_proc, o->seed);
        if (s) return cli_fail(s, "procedural materials");
        used += snprintf(description, desc_size, "procedural materials: %ld samples, seed %llu%s", n_proc,
                         (unsigned long long)o->seed, o->n_paths ? "; " : "");
    }
    mlb_brdf_load_options lo = {.max_pixels_per_map = o->pixels_per_map, .seed = o->seed};
    if (o->n_paths && used < desc_size) used += snprintf(description + used, desc_size - used, "SVBRDF data:");
    for (int i = 0; i < o->n_paths; i++) {
        size_t before = set->n;
        lo.seed = o->seed + 0x9E3779B97F4A7C15ull * (uint64_t)i;   // each path its own pixel choices
        mlb_status s = mlb_brdf_load_path(set, o->paths[i], &lo);
        if (s) { mlb_brdf_set_free(set); return cli_fail(s, "loading BRDF data"); }
        if (used < desc_size)
            used += snprintf(description + used, desc_size - used, " %s (%zu samples)", o->paths[i], set->n - before);
    }
    return 0;
}

// The data options 'train' and 'eval' share (--data, --samples, --pixels-per-map, --seed).
// Returns -1 when `c` is not one of them, 0 when handled, EXIT_USAGE on a bad value.
static int parse_data_option(int c, const char* arg, brdf_data_options* data, const char* cmd) {
    long v;
    switch (c) {
    case 'd':
        if (data->n_paths >= BRDF_MAX_DATA_PATHS) return cli_usage_error(cmd, "at most %d --data", BRDF_MAX_DATA_PATHS);
        data->paths[data->n_paths++] = arg;
        return 0;
    case 'n':
        if (cli_parse_long(arg, 0, 100000000, &v)) return cli_usage_error(cmd, "--samples: expected 0..1e8");
        data->procedural_samples = v;
        return 0;
    case 'p':
        if (cli_parse_long(arg, 1, 1L << 40, &v)) return cli_usage_error(cmd, "--pixels-per-map: expected a positive count");
        data->pixels_per_map = (size_t)v;
        return 0;
    case 's':
        if (cli_parse_long(arg, 0, 0x7fffffffffffffffL, &v)) return cli_usage_error(cmd, "--seed: expected a non-negative integer");
        data->seed = (uint64_t)v;
        return 0;
    }
    return -1;
}

static int load_model(const char* path, mlb_brdf_ae* ae, char* source, size_t n) {
    mlb_status s;
    if (path) { snprintf(source, n, "%s", path); s = mlb_brdf_ae_load(ae, path); }
    else s = mlb_brdf_ae_load_default(ae, source, n);
    return s ? cli_fail(s, "loading the BRDF prior") : 0;
}

// ---- train -----------------------------------------------------------------------------------

static const cli_option train_options[] = {
    {"data", 1, 'd', "PATH", "SVBRDF folder, texture set or tile image (repeatable); default: procedural"},
    {"samples", 1, 'n', "N", "procedural samples (default 1000000 without --data, 0 with it)"},
    {"pixels-per-map", 1, 'p', "N", "sample N pixels per SVBRDF map (default: every pixel)"},
    {"epochs", 1, 'e', "N", "epochs (default 30)"},
    {"encoder-epochs", 1, 'E', "N", "epochs of the encoder alone after the joint ones (default 5; 0: none)"},
    {"encoder-lr", 1, 'R', "X", "learning rate of those epochs, cosine to 1% of it (default 1e-3)"},
    {"batch", 1, 'b', "N", "batch size (default 256)"},
    {"lr", 1, 'l', "X", "AdamW learning rate at the first step (default 1e-3)"},
    {"lr-final", 1, 'L', "X", "learning rate at the last step, reached by a cosine decay (default 1e-5; 0: constant --lr)"},
    {"weight-decay", 1, 'w', "X", "AdamW decoupled weight decay (default 0.01)"},
    {"hidden", 1, 'H', "N", "hidden width (default 64)"},
    {"depth", 1, 'D', "N", "hidden layers per network (default 3)"},
    {"activation", 1, 'a', "NAME", "hidden activation (default silu)"},
    {"lambda-kl", 1, 'K', "X", "weight of the KL term (default 2e-4)"},
    {"lambda-s", 1, 'S', "X", "weight of the interpolation smoothness term (default 0.02; the paper 0.05 with the speed form)"},
    {"smoothness", 1, 'F', "FORM", "interpolation smoothness form: bend or speed (default bend; docs/brdf_prior.md)"},
    {"lambda-c", 1, 'C', "X", "weight of the cyclic term (default 1e-4)"},
    {"seed", 1, 's', "S", "seed of data, initialisation, shuffling and noise (default 1)"},
    {"out", 1, 'o', "FILE", "output safetensors file (default brdf_prior.safetensors)"},
    {"json", 0, 'j', NULL, "print a JSON summary on stdout"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

typedef struct { int json; } epoch_printer;

static void print_epoch(const mlb_brdf_epoch_stats* st, void* user) {
    mlb_log(MLB_LOG_INFO, "%sepoch %2d: loss %.6f (rec %.6f, kl %.4f, smooth %.5f, cyclic %.5f), %.0f samples/s",
            st->encoder_only ? "encoder " : "", st->epoch, st->loss, st->l_r, st->l_kl, st->l_s, st->l_c, st->samples_per_second);
}

int brdf_train_main(int argc, char** argv, const char* default_out, mlb_brdf_ae* trained_out) {
    brdf_data_options data = {.procedural_samples = -1, .default_procedural = 1000000, .seed = 1};
    mlb_brdf_train_config tc = mlb_brdf_train_default_config();
    mlb_brdf_ae_config mc = mlb_brdf_ae_default_config();
    const char* out_path = default_out;
    int json = 0;
    long v;
    double x;
    const struct option* table = cli_getopt_table(train_options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "h", table, NULL)) != -1) {
        int rc = parse_data_option(c, optarg, &data, "brdf train");
        if (rc >= 0) { if (rc) return rc; continue; }
        switch (c) {
        case 'e': if (cli_parse_long(optarg, 1, 100000, &v)) return cli_usage_error("brdf train", "--epochs: expected 1..100000"); tc.epochs = (int)v; break;
        case 'b': if (cli_parse_long(optarg, 2, 1 << 20, &v)) return cli_usage_error("brdf train", "--batch: expected 2..1048576"); tc.batch = (int)v; break;
        case 'l': if (cli_parse_double(optarg, 1e-12, 10, &x)) return cli_usage_error("brdf train", "--lr: expected a positive number"); tc.lr = x; break;
        case 'E': if (cli_parse_long(optarg, 0, 100000, &v)) return cli_usage_error("brdf train", "--encoder-epochs: expected 0..100000"); tc.encoder_epochs = (int)v; break;
        case 'R': if (cli_parse_double(optarg, 1e-12, 10, &x)) return cli_usage_error("brdf train", "--encoder-lr: expected a positive number"); tc.encoder_lr = x; break;
        case 'L': if (cli_parse_double(optarg, 0, 10, &x)) return cli_usage_error("brdf train", "--lr-final: expected 0..10"); tc.lr_final = x; break;
        case 'w': if (cli_parse_double(optarg, 0, 10, &x)) return cli_usage_error("brdf train", "--weight-decay: expected 0..10"); tc.weight_decay = x; break;
        case 'H': if (cli_parse_long(optarg, 1, 4096, &v)) return cli_usage_error("brdf train", "--hidden: expected 1..4096"); mc.hidden = (int)v; break;
        case 'D': if (cli_parse_long(optarg, 1, MLB_MLP_MAX_LAYERS - 1, &v)) return cli_usage_error("brdf train", "--depth: expected 1..%d", MLB_MLP_MAX_LAYERS - 1); mc.depth = (int)v; break;
        case 'a': if (mlb_activation_parse(optarg, &mc.act)) return cli_usage_error("brdf train", "--activation: unknown '%s'", optarg); break;
        case 'K': if (cli_parse_double(optarg, 0, 1e6, &x)) return cli_usage_error("brdf train", "--lambda-kl: expected >= 0"); tc.loss.lambda_kl = x; break;
        case 'S': if (cli_parse_double(optarg, 0, 1e6, &x)) return cli_usage_error("brdf train", "--lambda-s: expected >= 0"); tc.loss.lambda_s = x; break;
        case 'C': if (cli_parse_double(optarg, 0, 1e6, &x)) return cli_usage_error("brdf train", "--lambda-c: expected >= 0"); tc.loss.lambda_c = x; break;
        case 'F':
            if (!strcmp(optarg, "bend")) tc.loss.smooth_form = MLB_BRDF_SMOOTH_BEND;
            else if (!strcmp(optarg, "speed")) tc.loss.smooth_form = MLB_BRDF_SMOOTH_SPEED;
            else return cli_usage_error("brdf train", "--smoothness: expected bend or speed, not '%s'", optarg);
            break;
        case 'o': out_path = optarg; break;
        case 'j': json = 1; break;
        case 'h':
            printf("usage: matlaber brdf train [options]\n\n"
                   "Trains the latent BRDF auto-encoder (7 -> 4 -> 7) with L_r + 2e-4 L_KL + 0.02 L_s + 1e-4 L_c\n"
                   "(paper §3.3; L_s in its bend form), then the encoder alone for a few epochs (decoder frozen).\n"
                   "Without --data it trains on the built-in procedural material distribution;\n"
                   "the shipped prior is 'matlaber brdf train --out models/brdf_prior.safetensors'.\n\n");
            cli_print_options(stdout, train_options);
            return 0;
        default: return cli_usage_error("brdf train", "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error("brdf train", "unexpected argument '%s'", argv[optind]);
    tc.seed = data.seed;

    mlb_brdf_set set;
    char description[2048];
    int rc = brdf_gather_data(&data, &set, description, sizeof description);
    if (rc) return rc;
    mlb_log(MLB_LOG_INFO, "training on %s", description);
    mlb_brdf_ae ae;
    mlb_status s = brdf_ae_init(&ae, &mc, tc.seed);
    if (s) { mlb_brdf_set_free(&set); return cli_fail(s, "brdf train"); }
    mlb_progress progress;
    mlb_progress_begin(&progress, mlb_log_get_level() <= MLB_LOG_INFO ? stderr : NULL, "brdf train", 1, "step");
    double t0 = mlb_now_seconds();
    s = mlb_brdf_ae_train(&ae, set.k, set.n, &tc, &progress, print_epoch, NULL);
    double seconds = mlb_now_seconds() - t0;
    if (!s) mlb_progress_end(&progress, NULL);
    if (s) { mlb_brdf_set_free(&set); brdf_ae_free(&ae); return cli_fail(s, "brdf train"); }

    char command[1024] = "matlaber brdf";
    size_t used = strlen(command);
    for (int i = 0; i < argc && used < sizeof command; i++) used += snprintf(command + used, sizeof command - used, " %s", argv[i]);
    char settings[512];
    snprintf(settings, sizeof settings,
             "epochs %d, batch %d, lr %g (cosine to %g), weight decay %g, seed %llu, hidden %d, depth %d, %s, lambda_kl %g, "
             "lambda_s %g (%s form), lambda_c %g, then %d encoder epochs at lr %g",
             tc.epochs, tc.batch, tc.lr, tc.lr_final > 0 ? tc.lr_final : tc.lr, tc.weight_decay, (unsigned long long)tc.seed,
             mc.hidden, mc.depth, mlb_activation_name(mc.act), tc.loss.lambda_kl, tc.loss.lambda_s,
             tc.loss.smooth_form == MLB_BRDF_SMOOTH_BEND ? "bend" : "speed", tc.loss.lambda_c, tc.encoder_epochs,
             tc.encoder_lr);
    mlb_st_meta meta[] = {{"command", command}, {"data", description}, {"training", settings}};
    if (out_path) {
        s = mlb_brdf_ae_save(&ae, out_path, meta, sizeof meta / sizeof *meta);
        if (s) { mlb_brdf_set_free(&set); brdf_ae_free(&ae); return cli_fail(s, "saving the prior"); }
        mlb_log(MLB_LOG_INFO, "wrote %s (%zu parameters) in %.1f s, %.0f samples/s on %d threads", out_path, ae.n_params,
                seconds, (double)tc.epochs * (double)(set.n / (size_t)(tc.batch < (int)set.n ? tc.batch : (int)set.n)) * tc.batch / seconds,
                omp_get_max_threads());
    }
    if (json) {
        cJSON* o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "out", out_path ? out_path : "");
        cJSON_AddNumberToObject(o, "samples", (double)set.n);
        cJSON_AddNumberToObject(o, "parameters", (double)ae.n_params);
        cJSON_AddNumberToObject(o, "seconds", seconds);
        cJSON_AddStringToObject(o, "data", description);
        cJSON_AddStringToObject(o, "training", settings);
        char* text = cJSON_Print(o);
        printf("%s\n", text);
        free(text);
        cJSON_Delete(o);
    }
    mlb_brdf_set_free(&set);
    if (trained_out) *trained_out = ae;
    else brdf_ae_free(&ae);
    return 0;
}

// ---- eval ------------------------------------------------------------------------------------

static const cli_option eval_options[] = {
    {"model", 1, 'm', "FILE", "BRDF prior (default: $MATLABER_PRIOR or the built-in prior)"},
    {"data", 1, 'd', "PATH", "held-out SVBRDF data (repeatable); default: procedural, seed 1001"},
    {"samples", 1, 'n', "N", "procedural samples (default 200000 without --data, 0 with it)"},
    {"pixels-per-map", 1, 'p', "N", "sample N pixels per map (default: every pixel)"},
    {"seed", 1, 's', "S", "seed of the data sampling and the random interpolations (default 1001)"},
    {"json", 0, 'j', NULL, "print the result as JSON"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

static const char* fmt_optional(int has, double v) {
    static char buf[4][32];
    static int next;
    char* b = buf[next++ & 3];
    if (has) snprintf(b, 32, "%.5f", v);
    else snprintf(b, 32, "(not in the file)");
    return b;
}

void brdf_print_evaluation(FILE* out, const char* model, const char* data, const mlb_brdf_eval_result* r) {
    fprintf(out, "BRDF prior: %s\n", model);
    fprintf(out, "data: %s\n", data);
    fprintf(out, "\nreconstruction RMSE (linear units):\n"
                 "  channel   auto-encoder   refined latent   PCA-4 of this data   PCA-4 of the training data\n");
    for (int c = 0; c < 7; c++)
        fprintf(out, "  %-8s  %12.5f   %14.5f   %18.5f   %26s\n", channel_names[c], r->rmse[c], r->fit_rmse[c],
                r->pca_rmse[c], fmt_optional(r->has_train_pca, r->train_pca_rmse[c]));
    fprintf(out, "  %-8s  %12.5f   %14.5f   %18.5f   %26s\n", "all", r->rmse_all, r->fit_rmse_all, r->pca_rmse_all,
            fmt_optional(r->has_train_pca, r->train_pca_rmse_all));
    fprintf(out, "  (auto-encoder: D(mu(k)); refined latent: D(z*) with z* = argmin |D(z) - k| found from mu(k))\n\n");
    fprintf(out, "PCA-4 explains %.2f%% of the variance\n", 100 * r->pca_explained);
    fprintf(out, "KL(q(z|k) || N(0,I)): %.3f per sample; mean posterior std %.4f\n", r->kl, r->mean_sigma);
    fprintf(out, "latent interpolations: %ld paths, %ld decoded BRDFs, %.2f%% valid; decoded path length / end distance %.3f\n",
            r->interp_paths, r->interp_points, 100 * r->interp_valid_share, r->interp_path_ratio);
    const char* who[2] = {"auto-encoder D(mu(k))", "refined latent D(z*)"};
    double rm[2] = {r->rmse_all, r->fit_rmse_all};
    for (int i = 0; i < 2; i++) {
        fprintf(out, "verdict: %-21s %s PCA-4 fitted on this data (RMSE %.5f vs %.5f)\n", who[i],
                rm[i] < r->pca_rmse_all ? "beats        " : "does NOT beat", rm[i], r->pca_rmse_all);
        if (r->has_train_pca)
            fprintf(out, "verdict: %-21s %s the training data's PCA-4 (RMSE %.5f vs %.5f)\n", who[i],
                    rm[i] < r->train_pca_rmse_all ? "beats        " : "does NOT beat", rm[i], r->train_pca_rmse_all);
    }
}

static cJSON* eval_json(const char* model, const char* data, const mlb_brdf_eval_result* r) {
    cJSON* o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "model", model);
    cJSON_AddStringToObject(o, "data", data);
    cJSON_AddNumberToObject(o, "samples", (double)r->n);
    cJSON* ae = cJSON_AddObjectToObject(o, "rmse");
    cJSON* pca = cJSON_AddObjectToObject(o, "pca4_rmse");
    for (int c = 0; c < 7; c++) {
        cJSON_AddNumberToObject(ae, channel_names[c], r->rmse[c]);
        cJSON_AddNumberToObject(pca, channel_names[c], r->pca_rmse[c]);
    }
    cJSON_AddNumberToObject(ae, "all", r->rmse_all);
    cJSON* fit = cJSON_AddObjectToObject(o, "refined_latent_rmse");
    for (int c = 0; c < 7; c++) cJSON_AddNumberToObject(fit, channel_names[c], r->fit_rmse[c]);
    cJSON_AddNumberToObject(fit, "all", r->fit_rmse_all);
    cJSON_AddNumberToObject(pca, "all", r->pca_rmse_all);
    cJSON_AddNumberToObject(o, "pca4_explained_variance", r->pca_explained);
    cJSON_AddNumberToObject(o, "kl", r->kl);
    cJSON_AddNumberToObject(o, "mean_posterior_std", r->mean_sigma);
    cJSON_AddNumberToObject(o, "interp_paths", (double)r->interp_paths);
    cJSON_AddNumberToObject(o, "interp_points", (double)r->interp_points);
    cJSON_AddNumberToObject(o, "interp_valid_share", r->interp_valid_share);
    cJSON_AddNumberToObject(o, "interp_path_ratio", r->interp_path_ratio);
    cJSON_AddBoolToObject(o, "beats_pca4", r->rmse_all < r->pca_rmse_all);
    cJSON_AddBoolToObject(o, "refined_beats_pca4", r->fit_rmse_all < r->pca_rmse_all);
    if (r->has_train_pca) {
        cJSON* tp = cJSON_AddObjectToObject(o, "train_pca4_rmse");
        for (int c = 0; c < 7; c++) cJSON_AddNumberToObject(tp, channel_names[c], r->train_pca_rmse[c]);
        cJSON_AddNumberToObject(tp, "all", r->train_pca_rmse_all);
        cJSON_AddBoolToObject(o, "beats_train_pca4", r->rmse_all < r->train_pca_rmse_all);
        cJSON_AddBoolToObject(o, "refined_beats_train_pca4", r->fit_rmse_all < r->train_pca_rmse_all);
    }
    return o;
}

int brdf_eval_run(const mlb_brdf_ae* ae, const char* source, const brdf_data_options* data, int json) {
    mlb_brdf_set set;
    char description[2048];
    int rc = brdf_gather_data(data, &set, description, sizeof description);
    if (rc) return rc;
    mlb_brdf_eval_result r;
    mlb_status s = mlb_brdf_ae_evaluate(ae, set.k, set.n, data->seed, &r);
    mlb_brdf_set_free(&set);
    if (s) return cli_fail(s, "brdf eval");
    if (json) {
        cJSON* o = eval_json(source, description, &r);
        char* text = cJSON_Print(o);
        printf("%s\n", text);
        free(text);
        cJSON_Delete(o);
    } else {
        brdf_print_evaluation(stdout, source, description, &r);
    }
    return 0;
}

static int brdf_eval_main(int argc, char** argv) {
    brdf_data_options data = {.procedural_samples = -1, .default_procedural = 200000, .seed = 1001};
    const char* model = NULL;
    int json = 0;
    const struct option* table = cli_getopt_table(eval_options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "h", table, NULL)) != -1) {
        int rc = parse_data_option(c, optarg, &data, "brdf eval");
        if (rc >= 0) { if (rc) return rc; continue; }
        switch (c) {
        case 'm': model = optarg; break;
        case 'j': json = 1; break;
        case 'h':
            printf("usage: matlaber brdf eval [--model FILE] [--data PATH ...] [--json]\n\n"
                   "Per-channel reconstruction RMSE (linear units) of the auto-encoder D(mu(k)) and of D(z*) with the\n"
                   "latent refined toward k, against PCA-4 (fitted on this data, and the training data's PCA-4 stored\n"
                   "in the prior); the KL term; and the share of decoded BRDFs that stay valid along random latent\n"
                   "interpolations. Evaluate on data held out from training (docs/brdf_prior.md).\n\n");
            cli_print_options(stdout, eval_options);
            return 0;
        default: return cli_usage_error("brdf eval", "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error("brdf eval", "unexpected argument '%s'", argv[optind]);
    mlb_brdf_ae ae;
    char source[1024];
    int rc = load_model(model, &ae, source, sizeof source);
    if (rc) return rc;
    rc = brdf_eval_run(&ae, source, &data, json);
    brdf_ae_free(&ae);
    return rc;
}

// ---- encode / decode / interp ----------------------------------------------------------------

static void print_row(const float* v, int n, int json, int last) {
    if (json) printf("  [");
    for (int i = 0; i < n; i++) printf(json ? "%s%.6g" : "%s%.6f", i ? (json ? ", " : " ") : "", (double)v[i]);
    printf(json ? (last ? "]\n" : "],\n") : "\n");
}

// Values from --values or, without it, one row per line of stdin.
static int code_main(int argc, char** argv, int encode) {
    const char* cmd = encode ? "brdf encode" : "brdf decode";
    const cli_option options[] = {
        {"model", 1, 'm', "FILE", "BRDF prior (default: $MATLABER_PRIOR or the built-in prior)"},
        {encode ? "k" : "z", 1, 'v', encode ? "KD_R,KD_G,KD_B,KS_R,KS_G,KS_B,KR" : "Z1,Z2,Z3,Z4",
         encode ? "one BRDF, linear units (else rows of 7 numbers on stdin)" : "one latent code (else rows of 4 numbers on stdin)"},
        {"refine", 1, 'r', "N", encode ? "Levenberg-Marquardt steps from the encoder's mean toward the code that decodes"
                                          " closest to k (default 20; 0: the encoder's mean)" : "(encode only)"},
        {"json", 0, 'j', NULL, "print a JSON array"},
        {"help", 0, 'h', NULL, "this help"},
        {0, 0, 0, 0, 0}};
    const char* model = NULL;
    const char* values = NULL;
    int json = 0;
    long refine = 20;
    const struct option* table = cli_getopt_table(options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "h", table, NULL)) != -1) {
        switch (c) {
        case 'm': model = optarg; break;
        case 'v': values = optarg; break;
        case 'r':
            if (!encode) return cli_usage_error(cmd, "--refine applies to encode");
            if (cli_parse_long(optarg, 0, 10000, &refine)) return cli_usage_error(cmd, "--refine: expected 0..10000");
            break;
        case 'j': json = 1; break;
        case 'h':
            printf("usage: matlaber %s [--model FILE] [--%s VALUES] [--json]\n\n%s\n\n", cmd, encode ? "k" : "z",
                   encode ? "Encodes BRDFs (kd rgb, ks rgb, kr; linear) to latent codes (4 numbers per row): the encoder's\n"
                            "mean, refined so that the decoder reproduces the BRDF as closely as it can (--refine)."
                          : "Decodes latent codes to BRDFs (kd rgb, ks rgb, kr; linear; 7 numbers per row).");
            cli_print_options(stdout, options);
            return 0;
        default: return cli_usage_error(cmd, "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error(cmd, "unexpected argument '%s'", argv[optind]);
    int in_dim = encode ? 7 : 4, out_dim = encode ? 4 : 7;
    float in[7], out[7];
    if (values) {   // check the arguments before loading anything
        if (cli_parse_floats(values, in, in_dim))
            return cli_usage_error(cmd, "--%s: expected %d comma-separated numbers, got '%s'", encode ? "k" : "z", in_dim, values);
        if (encode && !mlb_brdf_valid(in))
            return cli_usage_error(cmd, "--k: not a valid BRDF (kd, ks in [0,1], kr in [%g,1])", (double)MLB_KR_MIN);
    }
    mlb_brdf_ae ae;
    char source[1024];
    int rc = load_model(model, &ae, source, sizeof source);
    if (rc) return rc;
    char line[4096];
    long row = 0;
    if (json) printf("[\n");
    for (;;) {
        const char* text = values;
        if (!values) {
            if (!fgets(line, sizeof line, stdin)) break;
            line[strcspn(line, "\r\n")] = 0;
            for (char* p = line; *p; p++) if (*p == ' ' || *p == '\t') *p = ',';
            char* q = line;   // collapse repeated separators
            for (char* p = line; *p; p++) if (!(*p == ',' && (q == line || q[-1] == ','))) *q++ = *p;
            while (q > line && q[-1] == ',') q--;
            *q = 0;
            if (!*line) continue;
            text = line;
        }
        row++;
        if (cli_parse_floats(text, in, in_dim)) {
            brdf_ae_free(&ae);
            fprintf(stderr, "matlaber %s: %s%ld: expected %d comma- or space-separated numbers, got '%s'\n", cmd,
                    values ? "--values " : "stdin line ", row, in_dim, text);
            return values ? EXIT_USAGE : 1;
        }
        if (encode && !mlb_brdf_valid(in)) {
            brdf_ae_free(&ae);
            fprintf(stderr, "matlaber %s: row %ld is not a valid BRDF (kd, ks in [0,1], kr in [%g,1])\n", cmd, row,
                    (double)MLB_KR_MIN);
            return 1;
        }
        mlb_status s = encode ? brdf_ae_latent_of(&ae, in, 1, out, (int)refine) : brdf_ae_decode(&ae, in, 1, out);
        if (s) { brdf_ae_free(&ae); return cli_fail(s, cmd); }
        print_row(out, out_dim, json, values != NULL);
        if (values) break;
    }
    if (json) printf(values ? "]\n" : "  []\n]\n");
    brdf_ae_free(&ae);
    return 0;
}

static int brdf_interp_main(int argc, char** argv) {
    static const cli_option options[] = {
        {"model", 1, 'm', "FILE", "BRDF prior (default: $MATLABER_PRIOR or the built-in prior)"},
        {"from-k", 1, 'a', "7 NUMBERS", "start BRDF (encoded to its latent mean)"},
        {"to-k", 1, 'b', "7 NUMBERS", "end BRDF"},
        {"from-z", 1, 'A', "4 NUMBERS", "start latent code"},
        {"to-z", 1, 'B', "4 NUMBERS", "end latent code"},
        {"steps", 1, 'n', "K", "points along the path, ends included (default 9)"},
        {"json", 0, 'j', NULL, "print JSON"},
        {"help", 0, 'h', NULL, "this help"},
        {0, 0, 0, 0, 0}};
    const char *model = NULL, *ends[4] = {NULL, NULL, NULL, NULL};
    long steps = 9;
    int json = 0;
    const struct option* table = cli_getopt_table(options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "h", table, NULL)) != -1) {
        switch (c) {
        case 'm': model = optarg; break;
        case 'a': ends[0] = optarg; break;
        case 'b': ends[1] = optarg; break;
        case 'A': ends[2] = optarg; break;
        case 'B': ends[3] = optarg; break;
        case 'n': if (cli_parse_long(optarg, 2, 100000, &steps)) return cli_usage_error("brdf interp", "--steps: expected 2..100000"); break;
        case 'j': json = 1; break;
        case 'h':
            printf("usage: matlaber brdf interp (--from-k K --to-k K | --from-z Z --to-z Z) [--steps K] [--json]\n\n"
                   "Decoded BRDFs at evenly spaced points of the straight latent path between two codes\n"
                   "(the paper's material interpolation). Columns: alpha, z (4), kd (3), ks (3), kr.\n\n");
            cli_print_options(stdout, options);
            return 0;
        default: return cli_usage_error("brdf interp", "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error("brdf interp", "unexpected argument '%s'", argv[optind]);
    float za[4], zb[4], ka[7], kb[7];
    int use_k = ends[0] || ends[1];
    if (use_k ? !(ends[0] && ends[1] && !ends[2] && !ends[3]) : !(ends[2] && ends[3]))
        return cli_usage_error("brdf interp", "give either --from-k and --to-k, or --from-z and --to-z");
    if (use_k) {
        if (cli_parse_floats(ends[0], ka, 7) || cli_parse_floats(ends[1], kb, 7))
            return cli_usage_error("brdf interp", "--from-k/--to-k: expected 7 comma-separated numbers");
        if (!mlb_brdf_valid(ka) || !mlb_brdf_valid(kb))
            return cli_usage_error("brdf interp", "--from-k/--to-k: not a valid BRDF (kd, ks in [0,1], kr in [%g,1])", (double)MLB_KR_MIN);
    } else if (cli_parse_floats(ends[2], za, 4) || cli_parse_floats(ends[3], zb, 4)) {
        return cli_usage_error("brdf interp", "--from-z/--to-z: expected 4 comma-separated numbers");
    }
    mlb_brdf_ae ae;
    char source[1024];
    int rc = load_model(model, &ae, source, sizeof source);
    if (rc) return rc;
    mlb_status s = MLB_OK;
    if (use_k && ((s = brdf_ae_encode(&ae, ka, 1, za, NULL)) || (s = brdf_ae_encode(&ae, kb, 1, zb, NULL)))) {
        brdf_ae_free(&ae);
        return cli_fail(s, "brdf interp");
    }
    if (json) printf("[\n");
    else printf("# alpha z1 z2 z3 z4 kd.r kd.g kd.b ks.r ks.g ks.b kr\n");
    for (long i = 0; i < steps; i++) {
        float a = (float)i / (float)(steps - 1), row[12];
        row[0] = a;
        for (int d = 0; d < 4; d++) row[1 + d] = (1 - a) * za[d] + a * zb[d];
        if ((s = brdf_ae_decode(&ae, row + 1, 1, row + 5))) { brdf_ae_free(&ae); return cli_fail(s, "brdf interp"); }
        print_row(row, 12, json, i == steps - 1);
    }
    if (json) printf("]\n");
    brdf_ae_free(&ae);
    return 0;
}

int cmd_brdf(int argc, char** argv) {
    if (argc < 2 || strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0) {
        FILE* out = argc < 2 ? stderr : stdout;
        fprintf(out, "usage: matlaber brdf <train|eval|encode|decode|interp|swatch> [options]\n\n"
                     "  train   train a latent BRDF auto-encoder (the material prior)\n"
                     "  eval    reconstruction error vs PCA-4, KL, validity along interpolations\n"
                     "  encode  BRDF -> latent code\n"
                     "  decode  latent code -> BRDF\n"
                     "  interp  decoded BRDFs along a latent path\n"
                     "  swatch  spheres rendered with a list of materials or a latent interpolation\n");
        return argc < 2 ? EXIT_USAGE : 0;
    }
    const char* sub = argv[1];
    if (strcmp(sub, "train") == 0) return brdf_train_main(argc - 1, argv + 1, "brdf_prior.safetensors", NULL);
    if (strcmp(sub, "eval") == 0) return brdf_eval_main(argc - 1, argv + 1);
    if (strcmp(sub, "encode") == 0) return code_main(argc - 1, argv + 1, 1);
    if (strcmp(sub, "decode") == 0) return code_main(argc - 1, argv + 1, 0);
    if (strcmp(sub, "interp") == 0) return brdf_interp_main(argc - 1, argv + 1);
    if (strcmp(sub, "swatch") == 0) return brdf_swatch_main(argc - 1, argv + 1);
    return cli_usage_error("brdf", "unknown subcommand '%s'", sub);
}
