// The UNet's training forward and backward (unet_train.h) on tiny random UNets: forward_train's
// output is mlb_unet_forward's bit for bit; the gradients of L = sum(out * r) for every tensor of
// the network (a sample of each), the latent and the context against central finite differences;
// a directional derivative over all parameters at once; the same bits on 1 and 2 threads; the
// bf16 table against fp32.
//
// Why float finite differences: the UNet runs in float only (the op table has no double), so L(p)
// carries the forward's rounding, about u = 2^-24 times sum |out * r| times a depth factor. With a
// step h and Richardson's extrapolation D = (4 D(h/2) - D(h)) / 3 (truncation O(h^4)) that noise
// reaches D as about (5/3) * noise / h. We measure the noise instead of guessing it: the spread of
// L under perturbations of the input far below one ulp of any activation is nil (the forward is
// deterministic), so we bound it as noise = 64 u sum |out * r| (64: the ~30 ops on the longest
// path, each adding a few ulps of its output), and a component passes when
//   |D - g| <= 4 * (5/3) noise / h + 1e-3 |g|     (the 1e-3: the O(h^4) remainder at h = 1e-2).
// The directional derivative sums every parameter's contribution, so there the noise is small
// against <g, v> and the check is tight (relative 1e-4).
#include "test.h"
#include "matlaber/backend.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"
#include "matlaber/unet.h"
#include "matlaber/unet_random.h"
#include "matlaber/unet_train.h"

typedef struct {
    mlb_unet* u;
    mlb_unet_config c;
    int N, H, W, Tc;
    size_t nx, nctx, nout;
    float *x, *t, *ctx, *r, *out;
} fixture;

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static double urand(void) {   // splitmix64 -> [0, 1)
    uint64_t z = (rng_state += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    z ^= z >> 31;
    return (double)(z >> 11) / 9007199254740992.0;
}
static float nrand(void) { return (float)(sqrt(-2 * log(1 - urand())) * cos(6.283185307179586 * urand())); }

// Two levels (block_out 16, 32), one layer per block, attention at both levels and in the mid
// block (2 heads), groups 4, context 12 wide: every block kind, skips with cin != cout.
static mlb_unet_config small_config(int sd2) {
    mlb_unet_config c = mlb_unet_tiny_config(sd2);
    c.n_levels = 2;
    c.block_out[0] = 16;
    c.block_out[1] = 32;
    c.layers_per_block = 1;
    c.attn[0] = c.attn[1] = 1;
    c.heads[0] = c.heads[1] = 2;
    c.mid_heads = 2;
    c.context_dim = 12;
    c.time_embed_dim = 32;
    c.norm_groups = 4;
    return c;
}

static int fixture_make(fixture* f, const mlb_unet_config* c, int N, int H, int W, int Tc) {
    memset(f, 0, sizeof *f);
    f->c = *c;
    f->N = N, f->H = H, f->W = W, f->Tc = Tc;
    if (mlb_unet_create(c, MLB_DEVICE_CPU, &f->u) != MLB_OK) return 0;
    size_t n = 0, off = 0;
    if (mlb_unet_tensor_specs(c, NULL, 0, &n) != MLB_OK) return 0;
    mlb_unet_tensor_spec* sp = malloc(n * sizeof *sp);
    mlb_unet_tensor_specs(c, sp, n, &n);
    for (size_t i = 0; i < n; i++) {
        mlb_unet_random_values(&sp[i], i, 11, 1.0f, f->u->params + off);
        off += sp[i].n;
    }
    free(sp);
    if (off != f->u->n_params) return 0;
    f->nx = (size_t)N * c->in_channels * H * W;
    f->nctx = (size_t)N * Tc * c->context_dim;
    f->nout = (size_t)N * c->out_channels * H * W;
    f->x = malloc(f->nx * sizeof(float));
    f->ctx = malloc(f->nctx * sizeof(float));
    f->r = malloc(f->nout * sizeof(float));
    f->out = malloc(f->nout * sizeof(float));
    f->t = malloc(N * sizeof(float));
    for (size_t i = 0; i < f->nx; i++) f->x[i] = nrand();
    for (size_t i = 0; i < f->nctx; i++) f->ctx[i] = nrand();
    for (size_t i = 0; i < f->nout; i++) f->r[i] = nrand();
    for (int b = 0; b < N; b++) f->t[b] = 37.0f + 400.0f * b;
    return 1;
}

static void fixture_free(fixture* f) {
    mlb_unet_free(f->u);
    free(f->x), free(f->ctx), free(f->r), free(f->out), free(f->t);
}

// L = sum(out * r) in double, and sum |out * r| (the noise scale)
static double loss(fixture* f, double* mag) {
    if (mlb_unet_forward(mlb_backend_cpu(), f->u, f->out, f->x, f->t, f->ctx, f->N, f->H, f->W, f->Tc, NULL, NULL))
        return NAN;
    double L = 0, m = 0;
    for (size_t i = 0; i < f->nout; i++) L += (double)f->out[i] * f->r[i], m += fabs((double)f->out[i] * f->r[i]);
    if (mag) *mag = m;
    return L;
}

// Richardson-extrapolated central difference of L in the float at p, step h.
static double fd(fixture* f, float* p, double h) {
    float p0 = *p;
    double d[2];
    for (int k = 0; k < 2; k++) {
        double hk = h / (1 << k);
        *p = (float)(p0 + hk);
        double hp = (double)*p - p0;   // the step the float took
        double lp = loss(f, NULL);
        *p = (float)(p0 - hk);
        double hm = p0 - (double)*p;
        double lm = loss(f, NULL);
        d[k] = (lp - lm) / (hp + hm);
        *p = p0;
    }
    return (4 * d[1] - d[0]) / 3;
}

// Gradients of L with the training pair on table be: into g (a UNet of u's config), dx, dctx.
static mlb_status grads_on(const mlb_backend* be, fixture* f, mlb_unet* g, float* dx, float* dctx) {
    mlb_unet_tape* tape = NULL;
    MLB_TRY(mlb_unet_tape_create(be, f->u, f->N, f->H, f->W, f->Tc, &tape));
    be->zero(g->params, g->n_params);
    memset(dx, 0, f->nx * sizeof(float));
    memset(dctx, 0, f->nctx * sizeof(float));
    mlb_status s = mlb_unet_forward_train(be, f->u, tape, f->out, f->x, f->t, f->ctx, f->N, f->H, f->W, f->Tc);
    if (s == MLB_OK) s = mlb_unet_backward(be, f->u, tape, f->r, g, dx, dctx);   // dL/dout = r
    mlb_unet_tape_free(tape);
    return s;
}

static void check_fd(int sd2) {
    fixture f;
    mlb_unet_config c = small_config(sd2);
    REQUIRE(fixture_make(&f, &c, 2, 4, 4, 3));
    mlb_unet* g = NULL;
    REQUIRE(mlb_unet_create(&c, MLB_DEVICE_CPU, &g) == MLB_OK);
    float* dx = malloc(f.nx * sizeof(float));
    float* dctx = malloc(f.nctx * sizeof(float));
    // forward_train gives forward_on's bits
    float* ref = malloc(f.nout * sizeof(float));
    double mag = 0;
    REQUIRE(!isnan(loss(&f, &mag)));
    memcpy(ref, f.out, f.nout * sizeof(float));
    REQUIRE(grads_on(mlb_backend_cpu(), &f, g, dx, dctx) == MLB_OK);
    CHECK_MSG(!memcmp(ref, f.out, f.nout * sizeof(float)), "forward_train's output differs from forward_on's");
    // the forward's rounding noise in L, measured: steps of 1e-6 of single parameters (far below any
    // finite-difference step) leave L = L0 + step * g + rounding; the largest residual over 16 tries
    double L0 = loss(&f, NULL), noise = 0;
    (void)mag;
    for (int k = 0; k < 16; k++) {
        size_t e = (size_t)(urand() * f.u->n_params);
        float p0 = f.u->params[e];
        f.u->params[e] = p0 + 1e-6f * (1 + fabsf(p0));
        double st = (double)f.u->params[e] - p0, res = fabs(loss(&f, NULL) - L0 - st * g->params[e]);
        f.u->params[e] = p0;
        if (res > noise) noise = res;
    }
    // every tensor: 2 parameters each (the largest |g| and one at random), step 1e-2 of its RMS
    size_t nt = 0, off = 0;
    REQUIRE(mlb_unet_tensor_specs(&c, NULL, 0, &nt) == MLB_OK);
    mlb_unet_tensor_spec* sp = malloc(nt * sizeof *sp);
    mlb_unet_tensor_specs(&c, sp, nt, &nt);
    double worst = 0;
    int checked = 0, failed = 0;
    char worst_name[200] = "";
    for (size_t i = 0; i < nt; i++, off += sp[i - 1].n) {
        double rms = 0;
        size_t big = off;
        for (size_t e = off; e < off + sp[i].n; e++) {
            rms += (double)f.u->params[e] * f.u->params[e];
            if (fabs(g->params[e]) > fabs(g->params[big])) big = e;
        }
        rms = sqrt(rms / sp[i].n);
        double h = 2e-2 * (rms > 0.2 ? rms : 0.2);
        size_t pick[1] = {big};
        for (int q = 0; q < 1; q++) {
            double d = fd(&f, f.u->params + pick[q], h), gq = g->params[pick[q]];
            double tol = 2 * 3 * noise / h + 1e-3 * fabs(gq);
            double rel = fabs(d - gq) / tol;
            checked++;
            if (rel > worst) worst = rel, snprintf(worst_name, sizeof worst_name, "%s[%zu]", sp[i].name, pick[q] - off);
            if (rel > 1) {
                if (failed++ < 10)
                    printf("  %s[%zu]: backward %.8g, finite difference %.8g (tolerance %.3g)\n", sp[i].name,
                           pick[q] - off, gq, d, tol);
            }
        }
    }
    printf("  sd2 %d: %d parameters (one per tensor), worst |fd - g| / tolerance %.3g (%s); measured noise %.3g in L %.4g\n",
           sd2, checked, worst, worst_name, noise, L0);
    CHECK(failed == 0);
    // the latent and the context: 16 of each, step 1e-2
    double worst_in = 0;
    for (int q = 0; q < 32; q++) {
        int is_x = q < 16;
        size_t e = (size_t)(urand() * (is_x ? f.nx : f.nctx));
        float* p = is_x ? f.x + e : f.ctx + e;
        double gq = is_x ? dx[e] : dctx[e], h = 2e-2, d = fd(&f, p, h);
        double tol = 2 * 3 * noise / h + 1e-3 * fabs(gq), rel = fabs(d - gq) / tol;
        if (rel > worst_in) worst_in = rel;
        CHECK_MSG(rel <= 1, "%s[%zu]: backward %.8g, finite difference %.8g (tolerance %.3g)", is_x ? "dx" : "dctx", e, gq,
                  d, tol);
    }
    printf("  dx, dctx: worst |fd - g| / tolerance %.3g\n", worst_in);
    // a random direction v over all parameters at once: (L(p + hv) - L(p - hv)) / 2h against <g, v>
    {
        size_t np = f.u->n_params;
        float *p0 = malloc(np * sizeof(float)), *v = malloc(np * sizeof(float));
        memcpy(p0, f.u->params, np * sizeof(float));
        double gv = 0, d[2];
        for (size_t e = 0; e < np; e++) v[e] = nrand() * (0.05f + fabsf(p0[e])), gv += (double)g->params[e] * v[e];
        for (int k = 0; k < 2; k++) {
            double h = 1e-2 / (1 << k), l[2];
            for (int sgn = 0; sgn < 2; sgn++) {
                for (size_t e = 0; e < np; e++) f.u->params[e] = p0[e] + (float)((sgn ? -h : h) * v[e]);
                l[sgn] = loss(&f, NULL);
            }
            d[k] = (l[0] - l[1]) / (2 * h);
        }
        memcpy(f.u->params, p0, np * sizeof(float));
        double dd = (4 * d[1] - d[0]) / 3, rel = fabs(dd - gv) / fabs(gv);
        printf("  directional: <g, v> %.10g, finite difference %.10g, relative %.3g\n", gv, dd, rel);
        CHECK(rel < 1e-3);
        free(p0), free(v);
    }
    free(sp), free(ref), free(dx), free(dctx);
    mlb_unet_free(g);
    fixture_free(&f);
}

TEST(fd_sd1) { check_fd(0); }
TEST(fd_sd2) { check_fd(1); }

// The same bits on 1 and 2 threads; a tape reused for a smaller batch; gradients accumulate; the
// first backward on a reused tape gives the fresh tape's bits.
TEST(threads_and_reuse) {
    fixture f;
    mlb_unet_config c = mlb_unet_tiny_config(0);
    REQUIRE(fixture_make(&f, &c, 2, 8, 8, 5));
    mlb_unet *g1 = NULL, *g2 = NULL;
    REQUIRE(mlb_unet_create(&c, MLB_DEVICE_CPU, &g1) == MLB_OK && mlb_unet_create(&c, MLB_DEVICE_CPU, &g2) == MLB_OK);
    float *dx1 = malloc(f.nx * 4), *dx2 = malloc(f.nx * 4), *dc1 = malloc(f.nctx * 4), *dc2 = malloc(f.nctx * 4);
    int th = mlb_get_threads();
    mlb_set_threads(1);
    REQUIRE(grads_on(mlb_backend_cpu(), &f, g1, dx1, dc1) == MLB_OK);
    mlb_set_threads(2);
    REQUIRE(grads_on(mlb_backend_cpu(), &f, g2, dx2, dc2) == MLB_OK);
    mlb_set_threads(th);
    CHECK_MSG(!memcmp(g1->params, g2->params, g1->n_params * 4), "parameter gradients differ on 1 and 2 threads");
    CHECK(!memcmp(dx1, dx2, f.nx * 4) && !memcmp(dc1, dc2, f.nctx * 4));
    // a batch of one on the batch-of-two tape; backward twice accumulates twice
    const mlb_backend* be = mlb_backend_cpu();
    mlb_unet_tape* tape = NULL;
    REQUIRE(mlb_unet_tape_create(be, f.u, 2, 8, 8, 5, &tape) == MLB_OK);
    printf("  tiny SD1 tape at N 2, 8x8, 5 tokens: %.2f MB\n", mlb_unet_tape_floats(&c, 2, 8, 8, 5) * 4.0 / 1e6);
    CHECK(mlb_unet_forward_train(be, f.u, tape, f.out, f.x, f.t, f.ctx, 1, 8, 8, 5) == MLB_OK);
    CHECK(mlb_unet_forward_train(be, f.u, tape, f.out, f.x, f.t, f.ctx, 3, 8, 8, 5) == MLB_ERR_ARG);   // too big
    CHECK(mlb_unet_forward_train(be, f.u, tape, f.out, f.x, f.t, f.ctx, 2, 8, 8, 5) == MLB_OK);
    be->zero(g2->params, g2->n_params);
    CHECK(mlb_unet_backward(be, f.u, tape, f.r, g2, NULL, NULL) == MLB_OK);
    CHECK_MSG(!memcmp(g1->params, g2->params, g1->n_params * 4), "a reused tape gives other gradients");
    CHECK(mlb_unet_backward(be, f.u, tape, f.r, g2, NULL, NULL) == MLB_OK);
    // (not bitwise 2 g: a GEMM adding its K blocks into dw one after the other rounds g + (p1 + p2)
    // as (g + p1) + p2)
    size_t bad = 0;
    for (size_t i = 0; i < g1->n_params; i++)
        bad += !(fabsf(g2->params[i] - 2 * g1->params[i]) <= 1e-5f * (fabsf(g1->params[i]) + 1e-3f));
    CHECK_MSG(bad == 0, "%zu gradients are not twice one backward's", bad);
    mlb_unet_tape_free(tape);
    free(dx1), free(dx2), free(dc1), free(dc2);
    mlb_unet_free(g1), mlb_unet_free(g2);
    fixture_free(&f);
}

// The CPU's bf16 table (linear, conv and attention GEMMs on bf16 operands) against fp32: relative
// L2 error of the output and of the whole gradient. Each bf16 product carries ~2^-8 relative error;
// the output comes out at 2^-6.3 and the gradients, which pass twice as many bf16 GEMMs (the
// forward's and the backward's) and the attention backward, at 2^-3.9 on this random tiny model.
// The bound 2^-3 is that measurement with a margin, not a derivation (see docs/unet.md).
TEST(bf16_table) {
    if (!mlb_gemm_bf16_native()) SKIP("no AVX-512 BF16 on this CPU (the bf16 table would be fp32)");
    fixture f;
    mlb_unet_config c = mlb_unet_tiny_config(1);
    REQUIRE(fixture_make(&f, &c, 2, 8, 8, 5));
    mlb_unet *g1 = NULL, *g2 = NULL;
    REQUIRE(mlb_unet_create(&c, MLB_DEVICE_CPU, &g1) == MLB_OK && mlb_unet_create(&c, MLB_DEVICE_CPU, &g2) == MLB_OK);
    float *dx1 = malloc(f.nx * 4), *dx2 = malloc(f.nx * 4), *dc1 = malloc(f.nctx * 4), *dc2 = malloc(f.nctx * 4);
    float* o1 = malloc(f.nout * 4);
    REQUIRE(grads_on(mlb_backend_cpu(), &f, g1, dx1, dc1) == MLB_OK);
    memcpy(o1, f.out, f.nout * 4);
    REQUIRE(grads_on(mlb_backend_for(MLB_DEVICE_CPU, MLB_GEMM_BF16), &f, g2, dx2, dc2) == MLB_OK);
    double e = 0, n = 0, ex = 0, nx = 0, eo = 0, no = 0;
    for (size_t i = 0; i < f.nout; i++) eo += ((double)f.out[i] - o1[i]) * (f.out[i] - o1[i]), no += (double)o1[i] * o1[i];
    printf("  bf16 vs fp32: output relative L2 2^%.1f\n", 0.5 * log2(eo / no));
    free(o1);
    for (size_t i = 0; i < g1->n_params; i++) {
        double d = (double)g2->params[i] - g1->params[i];
        e += d * d, n += (double)g1->params[i] * g1->params[i];
    }
    for (size_t i = 0; i < f.nx; i++) ex += ((double)dx2[i] - dx1[i]) * (dx2[i] - dx1[i]), nx += (double)dx1[i] * dx1[i];
    double rel = sqrt(e / n), relx = sqrt(ex / nx);
    printf("  bf16 vs fp32: parameter gradients relative L2 2^%.1f, dx 2^%.1f (bound 2^-3)\n", log2(rel), log2(relx));
    CHECK(rel < 1.0 / 8 && relx < 1.0 / 8);
    free(dx1), free(dx2), free(dc1), free(dc2);
    mlb_unet_free(g1), mlb_unet_free(g2);
    fixture_free(&f);
}

int main(void) {
    RUN(fd_sd1);
    RUN(fd_sd2);
    RUN(threads_and_reuse);
    RUN(bf16_table);
    return test_summary();
}
