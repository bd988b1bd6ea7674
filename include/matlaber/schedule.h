// The Stable Diffusion noise schedule and the DDIM sampler's arithmetic (reference.md §6-7,
// docs/unet.md): DDPM alphas_cumprod (float64, and diffusers' float32 values), DDIM timesteps
// ("leading" spacing with steps_offset), the deterministic DDIM update (eta 0), classifier-free
// guidance, add_noise and the v-prediction conversions. Plain functions over buffers; no state.
#ifndef MATLABER_SCHEDULE_H
#define MATLABER_SCHEDULE_H
#include <stddef.h>
#include "matlaber/error.h"

#define MLB_SD_TRAIN_STEPS 1000
#define MLB_SD_BETA_START 0.00085
#define MLB_SD_BETA_END 0.012

// "scaled_linear" (diffusers) = "linear" (ldm): betas[i] = linspace(sqrt(beta_start), sqrt(beta_end),
// n)[i]^2 and ac[i] = prod_{j<=i} (1 - betas[j]), all in float64. betas may be NULL.
// MLB_ERR_ARG for n < 2 or betas outside (0, 1).
mlb_status mlb_schedule_alphas_cumprod(double* ac, double* betas, int n, double beta_start, double beta_end);
// The same as diffusers' schedulers compute it: float32 torch.linspace (start + i*step for the first
// half, end - (n-1-i)*step for the second), squared, 1 - b and a sequential float32 cumprod.
// These are the values the DDIM/SDS references use (they differ from float64 by ~1e-7 relative).
mlb_status mlb_schedule_alphas_cumprod_f32(float* ac, int n, double beta_start, double beta_end);

// DDIM timesteps, "leading" spacing: ratio = n_train / n_steps (integer division),
// ts[i] = (n_steps - 1 - i) * ratio + steps_offset for i = 0..n_steps-1 (descending;
// SD: n_train 1000, offset 1; 4 steps -> 751, 501, 251, 1). MLB_ERR_ARG when n_steps is outside
// [1, n_train] or the offset puts a timestep outside [0, n_train).
mlb_status mlb_ddim_timesteps(int* ts, int n_steps, int n_train, int steps_offset);
// The timestep a DDIM step from t lands on: t - n_train / n_steps (may be negative: the last step).
int mlb_ddim_prev_timestep(int t, int n_steps, int n_train);
// alphas_cumprod at a previous timestep: ac[t_prev] when t_prev >= 0, else the "final alpha":
// 1 when set_alpha_to_one, else ac[0] (SD's scheduler config: set_alpha_to_one False).
double mlb_ddim_alpha_prev(const double* ac, int t_prev, int set_alpha_to_one);

// One deterministic DDIM step (eta 0), elementwise over n values; x_prev may alias x:
//   x0     = (x - sqrt(1 - ac_t) * eps) / sqrt(ac_t)
//   x_prev = sqrt(ac_prev) * x0 + sqrt(1 - ac_prev) * eps
// The coefficients are rounded to float first and the arithmetic is float, as diffusers does it.
// x0 (may be NULL) receives the predicted clean sample. MLB_ERR_ARG unless 0 < ac_t, ac_prev <= 1.
mlb_status mlb_ddim_step(float* x_prev, float* x0, const float* x, const float* eps, size_t n, double ac_t,
                         double ac_prev);

// Classifier-free guidance: out = uncond + scale * (cond - uncond), elementwise (out may alias either).
void mlb_cfg_combine(float* out, const float* eps_uncond, const float* eps_cond, size_t n, float scale);
// add_noise: x_t = sqrt(ac_t) * x0 + sqrt(1 - ac_t) * noise (x_t may alias x0 or noise).
void mlb_add_noise(float* x_t, const float* x0, const float* noise, size_t n, double ac_t);
// v-prediction (SD 2.x 768): eps = sqrt(ac_t) * v + sqrt(1 - ac_t) * x_t (eps may alias v or x_t);
// x0 = sqrt(ac_t) * x_t - sqrt(1 - ac_t) * v.
void mlb_v_to_eps(float* eps, const float* v, const float* x_t, size_t n, double ac_t);
void mlb_v_to_x0(float* x0, const float* v, const float* x_t, size_t n, double ac_t);

#endif
