// The text-to-3D benchmark's report (include/matlaber/text3d.h): the summary over the rows, the
// ablation's name, the Markdown table beside the runs and the JSON a program reads.
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/catalogue.h"
#include "matlaber/dist.h"
#include "matlaber/progress.h"
#include "matlaber/run.h"
#include "matlaber/text3d.h"

static int cmp_double(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return (x > y) - (x < y);
}

static double median_of(double* v, int n) {
    if (n < 1) return NAN;
    qsort(v, (size_t)n, sizeof(double), cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

void mlb_text3d_summarise(const mlb_text3d_row* rows, int n, double seconds, mlb_text3d_summary* o) {
    memset(o, 0, sizeof *o);
    o->n = n;
    o->seconds = seconds;
    int ok = 0, ok_seen = 0, ok_held = 0, metal = 0, colour = 0, measured = 0, measured_seen = 0, measured_held = 0;
    int by_mat_n[MLB_TEXT3D_MAX_CLASSES] = {0}, by_mat_ok[MLB_TEXT3D_MAX_CLASSES] = {0};
    double rmse_seen = 0, rmse_held = 0, psnr = 0;
    // per row: the Chamfer, normal error, completeness and accuracy (infinite when failed: counted)
    double* v = malloc(sizeof(double) * 4 * (size_t)(n > 0 ? n : 1));
    o->max_normal_deg = n ? -INFINITY : NAN;
    for (int i = 0; i < n; i++) {
        const mlb_text3d_scores* sc = &rows[i].scores;
        int failed = rows[i].error[0] != 0;
        o->n_failed += failed;
        ok += sc->class_ok;
        metal += sc->metal_ok;
        colour += sc->colour_ok;
        if (sc->mat >= 0 && sc->mat < MLB_TEXT3D_MAX_CLASSES) by_mat_n[sc->mat]++, by_mat_ok[sc->mat] += sc->colour_ok;
        if (v) {
            v[i] = sc->chamfer_prompted;
            v[n + i] = sc->normal_deg;
            v[2 * n + i] = sc->completeness;
            v[3 * n + i] = sc->accuracy;
        }
        if (sc->normal_deg > o->max_normal_deg) o->max_normal_deg = sc->normal_deg;
        if (!isnan(sc->thin)) o->n_with_parts++, o->n_parts_present += sc->thin <= MLB_TEXT3D_PART_PRESENT;
        if (sc->held_out) o->n_held_out++, ok_held += sc->class_ok;
        else o->n_seen++, ok_seen += sc->class_ok;
        if (failed) continue;
        measured++;
        psnr += sc->relight_psnr;
        if (sc->janus >= 0) o->n_janus_measured++, o->n_janus += sc->janus, o->n_mirrored += sc->mirrored;
        if (sc->held_out) measured_held++, rmse_held += sc->material_rmse;
        else measured_seen++, rmse_seen += sc->material_rmse;
    }
    o->class_acc = n ? (double)ok / n : NAN;
    o->class_acc_seen = o->n_seen ? (double)ok_seen / o->n_seen : NAN;
    o->class_acc_held_out = o->n_held_out ? (double)ok_held / o->n_held_out : NAN;
    o->metal_acc = n ? (double)metal / n : NAN;
    o->colour_acc = n ? (double)colour / n : NAN;
    for (int m = 0; m < MLB_TEXT3D_MAX_CLASSES; m++)
        o->colour_acc_by_material[m] = by_mat_n[m] ? (double)by_mat_ok[m] / by_mat_n[m] : NAN;
    o->material_rmse_seen = measured_seen ? rmse_seen / measured_seen : NAN;
    o->material_rmse_held_out = measured_held ? rmse_held / measured_held : NAN;
    o->relight_psnr = measured ? psnr / measured : NAN;
    o->median_chamfer = o->median_normal_deg = o->median_completeness = o->median_accuracy = NAN;
    if (v && n) {
        o->median_chamfer = median_of(v, n);
        o->median_normal_deg = median_of(v + n, n);
        o->median_completeness = median_of(v + 2 * n, n);
        o->median_accuracy = median_of(v + 3 * n, n);
    }
    free(v);
}

const char* mlb_text3d_ablation_name(const mlb_pipeline_config* c, char* buf, size_t cap) {
    buf[0] = 0;
    const char* parts[3] = {c->material == MLB_MATERIAL_DIRECT ? "direct" : NULL, c->fixed_env ? "fixed-env" : NULL,
                            c->view_prompts ? NULL : "no-view-prompts"};
    for (int i = 0; i < 3; i++)
        if (parts[i]) snprintf(buf + strlen(buf), cap - strlen(buf), "%s%s", buf[0] ? "+" : "", parts[i]);
    if (!buf[0]) snprintf(buf, cap, "latent");
    return buf;
}

static const char* num_or_dash(char buf[16], double v, int digits) {
    if (isnan(v)) snprintf(buf, 16, "-");
    else snprintf(buf, 16, "%.*f", digits, v);
    return buf;
}

void mlb_text3d_print(FILE* f, const mlb_text3d_bench_config* c, const mlb_text3d_row* rows, int n,
                      const mlb_text3d_summary* sum) {
    char abl[64];
    fprintf(f, "# Text to 3D against known truth\n\n"
               "Model %s%s%s%s; %d + %d steps (geometry + appearance), %d views at %d², seed %llu; ablation: %s.\n"
               "Chamfer: relative to the truth's bounding-box diagonal, to each class's best-fitting member (the\n"
               "best of %d shape seeds, then %d rounds of a fit of its shape parameters).\n"
               "Relighting under `%s` (no run saw it). Metal: mean ks > %.2f and mean kd < %.2f of the median BRDF.\n\n",
            c->base.model, c->base.appearance_model[0] ? " (appearance: " : "", c->base.appearance_model[0] ? c->base.appearance_model : "",
            c->base.appearance_model[0] ? ")" : "",
            c->base.geometry_iters, c->base.appearance_iters, c->base.views, c->base.res,
            (unsigned long long)c->base.seed, mlb_text3d_ablation_name(&c->base, abl, sizeof abl), c->n_seeds,
            c->measure.fit_rounds, c->relight_env, MLB_TEXT3D_METAL_KS, MLB_TEXT3D_METAL_KD);
    for (int i = 0; i < c->n_set; i++) fprintf(f, "%s`%s`%s", i ? ", " : "Set over the preset: ", c->set[i], i + 1 < c->n_set ? "" : ".\n\n");
    fprintf(f, "Surface against the truth instance (the prompted class's fitted member): normal error (mean angle\n"
               "between face normals, degrees), completeness and accuracy (95th percentiles of the distances truth ->\n"
               "asset and asset -> truth, relative to the diagonal), thin parts (completeness on each named part;\n"
               "present at <= %.2f). Colour: the catalogue material the median BRDF's colour reads as.\n\n",
            MLB_TEXT3D_PART_PRESENT);
    fprintf(f, "| prompt | split | nearest class | Chamfer to prompted | class | normal ° | complete | accurate | thin parts | "
               "material RMSE | metal | colour | relight PSNR | time |\n"
               "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (int i = 0; i < n; i++) {
        const mlb_text3d_scores* sc = &rows[i].scores;
        char t[32], parts[96] = "-";
        if (isnan(rows[i].seconds)) snprintf(t, sizeof t, "-");
        else mlb_format_duration(rows[i].seconds, t, sizeof t);
        if (rows[i].error[0]) {   // no asset: the error in the row, wrong where a call is made
            fprintf(f, "| %s | %s | failed: %s | - | wrong | - | - | - | - | - | wrong | wrong | - | %s%s |\n", rows[i].prompt,
                    sc->held_out ? "held out" : "seen", rows[i].error, t, rows[i].generated ? "" : " (earlier)");
            continue;
        }
        for (int k = 0, at = 0; k < mlb_catalogue_class_n_parts(sc->cls); k++)
            at += snprintf(parts + at, sizeof parts - (size_t)at, "%s%s %.3f%s", k ? ", " : "", mlb_catalogue_part_name(sc->cls, k + 1),
                           sc->part_completeness[k], sc->part_completeness[k] <= MLB_TEXT3D_PART_PRESENT ? "" : " (missing)");
        const char* read_as = mlb_catalogue_material_name(sc->colour_pred);
        fprintf(f, "| %s | %s | %s (%.4f) | %.4f | %s | %.1f | %.3f | %.3f | %s | %.3f | %s (%s) | %s (%s) | %.2f dB | %s%s |\n",
                rows[i].prompt, sc->held_out ? "held out" : "seen", mlb_catalogue_class_name(sc->nearest), sc->chamfer[sc->nearest],
                sc->chamfer_prompted, sc->class_ok ? "ok" : "wrong", sc->normal_deg, sc->completeness, sc->accuracy, parts,
                sc->material_rmse, sc->metal_ok ? "ok" : "wrong", sc->metal_pred ? "metal" : "dielectric",
                sc->colour_ok ? "ok" : "wrong", read_as ? read_as : "-", sc->relight_psnr, t, rows[i].generated ? "" : " (earlier)");
    }
    char tt[32], a[4][16];   // a subset without held-out (or seen) prompts has no number there: "-"
    if (sum->n_failed)
        fprintf(f, "\n%d of %d generations failed (wrong in every accuracy, infinite in the medians, not in the RMSE\n"
                   "and PSNR means).\n", sum->n_failed, sum->n);
    fprintf(f, "\n%d prompts (%d seen, %d held out): class accuracy %.2f (seen %s, held out %s); metal accuracy %.2f;\n"
               "median Chamfer to the prompted class %.4f; material RMSE seen %s, held out %s; relighting %.2f dB mean;\n"
               "total time %s on %d process%s.\n",
            sum->n, sum->n_seen, sum->n_held_out, sum->class_acc, num_or_dash(a[0], sum->class_acc_seen, 2),
            num_or_dash(a[1], sum->class_acc_held_out, 2), sum->metal_acc, sum->median_chamfer,
            num_or_dash(a[2], sum->material_rmse_seen, 3), num_or_dash(a[3], sum->material_rmse_held_out, 3),
            sum->relight_psnr, mlb_format_duration(sum->seconds, tt, sizeof tt), mlb_dist_world_size(),
            mlb_dist_world_size() > 1 ? "es" : "");
    fprintf(f, "\nSurface: median normal error %.1f° (worst %.1f°); median completeness %.4f, accuracy %.4f; thin parts\n"
               "present on %d of %d prompts that have them. Colour accuracy %.2f",
            sum->median_normal_deg, sum->max_normal_deg, sum->median_completeness, sum->median_accuracy, sum->n_parts_present,
            sum->n_with_parts, sum->colour_acc);
    for (int m = 0, first = 1; m < mlb_catalogue_n_materials() && m < MLB_TEXT3D_MAX_CLASSES; m++)
        if (!isnan(sum->colour_acc_by_material[m])) {
            fprintf(f, "%s%s %.2f", first ? " (" : ", ", mlb_catalogue_material_name(m), sum->colour_acc_by_material[m]);
            first = 0;
        }
    fprintf(f, "%s.\n", sum->n ? ")" : "");
    if (sum->n_janus_measured) {   // the classes whose two sides differ: is the far side's part doubled?
        fprintf(f, "\nJanus (mug, teapot: the one-sided part mirrored onto the other side is nearer than the truth):\n"
                   "%d of %d assets two-faced, %d mirrored", sum->n_janus, sum->n_janus_measured, sum->n_mirrored);
        const char* sep = ": ";
        for (int i = 0; i < n; i++)
            if (!rows[i].error[0] && rows[i].scores.janus == 1) { fprintf(f, "%s%s", sep, rows[i].prompt); sep = ", "; }
        fprintf(f, ".\n");
    }
}

mlb_status mlb_text3d_write_json(const char* path, const mlb_text3d_bench_config* c, const mlb_text3d_row* rows,
                                 int n, const mlb_text3d_summary* sum) {
    char abl[64];
    cJSON* j = cJSON_CreateObject();
    cJSON* arr = cJSON_CreateArray();
    cJSON* su = cJSON_CreateObject();
    if (!j || !arr || !su) {
        cJSON_Delete(j); cJSON_Delete(arr); cJSON_Delete(su);
        return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path);
    }
    cJSON_AddStringToObject(j, "model", c->base.model);
    if (c->base.appearance_model[0]) cJSON_AddStringToObject(j, "appearance_model", c->base.appearance_model);
    cJSON_AddStringToObject(j, "ablation", mlb_text3d_ablation_name(&c->base, abl, sizeof abl));
    cJSON_AddNumberToObject(j, "seed", (double)c->base.seed);
    cJSON_AddStringToObject(j, "init", c->base.init);
    cJSON* set = cJSON_AddArrayToObject(j, "set");
    for (int i = 0; set && i < c->n_set; i++) cJSON_AddItemToArray(set, cJSON_CreateString(c->set[i]));
    cJSON_AddNumberToObject(j, "geometry_iters", c->base.geometry_iters);
    cJSON_AddNumberToObject(j, "appearance_iters", c->base.appearance_iters);
    cJSON_AddNumberToObject(j, "views", c->base.views);
    cJSON_AddNumberToObject(j, "res", c->base.res);
    cJSON_AddNumberToObject(j, "shape_seeds", c->n_seeds);
    cJSON_AddNumberToObject(j, "shape_fit_rounds", c->measure.fit_rounds);
    cJSON_AddStringToObject(j, "relight_env", c->relight_env);
    for (int i = 0; i < n; i++) {
        const mlb_text3d_scores* sc = &rows[i].scores;
        cJSON* r = cJSON_CreateObject();
        if (!r) break;
        cJSON_AddStringToObject(r, "prompt", rows[i].prompt);
        cJSON_AddStringToObject(r, "class", mlb_catalogue_class_name(sc->cls));
        cJSON_AddStringToObject(r, "material", mlb_catalogue_material_name(sc->mat));
        cJSON_AddBoolToObject(r, "held_out", sc->held_out);
        cJSON_AddStringToObject(r, "run_dir", rows[i].run_dir);
        if (rows[i].error[0]) {   // the error, and null where a number needs an asset
            cJSON_AddStringToObject(r, "error", rows[i].error);
            cJSON_AddNullToObject(r, "nearest_class");
        } else {
            cJSON_AddStringToObject(r, "nearest_class", mlb_catalogue_class_name(sc->nearest));
        }
        cJSON_AddNumberToObject(r, "chamfer_prompted", sc->chamfer_prompted);
        cJSON_AddNumberToObject(r, "chamfer_nearest", sc->nearest >= 0 ? sc->chamfer[sc->nearest] : INFINITY);
        cJSON_AddBoolToObject(r, "class_ok", sc->class_ok);
        if (!rows[i].error[0]) {   // the prompted class's best-fitting member (catalogue.h's fractions)
            cJSON* tu = cJSON_CreateFloatArray(sc->shape_u[sc->cls], mlb_catalogue_class_n_params(sc->cls));
            if (tu) cJSON_AddItemToObject(r, "truth_params", tu);
        }
        cJSON* by = cJSON_AddObjectToObject(r, "chamfer_by_class");
        for (int k = 0; by && k < mlb_catalogue_n_classes(); k++)
            cJSON_AddNumberToObject(by, mlb_catalogue_class_name(k), sc->chamfer[k]);
        float kk[7];
        memcpy(kk, sc->median_k, sizeof kk);
        cJSON* mk = cJSON_CreateFloatArray(kk, 7);
        if (mk) cJSON_AddItemToObject(r, "median_brdf", mk);
        cJSON_AddNumberToObject(r, "material_rmse", sc->material_rmse);
        cJSON_AddBoolToObject(r, "metal_truth", sc->metal_truth);
        cJSON_AddBoolToObject(r, "metal_pred", sc->metal_pred);
        cJSON_AddBoolToObject(r, "metal_ok", sc->metal_ok);
        cJSON_AddNumberToObject(r, "relight_psnr", sc->relight_psnr);
        cJSON_AddNumberToObject(r, "normal_error_deg", sc->normal_deg);   // (cJSON writes an infinity as null)
        cJSON_AddNumberToObject(r, "completeness", sc->completeness);
        cJSON_AddNumberToObject(r, "accuracy", sc->accuracy);
        cJSON* pc = cJSON_AddObjectToObject(r, "part_completeness");
        for (int k = 0; pc && k < mlb_catalogue_class_n_parts(sc->cls); k++)
            cJSON_AddNumberToObject(pc, mlb_catalogue_part_name(sc->cls, k + 1), sc->part_completeness[k]);
        if (isnan(sc->thin)) cJSON_AddNullToObject(r, "parts_present");
        else cJSON_AddBoolToObject(r, "parts_present", sc->thin <= MLB_TEXT3D_PART_PRESENT);
        const char* read_as = mlb_catalogue_material_name(sc->colour_pred);
        if (read_as) cJSON_AddStringToObject(r, "colour_read_as", read_as);
        else cJSON_AddNullToObject(r, "colour_read_as");
        cJSON_AddBoolToObject(r, "colour_ok", sc->colour_ok);
        if (sc->janus >= 0) {   // absolute Chamfer distances to the truth, its mirror image and both
            cJSON_AddBoolToObject(r, "janus", sc->janus);
            cJSON_AddBoolToObject(r, "mirrored", sc->mirrored);
            cJSON_AddNumberToObject(r, "chamfer_truth", sc->chamfer_truth);
            cJSON_AddNumberToObject(r, "chamfer_mirror", sc->chamfer_mirror);
            cJSON_AddNumberToObject(r, "chamfer_both", sc->chamfer_both);
        }
        cJSON_AddNumberToObject(r, "seconds", rows[i].seconds);   // null when unknown
        cJSON_AddBoolToObject(r, "generated", rows[i].generated);
        cJSON_AddItemToArray(arr, r);
    }
    cJSON_AddItemToObject(j, "rows", arr);
    cJSON_AddNumberToObject(su, "prompts", sum->n);
    cJSON_AddNumberToObject(su, "seen", sum->n_seen);
    cJSON_AddNumberToObject(su, "held_out", sum->n_held_out);
    cJSON_AddNumberToObject(su, "failed", sum->n_failed);
    cJSON_AddNumberToObject(su, "class_accuracy", sum->class_acc);
    cJSON_AddNumberToObject(su, "class_accuracy_seen", sum->class_acc_seen);
    cJSON_AddNumberToObject(su, "class_accuracy_held_out", sum->class_acc_held_out);
    cJSON_AddNumberToObject(su, "metal_accuracy", sum->metal_acc);
    cJSON_AddNumberToObject(su, "median_chamfer", sum->median_chamfer);
    cJSON_AddNumberToObject(su, "material_rmse_seen", sum->material_rmse_seen);
    cJSON_AddNumberToObject(su, "material_rmse_held_out", sum->material_rmse_held_out);
    cJSON_AddNumberToObject(su, "relight_psnr_mean", sum->relight_psnr);
    cJSON_AddNumberToObject(su, "janus_measured", sum->n_janus_measured);
    cJSON_AddNumberToObject(su, "janus", sum->n_janus);
    cJSON_AddNumberToObject(su, "mirrored", sum->n_mirrored);
    cJSON_AddNumberToObject(su, "median_normal_error_deg", sum->median_normal_deg);
    cJSON_AddNumberToObject(su, "max_normal_error_deg", sum->max_normal_deg);
    cJSON_AddNumberToObject(su, "median_completeness", sum->median_completeness);
    cJSON_AddNumberToObject(su, "median_accuracy", sum->median_accuracy);
    cJSON_AddNumberToObject(su, "prompts_with_parts", sum->n_with_parts);
    cJSON_AddNumberToObject(su, "parts_present", sum->n_parts_present);
    cJSON_AddNumberToObject(su, "colour_accuracy", sum->colour_acc);
    cJSON* cm = cJSON_AddObjectToObject(su, "colour_accuracy_by_material");
    for (int m = 0; cm && m < mlb_catalogue_n_materials() && m < MLB_TEXT3D_MAX_CLASSES; m++)
        if (!isnan(sum->colour_acc_by_material[m])) cJSON_AddNumberToObject(cm, mlb_catalogue_material_name(m), sum->colour_acc_by_material[m]);
    cJSON_AddNumberToObject(su, "seconds", sum->seconds);
    cJSON_AddNumberToObject(su, "processes", mlb_dist_world_size());   // prompts shared among them
    cJSON_AddItemToObject(j, "summary", su);
    mlb_status s = mlb_run_write_json(path, j);
    cJSON_Delete(j);
    return s;
}
