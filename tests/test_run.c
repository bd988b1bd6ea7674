// Run folders, JSON config files, checkpoints and the loss log (include/matlaber/run.h).
#include "test.h"
#include "matlaber/error.h"
#include "matlaber/fileio.h"
#include "matlaber/image.h"
#include "matlaber/run.h"
#include "matlaber/safetensors.h"
#include <float.h>
#include <stdint.h>

static char tmp[4096];

static void path_of(char* out, const char* rel) { snprintf(out, 4096, "%s/%s", tmp, rel); }
static int write_text(const char* path, const char* text) { return mlb_write_file_atomic(path, text, strlen(text)) == MLB_OK; }
static int has(const char* s) { return strstr(mlb_last_error(), s) != NULL; }

TEST(run_create_and_refusals) {
    char dir[4096], p[4096];
    path_of(dir, "a/b/run1");
    REQUIRE(mlb_run_create(dir, 0) == MLB_OK);                  // mkdir -p
    snprintf(p, sizeof p, "%s/checkpoints", dir);
    CHECK(mlb_is_dir(p));
    snprintf(p, sizeof p, "%s/previews", dir);
    CHECK(mlb_is_dir(p));
    CHECK(!mlb_run_exists(dir));
    CHECK(mlb_run_check_resume(dir) == MLB_ERR_NOT_FOUND && has(dir) && has("config.json"));
    // holds only the empty subfolders: not empty, not a run
    CHECK(mlb_run_create(dir, 0) == MLB_ERR_ARG && has(dir) && has("not empty"));
    snprintf(p, sizeof p, "%s/config.json", dir);
    REQUIRE(write_text(p, "{}\n"));
    CHECK(mlb_run_exists(dir));
    CHECK(mlb_run_check_resume(dir) == MLB_OK);
    CHECK(mlb_run_create(dir, 0) == MLB_ERR_ARG && has(dir) && has("--resume") && has("already holds a run"));
    // overwrite removes the run files only
    char ck[4096], other[4096], prev[4096], log[4096];
    snprintf(ck, sizeof ck, "%s/checkpoints/geometry.safetensors", dir);
    snprintf(other, sizeof other, "%s/notes.txt", dir);
    snprintf(prev, sizeof prev, "%s/previews/p_000001.png", dir);
    snprintf(log, sizeof log, "%s/loss.csv", dir);
    REQUIRE(write_text(ck, "x") && write_text(other, "keep") && write_text(prev, "x") && write_text(log, "stage,step,a\n"));
    char fin[4096], sub[4096];
    snprintf(fin, sizeof fin, "%s/final/mesh.obj", dir);
    snprintf(sub, sizeof sub, "%s/final/textures", dir);
    REQUIRE(mlb_mkdir_p(sub) == MLB_OK && write_text(fin, "v 0 0 0\n"));
    CHECK(mlb_run_create(dir, 1) == MLB_OK);
    CHECK(!mlb_is_file(p) && !mlb_is_file(ck) && !mlb_is_file(prev) && !mlb_is_file(log) && !mlb_is_file(fin));
    CHECK(mlb_is_dir(sub));
    CHECK(mlb_is_file(other));
    CHECK(!mlb_run_exists(dir));
    // an empty existing folder is fine; a file is not a folder
    path_of(dir, "empty");
    REQUIRE(mlb_mkdir_p(dir) == MLB_OK);
    CHECK(mlb_run_create(dir, 0) == MLB_OK);
    path_of(p, "plainfile");
    REQUIRE(write_text(p, "x"));
    CHECK(mlb_run_create(p, 0) == MLB_ERR_IO && has(p));
    path_of(p, "nonempty");
    REQUIRE(mlb_mkdir_p(p) == MLB_OK);
    snprintf(other, sizeof other, "%s/file", p);
    REQUIRE(write_text(other, "x"));
    CHECK(mlb_run_create(p, 0) == MLB_ERR_ARG && has(p) && has("not a run"));
    CHECK(mlb_run_create(p, 1) == MLB_OK && mlb_is_file(other));
}

TEST(run_path) {
    char out[32];
    CHECK(mlb_run_path(out, sizeof out, "runs/x", "loss.csv") == MLB_OK && strcmp(out, "runs/x/loss.csv") == 0);
    CHECK(mlb_run_path(out, sizeof out, "runs/x/", "/loss.csv") == MLB_OK && strcmp(out, "runs/x/loss.csv") == 0);
    CHECK(mlb_run_path(out, sizeof out, "/", "a") == MLB_OK && strcmp(out, "/a") == 0);
    CHECK(mlb_run_path(out, 16, "runs/x", "loss.csv") == MLB_OK);   // 15 chars + NUL = 16 fits
    CHECK(mlb_run_path(out, 15, "runs/x", "loss.csv") == MLB_ERR_ARG && has("runs/x/loss.csv"));
}

TEST(json_round_trip_and_errors) {
    char p[4096];
    path_of(p, "config.json");
    cJSON* j = cJSON_CreateObject();
    cJSON_AddStringToObject(j, "prompt", "a \"wooden\" goblet\n");
    cJSON_AddNumberToObject(j, "lr", 0.001);
    cJSON_AddNumberToObject(j, "seed", 42);
    cJSON_AddBoolToObject(j, "sds", 1);
    cJSON* arr = cJSON_AddArrayToObject(j, "res");
    cJSON_AddItemToArray(arr, cJSON_CreateNumber(512));
    REQUIRE(mlb_run_write_json(p, j) == MLB_OK);
    char* text = NULL;
    size_t n = 0;
    REQUIRE(mlb_read_file(p, &text, &n, 1 << 20) == MLB_OK);
    CHECK(n > 0 && text[n - 1] == '\n');
    free(text);
    cJSON* back = NULL;
    REQUIRE(mlb_run_read_json(p, &back) == MLB_OK);
    CHECK(cJSON_Compare(j, back, 1));
    double lr;
    long seed;
    int sds;
    const char* prompt;
    CHECK(mlb_json_get_number(back, "lr", 0, 1, &lr, p) == MLB_OK && lr == 0.001);
    CHECK(mlb_json_get_int(back, "seed", 0, 100, &seed, p) == MLB_OK && seed == 42);
    CHECK(mlb_json_get_bool(back, "sds", &sds, p) == MLB_OK && sds == 1);
    CHECK(mlb_json_get_string(back, "prompt", &prompt, p) == MLB_OK && strcmp(prompt, "a \"wooden\" goblet\n") == 0);
    CHECK(mlb_json_get_int(back, "lr", 0, 1, &seed, p) == MLB_ERR_FORMAT && has("'lr'") && has(p));
    CHECK(mlb_json_get_int(back, "seed", 0, 10, &seed, p) == MLB_ERR_FORMAT && has("'seed'"));
    CHECK(mlb_json_get_number(back, "nope", 0, 1, &lr, p) == MLB_ERR_NOT_FOUND && has("'nope'") && has(p));
    CHECK(mlb_json_get_string(back, "lr", &prompt, p) == MLB_ERR_FORMAT);
    CHECK(mlb_json_get_bool(back, "lr", &sds, p) == MLB_ERR_FORMAT);
    cJSON_Delete(back);
    cJSON_Delete(j);
    // malformed: the error names the file and the byte offset (0-based) with line and column
    REQUIRE(write_text(p, "{\n  \"a\": 1,,\n}\n"));
    back = (cJSON*)1;
    CHECK(mlb_run_read_json(p, &back) == MLB_ERR_FORMAT && back == NULL);
    CHECK_MSG(has(p) && has("byte 12") && has("line 2, column 11"), "%s", mlb_last_error());
    REQUIRE(write_text(p, "{\"a\": [1, 2"));   // truncated
    CHECK(mlb_run_read_json(p, &back) == MLB_ERR_FORMAT && has(p) && has("truncated"));
    REQUIRE(write_text(p, "{} x"));            // trailing garbage
    CHECK(mlb_run_read_json(p, &back) == MLB_ERR_FORMAT && has("byte 3"));
    REQUIRE(write_text(p, ""));
    CHECK(mlb_run_read_json(p, &back) == MLB_ERR_FORMAT && has("byte 0"));
    REQUIRE(mlb_write_file_atomic(p, "{\"a\":\0 1}", 9) == MLB_OK);   // embedded NUL
    CHECK(mlb_run_read_json(p, &back) == MLB_ERR_FORMAT && has("byte 5"));
    path_of(p, "missing.json");
    CHECK(mlb_run_read_json(p, &back) == MLB_ERR_NOT_FOUND && has(p));
}

static uint32_t bits_of(float f) { uint32_t u; memcpy(&u, &f, 4); return u; }
static float float_of(uint32_t u) { float f; memcpy(&f, &u, 4); return f; }

TEST(checkpoint_round_trip_bitwise) {
    char p[4096];
    path_of(p, "ckpt.safetensors");
    float s0 = 3.5f, a[7], b[6], c[2 * 1 * 3 * 2], e[1];
    for (int i = 0; i < 7; i++) a[i] = float_of(0x3f800000u + 12345u * (uint32_t)i);
    a[1] = float_of(0x7f7fffffu);   // the largest float (NaN and infinities are refused: checkpoint_nan)
    a[2] = -0.0f;
    a[3] = float_of(1u);            // smallest denormal
    a[4] = -FLT_MAX;
    for (int i = 0; i < 6; i++) b[i] = (float)i * 0.1f - 0.25f;
    for (int i = 0; i < 12; i++) c[i] = 1.0f / (float)(i + 1);
    mlb_ckpt_tensor t[5] = {
        {"step_scale", &s0, 0, {0}}, {"geometry.params", a, 1, {7}}, {"adam.m", b, 2, {2, 3}},
        {"adam.v", c, 4, {2, 1, 3, 2}}, {"empty", e, 2, {0, 5}}};
    mlb_ckpt_meta m = {0};
    REQUIRE(mlb_ckpt_meta_set_i64(&m, "step", 1234567890123LL) == MLB_OK);
    REQUIRE(mlb_ckpt_meta_set_i64(&m, "min", INT64_MIN) == MLB_OK);
    REQUIRE(mlb_ckpt_meta_set_f64(&m, "lr", 0.1) == MLB_OK);
    REQUIRE(mlb_ckpt_meta_set_f64(&m, "tiny", 4.9406564584124654e-324) == MLB_OK);
    REQUIRE(mlb_ckpt_meta_set(&m, "stage", "geometry") == MLB_OK);
    REQUIRE(mlb_ckpt_meta_set(&m, "stage", "appearance") == MLB_OK);   // replaces
    CHECK(m.n == 5);
    REQUIRE(mlb_checkpoint_save(p, t, 5, &m) == MLB_OK);
    mlb_ckpt_meta_free(&m);
    CHECK(m.n == 0 && m.kv == NULL);

    float s0b = 0, a2[7] = {0}, b2[6] = {0}, c2[12] = {0};
    mlb_ckpt_tensor u[5] = {
        {"adam.v", c2, 4, {2, 1, 3, 2}}, {"step_scale", &s0b, 0, {0}}, {"geometry.params", a2, 1, {7}},
        {"adam.m", b2, 2, {2, 3}}, {"empty", NULL, 2, {0, 5}}};   // any order
    mlb_ckpt_meta got = {0};
    REQUIRE(mlb_checkpoint_load(p, u, 5, &got) == MLB_OK);
    CHECK(bits_of(s0b) == bits_of(s0));
    CHECK(memcmp(a, a2, sizeof a) == 0);
    CHECK(memcmp(b, b2, sizeof b) == 0);
    CHECK(memcmp(c, c2, sizeof c) == 0);
    int64_t step = 0, mn = 0;
    double lr = 0, tiny = 0;
    CHECK(mlb_ckpt_meta_get_i64(&got, "step", &step) == MLB_OK && step == 1234567890123LL);
    CHECK(mlb_ckpt_meta_get_i64(&got, "min", &mn) == MLB_OK && mn == INT64_MIN);
    CHECK(mlb_ckpt_meta_get_f64(&got, "lr", &lr) == MLB_OK && lr == 0.1);
    CHECK(mlb_ckpt_meta_get_f64(&got, "tiny", &tiny) == MLB_OK && tiny == 4.9406564584124654e-324);
    CHECK(mlb_ckpt_meta_get(&got, "stage") && strcmp(mlb_ckpt_meta_get(&got, "stage"), "appearance") == 0);
    CHECK(mlb_ckpt_meta_get_i64(&got, "nope", &step) == MLB_ERR_NOT_FOUND && has(p) && has("'nope'"));
    CHECK(mlb_ckpt_meta_get_i64(&got, "stage", &step) == MLB_ERR_FORMAT && has("'stage'"));
    CHECK(mlb_ckpt_meta_get_i64(&got, "lr", &step) == MLB_ERR_FORMAT);
    mlb_ckpt_meta_free(&got);
}

TEST(checkpoint_load_errors) {
    char p[4096];
    path_of(p, "ckpt2.safetensors");
    float a[6] = {1, 2, 3, 4, 5, 6}, b[2] = {7, 8};
    mlb_ckpt_tensor t[2] = {{"w", a, 2, {2, 3}}, {"b", b, 1, {2}}};
    REQUIRE(mlb_checkpoint_save(p, t, 2, NULL) == MLB_OK);
    float x[6], y[2];
    for (int i = 0; i < 6; i++) x[i] = -1;
    y[0] = y[1] = -1;
    // wrong shape: refused as a whole, nothing copied
    mlb_ckpt_tensor u[2] = {{"b", y, 1, {2}}, {"w", x, 2, {3, 2}}};
    CHECK(mlb_checkpoint_load(p, u, 2, NULL) == MLB_ERR_FORMAT);
    CHECK_MSG(has(p) && has("'w'") && has("[2, 3]") && has("expected [3, 2]"), "%s", mlb_last_error());
    CHECK(x[0] == -1 && y[0] == -1 && y[1] == -1);
    // missing
    mlb_ckpt_tensor v[3] = {{"w", x, 2, {2, 3}}, {"b", y, 1, {2}}, {"c", y, 1, {2}}};
    CHECK(mlb_checkpoint_load(p, v, 3, NULL) == MLB_ERR_NOT_FOUND && has(p) && has("'c'"));
    // extra tensor in the file
    CHECK(mlb_checkpoint_load(p, v, 1, NULL) == MLB_ERR_FORMAT && has("unexpected tensor 'b'"));
    CHECK(x[0] == -1);
    // rank mismatch
    mlb_ckpt_tensor r[2] = {{"w", x, 1, {6}}, {"b", y, 1, {2}}};
    CHECK(mlb_checkpoint_load(p, r, 2, NULL) == MLB_ERR_FORMAT && has("expected [6]"));
    // a file that is not F32
    char q[4096];
    path_of(q, "f16.safetensors");
    uint16_t h[2] = {0x3c00, 0x4000};
    int64_t sh[1] = {2};
    mlb_st_entry e = {"b", MLB_DT_F16, 1, sh, h};
    REQUIRE(mlb_st_write(q, &e, 1, NULL, 0) == MLB_OK);
    CHECK(mlb_checkpoint_load(q, &v[1], 1, NULL) == MLB_ERR_FORMAT && has("F16") && has(q));
    // bad specs
    mlb_ckpt_tensor dup[2] = {{"w", a, 1, {6}}, {"w", a, 1, {6}}};
    CHECK(mlb_checkpoint_save(p, dup, 2, NULL) == MLB_ERR_ARG && has("twice"));
    mlb_ckpt_tensor rank[1] = {{"w", a, 5, {1, 1, 1, 1}}};
    CHECK(mlb_checkpoint_save(p, rank, 1, NULL) == MLB_ERR_ARG);
    // the good file is still there and loads
    CHECK(mlb_checkpoint_load(p, v, 2, NULL) == MLB_OK && x[5] == 6 && y[1] == 8);
    path_of(q, "none.safetensors");
    CHECK(mlb_checkpoint_load(q, v, 2, NULL) != MLB_OK && has(q));
}

// Never a NaN or an infinity in a checkpoint: saving one is refused naming the tensor and the
// element, and a file holding one (damaged, or written by something else) is refused on load with
// nothing copied: a resumed run would carry it into every file after it.
TEST(checkpoint_nan) {
    char p[4096];
    path_of(p, "nan.safetensors");
    float a[4] = {1, 2, NAN, 4}, b[3] = {0, INFINITY, 0};
    mlb_ckpt_tensor t[2] = {{"params", a, 1, {4}}, {"adam_v", b, 1, {3}}};
    CHECK(mlb_checkpoint_save(p, t, 2, NULL) == MLB_ERR_NUMERIC);
    CHECK_MSG(has(p) && has("not written: tensor 'params' holds a NaN or an infinity (element 2 of 4)"), "%s", mlb_last_error());
    struct stat sb;
    CHECK(stat(p, &sb) != 0);   // nothing on disk
    a[2] = 3;
    CHECK(mlb_checkpoint_save(p, t, 2, NULL) == MLB_ERR_NUMERIC && has("'adam_v'") && has("element 1 of 3"));
    b[1] = 5;
    REQUIRE(mlb_checkpoint_save(p, t, 2, NULL) == MLB_OK);
    // the same file with a NaN written by another writer
    int64_t s4[1] = {4}, s3[1] = {3};
    float bad[4] = {1, 2, 3, NAN};
    mlb_st_entry e[2] = {{"params", MLB_DT_F32, 1, s4, bad}, {"adam_v", MLB_DT_F32, 1, s3, b}};
    REQUIRE(mlb_st_write(p, e, 2, NULL, 0) == MLB_OK);
    float x[4] = {-1, -1, -1, -1}, y[3] = {-1, -1, -1};
    mlb_ckpt_tensor u[2] = {{"params", x, 1, {4}}, {"adam_v", y, 1, {3}}};
    CHECK(mlb_checkpoint_load(p, u, 2, NULL) == MLB_ERR_NUMERIC);
    CHECK_MSG(has(p) && has("tensor 'params' holds a NaN or an infinity (element 3 of 4)"), "%s", mlb_last_error());
    CHECK(x[0] == -1 && y[0] == -1);   // nothing copied
}

static const char* COLS[3] = {"loss", "sds", "lr"};
static void row_values(int stage, long step, double* v) {
    v[0] = 1.0 / (1.0 + step + 100.0 * stage);
    v[1] = step == 3 ? NAN : (stage ? -0.5 * step : 1e-7 * step);
    v[2] = step == 5 && stage == 1 ? INFINITY : 0.01;
}
static int log_steps(mlb_losslog* l, int stage, long from, long to) {
    double v[3];
    for (long s = from; s < to; s++) {
        row_values(stage, s, v);
        if (mlb_losslog_append(l, stage, s, v) != MLB_OK) return 0;
    }
    return 1;
}
static char* slurp(const char* p, size_t* n) {
    char* t = NULL;
    *n = 0;
    if (mlb_read_file(p, &t, n, 1 << 24) != MLB_OK) return NULL;
    return t;
}

TEST(losslog_resume_is_byte_identical) {
    char pa[4096], pb[4096];
    path_of(pa, "full.csv");
    path_of(pb, "resumed.csv");
    mlb_losslog* l = NULL;
    REQUIRE(mlb_losslog_open(&l, pa, COLS, 3, -1, 0) == MLB_OK);
    REQUIRE(log_steps(l, 0, 0, 12) && log_steps(l, 1, 0, 10));
    mlb_losslog_close(l);
    size_t na, nb;
    char* A = slurp(pa, &na);
    REQUIRE(A);
    CHECK(strncmp(A, "stage,step,loss,sds,lr\n0,0,1,0,0.01\n", 36) == 0);
    CHECK(strstr(A, "\n1,3,0.00961538462,nan,0.01\n") != NULL);
    CHECK(strstr(A, "\n1,5,0.00943396226,-2.5,inf\n") != NULL);

    // interrupted in stage 1 after step 7; the last checkpoint was at (1, 4); plus a torn row
    REQUIRE(mlb_losslog_open(&l, pb, COLS, 3, -1, 0) == MLB_OK);
    REQUIRE(log_steps(l, 0, 0, 12) && log_steps(l, 1, 0, 8));
    mlb_losslog_close(l);
    FILE* f = fopen(pb, "ab");
    REQUIRE(f);
    fputs("1,8,0.0092", f);
    fclose(f);
    REQUIRE(mlb_losslog_open(&l, pb, COLS, 3, 1, 4) == MLB_OK);
    REQUIRE(log_steps(l, 1, 4, 10));
    mlb_losslog_close(l);
    char* B = slurp(pb, &nb);
    REQUIRE(B);
    CHECK(na == nb && memcmp(A, B, na) == 0);
    free(B);

    // resumed back in stage 0 (a crash before the geometry stage ended)
    REQUIRE(mlb_losslog_open(&l, pb, COLS, 3, 0, 9) == MLB_OK);
    REQUIRE(log_steps(l, 0, 9, 12) && log_steps(l, 1, 0, 10));
    mlb_losslog_close(l);
    B = slurp(pb, &nb);
    REQUIRE(B);
    CHECK(na == nb && memcmp(A, B, na) == 0);
    free(B);
    // resume after the end keeps everything; (0, 0) keeps only the header
    REQUIRE(mlb_losslog_open(&l, pb, COLS, 3, 2, 0) == MLB_OK);
    mlb_losslog_close(l);
    B = slurp(pb, &nb);
    CHECK(B && na == nb && memcmp(A, B, na) == 0);
    free(B);
    REQUIRE(mlb_losslog_open(&l, pb, COLS, 3, 0, 0) == MLB_OK);
    mlb_losslog_close(l);
    B = slurp(pb, &nb);
    CHECK(B && strcmp(B, "stage,step,loss,sds,lr\n") == 0);
    free(B);
    free(A);
}

TEST(losslog_errors) {
    char p[4096];
    path_of(p, "bad.csv");
    mlb_losslog* l = NULL;
    const char* cols2[2] = {"loss", "sds"};
    REQUIRE(write_text(p, "stage,step,loss,lr\n0,0,1,2\n"));
    CHECK(mlb_losslog_open(&l, p, COLS, 3, 0, 5) == MLB_ERR_FORMAT && l == NULL && has(p) && has("header"));
    REQUIRE(write_text(p, "stage,step,loss,sds\n0,0,1,2\n0,1,1\n0,2,1,2\n"));
    CHECK(mlb_losslog_open(&l, p, cols2, 2, 0, 5) == MLB_ERR_FORMAT && has(p) && has(":3:"));
    REQUIRE(write_text(p, "stage,step,loss,sds\n0,0,1,2\n0,x,1,2\n"));
    CHECK(mlb_losslog_open(&l, p, cols2, 2, 0, 5) == MLB_ERR_FORMAT && has(":3:"));
    const char* badc[2] = {"a,b", "c"};
    CHECK(mlb_losslog_open(&l, p, badc, 2, -1, 0) == MLB_ERR_ARG);
    CHECK(mlb_losslog_open(&l, p, cols2, 0, -1, 0) == MLB_ERR_ARG);
    // a missing file on resume starts afresh
    path_of(p, "new.csv");
    REQUIRE(mlb_losslog_open(&l, p, cols2, 2, 1, 7) == MLB_OK);
    double v[2] = {1, 2};
    CHECK(mlb_losslog_append(l, 1, 7, v) == MLB_OK);
    CHECK(mlb_losslog_append(l, -1, 7, v) == MLB_ERR_ARG);
    mlb_losslog_close(l);
    size_t n;
    char* t = slurp(p, &n);
    CHECK(t && strcmp(t, "stage,step,loss,sds\n1,7,1,2\n") == 0);
    free(t);
}

TEST(losslog_plot) {
    char p[4096], png[4096];
    path_of(p, "plot.csv");
    path_of(png, "loss.png");
    mlb_losslog* l = NULL;
    REQUIRE(mlb_losslog_open(&l, p, COLS, 3, -1, 0) == MLB_OK);
    REQUIRE(log_steps(l, 0, 0, 300) && log_steps(l, 1, 0, 200));
    mlb_losslog_close(l);
    REQUIRE(mlb_losslog_plot(p, png) == MLB_OK);
    mlb_image img = {0};
    REQUIRE(mlb_image_load(&img, png, 3) == MLB_OK);
    CHECK(img.w == 720 && img.h == 3 * 220);
    // both stage colours appear (palette 0 and 1 as 8-bit codes)
    int blue = 0, red = 0;
    for (int i = 0; i < img.w * img.h; i++) {
        const float* q = img.data + 3 * (size_t)i;
        if (fabsf(q[0] - 31 / 255.f) < 1e-3f && fabsf(q[1] - 120 / 255.f) < 1e-3f && fabsf(q[2] - 181 / 255.f) < 1e-3f) blue++;
        if (fabsf(q[0] - 214 / 255.f) < 1e-3f && fabsf(q[1] - 38 / 255.f) < 1e-3f && fabsf(q[2] - 41 / 255.f) < 1e-3f) red++;
    }
    CHECK_MSG(blue > 100 && red > 100, "blue %d red %d", blue, red);
    mlb_image_free(&img);
    REQUIRE(write_text(p, "stage,step,loss\n"));   // no rows yet: empty axes
    CHECK(mlb_losslog_plot(p, png) == MLB_OK);
    REQUIRE(write_text(p, "stage,step,loss\n0,1,2\n0,2\n"));
    CHECK(mlb_losslog_plot(p, png) == MLB_ERR_FORMAT && has(":3:"));
    REQUIRE(write_text(p, "step,loss\n1,2\n"));
    CHECK(mlb_losslog_plot(p, png) == MLB_ERR_FORMAT && has(p));
}

int main(void) {
    const char* t = test_tmpdir("run");
    if (!t) { printf("cannot make a scratch folder\n"); return 1; }
    snprintf(tmp, sizeof tmp, "%s", t);
    RUN(run_create_and_refusals);
    RUN(run_path);
    RUN(json_round_trip_and_errors);
    RUN(checkpoint_round_trip_bitwise);
    RUN(checkpoint_load_errors);
    RUN(checkpoint_nan);
    RUN(losslog_resume_is_byte_identical);
    RUN(losslog_errors);
    RUN(losslog_plot);
    return test_summary();
}
