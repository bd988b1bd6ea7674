// The appearance renderer's per-sample passes (raster_api.inc, "samples"): the covered pixels of
// rasterized views gathered into a flat list of surface samples, and their shaded colours
// composited back. The CPU side of the table ops of the same names (backend_ops.def); the maths
// is render/sample_math.h's, which the CUDA kernels include too. Dual-compiled (core/real.h).
#include <stdint.h>
#include "matlaber/raster.h"
#include "core/real.h"
#ifdef MLB_F64
#define MLB_SAMPLE_DOUBLE
#endif
#include "render/sample_math.h"

enum { ATTR_C = 6 };   // the interpolated attributes: position 3, normal 3

#ifndef MLB_F64
void mlb_covered_flags(int32_t* flags, const int32_t* tri, long n) {
    for (long i = 0; i < n; i++) flags[i] = tri[i] >= 0;
}
#endif

void FN(mlb_gather_samples)(real* pts, real* nrm, real* vdir, int32_t* where, const real* pix, const int32_t* tri,
                            const int32_t* index, int P, double ex, double ey, double ez) {
#pragma omp parallel for schedule(static) if (P > 65536)
    for (int i = 0; i < P; i++) {
        if (tri[i] < 0) continue;
        size_t j = (size_t)index[i];
        sample_geometry(pix + ATTR_C * (size_t)i, ex, ey, ez, pts + 3 * j, nrm + 3 * j, vdir + 3 * j);
        where[j] = i;
    }
}

void FN(mlb_composite_srgb)(real* color, const real* rgb, const int32_t* where, int m) {
#pragma omp parallel for schedule(static) if (m > 65536)
    for (int j = 0; j < m; j++) {
        real* c = color + 4 * (size_t)where[j];
        for (int ch = 0; ch < 3; ch++) c[ch] = srgb_clamped(rgb[3 * (size_t)j + ch]);
        c[3] = 1;
    }
}

void FN(mlb_composite_srgb_backward)(real* drgb, const real* dcolor, const real* rgb, const int32_t* where, int m) {
#pragma omp parallel for schedule(static) if (m > 65536)
    for (int j = 0; j < m; j++)
        for (int c = 0; c < 3; c++)
            drgb[3 * (size_t)j + c] += dcolor[4 * (size_t)where[j] + c] * srgb_clamped_d(rgb[3 * (size_t)j + c]);
}
