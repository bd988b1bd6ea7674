// Run folders for `matlaber generate` / `fit` (docs/runs.md): the folder itself, its JSON config,
// checkpoints (named float tensors + string/int/double metadata in one safetensors file) and the
// loss log (CSV + plot). Everything is written atomically (mlb_atomic_open/commit or mlb_st_write),
// except the loss log, which is appended a row at a time and rewritten atomically on resume.
//
//   RUN_DIR/config.json                   every setting (mlb_run_write_json), read back on --resume
//   RUN_DIR/checkpoints/<name>.safetensors
//   RUN_DIR/loss.csv, RUN_DIR/loss.png
//   RUN_DIR/previews/*.png
#ifndef MATLABER_RUN_H
#define MATLABER_RUN_H
#include <stddef.h>
#include <stdint.h>
#include <cjson/cJSON.h>
#include "matlaber/error.h"
#include "matlaber/safetensors.h"

#define MLB_RUN_CONFIG "config.json"          // its presence is what makes a folder a run
#define MLB_RUN_JSON_MAX (16u << 20)          // mlb_run_read_json refuses larger files

// ---- the folder ------------------------------------------------------------------------------
// 1 when dir holds a run (dir/config.json is a regular file), else 0.
int mlb_run_exists(const char* dir);
// Creates dir (mkdir -p) and dir/checkpoints, dir/previews.
// Without overwrite: a folder that holds a run → MLB_ERR_ARG "DIR already holds a run (DIR/config.json):
// resume it with --resume or start over with --overwrite"; any other non-empty folder → MLB_ERR_ARG
// "DIR is not empty and is not a run". With overwrite: the run files (config.json, loss.csv,
// loss.png, checkpoints/*.safetensors, previews/*.png, the regular files directly in final/) are
// removed (nothing else is touched) so no stale checkpoint, log row or result is picked up later. A path that exists but is not a folder → MLB_ERR_IO.
mlb_status mlb_run_create(const char* dir, int overwrite);
// For --resume: MLB_OK when dir holds a run; MLB_ERR_NOT_FOUND "DIR: no run to resume (no DIR/config.json)".
mlb_status mlb_run_check_resume(const char* dir);
// out = dir + "/" + rel (one slash); MLB_ERR_ARG when it does not fit in cap bytes (with its NUL).
mlb_status mlb_run_path(char* out, size_t cap, const char* dir, const char* rel);

// ---- JSON ------------------------------------------------------------------------------------
// Pretty-printed, newline-terminated, written atomically.
mlb_status mlb_run_write_json(const char* path, const cJSON* json);
// Reads and parses a whole JSON file (at most MLB_RUN_JSON_MAX bytes); *out (cJSON_Delete it) is
// NULL on failure. Malformed / truncated / trailing garbage → MLB_ERR_FORMAT
// "PATH: malformed JSON at byte B (line L, column C)"; missing → MLB_ERR_NOT_FOUND.
mlb_status mlb_run_read_json(const char* path, cJSON** out);
// Typed fields of a JSON object with errors naming `file` and the key (for config read-back):
// missing → MLB_ERR_NOT_FOUND "FILE: missing 'key'"; wrong type or out of [lo, hi] → MLB_ERR_FORMAT.
mlb_status mlb_json_get_number(const cJSON* obj, const char* key, double lo, double hi, double* out, const char* file);
mlb_status mlb_json_get_int(const cJSON* obj, const char* key, long lo, long hi, long* out, const char* file);  // integral numbers only
mlb_status mlb_json_get_bool(const cJSON* obj, const char* key, int* out, const char* file);
// *out points into obj (valid while obj lives).
mlb_status mlb_json_get_string(const cJSON* obj, const char* key, const char** out, const char* file);

// ---- checkpoint metadata ---------------------------------------------------------------------
// An owned list of string key/value pairs (the safetensors __metadata__), with typed setters and
// getters. Numbers are stored as text that reads back exactly: int64 as "%lld", double as "%.17g"
// ("nan", "inf", "-inf" allowed). Zero-initialise ({0}) before use; mlb_ckpt_meta_free after.
typedef struct {
    mlb_st_meta* kv;     // [n] (key and value strings owned)
    size_t n, cap;
    char* file;          // the file it was loaded from (for messages); NULL when built in memory
} mlb_ckpt_meta;

// Sets (or replaces) key. MLB_ERR_NOMEM, or MLB_ERR_ARG for an empty key.
mlb_status mlb_ckpt_meta_set(mlb_ckpt_meta* m, const char* key, const char* value);
mlb_status mlb_ckpt_meta_set_i64(mlb_ckpt_meta* m, const char* key, int64_t value);
mlb_status mlb_ckpt_meta_set_f64(mlb_ckpt_meta* m, const char* key, double value);
const char* mlb_ckpt_meta_get(const mlb_ckpt_meta* m, const char* key);    // NULL when absent
// MLB_ERR_NOT_FOUND "FILE: checkpoint metadata 'key' missing"; MLB_ERR_FORMAT when not a number.
mlb_status mlb_ckpt_meta_get_i64(const mlb_ckpt_meta* m, const char* key, int64_t* out);
mlb_status mlb_ckpt_meta_get_f64(const mlb_ckpt_meta* m, const char* key, double* out);
void mlb_ckpt_meta_free(mlb_ckpt_meta* m);   // leaves it zeroed; safe on a zeroed one

// ---- checkpoints -----------------------------------------------------------------------------
#define MLB_CKPT_MAX_DIMS 4
typedef struct {
    const char* name;                    // unique, UTF-8
    float* data;                         // nelem floats (save reads it, load fills it)
    int ndim;                            // 0..MLB_CKPT_MAX_DIMS (0 = scalar, 1 element)
    int64_t shape[MLB_CKPT_MAX_DIMS];    // shape[0..ndim-1], each >= 0
} mlb_ckpt_tensor;

// One safetensors file of F32 tensors (in the given order) + meta (NULL = none), atomically.
mlb_status mlb_checkpoint_save(const char* path, const mlb_ckpt_tensor* t, int n, const mlb_ckpt_meta* meta);
// Fills every t[i].data from the file, bit for bit. Before anything is copied it checks that each
// expected tensor is present (MLB_ERR_NOT_FOUND "PATH: checkpoint has no tensor 'x'"), has dtype F32
// and exactly the expected shape (MLB_ERR_FORMAT "PATH: tensor 'x' has shape [2, 3], expected [3, 2]"),
// and that the file has no other tensors (MLB_ERR_FORMAT "PATH: unexpected tensor 'y' ..."), so a
// checkpoint from another configuration is refused as a whole and no data is half-loaded.
// meta_out (may be NULL) receives the file's metadata (free it with mlb_ckpt_meta_free; any old
// content is freed first).
mlb_status mlb_checkpoint_load(const char* path, const mlb_ckpt_tensor* t, int n, mlb_ckpt_meta* meta_out);

// ---- loss log --------------------------------------------------------------------------------
// CSV: header "stage,step,<col1>,...", then one row per logged step: "stage,step,v1,..." with the
// values printed "%.9g" (nan/inf as "nan"/"inf"). Rows are flushed as they are appended.
typedef struct mlb_losslog mlb_losslog;
#define MLB_LOSSLOG_MAX_COLUMNS 32

// Fresh log (resume_stage < 0): the file is (atomically) replaced by the header alone.
// Resume: the existing file must have exactly this header (MLB_ERR_FORMAT otherwise, naming both);
// it is rewritten atomically keeping only the rows before (resume_stage, resume_step) in
// (stage, step) order, i.e. stage < resume_stage, or stage == resume_stage and step < resume_step;
// a torn last line (no newline) is dropped; a malformed row → MLB_ERR_FORMAT "PATH:LINE: ...".
// Then appending the steps from (resume_stage, resume_step) on gives the same bytes as a run that
// was never interrupted. A missing file on resume starts a fresh log (the header alone), so
// resuming at (0, 0) is the same as a fresh log, except that an existing file's header is checked.
// Column names: 1..MLB_LOSSLOG_MAX_COLUMNS, non-empty, no ',', '"', or line breaks.
mlb_status mlb_losslog_open(mlb_losslog** out, const char* path, const char* const* columns, int n_columns,
                            int resume_stage, long resume_step);
// values[n_columns]; MLB_ERR_IO when the write fails.
mlb_status mlb_losslog_append(mlb_losslog* l, int stage, long step, const double* values);
void mlb_losslog_close(mlb_losslog* l);   // NULL is fine
// Re-reads the CSV and draws one panel per column (PNG, 8-bit RGB): x = step, stages laid end to
// end (stage k starts after the last step of stage k-1, boundaries marked by a grey line), one
// colour per stage, raw values light with a moving average on top, log-y when all values are
// positive and span more than two decades. NaN/Inf values are skipped.
mlb_status mlb_losslog_plot(const char* csv_path, const char* png_path);
// The same with the stages' names (stage k: stage_names[k] when k < n_names; the pipeline's plot
// names 0 geometry and 1 appearance).
mlb_status mlb_losslog_plot_named(const char* csv_path, const char* png_path, const char* const* stage_names,
                                  int n_names);

#endif
