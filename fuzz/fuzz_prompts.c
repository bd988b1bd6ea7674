// libFuzzer target for the prompts file of generate --prompts (prompts.h; not part of the CMake
// build). Every input goes through mlb_prompts_parse with a stand-in of generate's option table. A
// rejected input must leave a zeroed list and a message naming the file; an accepted one must keep
// the parser's promises: at least one prompt; every prompt non-empty, at most 1023 bytes, strict
// UTF-8 without control bytes but tabs, no blank at either end; option words start with -- and are
// within the limits; folder names 1..127 bytes, without '/', not starting with '.', all different;
// lines increasing. A broken promise aborts.
//
// Build and run: scripts/fuzz.sh prompts [SECONDS] (clang with libFuzzer, ASan and UBSan).
// Built with -DMLB_FUZZ_SEED the same file is a small program that writes seed files into the
// folder given as its argument.
#include "matlaber/prompts.h"
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PROMISE(cond) do { if (!(cond)) { fprintf(stderr, "broken promise: %s\n", #cond); abort(); } } while (0)

// a few of generate's options, each kind: with a value, a flag, refused
static int arity(const char* name) {
    static const char* const one[] = {"seed", "init", "guidance-scale", "preset", "env", "set", "res", NULL};
    static const char* const zero[] = {"fixed-env", "no-view-prompts", NULL};
    for (const char* const* o = one; *o; o++)
        if (!strcmp(name, *o)) return 1;
    for (const char* const* o = zero; *o; o++)
        if (!strcmp(name, *o)) return 0;
    return -1;
}

// strict UTF-8 (no overlong forms, surrogates or code points past U+10FFFF), no control byte but tab
static int clean_text(const unsigned char* s, size_t n) {
    for (size_t i = 0; i < n;) {
        unsigned c = s[i];
        if (c < 0x80) {
            if ((c < 0x20 && c != '\t') || c == 0x7F) return 0;
            i++;
            continue;
        }
        int len = c >= 0xF0 ? 4 : c >= 0xE0 ? 3 : c >= 0xC2 ? 2 : 0;
        if (!len || c > 0xF4 || i + (size_t)len > n) return 0;
        unsigned cp = c & (0x3F >> (len - 1));
        for (int k = 1; k < len; k++) {
            if ((s[i + k] & 0xC0) != 0x80) return 0;
            cp = cp << 6 | (s[i + k] & 0x3F);
        }
        if ((len == 3 && cp < 0x800) || (len == 4 && (cp < 0x10000 || cp > 0x10FFFF)) || (cp >= 0xD800 && cp <= 0xDFFF)) return 0;
        i += (size_t)len;
    }
    return 1;
}

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    mlb_prompt_list l;
    memset(&l, 0x5a, sizeof l);
    mlb_status s = mlb_prompts_parse((const char*)data, size, "fuzz", arity, &l);
    if (s != MLB_OK) {
        PROMISE(l.items == NULL && l.n == 0 && l.text == NULL);
        PROMISE(strncmp(mlb_last_error(), "fuzz: ", 6) == 0);
        PROMISE(s == MLB_ERR_FORMAT || s == MLB_ERR_NOMEM);
        return 0;
    }
    PROMISE(l.n >= 1 && l.items && l.text);
    for (int i = 0; i < l.n; i++) {
        const mlb_prompt* p = &l.items[i];
        size_t n = strlen(p->prompt);
        PROMISE(n >= 1 && n <= MLB_PROMPTS_MAX_TEXT && clean_text((const unsigned char*)p->prompt, n));
        PROMISE(p->prompt[0] != ' ' && p->prompt[0] != '\t' && p->prompt[n - 1] != ' ' && p->prompt[n - 1] != '\t');
        PROMISE(strncmp(p->prompt, "--", 2) != 0);   // (a '#' after options is prompt text)
        // the prompt lies inside the list's own copy of the text
        PROMISE(p->prompt >= l.text && p->prompt + n <= l.text + size);
        PROMISE(p->n_opts >= 0 && p->n_opts <= MLB_PROMPTS_MAX_OPTS);
        for (int k = 0; k < p->n_opts; k++) {
            PROMISE(p->opts[k] && strlen(p->opts[k]) >= 1 && strlen(p->opts[k]) <= 2 + 64 + MLB_PROMPTS_MAX_TEXT);
            PROMISE(clean_text((const unsigned char*)p->opts[k], strlen(p->opts[k])));
        }
        if (p->n_opts) PROMISE(strncmp(p->opts[0], "--", 2) == 0);
        size_t nl = strlen(p->name);
        PROMISE(nl >= 1 && nl <= MLB_PROMPTS_MAX_NAME && !strchr(p->name, '/') && p->name[0] != '.');
        PROMISE(i == 0 || p->line > l.items[i - 1].line);
        for (int j = 0; j < i && j < 64; j++) PROMISE(strcmp(p->name, l.items[j].name) != 0);   // (the parser sorts all)
    }
    mlb_prompts_free(&l);
    PROMISE(l.items == NULL && l.text == NULL && l.n == 0);
    return 0;
}

#ifdef MLB_FUZZ_SEED
static int put(const char* dir, const char* name, const char* text, size_t n) {
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE* f = fopen(path, "wb");
    if (!f) { perror(path); return 0; }
    fwrite(text, 1, n, f);
    return fclose(f) == 0;
}
#define PUT(d, name, lit) put(d, name, lit, sizeof lit - 1)

int main(int argc, char** argv) {
    if (argc != 2) { fprintf(stderr, "usage: %s CORPUS_DIR\n", argv[0]); return 2; }
    const char* d = argv[1];
    int ok = 1;
    ok &= PUT(d, "seed_plain.txt", "a gold goblet\na red mug\n");
    ok &= PUT(d, "seed_options.txt", "# a comment, then a blank line\n\n--name a a gold goblet\n--name b --seed 1 a red mug\n"
                                     "--name c --guidance-scale 30 a blue vase\n--fixed-env --init=torus a ring\n");
    ok &= PUT(d, "seed_line_ends.txt", "\xEF\xBB\xBF" "a gold goblet\r\n--seed 2 a red mug\ra blue vase\n\t  # indented\n");
    ok &= PUT(d, "seed_utf8.txt", "une coupe dor\xC3\xA9" "e\n\xE9\x87\x91\xE8\x89\xB2\xE3\x81\xAE\xE6\x9D\xAF\n\xF0\x9F\x8F\x86 trophy\n");
    ok &= PUT(d, "seed_bad.txt", "--bogus 1 x\n--name a/b y\n--seed\n\x01\n");
    return ok ? 0 : 1;
}
#endif
