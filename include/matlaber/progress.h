// Progress of long work: a bar with rate and ETA when `out` is a terminal, plain periodic lines
// otherwise (logs, CI), or JSON lines (--progress json). The caller owns `out`; library functions
// take an mlb_progress* that may be NULL (silent).
//
// Work goes in stages (the pipeline's: shape start, geometry, material start, appearance, export),
// each with its steps and an estimate of one step's cost relative to the other stages'. The ETA is
// the remaining steps of every stage times that stage's seconds per step: measured on the stage's own
// steps once two have been taken after its first (the first carries one-time set-up), else the
// stage's weight times the seconds per unit of weight of the latest measured stage. There is no ETA
// (eta_s -1, none printed) until a stage with a weight has been measured, while a stage ahead has no
// weight to predict it by, and until the predicted part of what is left is at most twice the
// measured part (a guess from the set-up's time was off by 20x); the running stage's own end is
// known sooner.
#ifndef MATLABER_PROGRESS_H
#define MATLABER_PROGRESS_H
#include <stdio.h>

#define MLB_PROGRESS_MAX_STAGES 6

typedef struct {
    char name[24];
    long steps;         // planned (may grow while the stage runs: mlb_progress_stage_steps)
    double weight;      // estimated cost of one step relative to the other stages'; 0: not predictable
    long done;          // steps done
    long first;         // steps done when it started (a resumed run's), at t_enter
    double t_enter;
    long mark;          // steps done at t_mark (the end of the first step this process took), -1: none yet
    double t_mark;
    double per_step;    // measured seconds per step, 0 until measured
    int may_grow;       // may add steps dearer than its measured ones (mlb_progress_stage_may_grow)
} mlb_progress_stage;

typedef struct {
    FILE* out;            // NULL: silent
    char label[48];
    long total;           // units of work (steps, samples) of all stages
    const char* unit;     // "step", "sample", ...
    int is_tty;
    double t_start;       // seconds, monotonic
    double t_last;        // last time something was printed
    double plain_every;   // seconds between plain lines (default 10)
    long done;            // units done, all stages
    long base;            // units done before this invocation (a resumed run): not measured
    FILE* json;           // the JSON stream when mlb_progress_set_json was given one at begin
    int n_stages, cur;    // the plan (begin: one stage named by the label); cur: the running one
    long step_offset;     // added to the `done` of updates (a stage made of several counted parts)
    int show_status;      // 1 (begin's default): the updates' status texts are printed; 0: left out
    int eta_shown;        // the ETA passed its first test (progress.c, eta_gate) and is shown from then on
    mlb_progress_stage st[MLB_PROGRESS_MAX_STAGES];
} mlb_progress;

// Machine-readable progress (the program's --progress json; docs/usage.md "Progress"): once set,
// every mlb_progress writes one JSON object per line to `f` instead of its bar or plain lines:
//   {"event":"begin","label":L,"total":N,"unit":U}
//   {"event":"plan","label":L,"stages":[{"name":S,"steps":N},...]}
//   {"event":"stage","label":L,"stage":S,"index":I,"stages":K,"steps":N,"done":D}
//   {"event":"progress","label":L,"stage":S,"index":I,"stages":K,"stage_done":d,"stage_steps":n,
//    "done":D,"total":N,"fraction":F,"elapsed_s":E,"rate":R,"eta_s":T,"stage_eta_s":U[,"status":S]}
//   {"event":"end","label":L,"done":D,"total":N,"elapsed_s":E,"status":S}
// "progress" lines come at most every 0.2 s (and always for a stage's last step); rate is the
// stage's measured steps per second (0 until measured), eta_s -1 while unknown (see above),
// stage_eta_s the running stage's seconds left (-1 until measured); fraction the share of the work
// done, by the stages' costs.
// NULL turns it off. Not thread-safe: set it once at start-up.
void mlb_progress_set_json(FILE* f);
FILE* mlb_progress_json(void);   // the stream, or NULL
// s as a JSON string literal (quotes, escapes; control characters as \u00XX) to f.
void mlb_json_write_string(FILE* f, const char* s);

// One stage named by the label, `total` units of weight 1.
void mlb_progress_begin(mlb_progress* p, FILE* out, const char* label, long total, const char* unit);
// Replaces the plan with n stages (n <= MLB_PROGRESS_MAX_STAGES); none runs until mlb_progress_enter.
void mlb_progress_plan(mlb_progress* p, int n, const char* const* names, const long* steps, const double* weights);
// Stage i starts (the ones before it are over), `done` of its steps already done (a resumed run).
void mlb_progress_enter(mlb_progress* p, int i, long done);
// The running stage's planned steps change (a choice that looks further ahead than planned).
void mlb_progress_stage_steps(mlb_progress* p, long steps);
// Stage i may add steps that cost more than the ones it measures (the material start's close call
// scores on 4x the views): no first ETA while it runs (one shown before stays).
void mlb_progress_stage_may_grow(mlb_progress* p, int i);
// `done`: steps of the running stage (plus step_offset); `status` an optional short text appended
// to the line ("loss 0.0123").
void mlb_progress_update(mlb_progress* p, long done, const char* status);
void mlb_progress_end(mlb_progress* p, const char* status);
// Seconds left (-1: not known yet) and the running stage's measured steps per second (0: not yet).
double mlb_progress_eta(const mlb_progress* p);
double mlb_progress_rate(const mlb_progress* p);
// Seconds left in the running stage from its own measured steps (-1: not measured yet).
double mlb_progress_stage_eta(const mlb_progress* p);
double mlb_now_seconds(void);   // monotonic clock
// "1h02m", "3m05s", "12.3s" into buf
const char* mlb_format_duration(double seconds, char* buf, int n);

#endif
