// Writes the static three.js viewer folder (include/matlaber/export.h, docs/export.md): the page
// and its script from the viewer source folder, three.js copied from that folder's node_modules,
// the asset as .glb, and the built-in environments as Radiance .hdr files.
#include <cjson/cJSON.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "matlaber/envmap.h"
#include "matlaber/export.h"
#include "matlaber/fileio.h"
#include "matlaber/image_write.h"
#include "matlaber/latent_export.h"

// Files of the three npm package the page needs (the imports of GLTFLoader, HDRLoader and
// OrbitControls, followed by hand); paths relative to node_modules/three, copied to lib/three/.
static const char* const THREE_FILES[] = {
    "build/three.module.js",
    "build/three.core.js",
    "examples/jsm/loaders/GLTFLoader.js",
    "examples/jsm/loaders/HDRLoader.js",
    "examples/jsm/utils/BufferGeometryUtils.js",
    "examples/jsm/utils/SkeletonUtils.js",
    "examples/jsm/controls/OrbitControls.js",
    "LICENSE",
    NULL,
};
static const char* const PAGE_FILES[] = {"viewer.js", "latent.js", "index.html", NULL};   // index.html last
static const char* const DEFAULT_ENVS[] = {"sky", "studio", "overcast", NULL};
#define MAX_COPY_BYTES ((size_t)1 << 30)

static int is_viewer_source(const char* dir) {
    char p[PATH_MAX];
    static const char* const need[] = {"index.html", "viewer.js", "node_modules/three/build/three.module.js", NULL};
    for (int i = 0; need[i]; i++) {
        if (snprintf(p, sizeof p, "%s/%s", dir, need[i]) >= (int)sizeof p || !mlb_is_file(p)) return 0;
    }
    return 1;
}

static int try_dir(const char* dir, char* out, size_t n) {
    if (!dir || !dir[0] || !is_viewer_source(dir)) return 0;
    if (snprintf(out, n, "%s", dir) >= (int)n) return 0;
    return 1;
}

mlb_status mlb_viewer_find_source(const char* hint, char* out, size_t n) {
    if (!out || n == 0) return mlb_fail(MLB_ERR_ARG, "viewer: NULL output");
    out[0] = 0;
    if (hint) {
        if (try_dir(hint, out, n)) return MLB_OK;
        return mlb_fail(MLB_ERR_NOT_FOUND,
                        "%s: not a viewer source folder (needs index.html, viewer.js and node_modules/three; run "
                        "scripts/build.sh, which runs npm ci there)", hint);
    }
    const char* env = getenv("MATLABER_VIEWER_DIR");
    if (env && env[0]) {
        if (try_dir(env, out, n)) return MLB_OK;
        return mlb_fail(MLB_ERR_NOT_FOUND, "$MATLABER_VIEWER_DIR=%s: not a viewer source folder (needs index.html, "
                        "viewer.js and node_modules/three)", env);
    }
    char exe[PATH_MAX];
    ssize_t len = readlink("/proc/self/exe", exe, sizeof exe - 1);
    if (len > 0) {
        exe[len] = 0;
        char* slash = strrchr(exe, '/');
        if (slash) *slash = 0;
        static const char* const rel[] = {"viewer", "../viewer", "../../viewer", "../share/matlaber/viewer", NULL};
        char p[PATH_MAX];
        for (int i = 0; rel[i]; i++)
            if (snprintf(p, sizeof p, "%s/%s", exe, rel[i]) < (int)sizeof p && try_dir(p, out, n)) return MLB_OK;
    }
#ifdef MLB_VIEWER_DIR
    if (try_dir(MLB_VIEWER_DIR, out, n)) return MLB_OK;
#endif
    // The source tree this file was compiled from: __FILE__ is .../src/export/viewer.c (CMake passes
    // absolute paths).
    {
        char p[PATH_MAX];
        const char* f = __FILE__;
        const char* tail = strstr(f, "src/export/viewer.c");
        if (f[0] == '/' && tail && snprintf(p, sizeof p, "%.*sviewer", (int)(tail - f), f) < (int)sizeof p &&
            try_dir(p, out, n))
            return MLB_OK;
    }
    return mlb_fail(MLB_ERR_NOT_FOUND,
                    "viewer: no viewer source folder with three.js found (tried $MATLABER_VIEWER_DIR, viewer/ beside "
                    "the program and the source tree); install it with scripts/build.sh (npm ci in viewer/)");
}

static mlb_status copy_file(const char* from, const char* to) {
    char* data = NULL;
    size_t n = 0;
    mlb_status st = mlb_read_file(from, &data, &n, MAX_COPY_BYTES);
    if (st != MLB_OK) return st;
    st = mlb_write_file_atomic(to, data, n);
    free(data);
    return st;
}

static mlb_status parent_mkdir(const char* path) {
    char d[PATH_MAX];
    snprintf(d, sizeof d, "%s", path);
    char* slash = strrchr(d, '/');
    if (!slash) return MLB_OK;
    *slash = 0;
    return mlb_mkdir_p(d);
}

// The built-in map turned a quarter turn: our lat-long u = atan2(x, -z) / 2pi + 0.5, three.js's
// equirectUv u = atan2(z, x) / 2pi + 0.5 = ours - 1/4; so three's column c holds our column c + w/4.
static mlb_status write_env(const char* dir, const char* name, int height) {
    if (!mlb_envmap_is_builtin(name)) return mlb_fail(MLB_ERR_ARG, "viewer: '%s' is not a built-in environment (%s)", name, mlb_envmap_builtin_list());
    for (const char* c = name; *c; c++)
        if (!((*c >= 'a' && *c <= 'z') || (*c >= '0' && *c <= '9') || *c == '_' || *c == '-'))
            return mlb_fail(MLB_ERR_ARG, "viewer: environment name '%s' has characters other than a-z 0-9 _ -", name);
    mlb_envmap env = {0};
    MLB_TRY(mlb_envmap_named(&env, name, height));
    int w = env.w, h = env.h, shift = w / 4;
    float* img = malloc(sizeof(float) * 3 * (size_t)w * (size_t)h);
    if (!img) { mlb_envmap_free(&env); return mlb_fail(MLB_ERR_NOMEM, "viewer: out of memory for the %s map", name); }
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            const float* s = env.data + 3 * ((size_t)y * w + (size_t)((x + shift) % w));
            float* d = img + 3 * ((size_t)y * w + (size_t)x);
            // three.js filters the map in half floats (largest 65504): keep the sun below that
            for (int k = 0; k < 3; k++) d[k] = s[k] < 60000.0f ? s[k] : 60000.0f;
        }
    mlb_envmap_free(&env);
    char path[PATH_MAX];
    snprintf(path, sizeof path, "%s/env/%s.hdr", dir, name);
    mlb_status st = mlb_image_write_hdr(path, img, w, h, 3);
    free(img);
    return st;
}

// decoder: name the latent editor's file (latent_export.h): when the folder has one, and always in
// the page-only folder of `serve`, whose server answers 204 for a job without one.
static mlb_status write_config(const char* dir, const char* const* envs, const char* title, int decoder) {
    cJSON* root = cJSON_CreateObject();
    cJSON_AddStringToObject(root, "title", title);
    cJSON_AddStringToObject(root, "asset", "asset.glb");
    if (decoder) cJSON_AddStringToObject(root, "decoder", "asset.decoder.json");
    cJSON* list = cJSON_AddArrayToObject(root, "environments");
    for (int i = 0; envs[i]; i++) {
        cJSON* e = cJSON_CreateObject();
        cJSON_AddStringToObject(e, "name", envs[i]);
        char file[128];
        snprintf(file, sizeof file, "env/%s.hdr", envs[i]);
        cJSON_AddStringToObject(e, "file", file);
        cJSON_AddItemToArray(list, e);
    }
    char* text = cJSON_Print(root);
    cJSON_Delete(root);
    if (!text) return mlb_fail(MLB_ERR_NOMEM, "viewer: out of memory");
    char path[PATH_MAX];
    snprintf(path, sizeof path, "%s/viewer.json", dir);
    mlb_status st = mlb_write_file_atomic(path, text, strlen(text));
    free(text);
    return st;
}

// Everything except the asset; `write_glb` puts dir/asset.glb in place between the data and the page
// (NULL: no asset, the folder of mlb_viewer_write_page).
static mlb_status write_folder(const char* dir, const mlb_viewer_options* opt,
                               mlb_status (*write_glb)(const char* path, const void* ctx), const void* ctx) {
    if (!dir || !dir[0]) return mlb_fail(MLB_ERR_ARG, "viewer: NULL or empty output folder");
    if (strlen(dir) > PATH_MAX - 256) return mlb_fail(MLB_ERR_ARG, "viewer: output folder path too long");
    char src[PATH_MAX];
    MLB_TRY(mlb_viewer_find_source(opt ? opt->source_dir : NULL, src, sizeof src));
    const char* const* envs = opt && opt->envs ? opt->envs : DEFAULT_ENVS;
    if (!envs[0]) return mlb_fail(MLB_ERR_ARG, "viewer: no environments");
    int height = opt && opt->env_height ? opt->env_height : 256;
    if (height < 8 || height > 4096) return mlb_fail(MLB_ERR_ARG, "viewer: environment height %d (8 to 4096)", height);
    const char* title = opt && opt->title ? opt->title : "matlaber asset";
    char from[PATH_MAX], to[PATH_MAX];
    snprintf(to, sizeof to, "%s/env", dir);
    MLB_TRY(mlb_mkdir_p(to));
    for (int i = 0; THREE_FILES[i]; i++) {
        snprintf(from, sizeof from, "%s/node_modules/three/%s", src, THREE_FILES[i]);
        snprintf(to, sizeof to, "%s/lib/three/%s", dir, THREE_FILES[i]);
        MLB_TRY(parent_mkdir(to));
        mlb_status st = copy_file(from, to);
        if (st != MLB_OK) return mlb_fail_context(st, "viewer: copying three.js");
    }
    for (int i = 0; envs[i]; i++) MLB_TRY(write_env(dir, envs[i], height));
    snprintf(to, sizeof to, "%s/asset.glb", dir);
    if (write_glb) {
        mlb_latent_export_remove(to);   // an earlier asset's editor must not outlive it
        MLB_TRY(write_glb(to, ctx));
    }
    char json[PATH_MAX], bin[PATH_MAX];
    int decoder = !write_glb || (!mlb_latent_export_paths(to, json, bin, sizeof json) && mlb_is_file(json) && mlb_is_file(bin));
    MLB_TRY(write_config(dir, envs, title, decoder));
    for (int i = 0; PAGE_FILES[i]; i++) {
        snprintf(from, sizeof from, "%s/%s", src, PAGE_FILES[i]);
        snprintf(to, sizeof to, "%s/%s", dir, PAGE_FILES[i]);
        MLB_TRY(copy_file(from, to));
    }
    return MLB_OK;
}

static mlb_status glb_from_file(const char* path, const void* ctx) {
    const char* glb = ctx;
    char* data = NULL;
    size_t n = 0;
    MLB_TRY(mlb_read_file(glb, &data, &n, MAX_COPY_BYTES));
    mlb_status st = MLB_OK;
    if (n < 12 || memcmp(data, "glTF", 4) != 0) st = mlb_fail(MLB_ERR_FORMAT, "%s: not a binary glTF file (no glTF magic)", glb);
    else st = mlb_write_file_atomic(path, data, n);
    free(data);
    // a latent-mode export's codes and decoder beside it come along, renamed after asset.glb
    char js[PATH_MAX], bs[PATH_MAX], jd[PATH_MAX], bd[PATH_MAX];
    if (!st && !mlb_latent_export_paths(glb, js, bs, sizeof js) && mlb_is_file(js) && mlb_is_file(bs) &&
        !mlb_latent_export_paths(path, jd, bd, sizeof jd)) {
        st = copy_file(bs, bd);
        if (!st) st = copy_file(js, jd);
    }
    return st;
}

static mlb_status glb_from_asset(const char* path, const void* ctx) { return mlb_export_glb(path, ctx); }

mlb_status mlb_viewer_write(const char* dir, const char* glb_path, const mlb_viewer_options* opt) {
    if (!glb_path) return mlb_fail(MLB_ERR_ARG, "viewer: NULL .glb path");
    if (!mlb_is_file(glb_path)) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no such file", glb_path);
    return write_folder(dir, opt, glb_from_file, glb_path);
}

mlb_status mlb_viewer_write_with(const char* dir, const mlb_viewer_options* opt,
                                 mlb_status (*write_glb)(const char* path, const void* ctx), const void* ctx) {
    if (!write_glb) return mlb_fail(MLB_ERR_ARG, "viewer: NULL asset writer");
    return write_folder(dir, opt, write_glb, ctx);
}

mlb_status mlb_viewer_write_page(const char* dir, const mlb_viewer_options* opt) { return write_folder(dir, opt, NULL, NULL); }

mlb_status mlb_viewer_write_asset(const char* dir, const mlb_asset* a, const mlb_viewer_options* opt) {
    MLB_TRY(mlb_asset_check(a));
    return write_folder(dir, opt, glb_from_asset, a);
}
