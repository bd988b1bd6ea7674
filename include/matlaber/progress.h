// Progress of long work: a bar with rate and ETA when `out` is a terminal, plain periodic lines
// otherwise (logs, CI). The caller owns `out`; library functions take an mlb_progress* that may
// be NULL (silent).
#ifndef MATLABER_PROGRESS_H
#define MATLABER_PROGRESS_H
#include <stdio.h>

typedef struct {
    FILE* out;            // NULL: silent
    char label[48];
    long total;           // units of work (steps, samples)
    const char* unit;     // "step", "sample", ...
    int is_tty;
    double t_start;       // seconds, monotonic
    double t_last;        // last time something was printed
    double plain_every;   // seconds between plain lines (default 10)
    long done;
    long base;            // units done before this invocation (a resumed run): not counted in the rate
    FILE* json;           // the JSON stream when mlb_progress_set_json was given one at begin
} mlb_progress;

// Machine-readable progress (the program's --progress json; docs/paint.md "Progress stream"): once set,
// every mlb_progress writes one JSON object per line to `f` instead of its bar or plain lines:
//   {"event":"begin","label":L,"total":N,"unit":U}
//   {"event":"progress","label":L,"done":D,"total":N,"fraction":F,"elapsed_s":E,"eta_s":T,"rate":R,"status":S}
//   {"event":"end","label":L,"done":N,"total":N,"elapsed_s":E,"status":S}
// "progress" lines come at most every 0.2 s (and always for the last unit); eta_s is -1 while unknown.
// NULL turns it off. Not thread-safe: set it once at start-up.
void mlb_progress_set_json(FILE* f);
FILE* mlb_progress_json(void);   // the stream, or NULL
// s as a JSON string literal (quotes, escapes; control characters as \u00XX) to f.
void mlb_json_write_string(FILE* f, const char* s);

void mlb_progress_begin(mlb_progress* p, FILE* out, const char* label, long total, const char* unit);
// `status` is an optional short text appended to the line ("loss 0.0123").
void mlb_progress_update(mlb_progress* p, long done, const char* status);
void mlb_progress_end(mlb_progress* p, const char* status);
double mlb_now_seconds(void);   // monotonic clock
// "1h02m", "3m05s", "12.3s" into buf
const char* mlb_format_duration(double seconds, char* buf, int n);

#endif
