// matlaber serve: the job table (serve.h). Each job is a child process of this program,
// `generate --progress json ... -o RUNS/ID`, so a job that fails or is killed never takes the
// server down; its JSON lines on stderr go to RUNS/.serve/ID.events, which the event streams
// read. RUNS/.serve/ID.json records what the server knows of a job (its request and state), so that
// a restarted server lists finished jobs and resumes the ones it had not finished (generate
// --resume continues a run to the same bits as an uninterrupted one).
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <ftw.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include "matlaber/fileio.h"
#include "serve.h"

#ifdef MLB_HAVE_MHD
typedef struct {
    char id[64];
    serve_job_state state;
    cJSON* request;        // NULL: a run folder the server did not make (listed only)
    int resume;            // started again after a restart: generate --resume
    int cancel;            // DELETE asked for it while it ran
    pid_t pid;
    int exit_code;         // the child's exit status; -N: killed by signal N
    double created, started, ended;
    char message[256];     // why it failed, when the server knows
    char* progress;        // the newest progress line of the child (JSON text)
} job;

static struct {
    serve_options o;
    char meta[4096];       // RUNS/.serve
    pthread_mutex_t lock;
    pthread_cond_t changed;   // a job's state or events changed
    job** v;
    int n, cap, running, stopping;
    long next_id;
    pthread_t scheduler;
} J = {.lock = PTHREAD_MUTEX_INITIALIZER, .changed = PTHREAD_COND_INITIALIZER};

static const char* const STATE[] = {"queued", "running", "done", "failed", "cancelled", "stopped"};

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_REALTIME, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

// A job id and a listed file name: 1..63 of A-Z a-z 0-9 . _ -, not starting with a dot. Names read
// from the runs folder are checked with it; a request's name is only ever compared with them.
static int safe_name(const char* s) {
    size_t n = strlen(s);
    if (n == 0 || n > 63 || s[0] == '.') return 0;
    for (const char* p = s; *p; p++)
        if (!((*p >= 'a' && *p <= 'z') || (*p >= 'A' && *p <= 'Z') || (*p >= '0' && *p <= '9') || *p == '.' ||
              *p == '_' || *p == '-'))
            return 0;
    return 1;
}

static int is_regular(const char* path) {
    struct stat st;
    return lstat(path, &st) == 0 && S_ISREG(st.st_mode);   // lstat: a link in a run folder is not served
}

static void run_path(char* out, size_t cap, const job* j, const char* rel) {
    snprintf(out, cap, "%s/%s%s%s", J.o.runs, j->id, rel ? "/" : "", rel ? rel : "");
}

static void meta_path(char* out, size_t cap, const char* id, const char* ext) { snprintf(out, cap, "%s/%s%s", J.meta, id, ext); }

// A paint job's mesh: RUNS/.serve/uploads/ID/mesh.FMT; "" for a generate job
static const char* mesh_format(const cJSON* req) {
    const cJSON* m = req ? cJSON_GetObjectItemCaseSensitive(req, "mesh") : NULL;
    const cJSON* f = m ? cJSON_GetObjectItemCaseSensitive(m, "format") : NULL;
    return cJSON_IsString(f) ? f->valuestring : NULL;
}

static const char* request_string(const job* j, const char* key);

static job* find(const char* id) {
    for (int i = 0; i < J.n; i++)
        if (!strcmp(J.v[i]->id, id)) return J.v[i];
    return NULL;
}

static int ended(const job* j) { return j->state >= JOB_DONE; }

// RUNS/.serve/ID.json, atomically (held: J.lock)
static void save_record(const job* j) {
    if (!j->request) return;
    cJSON* r = cJSON_CreateObject();
    cJSON_AddStringToObject(r, "id", j->id);
    cJSON_AddStringToObject(r, "state", STATE[j->state]);
    cJSON_AddItemToObject(r, "request", cJSON_Duplicate(j->request, 1));
    cJSON_AddNumberToObject(r, "created", j->created);
    cJSON_AddNumberToObject(r, "started", j->started);
    cJSON_AddNumberToObject(r, "ended", j->ended);
    cJSON_AddNumberToObject(r, "exit_code", j->exit_code);
    cJSON_AddStringToObject(r, "message", j->message);
    char* text = cJSON_Print(r);
    cJSON_Delete(r);
    char path[4200];
    meta_path(path, sizeof path, j->id, ".json");
    if (!text || mlb_write_file_atomic(path, text, strlen(text)))
        fprintf(stderr, "matlaber serve: could not write %s\n", path);
    free(text);
}

// The server's own last event of a job, after the child's (held: J.lock)
static void append_closing_event(const job* j) {
    char path[4200];
    meta_path(path, sizeof path, j->id, ".events");
    FILE* f = fopen(path, "a");
    if (!f) return;
    fprintf(f, "{\"event\":\"job\",\"id\":\"%s\",\"state\":\"%s\",\"exit_code\":%d}\n", j->id, STATE[j->state], j->exit_code);
    fclose(f);
}

static job* add_job(const char* id) {
    if (J.n == J.cap) {
        int cap = J.cap ? 2 * J.cap : 64;
        job** v = realloc(J.v, sizeof *v * (size_t)cap);
        if (!v) return NULL;
        J.v = v;
        J.cap = cap;
    }
    job* j = calloc(1, sizeof *j);
    if (!j) return NULL;
    snprintf(j->id, sizeof j->id, "%s", id);
    J.v[J.n++] = j;
    long k;
    if (sscanf(id, "job-%ld", &k) == 1 && k >= J.next_id) J.next_id = k + 1;
    return j;
}

// ---- the children ----
typedef struct { job* j; int fd; } reader_arg;

// The child's stderr, line by line: JSON lines to the events file, the rest to the log, until the
// child ends; then its state.
static void* reader(void* p) {
    reader_arg a = *(reader_arg*)p;
    free(p);
    job* j = a.j;
    char path[4200];
    meta_path(path, sizeof path, j->id, ".events");
    FILE* events = fopen(path, "a");
    meta_path(path, sizeof path, j->id, ".log");
    FILE* log = fopen(path, "a");
    FILE* in = fdopen(a.fd, "r");
    char* line = NULL;
    size_t cap = 0;
    ssize_t n;
    while (in && (n = getline(&line, &cap, in)) > 0) {
        int json = line[0] == '{' && line[n - 1] == '\n';
        FILE* to = json ? events : log;
        if (to) { fwrite(line, 1, (size_t)n, to); fflush(to); }
        pthread_mutex_lock(&J.lock);
        if (json && (strstr(line, "\"event\":\"progress\"") || strstr(line, "\"event\":\"begin\"") ||
                     strstr(line, "\"event\":\"end\""))) {
            free(j->progress);
            j->progress = strndup(line, (size_t)n - 1);
        }
        pthread_cond_broadcast(&J.changed);
        pthread_mutex_unlock(&J.lock);
    }
    free(line);
    if (in) fclose(in);
    else close(a.fd);
    if (events) fclose(events);
    if (log) fclose(log);
    int status = 0;
    while (waitpid(j->pid, &status, 0) < 0 && errno == EINTR) {}
    pthread_mutex_lock(&J.lock);
    J.running--;
    // a server on its way out killed it: the record stays "running", and the next start resumes it
    if (!J.stopping) {
        j->exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : WIFSIGNALED(status) ? -WTERMSIG(status) : -1;
        j->state = j->cancel ? JOB_CANCELLED : j->exit_code == 0 ? JOB_DONE : JOB_FAILED;
        if (j->state == JOB_FAILED && !j->message[0])
            snprintf(j->message, sizeof j->message, "%s %d (the log: %s/.serve/%s.log)",
                     j->exit_code < 0 ? "killed by signal" : "exit status", j->exit_code < 0 ? -j->exit_code : j->exit_code,
                     J.o.runs, j->id);
        j->ended = now();
        j->pid = 0;
        append_closing_event(j);
        save_record(j);
    }
    pthread_cond_broadcast(&J.changed);
    pthread_mutex_unlock(&J.lock);
    return NULL;
}

// Starts a queued job (held: J.lock, in the scheduler thread: the children's parent-death signal
// follows the thread that forked them, which lives as long as the server).
static int start_job(job* j) {
    char dir[4200], log_path[4200];
    run_path(dir, sizeof dir, j, NULL);
    meta_path(log_path, sizeof log_path, j->id, ".log");
    const char* fmt = mesh_format(j->request);
    char mesh[4300] = "";
    if (fmt) snprintf(mesh, sizeof mesh, "%s/uploads/%s/mesh.%s", J.meta, j->id, fmt);
    char** args = j->resume ? NULL : serve_request_args(j->request, &J.o, mesh);
    int n = 0;
    while (args && args[n]) n++;
    char** argv = calloc((size_t)n + 16, sizeof *argv);
    char procs[16], threads[16];
    snprintf(procs, sizeof procs, "%d", J.o.mpi);
    snprintf(threads, sizeof threads, "%d", J.o.job_threads);
    int fds[2] = {-1, -1};
    int logfd = open(log_path, O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
    int nullfd = open("/dev/null", O_RDONLY | O_CLOEXEC);
    if (!argv || (!j->resume && !args) || logfd < 0 || nullfd < 0 || pipe2(fds, O_CLOEXEC)) {
        snprintf(j->message, sizeof j->message, "could not start the job: %s", strerror(errno));
        free(argv);
        serve_args_free(args);
        if (logfd >= 0) close(logfd);
        if (nullfd >= 0) close(nullfd);
        if (fds[0] >= 0) { close(fds[0]); close(fds[1]); }
        return -1;
    }
    int a = 0;
    if (J.o.mpi) {   // the same command under the launcher: its processes share the run (bitwise one's)
        argv[a++] = (char*)J.o.mpirun;
        argv[a++] = "-n";
        argv[a++] = procs;
    }
    argv[a++] = (char*)J.o.exe;
    if (J.o.mpi && J.o.job_threads) {
        argv[a++] = "--threads";
        argv[a++] = threads;
    }
    argv[a++] = "--progress";
    argv[a++] = "json";
    argv[a++] = fmt ? "paint" : "generate";
    if (j->resume) {
        argv[a++] = "--resume";
        argv[a++] = dir;
    } else {
        for (int i = 0; i < n; i++) argv[a++] = args[i];
        // under mpirun the processes share a step's views by whole batches: one view a batch, unless
        // the request chose, so that every process has views to guide
        if (J.o.mpi && !cJSON_GetObjectItemCaseSensitive(j->request, "view_batch")) {
            argv[a++] = "--view-batch";
            argv[a++] = "1";
        }
        argv[a++] = "-o";
        argv[a++] = dir;
    }
    argv[a] = NULL;
    pid_t parent = getpid();
    pid_t pid = fork();
    if (pid == 0) {   // the child: only async-signal-safe calls until exec
        prctl(PR_SET_PDEATHSIG, SIGKILL);   // the server gone (even kill -9): the job goes too
        if (getppid() != parent) _exit(126);
        setpgid(0, 0);                      // DELETE kills the job's whole group
        signal(SIGPIPE, SIG_DFL);           // (the server ignores it; an ignored signal stays so across exec)
        sigset_t none;                      // and blocks Ctrl-C for its sigwait: a mask too survives exec
        sigemptyset(&none);
        sigprocmask(SIG_SETMASK, &none, NULL);
        dup2(nullfd, 0);
        dup2(logfd, 1);
        dup2(fds[1], 2);
        execv(argv[0], argv);
        _exit(127);
    }
    int err = errno;
    if (pid > 0) setpgid(pid, pid);   // both sides set it: a DELETE right after the start finds the group
    close(fds[1]);
    close(logfd);
    close(nullfd);
    free(argv);
    serve_args_free(args);
    if (pid < 0) {
        close(fds[0]);
        snprintf(j->message, sizeof j->message, "could not start the job: %s", strerror(err));
        return -1;
    }
    j->pid = pid;
    reader_arg* ra = malloc(sizeof *ra);
    pthread_t t;
    pthread_attr_t attr;
    pthread_attr_init(&attr);
    pthread_attr_setdetachstate(&attr, PTHREAD_CREATE_DETACHED);
    if (ra) *ra = (reader_arg){j, fds[0]};
    if (!ra || pthread_create(&t, &attr, reader, ra)) {   // no reader: the job cannot be followed
        free(ra);
        kill(-pid, SIGKILL);
        kill(pid, SIGKILL);
        close(fds[0]);
        waitpid(pid, NULL, 0);
        pthread_attr_destroy(&attr);
        snprintf(j->message, sizeof j->message, "could not start the job's reader thread");
        return -1;
    }
    pthread_attr_destroy(&attr);
    return 0;
}

static void* scheduler(void* unused) {
    (void)unused;
    pthread_mutex_lock(&J.lock);
    while (!J.stopping) {
        for (int i = 0; i < J.n && J.running < J.o.jobs; i++) {
            job* j = J.v[i];
            if (j->state != JOB_QUEUED) continue;
            j->started = now();
            if (start_job(j) == 0) {
                j->state = JOB_RUNNING;
                J.running++;
            } else {
                j->state = JOB_FAILED;
                j->ended = now();
                append_closing_event(j);
            }
            save_record(j);
            pthread_cond_broadcast(&J.changed);
        }
        pthread_cond_wait(&J.changed, &J.lock);
    }
    pthread_mutex_unlock(&J.lock);
    return NULL;
}

// ---- the runs folder at start ----
static serve_job_state state_named(const char* s) {
    for (int i = 0; i <= JOB_STOPPED; i++)
        if (s && !strcmp(s, STATE[i])) return (serve_job_state)i;
    return JOB_FAILED;
}

static double number(const cJSON* o, const char* key) {
    const cJSON* v = cJSON_GetObjectItemCaseSensitive(o, key);
    return cJSON_IsNumber(v) ? v->valuedouble : 0;
}

// A job the server had queued or started when it stopped: queued again, to resume its run folder
// when generate had written one.
static void requeue(job* j) {
    char path[4200];
    run_path(path, sizeof path, j, "config.json");
    j->resume = mlb_is_file(path);
    if (!j->resume) {   // killed between the folder and its config.json: the empty folder goes
        static const char* const sub[] = {"checkpoints", "previews", "final", NULL};
        for (int i = 0; sub[i]; i++) { run_path(path, sizeof path, j, sub[i]); rmdir(path); }
        run_path(path, sizeof path, j, NULL);
        if (rmdir(path) != 0 && errno != ENOENT) {
            j->state = JOB_FAILED;
            snprintf(j->message, sizeof j->message, "%s is not empty and holds no run: left as it is", path);
            return;
        }
    }
    j->state = JOB_QUEUED;
}

static void load_record(const char* name) {
    char id[64], path[4200];
    size_t n = strlen(name);
    if (n < 6 || n - 5 >= sizeof id || strcmp(name + n - 5, ".json")) return;
    snprintf(id, sizeof id, "%.*s", (int)(n - 5), name);
    if (!safe_name(id)) return;
    meta_path(path, sizeof path, id, ".json");
    char* text = NULL;
    size_t len = 0;
    if (mlb_read_file(path, &text, &len, 1 << 20)) return;
    cJSON* r = cJSON_ParseWithLength(text, len);
    free(text);
    const cJSON* st = cJSON_GetObjectItemCaseSensitive(r, "state");
    cJSON* req = cJSON_GetObjectItemCaseSensitive(r, "request");
    job* j = cJSON_IsObject(req) && cJSON_IsString(st) ? add_job(id) : NULL;
    if (!j) { cJSON_Delete(r); fprintf(stderr, "matlaber serve: %s: not a job record, skipped\n", path); return; }
    j->request = cJSON_DetachItemViaPointer(r, req);
    j->state = state_named(st->valuestring);
    j->created = number(r, "created");
    j->started = number(r, "started");
    j->ended = number(r, "ended");
    j->exit_code = (int)number(r, "exit_code");
    const cJSON* m = cJSON_GetObjectItemCaseSensitive(r, "message");
    if (cJSON_IsString(m)) snprintf(j->message, sizeof j->message, "%s", m->valuestring);
    cJSON_Delete(r);
    if (j->state == JOB_QUEUED || j->state == JOB_RUNNING) requeue(j);
}

// A run folder of RUNS that the server did not make (generate -o RUNS/NAME): listed.
static void add_external(const char* name) {
    char path[4200];
    if (!safe_name(name) || find(name)) return;
    snprintf(path, sizeof path, "%s/%s/config.json", J.o.runs, name);
    struct stat st;
    if (stat(path, &st) != 0 || !S_ISREG(st.st_mode)) return;
    job* j = add_job(name);
    if (!j) return;
    j->created = (double)st.st_mtime;
    snprintf(path, sizeof path, "%s/%s/final/mesh.obj", J.o.runs, name);
    j->state = mlb_is_file(path) ? JOB_DONE : JOB_STOPPED;
}

static int remove_entry(const char* path, const struct stat* st, int flag, struct FTW* f) {
    (void)st; (void)f;
    return flag == FTW_DP ? rmdir(path) : unlink(path);
}

// RUNS/job-N.part: a latent edit the server was writing when it stopped (serve_edit.c renames it
// to RUNS/job-N once whole), never listed: removed at start so that the id's next edit starts clean.
static void remove_partial_edit(const char* name) {
    size_t n = strlen(name);
    if (!safe_name(name) || strncmp(name, "job-", 4) || n < 9 || strcmp(name + n - 5, ".part")) return;
    char path[4200];
    snprintf(path, sizeof path, "%s/%s", J.o.runs, name);
    if (nftw(path, remove_entry, 8, FTW_DEPTH | FTW_PHYS) != 0)
        fprintf(stderr, "matlaber serve: could not remove the unfinished edit %s\n", path);
}

static int by_created(const void* a, const void* b) {
    const job *x = *(job* const*)a, *y = *(job* const*)b;
    if (x->created != y->created) return x->created < y->created ? -1 : 1;
    return strcmp(x->id, y->id);
}

int serve_jobs_open(const serve_options* o) {
    J.o = *o;
    J.next_id = 1;
    snprintf(J.meta, sizeof J.meta, "%s/.serve", o->runs);
    if (mlb_mkdir_p(J.meta)) { fprintf(stderr, "matlaber serve: cannot make %s\n", J.meta); return -1; }
    DIR* d = opendir(J.meta);
    for (struct dirent* e; d && (e = readdir(d));) load_record(e->d_name);
    if (d) closedir(d);
    d = opendir(o->runs);
    for (struct dirent* e; d && (e = readdir(d));) {
        remove_partial_edit(e->d_name);
        add_external(e->d_name);
    }
    if (d) closedir(d);
    if (J.n > 1) qsort(J.v, (size_t)J.n, sizeof *J.v, by_created);   // (J.v is NULL while empty)
    if (pthread_create(&J.scheduler, NULL, scheduler, NULL)) { fprintf(stderr, "matlaber serve: no thread\n"); return -1; }
    return 0;
}

void serve_jobs_close(void) {
    pthread_mutex_lock(&J.lock);
    J.stopping = 1;
    pthread_cond_broadcast(&J.changed);
    pthread_mutex_unlock(&J.lock);
    pthread_join(J.scheduler, NULL);   // its children get SIGKILL as it ends (their parent-death signal)
    // their readers see the end and let go of their jobs (a few seconds at most; then left as they are)
    struct timespec t;
    clock_gettime(CLOCK_REALTIME, &t);
    t.tv_sec += 10;
    pthread_mutex_lock(&J.lock);
    while (J.running > 0 && pthread_cond_timedwait(&J.changed, &J.lock, &t) == 0) {}
    pthread_mutex_unlock(&J.lock);
}

void serve_jobs_free(void) {
    pthread_mutex_lock(&J.lock);
    if (J.running > 0) { pthread_mutex_unlock(&J.lock); return; }   // a reader still holds its job
    for (int i = 0; i < J.n; i++) {
        cJSON_Delete(J.v[i]->request);
        free(J.v[i]->progress);
        free(J.v[i]);
    }
    free(J.v);
    J.v = NULL;
    J.n = J.cap = 0;
    pthread_mutex_unlock(&J.lock);
}

int serve_jobs_stopping(void) {
    pthread_mutex_lock(&J.lock);
    int s = J.stopping;
    pthread_mutex_unlock(&J.lock);
    return s;
}

void serve_jobs_wait(double seconds) {
    struct timespec t;
    clock_gettime(CLOCK_REALTIME, &t);
    long ns = t.tv_nsec + (long)((seconds - (double)(long)seconds) * 1e9);
    t.tv_sec += (time_t)seconds + ns / 1000000000L;
    t.tv_nsec = ns % 1000000000L;
    pthread_mutex_lock(&J.lock);
    if (!J.stopping) pthread_cond_timedwait(&J.changed, &J.lock, &t);
    pthread_mutex_unlock(&J.lock);
}

int serve_jobs_submit(cJSON* req, const char* upload, char* id, size_t cap, char* err, size_t errcap) {
    pthread_mutex_lock(&J.lock);
    int queued = 0;
    for (int i = 0; i < J.n; i++) queued += J.v[i]->state == JOB_QUEUED;
    if (queued >= J.o.max_queue) {
        pthread_mutex_unlock(&J.lock);
        cJSON_Delete(req);
        serve_upload_discard(upload);
        snprintf(err, errcap, "the queue is full (%d jobs wait; --max-queue)", queued);
        return 429;
    }
    char name[64], path[4200];
    for (;; J.next_id++) {   // a name no job, record or folder has
        snprintf(name, sizeof name, "job-%06ld", J.next_id);
        snprintf(path, sizeof path, "%s/%s", J.o.runs, name);
        struct stat st;
        if (!find(name) && lstat(path, &st) != 0) break;
    }
    char kept[4200];
    snprintf(kept, sizeof kept, "%s/uploads/%s", J.meta, name);
    job* j = upload[0] && rename(upload, kept) != 0 ? NULL : add_job(name);   // the upload becomes the job's
    if (!j) {
        pthread_mutex_unlock(&J.lock);
        cJSON_Delete(req);
        serve_upload_discard(upload);
        snprintf(err, errcap, "could not keep the job: %s", strerror(errno));
        return 500;
    }
    j->request = req;
    j->state = JOB_QUEUED;
    j->created = now();
    save_record(j);
    snprintf(id, cap, "%s", j->id);
    pthread_cond_broadcast(&J.changed);
    pthread_mutex_unlock(&J.lock);
    return 0;
}

int serve_jobs_cancel(const char* id, const char** why) {
    pthread_mutex_lock(&J.lock);
    job* j = find(id);
    int rc = !j ? 404 : ended(j) ? 409 : 0;
    *why = !j ? "no such job" : "the job has already ended";
    if (!rc && j->state == JOB_QUEUED) {
        j->state = JOB_CANCELLED;
        j->ended = now();
        append_closing_event(j);
        save_record(j);
    } else if (!rc && j->state == JOB_RUNNING && j->pid <= 0) {
        rc = 409;   // an edit being saved (no child)
        *why = "an edit being saved cannot be cancelled: it ends by itself in a moment";
    } else if (!rc && j->state == JOB_RUNNING && !j->cancel) {
        j->cancel = 1;   // the reader records it when the child is gone
        kill(-j->pid, SIGKILL);
        kill(j->pid, SIGKILL);   // (in case it has not made its group yet)
    }
    pthread_cond_broadcast(&J.changed);
    pthread_mutex_unlock(&J.lock);
    return rc;
}

// ---- an edit saved as a new job (serve_edit.c): no child; listed as running while it is written ----
int serve_jobs_edit_begin(const char* src, cJSON* req, char* id, size_t cap, char* dir, size_t dcap) {
    pthread_mutex_lock(&J.lock);
    job* s = find(src);
    int rc = !s ? 404 : s->state != JOB_DONE ? 409 : 0;
    char name[64], path[4200];
    for (; !rc; J.next_id++) {   // a name no job, record or folder has
        snprintf(name, sizeof name, "job-%06ld", J.next_id);
        snprintf(path, sizeof path, "%s/%s", J.o.runs, name);
        struct stat st;
        if (!find(name) && lstat(path, &st) != 0) break;
    }
    job* j = rc ? NULL : add_job(name);
    if (!rc && !j) rc = 500;
    if (j) {
        const char* prompt = request_string(s, "prompt");
        if (prompt) cJSON_AddStringToObject(req, "prompt", prompt);   // the list shows what it was made from
        j->request = req;
        j->state = JOB_RUNNING;   // (its record is written when it ends: a restart meanwhile forgets it)
        j->created = j->started = now();
        snprintf(id, cap, "%s", j->id);
        snprintf(dir, dcap, "%s", path);
        pthread_cond_broadcast(&J.changed);
    } else {
        cJSON_Delete(req);
    }
    pthread_mutex_unlock(&J.lock);
    return rc;
}

void serve_jobs_edit_end(const char* id, int ok, const char* message) {
    pthread_mutex_lock(&J.lock);
    job* j = find(id);
    if (j) {
        j->state = ok ? JOB_DONE : JOB_FAILED;
        j->exit_code = ok ? 0 : 1;
        j->ended = now();
        if (message) snprintf(j->message, sizeof j->message, "%s", message);
        append_closing_event(j);
        save_record(j);
    }
    pthread_cond_broadcast(&J.changed);
    pthread_mutex_unlock(&J.lock);
}

// ---- a job's files: the names a request may ask for, each mapped to its place in the run ----
#define MAX_FILES 64
typedef struct { char name[64]; char rel[80]; } file_entry;

static const char* content_type(const char* name) {
    static const char* const types[][2] = {{".glb", "model/gltf-binary"}, {".png", "image/png"}, {".json", "application/json"},
                                           {".csv", "text/csv; charset=utf-8"}, {".obj", "text/plain; charset=utf-8"},
                                           {".mtl", "text/plain; charset=utf-8"}, {NULL, NULL}};
    for (int i = 0; types[i][0]; i++)
        if (mlb_ends_with(name, types[i][0])) return types[i][1];
    return "application/octet-stream";
}

static int by_name(const void* a, const void* b) { return strcmp(((const file_entry*)a)->name, ((const file_entry*)b)->name); }

// previews/<stage>_<step>.png: the appearance stage's sheets come after the geometry's
static int preview_later(const char* a, const char* b) {
    if (!b[0]) return 1;
    int ra = !strncmp(a, "appearance", 10), rb = !strncmp(b, "appearance", 10);
    return ra != rb ? ra > rb : strcmp(a, b) > 0;
}

// (held: J.lock) config.json, loss.csv, loss.png, the regular files of final/, and preview.png: the
// newest preview sheet
static int list_files(const job* j, file_entry* out) {
    static const char* const top[] = {"config.json", "loss.csv", "loss.png", NULL};
    char path[4200];
    int n = 0;
    for (int i = 0; top[i]; i++) {
        run_path(path, sizeof path, j, top[i]);
        if (is_regular(path)) { snprintf(out[n].name, 64, "%s", top[i]); snprintf(out[n++].rel, 80, "%s", top[i]); }
    }
    const char* const sub[] = {"final", "previews"};
    for (int s = 0; s < 2; s++) {
        run_path(path, sizeof path, j, sub[s]);
        DIR* d = opendir(path);
        char newest[64] = "";
        for (struct dirent* e; d && (e = readdir(d));) {
            if (!safe_name(e->d_name)) continue;
            char rel[80];
            snprintf(rel, sizeof rel, "%s/%s", sub[s], e->d_name);
            run_path(path, sizeof path, j, rel);
            if (!is_regular(path)) continue;
            if (s == 1) {
                if (mlb_ends_with(e->d_name, ".png") && preview_later(e->d_name, newest))
                    snprintf(newest, sizeof newest, "%s", e->d_name);
                continue;
            }
            int dup = 0;
            for (int k = 0; k < n; k++) dup |= !strcmp(out[k].name, e->d_name);
            if (!dup && n < MAX_FILES - 1) { snprintf(out[n].name, 64, "%s", e->d_name); snprintf(out[n++].rel, 80, "%s", rel); }
        }
        if (d) closedir(d);
        if (s == 1 && newest[0]) { snprintf(out[n].name, 64, "preview.png"); snprintf(out[n++].rel, 80, "previews/%s", newest); }
    }
    qsort(out, (size_t)n, sizeof *out, by_name);   // (readdir's order is the file system's)
    return n;
}

int serve_jobs_file(const char* id, const char* name, char* path, size_t cap, const char** type) {
    file_entry* files = malloc(sizeof *files * MAX_FILES);
    if (!files) return 500;
    pthread_mutex_lock(&J.lock);
    job* j = find(id);
    int n = j ? list_files(j, files) : 0, rc = 404;
    for (int i = 0; i < n && rc; i++)
        if (!strcmp(files[i].name, name)) {   // the request's name is compared, never joined to a path
            run_path(path, cap, j, files[i].rel);
            *type = content_type(files[i].name);
            rc = 0;
        }
    pthread_mutex_unlock(&J.lock);
    free(files);
    return rc;
}

int serve_jobs_events_path(const char* id, char* path, size_t cap) {
    pthread_mutex_lock(&J.lock);
    job* j = find(id);
    if (j) meta_path(path, cap, j->id, ".events");
    pthread_mutex_unlock(&J.lock);
    return j ? 0 : 404;
}

int serve_jobs_ended(const char* id) {
    pthread_mutex_lock(&J.lock);
    job* j = find(id);
    int e = !j || ended(j);
    pthread_mutex_unlock(&J.lock);
    return e;
}

// ---- JSON for the API ----
static const char* request_string(const job* j, const char* key) {
    const cJSON* v = j->request ? cJSON_GetObjectItemCaseSensitive(j->request, key) : NULL;
    return cJSON_IsString(v) ? v->valuestring : NULL;
}

// (held: J.lock)
static cJSON* job_json(const job* j, int with_files) {
    cJSON* o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "id", j->id);
    cJSON_AddStringToObject(o, "state", STATE[j->state]);
    const char* prompt = request_string(j, "prompt");
    if (prompt) cJSON_AddStringToObject(o, "prompt", prompt);
    else cJSON_AddNullToObject(o, "prompt");
    cJSON_AddBoolToObject(o, "external", j->request == NULL);
    if (j->request) cJSON_AddItemToObject(o, "request", cJSON_Duplicate(j->request, 1));
    cJSON_AddNumberToObject(o, "created", j->created);
    if (j->started > 0) cJSON_AddNumberToObject(o, "started", j->started);
    if (j->ended > 0) cJSON_AddNumberToObject(o, "ended", j->ended);
    if (ended(j) && j->request) cJSON_AddNumberToObject(o, "exit_code", j->exit_code);
    if (j->message[0]) cJSON_AddStringToObject(o, "message", j->message);
    cJSON* p = j->progress ? cJSON_Parse(j->progress) : NULL;
    if (p) cJSON_AddItemToObject(o, "progress", p);
    if (with_files) {
        file_entry* files = malloc(sizeof *files * MAX_FILES);
        int n = files ? list_files(j, files) : 0;
        cJSON* list = cJSON_AddArrayToObject(o, "files");
        for (int i = 0; i < n; i++) cJSON_AddItemToArray(list, cJSON_CreateString(files[i].name));
        free(files);
    }
    return o;
}

char* serve_jobs_list_json(void) {
    cJSON* root = cJSON_CreateObject();
    cJSON* list = cJSON_AddArrayToObject(root, "jobs");
    pthread_mutex_lock(&J.lock);
    for (int i = 0; i < J.n; i++) cJSON_AddItemToArray(list, job_json(J.v[i], 0));
    cJSON_AddNumberToObject(root, "running", J.running);
    cJSON_AddNumberToObject(root, "max_running", J.o.jobs);
    pthread_mutex_unlock(&J.lock);
    char* text = cJSON_PrintUnformatted(root);
    cJSON_Delete(root);
    return text;
}

char* serve_jobs_get_json(const char* id) {
    pthread_mutex_lock(&J.lock);
    job* j = find(id);
    cJSON* o = j ? job_json(j, 1) : NULL;
    pthread_mutex_unlock(&J.lock);
    char* text = o ? cJSON_PrintUnformatted(o) : NULL;
    cJSON_Delete(o);
    return text;
}
#endif
