// Random orbit cameras of the optimisation stages (reference.md §7, docs/guidance.md), shared by the
// SDS guidance and the pipeline. One view = one camera on a sphere around the origin plus the
// environment it is lit by (appearance stage):
//   radius 3, fovy U[25.7°, 45°], elevation U[−10°, 45°], azimuth U[−180°, 180°),
//   a small look-at jitter: the camera is shifted in its own image plane by (jx, jy) ~ U[−j, j]²
//   (j = 0.05 world units by default, ≈ 1.7% of the radius: eye and target move together, so the
//   view direction is unchanged and the object moves on screen by at most ~2% of the image),
//   environment U{0 .. n_envs − 1}, environment rotation about +y U[0°, 360°).
// Every number is Philox of (seed, stream 0x0B17'0000 + stage, index (step·2^20 + view)·2 + k): a pure
// function of (seed, stage, step, view), the same on any thread count and after a resume.
#ifndef MATLABER_CAMERAS_H
#define MATLABER_CAMERAS_H
#include <stdint.h>
#include "matlaber/error.h"
#include "matlaber/guidance.h"

typedef struct {
    double radius;                 // 3
    double fovy_min, fovy_max;     // 25.7, 45 (degrees)
    double el_min, el_max;         // −10, 45
    double az_min, az_max;         // −180, 180
    double jitter;                 // look-at jitter half-width in world units, 0.05 (0: none)
    double near_z, far_z;          // 0.1, 100
    int n_envs;                    // environment pool size, 1
    int fixed_env;                 // 1: env 0, rotation 0 always (the single-environment ablation)
} mlb_orbit_config;

mlb_orbit_config mlb_orbit_default(void);
// MLB_ERR_ARG naming the bad field (radius ≤ 0, fovy outside (0, 180), empty ranges, n_envs < 1).
mlb_status mlb_orbit_check(const mlb_orbit_config* c);
// View `index` (0 ≤ index < 2^20) of iteration `step` (≥ 0) of `stage`: camera (aspect 1),
// azimuth, elevation, radius, env, env_rotation_deg; target = −1.
mlb_status mlb_orbit_sample(mlb_view* v, const mlb_orbit_config* c, uint64_t seed, int stage, long step, int index);

#endif
