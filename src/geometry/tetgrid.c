// The DMTet tet grid (reference.md §3): a cube of `cells`^3 cells, each split into the 6 Kuhn
// tets, with shared vertices (conforming) and positive orientation.
#include <stdlib.h>
#include <string.h>
#include "matlaber/dmtet.h"

// Marching tetrahedra tables, reference.md §3.
const int mlb_mt_num_triangles[16] = {0, 1, 1, 2, 1, 2, 2, 1, 1, 2, 2, 1, 2, 1, 1, 0};
const int mlb_mt_triangle_table[16][6] = {
    {-1, -1, -1, -1, -1, -1}, {1, 0, 2, -1, -1, -1}, {4, 0, 3, -1, -1, -1}, {1, 4, 2, 1, 3, 4},
    {3, 1, 5, -1, -1, -1},    {2, 3, 0, 2, 5, 3},    {1, 4, 0, 1, 5, 4},    {4, 2, 5, -1, -1, -1},
    {4, 5, 2, -1, -1, -1},    {4, 1, 0, 4, 5, 1},    {3, 2, 0, 3, 5, 2},    {1, 3, 5, -1, -1, -1},
    {4, 1, 2, 4, 3, 1},       {3, 0, 4, -1, -1, -1}, {2, 0, 1, -1, -1, -1}, {-1, -1, -1, -1, -1, -1}};
const int mlb_mt_tet_edges[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};

// Cell corners v1..v8 as (i, j, k) offsets: v1=(i,j,k), v2=(i,j+1,k), v3=(i+1,j,k), v4=(i+1,j+1,k),
// v5..v8 the same at k+1; and the 6 Kuhn tets (1-based corner numbers) as listed in reference.md.
static const int corner_off[8][3] = {{0, 0, 0}, {0, 1, 0}, {1, 0, 0}, {1, 1, 0},
                                     {0, 0, 1}, {0, 1, 1}, {1, 0, 1}, {1, 1, 1}};
static const int kuhn[6][4] = {{1, 3, 8, 7}, {1, 8, 5, 7}, {1, 3, 4, 8}, {1, 4, 2, 8}, {1, 6, 5, 8}, {1, 2, 6, 8}};

static double orient(const int a[3], const int b[3], const int c[3], const int d[3]) {
    double u[3], v[3], w[3];
    for (int k = 0; k < 3; k++) { u[k] = b[k] - a[k]; v[k] = c[k] - a[k]; w[k] = d[k] - a[k]; }
    return u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) + u[2] * (v[0] * w[1] - v[1] * w[0]);
}

void mlb_tetgrid_free(mlb_tetgrid* g) {
    if (!g) return;
    free(g->verts);
    free(g->tets);
    free(g->edges);
    memset(g, 0, sizeof *g);
}

mlb_status mlb_tetgrid_create(mlb_tetgrid* g, int cells, float scale) {
    memset(g, 0, sizeof *g);
    if (cells < 1 || cells > 512) return mlb_fail(MLB_ERR_ARG, "tet grid: %d cells per axis, expected 1..512", cells);
    if (!(scale > 0)) return mlb_fail(MLB_ERR_ARG, "tet grid: scale %g must be positive", scale);
    const int n = cells + 1;
    g->cells = cells;
    g->scale = scale;
    g->n_verts = n * n * n;
    g->n_tets = 6 * cells * cells * cells;
    int64_t ne = 0;
    for (int code = 1; code < 8; code++)
        ne += (int64_t)(n - (code & 1)) * (n - ((code >> 1) & 1)) * (n - ((code >> 2) & 1));
    g->n_edges = (int)ne;
    g->verts = malloc(sizeof(float) * 3 * (size_t)g->n_verts);
    g->tets = malloc(sizeof(int32_t) * 4 * (size_t)g->n_tets);
    g->edges = malloc(sizeof(int32_t) * 2 * (size_t)g->n_edges);
    if (!g->verts || !g->tets || !g->edges) {
        mlb_tetgrid_free(g);
        return mlb_fail(MLB_ERR_NOMEM, "tet grid: out of memory for %d cells per axis", cells);
    }
    for (int k = 0; k < n; k++)
        for (int j = 0; j < n; j++)
            for (int i = 0; i < n; i++) {
                float* v = g->verts + 3 * ((size_t)i + (size_t)n * (j + (size_t)n * k));
                v[0] = ((float)i / cells - 0.5f) * scale;
                v[1] = ((float)j / cells - 0.5f) * scale;
                v[2] = ((float)k / cells - 0.5f) * scale;
            }
    // Orientation of each listed tet; a negative one gets its last two corners swapped.
    int order[6][4];
    for (int t = 0; t < 6; t++) {
        for (int c = 0; c < 4; c++) order[t][c] = kuhn[t][c] - 1;
        if (orient(corner_off[order[t][0]], corner_off[order[t][1]], corner_off[order[t][2]], corner_off[order[t][3]]) < 0) {
            int tmp = order[t][2];
            order[t][2] = order[t][3];
            order[t][3] = tmp;
        }
    }
#pragma omp parallel for schedule(static)
    for (int k = 0; k < cells; k++)
        for (int j = 0; j < cells; j++)
            for (int i = 0; i < cells; i++) {
                size_t cell = (size_t)i + (size_t)cells * (j + (size_t)cells * k);
                for (int t = 0; t < 6; t++)
                    for (int c = 0; c < 4; c++) {
                        const int* o = corner_off[order[t][c]];
                        g->tets[4 * (6 * cell + t) + c] = (i + o[0]) + n * ((j + o[1]) + n * (k + o[2]));
                    }
            }
    size_t e = 0;
    for (int k = 0; k < n; k++)
        for (int j = 0; j < n; j++)
            for (int i = 0; i < n; i++)
                for (int code = 1; code < 8; code++) {
                    int di = code & 1, dj = (code >> 1) & 1, dk = (code >> 2) & 1;
                    if (i + di >= n || j + dj >= n || k + dk >= n) continue;
                    g->edges[2 * e] = i + n * (j + n * k);
                    g->edges[2 * e + 1] = (i + di) + n * ((j + dj) + n * (k + dk));
                    e++;
                }
    return MLB_OK;
}

int64_t mlb_tetgrid_edge_id(const mlb_tetgrid* g, int32_t a, int32_t b) {
    if (a > b) { int32_t t = a; a = b; b = t; }
    if (a < 0 || b >= g->n_verts || a == b) return -1;
    const int n = g->cells + 1;
    int ai = a % n, aj = (a / n) % n, ak = a / (n * n);
    int bi = b % n, bj = (b / n) % n, bk = b / (n * n);
    int di = bi - ai, dj = bj - aj, dk = bk - ak;
    if (di < 0 || di > 1 || dj < 0 || dj > 1 || dk < 0 || dk > 1) return -1;
    int code = di | (dj << 1) | (dk << 2);
    return 7 * (int64_t)a + code - 1;
}
