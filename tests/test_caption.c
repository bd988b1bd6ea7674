// What the project's own model reads (include/matlaber/caption.h): the ways people write a caption
// read into the catalogue's, unknown words named, and the benchmark's phrasings read back.
#include "matlaber/caption.h"
#include "matlaber/catalogue.h"
#include "matlaber/error.h"
#include "matlaber/sds.h"
#include "test.h"

// prompt reads as caption (and nothing is unknown)
static int reads_as(const char* prompt, const char* caption) {
    mlb_caption_reading r;
    mlb_status s = mlb_caption_read(prompt, &r);
    if (s || strcmp(r.caption, caption)) {
        printf("  '%s' read as '%s' (status %d: %s), expected '%s'\n", prompt, r.caption, (int)s, s ? mlb_last_error() : "",
               caption);
        return 0;
    }
    return r.n_unknown == 0;
}

TEST(the_issues_phrasings) {
    // "golden", "gold-coloured", "made of gold", "a mug of copper", "a copper coffee mug", with or
    // without the article, capitals and a full stop
    const char* gold[] = {"a gold goblet", "a golden goblet", "A golden goblet.", "a gold-coloured goblet",
                          "a gold-colored goblet", "a goblet made of gold", "a goblet made from gold", "golden goblet",
                          "Gold Goblet", "THE GOLDEN GOBLET!", "  a   gilded\tchalice ", "a goblet in gold", "an goblet of gold",
                          "a goblet, made out of gold."};
    for (size_t i = 0; i < sizeof gold / sizeof *gold; i++) CHECK_MSG(reads_as(gold[i], "a gold goblet"), "%s", gold[i]);
    const char* copper[] = {"a mug of copper", "a copper coffee mug", "Copper mug.", "a coppery mug", "the copper-coloured coffee mug"};
    for (size_t i = 0; i < sizeof copper / sizeof *copper; i++) CHECK_MSG(reads_as(copper[i], "a copper mug"), "%s", copper[i]);
    CHECK(reads_as("a crimson tea pot", "a red teapot"));
    CHECK(reads_as("a cobalt flower vase", "a blue vase"));
    CHECK(reads_as("a stony toadstool", "a stone mushroom"));
    // a two-word class wins over its one-word reading: a table lamp is a lamp, not a table
    CHECK(reads_as("a white table lamp", "a white lamp"));
    CHECK(reads_as("a white dining table", "a white table"));
    // the same material or class twice is one
    CHECK(reads_as("a gold golden goblet", "a gold goblet"));
    // no material named: the class alone
    mlb_caption_reading r;
    CHECK(mlb_caption_read("A goblet.", &r) == MLB_OK && r.cls == 0 && r.mat == -1 && !strcmp(r.caption, "a goblet"));
    // a view suffix is read (sd txt2img draws it; generate refuses it: test_pipeline)
    CHECK(mlb_caption_read("a golden goblet, side view", &r) == MLB_OK && r.view == MLB_SDS_VIEW_SIDE &&
          !strcmp(r.caption, "a gold goblet, side view"));
    // the geometry captions' suffix, read back where sd train writes it (before the view's)
    CHECK(mlb_caption_read("A golden goblet normal map, front view", &r) == MLB_OK && r.normal_map &&
          r.view == MLB_SDS_VIEW_FRONT && !strcmp(r.caption, "a gold goblet, normal map, front view"));
    CHECK(reads_as("a goblet, normal map", "a goblet, normal map"));
    CHECK(mlb_caption_read("a gold goblet", &r) == MLB_OK && !r.normal_map);
    CHECK(mlb_caption_read("a gold goblet, normal", &r) == MLB_ERR_ARG);   // "normal" alone is no caption's
}

TEST(every_catalogue_caption_reads_as_itself) {
    char cap[96];
    for (int c = 0; c < mlb_catalogue_n_classes(); c++)
        for (int m = 0; m < mlb_catalogue_n_materials(); m++)
            for (int v = MLB_SDS_VIEW_NONE; v < MLB_SDS_N_VIEWS; v++) {
                mlb_catalogue_caption(c, m, v, cap, sizeof cap);
                mlb_caption_reading r;
                CHECK_MSG(mlb_caption_read(cap, &r) == MLB_OK && r.cls == c && r.mat == m && r.view == v && !strcmp(r.caption, cap),
                          "%s", cap);
            }
}

// The benchmark's held-out phrasings: each differs from the catalogue's caption and reads back to it.
TEST(phrasings_read_back) {
    char cap[96], ph[128];
    int forms_met[MLB_CAPTION_N_PHRASINGS + 1] = {0};
    for (int c = 0; c < mlb_catalogue_n_classes(); c++)
        for (int m = 0; m < mlb_catalogue_n_materials(); m++) {
            mlb_catalogue_caption(c, m, MLB_SDS_VIEW_NONE, cap, sizeof cap);
            for (int k = 0; k <= MLB_CAPTION_N_PHRASINGS; k++) {
                mlb_caption_phrase(c, m, k, ph, sizeof ph);
                CHECK_MSG(k == 0 ? !strcmp(ph, cap) : strcmp(ph, cap) != 0, "form %d of %s: '%s'", k, cap, ph);
                mlb_caption_reading r;
                CHECK_MSG(mlb_caption_read(ph, &r) == MLB_OK && r.cls == c && r.mat == m && !strcmp(r.caption, cap),
                          "'%s' read as '%s'", ph, r.caption);
            }
            int f = mlb_caption_phrasing_form(MLB_CAPTION_PHRASING_MIXED, c, m);
            CHECK(f >= 1 && f <= MLB_CAPTION_N_PHRASINGS);
            if (f >= 1 && f <= MLB_CAPTION_N_PHRASINGS) forms_met[f] = 1;
            CHECK(mlb_caption_phrasing_form(3, c, m) == 3 && mlb_caption_phrasing_form(0, c, m) == 0);
        }
    for (int k = 1; k <= MLB_CAPTION_N_PHRASINGS; k++) CHECK_MSG(forms_met[k], "mixed never uses form %d", k);
    mlb_caption_phrase(3, 2, 1, ph, sizeof ph);
    CHECK(!strcmp(ph, "A coppery mug."));
    mlb_caption_phrase(3, 2, 4, ph, sizeof ph);
    CHECK(!strcmp(ph, "Copper coffee mug"));
    mlb_caption_phrase(3, 2, 5, ph, sizeof ph);
    CHECK(!strcmp(ph, "a mug of copper"));
    mlb_caption_phrase(3, 3, 2, ph, sizeof ph);
    CHECK(!strcmp(ph, "a mug in red"));
}

TEST(unknown_words_named) {
    mlb_caption_reading r;
    CHECK(mlb_caption_read("a wooden chair", &r) == MLB_ERR_ARG);
    CHECK(r.cls == -1 && r.n_unknown == 2 && !strcmp(r.unknown[0], "wooden") && !strcmp(r.unknown[1], "chair"));
    CHECK(r.caption[0] == 0);
    const char* e = mlb_last_error();
    CHECK(strstr(e, "'wooden', 'chair'") != NULL);
    CHECK(strstr(e, "names none of its objects") != NULL);
    CHECK(strstr(e, mlb_catalogue_class_list()) != NULL && strstr(e, mlb_catalogue_material_list()) != NULL);
    CHECK(strstr(e, "-m MODEL") != NULL);
    // a known class with a word the model never saw: refused, the word named as typed, once
    CHECK(mlb_caption_read("A Shiny gold goblet, shiny!", &r) == MLB_ERR_ARG);
    CHECK(r.cls == 0 && r.mat == 0 && r.n_unknown == 1 && !strcmp(r.unknown[0], "Shiny") && !r.more_unknown);
    CHECK(strstr(mlb_last_error(), "the word 'Shiny'") != NULL);
    CHECK(strstr(mlb_last_error(), "names none") == NULL);
    // words whose meaning is not the catalogue's own are not guessed
    CHECK(mlb_caption_read("a red cup", &r) == MLB_ERR_ARG && r.n_unknown == 1 && !strcmp(r.unknown[0], "cup"));
    CHECK(mlb_caption_read("a grey pot", &r) == MLB_ERR_ARG && r.n_unknown == 2);
    CHECK(mlb_caption_read("gold goblets", &r) == MLB_ERR_ARG && !strcmp(r.unknown[0], "goblets"));
    CHECK(mlb_caption_read("a café goblet", &r) == MLB_ERR_ARG && !strcmp(r.unknown[0], "café"));
    CHECK(mlb_caption_read("a 2 gold goblet", &r) == MLB_ERR_ARG && !strcmp(r.unknown[0], "2"));
    // many: the first 8 named, the rest said
    CHECK(mlb_caption_read("one two three four five six seven eight nine goblet", &r) == MLB_ERR_ARG);
    CHECK(r.n_unknown == MLB_CAPTION_MAX_UNKNOWN && r.more_unknown && !strcmp(r.unknown[7], "eight"));
    CHECK(strstr(mlb_last_error(), "'eight', and more") != NULL);
    // a long word is kept cut, at a character boundary
    char longw[200] = "a x";   // x, then two-byte characters: the cut falls inside one
    for (int i = 0; i < 60; i++) strcat(longw, "\xc3\xa9");   // é x 60: 120 bytes
    strcat(longw, " goblet");
    CHECK(mlb_caption_read(longw, &r) == MLB_ERR_ARG && r.n_unknown == 1);
    size_t n = strlen(r.unknown[0]);
    CHECK(n < MLB_CAPTION_WORD && n > 3 && !strcmp(r.unknown[0] + n - 3, "...") && (n - 4) % 2 == 0);
}

TEST(nothing_or_too_much) {
    mlb_caption_reading r;
    CHECK(mlb_caption_read("", &r) == MLB_ERR_ARG && r.cls == -1 && r.n_unknown == 0);
    CHECK(strstr(mlb_last_error(), "names none of its objects") != NULL);
    CHECK(mlb_caption_read(" ... ", &r) == MLB_ERR_ARG && r.cls == -1);
    CHECK(mlb_caption_read(NULL, &r) == MLB_ERR_ARG);
    CHECK(mlb_caption_read("gold", &r) == MLB_ERR_ARG && r.mat == 0 && r.cls == -1);
    CHECK(mlb_caption_read("a gold goblet on a red table", &r) == MLB_ERR_ARG);
    CHECK(r.cls == 0 && r.second_cls == 6 && r.mat == 0 && r.second_mat == 3 && r.n_unknown == 1 && !strcmp(r.unknown[0], "on"));
    CHECK(strstr(mlb_last_error(), "two objects (goblet, table)") != NULL);
    CHECK(strstr(mlb_last_error(), "two materials (gold, red)") != NULL);
    CHECK(mlb_caption_read("a goblet, front view, back view", &r) == MLB_ERR_ARG);
    CHECK(strstr(mlb_last_error(), "two views") != NULL);
}

int main(void) {
    RUN(the_issues_phrasings);
    RUN(every_catalogue_caption_reads_as_itself);
    RUN(phrasings_read_back);
    RUN(unknown_words_named);
    RUN(nothing_or_too_much);
    return test_summary();
}
