// Material conventions, the sample set, the procedural distribution, the SVBRDF loaders and
// image loading (real shared data when present; broken inputs built here in a temp folder).
#include "test.h"
#include "matlaber/brdf.h"
#include "matlaber/image.h"
#include "matlaber/progress.h"
#include <omp.h>
#include <stdint.h>
#include <unistd.h>
#include <stb/stb_image_write.h>
#include <zlib.h>

// ---- helpers ----

static int contains(const char* s, const char* sub) { return s && strstr(s, sub) != NULL; }

static int is_dir_path(const char* p) {
    struct stat st;
    return stat(p, &st) == 0 && S_ISDIR(st.st_mode);
}

static void put32(unsigned char* p, uint32_t v) {
    p[0] = (unsigned char)(v >> 24); p[1] = (unsigned char)(v >> 16); p[2] = (unsigned char)(v >> 8); p[3] = (unsigned char)v;
}

static void write_chunk(FILE* f, const char* type, const unsigned char* data, uint32_t len) {
    unsigned char hdr[8], c[4];
    put32(hdr, len);
    memcpy(hdr + 4, type, 4);
    fwrite(hdr, 1, 8, f);
    if (len) fwrite(data, 1, len, f);
    uLong crc = crc32(0L, (const Bytef*)type, 4);
    put32(c, (uint32_t)(len ? crc32(crc, data, len) : crc));   // crc32(x, NULL, 0) would reset to 0
    fwrite(c, 1, 4, f);
}

// A PNG written by hand so tests control every field: 8- or 16-bit, grey/GA/RGB/RGBA, any
// declared size (pixels may be NULL to write a header-only file).
static int write_png(const char* path, uint32_t w, uint32_t h, int channels, int bits, const void* pixels) {
    static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
    static const int color_type[5] = {0, 0, 4, 2, 6};
    FILE* f = fopen(path, "wb");
    if (!f) return 0;
    fwrite(sig, 1, 8, f);
    unsigned char ihdr[13] = {0, 0, 0, 0, 0, 0, 0, 0, (unsigned char)bits, (unsigned char)color_type[channels], 0, 0, 0};
    put32(ihdr, w);
    put32(ihdr + 4, h);
    write_chunk(f, "IHDR", ihdr, 13);
    if (pixels) {
        size_t row = (size_t)w * channels * (bits / 8), raw_n = (row + 1) * h;
        unsigned char* raw = malloc(raw_n);
        for (uint32_t y = 0; y < h; y++) {
            raw[y * (row + 1)] = 0;   // filter: none
            if (bits == 8) memcpy(raw + y * (row + 1) + 1, (const unsigned char*)pixels + y * row, row);
            else
                for (size_t i = 0; i < row / 2; i++) {   // PNG stores 16-bit samples big-endian
                    uint16_t v = ((const uint16_t*)pixels)[y * (row / 2) + i];
                    raw[y * (row + 1) + 1 + 2 * i] = (unsigned char)(v >> 8);
                    raw[y * (row + 1) + 2 + 2 * i] = (unsigned char)v;
                }
        }
        uLongf zn = compressBound(raw_n);
        unsigned char* z = malloc(zn);
        compress(z, &zn, raw, raw_n);
        write_chunk(f, "IDAT", z, (uint32_t)zn);
        free(z); free(raw);
    }
    write_chunk(f, "IEND", NULL, 0);
    return fclose(f) == 0;
}

static int write_text(const char* path, const char* text) {
    FILE* f = fopen(path, "wb");
    if (!f) return 0;
    fputs(text, f);
    return fclose(f) == 0;
}

// Cuts a file to `num`/`den` of its size.
static int truncate_file(const char* path, long num, long den) {
    struct stat st;
    return stat(path, &st) == 0 && truncate(path, (long)st.st_size * num / den) == 0;
}

// A w x h 8-bit image of `channels` channels filled from a simple pattern.
static unsigned char* pattern8(int w, int h, int channels, int salt) {
    unsigned char* p = malloc((size_t)w * h * channels);
    for (int i = 0; i < w * h * channels; i++) p[i] = (unsigned char)((i * 37 + salt * 101) & 255);
    return p;
}

static char* path2(const char* a, const char* b) {
    static char buf[4][4096];
    static int k;
    k = (k + 1) & 3;
    snprintf(buf[k], sizeof buf[k], "%s/%s", a, b);
    return buf[k];
}

static void mkdir_p(const char* p) {
    char cmd[4200];
    snprintf(cmd, sizeof cmd, "mkdir -p '%s'", p);
    if (system(cmd) != 0) printf("  mkdir failed: %s\n", p);
}

// ---- conventions ----

TEST(srgb_known_values) {
    CHECK(mlb_srgb_to_linear(0.0f) == 0.0f);
    CHECK_CLOSE(mlb_srgb_to_linear(1.0f), 1.0, 0, 1e-6);
    CHECK_CLOSE(mlb_srgb_to_linear(0.04045f), 0.04045 / 12.92, 1e-6, 0);   // the linear segment's end
    CHECK_CLOSE(mlb_srgb_to_linear(0.5f), 0.2140411404, 1e-5, 0);
    CHECK_CLOSE(mlb_srgb_to_linear(56.0f / 255.0f), 0.0395462, 1e-4, 0);    // TwoShotBRDF's usual specular
    CHECK_CLOSE(mlb_linear_to_srgb(0.0031308f), 0.0404500, 1e-4, 0);
    CHECK_CLOSE(mlb_linear_to_srgb(0.18f), 0.4613561, 1e-5, 0);             // 18% grey
    CHECK_CLOSE(mlb_linear_to_srgb(0.04f), 0.2209163, 1e-5, 0);
    CHECK(mlb_linear_to_srgb(0.0f) == 0.0f);
    CHECK_CLOSE(mlb_linear_to_srgb(1.0f), 1.0, 0, 1e-6);
    // Continuous across both thresholds (the two segments meet within float rounding).
    CHECK_CLOSE(mlb_srgb_to_linear(0.04045f), mlb_srgb_to_linear(0.0404501f), 0, 1e-7);
    CHECK_CLOSE(mlb_linear_to_srgb(0.0031308f), mlb_linear_to_srgb(0.00313081f), 0, 1e-6);
}

TEST(srgb_round_trip) {
    float worst = 0, prev = -1;
    int monotone = 1;
    for (int i = 0; i <= 4096; i++) {
        float x = (float)i / 4096.0f, l = mlb_srgb_to_linear(x), back = mlb_linear_to_srgb(l);
        worst = fmaxf(worst, fabsf(back - x));
        if (l < prev) monotone = 0;
        prev = l;
        float y = mlb_srgb_to_linear(mlb_linear_to_srgb(x));
        worst = fmaxf(worst, fabsf(y - x));
    }
    CHECK_MSG(worst < 2e-6f, "round trip error %g", worst);
    CHECK(monotone);
}

TEST(brdf_validity) {
    float k[7] = {0.5f, 0.2f, 0.1f, 0.04f, 0.04f, 0.04f, 0.5f};
    CHECK(mlb_brdf_valid(k));
    float edge[7] = {0, 0, 0, 1, 1, 1, MLB_KR_MIN};
    CHECK(mlb_brdf_valid(edge));
    edge[6] = 1.0f;
    CHECK(mlb_brdf_valid(edge));
    const float bad_values[] = {NAN, INFINITY, -INFINITY, -0.001f, 1.001f};
    for (int i = 0; i < 7; i++)
        for (size_t b = 0; b < sizeof bad_values / sizeof bad_values[0]; b++) {
            float t[7];
            memcpy(t, k, sizeof t);
            t[i] = bad_values[b];
            CHECK_MSG(!mlb_brdf_valid(t), "channel %d value %g accepted", i, (double)bad_values[b]);
        }
    float r[7];
    memcpy(r, k, sizeof r);
    r[6] = 0.07f;
    CHECK(!mlb_brdf_valid(r));
    CHECK(mlb_brdf_clamp(r) == 1 && r[6] == MLB_KR_MIN && mlb_brdf_valid(r));
    float c[7] = {NAN, -1, 2, 0.5f, INFINITY, -INFINITY, NAN};
    CHECK(mlb_brdf_clamp(c) == 6);   // all but the 0.5
    CHECK(mlb_brdf_valid(c) && c[0] == 0 && c[2] == 1 && c[4] == 1 && c[5] == 0 && c[6] == MLB_KR_MIN);
}

TEST(brdf_set_helpers) {
    mlb_brdf_set s = {0};
    float rows[3 * 7];
    for (int i = 0; i < 21; i++) rows[i] = (float)i / 21.0f;
    REQUIRE(mlb_brdf_set_append(&s, rows, 2) == MLB_OK);
    REQUIRE(mlb_brdf_set_note_source(&s, 0, "first") == MLB_OK);
    float* dst;
    REQUIRE(mlb_brdf_set_extend(&s, 3000, &dst) == MLB_OK);   // forces a regrowth
    for (int i = 0; i < 3000 * 7; i++) dst[i] = 0.25f;
    REQUIRE(mlb_brdf_set_note_source(&s, 2, "second") == MLB_OK);
    CHECK(s.n == 3002 && s.capacity >= 3002);
    CHECK(memcmp(s.k, rows, 14 * sizeof(float)) == 0);
    CHECK(contains(mlb_brdf_set_source_of(&s, 1), "first"));
    CHECK(contains(mlb_brdf_set_source_of(&s, 2), "second"));
    CHECK(contains(mlb_brdf_set_source_of(&s, 3001), "second"));
    CHECK(mlb_brdf_set_source_of(&s, 3002) == NULL);
    mlb_brdf_set_truncate(&s, 1);
    CHECK(s.n == 1 && s.n_sources == 1 && s.sources[0].count == 1);
    CHECK(mlb_brdf_set_note_source(&s, 5, "past the end") == MLB_ERR_ARG);
    mlb_brdf_set_free(&s);
    CHECK(s.k == NULL && s.n == 0 && s.sources == NULL);
}

// ---- procedural distribution ----

TEST(procedural_deterministic) {
    const size_t n = 50000;
    mlb_brdf_set a = {0}, b = {0}, c = {0}, p = {0}, t1 = {0};
    REQUIRE(mlb_brdf_procedural(&a, n, 42) == MLB_OK);
    REQUIRE(mlb_brdf_procedural(&b, n, 42) == MLB_OK);
    REQUIRE(mlb_brdf_procedural(&c, n, 43) == MLB_OK);
    REQUIRE(mlb_brdf_procedural(&p, 1000, 42) == MLB_OK);
    int threads = omp_get_max_threads();
    omp_set_num_threads(1);
    mlb_status s1 = mlb_brdf_procedural(&t1, n, 42);
    omp_set_num_threads(threads);
    REQUIRE(s1 == MLB_OK);
    CHECK(a.n == n && b.n == n);
    CHECK(memcmp(a.k, b.k, n * 7 * sizeof(float)) == 0);
    CHECK(memcmp(a.k, t1.k, n * 7 * sizeof(float)) == 0);   // one thread = many threads, bit for bit
    CHECK(memcmp(a.k, p.k, 1000 * 7 * sizeof(float)) == 0);  // a shorter run is a prefix
    size_t same = 0;
    for (size_t i = 0; i < n * 7; i++) same += a.k[i] == c.k[i];
    CHECK_MSG(same < n * 7 / 20, "seeds 42 and 43 share %zu of %zu values", same, n * 7);
    CHECK(contains(mlb_brdf_set_source_of(&a, 0), "procedural seed=42"));
    // Appending keeps what was there.
    REQUIRE(mlb_brdf_procedural(&p, 500, 7) == MLB_OK);
    CHECK(p.n == 1500 && memcmp(a.k, p.k, 1000 * 7 * sizeof(float)) == 0);
    mlb_brdf_set_free(&a); mlb_brdf_set_free(&b); mlb_brdf_set_free(&c); mlb_brdf_set_free(&p); mlb_brdf_set_free(&t1);
}

static int cmp_float(const void* a, const void* b) {
    float x = *(const float*)a, y = *(const float*)b;
    return (x > y) - (x < y);
}

TEST(procedural_statistics) {
    const size_t n = 200000;
    mlb_brdf_set s = {0};
    uint8_t* cls = malloc(n);
    uint8_t* fam = malloc(n);
    REQUIRE(mlb_brdf_procedural_labeled(&s, n, 2024, cls, fam) == MLB_OK);
    size_t invalid = 0, count[4] = {0}, fam_count[MLB_FAM_COUNT] = {0};
    float lo[7], hi[7];
    for (int c = 0; c < 7; c++) { lo[c] = 1e9f; hi[c] = -1e9f; }
    size_t kr_at_min = 0, kr_at_max = 0;
    for (size_t i = 0; i < n; i++) {
        const float* k = s.k + 7 * i;
        invalid += !mlb_brdf_valid(k);
        count[cls[i]]++;
        fam_count[fam[i]]++;
        for (int c = 0; c < 7; c++) { lo[c] = fminf(lo[c], k[c]); hi[c] = fmaxf(hi[c], k[c]); }
        kr_at_min += k[6] == MLB_KR_MIN;
        kr_at_max += k[6] == 1.0f;
    }
    CHECK(invalid == 0);
    double share[4];
    for (int c = 0; c < 4; c++) share[c] = (double)count[c] / n;
    printf("  classes: dielectric %.3f metal %.3f authored %.3f mixed %.3f\n", share[0], share[1], share[2], share[3]);
    CHECK(share[MLB_MAT_METAL] > 0.10 && share[MLB_MAT_METAL] < 0.30);
    CHECK(share[MLB_MAT_DIELECTRIC] > 0.30 && share[MLB_MAT_DIELECTRIC] < 0.60);
    CHECK(share[MLB_MAT_AUTHORED] > 0.12 && share[MLB_MAT_AUTHORED] < 0.40);
    CHECK(share[MLB_MAT_MIXED] < 0.35);
    for (int f = 0; f < MLB_FAM_COUNT; f++) CHECK_MSG(fam_count[f] > 0, "family %s never appears", mlb_brdf_family_name(f));
    // The whole range is reached, including the clamp point masses real maps show.
    for (int c = 0; c < 6; c++) CHECK_MSG(lo[c] < 0.005f && hi[c] > 0.9f, "channel %d spans [%g, %g]", c, lo[c], hi[c]);
    CHECK(kr_at_min > n / 100 && kr_at_max > n / 200);

    // Pure dielectric pixels: achromatic F0 from real refractive indices (1.33 .. 1.77).
    size_t nd = 0, nd_in = 0, nd_grey = 0;
    // Pure metal pixels: F0 near the measured table. Brightness within [0.55, 1.08] x the table
    // (tarnish darkens to 0.6, tint +-3%), hue kept (per-channel share of the mean within 0.35,
    // tarnish greys by up to 30%), and next to no diffuse.
    size_t nm = 0, nm_in = 0, nm_dark = 0;
    float* ratio = malloc(n * sizeof(float));
    size_t nr = 0;
    double albedo_hist[3] = {0, 0, 0};
    for (size_t i = 0; i < n; i++) {
        const float* k = s.k + 7 * i;
        if (cls[i] == MLB_MAT_DIELECTRIC) {
            nd++;
            nd_in += k[3] >= 0.02f && k[3] <= 0.08f;
            nd_grey += fmaxf(fmaxf(k[3], k[4]), k[5]) - fminf(fminf(k[3], k[4]), k[5]) < 0.005f;
            float a = (k[0] + k[1] + k[2]) / 3;
            albedo_hist[a < 0.05f ? 0 : (a < 0.8f ? 1 : 2)] += 1;
        } else if (cls[i] == MLB_MAT_METAL) {
            float f0[3];
            REQUIRE(mlb_brdf_metal_f0(fam[i], f0));
            nm++;
            float mk = (k[3] + k[4] + k[5]) / 3, mf = (f0[0] + f0[1] + f0[2]) / 3, r = mk / mf;
            int ok = r >= 0.55f && r <= 1.08f;
            for (int c = 0; c < 3; c++) ok &= fabsf(k[3 + c] / mk - f0[c] / mf) < 0.35f;
            ratio[nr++] = r;
            nm_in += ok;
            nm_dark += fmaxf(fmaxf(k[0], k[1]), k[2]) < 0.1f;
        }
    }
    printf("  dielectric F0 in [0.02, 0.08]: %zu / %zu; albedo <0.05 %.3f, 0.05-0.8 %.3f, >0.8 %.3f\n", nd_in, nd,
           albedo_hist[0] / nd, albedo_hist[1] / nd, albedo_hist[2] / nd);
    CHECK(nd > 0 && nd_in >= nd - nd / 1000);
    CHECK(nd_grey >= nd - nd / 1000);
    CHECK(albedo_hist[1] / nd > 0.6 && albedo_hist[0] > 0 && albedo_hist[2] > 0);   // most real albedos are mid-range
    qsort(ratio, nr, sizeof(float), cmp_float);
    printf("  metal F0 / table (mean over rgb): p1 %.3f median %.3f p99 %.3f (%zu pixels, %zu near the table)\n",
           ratio[nr / 100], ratio[nr / 2], ratio[nr * 99 / 100], nm, nm_in);
    CHECK(nm > 0 && nm_in >= nm - nm / 1000);
    CHECK(ratio[nr / 2] > 0.85f && ratio[nr / 2] < 1.02f);
    CHECK(nm_dark >= nm - nm / 1000);
    // Spatial structure: neighbouring samples of one map (rows i, i+1) are much closer than
    // random pairs, as pixels of a real SVBRDF are; independent channels would give ratio ~1.
    double d_map = 0, d_rand = 0;
    size_t pairs = 0;
    for (size_t i = 0; i + 1 < n; i += 97) {
        if ((i + 1) % 128 == 0) continue;
        size_t j = (i * 7919 + 12345) % n;
        for (int c = 0; c < 7; c++) {
            d_map += fabs(s.k[7 * i + c] - s.k[7 * (i + 1) + c]);
            d_rand += fabs(s.k[7 * i + c] - s.k[7 * j + c]);
        }
        pairs++;
    }
    printf("  mean L1 distance: same map %.4f, random pairs %.4f\n", d_map / pairs, d_rand / pairs);
    CHECK(d_map < 0.5 * d_rand);
    free(ratio); free(cls); free(fam); mlb_brdf_set_free(&s);
}


TEST(family_table) {
    float f0[3];
    CHECK(mlb_brdf_metal_f0(MLB_FAM_GOLD, f0) && f0[0] == 1.000f && f0[1] == 0.766f && f0[2] == 0.336f);
    CHECK(mlb_brdf_metal_f0(MLB_FAM_TITANIUM, f0) && f0[2] == 0.449f);
    CHECK(!mlb_brdf_metal_f0(MLB_FAM_WOOD, f0));
    CHECK(mlb_brdf_family_class(MLB_FAM_IRON) == MLB_MAT_METAL);
    CHECK(mlb_brdf_family_class(MLB_FAM_GLASS) == MLB_MAT_DIELECTRIC);
    CHECK(mlb_brdf_family_class(MLB_FAM_AUTHORED) == MLB_MAT_AUTHORED);
    CHECK(mlb_brdf_family_name(MLB_FAM_COUNT) == NULL && !strcmp(mlb_brdf_family_name(MLB_FAM_GOLD), "gold"));
}

// ---- coverage of real maps by the procedural distribution ----

// A small k-d tree over the procedural samples for exact nearest-neighbour distances.
typedef struct { const float* pts; uint32_t* idx; } kdtree;

static const float* kd_pts;
static int kd_dim;
static int kd_cmp(const void* a, const void* b) {
    float x = kd_pts[7 * *(const uint32_t*)a + kd_dim], y = kd_pts[7 * *(const uint32_t*)b + kd_dim];
    return (x > y) - (x < y);
}

// Node = the median of idx[lo, hi) along depth % 7 (implicit: no node storage needed).
static void kd_build(kdtree* t, size_t lo, size_t hi, int depth) {
    if (hi - lo <= 8) return;
    kd_pts = t->pts;
    kd_dim = depth % 7;
    qsort(t->idx + lo, hi - lo, sizeof(uint32_t), kd_cmp);
    size_t mid = lo + (hi - lo) / 2;
    kd_build(t, lo, mid, depth + 1);
    kd_build(t, mid + 1, hi, depth + 1);
}

static void kd_search(const kdtree* t, size_t lo, size_t hi, int depth, const float* q, float* best) {
    if (hi - lo <= 8) {
        for (size_t i = lo; i < hi; i++) {
            const float* p = t->pts + 7 * (size_t)t->idx[i];
            float d = 0;
            for (int c = 0; c < 7; c++) d += (p[c] - q[c]) * (p[c] - q[c]);
            if (d < *best) *best = d;
        }
        return;
    }
    size_t mid = lo + (hi - lo) / 2;
    const float* p = t->pts + 7 * (size_t)t->idx[mid];
    int dim = depth % 7;
    float d = 0;
    for (int c = 0; c < 7; c++) d += (p[c] - q[c]) * (p[c] - q[c]);
    if (d < *best) *best = d;
    float diff = q[dim] - p[dim];
    size_t nlo = diff < 0 ? lo : mid + 1, nhi = diff < 0 ? mid : hi;
    size_t flo = diff < 0 ? mid + 1 : lo, fhi = diff < 0 ? hi : mid;
    kd_search(t, nlo, nhi, depth + 1, q, best);
    if (diff * diff < *best) kd_search(t, flo, fhi, depth + 1, q, best);
}

// The threshold: 0.1 in the 7-d Euclidean metric (every channel off by ~0.04) is well inside what
// an auto-encoder interpolates between neighbours. Measured with 200k procedural samples: the
// 95th percentile of the nearest distance is 0.012 - 0.08 over the six real maps (the blue,
// partly metallic TwoShotBRDF sample 00099_992 is the hardest) and >= 98.5% of pixels are within
// 0.1; 200k independent uniform channels give a median of 0.13 - 0.23 and 0 - 10% within 0.1.
// See docs/materials.md.
#define COVER_RADIUS 0.1f

TEST(procedural_covers_real_maps) {
    const char* shared = test_shared_data();
    if (!shared) SKIP("no shared data");
    static const char* const sets[] = {"twoshotbrdf/00099_990", "twoshotbrdf/00099_991", "twoshotbrdf/00099_992",
                                       "ambientcg_metal", "ambientcg_onyx", "deschaintre/10_brick_uneven_stones.png"};
    char root[4096];
    snprintf(root, sizeof root, "%s/svbrdf", shared);
    if (!is_dir_path(root)) SKIP("no svbrdf folder in shared data");
    const size_t np = 200000;
    mlb_brdf_set proc = {0};
    REQUIRE(mlb_brdf_procedural(&proc, np, 12345) == MLB_OK);
    kdtree t = {proc.k, malloc(np * sizeof(uint32_t))};
    for (size_t i = 0; i < np; i++) t.idx[i] = (uint32_t)i;
    kd_build(&t, 0, np, 0);
    for (size_t s = 0; s < sizeof sets / sizeof sets[0]; s++) {
        mlb_brdf_set real = {0};
        mlb_brdf_load_options o = {2000, 9, 0.0f};
        mlb_status st = mlb_brdf_load_path(&real, path2(root, sets[s]), &o);
        CHECK_MSG(st == MLB_OK, "%s", mlb_last_error());
        if (st != MLB_OK) continue;
        float* d = malloc(real.n * sizeof(float));
        size_t within = 0;
        for (size_t i = 0; i < real.n; i++) {
            float best = 1e30f;
            kd_search(&t, 0, np, 0, real.k + 7 * i, &best);
            d[i] = sqrtf(best);
            within += d[i] <= COVER_RADIUS;
        }
        qsort(d, real.n, sizeof(float), cmp_float);
        double frac = (double)within / real.n;
        printf("  %-40s %5zu px: nearest procedural p50 %.4f p95 %.4f max %.4f, within %.2f: %.1f%%\n", sets[s], real.n,
               d[real.n / 2], d[real.n * 95 / 100], d[real.n - 1], COVER_RADIUS, 100 * frac);
        CHECK(frac >= 0.95);
        CHECK(d[real.n / 2] < 0.06f);
        free(d); mlb_brdf_set_free(&real);
    }
    free(t.idx); mlb_brdf_set_free(&proc);
}

// ---- loaders on the real shared maps ----

static const char* svbrdf_root(void) {
    static char root[4096];
    const char* shared = test_shared_data();
    if (!shared) return NULL;
    snprintf(root, sizeof root, "%s/svbrdf", shared);
    return is_dir_path(root) ? root : NULL;
}

static int rows_all_valid(const mlb_brdf_set* s, size_t from) {
    for (size_t i = from; i < s->n; i++)
        if (!mlb_brdf_valid(s->k + 7 * i)) return 0;
    return 1;
}

TEST(load_twoshot_real) {
    const char* root = svbrdf_root();
    if (!root) SKIP("no shared svbrdf data");
    static const char* const samples[] = {"00099_990", "00099_991", "00099_992"};
    for (int s = 0; s < 3; s++) {
        char folder[4096];
        snprintf(folder, sizeof folder, "%s/twoshotbrdf/%s", root, samples[s]);
        // Expected count from the mask itself: grey in RGB, alpha a constant 255.
        mlb_image m, d, sp, r;
        REQUIRE(mlb_image_load(&m, path2(folder, "mask.png"), 0) == MLB_OK);
        REQUIRE(m.c == 4 && m.w == 256 && m.h == 256);
        size_t expect = 0, expect_half = 0, first = (size_t)-1;
        for (size_t i = 0; i < (size_t)m.w * m.h; i++) {
            expect += m.data[4 * i] > 0;
            expect_half += m.data[4 * i] > 0.5f;
            if (m.data[4 * i] > 0 && first == (size_t)-1) first = i;
            CHECK(m.data[4 * i + 3] == 1.0f);
        }
        mlb_brdf_set all = {0};
        REQUIRE(mlb_brdf_load_path(&all, folder, NULL) == MLB_OK);
        CHECK_MSG(all.n == expect, "%s: %zu rows, mask has %zu nonzero", samples[s], all.n, expect);
        CHECK(expect < (size_t)m.w * m.h && expect > 30000);
        CHECK(rows_all_valid(&all, 0));
        CHECK(contains(mlb_brdf_set_source_of(&all, 0), samples[s]));
        // The first masked-in pixel, decoded by hand.
        REQUIRE(mlb_image_load(&d, path2(folder, "diffuse.png"), 3) == MLB_OK);
        REQUIRE(mlb_image_load(&sp, path2(folder, "specular.png"), 3) == MLB_OK);
        REQUIRE(mlb_image_load(&r, path2(folder, "roughness.png"), 1) == MLB_OK);
        for (int c = 0; c < 3; c++) {
            CHECK_CLOSE(all.k[c], mlb_srgb_to_linear(d.data[3 * first + c]), 1e-6, 1e-7);
            CHECK_CLOSE(all.k[3 + c], mlb_srgb_to_linear(sp.data[3 * first + c]), 1e-6, 1e-7);
        }
        CHECK_CLOSE(all.k[6], fmaxf(r.data[first], MLB_KR_MIN), 1e-6, 0);
        // A higher mask threshold keeps fewer pixels.
        mlb_brdf_set half = {0};
        mlb_brdf_load_options oh = {0, 0, 0.5f};
        REQUIRE(mlb_brdf_load_path(&half, folder, &oh) == MLB_OK);
        CHECK(half.n == expect_half && half.n < all.n);
        // Subsampling: exactly max_pixels_per_map rows, each one a row of the full load, in
        // order; deterministic in the seed, different for another seed.
        mlb_brdf_load_options o = {1000, 77, 0};
        mlb_brdf_set sub = {0}, sub2 = {0}, sub3 = {0};
        REQUIRE(mlb_brdf_load_path(&sub, folder, &o) == MLB_OK);
        REQUIRE(mlb_brdf_load_path(&sub2, folder, &o) == MLB_OK);
        o.seed = 78;
        REQUIRE(mlb_brdf_load_path(&sub3, folder, &o) == MLB_OK);
        CHECK(sub.n == 1000 && sub3.n == 1000);
        CHECK(memcmp(sub.k, sub2.k, 1000 * 7 * sizeof(float)) == 0);
        CHECK(memcmp(sub.k, sub3.k, 1000 * 7 * sizeof(float)) != 0);
        size_t j = 0, matched = 0;
        for (size_t i = 0; i < sub.n && j < all.n; i++) {
            while (j < all.n && memcmp(all.k + 7 * j, sub.k + 7 * i, 7 * sizeof(float)) != 0) j++;
            if (j < all.n) { matched++; j++; }
        }
        CHECK(matched == sub.n);
        mlb_image_free(&m); mlb_image_free(&d); mlb_image_free(&sp); mlb_image_free(&r); mlb_brdf_set_free(&all);
        mlb_brdf_set_free(&half); mlb_brdf_set_free(&sub); mlb_brdf_set_free(&sub2); mlb_brdf_set_free(&sub3);
    }
}

TEST(load_pbr_real) {
    const char* root = svbrdf_root();
    if (!root) SKIP("no shared svbrdf data");
    char metal[4096], onyx[4096];
    snprintf(metal, sizeof metal, "%s/ambientcg_metal", root);
    snprintf(onyx, sizeof onyx, "%s/ambientcg_onyx", root);
    mlb_brdf_set s = {0};
    REQUIRE(mlb_brdf_load_path(&s, metal, NULL) == MLB_OK);
    CHECK(s.n == 1024 * 1024);
    CHECK(rows_all_valid(&s, 0));
    mlb_image base, met, rough;
    REQUIRE(mlb_image_load(&base, path2(metal, "albedo.jpg"), 3) == MLB_OK);
    REQUIRE(mlb_image_load(&met, path2(metal, "metallic.jpg"), 1) == MLB_OK);
    REQUIRE(mlb_image_load(&rough, path2(metal, "roughness.jpg"), 1) == MLB_OK);
    // The metallic formula, pixel by pixel on a spread of pixels.
    double worst = 0, ks_mean = 0, kd_mean = 0;
    for (size_t i = 0; i < s.n; i += 997) {
        float m = met.data[i];
        for (int c = 0; c < 3; c++) {
            float b = mlb_srgb_to_linear(base.data[3 * i + c]);
            worst = fmax(worst, fabs(s.k[7 * i + c] - b * (1 - m)));
            worst = fmax(worst, fabs(s.k[7 * i + 3 + c] - (0.04f * (1 - m) + b * m)));
        }
        worst = fmax(worst, fabs(s.k[7 * i + 6] - fmaxf(rough.data[i], MLB_KR_MIN)));
    }
    CHECK_MSG(worst < 1e-5, "metallic formula off by %g", worst);
    for (size_t i = 0; i < s.n; i++) {
        kd_mean += (s.k[7 * i] + s.k[7 * i + 1] + s.k[7 * i + 2]) / 3;
        ks_mean += (s.k[7 * i + 3] + s.k[7 * i + 4] + s.k[7 * i + 5]) / 3;
    }
    kd_mean /= s.n;
    ks_mean /= s.n;
    printf("  ambientcg_metal: mean kd %.4f, mean ks %.4f\n", kd_mean, ks_mean);
    CHECK(kd_mean < 0.01 && ks_mean > 0.4);   // a metal: F0 from the base colour, no diffuse
    mlb_image_free(&base); mlb_image_free(&met); mlb_image_free(&rough);
    // No metallic map: every pixel a dielectric with F0 0.04.
    size_t n0 = s.n;
    REQUIRE(mlb_brdf_load_path(&s, onyx, NULL) == MLB_OK);
    CHECK(s.n == n0 + 1024 * 1024);
    int all_004 = 1;
    for (size_t i = n0; i < s.n; i++)
        for (int c = 3; c < 6; c++) all_004 &= s.k[7 * i + c] == 0.04f;
    CHECK(all_004);
    CHECK(s.n_sources == 2 && contains(mlb_brdf_set_source_of(&s, n0), "ambientcg_onyx"));
    mlb_brdf_set_free(&s);
}

TEST(load_tiles_real) {
    const char* root = svbrdf_root();
    if (!root) SKIP("no shared svbrdf data");
    char file[4096];
    snprintf(file, sizeof file, "%s/deschaintre/10_brick_uneven_stones.png", root);
    mlb_brdf_set s = {0};
    REQUIRE(mlb_brdf_load_path(&s, file, NULL) == MLB_OK);
    CHECK(s.n == 512 * 512);
    CHECK(rows_all_valid(&s, 0));
    mlb_image im;
    REQUIRE(mlb_image_load(&im, file, 3) == MLB_OK);
    REQUIRE(im.w == 2048 && im.h == 512);
    int x = 300, y = 123;
    size_t row = (size_t)y * 512 + x;
    for (int c = 0; c < 3; c++) {
        CHECK_CLOSE(s.k[7 * row + c], mlb_srgb_to_linear(mlb_image_at(&im, 512 + x, y, c)), 1e-6, 1e-7);
        CHECK_CLOSE(s.k[7 * row + 3 + c], mlb_srgb_to_linear(mlb_image_at(&im, 1536 + x, y, c)), 1e-6, 1e-7);
    }
    CHECK_CLOSE(s.k[7 * row + 6], fmaxf(mlb_image_at(&im, 1024 + x, y, 0), MLB_KR_MIN), 1e-6, 0);
    mlb_brdf_set sub = {0};
    mlb_brdf_load_options o = {5000, 1, 0};
    REQUIRE(mlb_brdf_load_path(&sub, file, &o) == MLB_OK);
    CHECK(sub.n == 5000);
    mlb_image_free(&im); mlb_brdf_set_free(&s); mlb_brdf_set_free(&sub);
}

TEST(load_folder_recursive_real) {
    const char* root = svbrdf_root();
    if (!root) SKIP("no shared svbrdf data");
    mlb_brdf_set s = {0};
    mlb_brdf_load_options o = {300, 3, 0};
    REQUIRE(mlb_brdf_load_path(&s, root, &o) == MLB_OK);
    // 6 maps in sorted order: ambientcg_metal, ambientcg_onyx, deschaintre, three TwoShotBRDF.
    CHECK(s.n == 6 * 300 && s.n_sources == 6);
    if (s.n_sources == 6) {
        CHECK(contains(s.sources[0].name, "ambientcg_metal"));
        CHECK(contains(s.sources[2].name, "10_brick_uneven_stones.png"));
        CHECK(contains(s.sources[5].name, "00099_992"));
    }
    CHECK(rows_all_valid(&s, 0));
    mlb_brdf_set again = {0};
    REQUIRE(mlb_brdf_load_path(&again, root, &o) == MLB_OK);
    CHECK(again.n == s.n && memcmp(again.k, s.k, s.n * 7 * sizeof(float)) == 0);
    mlb_brdf_set_free(&s); mlb_brdf_set_free(&again);
}

// ---- loaders and image reading on inputs built here ----

// A TwoShotBRDF-style folder of w x h maps; `skip` names a file to leave out.
static void make_twoshot(const char* dir, int w, int h, const char* skip) {
    mkdir_p(dir);
    static const char* const names[4] = {"diffuse.png", "specular.png", "roughness.png", "mask.png"};
    for (int i = 0; i < 4; i++) {
        if (skip && !strcmp(skip, names[i])) continue;
        unsigned char* p = pattern8(w, h, 4, i);
        if (i == 3)
            for (int j = 0; j < w * h; j++) { p[4 * j] = p[4 * j + 1] = p[4 * j + 2] = (j % 3) ? 255 : 0; p[4 * j + 3] = 255; }
        write_png(path2(dir, names[i]), (uint32_t)w, (uint32_t)h, 4, 8, p);
        free(p);
    }
}

static void expect_error(const char* what, mlb_status got, mlb_status want, const char* sub1, const char* sub2) {
    const char* msg = mlb_last_error();
    CHECK_MSG(got == want, "%s: status %s, expected %s (%s)", what, mlb_status_name(got), mlb_status_name(want), msg);
    CHECK_MSG(contains(msg, sub1), "%s: message '%s' lacks '%s'", what, msg, sub1);
    if (sub2) CHECK_MSG(contains(msg, sub2), "%s: message '%s' lacks '%s'", what, msg, sub2);
}

TEST(loader_bad_inputs) {
    const char* tmp = test_tmpdir("brdf_data_bad");
    REQUIRE(tmp);
    char base[4096];
    snprintf(base, sizeof base, "%s", tmp);
    mlb_brdf_set s = {0};
    // Something already in the set: a failed load must leave it untouched.
    REQUIRE(mlb_brdf_procedural(&s, 10, 1) == MLB_OK);

    char good[4096], miss[4096], mism[4096], trunc_dir[4096], text_dir[4096], empty[4096], zero[4096], pbr[4096];
    snprintf(good, sizeof good, "%s/good", base);
    make_twoshot(good, 6, 5, NULL);
    REQUIRE(mlb_brdf_load_path(&s, good, NULL) == MLB_OK);
    CHECK(s.n == 10 + 20);   // 2 of every 3 mask pixels are 255
    CHECK(rows_all_valid(&s, 0));
    size_t n_before = s.n;

    snprintf(miss, sizeof miss, "%s/missing_specular", base);
    make_twoshot(miss, 6, 5, "specular.png");
    expect_error("missing specular", mlb_brdf_load_path(&s, miss, NULL), MLB_ERR_NOT_FOUND, "missing_specular/specular.png",
                 "missing");

    snprintf(mism, sizeof mism, "%s/mismatch", base);
    make_twoshot(mism, 6, 5, NULL);
    unsigned char* p = pattern8(4, 4, 4, 9);
    write_png(path2(mism, "roughness.png"), 4, 4, 4, 8, p);
    free(p);
    expect_error("mismatched sizes", mlb_brdf_load_path(&s, mism, NULL), MLB_ERR_FORMAT, "mismatch/roughness.png",
                 "mismatch/diffuse.png");

    snprintf(trunc_dir, sizeof trunc_dir, "%s/truncated", base);
    make_twoshot(trunc_dir, 64, 64, NULL);
    const char* tpath = path2(trunc_dir, "specular.png");
    REQUIRE(truncate_file(tpath, 1, 2));
    expect_error("truncated png", mlb_brdf_load_path(&s, trunc_dir, NULL), MLB_ERR_FORMAT, "truncated/specular.png",
                 "truncated PNG");

    snprintf(text_dir, sizeof text_dir, "%s/text", base);
    make_twoshot(text_dir, 6, 5, NULL);
    REQUIRE(write_text(path2(text_dir, "diffuse.png"), "this is not a picture\n"));
    expect_error("text as png", mlb_brdf_load_path(&s, text_dir, NULL), MLB_ERR_UNSUPPORTED, "text/diffuse.png",
                 "not an image");

    snprintf(empty, sizeof empty, "%s/empty", base);
    mkdir_p(empty);
    expect_error("empty folder", mlb_brdf_load_path(&s, empty, NULL), MLB_ERR_NOT_FOUND, "empty: no material maps found",
                 "diffuse.png, specular.png, roughness.png");

    snprintf(zero, sizeof zero, "%s/all_masked", base);
    make_twoshot(zero, 6, 5, NULL);
    p = calloc(6 * 5 * 4, 1);
    write_png(path2(zero, "mask.png"), 6, 5, 4, 8, p);
    free(p);
    expect_error("all masked", mlb_brdf_load_path(&s, zero, NULL), MLB_ERR_NOT_FOUND, "all_masked", "no valid pixels");

    snprintf(pbr, sizeof pbr, "%s/pbr_no_rough", base);
    mkdir_p(pbr);
    p = pattern8(4, 4, 3, 1);
    write_png(path2(pbr, "Wood_BaseColor.png"), 4, 4, 3, 8, p);
    free(p);
    expect_error("pbr without roughness", mlb_brdf_load_path(&s, pbr, NULL), MLB_ERR_NOT_FOUND, "pbr_no_rough",
                 "roughness");

    expect_error("missing path", mlb_brdf_load_path(&s, path2(base, "nope"), NULL), MLB_ERR_IO, "nope", "no such");

    p = pattern8(12, 4, 3, 2);
    write_png(path2(base, "not_tiles.png"), 12, 4, 3, 8, p);
    free(p);
    expect_error("wrong tile aspect", mlb_brdf_load_path(&s, path2(base, "not_tiles.png"), NULL), MLB_ERR_FORMAT,
                 "not_tiles.png", "4 square tiles");

    // A folder of folders fails as a whole when one sample is broken, naming that file.
    // (all_masked sorts first but holds no valid pixel, which is fine for one map among many;
    // empty holds nothing; mismatch is the first real error.)
    expect_error("recursive with a broken sample", mlb_brdf_load_path(&s, base, NULL), MLB_ERR_FORMAT,
                 "mismatch/roughness.png", NULL);
    CHECK(s.n == n_before && s.n_sources == 2);
    mlb_brdf_set_free(&s);
}

TEST(loader_synthetic_layouts) {
    const char* tmp = test_tmpdir("brdf_data_layouts");
    REQUIRE(tmp);
    char base[4096], pbr[4096], nest[4096];
    snprintf(base, sizeof base, "%s", tmp);
    // Metallic/roughness set with ambientCG-style names and exact known values.
    snprintf(pbr, sizeof pbr, "%s/set/Metal01_2K_Color_dir", base);
    mkdir_p(pbr);
    unsigned char col[2 * 3] = {255, 128, 0, 64, 64, 64}, met[2] = {255, 0}, rough[2] = {10, 200};
    write_png(path2(pbr, "Metal01_2K_Color.png"), 2, 1, 3, 8, col);
    write_png(path2(pbr, "Metal01_2K_Metalness.png"), 2, 1, 1, 8, met);
    write_png(path2(pbr, "Metal01_2K_Roughness.png"), 2, 1, 1, 8, rough);
    write_png(path2(pbr, "Metal01_2K_NormalGL.png"), 2, 1, 3, 8, col);   // ignored
    // A 4-tile image next to it, one folder deeper.
    snprintf(nest, sizeof nest, "%s/set/tiles", base);
    mkdir_p(nest);
    unsigned char* t = pattern8(8, 2, 3, 5);
    write_png(path2(nest, "a.png"), 8, 2, 3, 8, t);
    write_png(path2(nest, "preview.png"), 3, 2, 3, 8, t);   // not 4:1, skipped while searching
    char set[4096];
    snprintf(set, sizeof set, "%s/set", base);
    write_png(path2(set, "color_chart.png"), 3, 2, 3, 8, t);   // a "colour" name beside folders: still a search
    mlb_brdf_set s = {0};
    REQUIRE(mlb_brdf_load_path(&s, set, NULL) == MLB_OK);
    CHECK(s.n == 2 + 4 && s.n_sources == 2);
    if (s.n == 6) {
        // Pixel 0: metal, base (1, 0.2158, 0): kd 0, ks = base. Pixel 1: dielectric grey.
        float g = mlb_srgb_to_linear(64 / 255.0f);
        CHECK(s.k[0] == 0 && s.k[1] == 0 && s.k[2] == 0);
        CHECK_CLOSE(s.k[3], 1.0, 0, 1e-6);
        CHECK_CLOSE(s.k[4], mlb_srgb_to_linear(128 / 255.0f), 1e-5, 0);
        CHECK_CLOSE(s.k[6], MLB_KR_MIN, 0, 0);   // 10/255 clamped up
        CHECK_CLOSE(s.k[7], g, 1e-5, 0);
        CHECK_CLOSE(s.k[10], 0.04, 1e-6, 0);
        CHECK_CLOSE(s.k[13], 200 / 255.0, 1e-6, 0);
        // Tile pixel (0, 0): diffuse from x = 2, roughness x = 4, specular x = 6.
        const float* k = s.k + 7 * 2;
        CHECK_CLOSE(k[0], mlb_srgb_to_linear(t[(0 * 8 + 2) * 3] / 255.0f), 1e-5, 1e-7);
        CHECK_CLOSE(k[3], mlb_srgb_to_linear(t[(0 * 8 + 6) * 3] / 255.0f), 1e-5, 1e-7);
        CHECK_CLOSE(k[6], fmaxf(t[(0 * 8 + 4) * 3] / 255.0f, MLB_KR_MIN), 1e-6, 0);
    }
    free(t);
    // Two candidates for one role is an error, not a guess.
    write_png(path2(pbr, "Metal01_2K_Color_copy.png"), 2, 1, 3, 8, col);
    size_t n0 = s.n;
    expect_error("ambiguous base colour", mlb_brdf_load_path(&s, set, NULL), MLB_ERR_FORMAT, "ambiguous", "Color_copy.png");
    CHECK(s.n == n0);
    mlb_brdf_set_free(&s);
}

TEST(image_loading) {
    const char* tmp = test_tmpdir("brdf_data_image");
    REQUIRE(tmp);
    char dir[4096];
    snprintf(dir, sizeof dir, "%s", tmp);
    mlb_image im;
    // 16-bit grey+alpha PNG: samples / 65535 exactly.
    uint16_t px16[3 * 2 * 2];
    for (int i = 0; i < 12; i++) px16[i] = (uint16_t)(i * 5957 + 1);
    REQUIRE(write_png(path2(dir, "g16.png"), 3, 2, 2, 16, px16));
    REQUIRE(mlb_image_load(&im, path2(dir, "g16.png"), 0) == MLB_OK);
    CHECK(im.w == 3 && im.h == 2 && im.c == 2 && im.bits == 16 && im.file_channels == 2);
    int exact = 1;
    for (int i = 0; i < 12; i++) exact &= fabsf(im.data[i] - px16[i] / 65535.0f) < 1e-7f;
    CHECK(exact);
    mlb_image_free(&im);
    // Channel conversion: grey -> RGBA replicates and adds opaque alpha.
    REQUIRE(mlb_image_load(&im, path2(dir, "g16.png"), 4) == MLB_OK);
    CHECK(im.c == 4 && im.data[0] == im.data[1] && im.data[1] == im.data[2]);
    mlb_image_free(&im);
    // 8-bit RGB, and info.
    unsigned char* p8 = pattern8(5, 4, 3, 3);
    REQUIRE(write_png(path2(dir, "rgb8.png"), 5, 4, 3, 8, p8));
    int w, h, c, bits;
    REQUIRE(mlb_image_info(path2(dir, "rgb8.png"), &w, &h, &c, &bits) == MLB_OK);
    CHECK(w == 5 && h == 4 && c == 3 && bits == 8);
    REQUIRE(mlb_image_load(&im, path2(dir, "rgb8.png"), 0) == MLB_OK);
    CHECK(im.c == 3 && im.data[7] == p8[7] / 255.0f && mlb_image_at(&im, 4, 3, 2) == p8[(3 * 5 + 4) * 3 + 2] / 255.0f);
    mlb_image_free(&im);
    // JPEG through stb_image_write: loads, and a truncated copy is refused.
    unsigned char* big = pattern8(64, 48, 3, 1);
    REQUIRE(stbi_write_jpg(path2(dir, "a.jpg"), 64, 48, 3, big, 90));
    REQUIRE(mlb_image_load(&im, path2(dir, "a.jpg"), 0) == MLB_OK);
    CHECK(im.w == 64 && im.h == 48 && im.c == 3);
    mlb_image_free(&im);
    REQUIRE(stbi_write_jpg(path2(dir, "cut.jpg"), 64, 48, 3, big, 90));
    REQUIRE(truncate_file(path2(dir, "cut.jpg"), 2, 3));
    expect_error("truncated jpeg", mlb_image_load(&im, path2(dir, "cut.jpg"), 0), MLB_ERR_FORMAT, "cut.jpg", "truncated JPEG");
    free(big);
    // A flipped byte inside the compressed data: the CRC catches it.
    REQUIRE(write_png(path2(dir, "flip.png"), 5, 4, 3, 8, p8));
    FILE* f = fopen(path2(dir, "flip.png"), "r+b");
    REQUIRE(f);
    fseek(f, 8 + 25 + 10, SEEK_SET);   // past the signature and IHDR, into IDAT
    int byte = fgetc(f);
    fseek(f, -1, SEEK_CUR);
    fputc(byte ^ 0x55, f);
    fclose(f);
    expect_error("flipped byte", mlb_image_load(&im, path2(dir, "flip.png"), 0), MLB_ERR_FORMAT, "flip.png", "CRC");
    free(p8);
    // Zero size and huge size come from the header alone.
    REQUIRE(write_png(path2(dir, "zero.png"), 0, 7, 3, 8, NULL));
    expect_error("zero size", mlb_image_load(&im, path2(dir, "zero.png"), 0), MLB_ERR_FORMAT, "zero.png", "zero size");
    REQUIRE(write_png(path2(dir, "huge.png"), 100000, 100000, 4, 8, NULL));
    expect_error("huge", mlb_image_load(&im, path2(dir, "huge.png"), 0), MLB_ERR_ARG, "huge.png", "exceeds the limit");
    CHECK(im.data == NULL);
    REQUIRE(write_png(path2(dir, "small.png"), 16, 16, 1, 8, (unsigned char[256]){0}));
    expect_error("limit", mlb_image_load_limit(&im, path2(dir, "small.png"), 0, 100), MLB_ERR_ARG, "small.png",
                 "256 pixels");
    CHECK(mlb_image_load_limit(&im, path2(dir, "small.png"), 0, 256) == MLB_OK);
    mlb_image_free(&im);
    // Not images at all.
    REQUIRE(write_text(path2(dir, "notes.png"), "hello\n"));
    expect_error("text", mlb_image_load(&im, path2(dir, "notes.png"), 0), MLB_ERR_UNSUPPORTED, "notes.png", "looks like text");
    REQUIRE(write_text(path2(dir, "empty.png"), ""));
    expect_error("empty", mlb_image_load(&im, path2(dir, "empty.png"), 0), MLB_ERR_FORMAT, "empty.png", "empty file");
    expect_error("missing", mlb_image_load(&im, path2(dir, "absent.png"), 0), MLB_ERR_IO, "absent.png", "No such file");
    expect_error("folder", mlb_image_load(&im, dir, 0), MLB_ERR_IO, dir, NULL);
    expect_error("channels", mlb_image_load(&im, path2(dir, "rgb8.png"), 5), MLB_ERR_ARG, "rgb8.png", "channels");
    mlb_image_free(&im);
    mlb_image_free(&im);   // twice is fine
}

int main(void) {
    RUN(srgb_known_values);
    RUN(srgb_round_trip);
    RUN(brdf_validity);
    RUN(brdf_set_helpers);
    RUN(family_table);
    RUN(procedural_deterministic);
    RUN(procedural_statistics);
    RUN(procedural_covers_real_maps);
    RUN(load_twoshot_real);
    RUN(load_pbr_real);
    RUN(load_tiles_real);
    RUN(load_folder_recursive_real);
    RUN(loader_bad_inputs);
    RUN(loader_synthetic_layouts);
    RUN(image_loading);
    return test_summary();
}
