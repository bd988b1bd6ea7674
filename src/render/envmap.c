// Lat-long environment maps: Radiance .hdr / OpenEXR loading with structural checks and repairs,
// the built-in procedural environments, rotation about +y, bilinear lookup and importance sampling.
// stb_image decodes RGBE but is permissive (a truncated file decodes into zeros without complaint),
// so the header and every scanline's run-length structure are walked here first; tinyexr parses
// the EXR header before anything the size of the image is allocated.
#include "matlaber/envmap.h"
#include "matlaber/fileio.h"
#include "matlaber/image.h"
#include <errno.h>
#include <float.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <stb/stb_image.h>
#include <tinyexr.h>
#include "matlaber/log.h"

#define PI 3.14159265358979323846

static double luminance(const float* p) { return 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]; }

// ---------------------------------------------------------------- files

static mlb_status check_size(const char* path, long long w, long long h) {
    if (w <= 0 || h <= 0) return mlb_fail(MLB_ERR_FORMAT, "%s: image size %lldx%lld is empty", path, w, h);
    if ((unsigned long long)w * (unsigned long long)h > MLB_ENVMAP_MAX_PIXELS)
        return mlb_fail(MLB_ERR_ARG, "%s: %lldx%lld pixels is more than the limit of %zu for an environment map", path, w, h,
                        (size_t)MLB_ENVMAP_MAX_PIXELS);
    if (w != 2 * h)
        return mlb_fail(MLB_ERR_FORMAT, "%s: %lldx%lld is not a lat-long environment map (width must be twice the height)",
                        path, w, h);
    return MLB_OK;
}

// Radiance RGBE: "#?RADIANCE" or "#?RGBE", header lines up to an empty line (FORMAT must be
// 32-bit_rle_rgbe), then "-Y h +X w" and the scanlines, each flat (4 bytes a pixel) or new-style
// RLE (2, 2, w>>8, w&255, then four channels of runs). The walk mirrors what stb_image accepts.
static mlb_status hdr_check(const char* path, const unsigned char* b, size_t n, int* w_out, int* h_out) {
    size_t pos = 0;
    char line[1024];
    int line_no = 0, format_ok = 0;
    for (;;) {
        size_t len = 0;
        while (pos < n && b[pos] != '\n') {
            if (len + 1 < sizeof line) line[len++] = (char)b[pos];
            pos++;
        }
        if (pos >= n) return mlb_fail(MLB_ERR_FORMAT, "%s: truncated Radiance header (no resolution line)", path);
        pos++;
        line[len] = 0;
        if (line_no++ == 0) {
            if (strcmp(line, "#?RADIANCE") != 0 && strcmp(line, "#?RGBE") != 0)
                return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: not a Radiance .hdr file", path);
            continue;
        }
        if (len == 0) break;
        if (strncmp(line, "FORMAT=", 7) == 0) {
            if (strcmp(line + 7, "32-bit_rle_rgbe") != 0)
                return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: Radiance format '%s' is not supported (only 32-bit_rle_rgbe)", path,
                                line + 7);
            format_ok = 1;
        }
    }
    if (!format_ok) return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: Radiance header has no FORMAT=32-bit_rle_rgbe line", path);
    size_t len = 0;
    while (pos < n && b[pos] != '\n' && len + 1 < sizeof line) line[len++] = (char)b[pos++];
    line[len] = 0;
    if (pos >= n || b[pos] != '\n') return mlb_fail(MLB_ERR_FORMAT, "%s: truncated Radiance header (resolution line)", path);
    pos++;
    char* end;
    if (strncmp(line, "-Y ", 3) != 0)
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: Radiance layout '%s' is not supported (only -Y h +X w)", path, line);
    errno = 0;
    long long h = strtoll(line + 3, &end, 10);
    while (*end == ' ') end++;
    if (errno || strncmp(end, "+X ", 3) != 0)
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: Radiance layout '%s' is not supported (only -Y h +X w)", path, line);
    long long w = strtoll(end + 3, &end, 10);
    if (errno || (*end && *end != ' ' && *end != '\r'))
        return mlb_fail(MLB_ERR_FORMAT, "%s: bad Radiance resolution line '%s'", path, line);
    MLB_TRY(check_size(path, w, h));
    int rle = w >= 8 && w < 32768 && n - pos >= 4 && b[pos] == 2 && b[pos + 1] == 2 && !(b[pos + 2] & 0x80);
    if (!rle) {
        if ((n - pos) / 4 / (size_t)w < (size_t)h)
            return mlb_fail(MLB_ERR_FORMAT, "%s: truncated Radiance data (%zu bytes of pixels for %lldx%lld)", path, n - pos, w, h);
    } else {
        for (long long j = 0; j < h; j++) {
            if (n - pos < 4) return mlb_fail(MLB_ERR_FORMAT, "%s: truncated Radiance data in scanline %lld of %lld", path, j, h);
            if (b[pos] != 2 || b[pos + 1] != 2 || ((long long)b[pos + 2] << 8 | b[pos + 3]) != w)
                return mlb_fail(MLB_ERR_FORMAT, "%s: corrupt Radiance data: bad run-length header of scanline %lld", path, j);
            pos += 4;
            for (int k = 0; k < 4; k++)
                for (long long i = 0; i < w;) {
                    if (pos >= n) return mlb_fail(MLB_ERR_FORMAT, "%s: truncated Radiance data in scanline %lld of %lld", path, j, h);
                    int count = b[pos++];
                    int run = count > 128;
                    if (run) count -= 128;
                    if (count == 0 || count > w - i)
                        return mlb_fail(MLB_ERR_FORMAT, "%s: corrupt Radiance data: bad run in scanline %lld", path, j);
                    size_t need = run ? 1 : (size_t)count;
                    if (n - pos < need) return mlb_fail(MLB_ERR_FORMAT, "%s: truncated Radiance data in scanline %lld of %lld", path, j, h);
                    pos += need;
                    i += count;
                }
        }
    }
    *w_out = (int)w;
    *h_out = (int)h;
    return MLB_OK;
}

static mlb_status load_hdr(const char* path, const unsigned char* b, size_t n, float** rgb, int* w, int* h) {
    MLB_TRY(hdr_check(path, b, n, w, h));
    int sw, sh, comp;
    float* data = stbi_loadf_from_memory(b, (int)n, &sw, &sh, &comp, 3);
    if (!data) return mlb_fail(MLB_ERR_FORMAT, "%s: cannot decode Radiance data: %s", path, stbi_failure_reason());
    if (sw != *w || sh != *h) {
        stbi_image_free(data);
        return mlb_fail(MLB_ERR_FORMAT, "%s: decoded %dx%d, header says %dx%d", path, sw, sh, *w, *h);
    }
    *rgb = data;   // stb's allocator is malloc
    return MLB_OK;
}

static mlb_status exr_error(mlb_status code, const char* path, const char* what, const char* err) {
    mlb_status s = mlb_fail(code, "%s: %s%s%s", path, what, err ? ": " : "", err ? err : "");
    if (err) FreeEXRErrorMessage(err);
    return s;
}

// Through tinyexr's header + image API, so that every allocation on every error path is ours to
// free (its one-call LoadEXRFromMemory leaks its header when the data is truncated).
static mlb_status load_exr(const char* path, const unsigned char* b, size_t n, float** rgb, int* w, int* h) {
    EXRVersion ver;
    if (ParseEXRVersionFromMemory(&ver, b, n) != TINYEXR_SUCCESS)
        return mlb_fail(MLB_ERR_FORMAT, "%s: corrupt OpenEXR version field", path);
    if (ver.multipart || ver.non_image)
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: multi-part or deep OpenEXR files are not supported", path);
    EXRHeader hdr;
    InitEXRHeader(&hdr);
    const char* err = NULL;
    if (ParseEXRHeaderFromMemory(&hdr, &ver, b, n, &err) != TINYEXR_SUCCESS) {
        FreeEXRHeader(&hdr);   // whatever a partial parse allocated
        return exr_error(MLB_ERR_FORMAT, path, "corrupt OpenEXR header", err);
    }
    long long ew = (long long)hdr.data_window.max_x - hdr.data_window.min_x + 1;
    long long eh = (long long)hdr.data_window.max_y - hdr.data_window.min_y + 1;
    mlb_status st = check_size(path, ew, eh);
    int idx[3] = {-1, -1, -1};
    for (int c = 0; c < hdr.num_channels && st == MLB_OK; c++) {
        if (hdr.pixel_types[c] == TINYEXR_PIXELTYPE_HALF) hdr.requested_pixel_types[c] = TINYEXR_PIXELTYPE_FLOAT;
        const char* nm = hdr.channels[c].name;
        int k = strcmp(nm, "R") == 0 ? 0 : strcmp(nm, "G") == 0 ? 1 : strcmp(nm, "B") == 0 ? 2 : -1;
        if (k >= 0) idx[k] = c;
    }
    if (st == MLB_OK && (idx[0] < 0 || idx[1] < 0 || idx[2] < 0)) {
        if (hdr.num_channels == 1) idx[0] = idx[1] = idx[2] = 0;   // one channel (Y or anything): grey
        else st = mlb_fail(MLB_ERR_UNSUPPORTED, "%s: OpenEXR file has no R, G and B channels", path);
    }
    for (int k = 0; k < 3 && st == MLB_OK; k++)
        if (hdr.requested_pixel_types[idx[k]] != TINYEXR_PIXELTYPE_FLOAT)
            st = mlb_fail(MLB_ERR_UNSUPPORTED, "%s: OpenEXR channel '%s' holds integers, not radiance", path, hdr.channels[idx[k]].name);
    EXRImage img;
    InitEXRImage(&img);
    if (st == MLB_OK && LoadEXRImageFromMemory(&img, &hdr, b, n, &err) != TINYEXR_SUCCESS)
        st = exr_error(MLB_ERR_FORMAT, path, "cannot decode OpenEXR data", err);
    float* out = NULL;
    if (st == MLB_OK && (img.width != ew || img.height != eh))
        st = mlb_fail(MLB_ERR_FORMAT, "%s: decoded %dx%d, header says %lldx%lld", path, img.width, img.height, ew, eh);
    if (st == MLB_OK && !(out = calloc((size_t)ew * eh * 3, sizeof *out)))
        st = mlb_fail(MLB_ERR_NOMEM, "%s: cannot allocate %lldx%lld pixels", path, ew, eh);
    if (st == MLB_OK && img.tiles) {
        for (int t = 0; t < img.num_tiles; t++) {
            const EXRTile* tl = img.tiles + t;
            for (int j = 0; j < tl->height; j++)
                for (int i = 0; i < tl->width; i++) {
                    long long x = (long long)tl->offset_x * hdr.tile_size_x + i, y = (long long)tl->offset_y * hdr.tile_size_y + j;
                    if (x < 0 || y < 0 || x >= ew || y >= eh) continue;
                    for (int k = 0; k < 3; k++)
                        out[((size_t)y * ew + x) * 3 + k] = ((const float*)tl->images[idx[k]])[i + j * hdr.tile_size_x];
                }
        }
    } else if (st == MLB_OK) {
        if (!img.images) st = mlb_fail(MLB_ERR_FORMAT, "%s: OpenEXR file holds no pixels", path);
        for (size_t i = 0; st == MLB_OK && i < (size_t)ew * eh; i++)
            for (int k = 0; k < 3; k++) out[i * 3 + k] = ((const float*)img.images[idx[k]])[i];
    }
    FreeEXRImage(&img);
    FreeEXRHeader(&hdr);
    if (st != MLB_OK) {
        free(out);
        return st;
    }
    *rgb = out;
    *w = (int)ew;
    *h = (int)eh;
    return MLB_OK;
}

// Repairs (NaN/Inf -> 0, negative -> 0) and scales in place; counts into info.
static void repair_scale(float* rgb, size_t n, float scale, mlb_envmap_info* info) {
    size_t nonfinite = 0, negative = 0;
    for (size_t i = 0; i < n; i++) {
        float v = rgb[i];
        if (!isfinite(v)) {
            nonfinite++;
            v = 0;
        } else if (v < 0) {
            negative++;
            v = 0;
        }
        v *= scale;
        rgb[i] = v > FLT_MAX ? FLT_MAX : v;   // a huge value times a scale above 1
    }
    info->n_nonfinite = nonfinite;
    info->n_negative = negative;
}

static void set_name(mlb_envmap* env, const char* name) {
    const char* base = strrchr(name, '/');
    snprintf(env->name, sizeof env->name, "%s", base ? base + 1 : name);
}

static mlb_status finish(mlb_envmap* env, float* rgb, int w, int h, float scale, const char* name, mlb_envmap_info* info) {
    mlb_envmap_info local;
    if (!info) info = &local;
    memset(info, 0, sizeof *info);
    repair_scale(rgb, (size_t)w * h * 3, scale, info);
    if (info->n_nonfinite || info->n_negative)
        MLB_WARN("%s: replaced %zu NaN/Inf samples by 0 and clamped %zu negative samples to 0", name, info->n_nonfinite,
                 info->n_negative);
    memset(env, 0, sizeof *env);
    env->data = rgb;
    env->w = w;
    env->h = h;
    set_name(env, name);
    mlb_envmap_stats(env, info);
    return MLB_OK;
}

static mlb_status check_scale(const char* what, float scale) {
    if (!isfinite(scale) || scale < 0) return mlb_fail(MLB_ERR_ARG, "%s: scale %g must be finite and >= 0", what, scale);
    return MLB_OK;
}

mlb_status mlb_envmap_load(mlb_envmap* env, const char* path, float scale, mlb_envmap_info* info) {
    if (!env || !path) return mlb_fail(MLB_ERR_ARG, "mlb_envmap_load: NULL argument");
    memset(env, 0, sizeof *env);
    MLB_TRY(check_scale(path, scale));
    unsigned char* b;
    size_t n;
    MLB_TRY(mlb_image_file_read(path, &b, &n));
    float* rgb = NULL;
    int w = 0, h = 0;
    mlb_status s;
    if (n >= 4 && b[0] == 0x76 && b[1] == 0x2f && b[2] == 0x31 && b[3] == 0x01)
        s = load_exr(path, b, n, &rgb, &w, &h);
    else if (n >= 2 && b[0] == '#' && b[1] == '?')
        s = load_hdr(path, b, n, &rgb, &w, &h);
    else if (n == 0)
        s = mlb_fail(MLB_ERR_FORMAT, "%s: empty file", path);
    else
        s = mlb_fail(MLB_ERR_UNSUPPORTED, "%s: not a Radiance .hdr or OpenEXR file", path);
    free(b);
    if (s != MLB_OK) return s;
    return finish(env, rgb, w, h, scale, path, info);
}

mlb_status mlb_envmap_from_rgb(mlb_envmap* env, const float* rgb, int w, int h, const char* name, mlb_envmap_info* info) {
    if (!env || !rgb) return mlb_fail(MLB_ERR_ARG, "mlb_envmap_from_rgb: NULL argument");
    memset(env, 0, sizeof *env);
    if (!name) name = "memory";
    MLB_TRY(check_size(name, w, h));
    size_t n = (size_t)w * h * 3;
    float* copy = malloc(n * sizeof *copy);
    if (!copy) return mlb_fail(MLB_ERR_NOMEM, "%s: cannot allocate a %dx%d environment map", name, w, h);
    memcpy(copy, rgb, n * sizeof *copy);
    return finish(env, copy, w, h, 1.0f, name, info);
}

mlb_status mlb_envmap_scale(mlb_envmap* env, float scale) {
    MLB_TRY(check_scale(env->name, scale));
    size_t n = (size_t)env->w * env->h * 3;
    for (size_t i = 0; i < n; i++) {
        float v = env->data[i] * scale;
        env->data[i] = v > FLT_MAX ? FLT_MAX : v;
    }
    return MLB_OK;
}

mlb_status mlb_envmap_validate(const mlb_envmap* env) {
    if (!env || !env->data) return mlb_fail(MLB_ERR_ARG, "environment map is empty");
    MLB_TRY(check_size(env->name, env->w, env->h));
    size_t n = (size_t)env->w * env->h * 3;
    for (size_t i = 0; i < n; i++)
        if (!isfinite(env->data[i]) || env->data[i] < 0)
            return mlb_fail(MLB_ERR_NUMERIC, "%s: sample %zu (pixel %zu, %zu) is %g; radiance must be finite and >= 0", env->name,
                            i, i / 3 % (size_t)env->w, i / 3 / (size_t)env->w, env->data[i]);
    return MLB_OK;
}

void mlb_envmap_stats(const mlb_envmap* env, mlb_envmap_info* info) {
    double mx = 0, sum = 0, sum_sphere = 0;
    for (int j = 0; j < env->h; j++) {
        double wrow = sin(PI * (j + 0.5) / env->h);
        double row = 0;
        for (int i = 0; i < env->w; i++) {
            double l = luminance(env->data + ((size_t)j * env->w + i) * 3);
            if (l > mx) mx = l;
            row += l;
        }
        sum += row;
        sum_sphere += row * wrow;
    }
    double norm = 0;   // sum of sin over rows times w: the solid-angle weights' total
    for (int j = 0; j < env->h; j++) norm += sin(PI * (j + 0.5) / env->h);
    info->max_luminance = (float)mx;
    info->mean_luminance = (float)(sum / ((double)env->w * env->h));
    info->mean_luminance_sphere = (float)(sum_sphere / (norm * env->w));
}

void mlb_envmap_free(mlb_envmap* env) {
    if (!env) return;
    free(env->data);
    memset(env, 0, sizeof *env);
}

// ---------------------------------------------------------------- directions and lookup

void mlb_envmap_set_rotation(mlb_envmap* env, float radians) { env->rotation = radians; }

void mlb_rotate_y(double out[3], const double in[3], double angle) {
    double c = cos(angle), s = sin(angle), x = in[0], z = in[2];
    out[0] = c * x + s * z;
    out[1] = in[1];
    out[2] = -s * x + c * z;
}

void mlb_latlong_dir_to_uv(const double d[3], double* u, double* t) {
    double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    double y = len > 0 ? d[1] / len : 1;
    if (y > 1) y = 1;
    if (y < -1) y = -1;
    *u = atan2(d[0], -d[2]) / (2 * PI) + 0.5;
    *t = acos(y) / PI;
}

void mlb_latlong_uv_to_dir(double u, double t, double d[3]) {
    double th = t * PI, ph = (u - 0.5) * 2 * PI, s = sin(th);
    d[0] = s * sin(ph);
    d[1] = cos(th);
    d[2] = -s * cos(ph);
}

static void latlong_bilinear(const mlb_envmap* env, double u, double t, double rgb[3]) {
    int w = env->w, h = env->h;
    double px = u * w - 0.5, py = t * h - 0.5;
    if (!isfinite(px) || !isfinite(py)) {   // a NaN direction
        rgb[0] = rgb[1] = rgb[2] = 0;
        return;
    }
    double fx0 = floor(px), fy0 = floor(py);
    double ax = px - fx0, ay = py - fy0;
    long x0 = (long)fx0 % w;
    if (x0 < 0) x0 += w;
    long x1 = (x0 + 1) % w;
    long y0 = (long)fy0, y1 = y0 + 1;
    if (y0 < 0) y0 = 0;
    if (y1 < 0) y1 = 0;
    if (y0 > h - 1) y0 = h - 1;
    if (y1 > h - 1) y1 = h - 1;
    const float* r0 = env->data + (size_t)y0 * w * 3;
    const float* r1 = env->data + (size_t)y1 * w * 3;
    for (int c = 0; c < 3; c++)
        rgb[c] = (1 - ay) * ((1 - ax) * r0[x0 * 3 + c] + ax * r0[x1 * 3 + c]) + ay * ((1 - ax) * r1[x0 * 3 + c] + ax * r1[x1 * 3 + c]);
}

void mlb_envmap_lookup(const mlb_envmap* env, const double dir[3], double rgb[3]) {
    double d[3], u, t;
    mlb_rotate_y(d, dir, -(double)env->rotation);
    mlb_latlong_dir_to_uv(d, &u, &t);
    latlong_bilinear(env, u, t, rgb);
}

// ---------------------------------------------------------------- importance sampling

mlb_status mlb_envmap_sampler_build(mlb_envmap_sampler* s, const mlb_envmap* env) {
    memset(s, 0, sizeof *s);
    MLB_TRY(mlb_envmap_validate(env));
    int w = env->w, h = env->h;
    s->w = w;
    s->h = h;
    s->row_cdf = malloc((size_t)(h + 1) * sizeof(double));
    s->col_cdf = malloc((size_t)h * (w + 1) * sizeof(double));
    s->row_mass = malloc((size_t)h * sizeof(double));
    if (!s->row_cdf || !s->col_cdf || !s->row_mass) {
        mlb_envmap_sampler_free(s);
        return mlb_fail(MLB_ERR_NOMEM, "%s: cannot allocate the sampling tables", env->name);
    }
    // A pixel's weight is the largest luminance of its 3x3 neighbourhood: the bilinear lookup
    // spreads a pixel's radiance up to one pixel around it, and the density must cover that
    // (a small sun sampled only in its own pixel would leave its bilinear skirt to the other
    // strategies, with a huge variance).
    double total = 0;
    for (int pass = 0; pass < 2 && total <= 0; pass++) {   // pass 1: a black map samples uniformly
        total = 0;
        for (int j = 0; j < h; j++) {
            double sn = sin(PI * (j + 0.5) / h), acc = 0;
            double* cdf = s->col_cdf + (size_t)j * (w + 1);
            cdf[0] = 0;
            for (int i = 0; i < w; i++) {
                double l = 0;
                for (int dj = -1; dj <= 1 && !pass; dj++)
                    for (int di = -1; di <= 1; di++) {
                        int jj = j + dj < 0 ? 0 : j + dj >= h ? h - 1 : j + dj, ii = ((i + di) % w + w) % w;
                        double q = luminance(env->data + ((size_t)jj * w + ii) * 3);
                        if (q > l) l = q;
                    }
                acc += (pass ? 1.0 : l) * sn;
                cdf[i + 1] = acc;
            }
            s->row_mass[j] = acc;
            for (int i = 0; i <= w; i++) cdf[i] = acc > 0 ? cdf[i] / acc : (double)i / w;
            total += acc;
        }
    }
    s->total = total;
    s->row_cdf[0] = 0;
    for (int j = 0; j < h; j++) s->row_cdf[j + 1] = s->row_cdf[j] + s->row_mass[j] / total;
    s->row_cdf[h] = 1;
    return MLB_OK;
}

// Largest k in [0, n) with cdf[k] <= x (cdf[0] = 0, cdf[n] = 1), skipping empty cells.
static int cdf_find(const double* cdf, int n, double x) {
    int lo = 0, hi = n;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (cdf[mid] <= x) lo = mid;
        else hi = mid;
    }
    while (lo < n - 1 && cdf[lo + 1] <= cdf[lo]) lo++;
    return lo;
}

static double pixel_pdf(const mlb_envmap_sampler* s, int j, int i, double t) {
    double p = (s->row_cdf[j + 1] - s->row_cdf[j]) * (s->col_cdf[(size_t)j * (s->w + 1) + i + 1] - s->col_cdf[(size_t)j * (s->w + 1) + i]);
    double sn = sin(PI * t);
    if (sn < 1e-12) sn = 1e-12;
    return p * s->w * s->h / (2 * PI * PI * sn);
}

double mlb_envmap_sampler_sample(const mlb_envmap_sampler* s, const mlb_envmap* env, const double u[4], double dir[3]) {
    int j = cdf_find(s->row_cdf, s->h, u[0]);
    int i = cdf_find(s->col_cdf + (size_t)j * (s->w + 1), s->w, u[1]);
    double uu = (i + u[2]) / s->w, tt = (j + u[3]) / s->h, d[3];
    mlb_latlong_uv_to_dir(uu, tt, d);
    mlb_rotate_y(dir, d, env->rotation);
    return pixel_pdf(s, j, i, tt);
}

double mlb_envmap_sampler_pdf(const mlb_envmap_sampler* s, const mlb_envmap* env, const double dir[3]) {
    double d[3], u, t;
    mlb_rotate_y(d, dir, -(double)env->rotation);
    mlb_latlong_dir_to_uv(d, &u, &t);
    if (!isfinite(u) || !isfinite(t)) return 0;
    int i = (int)floor(u * s->w), j = (int)floor(t * s->h);
    if (i < 0) i = 0;
    if (i >= s->w) i = s->w - 1;
    if (j < 0) j = 0;
    if (j >= s->h) j = s->h - 1;
    return pixel_pdf(s, j, i, t);
}

void mlb_envmap_sampler_free(mlb_envmap_sampler* s) {
    if (!s) return;
    free(s->row_cdf);
    free(s->col_cdf);
    free(s->row_mass);
    memset(s, 0, sizeof *s);
}

// ---------------------------------------------------------------- procedural environments

#define SUN_SOLID_ANGLE 6.8e-5          // sr: the sun's 0.53 deg disc
#define SUN_ELEVATION (40.0 * PI / 180)
#define SUN_AZIMUTH (PI / 4)            // atan2(x, -z)
#define SUN_SKY_RATIO 6.0               // horizontal irradiance sun : sky
#define GROUND_ALBEDO 0.2

static void set_lum(float* p, double lum, const double col[3]) {   // col scaled to luminance 1
    double cl = 0.2126 * col[0] + 0.7152 * col[1] + 0.0722 * col[2];
    for (int c = 0; c < 3; c++) p[c] = (float)(lum * col[c] / cl);
}

static double dot3(const double a[3], const double b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

static double cie_indicatrix(double gamma) { return 0.91 + 10 * exp(-3 * gamma) + 0.45 * cos(gamma) * cos(gamma); }

// Exact solid angle of a pixel in row j of an h-row lat-long map with width w.
static double pixel_solid_angle(int j, int w, int h) { return 2 * PI / w * (cos(PI * j / h) - cos(PI * (j + 1) / h)); }

static int gen_sky(float* rgb, int w, int h) {   // 0: out of memory
    const double ground[3] = {0.30, 0.25, 0.19}, zen[3] = {0.30, 0.50, 1.00}, hor[3] = {0.78, 0.86, 1.00}, aur[3] = {1.0, 0.95, 0.86};
    const double sunc[3] = {1.0, 0.93, 0.84};
    double sun[3] = {cos(SUN_ELEVATION) * sin(SUN_AZIMUTH), sin(SUN_ELEVATION), -cos(SUN_ELEVATION) * cos(SUN_AZIMUTH)};
    double zs = PI / 2 - SUN_ELEVATION;
    double norm = cie_indicatrix(zs) * (1 - exp(-0.32));
    double e_sky = 0;   // horizontal irradiance of the unscaled sky (luminance)
    for (int j = 0; j < h; j++) {
        double sa = pixel_solid_angle(j, w, h);
        for (int i = 0; i < w; i++) {
            double d[3];
            mlb_latlong_uv_to_dir((i + 0.5) / w, (j + 0.5) / h, d);
            float* p = rgb + ((size_t)j * w + i) * 3;
            if (d[1] <= 0) continue;
            double g = acos(fmin(1, fmax(-1, dot3(d, sun))));
            double f = cie_indicatrix(g);
            double lum = f * (1 - exp(-0.32 / d[1])) / norm;   // relative to the zenith
            double a = 10 * exp(-3 * g) / f, m = pow(1 - d[1], 3), col[3];
            for (int c = 0; c < 3; c++) col[c] = (1 - a) * ((1 - m) * zen[c] + m * hor[c]) + a * aur[c];
            set_lum(p, lum, col);
            e_sky += lum * d[1] * sa;
        }
    }
    // Irradiance of a horizontal plane: pi in total (a white Lambertian plane has radiance 1),
    // 1/(1+ratio) of it from the sky, the rest from the sun.
    double sky_scale = PI / (1 + SUN_SKY_RATIO) / e_sky;
    double sun_lum = PI * SUN_SKY_RATIO / (1 + SUN_SKY_RATIO) / (SUN_SOLID_ANGLE * sin(SUN_ELEVATION));
    for (int j = 0; j < h; j++)
        for (int i = 0; i < w; i++) {
            float* p = rgb + ((size_t)j * w + i) * 3;
            double d[3];
            mlb_latlong_uv_to_dir((i + 0.5) / w, (j + 0.5) / h, d);
            if (d[1] > 0)
                for (int c = 0; c < 3; c++) p[c] = (float)(p[c] * sky_scale);
            else
                set_lum(p, GROUND_ALBEDO, ground);
        }
    // The sun disc, antialiased: coverage of each pixel near it from 16x16 sub-samples, then
    // normalised so that sum(coverage x pixel solid angle) is exactly the sun's solid angle.
    double rs = acos(1 - SUN_SOLID_ANGLE / (2 * PI)), cos_rs = cos(rs);
    double us, ts;
    mlb_latlong_dir_to_uv(sun, &us, &ts);
    double pix = PI / h;
    int jc = (int)(ts * h), ic = (int)(us * w);
    int rj = 2 + (int)(rs / pix), ri = 2 + (int)(rs / (pix * fmax(sin(PI * ts), 1e-3)));
    enum { SS = 16 };
    double total = 0;
    float* cov = calloc((size_t)(2 * rj + 1) * (2 * ri + 1), sizeof *cov);
    if (!cov) return 0;
    for (int pass = 0; pass < 2; pass++)
        for (int dj = -rj; dj <= rj; dj++)
            for (int di = -ri; di <= ri; di++) {
                int j = jc + dj, i = ((ic + di) % w + w) % w;
                if (j < 0 || j >= h) continue;
                float* cv = cov + (size_t)(dj + rj) * (2 * ri + 1) + (di + ri);
                if (pass == 0) {
                    int in = 0;
                    for (int a = 0; a < SS; a++)
                        for (int b = 0; b < SS; b++) {
                            double d[3];
                            mlb_latlong_uv_to_dir((i + (b + 0.5) / SS) / w, (j + (a + 0.5) / SS) / h, d);
                            in += dot3(d, sun) >= cos_rs;
                        }
                    *cv = (float)in / (SS * SS);
                    total += *cv * pixel_solid_angle(j, w, h);
                } else if (*cv > 0) {
                    float* p = rgb + ((size_t)j * w + i) * 3;
                    double cl = 0.2126 * sunc[0] + 0.7152 * sunc[1] + 0.0722 * sunc[2];
                    for (int c = 0; c < 3; c++) p[c] += (float)(sun_lum * *cv * SUN_SOLID_ANGLE / total * sunc[c] / cl);
                }
            }
    free(cov);
    return 1;
}

static void gen_overcast(float* rgb, int w, int h) {
    const double sky[3] = {0.93, 0.97, 1.04}, ground[3] = {0.30, 0.27, 0.23};
    double lz = 9.0 / 7.0;   // horizontal irradiance 7 pi Lz / 9 = pi
    for (int j = 0; j < h; j++)
        for (int i = 0; i < w; i++) {
            double d[3];
            mlb_latlong_uv_to_dir((i + 0.5) / w, (j + 0.5) / h, d);
            float* p = rgb + ((size_t)j * w + i) * 3;
            if (d[1] > 0) set_lum(p, lz * (1 + 2 * d[1]) / 3, sky);
            else set_lum(p, GROUND_ALBEDO, ground);
        }
}

static double smoothstep01(double x) { return x <= 0 ? 0 : x >= 1 ? 1 : x * x * (3 - 2 * x); }

// Rectangular soft boxes seen from the centre: a direction hits the box when its projection onto
// the plane tangent at the box centre lies within (tan a, tan b); edges fade over 8% of the size.
static void gen_studio(float* rgb, int w, int h) {
    struct { double el, az, a, b, lum, col[3]; } box[4] = {
        {30, 50, 20, 15, 10.0, {1.00, 0.96, 0.90}},    // key
        {15, -70, 25, 18, 3.0, {0.92, 0.96, 1.00}},    // fill
        {80, 0, 20, 20, 6.0, {1.00, 1.00, 1.00}},      // top
        {20, 180, 8, 30, 8.0, {1.00, 1.00, 1.00}},     // rim (a tall strip behind)
    };
    const double wall[3] = {1, 1, 1}, floor_col[3] = {0.9, 0.85, 0.8};
    for (int j = 0; j < h; j++)
        for (int i = 0; i < w; i++) {
            double d[3];
            mlb_latlong_uv_to_dir((i + 0.5) / w, (j + 0.5) / h, d);
            float* p = rgb + ((size_t)j * w + i) * 3;
            if (d[1] > 0) set_lum(p, 0.03, wall);
            else set_lum(p, 0.05, floor_col);
            for (int k = 0; k < 4; k++) {
                double el = box[k].el * PI / 180, az = box[k].az * PI / 180;
                double c[3] = {cos(el) * sin(az), sin(el), -cos(el) * cos(az)};
                double e1[3] = {cos(az), 0, sin(az)};   // horizontal, perpendicular to c
                double e2[3] = {c[1] * e1[2] - c[2] * e1[1], c[2] * e1[0] - c[0] * e1[2], c[0] * e1[1] - c[1] * e1[0]};
                double dc = dot3(d, c);
                if (dc <= 0) continue;
                double x = fabs(dot3(d, e1) / dc) / tan(box[k].a * PI / 180), y = fabs(dot3(d, e2) / dc) / tan(box[k].b * PI / 180);
                double m = smoothstep01((1 - x) / 0.08) * smoothstep01((1 - y) / 0.08);
                if (m <= 0) continue;
                float q[3];
                set_lum(q, box[k].lum, box[k].col);
                for (int ch = 0; ch < 3; ch++) p[ch] = (float)((1 - m) * p[ch] + m * q[ch]);
            }
        }
}

static const char* const builtin_names[] = {"sky", "overcast", "studio", "white"};

int mlb_envmap_is_builtin(const char* name) {
    if (!name) return 0;
    for (size_t k = 0; k < sizeof builtin_names / sizeof *builtin_names; k++)
        if (strcmp(name, builtin_names[k]) == 0) return 1;
    return 0;
}

const char* mlb_envmap_builtin_list(void) { return "sky, overcast, studio, white"; }

mlb_status mlb_envmap_named(mlb_envmap* env, const char* name, int height) {
    if (!env || !name) return mlb_fail(MLB_ERR_ARG, "mlb_envmap_named: NULL argument");
    memset(env, 0, sizeof *env);
    if (!mlb_envmap_is_builtin(name))
        return mlb_fail(MLB_ERR_NOT_FOUND, "no built-in environment called '%s' (built-ins: %s)", name, mlb_envmap_builtin_list());
    if (height == 0) height = 512;
    if (height < 2 || (size_t)height * 2 * height > MLB_ENVMAP_MAX_PIXELS)
        return mlb_fail(MLB_ERR_ARG, "environment '%s': height %d must be in [2, 8192]", name, height);
    int w = 2 * height;
    float* rgb = calloc((size_t)w * height * 3, sizeof *rgb);
    if (!rgb) return mlb_fail(MLB_ERR_NOMEM, "environment '%s': cannot allocate %dx%d", name, w, height);
    if (strcmp(name, "sky") == 0) {
        if (!gen_sky(rgb, w, height)) {
            free(rgb);
            return mlb_fail(MLB_ERR_NOMEM, "environment 'sky': cannot allocate the sun's coverage");
        }
    } else if (strcmp(name, "overcast") == 0) gen_overcast(rgb, w, height);
    else if (strcmp(name, "studio") == 0) gen_studio(rgb, w, height);
    else
        for (size_t i = 0; i < (size_t)w * height * 3; i++) rgb[i] = 1.0f;
    env->data = rgb;
    env->w = w;
    env->h = height;
    set_name(env, name);
    return MLB_OK;
}

mlb_status mlb_envmap_open(mlb_envmap* env, const char* name_or_path, float scale, int height, mlb_envmap_info* info) {
    if (!env || !name_or_path) return mlb_fail(MLB_ERR_ARG, "mlb_envmap_open: NULL argument");
    if (!mlb_envmap_is_builtin(name_or_path)) return mlb_envmap_load(env, name_or_path, scale, info);
    MLB_TRY(check_scale(name_or_path, scale));
    MLB_TRY(mlb_envmap_named(env, name_or_path, height));
    if (scale != 1.0f) mlb_envmap_scale(env, scale);
    if (info) {
        memset(info, 0, sizeof *info);
        mlb_envmap_stats(env, info);
    }
    return MLB_OK;
}
