// A mesh from outside, made fit for painting (paint.h, docs/paint.md): loaded through the OBJ
// reader's checks plus the ones painting needs, normals repaired where the file's are unusable, the
// generation frame computed, and an exact copy written into the run.
#include "matlaber/paint.h"
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/fileio.h"
#include "matlaber/gltf.h"
#include "matlaber/log.h"
#include "matlaber/obj.h"

// A face's doubled area (|e1 x e2|) in double: exact zero for repeated or collinear corners.
static double face_area2(const mlb_mesh* m, int f) {
    const int32_t* t = m->faces + 3 * (size_t)f;
    const float *a = m->pos + 3 * (size_t)t[0], *b = m->pos + 3 * (size_t)t[1], *c = m->pos + 3 * (size_t)t[2];
    double e1[3], e2[3];
    for (int k = 0; k < 3; k++) { e1[k] = (double)b[k] - a[k]; e2[k] = (double)c[k] - a[k]; }
    double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
    return sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
}

// The file's normals where they are usable (finite, not zero: the reader already refuses non-finite
// numbers), unit length; elsewhere the area-weighted normal over welded positions.
static mlb_status repair_normals(mlb_mesh* m, int* n_repaired) {
    *n_repaired = 0;
    float* given = m->normal;
    m->normal = NULL;
    mlb_status s = mlb_mesh_compute_normals(m);   // welded: seams (split by uv) get one normal
    if (s || !given) { free(given); return s; }
    for (size_t i = 0; i < (size_t)m->n_verts; i++) {
        const float* g = given + 3 * i;
        double len = sqrt((double)g[0] * g[0] + (double)g[1] * g[1] + (double)g[2] * g[2]);
        if (!(len > 1e-20) || !isfinite(len)) { (*n_repaired)++; continue; }
        for (int k = 0; k < 3; k++) m->normal[3 * i + k] = (float)(g[k] / len);
    }
    free(given);
    return MLB_OK;
}

mlb_status mlb_paint_frame(const mlb_mesh* m, double centre[3], double* scale) {
    if (!m || m->n_verts <= 0 || !m->pos) return mlb_fail(MLB_ERR_ARG, "the mesh has no vertices");
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t i = 0; i < (size_t)m->n_verts; i++)
        for (int k = 0; k < 3; k++) {
            double v = m->pos[3 * i + k];
            if (!isfinite(v)) return mlb_fail(MLB_ERR_NUMERIC, "vertex %zu has a non-finite position", i);
            if (v < lo[k]) lo[k] = v;
            if (v > hi[k]) hi[k] = v;
        }
    for (int k = 0; k < 3; k++) centre[k] = 0.5 * lo[k] + 0.5 * hi[k];   // halves first: no overflow near FLT_MAX
    double r = mlb_mesh_radius_about(m, centre);
    if (!(r > 0) || !isfinite(MLB_PAINT_RADIUS / r))
        return mlb_fail(MLB_ERR_ARG, "the mesh has no extent (every vertex at one point)");
    *scale = MLB_PAINT_RADIUS / r;
    return MLB_OK;
}

void mlb_paint_to_frame(const double centre[3], double scale, const float* in, float* out, size_t n) {
    for (size_t i = 0; i < n; i++)
        for (int k = 0; k < 3; k++) out[3 * i + k] = (float)(((double)in[3 * i + k] - centre[k]) * scale);
}

// Moves the points into the frame and evaluates the field there: the material (7 numbers a point)
// or, with latent set, the codes (4).
static mlb_status framed_eval(const mlb_framed_material* fm, const float* pos, size_t n, float* out, int latent) {
    float* p = malloc(sizeof(float) * 3 * (n ? n : 1));
    if (!p) return mlb_fail(MLB_ERR_NOMEM, "out of memory for %zu points' material", n);
    mlb_paint_to_frame(fm->centre, fm->scale, pos, p, n);
    mlb_status s = latent ? mlb_material_eval_latent(fm->net, p, n, out) : mlb_material_eval(fm->net, p, n, out);
    free(p);
    return s;
}

mlb_status mlb_framed_material_eval(void* user, const float* pos, size_t n, float* k) { return framed_eval(user, pos, n, k, 0); }

mlb_status mlb_framed_material_eval_latent(void* user, const float* pos, size_t n, float* z) { return framed_eval(user, pos, n, z, 1); }

static int is_gltf(const char* path) {
    static const char* const ext[4] = {".glb", ".gltf", ".GLB", ".GLTF"};
    for (int i = 0; i < 4; i++)
        if (mlb_ends_with(path, ext[i])) return 1;
    return 0;
}

mlb_status mlb_paint_load_mesh(const char* path, int keep_uv, mlb_mesh* out, mlb_paint_mesh_info* info) {
    mlb_paint_mesh_info inf;
    memset(&inf, 0, sizeof inf);
    memset(out, 0, sizeof *out);
    if (info) *info = inf;
    if (mlb_is_dir(path)) return mlb_fail(MLB_ERR_ARG, "%s: a folder, not a mesh file", path);
    mlb_mesh m;
    mlb_status s;
    int uv_dropped;
    if (is_gltf(path)) {   // .glb / .gltf: the glTF reader (its checks: include/matlaber/gltf.h)
        mlb_gltf_options opt = {MLB_PAINT_MAX_BYTES, MLB_PAINT_MAX_FACES, !keep_uv, 0};
        mlb_gltf_info gi;
        s = mlb_gltf_load(path, &m, &opt, &gi);
        if (s) return s;   // the reader's message names the file and the element
        uv_dropped = gi.uv_dropped;
        inf.n_unused_positions = gi.n_unused;
        if (gi.n_skipped) mlb_log(MLB_LOG_INFO, "%s: %d point or line primitives skipped", path, gi.n_skipped);
        mlb_log(MLB_LOG_INFO, "%s: %d meshes placed by the scene (%d primitives)%s", path, gi.n_instances, gi.n_primitives,
                gi.n_mirrored ? ", some mirrored" : "");
    } else {
        mlb_obj_options opt;
        memset(&opt, 0, sizeof opt);
        opt.max_bytes = MLB_PAINT_MAX_BYTES;
        opt.max_triangles = MLB_PAINT_MAX_FACES;
        opt.drop_uv = !keep_uv;
        mlb_obj_info oi;
        s = mlb_obj_load_ex(path, &m, &opt, &oi);
        if (s) return s;   // the reader's message names the file and the line
        if (m.n_faces == 0)
            s = mlb_fail(MLB_ERR_FORMAT, "%s: no faces (%d lines, %d vertices): nothing to paint", path, oi.n_lines, oi.n_positions);
        uv_dropped = oi.uv_dropped;
        inf.n_polygons_split = oi.n_polygons_split;
        inf.n_unused_positions = oi.n_unused_positions;
    }
    if (!s && keep_uv && uv_dropped)
        s = mlb_fail(MLB_ERR_FORMAT, "%s: only some faces have UVs (%s): give every face UVs, or pass --uv atlas "
                     "to replace them with an atlas", path, is_gltf(path) ? "TEXCOORD_0 in some primitives" : "vt on some face corners");
    for (size_t i = 0; !s && m.uv && i < 2 * (size_t)m.n_verts; i++) {
        float u = m.uv[i];
        if (u < -MLB_PAINT_UV_TOL || u > 1 + MLB_PAINT_UV_TOL)
            s = mlb_fail(MLB_ERR_FORMAT, "%s: vertex %zu has %s = %g, outside [0, 1] (tiled or UDIM UVs cannot be baked "
                         "into one texture): pass --uv atlas to replace them with an atlas", path, i / 2,
                         i % 2 ? "v" : "u", (double)u);
        else m.uv[i] = u < 0 ? 0 : u > 1 ? 1 : u;
    }
    double total = 0;
    for (int f = 0; !s && f < m.n_faces; f++) {
        double a = face_area2(&m, f);
        if (!(a > 0)) inf.n_degenerate++;
        total += a;
    }
    if (!s && !(total > 0)) s = mlb_fail(MLB_ERR_FORMAT, "%s: all %d faces have zero area: nothing to paint", path, m.n_faces);
    double centre[3], scale;
    if (!s) s = mlb_paint_frame(&m, centre, &scale);   // refuses a mesh without extent
    if (s && !strstr(mlb_last_error(), path)) s = mlb_fail_context(s, "%s", path);
    inf.normals_computed = m.normal == NULL;
    if (!s) s = repair_normals(&m, &inf.n_normals_repaired);
    if (s) {
        mlb_mesh_free(&m);
        return s;
    }
    inf.n_verts = m.n_verts;
    inf.n_faces = m.n_faces;
    inf.has_uv = m.uv != NULL;
    if (inf.n_degenerate) mlb_log(MLB_LOG_WARN, "%s: %d faces of zero area (kept; they cover nothing)", path, inf.n_degenerate);
    if (inf.n_normals_repaired)
        mlb_log(MLB_LOG_WARN, "%s: %d zero-length normals replaced by area-weighted ones", path, inf.n_normals_repaired);
    if (inf.n_unused_positions) mlb_log(MLB_LOG_INFO, "%s: %d vertices no face uses (dropped)", path, inf.n_unused_positions);
    *out = m;
    if (info) *info = inf;
    return MLB_OK;
}

mlb_status mlb_paint_frame_camera(const double centre[3], double scale, mlb_camera* cam) {
    // the view matrix's rows are the camera's right, up and back axes in world coordinates
    const double* V = cam->view.m;
    double up[3] = {V[4], V[5], V[6]}, back[3] = {V[8], V[9], V[10]}, eye[3], target[3];
    for (int k = 0; k < 3; k++) {
        eye[k] = (cam->eye[k] - centre[k]) * scale;
        target[k] = eye[k] - back[k];   // the look-at direction; the distance does not matter
        cam->target[k] = (cam->target[k] - centre[k]) * scale;
        cam->eye[k] = eye[k];
    }
    cam->near_z *= scale;
    cam->far_z *= scale;
    cam->radius *= scale;
    MLB_TRY(mlb_look_at(&cam->view, eye, target, up));
    MLB_TRY(mlb_perspective(&cam->proj, cam->fovy_deg, cam->aspect, cam->near_z, cam->far_z));
    cam->view_proj = mlb_mat4_mul(&cam->proj, &cam->view);
    return MLB_OK;
}

mlb_status mlb_paint_write_obj(const char* path, const mlb_mesh* m) {
    mlb_atomic_file af;
    mlb_status s = mlb_atomic_open(&af, path);
    if (s) return s;
    fprintf(af.f, "# matlaber paint: the input mesh as read (one line per vertex, positions as given)\n");
    size_t V = (size_t)m->n_verts;
    for (size_t i = 0; i < V; i++) fprintf(af.f, "v %.9g %.9g %.9g\n", m->pos[3 * i], m->pos[3 * i + 1], m->pos[3 * i + 2]);
    if (m->uv)
        for (size_t i = 0; i < V; i++) fprintf(af.f, "vt %.9g %.9g\n", m->uv[2 * i], m->uv[2 * i + 1]);
    if (m->normal)
        for (size_t i = 0; i < V; i++)
            fprintf(af.f, "vn %.9g %.9g %.9g\n", m->normal[3 * i], m->normal[3 * i + 1], m->normal[3 * i + 2]);
    for (size_t f = 0; f < (size_t)m->n_faces; f++) {
        fputc('f', af.f);
        for (int k = 0; k < 3; k++) {
            int v = m->faces[3 * f + k] + 1;
            if (m->uv && m->normal) fprintf(af.f, " %d/%d/%d", v, v, v);
            else if (m->uv) fprintf(af.f, " %d/%d", v, v);
            else if (m->normal) fprintf(af.f, " %d//%d", v, v);
            else fprintf(af.f, " %d", v);
        }
        fputc('\n', af.f);
    }
    if (ferror(af.f)) {
        mlb_atomic_abort(&af);
        return mlb_fail(MLB_ERR_IO, "%s: write failed", path);
    }
    return mlb_atomic_commit(&af);
}
