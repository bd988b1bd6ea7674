// Image writers: PNG 8/16-bit round trips through mlb_image_load (exact codes, as-is and sRGB),
// Radiance .hdr through stb_image's stbi_loadf (RGBE precision, RLE and flat scanlines), OpenEXR
// through tinyexr's readers (half and float, every channel count), and the failure cases: bad
// arguments, a missing or unwritable folder, a target that cannot be replaced — each with the path
// in the message and no file or temporary left behind.
#include "test.h"
#include <dirent.h>
#include <stdint.h>
#include <unistd.h>
#include <stb/stb_image.h>
#include <tinyexr.h>
#include "matlaber/half.h"
#include "matlaber/image.h"
#include "matlaber/image_write.h"
#include "matlaber/rng.h"

static const char* tmp;

// Files in the scratch folder whose name contains `part`.
static int count_files(const char* part) {
    DIR* d = opendir(tmp);
    if (!d) return -1;
    int n = 0;
    struct dirent* e;
    while ((e = readdir(d))) n += strstr(e->d_name, part) != NULL;
    closedir(d);
    return n;
}

static int exists(const char* path) {
    struct stat st;
    return stat(path, &st) == 0;
}

// A test image: random values in [-0.25, 1.25] plus exact codes, NaN and extremes.
static float* make_ldr(int w, int h, int c, uint64_t seed, unsigned maxv) {
    size_t n = (size_t)w * h * c;
    float* d = malloc(n * sizeof(float));
    if (!d) return NULL;
    for (size_t i = 0; i < n; i++) {
        double u = mlb_rng_uniform(seed, 0, i);
        switch (i % 5) {
        case 0: d[i] = (float)(u * 1.5 - 0.25); break;
        case 1: d[i] = (float)floor(u * (maxv + 1)) / (float)maxv; break;   // exact codes
        default: d[i] = (float)u; break;
        }
    }
    d[0] = NAN;
    d[n - 1] = INFINITY;
    if (n > 2) d[1] = -INFINITY;
    if (n > 3) d[2] = 1.0f;
    return d;
}

static double srgb(double x) { return x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1 / 2.4) - 0.055; }

// The code the documentation promises for sample v.
static unsigned expected_code(float v, int encode, unsigned maxv) {
    double x = v;
    if (isnan(x) || x <= 0) x = 0;
    if (x > 1) x = 1;
    if (encode) x = srgb(x);
    return (unsigned)floor(x * maxv + 0.5);
}

static void png_roundtrip(int bits, mlb_png_encoding enc) {
    unsigned maxv = bits == 16 ? 65535u : 255u;
    const int sizes[][2] = {{37, 23}, {1, 1}, {300, 2}};
    for (int s = 0; s < 3; s++)
        for (int c = 1; c <= 4; c++) {
            int w = sizes[s][0], h = sizes[s][1];
            float* d = make_ldr(w, h, c, (uint64_t)(bits * 100 + c * 10 + s), maxv);
            REQUIRE(d);
            char path[4200];
            snprintf(path, sizeof path, "%s/rt_%d_%d_%d_%d.png", tmp, bits, (int)enc, c, s);
            mlb_png_options opt = {bits, enc};
            mlb_status st = mlb_image_write_png(path, d, w, h, c, &opt);
            CHECK_MSG(st == MLB_OK, "%s", mlb_last_error());
            mlb_image img = {0};
            st = mlb_image_load(&img, path, 0);
            CHECK_MSG(st == MLB_OK, "%s", mlb_last_error());
            if (st != MLB_OK) { free(d); return; }
            CHECK(img.w == w && img.h == h && img.c == c && img.file_channels == c && img.bits == bits);
            int bad = 0;
            for (size_t i = 0; i < (size_t)w * h * c; i++) {
                int is_alpha = (c == 2 || c == 4) && (int)(i % c) == c - 1;
                unsigned q = expected_code(d[i], enc == MLB_PNG_SRGB && !is_alpha, maxv);
                if (img.data[i] != (float)q / (float)maxv && bad++ < 3)
                    printf("  %d bits c=%d sample %zu: wrote %.9g, read %.9g, expected code %u\n", bits, c, i, d[i],
                           img.data[i], q);
            }
            CHECK(bad == 0);
            mlb_image_free(&img);
            free(d);
        }
}

TEST(png8_as_is) { png_roundtrip(8, MLB_PNG_AS_IS); }
TEST(png16_as_is) { png_roundtrip(16, MLB_PNG_AS_IS); }
TEST(png8_srgb) { png_roundtrip(8, MLB_PNG_SRGB); }
TEST(png16_srgb) { png_roundtrip(16, MLB_PNG_SRGB); }

// Known values of the sRGB curve, colour-space chunks, the default options.
TEST(png_srgb_anchors_and_chunks) {
    // RGBA pixels: linear 0.5 -> 188, 0.18 -> 118, 0.0031308 -> 12.92*0.0031308*255 = 10.3 -> 10;
    // alpha stays linear: 0.5 -> 127.5 -> 128 (halves round up)
    const float px[8] = {0.5f, 0.18f, 0.0031308f, 0.5f, 1.0f, 0.0f, 0.04f, 1.0f};
    char path[4200], raw[4200];
    snprintf(path, sizeof path, "%s/anchors.png", tmp);
    mlb_png_options opt = {8, MLB_PNG_SRGB};
    REQUIRE(mlb_image_write_png(path, px, 2, 1, 4, &opt) == MLB_OK);
    int w, h, c;
    unsigned char* b = stbi_load(path, &w, &h, &c, 4);
    REQUIRE(b);
    // 0.04 -> 1.055 * 0.04^(1/2.4) - 0.055 = 0.2200 -> 56.1 -> 56
    const unsigned char want[8] = {188, 118, 10, 128, 255, 0, 56, 255};
    for (int i = 0; i < 8; i++) CHECK_MSG(b[i] == want[i], "byte %d: %d, expected %d", i, b[i], want[i]);
    stbi_image_free(b);
    // an sRGB chunk when encoding, none when writing as is (and 8-bit as-is is the default)
    FILE* f = fopen(path, "rb");
    REQUIRE(f);
    char buf[4096];
    size_t n = fread(buf, 1, sizeof buf, f);
    fclose(f);
    CHECK(memmem(buf, n, "sRGB", 4) != NULL);
    snprintf(raw, sizeof raw, "%s/asis.png", tmp);
    REQUIRE(mlb_image_write_png(raw, px, 2, 1, 4, NULL) == MLB_OK);
    f = fopen(raw, "rb");
    REQUIRE(f);
    n = fread(buf, 1, sizeof buf, f);
    fclose(f);
    CHECK(memmem(buf, n, "sRGB", 4) == NULL && memmem(buf, n, "gAMA", 4) == NULL);
    CHECK(buf[24] == 8);   // IHDR bit depth
    // 16-bit samples are stored big-endian: 0x1234 comes back as 0x1234
    float v = (float)0x1234 / 65535.0f;
    snprintf(raw, sizeof raw, "%s/be.png", tmp);
    opt = (mlb_png_options){16, MLB_PNG_AS_IS};
    REQUIRE(mlb_image_write_png(raw, &v, 1, 1, 1, &opt) == MLB_OK);
    stbi_us* s = stbi_load_16(raw, &w, &h, &c, 1);
    REQUIRE(s);
    CHECK(s[0] == 0x1234);
    stbi_image_free(s);
}

// ---- HDR ----

static void hdr_check(int w, int h, int c, const float* d, const char* name) {
    char path[4200];
    snprintf(path, sizeof path, "%s/%s", tmp, name);
    mlb_status st = mlb_image_write_hdr(path, d, w, h, c);
    CHECK_MSG(st == MLB_OK, "%s", mlb_last_error());
    if (st != MLB_OK) return;
    CHECK(stbi_is_hdr(path));
    int rw, rh, rc;
    float* r = stbi_loadf(path, &rw, &rh, &rc, 3);
    CHECK_MSG(r != NULL, "stbi_loadf: %s", stbi_failure_reason());
    if (!r) return;
    CHECK(rw == w && rh == h && rc == 3);
    int bad = 0;
    for (size_t p = 0; p < (size_t)w * h; p++) {
        float in[3];
        for (int k = 0; k < 3; k++) {
            float v = d[p * c + (c >= 3 ? k : 0)];
            in[k] = !(v > 0) ? 0.0f : (v > 1e38f ? 1e38f : v);   // NaN, negative -> 0; clamp
        }
        float mx = fmaxf(in[0], fmaxf(in[1], in[2]));
        for (int k = 0; k < 3; k++) {
            float got = r[3 * p + k];
            // within RGBE precision: stb_image decodes m * 2^(e-136) without Radiance's half step,
            // so it reads at most one step (< max / 128) low, never high
            int ok = got <= in[k] && in[k] - got <= mx / 128.0f;
            // and exactly Radiance's mantissa: floor(v * 2^(8-e)) with max = f * 2^e, f in [0.5, 1)
            if (mx >= 1e-32f) {
                int e;
                frexp(mx, &e);
                float want = (float)floor(in[k] * ldexp(1.0, 8 - e)) * (float)ldexp(1.0, e - 8);
                ok = ok && got == want;
            } else {
                ok = got == 0;   // below 1e-32 the pixel is black (Radiance's threshold)
            }
            if (!ok && bad++ < 3) printf("  %s pixel %zu ch %d: wrote %.9g, read %.9g\n", name, p, k, in[k], got);
        }
    }
    CHECK(bad == 0);
    stbi_image_free(r);
}

TEST(hdr_roundtrip) {
    // values over 12 decades, plus runs (RLE), NaN, negative, zero, Inf, huge
    enum { W = 300, H = 7 };
    for (int c = 1; c <= 4; c++) {
        float* d = malloc((size_t)W * H * c * sizeof(float));
        REQUIRE(d);
        for (size_t i = 0; i < (size_t)W * H * c; i++) {
            double u = mlb_rng_uniform(11, (uint64_t)c, i), e = mlb_rng_uniform(12, (uint64_t)c, i);
            size_t px = i / c, x = px % W, y = px / W;
            if (y == 1 && x < 200) d[i] = 0.75f;                       // a long run (> 127)
            else if (y == 2) d[i] = (x / 3) % 2 ? 2.0f : 0.001f;        // runs of exactly 3
            else if (y == 3) d[i] = (x % 2) ? 5.0f : 5.5f;              // no runs
            else d[i] = (float)(u * pow(10.0, floor(e * 12) - 6));
        }
        d[0] = NAN; d[1] = -3.0f; d[2] = 0.0f;
        d[(size_t)4 * W * c] = INFINITY; d[(size_t)4 * W * c + c] = 3e38f; d[(size_t)4 * W * c + 2 * c] = 1e-33f;
        char name[64];
        snprintf(name, sizeof name, "rt_%d.hdr", c);
        hdr_check(W, H, c, d, name);
        // narrow scanlines are written flat (RLE needs 8..32767 pixels)
        snprintf(name, sizeof name, "narrow_%d.hdr", c);
        hdr_check(5, H, c, d, name);
        free(d);
    }
    // a scanline too wide for RLE
    enum { WW = 40000 };
    float* d = malloc((size_t)WW * 3 * sizeof(float));
    REQUIRE(d);
    for (size_t i = 0; i < (size_t)WW * 3; i++) d[i] = (float)mlb_rng_uniform(13, 0, i) * 100.0f;
    hdr_check(WW, 1, 3, d, "wide.hdr");
    free(d);
    // the header
    char path[4200];
    snprintf(path, sizeof path, "%s/rt_3.hdr", tmp);
    FILE* f = fopen(path, "rb");
    REQUIRE(f);
    char buf[256] = {0};
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    CHECK(n > 40 && strncmp(buf, "#?RADIANCE\n", 11) == 0);
    CHECK(strstr(buf, "\nFORMAT=32-bit_rle_rgbe\n\n-Y 7 +X 300\n") != NULL);
}

// ---- EXR ----

// Reads every channel of an EXR file as float planes with tinyexr's full API.
static int read_exr_planes(const char* path, int* w, int* h, int* nc, char names[4][8], float* planes[4]) {
    EXRVersion ver;
    EXRHeader hdr;
    EXRImage img;
    const char* err = NULL;
    if (ParseEXRVersionFromFile(&ver, path) != TINYEXR_SUCCESS) return 0;
    InitEXRHeader(&hdr);
    if (ParseEXRHeaderFromFile(&hdr, &ver, path, &err) != TINYEXR_SUCCESS) {
        if (err) FreeEXRErrorMessage(err);
        return 0;
    }
    for (int i = 0; i < hdr.num_channels; i++) hdr.requested_pixel_types[i] = TINYEXR_PIXELTYPE_FLOAT;
    InitEXRImage(&img);
    if (LoadEXRImageFromFile(&img, &hdr, path, &err) != TINYEXR_SUCCESS || hdr.num_channels > 4) {
        if (err) FreeEXRErrorMessage(err);
        FreeEXRHeader(&hdr);
        return 0;
    }
    *w = img.width;
    *h = img.height;
    *nc = hdr.num_channels;
    for (int i = 0; i < hdr.num_channels; i++) {
        snprintf(names[i], 8, "%s", hdr.channels[i].name);
        planes[i] = malloc((size_t)img.width * img.height * sizeof(float));
        memcpy(planes[i], img.images[i], (size_t)img.width * img.height * sizeof(float));
    }
    FreeEXRImage(&img);
    FreeEXRHeader(&hdr);
    return 1;
}

static int same_float(float a, float b) { return (isnan(a) && isnan(b)) || (a == b && signbit(a) == signbit(b)); }

TEST(exr_roundtrip) {
    enum { W = 41, H = 19 };
    static const char* want_names[5][4] = {{0}, {"Y"}, {"A", "Y"}, {"B", "G", "R"}, {"A", "B", "G", "R"}};
    static const int src_ch[5][4] = {{0}, {0}, {1, 0}, {2, 1, 0}, {3, 2, 1, 0}};
    for (int c = 1; c <= 4; c++)
        for (int pix = 0; pix < 2; pix++)
            for (int comp = 0; comp < 2; comp++) {
                float* d = malloc((size_t)W * H * c * sizeof(float));
                REQUIRE(d);
                for (size_t i = 0; i < (size_t)W * H * c; i++) {
                    double u = mlb_rng_uniform(21, (uint64_t)c, i), e = mlb_rng_uniform(22, (uint64_t)c, i);
                    d[i] = (float)((u * 2 - 1) * pow(10.0, floor(e * 10) - 5));
                }
                d[0] = NAN; d[1] = INFINITY; d[2] = -0.0f; d[3] = 70000.0f; d[4] = 1e-7f;
                char path[4200];
                snprintf(path, sizeof path, "%s/rt_%d_%d_%d.exr", tmp, c, pix, comp);
                mlb_exr_options opt = {pix ? MLB_EXR_FLOAT : MLB_EXR_HALF, comp ? MLB_EXR_NONE : MLB_EXR_ZIP};
                mlb_status st = mlb_image_write_exr(path, d, W, H, c, &opt);
                CHECK_MSG(st == MLB_OK, "%s", mlb_last_error());
                if (st != MLB_OK) { free(d); return; }
                int w = 0, h = 0, nc = 0;
                char names[4][8];
                float* planes[4] = {0};
                CHECK(read_exr_planes(path, &w, &h, &nc, names, planes));
                CHECK(w == W && h == H && nc == c);
                int bad = 0;
                for (int k = 0; k < nc && k < c; k++) {
                    CHECK(strcmp(names[k], want_names[c][k]) == 0);
                    for (size_t i = 0; i < (size_t)W * H; i++) {
                        float v = d[i * c + src_ch[c][k]], got = planes[k][i];
                        // float: the bits; half: float16 rounding (nearest even), within 2^-11 relative
                        float want = pix ? v : mlb_f16_to_f32(mlb_f32_to_f16(v));
                        int ok = same_float(got, want);
                        if (!pix && isfinite(v) && fabsf(v) <= 65504 && fabsf(v) >= 6.2e-5f)
                            ok = ok && fabsf(got - v) <= fabsf(v) / 2048;
                        if (!ok && bad++ < 3) printf("  c=%d %s: %.9g -> %.9g\n", c, pix ? "float" : "half", v, got);
                    }
                }
                CHECK(bad == 0);
                for (int k = 0; k < 4; k++) free(planes[k]);
                // the RGBA reader most programs use
                if (c != 2) {
                    float* rgba = NULL;
                    const char* err = NULL;
                    int rw, rh;
                    int r = LoadEXR(&rgba, &rw, &rh, path, &err);
                    CHECK_MSG(r == TINYEXR_SUCCESS, "LoadEXR: %s", err ? err : "?");
                    if (err) FreeEXRErrorMessage(err);
                    if (r == TINYEXR_SUCCESS) {
                        bad = 0;
                        for (size_t i = 0; i < (size_t)W * H; i++)
                            for (int k = 0; k < 4; k++) {
                                int s = c == 1 ? 0 : (k < 3 ? k : (c == 4 ? 3 : -1));
                                float want = s < 0 ? 1.0f : d[i * c + s];
                                if (s >= 0 && !pix) want = mlb_f16_to_f32(mlb_f32_to_f16(want));
                                bad += !same_float(rgba[4 * i + k], want);
                            }
                        CHECK_MSG(bad == 0, "LoadEXR: %d samples differ", bad);
                        free(rgba);
                    }
                }
                free(d);
            }
    // half: overflow to Inf, NaN kept, 65504 kept
    float v[4] = {1e6f, NAN, 65504.0f, -1e6f};
    char path[4200];
    snprintf(path, sizeof path, "%s/special.exr", tmp);
    REQUIRE(mlb_image_write_exr(path, v, 4, 1, 1, NULL) == MLB_OK);
    int w, h, nc;
    char names[4][8];
    float* planes[4] = {0};
    REQUIRE(read_exr_planes(path, &w, &h, &nc, names, planes));
    CHECK(isinf(planes[0][0]) && planes[0][0] > 0 && isnan(planes[0][1]) && planes[0][2] == 65504.0f);
    CHECK(isinf(planes[0][3]) && planes[0][3] < 0);
    free(planes[0]);
}

// ---- errors ----

TEST(bad_arguments) {
    float px[16] = {0};
    char path[4200];
    snprintf(path, sizeof path, "%s/arg.png", tmp);
    mlb_png_options b12 = {12, MLB_PNG_AS_IS}, benc = {8, (mlb_png_encoding)7};
    mlb_exr_options epix = {(mlb_exr_pixel)9, MLB_EXR_ZIP}, ecomp = {MLB_EXR_HALF, (mlb_exr_compression)9};
    const mlb_status r[] = {
        mlb_image_write_png(NULL, px, 1, 1, 1, NULL),
        mlb_image_write_png(path, NULL, 1, 1, 1, NULL),
        mlb_image_write_png(path, px, 0, 1, 1, NULL),
        mlb_image_write_png(path, px, 1, -1, 1, NULL),
        mlb_image_write_png(path, px, 1, 1, 0, NULL),
        mlb_image_write_png(path, px, 1, 1, 5, NULL),
        mlb_image_write_png(path, px, 100000, 100000, 1, NULL),
        mlb_image_write_png(path, px, 1, 1, 1, &b12),
        mlb_image_write_png(path, px, 1, 1, 1, &benc),
        mlb_image_write_hdr(path, px, 2, 2, 9),
        mlb_image_write_hdr(path, NULL, 2, 2, 3),
        mlb_image_write_exr(path, px, 1, 1, 1, &epix),
        mlb_image_write_exr(path, px, 1, 1, 1, &ecomp),
        mlb_image_write_exr(path, px, -4, 1, 1, NULL),
        mlb_image_write(path, NULL, NULL),
    };
    for (size_t i = 0; i < sizeof r / sizeof r[0]; i++)
        CHECK_MSG(r[i] == MLB_ERR_ARG, "case %zu: %s", i, mlb_status_name(r[i]));
    CHECK(!exists(path));
    // each message, one at a time
    CHECK(mlb_image_write_png(NULL, px, 1, 1, 1, NULL) == MLB_ERR_ARG && strstr(mlb_last_error(), "NULL path"));
    CHECK(mlb_image_write_png(path, px, 1, 1, 5, NULL) == MLB_ERR_ARG && strstr(mlb_last_error(), path) &&
          strstr(mlb_last_error(), "5 channels (1 to 4 allowed)"));
    CHECK(mlb_image_write_png(path, px, 100000, 100000, 1, NULL) == MLB_ERR_ARG &&
          strstr(mlb_last_error(), "100000x100000 is more than the"));
    CHECK(mlb_image_write_png(path, px, 1, 1, 1, &b12) == MLB_ERR_ARG && strstr(mlb_last_error(), "12 bits per sample"));
    CHECK(mlb_image_write_exr(path, px, 1, 1, 1, &epix) == MLB_ERR_ARG && strstr(mlb_last_error(), "pixel type 9"));
    // dispatch by extension
    mlb_image img = {px, 2, 2, 3, 3, 8};
    char p2[4200];
    snprintf(p2, sizeof p2, "%s/ext.PNG", tmp);
    CHECK(mlb_image_write(p2, &img, NULL) == MLB_OK && exists(p2));
    snprintf(p2, sizeof p2, "%s/ext.Hdr", tmp);
    CHECK(mlb_image_write(p2, &img, NULL) == MLB_OK && exists(p2));
    snprintf(p2, sizeof p2, "%s/ext.exr", tmp);
    CHECK(mlb_image_write(p2, &img, NULL) == MLB_OK && exists(p2));
    snprintf(p2, sizeof p2, "%s/ext.jpg", tmp);
    CHECK(mlb_image_write(p2, &img, NULL) == MLB_ERR_ARG && strstr(mlb_last_error(), "cannot tell the image format"));
    snprintf(p2, sizeof p2, "%s/dir.png/noext", tmp);
    CHECK(mlb_image_write(p2, &img, NULL) == MLB_ERR_ARG);
    CHECK(!exists(p2));
}

typedef mlb_status (*writer_fn)(const char* path, const float* d);
static mlb_status w_png8(const char* p, const float* d) { return mlb_image_write_png(p, d, 4, 3, 3, NULL); }
static mlb_status w_png16(const char* p, const float* d) {
    mlb_png_options o = {16, MLB_PNG_SRGB};
    return mlb_image_write_png(p, d, 4, 3, 3, &o);
}
static mlb_status w_hdr(const char* p, const float* d) { return mlb_image_write_hdr(p, d, 4, 3, 3); }
static mlb_status w_exr(const char* p, const float* d) { return mlb_image_write_exr(p, d, 4, 3, 3, NULL); }

TEST(unwritable_targets) {
    float px[36];
    for (int i = 0; i < 36; i++) px[i] = i / 36.0f;
    writer_fn fns[4] = {w_png8, w_png16, w_hdr, w_exr};
    const char* ext[4] = {"png", "png", "hdr", "exr"};
    char path[4200], file[4200], dir[4200];
    snprintf(file, sizeof file, "%s/plain_file", tmp);
    FILE* f = fopen(file, "wb");
    REQUIRE(f && fputs("x", f) >= 0 && fclose(f) == 0);
    snprintf(dir, sizeof dir, "%s/a_folder.png", tmp);
    REQUIRE(mkdir(dir, 0777) == 0 || exists(dir));
    for (int k = 0; k < 4; k++) {
        // a folder that does not exist
        snprintf(path, sizeof path, "%s/no/such/folder/out.%s", tmp, ext[k]);
        mlb_status s = fns[k](path, px);
        CHECK_MSG(s == MLB_ERR_IO && strstr(mlb_last_error(), path), "%s: %s", ext[k], mlb_last_error());
        CHECK(!exists(path));
        // a "folder" that is a file
        snprintf(path, sizeof path, "%s/out.%s", file, ext[k]);
        s = fns[k](path, px);
        CHECK_MSG(s == MLB_ERR_IO && strstr(mlb_last_error(), path), "%s: %s", ext[k], mlb_last_error());
        // the target is a folder: everything is written, the final rename fails, the temporary goes
        snprintf(path, sizeof path, "%s", dir);
        s = fns[k](path, px);
        CHECK_MSG(s == MLB_ERR_IO && strstr(mlb_last_error(), dir), "%s: %s", ext[k], mlb_last_error());
        CHECK(count_files(".tmp.") == 0);
    }
    // a read-only folder (root ignores permissions, so only checked as another user)
    if (geteuid() != 0) {
        snprintf(dir, sizeof dir, "%s/readonly", tmp);
        REQUIRE(mkdir(dir, 0555) == 0);
        for (int k = 0; k < 4; k++) {
            snprintf(path, sizeof path, "%s/out.%s", dir, ext[k]);
            mlb_status s = fns[k](path, px);
            CHECK(s == MLB_ERR_IO && strstr(mlb_last_error(), path) && strstr(mlb_last_error(), "ermission"));
            CHECK(!exists(path));
        }
        chmod(dir, 0755);
    } else {
        printf("  (running as root: the read-only folder case is not meaningful and was left out)\n");
    }
    // libpng refuses the image (wider than its 1000000-pixel limit): its error comes back through
    // setjmp/longjmp as a status, the temporary is removed, nothing is left at the path
    float* wide = calloc(2000000, sizeof(float));
    REQUIRE(wide);
    snprintf(path, sizeof path, "%s/too_wide.png", tmp);
    mlb_status s = mlb_image_write_png(path, wide, 2000000, 1, 1, NULL);
    CHECK_MSG(s == MLB_ERR_FORMAT && strstr(mlb_last_error(), path) && strstr(mlb_last_error(), "PNG writing failed: ") &&
                  strstr(mlb_last_error(), "width exceeds"),
              "%s", mlb_last_error());
    CHECK(!exists(path) && count_files(".tmp.") == 0);
    free(wide);
    // an existing file is replaced whole, and a failed write leaves the old one as it was
    snprintf(path, sizeof path, "%s/keep.png", tmp);
    REQUIRE(w_png8(path, px) == MLB_OK);
    struct stat before, after;
    REQUIRE(stat(path, &before) == 0);
    CHECK(mlb_image_write_png(path, px, 4, 3, 7, NULL) == MLB_ERR_ARG);
    REQUIRE(stat(path, &after) == 0);
    CHECK(before.st_ino == after.st_ino && before.st_size == after.st_size);
    REQUIRE(w_png16(path, px) == MLB_OK);
    mlb_image img = {0};
    REQUIRE(mlb_image_load(&img, path, 0) == MLB_OK);
    CHECK(img.bits == 16);
    mlb_image_free(&img);
    CHECK(count_files(".tmp.") == 0);
}

int main(void) {
    tmp = test_tmpdir("image_write");
    if (!tmp) { printf("cannot create a scratch folder\n"); return 1; }
    RUN(png8_as_is);
    RUN(png16_as_is);
    RUN(png8_srgb);
    RUN(png16_srgb);
    RUN(png_srgb_anchors_and_chunks);
    RUN(hdr_roundtrip);
    RUN(exr_roundtrip);
    RUN(bad_arguments);
    RUN(unwritable_targets);
    return test_summary();
}
