// The parts of the nn API that do not depend on the scalar type (compiled once, unlike ops.c):
// activation names and the default AdamW configuration.
#include "matlaber/nn.h"
#include <strings.h>

// Indexed by mlb_activation; the names are what configs and the command line use.
static const char* const activation_names[MLB_ACT_COUNT] = {
    [MLB_ACT_IDENTITY] = "identity",
    [MLB_ACT_RELU] = "relu",
    [MLB_ACT_LEAKY_RELU] = "leaky_relu",
    [MLB_ACT_SIGMOID] = "sigmoid",
    [MLB_ACT_TANH] = "tanh",
    [MLB_ACT_SILU] = "silu",
    [MLB_ACT_SOFTPLUS] = "softplus",
    [MLB_ACT_GELU] = "gelu",
    [MLB_ACT_GELU_TANH] = "gelu_tanh",
    [MLB_ACT_QUICK_GELU] = "quick_gelu",
    [MLB_ACT_ELU] = "elu",
};

const char* mlb_activation_name(mlb_activation act) {
    if ((int)act < 0 || act >= MLB_ACT_COUNT) return "invalid";
    return activation_names[act];
}

// Accepts the names above (any case) and two common synonyms: "linear"/"none" for identity and
// "swish" for silu. Unknown names leave *out alone and set the error message.
int mlb_activation_parse(const char* name, mlb_activation* out) {
    if (!name || !out) {
        mlb_fail(MLB_ERR_ARG, "activation name: NULL argument");
        return -1;
    }
    for (int a = 0; a < MLB_ACT_COUNT; a++) {
        if (strcasecmp(name, activation_names[a]) == 0) { *out = (mlb_activation)a; return 0; }
    }
    if (strcasecmp(name, "linear") == 0 || strcasecmp(name, "none") == 0) { *out = MLB_ACT_IDENTITY; return 0; }
    if (strcasecmp(name, "swish") == 0) { *out = MLB_ACT_SILU; return 0; }
    mlb_fail(MLB_ERR_ARG,
             "unknown activation '%s' (expected identity, relu, leaky_relu, sigmoid, tanh, silu, "
             "softplus, gelu, gelu_tanh, quick_gelu or elu)", name);
    return -1;
}

mlb_adam_config mlb_adamw_default(double lr) {
    mlb_adam_config c = {.lr = lr, .beta1 = 0.9, .beta2 = 0.999, .eps = 1e-8,
                         .weight_decay = 0.01, .decoupled = 1};
    return c;
}
