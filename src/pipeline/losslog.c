// The loss log: a CSV appended a row per step, truncated on resume, and its plot (docs/runs.md).
#include "matlaber/run.h"
#include "matlaber/fileio.h"
#include "matlaber/image_write.h"
#include "matlaber/plot.h"
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define LOSSLOG_MAX_BYTES (1u << 30)

struct mlb_losslog {
    FILE* f;
    char* path;
    int n_columns;
};

static mlb_status build_header(char** out, const char* path, const char* const* columns, int n) {
    *out = NULL;
    if (n < 1 || n > MLB_LOSSLOG_MAX_COLUMNS || !columns)
        return mlb_fail(MLB_ERR_ARG, "%s: %d loss columns (1..%d)", path, n, MLB_LOSSLOG_MAX_COLUMNS);
    size_t len = strlen("stage,step") + 2;
    for (int i = 0; i < n; i++) {
        const char* c = columns[i];
        if (!c || !c[0] || strpbrk(c, ",\"\r\n"))
            return mlb_fail(MLB_ERR_ARG, "%s: loss column %d ('%s') must be non-empty without commas, quotes or line breaks",
                            path, i, c ? c : "(null)");
        len += strlen(c) + 1;
    }
    char* h = malloc(len);
    if (!h) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path);
    strcpy(h, "stage,step");
    for (int i = 0; i < n; i++) { strcat(h, ","); strcat(h, columns[i]); }
    strcat(h, "\n");
    *out = h;
    return MLB_OK;
}

// Parses "stage,step,v1,...,vn" (line without its newline, NUL-terminated). 0 on success.
static int parse_row(char* line, int n_columns, int* stage, long* step, double* values) {
    char* p = line;
    char* end;
    errno = 0;
    long st = strtol(p, &end, 10);
    if (end == p || *end != ',' || errno || st < 0 || st > 1000000) return -1;
    p = end + 1;
    long sp = strtol(p, &end, 10);
    if (end == p || errno || sp < 0) return -1;
    p = end;
    for (int i = 0; i < n_columns; i++) {
        if (*p != ',') return -1;
        p++;
        double v = strtod(p, &end);
        if (end == p) return -1;
        if (values) values[i] = v;
        p = end;
    }
    if (*p) return -1;
    *stage = (int)st;
    *step = sp;
    return 0;
}

// Keeps the rows of `text` (after the header) before (rs, rstep); writes header + kept rows to path atomically.
static mlb_status truncate_log(const char* path, char* text, size_t n, const char* header, int n_columns, int rs, long rstep) {
    size_t hl = strlen(header);
    if (n < hl || memcmp(text, header, hl) != 0) {
        char* nl = memchr(text, '\n', n);
        size_t l = nl ? (size_t)(nl - text) : n;
        if (l > 200) l = 200;
        return mlb_fail(MLB_ERR_FORMAT, "%s: header '%.*s' does not match this run's '%.*s'", path, (int)l, text, (int)(hl - 1), header);
    }
    size_t keep = hl;   // bytes of text to keep
    size_t pos = hl;
    long line_no = 2;
    while (pos < n) {
        char* nl = memchr(text + pos, '\n', n - pos);
        if (!nl) break;   // a torn last line: dropped
        *nl = 0;
        int stage;
        long step;
        if (parse_row(text + pos, n_columns, &stage, &step, NULL) != 0) {
            *nl = '\n';
            return mlb_fail(MLB_ERR_FORMAT, "%s:%ld: malformed row (expected stage,step and %d numbers)", path, line_no, n_columns);
        }
        *nl = '\n';
        if (stage < rs || (stage == rs && step < rstep)) keep = (size_t)(nl - text) + 1;
        else break;
        pos = (size_t)(nl - text) + 1;
        line_no++;
    }
    return mlb_write_file_atomic(path, text, keep);
}

mlb_status mlb_losslog_open(mlb_losslog** out, const char* path, const char* const* columns, int n_columns,
                            int resume_stage, long resume_step) {
    *out = NULL;
    if (!path) return mlb_fail(MLB_ERR_ARG, "loss log: NULL path");
    char* header = NULL;
    MLB_TRY(build_header(&header, path, columns, n_columns));
    mlb_status s;
    if (resume_stage < 0) {
        s = mlb_write_file_atomic(path, header, strlen(header));
    } else {
        char* text = NULL;
        size_t n = 0;
        s = mlb_read_file(path, &text, &n, LOSSLOG_MAX_BYTES);
        if (s == MLB_ERR_NOT_FOUND) s = mlb_write_file_atomic(path, header, strlen(header));   // nothing to keep
        else if (s == MLB_OK) s = truncate_log(path, text, n, header, n_columns, resume_stage, resume_step);
        free(text);
    }
    free(header);
    if (s) return s;
    mlb_losslog* l = calloc(1, sizeof *l);
    if (!l || !(l->path = strdup(path))) { free(l); return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); }
    l->n_columns = n_columns;
    l->f = fopen(path, "ab");
    if (!l->f) {
        int e = errno;
        free(l->path); free(l);
        return mlb_fail(MLB_ERR_IO, "%s: cannot open for appending: %s", path, strerror(e));
    }
    *out = l;
    return MLB_OK;
}

mlb_status mlb_losslog_append(mlb_losslog* l, int stage, long step, const double* values) {
    if (!l || !l->f || (!values && l->n_columns)) return mlb_fail(MLB_ERR_ARG, "loss log: not open or no values");
    if (stage < 0 || step < 0) return mlb_fail(MLB_ERR_ARG, "%s: negative stage %d or step %ld", l->path, stage, step);
    int bad = fprintf(l->f, "%d,%ld", stage, step) < 0;
    for (int i = 0; i < l->n_columns && !bad; i++) {
        double v = values[i];
        if (isnan(v)) bad = fputs(",nan", l->f) < 0;
        else if (isinf(v)) bad = fputs(v > 0 ? ",inf" : ",-inf", l->f) < 0;
        else bad = fprintf(l->f, ",%.9g", v) < 0;
    }
    if (!bad) bad = fputc('\n', l->f) == EOF || fflush(l->f) != 0;
    if (bad) return mlb_fail(MLB_ERR_IO, "%s: write failed: %s", l->path, strerror(errno));
    return MLB_OK;
}

void mlb_losslog_close(mlb_losslog* l) {
    if (!l) return;
    if (l->f) fclose(l->f);
    free(l->path);
    free(l);
}

// ---- plot ------------------------------------------------------------------------------------
#define PANEL_W 720
#define PANEL_H 220
#define MAX_STAGES 8

mlb_status mlb_losslog_plot(const char* csv_path, const char* png_path) {
    static const char* const pipeline_stages[2] = {"geometry", "appearance"};   // guidance.h
    return mlb_losslog_plot_named(csv_path, png_path, pipeline_stages, 2);
}

mlb_status mlb_losslog_plot_named(const char* csv_path, const char* png_path, const char* const* stage_names,
                                  int n_names) {
    char* text = NULL;
    size_t n = 0;
    MLB_TRY(mlb_read_file(csv_path, &text, &n, LOSSLOG_MAX_BYTES));
    // header
    char* nl = memchr(text, '\n', n);
    if (!nl || strncmp(text, "stage,step,", 11) != 0) {
        free(text);
        return mlb_fail(MLB_ERR_FORMAT, "%s: not a loss log (the first line must start with 'stage,step,')", csv_path);
    }
    *nl = 0;
    char* names[MLB_LOSSLOG_MAX_COLUMNS];
    int nc = 0;
    for (char* p = text + 11; p; ) {
        char* c = strchr(p, ',');
        if (c) *c = 0;
        if (nc == MLB_LOSSLOG_MAX_COLUMNS || !*p) {
            free(text);
            return mlb_fail(MLB_ERR_FORMAT, "%s: header has an empty name or more than %d columns", csv_path, MLB_LOSSLOG_MAX_COLUMNS);
        }
        names[nc++] = p;
        p = c ? c + 1 : NULL;
    }
    // rows
    size_t cap = 1024, rows = 0;
    int* stage = malloc(sizeof(int) * cap);
    double* step = malloc(sizeof(double) * cap);
    double* val = malloc(sizeof(double) * cap * nc);
    mlb_status s = (stage && step && val) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", csv_path);
    size_t pos = (size_t)(nl - text) + 1;
    long line_no = 2;
    while (s == MLB_OK && pos < n) {
        char* e = memchr(text + pos, '\n', n - pos);
        if (!e) break;   // torn last line
        *e = 0;
        if (rows == cap) {
            cap *= 2;
            int* a = realloc(stage, sizeof(int) * cap);
            if (a) stage = a;
            double* b = realloc(step, sizeof(double) * cap);
            if (b) step = b;
            double* c = realloc(val, sizeof(double) * cap * nc);
            if (c) val = c;
            if (!a || !b || !c) { s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", csv_path); break; }
        }
        long sp;
        if (parse_row(text + pos, nc, &stage[rows], &sp, val + rows * nc) != 0) {
            s = mlb_fail(MLB_ERR_FORMAT, "%s:%ld: malformed row (expected stage,step and %d numbers)", csv_path, line_no, nc);
            break;
        }
        if (stage[rows] >= MAX_STAGES) { s = mlb_fail(MLB_ERR_FORMAT, "%s:%ld: stage %d (at most %d stages plotted)", csv_path, line_no, stage[rows], MAX_STAGES); break; }
        step[rows++] = (double)sp;
        pos = (size_t)(e - text) + 1;
        line_no++;
    }
    // stage offsets: stage k is drawn after the last step of the stages before it
    double smax[MAX_STAGES], off[MAX_STAGES];
    int used[MAX_STAGES] = {0};
    for (int k = 0; k < MAX_STAGES; k++) smax[k] = -1;
    for (size_t r = 0; r < rows; r++) { used[stage[r]] = 1; if (step[r] > smax[stage[r]]) smax[stage[r]] = step[r]; }
    double acc = 0, vl[MAX_STAGES];
    int nvl = 0, first = 1;
    for (int k = 0; k < MAX_STAGES; k++) {
        off[k] = acc;
        if (!used[k]) continue;
        if (!first) vl[nvl++] = acc;
        first = 0;
        acc += smax[k] + 1;
    }
    float* img = NULL;
    double *xs = NULL, *ys = NULL;
    int W = PANEL_W, H = PANEL_H * nc;
    if (s == MLB_OK) {
        img = malloc(sizeof(float) * 3 * (size_t)W * H);
        xs = malloc(sizeof(double) * (rows ? rows : 1));
        ys = malloc(sizeof(double) * (rows ? rows : 1) * MAX_STAGES);
        if (!img || !xs || !ys) s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", png_path);
    }
    for (size_t r = 0; s == MLB_OK && r < rows; r++) xs[r] = step[r] + off[stage[r]];
    for (int c = 0; c < nc && s == MLB_OK; c++) {
        // one series per stage over the shared x: other stages' rows are NaN (not drawn)
        mlb_plot_series ser[MAX_STAGES];
        char lab[MAX_STAGES][24];
        int ns = 0, all_pos = 1, any = 0;
        double lo = INFINITY, hi = -INFINITY;
        for (size_t r = 0; r < rows; r++) {
            double v = val[r * nc + c];
            if (!isfinite(v)) continue;
            any = 1;
            if (v <= 0) all_pos = 0;
            if (v < lo) lo = v;
            if (v > hi) hi = v;
        }
        for (int k = 0; k < MAX_STAGES; k++) {
            if (!used[k]) continue;
            double* y = ys + (size_t)ns * (rows ? rows : 1);
            size_t cnt = 0;
            for (size_t r = 0; r < rows; r++) { y[r] = stage[r] == k ? val[r * nc + c] : NAN; cnt += stage[r] == k; }
            if (k < n_names && stage_names[k]) snprintf(lab[ns], sizeof lab[ns], "%s", stage_names[k]);
            else snprintf(lab[ns], sizeof lab[ns], "stage %d", k);
            int sm = (int)(cnt / 50);
            ser[ns] = (mlb_plot_series){xs, y, (int)rows, {0, 0, 0}, lab[ns], sm > 1 ? (sm > 100 ? 100 : sm) : 0};
            mlb_plot_color(k, ser[ns].rgb);
            ns++;
        }
        mlb_plot_opts o = {0};
        o.title = names[c];
        o.xlabel = c == nc - 1 ? "step" : NULL;
        o.log_y = any && all_pos && hi > 100 * lo;
        o.vlines = vl; o.n_vlines = nvl;
        s = mlb_plot_draw(img, W, H, 0, c * PANEL_H, W, PANEL_H, ser, ns, &o);
    }
    if (s == MLB_OK) s = mlb_image_write_png(png_path, img, W, H, 3, NULL);
    free(img); free(xs); free(ys); free(stage); free(step); free(val); free(text);
    return s;
}
