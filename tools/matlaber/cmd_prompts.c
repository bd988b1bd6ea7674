// matlaber generate --prompts FILE -o DIR: many assets, one run folder per prompt (docs/pipeline.md,
// "Many processes"). Every process walks the list in order and takes the next prompt nobody has
// taken (an O_EXCL claim file in DIR/.claims/<this job>/), so prompts go to processes as they free
// up, with no coordinator and nothing but a shared folder. A finished run (its batch.json says so)
// is skipped, a stopped or killed one resumed: rerunning the same command finishes what is missing.
// At the end rank 0 prints a table and writes DIR/summary.json.
#include <cjson/cJSON.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include "cli.h"
#include "matlaber/dist.h"
#include "matlaber/error.h"
#include "matlaber/fileio.h"
#include "matlaber/log.h"
#include "matlaber/pipeline.h"
#include "matlaber/progress.h"
#include "matlaber/prompts.h"

enum { PATH_CAP = 4096 };
enum { ST_NONE = 0, ST_DONE, ST_RESUMED, ST_SKIPPED, ST_STOPPED, ST_FAILED };
static const char* const STATUS[] = {"-", "done", "resumed", "skipped", "stopped", "failed"};

typedef mlb_prompt item;

// What one process did with one prompt (gathered to rank 0 at the end).
typedef struct {
    int32_t index, status, rank, pad;
    double seconds;
} record;

// The options a prompt line may set: generate's, less those that name the job's own files and flow.
static int line_option_arity(const char* name) {
    static const char* const refused[] = {"out", "resume", "prompts", "prompt", "help", "stop-after", NULL};
    for (const char* const* r = refused; *r; r++)
        if (!strcmp(name, *r)) return -1;
    return generate_option_arity(name);
}

// DIR/name/batch.json: {"status", "seconds", "prompt"}; the status of a run an earlier job finished.
static int read_batch(const char* dir, double* seconds) {
    char path[PATH_CAP];
    snprintf(path, sizeof path, "%s/batch.json", dir);
    char* text = NULL;
    size_t n = 0;
    *seconds = 0;
    if (!mlb_is_file(path) || mlb_read_file(path, &text, &n, 1 << 20)) return ST_NONE;
    cJSON* j = cJSON_Parse(text);
    free(text);
    int st = ST_NONE;
    const cJSON* s = cJSON_GetObjectItem(j, "status");
    const cJSON* t = cJSON_GetObjectItem(j, "seconds");
    if (cJSON_IsString(s) && (!strcmp(s->valuestring, "done") || !strcmp(s->valuestring, "resumed"))) st = ST_DONE;
    if (cJSON_IsNumber(t)) *seconds = t->valuedouble;
    cJSON_Delete(j);
    return st;
}

static void write_batch(const char* dir, const item* it, int status, double seconds) {
    char path[PATH_CAP];
    snprintf(path, sizeof path, "%s/batch.json", dir);
    cJSON* j = cJSON_CreateObject();
    cJSON_AddStringToObject(j, "prompt", it->prompt);
    cJSON_AddStringToObject(j, "status", STATUS[status]);
    cJSON_AddNumberToObject(j, "seconds", seconds);
    char* text = cJSON_Print(j);
    cJSON_Delete(j);
    mlb_atomic_file af;
    if (text && !mlb_atomic_open(&af, path)) {
        fprintf(af.f, "%s\n", text);
        if (mlb_atomic_commit(&af)) mlb_log(MLB_LOG_WARN, "%s: %s", path, mlb_last_error());
    }
    free(text);
}

// One prompt in this process alone: a new run, or --resume of a run that has a config.json.
static int run_item(const item* it, const char* out, int argc, char** argv, const char* stop_after, int* resumed) {
    char dir[PATH_CAP], cfg[PATH_CAP + 16];
    snprintf(dir, sizeof dir, "%s/%s", out, it->name);
    snprintf(cfg, sizeof cfg, "%s/config.json", dir);
    // every word of the command line, the line's options and at most 7 of our own, and the NULL
    char** args = malloc(sizeof(char*) * ((size_t)argc + (size_t)it->n_opts + 8));
    if (!args) return cli_fail(mlb_fail(MLB_ERR_NOMEM, "out of memory"), "--prompts");
    int n = 0;
    args[n++] = "generate";
    *resumed = mlb_is_file(cfg);
    if (*resumed) {
        args[n++] = "--resume";
        args[n++] = dir;
    } else {
        // the command line's options (less --prompts, -o, --stop-after), then the line's
        for (int i = 1; i < argc; i++) {
            const char* a = argv[i];
            if (!strcmp(a, "--prompts") || !strcmp(a, "-o") || !strcmp(a, "--out") || !strcmp(a, "--stop-after")) { i++; continue; }
            if (!strncmp(a, "--prompts=", 10) || !strncmp(a, "--out=", 6) || !strncmp(a, "--stop-after=", 13)) continue;
            args[n++] = argv[i];
        }
        for (int i = 0; i < it->n_opts; i++) args[n++] = it->opts[i];
        args[n++] = "-p";
        args[n++] = it->prompt;
        args[n++] = "-o";
        args[n++] = dir;
    }
    if (stop_after) {
        args[n++] = "--stop-after";
        args[n++] = (char*)stop_after;
    }
    args[n] = NULL;
    int was = mlb_dist_solo(1);   // this process alone: a group of one
    int rc = generate_run_quiet(n, args);
    mlb_dist_solo(was);
    free(args);
    return rc;
}

static int claim(const char* claims, int index) {
    char path[PATH_CAP];
    snprintf(path, sizeof path, "%s/%d", claims, index);
    int fd = open(path, O_CREAT | O_EXCL | O_WRONLY, 0644);
    if (fd < 0) return 0;
    close(fd);
    return 1;
}

static void print_summary(FILE* f, const item* items, const record* rec, int n, const char* out) {
    int w = 6;
    for (int i = 0; i < n; i++) {
        int l = (int)strlen(items[i].prompt);
        if (l > w) w = l;
    }
    if (w > 48) w = 48;
    fprintf(f, "%-*s  %-8s %9s  %s\n", w, "prompt", "status", "time", "asset");
    for (int i = 0; i < n; i++) {
        char glb[PATH_CAP + 256], secs[32];
        snprintf(glb, sizeof glb, "%s/%s/final/asset.glb", out, items[i].name);
        if (!mlb_is_file(glb)) snprintf(glb, sizeof glb, "- (%s/%s)", out, items[i].name);
        if (rec[i].seconds > 0) snprintf(secs, sizeof secs, "%.1f s", rec[i].seconds);
        else snprintf(secs, sizeof secs, "-");
        fprintf(f, "%-*.*s  %-8s %9s  %s\n", w, w, items[i].prompt, STATUS[rec[i].status], secs, glb);
    }
}

static mlb_status write_summary(const char* out, const item* items, const record* rec, int n, double wall) {
    cJSON* root = cJSON_CreateObject();
    cJSON_AddStringToObject(root, "format", "matlaber-prompts");
    cJSON_AddNumberToObject(root, "processes", mlb_dist_world_size());
    cJSON_AddNumberToObject(root, "seconds", wall);
    cJSON* arr = cJSON_AddArrayToObject(root, "runs");
    for (int i = 0; i < n; i++) {
        cJSON* o = cJSON_CreateObject();
        char path[PATH_CAP + 256];
        cJSON_AddStringToObject(o, "prompt", items[i].prompt);
        cJSON_AddNumberToObject(o, "line", items[i].line);
        snprintf(path, sizeof path, "%s/%s", out, items[i].name);
        cJSON_AddStringToObject(o, "run", path);
        cJSON_AddStringToObject(o, "status", STATUS[rec[i].status]);
        cJSON_AddNumberToObject(o, "seconds", rec[i].seconds);
        if (rec[i].rank >= 0) cJSON_AddNumberToObject(o, "process", rec[i].rank);
        snprintf(path, sizeof path, "%s/%s/final/asset.glb", out, items[i].name);
        if (mlb_is_file(path)) cJSON_AddStringToObject(o, "glb", path);
        else cJSON_AddNullToObject(o, "glb");
        cJSON_AddItemToArray(arr, o);
    }
    char* text = cJSON_Print(root);
    cJSON_Delete(root);
    char path[PATH_CAP];
    snprintf(path, sizeof path, "%s/summary.json", out);
    mlb_atomic_file af;
    mlb_status s = text ? mlb_atomic_open(&af, path) : mlb_fail(MLB_ERR_NOMEM, "out of memory");
    if (!s) {
        fprintf(af.f, "%s\n", text);
        s = mlb_atomic_commit(&af);
    }
    free(text);
    return s;
}

int generate_prompts_main(int argc, char** argv) {
    const char *file = NULL, *out = NULL, *stop_after = NULL;
    for (int i = 1; i < argc; i++) {
        if ((!strcmp(argv[i], "--prompts") || !strcmp(argv[i], "-o") || !strcmp(argv[i], "--out") ||
             !strcmp(argv[i], "--stop-after")) && i + 1 < argc) {
            const char** dst = argv[i][2] == 'p' ? &file : argv[i][2] == 's' ? &stop_after : &out;
            *dst = argv[++i];
        } else if (!strncmp(argv[i], "--prompts=", 10)) file = argv[i] + 10;
        else if (!strncmp(argv[i], "--out=", 6)) out = argv[i] + 6;
        else if (!strncmp(argv[i], "--stop-after=", 13)) stop_after = argv[i] + 13;
        else if (!strcmp(argv[i], "-p") || !strcmp(argv[i], "--prompt") || !strcmp(argv[i], "--resume"))
            return cli_usage_error("generate", "--prompts takes the prompts from FILE: drop %s", argv[i]);
    }
    if (!file) return cli_usage_error("generate", "--prompts FILE: no FILE");
    if (!out) return cli_usage_error("generate", "--prompts FILE needs -o DIR (the folder of the runs)");
    char* text = NULL;
    size_t len = 0;
    mlb_status s = mlb_read_file(file, &text, &len, 64 << 20);
    if (s) return cli_fail(s, "--prompts");
    mlb_prompt_list list;
    s = mlb_prompts_parse(text, len, file, line_option_arity, &list);
    free(text);
    text = NULL;
    if (s == MLB_ERR_FORMAT) return cli_usage_error("generate", "--prompts %s", mlb_last_error());
    if (s) return cli_fail(s, "--prompts");
    item* items = list.items;
    const int n = list.n;
    const int rank = mlb_dist_world_rank(), size = mlb_dist_world_size();
    // this job's claims folder: rank 0 names and makes it, the others learn its name
    char claims[PATH_CAP];
    int made = 0;
    if (rank == 0) {
        snprintf(claims, sizeof claims, "%s/.claims/%ld-%d", out, (long)time(NULL), (int)getpid());
        made = mlb_mkdir_p(claims) == MLB_OK;
        if (!made) fprintf(stderr, "matlaber: error: --prompts: %s\n", mlb_last_error());
    }
    mlb_dist_bcast(claims, sizeof claims, 0);
    mlb_dist_bcast(&made, sizeof made, 0);
    if (!made) { mlb_prompts_free(&list); return 1; }
    if (rank == 0)
        mlb_log(MLB_LOG_INFO, "%d prompts from %s into %s, %d process%s", n, file, out, size, size > 1 ? "es" : "");
    record* rec = calloc((size_t)n, sizeof(record));
    int* mine = calloc((size_t)n + 1, sizeof(int));   // the indices this process ran
    int n_mine = 0;
    double t_job = mlb_now_seconds();
    mlb_pipeline_keep_shape_fits(MLB_PIPELINE_KEEP_FITS_BYTES);   // prompts with one seed start from the same fits
    for (int i = 0; i < n; i++) {
        char dir[PATH_CAP];
        snprintf(dir, sizeof dir, "%s/%s", out, items[i].name);
        double earlier;
        if (read_batch(dir, &earlier) == ST_DONE) continue;   // finished by an earlier job
        if (!claim(claims, i)) continue;                       // another process has it
        mlb_log(MLB_LOG_INFO, "process %d: \"%s\" -> %s", rank, items[i].prompt, dir);
        double t0 = mlb_now_seconds();
        int resumed = 0;
        int rc = run_item(&items[i], out, argc, argv, stop_after, &resumed);
        double secs = mlb_now_seconds() - t0;
        int st = rc == 0 ? (resumed ? ST_RESUMED : ST_DONE) : rc == GENERATE_STOPPED ? ST_STOPPED : ST_FAILED;
        if (st == ST_FAILED) mlb_log(MLB_LOG_WARN, "process %d: \"%s\" failed (exit %d)", rank, items[i].prompt, rc);
        if (mlb_is_dir(dir) && st != ST_FAILED) write_batch(dir, &items[i], st, secs);
        rec[i] = (record){i, st, rank, 0, secs};
        mine[n_mine++] = i;
    }
    mlb_pipeline_keep_shape_fits(0);
    // every process's records to every process (fixed-size records, so two gathers)
    int* counts = calloc((size_t)size, sizeof(int));
    counts[rank] = n_mine;
    mlb_dist_allgather_items(&counts[rank], counts, size, sizeof(int));
    size_t* bytes = calloc((size_t)size, sizeof(size_t));
    size_t total = 0;
    for (int r = 0; r < size; r++) { bytes[r] = sizeof(record) * (size_t)counts[r]; total += (size_t)counts[r]; }
    record* all = calloc(total + 1, sizeof(record));
    record* own = calloc((size_t)n_mine + 1, sizeof(record));
    for (int k = 0; k < n_mine; k++) own[k] = rec[mine[k]];
    mlb_dist_allgatherv(own, all, bytes);
    int failed = 0;
    if (rank == 0) {
        for (int i = 0; i < n; i++) rec[i] = (record){i, ST_NONE, -1, 0, 0};
        for (size_t k = 0; k < total; k++) rec[all[k].index] = all[k];
        for (int i = 0; i < n; i++) {
            if (rec[i].status != ST_NONE) continue;
            char dir[PATH_CAP];
            snprintf(dir, sizeof dir, "%s/%s", out, items[i].name);
            double earlier = 0;
            if (read_batch(dir, &earlier) == ST_DONE) rec[i] = (record){i, ST_SKIPPED, -1, 0, earlier};
        }
        for (int i = 0; i < n; i++) failed += rec[i].status == ST_FAILED || rec[i].status == ST_NONE;
        double wall = mlb_now_seconds() - t_job;
        print_summary(stdout, items, rec, n, out);
        printf("%d prompts on %d process%s in %.1f s; %s/summary.json\n", n, size, size > 1 ? "es" : "", wall, out);
        s = write_summary(out, items, rec, n, wall);
        if (s) { cli_fail(s, "--prompts"); failed++; }
        // this job's claims go; finished runs carry their own batch.json
        for (int i = 0; i < n; i++) {
            char path[PATH_CAP + 16];
            snprintf(path, sizeof path, "%s/%d", claims, i);
            unlink(path);
        }
        rmdir(claims);
        char parent[PATH_CAP];
        snprintf(parent, sizeof parent, "%s/.claims", out);
        rmdir(parent);   // (only when empty: another job may be running)
    }
    mlb_dist_bcast(&failed, sizeof failed, 0);
    cli_rc_agreed = 1;   // every process returns the same status: no need to abort the others
    free(counts); free(bytes); free(all); free(own); free(rec); free(mine);
    mlb_prompts_free(&list);
    return failed ? 1 : 0;
}
