// The per-thread last error message.
#include "matlaber/error.h"
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

static _Thread_local char last_message[2048];

mlb_status mlb_fail(mlb_status code, const char* fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(last_message, sizeof last_message, fmt, ap);
    va_end(ap);
    return code;
}

mlb_status mlb_fail_context(mlb_status code, const char* fmt, ...) {
    char prefix[1024], old[sizeof last_message];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(prefix, sizeof prefix, fmt, ap);
    va_end(ap);
    memcpy(old, last_message, sizeof old);
    snprintf(last_message, sizeof last_message, "%s: %s", prefix, old[0] ? old : mlb_status_name(code));
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
