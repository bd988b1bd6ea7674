// Why cJSON refused a text, for an error message that names the problem without quoting the text:
// "nested more than 1000 levels deep" (cJSON's limit) or "a syntax error at byte N".
#ifndef MATLABER_JSON_WHY_H
#define MATLABER_JSON_WHY_H
#include <stddef.h>

// Call right after cJSON_Parse* returned NULL for text[0..n) (cJSON's error position is global, as
// cJSON's own parsing state is). Writes into buf (cap >= 80) and returns it.
const char* mlb_json_why(const char* text, size_t n, char* buf, size_t cap);

#endif
