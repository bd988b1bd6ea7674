// Cameras: look-at and perspective matrices, the orbit camera the pipeline samples (reference.md
// §7: radius 3, fovy 25.7°-45°, elevation -10°-45°, azimuth -180°-180°), and the transform of
// positions to clip space with its backward. Matrices are double, row-major, acting on column
// vectors (raster.h). The matrix part is compiled once; the transform is over `real` and compiled
// twice (CMakeLists.txt: MLB_DUAL_SOURCES).
#include <math.h>
#include "matlaber/raster.h"
#include "core/real.h"
#include "raster_math.h"

#ifndef MLB_F64
mlb_mat4 mlb_mat4_identity(void) {
    mlb_mat4 r = {{0}};
    r.m[0] = r.m[5] = r.m[10] = r.m[15] = 1;
    return r;
}

mlb_mat4 mlb_mat4_mul(const mlb_mat4* a, const mlb_mat4* b) {
    mlb_mat4 r;
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++) {
            double s = 0;
            for (int k = 0; k < 4; k++) s += a->m[4 * i + k] * b->m[4 * k + j];
            r.m[4 * i + j] = s;
        }
    return r;
}

static double dot3(const double a[3], const double b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
static void cross3(double r[3], const double a[3], const double b[3]) {
    r[0] = a[1] * b[2] - a[2] * b[1];
    r[1] = a[2] * b[0] - a[0] * b[2];
    r[2] = a[0] * b[1] - a[1] * b[0];
}
static int normalize3(double v[3]) {
    double n = sqrt(dot3(v, v));
    if (!(n > 1e-300) || !isfinite(n)) return 0;
    v[0] /= n; v[1] /= n; v[2] /= n;
    return 1;
}

// Rows of the rotation are the camera axes (right, up, back) in world coordinates; the camera
// looks down -back, i.e. down its -z axis, as OpenGL's gluLookAt.
mlb_status mlb_look_at(mlb_mat4* view, const double eye[3], const double target[3], const double up[3]) {
    double back[3] = {eye[0] - target[0], eye[1] - target[1], eye[2] - target[2]}, right[3], u[3];
    if (!normalize3(back)) return mlb_fail(MLB_ERR_ARG, "mlb_look_at: eye and target coincide (or are not finite)");
    cross3(right, up, back);
    if (!normalize3(right))
        return mlb_fail(MLB_ERR_ARG, "mlb_look_at: the up vector (%g, %g, %g) is parallel to the view direction",
                        up[0], up[1], up[2]);
    cross3(u, back, right);
    mlb_mat4 r = mlb_mat4_identity();
    for (int c = 0; c < 3; c++) {
        r.m[c] = right[c];
        r.m[4 + c] = u[c];
        r.m[8 + c] = back[c];
    }
    r.m[3] = -dot3(right, eye);
    r.m[7] = -dot3(u, eye);
    r.m[11] = -dot3(back, eye);
    *view = r;
    return MLB_OK;
}

mlb_status mlb_perspective(mlb_mat4* proj, double fovy_deg, double aspect, double near_z, double far_z) {
    if (!(fovy_deg > 0 && fovy_deg < 180))
        return mlb_fail(MLB_ERR_ARG, "mlb_perspective: vertical field of view %g degrees outside (0, 180)", fovy_deg);
    if (!(aspect > 0) || !isfinite(aspect))
        return mlb_fail(MLB_ERR_ARG, "mlb_perspective: aspect ratio %g must be positive", aspect);
    if (!(near_z > 0 && far_z > near_z) || !isfinite(far_z))
        return mlb_fail(MLB_ERR_ARG, "mlb_perspective: need 0 < near < far, got near %g, far %g", near_z, far_z);
    double f = 1.0 / tan(0.5 * fovy_deg * M_PI / 180.0);
    mlb_mat4 r = {{0}};
    r.m[0] = f / aspect;
    r.m[5] = f;
    r.m[10] = -(far_z + near_z) / (far_z - near_z);
    r.m[11] = -2.0 * far_z * near_z / (far_z - near_z);
    r.m[14] = -1;
    *proj = r;
    return MLB_OK;
}

mlb_status mlb_camera_orbit(mlb_camera* cam, double azimuth_deg, double elevation_deg, double radius,
                            const double target[3], double fovy_deg, double aspect, double near_z,
                            double far_z) {
    if (!(radius > 0) || !isfinite(radius))
        return mlb_fail(MLB_ERR_ARG, "mlb_camera_orbit: radius %g must be positive", radius);
    if (!isfinite(azimuth_deg) || !(elevation_deg >= -90 && elevation_deg <= 90))
        return mlb_fail(MLB_ERR_ARG, "mlb_camera_orbit: azimuth %g / elevation %g degrees (elevation must be in [-90, 90])",
                        azimuth_deg, elevation_deg);
    mlb_camera c = {0};
    c.azimuth_deg = azimuth_deg;
    c.elevation_deg = elevation_deg;
    c.radius = radius;
    c.fovy_deg = fovy_deg;
    c.aspect = aspect;
    c.near_z = near_z;
    c.far_z = far_z;
    for (int k = 0; k < 3; k++) c.target[k] = target ? target[k] : 0;
    double az = azimuth_deg * M_PI / 180, el = elevation_deg * M_PI / 180;
    double dir[3] = {cos(el) * sin(az), sin(el), cos(el) * cos(az)};
    for (int k = 0; k < 3; k++) c.eye[k] = c.target[k] + radius * dir[k];
    // y is up, except looking straight down or up, where the camera's up is the horizontal
    // direction it would have at a slightly lower elevation.
    double up[3] = {0, 1, 0};
    if (fabs(elevation_deg) > 89.999) {
        double s = elevation_deg > 0 ? -1 : 1;
        up[0] = s * sin(az); up[1] = 0; up[2] = s * cos(az);
    }
    MLB_TRY(mlb_look_at(&c.view, c.eye, c.target, up));
    MLB_TRY(mlb_perspective(&c.proj, fovy_deg, aspect, near_z, far_z));
    c.view_proj = mlb_mat4_mul(&c.proj, &c.view);
    *cam = c;
    return MLB_OK;
}
#endif

// clip[v] = M · [pos[v], 1], computed in double (raster_math.h, the CUDA kernel's maths too).
void FN(mlb_transform_points)(real* clip, const real* pos, int n_verts, const mlb_mat4* m) {
#pragma omp parallel for schedule(static) if (n_verts > 16384)
    for (int v = 0; v < n_verts; v++) rast_transform_point(clip + 4 * (size_t)v, pos + 3 * (size_t)v, m->m);
}

// dpos[v, c] += sum_r dclip[v, r] M[r, c]
void FN(mlb_transform_points_backward)(real* dpos, const real* dclip, int n_verts, const mlb_mat4* m) {
    if (!dpos) return;
#pragma omp parallel for schedule(static) if (n_verts > 16384)
    for (int v = 0; v < n_verts; v++) rast_transform_point_backward(dpos + 3 * (size_t)v, dclip + 4 * (size_t)v, m->m);
}
