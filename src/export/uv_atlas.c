// UV atlas: the mesh cut into charts (uv_charts.c), each chart's orthographic projection turned to
// its minimum-area rectangle, skyline then horizon packing (uv_pack.c) at a common texel density,
// and the atlas' measures. See uv_atlas.h and docs/uv_atlas.md.
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

// Packing order: decreasing rectangle height, then chart index (no global state: reentrant).
typedef struct { double h; int i; } order_key;
static int order_cmp(const void* a, const void* b) {
    const order_key *x = a, *y = b;
    if (x->h != y->h) return x->h > y->h ? -1 : 1;
    return x->i - y->i;
}

static mlb_status check_unwrap_args(const mlb_mesh* in, const mlb_uv_options* opt) {
    if (opt->texture_size < 8 || opt->texture_size > 65536)
        return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: texture size %d (need 8..65536)", opt->texture_size);
    if (opt->gutter < 0 || opt->gutter > opt->texture_size / 4)
        return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: gutter %d texels (need 0..%d)", opt->gutter, opt->texture_size / 4);
    if (!(opt->max_angle_deg > 0 && opt->max_angle_deg <= 80))
        return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: max angle %g degrees (need (0, 80])", (double)opt->max_angle_deg);
    if (in->n_verts <= 0 || in->n_faces <= 0 || !in->pos || !in->faces)
        return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: empty mesh (%d vertices, %d faces)", in->n_verts, in->n_faces);
    const int V = in->n_verts, F = in->n_faces;
    for (size_t i = 0; i < 3 * (size_t)F; i++)
        if (in->faces[i] < 0 || in->faces[i] >= V)
            return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: face %zu uses vertex %d, mesh has %d", i / 3, (int)in->faces[i], V);
    for (size_t i = 0; i < 3 * (size_t)V; i++)
        if (!isfinite(in->pos[i])) return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: vertex %zu has a non-finite position", i / 3);
    return MLB_OK;
}

// Point p in frame q: projected on the basis, then rotated (not yet moved to the min corner).
static void frame_point(const chart_frame* q, const float* p, double* xr, double* yr) {
    double pd[3] = {p[0], p[1], p[2]};
    double x = mlb_uv_dot3(pd, q->t1), y = mlb_uv_dot3(pd, q->t2);
    *xr = q->r[0] * x + q->r[1] * y;
    *yr = q->r[2] * x + q->r[3] * y;
}

// The angle of the minimum-area bounding rectangle of the convex hull [nh,2]: one of its sides
// lies along a hull edge.
static double min_rect_angle(const double* hull, int nh) {
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
    return best_ang;
}

// Chart c's frame: projection basis, rotation to the minimum-area rectangle (made wide), bbox.
// *cuv: scratch, grown here. 0 when out of memory.
static int frame_chart(const mlb_mesh* in, const mlb_uv_chart* c, chart_frame* q, double** cuv) {
    mlb_uv_plane_basis(c->axis, q->t1, q->t2);
    double* p = realloc(*cuv, sizeof **cuv * 12 * (size_t)c->n + 4 * sizeof **cuv);
    if (!p) return 0;
    *cuv = p;
    double* hull = p + 6 * (size_t)c->n;
    for (int i = 0; i < c->n; i++)
        for (int k = 0; k < 3; k++) {
            const float* pp = in->pos + 3 * (size_t)in->faces[3 * (size_t)c->faces[i] + k];
            double pd[3] = {pp[0], pp[1], pp[2]};
            p[6 * i + 2 * k] = mlb_uv_dot3(pd, q->t1);
            p[6 * i + 2 * k + 1] = mlb_uv_dot3(pd, q->t2);
        }
    int nh = mlb_uv_convex_hull(p, 3 * c->n, hull);
    double best_ang = min_rect_angle(hull, nh);
    double cs = cos(best_ang), sn = sin(best_ang);
    // rotate by −ang: x' = cs x + sn y, y' = −sn x + cs y (det +1)
    q->r[0] = cs; q->r[1] = sn; q->r[2] = -sn; q->r[3] = cs;
    double lo2[2] = {1e300, 1e300}, hi2[2] = {-1e300, -1e300};
    for (int i = 0; i < c->n; i++)
        for (int k = 0; k < 3; k++) {
            double xr, yr;
            frame_point(q, in->pos + 3 * (size_t)in->faces[3 * (size_t)c->faces[i] + k], &xr, &yr);
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
    return 1;
}

// The packing order ord [n] of the frames (order_key). 0 when out of memory.
static int packing_order(const chart_frame* fr, int n, int* ord) {
    order_key* ok = malloc(sizeof *ok * (size_t)n);
    if (!ok) return 0;
    for (int ci = 0; ci < n; ci++) ok[ci] = (order_key){fr[ci].h, ci};
    qsort(ok, (size_t)n, sizeof *ok, order_cmp);
    for (int ci = 0; ci < n; ci++) ord[ci] = ok[ci].i;
    free(ok);
    return 1;
}

static mlb_status unwrap_nomem(const mlb_mesh* in) {
    return mlb_fail(MLB_ERR_NOMEM, "mlb_uv_unwrap: out of memory for %d vertices, %d faces", in->n_verts, in->n_faces);
}

static double widest(const chart_frame* fr, int n) {
    double wmax = 0;
    for (int ci = 0; ci < n; ci++) wmax = MAX2(wmax, fr[ci].w);
    return wmax;
}

// The largest density *s (texels per world unit) at which the skyline packing of the frames'
// rectangles fits, found by bisection, and the charts' places at it (pl [n], unturned).
static mlb_status skyline_pack(const mlb_mesh* in, const chart_frame* fr, const int* ord, int n, const mlb_uv_options* opt,
                               double* s_out, mlb_uv_pack_place* pl) {
    const double size = opt->texture_size, gut = opt->gutter;
    mlb_status st = MLB_OK;
    mlb_uv_sky_seg* sky = malloc(sizeof *sky * (4 * (size_t)n + 8));
    double* wh = malloc(sizeof *wh * 4 * (size_t)n);   // [n,2] sizes then [n,2] skyline positions
    if (!sky || !wh) { st = unwrap_nomem(in); goto done; }
    mlb_uv_sky_seg* tmp = sky + 2 * (size_t)n + 4;
    for (int ci = 0; ci < n; ci++) { wh[2 * ci] = fr[ci].w; wh[2 * ci + 1] = fr[ci].h; }
    double area = 0;
    for (int ci = 0; ci < n; ci++) area += fr[ci].w * fr[ci].h;
    if (!mlb_uv_pack_skyline(wh, ord, n, 0.0, gut, size, NULL, sky, tmp)) {
        st = mlb_fail(MLB_ERR_NUMERIC, "mlb_uv_unwrap: %d charts with a %d-texel gutter do not fit a %d² texture", n,
                      opt->gutter, opt->texture_size);
        goto done;
    }
    double s_lo = 0, s_hi = size / sqrt(area > 0 ? area : 1e-300);
    double wmax = widest(fr, n);
    if (wmax > 0) s_hi = MIN2(s_hi, size / wmax);
    for (int it = 0; it < 50; it++) {
        double s = 0.5 * (s_lo + s_hi);
        if (mlb_uv_pack_skyline(wh, ord, n, s, gut, size, NULL, sky, tmp)) s_lo = s;
        else s_hi = s;
    }
    double s = s_lo;
    if (!(s > 0)) {
        st = mlb_fail(MLB_ERR_NUMERIC, "mlb_uv_unwrap: %d charts leave no room for texels in a %d² texture", n,
                      opt->texture_size);
        goto done;
    }
    mlb_uv_pack_skyline(wh, ord, n, s, gut, size, wh + 2 * (size_t)n, sky, tmp);
    for (int ci = 0; ci < n; ci++) pl[ci] = (mlb_uv_pack_place){wh[2 * (size_t)(n + ci)] + gut, wh[2 * (size_t)(n + ci) + 1] + gut, 0};
    *s_out = s;
done:
    free(sky);
    free(wh);
    return st;
}

// Each chart's outline for the horizon packer: its faces with area in its frame (min corner 0),
// each surface once (slivers and repeats cover no more, and 80,000 slivers across a chart were
// 80,000 profiles across its columns). ltri [F,3,2] holds the triangles; returns their total area.
static double chart_outlines(const mlb_mesh* in, const mlb_uv_charts* C, const chart_frame* fr, double* ltri,
                             mlb_uv_pack_chart* pc) {
    size_t off = 0;
    double chart_area = 0;
    for (int ci = 0; ci < C->n; ci++) {
        const chart_frame* q = &fr[ci];
        const mlb_uv_chart* c = &C->v[ci];
        int nt = 0;
        for (int i = 0; i < c->n; i++) {
            if (C->degen[c->faces[i]] || C->dup[c->faces[i]] >= 0) continue;
            nt++;
            for (int k = 0; k < 3; k++) {
                double xr, yr;
                frame_point(q, in->pos + 3 * (size_t)in->faces[3 * (size_t)c->faces[i] + k], &xr, &yr);
                ltri[off + 2 * k] = MAX2(xr - q->x, 0.0);
                ltri[off + 2 * k + 1] = MAX2(yr - q->y, 0.0);
            }
            const double* t = ltri + off;
            chart_area += 0.5 * fabs((t[2] - t[0]) * (t[5] - t[1]) - (t[4] - t[0]) * (t[3] - t[1]));
            off += 6;
        }
        pc[ci] = (mlb_uv_pack_chart){ltri + off - 6 * (size_t)nt, nt, q->w, q->h};
    }
    return chart_area;
}

// Then the horizon packer, which fits charts along their outlines: the largest density at which
// it fits, between the rectangles' density *s and the bound Σ chart area · s² ≤ size². When it
// fits at *s, *s and pl become its.
static mlb_status horizon_pack(const mlb_mesh* in, const mlb_uv_charts* C, const chart_frame* fr, const int* ord,
                               const mlb_uv_options* opt, double* s, mlb_uv_pack_place* pl) {
    const int n = C->n;
    const double size = opt->texture_size;
    mlb_status st = MLB_OK;
    mlb_uv_pack_place* pl_try = malloc(sizeof *pl_try * (size_t)n);
    mlb_uv_pack_chart* pc = malloc(sizeof *pc * (size_t)n);
    double* ltri = malloc(sizeof *ltri * 6 * (size_t)in->n_faces);
    if (!pl_try || !pc || !ltri) { st = unwrap_nomem(in); goto done; }
    double chart_area = chart_outlines(in, C, fr, ltri, pc);
    double h_lo = *s, h_hi = size / sqrt(chart_area > 0 ? chart_area : 1e-300);
    double wmax = widest(fr, n);
    if (wmax > 0) h_hi = MIN2(h_hi, size / wmax);   // no chart wider than the atlas (all slivers: no area bound)
    // a chart costs the horizon packer a scan of the atlas' columns per quarter turn: past
    // MLB_UV_HORIZON_MAX_CHARTS charts the rectangles' packing is kept (linear time)
    int r = n > MLB_UV_HORIZON_MAX_CHARTS ? 0 : mlb_uv_pack_horizon(pc, ord, n, h_lo, opt->gutter, opt->texture_size, pl_try);
    if (r < 0) { st = unwrap_nomem(in); goto done; }
    if (r == 1) {
        memcpy(pl, pl_try, sizeof *pl * (size_t)n);
        for (int it = 0; it < HORIZON_STEPS && h_hi > h_lo * 1.002; it++) {
            double m = 0.5 * (h_lo + h_hi);
            r = mlb_uv_pack_horizon(pc, ord, n, m, opt->gutter, opt->texture_size, pl_try);
            if (r < 0) { st = unwrap_nomem(in); goto done; }
            if (r == 1) { h_lo = m; memcpy(pl, pl_try, sizeof *pl * (size_t)n); }
            else h_hi = m;
        }
        *s = h_lo;
    }
done:
    free(pl_try);
    free(pc);
    free(ltri);
    return st;
}

// Vertex p's uv in the atlas: in its chart's frame, at density s, turned and placed by pl.
static void atlas_uv(const chart_frame* q, const mlb_uv_pack_place* pl, double s, double size, const float* p, float* uv) {
    double x, y;
    frame_point(q, p, &x, &y);
    double xr = MAX2(x - q->x, 0.0), yr = MAX2(y - q->y, 0.0);
    double a, b;
    pack_rotate(pl->rot, q->w * s, q->h * s, xr * s, yr * s, &a, &b);
    double u = (pl->x + a) / size, w = (pl->y + b) / size;
    uv[0] = (float)MIN2(MAX2(u, 0.0), 1.0);
    uv[1] = (float)MIN2(MAX2(w, 0.0), 1.0);
}

// The output mesh: one vertex per (input vertex, chart), in chart order, with its atlas uv.
static mlb_status write_atlas(const mlb_mesh* in, const mlb_uv_charts* C, const chart_frame* fr, const mlb_uv_pack_place* pl,
                              double s, const mlb_uv_options* opt, mlb_uv_mesh* out) {
    const int V = in->n_verts, F = in->n_faces;
    mlb_status st = MLB_OK;
    int32_t* last_chart = malloc(sizeof *last_chart * (size_t)V);
    int32_t* newid = malloc(sizeof *newid * (size_t)V);
    if (!last_chart || !newid) { st = unwrap_nomem(in); goto done; }
    for (int i = 0; i < V; i++) last_chart[i] = -1;
    int nv = 0;
    for (int ci = 0; ci < C->n; ci++)
        for (int i = 0; i < C->v[ci].n; i++)
            for (int k = 0; k < 3; k++) {
                int v = in->faces[3 * (size_t)C->v[ci].faces[i] + k];
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
    if (!om->pos || !om->uv || !om->faces || !out->vert_src || !out->face_chart || (in->normal && !om->normal)) {
        st = unwrap_nomem(in);
        goto done;
    }
    for (int i = 0; i < V; i++) last_chart[i] = -1;
    int vi = 0;
    for (int ci = 0; ci < C->n; ci++)
        for (int i = 0; i < C->v[ci].n; i++) {
            int f = C->v[ci].faces[i];
            out->face_chart[f] = ci;
            for (int k = 0; k < 3; k++) {
                int v = in->faces[3 * (size_t)f + k];
                if (last_chart[v] != ci) {
                    last_chart[v] = ci;
                    newid[v] = vi;
                    out->vert_src[vi] = v;
                    memcpy(om->pos + 3 * (size_t)vi, in->pos + 3 * (size_t)v, 3 * sizeof(float));
                    if (om->normal) memcpy(om->normal + 3 * (size_t)vi, in->normal + 3 * (size_t)v, 3 * sizeof(float));
                    atlas_uv(&fr[ci], &pl[ci], s, opt->texture_size, in->pos + 3 * (size_t)v, om->uv + 2 * (size_t)vi);
                    vi++;
                }
                om->faces[3 * (size_t)f + k] = newid[v];
            }
        }
    out->n_charts = C->n;
    out->texture_size = opt->texture_size;
    if (!om->normal) st = mlb_mesh_compute_normals(om);
done:
    free(last_chart);
    free(newid);
    return st;
}

mlb_status mlb_uv_unwrap(const mlb_mesh* in, const mlb_uv_options* opt_in, mlb_uv_mesh* out, mlb_uv_stats* stats) {
    if (out) memset(out, 0, sizeof *out);
    if (stats) memset(stats, 0, sizeof *stats);
    if (!in || !out) return mlb_fail(MLB_ERR_ARG, "mlb_uv_unwrap: NULL mesh");
    mlb_uv_options opt = opt_in ? *opt_in : mlb_uv_default();
    MLB_TRY(check_unwrap_args(in, &opt));

    mlb_status st = MLB_OK;
    mlb_uv_charts C;
    if (!mlb_uv_make_charts(in, cos(opt.max_angle_deg * M_PI / 180.0), &C)) return unwrap_nomem(in);
    const int n = C.n;
    chart_frame* fr = NULL;
    int* ord = NULL;
    double* cuv = NULL;
    mlb_uv_pack_place* pl = NULL;
    // Every chart takes at least 2·gutter texels a side: more than (size / 2·gutter)² charts
    // cannot fit at any density (16384 at the defaults). Said here, before the packers' bisections
    // spend time on a mesh of disconnected faces.
    if (opt.gutter > 0) {
        double side = floor(opt.texture_size / (2.0 * opt.gutter));
        if ((double)n > side * side) {
            st = mlb_fail(MLB_ERR_NUMERIC, "mlb_uv_unwrap: %d charts with a %d-texel gutter do not fit a %d² texture (at "
                          "most %.0f: faces that share no edge with another make a chart each)", n, opt.gutter,
                          opt.texture_size, side * side);
            goto done;
        }
    }

    fr = calloc((size_t)n, sizeof *fr);
    ord = malloc(sizeof *ord * (size_t)n);
    pl = malloc(sizeof *pl * (size_t)n);
    if (!fr || !ord || !pl) goto nomem;
    for (int ci = 0; ci < n; ci++)
        if (!frame_chart(in, &C.v[ci], &fr[ci], &cuv)) goto nomem;
    if (!packing_order(fr, n, ord)) goto nomem;
    double s = 0;
    if ((st = skyline_pack(in, fr, ord, n, &opt, &s, pl)) != MLB_OK) goto done;
    if ((st = horizon_pack(in, &C, fr, ord, &opt, &s, pl)) != MLB_OK) goto done;
    if ((st = write_atlas(in, &C, fr, pl, s, &opt, out)) != MLB_OK) goto done;
    if (stats) {
        mlb_uv_measure(out, stats);
        stats->n_split = C.n_split;
        stats->n_cut = C.n_cut;
        stats->texels_per_unit = s;
    }
    goto done;

nomem:
    st = unwrap_nomem(in);
done:
    if (st != MLB_OK) {
        mlb_uv_mesh_free(out);
        if (stats) memset(stats, 0, sizeof *stats);
    }
    free(fr); free(ord); free(cuv); free(pl);
    mlb_uv_charts_free(&C);
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
    mlb_uv_face_key* fk = malloc(sizeof *fk * (size_t)M->n_faces);
    uint8_t* again = calloc((size_t)M->n_faces, 1);
    if (fk && again) {
        mlb_uv_face_keys(M->faces, NULL, M->n_faces, fk);
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
        double hgt = mlb_uv_face_height(qf, c);
        double a3 = 0.5 * sqrt(mlb_uv_dot3(c, c));
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
        double a = mlb_uv_dot3(Ss, Ss), b = mlb_uv_dot3(Ss, St), cc = mlb_uv_dot3(St, St);
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
