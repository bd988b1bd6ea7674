// Multi-view image data sets: cameras.json reading / writing, image loading and resampling, and
// rendering a data set from a mesh (include/matlaber/views.h, docs/views.md).
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <cjson/cJSON.h>
#include "matlaber/brdf.h"
#include "matlaber/fileio.h"
#include "matlaber/geometry_fit.h"
#include "matlaber/image.h"
#include "matlaber/image_write.h"
#include "matlaber/render.h"
#include "matlaber/rng.h"
#include "matlaber/views.h"

enum { STREAM_VIEWS_RENDER = 0x71E5 };

// ---- cameras.json: reading -------------------------------------------------------------------------

typedef struct {
    const char* file;   // cameras.json path, for messages
} jctx;

// "file: path: " + message, with `code`: JFAIL(code, jc, path, fmt, ...).
#define JFAIL(code, jc, path, ...) jfail_where(jc, path, mlb_fail(code, __VA_ARGS__))
static mlb_status jfail_where(const jctx* jc, const char* path, mlb_status code) {
    return mlb_fail_context(code, "%s: %s", jc->file, path);
}

// A number member: required → error when missing; else *out keeps its default.
static mlb_status jnum(const jctx* jc, const cJSON* obj, const char* key, const char* where, int required, double* out) {
    char path[160];
    snprintf(path, sizeof path, "%s.%s", where, key);
    const cJSON* it = cJSON_GetObjectItemCaseSensitive(obj, key);
    if (!it) return required ? JFAIL(MLB_ERR_FORMAT, jc, path, "missing") : MLB_OK;
    if (!cJSON_IsNumber(it)) return JFAIL(MLB_ERR_FORMAT, jc, path, "not a number");
    if (!isfinite(it->valuedouble)) return JFAIL(MLB_ERR_FORMAT, jc, path, "not a finite number");
    *out = it->valuedouble;
    return MLB_OK;
}

// Numbers of a JSON array of exactly n.
static mlb_status jvec(const jctx* jc, const cJSON* arr, const char* path, int n, double* out) {
    if (!cJSON_IsArray(arr)) return JFAIL(MLB_ERR_FORMAT, jc, path, "not an array");
    if (cJSON_GetArraySize(arr) != n) return JFAIL(MLB_ERR_FORMAT, jc, path, "expected %d numbers, got %d", n, cJSON_GetArraySize(arr));
    int i = 0;
    for (const cJSON* e = arr->child; e; e = e->next, i++) {
        if (!cJSON_IsNumber(e)) return JFAIL(MLB_ERR_FORMAT, jc, path, "element %d: not a number", i);
        if (!isfinite(e->valuedouble)) return JFAIL(MLB_ERR_FORMAT, jc, path, "element %d: not a finite number", i);
        out[i] = e->valuedouble;
    }
    return MLB_OK;
}

// A relative path that stays inside the folder: not empty, not absolute, no ".." component, no
// backslash or control character, shorter than MLB_VIEWS_PATH_MAX.
static const char* bad_relpath(const char* p) {
    size_t n = strlen(p);
    if (n == 0) return "empty path";
    if (n >= MLB_VIEWS_PATH_MAX) return "path too long";
    if (p[0] == '/') return "absolute path (must be relative to the folder)";
    for (size_t i = 0; i < n; i++) {
        unsigned char c = (unsigned char)p[i];
        if (c < 32 || c == 127) return "control character in path";
        if (c == '\\') return "backslash in path";
    }
    const char* s = p;
    while (*s) {
        const char* e = strchr(s, '/');
        size_t len = e ? (size_t)(e - s) : strlen(s);
        if (len == 2 && s[0] == '.' && s[1] == '.') return "path leaves the folder ('..')";
        if (!e) break;
        s = e + 1;
    }
    return NULL;
}

static mlb_status jpath(const jctx* jc, const cJSON* obj, const char* key, const char* where, int required, char* out) {
    char path[160];
    snprintf(path, sizeof path, "%s.%s", where, key);
    const cJSON* it = cJSON_GetObjectItemCaseSensitive(obj, key);
    if (!it) return required ? JFAIL(MLB_ERR_FORMAT, jc, path, "missing") : MLB_OK;
    if (!cJSON_IsString(it) || !it->valuestring) return JFAIL(MLB_ERR_FORMAT, jc, path, "not a string");
    const char* bad = bad_relpath(it->valuestring);
    if (bad) return JFAIL(MLB_ERR_FORMAT, jc, path, "%s", bad);
    snprintf(out, MLB_VIEWS_PATH_MAX, "%s", it->valuestring);
    return MLB_OK;
}

static int is_integer(double x) { return isfinite(x) && x == floor(x); }

// Range checks shared by the reader and the writer.
static mlb_status check_entry(const jctx* jc, const mlb_views_entry* e, int i, int n_envs) {
    char w[64];
    snprintf(w, sizeof w, "views[%d]", i);
    char p[160];
#define RANGE(cond, key, ...) do { if (!(cond)) { snprintf(p, sizeof p, "%s.%s", w, key); return JFAIL(MLB_ERR_FORMAT, jc, p, __VA_ARGS__); } } while (0)
    RANGE(e->fovy_deg > 0 && e->fovy_deg < 180, "fovy_deg", "%g outside (0, 180)", e->fovy_deg);
    RANGE(e->near_z > 0 && e->far_z > e->near_z && isfinite(e->far_z), "near", "need 0 < near < far, got %g, %g", e->near_z, e->far_z);
    RANGE(e->env >= -1 && e->env < n_envs, "env", "index %d outside the %d environments", e->env, n_envs);
    RANGE(isfinite(e->env_rotation_deg) && fabs(e->env_rotation_deg) <= 1e6, "env_rotation_deg", "not a finite angle");
    if (e->orbit) {
        RANGE(e->radius > 0 && e->radius <= 1e6, "orbit.radius", "%g: expected 0 < radius <= 1e6", e->radius);
        RANGE(e->elevation_deg >= -90 && e->elevation_deg <= 90, "orbit.elevation_deg", "%g outside [-90, 90]", e->elevation_deg);
        RANGE(fabs(e->azimuth_deg) <= 1e6, "orbit.azimuth_deg", "%g: too large", e->azimuth_deg);
        for (int k = 0; k < 3; k++) RANGE(isfinite(e->target[k]) && fabs(e->target[k]) <= 1e6, "orbit.target", "not finite");
    } else {
        for (int k = 0; k < 16; k++) RANGE(isfinite(e->camera_to_world[k]) && fabs(e->camera_to_world[k]) <= 1e6, "camera_to_world", "not finite");
        mlb_camera cam;
        mlb_views_entry tmp = *e;
        if (mlb_views_entry_camera(&cam, &tmp)) RANGE(0, "camera_to_world", "%s", mlb_last_error());
    }
    const char* bad = bad_relpath(e->image);
    RANGE(!bad, "image", "%s", bad);
    if (e->normal[0]) { bad = bad_relpath(e->normal); RANGE(!bad, "normal", "%s", bad); }
#undef RANGE
    return MLB_OK;
}

static mlb_status parse_env(const jctx* jc, const cJSON* o, int i, mlb_views_env* env) {
    char w[64];
    snprintf(w, sizeof w, "environments[%d]", i);
    if (!cJSON_IsObject(o)) return JFAIL(MLB_ERR_FORMAT, jc, w, "not an object");
    memset(env, 0, sizeof *env);
    env->scale = 1;
    const cJSON* name = cJSON_GetObjectItemCaseSensitive(o, "name");
    const cJSON* file = cJSON_GetObjectItemCaseSensitive(o, "file");
    if (!!name == !!file) return JFAIL(MLB_ERR_FORMAT, jc, w, "expected exactly one of \"name\" (built-in) or \"file\"");
    if (name) {
        char p[96];
        snprintf(p, sizeof p, "%s.name", w);
        if (!cJSON_IsString(name) || !name->valuestring) return JFAIL(MLB_ERR_FORMAT, jc, p, "not a string");
        if (!mlb_envmap_is_builtin(name->valuestring))
            return JFAIL(MLB_ERR_FORMAT, jc, p, "'%.64s' is not a built-in environment (%s)", name->valuestring, mlb_envmap_builtin_list());
        snprintf(env->name, sizeof env->name, "%s", name->valuestring);
    } else {
        MLB_TRY(jpath(jc, o, "file", w, 1, env->file));
    }
    MLB_TRY(jnum(jc, o, "scale", w, 0, &env->scale));
    if (!(env->scale >= 0 && env->scale <= 1e9)) {
        char p[96];
        snprintf(p, sizeof p, "%s.scale", w);
        return JFAIL(MLB_ERR_FORMAT, jc, p, "%g: expected 0 <= scale <= 1e9", env->scale);
    }
    return MLB_OK;
}

static mlb_status parse_view(const jctx* jc, const cJSON* o, int i, int n_envs, mlb_views_entry* e) {
    char w[64];
    snprintf(w, sizeof w, "views[%d]", i);
    if (!cJSON_IsObject(o)) return JFAIL(MLB_ERR_FORMAT, jc, w, "not an object");
    memset(e, 0, sizeof *e);
    e->near_z = MLB_ORBIT_NEAR;
    e->far_z = MLB_ORBIT_FAR;
    e->env = -1;
    MLB_TRY(jpath(jc, o, "image", w, 1, e->image));
    MLB_TRY(jpath(jc, o, "normal", w, 0, e->normal));
    int has_fovy = cJSON_GetObjectItemCaseSensitive(o, "fovy_deg") != NULL;
    MLB_TRY(jnum(jc, o, "fovy_deg", w, 0, &e->fovy_deg));
    MLB_TRY(jnum(jc, o, "near", w, 0, &e->near_z));
    MLB_TRY(jnum(jc, o, "far", w, 0, &e->far_z));
    MLB_TRY(jnum(jc, o, "env_rotation_deg", w, 0, &e->env_rotation_deg));
    double env = -1;
    MLB_TRY(jnum(jc, o, "env", w, 0, &env));
    char p[160];
    snprintf(p, sizeof p, "%s.env", w);
    if (cJSON_GetObjectItemCaseSensitive(o, "env") && (!is_integer(env) || env < 0 || env >= n_envs))
        return JFAIL(MLB_ERR_FORMAT, jc, p, "%g is not an index into the %d environments", env, n_envs);
    e->env = (int)env;
    const cJSON* orbit = cJSON_GetObjectItemCaseSensitive(o, "orbit");
    const cJSON* c2w = cJSON_GetObjectItemCaseSensitive(o, "camera_to_world");
    if (!!orbit == !!c2w) return JFAIL(MLB_ERR_FORMAT, jc, w, "expected exactly one camera: \"orbit\" or \"camera_to_world\"");
    if (orbit) {
        snprintf(p, sizeof p, "%s.orbit", w);
        if (!cJSON_IsObject(orbit)) return JFAIL(MLB_ERR_FORMAT, jc, p, "not an object");
        e->orbit = 1;
        MLB_TRY(jnum(jc, orbit, "azimuth_deg", p, 1, &e->azimuth_deg));
        MLB_TRY(jnum(jc, orbit, "elevation_deg", p, 1, &e->elevation_deg));
        MLB_TRY(jnum(jc, orbit, "radius", p, 1, &e->radius));
        if (cJSON_GetObjectItemCaseSensitive(orbit, "fovy_deg")) {   // also accepted inside the orbit
            double f = 0;
            MLB_TRY(jnum(jc, orbit, "fovy_deg", p, 1, &f));
            if (has_fovy && f != e->fovy_deg)
                return JFAIL(MLB_ERR_FORMAT, jc, p, "fovy_deg %g differs from %s.fovy_deg %g", f, w, e->fovy_deg);
            e->fovy_deg = f;
            has_fovy = 1;
        }
        const cJSON* t = cJSON_GetObjectItemCaseSensitive(orbit, "target");
        if (t) {
            char tp[192];
            snprintf(tp, sizeof tp, "%s.target", p);
            MLB_TRY(jvec(jc, t, tp, 3, e->target));
        }
    } else {
        snprintf(p, sizeof p, "%s.camera_to_world", w);
        if (!has_fovy) return JFAIL(MLB_ERR_FORMAT, jc, p, "needs %s.fovy_deg", w);
        if (!cJSON_IsArray(c2w) || cJSON_GetArraySize(c2w) != 4) return JFAIL(MLB_ERR_FORMAT, jc, p, "expected 4 rows of 4 numbers");
        int r = 0;
        for (const cJSON* row = c2w->child; row; row = row->next, r++) {
            char rp[192];
            snprintf(rp, sizeof rp, "%s[%d]", p, r);
            MLB_TRY(jvec(jc, row, rp, 4, e->camera_to_world + 4 * r));
        }
    }
    if (!has_fovy) {
        snprintf(p, sizeof p, "%s.fovy_deg", w);
        return JFAIL(MLB_ERR_FORMAT, jc, p, "missing");
    }
    return check_entry(jc, e, i, n_envs);
}

void mlb_views_meta_free(mlb_views_meta* m) {
    if (!m) return;
    free(m->views);
    free(m->envs);
    memset(m, 0, sizeof *m);
}

static mlb_status meta_parse(mlb_views_meta* out, const char* text, size_t n, const char* file) {
    jctx jc = {file};
    cJSON* root = cJSON_ParseWithLength(text, n);
    if (!root) {
        const char* at = cJSON_GetErrorPtr();
        long off = (at && at >= text && at <= text + n) ? (long)(at - text) : -1;
        return mlb_fail(MLB_ERR_FORMAT, "%s: not valid JSON (near byte %ld)", file, off);
    }
    mlb_status s = MLB_OK;
    mlb_views_meta m = {0};
    const cJSON* fmt = cJSON_GetObjectItemCaseSensitive(root, "format");
    const cJSON* ver = cJSON_GetObjectItemCaseSensitive(root, "version");
    const cJSON* envs = cJSON_GetObjectItemCaseSensitive(root, "environments");
    const cJSON* views = cJSON_GetObjectItemCaseSensitive(root, "views");
    if (!cJSON_IsObject(root)) s = JFAIL(MLB_ERR_FORMAT, &jc, "(top)", "not an object");
    else if (!fmt) s = JFAIL(MLB_ERR_FORMAT, &jc, "format", "missing (expected \"%s\")", MLB_VIEWS_FORMAT);
    else if (!cJSON_IsString(fmt) || strcmp(fmt->valuestring, MLB_VIEWS_FORMAT) != 0)
        s = JFAIL(MLB_ERR_FORMAT, &jc, "format", "expected \"%s\"", MLB_VIEWS_FORMAT);
    else if (!ver) s = JFAIL(MLB_ERR_FORMAT, &jc, "version", "missing");
    else if (!cJSON_IsNumber(ver) || !is_integer(ver->valuedouble)) s = JFAIL(MLB_ERR_FORMAT, &jc, "version", "not an integer");
    else if (ver->valuedouble != MLB_VIEWS_VERSION)
        s = JFAIL(MLB_ERR_UNSUPPORTED, &jc, "version", "%g is not supported (this program reads version %d)", ver->valuedouble, MLB_VIEWS_VERSION);
    else if (envs && !cJSON_IsArray(envs)) s = JFAIL(MLB_ERR_FORMAT, &jc, "environments", "not an array");
    else if (!views) s = JFAIL(MLB_ERR_FORMAT, &jc, "views", "missing");
    else if (!cJSON_IsArray(views)) s = JFAIL(MLB_ERR_FORMAT, &jc, "views", "not an array");
    if (!s) {
        int ne = envs ? cJSON_GetArraySize(envs) : 0, nv = cJSON_GetArraySize(views);
        if (ne > MLB_VIEWS_MAX_ENVS) s = JFAIL(MLB_ERR_FORMAT, &jc, "environments", "%d entries, more than %d", ne, MLB_VIEWS_MAX_ENVS);
        else if (nv > MLB_VIEWS_MAX_VIEWS) s = JFAIL(MLB_ERR_FORMAT, &jc, "views", "%d entries, more than %d", nv, MLB_VIEWS_MAX_VIEWS);
        if (!s) {
            m.envs = calloc((size_t)(ne > 0 ? ne : 1), sizeof *m.envs);
            m.views = calloc((size_t)(nv > 0 ? nv : 1), sizeof *m.views);
            if (!m.envs || !m.views) s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", file);
        }
        int i = 0;
        for (const cJSON* e = envs ? envs->child : NULL; e && !s; e = e->next, i++) s = parse_env(&jc, e, i, &m.envs[i]);
        m.n_envs = ne;
        if (!s && nv < 1) s = JFAIL(MLB_ERR_FORMAT, &jc, "views", "empty");
        i = 0;
        for (const cJSON* v = views->child; v && !s; v = v->next, i++) s = parse_view(&jc, v, i, ne, &m.views[i]);
        m.n_views = nv;
    }
    cJSON_Delete(root);
    if (s) { mlb_views_meta_free(&m); return s; }
    *out = m;
    return MLB_OK;
}

static void join(char* out, size_t n, const char* dir, const char* rel) {
    size_t d = strlen(dir);
    snprintf(out, n, "%s%s%s", dir, (d && dir[d - 1] == '/') ? "" : "/", rel);
}

mlb_status mlb_views_meta_read(mlb_views_meta* out, const char* dir) {
    memset(out, 0, sizeof *out);
    char file[4400];
    join(file, sizeof file, dir, "cameras.json");
    if (strlen(dir) > 4000) return mlb_fail(MLB_ERR_ARG, "views: folder name too long");
    char* text = NULL;
    size_t n = 0;
    mlb_status s = mlb_read_file(file, &text, &n, MLB_VIEWS_MAX_JSON);
    if (s) return s;
    s = meta_parse(out, text, n, file);
    free(text);
    return s;
}

// ---- cameras.json: writing ---------------------------------------------------------------------------

mlb_status mlb_views_meta_write(const char* dir, const mlb_views_meta* m) {
    char file[4400];
    join(file, sizeof file, dir, "cameras.json");
    jctx jc = {file};
    if (m->n_views < 1 || m->n_views > MLB_VIEWS_MAX_VIEWS || m->n_envs < 0 || m->n_envs > MLB_VIEWS_MAX_ENVS)
        return mlb_fail(MLB_ERR_ARG, "%s: %d views, %d environments (need 1..%d, 0..%d)", file, m->n_views, m->n_envs,
                        MLB_VIEWS_MAX_VIEWS, MLB_VIEWS_MAX_ENVS);
    for (int i = 0; i < m->n_envs; i++) {
        const mlb_views_env* e = &m->envs[i];
        char w[64];
        snprintf(w, sizeof w, "environments[%d]", i);
        if (!!e->name[0] == !!e->file[0]) return JFAIL(MLB_ERR_ARG, &jc, w, "needs exactly one of name and file");
        if (e->name[0] && !mlb_envmap_is_builtin(e->name)) return JFAIL(MLB_ERR_ARG, &jc, w, "'%s' is not built in", e->name);
        if (e->file[0] && bad_relpath(e->file)) return JFAIL(MLB_ERR_ARG, &jc, w, "%s", bad_relpath(e->file));
        if (!(e->scale >= 0 && e->scale <= 1e9)) return JFAIL(MLB_ERR_ARG, &jc, w, "scale %g", e->scale);
    }
    for (int i = 0; i < m->n_views; i++) MLB_TRY(check_entry(&jc, &m->views[i], i, m->n_envs));
    cJSON* root = cJSON_CreateObject();
    mlb_status s = root ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", file);
    if (!s) {
        cJSON_AddStringToObject(root, "format", MLB_VIEWS_FORMAT);
        cJSON_AddNumberToObject(root, "version", MLB_VIEWS_VERSION);
        cJSON* envs = cJSON_AddArrayToObject(root, "environments");
        for (int i = 0; i < m->n_envs && envs; i++) {
            cJSON* o = cJSON_CreateObject();
            if (!o) break;
            if (m->envs[i].name[0]) cJSON_AddStringToObject(o, "name", m->envs[i].name);
            else {
                cJSON_AddStringToObject(o, "file", m->envs[i].file);
                cJSON_AddNumberToObject(o, "scale", m->envs[i].scale);
            }
            cJSON_AddItemToArray(envs, o);
        }
        cJSON* views = cJSON_AddArrayToObject(root, "views");
        for (int i = 0; i < m->n_views && views; i++) {
            const mlb_views_entry* e = &m->views[i];
            cJSON* o = cJSON_CreateObject();
            if (!o) break;
            cJSON_AddStringToObject(o, "image", e->image);
            if (e->normal[0]) cJSON_AddStringToObject(o, "normal", e->normal);
            if (e->orbit) {
                cJSON* ob = cJSON_AddObjectToObject(o, "orbit");
                cJSON_AddNumberToObject(ob, "azimuth_deg", e->azimuth_deg);
                cJSON_AddNumberToObject(ob, "elevation_deg", e->elevation_deg);
                cJSON_AddNumberToObject(ob, "radius", e->radius);
                cJSON_AddItemToObject(ob, "target", cJSON_CreateDoubleArray(e->target, 3));
            } else {
                cJSON* rows = cJSON_AddArrayToObject(o, "camera_to_world");
                for (int r = 0; r < 4; r++) cJSON_AddItemToArray(rows, cJSON_CreateDoubleArray(e->camera_to_world + 4 * r, 4));
            }
            cJSON_AddNumberToObject(o, "fovy_deg", e->fovy_deg);
            cJSON_AddNumberToObject(o, "near", e->near_z);
            cJSON_AddNumberToObject(o, "far", e->far_z);
            if (e->env >= 0) {
                cJSON_AddNumberToObject(o, "env", e->env);
                cJSON_AddNumberToObject(o, "env_rotation_deg", e->env_rotation_deg);
            }
            cJSON_AddItemToArray(views, o);
        }
        char* text = cJSON_Print(root);
        if (!text) s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", file);
        else {
            size_t n = strlen(text);
            char* t2 = malloc(n + 2);
            if (!t2) s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", file);
            else {
                memcpy(t2, text, n);
                t2[n] = '\n';
                s = mlb_write_file_atomic(file, t2, n + 1);
                free(t2);
            }
            cJSON_free(text);
        }
        cJSON_Delete(root);
    }
    return s;
}

// ---- cameras -----------------------------------------------------------------------------------------

mlb_status mlb_views_entry_camera(mlb_camera* cam, const mlb_views_entry* e) {
    if (e->orbit)
        return mlb_camera_orbit(cam, e->azimuth_deg, e->elevation_deg, e->radius, e->target, e->fovy_deg, 1.0, e->near_z,
                                e->far_z);
    const double* M = e->camera_to_world;
    // columns 0..2 of the rotation: the camera's right, up, back axes in world space
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) {
            double d = M[a] * M[b] + M[4 + a] * M[4 + b] + M[8 + a] * M[8 + b];
            if (!(fabs(d - (a == b)) <= 1e-3))
                return mlb_fail(MLB_ERR_ARG, "camera_to_world: the rotation is not orthonormal (columns %d, %d: dot %g)", a, b, d);
        }
    if (!(M[12] == 0 && M[13] == 0 && M[14] == 0 && M[15] == 1))
        return mlb_fail(MLB_ERR_ARG, "camera_to_world: last row must be 0 0 0 1");
    double det = M[0] * (M[5] * M[10] - M[6] * M[9]) - M[1] * (M[4] * M[10] - M[6] * M[8]) + M[2] * (M[4] * M[9] - M[5] * M[8]);
    if (!(det > 0)) return mlb_fail(MLB_ERR_ARG, "camera_to_world: the rotation is a reflection (determinant %g)", det);
    mlb_camera c;
    memset(&c, 0, sizeof c);
    c.fovy_deg = e->fovy_deg;
    c.aspect = 1;
    c.near_z = e->near_z;
    c.far_z = e->far_z;
    double eye[3] = {M[3], M[7], M[11]};
    c.view = mlb_mat4_identity();
    for (int r = 0; r < 3; r++) {   // view = [R^T, -R^T t]
        double t = 0;
        for (int k = 0; k < 3; k++) {
            c.view.m[4 * r + k] = M[4 * k + r];
            t += M[4 * k + r] * eye[k];
        }
        c.view.m[4 * r + 3] = -t;
    }
    for (int k = 0; k < 3; k++) {
        c.eye[k] = eye[k];
        c.target[k] = eye[k] - M[4 * k + 2];   // one unit along the viewing direction (−back)
    }
    double r = sqrt(eye[0] * eye[0] + eye[1] * eye[1] + eye[2] * eye[2]);
    c.radius = r;
    c.azimuth_deg = r > 0 ? atan2(eye[0], eye[2]) * 180 / M_PI : 0;
    c.elevation_deg = r > 0 ? asin(fmax(-1, fmin(1, eye[1] / r))) * 180 / M_PI : 0;
    MLB_TRY(mlb_perspective(&c.proj, e->fovy_deg, 1.0, e->near_z, e->far_z));
    c.view_proj = mlb_mat4_mul(&c.proj, &c.view);
    *cam = c;
    return MLB_OK;
}

// ---- images --------------------------------------------------------------------------------------------

// Output pixel x of res over n source pixels, centres aligned and clamped at the edges: the two
// source pixels *x0, *x1 it lies between and its weight on *x1 (returned).
static double bilinear_taps(int x, int n, int res, int* x0, int* x1) {
    double s = (x + 0.5) * n / res - 0.5;
    if (s < 0) s = 0;
    if (s > n - 1) s = n - 1;
    *x0 = (int)s;
    *x1 = *x0 + 1 < n ? *x0 + 1 : *x0;
    return s - *x0;
}

mlb_status mlb_views_resample(float* out, int res, const float* in, int w, int h, int c) {
    if (res < 1 || w < 1 || h < 1 || c < 1 || res > MLB_VIEWS_MAX_SIZE || w > 65536 || h > 65536)
        return mlb_fail(MLB_ERR_ARG, "views: resampling %dx%d to %d", w, h, res);
    if (w % res == 0 && h % res == 0) {   // box filter (factor 1 copies)
        int fx = w / res, fy = h / res;
        double inv = 1.0 / ((double)fx * fy);
#pragma omp parallel for schedule(static) if (res >= 128)
        for (int y = 0; y < res; y++)
            for (int x = 0; x < res; x++)
                for (int k = 0; k < c; k++) {
                    double s = 0;
                    for (int j = 0; j < fy; j++)
                        for (int i = 0; i < fx; i++) s += in[((size_t)(y * fy + j) * w + (size_t)(x * fx + i)) * c + k];
                    out[((size_t)y * res + x) * c + k] = (float)(s * inv);
                }
        return MLB_OK;
    }
#pragma omp parallel for schedule(static) if (res >= 128)
    for (int y = 0; y < res; y++) {
        int y0, y1;
        double ty = bilinear_taps(y, h, res, &y0, &y1);
        for (int x = 0; x < res; x++) {
            int x0, x1;
            double tx = bilinear_taps(x, w, res, &x0, &x1);
            for (int k = 0; k < c; k++) {
                double a = in[((size_t)y0 * w + x0) * c + k], b = in[((size_t)y0 * w + x1) * c + k];
                double d = in[((size_t)y1 * w + x0) * c + k], e = in[((size_t)y1 * w + x1) * c + k];
                out[((size_t)y * res + x) * c + k] = (float)((1 - ty) * ((1 - tx) * a + tx * b) + ty * ((1 - tx) * d + tx * e));
            }
        }
    }
    return MLB_OK;
}

// One file → [res, res, 4] premultiplied (normal: 2·rgb − 1 first).
static mlb_status load_one(float* out, const char* path, int res, int size, int is_normal) {
    int w, h, ch, bits;
    MLB_TRY(mlb_image_info(path, &w, &h, &ch, &bits));
    if (w != size || h != size)
        return mlb_fail(MLB_ERR_FORMAT, "%s: %dx%d, but the data set's images are %dx%d", path, w, h, size, size);
    if (ch != 2 && ch != 4) return mlb_fail(MLB_ERR_FORMAT, "%s: no alpha channel (the mask): %d channels", path, ch);
    if (is_normal && ch != 4) return mlb_fail(MLB_ERR_FORMAT, "%s: a normal map needs RGBA", path);
    mlb_image img = {0};
    MLB_TRY(mlb_image_load_limit(&img, path, 4, (size_t)MLB_VIEWS_MAX_SIZE * MLB_VIEWS_MAX_SIZE));
    if (img.w != size || img.h != size) { mlb_image_free(&img); return mlb_fail(MLB_ERR_FORMAT, "%s: size changed while loading", path); }
    size_t np = (size_t)size * size;
    for (size_t i = 0; i < np; i++) {
        float* p = img.data + 4 * i;
        for (int k = 0; k < 3; k++) p[k] = (is_normal ? 2 * p[k] - 1 : p[k]) * p[3];
    }
    mlb_status s = mlb_views_resample(out, res, img.data, size, size, 4);
    mlb_image_free(&img);
    return s;
}

void mlb_views_free(mlb_views* v) {
    if (!v) return;
    free(v->images);
    free(v->normals);
    free(v->cams);
    mlb_views_meta_free(&v->meta);
    memset(v, 0, sizeof *v);
}

mlb_status mlb_views_load(mlb_views* out, const char* dir, int res) {
    memset(out, 0, sizeof *out);
    if (!dir || strlen(dir) >= sizeof out->dir - MLB_VIEWS_PATH_MAX - 2) return mlb_fail(MLB_ERR_ARG, "views: folder name missing or too long");
    if (res < 0 || res > MLB_VIEWS_MAX_SIZE) return mlb_fail(MLB_ERR_ARG, "views: resolution %d outside 0..%d", res, MLB_VIEWS_MAX_SIZE);
    mlb_views v;
    memset(&v, 0, sizeof v);
    snprintf(v.dir, sizeof v.dir, "%s", dir);
    MLB_TRY(mlb_views_meta_read(&v.meta, dir));
    mlb_status s = MLB_OK;
    char path[4400];
    int n = v.meta.n_views, with_normal = 0;
    for (int i = 0; i < n; i++) with_normal += v.meta.views[i].normal[0] != 0;
    if (with_normal != 0 && with_normal != n) {
        join(path, sizeof path, dir, "cameras.json");
        s = mlb_fail(MLB_ERR_FORMAT, "%s: %d of %d views have a normal map: either all or none", path, with_normal, n);
    }
    // the size of the first image fixes everyone's
    int w = 0, h = 0, ch, bits;
    if (!s) {
        join(path, sizeof path, dir, v.meta.views[0].image);
        s = mlb_image_info(path, &w, &h, &ch, &bits);
        if (!s && w != h) s = mlb_fail(MLB_ERR_FORMAT, "%s: %dx%d is not square", path, w, h);
        if (!s && w > MLB_VIEWS_MAX_SIZE) s = mlb_fail(MLB_ERR_FORMAT, "%s: %dx%d is larger than %d", path, w, h, MLB_VIEWS_MAX_SIZE);
    }
    if (!s) {
        v.n = n;
        v.src_size = w;
        v.res = res ? res : w;
        v.has_normals = with_normal == n;
        size_t per = (size_t)v.res * v.res * 4;
        if ((double)per * sizeof(float) * n * (1 + v.has_normals) > (double)MLB_VIEWS_MAX_BYTES)
            s = mlb_fail(MLB_ERR_ARG, "%s: %d views at %dx%d need more than %zu GiB", dir, n, v.res, v.res, MLB_VIEWS_MAX_BYTES >> 30);
        if (!s) {
            v.images = malloc(sizeof(float) * per * n);
            v.normals = v.has_normals ? malloc(sizeof(float) * per * n) : NULL;
            v.cams = calloc((size_t)n, sizeof(mlb_camera));
            if (!v.images || (v.has_normals && !v.normals) || !v.cams) s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for %d views", dir, n);
        }
        for (int i = 0; i < n && !s; i++) {
            const mlb_views_entry* e = &v.meta.views[i];
            s = mlb_views_entry_camera(&v.cams[i], e);
            if (s) { join(path, sizeof path, dir, "cameras.json"); s = mlb_fail_context(s, "%s: views[%d]", path, i); break; }
            join(path, sizeof path, dir, e->image);
            s = load_one(v.images + per * i, path, v.res, w, 0);
            if (!s && v.has_normals) {
                join(path, sizeof path, dir, e->normal);
                s = load_one(v.normals + per * i, path, v.res, w, 1);
            }
        }
    }
    if (s) { mlb_views_free(&v); return s; }
    *out = v;
    return MLB_OK;
}

mlb_status mlb_views_open_env(const mlb_views* v, int i, mlb_envmap* env, int height) {
    if (i < 0 || i >= v->meta.n_envs) return mlb_fail(MLB_ERR_ARG, "%s: environment %d of %d", v->dir, i, v->meta.n_envs);
    const mlb_views_env* e = &v->meta.envs[i];
    if (e->name[0]) return mlb_envmap_named(env, e->name, height);
    char path[4400];
    join(path, sizeof path, v->dir, e->file);
    return mlb_envmap_load(env, path, (float)e->scale, NULL);
}

// ---- conversions ----------------------------------------------------------------------------------------

static float clamp01(float x) { return x > 0 ? (x < 1 ? x : 1) : 0; }   // NaN → 0

void mlb_views_linear_to_target(float* out, const float* rgba, size_t n_pix) {
    for (size_t i = 0; i < n_pix; i++) {
        float a = clamp01(rgba[4 * i + 3]);
        for (int k = 0; k < 3; k++) out[4 * i + k] = a > 0 ? mlb_linear_to_srgb(clamp01(rgba[4 * i + k] / a)) * a : 0;
        out[4 * i + 3] = a;
    }
}

mlb_status mlb_views_render_target(const mlb_render_params* p, float* out) {
    int ss = p->supersample > 0 ? p->supersample : 1;
    mlb_render_params q = *p;
    q.background = MLB_BG_COLOR;
    q.bg_color[0] = q.bg_color[1] = q.bg_color[2] = 0;
    q.width = p->width * ss;
    q.height = p->height * ss;
    q.supersample = 1;
    if (q.width > MLB_RASTER_MAX_SIZE || q.height > MLB_RASTER_MAX_SIZE || p->width < 1 || p->height < 1)
        return mlb_fail(MLB_ERR_ARG, "views: render of %dx%d at supersampling %d", p->width, p->height, ss);
    size_t n = (size_t)q.width * q.height;
    float* fine = malloc(sizeof(float) * 4 * n);
    if (!fine) return mlb_fail(MLB_ERR_NOMEM, "views: out of memory for %dx%d pixels", q.width, q.height);
    mlb_status s = mlb_render_shaded(&q, fine);
    if (!s) {
        mlb_views_linear_to_target(fine, fine, n);
        mlb_downsample_box(out, fine, p->height, p->width, 4, ss);
    }
    free(fine);
    return s;
}

// A premultiplied [h, w, 4] image as a straight-alpha PNG: sRGB colour in 8 bits, or a normal
// map (n / alpha mapped from [-1, 1] to [0, 1]; 0.5 where nothing covers) in 16.
static mlb_status write_straight_png(const char* path, const float* rgba, int w, int h, int normal) {
    size_t n = (size_t)w * h;
    float* s = malloc(sizeof(float) * 4 * (n ? n : 1));
    if (!s) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path);
    for (size_t i = 0; i < n; i++) {
        float a = clamp01(rgba[4 * i + 3]);
        for (int k = 0; k < 3; k++) {
            float v = rgba[4 * i + k];
            if (normal) s[4 * i + k] = a > 0 ? clamp01(0.5f * (v / a + 1)) : 0.5f;
            else s[4 * i + k] = a > 0 ? clamp01(v / a) : 0;
        }
        s[4 * i + 3] = a;
    }
    mlb_png_options po = {.bits = normal ? 16 : 8, .encoding = MLB_PNG_AS_IS};
    mlb_status st = mlb_image_write_png(path, s, w, h, 4, &po);
    free(s);
    return st;
}

mlb_status mlb_views_write_color_png(const char* path, const float* rgba, int w, int h) {
    return write_straight_png(path, rgba, w, h, 0);
}

mlb_status mlb_views_write_normal_png(const char* path, const float* nrm, int w, int h) {
    return write_straight_png(path, nrm, w, h, 1);
}

// ---- rendering a data set ---------------------------------------------------------------------------------

mlb_views_render_config mlb_views_render_default(void) {
    mlb_views_render_config c;
    memset(&c, 0, sizeof c);
    c.k_const[0] = c.k_const[1] = c.k_const[2] = 0.5f;
    c.k_const[3] = c.k_const[4] = c.k_const[5] = 0.04f;
    c.k_const[6] = 0.5f;
    c.n_views = 24;
    c.res = 256;
    c.supersample = 2;
    c.cube = 512;
    c.env_scale = 1;
    c.radius = MLB_ORBIT_RADIUS;
    c.fovy_deg = 40;
    c.el_min = -30;
    c.el_max = 75;
    c.seed = 1;
    c.normals = 1;
    c.fresnel = MLB_FRESNEL_PAPER;
    return c;
}

void mlb_views_render_pose(const mlb_views_render_config* c, int i, double* az, double* el, int* env,
                           double* rotation_deg) {
    const double golden = 180.0 * (3.0 - sqrt(5.0));   // 137.5077...°
    double offset = 360.0 * mlb_u32_to_unit(mlb_rng_words(c->seed, STREAM_VIEWS_RENDER, 0).v[0]);
    double s0 = sin(c->el_min * M_PI / 180), s1 = sin(c->el_max * M_PI / 180);
    double s = s0 + (i + 0.5) / c->n_views * (s1 - s0);
    *el = asin(fmax(-1, fmin(1, s))) * 180 / M_PI;
    double a = fmod(offset + golden * i, 360.0);
    if (a >= 180) a -= 360;
    *az = a;
    mlb_u32x4 w = mlb_rng_words(c->seed, STREAM_VIEWS_RENDER, 1 + (uint64_t)i);
    int e = (int)(mlb_u32_to_unit(w.v[0]) * c->n_envs);
    *env = e < c->n_envs ? e : c->n_envs - 1;
    *rotation_deg = c->fixed_rotation ? 0.0 : 360.0 * mlb_u32_to_unit(w.v[1]);
}

static const char* ext_of(const char* p) {
    const char* slash = strrchr(p, '/');
    const char* dot = strrchr(p, '.');
    if (!dot || (slash && dot < slash)) return "";
    if (strcasecmp(dot, ".hdr") == 0) return ".hdr";
    if (strcasecmp(dot, ".exr") == 0) return ".exr";
    return "";
}

mlb_status mlb_views_render(const char* dir, const mlb_views_render_config* c, mlb_progress* progress) {
    if (!dir || strlen(dir) > 3800) return mlb_fail(MLB_ERR_ARG, "views render: folder name missing or too long");
    if (!c->mesh || c->mesh->n_faces < 1 || c->n_views < 1 || c->n_views > MLB_VIEWS_MAX_VIEWS || c->res < 4 ||
        c->res > MLB_VIEWS_MAX_SIZE || c->supersample < 1 || c->supersample > 8 || c->n_envs < 1 ||
        c->n_envs > MLB_VIEWS_MAX_ENVS || !c->envs || !(c->radius > 0) || !(c->fovy_deg > 0 && c->fovy_deg < 180) ||
        !(c->el_min >= -90 && c->el_max <= 90 && c->el_min <= c->el_max) || c->cube < 64)
        return mlb_fail(MLB_ERR_ARG, "views render: bad configuration (%d views, res %d, ss %d, %d environments, cube %d)",
                        c->n_views, c->res, c->supersample, c->n_envs, c->cube);
    if (c->n_views > 1000) return mlb_fail(MLB_ERR_ARG, "views render: at most 1000 views (file names view_XXX)");
    MLB_TRY(mlb_mkdir_p(dir));
    int ne = c->n_envs, n = c->n_views, R = c->res;
    mlb_envmap* envs = calloc((size_t)ne, sizeof *envs);
    mlb_envlight* lights = calloc((size_t)ne, sizeof *lights);
    mlb_views_meta meta = {0};
    meta.envs = calloc((size_t)ne, sizeof *meta.envs);
    meta.views = calloc((size_t)n, sizeof *meta.views);
    float* img = malloc(sizeof(float) * 4 * (size_t)R * R);
    mlb_status s = (envs && lights && meta.envs && meta.views && img) ? MLB_OK : mlb_fail(MLB_ERR_NOMEM, "views render: out of memory");
    char path[4400];
    for (int i = 0; i < ne && !s; i++) {
        const char* name = c->envs[i];
        mlb_views_env* me = &meta.envs[i];
        me->scale = 1;
        if (mlb_envmap_is_builtin(name)) {
            snprintf(me->name, sizeof me->name, "%s", name);
            s = mlb_envmap_named(&envs[i], name, 0);
        } else {   // copy the file into the folder so that the data set is self-contained
            s = mlb_envmap_load(&envs[i], name, c->env_scale, NULL);
            snprintf(me->file, sizeof me->file, "env_%02d%s", i, ext_of(name));
            me->scale = c->env_scale;
            char* data = NULL;
            size_t nb = 0;
            if (!s) s = mlb_read_file(name, &data, &nb, (size_t)4 << 30);
            join(path, sizeof path, dir, me->file);
            if (!s) s = mlb_write_file_atomic(path, data, nb);
            free(data);
        }
        mlb_envlight_options lo = {.face_size = c->cube};
        if (!s) s = mlb_envlight_build(&lights[i], &envs[i], &lo);
    }
    meta.n_envs = ne;
    meta.n_views = n;
    mlb_render_params p;
    memset(&p, 0, sizeof p);
    p.mesh = c->mesh;
    p.k = c->k;
    memcpy(p.k_const, c->k_const, sizeof p.k_const);
    p.background = MLB_BG_COLOR;   // black: colour comes out premultiplied by coverage
    p.width = p.height = R;
    p.supersample = c->supersample;
    p.fresnel = c->fresnel;
    for (int i = 0; i < n && !s; i++) {
        mlb_views_entry* e = &meta.views[i];
        double az, el, rot;
        int env;
        mlb_views_render_pose(c, i, &az, &el, &env, &rot);
        e->orbit = 1;
        e->azimuth_deg = az;
        e->elevation_deg = el;
        e->radius = c->radius;
        e->fovy_deg = c->fovy_deg;
        e->near_z = MLB_ORBIT_NEAR;
        e->far_z = MLB_ORBIT_FAR;
        e->env = env;
        e->env_rotation_deg = rot;
        snprintf(e->image, sizeof e->image, "view_%03d.png", i);
        if (c->normals) snprintf(e->normal, sizeof e->normal, "normal_%03d.png", i);
        s = mlb_views_entry_camera(&p.camera, e);
        float rad = (float)(rot * M_PI / 180.0);
        mlb_envmap_set_rotation(&envs[env], rad);
        mlb_envlight_set_rotation(&lights[env], rad);
        p.light = &lights[env];
        p.env = &envs[env];
        if (!s) s = mlb_views_render_target(&p, img);
        join(path, sizeof path, dir, e->image);
        if (!s) s = mlb_views_write_color_png(path, img, R, R);
        if (!s && c->normals) {
            s = mlb_geofit_render_mesh(NULL, img, c->mesh, &p.camera, R, c->supersample);
            join(path, sizeof path, dir, e->normal);
            if (!s) s = mlb_views_write_normal_png(path, img, R, R);
        }
        if (progress) mlb_progress_update(progress, i + 1, NULL);
    }
    if (!s) s = mlb_views_meta_write(dir, &meta);
    for (int i = 0; i < ne && envs && lights; i++) { mlb_envmap_free(&envs[i]); mlb_envlight_free(&lights[i]); }
    free(envs); free(lights); free(img);
    mlb_views_meta_free(&meta);
    return s;
}
