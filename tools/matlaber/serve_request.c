// matlaber serve: a job request's JSON checked and turned into generate's arguments (serve.h).
// The request names no file: every key is a setting, strings go to generate only as option
// values, and generate's own checks (generate_check_args) judge them before the job is queued.
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "cli.h"
#include "matlaber/fileio.h"
#include "serve.h"

#ifdef MLB_HAVE_MHD
// A request's keys: the JSON name, generate's option, and what its value must be.
// K_SET: an integer setting of config.json that generate has no option for (--set KEY=N)
// K_MESH: {"format": "obj"|"glb", "data": base64}, a mesh to paint (the job is then `paint`)
enum { K_STRING, K_WORD, K_INT, K_NUMBER, K_SET, K_MESH };
typedef struct { const char* key; const char* option; int kind; } request_key;
static const request_key KEYS[] = {
    {"prompt", "--prompt", K_STRING},
    {"seed", "--seed", K_INT},
    {"preset", "--preset", K_WORD},
    {"negative", "--negative", K_STRING},
    {"init", "--init", K_WORD},
    {"views", "--views", K_INT},
    {"view_batch", "--view-batch", K_INT},
    {"res", "--res", K_INT},
    {"grid", "--grid", K_INT},
    {"geometry_iters", "--geometry-iters", K_INT},
    {"appearance_iters", "--appearance-iters", K_INT},
    {"init_iters", "--init-iters", K_INT},
    {"hash_table_log2", "--hash-table-log2", K_INT},
    {"export_texture", "--export-texture", K_INT},
    {"checkpoint_every", "--checkpoint-every", K_INT},
    {"preview_every", "--preview-every", K_INT},
    {"guidance_scale", "--guidance-scale", K_NUMBER},
    {"material_start", "--set", K_SET},
    {"mesh", "--mesh", K_MESH},
    {NULL, NULL, 0}};

// --init takes a shape name or an OBJ file: a request may name only the shapes
static const char* const INIT_WORDS[] = {"ellipsoid", "cylinder", "torus", "slab", "cup", "auto", NULL};

static const request_key* find_key(const char* name) {
    for (const request_key* k = KEYS; k->key; k++)
        if (!strcmp(k->key, name)) return k;
    return NULL;
}

// Text a person typed: no control characters (a prompt is one line of a config and a log).
static int printable(const char* s) {
    for (const unsigned char* p = (const unsigned char*)s; *p; p++)
        if (*p < 0x20 || *p == 0x7f) return 0;
    return 1;
}

static int is_word(const char* s) {
    if (!*s || strlen(s) > 32) return 0;
    for (const char* p = s; *p; p++)
        if (!((*p >= 'a' && *p <= 'z') || (*p >= '0' && *p <= '9') || *p == '_' || *p == '-')) return 0;
    return 1;
}

static int fail(char* err, size_t cap, int status, const char* fmt, const char* a) {
    snprintf(err, cap, fmt, a);
    return status;
}

// One value as generate's option text; 0 when it has the key's type.
static int value_text(const request_key* k, const cJSON* v, char* text, size_t cap) {
    switch (k->kind) {
    case K_STRING:
    case K_WORD:
        if (!cJSON_IsString(v) || !v->valuestring) return -1;
        snprintf(text, cap, "%s", v->valuestring);
        return 0;
    case K_SET:
    case K_INT: {
        // JSON numbers are doubles: integers up to 2^53 are exact, beyond they are not what was sent
        if (!cJSON_IsNumber(v)) return -1;
        double d = v->valuedouble;
        if (!isfinite(d) || d != floor(d) || d < 0 || d > 9007199254740991.0) return -1;
        if (k->kind == K_SET) snprintf(text, cap, "%s=%.0f", k->key, d);
        else snprintf(text, cap, "%.0f", d);
        return 0;
    }
    case K_NUMBER:
        if (!cJSON_IsNumber(v) || !isfinite(v->valuedouble)) return -1;
        snprintf(text, cap, "%.17g", v->valuedouble);
        return 0;
    case K_MESH: {   // (its file's path is the caller's: serve_request_args)
        const cJSON* f = cJSON_GetObjectItemCaseSensitive(v, "format");
        if (!cJSON_IsObject(v) || !cJSON_IsString(f) || (strcmp(f->valuestring, "obj") && strcmp(f->valuestring, "glb")))
            return -1;
        snprintf(text, cap, "%s", f->valuestring);
        return 0;
    }
    }
    return -1;
}

char** serve_request_args(const cJSON* req, const serve_options* o, const char* mesh_path) {
    int n = 0;
    for (const cJSON* v = req->child; v; v = v->next) n++;
    char** args = calloc((size_t)(2 * n + 3), sizeof *args);
    if (!args) return NULL;
    int a = 0, ok = 1;
    if (o->model) {
        args[a++] = strdup("--model");
        args[a++] = strdup(o->model);
    }
    for (const cJSON* v = req->child; v; v = v->next) {
        const request_key* k = find_key(v->string);
        char text[4096];
        if (!k || value_text(k, v, text, sizeof text)) continue;   // (checked before: not reached)
        args[a++] = strdup(k->option);
        args[a++] = strdup(k->kind == K_MESH ? (mesh_path ? mesh_path : "") : text);
    }
    for (int i = 0; i < a; i++) ok &= args[i] != NULL;
    if (!ok) { serve_args_free(args); return NULL; }
    return args;
}

void serve_args_free(char** args) {
    if (!args) return;
    for (char** p = args; *p; p++) free(*p);
    free(args);
}

// Standard base64 (RFC 4648, padded, no line breaks) into out (room for 3n/4 bytes); -1 when not.
static long base64_decode(const char* in, size_t n, unsigned char* out) {
    if (n % 4) return -1;
    long k = 0;
    for (size_t i = 0; i < n; i += 4) {
        int v[4], pad = 0;
        for (int j = 0; j < 4; j++) {
            char c = in[i + j];
            v[j] = c >= 'A' && c <= 'Z' ? c - 'A' : c >= 'a' && c <= 'z' ? c - 'a' + 26 : c >= '0' && c <= '9' ? c - '0' + 52
                 : c == '+' ? 62 : c == '/' ? 63 : c == '=' ? -2 : -1;
            if (v[j] == -1) return -1;
            if (v[j] == -2) { if (i + 4 != n || j < 2) return -1; pad++; v[j] = 0; }
            else if (pad) return -1;   // '=' only at the very end
        }
        unsigned x = (unsigned)(v[0] << 18 | v[1] << 12 | v[2] << 6 | v[3]);
        out[k++] = (unsigned char)(x >> 16);
        if (pad < 2) out[k++] = (unsigned char)(x >> 8);
        if (pad < 1) out[k++] = (unsigned char)x;
    }
    return k;
}

// The uploaded mesh into a folder of its own, RUNS/.serve/uploads/tmp-PID-N/mesh.FMT (a .gltf's
// external files, were it one, could name nothing else); 0, or the status with the reason.
static int write_upload(const cJSON* mesh, const serve_options* o, char* dir, size_t dcap, char* path, size_t pcap,
                        long* size, char* err, size_t cap) {
    static long counter;
    const cJSON* data = cJSON_GetObjectItemCaseSensitive(mesh, "data");
    const cJSON* format = cJSON_GetObjectItemCaseSensitive(mesh, "format");
    if (cJSON_GetArraySize(mesh) != 2 || !cJSON_IsString(data))
        return fail(err, cap, 400, "%s", "'mesh' must be {\"format\": \"obj\" or \"glb\", \"data\": base64}");
    size_t n = strlen(data->valuestring);
    unsigned char* bytes = malloc(n / 4 * 3 + 3);
    long m = bytes ? base64_decode(data->valuestring, n, bytes) : -1;
    if (m <= 0) { free(bytes); return fail(err, cap, 400, "%s", "'mesh.data' is not base64 (RFC 4648, padded, one line)"); }
    *size = m;
    snprintf(dir, dcap, "%s/.serve/uploads/tmp-%ld-%ld", o->runs, (long)getpid(), __atomic_fetch_add(&counter, 1, __ATOMIC_SEQ_CST));
    snprintf(path, pcap, "%s/mesh.%s", dir, format->valuestring);
    mlb_status s = mlb_mkdir_p(dir);
    if (!s) s = mlb_write_file_atomic(path, bytes, (size_t)m);
    free(bytes);
    if (s) return fail(err, cap, 500, "could not keep the upload: %s", mlb_last_error());
    return 0;
}

void serve_upload_discard(const char* dir) {
    if (!dir || !dir[0]) return;
    char path[4200];
    snprintf(path, sizeof path, "%s/mesh.obj", dir);
    unlink(path);
    snprintf(path, sizeof path, "%s/mesh.glb", dir);
    unlink(path);
    rmdir(dir);
}

// generate's checks use getopt (one global state): one request at a time
static pthread_mutex_t check_lock = PTHREAD_MUTEX_INITIALIZER;

int serve_request_parse(const char* body, size_t n, const serve_options* o, cJSON** out, char* upload, size_t ucap,
                        char* err, size_t cap) {
    *out = NULL;
    upload[0] = 0;
    if (n > o->max_body) return fail(err, cap, 413, "%s", "the request body is over the server's limit");
    if (memchr(body, 0, n)) return fail(err, cap, 400, "%s", "the request body holds a NUL byte");
    // cJSON decodes \u0000 into a NUL that would cut the string short: refused as the byte is
    for (const char* p = body; (p = strstr(p, "\\u")) != NULL; p += 2)
        if (!strncmp(p + 2, "0000", 4)) return fail(err, cap, 400, "%s", "a string holds \\u0000 (a NUL)");
    const char* end = NULL;
    // body[n] is a NUL, counted in: cJSON's "nothing may follow the value" wants it inside the length
    cJSON* req = cJSON_ParseWithLengthOpts(body, n + 1, &end, 1);
    if (!req) return fail(err, cap, 400, "%s", "the request body is not JSON");
    if (!cJSON_IsObject(req)) { cJSON_Delete(req); return fail(err, cap, 400, "%s", "the request must be a JSON object"); }
    int status = 0;
    for (const cJSON* v = req->child; v && !status; v = v->next) {
        const request_key* k = find_key(v->string);
        char text[4096];
        if (!k) status = fail(err, cap, 400, "unknown key '%.64s' (docs/server.md lists the keys)", v->string);
        else if (cJSON_GetObjectItemCaseSensitive(req, v->string) != v)
            status = fail(err, cap, 400, "key '%s' is given twice", k->key);
        else if (value_text(k, v, text, sizeof text))
            status = fail(err, cap, 400,
                          k->kind == K_INT || k->kind == K_SET ? "'%s' must be a non-negative integer"
                          : k->kind == K_NUMBER ? "'%s' must be a number"
                          : k->kind == K_MESH ? "'%s' must be {\"format\": \"obj\" or \"glb\", \"data\": base64}"
                          : "'%s' must be a string", k->key);
        else if (k->kind == K_STRING && !printable(text))
            status = fail(err, cap, 400, "'%s' holds a control character", k->key);
        else if (k->kind == K_STRING && strlen(text) > (size_t)o->max_prompt)
            status = fail(err, cap, 400, "'%s' is longer than the server's limit", k->key);
        else if (k->kind == K_WORD && !is_word(text))
            status = fail(err, cap, 400, "'%s' must be a name of a-z, 0-9, _ and -", k->key);
        if (!status && !strcmp(v->string, "init")) {
            int known = 0;
            for (int i = 0; INIT_WORDS[i]; i++) known |= !strcmp(text, INIT_WORDS[i]);
            if (!known) status = fail(err, cap, 400, "'init' must be one of ellipsoid, cylinder, torus, slab, cup, auto%s", "");
        }
    }
    const cJSON* prompt = cJSON_GetObjectItemCaseSensitive(req, "prompt");
    if (!status && (!prompt || !prompt->valuestring[0])) status = fail(err, cap, 400, "%s", "'prompt' is required");
    cJSON* mesh = cJSON_GetObjectItemCaseSensitive(req, "mesh");
    char mesh_path[4300] = "";
    long mesh_bytes = 0;
    if (!status && mesh) status = write_upload(mesh, o, upload, ucap, mesh_path, sizeof mesh_path, &mesh_bytes, err, cap);
    if (!status) {   // generate's (paint's) own checks on exactly the arguments the job will run with
        char** args = serve_request_args(req, o, mesh_path);
        if (!args) status = fail(err, cap, 500, "%s", "out of memory");
        int m = 0;
        while (args && args[m]) m++;
        char** argv = args ? calloc((size_t)m + 4, sizeof *argv) : NULL;
        if (args && !argv) status = fail(err, cap, 500, "%s", "out of memory");
        if (argv) {
            argv[0] = mesh ? "paint" : "generate";
            for (int i = 0; i < m; i++) argv[i + 1] = args[i];
            argv[m + 1] = "-o";
            argv[m + 2] = "(checked only)";   // the run folder is the server's
            pthread_mutex_lock(&check_lock);
            cli_set_quiet(1);
            int rc = generate_check_args(m + 3, argv);
            cli_set_quiet(0);
            if (rc) {   // the upload's place is the server's business: the message says "the mesh"
                char msg[1200];
                snprintf(msg, sizeof msg, "%s", cli_last_message());
                char* at = mesh_path[0] ? strstr(msg, mesh_path) : NULL;
                if (at) {   // (the path is longer than "the mesh": the rest moves left)
                    const char* rest = at + strlen(mesh_path);
                    memmove(at + 8, rest, strlen(rest) + 1);
                    memcpy(at, "the mesh", 8);
                }
                status = fail(err, cap, 400, "%s", msg);
            }
            pthread_mutex_unlock(&check_lock);
        }
        free(argv);
        serve_args_free(args);
    }
    if (status) {
        cJSON_Delete(req);
        serve_upload_discard(upload);
        upload[0] = 0;
        return status;
    }
    if (mesh) {   // the record keeps the mesh's format and size; its bytes are the upload's file
        const cJSON* f = cJSON_GetObjectItemCaseSensitive(mesh, "format");
        cJSON* kept = cJSON_CreateObject();
        cJSON_AddStringToObject(kept, "format", f->valuestring);
        cJSON_AddNumberToObject(kept, "bytes", (double)mesh_bytes);
        cJSON_ReplaceItemInObjectCaseSensitive(req, "mesh", kept);
    }
    *out = req;
    return 0;
}
#endif
