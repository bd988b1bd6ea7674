// matlaber catalogue list | export | render | measure: the procedural catalogue of objects and
// materials (include/matlaber/catalogue.h, docs/catalogue.md), for people to look at; measure is in
// cmd_catalogue_measure.c.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cli.h"
#include "matlaber/cameras.h"
#include "matlaber/catalogue.h"
#include "matlaber/export.h"
#include "matlaber/fileio.h"
#include "matlaber/sds.h"
#include "matlaber/uv_atlas.h"
#include "matlaber/views.h"

static int catalogue_list(int argc, char** argv) {
    int json = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--json")) json = 1;
        else if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            printf("usage: matlaber catalogue list [--json]\n\n"
                   "The classes (with their symmetry: 1 = a surface of revolution about +y), the materials (7-d\n"
                   "BRDF kd rgb, ks rgb, kr, linear; metal flag) and the held-out class x material pairs.\n");
            return 0;
        } else return cli_usage_error("catalogue list", "unexpected argument '%s'", argv[i]);
    }
    int nc = mlb_catalogue_n_classes(), nm = mlb_catalogue_n_materials();
    if (json) {
        printf("{\n  \"classes\": [");
        for (int c = 0; c < nc; c++)
            printf("%s\n    {\"name\": \"%s\", \"symmetric\": %s}", c ? "," : "", mlb_catalogue_class_name(c),
                   mlb_catalogue_class_symmetric(c) ? "true" : "false");
        printf("\n  ],\n  \"materials\": [");
        for (int m = 0; m < nm; m++) {
            const float* k = mlb_catalogue_material_brdf(m);
            printf("%s\n    {\"name\": \"%s\", \"brdf\": [", m ? "," : "", mlb_catalogue_material_name(m));
            for (int i = 0; i < 7; i++) printf("%s%.4g", i ? ", " : "", (double)k[i]);
            printf("], \"metal\": %s}", mlb_catalogue_material_metal(m) ? "true" : "false");
        }
        printf("\n  ],\n  \"held_out\": [");
        int n = 0;
        for (int c = 0; c < nc; c++)
            for (int m = 0; m < nm; m++)
                if (mlb_catalogue_held_out(c, m))
                    printf("%s\n    {\"class\": \"%s\", \"material\": \"%s\"}", n++ ? "," : "", mlb_catalogue_class_name(c),
                           mlb_catalogue_material_name(m));
        printf("\n  ]\n}\n");
        return 0;
    }
    printf("classes (%d):\n", nc);
    for (int c = 0; c < nc; c++)
        printf("  %-10s %s\n", mlb_catalogue_class_name(c), mlb_catalogue_class_symmetric(c) ? "symmetric" : "not symmetric");
    printf("materials (%d): kd rgb, ks rgb, kr (linear)\n", nm);
    for (int m = 0; m < nm; m++) {
        const float* k = mlb_catalogue_material_brdf(m);
        printf("  %-8s %-10s", mlb_catalogue_material_name(m), mlb_catalogue_material_metal(m) ? "metal" : "dielectric");
        for (int i = 0; i < 7; i++) printf(" %.3f", (double)k[i]);
        printf("\n");
    }
    printf("held out (%d):\n", mlb_catalogue_n_held_out());
    for (int c = 0; c < nc; c++)
        for (int m = 0; m < nm; m++)
            if (mlb_catalogue_held_out(c, m)) {
                char cap[96];
                mlb_catalogue_caption(c, m, MLB_SDS_VIEW_NONE, cap, sizeof cap);
                printf("  %s\n", cap);
            }
    return 0;
}

static mlb_status write_obj(const char* path, const mlb_mesh* m, const char* what) {
    mlb_atomic_file af;
    MLB_TRY(mlb_atomic_open(&af, path));
    fprintf(af.f, "# matlaber catalogue: %s, %d vertices, %d faces (+y up, front +z, unit sphere)\n", what, m->n_verts, m->n_faces);
    for (int i = 0; i < m->n_verts; i++) fprintf(af.f, "v %.7g %.7g %.7g\n", m->pos[3 * i], m->pos[3 * i + 1], m->pos[3 * i + 2]);
    for (int i = 0; i < m->n_verts; i++)
        fprintf(af.f, "vn %.6g %.6g %.6g\n", m->normal[3 * i], m->normal[3 * i + 1], m->normal[3 * i + 2]);
    for (int f = 0; f < m->n_faces; f++) {
        const int32_t* t = m->faces + 3 * f;
        fprintf(af.f, "f %d//%d %d//%d %d//%d\n", t[0] + 1, t[0] + 1, t[1] + 1, t[1] + 1, t[2] + 1, t[2] + 1);
    }
    return mlb_atomic_commit(&af);
}

static const cli_option export_options[] = {
    {"class", 1, 'c', "NAME", "object class ('matlaber catalogue list')"},
    {"seed", 1, 's', "S", "shape seed (default 0: the canonical shape)"},
    {"material", 1, 'm', "NAME", "with the material: a textured asset (UV atlas, constant kd / ks / roughness\n"
                                 "                           maps) as .glb, or .obj + .mtl + PNGs, as `matlaber export` writes a run"},
    {"out", 1, 'o', "FILE", "output: .obj (without --material: positions, normals, faces), or .glb with --material"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

// The truth as a textured asset, for viewers and Blender to show next to a generated one: the mesh
// unwrapped (the writers need uvs) and the material's constant BRDF in every texel. 256² because the
// atlas's gutter is measured at the texture size; constant maps compress to a few hundred bytes.
static mlb_status write_asset(const char* path, const mlb_mesh* m, int mat, const char* name) {
    enum { S = 256 };
    const float* k = mlb_catalogue_material_brdf(mat);
    mlb_uv_options opt = mlb_uv_default();
    opt.texture_size = S;
    mlb_uv_mesh uv;
    MLB_TRY(mlb_uv_unwrap(m, &opt, &uv, NULL));
    float *kd = malloc(sizeof(float) * 3 * S * S), *ks = malloc(sizeof(float) * 3 * S * S), *kr = malloc(sizeof(float) * S * S);
    mlb_status s = MLB_OK;
    if (!kd || !ks || !kr) s = mlb_fail(MLB_ERR_NOMEM, "out of memory for %d² maps", S);
    else {
        for (int i = 0; i < S * S; i++) {
            for (int c = 0; c < 3; c++) { kd[3 * i + c] = k[c]; ks[3 * i + c] = k[3 + c]; }
            kr[i] = k[6];
        }
        mlb_asset a = {uv.mesh.n_verts, uv.mesh.n_faces, uv.mesh.pos, uv.mesh.normal, uv.mesh.uv, uv.mesh.faces, S, kd, ks, kr, name};
        s = mlb_ends_with(path, ".glb") ? mlb_export_glb(path, &a) : mlb_export_obj(path, &a);
    }
    free(kd);
    free(ks);
    free(kr);
    mlb_uv_mesh_free(&uv);
    return s;
}

static int catalogue_export(int argc, char** argv) {
    const char *cls_name = NULL, *mat_name = NULL, *out = NULL;
    long seed = 0;
    const struct option* table = cli_getopt_table(export_options);
    optind = 1;
    int ch;
    while ((ch = getopt_long(argc, argv, "ho:", table, NULL)) != -1) {
        switch (ch) {
        case 'c': cls_name = optarg; break;
        case 's': if (cli_parse_long(optarg, 0, 0x7fffffffffffffffL, &seed)) return cli_usage_error("catalogue export", "--seed: expected a non-negative integer"); break;
        case 'm': mat_name = optarg; break;
        case 'o': out = optarg; break;
        case 'h':
            printf("usage: matlaber catalogue export --class NAME [--seed S] [--material NAME] -o FILE.obj|FILE.glb\n\n"
                   "The class's mesh for a shape seed, in the generation frame (+y up, centred, farthest vertex at\n"
                   "0.9, front towards +z: the azimuth-0 camera). With --material, the truth of a caption as an\n"
                   "asset (\"a gold goblet\": --class goblet --material gold -o goblet_gold.glb), mapped to glTF as\n"
                   "docs/export.md says.\n\n");
            cli_print_options(stdout, export_options);
            return 0;
        default: return cli_usage_error("catalogue export", "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error("catalogue export", "unexpected argument '%s'", argv[optind]);
    if (!cls_name) return cli_usage_error("catalogue export", "--class NAME is required (%s)", mlb_catalogue_class_list());
    if (!out) return cli_usage_error("catalogue export", "-o FILE.obj (or FILE.glb with --material) is required");
    int glb = mlb_ends_with(out, ".glb");
    if (glb && !mat_name) return cli_usage_error("catalogue export", "a .glb needs --material NAME (%s)", mlb_catalogue_material_list());
    int c, mat = -1;
    mlb_status s = mlb_catalogue_class_parse(cls_name, &c);
    if (s) return cli_fail(s, "--class");
    if (mat_name && (s = mlb_catalogue_material_parse(mat_name, &mat)) != MLB_OK) return cli_fail(s, "--material");
    mlb_mesh m;
    s = mlb_catalogue_mesh(c, (uint64_t)seed, &m);
    char what[64];
    if (mat >= 0) snprintf(what, sizeof what, "%s %s seed %ld", mat_name, cls_name, seed);
    else snprintf(what, sizeof what, "%s seed %ld", cls_name, seed);
    if (!s && mat >= 0) {
        char name[64];
        snprintf(name, sizeof name, "%s_%s", cls_name, mat_name);
        s = write_asset(out, &m, mat, name);
    } else if (!s) s = write_obj(out, &m, what);
    if (!s) printf("wrote %s: %s, %d vertices, %d faces\n", out, what, m.n_verts, m.n_faces);
    mlb_mesh_free(&m);
    return s ? cli_fail(s, out) : 0;
}

static const cli_option render_options[] = {
    {"class", 1, 'c', "NAME", "object class"},
    {"material", 1, 'm', "NAME", "material"},
    {"seed", 1, 's', "S", "shape seed (default 0: canonical); with --orbit also the cameras' seed"},
    {"views", 1, 'n', "N", "number of views (default 8): azimuths 360 i / N from the front, elevation 15"},
    {"orbit", 0, 'O', NULL, "views from the pipeline's random orbit instead (any azimuth, env, rotation)"},
    {"res", 1, 'r', "R", "image size (default 128)"},
    {"supersample", 1, 'S', "N", "render at R x N and box-filter (default 1, the pipeline's)"},
    {"env", 1, 'e', "NAME", "environment of the fixed views: sky, studio or overcast (default sky)"},
    {"out", 1, 'o', "DIR", "output folder: rgb_XXX.png, normal_XXX.png, captions.json"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

static int catalogue_render(int argc, char** argv) {
    const char *cls_name = NULL, *mat_name = NULL, *out = NULL, *env = "sky";
    long seed = 0, views = 8, res = 128, ss = 1;
    int orbit = 0;
    const struct option* table = cli_getopt_table(render_options);
    optind = 1;
    int ch;
    while ((ch = getopt_long(argc, argv, "ho:", table, NULL)) != -1) {
        switch (ch) {
        case 'c': cls_name = optarg; break;
        case 'm': mat_name = optarg; break;
        case 's': if (cli_parse_long(optarg, 0, 0x7fffffffffffffffL, &seed)) return cli_usage_error("catalogue render", "--seed: expected a non-negative integer"); break;
        case 'n': if (cli_parse_long(optarg, 1, 1000, &views)) return cli_usage_error("catalogue render", "--views: expected 1..1000"); break;
        case 'O': orbit = 1; break;
        case 'r': if (cli_parse_long(optarg, 8, 2048, &res)) return cli_usage_error("catalogue render", "--res: expected 8..2048"); break;
        case 'S': if (cli_parse_long(optarg, 1, 4, &ss)) return cli_usage_error("catalogue render", "--supersample: expected 1..4"); break;
        case 'e': env = optarg; break;
        case 'o': out = optarg; break;
        case 'h':
            printf("usage: matlaber catalogue render --class NAME --material NAME [--seed S] [--views N] [--res R] -o DIR\n\n"
                   "Renders the catalogue's images as the pipeline's stages see them: rgb_XXX.png (the appearance\n"
                   "stage's sRGB colour over black, alpha = coverage), normal_XXX.png (the geometry stage's world-space\n"
                   "normals, rgb = (n + 1) / 2, 16-bit), and captions.json (caption with the view suffix, camera).\n\n");
            cli_print_options(stdout, render_options);
            return 0;
        default: return cli_usage_error("catalogue render", "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error("catalogue render", "unexpected argument '%s'", argv[optind]);
    if (!cls_name) return cli_usage_error("catalogue render", "--class NAME is required (%s)", mlb_catalogue_class_list());
    if (!mat_name) return cli_usage_error("catalogue render", "--material NAME is required (%s)", mlb_catalogue_material_list());
    if (!out) return cli_usage_error("catalogue render", "-o DIR is required");
    mlb_catalogue_render_config rc = mlb_catalogue_render_default();
    int env_index = -1;
    for (int i = 0; i < rc.n_envs; i++)
        if (!strcmp(env, rc.envs[i])) env_index = i;
    if (env_index < 0) return cli_usage_error("catalogue render", "--env: '%s' is not sky, studio or overcast", env);
    mlb_catalogue_sample smp;
    memset(&smp, 0, sizeof smp);
    mlb_status s = mlb_catalogue_class_parse(cls_name, &smp.cls);
    if (s) return cli_fail(s, "--class");
    s = mlb_catalogue_material_parse(mat_name, &smp.mat);
    if (s) return cli_fail(s, "--material");
    smp.shape_seed = (uint64_t)seed;
    rc.res = (int)res;
    rc.supersample = (int)ss;
    mlb_catalogue_renderer* r = NULL;
    s = mlb_mkdir_p(out);
    if (!s) s = mlb_catalogue_renderer_create(&r, &rc);
    if (s) return cli_fail(s, out);
    size_t P = (size_t)res * res;
    float* rgb = malloc(sizeof(float) * 3 * P);
    float* nrm = malloc(sizeof(float) * 4 * P);
    float* rgba = malloc(sizeof(float) * 4 * P);
    char* json = malloc((size_t)views * 512 + 256);
    if (!rgb || !nrm || !rgba || !json) s = mlb_fail(MLB_ERR_NOMEM, "out of memory");
    size_t used = 0;
    if (!s) used += (size_t)sprintf(json, "{\n  \"class\": \"%s\", \"material\": \"%s\", \"shape_seed\": %ld, \"res\": %ld,\n  \"views\": [",
                                    cls_name, mat_name, seed, res);
    mlb_orbit_config oc = mlb_orbit_default();
    oc.n_envs = rc.n_envs;
    for (long i = 0; !s && i < views; i++) {
        if (orbit) s = mlb_orbit_sample(&smp.view, &oc, (uint64_t)seed, MLB_STAGE_APPEARANCE, i, 0);
        else {
            double az = fmod(360.0 * (double)i / (double)views + 180.0, 360.0) - 180.0;
            memset(&smp.view, 0, sizeof smp.view);
            s = mlb_camera_orbit(&smp.view.cam, az, 15, MLB_ORBIT_RADIUS, NULL, 35, 1, oc.near_z, oc.far_z);
            smp.view.azimuth_deg = az, smp.view.elevation_deg = 15, smp.view.radius = MLB_ORBIT_RADIUS;
            smp.view.env = env_index, smp.view.target = -1;
        }
        if (!s) s = mlb_catalogue_render(r, &smp, rgb, nrm);
        if (s) break;
        for (size_t p = 0; p < P; p++) {   // [3, R, R] → [R, R, 4] with the coverage as alpha
            for (int c = 0; c < 3; c++) rgba[4 * p + c] = rgb[c * P + p];
            rgba[4 * p + 3] = nrm[4 * p + 3];
        }
        char path[4096], cap[128];
        snprintf(path, sizeof path, "%s/rgb_%03ld.png", out, i);
        s = mlb_views_write_color_png(path, rgba, (int)res, (int)res);
        snprintf(path, sizeof path, "%s/normal_%03ld.png", out, i);
        if (!s) s = mlb_views_write_normal_png(path, nrm, (int)res, (int)res);
        mlb_catalogue_sample_caption(&smp, cap, sizeof cap);
        used += (size_t)sprintf(json + used,
                                "%s\n    {\"rgb\": \"rgb_%03ld.png\", \"normal\": \"normal_%03ld.png\", \"caption\": \"%s\", "
                                "\"azimuth_deg\": %.3f, \"elevation_deg\": %.3f, \"fovy_deg\": %.3f, \"env\": \"%s\", \"env_rotation_deg\": %.3f}",
                                i ? "," : "", i, i, cap, smp.view.azimuth_deg, smp.view.elevation_deg, smp.view.cam.fovy_deg,
                                rc.envs[smp.view.env], (double)smp.view.env_rotation_deg);
    }
    if (!s) {
        sprintf(json + used, "\n  ]\n}\n");
        char path[4096];
        snprintf(path, sizeof path, "%s/captions.json", out);
        mlb_atomic_file af;
        s = mlb_atomic_open(&af, path);
        if (!s) {
            fputs(json, af.f);
            s = mlb_atomic_commit(&af);
        }
    }
    if (!s) printf("wrote %ld views of %s to %s\n", views, cls_name, out);
    free(rgb); free(nrm); free(rgba); free(json);
    mlb_catalogue_renderer_free(r);
    return s ? cli_fail(s, out) : 0;
}

int cmd_catalogue(int argc, char** argv) {
    if (argc < 2 || strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0) {
        FILE* o = argc < 2 ? stderr : stdout;
        fprintf(o, "usage: matlaber catalogue list|export|render [options]  ('matlaber catalogue <sub> --help')\n"
                   "  list      classes, materials (7-d BRDF) and the held-out pairs (--json)\n"
                   "  export    a class's mesh for a shape seed as an OBJ; with a material as .glb or OBJ + MTL\n"
                   "  render    rgb and normal images with captions, as the pipeline's stages see them\n"
                   "  measure   a mesh or run folder against a class's truth, as bench text3d measures an asset\n");
        return argc < 2 ? EXIT_USAGE : 0;
    }
    if (strcmp(argv[1], "list") == 0) return catalogue_list(argc - 1, argv + 1);
    if (strcmp(argv[1], "export") == 0) return catalogue_export(argc - 1, argv + 1);
    if (strcmp(argv[1], "render") == 0) return catalogue_render(argc - 1, argv + 1);
    if (strcmp(argv[1], "measure") == 0) return catalogue_measure(argc - 1, argv + 1);
    return cli_usage_error("catalogue", "unknown subcommand '%s' (list, export, render, measure)", argv[1]);
}
