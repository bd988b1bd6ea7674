// Status codes and the last error message.
// Every library function that can fail returns an mlb_status and, on failure, leaves a message
// (per thread) that names the input and the problem. The library never prints or exits.
#ifndef MATLABER_ERROR_H
#define MATLABER_ERROR_H

typedef enum {
    MLB_OK = 0,
    MLB_ERR_ARG,          // a bad argument from the caller (shape, range, NULL)
    MLB_ERR_IO,           // open/read/write/rename failed (errno text in the message)
    MLB_ERR_FORMAT,       // a file's content is malformed
    MLB_ERR_UNSUPPORTED,  // well-formed but not something we handle (dtype, layout)
    MLB_ERR_NOT_FOUND,    // a named tensor/file/key is missing
    MLB_ERR_NOMEM,        // allocation failed
    MLB_ERR_NUMERIC,      // NaN/Inf or divergence
    MLB_ERR_DEVICE,       // GPU asked for and missing, or a CUDA call failed
} mlb_status;

// Sets the thread's message (printf-style) and returns `code`, so callers write
//   if (n < 0) return mlb_fail(MLB_ERR_ARG, "batch size %d must be positive", n);
mlb_status mlb_fail(mlb_status code, const char* fmt, ...) __attribute__((format(printf, 2, 3)));
// Prefixes context to the current message ("loading prior.safetensors: " + old message) and
// returns `code` unchanged; for the caller that knows which file or step was being handled.
mlb_status mlb_fail_context(mlb_status code, const char* fmt, ...) __attribute__((format(printf, 2, 3)));
const char* mlb_last_error(void);   // "" when none
void mlb_clear_error(void);
const char* mlb_status_name(mlb_status code);

// Propagate a failing status unchanged.
#define MLB_TRY(expr) do { mlb_status mlb_try_s_ = (expr); if (mlb_try_s_ != MLB_OK) return mlb_try_s_; } while (0)

#endif
