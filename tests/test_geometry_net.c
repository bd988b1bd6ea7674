// The geometry network (hash grid → MLP → sdf + deform): finite differences (double) of the whole
// chain network → deformation → marching tets; analytic SDFs; the generalised winding number
// (closed meshes, a mesh with a hole); the mesh SDF; the 400-step ellipsoid and mesh inits measured
// by the Chamfer distance of the extracted surface; save/load.
#include <stdint.h>
#include "matlaber/geometry.h"
#include "matlaber/obj.h"
#include "matlaber/rng.h"
#include "test.h"

static mlb_geometry_config small_config(void) {
    mlb_geometry_config c = mlb_geometry_default();
    c.enc = (mlb_hashgrid_config){4, 2, 256, 3, 1.7};   // levels 0, 1 dense, 2, 3 hashed
    c.hidden = 8;
    c.n_hidden = 2;
    c.seed = 7;
    return c;
}

// Loss of the whole chain: L = Σ_v c_v · v over marching-tets vertices of the deformed grid.
static double chain_loss(mlb_geometry_net_f64* net, const mlb_tetgrid* g, const double* verts, const double* coef,
                         int n_coef, int* n_out, double* dparams_out) {
    int V = g->n_verts;
    double* sdf = malloc(sizeof(double) * V);
    double* deform = malloc(sizeof(double) * 3 * V);
    double* pos = malloc(sizeof(double) * 3 * V);
    geometry_net_forward_f64(net, sdf, deform, verts, V);
    dmtet_deform_forward_f64(pos, verts, deform, V, 2.0 * g->cells);
    mlb_mt_surface_f64 s;
    marching_tets_forward_f64(&s, g, pos, sdf);
    double L = 0;
    for (int i = 0; i < 3 * s.n_verts && i < n_coef; i++) L += coef[i] * s.pos[i];
    *n_out = s.n_verts;
    if (dparams_out) {
        double* dv = calloc(3 * (size_t)s.n_verts, sizeof(double));
        for (int i = 0; i < 3 * s.n_verts && i < n_coef; i++) dv[i] = coef[i];
        double* dpos = calloc(3 * (size_t)V, sizeof(double));
        double* dsdf = calloc(V, sizeof(double));
        double* ddef = calloc(3 * (size_t)V, sizeof(double));
        marching_tets_backward_f64(dpos, dsdf, &s, pos, sdf, dv);
        dmtet_deform_backward_f64(NULL, ddef, dpos, deform, V, 2.0 * g->cells);
        geometry_net_backward_f64(net, dsdf, ddef);
        free(dv); free(dpos); free(dsdf); free(ddef);
    }
    mt_surface_free_f64(&s);
    free(sdf); free(deform); free(pos);
    return L;
}

TEST(fd_whole_chain_f64) {
    mlb_geometry_config c = small_config();
    mlb_geometry_net_f64 net;
    REQUIRE(geometry_net_init_f64(&net, &c) == MLB_OK);
    mlb_tetgrid g;
    REQUIRE(mlb_tetgrid_create(&g, 5, c.scale) == MLB_OK);
    int V = g.n_verts;
    double* verts = malloc(sizeof(double) * 3 * V);
    double* sdf = malloc(sizeof(double) * V);
    double* target = malloc(sizeof(double) * V);
    double* dsdf = malloc(sizeof(double) * V);
    for (int i = 0; i < 3 * V; i++) verts[i] = g.verts[i];
    for (int i = 0; i < V; i++) {
        const double* p = verts + 3 * i;
        target[i] = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) - 0.6;
    }
    // a few Adam steps towards a sphere so that marching tets finds a well-conditioned surface
    mlb_adam_config adam = mlb_geometry_adam(2e-2);
    double first = 0, last = 0;
    for (int it = 0; it < 150; it++) {
        REQUIRE(geometry_net_forward_f64(&net, sdf, NULL, verts, V) == MLB_OK);
        double loss = mse_forward_f64(sdf, target, V);
        if (it == 0) first = loss;
        last = loss;
        memset(dsdf, 0, sizeof(double) * V);
        mse_backward_f64(dsdf, sdf, target, V, 1.0);
        geometry_net_zero_grad_f64(&net);
        geometry_net_backward_f64(&net, dsdf, NULL);
        geometry_net_update_f64(&net, &adam);
    }
    CHECK_MSG(last < 0.1 * first, "pre-fit mse %g -> %g", first, last);
    // analytic gradient of the chain
    int nc = 3 * 4000, n_surf = 0, n2 = 0;
    double* coef = malloc(sizeof(double) * nc);
    for (int i = 0; i < nc; i++) coef[i] = 2 * mlb_rng_uniform_f64(3, 1, i) - 1;
    geometry_net_zero_grad_f64(&net);
    chain_loss(&net, &g, verts, coef, nc, &n_surf, (double*)1);
    CHECK(n_surf > 20);
    double* analytic = malloc(sizeof(double) * net.n_params);
    memcpy(analytic, net.grads, sizeof(double) * net.n_params);
    // accumulation: a second backward doubles the gradient
    chain_loss(&net, &g, verts, coef, nc, &n_surf, (double*)1);
    double acc_err = 0;
    for (size_t i = 0; i < net.n_params; i++) acc_err = fmax(acc_err, fabs(net.grads[i] - 2 * analytic[i]));
    CHECK_MSG(acc_err < 1e-12, "accumulate error %g", acc_err);
    double max_err = 0, max_g = 0;
    int bad = 0, nonzero_enc = 0, nonzero_mlp = 0;
    for (size_t i = 0; i < net.n_params; i++) {
        double h = 1e-6, keep = net.params[i];
        net.params[i] = keep + h;
        double lp = chain_loss(&net, &g, verts, coef, nc, &n2, NULL);
        int same = n2 == n_surf;
        net.params[i] = keep - h;
        double lm = chain_loss(&net, &g, verts, coef, nc, &n2, NULL);
        same &= n2 == n_surf;
        net.params[i] = keep;
        if (!same) continue;   // the perturbation changed the topology: not differentiable there
        double fd = (lp - lm) / (2 * h);
        double err = fabs(fd - analytic[i]);
        if (err > 1e-6 + 1e-5 * fabs(fd)) { if (bad++ < 5) printf("  param %zu: analytic %.10g fd %.10g\n", i, analytic[i], fd); }
        max_err = fmax(max_err, err);
        max_g = fmax(max_g, fabs(fd));
        if (fabs(fd) > 1e-8) { if (i < net.n_enc) nonzero_enc++; else nonzero_mlp++; }
    }
    printf("  chain FD: %zu params (%d table, %d MLP with nonzero gradient), max |err| %.3g, max |g| %.3g, %d surface verts\n",
           net.n_params, nonzero_enc, nonzero_mlp, max_err, max_g, n_surf);
    CHECK(bad == 0);
    CHECK(nonzero_enc > 50 && nonzero_mlp > 50);
    free(coef); free(analytic); free(verts); free(sdf); free(target); free(dsdf);
    mlb_tetgrid_free(&g);
    geometry_net_free_f64(&net);
}

// Coarse-to-fine (active_levels): the masked levels change nothing and get no gradient; the active
// ones keep their exact gradient (central differences, double).
TEST(coarse_to_fine_levels) {
    mlb_geometry_config c = small_config();
    mlb_geometry_net_f64 net;
    REQUIRE(geometry_net_init_f64(&net, &c) == MLB_OK);
    const int n = 64;
    double pos[3 * 64], sdf[64], sdf2[64], dsdf[64];
    for (int i = 0; i < 3 * n; i++) pos[i] = (mlb_rng_uniform_f64(5, 0, i) - 0.5) * c.scale;
    for (int i = 0; i < n; i++) dsdf[i] = mlb_rng_uniform_f64(5, 1, i) - 0.5;
    // table values of order 0.1 (the initialisation's 1e-4 would make a 1e-6 step cross ReLU kinks)
    for (size_t i = 0; i < net.n_enc; i++) net.params[i] = 0.2 * (mlb_rng_uniform_f64(5, 2, i) - 0.5);
    net.active_levels = 2;
    const size_t F = (size_t)c.enc.n_features, fine = net.enc.offset[2] * F;   // first value of level 2
    REQUIRE(geometry_net_forward_f64(&net, sdf, NULL, pos, n) == MLB_OK);
    for (size_t i = fine; i < net.n_enc; i++) net.params[i] += 0.5;   // the masked levels' table
    REQUIRE(geometry_net_forward_f64(&net, sdf2, NULL, pos, n) == MLB_OK);
    CHECK(!memcmp(sdf, sdf2, sizeof sdf));
    geometry_net_zero_grad_f64(&net);
    geometry_net_backward_f64(&net, dsdf, NULL);
    double masked = 0, active = 0;
    for (size_t i = 0; i < net.n_enc; i++) {
        if (i < fine) active += fabs(net.grads[i]);
        else masked += fabs(net.grads[i]);
    }
    CHECK(masked == 0 && active > 0);
    int checked = 0, bad = 0;
    for (size_t i = 0; i < fine && checked < 40; i += 7) {
        if (net.grads[i] == 0) continue;
        double h = 1e-6, keep = net.params[i], lp = 0, lm = 0;
        net.params[i] = keep + h;
        geometry_net_forward_f64(&net, sdf2, NULL, pos, n);
        for (int k = 0; k < n; k++) lp += dsdf[k] * sdf2[k];
        net.params[i] = keep - h;
        geometry_net_forward_f64(&net, sdf2, NULL, pos, n);
        for (int k = 0; k < n; k++) lm += dsdf[k] * sdf2[k];
        net.params[i] = keep;
        double fd = (lp - lm) / (2 * h);
        if (fabs(fd - net.grads[i]) > 1e-7 + 1e-6 * fabs(fd) && bad++ < 3)
            printf("  value %zu: analytic %.10g fd %.10g\n", i, net.grads[i], fd);
        checked++;
    }
    printf("  coarse-to-fine: 2 of 4 levels active, %d active table values checked by central differences\n", checked);
    CHECK(checked >= 10 && bad == 0);
    net.active_levels = 0;   // all levels again: the perturbed fine table now shows
    REQUIRE(geometry_net_forward_f64(&net, sdf2, NULL, pos, n) == MLB_OK);
    CHECK(memcmp(sdf, sdf2, sizeof sdf) != 0);
    geometry_net_free_f64(&net);
}

TEST(float_matches_double) {
    mlb_geometry_config c = small_config();
    mlb_geometry_net f;
    mlb_geometry_net_f64 d;
    REQUIRE(geometry_net_init(&f, &c) == MLB_OK && geometry_net_init_f64(&d, &c) == MLB_OK);
    for (size_t i = 0; i < f.n_params; i++) d.params[i] = f.params[i];
    float p[30], sf[10], df[30];
    double pd[30], sd[10], dd[30];
    for (int i = 0; i < 30; i++) pd[i] = p[i] = 2.1f * (mlb_rng_uniform(5, 0, i) - 0.5f);
    REQUIRE(geometry_net_forward(&f, sf, df, p, 10) == MLB_OK && geometry_net_forward_f64(&d, sd, dd, pd, 10) == MLB_OK);
    for (int i = 0; i < 10; i++) CHECK_CLOSE(sf[i], sd[i], 1e-4, 1e-9);
    for (int i = 0; i < 30; i++) CHECK_CLOSE(df[i], dd[i], 1e-4, 1e-9);
    geometry_net_free(&f);
    geometry_net_free_f64(&d);
}

TEST(analytic_sdfs) {
    mlb_shape s;
    mlb_shape_ellipsoid(&s, 0.8f, NULL);   // a sphere: exact distance
    float p[12] = {0, 0, 0, 1, 0, 0, 0.3f, 0.4f, 0, 0, 0, -2}, d[4];
    mlb_shape_sdf(&s, p, d, 4);
    CHECK_CLOSE(d[0], -0.8, 0, 1e-6);
    CHECK_CLOSE(d[1], 0.2, 0, 1e-6);
    CHECK_CLOSE(d[2], -0.3, 0, 1e-6);
    CHECK_CLOSE(d[3], 1.2, 0, 1e-6);
    float ax[3] = {1, 0.5f, 0.25f};
    mlb_shape_ellipsoid(&s, 1.0f, ax);
    float q[3 * 256], e[256];
    mlb_shape_surface_samples(&s, q, 256, 1, 2);
    mlb_shape_sdf(&s, q, e, 256);
    double worst = 0;
    for (int i = 0; i < 256; i++) worst = fmax(worst, fabs(e[i]));
    CHECK_MSG(worst < 1e-5, "ellipsoid sdf on its surface up to %g", worst);
    float axis_pts[6] = {1.5f, 0, 0, 0, 0, 0.1f};   // on the long axis 0.5 outside; 0.15 inside along z
    mlb_shape_sdf(&s, axis_pts, e, 2);
    CHECK_CLOSE(e[0], 0.5, 0, 1e-6);
    CHECK_CLOSE(e[1], -0.15, 0, 1e-6);
    mlb_shape_cylinder(&s, 1.0f);   // r 0.75, y ∈ [−0.4, 0.4]
    float cp[15] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1.05f, 0.8f, 0, 0.7f, 0.35f, 0};
    mlb_shape_sdf(&s, cp, e, 5);
    CHECK_CLOSE(e[0], -0.4, 0, 1e-6);
    CHECK_CLOSE(e[1], 0.25, 0, 1e-6);
    CHECK_CLOSE(e[2], 0.6, 0, 1e-6);
    CHECK_CLOSE(e[3], 0.5, 0, 1e-6);   // corner: (0.3, 0.4) → 0.5
    CHECK_CLOSE(e[4], -0.05, 0, 1e-6);
    mlb_shape_surface_samples(&s, q, 256, 1, 2);
    mlb_shape_sdf(&s, q, e, 256);
    worst = 0;
    for (int i = 0; i < 256; i++) worst = fmax(worst, fabs(e[i]));
    CHECK_MSG(worst < 1e-5, "cylinder sdf on its surface up to %g", worst);
    mlb_shape_torus(&s, 0.9f / 0.8f);   // major 0.6, minor 0.3, in the xy plane: the hole along z
    float tp[12] = {0, 0, 0, 0.6f, 0, 0, 0, 1.0f, 0, 0, 0.6f, 0.5f};
    mlb_shape_sdf(&s, tp, e, 4);
    CHECK_CLOSE(e[0], 0.3, 0, 1e-6);    // the centre of the hole is outside
    CHECK_CLOSE(e[1], -0.3, 0, 1e-6);   // the middle of the tube
    CHECK_CLOSE(e[2], 0.1, 0, 1e-6);
    CHECK_CLOSE(e[3], 0.2, 0, 1e-6);    // in front of the tube's top
    mlb_shape_surface_samples(&s, q, 256, 1, 2);
    mlb_shape_sdf(&s, q, e, 256);
    worst = 0;
    double mean_z2 = 0;
    for (int i = 0; i < 256; i++) worst = fmax(worst, fabs(e[i])), mean_z2 += (double)q[3 * i + 2] * q[3 * i + 2] / 256;
    CHECK_MSG(worst < 1e-5, "torus sdf on its surface up to %g", worst);
    CHECK_MSG(mean_z2 > 0.2 * 0.09 && mean_z2 < 0.8 * 0.09, "torus samples cover the tube (mean z² %g of r² 0.09)", mean_z2);
}

static void cube_mesh(mlb_mesh* m, int drop_top);

// The slab (a box): its analytic SDF against the distance and winding number of the same box as a
// mesh, at points inside, outside and near the edges; samples on its surface, spread by face area.
TEST(shape_slab) {
    mlb_shape s, ms;
    CHECK(mlb_shape_builtin(&s, "slab", 1.0f) == 1 && s.kind == MLB_SHAPE_BOX);
    const float *h = s.box_half, *ctr = s.box_center;
    double top = (double)ctr[1] + h[1];   // the box (±0.9, ±0.4, ±0.55)·k around it: corners at 0.8
    CHECK_CLOSE(sqrt((double)h[0] * h[0] + top * top + (double)h[2] * h[2]), 0.8, 0, 1e-6);
    CHECK_CLOSE(h[0] / h[2], 0.9 / 0.55, 0, 1e-6);
    CHECK_CLOSE(ctr[1] / h[1], 0.325 / 0.075, 0, 1e-5);   // high: y 0.25..0.4 of 0.4
    CHECK(ctr[0] == 0 && ctr[2] == 0);
    mlb_mesh box;
    cube_mesh(&box, 0);
    for (int i = 0; i < box.n_verts; i++)
        for (int k = 0; k < 3; k++) box.pos[3 * i + k] *= h[k];
    float r = sqrtf(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]);
    REQUIRE(mlb_shape_from_mesh(&ms, &box, r) == MLB_OK);   // normalised to its own radius: the same box, centred
    enum { N = 400 };
    static float p[3 * N], pc[3 * N], a[N], b[N];
    for (int i = 0; i < 3 * N; i++) {   // around the slab: x, z in ±1.2, y within 0.1 of its centre
        p[i] = (float)(mlb_rng_uniform_f64(5, 1, (uint64_t)i) * 2.4 - 1.2) * (i % 3 == 1 ? 0.1f : 1.0f) + ctr[i % 3];
        pc[i] = p[i] - ctr[i % 3];
    }
    mlb_shape_sdf(&s, p, a, N);
    mlb_shape_sdf(&ms, pc, b, N);
    double worst = 0;
    int inside = 0;
    for (int i = 0; i < N; i++) worst = fmax(worst, fabs((double)a[i] - b[i])), inside += a[i] < 0;
    CHECK_MSG(worst < 1e-5, "slab sdf vs the box mesh's: up to %g", worst);
    CHECK_MSG(inside > 10 && inside < N - 10, "both signs drawn (%d inside of %d)", inside, N);
    float c[6] = {ctr[0], ctr[1], ctr[2], 0, 0, 0};
    mlb_shape_sdf(&s, c, a, 2);
    CHECK_CLOSE(a[0], -h[1], 0, 1e-7);                   // its centre: the thickness's half to top and bottom
    CHECK_CLOSE(a[1], (double)ctr[1] - h[1], 0, 1e-7);   // the origin: below its underside
    // surface samples: on the surface, and on the top/bottom faces by their share of the area
    enum { M = 4096 };
    static float q[3 * M], e[M];
    mlb_shape_surface_samples(&s, q, M, 1, 2);
    mlb_shape_sdf(&s, q, e, M);
    worst = 0;
    int tops = 0;
    for (int i = 0; i < M; i++) worst = fmax(worst, fabs(e[i])), tops += fabsf(q[3 * i + 1] - ctr[1]) > h[1] - 1e-6f;
    double share = (double)h[0] * h[2] / ((double)h[1] * h[2] + (double)h[0] * h[2] + (double)h[0] * h[1]);
    double sd = sqrt(share * (1 - share) / M);
    CHECK_MSG(worst < 1e-6, "slab sdf on its surface up to %g", worst);
    CHECK_MSG(fabs((double)tops / M - share) < 5 * sd, "top and bottom hold %.4f of the samples, their area %.4f", (double)tops / M, share);
    CHECK(mlb_shape_builtin(&s, "slab.obj", 1.0f) == 0);   // a file name is no built-in
    mlb_shape_free(&ms);
    mlb_mesh_free(&box);
}

// The cup (an open hemispherical shell): its SDF at points worked by hand; against the distance to
// 60000 of its surface samples at random points (never more than that distance, and within the
// samples' spacing of it: the samples cover the surface), with the sign of an inside test written
// here; the samples on the surface, spread over the outer and inner hemispheres by area.
TEST(shape_cup) {
    mlb_shape s;
    CHECK(mlb_shape_builtin(&s, "cup", 1.0f) == 1 && s.kind == MLB_SHAPE_CUP);
    const double r = s.cup_radius, t = s.cup_wall, c = s.cup_center_y;
    CHECK_CLOSE(sqrt((r + t) * (r + t) + (c + t) * (c + t)), 0.8, 0, 1e-6);   // the rim's outer corner at 0.8
    CHECK_CLOSE(c - (r + t), -(c + t), 0, 1e-6);                              // centred in y: -0.4..0.4
    float h[15] = {0, (float)c, 0,   0, (float)(c - r), 0,   (float)r, (float)(c + 0.3), 0,
                   0, (float)(c + 0.1), 0,   (float)(r + 0.5), (float)(c - 0.2), 0};
    float e[5];
    mlb_shape_sdf(&s, h, e, 5);
    CHECK_CLOSE(e[0], r - t, 0, 1e-6);    // the sphere's centre: in the open cavity
    CHECK_CLOSE(e[1], -t, 0, 1e-6);       // the middle of the wall at the bottom
    CHECK_CLOSE(e[2], 0.3 - t, 0, 1e-6);  // above the rim
    CHECK_CLOSE(e[3], sqrt(r * r + 0.01) - t, 0, 1e-6);   // above the cut: the rim is nearest
    CHECK_CLOSE(e[4], sqrt((r + 0.5) * (r + 0.5) + 0.04) - r - t, 0, 1e-6);   // outside, beside the wall
    enum { M = 60000, N = 300 };
    static float q[3 * M], sd[M], p[3 * N], a[N];
    mlb_shape_surface_samples(&s, q, M, 1, 2);
    mlb_shape_sdf(&s, q, sd, M);
    double worst = 0;
    int outer = 0, inner = 0;
    for (int i = 0; i < M; i++) {
        worst = fmax(worst, fabs(sd[i]));
        double dy = q[3 * i + 1] - c, R = sqrt((double)q[3 * i] * q[3 * i] + dy * dy + (double)q[3 * i + 2] * q[3 * i + 2]);
        if (dy < -1e-6) outer += R > r, inner += R < r;
    }
    CHECK_MSG(worst < 1e-5, "cup sdf on its surface up to %g", worst);
    double total = 2 * M_PI * ((r + t) * (r + t) + (r - t) * (r - t)) + 2 * M_PI * M_PI * r * t;
    double share_out = 2 * M_PI * (r + t) * (r + t) / total, share_in = 2 * M_PI * (r - t) * (r - t) / total;
    CHECK_MSG(fabs((double)outer / M - share_out) < 5 * sqrt(share_out * (1 - share_out) / M), "outer %.4f of the samples, its area %.4f",
              (double)outer / M, share_out);
    CHECK_MSG(fabs((double)inner / M - share_in) < 5 * sqrt(share_in * (1 - share_in) / M), "inner %.4f of the samples, its area %.4f",
              (double)inner / M, share_in);
    for (int i = 0; i < 3 * N; i++) p[i] = (float)(mlb_rng_uniform_f64(6, 1, (uint64_t)i) * 2 - 1);
    mlb_shape_sdf(&s, p, a, N);
    double over = 0, gap = 0;
    int inside = 0, sign_wrong = 0;
    for (int i = 0; i < N; i++) {
        const float* x = p + 3 * i;
        double best = INFINITY;
        for (int j = 0; j < M; j++) {
            double dx = x[0] - q[3 * j], dy = x[1] - q[3 * j + 1], dz = x[2] - q[3 * j + 2];
            best = fmin(best, dx * dx + dy * dy + dz * dz);
        }
        best = sqrt(best);
        over = fmax(over, fabs(a[i]) - best);
        gap = fmax(gap, best - fabs(a[i]));
        double rad = sqrt((double)x[0] * x[0] + (double)x[2] * x[2]), y = x[1] - c, R = sqrt(rad * rad + y * y);
        int in = (y <= 0 && fabs(R - r) < t) || (y > 0 && (rad - r) * (rad - r) + y * y < t * t);
        inside += in;
        sign_wrong += in != (a[i] < 0);
    }
    CHECK_MSG(over < 1e-5, "the sdf exceeds the distance to a surface point by %g", over);
    CHECK_MSG(gap < 0.02, "a surface point nearer than the samples by up to %g (they miss part of it)", gap);
    CHECK_MSG(sign_wrong == 0 && inside > 5, "%d signs wrong (%d points inside)", sign_wrong, inside);
}

static void cube_mesh(mlb_mesh* m, int drop_top) {
    static const float v[24] = {-1, -1, -1, 1, -1, -1, 1, 1, -1, -1, 1, -1, -1, -1, 1, 1, -1, 1, 1, 1, 1, -1, 1, 1};
    static const int32_t f[36] = {0, 3, 2, 0, 2, 1, 4, 5, 6, 4, 6, 7, 0, 1, 5, 0, 5, 4,
                                  3, 7, 6, 3, 6, 2, 0, 4, 7, 0, 7, 3, 1, 2, 6, 1, 6, 5};   // CCW from outside; faces 9,10 = +y
    memset(m, 0, sizeof *m);
    m->n_verts = 8;
    m->pos = malloc(sizeof v);
    memcpy(m->pos, v, sizeof v);
    m->faces = malloc(sizeof f);
    int n = 0;
    for (int t = 0; t < 12; t++) {
        if (drop_top && (t == 6 || t == 7)) continue;
        memcpy(m->faces + 3 * n++, f + 3 * t, sizeof(int32_t) * 3);
    }
    m->n_faces = n;
}

TEST(winding_number) {
    mlb_mesh cube;
    cube_mesh(&cube, 0);
    float p[18] = {0, 0, 0, 0.9f, -0.9f, 0.5f, 0.3f, 0.99f, 0, 2, 0, 0, 0, 1.01f, 0, 5, 5, 5};
    double w[6];
    mlb_mesh_winding_number(&cube, p, w, 6);
    for (int i = 0; i < 3; i++) CHECK_CLOSE(w[i], 1.0, 0, 1e-9);
    for (int i = 3; i < 6; i++) CHECK_CLOSE(w[i], 0.0, 0, 1e-9);
    // open at the top (+y): the centre still reads 5/6, points inside near the hole stay > 0.5
    // away from its plane, outside points stay < 0.5
    mlb_mesh open;
    cube_mesh(&open, 1);
    CHECK(open.n_faces == 10);
    mlb_mesh_winding_number(&open, p, w, 6);
    CHECK_CLOSE(w[0], 5.0 / 6.0, 0, 1e-9);
    CHECK(w[1] > 0.9);
    CHECK(w[3] < 0.2 && w[5] < 0.01);
    float q[6] = {0, 0.5f, 0, 0, 1.5f, 0};
    mlb_mesh_winding_number(&open, q, w, 2);
    CHECK_MSG(w[0] > 0.5 && w[1] < 0.5, "open cube: w(0,0.5,0) = %g, w(0,1.5,0) = %g", w[0], w[1]);
    // the sign of the mesh SDF of the open cube
    mlb_shape s;
    REQUIRE(mlb_shape_from_mesh(&s, &open, 1.0f) == MLB_OK);
    float r = 1.0f / sqrtf(3.0f);   // normalised: corners on the unit sphere
    float t[6] = {0, 0, 0, 0.5f * r, 0, 0}, d[2];   // the centre, and halfway to +x
    mlb_shape_sdf(&s, t, d, 2);
    CHECK_CLOSE(d[0], -r, 1e-5, 0);
    CHECK_CLOSE(d[1], -0.5 * r, 1e-5, 0);
    mlb_shape_free(&s);
    mlb_mesh_free(&open);
    mlb_mesh_free(&cube);
    // a closed sphere mesh
    mlb_mesh sph;
    REQUIRE(mlb_mesh_uv_sphere(&sph, 1.0f, 48, 24) == MLB_OK);
    float u[12] = {0, 0, 0, 0.5f, 0.5f, 0.5f, 0, 0.98f, 0, 0.8f, 0.8f, 0};
    mlb_mesh_winding_number(&sph, u, w, 4);
    CHECK_CLOSE(w[0], 1.0, 0, 1e-9);
    CHECK_CLOSE(w[1], 1.0, 0, 1e-9);
    CHECK_CLOSE(w[2], 1.0, 0, 1e-9);
    CHECK_CLOSE(w[3], 0.0, 0, 1e-9);
    mlb_mesh_free(&sph);
}

TEST(mesh_sdf_of_sphere) {
    mlb_mesh sph;
    REQUIRE(mlb_mesh_uv_sphere(&sph, 1.0f, 96, 48) == MLB_OK);
    mlb_shape s;
    REQUIRE(mlb_shape_from_mesh(&s, &sph, 0.8f) == MLB_OK);
    enum { N = 500 };
    float p[3 * N], d[N];
    for (int i = 0; i < 3 * N; i++) p[i] = 2.0f * mlb_rng_uniform(9, 0, i) - 1.0f;
    mlb_shape_sdf(&s, p, d, N);
    double worst = 0;
    for (int i = 0; i < N; i++) {
        double r = sqrt((double)p[3 * i] * p[3 * i] + (double)p[3 * i + 1] * p[3 * i + 1] + (double)p[3 * i + 2] * p[3 * i + 2]);
        worst = fmax(worst, fabs(d[i] - (r - 0.8)));
    }
    // chord sagitta of the 96×48 tessellation: 0.8·(1 − cos(π/48)) ≈ 1.7e-3
    CHECK_MSG(worst < 2.5e-3, "mesh sdf vs |p| − 0.8: %g", worst);
    mlb_shape_free(&s);
    mlb_mesh_free(&sph);
}

// The init config of the tests: "64" grid (32 cells), 8 levels and a 2^14 table to stay fast.
static mlb_geometry_config init_config(void) {
    mlb_geometry_config c = mlb_geometry_default();
    c.enc = (mlb_hashgrid_config){8, 2, 1u << 14, 16, 1.5};
    return c;
}

static void fit_and_measure(const mlb_shape* shape, const mlb_mesh* reference, double* rel, double* loss, int* n_faces) {
    mlb_geometry_config c = init_config();
    mlb_geometry_net net;
    *rel = INFINITY;
    if (geometry_net_init(&net, &c) != MLB_OK) return;
    mlb_shape_fit_config fc = mlb_shape_fit_default();
    fc.batch = 6144;
    fc.pool = 8192;
    if (mlb_geometry_fit_shape(&net, shape, &fc, NULL, loss) == MLB_OK) {
        mlb_tetgrid g;
        mlb_mesh m;
        if (mlb_tetgrid_create(&g, 32, c.scale) == MLB_OK && mlb_geometry_extract(NULL, &net, &g, &m) == MLB_OK) {
            mlb_chamfer_result r;
            if (mlb_chamfer(&m, reference, 20000, 1, &r) == MLB_OK) {
                *rel = r.relative;
                printf("  mse %.3g, %d faces, chamfer %.5f (%.5f of the diagonal %.3f), max %.4f / %.4f\n", *loss, m.n_faces,
                       r.chamfer, r.relative, r.diag, r.max_a_to_b, r.max_b_to_a);
            }
            *n_faces = m.n_faces;
            mlb_mesh_free(&m);
        }
        mlb_tetgrid_free(&g);
    }
    geometry_net_free(&net);
}

TEST(ellipsoid_init_chamfer) {
    float axes[3] = {0.9f, 0.7f, 0.55f};
    mlb_shape s;
    mlb_shape_ellipsoid(&s, 1.0f, axes);
    mlb_mesh ref;
    REQUIRE(mlb_mesh_uv_sphere(&ref, 1.0f, 192, 96) == MLB_OK);
    for (int i = 0; i < ref.n_verts; i++) for (int k = 0; k < 3; k++) ref.pos[3 * i + k] *= axes[k];
    double rel, loss;
    int nf = 0;
    fit_and_measure(&s, &ref, &rel, &loss, &nf);
    // The 32-cell grid's cell is 2.1/32 = 0.066; a tenth of a cell (0.0066) is 0.25% of the
    // reference's diagonal (2.56).
    CHECK_MSG(rel < 0.0025, "relative chamfer %g", rel);
    CHECK(nf > 1000);
    mlb_mesh_free(&ref);
}

// A torus (R 0.6, r 0.25, about y), CCW from outside.
static void torus_mesh(mlb_mesh* m, int nu, int nv) {
    memset(m, 0, sizeof *m);
    m->n_verts = nu * nv;
    m->n_faces = 2 * nu * nv;
    m->pos = malloc(sizeof(float) * 3 * m->n_verts);
    m->faces = malloc(sizeof(int32_t) * 3 * m->n_faces);
    for (int i = 0; i < nu; i++)
        for (int j = 0; j < nv; j++) {
            double u = 2 * M_PI * i / nu, v = 2 * M_PI * j / nv, rr = 0.6 + 0.25 * cos(v);
            float* p = m->pos + 3 * (i * nv + j);
            p[0] = (float)(rr * cos(u)); p[2] = (float)(rr * sin(u)); p[1] = (float)(0.25 * sin(v));
        }
    int f = 0;
    for (int i = 0; i < nu; i++)
        for (int j = 0; j < nv; j++) {
            int a = i * nv + j, b = ((i + 1) % nu) * nv + j, c = ((i + 1) % nu) * nv + (j + 1) % nv, d = i * nv + (j + 1) % nv;
            int32_t* t = m->faces + 3 * f;
            t[0] = a; t[1] = d; t[2] = c; t[3] = a; t[4] = c; t[5] = b;
            f += 2;
        }
}

TEST(mesh_init_chamfer) {
    mlb_mesh src;
    const char* data = test_shared_data();
    char path[4096];
    int have_spot = 0;
    if (data) {
        snprintf(path, sizeof path, "%s/meshes/spot/spot.obj", data);
        have_spot = mlb_obj_load(path, &src) == MLB_OK;
    }
    if (!have_spot) torus_mesh(&src, 64, 32);
    printf("  target: %s (%d faces)\n", have_spot ? "spot" : "procedural torus", src.n_faces);
    // the torus must be oriented right for the winding number: its centre hole is outside
    double w[2];
    float q[6] = {0, 0, 0, 0.6f, 0, 0};
    if (!have_spot) {
        mlb_mesh_winding_number(&src, q, w, 2);
        CHECK_CLOSE(w[0], 0.0, 0, 1e-6);
        CHECK_CLOSE(w[1], 1.0, 0, 1e-6);
    }
    mlb_shape s;
    REQUIRE(mlb_shape_from_mesh(&s, &src, 1.0f) == MLB_OK);
    double rel, loss;
    int nf = 0;
    fit_and_measure(&s, &s.mesh, &rel, &loss, &nf);
    // Thin parts (spot's ears and horns, thinner than a cell) cannot be resolved by a 32-cell grid:
    // the bound is looser than the ellipsoid's.
    CHECK_MSG(rel < 0.006, "relative chamfer %g", rel);
    mlb_shape_free(&s);
    mlb_mesh_free(&src);
}

TEST(save_load) {
    mlb_geometry_config c = small_config();
    mlb_geometry_net a, b;
    REQUIRE(geometry_net_init(&a, &c) == MLB_OK);
    const char* dir = test_tmpdir("geometry_net");
    REQUIRE(dir);
    char path[4200];
    snprintf(path, sizeof path, "%s/g.safetensors", dir);
    mlb_st_meta extra[1] = {{"shape", "test"}};
    REQUIRE(mlb_geometry_save(&a, path, extra, 1) == MLB_OK);
    REQUIRE(mlb_geometry_load(&b, path) == MLB_OK);
    CHECK(b.n_params == a.n_params && b.cfg.hidden == 8 && b.cfg.enc.table_size == 256);
    CHECK(memcmp(a.params, b.params, sizeof(float) * a.n_params) == 0);
    geometry_net_free(&b);
    // a file that is not a geometry network
    snprintf(path, sizeof path, "%s/x.safetensors", dir);
    float z = 0;
    int64_t shp[1] = {1};
    mlb_st_entry e = {"x", MLB_DT_F32, 1, shp, &z};
    REQUIRE(mlb_st_write(path, &e, 1, NULL, 0) == MLB_OK);
    CHECK(mlb_geometry_load(&b, path) == MLB_ERR_FORMAT);
    geometry_net_free(&a);
}

int main(void) {
    RUN(fd_whole_chain_f64);
    RUN(coarse_to_fine_levels);
    RUN(float_matches_double);
    RUN(analytic_sdfs);
    RUN(shape_slab);
    RUN(shape_cup);
    RUN(winding_number);
    RUN(mesh_sdf_of_sphere);
    RUN(ellipsoid_init_chamfer);
    RUN(mesh_init_chamfer);
    RUN(save_load);
    return test_summary();
}
