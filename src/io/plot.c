// Line plots rasterised into an RGB float image (docs/runs.md): axes, ticks with labels in the
// project's bitmap font (font.c), title, legend, several series, log-y, moving-average smoothing.
#include "matlaber/plot.h"
#include "matlaber/image_write.h"
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const float BLACK[3] = {0, 0, 0}, WHITE[3] = {1, 1, 1}, GRID[3] = {0.9f, 0.9f, 0.9f},
                   MARK[3] = {0.6f, 0.6f, 0.6f};

void mlb_plot_color(int i, float rgb[3]) {
    static const float pal[8][3] = {
        {0.12f, 0.47f, 0.71f}, {0.84f, 0.15f, 0.16f}, {0.17f, 0.63f, 0.17f}, {1.00f, 0.50f, 0.05f},
        {0.58f, 0.40f, 0.74f}, {0.55f, 0.34f, 0.29f}, {0.89f, 0.47f, 0.76f}, {0.09f, 0.75f, 0.81f}};
    i = ((i % 8) + 8) % 8;
    memcpy(rgb, pal[i], sizeof pal[i]);
}

static inline void put(float* img, int w, int h, int x, int y, const float rgb[3]) {
    if (x < 0 || y < 0 || x >= w || y >= h) return;
    float* d = img + ((size_t)y * w + x) * 3;
    d[0] = rgb[0]; d[1] = rgb[1]; d[2] = rgb[2];
}

void mlb_fill_rect(float* img, int w, int h, int x, int y, int rw, int rh, const float rgb[3]) {
    int xa = x < 0 ? 0 : x, ya = y < 0 ? 0 : y;
    int xb = x + rw > w ? w : x + rw, yb = y + rh > h ? h : y + rh;
    for (int j = ya; j < yb; j++)
        for (int i = xa; i < xb; i++) put(img, w, h, i, j, rgb);
}

// Bresenham; pixels outside [cx0, cx1) x [cy0, cy1) are skipped (callers clip long lines first).
static void line_clip(float* img, int w, int h, int x0, int y0, int x1, int y1, const float rgb[3],
                      int cx0, int cy0, int cx1, int cy1) {
    int dx = abs(x1 - x0), sx = x0 < x1 ? 1 : -1;
    int dy = -abs(y1 - y0), sy = y0 < y1 ? 1 : -1;
    int err = dx + dy;
    for (;;) {
        if (x0 >= cx0 && x0 < cx1 && y0 >= cy0 && y0 < cy1) put(img, w, h, x0, y0, rgb);
        if (x0 == x1 && y0 == y1) break;
        int e2 = 2 * err;
        if (e2 >= dy) { err += dy; x0 += sx; }
        if (e2 <= dx) { err += dx; y0 += sy; }
    }
}

void mlb_draw_line(float* img, int w, int h, int x0, int y0, int x1, int y1, const float rgb[3]) {
    line_clip(img, w, h, x0, y0, x1, y1, rgb, 0, 0, w, h);
}

// Liang-Barsky: clips the segment to [xa, xb] x [ya, yb]; 0 when nothing is left.
static int clip_segment(double* x0, double* y0, double* x1, double* y1, double xa, double ya, double xb, double yb) {
    double t0 = 0, t1 = 1, dx = *x1 - *x0, dy = *y1 - *y0;
    double p[4] = {-dx, dx, -dy, dy}, q[4] = {*x0 - xa, xb - *x0, *y0 - ya, yb - *y0};
    for (int i = 0; i < 4; i++) {
        if (p[i] == 0) { if (q[i] < 0) return 0; continue; }
        double r = q[i] / p[i];
        if (p[i] < 0) { if (r > t1) return 0; if (r > t0) t0 = r; }
        else { if (r < t0) return 0; if (r < t1) t1 = r; }
    }
    double nx0 = *x0 + t0 * dx, ny0 = *y0 + t0 * dy, nx1 = *x0 + t1 * dx, ny1 = *y0 + t1 * dy;
    *x0 = nx0; *y0 = ny0; *x1 = nx1; *y1 = ny1;
    return 1;
}

// ---- layout ----------------------------------------------------------------------------------
typedef struct {
    int ax0, ay0, ax1, ay1;         // plot area [ax0, ax1) x [ay0, ay1)
    double xlo, xhi, ylo, yhi;      // data range (y in display space: log10 when log_y)
    int log_y, scale;
    double xt0, xstep, yt0, ystep;  // first tick and spacing
    int nxt, nyt;
} layout;

// x of point i, or NAN when not drawable; magnitudes above 1e300 count as not drawable so that
// ranges and their differences stay finite
static inline double sx_of(const mlb_plot_series* s, int i) {
    double x = s->x ? s->x[i] : (double)i;
    return isfinite(x) && fabs(x) <= 1e300 ? x : NAN;
}
// display-space y, or NAN when the point is not drawable
static inline double disp_y(double y, int log_y) {
    if (!isfinite(y) || fabs(y) > 1e300) return NAN;
    if (log_y) return y > 0 ? log10(y) : NAN;
    return y;
}

static double nice_step(double range, int target) {
    if (!(range > 0)) return 1;
    double raw = range / (target < 1 ? 1 : target);
    double p = pow(10, floor(log10(raw))), f = raw / p;
    double m = f <= 1 ? 1 : f <= 2 ? 2 : f <= 5 ? 5 : 10;
    return m * p;
}

static void ticks(double lo, double hi, double step, double* t0, int* nt) {
    double a = ceil(lo / step - 1e-9) * step;
    int n = (int)floor((hi - a) / step + 1e-9) + 1;
    if (n < 0) n = 0;
    if (n > 50) n = 50;
    *t0 = a; *nt = n;
}

// Tick label of v on a grid of `step` (1, 2 or 5 times a power of ten): plain decimals with as
// many places as the step needs ("0.0005", "150"), exponent form outside 1e-6 .. 1e6.
static void fmt_num(char* buf, size_t cap, double v, double step) {
    if (fabs(v) < step * 1e-6) v = 0;
    int dec = (int)-floor(log10(step) + 1e-9);
    if (dec < 0) dec = 0;
    if (v == 0) snprintf(buf, cap, "0");
    else if (fabs(v) < 1e6 && dec <= 6) snprintf(buf, cap, "%.*f", dec, v);
    else snprintf(buf, cap, "%.3g", v);
}

static void fmt_tick_y(char* buf, size_t cap, const layout* L, double t) {
    if (!L->log_y) { fmt_num(buf, cap, t, L->ystep); return; }
    double r = round(t);
    if (fabs(t - r) < 1e-9) {   // a power of ten
        int e = (int)r;
        if (e >= 0 && e <= 4) snprintf(buf, cap, "%.0f", pow(10, e));
        else if (e < 0 && e >= -3) snprintf(buf, cap, "%.*f", -e, pow(10, e));
        else snprintf(buf, cap, "1e%d", e);
    } else snprintf(buf, cap, "%.3g", pow(10, t));
}

static void data_range(const mlb_plot_series* s, int n_series, int log_y, double* xlo, double* xhi, double* ylo, double* yhi) {
    double a = INFINITY, b = -INFINITY, c = INFINITY, d = -INFINITY;
    for (int k = 0; k < n_series; k++)
        for (int i = 0; i < s[k].n; i++) {
            double x = sx_of(&s[k], i), y = s[k].y ? disp_y(s[k].y[i], log_y) : NAN;
            if (!isfinite(x) || isnan(y)) continue;
            if (x < a) a = x;
            if (x > b) b = x;
            if (y < c) c = y;
            if (y > d) d = y;
        }
    if (a > b) { a = 0; b = 1; c = 0; d = 1; }
    *xlo = a; *xhi = b; *ylo = c; *yhi = d;
}

static void compute_layout(layout* L, int x0, int y0, int pw, int ph, const mlb_plot_series* s, int n_series, const mlb_plot_opts* opt) {
    mlb_plot_opts none = {0};
    if (!opt) opt = &none;
    memset(L, 0, sizeof *L);
    L->scale = opt->scale > 0 ? opt->scale : 1;
    L->log_y = opt->log_y;
    int ch = MLB_FONT_H * L->scale;
    data_range(s, n_series, L->log_y, &L->xlo, &L->xhi, &L->ylo, &L->yhi);
    if (opt->xmin < opt->xmax && fabs(opt->xmin) <= 1e300 && fabs(opt->xmax) <= 1e300) { L->xlo = opt->xmin; L->xhi = opt->xmax; }
    if (L->xlo == L->xhi) { L->xlo -= 0.5; L->xhi += 0.5; }
    double ya = opt->ymin, yb = opt->ymax;
    if (L->log_y) { ya = ya > 0 ? log10(ya) : NAN; yb = yb > 0 ? log10(yb) : NAN; }
    if (ya < yb && fabs(ya) <= 1e300 && fabs(yb) <= 1e300) { L->ylo = ya; L->yhi = yb; }
    else {
        if (L->ylo == L->yhi) { double m = fabs(L->ylo) * 0.1; if (m == 0) m = 0.5; L->ylo -= m; L->yhi += m; }
        double pad = (L->yhi - L->ylo) * 0.05;
        L->ylo -= pad; L->yhi += pad;
    }
    // vertical: title on top, tick labels (and the x label) below
    L->ay0 = y0 + 6 + (opt->title ? ch + 6 : 0);
    L->ay1 = y0 + ph - (6 + ch + 4 + (opt->xlabel ? ch + 4 : 0));
    int target = (L->ay1 - L->ay0) / (ch * 4);
    if (target < 2) target = 2;
    L->ystep = nice_step(L->yhi - L->ylo, target);
    if (L->log_y && L->yhi - L->ylo >= 2 && L->ystep < 1) L->ystep = 1;
    ticks(L->ylo, L->yhi, L->ystep, &L->yt0, &L->nyt);
    int lw = 0;
    for (int i = 0; i < L->nyt; i++) {
        char buf[64];
        fmt_tick_y(buf, sizeof buf, L, L->yt0 + i * L->ystep);
        int tw = mlb_text_width(buf, L->scale);
        if (tw > lw) lw = tw;
    }
    L->ax0 = x0 + 4 + lw + 6;
    L->ax1 = x0 + pw - 10;
    int xt = (L->ax1 - L->ax0) / (MLB_FONT_ADVANCE * L->scale * 10);
    if (xt < 2) xt = 2;
    L->xstep = nice_step(L->xhi - L->xlo, xt);
    ticks(L->xlo, L->xhi, L->xstep, &L->xt0, &L->nxt);
}

static inline double map_x(const layout* L, double x) { return L->ax0 + (x - L->xlo) / (L->xhi - L->xlo) * (L->ax1 - 1 - L->ax0); }
static inline double map_y(const layout* L, double y) { return (L->ay1 - 1) - (y - L->ylo) / (L->yhi - L->ylo) * (L->ay1 - 1 - L->ay0); }

int mlb_plot_map(int x0, int y0, int pw, int ph, const mlb_plot_series* s, int n_series,
                 const mlb_plot_opts* opt, double x, double y, int* px, int* py) {
    layout L;
    compute_layout(&L, x0, y0, pw, ph, s, n_series, opt);
    double dy = disp_y(y, L.log_y);
    if (!isfinite(x) || isnan(dy)) return -1;
    double fx = floor(map_x(&L, x) + 0.5), fy = floor(map_y(&L, dy) + 0.5);
    if (fx < L.ax0 || fx >= L.ax1 || fy < L.ay0 || fy >= L.ay1) return -1;
    *px = (int)fx; *py = (int)fy;
    return 0;
}

// Draws the polyline of (xs[i], ys[i]) (ys in display space, NaN = break) clipped to the area.
static void polyline(float* img, int w, int h, const layout* L, const mlb_plot_series* s, const double* ys, const float rgb[3]) {
    int have = 0;
    double px = 0, py = 0;
    for (int i = 0; i < s->n; i++) {
        double x = sx_of(s, i), y = ys[i];
        if (!isfinite(x) || isnan(y)) { have = 0; continue; }
        double qx = map_x(L, x), qy = map_y(L, y);
        double a = have ? px : qx, b = have ? py : qy, c = qx, d = qy;
        if (clip_segment(&a, &b, &c, &d, L->ax0, L->ay0, L->ax1 - 1, L->ay1 - 1))
            line_clip(img, w, h, (int)floor(a + 0.5), (int)floor(b + 0.5), (int)floor(c + 0.5), (int)floor(d + 0.5),
                      rgb, L->ax0, L->ay0, L->ax1, L->ay1);
        px = qx; py = qy; have = 1;
    }
}

mlb_status mlb_plot_draw(float* img, int w, int h, int x0, int y0, int pw, int ph,
                         const mlb_plot_series* s, int n_series, const mlb_plot_opts* opt) {
    if (!img || w <= 0 || h <= 0) return mlb_fail(MLB_ERR_ARG, "plot: no image");
    if (n_series < 0 || (n_series > 0 && !s)) return mlb_fail(MLB_ERR_ARG, "plot: bad series list (n = %d)", n_series);
    if (x0 < 0 || y0 < 0 || pw < 80 || ph < 60 || x0 + pw > w || y0 + ph > h)
        return mlb_fail(MLB_ERR_ARG, "plot: rectangle %dx%d at (%d, %d) does not fit a %dx%d image (at least 80x60)", pw, ph, x0, y0, w, h);
    for (int k = 0; k < n_series; k++)
        if (s[k].n < 0 || (s[k].n > 0 && !s[k].y)) return mlb_fail(MLB_ERR_ARG, "plot: series %d has no data (n = %d)", k, s[k].n);
    mlb_plot_opts none = {0};
    if (!opt) opt = &none;
    layout L;
    compute_layout(&L, x0, y0, pw, ph, s, n_series, opt);
    int sc = L.scale, ch = MLB_FONT_H * sc;
    mlb_fill_rect(img, w, h, x0, y0, pw, ph, WHITE);
    // grid lines and ticks
    char buf[64];
    for (int i = 0; i < L.nyt; i++) {
        double t = L.yt0 + i * L.ystep;
        int py = (int)floor(map_y(&L, t) + 0.5);
        line_clip(img, w, h, L.ax0, py, L.ax1 - 1, py, GRID, L.ax0, L.ay0, L.ax1, L.ay1);
        mlb_draw_line(img, w, h, L.ax0 - 4, py, L.ax0 - 1, py, BLACK);
        fmt_tick_y(buf, sizeof buf, &L, t);
        mlb_draw_text(img, w, h, L.ax0 - 6 - mlb_text_width(buf, sc), py - ch / 2, buf, sc, BLACK);
    }
    for (int i = 0; i < L.nxt; i++) {
        double t = L.xt0 + i * L.xstep;
        int px = (int)floor(map_x(&L, t) + 0.5);
        line_clip(img, w, h, px, L.ay0, px, L.ay1 - 1, GRID, L.ax0, L.ay0, L.ax1, L.ay1);
        mlb_draw_line(img, w, h, px, L.ay1, px, L.ay1 + 3, BLACK);
        fmt_num(buf, sizeof buf, t, L.xstep);
        mlb_draw_text(img, w, h, px - mlb_text_width(buf, sc) / 2, L.ay1 + 6, buf, sc, BLACK);
    }
    for (int i = 0; i < opt->n_vlines && opt->vlines; i++) {
        double v = opt->vlines[i];
        if (!isfinite(v) || v < L.xlo || v > L.xhi) continue;
        int px = (int)floor(map_x(&L, v) + 0.5);
        for (int y = L.ay0; y < L.ay1; y += 4) line_clip(img, w, h, px, y, px, y + 1, MARK, L.ax0, L.ay0, L.ax1, L.ay1);
    }
    // series: the lighter raw curves first, then the full-colour ones on top
    size_t nmax = 0;
    for (int k = 0; k < n_series; k++) if ((size_t)s[k].n > nmax) nmax = (size_t)s[k].n;
    double* ys = malloc(sizeof(double) * (nmax ? nmax : 1));
    double* cs = malloc(sizeof(double) * (nmax + 1));
    int* cn = malloc(sizeof(int) * (nmax + 1));
    if (!ys || !cs || !cn) { free(ys); free(cs); free(cn); return mlb_fail(MLB_ERR_NOMEM, "plot: out of memory"); }
    for (int pass = 0; pass < 2; pass++)
        for (int k = 0; k < n_series; k++) {
            const mlb_plot_series* S = &s[k];
            float col[3];
            memcpy(col, S->rgb, sizeof col);
            if (col[0] == 0 && col[1] == 0 && col[2] == 0) mlb_plot_color(k, col);
            int smooth = S->smooth > 1;
            for (int i = 0; i < S->n; i++) ys[i] = disp_y(S->y[i], L.log_y);
            if (pass == 0) {
                if (!smooth) continue;
                float light[3] = {0.35f * col[0] + 0.65f, 0.35f * col[1] + 0.65f, 0.35f * col[2] + 0.65f};
                polyline(img, w, h, &L, S, ys, light);
                continue;
            }
            if (smooth) {   // centred moving average over the finite points of the window
                cs[0] = 0; cn[0] = 0;
                for (int i = 0; i < S->n; i++) {
                    int ok = !isnan(ys[i]);
                    cs[i + 1] = cs[i] + (ok ? ys[i] : 0);
                    cn[i + 1] = cn[i] + ok;
                }
                for (int i = 0; i < S->n; i++) {
                    if (isnan(ys[i])) continue;
                    int a = i - S->smooth / 2, b = a + S->smooth;
                    if (a < 0) a = 0;
                    if (b > S->n) b = S->n;
                    ys[i] = (cs[b] - cs[a]) / (cn[b] - cn[a]);
                }
            }
            polyline(img, w, h, &L, S, ys, col);
        }
    free(ys); free(cs); free(cn);
    // axes
    mlb_draw_line(img, w, h, L.ax0 - 1, L.ay0, L.ax0 - 1, L.ay1, BLACK);
    mlb_draw_line(img, w, h, L.ax0 - 1, L.ay1, L.ax1 - 1, L.ay1, BLACK);
    if (opt->title) mlb_draw_text(img, w, h, x0 + (pw - mlb_text_width(opt->title, sc)) / 2, y0 + 6, opt->title, sc, BLACK);
    if (opt->xlabel)
        mlb_draw_text(img, w, h, L.ax0 + (L.ax1 - L.ax0 - mlb_text_width(opt->xlabel, sc)) / 2, L.ay1 + 6 + ch + 4, opt->xlabel, sc, BLACK);
    // legend, top right inside the area
    int ly = L.ay0 + 4;
    for (int k = 0; k < n_series; k++) {
        if (!s[k].label) continue;
        float col[3];
        memcpy(col, s[k].rgb, sizeof col);
        if (col[0] == 0 && col[1] == 0 && col[2] == 0) mlb_plot_color(k, col);
        int tw = mlb_text_width(s[k].label, sc);
        int sw = 12 * sc, gap = 4 * sc;   // colour sample, gap, text
        int lx = L.ax1 - 8 - tw - sw - gap;
        mlb_fill_rect(img, w, h, lx - 2, ly - 2, sw + gap + tw + 4, ch + 4, WHITE);
        for (int t = 0; t < 2; t++) mlb_draw_line(img, w, h, lx, ly + ch / 2 + t, lx + sw - 1, ly + ch / 2 + t, col);
        mlb_draw_text(img, w, h, lx + sw + gap, ly, s[k].label, sc, BLACK);
        ly += ch + 4;
    }
    return MLB_OK;
}

mlb_status mlb_plot_png(const char* path, int w, int h, const mlb_plot_series* s, int n_series, const mlb_plot_opts* opt) {
    if (w < 80 || h < 60 || w > 16384 || h > 16384) return mlb_fail(MLB_ERR_ARG, "%s: plot size %dx%d out of range", path, w, h);
    float* img = malloc(sizeof(float) * 3 * (size_t)w * h);
    if (!img) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path);
    mlb_status st = mlb_plot_draw(img, w, h, 0, 0, w, h, s, n_series, opt);
    if (st != MLB_OK) st = mlb_fail_context(st, "%s", path);
    else st = mlb_image_write_png(path, img, w, h, 3, NULL);   // names the path itself
    free(img);
    return st;
}
