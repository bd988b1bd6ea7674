// Image writers: PNG through libpng, Radiance RGBE written here, OpenEXR through tinyexr (into
// memory, then to disk). Every file goes through the atomic file API. Encodings and guarantees
// are in include/matlaber/image_write.h and docs/files.md.
#include "matlaber/image_write.h"
#include <limits.h>
#include <math.h>
#include <png.h>
#include <setjmp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <tinyexr.h>
#include "matlaber/fileio.h"
#include "matlaber/half.h"

static mlb_status check_args(const char* fn, const char* path, const float* data, int w, int h, int c) {
    if (!path) return mlb_fail(MLB_ERR_ARG, "%s: NULL path", fn);
    if (!data) return mlb_fail(MLB_ERR_ARG, "%s: NULL pixel data", path);
    if (w < 1 || h < 1) return mlb_fail(MLB_ERR_ARG, "%s: image size %dx%d (both must be positive)", path, w, h);
    if (c < 1 || c > 4) return mlb_fail(MLB_ERR_ARG, "%s: %d channels (1 to 4 allowed)", path, c);
    if ((size_t)w * (size_t)h > MLB_IMAGE_MAX_PIXELS)
        return mlb_fail(MLB_ERR_ARG, "%s: %dx%d is more than the %zu pixels allowed", path, w, h, MLB_IMAGE_MAX_PIXELS);
    return MLB_OK;
}

// ---- PNG ----

typedef struct { char msg[256], warning[256]; } png_error_box;

// libpng calls this on a fatal error and must not get control back: keep the message, jump back.
static void png_on_error(png_structp png, png_const_charp msg) {
    png_error_box* box = png_get_error_ptr(png);
    if (box) snprintf(box->msg, sizeof box->msg, "%s", msg ? msg : "unknown error");
    png_longjmp(png, 1);
}

// Warnings are not printed (the library never prints); the last one is kept, because libpng often
// explains an error in a warning just before it ("Image width exceeds user limit in IHDR").
static void png_on_warning(png_structp png, png_const_charp msg) {
    png_error_box* box = png_get_error_ptr(png);
    if (box) snprintf(box->warning, sizeof box->warning, "%s", msg ? msg : "");
}

static double linear_to_srgb(double x) { return x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1.0 / 2.4) - 0.055; }

// NaN -> 0, clamp to [0, 1], optional sRGB encoding, round to the nearest code (halves up).
static unsigned quantize(float v, int srgb, unsigned maxv) {
    double x = v;
    if (!(x > 0)) x = 0;
    if (x > 1) x = 1;
    if (srgb) x = linear_to_srgb(x);
    unsigned q = (unsigned)(x * maxv + 0.5);
    return q > maxv ? maxv : q;
}

// Everything libpng touches between setjmp and a longjmp back is set up before setjmp and not
// changed afterwards (C11 7.13.2.1), so no volatile is needed.
static int png_encode(png_structp png, png_infop info, FILE* f, const float* data, int w, int h, int c, int bits,
                      int srgb, unsigned char* row) {
    if (setjmp(png_jmpbuf(png))) return 0;
    static const int color_types[5] = {0, PNG_COLOR_TYPE_GRAY, PNG_COLOR_TYPE_GRAY_ALPHA, PNG_COLOR_TYPE_RGB,
                                       PNG_COLOR_TYPE_RGB_ALPHA};
    png_init_io(png, f);
    png_set_IHDR(png, info, (png_uint_32)w, (png_uint_32)h, bits, color_types[c], PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    if (srgb) png_set_sRGB_gAMA_and_cHRM(png, info, PNG_sRGB_INTENT_PERCEPTUAL);
    png_write_info(png, info);
    unsigned maxv = bits == 16 ? 65535u : 255u;
    int alpha = (c == 2 || c == 4) ? c - 1 : -1;
    for (int y = 0; y < h; y++) {
        const float* src = data + (size_t)y * (size_t)w * (size_t)c;
        for (size_t i = 0; i < (size_t)w * (size_t)c; i++) {
            unsigned q = quantize(src[i], srgb && (int)(i % (size_t)c) != alpha, maxv);
            if (bits == 16) {
                row[2 * i] = (unsigned char)(q >> 8);   // PNG samples are big-endian
                row[2 * i + 1] = (unsigned char)(q & 0xff);
            } else {
                row[i] = (unsigned char)q;
            }
        }
        png_write_row(png, row);
    }
    png_write_end(png, info);
    return 1;
}

mlb_status mlb_image_write_png(const char* path, const float* data, int w, int h, int c, const mlb_png_options* opt) {
    MLB_TRY(check_args("mlb_image_write_png", path, data, w, h, c));
    int bits = opt && opt->bits ? opt->bits : 8;
    mlb_png_encoding enc = opt ? opt->encoding : MLB_PNG_AS_IS;
    if (bits != 8 && bits != 16) return mlb_fail(MLB_ERR_ARG, "%s: %d bits per sample (PNG: 8 or 16)", path, bits);
    if (enc != MLB_PNG_AS_IS && enc != MLB_PNG_SRGB)
        return mlb_fail(MLB_ERR_ARG, "%s: unknown PNG encoding %d", path, (int)enc);
    unsigned char* row = malloc((size_t)w * (size_t)c * (size_t)(bits / 8));
    if (!row) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for a row of %d pixels", path, w);
    png_error_box box = {{0}, {0}};
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &box, png_on_error, png_on_warning);
    png_infop info = png ? png_create_info_struct(png) : NULL;
    if (!info) {
        png_destroy_write_struct(png ? &png : NULL, NULL);
        free(row);
        return mlb_fail(MLB_ERR_NOMEM, "%s: cannot create the PNG writer", path);
    }
    mlb_atomic_file af;
    mlb_status s = mlb_atomic_open(&af, path);
    if (s != MLB_OK) {
        png_destroy_write_struct(&png, &info);
        free(row);
        return s;
    }
    int ok = png_encode(png, info, af.f, data, w, h, c, bits, enc == MLB_PNG_SRGB, row);
    png_destroy_write_struct(&png, &info);
    free(row);
    if (!ok) {
        int io = ferror(af.f);
        mlb_atomic_abort(&af);
        return mlb_fail(io ? MLB_ERR_IO : MLB_ERR_FORMAT, "%s: PNG writing failed: %s%s%s%s", path, box.msg,
                        box.warning[0] ? " (" : "", box.warning, box.warning[0] ? ")" : "");
    }
    return mlb_atomic_commit(&af);
}

// ---- Radiance RGBE ----

static float hdr_sanitize(float v) {
    if (!(v > 0)) return 0.0f;   // NaN, negative, zero
    return v > 1e38f ? 1e38f : v;
}

// Radiance's encoding: e such that max = f * 2^e with f in [0.5, 1); mantissas m = floor(x * 2^(8-e)).
// The scaling by a power of two is exact in double, so m < 256 holds without fudge factors.
static void to_rgbe(const float rgb[3], unsigned char out[4]) {
    float r = hdr_sanitize(rgb[0]), g = hdr_sanitize(rgb[1]), b = hdr_sanitize(rgb[2]);
    float mx = r > g ? r : g;
    if (b > mx) mx = b;
    if (mx < 1e-32f) {
        out[0] = out[1] = out[2] = out[3] = 0;
        return;
    }
    int e;
    frexp(mx, &e);
    double scale = ldexp(1.0, 8 - e);
    out[0] = (unsigned char)(r * scale);
    out[1] = (unsigned char)(g * scale);
    out[2] = (unsigned char)(b * scale);
    out[3] = (unsigned char)(e + 128);
}

// New-style RLE of one component: runs of 3..127 equal bytes as (128 + n, byte), everything
// else as literal blocks (n <= 128, then n bytes). Output is at most n + ceil(n / 128) bytes.
static size_t rle_component(const unsigned char* d, int n, unsigned char* out) {
    size_t o = 0;
    int i = 0;
    while (i < n) {
        int run = 1;
        while (i + run < n && run < 127 && d[i + run] == d[i]) run++;
        if (run >= 3) {
            out[o++] = (unsigned char)(128 + run);
            out[o++] = d[i];
            i += run;
            continue;
        }
        int start = i, len = 0;
        while (i < n && len < 128) {
            if (i + 2 < n && d[i] == d[i + 1] && d[i] == d[i + 2]) break;
            i++;
            len++;
        }
        out[o++] = (unsigned char)len;
        memcpy(out + o, d + start, (size_t)len);
        o += (size_t)len;
    }
    return o;
}

mlb_status mlb_image_write_hdr(const char* path, const float* data, int w, int h, int c) {
    MLB_TRY(check_args("mlb_image_write_hdr", path, data, w, h, c));
    int rle = w >= 8 && w < 32768;
    size_t wn = (size_t)w;
    unsigned char* px = malloc(4 * wn);                        // the scanline as RGBE, pixel by pixel
    unsigned char* comp = malloc(wn);                          // one component of it
    unsigned char* enc = malloc(4 + 4 * (wn + wn / 128 + 1));  // the encoded scanline
    if (!px || !comp || !enc) {
        free(px); free(comp); free(enc);
        return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for a row of %d pixels", path, w);
    }
    mlb_atomic_file af;
    mlb_status s = mlb_atomic_open(&af, path);
    if (s != MLB_OK) {
        free(px); free(comp); free(enc);
        return s;
    }
    int ok = fprintf(af.f, "#?RADIANCE\n# written by matlaber\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n", h, w) > 0;
    for (int y = 0; ok && y < h; y++) {
        const float* src = data + (size_t)y * wn * (size_t)c;
        for (size_t x = 0; x < wn; x++) {
            const float* p = src + x * (size_t)c;
            float rgb[3] = {p[0], c >= 3 ? p[1] : p[0], c >= 3 ? p[2] : p[0]};
            to_rgbe(rgb, px + 4 * x);
        }
        if (!rle) {
            ok = fwrite(px, 4, wn, af.f) == wn;
            continue;
        }
        size_t o = 0;
        enc[o++] = 2;
        enc[o++] = 2;
        enc[o++] = (unsigned char)(w >> 8);
        enc[o++] = (unsigned char)(w & 0xff);
        for (int k = 0; k < 4; k++) {
            for (size_t x = 0; x < wn; x++) comp[x] = px[4 * x + (size_t)k];
            o += rle_component(comp, w, enc + o);
        }
        ok = fwrite(enc, 1, o, af.f) == o;
    }
    free(px); free(comp); free(enc);
    if (!ok) {
        mlb_atomic_abort(&af);
        return mlb_fail(MLB_ERR_IO, "%s: write failed", path);
    }
    return mlb_atomic_commit(&af);
}

// ---- OpenEXR ----

mlb_status mlb_image_write_exr(const char* path, const float* data, int w, int h, int c, const mlb_exr_options* opt) {
    MLB_TRY(check_args("mlb_image_write_exr", path, data, w, h, c));
    mlb_exr_pixel pix = opt ? opt->pixel : MLB_EXR_HALF;
    mlb_exr_compression comp = opt ? opt->compression : MLB_EXR_ZIP;
    if (pix != MLB_EXR_HALF && pix != MLB_EXR_FLOAT) return mlb_fail(MLB_ERR_ARG, "%s: unknown EXR pixel type %d", path, (int)pix);
    if (comp != MLB_EXR_ZIP && comp != MLB_EXR_NONE)
        return mlb_fail(MLB_ERR_ARG, "%s: unknown EXR compression %d", path, (int)comp);
    // An EXR chunk (16 scanlines for ZIP) records its size in 32 bits.
    size_t bytes = pix == MLB_EXR_HALF ? 2 : 4;
    if ((size_t)w * (size_t)c * bytes * 16 > (size_t)INT_MAX)
        return mlb_fail(MLB_ERR_ARG, "%s: rows of %d pixels are too wide for an EXR file", path, w);

    // Channels in EXR's alphabetical order, and which input channel feeds each.
    static const char* names[5][4] = {{0}, {"Y"}, {"A", "Y"}, {"B", "G", "R"}, {"A", "B", "G", "R"}};
    static const int src_ch[5][4] = {{0}, {0}, {1, 0}, {2, 1, 0}, {3, 2, 1, 0}};
    size_t np = (size_t)w * (size_t)h;
    unsigned char* planes[4] = {0};
    for (int k = 0; k < c; k++) {
        planes[k] = malloc(np * bytes);
        if (!planes[k]) {
            for (int j = 0; j < k; j++) free(planes[j]);
            return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for a %dx%d EXR image", path, w, h);
        }
        int s = src_ch[c][k];
        if (pix == MLB_EXR_HALF) {
            uint16_t* dst = (uint16_t*)planes[k];
            for (size_t i = 0; i < np; i++) dst[i] = mlb_f32_to_f16(data[i * (size_t)c + (size_t)s]);
        } else {
            float* dst = (float*)planes[k];
            for (size_t i = 0; i < np; i++) dst[i] = data[i * (size_t)c + (size_t)s];
        }
    }
    EXRHeader hdr;
    EXRImage img;
    InitEXRHeader(&hdr);
    InitEXRImage(&img);
    EXRChannelInfo chans[4];
    int types[4], requested[4];
    memset(chans, 0, sizeof chans);
    int t = pix == MLB_EXR_HALF ? TINYEXR_PIXELTYPE_HALF : TINYEXR_PIXELTYPE_FLOAT;
    for (int k = 0; k < c; k++) {
        snprintf(chans[k].name, sizeof chans[k].name, "%s", names[c][k]);
        chans[k].pixel_type = t;
        chans[k].x_sampling = chans[k].y_sampling = 1;
        types[k] = requested[k] = t;
    }
    hdr.num_channels = c;
    hdr.channels = chans;
    hdr.pixel_types = types;
    hdr.requested_pixel_types = requested;
    hdr.compression_type = comp == MLB_EXR_ZIP ? TINYEXR_COMPRESSIONTYPE_ZIP : TINYEXR_COMPRESSIONTYPE_NONE;
    hdr.pixel_aspect_ratio = 1.0f;
    hdr.screen_window_width = 1.0f;
    img.images = planes;
    img.width = w;
    img.height = h;
    img.num_channels = c;
    unsigned char* mem = NULL;
    const char* err = NULL;
    size_t n = SaveEXRImageToMemory(&img, &hdr, &mem, &err);
    for (int k = 0; k < c; k++) free(planes[k]);
    if (n == 0) {
        mlb_status s = mlb_fail(MLB_ERR_FORMAT, "%s: EXR encoding failed: %s", path, err ? err : "unknown error");
        if (err) FreeEXRErrorMessage(err);
        free(mem);
        return s;
    }
    mlb_status s = mlb_write_file_atomic(path, mem, n);
    free(mem);
    return s;
}

// ---- by extension ----

mlb_status mlb_image_write(const char* path, const mlb_image* img, const mlb_png_options* png) {
    if (!path) return mlb_fail(MLB_ERR_ARG, "mlb_image_write: NULL path");
    if (!img) return mlb_fail(MLB_ERR_ARG, "%s: NULL image", path);
    const char* dot = strrchr(path, '.');
    const char* slash = strrchr(path, '/');
    if (dot && (!slash || dot > slash)) {
        if (!strcasecmp(dot, ".png")) return mlb_image_write_png(path, img->data, img->w, img->h, img->c, png);
        if (!strcasecmp(dot, ".hdr")) return mlb_image_write_hdr(path, img->data, img->w, img->h, img->c);
        if (!strcasecmp(dot, ".exr")) return mlb_image_write_exr(path, img->data, img->w, img->h, img->c, NULL);
    }
    return mlb_fail(MLB_ERR_ARG, "%s: cannot tell the image format from the name (use .png, .hdr or .exr)", path);
}
