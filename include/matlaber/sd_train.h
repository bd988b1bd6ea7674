// Training the project's own small Stable Diffusion model on the procedural catalogue
// (docs/sd_train.md): `matlaber sd train`. The model has SD's layout (CLIP tokenizer, CLIP text
// encoder, UNet with cross-attention, AutoencoderKL) at a size that trains on 2 cores, and is written
// as a diffusers folder that mlb_sd_model_load reads like a user's SD 1.5.
//
// Data: catalogue renders (catalogue.h) of the training class x material pairs from the pipeline's
// own orbit cameras and lights, in the three forms the pipeline hands the guidance:
//   appearance   rgb [3, R, R]: the shaded colour over black (the appearance stage, through the VAE)
//   geometry     0.5 (n·α + α) [3, R, R]: the normal render (the geometry stage's VAE phase)
//   latent phase the area resize of [n·α, α] to [4, R/8, R/8], used as a latent as it is
// captioned "a {material} {class}" (appearance) or "a {material} {class}, normal map" (geometry, latent
// phase) with the view suffix of the camera (or none, or empty).
//
// Steps: (1) the dataset is rendered once (deterministic per sample); (2) a frozen random text
// encoder and a tokenizer over the catalogue's words are written; (3) the VAE is trained
// (reconstruction + KL) on appearance and geometry images; (4) the latent scale is set so the
// appearance latents have unit variance; (5) the UNet is trained to predict the noise (SD's
// scaled-linear schedule, uniform t, the caption dropped for classifier-free guidance).
// Every op goes through the backend `be` (the CPU's tables or CUDA's); the losses are evaluated
// on the host. Deterministic: the same bits on any thread count; --resume continues bitwise.
#ifndef MATLABER_SD_TRAIN_H
#define MATLABER_SD_TRAIN_H
#include <stdint.h>
#include "matlaber/backend.h"
#include "matlaber/caption.h"
#include "matlaber/error.h"
#include "matlaber/progress.h"
#include "matlaber/sd_folder.h"
#include "matlaber/unet.h"
#include "matlaber/vae.h"

// ---- the dataset ----
typedef struct {
    int n, res, lat;     // samples, image size, latent size (res / 8)
    uint8_t* rgb;        // [n, 3, res, res] appearance image, value · 255 rounded
    uint8_t* geo;        // [n, 3, res, res] geometry image 0.5 (n·α + α), · 255 rounded
    float* lat_geo;      // [n, 4, lat, lat] latent-phase input: area resize of [n·α, α]
    int* cls;            // [n]
    int* mat;            // [n]
    int* view;           // [n] mlb_sds_view_for of the camera (MLB_SDS_VIEW_FRONT ..)
} mlb_sd_dataset;

// Renders samples 0 .. n-1 of data set `seed` (mlb_catalogue_sample_draw, training pairs only) at
// res x res (a multiple of 8), in parallel. progress may be NULL.
mlb_status mlb_sd_dataset_render(mlb_sd_dataset* d, int n, int res, uint64_t seed, mlb_progress* progress);
void mlb_sd_dataset_free(mlb_sd_dataset* d);
// The geometry images' (and latent-phase inputs') captions carry this after the object's name, before
// the view suffix: "a gold goblet, normal map, front view". With one caption for both forms the model
// learns a mixture of a shaded goblet and a normal map, and its samples and its score for a shaded
// render lean to the normal map's colours (the striped blue-green silver of docs/sd_train.md). The
// model folder names it (model_index.json "_matlaber_geometry_suffix", sd_folder.h) so that the
// geometry stage's guidance appends it (sd_model.h geometry_suffix).
#define MLB_SD_GEOMETRY_SUFFIX MLB_CAPTION_NORMAL_MAP   /* ", normal map": the caption reader reads it back */
// Caption index of (class, material, view in 0 .. MLB_SDS_N_VIEWS-1, geometry 0/1): the rows of the
// embedding table (after it: the unconditional prompts); the text of row 0 .. count-1.
int mlb_sd_caption_index(int cls, int mat, int view, int geometry);
int mlb_sd_caption_count(void);
void mlb_sd_caption_text(int row, char* out, size_t cap);

// ---- training ----
typedef struct {
    const char* out_dir;        // the model folder (diffusers layout); its train/ holds the state
    int res;                    // image size (128): latents res / 8
    int n_images;               // rendered samples (8000)
    uint64_t seed;
    mlb_text_encoder_shape text;   // vocab filled in from the tokenizer
    mlb_vae_config vae;
    int vae_steps, vae_batch;   // 0 steps: keep the VAE of a resumed state
    double vae_lr, vae_kl;      // Adam lr; KL weight (per latent element, relative to the per-pixel MSE)
    mlb_unet_config unet;       // context_dim = text.width
    int unet_steps, unet_batch;
    double unet_lr;
    float p_uncond;             // caption dropped to the empty prompt (0.1)
    float p_no_view;            // the view suffix dropped (0.2)
    float p_geo, p_latent;      // fractions of geometry-image and latent-phase examples (0.35, 0)
    int checkpoint_every;       // steps between state saves (500)
    mlb_dtype unet_dtype;       // the written UNet's tensors: MLB_DT_F16 (half the file; the state stays F32)
    const char* init_dir;       // a model folder whose VAE and UNet start the training (their configs
                                // replace vae and unet; the text side must be the same), or NULL
    int resume;                 // 1: continue from the states in out_dir/train/ (refused unless the
                                // options are those of out_dir/train/options.txt, the first run's)
    double time_limit;          // > 0: seconds for the whole run; after 20 steps of each phase its
                                // step count is cut to what fits (VAE a quarter of what is left,
                                // the UNet the rest). Runs cut so are not bitwise resumable.
    long stop_after;            // > 0: save the state and return after this many optimiser steps
                                // (VAE + UNet, counted from the start of training), the folder unfinished
} mlb_sd_train_config;

mlb_sd_train_config mlb_sd_train_default(void);
// MLB_ERR_ARG naming the bad field.
mlb_status mlb_sd_train_check(const mlb_sd_train_config* c);
// Trains and writes the model folder (atomically per file; the folder is complete once
// model_index.json exists). Logs progress with ETA; writes out_dir/train/loss.csv and loss.png.
mlb_status mlb_sd_train(const mlb_backend* be, const mlb_sd_train_config* c);

#endif
