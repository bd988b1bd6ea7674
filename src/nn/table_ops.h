// Scratch on an op table for the stages' dual sources (core/real.h; include after it): buffers of
// `real` on the table FN(mlb_backend) of the pass (the float pass's backend.h table, the double
// pass's backend_f64.h one), so the code that uses them calls be->op(...) in both passes. int32
// buffers are allocated as that many reals. Used by the appearance renderer and the geometry fit.
#ifndef MATLABER_TABLE_OPS_H
#define MATLABER_TABLE_OPS_H
#include <string.h>
#include "matlaber/backend_f64.h"

typedef struct { real* p; size_t cap; } FN(tbuf);   // cap in reals

static inline void FN(tbuf_free)(const FN(mlb_backend)* be, FN(tbuf)* b) {
    if (b->p) be->release(b->p);
    b->p = NULL;
    b->cap = 0;
}
// At least n reals (grown, never shrunk); NULL out of memory
static inline real* FN(tbuf_get)(const FN(mlb_backend)* be, FN(tbuf)* b, size_t n) {
    if (n < 1) n = 1;
    if (b->p && n <= b->cap) return b->p;
    FN(tbuf_free)(be, b);
    if (be->alloc(&b->p, n) != MLB_OK) b->p = NULL;
    b->cap = b->p ? n : 0;
    return b->p;
}

// n int32 values from the host into an int32 buffer of the table: their bits travel as reals, the
// last odd one (a double table's) in a real of its own, so nothing past src[n - 1] is read
static inline mlb_status FN(t_upload_i32)(const FN(mlb_backend)* be, int32_t* dst, const int32_t* src, size_t n) {
    const size_t per = sizeof(real) / sizeof(int32_t), whole = n / per, rest = n % per;
    MLB_TRY(be->upload((real*)dst, (const real*)src, whole));
    if (!rest) return MLB_OK;
    real last = 0;
    memcpy(&last, src + whole * per, rest * sizeof(int32_t));
    return be->upload((real*)(dst + whole * per), &last, 1);
}
// n int32 values of an int32 buffer of the table, brought to the host: the same way back, so
// nothing past dst[n - 1] is written
static inline mlb_status FN(t_download_i32)(const FN(mlb_backend)* be, int32_t* dst, const int32_t* src, size_t n) {
    const size_t per = sizeof(real) / sizeof(int32_t), whole = n / per, rest = n % per;
    if (whole) MLB_TRY(be->download((real*)dst, (const real*)src, whole));
    if (!rest) return MLB_OK;
    real got;   // the real that starts at the last odd value: its first bytes are the value's
    MLB_TRY(be->download(&got, (const real*)(src + whole * per), 1));
    memcpy(dst + whole * per, &got, rest * sizeof(int32_t));
    return MLB_OK;
}
// p [n] = 1: zeros mapped by 0 x + 1 (no upload)
static inline mlb_status FN(t_ones)(const FN(mlb_backend)* be, real* p, size_t n) {
    static const double zero = 0, one = 1;
    mlb_status s = be->zero(p, n);
    return s ? s : be->affine_columns(p, p, n, 1, &zero, &one, 0);
}
#endif
