// Between material_net.c (the network, dual-compiled) and material_net_device.c (its device twin,
// float only): the float net's operations dispatch to the twin when net->dev is set.
#ifndef MATLABER_MATERIAL_NET_INTERNAL_H
#define MATLABER_MATERIAL_NET_INTERNAL_H
#include "matlaber/material_net.h"

// k [n,7] = lo + (hi − lo)·s for sigmoid outputs s [n,7]: the decoder's output ranges (brdf_ae.h)
void material_map_to_ranges(float* k, const float* s, int n);
void material_map_to_ranges_f64(double* k, const double* s, int n);

void material_device_free(struct mlb_material_device* d);
mlb_status material_device_forward(mlb_material_net* net, float* k, float* z, const float* pos, int n);
mlb_status material_device_backward(mlb_material_net* net, const float* dk, float* dpos);
void material_device_zero_grad(mlb_material_net* net);   // an error is kept for the next op to return
mlb_status material_device_update(mlb_material_net* net, const mlb_adam_config* adam);
int material_device_host_behind(const mlb_material_net* net);   // 1: the host's params are stale

#endif
