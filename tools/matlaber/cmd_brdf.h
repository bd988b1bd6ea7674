// Pieces of 'matlaber brdf' that 'matlaber demo' reuses.
#ifndef MATLABER_CMD_BRDF_H
#define MATLABER_CMD_BRDF_H
#include <stdio.h>
#include "matlaber/brdf.h"
#include "matlaber/brdf_ae.h"

#define BRDF_MAX_DATA_PATHS 64
typedef struct {
    const char* paths[BRDF_MAX_DATA_PATHS];
    int n_paths;                 // 0: procedural
    long procedural_samples;     // -1: default_procedural without paths, 0 with them
    long default_procedural;
    size_t pixels_per_map;       // 0: every pixel
    uint64_t seed;
} brdf_data_options;

int brdf_gather_data(const brdf_data_options* o, mlb_brdf_set* set, char* description, size_t desc_size);
// Parses 'train' options from argv (argv[0] = "train"); trains and saves. When trained_out is not
// NULL the model is handed over instead of freed.
int brdf_train_main(int argc, char** argv, const char* default_out, mlb_brdf_ae* trained_out);
int brdf_eval_run(const mlb_brdf_ae* ae, const char* source, const brdf_data_options* data, int json);
void brdf_print_evaluation(FILE* out, const char* model, const char* data, const mlb_brdf_eval_result* r);

#endif
