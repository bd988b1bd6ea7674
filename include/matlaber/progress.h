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
} mlb_progress;

void mlb_progress_begin(mlb_progress* p, FILE* out, const char* label, long total, const char* unit);
// `status` is an optional short text appended to the line ("loss 0.0123").
void mlb_progress_update(mlb_progress* p, long done, const char* status);
void mlb_progress_end(mlb_progress* p, const char* status);
double mlb_now_seconds(void);   // monotonic clock
// "1h02m", "3m05s", "12.3s" into buf
const char* mlb_format_duration(double seconds, char* buf, int n);

#endif
