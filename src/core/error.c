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

// The message fmt makes, then ": " and `tail` when tail is not NULL, into last_message; 0 (and
// last_message untouched) when out of memory.
static int compose(const char* fmt, va_list ap, const char* tail) {
    va_list aq;
    va_copy(aq, ap);
    int len = vsnprintf(NULL, 0, fmt, aq);
    va_end(aq);
    if (len < 0) return 0;
    size_t n = (size_t)len, m = tail ? strlen(tail) : 0, total = tail ? n + 2 + m : n;
    char* text = malloc(total + 1);
    if (!text) return 0;
    vsnprintf(text, n + 1, fmt, ap);
    if (tail) {
        memcpy(text + n, ": ", 2);
        memcpy(text + n + 2, tail, m + 1);
    }
    keep(text, total);
    free(text);
    return 1;
}

mlb_status mlb_fail(mlb_status code, const char* fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    int ok = compose(fmt, ap, NULL);
    va_end(ap);
    if (!ok) snprintf(last_message, sizeof last_message, "%s (and out of memory for its message)", mlb_status_name(code));
    return code;
}

mlb_status mlb_fail_context(mlb_status code, const char* fmt, ...) {
    const char* old = last_message[0] ? last_message : mlb_status_name(code);
    va_list ap;
    va_start(ap, fmt);
    compose(fmt, ap, old);   // out of memory: the message stays as it was, without the context
    va_end(ap);
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
