// libFuzzer target for the safetensors reader (built and run by scripts/fuzz.sh, not by CMake).
// Every input goes through mlb_st_open_memory. A rejected input must leave a message naming the
// buffer; an accepted one must satisfy the reader's promises (tensors inside the buffer, tiling it
// exactly, lookups consistent), and every float tensor is converted with mlb_st_read_f32 so the
// sanitizers see each byte read. A broken promise aborts, which libFuzzer records as a crash.
//
// Built with -DMLB_FUZZ_SEED the same file is a small program that writes valid seed files with
// mlb_st_write into the folder given as its argument.
#include "matlaber/half.h"
#include "matlaber/safetensors.h"
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PROMISE(cond) do { if (!(cond)) { fprintf(stderr, "broken promise: %s\n", #cond); abort(); } } while (0)

static int is_float(mlb_dtype dt) {
    return dt == MLB_DT_F32 || dt == MLB_DT_F16 || dt == MLB_DT_BF16 || dt == MLB_DT_F64;
}

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    mlb_safetensors* st = NULL;
    mlb_status s = mlb_st_open_memory(&st, data, size, "fuzz");
    if (s != MLB_OK) {
        PROMISE(st == NULL);
        PROMISE(strncmp(mlb_last_error(), "fuzz: ", 6) == 0);
        return 0;
    }
    uint64_t hlen = 0;
    for (int i = 7; i >= 0; i--) hlen = (hlen << 8) | data[i];
    const uint8_t* buf = data + 8 + hlen;
    size_t buf_size = size - 8 - (size_t)hlen, covered = 0;
    volatile unsigned sink = 0;
    for (size_t i = 0; i < mlb_st_count(st); i++) {
        const mlb_st_tensor* t = mlb_st_tensor_at(st, i);
        PROMISE(t && t->name && mlb_st_find(st, t->name) == t);
        PROMISE(t->ndim >= 0 && t->ndim <= MLB_ST_MAX_DIMS);
        size_t ne = 1;
        for (int d = 0; d < t->ndim; d++) ne *= (size_t)t->shape[d];   // cannot overflow once accepted
        PROMISE(ne == t->nelem && t->nbytes == t->nelem * mlb_dtype_size(t->dtype));
        PROMISE((const uint8_t*)t->data == buf + t->offset && t->offset + t->nbytes <= buf_size);
        PROMISE(mlb_st_expect(st, t->name, t->ndim, t->shape) == MLB_OK);
        covered += t->nbytes;
        const uint8_t* p = t->data;
        for (size_t k = 0; k < t->nbytes; k++) sink += p[k];
        float* out = malloc((t->nelem ? t->nelem : 1) * sizeof *out);
        if (!out) continue;
        s = mlb_st_read_f32(st, t->name, out, t->nelem);
        PROMISE(is_float(t->dtype) ? s == MLB_OK : s == MLB_ERR_UNSUPPORTED);
        if (t->nelem) PROMISE(mlb_st_read_f32(st, t->name, out, t->nelem - 1) == MLB_ERR_FORMAT);
        free(out);
    }
    PROMISE(covered == buf_size);
    for (size_t i = 0; i < mlb_st_metadata_count(st); i++) {
        const char *k, *v;
        PROMISE(mlb_st_metadata_at(st, i, &k, &v) == 0 && mlb_st_metadata(st, k) == v);
    }
    PROMISE(mlb_st_find(st, "__metadata__") == NULL);
    mlb_st_close(st);
    (void)sink;
    return 0;
}

#ifdef MLB_FUZZ_SEED
// Seeds: small valid files covering every dtype, metadata, scalars, zero-size tensors, and one
// with an unaligned data buffer (written by hand: the writer always aligns).
int main(int argc, char** argv) {
    if (argc != 2) { fprintf(stderr, "usage: %s CORPUS_DIR\n", argv[0]); return 2; }
    char path[4096];
    unsigned char bytes[64];
    for (int i = 0; i < 64; i++) bytes[i] = (unsigned char)(i * 29 + 3);
    float f[4] = {1.0f, -2.5f, 1e-8f, 65504.0f};
    uint16_t h[4], b[4];
    mlb_f32_to_f16_array(h, f, 4);
    mlb_f32_to_bf16_array(b, f, 4);
    const mlb_st_meta meta[] = {{"format", "pt"}, {"note", "seed \"quoted\" \xc3\xa9"}};
    const mlb_st_entry all[] = {
        {"f32", MLB_DT_F32, 2, (const int64_t[]){2, 2}, f}, {"f16", MLB_DT_F16, 1, (const int64_t[]){4}, h},
        {"bf16", MLB_DT_BF16, 1, (const int64_t[]){4}, b}, {"f64", MLB_DT_F64, 0, NULL, bytes},
        {"i64", MLB_DT_I64, 1, (const int64_t[]){1}, bytes}, {"i32", MLB_DT_I32, 1, (const int64_t[]){2}, bytes},
        {"i16", MLB_DT_I16, 1, (const int64_t[]){1}, bytes}, {"i8", MLB_DT_I8, 1, (const int64_t[]){3}, bytes},
        {"u8", MLB_DT_U8, 1, (const int64_t[]){1}, bytes}, {"bool", MLB_DT_BOOL, 1, (const int64_t[]){2}, bytes},
        {"e4m3", MLB_DT_F8_E4M3, 1, (const int64_t[]){1}, bytes}, {"e5m2", MLB_DT_F8_E5M2, 1, (const int64_t[]){1}, bytes},
        {"u16", MLB_DT_U16, 1, (const int64_t[]){1}, bytes}, {"u32", MLB_DT_U32, 1, (const int64_t[]){1}, bytes},
        {"u64", MLB_DT_U64, 1, (const int64_t[]){1}, bytes},
        {"zero", MLB_DT_F32, 3, (const int64_t[]){0, 2, 3}, NULL},
        {"\xe5\x90\x8d.w", MLB_DT_F16, 8, (const int64_t[]){1, 1, 1, 1, 1, 1, 1, 2}, h},
    };
    struct { const char* name; size_t n_entries, n_meta; } seeds[] = {
        {"empty", 0, 0}, {"meta_only", 0, 2}, {"one", 1, 0}, {"floats", 4, 1}, {"all", 17, 2},
    };
    for (size_t i = 0; i < sizeof seeds / sizeof seeds[0]; i++) {
        snprintf(path, sizeof path, "%s/seed_%s.safetensors", argv[1], seeds[i].name);
        if (mlb_st_write(path, all, seeds[i].n_entries, meta, seeds[i].n_meta) != MLB_OK) {
            fprintf(stderr, "%s\n", mlb_last_error());
            return 1;
        }
    }
    static const char hdr[] = "{\"a\":{\"dtype\":\"F32\",\"shape\":[1],\"data_offsets\":[0,4]},"
                              "\"b\":{\"dtype\":\"F16\",\"shape\":[],\"data_offsets\":[4,6]}}";
    snprintf(path, sizeof path, "%s/seed_unaligned.safetensors", argv[1]);
    FILE* fp = fopen(path, "wb");
    if (!fp) { perror(path); return 1; }
    uint64_t n = sizeof hdr - 1;
    unsigned char len8[8];
    for (int i = 0; i < 8; i++) len8[i] = (unsigned char)(n >> (8 * i));
    fwrite(len8, 1, 8, fp);
    fwrite(hdr, 1, n, fp);
    fwrite(f, 1, 4, fp);
    fwrite(h, 1, 2, fp);
    return fclose(fp) == 0 ? 0 : 1;
}
#endif
