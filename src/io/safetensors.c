// safetensors: a validating zero-copy reader (mmap or caller's memory) and an atomic writer.
// The rules enforced follow the reference reader (docs/safetensors.md lists each with its message).
#include "matlaber/safetensors.h"
#include "matlaber/fileio.h"
#include "matlaber/half.h"
#include <cjson/cJSON.h>
#include <errno.h>
#include <fcntl.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "safetensors.c assumes a little-endian host (the format is little-endian)"
#endif
_Static_assert(sizeof(size_t) == 8, "safetensors.c assumes 64-bit size_t");

struct mlb_safetensors {
    char* path;                     // for messages
    void* map;                      // the mmap, or NULL for caller memory
    size_t map_size;
    size_t n;
    mlb_st_tensor* tensors;         // file order
    const mlb_st_tensor** by_name;  // sorted by name, for binary search
    size_t n_meta;
    struct meta_kv { char* key; char* value; }* meta;   // sorted by key
};

// ---------------------------------------------------------------- dtypes
static const struct { const char* name; size_t size; } dtype_info[MLB_DT_COUNT] = {
    [MLB_DT_F64] = {"F64", 8},   [MLB_DT_F32] = {"F32", 4},   [MLB_DT_F16] = {"F16", 2},
    [MLB_DT_BF16] = {"BF16", 2}, [MLB_DT_I64] = {"I64", 8},   [MLB_DT_I32] = {"I32", 4},
    [MLB_DT_I16] = {"I16", 2},   [MLB_DT_I8] = {"I8", 1},     [MLB_DT_U64] = {"U64", 8},
    [MLB_DT_U32] = {"U32", 4},   [MLB_DT_U16] = {"U16", 2},   [MLB_DT_U8] = {"U8", 1},
    [MLB_DT_BOOL] = {"BOOL", 1}, [MLB_DT_F8_E4M3] = {"F8_E4M3", 1}, [MLB_DT_F8_E5M2] = {"F8_E5M2", 1},
};

const char* mlb_dtype_name(mlb_dtype dt) { return (unsigned)dt < MLB_DT_COUNT ? dtype_info[dt].name : "?"; }
size_t mlb_dtype_size(mlb_dtype dt) { return (unsigned)dt < MLB_DT_COUNT ? dtype_info[dt].size : 0; }

mlb_status mlb_dtype_parse(const char* name, mlb_dtype* out) {
    for (int i = 0; i < MLB_DT_COUNT; i++)
        if (name && strcmp(name, dtype_info[i].name) == 0) { *out = (mlb_dtype)i; return MLB_OK; }
    return mlb_fail(MLB_ERR_UNSUPPORTED, "unknown dtype '%s' (known: F64 F32 F16 BF16 I64 I32 I16 I8 "
                    "U64 U32 U16 U8 BOOL F8_E4M3 F8_E5M2)", name ? name : "(null)");
}

// ---------------------------------------------------------------- small helpers
static void fmt_shape(char* buf, size_t cap, int ndim, const int64_t* shape) {
    size_t k = (size_t)snprintf(buf, cap, "[");
    for (int i = 0; i < ndim && k < cap; i++)
        k += (size_t)snprintf(buf + k, cap - k, "%s%lld", i ? ", " : "", (long long)shape[i]);
    if (k < cap) snprintf(buf + k, cap - k, "]");
}

// Length (1..4) of the valid UTF-8 sequence at s, or 0 with *why set. Rejects overlong forms,
// surrogates (U+D800..DFFF) and code points above U+10FFFF.
static size_t utf8_seq(const unsigned char* s, size_t n, const char** why) {
    unsigned c = s[0];
    if (c < 0x80) return 1;
    size_t len;
    uint32_t cp, min;
    if (c >= 0xC2 && c <= 0xDF) { len = 2; cp = c & 0x1F; min = 0x80; }
    else if (c >= 0xE0 && c <= 0xEF) { len = 3; cp = c & 0x0F; min = 0x800; }
    else if (c >= 0xF0 && c <= 0xF4) { len = 4; cp = c & 0x07; min = 0x10000; }
    else if (c == 0xC0 || c == 0xC1) { *why = "overlong encoding"; return 0; }
    else if (c <= 0xBF) { *why = "stray continuation byte"; return 0; }
    else { *why = "lead byte above 0xF4 (code point above U+10FFFF)"; return 0; }
    if (n < len) { *why = "sequence cut short"; return 0; }
    for (size_t k = 1; k < len; k++) {
        if ((s[k] & 0xC0) != 0x80) { *why = "missing continuation byte"; return 0; }
        cp = (cp << 6) | (s[k] & 0x3F);
    }
    if (cp < min) { *why = "overlong encoding"; return 0; }
    if (cp >= 0xD800 && cp <= 0xDFFF) { *why = "surrogate code point"; return 0; }
    if (cp > 0x10FFFF) { *why = "code point above U+10FFFF"; return 0; }
    return len;
}

static int utf8_valid(const char* s) {
    const unsigned char* p = (const unsigned char*)s;
    size_t n = strlen(s);
    const char* why;
    for (size_t i = 0; i < n;) {
        size_t k = utf8_seq(p + i, n - i, &why);
        if (!k) return 0;
        i += k;
    }
    return 1;
}

// A header number is canonical when it is a plain run of digits without a leading zero and at
// most 2^53. cJSON hands back doubles, so "1.0", "1e2", "-0", "01" and integers that round
// to a valid double would otherwise slip through unnoticed.
static int number_canonical(const unsigned char* t, size_t len) {
    if (len == 0 || len > 16) return 0;
    for (size_t i = 0; i < len; i++) if (t[i] < '0' || t[i] > '9') return 0;
    if (len > 1 && t[0] == '0') return 0;
    return len < 16 || memcmp(t, "9007199254740992", 16) <= 0;
}

// Everything cJSON would let through: the header must be UTF-8 and lexically strict JSON (no
// control characters outside the four JSON whitespace bytes, none inside strings, no byte-order
// mark). Records the first non-canonical number in *bad_num (SIZE_MAX when none); the caller
// reports it after the per-field checks, whose messages name the tensor.
static mlb_status check_header_text(const char* path, const unsigned char* h, size_t n,
                                    size_t* bad_num, size_t* bad_len) {
    *bad_num = SIZE_MAX;
    *bad_len = 0;
    if (n >= 3 && h[0] == 0xEF && h[1] == 0xBB && h[2] == 0xBF)
        return mlb_fail(MLB_ERR_FORMAT, "%s: header is not valid JSON: it starts with a byte-order mark", path);
    int in_str = 0;
    for (size_t i = 0; i < n;) {
        unsigned c = h[i];
        if (c >= 0x80) {
            const char* why = "";
            size_t k = utf8_seq(h + i, n - i, &why);
            if (!k) return mlb_fail(MLB_ERR_FORMAT, "%s: header is not valid UTF-8 at header byte %zu: %s", path, i, why);
            i += k;
        } else if (in_str) {
            if (c < 0x20)
                return mlb_fail(MLB_ERR_FORMAT, "%s: header is not valid JSON: control character 0x%02x "
                                "inside a string at header byte %zu", path, c, i);
            if (c == '"') in_str = 0;
            if (c == '\\' && i + 1 < n && h[i + 1] < 0x80) {
                if (h[i + 1] == 'u' && i + 6 <= n && memcmp(h + i + 2, "0000", 4) == 0)
                    return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: a string in the header contains \\u0000 "
                                    "(header byte %zu), which names here cannot hold", path, i);
                i++;   // skip the escaped character so \" does not end the string
            }
            i++;
        } else if (c == '"') {
            in_str = 1;
            i++;
        } else if (c == '-' || (c >= '0' && c <= '9')) {
            size_t j = i;   // the bytes cJSON's number parser takes
            while (j < n && ((h[j] >= '0' && h[j] <= '9') || h[j] == '-' || h[j] == '+' || h[j] == '.' ||
                             h[j] == 'e' || h[j] == 'E'))
                j++;
            if (*bad_num == SIZE_MAX && !number_canonical(h + i, j - i)) { *bad_num = i; *bad_len = j - i; }
            i = j;
        } else {
            if (c < 0x20 && c != '\t' && c != '\n' && c != '\r')
                return mlb_fail(MLB_ERR_FORMAT, "%s: header is not valid JSON: control character 0x%02x "
                                "at header byte %zu", path, c, i);
            i++;
        }
    }
    return MLB_OK;
}

// A shape or offset number: an exact integer in [0, 2^53].
static mlb_status get_uint(const char* path, const char* tname, const char* what, int idx,
                           const cJSON* item, uint64_t* out) {
    char field[48];
    if (idx >= 0) snprintf(field, sizeof field, "%s[%d]", what, idx);
    else snprintf(field, sizeof field, "%s", what);
    if (!cJSON_IsNumber(item))
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': %s is not a number", path, tname, field);
    double v = item->valuedouble;
    if (v < 0)
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': %s is negative (%.17g)", path, tname, field, v);
    if (!(v <= (double)MLB_ST_MAX_INT))
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': %s is too large (%.17g > 2^53)", path, tname, field, v);
    if (v != floor(v))
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': %s is not a whole number (%.17g)", path, tname, field, v);
    *out = (uint64_t)v;
    return MLB_OK;
}

// Reads one tensor entry's fields; data pointer filled in later.
static mlb_status parse_entry(const char* path, const cJSON* e, mlb_st_tensor* t) {
    const char* tn = e->string;
    if (!cJSON_IsObject(e)) return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': entry is not a JSON object", path, tn);
    const cJSON *jd = NULL, *js = NULL, *jo = NULL;
    for (const cJSON* f = e->child; f; f = f->next) {
        const cJSON** slot = strcmp(f->string, "dtype") == 0 ? &jd
                           : strcmp(f->string, "shape") == 0 ? &js
                           : strcmp(f->string, "data_offsets") == 0 ? &jo : NULL;
        if (!slot) return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': unknown field '%s'", path, tn, f->string);
        if (*slot) return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': field '%s' appears twice", path, tn, f->string);
        *slot = f;
    }
    if (!jd) return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': missing field 'dtype'", path, tn);
    if (!js) return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': missing field 'shape'", path, tn);
    if (!jo) return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': missing field 'data_offsets'", path, tn);

    if (!cJSON_IsString(jd)) return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': dtype is not a string", path, tn);
    if (mlb_dtype_parse(jd->valuestring, &t->dtype) != MLB_OK)
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: tensor '%s': unknown dtype '%s'", path, tn, jd->valuestring);

    if (!cJSON_IsArray(js)) return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': shape is not an array", path, tn);
    int nd = cJSON_GetArraySize(js);
    if (nd > MLB_ST_MAX_DIMS)
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: tensor '%s': shape has %d dimensions, more than the %d supported",
                        path, tn, nd, MLB_ST_MAX_DIMS);
    t->ndim = nd;
    int k = 0, zero = 0;
    for (const cJSON* d = js->child; d; d = d->next, k++) {
        uint64_t v;
        MLB_TRY(get_uint(path, tn, "shape", k, d, &v));
        t->shape[k] = (int64_t)v;
        if (v == 0) zero = 1;
    }

    if (!cJSON_IsArray(jo) || cJSON_GetArraySize(jo) != 2)
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': data_offsets is not an array of 2 integers", path, tn);
    uint64_t begin, end;
    MLB_TRY(get_uint(path, tn, "data_offsets", 0, jo->child, &begin));
    MLB_TRY(get_uint(path, tn, "data_offsets", 1, jo->child->next, &end));
    if (end < begin)
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': data_offsets [%llu, %llu] end before they begin",
                        path, tn, (unsigned long long)begin, (unsigned long long)end);

    // Element count and byte size with overflow checks; a zero dimension makes the product 0
    // whatever the others are.
    char sh[256];
    size_t nelem = 1, nbytes;
    if (zero) nelem = 0;
    else
        for (int i = 0; i < nd; i++)
            if (__builtin_mul_overflow(nelem, (size_t)t->shape[i], &nelem)) {
                fmt_shape(sh, sizeof sh, nd, t->shape);
                return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': shape %s has more elements than 64 bits can count "
                                "(overflow)", path, tn, sh);
            }
    if (__builtin_mul_overflow(nelem, mlb_dtype_size(t->dtype), &nbytes)) {
        fmt_shape(sh, sizeof sh, nd, t->shape);
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': shape %s of %s is more bytes than 64 bits can count "
                        "(overflow)", path, tn, sh, mlb_dtype_name(t->dtype));
    }
    if (nbytes != end - begin) {
        fmt_shape(sh, sizeof sh, nd, t->shape);
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': shape %s of %s needs %zu bytes but data_offsets "
                        "[%llu, %llu] hold %llu", path, tn, sh, mlb_dtype_name(t->dtype), nbytes,
                        (unsigned long long)begin, (unsigned long long)end, (unsigned long long)(end - begin));
    }
    t->nelem = nelem;
    t->nbytes = nbytes;
    t->offset = (size_t)begin;
    return MLB_OK;
}

static int cmp_meta(const void* a, const void* b) {
    return strcmp(((const struct meta_kv*)a)->key, ((const struct meta_kv*)b)->key);
}

static mlb_status parse_metadata(const char* path, mlb_safetensors* st, const cJSON* m) {
    if (!cJSON_IsObject(m)) return mlb_fail(MLB_ERR_FORMAT, "%s: __metadata__ is not a JSON object", path);
    size_t n = 0;
    for (const cJSON* c = m->child; c; c = c->next) n++;
    st->meta = calloc(n ? n : 1, sizeof *st->meta);
    if (!st->meta) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path);
    for (const cJSON* c = m->child; c; c = c->next) {
        if (!cJSON_IsString(c))
            return mlb_fail(MLB_ERR_FORMAT, "%s: __metadata__ value for key '%s' is not a string", path, c->string);
        struct meta_kv* kv = &st->meta[st->n_meta++];
        kv->key = strdup(c->string);
        kv->value = strdup(c->valuestring);
        if (!kv->key || !kv->value) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path);
    }
    qsort(st->meta, st->n_meta, sizeof *st->meta, cmp_meta);
    for (size_t i = 1; i < st->n_meta; i++)
        if (strcmp(st->meta[i - 1].key, st->meta[i].key) == 0)
            return mlb_fail(MLB_ERR_FORMAT, "%s: duplicate __metadata__ key '%s'", path, st->meta[i].key);
    return MLB_OK;
}

static int cmp_by_name(const void* a, const void* b) {
    return strcmp((*(const mlb_st_tensor* const*)a)->name, (*(const mlb_st_tensor* const*)b)->name);
}

// Sorted by (begin, end), as the reference reader does, so zero-size tensors sit before the
// tensor that starts where they do.
typedef struct { size_t begin, end, idx; } span;
static int cmp_span(const void* a, const void* b) {
    const span *x = a, *y = b;
    if (x->begin != y->begin) return x->begin < y->begin ? -1 : 1;
    if (x->end != y->end) return x->end < y->end ? -1 : 1;
    return x->idx < y->idx ? -1 : x->idx > y->idx;
}

// Short text shown when the length prefix is printable ASCII: such a "file" is usually a text
// stand-in (a symlink stored as a plain file, a Git LFS pointer), not safetensors at all.
static const char* text_hint(const unsigned char* p, char* buf, size_t cap) {
    for (int i = 0; i < 8; i++) if (p[i] < 0x20 || p[i] > 0x7E) return "";
    snprintf(buf, cap, " (the file starts with the text \"%.8s\": is it a text stand-in such as a symlink "
             "stored as a plain file, or a Git LFS pointer?)", (const char*)p);
    return buf;
}

static mlb_status parse(mlb_safetensors* st, const unsigned char* p, size_t size) {
    const char* path = st->path;
    if (size < 8)
        return mlb_fail(MLB_ERR_FORMAT, "%s: file is %zu bytes, too short for the 8-byte header length", path, size);
    uint64_t n = 0;
    for (int i = 7; i >= 0; i--) n = (n << 8) | p[i];
    char hint[192];
    if (n > MLB_ST_MAX_HEADER)
        return mlb_fail(MLB_ERR_FORMAT, "%s: header length %llu is more than the %llu allowed%s", path,
                        (unsigned long long)n, MLB_ST_MAX_HEADER, text_hint(p, hint, sizeof hint));
    if (n > size - 8)
        return mlb_fail(MLB_ERR_FORMAT, "%s: header length %llu runs past the end of the file (%zu bytes)%s", path,
                        (unsigned long long)n, size, text_hint(p, hint, sizeof hint));
    const unsigned char* h = p + 8;
    size_t bad_num, bad_len;
    MLB_TRY(check_header_text(path, h, (size_t)n, &bad_num, &bad_len));

    // cJSON gets a NUL-terminated copy so it can never read past the header.
    char* text = malloc((size_t)n + 1);
    if (!text) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for a %llu-byte header", path, (unsigned long long)n);
    memcpy(text, h, (size_t)n);
    text[n] = 0;
    const char* endp = NULL;
    cJSON* root = cJSON_ParseWithLengthOpts(text, (size_t)n, &endp, 0);
    mlb_status s = MLB_OK;
    if (!root) {
        size_t at = endp && endp >= text && endp <= text + n ? (size_t)(endp - text) : 0;
        s = mlb_fail(MLB_ERR_FORMAT, "%s: header is not valid JSON (parse error near header byte %zu)", path, at);
        goto done;
    }
    for (const char* q = endp; q < text + n; q++)
        if (*q != ' ' && *q != '\t' && *q != '\n' && *q != '\r') {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: header is not valid JSON: unexpected text after the top-level value "
                         "at header byte %zu", path, (size_t)(q - text));
            goto done;
        }
    if (!cJSON_IsObject(root)) {
        s = mlb_fail(MLB_ERR_FORMAT, "%s: header is valid JSON but not a JSON object", path);
        goto done;
    }

    size_t count = 0;
    const cJSON* meta = NULL;
    for (const cJSON* c = root->child; c; c = c->next) {
        if (strcmp(c->string, "__metadata__") != 0) { count++; continue; }
        if (meta) { s = mlb_fail(MLB_ERR_FORMAT, "%s: __metadata__ appears twice", path); goto done; }
        meta = c;
    }
    if (meta && (s = parse_metadata(path, st, meta)) != MLB_OK) goto done;

    st->tensors = calloc(count ? count : 1, sizeof *st->tensors);
    st->by_name = calloc(count ? count : 1, sizeof *st->by_name);
    span* spans = calloc(count ? count : 1, sizeof *spans);
    if (!st->tensors || !st->by_name || !spans) {
        free(spans);
        s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for %zu tensors", path, count);
        goto done;
    }
    const unsigned char* data = h + n;
    size_t data_size = size - 8 - (size_t)n;
    for (const cJSON* c = root->child; c; c = c->next) {
        if (c == meta) continue;
        mlb_st_tensor* t = &st->tensors[st->n];
        if ((s = parse_entry(path, c, t)) != MLB_OK) goto done_spans;
        if (t->offset + t->nbytes > data_size) {   // both <= 2^53: no overflow
            s = mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s': data_offsets [%zu, %zu] run past the end of the file "
                         "(the data buffer holds %zu bytes)", path, c->string, t->offset, t->offset + t->nbytes,
                         data_size);
            goto done_spans;
        }
        if (!(t->name = strdup(c->string))) { s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); goto done_spans; }
        t->data = data + t->offset;
        spans[st->n] = (span){t->offset, t->offset + t->nbytes, st->n};
        st->by_name[st->n] = t;
        st->n++;
    }

    qsort(st->by_name, st->n, sizeof *st->by_name, cmp_by_name);
    for (size_t i = 1; i < st->n; i++)
        if (strcmp(st->by_name[i - 1]->name, st->by_name[i]->name) == 0) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: duplicate tensor name '%s'", path, st->by_name[i]->name);
            goto done_spans;
        }

    qsort(spans, st->n, sizeof *spans, cmp_span);
    size_t expect = 0;
    for (size_t i = 0; i < st->n; i++) {
        const span* sp = &spans[i];
        const char* tn = st->tensors[sp->idx].name;
        if (sp->begin > expect && expect == 0) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: data does not start at offset 0: the first tensor '%s' begins at %zu "
                         "(bytes [0, %zu) belong to no tensor)", path, tn, sp->begin, sp->begin);
            goto done_spans;
        }
        if (sp->begin > expect) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: hole in the data buffer: bytes [%zu, %zu) before tensor '%s' belong "
                         "to no tensor", path, expect, sp->begin, tn);
            goto done_spans;
        }
        if (sp->begin < expect) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' data_offsets [%zu, %zu] overlap the previous tensor "
                         "'%s', which ends at %zu", path, tn, sp->begin, sp->end,
                         st->tensors[spans[i - 1].idx].name, expect);
            goto done_spans;
        }
        expect = sp->end;
    }
    if (expect != data_size) {
        s = mlb_fail(MLB_ERR_FORMAT, "%s: %zu trailing bytes after the last tensor (the tensors cover %zu bytes "
                     "of the %zu-byte data buffer)", path, data_size - expect, expect, data_size);
        goto done_spans;
    }
    if (bad_num != SIZE_MAX) {
        s = mlb_fail(MLB_ERR_FORMAT, "%s: number '%.*s' at header byte %zu is not a plain non-negative integer "
                     "of at most 2^53", path, (int)(bad_len < 40 ? bad_len : 40), (const char*)h + bad_num, bad_num);
        goto done_spans;
    }
done_spans:
    free(spans);
done:
    cJSON_Delete(root);
    free(text);
    return s;
}

// ---------------------------------------------------------------- open / close / lookup
static mlb_safetensors* new_handle(const char* name) {
    mlb_safetensors* st = calloc(1, sizeof *st);
    if (!st) return NULL;
    st->path = strdup(name);
    if (!st->path) { free(st); return NULL; }
    return st;
}

mlb_status mlb_st_open_memory(mlb_safetensors** out, const void* data, size_t n, const char* name_for_errors) {
    const char* name = name_for_errors ? name_for_errors : "<memory>";
    if (!out) return mlb_fail(MLB_ERR_ARG, "%s: mlb_st_open_memory needs an output pointer", name);
    *out = NULL;
    if (!data && n) return mlb_fail(MLB_ERR_ARG, "%s: NULL buffer of %zu bytes", name, n);
    mlb_safetensors* st = new_handle(name);
    if (!st) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", name);
    mlb_status s = parse(st, data, n);
    if (s != MLB_OK) { mlb_st_close(st); return s; }
    *out = st;
    return MLB_OK;
}

mlb_status mlb_st_open(mlb_safetensors** out, const char* path) {
    if (!out || !path) return mlb_fail(MLB_ERR_ARG, "mlb_st_open needs an output pointer and a path");
    *out = NULL;
    int fd;
    size_t size;
    MLB_TRY(mlb_open_input(path, &fd, &size));   // regular files only (fileio.h)
    mlb_safetensors* st = new_handle(path);
    if (!st) { close(fd); return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); }
    const unsigned char* p = (const unsigned char*)"";
    if (size > 0) {   // mmap of 0 bytes fails; the parser reports the short file itself
        void* m = mmap(NULL, size, PROT_READ, MAP_PRIVATE, fd, 0);
        if (m == MAP_FAILED) {
            int e = errno;
            close(fd);
            mlb_st_close(st);
            return mlb_fail(MLB_ERR_IO, "%s: mmap of %zu bytes failed: %s", path, size, strerror(e));
        }
        st->map = m;
        st->map_size = size;
        p = m;
    }
    close(fd);   // the mapping stays valid without the descriptor
    mlb_status s = parse(st, p, size);
    if (s != MLB_OK) { mlb_st_close(st); return s; }
    *out = st;
    return MLB_OK;
}

void mlb_st_close(mlb_safetensors* st) {
    if (!st) return;
    for (size_t i = 0; i < st->n; i++) free((char*)st->tensors[i].name);
    for (size_t i = 0; i < st->n_meta; i++) { free(st->meta[i].key); free(st->meta[i].value); }
    free(st->meta);
    free(st->tensors);
    free(st->by_name);
    if (st->map) munmap(st->map, st->map_size);
    free(st->path);
    free(st);
}

const char* mlb_st_path(const mlb_safetensors* st) { return st ? st->path : ""; }
size_t mlb_st_count(const mlb_safetensors* st) { return st ? st->n : 0; }
const mlb_st_tensor* mlb_st_tensor_at(const mlb_safetensors* st, size_t i) {
    return st && i < st->n ? &st->tensors[i] : NULL;
}

const mlb_st_tensor* mlb_st_find(const mlb_safetensors* st, const char* name) {
    if (!st || !name) return NULL;
    size_t lo = 0, hi = st->n;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        const mlb_st_tensor* t = st->by_name[mid];
        int c = strcmp(t->name, name);
        if (c == 0) return t;
        if (c < 0) lo = mid + 1;
        else hi = mid;
    }
    return NULL;
}

const char* mlb_st_metadata(const mlb_safetensors* st, const char* key) {
    if (!st || !key) return NULL;
    size_t lo = 0, hi = st->n_meta;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        int c = strcmp(st->meta[mid].key, key);
        if (c == 0) return st->meta[mid].value;
        if (c < 0) lo = mid + 1;
        else hi = mid;
    }
    return NULL;
}

size_t mlb_st_metadata_count(const mlb_safetensors* st) { return st ? st->n_meta : 0; }
int mlb_st_metadata_at(const mlb_safetensors* st, size_t i, const char** key, const char** value) {
    if (!st || i >= st->n_meta) return -1;
    if (key) *key = st->meta[i].key;
    if (value) *value = st->meta[i].value;
    return 0;
}

// After a tensor is converted, its whole pages of the mapping are dropped from memory (they are
// read back from the file if touched again): a loader reads each tensor once, so loading a 2 GB
// checkpoint holds what was converted, not that plus the file.
static void drop_pages(const mlb_safetensors* st, const mlb_st_tensor* t) {
    if (!st->map || !t->nbytes) return;
    uintptr_t page = (uintptr_t)sysconf(_SC_PAGESIZE), a = (uintptr_t)t->data, b = a + t->nbytes;
    a = (a + page - 1) / page * page;
    b = b / page * page;
    if (b > a) madvise((void*)a, b - a, MADV_DONTNEED);
}

// The first element of t whose bits say NaN or infinity (an all-ones exponent); SIZE_MAX when none.
static size_t first_nonfinite(const mlb_st_tensor* t) {
    const unsigned char* b = t->data;
    for (size_t i = 0; i < t->nelem; i++) {
        uint64_t v8;
        uint32_t v4;
        uint16_t v2;
        switch (t->dtype) {
        case MLB_DT_F64: memcpy(&v8, b + 8 * i, 8); if ((v8 >> 52 & 0x7FF) == 0x7FF) return i; break;
        case MLB_DT_F32: memcpy(&v4, b + 4 * i, 4); if ((v4 >> 23 & 0xFF) == 0xFF) return i; break;
        case MLB_DT_F16: memcpy(&v2, b + 2 * i, 2); if ((v2 >> 10 & 0x1F) == 0x1F) return i; break;
        case MLB_DT_BF16: memcpy(&v2, b + 2 * i, 2); if ((v2 >> 7 & 0xFF) == 0xFF) return i; break;
        case MLB_DT_F8_E5M2: if ((b[i] >> 2 & 0x1F) == 0x1F) return i; break;
        case MLB_DT_F8_E4M3: if ((b[i] & 0x7F) == 0x7F) return i; break;   // no infinity; S.1111.111 is NaN
        default: return SIZE_MAX;
        }
    }
    return SIZE_MAX;
}

mlb_status mlb_st_check_finite(const mlb_safetensors* st, const mlb_st_tensor* t) {
    if (!st || !t) return mlb_fail(MLB_ERR_ARG, "mlb_st_check_finite: NULL argument");
    size_t i = first_nonfinite(t);
    if (i == SIZE_MAX) return MLB_OK;
    return mlb_fail(MLB_ERR_NUMERIC, "%s: tensor '%s' holds a NaN or an infinity (element %zu of %zu): the file is damaged, "
                    "or was written by a run that diverged", st->path, t->name, i, t->nelem);
}

mlb_status mlb_st_read_f32(const mlb_safetensors* st, const char* name, float* out, size_t n_elems) {
    if (!st || !name) return mlb_fail(MLB_ERR_ARG, "mlb_st_read_f32: NULL handle or name");
    const mlb_st_tensor* t = mlb_st_find(st, name);
    if (!t) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no tensor named '%s'", st->path, name);
    if (t->nelem != n_elems) {
        char sh[256];
        fmt_shape(sh, sizeof sh, t->ndim, t->shape);
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' has %zu elements (shape %s), expected %zu",
                        st->path, name, t->nelem, sh, n_elems);
    }
    if (n_elems && !out) return mlb_fail(MLB_ERR_ARG, "%s: tensor '%s': NULL output buffer", st->path, name);
    MLB_TRY(mlb_st_check_finite(st, t));
    switch (t->dtype) {
    case MLB_DT_F32: if (n_elems) memcpy(out, t->data, t->nbytes); break;
    case MLB_DT_F16: mlb_f16_to_f32_array(out, t->data, n_elems); break;
    case MLB_DT_BF16: mlb_bf16_to_f32_array(out, t->data, n_elems); break;
    case MLB_DT_F64:
        for (size_t i = 0; i < n_elems; i++) {
            double d;
            memcpy(&d, (const unsigned char*)t->data + 8 * i, 8);
            if (!(fabs(d) <= FLT_MAX))
                return mlb_fail(MLB_ERR_NUMERIC, "%s: tensor '%s': element %zu (%g) is beyond float range", st->path, name, i, d);
            out[i] = (float)d;
        }
        break;
    default:
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: tensor '%s' is %s; only F32, F16, BF16 and F64 convert to float32",
                        st->path, name, mlb_dtype_name(t->dtype));
    }
    drop_pages(st, t);
    return MLB_OK;
}

mlb_status mlb_st_read_raw(const mlb_safetensors* st, const char* name, mlb_dtype dtype, void* out, size_t nbytes) {
    if (!st || !name || (nbytes && !out)) return mlb_fail(MLB_ERR_ARG, "mlb_st_read_raw: NULL argument");
    const mlb_st_tensor* t = mlb_st_find(st, name);
    if (!t) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no tensor named '%s'", st->path, name);
    if (t->dtype != dtype || t->nbytes != nbytes)
        return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' is %s, %zu bytes; expected %s, %zu bytes", st->path, name,
                        mlb_dtype_name(t->dtype), t->nbytes, mlb_dtype_name(dtype), nbytes);
    MLB_TRY(mlb_st_check_finite(st, t));
    if (nbytes) memcpy(out, t->data, nbytes);
    drop_pages(st, t);
    return MLB_OK;
}

mlb_status mlb_st_expect(const mlb_safetensors* st, const char* name, int ndim, const int64_t* shape) {
    if (!st || !name || ndim < 0 || (ndim > 0 && !shape))
        return mlb_fail(MLB_ERR_ARG, "mlb_st_expect: bad arguments");
    const mlb_st_tensor* t = mlb_st_find(st, name);
    if (!t) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no tensor named '%s'", st->path, name);
    int same = t->ndim == ndim;
    for (int i = 0; same && i < ndim; i++) same = t->shape[i] == shape[i];
    if (same) return MLB_OK;
    char have[256], want[256];
    fmt_shape(have, sizeof have, t->ndim, t->shape);
    fmt_shape(want, sizeof want, ndim, shape);
    return mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' has shape %s, expected %s", st->path, name, have, want);
}

// ---------------------------------------------------------------- writer
typedef struct { char* p; size_t n, cap; int oom; } strbuf;

static void sb_put(strbuf* b, const char* s, size_t n) {
    if (b->oom) return;
    if (b->n + n + 1 > b->cap) {
        size_t cap = b->cap ? b->cap : 256;
        while (cap < b->n + n + 1) cap *= 2;
        char* q = realloc(b->p, cap);
        if (!q) { b->oom = 1; return; }
        b->p = q;
        b->cap = cap;
    }
    memcpy(b->p + b->n, s, n);
    b->n += n;
    b->p[b->n] = 0;
}
static void sb_puts(strbuf* b, const char* s) { sb_put(b, s, strlen(s)); }

static void sb_json_string(strbuf* b, const char* s) {
    sb_puts(b, "\"");
    for (const unsigned char* p = (const unsigned char*)s; *p; p++) {
        char esc[8];
        if (*p == '"' || *p == '\\') { esc[0] = '\\'; esc[1] = (char)*p; sb_put(b, esc, 2); }
        else if (*p < 0x20) { snprintf(esc, sizeof esc, "\\u%04x", *p); sb_puts(b, esc); }
        else sb_put(b, (const char*)p, 1);
    }
    sb_puts(b, "\"");
}

static int cmp_str_ptr(const void* a, const void* b) {
    return strcmp(*(const char* const*)a, *(const char* const*)b);
}

// Sorts a copy of the names to find duplicates; returns the duplicate or NULL (and *oom).
static const char* find_duplicate(const char** names, size_t n, int* oom) {
    *oom = 0;
    if (n < 2) return NULL;
    const char** c = malloc(n * sizeof *c);
    if (!c) { *oom = 1; return NULL; }
    memcpy(c, names, n * sizeof *c);
    qsort(c, n, sizeof *c, cmp_str_ptr);
    const char* dup = NULL;
    for (size_t i = 1; i < n && !dup; i++) if (strcmp(c[i - 1], c[i]) == 0) dup = c[i];
    free(c);
    return dup;
}

mlb_status mlb_st_write(const char* path, const mlb_st_entry* entries, size_t n_entries,
                        const mlb_st_meta* metadata, size_t n_metadata) {
    if (!path) return mlb_fail(MLB_ERR_ARG, "mlb_st_write: NULL path");
    if (n_entries && !entries) return mlb_fail(MLB_ERR_ARG, "%s: %zu entries but a NULL entry array", path, n_entries);
    if (n_metadata && !metadata) return mlb_fail(MLB_ERR_ARG, "%s: %zu metadata pairs but a NULL array", path, n_metadata);
    size_t* nbytes = calloc(n_entries ? n_entries : 1, sizeof *nbytes);
    const char** names = calloc(n_entries + n_metadata + 1, sizeof *names);
    strbuf hb = {0};
    mlb_status s = MLB_OK;
    if (!nbytes || !names) { s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); goto out; }

    // Validate everything before creating any file.
    size_t total = 0;
    for (size_t i = 0; i < n_entries; i++) {
        const mlb_st_entry* e = &entries[i];
        if (!e->name) { s = mlb_fail(MLB_ERR_ARG, "%s: entry %zu has no name", path, i); goto out; }
        const char* en = e->name;
        if (!utf8_valid(en)) { s = mlb_fail(MLB_ERR_ARG, "%s: entry %zu: name is not valid UTF-8", path, i); goto out; }
        if (strcmp(en, "__metadata__") == 0) {
            s = mlb_fail(MLB_ERR_ARG, "%s: '__metadata__' is reserved and cannot name a tensor", path);
            goto out;
        }
        if ((unsigned)e->dtype >= MLB_DT_COUNT) {
            s = mlb_fail(MLB_ERR_ARG, "%s: tensor '%s': invalid dtype %d", path, en, (int)e->dtype);
            goto out;
        }
        if (e->ndim < 0 || e->ndim > MLB_ST_MAX_DIMS || (e->ndim > 0 && !e->shape)) {
            s = mlb_fail(MLB_ERR_ARG, "%s: tensor '%s': ndim %d must be 0..%d with a shape array", path, en, e->ndim,
                         MLB_ST_MAX_DIMS);
            goto out;
        }
        size_t ne = 1;
        for (int d = 0; d < e->ndim; d++) {
            if (e->shape[d] < 0 || (uint64_t)e->shape[d] > MLB_ST_MAX_INT) {
                s = mlb_fail(MLB_ERR_ARG, "%s: tensor '%s': shape[%d] = %lld is outside [0, 2^53]", path, en, d,
                             (long long)e->shape[d]);
                goto out;
            }
        }
        int zero = 0, ovf = 0;
        for (int d = 0; d < e->ndim; d++) zero |= e->shape[d] == 0;
        if (zero) ne = 0;
        for (int d = 0; d < e->ndim && !zero; d++) ovf |= __builtin_mul_overflow(ne, (size_t)e->shape[d], &ne);
        if (ovf || __builtin_mul_overflow(ne, mlb_dtype_size(e->dtype), &nbytes[i]) ||
            __builtin_add_overflow(total, nbytes[i], &total) || total > MLB_ST_MAX_INT) {
            s = mlb_fail(MLB_ERR_ARG, "%s: tensor '%s': sizes overflow (the data would exceed 2^53 bytes)", path, en);
            goto out;
        }
        if (nbytes[i] && !e->data) {
            s = mlb_fail(MLB_ERR_ARG, "%s: tensor '%s': NULL data for %zu bytes", path, en, nbytes[i]);
            goto out;
        }
        names[i] = en;
    }
    int oom;
    const char* dup = find_duplicate(names, n_entries, &oom);
    if (oom) { s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); goto out; }
    if (dup) { s = mlb_fail(MLB_ERR_ARG, "%s: duplicate tensor name '%s'", path, dup); goto out; }
    for (size_t i = 0; i < n_metadata; i++) {
        const mlb_st_meta* m = &metadata[i];
        if (!m->key || !m->value) { s = mlb_fail(MLB_ERR_ARG, "%s: metadata pair %zu has a NULL key or value", path, i); goto out; }
        if (!utf8_valid(m->key) || !utf8_valid(m->value)) {
            s = mlb_fail(MLB_ERR_ARG, "%s: metadata pair %zu is not valid UTF-8", path, i);
            goto out;
        }
        names[i] = m->key;
    }
    dup = find_duplicate(names, n_metadata, &oom);
    if (oom) { s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); goto out; }
    if (dup) { s = mlb_fail(MLB_ERR_ARG, "%s: duplicate metadata key '%s'", path, dup); goto out; }

    // Header: metadata first, then entries with data_offsets ascending in entry order.
    sb_puts(&hb, "{");
    int first = 1;
    if (n_metadata) {
        sb_puts(&hb, "\"__metadata__\":{");
        for (size_t i = 0; i < n_metadata; i++) {
            if (i) sb_puts(&hb, ",");
            sb_json_string(&hb, metadata[i].key);
            sb_puts(&hb, ":");
            sb_json_string(&hb, metadata[i].value);
        }
        sb_puts(&hb, "}");
        first = 0;
    }
    size_t off = 0;
    for (size_t i = 0; i < n_entries; i++) {
        const mlb_st_entry* e = &entries[i];
        char num[64];
        if (!first) sb_puts(&hb, ",");
        first = 0;
        sb_json_string(&hb, e->name);
        sb_puts(&hb, ":{\"dtype\":\"");
        sb_puts(&hb, mlb_dtype_name(e->dtype));
        sb_puts(&hb, "\",\"shape\":[");
        for (int d = 0; d < e->ndim; d++) {
            snprintf(num, sizeof num, "%s%lld", d ? "," : "", (long long)e->shape[d]);
            sb_puts(&hb, num);
        }
        snprintf(num, sizeof num, "],\"data_offsets\":[%zu,%zu]}", off, off + nbytes[i]);
        sb_puts(&hb, num);
        off += nbytes[i];
    }
    sb_puts(&hb, "}");
    while (!hb.oom && hb.n % 8) sb_puts(&hb, " ");   // 8 + N is then a multiple of 8
    if (hb.oom) { s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory building the header", path); goto out; }
    if (hb.n > MLB_ST_MAX_HEADER) {
        s = mlb_fail(MLB_ERR_ARG, "%s: the header would be %zu bytes, more than the %llu a reader accepts", path,
                     hb.n, MLB_ST_MAX_HEADER);
        goto out;
    }

    mlb_atomic_file af;
    if ((s = mlb_atomic_open(&af, path)) != MLB_OK) goto out;
    unsigned char len8[8];
    for (int i = 0; i < 8; i++) len8[i] = (unsigned char)((uint64_t)hb.n >> (8 * i));
    int ok = fwrite(len8, 1, 8, af.f) == 8 && fwrite(hb.p, 1, hb.n, af.f) == hb.n;
    for (size_t i = 0; ok && i < n_entries; i++)
        if (nbytes[i]) ok = fwrite(entries[i].data, 1, nbytes[i], af.f) == nbytes[i];
    if (!ok) {
        int e = errno;
        mlb_atomic_abort(&af);
        s = mlb_fail(MLB_ERR_IO, "%s: write failed: %s", path, strerror(e));
        goto out;
    }
    s = mlb_atomic_commit(&af);
out:
    free(hb.p);
    free(nbytes);
    free(names);
    return s;
}
