// libFuzzer target for a run folder's config.json (mlb_pipeline_config_parse; not part of the CMake
// build). A rejected input must leave the config as it was and a message naming the file; an
// accepted one must be a valid config (mlb_pipeline_validate) whose every text field fits its
// buffer, and its own config.json (mlb_pipeline_config_text) must read back as the same config,
// field for field. A broken promise aborts.
//
// Build and run: scripts/fuzz.sh config [SECONDS] (clang with libFuzzer, ASan and UBSan).
// Built with -DMLB_FUZZ_SEED the same file is a small program that writes seed files into the
// folder given as its argument.
#include "matlaber/pipeline.h"
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PROMISE(cond) do { if (!(cond)) { fprintf(stderr, "broken promise: %s\n", #cond); abort(); } } while (0)

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    mlb_pipeline_config c, before;
    memset(&c, 0x5a, sizeof c);
    before = c;
    mlb_status s = mlb_pipeline_config_parse(&c, (const char*)data, size, "fuzz.json");
    if (s != MLB_OK) {
        PROMISE(!memcmp(&c, &before, sizeof c));
        PROMISE(strncmp(mlb_last_error(), "fuzz.json: ", 11) == 0);
        return 0;
    }
    PROMISE(mlb_pipeline_validate(&c) == MLB_OK);
    PROMISE(memchr(c.prompt, 0, sizeof c.prompt) && memchr(c.model, 0, sizeof c.model) && memchr(c.init, 0, sizeof c.init));
    PROMISE(memchr(c.paint_mesh, 0, sizeof c.paint_mesh) && memchr(c.precision, 0, sizeof c.precision));
    PROMISE(c.n_envs >= 1 && c.n_envs <= MLB_PIPELINE_MAX_ENVS);
    for (int i = 0; i < c.n_envs; i++) PROMISE(c.envs[i][0] && memchr(c.envs[i], 0, sizeof c.envs[i]));
    char* text = mlb_pipeline_config_text(&c);
    PROMISE(text);
    mlb_pipeline_config back;
    s = mlb_pipeline_config_parse(&back, text, strlen(text), "again.json");
    PROMISE(s == MLB_OK);
    PROMISE(mlb_pipeline_config_differs(&c, &back, NULL) == NULL);
    free(text);
    return 0;
}

#ifdef MLB_FUZZ_SEED
int main(int argc, char** argv) {
    if (argc != 2) { fprintf(stderr, "usage: %s CORPUS_DIR\n", argv[0]); return 2; }
    int ok = 1;
    for (int k = 0; k < 4; k++) {   // the defaults, the presets, a paint run
        mlb_pipeline_config c = mlb_pipeline_default();
        snprintf(c.prompt, sizeof c.prompt, "a \"golden\" goblet");
        snprintf(c.model, sizeof c.model, "models/matlaber-tiny");
        c.latent_iters = c.geometry_iters / 3;
        if (k == 1) mlb_pipeline_preset(&c, "tiny");
        if (k == 2) mlb_pipeline_preset(&c, "cpu");
        if (k == 3) {
            snprintf(c.paint_mesh, sizeof c.paint_mesh, "chair.glb");
            c.geometry_iters = 0;
            c.paint_scale = 0.9;
            c.paint_centre[1] = -2.5;
        }
        char* text = mlb_pipeline_config_text(&c);
        char path[4096];
        snprintf(path, sizeof path, "%s/seed_%d.json", argv[1], k);
        FILE* f = text ? fopen(path, "wb") : NULL;
        ok &= f && fputs(text, f) >= 0;
        if (f) ok &= fclose(f) == 0;
        free(text);
    }
    return ok ? 0 : 1;
}
#endif
