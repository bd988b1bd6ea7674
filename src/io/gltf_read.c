// glTF 2.0 reader (what is read and the policies: include/matlaber/gltf.h, docs/files.md).
// The JSON goes through cJSON; then the default scene's node tree is walked, and every triangle
// primitive of every placed mesh is appended to growing vertex and face arrays. Every number taken
// from the file is an untrusted size or index: it is checked to be a whole number in range before
// any pointer arithmetic, and byte ranges are checked as "offset <= length && size <= length -
// offset" so that nothing can overflow. Nothing reaches `out` until the whole file is accepted.
#include "matlaber/gltf.h"
#include "matlaber/json_why.h"
#include <cjson/cJSON.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/fileio.h"

#define GLB_MAGIC 0x46546C67u   // "glTF"
#define GLB_JSON 0x4E4F534Au    // "JSON"
#define GLB_BIN 0x004E4942u     // "BIN\0"
#define MAX_VERTS ((size_t)1 << 28)

typedef struct {
    const char* name;        // the file, in messages
    const char* dir;         // external buffers' folder (NULL: refused)
    size_t budget;           // bytes the file and its buffers may still take
    size_t max_tris;
    int drop_uv, drop_normals;
    cJSON* root;
    const cJSON** table[5]; int table_n[5];     // TABLES[k]'s elements, indexed once (cJSON arrays are lists)
    const unsigned char* bin; size_t bin_len;   // the .glb's BIN chunk (NULL when none)
    int n_buf;
    unsigned char** owned;   // [n_buf] decoded data: URIs and external files (NULL until used)
    const unsigned char** buf; size_t* buf_len;  // [n_buf] loaded buffers (byteLength bytes)
    float* pos; float* nrm; float* uv; size_t nv, cap_v;   // vertices so far (3, 3, 2 floats)
    int32_t* tri; size_t nt, cap_t;                        // triangles so far (3 each)
    int uv_some, uv_missing, n_some, n_missing;            // primitives with / without the attribute
    mlb_gltf_info info;
} reader;

// "name: " + message, with `code`: GERR(R, code, fmt, ...).
#define GERR(R, code, ...) gerr_name(R, mlb_fail(code, __VA_ARGS__))
static mlb_status gerr_name(const reader* R, mlb_status code) { return mlb_fail_context(code, "%s", R->name); }

static uint32_t le32(const unsigned char* p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

// ---- JSON helpers: every number from the file is checked here ----

static const cJSON* item(const cJSON* obj, const char* key) { return cJSON_GetObjectItemCaseSensitive(obj, key); }

// obj[key] as a whole number in [0, max]; absent: *out = dflt, or an error when required.
static mlb_status get_size(reader* R, const cJSON* obj, const char* key, int required, size_t max, size_t dflt,
                           size_t* out, const char* what) {
    const cJSON* v = item(obj, key);
    if (!v) {
        if (required) return GERR(R, MLB_ERR_FORMAT, "%s: no %s", what, key);
        *out = dflt;
        return MLB_OK;
    }
    double d = cJSON_IsNumber(v) ? v->valuedouble : -1;
    if (!(d >= 0 && d <= (double)max && d == floor(d)))
        return GERR(R, MLB_ERR_FORMAT, "%s: %s is not a whole number in [0, %zu]", what, key, max);
    *out = (size_t)d;
    return MLB_OK;
}

// The top-level arrays that are looked up by index, each made an array of pointers once, so that a
// lookup is O(1) (cJSON's arrays are linked lists: a file of many primitives would be quadratic).
static const char* const TABLES[5] = {"buffers", "bufferViews", "accessors", "meshes", "nodes"};

static mlb_status make_tables(reader* R) {
    for (int k = 0; k < 5; k++) {
        const cJSON* a = item(R->root, TABLES[k]);
        if (a && !cJSON_IsArray(a)) return GERR(R, MLB_ERR_FORMAT, "%s is not an array", TABLES[k]);
        int n = cJSON_GetArraySize(a);
        R->table[k] = malloc(sizeof(cJSON*) * ((size_t)n + 1));
        if (!R->table[k]) return GERR(R, MLB_ERR_NOMEM, "out of memory for %d %s", n, TABLES[k]);
        int i = 0;
        const cJSON* e;
        cJSON_ArrayForEach(e, a) R->table[k][i++] = e;
        R->table_n[k] = n;
    }
    return MLB_OK;
}

// Element i of the array root[key] (an object), named "key[i]" in *what.
static mlb_status get_elem(reader* R, const char* key, size_t i, const cJSON** out, char* what, size_t what_n) {
    snprintf(what, what_n, "%s[%zu]", key, i);
    int k = 0;
    while (k < 4 && strcmp(TABLES[k], key)) k++;
    int n = R->table_n[k];
    if (i >= (size_t)n) return GERR(R, MLB_ERR_FORMAT, "%s: out of range (%d %s)", what, n, key);
    const cJSON* e = R->table[k][i];
    if (!cJSON_IsObject(e)) return GERR(R, MLB_ERR_FORMAT, "%s: not an object", what);
    *out = e;
    return MLB_OK;
}

// n finite numbers from obj[key] (an array of exactly n); absent: 0 (out untouched).
static mlb_status get_numbers(reader* R, const cJSON* obj, const char* key, int n, double* out, const char* what, int* present) {
    const cJSON* a = item(obj, key);
    *present = 0;
    if (!a) return MLB_OK;
    if (!cJSON_IsArray(a) || cJSON_GetArraySize(a) != n)
        return GERR(R, MLB_ERR_FORMAT, "%s: %s is not an array of %d numbers", what, key, n);
    for (int i = 0; i < n; i++) {
        const cJSON* v = cJSON_GetArrayItem(a, i);
        if (!cJSON_IsNumber(v) || !isfinite(v->valuedouble))
            return GERR(R, MLB_ERR_FORMAT, "%s: %s[%d] is not a finite number", what, key, i);
        out[i] = v->valuedouble;
    }
    *present = 1;
    return MLB_OK;
}

// ---- buffers ----

static int b64(int c) {
    if (c >= 'A' && c <= 'Z') return c - 'A';
    if (c >= 'a' && c <= 'z') return c - 'a' + 26;
    if (c >= '0' && c <= '9') return c - '0' + 52;
    return c == '+' ? 62 : c == '/' ? 63 : -1;
}

// Strict base64 (no whitespace; '=' only as the last one or two characters). *n: bytes decoded.
static int base64_decode(const char* s, size_t len, unsigned char* out, size_t* n) {
    size_t o = 0, pad = 0;
    while (pad < 2 && len > 0 && s[len - 1] == '=') { len--; pad++; }
    if ((len + pad) % 4 != 0 || (len % 4 == 1)) return 0;
    uint32_t acc = 0;
    int bits = 0;
    for (size_t i = 0; i < len; i++) {
        int v = b64((unsigned char)s[i]);
        if (v < 0) return 0;
        acc = (acc << 6 | (uint32_t)v) & 0xFFFFFF;
        bits += 6;
        if (bits >= 8) { bits -= 8; out[o++] = (unsigned char)(acc >> bits); }
    }
    *n = o;
    return 1;
}

static int hexval(int c) {
    return c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : c >= 'A' && c <= 'F' ? c - 'A' + 10 : -1;
}

// A relative URI as a path under R->dir: percent-decoded, no scheme, no absolute path, no "..", no
// backslash, no NUL; and (links followed) the file must lie inside the folder.
static mlb_status external_path(reader* R, const char* uri, const char* what, char* out, size_t out_n) {
    if (!R->dir) return GERR(R, MLB_ERR_UNSUPPORTED, "%s: an external file (\"%.60s\") cannot be read from memory", what, uri);
    char rel[1024];
    size_t k = 0;
    for (const char* p = uri; *p; p++) {
        int c = (unsigned char)*p;
        if (c == '%') {
            int hi = hexval((unsigned char)p[1]), lo = hi < 0 ? -1 : hexval((unsigned char)p[2]);
            if (lo < 0) return GERR(R, MLB_ERR_FORMAT, "%s: uri has a bad %% escape", what);
            c = hi * 16 + lo;
            p += 2;
        }
        if (c == 0 || c == '\\' || c == ':' || k + 1 >= sizeof rel)
            return GERR(R, MLB_ERR_FORMAT, "%s: uri \"%.60s\" is not a plain relative file name", what, uri);
        rel[k++] = (char)c;
    }
    rel[k] = 0;
    if (k == 0 || rel[0] == '/') return GERR(R, MLB_ERR_FORMAT, "%s: uri \"%.60s\" is not a relative file name", what, uri);
    for (const char* p = rel; *p;) {   // no ".." component
        const char* e = strchr(p, '/');
        size_t len = e ? (size_t)(e - p) : strlen(p);
        if (len == 2 && p[0] == '.' && p[1] == '.')
            return GERR(R, MLB_ERR_FORMAT, "%s: uri \"%.60s\" leaves the file's folder", what, uri);
        p += len + (e != NULL);
    }
    if ((size_t)snprintf(out, out_n, "%s/%s", R->dir, rel) >= out_n) return GERR(R, MLB_ERR_FORMAT, "%s: path too long", what);
    char *rd = realpath(R->dir, NULL), *rf = realpath(out, NULL);
    mlb_status s = MLB_OK;
    if (!rf) s = GERR(R, errno == ENOENT ? MLB_ERR_NOT_FOUND : MLB_ERR_IO, "%s: %s: %s", what, out, strerror(errno));
    else if (!rd || (strcmp(rd, "/") && (strncmp(rf, rd, strlen(rd)) != 0 || rf[strlen(rd)] != '/')))
        s = GERR(R, MLB_ERR_FORMAT, "%s: %s resolves outside the file's folder", what, out);
    free(rd);
    free(rf);
    return s;
}

// buffers[i] loaded (once): its first byteLength bytes.
static mlb_status get_buffer(reader* R, size_t i, const unsigned char** p, size_t* len) {
    char what[64];
    const cJSON* b;
    MLB_TRY(get_elem(R, "buffers", i, &b, what, sizeof what));
    if (R->buf[i]) { *p = R->buf[i]; *len = R->buf_len[i]; return MLB_OK; }
    size_t n;
    MLB_TRY(get_size(R, b, "byteLength", 1, SIZE_MAX / 2, 0, &n, what));
    if (n == 0) return GERR(R, MLB_ERR_FORMAT, "%s: byteLength is 0", what);
    const cJSON* uri = item(b, "uri");
    if (!uri) {   // the .glb's BIN chunk (may be up to 3 bytes longer: padding)
        if (i != 0 || !R->bin) return GERR(R, MLB_ERR_FORMAT, "%s: no uri, and the file has no BIN chunk for it", what);
        if (n > R->bin_len) return GERR(R, MLB_ERR_FORMAT, "%s: byteLength %zu, but the BIN chunk has %zu bytes", what, n, R->bin_len);
        R->buf[i] = R->bin;
    } else {
        if (!cJSON_IsString(uri)) return GERR(R, MLB_ERR_FORMAT, "%s: uri is not a string", what);
        if (n > R->budget) return GERR(R, MLB_ERR_UNSUPPORTED, "%s: byteLength %zu is over the %zu bytes left to read", what, n, R->budget);
        const char* u = uri->valuestring;
        size_t got = 0;
        unsigned char* data = NULL;
        if (!strncmp(u, "data:", 5)) {
            const char* comma = strchr(u, ',');
            if (!comma || comma - u < 12 || strncmp(comma - 7, ";base64", 7))
                return GERR(R, MLB_ERR_FORMAT, "%s: a data: uri that is not base64", what);
            size_t len = strlen(comma + 1);
            data = malloc(len / 4 * 3 + 3);
            if (!data) return GERR(R, MLB_ERR_NOMEM, "%s: out of memory", what);
            if (!base64_decode(comma + 1, len, data, &got)) { free(data); return GERR(R, MLB_ERR_FORMAT, "%s: bad base64 data", what); }
        } else {
            char path[4200];
            MLB_TRY(external_path(R, u, what, path, sizeof path));
            char* text = NULL;
            mlb_status s = mlb_read_file(path, &text, &got, R->budget);
            if (s) return mlb_fail_context(s, "%s: %s", R->name, what);
            data = (unsigned char*)text;
        }
        R->owned[i] = data;
        if (got < n) return GERR(R, MLB_ERR_FORMAT, "%s: byteLength %zu, but its data has %zu bytes", what, n, got);
        R->budget -= n;
        R->buf[i] = data;
    }
    R->buf_len[i] = n;
    *p = R->buf[i];
    *len = n;
    return MLB_OK;
}

// ---- accessors ----

typedef struct {
    const unsigned char* p;   // element 0
    size_t count, stride;
    int ctype, ncomp, csize, normalized;
} acc_t;

static int comp_size(int ctype) {
    switch (ctype) {
    case 5120: case 5121: return 1;   // (unsigned) byte
    case 5122: case 5123: return 2;   // (unsigned) short
    case 5125: case 5126: return 4;   // unsigned int, float
    default: return 0;
    }
}

// accessors[idx], every byte it covers checked to lie inside its bufferView and buffer.
static mlb_status get_accessor(reader* R, size_t idx, acc_t* A, char* what, size_t what_n) {
    const cJSON *a, *v;
    MLB_TRY(get_elem(R, "accessors", idx, &a, what, what_n));
    if (item(a, "sparse")) return GERR(R, MLB_ERR_UNSUPPORTED, "%s: sparse accessors are not read", what);
    if (!item(a, "bufferView")) return GERR(R, MLB_ERR_UNSUPPORTED, "%s: no bufferView (all zeros) is not read", what);
    size_t bv, ct, count, aoff;
    MLB_TRY(get_size(R, a, "bufferView", 1, INT_MAX, 0, &bv, what));
    MLB_TRY(get_size(R, a, "componentType", 1, 65535, 0, &ct, what));
    MLB_TRY(get_size(R, a, "count", 1, (size_t)1 << 31, 0, &count, what));
    MLB_TRY(get_size(R, a, "byteOffset", 0, SIZE_MAX / 2, 0, &aoff, what));
    A->ctype = (int)ct;
    A->csize = comp_size(A->ctype);
    if (!A->csize) return GERR(R, MLB_ERR_FORMAT, "%s: componentType %zu is not one of glTF's", what, ct);
    if (count == 0) return GERR(R, MLB_ERR_FORMAT, "%s: count is 0", what);
    const cJSON* type = item(a, "type");
    const char* t = cJSON_IsString(type) ? type->valuestring : "";
    A->ncomp = !strcmp(t, "SCALAR") ? 1 : !strcmp(t, "VEC2") ? 2 : !strcmp(t, "VEC3") ? 3 : !strcmp(t, "VEC4") ? 4 : 0;
    if (!A->ncomp) return GERR(R, MLB_ERR_FORMAT, "%s: type \"%.20s\" is not SCALAR or VEC2-4", what, t);
    const cJSON* nm = item(a, "normalized");
    A->normalized = cJSON_IsTrue(nm);
    char vwhat[64];
    MLB_TRY(get_elem(R, "bufferViews", bv, &v, vwhat, sizeof vwhat));
    size_t buf, voff, vlen, stride;
    MLB_TRY(get_size(R, v, "buffer", 1, INT_MAX, 0, &buf, vwhat));
    MLB_TRY(get_size(R, v, "byteOffset", 0, SIZE_MAX / 2, 0, &voff, vwhat));
    MLB_TRY(get_size(R, v, "byteLength", 1, SIZE_MAX / 2, 0, &vlen, vwhat));
    MLB_TRY(get_size(R, v, "byteStride", 0, 252, 0, &stride, vwhat));
    const unsigned char* base;
    size_t blen;
    MLB_TRY(get_buffer(R, buf, &base, &blen));
    if (voff > blen || vlen > blen - voff)
        return GERR(R, MLB_ERR_FORMAT, "%s: bytes %zu + %zu do not fit buffers[%zu] (%zu bytes)", vwhat, voff, vlen, buf, blen);
    size_t elem = (size_t)A->csize * (size_t)A->ncomp;
    if (stride && (stride < elem || stride % (size_t)A->csize))
        return GERR(R, MLB_ERR_FORMAT, "%s: byteStride %zu does not suit %s's %zu-byte elements", vwhat, stride, what, elem);
    A->stride = stride ? stride : elem;
    if (aoff > vlen || elem > vlen - aoff || count - 1 > (vlen - aoff - elem) / A->stride)
        return GERR(R, MLB_ERR_FORMAT, "%s: %zu elements of %zu bytes (stride %zu) from byte %zu do not fit %s (%zu bytes)",
                    what, count, elem, A->stride, aoff, vwhat, vlen);
    A->p = base + voff + aoff;
    A->count = count;
    return MLB_OK;
}

// Component c of element i as a double (normalized integers mapped to [0, 1] or [-1, 1]).
static double comp(const acc_t* A, size_t i, int c) {
    const unsigned char* p = A->p + i * A->stride + (size_t)c * (size_t)A->csize;
    switch (A->ctype) {
    case 5126: { uint32_t u = le32(p); float f; memcpy(&f, &u, 4); return f; }
    case 5125: return (double)le32(p);
    case 5121: return A->normalized ? p[0] / 255.0 : p[0];
    case 5123: { unsigned v = (unsigned)p[0] | (unsigned)p[1] << 8; return A->normalized ? v / 65535.0 : v; }
    case 5120: { double v = (int8_t)p[0]; return A->normalized ? fmax(v / 127.0, -1.0) : v; }
    default: { double v = (int16_t)(uint16_t)((unsigned)p[0] | (unsigned)p[1] << 8); return A->normalized ? fmax(v / 32767.0, -1.0) : v; }
    }
}

// An attribute accessor of the expected shape: float, or (allow_norm) one of the normalized
// integer types in `norm_types`.
static mlb_status check_attr(reader* R, const acc_t* A, const char* what, const char* attr, int ncomp, const int* norm_types) {
    int ok = A->ncomp == ncomp && A->ctype == 5126 && !A->normalized;
    for (int k = 0; norm_types && norm_types[k]; k++) ok |= A->ncomp == ncomp && A->ctype == norm_types[k] && A->normalized;
    if (!ok) return GERR(R, MLB_ERR_UNSUPPORTED, "%s: %s must be a float VEC%d%s (componentType %d, %d components%s)", what, attr,
                         ncomp, norm_types ? " or normalized integers" : "", A->ctype, A->ncomp, A->normalized ? ", normalized" : "");
    return MLB_OK;
}

// ---- the mesh under construction ----

static int grow_verts(reader* R, size_t need) {
    size_t cap = R->cap_v;
    if (!mlb_reserve((void**)&R->pos, &cap, need, 3 * sizeof(float))) return 0;
    size_t c2 = R->cap_v;
    if (!mlb_reserve((void**)&R->nrm, &c2, need, 3 * sizeof(float))) return 0;
    c2 = R->cap_v;
    if (!mlb_reserve((void**)&R->uv, &c2, need, 2 * sizeof(float))) return 0;
    R->cap_v = cap;
    return 1;
}

// m (column-major 4x4) applied to a point; n: its inverse transpose (cofactors, sign of det) to a normal.
static void transform_point(const double* m, const double* in, float* out) {
    for (int r = 0; r < 3; r++) out[r] = (float)(m[r] * in[0] + m[4 + r] * in[1] + m[8 + r] * in[2] + m[12 + r]);
}

// One primitive of a placed mesh: its vertices and triangles appended.
static mlb_status add_primitive(reader* R, const cJSON* prim, const char* pwhat, const double* M, int identity, int mirrored) {
    size_t mode;
    MLB_TRY(get_size(R, prim, "mode", 0, 6, 4, &mode, pwhat));
    if (mode < 4) { R->info.n_skipped++; return MLB_OK; }   // points, lines: no surface
    const cJSON* attrs = item(prim, "attributes");
    if (!cJSON_IsObject(attrs)) return GERR(R, MLB_ERR_FORMAT, "%s: no attributes", pwhat);
    if (!item(attrs, "POSITION")) return GERR(R, MLB_ERR_FORMAT, "%s: no POSITION", pwhat);
    char what[64], nwhat[64], twhat[64], iwhat[64] = "";
    size_t ip, in_ = 0, it = 0, ii = 0;
    acc_t P, N, T, I;
    memset(&N, 0, sizeof N);
    memset(&T, 0, sizeof T);
    memset(&I, 0, sizeof I);
    MLB_TRY(get_size(R, attrs, "POSITION", 1, INT_MAX, 0, &ip, pwhat));
    MLB_TRY(get_accessor(R, ip, &P, what, sizeof what));
    MLB_TRY(check_attr(R, &P, what, "POSITION", 3, NULL));
    int has_n = item(attrs, "NORMAL") != NULL, has_t = item(attrs, "TEXCOORD_0") != NULL;
    static const int n_norm[] = {5120, 5122, 0}, t_norm[] = {5121, 5123, 0};
    if (has_n) {
        MLB_TRY(get_size(R, attrs, "NORMAL", 1, INT_MAX, 0, &in_, pwhat));
        MLB_TRY(get_accessor(R, in_, &N, nwhat, sizeof nwhat));
        MLB_TRY(check_attr(R, &N, nwhat, "NORMAL", 3, n_norm));
        if (N.count != P.count) return GERR(R, MLB_ERR_FORMAT, "%s: NORMAL has %zu elements, POSITION %zu", pwhat, N.count, P.count);
    }
    if (has_t) {
        MLB_TRY(get_size(R, attrs, "TEXCOORD_0", 1, INT_MAX, 0, &it, pwhat));
        MLB_TRY(get_accessor(R, it, &T, twhat, sizeof twhat));
        MLB_TRY(check_attr(R, &T, twhat, "TEXCOORD_0", 2, t_norm));
        if (T.count != P.count) return GERR(R, MLB_ERR_FORMAT, "%s: TEXCOORD_0 has %zu elements, POSITION %zu", pwhat, T.count, P.count);
    }
    int indexed = item(prim, "indices") != NULL;
    size_t n_idx = P.count;
    if (indexed) {
        MLB_TRY(get_size(R, prim, "indices", 1, INT_MAX, 0, &ii, pwhat));
        MLB_TRY(get_accessor(R, ii, &I, iwhat, sizeof iwhat));
        if (I.ncomp != 1 || I.normalized || !(I.ctype == 5121 || I.ctype == 5123 || I.ctype == 5125))
            return GERR(R, MLB_ERR_FORMAT, "%s: indices must be unsigned byte, short or int SCALARs", iwhat);
        n_idx = I.count;
    }
    size_t n_tri = mode == 4 ? n_idx / 3 : n_idx >= 3 ? n_idx - 2 : 0;
    if (mode == 4 && n_idx % 3)
        return GERR(R, MLB_ERR_FORMAT, "%s: %zu %s is not a multiple of 3 (mode 4, triangles)", pwhat, n_idx, indexed ? "indices" : "vertices");
    if (n_tri > R->max_tris - R->nt)
        return GERR(R, MLB_ERR_UNSUPPORTED, "more than %zu triangles (at %s)", R->max_tris, pwhat);
    if (P.count > MAX_VERTS - R->nv) return GERR(R, MLB_ERR_UNSUPPORTED, "more than %zu vertices (at %s)", MAX_VERTS, pwhat);
    if (!grow_verts(R, R->nv + P.count) || !mlb_reserve((void**)&R->tri, &R->cap_t, R->nt + n_tri, 3 * sizeof(int32_t)))
        return GERR(R, MLB_ERR_NOMEM, "out of memory for %zu vertices", R->nv + P.count);
    // normals go through the inverse transpose: the cofactor matrix, times the sign of the determinant
    double C[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            int r1 = (r + 1) % 3, r2 = (r + 2) % 3, c1 = (c + 1) % 3, c2 = (c + 2) % 3;
            C[3 * r + c] = (M[4 * c1 + r1] * M[4 * c2 + r2] - M[4 * c2 + r1] * M[4 * c1 + r2]) * (mirrored ? -1 : 1);
        }
    for (size_t i = 0; i < P.count; i++) {
        float* p = R->pos + 3 * (R->nv + i);
        double x[3] = {comp(&P, i, 0), comp(&P, i, 1), comp(&P, i, 2)};
        if (identity) for (int k = 0; k < 3; k++) p[k] = (float)x[k];   // exact: no arithmetic on the bits
        else transform_point(M, x, p);
        if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]))
            return GERR(R, MLB_ERR_FORMAT, "%s: element %zu is not finite%s", what, i, identity ? "" : " (after its node's transform)");
        float* n = R->nrm + 3 * (R->nv + i);
        if (has_n) {
            double y[3] = {comp(&N, i, 0), comp(&N, i, 1), comp(&N, i, 2)};
            if (!isfinite(y[0]) || !isfinite(y[1]) || !isfinite(y[2])) return GERR(R, MLB_ERR_FORMAT, "%s: element %zu is not finite", nwhat, i);
            for (int r = 0; r < 3; r++) n[r] = identity ? (float)y[r] : (float)(C[3 * r] * y[0] + C[3 * r + 1] * y[1] + C[3 * r + 2] * y[2]);
            double l = sqrt((double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2]);
            if (!identity && l > 0 && isfinite(l)) for (int r = 0; r < 3; r++) n[r] = (float)(n[r] / l);
            if (!isfinite(l)) n[0] = n[1] = n[2] = 0;   // zero: paint repairs it
        } else n[0] = n[1] = n[2] = 0;
        float* t = R->uv + 2 * (R->nv + i);
        if (has_t) {
            double u = comp(&T, i, 0), v = comp(&T, i, 1);
            if (!isfinite(u) || !isfinite(v)) return GERR(R, MLB_ERR_FORMAT, "%s: element %zu is not finite", twhat, i);
            t[0] = (float)u;
            t[1] = 1.0f - (float)v;   // glTF's v runs down the image, OBJ's up
        } else t[0] = t[1] = 0;
    }
    for (size_t k = 0; k < n_tri; k++) {
        size_t c[3];
        if (mode == 4) { c[0] = 3 * k; c[1] = 3 * k + 1; c[2] = 3 * k + 2; }
        else if (mode == 5) { c[0] = k + (k & 1); c[1] = k + 1 - (k & 1); c[2] = k + 2; }   // odd strip triangles flip
        else { c[0] = 0; c[1] = k + 1; c[2] = k + 2; }                                     // fan
        int32_t* t = R->tri + 3 * (R->nt + k);
        for (int j = 0; j < 3; j++) {
            size_t v = indexed ? (size_t)comp(&I, c[j], 0) : c[j];
            if (v >= P.count)
                return GERR(R, MLB_ERR_FORMAT, "%s: index %zu (element %zu) out of range (%zu vertices)", iwhat, v, c[j], P.count);
            t[mirrored && j ? 3 - j : j] = (int32_t)(R->nv + v);
        }
    }
    R->nv += P.count;
    R->nt += n_tri;
    R->uv_some += has_t;
    R->uv_missing += !has_t;
    R->n_some += has_n;
    R->n_missing += !has_n;
    R->info.n_primitives++;
    return MLB_OK;
}

static mlb_status add_mesh(reader* R, size_t mi, const double* M) {
    const cJSON* m;
    char what[64], pwhat[96];
    MLB_TRY(get_elem(R, "meshes", mi, &m, what, sizeof what));
    const cJSON* prims = item(m, "primitives");
    if (!cJSON_IsArray(prims) || cJSON_GetArraySize(prims) < 1) return GERR(R, MLB_ERR_FORMAT, "%s: no primitives", what);
    int identity = 1;
    for (int k = 0; k < 16; k++) identity &= M[k] == (k % 5 == 0 ? 1.0 : 0.0);
    double det = M[0] * (M[5] * M[10] - M[9] * M[6]) - M[4] * (M[1] * M[10] - M[9] * M[2]) + M[8] * (M[1] * M[6] - M[5] * M[2]);
    int mirrored = det < 0;
    R->info.n_instances++;
    R->info.n_mirrored += mirrored;
    int p = 0;
    const cJSON* prim;
    cJSON_ArrayForEach(prim, prims) {
        snprintf(pwhat, sizeof pwhat, "%s.primitives[%d]", what, p);
        if (!cJSON_IsObject(prim)) return GERR(R, MLB_ERR_FORMAT, "%s: not an object", pwhat);
        MLB_TRY(add_primitive(R, prim, pwhat, M, identity, mirrored));
        p++;
    }
    return MLB_OK;
}

// ---- nodes ----

static void mat_mul(const double* a, const double* b, double* out) {   // column-major out = a b
    for (int c = 0; c < 4; c++)
        for (int r = 0; r < 4; r++) {
            double s = 0;
            for (int k = 0; k < 4; k++) s += a[4 * k + r] * b[4 * c + k];
            out[4 * c + r] = s;
        }
}

static mlb_status local_matrix(reader* R, const cJSON* node, const char* what, double* m) {
    int has;
    MLB_TRY(get_numbers(R, node, "matrix", 16, m, what, &has));
    if (has) return MLB_OK;
    double t[3] = {0, 0, 0}, q[4] = {0, 0, 0, 1}, s[3] = {1, 1, 1};
    MLB_TRY(get_numbers(R, node, "translation", 3, t, what, &has));
    MLB_TRY(get_numbers(R, node, "rotation", 4, q, what, &has));
    double ql = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (!(ql > 1e-12) || !isfinite(ql)) return GERR(R, MLB_ERR_FORMAT, "%s: rotation is not a unit quaternion", what);
    for (int k = 0; k < 4; k++) q[k] /= ql;
    MLB_TRY(get_numbers(R, node, "scale", 3, s, what, &has));
    double x = q[0], y = q[1], z = q[2], w = q[3];
    double rot[9] = {1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w),    // column 0
                     2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w),    // column 1
                     2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)};   // column 2
    for (int c = 0; c < 3; c++) {
        for (int r = 0; r < 3; r++) m[4 * c + r] = rot[3 * c + r] * s[c];
        m[4 * c + 3] = 0;
    }
    for (int r = 0; r < 3; r++) m[12 + r] = t[r];
    m[15] = 1;
    return MLB_OK;
}

// Node `ni` and its subtree, under the parent's world matrix. seen: each node once (a tree).
static mlb_status visit(reader* R, size_t ni, const double* parent, int depth, unsigned char* seen) {
    const cJSON* node;
    char what[64];
    MLB_TRY(get_elem(R, "nodes", ni, &node, what, sizeof what));
    if (seen[ni]) return GERR(R, MLB_ERR_FORMAT, "%s: reached twice (the nodes must form a tree)", what);
    if (depth >= MLB_GLTF_MAX_DEPTH) return GERR(R, MLB_ERR_UNSUPPORTED, "%s: nodes nested deeper than %d", what, MLB_GLTF_MAX_DEPTH);
    seen[ni] = 1;
    double local[16], world[16];
    MLB_TRY(local_matrix(R, node, what, local));
    mat_mul(parent, local, world);
    if (item(node, "mesh")) {
        size_t mi;
        MLB_TRY(get_size(R, node, "mesh", 1, INT_MAX, 0, &mi, what));
        MLB_TRY(add_mesh(R, mi, world));
    }
    const cJSON* ch = item(node, "children");
    if (ch && !cJSON_IsArray(ch)) return GERR(R, MLB_ERR_FORMAT, "%s: children is not an array", what);
    int k = 0;
    const cJSON* c;
    cJSON_ArrayForEach(c, ch) {
        double d = cJSON_IsNumber(c) ? c->valuedouble : -1;
        if (!(d >= 0 && d < INT_MAX && d == floor(d))) return GERR(R, MLB_ERR_FORMAT, "%s: children[%d] is not a node index", what, k);
        MLB_TRY(visit(R, (size_t)d, world, depth + 1, seen));
        k++;
    }
    return MLB_OK;
}

// The default scene's roots (or, without scenes, the nodes no node names as a child; without
// nodes, every mesh untransformed).
static mlb_status walk_scene(reader* R) {
    static const double I[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    int n_nodes = R->table_n[4];
    R->info.n_meshes = R->table_n[3];
    const cJSON* scenes = item(R->root, "scenes");
    if (!scenes && n_nodes == 0) {
        for (int m = 0; m < R->info.n_meshes; m++) MLB_TRY(add_mesh(R, (size_t)m, I));
        return MLB_OK;
    }
    unsigned char* seen = calloc((size_t)n_nodes + 1, 1);
    unsigned char* child = calloc((size_t)n_nodes + 1, 1);
    mlb_status s = seen && child ? MLB_OK : GERR(R, MLB_ERR_NOMEM, "out of memory for %d nodes", n_nodes);
    if (!s && scenes) {
        size_t si;
        const cJSON* scene = NULL;
        char what[64];
        s = get_size(R, R->root, "scene", 0, INT_MAX, 0, &si, "the file");
        snprintf(what, sizeof what, "scenes[%zu]", si);   // looked up once: no table needed
        int n_scenes = cJSON_IsArray(scenes) ? cJSON_GetArraySize(scenes) : 0;
        if (!s && si >= (size_t)n_scenes) s = GERR(R, MLB_ERR_FORMAT, "%s: out of range (%d scenes)", what, n_scenes);
        if (!s) scene = cJSON_GetArrayItem(scenes, (int)si);
        if (!s && !cJSON_IsObject(scene)) s = GERR(R, MLB_ERR_FORMAT, "%s: not an object", what);
        const cJSON* roots = s ? NULL : item(scene, "nodes");
        if (!s && roots && !cJSON_IsArray(roots)) s = GERR(R, MLB_ERR_FORMAT, "%s: nodes is not an array", what);
        if (s) roots = NULL;
        int k = 0;
        const cJSON* c;
        cJSON_ArrayForEach(c, roots) {
            double d = cJSON_IsNumber(c) ? c->valuedouble : -1;
            if (!(d >= 0 && d < INT_MAX && d == floor(d))) s = GERR(R, MLB_ERR_FORMAT, "%s: nodes[%d] is not a node index", what, k);
            else s = visit(R, (size_t)d, I, 0, seen);
            if (s) break;
            k++;
        }
    } else if (!s) {   // no scenes: the roots are the nodes nobody names as a child
        for (int i = 0; i < n_nodes; i++) {
            const cJSON* ch = item(R->table[4][i], "children");
            const cJSON* c;
            if (!cJSON_IsArray(ch)) continue;
            cJSON_ArrayForEach(c, ch) {
                double d = cJSON_IsNumber(c) ? c->valuedouble : -1;
                if (d >= 0 && d < n_nodes) child[(size_t)d] = 1;   // bad indices are reported by visit
            }
        }
        for (int i = 0; !s && i < n_nodes; i++)
            if (!child[i]) s = visit(R, (size_t)i, I, 0, seen);
    }
    free(seen);
    free(child);
    return s;
}

// ---- the file ----

// The JSON (and, for a .glb, the BIN chunk) of the file's bytes.
static mlb_status split_file(reader* R, const unsigned char* d, size_t n, const char** json, size_t* json_n) {
    if (n < 4 || le32(d) != GLB_MAGIC) {   // a .gltf: JSON text (a UTF-8 byte order mark is tolerated)
        if (n >= 3 && d[0] == 0xEF && d[1] == 0xBB && d[2] == 0xBF) { d += 3; n -= 3; }
        *json = (const char*)d;
        *json_n = n;
        return MLB_OK;
    }
    R->info.binary = 1;
    if (n < 20) return GERR(R, MLB_ERR_FORMAT, "truncated .glb: %zu bytes, less than a header and a chunk header", n);
    if (le32(d + 4) != 2) return GERR(R, MLB_ERR_UNSUPPORTED, ".glb version %u (only 2 is read)", le32(d + 4));
    if (le32(d + 8) != n) return GERR(R, MLB_ERR_FORMAT, "the .glb header says %u bytes, the file has %zu (truncated or padded)", le32(d + 8), n);
    size_t jl = le32(d + 12);
    if (le32(d + 16) != GLB_JSON) return GERR(R, MLB_ERR_FORMAT, "the .glb's first chunk is not JSON");
    if (jl > n - 20) return GERR(R, MLB_ERR_FORMAT, "the .glb's JSON chunk (%zu bytes) runs past the end of the file", jl);
    *json = (const char*)d + 20;
    *json_n = jl;
    for (size_t off = 20 + jl; n - off >= 8;) {   // later chunks: the first BIN is the buffer, others are skipped
        size_t cl = le32(d + off);
        if (cl > n - off - 8) return GERR(R, MLB_ERR_FORMAT, "a .glb chunk at byte %zu (%zu bytes) runs past the end of the file", off, cl);
        if (le32(d + off + 4) == GLB_BIN && !R->bin) { R->bin = d + off + 8; R->bin_len = cl; }
        off += 8 + cl;
    }
    return MLB_OK;
}

static mlb_status parse(reader* R, const unsigned char* data, size_t n) {
    const char* json = NULL;
    size_t jn = 0;
    MLB_TRY(split_file(R, data, n, &json, &jn));
    R->root = cJSON_ParseWithLength(json, jn);
    if (!R->root) {
        char why[96];
        mlb_json_why(json, jn, why, sizeof why);
        return GERR(R, MLB_ERR_FORMAT, "not glTF: %s (%s)", R->info.binary ? "the JSON chunk does not parse" : "neither a .glb nor JSON text", why);
    }
    if (!cJSON_IsObject(R->root)) return GERR(R, MLB_ERR_FORMAT, "not glTF: the JSON is not an object");
    const cJSON* asset = item(R->root, "asset");
    const cJSON* ver = cJSON_IsObject(asset) ? item(asset, "version") : NULL;
    if (!cJSON_IsString(ver)) return GERR(R, MLB_ERR_FORMAT, "not glTF: no asset.version");
    if (strncmp(ver->valuestring, "2.", 2)) return GERR(R, MLB_ERR_UNSUPPORTED, "glTF version %.20s (only 2.x is read)", ver->valuestring);
    const cJSON* req = item(R->root, "extensionsRequired");
    const cJSON* e;
    if (!cJSON_IsArray(req)) req = NULL;
    cJSON_ArrayForEach(e, req) {
        if (cJSON_IsString(e) && (!strcmp(e->valuestring, "KHR_draco_mesh_compression") || !strcmp(e->valuestring, "EXT_meshopt_compression")))
            return GERR(R, MLB_ERR_UNSUPPORTED, "compressed geometry (%s) is not read; export without compression", e->valuestring);
    }
    MLB_TRY(make_tables(R));
    R->n_buf = R->table_n[0];
    R->owned = calloc((size_t)R->n_buf + 1, sizeof *R->owned);
    R->buf = calloc((size_t)R->n_buf + 1, sizeof *R->buf);
    R->buf_len = calloc((size_t)R->n_buf + 1, sizeof *R->buf_len);
    if (!R->owned || !R->buf || !R->buf_len) return GERR(R, MLB_ERR_NOMEM, "out of memory for %d buffers", R->n_buf);
    MLB_TRY(walk_scene(R));
    if (R->nt == 0)
        return GERR(R, MLB_ERR_FORMAT, "no faces: no triangles in the scene (%d meshes, %d point or line primitives)",
                    R->info.n_meshes, R->info.n_skipped);
    return MLB_OK;
}

// The result: unused vertices dropped, attributes kept where every primitive had them.
static mlb_status finish(reader* R, mlb_mesh* out) {
    int keep_uv = R->uv_some && !R->uv_missing && !R->drop_uv, keep_n = R->n_some && !R->n_missing && !R->drop_normals;
    R->info.uv_dropped = R->uv_some && R->uv_missing;
    R->info.normals_dropped = R->n_some && R->n_missing;
    int32_t* map = malloc(sizeof(int32_t) * (R->nv + 1));
    if (!map) return GERR(R, MLB_ERR_NOMEM, "out of memory for %zu vertices", R->nv);
    for (size_t i = 0; i < R->nv; i++) map[i] = -1;
    int32_t nv = 0;
    for (size_t i = 0; i < 3 * R->nt; i++)
        if (map[R->tri[i]] < 0) map[R->tri[i]] = 0;
    for (size_t i = 0; i < R->nv; i++)
        if (map[i] == 0) map[i] = nv++;
        else R->info.n_unused++;
    // compact in place (map[i] <= i), then hand the arrays over
    for (size_t i = 0; i < R->nv; i++) {
        if (map[i] < 0) continue;
        size_t j = (size_t)map[i];
        memmove(R->pos + 3 * j, R->pos + 3 * i, 3 * sizeof(float));
        memmove(R->nrm + 3 * j, R->nrm + 3 * i, 3 * sizeof(float));
        memmove(R->uv + 2 * j, R->uv + 2 * i, 2 * sizeof(float));
    }
    for (size_t i = 0; i < 3 * R->nt; i++) R->tri[i] = map[R->tri[i]];
    free(map);
    out->n_verts = nv;
    out->n_faces = (int)R->nt;
    out->pos = R->pos;
    out->faces = R->tri;
    out->normal = keep_n ? R->nrm : NULL;
    out->uv = keep_uv ? R->uv : NULL;
    if (!keep_n) free(R->nrm);
    if (!keep_uv) free(R->uv);
    R->pos = R->nrm = R->uv = NULL;
    R->tri = NULL;
    return MLB_OK;
}

mlb_status mlb_gltf_parse(const unsigned char* data, size_t n, const char* name, const char* dir, mlb_mesh* out,
                          const mlb_gltf_options* opt, mlb_gltf_info* info) {
    if (out) memset(out, 0, sizeof *out);
    if (info) memset(info, 0, sizeof *info);
    if (!data || !out) return mlb_fail(MLB_ERR_ARG, "mlb_gltf_parse: NULL %s", data ? "output mesh" : "data");
    reader R;
    memset(&R, 0, sizeof R);
    R.name = name ? name : "(glTF)";
    R.dir = dir;
    size_t max_bytes = opt && opt->max_bytes ? opt->max_bytes : MLB_GLTF_MAX_BYTES;
    R.max_tris = opt && opt->max_triangles ? opt->max_triangles : MLB_GLTF_MAX_TRIANGLES;
    if (R.max_tris > MLB_GLTF_MAX_TRIANGLES) R.max_tris = MLB_GLTF_MAX_TRIANGLES;
    R.drop_uv = opt && opt->drop_uv;
    R.drop_normals = opt && opt->drop_normals;
    mlb_status s = n > max_bytes ? GERR(&R, MLB_ERR_UNSUPPORTED, "%zu bytes, more than the %zu allowed", n, max_bytes) : MLB_OK;
    R.budget = max_bytes - (s ? 0 : n);
    if (!s) s = parse(&R, data, n);
    if (!s) s = finish(&R, out);
    for (int i = 0; R.owned && i < R.n_buf; i++) free(R.owned[i]);
    free(R.owned);
    free(R.buf);
    free(R.buf_len);
    for (int k = 0; k < 5; k++) free(R.table[k]);
    cJSON_Delete(R.root);
    free(R.pos);
    free(R.nrm);
    free(R.uv);
    free(R.tri);
    if (s) memset(out, 0, sizeof *out);
    else if (info) *info = R.info;
    return s;
}

mlb_status mlb_gltf_load(const char* path, mlb_mesh* out, const mlb_gltf_options* opt, mlb_gltf_info* info) {
    if (out) memset(out, 0, sizeof *out);
    if (info) memset(info, 0, sizeof *info);
    if (!path || !out) return mlb_fail(MLB_ERR_ARG, "mlb_gltf_load: NULL %s", path ? "output mesh" : "path");
    size_t max_bytes = opt && opt->max_bytes ? opt->max_bytes : MLB_GLTF_MAX_BYTES;
    char* data = NULL;
    size_t n = 0;
    MLB_TRY(mlb_read_file(path, &data, &n, max_bytes));   // its message names the path
    char dir[4096];
    const char* slash = strrchr(path, '/');
    if (!slash) snprintf(dir, sizeof dir, ".");
    else if (slash == path) snprintf(dir, sizeof dir, "/");
    else snprintf(dir, sizeof dir, "%.*s", (int)(slash - path), path);
    mlb_status s = mlb_gltf_parse((const unsigned char*)data, n, path, dir, out, opt, info);
    free(data);
    return s;
}
