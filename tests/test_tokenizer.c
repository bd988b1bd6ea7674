// The CLIP BPE tokenizer: a hand-made merges file with hand-computed ids (runs everywhere), the real
// CLIP files in ../shared/data/clip (ids of the real tokenizer, every vocabulary word, both loaders),
// text cleaning, html.unescape, truncation/padding, decoding, and malformed inputs.
#include <stdint.h>
#include <zlib.h>
#include "matlaber/error.h"
#include "matlaber/fileio.h"
#include "matlaber/rng.h"
#include "matlaber/tokenizer.h"
#include "test.h"

#define HTML_ONLY MLB_TOKENIZER_UNESCAPE_HTML   // the reference pipeline without ftfy

static const char* tmp;          // this binary's scratch folder
static char path_buf[4][4096];

static const char* tpath(int slot, const char* name) {
    snprintf(path_buf[slot], sizeof path_buf[slot], "%s/%s", tmp, name);
    return path_buf[slot];
}

static int write_file(const char* path, const void* data, size_t n) {
    FILE* f = fopen(path, "wb");
    if (!f) return -1;
    size_t w = fwrite(data, 1, n, f);
    return fclose(f) == 0 && w == n ? 0 : -1;
}

static int write_gz(const char* path, const char* text) {
    gzFile f = gzopen(path, "wb9");
    if (!f) return -1;
    int n = (int)strlen(text);
    int w = gzwrite(f, text, (unsigned)n);
    return gzclose(f) == Z_OK && w == n ? 0 : -1;
}

static int read_all(const char* path, unsigned char** data, size_t* n) {
    FILE* f = fopen(path, "rb");
    if (!f) return -1;
    fseek(f, 0, SEEK_END);
    long len = ftell(f);
    fseek(f, 0, SEEK_SET);
    *data = malloc((size_t)len + 1);
    *n = fread(*data, 1, (size_t)len, f);
    fclose(f);
    return 0;
}

// Status `code` and a message containing `what` (and the file, when given).
#define CHECK_ERR(expr, code, what) do { mlb_clear_error(); mlb_status s_ = (expr); \
    CHECK_MSG(s_ == (code), "status %s, expected %s (%s)", mlb_status_name(s_), mlb_status_name(code), mlb_last_error()); \
    CHECK_MSG(strstr(mlb_last_error(), (what)) != NULL, "message '%s' lacks '%s'", mlb_last_error(), (what)); } while (0)

static int ids_equal(const int* a, size_t na, const int* b, size_t nb) {
    if (na != nb) return 0;
    for (size_t i = 0; i < na; i++)
        if (a[i] != b[i]) return 0;
    return 1;
}

static void print_ids(const char* label, const int* ids, size_t n) {
    printf("    %s:", label);
    for (size_t i = 0; i < n; i++) printf(" %d", ids[i]);
    printf("\n");
}

// tokenize(text) == expected[n]
#define CHECK_IDS(tok, text, ...) do { const int e_[] = {__VA_ARGS__}; int* g_ = NULL; size_t ng_ = 0; \
    mlb_status s_ = mlb_tokenizer_tokenize((tok), (text), &g_, &ng_); \
    CHECK_MSG(s_ == MLB_OK, "%s", mlb_last_error()); \
    int eq_ = s_ == MLB_OK && ids_equal(g_, ng_, e_, sizeof e_ / sizeof *e_); \
    CHECK_MSG(eq_, "ids of '%s' differ", (text)); \
    if (!eq_) { print_ids("got", g_, ng_); print_ids("expected", e_, sizeof e_ / sizeof *e_); } \
    free(g_); } while (0)

// ---- the byte-to-unicode table, written here from the spec (reference.md §6) -------------------

static int byte_is_printable(int b) { return (b >= '!' && b <= '~') || (b >= 0xA1 && b <= 0xAC) || (b >= 0xAE && b <= 0xFF); }

// id of byte b's single-character token: printable bytes first in byte order, then the other 68
static int byte_token_id(int b) {
    int id = 0;
    if (byte_is_printable(b)) {
        for (int x = 0; x < b; x++) id += byte_is_printable(x);
        return id;
    }
    id = 188;
    for (int x = 0; x < b; x++) id += !byte_is_printable(x);
    return id;
}

static uint32_t byte_char(int b) {
    if (byte_is_printable(b)) return (uint32_t)b;
    uint32_t k = 0;
    for (int x = 0; x < b; x++) k += !byte_is_printable(x);
    return 256 + k;
}

// A vocabulary string ("cat</w>") -> its bytes (without "</w>"); -1 when a character is not a byte char.
static int token_bytes(const char* tokstr, unsigned char* out, size_t cap, size_t* n, int* end_of_word) {
    size_t len = strlen(tokstr);
    *end_of_word = len >= 4 && strcmp(tokstr + len - 4, "</w>") == 0;
    if (*end_of_word) len -= 4;
    *n = 0;
    const unsigned char* s = (const unsigned char*)tokstr;
    for (size_t i = 0; i < len;) {
        uint32_t c;
        if (s[i] < 0x80) c = s[i++];
        else if ((s[i] & 0xE0) == 0xC0 && i + 1 < len) { c = ((uint32_t)(s[i] & 0x1F) << 6) | (s[i + 1] & 0x3F); i += 2; }
        else return -1;
        int b = -1;
        for (int x = 0; x < 256; x++)
            if (byte_char(x) == c) { b = x; break; }
        if (b < 0 || *n >= cap) return -1;
        out[(*n)++] = (unsigned char)b;
    }
    return 0;
}

static int valid_utf8(const unsigned char* s, size_t n) {
    for (size_t i = 0; i < n;) {
        unsigned b = s[i];
        int k;
        uint32_t c, min;
        if (b < 0x80) { i++; continue; }
        if (b >= 0xC2 && b <= 0xDF) { k = 1; c = b & 0x1F; min = 0x80; }
        else if (b >= 0xE0 && b <= 0xEF) { k = 2; c = b & 0x0F; min = 0x800; }
        else if (b >= 0xF0 && b <= 0xF4) { k = 3; c = b & 0x07; min = 0x10000; }
        else return 0;
        if (i + (size_t)k >= n) return 0;
        for (int j = 1; j <= k; j++) {
            if ((s[i + j] & 0xC0) != 0x80) return 0;
            c = (c << 6) | (s[i + j] & 0x3F);
        }
        if (c < min || (c >= 0xD800 && c <= 0xDFFF) || c > 0x10FFFF) return 0;
        i += (size_t)k + 1;
    }
    return 1;
}

TEST(byte_table_from_spec) {
    // sanity of the test's own table against facts: '!' is 0, 'a' is 64, byte 0 is 188 (chr 256)
    CHECK(byte_token_id('!') == 0);
    CHECK(byte_token_id('a') == 64);
    CHECK(byte_token_id(0) == 188 && byte_char(0) == 256);
    CHECK(byte_token_id(0xAD) == 255 && byte_char(0xAD) == 256 + 67);
    CHECK(byte_char(' ') == 256 + 32);   // 'Ġ'
}

// ---- a hand-made merges file ---------------------------------------------------------------------

// Ranks 0..5; ids 512.. in order; specials 518 and 519.
static const char* tiny_merges =
    "#version: 0.2\n"
    "l o\n"          // 512 "lo"
    "lo w</w>\n"     // 513 "low</w>"
    "e r</w>\n"      // 514 "er</w>"
    "n e\n"          // 515 "ne"
    "ne w</w>\n"     // 516 "new</w>"
    "l l\n";         // 517 "ll"

enum { L = 75, W = 86, Wend = 256 + 86, Lend = 256 + 75 };   // byte tokens 'l', 'w', 'w</w>', 'l</w>'

static void check_tiny(mlb_tokenizer* t) {
    CHECK(mlb_tokenizer_vocab_size(t) == 520);
    CHECK(mlb_tokenizer_n_merges(t) == 6);
    CHECK(mlb_tokenizer_bos(t) == 518 && mlb_tokenizer_eos(t) == 519);
    CHECK(strcmp(mlb_tokenizer_token(t, 516), "new</w>") == 0);
    CHECK(strcmp(mlb_tokenizer_token(t, 188), "\xc4\x80") == 0);   // byte 0 -> U+0100
    CHECK_IDS(t, "low", 513);
    CHECK_IDS(t, "lower", 512, W, 514);                 // "lo w" is not a merge, only "lo w</w>"
    CHECK_IDS(t, "newer", 515, W, 514);                 // rank 2 (right) merges before rank 3 (left)
    CHECK_IDS(t, "new", 516);
    CHECK_IDS(t, "NEW  Low", 516, 513);                 // case folding, whitespace
    CHECK_IDS(t, "lll", 517, Lend);                     // left to right: [ll, l</w>]
    CHECK_IDS(t, "llll", 517, L, Lend);                 // [ll, l, l</w>]: the pair (l, l</w>) is not a merge
    CHECK_IDS(t, "a", 256 + 64);
    CHECK_IDS(t, "12", 256 + 16, 256 + 17);             // digits one at a time
    CHECK_IDS(t, "w!?", Wend, 0, 256 + 30);             // "!?" is one punctuation piece: [!, ?</w>]
    CHECK_IDS(t, "w !? !", Wend, 0, 256 + 30, 256);
    CHECK_IDS(t, "low<|endoftext|>new", 513, 519, 516);
    int ids[8], n = 0;
    REQUIRE(mlb_tokenizer_encode(t, "new low", ids, 8, 0, &n) == MLB_OK);
    const int want[8] = {518, 516, 513, 519, 0, 0, 0, 0};
    CHECK(n == 4 && ids_equal(ids, 8, want, 8));
    REQUIRE(mlb_tokenizer_encode(t, "new low new low", ids, 4, 519, &n) == MLB_OK);
    const int cut[4] = {518, 516, 513, 519};
    CHECK(n == 4 && ids_equal(ids, 4, cut, 4));
    char* text;
    REQUIRE(mlb_tokenizer_decode(t, ids, 4, &text) == MLB_OK);
    CHECK(strcmp(text, "<|startoftext|>new low <|endoftext|>") == 0);
    free(text);
}

TEST(tiny_merges_gz) {
    const char* p = tpath(0, "tiny.txt.gz");
    REQUIRE(write_gz(p, tiny_merges) == 0);
    mlb_tokenizer* t = NULL;
    REQUIRE(mlb_tokenizer_load(p, &t) == MLB_OK);
    check_tiny(t);
    CHECK(strstr(mlb_tokenizer_source(t), "gzipped merges, 6 merges") != NULL);
    mlb_tokenizer_free(t);
}

// vocab.json for the tiny merges, built from the spec; `tamper` swaps two ids or drops one.
static char* tiny_vocab_json(int tamper) {
    size_t cap = 1 << 16, m = 0;
    char* s = malloc(cap);
    m += (size_t)snprintf(s + m, cap - m, "{");
    static const char* merged[] = {"lo", "low</w>", "er</w>", "ne", "new</w>", "ll", "<|startoftext|>", "<|endoftext|>"};
    for (int id = 0; id < 520; id++) {
        char tokstr[32];
        if (id < 512) {
            int b = -1;
            for (int x = 0; x < 256; x++)
                if (byte_token_id(x) == id % 256) b = x;
            uint32_t c = byte_char(b);
            int k = 0;
            if (c == '"' || c == '\\') { tokstr[k++] = '\\'; tokstr[k++] = (char)c; }
            else if (c < 0x80) tokstr[k++] = (char)c;
            else { tokstr[k++] = (char)(0xC0 | (c >> 6)); tokstr[k++] = (char)(0x80 | (c & 0x3F)); }
            tokstr[k] = 0;
            if (id >= 256) strcat(tokstr, "</w>");
        } else snprintf(tokstr, sizeof tokstr, "%s", merged[id - 512]);
        int value = id;
        if (tamper == 1 && id == 513) value = 514;
        if (tamper == 1 && id == 514) value = 513;
        if (tamper == 2 && id == 517) continue;
        m += (size_t)snprintf(s + m, cap - m, "%s\"%s\": %d", id ? ", " : "", tokstr, value);
    }
    snprintf(s + m, cap - m, "}");
    return s;
}

TEST(tiny_merges_folder_and_vocab_json) {
    char dir[4200];
    snprintf(dir, sizeof dir, "%s/tok_folder", tmp);
    REQUIRE(mlb_mkdir_p(dir) == MLB_OK);
    char merges[4300], vocab[4300];
    snprintf(merges, sizeof merges, "%s/merges.txt", dir);
    snprintf(vocab, sizeof vocab, "%s/vocab.json", dir);
    REQUIRE(write_file(merges, tiny_merges, strlen(tiny_merges)) == 0);
    // merges.txt alone
    mlb_tokenizer* t = NULL;
    REQUIRE(mlb_tokenizer_load(dir, &t) == MLB_OK);
    check_tiny(t);
    mlb_tokenizer_free(t);
    // with a matching vocab.json
    char* v = tiny_vocab_json(0);
    REQUIRE(write_file(vocab, v, strlen(v)) == 0);
    free(v);
    REQUIRE(mlb_tokenizer_load(dir, &t) == MLB_OK);
    check_tiny(t);
    CHECK(strstr(mlb_tokenizer_source(t), "merges.txt + vocab.json") != NULL);
    mlb_tokenizer_free(t);
    // a model folder holding tokenizer/
    char model[4300], sub[4400];
    snprintf(model, sizeof model, "%s/model", tmp);
    snprintf(sub, sizeof sub, "%s/tokenizer", model);
    REQUIRE(mlb_mkdir_p(sub) == MLB_OK);
    snprintf(merges, sizeof merges, "%s/merges.txt", sub);
    REQUIRE(write_file(merges, tiny_merges, strlen(tiny_merges)) == 0);
    REQUIRE(mlb_tokenizer_load(model, &t) == MLB_OK);
    check_tiny(t);
    mlb_tokenizer_free(t);
    // vocab.json that disagrees: two ids swapped, one token missing, not JSON
    v = tiny_vocab_json(1);
    REQUIRE(write_file(vocab, v, strlen(v)) == 0);
    free(v);
    t = (mlb_tokenizer*)1;
    CHECK_ERR(mlb_tokenizer_load(dir, &t), MLB_ERR_FORMAT, "vocab.json: token 'low</w>' has id 514 but merges.txt gives it id 513");
    CHECK(t == NULL);
    v = tiny_vocab_json(2);
    REQUIRE(write_file(vocab, v, strlen(v)) == 0);
    free(v);
    CHECK_ERR(mlb_tokenizer_load(dir, &t), MLB_ERR_FORMAT, "vocab.json has 519 tokens but the merges make 520");
    REQUIRE(write_file(vocab, "{\"a\": 1,", 8) == 0);
    CHECK_ERR(mlb_tokenizer_load(dir, &t), MLB_ERR_FORMAT, "vocab.json: not valid JSON");
    REQUIRE(write_file(vocab, "[1, 2]", 6) == 0);
    CHECK_ERR(mlb_tokenizer_load(dir, &t), MLB_ERR_FORMAT, "expected a JSON object");
}

TEST(malformed_inputs) {
    mlb_tokenizer* t = NULL;
    CHECK_ERR(mlb_tokenizer_load(tpath(0, "nope.txt.gz"), &t), MLB_ERR_NOT_FOUND, "nope.txt.gz: No such file");
    CHECK(t == NULL);
    CHECK_ERR(mlb_tokenizer_load("", &t), MLB_ERR_ARG, "empty path");
    // a folder with nothing in it, one with vocab.json only
    char dir[4200];
    snprintf(dir, sizeof dir, "%s/empty", tmp);
    REQUIRE(mlb_mkdir_p(dir) == MLB_OK);
    CHECK_ERR(mlb_tokenizer_load(dir, &t), MLB_ERR_NOT_FOUND,
              "no tokenizer found; expected the gzipped merges file bpe_simple_vocab_16e6.txt.gz, a folder with "
              "merges.txt (and vocab.json), or a model folder with tokenizer/merges.txt");
    char vj[4300];
    snprintf(vj, sizeof vj, "%s/vocab.json", dir);
    REQUIRE(write_file(vj, "{}", 2) == 0);
    CHECK_ERR(mlb_tokenizer_load(dir, &t), MLB_ERR_NOT_FOUND, "has vocab.json but no merges.txt beside it");
    // garbage named .gz, garbage with the gzip signature, a truncated gzip stream
    REQUIRE(write_file(tpath(0, "garbage.gz"), "this is not gzip data\n", 22) == 0);
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT, "garbage.gz: not gzip-compressed");
    unsigned char junk[64] = {0x1F, 0x8B, 8, 0, 0, 0, 0, 0, 0, 3};
    for (int i = 10; i < 64; i++) junk[i] = (unsigned char)(i * 37 + 11);
    REQUIRE(write_file(tpath(0, "junk.gz"), junk, sizeof junk) == 0);
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT, "junk.gz: broken gzip data");
    REQUIRE(write_gz(tpath(0, "whole.gz"), tiny_merges) == 0);
    unsigned char* gz;
    size_t ngz;
    REQUIRE(read_all(path_buf[0], &gz, &ngz) == 0);
    REQUIRE(write_file(tpath(1, "cut.gz"), gz, ngz - 6) == 0);   // loses most of the CRC/length trailer
    free(gz);
    CHECK_ERR(mlb_tokenizer_load(path_buf[1], &t), MLB_ERR_FORMAT, "cut.gz: broken gzip data");
    CHECK(strstr(mlb_last_error(), "truncated") != NULL);
    // content errors (gzipped and plain)
    REQUIRE(write_gz(tpath(0, "noheader.gz"), "l o\nlo w</w>\n") == 0);
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT, "line 1 is 'l o', not a '#version: ...' header");
    REQUIRE(write_gz(tpath(0, "three.gz"), "#version: 0.2\nl o\na b c\n") == 0);
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT, "line 3 is 'a b c', expected two symbols separated by a space");
    REQUIRE(write_gz(tpath(0, "blank.gz"), "#version: 0.2\nl o\n\nn e\n") == 0);
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT, "line 3 is '', expected two symbols");
    REQUIRE(write_gz(tpath(0, "unknown.gz"), "#version: 0.2\nl o\nlow w\n") == 0);
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT,
              "line 3: symbol 'low' is neither a byte symbol nor made by an earlier merge");
    REQUIRE(write_gz(tpath(0, "twice.gz"), "#version: 0.2\nl o\nl o\n") == 0);
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT, "line 3: token 'lo' is made twice");
    REQUIRE(write_gz(tpath(0, "empty.gz"), "#version: 0.2\n") == 0);
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT, "no merges after the header line");
    char longline[3000] = "#version: 0.2\nl o\n";
    memset(longline + strlen(longline), 'x', 2000);
    REQUIRE(write_gz(tpath(0, "long.gz"), longline) == 0);
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT, "line 3 is longer than 1024 bytes");
    REQUIRE(write_file(tpath(0, "binary.txt"), "#version\0\1\2", 11) == 0);
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT, "binary.txt: contains NUL bytes");
    CHECK(t == NULL);
}

TEST(text_cleaning) {
    char* out = NULL;
#define CLEAN(in, flags, want) do { REQUIRE(mlb_tokenizer_clean_text((in), (flags), &out) == MLB_OK); \
    CHECK_MSG(strcmp(out, (want)) == 0, "clean('%s') = '%s', expected '%s'", (in), out, (want)); free(out); } while (0)
    CLEAN("  A\tPhoto\n\n OF\r\n a   CAT  ", 0, "a photo of a cat");
    CLEAN("\x1c x \x1f", 0, "x");                                  // str.strip also removes U+001C..U+001F
    CLEAN("a\x1c" "b", 0, "a\x1c" "b");                            // ... but \s does not match them
    CLEAN("a\xc2\xa0\xe3\x80\x80" "b\xe2\x80\x83" "c", 0, "a b c");  // NBSP, ideographic, em space
    CLEAN("a\xe2\x80\x8b" "b", 0, "a\xe2\x80\x8b" "b");           // U+200B is not White_Space
    CLEAN("\xc3\x9c" "BER \xc3\x91" "O \xce\xa9", 0, "\xc3\xbc" "ber \xc3\xb1" "o \xcf\x89");   // ÜBER ÑO Ω
    CLEAN("\xc4\xb0", 0, "i\xcc\x87");                             // İ -> i + U+0307 as Python lowers it
    CLEAN("\xce\x9f\xce\x94\xce\x9f\xce\xa3 \xce\xa3", 0, "\xce\xbf\xce\xb4\xce\xbf\xcf\x82 \xcf\x83");   // ΟΔΟΣ Σ -> οδος σ
    CLEAN("\xc2\xaa\xce\xa3", 0, "\xc2\xaa\xcf\x82");              // ª is cased: final sigma
    CLEAN("&amp;amp; &amp;lt;", HTML_ONLY, "& <");                 // unescaped twice
    CLEAN("&amp;amp;amp;", HTML_ONLY, "&amp;");
    CLEAN("&amp;", 0, "&amp;");
    // the ftfy subset: curly quotes, ligatures, full-width forms, NFC
    CLEAN("\xe2\x80\x9c" "dog\xe2\x80\x99s\xe2\x80\x9d", MLB_TOKENIZER_FIX_TEXT, "\"dog's\"");
    CLEAN("\xef\xac\x81" "sh \xef\xac\x83", MLB_TOKENIZER_FIX_TEXT, "fish ffi");
    CLEAN("\xef\xbc\xa1\xef\xbc\xa2\xef\xbc\x91", MLB_TOKENIZER_FIX_TEXT, "ab1");     // ＡＢ１
    CLEAN("e\xcc\x81", MLB_TOKENIZER_FIX_TEXT, "\xc3\xa9");                          // e + U+0301 -> é
    CLEAN("e\xcc\x81", 0, "e\xcc\x81");
    CLEAN("\xe2\x80\x99", 0, "\xe2\x80\x99");
    // invalid UTF-8
    CHECK_ERR(mlb_tokenizer_clean_text("ab\xff" "cd", 0, &out), MLB_ERR_ARG, "text is not valid UTF-8: byte 0xFF at offset 2");
    CHECK_ERR(mlb_tokenizer_clean_text("ab\xe6\x9d", 0, &out), MLB_ERR_ARG, "byte 0xE6 at offset 2 starts a truncated sequence");
    CHECK_ERR(mlb_tokenizer_clean_text("\xed\xa0\x80", 0, &out), MLB_ERR_ARG, "byte 0xED at offset 0");   // a surrogate
    CHECK_ERR(mlb_tokenizer_clean_text("\xc0\xaf", 0, &out), MLB_ERR_ARG, "byte 0xC0 at offset 0");       // overlong
#undef CLEAN
}

TEST(html_unescape) {
    // expected values are Python 3.11's html.unescape
    static const char* cases[][2] = {
        {"&amp; &lt; &gt; &quot; &#39; &apos;", "& < > \" ' '"},
        {"&#65;&#x42;&#X43;&#100", "ABCd"},
        {"&amp;amp;", "&amp;"},
        {"&ampx &notit; &nbsp", "&x \xc2\xac" "it; \xc2\xa0"},
        {"&#0; &#128; &#x9F; &#xD800; &#99999999999;", "\xef\xbf\xbd \xe2\x82\xac \xc5\xb8 \xef\xbf\xbd \xef\xbf\xbd"},
        {"a&#1;b&#xFFFE;c&#x7f;d", "abcd"},
        {"& &; &#; &#x; &unknown; &AMP; &lang;", "& &; &#; &#x; &unknown; & \xe2\x9f\xa8"},
        {"&#x1F600; &eacute;t&eacute; &Eacute", "\xf0\x9f\x98\x80 \xc3\xa9t\xc3\xa9 \xc3\x89"},
        {"&abcdefghijklmnopqrstuvwxyzabcdefghij;", "&abcdefghijklmnopqrstuvwxyzabcdefghij;"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        char* out = NULL;
        REQUIRE(mlb_html_unescape(cases[i][0], &out) == MLB_OK);
        CHECK_MSG(strcmp(out, cases[i][1]) == 0, "unescape('%s') = '%s', expected '%s'", cases[i][0], out, cases[i][1]);
        free(out);
    }
}

// ---- the real CLIP files -----------------------------------------------------------------------

static int have_clip_files(void) {
    const char* data = test_shared_data();
    char p[4200];
    struct stat st;
    snprintf(p, sizeof p, "%s/clip/bpe_simple_vocab_16e6.txt.gz", data ? data : "");
    return data && stat(p, &st) == 0;
}

static mlb_tokenizer* clip_gz;
static mlb_tokenizer* clip_dir;

static int have_clip(void) { return clip_gz && clip_dir; }

static void load_clip(void) {
    const char* data = test_shared_data();
    if (!have_clip_files()) return;
    char p[4200];
    snprintf(p, sizeof p, "%s/clip/bpe_simple_vocab_16e6.txt.gz", data);
    if (mlb_tokenizer_load(p, &clip_gz) != MLB_OK) { printf("  loading %s: %s\n", p, mlb_last_error()); clip_gz = NULL; }
    snprintf(p, sizeof p, "%s/clip/tokenizer", data);
    if (mlb_tokenizer_load(p, &clip_dir) != MLB_OK) { printf("  loading %s: %s\n", p, mlb_last_error()); clip_dir = NULL; }
}

TEST(clip_loads) {
    if (!have_clip_files()) SKIP("no CLIP tokenizer files (../shared/data/clip or $MLB_SHARED_DATA/clip)");
    REQUIRE(have_clip());
    mlb_tokenizer* both[2] = {clip_gz, clip_dir};
    for (int k = 0; k < 2; k++) {
        mlb_tokenizer* t = both[k];
        CHECK(mlb_tokenizer_vocab_size(t) == MLB_CLIP_VOCAB);
        CHECK(mlb_tokenizer_n_merges(t) == MLB_CLIP_MERGES);
        CHECK(mlb_tokenizer_bos(t) == MLB_CLIP_BOS && mlb_tokenizer_eos(t) == MLB_CLIP_EOS);
        CHECK(strcmp(mlb_tokenizer_token(t, 49406), "<|startoftext|>") == 0);
        CHECK(strcmp(mlb_tokenizer_token(t, 0), "!") == 0);
        CHECK(strcmp(mlb_tokenizer_token(t, 320), "a</w>") == 0);
        CHECK(strcmp(mlb_tokenizer_token(t, 512), "in") == 0);   // the first merge, "i n"
        CHECK(strcmp(mlb_tokenizer_token(t, 49405), mlb_tokenizer_token(both[1 - k], 49405)) == 0);
        int id;
        CHECK(mlb_tokenizer_token_id(t, "golden</w>", &id) == MLB_OK && id == 3878);
        CHECK_ERR(mlb_tokenizer_token_id(t, "goblet</w>", &id), MLB_ERR_NOT_FOUND, "'goblet</w>' is not in the vocabulary");
        CHECK(id == -1);
    }
    const char* data = test_shared_data();
    char p[4200];
    snprintf(p, sizeof p, "%s/clip", data);   // the folder holding both: tokenizer/ is taken
    mlb_tokenizer* t;
    REQUIRE(mlb_tokenizer_load(p, &t) == MLB_OK);
    CHECK(strstr(mlb_tokenizer_source(t), "tokenizer (merges.txt + vocab.json, 48894 merges)") != NULL);
    mlb_tokenizer_free(t);
}

TEST(clip_known_ids) {
    if (!have_clip()) SKIP("no CLIP tokenizer files in the shared data");
    mlb_tokenizer* t = clip_gz;
    int ids[MLB_CLIP_CONTEXT], n = 0;
    REQUIRE(mlb_tokenizer_encode(t, "a photo of a cat", ids, MLB_CLIP_CONTEXT, MLB_CLIP_PAD_SD1, &n) == MLB_OK);
    const int want[7] = {49406, 320, 1125, 539, 320, 2368, 49407};
    CHECK(n == 7 && ids_equal(ids, 7, want, 7));
    int pads = 0;
    for (int i = 7; i < MLB_CLIP_CONTEXT; i++) pads += ids[i] == 49407;
    CHECK(pads == 70);
    // SD2 pads with 0
    REQUIRE(mlb_tokenizer_encode(t, "a photo of a cat", ids, MLB_CLIP_CONTEXT, MLB_CLIP_PAD_SD2, &n) == MLB_OK);
    CHECK(n == 7 && ids_equal(ids, 7, want, 7) && ids[6] == 49407);
    pads = 0;
    for (int i = 7; i < MLB_CLIP_CONTEXT; i++) pads += ids[i] == 0;
    CHECK(pads == 70);
    int pad;
    CHECK(mlb_tokenizer_pad_id("sd1", &pad) == MLB_OK && pad == 49407);
    CHECK(mlb_tokenizer_pad_id("sd2", &pad) == MLB_OK && pad == 0);
    CHECK_ERR(mlb_tokenizer_pad_id("sdxl", &pad), MLB_ERR_ARG, "unknown model 'sdxl'");
    // "golden</w>" is a whole-word token; "goblet" is not, BPE gives gob + let</w>
    int gob, let;
    REQUIRE(mlb_tokenizer_token_id(t, "gob", &gob) == MLB_OK && mlb_tokenizer_token_id(t, "let</w>", &let) == MLB_OK);
    CHECK(gob == 29559 && let == 1094);
    CHECK_IDS(t, "a golden goblet", 320, 3878, 29559, 1094);

    // The ids below are those of CLIP's own tokenizer (its Python code without ftfy) on the same text.
    mlb_tokenizer_set_flags(t, HTML_ONLY);
    CHECK_IDS(t, "2024", 273, 271, 273, 275);                       // digits one at a time
    CHECK_IDS(t, "3.14", 274, 269, 272, 275);
    CHECK_IDS(t, "hello!!! what?! ... (wow) --", 3306, 995, 768, 2835, 678, 263, 2781, 264, 2432);   // punctuation runs
    CHECK_IDS(t, "it's they're we've i'm you'll he'd don't", 585, 568, 889, 982, 649, 1200, 328, 880, 592, 1342, 797,
              1896, 847, 713);
    CHECK_IDS(t, "IT'S", 585, 568);
    CHECK_IDS(t, "rock'n'roll", 2172, 262, 333, 262, 3341);
    CHECK_IDS(t, "'dog", 1896, 8555);                               // "'d" then "og"
    CHECK_IDS(t, "caf\xc3\xa9 \xc3\xbc" "ber ni\xc3\xb1o", 15304, 6522, 1516, 697, 16574);   // café über niño
    CHECK_IDS(t, "na\xc3\xafve fa\xc3\xa7" "ade", 1097, 35689, 563, 778, 10067, 1928);       // naïve façade
    CHECK_IDS(t, "ma\xc3\xb1" "ana", 39354);
    CHECK_IDS(t, "\xc3\x9f", 127, 509);                             // ß: two byte tokens
    CHECK_IDS(t, "\xe6\x9d\xb1\xe4\xba\xac\xe3\x82\xbf\xe3\x83\xaf\xe3\x83\xbc", 48338, 21078, 105, 34941, 2429, 107, 30391);   // 東京タワー
    CHECK_IDS(t, "a \xf0\x9f\x90\xb1 and \xf0\x9f\x8e\x89", 320, 22979, 537, 3986);          // a 🐱 and 🎉
    CHECK_IDS(t, "\xd0\xbf\xd1\x80\xd0\xb8\xd0\xb2\xd0\xb5\xd1\x82 \xd0\xbc\xd0\xb8\xd1\x80", 26302, 16370, 29503, 110,
              22176, 141, 480, 38018, 16701, 141, 478);                                      // привет мир
    CHECK_IDS(t, "\xe2\x85\xab \xc2\xbd \xc2\xb2", 158, 227, 375, 33613, 41175);             // Ⅻ ½ ²: numbers, one each
    CHECK_IDS(t, "\xce\x9f\xce\x94\xce\x9f\xce\xa3", 138, 123, 138, 112, 138, 123, 139, 480);   // ΟΔΟΣ -> οδος
    CHECK_IDS(t, "\xc4\xb0", 328, 16384);                           // İ -> i + U+0307
    CHECK_IDS(t, "e\xcc\x81", 324, 136, 479);                       // e + combining acute: a separate piece
    CHECK_IDS(t, "  A\tPhoto\n\nOF   a CAT  ", 320, 1125, 539, 320, 2368);   // whitespace collapse, case folding
    CHECK_IDS(t, "\xc2\xa0nbsp\xe3\x80\x80ideographic", 6459, 4393, 1909, 78, 4245);
    CHECK_IDS(t, "&amp; &lt;3 &#39;s", 261, 283, 274, 568);
    CHECK_IDS(t, "x<|endoftext|>y", 343, 49407, 344);               // literal specials, as CLIP's pattern does
    CHECK_IDS(t, "a highly detailed 3d render of a rusty metal robot, octane render, 8k", 320, 5302, 12609, 274, 323,
              13024, 539, 320, 22646, 4044, 8797, 267, 43040, 13024, 267, 279, 330);
    // the ftfy subset (default): NFC joins e + U+0301 into é; curly apostrophe -> 's
    mlb_tokenizer_set_flags(t, MLB_TOKENIZER_FIX_TEXT | MLB_TOKENIZER_UNESCAPE_HTML);
    CHECK_IDS(t, "e\xcc\x81", 4166);                                // "Ã©</w>": é's UTF-8 bytes C3 A9
    CHECK_IDS(t, "it\xe2\x80\x99s", 585, 568);
    CHECK_IDS(t, "\xef\xac\x81sh", 2759);                           // ﬁsh -> fish
    int fish;
    CHECK(mlb_tokenizer_token_id(t, "fish</w>", &fish) == MLB_OK && fish == 2759);
    // invalid UTF-8 is an error, not a guess
    CHECK_ERR(mlb_tokenizer_encode(t, "caf\xe9", ids, MLB_CLIP_CONTEXT, 49407, &n), MLB_ERR_ARG,
              "text is not valid UTF-8: byte 0xE9 at offset 3");
}

// Every vocabulary word (token ending in "</w>") whose bytes are UTF-8 and which cleaning leaves as
// it is must encode to exactly its own id: this checks the byte table, the vocabulary, the merge
// ranks and the merge loop end to end, 34,300 times.
TEST(clip_every_vocab_word) {
    if (!have_clip()) SKIP("no CLIP tokenizer files in the shared data");
    mlb_tokenizer* t = clip_gz;
    mlb_tokenizer_set_flags(t, HTML_ONLY);
    int exact = 0, not_utf8 = 0, changed = 0, wrong = 0, has_nul = 0;
    for (int id = 256; id < MLB_CLIP_BOS; id++) {
        unsigned char word[512];
        size_t n;
        int eow;
        const char* tokstr = mlb_tokenizer_token(t, id);
        REQUIRE(token_bytes(tokstr, word, sizeof word - 1, &n, &eow) == 0);
        if (!eow) continue;
        word[n] = 0;
        if (!valid_utf8(word, n)) { not_utf8++; continue; }
        if (memchr(word, 0, n)) { has_nul++; continue; }   // "\0" (id 444) cannot be a C string
        char* clean;
        REQUIRE(mlb_tokenizer_clean_text((const char*)word, HTML_ONLY, &clean) == MLB_OK);
        int same = strcmp(clean, (const char*)word) == 0;
        free(clean);
        if (!same) { changed++; continue; }
        int* ids;
        size_t m;
        REQUIRE(mlb_tokenizer_tokenize(t, (const char*)word, &ids, &m) == MLB_OK);
        if (m == 1 && ids[0] == id) exact++;
        else if (wrong++ < 5) { printf("  '%s' (id %d):", tokstr, id); print_ids("got", ids, m); }
        free(ids);
    }
    printf("  %d vocabulary words encode to their own id; %d are not UTF-8, %d change under cleaning, %d wrong\n",
           exact, not_utf8, changed, wrong);
    CHECK(wrong == 0);
    // the counts CLIP's own Python tokenizer gives: every eligible word round-trips (34,301 there,
    // with "\0"); the 36 that cleaning changes are A..Z and ten whitespace/separator bytes
    CHECK(exact == 34300 && has_nul == 1);
    CHECK(not_utf8 == 146);
    CHECK(changed == 36);
    mlb_tokenizer_set_flags(t, MLB_TOKENIZER_FIX_TEXT | MLB_TOKENIZER_UNESCAPE_HTML);
}

// Random sentences of vocabulary words (counter RNG): the ids are the words' ids in order; both
// loaders agree; thread-parallel encoding agrees with serial.
TEST(clip_sentences_both_loaders) {
    if (!have_clip()) SKIP("no CLIP tokenizer files in the shared data");
    mlb_tokenizer_set_flags(clip_gz, HTML_ONLY);
    mlb_tokenizer_set_flags(clip_dir, HTML_ONLY);
    // plain lower-case ASCII words: the same under every cleaning flag
    int* words = malloc(MLB_CLIP_VOCAB * sizeof *words);
    int nw = 0;
    for (int id = 256 + 26; id < MLB_CLIP_BOS; id++) {
        const char* s = mlb_tokenizer_token(clip_gz, id);
        size_t len = strlen(s);
        if (len < 5 || strcmp(s + len - 4, "</w>") != 0) continue;
        int ok = 1;
        for (size_t i = 0; i + 4 < len; i++) ok &= (s[i] >= 'a' && s[i] <= 'z') || s[i] == '!' || s[i] == '.';
        if (ok) words[nw++] = id;
    }
    printf("  %d ASCII vocabulary words\n", nw);
    REQUIRE(nw > 20000);
    enum { N_SENT = 300 };
    static char text[N_SENT][4096];
    static int want[N_SENT][64];
    static int nwant[N_SENT];
    for (int k = 0; k < N_SENT; k++) {
        int len = 1 + (int)mlb_rng_below(7, 1, (uint64_t)k, 40);
        size_t used = 0;
        for (int j = 0; j < len; j++) {
            int id = words[mlb_rng_below(7, 2, (uint64_t)k * 64 + (uint64_t)j, (uint32_t)nw)];
            const char* s = mlb_tokenizer_token(clip_gz, id);
            size_t wl = strlen(s) - 4;
            // words of letters only run together when joined; separate them
            used += (size_t)snprintf(text[k] + used, sizeof text[k] - used, "%s%.*s", j ? "  " : "", (int)wl, s);
            want[k][j] = id;
        }
        nwant[k] = len;
    }
    int bad = 0, disagree = 0;
    for (int k = 0; k < N_SENT; k++) {
        int *a, *b;
        size_t na, nb;
        REQUIRE(mlb_tokenizer_tokenize(clip_gz, text[k], &a, &na) == MLB_OK);
        REQUIRE(mlb_tokenizer_tokenize(clip_dir, text[k], &b, &nb) == MLB_OK);
        if (!ids_equal(a, na, want[k], (size_t)nwant[k]) && bad++ < 3) { printf("  '%s'\n", text[k]); print_ids("got", a, na); }
        disagree += !ids_equal(a, na, b, nb);
        free(a); free(b);
    }
    CHECK(bad == 0);
    CHECK(disagree == 0);
    // a corpus of prompts with punctuation, numbers, Unicode: gz and folder give identical sequences
    static const char* prompts[] = {
        "a photo of a cat", "A DSLR photo of a golden goblet, 4k, trending on artstation", "it's a dog's life!!!",
        "an ornate wooden chest with brass fittings; octane render", "3 apples + 2 pears = 5 fruits?",
        "caf\xc3\xa9 au lait \xe2\x98\x95 in a ceramic cup", "\xe6\x9d\xb1\xe4\xba\xac tower at night",
        "rusty   metal\trobot\n\nwith glowing eyes", "&quot;marble&quot; statue &amp; bronze base", "",
        "<|startoftext|>hello<|endoftext|>", "\xf0\x9f\x90\xb1\xf0\x9f\x90\xb6\xf0\x9f\x90\xad", "ALL CAPS PROMPT",
    };
    for (size_t k = 0; k < sizeof prompts / sizeof *prompts; k++) {
        int a[MLB_CLIP_CONTEXT], b[MLB_CLIP_CONTEXT], na, nb;
        REQUIRE(mlb_tokenizer_encode(clip_gz, prompts[k], a, MLB_CLIP_CONTEXT, 49407, &na) == MLB_OK);
        REQUIRE(mlb_tokenizer_encode(clip_dir, prompts[k], b, MLB_CLIP_CONTEXT, 49407, &nb) == MLB_OK);
        CHECK_MSG(na == nb && ids_equal(a, MLB_CLIP_CONTEXT, b, MLB_CLIP_CONTEXT), "loaders disagree on '%s'", prompts[k]);
    }
    // many threads on one tokenizer (the shared cache) give the serial answer
    int mismatches = 0;
#pragma omp parallel for reduction(+ : mismatches) schedule(dynamic)
    for (int k = 0; k < N_SENT; k++) {
        int* a;
        size_t na;
        if (mlb_tokenizer_tokenize(clip_dir, text[k], &a, &na) != MLB_OK) { mismatches++; continue; }
        mismatches += !ids_equal(a, na, want[k], (size_t)nwant[k]);
        free(a);
    }
    CHECK(mismatches == 0);
    free(words);
    mlb_tokenizer_set_flags(clip_gz, MLB_TOKENIZER_FIX_TEXT | MLB_TOKENIZER_UNESCAPE_HTML);
    mlb_tokenizer_set_flags(clip_dir, MLB_TOKENIZER_FIX_TEXT | MLB_TOKENIZER_UNESCAPE_HTML);
}

TEST(clip_truncation_and_decode) {
    if (!have_clip()) SKIP("no CLIP tokenizer files in the shared data");
    mlb_tokenizer* t = clip_gz;
    // "cat " x n: n content tokens
    char text[2000] = "";
    int ids[MLB_CLIP_CONTEXT], n;
    for (int words = 74; words <= 77; words++) {
        text[0] = 0;
        for (int i = 0; i < words; i++) strcat(text, "cat ");
        REQUIRE(mlb_tokenizer_encode(t, text, ids, MLB_CLIP_CONTEXT, 0, &n) == MLB_OK);
        int cats = 0;
        for (int i = 1; i < MLB_CLIP_CONTEXT; i++) cats += ids[i] == 2368;
        CHECK(ids[0] == 49406);
        if (words <= 75) {
            CHECK(n == words + 2 && ids[words + 1] == 49407 && cats == words);
            if (words == 74) CHECK(ids[76] == 0);
        } else {
            CHECK(n == 77 && ids[76] == 49407 && cats == 75);   // cut after 75, the end token kept
        }
    }
    int* all;
    size_t nall;
    REQUIRE(mlb_tokenizer_tokenize(t, text, &all, &nall) == MLB_OK);
    CHECK(nall == 77);
    free(all);
    // a short max_len
    REQUIRE(mlb_tokenizer_encode(t, "a photo of a cat", ids, 4, 49407, &n) == MLB_OK);
    CHECK(n == 4 && ids[0] == 49406 && ids[1] == 320 && ids[2] == 1125 && ids[3] == 49407);
    REQUIRE(mlb_tokenizer_encode(t, "a photo of a cat", ids, 2, 49407, &n) == MLB_OK);
    CHECK(n == 2 && ids[0] == 49406 && ids[1] == 49407);
    CHECK_ERR(mlb_tokenizer_encode(t, "x", ids, 1, 49407, &n), MLB_ERR_ARG, "max_len 1 leaves no room");
    CHECK_ERR(mlb_tokenizer_encode(t, "x", ids, 77, 49408, &n), MLB_ERR_ARG, "pad id 49408 is outside the vocabulary");
    // decoding
    char* s;
    REQUIRE(mlb_tokenizer_encode(t, "A photo of a CAT", ids, MLB_CLIP_CONTEXT, 49407, &n) == MLB_OK);
    REQUIRE(mlb_tokenizer_decode(t, ids, (size_t)n, &s) == MLB_OK);
    CHECK(strcmp(s, "<|startoftext|>a photo of a cat <|endoftext|>") == 0);
    free(s);
    const char* unicode = "caf\xc3\xa9 \xe6\x9d\xb1\xe4\xba\xac \xf0\x9f\x98\x80";
    REQUIRE(mlb_tokenizer_tokenize(t, unicode, &all, &nall) == MLB_OK);
    REQUIRE(mlb_tokenizer_decode(t, all, nall, &s) == MLB_OK);
    CHECK(strcmp(s, "caf\xc3\xa9 \xe6\x9d\xb1\xe4\xba\xac \xf0\x9f\x98\x80 ") == 0);
    free(s);
    // [cafÃ©</w>, æĿ±, äº, ¬</w>, ðŁĺĢ</w>]: 東京 spans three tokens; without the last, 京's first two
    // bytes are one invalid sequence -> one U+FFFD (Python's errors="replace")
    CHECK(nall == 5 && all[4] == 7334);
    REQUIRE(mlb_tokenizer_decode(t, all + 1, 2, &s) == MLB_OK);
    CHECK(strcmp(s, "\xe6\x9d\xb1\xef\xbf\xbd") == 0);
    free(s);
    free(all);
    const int pad_ids[3] = {0, 0, 256};
    REQUIRE(mlb_tokenizer_decode(t, pad_ids, 3, &s) == MLB_OK);
    CHECK(strcmp(s, "!!! ") == 0);
    free(s);
    const int bad[2] = {320, 49408};
    CHECK_ERR(mlb_tokenizer_decode(t, bad, 2, &s), MLB_ERR_ARG, "id 49408 at position 1 is outside the vocabulary");
    // one very long word goes through the heap merge and decodes back
    size_t len = 100000;
    char* big = malloc(len + 1);
    for (size_t i = 0; i < len; i++) big[i] = "photograph"[i % 10];
    big[len] = 0;
    REQUIRE(mlb_tokenizer_tokenize(t, big, &all, &nall) == MLB_OK);
    CHECK(nall > 1000 && nall < len);
    REQUIRE(mlb_tokenizer_decode(t, all, nall, &s) == MLB_OK);
    CHECK(strlen(s) == len + 1 && strncmp(s, big, len) == 0 && s[len] == ' ');
    free(s); free(all); free(big);
    big = malloc(MLB_TOKENIZER_MAX_TEXT + 2);
    memset(big, 'a', MLB_TOKENIZER_MAX_TEXT + 1);
    big[MLB_TOKENIZER_MAX_TEXT + 1] = 0;
    CHECK_ERR(mlb_tokenizer_tokenize(t, big, &all, &nall), MLB_ERR_ARG, "more than the 1048576 allowed");
    free(big);
}

// The real merges file, damaged: truncated in the middle, and one byte flipped.
TEST(clip_damaged_gz) {
    if (!have_clip_files()) SKIP("no CLIP tokenizer files in the shared data");
    char p[4200];
    snprintf(p, sizeof p, "%s/clip/bpe_simple_vocab_16e6.txt.gz", test_shared_data());
    unsigned char* gz;
    size_t n;
    if (read_all(p, &gz, &n) != 0) SKIP("no %s", p);
    mlb_tokenizer* t = NULL;
    REQUIRE(write_file(tpath(0, "clip_cut.txt.gz"), gz, 100000) == 0);
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT, "(the file is truncated)");
    REQUIRE(write_file(tpath(0, "clip_cut_late.txt.gz"), gz, n - 1000) == 0);   // after the merges used: still caught
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT, "clip_cut_late.txt.gz: broken gzip data");
    gz[n / 2] ^= 0x55;
    REQUIRE(write_file(tpath(0, "clip_flip.txt.gz"), gz, n) == 0);
    CHECK_ERR(mlb_tokenizer_load(path_buf[0], &t), MLB_ERR_FORMAT, "clip_flip.txt.gz: broken gzip data");
    CHECK(t == NULL);
    free(gz);
}

int main(void) {
    tmp = test_tmpdir("tokenizer");
    if (!tmp) { printf("cannot make a scratch folder\n"); return 1; }
    RUN(byte_table_from_spec);
    RUN(tiny_merges_gz);
    RUN(tiny_merges_folder_and_vocab_json);
    RUN(malformed_inputs);
    RUN(text_cleaning);
    RUN(html_unescape);
    load_clip();
    RUN(clip_loads);
    RUN(clip_known_ids);
    RUN(clip_every_vocab_word);
    RUN(clip_sentences_both_loaders);
    RUN(clip_truncation_and_decode);
    RUN(clip_damaged_gz);
    mlb_tokenizer_free(clip_gz);
    mlb_tokenizer_free(clip_dir);
    return test_summary();
}
