// Supersampling (box downsample and its backward), the coverage mask, and compositing over a
// background. Written over `real`, compiled as float and as double (_f64).
#include <stdlib.h>
#include "matlaber/raster.h"
#include "core/real.h"

// out[y, x, c] = mean over the s×s block of in[(y s + i), (x s + j), c]
void FN(mlb_downsample_box)(real* out, const real* in, int H, int W, int C, int s) {
    size_t Wi = (size_t)W * s;
    double inv = 1.0 / ((double)s * s);
#pragma omp parallel for schedule(static) if ((size_t)H * W * C > 16384)
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            for (int c = 0; c < C; c++) {
                double acc = 0;
                for (int i = 0; i < s; i++) {
                    const real* row = in + (((size_t)y * s + i) * Wi + (size_t)x * s) * C + c;
                    for (int j = 0; j < s; j++) acc += row[(size_t)j * C];
                }
                out[((size_t)y * W + x) * C + c] = (real)(acc * inv);
            }
}

void FN(mlb_downsample_box_backward)(real* din, const real* dout, int H, int W, int C, int s) {
    if (!din) return;
    size_t Wi = (size_t)W * s;
    real inv = (real)(1.0 / ((double)s * s));
#pragma omp parallel for schedule(static) if ((size_t)H * W * C > 16384)
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            for (int c = 0; c < C; c++) {
                real g = dout[((size_t)y * W + x) * C + c] * inv;
                for (int i = 0; i < s; i++) {
                    real* row = din + (((size_t)y * s + i) * Wi + (size_t)x * s) * C + c;
                    for (int j = 0; j < s; j++) row[(size_t)j * C] += g;
                }
            }
}

void FN(mlb_coverage_mask)(real* mask, const int32_t* tri, int n_pix) {
#pragma omp parallel for schedule(static) if (n_pix > 65536)
    for (int p = 0; p < n_pix; p++) mask[p] = tri[p] >= 0 ? (real)1 : (real)0;
}

void FN(mlb_composite)(real* out, const real* color, const real* mask, const real* bg, int bg_per_pixel, int n_pix,
                       int C) {
#pragma omp parallel for schedule(static) if ((size_t)n_pix * C > 65536)
    for (int p = 0; p < n_pix; p++) {
        real m = mask[p];
        const real* b = bg_per_pixel ? bg + (size_t)p * C : bg;
        for (int c = 0; c < C; c++) {
            size_t i = (size_t)p * C + c;
            out[i] = m * color[i] + ((real)1 - m) * b[c];
        }
    }
}

#define COMPOSITE_BLOCKS 64   // fixed partition of the background's sum (thread-count independent)

void FN(mlb_composite_backward)(real* dcolor, real* dmask, real* dbg, const real* dout, const real* color,
                                const real* mask, const real* bg, int bg_per_pixel, int n_pix, int C) {
#pragma omp parallel for schedule(static) if ((size_t)n_pix * C > 65536)
    for (int p = 0; p < n_pix; p++) {
        real m = mask[p];
        const real* b = bg_per_pixel ? bg + (size_t)p * C : bg;
        double dm = 0;
        for (int c = 0; c < C; c++) {
            size_t i = (size_t)p * C + c;
            if (dcolor) dcolor[i] += m * dout[i];
            dm += (double)dout[i] * ((double)color[i] - b[c]);
            if (dbg && bg_per_pixel) dbg[i] += ((real)1 - m) * dout[i];
        }
        if (dmask) dmask[p] += (real)dm;
    }
    if (!dbg || bg_per_pixel || C <= 0) return;
    double* part = calloc((size_t)COMPOSITE_BLOCKS * C, sizeof(double));
    if (part) {
#pragma omp parallel for schedule(static) if ((size_t)n_pix * C > 65536)
        for (int k = 0; k < COMPOSITE_BLOCKS; k++) {
            int p0 = (int)((int64_t)n_pix * k / COMPOSITE_BLOCKS), p1 = (int)((int64_t)n_pix * (k + 1) / COMPOSITE_BLOCKS);
            for (int p = p0; p < p1; p++)
                for (int c = 0; c < C; c++)
                    part[(size_t)k * C + c] += (1.0 - mask[p]) * dout[(size_t)p * C + c];
        }
        for (int c = 0; c < C; c++) {
            double s = 0;
            for (int k = 0; k < COMPOSITE_BLOCKS; k++) s += part[(size_t)k * C + c];
            dbg[c] += (real)s;
        }
        free(part);
    } else {   // no memory for the partial sums: the same fixed order, on one thread
        for (int c = 0; c < C; c++) {
            double s = 0;
            for (int p = 0; p < n_pix; p++) s += (1.0 - mask[p]) * dout[(size_t)p * C + c];
            dbg[c] += (real)s;
        }
    }
}
