// Full-size Stable Diffusion 1.5 on this machine with random weights in the real names: writes
// the UNet (single-file `model.diffusion_model.*` names, F16), the CLIP ViT-L text encoder
// (`cond_stage_model.transformer.text_model.*`, F16) and the VAE (`first_stage_model.*`, F32 via
// mlb_vae_save) under a temporary folder in /tmp (deleted at the end unless --keep), loads them the
// way the program does and times: text encoding of 2 prompts, one UNet forward (batch 2 = cond +
// uncond), the VAE encoder forward + backward; peak resident memory and the achieved GFLOP/s
// against this machine's measured SGEMM rate. Prints a table (docs/sd_bench.md).
//   build/bench/bench_sd [--latent 64] [--batch 2] [--steps 1] [--vae 512] [--no-text] [--keep] [--dir /tmp]
//                        [--precision fp32|bf16] [--single-file OUT.safetensors]
// --single-file also merges the three into one F16 single-file checkpoint (what stable-diffusion.cpp
// and `matlaber sd txt2img -m` load; bench/compare_sdcpp.sh).
// --vae 0 skips the VAE; --latent 0 skips the UNet. --precision bf16 runs the UNet's and VAE's
// linear, conv and attention GEMMs with bf16 operands (mlb_unet_use_device / mlb_vae_use_device on
// the CPU), the UNet's weights kept in bf16 as the program loads them (mlb_unet_options.bf16_weights).
#include <cblas.h>
#include <math.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <unistd.h>
#include "bench_util.h"
#include "matlaber/backend.h"
#include "matlaber/half.h"
#include "matlaber/progress.h"
#include "matlaber/rng.h"
#include "matlaber/text_encoder.h"
#include "matlaber/threads.h"
#include "matlaber/unet.h"
#include "matlaber/unet_random.h"
#include "matlaber/vae.h"

// ---- CLIP ViT-L/14 text encoder, HF CLIP names inside an SD 1.x single file --------------------------
#define TXT_PREFIX "cond_stage_model.transformer.text_model."
static int write_text(const char* path, int W, int layers, int M, int vocab, int nctx, size_t* n_params) {
    int per = 16, n = 4 + per * layers, k = 0;
    mlb_st_entry* e = calloc((size_t)n, sizeof *e);
    char (*names)[128] = calloc((size_t)n, sizeof *names);
    int64_t (*shapes)[2] = calloc((size_t)n, sizeof *shapes);
    uint16_t** data = calloc((size_t)n, sizeof *data);
    float* tmp = malloc((size_t)vocab * W * sizeof(float));
    if (!e || !names || !shapes || !data || !tmp) return 1;
    static const char* leaf[] = {"layer_norm1.weight", "layer_norm1.bias", "self_attn.q_proj.weight", "self_attn.q_proj.bias",
        "self_attn.k_proj.weight", "self_attn.k_proj.bias", "self_attn.v_proj.weight", "self_attn.v_proj.bias",
        "self_attn.out_proj.weight", "self_attn.out_proj.bias", "layer_norm2.weight", "layer_norm2.bias",
        "mlp.fc1.weight", "mlp.fc1.bias", "mlp.fc2.weight", "mlp.fc2.bias"};
    int64_t d0[16] = {W, W, W, W, W, W, W, W, W, W, W, W, M, M, W, W}, d1[16] = {0, 0, W, 0, W, 0, W, 0, W, 0, 0, 0, W, 0, M, 0};
    *n_params = 0;
    for (int t = -1; t < layers + 1; t++) {
        int cnt = (t < 0 || t == layers) ? 2 : per;
        for (int j = 0; j < cnt; j++, k++) {
            int64_t a, b;
            int norm;
            if (t < 0) {
                snprintf(names[k], 128, TXT_PREFIX "embeddings.%s", j ? "position_embedding.weight" : "token_embedding.weight");
                a = j ? nctx : vocab; b = W; norm = 0;
            } else if (t == layers) {
                snprintf(names[k], 128, TXT_PREFIX "final_layer_norm.%s", j ? "bias" : "weight");
                a = W; b = 0; norm = j == 0;
            } else {
                snprintf(names[k], 128, TXT_PREFIX "encoder.layers.%d.%s", t, leaf[j]);
                a = d0[j]; b = d1[j]; norm = strstr(leaf[j], "norm") && !b && strstr(leaf[j], "weight");
            }
            size_t cntv = (size_t)a * (b ? b : 1);
            float sd = b ? (t < 0 ? 0.02f : 1.0f / sqrtf((float)b)) : 0.05f;
            mlb_rng_fill_normal(tmp, cntv, 9, (uint64_t)k, 0, norm ? 1.0f : 0.0f, sd);
            data[k] = malloc(cntv * 2);
            if (!data[k]) return 1;
            for (size_t i = 0; i < cntv; i++) data[k][i] = mlb_f32_to_f16(tmp[i]);
            shapes[k][0] = a; shapes[k][1] = b;
            e[k] = (mlb_st_entry){names[k], MLB_DT_F16, b ? 2 : 1, shapes[k], data[k]};
            *n_params += cntv;
        }
    }
    mlb_status s = mlb_st_write(path, e, (size_t)k, NULL, 0);
    for (int i = 0; i < k; i++) free(data[i]);
    free(e); free(names); free(shapes); free(data); free(tmp);
    return s != MLB_OK;
}

// ---- GEMM FLOP counts -------------------------------------------------------------------------------
// UNet: every weight tensor of >= 2 dims applied at its resolution (2 FLOPs per weight per token;
// attn2's to_k/to_v over the Tc context tokens, time_emb_proj once), plus attention scores and
// values: 4 T^2 C (self) and 4 T Tc C (cross) per transformer. GroupNorm/SiLU/adds not counted.
static double unet_flops(const mlb_unet_config* c, int N, int H, int W, int Tc) {
    size_t n = 0;
    mlb_unet_tensor_specs(c, NULL, 0, &n);
    mlb_unet_tensor_spec* sp = calloc(n, sizeof *sp);
    mlb_unet_tensor_specs(c, sp, n, &n);
    double f = 0;
    for (size_t i = 0; i < n; i++) {
        const char* nm = sp[i].name;
        if (sp[i].ndim < 2) continue;
        int lvl = 0, up = 0;
        if (sscanf(nm, "down_blocks.%d", &lvl) == 1) { if (strstr(nm, "downsamplers")) lvl++; }
        else if (sscanf(nm, "up_blocks.%d", &up) == 1) { lvl = c->n_levels - 1 - up; if (strstr(nm, "upsamplers")) lvl--; }
        else if (!strncmp(nm, "mid_block", 9)) lvl = c->n_levels - 1;
        double T = (double)(H >> lvl) * (W >> lvl);
        if (!strncmp(nm, "time_embedding", 14) || strstr(nm, "time_emb_proj")) T = 1;
        if (strstr(nm, "attn2.to_k") || strstr(nm, "attn2.to_v")) T = Tc;
        f += 2.0 * sp[i].n * T;
        if (strstr(nm, "attn1.to_q")) f += 4.0 * T * T * sp[i].shape[0];
        if (strstr(nm, "attn2.to_q")) f += 4.0 * T * Tc * sp[i].shape[0];
    }
    free(sp);
    return f * N;
}

// VAE encoder at H x W: convs (forward; the backward to the image is the same count again) and the
// mid attention (4 T^2 C + 8 T C^2 forward, about 10 T^2 C + 8 T C^2 backward).
static void vae_flops(const mlb_vae_config* g, int H, int W, double* fwd, double* bwd) {
    double f = 0, b = 0;
#define CV(C, OC, K) do { double x_ = 2.0 * (OC) * (C) * (K) * (K) * (double)H * W; f += x_; b += x_; } while (0)
    CV(g->in_channels, g->block_out[0], 3);
    int ch = g->block_out[0];
    for (int l = 0; l < g->n_levels; l++) {
        int co = g->block_out[l];
        for (int j = 0; j < g->layers_per_block; j++) {
            CV(ch, co, 3); CV(co, co, 3);
            if (ch != co) CV(ch, co, 1);
            ch = co;
        }
        if (l < g->n_levels - 1) { H /= 2; W /= 2; CV(co, co, 3); }
    }
    for (int k = 0; k < 4; k++) CV(ch, ch, 3);
    double T = (double)H * W;
    f += 4 * T * T * ch + 8 * T * ch * (double)ch;
    b += 10 * T * T * ch + 8 * T * ch * (double)ch;
    CV(ch, 2 * g->latent_channels, 3);
    CV(2 * g->latent_channels, 2 * g->latent_channels, 1);
#undef CV
    *fwd = f;
    *bwd = b;
}

// The three files merged into one SD 1.x single-file checkpoint at `path`, every tensor F16 (the VAE's
// F32 rounded to nearest), the UNet's metadata kept: what other programs load (bench/compare_sdcpp.sh
// runs stable-diffusion.cpp on it).
static int write_single_file(const char* path, const char* const parts[3]) {
    mlb_safetensors* st[3] = {NULL, NULL, NULL};
    size_t total = 0;
    int rc = 1;
    for (int i = 0; i < 3; i++) {
        if (mlb_st_open(&st[i], parts[i])) goto done;
        total += mlb_st_count(st[i]);
    }
    mlb_st_entry* e = calloc(total, sizeof *e);
    void** owned = calloc(total, sizeof *owned);
    size_t n = 0;
    if (!e || !owned) goto free_entries;
    for (int i = 0; i < 3; i++)
        for (size_t j = 0; j < mlb_st_count(st[i]); j++, n++) {
            const mlb_st_tensor* t = mlb_st_tensor_at(st[i], j);
            e[n] = (mlb_st_entry){t->name, MLB_DT_F16, t->ndim, t->shape, t->data};
            if (t->dtype == MLB_DT_F16) continue;
            float* f = malloc(t->nelem * sizeof(float));
            owned[n] = malloc(t->nelem * 2);
            if (!f || !owned[n] || mlb_st_read_f32(st[i], t->name, f, t->nelem)) { free(f); goto free_entries; }
            mlb_f32_to_f16_array(owned[n], f, t->nelem);
            free(f);
            e[n].data = owned[n];
        }
    size_t nm = mlb_st_metadata_count(st[0]);
    mlb_st_meta* meta = calloc(nm ? nm : 1, sizeof *meta);
    for (size_t j = 0; meta && j < nm; j++) mlb_st_metadata_at(st[0], j, &meta[j].key, &meta[j].value);
    rc = !meta || mlb_st_write(path, e, n, meta, nm) != MLB_OK;
    free(meta);
free_entries:
    if (rc) fprintf(stderr, "bench_sd: writing %s: %s\n", path, mlb_last_error());
    for (size_t j = 0; owned && j < total; j++) free(owned[j]);
    free(owned);
    free(e);
done:
    for (int i = 0; i < 3; i++) mlb_st_close(st[i]);
    return rc;
}

typedef struct { char what[64]; double gen_s, load_s, run_s, gflop, mb; char note[96]; } row;

static int fail(const char* what) {
    fprintf(stderr, "bench_sd: %s: %s\n", what, mlb_last_error());
    return 1;
}

int main(int argc, char** argv) {
    mlb_runtime_restart(argv);   // the program's runtime settings (threads.h)
    int latent = 64, batch = 2, steps = 1, vae_size = 512, keep = 0, text = 1;
    mlb_gemm_precision prec = MLB_GEMM_FP32;
    const char* base = "/tmp";
    const char* single = NULL;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--keep")) keep = 1;
        else if (!strcmp(argv[i], "--no-text")) text = 0;
        else if (i + 1 < argc && !strcmp(argv[i], "--latent")) latent = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--batch")) batch = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--steps")) steps = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--vae")) vae_size = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--dir")) base = argv[++i];
        else if (i + 1 < argc && !strcmp(argv[i], "--single-file")) single = argv[++i];
        else if (i + 1 < argc && !strcmp(argv[i], "--precision")) {
            if (mlb_gemm_precision_parse(argv[++i], &prec)) return fail("--precision");
        } else {
            fprintf(stderr, "usage: bench_sd [--latent 64] [--batch 2] [--steps 1] [--vae 512] [--no-text] [--keep] "
                            "[--dir /tmp] [--precision fp32|bf16] [--single-file OUT.safetensors]\n");
            return 2;
        }
    }
    if (single && (!text || latent <= 0 || vae_size <= 0)) {
        fprintf(stderr, "bench_sd: --single-file needs all three parts (no --no-text, --latent and --vae > 0)\n");
        return 2;
    }
    if (steps < 1) steps = 1;
    if (batch < 1) batch = 1;
    int threads = omp_get_max_threads();
    mlb_set_threads(threads);
    const char* wp = getenv("OMP_WAIT_POLICY");
    printf("SD 1.5 full size, random weights; %d threads, OpenBLAS kernels %s, OMP_WAIT_POLICY %s\n", threads,
           mlb_blas_corename(), wp ? wp : "(unset)");
    double rate = bench_sgemm_rate(4096, 320, 2880);
    printf("sgemm 4096x2880 . 2880x320: %.1f GFLOP/s\n", rate);
    printf("UNet and VAE GEMMs: %s%s\n", mlb_gemm_precision_name(prec),
           prec == MLB_GEMM_BF16 ? (mlb_gemm_bf16_native() ? " (linear, conv and attention, AVX-512 BF16)" : " asked, no AVX-512 BF16: fp32")
                                 : "");
    char dir[512];
    snprintf(dir, sizeof dir, "%s/mlb_bench_sd_XXXXXX", base);
    if (!mkdtemp(dir)) { perror("mkdtemp"); return 1; }
    printf("weights in %s%s\n\n", dir, keep ? " (kept)" : " (deleted at the end)");
    char pu[600], pt[600], pv[600];
    snprintf(pu, sizeof pu, "%s/unet.safetensors", dir);
    snprintf(pt, sizeof pt, "%s/text.safetensors", dir);
    snprintf(pv, sizeof pv, "%s/vae.safetensors", dir);
    row rows[3];
    int nr = 0, rc = 0;

    if (text) {   // ---- text encoder: 2 prompts of 77 tokens ----
        row* r = &rows[nr++];
        memset(r, 0, sizeof *r);
        size_t np = 0;
        double t0 = mlb_now_seconds();
        if (write_text(pt, 768, 12, 3072, 49408, 77, &np)) { rc = fail("writing the text encoder"); goto out; }
        double t1 = mlb_now_seconds();
        mlb_text_encoder* te = NULL;
        if (mlb_text_encoder_load(pt, NULL, &te)) { rc = fail("loading the text encoder"); goto out; }
        double t2 = mlb_now_seconds();
        int tok[2 * 77];
        for (int b = 0; b < 2; b++)
            for (int i = 0; i < 77; i++) tok[b * 77 + i] = i == 0 ? 49406 : i < 8 + b ? 320 + 17 * i + b : 49407;
        float* out = malloc((size_t)2 * 77 * 768 * sizeof(float));
        double best = 1e30;
        for (int rep = 0; rep < 3; rep++) {
            double a = mlb_now_seconds();
            // the CPU benchmark: the CPU's fp32 table
            if (mlb_text_encoder_forward(mlb_backend_cpu(), te, tok, 2, 77, out, NULL, 0)) { rc = fail("text forward"); free(out); mlb_text_encoder_free(te); goto out; }
            double d = mlb_now_seconds() - a;
            if (d < best) best = d;
        }
        double layer = 2.0 * (4.0 * 768 * 768 + 2.0 * 768 * 3072) * 77 + 4.0 * 77 * 77 * 768;
        snprintf(r->what, sizeof r->what, "text encoder, 2 x 77 tokens");
        r->gen_s = t1 - t0; r->load_s = t2 - t1; r->run_s = best; r->gflop = 2 * 12 * layer / 1e9; r->mb = bench_peak_mb();
        snprintf(r->note, sizeof r->note, "%zu M params (%s heads %d)", np / 1000000, te->heads_from, te->n_heads);
        free(out);
        mlb_text_encoder_free(te);
    }
    if (latent > 0) {   // ---- UNet ----
        row* r = &rows[nr++];
        memset(r, 0, sizeof *r);
        mlb_unet_config c = mlb_unet_sd15_config();
        mlb_unet_random_options o = mlb_unet_random_default_options();
        o.layout = MLB_UNET_LAYOUT_LDM;
        o.dtype = MLB_DT_F16;
        o.seed = 1;
        double t0 = mlb_now_seconds();
        if (mlb_unet_write_random(&c, &o, pu)) { rc = fail("writing the UNet"); goto out; }
        double t1 = mlb_now_seconds();
        mlb_unet* u = NULL;
        mlb_unet_options uo = mlb_unet_options_for(MLB_DEVICE_CPU, prec);   // as the program loads it
        if (mlb_unet_load(pu, &uo, &u)) { rc = fail("loading the UNet"); goto out; }
        if (mlb_unet_use_device(u, MLB_DEVICE_CPU, prec)) { rc = fail("UNet precision"); mlb_unet_free(u); goto out; }
        double t2 = mlb_now_seconds();
        size_t nx = (size_t)batch * 4 * latent * latent, nc = (size_t)batch * 77 * 768;
        float *x = malloc(nx * 4), *y = malloc(nx * 4), *ctx = malloc(nc * 4), *tt = malloc((size_t)batch * 4);
        mlb_rng_fill_normal(x, nx, 2, 1, 0, 0, 1);
        mlb_rng_fill_normal(ctx, nc, 2, 2, 0, 0, 1);
        for (int b = 0; b < batch; b++) tt[b] = 500;
        double best = 1e30;
        for (int s = 0; s < steps; s++) {
            double a = mlb_now_seconds();
            if (mlb_unet_forward(NULL, u, y, x, tt, ctx, batch, latent, latent, 77, NULL, NULL)) { rc = fail("UNet forward"); break; }
            double d = mlb_now_seconds() - a;
            if (d < best) best = d;
        }
        snprintf(r->what, sizeof r->what, "UNet forward, %d x %d², s/step", batch, latent);
        r->gen_s = t1 - t0; r->load_s = t2 - t1; r->run_s = best; r->gflop = unet_flops(&u->cfg, batch, latent, latent, 77) / 1e9;
        r->mb = bench_peak_mb();
        snprintf(r->note, sizeof r->note, "%.1f M params, F16 file, best of %d", u->n_params / 1e6, steps);
        free(x); free(y); free(ctx); free(tt);
        mlb_unet_free(u);
        if (rc) goto out;
    }
    if (vae_size > 0) {   // ---- VAE encoder forward + backward ----
        row* r = &rows[nr++];
        memset(r, 0, sizeof *r);
        mlb_vae_config g = mlb_vae_sd_config();
        mlb_vae* v = NULL;
        double t0 = mlb_now_seconds();
        if (mlb_vae_create(NULL, &g, &v)) { rc = fail("creating the VAE"); goto out; }
        mlb_vae_init_random(v, 1, 1.0f);
        if (mlb_vae_save(v, pv, MLB_VAE_LAYOUT_LDM, "first_stage_model.", NULL)) { rc = fail("writing the VAE"); mlb_vae_free(v); goto out; }
        mlb_vae_free(v);
        v = NULL;
        double t1 = mlb_now_seconds();
        if (mlb_vae_load(pv, NULL, &v)) { rc = fail("loading the VAE"); goto out; }
        if (mlb_vae_use_device(v, MLB_DEVICE_CPU, prec)) { rc = fail("VAE precision"); mlb_vae_free(v); goto out; }
        double t2 = mlb_now_seconds();
        int S = vae_size, h = mlb_vae_latent_size(&g, S);
        size_t ni = (size_t)3 * S * S, nz = (size_t)4 * h * h;
        float *img = malloc(ni * 4), *dimg = calloc(ni, 4), *mean = malloc(nz * 4), *dm = malloc(nz * 4);
        mlb_rng_fill_uniform(img, ni, 3, 1, 0, -1, 1);
        mlb_rng_fill_normal(dm, nz, 3, 2, 0, 0, 1);
        mlb_vae_cache cache = {0};
        double a = mlb_now_seconds();
        if (mlb_vae_encode(NULL, v, img, 1, S, S, mean, NULL, &cache) || mlb_vae_encode_backward(NULL, v, &cache, dm, NULL, dimg, NULL))
            rc = fail("VAE encode/backward");
        double d = mlb_now_seconds() - a;
        double ff, fb;
        vae_flops(&g, S, S, &ff, &fb);
        snprintf(r->what, sizeof r->what, "VAE encode fwd + bwd, 1 x %d²", S);
        r->gen_s = t1 - t0; r->load_s = t2 - t1; r->run_s = d; r->gflop = (ff + fb) / 1e9; r->mb = bench_peak_mb();
        snprintf(r->note, sizeof r->note, "%.1f M params, F32 file, cache %.0f MB", v->n_params / 1e6, cache.capacity * 4.0 / 1e6);
        mlb_vae_cache_free(&cache);
        free(img); free(dimg); free(mean); free(dm);
        mlb_vae_free(v);
    }
out:
    printf("| stage | write s | load s | run s | GEMM GFLOP | GFLOP/s | of sgemm | peak RSS MB | note |\n");
    printf("|---|--:|--:|--:|--:|--:|--:|--:|---|\n");
    for (int i = 0; i < nr; i++) {
        if (rows[i].run_s <= 0) continue;
        double g = rows[i].gflop / rows[i].run_s;
        printf("| %s | %.1f | %.1f | %.2f | %.0f | %.1f | %.0f%% | %.0f | %s |\n", rows[i].what, rows[i].gen_s, rows[i].load_s,
               rows[i].run_s, rows[i].gflop, g, 100 * g / rate, rows[i].mb, rows[i].note);
    }
    printf("\npeak resident memory: %.0f MB (getrusage ru_maxrss)\n", bench_peak_mb());
    if (single && !rc) {
        const char* const parts[3] = {pu, pt, pv};
        rc = write_single_file(single, parts);
        if (!rc) printf("single-file checkpoint (F16): %s\n", single);
    }
    if (!keep) {
        unlink(pu); unlink(pt); unlink(pv);
        char cj[620];
        snprintf(cj, sizeof cj, "%s/config.json", dir);
        unlink(cj);
        if (rmdir(dir)) perror(dir);
    }
    return rc;
}
