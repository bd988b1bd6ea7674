// Progress in stages (progress.h): a bar on a terminal, periodic plain lines in logs, or JSON lines;
// one ETA rule for all three.
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

// Steps a measurement needs after the stage's first step (whose set-up it leaves out)
enum { MEASURE_STEPS = 2 };

static mlb_progress_stage* running(mlb_progress* p) { return p && p->cur >= 0 && p->cur < p->n_stages ? &p->st[p->cur] : NULL; }

static void stage_init(mlb_progress_stage* s, const char* name, long steps, double weight) {
    memset(s, 0, sizeof *s);
    snprintf(s->name, sizeof s->name, "%s", name ? name : "");
    s->steps = steps > 0 ? steps : 0;
    s->weight = weight > 0 ? weight : 0;
    s->mark = -1;
}

static long steps_before(const mlb_progress* p, int i) {
    long n = 0;
    for (int k = 0; k < i && k < p->n_stages; k++) n += p->st[k].steps;
    return n;
}

// The running stage's seconds per step from the steps after its first; a stage that ends before
// that is measured on what it did (its set-up included: better than nothing to predict by).
static void measure(mlb_progress_stage* s, double t, int ending) {
    if (s->mark < 0 && s->done > s->first) {
        s->mark = s->done;
        s->t_mark = t;
    } else if (s->mark >= 0 && s->done - s->mark >= MEASURE_STEPS) {
        s->per_step = (t - s->t_mark) / (double)(s->done - s->mark);
    }
    if (ending && s->per_step <= 0) {
        if (s->mark >= 0 && s->done > s->mark) s->per_step = (t - s->t_mark) / (double)(s->done - s->mark);
        else if (s->done > s->first) s->per_step = (t - s->t_enter) / (double)(s->done - s->first);
    }
}

// Seconds per unit of weight: the latest measured stage's with a weight, 0 when none is.
static double seconds_per_weight(const mlb_progress* p) {
    double unit = 0;
    for (int i = 0; i <= p->cur && i < p->n_stages; i++)
        if (p->st[i].per_step > 0 && p->st[i].weight > 0) unit = p->st[i].per_step / p->st[i].weight;
    return unit;
}

static double step_cost(const mlb_progress_stage* s, double unit) {
    if (s->per_step > 0) return s->per_step;
    return s->weight > 0 && unit > 0 ? s->weight * unit : -1;
}

// The seconds left, split into what the stages' own steps measured and what their weights predict;
// 0 when something ahead is not known.
static int seconds_left(const mlb_progress* p, double* measured_out, double* predicted_out) {
    if (!p || p->cur < 0) return 0;
    double unit = seconds_per_weight(p), measured = 0, predicted = 0;
    for (int i = p->cur; i < p->n_stages; i++) {
        const mlb_progress_stage* s = &p->st[i];
        long n = s->steps - (i == p->cur ? s->done : 0);
        if (n <= 0) continue;
        double c = step_cost(s, unit);
        if (c < 0) return 0;   // a stage ahead nothing predicts yet
        if (s->per_step > 0) measured += (double)n * c;
        else predicted += (double)n * c;
    }
    *measured_out = measured;
    *predicted_out = predicted;
    return 1;
}

// The weights are one machine's and one setting's ratios, off by 2x or more elsewhere. The ETA shows
// first when the measured part of what is left is at least half the predicted part: a weight off by
// r then errs by at most (1 + 2r) / 3 (2x for r = 2.5) instead of r. Once shown it stays (the
// measured part shrinks as the stage runs; an ETA that came and went would say less).
static int growing(const mlb_progress* p) { return p->cur >= 0 && p->cur < p->n_stages && p->st[p->cur].may_grow; }

static void eta_gate(mlb_progress* p) {
    double m, q;
    if (!p->eta_shown && !growing(p) && seconds_left(p, &m, &q) && q <= 2 * m) p->eta_shown = 1;
}

double mlb_progress_eta(const mlb_progress* p) {
    double m, q;
    if (!seconds_left(p, &m, &q)) return -1;
    return p->eta_shown || (q <= 2 * m && !growing(p)) ? m + q : -1;
}

double mlb_progress_stage_eta(const mlb_progress* p) {
    const mlb_progress_stage* s = p && p->cur >= 0 && p->cur < p->n_stages ? &p->st[p->cur] : NULL;
    return s && s->per_step > 0 ? (double)(s->steps - s->done) * s->per_step : -1;
}

double mlb_progress_rate(const mlb_progress* p) {
    const mlb_progress_stage* s = p && p->cur >= 0 && p->cur < p->n_stages ? &p->st[p->cur] : NULL;
    return s && s->per_step > 0 ? 1.0 / s->per_step : 0;
}

// The share of the work done: steps weighted by their cost in seconds where every stage's is known,
// else by their weights (a stage without one counts nothing: counting its steps made the bar fall
// back once the costs were known).
static double fraction(const mlb_progress* p) {
    double unit = seconds_per_weight(p), all = 0, done = 0;
    for (int i = 0; i < p->n_stages; i++)
        if (unit > 0 && step_cost(&p->st[i], unit) < 0) unit = 0;
    for (int i = 0; i < p->n_stages; i++) {
        double c = unit > 0 ? step_cost(&p->st[i], unit) : p->n_stages == 1 ? 1.0 : p->st[i].weight;
        all += c * (double)p->st[i].steps;
        done += c * (double)(i < p->cur ? p->st[i].steps : i == p->cur ? p->st[i].done : 0);
    }
    return all > 0 ? done / all : 0;
}

static int multi(const mlb_progress* p) { return p->n_stages > 1; }

static void json_stage_fields(mlb_progress* p) {
    mlb_progress_stage* s = running(p);
    if (!s) return;
    fputs(",\"stage\":", p->json);
    mlb_json_write_string(p->json, s->name);
    fprintf(p->json, ",\"index\":%d,\"stages\":%d", p->cur, p->n_stages);
}

// One JSON line (progress.h): the event, the counts, the times, the status.
static void progress_json(mlb_progress* p, const char* event, const char* status) {
    double t = mlb_now_seconds(), elapsed = t - p->t_start;
    FILE* f = p->json;
    fprintf(f, "{\"event\":\"%s\",\"label\":", event);
    mlb_json_write_string(f, p->label);
    if (!strcmp(event, "begin")) {
        fprintf(f, ",\"total\":%ld,\"unit\":", p->total);
        mlb_json_write_string(f, p->unit);
    } else if (!strcmp(event, "plan")) {
        fputs(",\"stages\":[", f);
        for (int i = 0; i < p->n_stages; i++) {
            fputs(i ? ",{\"name\":" : "{\"name\":", f);
            mlb_json_write_string(f, p->st[i].name);
            fprintf(f, ",\"steps\":%ld}", p->st[i].steps);
        }
        fputc(']', f);
    } else if (!strcmp(event, "stage")) {
        json_stage_fields(p);
        fprintf(f, ",\"steps\":%ld,\"done\":%ld", p->st[p->cur].steps, p->st[p->cur].done);
    } else {
        if (!strcmp(event, "progress")) {
            json_stage_fields(p);
            mlb_progress_stage* s = running(p);
            if (s) fprintf(f, ",\"stage_done\":%ld,\"stage_steps\":%ld", s->done, s->steps);
        }
        fprintf(f, ",\"done\":%ld,\"total\":%ld,\"fraction\":%.4f,\"elapsed_s\":%.2f", p->done, p->total, fraction(p),
                elapsed);
        if (!strcmp(event, "progress"))
            fprintf(f, ",\"rate\":%.4g,\"eta_s\":%.1f,\"stage_eta_s\":%.1f", mlb_progress_rate(p), mlb_progress_eta(p),
                    mlb_progress_stage_eta(p));
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
    p->show_status = 1;
    p->n_stages = 1;
    stage_init(&p->st[0], p->label, p->total, 1.0);
    p->st[0].t_enter = p->t_start;
    if (p->json) progress_json(p, "begin", NULL);
}

void mlb_progress_plan(mlb_progress* p, int n, const char* const* names, const long* steps, const double* weights) {
    if (!p || n < 1) return;
    if (n > MLB_PROGRESS_MAX_STAGES) n = MLB_PROGRESS_MAX_STAGES;
    p->n_stages = n;
    p->cur = -1;
    p->total = 0;
    for (int i = 0; i < n; i++) {
        stage_init(&p->st[i], names[i], steps[i], weights ? weights[i] : 1.0);
        p->total += p->st[i].steps;
    }
    if (p->total < 1) p->total = 1;
    if (p->json) progress_json(p, "plan", NULL);
}

static void print_line(mlb_progress* p, const char* status, int final);

void mlb_progress_enter(mlb_progress* p, int i, long done) {
    if (!p || i < 0 || i >= p->n_stages) return;
    double t = mlb_now_seconds();
    for (int k = p->cur < 0 ? 0 : p->cur; k < i; k++) {   // the stages before it are over
        if (k == p->cur) measure(&p->st[k], t, 1);
        p->st[k].done = p->st[k].steps;
    }
    p->cur = i;
    mlb_progress_stage* s = &p->st[i];
    s->done = s->first = done < 0 ? 0 : done > s->steps ? s->steps : done;
    s->t_enter = t;
    s->mark = -1;
    p->step_offset = 0;
    p->done = steps_before(p, i) + s->done;
    if (s->steps == 0) return;   // a stage this run skips (fit's material start): nothing to announce
    if (p->json) progress_json(p, "stage", NULL);
    else if (p->out && !p->is_tty) {   // a line per stage in logs
        fprintf(p->out, "%s: %s (stage %d of %d, %ld step%s)\n", p->label, s->name, i + 1, p->n_stages, s->steps,
                s->steps == 1 ? "" : "s");
        fflush(p->out);
    }
}

void mlb_progress_stage_steps(mlb_progress* p, long steps) {
    mlb_progress_stage* s = running(p);
    if (!s || steps < s->done) return;
    p->total += steps - s->steps;
    s->steps = steps;
}

void mlb_progress_stage_may_grow(mlb_progress* p, int i) {
    if (p && i >= 0 && i < p->n_stages) p->st[i].may_grow = 1;
}

static void print_line(mlb_progress* p, const char* status, int final) {
    double t = mlb_now_seconds(), elapsed = t - p->t_start;
    double eta = final ? elapsed : mlb_progress_eta(p), frac = final ? 1.0 : fraction(p), rate = mlb_progress_rate(p);
    mlb_progress_stage* s = running(p);
    long done = p->done, total = p->total;
    char stage[64] = "", eta_s[48] = "", el_s[32];
    if (multi(p) && s && !final) {   // the stage and its own steps
        snprintf(stage, sizeof stage, " %s", s->name);
        done = s->done;
        total = s->steps;
    }
    if (final) snprintf(eta_s, sizeof eta_s, "took %s", mlb_format_duration(elapsed, el_s, sizeof el_s));
    else if (eta >= 0) snprintf(eta_s, sizeof eta_s, "ETA %s", mlb_format_duration(eta, el_s, sizeof el_s));
    else if (multi(p) && mlb_progress_stage_eta(p) >= 0)   // the stage's own end, sound from its steps
        snprintf(eta_s, sizeof eta_s, "stage ends in %s", mlb_format_duration(mlb_progress_stage_eta(p), el_s, sizeof el_s));
    mlb_format_duration(elapsed, el_s, sizeof el_s);
    char rate_s[48] = "";
    if (rate > 0 && !final) snprintf(rate_s, sizeof rate_s, "%.3g %s/s", rate, p->unit);
    if (p->is_tty) {
        char bar[31];
        int filled = (int)(frac * 30 + 0.5);
        for (int i = 0; i < 30; i++) bar[i] = i < filled ? '#' : '-';
        bar[30] = 0;
        fprintf(p->out, "\r\033[K%s%s [%s] %3.0f%% %ld/%ld %s %s%s%s", p->label, stage, bar, 100 * frac, done, total,
                rate_s, eta_s, status ? "  " : "", status ? status : "");
        if (final) fputc('\n', p->out);
    } else {
        fprintf(p->out, "%s:%s %ld/%ld (%.0f%%%s)%s%s%s%s%s%s%s%s\n", p->label, stage, done, total, 100 * frac,
                stage[0] ? " of the run" : "", rate_s[0] ? " " : "", rate_s, eta_s[0] ? ", " : "", eta_s,
                final ? "" : ", elapsed ", final ? "" : el_s, status ? ", " : "", status ? status : "");
    }
    fflush(p->out);
    p->t_last = t;
}

void mlb_progress_update(mlb_progress* p, long done, const char* status) {
    if (!p) return;
    if (p->cur < 0) mlb_progress_enter(p, 0, 0);   // a plan whose first stage was not named
    mlb_progress_stage* s = running(p);
    if (p->n_stages == 1) {   // the old single-stage callers set total and base themselves
        s->steps = p->total;
        if (s->mark < 0 && s->first < p->base) s->first = s->done = p->base;
    }
    done += p->step_offset;
    if (!p->show_status) status = NULL;
    s->done = done < 0 ? 0 : done > s->steps ? s->steps : done;
    p->done = steps_before(p, p->cur) + s->done;
    double t = mlb_now_seconds();
    measure(s, t, 0);
    eta_gate(p);
    const int last = s->done >= s->steps;
    if (p->json) {
        if (t - p->t_last >= 0.2 || last) progress_json(p, "progress", status);
        return;
    }
    if (!p->out) return;   // silent: measured all the same (mlb_progress_eta)
    double every = p->is_tty ? 0.1 : p->plain_every;
    if (t - p->t_last >= every) print_line(p, status, 0);
}

void mlb_progress_end(mlb_progress* p, const char* status) {
    if (!p) return;
    mlb_progress_stage* s = running(p);
    if (s) measure(s, mlb_now_seconds(), 1);
    if (p->json) {   // done stays what it was: a stopped run ends short of its total
        progress_json(p, "end", status);
        return;
    }
    if (!p->out) return;
    p->done = p->total;
    print_line(p, status, 1);
}
