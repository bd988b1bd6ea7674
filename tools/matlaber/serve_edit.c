// matlaber serve: POST /api/jobs/{id}/edits (serve.h, docs/server.md "Saving an edit"): a latent
// material edit made in the page, sent as its parameters (an offset, a region, a move toward another
// job's material), re-applied here to the job's own codes and decoded by its own decoder
// (latent_edit.h), written as a new job's run folder: final/asset.glb with its sidecars, the OBJ set
// and edit.json. The body is a few numbers, checked strictly; no image or path comes from it.
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include "matlaber/fileio.h"
#include "matlaber/latent_edit.h"
#include "serve.h"

#ifdef MLB_HAVE_MHD
#define MAX_OFFSET 64.0   // the codes spread over a few units; further is no material
#define MAX_RADIUS 64.0

typedef struct {
    double offset[4];
    int region, texel[2];   // region: a picked texel (x, y from the top row) and a radius
    double radius;
    int toward;             // toward: another job's mean code
    char other[64];
    double t;
} edit_request;

static int fail(char* err, size_t cap, int code, const char* msg, const char* what) {
    snprintf(err, cap, "%s%s%s", what ? what : "", what ? ": " : "", msg);
    return code;
}

// o holds only the keys of names, each once
static const char* unknown_key(const cJSON* o, const char* const* names) {
    for (const cJSON* k = o->child; k; k = k->next) {
        int known = 0;
        for (int i = 0; names[i]; i++) known |= !strcmp(k->string, names[i]);
        if (!known) return k->string;
        for (const cJSON* l = k->next; l; l = l->next)
            if (!strcmp(k->string, l->string)) return k->string;
    }
    return NULL;
}

// n numbers of o[key] in [-lim, lim] (integers when whole)
static int array_of(const cJSON* o, const char* key, int n, double lim, int whole, double* out) {
    const cJSON* a = cJSON_GetObjectItemCaseSensitive(o, key);
    if (!cJSON_IsArray(a) || cJSON_GetArraySize(a) != n) return 1;
    int i = 0;
    for (const cJSON* x = a->child; x; x = x->next, i++) {
        if (!cJSON_IsNumber(x) || !isfinite(x->valuedouble) || fabs(x->valuedouble) > lim) return 1;
        if (whole && x->valuedouble != floor(x->valuedouble)) return 1;
        out[i] = x->valuedouble;
    }
    return 0;
}

static int number_of(const cJSON* o, const char* key, double lo, double hi, double* out) {
    const cJSON* v = cJSON_GetObjectItemCaseSensitive(o, key);
    if (!cJSON_IsNumber(v) || !isfinite(v->valuedouble) || v->valuedouble < lo || v->valuedouble > hi) return 1;
    *out = v->valuedouble;
    return 0;
}

static int parse(const cJSON* r, edit_request* q, char* err, size_t cap) {
    static const char* const top[] = {"offset", "region", "toward", NULL};
    static const char* const region[] = {"texel", "radius", NULL};
    static const char* const toward[] = {"job", "t", NULL};
    memset(q, 0, sizeof *q);
    if (!cJSON_IsObject(r)) return fail(err, cap, 400, "the body must be a JSON object", NULL);
    const char* k = unknown_key(r, top);
    if (k) return fail(err, cap, 400, "an unknown or repeated key (offset, region, toward)", k);
    if (array_of(r, "offset", 4, MAX_OFFSET, 0, q->offset))
        return fail(err, cap, 400, "expected 4 numbers in [-64, 64]", "offset");
    const cJSON* g = cJSON_GetObjectItemCaseSensitive(r, "region");
    if (g && !cJSON_IsNull(g)) {
        double xy[2];
        if (!cJSON_IsObject(g)) return fail(err, cap, 400, "expected null or {\"texel\": [x, y], \"radius\": r}", "region");
        if ((k = unknown_key(g, region))) return fail(err, cap, 400, "an unknown or repeated key (texel, radius)", "region");
        if (array_of(g, "texel", 2, 16384, 1, xy)) return fail(err, cap, 400, "expected 2 integers", "region.texel");
        if (number_of(g, "radius", 0, MAX_RADIUS, &q->radius)) return fail(err, cap, 400, "expected a number in [0, 64]", "region.radius");
        q->region = 1;
        q->texel[0] = (int)xy[0];
        q->texel[1] = (int)xy[1];
    }
    const cJSON* w = cJSON_GetObjectItemCaseSensitive(r, "toward");
    if (w && !cJSON_IsNull(w)) {
        if (!cJSON_IsObject(w)) return fail(err, cap, 400, "expected null or {\"job\": ID, \"t\": t}", "toward");
        if ((k = unknown_key(w, toward))) return fail(err, cap, 400, "an unknown or repeated key (job, t)", "toward");
        const cJSON* j = cJSON_GetObjectItemCaseSensitive(w, "job");
        if (!cJSON_IsString(j) || !j->valuestring[0] || strlen(j->valuestring) > 63) return fail(err, cap, 400, "expected a job id", "toward.job");
        if (number_of(w, "t", 0, 1, &q->t)) return fail(err, cap, 400, "expected a number in [0, 1]", "toward.t");
        snprintf(q->other, sizeof q->other, "%s", j->valuestring);
        q->toward = 1;
    }
    return 0;
}

// A finished job's latent-mode asset: its .glb's path, 0; else 404 / 409 with the reason
static int latent_glb(const char* id, char* path, size_t cap, char* err, size_t errcap, const char* what) {
    const char* type;
    char side[4200];
    if (!serve_jobs_ended(id) || serve_jobs_file(id, "asset.glb", path, cap, &type))
        return fail(err, errcap, 404, "no such finished job with an asset.glb", what);
    if (serve_jobs_file(id, "asset.decoder.json", side, sizeof side, &type) || serve_jobs_file(id, "asset.latent.bin", side, sizeof side, &type))
        return fail(err, errcap, 409, "the job has no latent codes (a direct-mode material): nothing to edit", what);
    return 0;
}

static cJSON* floats(const float* v, int n) {
    cJSON* a = cJSON_CreateArray();
    for (int i = 0; i < n; i++) cJSON_AddItemToArray(a, cJSON_CreateNumber((double)v[i]));
    return a;
}

// The edit into dir (made here), atomically as a whole: written beside it, then renamed.
static int write_run(const char* dir, const char* src_glb, const mlb_latent_edit* e, cJSON* note, char* err, size_t cap) {
    char tmp[4300], path[4400], obj[4400];
    snprintf(tmp, sizeof tmp, "%s.part", dir);
    snprintf(path, sizeof path, "%s/final", tmp);
    size_t in = 0;
    mlb_status s = mlb_mkdir_p(path);
    snprintf(path, sizeof path, "%s/final/asset.glb", tmp);
    snprintf(obj, sizeof obj, "%s/final/asset.obj", tmp);
    if (!s) s = mlb_latent_edit_export(src_glb, e, path, obj, &in);
    cJSON_AddNumberToObject(note, "texels_edited", (double)in);
    char* text = cJSON_Print(note);
    snprintf(path, sizeof path, "%s/final/edit.json", tmp);
    if (!s) s = text ? mlb_write_file_atomic(path, text, strlen(text)) : mlb_fail(MLB_ERR_NOMEM, "out of memory");
    free(text);
    if (!s && rename(tmp, dir) != 0) s = mlb_fail(MLB_ERR_IO, "%s: could not rename it to %s", tmp, dir);
    if (s) return fail(err, cap, 500, mlb_last_error(), "saving the edit");
    return 0;
}

static pthread_mutex_t one_at_a_time = PTHREAD_MUTEX_INITIALIZER;

int serve_edit_save(const char* src, const char* body, size_t n, char* id, size_t cap, char* err, size_t errcap) {
    cJSON* r = cJSON_ParseWithLengthOpts(body, n + 1, NULL, 1);   // (+1: the NUL; trailing bytes refused)
    edit_request q;
    int rc = r ? parse(r, &q, err, errcap) : fail(err, errcap, 400, "malformed JSON", NULL);
    cJSON_Delete(r);
    if (rc) return rc;
    char src_glb[4200], other_glb[4200];
    if ((rc = latent_glb(src, src_glb, sizeof src_glb, err, errcap, src))) return rc;
    if (q.toward && (rc = latent_glb(q.other, other_glb, sizeof other_glb, err, errcap, "toward.job"))) return rc;
    // the decode takes a second or two at 1024²: one edit at a time, the next told to come back
    if (pthread_mutex_trylock(&one_at_a_time)) return fail(err, errcap, 429, "another edit is being saved: try again", NULL);
    mlb_latent_edit e = {.radius = -1};
    for (int c = 0; c < 4; c++) e.offset[c] = (float)q.offset[c];
    mlb_latent_asset a = {0}, b = {0};
    mlb_status s = mlb_latent_asset_read(src_glb, &a);
    if (!s && q.region) {
        if (q.texel[0] < 0 || q.texel[1] < 0 || q.texel[0] >= a.size || q.texel[1] >= a.size)
            rc = fail(err, errcap, 400, "outside the job's latent texture", "region.texel");
        else memcpy(e.pick, a.z + 4 * ((size_t)q.texel[1] * (size_t)a.size + (size_t)q.texel[0]), sizeof e.pick);
        e.radius = (float)q.radius;
    }
    if (!s && !rc && q.toward && !(s = mlb_latent_asset_read(other_glb, &b))) {
        mlb_latent_mean(b.z, (size_t)b.size * (size_t)b.size, e.target);
        e.t = (float)q.t;
    }
    if (s) rc = fail(err, errcap, 500, mlb_last_error(), "reading the job's latent codes");
    cJSON* req = NULL;
    char dir[4200];
    if (!rc) {   // the new job's request: what was asked, and the codes it came to
        req = cJSON_CreateObject();
        cJSON_AddStringToObject(req, "edit_of", src);
        cJSON_AddItemToObject(req, "offset", floats(e.offset, 4));
        if (q.region) {
            cJSON* g = cJSON_AddObjectToObject(req, "region");
            int xy[2] = {q.texel[0], q.texel[1]};
            cJSON_AddItemToObject(g, "texel", cJSON_CreateIntArray(xy, 2));
            cJSON_AddNumberToObject(g, "radius", q.radius);
            cJSON_AddItemToObject(g, "code", floats(e.pick, 4));
        }
        if (q.toward) {
            cJSON* w = cJSON_AddObjectToObject(req, "toward");
            cJSON_AddStringToObject(w, "job", q.other);
            cJSON_AddNumberToObject(w, "t", q.t);
            cJSON_AddItemToObject(w, "mean_code", floats(e.target, 4));
        }
        cJSON* note = cJSON_Duplicate(req, 1);
        rc = serve_jobs_edit_begin(src, req, id, cap, dir, sizeof dir);   // takes req
        if (rc) fail(err, errcap, rc, rc == 404 ? "no such job" : rc == 409 ? "the job is not done" : "out of memory", src);
        else {
            char why[1200] = "";
            int w = write_run(dir, src_glb, &e, note, why, sizeof why);
            serve_jobs_edit_end(id, w == 0, w ? why : NULL);
            if (w) rc = fail(err, errcap, w, why, NULL);
        }
        cJSON_Delete(note);
    }
    mlb_latent_asset_free(&a);
    mlb_latent_asset_free(&b);
    pthread_mutex_unlock(&one_at_a_time);
    return rc;
}
#endif
