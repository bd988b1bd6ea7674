// Levelled logging through a program-installed sink.
#include "matlaber/log.h"
#include <stdarg.h>
#include <string.h>
#include <strings.h>
#include <unistd.h>

static mlb_log_sink log_sink;
static void* log_user;
static mlb_log_level log_level = MLB_LOG_INFO;

void mlb_log_set_sink(mlb_log_sink sink, void* user) { log_sink = sink; log_user = user; }
void mlb_log_set_level(mlb_log_level level) { log_level = level; }
mlb_log_level mlb_log_get_level(void) { return log_level; }

void mlb_log(mlb_log_level level, const char* fmt, ...) {
    if (!log_sink || level < log_level || level >= MLB_LOG_QUIET) return;
    char message[2048];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(message, sizeof message, fmt, ap);
    va_end(ap);
    log_sink(level, message, log_user);
}

static const char* level_names[] = {"debug", "info", "warn", "error", "quiet"};

void mlb_log_file_sink(mlb_log_level level, const char* message, void* user) {
    FILE* out = user ? (FILE*)user : stderr;
    if (isatty(fileno(out))) fputs("\r\033[K", out);   // a progress bar may own the line: clear it first
    if (level == MLB_LOG_INFO) fprintf(out, "%s\n", message);
    else fprintf(out, "[%s] %s\n", level_names[level], message);
    fflush(out);
}

int mlb_log_level_parse(const char* name, mlb_log_level* out) {
    for (int i = 0; i <= MLB_LOG_QUIET; i++)
        if (strcasecmp(name, level_names[i]) == 0) { *out = (mlb_log_level)i; return 0; }
    return -1;
}
