// The bf16 GEMM's tile on Intel AMX (Sapphire Rapids and later): the same product as gemm_bf16.c's
// AVX-512 BF16 micro-kernel, one MR x NR tile of C per call, on the tile registers. TDPBF16PS
// multiplies a 16-row by 16-pair A tile with a 16-pair by 16-column B tile (pairs along K, the
// layout gemm_bf16.c packs B in) into 16 x 16 fp32 sums: 16 times the multiply-adds of VDPBF16PS
// per instruction. A is packed row-major along K for it ([MR][np] per panel instead of [np][MR]:
// gemm_bf16.c, pack_pairs), so a panel's rows are a tile's rows. The sums are fp32 as before but
// in AMX's own order inside each 16-pair step: the bits differ from the AVX-512 kernel's (not by
// more than the fp32 sums' bound: tests/test_gemm_bf16.c checks both against the exact product),
// and as before they never depend on the thread count.
//
// Linux hands the tile registers' state (8 KB) to a process only on request (arch_prctl
// ARCH_REQ_XCOMP_PERM): asked once; refused or absent, the AVX-512 kernel runs.
#include "nn/gemm_bf16.h"
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/cpu.h"
#include "matlaber/log.h"
#include "matlaber/nn.h"

#if defined(__x86_64__) && defined(__linux__) && defined(__GNUC__) && (__GNUC__ >= 11 || defined(__clang__))
#define MLB_AMX_KERNEL 1
#include <immintrin.h>
#include <sys/syscall.h>
#include "nn/gemm_tile_write.h"
#include <unistd.h>
#define AMX_TARGET __attribute__((target("amx-tile,amx-bf16,avx512f,avx512bw,avx512vl,avx512bf16")))
#define ARCH_REQ_XCOMP_PERM 0x1023
#define XFEATURE_XTILEDATA 18
#endif

#define MR MLB_GEMM_BF16_MR
#define NR 32
#define TK 16   // pairs per tile step: a tile row is 64 bytes
// GCC 12's _tile_loadd is an asm with no memory operand: without this, writes to what it loads may be
// dropped as dead or moved after it (seen: the zero-padded tail below read as garbage).
#define WRITES_BEFORE_TILE_LOADS() __asm__ volatile("" ::: "memory")

static pthread_once_t probe_once = PTHREAD_ONCE_INIT;
static int amx_usable;        // the CPU has AMX-BF16 and the OS granted the tile state
static int amx_forced = -1;   // -1: $MATLABER_CPU_AMX decides; 0/1 set by mlb_gemm_bf16_force_amx_off

static void probe(void) {
#ifdef MLB_AMX_KERNEL
    mlb_cpu_info f;
    mlb_cpu_detect(&f);
    if (!(f.amx_tile && f.amx_bf16 && f.avx512f && f.avx512bw && f.avx512vl && f.avx512_bf16)) return;
    if (syscall(SYS_arch_prctl, ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA) != 0) {
        mlb_log(MLB_LOG_INFO, "the CPU has AMX but the kernel refused its tile state: bf16 GEMMs on AVX-512 BF16");
        return;
    }
    amx_usable = 1;
#endif
}

int mlb_gemm_bf16_amx(void) {
    pthread_once(&probe_once, probe);
    if (!amx_usable) return 0;
    if (amx_forced < 0) {
        const char* e = getenv("MATLABER_CPU_AMX");
        amx_forced = e && (!strcmp(e, "0") || !strcmp(e, "off"));
    }
    return !amx_forced;
}

void mlb_gemm_bf16_force_amx_off(int off) { amx_forced = off ? 1 : 0; }

size_t mlb_gemm_amx_tail_words(int side_b) { return side_b ? (size_t)TK * NR : (size_t)MR * TK; }

// The last kp % TK pairs of `count` panels (np pairs each; A: [MR][np] panels, B: [np][NR]) copied
// into out, one whole zero-padded step per panel: [count][MR][TK] or [count][TK][NR]. Made once per
// K block and reused by every tile of the panel: reading past the pairs would read the next panel.
void mlb_gemm_amx_tails(int side_b, const uint32_t* panels, int count, int np, uint32_t* out) {
    const int whole = np / TK * TK, left = np - whole;
    const size_t words = mlb_gemm_amx_tail_words(side_b);
    memset(out, 0, sizeof(uint32_t) * words * (size_t)count);
    for (int q = 0; q < count; q++) {
        uint32_t* o = out + (size_t)q * words;
        if (side_b) {
            memcpy(o, panels + (size_t)q * np * NR + (size_t)whole * NR, sizeof(uint32_t) * left * NR);
            continue;
        }
        for (int i = 0; i < MR; i++)
            memcpy(o + i * TK, panels + (size_t)q * MR * np + (size_t)i * np + whole, sizeof(uint32_t) * left);
    }
}

#ifdef MLB_AMX_KERNEL
// The palette-1 configuration: tiles 0-3 two panels' C tiles, each two 16-column halves (MR rows),
// 4-5 the A panels' 16 pairs (MR rows of 64 bytes), 6-7 the B panel's two halves (16 pair rows).
typedef struct {
    uint8_t palette, start_row, reserved[14];
    uint16_t colsb[16];
    uint8_t rows[16];
} __attribute__((packed)) tile_config;

// Static, not built on the stack: GCC 12's _tile_loadconfig tells the compiler it reads 8 bytes, and
// stores to a local configuration were dropped as dead (seen: only the palette written, a fault).
static const tile_config CONFIG = {
    .palette = 1,
    .colsb = {64, 64, 64, 64, 64, 64, 64, 64},
    .rows = {MR, MR, MR, MR, MR, MR, TK, TK},
};

AMX_TARGET void mlb_gemm_amx_begin(void) { _tile_loadconfig(&CONFIG); }

AMX_TARGET void mlb_gemm_amx_end(void) { _tile_release(); }

// Rows < m of the tile's sums s [MR][NR] written to C (gemm_tile_write.h), as the AVX-512 kernel
// writes its registers.
AMX_TARGET static void write_tile(const float* s, float* C, int ldc, int m, int n, float alpha, float beta,
                                  const float* bias) {
    for (int i = 0; i < m && i < MR; i++)
        mlb_gemm_tile_write_row(C + (size_t)i * ldc, _mm512_loadu_ps(s + i * NR), _mm512_loadu_ps(s + i * NR + 16), n,
                                alpha, beta, bias ? bias + i : NULL);
}

// Panels 0 .. P (P = 1 or 2) of A, each MR rows, times one B panel: a = the first A panel [MR][kp]
// (rows along K; the next at a + MR·kp), b the B panel [kp][NR], a_tail and b_tail their last
// kp % TK pairs as whole steps (mlb_gemm_amx_tails; unread when none); tiles 0-1 panel 0's sums, 2-3
// panel 1's, 4-5 the A panels, 6-7 B's halves. Two panels load B once for four products.
AMX_TARGET static inline __attribute__((always_inline)) void tiles_body(const int P, int kp, const uint32_t* a,
                                                                        const uint32_t* b, const uint32_t* a_tail,
                                                                        const uint32_t* b_tail, const float* w_in,
                                                                        float* w_out, size_t w_step, float* C, int ldc,
                                                                        int m, int n, float alpha, float beta,
                                                                        const float* bias) {
// the C tiles of the P panels at X (the second panel's STEP floats on) through OP: _tile_loadd or _tile_stored
#define C_TILES(OP, X, STEP)                              \
    do {                                                  \
        OP(0, X, NR * 4);                                 \
        OP(1, (X) + 16, NR * 4);                          \
        if (P == 2) {                                     \
            OP(2, (X) + (STEP), NR * 4);                  \
            OP(3, (X) + (STEP) + 16, NR * 4);             \
        }                                                 \
    } while (0)
// one 16-pair step: B's two halves at B0, the panels' A tiles at A0 and A1 (rows LDA bytes apart)
#define TILE_STEP(A0, A1, LDA, B0)                        \
    do {                                                  \
        _tile_loadd(6, B0, NR * 4);                       \
        _tile_loadd(7, (B0) + 16, NR * 4);                \
        _tile_loadd(4, A0, LDA);                          \
        _tile_dpbf16ps(0, 4, 6);                          \
        _tile_dpbf16ps(1, 4, 7);                          \
        if (P == 2) {                                     \
            _tile_loadd(5, A1, LDA);                      \
            _tile_dpbf16ps(2, 5, 6);                      \
            _tile_dpbf16ps(3, 5, 7);                      \
        }                                                 \
    } while (0)
    WRITES_BEFORE_TILE_LOADS();   // the packed panels and w_in
    if (w_in) {
        C_TILES(_tile_loadd, w_in, w_step);
    } else {
        _tile_zero(0);
        _tile_zero(1);
        if (P == 2) {
            _tile_zero(2);
            _tile_zero(3);
        }
    }
    const int whole = kp / TK * TK;
    for (int p = 0; p < whole; p += TK) TILE_STEP(a + p, a + (size_t)MR * kp + p, kp * 4, b + (size_t)p * NR);
    // the last pairs, from the zero-padded tails (mlb_gemm_amx_tails)
    if (whole < kp) TILE_STEP(a_tail, a_tail + MR * TK, TK * 4, b_tail);
    float s[2][MR * NR] __attribute__((aligned(64)));   // the sums, when they are final
    C_TILES(_tile_stored, w_out ? w_out : s[0], w_out ? w_step : (size_t)MR * NR);
#undef TILE_STEP
#undef C_TILES
    if (w_out) return;
    write_tile(s[0], C, ldc, m, n, alpha, beta, bias);
    if (P == 2 && m > MR) write_tile(s[1], C + (size_t)MR * ldc, ldc, m - MR, n, alpha, beta, bias ? bias + MR : NULL);
}

AMX_TARGET void mlb_gemm_amx_tiles(int panels, int kp, const uint32_t* a, const uint32_t* b, const uint32_t* a_tail,
                                   const uint32_t* b_tail, const float* w_in, float* w_out, size_t w_step, float* C,
                                   int ldc, int m, int n, float alpha, float beta, const float* bias) {
    if (panels == 2) tiles_body(2, kp, a, b, a_tail, b_tail, w_in, w_out, w_step, C, ldc, m, n, alpha, beta, bias);
    else tiles_body(1, kp, a, b, a_tail, b_tail, w_in, w_out, w_step, C, ldc, m, n, alpha, beta, bias);
}
#else
void mlb_gemm_amx_begin(void) {}
void mlb_gemm_amx_end(void) {}
void mlb_gemm_amx_tiles(int panels, int kp, const uint32_t* a, const uint32_t* b, const uint32_t* a_tail,
                        const uint32_t* b_tail, const float* w_in, float* w_out, size_t w_step, float* C, int ldc,
                        int m, int n, float alpha, float beta, const float* bias) {
    (void)panels; (void)kp; (void)a; (void)b; (void)a_tail; (void)b_tail; (void)w_in; (void)w_out; (void)w_step; (void)C; (void)ldc; (void)m;
    (void)n; (void)alpha; (void)beta; (void)bias;   // never called: mlb_gemm_bf16_amx() is 0 where this is compiled
}
#endif
