// Shared between the CLIP tokenizer's two files: the text side (tokenizer_text.c: UTF-8, cleaning,
// pre-tokenizer) and the vocabulary/BPE side (tokenizer.c).
#ifndef MATLABER_TOKENIZER_INTERNAL_H
#define MATLABER_TOKENIZER_INTERNAL_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/error.h"

// Strict UTF-8 (Python's "strict" decoder: no overlongs, surrogates or code points past U+10FFFF).
// On failure the message says "<what> is not valid UTF-8: byte 0xNN at offset K".
mlb_status tok_utf8_decode(const char* s, size_t n, const char* what, uint32_t** cps, size_t* ncp);
// Length (1..4) of the valid UTF-8 sequence at s[0..n), 0 when the bytes there are not one.
int tok_utf8_seq_len(const unsigned char* s, size_t n);
// Writes c (a valid scalar value) as UTF-8 into out (4 bytes room); returns the byte count.
int tok_utf8_put(uint32_t c, char* out);
// Code points -> malloc'd NUL-terminated UTF-8.
mlb_status tok_utf8_encode(const uint32_t* cps, size_t n, char** out, size_t* nbytes);
// Bytes -> malloc'd UTF-8 text the way Python's bytes.decode("utf-8", errors="replace") does:
// every maximal invalid subsequence becomes one U+FFFD.
mlb_status tok_utf8_decode_replace(const unsigned char* s, size_t n, char** out, size_t* nout);

// The whole cleaning pipeline (docs/tokenizer.md): fix-text subset, html.unescape twice, strip,
// whitespace collapse, strip, Python str.lower(). *cps is malloc'd. MLB_ERR_ARG for a NULL text or
// one over MLB_TOKENIZER_MAX_TEXT bytes.
mlb_status tok_clean(const char* text, unsigned flags, uint32_t** cps, size_t* n);

// CLIP's pre-tokenizer over cleaned code points, one piece per call, findall-style:
// returns 0 at the end; otherwise [*start, *end) is the piece and *special is 1 for a literal
// "<|startoftext|>", 2 for "<|endoftext|>", 0 for an ordinary piece (to be BPE-encoded).
int tok_next_piece(const uint32_t* cp, size_t n, size_t* pos, size_t* start, size_t* end, int* special);

#endif
