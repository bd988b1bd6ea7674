// A free prompt read into the catalogue's caption for the project's own models (caption.h,
// docs/catalogue.md "What the built-in model reads").
#include <stdio.h>
#include <string.h>
#include "matlaber/caption.h"
#include "matlaber/catalogue.h"
#include "matlaber/sds.h"

typedef enum { FILLER, CLASS, MATERIAL, VIEW, NORMAL_MAP } kind;
// words: lower-case, separated by one space; name: the catalogue's class or material (VIEW: unused)
typedef struct { const char* words; kind k; const char* name; int view; } phrase;

// Only words whose meaning is the catalogue's own: "cup" (a mug? a goblet?), "pot", "grey" (stone or
// silver?), "shiny" (the white is matte) are not here, so a prompt with them is refused, not redrawn
// as something else. The first synonym of a class or material is the one the phrasings use.
static const phrase PHRASES[] = {
    // filler: dropping it loses nothing the model can draw
    {"a", FILLER, 0, 0}, {"an", FILLER, 0, 0}, {"the", FILLER, 0, 0}, {"of", FILLER, 0, 0}, {"in", FILLER, 0, 0},
    {"made of", FILLER, 0, 0}, {"made from", FILLER, 0, 0}, {"made out of", FILLER, 0, 0},
    {"coloured", FILLER, 0, 0}, {"colored", FILLER, 0, 0}, {"colour", FILLER, 0, 0}, {"color", FILLER, 0, 0},
    // materials (the catalogue's names are read besides these)
    {"golden", MATERIAL, "gold", 0}, {"gilded", MATERIAL, "gold", 0}, {"gilt", MATERIAL, "gold", 0},
    {"silvery", MATERIAL, "silver", 0}, {"coppery", MATERIAL, "copper", 0},
    {"crimson", MATERIAL, "red", 0}, {"scarlet", MATERIAL, "red", 0},
    {"cobalt", MATERIAL, "blue", 0},   // the catalogue's blue is a cobalt glaze
    {"stony", MATERIAL, "stone", 0},
    // classes
    {"chalice", CLASS, "goblet", 0}, {"flower vase", CLASS, "vase", 0}, {"coffee mug", CLASS, "mug", 0},
    {"wine bottle", CLASS, "bottle", 0}, {"toadstool", CLASS, "mushroom", 0}, {"dining table", CLASS, "table", 0},
    {"table lamp", CLASS, "lamp", 0}, {"desk lamp", CLASS, "lamp", 0}, {"tea pot", CLASS, "teapot", 0},
    // the view suffixes the model was trained with
    {"front view", VIEW, 0, MLB_SDS_VIEW_FRONT}, {"side view", VIEW, 0, MLB_SDS_VIEW_SIDE},
    {"back view", VIEW, 0, MLB_SDS_VIEW_BACK}, {"overhead view", VIEW, 0, MLB_SDS_VIEW_OVERHEAD},
    // the geometry captions' suffix (the normal renders', MLB_CAPTION_NORMAL_MAP)
    {"normal map", NORMAL_MAP, 0, 0},
};
#define N_PHRASES ((int)(sizeof PHRASES / sizeof *PHRASES))

static int class_of(const char* name) {
    for (int c = 0; name && c < mlb_catalogue_n_classes(); c++)
        if (!strcmp(name, mlb_catalogue_class_name(c))) return c;
    return -1;
}
static int material_of(const char* name) {
    for (int m = 0; name && m < mlb_catalogue_n_materials(); m++)
        if (!strcmp(name, mlb_catalogue_material_name(m))) return m;
    return -1;
}

// ASCII letters and digits, and every byte of a UTF-8 sequence (so "café" is one word, unknown);
// anything else (space, punctuation, hyphen, apostrophe) separates words.
static int word_byte(unsigned char b) { return (b >= 'a' && b <= 'z') || (b >= 'A' && b <= 'Z') || (b >= '0' && b <= '9') || b >= 0x80; }
static unsigned char lower(unsigned char b) { return b >= 'A' && b <= 'Z' ? (unsigned char)(b + 32) : b; }

#define MAX_WORDS 128
typedef struct { const char* s; int n; } word;

// 1 when w (n bytes, any case) is the text t[0..tn).
static int same(const word* w, const char* t, int tn) {
    if (w->n != tn) return 0;
    for (int i = 0; i < tn; i++)
        if (lower((unsigned char)w->s[i]) != (unsigned char)t[i]) return 0;
    return 1;
}

// Words of p matching words[at..]: their count, 0 when p does not match there.
static int match(const phrase* p, const word* words, int n, int at) {
    int k = 0;
    for (const char* t = p->words; *t; k++) {
        int tn = (int)strcspn(t, " ");
        if (at + k >= n || !same(&words[at + k], t, tn)) return 0;
        t += tn + (t[tn] == ' ');
    }
    return k;
}

// w as typed into out, cut at a character boundary with "..." when longer than out holds.
static void keep_word(const word* w, char* out) {
    int n = w->n;
    if (n >= MLB_CAPTION_WORD) {
        n = MLB_CAPTION_WORD - 4;
        while (n > 0 && ((unsigned char)w->s[n] & 0xC0) == 0x80) n--;   // not inside a UTF-8 sequence
        snprintf(out, MLB_CAPTION_WORD, "%.*s...", n, w->s);
    } else
        snprintf(out, MLB_CAPTION_WORD, "%.*s", n, w->s);
}

static void add_unknown(mlb_caption_reading* r, const word* w) {
    for (int i = 0; i < r->n_unknown; i++)   // once each, whatever its case
        if ((int)strlen(r->unknown[i]) == w->n) {
            int eq = 1;
            for (int j = 0; j < w->n && eq; j++) eq = lower((unsigned char)w->s[j]) == lower((unsigned char)r->unknown[i][j]);
            if (eq) return;
        }
    if (r->n_unknown < MLB_CAPTION_MAX_UNKNOWN) keep_word(w, r->unknown[r->n_unknown++]);
    else r->more_unknown = 1;
}

// One class or material word: the first named is kept; a different second one is noted.
static void name_one(int* first, int* second, int v) {
    if (*first < 0) *first = v;
    else if (v != *first && *second < 0) *second = v;
}

mlb_status mlb_caption_read(const char* prompt, mlb_caption_reading* r) {
    memset(r, 0, sizeof *r);
    r->cls = r->mat = r->second_cls = r->second_mat = -1;
    r->view = MLB_SDS_VIEW_NONE;
    if (!prompt) prompt = "";
    word words[MAX_WORDS];
    int n = 0;
    for (const char* s = prompt; *s;) {
        if (!word_byte((unsigned char)*s)) { s++; continue; }
        const char* e = s;
        while (*e && word_byte((unsigned char)*e)) e++;
        if (n < MAX_WORDS) words[n++] = (word){s, (int)(e - s)};
        else r->more_unknown = 1;   // a prompt this long is not a caption the model knows
        s = e;
    }
    int second_view = 0;
    for (int i = 0; i < n;) {
        int best = -1, len = 0;
        for (int p = 0; p < N_PHRASES; p++) {
            int k = match(&PHRASES[p], words, n, i);
            if (k > len) { len = k; best = p; }
        }
        if (best >= 0) {
            const phrase* p = &PHRASES[best];
            if (p->k == CLASS) name_one(&r->cls, &r->second_cls, class_of(p->name));
            else if (p->k == MATERIAL) name_one(&r->mat, &r->second_mat, material_of(p->name));
            else if (p->k == NORMAL_MAP) r->normal_map = 1;
            else if (p->k == VIEW) {
                if (r->view != MLB_SDS_VIEW_NONE && r->view != p->view) second_view = 1;
                r->view = p->view;
            }
            i += len;
            continue;
        }
        char w[MLB_CAPTION_WORD];
        keep_word(&words[i], w);
        for (char* q = w; *q; q++) *q = (char)lower((unsigned char)*q);
        int c = class_of(w), m = material_of(w);
        if (c >= 0) name_one(&r->cls, &r->second_cls, c);
        else if (m >= 0) name_one(&r->mat, &r->second_mat, m);
        else add_unknown(r, &words[i]);
        i++;
    }
    int ok = r->n_unknown == 0 && !r->more_unknown && r->cls >= 0 && r->second_cls < 0 && r->second_mat < 0 && !second_view;
    char object[64];   // "a gold goblet" or "a goblet", then the normal map's and the view's suffixes
    if (ok && r->mat >= 0) mlb_catalogue_caption(r->cls, r->mat, MLB_SDS_VIEW_NONE, object, sizeof object);
    else if (ok) snprintf(object, sizeof object, "a %s", mlb_catalogue_class_name(r->cls));
    if (ok)
        snprintf(r->caption, sizeof r->caption, "%s%s%s", object, r->normal_map ? MLB_CAPTION_NORMAL_MAP : "",
                 mlb_sds_view_suffix(r->view));
    if (ok) return MLB_OK;

    // what is wrong, then what the model does read
    char why[1024] = "";
    size_t at = 0;
#define SAY(...) (at += (size_t)snprintf(why + at, at < sizeof why ? sizeof why - at : 0, __VA_ARGS__), at = at < sizeof why ? at : sizeof why - 1)
    if (r->n_unknown || r->more_unknown) {
        SAY("it never saw the word%s", r->n_unknown == 1 && !r->more_unknown ? "" : "s");
        for (int i = 0; i < r->n_unknown; i++) SAY("%s '%s'", i ? "," : "", r->unknown[i]);
        if (r->more_unknown) SAY("%s and more", r->n_unknown ? "," : "");
    }
    if (r->cls < 0) SAY("%sthe prompt names none of its objects", at ? "; " : "");
    if (r->second_cls >= 0)
        SAY("%sthe prompt names two objects (%s, %s) and it draws one", at ? "; " : "", mlb_catalogue_class_name(r->cls),
            mlb_catalogue_class_name(r->second_cls));
    if (r->second_mat >= 0)
        SAY("%sthe prompt names two materials (%s, %s) and it gives an object one", at ? "; " : "",
            mlb_catalogue_material_name(r->mat), mlb_catalogue_material_name(r->second_mat));
    if (second_view) SAY("%sthe prompt names two views", at ? "; " : "");
#undef SAY
    return mlb_fail(MLB_ERR_ARG,
                    "'%.80s%s' is not a caption the project's own model reads: %s. It knows \"a MATERIAL CLASS\" "
                    "(also written \"golden\", \"gold-coloured\", \"made of gold\", \"a coffee mug\", with or without the "
                    "article) with the classes %s and the materials %s (docs/catalogue.md, \"What the built-in model "
                    "reads\"); any prompt works with Stable Diffusion weights (-m MODEL)",
                    prompt, strlen(prompt) > 80 ? "..." : "", why, mlb_catalogue_class_list(), mlb_catalogue_material_list());
}

// ---- phrasings (bench text3d --phrasing) --------------------------------------------------------
// The first synonym of class or material `name` in the table, or the name itself.
static const char* synonym(kind k, const char* name) {
    for (int p = 0; p < N_PHRASES; p++)
        if (PHRASES[p].k == k && !strcmp(PHRASES[p].name, name)) return PHRASES[p].words;
    return name;
}

void mlb_caption_phrase(int c, int m, int k, char* out, size_t cap) {
    if (!out || !cap) return;
    const char *cn = mlb_catalogue_class_name(c), *mn = mlb_catalogue_material_name(m);
    if (!cn || !mn || k < 1 || k > MLB_CAPTION_N_PHRASINGS) { mlb_catalogue_caption(c, m, MLB_SDS_VIEW_NONE, out, cap); return; }
    // metals and stone are what a thing is made of; the glazes are colours
    int stuff = mlb_catalogue_material_metal(m) || !strcmp(mn, "stone");
    const char* adj = synonym(MATERIAL, mn);
    switch (k) {
    case 1: snprintf(out, cap, "A %s %s.", adj, cn); break;                                     // "A golden goblet."
    case 2: snprintf(out, cap, "a %s %s %s", cn, stuff ? "made of" : "in", mn); break;         // "a goblet made of gold"
    case 3: snprintf(out, cap, "the %s-coloured %s", mn, cn); break;                            // "the gold-coloured goblet"
    case 4: snprintf(out, cap, "%c%s %s", mn[0] - 32, mn + 1, synonym(CLASS, cn)); break;       // "Copper coffee mug"
    default:
        if (stuff) snprintf(out, cap, "a %s of %s", cn, mn);                                      // "a mug of copper"
        else snprintf(out, cap, "a %s-colored %s", mn, cn);                                       // "a red-colored mug"
    }
}

int mlb_caption_phrasing_form(int phrasing, int c, int m) {
    if (phrasing == MLB_CAPTION_PHRASING_MIXED) return 1 + (c + m) % MLB_CAPTION_N_PHRASINGS;
    return phrasing >= 0 && phrasing <= MLB_CAPTION_N_PHRASINGS ? phrasing : 0;
}

static int g_bench_phrasing;
void mlb_caption_set_bench_phrasing(int phrasing) { g_bench_phrasing = phrasing; }
int mlb_caption_bench_phrasing(void) { return g_bench_phrasing; }
