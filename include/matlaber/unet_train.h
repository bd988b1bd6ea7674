// Training the Stable Diffusion UNet (unet.h): a forward that keeps what the backward needs (the
// tape), and the backward, which accumulates the gradients of every parameter (the time-embedding
// MLP included; the sinusoid has none) and of the latent and the context. Written once against the
// op table (backend.h), so it runs on the CPU's tables and on CUDA's. docs/unet.md "Backward".
//
//   const mlb_backend* be = mlb_backend_cpu();
//   mlb_unet_tape* tape;  MLB_TRY(mlb_unet_tape_create(be, u, N, H, W, Tc, &tape));
//   mlb_unet* g;          MLB_TRY(mlb_unet_create(&u->cfg, be->device, &g));   // same carve as u
//   be->zero(g->params, g->n_params);
//   MLB_TRY(mlb_unet_forward_train(be, u, tape, out, x, t, ctx, N, H, W, Tc));
//   ... dout = dL/dout ...
//   MLB_TRY(mlb_unet_backward(be, u, tape, dout, g, NULL, NULL));   // g->params += dL/dparams
//
// The tape holds (one be->alloc, on be's device) the inputs x and ctx (copied), each block's output,
// the up path's concatenations, per ResNet its conv1 + time output and the GroupNorm statistics, per
// Transformer2D the residual stream after proj_in, attention 1, attention 2 and the feed-forward,
// q/k/v, the attention outputs and log-sum-exps, the GEGLU input and the norm statistics, and the
// backward's scratch (gradient maps and the skip gradients). What is cheap is recomputed in the
// backward instead of kept: the norm + SiLU outputs, the LayerNorm outputs, GEGLU's output, the
// upsampled maps. mlb_unet_tape_floats gives the size.
#ifndef MATLABER_UNET_TRAIN_H
#define MATLABER_UNET_TRAIN_H
#include <stddef.h>
#include "matlaber/backend.h"
#include "matlaber/unet.h"

typedef struct mlb_unet_tape mlb_unet_tape;

// Floats a tape for (N, H, W, Tc) of configuration c holds (tape + backward scratch); 0 for a bad shape.
size_t mlb_unet_tape_floats(const mlb_unet_config* c, int N, int H, int W, int Tc);
// A tape on be's device for batches up to N of H x W latents and Tc context tokens (and any call
// needing no more floats). MLB_ERR_ARG for a bad shape, MLB_ERR_NOMEM.
mlb_status mlb_unet_tape_create(const mlb_backend* be, const mlb_unet* u, int N, int H, int W, int Tc,
                                mlb_unet_tape** out);
void mlb_unet_tape_free(mlb_unet_tape* tape);   // NULL is fine

// mlb_unet_forward's arithmetic (the same `out` bits on the same table), keeping the tape. x, ctx
// and out on be's device; t [N] on the host. MLB_ERR_ARG when the shape needs more than the tape
// holds, or for what mlb_unet_forward refuses (u on another device, bf16-stored weights).
mlb_status mlb_unet_forward_train(const mlb_backend* be, const mlb_unet* u, mlb_unet_tape* tape, float* out,
                                  const float* x, const float* t, const float* ctx, int N, int H, int W, int Tc);
// Given dout = dL/dout [N, out_channels, H, W] of the last forward_train on this tape:
//   grads->params += dL/dparams (grads: mlb_unet_create(&u->cfg, be->device, ...), so its params
//   line up with u->params element for element; zero it with be->zero before a step),
//   dx [N, in_channels, H, W] += dL/dx and dctx [N, Tc, context_dim] += dL/dctx (either may be NULL).
// The tape's scratch is overwritten (the activations are not: backward may run again).
// The same bits on any thread count on the CPU tables.
mlb_status mlb_unet_backward(const mlb_backend* be, const mlb_unet* u, const mlb_unet_tape* tape, const float* dout,
                             mlb_unet* grads, float* dx, float* dctx);

#endif
