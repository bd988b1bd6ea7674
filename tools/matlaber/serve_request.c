// matlaber serve: a job request's JSON checked and turned into generate's arguments (serve.h).
// The request names no file: every key is a setting, strings go to generate only as option
// values, and generate's own checks (generate_check_args) judge them before the job is queued.
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cli.h"
#include "serve.h"

#ifdef MLB_HAVE_MHD
// A request's keys: the JSON name, generate's option, and what its value must be.
// K_SET: an integer setting of config.json that generate has no option for (--set KEY=N)
enum { K_STRING, K_WORD, K_INT, K_NUMBER, K_SET };
typedef struct { const char* key; const char* option; int kind; } request_key;
static const request_key KEYS[] = {
    {"prompt", "--prompt", K_STRING},
    {"seed", "--seed", K_INT},
    {"preset", "--preset", K_WORD},
    {"negative", "--negative", K_STRING},
    {"init", "--init", K_WORD},
    {"views", "--views", K_INT},
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
    }
    return -1;
}

char** serve_request_args(const cJSON* req, const serve_options* o) {
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
        args[a++] = strdup(text);
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

// generate's checks use getopt (one global state): one request at a time
static pthread_mutex_t check_lock = PTHREAD_MUTEX_INITIALIZER;

int serve_request_parse(const char* body, size_t n, const serve_options* o, cJSON** out, char* err, size_t cap) {
    *out = NULL;
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
                          : k->kind == K_NUMBER ? "'%s' must be a number" : "'%s' must be a string", k->key);
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
    if (!status) {   // generate's own checks on exactly the arguments the job will run with
        char** args = serve_request_args(req, o);
        if (!args) status = fail(err, cap, 500, "%s", "out of memory");
        int m = 0;
        while (args && args[m]) m++;
        char** argv = args ? calloc((size_t)m + 4, sizeof *argv) : NULL;
        if (args && !argv) status = fail(err, cap, 500, "%s", "out of memory");
        if (argv) {
            argv[0] = "generate";
            for (int i = 0; i < m; i++) argv[i + 1] = args[i];
            argv[m + 1] = "-o";
            argv[m + 2] = "(checked only)";   // the run folder is the server's
            pthread_mutex_lock(&check_lock);
            cli_set_quiet(1);
            int rc = generate_check_args(m + 3, argv);
            cli_set_quiet(0);
            if (rc) status = fail(err, cap, 400, "%s", cli_last_message());
            pthread_mutex_unlock(&check_lock);
        }
        free(argv);
        serve_args_free(args);
    }
    if (status) { cJSON_Delete(req); return status; }
    *out = req;
    return 0;
}
#endif
