// Why cJSON refused a text (json_why.h).
#include "matlaber/json_why.h"
#include <cjson/cJSON.h>
#include <stdio.h>

const char* mlb_json_why(const char* text, size_t n, char* buf, size_t cap) {
    // the nesting depth outside strings: past cJSON's limit its parse fails without saying so
    size_t depth = 0;
    int in_string = 0;
    for (size_t i = 0; i < n; i++) {
        char c = text[i];
        if (in_string) {
            if (c == '\\') i++;
            else if (c == '"') in_string = 0;
        } else if (c == '"') in_string = 1;
        else if (c == '[' || c == '{') {
            if (++depth > CJSON_NESTING_LIMIT) {
                snprintf(buf, cap, "JSON nested more than %d levels deep (at byte %zu)", CJSON_NESTING_LIMIT, i);
                return buf;
            }
        } else if ((c == ']' || c == '}') && depth) depth--;
    }
    const char* at = cJSON_GetErrorPtr();
    if (at && at >= text && at <= text + n) snprintf(buf, cap, "a JSON syntax error at byte %zu", (size_t)(at - text));
    else snprintf(buf, cap, "not JSON text");
    return buf;
}
