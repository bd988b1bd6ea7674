// The UNet's tensor-name schema (unet_schema.h): the diffusers names, shapes and order of every
// parameter of a configuration, walked once for the loader and the random-weight writer.
#include <stdio.h>
#include "unet_schema.h"

typedef struct {
    unet_schema_visit visit;
    void* ctx;
} walker;

static mlb_status emit(const walker* w, float** slot, const char* name, int ndim, int64_t a, int64_t b, int64_t c,
                       int64_t d, int as_linear) {
    unet_schema_tensor t = {name, ndim, {a, b, c, d}, as_linear, slot};
    return w->visit(w->ctx, &t);
}

static mlb_status emit_p(const walker* w, float** slot, const char* pre, const char* suf, int ndim, int64_t a, int64_t b,
                         int64_t c, int64_t d, int as_linear) {
    char name[256];
    snprintf(name, sizeof name, "%s.%s", pre, suf);
    return emit(w, slot, name, ndim, a, b, c, d, as_linear);
}

#define SLOT(p, field) ((p) ? &(p)->field : NULL)

static mlb_status walk_resnet(const walker* w, const mlb_unet_config* c, mlb_unet_resnet* r, const char* pre, int cin,
                              int cout) {
    int TE = c->time_embed_dim;
    if (r) {
        r->cin = cin;
        r->cout = cout;
    }
#define R(field, suffix, nd, a, b, x, y) MLB_TRY(emit_p(w, SLOT(r, field), pre, suffix, nd, a, b, x, y, 0))
    R(norm1_w, "norm1.weight", 1, cin, 0, 0, 0); R(norm1_b, "norm1.bias", 1, cin, 0, 0, 0);
    R(conv1_w, "conv1.weight", 4, cout, cin, 3, 3); R(conv1_b, "conv1.bias", 1, cout, 0, 0, 0);
    R(temb_w, "time_emb_proj.weight", 2, cout, TE, 0, 0); R(temb_b, "time_emb_proj.bias", 1, cout, 0, 0, 0);
    R(norm2_w, "norm2.weight", 1, cout, 0, 0, 0); R(norm2_b, "norm2.bias", 1, cout, 0, 0, 0);
    R(conv2_w, "conv2.weight", 4, cout, cout, 3, 3); R(conv2_b, "conv2.bias", 1, cout, 0, 0, 0);
    if (cin != cout) {
        R(skip_w, "conv_shortcut.weight", 4, cout, cin, 1, 1); R(skip_b, "conv_shortcut.bias", 1, cout, 0, 0, 0);
    } else if (r) {
        r->skip_w = r->skip_b = NULL;
    }
#undef R
    return MLB_OK;
}

static mlb_status walk_attn(const walker* w, const mlb_unet_config* c, mlb_unet_transformer* a, const char* pre, int C,
                            int heads) {
    int D = c->context_dim, lin = c->linear_projection;
    if (a) {
        a->C = C;
        a->heads = heads;
    }
#define R(field, suffix, nd, x, y, z, v, l) MLB_TRY(emit_p(w, SLOT(a, field), pre, suffix, nd, x, y, z, v, l))
    R(norm_w, "norm.weight", 1, C, 0, 0, 0, 0); R(norm_b, "norm.bias", 1, C, 0, 0, 0, 0);
    R(proj_in_w, "proj_in.weight", lin ? 2 : 4, C, C, 1, 1, 1); R(proj_in_b, "proj_in.bias", 1, C, 0, 0, 0, 1);
    R(proj_out_w, "proj_out.weight", lin ? 2 : 4, C, C, 1, 1, 1); R(proj_out_b, "proj_out.bias", 1, C, 0, 0, 0, 1);
#undef R
    char p[200];
    snprintf(p, sizeof p, "%s.transformer_blocks.0", pre);
#define T(field, suffix, nd, x, y) MLB_TRY(emit_p(w, SLOT(a, field), p, suffix, nd, x, y, 0, 0, 0))
    T(ln1_w, "norm1.weight", 1, C, 0); T(ln1_b, "norm1.bias", 1, C, 0);
    T(q1, "attn1.to_q.weight", 2, C, C); T(k1, "attn1.to_k.weight", 2, C, C); T(v1, "attn1.to_v.weight", 2, C, C);
    T(o1_w, "attn1.to_out.0.weight", 2, C, C); T(o1_b, "attn1.to_out.0.bias", 1, C, 0);
    T(ln2_w, "norm2.weight", 1, C, 0); T(ln2_b, "norm2.bias", 1, C, 0);
    T(q2, "attn2.to_q.weight", 2, C, C); T(k2, "attn2.to_k.weight", 2, C, D); T(v2, "attn2.to_v.weight", 2, C, D);
    T(o2_w, "attn2.to_out.0.weight", 2, C, C); T(o2_b, "attn2.to_out.0.bias", 1, C, 0);
    T(ln3_w, "norm3.weight", 1, C, 0); T(ln3_b, "norm3.bias", 1, C, 0);
    T(ff1_w, "ff.net.0.proj.weight", 2, 8 * C, C); T(ff1_b, "ff.net.0.proj.bias", 1, 8 * C, 0);
    T(ff2_w, "ff.net.2.weight", 2, C, 4 * C); T(ff2_b, "ff.net.2.bias", 1, C, 0);
#undef T
    return MLB_OK;
}

// Layer j of down or up block i (BLOCK "down_blocks" / "up_blocks"): its ResNet cin -> co, then,
// where level lvl has attention, its transformer.
static mlb_status walk_layer(const walker* w, const mlb_unet_config* c, mlb_unet_resnet* r, mlb_unet_transformer* a,
                             const char* block, int i, int j, int cin, int co, int lvl) {
    char d[160];
    snprintf(d, sizeof d, "%s.%d.resnets.%d", block, i, j);
    MLB_TRY(walk_resnet(w, c, r, d, cin, co));
    if (!c->attn[lvl]) return MLB_OK;
    snprintf(d, sizeof d, "%s.%d.attentions.%d", block, i, j);
    return walk_attn(w, c, a, d, co, c->heads[lvl]);
}

// A down- or upsampler's 3x3 conv C -> C.
static mlb_status walk_conv(const walker* w, mlb_unet_conv* cv, const char* pre, int C) {
    MLB_TRY(emit_p(w, SLOT(cv, w), pre, "weight", 4, C, C, 3, 3, 0));
    return emit_p(w, SLOT(cv, b), pre, "bias", 1, C, 0, 0, 0, 0);
}

mlb_status unet_schema_walk(const mlb_unet_config* c, mlb_unet* u, unet_schema_visit visit, void* ctx) {
    const walker W = {visit, ctx}, *w = &W;
    int n = c->n_levels, NL = c->layers_per_block, C0 = c->block_out[0], TE = c->time_embed_dim;
    char d[160];
    MLB_TRY(emit(w, SLOT(u, time1_w), "time_embedding.linear_1.weight", 2, TE, C0, 0, 0, 0));
    MLB_TRY(emit(w, SLOT(u, time1_b), "time_embedding.linear_1.bias", 1, TE, 0, 0, 0, 0));
    MLB_TRY(emit(w, SLOT(u, time2_w), "time_embedding.linear_2.weight", 2, TE, TE, 0, 0, 0));
    MLB_TRY(emit(w, SLOT(u, time2_b), "time_embedding.linear_2.bias", 1, TE, 0, 0, 0, 0));
    MLB_TRY(emit(w, SLOT(u, conv_in_w), "conv_in.weight", 4, C0, c->in_channels, 3, 3, 0));
    MLB_TRY(emit(w, SLOT(u, conv_in_b), "conv_in.bias", 1, C0, 0, 0, 0, 0));
    int skip_ch[1 + MLB_UNET_MAX_LEVELS * (MLB_UNET_MAX_LAYERS + 1)], ns = 0;
    skip_ch[ns++] = C0;
    int ch = C0;
    for (int i = 0; i < n; i++) {
        int co = c->block_out[i];
        for (int j = 0; j < NL; j++) {
            MLB_TRY(walk_layer(w, c, u ? &u->down_res[i][j] : NULL, u ? &u->down_attn[i][j] : NULL, "down_blocks", i, j,
                               ch, co, i));
            ch = co;
            skip_ch[ns++] = co;
        }
        if (i < n - 1) {
            snprintf(d, sizeof d, "down_blocks.%d.downsamplers.0.conv", i);
            MLB_TRY(walk_conv(w, u ? &u->down_conv[i] : NULL, d, co));
            skip_ch[ns++] = co;
        }
    }
    MLB_TRY(walk_resnet(w, c, u ? &u->mid_res[0] : NULL, "mid_block.resnets.0", ch, ch));
    MLB_TRY(walk_attn(w, c, u ? &u->mid_attn : NULL, "mid_block.attentions.0", ch, c->mid_heads));
    MLB_TRY(walk_resnet(w, c, u ? &u->mid_res[1] : NULL, "mid_block.resnets.1", ch, ch));
    for (int i = 0; i < n; i++) {
        int lvl = n - 1 - i, co = c->block_out[lvl];
        for (int j = 0; j <= NL; j++) {
            int cin = ch + skip_ch[--ns];
            MLB_TRY(walk_layer(w, c, u ? &u->up_res[i][j] : NULL, u ? &u->up_attn[i][j] : NULL, "up_blocks", i, j, cin,
                               co, lvl));
            ch = co;
        }
        if (i < n - 1) {
            snprintf(d, sizeof d, "up_blocks.%d.upsamplers.0.conv", i);
            MLB_TRY(walk_conv(w, u ? &u->up_conv[i] : NULL, d, co));
        }
    }
    MLB_TRY(emit(w, SLOT(u, norm_out_w), "conv_norm_out.weight", 1, ch, 0, 0, 0, 0));
    MLB_TRY(emit(w, SLOT(u, norm_out_b), "conv_norm_out.bias", 1, ch, 0, 0, 0, 0));
    MLB_TRY(emit(w, SLOT(u, conv_out_w), "conv_out.weight", 4, c->out_channels, ch, 3, 3, 0));
    MLB_TRY(emit(w, SLOT(u, conv_out_b), "conv_out.bias", 1, c->out_channels, 0, 0, 0, 0));
    return MLB_OK;
}
