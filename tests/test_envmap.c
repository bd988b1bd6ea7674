// Environment maps and the pre-integrated cube map: loading the shared HDR files and hostile files
// written here, the procedural environments, rotation, cube conventions (reference.md §2),
// seamless lookups and their gradients (finite differences in double), the prefilter against
// its exact sum and against the definition evaluated on the lat-long map, and the irradiance.
#include "test.h"
#include <omp.h>
#include <tinyexr.h>
#include "matlaber/envmap.h"
#include "matlaber/rng.h"

#define PI 3.14159265358979323846

static double lum3(const double* p) { return 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]; }
static double lumf(const float* p) { return 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]; }
static double pixel_sa(int j, int w, int h) { return 2 * PI / w * (cos(PI * j / h) - cos(PI * (j + 1) / h)); }

static void rand_dir(uint64_t i, double d[3]) {
    double z = 2 * mlb_rng_uniform_f64(3, 1, i) - 1, ph = 2 * PI * mlb_rng_uniform_f64(3, 2, i), r = sqrt(1 - z * z);
    d[0] = r * cos(ph), d[1] = z, d[2] = r * sin(ph);
}

// ---------------------------------------------------------------- files

TEST(shared_hdr_files) {
    const char* data = test_shared_data();
    if (!data) SKIP("no ../shared/data");
    struct { const char* name; double max, mean; } f[2] = {{"mud_road_puresky_1k.hdr", 0.85, 0.40}, {"studio_small_03_1k.hdr", 3.4e3, 1.9}};
    for (int i = 0; i < 2; i++) {
        char path[4200];
        snprintf(path, sizeof path, "%s/envmaps/%s", data, f[i].name);
        mlb_envmap env;
        mlb_envmap_info info;
        REQUIRE(mlb_envmap_load(&env, path, 1.0f, &info) == MLB_OK);
        CHECK(env.w == 1024 && env.h == 512);
        CHECK(info.n_nonfinite == 0 && info.n_negative == 0);
        CHECK_CLOSE(info.max_luminance, f[i].max, 0.05, 0);   // README: max ~0.85 / ~3.4e3, mean ~0.40 / ~1.9
        CHECK_CLOSE(info.mean_luminance, f[i].mean, 0.05, 0);
        printf("  %s: %dx%d, max luminance %.4g, mean %.4g (solid-angle mean %.4g)\n", f[i].name, env.w, env.h,
               info.max_luminance, info.mean_luminance, info.mean_luminance_sphere);
        mlb_envmap scaled;
        mlb_envmap_info si;
        REQUIRE(mlb_envmap_open(&scaled, path, 2.0f, 0, &si) == MLB_OK);   // a path through open(), scale 2
        CHECK_CLOSE(si.max_luminance, 2 * info.max_luminance, 1e-6, 0);
        CHECK(scaled.data[12345] == 2 * env.data[12345]);
        mlb_envmap_free(&scaled);
        mlb_envmap_free(&env);
    }
}

static void write_bytes(const char* path, const void* p, size_t n) {
    FILE* f = fopen(path, "wb");
    if (f) {
        fwrite(p, 1, n, f);
        fclose(f);
    }
}

// A Radiance file of w x h pixels of value (i + j) / 8 (flat or RLE), into buf; returns its size.
static size_t make_hdr(unsigned char* buf, int w, int h, int rle, const char* format) {
    size_t n = (size_t)sprintf((char*)buf, "#?RADIANCE\nFORMAT=%s\n\n-Y %d +X %d\n", format, h, w);
    for (int j = 0; j < h; j++) {
        unsigned char px[4096][4];
        for (int i = 0; i < w; i++) {   // value (i + j + 1) / 8 = m * 2^(e - 136), m in [128, 256)
            double v = (i + j + 1) / 8.0;
            int e;
            double m = frexp(v, &e);
            px[i][0] = px[i][1] = px[i][2] = (unsigned char)(m * 256);
            px[i][3] = (unsigned char)(e + 128);
        }
        if (!rle) {
            memcpy(buf + n, px, (size_t)w * 4);
            n += (size_t)w * 4;
            continue;
        }
        buf[n++] = 2, buf[n++] = 2, buf[n++] = (unsigned char)(w >> 8), buf[n++] = (unsigned char)(w & 255);
        for (int k = 0; k < 4; k++)
            for (int i = 0; i < w; i += 128) {
                int c = w - i < 128 ? w - i : 128;
                buf[n++] = (unsigned char)c;
                for (int q = 0; q < c; q++) buf[n++] = px[i + q][k];
            }
    }
    return n;
}

static int fails_naming(mlb_status got, mlb_status want, const char* path, const char* word) {
    const char* m = mlb_last_error();
    int ok = got == want && strstr(m, path) != NULL && (!word || strstr(m, word) != NULL);
    if (!ok) printf("  status %s, message: %s\n", mlb_status_name(got), m);
    return ok;
}

TEST(hostile_hdr_files) {
    const char* dir = test_tmpdir("envmap_hdr");
    REQUIRE(dir);
    static unsigned char buf[1 << 20];
    char path[4200];
    mlb_envmap env;
    for (int rle = 0; rle < 2; rle++) {   // a valid file of each kind, then truncated
        size_t n = make_hdr(buf, 32, 16, rle, "32-bit_rle_rgbe");
        snprintf(path, sizeof path, "%s/ok%d.hdr", dir, rle);
        write_bytes(path, buf, n);
        REQUIRE(mlb_envmap_load(&env, path, 1.0f, NULL) == MLB_OK);
        CHECK(env.w == 32 && env.h == 16);
        CHECK(env.data[(5 * 32 + 7) * 3 + 1] == 13 / 8.0f);
        mlb_envmap_free(&env);
        snprintf(path, sizeof path, "%s/truncated%d.hdr", dir, rle);
        write_bytes(path, buf, n - 37);
        CHECK(fails_naming(mlb_envmap_load(&env, path, 1.0f, NULL), MLB_ERR_FORMAT, path, "truncated"));
        CHECK(env.data == NULL);
    }
    size_t n = make_hdr(buf, 32, 16, 1, "32-bit_rle_rgbe");
    buf[n - 202] = 0;   // the count byte of channel 2 in the second-last scanline: a zero-length run
    snprintf(path, sizeof path, "%s/badrun.hdr", dir);
    write_bytes(path, buf, n);
    CHECK(fails_naming(mlb_envmap_load(&env, path, 1.0f, NULL), MLB_ERR_FORMAT, path, "corrupt"));
    n = make_hdr(buf, 16, 16, 1, "32-bit_rle_rgbe");
    snprintf(path, sizeof path, "%s/square.hdr", dir);
    write_bytes(path, buf, n);
    CHECK(fails_naming(mlb_envmap_load(&env, path, 1.0f, NULL), MLB_ERR_FORMAT, path, "twice the height"));
    n = make_hdr(buf, 32, 16, 0, "32-bit_rle_xyze");
    snprintf(path, sizeof path, "%s/xyze.hdr", dir);
    write_bytes(path, buf, n);
    CHECK(fails_naming(mlb_envmap_load(&env, path, 1.0f, NULL), MLB_ERR_UNSUPPORTED, path, "xyze"));
    const char* huge = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 200000\n\x02\x02";
    snprintf(path, sizeof path, "%s/huge.hdr", dir);
    write_bytes(path, huge, strlen(huge));
    CHECK(fails_naming(mlb_envmap_load(&env, path, 1.0f, NULL), MLB_ERR_ARG, path, "limit"));
    const char* zero = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 0 +X 0\n";
    snprintf(path, sizeof path, "%s/zero.hdr", dir);
    write_bytes(path, zero, strlen(zero));
    CHECK(fails_naming(mlb_envmap_load(&env, path, 1.0f, NULL), MLB_ERR_FORMAT, path, "empty"));
    const char* header_only = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n";
    snprintf(path, sizeof path, "%s/header.hdr", dir);
    write_bytes(path, header_only, strlen(header_only));
    CHECK(fails_naming(mlb_envmap_load(&env, path, 1.0f, NULL), MLB_ERR_FORMAT, path, "truncated"));
    snprintf(path, sizeof path, "%s/empty.hdr", dir);
    write_bytes(path, "", 0);
    CHECK(fails_naming(mlb_envmap_load(&env, path, 1.0f, NULL), MLB_ERR_FORMAT, path, "empty"));
    snprintf(path, sizeof path, "%s/text.hdr", dir);
    write_bytes(path, "hello, world\n", 13);
    CHECK(fails_naming(mlb_envmap_load(&env, path, 1.0f, NULL), MLB_ERR_UNSUPPORTED, path, NULL));
    snprintf(path, sizeof path, "%s/missing.hdr", dir);
    CHECK(fails_naming(mlb_envmap_load(&env, path, 1.0f, NULL), MLB_ERR_IO, path, "No such file"));
    CHECK(fails_naming(mlb_envmap_load(&env, dir, 1.0f, NULL), MLB_ERR_IO, dir, "not a regular file"));
    snprintf(path, sizeof path, "%s/ok0.hdr", dir);
    CHECK(fails_naming(mlb_envmap_load(&env, path, -1.0f, NULL), MLB_ERR_ARG, path, "scale"));
    CHECK(fails_naming(mlb_envmap_load(&env, path, NAN, NULL), MLB_ERR_ARG, path, "scale"));
    const char* data = test_shared_data();   // the real file cut in half
    if (data) {
        char src[4200];
        snprintf(src, sizeof src, "%s/envmaps/mud_road_puresky_1k.hdr", data);
        FILE* f = fopen(src, "rb");
        REQUIRE(f);
        size_t got = fread(buf, 1, sizeof buf, f);
        fclose(f);
        snprintf(path, sizeof path, "%s/half.hdr", dir);
        write_bytes(path, buf, got / 2);
        CHECK(fails_naming(mlb_envmap_load(&env, path, 1.0f, NULL), MLB_ERR_FORMAT, path, "truncated"));
    }
}

TEST(exr_files_and_repairs) {
    const char* dir = test_tmpdir("envmap_exr");
    REQUIRE(dir);
    enum { W = 16, H = 8 };
    float rgb[W * H * 3];
    for (int i = 0; i < W * H * 3; i++) rgb[i] = 0.25f + 0.01f * (float)(i % 7);
    rgb[3 * 5 + 0] = NAN, rgb[3 * 9 + 1] = INFINITY, rgb[3 * 20 + 2] = -INFINITY, rgb[3 * 30 + 1] = -2.0f;
    char path[4200];
    snprintf(path, sizeof path, "%s/repair.exr", dir);
    const char* err = NULL;
    REQUIRE(SaveEXR(rgb, W, H, 3, 0, path, &err) == TINYEXR_SUCCESS);
    mlb_envmap env;
    mlb_envmap_info info;
    REQUIRE(mlb_envmap_load(&env, path, 2.0f, &info) == MLB_OK);
    CHECK(env.w == W && env.h == H);
    CHECK(info.n_nonfinite == 3 && info.n_negative == 1);   // documented: NaN/Inf and negatives become 0
    CHECK(env.data[3 * 5] == 0 && env.data[3 * 9 + 1] == 0 && env.data[3 * 20 + 2] == 0 && env.data[3 * 30 + 1] == 0);
    CHECK_CLOSE(env.data[3 * 7 + 2], 2 * rgb[3 * 7 + 2], 1e-6, 0);   // scaled by 2
    CHECK(mlb_envmap_validate(&env) == MLB_OK);
    mlb_envmap_free(&env);
    // the same repairs for maps from memory
    REQUIRE(mlb_envmap_from_rgb(&env, rgb, W, H, "mem", &info) == MLB_OK);
    CHECK(info.n_nonfinite == 3 && info.n_negative == 1);
    mlb_envmap_free(&env);
    // truncated, corrupted header, wrong aspect
    FILE* f = fopen(path, "rb");
    REQUIRE(f);
    static unsigned char buf[1 << 16];
    size_t n = fread(buf, 1, sizeof buf, f);
    fclose(f);
    char bad[4200];
    snprintf(bad, sizeof bad, "%s/truncated.exr", dir);
    write_bytes(bad, buf, n * 2 / 3);
    CHECK(fails_naming(mlb_envmap_load(&env, bad, 1.0f, NULL), MLB_ERR_FORMAT, bad, NULL));
    for (size_t i = 8; i < 60 && i < n; i++) buf[i] ^= 0x5a;
    snprintf(bad, sizeof bad, "%s/corrupt.exr", dir);
    write_bytes(bad, buf, n);
    CHECK(fails_naming(mlb_envmap_load(&env, bad, 1.0f, NULL), MLB_ERR_FORMAT, bad, NULL));
    snprintf(bad, sizeof bad, "%s/square.exr", dir);
    REQUIRE(SaveEXR(rgb, 8, 8, 3, 1, bad, &err) == TINYEXR_SUCCESS);
    CHECK(fails_naming(mlb_envmap_load(&env, bad, 1.0f, NULL), MLB_ERR_FORMAT, bad, "twice the height"));
    // one channel: grey
    float grey[W * H];
    for (int i = 0; i < W * H; i++) grey[i] = 0.125f * (float)(i % 5);
    snprintf(path, sizeof path, "%s/grey.exr", dir);
    REQUIRE(SaveEXR(grey, W, H, 1, 1, path, &err) == TINYEXR_SUCCESS);
    REQUIRE(mlb_envmap_load(&env, path, 1.0f, NULL) == MLB_OK);
    CHECK(env.data[3 * 13] == grey[13] && env.data[3 * 13 + 1] == grey[13] && env.data[3 * 13 + 2] == grey[13]);
    mlb_envmap_free(&env);
}

// A tiled EXR (20 x 10 in 8 x 8 tiles, partial tiles at the borders), written with tinyexr's API.
TEST(tiled_exr) {
    const char* dir = test_tmpdir("envmap_tiled");
    REQUIRE(dir);
    enum { W = 20, H = 10, T = 8, NTX = 3, NTY = 2 };
    EXRHeader hdr;
    EXRImage img;
    InitEXRHeader(&hdr);
    InitEXRImage(&img);
    EXRChannelInfo ch[3] = {{.name = "B"}, {.name = "G"}, {.name = "R"}};
    int types[3] = {TINYEXR_PIXELTYPE_FLOAT, TINYEXR_PIXELTYPE_FLOAT, TINYEXR_PIXELTYPE_FLOAT}, req[3];
    memcpy(req, types, sizeof req);
    hdr.num_channels = 3, hdr.channels = ch, hdr.pixel_types = types, hdr.requested_pixel_types = req;
    hdr.tiled = 1, hdr.tile_size_x = T, hdr.tile_size_y = T, hdr.tile_level_mode = TINYEXR_TILE_ONE_LEVEL;
    hdr.compression_type = TINYEXR_COMPRESSIONTYPE_NONE;
    hdr.data_window.max_x = W - 1, hdr.data_window.max_y = H - 1, hdr.display_window = hdr.data_window;
    hdr.pixel_aspect_ratio = 1, hdr.screen_window_width = 1;
    static float px[NTX * NTY][3][T * T];
    EXRTile tiles[NTX * NTY];
    unsigned char* ptr[NTX * NTY][3];
    for (int ty = 0; ty < NTY; ty++)
        for (int tx = 0; tx < NTX; tx++) {
            int t = ty * NTX + tx;
            tiles[t] = (EXRTile){.offset_x = tx, .offset_y = ty, .width = tx == NTX - 1 ? W - tx * T : T,
                                 .height = ty == NTY - 1 ? H - ty * T : T, .images = ptr[t]};
            for (int c = 0; c < 3; c++) {
                for (int j = 0; j < T; j++)
                    for (int i = 0; i < T; i++) px[t][c][i + j * T] = (float)((tx * T + i) + 100 * (ty * T + j) + 1000 * (2 - c));
                ptr[t][c] = (unsigned char*)px[t][c];
            }
        }
    img.tiles = tiles, img.num_tiles = NTX * NTY, img.width = W, img.height = H, img.num_channels = 3;
    char path[4200];
    snprintf(path, sizeof path, "%s/tiled.exr", dir);
    const char* err = NULL;
    REQUIRE(SaveEXRImageToFile(&img, &hdr, path, &err) == TINYEXR_SUCCESS);
    mlb_envmap env;
    REQUIRE(mlb_envmap_load(&env, path, 1.0f, NULL) == MLB_OK);
    CHECK(env.w == W && env.h == H);
    const float* p = env.data + (7 * W + 13) * 3;   // pixel (13, 7) of tile (1, 0)
    CHECK(p[0] == 713 && p[1] == 1713 && p[2] == 2713);
    p = env.data + (9 * W + 19) * 3;   // the last pixel, in a partial tile
    CHECK(p[0] == 919 && p[1] == 1919 && p[2] == 2919);
    mlb_envmap_free(&env);
}

// ---------------------------------------------------------------- procedural environments

// Horizontal irradiance of a map (luminance), split at a radiance threshold.
static void horizontal_irradiance(const mlb_envmap* e, double thresh, double* below, double* above) {
    *below = *above = 0;
    for (int j = 0; j < e->h; j++) {
        double y = cos(PI * (j + 0.5) / e->h), sa = pixel_sa(j, e->w, e->h);
        if (y <= 0) continue;
        for (int i = 0; i < e->w; i++) {
            double l = lumf(e->data + ((size_t)j * e->w + i) * 3) * y * sa;
            if (lumf(e->data + ((size_t)j * e->w + i) * 3) > thresh) *above += l;
            else *below += l;
        }
    }
}

TEST(procedural_environments) {
    const char* names[] = {"sky", "overcast", "studio", "white"};
    for (int k = 0; k < 4; k++) {
        mlb_envmap a, b;
        REQUIRE(mlb_envmap_named(&a, names[k], 256) == MLB_OK);
        REQUIRE(mlb_envmap_named(&b, names[k], 256) == MLB_OK);
        CHECK(a.w == 512 && a.h == 256 && strcmp(a.name, names[k]) == 0);
        CHECK(mlb_envmap_validate(&a) == MLB_OK);
        CHECK(memcmp(a.data, b.data, (size_t)a.w * a.h * 3 * sizeof(float)) == 0);   // deterministic
        mlb_envmap_info info;
        mlb_envmap_stats(&a, &info);
        double sky, sun;
        horizontal_irradiance(&a, 100.0, &sky, &sun);
        printf("  %-8s max %.4g  mean %.4g  horizontal irradiance %.4f (%.4f from radiance > 100)\n", names[k],
               info.max_luminance, info.mean_luminance, sky + sun, sun);
        if (k == 0) {   // a white horizontal Lambertian plane has radiance 1; the sun gives 6/7 of it
            CHECK_CLOSE(sky + sun, PI, 0.02, 0);
            CHECK(sun / sky > 5 && sun / sky < 10);
            CHECK(info.max_luminance > 1e4);
        } else if (k == 1) {   // CIE overcast: zenith 3x the horizon, no sun
            CHECK_CLOSE(sky + sun, PI, 0.02, 0);
            CHECK(sun == 0 && info.max_luminance < 1.5);
            double zen = lumf(a.data), hor = lumf(a.data + (size_t)(a.h / 2 - 1) * a.w * 3);
            CHECK_CLOSE(zen / hor, 3, 0.03, 0);
        } else if (k == 2) {   // dark room, bright boxes
            size_t dark = 0, bright = 0, np = (size_t)a.w * a.h;
            for (size_t i = 0; i < np; i++) {
                double l = lumf(a.data + 3 * i);
                dark += l < 0.1, bright += l > 1;
            }
            CHECK(dark > np / 2 && bright > np / 50 && bright < np / 3 && info.max_luminance >= 5);
        } else {
            CHECK(info.max_luminance == 1.0f && info.mean_luminance == 1.0f);
        }
        mlb_envmap_free(&a);
        mlb_envmap_free(&b);
    }
    mlb_envmap e;
    CHECK(mlb_envmap_named(&e, "sunset", 64) == MLB_ERR_NOT_FOUND && strstr(mlb_last_error(), "overcast"));
    CHECK(mlb_envmap_named(&e, "sky", 1) == MLB_ERR_ARG);
    CHECK(mlb_envmap_open(&e, "./sky", 1.0f, 64, NULL) == MLB_ERR_IO);   // a path, not the built-in
    REQUIRE(mlb_envmap_open(&e, "overcast", 0.5f, 64, NULL) == MLB_OK);
    CHECK_CLOSE(lumf(e.data), 0.5 * 9.0 / 7.0, 1e-3, 0);
    mlb_envmap_free(&e);
}

TEST(rotation_rotates_lookups) {
    mlb_envmap e;
    REQUIRE(mlb_envmap_named(&e, "studio", 64) == MLB_OK);
    for (int i = 0; i < 200; i++) {
        double d[3], dr[3], a[3], b[3], ang = (float)(6 * mlb_rng_uniform_f64(3, 5, i) - 3);
        rand_dir(i, d);
        mlb_rotate_y(dr, d, -ang);
        e.rotation = 0;
        mlb_envmap_lookup(&e, dr, a);
        mlb_envmap_set_rotation(&e, (float)ang);
        mlb_envmap_lookup(&e, d, b);
        for (int c = 0; c < 3; c++) CHECK_CLOSE(b[c], a[c], 1e-5, 1e-6);
    }
    double x[3] = {1, 0, 0}, y[3];   // +x turns towards -z
    mlb_rotate_y(y, x, PI / 2);
    CHECK(fabs(y[0]) < 1e-12 && fabs(y[2] + 1) < 1e-12);
    double u, t, d[3] = {0, 0, -1};   // the lat-long mapping of reference.md: -z is the image centre
    mlb_latlong_dir_to_uv(d, &u, &t);
    CHECK_CLOSE(u, 0.5, 0, 1e-12);
    CHECK_CLOSE(t, 0.5, 0, 1e-12);
    d[0] = 1, d[2] = 0;
    mlb_latlong_dir_to_uv(d, &u, &t);
    CHECK_CLOSE(u, 0.75, 0, 1e-12);
    mlb_envmap_free(&e);
}

// ---------------------------------------------------------------- cube conventions

TEST(cube_conventions) {
    const double axes[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    for (int f = 0; f < 6; f++) {
        double d[3];
        mlb_cube_texel_dir(f, 1.5, 1.5, 4, d);   // the face centre
        for (int k = 0; k < 3; k++) CHECK_CLOSE(d[k], axes[f][k], 0, 1e-12);
    }
    // texel (0, 0) of an N = 4 face: f = -0.75, directions as in reference.md §2
    const double e[6][3] = {{1, .75, .75}, {-1, .75, -.75}, {-.75, 1, -.75}, {-.75, -1, .75}, {-.75, .75, 1}, {.75, .75, -1}};
    for (int f = 0; f < 6; f++) {
        double d[3], len = sqrt(1 + 2 * .75 * .75);
        mlb_cube_texel_dir(f, 0, 0, 4, d);
        for (int k = 0; k < 3; k++) CHECK_CLOSE(d[k], e[f][k] / len, 0, 1e-12);
    }
    // texel weight: nvdiffrec's formula (with its offset on the low half), summed over a face
    int n = 16, H = 8;
    double s = 0, s1 = 0;
    for (int y = 0; y < n; y++)
        for (int x = 0; x < n; x++) s += mlb_cube_texel_solid_angle(x, y, n);
    for (int x = 0; x < n; x++) s1 += atan((abs(x - H) + 1.0) / H) - atan(abs(x - H) / (double)H);
    CHECK_CLOSE(s, s1 * s1, 1e-12, 0);
    CHECK_CLOSE(mlb_cube_texel_solid_angle(8, 8, 16), atan(1.0 / 8) * atan(1.0 / 8), 1e-12, 0);
    // direction -> texel round trip
    for (int f = 0; f < 6; f++)
        for (int y = 0; y < 8; y++)
            for (int x = 0; x < 8; x++) {
                double d[3], tx, ty;
                int g;
                mlb_cube_texel_dir(f, x, y, 8, d);
                mlb_cube_dir_to_texel(d, 8, &g, &tx, &ty);
                CHECK(g == f && fabs(tx - x) < 1e-9 && fabs(ty - y) < 1e-9);
            }
    // the base cube holds the bilinear lat-long value at each texel centre (no supersampling here)
    mlb_envmap env;
    REQUIRE(mlb_envmap_named(&env, "studio", 32) == MLB_OK);
    env.rotation = 1.0f;   // not baked in
    float* cube = malloc(6 * 64 * 64 * 3 * sizeof(float));
    REQUIRE(cube && mlb_cube_from_envmap(cube, 64, &env) == MLB_OK);
    env.rotation = 0;
    for (int i = 0; i < 100; i++) {
        int f = (int)mlb_rng_below(4, 1, i, 6), x = (int)mlb_rng_below(4, 2, i, 64), y = (int)mlb_rng_below(4, 3, i, 64);
        double d[3], v[3];
        mlb_cube_texel_dir(f, x, y, 64, d);
        mlb_envmap_lookup(&env, d, v);
        for (int c = 0; c < 3; c++) CHECK_CLOSE(cube[(((size_t)f * 64 + y) * 64 + x) * 3 + c], v[c], 1e-6, 1e-7);
    }
    free(cube);
    mlb_envmap_free(&env);
}

static float* random_cube(int n, uint64_t seed) {
    float* c = malloc((size_t)6 * n * n * 3 * sizeof(float));
    if (c) mlb_rng_fill_uniform(c, (size_t)6 * n * n * 3, seed, 0, 0, 0.0f, 1.0f);
    return c;
}

TEST(seamless_lookup) {
    enum { N = 8 };
    float* cube = random_cube(N, 11);
    REQUIRE(cube);
    const double eps = 1e-9;
    double worst = 0;
    for (int i = 0; i < 2000; i++) {
        // a random point on a random cube edge (two coordinates +-1), stepped to both sides
        double p[3], a[3], b[3], va[3], vb[3];
        int axis = (int)mlb_rng_below(5, 1, i, 3);
        for (int k = 0; k < 3; k++) p[k] = mlb_rng_uniform_f64(5, 2 + k, i) < 0.5 ? -1 : 1;
        p[axis] = 2 * mlb_rng_uniform_f64(5, 6, i) - 1;
        if (i % 10 == 0) p[axis] = p[axis] < 0 ? -1 : 1;   // some at the corners
        int o1 = (axis + 1) % 3, o2 = (axis + 2) % 3;
        for (int k = 0; k < 3; k++) a[k] = b[k] = p[k];
        a[o1] *= 1 - eps, b[o2] *= 1 - eps;   // a lies on the face of o2, b on the face of o1
        mlb_cube_sample(cube, N, a, va, NULL);
        mlb_cube_sample(cube, N, b, vb, NULL);
        for (int c = 0; c < 3; c++) worst = fmax(worst, fabs(va[c] - vb[c]));
    }
    printf("  largest jump across a face edge or corner: %.2e (texels in [0, 1])\n", worst);
    CHECK(worst < 1e-6);
    // and the lookup hits texel values at texel centres
    for (int f = 0; f < 6; f++) {
        double d[3], v[3];
        mlb_cube_texel_dir(f, 3, 5, N, d);
        mlb_cube_sample(cube, N, d, v, NULL);
        for (int c = 0; c < 3; c++) CHECK_CLOSE(v[c], cube[(((size_t)f * N + 5) * N + 3) * 3 + c], 1e-6, 1e-7);
    }
    free(cube);
}

// Central differences in double of lookups whose texels are float: the lookup arithmetic is
// double, so away from texel-centre lines (where bilinear interpolation has kinks; the stencil
// is skipped when it straddles one) the difference quotient converges to the analytic derivative
// to ~1e-8, and a wrong Jacobian term shows up as an O(1) error.
static int same_cell(const double a[3], const double b[3], int n) {
    int fa, fb;
    double xa, ya, xb, yb;
    mlb_cube_dir_to_texel(a, n, &fa, &xa, &ya);
    mlb_cube_dir_to_texel(b, n, &fb, &xb, &yb);
    return fa == fb && floor(xa) == floor(xb) && floor(ya) == floor(yb);
}

TEST(lookup_gradients) {
    enum { N = 8 };
    float* cube = random_cube(N, 12);
    REQUIRE(cube);
    const double h = 1e-6;
    int checked = 0;
    double worst = 0;
    for (int i = 0; i < 300; i++) {
        double d[3], v[3], jac[3][3];
        rand_dir(100 + i, d);
        for (int k = 0; k < 3; k++) d[k] *= 0.5 + mlb_rng_uniform_f64(6, 1, i);   // any length
        mlb_cube_sample(cube, N, d, v, jac);
        for (int k = 0; k < 3; k++) {
            double dp[3] = {d[0], d[1], d[2]}, dm[3] = {d[0], d[1], d[2]}, vp[3], vm[3];
            dp[k] += h, dm[k] -= h;
            if (!same_cell(dp, dm, N)) continue;
            mlb_cube_sample(cube, N, dp, vp, NULL);
            mlb_cube_sample(cube, N, dm, vm, NULL);
            for (int c = 0; c < 3; c++) worst = fmax(worst, fabs((vp[c] - vm[c]) / (2 * h) - jac[c][k]) / (1 + fabs(jac[c][k])));
            checked++;
        }
        double radial = 0;   // invariant to the length of d: the Jacobian is orthogonal to d
        for (int c = 0; c < 3; c++) radial = fmax(radial, fabs(jac[c][0] * d[0] + jac[c][1] * d[1] + jac[c][2] * d[2]));
        CHECK(radial < 1e-9);
    }
    printf("  cube lookup: %d directional derivatives, worst relative error %.2e\n", checked, worst);
    CHECK(checked > 800 && worst < 1e-6);
    free(cube);

    // the trilinear specular and the diffuse lookup of a built light, rotated
    mlb_envmap env;
    REQUIRE(mlb_envmap_named(&env, "overcast", 32) == MLB_OK);
    mlb_envlight light;
    mlb_envlight_options o = {.face_size = 16, .min_size = 4};
    REQUIRE(mlb_envlight_build(&light, &env, &o) == MLB_OK);
    mlb_envlight_set_rotation(&light, 0.7f);
    checked = 0, worst = 0;
    for (int i = 0; i < 200; i++) {
        double d[3], v[3], jd[3][3], jr[3], dm_dr, vn[3], jn[3][3];
        rand_dir(300 + i, d);
        double r = 0.1 + 0.85 * mlb_rng_uniform_f64(6, 2, i);
        double m = mlb_envlight_mip(&light, r, &dm_dr), mp = mlb_envlight_mip(&light, r + h, NULL), mm = mlb_envlight_mip(&light, r - h, NULL);
        mlb_envlight_specular(&light, d, r, v, jd, jr);
        mlb_envlight_diffuse(&light, d, vn, jn);
        if (floor(mp) == floor(mm) && (r - 0.5) * (r + h - 0.5) > 0 && (r - 0.5) * (r - h - 0.5) > 0) {
            double vp[3], vm[3];
            mlb_envlight_specular(&light, d, r + h, vp, NULL, NULL);
            mlb_envlight_specular(&light, d, r - h, vm, NULL, NULL);
            for (int c = 0; c < 3; c++) worst = fmax(worst, fabs((vp[c] - vm[c]) / (2 * h) - jr[c]) / (1 + fabs(jr[c])));
            checked++;
        }
        (void)m;
        for (int k = 0; k < 3; k++) {
            double dp[3] = {d[0], d[1], d[2]}, dn[3] = {d[0], d[1], d[2]}, lp[3], ln[3], vp[3], vm[3];
            dp[k] += h, dn[k] -= h;
            mlb_rotate_y(lp, dp, -0.7f);
            mlb_rotate_y(ln, dn, -0.7f);
            int ok = 1;
            for (int lv = 0; lv < light.n_levels; lv++) ok &= same_cell(lp, ln, light.size[lv]);
            if (!ok) continue;
            mlb_envlight_specular(&light, dp, r, vp, NULL, NULL);
            mlb_envlight_specular(&light, dn, r, vm, NULL, NULL);
            for (int c = 0; c < 3; c++) worst = fmax(worst, fabs((vp[c] - vm[c]) / (2 * h) - jd[c][k]) / (1 + fabs(jd[c][k])));
            mlb_envlight_diffuse(&light, dp, vp, NULL);
            mlb_envlight_diffuse(&light, dn, vm, NULL);
            for (int c = 0; c < 3; c++) worst = fmax(worst, fabs((vp[c] - vm[c]) / (2 * h) - jn[c][k]) / (1 + fabs(jn[c][k])));
            checked++;
        }
    }
    printf("  environment light: %d derivatives (direction, roughness), worst relative error %.2e\n", checked, worst);
    CHECK(checked > 500 && worst < 1e-6);
    // a rotation assigned directly to the field (not through the setter) is honoured too
    double da[3] = {0.3, 0.5, -0.8}, va[3], vb[3];
    mlb_envlight_set_rotation(&light, 1.1f);
    mlb_envlight_specular(&light, da, 0.3, va, NULL, NULL);
    mlb_envlight_set_rotation(&light, 0.0f);
    light.rotation = 1.1f;
    mlb_envlight_specular(&light, da, 0.3, vb, NULL, NULL);
    for (int c = 0; c < 3; c++) CHECK_CLOSE(va[c], vb[c], 1e-12, 1e-14);
    // mip schedule of reference.md §2 (L = 3 here: levels at roughness 0.08, 0.5, 1)
    CHECK(light.n_levels == 3);
    CHECK_CLOSE(mlb_envlight_mip(&light, 0.05, NULL), 0, 0, 1e-12);
    CHECK_CLOSE(mlb_envlight_mip(&light, 0.29, NULL), 0.5, 0, 1e-12);
    CHECK_CLOSE(mlb_envlight_mip(&light, 0.75, NULL), 1.5, 0, 1e-12);
    CHECK_CLOSE(mlb_envlight_mip(&light, 1.2, NULL), 2, 0, 1e-12);
    mlb_envlight_free(&light);
    mlb_envmap_free(&env);
}

// ---------------------------------------------------------------- pre-integration

TEST(constant_map_stays_constant) {
    mlb_envmap env;
    REQUIRE(mlb_envmap_named(&env, "white", 32) == MLB_OK);
    REQUIRE(mlb_envmap_scale(&env, 2.5f) == MLB_OK);
    mlb_envlight light;
    mlb_envlight_options o = {.face_size = 128, .min_size = 16};
    REQUIRE(mlb_envlight_build(&light, &env, &o) == MLB_OK);
    double worst = 0;
    for (int l = 0; l < light.n_levels; l++)
        for (size_t i = 0; i < (size_t)6 * light.size[l] * light.size[l] * 3; i++) worst = fmax(worst, fabs(light.spec[l][i] - 2.5));
    for (size_t i = 0; i < (size_t)6 * 16 * 16 * 3; i++) worst = fmax(worst, fabs(light.irr[i] - 2.5));
    CHECK(worst < 1e-5);
    CHECK(light.n_levels == 4 && light.size[3] == 16);
    CHECK_CLOSE(light.roughness[1], 0.29, 1e-6, 0);
    CHECK_CLOSE(light.roughness[3], 1.0, 0, 0);
    CHECK_CLOSE(light.cone[3], asin(sqrt(0.99)), 0, 2e-4);   // roughness 1: weight ~ cos sin -> sin^2 = 0.99
    mlb_envlight_free(&light);
    mlb_envlight_options bad = {.face_size = 96, .min_size = 16};
    CHECK(mlb_envlight_build(&light, &env, &bad) == MLB_ERR_ARG);
    mlb_envmap_free(&env);
}

// The tree walk against the exact sum over every texel of the cone, on maps with sharp light.
TEST(prefilter_tree_vs_exact) {
    const char* names[] = {"overcast", "studio", "sky"};
    for (int k = 0; k < 3; k++) {
        mlb_envmap env;
        REQUIRE(mlb_envmap_named(&env, names[k], 128) == MLB_OK);
        mlb_envlight a, b;
        mlb_envlight_options o = {.face_size = 128, .min_size = 16};
        REQUIRE(mlb_envlight_build(&a, &env, &o) == MLB_OK);
        o.exact = 1;
        REQUIRE(mlb_envlight_build(&b, &env, &o) == MLB_OK);
        for (int l = 0; l < 2; l++) {   // the levels above 32^2 (smaller ones are exact anyway)
            double num = 0, den = 0;
            for (size_t i = 0; i < (size_t)6 * a.size[l] * a.size[l]; i++) {
                num += fabs(lumf(a.spec[l] + 3 * i) - lumf(b.spec[l] + 3 * i));
                den += lumf(b.spec[l] + 3 * i);
            }
            printf("  %-8s level %d (%3d^2, roughness %.2f): mean |tree - exact| / mean = %.2e\n", names[k], l, a.size[l],
                   a.roughness[l], num / den);
            CHECK(num / den < 5e-3);
        }
        mlb_envlight_free(&a);
        mlb_envlight_free(&b);
        mlb_envmap_free(&env);
    }
}

// The prefiltered value at a texel against the definition evaluated directly on the lat-long map:
// sum over map pixels of L max(l.r, 0) D(r.h) dw / the same without L, inside the cone. With
// exact texel solid angles the cube's sum is a quadrature of the same integral; with reference.md's
// texel weights it is biased where the weights are wrong (small faces), which is printed.
static double definition_error(const mlb_envmap* env, int exact_sa, int face, int min) {
    mlb_envlight light;
    mlb_envlight_options o = {.face_size = face, .min_size = min, .reference_weights = !exact_sa};
    if (mlb_envlight_build(&light, env, &o) != MLB_OK) return 1e9;
    double worst = 0;
    printf("  %s texel weights, worst relative error per level:", exact_sa ? "exact" : "reference");
    for (int l = 1; l < light.n_levels; l++) {
        double a2 = pow(light.roughness[l], 4), cc = cos(light.cone[l]), lw = 0;
        for (int i = 0; i < 6; i++) {
            double r[3], v[3], num[3] = {0, 0, 0}, den = 0;
            int f = i, s = light.size[l], x = (int)mlb_rng_below(7, l, 2 * i, s), y = (int)mlb_rng_below(7, l, 2 * i + 1, s);
            mlb_cube_texel_dir(f, x, y, s, r);
            for (int j = 0; j < env->h; j++)
                for (int q = 0; q < env->w; q++) {
                    double d[3];
                    mlb_latlong_uv_to_dir((q + 0.5) / env->w, (j + 0.5) / env->h, d);
                    double c = d[0] * r[0] + d[1] * r[1] + d[2] * r[2];
                    if (c < cc || c <= 0) continue;
                    double ch2 = 0.5 * (1 + c), dd = ch2 * (a2 - 1) + 1, w = c * a2 / (PI * dd * dd) * pixel_sa(j, env->w, env->h);
                    const float* p = env->data + ((size_t)j * env->w + q) * 3;
                    for (int k = 0; k < 3; k++) num[k] += w * p[k];
                    den += w;
                }
            const float* t = light.spec[l] + (((size_t)f * s + y) * s + x) * 3;
            for (int k = 0; k < 3; k++) v[k] = t[k];
            double want = lum3(num) / den, got = lum3(v);
            lw = fmax(lw, fabs(got - want) / want);
        }
        printf("  %d^2 r=%.2f: %.3f", light.size[l], light.roughness[l], lw);
        worst = fmax(worst, lw);
    }
    printf("\n");
    mlb_envlight_free(&light);
    return worst;
}

TEST(prefilter_matches_definition) {
    mlb_envmap env;
    REQUIRE(mlb_envmap_named(&env, "studio", 256) == MLB_OK);
    CHECK(definition_error(&env, 1, 128, 16) < 0.025);
    CHECK(definition_error(&env, 0, 128, 16) < 0.25);
    mlb_envmap_free(&env);
}

static double irradiance_error(const mlb_envmap* env, int exact_sa) {
    mlb_envlight light;
    mlb_envlight_options o = {.face_size = 64, .min_size = 16, .reference_weights = !exact_sa};
    if (mlb_envlight_build(&light, env, &o) != MLB_OK) return 1e9;
    double worst = 0;
    for (int i = 0; i < 40; i++) {
        double n[3], v[3], want[3] = {0, 0, 0};
        rand_dir(500 + i, n);
        if (i == 0) n[0] = n[2] = 0, n[1] = 1;   // straight up: exactly the sky, irradiance / pi = 1
        if (i == 1) n[0] = n[2] = 0, n[1] = -1;  // straight down: the ground, 0.2
        for (int j = 0; j < env->h; j++)
            for (int q = 0; q < env->w; q++) {
                double d[3], dw[3];
                mlb_latlong_uv_to_dir((q + 0.5) / env->w, (j + 0.5) / env->h, d);
                mlb_rotate_y(dw, d, env->rotation);
                double c = dw[0] * n[0] + dw[1] * n[1] + dw[2] * n[2];
                if (c <= 0) continue;
                const float* p = env->data + ((size_t)j * env->w + q) * 3;
                for (int k = 0; k < 3; k++) want[k] += p[k] * c * pixel_sa(j, env->w, env->h) / PI;
            }
        mlb_envlight_diffuse(&light, n, v, NULL);
        if (i == 0) CHECK_CLOSE(lum3(v), 1.0, 0.01, 0);
        if (i == 1) CHECK_CLOSE(lum3(v), 0.2, 0.01, 0);
        worst = fmax(worst, fabs(lum3(v) - lum3(want)) / lum3(want));
    }
    CHECK(light.rotation == env->rotation);
    printf("  irradiance (%s texel weights) vs the cosine integral over the lat-long map: worst relative error %.4f\n",
           exact_sa ? "exact" : "reference", worst);
    mlb_envlight_free(&light);
    return worst;
}

TEST(irradiance_matches_definition) {
    mlb_envmap env;
    REQUIRE(mlb_envmap_named(&env, "overcast", 128) == MLB_OK);
    mlb_envmap_set_rotation(&env, 0.3f);
    CHECK(irradiance_error(&env, 1) < 0.01);
    CHECK(irradiance_error(&env, 0) < 0.04);
    mlb_envmap_free(&env);
}

TEST(build_is_thread_count_independent) {
    mlb_envmap env;
    REQUIRE(mlb_envmap_named(&env, "sky", 64) == MLB_OK);
    mlb_envlight a, b;
    mlb_envlight_options o = {.face_size = 64, .min_size = 8};
    int saved = omp_get_max_threads();
    omp_set_num_threads(1);
    REQUIRE(mlb_envlight_build(&a, &env, &o) == MLB_OK);
    omp_set_num_threads(2);
    REQUIRE(mlb_envlight_build(&b, &env, &o) == MLB_OK);
    omp_set_num_threads(saved);
    for (int l = 0; l < a.n_levels; l++)
        CHECK(memcmp(a.spec[l], b.spec[l], (size_t)6 * a.size[l] * a.size[l] * 3 * sizeof(float)) == 0);
    CHECK(memcmp(a.irr, b.irr, (size_t)6 * 8 * 8 * 3 * sizeof(float)) == 0);
    mlb_envlight_free(&a);
    mlb_envlight_free(&b);
    mlb_envmap_free(&env);
}

int main(void) {
    RUN(shared_hdr_files);
    RUN(hostile_hdr_files);
    RUN(exr_files_and_repairs);
    RUN(tiled_exr);
    RUN(procedural_environments);
    RUN(rotation_rotates_lookups);
    RUN(cube_conventions);
    RUN(seamless_lookup);
    RUN(lookup_gradients);
    RUN(constant_map_stays_constant);
    RUN(prefilter_tree_vs_exact);
    RUN(prefilter_matches_definition);
    RUN(irradiance_matches_definition);
    RUN(build_is_thread_count_independent);
    return test_summary();
}
