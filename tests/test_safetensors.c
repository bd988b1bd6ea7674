// safetensors reader/writer and float16/bfloat16 conversions.
// The malformed-file corpus is built here byte by byte: each case breaks one rule and checks the
// exact status, a distinctive part of the message, and that the message names the file, both
// through mlb_st_open_memory and through mlb_st_open on a written file.
#include "test.h"
#include "matlaber/fileio.h"
#include "matlaber/cpu.h"
#include "matlaber/half.h"
#include "matlaber/safetensors.h"
#include <dirent.h>
#include <float.h>
#include <stdint.h>
#include <unistd.h>

static const char* tmpdir;

static uint32_t fbits(float f) { uint32_t u; memcpy(&u, &f, 4); return u; }
static float bitsf(uint32_t u) { float f; memcpy(&f, &u, 4); return f; }

// ---------------------------------------------------------------- float16 / bfloat16

TEST(f16_known_values) {
    static const struct { float f; uint16_t h; } k[] = {
        {0.0f, 0x0000}, {-0.0f, 0x8000}, {1.0f, 0x3C00}, {-2.0f, 0xC000}, {0.5f, 0x3800},
        {65504.0f, 0x7BFF}, {0x1p-14f, 0x0400}, {0x1p-24f, 0x0001}, {0x3FFp-24f, 0x03FF},
        {0.1f, 0x2E66}, {1.0f / 3.0f, 0x3555}, {3.140625f, 0x4248}, {INFINITY, 0x7C00}, {-INFINITY, 0xFC00},
        {65519.99f, 0x7BFF}, {65520.0f, 0x7C00}, {1e6f, 0x7C00}, {-1e6f, 0xFC00},   // overflow: RNE to inf
        {0x1p-25f, 0x0000}, {0x1.000002p-25f, 0x0001}, {0x3p-25f, 0x0002}, {0x5p-25f, 0x0002},   // subnormal ties
        {1.0f + 0x1p-11f, 0x3C00}, {1.0f + 0x3p-11f, 0x3C02}, {0x1p-26f, 0x0000}, {FLT_MIN, 0x0000},
        {0x7FFp-25f, 0x0400},   // largest subnormal + half ulp rounds up into the smallest normal
    };
    for (size_t i = 0; i < sizeof k / sizeof k[0]; i++) {
        uint16_t h = mlb_f32_to_f16(k[i].f);
        CHECK_MSG(h == k[i].h, "f32_to_f16(%a) = 0x%04x, expected 0x%04x", k[i].f, h, k[i].h);
    }
    CHECK(mlb_f16_to_f32(0x3C00) == 1.0f);
    CHECK(mlb_f16_to_f32(0x7BFF) == 65504.0f);
    CHECK(mlb_f16_to_f32(0x0001) == 0x1p-24f);
    CHECK(isinf(mlb_f16_to_f32(0xFC00)) && mlb_f16_to_f32(0xFC00) < 0);
    CHECK(isnan(mlb_f16_to_f32(0x7E00)));
    CHECK((mlb_f32_to_f16(NAN) & 0x7E00) == 0x7E00);
    CHECK(mlb_f32_to_f16(bitsf(0x7F800001u)) == 0x7E00);   // NaN whose payload is below f16's: still NaN
    CHECK(mlb_f32_to_f16(bitsf(0xFFC00000u)) == 0xFE00);   // sign kept
}

TEST(f16_exhaustive) {
    int bad = 0;
    for (uint32_t h = 0; h < 65536; h++) {
        float f = mlb_f16_to_f32((uint16_t)h);
        uint32_t e = (h >> 10) & 0x1F, m = h & 0x3FF;
        double expect = e == 0 ? ldexp(m, -24) : e == 31 ? (m ? NAN : INFINITY) : ldexp(1024 + m, (int)e - 25);
        if (h & 0x8000) expect = -expect;
        uint16_t back = mlb_f32_to_f16(f);
        if (e == 31 && m) {
            if (!isnan(f) || back != (h | 0x200)) bad++;   // NaNs come back quiet, payload and sign kept
        } else if ((double)f != expect || back != h || !!signbit(f) != !!(h & 0x8000)) {
            bad++;
        }
        // Rounding at the midpoint to the next value up (in magnitude), and just either side of it.
        if (e < 31 && (h & 0x7FFF) != 0x7FFF) {
            float lo = fabsf(f);
            float hi = (h & 0x7FFF) == 0x7BFF ? 65536.0f : fabsf(mlb_f16_to_f32((uint16_t)((h & 0x7FFF) + 1)));
            float mid = (lo + hi) / 2;   // exact: 12 significant bits
            uint16_t s = (uint16_t)(h & 0x8000), a = (uint16_t)(h & 0x7FFF);
            float sg = s ? -1.0f : 1.0f;
            uint16_t even = (a & 1) ? (uint16_t)(a + 1) : a;
            if (mlb_f32_to_f16(sg * mid) != (s | even)) bad++;
            if (mlb_f32_to_f16(sg * nextafterf(mid, 0)) != (s | a)) bad++;
            if (mlb_f32_to_f16(sg * nextafterf(mid, INFINITY)) != (s | (a + 1))) bad++;
        }
    }
    CHECK_MSG(bad == 0, "%d float16 values or midpoints wrong", bad);
}

#ifdef __FLT16_MANT_DIG__
// The compiler's own _Float16 conversion is an independent oracle for arbitrary floats.
TEST(f16_vs_compiler) {
    uint64_t x = 0x9E3779B97F4A7C15ull;
    int bad = 0;
    for (int i = 0; i < 2000000; i++) {
        x ^= x << 13; x ^= x >> 7; x ^= x << 17;
        uint32_t u = (uint32_t)x;
        if (i & 1) u = (u & 0x8FFFFFFFu) | 0x30000000u;   // half the samples near f16's exponent range
        float f = bitsf(u);
        _Float16 ref = (_Float16)f;
        uint16_t rb;
        memcpy(&rb, &ref, 2);
        uint16_t h = mlb_f32_to_f16(f);
        if (isnan(f) ? !isnan(mlb_f16_to_f32(h)) : h != rb) bad++;
    }
    CHECK_MSG(bad == 0, "%d conversions differ from _Float16", bad);
}
#endif

// The array conversion (F16C where the CPU has it, in parallel blocks) gives the scalar loop's bits
// for every pattern, from an unaligned source, over lengths that end mid-vector and span blocks.
TEST(f16_array_matches_scalar) {
    size_t n = (size_t)65536 * 9 + 5;   // > two 2^18-value blocks
    unsigned char* raw = malloc(2 * n + 1);
    float *fast = malloc(n * sizeof(float)), *slow = malloc(n * sizeof(float));
    REQUIRE(raw && fast && slow);
    for (size_t i = 0; i < n; i++) { uint16_t h = (uint16_t)(i * 40503u); memcpy(raw + 1 + 2 * i, &h, 2); }
    size_t lens[] = {0, 1, 7, 8, 9, 65536 + 3, n};
    int bad = 0;
    for (int k = 0; k < 7; k++) {
        memset(fast, 0xA5, n * sizeof(float));
        memset(slow, 0x5A, n * sizeof(float));
        mlb_f16_to_f32_array(fast, raw + 1, lens[k]);
        mlb_f16_to_f32_array_scalar(slow, raw + 1, lens[k]);
        if (memcmp(fast, slow, lens[k] * sizeof(float))) bad++;
        if (lens[k] < n && memcmp(fast + lens[k], (unsigned char[4]){0xA5, 0xA5, 0xA5, 0xA5}, 4)) bad++;   // no write past n
    }
    CHECK_MSG(bad == 0, "%d lengths differ from the scalar conversion", bad);
    mlb_cpu_info f;
    mlb_cpu_detect(&f);
    printf("  f16 -> f32 arrays: %s path, every bit pattern as the scalar loop\n", f.f16c ? "F16C" : "scalar");
    free(raw); free(fast); free(slow);
}

TEST(bf16_exhaustive) {
    static const struct { float f; uint16_t h; } k[] = {
        {1.0f, 0x3F80}, {-1.0f, 0xBF80}, {3.14159265f, 0x4049}, {0.0f, 0}, {-0.0f, 0x8000},
        {INFINITY, 0x7F80}, {FLT_MAX, 0x7F80}, {0x1.fep127f, 0x7F7F}, {1.0f + 0x1p-8f, 0x3F80},
        {1.0f + 0x3p-8f, 0x3F82}, {FLT_MIN, 0x0080}, {0x1p-133f, 0x0001},
    };
    for (size_t i = 0; i < sizeof k / sizeof k[0]; i++)
        CHECK_MSG(mlb_f32_to_bf16(k[i].f) == k[i].h, "f32_to_bf16(%a) = 0x%04x, expected 0x%04x", k[i].f,
                  mlb_f32_to_bf16(k[i].f), k[i].h);
    int bad = 0;
    for (uint32_t h = 0; h < 65536; h++) {
        float f = mlb_bf16_to_f32((uint16_t)h);
        uint16_t back = mlb_f32_to_bf16(f);
        int nan = (h & 0x7F80) == 0x7F80 && (h & 0x7F);
        if (nan) { if (!isnan(f) || back != (h | 0x40)) bad++; continue; }
        if (fbits(f) != h << 16 || back != h) bad++;
        if ((h & 0x7F80) == 0x7F80) continue;   // inf: no next value
        // Below the tie, the tie (to even), above the tie.
        if (mlb_f32_to_bf16(bitsf((h << 16) | 0x7FFF)) != h) bad++;
        if (mlb_f32_to_bf16(bitsf((h << 16) | 0x8000)) != ((h & 1) ? h + 1 : h)) bad++;
        if (mlb_f32_to_bf16(bitsf((h << 16) | 0x8001)) != h + 1) bad++;
    }
    CHECK_MSG(bad == 0, "%d bfloat16 values wrong", bad);
}

// ---------------------------------------------------------------- malformed corpus

// 8-byte length + header bytes + data_len bytes of a pattern. Caller frees.
static unsigned char* make_file(const char* header, size_t hlen, size_t data_len, size_t* n) {
    *n = 8 + hlen + data_len;
    unsigned char* b = malloc(*n + 1);
    for (int i = 0; i < 8; i++) b[i] = (unsigned char)((uint64_t)hlen >> (8 * i));
    memcpy(b + 8, header, hlen);
    for (size_t i = 0; i < data_len; i++) b[8 + hlen + i] = (unsigned char)(i * 37 + 11);
    return b;
}

static void expect_bad_bytes(int line, const void* buf, size_t n, mlb_status code, const char* sub) {
    mlb_safetensors* st = (mlb_safetensors*)&st;
    mlb_status s = mlb_st_open_memory(&st, buf, n, "bad.safetensors");
    const char* msg = mlb_last_error();
    CHECK_MSG(s == code, "line %d: status %s, expected %s (%s)", line, mlb_status_name(s), mlb_status_name(code), msg);
    CHECK_MSG(st == NULL, "line %d: handle not NULL after failure", line);
    CHECK_MSG(strstr(msg, sub) != NULL, "line %d: message \"%s\" lacks \"%s\"", line, msg, sub);
    CHECK_MSG(strncmp(msg, "bad.safetensors: ", 17) == 0, "line %d: message \"%s\" does not name the buffer", line, msg);
    if (s == MLB_OK) mlb_st_close(st);
    // The same bytes through a real file and mmap.
    char path[4200];
    snprintf(path, sizeof path, "%s/bad_%d.safetensors", tmpdir, line);
    if (mlb_write_file_atomic(path, buf, n) != MLB_OK) { CHECK_MSG(0, "line %d: cannot write %s", line, path); return; }
    st = (mlb_safetensors*)&st;
    s = mlb_st_open(&st, path);
    msg = mlb_last_error();
    CHECK_MSG(s == code && st == NULL, "line %d: file: status %s (%s)", line, mlb_status_name(s), msg);
    CHECK_MSG(strstr(msg, sub) != NULL, "line %d: file: message \"%s\" lacks \"%s\"", line, msg, sub);
    CHECK_MSG(strncmp(msg, path, strlen(path)) == 0, "line %d: file: message \"%s\" does not name the path", line, msg);
    if (s == MLB_OK) mlb_st_close(st);
    unlink(path);
}

// A header given as a string literal (embedded NULs allowed) with data_len data bytes.
#define BAD(hdr, data_len, code, sub) do { size_t n_; \
    unsigned char* b_ = make_file(hdr, sizeof(hdr) - 1, data_len, &n_); \
    expect_bad_bytes(__LINE__, b_, n_, code, sub); free(b_); } while (0)
#define T1(dt, shape, offs) "{\"a\":{\"dtype\":\"" dt "\",\"shape\":" shape ",\"data_offsets\":" offs "}}"
#define FMT MLB_ERR_FORMAT

TEST(malformed_size_and_length) {
    expect_bad_bytes(__LINE__, "", 0, FMT, "too short for the 8-byte header length");
    expect_bad_bytes(__LINE__, "\x02\0\0\0\0", 5, FMT, "file is 5 bytes, too short");
    unsigned char b[16] = {0};
    uint64_t big = 100000001;   // one past the limit
    for (int i = 0; i < 8; i++) b[i] = (unsigned char)(big >> (8 * i));
    expect_bad_bytes(__LINE__, b, sizeof b, FMT, "header length 100000001 is more than the 100000000 allowed");
    memset(b, 0xFF, 8);
    expect_bad_bytes(__LINE__, b, sizeof b, FMT, "is more than the 100000000 allowed");
    memset(b, 0, 8);
    b[0] = 9;   // 9-byte header, 8 bytes present
    expect_bad_bytes(__LINE__, b, sizeof b, FMT, "header length 9 runs past the end of the file (16 bytes)");
    // A symlink stored as a plain text file (as some copies of the shared data have).
    const char* stub = "sd1_diffusers/text_encoder/model.safetensors";
    expect_bad_bytes(__LINE__, stub, strlen(stub), FMT, "text stand-in");
}

TEST(malformed_text) {
    BAD("{\"a\xff\":{}}", 0, FMT, "not valid UTF-8 at header byte 3: lead byte above 0xF4");
    BAD("{\"\xc0\xaf\":{}}", 0, FMT, "not valid UTF-8 at header byte 2: overlong encoding");
    BAD("{\"\xe0\x80\xaf\":{}}", 0, FMT, "overlong encoding");
    BAD("{\"\xed\xa0\x80\":{}}", 0, FMT, "surrogate code point");
    BAD("{\"\xf4\x90\x80\x80\":{}}", 0, FMT, "code point above U+10FFFF");
    BAD("{\"\x80\":{}}", 0, FMT, "stray continuation byte");
    BAD("{\"\xe2\x82\":{}}", 0, FMT, "missing continuation byte");
    BAD("{}\xe2\x82", 0, FMT, "sequence cut short");
    BAD("", 0, FMT, "not valid JSON");
    BAD("{\"a\":", 0, FMT, "header is not valid JSON (parse error");
    BAD("{\"a\":{}", 0, FMT, "header is not valid JSON (parse error");
    BAD("{} {}", 0, FMT, "unexpected text after the top-level value at header byte 3");
    BAD("{}\0\0\0\0\0\0", 0, FMT, "control character 0x00 at header byte 2");
    BAD("{}  x ", 0, FMT, "unexpected text after the top-level value at header byte 4");
    BAD("{\x01}", 0, FMT, "control character 0x01 at header byte 1");
    BAD("{\"a\nb\":{}}", 0, FMT, "control character 0x0a inside a string");
    BAD("\xef\xbb\xbf{}", 0, FMT, "byte-order mark");
    BAD("[]", 0, FMT, "valid JSON but not a JSON object");
    BAD("\"x\"", 0, FMT, "not a JSON object");
    BAD("17", 0, FMT, "not a JSON object");
    BAD("{\"a\\u0000b\":{}}", 0, MLB_ERR_UNSUPPORTED, "contains \\u0000");
}

TEST(malformed_metadata) {
    BAD("{\"__metadata__\":{\"a\":1}}", 0, FMT, "__metadata__ value for key 'a' is not a string");
    BAD("{\"__metadata__\":{\"a\":null}}", 0, FMT, "value for key 'a' is not a string");
    BAD("{\"__metadata__\":{\"a\":{\"b\":\"c\"}}}", 0, FMT, "value for key 'a' is not a string");
    BAD("{\"__metadata__\":[\"a\"]}", 0, FMT, "__metadata__ is not a JSON object");
    BAD("{\"__metadata__\":\"x\"}", 0, FMT, "__metadata__ is not a JSON object");
    BAD("{\"__metadata__\":{\"k\":\"1\",\"k\":\"2\"}}", 0, FMT, "duplicate __metadata__ key 'k'");
    BAD("{\"__metadata__\":{},\"__metadata__\":{}}", 0, FMT, "__metadata__ appears twice");
}

TEST(malformed_entries) {
    BAD("{\"a\":5}", 0, FMT, "tensor 'a': entry is not a JSON object");
    BAD("{\"a\":{\"shape\":[1],\"data_offsets\":[0,4]}}", 4, FMT, "tensor 'a': missing field 'dtype'");
    BAD("{\"a\":{\"dtype\":\"F32\",\"data_offsets\":[0,4]}}", 4, FMT, "tensor 'a': missing field 'shape'");
    BAD("{\"a\":{\"dtype\":\"F32\",\"shape\":[1]}}", 4, FMT, "tensor 'a': missing field 'data_offsets'");
    BAD("{\"a\":{\"dtype\":\"F32\",\"shape\":[1],\"data_offsets\":[0,4],\"foo\":1}}", 4, FMT,
        "tensor 'a': unknown field 'foo'");
    BAD("{\"a\":{\"dtype\":\"F32\",\"dtype\":\"F32\",\"shape\":[1],\"data_offsets\":[0,4]}}", 4, FMT,
        "tensor 'a': field 'dtype' appears twice");
    BAD(T1("F128", "[1]", "[0,4]"), 4, MLB_ERR_UNSUPPORTED, "tensor 'a': unknown dtype 'F128'");
    BAD(T1("f32", "[1]", "[0,4]"), 4, MLB_ERR_UNSUPPORTED, "unknown dtype 'f32'");
    BAD("{\"a\":{\"dtype\":4,\"shape\":[1],\"data_offsets\":[0,4]}}", 4, FMT, "tensor 'a': dtype is not a string");
    BAD(T1("F32", "4", "[0,4]"), 4, FMT, "tensor 'a': shape is not an array");
    BAD(T1("F32", "[1,1,1,1,1,1,1,1,1]", "[0,4]"), 4, MLB_ERR_UNSUPPORTED, "shape has 9 dimensions, more than the 8");
    BAD(T1("F32", "[\"1\"]", "[0,4]"), 4, FMT, "tensor 'a': shape[0] is not a number");
    BAD(T1("F32", "[1]", "[0]"), 4, FMT, "data_offsets is not an array of 2 integers");
    BAD(T1("F32", "[1]", "[0,4,8]"), 4, FMT, "data_offsets is not an array of 2 integers");
    BAD(T1("F32", "[1]", "{\"a\":0,\"b\":4}"), 4, FMT, "data_offsets is not an array of 2 integers");
    BAD(T1("F32", "[1]", "[4,0]"), 4, FMT, "data_offsets [4, 0] end before they begin");
}

TEST(malformed_numbers) {
    BAD(T1("F32", "[-1]", "[0,4]"), 4, FMT, "tensor 'a': shape[0] is negative (-1)");
    BAD(T1("F32", "[1]", "[-4,0]"), 4, FMT, "tensor 'a': data_offsets[0] is negative (-4)");
    BAD(T1("F32", "[1.5]", "[0,4]"), 4, FMT, "tensor 'a': shape[0] is not a whole number (1.5)");
    BAD(T1("F32", "[1]", "[0,4.5]"), 4, FMT, "tensor 'a': data_offsets[1] is not a whole number (4.5)");
    BAD(T1("F32", "[1e300]", "[0,4]"), 4, FMT, "tensor 'a': shape[0] is too large (1.0000000000000001e+300 > 2^53)");
    BAD(T1("F32", "[1e400]", "[0,4]"), 4, FMT, "shape[0] is too large (inf > 2^53)");
    BAD(T1("F32", "[9007199254740994]", "[0,4]"), 4, FMT, "shape[0] is too large (9007199254740994 > 2^53)");
    BAD(T1("F32", "[1]", "[0,18014398509481984]"), 4, FMT, "data_offsets[1] is too large");
    // Spellings cJSON turns into valid integers: caught by the lexical check, reported last.
    BAD(T1("F32", "[1]", "[0,4.0]"), 4, FMT, "number '4.0' at header byte");
    BAD(T1("F32", "[1e0]", "[0,4]"), 4, FMT, "number '1e0' at header byte 29 is not a plain non-negative integer");
    BAD(T1("F32", "[1]", "[-0,4]"), 4, FMT, "number '-0'");
    BAD(T1("F32", "[01]", "[0,4]"), 4, FMT, "number '01'");
}

TEST(malformed_layout) {
    // Overlap, hole, not from 0, past the end, size mismatch, overflow, trailing, truncated.
    BAD("{\"a\":{\"dtype\":\"F32\",\"shape\":[2],\"data_offsets\":[0,8]},"
        "\"b\":{\"dtype\":\"F32\",\"shape\":[2],\"data_offsets\":[4,12]}}", 12, FMT,
        "tensor 'b' data_offsets [4, 12] overlap the previous tensor 'a', which ends at 8");
    BAD("{\"a\":{\"dtype\":\"F32\",\"shape\":[2],\"data_offsets\":[0,8]},"
        "\"b\":{\"dtype\":\"F32\",\"shape\":[2],\"data_offsets\":[0,8]}}", 8, FMT, "overlap the previous tensor");
    BAD("{\"a\":{\"dtype\":\"F32\",\"shape\":[1],\"data_offsets\":[0,4]},"
        "\"b\":{\"dtype\":\"F32\",\"shape\":[1],\"data_offsets\":[8,12]}}", 12, FMT,
        "hole in the data buffer: bytes [4, 8) before tensor 'b' belong to no tensor");
    BAD(T1("F32", "[1]", "[4,8]"), 8, FMT, "data does not start at offset 0: the first tensor 'a' begins at 4");
    BAD(T1("F32", "[4]", "[0,16]"), 8, FMT, "tensor 'a': data_offsets [0, 16] run past the end of the file "
        "(the data buffer holds 8 bytes)");
    BAD(T1("F32", "[1]", "[4000000000,4000000004]"), 8, FMT, "run past the end of the file");
    BAD(T1("F32", "[3]", "[0,8]"), 8, FMT, "tensor 'a': shape [3] of F32 needs 12 bytes but data_offsets [0, 8] hold 8");
    BAD(T1("F16", "[2,2]", "[0,4]"), 4, FMT, "shape [2, 2] of F16 needs 8 bytes");
    BAD(T1("F32", "[1099511627776,1099511627776]", "[0,4]"), 4, FMT,
        "shape [1099511627776, 1099511627776] has more elements than 64 bits can count (overflow)");
    BAD(T1("F64", "[2147483648,2147483648]", "[0,8]"), 8, FMT, "of F64 is more bytes than 64 bits can count");
    BAD(T1("F32", "[1]", "[0,4]"), 5, FMT, "1 trailing bytes after the last tensor (the tensors cover 4 bytes of the 5-byte");
    BAD("{}", 3, FMT, "3 trailing bytes after the last tensor");
    BAD("{\"a\":{\"dtype\":\"F32\",\"shape\":[1],\"data_offsets\":[0,4]},"
        "\"a\":{\"dtype\":\"F32\",\"shape\":[1],\"data_offsets\":[4,8]}}", 8, FMT, "duplicate tensor name 'a'");
    // Truncation: a valid file cut short by one byte.
    static const char hdr[] = T1("F32", "[4]", "[0,16]");
    size_t n;
    unsigned char* b = make_file(hdr, sizeof hdr - 1, 16, &n);
    mlb_safetensors* st = NULL;
    CHECK(mlb_st_open_memory(&st, b, n, "ok") == MLB_OK);
    mlb_st_close(st);
    expect_bad_bytes(__LINE__, b, n - 1, FMT, "data_offsets [0, 16] run past the end of the file");
    free(b);
}

// ---------------------------------------------------------------- valid files

TEST(valid_edge_cases) {
    size_t n;
    mlb_safetensors* st = NULL;
    // Empty header, with and without padding; a header length of exactly the remaining bytes.
    unsigned char* b = make_file("{}", 2, 0, &n);
    REQUIRE(mlb_st_open_memory(&st, b, n, "empty") == MLB_OK);
    CHECK(mlb_st_count(st) == 0 && mlb_st_tensor_at(st, 0) == NULL && mlb_st_find(st, "a") == NULL);
    CHECK(mlb_st_metadata(st, "x") == NULL && mlb_st_metadata_count(st) == 0);
    mlb_st_close(st);
    free(b);
    b = make_file(" {  }\r\n\t  ", 10, 0, &n);
    CHECK(mlb_st_open_memory(&st, b, n, "empty2") == MLB_OK);
    mlb_st_close(st);
    free(b);
    // Zero-size tensors (before, between, after) and a scalar; unicode names, escapes, metadata.
    static const char h[] =
        "{\"z0\":{\"dtype\":\"F32\",\"shape\":[0,3],\"data_offsets\":[0,0]},"
        "\"s\":{\"dtype\":\"F32\",\"shape\":[],\"data_offsets\":[0,4]},"
        "\"z1\":{\"dtype\":\"BF16\",\"shape\":[5,0],\"data_offsets\":[4,4]},"
        "\"\xc3\xa9t\xc3\xa9\\u00e9\xf0\x9f\x98\x80\":{\"dtype\":\"U8\",\"shape\":[2],\"data_offsets\":[4,6]},"
        "\"__metadata__\":{\"format\":\"pt\",\"q\\\"uote\":\"a\\nb\"},"
        "\"z2\":{\"dtype\":\"I64\",\"shape\":[0],\"data_offsets\":[6,6]}}";
    b = make_file(h, sizeof h - 1, 6, &n);
    float one = 1.5f;
    memcpy(b + 8 + sizeof h - 1, &one, 4);
    REQUIRE(mlb_st_open_memory(&st, b, n, "edge") == MLB_OK);
    CHECK(mlb_st_count(st) == 5);
    CHECK(strcmp(mlb_st_tensor_at(st, 0)->name, "z0") == 0 && strcmp(mlb_st_tensor_at(st, 4)->name, "z2") == 0);
    const mlb_st_tensor* t = mlb_st_find(st, "z0");
    CHECK(t && t->nelem == 0 && t->nbytes == 0 && t->ndim == 2 && t->shape[1] == 3 && t->data != NULL);
    t = mlb_st_find(st, "s");
    CHECK(t && t->ndim == 0 && t->nelem == 1 && t->nbytes == 4);
    float v = 0;
    CHECK(mlb_st_read_f32(st, "s", &v, 1) == MLB_OK && v == 1.5f);
    CHECK(mlb_st_read_f32(st, "z0", NULL, 0) == MLB_OK);
    t = mlb_st_find(st, "\xc3\xa9t\xc3\xa9\xc3\xa9\xf0\x9f\x98\x80");
    CHECK(t && t->dtype == MLB_DT_U8 && t->offset == 4);
    CHECK(mlb_st_metadata(st, "format") && strcmp(mlb_st_metadata(st, "format"), "pt") == 0);
    CHECK(mlb_st_metadata(st, "q\"uote") && strcmp(mlb_st_metadata(st, "q\"uote"), "a\nb") == 0);
    CHECK(mlb_st_metadata_count(st) == 2);
    mlb_st_close(st);
    free(b);
}

TEST(valid_unaligned) {
    // Pad the header so the data starts at an odd byte: every tensor is misaligned for its type.
    char h[256];
    int hl = snprintf(h, sizeof h, "%s", "{\"a\":{\"dtype\":\"F32\",\"shape\":[3],\"data_offsets\":[0,12]},"
                      "\"b\":{\"dtype\":\"F64\",\"shape\":[1],\"data_offsets\":[12,20]},"
                      "\"c\":{\"dtype\":\"F16\",\"shape\":[2],\"data_offsets\":[20,24]}}");
    while ((8 + hl) % 8 != 3) h[hl++] = ' ';
    size_t n;
    unsigned char* b = make_file(h, (size_t)hl, 24, &n);
    unsigned char* d = b + 8 + hl;
    float fa[3] = {1.25f, -2.5f, 3e-8f};
    double db = 0.1;
    uint16_t hc[2] = {0x3C00, 0xC400};
    memcpy(d, fa, 12); memcpy(d + 12, &db, 8); memcpy(d + 20, hc, 4);
    mlb_safetensors* st = NULL;
    REQUIRE(mlb_st_open_memory(&st, b, n, "unaligned") == MLB_OK);
    const mlb_st_tensor* t = mlb_st_find(st, "a");
    REQUIRE(t != NULL);
    CHECK(((uintptr_t)t->data & 3) != 0);
    float out[3];
    CHECK(mlb_st_read_f32(st, "a", out, 3) == MLB_OK && memcmp(out, fa, 12) == 0);
    CHECK(mlb_st_read_f32(st, "b", out, 1) == MLB_OK && out[0] == 0.1f);
    CHECK(mlb_st_read_f32(st, "c", out, 2) == MLB_OK && out[0] == 1.0f && out[1] == -4.0f);
    mlb_st_close(st);
    free(b);
}

TEST(read_and_expect_errors) {
    char h[256];
    snprintf(h, sizeof h, "{\"enc.w0\":{\"dtype\":\"F32\",\"shape\":[64,7],\"data_offsets\":[0,1792]},"
             "\"ids\":{\"dtype\":\"I64\",\"shape\":[2],\"data_offsets\":[1792,1808]}}");
    size_t n;
    unsigned char* b = make_file(h, strlen(h), 1808, &n);
    mlb_safetensors* st = NULL;
    REQUIRE(mlb_st_open_memory(&st, b, n, "model.safetensors") == MLB_OK);
    CHECK(strcmp(mlb_st_path(st), "model.safetensors") == 0);
    CHECK(mlb_st_expect(st, "enc.w0", 2, (const int64_t[]){64, 7}) == MLB_OK);
    CHECK(mlb_st_expect(st, "enc.w0", 2, (const int64_t[]){64, 8}) == MLB_ERR_FORMAT);
    CHECK_MSG(strcmp(mlb_last_error(), "model.safetensors: tensor 'enc.w0' has shape [64, 7], expected [64, 8]") == 0,
              "%s", mlb_last_error());
    CHECK(mlb_st_expect(st, "enc.w0", 1, (const int64_t[]){448}) == MLB_ERR_FORMAT);
    CHECK(strstr(mlb_last_error(), "has shape [64, 7], expected [448]") != NULL);
    CHECK(mlb_st_expect(st, "enc.w1", 1, (const int64_t[]){1}) == MLB_ERR_NOT_FOUND);
    CHECK(strcmp(mlb_last_error(), "model.safetensors: no tensor named 'enc.w1'") == 0);
    float* out = malloc(448 * sizeof *out);
    CHECK(mlb_st_read_f32(st, "enc.w0", out, 448) == MLB_OK);
    CHECK(mlb_st_read_f32(st, "enc.w0", out, 447) == MLB_ERR_FORMAT);
    CHECK(strstr(mlb_last_error(), "model.safetensors: tensor 'enc.w0' has 448 elements (shape [64, 7]), expected 447"));
    CHECK(mlb_st_read_f32(st, "nope", out, 1) == MLB_ERR_NOT_FOUND);
    CHECK(strstr(mlb_last_error(), "model.safetensors: no tensor named 'nope'"));
    CHECK(mlb_st_read_f32(st, "ids", out, 2) == MLB_ERR_UNSUPPORTED);
    CHECK(strstr(mlb_last_error(), "tensor 'ids' is I64"));
    free(out);
    mlb_st_close(st);
    free(b);
    mlb_dtype dt;
    CHECK(mlb_dtype_parse("BF16", &dt) == MLB_OK && dt == MLB_DT_BF16 && mlb_dtype_size(dt) == 2);
    CHECK(mlb_dtype_parse("F8_E5M2", &dt) == MLB_OK && mlb_dtype_size(dt) == 1);
    CHECK(mlb_dtype_parse("F4", &dt) == MLB_ERR_UNSUPPORTED && strstr(mlb_last_error(), "unknown dtype 'F4'"));
    for (int i = 0; i < MLB_DT_COUNT; i++)
        CHECK(mlb_dtype_parse(mlb_dtype_name((mlb_dtype)i), &dt) == MLB_OK && dt == (mlb_dtype)i);
    mlb_st_close(NULL);
    mlb_safetensors* none = NULL;
    CHECK(mlb_st_open(&none, "/nonexistent/x.safetensors") == MLB_ERR_NOT_FOUND && none == NULL);
    CHECK(strstr(mlb_last_error(), "/nonexistent/x.safetensors: No such file"));
    CHECK(mlb_st_open(&none, tmpdir) == MLB_ERR_IO && strstr(mlb_last_error(), "not a regular file"));
}

// A NaN or an infinity in a floating-point tensor is refused by both readers, naming the file, the
// tensor and the element, in every float dtype (the bits of each: F16 0x7E00 and 0xFC00, BF16 0x7FC0
// and 0xFF80, F32 0x7FC00000, F64 +inf, F8_E5M2 0x7C, F8_E4M3 0x7F); an F64 beyond float range is
// refused by the converting reader; finite extremes and integer tensors pass.
TEST(non_finite_refused) {
    static const struct { const char* dtype; int size; uint64_t bits; } bad[] = {
        {"F16", 2, 0x7E00}, {"F16", 2, 0xFC00}, {"BF16", 2, 0x7FC0}, {"BF16", 2, 0xFF80}, {"F32", 4, 0x7FC00000},
        {"F32", 4, 0xFF800000}, {"F64", 8, 0x7FF0000000000000ull}, {"F8_E5M2", 1, 0x7C}, {"F8_E4M3", 1, 0x7F}};
    for (size_t k = 0; k < sizeof bad / sizeof *bad; k++) {
        char h[160];
        int sz = bad[k].size;
        snprintf(h, sizeof h, "{\"w\":{\"dtype\":\"%s\",\"shape\":[3],\"data_offsets\":[0,%d]}}", bad[k].dtype, 3 * sz);
        size_t n;
        unsigned char* b = make_file(h, strlen(h), (size_t)(3 * sz), &n);
        memset(b + 8 + strlen(h), 0, (size_t)(3 * sz));            // zeros: finite
        memcpy(b + 8 + strlen(h) + 2 * sz, &bad[k].bits, (size_t)sz);   // the third element (little-endian)
        mlb_safetensors* st = NULL;
        REQUIRE(mlb_st_open_memory(&st, b, n, "w.safetensors") == MLB_OK);
        float out[3] = {-1, -1, -1};
        unsigned char raw[24];
        mlb_dtype dt;
        REQUIRE(mlb_dtype_parse(bad[k].dtype, &dt) == MLB_OK);
        if (dt == MLB_DT_F32 || dt == MLB_DT_F16 || dt == MLB_DT_BF16 || dt == MLB_DT_F64) {
            CHECK_MSG(mlb_st_read_f32(st, "w", out, 3) == MLB_ERR_NUMERIC, "%s: read_f32", bad[k].dtype);
            CHECK_MSG(strstr(mlb_last_error(), "w.safetensors: tensor 'w' holds a NaN or an infinity (element 2 of 3)"), "%s: %s",
                      bad[k].dtype, mlb_last_error());
        }
        CHECK_MSG(mlb_st_read_raw(st, "w", dt, raw, (size_t)(3 * sz)) == MLB_ERR_NUMERIC, "%s: read_raw", bad[k].dtype);
        CHECK(mlb_st_check_finite(st, mlb_st_find(st, "w")) == MLB_ERR_NUMERIC);
        mlb_st_close(st);
        free(b);
    }
    // an F64 beyond float range, and finite extremes that pass
    const char* h = "{\"d\":{\"dtype\":\"F64\",\"shape\":[2],\"data_offsets\":[0,16]},"
                    "\"f\":{\"dtype\":\"F32\",\"shape\":[2],\"data_offsets\":[16,24]},"
                    "\"i\":{\"dtype\":\"I32\",\"shape\":[1],\"data_offsets\":[24,28]}}";
    size_t n;
    unsigned char* b = make_file(h, strlen(h), 28, &n);
    double d[2] = {1e300, 1};
    float f[2] = {FLT_MAX, -FLT_MAX};
    uint32_t i32 = 0x7FC00000u;   // an integer with a NaN's bits: not a float, passes
    memcpy(b + 8 + strlen(h), d, 16);
    memcpy(b + 8 + strlen(h) + 16, f, 8);
    memcpy(b + 8 + strlen(h) + 24, &i32, 4);
    mlb_safetensors* st = NULL;
    REQUIRE(mlb_st_open_memory(&st, b, n, "x.safetensors") == MLB_OK);
    float out[2];
    CHECK(mlb_st_read_f32(st, "d", out, 2) == MLB_ERR_NUMERIC && strstr(mlb_last_error(), "element 0 (1e+300) is beyond float range"));
    CHECK(mlb_st_read_f32(st, "f", out, 2) == MLB_OK && out[0] == FLT_MAX);
    int32_t iv;
    CHECK(mlb_st_read_raw(st, "i", MLB_DT_I32, &iv, 4) == MLB_OK);
    mlb_st_close(st);
    free(b);
}

// ---------------------------------------------------------------- writer

static int count_files(const char* dir) {
    DIR* d = opendir(dir);
    int k = 0;
    if (!d) return -1;
    for (struct dirent* e; (e = readdir(d));) if (e->d_name[0] != '.') k++;
    closedir(d);
    return k;
}

TEST(write_round_trip) {
    char path[4200];
    snprintf(path, sizeof path, "%s/rt.safetensors", tmpdir);
    float w[6] = {1.0f, -0.333333f, 65504.0f, 1e-6f, 3.14159f, -0.0f};
    uint16_t wh[6], wb[6];
    mlb_f32_to_f16_array(wh, w, 6);
    mlb_f32_to_bf16_array(wb, w, 6);
    double dd[2] = {1e-300, 2.5};
    int64_t ids[3] = {0, 1, -7};
    const mlb_st_entry e[] = {
        {"w.f32", MLB_DT_F32, 2, (const int64_t[]){2, 3}, w},
        {"w.f16", MLB_DT_F16, 2, (const int64_t[]){3, 2}, wh},
        {"empty", MLB_DT_F32, 2, (const int64_t[]){0, 4}, NULL},
        {"w.bf16", MLB_DT_BF16, 1, (const int64_t[]){6}, wb},
        {"scalar", MLB_DT_F64, 0, NULL, dd + 1},
        {"d", MLB_DT_F64, 1, (const int64_t[]){2}, dd},
        {"ids \"quoted\"\n\xc3\xa9", MLB_DT_I64, 1, (const int64_t[]){3}, ids},
    };
    const mlb_st_meta meta[] = {{"format", "pt"}, {"note", "line1\nline2 \"q\" \\ \x01 \xe2\x82\xac"}};
    REQUIRE(mlb_st_write(path, e, 7, meta, 2) == MLB_OK);
    CHECK(count_files(tmpdir) == 1);   // no temporary left behind
    mlb_safetensors* st = NULL;
    REQUIRE(mlb_st_open(&st, path) == MLB_OK);
    CHECK(mlb_st_count(st) == 7);
    for (size_t i = 0; i < 7; i++) CHECK(strcmp(mlb_st_tensor_at(st, i)->name, e[i].name) == 0);
    const mlb_st_tensor* t0 = mlb_st_tensor_at(st, 0);
    CHECK(t0->offset == 0 && (uintptr_t)t0->data % 8 == 0);   // mmap is page-aligned
    for (size_t i = 1; i < 7; i++)   // data_offsets ascending in entry order
        CHECK(mlb_st_tensor_at(st, i)->offset == mlb_st_tensor_at(st, i - 1)->offset + mlb_st_tensor_at(st, i - 1)->nbytes);
    float out[6];
    CHECK(mlb_st_read_f32(st, "w.f32", out, 6) == MLB_OK && memcmp(out, w, sizeof w) == 0);
    CHECK(mlb_st_read_f32(st, "w.f16", out, 6) == MLB_OK);
    for (int i = 0; i < 6; i++) CHECK(out[i] == mlb_f16_to_f32(wh[i]));
    CHECK_CLOSE(out[1], w[1], 1.0 / 2048, 0);
    CHECK(mlb_st_read_f32(st, "w.bf16", out, 6) == MLB_OK);
    for (int i = 0; i < 6; i++) CHECK_CLOSE(out[i], w[i], 1.0 / 256, 0);
    CHECK(signbit(out[5]));
    CHECK(mlb_st_read_f32(st, "scalar", out, 1) == MLB_OK && out[0] == 2.5f);
    CHECK(mlb_st_read_f32(st, "d", out, 2) == MLB_OK && out[0] == 0.0f && out[1] == 2.5f);
    const mlb_st_tensor* t = mlb_st_find(st, "ids \"quoted\"\n\xc3\xa9");
    CHECK(t && t->dtype == MLB_DT_I64 && memcmp(t->data, ids, sizeof ids) == 0);
    CHECK(mlb_st_expect(st, "empty", 2, (const int64_t[]){0, 4}) == MLB_OK);
    CHECK(mlb_st_metadata(st, "note") && strcmp(mlb_st_metadata(st, "note"), meta[1].value) == 0);
    mlb_st_close(st);
    // Header length is a multiple of 8, so the data starts 8-aligned in the file.
    FILE* f = fopen(path, "rb");
    unsigned char len8[8] = {0};
    CHECK(f && fread(len8, 1, 8, f) == 8);
    if (f) fclose(f);
    CHECK(len8[0] % 8 == 0);
    // Nothing at all, and only metadata.
    CHECK(mlb_st_write(path, NULL, 0, NULL, 0) == MLB_OK);
    REQUIRE(mlb_st_open(&st, path) == MLB_OK);
    CHECK(mlb_st_count(st) == 0);
    mlb_st_close(st);
    CHECK(mlb_st_write(path, NULL, 0, meta, 1) == MLB_OK);
    REQUIRE(mlb_st_open(&st, path) == MLB_OK);
    CHECK(mlb_st_count(st) == 0 && strcmp(mlb_st_metadata(st, "format"), "pt") == 0);
    mlb_st_close(st);
    unlink(path);
}

// mlb_st_read_f32 drops a tensor's pages of the mapping once converted (so a loader does not hold
// the file beside its weights): the data stays readable, through read_f32 again and through t->data.
TEST(read_drops_pages_keeps_data) {
    char path[4200];
    snprintf(path, sizeof path, "%s/pages.safetensors", tmpdir);
    enum { N = 6000 };   // 24 KB: whole pages inside it
    float* w = malloc(sizeof(float) * N), *out = malloc(sizeof(float) * N);
    REQUIRE(w && out);
    for (int i = 0; i < N; i++) w[i] = (float)i * 0.25f - 7.0f;
    const mlb_st_entry e[] = {{"head", MLB_DT_F32, 1, (const int64_t[]){3}, w},
                              {"big", MLB_DT_F32, 1, (const int64_t[]){N}, w}};
    REQUIRE(mlb_st_write(path, e, 2, NULL, 0) == MLB_OK);
    mlb_safetensors* st = NULL;
    REQUIRE(mlb_st_open(&st, path) == MLB_OK);
    for (int pass = 0; pass < 2; pass++) {
        memset(out, 0, sizeof(float) * N);
        CHECK(mlb_st_read_f32(st, "big", out, N) == MLB_OK && memcmp(out, w, sizeof(float) * N) == 0);
    }
    CHECK(memcmp(mlb_st_find(st, "big")->data, w, sizeof(float) * N) == 0);
    // the bytes as stored, only for the dtype and size asked (pages dropped the same way)
    memset(out, 0, sizeof(float) * N);
    CHECK(mlb_st_read_raw(st, "big", MLB_DT_F32, out, sizeof(float) * N) == MLB_OK && memcmp(out, w, sizeof(float) * N) == 0);
    CHECK(mlb_st_read_raw(st, "big", MLB_DT_F16, out, sizeof(float) * N) == MLB_ERR_FORMAT);
    CHECK(strstr(mlb_last_error(), "tensor 'big' is F32, 24000 bytes; expected F16") != NULL);
    CHECK(mlb_st_read_raw(st, "big", MLB_DT_F32, out, sizeof(float) * N - 4) == MLB_ERR_FORMAT);
    CHECK(mlb_st_read_raw(st, "nope", MLB_DT_F32, out, 4) == MLB_ERR_NOT_FOUND);
    CHECK(mlb_st_read_f32(st, "head", out, 3) == MLB_OK && memcmp(out, w, 3 * sizeof(float)) == 0);
    mlb_st_close(st);
    unlink(path);
    free(w);
    free(out);
}

TEST(write_errors_leave_file_alone) {
    char path[4200];
    snprintf(path, sizeof path, "%s/keep.safetensors", tmpdir);
    float x[2] = {1, 2};
    const mlb_st_entry ok[] = {{"x", MLB_DT_F32, 1, (const int64_t[]){2}, x}};
    REQUIRE(mlb_st_write(path, ok, 1, NULL, 0) == MLB_OK);
    char* before; size_t nb;
    REQUIRE(mlb_read_file(path, &before, &nb, 1 << 20) == MLB_OK);
    struct { mlb_st_entry e[2]; size_t n; mlb_st_meta m[2]; size_t nm; const char* msg; } cases[] = {
        {{{"x", MLB_DT_F32, 1, (const int64_t[]){2}, x}, {"x", MLB_DT_F32, 1, (const int64_t[]){2}, x}}, 2, {{0}}, 0,
         "duplicate tensor name 'x'"},
        {{{"x", MLB_DT_F32, 1, (const int64_t[]){2}, NULL}}, 1, {{0}}, 0, "tensor 'x': NULL data for 8 bytes"},
        {{{"x", MLB_DT_F32, 1, (const int64_t[]){-2}, x}}, 1, {{0}}, 0, "shape[0] = -2 is outside [0, 2^53]"},
        {{{"x", MLB_DT_F32, 9, (const int64_t[]){1, 1, 1, 1, 1, 1, 1, 1, 1}, x}}, 1, {{0}}, 0, "ndim 9 must be 0..8"},
        {{{"x", MLB_DT_COUNT, 1, (const int64_t[]){2}, x}}, 1, {{0}}, 0, "invalid dtype"},
        {{{"__metadata__", MLB_DT_F32, 1, (const int64_t[]){2}, x}}, 1, {{0}}, 0, "'__metadata__' is reserved"},
        {{{"bad\xff", MLB_DT_F32, 1, (const int64_t[]){2}, x}}, 1, {{0}}, 0, "entry 0: name is not valid UTF-8"},
        {{{NULL, MLB_DT_F32, 1, (const int64_t[]){2}, x}}, 1, {{0}}, 0, "entry 0 has no name"},
        {{{"x", MLB_DT_F32, 2, (const int64_t[]){1ll << 40, 1ll << 40}, x}}, 1, {{0}}, 0, "sizes overflow"},
        {{{"x", MLB_DT_F32, 1, (const int64_t[]){2}, x}}, 1, {{"k", "1"}, {"k", "2"}}, 2, "duplicate metadata key 'k'"},
        {{{"x", MLB_DT_F32, 1, (const int64_t[]){2}, x}}, 1, {{"k", NULL}}, 1, "NULL key or value"},
        {{{"x", MLB_DT_F32, 1, (const int64_t[]){2}, x}}, 1, {{"k", "\xc0\x80"}}, 1, "not valid UTF-8"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        mlb_status s = mlb_st_write(path, cases[i].e, cases[i].n, cases[i].m, cases[i].nm);
        CHECK_MSG(s == MLB_ERR_ARG && strstr(mlb_last_error(), cases[i].msg) &&
                  strncmp(mlb_last_error(), path, strlen(path)) == 0,
                  "case %zu: %s: %s", i, mlb_status_name(s), mlb_last_error());
    }
    char* after; size_t na;
    REQUIRE(mlb_read_file(path, &after, &na, 1 << 20) == MLB_OK);
    CHECK(na == nb && memcmp(before, after, nb) == 0);
    CHECK(count_files(tmpdir) == 1);
    free(before);
    free(after);
    char bad[4300];
    snprintf(bad, sizeof bad, "%s/no/such/dir/x.safetensors", tmpdir);
    CHECK(mlb_st_write(bad, ok, 1, NULL, 0) == MLB_ERR_IO && strstr(mlb_last_error(), "no/such/dir/x.safetensors"));
    unlink(path);
}

// ---------------------------------------------------------------- shared reference data

// A small file whose whole content is a relative path to a file beside it: a symlink that was
// copied as text. Returns the target path in `target` or 0.
static int text_standin(const char* path, char* target, size_t cap) {
    char* txt; size_t n;
    if (mlb_read_file(path, &txt, &n, 1024) != MLB_OK) return 0;
    int ok = n > 0 && n < 512 && !memchr(txt, '\n', n);
    for (size_t i = 0; ok && i < n; i++) ok = txt[i] > 0x20 && txt[i] < 0x7F;
    if (ok) {
        const char* slash = strrchr(path, '/');
        snprintf(target, cap, "%.*s/%s", (int)(slash - path), path, txt);
        ok = access(target, R_OK) == 0;
    }
    free(txt);
    return ok;
}

static int check_all_tensors(const char* path, const mlb_safetensors* st) {
    int bad = 0;
    for (size_t i = 0; i < mlb_st_count(st); i++) {
        const mlb_st_tensor* t = mlb_st_tensor_at(st, i);
        if (mlb_st_find(st, t->name) != t) bad++;
        if (t->dtype != MLB_DT_F32 && t->dtype != MLB_DT_F16 && t->dtype != MLB_DT_BF16 && t->dtype != MLB_DT_F64) continue;
        float* buf = malloc((t->nelem ? t->nelem : 1) * sizeof *buf);
        if (mlb_st_read_f32(st, t->name, buf, t->nelem) != MLB_OK) bad++;
        free(buf);
    }
    if (bad) printf("  %s: %d tensors failed to read\n", path, bad);
    return bad;
}

TEST(shared_sd_reference_files) {
    const char* data = test_shared_data();
    if (!data) SKIP("no shared data folder");
    char dir[4200];
    snprintf(dir, sizeof dir, "%s/sd_reference", data);
    const char* sub[] = {"", "/sd1_diffusers/text_encoder", "/sd1_diffusers/unet", "/sd1_diffusers/vae"};
    int opened = 0, standins = 0;
    for (size_t k = 0; k < sizeof sub / sizeof sub[0]; k++) {
        char d[4300];
        snprintf(d, sizeof d, "%s%s", dir, sub[k]);
        DIR* dd = opendir(d);
        if (!dd) continue;
        for (struct dirent* e; (e = readdir(dd));) {
            size_t len = strlen(e->d_name);
            if (len < 12 || strcmp(e->d_name + len - 12, ".safetensors") != 0) continue;
            char path[4600], target[4600];
            snprintf(path, sizeof path, "%s/%s", d, e->d_name);
            mlb_safetensors* st = NULL;
            mlb_status s = mlb_st_open(&st, path);
            if (s != MLB_OK && text_standin(path, target, sizeof target)) {
                // The reader must refuse it with a helpful message; the real file is read instead.
                CHECK_MSG(s == MLB_ERR_FORMAT && strstr(mlb_last_error(), "text stand-in"), "%s", mlb_last_error());
                standins++;
                snprintf(path, sizeof path, "%s", target);
                s = mlb_st_open(&st, path);
            }
            CHECK_MSG(s == MLB_OK, "%s", mlb_last_error());
            if (s != MLB_OK) continue;
            opened++;
            CHECK(mlb_st_count(st) > 0);
            CHECK(check_all_tensors(path, st) == 0);
            mlb_st_close(st);
        }
        closedir(dd);
    }
    printf("  opened %d files (%d text stand-ins followed)\n", opened, standins);
    CHECK(opened >= 10);
}

TEST(shared_sd1_f16_matches_f32) {
    const char* data = test_shared_data();
    if (!data) SKIP("no shared data folder");
    char p32[4200], p16[4200], pbf[4300];
    snprintf(p32, sizeof p32, "%s/sd_reference/sd1_tiny.safetensors", data);
    snprintf(p16, sizeof p16, "%s/sd_reference/sd1_tiny.f16.safetensors", data);
    if (access(p32, R_OK) != 0 || access(p16, R_OK) != 0) SKIP("sd1_tiny(.f16).safetensors missing");
    mlb_safetensors *a = NULL, *h = NULL;
    REQUIRE(mlb_st_open(&a, p32) == MLB_OK);
    REQUIRE(mlb_st_open(&h, p16) == MLB_OK);
    CHECK(mlb_st_count(a) == mlb_st_count(h) && mlb_st_count(a) == 993);
    size_t n = mlb_st_count(a), compared = 0, not_rne = 0, too_far = 0;
    mlb_st_entry* bf = calloc(n, sizeof *bf);
    void** bufs = calloc(n, sizeof *bufs);
    for (size_t i = 0; i < n; i++) {
        const mlb_st_tensor* ta = mlb_st_tensor_at(a, i);
        const mlb_st_tensor* th = mlb_st_find(h, ta->name);
        CHECK_MSG(th && th->ndim == ta->ndim && th->nelem == ta->nelem, "%s", ta->name);
        if (!th) continue;
        CHECK(mlb_st_expect(h, ta->name, ta->ndim, ta->shape) == MLB_OK);
        bf[i] = (mlb_st_entry){ta->name, ta->dtype, ta->ndim, ta->shape, ta->data};
        if (ta->dtype != MLB_DT_F32) {   // position_ids stay I64, byte for byte
            CHECK(th->dtype == ta->dtype && th->nbytes == ta->nbytes && memcmp(th->data, ta->data, ta->nbytes) == 0);
            continue;
        }
        CHECK(th->dtype == MLB_DT_F16);
        float* x = malloc(ta->nelem * sizeof *x);
        float* y = malloc(ta->nelem * sizeof *y);
        CHECK(mlb_st_read_f32(a, ta->name, x, ta->nelem) == MLB_OK);
        CHECK(mlb_st_read_f32(h, ta->name, y, ta->nelem) == MLB_OK);
        for (size_t j = 0; j < ta->nelem; j++) {
            if (mlb_f16_to_f32(mlb_f32_to_f16(x[j])) != y[j]) not_rne++;
            // within half an f16 ulp: relative 2^-11 for normals, absolute 2^-25 for subnormals
            if (!(fabsf(x[j] - y[j]) <= fmaxf(fabsf(x[j]) * 0x1p-11f, 0x1p-25f))) too_far++;
        }
        compared += ta->nelem;
        bufs[i] = malloc(ta->nelem * 2);   // keep a BF16 copy for the writer below
        mlb_f32_to_bf16_array(bufs[i], x, ta->nelem);
        bf[i].dtype = MLB_DT_BF16;
        bf[i].data = bufs[i];
        free(x);
        free(y);
    }
    printf("  compared %zu values: %zu not round-to-nearest-even, %zu beyond half an ulp\n", compared, not_rne, too_far);
    CHECK(compared > 1000000 && not_rne == 0 && too_far == 0);
    // No BF16 copy is shipped: write one with our writer and read it back against the F32 file.
    snprintf(pbf, sizeof pbf, "%s/sd1_tiny.bf16.safetensors", tmpdir);
    const mlb_st_meta meta[] = {{"format", "pt"}, {"dtype", "bfloat16"}};
    CHECK(mlb_st_write(pbf, bf, n, meta, 2) == MLB_OK);
    mlb_safetensors* b = NULL;
    REQUIRE(mlb_st_open(&b, pbf) == MLB_OK);
    size_t bad = 0;
    for (size_t i = 0; i < n; i++) {
        const mlb_st_tensor* ta = mlb_st_tensor_at(a, i);
        if (ta->dtype != MLB_DT_F32) continue;
        float* x = malloc(ta->nelem * sizeof *x);
        float* y = malloc(ta->nelem * sizeof *y);
        CHECK(mlb_st_read_f32(a, ta->name, x, ta->nelem) == MLB_OK);
        CHECK(mlb_st_read_f32(b, ta->name, y, ta->nelem) == MLB_OK);
        for (size_t j = 0; j < ta->nelem; j++)
            if (!(fabsf(x[j] - y[j]) <= fabsf(x[j]) * 0x1p-8f)) bad++;
        free(x);
        free(y);
    }
    CHECK_MSG(bad == 0, "%zu bf16 values beyond half an ulp", bad);
    mlb_st_close(b);
    for (size_t i = 0; i < n; i++) free(bufs[i]);
    free(bufs);
    free(bf);
    unlink(pbf);
    mlb_st_close(a);
    mlb_st_close(h);
}

int main(void) {
    tmpdir = test_tmpdir("safetensors");
    if (!tmpdir) { printf("cannot create a scratch folder\n"); return 1; }
    RUN(f16_known_values);
    RUN(f16_exhaustive);
#ifdef __FLT16_MANT_DIG__
    RUN(f16_vs_compiler);
#endif
    RUN(f16_array_matches_scalar);
    RUN(bf16_exhaustive);
    RUN(malformed_size_and_length);
    RUN(malformed_text);
    RUN(malformed_metadata);
    RUN(malformed_entries);
    RUN(malformed_numbers);
    RUN(malformed_layout);
    RUN(valid_edge_cases);
    RUN(valid_unaligned);
    RUN(read_and_expect_errors);
    RUN(non_finite_refused);
    RUN(write_round_trip);
    RUN(read_drops_pages_keeps_data);
    RUN(write_errors_leave_file_alone);
    RUN(shared_sd_reference_files);
    RUN(shared_sd1_f16_matches_f32);
    return test_summary();
}
