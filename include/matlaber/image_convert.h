// The conversions between the stages' renders and what a diffusion model sees (guidance_sds.h):
// channels-last renders [n, H, W, 4] to channels-first model inputs and back. Each is an op of the
// tables too (backend_ops.def: area_resize, renders_to_sd and their backwards), so that the
// guidance can take renders that live on a GPU.
#ifndef MATLABER_IMAGE_CONVERT_H
#define MATLABER_IMAGE_CONVERT_H

// Area (box-average) resize of channels-last src [n, H, W, C] to channels-first dst [n, C, h, w]:
// dst pixel (y, x) averages src rows [⌊yH/h⌋, ⌈(y+1)H/h⌉) × columns [⌊xW/w⌋, ⌈(x+1)W/w⌉)
// (PyTorch's "area" / adaptive average pooling); exact box averages for integer factors. The sum
// in double, rows then columns.
void mlb_area_resize_nhwc_to_nchw(float* dst, const float* src, int n, int H, int W, int C, int h, int w);
// Its adjoint: dsrc [n, H, W, C] += the transpose applied to ddst [n, C, h, w], output pixels in
// row-major order.
void mlb_area_resize_nhwc_to_nchw_backward(float* dsrc, const float* ddst, int n, int H, int W, int C, int h, int w);

// renders [n, H, W, 4] → x [n, 3, H, W] in [0, 1]: normal = 1 (the geometry stage's [normal·α, α]):
// 0.5 (n·α + α), the normal map composited over black; normal = 0 (colour·α, α): the colour.
void mlb_renders_to_sd(float* x, const float* renders, int n, int H, int W, int normal);
// Its adjoint: drenders [n, H, W, 4] += from dx [n, 3, H, W] (normal: 0.5 dx to channel c and to
// α, c = 0, 1, 2 in turn).
void mlb_renders_to_sd_backward(float* drenders, const float* dx, int n, int H, int W, int normal);

#endif
