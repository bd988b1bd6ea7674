// matlaber sd tokenize | txt2img: the Stable Diffusion side of the program (docs/tokenizer.md,
// docs/sds.md).
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include "cli.h"
#include "matlaber/caption.h"
#include "matlaber/fileio.h"
#include "matlaber/image_write.h"
#include "matlaber/log.h"
#include "matlaber/progress.h"
#include "matlaber/rng.h"
#include "matlaber/sd_model.h"
#include "matlaber/tokenizer.h"

static const cli_option tokenize_options[] = {
    {"tokenizer", 1, 't', "PATH", "CLIP merges .gz, tokenizer/ folder or model folder (default: $MATLABER_TOKENIZER)"},
    {"prompt", 1, 'p', "TEXT", "the text to tokenize (UTF-8); also -p"},
    {"pad", 1, 'P', "sd1|sd2", "padding: sd1 pads with <|endoftext|> (49407; the last id of a smaller vocabulary), sd2 with 0 (default sd1)"},
    {"max-length", 1, 'm', "N", "sequence length (default 77)"},
    {"no-fix-text", 0, 'F', NULL, "skip the ftfy subset (ligatures, full-width forms, curly quotes, NFC)"},
    {"json", 0, 'j', NULL, "print a JSON object: ids, token strings, counts"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

static int tokenize_main(int argc, char** argv) {
    const char* path = getenv("MATLABER_TOKENIZER");
    const char* prompt = NULL;
    const char* pad_name = "sd1";
    long max_len = MLB_CLIP_CONTEXT;
    int json = 0, fix_text = 1;
    const struct option* table = cli_getopt_table(tokenize_options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "hp:t:j", table, NULL)) != -1) {
        switch (c) {
        case 't': path = optarg; break;
        case 'p': prompt = optarg; break;
        case 'P':
            if (strcmp(optarg, "sd1") && strcmp(optarg, "sd2")) return cli_usage_error("sd tokenize", "--pad: expected sd1 or sd2, not '%s'", optarg);
            pad_name = optarg;
            break;
        case 'm':
            if (cli_parse_long(optarg, 2, 100000, &max_len)) return cli_usage_error("sd tokenize", "--max-length: expected 2..100000");
            break;
        case 'F': fix_text = 0; break;
        case 'j': json = 1; break;
        case 'h':
            printf("usage: matlaber sd tokenize --tokenizer PATH -p TEXT [--pad sd1|sd2] [--json]\n\n"
                   "Encodes TEXT with the CLIP BPE tokenizer of the Stable Diffusion text encoders: <|startoftext|>\n"
                   "(49406), the text's tokens, <|endoftext|> (49407), padded to 77 ids; longer texts are cut and\n"
                   "keep the end token. Prints the ids and the count before padding (docs/tokenizer.md).\n\n");
            cli_print_options(stdout, tokenize_options);
            return 0;
        default: return cli_usage_error("sd tokenize", "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error("sd tokenize", "unexpected argument '%s' (the text goes after -p)", argv[optind]);
    if (!path || !*path)
        return cli_usage_error("sd tokenize", "--tokenizer PATH is needed (the CLIP merges .gz, a tokenizer/ folder or a model folder)");
    if (!prompt) return cli_usage_error("sd tokenize", "-p TEXT is needed");
    int pad_id;
    mlb_tokenizer_pad_id(pad_name, &pad_id);

    mlb_tokenizer* tok;
    mlb_status s = mlb_tokenizer_load(path, &tok);
    if (s) return cli_fail(s, "loading the tokenizer");
    if (!fix_text) mlb_tokenizer_set_flags(tok, mlb_tokenizer_flags(tok) & ~(unsigned)MLB_TOKENIZER_FIX_TEXT);
    // SD1 pads with <|endoftext|>: the last id of a vocabulary smaller than CLIP's (the project's
    // own model's), as mlb_sd_model_load pads it
    if (!strcmp(pad_name, "sd1")) pad_id = mlb_tokenizer_eos(tok);
    int* ids = malloc((size_t)max_len * sizeof *ids);
    int* all = NULL;
    size_t n_all = 0;
    int n_used = 0;
    if (!ids) { mlb_tokenizer_free(tok); fprintf(stderr, "matlaber: error: out of memory\n"); return 1; }
    s = mlb_tokenizer_encode(tok, prompt, ids, (int)max_len, pad_id, &n_used);
    if (!s) s = mlb_tokenizer_tokenize(tok, prompt, &all, &n_all);
    if (s) { free(ids); mlb_tokenizer_free(tok); return cli_fail(s, "tokenizing the prompt"); }
    int truncated = n_all > (size_t)max_len - 2;
    if (truncated)
        mlb_log(MLB_LOG_WARN, "the prompt has %zu tokens; the sequence keeps the first %ld and the end token", n_all, max_len - 2);
    if (json) {
        cJSON* o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "tokenizer", mlb_tokenizer_source(tok));
        cJSON_AddStringToObject(o, "prompt", prompt);
        cJSON_AddStringToObject(o, "pad", pad_name);
        cJSON_AddNumberToObject(o, "pad_id", pad_id);
        cJSON_AddNumberToObject(o, "length", (double)max_len);
        cJSON_AddNumberToObject(o, "n_tokens", n_used);
        cJSON_AddNumberToObject(o, "n_text_tokens", (double)n_all);
        cJSON_AddBoolToObject(o, "truncated", truncated);
        cJSON* a = cJSON_AddArrayToObject(o, "ids");
        for (long i = 0; i < max_len; i++) cJSON_AddItemToArray(a, cJSON_CreateNumber(ids[i]));
        cJSON* t = cJSON_AddArrayToObject(o, "tokens");
        for (int i = 0; i < n_used; i++) cJSON_AddItemToArray(t, cJSON_CreateString(mlb_tokenizer_token(tok, ids[i])));
        char* text = cJSON_Print(o);
        printf("%s\n", text);
        free(text);
        cJSON_Delete(o);
    } else {
        printf("tokenizer: %s\n", mlb_tokenizer_source(tok));
        printf("tokens: %d before padding (start + %d + end%s), %ld in all, padded with %d (%s)\n", n_used, n_used - 2,
               truncated ? ", truncated" : "", max_len, pad_id, pad_name);
        printf("ids:");
        for (long i = 0; i < max_len; i++) printf(" %d", ids[i]);
        printf("\n");
    }
    free(ids);
    free(all);
    mlb_tokenizer_free(tok);
    return 0;
}


// ---- txt2img ------------------------------------------------------------------------------------
static const cli_option txt2img_options[] = {
    {"model", 1, 'm', "PATH", "diffusers model folder or single-file .safetensors checkpoint (default: the project's own model, models/matlaber-tiny or $MATLABER_MODEL)"},
    {"prompt", 1, 'p', "TEXT", "the prompt (the project's own model reads only the catalogue's captions, written in any of\n"
                               "                           their usual ways, and a view suffix: docs/catalogue.md)"},
    {"negative", 1, 'n', "TEXT", "negative prompt (replaces the empty unconditional prompt)"},
    {"steps", 1, 'S', "N", "DDIM steps, 1..999 (default 30)"},
    {"cfg", 1, 'c', "S", "classifier-free guidance scale (default 7.5; 3 with the project's own model)"},
    {"seed", 1, 's', "N", "seed of the initial noise (default 0)"},
    {"size", 1, 'z', "N", "image width and height, a multiple of 64 (default 512; 128, what it was trained at, with the project's own model)"},
    {"tokenizer", 1, 't', "PATH", "CLIP tokenizer (default: the model folder's tokenizer/, else $MATLABER_TOKENIZER)"},
    {"v-prediction", 1, 'v', "auto|on|off", "the UNet predicts v (default auto: from the configs)"},
    {"output", 1, 'o', "FILE.png", "output PNG (the name must end in .png)"},
    {"help", 0, 'h', NULL, "this help"},
    {0, 0, 0, 0, 0}};

#define TXT2IMG_NOISE_STREAM 0x7E1700000000ull

static int txt2img_main(int argc, char** argv) {
    const char *model_path = NULL, *prompt = NULL, *negative = "", *out_path = NULL;
    const char* tok_path = NULL;
    long steps = 30, seed = 0, size = -1;
    double cfg = NAN;
    int vpred = -1;
    const struct option* table = cli_getopt_table(txt2img_options);
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "hm:p:n:o:s:t:", table, NULL)) != -1) {
        switch (c) {
        case 'm': model_path = optarg; break;
        case 'p': prompt = optarg; break;
        case 'n': negative = optarg; break;
        case 'o': out_path = optarg; break;
        case 't': tok_path = optarg; break;
        case 'S':
            if (cli_parse_long(optarg, 1, MLB_DDIM_MAX_STEPS, &steps))
                return cli_usage_error("sd txt2img", "--steps: expected 1..%d", MLB_DDIM_MAX_STEPS);
            break;
        case 'c':
            if (cli_parse_double(optarg, -1000, 1000, &cfg)) return cli_usage_error("sd txt2img", "--cfg: expected a number in [-1000, 1000]");
            break;
        case 's':
            if (cli_parse_long(optarg, 0, 0x7fffffffffffffffL, &seed)) return cli_usage_error("sd txt2img", "--seed: expected a non-negative integer");
            break;
        case 'z':
            if (cli_parse_long(optarg, 64, 4096, &size) || size % 64)
                return cli_usage_error("sd txt2img", "--size: expected a multiple of 64 in 64..4096");
            break;
        case 'v':
            if (!strcmp(optarg, "auto")) vpred = -1;
            else if (!strcmp(optarg, "on")) vpred = 1;
            else if (!strcmp(optarg, "off")) vpred = 0;
            else return cli_usage_error("sd txt2img", "--v-prediction: expected auto, on or off");
            break;
        case 'h':
            printf("usage: matlaber sd txt2img [-m MODEL] -p PROMPT [--negative TEXT] [--steps 30] [--cfg 7.5] [--seed S]\n"
                   "                           [--size 512] [--tokenizer PATH] -o out.png\n\n"
                   "Samples an image with Stable Diffusion: DDIM (eta 0) with classifier-free guidance, then the VAE\n"
                   "decoder. MODEL is a diffusers folder or a single-file .safetensors checkpoint (F32/F16/BF16;\n"
                   "pickle .ckpt files must be converted first). docs/sds.md.\n\n");
            cli_print_options(stdout, txt2img_options);
            return 0;
        default: return cli_usage_error("sd txt2img", "unknown option");
        }
    }
    if (optind < argc) return cli_usage_error("sd txt2img", "unexpected argument '%s'", argv[optind]);
    if (!model_path) {
        // The project's own model (docs/sd_train.md): sampled at the size it was trained at, with the
        // guidance scale its samples were judged at, unless told otherwise.
        // The one that draws shaded objects: the appearance stage's when it is there
        model_path = cli_default_appearance_model();
        if (!model_path && !(model_path = cli_default_model()))
            return cli_usage_error("sd txt2img", "-m MODEL is needed: the project's own model is not there (train it: matlaber sd "
                                   "train -o models/%s; docs/sd_train.md)", MLB_DEFAULT_MODEL);
        if (size < 0) size = 128;
        if (isnan(cfg)) cfg = 3;
    }
    if (size < 0) size = 512;
    if (isnan(cfg)) cfg = 7.5;
    if (!prompt) return cli_usage_error("sd txt2img", "-p PROMPT is needed");
    if (!out_path) return cli_usage_error("sd txt2img", "-o out.png is needed");
    size_t on = strlen(out_path);   // the bytes are PNG: a name that says otherwise is refused, not written
    if (on < 5 || strcasecmp(out_path + on - 4, ".png"))
        return cli_usage_error("sd txt2img", "-o %s: the image is written as PNG: give a name ending in .png", out_path);
    mlb_status ws = mlb_check_writable(out_path);   // before the sampling, not after it
    if (ws) return cli_fail(ws, "sd txt2img -o");
    // the project's own models read only their catalogue's captions (caption.h): the prompt read
    // into one (a view suffix kept), or refused naming the words they never saw
    mlb_caption_reading reading = {0};
    if (mlb_sd_model_is_own(model_path)) {
        if (mlb_caption_read(prompt, &reading)) return cli_usage_error("sd txt2img", "%s", mlb_last_error());
        if (strcmp(reading.caption, prompt))
            mlb_log(MLB_LOG_INFO, "the prompt '%s' read as '%s' (the project's own model)", prompt, reading.caption);
        prompt = reading.caption;
    }
    mlb_sd_model_options mo = mlb_sd_model_default_options();
    mo.tokenizer_path = tok_path;
    mo.v_prediction = vpred;
    mo.device = mlb_device_current();   // the program's --device and --precision
    mo.precision = mlb_gemm_precision_current();
    double t0 = mlb_now_seconds();
    mlb_sd_model* m;
    mlb_status s = mlb_sd_model_load(model_path, &mo, &m);
    if (s) return cli_fail(s, "loading the model");
    mlb_log(MLB_LOG_INFO, "model: %s (%.1fs)", m->source, mlb_now_seconds() - t0);
    if (reading.normal_map && strcmp(m->geometry_suffix, MLB_CAPTION_NORMAL_MAP)) {
        mlb_sd_model_free(m);
        return cli_usage_error("sd txt2img", "'%s' asks for a normal map, and %s was not trained with normal-map captions "
                               "(its model_index.json names no \"_matlaber_geometry_suffix\")", prompt, model_path);
    }
    const int Dc = mlb_sd_model_context_width(m), T = MLB_CLIP_CONTEXT;
    const int h = (int)size / 8;
    const size_t n = (size_t)m->unet->cfg.in_channels * h * h;
    float* ctx = malloc(2 * (size_t)T * Dc * sizeof(float));
    float* latent = malloc(n * sizeof(float));
    float* img = malloc(3 * (size_t)size * size * sizeof(float));
    float* rgb = malloc(3 * (size_t)size * size * sizeof(float));
    int rc = 0;
    if (!ctx || !latent || !img || !rgb) { rc = cli_fail(mlb_fail(MLB_ERR_NOMEM, "out of memory"), "txt2img"); goto done; }
    double stage = mlb_now_seconds();
    if ((s = mlb_sd_model_encode_prompt(m, negative, ctx)) || (s = mlb_sd_model_encode_prompt(m, prompt, ctx + (size_t)T * Dc))) {
        rc = cli_fail(s, "encoding the prompt");
        goto done;
    }
    mlb_log(MLB_LOG_INFO, "prompts encoded (%.2fs)", mlb_now_seconds() - stage);
    mlb_sd_model_drop_text(m);
    mlb_rng_fill_normal(latent, n, (uint64_t)seed, TXT2IMG_NOISE_STREAM, 0, 0.0f, 1.0f);
    mlb_progress pr;
    mlb_progress_begin(&pr, mlb_log_get_level() <= MLB_LOG_INFO ? stderr : NULL, "txt2img", steps, "step");
    s = mlb_sd_ddim_sample(m->unet, m->alphas_cumprod, m->v_prediction, ctx, ctx + (size_t)T * Dc, T, latent, h, h, (int)steps,
                           (float)cfg, NULL, NULL, &pr);
    mlb_progress_end(&pr, NULL);
    if (s) { rc = cli_fail(s, "sampling"); goto done; }
    mlb_sd_model_drop_unet(m);
    stage = mlb_now_seconds();
    if ((s = mlb_sd_decode_latent(m->vae, m->scaling_factor, latent, h, h, img))) { rc = cli_fail(s, "decoding the latent"); goto done; }
    mlb_log(MLB_LOG_INFO, "latent decoded (%.2fs)", mlb_now_seconds() - stage);
    const size_t hw = (size_t)size * size;
    for (size_t i = 0; i < hw; i++)
        for (int ch = 0; ch < 3; ch++) {
            float v = 0.5f * img[ch * hw + i] + 0.5f;
            rgb[3 * i + ch] = v < 0 ? 0 : v > 1 ? 1 : v;
        }
    if ((s = mlb_image_write_png(out_path, rgb, (int)size, (int)size, 3, NULL))) { rc = cli_fail(s, "writing the image"); goto done; }
    mlb_log(MLB_LOG_INFO, "wrote %s (%ldx%ld, %ld steps, cfg %g, seed %ld) in %.1fs", out_path, size, size, steps, cfg, seed,
            mlb_now_seconds() - t0);
done:
    free(ctx); free(latent); free(img); free(rgb);
    mlb_sd_model_free(m);
    return rc;
}

int cmd_sd(int argc, char** argv) {
    if (argc < 2 || strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0) {
        FILE* out = argc < 2 ? stderr : stdout;
        fprintf(out, "usage: matlaber sd <tokenize|txt2img|train> [options]\n\n"
                     "  tokenize  text -> the 77 CLIP token ids of the SD text encoders\n"
                     "  txt2img   text -> image: DDIM sampling with classifier-free guidance\n"
                     "  train     the project's own small model, trained on the procedural catalogue\n");
        return argc < 2 ? EXIT_USAGE : 0;
    }
    const char* sub = argv[1];
    if (strcmp(sub, "tokenize") == 0) return tokenize_main(argc - 1, argv + 1);
    if (strcmp(sub, "txt2img") == 0) return txt2img_main(argc - 1, argv + 1);
    if (strcmp(sub, "train") == 0) return sd_train_main(argc - 1, argv + 1);
    return cli_usage_error("sd", "unknown subcommand '%s'", sub);
}
