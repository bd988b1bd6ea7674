// Contact sheets: images tiled in rows with a caption under each (docs/runs.md).
#include "matlaber/plot.h"
#include "matlaber/image_write.h"
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int grid_scale(int w) { return w >= 256 ? 2 : 1; }

void mlb_image_grid_layout(int i, int n, int w, int h, int cols, int pad, int has_labels,
                           int* x, int* y, int* label_h, int* out_w, int* out_h) {
    if (cols < 1) cols = 1;
    if (cols > n && n > 0) cols = n;
    int lh = has_labels ? MLB_FONT_H * grid_scale(w) + pad : 0;
    int rows = n > 0 ? (n + cols - 1) / cols : 0;
    if (x) *x = pad + (i % cols) * (w + pad);
    if (y) *y = pad + (i / cols) * (h + lh + pad);
    if (label_h) *label_h = lh;
    if (out_w) *out_w = pad + cols * (w + pad);
    if (out_h) *out_h = pad + rows * (h + lh + pad);
}

mlb_status mlb_image_grid(float** out, int* out_w, int* out_h, const float* const* images, int n,
                          int w, int h, int c, int cols, int pad, const char* const* labels) {
    *out = NULL; *out_w = 0; *out_h = 0;
    if (n < 1 || !images) return mlb_fail(MLB_ERR_ARG, "image grid: no images (n = %d)", n);
    if (w < 1 || h < 1 || w > 16384 || h > 16384) return mlb_fail(MLB_ERR_ARG, "image grid: tile size %dx%d out of range", w, h);
    if (c != 3 && c != 4) return mlb_fail(MLB_ERR_ARG, "image grid: %d channels (3 or 4 supported)", c);
    if (cols < 1) return mlb_fail(MLB_ERR_ARG, "image grid: %d columns", cols);
    if (pad < 0 || pad > 1024) return mlb_fail(MLB_ERR_ARG, "image grid: padding %d out of range", pad);
    for (int i = 0; i < n; i++) if (!images[i]) return mlb_fail(MLB_ERR_ARG, "image grid: image %d is NULL", i);
    int has_labels = 0;
    for (int i = 0; labels && i < n; i++) if (labels[i] && labels[i][0]) has_labels = 1;
    int cl = cols < n ? cols : n, rows = (n + cl - 1) / cl;
    if ((double)(pad + cl * ((double)w + pad)) * (pad + rows * ((double)h + MLB_FONT_H * 2 + 2.0 * pad)) > 1.0e8)
        return mlb_fail(MLB_ERR_ARG, "image grid: %d tiles of %dx%d in %d columns is too large", n, w, h, cols);
    int W, H, lh;
    mlb_image_grid_layout(0, n, w, h, cols, pad, has_labels, NULL, NULL, &lh, &W, &H);
    if ((double)W * H > 1.0e8) return mlb_fail(MLB_ERR_ARG, "image grid: %dx%d output is too large", W, H);
    float* img = malloc(sizeof(float) * 3 * (size_t)W * H);
    if (!img) return mlb_fail(MLB_ERR_NOMEM, "image grid: out of memory (%dx%d)", W, H);
    for (size_t i = 0; i < (size_t)W * H * 3; i++) img[i] = 1.0f;
    int sc = w >= 256 ? 2 : 1;
    const float black[3] = {0, 0, 0};
    for (int k = 0; k < n; k++) {
        int tx, ty;
        mlb_image_grid_layout(k, n, w, h, cols, pad, has_labels, &tx, &ty, NULL, NULL, NULL);
        const float* src = images[k];
        for (int y = 0; y < h; y++)
            for (int x = 0; x < w; x++) {
                const float* p = src + ((size_t)y * w + x) * c;
                float* d = img + ((size_t)(ty + y) * W + tx + x) * 3;
                if (c == 4) {   // over the white background
                    float a = p[3];
                    for (int j = 0; j < 3; j++) d[j] = p[j] * a + (1.0f - a);
                } else {
                    d[0] = p[0]; d[1] = p[1]; d[2] = p[2];
                }
            }
        if (has_labels && labels[k]) {
            int maxc = (w / sc + 1) / MLB_FONT_ADVANCE;   // characters that fit the tile width
            char buf[256];
            snprintf(buf, sizeof buf, "%s", labels[k]);
            if (maxc < (int)sizeof buf && (int)strlen(buf) > maxc) buf[maxc] = 0;
            int tw = mlb_text_width(buf, sc);
            mlb_draw_text(img, W, H, tx + (w - tw) / 2, ty + h + pad / 2, buf, sc, black);
        }
    }
    *out = img; *out_w = W; *out_h = H;
    return MLB_OK;
}

mlb_status mlb_image_grid_write(const char* path, const float* images, int n, int w, int h, int c, int cols,
                                const char* const* labels) {
    if (!path || !images || n < 1 || n > 1 << 20) return mlb_fail(MLB_ERR_ARG, "%s: image grid of %d tiles", path ? path : "(null)", n);
    const float** tiles = malloc(sizeof *tiles * (size_t)n);
    if (!tiles) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path);
    for (int i = 0; i < n; i++) tiles[i] = images + (size_t)i * w * h * c;
    float* out = NULL;
    int W = 0, H = 0;
    mlb_status s = mlb_image_grid(&out, &W, &H, tiles, n, w, h, c, cols, MLB_GRID_PAD, labels);
    free(tiles);
    if (s) return mlb_fail_context(s, "%s", path);
    s = mlb_image_write_png(path, out, W, H, 3, NULL);
    free(out);
    return s;
}
