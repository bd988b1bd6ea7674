// Multi-view data sets (views.h): render a folder, load it back and compare with fresh renders;
// resampling; camera_to_world cameras; cameras.json round trip; hostile cameras.json and images.
#include "matlaber/geometry_fit.h"
#include "matlaber/goblet.h"
#include "matlaber/image_write.h"
#include "matlaber/render.h"
#include "matlaber/views.h"
#include "test.h"

static void write_text(const char* dir, const char* name, const char* text) {
    char path[4400];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE* f = fopen(path, "wb");
    if (f) { fputs(text, f); fclose(f); }
}

static void write_png(const char* dir, const char* name, int size, int channels) {
    char path[4400];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    float* px = malloc(sizeof(float) * channels * size * size);
    for (int i = 0; i < channels * size * size; i++) px[i] = (float)((i * 37) % 256) / 255.0f;
    mlb_image_write_png(path, px, size, size, channels, NULL);
    free(px);
}

// The goblet rendered into a folder and loaded back equals a fresh render of each view up to the
// files' quantisation: 8-bit sRGB colour and alpha (|Δ(s·α)| <= 1/255), 16-bit normals.
TEST(render_load_round_trip) {
    const char* dir = test_tmpdir("views_rt");
    REQUIRE(dir);
    mlb_mesh m;
    REQUIRE(mlb_goblet_mesh(&m, 48) == MLB_OK);
    float* k = malloc(sizeof(float) * 7 * m.n_verts);
    mlb_goblet_materials(&m, k);
    const char* envs[] = {"sky", "studio"};
    mlb_views_render_config c = mlb_views_render_default();
    c.mesh = &m; c.k = k; c.n_views = 4; c.res = 40; c.supersample = 2; c.cube = 64;
    c.envs = envs; c.n_envs = 2; c.seed = 7;
    REQUIRE(mlb_views_render(dir, &c, NULL) == MLB_OK);
    mlb_views v;
    REQUIRE(mlb_views_load(&v, dir, 0) == MLB_OK);
    CHECK(v.n == 4 && v.res == 40 && v.src_size == 40 && v.has_normals && v.meta.n_envs == 2);
    CHECK(strcmp(v.meta.envs[0].name, "sky") == 0 && strcmp(v.meta.envs[1].name, "studio") == 0);
    mlb_envmap em[2] = {{0}};
    mlb_envlight el[2] = {{0}};
    mlb_envlight_options lo = {.face_size = 64};
    for (int e = 0; e < 2; e++) {
        REQUIRE(mlb_views_open_env(&v, e, &em[e], 0) == MLB_OK);
        REQUIRE(mlb_envlight_build(&el[e], &em[e], &lo) == MLB_OK);
    }
    size_t P = 40 * 40;
    float* img = malloc(sizeof(float) * 4 * P);
    float* tgt = malloc(sizeof(float) * 4 * P);
    int envs_seen[2] = {0, 0};
    for (int i = 0; i < v.n; i++) {
        double az, elv, rot;
        int env;
        mlb_views_render_pose(&c, i, &az, &elv, &env, &rot);
        CHECK(v.meta.views[i].orbit && v.meta.views[i].env == env);
        CHECK_CLOSE(v.meta.views[i].azimuth_deg, az, 0, 1e-12);
        CHECK_CLOSE(v.meta.views[i].env_rotation_deg, rot, 0, 1e-12);
        CHECK(elv >= -30 && elv <= 75);
        envs_seen[env]++;
        mlb_camera cam;
        REQUIRE(mlb_camera_orbit(&cam, az, elv, 3, NULL, 40, 1, 0.1, 100) == MLB_OK);
        for (int q = 0; q < 16; q++) CHECK_CLOSE(v.cams[i].view_proj.m[q], cam.view_proj.m[q], 0, 1e-12);
        float r = (float)(rot * M_PI / 180);
        mlb_envmap_set_rotation(&em[env], r);
        mlb_envlight_set_rotation(&el[env], r);
        mlb_render_params p;
        memset(&p, 0, sizeof p);
        p.mesh = &m; p.k = k; p.light = &el[env]; p.env = &em[env]; p.background = MLB_BG_COLOR;
        p.camera = cam; p.width = p.height = 40; p.supersample = 2; p.fresnel = MLB_FRESNEL_PAPER;
        REQUIRE(mlb_views_render_target(&p, tgt) == MLB_OK);
        double worst = 0, cover = 0;
        for (size_t j = 0; j < 4 * P; j++) worst = fmax(worst, fabs(tgt[j] - v.images[4 * P * i + j]));
        for (size_t j = 0; j < P; j++) cover += tgt[4 * j + 3];
        CHECK_MSG(worst <= 1.0 / 255 + 1e-6, "view %d: colour differs by %g", i, worst);
        CHECK(cover > 0.05 * P);   // the goblet is in the picture
        REQUIRE(mlb_geofit_render_mesh(NULL, img, &m, &cam, 40, 2) == MLB_OK);
        worst = 0;
        for (size_t j = 0; j < 4 * P; j++) worst = fmax(worst, fabs(img[j] - v.normals[4 * P * i + j]));
        CHECK_MSG(worst <= 1e-4, "view %d: normal differs by %g", i, worst);
    }
    CHECK(envs_seen[0] + envs_seen[1] == 4);
    // at half the resolution: exactly the 2x2 box filter of the full-resolution load
    mlb_views h;
    REQUIRE(mlb_views_load(&h, dir, 20) == MLB_OK);
    CHECK(h.res == 20 && h.src_size == 40);
    float* box = malloc(sizeof(float) * 4 * 400);
    REQUIRE(mlb_views_resample(box, 20, v.images + 4 * P * 2, 40, 40, 4) == MLB_OK);
    CHECK(memcmp(box, h.images + 4 * 400 * 2, sizeof(float) * 4 * 400) == 0);
    mlb_views_free(&h);
    for (int e = 0; e < 2; e++) { mlb_envmap_free(&em[e]); mlb_envlight_free(&el[e]); }
    free(box); free(img); free(tgt); free(k);
    mlb_views_free(&v);
    mlb_mesh_free(&m);
}

TEST(resample_box_and_bilinear) {
    // box: factor 2 of a 4x4 single-channel image
    float in[16], out[4];
    for (int i = 0; i < 16; i++) in[i] = (float)i;
    REQUIRE(mlb_views_resample(out, 2, in, 4, 4, 1) == MLB_OK);
    CHECK(out[0] == (0 + 1 + 4 + 5) / 4.0f && out[1] == (2 + 3 + 6 + 7) / 4.0f && out[3] == (10 + 11 + 14 + 15) / 4.0f);
    // factor 1 copies
    float same[16];
    REQUIRE(mlb_views_resample(same, 4, in, 4, 4, 1) == MLB_OK);
    CHECK(memcmp(same, in, sizeof in) == 0);
    // bilinear 6 → 4 of a linear ramp x + 10 y is the ramp at the sample points (interior)
    float ramp[36], r4[16];
    for (int y = 0; y < 6; y++)
        for (int x = 0; x < 6; x++) ramp[6 * y + x] = (float)(x + 10 * y);
    REQUIRE(mlb_views_resample(r4, 4, ramp, 6, 6, 1) == MLB_OK);
    for (int y = 0; y < 4; y++)
        for (int x = 0; x < 4; x++) {
            double sx = (x + 0.5) * 1.5 - 0.5, sy = (y + 0.5) * 1.5 - 0.5;
            CHECK_CLOSE(r4[4 * y + x], sx + 10 * sy, 0, 1e-5);
        }
    // upsampling 2 → 3 clamps at the edges: the corners keep the corner values
    float two[4] = {1, 2, 3, 4}, three[9];
    REQUIRE(mlb_views_resample(three, 3, two, 2, 2, 1) == MLB_OK);
    CHECK(three[0] == 1 && three[2] == 2 && three[6] == 3 && three[8] == 4);
    CHECK_CLOSE(three[4], 2.5, 0, 1e-6);
    CHECK(mlb_views_resample(three, 0, two, 2, 2, 1) == MLB_ERR_ARG);
}

// A camera_to_world entry equal to the inverse of an orbit camera's view gives the same camera.
TEST(camera_to_world_matches_orbit) {
    mlb_views_entry o;
    memset(&o, 0, sizeof o);
    o.orbit = 1; o.azimuth_deg = 35; o.elevation_deg = 20; o.radius = 2.5; o.target[1] = 0.1;
    o.fovy_deg = 45; o.near_z = 0.1; o.far_z = 100; o.env = -1;
    mlb_camera a, b;
    REQUIRE(mlb_views_entry_camera(&a, &o) == MLB_OK);
    mlb_views_entry c = o;
    c.orbit = 0;
    for (int r = 0; r < 3; r++) {
        for (int k = 0; k < 3; k++) c.camera_to_world[4 * r + k] = a.view.m[4 * k + r];   // R^T
        c.camera_to_world[4 * r + 3] = a.eye[r];
    }
    c.camera_to_world[15] = 1;
    REQUIRE(mlb_views_entry_camera(&b, &c) == MLB_OK);
    for (int q = 0; q < 16; q++) CHECK_CLOSE(b.view_proj.m[q], a.view_proj.m[q], 0, 1e-12);
    CHECK_CLOSE(b.azimuth_deg, 35, 0, 1e-6);
    CHECK_CLOSE(b.elevation_deg, atan2(a.eye[1], hypot(a.eye[0], a.eye[2])) * 180 / M_PI, 0, 1e-9);
    c.camera_to_world[0] *= 1.1;   // not orthonormal
    CHECK(mlb_views_entry_camera(&b, &c) == MLB_ERR_ARG);
    c.camera_to_world[0] /= 1.1;
    for (int r = 0; r < 3; r++) c.camera_to_world[4 * r] = -c.camera_to_world[4 * r];   // a reflection
    CHECK(mlb_views_entry_camera(&b, &c) == MLB_ERR_ARG);
}

TEST(meta_write_read_round_trip) {
    const char* dir = test_tmpdir("views_meta");
    REQUIRE(dir);
    mlb_views_meta m = {0};
    m.n_views = 2; m.n_envs = 2;
    m.views = calloc(2, sizeof *m.views);
    m.envs = calloc(2, sizeof *m.envs);
    snprintf(m.envs[0].name, sizeof m.envs[0].name, "overcast");
    m.envs[0].scale = 1;
    snprintf(m.envs[1].file, sizeof m.envs[1].file, "maps/room.hdr");
    m.envs[1].scale = 0.5;
    mlb_views_entry* a = &m.views[0];
    snprintf(a->image, sizeof a->image, "a.png");
    a->orbit = 1; a->azimuth_deg = -12.345678901234567; a->elevation_deg = 33; a->radius = 3; a->target[2] = 0.25;
    a->fovy_deg = 40; a->near_z = 0.1; a->far_z = 100; a->env = 1; a->env_rotation_deg = 271.5;
    mlb_views_entry* b = &m.views[1];
    snprintf(b->image, sizeof b->image, "sub/b.png");
    snprintf(b->normal, sizeof b->normal, "sub/nb.png");
    b->orbit = 0;
    double c2w[16] = {0, 0, 1, 4, 0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 0, 1};   // at +x looking towards -x
    memcpy(b->camera_to_world, c2w, sizeof c2w);
    b->fovy_deg = 30; b->near_z = 0.5; b->far_z = 10; b->env = -1;
    REQUIRE(mlb_views_meta_write(dir, &m) == MLB_OK);
    mlb_views_meta r;
    REQUIRE(mlb_views_meta_read(&r, dir) == MLB_OK);
    CHECK(r.n_views == 2 && r.n_envs == 2);
    CHECK(strcmp(r.envs[0].name, "overcast") == 0 && strcmp(r.envs[1].file, "maps/room.hdr") == 0 && r.envs[1].scale == 0.5);
    CHECK(memcmp(&r.views[0], a, sizeof *a) == 0);   // numbers survive exactly (17 digits)
    CHECK(memcmp(&r.views[1], b, sizeof *b) == 0);
    mlb_camera cam;
    REQUIRE(mlb_views_entry_camera(&cam, &r.views[1]) == MLB_OK);
    CHECK_CLOSE(cam.eye[0], 4, 0, 0);
    CHECK_CLOSE(cam.azimuth_deg, 90, 0, 1e-12);
    // a view with neither env nor normal keeps them absent
    mlb_views_meta_free(&r);
    // the writer refuses what the reader would refuse
    snprintf(a->image, sizeof a->image, "../a.png");
    CHECK(mlb_views_meta_write(dir, &m) == MLB_ERR_FORMAT);
    mlb_views_meta_free(&m);
}

// Each bad cameras.json gives an error naming the file and the JSON path.
TEST(hostile_cameras_json) {
    const char* dir = test_tmpdir("views_bad");
    REQUIRE(dir);
    write_png(dir, "a.png", 8, 4);
    write_png(dir, "b.png", 8, 4);
    write_png(dir, "big.png", 16, 4);
    write_png(dir, "rgb.png", 8, 3);
    static const struct { const char* json; const char* expect; } cases[] = {
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [", "not valid JSON"},
        {"[1, 2]", "not an object"},
        {"{\"version\": 1, \"views\": []}", "format: missing"},
        {"{\"format\": \"nerf\", \"version\": 1, \"views\": []}", "format: expected"},
        {"{\"format\": \"matlaber-views\", \"version\": 2, \"views\": []}", "version: 2 is not supported"},
        {"{\"format\": \"matlaber-views\", \"version\": 1}", "views: missing"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": []}", "views: empty"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"a.png\", \"fovy_deg\": 40, "
         "\"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3}}, {\"image\": \"b.png\", \"fovy_deg\": \"40\", "
         "\"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3}}]}", "views[1].fovy_deg: not a number"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"fovy_deg\": 40, "
         "\"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3}}]}", "views[0].image: missing"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"../a.png\", \"fovy_deg\": 40, "
         "\"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3}}]}", "views[0].image: path leaves the folder"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"x/../../a.png\", \"fovy_deg\": 40, "
         "\"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3}}]}", "path leaves the folder"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"/etc/passwd\", \"fovy_deg\": 40, "
         "\"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3}}]}", "views[0].image: absolute path"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"a.png\", \"fovy_deg\": 40, "
         "\"orbit\": {\"azimuth_deg\": 1e999, \"elevation_deg\": 0, \"radius\": 3}}]}", "views[0].orbit.azimuth_deg: not a finite number"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"a.png\", \"fovy_deg\": 40, "
         "\"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 95, \"radius\": 3}}]}", "views[0].orbit.elevation_deg: 95 outside"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"a.png\", \"fovy_deg\": 180, "
         "\"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3}}]}", "views[0].fovy_deg: 180 outside"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"a.png\", \"fovy_deg\": 40}]}",
         "views[0]: expected exactly one camera"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"a.png\", "
         "\"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3}}]}", "views[0].fovy_deg: missing"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"a.png\", \"fovy_deg\": 40, "
         "\"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3, \"fovy_deg\": 30}}]}", "views[0].orbit: fovy_deg 30 differs"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"a.png\", \"fovy_deg\": 40, "
         "\"camera_to_world\": [[1,0,0,0],[0,1,0,0],[0,0,1]]}]}", "views[0].camera_to_world: expected 4 rows of 4 numbers"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"a.png\", \"fovy_deg\": 40, "
         "\"camera_to_world\": [[2,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]}]}", "views[0].camera_to_world: camera_to_world: the rotation is not orthonormal"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"environments\": [{\"name\": \"sky\"}], \"views\": [{\"image\": "
         "\"a.png\", \"fovy_deg\": 40, \"env\": 1, \"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3}}]}",
         "views[0].env: 1 is not an index"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"environments\": [{\"name\": \"sky\"}], \"views\": [{\"image\": "
         "\"a.png\", \"fovy_deg\": 40, \"env\": 0.5, \"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3}}]}",
         "views[0].env: 0.5 is not an index"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"environments\": [{\"name\": \"mars\"}], \"views\": []}",
         "environments[0].name: 'mars' is not a built-in"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"environments\": [{\"file\": \"../x.hdr\"}], \"views\": []}",
         "environments[0].file: path leaves the folder"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"environments\": [{\"name\": \"sky\", \"file\": \"x.hdr\"}], \"views\": []}",
         "environments[0]: expected exactly one"},
        {"{\"format\": \"matlaber-views\", \"version\": 1, \"environments\": [{\"file\": \"x.hdr\", \"scale\": -1}], \"views\": []}",
         "environments[0].scale: -1"},
    };
    char path[4400];
    snprintf(path, sizeof path, "%s/cameras.json", dir);
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        write_text(dir, "cameras.json", cases[i].json);
        mlb_views v;
        mlb_status s = mlb_views_load(&v, dir, 0);
        const char* msg = mlb_last_error();
        CHECK_MSG(s != MLB_OK && strstr(msg, path) && strstr(msg, cases[i].expect), "case %zu: status %d, message '%s', expected '%s'",
                  i, (int)s, msg, cases[i].expect);
        CHECK(v.images == NULL && v.n == 0);
    }
    // image problems name the image
    static const struct { const char* a; const char* b; const char* expect; } imgs[] = {
        {"a.png", "big.png", "big.png: 16x16, but the data set's images are 8x8"},
        {"a.png", "missing.png", "missing.png"},
        {"a.png", "rgb.png", "rgb.png: no alpha channel"},
    };
    for (size_t i = 0; i < sizeof imgs / sizeof imgs[0]; i++) {
        char json[1024];
        snprintf(json, sizeof json,
                 "{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"%s\", \"fovy_deg\": 40, \"orbit\": "
                 "{\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3}}, {\"image\": \"%s\", \"fovy_deg\": 40, \"orbit\": "
                 "{\"azimuth_deg\": 90, \"elevation_deg\": 0, \"radius\": 3}}]}", imgs[i].a, imgs[i].b);
        write_text(dir, "cameras.json", json);
        mlb_views v;
        mlb_status s = mlb_views_load(&v, dir, 0);
        CHECK_MSG(s != MLB_OK && strstr(mlb_last_error(), imgs[i].expect), "image case %zu: '%s'", i, mlb_last_error());
    }
    // normal maps on some views only
    write_text(dir, "cameras.json",
               "{\"format\": \"matlaber-views\", \"version\": 1, \"views\": [{\"image\": \"a.png\", \"normal\": \"b.png\", "
               "\"fovy_deg\": 40, \"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3}}, {\"image\": \"b.png\", "
               "\"fovy_deg\": 40, \"orbit\": {\"azimuth_deg\": 90, \"elevation_deg\": 0, \"radius\": 3}}]}");
    mlb_views v;
    CHECK(mlb_views_load(&v, dir, 0) == MLB_ERR_FORMAT && strstr(mlb_last_error(), "1 of 2 views have a normal map"));
    // a good file loads; unknown keys are ignored; fovy_deg may sit inside the orbit; resolution limits
    write_text(dir, "cameras.json",
               "{\"format\": \"matlaber-views\", \"version\": 1, \"comment\": \"x\", \"views\": [{\"image\": \"./a.png\", "
               "\"orbit\": {\"azimuth_deg\": 0, \"elevation_deg\": 0, \"radius\": 3, \"fovy_deg\": 40}}, {\"image\": \"b.png\", "
               "\"fovy_deg\": 40, \"orbit\": {\"azimuth_deg\": 90, \"elevation_deg\": 0, \"radius\": 3}}]}");
    REQUIRE(mlb_views_load(&v, dir, 4) == MLB_OK);
    CHECK(v.n == 2 && v.res == 4 && !v.has_normals && v.normals == NULL && v.meta.views[0].env == -1);
    CHECK(v.meta.views[0].fovy_deg == 40 && v.cams[0].fovy_deg == 40);
    // colour comes premultiplied: every colour sample <= its alpha
    int premult = 1;
    for (int i = 0; i < 2 * 16; i++)
        for (int c = 0; c < 3; c++) premult &= v.images[4 * i + c] <= v.images[4 * i + 3] + 1e-6f;
    CHECK(premult);
    mlb_views_free(&v);
    CHECK(mlb_views_load(&v, dir, MLB_VIEWS_MAX_SIZE + 1) == MLB_ERR_ARG);
    // an oversized cameras.json is refused before parsing
    snprintf(path, sizeof path, "%s/cameras.json", dir);
    FILE* f = fopen(path, "wb");
    REQUIRE(f);
    fputc('{', f);
    for (size_t i = 0; i < MLB_VIEWS_MAX_JSON; i++) fputc(' ', f);
    fputc('}', f);
    fclose(f);
    CHECK(mlb_views_load(&v, dir, 0) != MLB_OK && strstr(mlb_last_error(), "cameras.json"));
    snprintf(path, sizeof path, "%s/nowhere", dir);
    CHECK(mlb_views_load(&v, path, 0) != MLB_OK && strstr(mlb_last_error(), "nowhere/cameras.json"));
}

int main(void) {
    RUN(render_load_round_trip);
    RUN(resample_box_and_bilinear);
    RUN(camera_to_world_matches_orbit);
    RUN(meta_write_read_round_trip);
    RUN(hostile_cameras_json);
    return test_summary();
}
