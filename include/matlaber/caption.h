// What the project's own diffusion models read (docs/catalogue.md, "What the built-in model reads").
// They were trained on the catalogue's captions alone, "a {material} {class}" (+ a view suffix), so
// a word outside them is noise to the text encoder. A free prompt is read here into (class,
// material, view): lower-cased, punctuation and hyphens dropped, filler words ("a", "the", "made
// of", "-coloured") skipped, and a small table of the ways people write the same thing ("golden",
// "coppery", "chalice", "coffee mug"). Its canonical caption, "a gold goblet", is then what the
// model encodes, so every way of writing a caption gives the same run. A word outside the table is
// never dropped: the reading fails naming it (a user's Stable Diffusion weights take any prompt).
#ifndef MATLABER_CAPTION_H
#define MATLABER_CAPTION_H
#include <stddef.h>
#include "matlaber/error.h"

#define MLB_CAPTION_MAX_UNKNOWN 8   // unknown words kept (the message names these)
#define MLB_CAPTION_WORD 48         // bytes kept of each (longer ones end in "...")

typedef struct {
    int cls;                  // catalogue class, -1 when none was named
    int mat;                  // catalogue material, -1 when none was named
    int view;                 // MLB_SDS_VIEW_NONE, or the view suffix the prompt names ("side view")
    char caption[96];         // "a gold goblet" (+ ", normal map") (+ ", side view"); "a goblet" without a material; "" when unread
    int n_unknown;            // words outside the table, named in unknown[] (once each, any case)
    char unknown[MLB_CAPTION_MAX_UNKNOWN][MLB_CAPTION_WORD];   // as typed
    int more_unknown;         // 1: more of them than unknown[] holds
    int second_cls, second_mat;   // a second, different class or material named (-1: none)
    int normal_map;           // 1: the prompt asks for the normal render ("normal map", the geometry captions)
} mlb_caption_reading;
// What the geometry captions add after the object (sd_train.h's MLB_SD_GEOMETRY_SUFFIX is this)
#define MLB_CAPTION_NORMAL_MAP ", normal map"

// Reads prompt into r (always filled). MLB_OK when it names exactly one class, at most one
// material and no unknown word; otherwise MLB_ERR_ARG with a message that names the unknown words
// (or what is missing or doubled), lists the classes and materials the model knows and says that
// any prompt works with Stable Diffusion weights (-m).
mlb_status mlb_caption_read(const char* prompt, mlb_caption_reading* r);

// The held-out phrasings of the benchmark (bench text3d --phrasing): caption (class c, material m)
// written in form k, 1..MLB_CAPTION_N_PHRASINGS ("A golden goblet.", "a goblet made of gold", ...);
// form 0 is the catalogue's own caption. Every form reads back to (c, m).
#define MLB_CAPTION_N_PHRASINGS 5
void mlb_caption_phrase(int c, int m, int k, char* out, size_t cap);
// The form of pair (c, m) under --phrasing K: K itself for 0..N, or for K = MLB_CAPTION_PHRASING_MIXED
// one of 1..N by the pair, so that a benchmark over the catalogue meets every form.
#define MLB_CAPTION_PHRASING_MIXED (-1)
int mlb_caption_phrasing_form(int phrasing, int c, int m);
// The benchmark's phrasing, a process-wide choice (default 0: the catalogue's captions).
void mlb_caption_set_bench_phrasing(int phrasing);
int mlb_caption_bench_phrasing(void);

#endif
