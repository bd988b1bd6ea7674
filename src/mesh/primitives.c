// Procedural meshes: a UV sphere (material swatches, tests).
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/mesh.h"

mlb_status mlb_mesh_uv_sphere(mlb_mesh* m, float radius, int segments, int rings) {
    memset(m, 0, sizeof *m);
    if (segments < 3 || rings < 2 || segments > 4096 || rings > 4096 || !(radius > 0))
        return mlb_fail(MLB_ERR_ARG, "uv sphere: %d segments, %d rings, radius %g (need >= 3, >= 2, > 0)", segments,
                        rings, (double)radius);
    // (rings + 1) x (segments + 1) vertices: the seam column is duplicated for the uv wrap
    int V = (rings + 1) * (segments + 1), F = 2 * segments * (rings - 1);
    m->pos = malloc(sizeof(float) * 3 * V);
    m->normal = malloc(sizeof(float) * 3 * V);
    m->uv = malloc(sizeof(float) * 2 * V);
    m->faces = malloc(sizeof(int32_t) * 3 * F);
    if (!m->pos || !m->normal || !m->uv || !m->faces) { mlb_mesh_free(m); return mlb_fail(MLB_ERR_NOMEM, "uv sphere: out of memory"); }
    for (int r = 0; r <= rings; r++) {
        double theta = M_PI * r / rings;   // from +y down
        for (int s = 0; s <= segments; s++) {
            double phi = 2 * M_PI * s / segments;
            int i = r * (segments + 1) + s;
            double n[3] = {sin(theta) * sin(phi), cos(theta), sin(theta) * cos(phi)};
            for (int c = 0; c < 3; c++) { m->normal[3 * i + c] = (float)n[c]; m->pos[3 * i + c] = (float)(radius * n[c]); }
            m->uv[2 * i] = (float)s / segments;
            m->uv[2 * i + 1] = 1.0f - (float)r / rings;
        }
    }
    int f = 0;
    for (int r = 0; r < rings; r++)
        for (int s = 0; s < segments; s++) {
            int a = r * (segments + 1) + s, b = a + 1, c = a + segments + 1, d = c + 1;
            // counter-clockwise seen from outside; the pole rows have one triangle per quad
            if (r > 0) { m->faces[3 * f] = a; m->faces[3 * f + 1] = c; m->faces[3 * f + 2] = b; f++; }
            if (r < rings - 1) { m->faces[3 * f] = b; m->faces[3 * f + 1] = c; m->faces[3 * f + 2] = d; f++; }
        }
    m->n_verts = V;
    m->n_faces = f;
    return MLB_OK;
}
