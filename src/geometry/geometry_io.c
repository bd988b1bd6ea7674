// The geometry network's configuration defaults and files (save, load, surface extraction);
// the network itself is src/geometry/geometry_net.c.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/geometry.h"

mlb_geometry_config mlb_geometry_default(void) {
    mlb_geometry_config c;
    memset(&c, 0, sizeof c);
    c.kind = MLB_FIELD_GEOMETRY;
    c.enc = mlb_hashgrid_default();
    c.hidden = 32;
    c.n_hidden = 2;
    c.scale = 2.1f;
    c.seed = 1;
    return c;
}

mlb_adam_config mlb_geometry_adam(double lr) {
    mlb_adam_config a = {.lr = lr, .beta1 = 0.9, .beta2 = 0.99, .eps = 1e-15, .weight_decay = 0, .decoupled = 0};
    return a;
}

// ---- files: the field format (src/field/field_io.c) under the prefix "geometry" ---------------------

mlb_status mlb_geometry_save(const mlb_geometry_net* net, const char* path, const mlb_st_meta* extra, size_t n_extra) {
    return mlb_field_save(net, path, 0, extra, n_extra);
}

mlb_status mlb_geometry_load(mlb_geometry_net* net, const char* path) { return mlb_field_load(net, MLB_FIELD_GEOMETRY, path); }

// ---- extraction --------------------------------------------------------------------------------

mlb_status mlb_geometry_extract(const mlb_backend* be, mlb_geometry_net* net, const mlb_tetgrid* grid, mlb_mesh* out) {
    if (!be) be = mlb_backend_cpu();
    memset(out, 0, sizeof *out);
    size_t V = (size_t)grid->n_verts;
    float* sdf = malloc(sizeof(float) * V);
    float* deform = malloc(sizeof(float) * 3 * V);
    float* pos = malloc(sizeof(float) * 3 * V);
    mlb_status s = (sdf && deform && pos) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "out of memory (%zu grid vertices)", V);
    if (!s) s = geometry_net_forward(net, sdf, deform, grid->verts, grid->n_verts);
    mlb_mt_surface surf = {0};
    mlb_mt_device* mt = NULL;
    if (!s) {
        dmtet_deform_forward(pos, grid->verts, deform, grid->n_verts, (float)(2 * grid->cells));
        s = mlb_mt_device_forward(&mt, be, &surf, grid, pos, sdf, MLB_MT_HOST);
    }
    mlb_mt_device_free(mt);
    if (!s && surf.n_faces == 0) s = mlb_fail(MLB_ERR_ARG, "no surface: the SDF has the same sign at every grid vertex");
    if (!s) s = mt_surface_to_mesh(&surf, out);
    mt_surface_free(&surf);
    free(sdf);
    free(deform);
    free(pos);
    return s;
}

