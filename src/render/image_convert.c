// The renders' conversions for the diffusion model (image_convert.h); the CUDA kernels of the same
// ops are in src/cuda/samples.cu and give these bits.
#include "matlaber/image_convert.h"
#include <stddef.h>
#include "render/area_box.h"

void mlb_area_resize_nhwc_to_nchw(float* dst, const float* src, int n, int H, int W, int C, int h, int w) {
    for (int b = 0; b < n; b++)
        for (int y = 0; y < h; y++)
            for (int x = 0; x < w; x++) {
                area_box a = area_box_at(y, x, H, W, h, w);
                for (int c = 0; c < C; c++) {
                    double s = 0;
                    for (int yy = a.y0; yy < a.y1; yy++)
                        for (int xx = a.x0; xx < a.x1; xx++) s += src[(((size_t)b * H + yy) * W + xx) * C + c];
                    dst[(((size_t)b * C + c) * h + y) * w + x] = (float)(s * a.inv);
                }
            }
}

void mlb_area_resize_nhwc_to_nchw_backward(float* dsrc, const float* ddst, int n, int H, int W, int C, int h, int w) {
    for (int b = 0; b < n; b++)
        for (int y = 0; y < h; y++)
            for (int x = 0; x < w; x++) {
                area_box a = area_box_at(y, x, H, W, h, w);
                for (int c = 0; c < C; c++) {
                    float g = (float)(ddst[(((size_t)b * C + c) * h + y) * w + x] * a.inv);
                    for (int yy = a.y0; yy < a.y1; yy++)
                        for (int xx = a.x0; xx < a.x1; xx++) dsrc[(((size_t)b * H + yy) * W + xx) * C + c] += g;
                }
            }
}

void mlb_renders_to_sd(float* x, const float* renders, int n, int H, int W, int normal) {
    const size_t HW = (size_t)H * W;
    for (int b = 0; b < n; b++)
        for (size_t i = 0; i < HW; i++) {
            const float* px = renders + ((size_t)b * HW + i) * 4;
            for (int c = 0; c < 3; c++) x[((size_t)b * 3 + c) * HW + i] = normal ? 0.5f * (px[c] + px[3]) : px[c];
        }
}

void mlb_renders_to_sd_backward(float* drenders, const float* dx, int n, int H, int W, int normal) {
    const size_t HW = (size_t)H * W;
    for (int b = 0; b < n; b++)
        for (size_t i = 0; i < HW; i++) {
            float* d = drenders + ((size_t)b * HW + i) * 4;
            for (int c = 0; c < 3; c++) {
                float g = dx[((size_t)b * 3 + c) * HW + i];
                if (normal) { d[c] += 0.5f * g; d[3] += 0.5f * g; }
                else d[c] += g;
            }
        }
}
