// matlaber serve: a local web app and API over generate jobs (docs/server.md). This file: the
// options, the safety checks at start, and the wait for Ctrl-C; serve_http.c, serve_jobs.c and
// serve_request.c do the work.
#include <arpa/inet.h>
#include <limits.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "cli.h"
#include "matlaber/dist.h"
#include "matlaber/fileio.h"
#include "matlaber/threads.h"
#include "serve.h"

static const cli_option options[] = {
    {"host", 1, 'H', "ADDR", "the address to listen on (default 127.0.0.1; any other needs --token)"},
    {"port", 1, 'p', "N", "the port (default 7860; 0: any free one, the first line says which)"},
    {"runs", 1, 'r', "DIR", "the folder of the jobs' run folders (default runs; made when missing)"},
    {"model", 1, 'm', "PATH", "the model every job uses (default: the project's own, with --preset tiny)"},
    {"token", 1, 't', "T", "a bearer token every request must carry (Authorization: Bearer T)"},
    {"jobs", 1, 'j', "N", "jobs running at once (default 1)"},
    {"mpi", 1, 'M', "N", "each job under mpirun -n N, its steps' views shared by N processes (default: one process; an MPI build)"},
    {"max-queue", 1, 'q', "N", "jobs waiting at most (default 16; more: 429)"},
    {"max-connections", 1, 'c', "N", "open connections at most (default 64; more: 429)"},
    {"max-body", 1, 'b', "BYTES", "request body at most, an uploaded mesh's base64 included (default 8388608; more: 413)"},
    {"max-prompt", 1, 'P', "BYTES", "prompt length at most (default 512; more: 400)"},
    {"timeout", 1, 'T', "S", "seconds before an idle or half-sent connection is closed (default 10)"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

#ifdef MLB_HAVE_MHD
// The first executable `name` in $PATH's folders into out; 0 when there is none.
static int find_on_path(const char* name, char* out, size_t cap) {
    const char* path = getenv("PATH");
    while (path && *path) {
        const char* end = strchr(path, ':');
        size_t len = end ? (size_t)(end - path) : strlen(path);
        if (len > 0 && (size_t)snprintf(out, cap, "%.*s/%s", (int)len, path, name) < cap && access(out, X_OK) == 0) return 1;
        path = end ? end + 1 : NULL;
    }
    return 0;
}

// 127.0.0.0/8, ::1 and localhost: the machine itself
static int loopback(const char* host) {
    struct in_addr a4;
    struct in6_addr a6;
    if (!strcmp(host, "localhost")) return 1;
    if (inet_pton(AF_INET, host, &a4) == 1) return (ntohl(a4.s_addr) >> 24) == 127;
    if (inet_pton(AF_INET6, host, &a6) == 1) return IN6_IS_ADDR_LOOPBACK(&a6);
    return 0;
}
#endif

int cmd_serve(int argc, char** argv) {
    serve_options o = {.host = "127.0.0.1", .port = 7860, .runs = "runs", .exe = "/proc/self/exe", .jobs = 1,
                       .max_queue = 16, .max_conns = 64, .max_body = 8 << 20, .max_prompt = 512, .timeout = 10};
    long v;
    const struct option* table = cli_getopt_table(options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "hm:", table, NULL)) != -1) {
        switch (c) {
        case 'H': o.host = optarg; break;
        case 'p': if (cli_parse_long(optarg, 0, 65535, &v)) return cli_usage_error("serve", "--port: expected 0..65535"); o.port = (int)v; break;
        case 'r': o.runs = optarg; break;
        case 'm': o.model = optarg; break;
        case 't': o.token = optarg; break;
        case 'j': if (cli_parse_long(optarg, 1, 64, &v)) return cli_usage_error("serve", "--jobs: expected 1..64"); o.jobs = (int)v; break;
        case 'M': if (cli_parse_long(optarg, 1, 1024, &v)) return cli_usage_error("serve", "--mpi: expected 1..1024 processes"); o.mpi = v > 1 ? (int)v : 0; break;
        case 'q': if (cli_parse_long(optarg, 0, 100000, &v)) return cli_usage_error("serve", "--max-queue: expected 0..100000"); o.max_queue = (int)v; break;
        case 'c': if (cli_parse_long(optarg, 1, 10000, &v)) return cli_usage_error("serve", "--max-connections: expected 1..10000"); o.max_conns = (int)v; break;
        case 'b': if (cli_parse_long(optarg, 16, 1 << 26, &v)) return cli_usage_error("serve", "--max-body: expected 16..67108864"); o.max_body = (size_t)v; break;
        case 'P': if (cli_parse_long(optarg, 1, CLI_MAX_ARG, &v)) return cli_usage_error("serve", "--max-prompt: expected 1..%d", CLI_MAX_ARG); o.max_prompt = (int)v; break;
        case 'T': if (cli_parse_long(optarg, 1, 3600, &v)) return cli_usage_error("serve", "--timeout: expected 1..3600 seconds"); o.timeout = (int)v; break;
        case 'h':
            printf("usage: matlaber serve [--host 127.0.0.1] [--port 7860] [--runs DIR] [-m MODEL] [--token T] [--mpi N]\n\n"
                   "A local server: a page to make assets in the browser and the API under it (docs/server.md).\n"
                   "Each job is `matlaber generate` (`paint` for an uploaded mesh) as a child process with its\n"
                   "run folder in --runs DIR; a restarted server lists the finished runs there and resumes the\n"
                   "unfinished jobs. The first line printed is the address to open.\n\n");
            cli_print_options(stdout, options);
            return 0;
        default: return cli_usage_error("serve", "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error("serve", "unexpected argument '%s'", argv[optind]);
#ifndef MLB_HAVE_MHD
    (void)o;
    fprintf(stderr, "matlaber serve: this build has no HTTP server: install libmicrohttpd (Debian: apt-get install "
                    "libmicrohttpd-dev; scripts/install-deps.sh) and build again\n");
    return 1;
#else
    if (!loopback(o.host) && !o.token)
        return cli_usage_error("serve", "--host %s is reachable from other machines: give --token T (every request then "
                               "needs Authorization: Bearer T)", o.host);
    if (o.token && strlen(o.token) < 16) return cli_usage_error("serve", "--token: at least 16 characters");
    for (const char* p = o.token; p && *p; p++)
        if (!((*p >= 'a' && *p <= 'z') || (*p >= 'A' && *p <= 'Z') || (*p >= '0' && *p <= '9') || strchr("-._~", *p)))
            return cli_usage_error("serve", "--token: letters, digits and - . _ ~ only (it travels in URLs too)");
    static char mpirun[PATH_MAX], exe[PATH_MAX];
    if (o.mpi) {
        if (!mlb_dist_built())
            return cli_usage_error("serve", "--mpi: this matlaber was built without MPI (install OpenMPI: "
                                   "scripts/install-deps.sh, then build again)");
        if (!find_on_path("mpirun", mpirun, sizeof mpirun))
            return cli_usage_error("serve", "--mpi: no mpirun on PATH (scripts/install-deps.sh installs OpenMPI)");
        // the launcher runs the program by name: /proc/self/exe would be mpirun itself there
        if (!realpath(o.exe, exe)) return cli_fail(MLB_ERR_IO, "serve: the program's own path");
        o.exe = exe;
        o.mpirun = mpirun;
        o.job_threads = mlb_get_threads() / o.mpi > 1 ? mlb_get_threads() / o.mpi : 1;   // the cores shared, not multiplied
        // OpenMPI refuses root and more processes than cores unless told; other launchers ignore these
        if (geteuid() == 0) {
            setenv("OMPI_ALLOW_RUN_AS_ROOT", "1", 0);
            setenv("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1", 0);
        }
        setenv("OMPI_MCA_rmaps_base_oversubscribe", "1", 0);
    }
    if (mlb_mkdir_p(o.runs)) return cli_fail(MLB_ERR_IO, "serve: --runs");
    static char runs[PATH_MAX];
    if (!realpath(o.runs, runs)) return cli_fail(MLB_ERR_IO, "serve: --runs");
    o.runs = runs;
    // Ctrl-C and SIGTERM are taken by sigwait below: blocked in every thread (the jobs unblock them)
    sigset_t stop;
    sigemptyset(&stop);
    sigaddset(&stop, SIGINT);
    sigaddset(&stop, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &stop, NULL);
    signal(SIGPIPE, SIG_IGN);   // a client that went away is a failed write, not the end of the server
    serve_static_open(&o);
    if (serve_jobs_open(&o)) return 1;
    int port = serve_http_start(&o);
    if (port < 0) { serve_jobs_close(); return 1; }
    int v6 = strchr(o.host, ':') != NULL;
    printf("http://%s%s%s:%d/\n", v6 ? "[" : "", o.host, v6 ? "]" : "", port);
    fflush(stdout);
    char procs[64] = "";
    if (o.mpi) snprintf(procs, sizeof procs, ", each %d processes of %d thread%s", o.mpi, o.job_threads, o.job_threads > 1 ? "s" : "");
    fprintf(stderr, "matlaber serve: runs in %s, %d job%s at a time%s%s; Ctrl-C stops (unfinished jobs resume at the next start)\n",
            o.runs, o.jobs, o.jobs > 1 ? "s" : "", procs, o.token ? ", bearer token required" : "");
    int sig = 0;
    sigwait(&stop, &sig);
    fprintf(stderr, "matlaber serve: stopping\n");
    serve_jobs_close();   // first: the event streams end, then the daemon's threads can be joined
    serve_http_stop();
    serve_jobs_free();
    return 0;
#endif
}
