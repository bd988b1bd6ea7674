// One guided step of the geometry stage (paper §3.3): the step's views, the guidance's gradient
// through marching tets and the rasteriser, the SDF regulariser, Adam. The stage (pipeline.c) and
// --init auto's look-ahead (pipeline_init.c) both step through it.
#include "matlaber/dist.h"
#include "pipeline/pipeline_internal.h"

// Coarse-to-fine hash grid: the first COARSE_LEVELS levels from the start, one more level at a time
// until all are active at coarse_to_fine × geometry_iters (0: all levels from the start). 0 = all.
#define COARSE_LEVELS 4
int pipeline_active_levels_at(const mlb_pipeline_config* c, const mlb_geometry_net* net, long it) {
    const int L = net->enc.cfg.n_levels;
    const double span = c->coarse_to_fine * c->geometry_iters;
    if (!(span > 0) || L <= COARSE_LEVELS) return 0;
    long a = COARSE_LEVELS + (long)((double)(L - COARSE_LEVELS) * it / span);
    return a >= L ? 0 : (int)a;
}

mlb_status pipeline_geometry_step(pipeline_run* r, mlb_geofit_state* st, const mlb_adam_config* adam, long it,
                                  mlb_view* views, mlb_geofit_stats* stats, float* images) {
    const mlb_pipeline_config* c = r->c;
    mlb_geometry_net* net = &r->geo;
    net->active_levels = pipeline_active_levels_at(c, net, it);
    mlb_status s = r->g->sample_views(r->g, MLB_STAGE_GEOMETRY, it, views);
    const double reg_weight = mlb_sdf_reg_weight(&c->sdf_reg, it, c->geometry_iters);
    if (!s) s = mlb_geometry_guided_step(st, net, &r->grid, r->g, it, views, c->res, c->ss, reg_weight, stats, images);
    s = pipeline_agree(s);   // every rank fails together, or none does
    if (!s) geometry_net_update(net, adam);
    return s;
}
