// Levelled logging through a sink the program installs. With no sink the library is silent.
#ifndef MATLABER_LOG_H
#define MATLABER_LOG_H
#include <stdio.h>

typedef enum { MLB_LOG_DEBUG = 0, MLB_LOG_INFO, MLB_LOG_WARN, MLB_LOG_ERROR, MLB_LOG_QUIET } mlb_log_level;
typedef void (*mlb_log_sink)(mlb_log_level level, const char* message, void* user);

void mlb_log_set_sink(mlb_log_sink sink, void* user);   // NULL: silent
void mlb_log_set_level(mlb_log_level level);            // messages below it are dropped
mlb_log_level mlb_log_get_level(void);
void mlb_log(mlb_log_level level, const char* fmt, ...) __attribute__((format(printf, 2, 3)));
// A ready-made sink for programs: "[info] message" on the FILE* passed as `user` (stderr if NULL).
void mlb_log_file_sink(mlb_log_level level, const char* message, void* user);
int mlb_log_level_parse(const char* name, mlb_log_level* out);  // "debug|info|warn|error|quiet"; 0 on success

#define MLB_DEBUG(...) mlb_log(MLB_LOG_DEBUG, __VA_ARGS__)
#define MLB_INFO(...)  mlb_log(MLB_LOG_INFO, __VA_ARGS__)
#define MLB_WARN(...)  mlb_log(MLB_LOG_WARN, __VA_ARGS__)

#endif
