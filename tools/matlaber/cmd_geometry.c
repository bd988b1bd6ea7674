// matlaber geometry init | extract: the DMTet geometry network's SDF initialisation (reference.md §3)
// and its marching-tets surface as an OBJ (docs/geometry_init.md).
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cli.h"
#include "matlaber/fileio.h"
#include "matlaber/geometry.h"
#include "matlaber/log.h"
#include "matlaber/obj.h"

static const cli_option init_options[] = {
    {"shape", 1, 'S', "SHAPE", "ellipsoid, cylinder, torus, slab, cup or FILE.obj (normalised to the unit sphere)"},
    {"shape-scale", 1, 'k', "X", "scale of the shape (default 1: ellipsoid radius 1, cylinder r 0.75 h 0.8, torus outer radius 0.8, slab 1.28 x 0.11 x 0.78 at y 0.18..0.28, cup an open hemispherical shell of radius 0.6, wall 0.2, rim corner at 0.8)"},
    {"grid", 1, 'g', "32|64|128", "tet grid of the extraction (16, 32 or 64 cells; default 64; 32 is the tiny preset's), kept in the file"},
    {"iters", 1, 'i', "N", "Adam steps (default 400)"},
    {"batch", 1, 'b', "N", "points per step (default 12288)"},
    {"lr", 1, 'l', "X", "learning rate (default 1e-2)"},
    {"scale", 1, 'c', "X", "the grid box is [-0.5,0.5]^3 x X (default 2.1)"},
    {"table-log2", 1, 'T', "N", "log2 of the hash table size per level (default 19)"},
    {"levels", 1, 'L', "N", "hash grid levels (default 16)"},
    {"seed", 1, 's', "S", "seed of the initialisation and the samples (default 1)"},
    {"out", 1, 'o', "FILE", "output safetensors file"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

static int geometry_init(int argc, char** argv) {
    const char* shape_arg = "ellipsoid";
    const char* out = NULL;
    double shape_scale = 1.0, x;
    long v, grid = 64;
    mlb_geometry_config cfg = mlb_geometry_default();
    mlb_shape_fit_config fit = mlb_shape_fit_default();
    const struct option* table = cli_getopt_table(init_options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "ho:", table, NULL)) != -1) {
        switch (c) {
        case 'S': shape_arg = optarg; break;
        case 'k': if (cli_parse_double(optarg, 1e-3, 10, &x)) return cli_usage_error("geometry init", "--shape-scale: expected 0.001..10"); shape_scale = x; break;
        case 'g': if (cli_parse_long(optarg, 32, 128, &v) || (v != 32 && v != 64 && v != 128)) return cli_usage_error("geometry init", "--grid: expected 32, 64 or 128"); grid = v; break;
        case 'i': if (cli_parse_long(optarg, 1, 1000000, &v)) return cli_usage_error("geometry init", "--iters: expected 1..1000000"); fit.iters = (int)v; break;
        case 'b': if (cli_parse_long(optarg, 3, 1 << 22, &v)) return cli_usage_error("geometry init", "--batch: expected 3..4194304"); fit.batch = (int)v; break;
        case 'l': if (cli_parse_double(optarg, 1e-9, 10, &x)) return cli_usage_error("geometry init", "--lr: expected a positive number"); fit.lr = x; break;
        case 'c': if (cli_parse_double(optarg, 1e-3, 1e3, &x)) return cli_usage_error("geometry init", "--scale: expected 0.001..1000"); cfg.scale = (float)x; break;
        case 'T': if (cli_parse_long(optarg, 8, 24, &v)) return cli_usage_error("geometry init", "--table-log2: expected 8..24"); cfg.enc.table_size = 1u << v; break;
        case 'L': if (cli_parse_long(optarg, 1, MLB_HASHGRID_MAX_LEVELS, &v)) return cli_usage_error("geometry init", "--levels: expected 1..%d", MLB_HASHGRID_MAX_LEVELS); cfg.enc.n_levels = (int)v; break;
        case 's': if (cli_parse_long(optarg, 0, 0x7fffffffffffffffL, &v)) return cli_usage_error("geometry init", "--seed: expected a non-negative integer"); cfg.seed = fit.seed = (uint64_t)v; break;
        case 'o': out = optarg; break;
        case 'h':
            printf("usage: matlaber geometry init --shape ellipsoid|cylinder|torus|slab|cup|FILE.obj [options] -o FILE.safetensors\n\n"
                   "Initialises the geometry network (hash grid -> MLP 32 wide, 2 hidden, ReLU -> sdf + deform) by\n"
                   "Adam steps of MSE against the shape's signed distance at surface, jittered (N(0, 0.05)) and\n"
                   "uniform points (reference.md §3). Prints the Chamfer distance of the extracted surface.\n\n");
            cli_print_options(stdout, init_options);
            return 0;
        default: return cli_usage_error("geometry init", "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error("geometry init", "unexpected argument '%s'", argv[optind]);
    if (!out) return cli_usage_error("geometry init", "-o FILE.safetensors is required");

    mlb_shape shape;
    mlb_status s;
    if (!mlb_shape_builtin(&shape, shape_arg, (float)shape_scale)) {
        mlb_mesh m;
        s = mlb_obj_load(shape_arg, &m);
        if (s) return cli_fail(s, "loading the shape");
        s = mlb_shape_from_mesh(&shape, &m, (float)shape_scale);
        mlb_mesh_free(&m);
        if (s) return cli_fail(mlb_fail_context(s, "%s", shape_arg), "shape");
    }
    mlb_geometry_net net;
    s = geometry_net_init(&net, &cfg);
    if (s) { mlb_shape_free(&shape); return cli_fail(s, "geometry init"); }
    mlb_progress progress;
    mlb_progress_begin(&progress, mlb_log_get_level() <= MLB_LOG_INFO ? stderr : NULL, "geometry init", fit.iters, "step");
    double t0 = mlb_now_seconds(), loss = 0;
    s = mlb_geometry_fit_shape(&net, &shape, &fit, &progress, &loss);
    double seconds = mlb_now_seconds() - t0;
    if (s) { geometry_net_free(&net); mlb_shape_free(&shape); return cli_fail(s, "geometry init"); }
    mlb_progress_end(&progress, NULL);
    // measure: extract and compare with the shape's surface
    mlb_tetgrid g;
    mlb_mesh m = {0}, ref = {0};
    int cells = (int)grid / 2;
    s = mlb_tetgrid_create(&g, cells, cfg.scale);
    if (!s) s = mlb_geometry_extract(NULL, &net, &g, &m);
    if (!s) {
        if (shape.kind == MLB_SHAPE_MESH) ref = shape.mesh, memset(&shape.mesh, 0, sizeof shape.mesh);
        else if (shape.kind == MLB_SHAPE_ELLIPSOID) {
            s = mlb_mesh_uv_sphere(&ref, 1.0f, 192, 96);
            for (int i = 0; !s && i < ref.n_verts; i++) for (int k = 0; k < 3; k++) ref.pos[3 * i + k] *= shape.radii[k];
        }
    }
    mlb_chamfer_result cr = {0};
    int have_cd = 0;
    if (!s && ref.n_faces) { s = mlb_chamfer(&m, &ref, 20000, 1, &cr); have_cd = !s; }
    mlb_tetgrid_free(&g);
    if (s) { mlb_mesh_free(&m); mlb_mesh_free(&ref); geometry_net_free(&net); mlb_shape_free(&shape); return cli_fail(s, "geometry init"); }

    char command[1024] = "matlaber geometry", settings[512], grid_text[16], cd_text[64];
    size_t used = strlen(command);
    for (int i = 0; i < argc && used < sizeof command; i++) used += snprintf(command + used, sizeof command - used, " %s", argv[i]);
    snprintf(settings, sizeof settings, "shape %s, shape scale %g, iters %d, batch %d, lr %g, seed %llu, final mse %.4g", shape_arg,
             shape_scale, fit.iters, fit.batch, fit.lr, (unsigned long long)fit.seed, loss);
    snprintf(grid_text, sizeof grid_text, "%ld", grid);
    snprintf(cd_text, sizeof cd_text, "%.6g", have_cd ? cr.relative : NAN);
    mlb_st_meta meta[] = {{"command", command}, {"init", settings}, {"geometry.grid", grid_text}, {"chamfer_relative", cd_text}};
    s = mlb_geometry_save(&net, out, meta, have_cd ? 4 : 3);
    if (s) { mlb_mesh_free(&m); mlb_mesh_free(&ref); geometry_net_free(&net); mlb_shape_free(&shape); return cli_fail(s, "saving"); }
    printf("wrote %s: %zu parameters, %d steps in %.1f s, final mse %.4g\n", out, net.n_params, fit.iters, seconds, loss);
    printf("surface on the %ld grid: %d vertices, %d faces\n", grid, m.n_verts, m.n_faces);
    if (have_cd)
        printf("chamfer to the shape: %.5f (%.5f of the bounding-box diagonal %.3f)\n", cr.chamfer, cr.relative, cr.diag);
    mlb_mesh_free(&m);
    mlb_mesh_free(&ref);
    geometry_net_free(&net);
    mlb_shape_free(&shape);
    return 0;
}

static const cli_option extract_options[] = {
    {"in", 1, 'i', "FILE", "geometry network (from 'matlaber geometry init')"},
    {"grid", 1, 'g', "32|64|128", "tet grid (default: the file's, else 64)"},
    {"out", 1, 'o', "FILE", "output OBJ"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

static mlb_status write_obj(const char* path, mlb_mesh* m) {
    mlb_status s = mlb_mesh_compute_normals(m);
    if (s) return s;
    mlb_atomic_file af;
    s = mlb_atomic_open(&af, path);
    if (s) return s;
    fprintf(af.f, "# matlaber geometry extract: %d vertices, %d faces\n", m->n_verts, m->n_faces);
    for (int i = 0; i < m->n_verts; i++) fprintf(af.f, "v %.7g %.7g %.7g\n", m->pos[3 * i], m->pos[3 * i + 1], m->pos[3 * i + 2]);
    for (int i = 0; i < m->n_verts; i++)
        fprintf(af.f, "vn %.6g %.6g %.6g\n", m->normal[3 * i], m->normal[3 * i + 1], m->normal[3 * i + 2]);
    for (int f = 0; f < m->n_faces; f++) {
        const int32_t* t = m->faces + 3 * f;
        fprintf(af.f, "f %d//%d %d//%d %d//%d\n", t[0] + 1, t[0] + 1, t[1] + 1, t[1] + 1, t[2] + 1, t[2] + 1);
    }
    return mlb_atomic_commit(&af);
}

static int geometry_extract(int argc, char** argv) {
    const char* in = NULL;
    const char* out = NULL;
    long v, grid = 0;
    const struct option* table = cli_getopt_table(extract_options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "hi:o:", table, NULL)) != -1) {
        switch (c) {
        case 'i': in = optarg; break;
        case 'o': out = optarg; break;
        case 'g': if (cli_parse_long(optarg, 32, 128, &v) || (v != 32 && v != 64 && v != 128)) return cli_usage_error("geometry extract", "--grid: expected 32, 64 or 128"); grid = v; break;
        case 'h':
            printf("usage: matlaber geometry extract -i FILE.safetensors -o mesh.obj [--grid 32|64|128]\n\n"
                   "Evaluates the geometry network at the tet grid's vertices (sdf and deformation) and writes\n"
                   "the marching-tetrahedra surface as an OBJ with vertex normals.\n\n");
            cli_print_options(stdout, extract_options);
            return 0;
        default: return cli_usage_error("geometry extract", "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error("geometry extract", "unexpected argument '%s'", argv[optind]);
    if (!in || !out) return cli_usage_error("geometry extract", "-i FILE.safetensors and -o mesh.obj are required");
    if (!grid) {   // the grid recorded by 'init'
        mlb_safetensors* st;
        if (mlb_st_open(&st, in) == MLB_OK) {
            const char* t = mlb_st_metadata(st, "geometry.grid");
            if (t && strcmp(t, "128") == 0) grid = 128;
            if (t && strcmp(t, "32") == 0) grid = 32;
            mlb_st_close(st);
        }
        if (!grid) grid = 64;
    }
    mlb_geometry_net net;
    mlb_status s = mlb_geometry_load(&net, in);
    if (s) return cli_fail(s, "loading the geometry network");
    mlb_tetgrid g;
    mlb_mesh m = {0};
    s = mlb_tetgrid_create(&g, (int)grid / 2, net.cfg.scale);
    if (!s) s = mlb_geometry_extract(NULL, &net, &g, &m);
    if (!s) s = write_obj(out, &m);
    if (!s) printf("wrote %s: %d vertices, %d faces (grid %ld)\n", out, m.n_verts, m.n_faces, grid);
    mlb_mesh_free(&m);
    mlb_tetgrid_free(&g);
    geometry_net_free(&net);
    return s ? cli_fail(s, in) : 0;
}

int cmd_geometry(int argc, char** argv) {
    if (argc < 2 || strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0) {
        FILE* o = argc < 2 ? stderr : stdout;
        fprintf(o, "usage: matlaber geometry init|extract [options]  ('matlaber geometry <sub> --help')\n"
                   "  init      fit the geometry network's SDF to an ellipsoid, a cylinder, a torus, a slab, a cup or a mesh\n"
                   "  extract   the network's marching-tets surface as an OBJ\n");
        return argc < 2 ? EXIT_USAGE : 0;
    }
    if (strcmp(argv[1], "init") == 0) return geometry_init(argc - 1, argv + 1);
    if (strcmp(argv[1], "extract") == 0) return geometry_extract(argc - 1, argv + 1);
    return cli_usage_error("geometry", "unknown subcommand '%s' (init, extract)", argv[1]);
}
