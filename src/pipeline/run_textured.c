// A finished run unwrapped and baked into a textured asset (run_textured.h).
#include "matlaber/run_textured.h"
#include <string.h>
#include "matlaber/fileio.h"
#include "matlaber/material_net.h"

static mlb_status eval_material(void* user, const float* pos, size_t n, float* k) {
    return mlb_material_eval(user, pos, n, k);
}

void mlb_run_textured_free(mlb_run_textured* r) {
    mlb_baked_free(&r->baked);
    mlb_uv_mesh_free(&r->uv);
    mlb_run_asset_free(&r->run);
    memset(r, 0, sizeof *r);
}

mlb_status mlb_run_textured_load(mlb_run_textured* r, const char* dir, int size) {
    memset(r, 0, sizeof *r);
    if (!mlb_is_dir(dir)) return mlb_fail(MLB_ERR_NOT_FOUND, "%s: no such run folder", dir);
    mlb_status s = mlb_run_asset_load(&r->run, dir);
    if (s) return s;
    mlb_uv_options uo = mlb_uv_default();
    uo.texture_size = size;
    // the default 4-texel gutter is for 1024² textures; small textures get a proportional one
    if (uo.gutter > size / 64) uo.gutter = size >= 128 ? size / 64 : 1;
    s = mlb_uv_unwrap(&r->run.mesh, &uo, &r->uv, &r->uv_stats);
    if (s) s = mlb_fail_context(s, "%s: UV atlas", dir);
    if (!s) s = mlb_bake(&r->uv, size, eval_material, &r->run.material, MLB_BAKE_DEFAULT_DILATE, &r->baked);
    if (s) {
        mlb_run_textured_free(r);
        return s;
    }
    const mlb_mesh* m = &r->uv.mesh;
    r->asset = (mlb_asset){m->n_verts, m->n_faces, m->pos, m->normal, m->uv, m->faces, size,
                           r->baked.kd, r->baked.ks, r->baked.roughness, "matlaber"};
    return MLB_OK;
}

mlb_status mlb_run_export_glb(const char* dir, int size, const char* path) {
    mlb_run_textured r;
    mlb_status s = mlb_run_textured_load(&r, dir, size);
    if (s) return s;
    s = mlb_export_glb(path, &r.asset);
    mlb_run_textured_free(&r);
    return s;
}
