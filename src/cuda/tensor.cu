// The glue between a network's layers on the device: the token + position embedding, residual and
// per-channel adds, the NCHW <-> token transpose, GEGLU, nearest 2x upsampling and strided row
// copies (channel concatenation). The contracts of the CPU code they mirror (conv_ops.h,
// transformer_ops.h, src/nn/backend.c); each output value is
// written by one thread with the CPU's float operations, so results agree bitwise except GEGLU
// (erfcf on the device, erfc in libm: a few ulps).
#include "act.cuh"
#include "common.cuh"

__global__ void add_kernel(float* y, const float* x, size_t n) {
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x)
        y[i] += x[i];
}

extern "C" mlb_status mlb_cuda_add(float* y, const float* x, size_t n) {
    if (!n) return MLB_OK;
    add_kernel<<<mlb_grid(n, 256), 256>>>(y, x, n);
    MLB_CUDA_LAUNCHED("add_kernel");
    return MLB_OK;
}

// out[bt, c] = wte[tokens[bt], c] + wpe[bt % T, c] (wpe may be NULL): embedding_forward's float add,
// a thread per value; a token outside [0, V) gets NaN (the CPU op fails on it instead)
__global__ void embedding_kernel(float* out, const int32_t* tokens, const float* wte, const float* wpe, int T, int C,
                                 int V, size_t n) {
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        size_t bt = i / C, c = i - bt * C;
        int id = tokens[bt];
        if (id < 0 || id >= V) { out[i] = __int_as_float(0x7fc00000); continue; }
        float e = wte[(size_t)id * C + c];
        out[i] = wpe ? e + wpe[(bt % T) * C + c] : e;
    }
}

extern "C" mlb_status mlb_cuda_embedding(float* out, const int32_t* tokens, const float* wte, const float* wpe, int B,
                                         int T, int C, int V) {
    if (B < 0 || T < 0 || C < 0 || V < 0)
        return mlb_fail(MLB_ERR_ARG, "mlb_cuda_embedding: bad shape B %d, T %d, C %d, vocabulary %d", B, T, C, V);
    size_t n = (size_t)B * T * C;
    if (!n) return MLB_OK;
    embedding_kernel<<<mlb_grid(n, 256), 256>>>(out, tokens, wte, wpe, T, C, V, n);
    MLB_CUDA_LAUNCHED("embedding_kernel");
    return MLB_OK;
}

// x[n, c, i] += v[n, c] for i < HW
__global__ void add_channel_kernel(float* x, const float* v, size_t rows, int HW) {
    size_t n = rows * (size_t)HW;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x)
        x[i] += v[i / HW];
}

extern "C" mlb_status mlb_cuda_add_channel(float* x, const float* v, int N, int C, int HW) {
    if (N < 0 || C < 0 || HW < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_add_channel: bad shape %d x %d x %d", N, C, HW);
    size_t n = (size_t)N * C * HW;
    if (!n) return MLB_OK;
    add_channel_kernel<<<mlb_grid(n, 256), 256>>>(x, v, (size_t)N * C, HW);
    MLB_CUDA_LAUNCHED("add_channel_kernel");
    return MLB_OK;
}

// out[n, s, r] (= or +=) in[n, r, s]: 32 x 32 tiles through shared memory (padded against bank
// conflicts), so both the reads and the writes coalesce.
__global__ void transpose_kernel(float* out, const float* in, int R, int S, int accumulate) {
    __shared__ float tile[32][33];
    const size_t base = (size_t)blockIdx.z * R * S;
    const int r0 = blockIdx.y * 32, s0 = blockIdx.x * 32;
    for (int dy = threadIdx.y; dy < 32; dy += blockDim.y) {
        int r = r0 + dy, s = s0 + threadIdx.x;
        if (r < R && s < S) tile[dy][threadIdx.x] = in[base + (size_t)r * S + s];
    }
    __syncthreads();
    for (int dy = threadIdx.y; dy < 32; dy += blockDim.y) {
        int s = s0 + dy, r = r0 + threadIdx.x;
        if (r < R && s < S) {
            float* o = out + base + (size_t)s * R + r;
            *o = accumulate ? *o + tile[threadIdx.x][dy] : tile[threadIdx.x][dy];
        }
    }
}

extern "C" mlb_status mlb_cuda_transpose_last2(float* out, const float* in, int N, int R, int S, int accumulate) {
    if (N < 0 || R < 0 || S < 0 || N > 65535)
        return mlb_fail(MLB_ERR_ARG, "mlb_cuda_transpose_last2: bad shape %d x %d x %d", N, R, S);
    if (!N || !R || !S) return MLB_OK;
    dim3 grid((S + 31) / 32, (R + 31) / 32, N), block(32, 8);
    if (grid.y > 65535) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_transpose_last2: %d rows is too many", R);
    transpose_kernel<<<grid, block>>>(out, in, R, S, accumulate);
    MLB_CUDA_LAUNCHED("transpose_kernel");
    return MLB_OK;
}

// out[t, j] = in[t, j] * gelu(in[t, C4 + j]) for in [rows, 2 C4], out [rows, C4]
__global__ void geglu_kernel(float* out, const float* in, size_t rows, int C4) {
    size_t n = rows * (size_t)C4;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        size_t t = i / C4, j = i - t * C4;
        const float* row = in + t * 2 * C4;
        out[i] = row[j] * dev_act(MLB_ACT_GELU, row[C4 + j]);
    }
}

extern "C" mlb_status mlb_cuda_geglu(float* out, const float* in, int rows, int C4) {
    if (rows < 0 || C4 < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_geglu: bad shape %d x %d", rows, C4);
    size_t n = (size_t)rows * C4;
    if (!n) return MLB_OK;
    geglu_kernel<<<mlb_grid(n, 256), 256>>>(out, in, (size_t)rows, C4);
    MLB_CUDA_LAUNCHED("geglu_kernel");
    return MLB_OK;
}

// out [N, C, 2H, 2W] from in [N, C, H, W]
__global__ void upsample2x_kernel(float* out, const float* in, size_t planes, int H, int W) {
    size_t n = planes * 4 * H * W;
    int W2 = 2 * W;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        size_t p = i / ((size_t)4 * H * W);
        int rem = (int)(i - p * 4 * H * W), y = rem / W2, x = rem - y * W2;
        out[i] = in[(p * H + y / 2) * W + x / 2];
    }
}

extern "C" mlb_status mlb_cuda_upsample_nearest2x(float* out, const float* in, int N, int C, int H, int W) {
    if (N < 0 || C < 0 || H < 0 || W < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_upsample_nearest2x: bad shape");
    size_t n = (size_t)N * C * 4 * H * W;
    if (!n) return MLB_OK;
    upsample2x_kernel<<<mlb_grid(n, 256), 256>>>(out, in, (size_t)N * C, H, W);
    MLB_CUDA_LAUNCHED("upsample2x_kernel");
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_copy_rows(float* dst, size_t dpitch, const float* src, size_t spitch, size_t width,
                                         size_t rows) {
    if (!width || !rows) return MLB_OK;
    if (width > dpitch || width > spitch) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_copy_rows: rows wider than the pitch");
    MLB_CUDA_CHECK(cudaMemcpy2DAsync(dst, dpitch * sizeof(float), src, spitch * sizeof(float), width * sizeof(float),
                                     rows, cudaMemcpyDeviceToDevice, 0));
    return MLB_OK;
}

// ---- backwards of the glue (the UNet's training: unet_train.h) ----
// din [rows, 2 C4] += d(h gelu(g)): one thread per (t, j) writes din[t, j] and din[t, C4 + j].
__global__ void geglu_backward_kernel(float* din, const float* dout, const float* in, size_t rows, int C4) {
    size_t n = rows * (size_t)C4;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        size_t t = i / C4, j = i - t * C4;
        const float* row = in + t * 2 * C4;
        float* g = din + t * 2 * C4;
        float d = dout[i], gate = row[C4 + j];
        g[j] += d * dev_act(MLB_ACT_GELU, gate);
        g[C4 + j] += d * row[j] * dev_act_d1(MLB_ACT_GELU, gate);
    }
}

extern "C" mlb_status mlb_cuda_geglu_backward(float* din, const float* dout, const float* in, int rows, int C4) {
    if (rows < 0 || C4 < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_geglu_backward: bad shape %d x %d", rows, C4);
    size_t n = (size_t)rows * C4;
    if (!n) return MLB_OK;
    geglu_backward_kernel<<<mlb_grid(n, 256), 256>>>(din, dout, in, (size_t)rows, C4);
    MLB_CUDA_LAUNCHED("geglu_backward_kernel");
    return MLB_OK;
}

// din [N, C, H, W] += the 2x2 block sums of dout [N, C, 2H, 2W], added as the CPU adds them
__global__ void upsample2x_backward_kernel(float* din, const float* dout, size_t planes, int H, int W) {
    size_t n = planes * H * W;
    int W2 = 2 * W;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        size_t p = i / ((size_t)H * W);
        int rem = (int)(i - p * H * W), y = rem / W, x = rem - y * W;
        const float* r0 = dout + (p * 2 * H + 2 * y) * W2;
        const float* r1 = r0 + W2;
        din[i] += (r0[2 * x] + r0[2 * x + 1]) + (r1[2 * x] + r1[2 * x + 1]);
    }
}

extern "C" mlb_status mlb_cuda_upsample_nearest2x_backward(float* din, const float* dout, int N, int C, int H, int W) {
    if (N < 0 || C < 0 || H < 0 || W < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_upsample_nearest2x_backward: bad shape");
    size_t n = (size_t)N * C * H * W;
    if (!n) return MLB_OK;
    upsample2x_backward_kernel<<<mlb_grid(n, 256), 256>>>(din, dout, (size_t)N * C, H, W);
    MLB_CUDA_LAUNCHED("upsample2x_backward_kernel");
    return MLB_OK;
}

// dv[r] += sum_i dx[r, i]: one warp per row r, strided partial sums in double, then a fixed
// butterfly (the same order every run)
__global__ void add_channel_backward_kernel(float* dv, const float* dx, size_t rows, int HW) {
    size_t warp = ((size_t)blockIdx.x * blockDim.x + threadIdx.x) / 32;
    int lane = threadIdx.x & 31;
    if (warp >= rows) return;
    const float* p = dx + warp * HW;
    double s = 0;
    for (int i = lane; i < HW; i += 32) s += p[i];
    for (int o = 16; o > 0; o >>= 1) s += __shfl_xor_sync(0xffffffffu, s, o);
    if (lane == 0) dv[warp] += (float)s;
}

extern "C" mlb_status mlb_cuda_add_channel_backward(float* dv, const float* dx, int N, int C, int HW) {
    if (N < 0 || C < 0 || HW < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_add_channel_backward: bad shape");
    size_t rows = (size_t)N * C;
    if (!rows) return MLB_OK;
    add_channel_backward_kernel<<<(unsigned)((rows * 32 + 255) / 256), 256>>>(dv, dx, rows, HW);
    MLB_CUDA_LAUNCHED("add_channel_backward_kernel");
    return MLB_OK;
}
