// safetensors reader and writer (the weight format; see docs/safetensors.md).
//
// File layout: 8-byte little-endian u64 N, N bytes of UTF-8 JSON header, then the data buffer.
//   {"__metadata__": {"key": "value", ...},          (optional, string -> string)
//    "name": {"dtype": "F32", "shape": [d0, d1, ...], "data_offsets": [begin, end]}, ...}
// Offsets are bytes relative to the start of the data buffer. Tensor data is row-major (C order,
// last dimension fastest), little-endian, with no padding between elements.
//
// The reader validates everything before returning (see docs/safetensors.md for the rules and
// their messages), so a successfully opened file is internally consistent: every tensor's bytes
// lie inside the buffer, the tensors tile it exactly, and nbytes == nelem * dtype size.
// Tensor data pointers point straight into the mapping (or the caller's memory): they are NOT
// aligned in general, so read them with memcpy or the converters here, never as float*.
// This code assumes a little-endian host.
#ifndef MATLABER_SAFETENSORS_H
#define MATLABER_SAFETENSORS_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/error.h"

#define MLB_ST_MAX_DIMS 8                       // higher ranks are refused (MLB_ERR_UNSUPPORTED)
#define MLB_ST_MAX_HEADER 100000000ull          // header length limit, as in the reference reader
#define MLB_ST_MAX_INT 9007199254740992ull      // 2^53: the largest shape/offset number accepted

typedef enum {
    MLB_DT_F64 = 0, MLB_DT_F32, MLB_DT_F16, MLB_DT_BF16,
    MLB_DT_I64, MLB_DT_I32, MLB_DT_I16, MLB_DT_I8,
    MLB_DT_U64, MLB_DT_U32, MLB_DT_U16, MLB_DT_U8,
    MLB_DT_BOOL, MLB_DT_F8_E4M3, MLB_DT_F8_E5M2,
    MLB_DT_COUNT
} mlb_dtype;

const char* mlb_dtype_name(mlb_dtype dt);           // "F32"; "?" when out of range
size_t mlb_dtype_size(mlb_dtype dt);                // bytes per element; 0 when out of range
// The safetensors spelling ("F16", "BF16", ...; case-sensitive) to a dtype; MLB_ERR_UNSUPPORTED
// (message lists the known names) for anything else.
mlb_status mlb_dtype_parse(const char* name, mlb_dtype* out);

typedef struct {
    const char* name;                   // owned by the mlb_safetensors
    mlb_dtype dtype;
    int ndim;                           // 0..MLB_ST_MAX_DIMS; 0 = scalar (one element)
    int64_t shape[MLB_ST_MAX_DIMS];     // shape[0..ndim-1]; the rest are 0
    size_t nelem;                       // product of the shape (1 for a scalar)
    size_t nbytes;                      // nelem * mlb_dtype_size(dtype) == end - begin
    size_t offset;                      // begin, relative to the data buffer
    const void* data;                   // into the mapping; maybe unaligned; never NULL (even when nbytes == 0)
} mlb_st_tensor;

typedef struct mlb_safetensors mlb_safetensors;

// Maps the file read-only (zero copy) and validates it. *out is NULL on failure.
// The mapping lives until mlb_st_close; truncating the file meanwhile is undefined (SIGBUS).
mlb_status mlb_st_open(mlb_safetensors** out, const char* path);
// Same over a caller's buffer, which must outlive the handle (nothing is copied).
// name_for_errors names the buffer in messages (NULL: "<memory>").
mlb_status mlb_st_open_memory(mlb_safetensors** out, const void* data, size_t n, const char* name_for_errors);
void mlb_st_close(mlb_safetensors* st);                     // NULL is fine

const char* mlb_st_path(const mlb_safetensors* st);        // the path or name used in messages
size_t mlb_st_count(const mlb_safetensors* st);            // number of tensors
const mlb_st_tensor* mlb_st_tensor_at(const mlb_safetensors* st, size_t i);   // file (header) order; NULL past the end
const mlb_st_tensor* mlb_st_find(const mlb_safetensors* st, const char* name); // O(log n); NULL when absent
// Metadata: NULL when absent. Keys in sorted order through mlb_st_metadata_at.
const char* mlb_st_metadata(const mlb_safetensors* st, const char* key);
size_t mlb_st_metadata_count(const mlb_safetensors* st);
int mlb_st_metadata_at(const mlb_safetensors* st, size_t i, const char** key, const char** value);  // 0 on success

// Copies tensor `name` into out[0..n_elems-1] as float32, converting from F32, F16, BF16 or F64
// (F64 rounds to nearest). Errors name the tensor and the file: MLB_ERR_NOT_FOUND when missing,
// MLB_ERR_FORMAT when it holds a different number of elements, MLB_ERR_UNSUPPORTED for other dtypes,
// MLB_ERR_NUMERIC when an element is NaN or infinite (or an F64 beyond float range): weights and
// checkpoints are finite, and a NaN read in would spread silently through every step after it.
mlb_status mlb_st_read_f32(const mlb_safetensors* st, const char* name, float* out, size_t n_elems);
// Copies tensor `name` as the file stores it (no conversion) into out[0..nbytes-1], its pages then
// dropped as mlb_st_read_f32 drops them: MLB_ERR_FORMAT unless it is `dtype` and holds nbytes bytes;
// a floating-point tensor with a NaN or an infinity: MLB_ERR_NUMERIC, as mlb_st_read_f32.
mlb_status mlb_st_read_raw(const mlb_safetensors* st, const char* name, mlb_dtype dtype, void* out, size_t nbytes);
// MLB_ERR_NUMERIC naming the file, the tensor and the first element when a floating-point tensor
// (F64, F32, F16, BF16, F8) holds a NaN or an infinity; MLB_OK otherwise (other dtypes too).
mlb_status mlb_st_check_finite(const mlb_safetensors* st, const mlb_st_tensor* t);
// MLB_OK when tensor `name` exists with exactly this shape; otherwise MLB_ERR_NOT_FOUND or
// MLB_ERR_FORMAT ("model.safetensors: tensor 'enc.w0' has shape [64, 7], expected [64, 8]").
mlb_status mlb_st_expect(const mlb_safetensors* st, const char* name, int ndim, const int64_t* shape);

// ---- writer ----
typedef struct {
    const char* name;       // UTF-8, unique, not "__metadata__"
    mlb_dtype dtype;
    int ndim;               // 0..MLB_ST_MAX_DIMS
    const int64_t* shape;   // ndim entries, each >= 0 (may be NULL when ndim == 0)
    const void* data;       // nelem * dtype size bytes, little-endian, any alignment (NULL only when empty)
} mlb_st_entry;

typedef struct {
    const char* key;        // UTF-8, unique
    const char* value;      // UTF-8
} mlb_st_meta;

// Writes entries in the given order (data_offsets ascending in that order), the header padded
// with spaces so the data starts at a multiple of 8 bytes. Written to a temporary file beside
// `path`, fsynced and renamed over it: on any failure `path` is left as it was.
// Bad arguments (duplicate names or keys, invalid UTF-8, bad shapes, NULL data) give MLB_ERR_ARG
// before anything is written.
mlb_status mlb_st_write(const char* path, const mlb_st_entry* entries, size_t n_entries,
                        const mlb_st_meta* metadata, size_t n_metadata);

#endif
