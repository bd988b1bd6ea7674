// Progress bar (terminal) or periodic plain lines (pipes, CI logs).
#include "matlaber/progress.h"
#include <string.h>
#include <time.h>
#include <unistd.h>

double mlb_now_seconds(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

const char* mlb_format_duration(double s, char* buf, int n) {
    if (!(s >= 0) || s > 1e8) snprintf(buf, n, "?");
    else if (s < 60) snprintf(buf, n, "%.1fs", s);
    else if (s < 3600) snprintf(buf, n, "%dm%02ds", (int)(s / 60), (int)s % 60);
    else snprintf(buf, n, "%dh%02dm", (int)(s / 3600), ((int)s % 3600) / 60);
    return buf;
}

static FILE* g_json;

void mlb_progress_set_json(FILE* f) { g_json = f; }
FILE* mlb_progress_json(void) { return g_json; }

void mlb_json_write_string(FILE* f, const char* s) {
    fputc('"', f);
    for (const unsigned char* c = (const unsigned char*)(s ? s : ""); *c; c++) {
        if (*c == '"' || *c == '\\') fprintf(f, "\\%c", *c);
        else if (*c == '\n') fputs("\\n", f);
        else if (*c < 0x20) fprintf(f, "\\u%04x", *c);
        else fputc(*c, f);
    }
    fputc('"', f);
}

// One JSON line (docs/paint.md): the event, the counts, the times, the status.
static void progress_json(mlb_progress* p, const char* event, const char* status) {
    double t = mlb_now_seconds(), elapsed = t - p->t_start;
    double rate = elapsed > 0 ? (double)(p->done - p->base) / elapsed : 0;
    double eta = rate > 0 ? (double)(p->total - p->done) / rate : -1;
    FILE* f = p->json;
    fprintf(f, "{\"event\":\"%s\",\"label\":", event);
    mlb_json_write_string(f, p->label);
    if (!strcmp(event, "begin")) {
        fprintf(f, ",\"total\":%ld,\"unit\":", p->total);
        mlb_json_write_string(f, p->unit);
    } else {
        fprintf(f, ",\"done\":%ld,\"total\":%ld,\"fraction\":%.4f,\"elapsed_s\":%.2f", p->done, p->total,
                (double)p->done / (double)p->total, elapsed);
        if (!strcmp(event, "progress")) fprintf(f, ",\"eta_s\":%.1f,\"rate\":%.4g", eta, rate);
        if (status) {
            fputs(",\"status\":", f);
            mlb_json_write_string(f, status);
        }
    }
    fputs("}\n", f);
    fflush(f);
    p->t_last = t;
}

void mlb_progress_begin(mlb_progress* p, FILE* out, const char* label, long total, const char* unit) {
    memset(p, 0, sizeof *p);
    if (g_json) {   // the JSON stream instead of the human one
        p->json = g_json;
        out = NULL;
    }
    p->out = out;
    snprintf(p->label, sizeof p->label, "%s", label ? label : "");
    p->total = total > 0 ? total : 1;
    p->unit = unit ? unit : "it";
    p->is_tty = out && isatty(fileno(out));
    p->t_start = p->t_last = mlb_now_seconds();
    p->plain_every = 10.0;
    if (p->json) progress_json(p, "begin", NULL);
}

static void progress_print(mlb_progress* p, const char* status, int final) {
    double t = mlb_now_seconds(), elapsed = t - p->t_start;
    double rate = elapsed > 0 ? (double)(p->done - p->base) / elapsed : 0;
    double eta = rate > 0 ? (double)(p->total - p->done) / rate : -1;
    double frac = (double)p->done / (double)p->total;
    char eta_s[32], el_s[32];
    mlb_format_duration(final ? elapsed : eta, eta_s, sizeof eta_s);
    mlb_format_duration(elapsed, el_s, sizeof el_s);
    if (p->is_tty) {
        char bar[31];
        int filled = (int)(frac * 30 + 0.5);
        for (int i = 0; i < 30; i++) bar[i] = i < filled ? '#' : '-';
        bar[30] = 0;
        fprintf(p->out, "\r\033[K%s [%s] %3.0f%% %ld/%ld %.1f %s/s %s %s%s%s", p->label, bar, 100 * frac,
                p->done, p->total, rate, p->unit, final ? "in" : "ETA", eta_s, status ? "  " : "",
                status ? status : "");
        if (final) fputc('\n', p->out);
    } else {
        fprintf(p->out, "%s: %ld/%ld (%.0f%%) %.1f %s/s, %s %s, elapsed %s%s%s\n", p->label, p->done,
                p->total, 100 * frac, rate, p->unit, final ? "took" : "ETA", eta_s, el_s,
                status ? ", " : "", status ? status : "");
    }
    fflush(p->out);
    p->t_last = t;
}

void mlb_progress_update(mlb_progress* p, long done, const char* status) {
    if (p && p->json) {
        p->done = done;
        if (mlb_now_seconds() - p->t_last >= 0.2 || done >= p->total) progress_json(p, "progress", status);
        return;
    }
    if (!p || !p->out) return;
    p->done = done;
    double t = mlb_now_seconds();
    double every = p->is_tty ? 0.1 : p->plain_every;
    if (t - p->t_last >= every) progress_print(p, status, 0);
}

void mlb_progress_end(mlb_progress* p, const char* status) {
    if (p && p->json) {   // done stays what it was: a stopped run ends short of its total
        progress_json(p, "end", status);
        return;
    }
    if (!p || !p->out) return;
    p->done = p->total;
    progress_print(p, status, 1);
}
