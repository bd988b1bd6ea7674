// The op table of the double pass (the dual sources compiled with MLB_F64, core/real.h): the same
// ops under the same names as backend.h's table, generated from the same list (backend_ops.def),
// with every float of their parameters a double. A model written against `const FN(mlb_backend)*`
// calls be->op(...) in both passes: the float pass on the table the run gives it, the double pass
// (the finite-difference references) on mlb_backend_cpu_f64(), over host memory.
//
// It is a type of its own because the contract is typed in float: a double table cannot be an
// mlb_backend. Only the CPU has one. Its ops are the CPU's _f64 functions (nn_api.inc, conv_ops.h,
// transformer_ops.h, raster_api.inc, mt_ops.h, shade.h) called as the CPU table calls their float
// twins; an op of the list without a double implementation fails with MLB_ERR_UNSUPPORTED naming
// itself (docs/ops.md "The double table").
#ifndef MATLABER_BACKEND_F64_H
#define MATLABER_BACKEND_F64_H
#include "matlaber/backend.h"

typedef struct mlb_backend_f64 mlb_backend_f64;
struct mlb_backend_f64 {
    mlb_device device;                // MLB_DEVICE_CPU
    mlb_gemm_precision precision;     // MLB_GEMM_FP32 (the GEMMs run in double)
    // backend_ops.def's fields with float spelled double and mlb_backend mlb_backend_f64 (no standard
    // header is included while `float` is a macro)
#define float double
#define mlb_backend mlb_backend_f64
#define MLB_OP(name, cuda_fn, params) mlb_status (*name) params;
#define MLB_GEMM_OP(name, cuda_fn, params, args) mlb_status (*name)(const mlb_backend* be, MLB_ARGS params);
#define MLB_DEVICE_OP(ret, name, params) ret (*name) params;
#include "matlaber/backend_ops.def"
#undef mlb_backend
#undef float
};

// The CPU's double table. Never NULL.
const mlb_backend_f64* mlb_backend_cpu_f64(void);
// backend.h's mlb_backend_for for the double pass: the CPU's double table for the CPU (any prec:
// the GEMMs run in double), NULL for another device (none has a double table).
const mlb_backend_f64* mlb_backend_for_f64(mlb_device d, mlb_gemm_precision prec);

#endif
