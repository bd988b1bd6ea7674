// Run folders, their JSON config and checkpoints (docs/runs.md).
#include "matlaber/run.h"
#include "matlaber/fileio.h"
#include <dirent.h>
#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

// ---- the folder ------------------------------------------------------------------------------
mlb_status mlb_run_path(char* out, size_t cap, const char* dir, const char* rel) {
    if (!out || !cap || !dir || !rel) return mlb_fail(MLB_ERR_ARG, "run path: NULL argument");
    size_t nd = strlen(dir);
    while (nd > 1 && dir[nd - 1] == '/') nd--;
    while (*rel == '/') rel++;
    int sep = nd > 0 && dir[nd - 1] != '/';
    size_t need = nd + (size_t)sep + strlen(rel) + 1;
    if (need > cap) { out[0] = 0; return mlb_fail(MLB_ERR_ARG, "%s/%s: path longer than %zu bytes", dir, rel, cap - 1); }
    memcpy(out, dir, nd);
    if (sep) out[nd] = '/';
    strcpy(out + nd + sep, rel);
    return MLB_OK;
}

int mlb_run_exists(const char* dir) {
    char p[4096];
    if (mlb_run_path(p, sizeof p, dir, MLB_RUN_CONFIG) != MLB_OK) { mlb_clear_error(); return 0; }
    return mlb_is_file(p);
}

mlb_status mlb_run_check_resume(const char* dir) {
    if (!mlb_is_dir(dir)) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no run to resume (no such folder)", dir);
    if (!mlb_run_exists(dir)) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no run to resume (no %s/%s)", dir, dir, MLB_RUN_CONFIG);
    return MLB_OK;
}

// 1 when dir has entries other than . and .., 0 when empty, -1 on error (message set).
static int dir_nonempty(const char* dir) {
    DIR* d = opendir(dir);
    if (!d) { mlb_fail(MLB_ERR_IO, "%s: cannot list the folder: %s", dir, strerror(errno)); return -1; }
    struct dirent* e;
    int any = 0;
    while ((e = readdir(d)) != NULL)
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, "..")) { any = 1; break; }
    closedir(d);
    return any;
}

static mlb_status remove_file(const char* path) {
    if (unlink(path) != 0 && errno != ENOENT) return mlb_fail(MLB_ERR_IO, "%s: cannot remove: %s", path, strerror(errno));
    return MLB_OK;
}

// Removes the regular files in dir/sub whose names end with suffix (nothing else).
static mlb_status remove_matching(const char* dir, const char* sub, const char* suffix) {
    char p[4096], f[4096];
    MLB_TRY(mlb_run_path(p, sizeof p, dir, sub));
    DIR* d = opendir(p);
    if (!d) return errno == ENOENT ? MLB_OK : mlb_fail(MLB_ERR_IO, "%s: cannot list the folder: %s", p, strerror(errno));
    struct dirent* e;
    mlb_status s = MLB_OK;
    while (s == MLB_OK && (e = readdir(d)) != NULL) {
        if (!mlb_ends_with(e->d_name, suffix)) continue;
        s = mlb_run_path(f, sizeof f, p, e->d_name);
        if (s == MLB_OK && mlb_is_file(f)) s = remove_file(f);
    }
    closedir(d);
    return s;
}

mlb_status mlb_run_create(const char* dir, int overwrite) {
    if (!dir || !dir[0]) return mlb_fail(MLB_ERR_ARG, "run folder: empty path");
    struct stat st;
    if (stat(dir, &st) == 0) {
        if (!S_ISDIR(st.st_mode)) return mlb_fail(MLB_ERR_IO, "%s: exists and is not a folder", dir);
        int ne = dir_nonempty(dir);
        if (ne < 0) return MLB_ERR_IO;
        if (ne && !overwrite) {
            if (mlb_run_exists(dir))
                return mlb_fail(MLB_ERR_ARG, "%s already holds a run (%s/%s): resume it with --resume or start over with --overwrite",
                                dir, dir, MLB_RUN_CONFIG);
            return mlb_fail(MLB_ERR_ARG, "%s is not empty and is not a run: choose another folder, or --overwrite to use it anyway", dir);
        }
        if (ne) {   // overwrite: drop the files a later --resume could pick up
            static const char* top[] = {MLB_RUN_CONFIG, "loss.csv", "loss.png"};
            char p[4096];
            for (int i = 0; i < 3; i++) {
                MLB_TRY(mlb_run_path(p, sizeof p, dir, top[i]));
                MLB_TRY(remove_file(p));
            }
            MLB_TRY(remove_matching(dir, "checkpoints", ".safetensors"));
            MLB_TRY(remove_matching(dir, "previews", ".png"));
            MLB_TRY(remove_matching(dir, "final", ""));   // every regular file directly in final/
        }
    }
    MLB_TRY(mlb_mkdir_p(dir));
    char p[4096];
    MLB_TRY(mlb_run_path(p, sizeof p, dir, "checkpoints"));
    MLB_TRY(mlb_mkdir_p(p));
    MLB_TRY(mlb_run_path(p, sizeof p, dir, "previews"));
    MLB_TRY(mlb_mkdir_p(p));
    return MLB_OK;
}

// ---- JSON ------------------------------------------------------------------------------------
mlb_status mlb_run_write_json(const char* path, const cJSON* json) {
    if (!path || !json) return mlb_fail(MLB_ERR_ARG, "write json: NULL argument");
    char* text = cJSON_Print(json);
    if (!text) return mlb_fail(MLB_ERR_NOMEM, "%s: cannot format the JSON (out of memory)", path);
    size_t n = strlen(text);
    char* buf = malloc(n + 2);
    if (!buf) { cJSON_free(text); return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); }
    memcpy(buf, text, n);
    buf[n] = '\n';
    cJSON_free(text);
    mlb_status s = mlb_write_file_atomic(path, buf, n + 1);
    free(buf);
    return s;
}

mlb_status mlb_run_read_json(const char* path, cJSON** out) {
    *out = NULL;
    char* text = NULL;
    size_t n = 0;
    MLB_TRY(mlb_read_file(path, &text, &n, MLB_RUN_JSON_MAX));
    const char* end = NULL;
    cJSON* root = NULL;
    if (memchr(text, 0, n)) end = memchr(text, 0, n);   // cJSON would stop at an embedded NUL
    else root = cJSON_ParseWithLengthOpts(text, n + 1, &end, 1);   // n + 1: include the NUL, require it next
    if (!root) {
        size_t off = end && end >= text && end <= text + n ? (size_t)(end - text) : n;
        size_t line = 1, col = 1;
        for (size_t i = 0; i < off; i++) { if (text[i] == '\n') { line++; col = 1; } else col++; }
        mlb_status s = mlb_fail(MLB_ERR_FORMAT, "%s: malformed JSON at byte %zu (line %zu, column %zu)%s", path, off, line, col,
                                off >= n ? ": the file ends too early (truncated?)" : "");
        free(text);
        return s;
    }
    free(text);
    *out = root;
    return MLB_OK;
}

static const cJSON* get_item(const cJSON* obj, const char* key, const char* file, mlb_status* s) {
    const cJSON* v = cJSON_IsObject(obj) ? cJSON_GetObjectItemCaseSensitive(obj, key) : NULL;
    if (!cJSON_IsObject(obj)) *s = mlb_fail(MLB_ERR_FORMAT, "%s: not a JSON object (looking for '%s')", file, key);
    else if (!v) *s = mlb_fail(MLB_ERR_NOT_FOUND, "%s: missing '%s'", file, key);
    else *s = MLB_OK;
    return v;
}

mlb_status mlb_json_get_number(const cJSON* obj, const char* key, double lo, double hi, double* out, const char* file) {
    mlb_status s;
    const cJSON* v = get_item(obj, key, file, &s);
    if (s) return s;
    if (!cJSON_IsNumber(v) || !(v->valuedouble >= lo && v->valuedouble <= hi))
        return mlb_fail(MLB_ERR_FORMAT, "%s: '%s' is not a number in [%g, %g]", file, key, lo, hi);
    *out = v->valuedouble;
    return MLB_OK;
}

mlb_status mlb_json_get_int(const cJSON* obj, const char* key, long lo, long hi, long* out, const char* file) {
    mlb_status s;
    const cJSON* v = get_item(obj, key, file, &s);
    if (s) return s;
    double d = cJSON_IsNumber(v) ? v->valuedouble : NAN;
    if (!(d >= (double)lo && d <= (double)hi) || d != floor(d))
        return mlb_fail(MLB_ERR_FORMAT, "%s: '%s' is not an integer in [%ld, %ld]", file, key, lo, hi);
    *out = (long)d;
    return MLB_OK;
}

mlb_status mlb_json_get_bool(const cJSON* obj, const char* key, int* out, const char* file) {
    mlb_status s;
    const cJSON* v = get_item(obj, key, file, &s);
    if (s) return s;
    if (!cJSON_IsBool(v)) return mlb_fail(MLB_ERR_FORMAT, "%s: '%s' is not true or false", file, key);
    *out = cJSON_IsTrue(v) ? 1 : 0;
    return MLB_OK;
}

mlb_status mlb_json_get_string(const cJSON* obj, const char* key, const char** out, const char* file) {
    mlb_status s;
    const cJSON* v = get_item(obj, key, file, &s);
    if (s) return s;
    if (!cJSON_IsString(v) || !v->valuestring) return mlb_fail(MLB_ERR_FORMAT, "%s: '%s' is not a string", file, key);
    *out = v->valuestring;
    return MLB_OK;
}

// ---- checkpoint metadata ---------------------------------------------------------------------
static const char* meta_name(const mlb_ckpt_meta* m) { return m->file ? m->file : "checkpoint"; }

mlb_status mlb_ckpt_meta_set(mlb_ckpt_meta* m, const char* key, const char* value) {
    if (!key || !key[0] || !value) return mlb_fail(MLB_ERR_ARG, "checkpoint metadata: empty key or NULL value");
    char* v = strdup(value);
    if (!v) return mlb_fail(MLB_ERR_NOMEM, "checkpoint metadata '%s': out of memory", key);
    for (size_t i = 0; i < m->n; i++)
        if (strcmp(m->kv[i].key, key) == 0) { free((char*)m->kv[i].value); m->kv[i].value = v; return MLB_OK; }
    char* k = strdup(key);
    if (!k) { free(v); return mlb_fail(MLB_ERR_NOMEM, "checkpoint metadata '%s': out of memory", key); }
    if (m->n == m->cap) {
        size_t cap = m->cap ? m->cap * 2 : 16;
        mlb_st_meta* kv = realloc(m->kv, sizeof *kv * cap);
        if (!kv) { free(k); free(v); return mlb_fail(MLB_ERR_NOMEM, "checkpoint metadata '%s': out of memory", key); }
        m->kv = kv; m->cap = cap;
    }
    m->kv[m->n++] = (mlb_st_meta){k, v};
    return MLB_OK;
}

mlb_status mlb_ckpt_meta_set_i64(mlb_ckpt_meta* m, const char* key, int64_t value) {
    char buf[32];
    snprintf(buf, sizeof buf, "%" PRId64, value);
    return mlb_ckpt_meta_set(m, key, buf);
}

mlb_status mlb_ckpt_meta_set_f64(mlb_ckpt_meta* m, const char* key, double value) {
    char buf[40];
    snprintf(buf, sizeof buf, "%.17g", value);
    return mlb_ckpt_meta_set(m, key, buf);
}

const char* mlb_ckpt_meta_get(const mlb_ckpt_meta* m, const char* key) {
    for (size_t i = 0; m && i < m->n; i++) if (strcmp(m->kv[i].key, key) == 0) return m->kv[i].value;
    return NULL;
}

mlb_status mlb_ckpt_meta_get_i64(const mlb_ckpt_meta* m, const char* key, int64_t* out) {
    const char* t = mlb_ckpt_meta_get(m, key);
    if (!t) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: checkpoint metadata '%s' missing", meta_name(m), key);
    char* end;
    errno = 0;
    long long v = strtoll(t, &end, 10);
    if (end == t || *end || errno) return mlb_fail(MLB_ERR_FORMAT, "%s: checkpoint metadata '%s' = '%s' is not an integer", meta_name(m), key, t);
    *out = (int64_t)v;
    return MLB_OK;
}

mlb_status mlb_ckpt_meta_get_f64(const mlb_ckpt_meta* m, const char* key, double* out) {
    const char* t = mlb_ckpt_meta_get(m, key);
    if (!t) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: checkpoint metadata '%s' missing", meta_name(m), key);
    char* end;
    double v = strtod(t, &end);
    if (end == t || *end) return mlb_fail(MLB_ERR_FORMAT, "%s: checkpoint metadata '%s' = '%s' is not a number", meta_name(m), key, t);
    *out = v;
    return MLB_OK;
}

void mlb_ckpt_meta_free(mlb_ckpt_meta* m) {
    if (!m) return;
    for (size_t i = 0; i < m->n; i++) { free((char*)m->kv[i].key); free((char*)m->kv[i].value); }
    free(m->kv);
    free(m->file);
    memset(m, 0, sizeof *m);
}

// ---- checkpoints -----------------------------------------------------------------------------
static void fmt_shape(char* buf, size_t cap, int ndim, const int64_t* shape) {
    size_t k = (size_t)snprintf(buf, cap, "[");
    for (int i = 0; i < ndim && k < cap; i++) k += (size_t)snprintf(buf + k, cap - k, "%s%" PRId64, i ? ", " : "", shape[i]);
    if (k < cap) snprintf(buf + k, cap - k, "]");
}

static mlb_status check_spec(const char* path, const mlb_ckpt_tensor* t, int n) {
    if (n < 0 || (n > 0 && !t)) return mlb_fail(MLB_ERR_ARG, "%s: bad tensor list (n = %d)", path, n);
    for (int i = 0; i < n; i++) {
        if (!t[i].name || !t[i].name[0]) return mlb_fail(MLB_ERR_ARG, "%s: tensor %d has no name", path, i);
        if (t[i].ndim < 0 || t[i].ndim > MLB_CKPT_MAX_DIMS)
            return mlb_fail(MLB_ERR_ARG, "%s: tensor '%s' has rank %d (0..%d supported)", path, t[i].name, t[i].ndim, MLB_CKPT_MAX_DIMS);
        size_t ne = 1;
        for (int d = 0; d < t[i].ndim; d++) {
            if (t[i].shape[d] < 0 || t[i].shape[d] > (int64_t)1 << 40)
                return mlb_fail(MLB_ERR_ARG, "%s: tensor '%s' has a bad dimension %" PRId64, path, t[i].name, t[i].shape[d]);
            ne *= (size_t)t[i].shape[d];
        }
        if (ne && !t[i].data) return mlb_fail(MLB_ERR_ARG, "%s: tensor '%s' has no data", path, t[i].name);
        for (int j = 0; j < i; j++)
            if (strcmp(t[i].name, t[j].name) == 0) return mlb_fail(MLB_ERR_ARG, "%s: tensor name '%s' used twice", path, t[i].name);
    }
    return MLB_OK;
}

// Never a NaN on disk: a run that diverged stops at its checkpoint, naming it.
static mlb_status check_finite(const char* path, const mlb_ckpt_tensor* t, int n) {
    for (int i = 0; i < n; i++) {
        size_t ne = 1;
        for (int d = 0; d < t[i].ndim; d++) ne *= (size_t)t[i].shape[d];
        for (size_t j = 0; j < ne; j++)
            if (!isfinite(t[i].data[j]))
                return mlb_fail(MLB_ERR_NUMERIC, "%s: not written: tensor '%s' holds a NaN or an infinity (element %zu of %zu): "
                                "the run diverged", path, t[i].name, j, ne);
    }
    return MLB_OK;
}

mlb_status mlb_checkpoint_save(const char* path, const mlb_ckpt_tensor* t, int n, const mlb_ckpt_meta* meta) {
    MLB_TRY(check_spec(path, t, n));
    MLB_TRY(check_finite(path, t, n));
    mlb_st_entry* e = malloc(sizeof *e * (n > 0 ? (size_t)n : 1));
    if (!e) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path);
    for (int i = 0; i < n; i++) e[i] = (mlb_st_entry){t[i].name, MLB_DT_F32, t[i].ndim, t[i].shape, t[i].data};
    mlb_status s = mlb_st_write(path, e, (size_t)n, meta ? meta->kv : NULL, meta ? meta->n : 0);
    free(e);
    return s;
}

mlb_status mlb_checkpoint_load(const char* path, const mlb_ckpt_tensor* t, int n, mlb_ckpt_meta* meta_out) {
    MLB_TRY(check_spec(path, t, n));
    mlb_safetensors* st = NULL;
    MLB_TRY(mlb_st_open(&st, path));
    mlb_status s = MLB_OK;
    char a[160], b[160];
    // check everything before copying anything
    for (int i = 0; i < n && s == MLB_OK; i++) {
        const mlb_st_tensor* x = mlb_st_find(st, t[i].name);
        if (!x) { s = mlb_fail(MLB_ERR_NOT_FOUND, "%s: checkpoint has no tensor '%s'", path, t[i].name); break; }
        if (x->dtype != MLB_DT_F32) { s = mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' is %s, expected F32", path, t[i].name, mlb_dtype_name(x->dtype)); break; }
        int same = x->ndim == t[i].ndim;
        for (int d = 0; same && d < x->ndim; d++) same = x->shape[d] == t[i].shape[d];
        if (!same) {
            fmt_shape(a, sizeof a, x->ndim, x->shape);
            fmt_shape(b, sizeof b, t[i].ndim, t[i].shape);
            s = mlb_fail(MLB_ERR_FORMAT, "%s: tensor '%s' has shape %s, expected %s", path, t[i].name, a, b);
        }
        if (!s) s = mlb_st_check_finite(st, x);   // a NaN resumed would be carried into every file after it
    }
    for (size_t k = 0; s == MLB_OK && k < mlb_st_count(st); k++) {
        const mlb_st_tensor* x = mlb_st_tensor_at(st, k);
        int known = 0;
        for (int i = 0; i < n && !known; i++) known = strcmp(x->name, t[i].name) == 0;
        if (!known) s = mlb_fail(MLB_ERR_FORMAT, "%s: unexpected tensor '%s' (the checkpoint was written with another configuration?)", path, x->name);
    }
    for (int i = 0; i < n && s == MLB_OK; i++) {
        const mlb_st_tensor* x = mlb_st_find(st, t[i].name);
        if (x->nbytes) memcpy(t[i].data, x->data, x->nbytes);
    }
    if (s == MLB_OK && meta_out) {
        mlb_ckpt_meta_free(meta_out);
        meta_out->file = strdup(path);
        if (!meta_out->file) s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path);
        for (size_t i = 0; s == MLB_OK && i < mlb_st_metadata_count(st); i++) {
            const char *k, *v;
            if (mlb_st_metadata_at(st, i, &k, &v) == 0) s = mlb_ckpt_meta_set(meta_out, k, v);
        }
        if (s) mlb_ckpt_meta_free(meta_out);
    }
    mlb_st_close(st);
    return s;
}
