// A short text-to-3D generation with the tests' tiny random SD 1 model, once with the UNet on the
// CPU and once on the GPU (fp32 GEMMs; the program's `--device cuda --precision fp32`), from the same
// seed: the final meshes and their material fields must agree. Skips without a GPU or without the
// sd_reference fixture (../shared/data or $MLB_SHARED_DATA).
// Tolerance: the UNet outputs differ by ~1e-6 relative (test_cuda_unet), so the SDS gradients do
// too; over 12 + 6 Adam steps the SDF and the material field move by far less than a grid cell, so
// the surfaces agree to Chamfer / diagonal <= 1e-3 and the material at the vertices to 1e-2 (max
// abs) when the two meshes have the same vertices. The numbers are printed.
#include "cuda_test_util.h"
#include "matlaber/geometry.h"
#include "matlaber/pipeline.h"
#include "matlaber/sd_model.h"

static mlb_status run_on(const char* device, const char* model, const char* dir, mlb_pipeline_result* r) {
    mlb_device d;
    MLB_TRY(mlb_device_select(device, &d));
    mlb_set_gemm_precision(MLB_GEMM_FP32);
    mlb_pipeline_config c = mlb_pipeline_default();
    snprintf(c.guidance, sizeof c.guidance, "sds");
    snprintf(c.prompt, sizeof c.prompt, "a golden goblet");
    snprintf(c.model, sizeof c.model, "%s", model);
    c.res = 64;
    c.grid = 16;
    c.views = 2;
    c.geometry_iters = 12;
    c.init_iters = 50;
    c.appearance_iters = 6;
    c.preview_every = 0;
    c.overwrite = 1;
    mlb_guidance* g = NULL;
    mlb_views* v = NULL;
    mlb_status s = mlb_pipeline_make_guidance(&c, &g, &v);
    if (!s) s = mlb_pipeline_run(dir, &c, g, v, 0, NULL, r);
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
    mlb_pipeline_result rc, rg;
    mlb_status s = run_on("cpu", model, dir_c, &rc);
    CHECK_MSG(s == MLB_OK, "CPU run: %s", mlb_last_error());
    if (s) return;
    s = run_on("cuda", model, dir_g, &rg);
    CHECK_MSG(s == MLB_OK, "GPU run: %s", mlb_last_error());
    mlb_device d;
    mlb_device_select("cpu", &d);
    if (s) return;
    CHECK(rc.finished && rg.finished);
    printf("  losses: geometry %.6g (cpu) %.6g (cuda), appearance %.6g (cpu) %.6g (cuda)\n", rc.geometry_loss,
           rg.geometry_loss, rc.appearance_loss, rg.appearance_loss);
    printf("  meshes: %d / %d vertices, %d / %d faces\n", rc.n_verts, rg.n_verts, rc.n_faces, rg.n_faces);
    mlb_run_asset a, b;
    memset(&a, 0, sizeof a);
    memset(&b, 0, sizeof b);
    CHECK(mlb_run_asset_load(&a, dir_c) == MLB_OK);
    CHECK(mlb_run_asset_load(&b, dir_g) == MLB_OK);
    mlb_chamfer_result cr;
    CHECK(mlb_chamfer(&a.mesh, &b.mesh, 20000, 7, &cr) == MLB_OK);
    printf("  Chamfer / diagonal between the CPU and GPU meshes: %.3e (bound 1e-3)\n", cr.relative);
    CHECK(cr.relative <= 1e-3);
    if (a.mesh.n_verts == b.mesh.n_verts) {
        size_t n = (size_t)a.mesh.n_verts * 7;
        float *ka = host_alloc(n), *kb = host_alloc(n);
        CHECK(mlb_run_asset_vertex_brdf(&a, ka) == MLB_OK);
        CHECK(mlb_run_asset_vertex_brdf(&b, kb) == MLB_OK);
        double m = 0;
        for (size_t i = 0; i < n; i++) m = fmax(m, fabs((double)ka[i] - kb[i]));
        printf("  material at the vertices: max |cpu - cuda| %.3e (bound 1e-2)\n", m);
        CHECK(m <= 1e-2);
        free(ka);
        free(kb);
    }
    mlb_run_asset_free(&a);
    mlb_run_asset_free(&b);
}

int main(void) {
    RUN(generate_agrees_between_devices);
    return test_summary();
}
