// The prompts file of generate --prompts (prompts.h): lines split in place, each checked whole
// (UTF-8, control bytes, lengths) before its options and prompt are taken apart.
#include "matlaber/prompts.h"
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "diffusion/tokenizer_internal.h"

static void slug(char* out, size_t cap, const char* text) {
    size_t n = 0;
    int dash = 0;
    for (const char* p = text; *p && n + 2 < cap && n < 40; p++) {
        char c = *p;
        if (c >= 'A' && c <= 'Z') c = (char)(c - 'A' + 'a');
        if ((c >= 'a' && c <= 'z') || (c >= '0' && c <= '9')) { out[n++] = c; dash = 0; }
        else if (!dash && n > 0) { out[n++] = '-'; dash = 1; }
    }
    while (n > 0 && out[n - 1] == '-') n--;
    out[n] = 0;
    if (!n) snprintf(out, cap, "prompt");
}

static uint64_t fnv(uint64_t h, const char* s) {
    for (; *s; s++) h = (h ^ (unsigned char)*s) * 1099511628211ull;
    return (h ^ 0x1f) * 1099511628211ull;
}

// 1 when an option word can be shown in a message: letters, digits and dashes, not too long
static int showable(const char* w) {
    size_t n = 0;
    for (; w[n]; n++)
        if (n >= 40 || !((w[n] >= 'a' && w[n] <= 'z') || (w[n] >= 'A' && w[n] <= 'Z') || (w[n] >= '0' && w[n] <= '9') || w[n] == '-'))
            return 0;
    return 1;
}

// The whole line (n bytes, no line end): strict UTF-8, no control byte but the tab.
static mlb_status check_line(const char* file, int line, const char* s, size_t n) {
    for (size_t i = 0; i < n;) {
        unsigned char c = (unsigned char)s[i];
        if (!c) return mlb_fail(MLB_ERR_FORMAT, "%s: line %d: a NUL byte at column %zu (binary data, not a prompts file)", file, line, i + 1);
        if ((c < 0x20 && c != '\t') || c == 0x7F)
            return mlb_fail(MLB_ERR_FORMAT, "%s: line %d: control byte 0x%02X at column %zu (not prompt text)", file, line, c, i + 1);
        int len = c < 0x80 ? 1 : tok_utf8_seq_len((const unsigned char*)s + i, n - i);
        if (!len) return mlb_fail(MLB_ERR_FORMAT, "%s: line %d: byte 0x%02X at column %zu is not valid UTF-8", file, line, c, i + 1);
        i += (size_t)len;
    }
    return MLB_OK;
}

// the next word of *p (spaces and tabs between words), NUL-terminated in place; "" at the end
static char* next_word(char** p) {
    char* q = *p;
    while (*q == ' ' || *q == '\t') q++;
    char* w = q;
    while (*q && *q != ' ' && *q != '\t') q++;
    if (*q) *q++ = 0;
    *p = q;
    return w;
}

// "[--opt [value] ...] prompt": options of generate first, the rest of the line is the prompt. The
// folder is --name, else the prompt's slug and a hash of prompt and options (a line edited into
// another prompt or other settings is another run; reordering lines changes nothing).
static mlb_status parse_line(mlb_prompt* it, char* text, int line, const char* file, mlb_prompt_arity_fn arity) {
    memset(it, 0, sizeof *it);
    it->line = line;
    char* p = text;
    const char* name = NULL;
    for (;;) {
        while (*p == ' ' || *p == '\t') p++;
        if (strncmp(p, "--", 2) != 0) break;
        char* tok = next_word(&p);
        char key[64];
        size_t klen = strcspn(tok + 2, "=");
        if (klen >= sizeof key) klen = sizeof key - 1;   // no option is that long: refused below as unknown
        memcpy(key, tok + 2, klen);
        key[klen] = 0;
        const char* eq = tok[2 + klen] == '=' ? tok + 2 + klen + 1 : NULL;
        if (!strcmp(key, "name")) {
            name = eq ? eq : next_word(&p);
            continue;
        }
        int a = klen > 60 ? -1 : arity(key);
        if (a < 0) {
            if (showable(key)) return mlb_fail(MLB_ERR_FORMAT, "%s: line %d: --%s is not an option a prompt line may set", file, line, key);
            return mlb_fail(MLB_ERR_FORMAT, "%s: line %d: a word starting with -- that is not an option a prompt line may set", file, line);
        }
        if (it->n_opts + 2 > MLB_PROMPTS_MAX_OPTS)
            return mlb_fail(MLB_ERR_FORMAT, "%s: line %d: more than %d option words", file, line, MLB_PROMPTS_MAX_OPTS);
        it->opts[it->n_opts++] = tok;
        const char* val = eq;
        if (a == 1 && !eq) {
            char* v = next_word(&p);
            if (!*v) return mlb_fail(MLB_ERR_FORMAT, "%s: line %d: --%s needs a value", file, line, key);
            it->opts[it->n_opts++] = v;
            val = v;
        }
        if (val && strlen(val) > MLB_PROMPTS_MAX_TEXT)
            return mlb_fail(MLB_ERR_FORMAT, "%s: line %d: the value of --%s has %zu bytes (at most %d)", file, line, key, strlen(val),
                            MLB_PROMPTS_MAX_TEXT);
    }
    size_t len = strlen(p);
    while (len && (p[len - 1] == ' ' || p[len - 1] == '\t')) p[--len] = 0;
    if (!*p) return mlb_fail(MLB_ERR_FORMAT, "%s: line %d: options but no prompt", file, line);
    if (len > MLB_PROMPTS_MAX_TEXT)
        return mlb_fail(MLB_ERR_FORMAT, "%s: line %d: a prompt of %zu bytes (at most %d)", file, line, len, MLB_PROMPTS_MAX_TEXT);
    it->prompt = p;
    if (name) {
        size_t nl = strlen(name);
        if (!nl || nl > MLB_PROMPTS_MAX_NAME || strchr(name, '/') || name[0] == '.')
            return mlb_fail(MLB_ERR_FORMAT, "%s: line %d: --name: a folder name of 1..%d bytes, without '/', not starting with '.'",
                            file, line, MLB_PROMPTS_MAX_NAME);
        memcpy(it->name, name, nl + 1);
    } else {
        uint64_t h = fnv(1469598103934665603ull, p);
        for (int i = 0; i < it->n_opts; i++) h = fnv(h, it->opts[i]);
        char s[64];
        slug(s, sizeof s, p);
        snprintf(it->name, sizeof it->name, "%s-%08x", s, (unsigned)(h ^ (h >> 32)));
    }
    return MLB_OK;
}

static int by_name(const void* a, const void* b) {
    const mlb_prompt *x = *(const mlb_prompt* const*)a, *y = *(const mlb_prompt* const*)b;
    int c = strcmp(x->name, y->name);
    return c ? c : x->line - y->line;
}

// Two lines that make the same run folder: the pair whose later line comes first (sorted by name,
// not compared pairwise: a file of a million lines takes a moment, not hours).
static mlb_status check_names(const mlb_prompt_list* l, const char* file) {
    const mlb_prompt** s = malloc(sizeof *s * (size_t)l->n);
    if (!s) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for %d prompts", file, l->n);
    for (int i = 0; i < l->n; i++) s[i] = &l->items[i];
    qsort(s, (size_t)l->n, sizeof *s, by_name);
    const mlb_prompt *first = NULL, *again = NULL;
    for (int i = 1; i < l->n; i++)
        if (!strcmp(s[i]->name, s[i - 1]->name) && (!again || s[i]->line < again->line)) {
            int j = i - 1;
            while (j > 0 && !strcmp(s[j - 1]->name, s[i]->name)) j--;
            first = s[j];
            again = s[i];
        }
    free(s);
    if (!again) return MLB_OK;
    return mlb_fail(MLB_ERR_FORMAT, "%s: lines %d and %d both make the run %s (a repeated line? tell them apart with --name or "
                    "--seed)", file, first->line, again->line, again->name);
}

mlb_status mlb_prompts_parse(const char* data, size_t n, const char* file, mlb_prompt_arity_fn arity, mlb_prompt_list* out) {
    memset(out, 0, sizeof *out);
    char* text = malloc(n + 1);
    if (!text) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for %zu bytes", file, n);
    if (n) memcpy(text, data, n);
    text[n] = 0;
    mlb_prompt_list l = {NULL, 0, text};
    int cap = 0, line = 0;
    mlb_status s = MLB_OK;
    size_t i = n >= 3 && !memcmp(text, "\xEF\xBB\xBF", 3) ? 3 : 0;   // a byte-order mark
    while (!s && i < n) {
        size_t e = i;
        while (e < n && text[e] != '\n' && text[e] != '\r') e++;   // LF, CRLF or CR
        size_t next = e < n && text[e] == '\r' && e + 1 < n && text[e + 1] == '\n' ? e + 2 : e + 1;
        line++;
        s = check_line(file, line, text + i, e - i);
        if (s) break;
        text[e < n ? e : n] = 0;
        char* q = text + i;
        i = next;
        while (*q == ' ' || *q == '\t') q++;
        if (!*q || *q == '#') continue;
        if (l.n == cap) {
            int nc = cap ? 2 * cap : 16;
            mlb_prompt* p = realloc(l.items, sizeof *p * (size_t)nc);
            if (!p) { s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory at line %d", file, line); break; }
            l.items = p;
            cap = nc;
        }
        s = parse_line(&l.items[l.n], q, line, file, arity);
        if (!s) l.n++;
    }
    if (!s && l.n == 0) s = mlb_fail(MLB_ERR_FORMAT, "%s: no prompt (%d lines)", file, line);
    if (!s) s = check_names(&l, file);
    if (s) {
        mlb_prompts_free(&l);
        return s;
    }
    *out = l;
    return MLB_OK;
}

void mlb_prompts_free(mlb_prompt_list* l) {
    if (!l) return;
    free(l->items);
    free(l->text);
    memset(l, 0, sizeof *l);
}
