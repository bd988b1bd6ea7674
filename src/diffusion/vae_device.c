// The VAE's device mirror (vae.h, mlb_vae_use_device): a copy of the weights on a GPU, or the
// CPU's bf16 table, that the host-buffer calls (be NULL) then run on. Float only, so not
// dual-compiled: no device has a double table, and the model code (vae.c, vae_decoder.c) only
// reads v->mirror and v->mirror_ops.
#include "matlaber/backend.h"
#include "matlaber/vae.h"

mlb_status mlb_vae_use_device(mlb_vae* v, mlb_device d, mlb_gemm_precision prec) {
    if (!v) return mlb_fail(MLB_ERR_ARG, "mlb_vae_use_device: NULL VAE");
    mlb_vae_free(v->mirror);
    v->mirror = NULL;
    // on the CPU no copy: only bf16 changes the ops (fp16 and tf32 are GPU formats: fp32 here)
    v->mirror_ops = d == MLB_DEVICE_CPU && prec == MLB_GEMM_BF16 ? mlb_backend_for(d, prec) : NULL;
    if (d == MLB_DEVICE_CPU) return MLB_OK;
    if (v->device != MLB_DEVICE_CPU) return mlb_fail(MLB_ERR_ARG, "mlb_vae_use_device: the VAE must be on the CPU");
    const mlb_backend* be = mlb_backend_for(d, prec);
    mlb_vae* m;
    mlb_status s = mlb_vae_create(be, &v->cfg, &m);
    if (!s) {
        s = be->upload(m->params, v->params, v->n_params);
        if (s) mlb_vae_free(m);
    }
    if (s) return mlb_fail_context(s, "moving the VAE (%zu parameters) to the %s", v->n_params, mlb_device_name(d));
    v->mirror = m;
    v->mirror_ops = be;
    return MLB_OK;
}
