// The procedural catalogue (include/matlaber/catalogue.h): meshes, materials, held-out pairs,
// captions, samples and renders.
#include <stdint.h>
#include "matlaber/catalogue.h"
#include "matlaber/geometry.h"
#include "matlaber/sds.h"
#include "test.h"

// Signed volume (divergence theorem) and edge manifoldness: every directed edge used once, and its
// reverse once, within a component (edges counted by vertex index).
static double signed_volume(const mlb_mesh* m) {
    double v = 0;
    for (int f = 0; f < m->n_faces; f++) {
        const float *a = m->pos + 3 * m->faces[3 * f], *b = m->pos + 3 * m->faces[3 * f + 1], *c = m->pos + 3 * m->faces[3 * f + 2];
        v += (a[0] * ((double)b[1] * c[2] - (double)b[2] * c[1]) - a[1] * ((double)b[0] * c[2] - (double)b[2] * c[0]) +
              a[2] * ((double)b[0] * c[1] - (double)b[1] * c[0])) / 6;
    }
    return v;
}

static int cmp(const void* x, const void* y) {
    uint64_t a = *(const uint64_t*)x, b = *(const uint64_t*)y;
    return a < b ? -1 : a > b;
}

// Counts directed edges without a reverse twin (0 for a closed, consistently wound mesh).
static long open_edges(const mlb_mesh* m) {
    size_t n = 3 * (size_t)m->n_faces;
    uint64_t* e = malloc(sizeof(uint64_t) * n);
    if (!e) return -1;
    for (int f = 0; f < m->n_faces; f++)
        for (int k = 0; k < 3; k++) e[3 * f + k] = (uint64_t)(uint32_t)m->faces[3 * f + k] << 32 | (uint32_t)m->faces[3 * f + (k + 1) % 3];
    // sort, then look each reversed edge up by binary search
    qsort(e, n, sizeof *e, cmp);
    long bad = 0;
    for (size_t i = 0; i < n; i++) {
        uint64_t r = e[i] << 32 | e[i] >> 32;
        if (!bsearch(&r, e, n, sizeof *e, cmp)) bad++;
        if (i && e[i] == e[i - 1]) bad++;   // a directed edge twice: inconsistent winding
    }
    free(e);
    return bad;
}

TEST(names_and_parse) {
    CHECK(mlb_catalogue_n_classes() >= 8);
    CHECK(mlb_catalogue_n_materials() >= 6);
    int n_asym = 0;
    for (int c = 0; c < mlb_catalogue_n_classes(); c++) {
        int back = -1;
        CHECK(mlb_catalogue_class_parse(mlb_catalogue_class_name(c), &back) == MLB_OK && back == c);
        n_asym += !mlb_catalogue_class_symmetric(c);
    }
    CHECK(n_asym >= 2);
    for (int m = 0; m < mlb_catalogue_n_materials(); m++) {
        int back = -1;
        CHECK(mlb_catalogue_material_parse(mlb_catalogue_material_name(m), &back) == MLB_OK && back == m);
        const float* k = mlb_catalogue_material_brdf(m);
        for (int i = 0; i < 7; i++) CHECK(k[i] >= 0 && k[i] <= 1);
        CHECK(k[6] >= 0.08f);
        if (mlb_catalogue_material_metal(m)) CHECK(k[0] + k[1] + k[2] < 0.1f && k[3] > 0.5f);
        else CHECK(k[3] < 0.1f);
    }
    int c;
    CHECK(mlb_catalogue_class_parse("spaceship", &c) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "spaceship") && strstr(mlb_last_error(), "goblet"));
    CHECK(mlb_catalogue_material_parse("plutonium", &c) == MLB_ERR_ARG);
    CHECK(mlb_catalogue_class_name(-1) == NULL && mlb_catalogue_material_brdf(99) == NULL);
    mlb_mesh m;
    CHECK(mlb_catalogue_mesh(99, 0, &m) == MLB_ERR_ARG);
}

TEST(held_out) {
    int nc = mlb_catalogue_n_classes(), nm = mlb_catalogue_n_materials(), total = 0;
    int* per_mat = calloc((size_t)nm, sizeof(int));
    for (int c = 0; c < nc; c++) {
        int train = 0;
        for (int m = 0; m < nm; m++) {
            int h = mlb_catalogue_held_out(c, m);
            total += h, train += !h, per_mat[m] += !h;
            CHECK(h == mlb_catalogue_held_out(c, m));
        }
        CHECK(train >= 1);
    }
    for (int m = 0; m < nm; m++) CHECK(per_mat[m] >= 1);
    CHECK(total >= 8);
    CHECK(total == mlb_catalogue_n_held_out());
    free(per_mat);
}

TEST(captions) {
    char s[128];
    int gob, gold, mug, blue;
    REQUIRE(!mlb_catalogue_class_parse("goblet", &gob) && !mlb_catalogue_material_parse("gold", &gold));
    REQUIRE(!mlb_catalogue_class_parse("mug", &mug) && !mlb_catalogue_material_parse("blue", &blue));
    mlb_catalogue_caption(gob, gold, MLB_SDS_VIEW_NONE, s, sizeof s);
    CHECK(!strcmp(s, "a gold goblet"));
    mlb_catalogue_caption(mug, blue, MLB_SDS_VIEW_SIDE, s, sizeof s);
    CHECK(!strcmp(s, "a blue mug, side view"));
    mlb_catalogue_caption(gob, gold, MLB_SDS_VIEW_FRONT, s, sizeof s);
    CHECK(!strcmp(s, "a gold goblet, front view"));
    mlb_catalogue_caption(gob, gold, MLB_SDS_VIEW_BACK, s, sizeof s);
    CHECK(!strcmp(s, "a gold goblet, back view"));
    mlb_catalogue_caption(gob, gold, MLB_SDS_VIEW_OVERHEAD, s, sizeof s);
    CHECK(!strcmp(s, "a gold goblet, overhead view"));
    mlb_catalogue_caption(gob, gold, MLB_SDS_VIEW_FRONT, s, 7);
    CHECK(!strcmp(s, "a gold"));
}

TEST(meshes) {
    for (int c = 0; c < mlb_catalogue_n_classes(); c++)
        for (uint64_t seed = 0; seed < 4; seed++) {
            mlb_mesh m;
            REQUIRE(mlb_catalogue_mesh(c, seed, &m) == MLB_OK);
            const char* name = mlb_catalogue_class_name(c);
            CHECK_MSG(m.n_verts > 100 && m.n_faces > 100 && m.normal, "%s: %d verts %d faces", name, m.n_verts, m.n_faces);
            float lo[3] = {1e9f, 1e9f, 1e9f}, hi[3] = {-1e9f, -1e9f, -1e9f};
            double rmax = 0;
            int finite = 1;
            for (int i = 0; i < m.n_verts; i++) {
                double r = 0;
                for (int k = 0; k < 3; k++) {
                    float x = m.pos[3 * i + k];
                    finite &= isfinite(x) && isfinite(m.normal[3 * i + k]);
                    lo[k] = fminf(lo[k], x), hi[k] = fmaxf(hi[k], x);
                    r += (double)x * x;
                }
                if (r > rmax) rmax = r;
            }
            CHECK_MSG(finite, "%s seed %llu: non-finite", name, (unsigned long long)seed);
            CHECK_MSG(sqrt(rmax) <= 0.9001 && sqrt(rmax) > 0.89, "%s: radius %g", name, sqrt(rmax));
            for (int k = 0; k < 3; k++) CHECK_MSG(fabsf(lo[k] + hi[k]) < 1e-4f, "%s: not centred on axis %d", name, k);
            CHECK_MSG(hi[1] - lo[1] > 0.3f, "%s: flat (%g tall)", name, hi[1] - lo[1]);
            double vol = signed_volume(&m);
            CHECK_MSG(vol > 0.02, "%s seed %llu: signed volume %g", name, (unsigned long long)seed, vol);
            long open = open_edges(&m);
            CHECK_MSG(open == 0, "%s seed %llu: %ld open or doubled edges", name, (unsigned long long)seed, open);
            // determinism
            mlb_mesh m2;
            REQUIRE(mlb_catalogue_mesh(c, seed, &m2) == MLB_OK);
            CHECK(m2.n_verts == m.n_verts && m2.n_faces == m.n_faces &&
                  !memcmp(m2.pos, m.pos, sizeof(float) * 3 * m.n_verts) && !memcmp(m2.faces, m.faces, sizeof(int32_t) * 3 * m.n_faces));
            mlb_mesh_free(&m2);
            if (seed == 1) {   // a different seed, a different shape
                mlb_mesh m0;
                REQUIRE(mlb_catalogue_mesh(c, 0, &m0) == MLB_OK);
                CHECK_MSG(m0.n_verts != m.n_verts || memcmp(m0.pos, m.pos, sizeof(float) * 3 * m.n_verts), "%s: seed 1 = seed 0", name);
                mlb_mesh_free(&m0);
            }
            mlb_mesh_free(&m);
        }
}

// The parameter path: a seed's fractions build that seed's mesh bit for bit; fractions outside
// [0, 1] build the clamped shape; each parameter changes the shape; bad calls are refused.
TEST(mesh_params) {
    for (int c = 0; c < mlb_catalogue_n_classes(); c++) {
        const char* name = mlb_catalogue_class_name(c);
        int n = mlb_catalogue_class_n_params(c);
        CHECK_MSG(n >= 2 && n <= MLB_CATALOGUE_MAX_PARAMS, "%s: %d parameters", name, n);
        float u[MLB_CATALOGUE_MAX_PARAMS];
        for (uint64_t seed = 0; seed < 3; seed++) {
            REQUIRE(mlb_catalogue_seed_params(c, seed, u) == n);
            for (int k = 0; k < n; k++) CHECK(u[k] >= 0 && u[k] <= 1);
            mlb_mesh a, b;
            REQUIRE(mlb_catalogue_mesh(c, seed, &a) == MLB_OK);
            REQUIRE(mlb_catalogue_mesh_params(c, u, &b) == MLB_OK);
            CHECK_MSG(a.n_verts == b.n_verts && a.n_faces == b.n_faces && !memcmp(a.pos, b.pos, sizeof(float) * 3 * a.n_verts) &&
                          !memcmp(a.faces, b.faces, sizeof(int32_t) * 3 * a.n_faces),
                      "%s seed %llu: the parameter path differs", name, (unsigned long long)seed);
            mlb_mesh_free(&a);
            mlb_mesh_free(&b);
        }
        // clamping: -3 and 7 build the shapes of 0 and 1
        float lo[MLB_CATALOGUE_MAX_PARAMS], lo_out[MLB_CATALOGUE_MAX_PARAMS];
        for (int k = 0; k < n; k++) lo[k] = 0, lo_out[k] = k % 2 ? -3.0f : 0.0f;
        mlb_mesh a, b;
        REQUIRE(mlb_catalogue_mesh_params(c, lo, &a) == MLB_OK);
        REQUIRE(mlb_catalogue_mesh_params(c, lo_out, &b) == MLB_OK);
        CHECK_MSG(a.n_verts == b.n_verts && !memcmp(a.pos, b.pos, sizeof(float) * 3 * a.n_verts), "%s: not clamped", name);
        mlb_mesh_free(&b);
        for (int k = 0; k < n; k++) {   // every parameter moves some vertex
            float v[MLB_CATALOGUE_MAX_PARAMS];
            memcpy(v, lo, sizeof v);
            v[k] = 1;
            REQUIRE(mlb_catalogue_mesh_params(c, v, &b) == MLB_OK);
            CHECK_MSG(b.n_verts != a.n_verts || memcmp(a.pos, b.pos, sizeof(float) * 3 * a.n_verts), "%s: parameter %d does nothing", name, k);
            mlb_mesh_free(&b);
        }
        mlb_mesh_free(&a);
    }
    mlb_mesh m;
    CHECK(mlb_catalogue_class_n_params(-1) == 0 && mlb_catalogue_class_n_params(mlb_catalogue_n_classes()) == 0);
    CHECK(mlb_catalogue_mesh_params(0, NULL, &m) == MLB_ERR_ARG);
    float u[MLB_CATALOGUE_MAX_PARAMS] = {0};
    CHECK(mlb_catalogue_mesh_params(99, u, &m) == MLB_ERR_ARG);
}

// Face centroid f of m: c[3].
static void centroid(const mlb_mesh* m, int f, float c[3]) {
    for (int k = 0; k < 3; k++) {
        c[k] = 0;
        for (int j = 0; j < 3; j++) c[k] += m->pos[3 * (size_t)m->faces[3 * f + j] + k] / 3;
    }
}

// The named parts: the same mesh as mlb_catalogue_mesh_params, every part carried by some faces of
// every member, and each where it belongs: stems near the axis and below the rest, legs reaching
// far below the top, the mug's handle and the teapot's spout on +x and its handle on -x, the lamp's shade above
// its pole, the ring's hole the tube's inner half.
TEST(parts) {
    const char* const want[][3] = {{"goblet", "stem", NULL}, {"mushroom", "stem", NULL}, {"lamp", "stem", "shade"},
                                   {"table", "legs", NULL}, {"stool", "legs", NULL}, {"mug", "handle", NULL},
                                   {"teapot", "spout", "handle"}, {"ring", "hole", NULL}, {"vase", NULL, NULL},
                                   {"bowl", NULL, NULL}, {"bottle", NULL, NULL}};
    CHECK((int)(sizeof want / sizeof want[0]) == mlb_catalogue_n_classes());
    for (size_t w = 0; w < sizeof want / sizeof want[0]; w++) {
        int c;
        REQUIRE(mlb_catalogue_class_parse(want[w][0], &c) == MLB_OK);
        int n = mlb_catalogue_class_n_parts(c);
        CHECK_MSG(n == (want[w][1] != NULL) + (want[w][2] != NULL), "%s: %d parts", want[w][0], n);
        for (int k = 1; k <= n; k++) CHECK(!strcmp(mlb_catalogue_part_name(c, k), want[w][k]));
        CHECK(mlb_catalogue_part_name(c, 0) == NULL && mlb_catalogue_part_name(c, n + 1) == NULL);
        for (uint64_t seed = 0; seed < 4; seed++) {
            float u[MLB_CATALOGUE_MAX_PARAMS];
            mlb_catalogue_seed_params(c, seed, u);
            mlb_mesh a, b;
            uint8_t* part = NULL;
            REQUIRE(mlb_catalogue_mesh_params(c, u, &a) == MLB_OK);
            REQUIRE(mlb_catalogue_mesh_parts(c, u, &b, &part) == MLB_OK && part);
            CHECK(a.n_faces == b.n_faces && !memcmp(a.pos, b.pos, sizeof(float) * 3 * a.n_verts) &&
                  !memcmp(a.faces, b.faces, sizeof(int32_t) * 3 * a.n_faces));
            int count[MLB_CATALOGUE_MAX_PARTS + 1] = {0};
            float rmax[3] = {0}, ymin[3] = {1e9f, 1e9f, 1e9f}, ymax[3] = {-1e9f, -1e9f, -1e9f}, xmin[3] = {1e9f, 1e9f, 1e9f};
            float xmax[3] = {-1e9f, -1e9f, -1e9f}, rxy_min[3] = {1e9f, 1e9f, 1e9f}, rxy_max[3] = {0};
            for (int f = 0; f < b.n_faces; f++) {
                REQUIRE(part[f] <= n);
                int p = part[f];
                count[p]++;
                float q[3];
                centroid(&b, f, q);
                float r = hypotf(q[0], q[2]), rxy = hypotf(q[0], q[1]);
                rmax[p] = fmaxf(rmax[p], r), ymin[p] = fminf(ymin[p], q[1]), ymax[p] = fmaxf(ymax[p], q[1]);
                xmin[p] = fminf(xmin[p], q[0]), xmax[p] = fmaxf(xmax[p], q[0]);
                rxy_min[p] = fminf(rxy_min[p], rxy), rxy_max[p] = fmaxf(rxy_max[p], rxy);
            }
            for (int k = 1; k <= n; k++) CHECK_MSG(count[k] > 0, "%s seed %d: no %s", want[w][0], (int)seed, want[w][k]);
            const char* nm = want[w][0];
            if (!strcmp(nm, "goblet") || !strcmp(nm, "mushroom"))   // a stem: near the axis, under the rest
                CHECK_MSG(rmax[1] < 0.5f * rmax[0] && ymax[1] <= ymax[0], "%s: stem r %g of %g", nm, rmax[1], rmax[0]);
            if (!strcmp(nm, "lamp")) CHECK(rmax[1] < 0.2f * rmax[2] && ymax[1] <= ymin[2] + 0.01f);
            if (!strcmp(nm, "table") || !strcmp(nm, "stool")) CHECK(ymin[1] < ymin[0] - 0.3f);   // down to the floor
            if (!strcmp(nm, "mug")) CHECK(xmin[1] > 0);
            if (!strcmp(nm, "teapot")) CHECK(xmin[1] > 0 && xmax[2] < 0);
            if (!strcmp(nm, "ring")) CHECK(rxy_max[1] <= rxy_min[0] + 0.02f && count[1] > count[0] / 3);
            free(part);
            mlb_mesh_free(&a);
            mlb_mesh_free(&b);
        }
    }
    mlb_mesh m;
    uint8_t* part;
    float u[MLB_CATALOGUE_MAX_PARAMS] = {0};
    CHECK(mlb_catalogue_mesh_parts(0, u, &m, NULL) == MLB_ERR_ARG);
    CHECK(mlb_catalogue_mesh_parts(99, u, &m, &part) == MLB_ERR_ARG && part == NULL);
}

// Classes are told apart: the Chamfer distance between two classes' canonical shapes is well above
// the distance between a class's canonical shape and its seeded variations.
TEST(classes_distinguishable) {
    int nc = mlb_catalogue_n_classes();
    mlb_mesh* can = calloc((size_t)nc, sizeof(mlb_mesh));
    REQUIRE(can);
    for (int c = 0; c < nc; c++) REQUIRE(mlb_catalogue_mesh(c, 0, &can[c]) == MLB_OK);
    double within = 0, between = 1e9;
    int wi = -1, b0 = -1, b1 = -1;
    for (int c = 0; c < nc; c++)
        for (uint64_t seed = 1; seed <= 2; seed++) {
            mlb_mesh m;
            mlb_chamfer_result r;
            REQUIRE(mlb_catalogue_mesh(c, seed, &m) == MLB_OK);
            REQUIRE(mlb_chamfer(&m, &can[c], 1500, 7, &r) == MLB_OK);
            if (r.chamfer > within) within = r.chamfer, wi = c;
            mlb_mesh_free(&m);
        }
    for (int a = 0; a < nc; a++)
        for (int b = a + 1; b < nc; b++) {
            mlb_chamfer_result r;
            REQUIRE(mlb_chamfer(&can[a], &can[b], 1500, 7, &r) == MLB_OK);
            if (r.chamfer < between) between = r.chamfer, b0 = a, b1 = b;
        }
    printf("  largest within-class Chamfer %.4f (%s), smallest between classes %.4f (%s, %s)\n", within,
           mlb_catalogue_class_name(wi), between, mlb_catalogue_class_name(b0), mlb_catalogue_class_name(b1));
    CHECK(between > 1.5 * within);
    for (int c = 0; c < nc; c++) mlb_mesh_free(&can[c]);
    free(can);
}

TEST(samples) {
    int counts_held = 0;
    for (uint64_t i = 0; i < 400; i++) {
        mlb_catalogue_sample a, b;
        REQUIRE(mlb_catalogue_sample_draw(&a, 5, i, 3, 0) == MLB_OK);
        REQUIRE(mlb_catalogue_sample_draw(&b, 5, i, 3, 0) == MLB_OK);
        CHECK(a.cls == b.cls && a.mat == b.mat && a.shape_seed == b.shape_seed && a.view.azimuth_deg == b.view.azimuth_deg);
        CHECK(!mlb_catalogue_held_out(a.cls, a.mat));
        CHECK(a.shape_seed != 0 && a.view.env >= 0 && a.view.env < 3);
        CHECK(a.view.elevation_deg >= -10 && a.view.elevation_deg <= 45 && a.view.radius == 3);
        REQUIRE(mlb_catalogue_sample_draw(&b, 5, i, 3, 1) == MLB_OK);
        counts_held += mlb_catalogue_held_out(b.cls, b.mat);
    }
    CHECK(counts_held > 0);   // 400 draws over 88 pairs with 11 held out: ~50 expected
    mlb_catalogue_sample s;
    REQUIRE(mlb_catalogue_sample_draw(&s, 1, 0, 3, 0) == MLB_OK);
    char cap[128], want[128];
    mlb_catalogue_sample_caption(&s, cap, sizeof cap);
    mlb_catalogue_caption(s.cls, s.mat, mlb_sds_view_for(s.view.azimuth_deg, s.view.elevation_deg), want, sizeof want);
    CHECK(!strcmp(cap, want));
    CHECK(mlb_catalogue_sample_draw(&s, 1, 0, 0, 0) == MLB_ERR_ARG);
}

// Renders: coverage, ranges, unit normals, black background, and the material in the colour.
TEST(renders) {
    mlb_catalogue_render_config rc = mlb_catalogue_render_default();
    rc.res = 64;
    rc.cube_size = 64;
    rc.env_height = 128;
    mlb_catalogue_renderer* r = NULL;
    REQUIRE(mlb_catalogue_renderer_create(&r, &rc) == MLB_OK);
    int res = 64, P = res * res;
    float* rgb = malloc(sizeof(float) * 3 * P);
    float* nrm = malloc(sizeof(float) * 4 * P);
    REQUIRE(rgb && nrm);
    int gold, blue;
    REQUIRE(!mlb_catalogue_material_parse("gold", &gold) && !mlb_catalogue_material_parse("blue", &blue));
    double hue[2][3] = {{0}};
    for (int c = 0; c < mlb_catalogue_n_classes(); c++)
        for (int which = 0; which < 2; which++) {
            mlb_catalogue_sample s;
            REQUIRE(mlb_catalogue_sample_draw(&s, 3, (uint64_t)c, 3, 1) == MLB_OK);
            s.cls = c;
            s.mat = which ? blue : gold;
            s.view.env = 0;   // the sky
            REQUIRE(mlb_catalogue_render(r, &s, rgb, nrm) == MLB_OK);
            double cover = 0, len_sum = 0;
            int full = 0, bad_range = 0, bad_bg = 0, short_n = 0;
            for (int i = 0; i < P; i++) {
                float a = nrm[4 * i + 3];
                cover += a;
                for (int ch = 0; ch < 3; ch++) bad_range += !(rgb[ch * P + i] >= 0 && rgb[ch * P + i] <= a + 1e-5f);
                if (a == 0) {
                    // (the geometry stage's antialias can leave a trace of normal beside a thin part
                    // on a pixel of zero coverage: a few are tolerated below)
                    for (int ch = 0; ch < 3; ch++) bad_bg += rgb[ch * P + i] > 1e-6f || fabsf(nrm[4 * i + ch]) > 1e-6f;
                } else if (a == 1) {
                    double l = sqrt(nrm[4 * i] * nrm[4 * i] + nrm[4 * i + 1] * nrm[4 * i + 1] + nrm[4 * i + 2] * nrm[4 * i + 2]);
                    len_sum += l, full++;
                    short_n += l < 0.6 || l > 1.001;
                    for (int ch = 0; ch < 3; ch++) hue[which][ch] += rgb[ch * P + i];
                }
            }
            const char* name = mlb_catalogue_class_name(c);
            CHECK_MSG(cover / P > 0.05, "%s: coverage %.3f", name, cover / P);
            CHECK_MSG(bad_range == 0 && bad_bg <= 4, "%s: %d out of range, %d background", name, bad_range, bad_bg);
            CHECK_MSG(full > 0 && len_sum / full > 0.97 && short_n <= full / 50, "%s: mean normal length %.3f, %d short of %d",
                      name, full ? len_sum / full : 0, short_n, full);
        }
    // gold: red > green > blue; blue glaze: blue > red, blue > green
    printf("  mean sRGB gold (%.3f %.3f %.3f), blue (%.3f %.3f %.3f) (sums)\n", hue[0][0], hue[0][1], hue[0][2], hue[1][0],
           hue[1][1], hue[1][2]);
    CHECK(hue[0][0] > hue[0][1] && hue[0][1] > 1.2 * hue[0][2]);
    CHECK(hue[1][2] > 1.5 * hue[1][0] && hue[1][2] > 1.5 * hue[1][1]);
    // errors name the problem
    mlb_catalogue_sample s;
    REQUIRE(mlb_catalogue_sample_draw(&s, 3, 0, 3, 0) == MLB_OK);
    s.view.env = 5;
    CHECK(mlb_catalogue_render(r, &s, rgb, NULL) == MLB_ERR_ARG);
    free(rgb);
    free(nrm);
    mlb_catalogue_renderer_free(r);
}

int main(void) {
    RUN(names_and_parse);
    RUN(held_out);
    RUN(captions);
    RUN(meshes);
    RUN(mesh_params);
    RUN(parts);
    RUN(classes_distinguishable);
    RUN(samples);
    RUN(renders);
    return test_summary();
}
