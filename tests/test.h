// A small test harness. Each tests/test_*.c is one executable (one CTest test) made of cases:
//   TEST(name) { CHECK(cond); CHECK_CLOSE(a, b, rtol, atol); }   and in main: RUN(name); return test_summary();
// MLB_TEST_CASE=name runs one case of a file (e.g. MLB_TEST_CASE=config_set build/tests/test_pipeline).
// A case that cannot run (missing ../shared data, no GPU) calls SKIP("why"); a file whose every
// case skipped exits 77, which CTest reports as skipped.
#ifndef MATLABER_TEST_H
#define MATLABER_TEST_H
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

static int test_n_pass, test_n_fail, test_n_skip, test_case_failed, test_case_skipped;
static const char* test_case_name;

#define TEST(name) static void test_##name(void)
// MLB_TEST_CASE=name runs that case alone (the others are not run, nor counted).
#define RUN(name) do { \
    const char* only_ = getenv("MLB_TEST_CASE"); if (only_ && *only_ && strcmp(only_, #name)) break; \
    test_case_name = #name; test_case_failed = 0; test_case_skipped = 0; \
    test_##name(); \
    if (test_case_skipped) { test_n_skip++; printf("SKIP %s\n", #name); } \
    else if (test_case_failed) { test_n_fail++; printf("FAIL %s\n", #name); } \
    else { test_n_pass++; printf("ok   %s\n", #name); } \
    fflush(stdout); } while (0)

#define CHECK(cond) do { if (!(cond)) { \
    printf("  %s:%d: %s: CHECK(%s) failed\n", __FILE__, __LINE__, test_case_name, #cond); \
    test_case_failed = 1; } } while (0)
#define CHECK_MSG(cond, ...) do { if (!(cond)) { \
    printf("  %s:%d: %s: CHECK(%s) failed: ", __FILE__, __LINE__, test_case_name, #cond); \
    printf(__VA_ARGS__); printf("\n"); test_case_failed = 1; } } while (0)
// |a - b| <= atol + rtol * |b|, and neither is NaN
#define CHECK_CLOSE(a, b, rtol, atol) do { double ta_ = (double)(a), tb_ = (double)(b); \
    if (!(fabs(ta_ - tb_) <= (atol) + (rtol) * fabs(tb_))) { \
    printf("  %s:%d: %s: %s = %.10g, expected %s = %.10g (rtol %g, atol %g)\n", __FILE__, __LINE__, \
           test_case_name, #a, ta_, #b, tb_, (double)(rtol), (double)(atol)); test_case_failed = 1; } } while (0)
// Stop the case with a failure (e.g. a setup step returned an error).
#define REQUIRE(cond) do { if (!(cond)) { \
    printf("  %s:%d: %s: REQUIRE(%s) failed\n", __FILE__, __LINE__, test_case_name, #cond); \
    test_case_failed = 1; return; } } while (0)
#define SKIP(...) do { printf("  skip: "); printf(__VA_ARGS__); printf("\n"); test_case_skipped = 1; return; } while (0)

static inline int test_summary(void) {
    printf("%d passed, %d failed, %d skipped\n", test_n_pass, test_n_fail, test_n_skip);
    if (test_n_fail) return 1;
    if (test_n_pass == 0 && test_n_skip > 0) return 77;
    return 0;
}

// For finite-difference checks of a hash grid + MLP: pick[0..t) the t table entries (index < n_enc)
// of largest |g|, pick[t..2t) the t MLP parameters (n_enc <= index < n_params) of largest |g|.
static inline void test_top_grads(const double* g, size_t n_enc, size_t n_params, int t, size_t* pick) {
    int np = 0;
    for (int part = 0; part < 2; part++) {
        size_t lo = part ? n_enc : 0, hi = part ? n_params : n_enc;
        for (int q = 0; q < t; q++) {
            size_t best = lo;
            double bg = -1;
            for (size_t i = lo; i < hi; i++) {
                int taken = 0;
                for (int r = 0; r < np; r++) taken |= pick[r] == i;
                if (!taken && fabs(g[i]) > bg) { bg = fabs(g[i]); best = i; }
            }
            pick[np++] = best;
        }
    }
}

// ../shared/data (or $MLB_SHARED_DATA) when present, else NULL: tests that need it SKIP.
static inline const char* test_shared_data(void) {
    static char path[4096];
    const char* env = getenv("MLB_SHARED_DATA");
    struct stat st;
    if (env && stat(env, &st) == 0 && S_ISDIR(st.st_mode)) return env;
#ifdef MLB_SOURCE_DIR
    snprintf(path, sizeof path, "%s/../shared/data", MLB_SOURCE_DIR);
    if (stat(path, &st) == 0 && S_ISDIR(st.st_mode)) return path;
#endif
    return NULL;
}

// A fresh scratch folder for this test binary under the build tree.
static inline const char* test_tmpdir(const char* name) {
    static char path[4096];
#ifdef MLB_BINARY_DIR
    snprintf(path, sizeof path, "%s/tests/tmp_%s", MLB_BINARY_DIR, name);
#else
    snprintf(path, sizeof path, "/tmp/mlb_test_%s", name);
#endif
    char cmd[4200];
    snprintf(cmd, sizeof cmd, "rm -rf '%s' && mkdir -p '%s'", path, path);
    if (system(cmd) != 0) return NULL;
    return path;
}

#endif
