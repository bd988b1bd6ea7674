// A whole Stable Diffusion model: loading the four parts, prompt encoding, DDIM sampling with
// classifier-free guidance and decoding (sd_model.h, docs/sds.md).
#include "matlaber/sd_model.h"
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"
#include "matlaber/fileio.h"
#include "matlaber/log.h"
#include "matlaber/schedule.h"
#include "matlaber/sd_files.h"


mlb_sd_model_options mlb_sd_model_default_options(void) {
    mlb_sd_model_options o = {NULL, -1, 1, 1, MLB_DEVICE_CPU, MLB_GEMM_FP32};
    return o;
}

void mlb_sd_model_drop_text(mlb_sd_model* m) {
    if (!m) return;
    mlb_tokenizer_free(m->tokenizer);
    mlb_text_encoder_free(m->text);
    m->tokenizer = NULL;
    m->text = NULL;
}

void mlb_sd_model_drop_unet(mlb_sd_model* m) {
    if (!m) return;
    mlb_unet_free(m->unet);
    m->unet = NULL;
}

void mlb_sd_model_free(mlb_sd_model* m) {
    if (!m) return;
    mlb_sd_model_drop_text(m);
    mlb_unet_free(m->unet);
    mlb_vae_free(m->vae);
    free(m);
}

// folder/rel parsed into *root; *root NULL when the file is absent (a folder need not have it). A
// file that is there but unreadable or not JSON is an error naming it.
static mlb_status folder_json(const char* folder, const char* rel, cJSON** root) {
    char p[4200];
    *root = NULL;
    snprintf(p, sizeof p, "%s/%s", folder, rel);
    return mlb_is_file(p) ? mlb_json_read_file(p, 1 << 20, root) : MLB_OK;
}

// scheduler/scheduler_config.json's prediction_type into *v_prediction: 1 v_prediction, 0 epsilon,
// left as it is when the file or the key is absent; any other value is an error naming the file.
static mlb_status scheduler_prediction(const char* folder, int* v_prediction) {
    cJSON* root = NULL;
    MLB_TRY(folder_json(folder, "scheduler/scheduler_config.json", &root));
    const cJSON* v = root ? cJSON_GetObjectItemCaseSensitive(root, "prediction_type") : NULL;
    mlb_status s = MLB_OK;
    if (v && cJSON_IsString(v) && !strcmp(v->valuestring, "v_prediction")) *v_prediction = 1;
    else if (v && cJSON_IsString(v) && !strcmp(v->valuestring, "epsilon")) *v_prediction = 0;
    else if (v)
        s = mlb_fail(MLB_ERR_UNSUPPORTED, "%s/scheduler/scheduler_config.json: prediction_type must be \"epsilon\" or "
                     "\"v_prediction\"", folder);
    cJSON_Delete(root);
    return s;
}

int mlb_sd_geometry_suffix_ok(const char* s) {
    if (!s || strlen(s) >= MLB_SD_SUFFIX_MAX) return 0;
    for (; *s; s++)
        if (*s < 0x20 || *s > 0x7e || *s == '"' || *s == '\\') return 0;
    return 1;
}

int mlb_sd_model_is_own(const char* path) {
    cJSON* root = NULL;
    if (!path || strlen(path) > 4000 || !mlb_is_dir(path) || folder_json(path, "model_index.json", &root) != MLB_OK) return 0;
    int own = root && cJSON_GetObjectItemCaseSensitive(root, "_matlaber") != NULL;
    cJSON_Delete(root);
    return own;
}

// model_index.json's "_matlaber_geometry_suffix" into out (sd_folder.h); "" when the file or the
// key is absent (a user's folder need not have an index); an index that is not JSON, or a key that
// is there but not a short printable string, is an error naming the file.
static mlb_status geometry_suffix(const char* folder, char out[MLB_SD_SUFFIX_MAX]) {
    out[0] = 0;
    cJSON* root = NULL;
    MLB_TRY(folder_json(folder, "model_index.json", &root));
    mlb_status s = MLB_OK;
    const cJSON* v = root ? cJSON_GetObjectItemCaseSensitive(root, "_matlaber_geometry_suffix") : NULL;
    if (v) {
        const char* t = cJSON_IsString(v) ? v->valuestring : NULL;
        if (mlb_sd_geometry_suffix_ok(t)) snprintf(out, MLB_SD_SUFFIX_MAX, "%s", t);
        else s = mlb_fail(MLB_ERR_FORMAT, "%s/model_index.json: \"_matlaber_geometry_suffix\" must be a string of at most %d "
                          "printable ASCII characters without quotes or backslashes", folder, MLB_SD_SUFFIX_MAX - 1);
    }
    cJSON_Delete(root);
    return s;
}

mlb_status mlb_sd_model_load(const char* path, const mlb_sd_model_options* opt_in, mlb_sd_model** out) {
    if (!path || !out) return mlb_fail(MLB_ERR_ARG, "mlb_sd_model_load: NULL argument");
    *out = NULL;
    mlb_sd_model_options opt = opt_in ? *opt_in : mlb_sd_model_default_options();
    if (strlen(path) > 4000) return mlb_fail(MLB_ERR_ARG, "model path too long");
    int folder = mlb_is_dir(path);
    if (!folder) {
        if (mlb_ends_with(path, ".ckpt") || mlb_ends_with(path, ".bin") || mlb_ends_with(path, ".pt") || mlb_ends_with(path, ".pth"))
            return mlb_fail(MLB_ERR_UNSUPPORTED,
                            "%s: pickle checkpoints are not read; convert it to .safetensors first (e.g. with "
                            "safetensors' convert script or diffusers' convert_original_stable_diffusion_to_diffusers.py)",
                            path);
        if (!mlb_is_file(path)) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no such model file or folder", path);
    }
    mlb_sd_model* m = calloc(1, sizeof *m);
    if (!m) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    mlb_status s;
    // a GPU, or bf16 on the CPU (its only other precision: fp16 and tf32 stay fp32 there); bf16 on a
    // CPU that has it keeps the UNet's weights in bf16, any other CPU load the file's F16 weights as
    // they are (half the memory either way, the same results: mlb_unet_options_for)
    int cpu_bf16 = opt.device == MLB_DEVICE_CPU && opt.precision == MLB_GEMM_BF16;
    mlb_unet_options uo = mlb_unet_options_for(opt.device, opt.precision);
    if ((s = mlb_unet_load(path, &uo, &m->unet)) != MLB_OK) { mlb_fail_context(s, "loading the UNet"); goto fail; }
    if (m->unet->f16_weights)
        mlb_log(MLB_LOG_INFO, "UNet weights kept in f16 as the file stores them (%.0f MB; widened per call, fp32 results)",
                m->unet->n_params * 2e-6);
    if (opt.device != MLB_DEVICE_CPU || cpu_bf16) {
        if ((s = mlb_unet_use_device(m->unet, opt.device, opt.precision)) != MLB_OK) {
            mlb_fail_context(s, "moving the UNet to the %s", mlb_device_name(opt.device));
            goto fail;
        }
        if (cpu_bf16 && !mlb_gemm_bf16_native())   // asked for by name: the command line warned (main.c)
            mlb_log(MLB_LOG_INFO, "UNet on the CPU in fp32 (no AVX-512 BF16 here for the bf16 GEMMs)");
        else
            mlb_log(MLB_LOG_INFO, "UNet on the %s, %s GEMM operands%s", mlb_device_name(opt.device),
                    mlb_gemm_precision_name(opt.precision),
                    !cpu_bf16 ? "" : mlb_gemm_bf16_amx() ? " (linear, conv and attention on AMX tiles; weights kept in bf16)"
                                                         : " (linear, conv and attention; weights kept in bf16)");
    }
    if (opt.load_vae && (s = mlb_vae_load(path, NULL, &m->vae)) != MLB_OK) { mlb_fail_context(s, "loading the VAE"); goto fail; }
    if (m->vae && (opt.device != MLB_DEVICE_CPU || cpu_bf16) &&
        (s = mlb_vae_use_device(m->vae, opt.device, opt.precision)) != MLB_OK) {
        mlb_fail_context(s, "moving the VAE to the %s", mlb_device_name(opt.device));
        goto fail;
    }
    if (opt.load_text_encoder) {
        if ((s = mlb_text_encoder_load(path, NULL, &m->text)) != MLB_OK) { mlb_fail_context(s, "loading the text encoder"); goto fail; }
        char tp[4200];
        const char* tpath = opt.tokenizer_path;
        // the folder's own tokenizer/, else $MATLABER_TOKENIZER (a single file carries none)
        if (!tpath && folder) {
            snprintf(tp, sizeof tp, "%s/tokenizer", path);
            if (mlb_is_dir(tp) || mlb_is_file(tp)) tpath = tp;
        }
        const char* env = getenv("MATLABER_TOKENIZER");
        if (!tpath && env && env[0]) tpath = env;
        if (!tpath && folder) tpath = tp;   // missing: its load names the path that was looked for
        if (!tpath) {
            s = mlb_fail(MLB_ERR_ARG, "%s is a single file: the CLIP tokenizer is needed (--tokenizer PATH or "
                                      "$MATLABER_TOKENIZER: the merges .gz, a tokenizer/ folder or a diffusers model folder)", path);
            goto fail;
        }
        if ((s = mlb_tokenizer_load(tpath, &m->tokenizer)) != MLB_OK) { mlb_fail_context(s, "loading the tokenizer"); goto fail; }
        // SD1 pads with <|endoftext|>: 49407 in CLIP's vocabulary, the last id in a smaller one (the
        // project's own model); SD2 pads with 0 in either
        m->pad_id = m->text->variant == MLB_TEXT_SD2 ? mlb_text_encoder_pad_id(m->text) : mlb_tokenizer_eos(m->tokenizer);
        if (mlb_tokenizer_vocab_size(m->tokenizer) > m->text->vocab) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: the tokenizer has %d tokens but the text encoder embeds %d", path,
                         mlb_tokenizer_vocab_size(m->tokenizer), m->text->vocab);
            goto fail;
        }
        if (m->text->width != m->unet->cfg.context_dim) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: the text encoder is %d wide but the UNet's cross-attention expects %d", path,
                         m->text->width, m->unet->cfg.context_dim);
            goto fail;
        }
    }
    m->v_prediction = m->unet->cfg.v_prediction;
    if (folder && ((s = scheduler_prediction(path, &m->v_prediction)) != MLB_OK ||
                   (s = geometry_suffix(path, m->geometry_suffix)) != MLB_OK)) goto fail;
    if (opt.v_prediction >= 0) m->v_prediction = opt.v_prediction;
    m->scaling_factor = m->vae ? m->vae->cfg.scaling_factor : 0.18215f;
    if (!(m->scaling_factor > 0)) m->scaling_factor = 0.18215f;
    if ((s = mlb_schedule_alphas_cumprod_f32(m->alphas_cumprod, 1000, MLB_SD_BETA_START, MLB_SD_BETA_END)) != MLB_OK) goto fail;
    snprintf(m->source, sizeof m->source, "%s (%s, UNet %zu params, %s%s)", path, folder ? "diffusers folder" : "single file",
             m->unet->n_params, m->unet->cfg.sd2 ? "SD2-style" : "SD1-style", m->v_prediction ? ", v-prediction" : "");
    *out = m;
    return MLB_OK;
fail:
    mlb_sd_model_free(m);
    return s;
}

int mlb_sd_model_context_width(const mlb_sd_model* m) { return m && m->unet ? m->unet->cfg.context_dim : 0; }

mlb_status mlb_sd_model_encode_prompt(const mlb_sd_model* m, const char* prompt, float* out) {
    if (!m || !prompt || !out) return mlb_fail(MLB_ERR_ARG, "mlb_sd_model_encode_prompt: NULL argument");
    if (!m->text || !m->tokenizer) return mlb_fail(MLB_ERR_ARG, "the model's text encoder is not loaded");
    int ids[MLB_CLIP_CONTEXT];
    MLB_TRY(mlb_tokenizer_encode(m->tokenizer, prompt, ids, MLB_CLIP_CONTEXT, m->pad_id, NULL));
    // No op table in scope: the model holds none (the UNet and the VAE keep their own, mirror_ops),
    // and the text encoder's weights stay on the host. So the CPU's fp32 table, whatever --device
    // and --precision say: a prompt is encoded a handful of times per run, and its conditioning is
    // the same on every machine.
    return mlb_text_encoder_forward(mlb_backend_cpu(), m->text, ids, 1, MLB_CLIP_CONTEXT, out, NULL, 0);
}

mlb_status mlb_sd_ddim_sample(const mlb_unet* unet, const float* ac, int v_prediction, const float* ctx_uncond,
                              const float* ctx_cond, int Tc, float* latent, int h, int w, int steps, float cfg,
                              float* trace_eps, float* trace_latents, mlb_progress* progress) {
    if (!unet || !ac || !ctx_uncond || !ctx_cond || !latent) return mlb_fail(MLB_ERR_ARG, "mlb_sd_ddim_sample: NULL argument");
    if (steps < 1 || steps > MLB_DDIM_MAX_STEPS)
        return mlb_fail(MLB_ERR_ARG, "DDIM steps %d outside 1..%d (steps_offset 1: a 1000th step would be timestep 1000 of 0..999)",
                        steps, MLB_DDIM_MAX_STEPS);
    if (!isfinite(cfg)) return mlb_fail(MLB_ERR_ARG, "guidance scale is not finite");
    const int C = unet->cfg.in_channels, Dc = unet->cfg.context_dim;
    const size_t n = (size_t)C * h * w, nc = (size_t)Tc * Dc;
    int* ts = malloc((size_t)steps * sizeof *ts);
    float* ctx = malloc(2 * nc * sizeof(float));
    float* x2 = malloc(2 * n * sizeof(float));
    float* e2 = malloc(2 * n * sizeof(float));
    mlb_status s = MLB_OK;
    if (!ts || !ctx || !x2 || !e2) { s = mlb_fail(MLB_ERR_NOMEM, "out of memory for DDIM sampling"); goto done; }
    if ((s = mlb_ddim_timesteps(ts, steps, 1000, 1)) != MLB_OK) goto done;
    memcpy(ctx, ctx_uncond, nc * sizeof(float));
    memcpy(ctx + nc, ctx_cond, nc * sizeof(float));
    for (int i = 0; i < steps; i++) {
        int t = ts[i];
        float tt[2] = {(float)t, (float)t};
        memcpy(x2, latent, n * sizeof(float));
        memcpy(x2 + n, latent, n * sizeof(float));
        if ((s = mlb_unet_forward(NULL, unet, e2, x2, tt, ctx, 2, h, w, Tc, NULL, NULL)) != MLB_OK) goto done;
        if (v_prediction) {
            mlb_v_to_eps(e2, e2, x2, n, ac[t]);
            mlb_v_to_eps(e2 + n, e2 + n, x2 + n, n, ac[t]);
        }
        mlb_cfg_combine(e2, e2, e2 + n, n, cfg);
        if (trace_eps) memcpy(trace_eps + (size_t)i * n, e2, n * sizeof(float));
        int tp = mlb_ddim_prev_timestep(t, steps, 1000);
        double ac_prev = tp >= 0 ? ac[tp] : ac[0];   // set_alpha_to_one False: the final alpha is ac[0]
        if ((s = mlb_ddim_step(latent, NULL, latent, e2, n, ac[t], ac_prev)) != MLB_OK) goto done;
        if (trace_latents) memcpy(trace_latents + (size_t)i * n, latent, n * sizeof(float));
        if (progress) mlb_progress_update(progress, i + 1, NULL);
    }
    for (size_t k = 0; k < n; k++)
        if (!isfinite(latent[k])) { s = mlb_fail(MLB_ERR_NUMERIC, "DDIM sampling produced a non-finite latent"); break; }
done:
    free(ts); free(ctx); free(x2); free(e2);
    return s;
}

mlb_status mlb_sd_decode_latent(const mlb_vae* vae, float scaling_factor, const float* latent, int h, int w, float* image) {
    if (!vae || !latent || !image || !(scaling_factor > 0)) return mlb_fail(MLB_ERR_ARG, "mlb_sd_decode_latent: bad argument");
    size_t n = (size_t)vae->cfg.latent_channels * h * w;
    float* z = malloc(n * sizeof(float));
    if (!z) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    for (size_t i = 0; i < n; i++) z[i] = latent[i] / scaling_factor;
    mlb_status s = mlb_vae_decode(NULL, vae, z, 1, h, w, image, NULL);
    free(z);
    return s;
}
