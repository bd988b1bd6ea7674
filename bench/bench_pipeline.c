// Seconds per iteration of the pipeline's two stages (src/pipeline/pipeline.c) and where they go
// (docs/benchmarks.md). The stage objects are built as the pipeline builds them:
//   geometry:   hash-grid geometry net (mlb_geometry_default) initialised to the ellipsoid, a
//               "64" tet grid (32 cells), a raster context; one iteration = sample_views →
//               zero_grad + mlb_geofit_forward (the render) → g->loss (guidance) → mlb_geofit_backward
//               (render + marching tets + net, SDF regulariser 0.2) → geometry_net_update (Adam),
//               the pieces of mlb_geometry_guided_step called one by one;
//   appearance: the material net (latent mode, the built-in BRDF prior) on the geometry net's
//               extracted surface under the sky / studio / overcast pool (cube 128); one iteration =
//               sample_views → zero_grad + mlb_appearance_render → g->loss → mlb_appearance_backward
//               → 4096-point material smoothness (0.03, σ 0.01) → material_net_update.
// Guidance: "images" (a 12-view data set rendered from a sphere at 512², loaded at each size, 4
// views per step), "tiny" (SDS with the tests' tiny random UNet + a block_out 32,32,64,64 VAE, 4
// views) and, with --sd15, "sd15" (SDS with full-size random SD 1.5: UNet F16 and VAE written to a
// temporary folder and loaded as bench_sd does, 1 view per step, deleted at the end). SDS geometry
// has two phases: "latent" (renders area-resized to 64² [normal, mask] latents) and "vae" (normal
// maps as colours through the VAE encoder); the appearance stage always goes through the VAE.
// Every configuration restarts from the same network parameters and a fresh Adam state, runs one
// warm-up iteration, then --iters timed ones (mean). The "UNet" column: one mlb_unet_forward of
// the same batch (2 × views: cond + uncond) and latent size timed separately after the loop —
// the share of the guidance column that is the UNet; the rest of an SDS "vae" guidance is the VAE
// encoder forward + backward. It is measured once per model, batch and latent size (the latent
// phase's 64² call is the same at every render size), so it can differ from the guidance mean by
// the run-to-run noise.
// Run time on the 2-core machine: the default about 5 min (--iters 3: 9 min), most of it the tiny
// UNet at 64² latents; --sd15 --no-images --no-tiny: 3 min (docs/benchmarks.md).
//   build/bench/bench_pipeline [--iters 1] [--sizes 64,128,512] [--sd15] [--sd15-sizes 512]
//                              [--no-images] [--no-tiny] [--stage both|geometry|appearance]
//                              [--init-iters 100] [--dir /tmp] [--sd15-views 1] [--device cpu|cuda]
//                              [--precision fp16]
// --device cuda moves the SD 1.5 UNet and VAE to the GPU (mlb_unet_use_device, mlb_vae_use_device) at
// --precision, and as the pipeline does both stages' rendering, networks (mlb_field_use_device),
// optimisers, shading and marching tets (the stages on the GPU's table, docs/cuda.md). On the CPU, --precision bf16 gives the UNet and
// VAE the CPU's bf16 GEMMs (as `matlaber --precision bf16` and the cpu preset do).
// --sd15 --generate PRESET (e.g. cpu) skips the table and runs a whole generation end to end with
// that preset (mlb_pipeline_preset) and the random SD 1.5 (random prompt embeddings): the pipeline's
// own loop with its checkpoints, previews and the final .glb, in a run folder under --dir that is
// removed afterwards; it prints the wall time (--generate-geometry-lr X overrides the preset's
// geometry learning rate: random weights' gradients can empty the grid, docs/pipeline.md;
// --generate-scale F multiplies both stages' step counts, for a miniature of a long schedule).
// --paint MESH (with --generate PRESET) runs `matlaber paint --preset PRESET` instead: the appearance
// stage alone on that mesh (.obj/.glb; docs/paint.md), the same random SD 1.5.
#include <cblas.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>
#include "bench_util.h"
#include "matlaber/appearance.h"
#include "matlaber/brdf_ae.h"
#include "matlaber/cuda_ops.h"
#include "matlaber/device.h"
#include "matlaber/dmtet.h"
#include "matlaber/envmap.h"
#include "matlaber/geometry.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/guidance_image.h"
#include "matlaber/guidance_sds.h"
#include "matlaber/pipeline.h"
#include "matlaber/progress.h"
#include "matlaber/rng.h"
#include "matlaber/schedule.h"
#include "matlaber/threads.h"
#include "matlaber/unet.h"
#include "matlaber/unet_random.h"
#include "matlaber/vae.h"
#include "matlaber/views.h"

#define N_ENVS 3
#define LATENT_ITERS 1000000L   // SDS geometry steps below this are latent steps; "vae" steps start here
#define SMOOTH_POINTS 4096      // as the pipeline's appearance stage

static const char* const ENV_NAMES[N_ENVS] = {"sky", "studio", "overcast"};

// ---- a guidance under test ------------------------------------------------------------------
typedef struct {
    const char* name;        // "images", "tiny", "sd15"
    mlb_guidance* g;
    const mlb_unet* unet;    // SDS: for the UNet column (NULL for images)
    int Tc;                  // SDS: context tokens
    mlb_views* views;        // images: the data set at this size (owned)
} guide;

static void guide_free(guide* gd) {
    mlb_guidance_free(gd->g);
    if (gd->views) { mlb_views_free(gd->views); free(gd->views); }
    memset(gd, 0, sizeof *gd);
}

// An SDS object with random embeddings (cond and uncond, Tc tokens): what mlb_sds_create_from_model
// makes from a prompt, without a text encoder.
static mlb_sds* random_sds(const mlb_unet* u, const mlb_vae* vae, const float* ac, int Tc, uint64_t seed) {
    mlb_sds_options o = mlb_sds_default_options();
    mlb_sds* s = NULL;
    if (mlb_sds_create(u, vae, 0.18215f, ac, 0, &o, &s)) return NULL;
    int D = u->cfg.context_dim;
    float* e = malloc(sizeof(float) * (size_t)Tc * D);
    if (!e) { mlb_sds_free(s); return NULL; }
    mlb_rng_fill_normal(e, (size_t)Tc * D, seed, 1, 0, 0, 1);
    mlb_sds_set_cond(s, MLB_SDS_VIEW_NONE, e, Tc);
    mlb_rng_fill_normal(e, (size_t)Tc * D, seed, 2, 0, 0, 1);
    mlb_sds_set_uncond(s, e, Tc);
    free(e);
    return s;
}

// latent_iters: the geometry steps fed as 64² latents (the table passes LATENT_ITERS and picks each
// phase by the step number; a --generate run its preset's).
static mlb_status make_sds_guide(guide* gd, const char* name, const mlb_unet* u, const mlb_vae* vae, const float* ac,
                                 int Tc, int views, long latent_iters) {
    memset(gd, 0, sizeof *gd);
    gd->name = name;
    gd->unet = u;
    gd->Tc = Tc;
    mlb_guidance_sds_config gc = mlb_guidance_sds_default();
    gc.views = views;
    gc.latent_iters = (int)latent_iters;
    gc.n_envs = N_ENVS;
    gc.seed = 0;
    mlb_sds* a = random_sds(u, vae, ac, Tc, 1);
    mlb_sds* b = random_sds(u, vae, ac, Tc, 2);
    if (!a || !b) {
        mlb_sds_free(a);
        mlb_sds_free(b);
        return mlb_fail(MLB_ERR_NOMEM, "bench_pipeline: SDS objects");
    }
    return mlb_guidance_sds_create_from(a, b, &gc, &gd->g);
}

static mlb_status make_image_guide(guide* gd, const char* dir, int res) {
    memset(gd, 0, sizeof *gd);
    gd->name = "images";
    gd->views = calloc(1, sizeof *gd->views);
    if (!gd->views) return mlb_fail(MLB_ERR_NOMEM, "bench_pipeline: views");
    mlb_status s = mlb_views_load(gd->views, dir, res);
    if (s) { free(gd->views); gd->views = NULL; return s; }
    mlb_guidance_images_config ic = mlb_guidance_images_default();
    ic.views_per_step = 4;
    return mlb_guidance_images_create(gd->views, &ic, &gd->g);
}

// ---- one configuration's timings ------------------------------------------------------------
typedef struct {
    double render, guide, back, smooth, opt, total, unet;   // s per iteration (unet: -1 = not SDS)
    int faces;
    double gpu_gib;   // device memory in use at the stage's end (weights, caches, scratch); -1 on the CPU
} split;

// GiB in use on the current GPU (total - free), -1 when the device is the CPU
static double gpu_in_use(void) {
    size_t free_b = 0, total_b = 0;
    if (mlb_device_current() != MLB_DEVICE_CUDA || mlb_cuda_mem_info(&free_b, &total_b)) return -1;
    return (double)(total_b - free_b) / (1024.0 * 1024.0 * 1024.0);
}

// The UNet's share of an SDS guidance call: one forward of batch 2·n at h × h (measured once per
// model, batch and size: the latent phase's 64² UNet call is the same at every render size).
static double time_unet(const guide* gd, int n, int h) {
    if (!gd->unet) return -1;
    static struct { const char* name; int n, h; double dt; } cache[32];
    static int n_cache = 0;
    for (int i = 0; i < n_cache; i++)
        if (!strcmp(cache[i].name, gd->name) && cache[i].n == n && cache[i].h == h) return cache[i].dt;
    const mlb_unet* u = gd->unet;
    int B = 2 * n, D = u->cfg.context_dim;
    size_t nx = (size_t)B * u->cfg.in_channels * h * h, ny = (size_t)B * u->cfg.out_channels * h * h,
           nc = (size_t)B * gd->Tc * D;
    float *x = malloc(nx * 4), *y = malloc(ny * 4), *c = malloc(nc * 4), *t = malloc((size_t)B * 4);
    double dt = -1;
    if (x && y && c && t) {
        mlb_rng_fill_normal(x, nx, 5, 1, 0, 0, 1);
        mlb_rng_fill_normal(c, nc, 5, 2, 0, 0, 1);
        for (int b = 0; b < B; b++) t[b] = 500;
        double t0 = mlb_now_seconds();
        if (!mlb_unet_forward(NULL, u, y, x, t, c, B, h, h, gd->Tc, NULL, NULL)) dt = mlb_now_seconds() - t0;
    }
    free(x); free(y); free(c); free(t);
    if (dt >= 0 && n_cache < 32) {
        cache[n_cache].name = gd->name; cache[n_cache].n = n; cache[n_cache].h = h; cache[n_cache].dt = dt;
        n_cache++;
    }
    return dt;
}

typedef struct {
    mlb_geometry_net geo;
    float *geo_params0;                 // the initialised network every configuration starts from
    mlb_tetgrid grid;
    mlb_mesh mesh;                      // the appearance stage's fixed surface
    mlb_material_net mat;
    float* mat_params0;
    mlb_envmap maps[N_ENVS];
    mlb_envlight lights[N_ENVS];
    const mlb_envlight* light_ptrs[N_ENVS];
} scene;

static void reset_geo(scene* sc) {
    mlb_geometry_net* n = &sc->geo;
    memcpy(n->params, sc->geo_params0, sizeof(float) * n->n_params);
    memset(n->adam_m, 0, sizeof(float) * n->n_params);
    memset(n->adam_v, 0, sizeof(float) * n->n_params);
    n->step = 0;
}

static void reset_mat(scene* sc) {
    mlb_material_net* n = &sc->mat;
    memcpy(n->params, sc->mat_params0, sizeof(float) * n->n_params);
    memset(n->adam_m, 0, sizeof(float) * n->n_params);
    memset(n->adam_v, 0, sizeof(float) * n->n_params);
    n->step = 0;
}

// The stages' table: the GPU's fp32 one on a GPU (what mlb_pipeline_run makes of a GPU's table), else NULL (the CPU's)
static const mlb_backend* stage_table(void) {
    return mlb_device_current() == MLB_DEVICE_CUDA ? mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_FP32) : NULL;
}

static mlb_status bench_geometry(scene* sc, guide* gd, long step0, int res, int iters, split* out) {
    memset(out, 0, sizeof *out);
    out->gpu_gib = -1;
    reset_geo(sc);
    mlb_guidance* g = gd->g;
    int n = g->n_views;
    mlb_adam_config adam = mlb_geometry_adam(1e-3);
    mlb_view* views = calloc((size_t)n, sizeof *views);
    mlb_camera* cams = calloc((size_t)n, sizeof *cams);
    size_t N = (size_t)n * res * res * 4;
    float* dimages = malloc(sizeof(float) * N);
    mlb_geofit_state st;
    memset(&st, 0, sizeof st);
    st.be = stage_table();
    mlb_status s = views && cams && dimages ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "bench_pipeline: geometry buffers");
    if (!s && st.be) s = mlb_field_use_device(&sc->geo, st.be);   // as the pipeline's geometry stage
    for (int it = 0; !s && it <= iters; it++) {   // it 0: warm-up
        long step = step0 + it;
        mlb_geofit_stats stats;
        double loss = 0, t0 = mlb_now_seconds();
        s = g->sample_views(g, MLB_STAGE_GEOMETRY, step, views);
        for (int v = 0; v < n; v++) cams[v] = views[v].cam;
        geometry_net_zero_grad(&sc->geo);
        if (!s) s = mlb_geofit_forward(&st, &sc->geo, &sc->grid, cams, n, res, 1, NULL, &stats);
        double t1 = mlb_now_seconds();
        memset(dimages, 0, sizeof(float) * N);
        if (!s) s = g->loss(g, MLB_STAGE_GEOMETRY, step, views, n, st.images, res, res, dimages, &loss);
        double t2 = mlb_now_seconds();
        if (!s) s = mlb_geofit_backward(&st, &sc->geo, dimages, 0.2);
        double t3 = mlb_now_seconds();
        if (!s) geometry_net_update(&sc->geo, &adam);
        double t4 = mlb_now_seconds();
        if (!s && it > 0) {
            out->render += t1 - t0; out->guide += t2 - t1; out->back += t3 - t2; out->opt += t4 - t3; out->total += t4 - t0;
            out->faces = stats.n_faces;
        }
    }
    if (!s && iters > 0) {
        out->render /= iters; out->guide /= iters; out->back /= iters; out->opt /= iters; out->total /= iters;
        out->unet = time_unet(gd, n, step0 < LATENT_ITERS ? MLB_GUIDANCE_LATENT_SIZE : res / 8);
        out->gpu_gib = gpu_in_use();
    }
    mlb_status left = mlb_field_leave_device(&sc->geo);
    if (!s) s = left;
    mlb_geofit_state_free(&st);
    free(views); free(cams); free(dimages);
    return s;
}

static mlb_status bench_appearance(scene* sc, guide* gd, int res, int iters, split* out) {
    memset(out, 0, sizeof *out);
    out->gpu_gib = -1;
    reset_mat(sc);
    mlb_guidance* g = gd->g;
    int n = g->n_views;
    mlb_adam_config adam = mlb_material_adam(1e-2);
    mlb_view* views = calloc((size_t)n, sizeof *views);
    size_t N = (size_t)n * res * res * 4;
    float* images = malloc(sizeof(float) * N);
    float* dimages = malloc(sizeof(float) * N);
    float* pts = malloc(sizeof(float) * 3 * SMOOTH_POINTS);
    mlb_appearance app;
    memset(&app, 0, sizeof app);
    app.be = stage_table();
    mlb_status s = views && images && dimages && pts ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "bench_pipeline: appearance buffers");
    if (!s && app.be) s = mlb_field_use_device(&sc->mat, app.be);   // as the pipeline's appearance stage
    for (int it = 0; !s && it <= iters; it++) {
        long step = it;
        double loss = 0, smooth = 0, t0 = mlb_now_seconds();
        s = g->sample_views(g, MLB_STAGE_APPEARANCE, step, views);
        for (int v = 0; v < n; v++)
            if (views[v].env < 0 || views[v].env >= N_ENVS) views[v].env = 0;   // as pipeline_fix_env
        material_net_zero_grad(&sc->mat);
        if (!s) s = mlb_appearance_render(&app, &sc->mat, &sc->mesh, sc->light_ptrs, views, n, res, 1, images, 1);
        double t1 = mlb_now_seconds();
        memset(dimages, 0, sizeof(float) * N);
        if (!s) s = g->loss(g, MLB_STAGE_APPEARANCE, step, views, n, images, res, res, dimages, &loss);
        double t2 = mlb_now_seconds();
        if (!s) s = mlb_appearance_backward(&app, &sc->mat, dimages);
        double t3 = mlb_now_seconds();
        if (!s) s = mlb_mesh_sample_surface(&sc->mesh, pts, SMOOTH_POINTS, 0, 0x5300000000ull + (uint64_t)step);
        if (!s) s = mlb_material_smoothness(&sc->mat, pts, SMOOTH_POINTS, 0.01, 0.03, 0, 0, step, 1, &smooth);
        double t4 = mlb_now_seconds();
        if (!s) s = material_net_update(&sc->mat, &adam);
        double t5 = mlb_now_seconds();
        if (!s && it > 0) {
            out->render += t1 - t0; out->guide += t2 - t1; out->back += t3 - t2; out->smooth += t4 - t3;
            out->opt += t5 - t4; out->total += t5 - t0;
        }
    }
    if (!s && iters > 0) {
        out->render /= iters; out->guide /= iters; out->back /= iters; out->smooth /= iters; out->opt /= iters;
        out->total /= iters;
        out->faces = sc->mesh.n_faces;
        out->unet = time_unet(gd, n, res / 8);
        out->gpu_gib = gpu_in_use();
    }
    mlb_appearance_free(&app);
    mlb_status left = mlb_field_leave_device(&sc->mat);
    if (!s) s = left;
    free(views); free(images); free(dimages); free(pts);
    return s;
}

// ---- setup ------------------------------------------------------------------------------------
static mlb_status scene_init(scene* sc, int init_iters) {
    memset(sc, 0, sizeof *sc);
    mlb_geometry_config gc = mlb_geometry_default();
    gc.seed = 1;
    mlb_status s = geometry_net_init(&sc->geo, &gc);
    if (!s) s = mlb_tetgrid_create(&sc->grid, 32, gc.scale);
    if (!s) {   // the pipeline's default start: the ellipsoid
        mlb_shape shape;
        memset(&shape, 0, sizeof shape);
        const float axes[3] = {0.5f, 0.5f, 0.5f};
        mlb_shape_ellipsoid(&shape, 1.0f, axes);
        mlb_shape_fit_config fc = mlb_shape_fit_default();
        fc.iters = init_iters;
        fc.seed = 1;
        s = mlb_geometry_fit_shape(&sc->geo, &shape, &fc, NULL, NULL);
        mlb_shape_free(&shape);
    }
    if (!s) {
        sc->geo_params0 = malloc(sizeof(float) * sc->geo.n_params);
        if (!sc->geo_params0) s = mlb_fail(MLB_ERR_NOMEM, "bench_pipeline: parameters");
        else memcpy(sc->geo_params0, sc->geo.params, sizeof(float) * sc->geo.n_params);
    }
    if (!s) s = mlb_geometry_extract(NULL, &sc->geo, &sc->grid, &sc->mesh);
    if (!s) s = mlb_mesh_compute_normals(&sc->mesh);
    mlb_brdf_ae prior;
    memset(&prior, 0, sizeof prior);
    char source[256];
    if (!s) s = mlb_brdf_ae_load_default(&prior, source, sizeof source);
    if (!s) {
        mlb_material_config mc = mlb_material_default();
        mc.seed = 2;
        mc.scale = gc.scale;
        s = material_net_init(&sc->mat, &mc, &prior);
    }
    brdf_ae_free(&prior);
    if (!s) {
        sc->mat_params0 = malloc(sizeof(float) * sc->mat.n_params);
        if (!sc->mat_params0) s = mlb_fail(MLB_ERR_NOMEM, "bench_pipeline: parameters");
        else memcpy(sc->mat_params0, sc->mat.params, sizeof(float) * sc->mat.n_params);
    }
    mlb_envlight_options opt;
    memset(&opt, 0, sizeof opt);
    opt.face_size = 128;   // the pipeline's default cube_size
    for (int i = 0; !s && i < N_ENVS; i++) {
        s = mlb_envmap_named(&sc->maps[i], ENV_NAMES[i], 256);
        if (!s) s = mlb_envlight_build(&sc->lights[i], &sc->maps[i], &opt);
        sc->light_ptrs[i] = &sc->lights[i];
    }
    return s;
}

static void scene_free(scene* sc) {
    for (int i = 0; i < N_ENVS; i++) {
        if (sc->light_ptrs[i]) mlb_envlight_free(&sc->lights[i]);
        mlb_envmap_free(&sc->maps[i]);
    }
    material_net_free(&sc->mat);
    geometry_net_free(&sc->geo);
    mlb_tetgrid_free(&sc->grid);
    mlb_mesh_free(&sc->mesh);
    free(sc->geo_params0);
    free(sc->mat_params0);
}

// 12 views of a sphere at 512² (sky / studio / overcast, normal maps): the image guidance's data.
static mlb_status render_views(const char* dir) {
    mlb_mesh m;
    mlb_status s = mlb_mesh_uv_sphere(&m, 0.55f, 64, 32);
    if (s) return s;
    static const float K[7] = {0.60f, 0.30f, 0.10f, 0.04f, 0.04f, 0.04f, 0.5f};
    mlb_views_render_config rc = mlb_views_render_default();
    rc.mesh = &m;
    memcpy(rc.k_const, K, sizeof K);
    rc.n_views = 12;
    rc.res = 512;
    rc.supersample = 1;
    rc.cube = 128;
    rc.envs = ENV_NAMES;
    rc.n_envs = N_ENVS;
    s = mlb_views_render(dir, &rc, NULL);
    mlb_mesh_free(&m);
    return s;
}

// ---- the table ----------------------------------------------------------------------------------
static void print_header(void) {
    printf("| stage | guidance | phase | res | views | faces | s/iter | render fwd | guidance | of which UNet | backward | "
           "smoothness | optimizer | GPU GiB |\n");
    printf("|---|---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|\n");
}

static void print_row(const char* stage, const char* guidance, const char* phase, int res, int views, const split* r) {
    char unet[32], smooth[32], gpu[32];
    if (r->gpu_gib >= 0) snprintf(gpu, sizeof gpu, "%.1f", r->gpu_gib);
    else snprintf(gpu, sizeof gpu, "-");
    if (r->unet >= 0) snprintf(unet, sizeof unet, "%.3f", r->unet);
    else snprintf(unet, sizeof unet, "-");
    if (!strcmp(stage, "appearance")) snprintf(smooth, sizeof smooth, "%.3f", r->smooth);
    else snprintf(smooth, sizeof smooth, "-");
    printf("| %s | %s | %s | %d | %d | %d | %.3f | %.3f | %.3f | %s | %.3f | %s | %.3f | %s |\n", stage, guidance, phase, res,
           views, r->faces, r->total, r->render, r->guide, unet, r->back, smooth, r->opt, gpu);
    fflush(stdout);
}

static int parse_sizes(const char* arg, int* out, int cap) {
    int n = 0;
    const char* p = arg;
    while (*p && n < cap) {
        char* end;
        long v = strtol(p, &end, 10);
        if (end == p || v < 8 || v > 2048) return -1;
        out[n++] = (int)v;
        p = *end == ',' ? end + 1 : end;
        if (*end && *end != ',') return -1;
    }
    return n;
}

// A whole `matlaber generate --preset NAME` (its settings, the pipeline's own loop) with the random
// SD 1.5 u, vae in a run folder under dir, removed afterwards; t_model: when the weights began loading.
static int generate_run(const char* preset, double geometry_lr, double scale, const char* paint, const char* dir,
                        const mlb_unet* u, const mlb_vae* vae, const float* ac, double t_model) {
    mlb_pipeline_config c = mlb_pipeline_default();
    if (mlb_pipeline_preset(&c, preset)) { fprintf(stderr, "bench_pipeline: %s\n", mlb_last_error()); return 2; }
    // Random weights' SDS gradients are noise with a guidance scale of 100: at the preset's learning
    // rate they can empty the grid ("no surface") in a few dozen steps. --generate-geometry-lr keeps
    // a surface for the timing (a step's time does not depend on the learning rate).
    if (geometry_lr > 0) c.geometry_lr = geometry_lr;
    // --generate-scale F: both stages' step counts times F (a miniature of a long schedule, whose
    // per-step time then extrapolates; the latent phase stays the first third)
    if (scale > 0 && scale != 1) {
        c.geometry_iters = (int)(c.geometry_iters * scale + 0.5);
        c.appearance_iters = (int)(c.appearance_iters * scale + 0.5);
    }
    snprintf(c.prompt, sizeof c.prompt, "(random embeddings)");
    snprintf(c.model, sizeof c.model, "(random SD 1.5)");
    if (c.latent_iters < 0) c.latent_iters = c.geometry_iters / 3;
    if (paint) {   // no geometry stage
        snprintf(c.paint_mesh, sizeof c.paint_mesh, "%s", paint);
        c.geometry_iters = 0;
    }
    double t0 = mlb_now_seconds();
    if (paint) printf("paint --mesh %s (no geometry stage): ", paint);
    printf("generate --preset %s end to end: %d views at %d², %d geometry steps (%d latent-phase, lr %g), %d "
           "appearance steps, grid %d, %s GEMMs (weights loaded in %.1f s)\n", preset, c.views, c.res,
           c.geometry_iters, c.latent_iters, c.geometry_lr, c.appearance_iters, c.grid,
           mlb_gemm_precision_name(mlb_gemm_precision_current()), t0 - t_model);
    fflush(stdout);
    guide gd;
    memset(&gd, 0, sizeof gd);
    char run[700];
    snprintf(run, sizeof run, "%s/run", dir);
    mlb_progress progress;
    mlb_pipeline_result result;
    mlb_status s = make_sds_guide(&gd, "sds SD 1.5", u, vae, ac, 77, c.views, c.latent_iters);
    if (!s) s = mlb_pipeline_run(run, &c, gd.g, NULL, stage_table(), 0, &progress, &result);
    double total = mlb_now_seconds() - t0;
    guide_free(&gd);
    int rc = 0;
    if (s) {
        fprintf(stderr, "bench_pipeline: generate: %s\n", mlb_last_error());
        rc = 1;
    } else {
        char glb[800];
        snprintf(glb, sizeof glb, "%s/final/asset.glb", run);
        struct stat st;
        long glb_bytes = stat(glb, &st) ? -1 : (long)st.st_size;
        printf("done: %.1f s (%.1f min) for %ld + %ld steps, %d faces, final/asset.glb %ld bytes; "
               "with the weights' loading %.1f min\n", total, total / 60, result.geometry_steps,
               result.appearance_steps, result.n_faces, glb_bytes, (mlb_now_seconds() - t_model) / 60);
        printf("peak resident memory: %.2f GB (getrusage ru_maxrss)\n", bench_peak_mb() / 1024.0);
    }
    char cmd[800];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", run);
    if (system(cmd)) fprintf(stderr, "bench_pipeline: could not remove %s\n", run);
    return rc;
}

static int usage(void) {
    fprintf(stderr, "usage: bench_pipeline [--iters 1] [--sizes 64,128,512] [--sd15] [--sd15-sizes 512] [--no-images] "
                    "[--no-tiny] [--stage both|geometry|appearance] [--init-iters 100] [--dir /tmp] [--sd15-views 1] "
                    "[--device cpu|cuda] [--precision fp16] [--generate PRESET [--generate-geometry-lr X] [--generate-scale F] "
                    "[--paint MESH]]\n");
    return 2;
}

// Runs every configuration of one guidance (images: a fresh data set per size).
static int run_guidance(scene* sc, const char* name, guide* sds, const char* views_dir, const int* sizes, int n_sizes,
                        int iters, int do_geo, int do_app) {
    for (int si = 0; si < n_sizes; si++) {
        int res = sizes[si];
        guide img;
        memset(&img, 0, sizeof img);
        guide* gd = sds;
        if (!sds) {
            if (make_image_guide(&img, views_dir, res)) {
                fprintf(stderr, "bench_pipeline: image guidance at %d: %s\n", res, mlb_last_error());
                return 1;
            }
            gd = &img;
        }
        int n = gd->g->n_views;
        split r;
        mlb_status s = MLB_OK;
        if (do_geo && sds) {   // SDS geometry: both phases
            s = bench_geometry(sc, gd, 0, res, iters, &r);
            if (!s) print_row("geometry", name, "latent 64²", res, n, &r);
            if (!s && res % 64 == 0) {
                s = bench_geometry(sc, gd, LATENT_ITERS, res, iters, &r);
                if (!s) print_row("geometry", name, "vae", res, n, &r);
            }
        } else if (do_geo) {
            s = bench_geometry(sc, gd, 0, res, iters, &r);
            if (!s) print_row("geometry", name, "-", res, n, &r);
        }
        if (!s && do_app && (!sds || res % 64 == 0)) {
            s = bench_appearance(sc, gd, res, iters, &r);
            if (!s) print_row("appearance", name, sds ? "vae" : "-", res, n, &r);
        }
        if (!sds) guide_free(&img);
        if (s) {
            fprintf(stderr, "bench_pipeline: %s at %d: %s\n", name, res, mlb_last_error());
            return 1;
        }
    }
    return 0;
}

int main(int argc, char** argv) {
    // the program's runtime settings (tools/matlaber/main.c), read when the runtimes load
    mlb_runtime_restart(argv);   // the program's runtime settings (threads.h)
    int iters = 1, sd15 = 0, images = 1, tiny = 1, do_geo = 1, do_app = 1, init_iters = 100;
    int sizes[8] = {64, 128, 512}, n_sizes = 3, sd_sizes[8] = {512}, n_sd_sizes = 1;
    const char* base = "/tmp";
    int sd_views = 1;
    const char* generate = NULL, *paint = NULL;
    double generate_geo_lr = 0, generate_scale = 1;
    mlb_device device = MLB_DEVICE_CPU;
    mlb_gemm_precision precision = MLB_GEMM_FP16;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--sd15")) sd15 = 1;
        else if (!strcmp(argv[i], "--no-images")) images = 0;
        else if (!strcmp(argv[i], "--no-tiny")) tiny = 0;
        else if (i + 1 < argc && !strcmp(argv[i], "--iters")) iters = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--init-iters")) init_iters = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--dir")) base = argv[++i];
        else if (i + 1 < argc && !strcmp(argv[i], "--sd15-views")) sd_views = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--generate")) generate = argv[++i];
        else if (i + 1 < argc && !strcmp(argv[i], "--generate-geometry-lr")) generate_geo_lr = atof(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--generate-scale")) generate_scale = atof(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--paint")) paint = argv[++i];
        else if (i + 1 < argc && !strcmp(argv[i], "--device")) {
            if (mlb_device_select(argv[++i], &device) != MLB_OK) { fprintf(stderr, "bench_pipeline: %s\n", mlb_last_error()); return 2; }
        } else if (i + 1 < argc && !strcmp(argv[i], "--precision")) {
            if (mlb_gemm_precision_parse(argv[++i], &precision) != MLB_OK) return usage();
        }
        else if (i + 1 < argc && !strcmp(argv[i], "--sizes")) {
            if ((n_sizes = parse_sizes(argv[++i], sizes, 8)) < 0) return usage();
        } else if (i + 1 < argc && !strcmp(argv[i], "--sd15-sizes")) {
            if ((n_sd_sizes = parse_sizes(argv[++i], sd_sizes, 8)) < 0) return usage();
        } else if (i + 1 < argc && !strcmp(argv[i], "--stage")) {
            const char* st = argv[++i];
            do_geo = !strcmp(st, "both") || !strcmp(st, "geometry");
            do_app = !strcmp(st, "both") || !strcmp(st, "appearance");
            if (!do_geo && !do_app) return usage();
        } else return usage();
    }
    if (paint && !generate) return usage();
    if (generate) {   // the end-to-end run: SD 1.5 only
        if (!sd15) return usage();
        images = 0;
        tiny = 0;
    }
    if (iters < 1) iters = 1;
    if (init_iters < 1) init_iters = 1;
    int threads = omp_get_max_threads();
    mlb_set_threads(threads);
    const char* wp = getenv("OMP_WAIT_POLICY");
    printf("pipeline stages, s/iteration: %d threads, OpenBLAS kernels %s, OMP_WAIT_POLICY %s; 1 warm-up + %d timed "
           "iterations (mean)\n", threads, mlb_blas_corename(), wp ? wp : "(unset)", iters);
    printf("sgemm 4096x2880 . 2880x320: %.1f GFLOP/s\n", bench_sgemm_rate(4096, 320, 2880));

    char dir[512], views_dir[600], pu[600], pv[600], cj[600];
    snprintf(dir, sizeof dir, "%s/mlb_bench_pipeline_XXXXXX", base);
    if (!mkdtemp(dir)) { perror("mkdtemp"); return 1; }
    snprintf(views_dir, sizeof views_dir, "%s/views", dir);
    snprintf(pu, sizeof pu, "%s/unet.safetensors", dir);
    snprintf(pv, sizeof pv, "%s/vae.safetensors", dir);
    snprintf(cj, sizeof cj, "%s/unet.config.json", dir);
    int rc = 0;
    scene sc;
    mlb_unet* tu = NULL;
    mlb_vae* tv = NULL;
    guide tg;
    memset(&tg, 0, sizeof tg);
    float ac[1000];
    double t0 = mlb_now_seconds();
    if (scene_init(&sc, init_iters)) { fprintf(stderr, "bench_pipeline: setup: %s\n", mlb_last_error()); rc = 1; goto out; }
    printf("geometry: %zu parameters, grid 32 cells, ellipsoid init %d steps; appearance: %zu parameters, %d faces "
           "(setup %.1f s)\n", sc.geo.n_params, init_iters, sc.mat.n_params, sc.mesh.n_faces, mlb_now_seconds() - t0);
    if (mlb_schedule_alphas_cumprod_f32(ac, 1000, MLB_SD_BETA_START, MLB_SD_BETA_END)) { rc = 1; goto out; }
    if (images) {
        t0 = mlb_now_seconds();
        if (render_views(views_dir)) { fprintf(stderr, "bench_pipeline: views: %s\n", mlb_last_error()); rc = 1; goto out; }
        printf("image guidance data: 12 views of a sphere at 512² (%.1f s)\n", mlb_now_seconds() - t0);
    }
    printf("\n");
    if (!generate) print_header();
    if (images && run_guidance(&sc, "images", NULL, views_dir, sizes, n_sizes, iters, do_geo, do_app)) { rc = 1; goto out; }
    if (tiny) {
        mlb_unet_config uc = mlb_unet_tiny_config(0);
        mlb_unet_random_options uo = mlb_unet_random_default_options();
        uo.seed = 7;
        uo.config_json_path = cj;
        mlb_vae_config vc = mlb_vae_sd_config();
        int bo[4] = {32, 32, 64, 64};
        for (int i = 0; i < 4; i++) vc.block_out[i] = bo[i];
        if (mlb_unet_write_random(&uc, &uo, pu) || mlb_unet_load(pu, NULL, &tu) || mlb_vae_create(NULL, &vc, &tv)) {
            fprintf(stderr, "bench_pipeline: tiny model: %s\n", mlb_last_error());
            rc = 1;
            goto out;
        }
        unlink(pu);
        unlink(cj);
        mlb_vae_init_random(tv, 3, 1.0f);
        if (make_sds_guide(&tg, "sds tiny", tu, tv, ac, 6, 4, LATENT_ITERS) ||
            run_guidance(&sc, "sds tiny", &tg, NULL, sizes, n_sizes, iters, do_geo, do_app)) {
            fprintf(stderr, "bench_pipeline: tiny SDS: %s\n", mlb_last_error());
            rc = 1;
            goto out;
        }
        guide_free(&tg);
        mlb_unet_free(tu);
        mlb_vae_free(tv);
        tu = NULL;
        tv = NULL;
    }
    if (sd15) {   // bench_sd's way: write the full-size random weights, load them as the program does
        t0 = mlb_now_seconds();
        mlb_unet_config uc = mlb_unet_sd15_config();
        mlb_unet_random_options uo = mlb_unet_random_default_options();
        uo.layout = MLB_UNET_LAYOUT_LDM;
        uo.dtype = MLB_DT_F16;
        uo.seed = 1;
        mlb_vae_config vc = mlb_vae_sd_config();
        mlb_status s = mlb_unet_write_random(&uc, &uo, pu);
        mlb_unet_options lo = mlb_unet_options_for(device, precision);   // as the program loads it
        if (!s) s = mlb_unet_load(pu, &lo, &tu);
        if (!s) s = mlb_vae_create(NULL, &vc, &tv);
        if (!s) {
            mlb_vae_init_random(tv, 1, 1.0f);
            s = mlb_vae_save(tv, pv, MLB_VAE_LAYOUT_LDM, "first_stage_model.", NULL);
            mlb_vae_free(tv);
            tv = NULL;
        }
        if (!s) s = mlb_vae_load(pv, NULL, &tv);
        unlink(pu);
        unlink(pv);
        if (s) { fprintf(stderr, "bench_pipeline: SD 1.5: %s\n", mlb_last_error()); rc = 1; goto out; }
        fprintf(stderr, "SD 1.5 random weights written and loaded in %.1f s\n", mlb_now_seconds() - t0);
        if (device != MLB_DEVICE_CPU || precision == MLB_GEMM_BF16) {
            s = mlb_unet_use_device(tu, device, precision);
            if (!s) s = mlb_vae_use_device(tv, device, precision);
            if (s) { fprintf(stderr, "bench_pipeline: --device: %s\n", mlb_last_error()); rc = 1; goto out; }
            printf("SD 1.5 UNet and VAE on the %s, %s GEMMs", mlb_device_name(device), mlb_gemm_precision_name(precision));
            if (!generate) printf("; %d views per step", sd_views);
            printf("\n");
        }
        if (generate) {
            mlb_set_gemm_precision(precision);
            rc = generate_run(generate, generate_geo_lr, generate_scale, paint, dir, tu, tv, ac, t0);
            goto out;
        }
        if (make_sds_guide(&tg, "sds SD 1.5", tu, tv, ac, 77, sd_views < 1 ? 1 : sd_views, LATENT_ITERS) ||
            run_guidance(&sc, "sds SD 1.5", &tg, NULL, sd_sizes, n_sd_sizes, iters, do_geo, do_app)) {
            fprintf(stderr, "bench_pipeline: SD 1.5 SDS: %s\n", mlb_last_error());
            rc = 1;
            goto out;
        }
    }
    printf("\npeak resident memory: %.2f GB (getrusage ru_maxrss)\n", bench_peak_mb() / 1024.0);
out:
    guide_free(&tg);
    mlb_unet_free(tu);
    mlb_vae_free(tv);
    scene_free(&sc);
    unlink(pu);
    unlink(pv);
    unlink(cj);
    if (images) {
        char cmd[700];
        snprintf(cmd, sizeof cmd, "rm -rf '%s'", views_dir);
        if (system(cmd)) fprintf(stderr, "bench_pipeline: could not remove %s\n", views_dir);
    }
    if (rmdir(dir)) perror(dir);
    return rc;
}
