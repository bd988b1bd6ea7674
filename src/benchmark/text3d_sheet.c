// The text-to-3D benchmark's contact sheet (include/matlaber/text3d.h): every measured prompt's truth
// instance (the prompted class's fitted member in its true material) beside the generated asset,
// seen from one camera under one light, so that the state of the whole benchmark is seen at a glance.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/catalogue.h"
#include "matlaber/plot.h"
#include "matlaber/raster.h"
#include "matlaber/render.h"
#include "matlaber/shade.h"
#include "matlaber/run.h"
#include "matlaber/text3d.h"

// The sheet's camera: front-right and a little above, so that the mug's handle, the teapot's spout
// and the stool's front leg face it; the catalogue's radius 0.9 fills most of the frame.
#define SHEET_AZIMUTH 30.0
#define SHEET_ELEVATION 20.0
#define SHEET_FOVY 40.0

// mesh with per-vertex BRDF k into rgb [res, res, 3]: sRGB over a white background.
// k: per-vertex BRDF, or NULL for the run's material field at every pixel (as its baked asset shows it).
static mlb_status render_cell(const mlb_mesh* mesh, const float* k, mlb_run_asset* run, const mlb_envlight* light, int res,
                              float* rgba, float* rgb) {
    mlb_render_params rp;
    memset(&rp, 0, sizeof rp);
    rp.mesh = mesh;
    rp.k = k;
    rp.material = k ? NULL : mlb_run_asset_material;
    rp.material_user = run;
    rp.light = light;
    rp.background = MLB_BG_COLOR;
    rp.width = rp.height = res;
    rp.supersample = 2;
    rp.fresnel = MLB_FRESNEL_PAPER;
    mlb_status s = mlb_camera_orbit(&rp.camera, SHEET_AZIMUTH, SHEET_ELEVATION, MLB_ORBIT_RADIUS, NULL, SHEET_FOVY, 1.0, 0.1, 10.0);
    if (!s) s = mlb_render_shaded(&rp, rgba);
    for (size_t i = 0; !s && i < (size_t)res * res; i++)   // premultiplied over black: white shows through
        for (int c = 0; c < 3; c++) rgb[3 * i + c] = mlb_srgb_encode(rgba[4 * i + c] + 1.0f - rgba[4 * i + 3]);
    return s;
}

// The row's two cells: its truth instance and its asset (grey where the generation failed).
static mlb_status row_cells(const mlb_text3d_row* row, const mlb_envlight* light, int res, float* rgba, float* truth_rgb,
                            float* asset_rgb) {
    const mlb_text3d_scores* sc = &row->scores;
    mlb_mesh truth = {0};
    mlb_run_asset a;
    memset(&a, 0, sizeof a);
    float* tk = NULL;
    float u[MLB_CATALOGUE_MAX_PARAMS];
    if (row->error[0]) mlb_catalogue_seed_params(sc->cls, 0, u);   // no fit without an asset: the canonical member
    else memcpy(u, sc->shape_u[sc->cls], sizeof u);
    mlb_status s = mlb_catalogue_mesh_params(sc->cls, u, &truth);
    if (!s && !(tk = malloc(sizeof(float) * 7 * (size_t)truth.n_verts))) s = mlb_fail(MLB_ERR_NOMEM, "contact sheet: out of memory");
    for (int i = 0; !s && i < truth.n_verts; i++) memcpy(tk + 7 * (size_t)i, mlb_catalogue_material_brdf(sc->mat), sizeof(float) * 7);
    if (!s) s = render_cell(&truth, tk, NULL, light, res, rgba, truth_rgb);
    if (!s && row->error[0]) {
        for (size_t i = 0; i < 3 * (size_t)res * res; i++) asset_rgb[i] = 0.8f;
    } else if (!s) {
        s = mlb_run_asset_load(&a, row->run_dir);
        if (!s) s = render_cell(&a.mesh, NULL, &a, light, res, rgba, asset_rgb);
        mlb_run_asset_free(&a);
    }
    free(tk);
    mlb_mesh_free(&truth);
    return s ? mlb_fail_context(s, "contact sheet: %s", row->run_dir) : MLB_OK;
}

mlb_status mlb_text3d_sheet_write(const char* path, const mlb_text3d_row* rows, int n, const char* env, int env_height,
                                  int cube_size, int res, int cols) {
    if (n < 1 || res < 16 || res > 1024 || cols < 1) return mlb_fail(MLB_ERR_ARG, "contact sheet: %d rows at %d px, %d columns", n, res, cols);
    mlb_envmap map = {0};
    mlb_envlight lt = {0};
    mlb_envlight_options lo;
    memset(&lo, 0, sizeof lo);
    lo.face_size = cube_size;
    mlb_status s = mlb_envmap_open(&map, env, 1.0f, env_height, NULL);
    if (!s) s = mlb_envlight_build(&lt, &map, &lo);
    if (s) {
        mlb_envmap_free(&map);
        return mlb_fail_context(s, "contact sheet: the light %s", env);
    }
    const mlb_envlight* light = &lt;
    size_t px = (size_t)res * res;
    float* img = malloc(sizeof(float) * 3 * px * 2 * (size_t)n);
    float* rgba = malloc(sizeof(float) * 4 * px);
    char(*text)[48] = calloc(2 * (size_t)n, sizeof *text);
    const char** labels = calloc(2 * (size_t)n, sizeof *labels);
    s = img && rgba && text && labels ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "contact sheet: out of memory");
    for (int i = 0; !s && i < n; i++) {
        const mlb_text3d_scores* sc = &rows[i].scores;
        s = row_cells(&rows[i], light, res, rgba, img + 3 * px * (2 * (size_t)i), img + 3 * px * (2 * (size_t)i + 1));
        const char* p = rows[i].prompt;
        snprintf(text[2 * i], sizeof text[0], "%s", strncmp(p, "a ", 2) ? p : p + 2);   // the caption less its article
        if (rows[i].error[0]) snprintf(text[2 * i + 1], sizeof text[0], "failed");
        else snprintf(text[2 * i + 1], sizeof text[0], "%.0f deg, %s", sc->normal_deg,
                      sc->colour_pred >= 0 ? mlb_catalogue_material_name(sc->colour_pred) : "-");
        labels[2 * i] = text[2 * i];
        labels[2 * i + 1] = text[2 * i + 1];
    }
    if (!s) s = mlb_image_grid_write(path, img, 2 * n, res, res, 3, 2 * cols, labels);
    free(img);
    free(rgba);
    free(text);
    free(labels);
    mlb_envlight_free(&lt);
    mlb_envmap_free(&map);
    return s;
}
