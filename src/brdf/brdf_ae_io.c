// BRDF prior files: the float auto-encoder to and from safetensors, and the built-in default.
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>
#include "matlaber/brdf.h"
#include "matlaber/brdf_ae.h"

#define PRIOR_FORMAT "matlaber-brdf-ae/1"
// Optional: PCA-4 of the training data, the linear baseline 'brdf eval' compares against.
#define PCA_MEAN "baseline.pca4.mean"
#define PCA_COMPONENTS "baseline.pca4.components"

// Generated at build time from models/brdf_prior.safetensors (CMakeLists.txt).
extern const unsigned char mlb_builtin_prior[];
extern const size_t mlb_builtin_prior_size;

static void tensor_name(char* buf, size_t n, const char* net, int layer, const char* kind) {
    snprintf(buf, n, "%s.%d.%s", net, layer, kind);
}

mlb_status mlb_brdf_ae_save(const mlb_brdf_ae* ae, const char* path, const mlb_st_meta* extra, size_t n_extra) {
    enum { MAX_T = 2 * 2 * MLB_MLP_MAX_LAYERS + 2 };
    mlb_st_entry entries[MAX_T];
    int64_t shapes[MAX_T][2];
    char names[MAX_T][40];
    size_t n = 0;
    const mlb_mlp* nets[2] = {&ae->enc, &ae->dec};
    const char* net_names[2] = {"encoder", "decoder"};
    for (int k = 0; k < 2; k++)
        for (int l = 0; l < nets[k]->n_layers; l++) {
            int in = nets[k]->dims[l], out = nets[k]->dims[l + 1];
            tensor_name(names[n], sizeof names[n], net_names[k], l, "weight");
            shapes[n][0] = out; shapes[n][1] = in;
            entries[n] = (mlb_st_entry){names[n], MLB_DT_F32, 2, shapes[n], nets[k]->weight[l]};
            n++;
            tensor_name(names[n], sizeof names[n], net_names[k], l, "bias");
            shapes[n][0] = out;
            entries[n] = (mlb_st_entry){names[n], MLB_DT_F32, 1, shapes[n], nets[k]->bias[l]};
            n++;
        }
    static const int64_t pca_mean_shape[1] = {7}, pca_comp_shape[2] = {4, 7};
    if (ae->has_pca) {
        entries[n++] = (mlb_st_entry){PCA_MEAN, MLB_DT_F32, 1, pca_mean_shape, ae->pca_mean};
        entries[n++] = (mlb_st_entry){PCA_COMPONENTS, MLB_DT_F32, 2, pca_comp_shape, ae->pca_components};
    }
    char hidden[16], depth[16], kr_min[32];
    snprintf(hidden, sizeof hidden, "%d", ae->config.hidden);
    snprintf(depth, sizeof depth, "%d", ae->config.depth);
    snprintf(kr_min, sizeof kr_min, "%.9g", (double)MLB_KR_MIN);
    mlb_st_meta meta[32];
    size_t nm = 0;
    meta[nm++] = (mlb_st_meta){"format", PRIOR_FORMAT};
    meta[nm++] = (mlb_st_meta){"hidden", hidden};
    meta[nm++] = (mlb_st_meta){"depth", depth};
    meta[nm++] = (mlb_st_meta){"activation", mlb_activation_name(ae->config.act)};
    meta[nm++] = (mlb_st_meta){"kr_min", kr_min};
    meta[nm++] = (mlb_st_meta){"encoder_input", "x = 2k - 1, k = (kd rgb, ks rgb, kr) linear"};
    meta[nm++] = (mlb_st_meta){"decoder_output", "sigmoid, then kd, ks in [0,1], kr in [kr_min,1]"};
    for (size_t i = 0; i < n_extra && nm < sizeof meta / sizeof *meta; i++) meta[nm++] = extra[i];
    return mlb_st_write(path, entries, n, meta, nm);
}

static mlb_status parse_int_meta(const mlb_safetensors* st, const char* key, int lo, int hi, int* out) {
    const char* v = mlb_st_metadata(st, key);
    if (!v) return mlb_fail(MLB_ERR_FORMAT, "%s: not a BRDF prior: metadata '%s' is missing", mlb_st_path(st), key);
    char* end;
    long x = strtol(v, &end, 10);
    if (*v == 0 || *end != 0 || x < lo || x > hi)
        return mlb_fail(MLB_ERR_FORMAT, "%s: metadata %s = '%s', expected an integer in %d..%d", mlb_st_path(st), key, v, lo, hi);
    *out = (int)x;
    return MLB_OK;
}

mlb_status mlb_brdf_ae_from_safetensors(mlb_brdf_ae* ae, const mlb_safetensors* st) {
    memset(ae, 0, sizeof *ae);
    const char* path = mlb_st_path(st);
    const char* format = mlb_st_metadata(st, "format");
    if (!format || strcmp(format, PRIOR_FORMAT) != 0)
        return mlb_fail(MLB_ERR_FORMAT, "%s: not a BRDF prior (metadata format is '%s', expected '%s')", path,
                        format ? format : "(missing)", PRIOR_FORMAT);
    mlb_brdf_ae_config cfg;
    MLB_TRY(parse_int_meta(st, "hidden", 1, 4096, &cfg.hidden));
    MLB_TRY(parse_int_meta(st, "depth", 1, MLB_MLP_MAX_LAYERS - 1, &cfg.depth));
    const char* act = mlb_st_metadata(st, "activation");
    if (!act || mlb_activation_parse(act, &cfg.act) != 0)
        return mlb_fail(MLB_ERR_FORMAT, "%s: unknown activation '%s'", path, act ? act : "(missing)");
    const char* kr = mlb_st_metadata(st, "kr_min");
    if (!kr || (float)strtod(kr, NULL) != MLB_KR_MIN)
        return mlb_fail(MLB_ERR_FORMAT, "%s: prior made for minimum roughness %s, this build uses %g", path,
                        kr ? kr : "(missing)", (double)MLB_KR_MIN);
    MLB_TRY(brdf_ae_init(ae, &cfg, 0));
    mlb_mlp* nets[2] = {&ae->enc, &ae->dec};
    const char* net_names[2] = {"encoder", "decoder"};
    for (int k = 0; k < 2; k++)
        for (int l = 0; l < nets[k]->n_layers; l++) {
            char name[40];
            int64_t wshape[2] = {nets[k]->dims[l + 1], nets[k]->dims[l]};
            mlb_status s;
            tensor_name(name, sizeof name, net_names[k], l, "weight");
            if ((s = mlb_st_expect(st, name, 2, wshape)) ||
                (s = mlb_st_read_f32(st, name, nets[k]->weight[l], (size_t)(wshape[0] * wshape[1])))) {
                brdf_ae_free(ae);
                return s;
            }
            tensor_name(name, sizeof name, net_names[k], l, "bias");
            if ((s = mlb_st_expect(st, name, 1, wshape)) ||
                (s = mlb_st_read_f32(st, name, nets[k]->bias[l], (size_t)wshape[0]))) {
                brdf_ae_free(ae);
                return s;
            }
        }
    if (mlb_st_find(st, PCA_MEAN) || mlb_st_find(st, PCA_COMPONENTS)) {
        static const int64_t mean_shape[1] = {7}, comp_shape[2] = {4, 7};
        mlb_status s;
        if ((s = mlb_st_expect(st, PCA_MEAN, 1, mean_shape)) || (s = mlb_st_expect(st, PCA_COMPONENTS, 2, comp_shape)) ||
            (s = mlb_st_read_f32(st, PCA_MEAN, ae->pca_mean, 7)) ||
            (s = mlb_st_read_f32(st, PCA_COMPONENTS, ae->pca_components, 28))) {
            brdf_ae_free(ae);
            return s;
        }
        ae->has_pca = 1;
    }
    if (mlb_st_count(st) != (size_t)(2 * (ae->enc.n_layers + ae->dec.n_layers) + 2 * ae->has_pca)) {
        size_t count = mlb_st_count(st);
        brdf_ae_free(ae);
        return mlb_fail(MLB_ERR_FORMAT, "%s: %zu tensors, expected %d for hidden %d depth %d", path, count,
                        2 * 2 * (cfg.depth + 1), cfg.hidden, cfg.depth);
    }
    for (size_t i = 0; i < ae->n_params; i++)
        if (!isfinite(ae->params[i])) {
            brdf_ae_free(ae);
            return mlb_fail(MLB_ERR_FORMAT, "%s: parameter %zu is not finite", path, i);
        }
    return MLB_OK;
}

mlb_status mlb_brdf_ae_load(mlb_brdf_ae* ae, const char* path) {
    mlb_safetensors* st;
    MLB_TRY(mlb_st_open(&st, path));
    mlb_status s = mlb_brdf_ae_from_safetensors(ae, st);
    mlb_st_close(st);
    return s;
}

mlb_status mlb_brdf_ae_load_default(mlb_brdf_ae* ae, char* source, size_t source_size) {
    const char* env = getenv("MATLABER_PRIOR");
    if (env && *env) {
        if (source) snprintf(source, source_size, "%s", env);
        mlb_status s = mlb_brdf_ae_load(ae, env);
        return s ? mlb_fail_context(s, "$MATLABER_PRIOR") : s;
    }
    if (source) snprintf(source, source_size, "built-in prior");
    if (mlb_builtin_prior_size == 0)
        return mlb_fail(MLB_ERR_NOT_FOUND, "this build has no built-in BRDF prior (models/brdf_prior.safetensors was "
                        "missing at build time): train one with 'matlaber brdf train --out FILE' and pass --model FILE");
    mlb_safetensors* st;
    MLB_TRY(mlb_st_open_memory(&st, mlb_builtin_prior, mlb_builtin_prior_size, "built-in prior"));
    mlb_status s = mlb_brdf_ae_from_safetensors(ae, st);
    mlb_st_close(st);
    return s;
}
