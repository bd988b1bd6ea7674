// matlaber export | view: a run's final mesh and material field as a textured asset (UV atlas,
// baked kd / ks / roughness maps) written as .glb or OBJ + MTL, or as a static three.js viewer
// folder. docs/export.md.
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cli.h"
#include "matlaber/envmap.h"
#include "matlaber/export.h"
#include "matlaber/fileio.h"
#include "matlaber/run_textured.h"

// RUN_DIR's final/ unwrapped and baked at size x size (run_textured.h), the atlas reported.
static int load_run(const char* run_dir, int size, mlb_run_textured* r) {
    mlb_status s = mlb_run_textured_load(r, run_dir, size);
    if (s != MLB_OK) return cli_fail(s, "reading the run");
    const mlb_uv_stats* st = &r->uv_stats;
    fprintf(stderr, "matlaber: UV atlas: %d charts, %d vertices, %d faces, utilisation %.1f%%, stretch L2 %.3f\n",
            st->n_charts, st->n_verts, st->n_faces, 100 * st->utilisation, st->stretch_l2);
    return 0;
}

static const cli_option export_options[] = {
    {"format", 1, 'f', "glb|obj", "file format (default: from the extension of -o)"},
    {"texture-size", 1, 't', "N", "size of the baked square textures (default 1024)"},
    {"out", 1, 'o', "FILE", "the .glb, or the .obj (beside it: .mtl and the _kd, _ks, _roughness PNGs)"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

int cmd_export(int argc, char** argv) {
    const char *format = NULL, *out = NULL;
    long size = 1024;
    const struct option* table = cli_getopt_table(export_options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "ho:f:", table, NULL)) != -1) {
        switch (c) {
        case 'f': format = optarg; break;
        case 't': if (cli_parse_long(optarg, 8, 16384, &size)) return cli_usage_error("export", "--texture-size: expected 8..16384"); break;
        case 'o': out = optarg; break;
        case 'h':
            printf("usage: matlaber export RUN_DIR [--format glb|obj] [--texture-size N] -o FILE\n\n"
                   "The run's final mesh (RUN_DIR/final/mesh.obj) unwrapped into a UV atlas, its material field\n"
                   "(RUN_DIR/final/material.safetensors) baked into kd and ks (sRGB) and roughness (linear) maps,\n"
                   "written as glTF 2.0 binary (PBR, metallic 0, KHR_materials_specular) or OBJ + MTL with PNG\n"
                   "textures. The mapping is in docs/export.md.\n\n");
            cli_print_options(stdout, export_options);
            return 0;
        default: return cli_usage_error("export", "unknown option");
        }
    }
    if (optind >= argc) return cli_usage_error("export", "RUN_DIR is required");
    if (optind + 1 < argc) return cli_usage_error("export", "unexpected argument '%s'", argv[optind + 1]);
    if (!out) return cli_usage_error("export", "-o FILE is required");
    if (!format) format = mlb_ends_with(out, ".obj") ? "obj" : mlb_ends_with(out, ".glb") ? "glb" : NULL;
    if (!format) return cli_usage_error("export", "-o %s: give --format, or end the name in .glb or .obj", out);
    int glb = strcmp(format, "glb") == 0;
    if (!glb && strcmp(format, "obj") != 0) return cli_usage_error("export", "--format: expected glb or obj");
    if (!glb && !mlb_ends_with(out, ".obj")) return cli_usage_error("export", "-o %s: an OBJ export must end in .obj", out);
    mlb_status s = mlb_check_writable(out);   // before the atlas and the bake, not after them
    if (s) return cli_fail(s, "export");
    mlb_run_textured r;
    int rc = load_run(argv[optind], (int)size, &r);
    if (rc) return rc;
    s = glb ? mlb_run_textured_write_glb(&r, out) : mlb_export_obj(out, &r.asset);
    mlb_run_textured_free(&r);
    if (s != MLB_OK) return cli_fail(s, "export");
    printf("%s\n", out);
    return 0;
}

static mlb_status write_run_glb(const char* path, const void* ctx) { return mlb_run_textured_write_glb(ctx, path); }

static const cli_option view_options[] = {
    {"texture-size", 1, 't', "N", "size of the baked textures (default 1024)"},
    {"env", 1, 'e', "A,B,...", "built-in environments offered, the first shown (default sky,studio,overcast)"},
    {"env-height", 1, 'H', "N", "rows of the written environment maps (default 256)"},
    {"viewer-dir", 1, 'V', "DIR", "the viewer source folder with node_modules/three (default: searched, docs/export.md)"},
    {"out", 1, 'o', "DIR", "the folder to write (created)"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

int cmd_view(int argc, char** argv) {
    const char *out = NULL, *envs_text = NULL, *viewer_dir = NULL;
    long size = 1024, env_height = 256;
    const struct option* table = cli_getopt_table(view_options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "ho:", table, NULL)) != -1) {
        switch (c) {
        case 't': if (cli_parse_long(optarg, 8, 16384, &size)) return cli_usage_error("view", "--texture-size: expected 8..16384"); break;
        case 'e': envs_text = optarg; break;
        case 'H': if (cli_parse_long(optarg, 8, 4096, &env_height)) return cli_usage_error("view", "--env-height: expected 8..4096"); break;
        case 'V': viewer_dir = optarg; break;
        case 'o': out = optarg; break;
        case 'h':
            printf("usage: matlaber view (RUN_DIR | FILE.glb) -o DIR [options]\n\n"
                   "A self-contained static web page showing the asset under a choice of environments, with a\n"
                   "slider that turns the light and views of the kd / ks / roughness maps. three.js is copied\n"
                   "beside the page; nothing is loaded from the network. Browsers do not run it from file://:\n"
                   "serve it with   python3 -m http.server -d DIR 8000   and open http://localhost:8000/.\n\n");
            cli_print_options(stdout, view_options);
            return 0;
        default: return cli_usage_error("view", "unknown option");
        }
    }
    if (optind >= argc) return cli_usage_error("view", "RUN_DIR or FILE.glb is required");
    if (optind + 1 < argc) return cli_usage_error("view", "unexpected argument '%s'", argv[optind + 1]);
    if (!out) return cli_usage_error("view", "-o DIR is required");
    // --env a,b,c -> a NULL-terminated list (at most 16 names)
    char env_buf[1024];
    const char* envs[17] = {0};
    if (envs_text) {
        if (strlen(envs_text) >= sizeof env_buf) return cli_usage_error("view", "--env: too long");
        strcpy(env_buf, envs_text);
        int n = 0;
        for (char* tok = strtok(env_buf, ","); tok; tok = strtok(NULL, ",")) {
            if (n == 16) return cli_usage_error("view", "--env: at most 16 environments");
            if (!mlb_envmap_is_builtin(tok)) return cli_usage_error("view", "--env: '%s' is not one of %s", tok, mlb_envmap_builtin_list());
            envs[n++] = tok;
        }
        if (n == 0) return cli_usage_error("view", "--env: no names");
    }
    const char* in = argv[optind];
    char title[256];   // the run folder's or the file's name
    size_t len = strlen(in);
    while (len > 1 && in[len - 1] == '/') len--;
    size_t start = len;
    while (start > 0 && in[start - 1] != '/') start--;
    snprintf(title, sizeof title, "matlaber: %.*s", (int)(len - start), in + start);
    mlb_viewer_options opt = {viewer_dir, envs_text ? envs : NULL, (int)env_height, title};
    mlb_status s;
    if (mlb_is_file(in)) {
        s = mlb_viewer_write(out, in, &opt);
    } else {
        mlb_run_textured r;
        int rc = load_run(in, (int)size, &r);
        if (rc) return rc;
        s = mlb_viewer_write_with(out, &opt, write_run_glb, &r);   // with the latent editor's files
        mlb_run_textured_free(&r);
    }
    if (s != MLB_OK) return cli_fail(s, "view");
    printf("%s\nserve it:  python3 -m http.server -d %s 8000   then open http://localhost:8000/\n", out, out);
    return 0;
}
