// Noise schedule, DDIM timesteps and update, guidance and v-prediction (see schedule.h).
#include "matlaber/schedule.h"
#include <math.h>

static mlb_status check_betas(int n, double beta_start, double beta_end) {
    if (n < 2) return mlb_fail(MLB_ERR_ARG, "noise schedule: %d training steps (need at least 2)", n);
    if (!(beta_start > 0 && beta_start < 1 && beta_end > 0 && beta_end < 1))
        return mlb_fail(MLB_ERR_ARG, "noise schedule: betas %g..%g must lie in (0, 1)", beta_start, beta_end);
    return MLB_OK;
}

mlb_status mlb_schedule_alphas_cumprod(double* ac, double* betas, int n, double beta_start, double beta_end) {
    if (!ac) return mlb_fail(MLB_ERR_ARG, "noise schedule: NULL output");
    MLB_TRY(check_betas(n, beta_start, beta_end));
    // torch.linspace in float64 (ldm's register_schedule): start + i*step for the first half,
    // end - (n-1-i)*step for the second.
    double s0 = sqrt(beta_start), s1 = sqrt(beta_end), prod = 1.0;
    double step = (s1 - s0) / (double)(n - 1);
    int half = n / 2;
    for (int i = 0; i < n; i++) {
        double s = i < half ? s0 + step * (double)i : s1 - step * (double)(n - 1 - i);
        double b = s * s;
        if (betas) betas[i] = b;
        prod *= 1.0 - b;
        ac[i] = prod;
    }
    return MLB_OK;
}

mlb_status mlb_schedule_alphas_cumprod_f32(float* ac, int n, double beta_start, double beta_end) {
    if (!ac) return mlb_fail(MLB_ERR_ARG, "noise schedule: NULL output");
    MLB_TRY(check_betas(n, beta_start, beta_end));
    // torch's CPU linspace kernel for float: step = (end - start) / (n - 1) in float, the first half
    // counted up from start, the second half down from end.
    float s0 = (float)sqrt(beta_start), s1 = (float)sqrt(beta_end);
    float step = (s1 - s0) / (float)(n - 1);
    int half = n / 2;
    float prod = 1.0f;
    for (int i = 0; i < n; i++) {
        float s = i < half ? s0 + step * (float)i : s1 - step * (float)(n - 1 - i);
        float b = s * s;
        prod = prod * (1.0f - b);
        ac[i] = prod;
    }
    return MLB_OK;
}

mlb_status mlb_ddim_timesteps(int* ts, int n_steps, int n_train, int steps_offset) {
    if (!ts) return mlb_fail(MLB_ERR_ARG, "DDIM timesteps: NULL output");
    if (n_train < 1 || n_steps < 1 || n_steps > n_train)
        return mlb_fail(MLB_ERR_ARG, "DDIM timesteps: %d steps must lie in [1, %d] (the training steps)", n_steps,
                        n_train);
    int ratio = n_train / n_steps;
    if (steps_offset < 0 || (n_steps - 1) * ratio + steps_offset >= n_train)
        return mlb_fail(MLB_ERR_ARG, "DDIM timesteps: steps_offset %d puts the first of %d steps past %d", steps_offset,
                        n_steps, n_train - 1);
    for (int i = 0; i < n_steps; i++) ts[i] = (n_steps - 1 - i) * ratio + steps_offset;
    return MLB_OK;
}

int mlb_ddim_prev_timestep(int t, int n_steps, int n_train) {
    return t - (n_steps > 0 ? n_train / n_steps : 0);
}

double mlb_ddim_alpha_prev(const double* ac, int t_prev, int set_alpha_to_one) {
    if (t_prev >= 0) return ac[t_prev];
    return set_alpha_to_one ? 1.0 : ac[0];
}

mlb_status mlb_ddim_step(float* x_prev, float* x0, const float* x, const float* eps, size_t n, double ac_t,
                         double ac_prev) {
    if (!(ac_t > 0 && ac_t <= 1 && ac_prev > 0 && ac_prev <= 1))
        return mlb_fail(MLB_ERR_ARG, "DDIM step: alphas_cumprod %g -> %g must lie in (0, 1]", ac_t, ac_prev);
    float a = (float)ac_t, ap = (float)ac_prev;
    float sqrt_b = sqrtf(1.0f - a), sqrt_a = sqrtf(a);
    float sqrt_ap = sqrtf(ap), sqrt_bp = sqrtf(1.0f - ap);
    for (size_t i = 0; i < n; i++) {
        float e = eps[i];
        float p0 = (x[i] - sqrt_b * e) / sqrt_a;
        if (x0) x0[i] = p0;
        x_prev[i] = sqrt_ap * p0 + sqrt_bp * e;
    }
    return MLB_OK;
}

void mlb_cfg_combine(float* out, const float* eps_uncond, const float* eps_cond, size_t n, float scale) {
    for (size_t i = 0; i < n; i++) {
        float u = eps_uncond[i];
        out[i] = u + scale * (eps_cond[i] - u);
    }
}

void mlb_add_noise(float* x_t, const float* x0, const float* noise, size_t n, double ac_t) {
    float sa = (float)sqrt(ac_t), sb = (float)sqrt(1.0 - ac_t);
    for (size_t i = 0; i < n; i++) x_t[i] = sa * x0[i] + sb * noise[i];
}

void mlb_v_to_eps(float* eps, const float* v, const float* x_t, size_t n, double ac_t) {
    float sa = (float)sqrt(ac_t), sb = (float)sqrt(1.0 - ac_t);
    for (size_t i = 0; i < n; i++) eps[i] = sa * v[i] + sb * x_t[i];
}

void mlb_v_to_x0(float* x0, const float* v, const float* x_t, size_t n, double ac_t) {
    float sa = (float)sqrt(ac_t), sb = (float)sqrt(1.0 - ac_t);
    for (size_t i = 0; i < n; i++) x0[i] = sa * x_t[i] - sb * v[i];
}
