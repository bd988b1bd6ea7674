// Atomic file writes (temporary + fsync + rename) and small-file reading.
#include "matlaber/fileio.h"
#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

static void fsync_parent_dir(const char* path) {
    char* copy = strdup(path);
    if (!copy) return;
    int fd = open(dirname(copy), O_RDONLY | O_DIRECTORY);
    if (fd >= 0) { fsync(fd); close(fd); }
    free(copy);
}

mlb_status mlb_atomic_open(mlb_atomic_file* af, const char* path) {
    memset(af, 0, sizeof *af);
    size_t n = strlen(path);
    af->path = strdup(path);
    af->tmp_path = malloc(n + 32);
    if (!af->path || !af->tmp_path) { mlb_atomic_abort(af); return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); }
    snprintf(af->tmp_path, n + 32, "%s.tmp.%ld.XXXXXX", path, (long)getpid());
    int fd = mkstemp(af->tmp_path);
    if (fd < 0) {
        int e = errno;
        free(af->tmp_path); af->tmp_path = NULL;
        mlb_atomic_abort(af);
        return mlb_fail(MLB_ERR_IO, "%s: cannot create a temporary file beside it: %s", path, strerror(e));
    }
    // mkstemp creates the file 0600; give it the permissions a plain fopen would have
    mode_t mask = umask(0);
    umask(mask);
    fchmod(fd, 0666 & ~mask);
    af->f = fdopen(fd, "wb");
    if (!af->f) { close(fd); mlb_atomic_abort(af); return mlb_fail(MLB_ERR_IO, "%s: fdopen failed", path); }
    return MLB_OK;
}

void mlb_atomic_abort(mlb_atomic_file* af) {
    if (af->f) fclose(af->f);
    if (af->tmp_path) unlink(af->tmp_path);
    free(af->tmp_path);
    free(af->path);
    memset(af, 0, sizeof *af);
}

mlb_status mlb_atomic_commit(mlb_atomic_file* af) {
    const char* what = NULL;
    int e = 0;
    if (fflush(af->f) != 0) what = "write", e = errno;
    else if (ferror(af->f)) what = "write", e = EIO;
    else if (fsync(fileno(af->f)) != 0) what = "fsync", e = errno;
    if (what) {
        char* p = strdup(af->path ? af->path : "?");
        mlb_atomic_abort(af);
        mlb_status s = mlb_fail(MLB_ERR_IO, "%s: %s failed: %s", p ? p : "?", what, strerror(e));
        free(p);
        return s;
    }
    int rc = fclose(af->f);
    af->f = NULL;
    if (rc != 0 || rename(af->tmp_path, af->path) != 0) {
        e = errno;
        char* p = strdup(af->path);
        mlb_atomic_abort(af);
        mlb_status s = mlb_fail(MLB_ERR_IO, "%s: cannot move the finished file into place: %s", p ? p : "?", strerror(e));
        free(p);
        return s;
    }
    fsync_parent_dir(af->path);
    free(af->tmp_path); af->tmp_path = NULL;
    free(af->path); af->path = NULL;
    return MLB_OK;
}

mlb_status mlb_check_writable(const char* path) {
    if (mlb_is_dir(path)) return mlb_fail(MLB_ERR_IO, "%s: a folder, not a file that can be written", path);
    mlb_atomic_file af;
    MLB_TRY(mlb_atomic_open(&af, path));   // a temporary beside it: the folder is there and writable
    mlb_atomic_abort(&af);
    return MLB_OK;
}

mlb_status mlb_write_file_atomic(const char* path, const void* data, size_t n) {
    mlb_atomic_file af;
    MLB_TRY(mlb_atomic_open(&af, path));
    if (n && fwrite(data, 1, n, af.f) != n) {
        int e = errno;
        mlb_atomic_abort(&af);
        return mlb_fail(MLB_ERR_IO, "%s: write failed: %s", path, strerror(e));
    }
    return mlb_atomic_commit(&af);
}

mlb_status mlb_open_input(const char* path, int* fd, size_t* size) {
    *fd = -1;
    if (size) *size = 0;
    // O_NONBLOCK: opening a named pipe for reading would otherwise wait for a writer (forever)
    int f = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
    if (f < 0) {
        int e = errno;
        return mlb_fail(e == ENOENT ? MLB_ERR_NOT_FOUND : MLB_ERR_IO, "%s: %s", path, strerror(e));
    }
    struct stat st;
    if (fstat(f, &st) != 0) {
        int e = errno;
        close(f);
        return mlb_fail(MLB_ERR_IO, "%s: %s", path, strerror(e));
    }
    if (!S_ISREG(st.st_mode)) {
        close(f);
        return mlb_fail(MLB_ERR_IO, "%s: not a regular file (%s)", path,
                        S_ISDIR(st.st_mode) ? "a folder" : S_ISFIFO(st.st_mode) ? "a named pipe" : S_ISSOCK(st.st_mode) ? "a socket"
                        : S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode) ? "a device" : "not a file");
    }
    int flags = fcntl(f, F_GETFL);   // a regular file's reads never block; reads as usual from here
    if (flags < 0 || fcntl(f, F_SETFL, flags & ~O_NONBLOCK) != 0) {
        int e = errno;
        close(f);
        return mlb_fail(MLB_ERR_IO, "%s: %s", path, strerror(e));
    }
    *fd = f;
    if (size) *size = (size_t)st.st_size;
    return MLB_OK;
}

FILE* mlb_open_input_file(const char* path) {
    int fd;
    if (mlb_open_input(path, &fd, NULL)) return NULL;
    FILE* f = fdopen(fd, "rb");
    if (!f) {
        int e = errno;
        close(fd);
        mlb_fail(MLB_ERR_IO, "%s: %s", path, strerror(e));
    }
    return f;
}

mlb_status mlb_read_file(const char* path, char** data, size_t* n, size_t max_bytes) {
    *data = NULL; *n = 0;
    int fd;
    size_t size;
    MLB_TRY(mlb_open_input(path, &fd, &size));
    if (size > max_bytes) {
        close(fd);
        return mlb_fail(MLB_ERR_UNSUPPORTED, "%s: %zu bytes, more than the %zu allowed", path, size, max_bytes);
    }
    char* buf = malloc(size + 1);
    if (!buf) { close(fd); return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", path); }
    size_t got = 0;
    while (got < size) {
        ssize_t r = read(fd, buf + got, size - got);
        if (r < 0 && errno == EINTR) continue;
        if (r <= 0) break;
        got += (size_t)r;
    }
    int e = errno;
    close(fd);
    if (got != size) {
        free(buf);
        return mlb_fail(MLB_ERR_IO, "%s: read %zu of %zu bytes%s%s", path, got, size, got < size && e ? ": " : "",
                        got < size && e ? strerror(e) : "");
    }
    buf[got] = 0;
    *data = buf; *n = got;
    return MLB_OK;
}

mlb_status mlb_mkdir_p(const char* path) {
    char buf[4096];
    if (strlen(path) >= sizeof buf) return mlb_fail(MLB_ERR_ARG, "%s: path too long", path);
    strcpy(buf, path);
    for (char* p = buf + 1; ; p++) {
        if (*p == '/' || *p == 0) {
            char c = *p;
            *p = 0;
            if (mkdir(buf, 0777) != 0 && errno != EEXIST)
                return mlb_fail(MLB_ERR_IO, "%s: cannot create folder: %s", buf, strerror(errno));
            *p = c;
            if (!c) break;
        }
    }
    struct stat st;
    if (stat(path, &st) != 0 || !S_ISDIR(st.st_mode)) return mlb_fail(MLB_ERR_IO, "%s: exists and is not a folder", path);
    return MLB_OK;
}

int mlb_is_file(const char* path) { struct stat st; return stat(path, &st) == 0 && S_ISREG(st.st_mode); }
int mlb_is_dir(const char* path) { struct stat st; return stat(path, &st) == 0 && S_ISDIR(st.st_mode); }
int mlb_ends_with(const char* s, const char* suffix) {
    size_t a = strlen(s), b = strlen(suffix);
    return a >= b && memcmp(s + a - b, suffix, b) == 0;
}

int mlb_reserve(void** p, size_t* cap, size_t need, size_t elem) {
    if (need <= *cap) return 1;
    size_t c = *cap ? *cap : 256;
    while (c < need) {
        if (c > SIZE_MAX / 2 / elem) return 0;
        c *= 2;
    }
    void* q = realloc(*p, c * elem);
    if (!q) return 0;
    *p = q;
    *cap = c;
    return 1;
}
