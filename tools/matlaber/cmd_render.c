// matlaber render | relight | brdf swatch: a mesh (or spheres) with a 7-d BRDF under an environment.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include "cli.h"
#include "matlaber/brdf.h"
#include "matlaber/brdf_ae.h"
#include "matlaber/fileio.h"
#include "matlaber/goblet.h"
#include "matlaber/image_write.h"
#include "matlaber/log.h"
#include "matlaber/obj.h"
#include "matlaber/progress.h"
#include "matlaber/render.h"
#include "matlaber/views.h"

// Options render and relight share.
typedef struct {
    const char *mesh, *env, *model, *out, *latent, *kd, *ks, *kr, *background, *views_out;
    double rotate, az, el, radius, fov, env_scale, el_min, el_max;
    long size, ss, frames, cube, views, seed;
    int fresnel_schlick, keep_scale, goblet;
} render_opts;

static const cli_option render_options[] = {
    {"mesh", 1, 'm', "FILE.obj", "the mesh (normalised into the unit sphere unless --keep-scale)"},
    {"goblet", 0, 'G', NULL, "the procedural goblet of the demo with its own materials (instead of --mesh)"},
    {"kd", 1, 'd', "R,G,B", "diffuse albedo, linear (default 0.5,0.5,0.5)"},
    {"ks", 1, 's', "R,G,B", "specular albedo F0, linear (default 0.04,0.04,0.04)"},
    {"kr", 1, 'r', "X", "roughness in [0.08, 1] (default 0.5)"},
    {"latent", 1, 'z', "Z1,Z2,Z3,Z4", "material as a latent code of the BRDF prior (instead of --kd/--ks/--kr)"},
    {"model", 1, 'M', "FILE", "BRDF prior for --latent (default: the built-in prior)"},
    {"env", 1, 'e', "NAME|FILE", "environment: sky, overcast, studio, white, or an .hdr/.exr file (default studio)"},
    {"env-scale", 1, 'x', "X", "multiply the environment's radiance (default 1)"},
    {"rotate", 1, 'R', "DEG", "rotate the environment about the vertical axis (default 0)"},
    {"view", 1, 'v', "AZ,EL", "camera azimuth and elevation in degrees (default 30,20)"},
    {"radius", 1, 'D', "X", "camera distance (default 3)"},
    {"fov", 1, 'f', "DEG", "vertical field of view (default 40)"},
    {"size", 1, 'n', "N", "image width and height (default 512)"},
    {"supersample", 1, 'S', "S", "render at S x and filter down (default 2)"},
    {"background", 1, 'b', "env|black|white|R,G,B", "what is behind the object (default env)"},
    {"cube", 1, 'c', "N", "cube-map face size of the pre-integrated light (default 512)"},
    {"fresnel", 1, 'F', "paper|schlick", "Fresnel of the split sum (default paper)"},
    {"frames", 1, 'k', "N", "relight: frames of a full turn of the light (default 36)"},
    {"keep-scale", 0, 'K', NULL, "do not normalise the mesh"},
    {"out", 1, 'o', "FILE|DIR", "render: .png (sRGB), .exr or .hdr (linear); relight: a folder"},
    {"views-out", 1, 'O', "DIR", "render: a multi-view data set instead of one image (docs/views.md)"},
    {"views", 1, 'V', "N", "--views-out: number of views (default 24)"},
    {"res", 1, 'n', "N", "same as --size"},
    {"elevation", 1, 'E', "MIN,MAX", "--views-out: elevation band of the cameras in degrees (default -30,75)"},
    {"seed", 1, 'Q', "S", "--views-out: seed of the azimuths, environments and rotations (default 1)"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

static int parse_render_options(int argc, char** argv, const char* cmd, render_opts* o) {
    const mlb_views_render_config v = mlb_views_render_default();   // --views-out's defaults, and the camera's
    *o = (render_opts){.env = "studio", .az = 30, .el = 20, .radius = v.radius, .fov = v.fovy_deg, .env_scale = 1,
                       .size = 512, .ss = 2, .frames = 36, .cube = 512, .background = "env", .views = v.n_views,
                       .seed = (long)v.seed, .el_min = v.el_min, .el_max = v.el_max};
    const struct option* table = cli_getopt_table(render_options);
    optind = 1;
    int c;
    float two[2];
    while ((c = getopt_long(argc, argv, "ho:", table, NULL)) != -1) {
        switch (c) {
        case 'm': o->mesh = optarg; break;
        case 'd': o->kd = optarg; break;
        case 's': o->ks = optarg; break;
        case 'r': o->kr = optarg; break;
        case 'z': o->latent = optarg; break;
        case 'M': o->model = optarg; break;
        case 'e': o->env = optarg; break;
        case 'x': if (cli_parse_double(optarg, 0, 1e9, &o->env_scale)) return cli_usage_error(cmd, "--env-scale: expected >= 0"); break;
        case 'R': if (cli_parse_double(optarg, -1e6, 1e6, &o->rotate)) return cli_usage_error(cmd, "--rotate: expected degrees"); break;
        case 'v':
            if (cli_parse_floats(optarg, two, 2) || fabsf(two[1]) > 89.9f) return cli_usage_error(cmd, "--view: expected AZ,EL with |EL| < 90");
            o->az = two[0]; o->el = two[1];
            break;
        case 'D': if (cli_parse_double(optarg, 0.01, 1e6, &o->radius)) return cli_usage_error(cmd, "--radius: expected > 0"); break;
        case 'f': if (cli_parse_double(optarg, 1, 170, &o->fov)) return cli_usage_error(cmd, "--fov: expected 1..170 degrees"); break;
        case 'n': if (cli_parse_long(optarg, 8, 8192, &o->size)) return cli_usage_error(cmd, "--size: expected 8..8192"); break;
        case 'S': if (cli_parse_long(optarg, 1, 8, &o->ss)) return cli_usage_error(cmd, "--supersample: expected 1..8"); break;
        case 'b': o->background = optarg; break;
        case 'c':
            if (cli_parse_long(optarg, 64, 4096, &o->cube) || (o->cube & (o->cube - 1)))
                return cli_usage_error(cmd, "--cube: expected a power of two in 64..4096");
            break;
        case 'F':
            if (strcmp(optarg, "paper") == 0) o->fresnel_schlick = 0;
            else if (strcmp(optarg, "schlick") == 0) o->fresnel_schlick = 1;
            else return cli_usage_error(cmd, "--fresnel: expected paper or schlick");
            break;
        case 'k': if (cli_parse_long(optarg, 1, 100000, &o->frames)) return cli_usage_error(cmd, "--frames: expected >= 1"); break;
        case 'K': o->keep_scale = 1; break;
        case 'G': o->goblet = 1; break;
        case 'O': o->views_out = optarg; break;
        case 'V': if (cli_parse_long(optarg, 1, 1000, &o->views)) return cli_usage_error(cmd, "--views: expected 1..1000"); break;
        case 'Q': if (cli_parse_long(optarg, 0, 0x7fffffffffffffffL, &o->seed)) return cli_usage_error(cmd, "--seed: expected an integer >= 0"); break;
        case 'E':
            if (cli_parse_floats(optarg, two, 2) || two[0] < -90 || two[1] > 90 || two[0] > two[1])
                return cli_usage_error(cmd, "--elevation: expected MIN,MAX with -90 <= MIN <= MAX <= 90");
            o->el_min = two[0]; o->el_max = two[1];
            break;
        case 'o': o->out = optarg; break;
        case 'h': return -1;
        default: return cli_usage_error(cmd, "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error(cmd, "unexpected argument '%s'", argv[optind]);
    if (!o->mesh && !o->goblet) return cli_usage_error(cmd, "--mesh FILE.obj (or --goblet) is required");
    if (o->mesh && o->goblet) return cli_usage_error(cmd, "give either --mesh or --goblet");
    if (o->views_out && strcmp(cmd, "render") != 0) return cli_usage_error(cmd, "--views-out belongs to 'matlaber render'");
    if (o->views_out && o->out) return cli_usage_error(cmd, "give either -o/--out or --views-out");
    if (!o->out && !o->views_out) return cli_usage_error(cmd, "-o/--out is required");
    if (o->latent && (o->kd || o->ks || o->kr)) return cli_usage_error(cmd, "give either --latent or --kd/--ks/--kr");
    if (o->goblet && (o->latent || o->kd || o->ks || o->kr)) return cli_usage_error(cmd, "--goblet has its own materials");
    return 0;
}

// The material: explicit values or a decoded latent code.
static int material_from_options(const render_opts* o, const char* cmd, float k[7]) {
    float d[3] = {0.5f, 0.5f, 0.5f}, s[3] = {0.04f, 0.04f, 0.04f}, r = 0.5f;
    if (o->latent) {
        float z[4];
        if (cli_parse_floats(o->latent, z, 4)) return cli_usage_error(cmd, "--latent: expected 4 comma-separated numbers");
        mlb_brdf_ae ae;
        char source[1024];
        mlb_status st = o->model ? mlb_brdf_ae_load(&ae, o->model) : mlb_brdf_ae_load_default(&ae, source, sizeof source);
        if (!st) st = brdf_ae_decode(&ae, z, 1, k);
        if (o->model || !st) brdf_ae_free(&ae);
        return st ? cli_fail(st, "decoding --latent") : 0;
    }
    if (o->kd && cli_parse_floats(o->kd, d, 3)) return cli_usage_error(cmd, "--kd: expected R,G,B");
    if (o->ks && cli_parse_floats(o->ks, s, 3)) return cli_usage_error(cmd, "--ks: expected R,G,B");
    if (o->kr && cli_parse_floats(o->kr, &r, 1)) return cli_usage_error(cmd, "--kr: expected a number");
    float kk[7] = {d[0], d[1], d[2], s[0], s[1], s[2], r};
    if (!mlb_brdf_valid(kk)) return cli_usage_error(cmd, "not a valid BRDF: kd, ks in [0,1], kr in [%g,1]", (double)MLB_KR_MIN);
    memcpy(k, kk, sizeof kk);
    return 0;
}

static int background_from_options(const char* text, const char* cmd, mlb_render_params* p) {
    if (strcmp(text, "env") == 0) { p->background = MLB_BG_ENV; return 0; }
    p->background = MLB_BG_COLOR;
    if (strcmp(text, "black") == 0) { p->bg_color[0] = p->bg_color[1] = p->bg_color[2] = 0; return 0; }
    if (strcmp(text, "white") == 0) { p->bg_color[0] = p->bg_color[1] = p->bg_color[2] = 1; return 0; }
    if (cli_parse_floats(text, p->bg_color, 3)) return cli_usage_error(cmd, "--background: expected env, black, white or R,G,B");
    return 0;
}

// Writes a linear RGBA render: PNG in sRGB (alpha kept when the background is transparent to the
// viewer: we always write RGB), EXR/HDR linear.
static mlb_status write_render(const char* path, const float* rgba, int w, int h) {
    float* rgb = malloc(sizeof(float) * 3 * (size_t)w * h);
    if (!rgb) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path);
    for (size_t i = 0; i < (size_t)w * h; i++) memcpy(rgb + 3 * i, rgba + 4 * i, sizeof(float) * 3);
    size_t n = strlen(path);
    mlb_status st;
    if (n > 4 && (strcmp(path + n - 4, ".exr") == 0 || strcmp(path + n - 4, ".hdr") == 0)) {
        st = strcmp(path + n - 4, ".exr") == 0 ? mlb_image_write_exr(path, rgb, w, h, 3, NULL) : mlb_image_write_hdr(path, rgb, w, h, 3);
    } else {
        mlb_png_options po = {.bits = 8, .encoding = MLB_PNG_SRGB};
        st = mlb_image_write_png(path, rgb, w, h, 3, &po);
    }
    free(rgb);
    return st;
}

typedef struct {
    mlb_mesh mesh;
    mlb_envmap env;
    mlb_envlight light;
    mlb_render_params p;
    float* image;
    float* k;   // per-vertex materials [V, 7] (--goblet), or NULL
} render_setup;

static void setup_free(render_setup* r) {
    mlb_mesh_free(&r->mesh);
    mlb_envmap_free(&r->env);
    mlb_envlight_free(&r->light);
    free(r->image);
    free(r->k);
}

// The mesh of --mesh (normalised unless --keep-scale) or --goblet (with its per-vertex materials).
static int load_mesh(const render_opts* o, mlb_mesh* mesh, float** k) {
    *k = NULL;
    if (o->goblet) {
        mlb_status st = mlb_goblet_mesh(mesh, 96);
        if (st) return cli_fail(st, "building the goblet");
        *k = malloc(sizeof(float) * 7 * (size_t)mesh->n_verts);
        if (!*k) { mlb_mesh_free(mesh); return cli_fail(mlb_fail(MLB_ERR_NOMEM, "out of memory"), "goblet"); }
        mlb_goblet_materials(mesh, *k);
        return 0;
    }
    mlb_status st = mlb_obj_load(o->mesh, mesh);
    if (st) return cli_fail(st, "loading the mesh");
    if (!o->keep_scale) mlb_mesh_normalize_unit_sphere(mesh);
    return 0;
}

static int setup(render_setup* r, const render_opts* o, const char* cmd) {
    memset(r, 0, sizeof *r);
    mlb_render_params* p = &r->p;
    int rc = material_from_options(o, cmd, p->k_const);
    if (!rc) rc = background_from_options(o->background, cmd, p);
    if (rc) return rc;
    if ((rc = load_mesh(o, &r->mesh, &r->k))) return rc;
    p->k = r->k;
    mlb_status st;
    mlb_envmap_info info;
    if ((st = mlb_envmap_open(&r->env, o->env, (float)o->env_scale, 0, &info))) { setup_free(r); return cli_fail(st, "loading the environment"); }
    mlb_log(MLB_LOG_INFO, "pre-integrating the environment '%s' (%ldx%ld cube faces)", r->env.name, o->cube, o->cube);
    mlb_envlight_options lo = {.face_size = (int)o->cube};
    if ((st = mlb_envlight_build(&r->light, &r->env, &lo))) { setup_free(r); return cli_fail(st, "pre-integrating the environment"); }
    p->mesh = &r->mesh;
    p->light = &r->light;
    p->env = &r->env;
    p->width = p->height = (int)o->size;
    p->supersample = (int)o->ss;
    p->fresnel = o->fresnel_schlick ? MLB_FRESNEL_SCHLICK : MLB_FRESNEL_PAPER;
    if ((st = mlb_camera_orbit(&p->camera, o->az, o->el, o->radius, NULL, o->fov, 1.0, 0.05, 100))) {
        setup_free(r);
        return cli_fail(st, "camera");
    }
    r->image = malloc(sizeof(float) * 4 * (size_t)o->size * o->size);
    if (!r->image) { setup_free(r); return cli_fail(mlb_fail(MLB_ERR_NOMEM, "out of memory"), cmd); }
    return 0;
}

static void set_rotation(render_setup* r, double degrees) {
    float rad = (float)(degrees * M_PI / 180.0);
    mlb_envmap_set_rotation(&r->env, rad);
    mlb_envlight_set_rotation(&r->light, rad);
}

static void print_help(const char* usage, const char* text) {
    printf("%s\n\n%s\n\n", usage, text);
    cli_print_options(stdout, render_options);
}

// --views-out DIR: a multi-view data set (views.h) of the mesh under random environments of --env
// (comma-separated), cameras on a golden-angle spiral over the elevation band.
static int render_views(const render_opts* o) {
    enum { MAX_ENVS = 16 };
    char list[4096];
    if (strlen(o->env) >= sizeof list) return cli_usage_error("render", "--env: list too long");
    snprintf(list, sizeof list, "%s", o->env);
    const char* envs[MAX_ENVS];
    int n_envs = 0;
    for (char* save = NULL, *t = strtok_r(list, ",", &save); t; t = strtok_r(NULL, ",", &save)) {
        if (n_envs == MAX_ENVS) return cli_usage_error("render", "--env: at most %d environments", MAX_ENVS);
        envs[n_envs++] = t;
    }
    if (n_envs == 0) return cli_usage_error("render", "--env: expected NAME|FILE[,NAME|FILE...]");
    if (strcmp(o->background, "env") != 0) mlb_log(MLB_LOG_WARN, "--views-out: the background is always transparent black");
    mlb_views_render_config c = mlb_views_render_default();
    int rc = 0;
    if (!o->goblet) rc = material_from_options(o, "render", c.k_const);
    if (rc) return rc;
    mlb_mesh mesh;
    float* k = NULL;
    if ((rc = load_mesh(o, &mesh, &k))) return rc;
    c.mesh = &mesh;
    c.k = k;
    c.n_views = (int)o->views;
    c.res = (int)o->size;
    c.supersample = (int)o->ss;
    c.cube = (int)o->cube;
    c.envs = envs;
    c.n_envs = n_envs;
    c.env_scale = (float)o->env_scale;
    c.radius = o->radius;
    c.fovy_deg = o->fov;
    c.el_min = o->el_min;
    c.el_max = o->el_max;
    c.seed = (uint64_t)o->seed;
    c.fresnel = o->fresnel_schlick ? MLB_FRESNEL_SCHLICK : MLB_FRESNEL_PAPER;
    mlb_progress progress;
    mlb_progress_begin(&progress, mlb_log_get_level() <= MLB_LOG_INFO ? stderr : NULL, "views", c.n_views, "view");
    mlb_status st = mlb_views_render(o->views_out, &c, &progress);
    mlb_mesh_free(&mesh);
    free(k);
    if (st) return cli_fail(st, "render --views-out");
    mlb_progress_end(&progress, NULL);
    mlb_log(MLB_LOG_INFO, "wrote %d views to %s (cameras.json, view_XXX.png, normal_XXX.png)", c.n_views, o->views_out);
    return 0;
}

int cmd_render(int argc, char** argv) {
    render_opts o;
    int rc = parse_render_options(argc, argv, "render", &o);
    if (rc < 0) {
        print_help("usage: matlaber render (--mesh FILE.obj [--kd R,G,B --ks R,G,B --kr X | --latent Z] | --goblet)\n"
                   "                       --env NAME|FILE [--rotate DEG] [--view AZ,EL] [--size N] -o out.png\n"
                   "       matlaber render (--mesh FILE.obj [material] | --goblet) --views-out DIR [--views N] [--res N]\n"
                   "                       [--env NAME|FILE[,NAME|FILE...]] [--elevation MIN,MAX] [--seed S]",
                   "Renders the mesh with one material under an environment light: split-sum GGX shading\n"
                   "(paper §3.4), antialiased, supersampled. PNG output is sRGB; EXR/HDR output is linear.\n"
                   "With --views-out, writes a multi-view data set instead (docs/views.md): DIR/cameras.json,\n"
                   "view_XXX.png (sRGB RGBA, alpha = coverage) and normal_XXX.png, cameras on a golden-angle spiral\n"
                   "over the elevation band at --radius, each view under a random environment of the --env list\n"
                   "with a random rotation.");
        return 0;
    }
    if (rc) return rc;
    if (o.views_out) return render_views(&o);
    render_setup r;
    if ((rc = setup(&r, &o, "render"))) return rc;
    set_rotation(&r, o.rotate);
    mlb_status st = mlb_render_shaded(&r.p, r.image);
    if (!st) st = write_render(o.out, r.image, (int)o.size, (int)o.size);
    setup_free(&r);
    if (st) return cli_fail(st, "render");
    mlb_log(MLB_LOG_INFO, "wrote %s", o.out);
    return 0;
}

int cmd_relight(int argc, char** argv) {
    render_opts o;
    int rc = parse_render_options(argc, argv, "relight", &o);
    if (rc < 0) {
        print_help("usage: matlaber relight --mesh FILE.obj [material options] --env NAME|FILE [--frames N] -o DIR",
                   "Renders the mesh while the environment turns once about the vertical axis: DIR/frame_0000.png ...,\n"
                   "and DIR/relight.mp4 when ffmpeg is installed. The camera stays still; only the light moves.");
        return 0;
    }
    if (rc) return rc;
    mlb_status st = mlb_mkdir_p(o.out);
    if (st) return cli_fail(st, "relight");
    render_setup r;
    if ((rc = setup(&r, &o, "relight"))) return rc;
    mlb_progress progress;
    mlb_progress_begin(&progress, mlb_log_get_level() <= MLB_LOG_INFO ? stderr : NULL, "relight", o.frames, "frame");
    for (long f = 0; f < o.frames && !st; f++) {
        set_rotation(&r, o.rotate + 360.0 * (double)f / (double)o.frames);
        char path[4200];
        snprintf(path, sizeof path, "%s/frame_%04ld.png", o.out, f);
        st = mlb_render_shaded(&r.p, r.image);
        if (!st) st = write_render(path, r.image, (int)o.size, (int)o.size);
        mlb_progress_update(&progress, f + 1, NULL);
    }
    setup_free(&r);
    if (st) return cli_fail(st, "relight");
    mlb_progress_end(&progress, NULL);
    cli_frames_to_mp4(o.out, "relight.mp4");
    return 0;
}

// ---- matlaber brdf swatch -----------------------------------------------------------------------

int brdf_swatch_main(int argc, char** argv) {
    static const cli_option options[] = {
        {"k", 1, 'k', "7 NUMBERS", "a material kd rgb, ks rgb, kr (repeatable, up to 32)"},
        {"from-k", 1, 'a', "7 NUMBERS", "interpolate in latent space from this BRDF ..."},
        {"to-k", 1, 'b', "7 NUMBERS", "... to this one"},
        {"from-z", 1, 'A', "4 NUMBERS", "interpolate from this latent code ..."},
        {"to-z", 1, 'B', "4 NUMBERS", "... to this one"},
        {"steps", 1, 'n', "K", "spheres along an interpolation (default 7)"},
        {"model", 1, 'm', "FILE", "BRDF prior for interpolations (default: the built-in prior)"},
        {"env", 1, 'e', "NAME|FILE", "environment (default studio)"},
        {"rotate", 1, 'R', "DEG", "rotate the environment (default 0)"},
        {"size", 1, 's', "N", "pixels per sphere (default 256)"},
        {"background", 1, 'g', "env|black|white|R,G,B", "behind the spheres (default env)"},
        {"out", 1, 'o', "FILE", "output image (.png sRGB, .exr/.hdr linear)"},
        {"help", 0, 'h', NULL, "this help"},
        {0, 0, 0, 0, 0}};
    enum { MAX_K = 32 };
    float k[MAX_K * 7];
    int n = 0;
    const char *ends[4] = {0}, *model = NULL, *env_name = "studio", *out = NULL, *background = "env";
    long steps = 7, size = 256;
    double rotate = 0;
    const struct option* table = cli_getopt_table(options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "ho:", table, NULL)) != -1) {
        switch (c) {
        case 'k':
            if (n >= MAX_K) return cli_usage_error("brdf swatch", "at most %d --k", MAX_K);
            if (cli_parse_floats(optarg, k + 7 * n, 7) || !mlb_brdf_valid(k + 7 * n))
                return cli_usage_error("brdf swatch", "--k: expected 7 numbers, a valid BRDF (kd, ks in [0,1], kr in [%g,1])", (double)MLB_KR_MIN);
            n++;
            break;
        case 'a': ends[0] = optarg; break;
        case 'b': ends[1] = optarg; break;
        case 'A': ends[2] = optarg; break;
        case 'B': ends[3] = optarg; break;
        case 'n': if (cli_parse_long(optarg, 2, MAX_K, &steps)) return cli_usage_error("brdf swatch", "--steps: expected 2..%d", MAX_K); break;
        case 'm': model = optarg; break;
        case 'e': env_name = optarg; break;
        case 'R': if (cli_parse_double(optarg, -1e6, 1e6, &rotate)) return cli_usage_error("brdf swatch", "--rotate: expected degrees"); break;
        case 's': if (cli_parse_long(optarg, 16, 2048, &size)) return cli_usage_error("brdf swatch", "--size: expected 16..2048"); break;
        case 'g': background = optarg; break;
        case 'o': out = optarg; break;
        case 'h':
            printf("usage: matlaber brdf swatch (--k K [--k K ...] | --from-k K --to-k K | --from-z Z --to-z Z) -o out.png\n\n"
                   "Spheres in a row under one environment: a list of materials, or the decoded BRDFs along a\n"
                   "straight latent path (the paper's material interpolation).\n\n");
            cli_print_options(stdout, options);
            return 0;
        default: return cli_usage_error("brdf swatch", "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error("brdf swatch", "unexpected argument '%s'", argv[optind]);
    if (!out) return cli_usage_error("brdf swatch", "-o/--out is required");
    int interp_k = ends[0] || ends[1], interp_z = ends[2] || ends[3];
    if ((n > 0) + interp_k + interp_z != 1 || (interp_k && !(ends[0] && ends[1])) || (interp_z && !(ends[2] && ends[3])))
        return cli_usage_error("brdf swatch", "give --k materials, or --from-k/--to-k, or --from-z/--to-z");
    mlb_render_params p;
    memset(&p, 0, sizeof p);
    int rc = background_from_options(background, "brdf swatch", &p);
    if (rc) return rc;
    if (interp_k || interp_z) {
        float za[4], zb[4], ka[7], kb[7];
        if (interp_k && (cli_parse_floats(ends[0], ka, 7) || cli_parse_floats(ends[1], kb, 7) || !mlb_brdf_valid(ka) || !mlb_brdf_valid(kb)))
            return cli_usage_error("brdf swatch", "--from-k/--to-k: expected 7 numbers, a valid BRDF each");
        if (interp_z && (cli_parse_floats(ends[2], za, 4) || cli_parse_floats(ends[3], zb, 4)))
            return cli_usage_error("brdf swatch", "--from-z/--to-z: expected 4 numbers each");
        mlb_brdf_ae ae;
        char source[1024];
        mlb_status st = model ? mlb_brdf_ae_load(&ae, model) : mlb_brdf_ae_load_default(&ae, source, sizeof source);
        if (st) return cli_fail(st, "loading the BRDF prior");
        if (interp_k) {   // the codes that decode closest to the end materials
            st = brdf_ae_latent_of(&ae, ka, 1, za, 20);
            if (!st) st = brdf_ae_latent_of(&ae, kb, 1, zb, 20);
        }
        for (int i = 0; i < steps && !st; i++) {
            float a = (float)i / (float)(steps - 1), z[4];
            for (int d = 0; d < 4; d++) z[d] = (1 - a) * za[d] + a * zb[d];
            st = brdf_ae_decode(&ae, z, 1, k + 7 * i);
        }
        brdf_ae_free(&ae);
        if (st) return cli_fail(st, "brdf swatch");
        n = (int)steps;
    }
    mlb_mesh sphere;
    mlb_envmap env = {0};
    mlb_envlight light = {0};
    float* tile = malloc(sizeof(float) * 4 * (size_t)size * size);
    float* row = malloc(sizeof(float) * 4 * (size_t)size * size * n);
    mlb_status st = (!tile || !row) ? mlb_fail(MLB_ERR_NOMEM, "brdf swatch: out of memory") : MLB_OK;
    if (!st) st = mlb_mesh_uv_sphere(&sphere, 1.0f, 96, 48);
    if (!st) st = mlb_envmap_open(&env, env_name, 1.0f, 0, NULL);
    mlb_envlight_options lo = {.face_size = 256};
    if (!st) st = mlb_envlight_build(&light, &env, &lo);
    if (!st) {
        float rad = (float)(rotate * M_PI / 180.0);
        mlb_envmap_set_rotation(&env, rad);
        mlb_envlight_set_rotation(&light, rad);
        p.mesh = &sphere; p.light = &light; p.env = &env;
        p.width = p.height = (int)size; p.supersample = 2; p.fresnel = MLB_FRESNEL_PAPER;
        st = mlb_camera_orbit(&p.camera, 0, 0, 3.2, NULL, 40, 1.0, 0.05, 100);
    }
    for (int i = 0; i < n && !st; i++) {
        memcpy(p.k_const, k + 7 * i, sizeof(float) * 7);
        st = mlb_render_shaded(&p, tile);
        for (long y = 0; y < size && !st; y++)
            memcpy(row + 4 * ((size_t)y * size * n + (size_t)i * size), tile + 4 * (size_t)y * size, sizeof(float) * 4 * size);
    }
    if (!st) st = write_render(out, row, (int)size * n, (int)size);
    mlb_mesh_free(&sphere);
    mlb_envmap_free(&env);
    mlb_envlight_free(&light);
    free(tile); free(row);
    if (st) return cli_fail(st, "brdf swatch");
    for (int i = 0; i < n; i++)
        printf("%d: kd %.4f %.4f %.4f  ks %.4f %.4f %.4f  kr %.4f\n", i, k[7 * i], k[7 * i + 1], k[7 * i + 2], k[7 * i + 3],
               k[7 * i + 4], k[7 * i + 5], k[7 * i + 6]);
    mlb_log(MLB_LOG_INFO, "wrote %s", out);
    return 0;
}
