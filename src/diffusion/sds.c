// Score distillation sampling (sds.h, docs/sds.md).
#include "matlaber/sds.h"
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"
#include "matlaber/rng.h"
#include "matlaber/schedule.h"

#define SDS_STREAM_T 0x5D5000000000ull       // + 0: timesteps, index step * MAX_BATCH + b
#define SDS_STREAM_NOISE 0x5D5100000000ull   // + step: noise, index b * n + i

struct mlb_sds {
    const mlb_unet* unet;
    const mlb_vae* vae;
    float scaling_factor;
    float ac[1000];
    int v_prediction;
    mlb_sds_options opt;
    int Tc, Dc;
    float* cond[MLB_SDS_N_VIEWS];   // [Tc, Dc] or NULL
    float* uncond;
    mlb_vae_cache cache;
};

mlb_sds_options mlb_sds_default_options(void) {
    mlb_sds_options o = {100.0f, 20, 980, MLB_SDS_W_DREAMFUSION, 0, 0};
    return o;
}

static const char* const weight_names[] = {"dreamfusion", "fantasia0", "fantasia1", "fantasia2"};
const char* mlb_sds_weighting_name(mlb_sds_weighting w) {
    return (unsigned)w < 4 ? weight_names[w] : "?";
}
mlb_status mlb_sds_weighting_parse(const char* name, mlb_sds_weighting* out) {
    for (int i = 0; i < 4; i++)
        if (name && !strcmp(name, weight_names[i])) { *out = (mlb_sds_weighting)i; return MLB_OK; }
    return mlb_fail(MLB_ERR_ARG, "unknown SDS weighting '%s' (dreamfusion, fantasia0, fantasia1, fantasia2)", name ? name : "(null)");
}

float mlb_sds_weight(mlb_sds_weighting w, float ac, long step, long coarse_iter) {
    float r;
    switch (w) {
    case MLB_SDS_W_FANTASIA0: r = sqrtf(ac) * (1.0f - ac); break;
    case MLB_SDS_W_FANTASIA1: r = 1.0f / (1.0f - ac); break;
    case MLB_SDS_W_FANTASIA2: r = step < coarse_iter ? 0.0f : 1.0f; break;
    default: r = 1.0f - ac; break;
    }
    return isfinite(r) ? r : 0.0f;
}

int mlb_sds_view_for_azimuth(double az) {
    double a = fmod(az, 360.0);
    if (a > 180.0) a -= 360.0;
    if (a < -180.0) a += 360.0;
    a = fabs(a);
    if (a <= 45.0) return MLB_SDS_VIEW_FRONT;
    if (a >= 135.0) return MLB_SDS_VIEW_BACK;
    return MLB_SDS_VIEW_SIDE;
}

int mlb_sds_view_for(double az, double el) {
    return el > MLB_SDS_OVERHEAD_ELEVATION ? MLB_SDS_VIEW_OVERHEAD : mlb_sds_view_for_azimuth(az);
}

const char* mlb_sds_view_suffix(int view) {
    static const char* const suffix[MLB_SDS_N_VIEWS] = {"", ", front view", ", side view", ", back view",
                                                        ", overhead view"};
    return view >= 0 && view < MLB_SDS_N_VIEWS ? suffix[view] : "";
}

mlb_status mlb_sds_create(const mlb_unet* unet, const mlb_vae* vae, float scaling_factor, const float* ac, int v_prediction,
                          const mlb_sds_options* opt, mlb_sds** out) {
    if (!out || !unet || !ac) return mlb_fail(MLB_ERR_ARG, "mlb_sds_create: NULL argument");
    *out = NULL;
    mlb_sds_options o = opt ? *opt : mlb_sds_default_options();
    if (o.t_min < 0 || o.t_max > 999 || o.t_min > o.t_max)
        return mlb_fail(MLB_ERR_ARG, "SDS timestep range [%d, %d] must lie within [0, 999] and be ordered", o.t_min, o.t_max);
    if (!isfinite(o.guidance_scale)) return mlb_fail(MLB_ERR_ARG, "SDS guidance scale is not finite");
    if ((unsigned)o.weighting > MLB_SDS_W_FANTASIA2) return mlb_fail(MLB_ERR_ARG, "unknown SDS weighting %d", (int)o.weighting);
    if (vae && !(scaling_factor > 0)) return mlb_fail(MLB_ERR_ARG, "SDS scaling factor must be positive");
    mlb_sds* s = calloc(1, sizeof *s);
    if (!s) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    s->unet = unet;
    s->vae = vae;
    s->scaling_factor = scaling_factor;
    memcpy(s->ac, ac, sizeof s->ac);
    s->v_prediction = v_prediction;
    s->opt = o;
    s->Dc = unet->cfg.context_dim;
    *out = s;
    return MLB_OK;
}

void mlb_sds_free(mlb_sds* s) {
    if (!s) return;
    for (int i = 0; i < MLB_SDS_N_VIEWS; i++) free(s->cond[i]);
    free(s->uncond);
    mlb_vae_cache_free(&s->cache);
    free(s);
}

mlb_sds_options* mlb_sds_options_of(mlb_sds* s) { return s ? &s->opt : NULL; }

static mlb_status set_emb(mlb_sds* s, float** slot, const float* emb, int Tc) {
    if (!s || !emb || Tc < 1) return mlb_fail(MLB_ERR_ARG, "SDS embedding: bad argument");
    if (s->Tc && Tc != s->Tc) return mlb_fail(MLB_ERR_ARG, "SDS embedding has %d tokens, the others %d", Tc, s->Tc);
    size_t n = (size_t)Tc * s->Dc;
    float* p = *slot ? *slot : malloc(n * sizeof(float));
    if (!p) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    memcpy(p, emb, n * sizeof(float));
    *slot = p;
    s->Tc = Tc;
    return MLB_OK;
}
mlb_status mlb_sds_set_cond(mlb_sds* s, int view, const float* emb, int Tc) {
    if (!s || view < 0 || view >= MLB_SDS_N_VIEWS) return mlb_fail(MLB_ERR_ARG, "SDS view %d out of range", view);
    return set_emb(s, &s->cond[view], emb, Tc);
}
mlb_status mlb_sds_set_uncond(mlb_sds* s, const float* emb, int Tc) {
    if (!s) return mlb_fail(MLB_ERR_ARG, "NULL SDS object");
    return set_emb(s, &s->uncond, emb, Tc);
}

mlb_status mlb_sds_create_from_model(const mlb_sd_model* m, const char* prompt, const char* negative, int view_dependent,
                                     const mlb_sds_options* opt, mlb_sds** out) {
    if (!m || !prompt || !out) return mlb_fail(MLB_ERR_ARG, "mlb_sds_create_from_model: NULL argument");
    *out = NULL;
    MLB_TRY(mlb_sds_create(m->unet, m->vae, m->scaling_factor, m->alphas_cumprod, m->v_prediction, opt, out));
    mlb_sds* s = *out;
    size_t n = (size_t)MLB_CLIP_CONTEXT * s->Dc;
    float* emb = malloc(n * sizeof(float));
    char* text = malloc(strlen(prompt) + 32);
    mlb_status st = MLB_OK;
    if (!emb || !text) { st = mlb_fail(MLB_ERR_NOMEM, "out of memory"); goto done; }
    for (int v = 0; v < (view_dependent ? MLB_SDS_N_VIEWS : 1); v++) {
        sprintf(text, "%s%s", prompt, mlb_sds_view_suffix(v));
        if ((st = mlb_sd_model_encode_prompt(m, text, emb)) != MLB_OK) goto done;
        if ((st = mlb_sds_set_cond(s, v, emb, MLB_CLIP_CONTEXT)) != MLB_OK) goto done;
    }
    if ((st = mlb_sd_model_encode_prompt(m, negative ? negative : "", emb)) != MLB_OK) goto done;
    st = mlb_sds_set_uncond(s, emb, MLB_CLIP_CONTEXT);
done:
    free(emb);
    free(text);
    if (st) { mlb_sds_free(s); *out = NULL; }
    return st;
}

mlb_status mlb_sds_latent_shape(const mlb_sds* s, int C, int H, int W, int* c, int* h, int* w) {
    const int Lc = s->unet->cfg.in_channels;
    if (c) *c = Lc;
    if (C == Lc) { *h = H; *w = W; }
    else if (s->vae && C == s->vae->cfg.in_channels) {
        *h = mlb_vae_latent_size(&s->vae->cfg, H);
        *w = mlb_vae_latent_size(&s->vae->cfg, W);
        if (*h < 1 || *w < 1) return mlb_fail(MLB_ERR_ARG, "SDS image %dx%d is too small for the VAE", W, H);
    } else
        return mlb_fail(MLB_ERR_ARG, "SDS input has %d channels: expected %d (images in [0, 1]%s) or %d (latents)", C,
                        s->vae ? s->vae->cfg.in_channels : 3, s->vae ? "" : ", needs a VAE", Lc);
    int mult = 1 << (s->unet->cfg.n_levels - 1);
    if (*h % mult || *w % mult) return mlb_fail(MLB_ERR_ARG, "SDS latent %dx%d is not a multiple of %d (the UNet's downsampling)", *w, *h, mult);
    return MLB_OK;
}

// Where the VAE runs when the images live on be's device: on its own table (a GPU copy, or the CPU's
// bf16 ops), else an fp32 CPU model on be itself (the CPU's table, or a test's guarded one).
static mlb_status vae_where(const mlb_sds* s, const mlb_backend* be, const mlb_backend** vbe, const mlb_vae** vm) {
    const mlb_vae* v = s->vae;
    *vbe = v->mirror_ops ? v->mirror_ops : be;
    *vm = v->mirror ? v->mirror : v;
    if ((*vbe)->device != be->device)
        return mlb_fail(MLB_ERR_ARG, "SDS: the images are on the %s, the VAE runs on the %s", mlb_device_name(be->device),
                        mlb_device_name((*vbe)->device));
    return MLB_OK;
}

const mlb_backend* mlb_sds_images_table(const mlb_sds* s, int C) {
    const mlb_backend* cpu = mlb_backend_cpu();
    if (!s || !s->vae || C == s->unet->cfg.in_channels || !s->vae->mirror_ops) return cpu;
    return s->vae->mirror_ops;
}

mlb_status mlb_sds_step_on(mlb_sds* s, const mlb_backend* be, const mlb_sds_input* in, float* grad_images, float* loss,
                           mlb_sds_trace* tr) {
    if (!s || !be || !in || !in->images) return mlb_fail(MLB_ERR_ARG, "mlb_sds_step: NULL argument");
    const int B = in->B, C = in->C, H = in->H, W = in->W;
    if (B < 1 || B > MLB_SDS_MAX_BATCH) return mlb_fail(MLB_ERR_ARG, "SDS batch %d outside 1..%d", B, MLB_SDS_MAX_BATCH);
    const int first = in->first, total = in->total > 0 ? in->total : B;
    if (first < 0 || first + B > total || total > MLB_SDS_MAX_BATCH)
        return mlb_fail(MLB_ERR_ARG, "SDS part: elements %d..%d of %d", first, first + B - 1, total);
    if (!s->cond[0] || !s->uncond) return mlb_fail(MLB_ERR_ARG, "SDS: the prompt and unconditional embeddings are not set");
    const int Lc = s->unet->cfg.in_channels;
    int h, w;
    MLB_TRY(mlb_sds_latent_shape(s, C, H, W, NULL, &h, &w));
    const mlb_backend* vbe = NULL;
    const mlb_vae* vm = NULL;
    if (C != Lc) MLB_TRY(vae_where(s, be, &vbe, &vm));
    const size_t n = (size_t)Lc * h * w, nimg = (size_t)B * C * H * W, nall = (size_t)B * n;
    const size_t nc = (size_t)s->Tc * s->Dc;
    // the latent-sized work is the host's; the images and their gradient stay on be's device
    float *z = malloc(nall * sizeof(float)), *noise = malloc(nall * sizeof(float));
    float *x2 = malloc(2 * nall * sizeof(float)), *e2 = malloc(2 * nall * sizeof(float));
    float *ctx = malloc(2 * (size_t)B * nc * sizeof(float)), *grad = malloc(nall * sizeof(float));
    float *img = NULL, *dimg = NULL;   // on be's device
    int ts[MLB_SDS_MAX_BATCH];
    float tt[2 * MLB_SDS_MAX_BATCH], wt[MLB_SDS_MAX_BATCH];
    const double two = 2.0, minus_one = -1.0;
    mlb_status st = MLB_OK;
    if (!z || !noise || !x2 || !e2 || !ctx || !grad) { st = mlb_fail(MLB_ERR_NOMEM, "out of memory for the SDS step"); goto done; }
    // 1. the latent: the input itself, or the VAE's mean of 2 x - 1
    if (C == Lc) st = be->download(z, in->images, nall);
    else {
        if ((st = be->alloc(&img, nimg)) != MLB_OK) goto done;
        if ((st = be->affine_columns(img, in->images, nimg, 1, &two, &minus_one, 1)) != MLB_OK) goto done;
        if ((st = mlb_vae_encode_on(vbe, vm, img, B, H, W, z, NULL, grad_images ? &s->cache : NULL)) != MLB_OK) goto done;
        for (size_t i = 0; i < nall; i++) z[i] *= s->scaling_factor;
    }
    if (st) goto done;
    // 2. timesteps, noise, x_t; the batch [cond x B, uncond x B]
    for (int b = 0; b < B; b++) {
        int t;
        if (in->t) {
            t = in->t[b];
            if (t < 0 || t > 999) { st = mlb_fail(MLB_ERR_ARG, "SDS timestep %d outside 0..999", t); goto done; }
        } else
            t = s->opt.t_min + (int)mlb_rng_below(s->opt.seed, SDS_STREAM_T, (uint64_t)in->step * MLB_SDS_MAX_BATCH + (uint64_t)(first + b),
                                                  (uint32_t)(s->opt.t_max - s->opt.t_min + 1));
        ts[b] = t;
        tt[b] = tt[B + b] = (float)t;
        wt[b] = mlb_sds_weight(s->opt.weighting, s->ac[t], in->step, s->opt.coarse_iter);
        if (in->noise) memcpy(noise + b * n, in->noise + b * n, n * sizeof(float));
        else mlb_rng_fill_normal(noise + b * n, n, s->opt.seed, SDS_STREAM_NOISE + (uint64_t)in->step, (uint64_t)(first + b) * n, 0.0f, 1.0f);
        mlb_add_noise(x2 + b * n, z + b * n, noise + b * n, n, s->ac[t]);
        memcpy(x2 + nall + b * n, x2 + b * n, n * sizeof(float));
        int v = in->views ? in->views[b] : MLB_SDS_VIEW_NONE;
        if (v < 0 || v >= MLB_SDS_N_VIEWS) { st = mlb_fail(MLB_ERR_ARG, "SDS view %d out of range", v); goto done; }
        const float* c = s->cond[v] ? s->cond[v] : s->cond[0];
        memcpy(ctx + (size_t)b * nc, c, nc * sizeof(float));
        memcpy(ctx + (size_t)(B + b) * nc, s->uncond, nc * sizeof(float));
    }
    // 3. the UNet, eps from v, guidance, the weighted gradient
    if ((st = mlb_unet_forward(s->unet, e2, x2, tt, ctx, 2 * B, h, w, s->Tc, NULL, NULL)) != MLB_OK) goto done;
    if (s->v_prediction)
        for (int b = 0; b < 2 * B; b++) mlb_v_to_eps(e2 + b * n, e2 + b * n, x2 + b * n, n, s->ac[ts[b % B]]);
    if (tr) {
        if (tr->latent) memcpy(tr->latent, z, nall * sizeof(float));
        if (tr->noisy_latent) memcpy(tr->noisy_latent, x2, nall * sizeof(float));
        if (tr->eps_cond) memcpy(tr->eps_cond, e2, nall * sizeof(float));
        if (tr->eps_uncond) memcpy(tr->eps_uncond, e2 + nall, nall * sizeof(float));
        if (tr->w) memcpy(tr->w, wt, (size_t)B * sizeof(float));
        if (tr->t) memcpy(tr->t, ts, (size_t)B * sizeof(int));
        for (int b = 0; b < B && (tr->err_cond || tr->err_uncond); b++) {
            double ec = 0, eu = 0;
            for (size_t i = 0; i < n; i++) {
                double dc = (double)e2[b * n + i] - noise[b * n + i], du = (double)e2[nall + b * n + i] - noise[b * n + i];
                ec += dc * dc;
                eu += du * du;
            }
            if (tr->err_cond) tr->err_cond[b] = ec / (double)n;
            if (tr->err_uncond) tr->err_uncond[b] = eu / (double)n;
        }
    }
    mlb_cfg_combine(e2, e2 + nall, e2, nall, s->opt.guidance_scale);
    if (tr && tr->eps_guided) memcpy(tr->eps_guided, e2, nall * sizeof(float));
    double l = 0;
    for (int b = 0; b < B; b++)
        for (size_t i = 0; i < n; i++) {
            float g = wt[b] * (e2[b * n + i] - noise[b * n + i]);
            if (!isfinite(g)) g = 0.0f;
            grad[b * n + i] = g;
            l += (double)g * g;
        }
    if (tr && tr->grad_latent) memcpy(tr->grad_latent, grad, nall * sizeof(float));
    if (loss) *loss = (float)(0.5 * l / total);
    // 4. d loss / d images, on be's device
    if (grad_images) {
        if (C == Lc) {
            for (size_t i = 0; i < nall; i++) grad[i] /= (float)total;
            if ((st = be->alloc(&dimg, nall)) != MLB_OK) goto done;
            if ((st = be->upload(dimg, grad, nall)) != MLB_OK) goto done;
            st = be->add(grad_images, dimg, nall);
        } else {
            float k = s->scaling_factor / (float)total;
            for (size_t i = 0; i < nall; i++) grad[i] *= k;   // d loss / d mean
            if ((st = be->zero(img, nimg)) != MLB_OK) goto done;
            dimg = img, img = NULL;
            if ((st = mlb_vae_encode_backward_params_on(vbe, vm, &s->cache, grad, NULL, dimg, NULL)) != MLB_OK) goto done;
            if ((st = be->affine_columns(dimg, dimg, nimg, 1, &two, NULL, 1)) != MLB_OK) goto done;   // d(2x - 1)/dx
            st = be->add(grad_images, dimg, nimg);
        }
    }
done:
    free(z); free(noise); free(x2); free(e2); free(ctx); free(grad);
    if (img) be->release(img);
    if (dimg) be->release(dimg);
    return st;
}

mlb_status mlb_sds_step(mlb_sds* s, const mlb_sds_input* in, float* grad_images, float* loss, mlb_sds_trace* tr) {
    if (!s || !in || !in->images) return mlb_fail(MLB_ERR_ARG, "mlb_sds_step: NULL argument");
    const mlb_backend* be = mlb_sds_images_table(s, in->C);
    if (be->device == MLB_DEVICE_CPU) return mlb_sds_step_on(s, mlb_backend_cpu(), in, grad_images, loss, tr);
    // the VAE is on a GPU: the images go up, the step runs there, the gradient comes down (added)
    const size_t nimg = (size_t)in->B * in->C * in->H * in->W;
    float *d = NULL, *dg = NULL;
    mlb_sds_input on = *in;
    mlb_status st = be->alloc(&d, nimg);
    if (!st) st = be->upload(d, in->images, nimg);
    if (!st && grad_images) st = be->alloc(&dg, nimg);
    if (!st && grad_images) st = be->upload(dg, grad_images, nimg);
    on.images = d;
    if (!st) st = mlb_sds_step_on(s, be, &on, dg, loss, tr);
    if (!st && grad_images) st = be->download(grad_images, dg, nimg);
    if (d) be->release(d);
    if (dg) be->release(dg);
    return st;
}
