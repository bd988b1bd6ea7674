// Starting-shape fits kept for the process's next generation (mlb_pipeline_keep_shape_fits).
//
// --init auto fits the SDF network to four primitives before every generation: 100 Adam steps over
// 12288 points each, ~1.1 s, 4.4 s of a 64 s `tiny` generation on one thread. A fit is a function of the
// network's state before it (parameters, Adam's moments, step), the shape's name, the fit's settings
// and the hash grid's active levels; nothing else enters it (no prompt, no guidance). A process
// that runs many generations with one seed (bench text3d, generate --prompts) starts each from the
// same network, so it fits the same shapes again and again. Here the fitted parameters are kept
// under a 128-bit hash of all of that, and a repeat takes them: the same bits as fitting again.
// Only the built-in shapes: an OBJ file could change between two runs of one process.
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/pipeline.h"
#include "pipeline/pipeline_internal.h"

typedef struct {
    uint64_t key[2];
    double loss;      // the fit's final_loss, for the log line
    float* params;    // [n]
    size_t n;
} kept_fit;

enum { MAX_KEPT = 16 };
static kept_fit kept[MAX_KEPT];
static int n_kept;
static size_t budget;   // bytes of parameters kept at most; 0: none

// Two 64-bit lanes over the bytes as words (a multiply-xorshift chain each, different constants):
// a fingerprint, not a defence against a chosen collision (the inputs are the process's own).
typedef struct { uint64_t a, b; } hash128;
static void hash_bytes(hash128* h, const void* p, size_t n) {
    const unsigned char* s = p;
    for (size_t i = 0; i < n; i += 8) {
        uint64_t w = 0;
        memcpy(&w, s + i, n - i < 8 ? n - i : 8);
        h->a = (h->a ^ w) * 0x9e3779b97f4a7c15ull;
        h->a ^= h->a >> 29;
        h->b = (h->b ^ w) * 0xc2b2ae3d27d4eb4full;
        h->b ^= h->b >> 31;
    }
    h->a ^= (uint64_t)n;   // "ab" + "" and "a" + "b" differ
    h->b += (uint64_t)n;
}
#define HASH_VALUE(h, v) hash_bytes(h, &(v), sizeof(v))

void mlb_pipeline_keep_shape_fits(size_t bytes) {
    for (int i = 0; i < n_kept; i++) free(kept[i].params);
    n_kept = 0;
    budget = bytes;
}

void pipeline_shape_fit_key(const mlb_geometry_net* net, const mlb_pipeline_config* c, const char* init, int levels,
                            uint64_t key[2]) {
    hash128 h = {0x6d6c622d66697431ull, 0x7368617065733031ull};
    const mlb_field_config* f = &net->cfg;
    hash_bytes(&h, init, strlen(init) + 1);
    HASH_VALUE(&h, c->init_iters);
    HASH_VALUE(&h, c->seed);
    HASH_VALUE(&h, levels);
    HASH_VALUE(&h, f->kind);   // the config field by field: a struct's padding is not its value
    HASH_VALUE(&h, f->enc.n_levels);
    HASH_VALUE(&h, f->enc.n_features);
    HASH_VALUE(&h, f->enc.table_size);
    HASH_VALUE(&h, f->enc.base_res);
    HASH_VALUE(&h, f->enc.per_level_scale);
    HASH_VALUE(&h, f->hidden);
    HASH_VALUE(&h, f->n_hidden);
    HASH_VALUE(&h, f->scale);
    HASH_VALUE(&h, net->n_params);
    HASH_VALUE(&h, net->step);
    hash_bytes(&h, net->params, sizeof(float) * net->n_params);
    hash_bytes(&h, net->adam_m, sizeof(float) * net->n_params);
    hash_bytes(&h, net->adam_v, sizeof(float) * net->n_params);
    key[0] = h.a;
    key[1] = h.b;
}

int pipeline_shape_fit_recall(const uint64_t key[2], mlb_geometry_net* net, double* loss) {
    for (int i = 0; i < n_kept; i++)
        if (kept[i].key[0] == key[0] && kept[i].key[1] == key[1] && kept[i].n == net->n_params) {
            memcpy(net->params, kept[i].params, sizeof(float) * kept[i].n);
            *loss = kept[i].loss;
            return 1;
        }
    return 0;
}

void pipeline_shape_fit_keep(const uint64_t key[2], const mlb_geometry_net* net, double loss) {
    const size_t bytes = sizeof(float) * net->n_params;
    if (bytes > budget) return;
    size_t used = bytes;
    for (int i = 0; i < n_kept; i++) used += sizeof(float) * kept[i].n;
    while (n_kept > 0 && (used > budget || n_kept == MAX_KEPT)) {   // the oldest out first
        used -= sizeof(float) * kept[0].n;
        free(kept[0].params);
        memmove(kept, kept + 1, sizeof *kept * (size_t)--n_kept);
    }
    float* p = malloc(bytes);
    if (!p) return;   // nothing kept: the next run fits again
    memcpy(p, net->params, bytes);
    kept[n_kept++] = (kept_fit){{key[0], key[1]}, loss, p, net->n_params};
}
