// OBJ reading and the mesh utilities: the real meshes in ../shared/data/meshes, a hand-written
// cube (quads, negative indices), every corner form and repair, numbers parsed exactly as strtof
// does, a corpus of malformed files (each: status, file name and line number in the message, and
// nothing returned), large inputs; then area-weighted normals, bounds and the unit sphere fit.
#include "test.h"
#include <float.h>
#include <stdint.h>
#include <unistd.h>
#include "matlaber/error.h"
#include "matlaber/mesh.h"
#include "matlaber/obj.h"
#include "matlaber/rng.h"

static const char* tmp;   // scratch folder

static int write_text(const char* path, const char* text, size_t n) {
    FILE* f = fopen(path, "wb");
    if (!f) return 0;
    size_t w = fwrite(text, 1, n, f);
    return fclose(f) == 0 && w == n;
}

static int mesh_is_zero(const mlb_mesh* m) {
    return m->n_verts == 0 && m->n_faces == 0 && !m->pos && !m->normal && !m->uv && !m->faces;
}

static mlb_status parse_str(const char* text, mlb_mesh* m, mlb_obj_info* info) {
    return mlb_obj_parse(text, strlen(text), "mem.obj", m, NULL, info);
}

// ---- real meshes ----

static void check_real(const char* rel, int n_v, int n_vt, int n_vn, int n_f, int unified) {
    const char* data = test_shared_data();
    if (!data) SKIP("no ../shared/data");
    char path[4096];
    snprintf(path, sizeof path, "%s/meshes/%s", data, rel);
    mlb_mesh m;
    mlb_obj_info info;
    mlb_status s = mlb_obj_load_ex(path, &m, NULL, &info);
    CHECK_MSG(s == MLB_OK, "%s", mlb_last_error());
    if (s != MLB_OK) return;
    CHECK(info.n_positions == n_v && info.n_texcoords == n_vt && info.n_normals == n_vn);
    CHECK(info.n_polygons == n_f && info.n_polygons_split == 0 && m.n_faces == n_f);
    CHECK(info.n_unused_positions == 0 && !info.uv_dropped && !info.normals_dropped);
    CHECK(m.uv && m.normal);
    // A unified vertex is a distinct (v, vt, vn) triple. In these files every vn belongs to exactly
    // one v (smooth normals, n_vn == n_v), so only uv seams split positions: unified == n_vt.
    CHECK_MSG(m.n_verts == unified, "%s: %d unified vertices, expected %d", rel, m.n_verts, unified);
    CHECK(strstr(info.mtllib, ".mtl") != NULL);
    int bad_index = 0, bad_len = 0, flipped = 0;
    for (int i = 0; i < 3 * m.n_faces; i++) bad_index += m.faces[i] < 0 || m.faces[i] >= m.n_verts;
    for (int i = 0; i < m.n_verts; i++) {
        const float* n = m.normal + 3 * i;
        bad_len += fabs(sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]) - 1) > 1e-3;
    }
    // counter-clockwise winding: the geometric normal agrees with the file's vertex normals
    for (int f = 0; f < m.n_faces && !bad_index; f++) {
        const int32_t* t = m.faces + 3 * f;
        const float *a = m.pos + 3 * t[0], *b = m.pos + 3 * t[1], *c = m.pos + 3 * t[2];
        double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double g[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        double d = 0;
        for (int k = 0; k < 3; k++)
            for (int j = 0; j < 3; j++) d += g[j] * m.normal[3 * t[k] + j];
        flipped += d < 0;
    }
    CHECK(bad_index == 0);
    CHECK_MSG(bad_len == 0, "%d normals are not unit length", bad_len);
    CHECK_MSG(flipped == 0, "%d of %d triangles wind against their normals", flipped, m.n_faces);
    float lo[3], hi[3];
    mlb_mesh_bounds(&m, lo, hi);
    printf("  %s: %d v / %d vt / %d vn / %d f -> %d vertices; bounds [%.3f %.3f %.3f]..[%.3f %.3f %.3f]\n", rel,
           info.n_positions, info.n_texcoords, info.n_normals, info.n_polygons, m.n_verts, lo[0], lo[1], lo[2], hi[0],
           hi[1], hi[2]);
    // the file's normals and recomputed area-weighted ones (welded across seams) agree closely
    float* file_n = malloc(3 * (size_t)m.n_verts * sizeof(float));
    REQUIRE(file_n);
    memcpy(file_n, m.normal, 3 * (size_t)m.n_verts * sizeof(float));
    REQUIRE(mlb_mesh_compute_normals(&m) == MLB_OK);
    double worst = 1;
    for (int i = 0; i < m.n_verts; i++) {
        double d = 0;
        for (int j = 0; j < 3; j++) d += (double)file_n[3 * i + j] * m.normal[3 * i + j];
        if (d < worst) worst = d;
    }
    printf("  %s: smallest cosine between file and recomputed normals %.4f\n", rel, worst);
    CHECK(worst > 0.5);
    free(file_n);
    mlb_mesh_normalize_unit_sphere(&m);
    double r = 0;
    for (int i = 0; i < m.n_verts; i++) {
        const float* p = m.pos + 3 * i;
        r = fmax(r, sqrt((double)p[0] * p[0] + (double)p[1] * p[1] + (double)p[2] * p[2]));
    }
    CHECK(r <= 1.0 && r > 0.9999);
    mlb_mesh_free(&m);
    CHECK(mesh_is_zero(&m));
}

TEST(real_spot) { check_real("spot/spot.obj", 2930, 3225, 2930, 5856, 3225); }
TEST(real_bob) { check_real("bob/bob_tri.obj", 5344, 5647, 5344, 10688, 5647); }

// ---- hand-written meshes ----

// Unit cube, quads wound counter-clockwise from outside, every index negative (relative).
static const char* cube_obj =
    "# cube\r\n"
    "mtllib cube.mtl\r\n"
    "o Cube\r\n"
    "v 0 0 0\r\nv 1 0 0\r\nv 1 1 0\r\nv 0 1 0\r\n"
    "v 0 0 1\r\nv 1 0 1\r\nv 1 1 1\r\nv 0 1 1\r\n"
    "vt 0 0\r\nvt 1 0\r\nvt 1 1\r\nvt 0 1\r\n"
    "vn 0 0 -1\r\nvn 0 0 1\r\nvn 0 -1 0\r\nvn 0 1 0\r\nvn -1 0 0\r\nvn 1 0 0\r\n"
    "usemtl mat\r\ns off\r\n"
    "\r\n"
    "f -8/-4/-6 -5/-1/-6 -6/-2/-6 -7/-3/-6\r\n"   // z=0: 1 4 3 2
    "f -4/-4/-5 -3/-3/-5 -2/-2/-5 -1/-1/-5\r\n"   // z=1: 5 6 7 8
    "f -8/-4/-4 -7/-3/-4 -3/-2/-4 -4/-1/-4\r\n"   // y=0: 1 2 6 5
    "f -5/-4/-3 -1/-3/-3 -2/-2/-3 -6/-1/-3\r\n"   // y=1: 4 8 7 3
    "f -8/-4/-2 -4/-3/-2 -1/-2/-2 -5/-1/-2\r\n"   // x=0: 1 5 8 4
    "f -7/-4/-1 -6/-3/-1 -2/-2/-1 -3/-1/-1\r\n";  // x=1: 2 3 7 6

TEST(cube_quads_negative_indices) {
    mlb_mesh m;
    mlb_obj_info info;
    mlb_status s = parse_str(cube_obj, &m, &info);
    REQUIRE(s == MLB_OK);
    CHECK(m.n_faces == 12 && info.n_polygons == 6 && info.n_polygons_split == 6);
    CHECK(m.n_verts == 24);   // each corner of each face has its own normal
    CHECK(m.uv && m.normal);
    CHECK(strcmp(info.mtllib, "cube.mtl") == 0);
    CHECK(info.n_ignored == 4);   // mtllib o usemtl s
    CHECK(info.n_lines == 30);
    // every triangle: CCW from outside (geometric normal == vertex normal == outward), area 1/2
    int bad = 0;
    for (int f = 0; f < 12; f++) {
        const int32_t* t = m.faces + 3 * f;
        const float *a = m.pos + 3 * t[0], *b = m.pos + 3 * t[1], *c = m.pos + 3 * t[2];
        float e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        float g[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        for (int k = 0; k < 3; k++) {
            const float* n = m.normal + 3 * t[k];
            bad += g[0] != n[0] || g[1] != n[1] || g[2] != n[2];
            // outward: the normal points away from the centre
            const float* p = m.pos + 3 * t[k];
            bad += (p[0] - 0.5f) * n[0] + (p[1] - 0.5f) * n[1] + (p[2] - 0.5f) * n[2] <= 0;
        }
    }
    CHECK(bad == 0);
    // the fan: face 1 (1 4 3 2) -> (1 4 3), (1 3 2); positions of the first two triangles
    const float want[6][3] = {{0, 0, 0}, {0, 1, 0}, {1, 1, 0}, {0, 0, 0}, {1, 1, 0}, {1, 0, 0}};
    for (int i = 0; i < 6; i++)
        for (int k = 0; k < 3; k++) CHECK(m.pos[3 * m.faces[i] + k] == want[i][k]);
    // uv of the first corner of face 1 is vt 1 = (0, 0), of its second corner vt 4 = (0, 1)
    CHECK(m.uv[2 * m.faces[0]] == 0 && m.uv[2 * m.faces[0] + 1] == 0);
    CHECK(m.uv[2 * m.faces[1]] == 0 && m.uv[2 * m.faces[1] + 1] == 1);
    // the same cube written with positive indices gives the identical mesh
    char pos_obj[2048];
    snprintf(pos_obj, sizeof pos_obj,
             "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
             "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
             "vn 0 0 -1\nvn 0 0 1\nvn 0 -1 0\nvn 0 1 0\nvn -1 0 0\nvn 1 0 0\n"
             "f 1/1/1 4/4/1 3/3/1 2/2/1\nf 5/1/2 6/2/2 7/3/2 8/4/2\nf 1/1/3 2/2/3 6/3/3 5/4/3\n"
             "f 4/1/4 8/2/4 7/3/4 3/4/4\nf 1/1/5 5/2/5 8/3/5 4/4/5\nf 2/1/6 3/2/6 7/3/6 6/4/6\n");
    mlb_mesh p;
    REQUIRE(parse_str(pos_obj, &p, NULL) == MLB_OK);
    CHECK(p.n_verts == m.n_verts && p.n_faces == m.n_faces);
    CHECK(memcmp(p.faces, m.faces, 36 * sizeof(int32_t)) == 0);
    CHECK(memcmp(p.pos, m.pos, 72 * sizeof(float)) == 0);
    CHECK(memcmp(p.uv, m.uv, 48 * sizeof(float)) == 0);
    CHECK(memcmp(p.normal, m.normal, 72 * sizeof(float)) == 0);
    mlb_mesh_free(&p);
    mlb_mesh_free(&m);

    // positions only: the 8 corners are shared, no uv, no normals
    REQUIRE(parse_str("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
                      "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 4 8 7 3\nf 1 5 8 4\nf 2 3 7 6\n",
                      &m, NULL) == MLB_OK);
    CHECK(m.n_verts == 8 && m.n_faces == 12 && !m.uv && !m.normal);
    mlb_mesh_free(&m);
}

TEST(corner_forms_and_unification) {
    mlb_mesh m;
    mlb_obj_info info;
    // v/vt only: (1,1) shared by both triangles, (1,2) differs in uv -> separate vertex
    REQUIRE(parse_str("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\n"
                      "f 1/1 2/2 3/3\nf 2/2 4/4 3/3\nf 1/2 2/2 3/3\n", &m, &info) == MLB_OK);
    CHECK(m.n_faces == 3 && m.n_verts == 5 && m.uv && !m.normal);
    CHECK(m.faces[3] == m.faces[1] && m.faces[5] == m.faces[2]);   // shared corners
    CHECK(m.faces[6] != m.faces[0] && m.faces[7] == m.faces[1]);
    CHECK(m.uv[2 * m.faces[6]] == 1 && m.pos[3 * m.faces[6]] == 0);
    mlb_mesh_free(&m);
    // v//vn
    REQUIRE(parse_str("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\n", &m, NULL) == MLB_OK);
    CHECK(m.n_verts == 3 && !m.uv && m.normal && m.normal[2] == 1);
    mlb_mesh_free(&m);
    // mixed: some corners without vt -> the mesh gets no uv, unified on (v, vn) only
    REQUIRE(parse_str("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 1\nvn 0 0 1\n"
                      "f 1/1/1 2/2/1 3/1/1\nf 2//1 4//1 3//1\n", &m, &info) == MLB_OK);
    CHECK(info.uv_dropped == 1 && info.normals_dropped == 0);
    CHECK(!m.uv && m.normal && m.n_verts == 4);
    mlb_mesh_free(&m);
    // mixed normals
    REQUIRE(parse_str("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2 3\n", &m, &info) == MLB_OK);
    CHECK(info.normals_dropped == 1 && !m.normal && m.n_verts == 3);
    mlb_mesh_free(&m);
    // options: drop uv and normals on request; unused positions are dropped and counted
    mlb_obj_options opt = {0};
    opt.drop_uv = opt.drop_normals = 1;
    const char* t = "v 9 9 9\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvn 0 0 1\nf 2/1/1 3/2/1 4/1/1\n";
    REQUIRE(mlb_obj_parse(t, strlen(t), "x.obj", &m, &opt, &info) == MLB_OK);
    CHECK(!m.uv && !m.normal && m.n_verts == 3 && info.n_unused_positions == 1);
    CHECK(m.pos[0] == 0 && m.pos[3] == 1);   // vertices in order of first use
    mlb_mesh_free(&m);
}

TEST(repairs_and_tolerated_syntax) {
    mlb_mesh m;
    mlb_obj_info info;
    const char* t =
        "\xEF\xBB\xBF# BOM, comments, tabs, CRLF and odd statements\r\n"
        "\r\n"
        "   \t\r\n"
        "g   grp \t\r\n"
        "v\t1 2 3 0.5   # w is ignored\r\n"
        "v 4 5 6 0.1 0.2 0.3\r\n"        // xyz + vertex colour (ignored)
        "v -1.5e+0 +2.5E-1 .5\r\n"
        "vt 0.25 0.75 0.5\r\n"            // third component ignored
        "vt 0.5\r\n"                      // v defaults to 0
        "vn 0 0 1\r\n"
        "vp 0.1 0.2\r\n"                  // parameter-space vertex: ignored
        "l 1 2\r\n"                       // polyline: ignored
        "p 1\r\n"                         // point: ignored
        "mystery_keyword 1 2 3\r\n"       // unknown identifiers: ignored
        "f 1/1/1 2/2/1 \\\r\n"            // continuation line
        "  3/1/1\r\n"
        "f 1/1/1 2/2/1 3/1/1";            // last line without newline
    REQUIRE(mlb_obj_parse(t, strlen(t), "ok.obj", &m, NULL, &info) == MLB_OK);
    CHECK(m.n_faces == 2 && m.n_verts == 3 && info.n_lines == 17);
    CHECK(info.n_ignored == 5);
    CHECK(m.pos[0] == 1 && m.pos[1] == 2 && m.pos[2] == 3);
    CHECK(m.pos[6] == -1.5f && m.pos[7] == 0.25f && m.pos[8] == 0.5f);
    CHECK(m.uv[0] == 0.25f && m.uv[1] == 0.75f && m.uv[2] == 0.5f && m.uv[3] == 0.0f);
    mlb_mesh_free(&m);
    // a backslash at the end of a comment does not swallow the next line
    REQUIRE(parse_str("# C:\\models\\\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", &m, NULL) == MLB_OK);
    CHECK(m.n_faces == 1);
    mlb_mesh_free(&m);
    // degenerate polygons and a long one: kept / fanned
    char big[200000];
    int n = snprintf(big, sizeof big, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 1 2\nf");
    for (int i = 0; i < 5000; i++) n += snprintf(big + n, sizeof big - (size_t)n, " %d", 1 + i % 3);
    snprintf(big + n, sizeof big - (size_t)n, "\n");
    REQUIRE(parse_str(big, &m, &info) == MLB_OK);
    CHECK(m.n_faces == 1 + 4998 && info.n_polygons == 2);
    mlb_mesh_free(&m);
}

// Every number written in the usual ways parses to the float strtof gives (fast path or not).
TEST(numbers_exact) {
    enum { N = 6000 };
    size_t cap = (size_t)N * 64 + 64;
    char* t = malloc(cap);
    float* want = malloc(N * sizeof(float));
    REQUIRE(t && want);
    size_t n = 0;
    for (int i = 0; i < N; i++) {
        double u = mlb_rng_uniform(7, 1, (uint64_t)i), e = mlb_rng_uniform(7, 2, (uint64_t)i);
        double x = (u * 2 - 1) * pow(10.0, floor(e * 16) - 8);
        char num[48];
        switch (i % 6) {
        case 0: snprintf(num, sizeof num, "%.6f", x); break;
        case 1: snprintf(num, sizeof num, "%.9g", x); break;
        case 2: snprintf(num, sizeof num, "%.3e", x); break;
        case 3: snprintf(num, sizeof num, "%.17g", x); break;
        case 4: snprintf(num, sizeof num, "%.4f", x); break;
        default: snprintf(num, sizeof num, "%.8E", x); break;
        }
        want[i] = strtof(num, NULL);
        n += (size_t)snprintf(t + n, cap - n, "%s%s", i % 3 == 0 ? "v " : " ", num);
        if (i % 3 == 2) t[n++] = '\n';
    }
    // reference every vertex: one triangle per vertex (i, i, i)
    mlb_mesh m;
    mlb_obj_options opt = {0};
    size_t n2 = n;
    char* t2 = malloc(n2 + (size_t)N / 3 * 40 + 64);
    REQUIRE(t2);
    memcpy(t2, t, n2);
    for (int i = 1; i <= N / 3; i++) n2 += (size_t)sprintf(t2 + n2, "f %d %d %d\n", i, i, i);
    REQUIRE(mlb_obj_parse(t2, n2, "num.obj", &m, &opt, NULL) == MLB_OK);
    REQUIRE(m.n_verts == N / 3);
    int bad = 0;
    for (int i = 0; i < N; i++) {
        uint32_t a, b;
        memcpy(&a, &m.pos[i], 4);
        memcpy(&b, &want[i], 4);
        if (a != b && bad++ < 5) printf("  number %d: got %.9g, strtof %.9g\n", i, m.pos[i], want[i]);
    }
    CHECK(bad == 0);
    mlb_mesh_free(&m);
    free(t);
    free(t2);
    free(want);
}

// ---- malformed files ----

typedef struct {
    const char* text;
    size_t len;            // 0: strlen
    mlb_status status;
    const char* expect;    // substring of the message (after "file: ")
} bad_case;

TEST(malformed_corpus) {
    static const char tri[] = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    static const char elf[] = "\x7f" "ELF\x02\x01\x01\x00\x00\x00\x00\x00";
    static const char nul[] = "v 0 0 0\nv 1\0 0 0\n";
    char longline[70000];
    memset(longline, '1', sizeof longline);
    memcpy(longline, "v ", 2);
    longline[sizeof longline - 1] = 0;
    const bad_case cases[] = {
        {"v 1 2\n", 0, MLB_ERR_FORMAT, "line 1: 'v' needs 3 coordinates, got 2"},
        {"v 1 2 x\n", 0, MLB_ERR_FORMAT, "line 1: malformed number 'x' in 'v'"},
        {"v 0 0 0\nv 1e39 0 0\n", 0, MLB_ERR_FORMAT, "line 2: number '1e39' in 'v' is out of float range"},
        {"v nan 0 0\n", 0, MLB_ERR_FORMAT, "line 1: malformed number 'nan'"},
        {"v inf 0 0\n", 0, MLB_ERR_FORMAT, "line 1: malformed number 'inf'"},
        {"v 0x1p3 0 0\n", 0, MLB_ERR_FORMAT, "line 1: malformed number '0x1p3'"},
        {"v 1.2.3 0 0\n", 0, MLB_ERR_FORMAT, "line 1: malformed number '1.2.3'"},
        {"v 1e 0 0\n", 0, MLB_ERR_FORMAT, "line 1: malformed number '1e'"},
        {"v - 0 0\n", 0, MLB_ERR_FORMAT, "line 1: malformed number '-'"},
        {"v 1,5 0 0\n", 0, MLB_ERR_FORMAT, "line 1: malformed number '1,5'"},
        {"v 1 2 3 4 5 6 7 8\n", 0, MLB_ERR_FORMAT, "line 1: 'v' with more than 7 numbers"},
        {"vt\n", 0, MLB_ERR_FORMAT, "line 1: 'vt' needs at least 1 coordinate"},
        {"vt 1 2 3 4\n", 0, MLB_ERR_FORMAT, "line 1: 'vt' with more than 3 numbers"},
        {"vn 0 1\n", 0, MLB_ERR_FORMAT, "line 1: 'vn' needs 3 components, got 2"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", 0, MLB_ERR_FORMAT, "line 4: face corner '0': position index 0 is invalid"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", 0, MLB_ERR_FORMAT,
         "line 4: face corner '4': position index 4 out of range (3 defined so far)"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n", 0, MLB_ERR_FORMAT,
         "line 4: face corner '-4': relative position index -4 out of range (3 defined so far)"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 99999999999999999999 1 2\n", 0, MLB_ERR_FORMAT,
         "line 4: face corner '99999999999999999999': position index out of range"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\n", 0, MLB_ERR_FORMAT,
         "line 4: face corner '1/1': texture coordinate index 1 out of range (0 defined so far)"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\n\nf 1//1 2//2 3//1\n", 0, MLB_ERR_FORMAT,
         "line 6: face corner '2//2': normal index 2 out of range (1 defined so far)"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2\n", 0, MLB_ERR_FORMAT, "line 5: face with 2 corners (at least 3"},
        {"v 0 0 0\nf\n", 0, MLB_ERR_FORMAT, "line 2: face with 0 corners"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/2/3/4 2 3\n", 0, MLB_ERR_FORMAT, "line 4: malformed face corner '1/2/3/4'"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3/\n", 0, MLB_ERR_FORMAT, "line 4: malformed face corner '3/'"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf /1 2 3\n", 0, MLB_ERR_FORMAT, "line 4: malformed face corner '/1'"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1// 2 3\n", 0, MLB_ERR_FORMAT, "line 4: malformed face corner '1//'"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", 0, MLB_ERR_FORMAT, "line 4: malformed face corner 'x'"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3.0\n", 0, MLB_ERR_FORMAT, "line 4: malformed face corner '3.0'"},
        // truncated in the middle of a face
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2", 0, MLB_ERR_FORMAT, "line 4: face with 2 corners"},
        {"v 0 0 0\nvt 0 0\nv 1 0 0\nv 0 1 0\nf 1/1/", 0, MLB_ERR_FORMAT, "line 5: malformed face corner '1/1/'"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\n", 0, MLB_ERR_FORMAT, "no faces in 3 lines (3 positions)"},
        {"", 0, MLB_ERR_FORMAT, "no faces in 0 lines"},
        {elf, sizeof elf - 1, MLB_ERR_FORMAT, "line 1: control byte 0x02 at column 5 (binary data"},
        {nul, sizeof nul - 1, MLB_ERR_FORMAT, "line 2: control byte 0x00 at column 4"},
        {"v 0 0 0\n\xff\xfe\x01", 0, MLB_ERR_FORMAT, "line 2: control byte 0x01"},
        {"v 0 0 0\n\xff\xfe garbage\n", 0, MLB_ERR_FORMAT, "line 2: not an OBJ statement"},
        {"v 0 0 0\n%%! 1 2\n", 0, MLB_ERR_FORMAT, "line 2: not an OBJ statement (a statement starts with a keyword"},
        // another file's words are not repeated: a password file's first line, a word on a 'v' line
        {"root:$y$j9T$SECRET:19000:0:99999:7:::\n", 0, MLB_ERR_FORMAT, "line 1: not an OBJ statement"},
        {"v 1 hunter2 0\n", 0, MLB_ERR_FORMAT, "line 1: malformed number of 7 bytes in 'v'"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 secret\n", 0, MLB_ERR_FORMAT, "line 4: malformed face corner of 6 bytes"},
        {longline, 0, MLB_ERR_FORMAT, "line 1: statement longer than 65536 bytes"},
        // joined lines: statement errors name the first line, byte errors the physical line
        {"v 0 0 0\nv 1 \\\n 2\n", 0, MLB_ERR_FORMAT, "line 2: 'v' needs 3 coordinates, got 2"},
        {"v 0 0 0\nf 1 \\\n 2\x01 3\n", 0, MLB_ERR_FORMAT, "line 3: control byte 0x01 at column 3"},
        {"cstype bspline\ndeg 3\ncurv 0 1 1 2 3 4\n", 0, MLB_ERR_UNSUPPORTED, "line 3: free-form geometry ('curv')"},
    };
    int n_cases = (int)(sizeof cases / sizeof cases[0]);
    for (int i = 0; i < n_cases; i++) {
        char path[4200];
        snprintf(path, sizeof path, "%s/bad_%02d.obj", tmp, i);
        size_t len = cases[i].len ? cases[i].len : strlen(cases[i].text);
        REQUIRE(write_text(path, cases[i].text, len));
        mlb_mesh m;
        memset(&m, 0x5a, sizeof m);   // garbage in: must come back zeroed
        mlb_obj_info info;
        mlb_status s = mlb_obj_load_ex(path, &m, NULL, &info);
        const char* msg = mlb_last_error();
        CHECK_MSG(s == cases[i].status, "case %d: status %s, expected %s (%s)", i, mlb_status_name(s),
                  mlb_status_name(cases[i].status), msg);
        CHECK_MSG(strncmp(msg, path, strlen(path)) == 0 && strstr(msg, cases[i].expect),
                  "case %d: message '%s' lacks '%s: ...%s'", i, msg, path, cases[i].expect);
        CHECK_MSG(mesh_is_zero(&m), "case %d: mesh not zeroed", i);
        CHECK_MSG(!strstr(msg, "SECRET") && !strstr(msg, "hunter2") && !strstr(msg, "secret"), "case %d: '%s' quotes the file", i, msg);
        // the same bytes from memory give the same message, with the given name
        s = mlb_obj_parse(cases[i].text, len, "in-memory", &m, NULL, NULL);
        CHECK(s == cases[i].status && strstr(mlb_last_error(), cases[i].expect) && mesh_is_zero(&m));
    }
    (void)tri;
}

TEST(limits_and_file_errors) {
    mlb_mesh m;
    char path[4200];
    // triangle limit: the polygon crossing it is named
    mlb_obj_options opt = {0};
    opt.max_triangles = 3;
    const char* t = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 1 2 4 3\nf 1 2 3\n";
    mlb_status s = mlb_obj_parse(t, strlen(t), "lim.obj", &m, &opt, NULL);
    CHECK(s == MLB_ERR_UNSUPPORTED && strstr(mlb_last_error(), "lim.obj: line 7: more than 3 triangles"));
    CHECK(mesh_is_zero(&m));
    // statement length limit
    opt = (mlb_obj_options){0};
    opt.max_line = 16;
    t = "v 0 0 0\nv 1.000000 0.000000 0\n";
    s = mlb_obj_parse(t, strlen(t), "lim.obj", &m, &opt, NULL);
    CHECK(s == MLB_ERR_FORMAT && strstr(mlb_last_error(), "lim.obj: line 2: statement longer than 16 bytes"));
    // file size limit, checked before reading
    snprintf(path, sizeof path, "%s/size.obj", tmp);
    REQUIRE(write_text(path, cube_obj, strlen(cube_obj)));
    opt = (mlb_obj_options){0};
    opt.max_bytes = 100;
    s = mlb_obj_load_ex(path, &m, &opt, NULL);
    CHECK(s == MLB_ERR_UNSUPPORTED && strstr(mlb_last_error(), path) && strstr(mlb_last_error(), "more than the 100"));
    CHECK(mesh_is_zero(&m));
    // missing file, folder
    snprintf(path, sizeof path, "%s/missing.obj", tmp);
    s = mlb_obj_load(path, &m);
    CHECK(s == MLB_ERR_NOT_FOUND && strstr(mlb_last_error(), path));
    s = mlb_obj_load(tmp, &m);
    CHECK(s == MLB_ERR_IO && strstr(mlb_last_error(), tmp));
    CHECK(mesh_is_zero(&m));
    // bad arguments
    CHECK(mlb_obj_load(NULL, &m) == MLB_ERR_ARG);
    CHECK(mlb_obj_load(path, NULL) == MLB_ERR_ARG);
    CHECK(mlb_obj_parse(NULL, 5, "x", &m, NULL, NULL) == MLB_ERR_ARG);
}

// A large grid (320k triangles, ~13 MB of text), and 300k copies of one triangle: both must
// load (linear work, no quadratic hash behaviour) and give the right counts.
TEST(large_inputs) {
    enum { G = 400 };   // (G+1)^2 positions, 2 G^2 triangles per copy
    size_t cap = (size_t)(G + 1) * (G + 1) * 40 + (size_t)G * G * 80 + 64;
    char* t = malloc(cap);
    REQUIRE(t);
    size_t n = 0;
    for (int y = 0; y <= G; y++)
        for (int x = 0; x <= G; x++) n += (size_t)snprintf(t + n, cap - n, "v %.6f %.6f 0\nvt %d %d\n", x / (double)G, y / (double)G, x, y);
    for (int y = 0; y < G; y++)
        for (int x = 0; x < G; x++) {
            int a = y * (G + 1) + x + 1, b = a + 1, c = a + G + 1, d = c + 1;
            n += (size_t)snprintf(t + n, cap - n, "f %d/%d %d/%d %d/%d %d/%d\n", a, a, b, b, d, d, c, c);
        }
    mlb_mesh m;
    mlb_obj_info info;
    REQUIRE(mlb_obj_parse(t, n, "grid.obj", &m, NULL, &info) == MLB_OK);
    CHECK(m.n_verts == (G + 1) * (G + 1) && m.n_faces == 2 * G * G && info.n_polygons_split == G * G);
    REQUIRE(mlb_mesh_compute_normals(&m) == MLB_OK);
    int bad = 0;
    for (int i = 0; i < m.n_verts; i++) bad += m.normal[3 * i + 2] != 1.0f;
    CHECK(bad == 0);
    mlb_mesh_free(&m);
    n = (size_t)snprintf(t, cap, "v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    for (int i = 0; i < 300000; i++) n += (size_t)snprintf(t + n, cap - n, "f -3 -2 -1\n");
    REQUIRE(mlb_obj_parse(t, n, "same.obj", &m, NULL, NULL) == MLB_OK);
    CHECK(m.n_verts == 3 && m.n_faces == 300000);
    mlb_mesh_free(&m);
    free(t);
}

// ---- mesh utilities ----

static void set_mesh(mlb_mesh* m, const float* pos, int nv, const int32_t* faces, int nf) {
    memset(m, 0, sizeof *m);
    m->n_verts = nv;
    m->n_faces = nf;
    m->pos = malloc((size_t)nv * 3 * sizeof(float));
    m->faces = malloc((size_t)nf * 3 * sizeof(int32_t));
    memcpy(m->pos, pos, (size_t)nv * 3 * sizeof(float));
    memcpy(m->faces, faces, (size_t)nf * 3 * sizeof(int32_t));
}

TEST(normals_area_weighted) {
    // octahedron: by symmetry each vertex normal is its own direction, exactly
    const float op[] = {1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1};
    const int32_t of[] = {0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5};
    mlb_mesh m;
    set_mesh(&m, op, 6, of, 8);
    REQUIRE(mlb_mesh_compute_normals(&m) == MLB_OK);
    for (int i = 0; i < 18; i++) CHECK_CLOSE(m.normal[i], op[i], 0, 1e-7);
    mlb_mesh_free(&m);

    // area weighting: vertex 0 is shared by a triangle of area 2 in the plane z=0 (normal +z) and
    // one of area 1/2 in the plane x=0 (normal +x): n0 = normalize(2 z + 0.5 x)
    const float ap[] = {0, 0, 0, 2, 0, 0, 0, 2, 0, 0, 0, 1, 0, -1, 0};
    const int32_t af[] = {0, 1, 2, 0, 3, 4};   // (0,0,0)(2,0,0)(0,2,0): +z area 2; (0,0,0)(0,0,1)(0,-1,0): +x area 1/2
    set_mesh(&m, ap, 5, af, 2);
    REQUIRE(mlb_mesh_compute_normals(&m) == MLB_OK);
    double l = sqrt(4.0 + 0.25);
    CHECK_CLOSE(m.normal[0], 0.5 / l, 0, 1e-7);
    CHECK_CLOSE(m.normal[1], 0, 0, 1e-7);
    CHECK_CLOSE(m.normal[2], 2 / l, 0, 1e-7);
    CHECK(m.normal[5] == 1 && m.normal[9] == 1);   // vertices of one face only: that face's normal
    mlb_mesh_free(&m);

    // UV sphere: area-weighted normals approach the radial direction
    enum { NU = 96, NV = 48 };
    int nv = NU * (NV - 1) + 2, nf = 2 * NU * (NV - 2) + 2 * NU;
    float* sp = malloc((size_t)nv * 3 * sizeof(float));
    int32_t* sf = malloc((size_t)nf * 3 * sizeof(int32_t));
    REQUIRE(sp && sf);
    int k = 0;
    for (int j = 1; j < NV; j++)
        for (int i = 0; i < NU; i++) {
            double th = M_PI * j / NV, ph = 2 * M_PI * i / NU;
            sp[k++] = (float)(3 * sin(th) * cos(ph));
            sp[k++] = (float)(3 * sin(th) * sin(ph));
            sp[k++] = (float)(3 * cos(th));
        }
    int top = nv - 2, bot = nv - 1;
    sp[3 * top] = sp[3 * top + 1] = 0; sp[3 * top + 2] = 3;
    sp[3 * bot] = sp[3 * bot + 1] = 0; sp[3 * bot + 2] = -3;
    int f = 0;
#define V(j, i) ((j) * NU + ((i) % NU))
    for (int j = 0; j < NV - 2; j++)
        for (int i = 0; i < NU; i++) {   // outward CCW: rows go from +z to -z, columns counter-clockwise
            int32_t a = V(j, i), b = V(j + 1, i), c = V(j + 1, i + 1), d = V(j, i + 1);
            sf[f++] = a; sf[f++] = b; sf[f++] = c;
            sf[f++] = a; sf[f++] = c; sf[f++] = d;
        }
    for (int i = 0; i < NU; i++) {
        sf[f++] = top; sf[f++] = V(0, i); sf[f++] = V(0, i + 1);
        sf[f++] = bot; sf[f++] = V(NV - 2, i + 1); sf[f++] = V(NV - 2, i);
    }
#undef V
    REQUIRE(f == 3 * nf);
    set_mesh(&m, sp, nv, sf, nf);
    REQUIRE(mlb_mesh_compute_normals(&m) == MLB_OK);
    double worst = 1;
    for (int i = 0; i < nv; i++) {
        double d = 0;
        for (int c = 0; c < 3; c++) d += m.normal[3 * i + c] * sp[3 * i + c] / 3.0;
        worst = fmin(worst, d);
    }
    CHECK_MSG(worst > 0.9995, "smallest cosine to the radial direction %.6f", worst);
    mlb_mesh_free(&m);
    free(sp);
    free(sf);
}

TEST(normals_weld_seams_and_errors) {
    // two triangles meeting along an edge, the shared edge's vertices duplicated (as a uv seam
    // does): the copies get the same normal, as if welded
    const float p[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, /* copies */ 1, 0, 0, 0, 1, 0, /* */ 1, 1, 1};
    const int32_t fa[] = {0, 1, 2, 3, 5, 4};
    mlb_mesh m;
    set_mesh(&m, p, 6, fa, 2);
    REQUIRE(mlb_mesh_compute_normals(&m) == MLB_OK);
    for (int c = 0; c < 3; c++) {
        CHECK(m.normal[3 + c] == m.normal[9 + c]);
        CHECK(m.normal[6 + c] == m.normal[12 + c]);
    }
    // expected at the seam: normalize(n1 + n2), n1 = (0,0,1), n2 = cross((0,1,1),(-1,1,0)) = (-1,-1,1)
    double l = sqrt(1 + 1 + 4);
    CHECK_CLOSE(m.normal[3], -1 / l, 0, 1e-7);
    CHECK_CLOSE(m.normal[4], -1 / l, 0, 1e-7);
    CHECK_CLOSE(m.normal[5], 2 / l, 0, 1e-7);
    mlb_mesh_free(&m);
    // an unused vertex and a degenerate triangle get (0, 0, 1)
    const float q[] = {0, 0, 0, 1, 1, 1, 2, 2, 2, 5, 5, 5};
    const int32_t qf[] = {0, 1, 2};
    set_mesh(&m, q, 4, qf, 1);
    REQUIRE(mlb_mesh_compute_normals(&m) == MLB_OK);
    for (int i = 0; i < 4; i++) CHECK(m.normal[3 * i] == 0 && m.normal[3 * i + 1] == 0 && m.normal[3 * i + 2] == 1);
    // errors: an index out of range, a NaN position; the mesh keeps its normals
    m.faces[2] = 7;
    CHECK(mlb_mesh_compute_normals(&m) == MLB_ERR_ARG && strstr(mlb_last_error(), "face 0 uses vertex 7"));
    m.faces[2] = 2;
    m.pos[4] = NAN;
    CHECK(mlb_mesh_compute_normals(&m) == MLB_ERR_NUMERIC && strstr(mlb_last_error(), "vertex 1"));
    CHECK(m.normal && m.normal[2] == 1);
    CHECK(mlb_mesh_compute_normals(NULL) == MLB_ERR_ARG);
    mlb_mesh_free(&m);
    mlb_mesh_free(&m);   // twice: safe
    CHECK(mlb_mesh_compute_normals(&m) == MLB_OK);   // empty mesh
}

TEST(bounds_and_unit_sphere) {
    const float p[] = {1, 2, 3, -1, 5, 3.5f, 0, 0, 10, 4, 2, 3};
    const int32_t f[] = {0, 1, 2};
    mlb_mesh m;
    set_mesh(&m, p, 4, f, 1);
    float lo[3], hi[3];
    mlb_mesh_bounds(&m, lo, hi);
    CHECK(lo[0] == -1 && lo[1] == 0 && lo[2] == 3 && hi[0] == 4 && hi[1] == 5 && hi[2] == 10);
    mlb_mesh_normalize_unit_sphere(&m);
    // centre of the box (1.5, 2.5, 6.5); farthest vertex from it at distance r
    double r = 0;
    for (int i = 0; i < 4; i++) {
        double dx = p[3 * i] - 1.5, dy = p[3 * i + 1] - 2.5, dz = p[3 * i + 2] - 6.5;
        r = fmax(r, sqrt(dx * dx + dy * dy + dz * dz));
    }
    double rmax = 0;
    for (int i = 0; i < 4; i++) {
        CHECK_CLOSE(m.pos[3 * i], (p[3 * i] - 1.5) / r, 0, 2e-6);
        CHECK_CLOSE(m.pos[3 * i + 1], (p[3 * i + 1] - 2.5) / r, 0, 2e-6);
        CHECK_CLOSE(m.pos[3 * i + 2], (p[3 * i + 2] - 6.5) / r, 0, 2e-6);
        const float* q = m.pos + 3 * i;
        rmax = fmax(rmax, sqrt((double)q[0] * q[0] + (double)q[1] * q[1] + (double)q[2] * q[2]));
    }
    CHECK(rmax <= 1.0 && rmax > 1 - 1e-5);
    mlb_mesh_bounds(&m, lo, hi);
    for (int k = 0; k < 3; k++) CHECK_CLOSE(lo[k] + hi[k], 0, 0, 1e-6);
    mlb_mesh_free(&m);
    // a mesh collapsed to one point is only moved; an empty one is left alone
    const float one[] = {2, 2, 2, 2, 2, 2, 2, 2, 2};
    set_mesh(&m, one, 3, f, 1);
    mlb_mesh_normalize_unit_sphere(&m);
    for (int i = 0; i < 9; i++) CHECK(m.pos[i] == 0);
    mlb_mesh_free(&m);
    mlb_mesh_bounds(&m, lo, hi);
    CHECK(lo[0] == 0 && hi[2] == 0);
    mlb_mesh_normalize_unit_sphere(&m);
    mlb_mesh_normalize_unit_sphere(NULL);
}

int main(void) {
    tmp = test_tmpdir("obj");
    if (!tmp) { printf("cannot create a scratch folder\n"); return 1; }
    RUN(real_spot);
    RUN(real_bob);
    RUN(cube_quads_negative_indices);
    RUN(corner_forms_and_unification);
    RUN(repairs_and_tolerated_syntax);
    RUN(numbers_exact);
    RUN(malformed_corpus);
    RUN(limits_and_file_errors);
    RUN(large_inputs);
    RUN(normals_area_weighted);
    RUN(normals_weld_seams_and_errors);
    RUN(bounds_and_unit_sphere);
    return test_summary();
}
