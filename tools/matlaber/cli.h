// Shared helpers of the command-line program.
#ifndef MATLABER_CLI_H
#define MATLABER_CLI_H
#include <getopt.h>
#include <stdint.h>
#include <stdio.h>
#include "matlaber/error.h"

#define EXIT_USAGE 2

// "matlaber: error: <what>: <library message>"; returns 1 (the exit code for failures).
int cli_fail(mlb_status s, const char* what);
// The message of this thread's last cli_fail or cli_usage_error; with quiet on they print nothing
// (matlaber serve checks a job's options and answers with the message).
const char* cli_last_message(void);
void cli_set_quiet(int on);
// Usage errors: message + hint to --help; returns EXIT_USAGE.
int cli_usage_error(const char* command, const char* fmt, ...) __attribute__((format(printf, 2, 3)));
// Every argument of the command line (a path, a prompt, a name, --set KEY=VALUE) has at most this many
// bytes (the run's config.json fields hold as much): a longer one is refused, never cut
// (docs/files.md). Returns EXIT_USAGE naming the argument's place or option, 0 when all fit.
#define CLI_MAX_ARG 1023
int cli_check_args(int argc, char** argv);
// Comma-separated numbers into out[n]; exactly n values, all finite. 0 on success.
int cli_parse_floats(const char* text, float* out, int n);
int cli_parse_long(const char* text, long lo, long hi, long* out);
// A decimal integer in 0..2^64-1 (no sign; overflow refused, not clamped). 0 on success.
int cli_parse_u64(const char* text, uint64_t* out);
int cli_parse_double(const char* text, double lo, double hi, double* out);
// ../shared/data beside the source tree, or $MLB_SHARED_DATA; NULL when absent.
const char* cli_shared_data(void);
// The project's own diffusion model (docs/sd_train.md): $MATLABER_MODEL, else models/matlaber-tiny of
// the source tree when it holds a finished model; NULL when neither.
#define MLB_DEFAULT_MODEL "matlaber-tiny"
const char* cli_default_model(void);
// The appearance stage's model that goes with it (docs/pipeline.md, "A model per stage"; used only
// where no -m was given): $MATLABER_APPEARANCE_MODEL, else none when $MATLABER_MODEL names another
// model, else models/matlaber-tiny-appearance when it is there. NULL: none (one model guides both
// stages).
#define MLB_DEFAULT_APPEARANCE_MODEL "matlaber-tiny-appearance"
const char* cli_default_appearance_model(void);
// The op table a run's models and stages use (mlb_pipeline_make_guidance, mlb_pipeline_run): the
// program's --device, with its GEMMs at the program's --precision when one was given, else at the
// run's own (config.json "precision", e.g. the cpu preset's bf16) when it names one, else at the
// program's default. The one place the program's device and precision reach a run.
struct mlb_backend;
const struct mlb_backend* cli_run_backend(const char* run_precision);
// Shown in --help: the getopt option table as "  --name ARG  help".
typedef struct { const char* name; int has_arg; int val; const char* arg; const char* help; } cli_option;
void cli_print_options(FILE* out, const cli_option* opts);
// Converts cli_option[] into a struct option[] for getopt_long (static storage, up to 64).
const struct option* cli_getopt_table(const cli_option* opts);

int cmd_brdf(int argc, char** argv);
int cmd_bench(int argc, char** argv);
int cmd_catalogue(int argc, char** argv);
int cmd_demo(int argc, char** argv);
// matlaber demo without --fit (cmd_demo_text.c)
int demo_text_main(const char* out, uint64_t seed, int quick, const char* cls, const char* mat);
int cmd_device(int argc, char** argv);
int cmd_geometry(int argc, char** argv);
int cmd_render(int argc, char** argv);
int cmd_relight(int argc, char** argv);
int brdf_swatch_main(int argc, char** argv);
int cmd_sd(int argc, char** argv);
int sd_train_main(int argc, char** argv);
int cmd_generate(int argc, char** argv);
// Set by a command whose exit status every process agreed on (mpirun): main then ends normally
// instead of aborting the other processes
extern int cli_rc_agreed;
// generate's option table: 1 when --name takes a value, 0 when not, -1 when generate has no such option
int generate_option_arity(const char* name);
// generate without progress bars or closing message (--prompts); GENERATE_STOPPED when the run
// stopped at --stop-after
#define GENERATE_STOPPED 3
int generate_run_quiet(int argc, char** argv);
// generate's checks alone, nothing but a paint mesh loaded, nothing written: 0 when `generate
// argv...` (or paint, when argv[0] is "paint") would start, else the exit status it would end with
// (the reason in cli_last_message). Not reentrant (getopt).
int generate_check_args(int argc, char** argv);
int cmd_serve(int argc, char** argv);
// matlaber generate --prompts FILE -o DIR (cmd_prompts.c)
int generate_prompts_main(int argc, char** argv);
int cmd_fit(int argc, char** argv);
// matlaber catalogue measure (cmd_catalogue_measure.c)
int catalogue_measure(int argc, char** argv);
int cmd_paint(int argc, char** argv);
int cmd_relight_run(int argc, char** argv);
int cmd_interp(int argc, char** argv);
int cmd_export(int argc, char** argv);
int cmd_view(int argc, char** argv);
// DIR/frame_%04d.png → DIR/<name> with ffmpeg when it is installed (a log line either way).
void cli_frames_to_mp4(const char* dir, const char* name);

#endif
