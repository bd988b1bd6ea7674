// Bitmap font, line plots and image grids (include/matlaber/plot.h).
#include "test.h"
#include "matlaber/error.h"
#include "matlaber/image.h"
#include "matlaber/plot.h"
#include <stdint.h>

static const float RED[3] = {1, 0, 0}, BLUE[3] = {0, 0, 1};

static float* canvas(int w, int h) {
    float* img = malloc(sizeof(float) * 3 * (size_t)w * h);
    for (int i = 0; i < 3 * w * h; i++) img[i] = 1;
    return img;
}
static const float* px(const float* img, int w, int x, int y) { return img + ((size_t)y * w + x) * 3; }
static int is_col(const float* p, const float c[3]) { return p[0] == c[0] && p[1] == c[1] && p[2] == c[2]; }

TEST(font_glyphs_distinct) {
    const char* set = mlb_font_charset();
    int n = (int)strlen(set);
    CHECK(n == 58);
    uint8_t g[128][MLB_FONT_H];
    for (int i = 0; i < n; i++) {
        CHECK_MSG(mlb_font_glyph((unsigned char)set[i], g[i]) == 1, "'%c' unsupported", set[i]);
        int ink = 0;
        for (int r = 0; r < MLB_FONT_H; r++) { ink += g[i][r] != 0; CHECK(g[i][r] < 32); }
        CHECK_MSG(set[i] == ' ' ? ink == 0 : ink > 0, "'%c' ink rows %d", set[i], ink);
        for (int j = 0; j < i; j++) CHECK_MSG(memcmp(g[i], g[j], MLB_FONT_H) != 0, "'%c' and '%c' look the same", set[i], set[j]);
    }
    for (const char* p = "0123456789.-e+:%"; *p; p++) CHECK_MSG(strchr(set, *p >= 'a' ? *p - 32 : *p), "'%c' missing", *p);
    uint8_t a[MLB_FONT_H], b[MLB_FONT_H], box[MLB_FONT_H];
    mlb_font_glyph('e', a);
    mlb_font_glyph('E', b);
    CHECK(memcmp(a, b, MLB_FONT_H) == 0);      // lowercase draws as uppercase
    CHECK(mlb_font_glyph('~', box) == 0);      // unknown: a box, unlike every real glyph
    for (int i = 0; i < n; i++) CHECK(memcmp(box, g[i], MLB_FONT_H) != 0);
    CHECK(mlb_text_width("", 1) == 0);
    CHECK(mlb_text_width("AB", 1) == 11);
    CHECK(mlb_text_width("1e-3", 3) == 69);
}

TEST(draw_text_pixels) {
    int w = 40, h = 30;
    float* img = canvas(w, h);
    mlb_draw_text(img, w, h, 3, 2, "7%", 2, RED);
    uint8_t g7[MLB_FONT_H], gp[MLB_FONT_H];
    mlb_font_glyph('7', g7);
    mlb_font_glyph('%', gp);
    int bad = 0;
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            int on = 0;
            int gx = x - 3, gy = y - 2;
            if (gy >= 0 && gy < 14 && gx >= 0) {
                int c = gx / 2, r = gy / 2;
                if (c < 5) on = (g7[r] >> (4 - c)) & 1;
                else if (c >= 6 && c < 11) on = (gp[r] >> (4 - (c - 6))) & 1;
            }
            bad += is_col(px(img, w, x, y), on ? RED : (const float[3]){1, 1, 1}) ? 0 : 1;
        }
    CHECK_MSG(bad == 0, "%d pixels differ", bad);
    mlb_draw_text(img, w, h, -7, 25, "WXYZ", 3, BLUE);   // clipped on three sides: no crash
    mlb_draw_text(img, w, h, 38, -3, "88", 1, BLUE);
    free(img);
}

TEST(plot_series_pixels_and_nan) {
    int w = 400, h = 300;
    double x[11], ya[11], yb[11];
    for (int i = 0; i <= 10; i++) { x[i] = i; ya[i] = i; yb[i] = 8; }
    yb[5] = NAN;
    mlb_plot_series s[2] = {{x, ya, 11, {1, 0, 0}, "a", 0}, {x, yb, 11, {0, 0, 1}, "b", 0}};
    mlb_plot_opts o = {0};
    o.title = "Loss: test 1e-3 (100%)";
    o.xlabel = "step";
    float* img = canvas(w, h);
    REQUIRE(mlb_plot_draw(img, w, h, 0, 0, w, h, s, 2, &o) == MLB_OK);
    int pxx, pyy;
    for (int i = 0; i <= 10; i++) {
        if (i == 8) continue;   // where b (drawn after a) crosses a
        REQUIRE(mlb_plot_map(0, 0, w, h, s, 2, &o, x[i], ya[i], &pxx, &pyy) == 0);
        CHECK_MSG(is_col(px(img, w, pxx, pyy), RED), "a[%d] at (%d, %d)", i, pxx, pyy);
    }
    // the red line is monotone: (2.5, 2.5) lies on it too
    REQUIRE(mlb_plot_map(0, 0, w, h, s, 2, &o, 2.5, 2.5, &pxx, &pyy) == 0);
    int near = 0;
    for (int d = -1; d <= 1; d++) near |= is_col(px(img, w, pxx, pyy + d), RED);
    CHECK(near);
    // series b: points around the NaN are drawn, the gap over it is not
    CHECK(mlb_plot_map(0, 0, w, h, s, 2, &o, 5, NAN, &pxx, &pyy) == -1);
    int x4, x6, yy;
    REQUIRE(mlb_plot_map(0, 0, w, h, s, 2, &o, 4, 8, &x4, &yy) == 0);
    REQUIRE(mlb_plot_map(0, 0, w, h, s, 2, &o, 6, 8, &x6, &yy) == 0);
    CHECK(is_col(px(img, w, x4, yy), BLUE) && is_col(px(img, w, x6, yy), BLUE));
    int gap_blue = 0;
    for (int xx = x4 + 1; xx < x6; xx++) gap_blue += is_col(px(img, w, xx, yy), BLUE);
    CHECK_MSG(gap_blue == 0, "%d blue pixels over the NaN gap", gap_blue);
    // the axis is black, the title is drawn (ink in the top band), white outside the area
    int ink = 0;
    for (int yy2 = 0; yy2 < 16; yy2++) for (int xx = 0; xx < w; xx++) ink += is_col(px(img, w, xx, yy2), (const float[3]){0, 0, 0});
    CHECK(ink > 50);
    CHECK(is_col(px(img, w, w - 1, h - 1), (const float[3]){1, 1, 1}));
    free(img);
}

TEST(plot_log_y_and_smoothing) {
    int w = 500, h = 300;
    double y[100];
    for (int i = 0; i < 100; i++) y[i] = pow(10, -i / 25.0);   // 1 .. 1e-4
    y[10] = -1;   // not drawable on a log axis
    mlb_plot_series s = {NULL, y, 100, {0, 0.5f, 0}, NULL, 0};
    mlb_plot_opts o = {0};
    o.log_y = 1;
    float* img = canvas(w, h);
    REQUIRE(mlb_plot_draw(img, w, h, 0, 0, w, h, &s, 1, &o) == MLB_OK);
    int a, b;
    CHECK(mlb_plot_map(0, 0, w, h, &s, 1, &o, 10, -1, &a, &b) == -1);
    for (int i = 30; i < 100; i += 7) {   // straight line in log space
        REQUIRE(mlb_plot_map(0, 0, w, h, &s, 1, &o, i, y[i], &a, &b) == 0);
        CHECK(is_col(px(img, w, a, b), s.rgb));
    }
    int a0, b0, a1, b1;
    REQUIRE(mlb_plot_map(0, 0, w, h, &s, 1, &o, 0, 1.0, &a0, &b0) == 0);
    REQUIRE(mlb_plot_map(0, 0, w, h, &s, 1, &o, 50, 0.01, &a1, &b1) == 0);
    int a2, b2;
    REQUIRE(mlb_plot_map(0, 0, w, h, &s, 1, &o, 99, 1e-4 * pow(10, 1 / 25.0), &a2, &b2) == 0);
    CHECK(abs((b1 - b0) - (b2 - b1)) <= 2);   // equal decades, equal heights
    free(img);

    // smoothing: a spike is drawn light, the moving average on top in full colour
    double z[101];
    for (int i = 0; i <= 100; i++) z[i] = 0;
    z[50] = 10;
    mlb_plot_series t = {NULL, z, 101, {1, 0, 0}, "smoothed", 21};
    mlb_plot_opts p = {0};
    img = canvas(w, h);
    REQUIRE(mlb_plot_draw(img, w, h, 0, 0, w, h, &t, 1, &p) == MLB_OK);
    const float light[3] = {0.35f + 0.65f, 0.65f, 0.65f};
    REQUIRE(mlb_plot_map(0, 0, w, h, &t, 1, &p, 50, 10, &a, &b) == 0);
    CHECK(is_col(px(img, w, a, b), light));
    REQUIRE(mlb_plot_map(0, 0, w, h, &t, 1, &p, 50, 10.0 / 21, &a, &b) == 0);   // the average at the spike
    CHECK(is_col(px(img, w, a, b), RED));
    REQUIRE(mlb_plot_map(0, 0, w, h, &t, 1, &p, 10, 0, &a, &b) == 0);
    CHECK(is_col(px(img, w, a, b), RED));
    free(img);
}

TEST(plot_edge_cases_and_png) {
    int w = 200, h = 150;
    float* img = canvas(w, h);
    double nan[3] = {NAN, INFINITY, -INFINITY};
    mlb_plot_series s = {NULL, nan, 3, {0}, "nothing", 0};
    CHECK(mlb_plot_draw(img, w, h, 0, 0, w, h, &s, 1, NULL) == MLB_OK);   // nothing drawable
    CHECK(mlb_plot_draw(img, w, h, 0, 0, w, h, NULL, 0, NULL) == MLB_OK);
    double one = 3;
    mlb_plot_series t = {NULL, &one, 1, {0}, NULL, 0};
    CHECK(mlb_plot_draw(img, w, h, 0, 0, w, h, &t, 1, NULL) == MLB_OK);   // one point, zero range
    int a, b;
    REQUIRE(mlb_plot_map(0, 0, w, h, &t, 1, NULL, 0, 3, &a, &b) == 0);
    float c0[3];
    mlb_plot_color(0, c0);
    CHECK(is_col(px(img, w, a, b), c0));
    CHECK(mlb_plot_draw(img, w, h, 150, 0, 100, 100, &t, 1, NULL) == MLB_ERR_ARG);   // outside
    CHECK(mlb_plot_draw(img, w, h, 0, 0, 50, 50, &t, 1, NULL) == MLB_ERR_ARG);       // too small
    // fixed ranges: points outside are clipped, not wrapped
    double big[2] = {-1e300, 1e300};
    mlb_plot_series u = {NULL, big, 2, {1, 0, 0}, NULL, 0};
    mlb_plot_opts o = {0};
    o.ymin = -1; o.ymax = 1;
    CHECK(mlb_plot_draw(img, w, h, 0, 0, w, h, &u, 1, &o) == MLB_OK);
    // extreme values with automatic ranges: not drawable beyond 1e300, the rest still is
    double ext[4] = {-1.7e308, 1.7e308, 2, 4};
    double ex[4] = {0, 1, 2, -1.7e308};
    mlb_plot_series v2 = {ex, ext, 4, {1, 0, 0}, NULL, 0};
    CHECK(mlb_plot_draw(img, w, h, 0, 0, w, h, &v2, 1, NULL) == MLB_OK);
    CHECK(mlb_plot_map(0, 0, w, h, &v2, 1, NULL, 1, 1.7e308, &a, &b) == -1);
    REQUIRE(mlb_plot_map(0, 0, w, h, &v2, 1, NULL, 2, 2, &a, &b) == 0);
    CHECK(is_col(px(img, w, a, b), RED));
    free(img);
    // PNG: pixel colours survive 8-bit quantisation
    const char* dir = test_tmpdir("plot");
    REQUIRE(dir);
    char path[4200];
    snprintf(path, sizeof path, "%s/p.png", dir);
    double y[5] = {1, 3, 2, 5, 4};
    mlb_plot_series v = {NULL, y, 5, {1, 0, 0}, "v", 0};
    REQUIRE(mlb_plot_png(path, 320, 200, &v, 1, NULL) == MLB_OK);
    mlb_image im = {0};
    REQUIRE(mlb_image_load(&im, path, 3) == MLB_OK);
    CHECK(im.w == 320 && im.h == 200);
    for (int i = 0; i < 5; i++) {
        REQUIRE(mlb_plot_map(0, 0, 320, 200, &v, 1, NULL, i, y[i], &a, &b) == 0);
        CHECK(is_col(px(im.data, im.w, a, b), RED));
    }
    mlb_image_free(&im);
    snprintf(path, sizeof path, "%s/no/such/dir/p.png", dir);
    CHECK(mlb_plot_png(path, 320, 200, &v, 1, NULL) != MLB_OK && strstr(mlb_last_error(), path));
}

TEST(image_grid_layout) {
    int w = 10, h = 8, n = 3, cols = 2, pad = 3;
    float* tiles[3];
    const float cols_rgb[3][4] = {{1, 0, 0, 1}, {0, 1, 0, 1}, {0, 0, 1, 0.5f}};
    for (int k = 0; k < n; k++) {
        tiles[k] = malloc(sizeof(float) * 4 * w * h);
        for (int i = 0; i < w * h; i++) memcpy(tiles[k] + 4 * i, cols_rgb[k], sizeof cols_rgb[k]);
    }
    const char* labels[3] = {"A", NULL, "C"};
    float* out = NULL;
    int W, H;
    REQUIRE(mlb_image_grid(&out, &W, &H, (const float* const*)tiles, n, w, h, 4, cols, pad, labels) == MLB_OK);
    int lh = MLB_FONT_H + pad;
    CHECK(W == pad + cols * (w + pad) && H == pad + 2 * (h + lh + pad));
    int ex[3] = {pad, pad + w + pad, pad}, ey[3] = {pad, pad, pad + h + lh + pad};
    for (int k = 0; k < n; k++) {
        int x, y, l2, w2, h2;
        mlb_image_grid_layout(k, n, w, h, cols, pad, 1, &x, &y, &l2, &w2, &h2);
        CHECK(x == ex[k] && y == ey[k] && l2 == lh && w2 == W && h2 == H);
        float e[3];
        for (int j = 0; j < 3; j++) e[j] = cols_rgb[k][j] * cols_rgb[k][3] + (1 - cols_rgb[k][3]);
        int wrong = 0;
        for (int yy = 0; yy < h; yy++) for (int xx = 0; xx < w; xx++) wrong += !is_col(px(out, W, x + xx, y + yy), e);
        CHECK_MSG(wrong == 0, "tile %d: %d pixels wrong", k, wrong);
        // white padding left of and above the tile
        CHECK(is_col(px(out, W, x - 1, y), (const float[3]){1, 1, 1}) && is_col(px(out, W, x, y - 1), (const float[3]){1, 1, 1}));
        // label ink only under labelled tiles
        int ink = 0;
        for (int yy = y + h; yy < y + h + lh; yy++) for (int xx = x; xx < x + w; xx++) ink += is_col(px(out, W, xx, yy), (const float[3]){0, 0, 0});
        CHECK_MSG(labels[k] ? ink > 5 : ink == 0, "tile %d label ink %d", k, ink);
    }
    free(out);
    // no labels: no strip
    REQUIRE(mlb_image_grid(&out, &W, &H, (const float* const*)tiles, n, w, h, 4, 3, 0, NULL) == MLB_OK);
    CHECK(W == 3 * w && H == h);
    CHECK(is_col(px(out, W, w, 0), (const float[3]){0, 1, 0}));
    free(out);
    CHECK(mlb_image_grid(&out, &W, &H, (const float* const*)tiles, n, w, h, 2, 3, 0, NULL) == MLB_ERR_ARG);
    CHECK(mlb_image_grid(&out, &W, &H, (const float* const*)tiles, 0, w, h, 4, 3, 0, NULL) == MLB_ERR_ARG);
    for (int k = 0; k < n; k++) free(tiles[k]);
    // contiguous tiles to a PNG
    const char* dir = test_tmpdir("plot_grid");
    REQUIRE(dir);
    char path[4200];
    snprintf(path, sizeof path, "%s/g.png", dir);
    float* strip = malloc(sizeof(float) * 3 * w * h * 2);
    for (int i = 0; i < w * h; i++) { memcpy(strip + 3 * i, RED, 12); memcpy(strip + 3 * (w * h + i), BLUE, 12); }
    const char* l2[2] = {"target", "fit"};
    REQUIRE(mlb_image_grid_write(path, strip, 2, w, h, 3, 2, l2) == MLB_OK);
    mlb_image im = {0};
    REQUIRE(mlb_image_load(&im, path, 3) == MLB_OK);
    int x1, y1, ww, hh;
    mlb_image_grid_layout(1, 2, w, h, 2, MLB_GRID_PAD, 1, &x1, &y1, NULL, &ww, &hh);
    CHECK(im.w == ww && im.h == hh);
    CHECK(is_col(px(im.data, im.w, x1, y1), BLUE) && is_col(px(im.data, im.w, MLB_GRID_PAD, MLB_GRID_PAD), RED));
    mlb_image_free(&im);
    free(strip);
}

int main(void) {
    RUN(font_glyphs_distinct);
    RUN(draw_text_pixels);
    RUN(plot_series_pixels_and_nan);
    RUN(plot_log_y_and_smoothing);
    RUN(plot_edge_cases_and_png);
    RUN(image_grid_layout);
    return test_summary();
}
