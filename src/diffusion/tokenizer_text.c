// The text side of the CLIP tokenizer: strict UTF-8, the cleaning pipeline of CLIP's
// simple_tokenizer (a subset of ftfy.fix_text, html.unescape twice, whitespace collapse and strip,
// Python's str.lower) and the pre-tokenizer pattern
//   <\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+
// (compiled with IGNORECASE) as a hand-written scanner. Unicode categories, case mappings and
// normalisation come from utf8proc. docs/tokenizer.md lists every difference from the Python.
#include <stdlib.h>
#include <string.h>
#include <utf8proc.h>
#include "diffusion/tokenizer_internal.h"
#include "matlaber/tokenizer.h"

// ---- UTF-8 ------------------------------------------------------------------------------------

// One scalar value from s[0..n): its length (1..4), or -k where the first k bytes are the maximal
// invalid subsequence (Unicode's "maximal subpart"; Python's replace decoder emits one U+FFFD each).
static int utf8_step(const unsigned char* s, size_t n, uint32_t* out) {
    unsigned b0 = s[0];
    if (b0 < 0x80) { *out = b0; return 1; }
    int need;
    uint32_t c;
    unsigned lo = 0x80, hi = 0xBF;
    if (b0 >= 0xC2 && b0 <= 0xDF) { need = 1; c = b0 & 0x1F; }
    else if (b0 >= 0xE0 && b0 <= 0xEF) { need = 2; c = b0 & 0x0F; if (b0 == 0xE0) lo = 0xA0; if (b0 == 0xED) hi = 0x9F; }
    else if (b0 >= 0xF0 && b0 <= 0xF4) { need = 3; c = b0 & 0x07; if (b0 == 0xF0) lo = 0x90; if (b0 == 0xF4) hi = 0x8F; }
    else return -1;
    for (int k = 1; k <= need; k++) {
        if ((size_t)k >= n) return -k;
        unsigned b = s[k];
        if (b < lo || b > hi) return -k;
        lo = 0x80; hi = 0xBF;
        c = (c << 6) | (b & 0x3F);
    }
    *out = c;
    return need + 1;
}

int tok_utf8_seq_len(const unsigned char* s, size_t n) {
    uint32_t c;
    int len = n ? utf8_step(s, n, &c) : 0;
    return len > 0 ? len : 0;
}

mlb_status tok_utf8_decode(const char* s, size_t n, const char* what, uint32_t** cps, size_t* ncp) {
    *cps = NULL; *ncp = 0;
    uint32_t* out = malloc((n + 1) * sizeof *out);
    if (!out) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory (%zu bytes of text)", what, n);
    size_t m = 0;
    const unsigned char* u = (const unsigned char*)s;
    for (size_t i = 0; i < n;) {
        int len = utf8_step(u + i, n - i, &out[m]);
        if (len < 0) {
            free(out);
            return mlb_fail(MLB_ERR_ARG, "%s is not valid UTF-8: byte 0x%02X at offset %zu %s", what, u[i], i,
                            i + (size_t)(-len) >= n ? "starts a truncated sequence" : "does not start a valid sequence");
        }
        i += (size_t)len; m++;
    }
    *cps = out; *ncp = m;
    return MLB_OK;
}

int tok_utf8_put(uint32_t c, char* o) {
    if (c < 0x80) { o[0] = (char)c; return 1; }
    if (c < 0x800) { o[0] = (char)(0xC0 | (c >> 6)); o[1] = (char)(0x80 | (c & 0x3F)); return 2; }
    if (c < 0x10000) {
        o[0] = (char)(0xE0 | (c >> 12)); o[1] = (char)(0x80 | ((c >> 6) & 0x3F)); o[2] = (char)(0x80 | (c & 0x3F));
        return 3;
    }
    o[0] = (char)(0xF0 | (c >> 18)); o[1] = (char)(0x80 | ((c >> 12) & 0x3F));
    o[2] = (char)(0x80 | ((c >> 6) & 0x3F)); o[3] = (char)(0x80 | (c & 0x3F));
    return 4;
}

mlb_status tok_utf8_encode(const uint32_t* cps, size_t n, char** out, size_t* nbytes) {
    char* o = malloc(4 * n + 1);
    if (!o) return mlb_fail(MLB_ERR_NOMEM, "out of memory encoding %zu characters", n);
    size_t m = 0;
    for (size_t i = 0; i < n; i++) m += (size_t)tok_utf8_put(cps[i], o + m);
    o[m] = 0;
    *out = o;
    if (nbytes) *nbytes = m;
    return MLB_OK;
}

mlb_status tok_utf8_decode_replace(const unsigned char* s, size_t n, char** out, size_t* nout) {
    char* o = malloc(3 * n + 1);   // each bad byte -> at most one 3-byte U+FFFD
    if (!o) return mlb_fail(MLB_ERR_NOMEM, "out of memory decoding %zu bytes", n);
    size_t m = 0;
    for (size_t i = 0; i < n;) {
        uint32_t c;
        int len = utf8_step(s + i, n - i, &c);
        if (len > 0) { memcpy(o + m, s + i, (size_t)len); m += (size_t)len; i += (size_t)len; }
        else { m += (size_t)tok_utf8_put(0xFFFD, o + m); i += (size_t)(-len); }
    }
    o[m] = 0;
    *out = o;
    if (nout) *nout = m;
    return MLB_OK;
}

// A growable code point buffer for the cleaning stages.
typedef struct { uint32_t* v; size_t n, cap; int oom; } cpbuf;

static void cp_push(cpbuf* b, uint32_t c) {
    if (b->oom) return;
    if (b->n == b->cap) {
        size_t cap = b->cap ? 2 * b->cap : 64;
        uint32_t* v = realloc(b->v, cap * sizeof *v);
        if (!v) { b->oom = 1; return; }
        b->v = v; b->cap = cap;
    }
    b->v[b->n++] = c;
}

// ---- ftfy subset --------------------------------------------------------------------------------

// NFKC of one code point through utf8proc; 0 when it maps to itself.
static int nfkc_char(uint32_t c, cpbuf* out) {
    char in[5];
    in[tok_utf8_put(c, in)] = 0;
    utf8proc_uint8_t* r = utf8proc_NFKC((const utf8proc_uint8_t*)in);
    if (!r) return 0;
    int changed = strcmp((const char*)r, in) != 0;
    for (const unsigned char* p = r; changed && *p;) {
        uint32_t x;
        int len = utf8_step(p, strlen((const char*)p), &x);
        if (len <= 0) break;
        cp_push(out, x);
        p += len;
    }
    free(r);
    return changed;
}

// ftfy's fix_latin_ligatures, fix_character_width and uncurl_quotes tables (the character-level
// fixes of fix_text), then its final NFC. Mojibake repair, control-character removal and the other
// heuristics are not reproduced (docs/tokenizer.md).
static mlb_status fix_text_subset(const uint32_t* in, size_t n, cpbuf* out) {
    for (size_t i = 0; i < n; i++) {
        uint32_t c = in[i];
        switch (c) {
        case 0x0132: cp_push(out, 'I'); cp_push(out, 'J'); continue;
        case 0x0133: cp_push(out, 'i'); cp_push(out, 'j'); continue;
        case 0xFB00: cp_push(out, 'f'); cp_push(out, 'f'); continue;
        case 0xFB01: cp_push(out, 'f'); cp_push(out, 'i'); continue;
        case 0xFB02: cp_push(out, 'f'); cp_push(out, 'l'); continue;
        case 0xFB03: cp_push(out, 'f'); cp_push(out, 'f'); cp_push(out, 'i'); continue;
        case 0xFB04: cp_push(out, 'f'); cp_push(out, 'f'); cp_push(out, 'l'); continue;
        case 0xFB05: cp_push(out, 0x017F); cp_push(out, 't'); continue;
        case 0xFB06: cp_push(out, 's'); cp_push(out, 't'); continue;
        case 0x3000: cp_push(out, ' '); continue;
        }
        if (c >= 0x2018 && c <= 0x201B) { cp_push(out, '\''); continue; }
        if (c >= 0x201C && c <= 0x201F) { cp_push(out, '"'); continue; }
        if (c >= 0xFF01 && c <= 0xFFEF && nfkc_char(c, out)) continue;
        cp_push(out, c);
    }
    if (out->oom) return mlb_fail(MLB_ERR_NOMEM, "out of memory cleaning text");
    // NFC of the whole text
    if (out->n == 0) return MLB_OK;
    char* utf8;
    MLB_TRY(tok_utf8_encode(out->v, out->n, &utf8, NULL));
    utf8proc_uint8_t* nfc = utf8proc_NFC((const utf8proc_uint8_t*)utf8);
    free(utf8);
    if (!nfc) return mlb_fail(MLB_ERR_NOMEM, "out of memory normalising text (NFC)");
    uint32_t* cps;
    size_t m;
    mlb_status s = tok_utf8_decode((const char*)nfc, strlen((const char*)nfc), "NFC text", &cps, &m);
    free(nfc);
    if (s) return s;
    free(out->v);
    out->v = cps; out->n = m; out->cap = m + 1;
    return MLB_OK;
}

// ---- html.unescape ------------------------------------------------------------------------------

// Named character references, as Python's html.entities.html5 maps them: HTML 4's 252 names
// (with ';'), the 106 legacy names HTML 5 also accepts without ';' (and their ';' forms), and
// "apos;". Sorted by strcmp for bsearch.
typedef struct { const char* name; uint32_t cp; } html_entity;
static const html_entity ENTITIES[] = {
    {"AElig", 0xC6}, {"AElig;", 0xC6}, {"AMP", 0x26}, {"AMP;", 0x26}, {"Aacute", 0xC1}, {"Aacute;", 0xC1},
    {"Acirc", 0xC2}, {"Acirc;", 0xC2}, {"Agrave", 0xC0}, {"Agrave;", 0xC0}, {"Alpha;", 0x391},
    {"Aring", 0xC5}, {"Aring;", 0xC5}, {"Atilde", 0xC3}, {"Atilde;", 0xC3}, {"Auml", 0xC4}, {"Auml;", 0xC4},
    {"Beta;", 0x392}, {"COPY", 0xA9}, {"COPY;", 0xA9}, {"Ccedil", 0xC7}, {"Ccedil;", 0xC7}, {"Chi;", 0x3A7},
    {"Dagger;", 0x2021}, {"Delta;", 0x394}, {"ETH", 0xD0}, {"ETH;", 0xD0}, {"Eacute", 0xC9},
    {"Eacute;", 0xC9}, {"Ecirc", 0xCA}, {"Ecirc;", 0xCA}, {"Egrave", 0xC8}, {"Egrave;", 0xC8},
    {"Epsilon;", 0x395}, {"Eta;", 0x397}, {"Euml", 0xCB}, {"Euml;", 0xCB}, {"GT", 0x3E}, {"GT;", 0x3E},
    {"Gamma;", 0x393}, {"Iacute", 0xCD}, {"Iacute;", 0xCD}, {"Icirc", 0xCE}, {"Icirc;", 0xCE},
    {"Igrave", 0xCC}, {"Igrave;", 0xCC}, {"Iota;", 0x399}, {"Iuml", 0xCF}, {"Iuml;", 0xCF}, {"Kappa;", 0x39A},
    {"LT", 0x3C}, {"LT;", 0x3C}, {"Lambda;", 0x39B}, {"Mu;", 0x39C}, {"Ntilde", 0xD1}, {"Ntilde;", 0xD1},
    {"Nu;", 0x39D}, {"OElig;", 0x152}, {"Oacute", 0xD3}, {"Oacute;", 0xD3}, {"Ocirc", 0xD4}, {"Ocirc;", 0xD4},
    {"Ograve", 0xD2}, {"Ograve;", 0xD2}, {"Omega;", 0x3A9}, {"Omicron;", 0x39F}, {"Oslash", 0xD8},
    {"Oslash;", 0xD8}, {"Otilde", 0xD5}, {"Otilde;", 0xD5}, {"Ouml", 0xD6}, {"Ouml;", 0xD6}, {"Phi;", 0x3A6},
    {"Pi;", 0x3A0}, {"Prime;", 0x2033}, {"Psi;", 0x3A8}, {"QUOT", 0x22}, {"QUOT;", 0x22}, {"REG", 0xAE},
    {"REG;", 0xAE}, {"Rho;", 0x3A1}, {"Scaron;", 0x160}, {"Sigma;", 0x3A3}, {"THORN", 0xDE}, {"THORN;", 0xDE},
    {"Tau;", 0x3A4}, {"Theta;", 0x398}, {"Uacute", 0xDA}, {"Uacute;", 0xDA}, {"Ucirc", 0xDB},
    {"Ucirc;", 0xDB}, {"Ugrave", 0xD9}, {"Ugrave;", 0xD9}, {"Upsilon;", 0x3A5}, {"Uuml", 0xDC},
    {"Uuml;", 0xDC}, {"Xi;", 0x39E}, {"Yacute", 0xDD}, {"Yacute;", 0xDD}, {"Yuml;", 0x178}, {"Zeta;", 0x396},
    {"aacute", 0xE1}, {"aacute;", 0xE1}, {"acirc", 0xE2}, {"acirc;", 0xE2}, {"acute", 0xB4}, {"acute;", 0xB4},
    {"aelig", 0xE6}, {"aelig;", 0xE6}, {"agrave", 0xE0}, {"agrave;", 0xE0}, {"alefsym;", 0x2135},
    {"alpha;", 0x3B1}, {"amp", 0x26}, {"amp;", 0x26}, {"and;", 0x2227}, {"ang;", 0x2220}, {"apos;", 0x27},
    {"aring", 0xE5}, {"aring;", 0xE5}, {"asymp;", 0x2248}, {"atilde", 0xE3}, {"atilde;", 0xE3},
    {"auml", 0xE4}, {"auml;", 0xE4}, {"bdquo;", 0x201E}, {"beta;", 0x3B2}, {"brvbar", 0xA6},
    {"brvbar;", 0xA6}, {"bull;", 0x2022}, {"cap;", 0x2229}, {"ccedil", 0xE7}, {"ccedil;", 0xE7},
    {"cedil", 0xB8}, {"cedil;", 0xB8}, {"cent", 0xA2}, {"cent;", 0xA2}, {"chi;", 0x3C7}, {"circ;", 0x2C6},
    {"clubs;", 0x2663}, {"cong;", 0x2245}, {"copy", 0xA9}, {"copy;", 0xA9}, {"crarr;", 0x21B5},
    {"cup;", 0x222A}, {"curren", 0xA4}, {"curren;", 0xA4}, {"dArr;", 0x21D3}, {"dagger;", 0x2020},
    {"darr;", 0x2193}, {"deg", 0xB0}, {"deg;", 0xB0}, {"delta;", 0x3B4}, {"diams;", 0x2666}, {"divide", 0xF7},
    {"divide;", 0xF7}, {"eacute", 0xE9}, {"eacute;", 0xE9}, {"ecirc", 0xEA}, {"ecirc;", 0xEA},
    {"egrave", 0xE8}, {"egrave;", 0xE8}, {"empty;", 0x2205}, {"emsp;", 0x2003}, {"ensp;", 0x2002},
    {"epsilon;", 0x3B5}, {"equiv;", 0x2261}, {"eta;", 0x3B7}, {"eth", 0xF0}, {"eth;", 0xF0}, {"euml", 0xEB},
    {"euml;", 0xEB}, {"euro;", 0x20AC}, {"exist;", 0x2203}, {"fnof;", 0x192}, {"forall;", 0x2200},
    {"frac12", 0xBD}, {"frac12;", 0xBD}, {"frac14", 0xBC}, {"frac14;", 0xBC}, {"frac34", 0xBE},
    {"frac34;", 0xBE}, {"frasl;", 0x2044}, {"gamma;", 0x3B3}, {"ge;", 0x2265}, {"gt", 0x3E}, {"gt;", 0x3E},
    {"hArr;", 0x21D4}, {"harr;", 0x2194}, {"hearts;", 0x2665}, {"hellip;", 0x2026}, {"iacute", 0xED},
    {"iacute;", 0xED}, {"icirc", 0xEE}, {"icirc;", 0xEE}, {"iexcl", 0xA1}, {"iexcl;", 0xA1}, {"igrave", 0xEC},
    {"igrave;", 0xEC}, {"image;", 0x2111}, {"infin;", 0x221E}, {"int;", 0x222B}, {"iota;", 0x3B9},
    {"iquest", 0xBF}, {"iquest;", 0xBF}, {"isin;", 0x2208}, {"iuml", 0xEF}, {"iuml;", 0xEF},
    {"kappa;", 0x3BA}, {"lArr;", 0x21D0}, {"lambda;", 0x3BB}, {"lang;", 0x27E8}, {"laquo", 0xAB},
    {"laquo;", 0xAB}, {"larr;", 0x2190}, {"lceil;", 0x2308}, {"ldquo;", 0x201C}, {"le;", 0x2264},
    {"lfloor;", 0x230A}, {"lowast;", 0x2217}, {"loz;", 0x25CA}, {"lrm;", 0x200E}, {"lsaquo;", 0x2039},
    {"lsquo;", 0x2018}, {"lt", 0x3C}, {"lt;", 0x3C}, {"macr", 0xAF}, {"macr;", 0xAF}, {"mdash;", 0x2014},
    {"micro", 0xB5}, {"micro;", 0xB5}, {"middot", 0xB7}, {"middot;", 0xB7}, {"minus;", 0x2212},
    {"mu;", 0x3BC}, {"nabla;", 0x2207}, {"nbsp", 0xA0}, {"nbsp;", 0xA0}, {"ndash;", 0x2013}, {"ne;", 0x2260},
    {"ni;", 0x220B}, {"not", 0xAC}, {"not;", 0xAC}, {"notin;", 0x2209}, {"nsub;", 0x2284}, {"ntilde", 0xF1},
    {"ntilde;", 0xF1}, {"nu;", 0x3BD}, {"oacute", 0xF3}, {"oacute;", 0xF3}, {"ocirc", 0xF4}, {"ocirc;", 0xF4},
    {"oelig;", 0x153}, {"ograve", 0xF2}, {"ograve;", 0xF2}, {"oline;", 0x203E}, {"omega;", 0x3C9},
    {"omicron;", 0x3BF}, {"oplus;", 0x2295}, {"or;", 0x2228}, {"ordf", 0xAA}, {"ordf;", 0xAA}, {"ordm", 0xBA},
    {"ordm;", 0xBA}, {"oslash", 0xF8}, {"oslash;", 0xF8}, {"otilde", 0xF5}, {"otilde;", 0xF5},
    {"otimes;", 0x2297}, {"ouml", 0xF6}, {"ouml;", 0xF6}, {"para", 0xB6}, {"para;", 0xB6}, {"part;", 0x2202},
    {"permil;", 0x2030}, {"perp;", 0x22A5}, {"phi;", 0x3C6}, {"pi;", 0x3C0}, {"piv;", 0x3D6},
    {"plusmn", 0xB1}, {"plusmn;", 0xB1}, {"pound", 0xA3}, {"pound;", 0xA3}, {"prime;", 0x2032},
    {"prod;", 0x220F}, {"prop;", 0x221D}, {"psi;", 0x3C8}, {"quot", 0x22}, {"quot;", 0x22}, {"rArr;", 0x21D2},
    {"radic;", 0x221A}, {"rang;", 0x27E9}, {"raquo", 0xBB}, {"raquo;", 0xBB}, {"rarr;", 0x2192},
    {"rceil;", 0x2309}, {"rdquo;", 0x201D}, {"real;", 0x211C}, {"reg", 0xAE}, {"reg;", 0xAE},
    {"rfloor;", 0x230B}, {"rho;", 0x3C1}, {"rlm;", 0x200F}, {"rsaquo;", 0x203A}, {"rsquo;", 0x2019},
    {"sbquo;", 0x201A}, {"scaron;", 0x161}, {"sdot;", 0x22C5}, {"sect", 0xA7}, {"sect;", 0xA7}, {"shy", 0xAD},
    {"shy;", 0xAD}, {"sigma;", 0x3C3}, {"sigmaf;", 0x3C2}, {"sim;", 0x223C}, {"spades;", 0x2660},
    {"sub;", 0x2282}, {"sube;", 0x2286}, {"sum;", 0x2211}, {"sup1", 0xB9}, {"sup1;", 0xB9}, {"sup2", 0xB2},
    {"sup2;", 0xB2}, {"sup3", 0xB3}, {"sup3;", 0xB3}, {"sup;", 0x2283}, {"supe;", 0x2287}, {"szlig", 0xDF},
    {"szlig;", 0xDF}, {"tau;", 0x3C4}, {"there4;", 0x2234}, {"theta;", 0x3B8}, {"thetasym;", 0x3D1},
    {"thinsp;", 0x2009}, {"thorn", 0xFE}, {"thorn;", 0xFE}, {"tilde;", 0x2DC}, {"times", 0xD7},
    {"times;", 0xD7}, {"trade;", 0x2122}, {"uArr;", 0x21D1}, {"uacute", 0xFA}, {"uacute;", 0xFA},
    {"uarr;", 0x2191}, {"ucirc", 0xFB}, {"ucirc;", 0xFB}, {"ugrave", 0xF9}, {"ugrave;", 0xF9}, {"uml", 0xA8},
    {"uml;", 0xA8}, {"upsih;", 0x3D2}, {"upsilon;", 0x3C5}, {"uuml", 0xFC}, {"uuml;", 0xFC},
    {"weierp;", 0x2118}, {"xi;", 0x3BE}, {"yacute", 0xFD}, {"yacute;", 0xFD}, {"yen", 0xA5}, {"yen;", 0xA5},
    {"yuml", 0xFF}, {"yuml;", 0xFF}, {"zeta;", 0x3B6}, {"zwj;", 0x200D}, {"zwnj;", 0x200C},
};

static int entity_cmp(const void* key, const void* elem) {
    return strcmp((const char*)key, ((const html_entity*)elem)->name);
}

// Looks up the name s[0..len) (code points); 1 and *cp when known.
static int entity_lookup(const uint32_t* s, size_t len, uint32_t* cp) {
    char name[40];
    if (len >= sizeof name) return 0;
    for (size_t i = 0; i < len; i++) {
        if (s[i] >= 0x80) return 0;
        name[i] = (char)s[i];
    }
    name[len] = 0;
    const html_entity* e = bsearch(name, ENTITIES, sizeof ENTITIES / sizeof *ENTITIES, sizeof *ENTITIES, entity_cmp);
    if (!e) return 0;
    *cp = e->cp;
    return 1;
}

// Python's html._invalid_charrefs for 0x80..0x9F (Windows-1252 where defined).
static const uint16_t CP1252_C1[32] = {
    0x20AC, 0x81, 0x201A, 0x0192, 0x201E, 0x2026, 0x2020, 0x2021, 0x02C6, 0x2030, 0x0160, 0x2039, 0x0152, 0x8D, 0x017D, 0x8F,
    0x90, 0x2018, 0x2019, 0x201C, 0x201D, 0x2022, 0x2013, 0x2014, 0x02DC, 0x2122, 0x0161, 0x203A, 0x0153, 0x9D, 0x017E, 0x0178};

// A numeric reference's value (saturated at 0x110000) -> what Python's html.unescape emits.
static void numeric_entity(uint32_t v, cpbuf* out) {
    if (v == 0) { cp_push(out, 0xFFFD); return; }
    if (v == 0x0D) { cp_push(out, 0x0D); return; }
    if (v >= 0x80 && v <= 0x9F) { cp_push(out, CP1252_C1[v - 0x80]); return; }
    if ((v >= 0xD800 && v <= 0xDFFF) || v > 0x10FFFF) { cp_push(out, 0xFFFD); return; }
    if ((v >= 0x01 && v <= 0x08) || v == 0x0B || (v >= 0x0E && v <= 0x1F) || v == 0x7F ||
        (v >= 0xFDD0 && v <= 0xFDEF) || (v & 0xFFFE) == 0xFFFE)
        return;   // Python drops these
    cp_push(out, v);
}

static int is_digit(uint32_t c) { return c >= '0' && c <= '9'; }
static int hex_value(uint32_t c) {
    if (c >= '0' && c <= '9') return (int)(c - '0');
    if (c >= 'a' && c <= 'f') return (int)(c - 'a' + 10);
    if (c >= 'A' && c <= 'F') return (int)(c - 'A' + 10);
    return -1;
}

// re.sub(r'&(#[0-9]+;?|#[xX][0-9a-fA-F]+;?|[^\t\n\f <&#;]{1,32};?)', replace_charref, s)
static void html_unescape_cps(const uint32_t* s, size_t n, cpbuf* out) {
    for (size_t i = 0; i < n;) {
        if (s[i] != '&') { cp_push(out, s[i++]); continue; }
        size_t j = i + 1;
        if (j < n && s[j] == '#') {
            int hex = j + 1 < n && (s[j + 1] == 'x' || s[j + 1] == 'X');
            size_t k = j + 1 + (size_t)hex;
            if (k >= n || (hex ? hex_value(s[k]) < 0 : !is_digit(s[k]))) { cp_push(out, s[i++]); continue; }
            uint32_t v = 0;
            for (; k < n && (hex ? hex_value(s[k]) >= 0 : is_digit(s[k])); k++) {
                uint32_t d = hex ? (uint32_t)hex_value(s[k]) : s[k] - '0';
                v = v > 0x10FFFF ? 0x110000 : v * (hex ? 16u : 10u) + d;
            }
            if (v > 0x10FFFF) v = 0x110000;
            if (k < n && s[k] == ';') k++;
            numeric_entity(v, out);
            i = k;
            continue;
        }
        size_t k = j;
        while (k < n && k - j < 32 && s[k] != '\t' && s[k] != '\n' && s[k] != '\f' && s[k] != ' ' && s[k] != '<' &&
               s[k] != '&' && s[k] != '#' && s[k] != ';')
            k++;
        if (k == j) { cp_push(out, s[i++]); continue; }
        if (k < n && s[k] == ';') k++;
        size_t len = k - j;
        uint32_t cp;
        if (entity_lookup(s + j, len, &cp)) cp_push(out, cp);
        else {
            size_t x = len - 1;
            for (; x >= 2; x--)
                if (entity_lookup(s + j, x, &cp)) break;
            if (x >= 2) {
                cp_push(out, cp);
                for (size_t t = j + x; t < k; t++) cp_push(out, s[t]);
            } else {
                for (size_t t = i; t < k; t++) cp_push(out, s[t]);
            }
        }
        i = k;
    }
}

mlb_status mlb_html_unescape(const char* text, char** out) {
    *out = NULL;
    if (!text) return mlb_fail(MLB_ERR_ARG, "html unescape: text is NULL");
    uint32_t* cps;
    size_t n;
    MLB_TRY(tok_utf8_decode(text, strlen(text), "text", &cps, &n));
    cpbuf b = {0};
    html_unescape_cps(cps, n, &b);
    free(cps);
    if (b.oom) { free(b.v); return mlb_fail(MLB_ERR_NOMEM, "html unescape: out of memory"); }
    mlb_status s = tok_utf8_encode(b.v, b.n, out, NULL);
    free(b.v);
    return s;
}

// ---- whitespace and case -------------------------------------------------------------------------

// \s of the `regex` module: the Unicode White_Space property.
static int is_white_space(uint32_t c) {
    return (c >= 0x09 && c <= 0x0D) || c == 0x20 || c == 0x85 || c == 0xA0 || c == 0x1680 || (c >= 0x2000 && c <= 0x200A) ||
           c == 0x2028 || c == 0x2029 || c == 0x202F || c == 0x205F || c == 0x3000;
}
// Python's str.isspace (what str.strip removes): White_Space plus the separators U+001C..U+001F.
static int is_py_space(uint32_t c) { return is_white_space(c) || (c >= 0x1C && c <= 0x1F); }

static void strip(cpbuf* b) {
    size_t a = 0, e = b->n;
    while (a < e && is_py_space(b->v[a])) a++;
    while (e > a && is_py_space(b->v[e - 1])) e--;
    if (a > 0) memmove(b->v, b->v + a, (e - a) * sizeof *b->v);
    b->n = e - a;
}

// re.sub(r'\s+', ' ', text) in place.
static void collapse_space(cpbuf* b) {
    size_t m = 0;
    for (size_t i = 0; i < b->n;) {
        if (is_white_space(b->v[i])) {
            while (i < b->n && is_white_space(b->v[i])) i++;
            b->v[m++] = ' ';
        } else b->v[m++] = b->v[i++];
    }
    b->n = m;
}

// Unicode "Cased" (Lowercase, Uppercase or Lt) from utf8proc: a cased category or a case mapping,
// plus the Other_Lowercase/Other_Uppercase characters that have neither and are not case-ignorable
// (ª º and the squared / negative circled / negative squared capitals). Checked against CPython for
// every code point (docs/tokenizer.md).
static int is_cased(uint32_t c) {
    if (c == 0xAA || c == 0xBA || (c >= 0x1F130 && c <= 0x1F149) || (c >= 0x1F150 && c <= 0x1F169) ||
        (c >= 0x1F170 && c <= 0x1F189))
        return 1;
    utf8proc_category_t k = utf8proc_category((utf8proc_int32_t)c);
    if (k == UTF8PROC_CATEGORY_LU || k == UTF8PROC_CATEGORY_LL || k == UTF8PROC_CATEGORY_LT) return 1;
    utf8proc_int32_t x = (utf8proc_int32_t)c;
    return utf8proc_tolower(x) != x || utf8proc_toupper(x) != x || utf8proc_totitle(x) != x;
}

// Unicode "Case_Ignorable": Mn, Me, Cf, Lm, Sk, and Word_Break MidLetter / MidNumLet / Single_Quote.
static int is_case_ignorable(uint32_t c) {
    switch (utf8proc_category((utf8proc_int32_t)c)) {
    case UTF8PROC_CATEGORY_MN: case UTF8PROC_CATEGORY_ME: case UTF8PROC_CATEGORY_CF:
    case UTF8PROC_CATEGORY_LM: case UTF8PROC_CATEGORY_SK: return 1;
    default: break;
    }
    switch (c) {
    case 0x27: case 0x2E: case 0x3A: case 0xB7: case 0x387: case 0x55F: case 0x5F4: case 0x2018: case 0x2019:
    case 0x2024: case 0x2027: case 0xFE13: case 0xFE52: case 0xFE55: case 0xFF07: case 0xFF0E: case 0xFF1A: return 1;
    default: return 0;
    }
}

// Python's str.lower(): utf8proc's simple lower-case mapping plus the two full mappings Python
// applies: U+0130 -> "i" U+0307, and capital sigma -> final sigma at the end of a word.
static void py_lower(const uint32_t* s, size_t n, cpbuf* out) {
    for (size_t i = 0; i < n; i++) {
        uint32_t c = s[i];
        if (c == 0x130) { cp_push(out, 'i'); cp_push(out, 0x307); continue; }
        if (c == 0x3A3) {
            size_t j = i;
            while (j > 0 && is_case_ignorable(s[j - 1])) j--;
            int final = j > 0 && is_cased(s[j - 1]);
            if (final) {
                size_t k = i + 1;
                while (k < n && is_case_ignorable(s[k])) k++;
                final = k == n || !is_cased(s[k]);
            }
            cp_push(out, final ? 0x3C2 : 0x3C3);
            continue;
        }
        cp_push(out, (uint32_t)utf8proc_tolower((utf8proc_int32_t)c));
    }
}

mlb_status tok_clean(const char* text, unsigned flags, uint32_t** cps_out, size_t* n_out) {
    *cps_out = NULL; *n_out = 0;
    if (!text) return mlb_fail(MLB_ERR_ARG, "tokenizer: text is NULL");
    size_t nbytes = strlen(text);
    if (nbytes > MLB_TOKENIZER_MAX_TEXT)
        return mlb_fail(MLB_ERR_ARG, "text is %zu bytes, more than the %d allowed", nbytes, MLB_TOKENIZER_MAX_TEXT);
    uint32_t* cps;
    size_t n;
    MLB_TRY(tok_utf8_decode(text, nbytes, "text", &cps, &n));
    cpbuf a = {0}, b = {0};
    mlb_status s = MLB_OK;
    if (flags & MLB_TOKENIZER_FIX_TEXT) {
        s = fix_text_subset(cps, n, &a);
        free(cps);
    } else {
        a.v = cps; a.n = n; a.cap = n + 1;
    }
    if (!s && (flags & MLB_TOKENIZER_UNESCAPE_HTML)) {
        for (int pass = 0; pass < 2; pass++) {   // CLIP: html.unescape(html.unescape(text))
            b.n = 0;
            html_unescape_cps(a.v, a.n, &b);
            cpbuf t = a; a = b; b = t;
        }
    }
    if (!s && !a.oom && !b.oom) {
        strip(&a);             // basic_clean's strip
        collapse_space(&a);    // whitespace_clean
        strip(&a);
        b.n = 0;
        py_lower(a.v, a.n, &b);
    }
    if (!s && (a.oom || b.oom)) s = mlb_fail(MLB_ERR_NOMEM, "out of memory cleaning text");
    free(a.v);
    if (s) { free(b.v); return s; }
    *cps_out = b.v ? b.v : malloc(sizeof(uint32_t));
    *n_out = b.n;
    if (!*cps_out) return mlb_fail(MLB_ERR_NOMEM, "out of memory cleaning text");
    return MLB_OK;
}

mlb_status mlb_tokenizer_clean_text(const char* text, unsigned flags, char** out) {
    *out = NULL;
    uint32_t* cps;
    size_t n;
    MLB_TRY(tok_clean(text, flags, &cps, &n));
    mlb_status s = tok_utf8_encode(cps, n, out, NULL);
    free(cps);
    return s;
}

// ---- pre-tokenizer ---------------------------------------------------------------------------------

enum { CLS_SPACE, CLS_LETTER, CLS_NUMBER, CLS_OTHER };

static int char_class(uint32_t c) {
    // U+0345 (Mn) case-folds to a letter: with IGNORECASE it is in neither [\p{L}] nor
    // [^\s\p{L}\p{N}], so the pattern skips it like a space.
    if (is_white_space(c) || c == 0x345) return CLS_SPACE;
    switch (utf8proc_category((utf8proc_int32_t)c)) {
    case UTF8PROC_CATEGORY_LU: case UTF8PROC_CATEGORY_LL: case UTF8PROC_CATEGORY_LT:
    case UTF8PROC_CATEGORY_LM: case UTF8PROC_CATEGORY_LO: return CLS_LETTER;
    case UTF8PROC_CATEGORY_ND: case UTF8PROC_CATEGORY_NL: case UTF8PROC_CATEGORY_NO: return CLS_NUMBER;
    default: return CLS_OTHER;
    }
}

// Does the literal (ASCII, lower case) match at s[i..] under IGNORECASE? After lower-casing, the
// only other character that case-folds to one of these letters is U+017F (long s) for 's'.
static size_t match_literal(const uint32_t* s, size_t n, size_t i, const char* lit) {
    size_t k = 0;
    for (; lit[k]; k++) {
        if (i + k >= n) return 0;
        uint32_t c = s[i + k];
        if (c == 0x17F) c = 's';
        if (c != (uint32_t)(unsigned char)lit[k]) return 0;
    }
    return k;
}

int tok_next_piece(const uint32_t* s, size_t n, size_t* pos, size_t* start, size_t* end, int* special) {
    static const char* contractions[] = {"'s", "'t", "'re", "'ve", "'m", "'ll", "'d"};
    size_t i = *pos;
    while (i < n) {
        uint32_t c = s[i];
        *special = 0;
        size_t len = 0;
        if (c == '<') {
            if ((len = match_literal(s, n, i, "<|startoftext|>"))) *special = 1;
            else if ((len = match_literal(s, n, i, "<|endoftext|>"))) *special = 2;
            // the literal with U+017F matched by IGNORECASE is an ordinary piece
            if (len && *special == 1 && s[i + 2] != 's') *special = 0;
        } else if (c == '\'') {
            for (int k = 0; k < 7 && !len; k++) len = match_literal(s, n, i, contractions[k]);
        }
        if (!len) {
            int cls = char_class(c);
            if (cls == CLS_SPACE) { i++; continue; }
            if (cls == CLS_NUMBER) len = 1;
            else {
                len = 1;
                while (i + len < n && char_class(s[i + len]) == cls) len++;
            }
        }
        *start = i; *end = i + len; *pos = i + len;
        return 1;
    }
    *pos = n;
    return 0;
}
