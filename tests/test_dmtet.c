// DMTet: the tet grid (orientation, conformity, volume, edges), marching tetrahedra on analytic
// SDFs (closed manifold meshes, topology, outward faces, distance to the surface), and
// finite-difference checks (double) of the marching-tets, deformation and regulariser backward;
// the passes of mt_ops.h: the packed tables and edge slots, the GPU's gathered backward against the
// CPU's scatter and the op-table path against marching_tets_forward, bit for bit.
#include <stdint.h>
#include "matlaber/backend_f64.h"
#include "geometry/mt_device_f64.h"
#include "matlaber/dmtet.h"
#include "matlaber/mt_ops.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"
#include "test.h"
typedef float real;   // the scalar of the maths header (only its integer functions are used here)
#define R_EXP expf
#define R_LOG1P log1pf
#define R_FABS fabsf
#include "mesh/marching_tets_math.h"

static double signed_vol6(const float* a, const float* b, const float* c, const float* d) {
    double u[3], v[3], w[3];
    for (int k = 0; k < 3; k++) { u[k] = b[k] - a[k]; v[k] = c[k] - a[k]; w[k] = d[k] - a[k]; }
    return u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) + u[2] * (v[0] * w[1] - v[1] * w[0]);
}

static int cmp_u64(const void* a, const void* b) {
    uint64_t x = *(const uint64_t*)a, y = *(const uint64_t*)b;
    return x < y ? -1 : x > y;
}
static void sort3(int32_t* v) {
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2 - i; j++)
            if (v[j] > v[j + 1]) { int32_t t = v[j]; v[j] = v[j + 1]; v[j + 1] = t; }
}

TEST(tetgrid_structure) {
    const int cells = 4;
    const float scale = 2.1f;
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, cells, scale) == MLB_OK);
    CHECK(g.n_verts == 125 && g.n_tets == 6 * 64);
    // unique edges: 3 axis, 3 face-diagonal and 1 body-diagonal directions
    CHECK(g.n_edges == 3 * 4 * 25 + 3 * 16 * 5 + 64);
    double vol = 0, hcell = scale / cells;
    for (int t = 0; t < g.n_tets; t++) {
        const int32_t* v = g.tets + 4 * t;
        double s = signed_vol6(g.verts + 3 * v[0], g.verts + 3 * v[1], g.verts + 3 * v[2], g.verts + 3 * v[3]);
        CHECK_MSG(s > 0, "tet %d volume*6 = %g", t, s);
        CHECK_CLOSE(s, hcell * hcell * hcell, 1e-4, 0);   // each Kuhn tet is 1/6 of a cell
        vol += s / 6;
    }
    CHECK_CLOSE(vol, (double)scale * scale * scale, 1e-5, 0);
    // Faces: interior ones shared by exactly two tets, those on the cube's boundary by one.
    int64_t nf = 4 * (int64_t)g.n_tets;
    uint64_t* keys = malloc(sizeof(uint64_t) * nf);
    const int n = cells + 1;
    for (int t = 0; t < g.n_tets; t++)
        for (int f = 0; f < 4; f++) {
            int32_t tri[3], m = 0;
            for (int c = 0; c < 4; c++) if (c != f) tri[m++] = g.tets[4 * t + c];
            sort3(tri);
            keys[4 * t + f] = ((uint64_t)tri[0] << 42) | ((uint64_t)tri[1] << 21) | (uint64_t)tri[2];
        }
    qsort(keys, nf, sizeof *keys, cmp_u64);
    int bad = 0, n_boundary = 0;
    for (int64_t i = 0; i < nf;) {
        int64_t j = i;
        while (j < nf && keys[j] == keys[i]) j++;
        int32_t tri[3] = {(int32_t)(keys[i] >> 42), (int32_t)((keys[i] >> 21) & 0x1fffff), (int32_t)(keys[i] & 0x1fffff)};
        int on_boundary = 0;
        for (int d = 0; d < 3; d++) {
            int lo = 1, hi = 1;
            for (int c = 0; c < 3; c++) {
                int coord = d == 0 ? tri[c] % n : d == 1 ? (tri[c] / n) % n : tri[c] / (n * n);
                lo &= coord == 0;
                hi &= coord == cells;
            }
            on_boundary |= lo | hi;
        }
        if ((int)(j - i) != (on_boundary ? 1 : 2)) bad++;
        n_boundary += on_boundary;
        i = j;
    }
    CHECK(bad == 0);
    CHECK(n_boundary == 6 * cells * cells * 2);
    free(keys);
    // Every tet edge is a listed grid edge; the edge list is exactly the set of tet edges.
    char* seen = calloc(7 * (size_t)g.n_verts, 1);
    for (int t = 0; t < g.n_tets; t++)
        for (int e = 0; e < 6; e++) {
            int64_t id = mlb_tetgrid_edge_id(&g, g.tets[4 * t + mlb_mt_tet_edges[e][0]], g.tets[4 * t + mlb_mt_tet_edges[e][1]]);
            REQUIRE(id >= 0 && id < 7 * (int64_t)g.n_verts);
            seen[id] = 1;
        }
    int listed = 0, n_seen = 0;
    for (int e = 0; e < g.n_edges; e++) {
        CHECK(g.edges[2 * e] < g.edges[2 * e + 1]);
        int64_t id = mlb_tetgrid_edge_id(&g, g.edges[2 * e], g.edges[2 * e + 1]);
        listed += id >= 0 && seen[id];
    }
    for (int64_t i = 0; i < 7 * (int64_t)g.n_verts; i++) n_seen += seen[i];
    CHECK(listed == g.n_edges && n_seen == g.n_edges);
    CHECK(mlb_tetgrid_edge_id(&g, 0, 2) == -1);
    free(seen);
    mlb_tetgrid_free(&g);
    CHECK(mlb_tetgrid_create(&g, 0, 1.f) == MLB_ERR_ARG);
}

// Closed, consistently oriented 2-manifold: every directed edge once and its reverse once.
// Returns the Euler characteristic through *chi.
static int check_closed_manifold(const mlb_mt_surface* s, int* chi) {
    int64_t m = 3 * (int64_t)s->n_faces;
    uint64_t* dir = malloc(sizeof(uint64_t) * (m ? m : 1));
    for (int f = 0; f < s->n_faces; f++)
        for (int c = 0; c < 3; c++)
            dir[3 * f + c] = ((uint64_t)s->faces[3 * f + c] << 32) | (uint32_t)s->faces[3 * f + (c + 1) % 3];
    qsort(dir, m, sizeof *dir, cmp_u64);
    int ok = 1;
    for (int64_t i = 0; i < m; i++) {
        uint32_t a = (uint32_t)(dir[i] >> 32), b = (uint32_t)dir[i];
        if (a == b || (i + 1 < m && dir[i + 1] == dir[i])) ok = 0;   // degenerate or repeated direction
        uint64_t rev = ((uint64_t)b << 32) | a;
        if (!bsearch(&rev, dir, m, sizeof *dir, cmp_u64)) ok = 0;     // open edge or flipped neighbour
    }
    free(dir);
    *chi = s->n_verts - (int)(m / 2) + s->n_faces;
    return ok;
}

static void sdf_grid(const mlb_tetgrid* g, float* sdf, int torus) {
    for (int v = 0; v < g->n_verts; v++) {
        const float* p = g->verts + 3 * v;
        if (torus) {
            float q = sqrtf(p[0] * p[0] + p[2] * p[2]) - 0.5f;
            sdf[v] = sqrtf(q * q + p[1] * p[1]) - 0.2f;
        } else {
            sdf[v] = sqrtf(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) - 0.6f;
        }
    }
}

TEST(sphere_closed_outward_close) {
    const int cells = 24;
    const float scale = 2.1f, r = 0.6f;
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, cells, scale) == MLB_OK);
    float* sdf = malloc(sizeof(float) * g.n_verts);
    sdf_grid(&g, sdf, 0);
    mlb_mt_surface s;
    REQUIRE(marching_tets_forward(&s, &g, g.verts, sdf) == MLB_OK);
    CHECK(s.n_verts > 100 && s.n_faces > 200);
    int chi;
    CHECK(check_closed_manifold(&s, &chi));
    CHECK(chi == 2);
    // Outward: the enclosed signed volume is positive (≈ the sphere's) and every face normal
    // points away from the centre.
    double vol = 0;
    int inward = 0;
    for (int f = 0; f < s.n_faces; f++) {
        const float *a = s.pos + 3 * s.faces[3 * f], *b = s.pos + 3 * s.faces[3 * f + 1], *c = s.pos + 3 * s.faces[3 * f + 2];
        const float o[3] = {0, 0, 0};
        double v6 = signed_vol6(o, a, b, c);
        vol += v6 / 6;
        if (v6 <= 0) inward++;
    }
    CHECK(inward == 0);
    CHECK_CLOSE(vol, 4.0 / 3.0 * M_PI * r * r * r, 0.05, 0);
    // Distance: a vertex is the zero of the linear interpolant of f(x) = |x| − r along a grid edge of
    // length ℓ ≤ √3·h (the body diagonal). f is convex, so its chord lies above it: f(v) ≤ 0. And
    // f'' ≤ ℓ²/ρ along the edge (ρ = the least |x| on it ≥ r − ℓ), so the chord exceeds f by at most
    // ℓ²/(8ρ): −ℓ²/(8(r − ℓ)) ≤ |v| − r ≤ 0.
    double hcell = scale / cells, l = sqrt(3.0) * hcell, bound = l * l / (8 * (r - l)), worst = 0;
    for (int i = 0; i < s.n_verts; i++) {
        const float* p = s.pos + 3 * i;
        double d = sqrt((double)p[0] * p[0] + (double)p[1] * p[1] + (double)p[2] * p[2]) - r;
        CHECK_MSG(d <= 1e-5 && d >= -bound - 1e-5, "vertex %d at distance %g (bound %g)", i, d, bound);
        if (-d > worst) worst = -d;
    }
    printf("  sphere: %d verts, %d faces, max |v| - r = %.4g (bound %.4g, cell %.4g)\n", s.n_verts, s.n_faces, -worst, -bound, hcell);
    // Welded: no two vertices at the same place.
    mlb_mesh mesh;
    REQUIRE(mt_surface_to_mesh(&s, &mesh) == MLB_OK);
    CHECK(mesh.n_verts == s.n_verts && mesh.n_faces == s.n_faces && mesh.pos[5] == s.pos[5]);
    mlb_mesh_free(&mesh);
    // Same output on 1 and 2 threads.
    int saved = mlb_get_threads();
    mlb_set_threads(1);
    mlb_mt_surface s1;
    REQUIRE(marching_tets_forward(&s1, &g, g.verts, sdf) == MLB_OK);
    mlb_set_threads(saved);
    CHECK(s1.n_faces == s.n_faces && memcmp(s1.faces, s.faces, sizeof(int32_t) * 3 * s.n_faces) == 0);
    CHECK(memcmp(s1.pos, s.pos, sizeof(float) * 3 * s.n_verts) == 0);
    mt_surface_free(&s1);
    mt_surface_free(&s);
    free(sdf);
    mlb_tetgrid_free(&g);
}

TEST(torus_genus_one) {
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 32, 2.1f) == MLB_OK);
    float* sdf = malloc(sizeof(float) * g.n_verts);
    sdf_grid(&g, sdf, 1);
    mlb_mt_surface s;
    REQUIRE(marching_tets_forward(&s, &g, g.verts, sdf) == MLB_OK);
    int chi;
    CHECK(check_closed_manifold(&s, &chi));
    CHECK_MSG(chi == 0, "Euler characteristic %d", chi);
    mt_surface_free(&s);
    // All outside / all inside: empty surfaces.
    for (int v = 0; v < g.n_verts; v++) sdf[v] = 1;
    REQUIRE(marching_tets_forward(&s, &g, g.verts, sdf) == MLB_OK);
    CHECK(s.n_verts == 0 && s.n_faces == 0);
    mt_surface_free(&s);
    free(sdf);
    mlb_tetgrid_free(&g);
}

// L = Σ r·v over the marching-tets vertices of the deformed grid: gradients to the SDF values and
// the deformation, against central differences in double.
TEST(marching_tets_backward_fd) {
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 3, 1.0f) == MLB_OK);
    const int V = g.n_verts;
    double* grid = malloc(sizeof(double) * 3 * V);
    double* def = malloc(sizeof(double) * 3 * V);
    double* pos = malloc(sizeof(double) * 3 * V);
    double* sdf = malloc(sizeof(double) * V);
    for (int i = 0; i < 3 * V; i++) { grid[i] = g.verts[i]; def[i] = mlb_rng_normal_f64(1, 1, i); }
    for (int v = 0; v < V; v++) {
        const double* p = grid + 3 * v;
        double s = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) - 0.4 + 0.1 * mlb_rng_normal_f64(1, 2, v);
        if (fabs(s) < 1e-3) s = 1e-3;   // away from 0: the topology is fixed under the FD step
        sdf[v] = s;
    }
    const double res = 6;
    dmtet_deform_forward_f64(pos, grid, def, V, res);
    mlb_mt_surface_f64 s;
    REQUIRE(marching_tets_forward_f64(&s, &g, pos, sdf) == MLB_OK);
    REQUIRE(s.n_verts > 4);
    const int M = s.n_verts;
    double* r = malloc(sizeof(double) * 3 * M);
    for (int i = 0; i < 3 * M; i++) r[i] = mlb_rng_normal_f64(1, 3, i);
    double* dpos = calloc(3 * V, sizeof(double));
    double* dsdf = calloc(V, sizeof(double));
    double* ddef = calloc(3 * V, sizeof(double));
    marching_tets_backward_f64(dpos, dsdf, &s, pos, sdf, r);
    dmtet_deform_backward_f64(NULL, ddef, dpos, def, V, res);
    mt_surface_free_f64(&s);
#define LOSS(out) do { mlb_mt_surface_f64 s_; dmtet_deform_forward_f64(pos, grid, def, V, res); \
    marching_tets_forward_f64(&s_, &g, pos, sdf); REQUIRE(s_.n_verts == M); out = 0; \
    for (int i_ = 0; i_ < 3 * M; i_++) { out += r[i_] * s_.pos[i_]; } mt_surface_free_f64(&s_); } while (0)
    const double h = 1e-6;
    int nonzero = 0;
    for (int v = 0; v < V; v++) {
        double keep = sdf[v], lp, lm;
        sdf[v] = keep + h; LOSS(lp);
        sdf[v] = keep - h; LOSS(lm);
        sdf[v] = keep;
        CHECK_CLOSE(dsdf[v], (lp - lm) / (2 * h), 1e-5, 1e-7);
        nonzero += dsdf[v] != 0;
    }
    for (int i = 0; i < 3 * V; i++) {
        double keep = def[i], lp, lm;
        def[i] = keep + h; LOSS(lp);
        def[i] = keep - h; LOSS(lm);
        def[i] = keep;
        CHECK_CLOSE(ddef[i], (lp - lm) / (2 * h), 1e-5, 1e-8);
    }
#undef LOSS
    CHECK(nonzero > 4);
    free(grid); free(def); free(pos); free(sdf); free(r); free(dpos); free(dsdf); free(ddef);
    mlb_tetgrid_free(&g);
}

TEST(sdf_regulariser) {
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 4, 1.0f) == MLB_OK);
    const int V = g.n_verts;
    double* sdf = malloc(sizeof(double) * V);
    for (int v = 0; v < V; v++) {
        const float* p = g.verts + 3 * v;
        sdf[v] = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) - 0.3 + 0.2 * mlb_rng_normal_f64(2, 1, v);
        if (fabs(sdf[v]) < 1e-3) sdf[v] = 1e-3;
    }
    // Brute force over the edge list.
    double sum = 0;
    int m = 0;
    for (int e = 0; e < g.n_edges; e++) {
        double a = sdf[g.edges[2 * e]], b = sdf[g.edges[2 * e + 1]];
        if ((a > 0) == (b > 0)) continue;
        m++;
        sum += fmax(a, 0) - a * (b > 0) + log1p(exp(-fabs(a)));
        sum += fmax(b, 0) - b * (a > 0) + log1p(exp(-fabs(b)));
    }
    REQUIRE(m > 10);
    CHECK_CLOSE(sdf_reg_forward_f64(&g, sdf), sum / m, 1e-12, 0);
    double* d = calloc(V, sizeof(double));
    sdf_reg_backward_f64(d, &g, sdf, 0.7);
    const double h = 1e-6;
    for (int v = 0; v < V; v++) {
        double keep = sdf[v];
        sdf[v] = keep + h;
        double lp = sdf_reg_forward_f64(&g, sdf);
        sdf[v] = keep - h;
        double lm = sdf_reg_forward_f64(&g, sdf);
        sdf[v] = keep;
        CHECK_CLOSE(d[v], 0.7 * (lp - lm) / (2 * h), 1e-6, 1e-9);
    }
    for (int v = 0; v < V; v++) sdf[v] = 1;
    CHECK(sdf_reg_forward_f64(&g, sdf) == 0);
    free(d);
    free(sdf);
    mlb_tetgrid_free(&g);
}

// Vertex normals of the extracted sphere point away from the centre; the backward against central
// differences on a small perturbed mesh (double).
TEST(vertex_normals) {
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 5, 1.0f) == MLB_OK);
    const int V = g.n_verts;
    double* pos = malloc(sizeof(double) * 3 * V);
    double* sdf = malloc(sizeof(double) * V);
    for (int i = 0; i < 3 * V; i++) pos[i] = g.verts[i];
    for (int v = 0; v < V; v++) {
        const double* p = pos + 3 * v;
        sdf[v] = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) - 0.33;
    }
    mlb_mt_surface_f64 s;
    REQUIRE(marching_tets_forward_f64(&s, &g, pos, sdf) == MLB_OK);
    const int M = s.n_verts;
    double* nrm = malloc(sizeof(double) * 3 * M);
    double* sum = malloc(sizeof(double) * 3 * M);
    vertex_normals_forward_f64(nrm, sum, s.pos, M, s.faces, s.n_faces);
    int away = 0;
    for (int i = 0; i < M; i++) {
        const double *p = s.pos + 3 * i, *n = nrm + 3 * i;
        double len = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
        CHECK_CLOSE(n[0] * n[0] + n[1] * n[1] + n[2] * n[2], 1.0, 1e-12, 0);
        away += (n[0] * p[0] + n[1] * p[1] + n[2] * p[2]) / len > 0.8;
    }
    CHECK(away == M);
    double* vp = malloc(sizeof(double) * 3 * M);
    double* r = malloc(sizeof(double) * 3 * M);
    double* dp = calloc(3 * M, sizeof(double));
    for (int i = 0; i < 3 * M; i++) {
        vp[i] = s.pos[i] + 0.01 * mlb_rng_normal_f64(4, 1, i);
        r[i] = mlb_rng_normal_f64(4, 2, i);
    }
    vertex_normals_forward_f64(nrm, sum, vp, M, s.faces, s.n_faces);
    CHECK(vertex_normals_backward_f64(dp, r, sum, vp, M, s.faces, s.n_faces) == MLB_OK);
    const double h = 1e-6;
    for (int i = 0; i < 3 * M; i++) {
        double keep = vp[i], lp = 0, lm = 0;
        vp[i] = keep + h;
        vertex_normals_forward_f64(nrm, NULL, vp, M, s.faces, s.n_faces);
        for (int j = 0; j < 3 * M; j++) lp += r[j] * nrm[j];
        vp[i] = keep - h;
        vertex_normals_forward_f64(nrm, NULL, vp, M, s.faces, s.n_faces);
        for (int j = 0; j < 3 * M; j++) lm += r[j] * nrm[j];
        vp[i] = keep;
        CHECK_CLOSE(dp[i], (lp - lm) / (2 * h), 1e-5, 1e-6);
    }
    free(vp); free(r); free(dp); free(nrm); free(sum); free(pos); free(sdf);
    mt_surface_free_f64(&s);
    mlb_tetgrid_free(&g);
}

// The gather forms of the vertex normals (the op tables' and the CUDA kernels': per vertex over
// mlb_vertex_faces's lists) give the scatter forms' bits, in float and in double: on a sphere's
// surface and on random meshes whose faces repeat vertices, have no area or leave vertices out.
#define GATHER_SCATTER(R, SUF)                                                                          \
    static int gather_scatter_##R(const R* pos, int V, const int32_t* faces, int F, const R* dnormal) { \
        int32_t *off = malloc(sizeof(int32_t) * (V + 1)), *vf = malloc(sizeof(int32_t) * (3 * F + 1));   \
        R *n1 = malloc(sizeof(R) * 3 * V), *n2 = malloc(sizeof(R) * 3 * V), *s1 = malloc(sizeof(R) * 3 * V); \
        R *s2 = malloc(sizeof(R) * 3 * V), *d1 = malloc(sizeof(R) * 3 * V), *d2 = malloc(sizeof(R) * 3 * V); \
        int same = off && vf && n1 && n2 && s1 && s2 && d1 && d2 && mlb_vertex_faces(off, vf, faces, F, V) == MLB_OK; \
        if (same) {                                                                                     \
            vertex_normals_forward##SUF(n1, s1, pos, V, faces, F);                                      \
            mlb_vertex_normals##SUF(n2, s2, pos, V, faces, off, vf);                                    \
            for (int i = 0; i < 3 * V; i++) d1[i] = d2[i] = (R)(0.5 - (i % 7) * 0.125);                 \
            same = vertex_normals_backward##SUF(d1, dnormal, s1, pos, V, faces, F) == MLB_OK;           \
            mlb_vertex_normals_backward##SUF(d2, dnormal, s1, pos, V, faces, off, vf);                 \
            same = same && !memcmp(n1, n2, sizeof(R) * 3 * V) && !memcmp(s1, s2, sizeof(R) * 3 * V) &&  \
                   !memcmp(d1, d2, sizeof(R) * 3 * V);                                                 \
        }                                                                                               \
        free(off), free(vf), free(n1), free(n2), free(s1), free(s2), free(d1), free(d2);                \
        return same;                                                                                    \
    }
GATHER_SCATTER(float, )
GATHER_SCATTER(double, _f64)

TEST(vertex_normals_gather_is_scatter) {
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 8, 1.0f) == MLB_OK);
    float* sdf = malloc(sizeof(float) * g.n_verts);
    REQUIRE(sdf);
    for (int v = 0; v < g.n_verts; v++) {
        const float* p = g.verts + 3 * v;
        sdf[v] = 0.35f - sqrtf(p[0] * p[0] + 1.4f * p[1] * p[1] + p[2] * p[2]);
    }
    mlb_mt_surface s;
    REQUIRE(marching_tets_forward(&s, &g, g.verts, sdf) == MLB_OK);
    REQUIRE(s.n_faces > 100);
    int M = s.n_verts;
    float* dn = malloc(sizeof(float) * 3 * M);
    double *pd = malloc(sizeof(double) * 3 * M), *dnd = malloc(sizeof(double) * 3 * M);
    REQUIRE(dn && pd && dnd);
    for (int i = 0; i < 3 * M; i++) dn[i] = (float)(dnd[i] = mlb_rng_normal_f64(9, 1, i)), pd[i] = s.pos[i];
    CHECK_MSG(gather_scatter_float(s.pos, M, s.faces, s.n_faces, dn), "sphere, %d faces, float", s.n_faces);
    CHECK_MSG(gather_scatter_double(pd, M, s.faces, s.n_faces, dnd), "sphere, %d faces, double", s.n_faces);
    free(dn), free(pd), free(dnd);
    mt_surface_free(&s);
    mlb_tetgrid_free(&g);
    free(sdf);
    for (int t = 0; t < 6; t++) {   // random meshes: V up to 400, F up to 900
        int V = 1 + (int)(mlb_rng_uniform_f64(10, t, 0) * 400), F = (int)(mlb_rng_uniform_f64(10, t, 1) * 900);
        int32_t* faces = malloc(sizeof(int32_t) * (3 * F + 1));
        float *p = malloc(sizeof(float) * 3 * V), *d = malloc(sizeof(float) * 3 * V);
        double *p64 = malloc(sizeof(double) * 3 * V), *d64 = malloc(sizeof(double) * 3 * V);
        REQUIRE(faces && p && d && p64 && d64);
        for (int i = 0; i < 3 * F; i++) faces[i] = (int32_t)(mlb_rng_uniform_f64(11, t, i) * V);
        for (int i = 0; i < 3 * V; i++) {
            p[i] = (float)(p64[i] = mlb_rng_normal_f64(12, t, i));
            d[i] = (float)(d64[i] = mlb_rng_normal_f64(13, t, i));
        }
        if (F > 2) faces[3] = faces[4] = faces[5];   // a face on one vertex
        CHECK_MSG(gather_scatter_float(p, V, faces, F, d), "random mesh V %d F %d, float", V, F);
        CHECK_MSG(gather_scatter_double(p64, V, faces, F, d64), "random mesh V %d F %d, double", V, F);
        free(faces), free(p), free(d), free(p64), free(d64);
    }
    int32_t off[3], vf[3], bad[3] = {0, 1, 2};
    CHECK(mlb_vertex_faces(off, vf, bad, 1, 2) == MLB_ERR_ARG);   // vertex 2 of 2: named, refused
    CHECK(strstr(mlb_last_error(), "face 0 names vertex 2 of 2") != NULL);
}

// The tables packed for both devices (marching_tets_math.h) are reference.md's, and the edge slots
// are mlb_tetgrid_edge_id's ids: the slots that are edges, in increasing order, are g.edges.
TEST(packed_tables_and_slots) {
    for (int c = 0; c < 16; c++) {
        CHECK(mt_num_tri(c) == mlb_mt_num_triangles[c]);
        for (int i = 0; i < 3 * mlb_mt_num_triangles[c]; i++)
            CHECK_MSG(mt_row_entry(mt_row(c), i) == mlb_mt_triangle_table[c][i], "case %d entry %d", c, i);
    }
    for (int e = 0; e < 6; e++) CHECK(mt_edge_lo(e) == mlb_mt_tet_edges[e][0] && mt_edge_hi(e) == mlb_mt_tet_edges[e][1]);
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 4, 1.0f) == MLB_OK);
    const int n = g.cells + 1;
    int64_t e = 0;
    for (int64_t s = 0; s < 7 * (int64_t)g.n_verts; s++) {
        int32_t a, b;
        if (!mt_slot_ends(s, n, &a, &b)) continue;
        REQUIRE(e < g.n_edges);
        CHECK_MSG(a == g.edges[2 * e] && b == g.edges[2 * e + 1], "slot %lld is not edge %lld", (long long)s, (long long)e);
        CHECK(mt_slot_of(a, b, n) == s && mt_slot_of(b, a, n) == s && mlb_tetgrid_edge_id(&g, a, b) == s);
        e++;
    }
    CHECK(e == g.n_edges);
    for (int t = 0; t < g.n_tets; t++)
        for (int k = 0; k < 6; k++) {
            const int32_t* tv = g.tets + 4 * t;
            int32_t a = tv[mt_edge_lo(k)], b = tv[mt_edge_hi(k)];
            CHECK(mt_slot_of(a, b, n) == mlb_tetgrid_edge_id(&g, a, b));
        }
    mlb_tetgrid_free(&g);
}

// The chunked scan against the plain running sum: empty, short, and long enough for its parallel
// path, into another buffer and in place, on 1 and 2 threads.
TEST(scan_i32) {
    int saved = mlb_get_threads();
    static const int sizes[] = {0, 1, 63, 64, 65, 1000, 300007};
    for (size_t z = 0; z < sizeof sizes / sizeof sizes[0]; z++) {
        int n = sizes[z];
        int32_t* in = malloc(sizeof(int32_t) * (n + 1));
        int32_t* ref = malloc(sizeof(int32_t) * (n + 1));
        int32_t* out = malloc(sizeof(int32_t) * (n + 1));
        REQUIRE(in && ref && out);
        int32_t acc = 0;
        for (int i = 0; i < n; i++) {
            in[i] = (int32_t)(mlb_rng_uniform_f64(9, z, i) * 8);
            ref[i] = acc;
            acc += in[i];
        }
        ref[n] = acc;
        for (int threads = 1; threads <= 2; threads++) {
            mlb_set_threads(threads);
            out[n] = -1;
            mlb_scan_i32(out, in, n);
            CHECK_MSG(!memcmp(out, ref, sizeof(int32_t) * (n + 1)), "n %d, %d threads", n, threads);
            memcpy(out, in, sizeof(int32_t) * n);
            out[n] = -1;
            mlb_scan_i32(out, out, n);
            CHECK_MSG(!memcmp(out, ref, sizeof(int32_t) * (n + 1)), "n %d in place, %d threads", n, threads);
        }
        mlb_set_threads(saved);
        free(in), free(ref), free(out);
    }
}

// A sphere SDF with noise on a grid of `cells`, exact zeros at every 9th vertex (inside).
static void noisy_sphere(float* sdf, const mlb_tetgrid* g, uint64_t seed) {
    for (int v = 0; v < g->n_verts; v++) {
        const float* p = g->verts + 3 * v;
        sdf[v] = v % 9 == 4 ? 0.0f : sqrtf(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) - 0.3f +
                                     0.15f * (float)mlb_rng_normal_f64(seed, 1, v);
    }
}

// The CUDA kernel's backward, a gather per grid vertex (compiled here for the host), adds every
// term the CPU's scatter adds in the same order: the same bits, onto random values, with either
// gradient NULL, in float and in double.
TEST(backward_gather_is_scatter) {
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 7, 1.0f) == MLB_OK);
    const int V = g.n_verts, T = g.n_tets;
    const int64_t S = 7 * (int64_t)V;
    float* sdf = malloc(sizeof(float) * V);
    int32_t* tet_off = malloc(sizeof(int32_t) * (T + 1));
    int32_t* slot_off = malloc(sizeof(int32_t) * (S + 1));
    double *sdf64 = malloc(sizeof(double) * V), *pos64 = malloc(sizeof(double) * 3 * V);
    REQUIRE(sdf && tet_off && slot_off && sdf64 && pos64);
    noisy_sphere(sdf, &g, 5);
    for (int v = 0; v < V; v++) sdf64[v] = sdf[v];
    for (int i = 0; i < 3 * V; i++) pos64[i] = g.verts[i] + 0.01 * mlb_rng_normal_f64(5, 2, i);
    mlb_mt_count(tet_off, slot_off, sdf, g.tets, T, g.cells);
    mlb_scan_i32(tet_off, tet_off, T);
    mlb_scan_i32(slot_off, slot_off, (int)S);
    mlb_mt_surface s;
    mlb_mt_surface_f64 s64;
    REQUIRE(marching_tets_forward(&s, &g, g.verts, sdf) == MLB_OK);
    REQUIRE(marching_tets_forward_f64(&s64, &g, pos64, sdf64) == MLB_OK);
    const int M = s.n_verts;
    REQUIRE(M > 50 && M == slot_off[S] && s64.n_verts == M);
    float* dv = malloc(sizeof(float) * 3 * M);
    double* dv64 = malloc(sizeof(double) * 3 * M);
    float *p1 = malloc(sizeof(float) * 3 * V), *p2 = malloc(sizeof(float) * 3 * V);
    float *q1 = malloc(sizeof(float) * V), *q2 = malloc(sizeof(float) * V);
    double *P1 = malloc(sizeof(double) * 3 * V), *P2 = malloc(sizeof(double) * 3 * V);
    double *Q1 = malloc(sizeof(double) * V), *Q2 = malloc(sizeof(double) * V);
    REQUIRE(dv && dv64 && p1 && p2 && q1 && q2 && P1 && P2 && Q1 && Q2);
    for (int i = 0; i < 3 * M; i++) dv64[i] = dv[i] = (float)mlb_rng_normal_f64(5, 3, i);
    for (int null = 0; null < 3; null++) {   // 0: both, 1: dsdf NULL, 2: dpos NULL
        for (int i = 0; i < 3 * V; i++) P1[i] = P2[i] = p1[i] = p2[i] = (float)mlb_rng_normal_f64(5, 4, i);
        for (int i = 0; i < V; i++) Q1[i] = Q2[i] = q1[i] = q2[i] = (float)mlb_rng_normal_f64(5, 5, i);
        float *dp1 = null == 2 ? NULL : p1, *dp2 = null == 2 ? NULL : p2;
        float *ds1 = null == 1 ? NULL : q1, *ds2 = null == 1 ? NULL : q2;
        mlb_mt_backward(dp1, ds1, dv, s.weight, s.edge, M, g.verts, sdf);
        mlb_mt_backward_gather(dp2, ds2, dv, s.weight, g.verts, sdf, slot_off, g.cells);
        CHECK_MSG(!memcmp(p1, p2, sizeof(float) * 3 * V), "float dpos differs (null %d)", null);
        CHECK_MSG(!memcmp(q1, q2, sizeof(float) * V), "float dsdf differs (null %d)", null);
        double *DP1 = null == 2 ? NULL : P1, *DP2 = null == 2 ? NULL : P2;
        double *DS1 = null == 1 ? NULL : Q1, *DS2 = null == 1 ? NULL : Q2;
        mlb_mt_backward_f64(DP1, DS1, dv64, s64.weight, s64.edge, M, pos64, sdf64);
        mlb_mt_backward_gather_f64(DP2, DS2, dv64, s64.weight, pos64, sdf64, slot_off, g.cells);
        CHECK_MSG(!memcmp(P1, P2, sizeof(double) * 3 * V), "double dpos differs (null %d)", null);
        CHECK_MSG(!memcmp(Q1, Q2, sizeof(double) * V), "double dsdf differs (null %d)", null);
    }
    int touched = 0;
    for (int i = 0; i < V; i++) touched += q1[i] != (float)mlb_rng_normal_f64(5, 5, i);
    CHECK(touched > 20);
    free(dv), free(dv64), free(p1), free(p2), free(q1), free(q2), free(P1), free(P2), free(Q1), free(Q2);
    free(sdf), free(tet_off), free(slot_off), free(sdf64), free(pos64);
    mt_surface_free(&s);
    mt_surface_free_f64(&s64);
    mlb_tetgrid_free(&g);
}

// marching tets through the CPU's op tables (mlb_mt_device_*, what the geometry stage calls: the
// float table's, and the double table's of geometry/mt_device_f64.h) is marching_tets_forward and
// _backward bit for bit, including a second forward on the same handle and an empty surface; the
// surface left on the table (MLB_MT_TABLE) is the same one. The surfaces: two noisy spheres, a
// noisy slanted plane cut by the grid's sides, none.
#define TABLE_PATH(R, SUF, TABLE)                                                                           \
    static void table_path_##R(const mlb_tetgrid* g) {                                                      \
        const int V = g->n_verts;                                                                           \
        float* sdf32 = malloc(sizeof(float) * V);                                                           \
        R *sdf = malloc(sizeof(R) * V), *pos = malloc(sizeof(R) * 3 * V);                                   \
        REQUIRE(sdf32 && sdf && pos);                                                                       \
        for (int i = 0; i < 3 * V; i++) pos[i] = (R)(g->verts[i] + 0.02f * (float)mlb_rng_normal_f64(6, 1, i)); \
        mlb_mt_device *d = NULL, *t = NULL;                                                                 \
        for (int round = 0; round < 4; round++) {                                                           \
            noisy_sphere(sdf32, g, 6 + round);                                                              \
            for (int v = 0; v < V; v++) {   /* 2: a slanted plane, 3: nothing inside */                     \
                const float* p = g->verts + 3 * v;                                                          \
                sdf[v] = round == 3 ? 1 : round == 2 ? (R)(p[0] + 0.3f * p[1] + 0.2f * sdf32[v]) : sdf32[v]; \
            }                                                                                               \
            mlb_mt_surface##SUF a, b, c;                                                                    \
            REQUIRE(marching_tets_forward##SUF(&a, g, pos, sdf) == MLB_OK);                                 \
            REQUIRE(mlb_mt_device_forward##SUF(&d, TABLE, &b, g, pos, sdf, MLB_MT_HOST) == MLB_OK);         \
            REQUIRE(mlb_mt_device_forward##SUF(&t, TABLE, &c, g, pos, sdf, MLB_MT_TABLE) == MLB_OK);        \
            const int M = a.n_verts, F = a.n_faces;                                                         \
            CHECK(b.n_verts == M && b.n_faces == F && c.n_verts == M && c.n_faces == F && !c.pos);          \
            CHECK(round == 3 ? M == 0 : M > 100);                                                           \
            if (b.n_verts != M || b.n_faces != F) break;                                                    \
            CHECK(!memcmp(a.pos, b.pos, sizeof(R) * 3 * M) && !memcmp(a.faces, b.faces, sizeof(int32_t) * 3 * F)); \
            CHECK(!memcmp(a.edge, b.edge, sizeof(int32_t) * 2 * M) && !memcmp(a.weight, b.weight, sizeof(R) * 2 * M)); \
            const R* tv;                                                                                    \
            const int32_t* tf;                                                                              \
            REQUIRE(mlb_mt_device_surface##SUF(t, &tv, &tf) == MLB_OK);   /* host memory on a CPU table */  \
            CHECK(!memcmp(a.pos, tv, sizeof(R) * 3 * M) && !memcmp(a.faces, tf, sizeof(int32_t) * 3 * F));  \
            mt_surface_free##SUF(&c);                                                                       \
            REQUIRE(mlb_mt_device_surface_host##SUF(t, &c) == MLB_OK);                                      \
            CHECK(c.n_faces == F && !memcmp(a.faces, c.faces, sizeof(int32_t) * 3 * F) &&                   \
                  !memcmp(a.edge, c.edge, sizeof(int32_t) * 2 * M));                                        \
            R* dv = malloc(sizeof(R) * 3 * (M + 1));                                                        \
            R *p1 = calloc(3 * V, sizeof(R)), *p2 = calloc(3 * V, sizeof(R)), *p3 = calloc(3 * V, sizeof(R)); \
            R *q1 = calloc(V, sizeof(R)), *q2 = calloc(V, sizeof(R)), *q3 = calloc(V, sizeof(R));           \
            REQUIRE(dv && p1 && p2 && p3 && q1 && q2 && q3);                                                \
            for (int i = 0; i < 3 * M; i++) dv[i] = (R)(float)mlb_rng_normal_f64(6, 2, i);                  \
            marching_tets_backward##SUF(p1, q1, &a, pos, sdf, dv);                                          \
            REQUIRE(mlb_mt_device_backward##SUF(d, p2, q2, dv, MLB_MT_HOST) == MLB_OK);                     \
            REQUIRE(mlb_mt_device_backward##SUF(t, p3, q3, dv, MLB_MT_TABLE) == MLB_OK);                    \
            CHECK(!memcmp(p1, p2, sizeof(R) * 3 * V) && !memcmp(q1, q2, sizeof(R) * V));                    \
            CHECK(!memcmp(p1, p3, sizeof(R) * 3 * V) && !memcmp(q1, q3, sizeof(R) * V));                    \
            free(dv), free(p1), free(p2), free(p3), free(q1), free(q2), free(q3);                           \
            mt_surface_free##SUF(&a);                                                                       \
            mt_surface_free##SUF(&b);                                                                       \
            mt_surface_free##SUF(&c);                                                                       \
        }                                                                                                   \
        mlb_mt_device_free##SUF(d);                                                                         \
        mlb_mt_device_free##SUF(t);                                                                         \
        free(sdf32), free(sdf), free(pos);                                                                  \
    }
TABLE_PATH(float, , mlb_backend_cpu())
TABLE_PATH(double, _f64, mlb_backend_cpu_f64())

TEST(table_path_is_forward) {
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 9, 1.0f) == MLB_OK);
    table_path_float(&g);
    table_path_double(&g);
    mlb_tetgrid_free(&g);
}

// rms and mean of |v| - r over a mesh's vertices
static void radial_stats(const mlb_mesh* m, double r, double* rms, double* mean) {
    double s2 = 0, s1 = 0;
    for (int i = 0; i < m->n_verts; i++) {
        const float* p = m->pos + 3 * (size_t)i;
        double d = sqrt((double)p[0] * p[0] + (double)p[1] * p[1] + (double)p[2] * p[2]) - r;
        s2 += d * d, s1 += d;
    }
    *rms = sqrt(s2 / m->n_verts), *mean = s1 / m->n_verts;
}

// Taubin smoothing on the marching-tets sphere (what the pipeline smooths): radial noise of up to
// 0.02 at every vertex falls below half in 10 rounds (the smoothing is linear, so the smoothed
// noisy sphere less the smoothed clean one is the smoothed noise), while the sphere keeps its size
// (a Laplacian alone would shrink it); 0 rounds change nothing; bad factors are refused.
TEST(taubin_smoothing) {
    const float r = 0.6f;
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 24, 2.1f) == MLB_OK);
    float* sdf = malloc(sizeof(float) * g.n_verts);
    sdf_grid(&g, sdf, 0);
    mlb_mt_surface s;
    REQUIRE(marching_tets_forward(&s, &g, g.verts, sdf) == MLB_OK);
    mlb_mesh clean, noisy;
    REQUIRE(mt_surface_to_mesh(&s, &clean) == MLB_OK && mt_surface_to_mesh(&s, &noisy) == MLB_OK);
    for (int i = 0; i < noisy.n_verts; i++) {
        float* p = noisy.pos + 3 * (size_t)i;
        double len = sqrt((double)p[0] * p[0] + (double)p[1] * p[1] + (double)p[2] * p[2]);
        double k = 1 + 0.02 * (2 * mlb_rng_uniform(5, 1, (uint64_t)i) - 1) / len;
        for (int d = 0; d < 3; d++) p[d] = (float)(p[d] * k);
    }
    double rms0, mean0, rms1, mean1, rms_c, mean_c, rms_cs, mean_cs, noise0 = 0, noise1 = 0;
    for (int i = 0; i < 3 * noisy.n_verts; i++) noise0 += ((double)noisy.pos[i] - clean.pos[i]) * ((double)noisy.pos[i] - clean.pos[i]);
    radial_stats(&clean, r, &rms_c, &mean_c);
    radial_stats(&noisy, r, &rms0, &mean0);
    float* before = malloc(sizeof(float) * 3 * (size_t)noisy.n_verts);
    REQUIRE(before);
    memcpy(before, noisy.pos, sizeof(float) * 3 * (size_t)noisy.n_verts);
    REQUIRE(mlb_mesh_smooth_taubin(&noisy, 0, 0.5f, -0.53f) == MLB_OK);
    CHECK(!memcmp(before, noisy.pos, sizeof(float) * 3 * (size_t)noisy.n_verts));
    REQUIRE(mlb_mesh_smooth_taubin(&noisy, 10, 0.5f, -0.53f) == MLB_OK);
    REQUIRE(mlb_mesh_smooth_taubin(&clean, 10, 0.5f, -0.53f) == MLB_OK);
    radial_stats(&noisy, r, &rms1, &mean1);
    radial_stats(&clean, r, &rms_cs, &mean_cs);
    for (int i = 0; i < 3 * noisy.n_verts; i++) noise1 += ((double)noisy.pos[i] - clean.pos[i]) * ((double)noisy.pos[i] - clean.pos[i]);
    noise0 = sqrt(noise0 / noisy.n_verts), noise1 = sqrt(noise1 / noisy.n_verts);
    printf("  noisy sphere: noise %.4f -> %.4f; rms |v| - r %.4f -> %.4f; mean %.4f -> %.4f; clean mean %.4f -> %.4f\n",
           noise0, noise1, rms0, rms1, mean0, mean1, mean_c, mean_cs);
    CHECK(noise1 < noise0 / 2 && rms1 < rms0 / 2);
    CHECK(fabs(mean_cs - mean_c) < 0.01 * r && fabs(mean1 - mean_c) < 0.01 * r);   // the size kept
    CHECK(mlb_mesh_smooth_taubin(&clean, 1, 0.5f, -0.4f) == MLB_ERR_ARG);   // |mu| must exceed lambda
    CHECK(mlb_mesh_smooth_taubin(&clean, -1, 0.5f, -0.53f) == MLB_ERR_ARG);
    free(before);
    mlb_mesh_free(&clean);
    mlb_mesh_free(&noisy);
    mt_surface_free(&s);
    free(sdf);
    mlb_tetgrid_free(&g);
}

int main(void) {
    RUN(tetgrid_structure);
    RUN(sphere_closed_outward_close);
    RUN(torus_genus_one);
    RUN(marching_tets_backward_fd);
    RUN(sdf_regulariser);
    RUN(vertex_normals);
    RUN(vertex_normals_gather_is_scatter);
    RUN(packed_tables_and_slots);
    RUN(scan_i32);
    RUN(backward_gather_is_scatter);
    RUN(table_path_is_forward);
    RUN(taubin_smoothing);
    return test_summary();
}
