// The two-stage pipeline end to end (include/matlaber/pipeline.h): config files, a small image-
// guided fit that recovers a known albedo, resume equivalence, and score distillation with a tiny
// random Stable Diffusion UNet + VAE written by the test, and --init auto's look-ahead and the
// material start with guidances written by the test.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "matlaber/cameras.h"
#include "matlaber/evaluate.h"
#include "matlaber/fileio.h"
#include "matlaber/log.h"
#include "matlaber/guidance_sds.h"
#include "matlaber/material_net.h"
#include "matlaber/pipeline.h"
#include "matlaber/threads.h"
#include "matlaber/rng.h"
#include "matlaber/safetensors.h"
#include "matlaber/schedule.h"
#include "matlaber/text3d.h"
#include "matlaber/unet_random.h"
#include "matlaber/vae.h"
#include "matlaber/views.h"
#include "pipeline/pipeline_internal.h"
#include "test.h"
#include "matlaber/threads.h"

static char tmpdir[256];

static void tmp_path(char* out, size_t cap, const char* name) { snprintf(out, cap, "%s/%s", tmpdir, name); }

static int same_file(const char* a, const char* b) {
    char *x = NULL, *y = NULL;
    size_t nx = 0, ny = 0;
    if (mlb_read_file(a, &x, &nx, 1 << 28) || mlb_read_file(b, &y, &ny, 1 << 28)) {
        free(x);
        free(y);
        return 0;
    }
    int same = nx == ny && memcmp(x, y, nx) == 0;
    free(x);
    free(y);
    return same;
}

// c saved to path with keys a and b renamed (as a config.json written before they existed), loaded
// into *back.
static mlb_status load_without_keys(const mlb_pipeline_config* c, const char* path, const char* a, const char* b,
                                    mlb_pipeline_config* back) {
    MLB_TRY(mlb_pipeline_config_save(c, path));
    char* text = NULL;
    size_t n = 0;
    MLB_TRY(mlb_read_file(path, &text, &n, 1 << 20));
    const char* keys[2] = {a, b};
    for (int i = 0; i < 2; i++) {
        char quoted[128];
        snprintf(quoted, sizeof quoted, "\"%s\"", keys[i]);
        char* at = strstr(text, quoted);
        if (!at) { free(text); return mlb_fail(MLB_ERR_FORMAT, "%s: no key %s", path, quoted); }
        at[1] = 'x';
    }
    mlb_status s = mlb_write_file_atomic(path, text, n);
    free(text);
    return s ? s : mlb_pipeline_config_load(back, path);
}

// A key added after runs were written: KEY=value (--set) saved and loaded back as it was; a
// config.json without it (and without coarse_to_fine, legacy 0) loads as KEY=legacy, what such a
// run ran with; KEY=bad (when not NULL) is refused by the validation.
static void optional_key(const mlb_pipeline_config* c0, const char* path, const char* key, const char* value,
                         const char* legacy, const char* bad) {
    char kv[128];
    mlb_pipeline_config c = *c0, back, want;
    snprintf(kv, sizeof kv, "%s=%s", key, value);
    REQUIRE(mlb_pipeline_config_set(&c, kv) == MLB_OK);
    REQUIRE(mlb_pipeline_config_save(&c, path) == MLB_OK);
    REQUIRE(mlb_pipeline_config_load(&back, path) == MLB_OK);
    CHECK_MSG(!mlb_pipeline_config_differs(&back, &c, NULL), "%s: %s differs after a round trip", key,
              mlb_pipeline_config_differs(&back, &c, NULL));
    want = c;
    snprintf(kv, sizeof kv, "%s=%s", key, legacy);
    REQUIRE(mlb_pipeline_config_set(&want, kv) == MLB_OK);
    want.coarse_to_fine = 0;
    REQUIRE(load_without_keys(&c, path, key, "coarse_to_fine", &back) == MLB_OK);
    CHECK_MSG(!mlb_pipeline_config_differs(&back, &want, NULL), "%s: a config.json without it loads %s differently", key,
              mlb_pipeline_config_differs(&back, &want, NULL));
    if (!bad) return;
    snprintf(kv, sizeof kv, "%s=%s", key, bad);
    REQUIRE(mlb_pipeline_config_set(&c, kv) == MLB_OK);
    CHECK_MSG(mlb_pipeline_validate(&c) == MLB_ERR_ARG, "%s=%s validated", key, bad);
}

TEST(config_round_trip_and_errors) {
    mlb_pipeline_config c = mlb_pipeline_default(), back;
    snprintf(c.prompt, sizeof c.prompt, "a \"golden\" goblet");
    snprintf(c.model, sizeof c.model, "/models/sd15");
    c.seed = 0xFFFFFFFFFFFFFFF1ull;   // beyond a double's integers: stored as a decimal string
    c.material = MLB_MATERIAL_DIRECT;
    c.geometry_lr = 3.3e-4;
    c.sdf_reg.end = 8.0 / 9;        // no 15-digit decimal reads back as this double: saved with 16
    c.guidance_scale = 0.1 + 0.2;   // (0.30000000000000004: 17 digits)
    c.n_envs = 2;
    snprintf(c.envs[1], sizeof c.envs[1], "/maps/a b.hdr");
    char path[512];
    tmp_path(path, sizeof path, "config.json");
    REQUIRE(mlb_pipeline_config_save(&c, path) == MLB_OK);
    REQUIRE(mlb_pipeline_config_load(&back, path) == MLB_OK);
    CHECK(back.seed == c.seed);
    CHECK(back.material == MLB_MATERIAL_DIRECT);
    CHECK(back.geometry_lr == c.geometry_lr && back.sdf_reg.end == c.sdf_reg.end && back.guidance_scale == c.guidance_scale);
    CHECK(!strcmp(back.prompt, c.prompt) && !strcmp(back.envs[1], c.envs[1]) && back.n_envs == 2);
    back.stop_after = c.stop_after;
    back.overwrite = c.overwrite;
    CHECK(!memcmp(&back, &c, sizeof c));   // every field (the struct was zeroed by the defaults)
    // hostile files: errors name the file and the key
    const char* bad[] = {"{\"format\": \"matlaber-run\"}", "[1, 2]", "{\"format\": \"other\"}"};
    for (int i = 0; i < 3; i++) {
        REQUIRE(mlb_write_file_atomic(path, bad[i], strlen(bad[i])) == MLB_OK);
        CHECK(mlb_pipeline_config_load(&back, path) != MLB_OK);
        CHECK(strstr(mlb_last_error(), "config.json") != NULL);
    }
    REQUIRE(mlb_pipeline_config_save(&c, path) == MLB_OK);
    char* text = NULL;
    size_t n = 0;
    REQUIRE(mlb_read_file(path, &text, &n, 1 << 20) == MLB_OK);
    char* at = strstr(text, "\"res\":");
    REQUIRE(at);
    memcpy(at, "\"rez\":", 6);
    REQUIRE(mlb_write_file_atomic(path, text, n) == MLB_OK);
    CHECK(mlb_pipeline_config_load(&back, path) != MLB_OK);
    CHECK(strstr(mlb_last_error(), "\"res\"") != NULL);
    // a run written before "view_prompts" existed loads with them on (what it ran with); a saved 0
    // comes back as 0; anything else is refused
    mlb_pipeline_config off = c;
    off.view_prompts = 0;
    REQUIRE(mlb_pipeline_config_save(&off, path) == MLB_OK);
    REQUIRE(mlb_pipeline_config_load(&back, path) == MLB_OK);
    CHECK(back.view_prompts == 0);
    free(text);
    text = NULL;
    REQUIRE(mlb_read_file(path, &text, &n, 1 << 20) == MLB_OK);
    char* vp = strstr(text, "\"view_prompts\":\t0");
    REQUIRE(vp);
    memcpy(vp, "\"view_prompts\":\t7", 17);
    REQUIRE(mlb_write_file_atomic(path, text, n) == MLB_OK);
    CHECK(mlb_pipeline_config_load(&back, path) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "view_prompts") != NULL);
    memcpy(vp, "\"view_prompt_\":\t0", 17);   // the key gone (renamed to one the loader ignores)
    REQUIRE(mlb_write_file_atomic(path, text, n) == MLB_OK);
    REQUIRE(mlb_pipeline_config_load(&back, path) == MLB_OK);
    CHECK(back.view_prompts == 1);
    free(text);
    // a run from before "coarse_to_fine" and "material_smoothness_specular" loads with what it ran
    // with (0, 0), not today's defaults (0.5, 0.1)
    CHECK(c.coarse_to_fine == 0.5 && c.w_mat_spec == 0.1);
    REQUIRE(load_without_keys(&c, path, "coarse_to_fine", "material_smoothness_specular", &back) == MLB_OK);
    CHECK(back.coarse_to_fine == 0 && back.w_mat_spec == 0);
    // "appearance_guidance_scale": a run from before it ran both stages at guidance_scale, which 0 means
    optional_key(&c, path, "appearance_guidance_scale", "75", "0", "-1");
    // "material_start": a run from before it started at the prior's centre (0)
    optional_key(&c, path, "material_start", "1", "0", "2");
    // "metal_start_lr_scale": a run from before it refined a metal start at the stage's rate (1)
    optional_key(&c, path, "metal_start_lr_scale", "0.1", "1", "0");
    // the prior's support term: a run from before it had none (0), and its radius 4.2
    optional_key(&c, path, "material_support", "100", "0", "-1");
    optional_key(&c, path, "material_support_radius", "5", "4.2", "0");
    // "appearance_model": a run from before it guided both stages with "model" ("")
    optional_key(&c, path, "appearance_model", "/models/other one", "", NULL);
    // "surface_smooth": a run from before it used the surface as extracted (0)
    optional_key(&c, path, "surface_smooth", "10", "0", "-1");
    // the geometry hash grid's span: a run from before it had the paper's (0 = 16 levels, 16..4096)
    optional_key(&c, path, "geometry_hash_levels", "8", "0", "33");
    optional_key(&c, path, "geometry_hash_base_res", "4", "0", "1");
    optional_key(&c, path, "geometry_hash_max_res", "16", "0", "4097");
    mlb_pipeline_config span = c;
    span.geometry_hash_levels = 8;
    span.geometry_hash_base_res = 32;   // finest below coarsest: 32..16
    span.geometry_hash_max_res = 16;
    CHECK(mlb_pipeline_validate(&span) == MLB_ERR_ARG && strstr(mlb_last_error(), "geometry_hash_max_res"));
    span.geometry_hash_base_res = 0;    // 16..16 over 8 levels: allowed (all one resolution)
    CHECK(mlb_pipeline_validate(&span) == MLB_OK);
    span.geometry_hash_levels = 1;
    span.geometry_hash_max_res = 64;    // one level, two resolutions
    CHECK(mlb_pipeline_validate(&span) == MLB_ERR_ARG && strstr(mlb_last_error(), "geometry_hash_levels 1"));
    mlb_hashgrid_config enc = mlb_hashgrid_default(), paper = enc;
    mlb_pipeline_geometry_hash(&c, &enc);   // all 0: the paper's grid, bit for bit
    CHECK(!memcmp(&enc, &paper, sizeof enc));
    mlb_pipeline_config img = c;   // a model for image guidance's appearance stage makes no sense
    snprintf(img.guidance, sizeof img.guidance, "images");
    snprintf(img.views_dir, sizeof img.views_dir, "/views");
    CHECK(mlb_pipeline_validate(&img) == MLB_OK);
    snprintf(img.appearance_model, sizeof img.appearance_model, "/models/x");
    CHECK(mlb_pipeline_validate(&img) == MLB_ERR_ARG && strstr(mlb_last_error(), "appearance_model"));
    mlb_clear_error();
}

// --set KEY=VALUE: any config.json key by its JSON type; unknown keys and wrong types are refused
// naming the key, the config unchanged; ranges are mlb_pipeline_validate's.
TEST(config_set) {
    mlb_pipeline_config c = mlb_pipeline_default(), before;
    snprintf(c.prompt, sizeof c.prompt, "a gold goblet");
    snprintf(c.model, sizeof c.model, "/models/sd15");
    REQUIRE(mlb_pipeline_config_set(&c, "geometry_t_max_end=300") == MLB_OK);
    CHECK(c.geometry_t_max_end == 300);
    REQUIRE(mlb_pipeline_config_set(&c, "appearance_lr=2.5e-2") == MLB_OK);
    CHECK(c.appearance_lr == 2.5e-2);
    REQUIRE(mlb_pipeline_config_set(&c, "init=torus") == MLB_OK);
    CHECK(!strcmp(c.init, "torus"));
    REQUIRE(mlb_pipeline_config_set(&c, "seed=18446744073709551615") == MLB_OK);
    CHECK(c.seed == UINT64_MAX);
    REQUIRE(mlb_pipeline_config_set(&c, "material=direct") == MLB_OK);
    CHECK(c.material == MLB_MATERIAL_DIRECT);
    CHECK(mlb_pipeline_validate(&c) == MLB_OK);
    REQUIRE(mlb_pipeline_config_set(&c, "envs=studio,/maps/a b.hdr") == MLB_OK);
    CHECK(c.n_envs == 2 && !strcmp(c.envs[0], "studio") && !strcmp(c.envs[1], "/maps/a b.hdr"));
    before = c;
    const char* bad[] = {"rez=64", "res", "=3", "res=abc", "res=64.5", "material=shiny", "envs=", "envs=sky,", "envs=a,,b",
                         "res=", "seed=-1", "seed=18446744073709551616", "seed=+5", "geometry_iters=3000000000"};
    for (int i = 0; i < 14; i++) {
        CHECK_MSG(mlb_pipeline_config_set(&c, bad[i]) != MLB_OK, "%s accepted", bad[i]);
        CHECK_MSG(strstr(mlb_last_error(), "--set") != NULL, "%s: %s", bad[i], mlb_last_error());
    }
    CHECK(strstr(mlb_last_error(), "out of range") != NULL);
    // text longer than a field holds is refused, never cut
    char long_prompt[1100 + 8];
    snprintf(long_prompt, sizeof long_prompt, "prompt=%01100d", 7);
    CHECK(mlb_pipeline_config_set(&c, long_prompt) != MLB_OK && strstr(mlb_last_error(), "too long"));
    CHECK(!memcmp(&c, &before, sizeof c));
    // what the command-line options refuse, the validation refuses too (--set and config.json)
    const char* out_of_range[] = {"geometry_lr=1e308", "appearance_lr=0", "geometry_iters=10000001", "appearance_iters=-1",
                                  "init_iters=1000001", "latent_size=7", "latent_size=264", "latent_size=-8",
                                  "guidance_scale=1e300", "appearance_guidance_scale=10001", "checkpoint_every=0",
                                  "preview_every=10000001", "material_smoothness=1000", "res=2056", "latent_iters=-2",
                                  "paint_centre_z=-0"};   // not written without paint_mesh: -0 would read back as 0
    const char* named[] = {"learning rates", "learning rates", "iteration counts", "iteration counts", "init_iters",
                           "latent_size", "latent_size", "latent_size", "guidance scale", "appearance guidance scale",
                           "checkpoint_every", "preview_every", "material smoothness", "--res", "latent_iters",
                           "belong to paint runs"};
    for (int i = 0; i < 16; i++) {
        mlb_pipeline_config t = c;
        REQUIRE(mlb_pipeline_config_set(&t, out_of_range[i]) == MLB_OK);
        CHECK_MSG(mlb_pipeline_validate(&t) == MLB_ERR_ARG && strstr(mlb_last_error(), named[i]), "%s: %s", out_of_range[i],
                  mlb_last_error());
    }
    mlb_pipeline_config t = c;
    REQUIRE(mlb_pipeline_config_set(&t, "latent_size=16") == MLB_OK && mlb_pipeline_config_set(&t, "geometry_lr=10") == MLB_OK);
    CHECK(mlb_pipeline_validate(&t) == MLB_OK);
    mlb_pipeline_config other = c;
    CHECK(mlb_pipeline_config_differs(&c, &other, NULL) == NULL);
    REQUIRE(mlb_pipeline_config_set(&other, "geometry_t_max_end=250") == MLB_OK);
    const char* diff = mlb_pipeline_config_differs(&c, &other, NULL);
    CHECK(diff && !strcmp(diff, "geometry_t_max_end"));
    static const char* const skip[] = {"geometry_t_max_end", NULL};
    CHECK(mlb_pipeline_config_differs(&c, &other, skip) == NULL);
    other.n_envs = 1;
    diff = mlb_pipeline_config_differs(&c, &other, skip);
    CHECK(diff && !strcmp(diff, "envs"));
    other.n_envs = c.n_envs;
    // the annealed range is validated: below the smallest timestep, or past 999
    other.geometry_t_min = 150;
    other.geometry_t_max_end = 100;
    CHECK(mlb_pipeline_validate(&other) == MLB_ERR_ARG);
    other.geometry_t_max_end = 1000;
    CHECK(mlb_pipeline_validate(&other) == MLB_ERR_ARG);
    mlb_clear_error();
}

// Presets: "paper" is the defaults, "cpu" a valid config that survives config.json (precision and
// the .glb size included); a run written before "export_texture" and "precision" existed resumes
// with no .glb and the program's precision; unknown names are refused with the list.
TEST(presets) {
    mlb_pipeline_config d = mlb_pipeline_default(), c = d, back;
    REQUIRE(mlb_pipeline_preset(&c, "paper") == MLB_OK);
    CHECK(!memcmp(&c, &d, sizeof c));
    REQUIRE(mlb_pipeline_preset(&c, "cpu") == MLB_OK);
    CHECK(c.views == 1 && c.res == 256 && !strcmp(c.precision, "bf16") && c.export_texture == 1024);
    CHECK(c.geometry_iters > 0 && c.appearance_iters > 0 && c.latent_iters < 0);   // a third latent, as the default
    CHECK(c.geometry_iters < d.geometry_iters / 10 && c.checkpoint_every < 20);
    snprintf(c.prompt, sizeof c.prompt, "a goblet");
    snprintf(c.model, sizeof c.model, "/models/sd15");
    CHECK(mlb_pipeline_validate(&c) == MLB_OK);
    char path[512];
    tmp_path(path, sizeof path, "config.json");
    REQUIRE(mlb_pipeline_config_save(&c, path) == MLB_OK);
    REQUIRE(mlb_pipeline_config_load(&back, path) == MLB_OK);
    back.stop_after = c.stop_after;
    back.overwrite = c.overwrite;
    CHECK(!memcmp(&back, &c, sizeof c));
    REQUIRE(load_without_keys(&c, path, "export_texture", "precision", &back) == MLB_OK);
    CHECK(back.export_texture == 0 && back.precision[0] == 0);
    c.export_texture = -1;
    CHECK(mlb_pipeline_validate(&c) == MLB_ERR_ARG);
    c.export_texture = 0;
    snprintf(c.precision, sizeof c.precision, "int8");
    CHECK(mlb_pipeline_validate(&c) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "precision") != NULL);
    // the tiny preset lets the model pick the start; image guidance has no model to ask
    mlb_pipeline_config t = mlb_pipeline_default();
    REQUIRE(mlb_pipeline_preset(&t, "tiny") == MLB_OK);
    CHECK(!strcmp(t.init, "auto"));
    // its geometry hash grid is no finer than its tet grid (docs/geometry.md, "Smoothness")
    CHECK(t.geometry_hash_max_res > 0 && t.geometry_hash_max_res <= mlb_pipeline_cells(&t));
    snprintf(t.prompt, sizeof t.prompt, "a ring");
    snprintf(t.model, sizeof t.model, "/models/tiny");
    CHECK(mlb_pipeline_validate(&t) == MLB_OK);
    snprintf(t.init, sizeof t.init, "auto:ellipsoid,cylinder,/meshes/cup.obj");
    CHECK(mlb_pipeline_validate(&t) == MLB_OK);
    const char* bad_lists[3] = {"auto:", "auto:torus,,cylinder", "auto:torus,"};
    for (int i = 0; i < 3; i++) {
        snprintf(t.init, sizeof t.init, "%s", bad_lists[i]);
        CHECK(mlb_pipeline_validate(&t) == MLB_ERR_ARG);
    }
    snprintf(t.init, sizeof t.init, "auto");
    snprintf(t.guidance, sizeof t.guidance, "images");
    snprintf(t.views_dir, sizeof t.views_dir, "/views");
    CHECK(mlb_pipeline_validate(&t) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "--init auto") != NULL);
    CHECK(mlb_pipeline_preset(&c, "fast") == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "fast") && strstr(mlb_last_error(), MLB_PIPELINE_PRESETS));
    mlb_clear_error();
}

// A sphere of one known material, rendered into a views folder.
static const float SPHERE_K[7] = {0.60f, 0.30f, 0.10f, 0.04f, 0.04f, 0.04f, 0.5f};
static void sphere_truth(const float* pos, float k[7]) {
    (void)pos;
    memcpy(k, SPHERE_K, sizeof SPHERE_K);
}

static mlb_status sphere_views(const char* dir, int res) {
    mlb_mesh m;
    mlb_status s = mlb_mesh_uv_sphere(&m, 0.55f, 48, 24);
    if (s) return s;
    static const char* envs[2] = {"sky", "studio"};
    mlb_views_render_config rc = mlb_views_render_default();
    rc.mesh = &m;
    rc.k = NULL;
    memcpy(rc.k_const, SPHERE_K, sizeof SPHERE_K);
    rc.n_views = 12;
    rc.res = res;
    rc.cube = 64;
    rc.envs = envs;
    rc.n_envs = 2;
    s = mlb_views_render(dir, &rc, NULL);
    mlb_mesh_free(&m);
    return s;
}

static mlb_pipeline_config small_fit(const char* views, int geometry_iters, int appearance_iters) {
    mlb_pipeline_config c = mlb_pipeline_default();
    snprintf(c.guidance, sizeof c.guidance, "images");
    snprintf(c.views_dir, sizeof c.views_dir, "%s", views);
    c.res = 32;
    c.views = 3;
    c.grid = 24;
    c.init_iters = 60;
    c.geometry_iters = geometry_iters;
    c.appearance_iters = appearance_iters;
    c.geometry_lr = 1e-2;
    c.cube_size = 64;
    c.env_height = 64;
    c.preview_every = 0;
    c.checkpoint_every = 2;
    c.n_envs = 2;
    snprintf(c.envs[0], sizeof c.envs[0], "sky");
    snprintf(c.envs[1], sizeof c.envs[1], "studio");
    return c;
}

static mlb_status run_fit(const char* run, const mlb_pipeline_config* c, int resume, mlb_pipeline_result* r) {
    mlb_guidance* g = NULL;
    mlb_views* v = NULL;
    mlb_status s = mlb_pipeline_make_guidance(c, NULL, &g, &v);
    if (!s) s = mlb_pipeline_run(run, c, g, v, NULL, resume, NULL, r);
    mlb_guidance_free(g);
    mlb_pipeline_free_views(v);
    return s;
}

// A known diffuse albedo is recovered. Tolerance: 0.02 RMSE on kd (linear; measured 0.006). Sources of error the
// fit cannot remove: the targets are 8-bit sRGB (quantisation ~0.002 linear at these values), the
// latent prior reproduces a given BRDF to ~0.01 RMSE (docs/brdf_prior.md, refined latent), the
// split-sum light of a 64² cube, antialiased edges at 32 px, and 150 steps. A fit that does not
// learn stays near the network's initial output (kd ≈ the prior's mean ~0.2-0.3 grey): RMSE ≳ 0.2.
TEST(image_fit_recovers_a_known_albedo) {
    char views[512], run[512];
    tmp_path(views, sizeof views, "sphere_views");
    tmp_path(run, sizeof run, "fit_albedo");
    REQUIRE(sphere_views(views, 32) == MLB_OK);
    mlb_pipeline_config c = small_fit(views, 30, 150);
    c.checkpoint_every = 1000;
    mlb_pipeline_result r;
    REQUIRE(run_fit(run, &c, 0, &r) == MLB_OK);
    CHECK(r.finished);
    mlb_run_asset a;
    REQUIRE(mlb_run_asset_load(&a, run) == MLB_OK);
    double psnr = 0, rmse = 1;
    REQUIRE(mlb_eval_albedo(&a.mesh, &a.material, sphere_truth, 6, 64, &psnr, &rmse) == MLB_OK);
    printf("  albedo RMSE %.4f (PSNR %.2f dB), %d faces\n", rmse, psnr, a.mesh.n_faces);
    CHECK(rmse < 0.02);
    // outputs a user opens
    const char* files[] = {"final/mesh.obj", "final/mesh_ks.obj", "final/mesh_roughness.obj", "final/material.safetensors",
                           "final/geometry.safetensors", "final/views.png", "final/shaded_0.png", "final/kd_3.png",
                           "loss.csv", "loss.png", "config.json"};
    for (size_t i = 0; i < sizeof files / sizeof *files; i++) {
        char p[700];
        snprintf(p, sizeof p, "%s/%s", run, files[i]);
        CHECK_MSG(mlb_is_file(p), "missing %s", files[i]);
    }
    mlb_run_asset_free(&a);
    // a second run into the same folder is refused (resume or overwrite instead)
    CHECK(run_fit(run, &c, 0, &r) != MLB_OK);
    CHECK(strstr(mlb_last_error(), "resume") != NULL);
    mlb_clear_error();
}

// Killed (stop_after: no checkpoint at the stop) in the geometry stage and again in the appearance
// stage, resumed each time: the same bytes as an uninterrupted run. The pieces run on 1 and 2
// threads in turn, against the uninterrupted run on 2: the thread count never changes a bit.
TEST(resume_reaches_the_uninterrupted_result) {
    char views[512], a[512], b[512], pa[700], pb[700];
    tmp_path(views, sizeof views, "sphere_views");
    tmp_path(a, sizeof a, "resume_a");
    tmp_path(b, sizeof b, "resume_b");
    if (!mlb_is_dir(views)) REQUIRE(sphere_views(views, 32) == MLB_OK);
    mlb_pipeline_config c = small_fit(views, 7, 7);
    c.init_iters = 20;
    mlb_pipeline_result r;
    int threads = mlb_get_threads();
    mlb_set_threads(2);
    REQUIRE(run_fit(a, &c, 0, &r) == MLB_OK);
    REQUIRE(r.finished);
    mlb_set_threads(1);
    c.stop_after = 5;   // geometry steps 0..4; the last checkpoint is after step 4 (every 2 steps → 4)
    REQUIRE(run_fit(b, &c, 0, &r) == MLB_OK);
    CHECK(!r.finished && r.geometry_steps == 5);
    mlb_set_threads(2);
    c.stop_after = 6;   // resumes at 4: geometry 4..6, appearance 0..2 (checkpoint at 2)
    REQUIRE(run_fit(b, &c, 1, &r) == MLB_OK);
    CHECK(!r.finished && r.geometry_steps == 3 && r.appearance_steps == 3);
    mlb_set_threads(1);
    c.stop_after = 0;
    REQUIRE(run_fit(b, &c, 1, &r) == MLB_OK);
    CHECK(r.finished && r.appearance_steps == 5);
    mlb_set_threads(threads);
    const char* files[] = {"final/material.safetensors", "final/geometry.safetensors", "final/mesh.obj", "loss.csv"};
    for (size_t i = 0; i < sizeof files / sizeof *files; i++) {
        snprintf(pa, sizeof pa, "%s/%s", a, files[i]);
        snprintf(pb, sizeof pb, "%s/%s", b, files[i]);
        CHECK_MSG(same_file(pa, pb), "%s differs after resume", files[i]);
    }
}

// surface_smooth: the appearance stage's and the outputs' mesh is the extraction smoothed by Taubin's
// rounds (the same faces, the vertices of mlb_mesh_smooth_taubin on the unsmoothed run's mesh, to
// the OBJ's printed digits), and a run stopped in the appearance stage resumes to the same bytes
// (the surface is extracted and smoothed again the same way).
TEST(surface_smooth) {
    char views[512], a[512], b[512], b2[512], pa[700], pb[700];
    tmp_path(views, sizeof views, "sphere_views");
    tmp_path(a, sizeof a, "smooth_0");
    tmp_path(b, sizeof b, "smooth_4");
    tmp_path(b2, sizeof b2, "smooth_4_resumed");
    if (!mlb_is_dir(views)) REQUIRE(sphere_views(views, 32) == MLB_OK);
    mlb_pipeline_config c = small_fit(views, 3, 3);
    c.init_iters = 20;
    mlb_pipeline_result r;
    REQUIRE(run_fit(a, &c, 0, &r) == MLB_OK && r.finished);
    c.surface_smooth = 4;
    REQUIRE(run_fit(b, &c, 0, &r) == MLB_OK && r.finished);
    c.stop_after = 4;   // the geometry stage's 3 steps and the appearance stage's first
    REQUIRE(run_fit(b2, &c, 0, &r) == MLB_OK && !r.finished);
    c.stop_after = 0;
    REQUIRE(run_fit(b2, &c, 1, &r) == MLB_OK && r.finished);
    mlb_run_asset ra, rb;
    REQUIRE(mlb_run_asset_load(&ra, a) == MLB_OK);
    REQUIRE(mlb_run_asset_load(&rb, b) == MLB_OK);
    CHECK(ra.config.surface_smooth == 0 && rb.config.surface_smooth == 4);
    REQUIRE(ra.mesh.n_verts == rb.mesh.n_verts && ra.mesh.n_faces == rb.mesh.n_faces);
    CHECK(!memcmp(ra.mesh.faces, rb.mesh.faces, sizeof(int32_t) * 3 * (size_t)ra.mesh.n_faces));
    REQUIRE(mlb_mesh_smooth_taubin(&ra.mesh, 4, 0.5f, -0.53f) == MLB_OK);
    double worst = 0, moved = 0;
    for (int i = 0; i < 3 * ra.mesh.n_verts; i++) worst = fmax(worst, fabs((double)ra.mesh.pos[i] - rb.mesh.pos[i]));
    mlb_run_asset_free(&ra);
    REQUIRE(mlb_run_asset_load(&ra, a) == MLB_OK);
    for (int i = 0; i < 3 * ra.mesh.n_verts; i++) moved = fmax(moved, fabs((double)ra.mesh.pos[i] - rb.mesh.pos[i]));
    printf("  smoothed: vertices moved up to %.4f, off the smoothing by %.2g\n", moved, worst);
    CHECK(worst < 1e-5 && moved > 1e-3);
    const char* files[] = {"final/material.safetensors", "final/mesh.obj", "loss.csv"};
    for (size_t i = 0; i < sizeof files / sizeof *files; i++) {
        snprintf(pa, sizeof pa, "%s/%s", b, files[i]);
        snprintf(pb, sizeof pb, "%s/%s", b2, files[i]);
        CHECK_MSG(same_file(pa, pb), "%s differs after resume", files[i]);
    }
    mlb_run_asset_free(&ra);
    mlb_run_asset_free(&rb);
}

// ---- score distillation with a tiny random SD model --------------------------------------------
static mlb_sds* tiny_sds(const mlb_unet* u, const mlb_vae* vae, const float* ac, uint64_t seed) {
    mlb_sds_options o = mlb_sds_default_options();
    mlb_sds* s = NULL;
    if (mlb_sds_create(u, vae, 0.18215f, ac, 0, &o, &s)) return NULL;
    enum { TC = 6 };
    int D = u->cfg.context_dim;
    float* e = malloc(sizeof(float) * TC * D);
    mlb_rng_fill_normal(e, (size_t)TC * D, seed, 1, 0, 0, 1);
    mlb_sds_set_cond(s, MLB_SDS_VIEW_NONE, e, TC);
    mlb_rng_fill_normal(e, (size_t)TC * D, seed, 2, 0, 0, 1);
    mlb_sds_set_uncond(s, e, TC);
    free(e);
    return s;
}

TEST(sds_generate_two_steps_per_stage) {
    char unet_path[512], cfg_path[512], run[512];
    tmp_path(unet_path, sizeof unet_path, "unet.safetensors");
    tmp_path(cfg_path, sizeof cfg_path, "unet.config.json");
    tmp_path(run, sizeof run, "generate_tiny");
    mlb_unet_config uc = mlb_unet_tiny_config(0);
    mlb_unet_random_options uo = mlb_unet_random_default_options();
    uo.seed = 7;
    uo.config_json_path = cfg_path;
    REQUIRE(mlb_unet_write_random(&uc, &uo, unet_path) == MLB_OK);
    mlb_unet* u = NULL;
    REQUIRE(mlb_unet_load(unet_path, NULL, &u) == MLB_OK);
    mlb_vae_config vc = mlb_vae_sd_config();
    int bo[4] = {32, 32, 64, 64};
    for (int i = 0; i < 4; i++) vc.block_out[i] = bo[i];
    mlb_vae* vae = NULL;
    REQUIRE(mlb_vae_create(NULL, &vc, &vae) == MLB_OK);
    mlb_vae_init_random(vae, 3, 1.0f);
    float ac[1000];
    REQUIRE(mlb_schedule_alphas_cumprod_f32(ac, 1000, MLB_SD_BETA_START, MLB_SD_BETA_END) == MLB_OK);

    mlb_pipeline_config c = mlb_pipeline_default();   // guidance "sds"
    snprintf(c.prompt, sizeof c.prompt, "a golden goblet");
    snprintf(c.model, sizeof c.model, "(tiny random model written by the test)");
    c.res = 64;   // the VAE's 8× downsampling → 8×8 latents
    c.views = 2;
    c.grid = 16;
    c.init_iters = 30;
    c.geometry_iters = 2;
    c.appearance_iters = 2;
    c.latent_iters = 1;   // step 0: 64² [normal, mask] latents; step 1: VAE-encoded normals
    c.cube_size = 64;
    c.env_height = 64;
    c.preview_every = 1;
    c.geometry_hash_levels = 6;   // the geometry network's hash grid from 4 to 16
    c.geometry_hash_base_res = 4;
    c.geometry_hash_max_res = 16;
    mlb_guidance_sds_config gc = mlb_guidance_sds_default();
    gc.views = c.views;
    gc.latent_iters = c.latent_iters;
    gc.n_envs = c.n_envs;
    gc.seed = c.seed;
    mlb_guidance* g = NULL;
    REQUIRE(mlb_guidance_sds_create_from(tiny_sds(u, vae, ac, 1), tiny_sds(u, vae, ac, 2), &gc, &g) == MLB_OK);
    mlb_pipeline_result r;
    mlb_status s = mlb_pipeline_run(run, &c, g, NULL, NULL, 0, NULL, &r);
    CHECK_MSG(s == MLB_OK, "%s", mlb_last_error());
    CHECK(r.finished && r.geometry_steps == 2 && r.appearance_steps == 2);
    CHECK(isfinite(r.geometry_loss) && r.geometry_loss > 0);
    CHECK(isfinite(r.appearance_loss) && r.appearance_loss > 0);
    char p[700];
    snprintf(p, sizeof p, "%s/previews/geometry_000002.png", run);
    CHECK(mlb_is_file(p));
    snprintf(p, sizeof p, "%s/final/mesh.obj", run);
    CHECK(mlb_is_file(p));
    // the network was made, and saved, with the config's hash-grid span
    snprintf(p, sizeof p, "%s/final/geometry.safetensors", run);
    mlb_geometry_net net;
    memset(&net, 0, sizeof net);
    REQUIRE(mlb_geometry_load(&net, p) == MLB_OK);
    CHECK(net.cfg.enc.n_levels == 6 && net.cfg.enc.base_res == 4);
    CHECK_MSG(fabs(pow(net.cfg.enc.per_level_scale, 5) - 4.0) < 1e-12, "per-level scale %.17g", net.cfg.enc.per_level_scale);
    geometry_net_free(&net);
    mlb_guidance_free(g);
    mlb_vae_free(vae);
    mlb_unet_free(u);
}

// ---- --init auto's look-ahead with a guidance written by the test --------------------------------
// It scores a render by how little of the image the object covers, so the flat slab beats the
// ellipsoid at once, and its loss is 0: in the look-ahead only the SDF regulariser acts, which at a
// working learning rate erases the thin slab (as it erases a table from a blob) and leaves the
// ellipsoid; at a learning rate too small to move anything the slab stays the choice. Either way
// the stage starts bitwise from the chosen candidate's own fit (--init NAME).
static mlb_status cov_sample_views(mlb_guidance* g, mlb_stage stage, long step, mlb_view* views) {
    const mlb_orbit_config* orbit = g->impl;
    for (int v = 0; v < g->n_views; v++) MLB_TRY(mlb_orbit_sample(&views[v], orbit, 5, (int)stage, step, v));
    return MLB_OK;
}
static mlb_status cov_loss(mlb_guidance* g, mlb_stage stage, long step, const mlb_view* views, int n, const float* images,
                           int H, int W, float* dimages, double* loss) {
    (void)g, (void)stage, (void)step, (void)views, (void)n, (void)images, (void)H, (void)W, (void)dimages;
    *loss = 0;
    return MLB_OK;
}
// cov_spread > 0 weighs the odd views' scores by 1 + spread and the even ones' by 1 - spread: the
// same mean win for the slab, spread over the views, so fewer standard errors.
static double cov_spread;
static mlb_status cov_score(mlb_guidance* g, mlb_stage stage, const mlb_view* views, int n, const float* images, int H,
                            int W, const int* t_range, double* per_view) {
    (void)g, (void)stage, (void)views, (void)t_range;
    for (int v = 0; v < n; v++) {
        double sum = 0;
        for (size_t i = 0; i < (size_t)H * W; i++) sum += images[4 * ((size_t)v * H * W + i) + 3];
        per_view[v] = -sum / ((double)H * W) * (1 + cov_spread * (v & 1 ? 1 : -1));
    }
    return MLB_OK;
}

// The log lines that contain the sink's `user` string, kept by the test's sink.
static char kept_log[4096];
static void keep_lines(mlb_log_level level, const char* message, void* user) {
    (void)level;
    if (strstr(message, (const char*)user) && strlen(kept_log) + strlen(message) + 2 < sizeof kept_log) {
        strcat(kept_log, message);
        strcat(kept_log, "\n");
    }
}

// The geometry checkpoint a run leaves after its first step (the fitted start), or NULL.
static char* start_of(const char* run, const char* init, double lr, long* size) {
    mlb_orbit_config orbit = mlb_orbit_default();
    mlb_guidance g = {.kind = "sds", .n_views = 2, .sample_views = cov_sample_views, .loss = cov_loss, .score = cov_score, .impl = &orbit};
    mlb_pipeline_config c = mlb_pipeline_default();
    snprintf(c.prompt, sizeof c.prompt, "a flat thing");
    snprintf(c.model, sizeof c.model, "(a guidance written by the test)");
    snprintf(c.init, sizeof c.init, "%s", init);
    c.res = 32;
    c.views = 2;
    c.grid = 32;
    c.hash_log2 = 14;
    c.init_iters = 60;
    c.geometry_iters = 40;
    c.geometry_lr = lr;
    c.appearance_iters = 0;
    c.stop_after = 1;   // stopped as if killed after a step: the checkpoint holds the start
    c.preview_every = 0;
    mlb_pipeline_result r;
    if (mlb_pipeline_run(run, &c, &g, NULL, NULL, 0, NULL, &r)) { printf("  %s: %s\n", init, mlb_last_error()); return NULL; }
    char path[700];
    snprintf(path, sizeof path, "%s/checkpoints/geometry.safetensors", run);
    char* bytes = NULL;
    size_t n = 0;
    if (mlb_read_file(path, &bytes, &n, 1 << 28)) return NULL;
    *size = (long)n;
    return bytes;
}

TEST(auto_init_looks_ahead) {
    const double lrs[2] = {1e-9, 3e-3};
    const char* expect[2] = {"slab", "ellipsoid"};
    for (int k = 0; k < 2; k++) {
        char run_auto[512], run_fixed[512];
        snprintf(run_auto, sizeof run_auto, "%s/auto_%d", tmpdir, k);
        snprintf(run_fixed, sizeof run_fixed, "%s/fixed_%d", tmpdir, k);
        long na = 0, nb = 0;
        kept_log[0] = 0;
        mlb_log_level level = mlb_log_get_level();
        mlb_log_set_level(MLB_LOG_INFO);
        mlb_log_set_sink(keep_lines, (void*)"--init auto");
        char* a = start_of(run_auto, "auto:ellipsoid,slab", lrs[k], &na);
        mlb_log_set_sink(NULL, NULL);
        mlb_log_set_level(level);
        char* b = start_of(run_fixed, expect[k], lrs[k], &nb);
        REQUIRE(a && b);
        printf("  lr %g:\n%s", lrs[k], kept_log);
        CHECK(strstr(kept_log, "16 views: ellipsoid") && strstr(kept_log, "best: the slab\n"));   // the start: the slab
        CHECK(strstr(kept_log, "after 20 steps") != NULL);
        if (k == 0) CHECK(!strstr(kept_log, "vanished") && strstr(kept_log, "starting from the slab"));
        else CHECK(strstr(kept_log, "slab vanished") && !strstr(kept_log, "ellipsoid vanished") &&
                   strstr(kept_log, "starting from the ellipsoid"));
        CHECK_MSG(na == nb && !memcmp(a, b, (size_t)na), "the start differs from --init %s", expect[k]);
        free(a);
        free(b);
    }
}

// A start must win clearly: the slab's win spread over the views so that it is 3 to 5 standard
// errors (enough once, under the old rule) leaves the ellipsoid, with no look-ahead; the same win
// by more (cov_spread 0, above) is the slab's.
TEST(auto_init_needs_a_clear_win) {
    char run_auto[512], run_fixed[512];
    snprintf(run_auto, sizeof run_auto, "%s/auto_spread", tmpdir);
    snprintf(run_fixed, sizeof run_fixed, "%s/fixed_spread", tmpdir);
    long na = 0, nb = 0;
    kept_log[0] = 0;
    mlb_log_level level = mlb_log_get_level();
    mlb_log_set_level(MLB_LOG_INFO);
    mlb_log_set_sink(keep_lines, (void*)"--init auto");
    cov_spread = 0.9;
    char* a = start_of(run_auto, "auto:ellipsoid,slab", 1e-9, &na);
    cov_spread = 0;
    mlb_log_set_sink(NULL, NULL);
    mlb_log_set_level(level);
    char* b = start_of(run_fixed, "ellipsoid", 1e-9, &nb);
    REQUIRE(a && b);
    printf("%s", kept_log);
    double m = 0, se = 0;
    const char* slab = strstr(kept_log, "slab ");
    REQUIRE(slab && sscanf(slab, "slab %*f (%lf +- %lf)", &m, &se) == 2 && se > 0);
    CHECK_MSG(m / se > 3 && m / se < 5, "the slab wins by %.2f standard errors: the case is not between 3 and 5", m / se);
    CHECK(strstr(kept_log, "best: the ellipsoid\n") && !strstr(kept_log, "after 20 steps"));
    CHECK(strstr(kept_log, "starting from the ellipsoid") != NULL);
    CHECK_MSG(na == nb && !memcmp(a, b, (size_t)na), "the start differs from --init ellipsoid");
    free(a);
    free(b);
}

// ---- starting-shape fits kept between the runs of one process (shape_fits.c) -------------------------
// start_of with the run's "shape init" lines in kept_log.
static char* start_logged(const char* run, const char* init, long* size) {
    kept_log[0] = 0;
    mlb_log_level level = mlb_log_get_level();
    mlb_log_set_level(MLB_LOG_INFO);
    mlb_log_set_sink(keep_lines, (void*)"shape init");
    char* bytes = start_of(run, init, 1e-9, size);
    mlb_log_set_sink(NULL, NULL);
    mlb_log_set_level(level);
    return bytes;
}

// A second run of the process takes the first's fits and starts from the same bytes; a fit from
// another network state is fitted again, and gives what a process keeping nothing gets.
TEST(shape_fits_kept) {
    char run[4][512];
    for (int k = 0; k < 4; k++) snprintf(run[k], sizeof run[k], "%s/kept_%d", tmpdir, k);
    long n[4] = {0};
    mlb_pipeline_keep_shape_fits(64 << 20);
    char* a = start_logged(run[0], "auto:ellipsoid,slab", &n[0]);
    CHECK(strstr(kept_log, "(slab): SDF") && !strstr(kept_log, "kept"));
    char* b = start_logged(run[1], "auto:ellipsoid,slab", &n[1]);
    printf("%s", kept_log);
    CHECK(strstr(kept_log, "(ellipsoid): SDF") && strstr(kept_log, "(slab): SDF"));
    CHECK(strstr(kept_log, "steps (kept") && !strstr(kept_log, "steps\n"));   // both kept
    REQUIRE(a && b);
    CHECK_MSG(n[0] == n[1] && !memcmp(a, b, (size_t)n[0]), "the kept fits start another run");
    free(a);
    free(b);

    // the key: the network's state before the fit (a fresh one at another seed, the slab itself)
    mlb_geometry_config gc = mlb_geometry_default();
    gc.enc.table_size = 1u << 12;
    mlb_pipeline_config c = mlb_pipeline_default();
    c.init_iters = 20;
    mlb_geometry_net net, ref;
    memset(&net, 0, sizeof net);
    memset(&ref, 0, sizeof ref);
    REQUIRE(!geometry_net_init(&net, &gc) && !geometry_net_init(&ref, &gc));
    float* fit1 = malloc(sizeof(float) * net.n_params);
    REQUIRE(fit1);
    REQUIRE(!pipeline_init_shape(&net, &c, "torus", 0, NULL));
    memcpy(fit1, net.params, sizeof(float) * net.n_params);
    net.params[7] += 1e-3f;   // another start: not the kept fit's
    memcpy(ref.params, net.params, sizeof(float) * net.n_params);
    REQUIRE(!pipeline_init_shape(&net, &c, "torus", 0, NULL));
    mlb_pipeline_keep_shape_fits(0);   // the reference: nothing kept
    REQUIRE(!pipeline_init_shape(&ref, &c, "torus", 0, NULL));
    CHECK_MSG(!memcmp(net.params, ref.params, sizeof(float) * net.n_params), "a fit from another start was not fitted");
    CHECK(memcmp(net.params, fit1, sizeof(float) * net.n_params) != 0);
    geometry_net_free(&net);
    geometry_net_free(&ref);
    free(fit1);
}

// ---- material_start with a guidance written by the test -----------------------------------------
// Its score favours the archetype rendered at one call (the archetypes are scored one call each, in
// material_start.c's order: grey metal 0, warm metal 1, white glossy 2, grey rough 3, warm glossy 4,
// red glossy 5, blue glossy 6, green glossy 7), and it keeps each call's mean colour over the
// object, so the test sees that the renders are the archetypes. A metal's win starts the network
// from that metal (in latent and direct mode); a dielectric's leaves the start bitwise the prior's
// centre, as material_start 0 does.
// With `close` set it makes a close call instead: on the first look (8 views) the grey metal wins
// by 0.1 with per-view scores of 0.3 and -0.1 in turn (the white glossy 0, the rest -1), within 2
// standard errors; on the second look (the two, 32 views: calls 8 and 9) the metal scores -0.2 on
// the 24 new views, so the white glossy wins. With `close` TIE_METAL or TIE_CENTRE the second look
// is a tie (the metal 0.3 and -0.5 in turn on the new views: -0.05 +- 0.07 on 32), so the stage is
// tried from both starts (calls 10 and 11: the network trained from the metal, then from the
// centre), and the trial named wins.
enum { ARCH_N = 8, ARCH_GREY_METAL = 0, ARCH_WHITE = 2, ARCH_RED = 5, ARCH_BLUE = 6 };
enum { CLOSE_CALL = 1, TIE_METAL = 2, TIE_CENTRE = 3 };
typedef struct {
    mlb_orbit_config orbit;
    int want, calls, close;
    int n_views[ARCH_N + 4];   // each call's views
    int t_range[2];   // the timesteps the start asked to be scored at
    double rgb[ARCH_N][3];
} arch_guidance;
static mlb_status arch_sample_views(mlb_guidance* g, mlb_stage stage, long step, mlb_view* views) {
    const arch_guidance* a = g->impl;
    for (int v = 0; v < g->n_views; v++) MLB_TRY(mlb_orbit_sample(&views[v], &a->orbit, 5, (int)stage, step, v));
    return MLB_OK;
}
static mlb_status arch_score(mlb_guidance* g, mlb_stage stage, const mlb_view* views, int n, const float* images, int H,
                             int W, const int* t_range, double* per_view) {
    (void)views;
    arch_guidance* a = g->impl;
    const int expected = ARCH_N + (a->close ? 2 : 0) + (a->close > CLOSE_CALL ? 2 : 0);
    if (stage != MLB_STAGE_APPEARANCE || a->calls >= expected) return mlb_fail(MLB_ERR_ARG, "arch_score: unexpected call");
    a->n_views[a->calls] = n;
    if (a->close && a->calls >= ARCH_N + 2) {   // a tie's trials: from the metal (call 10), from the centre (11)
        int from_metal = a->calls == ARCH_N + 2;
        for (int v = 0; v < n; v++) per_view[v] = from_metal == (a->close == TIE_METAL) ? 1.0 : 0.0;
        a->calls++;
        return MLB_OK;
    }
    if (a->close) {   // the close call: the archetype by the call (the first look's order, then the pair)
        int arch = a->calls < ARCH_N ? a->calls : a->calls == ARCH_N ? ARCH_GREY_METAL : ARCH_WHITE;
        double later = a->close == CLOSE_CALL ? -0.2 : 0;
        for (int v = 0; v < n; v++) {
            if (a->close != CLOSE_CALL && v >= 8) later = v % 2 ? -0.5 : 0.3;
            per_view[v] = arch == ARCH_WHITE ? 0.0 : arch != ARCH_GREY_METAL ? -1.0 : v < 8 ? (v % 2 ? -0.1 : 0.3) : later;
        }
        a->calls++;
        return MLB_OK;
    }
    if (t_range) a->t_range[0] = t_range[0], a->t_range[1] = t_range[1];
    double sum[3] = {0, 0, 0}, cover = 0;
    for (size_t i = 0; i < (size_t)n * H * W; i++) {
        const float* px = images + 4 * i;
        if (px[3] < 0.5f) continue;
        for (int k = 0; k < 3; k++) sum[k] += px[k];
        cover++;
    }
    for (int k = 0; k < 3; k++) a->rgb[a->calls][k] = cover > 0 ? sum[k] / cover : 0;
    for (int v = 0; v < n; v++) per_view[v] = a->calls == a->want ? 1.0 : 0.0;
    a->calls++;
    return MLB_OK;
}

// How material_start_run runs beyond its arguments (all 0: one appearance step, the same rate after
// a metal start, uninterrupted, fresh).
typedef struct {
    double lr_scale;          // metal_start_lr_scale (0: 1)
    int appearance_iters;     // (0: 1)
    int stop_after, resume;   // the config's stop_after; resume the run folder
    int close;                // the guidance makes a close call (arch_guidance)
} mstart_opts;

// The appearance checkpoint's learning rate (its metadata "lr"), or -1.
static double checkpoint_lr(const char* run) {
    char path[700];
    snprintf(path, sizeof path, "%s/checkpoints/appearance.safetensors", run);
    mlb_safetensors* st = NULL;
    if (mlb_st_open(&st, path)) return -1;
    const char* t = mlb_st_metadata(st, "lr");
    double lr = t ? strtod(t, NULL) : -1;
    mlb_st_close(st);
    return lr;
}

// n points on a spiral over the sphere of radius 0.5 (the test runs' surface), pos [n,3].
static void sphere_points(float* pos, int n) {
    for (int i = 0; i < n; i++) {
        double y = 1 - (2.0 * i + 1) / n, rho = sqrt(1 - y * y), phi = 2.399963 * i;
        pos[3 * i] = (float)(0.5 * rho * cos(phi)), pos[3 * i + 1] = (float)(0.5 * y), pos[3 * i + 2] = (float)(0.5 * rho * sin(phi));
    }
}

// One geometry step from the ellipsoid and one appearance step (or o's); the final material
// network's bytes (*size) and its mean kd and ks over points of the surface (the sphere of radius 0.5).
static char* material_start_run(const char* run, int material_start, int want, mlb_material_mode mode, arch_guidance* a,
                                const mstart_opts* o, long* size, double* kd, double* ks) {
    memset(a, 0, sizeof *a);
    a->orbit = mlb_orbit_default();
    a->want = want;
    a->close = o->close;
    mlb_guidance g = {.kind = "sds", .n_views = 2, .sample_views = arch_sample_views, .loss = cov_loss, .score = arch_score, .impl = a};
    mlb_pipeline_config c = mlb_pipeline_default();
    snprintf(c.prompt, sizeof c.prompt, "a metal thing");
    snprintf(c.model, sizeof c.model, "(a guidance written by the test)");
    c.res = 32;
    c.views = 2;
    c.grid = 16;
    c.hash_log2 = 14;
    c.init_iters = 30;
    c.geometry_iters = 1;
    c.appearance_iters = o->appearance_iters > 0 ? o->appearance_iters : 1;
    c.checkpoint_every = 1;
    c.stop_after = o->stop_after;
    c.preview_every = 0;
    c.export_texture = 0;
    c.cube_size = 64;
    c.env_height = 32;
    c.material = mode;
    c.material_start = material_start;
    c.metal_start_lr_scale = o->lr_scale > 0 ? o->lr_scale : 1;
    mlb_pipeline_result r;
    if (mlb_pipeline_run(run, &c, &g, NULL, NULL, o->resume, NULL, &r)) { printf("  %s: %s\n", run, mlb_last_error()); return NULL; }
    if (!r.finished) return calloc(1, 1);   // stopped: nothing final to read
    char path[700];
    snprintf(path, sizeof path, "%s/final/material.safetensors", run);
    char* bytes = NULL;
    size_t n = 0;
    mlb_material_net net;
    memset(&net, 0, sizeof net);
    if (mlb_read_file(path, &bytes, &n, 1 << 28) || mlb_material_load(&net, path)) {
        printf("  %s: %s\n", path, mlb_last_error());
        free(bytes);
        return NULL;
    }
    enum { P = 64 };
    float pos[3 * P], k[7 * P];
    sphere_points(pos, P);
    mlb_status s = mlb_material_eval(&net, pos, P, k);
    *kd = *ks = 0;
    for (int i = 0; !s && i < P; i++)
        for (int j = 0; j < 3; j++) { *kd += k[7 * i + j] / (3.0 * P); *ks += k[7 * i + 3 + j] / (3.0 * P); }
    material_net_free(&net);
    if (s) { printf("  %s: %s\n", path, mlb_last_error()); free(bytes); return NULL; }
    *size = (long)n;
    return bytes;
}

TEST(material_start_picks_a_metal) {
    char run[512];
    arch_guidance a;
    long n_metal = 0, n_red = 0, n_off = 0;
    double kd[4], ks[4];
    snprintf(run, sizeof run, "%s/mstart_metal", tmpdir);
    const mstart_opts plain = {0}, tenth = {.lr_scale = 0.1};
    char* metal = material_start_run(run, 1, ARCH_GREY_METAL, MLB_MATERIAL_LATENT, &a, &tenth, &n_metal, &kd[0], &ks[0]);
    CHECK(checkpoint_lr(run) == 1e-2 * 0.1);   // the metal start's rate, as the stage took it
    CHECK(a.calls == ARCH_N);
    CHECK(a.t_range[0] == 350 && a.t_range[1] == 550);   // the middle timesteps, where a metal and a glaze differ
    // the renders are the archetypes: the red one red, the blue one blue
    CHECK(a.rgb[ARCH_RED][0] > 1.5 * a.rgb[ARCH_RED][1] && a.rgb[ARCH_RED][0] > 1.5 * a.rgb[ARCH_RED][2]);
    CHECK(a.rgb[ARCH_BLUE][2] > 1.5 * a.rgb[ARCH_BLUE][0] && a.rgb[ARCH_BLUE][2] > 1.2 * a.rgb[ARCH_BLUE][1]);
    snprintf(run, sizeof run, "%s/mstart_red", tmpdir);
    char* red = material_start_run(run, 1, ARCH_RED, MLB_MATERIAL_LATENT, &a, &tenth, &n_red, &kd[1], &ks[1]);
    CHECK(a.calls == ARCH_N);
    CHECK(checkpoint_lr(run) == 1e-2);   // a dielectric's win keeps the config's rate
    snprintf(run, sizeof run, "%s/mstart_off", tmpdir);
    char* off = material_start_run(run, 0, ARCH_GREY_METAL, MLB_MATERIAL_LATENT, &a, &plain, &n_off, &kd[2], &ks[2]);
    CHECK(a.calls == 0);   // material_start 0: no scoring
    long n_direct = 0;
    snprintf(run, sizeof run, "%s/mstart_direct", tmpdir);
    char* direct = material_start_run(run, 1, ARCH_GREY_METAL, MLB_MATERIAL_DIRECT, &a, &plain, &n_direct, &kd[3], &ks[3]);
    REQUIRE(metal && red && off && direct);
    printf("  mean kd / ks: metal %.3f / %.3f, red won %.3f / %.3f, off %.3f / %.3f, direct metal %.3f / %.3f\n", kd[0],
           ks[0], kd[1], ks[1], kd[2], ks[2], kd[3], ks[3]);
    // the grey metal (kd 0.02, ks 0.9) after one step of lr 0.001 (latent) or 0.01 (direct); the centre is not metal
    CHECK(kd[0] < 0.08 && ks[0] > 0.8);
    CHECK(kd[3] < 0.08 && ks[3] > 0.8);
    // a close call between the grey metal and the white glossy, looked at again on 32 views (the
    // first 16 steps' 2 views each) and won there by the dielectric: the run is material_start 0's
    long n_close = 0;
    double kd_close, ks_close;
    const mstart_opts close = {.lr_scale = 0.1, .close = 1};
    snprintf(run, sizeof run, "%s/mstart_close", tmpdir);
    char* closed = material_start_run(run, 1, ARCH_GREY_METAL, MLB_MATERIAL_LATENT, &a, &close, &n_close, &kd_close, &ks_close);
    REQUIRE(closed);
    CHECK_MSG(a.calls == ARCH_N + 2 && a.n_views[0] == 8 && a.n_views[ARCH_N] == 32 && a.n_views[ARCH_N + 1] == 32,
              "%d calls, views %d then %d, %d", a.calls, a.n_views[0], a.n_views[ARCH_N], a.n_views[ARCH_N + 1]);
    CHECK(checkpoint_lr(run) == 1e-2);   // not a metal start
    CHECK(n_close == n_off && !memcmp(closed, off, (size_t)n_off));
    free(closed);
    // a tie on the 32 views: the stage tried from the grey metal and from the centre (one step each,
    // the stage's length here), each result scored on the 32 views; the trial that wins decides,
    // and a trial leaves nothing behind: the centre's win is material_start 0's run, bit for bit
    for (int who = TIE_METAL; who <= TIE_CENTRE; who++) {
        const mstart_opts tie = {.lr_scale = 0.1, .close = who};
        long n_tie = 0;
        double kd_tie, ks_tie;
        snprintf(run, sizeof run, "%s/mstart_tie%d", tmpdir, who);
        char* tied = material_start_run(run, 1, ARCH_GREY_METAL, MLB_MATERIAL_LATENT, &a, &tie, &n_tie, &kd_tie, &ks_tie);
        REQUIRE(tied);
        CHECK_MSG(a.calls == ARCH_N + 4 && a.n_views[ARCH_N + 2] == 32 && a.n_views[ARCH_N + 3] == 32, "%d calls", a.calls);
        if (who == TIE_METAL) {
            CHECK(checkpoint_lr(run) == 1e-2 * 0.1);   // the metal start, at its rate
            CHECK(kd_tie < 0.08 && ks_tie > 0.8);
            CHECK(n_tie == n_metal && !memcmp(tied, metal, (size_t)n_metal));   // the metal start's run, bit for bit
        } else {
            CHECK(checkpoint_lr(run) == 1e-2);
            CHECK(n_tie == n_off && !memcmp(tied, off, (size_t)n_off));
        }
        free(tied);
    }
    const float centre[7] = {(float)kd[2], (float)kd[2], (float)kd[2], (float)ks[2], (float)ks[2], (float)ks[2], 0.5f};
    CHECK(!mlb_text3d_is_metal(centre));   // (the benchmark's rule on the means)
    // a dielectric's win: the run as material_start 0 makes it, bit for bit
    CHECK(n_red == n_off && !memcmp(red, off, (size_t)n_off));
    CHECK(!(n_metal == n_off && !memcmp(metal, off, (size_t)n_off)));
    free(metal);
    free(red);
    free(off);
    free(direct);
}

// Killed in the appearance stage after a metal start and resumed: the same bytes as the run not
// killed, so the resumed steps take the checkpoint's lowered rate (the config's would differ), and
// the start is not scored again.
TEST(metal_start_resumes_at_its_rate) {
    char a_run[512], b_run[512];
    arch_guidance a;
    long n_a = 0, n_b = 0;
    double kd, ks;
    snprintf(a_run, sizeof a_run, "%s/mstart_whole", tmpdir);
    snprintf(b_run, sizeof b_run, "%s/mstart_killed", tmpdir);
    mstart_opts o = {.lr_scale = 0.1, .appearance_iters = 3};
    char* whole = material_start_run(a_run, 1, ARCH_GREY_METAL, MLB_MATERIAL_LATENT, &a, &o, &n_a, &kd, &ks);
    o.stop_after = 3;   // geometry step 0, appearance steps 0 and 1 (checkpointed after 0: the stop is a kill)
    char* killed = material_start_run(b_run, 1, ARCH_GREY_METAL, MLB_MATERIAL_LATENT, &a, &o, &n_b, &kd, &ks);
    CHECK(a.calls == ARCH_N);
    free(killed);
    o.stop_after = 0;
    o.resume = 1;
    char* resumed = material_start_run(b_run, 1, ARCH_GREY_METAL, MLB_MATERIAL_LATENT, &a, &o, &n_b, &kd, &ks);
    REQUIRE(whole && resumed);
    CHECK(a.calls == 0);   // resumed in the appearance stage: no second scoring
    CHECK(checkpoint_lr(b_run) == 1e-2 * 0.1);
    CHECK_MSG(n_a == n_b && !memcmp(whole, resumed, (size_t)n_a), "the resumed run's material network differs");
    free(whole);
    free(resumed);
}

// ---- the prior's support (material_support) ----------------------------------------------------
// A guidance that asks for brighter renders in the appearance stage (dL/dimage = -1 on every
// colour channel): the codes run outwards, to where the decoder's kd and ks saturate. With the
// support term at a small test radius they stay near it; without, they go well past it.
static mlb_status bright_loss(mlb_guidance* g, mlb_stage stage, long step, const mlb_view* views, int n,
                              const float* images, int H, int W, float* dimages, double* loss) {
    (void)g, (void)step, (void)views;
    *loss = 0;
    if (stage != MLB_STAGE_APPEARANCE) return MLB_OK;
    for (size_t i = 0; i < (size_t)n * H * W; i++)
        for (int c = 0; c < 3; c++) {
            dimages[4 * i + c] = -1.0f;
            *loss -= images[4 * i + c];
        }
    return MLB_OK;
}

// The final codes' largest |z| over points of the sphere of radius 0.5 (the run's surface), or -1.
static double support_run(const char* run, double weight, double radius) {
    arch_guidance a;   // for its orbit's views only
    memset(&a, 0, sizeof a);
    a.orbit = mlb_orbit_default();
    mlb_guidance g = {.kind = "sds", .n_views = 2, .sample_views = arch_sample_views, .loss = bright_loss, .impl = &a};
    mlb_pipeline_config c = mlb_pipeline_default();
    snprintf(c.prompt, sizeof c.prompt, "a bright thing");
    snprintf(c.model, sizeof c.model, "(a guidance written by the test)");
    c.res = 32, c.views = 2, c.grid = 16, c.hash_log2 = 14, c.init_iters = 30;
    c.geometry_iters = 1, c.appearance_iters = 25, c.appearance_lr = 0.05;
    c.checkpoint_every = 100, c.preview_every = 0, c.export_texture = 0, c.cube_size = 64, c.env_height = 32;
    c.material_support = weight, c.material_support_radius = radius;
    mlb_pipeline_result r;
    if (mlb_pipeline_run(run, &c, &g, NULL, NULL, 0, NULL, &r)) { printf("  %s: %s\n", run, mlb_last_error()); return -1; }
    char path[700];
    snprintf(path, sizeof path, "%s/final/material.safetensors", run);
    mlb_material_net net;
    memset(&net, 0, sizeof net);
    if (mlb_material_load(&net, path)) { printf("  %s: %s\n", path, mlb_last_error()); return -1; }
    enum { P = 64 };
    float pos[3 * P], z[4 * P];
    sphere_points(pos, P);
    mlb_status s = mlb_material_eval_latent(&net, pos, P, z);
    material_net_free(&net);
    if (s) return -1;
    double most = 0;
    for (int i = 0; i < P; i++)
        most = fmax(most, sqrt((double)z[4 * i] * z[4 * i] + (double)z[4 * i + 1] * z[4 * i + 1] +
                               (double)z[4 * i + 2] * z[4 * i + 2] + (double)z[4 * i + 3] * z[4 * i + 3]));
    return most;
}

TEST(material_support_holds_the_codes) {
    char run[512];
    double most[3];
    const double weight[3] = {0, 100, 1000};
    for (int i = 0; i < 3; i++) {
        snprintf(run, sizeof run, "%s/support_%d", tmpdir, i);
        most[i] = support_run(run, weight[i], 1.0);
        REQUIRE(most[i] >= 0);
    }
    printf("  largest |z| after 25 steps towards brightness: off %.3f; radius 1 at weight 100 %.3f, 1000 %.3f\n", most[0],
           most[1], most[2]);
    CHECK(most[0] > 10);                      // the guidance alone takes the codes far past the radius
    CHECK(most[1] < 0.1 * most[0] && most[2] < most[1]);   // the term holds them, the harder the stronger
    CHECK(most[2] < 1.5 && most[2] > 0.5);    // at 1000 near the radius (and they did move out to it)
}

int main(void) {
    const char* base = getenv("TMPDIR");
    snprintf(tmpdir, sizeof tmpdir, "%s/mlb_pipeline_XXXXXX", base && *base ? base : "/tmp");
    if (!mkdtemp(tmpdir)) return 1;
    RUN(config_round_trip_and_errors);
    RUN(config_set);
    RUN(presets);
    RUN(image_fit_recovers_a_known_albedo);
    RUN(resume_reaches_the_uninterrupted_result);
    RUN(surface_smooth);
    RUN(sds_generate_two_steps_per_stage);
    RUN(auto_init_looks_ahead);
    RUN(auto_init_needs_a_clear_win);
    RUN(shape_fits_kept);
    RUN(material_start_picks_a_metal);
    RUN(metal_start_resumes_at_its_rate);
    RUN(material_support_holds_the_codes);
    char cmd[400];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmpdir);
    if (system(cmd)) return 1;
    return test_summary();
}
