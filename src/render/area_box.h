// The area resize's boxes (image_convert.h), written once for the CPU (src/render/image_convert.c)
// and the GPU (src/cuda/samples.cu): output row (or column) y of h covers source rows
// [area_lo, area_hi) of H, and a box's mean is its double sum times area_inv.
#ifndef MATLABER_AREA_BOX_H
#define MATLABER_AREA_BOX_H
#include "core/hd.h"

MLB_HD int area_lo(int y, int H, int h) { return (int)((long long)y * H / h); }
MLB_HD int area_hi(int y, int H, int h) { return (int)(((long long)(y + 1) * H + h - 1) / h); }
MLB_HD double area_inv(int y0, int y1, int x0, int x1) { return 1.0 / ((double)(y1 - y0) * (x1 - x0)); }

// The box of output pixel (y, x) of h x w over an H x W source, and its mean's weight.
typedef struct {
    int y0, y1, x0, x1;
    double inv;
} area_box;
MLB_HD area_box area_box_at(int y, int x, int H, int W, int h, int w) {
    area_box a;
    a.y0 = area_lo(y, H, h), a.y1 = area_hi(y, H, h);
    a.x0 = area_lo(x, W, w), a.x1 = area_hi(x, W, w);
    a.inv = area_inv(a.y0, a.y1, a.x0, a.x1);
    return a;
}

#endif
