// Painting a given mesh (paint.h): a camera moved into the paint frame with the mesh sees the moved
// mesh exactly where the original camera saw the original (image guidance on a mesh, docs/paint.md).
#include "test.h"
#include "matlaber/paint.h"
#include "matlaber/raster.h"

static void project(const mlb_camera* c, const double p[3], double out[3]) {   // NDC x, y and view depth
    const double* M = c->view_proj.m;
    double w = M[12] * p[0] + M[13] * p[1] + M[14] * p[2] + M[15];
    for (int r = 0; r < 2; r++) out[r] = (M[4 * r] * p[0] + M[4 * r + 1] * p[1] + M[4 * r + 2] * p[2] + M[4 * r + 3]) / w;
    out[2] = w;
}

TEST(frame_camera) {
    const double centre[3] = {100, 50, -20}, scale = 0.05;
    const double target[3] = {101, 48, -19};
    mlb_camera cam, moved;
    REQUIRE(mlb_camera_orbit(&cam, 37, 21, 60, target, 40, 1, 0.5, 500) == MLB_OK);
    moved = cam;
    REQUIRE(mlb_paint_frame_camera(centre, scale, &moved) == MLB_OK);
    double worst = 0;
    for (int i = 0; i < 50; i++) {
        double p[3] = {centre[0] + (i % 5) * 3.1 - 6, centre[1] + (i % 7) * 2.3 - 7, centre[2] + (i % 3) * 4.7 - 4}, q[3], a[3], b[3];
        for (int k = 0; k < 3; k++) q[k] = (p[k] - centre[k]) * scale;
        project(&cam, p, a);
        project(&moved, q, b);
        worst = fmax(worst, fmax(fabs(a[0] - b[0]), fabs(a[1] - b[1])));
        CHECK_CLOSE(b[2], a[2] * scale, 1e-9, 1e-12);   // depth scales with the scene
    }
    CHECK_MSG(worst < 1e-12, "NDC differs by %g", worst);
    CHECK_CLOSE(moved.near_z, 0.5 * scale, 1e-12, 0);
    CHECK_CLOSE(moved.eye[0], (cam.eye[0] - centre[0]) * scale, 1e-12, 1e-12);
}

int main(void) {
    RUN(frame_camera);
    return test_summary();
}
