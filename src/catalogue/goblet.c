// The procedural goblet: a lathe profile swept about +y, and its materials (include/matlaber/goblet.h).
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/goblet.h"

// The profile (radius, height) from the bottom centre, out along the underside of the foot, up the
// outside, over the rim and down into the dish to the top centre. Corners are kept; long segments
// are subdivided so that no ring is more than MAX_STEP from the next.
static const float PROFILE[][2] = {
    {0.00f, -0.74f},   // bottom centre
    {0.45f, -0.74f},   // underside of the foot
    {0.45f, -0.56f},   // foot edge (0.18 tall)
    {0.30f, -0.47f},   // foot slope
    {0.15f, -0.38f},   // stem base
    {0.12f, -0.20f},   // stem waist (0.24 wide)
    {0.13f, -0.05f},
    {0.17f, 0.05f},    // the stem flares into the cup
    {0.30f, 0.14f},
    {0.42f, 0.27f},
    {0.50f, 0.45f},
    {0.53f, 0.62f},    // widest
    {0.51f, 0.70f},    // rim, outside
    {0.36f, 0.70f},    // rim, inside (0.15 wide)
    {0.20f, 0.62f},    // dish
    {0.00f, 0.60f},    // top centre (the dish is 0.10 deep)
};
#define N_PROFILE ((int)(sizeof PROFILE / sizeof PROFILE[0]))
#define MAX_STEP 0.03f

static const float GOLD[7] = {0.01f, 0.01f, 0.01f, 1.000f, 0.766f, 0.336f, 0.25f};
static const float COBALT[7] = {0.02f, 0.06f, 0.45f, 0.04f, 0.04f, 0.04f, 0.15f};
static const float WHITE[7] = {0.80f, 0.80f, 0.76f, 0.04f, 0.04f, 0.04f, 0.15f};

void mlb_goblet_material(const float* pos, float k[7]) {
    float y = pos[1];
    const float* m = y >= MLB_GOBLET_CUP_Y ? GOLD : (y < MLB_GOBLET_BAND_Y ? WHITE : COBALT);
    memcpy(k, m, sizeof(float) * 7);
}

void mlb_goblet_materials(const mlb_mesh* m, float* k) {
    for (int i = 0; i < m->n_verts; i++) mlb_goblet_material(m->pos + 3 * (size_t)i, k + 7 * (size_t)i);
}

mlb_status mlb_goblet_mesh(mlb_mesh* out, int segments) {
    memset(out, 0, sizeof *out);
    if (segments < 8 || segments > 4096) return mlb_fail(MLB_ERR_ARG, "goblet: %d segments (need 8..4096)", segments);
    // densify the profile: points[0] and points[n-1] are on the axis, the rest become rings
    int cap = 1;
    for (int i = 0; i + 1 < N_PROFILE; i++) {
        float dr = PROFILE[i + 1][0] - PROFILE[i][0], dy = PROFILE[i + 1][1] - PROFILE[i][1];
        cap += (int)ceilf(sqrtf(dr * dr + dy * dy) / MAX_STEP);
    }
    float(*pts)[2] = malloc(sizeof *pts * (size_t)cap);
    if (!pts) return mlb_fail(MLB_ERR_NOMEM, "goblet: out of memory");
    int np = 0;
    pts[np][0] = PROFILE[0][0]; pts[np][1] = PROFILE[0][1]; np++;
    for (int i = 0; i + 1 < N_PROFILE; i++) {
        float dr = PROFILE[i + 1][0] - PROFILE[i][0], dy = PROFILE[i + 1][1] - PROFILE[i][1];
        int steps = (int)ceilf(sqrtf(dr * dr + dy * dy) / MAX_STEP);
        for (int s = 1; s <= steps; s++) {
            float t = (float)s / (float)steps;
            pts[np][0] = PROFILE[i][0] + t * dr;
            pts[np][1] = PROFILE[i][1] + t * dy;
            np++;
        }
    }
    int rings = np - 2, S = segments;
    int V = 2 + rings * S, F = 2 * S * (rings - 1) + 2 * S;
    out->pos = malloc(sizeof(float) * 3 * (size_t)V);
    out->faces = malloc(sizeof(int32_t) * 3 * (size_t)F);
    if (!out->pos || !out->faces) { free(pts); mlb_mesh_free(out); return mlb_fail(MLB_ERR_NOMEM, "goblet: out of memory"); }
    // vertex 0: bottom pole, 1 + r·S + j: ring r at angle j, V − 1: top pole
    float* p = out->pos;
    p[0] = 0; p[1] = pts[0][1]; p[2] = 0;
    for (int r = 0; r < rings; r++)
        for (int j = 0; j < S; j++) {
            double a = 2 * M_PI * j / S;
            float* q = p + 3 * (1 + (size_t)r * S + j);
            q[0] = (float)(pts[r + 1][0] * sin(a));
            q[1] = pts[r + 1][1];
            q[2] = (float)(pts[r + 1][0] * cos(a));
        }
    float* top = p + 3 * (size_t)(V - 1);
    top[0] = 0; top[1] = pts[np - 1][1]; top[2] = 0;
    free(pts);
    // Walking the profile goes outward under the foot, up the side and inward over the top; the
    // angle turns from +z towards +x, so (ring r, j), (r, j+1), (r+1, j) is counter-clockwise seen
    // from outside (the normal e.g. at j = 0 of a vertical wall is +z).
    int32_t* f = out->faces;
    int nf = 0;
#define RV(r, j) (1 + (r) * S + ((j) % S))
    for (int j = 0; j < S; j++) {   // bottom fan: seen from below
        f[3 * nf] = 0; f[3 * nf + 1] = RV(0, j + 1); f[3 * nf + 2] = RV(0, j); nf++;
    }
    for (int r = 0; r + 1 < rings; r++)
        for (int j = 0; j < S; j++) {
            int a = RV(r, j), b = RV(r, j + 1), c = RV(r + 1, j), d = RV(r + 1, j + 1);
            f[3 * nf] = a; f[3 * nf + 1] = b; f[3 * nf + 2] = c; nf++;
            f[3 * nf] = b; f[3 * nf + 1] = d; f[3 * nf + 2] = c; nf++;
        }
    for (int j = 0; j < S; j++) {   // top fan
        f[3 * nf] = V - 1; f[3 * nf + 1] = RV(rings - 1, j); f[3 * nf + 2] = RV(rings - 1, j + 1); nf++;
    }
#undef RV
    out->n_verts = V;
    out->n_faces = nf;
    return mlb_mesh_compute_normals(out);
}
