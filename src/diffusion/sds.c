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
    // the embeddings on the device of the last step_on ([N_VIEWS cond | uncond] x Tc x Dc, a view
    // without its own holding the base prompt's), allocated by emb_be; emb_stale after a set
    float* emb_dev;
    const mlb_backend* emb_be;
    int emb_stale;
};

mlb_sds_options mlb_sds_default_options(void) {
    mlb_sds_options o = {.guidance_scale = 100.0f, .t_min = 20, .t_max = 980, .weighting = MLB_SDS_W_DREAMFUSION};
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

int mlb_sds_t_max_at(const mlb_sds_options* o, long step) {
    if (o->anneal_steps <= 0) return o->t_max;
    double f = step <= 0 ? 0.0 : step >= o->anneal_steps ? 1.0 : (double)step / (double)o->anneal_steps;
    return (int)lround(o->t_max + (o->t_max_end - o->t_max) * f);
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

mlb_status mlb_sds_options_check(const mlb_sds_options* op) {
    if (!op) return mlb_fail(MLB_ERR_ARG, "mlb_sds_options_check: NULL options");
    const mlb_sds_options o = *op;
    if (o.t_min < 0 || o.t_max > 999 || o.t_min > o.t_max)
        return mlb_fail(MLB_ERR_ARG, "SDS timestep range [%d, %d] must lie within [0, 999] and be ordered", o.t_min, o.t_max);
    if (o.anneal_steps < 0 || (o.anneal_steps > 0 && (o.t_max_end < o.t_min || o.t_max_end > 999)))
        return mlb_fail(MLB_ERR_ARG, "SDS annealing: t_max_end %d must lie within [t_min %d, 999] over %ld >= 0 steps",
                        o.t_max_end, o.t_min, o.anneal_steps);
    if (!isfinite(o.guidance_scale)) return mlb_fail(MLB_ERR_ARG, "SDS guidance scale is not finite");
    if ((unsigned)o.weighting > MLB_SDS_W_FANTASIA2) return mlb_fail(MLB_ERR_ARG, "unknown SDS weighting %d", (int)o.weighting);
    return MLB_OK;
}

mlb_status mlb_sds_create(const mlb_unet* unet, const mlb_vae* vae, float scaling_factor, const float* ac, int v_prediction,
                          const mlb_sds_options* opt, mlb_sds** out) {
    if (!out || !unet || !ac) return mlb_fail(MLB_ERR_ARG, "mlb_sds_create: NULL argument");
    *out = NULL;
    mlb_sds_options o = opt ? *opt : mlb_sds_default_options();
    MLB_TRY(mlb_sds_options_check(&o));
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
    if (s->emb_dev) s->emb_be->release(s->emb_dev);
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
    s->emb_stale = 1;
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

// The table a model runs on when its inputs live on be's device: its own (mirror_ops: a GPU copy,
// or the CPU's bf16 / 16-bit-weight ops), else an fp32 CPU model runs on be itself (the CPU's table,
// or a test's guarded one); it must be on be's device.
static mlb_status model_table(const mlb_backend* own, const mlb_backend* be, const char* what, const mlb_backend** out) {
    *out = own ? own : be;
    if ((*out)->device != be->device)
        return mlb_fail(MLB_ERR_ARG, "SDS: the inputs are on the %s, the %s runs on the %s", mlb_device_name(be->device),
                        what, mlb_device_name((*out)->device));
    return MLB_OK;
}

const mlb_backend* mlb_sds_images_table(const mlb_sds* s, int C) {
    const mlb_backend* cpu = mlb_backend_cpu();
    if (!s) return cpu;
    const mlb_backend* t = s->vae && C != s->unet->cfg.in_channels ? s->vae->mirror_ops : s->unet->mirror_ops;
    return t ? t : cpu;
}

// The trace's values (sds.h), brought to the host: the latents, the UNet's outputs and the
// denoising errors against the noise (hnoise, the host's copy).
static mlb_status trace_fill(mlb_sds_trace* tr, const mlb_backend* be, const float* z, const float* x2, const float* e2,
                             const float* hnoise, const float* wt, const int* ts, int B, size_t n) {
    const size_t nall = (size_t)B * n;
    if (tr->latent) MLB_TRY(be->download(tr->latent, z, nall));
    if (tr->noisy_latent) MLB_TRY(be->download(tr->noisy_latent, x2, nall));
    if (tr->w) memcpy(tr->w, wt, (size_t)B * sizeof(float));
    if (tr->t) memcpy(tr->t, ts, (size_t)B * sizeof(int));
    int errs = tr->err_cond || tr->err_uncond;
    if (!tr->eps_cond && !tr->eps_uncond && !errs) return MLB_OK;
    float* e = malloc(2 * nall * sizeof(float));
    if (!e) return mlb_fail(MLB_ERR_NOMEM, "out of memory for the SDS trace");
    mlb_status st = be->download(e, e2, 2 * nall);
    if (!st && tr->eps_cond) memcpy(tr->eps_cond, e, nall * sizeof(float));
    if (!st && tr->eps_uncond) memcpy(tr->eps_uncond, e + nall, nall * sizeof(float));
    for (int b = 0; !st && errs && b < B; b++) {
        double ec = 0, eu = 0;
        for (size_t i = 0; i < n; i++) {
            double dc = (double)e[b * n + i] - hnoise[b * n + i], du = (double)e[nall + b * n + i] - hnoise[b * n + i];
            ec += dc * dc;
            eu += du * du;
        }
        if (tr->err_cond) tr->err_cond[b] = ec / (double)n;
        if (tr->err_uncond) tr->err_uncond[b] = eu / (double)n;
    }
    free(e);
    return st;
}

// The embeddings on be's device (uploaded when they or the device changed).
static mlb_status embeddings_on(mlb_sds* s, const mlb_backend* be) {
    const size_t nc = (size_t)s->Tc * s->Dc;
    if (s->emb_dev && (s->emb_be->alloc != be->alloc || s->emb_stale)) {
        s->emb_be->release(s->emb_dev);
        s->emb_dev = NULL;
    }
    if (s->emb_dev) return MLB_OK;
    MLB_TRY(be->alloc(&s->emb_dev, (MLB_SDS_N_VIEWS + 1) * nc));
    s->emb_be = be;
    s->emb_stale = 0;
    mlb_status st = MLB_OK;
    for (int v = 0; !st && v < MLB_SDS_N_VIEWS; v++) st = be->upload(s->emb_dev + v * nc, s->cond[v] ? s->cond[v] : s->cond[0], nc);
    if (!st) st = be->upload(s->emb_dev + MLB_SDS_N_VIEWS * nc, s->uncond, nc);
    if (st) {
        be->release(s->emb_dev);
        s->emb_dev = NULL;
    }
    return st;
}

static mlb_status step_on(mlb_sds* s, const mlb_backend* be, const mlb_sds_input* in, float* grad_images, float* loss,
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
    const mlb_backend *vbe = NULL, *ube;
    const mlb_vae* vm = s->vae && s->vae->mirror ? s->vae->mirror : s->vae;   // the copies the tables run
    const mlb_unet* um = s->unet->mirror ? s->unet->mirror : s->unet;
    if (C != Lc) MLB_TRY(model_table(s->vae->mirror_ops, be, "VAE", &vbe));
    MLB_TRY(model_table(s->unet->mirror_ops, be, "UNet", &ube));
    MLB_TRY(embeddings_on(s, be));
    const size_t n = (size_t)Lc * h * w, nimg = (size_t)B * C * H * W, nall = (size_t)B * n;
    const size_t nc = (size_t)s->Tc * s->Dc;
    // on be's device: z | noise | x2 [2B] | e2 [2B] | ctx [2B] | grad | dz | the loss's 3 floats;
    // the host draws t, the device the noise (the caller's noise is uploaded), the host reads the loss
    const size_t need = nall * 8 + 2 * (size_t)B * nc + 3;
    float *buf = NULL, *img = NULL, *hnoise = NULL;
    int ts[MLB_SDS_MAX_BATCH];
    float tt[2 * MLB_SDS_MAX_BATCH], wt[MLB_SDS_MAX_BATCH], sa[2 * MLB_SDS_MAX_BATCH], sb[2 * MLB_SDS_MAX_BATCH];
    const double two = 2.0, minus_one = -1.0, sf = s->scaling_factor;
    mlb_status st = be->alloc(&buf, need);
    if (st) goto done;
    float *z = buf, *noise = z + nall, *x2 = noise + nall, *e2 = x2 + 2 * nall, *ctx = e2 + 2 * nall;
    float *grad = ctx + 2 * (size_t)B * nc, *dz = grad + nall, *sumsq = dz + nall;
    // 1. the latent: the input itself, or the VAE's mean of 2 x - 1, times the scaling factor
    if (C == Lc) st = be->copy(z, in->images, nall);
    else {
        if ((st = be->alloc(&img, nimg)) != MLB_OK) goto done;
        if ((st = be->affine_columns(img, in->images, nimg, 1, &two, &minus_one, 1)) != MLB_OK) goto done;
        if ((st = mlb_vae_encode_mean(vbe, vm, img, B, H, W, z, &s->cache)) != MLB_OK) goto done;
        st = be->affine_columns(z, z, nall, 1, &sf, NULL, 1);
    }
    if (st) goto done;
    // 2. timesteps (the host's) and noise, x_t, the batch [cond x B, uncond x B]
    for (int b = 0; b < B; b++) {
        int t;
        if (in->t) {
            t = in->t[b];
            if (t < 0 || t > 999) { st = mlb_fail(MLB_ERR_ARG, "SDS timestep %d outside 0..999", t); goto done; }
        } else
            t = s->opt.t_min + (int)mlb_rng_below(s->opt.seed, SDS_STREAM_T, (uint64_t)in->step * MLB_SDS_MAX_BATCH + (uint64_t)(first + b),
                                                  (uint32_t)(mlb_sds_t_max_at(&s->opt, in->step) - s->opt.t_min + 1));
        ts[b] = t;
        tt[b] = tt[B + b] = (float)t;
        wt[b] = mlb_sds_weight(s->opt.weighting, s->ac[t], in->step, s->opt.coarse_iter);
        sa[b] = sa[B + b] = (float)sqrt((double)s->ac[t]);   // schedule.h's add_noise and v_to_eps
        sb[b] = sb[B + b] = (float)sqrt(1.0 - (double)s->ac[t]);
        if (!in->noise && (st = be->fill_normal(noise + b * n, n, s->opt.seed, SDS_STREAM_NOISE + (uint64_t)in->step,
                                                (uint64_t)(first + b) * n)) != MLB_OK)
            goto done;
        int v = in->views ? in->views[b] : MLB_SDS_VIEW_NONE;
        if (v < 0 || v >= MLB_SDS_N_VIEWS) { st = mlb_fail(MLB_ERR_ARG, "SDS view %d out of range", v); goto done; }
        if ((st = be->copy(ctx + (size_t)b * nc, s->emb_dev + v * nc, nc)) != MLB_OK) goto done;
        if ((st = be->copy(ctx + (size_t)(B + b) * nc, s->emb_dev + MLB_SDS_N_VIEWS * nc, nc)) != MLB_OK) goto done;
    }
    if (in->noise && (st = be->upload(noise, in->noise, nall)) != MLB_OK) goto done;
    if ((st = be->axpby_rows(x2, z, noise, B, n, sa, sb)) != MLB_OK) goto done;
    if ((st = be->copy(x2 + nall, x2, nall)) != MLB_OK) goto done;
    // 3. the UNet, eps from v, guidance, the weighted gradient and d loss / d latent
    if ((st = mlb_unet_forward(ube, um, e2, x2, tt, ctx, 2 * B, h, w, s->Tc, NULL, NULL)) != MLB_OK) goto done;
    if (s->v_prediction && (st = be->axpby_rows(e2, e2, x2, 2 * B, n, sa, sb)) != MLB_OK) goto done;
    if (tr) {   // the trace's errors against the noise, on the host
        if (!(hnoise = malloc(nall * sizeof(float)))) { st = mlb_fail(MLB_ERR_NOMEM, "out of memory for the SDS trace"); goto done; }
        if ((st = be->download(hnoise, noise, nall)) != MLB_OK) goto done;
        if ((st = trace_fill(tr, be, z, x2, e2, hnoise, wt, ts, B, n)) != MLB_OK) goto done;
    }
    float div = C == Lc ? (float)total : 1.0f, mul = C == Lc ? 1.0f : s->scaling_factor / (float)total;
    if ((st = be->sds_grad(e2, grad, grad_images ? dz : NULL, sumsq, noise, B, n, s->opt.guidance_scale, wt, div, mul)))
        goto done;
    if (tr && tr->eps_guided && (st = be->download(tr->eps_guided, e2, nall))) goto done;
    if (tr && tr->grad_latent && (st = be->download(tr->grad_latent, grad, nall))) goto done;
    if (loss) {
        float l3[3];
        if ((st = be->download(l3, sumsq, 3)) != MLB_OK) goto done;
        *loss = (float)(0.5 * mlb_sumsq_join(l3) / total);
    }
    // 4. d loss / d images, on be's device
    if (grad_images) {
        if (C == Lc) st = be->add(grad_images, dz, nall);
        else {
            if ((st = be->zero(img, nimg)) != MLB_OK) goto done;
            if ((st = mlb_vae_encode_backward_mean(vbe, vm, &s->cache, dz, img)) != MLB_OK) goto done;
            if ((st = be->affine_columns(img, img, nimg, 1, &two, NULL, 1)) != MLB_OK) goto done;   // d(2x - 1)/dx
            st = be->add(grad_images, img, nimg);
        }
    }
done:
    free(hnoise);
    if (buf) be->release(buf);
    if (img) be->release(img);
    return st;
}

mlb_status mlb_sds_step(mlb_sds* s, const mlb_backend* be, const mlb_sds_input* in, float* grad_images, float* loss,
                        mlb_sds_trace* tr) {
    if (be) return step_on(s, be, in, grad_images, loss, tr);
    if (!s || !in || !in->images) return mlb_fail(MLB_ERR_ARG, "mlb_sds_step: NULL argument");
    be = mlb_sds_images_table(s, in->C);
    if (be->device == MLB_DEVICE_CPU) return step_on(s, mlb_backend_cpu(), in, grad_images, loss, tr);
    // the VAE is on a GPU: the images go up, the step runs there, the gradient comes down (added)
    const size_t nimg = (size_t)in->B * in->C * in->H * in->W;
    float *d = NULL, *dg = NULL;
    mlb_sds_input on = *in;
    mlb_status st = be->alloc(&d, nimg);
    if (!st) st = be->upload(d, in->images, nimg);
    if (!st && grad_images) st = be->alloc(&dg, nimg);
    if (!st && grad_images) st = be->upload(dg, grad_images, nimg);
    on.images = d;
    if (!st) st = step_on(s, be, &on, dg, loss, tr);
    if (!st && grad_images) st = be->download(grad_images, dg, nimg);
    if (d) be->release(d);
    if (dg) be->release(dg);
    return st;
}
