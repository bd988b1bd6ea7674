// Between field.c (the field, dual-compiled) and field_device.c (its device twin, float only): a
// field's operations dispatch to the twin when f->dev is set (only ever for a float field).
#ifndef MATLABER_FIELD_INTERNAL_H
#define MATLABER_FIELD_INTERNAL_H
#include "matlaber/field.h"

// k [n,7] = lo + (hi − lo)·s for sigmoid outputs s [n,7]: the decoder's output ranges (brdf_ae.h)
void field_map_to_ranges(float* k, const float* s, int n);
void field_map_to_ranges_f64(double* k, const double* s, int n);

// The hash grid of the active levels only (coarse to fine: f->active_levels; the output stride
// stays L·F): what the forward encodes and the backward differentiates. A copy whose level count
// stops there, so that the masked levels cost nothing; with all levels, the encoding. Both the host
// path (field.c) and the device twin (field_device.c, its table's hash-grid ops) take it, so it is
// here rather than in either file.
static inline mlb_hashgrid field_active_enc(const mlb_field* f) {
    mlb_hashgrid g = f->enc;
    if (f->active_levels > 0 && f->active_levels < g.cfg.n_levels) g.cfg.n_levels = f->active_levels;
    return g;
}
static inline mlb_hashgrid_f64 field_active_enc_f64(const mlb_field_f64* f) {
    mlb_hashgrid_f64 g = f->enc;
    if (f->active_levels > 0 && f->active_levels < g.cfg.n_levels) g.cfg.n_levels = f->active_levels;
    return g;
}

// The device twin's entry points, named per precision (FN) so that field.c is written once. The
// double ones (field_device.c's end) are never reached: a double field's dev stays NULL.
void field_device_free(struct mlb_field_device* d);
mlb_status field_device_forward(mlb_field* f, float* y, float* z, const float* pos, int n);
mlb_status field_device_backward(mlb_field* f, const float* dy, const float* dz, float* dpos);
void field_device_zero_grad(mlb_field* f);   // an error is kept for the next op to return
mlb_status field_device_update(mlb_field* f, const mlb_adam_config* adam);
int field_device_host_behind(const mlb_field* f);   // 1: the host's params are stale
void field_device_free_f64(struct mlb_field_device* d);
mlb_status field_device_forward_f64(mlb_field_f64* f, double* y, double* z, const double* pos, int n);
mlb_status field_device_backward_f64(mlb_field_f64* f, const double* dy, const double* dz, double* dpos);
void field_device_zero_grad_f64(mlb_field_f64* f);
mlb_status field_device_update_f64(mlb_field_f64* f, const mlb_adam_config* adam);
int field_device_host_behind_f64(const mlb_field_f64* f);

#endif
