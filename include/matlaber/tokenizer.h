// The CLIP byte-level BPE tokenizer of the Stable Diffusion text encoders (reference.md §6,
// docs/tokenizer.md): text -> 77 token ids, [49406] + BPE ids + [49407] + padding.
//
// Loading accepts OpenAI's gzipped merges file (bpe_simple_vocab_16e6.txt.gz), a diffusers
// tokenizer/ folder (merges.txt, and vocab.json which is checked against the vocabulary the merges
// give), or a model folder that contains tokenizer/. Text is UTF-8; it is cleaned as CLIP does
// (a documented subset of ftfy, html.unescape twice, whitespace collapse and strip, Python-style
// lower-casing), split by CLIP's pre-tokenizer pattern (Unicode letters and numbers from utf8proc)
// and each piece is BPE-merged lowest rank first.
#ifndef MATLABER_TOKENIZER_H
#define MATLABER_TOKENIZER_H
#include <stddef.h>
#include "matlaber/error.h"

#define MLB_CLIP_CONTEXT 77          // tokens per sequence of both SD text encoders
#define MLB_CLIP_VOCAB 49408         // 256 bytes, 256 bytes + "</w>", 48,894 merges, 2 specials
#define MLB_CLIP_MERGES 48894        // merges used from the file (lines 1..48,894 after the header)
#define MLB_CLIP_BOS 49406           // <|startoftext|>
#define MLB_CLIP_EOS 49407           // <|endoftext|>
#define MLB_CLIP_PAD_SD1 49407       // SD 1.x (HF CLIPTokenizer): pads with <|endoftext|>
#define MLB_CLIP_PAD_SD2 0           // SD 2.x (open_clip.tokenize): pads with 0 ("!")

#define MLB_TOKENIZER_MAX_TEXT (1 << 20)   // bytes of text accepted by encode/tokenize

// Text cleaning steps (mlb_tokenizer_set_flags); both on by default.
enum {
    MLB_TOKENIZER_FIX_TEXT = 1,      // the ftfy subset: Latin ligatures, full-width forms, curly quotes, NFC
    MLB_TOKENIZER_UNESCAPE_HTML = 2, // html.unescape applied twice (common named + all numeric entities)
};

typedef struct mlb_tokenizer mlb_tokenizer;

// `path`: a gzipped merges file, a plain merges text file, a folder with merges.txt (+ vocab.json),
// a model folder with tokenizer/, or a folder holding bpe_simple_vocab_16e6.txt.gz.
// Errors name the path and say what was expected. *tok is NULL on failure.
mlb_status mlb_tokenizer_load(const char* path, mlb_tokenizer** tok);
void mlb_tokenizer_free(mlb_tokenizer* tok);

// What was loaded, e.g. "/x/bpe_simple_vocab_16e6.txt.gz (gzipped merges, 48894 merges)".
const char* mlb_tokenizer_source(const mlb_tokenizer* tok);
int mlb_tokenizer_vocab_size(const mlb_tokenizer* tok);   // 49408 for the CLIP files
int mlb_tokenizer_n_merges(const mlb_tokenizer* tok);
int mlb_tokenizer_bos(const mlb_tokenizer* tok);          // 49406 for the CLIP files
int mlb_tokenizer_eos(const mlb_tokenizer* tok);          // 49407 for the CLIP files
unsigned mlb_tokenizer_flags(const mlb_tokenizer* tok);
void mlb_tokenizer_set_flags(mlb_tokenizer* tok, unsigned flags);

// A token's vocabulary string in the byte-to-unicode form of vocab.json ("cat</w>", "Ã©</w>");
// NULL when id is out of range. Lookup the other way: *id = -1 (and MLB_ERR_NOT_FOUND) when absent.
const char* mlb_tokenizer_token(const mlb_tokenizer* tok, int id);
mlb_status mlb_tokenizer_token_id(const mlb_tokenizer* tok, const char* token, int* id);

// The sequence a text encoder takes: ids[0] = bos, the text's BPE ids, eos, then pad_id up to
// max_len. A text with more than max_len - 2 tokens is cut after max_len - 2 of them; the last
// id before padding is always eos. *n_used (may be NULL) = ids before padding (bos and eos included).
// Invalid UTF-8 is an error (MLB_ERR_ARG naming the byte offset). Safe to call from several threads.
mlb_status mlb_tokenizer_encode(mlb_tokenizer* tok, const char* text, int* ids, int max_len, int pad_id, int* n_used);
// All BPE ids of the text, without bos/eos, untruncated: *ids is malloc'd (free it), *n its length.
mlb_status mlb_tokenizer_tokenize(mlb_tokenizer* tok, const char* text, int** ids, size_t* n);
// ids -> text as CLIP's decode does: token bytes joined, invalid UTF-8 replaced by U+FFFD, every
// "</w>" turned into a space; specials and padding come out as their strings. *text is malloc'd.
mlb_status mlb_tokenizer_decode(const mlb_tokenizer* tok, const int* ids, size_t n, char** text);

// "sd1" -> 49407, "sd2" -> 0.
mlb_status mlb_tokenizer_pad_id(const char* model, int* pad_id);

// The cleaning pipeline on its own (what the pre-tokenizer sees), for tests and debugging:
// flags as above; *out is malloc'd UTF-8.
mlb_status mlb_tokenizer_clean_text(const char* text, unsigned flags, char** out);
// Python's html.unescape (named entities: HTML 4's 252 and HTML 5's legacy forms without ';',
// plus &apos;; numeric entities exactly as Python maps them). *out is malloc'd UTF-8.
mlb_status mlb_html_unescape(const char* text, char** out);

#endif
