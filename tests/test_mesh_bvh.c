// The BVH behind mlb_mesh_distance (src/geometry/mesh_bvh.c) against a brute-force minimum over
// every triangle kept here: bit for bit on random triangle soups, catalogue meshes, degenerate and
// sliver triangles, points far away, on the surface and at vertices; the same bits on 1 and 2
// threads; hostile inputs (no faces, NaN and infinite coordinates) neither crash nor hang.
#include <math.h>
#include <omp.h>
#include <stdint.h>
#include "matlaber/catalogue.h"
#include "matlaber/geometry.h"
#include "matlaber/rng.h"
#include "test.h"

// ---- the reference: every triangle, no pruning --------------------------------------------------

static int tri_finite(const mlb_mesh* m, int f) {
    for (int c = 0; c < 3; c++)
        for (int k = 0; k < 3; k++)
            if (!isfinite(m->pos[3 * (size_t)m->faces[3 * f + c] + k])) return 0;
    return 1;
}

static void brute_distance(const mlb_mesh* m, const float* p, float* out, int n) {
    for (int i = 0; i < n; i++) {
        double q[3] = {p[3 * i], p[3 * i + 1], p[3 * i + 2]};
        double best = INFINITY;
        int any = 0;
        for (int f = 0; f < m->n_faces; f++) {
            if (!tri_finite(m, f)) continue;
            any = 1;
            const int32_t* t = m->faces + 3 * f;
            double d2 = mlb_point_triangle_dist2(q, m->pos + 3 * t[0], m->pos + 3 * t[1], m->pos + 3 * t[2]);
            if (d2 < best) best = d2;
        }
        out[i] = !any ? INFINITY : (isnan(q[0]) || isnan(q[1]) || isnan(q[2])) ? NAN : (float)sqrt(best);
    }
}

static int same_bits(float a, float b) {
    if (isnan(a) || isnan(b)) return isnan(a) && isnan(b);
    uint32_t x, y;
    memcpy(&x, &a, 4);
    memcpy(&y, &b, 4);
    return x == y;
}

// mlb_mesh_distance against the reference; returns the number of points that differ.
static int compare(const mlb_mesh* m, const float* p, int n, const char* what) {
    float* got = malloc(sizeof(float) * (size_t)(n > 0 ? n : 1));
    float* want = malloc(sizeof(float) * (size_t)(n > 0 ? n : 1));
    if (!got || !want) { free(got); free(want); return -1; }
    mlb_mesh_distance(m, p, got, n);
    brute_distance(m, p, want, n);
    int bad = 0;
    for (int i = 0; i < n; i++)
        if (!same_bits(got[i], want[i])) {
            if (bad < 3) printf("  %s: point %d (%g %g %g): bvh %.9g, brute %.9g\n", what, i, p[3 * i], p[3 * i + 1],
                                p[3 * i + 2], got[i], want[i]);
            bad++;
        }
    free(got);
    free(want);
    return bad;
}

// ---- meshes and points ----------------------------------------------------------------------------

static float unif(uint64_t stream, uint64_t i) { return 2 * mlb_rng_uniform(11, stream, i) - 1; }

// F independent triangles: centres uniform in [-1, 1]^3, corners within `size` of their centre.
static int soup(mlb_mesh* m, int F, float size, uint64_t stream) {
    memset(m, 0, sizeof *m);
    m->n_verts = 3 * F;
    m->n_faces = F;
    m->pos = malloc(sizeof(float) * 9 * (size_t)(F > 0 ? F : 1));
    m->faces = malloc(sizeof(int32_t) * 3 * (size_t)(F > 0 ? F : 1));
    if (!m->pos || !m->faces) return 0;
    for (int f = 0; f < F; f++)
        for (int c = 0; c < 3; c++) {
            for (int k = 0; k < 3; k++)
                m->pos[9 * f + 3 * c + k] = unif(stream, 3 * f + k) + size * unif(stream + 1, 9 * f + 3 * c + k);
            m->faces[3 * f + c] = 3 * f + c;
        }
    return 1;
}

// n points: a quarter uniform in [-1.5, 1.5]^3, a quarter far away (|p| ~ 1e3), a quarter on the
// surface, a quarter at vertices (distance exactly 0 from some triangle).
static float* points_for(const mlb_mesh* m, int n, uint64_t stream) {
    float* p = malloc(sizeof(float) * 3 * (size_t)n);
    if (!p) return NULL;
    int q = n / 4;
    for (int i = 0; i < q; i++)
        for (int k = 0; k < 3; k++) {
            p[3 * i + k] = 1.5f * unif(stream, 3 * i + k);
            p[3 * (q + i) + k] = 1e3f * unif(stream + 1, 3 * i + k);
        }
    if (mlb_mesh_sample_surface(m, p + 6 * q, q, 5, stream) != MLB_OK)   // zero area: uniform instead
        for (int i = 0; i < 3 * q; i++) p[6 * q + i] = unif(stream + 2, i);
    for (int i = 3 * q; i < n; i++) {
        int v = (int)mlb_rng_below(5, stream + 3, (uint64_t)i, (uint32_t)m->n_verts);
        memcpy(p + 3 * i, m->pos + 3 * v, sizeof(float) * 3);
    }
    return p;
}

// ---- cases ----------------------------------------------------------------------------------------

// What pruning relies on: a triangle is never nearer than its bounding box (the box distance
// summed as mesh_bvh.c sums it), degenerate and sliver triangles included.
TEST(triangle_never_nearer_than_its_box) {
    int bad = 0, n = 0;
    for (int t = 0; t < 20000; t++) {
        float v[9];
        for (int k = 0; k < 9; k++) v[k] = unif(100, 9 * t + k);
        int kind = t % 4;
        if (kind == 1) for (int k = 0; k < 3; k++) v[6 + k] = 0.5f * (v[k] + v[3 + k]);           // collinear
        if (kind == 2) for (int k = 0; k < 3; k++) v[6 + k] = v[k] + 1e-7f * unif(101, 3 * t + k);   // sliver
        if (kind == 3) memcpy(v + 3, v, sizeof(float) * 3);                                        // two equal corners
        for (int j = 0; j < 8; j++) {
            double q[3], e2 = 0;
            for (int k = 0; k < 3; k++) q[k] = (j < 4 ? 1.5 : 1e-3) * unif(102, 24 * t + 3 * j + k) + (j < 4 ? 0 : v[k]);
            for (int k = 0; k < 3; k++) {
                double lo = fminf(v[k], fminf(v[3 + k], v[6 + k])), hi = fmaxf(v[k], fmaxf(v[3 + k], v[6 + k]));
                double e = q[k] < lo ? lo - q[k] : (q[k] > hi ? q[k] - hi : 0);
                e2 += e * e;
            }
            double d2 = mlb_point_triangle_dist2(q, v, v + 3, v + 6);
            bad += !(d2 >= e2);
            n++;
        }
    }
    CHECK_MSG(bad == 0, "%d of %d distances below their box's", bad, n);
}

// A zero-area triangle measures to its segment; before, a point on it could read the distance to a corner.
TEST(degenerate_triangle_distance) {
    float a[3] = {0, 0, 0}, b[3] = {1, 0, 0}, c[3] = {2, 0, 0};
    double p[3] = {1.5, 0, 0}, up[3] = {1.5, 0.25, 0};
    CHECK(mlb_point_triangle_dist2(p, a, b, c) == 0);
    CHECK(mlb_point_triangle_dist2(p, c, a, b) == 0);
    CHECK_CLOSE(mlb_point_triangle_dist2(up, a, b, c), 0.0625, 1e-15, 0);
    CHECK_CLOSE(mlb_point_triangle_dist2(up, b, c, a), 0.0625, 1e-15, 0);
    float s[3] = {0, 0, 0};   // all three corners equal: a point
    double r[3] = {3, 4, 0};
    CHECK(mlb_point_triangle_dist2(r, s, s, s) == 25);
}

TEST(soups_match_brute_force) {
    int sizes[] = {1, 2, 3, 4, 5, 7, 17, 100, 1000, 4000};
    for (size_t s = 0; s < sizeof sizes / sizeof *sizes; s++) {
        for (int big = 0; big < 2; big++) {   // small triangles, and large overlapping ones
            mlb_mesh m;
            REQUIRE(soup(&m, sizes[s], big ? 0.8f : 0.05f, 200 + 10 * s + big));
            float* p = points_for(&m, 2000, 300 + s);
            REQUIRE(p);
            char what[64];
            snprintf(what, sizeof what, "soup F %d %s", sizes[s], big ? "large" : "small");
            int bad = compare(&m, p, 2000, what);
            CHECK_MSG(bad == 0, "%s: %d of 2000 differ", what, bad);
            free(p);
            mlb_mesh_free(&m);
        }
    }
}

TEST(catalogue_matches_brute_force) {
    int nc = mlb_catalogue_n_classes();
    for (int c = 0; c < nc; c++) {
        mlb_mesh m, other;
        REQUIRE(mlb_catalogue_mesh(c, (uint64_t)c, &m) == MLB_OK);
        REQUIRE(mlb_catalogue_mesh((c + 1) % nc, 0, &other) == MLB_OK);
        float* p = points_for(&m, 1200, 400 + c);
        REQUIRE(p);
        // and samples on another class, as the Chamfer distance draws them
        float* q = malloc(sizeof(float) * 3 * 800);
        REQUIRE(q && mlb_mesh_sample_surface(&other, q, 800, 7, 0xC4A1) == MLB_OK);
        char what[64];
        snprintf(what, sizeof what, "%s (%d faces)", mlb_catalogue_class_name(c), m.n_faces);
        CHECK_MSG(compare(&m, p, 1200, what) == 0, "%s", what);
        CHECK_MSG(compare(&m, q, 800, what) == 0, "%s, another class's samples", what);
        free(p);
        free(q);
        mlb_mesh_free(&m);
        mlb_mesh_free(&other);
    }
}

// Zero-area triangles, slivers, duplicates, every centroid equal, a grid of equal coordinates.
TEST(degenerate_meshes_match_brute_force) {
    mlb_mesh m;
    REQUIRE(soup(&m, 600, 0.3f, 500));
    for (int f = 0; f < 600; f++) {
        float* v = m.pos + 9 * f;
        switch (f % 6) {
        case 0: for (int k = 0; k < 3; k++) v[6 + k] = 0.5f * (v[k] + v[3 + k]); break;   // collinear
        case 1: memcpy(v + 3, v, sizeof(float) * 3); memcpy(v + 6, v, sizeof(float) * 3); break;   // a point
        case 2: for (int k = 0; k < 3; k++) v[6 + k] = v[3 + k] + 1e-6f * unif(501, 3 * f + k); break;   // sliver
        case 3: if (f >= 6) memcpy(v, m.pos + 9 * (f - 6), sizeof(float) * 9); break;   // a duplicate
        default: break;
        }
    }
    float* p = points_for(&m, 2000, 502);
    REQUIRE(p);
    CHECK(compare(&m, p, 2000, "degenerate soup") == 0);
    free(p);
    // every triangle the same: the median split sees only equal keys
    for (int f = 1; f < 600; f++) memcpy(m.pos + 9 * f, m.pos, sizeof(float) * 9);
    p = points_for(&m, 400, 503);
    REQUIRE(p);
    CHECK(compare(&m, p, 400, "600 equal triangles") == 0);
    free(p);
    // axis-aligned right triangles on a 20 x 20 grid in z = 0 (many equal centroid coordinates)
    for (int f = 0; f < 600; f++) {
        float x = (float)((f / 2) % 20), y = (float)((f / 2) / 20), *v = m.pos + 9 * f;
        float tri[2][9] = {{x, y, 0, x + 1, y, 0, x, y + 1, 0}, {x + 1, y, 0, x + 1, y + 1, 0, x, y + 1, 0}};
        memcpy(v, tri[f % 2], sizeof(float) * 9);
    }
    p = points_for(&m, 2000, 504);
    REQUIRE(p);
    for (int i = 0; i < 500; i++) p[3 * i] *= 20, p[3 * i + 1] *= 20;   // over the grid, not only its corner
    CHECK(compare(&m, p, 2000, "grid") == 0);
    free(p);
    mlb_mesh_free(&m);
}

TEST(hostile_inputs) {
    float p[12] = {0, 0, 0, NAN, 0, 0, INFINITY, 0, 0, 1e30f, -1e30f, 0}, out[4];
    mlb_mesh empty = {0};
    mlb_mesh_distance(&empty, p, out, 4);
    for (int i = 0; i < 4; i++) CHECK(isinf(out[i]) && out[i] > 0);
    mlb_mesh_distance(&empty, p, out, 0);
    mlb_mesh m;
    REQUIRE(soup(&m, 50, 0.1f, 600));
    CHECK(compare(&m, p, 4, "hostile points") == 0);
    mlb_mesh_distance(&m, p, out, 4);
    CHECK(isnan(out[1]) && isinf(out[2]) && isfinite(out[0]) && isfinite(out[3]));
    // NaN and infinite corners: those triangles are left out, the others still measured
    m.pos[0] = NAN;
    m.pos[9 + 4] = INFINITY;
    m.pos[18 + 8] = -INFINITY;
    float* q = points_for(&m, 400, 601);
    REQUIRE(q);
    CHECK(compare(&m, q, 400, "NaN corners") == 0);
    CHECK(compare(&m, p, 4, "NaN corners, hostile points") == 0);
    // every triangle NaN: no triangle, INFINITY as for an empty mesh
    for (int i = 0; i < 9 * 50; i += 9) m.pos[i] = NAN;
    mlb_mesh_distance(&m, q, out, 4);
    for (int i = 0; i < 4; i++) CHECK(isinf(out[i]));
    free(q);
    mlb_mesh_free(&m);
    // the BVH itself: every finite triangle in exactly one leaf, children inside their parent
    mlb_mesh c;
    REQUIRE(mlb_catalogue_mesh(0, 0, &c) == MLB_OK);
    mlb_mesh_bvh b;
    REQUIRE(mlb_mesh_bvh_build(&b, &c) == MLB_OK);
    CHECK(b.n_tris == c.n_faces && b.n_nodes <= 2 * c.n_faces);
    int in_leaves = 0, boxes_ok = 1;
    for (int i = 0; i < b.n_nodes; i++) {
        const mlb_bvh_node* nd = b.nodes + i;
        if (nd->count) { in_leaves += nd->count; CHECK(nd->count <= 4); continue; }
        for (int ch = nd->first; ch < nd->first + 2; ch++)
            for (int k = 0; k < 3; k++) boxes_ok &= b.nodes[ch].lo[k] >= nd->lo[k] && b.nodes[ch].hi[k] <= nd->hi[k];
    }
    CHECK(in_leaves == c.n_faces);
    CHECK(boxes_ok);
    mlb_mesh_bvh_free(&b);
    mlb_mesh_bvh_free(&b);   // safe twice
    mlb_mesh_free(&c);
}

TEST(threads_same_bits) {
    mlb_mesh m;
    REQUIRE(mlb_catalogue_mesh(1, 3, &m) == MLB_OK);
    int n = 20000;
    float* p = points_for(&m, n, 700);
    float* one = malloc(sizeof(float) * n);
    float* two = malloc(sizeof(float) * n);
    REQUIRE(p && one && two);
    int threads = omp_get_max_threads();
    omp_set_num_threads(1);
    mlb_mesh_distance(&m, p, one, n);
    omp_set_num_threads(2);
    mlb_mesh_distance(&m, p, two, n);
    omp_set_num_threads(threads);
    CHECK(memcmp(one, two, sizeof(float) * n) == 0);
    // and the Chamfer distance built on it
    mlb_mesh other;
    REQUIRE(mlb_catalogue_mesh(2, 1, &other) == MLB_OK);
    mlb_chamfer_result r1, r2;
    omp_set_num_threads(1);
    REQUIRE(mlb_chamfer(&m, &other, 3000, 7, &r1) == MLB_OK);
    omp_set_num_threads(2);
    REQUIRE(mlb_chamfer(&m, &other, 3000, 7, &r2) == MLB_OK);
    omp_set_num_threads(threads);
    CHECK(memcmp(&r1, &r2, sizeof r1) == 0);
    free(p); free(one); free(two);
    mlb_mesh_free(&m);
    mlb_mesh_free(&other);
}

// Triangles at x = 2^-i: SAH peels a few off per split, so the depth guard (median split from depth
// 48) is what keeps the tree within the query's stack.
TEST(lopsided_tree_stays_shallow) {
    mlb_mesh m;
    int F = 3000;
    REQUIRE(soup(&m, F, 0, 800));
    for (int f = 0; f < F; f++) {
        float x = ldexpf(1.0f, -(f % 120)) * (1 + (float)(f / 120) / 32);
        float tri[9] = {x, 0, 0, x, 1e-3f, 0, x, 0, 1e-3f};
        memcpy(m.pos + 9 * f, tri, sizeof tri);
    }
    mlb_mesh_bvh b;
    REQUIRE(mlb_mesh_bvh_build(&b, &m) == MLB_OK);
    printf("  %d triangles: %d nodes, depth %d\n", F, b.n_nodes, b.depth);
    CHECK(b.depth <= 48 + 12 + 1);
    mlb_mesh_bvh_free(&b);
    float* p = points_for(&m, 1000, 801);
    REQUIRE(p);
    for (int i = 0; i < 250; i++) p[3 * i] = ldexpf(1.0f, -(i % 130)), p[3 * i + 1] = 0.01f;   // down the staircase
    CHECK(compare(&m, p, 1000, "powers of two") == 0);
    free(p);
    mlb_mesh_free(&m);
}

// mlb_chamfer_many gives mlb_chamfer's numbers bit for bit, with and without the targets' BVHs,
// on 1 and 2 threads; a bad target is named.
TEST(chamfer_many_matches_chamfer) {
    enum { M = 6 };
    mlb_mesh a, t[M];
    mlb_mesh_bvh tb[M];
    REQUIRE(mlb_catalogue_mesh(4, 2, &a) == MLB_OK);
    for (int j = 0; j < M; j++) {
        REQUIRE(mlb_catalogue_mesh(j, (uint64_t)j, &t[j]) == MLB_OK);
        REQUIRE(mlb_mesh_bvh_build(&tb[j], &t[j]) == MLB_OK);
    }
    mlb_chamfer_result one[M], many[M], with_bvh[M], two[M];
    for (int j = 0; j < M; j++) REQUIRE(mlb_chamfer(&a, &t[j], 700, 3, &one[j]) == MLB_OK);
    int threads = omp_get_max_threads();
    omp_set_num_threads(1);
    REQUIRE(mlb_chamfer_many(&a, t, NULL, M, 700, 3, many) == MLB_OK);
    omp_set_num_threads(2);
    REQUIRE(mlb_chamfer_many(&a, t, tb, M, 700, 3, with_bvh) == MLB_OK);
    REQUIRE(mlb_chamfer_many(&a, t, NULL, M, 700, 3, two) == MLB_OK);
    omp_set_num_threads(threads);
    CHECK(memcmp(one, many, sizeof one) == 0);
    CHECK(memcmp(one, with_bvh, sizeof one) == 0);
    CHECK(memcmp(one, two, sizeof one) == 0);
    CHECK(one[4].chamfer > 0 && one[4].relative < one[0].relative);   // a's own class is the nearest here
    // target 3 without area: its sampling fails, and the error names it
    mlb_mesh flat = t[3];
    float* pos = malloc(sizeof(float) * 3 * (size_t)flat.n_verts);
    REQUIRE(pos);
    for (int i = 0; i < 3 * flat.n_verts; i++) pos[i] = 0.5f;
    flat.pos = pos;
    mlb_mesh bad[M];
    memcpy(bad, t, sizeof bad);
    bad[3] = flat;
    CHECK(mlb_chamfer_many(&a, bad, NULL, M, 100, 3, many) == MLB_ERR_ARG);
    CHECK_MSG(strstr(mlb_last_error(), "target 3") != NULL, "%s", mlb_last_error());
    bad[3].n_faces = 0;
    CHECK(mlb_chamfer_many(&a, bad, NULL, M, 100, 3, many) == MLB_ERR_ARG);
    CHECK(mlb_chamfer_many(&a, t, NULL, M, 0, 3, many) == MLB_ERR_ARG);
    free(pos);
    for (int j = 0; j < M; j++) { mlb_mesh_free(&t[j]); mlb_mesh_bvh_free(&tb[j]); }
    mlb_mesh_free(&a);
}

// A square [0, 1]² in the plane z = 0 (two triangles), turned by `deg` about the x axis through
// its centre line y = 0.5, and lifted by dz.
static void square(mlb_mesh* m, float* pos, int32_t* faces, double deg, float dz) {
    static const float xy[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    double c = cos(deg * M_PI / 180), s = sin(deg * M_PI / 180);
    for (int i = 0; i < 4; i++) {
        double y = xy[i][1] - 0.5;
        pos[3 * i] = xy[i][0], pos[3 * i + 1] = (float)(0.5 + c * y), pos[3 * i + 2] = (float)(s * y) + dz;
    }
    static const int32_t f[6] = {0, 1, 2, 0, 2, 3};
    memcpy(faces, f, sizeof f);
    memset(m, 0, sizeof *m);
    m->pos = pos, m->faces = faces, m->n_verts = 4, m->n_faces = 2;
}

// The nearest face and the masked sampler: the face each point came from is the one nearest to it
// (points on a surface), a mask restricts the samples to its faces, and no mask is bitwise
// mlb_mesh_sample_surface.
TEST(nearest_faces_and_masked_samples) {
    mlb_mesh m;
    REQUIRE(mlb_catalogue_mesh(3, 1, &m) == MLB_OK);   // a mug
    enum { N = 500 };
    float p[3 * N], q[3 * N], d[N];
    int32_t from[N], near[N];
    REQUIRE(mlb_mesh_sample_surface(&m, q, N, 5, 9) == MLB_OK);
    REQUIRE(mlb_mesh_sample_faces(&m, NULL, p, from, N, 5, 9) == MLB_OK);
    CHECK(memcmp(p, q, sizeof p) == 0);
    mlb_mesh_bvh b;
    REQUIRE(mlb_mesh_bvh_build(&b, &m) == MLB_OK);
    mlb_mesh_bvh_nearest_faces(&b, p, d, near, N);
    int same = 0;
    for (int i = 0; i < N; i++) {
        CHECK(d[i] < 1e-5f);
        // the point's own face, or a neighbour it lies on as well (an edge) at distance ~0
        const int32_t *a = m.faces + 3 * (size_t)from[i], *e = m.faces + 3 * (size_t)near[i];
        double q2[3] = {p[3 * i], p[3 * i + 1], p[3 * i + 2]};
        same += near[i] == from[i];
        CHECK(mlb_point_triangle_dist2(q2, m.pos + 3 * e[0], m.pos + 3 * e[1], m.pos + 3 * e[2]) < 1e-10);
        (void)a;
    }
    CHECK_MSG(same > N * 9 / 10, "%d of %d on their own face", same, N);
    uint8_t* mask = calloc((size_t)m.n_faces, 1);
    REQUIRE(mask);
    for (int f = 0; f < m.n_faces; f += 7) mask[f] = 1;
    REQUIRE(mlb_mesh_sample_faces(&m, mask, p, from, N, 5, 9) == MLB_OK);
    for (int i = 0; i < N; i++) CHECK(mask[from[i]]);
    memset(mask, 0, (size_t)m.n_faces);
    CHECK(mlb_mesh_sample_faces(&m, mask, p, from, N, 5, 9) == MLB_ERR_ARG);   // no area left
    free(mask);
    mlb_mesh_bvh_free(&b);
    mlb_mesh_free(&m);
}

// The surface measures on cases with a known answer: a square against itself lifted by 0.1 (every
// distance 0.1, normals equal), turned by 30° about its centre line (every normal 30° off; 120° is
// 60° either way round, a reversed winding 0°), and a
// square half of which is labelled a part and half of which the asset lacks.
TEST(surface_compare_analytic) {
    float pa[12], pb[12];
    int32_t fa[6], fb[6];
    mlb_mesh a, b;
    mlb_surface_result r;
    square(&b, pb, fb, 0, 0);
    const double diag = sqrt(2.0);
    square(&a, pa, fa, 0, 0.1f);
    REQUIRE(mlb_surface_compare(&a, &b, NULL, 0, 400, 1, &r) == MLB_OK);
    CHECK_CLOSE(r.diag, diag, 1e-6, 0);
    CHECK_CLOSE(r.normal_deg, 0, 0, 1e-4);
    CHECK_CLOSE(r.accuracy, 0.1 / diag, 1e-5, 0);
    CHECK_CLOSE(r.completeness, 0.1 / diag, 1e-5, 0);
    CHECK(isnan(r.part_completeness[0]));
    square(&a, pa, fa, 30, 0);
    REQUIRE(mlb_surface_compare(&a, &b, NULL, 0, 400, 1, &r) == MLB_OK);
    CHECK_CLOSE(r.normal_deg, 30, 1e-5, 0);
    square(&a, pa, fa, 120, 0);   // 120° is 60° the other way round: a thin wall's other side
    REQUIRE(mlb_surface_compare(&a, &b, NULL, 0, 400, 1, &r) == MLB_OK);
    CHECK_CLOSE(r.normal_deg, 60, 1e-5, 0);
    int32_t flip[6] = {0, 2, 1, 0, 3, 2};   // the winding reversed: the same plane
    square(&a, pa, fa, 0, 0.0f);
    a.faces = flip;
    REQUIRE(mlb_surface_compare(&a, &b, NULL, 0, 400, 1, &r) == MLB_OK);
    CHECK_CLOSE(r.normal_deg, 0, 0, 1e-4);
    // the truth's triangle (0 1 2) is part 1, (0 2 3) part 2; the asset is triangle (0 1 2) alone:
    // part 1 is complete, part 2's far corner (0, 1) is sqrt(0.5) from the asset's hypotenuse
    square(&a, pa, fa, 0, 0);
    a.n_faces = 1;
    uint8_t part[2] = {1, 2};
    REQUIRE(mlb_surface_compare(&a, &b, part, 2, 4000, 1, &r) == MLB_OK);
    CHECK_CLOSE(r.part_completeness[0], 0, 0, 1e-6);
    // distances from the far corner's triangle to the diagonal y = x: the 95th percentile of
    // (y - x)/sqrt2 over a uniform triangle, 1 - sqrt(0.05) of the corner's sqrt(0.5), /diag
    double p95 = (1 - sqrt(0.05)) * sqrt(0.5) / diag;
    CHECK_CLOSE(r.part_completeness[1], p95, 0.03, 0);
    CHECK(r.completeness > 0.5 * p95 && r.completeness < p95);   // half the truth is complete
    CHECK_CLOSE(r.accuracy, 0, 0, 1e-6);                          // and the asset lies on it
    CHECK(mlb_surface_compare(&a, &b, part, MLB_SURFACE_MAX_PARTS + 1, 400, 1, &r) == MLB_ERR_ARG);
    CHECK(mlb_surface_compare(&a, &b, NULL, 0, 1, 1, &r) == MLB_ERR_ARG);
}

int main(void) {
    RUN(triangle_never_nearer_than_its_box);
    RUN(degenerate_triangle_distance);
    RUN(soups_match_brute_force);
    RUN(catalogue_matches_brute_force);
    RUN(degenerate_meshes_match_brute_force);
    RUN(hostile_inputs);
    RUN(threads_same_bits);
    RUN(lopsided_tree_stays_shallow);
    RUN(chamfer_many_matches_chamfer);
    RUN(nearest_faces_and_masked_samples);
    RUN(surface_compare_analytic);
    return test_summary();
}
