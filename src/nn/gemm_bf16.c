// The bf16 GEMM of one thread: C[M,N] = alpha·op(A)[M,K]·op(B)[K,N] + beta·C (row-major), the
// operands rounded to bf16 (round to nearest even, as VCVTNE2PS2BF16 does: denormals read as zero),
// the products summed in fp32 by AVX-512 BF16 (VDPBF16PS: two bf16 products per fp32 lane per
// instruction, twice the multiply-adds of an fp32 FMA). mlb_gemm_bf16 (gemm.c) cuts a product into
// the same shards as mlb_gemm and calls this once per shard, so the bits never depend on the thread
// count. Compiled for the generic target: only the functions marked BF16_TARGET use AVX-512, and
// they run only after mlb_gemm_bf16_native() said the CPU has it.
//
// Layout: op(A) is packed into panels of MR rows, op(B) into panels of NR columns, both as pairs
// along K: one 32-bit word = (bf16 x[k+1] << 16) | bf16 x[k], a zero pad after an odd K, zero
// rows/columns past the edges; a panel pair by pair ([np][MR]), or row by row for A when the
// tiles run on AMX (gemm_amx.c: [MR][np], an AMX tile's rows). The micro-kernel keeps an MR x NR tile in 28 zmm registers over the
// K block (KC pairs), keeping the fp32 sums in a tile buffer between blocks (one fp32 sum per
// element in k order either way), then writes alpha·tile + beta·C with masked stores for the
// ragged edges.
#include "nn/gemm_bf16.h"
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <cblas.h>
#include "matlaber/cpu.h"
#include "matlaber/log.h"
#include "matlaber/nn.h"

#if defined(__x86_64__) && defined(__GNUC__) && (__GNUC__ >= 10 || defined(__clang__))
#define MLB_BF16_KERNEL 1
#include <immintrin.h>
#include "nn/gemm_tile_write.h"
#define BF16_TARGET __attribute__((target("avx512f,avx512bw,avx512vl,avx512bf16")))
#endif

#define MR MLB_GEMM_BF16_MR   // rows of the register tile: 14 x 2 accumulators + 2 B vectors of the 32 zmm
#define NR 32   // columns: two zmm of 16 fp32
#define KC 128  // K pairs per block: an A micro-panel (7 KB) and a B one (16 KB) stay in L1
#define MC 24   // A panels packed at a time (172 KB at KC: stays in L2 while the B panels pass)

static int force_fallback = -1;   // -1: not read yet ($MATLABER_CPU_BF16), 0/1 set

void mlb_gemm_bf16_force_fallback(int on) { force_fallback = on ? 1 : 0; }

static int cpu_has_bf16(void) {
    static int cpu_has = -1;
    if (cpu_has < 0) {
#ifdef MLB_BF16_KERNEL
        mlb_cpu_info f;
        mlb_cpu_detect(&f);
        cpu_has = f.avx512f && f.avx512bw && f.avx512vl && f.avx512_bf16;
#else
        cpu_has = 0;
#endif
    }
    return cpu_has;
}

int mlb_gemm_bf16_cpu_has(void) { return cpu_has_bf16(); }

int mlb_gemm_bf16_native(void) {
    if (force_fallback < 0) {
        const char* e = getenv("MATLABER_CPU_BF16");
        force_fallback = e && (!strcmp(e, "0") || !strcmp(e, "off"));
    }
    return cpu_has_bf16() && !force_fallback;
}

// Where mlb_gemm_bf16_image puts a conv's input: Hp padded rows of `row` values (stride_w phases of
// Wq columns each); padded column X is value X % stride_w · Wq + X / stride_w of its row.
typedef struct {
    int Hp, sw, Wq;
    size_t row;
} image_layout;

static image_layout layout_of(const mlb_conv2d* cv) {
    image_layout l;
    l.Hp = cv->H + cv->pad_top + cv->pad_bottom;
    l.sw = cv->stride_w;
    l.Wq = (cv->W + cv->pad_left + cv->pad_right + l.sw - 1) / l.sw;
    l.row = (size_t)l.sw * l.Wq;
    return l;
}

#ifdef MLB_BF16_KERNEL
// 32 consecutive fp32 values x[at .. at + left) rounded to 32 bf16 (16 pair words), zero past `left`.
BF16_TARGET static inline __m512i load32_bf16(const float* X, size_t at, int left) {
    const float* x = X + at;
    __mmask16 m0 = left >= 16 ? 0xFFFF : left > 0 ? (__mmask16)((1u << left) - 1) : 0;
    __mmask16 m1 = left >= 32 ? 0xFFFF : left > 16 ? (__mmask16)((1u << (left - 16)) - 1) : 0;
    return (__m512i)_mm512_cvtne2ps_pbh(_mm512_maskz_loadu_ps(m1, x + 16), _mm512_maskz_loadu_ps(m0, x));
}

// 16 values of two rows a (at a_at) and b (at b_at, or zero when has_b is 0) as [a0..a15 | b0..b15] bf16.
BF16_TARGET static inline __m512i load16x2_bf16(const float* x, size_t a_at, size_t b_at, int has_b, __mmask16 m) {
    __m512 a = _mm512_maskz_loadu_ps(m, x + a_at);
    __m512 b = has_b ? _mm512_maskz_loadu_ps(m, x + b_at) : _mm512_setzero_ps();
    return (__m512i)_mm512_cvtne2ps_pbh(b, a);
}

// [a0..a15 | b0..b15] (bf16) -> word r = (b_r << 16) | a_r: two neighbours along K as one pair word.
static const uint16_t pair_weave[32] = {0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23,
                                        8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31};

// Rows r0 .. r0+R of X (fp32 values, rounded here) packed as pairs along K into out[kp][Rpad]
// (Rpad = MR or NR), or with rows_major into out[Rpad][kp] (A for the AMX tile: gemm_amx.c):
// X[r, k] is X[at + r·rs + k·ks] with rs = 1 or ks = 1. Rows past R and the pad after an odd K are
// zero.
BF16_TARGET static void pack_pairs(uint32_t* out, int Rpad, int rows_major, const float* X, size_t at, size_t rs,
                                   size_t ks, int R, int K) {
    const int kp = (K + 1) / 2;
    const size_t ps = rows_major ? 1 : (size_t)Rpad, ro = rows_major ? (size_t)kp : 1;   // pair p, row r at p·ps + r·ro
    if (ks == 1) {   // each row runs along K: 32 values -> 16 pair words, then spread with stride ps
        uint32_t tmp[16];
        for (int r = 0; r < Rpad; r++) {
            if (r >= R) {
                for (int p = 0; p < kp; p++) out[(size_t)p * ps + r * ro] = 0;
                continue;
            }
            for (int k = 0; k < K; k += 32) {
                int np = kp - k / 2 < 16 ? kp - k / 2 : 16;
                __m512i w = load32_bf16(X, at + (size_t)r * rs + k, K - k);
                if (rows_major) {
                    _mm512_mask_storeu_epi32(out + r * ro + k / 2, (__mmask16)((1u << np) - 1), w);
                    continue;
                }
                _mm512_storeu_si512(tmp, w);
                for (int p = 0; p < np; p++) out[(size_t)(k / 2 + p) * ps + r] = tmp[p];
            }
        }
        return;
    }
    // each k runs along the rows: rows k and k+1, 16 at a time, interleaved word by word
    const __m512i weave = _mm512_loadu_si512(pair_weave);
    const __m512i lane_row = _mm512_mullo_epi32(_mm512_set_epi32(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0),
                                                _mm512_set1_epi32(kp));   // rows_major: lane l's offset l·kp
    for (int p = 0; p < kp; p++) {
        size_t x0 = at + (size_t)(2 * p) * ks;
        int has1 = 2 * p + 1 < K;
        for (int r = 0; r < Rpad; r += 16) {
            int left = R - r;
            __mmask16 m = left >= 16 ? 0xFFFF : left > 0 ? (__mmask16)((1u << left) - 1) : 0;
            __m512i w = _mm512_permutexvar_epi16(weave, load16x2_bf16(X, x0 + r, x0 + ks + r, has1, m));
            __mmask16 keep = Rpad - r >= 16 ? 0xFFFF : (__mmask16)((1u << (Rpad - r)) - 1);
            if (rows_major) _mm512_mask_i32scatter_epi32(out + (size_t)r * ro + p, keep, lane_row, w, 4);
            else _mm512_mask_storeu_epi32(out + (size_t)p * ps + r, keep, w);
        }
    }
}

// lo/hi (lanes 0-15 / 16-31) = row k = (c, i, j) of the im2col matrix of cv's input img for the
// `lanes` output pixels from (y, x) on; the other lanes zero. The pixels fall in runs along output
// rows (one when OW >= NR); a run of a stride-1 conv is one masked load from an input row (the
// padding's lanes stay zero), of a strided one a gather.
BF16_TARGET static inline void im2col_lanes(__m512* lo, __m512* hi, const float* img, const mlb_conv2d* cv, int OW,
                                            int c, int i, int j, int y, int x, int lanes) {
    *lo = *hi = _mm512_setzero_ps();
    const float* plane = img + (size_t)c * cv->H * cv->W;
    for (int lane = 0; lane < lanes; y++, x = 0) {
        const int len = OW - x < lanes - lane ? OW - x : lanes - lane, first = lane;
        lane += len;
        const int iy = y * cv->stride_h - cv->pad_top + i;
        if (iy < 0 || iy >= cv->H) continue;
        const float* row = plane + (size_t)iy * cv->W;
        const int ix0 = x * cv->stride_w - cv->pad_left + j;   // the input column of the run's first lane
        if (cv->stride_w == 1) {   // lane l reads row[ix0 + l - first] where that is inside the row
            const int t_lo = ix0 < 0 ? -ix0 : 0, t_hi = cv->W - ix0 < len ? cv->W - ix0 : len;
            if (t_hi <= t_lo) continue;
            const int n = t_hi - t_lo;
            const uint32_t m = (n >= 32 ? 0xFFFFFFFFu : (1u << n) - 1) << (first + t_lo);
            const float* base = row + ix0 - first;
            if ((uint16_t)m) *lo = _mm512_mask_loadu_ps(*lo, (__mmask16)m, base);
            if (m >> 16) *hi = _mm512_mask_loadu_ps(*hi, (__mmask16)(m >> 16), base + 16);
        } else {
            float tmp[NR] = {0};
            for (int t = 0; t < len; t++) {
                const int ix = ix0 + t * cv->stride_w;
                if (ix >= 0 && ix < cv->W) tmp[first + t] = row[ix];
            }
            const uint32_t m = (len >= 32 ? 0xFFFFFFFFu : (1u << len) - 1) << first;
            *lo = _mm512_mask_loadu_ps(*lo, (__mmask16)m, tmp);
            *hi = _mm512_mask_loadu_ps(*hi, (__mmask16)(m >> 16), tmp + 16);
        }
    }
}

// A B block of the im2col operand: columns pixel0 .. pixel0 + R, rows k0 .. k0 + K, into out
// ([panels][np][NR], as pack_block lays out B). Pair by pair across all panels, so that each input
// row is read along its length (prefetched, and again from L1 for the kernel's next column j).
BF16_TARGET static void pack_im2col_block(uint32_t* out, int np, const float* img, const mlb_conv2d* cv,
                                          size_t pixel0, int R, int k0, int K) {
    const __m512i weave = _mm512_loadu_si512(pair_weave);
    const int OW = mlb_conv2d_out_w(cv), KHW = cv->KH * cv->KW, panels = (R + NR - 1) / NR;
    const int y0 = (int)(pixel0 / (size_t)OW), x0 = (int)(pixel0 % (size_t)OW);
    int c = k0 / KHW, i = k0 / cv->KW % cv->KH, j = k0 % cv->KW;   // row k's (c, i, j), stepped along
    for (int p = 0; 2 * p < K; p++) {
        const int ca = c, ia = i, ja = j, has_b = 2 * p + 1 < K;
        if (++j == cv->KW) { j = 0; if (++i == cv->KH) { i = 0; c++; } }
        const int cb = c, ib = i, jb = j;
        if (++j == cv->KW) { j = 0; if (++i == cv->KH) { i = 0; c++; } }
        int y = y0, x = x0;
        for (int q = 0; q < panels; q++) {
            const int lanes = R - q * NR < NR ? R - q * NR : NR;
            __m512 a[2], b[2] = {_mm512_setzero_ps(), _mm512_setzero_ps()};
            im2col_lanes(&a[0], &a[1], img, cv, OW, ca, ia, ja, y, x, lanes);
            if (has_b) im2col_lanes(&b[0], &b[1], img, cv, OW, cb, ib, jb, y, x, lanes);
            uint32_t* o = out + ((size_t)q * np + p) * NR;
            _mm512_storeu_si512(o, _mm512_permutexvar_epi16(weave, (__m512i)_mm512_cvtne2ps_pbh(b[0], a[0])));
            _mm512_storeu_si512(o + 16, _mm512_permutexvar_epi16(weave, (__m512i)_mm512_cvtne2ps_pbh(b[1], a[1])));
            for (x += NR; x >= OW; x -= OW) y++;
        }
    }
}

// 32 bf16 -> the 16 of even index, then the 16 of odd index.
static const uint16_t even_odd[32] = {0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30,
                                      1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31};

// Channels c0 .. c1 of img into the layout above: rows of the padding zero, each input row rounded
// 16 values at a time (VCVTNEPS2BF16 rounds as VCVTNE2PS2BF16 does: the same bf16 as the panels
// packed from fp32), then spread over the phases when strided.
BF16_TARGET static void image_channels(const mlb_conv2d* cv, const float* img, int c0, int c1, uint16_t* out) {
    const image_layout l = layout_of(cv);
    const int W = cv->W, pl = cv->pad_left;
    for (int c = c0; c < c1; c++)
        for (int r = 0; r < l.Hp; r++) {
            uint16_t* d = out + ((size_t)c * l.Hp + r) * l.row;
            const int iy = r - cv->pad_top;
            if (iy < 0 || iy >= cv->H) {
                memset(d, 0, sizeof(uint16_t) * l.row);
                continue;
            }
            const float* s = img + ((size_t)c * cv->H + iy) * W;
            if (l.sw == 1) {
                for (int x = 0; x < pl; x++) d[x] = 0;
                for (int x = 0; x < W; x += 16) {
                    const __mmask16 m = W - x >= 16 ? 0xFFFF : (__mmask16)((1u << (W - x)) - 1);
                    _mm256_mask_storeu_epi16(d + pl + x, m, (__m256i)_mm512_cvtneps_pbh(_mm512_maskz_loadu_ps(m, s + x)));
                }
                for (size_t x = (size_t)pl + W; x < l.row; x++) d[x] = 0;
                continue;
            }
            memset(d, 0, sizeof(uint16_t) * l.row);
            if (l.sw == 2) {   // 32 values rounded, split into evens and odds, one store per phase
                const __m512i split = _mm512_loadu_si512(even_odd);
                const int pe = pl % 2, be = pl / 2, bo = (pl + 1) / 2;   // phase and start of the even ix, of the odd
                for (int x = 0; x < W; x += 32) {
                    const int n = W - x < 32 ? W - x : 32, ne = (n + 1) / 2, no = n / 2;
                    const __mmask16 m0 = n >= 16 ? 0xFFFF : (__mmask16)((1u << n) - 1);
                    const __mmask16 m1 = n >= 32 ? 0xFFFF : n > 16 ? (__mmask16)((1u << (n - 16)) - 1) : 0;
                    const __m512i v = _mm512_permutexvar_epi16(
                        split, (__m512i)_mm512_cvtne2ps_pbh(_mm512_maskz_loadu_ps(m1, s + x + 16), _mm512_maskz_loadu_ps(m0, s + x)));
                    _mm256_mask_storeu_epi16(d + (size_t)pe * l.Wq + be + x / 2, (__mmask16)((1u << ne) - 1),
                                             _mm512_castsi512_si256(v));
                    _mm256_mask_storeu_epi16(d + (size_t)(1 - pe) * l.Wq + bo + x / 2, (__mmask16)((1u << no) - 1),
                                             _mm512_extracti64x4_epi64(v, 1));
                }
                continue;
            }
            uint16_t tmp[16];   // other strides: value by value, the phase and index stepped along
            int ph = pl % l.sw, at = pl / l.sw;
            for (int x = 0; x < W; x += 16) {
                const int n = W - x < 16 ? W - x : 16;
                const __mmask16 m = n == 16 ? 0xFFFF : (__mmask16)((1u << n) - 1);
                _mm256_storeu_si256((__m256i*)tmp, (__m256i)_mm512_cvtneps_pbh(_mm512_maskz_loadu_ps(m, s + x)));
                for (int t = 0; t < n; t++) {
                    d[(size_t)ph * l.Wq + at] = tmp[t];
                    if (++ph == l.sw) { ph = 0; at++; }
                }
            }
        }
}

// Interleave two rows of 32 bf16 (a: k, b: k + 1) into pair words: lanes 0-15, then 16-31.
static const uint16_t weave_lo[32] = {0, 32, 1, 33, 2, 34, 3, 35, 4, 36, 5, 37, 6, 38, 7, 39,
                                      8, 40, 9, 41, 10, 42, 11, 43, 12, 44, 13, 45, 14, 46, 15, 47};
static const uint16_t weave_hi[32] = {16, 48, 17, 49, 18, 50, 19, 51, 20, 52, 21, 53, 22, 54, 23, 55,
                                      24, 56, 25, 57, 26, 58, 27, 59, 28, 60, 29, 61, 30, 62, 31, 63};

// pack_im2col_block from the image in bf16 (mlb_gemm_bf16_image): the same words. Panel by panel
// (its writes in order): the panel's pixels fall in runs along output rows, found once; row k of a
// run is then one masked load at the run's offset plus row k's (no edge tests: the padding is in
// the image), two rows woven into pair words.
BF16_TARGET static void pack_image_block(uint32_t* out, int np, const uint16_t* img, const mlb_conv2d* cv,
                                         size_t pixel0, int R, int k0, int K) {
    const image_layout l = layout_of(cv);
    const int OW = mlb_conv2d_out_w(cv), KW = cv->KW, KHW = cv->KH * KW, panels = (R + NR - 1) / NR;
    const ptrdiff_t pix_row = (ptrdiff_t)cv->stride_h * (ptrdiff_t)l.row;   // values from one output row to the next
    ptrdiff_t koff[2 * KC];   // im2col row k0 + t = (c, i, j) starts at image value koff[t]
    for (int t = 0; t < K; t++) {
        const int k = k0 + t, c = k / KHW, i = k / KW % cv->KH, j = k % KW;
        koff[t] = ((ptrdiff_t)c * l.Hp + i) * (ptrdiff_t)l.row + (ptrdiff_t)(j % l.sw) * l.Wq + j / l.sw;
    }
    const __m512i wlo = _mm512_loadu_si512(weave_lo), whi = _mm512_loadu_si512(weave_hi), zero = _mm512_setzero_si512();
    const int pairs = K / 2;
    for (int q = 0; q < panels; q++) {
        const int lanes = R - q * NR < NR ? R - q * NR : NR;
        ptrdiff_t roff[NR];   // run r: lanes rmask[r] read image value roff[r] + lane + koff[t]
        __mmask32 rmask[NR];
        int nr = 0;
        const size_t pix = pixel0 + (size_t)q * NR;
        int y = (int)(pix / (size_t)OW), x = (int)(pix % (size_t)OW);
        for (int lane = 0; lane < lanes; y++, x = 0) {
            const int len = OW - x < lanes - lane ? OW - x : lanes - lane;
            rmask[nr] = (__mmask32)((len >= 32 ? 0xFFFFFFFFu : (1u << len) - 1) << lane);
            roff[nr++] = (ptrdiff_t)y * pix_row + x - lane;
            lane += len;
        }
        uint32_t* o = out + (size_t)q * np * NR;
        if (nr == 1) {   // the panel within one output row (OW >= 32): one load per im2col row
            const uint16_t* base = img + roff[0];
            const __mmask32 m = rmask[0];
            for (int p = 0; p < pairs; p++, o += NR) {
                const __m512i a = _mm512_maskz_loadu_epi16(m, base + koff[2 * p]);
                const __m512i b = _mm512_maskz_loadu_epi16(m, base + koff[2 * p + 1]);
                _mm512_storeu_si512(o, _mm512_permutex2var_epi16(a, wlo, b));
                _mm512_storeu_si512(o + 16, _mm512_permutex2var_epi16(a, whi, b));
            }
            if (K & 1) {
                const __m512i a = _mm512_maskz_loadu_epi16(m, base + koff[K - 1]);
                _mm512_storeu_si512(o, _mm512_permutex2var_epi16(a, wlo, zero));
                _mm512_storeu_si512(o + 16, _mm512_permutex2var_epi16(a, whi, zero));
            }
            continue;
        }
        for (int p = 0; 2 * p < K; p++, o += NR) {
            __m512i a = zero, b = zero;
            for (int r = 0; r < nr; r++) a = _mm512_mask_loadu_epi16(a, rmask[r], img + roff[r] + koff[2 * p]);
            if (2 * p + 1 < K)
                for (int r = 0; r < nr; r++) b = _mm512_mask_loadu_epi16(b, rmask[r], img + roff[r] + koff[2 * p + 1]);
            _mm512_storeu_si512(o, _mm512_permutex2var_epi16(a, wlo, b));
            _mm512_storeu_si512(o + 16, _mm512_permutex2var_epi16(a, whi, b));
        }
    }
}

// One RM x NR tile (RM <= MR rows of the MR-row panels) over kp pairs: the sums start from zero
// (w_in NULL) or from the fp32 tile w_in (the K blocks before), and end in the fp32 tile w_out (K
// blocks follow), or, with w_out NULL, as C[m, n] (m <= RM, n <= NR) = alpha · sum + beta · C, or
// alpha · sum + bias[m] with bias (then C is not read: the same rounding as C = bias, beta = 1). A
// stored and reloaded fp32 sum is the same sum: K blocking does not change a bit. RM is a constant
// where it is inlined (micro_kernel below): a panel's last rows of a small M (the tiny model's 32,
// 8, 3 channels) are not multiplied as 14, and each row's sums are the ones the 14-row tile makes.
BF16_TARGET static inline __attribute__((always_inline)) void micro_body(const int RM, int kp, const uint32_t* a,
                                                                         const uint32_t* b, const float* w_in,
                                                                         float* w_out, float* C, int ldc, int m, int n,
                                                                         float alpha, float beta, const float* bias) {
#define ACC(i)                                                                                       \
    __m512 c##i##0 = (i) < RM && w_in ? _mm512_loadu_ps(w_in + (i) * NR) : _mm512_setzero_ps(),      \
           c##i##1 = (i) < RM && w_in ? _mm512_loadu_ps(w_in + (i) * NR + 16) : _mm512_setzero_ps();
    ACC(0) ACC(1) ACC(2) ACC(3) ACC(4) ACC(5) ACC(6) ACC(7) ACC(8) ACC(9) ACC(10) ACC(11) ACC(12) ACC(13)
#undef ACC
    for (int p = 0; p < kp; p++, a += MR, b += NR) {
        __m512bh b0 = (__m512bh)_mm512_loadu_si512(b), b1 = (__m512bh)_mm512_loadu_si512(b + 16);
#define STEP(i)                                                             \
    if ((i) < RM) {                                                         \
        __m512bh ai = (__m512bh)_mm512_set1_epi32((int)a[i]);               \
        c##i##0 = _mm512_dpbf16_ps(c##i##0, ai, b0);                        \
        c##i##1 = _mm512_dpbf16_ps(c##i##1, ai, b1);                        \
    }
        STEP(0) STEP(1) STEP(2) STEP(3) STEP(4) STEP(5) STEP(6) STEP(7) STEP(8) STEP(9) STEP(10) STEP(11)
        STEP(12) STEP(13)
#undef STEP
    }
    if (w_out) {
#define KEEP(i) if ((i) < RM) { _mm512_storeu_ps(w_out + (i) * NR, c##i##0); _mm512_storeu_ps(w_out + (i) * NR + 16, c##i##1); }
        KEEP(0) KEEP(1) KEEP(2) KEEP(3) KEEP(4) KEEP(5) KEEP(6) KEEP(7) KEEP(8) KEEP(9) KEEP(10) KEEP(11) KEEP(12)
        KEEP(13)
#undef KEEP
        return;
    }
#define PUT(i)                                                                                                \
    if ((i) < RM && (i) < m)                                                                                  \
        mlb_gemm_tile_write_row(C + (size_t)(i) * ldc, c##i##0, c##i##1, n, alpha, beta, bias ? bias + (i) : NULL);
    PUT(0) PUT(1) PUT(2) PUT(3) PUT(4) PUT(5) PUT(6) PUT(7) PUT(8) PUT(9) PUT(10) PUT(11) PUT(12) PUT(13)
#undef PUT
}

#define MICRO(RM)                                                                                              \
    BF16_TARGET static void micro_kernel_##RM(int kp, const uint32_t* a, const uint32_t* b, const float* w_in, \
                                              float* w_out, float* C, int ldc, int m, int n, float alpha,      \
                                              float beta, const float* bias) {                                 \
        micro_body(RM, kp, a, b, w_in, w_out, C, ldc, m, n, alpha, beta, bias);                                \
    }
MICRO(2) MICRO(4) MICRO(6) MICRO(8) MICRO(10) MICRO(12) MICRO(14)
#undef MICRO

// The tile of a panel whose rows m (1 .. MR) are valid, as few rows as cover them.
BF16_TARGET static void micro_kernel(int kp, const uint32_t* a, const uint32_t* b, const float* w_in, float* w_out,
                                     float* C, int ldc, int m, int n, float alpha, float beta, const float* bias) {
    switch ((m + 1) / 2) {
    case 1: micro_kernel_2(kp, a, b, w_in, w_out, C, ldc, m, n, alpha, beta, bias); break;
    case 2: micro_kernel_4(kp, a, b, w_in, w_out, C, ldc, m, n, alpha, beta, bias); break;
    case 3: micro_kernel_6(kp, a, b, w_in, w_out, C, ldc, m, n, alpha, beta, bias); break;
    case 4: micro_kernel_8(kp, a, b, w_in, w_out, C, ldc, m, n, alpha, beta, bias); break;
    case 5: micro_kernel_10(kp, a, b, w_in, w_out, C, ldc, m, n, alpha, beta, bias); break;
    case 6: micro_kernel_12(kp, a, b, w_in, w_out, C, ldc, m, n, alpha, beta, bias); break;
    default: micro_kernel_14(kp, a, b, w_in, w_out, C, ldc, m, n, alpha, beta, bias); break;
    }
}
#endif

// Words of op(X)'s panels over all K blocks: block after block, in each the panels of R rows
// (A: MR, B: NR) over that block's pairs, the layout the loop below reads per block.
size_t mlb_gemm_bf16_packed_words(int side_b, int R, int K) {
    if (R <= 0 || K <= 0) return 0;
    const int Rpad = side_b ? NR : MR;
    return (size_t)((R + Rpad - 1) / Rpad) * Rpad * (size_t)((K + 1) / 2);
}

// Strides of op(X)'s rows and K: op(A)[i, k] = A[i·lda + k] (or A[k·lda + i] transposed); for B the
// "rows" are op(B)'s columns: op(B)[k, j] = B[k·ldb + j] (or B[j·ldb + k] transposed).
static void operand_strides(int side_b, int trans, int ld, size_t* rs, size_t* ks) {
    int along_k_contiguous = side_b ? trans : !trans;
    *rs = along_k_contiguous ? (size_t)ld : 1;
    *ks = along_k_contiguous ? 1 : (size_t)ld;
}

// Value (k, pixel) of the im2col matrix of cv's input image img (zero in the padding).
static float im2col_value(const float* img, const mlb_conv2d* cv, int k, size_t pixel) {
    const int OW = mlb_conv2d_out_w(cv), c = k / (cv->KH * cv->KW), i = k / cv->KW % cv->KH, j = k % cv->KW;
    const long y = (long)(pixel / (size_t)OW), x = (long)(pixel % (size_t)OW);
    const long iy = y * cv->stride_h - cv->pad_top + i, ix = x * cv->stride_w - cv->pad_left + j;
    if (iy < 0 || iy >= cv->H || ix < 0 || ix >= cv->W) return 0;
    return img[((size_t)c * cv->H + (size_t)iy) * cv->W + (size_t)ix];
}

// Value (r, k) of an operand given only packed (side_b 0: A, R = M rows; 1: B, R = N columns), as
// mlb_gemm_bf16_pack lays it out: per K block of KC pairs, its panels of Rpad rows, pair by pair.
static float packed_value(const uint32_t* P, int side_b, int R, int K, int r, int k) {
    const int Rpad = side_b ? NR : MR, kp = (K + 1) / 2, panels = (R + Rpad - 1) / Rpad, pair = k / 2;
    const int blk = pair / KC, np = kp - blk * KC < KC ? kp - blk * KC : KC;
    const size_t panel = (size_t)blk * KC * panels * Rpad + (size_t)(r / Rpad) * np * Rpad;
    uint32_t w = !side_b && mlb_gemm_bf16_amx() ? P[panel + (size_t)(r % Rpad) * np + (pair - blk * KC)]
                                              : P[panel + (size_t)(pair - blk * KC) * Rpad + r % Rpad];
    uint32_t u = (k & 1 ? w >> 16 : w & 0xFFFFu) << 16;
    float f;
    memcpy(&f, &u, 4);
    return f;
}

// Element (r, k) of op(X) (side_b 0: A with R = M rows; 1: B, R = N), as fp32 (the out-of-memory path
// only): from the fp32 storage, the image of an im2col operand, or the packed form when there is
// no other (a weight packed at load: data NULL).
static float element(const mlb_bf16_operand* X, int side_b, int trans, int R, int K, int r, int k) {
    if (!X->data) return packed_value(X->packed, side_b, R, K, r, k);
    if (X->im2col) return im2col_value(X->data, X->im2col, k, X->offset + (size_t)r);
    size_t rs, ks;
    operand_strides(side_b, trans, X->ld, &rs, &ks);
    return ((const float*)X->data)[X->offset + (size_t)r * rs + (size_t)k * ks];
}

// C = alpha·op(A)·op(B) + beta·C element by element in fp32, needing no memory and no AVX-512: for an
// operand with no fp32 storage (packed, or an im2col view) when the kernel cannot pack (out of memory).
static void gemm_elementwise(int ta, int tb, int M, int N, int K, float alpha, const mlb_bf16_operand* A,
                             const mlb_bf16_operand* B, float beta, float* C, int ldc) {
    for (int i = 0; i < M; i++)
        for (int j = 0; j < N; j++) {
            float sum = 0;
            for (int k = 0; k < K; k++) sum += element(A, 0, ta, M, K, i, k) * element(B, 1, tb, N, K, j, k);
            float* c = C + (size_t)i * ldc + j;
            *c = beta == 0 ? alpha * sum : alpha * sum + beta * *c;
        }
}

#ifdef MLB_BF16_KERNEL
// K block blk's panels of op(X) (R rows, starting r0 rows into it) into out ([panels][np][Rpad]).
static void pack_block(uint32_t* out, int side_b, int R, int K, int blk, const mlb_bf16_operand* X, int trans,
                       int r0) {
    const int Rpad = side_b ? NR : MR, kp = (K + 1) / 2, panels = (R + Rpad - 1) / Rpad;
    const int p0 = blk * KC, np = kp - p0 < KC ? kp - p0 : KC, k0 = 2 * p0, nk = K - k0 < 2 * np ? K - k0 : 2 * np;
    if (X->im2col && X->image) {
        pack_image_block(out, np, X->image, X->im2col, X->offset + (size_t)r0, R, k0, nk);
        return;
    }
    if (X->im2col) {
        pack_im2col_block(out, np, X->data, X->im2col, X->offset + (size_t)r0, R, k0, nk);
        return;
    }
    size_t rs, ks;
    operand_strides(side_b, trans, X->ld, &rs, &ks);
    for (int q = 0; q < panels; q++) {
        int i0 = q * Rpad, rows = R - i0 < Rpad ? R - i0 : Rpad;
        size_t at = X->offset + (size_t)(r0 + i0) * rs + (size_t)k0 * ks;
        uint32_t* o = out + (size_t)q * Rpad * np;
        pack_pairs(o, Rpad, !side_b && mlb_gemm_bf16_amx(), X->data, at, rs, ks, rows, nk);
    }
}
#endif

size_t mlb_gemm_bf16_image_len(const mlb_conv2d* cv) {
    const image_layout l = layout_of(cv);
    return (size_t)cv->C * l.Hp * l.row;
}

void mlb_gemm_bf16_image(const mlb_conv2d* cv, const float* img, int c0, int c1, uint16_t* out) {
#ifdef MLB_BF16_KERNEL
    image_channels(cv, img, c0, c1, out);
#else
    (void)cv; (void)img; (void)c0; (void)c1; (void)out;
#endif
}

void mlb_gemm_bf16_pack(int side_b, int trans, int R, int K, const mlb_bf16_operand* X, uint32_t* out) {
#ifdef MLB_BF16_KERNEL
    if (R <= 0 || K <= 0) return;
    const int Rpad = side_b ? NR : MR, blocks = ((K + 1) / 2 + KC - 1) / KC, panels = (R + Rpad - 1) / Rpad;
    // the K blocks in parallel for a large operand (a conv's weight: up to 30M values in the SD UNet)
#pragma omp parallel for schedule(static) if (blocks > 1 && (size_t)R * K >= ((size_t)1 << 20))
    for (int blk = 0; blk < blocks; blk++) pack_block(out + (size_t)blk * KC * panels * Rpad, side_b, R, K, blk, X, trans, 0);
#else
    (void)side_b; (void)trans; (void)R; (void)K; (void)X; (void)out;
#endif
}

// C = bias per row and beta = 1: the bias of mlb_gemm_bf16_kernel_bias where the kernel does not run.
static void fill_bias(float* C, int ldc, int M, int N, const float* bias, float* beta) {
    for (int i = 0; i < M; i++)
        for (int j = 0; j < N; j++) C[(size_t)i * ldc + j] = bias[i];
    *beta = 1;
}

void mlb_gemm_bf16_kernel(int ta, int tb, int M, int N, int K, float alpha, const mlb_bf16_operand* A,
                          const mlb_bf16_operand* B, float beta, float* C, int ldc) {
    mlb_gemm_bf16_kernel_bias(ta, tb, M, N, K, alpha, A, B, beta, NULL, C, ldc);
}

void mlb_gemm_bf16_kernel_bias(int ta, int tb, int M, int N, int K, float alpha, const mlb_bf16_operand* A,
                               const mlb_bf16_operand* B, float beta, const float* bias, float* C, int ldc) {
    if (!cpu_has_bf16()) {   // never: every caller checks first; still correct if one did not
        if (bias) fill_bias(C, ldc, M, N, bias, &beta);
        gemm_elementwise(ta, tb, M, N, K, alpha, A, B, beta, C, ldc);
        return;
    }
#ifdef MLB_BF16_KERNEL
    const int kp = (K + 1) / 2, mpanels = (M + MR - 1) / MR, npanels = (N + NR - 1) / NR;
    const int kc = kp < KC ? kp : KC, mc = mpanels < MC ? mpanels : MC, blocks = (kp + KC - 1) / KC;
    // per K block: op(B) packed whole ([npanels][kc][NR]), op(A) MC panels at a time ([MC][kc][MR]),
    // unless given packed; over several K blocks the sums wait in fp32 tiles ([mpanels][npanels][MR][NR])
    uint32_t* pa = A->packed ? NULL : malloc(sizeof(uint32_t) * (size_t)mc * MR * kc);
    uint32_t* pb = B->packed ? NULL : malloc(sizeof(uint32_t) * (size_t)npanels * NR * kc);
    float* w = blocks > 1 ? malloc(sizeof(float) * (size_t)mpanels * npanels * MR * NR) : NULL;
    // AMX: the panels' last pairs past whole tile steps, zero-padded ([npanels] B tails, [MC] A tails);
    // only the last K block can end inside a tile step
    const int amx = mlb_gemm_bf16_amx(), tail_pairs = amx && ((kp - 1) % KC + 1) % 16;
    const size_t b_tail_words = mlb_gemm_amx_tail_words(1) * (size_t)npanels;
    uint32_t* tails = tail_pairs ? malloc(sizeof(uint32_t) * (b_tail_words + mlb_gemm_amx_tail_words(0) * (size_t)mc)) : NULL;
    if ((!A->packed && !pa) || (!B->packed && !pb) || (blocks > 1 && !w) || (tail_pairs && !tails)) {   // a few MB at most; never seen
        free(pa);
        free(pb);
        free(w);
        free(tails);
        mlb_log(MLB_LOG_WARN, "bf16 GEMM %dx%dx%d: out of memory for the packed operands; this one in fp32", M, N, K);
        if (bias) fill_bias(C, ldc, M, N, bias, &beta);
        if (A->data && B->data && !B->im2col) {
            cblas_sgemm(CblasRowMajor, ta ? CblasTrans : CblasNoTrans, tb ? CblasTrans : CblasNoTrans, M, N, K, alpha,
                        A->data + A->offset, A->ld, B->data + B->offset, B->ld, beta, C,
                        ldc);
            return;
        }
        gemm_elementwise(ta, tb, M, N, K, alpha, A, B, beta, C, ldc);   // a packed or im2col operand
        return;
    }
    uint32_t* a_tails = tails ? tails + b_tail_words : NULL;
    if (amx) mlb_gemm_amx_begin();
    for (int blk = 0; blk < blocks; blk++) {
        const int p0 = blk * KC, np = kp - p0 < KC ? kp - p0 : KC;
        const int first = blk == 0, last = blk == blocks - 1;
        const uint32_t* pbk = B->packed ? B->packed + (size_t)p0 * npanels * NR : pb;
        if (!B->packed) pack_block(pb, 1, N, K, blk, B, tb, 0);
        const int tail = amx && np % 16;
        if (tail) mlb_gemm_amx_tails(1, pbk, npanels, np, tails);
        for (int q0 = 0; q0 < mpanels; q0 += MC) {
            int nq = mpanels - q0 < MC ? mpanels - q0 : MC;
            const uint32_t* pak = A->packed ? A->packed + (size_t)p0 * mpanels * MR + (size_t)q0 * MR * np : pa;
            if (!A->packed) {   // panels q0 .. q0 + nq of this block
                int rows = M - q0 * MR < nq * MR ? M - q0 * MR : nq * MR;
                pack_block(pa, 0, rows, K, blk, A, ta, q0 * MR);
            }
            if (tail) mlb_gemm_amx_tails(0, pak, nq, np, a_tails);
            for (int jp = 0; jp < npanels; jp++) {
                int j0 = jp * NR, cols = N - j0 < NR ? N - j0 : NR;
                for (int q = 0; q < nq; q += amx ? 2 : 1) {
                    int i0 = (q0 + q) * MR, rows = M - i0 < MR ? M - i0 : MR;
                    float* tile = w ? w + ((size_t)(q0 + q) * npanels + jp) * MR * NR : NULL;
                    const uint32_t *ap = pak + (size_t)q * MR * np, *bp = pbk + (size_t)jp * NR * np;
                    float* c = C + (size_t)i0 * ldc + j0;
                    const float* bi = bias ? bias + i0 : NULL;
                    if (amx) {   // two A panels at a time where there are two
                        const int two = q + 1 < nq;
                        if (two) rows = M - i0 < 2 * MR ? M - i0 : 2 * MR;
                        const uint32_t* at = tail ? a_tails + mlb_gemm_amx_tail_words(0) * (size_t)q : NULL;
                        const uint32_t* bt = tail ? tails + mlb_gemm_amx_tail_words(1) * (size_t)jp : NULL;
                        mlb_gemm_amx_tiles(1 + two, np, ap, bp, at, bt, first ? NULL : tile, last ? NULL : tile,
                                           (size_t)npanels * MR * NR, c, ldc, rows, cols, alpha, beta, bi);
                    } else {
                        micro_kernel(np, ap, bp, first ? NULL : tile, last ? NULL : tile, c, ldc, rows, cols, alpha,
                                     beta, bi);
                    }
                }
            }
        }
    }
    if (amx) mlb_gemm_amx_end();
    free(tails);
    free(pa);
    free(pb);
    free(w);
#endif
}
