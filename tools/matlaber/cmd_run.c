// matlaber relight RUN_DIR | interp RUN_A RUN_B: the paper's downstream tasks on finished runs
// (docs/pipeline.md): the asset under a turning light, and material interpolation in latent space.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cli.h"
#include "matlaber/envmap.h"
#include "matlaber/fileio.h"
#include "matlaber/image_write.h"
#include "matlaber/log.h"
#include "matlaber/pipeline.h"
#include "matlaber/plot.h"
#include "matlaber/raster.h"
#include "matlaber/render.h"
#include "matlaber/shade.h"

typedef struct {
    mlb_envmap env;
    mlb_envlight light;
} run_light;

static mlb_status light_open(run_light* l, const char* name) {
    memset(l, 0, sizeof *l);
    mlb_status s = mlb_envmap_open(&l->env, name, 1.0f, 512, NULL);
    if (!s) s = mlb_envlight_build(&l->light, &l->env, NULL);
    return s;
}

static void light_free(run_light* l) {
    mlb_envlight_free(&l->light);
    mlb_envmap_free(&l->env);
}

static void light_rotate(run_light* l, double deg) {
    float rad = (float)(deg * M_PI / 180.0);
    mlb_envmap_set_rotation(&l->env, rad);
    mlb_envlight_set_rotation(&l->light, rad);
}

// The mesh with its material at every pixel (material(user, ...)), as the baked asset shows it.
static mlb_status render_asset(const mlb_mesh* m, mlb_material_fn material, void* user, run_light* l, int env_background,
                               double az, double el, int res, float* rgba) {
    mlb_render_params p;
    memset(&p, 0, sizeof p);
    p.mesh = m;
    p.material = material;
    p.material_user = user;
    p.light = &l->light;
    p.env = &l->env;
    p.background = env_background ? MLB_BG_ENV : MLB_BG_COLOR;
    p.width = p.height = res;
    p.supersample = 2;
    p.fresnel = MLB_FRESNEL_PAPER;
    mlb_status s = mlb_camera_orbit(&p.camera, az, el, MLB_ORBIT_RADIUS, NULL, MLB_ORBIT_FOVY_MAX, 1.0, MLB_ORBIT_NEAR,
                                    MLB_ORBIT_FAR);
    return s ? s : mlb_render_shaded(&p, rgba);
}

static const cli_option relight_options[] = {
    {"env", 1, 'e', "NAME|FILE", "environment (built-in sky, overcast, studio, white, or an .hdr/.exr; default studio)"},
    {"frames", 1, 'k', "N", "frames of a full turn of the light (default 36)"},
    {"res", 1, 'r', "N", "image size (default 512)"},
    {"azimuth", 1, 'a', "DEG", "camera azimuth (default 30)"},
    {"elevation", 1, 'E', "DEG", "camera elevation (default 20)"},
    {"background", 1, 'b', "env|black", "behind the asset (default env)"},
    {"out", 1, 'o', "DIR", "output folder (default RUN_DIR/relight_<env>)"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

// matlaber relight RUN_DIR ...
int cmd_relight_run(int argc, char** argv) {
    const char *env = "studio", *out = NULL, *background = "env";
    long frames = 36, res = 512;
    double az = 30, el = 20;
    const struct option* table = cli_getopt_table(relight_options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "ho:", table, NULL)) != -1) {
        switch (c) {
        case 'e': env = optarg; break;
        case 'k': if (cli_parse_long(optarg, 1, 100000, &frames)) return cli_usage_error("relight", "--frames: expected 1..100000"); break;
        case 'r': if (cli_parse_long(optarg, 16, 4096, &res)) return cli_usage_error("relight", "--res: expected 16..4096"); break;
        case 'a': if (cli_parse_double(optarg, -1e4, 1e4, &az)) return cli_usage_error("relight", "--azimuth: expected degrees"); break;
        case 'E': if (cli_parse_double(optarg, -89, 89, &el)) return cli_usage_error("relight", "--elevation: expected -89..89"); break;
        case 'b':
            if (strcmp(optarg, "env") && strcmp(optarg, "black")) return cli_usage_error("relight", "--background: env or black");
            background = optarg;
            break;
        case 'o': out = optarg; break;
        case 'h':
            printf("usage: matlaber relight RUN_DIR [--env NAME|FILE] [--frames N] [-o DIR]\n\n"
                   "The finished run's asset (final/mesh.obj with its material field at every pixel) while the\n"
                   "environment turns once about the vertical axis: DIR/frame_0000.png ..., and DIR/relight.mp4 when\n"
                   "ffmpeg is installed. (For a plain mesh: matlaber relight --mesh FILE.obj ...)\n\n");
            cli_print_options(stdout, relight_options);
            return 0;
        default: return cli_usage_error("relight", "unknown option");
        }
    }
    if (optind != argc - 1) return cli_usage_error("relight", "expected one RUN_DIR");
    const char* dir = argv[optind];
    char out_buf[4096];
    if (!out) {
        const char* base = strrchr(env, '/');
        snprintf(out_buf, sizeof out_buf, "%s/relight_%s", dir, base ? base + 1 : env);
        out = out_buf;
    }
    mlb_run_asset a;
    mlb_status s = mlb_run_asset_load(&a, dir);
    if (s) return cli_fail(s, "relight");
    float* rgba = malloc(sizeof(float) * 4 * (size_t)res * res);
    run_light l;
    memset(&l, 0, sizeof l);
    if (!rgba) s = mlb_fail(MLB_ERR_NOMEM, "relight: out of memory");
    if (!s) s = light_open(&l, env);
    if (!s) s = mlb_mkdir_p(out);
    mlb_progress progress;
    mlb_progress_begin(&progress, mlb_log_get_level() <= MLB_LOG_INFO ? stderr : NULL, "relight", frames, "frame");
    for (long f = 0; !s && f < frames; f++) {
        light_rotate(&l, 360.0 * (double)f / (double)frames);
        s = render_asset(&a.mesh, mlb_run_asset_material, &a, &l, strcmp(background, "env") == 0, az, el, (int)res, rgba);
        char path[4200];
        snprintf(path, sizeof path, "%s/frame_%04ld.png", out, f);
        mlb_png_options po = {8, MLB_PNG_SRGB};
        if (!s) s = mlb_image_write_png(path, rgba, (int)res, (int)res, 4, &po);
        mlb_progress_update(&progress, f + 1, NULL);
    }
    light_free(&l);
    free(rgba);
    mlb_run_asset_free(&a);
    if (s) return cli_fail(s, "relight");
    mlb_progress_end(&progress, NULL);
    cli_frames_to_mp4(out, "relight.mp4");
    printf("relight: %ld frames in %s\n", frames, out);
    return 0;
}

static const cli_option interp_options[] = {
    {"steps", 1, 'k', "K", "materials from A's to B's, both included (default 5)"},
    {"env", 1, 'e', "NAME|FILE", "environment (default studio)"},
    {"res", 1, 'r', "N", "image size per step (default 384)"},
    {"azimuth", 1, 'a', "DEG", "camera azimuth (default 30)"},
    {"elevation", 1, 'E', "DEG", "camera elevation (default 20)"},
    {"out", 1, 'o', "DIR", "output folder (default RUN_A/interp)"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

// matlaber interp RUN_A RUN_B: on A's geometry, z(t) = (1 − t) z_A(x) + t z_B(x) at every vertex x,
// decoded by the frozen BRDF decoder (the paper's golden → silver goblet).
// Two runs' material fields mixed in the prior's latent space, (1 - t) z_a + t z_b, decoded by A's
// decoder: an mlb_material_fn, so that every pixel shows its own point's mix.
typedef struct { const mlb_run_asset *a, *b; double t; } latent_mix;

static mlb_status latent_mix_material(void* user, const float* pos, size_t n, float* k) {
    const latent_mix* m = user;
    float* za = malloc(sizeof(float) * 4 * (n ? n : 1));
    float* zb = malloc(sizeof(float) * 4 * (n ? n : 1));
    mlb_status s = (za && zb) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "interp: out of memory for %zu points", n);
    if (!s) s = mlb_material_eval_latent(&m->a->material, pos, n, za);
    if (!s) s = mlb_material_eval_latent(&m->b->material, pos, n, zb);   // B's field on A's surface
    for (size_t j = 0; !s && j < 4 * n; j++) za[j] = (float)((1 - m->t) * za[j] + m->t * zb[j]);
    if (!s) s = mlb_material_decode(&m->a->material, za, n, k);
    free(za);
    free(zb);
    return s;
}

int cmd_interp(int argc, char** argv) {
    const char *env = "studio", *out = NULL;
    long steps = 5, res = 384;
    double az = 30, el = 20;
    const struct option* table = cli_getopt_table(interp_options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "ho:", table, NULL)) != -1) {
        switch (c) {
        case 'k': if (cli_parse_long(optarg, 2, 64, &steps)) return cli_usage_error("interp", "--steps: expected 2..64"); break;
        case 'e': env = optarg; break;
        case 'r': if (cli_parse_long(optarg, 16, 2048, &res)) return cli_usage_error("interp", "--res: expected 16..2048"); break;
        case 'a': if (cli_parse_double(optarg, -1e4, 1e4, &az)) return cli_usage_error("interp", "--azimuth: expected degrees"); break;
        case 'E': if (cli_parse_double(optarg, -89, 89, &el)) return cli_usage_error("interp", "--elevation: expected -89..89"); break;
        case 'o': out = optarg; break;
        case 'h':
            printf("usage: matlaber interp RUN_A RUN_B [--steps K] [--env NAME|FILE] [-o DIR]\n\n"
                   "On A's geometry, interpolates the two runs' material fields in the latent space of the BRDF\n"
                   "prior (both runs made with --material latent) and renders each step: DIR/step_00.png ... and\n"
                   "DIR/interp.png (all steps in a row). Every step is a valid BRDF: the decoder maps any code to one.\n\n");
            cli_print_options(stdout, interp_options);
            return 0;
        default: return cli_usage_error("interp", "unknown option");
        }
    }
    if (optind != argc - 2) return cli_usage_error("interp", "expected RUN_A and RUN_B");
    const char *dir_a = argv[optind], *dir_b = argv[optind + 1];
    char out_buf[4096];
    if (!out) {
        snprintf(out_buf, sizeof out_buf, "%s/interp", dir_a);
        out = out_buf;
    }
    mlb_run_asset a, b;
    mlb_status s = mlb_run_asset_load(&a, dir_a);
    if (s) return cli_fail(s, "interp");
    s = mlb_run_asset_load(&b, dir_b);
    if (s) { mlb_run_asset_free(&a); return cli_fail(s, "interp"); }
    if (a.material.cfg.mode != MLB_MATERIAL_LATENT || b.material.cfg.mode != MLB_MATERIAL_LATENT)
        s = mlb_fail(MLB_ERR_UNSUPPORTED, "%s: made with --material direct: latent interpolation needs two latent runs",
                     a.material.cfg.mode != MLB_MATERIAL_LATENT ? dir_a : dir_b);
    size_t p = (size_t)res * res;
    float* rgba = malloc(sizeof(float) * 4 * p);
    float* strip = malloc(sizeof(float) * 3 * p * (size_t)steps);
    run_light l;
    memset(&l, 0, sizeof l);
    if (!s && (!rgba || !strip)) s = mlb_fail(MLB_ERR_NOMEM, "interp: out of memory");
    if (!s) s = light_open(&l, env);
    if (!s) s = mlb_mkdir_p(out);
    char labels[64][16];
    const char* label_ptrs[64];
    for (long i = 0; !s && i < steps; i++) {
        double t = (double)i / (double)(steps - 1);
        latent_mix mix = {&a, &b, t};
        s = render_asset(&a.mesh, latent_mix_material, &mix, &l, 1, az, el, (int)res, rgba);
        char path[4200];
        snprintf(path, sizeof path, "%s/step_%02ld.png", out, i);
        mlb_png_options po = {8, MLB_PNG_SRGB};
        if (!s) s = mlb_image_write_png(path, rgba, (int)res, (int)res, 4, &po);
        for (size_t q = 0; !s && q < p; q++)
            for (int ch = 0; ch < 3; ch++) strip[3 * p * i + 3 * q + ch] = mlb_srgb_encode(rgba[4 * q + ch]);
        snprintf(labels[i], sizeof labels[i], "t = %.2f", t);
        label_ptrs[i] = labels[i];
    }
    if (!s) {
        char path[4200];
        snprintf(path, sizeof path, "%s/interp.png", out);
        s = mlb_image_grid_write(path, strip, (int)steps, (int)res, (int)res, 3, (int)steps, label_ptrs);
    }
    light_free(&l);
    free(rgba);
    free(strip);
    mlb_run_asset_free(&a);
    mlb_run_asset_free(&b);
    if (s) return cli_fail(s, "interp");
    printf("interp: %ld steps from %s to %s on %s's geometry in %s\n", steps, dir_a, dir_b, dir_a, out);
    return 0;
}
