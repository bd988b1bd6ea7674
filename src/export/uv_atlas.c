// UV atlas: charts by normal-cone region growing, orthographic projection per chart, overlap
// check (and cut) per chart, skyline packing at a common texel density. See uv_atlas.h and
// docs/uv_atlas.md.
#include "matlaber/uv_atlas.h"
#include "export/uv_internal.h"
#include <math.h>
#include <stdlib.h>
#include <string.h>

// NaN-free min/max without libm calls (the inputs here are finite or ±INFINITY)
#define MIN2(a, b) ((a) < (b) ? (a) : (b))
#define MAX2(a, b) ((a) > (b) ? (a) : (b))

mlb_uv_options mlb_uv_default(void) {
    mlb_uv_options o = {.texture_size = 1024, .gutter = 4, .max_angle_deg = 40.0f};
    return o;
}

void mlb_uv_mesh_free(mlb_uv_mesh* m) {
    if (!m) return;
    mlb_mesh_free(&m->mesh);
    free(m->vert_src);
    free(m->face_chart);
    memset(m, 0, sizeof *m);
}

// ---- small helpers -------------------------------------------------------------------------------

static void cross3(const double* a, const double* b, double* o) {
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}
static double dot3(const double* a, const double* b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

// An orthonormal basis (t1, t2) with t1 × t2 = n (n unit).
static void plane_basis(const double* n, double* t1, double* t2) {
    double a[3] = {0, 0, 0};
    if (fabs(n[0]) <= fabs(n[1]) && fabs(n[0]) <= fabs(n[2])) a[0] = 1;
    else if (fabs(n[1]) <= fabs(n[2])) a[1] = 1;
    else a[2] = 1;
    cross3(a, n, t1);   // ⟂ n
    double l = sqrt(dot3(t1, t1));
    for (int k = 0; k < 3; k++) t1[k] /= l;
    cross3(n, t1, t2);  // t1 × t2 = t1 × (n × t1) = n
}

// The triangle's smallest height (2·area / longest edge; 0 when all corners coincide) and its
// un-normalised normal c = (q1 − q0) × (q2 − q0).
static double face_height(const float* const q[3], double* c) {
    double e[3][3];
    for (int k = 0; k < 3; k++) {
        e[0][k] = (double)q[1][k] - q[0][k];
        e[1][k] = (double)q[2][k] - q[0][k];
        e[2][k] = (double)q[2][k] - q[1][k];
    }
    cross3(e[0], e[1], c);
    double L = MAX2(dot3(e[0], e[0]), MAX2(dot3(e[1], e[1]), dot3(e[2], e[2])));
    return L > 0 ? sqrt(dot3(c, c)) / sqrt(L) : 0;
}

typedef struct { uint64_t key; int32_t face; int8_t dir; } edge_rec;   // dir: 1 when a < b as written

static int edge_cmp(const void* x, const void* y) {
    const edge_rec *a = x, *b = y;
    if (a->key != b->key) return a->key < b->key ? -1 : 1;
    return a->face < b->face ? -1 : a->face > b->face;
}

// A face's welded corners turned so that the smallest comes first (the winding kept): two faces
// with the same key are one surface given twice.
typedef struct { int32_t v[3], face; } face_key;

static int face_key_cmp(const void* x, const void* y) {
    const face_key *a = x, *b = y;
    for (int k = 0; k < 3; k++)
        if (a->v[k] != b->v[k]) return a->v[k] < b->v[k] ? -1 : 1;
    return a->face < b->face ? -1 : a->face > b->face;
}

typedef struct {
    int32_t* faces;
    int n, cap;
    double axis[3];
} chart;

static int chart_push(chart* c, int32_t f) {
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

typedef struct {
    chart* v;
    int n, cap;
} chart_list;

static chart* chart_new(chart_list* L) {
    if (L->n == L->cap) {
        int nc = L->cap ? 2 * L->cap : 64;
        chart* p = realloc(L->v, sizeof *p * (size_t)nc);
        if (!p) return NULL;
        L->v = p;
        L->cap = nc;
    }
    chart* c = &L->v[L->n++];
    memset(c, 0, sizeof *c);
    return c;
}

static void chart_list_free(chart_list* L) {
    for (int i = 0; i < L->n; i++) free(L->v[i].faces);
    free(L->v);
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

// ---- the unwrap ----------------------------------------------------------------------------------

typedef struct {
    double x, y, w, h;        // chart's local bbox after rotation (x, y = min corner)
    double r[4];              // 2x2 rotation applied to the projected coordinates (row-major)
    double t1[3], t2[3];      // projection basis
} chart_frame;

// Rotation by `rot` quarter turns of a point (a, b) of a w × h box (uv_internal.h).
static void pack_rotate(int rot, double w, double h, double a, double b, double* x, double* y) {
    switch (rot & 3) {
        case 0: *x = a; *y = b; break;
        case 1: *x = h - b; *y = a; break;
        case 2: *x = w - a; *y = h - b; break;
        default: *x = b; *y = w - a; break;
    }
}

#define HORIZON_STEPS 12       // bisection steps of the horizon packer's density
#define MIN_CUT_FACES 32       // charts smaller than this are never cut for convexity
#define MIN_CONVEXITY 0.6      // chart area / convex hull area below which a chart is cut

// Packing order: decreasing rectangle height, then chart index (no global state: reentrant).
typedef struct { double h; int i; } order_key;
static int order_cmp(const void* a, const void* b) {
    const order_key *x = a, *y = b;
    if (x->h != y->h) return x->h > y->h ? -1 : 1;
    return x->i - y->i;
}

mlb_status mlb_uv_unwrap(const mlb_mesh* in, const mlb_uv_options* opt_in, mlb_uv_mesh* out, mlb_uv_stats* stats) {
    if (out) memset(out, 0, sizeof *out);
    if (stats) memset(stats, 0, sizeof *stats);
    if (!in || !out) return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: NULL mesh");
    mlb_uv_options opt = opt_in ? *opt_in : mlb_uv_default();
    if (opt.texture_size < 8 || opt.texture_size > 65536)
        return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: texture size %d (need 8..65536)", opt.texture_size);
    if (opt.gutter < 0 || opt.gutter > opt.texture_size / 4)
        return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: gutter %d texels (need 0..%d)", opt.gutter, opt.texture_size / 4);
    if (!(opt.max_angle_deg > 0 && opt.max_angle_deg <= 80))
        return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: max angle %g degrees (need (0, 80])", (double)opt.max_angle_deg);
    if (in->n_verts <= 0 || in->n_faces <= 0 || !in->pos || !in->faces)
        return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: empty mesh (%d vertices, %d faces)", in->n_verts, in->n_faces);
    const int V = in->n_verts, F = in->n_faces;
    for (size_t i = 0; i < 3 * (size_t)F; i++)
        if (in->faces[i] < 0 || in->faces[i] >= V)
            return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: face %zu uses vertex %d, mesh has %d", i / 3, (int)in->faces[i], V);
    for (size_t i = 0; i < 3 * (size_t)V; i++)
        if (!isfinite(in->pos[i])) return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: vertex %zu has a non-finite position", i / 3);

    mlb_status st = MLB_OK;
    const double cos_max = cos(opt.max_angle_deg * M_PI / 180.0);
    int32_t* weld = malloc(sizeof *weld * (size_t)V);           // [V] first vertex at the same position
    double* fn = malloc(sizeof *fn * 3 * (size_t)F);            // [F,3] unit normals
    double* farea = malloc(sizeof *farea * (size_t)F);          // [F] 3D area
    uint8_t* degen = calloc((size_t)F, 1);
    edge_rec* er = malloc(sizeof *er * 3 * (size_t)F);
    int32_t* adj = malloc(sizeof *adj * 3 * (size_t)F);         // [F,3] neighbour across edge k (k→k+1), -1 none
    int32_t* fchart = malloc(sizeof *fchart * (size_t)F);
    int32_t* mark = malloc(sizeof *mark * (size_t)F);
    int32_t* queue = malloc(sizeof *queue * (size_t)F);
    int32_t* dup = malloc(sizeof *dup * (size_t)F);             // [F] the earlier face it repeats, -1 none
    face_key* fk = malloc(sizeof *fk * (size_t)F);
    chart_list L = {0};
    chart_frame* fr = NULL;
    int* ord = NULL;
    double* cuv = NULL;
    mlb_uv_sky_seg* sky = NULL;
    double* wh = NULL;
    mlb_uv_pack_place *pl = NULL, *pl_try = NULL;
    mlb_uv_pack_chart* pc = NULL;
    double* ltri = NULL;
    int32_t* last_chart = NULL;
    int32_t* newid = NULL;
    if (!weld || !fn || !farea || !degen || !er || !adj || !fchart || !mark || !queue || !dup || !fk) goto nomem;

    // weld by exact position (the mesh may come with seams already split)
    if (mlb_mesh_weld_map(in->pos, V, weld)) goto nomem;

    float lo[3], hi[3];
    mlb_mesh_bounds(in, lo, hi);
    double diag = 0;
    for (int k = 0; k < 3; k++) diag += (double)(hi[k] - lo[k]) * (hi[k] - lo[k]);
    diag = sqrt(diag);
    int n_degen = 0;
    for (int f = 0; f < F; f++) {
        const int32_t* t = in->faces + 3 * (size_t)f;
        const float* q[3] = {in->pos + 3 * (size_t)t[0], in->pos + 3 * (size_t)t[1], in->pos + 3 * (size_t)t[2]};
        double c[3];
        double h = face_height(q, c);
        double l = sqrt(dot3(c, c));
        farea[f] = 0.5 * l;
        if (!(h >= MLB_UV_DEGENERATE_REL * diag)) {
            degen[f] = 1;
            n_degen++;
            fn[3 * f] = fn[3 * f + 1] = 0;
            fn[3 * f + 2] = 1;
        } else {
            for (int k = 0; k < 3; k++) fn[3 * f + k] = c[k] / l;
        }
    }

    // A face given again (the same welded corners in the same turn) is the same surface: it takes no
    // part in the adjacency or the charts, and at the end gets the first copy's chart and so its
    // UVs. (400 copies of one face were 400 charts, and their shared edges joined nothing.)
    for (int f = 0; f < F; f++) {
        const int32_t* t = in->faces + 3 * (size_t)f;
        int32_t a = weld[t[0]], b = weld[t[1]], c = weld[t[2]];
        int r = (b < a && b <= c) ? 1 : (c < a && c < b) ? 2 : 0;
        int32_t w[3] = {a, b, c};
        fk[f] = (face_key){{w[r], w[(r + 1) % 3], w[(r + 2) % 3]}, f};
        dup[f] = -1;
    }
    qsort(fk, (size_t)F, sizeof *fk, face_key_cmp);
    for (int i = 1; i < F; i++) {
        const face_key *a = &fk[i - 1], *b = &fk[i];
        int first = dup[a->face] >= 0 ? dup[a->face] : a->face;
        if (!memcmp(a->v, b->v, sizeof a->v) && !degen[first]) dup[b->face] = first;
    }
    free(fk);
    fk = NULL;

    // edge adjacency: an edge used by exactly two faces in opposite directions joins them
    for (int f = 0; f < F; f++)
        for (int k = 0; k < 3; k++) {
            uint32_t a = (uint32_t)weld[in->faces[3 * (size_t)f + k]], b = (uint32_t)weld[in->faces[3 * (size_t)f + (k + 1) % 3]];
            edge_rec* r = &er[3 * (size_t)f + k];
            r->key = a < b ? ((uint64_t)a << 32 | b) : ((uint64_t)b << 32 | a);
            r->face = f;
            r->dir = (int8_t)(a < b);
            adj[3 * (size_t)f + k] = -1;
            if (a == b || dup[f] >= 0) r->key = UINT64_MAX;   // a collapsed edge, a repeated face: join nothing
        }
    qsort(er, 3 * (size_t)F, sizeof *er, edge_cmp);
    for (size_t i = 0; i < 3 * (size_t)F;) {
        size_t j = i;
        while (j < 3 * (size_t)F && er[j].key == er[i].key) j++;
        if (er[i].key != UINT64_MAX && j - i == 2 && er[i].dir != er[i + 1].dir && er[i].face != er[i + 1].face) {
            int fa = er[i].face, fb = er[i + 1].face;
            for (int k = 0; k < 3; k++) {
                uint32_t a = (uint32_t)weld[in->faces[3 * (size_t)fa + k]], b = (uint32_t)weld[in->faces[3 * (size_t)fa + (k + 1) % 3]];
                if ((a < b ? ((uint64_t)a << 32 | b) : ((uint64_t)b << 32 | a)) == er[i].key) adj[3 * (size_t)fa + k] = fb;
                a = (uint32_t)weld[in->faces[3 * (size_t)fb + k]], b = (uint32_t)weld[in->faces[3 * (size_t)fb + (k + 1) % 3]];
                if ((a < b ? ((uint64_t)a << 32 | b) : ((uint64_t)b << 32 | a)) == er[i].key) adj[3 * (size_t)fb + k] = fa;
            }
        }
        i = j;
    }
    free(er);
    er = NULL;

    // region growing: seed = the first unassigned non-degenerate face; axis refined from the grown
    // set's area-weighted mean normal (3 rounds); the last round's set becomes the chart
    for (int f = 0; f < F; f++) { fchart[f] = -1; mark[f] = -1; }
    int stamp = 0;
    for (int seed = 0; seed < F; seed++) {
        if (fchart[seed] >= 0 || degen[seed] || dup[seed] >= 0) continue;
        double axis[3] = {fn[3 * seed], fn[3 * seed + 1], fn[3 * seed + 2]};
        int qn = 0;
        for (int round = 0; round < 3; round++) {
            stamp++;
            qn = 0;
            queue[qn++] = seed;
            mark[seed] = stamp;
            for (int qi = 0; qi < qn; qi++) {
                int f = queue[qi];
                for (int k = 0; k < 3; k++) {
                    int g = adj[3 * (size_t)f + k];
                    if (g < 0 || fchart[g] >= 0 || degen[g] || mark[g] == stamp) continue;
                    if (dot3(fn + 3 * g, axis) < cos_max) continue;
                    mark[g] = stamp;
                    queue[qn++] = g;
                }
            }
            if (round == 2) break;
            double m[3] = {0, 0, 0};
            for (int qi = 0; qi < qn; qi++)
                for (int k = 0; k < 3; k++) m[k] += farea[queue[qi]] * fn[3 * queue[qi] + k];
            double l = sqrt(dot3(m, m));
            if (!(l > 0)) break;
            for (int k = 0; k < 3; k++) m[k] /= l;
            if (dot3(fn + 3 * seed, m) < cos_max) break;   // the seed would leave its own chart
            memcpy(axis, m, sizeof axis);
        }
        // `queue` holds the set grown with `axis` (every round ends after a BFS with the axis kept)
        chart* c = chart_new(&L);
        if (!c) goto nomem;
        memcpy(c->axis, axis, sizeof axis);
        for (int qi = 0; qi < qn; qi++) {
            fchart[queue[qi]] = L.n - 1;
            if (!chart_push(c, queue[qi])) goto nomem;
        }
    }
    // degenerate faces join a neighbouring chart: in face order those beside a chart, then breadth-
    // first from them those beside a face that joined (linear: a chain of slivers is one walk, not
    // a pass over the mesh per link); leftovers form one chart
    {
        int qn = 0;
        for (int f = 0; f < F; f++) {
            if (fchart[f] >= 0 || dup[f] >= 0) continue;
            for (int k = 0; k < 3; k++) {
                int g = adj[3 * (size_t)f + k];
                if (g >= 0 && fchart[g] >= 0) {
                    fchart[f] = fchart[g];
                    if (!chart_push(&L.v[fchart[g]], f)) goto nomem;
                    queue[qn++] = f;
                    break;
                }
            }
        }
        for (int qi = 0; qi < qn; qi++) {
            int f = queue[qi];
            for (int k = 0; k < 3; k++) {
                int g = adj[3 * (size_t)f + k];
                if (g < 0 || fchart[g] >= 0 || dup[g] >= 0) continue;
                fchart[g] = fchart[f];
                if (!chart_push(&L.v[fchart[f]], g)) goto nomem;
                queue[qn++] = g;
            }
        }
    }
    {
        int leftover = -1;
        for (int f = 0; f < F; f++) {
            if (fchart[f] >= 0 || dup[f] >= 0) continue;
            if (leftover < 0) {
                chart* c = chart_new(&L);
                if (!c) goto nomem;
                c->axis[2] = 1;
                leftover = L.n - 1;
            }
            fchart[f] = leftover;
            if (!chart_push(&L.v[leftover], f)) goto nomem;
        }
    }

    // overlap check per chart; an overlapping chart is cut in two along the surface (the new part
    // keeps the axis) and both parts are checked again. Only faces with area are checked and
    // counted (a degenerate face covers no texel), so the leftover chart of slivers is never cut.
    int n_split = 0, n_cut = 0;
    for (int ci = 0; ci < L.n; ci++) {
        for (;;) {
            chart* c = &L.v[ci];
            double t1[3], t2[3];
            plane_basis(c->axis, t1, t2);
            double* p = realloc(cuv, sizeof *cuv * (12 * (size_t)c->n + 4));
            if (!p) goto nomem;
            cuv = p;
            int na = 0;   // the chart's faces with area, projected
            for (int i = 0; i < c->n; i++) {
                if (degen[c->faces[i]]) continue;
                for (int k = 0; k < 3; k++) {
                    const float* q = in->pos + 3 * (size_t)weld[in->faces[3 * (size_t)c->faces[i] + k]];
                    double qd[3] = {q[0], q[1], q[2]};
                    cuv[6 * na + 2 * k] = dot3(qd, t1);
                    cuv[6 * na + 2 * k + 1] = dot3(qd, t2);
                }
                na++;
            }
            if (c->n < 2) break;
            int ov = chart_overlaps(cuv, na);
            if (ov < 0) goto nomem;
            if (!ov) {
                // convexity = chart area / hull area: an annulus or a C shape wastes its rectangle
                // in the packing, so a poorly convex chart of MIN_CUT_FACES or more is cut too
                if (na < MIN_CUT_FACES) break;
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
                if (!(ha > 0) || a >= MIN_CONVEXITY * ha) break;
                n_cut++;
            } else n_split++;
            // split along the surface: breadth-first from a far face (the last one reached from
            // the chart's first face), the first half reached stays, the rest is a new chart; a
            // disconnected chart keeps the part reached and every other part becomes a chart of
            // its own, all in one pass (one part at a time was a pass over the chart per part)
            int seed = c->faces[0], whole = 1;
            for (int pass = 0; pass < 2 && whole; pass++) {
                stamp++;
                int qn = 0;
                queue[qn++] = seed;
                mark[seed] = stamp;
                for (int qi = 0; qi < qn; qi++) {
                    int f = queue[qi];
                    for (int k = 0; k < 3; k++) {
                        int g = adj[3 * (size_t)f + k];
                        if (g < 0 || fchart[g] != ci || mark[g] == stamp) continue;
                        mark[g] = stamp;
                        queue[qn++] = g;
                    }
                }
                if (qn < c->n) whole = 0;   // disconnected: the part reached stays
                else if (pass == 0) seed = queue[qn - 1];
                else {                      // keep the first half
                    stamp++;
                    for (int qi = 0; qi < qn / 2; qi++) mark[queue[qi]] = stamp;
                }
            }
            double axis[3];
            memcpy(axis, c->axis, sizeof axis);
            const int n_before = c->n;
            int keep = 0;
            for (int i = 0; i < n_before; i++) {
                int f = L.v[ci].faces[i];
                if (mark[f] == stamp) { L.v[ci].faces[keep++] = f; continue; }
                if (fchart[f] != ci) continue;   // moved with an earlier part
                // f starts the next part: all of it (a connected chart: all the rest) to a new chart
                chart* d = chart_new(&L);
                if (!d) goto nomem;
                memcpy(d->axis, axis, sizeof axis);
                const int id = L.n - 1;
                int qn = 0;
                queue[qn++] = f;
                fchart[f] = id;
                for (int qi = 0; qi < qn; qi++) {
                    int h = queue[qi];
                    if (!chart_push(&L.v[id], h)) goto nomem;
                    for (int k = 0; k < 3 && !whole; k++) {
                        int g = adj[3 * (size_t)h + k];
                        if (g < 0 || fchart[g] != ci || mark[g] == stamp) continue;
                        fchart[g] = id;
                        queue[qn++] = g;
                    }
                }
                if (whole)   // the rest of a connected chart's order, whatever its adjacency
                    for (int j = i + 1; j < n_before; j++) {
                        int h = L.v[ci].faces[j];
                        if (mark[h] == stamp || fchart[h] != ci) continue;
                        fchart[h] = id;
                        if (!chart_push(&L.v[id], h)) goto nomem;
                    }
            }
            L.v[ci].n = keep;
        }
    }

    // the repeated faces join their first copy's chart: the same UVs, the same texels
    for (int f = 0; f < F; f++)
        if (dup[f] >= 0) {
            fchart[f] = fchart[dup[f]];
            if (!chart_push(&L.v[fchart[f]], f)) goto nomem;
        }
    // Every chart takes at least 2·gutter texels a side: more than (size / 2·gutter)² charts
    // cannot fit at any density (16384 at the defaults). Said here, before the packers' bisections
    // spend time on a mesh of disconnected faces.
    if (opt.gutter > 0) {
        double side = floor(opt.texture_size / (2.0 * opt.gutter));
        if ((double)L.n > side * side) {
            st = mlb_fail(MLB_ERR_NUMERIC, "mlb_uv_unwrap: %d charts with a %d-texel gutter do not fit a %d² texture (at "
                          "most %.0f: faces that share no edge with another make a chart each)", L.n, opt.gutter,
                          opt.texture_size, side * side);
            goto done;
        }
    }

    // frames: projection basis, rotation to the minimum-area rectangle, bbox
    fr = calloc((size_t)L.n, sizeof *fr);
    ord = malloc(sizeof *ord * (size_t)L.n);
    if (!fr || !ord) goto nomem;
    for (int ci = 0; ci < L.n; ci++) {
        chart* c = &L.v[ci];
        chart_frame* q = &fr[ci];
        plane_basis(c->axis, q->t1, q->t2);
        // the rotation of the minimum-area bounding rectangle: one of its sides lies along a hull edge
        double* p = realloc(cuv, sizeof *cuv * 12 * (size_t)c->n + 4 * sizeof *cuv);
        if (!p) goto nomem;
        cuv = p;
        double* hull = cuv + 6 * (size_t)c->n;
        for (int i = 0; i < c->n; i++)
            for (int k = 0; k < 3; k++) {
                const float* pp = in->pos + 3 * (size_t)in->faces[3 * (size_t)c->faces[i] + k];
                double pd[3] = {pp[0], pp[1], pp[2]};
                cuv[6 * i + 2 * k] = dot3(pd, q->t1);
                cuv[6 * i + 2 * k + 1] = dot3(pd, q->t2);
            }
        int nh = mlb_uv_convex_hull(cuv, 3 * c->n, hull);
        double best = INFINITY, best_ang = 0;
        for (int e = 0; e < nh; e++) {
            const double *a = hull + 2 * e, *b = hull + 2 * ((e + 1) % nh);
            double ang = atan2(b[1] - a[1], b[0] - a[0]);
            double cs = cos(ang), sn = sin(ang);
            double l0 = 1e300, h0 = -1e300, l1 = 1e300, h1 = -1e300;
            for (int i = 0; i < nh; i++) {
                double x = cs * hull[2 * i] + sn * hull[2 * i + 1], y = -sn * hull[2 * i] + cs * hull[2 * i + 1];
                l0 = MIN2(l0, x); h0 = MAX2(h0, x); l1 = MIN2(l1, y); h1 = MAX2(h1, y);
            }
            double ar = (h0 - l0) * (h1 - l1);
            if (ar < best * (1 - 1e-9)) { best = ar; best_ang = ang; }
        }
        double cs = cos(best_ang), sn = sin(best_ang);
        // rotate by −ang: x' = cs x + sn y, y' = −sn x + cs y (det +1)
        q->r[0] = cs; q->r[1] = sn; q->r[2] = -sn; q->r[3] = cs;
        double lo2[2] = {1e300, 1e300}, hi2[2] = {-1e300, -1e300};
        for (int i = 0; i < c->n; i++)
            for (int k = 0; k < 3; k++) {
                const float* pp = in->pos + 3 * (size_t)in->faces[3 * (size_t)c->faces[i] + k];
                double pd[3] = {pp[0], pp[1], pp[2]};
                double x = dot3(pd, q->t1), y = dot3(pd, q->t2);
                double xr = q->r[0] * x + q->r[1] * y, yr = q->r[2] * x + q->r[3] * y;
                lo2[0] = MIN2(lo2[0], xr); hi2[0] = MAX2(hi2[0], xr);
                lo2[1] = MIN2(lo2[1], yr); hi2[1] = MAX2(hi2[1], yr);
            }
        if (hi2[1] - lo2[1] > hi2[0] - lo2[0]) {   // make it wide: rotate by +90° more, (x, y) → (−y, x)
            double r0 = q->r[0], r1 = q->r[1], r2 = q->r[2], r3 = q->r[3];
            q->r[0] = -r2; q->r[1] = -r3; q->r[2] = r0; q->r[3] = r1;
            double l0 = lo2[0], h0 = hi2[0];
            lo2[0] = -hi2[1]; hi2[0] = -lo2[1];
            lo2[1] = l0; hi2[1] = h0;
        }
        q->x = lo2[0]; q->y = lo2[1];
        q->w = hi2[0] - lo2[0]; q->h = hi2[1] - lo2[1];
        ord[ci] = ci;
    }
    {
        order_key* ok = malloc(sizeof *ok * (size_t)L.n);
        if (!ok) goto nomem;
        for (int ci = 0; ci < L.n; ci++) ok[ci] = (order_key){fr[ci].h, ci};
        qsort(ok, (size_t)L.n, sizeof *ok, order_cmp);
        for (int ci = 0; ci < L.n; ci++) ord[ci] = ok[ci].i;
        free(ok);
    }

    // the largest density s (texels per world unit) at which the skyline packing fits
    const double size = opt.texture_size, gut = opt.gutter;
    sky = malloc(sizeof *sky * (4 * (size_t)L.n + 8));
    wh = malloc(sizeof *wh * 4 * (size_t)L.n);   // [n,2] sizes then [n,2] skyline positions
    if (!sky || !wh) goto nomem;
    for (int ci = 0; ci < L.n; ci++) { wh[2 * ci] = fr[ci].w; wh[2 * ci + 1] = fr[ci].h; }
    double area = 0;
    for (int ci = 0; ci < L.n; ci++) area += fr[ci].w * fr[ci].h;
    if (!mlb_uv_pack_skyline(wh, ord, L.n, 0.0, gut, size, NULL, sky, sky + 2 * (size_t)L.n + 4)) {
        st = mlb_fail(MLB_ERR_NUMERIC, "mlb_uv_unwrap: %d charts with a %d-texel gutter do not fit a %d² texture", L.n,
                      opt.gutter, opt.texture_size);
        goto done;
    }
    double s_lo = 0, s_hi = size / sqrt(area > 0 ? area : 1e-300);
    double wmax = 0;
    for (int ci = 0; ci < L.n; ci++) wmax = MAX2(wmax, fr[ci].w);
    if (wmax > 0) s_hi = MIN2(s_hi, size / wmax);
    for (int it = 0; it < 50; it++) {
        double s = 0.5 * (s_lo + s_hi);
        if (mlb_uv_pack_skyline(wh, ord, L.n, s, gut, size, NULL, sky, sky + 2 * (size_t)L.n + 4)) s_lo = s;
        else s_hi = s;
    }
    double s = s_lo;
    if (!(s > 0)) {
        st = mlb_fail(MLB_ERR_NUMERIC, "mlb_uv_unwrap: %d charts leave no room for texels in a %d² texture", L.n,
                      opt.texture_size);
        goto done;
    }
    mlb_uv_pack_skyline(wh, ord, L.n, s, gut, size, wh + 2 * (size_t)L.n, sky, sky + 2 * (size_t)L.n + 4);
    pl = malloc(sizeof *pl * (size_t)L.n);
    pl_try = malloc(sizeof *pl_try * (size_t)L.n);
    pc = malloc(sizeof *pc * (size_t)L.n);
    ltri = malloc(sizeof *ltri * 6 * (size_t)F);
    if (!pl || !pl_try || !pc || !ltri) goto nomem;
    for (int ci = 0; ci < L.n; ci++) pl[ci] = (mlb_uv_pack_place){wh[2 * (size_t)(L.n + ci)] + gut, wh[2 * (size_t)(L.n + ci) + 1] + gut, 0};

    // then the horizon packer, which fits charts along their outlines: the largest density at which
    // it fits, between the rectangles' density and the bound Σ chart area · s² ≤ size²
    {
        size_t off = 0;
        double chart_area = 0;
        for (int ci = 0; ci < L.n; ci++) {
            const chart_frame* q = &fr[ci];
            // the outline of the faces with area, each surface once (slivers and repeats cover no
            // more, and 80,000 slivers across a chart were 80,000 profiles across its columns)
            int nt = 0;
            for (int i = 0; i < L.v[ci].n; i++) {
                if (degen[L.v[ci].faces[i]] || dup[L.v[ci].faces[i]] >= 0) continue;
                nt++;
                for (int k = 0; k < 3; k++) {
                    const float* pp = in->pos + 3 * (size_t)in->faces[3 * (size_t)L.v[ci].faces[i] + k];
                    double pd[3] = {pp[0], pp[1], pp[2]};
                    double x = dot3(pd, q->t1), y = dot3(pd, q->t2);
                    ltri[off + 2 * k] = MAX2(q->r[0] * x + q->r[1] * y - q->x, 0.0);
                    ltri[off + 2 * k + 1] = MAX2(q->r[2] * x + q->r[3] * y - q->y, 0.0);
                }
                const double* t = ltri + off;
                chart_area += 0.5 * fabs((t[2] - t[0]) * (t[5] - t[1]) - (t[4] - t[0]) * (t[3] - t[1]));
                off += 6;
            }
            pc[ci] = (mlb_uv_pack_chart){ltri + off - 6 * (size_t)nt, nt, q->w, q->h};
        }
        double h_lo = s, h_hi = size / sqrt(chart_area > 0 ? chart_area : 1e-300);
        if (wmax > 0) h_hi = MIN2(h_hi, size / wmax);   // no chart wider than the atlas (all slivers: no area bound)
        // a chart costs the horizon packer a scan of the atlas' columns per quarter turn: past
        // MLB_UV_HORIZON_MAX_CHARTS charts the rectangles' packing is kept (linear time)
        int r = L.n > MLB_UV_HORIZON_MAX_CHARTS ? 0 : mlb_uv_pack_horizon(pc, ord, L.n, h_lo, opt.gutter, opt.texture_size, pl_try);
        if (r < 0) goto nomem;
        if (r == 1) {
            memcpy(pl, pl_try, sizeof *pl * (size_t)L.n);
            for (int it = 0; it < HORIZON_STEPS && h_hi > h_lo * 1.002; it++) {
                double m = 0.5 * (h_lo + h_hi);
                r = mlb_uv_pack_horizon(pc, ord, L.n, m, opt.gutter, opt.texture_size, pl_try);
                if (r < 0) goto nomem;
                if (r == 1) { h_lo = m; memcpy(pl, pl_try, sizeof *pl * (size_t)L.n); }
                else h_hi = m;
            }
            s = h_lo;
        }
    }

    // output: one vertex per (input vertex, chart)
    last_chart = malloc(sizeof *last_chart * (size_t)V);
    newid = malloc(sizeof *newid * (size_t)V);
    if (!last_chart || !newid) goto nomem;
    for (int i = 0; i < V; i++) last_chart[i] = -1;
    int nv = 0;
    for (int ci = 0; ci < L.n; ci++)
        for (int i = 0; i < L.v[ci].n; i++)
            for (int k = 0; k < 3; k++) {
                int v = in->faces[3 * (size_t)L.v[ci].faces[i] + k];
                if (last_chart[v] != ci) { last_chart[v] = ci; nv++; }
            }
    mlb_mesh* om = &out->mesh;
    om->n_verts = nv;
    om->n_faces = F;
    om->pos = malloc(sizeof(float) * 3 * (size_t)nv);
    om->uv = malloc(sizeof(float) * 2 * (size_t)nv);
    om->faces = malloc(sizeof(int32_t) * 3 * (size_t)F);
    out->vert_src = malloc(sizeof(int32_t) * (size_t)nv);
    out->face_chart = malloc(sizeof(int32_t) * (size_t)F);
    if (in->normal) om->normal = malloc(sizeof(float) * 3 * (size_t)nv);
    if (!om->pos || !om->uv || !om->faces || !out->vert_src || !out->face_chart || (in->normal && !om->normal)) goto nomem;
    for (int i = 0; i < V; i++) last_chart[i] = -1;
    int vi = 0;
    for (int ci = 0; ci < L.n; ci++) {
        const chart_frame* q = &fr[ci];
        for (int i = 0; i < L.v[ci].n; i++) {
            int f = L.v[ci].faces[i];
            out->face_chart[f] = ci;
            for (int k = 0; k < 3; k++) {
                int v = in->faces[3 * (size_t)f + k];
                if (last_chart[v] != ci) {
                    last_chart[v] = ci;
                    newid[v] = vi;
                    out->vert_src[vi] = v;
                    memcpy(om->pos + 3 * (size_t)vi, in->pos + 3 * (size_t)v, 3 * sizeof(float));
                    if (om->normal) memcpy(om->normal + 3 * (size_t)vi, in->normal + 3 * (size_t)v, 3 * sizeof(float));
                    double pd[3] = {in->pos[3 * (size_t)v], in->pos[3 * (size_t)v + 1], in->pos[3 * (size_t)v + 2]};
                    double x = dot3(pd, q->t1), y = dot3(pd, q->t2);
                    double xr = MAX2(q->r[0] * x + q->r[1] * y - q->x, 0.0), yr = MAX2(q->r[2] * x + q->r[3] * y - q->y, 0.0);
                    double a, b;
                    pack_rotate(pl[ci].rot, q->w * s, q->h * s, xr * s, yr * s, &a, &b);
                    double u = (pl[ci].x + a) / size, w = (pl[ci].y + b) / size;
                    om->uv[2 * (size_t)vi] = (float)MIN2(MAX2(u, 0.0), 1.0);
                    om->uv[2 * (size_t)vi + 1] = (float)MIN2(MAX2(w, 0.0), 1.0);
                    vi++;
                }
                om->faces[3 * (size_t)f + k] = newid[v];
            }
        }
    }
    out->n_charts = L.n;
    out->texture_size = opt.texture_size;
    if (!om->normal) {
        st = mlb_mesh_compute_normals(om);
        if (st != MLB_OK) goto done;
    }
    if (stats) {
        mlb_uv_measure(out, stats);
        stats->n_split = n_split;
        stats->n_cut = n_cut;
        stats->texels_per_unit = s;
    }
    goto done;

nomem:
    st = mlb_fail(MLB_ERR_NOMEM, "mlb_uv_unwrap: out of memory for %d vertices, %d faces", V, F);
done:
    if (st != MLB_OK) {
        mlb_uv_mesh_free(out);
        if (stats) memset(stats, 0, sizeof *stats);
    }
    free(weld); free(fn); free(farea); free(degen); free(er); free(adj); free(fchart);
    free(mark); free(queue); free(dup); free(fk); free(fr); free(ord); free(cuv); free(last_chart); free(newid); free(sky); free(wh);
    free(pl); free(pl_try); free(pc); free(ltri);
    chart_list_free(&L);
    return st;
}

// Sander et al. 2001: for the map from texture to surface on one triangle, Ss = ∂q/∂s, St = ∂q/∂t;
// Γ, γ = its largest / smallest singular values; L2 = sqrt((Γ² + γ²)/2). Area-weighted by 3D area;
// both normalised by sqrt(Σ A_uv / Σ A_3d) so that a uniform scale does not count.
void mlb_uv_measure(const mlb_uv_mesh* m, mlb_uv_stats* st) {
    if (!st) return;
    memset(st, 0, sizeof *st);
    if (!m || !m->mesh.uv || !m->mesh.pos || !m->mesh.faces) return;
    const mlb_mesh* M = &m->mesh;
    st->n_charts = m->n_charts;
    st->n_verts = M->n_verts;
    st->n_faces = M->n_faces;
    float lo[3], hi[3];
    mlb_mesh_bounds(M, lo, hi);
    double diag = 0;
    for (int k = 0; k < 3; k++) diag += (double)(hi[k] - lo[k]) * (hi[k] - lo[k]);
    diag = sqrt(diag);
    // a face given again (the same vertices in the same turn: the unwrap gives a repeated face its
    // first copy's) covers nothing more: counted once
    face_key* fk = malloc(sizeof *fk * (size_t)M->n_faces);
    uint8_t* again = calloc((size_t)M->n_faces, 1);
    if (fk && again) {
        for (int f = 0; f < M->n_faces; f++) {
            const int32_t* t = M->faces + 3 * (size_t)f;
            int r = (t[1] < t[0] && t[1] <= t[2]) ? 1 : (t[2] < t[0] && t[2] < t[1]) ? 2 : 0;
            fk[f] = (face_key){{t[r], t[(r + 1) % 3], t[(r + 2) % 3]}, f};
        }
        qsort(fk, (size_t)M->n_faces, sizeof *fk, face_key_cmp);
        for (int i = 1; i < M->n_faces; i++) again[fk[i].face] = !memcmp(fk[i].v, fk[i - 1].v, sizeof fk[i].v);
    }
    free(fk);
    double sum_uv = 0, sum_3d = 0, sum_l2 = 0, max_g = 0;
    for (int f = 0; f < M->n_faces; f++) {
        const int rep = again && again[f];
        const int32_t* t = M->faces + 3 * (size_t)f;
        double q[3][3], s[3], tt[3];
        for (int i = 0; i < 3; i++) {
            for (int k = 0; k < 3; k++) q[i][k] = M->pos[3 * (size_t)t[i] + k];
            s[i] = M->uv[2 * (size_t)t[i]];
            tt[i] = M->uv[2 * (size_t)t[i] + 1];
        }
        const float* qf[3] = {M->pos + 3 * (size_t)t[0], M->pos + 3 * (size_t)t[1], M->pos + 3 * (size_t)t[2]};
        double c[3];
        double hgt = face_height(qf, c);
        double a3 = 0.5 * sqrt(dot3(c, c));
        double auv = 0.5 * ((s[1] - s[0]) * (tt[2] - tt[0]) - (s[2] - s[0]) * (tt[1] - tt[0]));
        if (!(hgt >= MLB_UV_DEGENERATE_REL * diag)) { st->n_degenerate++; continue; }
        if (rep) continue;
        sum_uv += fabs(auv);
        sum_3d += a3;
        if (!(auv > 0)) { max_g = INFINITY; sum_l2 = INFINITY; continue; }
        double Ss[3], St[3];
        for (int k = 0; k < 3; k++) {
            Ss[k] = (q[0][k] * (tt[1] - tt[2]) + q[1][k] * (tt[2] - tt[0]) + q[2][k] * (tt[0] - tt[1])) / (2 * auv);
            St[k] = (q[0][k] * (s[2] - s[1]) + q[1][k] * (s[0] - s[2]) + q[2][k] * (s[1] - s[0])) / (2 * auv);
        }
        double a = dot3(Ss, Ss), b = dot3(Ss, St), cc = dot3(St, St);
        double G = sqrt(0.5 * ((a + cc) + sqrt((a - cc) * (a - cc) + 4 * b * b)));
        sum_l2 += 0.5 * (a + cc) * a3;
        max_g = MAX2(max_g, G);
    }
    free(again);
    st->utilisation = sum_uv;
    if (sum_3d > 0) {
        double norm = sqrt(sum_uv / sum_3d);
        st->stretch_l2 = norm * sqrt(sum_l2 / sum_3d);
        st->stretch_linf = norm * max_g;
    }
}
