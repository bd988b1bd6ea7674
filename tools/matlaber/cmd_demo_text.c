// matlaber demo (the default): text to 3D with the project's own model and nothing downloaded. One
// catalogue caption ("a gold goblet") is generated with --preset tiny, then measured against the
// catalogue's truth as `bench text3d` measures it (text3d.h): nearest class by Chamfer, the median
// BRDF against the material's, relighting PSNR under a light the run never saw; the truth and the
// result are rendered side by side under that light. `matlaber demo --fit` is the image-fitting demo.
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cli.h"
#include "matlaber/catalogue.h"
#include "matlaber/evaluate.h"
#include "matlaber/fileio.h"
#include "matlaber/log.h"
#include "matlaber/plot.h"
#include "matlaber/text3d.h"

#define DEMO_VIEWS 4
#define DEMO_RES 192

// The truth (the class's best-fitting member in the true material) and the asset under `light`, four
// views each: DIR/compare.png (top row the truth, bottom row the result).
static mlb_status side_by_side(const char* out, const mlb_text3d_row* row, const mlb_envlight* light, double* psnr) {
    const mlb_text3d_scores* sc = &row->scores;
    mlb_mesh truth = {0};
    mlb_run_asset a;
    memset(&a, 0, sizeof a);
    float *tk = NULL, *img = NULL;
    mlb_status s = mlb_catalogue_mesh_params(sc->cls, sc->shape_u[sc->cls], &truth);
    if (!s) s = mlb_run_asset_load(&a, row->run_dir);
    if (!s) {
        tk = malloc(sizeof(float) * 7 * (size_t)truth.n_verts);
        img = malloc(sizeof(float) * 3 * 2 * DEMO_VIEWS * DEMO_RES * DEMO_RES);
        if (!tk || !img) s = mlb_fail(MLB_ERR_NOMEM, "demo: out of memory");
    }
    for (int i = 0; !s && i < truth.n_verts; i++) memcpy(tk + 7 * (size_t)i, mlb_catalogue_material_brdf(sc->mat), 7 * sizeof(float));
    if (!s) s = mlb_eval_relight(&truth, tk, &a.mesh, NULL, mlb_run_asset_material, &a, light, DEMO_VIEWS, 30.0, DEMO_RES, psnr, img);
    char path[4200];
    snprintf(path, sizeof path, "%s/compare.png", out);
    static const char* const labels[2 * DEMO_VIEWS] = {"truth", "", "", "", "generated", "", "", ""};
    if (!s) s = mlb_image_grid_write(path, img, 2 * DEMO_VIEWS, DEMO_RES, DEMO_RES, 3, DEMO_VIEWS, labels);
    free(tk);
    free(img);
    mlb_run_asset_free(&a);
    mlb_mesh_free(&truth);
    return s;
}

static mlb_status write_report(const char* out, const mlb_text3d_row* r, double seconds, double psnr_pictured) {
    const mlb_text3d_scores* sc = &r->scores;
    const float* t = mlb_catalogue_material_brdf(sc->mat);
    char path[4200], text[4096];
    snprintf(path, sizeof path, "%s/report.md", out);
    snprintf(text, sizeof text,
             "# matlaber demo: text to 3D with the project's own model\n\n"
             "Prompt: \"%s\" (%s pair of the catalogue), `--preset tiny`, generated in %.0f s; the run: `%s`\n"
             "(export it: `matlaber export %s --format glb -o asset.glb`).\n\n"
             "| measure | value |\n|---|---|\n"
             "| nearest catalogue class (Chamfer / diagonal to the best of 8 shapes) | %s (%.4f; to %s %.4f) |\n"
             "| material: median kd / ks / roughness | %.2f %.2f %.2f / %.2f %.2f %.2f / %.2f |\n"
             "| material truth (%s) | %.2f %.2f %.2f / %.2f %.2f %.2f / %.2f |\n"
             "| material RMSE over the 7 numbers | %.3f |\n"
             "| metal vs dielectric | %s (%s) |\n"
             "| relighting PSNR under the white environment (never seen by the run) | %.2f dB |\n\n"
             "`compare.png`: the truth (top: the class's nearest shape in the true material) and the result\n"
             "(bottom) under that light (%.2f dB over these %d views at %d²). Numbers as `matlaber bench text3d`\n"
             "computes them (docs/benchmarks.md).\n",
             r->prompt, sc->held_out ? "a held-out" : "a training", r->seconds, r->run_dir, r->run_dir,
             mlb_catalogue_class_name(sc->nearest), sc->chamfer[sc->nearest], mlb_catalogue_class_name(sc->cls),
             sc->chamfer_prompted, sc->median_k[0], sc->median_k[1], sc->median_k[2], sc->median_k[3], sc->median_k[4],
             sc->median_k[5], sc->median_k[6], mlb_catalogue_material_name(sc->mat), t[0], t[1], t[2], t[3], t[4], t[5],
             t[6], sc->material_rmse, sc->metal_pred ? "metal" : "dielectric", sc->metal_ok ? "right" : "wrong",
             sc->relight_psnr, psnr_pictured, DEMO_VIEWS, DEMO_RES);
    (void)seconds;
    return mlb_write_file_atomic(path, text, strlen(text));
}

int demo_text_main(const char* out, uint64_t seed, int quick, const char* cls_name, const char* mat_name) {
    const char* model = cli_default_model();
    if (!model)
        return cli_usage_error("demo", "the project's own model is not there (models/%s, $MATLABER_MODEL): train it "
                                       "(matlaber sd train; docs/sd_train.md) or run the image-fitting demo (demo --fit)",
                               MLB_DEFAULT_MODEL);
    double t0 = mlb_now_seconds();
    mlb_text3d_bench_config bc = mlb_text3d_bench_default();
    int cls = -1, mat = -1;
    mlb_status s = mlb_catalogue_class_parse(cls_name, &cls);
    if (!s) s = mlb_catalogue_material_parse(mat_name, &mat);
    if (!s) s = mlb_text3d_base_config(&bc.base, "tiny", model, seed, quick ? 0.25 : 1.0, MLB_MATERIAL_LATENT, 0, 1);
    if (s) return cli_fail(s, "demo");
    const char* appearance_model = cli_default_appearance_model();
    if (appearance_model) snprintf(bc.base.appearance_model, sizeof bc.base.appearance_model, "%s", appearance_model);
    bc.out_dir = out;
    bc.classes[0] = cls;
    bc.n_classes = 1;
    bc.materials[0] = mat;
    bc.n_materials = 1;
    bc.progress = 1;
    bc.be = cli_run_backend(bc.base.precision);   // --device, and the tiny preset's precision as generate takes it
    mlb_text3d_row row;
    int n = 0;
    mlb_text3d_summary sum;
    s = mlb_mkdir_p(out);
    if (!s) s = mlb_text3d_bench_run(&bc, &row, &n, &sum);
    if (!s && n != 1) s = mlb_fail(MLB_ERR_ARG, "demo: %d runs instead of one", n);
    if (!s && row.error[0]) s = mlb_fail(MLB_ERR_NUMERIC, "demo: generating '%s' failed: %s", row.prompt, row.error);
    // the picture, under the same unseen light as the measure
    mlb_envmap env = {0};
    mlb_envlight light = {0};
    double psnr = 0;
    if (!s) s = mlb_envmap_open(&env, bc.relight_env, 1.0f, bc.base.env_height, NULL);
    if (!s) s = mlb_envlight_build(&light, &env, NULL);
    if (!s) s = side_by_side(out, &row, &light, &psnr);
    if (!s) s = write_report(out, &row, mlb_now_seconds() - t0, psnr);
    mlb_envlight_free(&light);
    mlb_envmap_free(&env);
    if (s) return cli_fail(s, "demo");
    mlb_text3d_print(stdout, &bc, &row, 1, &sum);
    printf("\nreport: %s/report.md; truth and result side by side: %s/compare.png; the asset: %s (%.0f s in all)\n", out,
           out, row.run_dir, mlb_now_seconds() - t0);
    return 0;
}
