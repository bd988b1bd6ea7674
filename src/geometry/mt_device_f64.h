// Marching tets through the CPU's double table (backend_f64.h): the double pass of
// src/geometry/mt_device.c, dmtet.h's mlb_mt_device_* with double buffers, for the double geometry
// fit (the finite-difference references). The handle is dmtet.h's mlb_mt_device; one these
// functions made is used and freed by these only. Library-internal, beside its float twins' public
// declarations in dmtet.h.
#ifndef MATLABER_GEOMETRY_MT_DEVICE_F64_H
#define MATLABER_GEOMETRY_MT_DEVICE_F64_H
#include "matlaber/backend_f64.h"
#include "matlaber/dmtet.h"

mlb_status mlb_mt_device_forward_f64(mlb_mt_device** d, const mlb_backend_f64* be, mlb_mt_surface_f64* out,
                                     const mlb_tetgrid* g, const double* pos, const double* sdf, mlb_mt_place where);
mlb_status mlb_mt_device_backward_f64(mlb_mt_device* d, double* dpos, double* dsdf, const double* dverts,
                                      mlb_mt_place where);
mlb_status mlb_mt_device_surface_f64(const mlb_mt_device* d, const double** verts, const int32_t** faces);
mlb_status mlb_mt_device_surface_host_f64(const mlb_mt_device* d, mlb_mt_surface_f64* out);
void mlb_mt_device_free_f64(mlb_mt_device* d);

#endif
