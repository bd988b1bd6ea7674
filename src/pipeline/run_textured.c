// A finished run unwrapped and baked into a textured asset (run_textured.h).
#include "matlaber/run_textured.h"
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/fileio.h"
#include "matlaber/latent_export.h"
#include "matlaber/material_net.h"
#include "matlaber/obj.h"
#include "matlaber/paint.h"

static mlb_status eval_material(void* user, const float* pos, size_t n, float* k) {
    return mlb_material_eval(user, pos, n, k);
}

static mlb_status eval_latent(void* user, const float* pos, size_t n, float* z) {
    return mlb_material_eval_latent(user, pos, n, z);
}

void mlb_run_textured_free(mlb_run_textured* r) {
    free(r->latent);
    mlb_baked_free(&r->baked);
    mlb_uv_mesh_free(&r->uv);
    mlb_run_asset_free(&r->run);
    memset(r, 0, sizeof *r);
}

// The paint input's own UVs as a one-chart "atlas" (the mesh is moved into it, not copied).
static mlb_status own_uv_atlas(mlb_mesh* in, int size, mlb_uv_mesh* out, mlb_uv_stats* st) {
    memset(out, 0, sizeof *out);
    size_t V = (size_t)in->n_verts, F = (size_t)in->n_faces;
    out->vert_src = malloc(sizeof(int32_t) * (V ? V : 1));
    out->face_chart = calloc(F ? F : 1, sizeof(int32_t));
    if (!out->vert_src || !out->face_chart) {
        mlb_uv_mesh_free(out);
        return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    }
    for (size_t i = 0; i < V; i++) out->vert_src[i] = (int32_t)i;
    out->mesh = *in;
    memset(in, 0, sizeof *in);
    out->n_charts = 1;
    out->texture_size = size;
    mlb_uv_measure(out, st);
    return MLB_OK;
}

mlb_status mlb_run_textured_load(mlb_run_textured* r, const char* dir, int size) {
    memset(r, 0, sizeof *r);
    if (!mlb_is_dir(dir)) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no such run folder", dir);
    mlb_status s = mlb_run_asset_load(&r->run, dir);
    if (s) return s;
    const mlb_pipeline_config* c = &r->run.config;
    const int paint = c->paint_mesh[0] != 0;
    mlb_mesh input;   // paint: the input as given (original positions, its UVs and normals)
    memset(&input, 0, sizeof input);
    if (paint) {
        char path[MLB_PIPELINE_PATH + 64];
        snprintf(path, sizeof path, "%s/input/mesh.obj", dir);
        s = mlb_obj_load(path, &input);
        if (!s && !input.normal) s = mlb_mesh_compute_normals(&input);
        if (!s && input.n_verts != r->run.mesh.n_verts)
            s = mlb_fail(MLB_ERR_FORMAT, "%s: %d vertices, but final/mesh.obj has %d", path, input.n_verts, r->run.mesh.n_verts);
        if (s) {
            mlb_mesh_free(&input);
            mlb_run_textured_free(r);
            return s;
        }
    }
    mlb_uv_options uo = mlb_uv_default();
    uo.texture_size = size;
    // the default 4-texel gutter is for 1024² textures; small textures get a proportional one
    if (uo.gutter > size / 64) uo.gutter = size >= 128 ? size / 64 : 1;
    if (paint && input.uv && c->paint_keep_uv) {
        s = own_uv_atlas(&input, size, &r->uv, &r->uv_stats);
    } else {
        s = mlb_uv_unwrap(paint ? &input : &r->run.mesh, &uo, &r->uv, &r->uv_stats);
        if (s) s = mlb_fail_context(s, "%s: UV atlas", dir);
    }
    mlb_mesh_free(&input);
    mlb_framed_material fm = {&r->run.material, c->paint_centre, c->paint_scale};
    if (!s && paint) s = mlb_bake(&r->uv, size, mlb_framed_material_eval, &fm, MLB_BAKE_DEFAULT_DILATE, &r->baked);
    if (!s && !paint) s = mlb_bake(&r->uv, size, eval_material, &r->run.material, MLB_BAKE_DEFAULT_DILATE, &r->baked);
    if (!s && r->run.material.cfg.mode == MLB_MATERIAL_LATENT) {   // the codes over the same texels, for the viewer's editor
        r->latent = malloc(sizeof(float) * 4 * (size_t)size * (size_t)size);
        if (!r->latent) s = mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for the latent texture", dir);
        else if (paint) s = mlb_bake_codes(&r->uv, size, mlb_framed_material_eval_latent, &fm, MLB_BAKE_DEFAULT_DILATE, r->latent);
        else s = mlb_bake_codes(&r->uv, size, eval_latent, &r->run.material, MLB_BAKE_DEFAULT_DILATE, r->latent);
    }
    if (s) {
        mlb_run_textured_free(r);
        return s;
    }
    const mlb_mesh* m = &r->uv.mesh;
    r->asset = (mlb_asset){m->n_verts, m->n_faces, m->pos, m->normal, m->uv, m->faces, size,
                           r->baked.kd, r->baked.ks, r->baked.roughness, "matlaber"};
    return MLB_OK;
}

mlb_status mlb_run_textured_write_glb(const mlb_run_textured* r, const char* path) {
    MLB_TRY(mlb_export_glb(path, &r->asset));
    if (!mlb_ends_with(path, ".glb")) return MLB_OK;   // the sidecars are named after NAME.glb
    if (!r->latent) {
        mlb_latent_export_remove(path);
        return MLB_OK;
    }
    return mlb_latent_export(path, &r->run.material.dec, r->latent, r->asset.tex_size);
}

mlb_status mlb_run_export_glb(const char* dir, int size, const char* path) {
    mlb_run_textured r;
    mlb_status s = mlb_run_textured_load(&r, dir, size);
    if (s) return s;
    s = mlb_run_textured_write_glb(&r, path);
    mlb_run_textured_free(&r);
    return s;
}
