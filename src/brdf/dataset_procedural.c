// The built-in procedural material distribution: the auto-encoder's training data when the user
// gives no SVBRDF maps. Rather than drawing the 7 channels independently (which would fill the
// cube with implausible materials and leave real ones sparse), it draws small procedural
// "maps" like the real datasets: each map mixes one to three base materials from measured
// families (metal F0 from complex indices, dielectric F0 from refractive indices, albedos from
// published charts) through fBm value noise, adds wear (dirt, scratches, rust, baked cavities),
// and contributes PIXELS_PER_MAP pixels. docs/materials.md lists the numbers and their sources,
// and the analysis of the real maps that set the "authored" ranges.
//
// Determinism: sample i belongs to map i / PIXELS_PER_MAP; the map's parameters come from the
// counter RNG at (seed, map stream), the pixel's position from (seed, pixel stream, i) and the
// noise lattices from (seed, noise stream of the map, lattice point). Nothing depends on the
// order of evaluation, so any thread count gives the same bits, and n samples are a prefix of
// n + m samples.
#include "matlaber/brdf.h"
#include "matlaber/rng.h"
#include <math.h>
#include <stdio.h>
#include <string.h>

#define PIXELS_PER_MAP 128
#define MAX_LAYERS 3
// Stream tags in the top bits keep the three uses apart for any map count below 2^56.
#define STREAM_MAP(j) ((1ull << 60) | (uint64_t)(j))
#define STREAM_PIXEL (2ull << 60)
#define STREAM_NOISE(j, sub) ((3ull << 60) | ((uint64_t)(j) << 4) | (uint64_t)(sub))

// ---- per-map random draws: a sequence of uniforms from the map's own stream ----
typedef struct {
    uint64_t seed, stream, next;
    uint32_t buf[4];
    int left;
} draws;

static float U(draws* d) {
    if (d->left == 0) {
        mlb_u32x4 w = mlb_rng_words(d->seed, d->stream, d->next++);
        memcpy(d->buf, w.v, sizeof d->buf);
        d->left = 4;
    }
    return (float)(d->buf[4 - d->left--] >> 8) * (1.0f / 16777216.0f);
}
static float uni(draws* d, float lo, float hi) { return lo + (hi - lo) * U(d); }
static float loguni(draws* d, float lo, float hi) { return lo * powf(hi / lo, U(d)); }
static int chance(draws* d, float p) { return U(d) < p; }

static float clampf(float x, float lo, float hi) { return x < lo ? lo : (x > hi ? hi : x); }
static float lerpf(float a, float b, float t) { return a + (b - a) * t; }
static float smoothstep(float e0, float e1, float x) {
    float t = clampf((x - e0) / (e1 - e0), 0.0f, 1.0f);
    return t * t * (3.0f - 2.0f * t);
}

// ---- material families ----
// Dielectric families: refractive index range (F0 = ((n-1)/(n+1))^2), albedo colour (HSV hue
// and saturation in sRGB, mean linear albedo drawn uniformly in sRGB-encoded value, i.e.
// perceptually uniform, which puts more samples at the dark end where real albedos crowd) and
// perceptual roughness range (values below MLB_KR_MIN clamp there, which gives the
// point mass that polished real surfaces show). Weights: share of maps whose first material is
// of this family (metals 22, authored 30, dielectrics 55 in all).
typedef struct {
    int fam;
    float weight;
    float n_lo, n_hi;
    float hue_lo, hue_hi, sat_lo, sat_hi;
    float alb_lo, alb_hi;
    float r_lo, r_hi;
} diel_family;

static const diel_family diel[] = {
    // fam                  w    n range      hue (deg)  saturation  albedo        roughness
    {MLB_FAM_WOOD,           6.0f, 1.50f, 1.56f, 15, 45,   0.30f, 0.75f, 0.04f, 0.45f, 0.30f, 0.85f},
    {MLB_FAM_STONE,          7.0f, 1.50f, 1.66f, 0, 55,    0.00f, 0.45f, 0.02f, 0.55f, 0.50f, 1.05f},
    {MLB_FAM_POLISHED_STONE, 4.0f, 1.49f, 1.66f, 0, 60,    0.00f, 0.70f, 0.02f, 0.90f, 0.00f, 0.30f},
    {MLB_FAM_CERAMIC,        4.0f, 1.50f, 1.60f, 0, 360,   0.00f, 0.80f, 0.10f, 0.85f, 0.00f, 0.35f},
    {MLB_FAM_PAINT,          6.0f, 1.45f, 1.55f, 0, 360,   0.00f, 0.95f, 0.02f, 0.85f, 0.05f, 0.80f},
    {MLB_FAM_PLASTIC,        7.0f, 1.46f, 1.59f, 0, 360,   0.00f, 1.00f, 0.02f, 0.80f, 0.05f, 0.65f},
    {MLB_FAM_RUBBER,         2.5f, 1.50f, 1.53f, 0, 360,   0.00f, 0.40f, 0.015f, 0.15f, 0.45f, 0.95f},
    {MLB_FAM_FABRIC,         5.0f, 1.46f, 1.58f, 0, 360,   0.00f, 0.90f, 0.03f, 0.75f, 0.65f, 1.05f},
    {MLB_FAM_SKIN,           1.5f, 1.40f, 1.45f, 10, 35,   0.25f, 0.60f, 0.08f, 0.50f, 0.35f, 0.70f},
    {MLB_FAM_LEAF,           2.5f, 1.42f, 1.50f, 60, 130,  0.35f, 0.85f, 0.03f, 0.30f, 0.30f, 0.85f},
    {MLB_FAM_GLASS,          1.5f, 1.47f, 1.52f, 0, 360,   0.00f, 0.70f, 0.003f, 0.10f, 0.00f, 0.25f},
    {MLB_FAM_GEM,            1.0f, 1.54f, 1.77f, 0, 360,   0.50f, 1.00f, 0.01f, 0.30f, 0.00f, 0.20f},
    {MLB_FAM_WATER,          1.0f, 1.33f, 1.36f, 20, 220,  0.00f, 0.60f, 0.005f, 0.10f, 0.00f, 0.20f},
    {MLB_FAM_BRIGHT,         2.5f, 1.33f, 1.55f, 0, 60,    0.00f, 0.15f, 0.50f, 0.92f, 0.55f, 1.05f},
    {MLB_FAM_DARK,           3.0f, 1.50f, 1.60f, 10, 45,   0.00f, 0.50f, 0.02f, 0.20f, 0.60f, 1.05f},
    {MLB_FAM_RUST,           0.5f, 1.50f, 1.65f, 10, 30,   0.55f, 0.90f, 0.04f, 0.25f, 0.60f, 1.05f},
    {MLB_FAM_PATINA,         0.0f, 1.55f, 1.70f, 150, 190, 0.30f, 0.60f, 0.08f, 0.35f, 0.60f, 0.95f},
};
#define N_DIEL ((int)(sizeof diel / sizeof diel[0]))

static const float metal_weight[8] = {2.5f, 2.5f, 2.5f, 3.0f, 4.0f, 2.5f, 2.5f, 2.5f};
#define AUTHORED_WEIGHT 30.0f

static const diel_family* diel_of(int fam) {
    for (int i = 0; i < N_DIEL; i++)
        if (diel[i].fam == fam) return &diel[i];
    return &diel[0];
}

// A family by the weights above; `allow_authored` = 0 leaves the authored class out.
static int pick_family(draws* d, int allow_authored) {
    float total = 0;
    for (int i = 0; i < 8; i++) total += metal_weight[i];
    for (int i = 0; i < N_DIEL; i++) total += diel[i].weight;
    if (allow_authored) total += AUTHORED_WEIGHT;
    float x = U(d) * total;
    for (int i = 0; i < 8; i++)
        if ((x -= metal_weight[i]) < 0) return MLB_FAM_GOLD + i;
    for (int i = 0; i < N_DIEL; i++)
        if ((x -= diel[i].weight) < 0) return diel[i].fam;
    return allow_authored ? MLB_FAM_AUTHORED : MLB_FAM_PLASTIC;
}

static int pick_dielectric(draws* d) {
    float total = 0;
    for (int i = 0; i < N_DIEL; i++) total += diel[i].weight;
    float x = U(d) * total;
    for (int i = 0; i < N_DIEL; i++)
        if ((x -= diel[i].weight) < 0) return diel[i].fam;
    return MLB_FAM_PLASTIC;
}

// Colour of a family: hue/saturation through HSV in sRGB (where artists and charts specify
// colour), decoded to linear and scaled to the drawn mean albedo; a colour too saturated to
// reach that albedo is capped at 1 in its brightest channel, as real pigments are.
static void family_colour(draws* d, const diel_family* f, float out[3]) {
    float hue = uni(d, f->hue_lo, f->hue_hi), sat = uni(d, f->sat_lo, f->sat_hi);
    float alb = mlb_srgb_to_linear(uni(d, mlb_linear_to_srgb(f->alb_lo), mlb_linear_to_srgb(f->alb_hi)));
    hue = fmodf(hue, 360.0f) / 60.0f;
    int sector = (int)hue;
    float frac = hue - (float)sector, p = 1.0f - sat, q = 1.0f - sat * frac, t = 1.0f - sat * (1.0f - frac);
    float rgb[6][3] = {{1, t, p}, {q, 1, p}, {p, 1, t}, {p, q, 1}, {t, p, 1}, {1, p, q}};
    float lin[3], mean = 0, mx = 0;
    for (int c = 0; c < 3; c++) {
        lin[c] = mlb_srgb_to_linear(rgb[sector % 6][c]);
        mean += lin[c] / 3.0f;
    }
    for (int c = 0; c < 3; c++) {
        out[c] = lin[c] / mean * alb;
        mx = fmaxf(mx, out[c]);
    }
    if (mx > 1.0f)
        for (int c = 0; c < 3; c++) out[c] /= mx;
}

static float f0_of_index(float n) { return ((n - 1.0f) / (n + 1.0f)) * ((n - 1.0f) / (n + 1.0f)); }

// ---- layers (one base material of a map) and maps ----
typedef struct {
    int fam, cls;
    float kd[3], ks[3], kr;
    float alb_var, hue_var[3];   // relative albedo / per-channel colour variation
    float kr_var, kr_couple;     // roughness variation, and its coupling to albedo variation
    float ks_var;                // relative F0 variation (metals: polish, fingerprints)
    // authored only
    int metal_mode;              // 0 none, 1 binary regions, 2 continuous
    float m_lo, m_hi, m_thr, m_edge, kr_metal;
    float metal_col[3];
    float spec_level, spec_var;
    int grey_spec;
} layer;

typedef struct {
    int n_layers;
    layer L[MAX_LAYERS];
    float freq;                  // noise cells across the map
    float t2, e2, t3, e3;        // layer partition thresholds / blend half-widths
    float dirt, dirt_t, dirt_e, dirt_kd[3], dirt_ks, dirt_kr;
    float scratch_amp, scratch_width, scratch_cos, scratch_sin, scratch_freq;
    float cavity_depth, cavity_t;
} proc_map;

static void make_dielectric(draws* d, int fam, layer* l) {
    const diel_family* f = diel_of(fam);
    l->fam = fam;
    l->cls = MLB_MAT_DIELECTRIC;
    family_colour(d, f, l->kd);
    float f0 = f0_of_index(uni(d, f->n_lo, f->n_hi));
    for (int c = 0; c < 3; c++) l->ks[c] = f0;
    l->kr = uni(d, f->r_lo, f->r_hi);
    if (fam == MLB_FAM_WOOD && chance(d, 0.3f)) l->kr = uni(d, 0.05f, 0.35f);   // varnished
    l->alb_var = uni(d, 0.0f, 0.5f);
    for (int c = 0; c < 3; c++) l->hue_var[c] = uni(d, 0.0f, 0.15f);
    l->kr_var = uni(d, 0.0f, 0.15f);
    l->kr_couple = uni(d, -0.15f, 0.15f);
}

static void make_metal(draws* d, int fam, layer* l) {
    l->fam = fam;
    l->cls = MLB_MAT_METAL;
    float f0[3];
    mlb_brdf_metal_f0(fam, f0);
    // Alloy / measurement spread of a few percent per channel; 30% of metals are tarnished:
    // darker and greyer F0 and a little diffuse from the oxide film.
    int tarnished = chance(d, 0.3f);
    float dim = tarnished ? uni(d, 0.6f, 0.92f) : uni(d, 0.94f, 1.0f);
    float grey = tarnished ? uni(d, 0.0f, 0.3f) : 0.0f;
    float mean = (f0[0] + f0[1] + f0[2]) / 3.0f;
    for (int c = 0; c < 3; c++) l->ks[c] = clampf(lerpf(f0[c], mean, grey) * dim * uni(d, 0.97f, 1.03f), 0.0f, 1.0f);
    float kd = tarnished ? uni(d, 0.0f, 0.04f) : uni(d, 0.0f, 0.01f);
    for (int c = 0; c < 3; c++) l->kd[c] = kd * l->ks[c];
    float finish = U(d);   // polished 35%, brushed 35%, rough/cast 30%
    l->kr = finish < 0.35f ? uni(d, 0.0f, 0.2f) : finish < 0.7f ? uni(d, 0.2f, 0.45f) : uni(d, 0.45f, 0.8f);
    l->alb_var = uni(d, 0.0f, 0.5f);
    l->kr_var = uni(d, 0.0f, 0.1f);
    l->kr_couple = uni(d, -0.1f, 0.1f);
    l->ks_var = uni(d, 0.0f, 0.04f);
}

// Artist-made maps (how TwoShotBRDF, Deschaintre's set and texture libraries are built): colour
// from any dielectric family, metalness in regions or continuous, a "specular level" giving
// dielectric F0 in [0, 0.08] (0.5 -> 0.04 is the tools' default and the most common value in the
// real maps), often a monochrome specular map, and roughness over the whole range.
static void make_authored(draws* d, layer* l) {
    l->fam = MLB_FAM_AUTHORED;
    l->cls = MLB_MAT_AUTHORED;
    family_colour(d, diel_of(pick_dielectric(d)), l->kd);
    float mode = U(d);
    l->metal_mode = mode < 0.3f ? 0 : mode < 0.6f ? 1 : 2;
    l->m_lo = uni(d, 0.0f, 0.3f);
    l->m_hi = uni(d, 0.5f, 1.0f);
    l->m_thr = uni(d, 0.3f, 0.7f);
    l->m_edge = uni(d, 0.01f, 0.15f);
    if (chance(d, 0.5f)) {
        int fam = MLB_FAM_GOLD + (int)(U(d) * 8.0f);
        mlb_brdf_metal_f0(fam, l->metal_col);
        float mean = (l->metal_col[0] + l->metal_col[1] + l->metal_col[2]) / 3.0f, g = U(d), dim = uni(d, 0.5f, 1.0f);
        for (int c = 0; c < 3; c++) l->metal_col[c] = lerpf(l->metal_col[c], mean, g) * dim;
    } else {
        float g = uni(d, 0.1f, 0.95f);
        for (int c = 0; c < 3; c++) l->metal_col[c] = clampf(g * uni(d, 0.97f, 1.03f), 0.0f, 1.0f);
    }
    l->spec_level = chance(d, 0.35f) ? 0.5f : U(d);
    l->spec_var = chance(d, 0.3f) ? uni(d, 0.0f, 0.3f) : 0.0f;
    l->grey_spec = chance(d, 0.6f);
    l->kr = uni(d, 0.0f, 1.05f);
    l->alb_var = uni(d, 0.0f, 0.6f);
    for (int c = 0; c < 3; c++) l->hue_var[c] = uni(d, 0.0f, 0.15f);
    l->kr_var = uni(d, 0.0f, 0.25f);
    l->kr_couple = uni(d, -0.25f, 0.25f);
    l->kr_metal = uni(d, -0.4f, 0.4f);
}

static void make_layer(draws* d, int fam, layer* l) {
    memset(l, 0, sizeof *l);
    if (fam == MLB_FAM_AUTHORED) make_authored(d, l);
    else if (mlb_brdf_family_class(fam) == MLB_MAT_METAL) make_metal(d, fam, l);
    else make_dielectric(d, fam, l);
}

static void make_map(proc_map* m, uint64_t seed, uint64_t j) {
    draws d = {seed, STREAM_MAP(j), 0, {0}, 0};
    memset(m, 0, sizeof *m);
    float nl = U(&d);
    m->n_layers = nl < 0.35f ? 1 : nl < 0.8f ? 2 : 3;
    int f1 = pick_family(&d, 1);
    make_layer(&d, f1, &m->L[0]);
    int any_iron = f1 == MLB_FAM_IRON;
    if (m->n_layers >= 2) {
        int f2;
        if (f1 == MLB_FAM_AUTHORED) f2 = MLB_FAM_AUTHORED;   // authored maps stay authored (cavity applies to all)
        else if (f1 == MLB_FAM_IRON && chance(&d, 0.55f)) f2 = MLB_FAM_RUST;
        else if (f1 == MLB_FAM_COPPER && chance(&d, 0.35f)) f2 = MLB_FAM_PATINA;
        else if (chance(&d, 0.4f)) f2 = f1;                  // two variants of one family: grain, veins, weave
        else f2 = pick_family(&d, 0);
        any_iron |= f2 == MLB_FAM_IRON;
        make_layer(&d, f2, &m->L[1]);
    }
    if (m->n_layers >= 3) {
        // Mostly weathering: moss, soil, dust, or rust where there is iron.
        static const int weather[4] = {MLB_FAM_LEAF, MLB_FAM_DARK, MLB_FAM_BRIGHT, MLB_FAM_RUST};
        int f3;
        if (f1 == MLB_FAM_AUTHORED) f3 = MLB_FAM_AUTHORED;
        else if (chance(&d, 0.5f)) f3 = any_iron && chance(&d, 0.5f) ? MLB_FAM_RUST : weather[(int)(U(&d) * 3.0f)];
        else f3 = pick_family(&d, 0);
        make_layer(&d, f3, &m->L[2]);
    }
    m->freq = loguni(&d, 1.5f, 10.0f);
    m->t2 = uni(&d, 0.25f, 0.75f);
    m->e2 = uni(&d, 0.01f, 0.12f);
    m->t3 = uni(&d, 0.35f, 0.85f);
    m->e3 = uni(&d, 0.01f, 0.12f);
    if (chance(&d, 0.3f)) {   // dirt or dust: a rough dielectric film, in blotches
        layer tmp;
        make_layer(&d, chance(&d, 0.7f) ? MLB_FAM_DARK : MLB_FAM_BRIGHT, &tmp);
        memcpy(m->dirt_kd, tmp.kd, sizeof m->dirt_kd);
        m->dirt_ks = tmp.ks[0];
        m->dirt_kr = uni(&d, 0.75f, 1.0f);
        m->dirt = uni(&d, 0.2f, 0.7f);
        m->dirt_t = uni(&d, 0.4f, 0.8f);
        m->dirt_e = uni(&d, 0.05f, 0.25f);
    }
    int metal_first = m->L[0].cls == MLB_MAT_METAL;
    if (chance(&d, metal_first ? 0.5f : 0.25f)) {
        // Scratches roughen a polished surface, or burnish a rough one: sign at random.
        m->scratch_amp = uni(&d, 0.05f, 0.3f) * (chance(&d, 0.7f) ? 1.0f : -1.0f);
        m->scratch_width = uni(&d, 0.03f, 0.15f);
        float a = uni(&d, 0.0f, 3.14159265f);
        m->scratch_cos = cosf(a);
        m->scratch_sin = sinf(a);
        m->scratch_freq = uni(&d, 4.0f, 16.0f);
    }
    if (f1 == MLB_FAM_AUTHORED && chance(&d, 0.6f)) {
        // Baked ambient occlusion / cavity: texture authors multiply it into colour and specular.
        m->cavity_depth = uni(&d, 0.3f, 0.97f);
        m->cavity_t = uni(&d, 0.25f, 0.6f);
    }
}

// ---- noise ----
// Value noise on an integer lattice whose values are Philox words of (seed, stream, lattice
// point): one call gives four independent fields at once. Quintic interpolation; fBm sums
// octaves with gain 1/2, then a contrast stretch spreads the result over [0, 1] (clamping
// at the ends, which gives the flat, pure regions real maps have).
static float quintic(float t) { return t * t * t * (t * (t * 6.0f - 15.0f) + 10.0f); }

static void value_noise4(uint64_t seed, uint64_t stream, float x, float y, float out[4]) {
    float fx = floorf(x), fy = floorf(y);
    int64_t ix = (int64_t)fx, iy = (int64_t)fy;
    float tx = quintic(x - fx), ty = quintic(y - fy);
    mlb_u32x4 w[4];
    for (int k = 0; k < 4; k++) {
        uint64_t cx = (uint64_t)(ix + (k & 1)), cy = (uint64_t)(iy + (k >> 1));
        w[k] = mlb_rng_words(seed, stream, (cx & 0xffffffffull) | (cy << 32));
    }
    for (int c = 0; c < 4; c++) {
        float v00 = (float)(w[0].v[c] >> 8), v10 = (float)(w[1].v[c] >> 8);
        float v01 = (float)(w[2].v[c] >> 8), v11 = (float)(w[3].v[c] >> 8);
        out[c] = lerpf(lerpf(v00, v10, tx), lerpf(v01, v11, tx), ty) * (1.0f / 16777216.0f);
    }
}

static void fbm4(uint64_t seed, uint64_t map, int group, float x, float y, int octaves, float out[4]) {
    float acc[4] = {0, 0, 0, 0}, amp = 1.0f, norm = 0.0f, o[4];
    for (int k = 0; k < octaves; k++) {
        // Each octave has its own lattice stream; the offset avoids lattice-aligned octaves.
        value_noise4(seed, STREAM_NOISE(map, group * 8 + k), x + 17.31f * (float)k, y + 5.73f * (float)k, o);
        for (int c = 0; c < 4; c++) acc[c] += amp * o[c];
        norm += amp;
        x *= 2.0f;
        y *= 2.0f;
        amp *= 0.5f;
    }
    for (int c = 0; c < 4; c++) out[c] = clampf(0.5f + (acc[c] / norm - 0.5f) * 2.5f, 0.0f, 1.0f);
}

// ---- one pixel ----
static void eval_layer(const layer* l, const float A[4], const float B[4], float k[7]) {
    float a = A[1] - 0.5f;   // albedo variation field, shared so colour and roughness correlate
    for (int c = 0; c < 3; c++) {
        float var = (1.0f + 2.0f * l->alb_var * a) * (1.0f + 2.0f * l->hue_var[c] * (B[3] - 0.5f));
        k[c] = l->kd[c] * var;
        k[3 + c] = l->ks[c] * (1.0f + 2.0f * l->ks_var * (A[3] - 0.5f));
    }
    k[6] = l->kr + 2.0f * l->kr_var * (A[2] - 0.5f) + 2.0f * l->kr_couple * a;
    if (l->cls != MLB_MAT_AUTHORED) return;
    float m = 0.0f;
    if (l->metal_mode == 1) m = smoothstep(l->m_thr - l->m_edge, l->m_thr + l->m_edge, A[3]);
    else if (l->metal_mode == 2) m = lerpf(l->m_lo, l->m_hi, A[3]);
    float level = clampf(l->spec_level + 2.0f * l->spec_var * (A[2] - 0.5f), 0.0f, 1.0f);
    float f0d = 0.08f * level;   // the tools' specular-level convention: 0.5 -> 0.04
    float mean = 0.0f;
    for (int c = 0; c < 3; c++) {
        float base = lerpf(k[c], l->metal_col[c], m);   // metal regions take their colour as F0
        k[c] = base * (1.0f - m);
        k[3 + c] = f0d * (1.0f - m) + base * m;
        mean += k[3 + c] / 3.0f;
    }
    if (l->grey_spec)
        for (int c = 0; c < 3; c++) k[3 + c] = mean;
    k[6] += l->kr_metal * m;
}

static void eval_pixel(const proc_map* m, uint64_t seed, uint64_t map, uint64_t i, float k[7], uint8_t* cls,
                       uint8_t* fam) {
    mlb_u32x4 w = mlb_rng_words(seed, STREAM_PIXEL, i);
    float u = (float)(w.v[0] >> 8) * (1.0f / 16777216.0f), v = (float)(w.v[1] >> 8) * (1.0f / 16777216.0f);
    float x = u * m->freq, y = v * m->freq, A[4], B[4];
    // Group A: layer-2 partition, albedo, roughness, metalness/F0 variation (3 octaves);
    // group B: layer-3 partition, dirt, cavity, colour variation (2 octaves). With 128 random
    // pixels per map, higher octaves would add cost but no structure the samples can show.
    fbm4(seed, map, 0, x, y, 3, A);
    fbm4(seed, map, 1, x, y, 2, B);

    float kl[MAX_LAYERS][7], wl[MAX_LAYERS] = {1.0f, 0.0f, 0.0f};
    for (int l = 0; l < m->n_layers; l++) eval_layer(&m->L[l], A, B, kl[l]);
    float b2 = m->n_layers >= 2 ? smoothstep(m->t2 - m->e2, m->t2 + m->e2, A[0]) : 0.0f;
    float b3 = m->n_layers >= 3 ? smoothstep(m->t3 - m->e3, m->t3 + m->e3, B[0]) : 0.0f;
    wl[0] = (1.0f - b2) * (1.0f - b3);
    wl[1] = b2 * (1.0f - b3);
    wl[2] = b3;
    for (int c = 0; c < 7; c++) {
        float s = 0.0f;
        for (int l = 0; l < m->n_layers; l++) s += wl[l] * kl[l][c];
        k[c] = s;
    }
    float dirt = 0.0f;
    if (m->dirt > 0.0f) {
        dirt = m->dirt * smoothstep(m->dirt_t - m->dirt_e, m->dirt_t + m->dirt_e, B[1]);
        for (int c = 0; c < 3; c++) {
            k[c] = lerpf(k[c], m->dirt_kd[c], dirt);
            k[3 + c] = lerpf(k[3 + c], m->dirt_ks, dirt);
        }
        k[6] = lerpf(k[6], m->dirt_kr, dirt);
    }
    if (m->scratch_amp != 0.0f) {
        // Long thin features: value noise stretched 24x along the scratch direction, kept where
        // it crosses 0.5 (a ridge), so the lines have random length and spacing.
        float sx = (x * m->scratch_cos + y * m->scratch_sin) * m->scratch_freq / m->freq;
        float sy = (y * m->scratch_cos - x * m->scratch_sin) * m->scratch_freq / m->freq * 24.0f;
        float s[4];
        fbm4(seed, map, 2, sx, sy, 2, s);
        float ridge = 1.0f - fabsf(2.0f * s[0] - 1.0f);
        k[6] += m->scratch_amp * smoothstep(1.0f - m->scratch_width, 1.0f, ridge);
    }
    if (m->cavity_depth > 0.0f) {
        float cav = m->cavity_depth * smoothstep(m->cavity_t, 0.0f, B[2]);
        for (int c = 0; c < 6; c++) k[c] *= 1.0f - cav;
    }
    mlb_brdf_clamp(k);
    if (cls || fam) {
        int top = 0;
        for (int l = 1; l < m->n_layers; l++)
            if (wl[l] > wl[top]) top = l;
        float purity = wl[top] * (1.0f - dirt);
        if (cls) *cls = (uint8_t)(purity >= 0.99f ? m->L[top].cls : MLB_MAT_MIXED);
        if (fam) *fam = (uint8_t)m->L[top].fam;
    }
}

mlb_status mlb_brdf_procedural_labeled(mlb_brdf_set* out, size_t n_samples, uint64_t seed, uint8_t* cls,
                                       uint8_t* family) {
    if (!out) return mlb_fail(MLB_ERR_ARG, "procedural materials: output set is NULL");
    size_t n0 = out->n;
    float* dst;
    MLB_TRY(mlb_brdf_set_extend(out, n_samples, &dst));
    long n_maps = (long)((n_samples + PIXELS_PER_MAP - 1) / PIXELS_PER_MAP);
#pragma omp parallel for schedule(dynamic, 16) if (n_maps > 8)
    for (long j = 0; j < n_maps; j++) {
        proc_map m;
        make_map(&m, seed, (uint64_t)j);
        size_t lo = (size_t)j * PIXELS_PER_MAP, hi = lo + PIXELS_PER_MAP < n_samples ? lo + PIXELS_PER_MAP : n_samples;
        for (size_t i = lo; i < hi; i++)
            eval_pixel(&m, seed, (uint64_t)j, i, dst + i * MLB_BRDF_DIM, cls ? cls + i : NULL, family ? family + i : NULL);
    }
    char name[64];
    snprintf(name, sizeof name, "procedural seed=%llu", (unsigned long long)seed);
    mlb_status s = mlb_brdf_set_note_source(out, n0, name);
    if (s != MLB_OK) mlb_brdf_set_truncate(out, n0);
    return s;
}

mlb_status mlb_brdf_procedural(mlb_brdf_set* out, size_t n_samples, uint64_t seed) {
    return mlb_brdf_procedural_labeled(out, n_samples, seed, NULL, NULL);
}
