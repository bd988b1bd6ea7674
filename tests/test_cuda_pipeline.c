// A short text-to-3D generation with the tests' tiny random SD 1 model, once with the UNet on the
// CPU and once on the GPU (fp32 GEMMs; the program's `--device cuda --precision fp32`), from the same
// seed: the final meshes and their material fields must agree. Skips without a GPU or without the
// sd_reference fixture (../shared/data or $MLB_SHARED_DATA).
// Tolerance. The UNet outputs differ by ~1e-6 relative (test_cuda_unet), but Adam's step m / sqrt(v)
// turns any difference in a near-zero gradient into a full +-lr step, so the two runs separate at
// the scale of the learning rate, not of the rounding (measured on an H200: Chamfer / diagonal
// 1.0e-3 .. 1.7e-3, 188 vs 182 vertices). The control is a second CPU run with another seed: the
// device difference must be smaller than the seed's, and under 1e-2 of the diagonal (an eighth of a
// grid cell at --grid 16).
// The materials are compared on one surface: runs without geometry steps (the initial shape, fitted
// on the CPU in both), since a material field evaluated on the other run's surface reads hash cells
// that run never trained (the finest cells are ~1e-3 of the diagonal, the surfaces 1e-3 apart):
// that confound put the two devices' materials as far apart as two seeds' (H200: 9.99e-3 .. 2.10e-2
// vs 2.00e-2 mean |difference| at the vertices). On one surface the device difference must be
// under 1e-2 and under the seed's. The appearance arithmetic itself is checked step by step in
// test_cuda_material.
#include "cuda_test_util.h"
#include "matlaber/geometry.h"
#include "matlaber/pipeline.h"
#include "matlaber/sd_model.h"

static mlb_status run_on(const char* device, const char* model, const char* dir, uint64_t seed, int geometry_iters,
                         mlb_pipeline_result* r) {
    mlb_device d;
    MLB_TRY(mlb_device_select(device, &d));
    const mlb_backend* be = mlb_backend_for(d, MLB_GEMM_FP32);   // the program's --device D --precision fp32
    mlb_pipeline_config c = mlb_pipeline_default();
    snprintf(c.guidance, sizeof c.guidance, "sds");
    snprintf(c.prompt, sizeof c.prompt, "a golden goblet");
    snprintf(c.model, sizeof c.model, "%s", model);
    c.res = 64;
    c.grid = 16;
    c.views = 2;
    c.geometry_iters = geometry_iters;
    c.init_iters = 50;
    c.appearance_iters = 6;
    c.preview_every = 0;
    c.overwrite = 1;
    c.seed = seed;
    // the settings this comparison was measured with on the H200 (see the header): with the later
    // defaults (coarse-to-fine 0.5, ks/kr smoothness 0.1) two seeds' materials end closer (1.15e-2)
    // than the two devices' (1.63e-2, on meshes of 188 and 182 vertices), so the control no longer
    // separates them at 12 + 6 steps
    c.coarse_to_fine = 0;
    c.w_mat_spec = 0;
    mlb_guidance* g = NULL;
    mlb_views* v = NULL;
    mlb_status s = mlb_pipeline_make_guidance(&c, be, &g, &v);
    if (!s) s = mlb_pipeline_run(dir, &c, g, v, be, 0, NULL, r);
    mlb_guidance_free(g);
    mlb_pipeline_free_views(v);
    return s;
}

TEST(generate_agrees_between_devices) {
    REQUIRE_GPU();
    const char* data = test_shared_data();
    if (!data) SKIP("no shared data (../shared/data or $MLB_SHARED_DATA)");
    char model[700];
    snprintf(model, sizeof model, "%s/sd_reference/sd1_diffusers", data);
    struct stat st;
    if (stat(model, &st) != 0) SKIP("no %s", model);
    const char* tmp = test_tmpdir("cuda_pipeline");
    char dir_c[700], dir_g[700];
    snprintf(dir_c, sizeof dir_c, "%s/cpu", tmp);
    snprintf(dir_g, sizeof dir_g, "%s/cuda", tmp);
    mlb_pipeline_result rc, rg, rs;
    char dir_s[700];
    snprintf(dir_s, sizeof dir_s, "%s/cpu_seed1", tmp);
    mlb_status s = run_on("cpu", model, dir_c, 0, 12, &rc);
    if (!s) s = run_on("cpu", model, dir_s, 1, 12, &rs);
    CHECK_MSG(s == MLB_OK, "CPU run: %s", mlb_last_error());
    if (s) return;
    s = run_on("cuda", model, dir_g, 0, 12, &rg);
    CHECK_MSG(s == MLB_OK, "GPU run: %s", mlb_last_error());
    mlb_device d;
    mlb_device_select("cpu", &d);
    if (s) return;
    CHECK(rc.finished && rg.finished && rs.finished);
    printf("  losses: geometry %.6g (cpu) %.6g (cuda), appearance %.6g (cpu) %.6g (cuda)\n", rc.geometry_loss,
           rg.geometry_loss, rc.appearance_loss, rg.appearance_loss);
    printf("  meshes: %d / %d vertices, %d / %d faces\n", rc.n_verts, rg.n_verts, rc.n_faces, rg.n_faces);
    mlb_run_asset a, b, c;
    memset(&a, 0, sizeof a);
    memset(&b, 0, sizeof b);
    memset(&c, 0, sizeof c);
    CHECK(mlb_run_asset_load(&a, dir_c) == MLB_OK);
    CHECK(mlb_run_asset_load(&b, dir_g) == MLB_OK);
    CHECK(mlb_run_asset_load(&c, dir_s) == MLB_OK);
    mlb_chamfer_result dev, seed;
    CHECK(mlb_chamfer(&a.mesh, &b.mesh, 20000, 7, &dev) == MLB_OK);
    CHECK(mlb_chamfer(&a.mesh, &c.mesh, 20000, 7, &seed) == MLB_OK);
    printf("  Chamfer / diagonal to the CPU mesh: GPU %.3e, CPU with another seed %.3e (bound: below both 1e-2 and "
           "the seed's)\n", dev.relative, seed.relative);
    CHECK(dev.relative <= 1e-2);
    CHECK(dev.relative < seed.relative);
    mlb_run_asset_free(&a);
    mlb_run_asset_free(&b);
    mlb_run_asset_free(&c);
    // the materials, on the one surface of runs without geometry steps
    snprintf(dir_c, sizeof dir_c, "%s/cpu_app", tmp);
    snprintf(dir_g, sizeof dir_g, "%s/cuda_app", tmp);
    snprintf(dir_s, sizeof dir_s, "%s/cpu_app_seed1", tmp);
    s = run_on("cpu", model, dir_c, 0, 0, &rc);
    if (!s) s = run_on("cpu", model, dir_s, 1, 0, &rs);
    if (!s) s = run_on("cuda", model, dir_g, 0, 0, &rg);
    mlb_device_select("cpu", &d);
    CHECK_MSG(s == MLB_OK, "appearance runs: %s", mlb_last_error());
    if (s) return;
    CHECK(mlb_run_asset_load(&a, dir_c) == MLB_OK);
    CHECK(mlb_run_asset_load(&b, dir_g) == MLB_OK);
    CHECK(mlb_run_asset_load(&c, dir_s) == MLB_OK);
    CHECK(a.mesh.n_verts == b.mesh.n_verts && !memcmp(a.mesh.pos, b.mesh.pos, sizeof(float) * 3 * a.mesh.n_verts));
    size_t n = (size_t)a.mesh.n_verts * 7;
    float *ka = host_alloc(n), *kb = host_alloc(n), *kc = host_alloc(n);
    mlb_run_asset cc = c;   // borrows a's mesh
    cc.mesh = a.mesh;
    CHECK(mlb_run_asset_vertex_brdf(&a, ka) == MLB_OK);
    CHECK(mlb_run_asset_vertex_brdf(&b, kb) == MLB_OK);
    CHECK(mlb_run_asset_vertex_brdf(&cc, kc) == MLB_OK);
    double mb = 0, mc = 0;
    for (size_t i = 0; i < n; i++) {
        mb += fabs((double)ka[i] - kb[i]);
        mc += fabs((double)ka[i] - kc[i]);
    }
    mb /= (double)n;
    mc /= (double)n;
    printf("  one surface (%d vertices): material (kd, ks, roughness) at the vertices, mean |difference| to the CPU "
           "run: GPU %.3e, CPU with another seed %.3e (bound: below both 1e-2 and the seed's)\n", a.mesh.n_verts, mb, mc);
    CHECK(mb <= 1e-2);
    CHECK(mb < mc);
    free(ka); free(kb); free(kc);
    mlb_run_asset_free(&a);
    mlb_run_asset_free(&b);
    mlb_run_asset_free(&c);
}

int main(void) {
    RUN(generate_agrees_between_devices);
    return test_summary();
}
