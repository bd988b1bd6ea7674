// matlaber sd train: the project's own small diffusion model, trained on the procedural catalogue
// (include/matlaber/sd_train.h, docs/sd_train.md).
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cli.h"
#include "matlaber/backend.h"
#include "matlaber/device.h"
#include "matlaber/log.h"
#include "matlaber/nn.h"
#include "matlaber/sd_train.h"

static const cli_option train_options[] = {
    {"output", 1, 'o', "DIR", "the model folder to write (diffusers layout; DIR/train/ holds the state and the loss)"},
    {"images", 1, 'n', "N", "catalogue images rendered for training (default 8000)"},
    {"res", 1, 'r', "R", "image size, a multiple of 32; latents R/8 (default 128)"},
    {"vae-steps", 1, 'V', "N", "VAE optimiser steps (default 3000)"},
    {"unet-steps", 1, 'U', "N", "UNet optimiser steps (default 20000)"},
    {"vae-batch", 1, 'b', "N", "VAE batch (default 16)"},
    {"unet-batch", 1, 'B', "N", "UNet batch (default 32)"},
    {"vae-lr", 1, 'l', "LR", "VAE learning rate (default 1e-3)"},
    {"unet-lr", 1, 'L', "LR", "UNet learning rate (default 5e-4)"},
    {"seed", 1, 's', "N", "seed of the data, the weights and the noise (default 1)"},
    {"checkpoint-every", 1, 'c', "N", "steps between saved states (default 500)"},
    {"p-geo", 1, 'G', "P", "UNet examples that are geometry (normal) images (default 0.35)"},
    {"p-latent", 1, 'A', "P", "UNet examples that are latent-phase [normal, mask] inputs (default 0)"},
    {"time-limit", 1, 'm', "SECONDS", "cut each phase's steps to what fits (a quarter of the time for the VAE)"},
    {"tiny", 0, 'T', NULL, "a very small model (tests): VAE 8-16 channels, UNet 32-64"},
    {"init", 1, 'I', "DIR", "start from the VAE and UNet of a model folder (e.g. --vae-steps 0 to keep its VAE)"},
    {"resume", 0, 'R', NULL, "continue from DIR/train/ with the first run's options (checked: DIR/train/options.txt)"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

int sd_train_main(int argc, char** argv) {
    mlb_sd_train_config c = mlb_sd_train_default();
    long v;
    double x;
    const struct option* table = cli_getopt_table(train_options);
    optind = 1;
    int o;
    while ((o = getopt_long(argc, argv, "ho:n:r:s:", table, NULL)) != -1) {
        switch (o) {
        case 'o': c.out_dir = optarg; break;
        case 'n': if (cli_parse_long(optarg, 1, 1000000, &v)) return cli_usage_error("sd train", "--images: 1..1000000"); c.n_images = (int)v; break;
        case 'r': if (cli_parse_long(optarg, 32, 512, &v) || v % 32) return cli_usage_error("sd train", "--res: a multiple of 32 in 32..512"); c.res = (int)v; break;
        case 'V': if (cli_parse_long(optarg, 0, 10000000, &v)) return cli_usage_error("sd train", "--vae-steps: 0..10000000"); c.vae_steps = (int)v; break;
        case 'U': if (cli_parse_long(optarg, 0, 10000000, &v)) return cli_usage_error("sd train", "--unet-steps: 0..10000000"); c.unet_steps = (int)v; break;
        case 'b': if (cli_parse_long(optarg, 1, 4096, &v)) return cli_usage_error("sd train", "--vae-batch: 1..4096"); c.vae_batch = (int)v; break;
        case 'B': if (cli_parse_long(optarg, 1, 64, &v)) return cli_usage_error("sd train", "--unet-batch: 1..64"); c.unet_batch = (int)v; break;
        case 'l': if (cli_parse_double(optarg, 1e-8, 1, &x)) return cli_usage_error("sd train", "--vae-lr: in (0, 1]"); c.vae_lr = x; break;
        case 'L': if (cli_parse_double(optarg, 1e-8, 1, &x)) return cli_usage_error("sd train", "--unet-lr: in (0, 1]"); c.unet_lr = x; break;
        case 's': if (cli_parse_long(optarg, 0, 0x7fffffffL, &v)) return cli_usage_error("sd train", "--seed: a non-negative integer"); c.seed = (uint64_t)v; break;
        case 'c': if (cli_parse_long(optarg, 1, 10000000, &v)) return cli_usage_error("sd train", "--checkpoint-every: 1..10000000"); c.checkpoint_every = (int)v; break;
        case 'T':
            c.vae.block_out[0] = 8; c.vae.block_out[1] = 16; c.vae.block_out[2] = 16; c.vae.block_out[3] = 16;
            c.vae.norm_groups = 4;
            c.unet.block_out[0] = 32; c.unet.block_out[1] = 64; c.unet.block_out[2] = 64;
            c.unet.heads[0] = c.unet.heads[1] = c.unet.heads[2] = c.unet.mid_heads = 2;
            c.unet.norm_groups = 16;
            c.unet.time_embed_dim = 64;
            c.text.width = c.unet.context_dim = 32;
            c.text.heads = 2;
            c.text.mlp = 64;
            break;
        case 'R': c.resume = 1; break;
        case 'I': c.init_dir = optarg; break;
        case 'G': if (cli_parse_double(optarg, 0, 1, &x)) return cli_usage_error("sd train", "--p-geo: in [0, 1]"); c.p_geo = (float)x; break;
        case 'A': if (cli_parse_double(optarg, 0, 1, &x)) return cli_usage_error("sd train", "--p-latent: in [0, 1]"); c.p_latent = (float)x; break;
        case 'm': if (cli_parse_double(optarg, 1, 1e7, &x)) return cli_usage_error("sd train", "--time-limit: seconds, 1..1e7"); c.time_limit = x; break;
        case 'h':
            printf("usage: matlaber sd train -o DIR [options]\n\n"
                   "Renders the procedural catalogue (matlaber catalogue list), writes a tokenizer and a frozen random\n"
                   "text encoder, trains the VAE and then the UNet, and writes DIR as a diffusers model folder that\n"
                   "`sd txt2img -m DIR` and `generate -m DIR` read like a user's SD 1.5. Runs on --device; on a CPU\n"
                   "with AVX-512 BF16 with bf16 GEMM operands (fp32 sums and weights) unless --precision says fp32.\n\n");
            cli_print_options(stdout, train_options);
            return 0;
        default: return cli_usage_error("sd train", "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error("sd train", "unexpected argument '%s'", argv[optind]);
    if (!c.out_dir) return cli_usage_error("sd train", "-o DIR is needed");
    // A CPU with AVX-512 BF16 trains with bf16 GEMM operands (fp32 sums, fp32 weights and moments:
    // 1.8x a step, docs/sd_train.md) unless --precision names another; the bits then differ from an
    // fp32 machine's, and a --resume on another CPU continues in that CPU's precision.
    mlb_gemm_precision prec = mlb_gemm_precision_current();
    if (mlb_device_current() == MLB_DEVICE_CPU && !mlb_gemm_precision_chosen() && mlb_gemm_bf16_native()) prec = MLB_GEMM_BF16;
    const mlb_backend* be = mlb_backend_for(mlb_device_current(), prec);
    mlb_log(MLB_LOG_INFO, "sd train: on the %s, GEMMs in %s", mlb_device_name(be->device), mlb_gemm_precision_name(be->precision));
    mlb_status s = mlb_sd_train(be, &c);
    if (s) return cli_fail(s, "sd train");
    return 0;
}
