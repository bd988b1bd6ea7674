// Shared by tests/test_appearance.c and tests/test_cuda_material.c (not itself a test): a closed
// sphere under two procedural environment lights, views around it, and the check that the
// appearance renderer with its material network on an op table's device (mlb_field_use_device)
// agrees with the host's.
#ifndef MATLABER_APPEARANCE_TEST_UTIL_H
#define MATLABER_APPEARANCE_TEST_UTIL_H
#include "matlaber/appearance.h"
#include "matlaber/envmap.h"
#include "matlaber/geometry.h"
#include "matlaber/render.h"
#include "matlaber/rng.h"
#include "cuda_test_util.h"
#include "material_test_util.h"

typedef struct {
    mlb_envmap env[2];
    mlb_envlight light[2];
    const mlb_envlight* ptr[2];
    mlb_mesh mesh;
} scene;

static int scene_init(scene* s, int segments, int rings) {
    memset(s, 0, sizeof *s);
    static const char* names[2] = {"sky", "studio"};
    mlb_envlight_options o = {.face_size = 16, .min_size = 4};
    for (int i = 0; i < 2; i++) {
        if (mlb_envmap_named(&s->env[i], names[i], 32) || mlb_envlight_build(&s->light[i], &s->env[i], &o)) return 0;
        s->ptr[i] = &s->light[i];
    }
    if (mlb_mesh_uv_sphere(&s->mesh, 0.8f, segments, rings)) return 0;
    // weld the seam and pole copies into a closed mesh (as the pipeline's marching-tets surfaces
    // are): otherwise the seam's edges are boundary edges, which antialias blends across
    mlb_mesh* m = &s->mesh;
    int32_t* remap = malloc(sizeof(int32_t) * m->n_verts);
    int nv = 0;
    for (int i = 0; i < m->n_verts; i++) {
        int j = 0;
        while (j < nv && fabsf(m->pos[3 * j] - m->pos[3 * i]) + fabsf(m->pos[3 * j + 1] - m->pos[3 * i + 1]) +
                             fabsf(m->pos[3 * j + 2] - m->pos[3 * i + 2]) > 1e-6f)
            j++;
        if (j == nv) {
            memmove(m->pos + 3 * nv, m->pos + 3 * i, sizeof(float) * 3);
            memmove(m->normal + 3 * nv, m->normal + 3 * i, sizeof(float) * 3);
            nv++;
        }
        remap[i] = j;
    }
    for (int f = 0; f < 3 * m->n_faces; f++) m->faces[f] = remap[m->faces[f]];
    m->n_verts = nv;
    free(m->uv);
    m->uv = NULL;
    free(remap);
    return 1;
}

static void scene_free(scene* s) {
    for (int i = 0; i < 2; i++) { mlb_envlight_free(&s->light[i]); mlb_envmap_free(&s->env[i]); }
    mlb_mesh_free(&s->mesh);
}

static void make_views(mlb_view* v, int n) {
    for (int i = 0; i < n; i++) {
        memset(&v[i], 0, sizeof v[i]);
        v[i].azimuth_deg = 30 + 100 * i;
        v[i].elevation_deg = 20 - 25 * i;
        v[i].radius = 2.6;
        v[i].env = i % 2;
        v[i].env_rotation_deg = 40.0f + 75.0f * i;
        v[i].target = -1;
        mlb_camera_orbit(&v[i].cam, v[i].azimuth_deg, v[i].elevation_deg, v[i].radius, NULL, 45, 1, 0.1, 100);
    }
}

// Renders n views of the sphere with two copies of one random latent-mode network, one on the
// host and one moved to `be`'s device (and rendered with `be`), for `steps` AdamW steps (eps 1e-4, so that the update is
// smooth in the gradient and rounding cannot flip a step's sign), each comparing the images, the
// gradients and then the parameters (relative L2 within tol), and the material smoothness term.
// The loss is ½|image − 0.3|² (from the host's image): a coherent gradient, which a ReLU flipped by
// rounding at one sample moves by about one part in the sample count (field_twin_check).
static inline void appearance_twin_check(const mlb_backend* be, int n, int res, int ss, int steps, double tol) {
    scene sc;
    REQUIRE(scene_init(&sc, 48, 24));
    mlb_brdf_ae prior;
    REQUIRE(random_prior(&prior));
    mlb_material_config c = mlb_material_default();
    c.enc = (mlb_hashgrid_config){8, 2, 1 << 14, 4, 1.5};
    c.hidden = 32;
    c.seed = 11;
    mlb_material_net net[2];
    for (int t = 0; t < 2; t++) {
        REQUIRE(material_net_init(&net[t], &c, &prior) == MLB_OK);
        for (size_t i = 0; i < net[t].n_enc; i++) net[t].params[i] = 0.3f * mlb_rng_normal(21, 0, i);
    }
    REQUIRE(mlb_field_use_device(&net[1], be) == MLB_OK);
    CHECK(mlb_field_backend(&net[1]) == be && mlb_field_backend(&net[0]) == NULL);
    mlb_view* views = calloc((size_t)n, sizeof *views);
    make_views(views, n);
    size_t m = (size_t)n * res * res * 4, np = net[0].n_params;
    float *img[2] = {malloc(sizeof(float) * m), malloc(sizeof(float) * m)}, *dimg = malloc(sizeof(float) * m);
    float* grads0 = malloc(sizeof(float) * np);
    enum { SP = 3000 };
    float* pts = malloc(sizeof(float) * 3 * SP);
    REQUIRE(mlb_mesh_sample_surface(&sc.mesh, pts, SP, 5, 0) == MLB_OK);
    mlb_appearance app[2];
    memset(app, 0, sizeof app);
    app[1].be = be;   // the render on the network's table: its buffers there too
    mlb_adam_config adam = mlb_material_adam(1e-2);
    adam.eps = 1e-4;
    for (int it = 0; it < steps; it++) {
        double smooth[2];
        for (int t = 0; t < 2; t++) {
            material_net_zero_grad(&net[t]);
            REQUIRE(mlb_appearance_render(&app[t], &net[t], &sc.mesh, sc.ptr, views, n, res, ss, img[t], 1) == MLB_OK);
            if (t == 0)
                for (size_t i = 0; i < m; i++) dimg[i] = img[0][i] - 0.3f;
            REQUIRE(mlb_appearance_backward(&app[t], &net[t], dimg) == MLB_OK);
            REQUIRE(mlb_material_smoothness(&net[t], pts, SP, 0.02, 0.03, 0.02, 9, it, 1, &smooth[t]) == MLB_OK);
        }
        char what[64];
        snprintf(what, sizeof what, "step %d: images", it);
        CHECK_PARITY(what, img[1], img[0], m, tol);
        CHECK_CLOSE(smooth[1], smooth[0], 10 * tol, 1e-9);
        // the host's copy is behind until synced: eval refuses it
        float k[7];
        CHECK(mlb_material_eval(&net[1], pts, 1, k) == MLB_ERR_ARG);
        memcpy(grads0, net[0].grads, sizeof(float) * np);
        REQUIRE(mlb_field_sync_host(&net[1]) == MLB_OK);
        snprintf(what, sizeof what, "step %d: table gradient", it);
        CHECK_PARITY(what, net[1].grads, grads0, net[0].n_enc, 10 * tol);
        snprintf(what, sizeof what, "step %d: MLP gradient", it);
        CHECK_PARITY(what, net[1].grads + net[0].n_enc, grads0 + net[0].n_enc, net[0].n_mlp, 10 * tol);
        // the device's gradient to the host and back, as the pipeline sums several batches' (the
        // update below would see zeros if the way back failed)
        REQUIRE(mlb_field_grads_get(&net[1], grads0) == MLB_OK);
        CHECK(!memcmp(grads0, net[1].grads, sizeof(float) * np));
        material_net_zero_grad(&net[1]);
        REQUIRE(mlb_field_grads_set(&net[1], grads0) == MLB_OK);
        for (int t = 0; t < 2; t++) REQUIRE(material_net_update(&net[t], &adam) == MLB_OK);
    }
    REQUIRE(mlb_field_leave_device(&net[1]) == MLB_OK);
    CHECK(mlb_field_backend(&net[1]) == NULL && net[1].step == steps);
    CHECK_PARITY("parameters after the steps", net[1].params, net[0].params, np, tol);
    CHECK_PARITY("Adam second moments", net[1].adam_v, net[0].adam_v, np, 10 * tol);
    float k[2][7 * 16];
    for (int t = 0; t < 2; t++) REQUIRE(mlb_material_eval(&net[t], pts, 16, k[t]) == MLB_OK);
    CHECK_PARITY("eval after leaving the device", k[1], k[0], 7 * 16, tol);
    for (int t = 0; t < 2; t++) {
        mlb_appearance_free(&app[t]);
        material_net_free(&net[t]);
        free(img[t]);
    }
    free(dimg); free(grads0); free(pts); free(views);
    brdf_ae_free(&prior);
    scene_free(&sc);
}

#endif
