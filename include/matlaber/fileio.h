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
// Whether `path` could be written atomically now (its folder exists and takes a new file; it is not
// a folder): a command checks its outputs this way before the work that ends in writing them.
// Nothing is left behind. Errors name the path and the reason.
mlb_status mlb_check_writable(const char* path);
// Whole buffer to `path`, atomically.
mlb_status mlb_write_file_atomic(const char* path, const void* data, size_t n);
// Opens a file from outside for reading: a regular file only, refused before anything can block (a
// named pipe, a device or a socket is opened without waiting, checked with fstat and closed). *fd:
// a blocking, close-on-exec descriptor; *size (may be NULL): the file's size. Errors name the path:
// MLB_ERR_NOT_FOUND (missing), MLB_ERR_IO ("not a regular file (a folder)", "(a named pipe)", ...,
// unreadable). Every reader of a path a user gives goes through it (docs/files.md).
mlb_status mlb_open_input(const char* path, int* fd, size_t* size);
// The same as a FILE* ("rb"); NULL with the error set.
FILE* mlb_open_input_file(const char* path);
// Reads a whole file through mlb_open_input; *data is malloc'd and NUL-terminated. A file over
// max_bytes is refused before reading (MLB_ERR_UNSUPPORTED: a limit, not a broken file).
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
