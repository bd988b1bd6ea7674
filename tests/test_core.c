// Core: CPU feature detection against the kernel's /proc/cpuinfo and the BLAS kernel choice, Philox
// against Random123's known answers, the distributions it feeds, permutations, error messages, the progress reporter's plain mode, atomic files and small-file reading, and the runtime restart's OpenMP wait policy.
#include "test.h"
#include <omp.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>
#include "matlaber/cpu.h"
#include "matlaber/error.h"
#include "matlaber/fileio.h"
#include "matlaber/log.h"
#include "matlaber/progress.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"

TEST(philox_known_answers) {
    // Random123's kat_vectors for philox4x32_10 (Salmon et al. 2011)
    struct { uint32_t ctr[4], key[2], out[4]; } kat[3] = {
        {{0, 0, 0, 0}, {0, 0}, {0x6627e8d5, 0xe169c58d, 0xbc57ac4c, 0x9b00dbd8}},
        {{0xffffffff, 0xffffffff, 0xffffffff, 0xffffffff}, {0xffffffff, 0xffffffff}, {0x408f276d, 0x41c83b0e, 0xa20bc7c6, 0x6d5451fd}},
        {{0x243f6a88, 0x85a308d3, 0x13198a2e, 0x03707344}, {0xa4093822, 0x299f31d0}, {0xd16cfe09, 0x94fdcceb, 0x5001e420, 0x24126ea1}},
    };
    for (int i = 0; i < 3; i++) {
        mlb_u32x4 r = mlb_philox4x32_10(kat[i].ctr, kat[i].key);
        for (int j = 0; j < 4; j++) CHECK_MSG(r.v[j] == kat[i].out[j], "vector %d word %d: %08x", i, j, r.v[j]);
    }
}

TEST(uniform_and_normal_moments) {
    enum { N = 200000 };
    double su = 0, su2 = 0, sn = 0, sn2 = 0, sn4 = 0, umin = 1, umax = 0;
    for (int i = 0; i < N; i++) {
        double u = mlb_rng_uniform(42, 7, i), x = mlb_rng_normal_f64(42, 8, i);
        su += u; su2 += u * u; umin = fmin(umin, u); umax = fmax(umax, u);
        sn += x; sn2 += x * x; sn4 += x * x * x * x;
    }
    // standard errors: mean 1/sqrt(12 N) ~ 6.5e-4; normal mean 2.2e-3, variance 3.2e-3, kurtosis 0.011
    CHECK(umin >= 0 && umax < 1);
    CHECK_CLOSE(su / N, 0.5, 0, 3e-3);
    CHECK_CLOSE(su2 / N - (su / N) * (su / N), 1.0 / 12, 0, 2e-3);
    CHECK_CLOSE(sn / N, 0, 0, 1e-2);
    CHECK_CLOSE(sn2 / N, 1, 0, 1.5e-2);
    CHECK_CLOSE(sn4 / N, 3, 0, 6e-2);
}

TEST(streams_and_seeds_differ_and_repeat) {
    CHECK(mlb_rng_uniform(1, 2, 3) == mlb_rng_uniform(1, 2, 3));
    CHECK(mlb_rng_uniform(1, 2, 3) != mlb_rng_uniform(1, 2, 4));
    CHECK(mlb_rng_uniform(1, 2, 3) != mlb_rng_uniform(1, 3, 3));
    CHECK(mlb_rng_uniform(1, 2, 3) != mlb_rng_uniform(2, 2, 3));
    // fills are the same on any thread count and equal the scalar draws
    enum { N = 100000 };
    static float a[N], b[N];
    omp_set_num_threads(1);
    mlb_rng_fill_normal(a, N, 5, 6, 100, 0, 1);
    omp_set_num_threads(2);
    mlb_rng_fill_normal(b, N, 5, 6, 100, 0, 1);
    CHECK(memcmp(a, b, sizeof a) == 0);
    CHECK(a[17] == mlb_rng_normal(5, 6, 117));
}

TEST(below_and_permutation) {
    int counts[5] = {0};
    for (int i = 0; i < 50000; i++) {
        uint32_t x = mlb_rng_below(3, 1, i, 5);
        REQUIRE(x < 5);
        counts[x]++;
    }
    for (int k = 0; k < 5; k++) CHECK_CLOSE(counts[k], 10000, 0, 500);   // 5 sigma ~ 450
    enum { N = 1000 };
    uint32_t perm[N], again[N];
    int seen[N] = {0};
    mlb_rng_permutation(perm, N, 9, 1);
    mlb_rng_permutation(again, N, 9, 1);
    CHECK(memcmp(perm, again, sizeof perm) == 0);
    int fixed = 0;
    for (int i = 0; i < N; i++) { REQUIRE(perm[i] < N); seen[perm[i]]++; fixed += perm[i] == (uint32_t)i; }
    for (int i = 0; i < N; i++) CHECK(seen[i] == 1);
    CHECK(fixed < 10);   // expected 1 fixed point
}

TEST(error_messages_and_context) {
    mlb_clear_error();
    CHECK(strcmp(mlb_last_error(), "") == 0);
    CHECK(mlb_fail(MLB_ERR_FORMAT, "%s: bad header", "x.bin") == MLB_ERR_FORMAT);
    CHECK(strcmp(mlb_last_error(), "x.bin: bad header") == 0);
    CHECK(mlb_fail_context(MLB_ERR_FORMAT, "loading %s", "model") == MLB_ERR_FORMAT);
    CHECK(strcmp(mlb_last_error(), "loading model: x.bin: bad header") == 0);
    CHECK(strcmp(mlb_status_name(MLB_ERR_NOMEM), "out of memory") == 0);
    // a message longer than the buffer keeps its beginning and its end (the reason comes last)
    static char path[5001];
    memset(path, 'p', 5000);
    mlb_fail(MLB_ERR_IO, "%s: not a regular file (a named pipe)", path);
    const char* m = mlb_last_error();
    size_t n = strlen(m);
    CHECK(n < 4096 && strncmp(m, "pppp", 4) == 0 && strstr(m, "p ... p") != NULL);
    CHECK(n > 30 && strcmp(m + n - 30, "not a regular file (a named pipe)" + 3) == 0);
    mlb_fail_context(MLB_ERR_IO, "reading %s", path);
    m = mlb_last_error();
    n = strlen(m);
    CHECK(n < 4096 && strncmp(m, "reading ppp", 11) == 0 && strcmp(m + n - 14, "(a named pipe)") == 0);
    // cut between characters, never inside one
    static char wide[6001];
    for (int i = 0; i < 3000; i++) memcpy(wide + 2 * i, "\xC3\xA9", 2);
    mlb_fail(MLB_ERR_ARG, "%s!", wide);
    m = mlb_last_error();
    const char* gap = strstr(m, " ... ");
    REQUIRE(gap);
    CHECK((gap - m) % 2 == 0 && ((unsigned char)gap[5] == 0xC3) && strcmp(m + strlen(m) - 1, "!") == 0);
    mlb_clear_error();
}

static char log_seen[256];
static void capture(mlb_log_level level, const char* message, void* user) { snprintf(log_seen, sizeof log_seen, "%d:%s", level, message); }

TEST(log_levels_and_sink) {
    log_seen[0] = 0;
    mlb_log(MLB_LOG_WARN, "nobody listens");   // no sink: silent
    CHECK(log_seen[0] == 0);
    mlb_log_set_sink(capture, NULL);
    mlb_log_set_level(MLB_LOG_WARN);
    mlb_log(MLB_LOG_INFO, "dropped");
    CHECK(log_seen[0] == 0);
    mlb_log(MLB_LOG_ERROR, "kept %d", 3);
    CHECK(strcmp(log_seen, "3:kept 3") == 0);
    mlb_log_level l;
    CHECK(mlb_log_level_parse("debug", &l) == 0 && l == MLB_LOG_DEBUG);
    CHECK(mlb_log_level_parse("loud", &l) != 0);
    mlb_log_set_sink(NULL, NULL);
    mlb_log_set_level(MLB_LOG_INFO);
}

TEST(progress_plain_lines) {
    const char* dir = test_tmpdir("core_progress");
    REQUIRE(dir);
    char path[4200];
    snprintf(path, sizeof path, "%s/log.txt", dir);
    FILE* f = fopen(path, "w");
    REQUIRE(f);
    mlb_progress p;
    mlb_progress_begin(&p, f, "work", 10, "step");
    CHECK(!p.is_tty);
    p.plain_every = 0;   // every update prints
    mlb_progress_update(&p, 1, NULL);   // the first step: its set-up is not measured
    CHECK(mlb_progress_eta(&p) < 0);
    p.st[0].t_mark -= 4.0;   // as if steps 2..5 took 1 s each
    mlb_progress_update(&p, 5, "loss 1.5");
    CHECK_CLOSE(mlb_progress_rate(&p), 1.0, 1e-3, 0);
    CHECK_CLOSE(mlb_progress_eta(&p), 5.0, 1e-3, 0);
    mlb_progress_end(&p, NULL);
    fclose(f);
    char* text; size_t n;
    REQUIRE(mlb_read_file(path, &text, &n, 1 << 20) == MLB_OK);
    CHECK(strstr(text, "work: 1/10 (10%), elapsed") != NULL);   // no rate, no ETA yet
    CHECK(strstr(text, "work: 5/10 (50%) 1 step/s, ETA 5.0s") != NULL);
    CHECK(strstr(text, "loss 1.5") != NULL);
    CHECK(strstr(text, "work: 10/10 (100%), took") != NULL);
    free(text);
    char buf[32];
    CHECK(strcmp(mlb_format_duration(3725, buf, sizeof buf), "1h02m") == 0);
    CHECK(strcmp(mlb_format_duration(65, buf, sizeof buf), "1m05s") == 0);
    mlb_progress_update(NULL, 1, NULL);   // NULL progress is silent
}

// Stages (progress.h): no ETA until a stage with a cost has been measured on two steps after its
// first; then the stages ahead by their costs, each measured stage by its own seconds per step.
TEST(progress_stages_eta) {
    mlb_progress p;
    mlb_progress_begin(&p, NULL, "gen", 1, "step");
    const char* names[4] = {"start", "a", "b", "end"};
    const long steps[4] = {50, 10, 20, 1};
    const double cost[4] = {0, 1.0, 2.0, 3.0};
    mlb_progress_plan(&p, 4, names, steps, cost);
    CHECK(p.total == 81);
    mlb_progress_enter(&p, 0, 0);
    mlb_progress_update(&p, 1, NULL);
    p.st[0].t_mark -= 0.3;
    mlb_progress_update(&p, 4, NULL);
    CHECK_CLOSE(mlb_progress_rate(&p), 10.0, 1e-2, 0);   // measured, but nothing predicts "a" from it
    CHECK(mlb_progress_eta(&p) < 0);
    mlb_progress_enter(&p, 1, 0);
    CHECK(p.done == 50);
    mlb_progress_update(&p, 1, NULL);
    CHECK(mlb_progress_eta(&p) < 0);
    p.st[1].t_mark -= 4.0;   // steps 2..3: 2 s each
    mlb_progress_update(&p, 3, NULL);
    // 7 of a at 2 s measured, 20 of b at 2 x 2 s and end at 3 x 2 s predicted: more than twice as
    // much predicted as measured, no ETA; the stage's own end is known
    CHECK(mlb_progress_eta(&p) < 0);
    CHECK_CLOSE(mlb_progress_stage_eta(&p), 7 * 2.0, 1e-3, 0);
    mlb_progress_stage_steps(&p, 50);   // 47 steps of a measured (94 s), 86 s predicted: shown
    mlb_progress_update(&p, 3, NULL);
    CHECK(p.total == 121);
    CHECK_CLOSE(mlb_progress_eta(&p), 47 * 2.0 + 20 * 4.0 + 6.0, 1e-3, 0);
    mlb_progress_stage_steps(&p, 10);   // 14 s measured, 86 s predicted: shown from then on all the same
    CHECK_CLOSE(mlb_progress_eta(&p), 7 * 2.0 + 20 * 4.0 + 6.0, 1e-3, 0);
    mlb_progress_stage_steps(&p, 100);
    CHECK(p.total == 171);
    CHECK_CLOSE(mlb_progress_eta(&p), 97 * 2.0 + 20 * 4.0 + 6.0, 1e-3, 0);
    mlb_progress_enter(&p, 2, 5);   // b resumed at its step 5
    CHECK(p.done == 155);
    mlb_progress_update(&p, 6, NULL);
    p.st[2].t_mark -= 2.0;   // b measured at 1 s per step: half its estimate, and so is end's
    mlb_progress_update(&p, 8, NULL);
    CHECK_CLOSE(mlb_progress_eta(&p), 12 * 1.0 + 1.5, 1e-3, 0);
    mlb_progress_stage_steps(&p, 30);
    CHECK(p.total == 181);
    CHECK_CLOSE(mlb_progress_eta(&p), 22 * 1.0 + 1.5, 1e-3, 0);
}

// A stage that may grow by dearer steps (the material start's close call) gives no first ETA while
// it runs, however well measured; the next stage, measured, does; an ETA shown before stays.
TEST(progress_growing_stage) {
    mlb_progress p;
    mlb_progress_begin(&p, NULL, "paint", 1, "step");
    const char* names[2] = {"material start", "appearance"};
    const long steps[2] = {8, 10};
    const double cost[2] = {1.0, 1.0};
    mlb_progress_plan(&p, 2, names, steps, cost);
    mlb_progress_stage_may_grow(&p, 0);
    mlb_progress_enter(&p, 0, 0);
    mlb_progress_update(&p, 1, NULL);
    p.st[0].t_mark -= 2.0;   // steps 2..3: 1 s each; everything ahead measured or predicted
    mlb_progress_update(&p, 3, NULL);
    CHECK(mlb_progress_eta(&p) < 0);
    CHECK_CLOSE(mlb_progress_stage_eta(&p), 5.0, 1e-3, 0);   // the stage's own end is still told
    mlb_progress_enter(&p, 1, 0);
    mlb_progress_update(&p, 1, NULL);
    p.st[1].t_mark -= 4.0;   // 2 s a step
    mlb_progress_update(&p, 3, NULL);
    CHECK_CLOSE(mlb_progress_eta(&p), 7 * 2.0, 1e-3, 0);
    // shown before a growing stage: it stays
    mlb_progress q;
    mlb_progress_begin(&q, NULL, "gen", 1, "step");
    const char* qn[2] = {"geometry", "material start"};
    mlb_progress_plan(&q, 2, qn, (const long[2]){10, 8}, (const double[2]){1.0, 1.0});
    mlb_progress_stage_may_grow(&q, 1);
    mlb_progress_enter(&q, 0, 0);
    mlb_progress_update(&q, 1, NULL);
    q.st[0].t_mark -= 2.0;
    mlb_progress_update(&q, 3, NULL);
    CHECK_CLOSE(mlb_progress_eta(&q), 7 * 1.0 + 8 * 1.0, 1e-3, 0);
    mlb_progress_enter(&q, 1, 0);
    CHECK(mlb_progress_eta(&q) >= 0);
}

TEST(atomic_files) {
    const char* dir = test_tmpdir("core_atomic");
    REQUIRE(dir);
    char path[4200], cmd[4300];
    snprintf(path, sizeof path, "%s/out.bin", dir);
    REQUIRE(mlb_write_file_atomic(path, "first", 5) == MLB_OK);
    // an aborted write leaves the old file and no temporary behind
    mlb_atomic_file af;
    REQUIRE(mlb_atomic_open(&af, path) == MLB_OK);
    fputs("half-writ", af.f);
    mlb_atomic_abort(&af);
    char* text; size_t n;
    REQUIRE(mlb_read_file(path, &text, &n, 100) == MLB_OK);
    CHECK(n == 5 && memcmp(text, "first", 5) == 0);
    free(text);
    snprintf(cmd, sizeof cmd, "test $(ls '%s' | wc -l) -eq 1", dir);
    CHECK(system(cmd) == 0);
    // a folder that does not exist: an error naming the path, nothing written
    char bad[4200];
    snprintf(bad, sizeof bad, "%s/missing/out.bin", dir);
    CHECK(mlb_write_file_atomic(bad, "x", 1) == MLB_ERR_IO);
    CHECK(strstr(mlb_last_error(), "missing/out.bin") != NULL);
    // reading: size limit and missing files
    CHECK(mlb_read_file(path, &text, &n, 4) == MLB_ERR_UNSUPPORTED);
    CHECK(mlb_read_file(bad, &text, &n, 4) == MLB_ERR_NOT_FOUND);
    snprintf(bad, sizeof bad, "%s/a/b/c", dir);
    CHECK(mlb_mkdir_p(bad) == MLB_OK);
    CHECK(mlb_mkdir_p(path) == MLB_ERR_IO);   // exists and is a file
}

// Outside files: only regular files are opened, and a named pipe with no writer is refused at once
// (opening it for reading would wait for a writer forever); an alarm ends the test if it blocks.
TEST(input_files_regular_only) {
    const char* dir = test_tmpdir("core_input");
    REQUIRE(dir);
    char fifo[4200], file[4200];
    snprintf(fifo, sizeof fifo, "%s/pipe.obj", dir);
    snprintf(file, sizeof file, "%s/data.txt", dir);
    unlink(fifo);
    REQUIRE(mkfifo(fifo, 0600) == 0);
    REQUIRE(mlb_write_file_atomic(file, "abc", 3) == MLB_OK);
    alarm(20);
    char* text; size_t n;
    int fd = -1;
    size_t size = 0;
    CHECK(mlb_read_file(fifo, &text, &n, 100) == MLB_ERR_IO);
    CHECK(strstr(mlb_last_error(), "pipe.obj: not a regular file (a named pipe)") != NULL && text == NULL);
    CHECK(mlb_open_input(fifo, &fd, &size) == MLB_ERR_IO && fd == -1);
    CHECK(mlb_open_input_file(fifo) == NULL);
    CHECK(mlb_open_input(dir, &fd, &size) == MLB_ERR_IO && strstr(mlb_last_error(), "(a folder)"));
    CHECK(mlb_open_input("/dev/null", &fd, &size) == MLB_ERR_IO && strstr(mlb_last_error(), "(a device)"));
    alarm(0);
    REQUIRE(mlb_open_input(file, &fd, &size) == MLB_OK);
    char buf[8];
    CHECK(size == 3 && read(fd, buf, sizeof buf) == 3 && memcmp(buf, "abc", 3) == 0);
    close(fd);
    unlink(fifo);
}

// The features read from cpuid + XCR0 agree with the kernel's flags in /proc/cpuinfo (which also
// hides what the OS does not save); skipped where there is no such file or no x86 CPU.
TEST(cpu_features_match_proc_cpuinfo) {
    mlb_cpu_info c;
    mlb_cpu_detect(&c);
    FILE* f = fopen("/proc/cpuinfo", "r");
    if (!f) SKIP("no /proc/cpuinfo");
    static char line[16384];
    char flags[16384] = "", model[128] = "";
    while (fgets(line, sizeof line, f) && !(flags[0] && model[0])) {
        const char* v = strchr(line, ':');
        if (!v) continue;
        if (strncmp(line, "flags", 5) == 0) snprintf(flags, sizeof flags, " %s", v + 1);
        if (strncmp(line, "model name", 10) == 0 && !model[0]) {
            snprintf(model, sizeof model, "%s", v + 1 + (v[1] == ' '));
            model[strcspn(model, "\n")] = 0;
        }
    }
    fclose(f);
    if (!flags[0]) SKIP("/proc/cpuinfo has no flags line (not x86)");
    // the brand string, as the kernel trims it (a CPU without one: the kernel names it from a table)
    if (strcmp(c.model, "unknown") != 0)
        CHECK_MSG(!strcmp(c.model, model), "model \"%s\", /proc/cpuinfo says \"%s\"", c.model, model);
    char* nl = strchr(flags, '\n');
    if (nl) *nl = ' ';
    const struct { int ours; const char* flag; } pairs[] = {
        {c.avx2, "avx2"}, {c.fma, "fma"}, {c.avx512f, "avx512f"}, {c.avx512bw, "avx512bw"}, {c.avx512vl, "avx512vl"},
        {c.avx512dq, "avx512dq"}, {c.avx512cd, "avx512cd"}, {c.avx512_bf16, "avx512_bf16"},
        {c.avx512_fp16, "avx512_fp16"}, {c.amx_tile, "amx_tile"}, {c.amx_bf16, "amx_bf16"}};
    for (size_t i = 0; i < sizeof pairs / sizeof pairs[0]; i++) {
        char want[40];
        snprintf(want, sizeof want, " %s ", pairs[i].flag);
        int listed = strstr(flags, want) != NULL;
        CHECK_MSG(pairs[i].ours == listed, "%s: cpuid says %d, /proc/cpuinfo says %d", pairs[i].flag, pairs[i].ours, listed);
    }
    char buf[256];
    mlb_cpu_feature_string(&c, buf, sizeof buf);
    printf("  %s (family %d model %d): %s\n", c.model, c.family, c.model_id, buf);
}

// The OpenBLAS kernel family follows the features: AMD Zen 5 (AVX-512 with BF16), on which
// OpenBLAS 0.3.21 picks Haswell or Zen kernels, gets Cooperlake's; nothing is ever downgraded.
TEST(blas_coretype_follows_features) {
    mlb_cpu_info avx2 = {.avx2 = 1, .fma = 1};
    mlb_cpu_info avx512 = avx2;
    avx512.avx512f = avx512.avx512bw = avx512.avx512vl = avx512.avx512dq = avx512.avx512cd = 1;
    mlb_cpu_info bf16 = avx512;
    bf16.avx512_bf16 = 1;
    mlb_cpu_info none = {0};
    const struct { const char* current; const mlb_cpu_info* cpu; const char* want; } cases[] = {
        {"Haswell", &bf16, "Cooperlake"}, {"Zen", &bf16, "Cooperlake"}, {"Prescott", &bf16, "Cooperlake"},
        {"SkylakeX", &bf16, "Cooperlake"}, {"Cooperlake", &bf16, NULL}, {"SapphireRapids", &bf16, NULL},
        {"Zen", &avx512, "SkylakeX"}, {"Sandybridge", &avx512, "SkylakeX"}, {"SkylakeX", &avx512, NULL},
        {"Prescott", &avx2, "Haswell"}, {"Nehalem", &avx2, "Haswell"}, {"Zen", &avx2, NULL},
        {"Haswell", &avx2, NULL}, {"Prescott", &none, NULL}, {"SomethingNew", &bf16, NULL}, {NULL, &bf16, NULL}};
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        const char* got = mlb_blas_coretype_for(cases[i].current, cases[i].cpu);
        int ok = (got == NULL && cases[i].want == NULL) || (got && cases[i].want && strcmp(got, cases[i].want) == 0);
        CHECK_MSG(ok, "case %zu: current %s: got %s, want %s", i, cases[i].current ? cases[i].current : "(null)",
                  got ? got : "NULL", cases[i].want ? cases[i].want : "NULL");
    }
}

// The restarted test reports its OpenMP wait policy: exit 0 when OMP_WAIT_POLICY is `want` ("-" for
// unset), else 1.
static int report_wait_policy(const char* want) {
    const char* got = getenv("OMP_WAIT_POLICY");
    if (!strcmp(want, "-") ? got == NULL : got && !strcmp(got, want)) return 0;
    fprintf(stderr, "OMP_WAIT_POLICY %s, want %s\n", got ? got : "unset", want);
    return 1;
}

// mlb_runtime_restart in a child with the launcher's variable `local` (NULL: none) and the user's
// OMP_WAIT_POLICY `user` (NULL: none): the child's exit status, with the policy the (re)started
// child must see.
static int restarted_policy_status(const char* local, const char* user, const char* want) {
    fflush(stdout);
    pid_t pid = fork();
    if (pid == 0) {
        unsetenv("MATLABER_REEXEC");
        unsetenv("GOMP_SPINCOUNT");
        unsetenv("MPI_LOCALNRANKS");
        unsetenv("SLURM_NTASKS_PER_NODE");
        if (user) setenv("OMP_WAIT_POLICY", user, 1);
        else unsetenv("OMP_WAIT_POLICY");
        if (local) setenv("OMPI_COMM_WORLD_LOCAL_SIZE", local, 1);
        else unsetenv("OMPI_COMM_WORLD_LOCAL_SIZE");
        char* argv[] = {"test_core", "--report-wait-policy", (char*)want, NULL};
        mlb_runtime_restart(argv);   // returns where nothing needed a restart
        _exit(report_wait_policy(want));
    }
    int st = -1;
    if (pid < 0 || waitpid(pid, &st, 0) != pid) return -1;
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

// Idle OpenMP threads sleep at once only where several processes of a job share the node; a process
// alone keeps libgomp's default; the user's setting always stands.
TEST(runtime_restart_wait_policy) {
    CHECK_MSG(restarted_policy_status(NULL, NULL, "-") == 0, "alone: no policy forced");
    CHECK_MSG(restarted_policy_status("1", NULL, "-") == 0, "one local process: no policy forced");
    CHECK_MSG(restarted_policy_status("2", NULL, "passive") == 0, "two local processes: passive");
    CHECK_MSG(restarted_policy_status("2", "active", "active") == 0, "the user's active kept");
    CHECK_MSG(restarted_policy_status("x", NULL, "-") == 0, "a malformed count is ignored");
}

// mlb_runtime_tune_malloc in a child with the user's MALLOC_MMAP_THRESHOLD_ `user` (NULL: none): 0
// when a 48 MB block then comes from the heap (glibc marks a block of its own mapping with bit 1 of
// the size word before it) as `want_heap` says, else 1.
static int malloc_status(const char* user, int want_heap) {
    fflush(stdout);
    pid_t pid = fork();
    if (pid == 0) {
        unsetenv("MALLOC_TRIM_THRESHOLD_");
        unsetenv("GLIBC_TUNABLES");
        if (user) setenv("MALLOC_MMAP_THRESHOLD_", user, 1);
        else unsetenv("MALLOC_MMAP_THRESHOLD_");
        mlb_runtime_tune_malloc();
        char* p = malloc((size_t)48 << 20);
        if (!p) _exit(2);
        size_t size_word;   // glibc's chunk header, just before the block
        memcpy(&size_word, (const char*)((uintptr_t)p - sizeof size_word), sizeof size_word);
        int heap = !(size_word & 2);
        free(p);
        _exit(heap == want_heap ? 0 : 1);
    }
    int st = -1;
    if (pid < 0 || waitpid(pid, &st, 0) != pid) return -1;
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

// Large blocks from the heap, unless the user set glibc's own variables (glibc reads them when the
// process starts, so the child that sets one sees what glibc does by default: a 48 MB block is
// above its largest dynamic threshold, 32 MB, and gets a mapping of its own).
TEST(runtime_tune_malloc) {
#if defined(__SANITIZE_ADDRESS__)
    SKIP("AddressSanitizer's allocator is not glibc's");
#else
    CHECK_MSG(malloc_status(NULL, 1) == 0, "a 48 MB block not from the heap after mlb_runtime_tune_malloc");
    CHECK_MSG(malloc_status("1000000000", 0) == 0, "the user's MALLOC_MMAP_THRESHOLD_ not left to glibc");
#endif
}

int main(int argc, char** argv) {
    if (argc == 3 && !strcmp(argv[1], "--report-wait-policy")) return report_wait_policy(argv[2]);
    RUN(cpu_features_match_proc_cpuinfo);
    RUN(blas_coretype_follows_features);
    RUN(philox_known_answers);
    RUN(uniform_and_normal_moments);
    RUN(streams_and_seeds_differ_and_repeat);
    RUN(below_and_permutation);
    RUN(error_messages_and_context);
    RUN(log_levels_and_sink);
    RUN(progress_plain_lines);
    RUN(progress_stages_eta);
    RUN(progress_growing_stage);
    RUN(atomic_files);
    RUN(input_files_regular_only);
    RUN(runtime_restart_wait_policy);
    RUN(runtime_tune_malloc);
    return test_summary();
}
