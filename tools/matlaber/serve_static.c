// matlaber serve: the page and the viewer's files (serve.h). At start the viewer of `matlaber
// view` is written once, without an asset, to RUNS/.serve/viewer (its page, three.js, the built-in
// environments); /view/ID/ serves that folder with the job's own asset.glb beside it, so the
// page reuses the one viewer. The names a request may ask for are the files found there at start:
// a request's name is compared with that list, never joined to a path.
#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include "matlaber/export.h"
#include "matlaber/fileio.h"
#include "serve.h"

#ifdef MLB_HAVE_MHD
#define MAX_STATIC 64
static struct {
    char rel[MAX_STATIC][128];   // viewer files, relative to the folder
    int n;
    char dir[4096];              // RUNS/.serve/viewer
    char source[4096];           // the viewer source folder (serve.html, serve.js)
    int ok;
} S;

static void walk(const char* base, const char* rel, int depth) {
    char path[4400];
    snprintf(path, sizeof path, "%s%s%s", base, rel[0] ? "/" : "", rel);
    DIR* d = opendir(path);
    for (struct dirent* e; d && (e = readdir(d));) {
        if (e->d_name[0] == '.') continue;
        char sub[256];
        if (snprintf(sub, sizeof sub, "%s%s%s", rel, rel[0] ? "/" : "", e->d_name) >= 128) continue;
        char full[4400];
        snprintf(full, sizeof full, "%s/%s", base, sub);
        struct stat st;
        if (lstat(full, &st) != 0) continue;
        if (S_ISDIR(st.st_mode) && depth < 8) walk(base, sub, depth + 1);
        else if (S_ISREG(st.st_mode) && S.n < MAX_STATIC) snprintf(S.rel[S.n++], 128, "%s", sub);
    }
    if (d) closedir(d);
}

int serve_static_open(const serve_options* o) {
    if (mlb_viewer_find_source(NULL, S.source, sizeof S.source)) {
        fprintf(stderr, "matlaber serve: no page: %s\n", mlb_last_error());
        return 0;   // the API works without it
    }
    char app[4200];
    snprintf(app, sizeof app, "%s/serve.html", S.source);
    if (!mlb_is_file(app)) {
        fprintf(stderr, "matlaber serve: no page: %s has no serve.html\n", S.source);
        return 0;
    }
    snprintf(S.dir, sizeof S.dir, "%s/.serve/viewer", o->runs);
    mlb_viewer_options vo = {S.source, NULL, 256, "matlaber serve"};
    if (mlb_viewer_write_page(S.dir, &vo)) {
        fprintf(stderr, "matlaber serve: no viewer: %s\n", mlb_last_error());
        return 0;
    }
    walk(S.dir, "", 0);
    S.ok = 1;
    return 0;
}

static const char* type_of(const char* name) {
    static const char* const types[][2] = {{".html", "text/html; charset=utf-8"}, {".js", "text/javascript; charset=utf-8"},
                                           {".json", "application/json"}, {".hdr", "application/octet-stream"},
                                           {NULL, NULL}};
    for (int i = 0; types[i][0]; i++)
        if (mlb_ends_with(name, types[i][0])) return types[i][1];
    return "text/plain; charset=utf-8";
}

int serve_static_app(const char* name, char* path, size_t cap, const char** type) {
    if (!S.ok || (strcmp(name, "serve.html") && strcmp(name, "serve.js"))) return 404;
    snprintf(path, cap, "%s/%s", S.source, name);
    *type = type_of(name);
    return 0;
}

int serve_static_viewer(const char* rel, char* path, size_t cap, const char** type) {
    if (!S.ok) return 404;
    for (int i = 0; i < S.n; i++)
        if (!strcmp(S.rel[i], rel)) {
            snprintf(path, cap, "%s/%s", S.dir, S.rel[i]);
            *type = type_of(S.rel[i]);
            return 0;
        }
    return 404;
}
#endif
