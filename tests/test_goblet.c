// The procedural goblet (goblet.h): a closed, consistently oriented genus-0 surface of the expected
// volume inside the unit sphere, with its real materials on the surface.
#include <stdint.h>
#include "matlaber/brdf.h"
#include "matlaber/goblet.h"
#include "test.h"

static int cmp_u64(const void* a, const void* b) {
    uint64_t x = *(const uint64_t*)a, y = *(const uint64_t*)b;
    return x < y ? -1 : x > y;
}

// Every directed edge once and its reverse once: each undirected edge in exactly two faces, and
// the two faces agree on orientation. Returns the number of undirected edges, -1 on failure.
static long check_closed(const mlb_mesh* m) {
    size_t n = 3 * (size_t)m->n_faces;
    uint64_t* e = malloc(sizeof(uint64_t) * n);
    for (int f = 0; f < m->n_faces; f++)
        for (int k = 0; k < 3; k++) {
            uint64_t a = (uint32_t)m->faces[3 * f + k], b = (uint32_t)m->faces[3 * f + (k + 1) % 3];
            e[3 * (size_t)f + k] = a << 32 | b;
        }
    qsort(e, n, sizeof *e, cmp_u64);
    long bad = 0;
    for (size_t i = 0; i < n; i++) {
        if (i + 1 < n && e[i] == e[i + 1]) bad++;   // a directed edge twice: orientation flips or > 2 faces
        uint64_t rev = (e[i] & 0xffffffffu) << 32 | e[i] >> 32;
        if (!bsearch(&rev, e, n, sizeof *e, cmp_u64)) bad++;   // boundary edge
    }
    free(e);
    return bad ? -1 : (long)(n / 2);
}

static double signed_volume(const mlb_mesh* m) {
    double v = 0;
    for (int f = 0; f < m->n_faces; f++) {
        const float *a = m->pos + 3 * m->faces[3 * f], *b = m->pos + 3 * m->faces[3 * f + 1], *c = m->pos + 3 * m->faces[3 * f + 2];
        v += (a[0] * ((double)b[1] * c[2] - (double)b[2] * c[1]) - a[1] * ((double)b[0] * c[2] - (double)b[2] * c[0]) +
              a[2] * ((double)b[0] * c[1] - (double)b[1] * c[0])) / 6.0;
    }
    return v;
}

TEST(closed_genus0_outward) {
    mlb_mesh m;
    REQUIRE(mlb_goblet_mesh(&m, 48) == MLB_OK);
    long E = check_closed(&m);
    CHECK_MSG(E > 0, "not watertight / not consistently oriented");
    CHECK(m.n_verts - E + m.n_faces == 2);   // Euler characteristic of a sphere
    CHECK(signed_volume(&m) > 0);            // counter-clockwise outward faces
    CHECK(m.normal != NULL);
    for (int f = 0; f < m.n_faces; f++) {
        int a = m.faces[3 * f], b = m.faces[3 * f + 1], c = m.faces[3 * f + 2];
        if (a == b || b == c || a == c || a < 0 || b < 0 || c < 0 || a >= m.n_verts || b >= m.n_verts || c >= m.n_verts) {
            CHECK_MSG(0, "face %d is degenerate or out of range", f);
            break;
        }
    }
    mlb_mesh_free(&m);
    CHECK(mlb_goblet_mesh(&m, 7) == MLB_ERR_ARG);
    CHECK(mlb_goblet_mesh(&m, 5000) == MLB_ERR_ARG);
}

// Volume of the solid of revolution of the documented profile (Pappus, frustum by frustum):
// the mesh is the lathe of inscribed regular S-gons, which hold S sin(2π/S) / (2π) of each disc.
TEST(volume_matches_the_profile) {
    static const double P[][2] = {{0.00, -0.74}, {0.45, -0.74}, {0.45, -0.56}, {0.30, -0.47}, {0.15, -0.38}, {0.12, -0.20},
                                  {0.13, -0.05}, {0.17, 0.05},  {0.30, 0.14},  {0.42, 0.27},  {0.50, 0.45},  {0.53, 0.62},
                                  {0.51, 0.70},  {0.36, 0.70},  {0.20, 0.62},  {0.00, 0.60}};
    int n = (int)(sizeof P / sizeof P[0]);
    double exact = 0;
    for (int i = 0; i + 1 < n; i++) {
        double r0 = P[i][0], r1 = P[i + 1][0], dy = P[i + 1][1] - P[i][1];
        exact += M_PI / 3 * dy * (r0 * r0 + r0 * r1 + r1 * r1);
    }
    int S = 256;
    mlb_mesh m;
    REQUIRE(mlb_goblet_mesh(&m, S) == MLB_OK);
    double factor = S * sin(2 * M_PI / S) / (2 * M_PI);
    CHECK_CLOSE(signed_volume(&m), exact * factor, 1e-4, 0);   // the trapezoids are planar: exact
    mlb_mesh_free(&m);
}

TEST(inside_unit_sphere_and_wide_enough) {
    mlb_mesh m;
    REQUIRE(mlb_goblet_mesh(&m, 64) == MLB_OK);
    double rmax = 0, ymin = 1e9, ymax = -1e9, stem_min = 1e9;
    for (int i = 0; i < m.n_verts; i++) {
        const float* p = m.pos + 3 * i;
        double r = sqrt((double)p[0] * p[0] + (double)p[1] * p[1] + (double)p[2] * p[2]);
        if (r > rmax) rmax = r;
        if (p[1] < ymin) ymin = p[1];
        if (p[1] > ymax) ymax = p[1];
        double h = sqrt((double)p[0] * p[0] + (double)p[2] * p[2]);
        if (p[1] > -0.38 && p[1] < 0.05) stem_min = fmin(stem_min, h);   // the stem
    }
    CHECK(rmax <= 0.9);
    CHECK(rmax >= 0.8);            // it uses the sphere
    CHECK(fabs(ymin + ymax) < 0.2);   // roughly centred
    CHECK(2 * stem_min >= 0.15);   // the narrowest feature is >= 0.15 wide
    mlb_mesh_free(&m);
}

TEST(materials) {
    mlb_mesh m;
    REQUIRE(mlb_goblet_mesh(&m, 32) == MLB_OK);
    float* k = malloc(sizeof(float) * 7 * m.n_verts);
    mlb_goblet_materials(&m, k);
    int gold = 0, cobalt = 0, white = 0;
    for (int i = 0; i < m.n_verts; i++) {
        const float* q = k + 7 * i;
        CHECK(mlb_brdf_valid(q));
        if (q[3] == 1.0f && q[4] == 0.766f && q[5] == 0.336f && q[0] <= 0.02f && q[6] == 0.25f) gold++;   // reference.md §1
        else if (q[3] == 0.04f && q[2] > 3 * q[0] && q[2] > 0.3f) cobalt++;
        else if (q[3] == 0.04f && q[0] > 0.7f) white++;
    }
    CHECK(gold > m.n_verts / 4);
    CHECK(cobalt > m.n_verts / 10);
    CHECK(white > 0);
    CHECK(gold + cobalt + white == m.n_verts);
    // defined everywhere, a pure function of position
    for (int i = 0; i < 1000; i++) {
        float p[3] = {(float)(sin(i * 1.3) * 5), (float)(cos(i * 0.7) * 5), (float)(sin(i * 2.1) * 5)}, a[7], b[7];
        mlb_goblet_material(p, a);
        mlb_goblet_material(p, b);
        CHECK(mlb_brdf_valid(a));
        CHECK(memcmp(a, b, sizeof a) == 0);
    }
    float above[3] = {0, 0.5f, 0}, below[3] = {0, -0.3f, 0}, k1[7], k2[7];
    mlb_goblet_material(above, k1);
    mlb_goblet_material(below, k2);
    CHECK(k1[3] == 1.0f && k2[3] == 0.04f);
    free(k);
    mlb_mesh_free(&m);
}

int main(void) {
    RUN(closed_genus0_outward);
    RUN(volume_matches_the_profile);
    RUN(inside_unit_sphere_and_wide_enough);
    RUN(materials);
    return test_summary();
}
