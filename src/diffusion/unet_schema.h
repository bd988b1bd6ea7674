// The UNet's tensors in the diffusers layout, written once: the walk by which the loader
// (unet_load.c) registers the model's parameters and the random-weight writer (unet_random.c) lists
// the tensors of a file, in the order of the parameter buffer. Not part of the API.
#ifndef MATLABER_UNET_SCHEMA_H
#define MATLABER_UNET_SCHEMA_H
#include <stdint.h>
#include "matlaber/unet.h"

typedef struct {
    const char* name;    // diffusers name: "down_blocks.0.resnets.1.conv1.weight"
    int ndim;
    int64_t shape[4];    // the unused dimensions 0
    int as_linear;       // a transformer's proj_in / proj_out: runs as a linear layer over the tokens
                         // whatever its dimensions (SD 1.x stores them as 1x1 convs)
    float** slot;        // the model's pointer for it; NULL when walking without a model
} unet_schema_tensor;

typedef mlb_status (*unet_schema_visit)(void* ctx, const unet_schema_tensor* t);

// Visits every tensor of configuration c in order; stops at the first error the visitor returns.
// With a model u (c its configuration), also sets what the walk knows of each block: a ResNet's
// channels (and NULL shortcut slots when cin == cout), a transformer's channels and heads.
mlb_status unet_schema_walk(const mlb_unet_config* c, mlb_unet* u, unet_schema_visit visit, void* ctx);

#endif
