// Split-sum shading of the appearance renderer on a device (appearance_device.h): the inputs go up
// once per render and stay for the backward; the lights go up once and stay.
#include "appearance_device.h"
#include <stdlib.h>
#include <string.h>

enum { MAX_LIGHTS = 64 };

struct appearance_device {
    const mlb_backend* be;
    int capacity, N, n_views;
    float *kd, *ks, *kr, *nrm, *vdir, *rgb;   // [N,3], [N,3], [N], [N,3], [N,3], [N,3] on the device
    float *dkd, *dks, *dkr;                    // backward: [N,3], [N,3], [N]
    int32_t* start;                            // [n_views + 1], host
    int* view_light;                           // [n_views]: index into lights
    float* rotation;                           // [n_views]
    mlb_fresnel fresnel;
    int n_lights;
    const mlb_envlight* light_key[MAX_LIGHTS];
    void* light[MAX_LIGHTS];
};

static void release_points(appearance_device* d) {
    float** all[] = {&d->kd, &d->ks, &d->kr, &d->nrm, &d->vdir, &d->rgb, &d->dkd, &d->dks, &d->dkr};
    for (size_t i = 0; i < sizeof all / sizeof all[0]; i++) { d->be->release(*all[i]); *all[i] = NULL; }
    d->capacity = 0;
}

void appearance_device_free(appearance_device* d) {
    if (!d) return;
    release_points(d);
    for (int i = 0; i < d->n_lights; i++) d->be->light_free(d->light[i]);
    free(d->start);
    free(d->view_light);
    free(d->rotation);
    free(d);
}

static mlb_status reserve(appearance_device* d, int N, int n_views) {
    if (n_views > d->n_views || !d->start) {
        free(d->start); free(d->view_light); free(d->rotation);
        d->start = malloc(sizeof(int32_t) * (size_t)(n_views + 1));
        d->view_light = malloc(sizeof(int) * (size_t)n_views);
        d->rotation = malloc(sizeof(float) * (size_t)n_views);
        d->n_views = 0;
        if (!d->start || !d->view_light || !d->rotation) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    }
    d->n_views = n_views;
    if (N <= d->capacity) return MLB_OK;
    release_points(d);
    const mlb_backend* be = d->be;
    size_t n = (size_t)N;
    mlb_status s = be->alloc(&d->kd, 3 * n);
    if (!s) s = be->alloc(&d->ks, 3 * n);
    if (!s) s = be->alloc(&d->kr, n);
    if (!s) s = be->alloc(&d->nrm, 3 * n);
    if (!s) s = be->alloc(&d->vdir, 3 * n);
    if (!s) s = be->alloc(&d->rgb, 3 * n);
    if (!s) s = be->alloc(&d->dkd, 3 * n);
    if (!s) s = be->alloc(&d->dks, 3 * n);
    if (!s) s = be->alloc(&d->dkr, n);
    if (s) { release_points(d); return s; }
    d->capacity = N;
    return MLB_OK;
}

// The index of `key`'s uploaded copy, uploading it on first use.
static mlb_status light_index(appearance_device* d, const mlb_envlight* key, int* index) {
    for (int i = 0; i < d->n_lights; i++)
        if (d->light_key[i] == key) { *index = i; return MLB_OK; }
    if (d->n_lights == MAX_LIGHTS) return mlb_fail(MLB_ERR_ARG, "more than %d environment lights in one render state", MAX_LIGHTS);
    MLB_TRY(d->be->light_upload(&d->light[d->n_lights], key));
    d->light_key[d->n_lights] = key;
    *index = d->n_lights++;
    return MLB_OK;
}

mlb_status appearance_device_shade(appearance_device** dp, const mlb_backend* be, float* rgb, const float* kd,
                                   const float* ks, const float* kr, const float* nrm, const float* vdir,
                                   const int32_t* start, int n_views, const mlb_envlight* light,
                                   const mlb_envlight* const* light_source, mlb_fresnel fresnel) {
    if (!*dp) {
        if (!(*dp = calloc(1, sizeof **dp))) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
        (*dp)->be = be;
    }
    appearance_device* d = *dp;
    if (d->be != be) return mlb_fail(MLB_ERR_ARG, "appearance shading: the render state belongs to another device");
    int N = start[n_views];
    d->N = 0;
    MLB_TRY(reserve(d, N, n_views));
    memcpy(d->start, start, sizeof(int32_t) * (size_t)(n_views + 1));
    d->fresnel = fresnel;
    for (int v = 0; v < n_views; v++) {
        MLB_TRY(light_index(d, light_source[v], &d->view_light[v]));
        d->rotation[v] = light[v].rotation;
    }
    if (N == 0) return MLB_OK;
    size_t n = (size_t)N;
    MLB_TRY(be->upload(d->kd, kd, 3 * n));
    MLB_TRY(be->upload(d->ks, ks, 3 * n));
    MLB_TRY(be->upload(d->kr, kr, n));
    MLB_TRY(be->upload(d->nrm, nrm, 3 * n));
    MLB_TRY(be->upload(d->vdir, vdir, 3 * n));
    for (int v = 0; v < n_views; v++) {
        size_t o = (size_t)start[v];
        int m = start[v + 1] - start[v];
        if (m > 0)
            MLB_TRY(be->shade(d->rgb + 3 * o, d->kd + 3 * o, d->ks + 3 * o, d->kr + o, d->nrm + 3 * o, d->vdir + 3 * o, m,
                              d->light[d->view_light[v]], d->rotation[v], fresnel));
    }
    MLB_TRY(be->download(rgb, d->rgb, 3 * n));
    d->N = N;
    return MLB_OK;
}

mlb_status appearance_device_shade_backward(appearance_device* d, float* dkd, float* dks, float* dkr, const float* drgb) {
    if (!d || d->N == 0) return MLB_OK;
    const mlb_backend* be = d->be;
    size_t n = (size_t)d->N;
    MLB_TRY(be->upload(d->rgb, drgb, 3 * n));   // the forward's rgb is no longer needed: drgb goes there
    MLB_TRY(be->zero(d->dkd, 3 * n));
    MLB_TRY(be->zero(d->dks, 3 * n));
    MLB_TRY(be->zero(d->dkr, n));
    for (int v = 0; v < d->n_views; v++) {
        size_t o = (size_t)d->start[v];
        int m = d->start[v + 1] - d->start[v];
        if (m > 0)
            MLB_TRY(be->shade_backward(d->dkd + 3 * o, d->dks + 3 * o, d->dkr + o, NULL, NULL, d->rgb + 3 * o, d->kd + 3 * o,
                                       d->ks + 3 * o, d->kr + o, d->nrm + 3 * o, d->vdir + 3 * o, m,
                                       d->light[d->view_light[v]], d->rotation[v], d->fresnel));
    }
    MLB_TRY(be->download(dkd, d->dkd, 3 * n));
    MLB_TRY(be->download(dks, d->dks, 3 * n));
    return be->download(dkr, d->dkr, n);
}
