// Tests of the fit measures (include/matlaber/evaluate.h) that the other tests do not reach: the
// angle between normals, on analytic cases (the same surface, normals tilted by a known angle,
// faceted against smooth), and its errors.
#include "test.h"
#include "matlaber/evaluate.h"
#include "matlaber/mesh.h"

// n' = cos(t)·n + sin(t)·w with w a unit vector perpendicular to n: exactly t from n at each vertex.
static void tilt_normals(float* out, const float* n, int V, double t) {
    for (int i = 0; i < V; i++) {
        const float* a = n + 3 * i;
        double ax[3] = {0.6, 0.48, 0.64};   // any fixed axis; w = unit(n x ax)
        double w[3] = {a[1] * ax[2] - a[2] * ax[1], a[2] * ax[0] - a[0] * ax[2], a[0] * ax[1] - a[1] * ax[0]};
        double l = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
        for (int c = 0; c < 3; c++) out[3 * i + c] = (float)(cos(t) * a[c] + sin(t) * w[c] / l);
    }
}

TEST(normal_angle_analytic) {
    mlb_mesh a = {0}, b = {0};
    REQUIRE(mlb_mesh_uv_sphere(&a, 0.8f, 96, 48) == MLB_OK);
    REQUIRE(mlb_mesh_uv_sphere(&b, 0.8f, 96, 48) == MLB_OK);
    double deg = -1;
    size_t covered = 0;
    REQUIRE(mlb_eval_normals(&a, &b, 6, 96, &deg, &covered) == MLB_OK);
    CHECK(deg >= 0 && deg < 1e-3);   // the same surface
    CHECK(covered > 6 * 96 * 96 / 5);
    // normals tilted by 20° at every vertex: 20° everywhere but where the tilt direction turns fast
    // (near the axis, where interpolation between vertices shortens the tilt)
    tilt_normals(b.normal, a.normal, a.n_verts, 20.0 * M_PI / 180.0);
    REQUIRE(mlb_eval_normals(&a, &b, 6, 96, &deg, NULL) == MLB_OK);
    printf("  tilted by 20 degrees: mean %.3f degrees\n", deg);
    CHECK_CLOSE(deg, 20.0, 0.02, 0.0);
    // without normals the fit gets area-weighted vertex normals: a coarse sphere's, a few degrees off
    mlb_mesh c = {0};
    REQUIRE(mlb_mesh_uv_sphere(&c, 0.8f, 12, 6) == MLB_OK);
    free(c.normal);
    c.normal = NULL;
    REQUIRE(mlb_eval_normals(&a, &c, 6, 96, &deg, NULL) == MLB_OK);
    printf("  12 x 6 sphere, area-weighted normals: mean %.3f degrees\n", deg);
    CHECK(deg > 1 && deg < 15);
    mlb_mesh_free(&a); mlb_mesh_free(&b); mlb_mesh_free(&c);
}

TEST(normal_angle_errors) {
    mlb_mesh a = {0}, b = {0};
    REQUIRE(mlb_mesh_uv_sphere(&a, 0.5f, 16, 8) == MLB_OK);
    REQUIRE(mlb_mesh_uv_sphere(&b, 0.5f, 16, 8) == MLB_OK);
    double deg;
    CHECK(mlb_eval_normals(&a, &b, 0, 64, &deg, NULL) == MLB_ERR_ARG);
    CHECK(mlb_eval_normals(&a, &b, 3, 4, &deg, NULL) == MLB_ERR_ARG);
    for (int i = 0; i < b.n_verts; i++) b.pos[3 * i] += 50.0f;   // out of every view
    CHECK(mlb_eval_normals(&a, &b, 3, 64, &deg, NULL) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "no pixel") != NULL);
    mlb_mesh_free(&a); mlb_mesh_free(&b);
}

int main(void) {
    RUN(normal_angle_analytic);
    RUN(normal_angle_errors);
    return test_summary();
}
