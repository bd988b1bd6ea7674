// matlaber serve (docs/server.md): a local HTTP server over a queue of generate jobs. Split in
// cmd_serve.c (options, start), serve_http.c (routes, limits, server-sent events), serve_jobs.c
// (the job table, child processes, run folders), serve_request.c (a job request's JSON checked
// and turned into generate's arguments) and serve_static.c (the page and the viewer's files).
#ifndef MATLABER_SERVE_H
#define MATLABER_SERVE_H
#include <stddef.h>
#include <stdint.h>
#include <cjson/cJSON.h>

typedef struct {
    const char* host;      // bind address (default 127.0.0.1)
    int port;              // 0: any free port (the first line says which)
    const char* runs;      // folder of the run folders, one per job
    const char* model;     // -m for every job, NULL: the project's own model
    const char* token;     // bearer token, NULL: none (loopback only)
    const char* exe;       // the program the jobs run (/proc/self/exe; its real path with mpi)
    int mpi;               // processes per job under mpirun (0: a job is one process)
    const char* mpirun;    // the launcher's path, with mpi
    int job_threads;       // --threads of each of a job's processes under mpirun (0: the program's own)
    int jobs;              // jobs running at once
    int max_queue;         // jobs waiting at most
    int max_conns;         // open connections at most
    size_t max_body;       // request body bytes at most
    int max_prompt;        // prompt bytes at most
    int timeout;           // seconds an idle or half-sent connection is kept
} serve_options;

// ---- serve_request.c ----
// A job request (the body of POST /api/jobs) checked strictly: a JSON object of known keys and
// types, then generate's own option checks on the arguments it becomes. body[n] must be a NUL. On success *out is the
// request as it will be kept (cJSON, the caller's) and 0 is returned; else the HTTP status (400,
// 413) with the reason in err.
// With "mesh" (a paint job) the decoded mesh is kept in a folder of its own, named in upload (else
// upload is ""), for serve_jobs_submit to take; a refused request leaves nothing.
int serve_request_parse(const char* body, size_t n, const serve_options* o, cJSON** out, char* upload, size_t ucap,
                        char* err, size_t cap);
void serve_upload_discard(const char* dir);
// The request's generate (paint) options (after the command, before -o), NULL-terminated, malloc'd
// strings; mesh_path: the mesh file of a paint job. NULL when out of memory. serve_args_free
// releases them.
char** serve_request_args(const cJSON* req, const serve_options* o, const char* mesh_path);
void serve_args_free(char** args);

// ---- serve_jobs.c ----
typedef enum { JOB_QUEUED, JOB_RUNNING, JOB_DONE, JOB_FAILED, JOB_CANCELLED, JOB_STOPPED } serve_job_state;
// Reads the runs folder (finished runs listed, the server's unfinished jobs queued again to
// resume) and starts the scheduler. 0 on success, else a message on stderr.
int serve_jobs_open(const serve_options* o);
// Stops: event streams end, the scheduler ends, its running children die (they resume at the next
// start); then, once no connection can ask (serve_http_stop), serve_jobs_free releases the table.
void serve_jobs_close(void);
void serve_jobs_free(void);
// Queues a checked request (takes it, and its upload folder when not ""); 0 with the new id in id,
// 429 when the queue is full.
int serve_jobs_submit(cJSON* req, const char* upload, char* id, size_t cap, char* err, size_t errcap);
// JSON text (malloc'd) of all jobs, or of one (NULL when there is no such id).
char* serve_jobs_list_json(void);
char* serve_jobs_get_json(const char* id);
// 0 cancelled (a queued job at once, a running one killed), 404 no such id, 409 already ended or an
// edit being saved (which ends by itself).
int serve_jobs_cancel(const char* id, const char** why);   // 0, or 404 / 409 with *why the reason
// The file of the job's own list named name: 0 with its path and content type, else 404.
int serve_jobs_file(const char* id, const char* name, char* path, size_t cap, const char** type);
// Events (the child's --progress json lines, then the server's closing {"event":"job",...}):
// the job's events file, 0 or 404.
int serve_jobs_events_path(const char* id, char* path, size_t cap);
// 1 when the job has ended and its events file will not grow again.
int serve_jobs_ended(const char* id);
// Waits up to seconds for any job's events or state to change.
void serve_jobs_wait(double seconds);
// 1 once serve_jobs_close began (streams end).
int serve_jobs_stopping(void);

// An edit saved as a new job (serve_edit.c): reserves a new id for an edit of the finished job src
// (404 unknown, 409 not done) and lists it as running, with req as its request (taken: it gets
// src's prompt); dir is its run folder, not yet made. serve_jobs_edit_end records it done or failed.
int serve_jobs_edit_begin(const char* src, cJSON* req, char* id, size_t cap, char* dir, size_t dcap);
void serve_jobs_edit_end(const char* id, int ok, const char* message);

// ---- serve_edit.c ----
#define SERVE_EDIT_MAX_BODY 4096   // an edit's request is a few numbers
// POST /api/jobs/{src}/edits: the body (body[n] a NUL) checked, the edit written as a new job's run
// folder. 0 with the new id; else the HTTP status with the reason in err.
int serve_edit_save(const char* src, const char* body, size_t n, char* id, size_t cap, char* err, size_t errcap);

// ---- serve_static.c ----
// Writes the viewer's page folder to RUNS/.serve/viewer when the viewer source is there (else the
// API alone, said on stderr); 0.
int serve_static_open(const serve_options* o);
// The app page's files ("serve.html", "serve.js") and the viewer's (a name relative to its
// folder, e.g. "lib/three/build/three.module.js"): 0 with the path and type, 404 when not there.
int serve_static_app(const char* name, char* path, size_t cap, const char** type);
int serve_static_viewer(const char* rel, char* path, size_t cap, const char** type);

// ---- serve_http.c ----
// Starts the HTTP daemon; returns the port it listens on, or -1 with a message on stderr.
int serve_http_start(const serve_options* o);
void serve_http_stop(void);

#endif
