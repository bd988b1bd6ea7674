// matlaber sd tokenize: the Stable Diffusion side of the program (for now the CLIP tokenizer).
#include <cjson/cJSON.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cli.h"
#include "matlaber/log.h"
#include "matlaber/tokenizer.h"

static const cli_option tokenize_options[] = {
    {"tokenizer", 1, 't', "PATH", "CLIP merges .gz, tokenizer/ folder or model folder (default: $MATLABER_TOKENIZER)"},
    {"prompt", 1, 'p', "TEXT", "the text to tokenize (UTF-8); also -p"},
    {"pad", 1, 'P', "sd1|sd2", "padding: sd1 pads with 49407 (<|endoftext|>), sd2 with 0 (default sd1)"},
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

int cmd_sd(int argc, char** argv) {
    if (argc < 2 || strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0) {
        FILE* out = argc < 2 ? stderr : stdout;
        fprintf(out, "usage: matlaber sd <tokenize> [options]\n\n"
                     "  tokenize  text -> the 77 CLIP token ids of the SD text encoders\n");
        return argc < 2 ? EXIT_USAGE : 0;
    }
    const char* sub = argv[1];
    if (strcmp(sub, "tokenize") == 0) return tokenize_main(argc - 1, argv + 1);
    return cli_usage_error("sd", "unknown subcommand '%s'", sub);
}
