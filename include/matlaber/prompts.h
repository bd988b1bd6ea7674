// The prompts file of `matlaber generate --prompts FILE` (docs/pipeline.md, "Many processes";
// docs/files.md, "What each input may be"): a prompt per line, optionally after options of generate
// ("--seed 3 --name goblet3 a gold goblet"); blank lines and lines starting with # are skipped.
// Lines end in LF, CRLF or CR; the text is strict UTF-8 (a byte-order mark at the start is skipped)
// with no control bytes but tabs; a NUL byte is an error, never the end of the file. A prompt and
// an option's value have at most MLB_PROMPTS_MAX_TEXT bytes, a --name MLB_PROMPTS_MAX_NAME; every
// run folder name is different. Errors name the file and the line, and quote nothing but option
// names (letters, digits and dashes): the file may be anything.
#ifndef MATLABER_PROMPTS_H
#define MATLABER_PROMPTS_H
#include <stddef.h>
#include "matlaber/error.h"

#define MLB_PROMPTS_MAX_TEXT 1023   // bytes of a prompt or of an option's value (a run's config.json holds as much)
#define MLB_PROMPTS_MAX_NAME 127    // bytes of a run folder's name
#define MLB_PROMPTS_MAX_OPTS 64     // option words on one line (an option and its value are two)

typedef struct {
    char* prompt;                   // the line's prompt (inside the list's text)
    char* opts[MLB_PROMPTS_MAX_OPTS];   // its option words, --name taken out
    int n_opts;
    char name[MLB_PROMPTS_MAX_NAME + 1];   // the run folder's name: --name, else the prompt's slug and a hash
    int line;                       // 1-based
} mlb_prompt;

typedef struct {
    mlb_prompt* items;
    int n;
    char* text;   // the file's bytes, split in place
} mlb_prompt_list;

// How many values the option --name takes: 1, 0, or -1 when a prompt line may not set it.
typedef int (*mlb_prompt_arity_fn)(const char* name);

// Parses n bytes (a copy is kept in out->text); `file` names them in errors. On error out is zeroed
// (MLB_ERR_FORMAT: the file's content; MLB_ERR_NOMEM).
mlb_status mlb_prompts_parse(const char* data, size_t n, const char* file, mlb_prompt_arity_fn arity, mlb_prompt_list* out);
void mlb_prompts_free(mlb_prompt_list* l);   // safe on a zeroed list

#endif
