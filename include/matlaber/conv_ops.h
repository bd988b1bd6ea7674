// Convolution-family ops over NCHW tensors (llm.c style: plain functions over row-major buffers,
// shapes in the signature or in a small descriptor): 2-D convolution, group normalisation (with
// an optional fused activation), nearest 2x upsampling, a batched transpose between NCHW and
// token-major [N, HW, C], and scaled dot-product attention that never holds a whole [Tq, Tk]
// matrix. Used by the SD VAE (vae.h) and the UNet. See docs/vae.md.
//
// Every op exists twice from one source (src/nn/conv_ops.c, an MLB_DUAL_SOURCE, see
// src/core/real.h): float under the plain name and double under name_f64 (finite-difference tests).
// Conventions, as everywhere in matlaber:
//   - backward functions ACCUMULATE (+=) into their gradient buffers, any of which may be NULL
//     (that gradient is skipped, and so is the work only it needs);
//   - results never depend on the thread count (every output value is summed by one thread in a
//     fixed order; OpenBLAS GEMMs give the same bits on 1 and 2 threads on this build);
//   - buffers must not overlap unless a comment says so;
//   - ops that can fail return mlb_status (MLB_ERR_ARG for a bad shape, with a message naming it;
//     MLB_ERR_NOMEM when an internal scratch allocation fails) and never print.
//
// WORKSPACE. Ops that need scratch take `ws` (float* or double*, matching the op) and a
// *_workspace_size function giving the number of ELEMENTS it must hold (the same count for both
// precisions). ws == NULL: the op allocates (and frees) the scratch itself on every call, and
// returns MLB_ERR_NOMEM if that fails. A caller-provided ws must not overlap any other argument
// and must not be shared by two calls running at the same time. Workspace sizes are bounded
// (the ops tile their work), so a few MB per call, whatever the image size.
#ifndef MATLABER_CONV_OPS_H
#define MATLABER_CONV_OPS_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/conv_desc.h"
#include "matlaber/error.h"
#include "matlaber/nn.h"   // mlb_activation

// ---- 2-D convolution (cross-correlation, as torch.nn.Conv2d with groups = 1, dilation 1) --------
// The descriptor mlb_conv2d, its output size and its check: matlaber/conv_desc.h.
// Elements of scratch conv2d_forward/conv2d_backward need (either precision): the im2col matrix
// for a band of output rows, C*KH*KW x (rows*OW), with at most ~4M elements unless a single output
// row needs more. 0 for a 1x1 kernel with stride 1 and no padding (a plain GEMM), and for an
// invalid descriptor.
size_t conv2d_workspace_size(const mlb_conv2d* cv);

// out = conv(in, weight) + bias. out must not overlap in. Returns MLB_ERR_ARG (via
// mlb_conv2d_check, or for a NULL in/out/weight) or MLB_ERR_NOMEM (ws == NULL and no memory).
mlb_status conv2d_forward(float* out, const float* in, const float* weight, const float* bias,
                          const mlb_conv2d* cv, float* ws);
mlb_status conv2d_forward_f64(double* out, const double* in, const double* weight, const double* bias,
                              const mlb_conv2d* cv, double* ws);
// Given dout [N, OC, OH, OW]:
//   din[N,C,H,W]        += d/d(in)      (needs weight; `in` is not read for it)
//   dweight[OC,C,KH,KW] += d/d(weight)  (needs in)
//   dbias[OC]           += sum over n, y, x of dout   (summed in double)
// Any of din/dweight/dbias may be NULL; in may be NULL when dweight is. din must not overlap dout.
mlb_status conv2d_backward(float* din, float* dweight, float* dbias, const float* dout, const float* in,
                           const float* weight, const mlb_conv2d* cv, float* ws);
mlb_status conv2d_backward_f64(double* din, double* dweight, double* dbias, const double* dout, const double* in,
                               const double* weight, const mlb_conv2d* cv, double* ws);
// The same two with their GEMMs in mlb_gemm_bf16 (nn.h: bf16 operands, fp32 sums; fp32 where the
// CPU lacks AVX-512 BF16). The backend's CPU bf16 table runs these.
mlb_status conv2d_forward_bf16(float* out, const float* in, const float* weight, const float* bias,
                               const mlb_conv2d* cv, float* ws);
// conv2d_forward_bf16 with the weight packed once for the bf16 kernel (a frozen model's: the UNet
// loaded with bf16_weights), by mlb_bf16_pack_conv_weight (K = C·KH·KW) into
// mlb_bf16_conv_weight_words(OC, K) words: the same bits, without packing the weight per call.
// The packing returns 0 (writing nothing), the conv MLB_ERR_UNSUPPORTED, on a CPU without AVX-512 BF16.
size_t mlb_bf16_conv_weight_words(int OC, int K);
int mlb_bf16_pack_conv_weight(uint32_t* out, const float* weight, int OC, int K);
mlb_status conv2d_forward_bf16_packed(float* out, const float* in, const uint32_t* weight, const float* bias,
                                      const mlb_conv2d* cv);
mlb_status conv2d_backward_bf16(float* din, float* dweight, float* dbias, const float* dout, const float* in,
                                const float* weight, const mlb_conv2d* cv, float* ws);

// ---- group normalisation (torch.nn.GroupNorm) with an optional fused activation ----------------
// in/out [N, C, HW] (HW = H*W values per channel), G groups of C/G consecutive channels:
//   xhat = (in - mean[n,g]) * rstd[n,g],  rstd = 1 / sqrt(var + eps)   (biased variance)
//   out  = act(xhat * weight[c] + bias[c])      (act = MLB_ACT_IDENTITY for a plain GroupNorm;
//                                                MLB_ACT_SILU for the norm -> SiLU of ResNet blocks)
// The statistics are two-pass sums in double over the group's C/G * HW values. weight/bias [C]
// may be NULL (1 / 0). mean/rstd [N, G] receive the statistics for the backward (may be NULL).
// out may alias in. MLB_ERR_ARG when C is not a multiple of G or a size is negative.
mlb_status groupnorm_forward(float* out, float* mean, float* rstd, const float* in, const float* weight,
                             const float* bias, int N, int C, int HW, int G, float eps, mlb_activation act);
mlb_status groupnorm_forward_f64(double* out, double* mean, double* rstd, const double* in, const double* weight,
                                 const double* bias, int N, int C, int HW, int G, double eps, mlb_activation act);
// Given dout (the gradient of `out`) and the forward's in, weight, bias, act and mean/rstd (which
// are required): with gy = dout * act'(xhat * weight + bias) and g = gy * weight,
//   din[n,c,:]  += rstd * (g - mean_group(g) - xhat * mean_group(g * xhat))
//   dweight[c]  += sum_{n,hw} gy * xhat,   dbias[c] += sum_{n,hw} gy     (sums in double)
// Only the input and the statistics are kept: the pre-activation is recomputed, so a cache holds
// one tensor per norm. din must not overlap dout. MLB_ERR_NOMEM when the per-channel partial sums for
// dweight/dbias cannot be allocated (nothing is allocated when both are NULL).
mlb_status groupnorm_backward(float* din, float* dweight, float* dbias, const float* dout, const float* in,
                              const float* weight, const float* bias, const float* mean, const float* rstd,
                              int N, int C, int HW, int G, mlb_activation act);
mlb_status groupnorm_backward_f64(double* din, double* dweight, double* dbias, const double* dout,
                                  const double* in, const double* weight, const double* bias, const double* mean,
                                  const double* rstd, int N, int C, int HW, int G, mlb_activation act);

// ---- nearest-neighbour 2x upsampling (F.interpolate(scale_factor=2, mode="nearest")) ----------
// in [N, C, H, W] -> out [N, C, 2H, 2W], out[n,c,y,x] = in[n,c,y/2,x/2].
void upsample_nearest2x_forward(float* out, const float* in, int N, int C, int H, int W);
void upsample_nearest2x_forward_f64(double* out, const double* in, int N, int C, int H, int W);
// din[N,C,H,W] += the sum of each 2x2 block of dout [N, C, 2H, 2W].
void upsample_nearest2x_backward(float* din, const float* dout, int N, int C, int H, int W);
void upsample_nearest2x_backward_f64(double* din, const double* dout, int N, int C, int H, int W);

// ---- batched transpose: NCHW <-> tokens ---------------------------------------------------------
// out[n, s, r] (= or +=) in[n, r, s] for in [N, R, S], out [N, S, R]. With R = C and S = H*W this
// turns an NCHW map into tokens [N, HW, C] (and back with R = HW, S = C). accumulate = 0 writes,
// 1 adds (a residual add fused with the transpose; also the backward of either direction).
void transpose_last2(float* out, const float* in, int N, int R, int S, int accumulate);
void transpose_last2_f64(double* out, const double* in, int N, int R, int S, int accumulate);

// ---- scaled dot-product attention, memory-efficient ---------------------------------------------
// NH heads of width hd = C / NH. For batch b, head h, query t (no mask):
//   p[t, s] = softmax_s(q[b,t,h] . k[b,s,h] / sqrt(hd)),  s in [0, Tk)
//   out[b, t, h*hd : (h+1)*hd] = sum_s p[t, s] v[b,s,h]
// q: query token t of batch b starts at q + (b*Tq + t)*ldq, head h at + h*hd (ldq >= C);
// k, v: key token s at k + (b*Tk + s)*ldkv (ldkv >= C), likewise v. So ldq = ldkv = C for separate
// [B,T,C] buffers, ldq = ldkv = 3C for a fused self-attention qkv [B,T,3C] (q = qkv, k = qkv + C,
// v = qkv + 2C), Tk = 77 and a [B,77,2C] fused kv for cross-attention.
// out [B, Tq, C] (row stride C) must not overlap q/k/v.
// The queries are processed in blocks of rows (GEMMs through OpenBLAS) whose score rows are
// complete, so only a [rows, Tk] block of scores exists at a time (rows = 2^20 / Tk, at least 16):
// at Tq = Tk = 4096 (a 512x512 SD image in the VAE mid block) 256 rows, 4 MB of float scores
// instead of 64 MB per head; the backward holds two such blocks. The softmax subtracts the row
// maximum; row sums are in double.
// lse [B, NH, Tq] (may be NULL) receives each row's log-sum-exp of the scaled scores, which the
// backward needs. MLB_ERR_ARG: C not a multiple of NH, ld < C, Tk < 1 with Tq >= 1, ...
// The same forward for the CPU's bf16 op table (src/nn/attention_bf16.c): both products with bf16
// operands and fp32 sums, the softmax in fp32; bitwise the same on any thread count; sdpa_forward
// itself (fp32 bits) where the CPU lacks AVX-512 BF16. Relative error about 2^-8 (tests/test_gemm_bf16.c).
mlb_status sdpa_forward_bf16(float* out, float* lse, const float* q, const float* k, const float* v, int B, int Tq,
                             int Tk, int C, int NH, int ldq, int ldkv);
size_t sdpa_workspace_size(int Tq, int Tk);   // elements; enough for forward and backward
mlb_status sdpa_forward(float* out, float* lse, const float* q, const float* k, const float* v, int B, int Tq,
                        int Tk, int C, int NH, int ldq, int ldkv, float* ws);
mlb_status sdpa_forward_f64(double* out, double* lse, const double* q, const double* k, const double* v, int B,
                            int Tq, int Tk, int C, int NH, int ldq, int ldkv, double* ws);
// Given dout [B, Tq, C] and the forward's out and lse (required; the scores are recomputed):
//   dq (layout of q, stride ldq) += dL/dq,  dk, dv (layout of k, v, stride ldkv) += dL/dk, dL/dv.
// Any of dq/dk/dv may be NULL; they may point into one fused dqkv buffer (disjoint columns).
mlb_status sdpa_backward(float* dq, float* dk, float* dv, const float* dout, const float* out, const float* lse,
                         const float* q, const float* k, const float* v, int B, int Tq, int Tk, int C, int NH,
                         int ldq, int ldkv, float* ws);
mlb_status sdpa_backward_f64(double* dq, double* dk, double* dv, const double* dout, const double* out,
                             const double* lse, const double* q, const double* k, const double* v, int B, int Tq,
                             int Tk, int C, int NH, int ldq, int ldkv, double* ws);
// sdpa_backward with its five products on the bf16 GEMM (mlb_gemm_bf16; the scores, dS and the row
// sums stay fp32/double): the CPU's bf16 op table runs it; sdpa_backward's bits without AVX-512 BF16.
mlb_status sdpa_backward_bf16(float* dq, float* dk, float* dv, const float* dout, const float* out, const float* lse,
                              const float* q, const float* k, const float* v, int B, int Tq, int Tk, int C, int NH,
                              int ldq, int ldkv, float* ws);

#endif
