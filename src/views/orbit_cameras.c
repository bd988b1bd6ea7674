// Random orbit cameras (include/matlaber/cameras.h, docs/guidance.md).
#include <math.h>
#include <string.h>
#include "matlaber/cameras.h"
#include "matlaber/rng.h"

#define ORBIT_STREAM 0x0B170000ull   // + stage

mlb_orbit_config mlb_orbit_default(void) {
    mlb_orbit_config c;
    memset(&c, 0, sizeof c);
    c.radius = MLB_ORBIT_RADIUS;
    c.fovy_min = MLB_ORBIT_FOVY_MIN;
    c.fovy_max = MLB_ORBIT_FOVY_MAX;
    c.el_min = MLB_ORBIT_EL_MIN;
    c.el_max = MLB_ORBIT_EL_MAX;
    c.az_min = -180.0;
    c.az_max = 180.0;
    c.jitter = 0.05;
    c.near_z = MLB_ORBIT_NEAR;
    c.far_z = MLB_ORBIT_FAR;
    c.n_envs = 1;
    c.fixed_env = 0;
    return c;
}

mlb_status mlb_orbit_check(const mlb_orbit_config* c) {
    if (!c) return mlb_fail(MLB_ERR_ARG, "orbit cameras: NULL config");
    if (!(c->radius > 0) || !isfinite(c->radius)) return mlb_fail(MLB_ERR_ARG, "orbit cameras: radius %g must be > 0", c->radius);
    if (!(c->fovy_min > 0 && c->fovy_min <= c->fovy_max && c->fovy_max < 180))
        return mlb_fail(MLB_ERR_ARG, "orbit cameras: fovy range [%g, %g] must lie in (0, 180) and be ordered", c->fovy_min, c->fovy_max);
    if (!(c->el_min <= c->el_max && c->el_min >= -90 && c->el_max <= 90))
        return mlb_fail(MLB_ERR_ARG, "orbit cameras: elevation range [%g, %g] must lie in [-90, 90] and be ordered", c->el_min, c->el_max);
    if (!(c->az_min <= c->az_max) || !isfinite(c->az_min) || !isfinite(c->az_max))
        return mlb_fail(MLB_ERR_ARG, "orbit cameras: azimuth range [%g, %g] is not ordered", c->az_min, c->az_max);
    if (!(c->jitter >= 0) || !isfinite(c->jitter)) return mlb_fail(MLB_ERR_ARG, "orbit cameras: jitter %g must be >= 0", c->jitter);
    if (!(c->near_z > 0 && c->near_z < c->far_z)) return mlb_fail(MLB_ERR_ARG, "orbit cameras: need 0 < near < far");
    if (c->n_envs < 1) return mlb_fail(MLB_ERR_ARG, "orbit cameras: n_envs %d must be >= 1", c->n_envs);
    return MLB_OK;
}

mlb_status mlb_orbit_sample(mlb_view* v, const mlb_orbit_config* c, uint64_t seed, int stage, long step, int index) {
    if (!v) return mlb_fail(MLB_ERR_ARG, "orbit cameras: NULL view");
    MLB_TRY(mlb_orbit_check(c));
    if (step < 0 || index < 0 || index >= (1 << 20) || stage < 0 || stage > 255)
        return mlb_fail(MLB_ERR_ARG, "orbit cameras: step %ld, view %d, stage %d out of range", step, index, stage);
    uint64_t base = (((uint64_t)step << 20) | (uint64_t)index) * 2;
    mlb_u32x4 a = mlb_rng_words(seed, ORBIT_STREAM + (uint64_t)stage, base);
    mlb_u32x4 b = mlb_rng_words(seed, ORBIT_STREAM + (uint64_t)stage, base + 1);
    double az = c->az_min + (c->az_max - c->az_min) * mlb_u32_to_unit(a.v[0]);
    double el = c->el_min + (c->el_max - c->el_min) * mlb_u32_to_unit(a.v[1]);
    double fovy = c->fovy_min + (c->fovy_max - c->fovy_min) * mlb_u32_to_unit(a.v[2]);
    double jx = c->jitter * (2.0 * mlb_u32_to_unit(a.v[3]) - 1.0);
    double jy = c->jitter * (2.0 * mlb_u32_to_unit(b.v[0]) - 1.0);
    memset(v, 0, sizeof *v);
    // the unjittered camera gives the image plane's axes (rows 0 and 1 of its view matrix)
    MLB_TRY(mlb_camera_orbit(&v->cam, az, el, c->radius, NULL, fovy, 1.0, c->near_z, c->far_z));
    if (c->jitter > 0) {
        const double* m = v->cam.view.m;
        double target[3];
        for (int k = 0; k < 3; k++) target[k] = jx * m[k] + jy * m[4 + k];
        MLB_TRY(mlb_camera_orbit(&v->cam, az, el, c->radius, target, fovy, 1.0, c->near_z, c->far_z));
    }
    v->azimuth_deg = az;
    v->elevation_deg = el;
    v->radius = c->radius;
    if (c->fixed_env) {
        v->env = 0;
        v->env_rotation_deg = 0.0f;
    } else {
        v->env = (int)(((uint64_t)b.v[1] * (uint64_t)c->n_envs) >> 32);   // U{0 .. n_envs − 1} (bias < 2^-32·n)
        v->env_rotation_deg = (float)(360.0 * mlb_u32_to_unit(b.v[2]));
    }
    v->target = -1;
    return MLB_OK;
}
