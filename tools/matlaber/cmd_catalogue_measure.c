// matlaber catalogue measure: one mesh or run folder against a catalogue class's truth, as `bench
// text3d` measures an asset (include/matlaber/text3d.h): the nearest class by Chamfer, the surface
// (normal error, completeness, accuracy, thin parts) against the class's fitted member and, for a
// run folder, its material.
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cli.h"
#include "matlaber/catalogue.h"
#include "matlaber/fileio.h"
#include "matlaber/obj.h"
#include "matlaber/run.h"
#include "matlaber/text3d.h"

static void print_scores(const char* what, const mlb_text3d_scores* sc, int with_material) {
    int c = sc->cls;
    printf("%s as a %s: nearest class %s (Chamfer %.4f), Chamfer to the %s %.4f\n", what, mlb_catalogue_class_name(c),
           mlb_catalogue_class_name(sc->nearest), sc->chamfer[sc->nearest], mlb_catalogue_class_name(c), sc->chamfer_prompted);
    printf("surface: normal error %.1f deg, completeness %.4f, accuracy %.4f (of the diagonal)", sc->normal_deg,
           sc->completeness, sc->accuracy);
    for (int k = 0; k < mlb_catalogue_class_n_parts(c); k++)
        printf("%s%s %.4f%s", k ? ", " : "; ", mlb_catalogue_part_name(c, k + 1), sc->part_completeness[k],
               sc->part_completeness[k] <= MLB_TEXT3D_PART_PRESENT ? "" : " (missing)");
    printf("\n");
    if (with_material)
        printf("material: RMSE %.3f against %s, %s, colour reads as %s; relit %.2f dB\n", sc->material_rmse,
               mlb_catalogue_material_name(sc->mat), sc->metal_pred ? "metal" : "dielectric",
               sc->colour_pred >= 0 ? mlb_catalogue_material_name(sc->colour_pred) : "-", sc->relight_psnr);
}

int catalogue_measure(int argc, char** argv) {
    const char* cmd = "catalogue measure";
    const char *path = NULL, *cls_name = NULL, *mat_name = NULL;
    mlb_text3d_measure_config mc = mlb_text3d_measure_default();
    for (int i = 1; i < argc; i++) {
        long v;
        if ((!strcmp(argv[i], "--class") || !strcmp(argv[i], "--material")) && i + 1 < argc) {
            if (argv[i][2] == 'c') cls_name = argv[++i];
            else mat_name = argv[++i];
        } else if (!strcmp(argv[i], "--shape-fit") && i + 1 < argc) {
            if (cli_parse_long(argv[++i], 0, 1000, &v)) return cli_usage_error(cmd, "--shape-fit: expected 0..1000");
            mc.fit_rounds = (int)v;
        } else if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            printf("usage: matlaber catalogue measure MESH.obj|RUN_DIR --class C [--material M] [--shape-fit N]\n\n"
                   "Measures a mesh (or a run folder's final asset) against class C of the catalogue as `bench text3d`\n"
                   "measures an asset: the Chamfer distance to every class's best-fitting member (the nearest\n"
                   "class), and against C's: the mean angle between face normals, completeness and accuracy (95th\n"
                   "percentiles of the distances truth -> mesh and mesh -> truth, relative to the diagonal) and the\n"
                   "completeness of C's thin parts. A run folder's material is measured against M's (default: the\n"
                   "material its prompt names when it is a catalogue caption). The mesh is taken in the generation\n"
                   "frame (+y up, front +z, radius 0.9), as the catalogue's own meshes are. --shape-fit: rounds of the\n"
                   "fit of each near class's shape parameters from the best of 8 seeds (default 64; 0: the seeds alone).\n");
            return 0;
        } else if (argv[i][0] == '-') return cli_usage_error(cmd, "unknown option '%s'", argv[i]);
        else if (!path) path = argv[i];
        else return cli_usage_error(cmd, "unexpected argument '%s'", argv[i]);
    }
    if (!path) return cli_usage_error(cmd, "a mesh or run folder is required");
    if (!cls_name) return cli_usage_error(cmd, "--class is required (%s)", mlb_catalogue_class_list());
    int cls, mat = -1;
    if (mlb_catalogue_class_parse(cls_name, &cls)) return cli_usage_error(cmd, "--class: %s", mlb_last_error());
    if (mat_name && mlb_catalogue_material_parse(mat_name, &mat)) return cli_usage_error(cmd, "--material: %s", mlb_last_error());
    const int run = mlb_is_dir(path);
    mlb_mesh mesh = {0};
    mlb_run_asset a;
    memset(&a, 0, sizeof a);
    float* k = NULL;
    mlb_status s = run ? mlb_run_asset_load(&a, path) : mlb_obj_load(path, &mesh);
    const mlb_mesh* m = run ? &a.mesh : &mesh;
    if (!s && run && mat < 0)   // the material of a catalogue caption
        for (int j = 0; j < mlb_catalogue_n_materials(); j++)
            if (strstr(a.config.prompt, mlb_catalogue_material_name(j))) mat = j;
    int with_material = run && mat >= 0;
    if (mat < 0) mat = 0;   // (not reported: the mesh alone carries no material)
    if (!s && !(k = malloc(sizeof(float) * 7 * (size_t)m->n_verts))) s = mlb_fail(MLB_ERR_NOMEM, "out of memory");
    if (!s && run) s = mlb_run_asset_vertex_brdf(&a, k);
    for (int i = 0; !s && !run && i < m->n_verts; i++) memcpy(k + 7 * (size_t)i, mlb_catalogue_material_brdf(mat), sizeof(float) * 7);
    mlb_text3d_truth truth;
    mlb_envmap env = {0};
    mlb_envlight light = {0};
    mlb_envlight_options lo;
    memset(&lo, 0, sizeof lo);
    lo.face_size = 64;
    mlb_text3d_scores sc;
    if (!s) s = mlb_text3d_truth_create(&truth, 8);
    if (!s) s = mlb_envmap_open(&env, "white", 1.0f, 128, NULL);
    if (!s) s = mlb_envlight_build(&light, &env, &lo);
    if (!s) s = mlb_text3d_measure(&truth, m, k, cls, mat, &light, &mc, &sc);
    if (!s) print_scores(path, &sc, with_material);
    mlb_envlight_free(&light);
    mlb_envmap_free(&env);
    mlb_text3d_truth_free(&truth);
    free(k);
    mlb_mesh_free(&mesh);
    mlb_run_asset_free(&a);
    return s ? cli_fail(s, path) : 0;
}
