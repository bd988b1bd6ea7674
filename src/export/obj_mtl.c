// Wavefront OBJ + MTL writer with PNG textures (kd, ks sRGB; roughness linear grey) and the MTL
// PBR extension keys (Pr / map_Pr, Pm). Mapping and caveats: docs/export.md.
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "matlaber/export.h"
#include "matlaber/fileio.h"
#include "matlaber/image_write.h"

// The files of one OBJ export: dir/stem.obj, .mtl, _kd.png, _ks.png, _roughness.png.
typedef struct { char obj[4096], mtl[4096], kd[4096], ks[4096], kr[4096]; const char* base; } obj_names;

static mlb_status make_names(const char* path, obj_names* nm) {
    size_t n = strlen(path);
    if (n < 5 || !mlb_ends_with(path, ".obj"))
        return mlb_fail(MLB_ERR_ARG, "%s: an OBJ export path must end in .obj", path);
    if (n + 16 >= sizeof nm->obj) return mlb_fail(MLB_ERR_ARG, "%s: path too long", path);
    const char* slash = strrchr(path, '/');
    nm->base = slash ? slash + 1 : path;
    if (nm->base[0] == '.' && nm->base[1] == 'o') return mlb_fail(MLB_ERR_ARG, "%s: empty file name", path);
    for (const char* c = nm->base; *c; c++)
        if (*c == ' ' || *c == '\t' || *c == '\n' || *c == '\r')   // MTL file names end at whitespace
            return mlb_fail(MLB_ERR_ARG, "%s: the file name must not contain whitespace (MTL cannot name it)", path);
    int stem = (int)(n - 4);
    snprintf(nm->obj, sizeof nm->obj, "%s", path);
    snprintf(nm->mtl, sizeof nm->mtl, "%.*s.mtl", stem, path);
    snprintf(nm->kd, sizeof nm->kd, "%.*s_kd.png", stem, path);
    snprintf(nm->ks, sizeof nm->ks, "%.*s_ks.png", stem, path);
    snprintf(nm->kr, sizeof nm->kr, "%.*s_roughness.png", stem, path);
    return MLB_OK;
}

static const char* base_of(const char* p) {
    const char* s = strrchr(p, '/');
    return s ? s + 1 : p;
}

// Phong exponent of the same highlight width as GGX at the mean roughness: alpha = r^2,
// Ns = 2 / alpha^2 - 2 (the Blinn-Phong / Beckmann correspondence), clamped to [0, 1000].
static double mean_ns(const float* kr, size_t n) {
    double s = 0;
    for (size_t i = 0; i < n; i++) s += kr[i];
    double r = s / (double)n, alpha = fmax(r * r, 1e-3);
    double ns = 2.0 / (alpha * alpha) - 2.0;
    return fmin(fmax(ns, 0.0), 1000.0);
}

static mlb_status write_obj_text(const char* path, const char* mtl_base, const char* mat, const mlb_asset* a) {
    mlb_atomic_file af;
    MLB_TRY(mlb_atomic_open(&af, path));
    FILE* f = af.f;
    size_t V = (size_t)a->n_verts;
    float* nrm = NULL;
    if (!a->normal) {   // area-weighted normals, as the glTF writer computes them
        nrm = calloc(3 * V, sizeof(float));
        if (!nrm) { mlb_atomic_abort(&af); return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); }
        for (int t = 0; t < a->n_faces; t++) {
            const int32_t* c = a->faces + 3 * (size_t)t;
            const float *p0 = a->pos + 3 * (size_t)c[0], *p1 = a->pos + 3 * (size_t)c[1], *p2 = a->pos + 3 * (size_t)c[2];
            float e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]}, e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
            float n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
            for (int k = 0; k < 3; k++)
                for (int j = 0; j < 3; j++) nrm[3 * (size_t)c[k] + j] += n[j];
        }
    }
    const float* N = a->normal ? a->normal : nrm;
    fprintf(f, "# written by matlaber: %d vertices, %d triangles; material in %s (docs/export.md)\n", a->n_verts,
            a->n_faces, mtl_base);
    fprintf(f, "mtllib %s\no %s\n", mtl_base, mat);
    for (size_t i = 0; i < V; i++) fprintf(f, "v %.9g %.9g %.9g\n", a->pos[3 * i], a->pos[3 * i + 1], a->pos[3 * i + 2]);
    for (size_t i = 0; i < V; i++) fprintf(f, "vt %.9g %.9g\n", a->uv[2 * i], a->uv[2 * i + 1]);
    for (size_t i = 0; i < V; i++) {
        const float* n = N + 3 * i;
        double l = sqrt((double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2]);
        if (l > 1e-20) fprintf(f, "vn %.7g %.7g %.7g\n", n[0] / l, n[1] / l, n[2] / l);
        else fprintf(f, "vn 0 1 0\n");
    }
    fprintf(f, "usemtl %s\ns 1\n", mat);
    for (int t = 0; t < a->n_faces; t++) {
        const int32_t* c = a->faces + 3 * (size_t)t;
        fprintf(f, "f %d/%d/%d %d/%d/%d %d/%d/%d\n", c[0] + 1, c[0] + 1, c[0] + 1, c[1] + 1, c[1] + 1, c[1] + 1, c[2] + 1,
                c[2] + 1, c[2] + 1);
    }
    free(nrm);
    return mlb_atomic_commit(&af);
}

mlb_status mlb_export_obj(const char* path, const mlb_asset* a) {
    if (!path) return mlb_fail(MLB_ERR_ARG, "OBJ export: NULL path");
    obj_names nm;
    MLB_TRY(make_names(path, &nm));
    mlb_status st = mlb_asset_check(a);
    if (st != MLB_OK) return mlb_fail_context(st, "%s", path);
    const char* mat = a->name ? a->name : "matlaber";
    for (const char* c = mat; *c; c++)
        if (*c == ' ' || *c == '\t' || *c == '\n' || *c == '\r' || *c == '#')
            return mlb_fail(MLB_ERR_ARG, "%s: material name '%s' has whitespace or '#'", path, mat);
    int S = a->tex_size;
    const char* written[5];
    int n_written = 0;
    mlb_png_options srgb = {8, MLB_PNG_SRGB}, lin = {8, MLB_PNG_AS_IS};
    if ((st = mlb_image_write_png(nm.kd, a->kd, S, S, 3, &srgb)) != MLB_OK) goto fail;
    written[n_written++] = nm.kd;
    if ((st = mlb_image_write_png(nm.ks, a->ks, S, S, 3, &srgb)) != MLB_OK) goto fail;
    written[n_written++] = nm.ks;
    if ((st = mlb_image_write_png(nm.kr, a->kr, S, S, 1, &lin)) != MLB_OK) goto fail;
    written[n_written++] = nm.kr;
    {
        char mtl[8192];
        int len = snprintf(mtl, sizeof mtl,
                           "# written by matlaber. kd, ks (= F0) and roughness (GGX alpha = roughness^2) are in the\n"
                           "# textures; Pr / map_Pr / Pm are the PBR extension keys (read by Blender's OBJ importer).\n"
                           "# Mapping and caveats: docs/export.md\n"
                           "newmtl %s\n"
                           "Ka 0 0 0\nKd 1 1 1\nKs 1 1 1\nNs %.6g\nd 1\nillum 2\n"
                           "map_Kd %s\nmap_Ks %s\n"
                           "Pr 1\nmap_Pr %s\nPm 0\n",
                           mat, mean_ns(a->kr, (size_t)S * (size_t)S), base_of(nm.kd), base_of(nm.ks), base_of(nm.kr));
        if (len < 0 || len >= (int)sizeof mtl) { st = mlb_fail(MLB_ERR_ARG, "%s: material text too long", nm.mtl); goto fail; }
        if ((st = mlb_write_file_atomic(nm.mtl, mtl, (size_t)len)) != MLB_OK) goto fail;
        written[n_written++] = nm.mtl;
    }
    if ((st = write_obj_text(nm.obj, base_of(nm.mtl), mat, a)) != MLB_OK) goto fail;
    return MLB_OK;
fail:
    for (int i = 0; i < n_written; i++) unlink(written[i]);
    return st;
}
