// Baking (bake.h) over UV atlases: an analytic material field is baked and the textures, sampled
// bilinearly at the uv of random surface points, reproduce it within a bound set by the texel
// size; dilation fills exactly the texels within the radius, each with a value of its chart; a
// 2×-downsampled mip sampled at chart-border points stays close to the field; thin triangles are
// covered; errors of the material function reach the caller; codes baked with mlb_bake_codes
// land on the texels mlb_bake gives the material.
#include <stdint.h>
#include "matlaber/bake.h"
#include "matlaber/dmtet.h"
#include "matlaber/rng.h"
#include "matlaber/uv_atlas.h"
#include "test.h"

// The field: smooth, every channel's gradient magnitude at most GRAD per world unit.
#define GRAD 1.2
static void field(const float* p, float* k) {
    k[0] = (float)(0.5 + 0.4 * sin(3.0 * p[0] + 1.0));
    k[1] = (float)(0.5 + 0.4 * sin(3.0 * p[1]));
    k[2] = (float)(0.5 + 0.4 * cos(3.0 * p[2]));
    k[3] = (float)(0.3 + 0.2 * sin(2.0 * (p[0] + p[1])));
    k[4] = (float)(0.3 + 0.2 * cos(2.0 * (p[1] - p[2])));
    k[5] = 0.04f;
    k[6] = (float)(0.5 + 0.3 * sin(2.0 * p[2] + 0.5));
}

static int n_calls;
static mlb_status field_fn(void* user, const float* pos, size_t n, float* k) {
    (void)user;
    n_calls++;
    for (size_t i = 0; i < n; i++) field(pos + 3 * i, k + 7 * i);
    return MLB_OK;
}

static mlb_status failing_fn(void* user, const float* pos, size_t n, float* k) {
    return mlb_fail(MLB_ERR_IO, "material file gone");
}

static mlb_status nan_fn(void* user, const float* pos, size_t n, float* k) {
    for (size_t i = 0; i < 7 * n; i++) k[i] = i == 7 * (n / 2) ? NAN : 0.5f;
    return MLB_OK;
}

// Bilinear sample of img [size,size,c] at uv (texel centres at ((x+0.5)/size, 1 − (y+0.5)/size)).
static void sample(const float* img, int size, int c, double u, double v, float* out) {
    double x = u * size - 0.5, y = (1 - v) * size - 0.5;
    int x0 = (int)floor(x), y0 = (int)floor(y);
    double fx = x - x0, fy = y - y0;
    for (int ch = 0; ch < c; ch++) out[ch] = 0;
    for (int j = 0; j < 2; j++)
        for (int i = 0; i < 2; i++) {
            int xx = x0 + i, yy = y0 + j;
            xx = xx < 0 ? 0 : xx >= size ? size - 1 : xx;
            yy = yy < 0 ? 0 : yy >= size ? size - 1 : yy;
            double w = (i ? fx : 1 - fx) * (j ? fy : 1 - fy);
            for (int ch = 0; ch < c; ch++) out[ch] += (float)(w * img[((size_t)yy * size + xx) * c + ch]);
        }
}

// The 7 channels at uv from the three textures.
static void sample_k(const mlb_baked* b, const float* kd, const float* ks, const float* rough, int size, double u, double v, float* k) {
    sample(kd, size, 3, u, v, k);
    sample(ks, size, 3, u, v, k + 3);
    sample(rough, size, 1, u, v, k + 6);
    (void)b;
}

static int make_mt_blob(mlb_mesh* m, int cells) {
    mlb_tetgrid g;
    if (mlb_tetgrid_create(&g, cells, 1.0f) != MLB_OK) return 0;
    float* sdf = malloc(sizeof *sdf * g.n_verts);
    for (int i = 0; i < g.n_verts; i++) {   // a torus with a bump: genus 1, varied curvature
        const float* p = g.verts + 3 * i;
        double q = sqrt((double)p[0] * p[0] + (double)p[2] * p[2]) - 0.27;
        double d = sqrt(q * q + (double)p[1] * p[1]) - 0.11 - 0.03 * sin(5 * atan2(p[2], p[0]));
        sdf[i] = (float)d;
    }
    mlb_mt_surface s;
    int ok = marching_tets_forward(&s, &g, g.verts, sdf) == MLB_OK && mt_surface_to_mesh(&s, m) == MLB_OK;
    if (ok) mt_surface_free(&s);
    free(sdf);
    mlb_tetgrid_free(&g);
    return ok;
}

// Random point on face f with barycentrics from (seed, i): position and uv.
static void random_point(const mlb_mesh* M, uint64_t i, int* face, float* p, double* uv) {
    mlb_u32x4 r = mlb_rng_words(7, 3, i);
    int f = (int)(r.v[0] % (uint32_t)M->n_faces);
    double a = mlb_u32_to_unit(r.v[1]), b = mlb_u32_to_unit(r.v[2]);
    if (a + b > 1) { a = 1 - a; b = 1 - b; }
    double w[3] = {1 - a - b, a, b};
    for (int c = 0; c < 3; c++) {
        double s = 0;
        for (int k = 0; k < 3; k++) s += w[k] * M->pos[3 * M->faces[3 * f + k] + c];
        p[c] = (float)s;
    }
    for (int c = 0; c < 2; c++) {
        double s = 0;
        for (int k = 0; k < 3; k++) s += w[k] * M->uv[2 * M->faces[3 * f + k] + c];
        uv[c] = s;
    }
    *face = f;
}

// Surface length of one texel step at most: a uv step of 1/density maps to at most
// 1/(density·cos θmax) on the surface (projection charts within a cone of θmax; uv_atlas.h).
static double texel_world(const mlb_uv_stats* s) {
    return 1.0 / s->texels_per_unit / cos(mlb_uv_default().max_angle_deg * M_PI / 180.0);
}

TEST(field_reproduced) {
    mlb_mesh m;
    REQUIRE(make_mt_blob(&m, 40));
    mlb_uv_options o = mlb_uv_default();
    o.texture_size = 512;
    mlb_uv_mesh u;
    mlb_uv_stats st;
    REQUIRE(mlb_uv_unwrap(&m, &o, &u, &st) == MLB_OK);
    mlb_baked b;
    n_calls = 0;
    REQUIRE(mlb_bake(&u, 512, field_fn, NULL, MLB_BAKE_DEFAULT_DILATE, &b) == MLB_OK);
    CHECK(n_calls == 1);   // one batch
    CHECK(b.n_covered > 0.3 * 512 * 512);
    // h: surface length of one texel step (at most)
    double h = texel_world(&st);
    double max_err = 0, sum_err = 0;
    int n = 4000;
    for (int i = 0; i < n; i++) {
        int f;
        float p[3], k[7], want[7];
        double uv[2];
        random_point(&u.mesh, (uint64_t)i, &f, p, uv);
        sample_k(&b, b.kd, b.ks, b.roughness, 512, uv[0], uv[1], k);
        field(p, want);
        for (int c = 0; c < 7; c++) {
            double e = fabs(k[c] - want[c]);
            max_err = fmax(max_err, e);
            sum_err += e;
        }
    }
    printf("  texel = %.5f world units; max error %.5f, mean %.6f (bound %.5f)\n", h, max_err, sum_err / (7.0 * n),
           GRAD * h);
    // Inside a chart bilinear interpolation of texel-centre values is exact for a linear field, so
    // the error is second order (~|∇²k|·h²); only next to a chart border does a dilated neighbour
    // (holding the value one texel step away) enter, with weight < 1: |error| < GRAD·h. A half-
    // texel offset in the texel-centre convention would give a mean error ~ GRAD·h/4.
    CHECK(max_err <= GRAD * h);
    CHECK(sum_err / (7.0 * n) <= 0.05 * GRAD * h);
    mlb_baked_free(&b);
    mlb_uv_mesh_free(&u);
    mlb_mesh_free(&m);
}

// Chebyshev distance (in texels) from every texel to the covered set, by brute force over a window.
TEST(dilation_radius_and_chart) {
    mlb_mesh m;
    REQUIRE(mlb_mesh_uv_sphere(&m, 1.0f, 48, 24) == MLB_OK);
    mlb_uv_options o = mlb_uv_default();
    o.texture_size = 256;
    o.gutter = 6;
    mlb_uv_mesh u;
    REQUIRE(mlb_uv_unwrap(&m, &o, &u, NULL) == MLB_OK);
    const int S = 256, D = 5;
    mlb_baked b;
    REQUIRE(mlb_bake(&u, S, field_fn, NULL, D, &b) == MLB_OK);
    int wrong_fill = 0, wrong_value = 0, covered_face_bad = 0, n_dil = 0;
    for (int y = 0; y < S; y++)
        for (int x = 0; x < S; x++) {
            size_t t = (size_t)y * S + x;
            if (b.mask[t]) { covered_face_bad += b.face[t] < 0; continue; }
            // nearest covered texel distance, and whether a covered texel of the same chart within
            // that distance holds exactly this value
            int dmin = 1 << 30, match = 0;
            for (int yy = y - D; yy <= y + D; yy++)
                for (int xx = x - D; xx <= x + D; xx++) {
                    if (xx < 0 || yy < 0 || xx >= S || yy >= S) continue;
                    size_t q = (size_t)yy * S + xx;
                    if (!b.mask[q]) continue;
                    int d = abs(xx - x) > abs(yy - y) ? abs(xx - x) : abs(yy - y);
                    if (d < dmin) dmin = d;
                    if (b.face[t] >= 0 && u.face_chart[b.face[q]] == u.face_chart[b.face[t]] &&
                        memcmp(b.kd + 3 * q, b.kd + 3 * t, 3 * sizeof(float)) == 0 && b.roughness[q] == b.roughness[t])
                        match = 1;
                }
            int filled = b.face[t] >= 0;
            n_dil += filled;
            if (filled != (dmin <= D)) wrong_fill++;
            if (filled && !match) wrong_value++;
        }
    CHECK(covered_face_bad == 0);
    CHECK_MSG(wrong_fill == 0, "%d texels filled iff within %d texels of a chart: wrong", wrong_fill, D);
    CHECK_MSG(wrong_value == 0, "%d dilated texels hold no value of their chart", wrong_value);
    CHECK(n_dil == b.n_dilated && n_dil > 0);
    // outside the radius: the mean of the covered texels (finite, in range)
    int bad = 0;
    for (size_t t = 0; t < (size_t)S * S; t++)
        if (b.face[t] < 0) bad += !(b.kd[3 * t] > 0.1f && b.kd[3 * t] < 0.9f);
    CHECK(bad == 0);
    mlb_baked_free(&b);
    // dilate < 0 fills everything
    REQUIRE(mlb_bake(&u, S, field_fn, NULL, -1, &b) == MLB_OK);
    int empty = 0;
    for (size_t t = 0; t < (size_t)S * S; t++) empty += b.face[t] < 0;
    CHECK(empty == 0);
    mlb_baked_free(&b);
    mlb_uv_mesh_free(&u);
    mlb_mesh_free(&m);
}

// 2×2 box downsample of img [S,S,c] → [S/2,S/2,c].
static float* downsample(const float* img, int S, int c) {
    int H = S / 2;
    float* o = malloc(sizeof *o * (size_t)H * H * c);
    for (int y = 0; y < H; y++)
        for (int x = 0; x < H; x++)
            for (int ch = 0; ch < c; ch++)
                o[((size_t)y * H + x) * c + ch] = 0.25f * (img[((size_t)(2 * y) * S + 2 * x) * c + ch] + img[((size_t)(2 * y) * S + 2 * x + 1) * c + ch] +
                                                           img[((size_t)(2 * y + 1) * S + 2 * x) * c + ch] + img[((size_t)(2 * y + 1) * S + 2 * x + 1) * c + ch]);
    return o;
}

// Mip level 1 sampled at chart-border points (corners of seam vertices): with dilation the error
// stays at the level of the texel size; without it the background bleeds in.
TEST(mip_border_no_seam) {
    mlb_mesh m;
    REQUIRE(make_mt_blob(&m, 32));
    mlb_uv_options o = mlb_uv_default();
    o.texture_size = 512;
    mlb_uv_mesh u;
    mlb_uv_stats st;
    REQUIRE(mlb_uv_unwrap(&m, &o, &u, &st) == MLB_OK);
    // border vertices: an input vertex used by two or more charts
    int* count = calloc((size_t)m.n_verts, sizeof *count);
    for (int i = 0; i < u.mesh.n_verts; i++) count[u.vert_src[i]]++;
    double err[2] = {0, 0};
    int n_border = 0;
    for (int pass = 0; pass < 2; pass++) {
        mlb_baked b;
        REQUIRE(mlb_bake(&u, 512, field_fn, NULL, pass == 0 ? MLB_BAKE_DEFAULT_DILATE : 0, &b) == MLB_OK);
        float* kd1 = downsample(b.kd, 512, 3);
        n_border = 0;
        for (int i = 0; i < u.mesh.n_verts; i++) {
            if (count[u.vert_src[i]] < 2) continue;
            n_border++;
            float k[3], want[7];
            sample(kd1, 256, 3, u.mesh.uv[2 * i], u.mesh.uv[2 * i + 1], k);
            field(u.mesh.pos + 3 * i, want);
            for (int c = 0; c < 3; c++) err[pass] = fmax(err[pass], fabs(k[c] - want[c]));
        }
        free(kd1);
        mlb_baked_free(&b);
    }
    double h = texel_world(&st);   // surface length of a level-0 texel
    printf("  %d border vertices; mip-1 max error %.4f with dilation, %.4f without (bound %.4f)\n", n_border, err[0],
           err[1], 2 * GRAD * h);
    CHECK(n_border > 100);
    // a level-1 texel averages 2×2 level-0 texels, each within ~1 texel step of the point's
    // neighbourhood; the bilinear footprint adds one more level-1 texel: |error| < 2·GRAD·h
    CHECK(err[0] <= 2 * GRAD * h);
    CHECK(err[1] > 2 * err[0]);   // without dilation the seams do show: the test can tell
    free(count);
    mlb_uv_mesh_free(&u);
    mlb_mesh_free(&m);
}

// A needle triangle thinner than a texel: conservative coverage still gives it texels.
TEST(thin_triangle_covered) {
    mlb_uv_mesh u;
    memset(&u, 0, sizeof u);
    float pos[9] = {0, 0, 0, 1, 0, 0, 0, 0.001f, 0};
    float uv[6] = {0.1f, 0.5f, 0.9f, 0.5f, 0.1f, 0.5005f};   // 0.26 texel high at 128
    int32_t faces[3] = {0, 1, 2}, fc[1] = {0};
    u.mesh.n_verts = 3;
    u.mesh.n_faces = 1;
    u.mesh.pos = pos;
    u.mesh.uv = uv;
    u.mesh.faces = faces;
    u.face_chart = fc;
    u.n_charts = 1;
    mlb_baked b;
    REQUIRE(mlb_bake(&u, 128, field_fn, NULL, 0, &b) == MLB_OK);
    // the strip from x = 12.8 to 115.2 at y ≈ 64: every column in between has a covered texel
    int missing = 0;
    for (int x = 13; x <= 114; x++) {
        int any = 0;
        for (int y = 60; y < 68; y++) any |= b.mask[y * 128 + x];
        missing += !any;
    }
    CHECK(missing == 0);
    // the values are the field at the interpolated position: along the needle kd.r follows x
    int bad = 0;
    for (int t = 0; t < 128 * 128; t++) {
        if (!b.mask[t]) continue;
        double x = ((t % 128) + 0.5) / 128.0;
        double px = fmin(fmax((x - 0.1) / 0.8, 0), 1);
        float want[7];
        float p[3] = {(float)px, 0, 0};
        field(p, want);
        bad += fabs(b.kd[3 * t] - want[0]) > 0.05;
    }
    CHECK(bad == 0);
    mlb_baked_free(&b);
}

// 4-channel codes: the field's first four channels, so mlb_bake_codes must give mlb_bake's texels.
static mlb_status codes_fn(void* user, const float* pos, size_t n, float* z) {
    (void)user;
    for (size_t i = 0; i < n; i++) {
        float k[7];
        field(pos + 3 * i, k);
        memcpy(z + 4 * i, k, sizeof(float) * 4);
    }
    return MLB_OK;
}

TEST(codes_on_the_same_texels) {
    mlb_mesh m;
    REQUIRE(make_mt_blob(&m, 12));
    const int S = 128;
    mlb_uv_options o = mlb_uv_default();
    o.texture_size = S;
    mlb_uv_mesh u;
    REQUIRE(mlb_uv_unwrap(&m, &o, &u, NULL) == MLB_OK);
    mlb_baked b;
    REQUIRE(mlb_bake(&u, S, field_fn, NULL, MLB_BAKE_DEFAULT_DILATE, &b) == MLB_OK);
    float* z = malloc(sizeof(float) * 4 * S * S);
    REQUIRE(z);
    REQUIRE(mlb_bake_codes(&u, S, codes_fn, NULL, MLB_BAKE_DEFAULT_DILATE, z) == MLB_OK);
    int differ = 0;
    for (int t = 0; t < S * S; t++)
        differ += z[4 * t] != b.kd[3 * t] || z[4 * t + 1] != b.kd[3 * t + 1] || z[4 * t + 2] != b.kd[3 * t + 2] ||
                  z[4 * t + 3] != b.ks[3 * t];
    CHECK_MSG(differ == 0, "%d of %d texels hold another point's code", differ, S * S);
    CHECK(mlb_bake_codes(&u, S, failing_fn, NULL, 0, z) == MLB_ERR_IO);
    CHECK(mlb_bake_codes(&u, S, NULL, NULL, 0, z) == MLB_ERR_ARG);
    free(z);
    mlb_baked_free(&b);
    mlb_uv_mesh_free(&u);
    mlb_mesh_free(&m);
}

// One uv triangle given n times (copies: the same corners; else each shifted by i/4096 in u),
// positions on the plane z = 0 with x = u, y = v.
static void stack_mesh(mlb_uv_mesh* u, int n, int copies, const float tri[6]) {
    memset(u, 0, sizeof *u);
    u->mesh.n_verts = 3 * n;
    u->mesh.n_faces = n;
    u->mesh.pos = calloc(9 * (size_t)n, sizeof(float));
    u->mesh.uv = malloc(sizeof(float) * 6 * (size_t)n);
    u->mesh.faces = malloc(sizeof(int32_t) * 3 * (size_t)n);
    u->face_chart = calloc((size_t)n, sizeof(int32_t));
    u->n_charts = 1;
    for (int f = 0; f < n; f++)
        for (int k = 0; k < 3; k++) {
            float a = tri[2 * k] + (copies ? 0 : f / 4096.0f), b = tri[2 * k + 1];
            u->mesh.uv[6 * f + 2 * k] = a;
            u->mesh.uv[6 * f + 2 * k + 1] = b;
            u->mesh.pos[9 * f + 3 * k] = a;
            u->mesh.pos[9 * f + 3 * k + 1] = b;
            u->mesh.faces[3 * f + k] = 3 * f + k;
        }
}

// Each face is rasterised over its own extent row by row: a needle across the texture covers
// exactly the texels within half a texel diagonal of it (brute force over every texel agrees); a
// face given 100 times bakes as once; 100 different faces over the whole square are refused.
TEST(stacked_and_needle_uvs) {
    const float needle[6] = {0.02f, 0.02f, 0.98f, 0.98f, 0.5f, 0.5f};   // a segment along the diagonal
    mlb_uv_mesh u;
    stack_mesh(&u, 1, 1, needle);
    mlb_baked b;
    REQUIRE(mlb_bake(&u, 128, field_fn, NULL, 0, &b) == MLB_OK);
    int differ = 0, covered = 0;
    for (int y = 0; y < 128; y++)
        for (int x = 0; x < 128; x++) {
            // texel centre in texel units against the segment (x = u·128, y = (1 − v)·128)
            double cx = x + 0.5, cy = y + 0.5, px = 0.02 * 128, py = (1 - 0.02) * 128, qx = 0.98 * 128, qy = (1 - 0.98) * 128;
            double dx = qx - px, dy = qy - py, t = ((cx - px) * dx + (cy - py) * dy) / (dx * dx + dy * dy);
            t = t < 0 ? 0 : t > 1 ? 1 : t;
            double ex = px + t * dx - cx, ey = py + t * dy - cy;
            int want = sqrt(ex * ex + ey * ey) <= 0.7072;
            differ += want != b.mask[y * 128 + x];
            covered += want;
        }
    CHECK(differ == 0 && covered > 2 * 120);
    mlb_baked_free(&b);
    mlb_uv_mesh_free(&u);
    // one face over the lower-left half, 100 times: the same texels as once
    const float half[6] = {0, 0, 1, 0, 0, 1};
    stack_mesh(&u, 1, 1, half);
    mlb_baked once;
    REQUIRE(mlb_bake(&u, 64, field_fn, NULL, 0, &once) == MLB_OK);
    mlb_uv_mesh_free(&u);
    stack_mesh(&u, 100, 1, half);
    REQUIRE(mlb_bake(&u, 64, field_fn, NULL, 0, &b) == MLB_OK);
    CHECK(b.n_covered == once.n_covered && !memcmp(b.kd, once.kd, sizeof(float) * 3 * 64 * 64));
    mlb_baked_free(&b);
    mlb_baked_free(&once);
    mlb_uv_mesh_free(&u);
    // 200 faces, each shifted a little: 200 layers over half the texture
    stack_mesh(&u, 200, 0, half);
    CHECK(mlb_bake(&u, 64, field_fn, NULL, 0, &b) == MLB_ERR_UNSUPPORTED);
    CHECK(strstr(mlb_last_error(), "layers deep") != NULL);
    CHECK(b.kd == NULL && b.mask == NULL);
    mlb_uv_mesh_free(&u);
}

TEST(errors) {
    mlb_mesh m;
    REQUIRE(mlb_mesh_uv_sphere(&m, 1.0f, 16, 8) == MLB_OK);
    mlb_uv_mesh u;
    REQUIRE(mlb_uv_unwrap(&m, NULL, &u, NULL) == MLB_OK);
    mlb_baked b;
    CHECK(mlb_bake(&u, 64, NULL, NULL, 4, &b) == MLB_ERR_ARG);
    CHECK(mlb_bake(&u, 0, field_fn, NULL, 4, &b) == MLB_ERR_ARG);
    CHECK(mlb_bake(&u, 64, failing_fn, NULL, 4, &b) == MLB_ERR_IO);
    CHECK(strstr(mlb_last_error(), "baking") && strstr(mlb_last_error(), "material file gone"));
    CHECK(b.kd == NULL && b.mask == NULL);
    CHECK(mlb_bake(&u, 64, nan_fn, NULL, 4, &b) == MLB_ERR_NUMERIC);
    CHECK(b.kd == NULL);
    u.mesh.faces[4] = u.mesh.n_verts;
    CHECK(mlb_bake(&u, 64, field_fn, NULL, 4, &b) == MLB_ERR_ARG);
    mlb_uv_mesh_free(&u);
    mlb_mesh_free(&m);
}

int main(void) {
    RUN(field_reproduced);
    RUN(dilation_radius_and_chart);
    RUN(mip_border_no_seam);
    RUN(thin_triangle_covered);
    RUN(stacked_and_needle_uvs);
    RUN(errors);
    RUN(codes_on_the_same_texels);
    return test_summary();
}
