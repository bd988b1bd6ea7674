// The prompts file of generate --prompts (prompts.h): lines, comments and options as the command
// reads them, folder names that stay the same from version to version, and hostile files refused
// naming the file and the line: a NUL byte (once the silent end of the file), CR-only line ends
// (once one merged prompt), over-long prompts, values and names, invalid UTF-8, control bytes,
// unknown options (named only when they look like option names), repeated runs.
#include "matlaber/prompts.h"
#include "test.h"

static int arity(const char* name) {
    if (!strcmp(name, "seed") || !strcmp(name, "init") || !strcmp(name, "guidance-scale")) return 1;
    if (!strcmp(name, "fixed-env")) return 0;
    return -1;
}

static mlb_status parse(const char* text, size_t n, mlb_prompt_list* l) { return mlb_prompts_parse(text, n, "p.txt", arity, l); }

TEST(lines_options_and_names) {
    const char text[] = "\xEF\xBB\xBF# a comment, then a blank line\n\n  a gold goblet  \n--seed 2 a red mug\r\n"
                        "--name vase --fixed-env --guidance-scale=30 a blue vase\r--init torus\ta ring\n\t# indented comment\n";
    mlb_prompt_list l;
    REQUIRE(parse(text, sizeof text - 1, &l) == MLB_OK);
    REQUIRE(l.n == 4);
    CHECK(!strcmp(l.items[0].prompt, "a gold goblet") && l.items[0].n_opts == 0 && l.items[0].line == 3);
    // the folder names of runs written by earlier versions: a rerun skips or resumes them
    CHECK(!strcmp(l.items[0].name, "a-gold-goblet-2d3c54a6"));
    CHECK(!strcmp(l.items[1].name, "a-red-mug-ce0a118c") && l.items[1].n_opts == 2 && !strcmp(l.items[1].opts[1], "2"));
    CHECK(!strcmp(l.items[2].name, "vase") && l.items[2].n_opts == 2 && !strcmp(l.items[2].opts[0], "--fixed-env") &&
          !strcmp(l.items[2].opts[1], "--guidance-scale=30") && l.items[2].line == 5);
    CHECK(!strcmp(l.items[3].prompt, "a ring") && !strcmp(l.items[3].opts[1], "torus") && l.items[3].line == 6);
    mlb_prompts_free(&l);
    mlb_prompts_free(&l);   // twice: safe on a zeroed list
}

// each hostile file: refused, the list zeroed, the message naming the file, the line and the problem
static void refused(const char* what, const char* text, size_t n, const char* want) {
    mlb_prompt_list l;
    mlb_status s = parse(text, n, &l);
    CHECK_MSG(s == MLB_ERR_FORMAT && l.items == NULL && l.n == 0 && l.text == NULL, "%s: status %d", what, (int)s);
    CHECK_MSG(strncmp(mlb_last_error(), "p.txt: ", 7) == 0 && strstr(mlb_last_error(), want), "%s: '%s' lacks '%s'", what,
              mlb_last_error(), want);
}

TEST(hostile_files) {
    const char nul[] = "a gold goblet\n--seed 2 a red mug\0 --seed 3 a hidden line\n";
    refused("a NUL byte", nul, sizeof nul - 1, "line 2: a NUL byte at column 19");
    // CR-only line ends are line ends: two lines here, not one prompt "a\rb" (the same prompt twice: refused)
    refused("CR-only lines", "a gold goblet\ra gold goblet\r", 28, "lines 1 and 2 both make the run a-gold-goblet-2d3c54a6");
    char long_prompt[1200];
    memset(long_prompt, 'x', 1100);
    memcpy(long_prompt + 1100, "\n", 2);
    refused("a prompt of 1100 bytes", long_prompt, strlen(long_prompt), "line 1: a prompt of 1100 bytes (at most 1023)");
    // 1023 bytes of prompt, ending in a 2-byte character: accepted whole
    char edge[1100];
    memset(edge, 'y', 1021);
    memcpy(edge + 1021, "\xC3\xA9\n", 4);
    mlb_prompt_list l;
    REQUIRE(parse(edge, strlen(edge), &l) == MLB_OK);
    CHECK(strlen(l.items[0].prompt) == 1023);
    mlb_prompts_free(&l);
    char long_value[1200] = "--init ";
    memset(long_value + 7, 'v', 1030);
    memcpy(long_value + 1037, " a ring\n", 9);
    refused("a value of 1030 bytes", long_value, strlen(long_value), "line 1: the value of --init has 1030 bytes");
    char long_name[300] = "--name ";
    memset(long_name + 7, 'n', 200);
    memcpy(long_name + 207, " a ring\n", 9);
    refused("a name of 200 bytes", long_name, strlen(long_name), "--name: a folder name of 1..127 bytes");
    refused("invalid UTF-8", "a gold \xE9goblet\n", 15, "line 1: byte 0xE9 at column 8 is not valid UTF-8");
    refused("a truncated sequence at the end", "a gold goblet \xE2\x82", 16, "byte 0xE2 at column 15");
    refused("an escape sequence", "a \x1b[31mred\x1b[0m mug\n", 18, "line 1: control byte 0x1B at column 3");
    refused("an unknown option", "# c\n--bogus 1 x\n", 16, "line 2: --bogus is not an option a prompt line may set");
    refused("a password line as an option", "--root:x:0:0:root:/root:/bin/bash a\n", 36,
            "line 1: a word starting with -- that is not an option");
    CHECK(strstr(mlb_last_error(), "root:x") == NULL);   // nothing of the line quoted
    refused("an option without its value", "--seed\n", 7, "line 1: --seed needs a value");
    refused("options but no prompt", "--seed 3   \n", 12, "line 1: options but no prompt");
    refused("a name with a slash", "--name a/b x\n", 13, "--name: a folder name");
    refused("a hidden name", "--name .x x\n", 12, "--name: a folder name");
    refused("no prompt at all", "# only\n\n   \n", 12, "no prompt (3 lines)");
    refused("an empty file", "", 0, "no prompt (0 lines)");
    char many[1024] = "";
    for (int i = 0; i < 33; i++) strcat(many, "--seed 1 ");
    strcat(many, "x\n");
    refused("65 option words", many, strlen(many), "line 1: more than 64 option words");
}

// A repeated run is found by sorting, not pairwise: 100000 lines, the last repeating the 50000th
TEST(many_lines) {
    size_t cap = 100000 * 24, n = 0;
    char* text = malloc(cap);
    REQUIRE(text);
    for (int i = 0; i < 100000; i++) n += (size_t)snprintf(text + n, cap - n, "--name r%d p\n", i == 99999 ? 49999 : i);
    refused("a name given twice among 100000", text, n, "lines 50000 and 100000 both make the run r49999");
    free(text);
}

int main(void) {
    RUN(lines_options_and_names);
    RUN(hostile_files);
    RUN(many_lines);
    return test_summary();
}
