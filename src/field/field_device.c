// A field on a device (field.h, "on a device"): the same hash grid → MLP → frozen decoder as
// field.c, written against an op table (backend.h) over the whole batch, with its parameters,
// gradients, Adam moments and forward cache on the table's device. The points and outputs are on
// that device (mlb_field_forward_on_device) or cross as host arrays (field_forward through
// field_device_forward: the same path with an upload and a download); the grid-box mapping of the
// points and the output ranges are table ops with the CPU path's own arithmetic.
#include <stdlib.h>
#include <string.h>
#include "matlaber/brdf.h"
#include "matlaber/field.h"
#include "field/field_internal.h"

enum { K_DIM = 7, NET_MLP = 0, NET_DEC = 1 };

struct mlb_field_device {
    const mlb_backend* be;
    float *params, *grads, *m, *v;   // [n_params] on the device: the table, then the MLP
    float* dec_params;               // the frozen decoder (latent mode)
    mlb_mlp net[2];                  // the MLP and the decoder over device weights (host metadata)
    mlb_mlp grad_mlp;                // the MLP's layout over grads: weight/bias gradient pointers
    int capacity;                    // points the buffers below hold
    float *x, *feat, *dfeat, *dx;    // [n,3], [n,L], [n,L], [n,3]
    float* pre[2][MLB_MLP_MAX_LAYERS];    // per network and layer: [n, dims[l+1]] before ...
    float* post[2][MLB_MLP_MAX_LAYERS];   // ... and after the activation
    float *ds, *dz, *dpre, *dbuf[2];      // backward scratch: [n,7], [n,out], [n,W] × 3
    float* host;                          // staging [n,7]
    int width;                            // W: the widest layer of either network
    int host_behind;                      // the host's params/grads/moments are stale
    mlb_status pending;                   // an error of zero_grad, returned by the next op
};

static mlb_activation layer_act(const mlb_mlp* m, int l) { return l == m->n_layers - 1 ? m->out_act : m->hidden_act; }
static int latent(const mlb_field* f) { return f->cfg.kind == MLB_FIELD_MATERIAL && f->cfg.mode == MLB_MATERIAL_LATENT; }
static int net_count(const mlb_field* net) { return latent(net) ? 2 : 1; }
// Coarse to fine: levels >= active_levels give zero features. The table's hash-grid ops get the
// encoding cut to the active levels (field_active_enc: the stride stays L·F), so the inactive
// columns are never written: they are zeroed first, and the backward leaves their table entries alone.

static void release_batch(struct mlb_field_device* d) {
    const mlb_backend* be = d->be;
    float** all[] = {&d->x, &d->feat, &d->dfeat, &d->dx, &d->ds, &d->dz, &d->dpre, &d->dbuf[0], &d->dbuf[1]};
    for (size_t i = 0; i < sizeof all / sizeof all[0]; i++) { be->release(*all[i]); *all[i] = NULL; }
    for (int k = 0; k < 2; k++)
        for (int l = 0; l < MLB_MLP_MAX_LAYERS; l++) {
            be->release(d->pre[k][l]); be->release(d->post[k][l]);
            d->pre[k][l] = d->post[k][l] = NULL;
        }
    free(d->host);
    d->host = NULL;
    d->capacity = 0;
}

void field_device_free(struct mlb_field_device* d) {
    if (!d) return;
    release_batch(d);
    float* all[] = {d->params, d->grads, d->m, d->v, d->dec_params};
    for (size_t i = 0; i < sizeof all / sizeof all[0]; i++) d->be->release(all[i]);
    free(d);
}

// Buffers for n points (grown, never shrunk).
static mlb_status reserve(mlb_field* net, int n) {
    struct mlb_field_device* d = net->dev;
    if (n <= d->capacity) return MLB_OK;
    release_batch(d);
    const mlb_backend* be = d->be;
    size_t N = (size_t)n, L = (size_t)net->enc.out_dim, W = (size_t)d->width;
    mlb_status s = MLB_OK;
    if (!s) s = be->alloc(&d->x, 3 * N);
    if (!s) s = be->alloc(&d->feat, L * N);
    if (!s) s = be->alloc(&d->dfeat, L * N);
    if (!s) s = be->alloc(&d->dx, 3 * N);
    if (!s) s = be->alloc(&d->ds, K_DIM * N);
    if (!s) s = be->alloc(&d->dz, K_DIM * N);
    if (!s) s = be->alloc(&d->dpre, W * N);
    for (int i = 0; i < 2 && !s; i++) s = be->alloc(&d->dbuf[i], W * N);
    for (int k = 0; k < net_count(net) && !s; k++)
        for (int l = 0; l < d->net[k].n_layers && !s; l++) {
            s = be->alloc(&d->pre[k][l], (size_t)d->net[k].dims[l + 1] * N);
            if (!s) s = be->alloc(&d->post[k][l], (size_t)d->net[k].dims[l + 1] * N);
        }
    if (!s && !(d->host = malloc(sizeof(float) * K_DIM * N))) s = mlb_fail(MLB_ERR_NOMEM, "out of memory");
    if (s) { release_batch(d); return mlb_fail_context(s, "field on the %s: %d points", mlb_device_name(be->device), n); }
    d->capacity = n;
    return MLB_OK;
}

// Network k over n rows of `in`; returns its output (the last layer's post).
static mlb_status mlp_forward_on(struct mlb_field_device* d, int k, const float* in, int n, const float** out) {
    const mlb_backend* be = d->be;
    const mlb_mlp* m = &d->net[k];
    const float* x = in;
    for (int l = 0; l < m->n_layers; l++) {
        MLB_TRY(be->linear(be, d->pre[k][l], x, m->weight[l], m->bias[l], n, m->dims[l], m->dims[l + 1]));
        MLB_TRY(be->activation(d->post[k][l], d->pre[k][l], (size_t)n * m->dims[l + 1], layer_act(m, l)));
        x = d->post[k][l];
    }
    *out = x;
    return MLB_OK;
}

// din [n, dims[0]] = ∂(Σ dout·out)/∂in through network k's cached forward (overwritten); the
// weight gradients (+=) into `grads` when given (a layout of the network over the gradient array).
static mlb_status mlp_backward_on(struct mlb_field_device* d, int k, const mlb_mlp* grads, const float* in,
                                  const float* dout, float* din, int n) {
    const mlb_backend* be = d->be;
    const mlb_mlp* m = &d->net[k];
    const float* dpost = dout;
    for (int l = m->n_layers - 1; l >= 0; l--) {
        size_t C = (size_t)m->dims[l], OC = (size_t)m->dims[l + 1];
        MLB_TRY(be->zero(d->dpre, n * OC));
        MLB_TRY(be->activation_backward(d->dpre, dpost, d->pre[k][l], n * OC, layer_act(m, l)));
        float* dx = l ? d->dbuf[l & 1] : din;
        MLB_TRY(be->zero(dx, n * C));
        MLB_TRY(be->linear_backward(be, dx, grads ? grads->weight[l] : NULL, grads ? grads->bias[l] : NULL, d->dpre,
                                    l ? d->post[k][l - 1] : in, m->weight[l], n, (int)C, (int)OC));
        dpost = dx;
    }
    return MLB_OK;
}

// The forward over d->x (the points mapped to [0,1]^3): *out the MLP's output, *s the network's
// last (the decoder's in latent mode), both on the device.
static mlb_status forward_mapped(mlb_field* net, int n, const float** out, const float** s) {
    struct mlb_field_device* d = net->dev;
    const mlb_backend* be = d->be;
    const mlb_hashgrid enc = field_active_enc(net);
    if (enc.cfg.n_levels < net->enc.cfg.n_levels) MLB_TRY(be->zero(d->feat, (size_t)net->enc.out_dim * n));
    MLB_TRY(be->hashgrid(&enc, d->params, d->feat, d->x, n));
    MLB_TRY(mlp_forward_on(d, NET_MLP, d->feat, n, out));
    *s = *out;
    if (latent(net)) MLB_TRY(mlp_forward_on(d, NET_DEC, *out, n, s));
    return MLB_OK;
}

// The output ranges of the material channels as affine_columns' columns: k = lo + (hi - lo) s
static void range_columns(double* scale, double* shift) {
    for (int c = 0; c < K_DIM; c++) {
        scale[c] = mlb_brdf_range_hi[c] - mlb_brdf_range_lo[c];
        shift[c] = mlb_brdf_range_lo[c];
    }
}
static int out_dim(const mlb_field* net) { return net->cfg.kind == MLB_FIELD_GEOMETRY ? 4 : K_DIM; }

// pos [n,3] (on the device; may be d->x) → y [n, out_dim] on the device; *latent the MLP's output
// (the latent code in latent mode). The grid box → [0,1]^3 in float, and the outputs to their
// ranges in double: the host path's arithmetic (field.c).
static mlb_status forward_on(mlb_field* net, float* y, const float* pos, int n, const float** latent) {
    struct mlb_field_device* d = net->dev;
    const mlb_backend* be = d->be;
    if (d->pending) { mlb_status s = d->pending; d->pending = MLB_OK; return s; }
    MLB_TRY(reserve(net, n));
    net->n = 0;
    const double inv = (float)(1.0 / net->cfg.scale), inv3[3] = {inv, inv, inv}, half[3] = {0.5, 0.5, 0.5};
    MLB_TRY(be->affine_columns(d->x, pos, (size_t)n, 3, inv3, half, 1));
    const float *out, *s;
    MLB_TRY(forward_mapped(net, n, &out, &s));
    if (net->cfg.kind == MLB_FIELD_GEOMETRY) {
        MLB_TRY(be->copy(y, out, 4 * (size_t)n));
    } else {
        double scale[K_DIM], shift[K_DIM];
        range_columns(scale, shift);
        MLB_TRY(be->affine_columns(y, s, (size_t)n, K_DIM, scale, shift, 0));
    }
    if (latent) *latent = out;
    net->n = n;
    return MLB_OK;
}

mlb_status mlb_field_forward_on_device(mlb_field* net, float* y, const float* pos, int n) {
    if (!net->dev) return mlb_fail(MLB_ERR_ARG, "field forward on the device: the field is on the host");
    if (n < 0) return mlb_fail(MLB_ERR_ARG, "field forward on the device: %d points", n);
    return forward_on(net, y, pos, n, NULL);
}

// The host's arrays through the device path: the points go up (mapped in place), y comes down
// from the backward's input buffer (free until the backward), and z from the MLP's output.
mlb_status field_device_forward(mlb_field* net, float* y, float* z, const float* pos, int n) {
    struct mlb_field_device* d = net->dev;
    const mlb_backend* be = d->be;
    if (d->pending) { mlb_status s = d->pending; d->pending = MLB_OK; return s; }
    MLB_TRY(reserve(net, n));
    net->n = 0;
    MLB_TRY(be->upload(d->x, pos, 3 * (size_t)n));
    const float* out;
    MLB_TRY(forward_on(net, d->ds, d->x, n, &out));
    if (y) MLB_TRY(be->download(y, d->ds, (size_t)out_dim(net) * n));
    if (z && latent(net)) MLB_TRY(be->download(z, out, MLB_LATENT_DIM * (size_t)n));
    return MLB_OK;
}

// The backward from dy [n, out_dim] on the device (may be d->ds): the gradient at the network's
// last outputs ds = dy (geometry) or dy·(hi − lo) in float (material: the sigmoid outputs, the
// decoder's or the MLP's own); dx [n,3] on the device (in [0,1]^3 units) when with_dx.
static mlb_status backward_on(mlb_field* net, const float* dy, const float* dz_host, int with_dx) {
    struct mlb_field_device* d = net->dev;
    const mlb_backend* be = d->be;
    if (d->pending) { mlb_status s = d->pending; d->pending = MLB_OK; return s; }
    int n = net->n;
    size_t N = (size_t)n;
    if (net->cfg.kind == MLB_FIELD_GEOMETRY) {
        if (dy != d->ds) MLB_TRY(be->copy(d->ds, dy, 4 * N));
    } else {
        double scale[K_DIM];
        for (int c = 0; c < K_DIM; c++) scale[c] = (float)(mlb_brdf_range_hi[c] - mlb_brdf_range_lo[c]);
        if (dy) MLB_TRY(be->affine_columns(d->ds, dy, N, K_DIM, scale, NULL, 1));
        else MLB_TRY(be->zero(d->ds, K_DIM * N));
    }
    const float* dout = d->ds;
    if (latent(net)) {   // dz through the frozen decoder
        const mlb_mlp* mlp = &d->net[NET_MLP];
        MLB_TRY(mlp_backward_on(d, NET_DEC, NULL, d->post[NET_MLP][mlp->n_layers - 1], d->ds, d->dz, n));
        if (dz_host) {   // the codes' own term, through ds (read above, free now)
            MLB_TRY(be->upload(d->ds, dz_host, MLB_LATENT_DIM * N));
            MLB_TRY(be->add(d->dz, d->ds, MLB_LATENT_DIM * N));
        }
        dout = d->dz;
    }
    MLB_TRY(mlp_backward_on(d, NET_MLP, &d->grad_mlp, d->feat, dout, d->dfeat, n));
    if (with_dx) MLB_TRY(be->zero(d->dx, 3 * N));
    const mlb_hashgrid enc = field_active_enc(net);
    MLB_TRY(be->hashgrid_backward(&enc, d->params, d->grads, with_dx ? d->dx : NULL, d->dfeat, d->x, n));
    d->host_behind = 1;
    return MLB_OK;
}

mlb_status mlb_field_backward_on_device(mlb_field* net, const float* dy) {
    if (!net->dev) return mlb_fail(MLB_ERR_ARG, "field backward on the device: the field is on the host");
    return backward_on(net, dy, NULL, 0);
}

mlb_status field_device_backward(mlb_field* net, const float* dy, const float* dz, float* dpos) {
    struct mlb_field_device* d = net->dev;
    const mlb_backend* be = d->be;
    size_t N = (size_t)net->n;
    if (dy) MLB_TRY(be->upload(d->ds, dy, (size_t)out_dim(net) * N));
    MLB_TRY(backward_on(net, dy ? d->ds : NULL, dz, dpos != NULL));
    if (dpos) {
        MLB_TRY(be->download(d->host, d->dx, 3 * N));
        float inv = (float)(1.0 / net->cfg.scale);
        for (size_t i = 0; i < 3 * N; i++) dpos[i] += d->host[i] * inv;
    }
    return MLB_OK;
}

void field_device_zero_grad(mlb_field* net) {
    struct mlb_field_device* d = net->dev;
    mlb_status s = d->be->zero(d->grads, net->n_params);
    if (s && !d->pending) d->pending = s;
    d->host_behind = 1;
}

mlb_status field_device_update(mlb_field* net, const mlb_adam_config* adam) {
    struct mlb_field_device* d = net->dev;
    if (d->pending) { mlb_status s = d->pending; d->pending = MLB_OK; return s; }
    net->step++;
    d->host_behind = 1;
    return d->be->adam(d->params, d->grads, d->m, d->v, net->n_params, adam, net->step);
}

int field_device_host_behind(const mlb_field* net) { return net->dev && net->dev->host_behind; }

const mlb_backend* mlb_field_backend(const mlb_field* net) { return net->dev ? net->dev->be : NULL; }

mlb_status mlb_field_sync_host(mlb_field* net) {
    struct mlb_field_device* d = net->dev;
    if (!d || !d->host_behind) return MLB_OK;
    const mlb_backend* be = d->be;
    float* host[] = {net->params, net->grads, net->adam_m, net->adam_v};
    float* dev[] = {d->params, d->grads, d->m, d->v};
    for (int i = 0; i < 4; i++) MLB_TRY(be->download(host[i], dev[i], net->n_params));
    d->host_behind = 0;
    return MLB_OK;
}

mlb_status mlb_field_grads_get(mlb_field* net, float* out) {
    struct mlb_field_device* d = net->dev;
    if (!d) {
        if (out != net->grads) memcpy(out, net->grads, sizeof(float) * net->n_params);
        return MLB_OK;
    }
    if (d->pending) { mlb_status s = d->pending; d->pending = MLB_OK; return s; }
    return d->be->download(out, d->grads, net->n_params);
}

mlb_status mlb_field_grads_set(mlb_field* net, const float* in) {
    struct mlb_field_device* d = net->dev;
    if (!d) {
        if (in != net->grads) memcpy(net->grads, in, sizeof(float) * net->n_params);
        return MLB_OK;
    }
    d->host_behind = 1;   // (the host's grads may be `in` itself: the other arrays are behind anyway)
    return d->be->upload(d->grads, in, net->n_params);
}

mlb_status mlb_field_leave_device(mlb_field* net) {
    if (!net->dev) return MLB_OK;
    MLB_TRY(mlb_field_sync_host(net));
    field_device_free(net->dev);
    net->dev = NULL;
    net->n = 0;
    return MLB_OK;
}

mlb_status mlb_field_use_device(mlb_field* net, const mlb_backend* be) {
    if (!net->params || !be) return mlb_fail(MLB_ERR_ARG, "field to a device: no field or no device");
    MLB_TRY(mlb_field_leave_device(net));
    struct mlb_field_device* d = calloc(1, sizeof *d);
    if (!d) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    d->be = be;
    size_t np = net->n_params;
    size_t nd = latent(net) ? mlp_param_count(net->dec.n_layers, net->dec.dims, 1) : 0;
    mlb_status s = be->alloc(&d->params, np);
    if (!s) s = be->alloc(&d->grads, np);
    if (!s) s = be->alloc(&d->m, np);
    if (!s) s = be->alloc(&d->v, np);
    if (!s && nd) s = be->alloc(&d->dec_params, nd);
    if (!s) s = be->upload(d->params, net->params, np);
    if (!s) s = be->upload(d->grads, net->grads, np);
    if (!s) s = be->upload(d->m, net->adam_m, np);
    if (!s) s = be->upload(d->v, net->adam_v, np);
    if (!s && nd) s = be->upload(d->dec_params, net->dec_params, nd);
    // the networks' layouts over the device arrays (mlp_init only carves pointers)
    const mlb_mlp* m = &net->mlp;
    if (!s) s = mlp_init(&d->net[NET_MLP], m->n_layers, m->dims, m->has_bias, m->hidden_act, m->out_act, d->params + net->n_enc);
    if (!s) s = mlp_init(&d->grad_mlp, m->n_layers, m->dims, m->has_bias, m->hidden_act, m->out_act, d->grads + net->n_enc);
    if (!s && nd) s = mlp_init(&d->net[NET_DEC], net->dec.n_layers, net->dec.dims, 1, net->dec.hidden_act, net->dec.out_act,
                               d->dec_params);
    for (int k = 0; k < net_count(net); k++)
        for (int l = 0; l <= d->net[k].n_layers; l++)
            if (d->net[k].dims[l] > d->width) d->width = d->net[k].dims[l];
    if (s) {
        field_device_free(d);
        return mlb_fail_context(s, "moving the field to the %s", mlb_device_name(be->device));
    }
    net->dev = d;
    net->n = 0;   // a host forward's cache is not the device's
    return MLB_OK;
}

// ---- the double field (field.c's _f64 build) ----
// The double pass (the finite-difference references) has only the CPU's double table, so a double
// field never goes to a device: its dev stays NULL and these, its twin's entry points, are never
// reached from field.c. They are here, in one place, so that field.c and the models over a field
// are written once for both precisions instead of holding float-only branches.
static mlb_status no_device_f64(const char* what) {
    return mlb_fail(MLB_ERR_UNSUPPORTED, "field %s: a double field has no device (the double pass runs on the host)", what);
}
void field_device_free_f64(struct mlb_field_device* d) { field_device_free(d); }
mlb_status field_device_forward_f64(mlb_field_f64* f, double* y, double* z, const double* pos, int n) {
    return no_device_f64("forward");
}
mlb_status field_device_backward_f64(mlb_field_f64* f, const double* dy, const double* dz, double* dpos) {
    return no_device_f64("backward");
}
void field_device_zero_grad_f64(mlb_field_f64* f) {}
mlb_status field_device_update_f64(mlb_field_f64* f, const mlb_adam_config* adam) { return no_device_f64("update"); }
int field_device_host_behind_f64(const mlb_field_f64* f) { return 0; }
const mlb_backend_f64* mlb_field_backend_f64(const mlb_field_f64* f) { return NULL; }
mlb_status mlb_field_forward_on_device_f64(mlb_field_f64* f, double* y, const double* pos, int n) {
    return no_device_f64("forward on the device");
}
mlb_status mlb_field_backward_on_device_f64(mlb_field_f64* f, const double* dy) {
    return no_device_f64("backward on the device");
}
