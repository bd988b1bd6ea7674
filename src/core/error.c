// The per-thread last error message.
#include "matlaber/error.h"
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

// A message longer than this keeps its beginning and its end (the reason comes last) around " ... ":
// a long path in it can never push the problem out of the message.
#define MESSAGE_CAP 4096
#define MESSAGE_HEAD 1024
static _Thread_local char last_message[MESSAGE_CAP];

// The start of the UTF-8 character at or before s[i] (a cut falls between characters).
static size_t char_start(const char* s, size_t i) {
    while (i > 0 && ((unsigned char)s[i] & 0xC0) == 0x80) i--;
    return i;
}

// text (n bytes) into last_message, whole or with its middle left out
static void keep(const char* text, size_t n) {
    if (n < MESSAGE_CAP) { memcpy(last_message, text, n + 1); return; }
    static const char gap[] = " ... ";
    size_t head = char_start(text, MESSAGE_HEAD);
    size_t tail_len = MESSAGE_CAP - 1 - head - (sizeof gap - 1);
    size_t from = n - tail_len;
    while (from < n && ((unsigned char)text[from] & 0xC0) == 0x80) from++;   // whole characters only
    memcpy(last_message, text, head);
    memcpy(last_message + head, gap, sizeof gap - 1);
    memcpy(last_message + head + sizeof gap - 1, text + from, n - from + 1);
}

// vsnprintf into a buffer of the message's own size; NULL when out of memory
static char* format(const char* fmt, va_list ap, size_t* n) {
    va_list aq;
    va_copy(aq, ap);
    int len = vsnprintf(NULL, 0, fmt, aq);
    va_end(aq);
    if (len < 0) return NULL;
    char* text = malloc((size_t)len + 1);
    if (text) vsnprintf(text, (size_t)len + 1, fmt, ap);
    *n = (size_t)len;
    return text;
}

mlb_status mlb_fail(mlb_status code, const char* fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    size_t n = 0;
    char* text = format(fmt, ap, &n);
    va_end(ap);
    if (text) keep(text, n);
    else snprintf(last_message, sizeof last_message, "%s (and out of memory for its message)", mlb_status_name(code));
    free(text);
    return code;
}

mlb_status mlb_fail_context(mlb_status code, const char* fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    size_t n = 0;
    char* prefix = format(fmt, ap, &n);
    va_end(ap);
    const char* old = last_message[0] ? last_message : mlb_status_name(code);
    size_t m = strlen(old);
    char* text = prefix ? malloc(n + 2 + m + 1) : NULL;
    if (text) {
        memcpy(text, prefix, n);
        memcpy(text + n, ": ", 2);
        memcpy(text + n + 2, old, m + 1);
        keep(text, n + 2 + m);
    }
    free(prefix);
    free(text);
    return code;
}

const char* mlb_last_error(void) { return last_message; }
void mlb_clear_error(void) { last_message[0] = 0; }

const char* mlb_status_name(mlb_status code) {
    switch (code) {
    case MLB_OK: return "ok";
    case MLB_ERR_ARG: return "invalid argument";
    case MLB_ERR_IO: return "input/output error";
    case MLB_ERR_FORMAT: return "malformed file";
    case MLB_ERR_UNSUPPORTED: return "unsupported";
    case MLB_ERR_NOT_FOUND: return "not found";
    case MLB_ERR_NOMEM: return "out of memory";
    case MLB_ERR_NUMERIC: return "numerical failure";
    case MLB_ERR_DEVICE: return "device error";
    }
    return "unknown error";
}
