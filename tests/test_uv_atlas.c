// UV atlas (uv_atlas.h): on a cube, a uv sphere, a parametric torus, a marching-tets torus (slivers,
// genus 1), an overlapping helical ramp, and the real meshes of ../shared/data: UVs in [0,1], every
// non-degenerate face with positive UV area, each input face present once (same corners through
// vert_src), no two faces overlapping in UV (rasterised at texel centres of a 2048² grid, strict
// interior), stretch within the bound the construction guarantees, utilisation above a floor.
#include <stdint.h>
#include "matlaber/dmtet.h"
#include "matlaber/obj.h"
#include "matlaber/uv_atlas.h"
#include "test.h"

// Orthographic projection within a cone of half-angle θ: Γ = 1/cos(face-to-axis angle) ≤ 1/cos θ,
// γ = 1; the normalisation factor sqrt(ΣA_uv/ΣA_3d)·(texels per unit)⁻¹ = sqrt(mean cos) ≤ 1, so
// L∞ ≤ 1/cos θ and L2 ≤ sqrt((1/cos²θ + 1)/2).
static double linf_bound(float deg) { return 1.0 / cos(deg * M_PI / 180.0) * (1 + 1e-4); }
static double l2_bound(float deg) { double c = cos(deg * M_PI / 180.0); return sqrt((1 / (c * c) + 1) / 2) * (1 + 1e-4); }

typedef struct { int overlaps, out_of_range, non_positive, bad_corners; } atlas_check;

// A face's vertices turned so that the smallest comes first: equal keys are one face given twice.
typedef struct { int32_t v[3], f; } tri_key;
static int tri_key_cmp(const void* x, const void* y) {
    const tri_key *a = x, *b = y;
    int c = memcmp(a->v, b->v, sizeof a->v);
    return c ? c : a->f - b->f;
}

// [F] 1 for a face that repeats an earlier one with the same output vertices (uv_atlas.h: a repeated
// face shares its first copy's UVs, so the two cover the same texels by design)
static uint8_t* repeated_faces(const mlb_mesh* M) {
    tri_key* k = malloc(sizeof *k * (size_t)M->n_faces);
    uint8_t* rep = calloc((size_t)M->n_faces, 1);
    for (int f = 0; f < M->n_faces; f++) {
        const int32_t* t = M->faces + 3 * f;
        int r = (t[1] < t[0] && t[1] <= t[2]) ? 1 : (t[2] < t[0] && t[2] < t[1]) ? 2 : 0;
        k[f] = (tri_key){{t[r], t[(r + 1) % 3], t[(r + 2) % 3]}, f};
    }
    qsort(k, (size_t)M->n_faces, sizeof *k, tri_key_cmp);
    for (int i = 1; i < M->n_faces; i++) rep[k[i].f] = !memcmp(k[i].v, k[i - 1].v, sizeof k[i].v);
    free(k);
    return rep;
}

static atlas_check check_atlas(const mlb_mesh* in, const mlb_uv_mesh* u) {
    atlas_check r = {0};
    const mlb_mesh* M = &u->mesh;
    for (int i = 0; i < 2 * M->n_verts; i++) r.out_of_range += !(M->uv[i] >= 0 && M->uv[i] <= 1);
    float lo[3], hi[3];
    mlb_mesh_bounds(in, lo, hi);
    double diag = 0;
    for (int k = 0; k < 3; k++) diag += (double)(hi[k] - lo[k]) * (hi[k] - lo[k]);
    diag = sqrt(diag);
    if (M->n_faces != in->n_faces) r.bad_corners = 1 << 30;
    for (int f = 0; f < M->n_faces && f < in->n_faces; f++) {
        const int32_t* t = M->faces + 3 * f;
        for (int k = 0; k < 3; k++) r.bad_corners += u->vert_src[t[k]] != in->faces[3 * f + k];
        const float* p[3] = {in->pos + 3 * in->faces[3 * f], in->pos + 3 * in->faces[3 * f + 1], in->pos + 3 * in->faces[3 * f + 2]};
        double e[3][3];
        for (int k = 0; k < 3; k++) { e[0][k] = p[1][k] - p[0][k]; e[1][k] = p[2][k] - p[0][k]; e[2][k] = p[2][k] - p[1][k]; }
        double cx = e[0][1] * e[1][2] - e[0][2] * e[1][1], cy = e[0][2] * e[1][0] - e[0][0] * e[1][2], cz = e[0][0] * e[1][1] - e[0][1] * e[1][0];
        double L2 = 0;
        for (int i = 0; i < 3; i++) L2 = fmax(L2, e[i][0] * e[i][0] + e[i][1] * e[i][1] + e[i][2] * e[i][2]);
        double height = L2 > 0 ? sqrt(cx * cx + cy * cy + cz * cz) / sqrt(L2) : 0;   // 2·area / longest edge
        const float *a = M->uv + 2 * t[0], *b = M->uv + 2 * t[1], *c = M->uv + 2 * t[2];
        double auv = (double)(b[0] - a[0]) * (c[1] - a[1]) - (double)(c[0] - a[0]) * (b[1] - a[1]);
        if (height >= MLB_UV_DEGENERATE_REL * diag && !(auv > 0)) r.non_positive++;
    }
    // strict-interior coverage of texel centres: no centre may lie inside two faces
    const int G = 2048;
    int32_t* owner = malloc(sizeof *owner * G * G);
    uint8_t* repeated = repeated_faces(M);
    for (int i = 0; i < G * G; i++) owner[i] = -1;
    for (int f = 0; f < M->n_faces; f++) {
        if (repeated[f]) continue;
        double P[3][2];
        for (int i = 0; i < 3; i++) { P[i][0] = M->uv[2 * M->faces[3 * f + i]] * G; P[i][1] = M->uv[2 * M->faces[3 * f + i] + 1] * G; }
        double A = (P[1][0] - P[0][0]) * (P[2][1] - P[0][1]) - (P[2][0] - P[0][0]) * (P[1][1] - P[0][1]);
        if (A == 0) continue;
        int x0 = (int)floor(fmin(P[0][0], fmin(P[1][0], P[2][0]))), x1 = (int)ceil(fmax(P[0][0], fmax(P[1][0], P[2][0])));
        int y0 = (int)floor(fmin(P[0][1], fmin(P[1][1], P[2][1]))), y1 = (int)ceil(fmax(P[0][1], fmax(P[1][1], P[2][1])));
        if (x0 < 0) x0 = 0;
        if (y0 < 0) y0 = 0;
        if (x1 > G - 1) x1 = G - 1;
        if (y1 > G - 1) y1 = G - 1;
        for (int y = y0; y <= y1; y++)
            for (int x = x0; x <= x1; x++) {
                double c[2] = {x + 0.5, y + 0.5}, b[3];
                for (int i = 0; i < 3; i++) {
                    const double *p = P[(i + 1) % 3], *q = P[(i + 2) % 3];
                    b[i] = ((q[0] - p[0]) * (c[1] - p[1]) - (q[1] - p[1]) * (c[0] - p[0])) / A;
                }
                if (b[0] > 1e-6 && b[1] > 1e-6 && b[2] > 1e-6) {
                    if (owner[y * G + x] >= 0) r.overlaps++;
                    owner[y * G + x] = f;
                }
            }
    }
    free(owner);
    free(repeated);
    return r;
}

static void report(const char* name, const mlb_uv_stats* s) {
    printf("  %-14s faces %6d  charts %5d  verts %6d  degenerate %4d  split %3d  cut %3d  util %.3f  L2 %.4f  Linf %.4f\n", name,
           s->n_faces, s->n_charts, s->n_verts, s->n_degenerate, s->n_split, s->n_cut, s->utilisation, s->stretch_l2, s->stretch_linf);
}

// Full check of one mesh at the default options; returns the stats.
static mlb_uv_stats unwrap_and_check(const char* name, const mlb_mesh* in, double util_floor) {
    mlb_uv_mesh u;
    mlb_uv_stats s;
    memset(&s, 0, sizeof s);
    mlb_status st = mlb_uv_unwrap(in, NULL, &u, &s);
    CHECK_MSG(st == MLB_OK, "%s: %s", name, mlb_last_error());
    if (st != MLB_OK) return s;
    report(name, &s);
    atlas_check r = check_atlas(in, &u);
    CHECK_MSG(r.overlaps == 0, "%s: %d texel centres inside two faces", name, r.overlaps);
    CHECK_MSG(r.out_of_range == 0, "%s: %d uv coordinates outside [0,1]", name, r.out_of_range);
    CHECK_MSG(r.non_positive == 0, "%s: %d faces with non-positive uv area", name, r.non_positive);
    CHECK_MSG(r.bad_corners == 0, "%s: %d corners differ from the input's", name, r.bad_corners);
    float deg = mlb_uv_default().max_angle_deg;
    CHECK_MSG(s.stretch_linf >= 1 - 1e-4 && s.stretch_linf <= linf_bound(deg), "%s: Linf %g", name, s.stretch_linf);
    CHECK_MSG(s.stretch_l2 >= 1 - 1e-4 && s.stretch_l2 <= l2_bound(deg), "%s: L2 %g", name, s.stretch_l2);
    CHECK_MSG(s.utilisation > util_floor && s.utilisation <= 1, "%s: utilisation %g", name, s.utilisation);
    CHECK(u.n_charts == s.n_charts && u.mesh.normal != NULL);
    for (int f = 0; f < u.mesh.n_faces; f++)
        if (u.face_chart[f] < 0 || u.face_chart[f] >= u.n_charts) { CHECK_MSG(0, "%s: face %d chart %d", name, f, u.face_chart[f]); break; }
    // the three corners of a face share its chart's vertices: a vertex belongs to one chart
    int32_t* vchart = malloc(sizeof *vchart * u.mesh.n_verts);
    for (int i = 0; i < u.mesh.n_verts; i++) vchart[i] = -1;
    int mixed = 0;
    for (int f = 0; f < u.mesh.n_faces; f++)
        for (int k = 0; k < 3; k++) {
            int v = u.mesh.faces[3 * f + k];
            if (vchart[v] >= 0 && vchart[v] != u.face_chart[f]) mixed++;
            vchart[v] = u.face_chart[f];
        }
    CHECK_MSG(mixed == 0, "%s: %d vertices shared by two charts", name, mixed);
    free(vchart);
    mlb_uv_mesh_free(&u);
    return s;
}

// Cube [-1,1]^3, 8 vertices, 12 triangles CCW from outside.
static void make_cube(mlb_mesh* m) {
    static const float P[8][3] = {{-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1}, {-1, -1, 1}, {1, -1, 1}, {1, 1, 1}, {-1, 1, 1}};
    static const int32_t Fc[12][3] = {{0, 2, 1}, {0, 3, 2}, {4, 5, 6}, {4, 6, 7}, {0, 1, 5}, {0, 5, 4},
                                      {3, 7, 6}, {3, 6, 2}, {0, 4, 7}, {0, 7, 3}, {1, 2, 6}, {1, 6, 5}};
    memset(m, 0, sizeof *m);
    m->n_verts = 8;
    m->n_faces = 12;
    m->pos = malloc(sizeof P);
    m->faces = malloc(sizeof Fc);
    memcpy(m->pos, P, sizeof P);
    memcpy(m->faces, Fc, sizeof Fc);
}

// Torus around y: major radius R, minor r, nu × nv quads (shared vertices, closed).
static void make_torus(mlb_mesh* m, double R, double r, int nu, int nv) {
    memset(m, 0, sizeof *m);
    m->n_verts = nu * nv;
    m->n_faces = 2 * nu * nv;
    m->pos = malloc(sizeof(float) * 3 * m->n_verts);
    m->faces = malloc(sizeof(int32_t) * 3 * m->n_faces);
    for (int i = 0; i < nu; i++)
        for (int j = 0; j < nv; j++) {
            double a = 2 * M_PI * i / nu, b = 2 * M_PI * j / nv;
            float* p = m->pos + 3 * (i * nv + j);
            p[0] = (float)((R + r * cos(b)) * cos(a));
            p[1] = (float)(r * sin(b));
            p[2] = (float)((R + r * cos(b)) * sin(a));
        }
    int f = 0;
    for (int i = 0; i < nu; i++)
        for (int j = 0; j < nv; j++) {
            int a = i * nv + j, b = ((i + 1) % nu) * nv + j, c = ((i + 1) % nu) * nv + (j + 1) % nv, d = i * nv + (j + 1) % nv;
            // outward: (b − a) × (d − a) points away from the tube centre for this orientation
            int32_t t1[3] = {a, d, b}, t2[3] = {b, d, c};
            memcpy(m->faces + 3 * f++, t1, sizeof t1);
            memcpy(m->faces + 3 * f++, t2, sizeof t2);
        }
}

// Marching tets on a torus SDF: the kind of mesh the pipeline produces (slivers, genus 1).
static int make_mt_torus(mlb_mesh* m, int cells) {
    mlb_tetgrid g;
    if (mlb_tetgrid_create(&g, cells, 1.0f) != MLB_OK) return 0;
    float* sdf = malloc(sizeof *sdf * g.n_verts);
    for (int i = 0; i < g.n_verts; i++) {
        const float* p = g.verts + 3 * i;
        double q = sqrt((double)p[0] * p[0] + (double)p[2] * p[2]) - 0.28;
        sdf[i] = (float)(sqrt(q * q + (double)p[1] * p[1]) - 0.12);
    }
    mlb_mt_surface s;
    int ok = marching_tets_forward(&s, &g, g.verts, sdf) == MLB_OK && mt_surface_to_mesh(&s, m) == MLB_OK;
    if (ok) mt_surface_free(&s);
    free(sdf);
    mlb_tetgrid_free(&g);
    return ok;
}

TEST(cube_exact) {
    mlb_mesh m;
    make_cube(&m);
    mlb_uv_stats s = unwrap_and_check("cube", &m, 0.6);
    CHECK(s.n_charts == 6);
    CHECK(s.n_verts == 24);
    CHECK_CLOSE(s.stretch_l2, 1.0, 0, 1e-5);    // each side is flat: an isometry up to scale
    CHECK_CLOSE(s.stretch_linf, 1.0, 0, 1e-5);
    // six equal squares shelf-packed 3 + 3 (or 2 + 2 + 2): side ≤ 1/3 of the square minus gutters
    CHECK(s.utilisation > 6.0 * pow((1024 - 3 * 8) / 3.0 / 1024, 2) * 0.999);
    mlb_mesh_free(&m);
}

TEST(uv_sphere) {
    mlb_mesh m;
    REQUIRE(mlb_mesh_uv_sphere(&m, 1.0f, 64, 32) == MLB_OK);   // seam column duplicated: welded
    unwrap_and_check("uv sphere", &m, 0.52);
    mlb_mesh_free(&m);
}

TEST(torus) {
    mlb_mesh m;
    make_torus(&m, 1.0, 0.35, 96, 32);
    unwrap_and_check("torus", &m, 0.45);
    mlb_mesh_free(&m);
}

TEST(marching_tets_torus) {
    mlb_mesh m;
    REQUIRE(make_mt_torus(&m, 48));
    unwrap_and_check("mt torus", &m, 0.44);
    mlb_mesh_free(&m);
}

// A helical ramp (1.6 turns, gently sloped, normals within 25° of +z): its projection onto one
// plane overlaps itself, so the chart must be cut.
TEST(helix_overlap_is_cut) {
    int nu = 200, nv = 4;
    mlb_mesh m;
    memset(&m, 0, sizeof m);
    m.n_verts = (nu + 1) * (nv + 1);
    m.n_faces = 2 * nu * nv;
    m.pos = malloc(sizeof(float) * 3 * m.n_verts);
    m.faces = malloc(sizeof(int32_t) * 3 * m.n_faces);
    for (int i = 0; i <= nu; i++)
        for (int j = 0; j <= nv; j++) {
            double a = 1.6 * 2 * M_PI * i / nu, r = 1.0 + 0.5 * j / nv;
            float* p = m.pos + 3 * (i * (nv + 1) + j);
            p[0] = (float)(r * cos(a)); p[1] = (float)(r * sin(a)); p[2] = (float)(0.1 * a);
        }
    int f = 0;
    for (int i = 0; i < nu; i++)
        for (int j = 0; j < nv; j++) {
            int a = i * (nv + 1) + j, b = a + 1, c = a + nv + 1, d = c + 1;
            int32_t t1[3] = {a, c, b}, t2[3] = {b, c, d};   // normal towards +z
            memcpy(m.faces + 3 * f++, t1, sizeof t1);
            memcpy(m.faces + 3 * f++, t2, sizeof t2);
        }
    mlb_uv_stats s = unwrap_and_check("helix", &m, 0.45);
    CHECK(s.n_split >= 1);
    mlb_mesh_free(&m);
}

TEST(options_and_determinism) {
    mlb_mesh m;
    REQUIRE(make_mt_torus(&m, 24));
    mlb_uv_options o = mlb_uv_default();
    o.max_angle_deg = 25;
    o.gutter = 2;
    o.texture_size = 512;
    mlb_uv_mesh a, b;
    mlb_uv_stats sa, sb;
    REQUIRE(mlb_uv_unwrap(&m, &o, &a, &sa) == MLB_OK);
    REQUIRE(mlb_uv_unwrap(&m, &o, &b, &sb) == MLB_OK);
    CHECK(a.mesh.n_verts == b.mesh.n_verts && memcmp(a.mesh.uv, b.mesh.uv, sizeof(float) * 2 * a.mesh.n_verts) == 0);
    CHECK(a.texture_size == 512);
    CHECK(sa.stretch_linf <= linf_bound(25));
    atlas_check r = check_atlas(&m, &a);
    CHECK(r.overlaps == 0 && r.non_positive == 0 && r.out_of_range == 0 && r.bad_corners == 0);
    // gutter: charts 2·gutter = 4 texels apart at 512². Sample 4×4 points per texel (strict
    // interior), give each touched texel its chart, and require no texel of another chart within
    // Chebyshev distance 2 (the 4 minus a texel of slack at each side for partly touched texels).
    {
        const int S = 512, SS = 4 * S;
        int32_t* owner = malloc(sizeof *owner * S * S);
        for (int i = 0; i < S * S; i++) owner[i] = -1;
        int conflicts = 0;
        for (int f = 0; f < a.mesh.n_faces; f++) {
            double P[3][2];
            for (int i = 0; i < 3; i++) { P[i][0] = a.mesh.uv[2 * a.mesh.faces[3 * f + i]] * SS; P[i][1] = a.mesh.uv[2 * a.mesh.faces[3 * f + i] + 1] * SS; }
            double A = (P[1][0] - P[0][0]) * (P[2][1] - P[0][1]) - (P[2][0] - P[0][0]) * (P[1][1] - P[0][1]);
            if (A == 0) continue;
            int x0 = (int)floor(fmin(P[0][0], fmin(P[1][0], P[2][0]))), x1 = (int)ceil(fmax(P[0][0], fmax(P[1][0], P[2][0])));
            int y0 = (int)floor(fmin(P[0][1], fmin(P[1][1], P[2][1]))), y1 = (int)ceil(fmax(P[0][1], fmax(P[1][1], P[2][1])));
            for (int y = y0 < 0 ? 0 : y0; y <= y1 && y < SS; y++)
                for (int x = x0 < 0 ? 0 : x0; x <= x1 && x < SS; x++) {
                    double c[2] = {x + 0.5, y + 0.5}, b[3];
                    for (int i = 0; i < 3; i++) {
                        const double *p = P[(i + 1) % 3], *q = P[(i + 2) % 3];
                        b[i] = ((q[0] - p[0]) * (c[1] - p[1]) - (q[1] - p[1]) * (c[0] - p[0])) / A;
                    }
                    if (!(b[0] >= 0 && b[1] >= 0 && b[2] >= 0)) continue;
                    int t = (y / 4) * S + x / 4;
                    if (owner[t] >= 0 && owner[t] != a.face_chart[f]) conflicts++;
                    owner[t] = a.face_chart[f];
                }
        }
        int close = 0;
        for (int y = 0; y < S; y++)
            for (int x = 0; x < S; x++) {
                int o = owner[y * S + x];
                if (o < 0) continue;
                for (int yy = y - 2; yy <= y + 2; yy++)
                    for (int xx = x - 2; xx <= x + 2; xx++)
                        if (xx >= 0 && yy >= 0 && xx < S && yy < S && owner[yy * S + xx] >= 0 && owner[yy * S + xx] != o) close++;
            }
        CHECK_MSG(conflicts == 0 && close == 0, "%d shared texels, %d texel pairs of two charts within 2 texels", conflicts, close);
        free(owner);
    }
    mlb_uv_stats sm;
    mlb_uv_measure(&a, &sm);
    CHECK_CLOSE(sm.stretch_l2, sa.stretch_l2, 1e-12, 0);
    CHECK_CLOSE(sm.utilisation, sa.utilisation, 1e-12, 0);
    mlb_uv_mesh_free(&a);
    mlb_uv_mesh_free(&b);
    mlb_mesh_free(&m);
}

// Odd input: a non-manifold edge (three faces), a duplicated face, the same face reversed, a face
// with a repeated corner and an isolated zero-area face; all come out in valid charts.
TEST(odd_topology) {
    mlb_mesh cube, m;
    make_cube(&cube);
    memset(&m, 0, sizeof m);
    m.n_verts = 10;
    m.n_faces = 12 + 6;
    m.pos = malloc(sizeof(float) * 3 * m.n_verts);
    m.faces = malloc(sizeof(int32_t) * 3 * m.n_faces);
    memcpy(m.pos, cube.pos, sizeof(float) * 24);
    float extra[6] = {0, 3, 0, 0.5f, 0.5f, 0.5f};   // a fin vertex, an interior point
    memcpy(m.pos + 24, extra, sizeof extra);
    memcpy(m.faces, cube.faces, sizeof(int32_t) * 36);
    int32_t more[6][3] = {{3, 8, 2},     // fin on the top edge 3-2 (now used by three faces)
                          {0, 2, 1},     // duplicate of face 0
                          {0, 1, 2},     // face 0 reversed
                          {4, 4, 5},     // repeated corner
                          {9, 9, 9},     // a point
                          {6, 7, 8}};
    memcpy(m.faces + 36, more, sizeof more);
    mlb_uv_mesh u;
    mlb_uv_stats st;
    REQUIRE(mlb_uv_unwrap(&m, NULL, &u, &st) == MLB_OK);
    atlas_check r = check_atlas(&m, &u);
    CHECK(r.overlaps == 0 && r.out_of_range == 0 && r.non_positive == 0 && r.bad_corners == 0);
    CHECK(st.n_degenerate == 2);
    CHECK(st.stretch_linf <= linf_bound(mlb_uv_default().max_angle_deg));
    // the repeated face is face 0 again: its first copy's vertices, so its UVs
    for (int k = 0; k < 3; k++) CHECK(u.mesh.faces[3 * 13 + k] == u.mesh.faces[k]);
    mlb_uv_mesh_free(&u);
    mlb_mesh_free(&m);
    mlb_mesh_free(&cube);
}

// Input that once made the unwrap super-linear, each ending in a valid atlas (or a clear error):
// one triangle given 400 times as an OBJ polygon (`f 1 2 3 1 2 3 ...`: 400 copies of the triangle
// and 798 slivers, fanned), a disc fanned into 2000 slivers round its centre, a strip of slivers
// joined to one triangle at its far end, and more disjoint triangles than a texture has room for.
static void mesh_alloc(mlb_mesh* m, int nv, int nf) {
    memset(m, 0, sizeof *m);
    m->n_verts = nv;
    m->n_faces = nf;
    m->pos = calloc(3 * (size_t)nv, sizeof(float));
    m->faces = malloc(sizeof(int32_t) * 3 * (size_t)nf);
}

TEST(hostile_faces) {
    mlb_mesh m;
    mlb_uv_mesh u;
    mlb_uv_stats st;
    // 1 2 3 x 400, fanned by the reader: faces (1, c_i, c_i+1)
    mesh_alloc(&m, 3, 3 * 400 - 2);
    m.pos[3] = 1;
    m.pos[7] = 1;
    for (int f = 0; f < m.n_faces; f++) {
        m.faces[3 * f] = 0;
        m.faces[3 * f + 1] = (f + 1) % 3;
        m.faces[3 * f + 2] = (f + 2) % 3;
    }
    REQUIRE(mlb_uv_unwrap(&m, NULL, &u, &st) == MLB_OK);
    atlas_check r = check_atlas(&m, &u);
    CHECK(r.overlaps == 0 && r.out_of_range == 0 && r.non_positive == 0 && r.bad_corners == 0);
    CHECK(st.n_charts == 2);   // the triangle, and the slivers no chart borders
    CHECK(st.n_degenerate == 798);
    for (int f = 3; f < m.n_faces; f += 3)   // every copy of (1 2 3): the first copy's vertices
        for (int k = 0; k < 3; k++) CHECK(u.mesh.faces[3 * f + k] == u.mesh.faces[k]);
    mlb_uv_mesh_free(&u);
    mlb_mesh_free(&m);
    // a disc of 2000 slices: the overlap check's work is bounded, the disc cut where it runs out
    const int N = 2000;
    mesh_alloc(&m, N + 1, N);
    for (int i = 0; i < N; i++) {
        m.pos[3 * (i + 1)] = (float)cos(2 * M_PI * i / N);
        m.pos[3 * (i + 1) + 1] = (float)sin(2 * M_PI * i / N);
        m.faces[3 * i] = 0;
        m.faces[3 * i + 1] = 1 + i;
        m.faces[3 * i + 2] = 1 + (i + 1) % N;
    }
    REQUIRE(mlb_uv_unwrap(&m, NULL, &u, &st) == MLB_OK);
    r = check_atlas(&m, &u);
    CHECK(r.overlaps == 0 && r.out_of_range == 0 && r.non_positive == 0 && r.bad_corners == 0);
    CHECK(st.n_degenerate == 0 && st.n_charts > 1 && st.n_charts == st.n_split + 1);
    mlb_uv_mesh_free(&u);
    mlb_mesh_free(&m);
    // a strip of 4000 slivers (1e-9 high) listed from the end away from its one triangle: they all
    // join that triangle's chart, breadth-first along the strip
    mesh_alloc(&m, 2 * (N + 1) + 1, 2 * N + 1);
    for (int i = 0; i <= N; i++) {
        m.pos[3 * (2 * i)] = m.pos[3 * (2 * i + 1)] = (float)i / N;
        m.pos[3 * (2 * i + 1) + 1] = 1e-9f;
    }
    m.pos[3 * (2 * N + 2) + 1] = -1;   // the triangle's apex, below the strip's start
    int32_t* t = m.faces;
    for (int i = N - 1; i >= 0; i--) {   // quad i: (a_i, a_i+1, b_i+1, b_i), counter-clockwise
        int a0 = 2 * i, b0 = 2 * i + 1, a1 = 2 * i + 2, b1 = 2 * i + 3;
        *t++ = a0; *t++ = a1; *t++ = b1;
        *t++ = a0; *t++ = b1; *t++ = b0;
    }
    *t++ = 0; *t++ = 2 * N + 2; *t++ = 2;   // below edge a_0 a_1, which the strip's quad 0 uses as a_0 -> a_1
    REQUIRE(mlb_uv_unwrap(&m, NULL, &u, &st) == MLB_OK);
    CHECK(st.n_degenerate == 2 * N && st.n_charts == 1);
    mlb_uv_mesh_free(&u);
    mlb_mesh_free(&m);
    // 16385 disjoint triangles: more charts than a 1024² texture with 4-texel gutters holds, said at once
    const int D = 16385;
    mesh_alloc(&m, 3 * D, D);
    for (int f = 0; f < D; f++) {
        float x = (float)(f % 128), y = (float)(f / 128);
        float c[3][3] = {{x, y, 0}, {x + 0.5f, y, 0}, {x, y + 0.5f, 0}};
        memcpy(m.pos + 9 * (size_t)f, c, sizeof c);
        for (int k = 0; k < 3; k++) m.faces[3 * f + k] = 3 * f + k;
    }
    CHECK(mlb_uv_unwrap(&m, NULL, &u, &st) == MLB_ERR_NUMERIC);
    CHECK(strstr(mlb_last_error(), "16385 charts") && strstr(mlb_last_error(), "at most 16384"));
    CHECK(u.mesh.uv == NULL);
    mlb_mesh_free(&m);
}

TEST(errors) {
    mlb_mesh m;
    make_cube(&m);
    mlb_uv_mesh u;
    CHECK(mlb_uv_unwrap(NULL, NULL, &u, NULL) == MLB_ERR_ARG);
    mlb_uv_options o = mlb_uv_default();
    o.max_angle_deg = 95;
    CHECK(mlb_uv_unwrap(&m, &o, &u, NULL) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "angle") != NULL);
    o = mlb_uv_default();
    o.gutter = -1;
    CHECK(mlb_uv_unwrap(&m, &o, &u, NULL) == MLB_ERR_ARG);
    m.faces[5] = 8;
    CHECK(mlb_uv_unwrap(&m, NULL, &u, NULL) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "vertex 8") != NULL);
    CHECK(u.mesh.uv == NULL && u.vert_src == NULL);
    m.faces[5] = 1;
    m.pos[4] = NAN;
    CHECK(mlb_uv_unwrap(&m, NULL, &u, NULL) == MLB_ERR_ARG);
    m.pos[4] = -1;
    // too many charts for the gutter: 6 charts of at least 4×4 texels (gutter 2) in an 8² texture
    o = mlb_uv_default();
    o.texture_size = 8;
    o.gutter = 2;
    CHECK(mlb_uv_unwrap(&m, &o, &u, NULL) == MLB_ERR_NUMERIC);
    mlb_mesh_free(&m);
    mlb_uv_mesh_free(&u);
}

static void real_mesh(const char* rel, double util_floor) {
    const char* dir = test_shared_data();
    if (!dir) SKIP("no ../shared/data");
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, rel);
    struct stat sb;
    if (stat(path, &sb) != 0) SKIP("%s absent", path);
    mlb_mesh m;
    mlb_obj_options oo = {0};
    oo.drop_uv = 1;
    oo.drop_normals = 1;
    REQUIRE(mlb_obj_load_ex(path, &m, &oo, NULL) == MLB_OK);
    unwrap_and_check(rel, &m, util_floor);
    mlb_mesh_free(&m);
}

TEST(spot) { real_mesh("meshes/spot/spot.obj", 0.45); }
TEST(bob) { real_mesh("meshes/bob/bob_tri.obj", 0.45); }

int main(void) {
    RUN(cube_exact);
    RUN(uv_sphere);
    RUN(torus);
    RUN(marching_tets_torus);
    RUN(helix_overlap_is_cut);
    RUN(options_and_determinism);
    RUN(odd_topology);
    RUN(hostile_faces);
    RUN(errors);
    RUN(spot);
    RUN(bob);
    return test_summary();
}
