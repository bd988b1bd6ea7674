// Wavefront OBJ reader (subset and policies in include/matlaber/obj.h and docs/files.md).
// One pass over the text: v/vt/vn go into growing arrays, every face corner is resolved to
// 0-based (v, vt, vn) indices at once (negative indices are relative to what is defined so far),
// polygons are fanned into triangles. Afterwards a hash map from index triples to output vertices
// builds the unified mesh. Everything is linear in the file size; nothing is written to `out`
// until the whole file has been accepted.
#include "matlaber/obj.h"
#include <errno.h>
#include <locale.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/fileio.h"

typedef struct { int32_t v, t, n; } corner;   // 0-based indices, -1 = absent

typedef struct {
    const char* name;
    int line;                  // line of the statement being parsed (its first line)
    size_t max_line, max_tris;
    locale_t loc;
    float* pos; size_t n_pos, cap_pos;    // 3 floats each
    float* tex; size_t n_tex, cap_tex;    // 2 floats each
    float* nrm; size_t n_nrm, cap_nrm;    // 3 floats each
    corner* cor; size_t n_cor, cap_cor;   // 3 per triangle
    char* stmt; size_t stmt_cap;          // the current statement, NUL-terminated
    int t_present, t_missing, n_present, n_missing;
    mlb_obj_info info;
} parser;

// "name: line N: " + message, with `code`: PERR(P, code, fmt, ...).
#define PERR(P, code, ...) perr_line(P, mlb_fail(code, __VA_ARGS__))
static mlb_status perr_line(const parser* P, mlb_status code) { return mlb_fail_context(code, "%s: line %d", P->name, P->line); }

// A token as a message shows it: quoted when it could be a number or a face corner (at most 24
// bytes of digits, signs, points, commas, slashes and the letters of e, 0x, nan, inf), else only its
// length. The file may be anything (a password file given as a mesh): its words are not repeated.
static const char* show(const char* s, char buf[48]) {
    size_t n = strlen(s);
    int ok = n <= 24;
    for (size_t i = 0; ok && i < n; i++) ok = strchr("0123456789+-.,/eExXpPnaifNAIF", s[i]) != NULL;
    if (ok) snprintf(buf, 48, "'%s'", s);
    else snprintf(buf, 48, "of %zu bytes", n);
    return buf;
}

// ---- numbers ----

static const float pow10f_exact[11] = {1e0f, 1e1f, 1e2f, 1e3f, 1e4f, 1e5f, 1e6f, 1e7f, 1e8f, 1e9f, 1e10f};

// Decimal floating point, as OBJ exporters write it: [+-] digits [. digits] [(e|E) [+-] digits]
// (digits on at least one side of the point). No hex, inf or nan. Returns 0 ok, 1 malformed,
// 2 out of float range. Short numbers take an exact fast path: when the decimal mantissa fits in
// 24 bits and the power of ten is at most 10, both are exact floats and one IEEE multiply or
// divide gives the correctly rounded result, the same float strtof would. Others go to strtof_l
// in the C locale (so a program's setlocale cannot turn the decimal point into a comma).
static int parse_float(const char* s, locale_t loc, float* out) {
    const char* p = s;
    int neg = 0;
    if (*p == '+' || *p == '-') neg = (*p++ == '-');
    uint64_t mant = 0;
    int digits = 0, frac = 0, big = 0;
    for (; *p >= '0' && *p <= '9'; p++, digits++) {
        if (mant > ((uint64_t)1 << 40)) big = 1;
        else mant = mant * 10 + (uint64_t)(*p - '0');
    }
    if (*p == '.') {
        p++;
        for (; *p >= '0' && *p <= '9'; p++, digits++, frac++) {
            if (mant > ((uint64_t)1 << 40)) big = 1;
            else mant = mant * 10 + (uint64_t)(*p - '0');
        }
    }
    if (digits == 0) return 1;
    long e10 = 0;
    if (*p == 'e' || *p == 'E') {
        p++;
        int eneg = 0;
        if (*p == '+' || *p == '-') eneg = (*p++ == '-');
        if (!(*p >= '0' && *p <= '9')) return 1;
        for (; *p >= '0' && *p <= '9'; p++)
            if (e10 < 100000) e10 = e10 * 10 + (*p - '0');
        if (eneg) e10 = -e10;
    }
    if (*p) return 1;
    e10 -= frac;
    if (!big && mant <= ((uint64_t)1 << 24) && e10 >= -10 && e10 <= 10) {
        float m = (float)mant;
        float v = e10 < 0 ? m / pow10f_exact[-e10] : m * pow10f_exact[e10];
        *out = neg ? -v : v;
        return 0;
    }
    errno = 0;
    char* end = NULL;
    float v = strtof_l(s, &end, loc);
    if (end != p) return 1;
    if (!isfinite(v)) return 2;   // overflow (ERANGE with HUGE_VALF); underflow to 0 is accepted
    *out = v;
    return 0;
}

// ---- tokens ----

static int is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v'; }

// Next whitespace-separated token of the statement at *cur (NUL-terminated in place), or NULL.
static char* next_token(char** cur) {
    char* p = *cur;
    while (is_space(*p)) p++;
    if (!*p) { *cur = p; return NULL; }
    char* t = p;
    while (*p && !is_space(*p)) p++;
    if (*p) *p++ = 0;
    *cur = p;
    return t;
}

static mlb_status read_numbers(parser* P, char** cur, const char* kw, float* vals, int max, int* count) {
    char* tok;
    char b[48];
    int k = 0;
    while ((tok = next_token(cur))) {
        if (k == max) return PERR(P, MLB_ERR_FORMAT, "'%s' with more than %d numbers", kw, max);
        int r = parse_float(tok, P->loc, &vals[k]);
        if (r == 1) return PERR(P, MLB_ERR_FORMAT, "malformed number %s in '%s'", show(tok, b), kw);
        if (r == 2) return PERR(P, MLB_ERR_FORMAT, "number %s in '%s' is out of float range", show(tok, b), kw);
        k++;
    }
    *count = k;
    return MLB_OK;
}

// ---- statements ----

static mlb_status stmt_v(parser* P, char** cur) {
    float x[7];
    int k = 0;
    MLB_TRY(read_numbers(P, cur, "v", x, 7, &k));
    if (k < 3) return PERR(P, MLB_ERR_FORMAT, "'v' needs 3 coordinates, got %d", k);
    if (P->n_pos >= INT32_MAX) return PERR(P, MLB_ERR_UNSUPPORTED, "more than %d positions", INT32_MAX);
    if (!mlb_reserve((void**)&P->pos, &P->cap_pos, 3 * (P->n_pos + 1), sizeof(float)))
        return PERR(P, MLB_ERR_NOMEM, "out of memory for %zu positions", P->n_pos + 1);
    memcpy(P->pos + 3 * P->n_pos, x, 3 * sizeof(float));   // w (x[3]) and colours (x[3..6]) are ignored
    P->n_pos++;
    return MLB_OK;
}

static mlb_status stmt_vt(parser* P, char** cur) {
    float x[3] = {0, 0, 0};
    int k = 0;
    MLB_TRY(read_numbers(P, cur, "vt", x, 3, &k));
    if (k < 1) return PERR(P, MLB_ERR_FORMAT, "'vt' needs at least 1 coordinate, got 0");
    if (P->n_tex >= INT32_MAX) return PERR(P, MLB_ERR_UNSUPPORTED, "more than %d texture coordinates", INT32_MAX);
    if (!mlb_reserve((void**)&P->tex, &P->cap_tex, 2 * (P->n_tex + 1), sizeof(float)))
        return PERR(P, MLB_ERR_NOMEM, "out of memory for %zu texture coordinates", P->n_tex + 1);
    P->tex[2 * P->n_tex] = x[0];
    P->tex[2 * P->n_tex + 1] = x[1];   // 0 when absent; the third (w) is ignored
    P->n_tex++;
    return MLB_OK;
}

static mlb_status stmt_vn(parser* P, char** cur) {
    float x[3];
    int k = 0;
    MLB_TRY(read_numbers(P, cur, "vn", x, 3, &k));
    if (k != 3) return PERR(P, MLB_ERR_FORMAT, "'vn' needs 3 components, got %d", k);
    if (P->n_nrm >= INT32_MAX) return PERR(P, MLB_ERR_UNSUPPORTED, "more than %d normals", INT32_MAX);
    if (!mlb_reserve((void**)&P->nrm, &P->cap_nrm, 3 * (P->n_nrm + 1), sizeof(float)))
        return PERR(P, MLB_ERR_NOMEM, "out of memory for %zu normals", P->n_nrm + 1);
    memcpy(P->nrm + 3 * P->n_nrm, x, 3 * sizeof(float));
    P->n_nrm++;
    return MLB_OK;
}

// One index of a corner: [+-]digits. Returns the pointer after it, or NULL when malformed.
static const char* parse_index(const char* p, long long* out) {
    int neg = 0;
    if (*p == '+' || *p == '-') neg = (*p++ == '-');
    if (!(*p >= '0' && *p <= '9')) return NULL;
    long long v = 0;
    for (; *p >= '0' && *p <= '9'; p++)
        if (v < ((long long)1 << 40)) v = v * 10 + (*p - '0');   // saturates far beyond any count
    *out = neg ? -v : v;
    return p;
}

static mlb_status resolve(parser* P, const char* tok, long long idx, size_t count, const char* what, int32_t* out) {
    char b[48];
    if (idx == 0)
        return PERR(P, MLB_ERR_FORMAT, "face corner %s: %s index 0 is invalid (OBJ indices start at 1)", show(tok, b), what);
    unsigned long long mag = idx > 0 ? (unsigned long long)idx : (unsigned long long)(-idx);
    if (mag > count) {
        char num[32] = "";
        if (mag < ((unsigned long long)1 << 40)) snprintf(num, sizeof num, " %lld", idx);   // else saturated: the token tells
        return PERR(P, MLB_ERR_FORMAT, "face corner %s: %s%s index%s out of range (%zu defined so far)", show(tok, b),
                    idx < 0 ? "relative " : "", what, num, count);
    }
    *out = (int32_t)(idx > 0 ? idx - 1 : (long long)count + idx);
    return MLB_OK;
}

// v | v/vt | v//vn | v/vt/vn
static mlb_status parse_corner(parser* P, const char* tok, corner* c) {
    char b[48];
    long long iv = 0, it = 0, in = 0;
    int has_t = 0, has_n = 0;
    const char* p = parse_index(tok, &iv);
    if (p && *p == '/') {
        p++;
        if (*p != '/') {
            p = parse_index(p, &it);
            has_t = 1;
        }
        if (p && *p == '/') {
            p = parse_index(p + 1, &in);
            has_n = 1;
        }
    }
    if (!p || *p)
        return PERR(P, MLB_ERR_FORMAT, "malformed face corner %s (expected v, v/vt, v//vn or v/vt/vn)", show(tok, b));
    c->t = c->n = -1;
    MLB_TRY(resolve(P, tok, iv, P->n_pos, "position", &c->v));
    if (has_t) MLB_TRY(resolve(P, tok, it, P->n_tex, "texture coordinate", &c->t));
    if (has_n) MLB_TRY(resolve(P, tok, in, P->n_nrm, "normal", &c->n));
    return MLB_OK;
}

static mlb_status stmt_f(parser* P, char** cur) {
    corner first = {0, 0, 0}, prev = {0, 0, 0}, c;
    int k = 0;
    char* tok;
    while ((tok = next_token(cur))) {
        MLB_TRY(parse_corner(P, tok, &c));
        if (c.t >= 0) P->t_present = 1; else P->t_missing = 1;
        if (c.n >= 0) P->n_present = 1; else P->n_missing = 1;
        if (k == 0) first = c;
        if (k >= 2) {   // fan: (first, previous, this)
            if (P->n_cor / 3 >= P->max_tris)
                return PERR(P, MLB_ERR_UNSUPPORTED, "more than %zu triangles (the limit)", P->max_tris);
            if (!mlb_reserve((void**)&P->cor, &P->cap_cor, P->n_cor + 3, sizeof(corner)))
                return PERR(P, MLB_ERR_NOMEM, "out of memory for %zu triangles", P->n_cor / 3 + 1);
            P->cor[P->n_cor++] = first;
            P->cor[P->n_cor++] = prev;
            P->cor[P->n_cor++] = c;
        }
        prev = c;
        k++;
    }
    if (k < 3) return PERR(P, MLB_ERR_FORMAT, "face with %d corner%s (at least 3 are needed)", k, k == 1 ? "" : "s");
    P->info.n_polygons++;
    if (k > 3) P->info.n_polygons_split++;
    return MLB_OK;
}

static int is_identifier(const char* s) {
    if (!((*s >= 'a' && *s <= 'z') || (*s >= 'A' && *s <= 'Z') || *s == '_')) return 0;
    for (s++; *s; s++)
        if (!((*s >= 'a' && *s <= 'z') || (*s >= 'A' && *s <= 'Z') || (*s >= '0' && *s <= '9') || *s == '_')) return 0;
    return 1;
}

static mlb_status statement(parser* P) {
    char* cur = P->stmt;
    char* hash = strchr(cur, '#');
    if (hash) *hash = 0;   // comment to the end of the statement
    char* kw = next_token(&cur);
    if (!kw) return MLB_OK;   // blank
    if (!strcmp(kw, "v")) { P->info.n_positions++; return stmt_v(P, &cur); }
    if (!strcmp(kw, "vt")) { P->info.n_texcoords++; return stmt_vt(P, &cur); }
    if (!strcmp(kw, "vn")) { P->info.n_normals++; return stmt_vn(P, &cur); }
    if (!strcmp(kw, "f") || !strcmp(kw, "fo")) return stmt_f(P, &cur);   // fo: the old spelling of f
    if (!strcmp(kw, "curv") || !strcmp(kw, "curv2") || !strcmp(kw, "surf"))
        return PERR(P, MLB_ERR_UNSUPPORTED, "free-form geometry ('%s') is not supported; triangulate the mesh first", kw);
    if (!is_identifier(kw))   // not shown: the first word of a line of some other file
        return PERR(P, MLB_ERR_FORMAT, "not an OBJ statement (a statement starts with a keyword of letters, digits and _)");
    if (!strcmp(kw, "mtllib") && !P->info.mtllib[0]) {
        while (is_space(*cur)) cur++;
        snprintf(P->info.mtllib, sizeof P->info.mtllib, "%s", cur);
        size_t n = strlen(P->info.mtllib);
        while (n && is_space(P->info.mtllib[n - 1])) P->info.mtllib[--n] = 0;
    }
    P->info.n_ignored++;   // o g s usemtl mtllib l p vp mg lod ... and any other keyword
    return MLB_OK;
}

// Splits the text into statements (a line, or several joined by a trailing backslash), checks
// that they are text and not too long, and parses each.
static mlb_status parse_text(parser* P, const char* text, size_t n) {
    size_t i = 0;
    if (n >= 3 && (unsigned char)text[0] == 0xEF && (unsigned char)text[1] == 0xBB && (unsigned char)text[2] == 0xBF)
        i = 3;   // UTF-8 byte order mark
    int line = 0;
    while (i < n) {
        int first = ++line;
        size_t len = 0;
        for (;;) {   // one physical line per turn; continues while it ends in a backslash
            P->line = line;   // byte-level errors name the physical line
            const char* s = text + i;
            const char* nl = memchr(s, '\n', n - i);
            size_t l = nl ? (size_t)(nl - s) : n - i;
            i += l + (nl ? 1 : 0);
            if (l && s[l - 1] == '\r') l--;
            if (len + l + 1 > P->max_line)
                return PERR(P, MLB_ERR_FORMAT, "statement longer than %zu bytes (binary data, or raise max_line)", P->max_line);
            if (!mlb_reserve((void**)&P->stmt, &P->stmt_cap, len + l + 1, 1))
                return PERR(P, MLB_ERR_NOMEM, "out of memory");
            for (size_t k = 0; k < l; k++) {
                unsigned char ch = (unsigned char)s[k];
                if (ch < 32 && ch != '\t' && ch != '\r' && ch != '\f' && ch != '\v')
                    return PERR(P, MLB_ERR_FORMAT, "control byte 0x%02x at column %zu (binary data, not OBJ text)", ch,
                                k + 1);
                P->stmt[len + k] = (char)ch;
            }
            len += l;
            // A trailing backslash joins the next line (the OBJ spec's continuation), except in a
            // comment, where a Windows path could otherwise swallow the next statement.
            size_t lead = 0;
            while (lead < len && is_space(P->stmt[lead])) lead++;
            if (len && P->stmt[len - 1] == '\\' && i < n && !(lead < len && P->stmt[lead] == '#')) {
                P->stmt[len - 1] = ' ';
                line++;
                continue;
            }
            break;
        }
        P->stmt[len] = 0;
        P->line = first;   // statement errors name the line it starts on
        MLB_TRY(statement(P));
    }
    P->info.n_lines = line;
    return MLB_OK;
}

// ---- unification ----

static uint64_t hash3(int32_t a, int32_t b, int32_t c) {
    uint64_t h = (uint64_t)(uint32_t)a * 0x9E3779B97F4A7C15ull;
    h ^= (uint64_t)(uint32_t)b * 0xC2B2AE3D27D4EB4Full + (h >> 29);
    h ^= (uint64_t)(uint32_t)c * 0x165667B19E3779F9ull + (h >> 32);
    h ^= h >> 31;
    h *= 0xD6E8FEB86659FD93ull;
    return h ^ (h >> 32);
}

static mlb_status build_mesh(parser* P, const mlb_obj_options* opt, mlb_mesh* out) {
    size_t nc = P->n_cor;
    int use_t = P->t_present && !P->t_missing && !(opt && opt->drop_uv);
    int use_n = P->n_present && !P->n_missing && !(opt && opt->drop_normals);
    P->info.uv_dropped = P->t_present && P->t_missing;
    P->info.normals_dropped = P->n_present && P->n_missing;
    size_t cap = 16;
    while (cap < 2 * nc) cap *= 2;
    int32_t* table = malloc(cap * sizeof *table);
    corner* keys = malloc(nc * sizeof *keys);   // the distinct triples, in order of first use
    int32_t* faces = malloc(nc * sizeof *faces);
    unsigned char* used = calloc(P->n_pos ? P->n_pos : 1, 1);
    if (!table || !keys || !faces || !used) {
        free(table); free(keys); free(faces); free(used);
        return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for a mesh of %zu triangles", P->name, nc / 3);
    }
    memset(table, 0xff, cap * sizeof *table);
    size_t nv = 0;
    for (size_t i = 0; i < nc; i++) {
        corner k = {P->cor[i].v, use_t ? P->cor[i].t : -1, use_n ? P->cor[i].n : -1};
        size_t h = (size_t)hash3(k.v, k.t, k.n) & (cap - 1);
        while (table[h] >= 0) {
            const corner* q = &keys[table[h]];
            if (q->v == k.v && q->t == k.t && q->n == k.n) break;
            h = (h + 1) & (cap - 1);
        }
        if (table[h] < 0) {
            table[h] = (int32_t)nv;
            keys[nv++] = k;
        }
        faces[i] = table[h];
        used[k.v] = 1;
    }
    free(table);
    mlb_mesh m = {0};
    m.n_verts = (int)nv;
    m.n_faces = (int)(nc / 3);
    m.faces = faces;
    m.pos = malloc(3 * nv * sizeof(float));
    if (use_t) m.uv = malloc(2 * nv * sizeof(float));
    if (use_n) m.normal = malloc(3 * nv * sizeof(float));
    if (!m.pos || (use_t && !m.uv) || (use_n && !m.normal)) {
        free(keys); free(used);
        mlb_mesh_free(&m);
        return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for %zu vertices", P->name, nv);
    }
    for (size_t i = 0; i < nv; i++) {
        memcpy(m.pos + 3 * i, P->pos + 3 * (size_t)keys[i].v, 3 * sizeof(float));
        if (use_t) memcpy(m.uv + 2 * i, P->tex + 2 * (size_t)keys[i].t, 2 * sizeof(float));
        if (use_n) memcpy(m.normal + 3 * i, P->nrm + 3 * (size_t)keys[i].n, 3 * sizeof(float));
    }
    int unused = 0;
    for (size_t i = 0; i < P->n_pos; i++) unused += !used[i];
    P->info.n_unused_positions = unused;
    P->info.n_triangles = m.n_faces;
    free(keys);
    free(used);
    *out = m;
    return MLB_OK;
}

static void parser_free(parser* P) {
    free(P->pos); free(P->tex); free(P->nrm); free(P->cor); free(P->stmt);
    if (P->loc) freelocale(P->loc);
}

mlb_status mlb_obj_parse(const char* text, size_t n, const char* name, mlb_mesh* out, const mlb_obj_options* opt,
                         mlb_obj_info* info) {
    if (out) memset(out, 0, sizeof *out);
    if (info) memset(info, 0, sizeof *info);
    if (!name) name = "(memory)";
    if (!out || (!text && n)) return mlb_fail(MLB_ERR_ARG, "%s: mlb_obj_parse: NULL %s", name, out ? "text" : "output mesh");
    parser P;
    memset(&P, 0, sizeof P);
    P.name = name;
    P.max_line = opt && opt->max_line ? opt->max_line : MLB_OBJ_MAX_LINE;
    P.max_tris = opt && opt->max_triangles ? opt->max_triangles : MLB_OBJ_MAX_TRIANGLES;
    if (P.max_tris > (size_t)INT32_MAX / 3) P.max_tris = (size_t)INT32_MAX / 3;   // vertex ids are int32
    size_t max_bytes = opt && opt->max_bytes ? opt->max_bytes : MLB_OBJ_MAX_BYTES;
    if (n > max_bytes)
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: %zu bytes, more than the %zu allowed for an OBJ file", name, n, max_bytes);
    P.loc = newlocale(LC_NUMERIC_MASK, "C", (locale_t)0);
    if (!P.loc) return mlb_fail(MLB_ERR_NOMEM, "%s: cannot create the C locale for number parsing", name);
    mlb_status s = parse_text(&P, text, n);
    if (s == MLB_OK && P.n_cor == 0) {
        P.line = P.info.n_lines;
        s = mlb_fail(MLB_ERR_FORMAT, "%s: no faces in %d line%s (%zu positions): nothing to render", name, P.info.n_lines,
                     P.info.n_lines == 1 ? "" : "s", P.n_pos);
    }
    if (s == MLB_OK) s = build_mesh(&P, opt, out);
    if (s == MLB_OK && info) *info = P.info;
    parser_free(&P);
    return s;
}

mlb_status mlb_obj_load_ex(const char* path, mlb_mesh* out, const mlb_obj_options* opt, mlb_obj_info* info) {
    if (out) memset(out, 0, sizeof *out);
    if (info) memset(info, 0, sizeof *info);
    if (!path || !out) return mlb_fail(MLB_ERR_ARG, "mlb_obj_load: NULL %s", path ? "output mesh" : "path");
    size_t max_bytes = opt && opt->max_bytes ? opt->max_bytes : MLB_OBJ_MAX_BYTES;
    char* text = NULL;
    size_t n = 0;
    mlb_status s = mlb_read_file(path, &text, &n, max_bytes);
    if (s != MLB_OK) return s;   // its message names the path
    s = mlb_obj_parse(text, n, path, out, opt, info);
    free(text);
    return s;
}

mlb_status mlb_obj_load(const char* path, mlb_mesh* out) { return mlb_obj_load_ex(path, out, NULL, NULL); }
