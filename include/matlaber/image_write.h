// Image writers: PNG (8/16-bit, libpng), Radiance .hdr (RGBE) and OpenEXR (tinyexr). All take
// interleaved float samples (`h` rows of `w` pixels of `c` floats, top row first: the layout of
// mlb_image), 1 <= c <= 4, at most MLB_IMAGE_MAX_PIXELS pixels, and all write through
// mlb_atomic_open/commit: the file appears complete or not at all, never half-written. Errors name
// the path: MLB_ERR_ARG (NULL, size, channels), MLB_ERR_IO (folder missing or not writable, disk
// full), MLB_ERR_NOMEM, MLB_ERR_FORMAT (the encoder refused). docs/files.md has the details.
#ifndef MATLABER_IMAGE_WRITE_H
#define MATLABER_IMAGE_WRITE_H
#include "matlaber/error.h"
#include "matlaber/image.h"

// ---- PNG ----
// Channels: 1 grey, 2 grey+alpha, 3 RGB, 4 RGBA. Each sample is mapped to an integer code:
//   NaN -> 0; clamp to [0, 1]; (sRGB only, colour channels only) encode with the exact
//   IEC 61966-2-1 curve (x <= 0.0031308 ? 12.92 x : 1.055 x^(1/2.4) - 0.055) in double;
//   code = round(x * (2^bits - 1)), halves rounding up.
// Alpha (channel 2 of 2, channel 4 of 4) is always written as it is. With MLB_PNG_SRGB the file
// gets an sRGB chunk (with the matching gAMA/cHRM); MLB_PNG_AS_IS writes no colour-space chunk.
// mlb_image_load reads a file written as-is back to code / (2^bits - 1), the exact value written
// for inputs that are multiples of 1/(2^bits - 1).
typedef enum {
    MLB_PNG_AS_IS = 0,   // values as they are (already sRGB colours, or data such as roughness)
    MLB_PNG_SRGB = 1,    // linear values, encoded to sRGB on write
} mlb_png_encoding;

typedef struct {
    int bits;                    // 8 or 16; 0 = 8
    mlb_png_encoding encoding;   // default MLB_PNG_AS_IS
} mlb_png_options;

// opt NULL: 8-bit, as is.
mlb_status mlb_image_write_png(const char* path, const float* data, int w, int h, int c, const mlb_png_options* opt);

// ---- Radiance .hdr (RGBE) ----
// Linear radiance in the "32-bit_rle_rgbe" format with a "-Y h +X w" (top row first) header;
// scanlines 8..32767 pixels wide are run-length encoded (the new-style RLE), others flat.
// c = 1 or 2: channel 0 is written as grey (R = G = B); c = 3 or 4: RGB. Alpha is dropped (the
// format has none). NaN and negative samples become 0; samples above 1e38 (and +Inf) become 1e38.
// The mantissas are truncated as in Radiance's own writer, so a reader that decodes
// (m + 0.5) * 2^(e-136) (Radiance) is unbiased and one that decodes m * 2^(e-136) (stb_image) reads
// up to one step low: relative to the pixel's largest component, the error is below 2^-7.
mlb_status mlb_image_write_hdr(const char* path, const float* data, int w, int h, int c);

// ---- OpenEXR ----
// Scanline single-part file, channels named (alphabetically, as EXR orders them) Y (c = 1),
// A Y (c = 2, grey + alpha), B G R (c = 3), A B G R (c = 4).
// MLB_EXR_HALF: each sample rounded to float16 (nearest, ties to even; magnitudes above 65504
// become +-Inf, NaN stays NaN); MLB_EXR_FLOAT: the float bits exactly. Values are written as they
// are: no clamping, NaN and Inf kept (EXR can hold them).
typedef enum { MLB_EXR_HALF = 0, MLB_EXR_FLOAT = 1 } mlb_exr_pixel;
typedef enum { MLB_EXR_ZIP = 0, MLB_EXR_NONE = 1 } mlb_exr_compression;
typedef struct {
    mlb_exr_pixel pixel;               // default MLB_EXR_HALF
    mlb_exr_compression compression;   // default MLB_EXR_ZIP (lossless, 16 scanlines per block)
} mlb_exr_options;

// opt NULL: half, ZIP.
mlb_status mlb_image_write_exr(const char* path, const float* data, int w, int h, int c, const mlb_exr_options* opt);

// Picks the writer from the extension (.png, .hdr, .exr; case-insensitive) and writes img with
// the defaults above; for .png, `png` (may be NULL) gives the options.
mlb_status mlb_image_write(const char* path, const mlb_image* img, const mlb_png_options* png);

#endif
