// matlaber serve: the HTTP side (serve.h) on libmicrohttpd: routes, the bearer token, the limits
// (body, connections; each a 4xx with a JSON error), server-sent events and the files of a job.
// No path from a request reaches the file system: a job is found by comparing its id, a file by
// comparing its name with the job's own list (serve_jobs.c); the URL is taken as sent (no
// percent-decoding), and one holding '%' is refused outright.
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>
#include "matlaber/fileio.h"
#include "serve.h"

#ifdef MLB_HAVE_MHD
#include <microhttpd.h>

static struct MHD_Daemon* daemon_;
static serve_options O;
static atomic_int open_connections;

// ---- replies ----
// Every reply's common headers (never cached, never sniffed into another type), then queued; the
// response is released here (libmicrohttpd keeps its own reference until it is sent).
static enum MHD_Result queue_reply(struct MHD_Connection* c, unsigned code, struct MHD_Response* r, const char* type) {
    MHD_add_response_header(r, "Content-Type", type);
    MHD_add_response_header(r, "Cache-Control", "no-store");
    MHD_add_response_header(r, "X-Content-Type-Options", "nosniff");
    enum MHD_Result ret = MHD_queue_response(c, code, r);
    MHD_destroy_response(r);
    return ret;
}

static enum MHD_Result send_text_allow(struct MHD_Connection* c, unsigned code, const char* type, char* text, const char* allow) {
    if (!text) return MHD_NO;
    struct MHD_Response* r = MHD_create_response_from_buffer(strlen(text), text, MHD_RESPMEM_MUST_FREE);
    if (!r) { free(text); return MHD_NO; }
    if (allow) MHD_add_response_header(r, "Allow", allow);
    return queue_reply(c, code, r, type);
}

static enum MHD_Result send_text(struct MHD_Connection* c, unsigned code, const char* type, char* text) {
    return send_text_allow(c, code, type, text, NULL);
}

static enum MHD_Result send_json(struct MHD_Connection* c, unsigned code, cJSON* o) {
    char* text = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    return send_text(c, code, "application/json", text);
}

// {"error": message, "status": code}: every refusal of the API
static enum MHD_Result send_error(struct MHD_Connection* c, unsigned code, const char* msg) {
    cJSON* o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "error", msg);
    cJSON_AddNumberToObject(o, "status", code);
    return send_json(c, code, o);
}

// 405 with the methods the route takes
static enum MHD_Result send_405(struct MHD_Connection* c, const char* allow) {
    char msg[96];
    snprintf(msg, sizeof msg, "method not allowed: %s", allow);
    cJSON* o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "error", msg);
    cJSON_AddNumberToObject(o, "status", 405);
    char* text = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    return send_text_allow(c, 405, "application/json", text, allow);
}

// ---- the bearer token ----
// Equal in time that depends on the token's length only, not on where a guess first differs.
static int same_secret(const char* given, const char* token) {
    size_t ng = strlen(given), nt = strlen(token);
    unsigned char d = ng != nt;
    for (size_t i = 0; i < nt; i++) d |= (unsigned char)((i < ng ? given[i] : 0) ^ token[i]);
    return d == 0;
}

// "Authorization: Bearer T"; or ?token=T, or the cookie matlaber_token=T that the page sets from
// it (an EventSource, a link and the viewer's own requests cannot send a header)
static int authorised(struct MHD_Connection* c) {
    if (!O.token) return 1;
    const char* h = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Authorization");
    if (h && !strncmp(h, "Bearer ", 7) && same_secret(h + 7, O.token)) return 1;
    const char* q = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "token");
    if (q && same_secret(q, O.token)) return 1;
    const char* k = MHD_lookup_connection_value(c, MHD_COOKIE_KIND, "matlaber_token");
    return k && same_secret(k, O.token);
}

// Without a token the server trusts the machine, so it answers only requests addressed to the machine:
// a page elsewhere that points a name of its own at 127.0.0.1 (DNS rebinding) sends its own Host.
static int host_is_loopback(struct MHD_Connection* c) {
    const char* h = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Host");
    if (!h) return 0;
    static const char* const names[] = {"127.0.0.1", "localhost", "[::1]", NULL};
    for (int i = 0; names[i]; i++) {
        size_t n = strlen(names[i]);
        if (!strncasecmp(h, names[i], n) && (h[n] == 0 || h[n] == ':')) return 1;
    }
    return 0;
}

// ---- server-sent events: the job's events file from an offset, a line an event ----
typedef struct {
    char id[64];
    char path[4200];
    long offset;        // the next byte of the file to send (each event's id: a reconnection resumes there)
    double last_sent;
    int fd;             // the connection's socket, -1 when unknown
} stream;

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

// Complete lines from s->offset as "id: END\ndata: LINE\n\n" into buf; the bytes written.
static size_t read_events(stream* s, char* buf, size_t max) {
    int fd = open(s->path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) return 0;
    size_t chunk = max / 2;
    char* in = malloc(chunk);
    ssize_t got = in ? pread(fd, in, chunk, s->offset) : -1;
    close(fd);
    size_t out = 0, at = 0;
    while (got > 0 && at < (size_t)got) {
        char* nl = memchr(in + at, '\n', (size_t)got - at);
        if (!nl) {
            if (at == 0 && (size_t)got == chunk) s->offset += got;   // a line longer than a block: dropped
            break;
        }
        size_t len = (size_t)(nl - (in + at));
        char head[48];
        int h = snprintf(head, sizeof head, "id: %ld\ndata: ", s->offset + (long)(len + 1));
        if (out + (size_t)h + len + 2 > max) break;
        memcpy(buf + out, head, (size_t)h);
        memcpy(buf + out + h, in + at, len);
        memcpy(buf + out + h + len, "\n\n", 2);
        out += (size_t)h + len + 2;
        at += len + 1;
        s->offset += (long)(len + 1);
    }
    free(in);
    return out;
}

// A client that closed its side: readable with nothing to read. An event stream's client sends
// nothing after its request, so this finds it gone while the job is quiet; a write alone finds it
// out only at the second write after the close, and until then its connection and thread count
// against --max-connections (200 clients that each leave a stream reached 300 and more). (A client
// that half-closes after its request, which no browser does, has its stream ended too.)
static int client_gone(int fd) {
    if (fd < 0) return 0;
    char b;
    ssize_t n = recv(fd, &b, 1, MSG_PEEK | MSG_DONTWAIT);
    return n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR);
}

static ssize_t stream_read(void* cls, uint64_t pos, char* buf, size_t max) {
    (void)pos;
    stream* s = cls;
    for (;;) {
        if (serve_jobs_stopping()) return MHD_CONTENT_READER_END_OF_STREAM;
        if (client_gone(s->fd)) return MHD_CONTENT_READER_END_WITH_ERROR;
        int ended = serve_jobs_ended(s->id);   // before the read: an ended job's last line is written
        size_t n = read_events(s, buf, max);
        if (n > 0) { s->last_sent = now(); return (ssize_t)n; }
        if (ended) return MHD_CONTENT_READER_END_OF_STREAM;
        // a comment now and then: a client that left is found out, and the idle timeout never fires
        double keepalive = O.timeout > 2 ? O.timeout / 2.0 : 1.0;
        if (now() - s->last_sent >= keepalive) {
            s->last_sent = now();
            memcpy(buf, ": keepalive\n\n", 13);
            return 13;
        }
        serve_jobs_wait(0.5);
    }
}

static enum MHD_Result send_events(struct MHD_Connection* c, const char* id) {
    stream* s = calloc(1, sizeof *s);
    if (!s) return send_error(c, 500, "out of memory");
    snprintf(s->id, sizeof s->id, "%s", id);
    if (serve_jobs_events_path(id, s->path, sizeof s->path)) { free(s); return send_error(c, 404, "no such job"); }
    // a reconnecting EventSource sends the id of the last event it had: the offset after it, taken
    // only where it ends a line of the file
    const char* last = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Last-Event-ID");
    if (last) {
        char* end;
        long v = strtol(last, &end, 10);
        int fd = open(s->path, O_RDONLY | O_CLOEXEC);
        char b = 0;
        if (*last && !*end && v > 0 && fd >= 0 && pread(fd, &b, 1, v - 1) == 1 && b == '\n') s->offset = v;
        if (fd >= 0) close(fd);
    }
    s->last_sent = now();
    const union MHD_ConnectionInfo* info = MHD_get_connection_info(c, MHD_CONNECTION_INFO_CONNECTION_FD);
    s->fd = info ? (int)info->connect_fd : -1;
    struct MHD_Response* r = MHD_create_response_from_callback(MHD_SIZE_UNKNOWN, 64 * 1024, stream_read, s, free);
    if (!r) { free(s); return MHD_NO; }
    return queue_reply(c, 200, r, "text/event-stream");
}

// ---- files: a job's, the page's ----
static enum MHD_Result send_path(struct MHD_Connection* c, const char* path, const char* type) {
    int fd = open(path, O_RDONLY | O_NOFOLLOW | O_CLOEXEC);
    struct stat st;
    if (fd < 0 || fstat(fd, &st) || !S_ISREG(st.st_mode)) {
        if (fd >= 0) close(fd);
        return send_error(c, 404, "the file is gone");
    }
    struct MHD_Response* r = MHD_create_response_from_fd((uint64_t)st.st_size, fd);   // closes fd
    if (!r) { close(fd); return MHD_NO; }
    return queue_reply(c, 200, r, type);
}

static enum MHD_Result send_file(struct MHD_Connection* c, const char* id, const char* name) {
    char path[4200];
    const char* type = NULL;
    int rc = serve_jobs_file(id, name, path, sizeof path, &type);
    if (rc) return send_error(c, rc, rc == 404 ? "no such job or file (GET /api/jobs/ID lists its files)" : "server error");
    return send_path(c, path, type);
}

static enum MHD_Result send_static(struct MHD_Connection* c, int rc, const char* path, const char* type) {
    return rc ? send_error(c, 404, "no such file (the page needs viewer/ with its npm packages: scripts/build.sh)")
              : send_path(c, path, type);
}

// /view/ID/REST: the viewer's folder with the job's asset.glb (and latent sidecars) beside it
static enum MHD_Result send_view(struct MHD_Connection* c, const char* url) {
    const char* p = url + strlen("/view/");
    const char* slash = strchr(p, '/');
    char id[64], path[4200];
    const char* type = NULL;
    if (!slash || slash == p || slash - p > 63) return send_error(c, 404, "no such route (/view/ID/)");
    snprintf(id, sizeof id, "%.*s", (int)(slash - p), p);
    const char* rest = slash + 1;
    if (serve_jobs_events_path(id, path, sizeof path)) return send_error(c, 404, "no such job");
    if (!strcmp(rest, "asset.glb")) return send_file(c, id, "asset.glb");
    if (!strcmp(rest, "asset.decoder.json") || !strcmp(rest, "asset.latent.bin")) {
        // the viewer asks every job for its latent editor; a direct-mode (or unfinished) job has
        // none, which is no error: 204, so the page logs nothing
        if (serve_jobs_file(id, rest, path, sizeof path, &type) == 404) return send_text(c, 204, "application/json", calloc(1, 1));
        return send_file(c, id, rest);
    }
    int rc = serve_static_viewer(rest[0] ? rest : "index.html", path, sizeof path, &type);
    return send_static(c, rc, path, type);
}

// ---- requests ----
typedef struct {
    char* body;
    size_t len, cap;
    int too_big;
    char edit_of[64];   // POST /api/jobs/ID/edits: ID ("" for POST /api/jobs)
} request;

// "/api/jobs/ID/files/NAME" -> up to 5 segments of 1 to 63 bytes; -1 when longer, more, or one is
// empty ("//", a trailing "/"); "/" -> 0
static int split(const char* url, char seg[5][64]) {
    if (url[0] != '/') return -1;
    if (!url[1]) return 0;
    int n = 0;
    for (const char* p = url + 1;; p++) {
        const char* e = strchr(p, '/');
        size_t len = e ? (size_t)(e - p) : strlen(p);
        if (n == 5 || len == 0 || len > 63) return -1;
        memcpy(seg[n], p, len);
        seg[n++][len] = 0;
        if (!e) return n;
        p = e;
    }
}

static enum MHD_Result submit(struct MHD_Connection* c, request* q) {
    if (q->too_big) return send_error(c, 413, "the request body is over the server's limit (--max-body)");
    cJSON* req = NULL;
    char err[1200], id[64], upload[4200];
    int rc = serve_request_parse(q->body ? q->body : "", q->len, &O, &req, upload, sizeof upload, err, sizeof err);
    if (rc) return send_error(c, (unsigned)rc, err);
    rc = serve_jobs_submit(req, upload, id, sizeof id, err, sizeof err);   // takes req and the upload
    if (rc) return send_error(c, (unsigned)rc, err);
    char* text = serve_jobs_get_json(id);
    return send_text(c, 201, "application/json", text);
}

// POST /api/jobs/ID/edits: the edit saved as a new job (serve_edit.c)
static enum MHD_Result save_edit(struct MHD_Connection* c, request* q) {
    if (q->too_big) return send_error(c, 413, "an edit's body is over 4096 bytes");
    char err[1400], id[64];
    int rc = serve_edit_save(q->edit_of, q->body ? q->body : "", q->len, id, sizeof id, err, sizeof err);
    if (rc) return send_error(c, (unsigned)rc, err);
    return send_text(c, 201, "application/json", serve_jobs_get_json(id));
}

// POST /api/jobs/ID/edits, first call: refused at once when too big or not JSON (as POST /api/jobs),
// else its body is read
static enum MHD_Result accept_edit(struct MHD_Connection* c, const char* edit_of, void** ctx) {
    const char* len = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Content-Length");
    if (len && strtoull(len, NULL, 10) > SERVE_EDIT_MAX_BODY) return send_error(c, 413, "an edit's body is over 4096 bytes");
    const char* ct = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Content-Type");
    if (!ct || strncasecmp(ct, "application/json", 16) || (ct[16] && ct[16] != ';' && ct[16] != ' '))
        return send_error(c, 415, "the body must be sent as Content-Type: application/json");
    request* q = calloc(1, sizeof *q);
    if (!q) return MHD_NO;
    snprintf(q->edit_of, sizeof q->edit_of, "%s", edit_of);
    *ctx = q;
    return MHD_YES;
}

static enum MHD_Result handler(void* cls, struct MHD_Connection* c, const char* url, const char* method,
                               const char* version, const char* upload, size_t* upload_size, void** ctx) {
    (void)cls;
    (void)version;
    request* q = *ctx;
    if (q) {   // a later call: the body of POST /api/jobs, then its answer
        if (*upload_size) {
            size_t limit = q->edit_of[0] ? SERVE_EDIT_MAX_BODY : O.max_body;
            if (q->len + *upload_size > limit) q->too_big = 1;   // read on, kept no more
            else if (!mlb_reserve((void**)&q->body, &q->cap, q->len + *upload_size + 1, 1)) q->too_big = 1;
            else {
                memcpy(q->body + q->len, upload, *upload_size);
                q->len += *upload_size;
                q->body[q->len] = 0;   // cJSON's "nothing after the value" reads the end's NUL
            }
            *upload_size = 0;
            return MHD_YES;
        }
        return q->edit_of[0] ? save_edit(c, q) : submit(c, q);
    }
    // the first call: everything but a job's body is answered here, before any body is read
    if (atomic_load(&open_connections) > O.max_conns) return send_error(c, 429, "too many connections (--max-connections)");
    if (!authorised(c)) return send_error(c, 401, "a bearer token is required (Authorization: Bearer TOKEN)");
    if (!O.token && !host_is_loopback(c))
        return send_error(c, 403, "the Host header does not name this machine (127.0.0.1, localhost, [::1])");
    if (strchr(url, '%')) return send_error(c, 400, "percent-encoded URLs are refused (ids and file names need none)");
    char seg[5][64], path[4200];
    const char* type = NULL;
    int get = !strcmp(method, "GET") || !strcmp(method, "HEAD");
    if (!strncmp(url, "/view/", 6)) return get ? send_view(c, url) : send_405(c, "GET, HEAD");
    int n = split(url, seg);
    if (n < 0) return send_error(c, 404, "no such route");
    if (n == 0 || (n == 1 && !strcmp(seg[0], "serve.js"))) {
        if (!get) return send_405(c, "GET, HEAD");
        int rc = serve_static_app(n ? "serve.js" : "serve.html", path, sizeof path, &type);
        return send_static(c, rc, path, type);
    }
    if (n < 2 || strcmp(seg[0], "api") || strcmp(seg[1], "jobs")) return send_error(c, 404, "no such route");
    if (n == 2) {
        if (get) return send_text(c, 200, "application/json", serve_jobs_list_json());
        if (strcmp(method, "POST")) return send_405(c, "GET, HEAD, POST");
        const char* len = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Content-Length");
        if (len && strtoull(len, NULL, 10) > O.max_body)
            return send_error(c, 413, "the request body is over the server's limit (--max-body)");
        // JSON only: a form another site's page posts (no preflight for text/plain or a form) is refused
        const char* ct = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Content-Type");
        if (!ct || strncasecmp(ct, "application/json", 16) || (ct[16] && ct[16] != ';' && ct[16] != ' '))
            return send_error(c, 415, "the body must be sent as Content-Type: application/json");
        q = calloc(1, sizeof *q);
        if (!q) return MHD_NO;
        *ctx = q;
        return MHD_YES;
    }
    const char* id = seg[2];
    if (n == 3) {
        if (get) {
            char* text = serve_jobs_get_json(id);
            return text ? send_text(c, 200, "application/json", text) : send_error(c, 404, "no such job");
        }
        if (strcmp(method, "DELETE")) return send_405(c, "GET, HEAD, DELETE");
        const char* why = NULL;
        int rc = serve_jobs_cancel(id, &why);
        if (rc) return send_error(c, rc, why);
        return send_text(c, 200, "application/json", serve_jobs_get_json(id));
    }
    if (n == 4 && !strcmp(seg[3], "events")) return get ? send_events(c, id) : send_405(c, "GET, HEAD");
    if (n == 4 && !strcmp(seg[3], "edits")) {
        if (strcmp(method, "POST")) return send_405(c, "POST");
        return accept_edit(c, id, ctx);
    }
    if (n == 5 && !strcmp(seg[3], "files")) return get ? send_file(c, id, seg[4]) : send_405(c, "GET, HEAD");
    return send_error(c, 404, "no such route");
}

static void completed(void* cls, struct MHD_Connection* c, void** ctx, enum MHD_RequestTerminationCode why) {
    (void)cls;
    (void)c;
    (void)why;
    request* q = *ctx;
    if (q) { free(q->body); free(q); }
    *ctx = NULL;
}

static void connection_notice(void* cls, struct MHD_Connection* c, void** socket_ctx, enum MHD_ConnectionNotificationCode code) {
    (void)cls;
    (void)c;
    (void)socket_ctx;
    if (code == MHD_CONNECTION_NOTIFY_STARTED) atomic_fetch_add(&open_connections, 1);
    else atomic_fetch_sub(&open_connections, 1);
}

// The URL as sent: nothing decoded (a request's names are compared, and ours need no escapes)
static size_t no_unescape(void* cls, struct MHD_Connection* c, char* s) {
    (void)cls;
    (void)c;
    return strlen(s);
}

int serve_http_start(const serve_options* o) {
    O = *o;
    struct sockaddr_in a4;
    struct sockaddr_in6 a6;
    memset(&a4, 0, sizeof a4);
    memset(&a6, 0, sizeof a6);
    unsigned flags = MHD_USE_THREAD_PER_CONNECTION | MHD_USE_INTERNAL_POLLING_THREAD | MHD_USE_ERROR_LOG;
    const struct sockaddr* sa;
    const char* host = !strcmp(o->host, "localhost") ? "127.0.0.1" : o->host;
    if (inet_pton(AF_INET, host, &a4.sin_addr) == 1) {
        a4.sin_family = AF_INET;
        a4.sin_port = htons((uint16_t)o->port);
        sa = (const struct sockaddr*)&a4;
    } else if (inet_pton(AF_INET6, host, &a6.sin6_addr) == 1) {
        a6.sin6_family = AF_INET6;
        a6.sin6_port = htons((uint16_t)o->port);
        sa = (const struct sockaddr*)&a6;
        flags |= MHD_USE_IPv6;
    } else {
        fprintf(stderr, "matlaber serve: --host %s: not an IPv4 or IPv6 address\n", o->host);
        return -1;
    }
    daemon_ = MHD_start_daemon(flags, (uint16_t)o->port, NULL, NULL, handler, NULL, MHD_OPTION_SOCK_ADDR, sa,
                               MHD_OPTION_CONNECTION_TIMEOUT, (unsigned)o->timeout,
                               MHD_OPTION_CONNECTION_LIMIT, (unsigned)o->max_conns + 4,   // the 429 comes first
                               MHD_OPTION_NOTIFY_COMPLETED, completed, NULL,
                               MHD_OPTION_NOTIFY_CONNECTION, connection_notice, NULL,
                               MHD_OPTION_UNESCAPE_CALLBACK, no_unescape, NULL,
                               MHD_OPTION_THREAD_STACK_SIZE, (size_t)1 << 20, MHD_OPTION_END);
    if (!daemon_) {
        fprintf(stderr, "matlaber serve: cannot listen on %s port %d: %s\n", o->host, o->port, strerror(errno));
        return -1;
    }
    const union MHD_DaemonInfo* info = MHD_get_daemon_info(daemon_, MHD_DAEMON_INFO_BIND_PORT);
    return info ? info->port : o->port;
}

void serve_http_stop(void) {
    if (daemon_) MHD_stop_daemon(daemon_);
    daemon_ = NULL;
}
#endif
