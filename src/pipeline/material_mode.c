// The material network's output mode by name (material_net.h): a config.json field, read without
// the network's code.
#include <string.h>
#include "matlaber/material_net.h"

const char* mlb_material_mode_name(mlb_material_mode m) {
    return m == MLB_MATERIAL_LATENT ? "latent" : m == MLB_MATERIAL_DIRECT ? "direct" : "?";
}

mlb_status mlb_material_mode_parse(const char* text, mlb_material_mode* out) {
    if (text && !strcmp(text, "latent")) { *out = MLB_MATERIAL_LATENT; return MLB_OK; }
    if (text && !strcmp(text, "direct")) { *out = MLB_MATERIAL_DIRECT; return MLB_OK; }
    return mlb_fail(MLB_ERR_ARG, "material mode '%s': expected 'latent' or 'direct'", text ? text : "(null)");
}
