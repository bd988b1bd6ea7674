// Image loading: PNG (8 or 16 bits per channel) and baseline/progressive JPEG, decoded by the
// system's stb_image into interleaved float samples in [0, 1]. Values are returned as stored
// (no sRGB decoding): colour-space conversion is the caller's business because the same file
// type holds sRGB colours in one map and linear roughness in the next.
#ifndef MATLABER_IMAGE_H
#define MATLABER_IMAGE_H
#include <stddef.h>
#include "matlaber/error.h"

// Largest image accepted by default (pixels, not bytes): 2^28 = 16384 x 16384. A 4-channel
// float copy of that is 4 GiB, already more than any material map needs; the limit exists so
// that a corrupt or hostile header cannot make us allocate absurd amounts.
#define MLB_IMAGE_MAX_PIXELS ((size_t)1 << 28)

typedef struct {
    float* data;       // h rows of w pixels of c floats, top row first; malloc'd
    int w, h;          // pixels
    int c;             // channels in `data` (1..4)
    int file_channels; // channels stored in the file (1 grey, 2 grey+alpha, 3 RGB, 4 RGBA)
    int bits;          // 8 or 16: the file's bits per channel
} mlb_image;

// Loads `path`. `channels` = 0 keeps the file's channel count; 1..4 converts the way stb_image
// does (grey <-> RGB replication, alpha added as 1 or dropped; RGB -> grey uses the
// ITU-R BT.601 luma weights). Errors name the file: MLB_ERR_IO (missing / unreadable),
// MLB_ERR_UNSUPPORTED (not a PNG or JPEG), MLB_ERR_FORMAT (truncated, bad checksum, corrupt
// data, zero size), MLB_ERR_ARG (more than the pixel limit, or w*h*c would overflow).
mlb_status mlb_image_load(mlb_image* img, const char* path, int channels);
// Same with an explicit pixel limit (0 = MLB_IMAGE_MAX_PIXELS).
mlb_status mlb_image_load_limit(mlb_image* img, const char* path, int channels, size_t max_pixels);
// Reads only the header: size and stored channel count / bit depth. Same checks as loading,
// except that the pixel data is not decoded (a truncated body may go unnoticed).
mlb_status mlb_image_info(const char* path, int* w, int* h, int* file_channels, int* bits);
// A whole image file in memory, for the loaders that decode it (this file's and envmap.h's):
// mlb_read_file (regular files only) of at most INT_MAX bytes, since stb_image takes an int length
// (no image comes near 2 GiB compressed); a missing file is MLB_ERR_IO, as every image loader says.
// *out is malloc'd.
mlb_status mlb_image_file_read(const char* path, unsigned char** out, size_t* n);
void mlb_image_free(mlb_image* img);   // safe on a zeroed or already freed image

// Sample (x, y, ch) of a loaded image; no bounds checks.
static inline float mlb_image_at(const mlb_image* img, int x, int y, int ch) {
    return img->data[((size_t)y * (size_t)img->w + (size_t)x) * (size_t)img->c + (size_t)ch];
}

#endif
