// The CLIP byte-level BPE tokenizer: vocabulary from the merges (reference.md §6), loading from
// OpenAI's gzipped merges file or a diffusers tokenizer/ folder, lowest-rank-first merging with a
// per-word cache, the 77-token sequence and decoding. The text side is tokenizer_text.c.
#include <cjson/cJSON.h>
#include <errno.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>
#include "diffusion/tokenizer_internal.h"
#include "matlaber/fileio.h"
#include "matlaber/sd_files.h"
#include "matlaber/tokenizer.h"

#define MAX_MERGES_BYTES (64u << 20)    // decompressed merges file (the CLIP one is 3.2 MB)
#define MAX_MERGES_LINE 1024            // bytes per line (the CLIP one has at most 129)
#define MAX_VOCAB_JSON_BYTES (32u << 20)
#define CACHE_SLOTS 16384               // per-word cache: cleared when half full
#define CACHE_ARENA (4u << 20)

// An open-addressing hash table slot list; -1 = empty.
typedef struct { int32_t* slot; uint32_t mask; } hash_index;

typedef struct {
    uint64_t key;      // (left id << 32) | right id
    int32_t rank;      // 0-based line of the merge
    int32_t merged;    // id of the concatenation
} pair_entry;

struct mlb_tokenizer {
    int n_vocab, n_merges, bos, eos;
    size_t max_tokens;
    unsigned flags;
    int lock_ready;
    char source[1200];
    // token strings in vocab.json's byte-to-unicode form, NUL-terminated, in one arena
    char* arena;
    size_t arena_used, arena_cap;
    uint32_t* tok_off;
    uint32_t* tok_len;
    hash_index vocab;          // string -> id
    pair_entry* pairs;         // open addressing, key 0 = empty (id pairs never have key 0: ids >= 0, see pair_key)
    uint32_t pair_mask;
    int byte_id[256];          // byte -> id of its single-character token
    int byte_id_end[256];      // byte -> id of its token + "</w>"
    int16_t unicode_to_byte[512];   // the inverse byte-to-unicode table (code points < 324), -1 elsewhere
    // per-word cache: word bytes -> ids, stored as [len u32][bytes][n u32][ids] in cache_arena
    pthread_mutex_t lock;
    uint32_t* cache_slot;      // offset + 1 into cache_arena; 0 = empty
    size_t cache_count;
    unsigned char* cache_arena;
    size_t cache_used;
};

// ---- hashing ---------------------------------------------------------------------------------------

static uint64_t hash_bytes(const void* p, size_t n) {   // FNV-1a, then a final mix
    const unsigned char* s = p;
    uint64_t h = 1469598103934665603ull;
    for (size_t i = 0; i < n; i++) { h ^= s[i]; h *= 1099511628211ull; }
    h ^= h >> 29; h *= 0xbf58476d1ce4e5b9ull; h ^= h >> 32;
    return h;
}

static uint64_t mix64(uint64_t x) {
    x ^= x >> 33; x *= 0xff51afd7ed558ccdull; x ^= x >> 33; x *= 0xc4ceb9fe1a85ec53ull; x ^= x >> 33;
    return x;
}

static uint64_t pair_key(int a, int b) { return ((uint64_t)(uint32_t)(a + 1) << 32) | (uint32_t)b; }

static const char* tok_str(const mlb_tokenizer* t, int id) { return t->arena + t->tok_off[id]; }

static int vocab_find(const mlb_tokenizer* t, const char* s, size_t n) {
    for (uint32_t i = (uint32_t)hash_bytes(s, n) & t->vocab.mask;; i = (i + 1) & t->vocab.mask) {
        int32_t id = t->vocab.slot[i];
        if (id < 0) return -1;
        if (t->tok_len[id] == n && memcmp(tok_str(t, id), s, n) == 0) return id;
    }
}

static const pair_entry* pair_find(const mlb_tokenizer* t, int a, int b) {
    uint64_t key = pair_key(a, b);
    for (uint32_t i = (uint32_t)mix64(key) & t->pair_mask;; i = (i + 1) & t->pair_mask) {
        if (t->pairs[i].key == key) return &t->pairs[i];
        if (t->pairs[i].key == 0) return NULL;
    }
}

// ---- building the vocabulary ---------------------------------------------------------------------

// Printable excerpt of untrusted bytes for messages: non-printable bytes as \xNN, at most ~40 bytes.
static const char* excerpt(const char* s, size_t n, char* buf, size_t cap) {
    size_t m = 0;
    for (size_t i = 0; i < n && m + 8 < cap; i++) {
        unsigned char c = (unsigned char)s[i];
        if (i >= 40) { m += (size_t)snprintf(buf + m, cap - m, "..."); break; }
        int len = c >= 0x80 ? tok_utf8_seq_len((const unsigned char*)s + i, n - i) : 0;
        if (c >= 0x20 && c < 0x7F && c != '\\') buf[m++] = (char)c;
        else if (len > 0 && m + (size_t)len + 8 < cap) {   // whole UTF-8 characters pass through
            memcpy(buf + m, s + i, (size_t)len);
            m += (size_t)len; i += (size_t)len - 1;
        } else m += (size_t)snprintf(buf + m, cap - m, "\\x%02X", c);
    }
    buf[m] = 0;
    return buf;
}

// Adds a token string; a string already in the vocabulary is an error (vocab.json could not
// represent it). Returns the new id or -1 with the message set.
static int add_token(mlb_tokenizer* t, const char* s, size_t n, const char* where) {
    if ((size_t)t->n_vocab >= t->max_tokens) {
        mlb_fail(MLB_ERR_FORMAT, "%s: too many tokens", where);
        return -1;
    }
    if (vocab_find(t, s, n) >= 0) {
        char b[160];
        mlb_fail(MLB_ERR_FORMAT, "%s: token '%s' is made twice", where, excerpt(s, n, b, sizeof b));
        return -1;
    }
    if (t->arena_used + n + 1 > t->arena_cap) {
        size_t cap = 2 * t->arena_cap + n + 1;
        char* a = realloc(t->arena, cap);
        if (!a) { mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", where); return -1; }
        t->arena = a; t->arena_cap = cap;
    }
    int id = t->n_vocab++;
    t->tok_off[id] = (uint32_t)t->arena_used;
    t->tok_len[id] = (uint32_t)n;
    memcpy(t->arena + t->arena_used, s, n);
    t->arena[t->arena_used + n] = 0;
    t->arena_used += n + 1;
    uint32_t i = (uint32_t)hash_bytes(s, n) & t->vocab.mask;
    while (t->vocab.slot[i] >= 0) i = (i + 1) & t->vocab.mask;
    t->vocab.slot[i] = id;
    return id;
}

// GPT-2/CLIP's bytes_to_unicode: bytes '!'..'~', 0xA1..0xAC, 0xAE..0xFF stand for themselves, the
// other 68 for chr(256 + k) in byte order. order[i] = the byte of vocabulary entry i.
static void byte_table(uint32_t cp[256], int order[256]) {
    int m = 0;
    for (int b = 0; b < 256; b++)
        if ((b >= '!' && b <= '~') || (b >= 0xA1 && b <= 0xAC) || (b >= 0xAE && b <= 0xFF)) { cp[b] = (uint32_t)b; order[m++] = b; }
    int extra = 0;
    for (int b = 0; b < 256; b++)
        if (!((b >= '!' && b <= '~') || (b >= 0xA1 && b <= 0xAC) || (b >= 0xAE && b <= 0xFF))) {
            cp[b] = 256u + (uint32_t)extra++;
            order[m++] = b;
        }
}

static mlb_status tokenizer_alloc(mlb_tokenizer** out, int max_merges) {
    mlb_tokenizer* t = calloc(1, sizeof *t);
    if (!t) return mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory");
    *out = t;
    pthread_mutex_init(&t->lock, NULL);
    t->lock_ready = 1;
    size_t max_tokens = 512 + (size_t)max_merges + 2;
    t->max_tokens = max_tokens;
    uint32_t vcap = 1;
    while (vcap < 2 * max_tokens + 2) vcap <<= 1;
    uint32_t pcap = 1;
    while (pcap < 2 * (size_t)max_merges + 2) pcap <<= 1;
    t->vocab.slot = malloc(vcap * sizeof *t->vocab.slot);
    t->vocab.mask = vcap - 1;
    t->tok_off = malloc(max_tokens * sizeof *t->tok_off);
    t->tok_len = malloc(max_tokens * sizeof *t->tok_len);
    t->pairs = calloc(pcap, sizeof *t->pairs);
    t->pair_mask = pcap - 1;
    t->arena_cap = 1 << 20;
    t->arena = malloc(t->arena_cap);
    t->cache_slot = calloc(CACHE_SLOTS, sizeof *t->cache_slot);
    t->cache_arena = malloc(CACHE_ARENA);
    if (!t->vocab.slot || !t->tok_off || !t->tok_len || !t->pairs || !t->arena || !t->cache_slot || !t->cache_arena)
        return mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory");
    memset(t->vocab.slot, 0xFF, vcap * sizeof *t->vocab.slot);
    t->flags = MLB_TOKENIZER_FIX_TEXT | MLB_TOKENIZER_UNESCAPE_HTML;
    return MLB_OK;
}

void mlb_tokenizer_free(mlb_tokenizer* t) {
    if (!t) return;
    if (t->lock_ready) pthread_mutex_destroy(&t->lock);
    free(t->vocab.slot); free(t->tok_off); free(t->tok_len); free(t->pairs); free(t->arena);
    free(t->cache_slot); free(t->cache_arena);
    free(t);
}

// The 512 byte tokens, then one token per merge line, then the two specials. `text` holds the
// merges file (NUL-terminated); line 0 is the header and is skipped, at most MLB_CLIP_MERGES used.
static mlb_status build_from_merges(mlb_tokenizer* t, const char* text, size_t n, const char* name) {
    uint32_t cp[256];
    int order[256];
    byte_table(cp, order);
    for (int i = 0; i < 512; i++) t->unicode_to_byte[i] = -1;
    char buf[16];
    for (int pass = 0; pass < 2; pass++)
        for (int i = 0; i < 256; i++) {
            int b = order[i];
            int len = tok_utf8_put(cp[b], buf);
            if (pass) { memcpy(buf + len, "</w>", 4); len += 4; }
            int id = add_token(t, buf, (size_t)len, name);
            if (id < 0) return MLB_ERR_FORMAT;
            if (pass) t->byte_id_end[b] = id;
            else { t->byte_id[b] = id; t->unicode_to_byte[cp[b]] = (int16_t)b; }
        }
    // the header
    const char* p = text;
    const char* end = text + n;
    const char* nl = memchr(p, '\n', (size_t)(end - p));
    size_t hlen = nl ? (size_t)(nl - p) : (size_t)(end - p);
    if (hlen > MAX_MERGES_LINE) return mlb_fail(MLB_ERR_FORMAT, "%s: line 1 is longer than %d bytes", name, MAX_MERGES_LINE);
    char hb[160];
    if (!memmem(p, hlen, "#version", 8))
        return mlb_fail(MLB_ERR_FORMAT,
                        "%s: line 1 is '%s', not a '#version: ...' header: expected a CLIP BPE merges file "
                        "(bpe_simple_vocab_16e6.txt.gz or merges.txt)",
                        name, excerpt(p, hlen, hb, sizeof hb));
    p = nl ? nl + 1 : end;
    int line = 1;
    while (p < end) {
        line++;
        nl = memchr(p, '\n', (size_t)(end - p));
        const char* le = nl ? nl : end;
        if ((size_t)(le - p) > MAX_MERGES_LINE)
            return mlb_fail(MLB_ERR_FORMAT, "%s: line %d is longer than %d bytes", name, line, MAX_MERGES_LINE);
        if (t->n_merges < MLB_CLIP_MERGES) {
            const char* q = le;
            if (q > p && q[-1] == '\r') q--;
            if (q == p && !nl) break;   // a final newline
            // two symbols separated by one space
            const char* sp = memchr(p, ' ', (size_t)(q - p));
            const char* sp2 = sp ? memchr(sp + 1, ' ', (size_t)(q - sp - 1)) : NULL;
            if (!sp || sp == p || sp + 1 == q || sp2 || memchr(p, '\t', (size_t)(q - p)))
                return mlb_fail(MLB_ERR_FORMAT, "%s: line %d is '%s', expected two symbols separated by a space", name,
                                line, excerpt(p, (size_t)(q - p), hb, sizeof hb));
            int a = vocab_find(t, p, (size_t)(sp - p));
            int b = vocab_find(t, sp + 1, (size_t)(q - sp - 1));
            if (a < 0 || b < 0) {
                const char* bad = a < 0 ? p : sp + 1;
                size_t bl = a < 0 ? (size_t)(sp - p) : (size_t)(q - sp - 1);
                return mlb_fail(MLB_ERR_FORMAT, "%s: line %d: symbol '%s' is neither a byte symbol nor made by an earlier merge",
                                name, line, excerpt(bad, bl, hb, sizeof hb));
            }
            char cat[2 * MAX_MERGES_LINE];
            size_t la = t->tok_len[a], lb = t->tok_len[b];
            memcpy(cat, tok_str(t, a), la);
            memcpy(cat + la, tok_str(t, b), lb);
            char where[256];
            snprintf(where, sizeof where, "%s: line %d", name, line);
            int id = add_token(t, cat, la + lb, where);
            if (id < 0) return MLB_ERR_FORMAT;
            uint64_t key = pair_key(a, b);
            uint32_t i = (uint32_t)mix64(key) & t->pair_mask;
            while (t->pairs[i].key != 0 && t->pairs[i].key != key) i = (i + 1) & t->pair_mask;
            if (t->pairs[i].key == key)   // cannot happen: the concatenation would be a duplicate token
                return mlb_fail(MLB_ERR_FORMAT, "%s: line %d repeats an earlier merge", name, line);
            t->pairs[i] = (pair_entry){key, t->n_merges, id};
            t->n_merges++;
        }
        if (!nl) break;
        p = nl + 1;
    }
    if (t->n_merges == 0) return mlb_fail(MLB_ERR_FORMAT, "%s: no merges after the header line", name);
    t->bos = add_token(t, "<|startoftext|>", 15, name);
    if (t->bos < 0) return MLB_ERR_FORMAT;
    t->eos = add_token(t, "<|endoftext|>", 13, name);
    if (t->eos < 0) return MLB_ERR_FORMAT;
    return MLB_OK;
}

// ---- reading the files ----------------------------------------------------------------------------


// A whole gzip file into memory from fd (which it closes), checking the stream to its end (CRC and
// length included).
static mlb_status read_gzip(const char* path, int fd, char** data, size_t* n) {
    *data = NULL; *n = 0;
    gzFile f = gzdopen(fd, "rb");
    if (!f) { close(fd); return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); }
    size_t cap = 4u << 20, used = 0;
    char* buf = malloc(cap + 1);
    if (!buf) { gzclose(f); return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); }
    for (;;) {
        if (used == cap) {
            if (cap >= MAX_MERGES_BYTES) {
                free(buf); gzclose(f);
                return mlb_fail(MLB_ERR_FORMAT, "%s: decompresses to more than %u bytes: not a CLIP merges file", path,
                                MAX_MERGES_BYTES);
            }
            cap *= 2;
            char* b = realloc(buf, cap + 1);
            if (!b) { free(buf); gzclose(f); return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); }
            buf = b;
        }
        int got = gzread(f, buf + used, (unsigned)(cap - used));
        if (got < 0) break;
        if (got == 0) break;
        used += (size_t)got;
    }
    int err = Z_OK;
    const char* msg = gzerror(f, &err);
    int direct = gzdirect(f);
    if (err != Z_OK && err != Z_STREAM_END) {
        mlb_status s = mlb_fail(MLB_ERR_FORMAT, "%s: broken gzip data after %zu decompressed bytes: %s%s", path, used,
                                msg && *msg ? msg : "zlib error",
                                err == Z_BUF_ERROR ? " (the file is truncated)" : "");
        free(buf); gzclose(f);
        return s;
    }
    gzclose(f);
    if (direct) {
        free(buf);
        return mlb_fail(MLB_ERR_FORMAT, "%s: not gzip-compressed; expected the gzipped CLIP merges file "
                        "(bpe_simple_vocab_16e6.txt.gz)", path);
    }
    buf[used] = 0;
    *data = buf; *n = used;
    return MLB_OK;
}

static mlb_status load_merges_text(mlb_tokenizer* t, const char* path, const char* text, size_t n) {
    if (memchr(text, 0, n)) return mlb_fail(MLB_ERR_FORMAT, "%s: contains NUL bytes: not a CLIP BPE merges file (expected "
                                           "bpe_simple_vocab_16e6.txt.gz, merges.txt or a tokenizer folder)", path);
    return build_from_merges(t, text, n, path);
}

// vocab.json must map exactly the tokens the merges made to the same ids.
static mlb_status check_vocab_json(const mlb_tokenizer* t, const char* path) {
    cJSON* root;
    MLB_TRY(mlb_json_read_file(path, MAX_VOCAB_JSON_BYTES, &root));
    mlb_status s = MLB_OK;
    unsigned char* seen = calloc((size_t)t->n_vocab, 1);
    if (!seen) { cJSON_Delete(root); return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); }
    if (!cJSON_IsObject(root)) { s = mlb_fail(MLB_ERR_FORMAT, "%s: expected a JSON object of token -> id", path); goto done; }
    int count = cJSON_GetArraySize(root);
    if (count != t->n_vocab) {
        s = mlb_fail(MLB_ERR_FORMAT, "%s has %d tokens but the merges make %d: vocab.json and merges.txt do not belong together",
                     path, count, t->n_vocab);
        goto done;
    }
    char b[160];
    for (const cJSON* e = root->child; e; e = e->next) {
        const char* key = e->string ? e->string : "";
        double v = cJSON_IsNumber(e) ? e->valuedouble : -1;
        if (v < 0 || v >= t->n_vocab || v != (double)(int)v) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: token '%s' has no valid id (expected an integer 0..%d)", path,
                         excerpt(key, strlen(key), b, sizeof b), t->n_vocab - 1);
            goto done;
        }
        int id = vocab_find(t, key, strlen(key));
        if (id < 0) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: token '%s' (id %d) is not made by merges.txt", path, excerpt(key, strlen(key), b, sizeof b), (int)v);
            goto done;
        }
        if (id != (int)v) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: token '%s' has id %d but merges.txt gives it id %d", path,
                         excerpt(key, strlen(key), b, sizeof b), (int)v, id);
            goto done;
        }
        if (seen[id]++) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s: token '%s' appears twice", path, excerpt(key, strlen(key), b, sizeof b));
            goto done;
        }
    }
done:
    free(seen);
    cJSON_Delete(root);
    return s;
}


// A folder with merges.txt (and vocab.json when present).
static mlb_status load_folder(mlb_tokenizer* t, const char* dir) {
    char merges[1100], vocab[1100];
    snprintf(merges, sizeof merges, "%s/merges.txt", dir);
    snprintf(vocab, sizeof vocab, "%s/vocab.json", dir);
    char* text;
    size_t n;
    MLB_TRY(mlb_read_file(merges, &text, &n, MAX_MERGES_BYTES));
    mlb_status s = load_merges_text(t, merges, text, n);
    free(text);
    if (s) return s;
    int has_vocab = mlb_is_file(vocab);
    if (has_vocab) MLB_TRY(check_vocab_json(t, vocab));
    snprintf(t->source, sizeof t->source, "%s (merges.txt%s, %d merges)", dir, has_vocab ? " + vocab.json" : "", t->n_merges);
    return MLB_OK;
}

static mlb_status load_file(mlb_tokenizer* t, const char* path) {
    int fd;
    MLB_TRY(mlb_open_input(path, &fd, NULL));   // regular files only (fileio.h)
    unsigned char magic[2] = {0, 0};
    ssize_t got = read(fd, magic, 2);
    char* text;
    size_t n;
    if (got == 2 && magic[0] == 0x1F && magic[1] == 0x8B && lseek(fd, 0, SEEK_SET) == 0) {
        MLB_TRY(read_gzip(path, fd, &text, &n));
        mlb_status s = load_merges_text(t, path, text, n);
        free(text);
        if (s) return s;
        snprintf(t->source, sizeof t->source, "%s (gzipped merges, %d merges)", path, t->n_merges);
        return MLB_OK;
    }
    close(fd);
    if (mlb_ends_with(path, ".gz"))
        return mlb_fail(MLB_ERR_FORMAT, "%s: not gzip-compressed (no gzip signature); expected the gzipped CLIP merges "
                        "file bpe_simple_vocab_16e6.txt.gz", path);
    if (mlb_ends_with(path, ".json"))
        return mlb_fail(MLB_ERR_ARG, "%s: a JSON file; pass the tokenizer folder (merges.txt + vocab.json) instead", path);
    MLB_TRY(mlb_read_file(path, &text, &n, MAX_MERGES_BYTES));
    mlb_status s = load_merges_text(t, path, text, n);
    free(text);
    if (s) return s;
    snprintf(t->source, sizeof t->source, "%s (merges text, %d merges)", path, t->n_merges);
    return MLB_OK;
}

static mlb_status load_path(mlb_tokenizer* t, const char* path) {
    struct stat st;
    if (stat(path, &st) != 0)
        return mlb_fail(errno == ENOENT ? MLB_ERR_NOT_FOUND : MLB_ERR_IO, "tokenizer %s: %s", path, strerror(errno));
    if (S_ISREG(st.st_mode)) return load_file(t, path);
    if (!S_ISDIR(st.st_mode)) return mlb_fail(MLB_ERR_ARG, "tokenizer %s: neither a file nor a folder", path);
    char p[1100];
    snprintf(p, sizeof p, "%s/merges.txt", path);
    if (mlb_is_file(p)) return load_folder(t, path);
    snprintf(p, sizeof p, "%s/tokenizer/merges.txt", path);
    if (mlb_is_file(p)) { snprintf(p, sizeof p, "%s/tokenizer", path); return load_folder(t, p); }
    snprintf(p, sizeof p, "%s/bpe_simple_vocab_16e6.txt.gz", path);
    if (mlb_is_file(p)) return load_file(t, p);
    snprintf(p, sizeof p, "%s/vocab.json", path);
    char q[1100];
    snprintf(q, sizeof q, "%s/tokenizer", path);
    if (mlb_is_file(p) || mlb_is_dir(q))
        return mlb_fail(MLB_ERR_NOT_FOUND, "tokenizer %s: has %s but no merges.txt beside it; the BPE merges are needed",
                        path, mlb_is_file(p) ? "vocab.json" : "tokenizer/");
    return mlb_fail(MLB_ERR_NOT_FOUND,
                    "tokenizer %s: no tokenizer found; expected the gzipped merges file bpe_simple_vocab_16e6.txt.gz, "
                    "a folder with merges.txt (and vocab.json), or a model folder with tokenizer/merges.txt", path);
}

mlb_status mlb_tokenizer_load(const char* path, mlb_tokenizer** out) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "tokenizer: NULL output");
    *out = NULL;
    if (!path || !*path) return mlb_fail(MLB_ERR_ARG, "tokenizer: empty path");
    if (strlen(path) > 1000) return mlb_fail(MLB_ERR_ARG, "tokenizer: path longer than 1000 bytes");
    mlb_tokenizer* t = NULL;
    mlb_status s = tokenizer_alloc(&t, MLB_CLIP_MERGES);
    if (!s) s = load_path(t, path);
    if (s) { mlb_tokenizer_free(t); return s; }
    *out = t;
    return MLB_OK;
}

// ---- BPE ----------------------------------------------------------------------------------------

typedef struct { int32_t rank, left, right; } heap_item;

static int heap_less(heap_item a, heap_item b) { return a.rank < b.rank || (a.rank == b.rank && a.left < b.left); }

static void heap_push(heap_item* h, int* n, heap_item x) {
    int i = (*n)++;
    while (i > 0) {
        int p = (i - 1) / 2;
        if (!heap_less(x, h[p])) break;
        h[i] = h[p]; i = p;
    }
    h[i] = x;
}

static heap_item heap_pop(heap_item* h, int* n) {
    heap_item top = h[0], x = h[--(*n)];
    int i = 0;
    for (;;) {
        int c = 2 * i + 1;
        if (c >= *n) break;
        if (c + 1 < *n && heap_less(h[c + 1], h[c])) c++;
        if (!heap_less(h[c], x)) break;
        h[i] = h[c]; i = c;
    }
    if (*n > 0) h[i] = x;
    return top;
}

// BPE of one piece (its UTF-8 bytes): symbols start as the bytes (the last with "</w>"); the
// lowest-ranked adjacent pair is merged, all its occurrences left to right, until no pair is a
// merge. A heap ordered by (rank, position) does this in O(n log n): a merge's parts are always
// made by earlier merges (checked at load), so a merge never creates a pair ranked below its own.
// Writes the ids to out (n entries suffice) and returns their count; -1 when out of memory.
static int bpe_word(const mlb_tokenizer* t, const unsigned char* w, int n, int* out) {
    if (n == 1) { out[0] = t->byte_id_end[w[0]]; return 1; }
    // The heap holds the n - 1 first pairs plus at most two per merge (n - 1 merges): < 3n items.
    int32_t stack_buf[4 * 64];
    heap_item stack_heap[3 * 64];
    int32_t* mem = n <= 64 ? stack_buf : malloc((size_t)n * 4 * sizeof *mem);
    heap_item* heap = n <= 64 ? stack_heap : malloc((size_t)n * 3 * sizeof *heap);
    if (!mem || !heap) { if (n > 64) { free(mem); free(heap); } return -1; }
    int32_t *sym = mem, *next = mem + n, *prev = mem + 2 * n, *alive = mem + 3 * n;
    for (int i = 0; i < n; i++) {
        sym[i] = i == n - 1 ? t->byte_id_end[w[i]] : t->byte_id[w[i]];
        next[i] = i + 1 < n ? i + 1 : -1;
        prev[i] = i - 1;
        alive[i] = 1;
    }
    int nh = 0;
    for (int i = 0; i + 1 < n; i++) {
        const pair_entry* e = pair_find(t, sym[i], sym[i + 1]);
        if (e) heap_push(heap, &nh, (heap_item){e->rank, i, i + 1});
    }
    while (nh > 0) {
        heap_item it = heap_pop(heap, &nh);
        int l = it.left, r = it.right;
        if (!alive[l] || !alive[r] || next[l] != r) continue;   // stale: one side merged since
        const pair_entry* e = pair_find(t, sym[l], sym[r]);
        if (!e || e->rank != it.rank) continue;                 // stale: a side changed
        sym[l] = e->merged;
        alive[r] = 0;
        next[l] = next[r];
        if (next[r] >= 0) prev[next[r]] = l;
        if (prev[l] >= 0) {
            const pair_entry* p = pair_find(t, sym[prev[l]], sym[l]);
            if (p) heap_push(heap, &nh, (heap_item){p->rank, prev[l], l});
        }
        if (next[l] >= 0) {
            const pair_entry* p = pair_find(t, sym[l], sym[next[l]]);
            if (p) heap_push(heap, &nh, (heap_item){p->rank, l, next[l]});
        }
    }
    int m = 0;
    for (int i = 0; i >= 0; i = next[i]) out[m++] = sym[i];
    if (n > 64) { free(mem); free(heap); }
    return m;
}

// The cache: lookups and inserts under the lock; BPE itself runs outside it.
static int cache_get(mlb_tokenizer* t, const unsigned char* w, uint32_t n, uint64_t h, int* out) {
    int found = -1;
    pthread_mutex_lock(&t->lock);
    for (uint32_t i = (uint32_t)h & (CACHE_SLOTS - 1);; i = (i + 1) & (CACHE_SLOTS - 1)) {
        uint32_t off = t->cache_slot[i];
        if (!off) break;
        const unsigned char* e = t->cache_arena + off - 1;
        uint32_t len, cnt;
        memcpy(&len, e, 4);
        if (len == n && memcmp(e + 4, w, n) == 0) {
            memcpy(&cnt, e + 4 + n, 4);
            memcpy(out, e + 8 + n, cnt * sizeof *out);
            found = (int)cnt;
            break;
        }
    }
    pthread_mutex_unlock(&t->lock);
    return found;
}

static void cache_put(mlb_tokenizer* t, const unsigned char* w, uint32_t n, uint64_t h, const int* ids, uint32_t cnt) {
    size_t need = 8 + n + (size_t)cnt * sizeof *ids;
    if (need > CACHE_ARENA / 64) return;   // long pieces are not worth keeping
    pthread_mutex_lock(&t->lock);
    if (t->cache_count >= CACHE_SLOTS / 2 || t->cache_used + need > CACHE_ARENA) {
        memset(t->cache_slot, 0, CACHE_SLOTS * sizeof *t->cache_slot);
        t->cache_count = 0; t->cache_used = 0;
    }
    uint32_t i = (uint32_t)h & (CACHE_SLOTS - 1);
    int present = 0;
    for (; t->cache_slot[i]; i = (i + 1) & (CACHE_SLOTS - 1)) {
        const unsigned char* e = t->cache_arena + t->cache_slot[i] - 1;
        uint32_t len;
        memcpy(&len, e, 4);
        if (len == n && memcmp(e + 4, w, n) == 0) { present = 1; break; }   // another thread was first
    }
    if (!present) {
        unsigned char* e = t->cache_arena + t->cache_used;
        memcpy(e, &n, 4);
        memcpy(e + 4, w, n);
        memcpy(e + 4 + n, &cnt, 4);
        memcpy(e + 8 + n, ids, cnt * sizeof *ids);
        t->cache_slot[i] = (uint32_t)t->cache_used + 1;
        t->cache_used += (need + 7) & ~(size_t)7;
        t->cache_count++;
    }
    pthread_mutex_unlock(&t->lock);
}

// ---- encoding -----------------------------------------------------------------------------------

typedef struct { int* v; size_t n, cap; } idbuf;

static int idbuf_reserve(idbuf* b, size_t extra) {
    if (b->n + extra <= b->cap) return 0;
    size_t cap = b->cap ? b->cap : 128;
    while (cap < b->n + extra) cap *= 2;
    int* v = realloc(b->v, cap * sizeof *v);
    if (!v) return -1;
    b->v = v; b->cap = cap;
    return 0;
}

// The text's BPE ids into *out (no bos/eos), stopping once `stop_after` ids are there.
static mlb_status encode_ids(mlb_tokenizer* t, const char* text, idbuf* out, size_t stop_after) {
    if (!t) return mlb_fail(MLB_ERR_ARG, "tokenizer: NULL tokenizer");
    uint32_t* cps;
    size_t n;
    MLB_TRY(tok_clean(text, t->flags, &cps, &n));
    mlb_status s = MLB_OK;
    unsigned char small[256];
    unsigned char* word = small;
    size_t word_cap = sizeof small;
    size_t pos = 0, a, e;
    int special;
    while (out->n < stop_after && tok_next_piece(cps, n, &pos, &a, &e, &special)) {
        if (special) {
            if (idbuf_reserve(out, 1)) { s = mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory"); break; }
            out->v[out->n++] = special == 1 ? t->bos : t->eos;
            continue;
        }
        size_t need = 4 * (e - a);
        if (need > word_cap) {
            unsigned char* w = malloc(need);
            if (!w) { s = mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory"); break; }
            if (word != small) free(word);
            word = w; word_cap = need;
        }
        size_t wn = 0;
        for (size_t i = a; i < e; i++) wn += (size_t)tok_utf8_put(cps[i], (char*)word + wn);
        if (idbuf_reserve(out, wn)) { s = mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory"); break; }
        uint64_t h = hash_bytes(word, wn);
        int m = cache_get(t, word, (uint32_t)wn, h, out->v + out->n);
        if (m < 0) {
            m = bpe_word(t, word, (int)wn, out->v + out->n);
            if (m < 0) { s = mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory"); break; }
            cache_put(t, word, (uint32_t)wn, h, out->v + out->n, (uint32_t)m);
        }
        out->n += (size_t)m;
    }
    if (word != small) free(word);
    free(cps);
    return s;
}

mlb_status mlb_tokenizer_tokenize(mlb_tokenizer* t, const char* text, int** ids, size_t* n) {
    if (!ids || !n) return mlb_fail(MLB_ERR_ARG, "tokenizer: NULL output");
    *ids = NULL; *n = 0;
    idbuf b = {0};
    mlb_status s = encode_ids(t, text, &b, (size_t)-1);
    if (s) { free(b.v); return s; }
    if (!b.v) b.v = malloc(sizeof *b.v);
    if (!b.v) return mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory");
    *ids = b.v; *n = b.n;
    return MLB_OK;
}

mlb_status mlb_tokenizer_encode(mlb_tokenizer* t, const char* text, int* ids, int max_len, int pad_id, int* n_used) {
    if (n_used) *n_used = 0;
    if (!t || !ids) return mlb_fail(MLB_ERR_ARG, "tokenizer: NULL tokenizer or output");
    if (max_len < 2) return mlb_fail(MLB_ERR_ARG, "tokenizer: max_len %d leaves no room for the start and end tokens", max_len);
    if (pad_id < 0 || pad_id >= t->n_vocab)
        return mlb_fail(MLB_ERR_ARG, "tokenizer: pad id %d is outside the vocabulary (0..%d)", pad_id, t->n_vocab - 1);
    size_t room = (size_t)max_len - 2;
    idbuf b = {0};
    mlb_status s = encode_ids(t, text, &b, room + 1);
    if (s) { free(b.v); return s; }
    size_t m = b.n < room ? b.n : room;
    ids[0] = t->bos;
    for (size_t i = 0; i < m; i++) ids[1 + i] = b.v[i];
    ids[1 + m] = t->eos;
    for (size_t i = m + 2; i < (size_t)max_len; i++) ids[i] = pad_id;
    if (n_used) *n_used = (int)(m + 2);
    free(b.v);
    return MLB_OK;
}

// ---- decoding and queries -------------------------------------------------------------------------

mlb_status mlb_tokenizer_decode(const mlb_tokenizer* t, const int* ids, size_t n, char** text) {
    if (!text) return mlb_fail(MLB_ERR_ARG, "tokenizer: NULL output");
    *text = NULL;
    if (!t || (!ids && n)) return mlb_fail(MLB_ERR_ARG, "tokenizer: NULL tokenizer or ids");
    size_t total = 0;
    for (size_t i = 0; i < n; i++) {
        if (ids[i] < 0 || ids[i] >= t->n_vocab)
            return mlb_fail(MLB_ERR_ARG, "tokenizer: id %d at position %zu is outside the vocabulary (0..%d)", ids[i], i,
                            t->n_vocab - 1);
        total += t->tok_len[ids[i]];
    }
    unsigned char* bytes = malloc(total + 1);
    if (!bytes) return mlb_fail(MLB_ERR_NOMEM, "tokenizer: out of memory");
    size_t m = 0;
    for (size_t i = 0; i < n; i++) {
        const char* s = tok_str(t, ids[i]);
        size_t len = t->tok_len[ids[i]];
        // byte_decoder over the token's characters; every character of a token is in the table
        // except those of the special tokens, which are ASCII and map to themselves.
        for (size_t k = 0; k < len;) {
            uint32_t c;
            size_t step;
            unsigned char b0 = (unsigned char)s[k];
            if (b0 < 0x80) { c = b0; step = 1; }
            else if (b0 < 0xE0) { c = ((uint32_t)(b0 & 0x1F) << 6) | ((unsigned char)s[k + 1] & 0x3F); step = 2; }
            else { c = 0xFFFD; step = 1; }   // not produced by the byte table
            bytes[m++] = c < 512 && t->unicode_to_byte[c] >= 0 ? (unsigned char)t->unicode_to_byte[c] : (unsigned char)'?';
            k += step;
        }
    }
    char* utf8;
    size_t un;
    mlb_status st = tok_utf8_decode_replace(bytes, m, &utf8, &un);
    free(bytes);
    if (st) return st;
    // .replace('</w>', ' ') in place: the result only shrinks
    size_t w = 0;
    for (size_t r = 0; r < un;) {
        if (r + 4 <= un && memcmp(utf8 + r, "</w>", 4) == 0) { utf8[w++] = ' '; r += 4; }
        else utf8[w++] = utf8[r++];
    }
    utf8[w] = 0;
    *text = utf8;
    return MLB_OK;
}

const char* mlb_tokenizer_source(const mlb_tokenizer* t) { return t ? t->source : ""; }
int mlb_tokenizer_vocab_size(const mlb_tokenizer* t) { return t ? t->n_vocab : 0; }
int mlb_tokenizer_n_merges(const mlb_tokenizer* t) { return t ? t->n_merges : 0; }
int mlb_tokenizer_bos(const mlb_tokenizer* t) { return t ? t->bos : -1; }
int mlb_tokenizer_eos(const mlb_tokenizer* t) { return t ? t->eos : -1; }
unsigned mlb_tokenizer_flags(const mlb_tokenizer* t) { return t ? t->flags : 0; }
void mlb_tokenizer_set_flags(mlb_tokenizer* t, unsigned flags) { if (t) t->flags = flags & 3u; }

const char* mlb_tokenizer_token(const mlb_tokenizer* t, int id) {
    if (!t || id < 0 || id >= t->n_vocab) return NULL;
    return tok_str(t, id);
}

mlb_status mlb_tokenizer_token_id(const mlb_tokenizer* t, const char* token, int* id) {
    if (!id) return mlb_fail(MLB_ERR_ARG, "tokenizer: NULL output");
    *id = -1;
    if (!t || !token) return mlb_fail(MLB_ERR_ARG, "tokenizer: NULL tokenizer or token");
    *id = vocab_find(t, token, strlen(token));
    if (*id < 0) {
        char b[160];
        return mlb_fail(MLB_ERR_NOT_FOUND, "tokenizer: '%s' is not in the vocabulary", excerpt(token, strlen(token), b, sizeof b));
    }
    return MLB_OK;
}

mlb_status mlb_tokenizer_pad_id(const char* model, int* pad_id) {
    if (!pad_id) return mlb_fail(MLB_ERR_ARG, "tokenizer: NULL output");
    if (model && strcmp(model, "sd1") == 0) { *pad_id = MLB_CLIP_PAD_SD1; return MLB_OK; }
    if (model && strcmp(model, "sd2") == 0) { *pad_id = MLB_CLIP_PAD_SD2; return MLB_OK; }
    return mlb_fail(MLB_ERR_ARG, "unknown model '%s' for padding: expected sd1 (pads with 49407) or sd2 (pads with 0)",
                    model ? model : "(null)");
}
