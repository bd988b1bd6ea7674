// Shared helpers of the command-line program.
#include "cli.h"
#include "matlaber/backend.h"
#include "matlaber/device.h"
#include "matlaber/log.h"
#include "matlaber/progress.h"
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

// serve checks a job's options in its own threads: the message is kept for the reply, not printed
int cli_rc_agreed;
static _Thread_local int quiet;
static _Thread_local char last_message[1024];
void cli_set_quiet(int on) { quiet = on; }
const char* cli_last_message(void) { return last_message; }

const mlb_backend* cli_run_backend(const char* run_precision) {
    mlb_gemm_precision p = mlb_gemm_precision_current();
    // (a name that does not parse leaves p: mlb_pipeline_validate has refused it before)
    if (run_precision && run_precision[0] && !mlb_gemm_precision_chosen()) mlb_gemm_precision_parse(run_precision, &p);
    return mlb_backend_for(mlb_device_current(), p);
}

int cli_fail(mlb_status s, const char* what) {
    const char* msg = mlb_last_error();
    const char *a = what ? what : "", *sep = what && *msg ? ": " : "", *b = *msg ? msg : mlb_status_name(s);
    snprintf(last_message, sizeof last_message, "%s%s%s", a, sep, b);
    if (quiet) return 1;
    fprintf(stderr, "matlaber: error: %s%s%s\n", a, sep, b);
    FILE* json = mlb_progress_json();
    if (json) {   // the same message for programs reading the progress stream
        size_t n = strlen(a) + strlen(sep) + strlen(b) + 1;
        char* line = malloc(n);
        if (line) snprintf(line, n, "%s%s%s", a, sep, b);
        fputs("{\"event\":\"error\",\"message\":", json);
        mlb_json_write_string(json, line ? line : b);
        fputs("}\n", json);
        fflush(json);
        free(line);
    }
    return 1;
}

int cli_usage_error(const char* command, const char* fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(last_message, sizeof last_message, fmt, ap);
    va_end(ap);
    if (quiet) return EXIT_USAGE;
    fprintf(stderr, "matlaber %s: ", command);
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fprintf(stderr, "\n(see 'matlaber %s --help')\n", command);
    FILE* json = mlb_progress_json();
    if (json) {
        va_start(ap, fmt);
        int n = vsnprintf(NULL, 0, fmt, ap);
        va_end(ap);
        char* line = n >= 0 ? malloc((size_t)n + 1) : NULL;
        if (line) {
            va_start(ap, fmt);
            vsnprintf(line, (size_t)n + 1, fmt, ap);
            va_end(ap);
        }
        fprintf(json, "{\"event\":\"error\",\"usage\":true,\"message\":");
        mlb_json_write_string(json, line ? line : "usage error");
        fputs("}\n", json);
        fflush(json);
        free(line);
    }
    return EXIT_USAGE;
}

int cli_check_args(int argc, char** argv) {
    for (int i = 1; i < argc; i++) {
        size_t n = strlen(argv[i]);
        if (n <= CLI_MAX_ARG) continue;
        // the argument itself is not shown: it may be anything (a whole file pasted as a prompt)
        if (i > 1 && argv[i - 1][0] == '-')
            return cli_usage_error(argv[0], "the value of %.64s is %zu bytes: a path, a prompt or a name may have at most %d",
                                   argv[i - 1], n, CLI_MAX_ARG);
        return cli_usage_error(argv[0], "argument %d is %zu bytes: a path, a prompt or a name may have at most %d", i, n,
                               CLI_MAX_ARG);
    }
    return 0;
}

int cli_parse_floats(const char* text, float* out, int n) {
    const char* p = text;
    for (int i = 0; i < n; i++) {
        char* end;
        errno = 0;
        double v = strtod(p, &end);
        if (end == p || errno || !isfinite(v)) return -1;
        out[i] = (float)v;
        p = end;
        while (*p == ' ') p++;
        if (i < n - 1) { if (*p != ',') return -1; p++; }
    }
    return *p == 0 ? 0 : -1;
}

int cli_parse_long(const char* text, long lo, long hi, long* out) {
    char* end;
    errno = 0;
    long v = strtol(text, &end, 10);
    if (end == text || *end || errno || v < lo || v > hi) return -1;
    *out = v;
    return 0;
}

int cli_parse_u64(const char* text, uint64_t* out) {
    char* end;
    errno = 0;
    unsigned long long v = strtoull(text, &end, 10);
    if (!isdigit((unsigned char)text[0]) || *end || errno) return -1;   // no sign, no overflow to 2^64 - 1
    *out = (uint64_t)v;
    return 0;
}

int cli_parse_double(const char* text, double lo, double hi, double* out) {
    char* end;
    errno = 0;
    double v = strtod(text, &end);
    if (end == text || *end || errno || !isfinite(v) || v < lo || v > hi) return -1;
    *out = v;
    return 0;
}

const char* cli_shared_data(void) {
    static char path[4096];
    struct stat st;
    const char* env = getenv("MLB_SHARED_DATA");
    if (env && stat(env, &st) == 0 && S_ISDIR(st.st_mode)) return env;
    snprintf(path, sizeof path, "%s/../shared/data", MLB_SOURCE_DIR);
    if (stat(path, &st) == 0 && S_ISDIR(st.st_mode)) return path;
    return NULL;
}

// models/NAME when it holds a model (its model_index.json), else NULL; path is the caller's buffer.
static const char* own_model(const char* name, char* path, size_t cap) {
    struct stat st;
    snprintf(path, cap, "%s/models/%s/model_index.json", MLB_SOURCE_DIR, name);
    if (stat(path, &st) != 0) return NULL;
    snprintf(path, cap, "%s/models/%s", MLB_SOURCE_DIR, name);
    return path;
}

const char* cli_default_model(void) {
    static char path[4200];
    const char* env = getenv("MATLABER_MODEL");
    if (env && env[0]) return env;
    return own_model(MLB_DEFAULT_MODEL, path, sizeof path);
}

const char* cli_default_appearance_model(void) {
    static char path[4200];
    const char* env = getenv("MATLABER_APPEARANCE_MODEL");
    if (env && env[0]) return env;
    env = getenv("MATLABER_MODEL");   // a model of the user's own guides both stages
    if (env && env[0]) return NULL;
    return own_model(MLB_DEFAULT_APPEARANCE_MODEL, path, sizeof path);
}

void cli_print_options(FILE* out, const cli_option* o) {
    for (; o->name; o++) {
        char left[64];
        snprintf(left, sizeof left, "--%s%s%s", o->name, o->has_arg ? " " : "", o->has_arg ? o->arg : "");
        fprintf(out, "  %-24s %s\n", left, o->help);
    }
}

const struct option* cli_getopt_table(const cli_option* opts) {
    static struct option table[65];
    int n = 0;
    for (; opts[n].name && n < 64; n++)
        table[n] = (struct option){opts[n].name, opts[n].has_arg, NULL, opts[n].val};
    table[n] = (struct option){0, 0, 0, 0};
    return table;
}

void cli_frames_to_mp4(const char* dir, const char* name) {
    if (system("command -v ffmpeg > /dev/null 2>&1") != 0) {
        mlb_log(MLB_LOG_INFO, "PNG frames in %s (install ffmpeg for an MP4)", dir);
        return;
    }
    char cmdline[9000];
    snprintf(cmdline, sizeof cmdline, "ffmpeg -loglevel error -y -framerate 24 -i '%s/frame_%%04d.png' -pix_fmt yuv420p '%s/%s'",
             dir, dir, name);
    if (system(cmdline) == 0) mlb_log(MLB_LOG_INFO, "wrote %s/%s", dir, name);
    else mlb_log(MLB_LOG_WARN, "ffmpeg failed; the PNG frames are in %s", dir);
}
