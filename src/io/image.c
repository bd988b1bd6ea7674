// PNG / JPEG loading through the system stb_image (libstb provides the implementation, so this
// file only includes the declarations). stb_image is permissive: it guesses formats (a text file
// can pass as a TGA), does not check PNG CRCs and decodes a truncated JPEG into grey garbage
// without complaint. Material maps feed training directly, so silently wrong pixels are worse
// than an error; hence the structural checks here before stb_image sees the bytes.
#include "matlaber/image.h"
#include "matlaber/fileio.h"
#include <errno.h>
#include <limits.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <stb/stb_image.h>
#include <zlib.h>

enum { FMT_PNG = 1, FMT_JPEG = 2 };

mlb_status mlb_image_file_read(const char* path, unsigned char** out, size_t* n_out) {
    char* b = NULL;
    mlb_status s = mlb_read_file(path, &b, n_out, INT_MAX);   // regular files only (fileio.h)
    if (s == MLB_ERR_NOT_FOUND) s = MLB_ERR_IO;   // this reader's contract: missing is an I/O error
    *out = (unsigned char*)b;
    return s;
}

static uint32_t be32(const unsigned char* p) {
    return ((uint32_t)p[0] << 24) | ((uint32_t)p[1] << 16) | ((uint32_t)p[2] << 8) | p[3];
}

// Walks the chunk list: every chunk must fit in the file and carry a correct CRC, IHDR first,
// IEND present. A truncated download or a flipped byte is caught here with a precise message
// instead of turning into a half-black training map.
static mlb_status check_png(const char* path, const unsigned char* b, size_t n, int* w, int* h, int* bits, int* ch) {
    size_t pos = 8;
    int seen_ihdr = 0, color_type = 0, trns = 0;
    while (1) {
        if (pos == n) return mlb_fail(MLB_ERR_FORMAT, "%s: truncated PNG (no IEND chunk; file ends at byte %zu)", path, n);
        if (n - pos < 12)
            return mlb_fail(MLB_ERR_FORMAT, "%s: truncated PNG (file ends inside a chunk header at byte %zu)", path, pos);
        uint32_t len = be32(b + pos);
        const unsigned char* type = b + pos + 4;
        char tname[5];
        for (int i = 0; i < 4; i++) tname[i] = (type[i] >= 32 && type[i] < 127) ? (char)type[i] : '?';
        tname[4] = 0;
        if (len > 0x7fffffffu)
            return mlb_fail(MLB_ERR_FORMAT, "%s: corrupt PNG (chunk '%s' at byte %zu claims %u bytes)", path, tname, pos, len);
        if ((size_t)len > n - pos - 12)
            return mlb_fail(MLB_ERR_FORMAT, "%s: truncated PNG (chunk '%s' at byte %zu needs %u bytes, file has %zu)", path,
                            tname, pos, len, n - pos - 12);
        uint32_t crc_stored = be32(b + pos + 8 + len);
        uint32_t crc = (uint32_t)crc32(0L, type, (uInt)len + 4);
        if (crc != crc_stored)
            return mlb_fail(MLB_ERR_FORMAT, "%s: corrupt PNG (CRC mismatch in chunk '%s' at byte %zu)", path, tname, pos);
        if (!seen_ihdr) {
            if (memcmp(type, "IHDR", 4) != 0 || len != 13)
                return mlb_fail(MLB_ERR_FORMAT, "%s: corrupt PNG (first chunk is '%s', expected IHDR)", path, tname);
            seen_ihdr = 1;
            uint32_t ww = be32(b + pos + 8), hh = be32(b + pos + 12);
            if (ww == 0 || hh == 0) return mlb_fail(MLB_ERR_FORMAT, "%s: PNG has zero size (%ux%u)", path, ww, hh);
            if (ww > 0x7fffffffu || hh > 0x7fffffffu)
                return mlb_fail(MLB_ERR_FORMAT, "%s: corrupt PNG (size %ux%u)", path, ww, hh);
            *w = (int)ww;
            *h = (int)hh;
            *bits = b[pos + 16] == 16 ? 16 : 8;
            color_type = b[pos + 17];
        }
        if (memcmp(type, "tRNS", 4) == 0) trns = 1;
        if (memcmp(type, "IEND", 4) == 0) {
            // Channels as stb_image reports them: palette images expand to RGB, or RGBA with tRNS.
            switch (color_type) {
            case 0: *ch = 1; break;
            case 2: *ch = 3; break;
            case 3: *ch = trns ? 4 : 3; break;
            case 4: *ch = 2; break;
            case 6: *ch = 4; break;
            default: return mlb_fail(MLB_ERR_FORMAT, "%s: corrupt PNG (colour type %d)", path, color_type);
            }
            return MLB_OK;   // trailing bytes after IEND are ignored, as libpng does
        }
        pos += 12 + (size_t)len;
    }
}

// In JPEG entropy-coded data every 0xFF byte is stuffed (FF 00), so a genuine FF D9 (end of
// image) after the last start-of-scan marker means the scan data is complete. An embedded EXIF
// thumbnail has its own SOS/EOI pair, but it sits before the main image's last SOS.
static mlb_status check_jpeg(const char* path, const unsigned char* b, size_t n) {
    size_t last_sos = 0, last_eoi = 0;
    int have_sos = 0, have_eoi = 0;
    for (size_t i = 2; i + 1 < n; i++) {
        if (b[i] != 0xFF) continue;
        if (b[i + 1] == 0xDA) { last_sos = i; have_sos = 1; }
        else if (b[i + 1] == 0xD9) { last_eoi = i; have_eoi = 1; }
    }
    if (!have_sos) return mlb_fail(MLB_ERR_FORMAT, "%s: truncated or corrupt JPEG (no image data: no start-of-scan marker)", path);
    if (!have_eoi || last_eoi < last_sos)
        return mlb_fail(MLB_ERR_FORMAT, "%s: truncated JPEG (no end-of-image marker after the image data)", path);
    return MLB_OK;
}

static int looks_like_text(const unsigned char* b, size_t n) {
    size_t m = n < 64 ? n : 64;
    for (size_t i = 0; i < m; i++) {
        unsigned char c = b[i];
        if (c < 9 || (c > 13 && c < 32) || c == 127) return 0;
    }
    return m > 0;
}

// Format sniffing and header checks shared by info and load. `max_pixels` (0: none) is checked
// before stb_image parses anything, because stb_image itself refuses headers whose w*h*c exceeds
// 2^30 with a misleading "unknown image type".
static mlb_status probe(const char* path, const unsigned char* b, size_t n, size_t max_pixels, int* fmt, int* w, int* h,
                        int* fc, int* bits) {
    static const unsigned char png_sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
    if (n == 0) return mlb_fail(MLB_ERR_FORMAT, "%s: empty file (0 bytes), not an image", path);
    if (n >= 8 && memcmp(b, png_sig, 8) == 0) {
        *fmt = FMT_PNG;
        MLB_TRY(check_png(path, b, n, w, h, bits, fc));
        size_t npix = (size_t)*w * (size_t)*h;
        if (max_pixels && npix > max_pixels)
            return mlb_fail(MLB_ERR_ARG, "%s: image of %dx%d = %zu pixels exceeds the limit of %zu pixels", path, *w, *h,
                            npix, max_pixels);
        if (npix * (size_t)*fc > ((size_t)1 << 30)) return MLB_OK;   // beyond stb_image's own check; header is ours
    } else if (n >= 3 && b[0] == 0xFF && b[1] == 0xD8 && b[2] == 0xFF) {
        *fmt = FMT_JPEG;
        *bits = 8;
        MLB_TRY(check_jpeg(path, b, n));
    } else if (n < 8 && b[0] == 0x89) {
        return mlb_fail(MLB_ERR_FORMAT, "%s: truncated PNG (%zu bytes, shorter than the signature)", path, n);
    } else {
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: not an image: neither PNG nor JPEG%s", path,
                        looks_like_text(b, n) ? " (the file looks like text)" : " (unrecognised signature)");
    }
    int sw = 0, sh = 0, sc = 0;
    if (!stbi_info_from_memory(b, (int)n, &sw, &sh, &sc)) {
        const char* why = stbi_failure_reason();
        return mlb_fail(MLB_ERR_FORMAT, "%s: corrupt %s header (stb_image: %s)", path, *fmt == FMT_PNG ? "PNG" : "JPEG",
                        why ? why : "unknown");
    }
    if (sw <= 0 || sh <= 0) return mlb_fail(MLB_ERR_FORMAT, "%s: image has zero size (%dx%d)", path, sw, sh);
    if (*fmt == FMT_PNG && (sw != *w || sh != *h))
        return mlb_fail(MLB_ERR_FORMAT, "%s: corrupt PNG header (size %dx%d vs %dx%d)", path, *w, *h, sw, sh);
    *w = sw;
    *h = sh;
    *fc = sc;
    size_t npix = (size_t)sw * (size_t)sh;
    if (max_pixels && npix > max_pixels)
        return mlb_fail(MLB_ERR_ARG, "%s: image of %dx%d = %zu pixels exceeds the limit of %zu pixels", path, sw, sh, npix,
                        max_pixels);
    return MLB_OK;
}

mlb_status mlb_image_info(const char* path, int* w, int* h, int* file_channels, int* bits) {
    if (!path) return mlb_fail(MLB_ERR_ARG, "image path is NULL");
    unsigned char* b;
    size_t n;
    MLB_TRY(mlb_image_file_read(path, &b, &n));
    int fmt = 0, ww = 0, hh = 0, fc = 0, bt = 8;
    mlb_status s = probe(path, b, n, 0, &fmt, &ww, &hh, &fc, &bt);
    free(b);
    if (s != MLB_OK) return s;
    if (w) *w = ww;
    if (h) *h = hh;
    if (file_channels) *file_channels = fc;
    if (bits) *bits = bt;
    return MLB_OK;
}

mlb_status mlb_image_load_limit(mlb_image* img, const char* path, int channels, size_t max_pixels) {
    if (!img) return mlb_fail(MLB_ERR_ARG, "image output is NULL");
    memset(img, 0, sizeof *img);
    if (!path) return mlb_fail(MLB_ERR_ARG, "image path is NULL");
    if (channels < 0 || channels > 4) return mlb_fail(MLB_ERR_ARG, "%s: channels %d must be 0..4", path, channels);
    if (max_pixels == 0) max_pixels = MLB_IMAGE_MAX_PIXELS;

    unsigned char* b;
    size_t n;
    MLB_TRY(mlb_image_file_read(path, &b, &n));
    int fmt = 0, w = 0, h = 0, fc = 0, bits = 8;
    mlb_status s = probe(path, b, n, max_pixels, &fmt, &w, &h, &fc, &bits);
    if (s != MLB_OK) {
        free(b);
        return s;
    }
    // Size checks before any pixel allocation: the header alone decides.
    size_t npix = (size_t)w * (size_t)h;   // w, h < 2^31 each: cannot overflow a 64-bit size_t
    int c = channels ? channels : fc;
    if (c < 1 || c > 4 || npix > SIZE_MAX / sizeof(float) / (size_t)c) {
        free(b);
        return mlb_fail(MLB_ERR_ARG, "%s: image of %dx%d with %d channels is too large to hold", path, w, h, c);
    }
    size_t count = npix * (size_t)c;
    float* data = malloc(count * sizeof(float));
    if (!data) {
        free(b);
        return mlb_fail(MLB_ERR_NOMEM, "%s: cannot allocate %zu floats for %dx%dx%d", path, count, w, h, c);
    }
    int dw = 0, dh = 0, dc = 0;
    if (bits == 16) {
        stbi_us* px = stbi_load_16_from_memory(b, (int)n, &dw, &dh, &dc, c);
        if (px && dw == w && dh == h) {
            for (size_t i = 0; i < count; i++) data[i] = (float)px[i] / 65535.0f;   // division: exactly the nearest float to v/65535
        }
        if (px) stbi_image_free(px);
        else s = MLB_ERR_FORMAT;
    } else {
        stbi_uc* px = stbi_load_from_memory(b, (int)n, &dw, &dh, &dc, c);
        if (px && dw == w && dh == h) {
            for (size_t i = 0; i < count; i++) data[i] = (float)px[i] / 255.0f;
        }
        if (px) stbi_image_free(px);
        else s = MLB_ERR_FORMAT;
    }
    free(b);
    if (s != MLB_OK) {
        free(data);
        const char* why = stbi_failure_reason();
        return mlb_fail(MLB_ERR_FORMAT, "%s: corrupt %s data (stb_image: %s)", path, fmt == FMT_PNG ? "PNG" : "JPEG",
                        why ? why : "unknown");
    }
    if (dw != w || dh != h) {
        free(data);
        return mlb_fail(MLB_ERR_FORMAT, "%s: decoded size %dx%d differs from the header's %dx%d", path, dw, dh, w, h);
    }
    img->data = data;
    img->w = w;
    img->h = h;
    img->c = c;
    img->file_channels = fc;
    img->bits = bits;
    return MLB_OK;
}

mlb_status mlb_image_load(mlb_image* img, const char* path, int channels) {
    return mlb_image_load_limit(img, path, channels, 0);
}

void mlb_image_free(mlb_image* img) {
    if (!img) return;
    free(img->data);
    memset(img, 0, sizeof *img);
}
