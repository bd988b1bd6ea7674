// Measuring a fitted asset against a known truth (the demo's report, docs/pipeline.md): geometry by
// Chamfer distance (geometry.h) and the angle between normals, albedo by the PSNR of kd on the
// fitted surface, and relighting by the PSNR of renders under an environment the fit never saw.
#ifndef MATLABER_EVALUATE_H
#define MATLABER_EVALUATE_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/envmap.h"
#include "matlaber/error.h"
#include "matlaber/material_net.h"
#include "matlaber/mesh.h"
#include "matlaber/render.h"   // mlb_material_fn

// 10 log10(1 / MSE) of a against b (values meant in [0, 1]); +inf when equal.
double mlb_psnr(const float* a, const float* b, size_t n);

// The true BRDF at any point of space (a pure function of position).
typedef void (*mlb_brdf_truth_fn)(const float* pos, float k[7]);

// The material field's kd against truth(pos).kd (both linear) at every pixel of the fitted mesh seen
// by n_views cameras (azimuths all round, elevations −15°, 20°, 50° in turn, radius 3, fovy 45°) at
// res × res: the visible surface, as the target views show it (a face no view can see, such as the
// underside of a foot, is not measured). psnr and rmse may be NULL.
mlb_status mlb_eval_albedo(const mlb_mesh* fit, const mlb_material_net* net, mlb_brdf_truth_fn truth, int n_views,
                           int res, double* psnr, double* rmse);

// Mean angle (degrees) between the fit's and the truth's shading normals (vertex normals interpolated
// and normalised; a mesh without normals gets area-weighted ones) over the pixels both cover, seen
// from the albedo measure's n_views views at res × res. What the relit images show of a bumpy
// surface that Chamfer, a distance, hardly sees. *covered (may be NULL): pixels measured.
mlb_status mlb_eval_normals(const mlb_mesh* truth, const mlb_mesh* fit, int n_views, int res, double* mean_deg,
                            size_t* covered);

// Renders truth (mesh + per-vertex BRDF [V,7]) and fit (the same for the fit, or, when fit_material is
// set, its material field at every pixel's surface point, as the baked asset shows it) under `light` from
// n_views orbit views (azimuths spread evenly from azimuth0_deg, elevations −15°, 20°, 50° in turn,
// radius 3, fovy 45°,
// 2× supersampling), sRGB composited over black. *psnr over every pixel of every view. images (may
// be NULL) receives [2 · n_views, res, res, 3]: the truth's views, then the fit's.
mlb_status mlb_eval_relight(const mlb_mesh* truth, const float* truth_k, const mlb_mesh* fit, const float* fit_k,
                            mlb_material_fn fit_material, void* fit_user, const mlb_envlight* light, int n_views, double azimuth0_deg, int res, double* psnr,
                            float* images);

#endif
