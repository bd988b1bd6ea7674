// Private to src/cuda: the cuDNN convolutions (conv_cudnn.cu) that conv.cu and conv_backward.cu
// hand a convolution to when cuDNN can run it.
#ifndef MLB_CUDA_CONV_CUDNN_CUH
#define MLB_CUDA_CONV_CUDNN_CUH
extern "C" {
#include "matlaber/conv_ops.h"
#include "matlaber/cuda_ops.h"
}

// 1 when this convolution goes to cuDNN: built with it, not turned off (mlb_cuda_use_cudnn, or
// MLB_CUDNN=0 in the environment), symmetric padding.
int mlb_cudnn_conv_usable(const mlb_conv2d* cv);
// conv2d_forward's contract (out = conv + bias)
mlb_status mlb_cudnn_conv2d_forward(float* out, const float* in, const float* weight, const float* bias,
                                    const mlb_conv2d* cv, mlb_gemm_precision prec);
// din += the input gradient of dout
mlb_status mlb_cudnn_conv2d_backward_data(float* din, const float* dout, const float* weight, const mlb_conv2d* cv,
                                          mlb_gemm_precision prec);
#endif
