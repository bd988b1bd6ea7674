// The SD VAE's configuration (vae.h): Stable Diffusion's, its check and the latent size it gives.
// A file of its own: the model (vae.c) checks a configuration before it builds one, and loading
// (vae_load.c) reads one and builds the model, so with the check in either they would call each
// other.
#include "matlaber/vae.h"

mlb_vae_config mlb_vae_sd_config(void) {
    mlb_vae_config c = {3, 3, 4, 4, {128, 256, 512, 512}, 2, 32, 1e-6f, 0.18215f, 1};
    return c;
}

mlb_status mlb_vae_config_check(const mlb_vae_config* c) {
    if (!c) return mlb_fail(MLB_ERR_ARG, "VAE config: NULL");
    if (c->n_levels < 1 || c->n_levels > MLB_VAE_MAX_LEVELS)
        return mlb_fail(MLB_ERR_ARG, "VAE config: %d levels (supported: 1 to %d)", c->n_levels, MLB_VAE_MAX_LEVELS);
    if (c->layers_per_block < 1 || c->layers_per_block > MLB_VAE_MAX_LAYERS)
        return mlb_fail(MLB_ERR_ARG, "VAE config: %d layers per block (supported: 1 to %d)", c->layers_per_block,
                        MLB_VAE_MAX_LAYERS);
    if (c->in_channels < 1 || c->out_channels < 1 || c->latent_channels < 1 || c->in_channels > 4096 ||
        c->out_channels > 4096 || c->latent_channels > 4096)
        return mlb_fail(MLB_ERR_ARG, "VAE config: bad channel counts: in %d, out %d, latent %d", c->in_channels,
                        c->out_channels, c->latent_channels);
    if (c->norm_groups < 1) return mlb_fail(MLB_ERR_ARG, "VAE config: %d norm groups", c->norm_groups);
    if (!(c->norm_eps > 0 && c->norm_eps < 1)) return mlb_fail(MLB_ERR_ARG, "VAE config: norm eps %g", c->norm_eps);
    for (int l = 0; l < c->n_levels; l++) {
        if (c->block_out[l] < 1 || c->block_out[l] > 65536)
            return mlb_fail(MLB_ERR_ARG, "VAE config: block_out[%d] = %d", l, c->block_out[l]);
        if (c->block_out[l] % c->norm_groups)
            return mlb_fail(MLB_ERR_ARG, "VAE config: block_out[%d] = %d is not a multiple of the %d groups", l,
                            c->block_out[l], c->norm_groups);
    }
    return MLB_OK;
}

int mlb_vae_latent_size(const mlb_vae_config* cfg, int s) {
    if (!cfg || cfg->n_levels < 1) return 0;
    for (int l = 0; l < cfg->n_levels - 1; l++) {
        if (s < 2) return 0;
        s /= 2;
    }
    return s < 1 ? 0 : s;
}
