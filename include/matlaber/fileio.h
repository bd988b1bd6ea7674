// Files written so that a crash never leaves a half-written output: write to a temporary file
// in the same folder, fsync, rename over the target, fsync the folder.
#ifndef MATLABER_FILEIO_H
#define MATLABER_FILEIO_H
#include <stdio.h>
#include <stddef.h>
#include "matlaber/error.h"

typedef struct {
    FILE* f;            // write through this
    char* path;         // final path
    char* tmp_path;     // temporary path beside it
} mlb_atomic_file;

mlb_status mlb_atomic_open(mlb_atomic_file* af, const char* path);
// Flushes, fsyncs and renames; on any failure removes the temporary and leaves `path` untouched.
mlb_status mlb_atomic_commit(mlb_atomic_file* af);
void mlb_atomic_abort(mlb_atomic_file* af);     // removes the temporary file
// Whole buffer to `path`, atomically.
mlb_status mlb_write_file_atomic(const char* path, const void* data, size_t n);
// Reads a whole file (for small text files); *data is malloc'd and NUL-terminated.
mlb_status mlb_read_file(const char* path, char** data, size_t* n, size_t max_bytes);
mlb_status mlb_mkdir_p(const char* path);
// Path tests the loaders share: a regular file, a folder (both follow links), a name's suffix.
int mlb_is_file(const char* path);
int mlb_is_dir(const char* path);
int mlb_ends_with(const char* s, const char* suffix);

// Room for `need` elements of `elem` bytes in *p, *cap elements now (capacity doubles from 256, so
// appends are amortised O(1)); 0 on overflow or allocation failure, *p and *cap unchanged. The
// parsers' growing arrays (OBJ, glTF).
int mlb_reserve(void** p, size_t* cap, size_t need, size_t elem);

#endif
