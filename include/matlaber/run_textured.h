// A finished run as a textured asset: final/mesh.obj unwrapped into a UV atlas and the material
// field (final/material.safetensors) baked into kd / ks / roughness maps, in the view export.h's
// writers take. `matlaber export` and `view` read runs through it; a run whose config asks for it
// (export_texture > 0) writes final/asset.glb with it as its last step.
#ifndef MATLABER_RUN_TEXTURED_H
#define MATLABER_RUN_TEXTURED_H
#include "matlaber/bake.h"
#include "matlaber/export.h"
#include "matlaber/pipeline.h"
#include "matlaber/uv_atlas.h"

typedef struct {
    mlb_run_asset run;    // final/mesh.obj and final/material.safetensors
    mlb_uv_mesh uv;
    mlb_baked baked;
    mlb_uv_stats uv_stats;
    mlb_asset asset;      // points into uv and baked
    float* latent;        // latent-mode runs: [size, size, 4] the codes baked as `baked` (mlb_bake_codes); else NULL
} mlb_run_textured;

// dir: a finished run folder; size: the texture size (the atlas's gutter scales with it).
mlb_status mlb_run_textured_load(mlb_run_textured* r, const char* dir, int size);
void mlb_run_textured_free(mlb_run_textured* r);
// dir's asset, baked at size², written as the .glb at path (atomically: a complete file or none);
// a latent-mode run also gets its codes and decoder beside it (latent_export.h), a direct-mode run
// none (stale ones removed).
mlb_status mlb_run_export_glb(const char* dir, int size, const char* path);
// r's asset as the .glb at path, and the latent sidecars as mlb_run_export_glb writes them.
mlb_status mlb_run_textured_write_glb(const mlb_run_textured* r, const char* path);

#endif
