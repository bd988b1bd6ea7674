// A static bounding-volume hierarchy over a mesh's triangles for the exact unsigned point-to-mesh
// distance (include/matlaber/geometry.h, docs/geometry_init.md). Build: median split of the
// triangle centroids on the longest axis, leaves of at most BVH_LEAF triangles, one flat node array
// (children side by side) and the triangles' corners copied in leaf order. Query: nearest child
// first, a subtree skipped when its box is no nearer than the best distance so far.
//
// Exactness: mlb_point_triangle_dist2 keeps its closest point inside the triangle's bounding box,
// and the box distance below is computed with the same operations in the same order, so rounding
// (monotone) gives d2(triangle) >= e2(box) >= e2(any box around it) for every triangle. A skipped
// subtree therefore never holds a triangle below the best so far: the answer is the minimum over
// all triangles, bit for bit, whatever the traversal order or the thread count (the minimum of a
// set of doubles does not depend on the order it is taken in).
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/geometry.h"

enum { BVH_LEAF = 4, BVH_STACK = 64 };   // median split: depth <= log2(F) + 1 < 33 for any int F
// A box is visited when e2·BOX_SLACK < best. Without contraction e2 <= d2 holds exactly; the slack
// (far above the few ulps any FMA contraction of either sum could move them) keeps it so under
// -march flags too, at no measurable cost.
#define BOX_SLACK (1.0 - 0x1p-40)

static int tri_finite(const float* v) {
    for (int k = 0; k < 9; k++) if (!isfinite(v[k])) return 0;
    return 1;
}

// (fmin/fmax are libm calls at -O2 on x86-64; every value here is finite)
#define MIN(x, y) ((x) < (y) ? (x) : (y))
#define MAX(x, y) ((x) > (y) ? (x) : (y))
#define SWAP(x, y) do { int32_t t_ = (x); (x) = (y); (y) = t_; } while (0)

// Hoare quickselect: idx[lo..hi] reordered so that key[idx[mid]] is in sorted position, smaller or
// equal keys before it, larger or equal after. Equal keys split evenly (grid-aligned meshes have many).
static void select_mid(int32_t* idx, const double* key, int lo, int hi, int mid) {
    while (lo < hi) {
        // median of three, moved to the middle: a pivot below position hi keeps j < hi (progress)
        int m = lo + (hi - lo) / 2;
        if (key[idx[m]] < key[idx[lo]]) SWAP(idx[m], idx[lo]);
        if (key[idx[hi]] < key[idx[lo]]) SWAP(idx[hi], idx[lo]);
        if (key[idx[hi]] < key[idx[m]]) SWAP(idx[hi], idx[m]);
        double pivot = key[idx[m]];
        int i = lo - 1, j = hi + 1;
        for (;;) {
            do i++; while (key[idx[i]] < pivot);
            do j--; while (key[idx[j]] > pivot);
            if (i >= j) break;
            SWAP(idx[i], idx[j]);
        }
        if (mid <= j) hi = j; else lo = j + 1;
    }
}

typedef struct {
    const float* box;     // [F, 6] per-triangle lo, hi
    const double* cen;    // [F, 3] centroids
    double* key;          // [F] scratch: the split axis' centroid coordinate
    int32_t* idx;         // triangle order, rearranged in place
    mlb_bvh_node* nodes;
    int n_nodes;
} bvh_builder;

static void build_node(bvh_builder* B, int node, int lo, int hi) {   // triangles idx[lo..hi)
    mlb_bvh_node* nd = B->nodes + node;
    double clo[3] = {INFINITY, INFINITY, INFINITY}, chi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int k = 0; k < 3; k++) { nd->lo[k] = INFINITY; nd->hi[k] = -INFINITY; }
    for (int i = lo; i < hi; i++) {
        const float* bx = B->box + 6 * (size_t)B->idx[i];
        const double* c = B->cen + 3 * (size_t)B->idx[i];
        for (int k = 0; k < 3; k++) {
            nd->lo[k] = MIN(nd->lo[k], bx[k]);
            nd->hi[k] = MAX(nd->hi[k], bx[3 + k]);
            clo[k] = MIN(clo[k], c[k]);
            chi[k] = MAX(chi[k], c[k]);
        }
    }
    if (hi - lo <= BVH_LEAF) { nd->first = lo; nd->count = hi - lo; return; }
    int axis = 0;
    for (int k = 1; k < 3; k++) if (chi[k] - clo[k] > chi[axis] - clo[axis]) axis = k;
    for (int i = lo; i < hi; i++) B->key[B->idx[i]] = B->cen[3 * (size_t)B->idx[i] + axis];
    int mid = lo + (hi - lo) / 2;
    select_mid(B->idx, B->key, lo, hi - 1, mid);
    int child = B->n_nodes;
    B->n_nodes += 2;
    nd->first = child;
    nd->count = 0;
    build_node(B, child, lo, mid);
    build_node(B, child + 1, mid, hi);
}

mlb_status mlb_mesh_bvh_build(mlb_mesh_bvh* b, const mlb_mesh* m) {
    memset(b, 0, sizeof *b);
    int F = m->n_faces > 0 ? m->n_faces : 0;
    if (F > (1 << 29)) return mlb_fail(MLB_ERR_ARG, "mesh BVH: %d faces (at most 2^29)", F);
    // triangles with a non-finite coordinate have no distance: left out (their box would be NaN)
    float* tri = malloc(sizeof(float) * 9 * (size_t)(F > 0 ? F : 1));
    float* box = malloc(sizeof(float) * 6 * (size_t)(F > 0 ? F : 1));
    double* cen = malloc(sizeof(double) * 4 * (size_t)(F > 0 ? F : 1));   // centroids, then the key
    int32_t* idx = malloc(sizeof(int32_t) * (size_t)(F > 0 ? F : 1));
    mlb_bvh_node* nodes = malloc(sizeof(mlb_bvh_node) * 2 * (size_t)(F > 0 ? F : 1));
    if (!tri || !box || !cen || !idx || !nodes) {
        free(tri); free(box); free(cen); free(idx); free(nodes);
        return mlb_fail(MLB_ERR_NOMEM, "mesh BVH: out of memory (%d faces)", F);
    }
    int n = 0;
    for (int f = 0; f < F; f++) {
        const int32_t* t = m->faces + 3 * (size_t)f;
        float v[9];
        for (int c = 0; c < 3; c++) memcpy(v + 3 * c, m->pos + 3 * (size_t)t[c], sizeof(float) * 3);
        if (!tri_finite(v)) continue;
        memcpy(tri + 9 * (size_t)n, v, sizeof v);
        for (int k = 0; k < 3; k++) {
            box[6 * n + k] = MIN(v[k], MIN(v[3 + k], v[6 + k]));
            box[6 * n + 3 + k] = MAX(v[k], MAX(v[3 + k], v[6 + k]));
            cen[3 * n + k] = ((double)v[k] + v[3 + k] + v[6 + k]) / 3.0;
        }
        idx[n] = n;
        n++;
    }
    b->n_tris = n;
    if (n > 0) {
        bvh_builder B = {.box = box, .cen = cen, .key = cen + 3 * (size_t)F, .idx = idx, .nodes = nodes, .n_nodes = 1};
        build_node(&B, 0, 0, n);
        b->n_nodes = B.n_nodes;
        // corners in leaf order: a leaf's triangles are contiguous in memory
        b->tri = malloc(sizeof(float) * 9 * (size_t)n);
        if (!b->tri) { free(tri); free(box); free(cen); free(idx); free(nodes); memset(b, 0, sizeof *b);
                       return mlb_fail(MLB_ERR_NOMEM, "mesh BVH: out of memory (%d faces)", F); }
        for (int i = 0; i < n; i++) memcpy(b->tri + 9 * (size_t)i, tri + 9 * (size_t)idx[i], sizeof(float) * 9);
        b->nodes = nodes;
    } else {
        free(nodes);
    }
    free(tri); free(box); free(cen); free(idx);
    return MLB_OK;
}

void mlb_mesh_bvh_free(mlb_mesh_bvh* b) {
    if (!b) return;
    free(b->nodes);
    free(b->tri);
    memset(b, 0, sizeof *b);
}

// Squared distance from q to the box, in the order mlb_point_triangle_dist2 sums its closest
// point's offsets (see the exactness note at the top).
static inline double box_dist2(const mlb_bvh_node* nd, const double q[3]) {
    double e2 = 0;
    for (int k = 0; k < 3; k++) {
        double e = q[k] < nd->lo[k] ? (double)nd->lo[k] - q[k] : (q[k] > nd->hi[k] ? q[k] - (double)nd->hi[k] : 0);
        e2 += e * e;
    }
    return e2;
}

double mlb_mesh_bvh_dist2(const mlb_mesh_bvh* b, const double q[3]) {
    double best = INFINITY;
    if (b->n_tris == 0) return best;
    if (isnan(q[0]) || isnan(q[1]) || isnan(q[2])) return NAN;   // (it would visit every box)
    struct { int node; double e2; } stack[BVH_STACK];
    int sp = 0, node = 0;
    for (;;) {
        const mlb_bvh_node* nd = b->nodes + node;
        if (nd->count) {
            for (int t = nd->first; t < nd->first + nd->count; t++) {
                const float* v = b->tri + 9 * (size_t)t;
                double d2 = mlb_point_triangle_dist2(q, v, v + 3, v + 6);
                if (d2 < best) best = d2;
            }
        } else {
            int near = nd->first, far = nd->first + 1;
            double en = box_dist2(b->nodes + near, q), ef = box_dist2(b->nodes + far, q);
            if (ef < en) { int t = near; near = far; far = t; double e = en; en = ef; ef = e; }
            if (en * BOX_SLACK < best) {   // a box at >= best cannot hold a triangle below best
                if (ef * BOX_SLACK < best) { stack[sp].node = far; stack[sp].e2 = ef; sp++; }
                node = near;
                continue;
            }
        }
        // next: the most recently deferred subtree still nearer than the best so far
        for (;;) {
            if (sp == 0) return best;
            sp--;
            if (stack[sp].e2 * BOX_SLACK < best) { node = stack[sp].node; break; }
        }
    }
}

void mlb_mesh_bvh_distance(const mlb_mesh_bvh* b, const float* p, float* out, int n) {
#pragma omp parallel for schedule(dynamic, 64)
    for (int i = 0; i < n; i++) {
        double q[3] = {p[3 * (size_t)i], p[3 * (size_t)i + 1], p[3 * (size_t)i + 2]};
        out[i] = (float)sqrt(mlb_mesh_bvh_dist2(b, q));
    }
}
