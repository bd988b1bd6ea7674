// Device selection (--device). Without the CUDA part the CUDA functions it calls are the stand-ins
// of src/nn/no_cuda.c (they need the op list's types, which live above core).
#include "matlaber/device.h"
#include <stdlib.h>
#include <string.h>

static mlb_device current_device = MLB_DEVICE_CPU;

mlb_device mlb_device_current(void) { return current_device; }
const char* mlb_device_name(mlb_device d) { return d == MLB_DEVICE_CUDA ? "cuda" : "cpu"; }

#define NO_CUDA_HINT "install the CUDA toolkit at /usr/local/cuda and rebuild, or use --device cpu"

// "cuda" -> 0, "cuda:3" -> 3; -1 when name is not a cuda name, -2 when the index is malformed.
static int cuda_index(const char* name) {
    if (strncmp(name, "cuda", 4) != 0) return -1;
    if (name[4] == 0) return 0;
    if (name[4] != ':' || name[5] < '0' || name[5] > '9') return -2;
    char* end;
    long i = strtol(name + 5, &end, 10);
    if (*end || i > 1024) return -2;
    return (int)i;
}

static mlb_status require_cuda(const char* name, int index) {
    if (!mlb_cuda_compiled())
        return mlb_fail(MLB_ERR_DEVICE, "--device %s: this build has no CUDA part (built without CUDA: nvcc was not "
                        "found at build time); " NO_CUDA_HINT, name);
    int count = 0;
    if (mlb_cuda_probe(&count) != MLB_OK)
        return mlb_fail_context(MLB_ERR_DEVICE, "--device %s (use --device cpu)", name);
    if (index >= count)
        return mlb_fail(MLB_ERR_DEVICE, "--device %s: GPU %d asked for, %d visible; use --device cpu or cuda:0..%d", name,
                        index, count, count - 1);
    return MLB_OK;
}

mlb_status mlb_device_parse(const char* name, mlb_device* out) {
    if (!name) return mlb_fail(MLB_ERR_ARG, "device name is NULL (expected cpu, cuda or auto)");
    if (strcmp(name, "cpu") == 0) { *out = MLB_DEVICE_CPU; return MLB_OK; }
    if (strcmp(name, "auto") == 0) { *out = mlb_cuda_device_count() > 0 ? MLB_DEVICE_CUDA : MLB_DEVICE_CPU; return MLB_OK; }
    int idx = cuda_index(name);
    if (idx >= 0) {
        MLB_TRY(require_cuda(name, idx));
        *out = MLB_DEVICE_CUDA;
        return MLB_OK;
    }
    return mlb_fail(MLB_ERR_ARG, "unknown device '%s' (expected cpu, cuda, cuda:N or auto)", name);
}

mlb_status mlb_device_select(const char* name, mlb_device* out) {
    mlb_device d;
    MLB_TRY(mlb_device_parse(name, &d));
    if (d == MLB_DEVICE_CUDA) {
        int idx = cuda_index(name);
        if (idx < 0) idx = 0;   // "auto"
        mlb_status st = mlb_cuda_init(idx);
        if (st != MLB_OK) {
            if (strcmp(name, "auto") != 0) return mlb_fail_context(st, "--device %s (use --device cpu)", name);
            d = MLB_DEVICE_CPU;   // auto: a GPU that cannot be initialised means the CPU
        }
    }
    current_device = d;
    *out = d;
    return MLB_OK;
}

mlb_status mlb_device_option(const char* arg, mlb_device* out) {
    if (!arg) {
        arg = getenv("MATLABER_DEVICE");
        if (!arg || !*arg) arg = "auto";
    }
    return mlb_device_select(arg, out);
}
