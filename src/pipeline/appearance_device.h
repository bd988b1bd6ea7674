// The appearance renderer's split-sum shading on the material network's device (appearance.c,
// float build): the samples' materials and geometry cross once per render, the lights' cube maps
// once per appearance state.
#ifndef MATLABER_APPEARANCE_DEVICE_H
#define MATLABER_APPEARANCE_DEVICE_H
#include <stdint.h>
#include "matlaber/backend.h"
#include "matlaber/envmap.h"

typedef struct appearance_device appearance_device;

// rgb [N,3] = shade(kd, ks [N,3], kr [N], nrm, vdir [N,3]) where view v's samples are
// [start[v], start[v+1]) lit by light[v] (already turned: its rotation is used). *dp is created on
// first use and keeps the device copies of the inputs for appearance_device_shade_backward and the
// uploaded lights, keyed by their address: a light at an address must not change while *dp lives.
mlb_status appearance_device_shade(appearance_device** dp, const mlb_backend* be, float* rgb, const float* kd,
                                   const float* ks, const float* kr, const float* nrm, const float* vdir,
                                   const int32_t* start, int n_views, const mlb_envlight* light,
                                   const mlb_envlight* const* light_source, mlb_fresnel fresnel);
// dkd, dks [N,3], dkr [N] = (overwritten) the gradients of Σ drgb·rgb of the last shade.
mlb_status appearance_device_shade_backward(appearance_device* d, float* dkd, float* dks, float* dkr, const float* drgb);
void appearance_device_free(appearance_device* d);

#endif
