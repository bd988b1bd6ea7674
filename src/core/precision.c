// The GEMMs' operand precision (--precision; device.h): its names and the program's choice. Apart
// from device.c, which reaches the CUDA stand-ins, so that a config.json can be read without them.
#include "matlaber/device.h"
#include <string.h>

const char* mlb_gemm_precision_name(mlb_gemm_precision p) {
    switch (p) {
    case MLB_GEMM_FP32: return "fp32";
    case MLB_GEMM_TF32: return "tf32";
    case MLB_GEMM_FP16: return "fp16";
    case MLB_GEMM_BF16: return "bf16";
    }
    return "?";
}

mlb_status mlb_gemm_precision_parse(const char* name, mlb_gemm_precision* out) {
    for (int p = MLB_GEMM_FP32; p <= MLB_GEMM_BF16; p++)
        if (name && !strcmp(name, mlb_gemm_precision_name((mlb_gemm_precision)p))) {
            *out = (mlb_gemm_precision)p;
            return MLB_OK;
        }
    return mlb_fail(MLB_ERR_ARG, "--precision: expected fp16, bf16, tf32 or fp32, not '%s'", name ? name : "");
}

static mlb_gemm_precision current_precision = MLB_GEMM_FP16;
static int precision_chosen = 0;
void mlb_set_gemm_precision(mlb_gemm_precision p) { current_precision = p; precision_chosen = 1; }
mlb_gemm_precision mlb_gemm_precision_current(void) { return current_precision; }
int mlb_gemm_precision_chosen(void) { return precision_chosen; }
