// Small raster drawing for run outputs (docs/runs.md): a 5x7 bitmap font, line plots and image
// grids (contact sheets). Images here are interleaved RGB floats, h rows of w pixels of 3 floats,
// top row first (what mlb_image_write_png takes with c = 3). Drawing clips to the image.
#ifndef MATLABER_PLOT_H
#define MATLABER_PLOT_H
#include <stdint.h>
#include "matlaber/error.h"

// ---- font ------------------------------------------------------------------------------------
// Glyphs 5 wide, 7 tall, advance 6 (one blank column); scaled by an integer factor.
// Supported: space, 0-9, A-Z (lowercase a-z draws as uppercase), and . , - + : % / ( ) _ = [ ] ' ! ? # < > * |
#define MLB_FONT_W 5
#define MLB_FONT_H 7
#define MLB_FONT_ADVANCE 6
// rows[r] bit (4 - col) set = pixel (col, r) on. Returns 1 for a supported character, 0 otherwise
// (rows then hold the "unknown" box glyph, which is what mlb_draw_text draws for it).
int mlb_font_glyph(int ch, uint8_t rows[MLB_FONT_H]);
// The characters with a glyph of their own (NUL-terminated; lowercase not listed).
const char* mlb_font_charset(void);
// Width in pixels of text drawn at `scale` (no trailing blank column); 0 for "".
int mlb_text_width(const char* text, int scale);
// Draws text with its top-left corner at (x, y); pixels outside the image are skipped.
void mlb_draw_text(float* img, int w, int h, int x, int y, const char* text, int scale, const float rgb[3]);

// ---- primitives ------------------------------------------------------------------------------
void mlb_draw_line(float* img, int w, int h, int x0, int y0, int x1, int y1, const float rgb[3]);   // 1 px, Bresenham
void mlb_fill_rect(float* img, int w, int h, int x, int y, int rw, int rh, const float rgb[3]);

// ---- line plots ------------------------------------------------------------------------------
typedef struct {
    const double* x;     // [n]; NULL = 0, 1, 2, ...
    const double* y;     // [n]; NaN/Inf (and y <= 0 on a log axis) skipped; the line breaks there
    int n;
    float rgb[3];        // colour; {0,0,0} = pick from the default palette by series index
    const char* label;   // legend entry; NULL = none
    int smooth;          // > 1: raw points drawn lighter + a centred moving average over `smooth`
                         // points (finite ones only; on a log axis averaged in log10) in full colour
} mlb_plot_series;

typedef struct {
    const char* title;    // NULL = none
    const char* xlabel;   // NULL = none
    int log_y;            // 1 = log10 y axis
    int scale;            // font scale, 0 = 1
    double xmin, xmax, ymin, ymax;   // used when min < max; else from the data (y padded by 5%)
    const double* vlines; int n_vlines;   // grey vertical markers at these x (e.g. stage boundaries)
} mlb_plot_opts;

// The default palette: distinct, saturated colours (index taken modulo its size, 8).
void mlb_plot_color(int i, float rgb[3]);
// Draws a plot (white background, axes, ticks with labels, title, legend) into the rectangle
// [x0, x0+pw) x [y0, y0+ph) of img. MLB_ERR_ARG for a rectangle outside img or too small
// (pw < 80 or ph < 60), or n < 0. Series with no drawable point are fine (empty plot, axes [0, 1]).
mlb_status mlb_plot_draw(float* img, int w, int h, int x0, int y0, int pw, int ph,
                         const mlb_plot_series* s, int n_series, const mlb_plot_opts* opt);
// Where the plot area of a mlb_plot_draw call maps a data point (same arguments and data);
// returns 0 and sets (*px, *py) (pixel column, row), or -1 when the point is not drawable.
int mlb_plot_map(int x0, int y0, int pw, int ph, const mlb_plot_series* s, int n_series,
                 const mlb_plot_opts* opt, double x, double y, int* px, int* py);
// One plot to a PNG (8-bit RGB) of w x h pixels.
mlb_status mlb_plot_png(const char* path, int w, int h, const mlb_plot_series* s, int n_series, const mlb_plot_opts* opt);

// ---- image grids -----------------------------------------------------------------------------
// Tiles n images (each h x w x c floats, c = 3 or 4; alpha composited over the white background)
// into rows of `cols`, `pad` pixels around and between tiles, with labels[i] (labels or labels[i]
// may be NULL) written in black under each tile, truncated to the tile width.
// *out is a malloc'd RGB image of *out_w x *out_h (free it). Layout: mlb_image_grid_tile.
mlb_status mlb_image_grid(float** out, int* out_w, int* out_h, const float* const* images, int n,
                          int w, int h, int c, int cols, int pad, const char* const* labels);
// mlb_image_grid over n tiles stored one after another in `images` ([n, h, w, c] floats), with
// padding MLB_GRID_PAD, written to `path` as an 8-bit RGB PNG (values as they are, see
// mlb_image_write_png). labels as in mlb_image_grid.
#define MLB_GRID_PAD 4
mlb_status mlb_image_grid_write(const char* path, const float* images, int n, int w, int h, int c, int cols,
                                const char* const* labels);
// Layout of mlb_image_grid: the top-left pixel (*x, *y) of tile i, the label strip height
// (*label_h: 0 without labels, else 7·scale + pad with scale = w >= 256 ? 2 : 1) and the whole
// size; rows = ceil(n / cols).
//   tile i at x = pad + (i % cols)·(w + pad), y = pad + (i / cols)·(h + label_h + pad)
//   out_w = pad + cols·(w + pad), out_h = pad + rows·(h + label_h + pad)
void mlb_image_grid_layout(int i, int n, int w, int h, int cols, int pad, int has_labels,
                           int* x, int* y, int* label_h, int* out_w, int* out_h);

#endif
