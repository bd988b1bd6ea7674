// Convolution through cuDNN, when the build found it (MLB_HAVE_CUDNN): the forward and the input
// gradient, which the SD UNet and the VAE (encoder forward and backward) spend a third and most of
// their time in. cuDNN's implicit-GEMM kernels read the input once instead of writing and reading
// an im2col matrix KH*KW times its size (conv.cu). The weight gradient stays on conv_backward.cu's
// GEMMs (no model trains a convolution here).
// Precision as the GEMM path: fp32 on CUDA cores (FMA math), tf32 on tensor cores, fp16/bf16 by
// converting the operands (fp32 accumulation; the result is rounded to the operand type once before
// it is widened back, which is within those types' bounds). Asymmetric padding (the SD VAE's
// downsampling) is not in cuDNN's descriptor: those convolutions stay on the GEMM path.
#include "common.cuh"
#include "conv_cudnn.cuh"
#include <cuda_bf16.h>
#include <cuda_fp16.h>
#include <stdlib.h>
#include <string.h>

static int g_cudnn_on = -1;   // -1: from $MLB_CUDNN on first use (0 turns it off)

extern "C" void mlb_cuda_use_cudnn(int on) { g_cudnn_on = on ? 1 : 0; }

#ifdef MLB_HAVE_CUDNN
#include <cudnn.h>

#define CUDNN_CHECK(call) do { cudnnStatus_t st_ = (call); if (st_ != CUDNN_STATUS_SUCCESS) \
        return mlb_fail(MLB_ERR_DEVICE, "%s:%d: %s: %s", __FILE__, __LINE__, #call, cudnnGetErrorString(st_)); } while (0)

extern "C" int mlb_cuda_cudnn_version(void) { return (int)cudnnGetVersion(); }

int mlb_cudnn_conv_usable(const mlb_conv2d* cv) {
    if (g_cudnn_on < 0) {
        const char* e = getenv("MLB_CUDNN");
        g_cudnn_on = !(e && e[0] == '0');
    }
    return g_cudnn_on && cv->pad_top == cv->pad_bottom && cv->pad_left == cv->pad_right;
}

static cudnnHandle_t g_handle;
static int g_handle_device = -1;
static mlb_status handle(cudnnHandle_t* out) {
    int dev;
    MLB_CUDA_CHECK(cudaGetDevice(&dev));
    if (g_handle && g_handle_device != dev) { cudnnDestroy(g_handle); g_handle = NULL; }
    if (!g_handle) {
        CUDNN_CHECK(cudnnCreate(&g_handle));
        g_handle_device = dev;
    }
    *out = g_handle;
    return MLB_OK;
}

// The descriptors of one convolution at one operand type.
typedef struct {
    cudnnTensorDescriptor_t x, y;
    cudnnFilterDescriptor_t w;
    cudnnConvolutionDescriptor_t conv;
} descs;

static void descs_free(descs* d) {
    if (d->x) cudnnDestroyTensorDescriptor(d->x);
    if (d->y) cudnnDestroyTensorDescriptor(d->y);
    if (d->w) cudnnDestroyFilterDescriptor(d->w);
    if (d->conv) cudnnDestroyConvolutionDescriptor(d->conv);
    memset(d, 0, sizeof *d);
}

static cudnnDataType_t data_type(mlb_gemm_precision p) {
    return p == MLB_GEMM_FP16 ? CUDNN_DATA_HALF : p == MLB_GEMM_BF16 ? CUDNN_DATA_BFLOAT16 : CUDNN_DATA_FLOAT;
}
static int is_half_prec(mlb_gemm_precision p) { return p == MLB_GEMM_FP16 || p == MLB_GEMM_BF16; }

static mlb_status descs_make(descs* d, const mlb_conv2d* cv, mlb_gemm_precision prec) {
    memset(d, 0, sizeof *d);
    const cudnnDataType_t t = data_type(prec);
    const int OH = mlb_conv2d_out_h(cv), OW = mlb_conv2d_out_w(cv);
    CUDNN_CHECK(cudnnCreateTensorDescriptor(&d->x));
    CUDNN_CHECK(cudnnCreateTensorDescriptor(&d->y));
    CUDNN_CHECK(cudnnCreateFilterDescriptor(&d->w));
    CUDNN_CHECK(cudnnCreateConvolutionDescriptor(&d->conv));
    CUDNN_CHECK(cudnnSetTensor4dDescriptor(d->x, CUDNN_TENSOR_NCHW, t, cv->N, cv->C, cv->H, cv->W));
    CUDNN_CHECK(cudnnSetTensor4dDescriptor(d->y, CUDNN_TENSOR_NCHW, t, cv->N, cv->OC, OH, OW));
    CUDNN_CHECK(cudnnSetFilter4dDescriptor(d->w, t, CUDNN_TENSOR_NCHW, cv->OC, cv->C, cv->KH, cv->KW));
    CUDNN_CHECK(cudnnSetConvolution2dDescriptor(d->conv, cv->pad_top, cv->pad_left, cv->stride_h, cv->stride_w, 1, 1,
                                                CUDNN_CROSS_CORRELATION, CUDNN_DATA_FLOAT));
    // fp32: FMA only (cuDNN would otherwise take TF32 on tensor cores); the rest: tensor cores
    CUDNN_CHECK(cudnnSetConvolutionMathType(d->conv, prec == MLB_GEMM_FP32 ? CUDNN_FMA_MATH : CUDNN_TENSOR_OP_MATH));
    return MLB_OK;
}

// The algorithm per (shape, precision, direction): cuDNN's heuristic ranking, the first that runs
// within WORKSPACE_MAX, remembered.
#define WORKSPACE_MAX ((size_t)2 << 30)
#define ALGO_CACHE 256
static struct { mlb_conv2d cv; int prec, backward, algo; size_t ws; } g_algos[ALGO_CACHE];
static int g_n_algos;

static mlb_status pick_algo(cudnnHandle_t h, const descs* d, const mlb_conv2d* cv, mlb_gemm_precision prec, int backward,
                            int* algo, size_t* ws) {
    for (int i = 0; i < g_n_algos; i++)
        if (!memcmp(&g_algos[i].cv, cv, sizeof *cv) && g_algos[i].prec == (int)prec && g_algos[i].backward == backward) {
            *algo = g_algos[i].algo;
            *ws = g_algos[i].ws;
            return MLB_OK;
        }
    int found = 0, chosen = -1;
    size_t need = 0;
    if (!backward) {
        cudnnConvolutionFwdAlgoPerf_t perf[CUDNN_CONVOLUTION_FWD_ALGO_COUNT];
        CUDNN_CHECK(cudnnGetConvolutionForwardAlgorithm_v7(h, d->x, d->w, d->conv, d->y, CUDNN_CONVOLUTION_FWD_ALGO_COUNT,
                                                           &found, perf));
        for (int i = 0; i < found && chosen < 0; i++)
            if (perf[i].status == CUDNN_STATUS_SUCCESS && perf[i].memory <= WORKSPACE_MAX) {
                chosen = (int)perf[i].algo;
                need = perf[i].memory;
            }
    } else {
        cudnnConvolutionBwdDataAlgoPerf_t perf[CUDNN_CONVOLUTION_BWD_DATA_ALGO_COUNT];
        CUDNN_CHECK(cudnnGetConvolutionBackwardDataAlgorithm_v7(h, d->w, d->y, d->conv, d->x,
                                                                CUDNN_CONVOLUTION_BWD_DATA_ALGO_COUNT, &found, perf));
        for (int i = 0; i < found && chosen < 0; i++)
            if (perf[i].status == CUDNN_STATUS_SUCCESS && perf[i].memory <= WORKSPACE_MAX) {
                chosen = (int)perf[i].algo;
                need = perf[i].memory;
            }
    }
    if (chosen < 0)
        return mlb_fail(MLB_ERR_DEVICE, "cuDNN has no %s algorithm for conv %dx%d, %d -> %d channels, %dx%d, batch %d",
                        backward ? "input-gradient" : "forward", cv->KH, cv->KW, cv->C, cv->OC, cv->H, cv->W, cv->N);
    if (g_n_algos < ALGO_CACHE) {
        g_algos[g_n_algos].cv = *cv;
        g_algos[g_n_algos].prec = (int)prec;
        g_algos[g_n_algos].backward = backward;
        g_algos[g_n_algos].algo = chosen;
        g_algos[g_n_algos].ws = need;
        g_n_algos++;
    }
    *algo = chosen;
    *ws = need;
    return MLB_OK;
}

static size_t round_256(size_t b) { return (b + 255) / 256 * 256; }

// out[n, c, :] = (float)y16[n, c, :] (+ bias[c]) or, accumulate, out += (float)y16
template <typename T>
__global__ void widen_kernel(float* out, const T* y, const float* bias, size_t n, int C, int HW, int accumulate) {
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        float v = (float)y[i];
        if (bias) v += bias[(i / HW) % C];
        out[i] = accumulate ? out[i] + v : v;
    }
}
__global__ void add_bias_kernel(float* out, const float* bias, size_t n, int C, int HW) {
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x)
        out[i] += bias[(i / HW) % C];
}
static mlb_status widen(mlb_gemm_precision prec, float* out, const void* y, const float* bias, size_t n, int C, int HW,
                        int accumulate) {
    if (prec == MLB_GEMM_FP16)
        widen_kernel<__half><<<mlb_grid(n, 256), 256>>>(out, (const __half*)y, bias, n, C, HW, accumulate);
    else
        widen_kernel<__nv_bfloat16><<<mlb_grid(n, 256), 256>>>(out, (const __nv_bfloat16*)y, bias, n, C, HW, accumulate);
    MLB_CUDA_LAUNCHED("widen_kernel");
    return MLB_OK;
}

// One direction of the convolution. Forward: a = in, b = out (+ bias). Backward: a = dout, b = din
// (accumulated).
static mlb_status run(int backward, float* b, const float* a, const float* weight, const float* bias,
                      const mlb_conv2d* cv, mlb_gemm_precision prec) {
    cudnnHandle_t h = NULL;
    MLB_TRY(handle(&h));
    descs d;
    mlb_status s = descs_make(&d, cv, prec);
    int algo = 0;
    size_t ws = 0;
    if (!s) s = pick_algo(h, &d, cv, prec, backward, &algo, &ws);
    if (s) { descs_free(&d); return s; }
    const int OH = mlb_conv2d_out_h(cv), OW = mlb_conv2d_out_w(cv);
    const size_t nx = (size_t)cv->N * cv->C * cv->H * cv->W, ny = (size_t)cv->N * cv->OC * OH * OW,
                 nw = (size_t)cv->OC * cv->C * cv->KH * cv->KW;
    const size_t na = backward ? ny : nx, nb = backward ? nx : ny;
    const int half = is_half_prec(prec), b_channels = backward ? cv->C : cv->OC, b_hw = backward ? cv->H * cv->W : OH * OW;
    const size_t esz = half ? 2 : 0;   // operand copies only when half
    const size_t a_bytes = round_256(na * esz), w_bytes = round_256(nw * esz), b_bytes = round_256(nb * esz);
    void* scratch = NULL;
    s = mlb_cuda_scratch(&scratch, a_bytes + w_bytes + b_bytes + round_256(ws));
    if (s) { descs_free(&d); return s; }
    char* a16 = (char*)scratch;
    char* w16 = a16 + a_bytes;
    char* b16 = w16 + w_bytes;
    void* work = b16 + b_bytes;
    const void *a_op = a, *w_op = weight;
    void* b_op = b;
    if (half) {
        mlb_cuda_dtype t = prec == MLB_GEMM_FP16 ? MLB_DTYPE_F16 : MLB_DTYPE_BF16;
        if (!s) s = mlb_cuda_convert(a16, t, a, na);
        if (!s) s = mlb_cuda_convert(w16, t, weight, nw);
        a_op = a16;
        w_op = w16;
        b_op = b16;
    }
    const float one = 1.0f, zero = 0.0f;
    const float* beta = (backward && !half) ? &one : &zero;   // the float input gradient accumulates in place
    cudnnStatus_t st = CUDNN_STATUS_SUCCESS;
    if (!s && !backward)
        st = cudnnConvolutionForward(h, &one, d.x, a_op, d.w, w_op, d.conv, (cudnnConvolutionFwdAlgo_t)algo, work, ws, beta,
                                     d.y, b_op);
    else if (!s)
        st = cudnnConvolutionBackwardData(h, &one, d.w, w_op, d.y, a_op, d.conv, (cudnnConvolutionBwdDataAlgo_t)algo, work,
                                          ws, beta, d.x, b_op);
    descs_free(&d);
    if (s) return s;
    if (st != CUDNN_STATUS_SUCCESS)
        return mlb_fail(MLB_ERR_DEVICE, "cuDNN convolution %s (%dx%d, %d -> %d channels, %dx%d, batch %d, %s): %s",
                        backward ? "input gradient" : "forward", cv->KH, cv->KW, cv->C, cv->OC, cv->H, cv->W, cv->N,
                        mlb_gemm_precision_name(prec), cudnnGetErrorString(st));
    if (half) return widen(prec, b, b16, backward ? NULL : bias, nb, b_channels, b_hw, backward);
    if (bias) {
        add_bias_kernel<<<mlb_grid(nb, 256), 256>>>(b, bias, nb, b_channels, b_hw);
        MLB_CUDA_LAUNCHED("add_bias_kernel");
    }
    return MLB_OK;
}

mlb_status mlb_cudnn_conv2d_forward(float* out, const float* in, const float* weight, const float* bias,
                                    const mlb_conv2d* cv, mlb_gemm_precision prec) {
    return run(0, out, in, weight, bias, cv, prec);
}

mlb_status mlb_cudnn_conv2d_backward_data(float* din, const float* dout, const float* weight, const mlb_conv2d* cv,
                                          mlb_gemm_precision prec) {
    return run(1, din, dout, weight, NULL, cv, prec);
}

#else   // built without cuDNN: the GEMM path does every convolution

extern "C" int mlb_cuda_cudnn_version(void) { return 0; }
int mlb_cudnn_conv_usable(const mlb_conv2d* cv) { (void)cv; return 0; }
mlb_status mlb_cudnn_conv2d_forward(float* out, const float* in, const float* weight, const float* bias,
                                    const mlb_conv2d* cv, mlb_gemm_precision prec) {
    (void)out; (void)in; (void)weight; (void)bias; (void)cv; (void)prec;
    return mlb_fail(MLB_ERR_DEVICE, "built without cuDNN");
}
mlb_status mlb_cudnn_conv2d_backward_data(float* din, const float* dout, const float* weight, const mlb_conv2d* cv,
                                          mlb_gemm_precision prec) {
    (void)din; (void)dout; (void)weight; (void)cv; (void)prec;
    return mlb_fail(MLB_ERR_DEVICE, "built without cuDNN");
}
#endif
