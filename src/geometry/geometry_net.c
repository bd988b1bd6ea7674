// The geometry network: a field (src/field/field.c) whose 4 outputs are the SDF and a deformation
// (include/matlaber/geometry.h, docs/geometry_init.md). Dual-compiled (float / double _f64), see
// core/real.h.
#include <stdlib.h>
#include <string.h>
#include "matlaber/geometry.h"
#include "core/real.h"

mlb_status FN(geometry_net_init)(FN(mlb_geometry_net)* net, const mlb_geometry_config* cfg) {
    mlb_field_config c = *cfg;
    c.kind = MLB_FIELD_GEOMETRY;
    return FN(field_init)(net, &c, NULL);
}

void FN(geometry_net_free)(FN(mlb_geometry_net)* net) { FN(field_free)(net); }
void FN(geometry_net_zero_grad)(FN(mlb_geometry_net)* net) { FN(field_zero_grad)(net); }

mlb_status FN(geometry_net_forward)(FN(mlb_geometry_net)* net, real* sdf, real* deform, const real* pos, int n) {
    if (n < 1) return mlb_fail(MLB_ERR_ARG, "geometry network: %d points", n);
    real* y = malloc(sizeof(real) * 4 * (size_t)n);   // [n, 4]: sdf, deformation
    if (!y) return mlb_fail(MLB_ERR_NOMEM, "geometry network: out of memory (%d points)", n);
    mlb_status s = FN(field_forward)(net, y, NULL, pos, n);
    for (int i = 0; !s && i < n; i++) {
        if (sdf) sdf[i] = y[4 * (size_t)i];
        if (deform) for (int d = 0; d < 3; d++) deform[3 * (size_t)i + d] = y[4 * (size_t)i + 1 + d];
    }
    free(y);
    return s;
}

mlb_status FN(geometry_net_backward)(FN(mlb_geometry_net)* net, const real* dsdf, const real* ddeform) {
    int n = net->n;
    if (n < 1) return mlb_fail(MLB_ERR_ARG, "geometry network: backward without a forward");
    real* dy = malloc(sizeof(real) * 4 * (size_t)n);
    if (!dy) return mlb_fail(MLB_ERR_NOMEM, "geometry network: out of memory (%d points)", n);
    for (int i = 0; i < n; i++) {
        dy[4 * (size_t)i] = dsdf ? dsdf[i] : 0;
        for (int d = 0; d < 3; d++) dy[4 * (size_t)i + 1 + d] = ddeform ? ddeform[3 * (size_t)i + d] : 0;
    }
    mlb_status s = FN(field_backward)(net, dy, NULL);
    free(dy);
    return s;
}

mlb_status FN(geometry_net_update)(FN(mlb_geometry_net)* net, const mlb_adam_config* adam) {
    return FN(field_update)(net, adam);
}
