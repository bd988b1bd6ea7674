// UV charts: a mesh cut into charts by normal-cone region growing, each chart checked for overlap
// (and poor convexity) in its orthographic projection and cut until none is left. uv_atlas.c
// lays the charts out; see docs/uv_atlas.md.
#include "export/uv_internal.h"
#include <math.h>
#include <stdlib.h>
#include <string.h>

// NaN-free min/max without libm calls (the inputs here are finite or ±INFINITY)
#define MIN2(a, b) ((a) < (b) ? (a) : (b))
#define MAX2(a, b) ((a) > (b) ? (a) : (b))

#define MIN_CUT_FACES 32       // charts smaller than this are never cut for convexity
#define MIN_CONVEXITY 0.6      // chart area / convex hull area below which a chart is cut

// ---- small helpers -------------------------------------------------------------------------------

static void cross3(const double* a, const double* b, double* o) {
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}

void mlb_uv_plane_basis(const double* n, double* t1, double* t2) {
    double a[3] = {0, 0, 0};
    if (fabs(n[0]) <= fabs(n[1]) && fabs(n[0]) <= fabs(n[2])) a[0] = 1;
    else if (fabs(n[1]) <= fabs(n[2])) a[1] = 1;
    else a[2] = 1;
    cross3(a, n, t1);   // ⟂ n
    double l = sqrt(mlb_uv_dot3(t1, t1));
    for (int k = 0; k < 3; k++) t1[k] /= l;
    cross3(n, t1, t2);  // t1 × t2 = t1 × (n × t1) = n
}

double mlb_uv_face_height(const float* const q[3], double* c) {
    double e[3][3];
    for (int k = 0; k < 3; k++) {
        e[0][k] = (double)q[1][k] - q[0][k];
        e[1][k] = (double)q[2][k] - q[0][k];
        e[2][k] = (double)q[2][k] - q[1][k];
    }
    cross3(e[0], e[1], c);
    double L = MAX2(mlb_uv_dot3(e[0], e[0]), MAX2(mlb_uv_dot3(e[1], e[1]), mlb_uv_dot3(e[2], e[2])));
    return L > 0 ? sqrt(mlb_uv_dot3(c, c)) / sqrt(L) : 0;
}

static int face_key_cmp(const void* x, const void* y) {
    const mlb_uv_face_key *a = x, *b = y;
    for (int k = 0; k < 3; k++)
        if (a->v[k] != b->v[k]) return a->v[k] < b->v[k] ? -1 : 1;
    return a->face < b->face ? -1 : a->face > b->face;
}

void mlb_uv_face_keys(const int32_t* faces, const int32_t* weld, int F, mlb_uv_face_key* fk) {
    for (int f = 0; f < F; f++) {
        const int32_t* t = faces + 3 * (size_t)f;
        int32_t w[3] = {t[0], t[1], t[2]};
        if (weld)
            for (int k = 0; k < 3; k++) w[k] = weld[w[k]];
        int r = (w[1] < w[0] && w[1] <= w[2]) ? 1 : (w[2] < w[0] && w[2] < w[1]) ? 2 : 0;
        fk[f] = (mlb_uv_face_key){{w[r], w[(r + 1) % 3], w[(r + 2) % 3]}, f};
    }
    qsort(fk, (size_t)F, sizeof *fk, face_key_cmp);
}

typedef struct { uint64_t key; int32_t face; int8_t dir; } edge_rec;   // dir: 1 when a < b as written

static int edge_cmp(const void* x, const void* y) {
    const edge_rec *a = x, *b = y;
    if (a->key != b->key) return a->key < b->key ? -1 : 1;
    return a->face < b->face ? -1 : a->face > b->face;
}

static int chart_push(mlb_uv_chart* c, int32_t f) {
    if (c->n == c->cap) {
        int nc = c->cap ? 2 * c->cap : 16;
        int32_t* p = realloc(c->faces, sizeof *p * (size_t)nc);
        if (!p) return 0;
        c->faces = p;
        c->cap = nc;
    }
    c->faces[c->n++] = f;
    return 1;
}

static mlb_uv_chart* chart_new(mlb_uv_charts* L) {
    if (L->n == L->cap) {
        int nc = L->cap ? 2 * L->cap : 64;
        mlb_uv_chart* p = realloc(L->v, sizeof *p * (size_t)nc);
        if (!p) return NULL;
        L->v = p;
        L->cap = nc;
    }
    mlb_uv_chart* c = &L->v[L->n++];
    memset(c, 0, sizeof *c);
    return c;
}

void mlb_uv_charts_free(mlb_uv_charts* L) {
    for (int i = 0; i < L->n; i++) free(L->v[i].faces);
    free(L->v);
    free(L->degen);
    free(L->dup);
    memset(L, 0, sizeof *L);
}

// ---- overlap of one chart's projection -----------------------------------------------------------

// Closed triangles a, b [3,2] overlap with a positive-area intersection (by more than eps along
// every separating-axis candidate: the six edge normals).
static int tri_overlap(const double* a, const double* b, double eps) {
    const double* T[2] = {a, b};
    for (int t = 0; t < 2; t++)
        for (int e = 0; e < 3; e++) {
            const double* p = T[t] + 2 * e;
            const double* q = T[t] + 2 * ((e + 1) % 3);
            double nx = -(q[1] - p[1]), ny = q[0] - p[0];
            double l = sqrt(nx * nx + ny * ny);
            if (l == 0) continue;
            nx /= l;
            ny /= l;
            double amin = 1e300, amax = -1e300, bmin = 1e300, bmax = -1e300;
            for (int k = 0; k < 3; k++) {
                double da = a[2 * k] * nx + a[2 * k + 1] * ny, db = b[2 * k] * nx + b[2 * k + 1] * ny;
                amin = MIN2(amin, da); amax = MAX2(amax, da);
                bmin = MIN2(bmin, db); bmax = MAX2(bmax, db);
            }
            if (amax <= bmin + eps || bmax <= amin + eps) return 0;
        }
    return 1;
}

// 1 when two faces of the chart overlap in the projection, -1 on out-of-memory, 0 otherwise.
// uv [n,3,2]: the corners of the chart's faces (those with area: a face without cannot overlap).
// Long faces across many cells or many faces in one cell (a fan of slivers round a point) would
// make the grid's entries or the pair tests quadratic: past OVERLAP_WORK_PER_FACE of them a face
// (and OVERLAP_WORK_FLOOR for any chart) the chart counts as overlapping and is cut, which costs
// seams, never an overlap, and keeps the check linear in the chart's faces.
#define OVERLAP_WORK_PER_FACE 64
#define OVERLAP_WORK_FLOOR 16384
static int chart_overlaps(const double* uv, int n) {
    if (n < 2) return 0;
    double lo[2] = {1e300, 1e300}, hi[2] = {-1e300, -1e300};
    for (int i = 0; i < 3 * n; i++)
        for (int k = 0; k < 2; k++) { lo[k] = MIN2(lo[k], uv[2 * i + k]); hi[k] = MAX2(hi[k], uv[2 * i + k]); }
    double ext = MAX2(hi[0] - lo[0], hi[1] - lo[1]);
    if (!(ext > 0)) return 0;
    double eps = 1e-7 * ext;
    int g = (int)ceil(sqrt((double)n));
    if (g > 1024) g = 1024;
    double cw = MAX2(hi[0] - lo[0], 1e-300) / g, ch = MAX2(hi[1] - lo[1], 1e-300) / g;
    // counting sort of (cell, face) entries
    int* cnt = calloc((size_t)g * g + 1, sizeof *cnt);
    int (*box)[4] = malloc(sizeof *box * (size_t)n);
    if (!cnt || !box) { free(cnt); free(box); return -1; }
    size_t total = 0, budget = (size_t)OVERLAP_WORK_PER_FACE * (size_t)n + OVERLAP_WORK_FLOOR;
    for (int f = 0; f < n; f++) {
        const double* t = uv + 6 * f;
        double x0 = MIN2(t[0], MIN2(t[2], t[4])), x1 = MAX2(t[0], MAX2(t[2], t[4]));
        double y0 = MIN2(t[1], MIN2(t[3], t[5])), y1 = MAX2(t[1], MAX2(t[3], t[5]));
        int i0 = (int)((x0 - lo[0]) / cw), i1 = (int)((x1 - lo[0]) / cw);
        int j0 = (int)((y0 - lo[1]) / ch), j1 = (int)((y1 - lo[1]) / ch);
        i0 = i0 < 0 ? 0 : i0 >= g ? g - 1 : i0; i1 = i1 < 0 ? 0 : i1 >= g ? g - 1 : i1;
        j0 = j0 < 0 ? 0 : j0 >= g ? g - 1 : j0; j1 = j1 < 0 ? 0 : j1 >= g ? g - 1 : j1;
        box[f][0] = i0; box[f][1] = i1; box[f][2] = j0; box[f][3] = j1;
        total += (size_t)(i1 - i0 + 1) * (size_t)(j1 - j0 + 1);
    }
    if (total > budget) { free(cnt); free(box); return 1; }
    for (int f = 0; f < n; f++)
        for (int j = box[f][2]; j <= box[f][3]; j++)
            for (int i = box[f][0]; i <= box[f][1]; i++) cnt[j * g + i + 1]++;
    for (int c = 0; c < g * g; c++) cnt[c + 1] += cnt[c];
    int* ent = malloc(sizeof *ent * (total ? total : 1));
    int* fill = malloc(sizeof *fill * (size_t)g * g);
    if (!ent || !fill) { free(cnt); free(box); free(ent); free(fill); return -1; }
    memcpy(fill, cnt, sizeof *fill * (size_t)g * g);
    for (int f = 0; f < n; f++)
        for (int j = box[f][2]; j <= box[f][3]; j++)
            for (int i = box[f][0]; i <= box[f][1]; i++) ent[fill[j * g + i]++] = f;
    int found = 0;
    size_t tests = total;
    for (int c = 0; c < g * g && !found; c++)
        for (int x = cnt[c]; x < cnt[c + 1] && !found; x++)
            for (int y = x + 1; y < cnt[c + 1] && !found; y++) {
                if (++tests > budget) { found = 1; break; }
                int a = ent[x], b = ent[y];
                if (box[a][1] < box[b][0] || box[b][1] < box[a][0] || box[a][3] < box[b][2] || box[b][3] < box[a][2]) continue;
                // a pair whose boxes share several cells is tested in the first of them only
                if (c % g != MAX2(box[a][0], box[b][0]) || c / g != MAX2(box[a][2], box[b][2])) continue;
                if (tri_overlap(uv + 6 * a, uv + 6 * b, eps)) found = 1;
            }
    free(cnt); free(box); free(ent); free(fill);
    return found;
}


// ---- cutting the mesh into charts ----------------------------------------------------------------

// The working state of one mesh's charting; the charts themselves (and degen, dup) go to L.
typedef struct {
    const mlb_mesh* in;
    int F;
    double cos_max;       // cosine of the largest angle between a chart's faces and its axis
    int32_t* weld;        // [V] first vertex at the same position
    double* fn;           // [F,3] unit normals
    double* farea;        // [F] 3D area
    int32_t* adj;         // [F,3] neighbour across edge k (k→k+1), -1 none
    int32_t* fchart;      // [F] the face's chart, -1 none yet
    int32_t* mark;        // [F] the stamp of the last walk that reached the face
    int32_t* queue;       // [F] a walk's faces in the order reached
    double* cuv;          // the projected corners of the chart being checked, then its hull
    int stamp;
    mlb_uv_charts* L;
} charting;

// Unit normals and areas; a face thinner than MLB_UV_DEGENERATE_REL × the bbox diagonal is
// degenerate (normal +z: it takes no part in growing the charts).
static void face_normals(charting* w) {
    const mlb_mesh* in = w->in;
    float lo[3], hi[3];
    mlb_mesh_bounds(in, lo, hi);
    double diag = 0;
    for (int k = 0; k < 3; k++) diag += (double)(hi[k] - lo[k]) * (hi[k] - lo[k]);
    diag = sqrt(diag);
    for (int f = 0; f < w->F; f++) {
        const int32_t* t = in->faces + 3 * (size_t)f;
        const float* q[3] = {in->pos + 3 * (size_t)t[0], in->pos + 3 * (size_t)t[1], in->pos + 3 * (size_t)t[2]};
        double c[3];
        double h = mlb_uv_face_height(q, c);
        double l = sqrt(mlb_uv_dot3(c, c));
        w->farea[f] = 0.5 * l;
        if (!(h >= MLB_UV_DEGENERATE_REL * diag)) {
            w->L->degen[f] = 1;
            w->fn[3 * f] = w->fn[3 * f + 1] = 0;
            w->fn[3 * f + 2] = 1;
        } else {
            for (int k = 0; k < 3; k++) w->fn[3 * f + k] = c[k] / l;
        }
    }
}

// A face given again (the same welded corners in the same turn) is the same surface: it takes no
// part in the adjacency or the charts, and at the end gets the first copy's chart and so its
// UVs. (400 copies of one face were 400 charts, and their shared edges joined nothing.)
// 0 when out of memory.
static int find_repeats(charting* w) {
    const int F = w->F;
    int32_t* dup = w->L->dup;
    mlb_uv_face_key* fk = malloc(sizeof *fk * (size_t)F);
    if (!fk) return 0;
    for (int f = 0; f < F; f++) dup[f] = -1;
    mlb_uv_face_keys(w->in->faces, w->weld, F, fk);
    for (int i = 1; i < F; i++) {
        const mlb_uv_face_key *a = &fk[i - 1], *b = &fk[i];
        int first = dup[a->face] >= 0 ? dup[a->face] : a->face;
        if (!memcmp(a->v, b->v, sizeof a->v) && !w->L->degen[first]) dup[b->face] = first;
    }
    free(fk);
    return 1;
}

// The key of face f's edge k (k→k+1) between welded corners, the smaller corner first.
static uint64_t edge_key(const charting* w, int f, int k, uint32_t* a_out, uint32_t* b_out) {
    const int32_t* t = w->in->faces + 3 * (size_t)f;
    uint32_t a = (uint32_t)w->weld[t[k]], b = (uint32_t)w->weld[t[(k + 1) % 3]];
    if (a_out) *a_out = a, *b_out = b;
    return a < b ? ((uint64_t)a << 32 | b) : ((uint64_t)b << 32 | a);
}

// Edge adjacency: an edge used by exactly two faces in opposite directions joins them. 0 when out
// of memory.
static int edge_adjacency(charting* w) {
    const int F = w->F;
    edge_rec* er = malloc(sizeof *er * 3 * (size_t)F);
    if (!er) return 0;
    for (int f = 0; f < F; f++)
        for (int k = 0; k < 3; k++) {
            uint32_t a, b;
            edge_rec* r = &er[3 * (size_t)f + k];
            r->key = edge_key(w, f, k, &a, &b);
            r->face = f;
            r->dir = (int8_t)(a < b);
            w->adj[3 * (size_t)f + k] = -1;
            if (a == b || w->L->dup[f] >= 0) r->key = UINT64_MAX;   // a collapsed edge, a repeated face: join nothing
        }
    qsort(er, 3 * (size_t)F, sizeof *er, edge_cmp);
    for (size_t i = 0; i < 3 * (size_t)F;) {
        size_t j = i;
        while (j < 3 * (size_t)F && er[j].key == er[i].key) j++;
        if (er[i].key != UINT64_MAX && j - i == 2 && er[i].dir != er[i + 1].dir && er[i].face != er[i + 1].face) {
            int fa = er[i].face, fb = er[i + 1].face;
            for (int k = 0; k < 3; k++) {
                if (edge_key(w, fa, k, NULL, NULL) == er[i].key) w->adj[3 * (size_t)fa + k] = fb;
                if (edge_key(w, fb, k, NULL, NULL) == er[i].key) w->adj[3 * (size_t)fb + k] = fa;
            }
        }
        i = j;
    }
    free(er);
    return 1;
}

// Breadth-first from seed over the faces of chart `chart` (-1: the faces with no chart yet that
// are not degenerate and lie within the cone of `axis`), marked with a new stamp: their number,
// the faces in w->queue in the order reached.
static int walk(charting* w, int seed, int chart, const double* axis) {
    const uint8_t* degen = w->L->degen;
    w->stamp++;
    int qn = 0;
    w->queue[qn++] = seed;
    w->mark[seed] = w->stamp;
    for (int qi = 0; qi < qn; qi++) {
        int f = w->queue[qi];
        for (int k = 0; k < 3; k++) {
            int g = w->adj[3 * (size_t)f + k];
            if (g < 0 || w->fchart[g] != chart || w->mark[g] == w->stamp) continue;
            if (axis && (degen[g] || mlb_uv_dot3(w->fn + 3 * g, axis) < w->cos_max)) continue;
            w->mark[g] = w->stamp;
            w->queue[qn++] = g;
        }
    }
    return qn;
}

// Region growing: seed = the first unassigned non-degenerate face; axis refined from the grown
// set's area-weighted mean normal (3 rounds); the last round's set becomes the chart. 0 when out
// of memory.
static int grow_charts(charting* w) {
    mlb_uv_charts* L = w->L;
    for (int f = 0; f < w->F; f++) { w->fchart[f] = -1; w->mark[f] = -1; }
    for (int seed = 0; seed < w->F; seed++) {
        if (w->fchart[seed] >= 0 || L->degen[seed] || L->dup[seed] >= 0) continue;
        const double* fs = w->fn + 3 * seed;
        double axis[3] = {fs[0], fs[1], fs[2]};
        int qn = 0;
        for (int round = 0; round < 3; round++) {
            qn = walk(w, seed, -1, axis);
            if (round == 2) break;
            double m[3] = {0, 0, 0};
            for (int qi = 0; qi < qn; qi++)
                for (int k = 0; k < 3; k++) m[k] += w->farea[w->queue[qi]] * w->fn[3 * w->queue[qi] + k];
            double l = sqrt(mlb_uv_dot3(m, m));
            if (!(l > 0)) break;
            for (int k = 0; k < 3; k++) m[k] /= l;
            if (mlb_uv_dot3(fs, m) < w->cos_max) break;   // the seed would leave its own chart
            memcpy(axis, m, sizeof axis);
        }
        // `queue` holds the set grown with `axis` (every round ends after a BFS with the axis kept)
        mlb_uv_chart* c = chart_new(L);
        if (!c) return 0;
        memcpy(c->axis, axis, sizeof axis);
        for (int qi = 0; qi < qn; qi++) {
            w->fchart[w->queue[qi]] = L->n - 1;
            if (!chart_push(c, w->queue[qi])) return 0;
        }
    }
    return 1;
}

// Degenerate faces join a neighbouring chart: in face order those beside a chart, then breadth-
// first from them those beside a face that joined (linear: a chain of slivers is one walk, not
// a pass over the mesh per link); leftovers form one chart. 0 when out of memory.
static int place_degenerate(charting* w) {
    mlb_uv_charts* L = w->L;
    int32_t *fchart = w->fchart, *queue = w->queue;
    const int32_t* dup = L->dup;
    int qn = 0;
    for (int f = 0; f < w->F; f++) {
        if (fchart[f] >= 0 || dup[f] >= 0) continue;
        for (int k = 0; k < 3; k++) {
            int g = w->adj[3 * (size_t)f + k];
            if (g >= 0 && fchart[g] >= 0) {
                fchart[f] = fchart[g];
                if (!chart_push(&L->v[fchart[g]], f)) return 0;
                queue[qn++] = f;
                break;
            }
        }
    }
    for (int qi = 0; qi < qn; qi++) {
        int f = queue[qi];
        for (int k = 0; k < 3; k++) {
            int g = w->adj[3 * (size_t)f + k];
            if (g < 0 || fchart[g] >= 0 || dup[g] >= 0) continue;
            fchart[g] = fchart[f];
            if (!chart_push(&L->v[fchart[f]], g)) return 0;
            queue[qn++] = g;
        }
    }
    int leftover = -1;
    for (int f = 0; f < w->F; f++) {
        if (fchart[f] >= 0 || dup[f] >= 0) continue;
        if (leftover < 0) {
            mlb_uv_chart* c = chart_new(L);
            if (!c) return 0;
            c->axis[2] = 1;
            leftover = L->n - 1;
        }
        fchart[f] = leftover;
        if (!chart_push(&L->v[leftover], f)) return 0;
    }
    return 1;
}

// Whether chart ci must be cut: 1 when its projection overlaps itself, 2 when it is of
// MIN_CUT_FACES faces with area or more and poorly convex (chart area / hull area below
// MIN_CONVEXITY: an annulus or a C shape wastes its rectangle in the packing), 0 when neither,
// -1 when out of memory. Only faces with area are checked and counted (a degenerate face covers
// no texel), so the leftover chart of slivers is never cut.
static int needs_cut(charting* w, int ci) {
    const mlb_mesh* in = w->in;
    const mlb_uv_chart* c = &w->L->v[ci];
    double t1[3], t2[3];
    mlb_uv_plane_basis(c->axis, t1, t2);
    double* p = realloc(w->cuv, sizeof *w->cuv * (12 * (size_t)c->n + 4));
    if (!p) return -1;
    w->cuv = p;
    double* cuv = w->cuv;
    int na = 0;   // the chart's faces with area, projected
    for (int i = 0; i < c->n; i++) {
        if (w->L->degen[c->faces[i]]) continue;
        for (int k = 0; k < 3; k++) {
            const float* q = in->pos + 3 * (size_t)w->weld[in->faces[3 * (size_t)c->faces[i] + k]];
            double qd[3] = {q[0], q[1], q[2]};
            cuv[6 * na + 2 * k] = mlb_uv_dot3(qd, t1);
            cuv[6 * na + 2 * k + 1] = mlb_uv_dot3(qd, t2);
        }
        na++;
    }
    if (c->n < 2) return 0;
    int ov = chart_overlaps(cuv, na);
    if (ov) return ov;
    if (na < MIN_CUT_FACES) return 0;
    double a = 0;
    for (int i = 0; i < na; i++) {
        const double* t = cuv + 6 * i;
        a += 0.5 * fabs((t[2] - t[0]) * (t[5] - t[1]) - (t[4] - t[0]) * (t[3] - t[1]));
    }
    double* hull = cuv + 6 * (size_t)na;
    int nh = mlb_uv_convex_hull(cuv, 3 * na, hull);
    double ha = 0;
    for (int e = 0; e < nh; e++) {
        const double *p0 = hull + 2 * e, *p1 = hull + 2 * ((e + 1) % nh);
        ha += 0.5 * (p0[0] * p1[1] - p1[0] * p0[1]);
    }
    return !(ha > 0) || a >= MIN_CONVEXITY * ha ? 0 : 2;
}

// The half of chart ci to keep, marked with the stamp: breadth-first from a far face (the last
// one reached from the chart's first face), the first half reached. A disconnected chart keeps
// the part reached from its first face instead: returns 0 then, 1 for a connected chart.
static int mark_kept_half(charting* w, int ci) {
    const mlb_uv_chart* c = &w->L->v[ci];
    int seed = c->faces[0], whole = 1;
    for (int pass = 0; pass < 2 && whole; pass++) {
        int qn = walk(w, seed, ci, NULL);
        if (qn < c->n) whole = 0;   // disconnected: the part reached stays
        else if (pass == 0) seed = w->queue[qn - 1];
        else {                      // keep the first half
            w->stamp++;
            for (int qi = 0; qi < qn / 2; qi++) w->mark[w->queue[qi]] = w->stamp;
        }
    }
    return whole;
}

// Chart ci cut in two along the surface (the new part keeps the axis): the marked half stays, the
// rest is a new chart; a disconnected chart keeps the part reached and every other part becomes a
// chart of its own, all in one pass (one part at a time was a pass over the chart per part). 0
// when out of memory.
static int cut_chart(charting* w, int ci) {
    mlb_uv_charts* L = w->L;
    int32_t *fchart = w->fchart, *queue = w->queue;
    const int whole = mark_kept_half(w, ci);
    const int stamp = w->stamp;
    double axis[3];
    memcpy(axis, L->v[ci].axis, sizeof axis);
    const int n_before = L->v[ci].n;
    int keep = 0;
    for (int i = 0; i < n_before; i++) {
        int f = L->v[ci].faces[i];
        if (w->mark[f] == stamp) { L->v[ci].faces[keep++] = f; continue; }
        if (fchart[f] != ci) continue;   // moved with an earlier part
        // f starts the next part: all of it (a connected chart: all the rest) to a new chart
        mlb_uv_chart* d = chart_new(L);
        if (!d) return 0;
        memcpy(d->axis, axis, sizeof axis);
        const int id = L->n - 1;
        int qn = 0;
        queue[qn++] = f;
        fchart[f] = id;
        for (int qi = 0; qi < qn; qi++) {
            int h = queue[qi];
            if (!chart_push(&L->v[id], h)) return 0;
            for (int k = 0; k < 3 && !whole; k++) {
                int g = w->adj[3 * (size_t)h + k];
                if (g < 0 || fchart[g] != ci || w->mark[g] == stamp) continue;
                fchart[g] = id;
                queue[qn++] = g;
            }
        }
        if (whole)   // the rest of a connected chart's order, whatever its adjacency
            for (int j = i + 1; j < n_before; j++) {
                int h = L->v[ci].faces[j];
                if (w->mark[h] == stamp || fchart[h] != ci) continue;
                fchart[h] = id;
                if (!chart_push(&L->v[id], h)) return 0;
            }
    }
    L->v[ci].n = keep;
    return 1;
}

// Overlap check per chart; an overlapping or poorly convex chart is cut in two and both parts
// are checked again (the new part when the loop reaches it). 0 when out of memory.
static int cut_charts(charting* w) {
    for (int ci = 0; ci < w->L->n; ci++)
        for (;;) {
            int why = needs_cut(w, ci);
            if (why < 0) return 0;
            if (!why) break;
            if (why == 1) w->L->n_split++;
            else w->L->n_cut++;
            if (!cut_chart(w, ci)) return 0;
        }
    return 1;
}

// The repeated faces join their first copy's chart: the same UVs, the same texels.
static int place_repeats(charting* w) {
    mlb_uv_charts* L = w->L;
    for (int f = 0; f < w->F; f++)
        if (L->dup[f] >= 0) {
            w->fchart[f] = w->fchart[L->dup[f]];
            if (!chart_push(&L->v[w->fchart[f]], f)) return 0;
        }
    return 1;
}

int mlb_uv_make_charts(const mlb_mesh* in, double cos_max, mlb_uv_charts* L) {
    const int V = in->n_verts, F = in->n_faces;
    memset(L, 0, sizeof *L);
    charting w = {.in = in, .F = F, .cos_max = cos_max, .L = L};
    w.weld = malloc(sizeof *w.weld * (size_t)V);
    w.fn = malloc(sizeof *w.fn * 3 * (size_t)F);
    w.farea = malloc(sizeof *w.farea * (size_t)F);
    w.adj = malloc(sizeof *w.adj * 3 * (size_t)F);
    w.fchart = malloc(sizeof *w.fchart * (size_t)F);
    w.mark = malloc(sizeof *w.mark * (size_t)F);
    w.queue = malloc(sizeof *w.queue * (size_t)F);
    L->degen = calloc((size_t)F, 1);
    L->dup = malloc(sizeof *L->dup * (size_t)F);
    // weld by exact position (the mesh may come with seams already split)
    int ok = w.weld && w.fn && w.farea && w.adj && w.fchart && w.mark && w.queue && L->degen && L->dup &&
             !mlb_mesh_weld_map(in->pos, V, w.weld);
    if (ok) face_normals(&w);
    ok = ok && find_repeats(&w) && edge_adjacency(&w) && grow_charts(&w) && place_degenerate(&w) && cut_charts(&w) &&
         place_repeats(&w);
    free(w.weld); free(w.fn); free(w.farea); free(w.adj); free(w.fchart); free(w.mark); free(w.queue); free(w.cuv);
    if (!ok) mlb_uv_charts_free(L);
    return ok;
}
