// The catalogue's procedural shapes (include/matlaber/catalogue.h, docs/catalogue.md): every class is
// a union of closed swept surfaces — lathes (a profile turned about +y, optionally with a
// superellipse cross-section) and tubes (a circle swept along a polyline, rounded caps or a closed
// loop) — then centred and scaled into the generation frame.
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/catalogue.h"
#include "matlaber/rng.h"
#include "catalogue_internal.h"

#define STEP 0.03f          // profile and path points at most this far apart (before scaling)
#define TUBE_SEGMENTS 16    // vertices around a tube
#define CAP_RINGS 4         // rings of a tube's rounded cap

// ---- a growable mesh ------------------------------------------------------------------------------
typedef struct {
    float* pos;       // [nv, 3]
    int32_t* faces;   // [nf, 3]
    uint8_t* part;    // [nf]: the named part each face belongs to (0: none), `part_now` when added
    int nv, nf, cap_v, cap_f;
    int part_now;
    int oom;
} builder;

static int add_vert(builder* b, float x, float y, float z) {
    if (b->nv == b->cap_v) {
        int n = b->cap_v ? 2 * b->cap_v : 1024;
        float* p = realloc(b->pos, sizeof(float) * 3 * (size_t)n);
        if (!p) { b->oom = 1; return 0; }
        b->pos = p, b->cap_v = n;
    }
    float* q = b->pos + 3 * (size_t)b->nv;
    q[0] = x, q[1] = y, q[2] = z;
    return b->nv++;
}

static void add_face(builder* b, int i, int j, int k) {
    if (b->oom) return;
    if (b->nf == b->cap_f) {
        int n = b->cap_f ? 2 * b->cap_f : 2048;
        int32_t* f = realloc(b->faces, sizeof(int32_t) * 3 * (size_t)n);
        if (!f) { b->oom = 1; return; }
        b->faces = f;
        uint8_t* pt = realloc(b->part, (size_t)n);
        if (!pt) { b->oom = 1; return; }
        b->part = pt, b->cap_f = n;
    }
    b->part[b->nf] = (uint8_t)b->part_now;
    int32_t* f = b->faces + 3 * (size_t)b->nf++;
    f[0] = i, f[1] = j, f[2] = k;
}

// Faces from f0 on whose centroid height lies in (y0, y1) become part k: a lathe's stem or shade.
static void part_by_height(builder* b, int f0, float y0, float y1, int k) {
    for (int f = f0; !b->oom && f < b->nf; f++) {
        const int32_t* t = b->faces + 3 * (size_t)f;
        float y = (b->pos[3 * t[0] + 1] + b->pos[3 * t[1] + 1] + b->pos[3 * t[2] + 1]) / 3;
        if (y > y0 && y < y1) b->part[f] = (uint8_t)k;
    }
}

// ---- swept rings ----------------------------------------------------------------------------------
// K rings: ring k has centre c[k], frame (nrm[k], bin[k]) ⟂ the sweep direction, half-widths rad[k] =
// (along nrm, along bin); vertex j of a ring = c + ra·sq(cos φ)·nrm + rb·sq(sin φ)·bin, φ = 2πj/S,
// sq(t) = sign(t)|t|^(2/p) (p = 2: a circle; large p: a rounded rectangle). pole0 / pole1 close the
// ends with fans (NULL with loop = 1: ring K−1 joins ring 0). With tangent t = bin × nrm along the
// sweep, (k, j), (k, j+1), (k+1, j) is counter-clockwise seen from outside (at φ = 0 the face
// normal (∂φ) × t = bin × t = nrm points out), the goblet's winding.
static float sq(float t, float p) { return p == 2.0f ? t : copysignf(powf(fabsf(t), 2.0f / p), t); }

static void sweep(builder* b, int K, const float (*c)[3], const float (*nrm)[3], const float (*bin)[3],
                  const float (*rad)[2], int S, float p, const float* pole0, const float* pole1, int loop) {
    int base = b->nv;
    for (int k = 0; k < K; k++)
        for (int j = 0; j < S; j++) {
            double a = 2 * M_PI * j / S;
            float u = sq((float)cos(a), p) * rad[k][0], v = sq((float)sin(a), p) * rad[k][1];
            add_vert(b, c[k][0] + u * nrm[k][0] + v * bin[k][0], c[k][1] + u * nrm[k][1] + v * bin[k][1],
                     c[k][2] + u * nrm[k][2] + v * bin[k][2]);
        }
#define RV(k, j) (base + (k) * S + ((j) % S))
    for (int k = 0; k + 1 < K + (loop ? 1 : 0); k++) {
        int k1 = (k + 1) % K;
        for (int j = 0; j < S; j++) {
            add_face(b, RV(k, j), RV(k, j + 1), RV(k1, j));
            add_face(b, RV(k, j + 1), RV(k1, j + 1), RV(k1, j));
        }
    }
    if (!loop) {
        int p0 = add_vert(b, pole0[0], pole0[1], pole0[2]);
        int p1 = add_vert(b, pole1[0], pole1[1], pole1[2]);
        for (int j = 0; j < S; j++) add_face(b, p0, RV(0, j + 1), RV(0, j));
        for (int j = 0; j < S; j++) add_face(b, p1, RV(K - 1, j), RV(K - 1, j + 1));
    }
#undef RV
}

// A lathe: profile (r, y) [n] from a point on the axis (r = 0) to another, turned about +y; the
// cross-section is scaled by (sz along z, sx along x) with superellipse exponent p. Segments are
// subdivided to STEP.
static void lathe(builder* b, const float (*prof)[2], int n, float sx, float sz, float p, int S) {
    int cap = 2;
    for (int i = 0; i + 1 < n; i++)
        cap += (int)ceilf(hypotf(prof[i + 1][0] - prof[i][0], prof[i + 1][1] - prof[i][1]) / STEP);
    float(*c)[3] = malloc(sizeof *c * (size_t)cap), (*rad)[2] = malloc(sizeof *rad * (size_t)cap);
    float(*nz)[3] = malloc(sizeof *nz * (size_t)cap), (*bx)[3] = malloc(sizeof *bx * (size_t)cap);
    if (!c || !rad || !nz || !bx) { b->oom = 1; free(c); free(rad); free(nz); free(bx); return; }
    int K = 0;
    for (int i = 0; i + 1 < n; i++) {
        float dr = prof[i + 1][0] - prof[i][0], dy = prof[i + 1][1] - prof[i][1];
        int steps = (int)ceilf(hypotf(dr, dy) / STEP);
        for (int s = 1; s <= steps; s++) {
            if (i + 2 == n && s == steps) break;   // the last point is the top pole
            float t = (float)s / (float)steps, r = prof[i][0] + t * dr;
            c[K][0] = 0, c[K][1] = prof[i][1] + t * dy, c[K][2] = 0;
            rad[K][0] = r * sz, rad[K][1] = r * sx;
            nz[K][0] = 0, nz[K][1] = 0, nz[K][2] = 1;
            bx[K][0] = 1, bx[K][1] = 0, bx[K][2] = 0;
            K++;
        }
    }
    float p0[3] = {0, prof[0][1], 0}, p1[3] = {0, prof[n - 1][1], 0};
    sweep(b, K, (const float(*)[3])c, (const float(*)[3])nz, (const float(*)[3])bx, (const float(*)[2])rad, S, p, p0, p1, 0);
    free(c); free(rad); free(nz); free(bx);
}

static void sub3(float* r, const float* a, const float* b) { for (int k = 0; k < 3; k++) r[k] = a[k] - b[k]; }
static void norm3(float* v) {
    float l = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    if (l > 0) for (int k = 0; k < 3; k++) v[k] /= l;
}
static void cross3(float* r, const float* a, const float* b) {
    r[0] = a[1] * b[2] - a[2] * b[1], r[1] = a[2] * b[0] - a[0] * b[2], r[2] = a[0] * b[1] - a[1] * b[0];
}

// A tube of radius r[i] along the polyline pts[n] (subdivided to STEP), frames by parallel
// transport; rounded caps at both ends, or a closed loop (the last point joins the first).
static void tube(builder* b, const float (*pts)[3], const float* r, int n, int loop) {
    int cap = 2 * CAP_RINGS + 2 + (loop ? 1 : 0);
    for (int i = 0; i + 1 < n + (loop ? 1 : 0); i++) {
        const float *a = pts[i], *e = pts[(i + 1) % n];
        cap += (int)ceilf(sqrtf((e[0] - a[0]) * (e[0] - a[0]) + (e[1] - a[1]) * (e[1] - a[1]) + (e[2] - a[2]) * (e[2] - a[2])) / STEP);
    }
    float(*c)[3] = malloc(sizeof *c * (size_t)cap), (*t)[3] = malloc(sizeof *t * (size_t)cap);
    float(*nv)[3] = malloc(sizeof *nv * (size_t)cap), (*bv)[3] = malloc(sizeof *bv * (size_t)cap);
    float(*rad)[2] = malloc(sizeof *rad * (size_t)cap);
    if (!c || !t || !nv || !bv || !rad) { b->oom = 1; goto done; }
    // densified centres and radii (a loop stops before repeating its first point)
    int m = 0;
    for (int i = 0; i + 1 < n + (loop ? 1 : 0); i++) {
        const float *a = pts[i], *e = pts[(i + 1) % n];
        float ra = r[i], re = r[(i + 1) % n];
        float d[3];
        sub3(d, e, a);
        int steps = (int)ceilf(sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) / STEP);
        if (steps < 1) steps = 1;
        for (int s = (i == 0 ? 0 : 1); s <= steps; s++) {
            if (loop && i + 1 == n && s == steps) break;
            float u = (float)s / (float)steps;
            for (int k = 0; k < 3; k++) c[m][k] = a[k] + u * d[k];
            rad[m][0] = rad[m][1] = ra + u * (re - ra);
            m++;
        }
    }
    if (m < 2) { b->oom = 1; goto done; }   // a path of one point: no tube (not reached by the classes)
    // tangents, then frames by parallel transport from an initial normal ⟂ the first tangent
    for (int i = 0; i < m; i++) {
        int i0 = loop ? (i + m - 1) % m : (i > 0 ? i - 1 : 0), i1 = loop ? (i + 1) % m : (i + 1 < m ? i + 1 : m - 1);
        sub3(t[i], c[i1], c[i0]);
        norm3(t[i]);
    }
    float seed_dir[3] = {0, 0, 1};
    if (fabsf(t[0][2]) > 0.9f) seed_dir[0] = 1, seed_dir[2] = 0;
    for (int i = 0; i < m; i++) {
        const float* prev = i ? nv[i - 1] : seed_dir;
        float d = prev[0] * t[i][0] + prev[1] * t[i][1] + prev[2] * t[i][2];
        for (int k = 0; k < 3; k++) nv[i][k] = prev[k] - d * t[i][k];
        norm3(nv[i]);
        cross3(bv[i], t[i], nv[i]);   // bin = t × nrm: then bin × t = nrm, sweep's outward winding
    }
    if (loop) {
        sweep(b, m, (const float(*)[3])c, (const float(*)[3])nv, (const float(*)[3])bv, (const float(*)[2])rad, TUBE_SEGMENTS, 2, NULL, NULL, 1);
        goto done;
    }
    // rounded caps: rings shrinking on a quarter circle beyond each end, then the poles
    int K = m + 2 * CAP_RINGS;
    memmove(c + CAP_RINGS, c, sizeof *c * (size_t)m);
    memmove(t + CAP_RINGS, t, sizeof *t * (size_t)m);
    memmove(nv + CAP_RINGS, nv, sizeof *nv * (size_t)m);
    memmove(bv + CAP_RINGS, bv, sizeof *bv * (size_t)m);
    memmove(rad + CAP_RINGS, rad, sizeof *rad * (size_t)m);
    for (int q = 0; q < CAP_RINGS; q++) {
        float th = (float)(M_PI / 2 * (CAP_RINGS - q) / (CAP_RINGS + 1));   // from near the pole outwards
        int s0 = q, s1 = K - 1 - q, e0 = CAP_RINGS, e1 = CAP_RINGS + m - 1;
        float r0 = rad[e0][0], r1 = rad[e1][0];
        for (int k = 0; k < 3; k++) {
            c[s0][k] = c[e0][k] - t[e0][k] * r0 * sinf(th);
            c[s1][k] = c[e1][k] + t[e1][k] * r1 * sinf(th);
            nv[s0][k] = nv[e0][k], bv[s0][k] = bv[e0][k], nv[s1][k] = nv[e1][k], bv[s1][k] = bv[e1][k];
        }
        rad[s0][0] = rad[s0][1] = r0 * cosf(th);
        rad[s1][0] = rad[s1][1] = r1 * cosf(th);
    }
    float p0[3], p1[3];
    for (int k = 0; k < 3; k++) {
        p0[k] = c[CAP_RINGS][k] - t[CAP_RINGS][k] * rad[CAP_RINGS][0];
        p1[k] = c[CAP_RINGS + m - 1][k] + t[CAP_RINGS + m - 1][k] * rad[CAP_RINGS + m - 1][0];
    }
    sweep(b, K, (const float(*)[3])c, (const float(*)[3])nv, (const float(*)[3])bv, (const float(*)[2])rad, TUBE_SEGMENTS, 2, p0, p1, 0);
done:
    free(c); free(t); free(nv); free(bv); free(rad);
}

// ---- shape parameters -----------------------------------------------------------------------------
// Parameter k of class c: lo + (hi − lo)·u, u given (clamped to [0, 1]: a fit's search) or drawn
// from the seed: 0.5 for seed 0 (canonical), else Philox.
typedef struct { uint64_t seed; const float* u; int cls, k; } params;
static float seed_fraction(uint64_t seed, int cls, int k) {
    return seed ? (float)mlb_rng_uniform_f64(seed, 0xCA7A0000ull + (uint64_t)cls, (uint64_t)k) : 0.5f;
}
static float P(params* q, float lo, float hi) {
    float u = q->u ? fminf(fmaxf(q->u[q->k], 0.0f), 1.0f) : seed_fraction(q->seed, q->cls, q->k);
    q->k++;
    return lo + (hi - lo) * u;
}

// A quarter ellipse from (r0, y0) to (r1, y1), n points appended to prof at *np (the start excluded):
// out = 1 leaves along y first (a dome, a trumpet), out = 0 along r first (a bowl's underside).
static void arc(float (*prof)[2], int* np, float r0, float y0, float r1, float y1, int n, int out) {
    for (int i = 1; i <= n; i++) {
        double a = M_PI / 2 * i / n;
        float r = out ? r1 + (r0 - r1) * (float)cos(a) : r0 + (r1 - r0) * (float)sin(a);
        float y = out ? y0 + (y1 - y0) * (float)sin(a) : y1 + (y0 - y1) * (float)cos(a);
        prof[*np][0] = r, prof[*np][1] = y, (*np)++;
    }
}
#define PT(r, y) (prof[np][0] = (r), prof[np][1] = (y), np++)

static void goblet(builder* b, params* q) {
    float foot = P(q, 0.38f, 0.48f), stem_r = P(q, 0.08f, 0.13f), stem_h = P(q, 0.35f, 0.55f);
    float cup_r = P(q, 0.42f, 0.55f), cup_h = P(q, 0.55f, 0.75f), bulge = P(q, 0.2f, 0.8f);
    float prof[64][2];
    int np = 0;
    PT(0, 0); PT(foot, 0); PT(foot, 0.06f); PT(stem_r * 1.6f, 0.14f); PT(stem_r, 0.22f);
    float y0 = 0.22f + stem_h;
    PT(stem_r * 0.9f, 0.22f + 0.5f * stem_h); PT(stem_r, y0);
    arc(prof, &np, stem_r, y0, cup_r, y0 + cup_h * (0.4f + 0.4f * bulge), 8, 0);   // out, then up: a bowl
    float top = y0 + cup_h;
    PT(cup_r * 0.97f, top); PT(cup_r * 0.8f, top); PT(cup_r * 0.45f, top - 0.12f); PT(0, top - 0.14f);
    lathe(b, (const float(*)[2])prof, np, 1, 1, 2, MLB_CATALOGUE_SEGMENTS);
    part_by_height(b, 0, 0.14f, y0, 1);   // the stem with its flare: above the foot's slope, below the bowl
}

static void vase(builder* b, params* q) {
    float H = P(q, 1.35f, 1.65f), base = P(q, 0.22f, 0.3f), belly = P(q, 0.5f, 0.62f), belly_y = P(q, 0.35f, 0.45f);
    float neck = P(q, 0.14f, 0.2f), lip = P(q, 0.06f, 0.12f);
    float prof[64][2];
    int np = 0;
    PT(0, 0); PT(base, 0);
    // base → belly → neck → lip: smooth steps (cosine easing) in r along y
    float key[4][2] = {{base, 0}, {belly, belly_y * H}, {neck, 0.82f * H}, {neck + lip, H}};
    for (int s = 0; s < 3; s++)
        for (int i = 1; i <= 8; i++) {
            float t = (float)i / 8, e = 0.5f - 0.5f * cosf((float)M_PI * t);
            PT(key[s][0] + (key[s + 1][0] - key[s][0]) * e, key[s][1] + (key[s + 1][1] - key[s][1]) * t);
        }
    float inner = neck + lip - 0.05f;   // an opening: the rim, then a shallow well
    PT(inner, H); PT(inner * 0.8f, H - 0.15f); PT(0, H - 0.17f);
    lathe(b, (const float(*)[2])prof, np, 1, 1, 2, MLB_CATALOGUE_SEGMENTS);
}

static void bowl(builder* b, params* q) {
    float R = P(q, 0.7f, 1.0f), h = R * P(q, 0.45f, 0.65f), foot = R * P(q, 0.3f, 0.45f), t = 0.06f;
    float prof[64][2];
    int np = 0;
    PT(0, 0); PT(foot, 0); PT(foot, 0.06f);
    arc(prof, &np, foot, 0.06f, R, h, 10, 0);
    PT(R - t, h);
    // inside, from the rim down to the centre (a quarter ellipse inside the outer one)
    for (int i = 1; i <= 10; i++) {
        double a = M_PI / 2 * i / 10;
        PT((R - t) * (float)cos(a), h - (h - 0.06f - t) * (float)sin(a));
    }
    prof[np - 1][0] = 0;
    lathe(b, (const float(*)[2])prof, np, 1, 1, 2, MLB_CATALOGUE_SEGMENTS);
}

// A "C" handle on the side dir (±1 along x) of a wall of radius R: a half ellipse of reach a and
// half-height bh around height yc, its ends sunk into the wall.
static void handle(builder* b, float dir, float R, float yc, float a, float bh, float r) {
    float pts[13][3], rr[13];
    for (int i = 0; i < 13; i++) {
        double th = M_PI / 2 - M_PI * i / 12;
        pts[i][0] = dir * (R - 0.01f + (a + 0.01f) * (float)cos(th));
        pts[i][1] = yc + bh * (float)sin(th);
        pts[i][2] = 0;
        rr[i] = r;
    }
    tube(b, (const float(*)[3])pts, rr, 13, 0);
}

static void mug(builder* b, params* q) {
    float R = P(q, 0.33f, 0.45f), H = P(q, 0.75f, 1.1f), taper = P(q, 0.85f, 1.0f);
    float reach = P(q, 0.18f, 0.28f), hh = P(q, 0.28f, 0.36f), hr = P(q, 0.045f, 0.06f), wall = 0.07f;
    float prof[16][2];
    int np = 0;
    float Rb = R * taper;
    PT(0, 0); PT(Rb - 0.02f, 0); PT(Rb, 0.02f); PT(R, H); PT(R - wall, H); PT(Rb - wall, 0.12f); PT(0, 0.12f);
    lathe(b, (const float(*)[2])prof, np, 1, 1, 2, MLB_CATALOGUE_SEGMENTS);
    b->part_now = 1;
    handle(b, 1, 0.5f * (R + Rb), 0.5f * H, reach, hh * H, hr);
    b->part_now = 0;
}

static void bottle(builder* b, params* q) {
    float R = P(q, 0.3f, 0.38f), Hb = P(q, 0.85f, 1.05f), neck = P(q, 0.07f, 0.1f), sh = P(q, 0.18f, 0.3f);
    float nl = P(q, 0.3f, 0.45f);
    float prof[64][2];
    int np = 0;
    PT(0, 0); PT(R - 0.03f, 0); PT(R, 0.03f); PT(R, Hb);
    for (int i = 1; i <= 8; i++) {   // the shoulder
        float t = (float)i / 8, e = 0.5f - 0.5f * cosf((float)M_PI * t);
        PT(R + (neck - R) * e, Hb + sh * t);
    }
    float top = Hb + sh + nl;
    PT(neck, top - 0.06f); PT(neck + 0.02f, top - 0.05f); PT(neck + 0.02f, top); PT(0, top);   // a cap
    lathe(b, (const float(*)[2])prof, np, 1, 1, 2, MLB_CATALOGUE_SEGMENTS);
}

static void mushroom(builder* b, params* q) {
    float s = P(q, 0.13f, 0.18f), h = P(q, 0.4f, 0.6f), c = P(q, 0.5f, 0.62f), ch = P(q, 0.28f, 0.4f);
    float prof[64][2];
    int np = 0;
    PT(0, 0); PT(s * 1.3f, 0); PT(s * 1.25f, 0.04f); PT(s, h * 0.4f); PT(s * 0.95f, h);
    PT(c * 0.9f, h + 0.04f); PT(c, h + 0.1f);   // gills, the cap's edge
    arc(prof, &np, c, h + 0.1f, 0, h + 0.1f + ch, 12, 1);   // up, then in: a dome
    lathe(b, (const float(*)[2])prof, np, 1, 1, 2, MLB_CATALOGUE_SEGMENTS);
    part_by_height(b, 0, 0.02f, h, 1);   // the stem, less its base disc
}

// A slab: a unit disc profile of thickness th at height y, rounded edge, cross-section scaled.
static void slab(builder* b, float y, float th, float sx, float sz, float p) {
    float e = fminf(0.03f, th / 3);
    float prof[8][2] = {{0, y - th}, {1 - e, y - th}, {1, y - th + e}, {1, y - e}, {1 - e, y}, {0, y}};
    lathe(b, (const float(*)[2])prof, 6, sx, sz, p, 64);
}

static void table(builder* b, params* q) {
    float wx = P(q, 0.8f, 1.0f), wz = P(q, 0.42f, 0.6f), th = P(q, 0.06f, 0.1f), H = P(q, 0.65f, 0.9f);
    float lr = P(q, 0.035f, 0.055f), inset = P(q, 0.06f, 0.14f);
    slab(b, H, th, wx, wz, 8);
    b->part_now = 1;   // the legs
    for (int i = 0; i < 4; i++) {
        float x = (i & 1 ? 1 : -1) * (wx - inset), z = (i & 2 ? 1 : -1) * (wz - inset);
        float pts[2][3] = {{x, lr, z}, {x, H - th * 0.5f, z}}, rr[2] = {lr * 0.8f, lr};
        tube(b, (const float(*)[3])pts, rr, 2, 0);
    }
}

static void stool(builder* b, params* q) {
    float R = P(q, 0.45f, 0.55f), th = P(q, 0.07f, 0.11f), H = P(q, 0.75f, 0.95f), lr = P(q, 0.035f, 0.05f);
    float splay = P(q, 1.1f, 1.3f);
    slab(b, H, th, R, R, 2);
    b->part_now = 1;   // the legs
    for (int i = 0; i < 3; i++) {   // leg 0 to the front (+z)
        double a = 2 * M_PI * i / 3;
        float top_r = 0.7f * R, bot_r = 0.7f * R * splay;
        float pts[2][3] = {{bot_r * (float)sin(a), lr, bot_r * (float)cos(a)},
                           {top_r * (float)sin(a), H - th * 0.5f, top_r * (float)cos(a)}};
        float rr[2] = {lr * 0.85f, lr};
        tube(b, (const float(*)[3])pts, rr, 2, 0);
    }
}

static void lamp(builder* b, params* q) {
    float base = P(q, 0.25f, 0.33f), pole = P(q, 0.03f, 0.045f), ph = P(q, 0.95f, 1.2f);
    float sb = P(q, 0.5f, 0.62f), st = sb * P(q, 0.35f, 0.5f), sh = P(q, 0.42f, 0.55f);
    float prof[16][2];
    int np = 0;
    PT(0, 0); PT(base, 0); PT(base, 0.05f); PT(base * 0.85f, 0.09f); PT(pole * 1.6f, 0.11f); PT(pole, 0.14f);
    PT(pole, ph); PT(sb, ph + 0.02f); PT(sb, ph + 0.05f); PT(st, ph + sh); PT(0, ph + sh);
    lathe(b, (const float(*)[2])prof, np, 1, 1, 2, MLB_CATALOGUE_SEGMENTS);
    part_by_height(b, 0, 0.14f, ph, 1);        // the pole
    part_by_height(b, 0, ph, ph + sh + 1, 2);  // the shade
}

static void ring(builder* b, params* q) {
    float minor = P(q, 0.18f, 0.35f), squash = P(q, 0.85f, 1.0f);
    enum { N = 40 };
    float pts[N][3], rr[N];
    for (int i = 0; i < N; i++) {   // in the xy plane: the hole faces the front camera (+z)
        double a = 2 * M_PI * i / N;
        pts[i][0] = (float)cos(a), pts[i][1] = squash * (float)sin(a), pts[i][2] = 0;
        rr[i] = minor;
    }
    tube(b, (const float(*)[3])pts, rr, N, 1);
    // the hole: the tube's inner half, facing the centre (a filled hole leaves it far from the surface)
    for (int f = 0; f < b->nf; f++) {
        const int32_t* t = b->faces + 3 * (size_t)f;
        float x = 0, y = 0;
        for (int j = 0; j < 3; j++) x += b->pos[3 * t[j]] / 3, y += b->pos[3 * t[j] + 1] / 3;
        if (x * x + (y / squash) * (y / squash) < 1) b->part[f] = 1;
    }
}

static void teapot(builder* b, params* q) {
    float R = P(q, 0.48f, 0.6f), H = P(q, 0.55f, 0.75f), sp = P(q, 0.25f, 0.4f), hr = P(q, 0.04f, 0.055f);
    float knob = P(q, 0.05f, 0.09f);
    float prof[64][2];
    int np = 0;
    PT(0, 0); PT(R * 0.7f, 0); PT(R * 0.72f, 0.03f);
    arc(prof, &np, R * 0.72f, 0.03f, R, 0.45f * H, 6, 0);
    arc(prof, &np, R, 0.45f * H, R * 0.45f, H, 6, 1);
    PT(R * 0.45f, H + 0.03f); PT(knob, H + 0.05f); PT(knob, H + 0.1f);
    arc(prof, &np, knob, H + 0.1f, 0, H + 0.1f + knob, 4, 0);
    lathe(b, (const float(*)[2])prof, np, 1, 1, 2, MLB_CATALOGUE_SEGMENTS);
    // spout on +x: from inside the body up and out, tapering
    float pts[4][3] = {{R * 0.7f, 0.3f * H, 0}, {R + 0.1f, 0.45f * H, 0}, {R + 0.5f * sp, 0.7f * H, 0}, {R + sp, 0.95f * H, 0}};
    float rr[4] = {0.1f, 0.075f, 0.055f, 0.045f};
    b->part_now = 1;
    tube(b, (const float(*)[3])pts, rr, 4, 0);
    b->part_now = 2;
    handle(b, -1, R * 0.93f, 0.5f * H, 0.25f, 0.3f * H, hr);
    b->part_now = 0;
}

typedef void (*shape_fn)(builder*, params*);
static const shape_fn SHAPES[MLB_CATALOGUE_N_CLASSES] = {goblet, vase, bowl, mug, bottle, mushroom, table, stool, lamp, ring, teapot};

// How many parameters each shape function draws (P calls, none conditional); checked at every build.
static const int N_PARAMS[MLB_CATALOGUE_N_CLASSES] = {6, 6, 3, 6, 5, 4, 6, 5, 6, 2, 5};
// The named parts each shape function labels (part 1, 2, ...): the thin ones a generation may lose.
static const char* const PARTS[MLB_CATALOGUE_N_CLASSES][MLB_CATALOGUE_MAX_PARTS] = {
    {"stem"}, {0}, {0}, {"handle"}, {0}, {"stem"}, {"legs"}, {"legs"}, {"stem", "shade"}, {"hole"}, {"spout", "handle"}};

int mlb_catalogue_class_n_parts(int c) {
    int n = 0;
    while (c >= 0 && c < MLB_CATALOGUE_N_CLASSES && n < MLB_CATALOGUE_MAX_PARTS && PARTS[c][n]) n++;
    return n;
}

const char* mlb_catalogue_part_name(int c, int k) {
    return k >= 1 && k <= mlb_catalogue_class_n_parts(c) ? PARTS[c][k - 1] : NULL;
}

int mlb_catalogue_class_n_params(int c) { return c >= 0 && c < MLB_CATALOGUE_N_CLASSES ? N_PARAMS[c] : 0; }

int mlb_catalogue_seed_params(int c, uint64_t seed, float u[MLB_CATALOGUE_MAX_PARAMS]) {
    int n = mlb_catalogue_class_n_params(c);
    for (int k = 0; k < n; k++) u[k] = seed_fraction(seed, c, k);
    return n;
}

static mlb_status build(int c, uint64_t seed, const float* u, mlb_mesh* out, uint8_t** part) {
    if (part) *part = NULL;
    if (!out) return mlb_fail(MLB_ERR_ARG, "mlb_catalogue_mesh: NULL mesh");
    memset(out, 0, sizeof *out);
    if (c < 0 || c >= MLB_CATALOGUE_N_CLASSES)
        return mlb_fail(MLB_ERR_ARG, "catalogue: class %d out of range 0..%d", c, MLB_CATALOGUE_N_CLASSES - 1);
    builder b = {0};
    params q = {seed, u, c, 0};
    SHAPES[c](&b, &q);
    if (q.k != N_PARAMS[c]) {
        free(b.pos); free(b.faces); free(b.part);
        return mlb_fail(MLB_ERR_ARG, "catalogue: a %s draws %d parameters, N_PARAMS says %d", mlb_catalogue_class_name(c), q.k, N_PARAMS[c]);
    }
    if (b.oom || !b.nv || !b.nf) {
        free(b.pos); free(b.faces); free(b.part);
        return mlb_fail(MLB_ERR_NOMEM, "catalogue: out of memory building a %s", mlb_catalogue_class_name(c));
    }
    // into the frame: bounding box centred at the origin, farthest vertex at MLB_CATALOGUE_RADIUS
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int i = 0; i < b.nv; i++)
        for (int k = 0; k < 3; k++) lo[k] = fminf(lo[k], b.pos[3 * i + k]), hi[k] = fmaxf(hi[k], b.pos[3 * i + k]);
    double r2 = 0;
    for (int i = 0; i < b.nv; i++) {
        double s = 0;
        for (int k = 0; k < 3; k++) {
            b.pos[3 * i + k] -= 0.5f * (lo[k] + hi[k]);
            s += (double)b.pos[3 * i + k] * b.pos[3 * i + k];
        }
        if (s > r2) r2 = s;
    }
    float scale = (float)(MLB_CATALOGUE_RADIUS / sqrt(r2));
    for (int i = 0; i < 3 * b.nv; i++) b.pos[i] *= scale;
    out->pos = b.pos;
    out->faces = b.faces;
    out->n_verts = b.nv;
    out->n_faces = b.nf;
    mlb_status s = mlb_mesh_compute_normals(out);
    if (s) mlb_mesh_free(out);
    if (!s && part) *part = b.part;
    else free(b.part);
    return s;
}

mlb_status mlb_catalogue_mesh(int c, uint64_t seed, mlb_mesh* out) { return build(c, seed, NULL, out, NULL); }

mlb_status mlb_catalogue_mesh_params(int c, const float* u, mlb_mesh* out) {
    if (!u) return mlb_fail(MLB_ERR_ARG, "mlb_catalogue_mesh_params: NULL parameters");
    return build(c, 0, u, out, NULL);
}

mlb_status mlb_catalogue_mesh_parts(int c, const float* u, mlb_mesh* out, uint8_t** part) {
    if (!u || !part) return mlb_fail(MLB_ERR_ARG, "mlb_catalogue_mesh_parts: NULL parameters or parts");
    return build(c, 0, u, out, part);
}
