// Writing a Stable Diffusion model in the diffusers folder layout (docs/sd_train.md): what `matlaber
// sd train` saves, so that the project's own model is read back by the very loaders a user's SD 1.5
// goes through (mlb_sd_model_load).
//
//   DIR/model_index.json, scheduler/scheduler_config.json     (DDIM, scaled-linear betas, epsilon)
//   DIR/tokenizer/merges.txt, vocab.json                      (CLIP byte-level BPE, a small vocabulary)
//   DIR/text_encoder/config.json, model.safetensors           (CLIPTextModel, SD1 variant)
//   DIR/unet/config.json, diffusion_pytorch_model.safetensors (UNet2DConditionModel)
//   DIR/vae/config.json, diffusion_pytorch_model.safetensors  (AutoencoderKL)
#ifndef MATLABER_SD_FOLDER_H
#define MATLABER_SD_FOLDER_H
#include <stdint.h>
#include "matlaber/error.h"
#include "matlaber/safetensors.h"
#include "matlaber/sd_model.h"
#include "matlaber/unet.h"
#include "matlaber/vae.h"

// A CLIP BPE tokenizer whose merges make each of `words` one token where BPE's rank order allows
// (a word's prefixes merged left to right, shared prefixes once); any other text still tokenises,
// byte by byte. Writes DIR/merges.txt and DIR/vocab.json (the tokens the merges give, as the
// loader checks). words: lower-case UTF-8 without spaces. Atomic per file.
mlb_status mlb_sd_write_tokenizer(const char* dir, const char* const* words, int n_words);

typedef struct {
    int vocab;       // rows of the token embedding (the tokenizer's vocabulary size)
    int width;       // W
    int layers;
    int heads;
    int mlp;         // hidden width of the MLP
    uint64_t seed;   // Philox seed of the values
} mlb_text_encoder_shape;

// DIR/config.json + DIR/model.safetensors of a CLIP text encoder (SD1 variant: quick_gelu, output
// of the last layer + final LayerNorm, 77 positions) with random weights: token embeddings
// N(0, 1), positions N(0, 0.1^2), linear weights N(0, 1 / fan_in), biases 0, norms 1 and 0. Kept
// frozen by training: a fixed, distinct code per token that the UNet's cross-attention learns to read.
mlb_status mlb_text_encoder_write_random(const char* dir, const mlb_text_encoder_shape* shape);

// DIR/config.json + DIR/diffusion_pytorch_model.safetensors of a UNet on the host, its tensors
// stored as dtype (MLB_DT_F32, or MLB_DT_F16 / MLB_DT_BF16 rounded to nearest: half the file; the
// loaders convert back to float32).
mlb_status mlb_unet_save_folder(const mlb_unet* u, const char* dir, mlb_dtype dtype);

// DIR/model_index.json and DIR/scheduler/scheduler_config.json (SD's DDIM settings).
// geometry_suffix (NULL or "" for none): what the model's captions of normal renders add after the
// object ("_matlaber_geometry_suffix": diffusers skips keys that start with "_"); mlb_sd_model_load
// reads it back (mlb_sd_geometry_suffix_ok, sd_model.h).
mlb_status mlb_sd_write_index(const char* dir, const char* geometry_suffix);

#endif
