// Shared by the UNet's forward (unet.c) and its training (unet_tape.c, unet_backward.c): the
// forward's scratch, the tape's layout, and the sizes both derive from one walk over the config.
#ifndef MATLABER_UNET_INTERNAL_H
#define MATLABER_UNET_INTERNAL_H
#include "matlaber/backend.h"
#include "matlaber/unet.h"
#include "matlaber/unet_train.h"

typedef struct {
    float *ta, *tb;                                   // feature-map scratch [N, <= cmax, H, W]
    float *tok, *ln, *q, *k, *v, *att, *tmp, *ff, *gg; // transformer scratch
    float *emb_silu;                                  // [N, TE]
    float *tvec;                                      // [N, cmax]
} unet_ws;

// Per ResNet: h1 = conv1(silu(gn1 x)) + temb(silu emb) [N, cout, HW] (gn2's input) and both norms'
// statistics [N, G].
typedef struct {
    float *h1, *m1, *r1, *m2, *r2;
} unet_res_tape;

// Per Transformer2D (T = H W tokens, NT = N T): the residual stream tok[0..3] [NT, C] after proj_in,
// self-attention, cross-attention and the feed-forward; the GroupNorm [N, G] and LayerNorm [NT]
// statistics; the attention operands and outputs with their log-sum-exps [N, heads, T]; GEGLU's
// input ff [NT, 8C].
typedef struct {
    float *m, *r;
    float *tok[4];
    float *lm[3], *lr[3];
    float *q1, *k1, *v1, *o1, *lse1;
    float *q2, *k2, *v2, *o2, *lse2;   // k2, v2 [N, Tc, C]
    float* ff;
} unet_attn_tape;

#define UNET_L MLB_UNET_MAX_LEVELS
#define UNET_J MLB_UNET_MAX_LAYERS
struct mlb_unet_tape {
    mlb_device device;
    float* arena;   // one be->alloc
    size_t cap;     // floats in arena
    mlb_unet_config cfg;
    int N, H, W, Tc, ready;   // the last forward_train's shape; ready once it succeeded
    // inputs (copies) and the time embedding: tproj [N, C0], e1 = time1(tproj) and emb [N, TE],
    // s1 = silu(e1), es = silu(emb)
    float *x, *ctx, *tproj, *e1, *s1, *emb, *es;
    // block outputs in forward order; up_cat: the concatenation [h | skip] each up ResNet reads
    float* conv_in;
    float *down_res[UNET_L][UNET_J], *down_attn[UNET_L][UNET_J], *down_conv[UNET_L];
    float *mid_res[2], *mid_attn;
    float *up_cat[UNET_L][UNET_J + 1], *up_res[UNET_L][UNET_J + 1], *up_attn[UNET_L][UNET_J + 1], *up_conv[UNET_L];
    unet_res_tape down_rt[UNET_L][UNET_J], mid_rt[2], up_rt[UNET_L][UNET_J + 1];
    unet_attn_tape down_at[UNET_L][UNET_J], mid_at, up_at[UNET_L][UNET_J + 1];
    float* hf;              // the last up block's output (norm_out's input), a slot above
    float *out_m, *out_r;   // norm_out statistics [N, G]
    // scratch: the forward's (ws) and the backward's: gradient maps g0..g2 and s0..s2 [fmax], the skip
    // gradients dskip [skip_total], the transformer's gradients, the time embedding's
    unet_ws ws;
    float *g[3], *s[3], *dskip;
    float *dtok, *dln, *datt, *dq, *dk, *dv, *dff, *dgg;
    float *demb_s, *demb, *ds1, *dtvec;
};

// Sizes of the forward's buffers for (N, H, W, Tc): fmax (a feature map, the widest concat),
// amax (a transformer's [NT, C]), kv (N Tc cmax), skip_total (the skip stack), cmax.
typedef struct {
    size_t fmax, amax, kv, skip_total;
    int cmax;
} unet_sizes;
void unet_sizes_of(const mlb_unet_config* c, int N, int H, int W, int Tc, unet_sizes* s);

// Carves the tape's pointers from base (NULL: count only); returns the floats used.
size_t unet_tape_carve(mlb_unet_tape* tp, const mlb_unet_config* c, int N, int H, int W, int Tc, float* base);

// The forward's blocks (unet.c). tape NULL: mlb_unet_forward's buffers; else the outputs the
// tape keeps. resnet: out [N, cout, H, W] = resnet(x), out must not overlap x. attn: xo = xi +
// transformer(xi, ctx); xo == xi runs in place.
mlb_status unet_resnet_fwd(const mlb_backend* be, const mlb_unet* u, const mlb_unet_resnet* r, float* out,
                           const float* x, int N, int H, int W, unet_ws* ws, unet_res_tape* rt);
mlb_status unet_attn_fwd(const mlb_backend* be, const mlb_unet* u, const mlb_unet_transformer* a, float* xo,
                         const float* xi, const float* ctx, int N, int H, int W, int Tc, unet_ws* ws,
                         unet_attn_tape* at);
// The sinusoid [N, C0] of timesteps t (host) into host memory.
void unet_time_proj(const mlb_unet_config* c, const float* t, int N, float* out);
// The shape checks mlb_unet_forward makes (and forward_train).
mlb_status unet_check(const mlb_backend* be, const mlb_unet* u, int N, int H, int W, int Tc);
// The walk from x to out, on ws and the given feature buffers (tape NULL: h, h2, the skip stack
// skips, emb, tproj; with a tape those come from it and these are ignored).
mlb_status unet_walk(const mlb_backend* be, const mlb_unet* u, float* out, const float* x, const float* t,
                     const float* ctx, int N, int H, int W, int Tc, mlb_unet_debug_fn debug, void* debug_user,
                     unet_ws* ws, float* h, float* h2, float* skips, float* emb, float* tproj, mlb_unet_tape* tp);

#endif
