// A multilayer perceptron over the linear and activation ops: forward, backward, and the
// forward-mode tangent (Jacobian-vector product) with its own backward, which the BRDF
// auto-encoder's smoothness loss needs (it penalises J_D(z) (z_a - z_b)).
// Dual-compiled (float / double _f64), see core/real.h.
#include <stdlib.h>
#include <string.h>
#include "matlaber/nn.h"
#include "matlaber/rng.h"
#include "core/real.h"

size_t FN(mlp_param_count)(int n_layers, const int* dims, int has_bias) {
    size_t n = 0;
    for (int l = 0; l < n_layers; l++) n += (size_t)dims[l + 1] * dims[l] + (has_bias ? dims[l + 1] : 0);
    return n;
}

mlb_status FN(mlp_init)(FN(mlb_mlp)* mlp, int n_layers, const int* dims, int has_bias,
                        mlb_activation hidden_act, mlb_activation out_act, real* params) {
    if (n_layers < 1 || n_layers > MLB_MLP_MAX_LAYERS)
        return mlb_fail(MLB_ERR_ARG, "mlp: %d layers, expected 1..%d", n_layers, MLB_MLP_MAX_LAYERS);
    memset(mlp, 0, sizeof *mlp);
    mlp->n_layers = n_layers;
    mlp->has_bias = has_bias;
    mlp->hidden_act = hidden_act;
    mlp->out_act = out_act;
    mlp->params = params;
    real* p = params;
    for (int l = 0; l <= n_layers; l++) {
        if (dims[l] < 1) return mlb_fail(MLB_ERR_ARG, "mlp: width %d of layer %d must be positive", dims[l], l);
        mlp->dims[l] = dims[l];
    }
    for (int l = 0; l < n_layers; l++) {
        mlp->weight[l] = p; p += (size_t)dims[l + 1] * dims[l];
        mlp->bias[l] = has_bias ? p : NULL; p += has_bias ? dims[l + 1] : 0;
    }
    return MLB_OK;
}

void FN(mlp_init_weights)(FN(mlb_mlp)* mlp, uint64_t seed, uint64_t stream) {
    uint64_t index = 0;
    for (int l = 0; l < mlp->n_layers; l++) {
        int in = mlp->dims[l], out = mlp->dims[l + 1];
        double limit = sqrt(6.0 / (in + out));
        for (size_t i = 0; i < (size_t)in * out; i++)
            mlp->weight[l][i] = (real)((2.0 * mlb_rng_uniform_f64(seed, stream, index++) - 1.0) * limit);
        if (mlp->bias[l]) memset(mlp->bias[l], 0, sizeof(real) * out);
    }
}

static int max_width(const FN(mlb_mlp)* mlp) {
    int m = 0;
    for (int l = 0; l <= mlp->n_layers; l++) if (mlp->dims[l] > m) m = mlp->dims[l];
    return m;
}

mlb_status FN(mlp_cache_alloc)(FN(mlb_mlp_cache)* c, const FN(mlb_mlp)* mlp, int B) {
    memset(c, 0, sizeof *c);
    size_t per_batch = 0;
    for (int l = 0; l < mlp->n_layers; l++) per_batch += 6 * (size_t)mlp->dims[l + 1];
    per_batch += 6 * (size_t)max_width(mlp);
    c->buffer = calloc(per_batch * (size_t)B, sizeof(real));
    if (!c->buffer) return mlb_fail(MLB_ERR_NOMEM, "mlp: cannot allocate activations for batch %d", B);
    c->B = 0;
    c->capacity = B;
    real* p = c->buffer;
    for (int l = 0; l < mlp->n_layers; l++) {
        size_t n = (size_t)B * mlp->dims[l + 1];
        c->pre[l] = p; p += n;
        c->post[l] = p; p += n;
        c->d1[l] = p; p += n;
        c->d2[l] = p; p += n;
        c->tpre[l] = p; p += n;
        c->tpost[l] = p; p += n;
    }
    for (int i = 0; i < 6; i++) { c->scratch[i] = p; p += (size_t)B * max_width(mlp); }
    return MLB_OK;
}

void FN(mlp_cache_free)(FN(mlb_mlp_cache)* c) {
    free(c->buffer);
    memset(c, 0, sizeof *c);
}

static mlb_activation layer_act(const FN(mlb_mlp)* mlp, int l) {
    return l == mlp->n_layers - 1 ? mlp->out_act : mlp->hidden_act;
}

const real* FN(mlp_forward)(const FN(mlb_mlp)* mlp, FN(mlb_mlp_cache)* c, const real* in, int B) {
    c->B = B;
    const real* x = in;
    for (int l = 0; l < mlp->n_layers; l++) {
        int C = mlp->dims[l], OC = mlp->dims[l + 1];
        FN(linear_forward)(c->pre[l], x, mlp->weight[l], mlp->bias[l], B, C, OC);
        FN(activation_forward_derivs)(c->post[l], c->d1[l], c->d2[l], c->pre[l], (size_t)B * OC, layer_act(mlp, l));
        x = c->post[l];
    }
    return x;
}

void FN(mlp_backward)(const FN(mlb_mlp)* mlp, FN(mlb_mlp_cache)* c, real* dparams, real* din,
                      const real* dout, const real* in, int B) {
    // dpost of the current layer arrives in `dpost`; dpre and the next dpost use the scratch buffers.
    const real* dpost = dout;
    real* bufs[2] = {c->scratch[0], c->scratch[1]};
    real* dpre = c->scratch[2];
    for (int l = mlp->n_layers - 1; l >= 0; l--) {
        int C = mlp->dims[l], OC = mlp->dims[l + 1];
        for (size_t i = 0; i < (size_t)B * OC; i++) dpre[i] = dpost[i] * c->d1[l][i];
        real* dweight = dparams ? dparams + (mlp->weight[l] - mlp->params) : NULL;
        real* dbias = dparams && mlp->bias[l] ? dparams + (mlp->bias[l] - mlp->params) : NULL;
        const real* x = l ? c->post[l - 1] : in;
        real* dx;
        if (l == 0) dx = din;   // may be NULL: no input gradient wanted
        else { dx = bufs[l & 1]; memset(dx, 0, sizeof(real) * (size_t)B * C); }
        FN(linear_backward)(dx, dweight, dbias, dpre, x, mlp->weight[l], B, C, OC);
        dpost = dx;
    }
}

const real* FN(mlp_jvp_forward)(const FN(mlb_mlp)* mlp, FN(mlb_mlp_cache)* c, const real* tin, int B) {
    // tpre = W t (no bias: the tangent of a constant is 0); tpost = f'(pre) * tpre
    const real* t = tin;
    for (int l = 0; l < mlp->n_layers; l++) {
        int C = mlp->dims[l], OC = mlp->dims[l + 1];
        FN(linear_forward)(c->tpre[l], t, mlp->weight[l], NULL, B, C, OC);
        size_t n = (size_t)B * OC;
        for (size_t i = 0; i < n; i++) c->tpost[l][i] = c->d1[l][i] * c->tpre[l][i];
        t = c->tpost[l];
    }
    return t;
}

void FN(mlp_jvp_backward)(const FN(mlb_mlp)* mlp, FN(mlb_mlp_cache)* c, real* dparams, real* din,
                          real* dtin, const real* dout, const real* dtout, const real* in,
                          const real* tin, int B) {
    // Adjoints per layer: a_post (dL/dpost), a_tpost (dL/dtpost). Through
    //   tpost = f'(pre) tpre : a_tpre = a_tpost f'(pre);  a_pre += a_tpost f''(pre) tpre
    //   post  = f(pre)       : a_pre += a_post f'(pre)
    //   tpre  = W t          : a_W += a_tpre^T t;  a_t = a_tpre W
    //   pre   = W x + b      : a_W += a_pre^T x;   a_b += sum a_pre;  a_x = a_pre W
    real* a_pre = c->scratch[0];
    real* a_tpre = c->scratch[1];
    real* out_x[2] = {c->scratch[2], c->scratch[4]};
    real* out_t[2] = {c->scratch[3], c->scratch[5]};
    const real* a_post = dout;
    const real* a_tpost = dtout;
    for (int l = mlp->n_layers - 1; l >= 0; l--) {
        int C = mlp->dims[l], OC = mlp->dims[l + 1];
        size_t n = (size_t)B * OC;
        for (size_t i = 0; i < n; i++) {
            real d1 = c->d1[l][i], at = a_tpost ? a_tpost[i] : 0;
            a_tpre[i] = at * d1;
            a_pre[i] = at * c->d2[l][i] * c->tpre[l][i] + (a_post ? a_post[i] * d1 : 0);
        }
        real* dweight = dparams + (mlp->weight[l] - mlp->params);
        real* dbias = mlp->bias[l] ? dparams + (mlp->bias[l] - mlp->params) : NULL;
        const real* x = l ? c->post[l - 1] : in;
        const real* t = l ? c->tpost[l - 1] : tin;
        real *dx, *dt;
        if (l == 0) { dx = din; dt = dtin; }
        else {
            dx = out_x[l & 1]; dt = out_t[l & 1];
            memset(dx, 0, sizeof(real) * (size_t)B * C);
            memset(dt, 0, sizeof(real) * (size_t)B * C);
        }
        FN(linear_backward)(dx, dweight, dbias, a_pre, x, mlp->weight[l], B, C, OC);
        FN(linear_backward)(dt, dweight, NULL, a_tpre, t, mlp->weight[l], B, C, OC);
        a_post = dx;
        a_tpost = dt;
    }
}
