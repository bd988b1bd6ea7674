// Taubin smoothing of a triangle mesh (include/matlaber/mesh.h): each round moves every vertex
// towards the mean of its neighbours by lambda, then away by mu (mu < -lambda < 0), so noise at the
// scale of a few edges fades while the shape, which a plain Laplacian would shrink, keeps its size.
// Neighbours are the other corners of the faces at a vertex (each edge of a closed surface counted
// from both its faces, so every neighbour weighs the same). Positions only; normals are the caller's.
#include <stdlib.h>
#include <string.h>
#include "matlaber/mesh.h"
#include "matlaber/mt_ops.h"

// out = pos + w (mean of the neighbours - pos), per vertex over the faces at it (off, vf).
static void umbrella_step(float* out, const float* pos, int n, const int32_t* faces, const int32_t* off, const int32_t* vf,
                          float w) {
#pragma omp parallel for schedule(static) if (n >= 4096)
    for (int v = 0; v < n; v++) {
        double m[3] = {0, 0, 0};
        int k = 0;
        for (int32_t e = off[v]; e < off[v + 1]; e++) {
            const int32_t* f = faces + 3 * (size_t)(vf[e] / 3);
            for (int c = 0; c < 3; c++)
                if (f[c] != v) {
                    for (int d = 0; d < 3; d++) m[d] += pos[3 * (size_t)f[c] + d];
                    k++;
                }
        }
        for (int d = 0; d < 3; d++) {
            float p = pos[3 * (size_t)v + d];
            out[3 * (size_t)v + d] = k ? (float)(p + w * (m[d] / k - p)) : p;
        }
    }
}

mlb_status mlb_mesh_smooth_taubin(mlb_mesh* m, int rounds, float lambda, float mu) {
    if (rounds < 0 || !(lambda > 0 && lambda < 1) || !(mu < -lambda && mu > -1))
        return mlb_fail(MLB_ERR_ARG, "Taubin smoothing: %d rounds, lambda %g, mu %g (0 < lambda < -mu < 1)", rounds, lambda, mu);
    if (rounds == 0 || m->n_verts == 0) return MLB_OK;
    int32_t* off = malloc(sizeof(int32_t) * ((size_t)m->n_verts + 1));
    int32_t* vf = malloc(sizeof(int32_t) * 3 * (size_t)(m->n_faces > 0 ? m->n_faces : 1));
    float* tmp = malloc(sizeof(float) * 3 * (size_t)m->n_verts);
    mlb_status s = off && vf && tmp ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "Taubin smoothing: out of memory (%d vertices)", m->n_verts);
    if (!s) s = mlb_vertex_faces(off, vf, m->faces, m->n_faces, m->n_verts);
    for (int r = 0; !s && r < rounds; r++) {
        umbrella_step(tmp, m->pos, m->n_verts, m->faces, off, vf, lambda);
        umbrella_step(m->pos, tmp, m->n_verts, m->faces, off, vf, mu);
    }
    free(off);
    free(vf);
    free(tmp);
    return s;
}
