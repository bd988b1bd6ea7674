// Loading real SVBRDF maps into material samples: TwoShotBRDF sample folders, metallic/roughness
// texture folders, Deschaintre 4-tile images, and folders holding any of them at any depth.
// Every pixel of a map is one 7-d sample (the paper trains its auto-encoder that way).
#include "matlaber/brdf.h"
#include "matlaber/fileio.h"
#include "matlaber/image.h"
#include "matlaber/rng.h"
#include <ctype.h>
#include <dirent.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>

#define EXPECTED_LAYOUTS \
    "expected a TwoShotBRDF sample folder (diffuse.png, specular.png, roughness.png, optional mask.png), " \
    "a metallic/roughness texture folder (a base colour map named albedo/basecolor/base_color/color/diffuse, " \
    "a roughness map, optional metallic map; .png/.jpg), or 4-tile images (normal|diffuse|roughness|specular, " \
    "width = 4 x height)"

// Streams of the pixel subsampling; the offset keeps them apart from other users of the same seed.
#define STREAM_PIXEL_CHOICE 0x5356425244000000ull
#define MAX_DEPTH 32

static const mlb_brdf_load_options default_options = {0, 0, 0.0f};

static char* join(const char* a, const char* b) {
    size_t na = strlen(a), nb = strlen(b);
    char* s = malloc(na + nb + 2);
    if (!s) return NULL;
    memcpy(s, a, na);
    size_t o = na;
    if (na == 0 || a[na - 1] != '/') s[o++] = '/';
    memcpy(s + o, b, nb + 1);
    return s;
}

// sRGB decoding through a table when the samples are exact 8-bit levels (the usual case): the
// per-pixel powf would otherwise dominate loading a 4K map.
typedef struct { float lut[256]; } srgb_table;

static void srgb_table_init(srgb_table* t) {
    for (int i = 0; i < 256; i++) t->lut[i] = mlb_srgb_to_linear((float)i / 255.0f);
}

static float decode_srgb(const srgb_table* t, const mlb_image* im, float v) {
    if (im->bits == 8) {
        int i = (int)(v * 255.0f + 0.5f);
        return t->lut[i < 0 ? 0 : (i > 255 ? 255 : i)];
    }
    return mlb_srgb_to_linear(v);
}

static float clamp_kr(float r) { return r < MLB_KR_MIN ? MLB_KR_MIN : (r > 1.0f ? 1.0f : r); }

static int cmp_u32(const void* a, const void* b) {
    uint32_t x = *(const uint32_t*)a, y = *(const uint32_t*)b;
    return (x > y) - (x < y);
}

// Indices of the pixels to use: those passing the mask, then (if asked) a uniform subset without
// replacement, by a partial Fisher-Yates shuffle driven by the counter RNG, sorted back into
// raster order so rows follow the image.
static mlb_status choose_pixels(const char* name, size_t npix, const mlb_image* mask, const mlb_brdf_load_options* opt,
                                uint64_t map_index, uint32_t** out_idx, size_t* out_n) {
    uint32_t* idx = malloc((npix ? npix : 1) * sizeof(uint32_t));
    if (!idx) return mlb_fail(MLB_ERR_NOMEM, "%s: cannot allocate a pixel index of %zu entries", name, npix);
    size_t n = 0;
    for (size_t i = 0; i < npix; i++) {
        if (mask) {
            // Mask = first channel, times alpha when the file has one: covers masks stored in the
            // grey/RGB values (TwoShotBRDF: alpha is a constant 255) and masks stored as alpha.
            float m = mask->data[i * (size_t)mask->c];
            if (mask->c == 2 || mask->c == 4) m *= mask->data[i * (size_t)mask->c + (size_t)mask->c - 1];
            if (!(m > opt->mask_threshold)) continue;
        }
        idx[n++] = (uint32_t)i;
    }
    size_t want = opt->max_pixels_per_map;
    if (want > 0 && want < n) {
        uint64_t stream = STREAM_PIXEL_CHOICE + map_index;
        for (size_t i = 0; i < want; i++) {
            size_t j = i + mlb_rng_below(opt->seed, stream, i, (uint32_t)(n - i));
            uint32_t t = idx[i];
            idx[i] = idx[j];
            idx[j] = t;
        }
        n = want;
        qsort(idx, n, sizeof(uint32_t), cmp_u32);
    }
    *out_idx = idx;
    *out_n = n;
    return MLB_OK;
}

static mlb_status check_same_size(const char* a, const mlb_image* ia, const char* b, const mlb_image* ib) {
    if (ia->w == ib->w && ia->h == ib->h) return MLB_OK;
    return mlb_fail(MLB_ERR_FORMAT, "%s is %dx%d but %s is %dx%d: the maps of one material must have the same size", b,
                    ib->w, ib->h, a, ia->w, ia->h);
}

// ---- (a) TwoShotBRDF ----

mlb_status mlb_brdf_load_twoshot(mlb_brdf_set* out, const char* folder, const mlb_brdf_load_options* opt,
                                 uint64_t map_index) {
    if (!out || !folder) return mlb_fail(MLB_ERR_ARG, "load_twoshot: NULL argument");
    if (!opt) opt = &default_options;
    static const char* const names[4] = {"diffuse.png", "specular.png", "roughness.png", "mask.png"};
    char* paths[4] = {0};
    mlb_image im[4];
    memset(im, 0, sizeof im);
    uint32_t* idx = NULL;
    size_t n0 = out->n;
    mlb_status s = MLB_OK;
    for (int i = 0; i < 4; i++)
        if (!(paths[i] = join(folder, names[i]))) { s = mlb_fail(MLB_ERR_NOMEM, "%s: path too long", folder); goto done; }
    for (int i = 0; i < 3; i++)
        if (!mlb_is_file(paths[i])) {
            s = mlb_fail(MLB_ERR_NOT_FOUND,
                         "%s: missing (a TwoShotBRDF sample folder needs diffuse.png, specular.png and roughness.png; "
                         "mask.png is optional)", paths[i]);
            goto done;
        }
    int has_mask = mlb_is_file(paths[3]);
    static const int chans[4] = {3, 3, 0, 0};
    for (int i = 0; i < (has_mask ? 4 : 3); i++) {
        if ((s = mlb_image_load(&im[i], paths[i], chans[i])) != MLB_OK) goto done;
        if (i > 0 && (s = check_same_size(paths[0], &im[0], paths[i], &im[i])) != MLB_OK) goto done;
    }
    size_t n;
    if ((s = choose_pixels(folder, (size_t)im[0].w * im[0].h, has_mask ? &im[3] : NULL, opt, map_index, &idx, &n)) != MLB_OK)
        goto done;
    float* dst;
    if ((s = mlb_brdf_set_extend(out, n, &dst)) != MLB_OK) goto done;
    srgb_table t;
    srgb_table_init(&t);
    const mlb_image *d = &im[0], *sp = &im[1], *r = &im[2];
    for (size_t j = 0; j < n; j++) {
        size_t p = idx[j];
        float* k = dst + j * MLB_BRDF_DIM;
        for (int c = 0; c < 3; c++) {
            k[c] = decode_srgb(&t, d, d->data[p * 3 + c]);
            k[3 + c] = decode_srgb(&t, sp, sp->data[p * 3 + c]);
        }
        k[6] = clamp_kr(r->data[p * (size_t)r->c]);
    }
    s = mlb_brdf_set_note_source(out, n0, folder);
done:
    if (s != MLB_OK) mlb_brdf_set_truncate(out, n0);
    for (int i = 0; i < 4; i++) {
        mlb_image_free(&im[i]);
        free(paths[i]);
    }
    free(idx);
    return s;
}

// ---- (b) metallic / roughness texture sets ----

enum { ROLE_NONE = 0, ROLE_BASE, ROLE_ROUGH, ROLE_METAL };

static int has_image_ext(const char* name) {
    const char* dot = strrchr(name, '.');
    return dot && (!strcasecmp(dot, ".png") || !strcasecmp(dot, ".jpg") || !strcasecmp(dot, ".jpeg"));
}

// The role of a file from the words of its name ("Metal055A_1K_Color.jpg" -> base colour):
// lower-cased, split at every non-alphanumeric character.
static int file_role(const char* name) {
    if (!has_image_ext(name)) return ROLE_NONE;
    char stem[256];
    size_t len = (size_t)(strrchr(name, '.') - name);   // has_image_ext found the dot
    if (len >= sizeof stem) return ROLE_NONE;
    for (size_t i = 0; i < len; i++) stem[i] = (char)tolower((unsigned char)name[i]);
    stem[len] = 0;
    int base = 0, rough = 0, metal = 0, plain_metal = 0, prev_base = 0;
    char* save = NULL;
    for (char* tok = strtok_r(stem, "_-. ", &save); tok; tok = strtok_r(NULL, "_-. ", &save)) {
        if (!strcmp(tok, "albedo") || !strcmp(tok, "basecolor") || !strcmp(tok, "basecolour") || !strcmp(tok, "color") ||
            !strcmp(tok, "colour") || !strcmp(tok, "diffuse") || !strcmp(tok, "diff") || !strcmp(tok, "col"))
            base = 1;
        if (prev_base && (!strcmp(tok, "color") || !strcmp(tok, "colour"))) base = 1;
        if (!strcmp(tok, "roughness") || !strcmp(tok, "rough")) rough = 1;
        if (!strcmp(tok, "metallic") || !strcmp(tok, "metalness")) metal = 1;
        if (!strcmp(tok, "metal")) plain_metal = 1;
        prev_base = !strcmp(tok, "base");
    }
    if (rough) return ROLE_ROUGH;
    if (metal) return ROLE_METAL;
    if (base) return ROLE_BASE;
    if (plain_metal) return ROLE_METAL;   // "metal.png", but not "metal_albedo.png"
    return ROLE_NONE;
}

typedef struct { char** names; size_t n, cap; } name_list;

static void name_list_free(name_list* l) {
    for (size_t i = 0; i < l->n; i++) free(l->names[i]);
    free(l->names);
    memset(l, 0, sizeof *l);
}

static int cmp_str(const void* a, const void* b) { return strcmp(*(char* const*)a, *(char* const*)b); }

// Entries of a folder, dot-files skipped (macOS "._x.png" resource forks are not images), sorted
// bytewise so every machine walks the same order.
static mlb_status list_dir(const char* dir, name_list* l) {
    memset(l, 0, sizeof *l);
    DIR* d = opendir(dir);
    if (!d) return mlb_fail(MLB_ERR_IO, "%s: cannot open folder: %s", dir, strerror(errno));
    struct dirent* e;
    while ((e = readdir(d)) != NULL) {
        if (e->d_name[0] == '.') continue;
        if (l->n == l->cap) {
            size_t cap = l->cap ? l->cap * 2 : 32;
            char** p = realloc(l->names, cap * sizeof *p);
            if (!p) { closedir(d); name_list_free(l); return mlb_fail(MLB_ERR_NOMEM, "%s: listing", dir); }
            l->names = p;
            l->cap = cap;
        }
        if (!(l->names[l->n] = strdup(e->d_name))) { closedir(d); name_list_free(l); return mlb_fail(MLB_ERR_NOMEM, "%s", dir); }
        l->n++;
    }
    closedir(d);
    if (l->n) qsort(l->names, l->n, sizeof(char*), cmp_str);
    return MLB_OK;
}

// Finds the one file of each role; two candidates for a role is an error rather than a guess.
static mlb_status pbr_files(const char* folder, const name_list* l, char* found[4]) {
    for (size_t i = 0; i < l->n; i++) {
        int role = file_role(l->names[i]);
        if (role == ROLE_NONE) continue;
        char* p = join(folder, l->names[i]);
        if (!p) return mlb_fail(MLB_ERR_NOMEM, "%s: path too long", folder);
        if (!mlb_is_file(p)) { free(p); continue; }
        if (found[role]) {
            static const char* const what[4] = {"", "base colour", "roughness", "metallic"};
            mlb_status s = mlb_fail(MLB_ERR_FORMAT, "%s: ambiguous: both %s and %s look like the %s map", folder,
                                    found[role], p, what[role]);
            free(p);
            return s;
        }
        found[role] = p;
    }
    return MLB_OK;
}

mlb_status mlb_brdf_load_pbr(mlb_brdf_set* out, const char* folder, const mlb_brdf_load_options* opt, uint64_t map_index) {
    if (!out || !folder) return mlb_fail(MLB_ERR_ARG, "load_pbr: NULL argument");
    if (!opt) opt = &default_options;
    name_list l;
    MLB_TRY(list_dir(folder, &l));
    char* f[4] = {0};
    mlb_image base = {0}, rough = {0}, metal = {0};
    uint32_t* idx = NULL;
    size_t n0 = out->n;
    mlb_status s = pbr_files(folder, &l, f);
    if (s != MLB_OK) goto done;
    if (!f[ROLE_BASE] || !f[ROLE_ROUGH]) {
        s = mlb_fail(MLB_ERR_NOT_FOUND,
                     "%s: missing the %s map (a metallic/roughness folder needs a base colour map named "
                     "albedo/basecolor/base_color/color/diffuse and a roughness map, .png or .jpg; metallic is optional)",
                     folder, !f[ROLE_BASE] ? "base colour" : "roughness");
        goto done;
    }
    if ((s = mlb_image_load(&base, f[ROLE_BASE], 3)) != MLB_OK) goto done;
    if ((s = mlb_image_load(&rough, f[ROLE_ROUGH], 0)) != MLB_OK) goto done;
    if ((s = check_same_size(f[ROLE_BASE], &base, f[ROLE_ROUGH], &rough)) != MLB_OK) goto done;
    if (f[ROLE_METAL]) {
        if ((s = mlb_image_load(&metal, f[ROLE_METAL], 0)) != MLB_OK) goto done;
        if ((s = check_same_size(f[ROLE_BASE], &base, f[ROLE_METAL], &metal)) != MLB_OK) goto done;
    }
    size_t n;
    if ((s = choose_pixels(folder, (size_t)base.w * base.h, NULL, opt, map_index, &idx, &n)) != MLB_OK) goto done;
    float* dst;
    if ((s = mlb_brdf_set_extend(out, n, &dst)) != MLB_OK) goto done;
    srgb_table t;
    srgb_table_init(&t);
    for (size_t j = 0; j < n; j++) {
        size_t p = idx[j];
        float* k = dst + j * MLB_BRDF_DIM;
        float m = metal.data ? metal.data[p * (size_t)metal.c] : 0.0f;
        // The metallic/roughness convention (glTF 2.0, Unreal, ambientCG): dielectric F0 0.04,
        // metals take their F0 from the base colour and have no diffuse.
        for (int c = 0; c < 3; c++) {
            float b = decode_srgb(&t, &base, base.data[p * 3 + c]);
            k[c] = b * (1.0f - m);
            k[3 + c] = 0.04f * (1.0f - m) + b * m;
        }
        k[6] = clamp_kr(rough.data[p * (size_t)rough.c]);
    }
    s = mlb_brdf_set_note_source(out, n0, folder);
done:
    if (s != MLB_OK) mlb_brdf_set_truncate(out, n0);
    for (int i = 0; i < 4; i++) free(f[i]);
    name_list_free(&l);
    mlb_image_free(&base);
    mlb_image_free(&rough);
    mlb_image_free(&metal);
    free(idx);
    return s;
}

// ---- (c) 4-tile images ----

mlb_status mlb_brdf_load_tiles(mlb_brdf_set* out, const char* file, const mlb_brdf_load_options* opt, uint64_t map_index) {
    if (!out || !file) return mlb_fail(MLB_ERR_ARG, "load_tiles: NULL argument");
    if (!opt) opt = &default_options;
    mlb_image im = {0};
    MLB_TRY(mlb_image_load(&im, file, 3));
    if (im.w != 4 * im.h) {
        mlb_status s = mlb_fail(MLB_ERR_FORMAT,
                                "%s: %dx%d is not 4 square tiles (expected width = 4 x height: normal | diffuse | "
                                "roughness | specular; for a TwoShotBRDF sample or a texture set pass its folder)",
                                file, im.w, im.h);
        mlb_image_free(&im);
        return s;
    }
    size_t T = (size_t)im.h, n0 = out->n, n;
    uint32_t* idx = NULL;
    mlb_status s = choose_pixels(file, T * T, NULL, opt, map_index, &idx, &n);
    float* dst = NULL;
    if (s == MLB_OK) s = mlb_brdf_set_extend(out, n, &dst);
    if (s == MLB_OK) {
        srgb_table t;
        srgb_table_init(&t);
        for (size_t j = 0; j < n; j++) {
            size_t y = idx[j] / T, x = idx[j] % T, row = y * (size_t)im.w;
            const float* dif = im.data + (row + T + x) * 3;
            const float* rgh = im.data + (row + 2 * T + x) * 3;
            const float* spc = im.data + (row + 3 * T + x) * 3;
            float* k = dst + j * MLB_BRDF_DIM;
            for (int c = 0; c < 3; c++) {
                k[c] = decode_srgb(&t, &im, dif[c]);
                k[3 + c] = decode_srgb(&t, &im, spc[c]);
            }
            k[6] = clamp_kr(rgh[0]);
        }
        s = mlb_brdf_set_note_source(out, n0, file);
    }
    if (s != MLB_OK) mlb_brdf_set_truncate(out, n0);
    free(idx);
    mlb_image_free(&im);
    return s;
}

// ---- (d) discovery ----

enum { JOB_TWOSHOT = 1, JOB_PBR, JOB_TILES };
typedef struct { int kind; char* path; } job;
typedef struct { job* v; size_t n, cap; size_t skipped_images; } job_list;

static mlb_status add_job(job_list* jl, int kind, const char* path) {
    if (jl->n == jl->cap) {
        size_t cap = jl->cap ? jl->cap * 2 : 16;
        job* p = realloc(jl->v, cap * sizeof *p);
        if (!p) return mlb_fail(MLB_ERR_NOMEM, "listing material folders");
        jl->v = p;
        jl->cap = cap;
    }
    if (!(jl->v[jl->n].path = strdup(path))) return mlb_fail(MLB_ERR_NOMEM, "listing material folders");
    jl->v[jl->n++].kind = kind;
    return MLB_OK;
}

static int list_has(const name_list* l, const char* name) {
    for (size_t i = 0; i < l->n; i++)
        if (!strcmp(l->names[i], name)) return 1;
    return 0;
}

// What a folder is: TwoShotBRDF when it has specular.png, or diffuse.png together with one of the
// files only TwoShotBRDF samples carry (mask.png, normal.exr, depth.exr) - so a sample that lost its
// specular.png is reported as such instead of being read as a metallic/roughness set; else a
// metallic/roughness set (see below); else a plain folder to search.
static mlb_status discover(const char* path, int depth, job_list* jl) {
    if (depth > MAX_DEPTH) return mlb_fail(MLB_ERR_FORMAT, "%s: folders nested deeper than %d (a link loop?)", path, MAX_DEPTH);
    name_list l;
    MLB_TRY(list_dir(path, &l));
    mlb_status s = MLB_OK;
    int twoshot = list_has(&l, "specular.png") ||
                  (list_has(&l, "diffuse.png") &&
                   (list_has(&l, "mask.png") || list_has(&l, "normal.exr") || list_has(&l, "depth.exr")));
    if (twoshot) {
        s = add_job(jl, JOB_TWOSHOT, path);
        name_list_free(&l);
        return s;
    }
    // A texture set when it has a roughness map, or a base colour / metallic map and no
    // subfolders (then a missing roughness map is reported); a stray "color_chart.png" beside
    // sample folders does not stop the search.
    int has_rough = 0, has_other = 0, has_dirs = 0;
    for (size_t i = 0; i < l.n; i++) {
        int role = file_role(l.names[i]);
        has_rough |= role == ROLE_ROUGH;
        has_other |= role == ROLE_BASE || role == ROLE_METAL;
        if (!has_dirs) {
            char* p = join(path, l.names[i]);
            if (!p) { name_list_free(&l); return mlb_fail(MLB_ERR_NOMEM, "%s: path too long", path); }
            has_dirs = mlb_is_dir(p);
            free(p);
        }
    }
    if (has_rough || (has_other && !has_dirs)) {
        s = add_job(jl, JOB_PBR, path);
        name_list_free(&l);
        return s;
    }
    for (size_t i = 0; i < l.n && s == MLB_OK; i++) {
        char* p = join(path, l.names[i]);
        if (!p) { s = mlb_fail(MLB_ERR_NOMEM, "%s: path too long", path); break; }
        if (mlb_is_dir(p)) {
            s = discover(p, depth + 1, jl);
        } else if (has_image_ext(l.names[i]) && mlb_is_file(p)) {
            int w = 0, h = 0;
            // Only the header is read here; a broken file is reported when it is loaded.
            if (mlb_image_info(p, &w, &h, NULL, NULL) != MLB_OK || w == 4 * h) s = add_job(jl, JOB_TILES, p);
            else jl->skipped_images++;
        }
        free(p);
    }
    name_list_free(&l);
    return s;
}

mlb_status mlb_brdf_load_path(mlb_brdf_set* out, const char* path, const mlb_brdf_load_options* opt) {
    if (!out || !path) return mlb_fail(MLB_ERR_ARG, "brdf load: NULL argument");
    if (!opt) opt = &default_options;
    if (!(opt->mask_threshold >= 0.0f && opt->mask_threshold < 1.0f))
        return mlb_fail(MLB_ERR_ARG, "%s: mask threshold %g must be in [0, 1)", path, (double)opt->mask_threshold);
    struct stat st;
    if (stat(path, &st) != 0) {
        if (errno == ENOENT) return mlb_fail(MLB_ERR_IO, "%s: no such file or folder", path);
        return mlb_fail(MLB_ERR_IO, "%s: %s", path, strerror(errno));
    }
    size_t n0 = out->n;
    if (S_ISREG(st.st_mode)) {
        MLB_TRY(mlb_brdf_load_tiles(out, path, opt, 0));
    } else if (S_ISDIR(st.st_mode)) {
        job_list jl = {0};
        mlb_status s = discover(path, 0, &jl);
        if (s == MLB_OK && jl.n == 0) {
            if (jl.skipped_images)
                s = mlb_fail(MLB_ERR_NOT_FOUND, "%s: no material maps found (%zu images that are not 4-tile); " EXPECTED_LAYOUTS,
                             path, jl.skipped_images);
            else
                s = mlb_fail(MLB_ERR_NOT_FOUND, "%s: no material maps found; " EXPECTED_LAYOUTS, path);
        }
        for (size_t i = 0; i < jl.n && s == MLB_OK; i++) {
            if (jl.v[i].kind == JOB_TWOSHOT) s = mlb_brdf_load_twoshot(out, jl.v[i].path, opt, i);
            else if (jl.v[i].kind == JOB_PBR) s = mlb_brdf_load_pbr(out, jl.v[i].path, opt, i);
            else s = mlb_brdf_load_tiles(out, jl.v[i].path, opt, i);
        }
        for (size_t i = 0; i < jl.n; i++) free(jl.v[i].path);
        free(jl.v);
        if (s != MLB_OK) {
            mlb_brdf_set_truncate(out, n0);
            return s;
        }
    } else {
        return mlb_fail(MLB_ERR_ARG, "%s: neither a file nor a folder", path);
    }
    if (out->n == n0)
        return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no valid pixels (every mask value is <= %g)", path, (double)opt->mask_threshold);
    return MLB_OK;
}
