// CPU features from cpuid (leaf 1, 7.0, 7.1, the brand string) checked against XCR0, the register
// state the OS saves: AVX needs XMM|YMM, AVX-512 also the opmask and ZMM state, AMX the tile state.
#include "matlaber/cpu.h"
#include <stdio.h>
#include <string.h>
#include <strings.h>
#if defined(__x86_64__) || defined(__i386__)
#include <cpuid.h>
#define MLB_X86 1
#endif

#ifdef MLB_X86
static unsigned long long read_xcr0(void) {
    unsigned int lo, hi;
    __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));
    return ((unsigned long long)hi << 32) | lo;
}
#endif

void mlb_cpu_detect(mlb_cpu_info* info) {
    memset(info, 0, sizeof *info);
    strcpy(info->model, "unknown");
    strcpy(info->vendor, "unknown");
#ifdef MLB_X86
    unsigned int a = 0, b = 0, c = 0, d = 0, max_leaf = 0;
    if (!__get_cpuid(0, &max_leaf, &b, &c, &d)) return;
    memcpy(info->vendor, &b, 4);
    memcpy(info->vendor + 4, &d, 4);
    memcpy(info->vendor + 8, &c, 4);
    info->vendor[12] = 0;
    unsigned int ext_max = __get_cpuid_max(0x80000000u, NULL);
    if (ext_max >= 0x80000004u) {
        unsigned int r[12];
        for (unsigned int i = 0; i < 3; i++) __get_cpuid(0x80000002u + i, &r[4 * i], &r[4 * i + 1], &r[4 * i + 2], &r[4 * i + 3]);
        char brand[49];
        memcpy(brand, r, 48);
        brand[48] = 0;
        char* s = brand;
        while (*s == ' ') s++;
        size_t n = strlen(s);
        while (n && s[n - 1] == ' ') s[--n] = 0;
        if (n) snprintf(info->model, sizeof info->model, "%s", s);
    }
    __get_cpuid(1, &a, &b, &c, &d);
    int base_family = (a >> 8) & 0xf, base_model = (a >> 4) & 0xf;
    info->family = base_family == 0xf ? base_family + (int)((a >> 20) & 0xff) : base_family;
    info->model_id = (base_family == 0x6 || base_family == 0xf) ? (int)(((a >> 16) & 0xf) << 4) + base_model : base_model;
    int osxsave = (c >> 27) & 1, fma = (c >> 12) & 1, f16c = (c >> 29) & 1;
    unsigned long long xcr0 = osxsave ? read_xcr0() : 0;
    int os_avx = (xcr0 & 0x6) == 0x6, os_avx512 = os_avx && (xcr0 & 0xe0) == 0xe0;
    int os_amx = (xcr0 & 0x60000) == 0x60000;
    info->f16c = os_avx && f16c;
    if (max_leaf < 7) return;
    unsigned int b7 = 0, c7 = 0, d7 = 0, a71 = 0, b71 = 0, c71 = 0, d71 = 0;
    __get_cpuid_count(7, 0, &a, &b7, &c7, &d7);
    int max_sub = (int)a;
    if (max_sub >= 1) __get_cpuid_count(7, 1, &a71, &b71, &c71, &d71);
    info->avx2 = os_avx && ((b7 >> 5) & 1);
    info->fma = os_avx && fma;
    info->avx512f = os_avx512 && ((b7 >> 16) & 1);
    info->avx512dq = os_avx512 && ((b7 >> 17) & 1);
    info->avx512cd = os_avx512 && ((b7 >> 28) & 1);
    info->avx512bw = os_avx512 && ((b7 >> 30) & 1);
    info->avx512vl = os_avx512 && ((b7 >> 31) & 1);
    info->avx512_fp16 = os_avx512 && ((d7 >> 23) & 1);
    info->avx512_bf16 = os_avx512 && ((a71 >> 5) & 1);
    info->amx_bf16 = os_amx && ((d7 >> 22) & 1);
    info->amx_tile = os_amx && ((d7 >> 24) & 1);
#endif
}

void mlb_cpu_feature_string(const mlb_cpu_info* f, char* buf, size_t size) {
    const struct { int on; const char* name; } list[] = {
        {f->avx2, "avx2"}, {f->fma, "fma"}, {f->f16c, "f16c"}, {f->avx512f, "avx512f"}, {f->avx512bw, "avx512bw"},
        {f->avx512vl, "avx512vl"}, {f->avx512dq, "avx512dq"}, {f->avx512cd, "avx512cd"},
        {f->avx512_bf16, "avx512_bf16"}, {f->avx512_fp16, "avx512_fp16"}, {f->amx_tile, "amx_tile"},
        {f->amx_bf16, "amx_bf16"}};
    size_t used = 0;
    if (size) buf[0] = 0;
    for (size_t i = 0; i < sizeof list / sizeof list[0]; i++) {
        if (!list[i].on) continue;
        int w = snprintf(buf + used, size > used ? size - used : 0, "%s%s", used ? " " : "", list[i].name);
        if (w < 0 || (size_t)w >= (size > used ? size - used : 0)) break;
        used += (size_t)w;
    }
    if (size && used == 0) snprintf(buf, size, "(none of avx2, avx-512, amx)");
}

// OpenBLAS's x86-64 kernel families, weakest first. Zen runs the Haswell kernels with other
// blocking, so the two rank the same; SapphireRapids adds AMX bf16 GEMMs to Cooperlake's.
static const struct { const char* name; int rank; } families[] = {
    {"Prescott", 0}, {"Core2", 1}, {"Penryn", 1}, {"Dunnington", 1}, {"Nehalem", 2}, {"Barcelona", 2},
    {"Bulldozer", 3}, {"Piledriver", 3}, {"Steamroller", 3}, {"Excavator", 3}, {"Sandybridge", 3},
    {"Haswell", 4}, {"Zen", 4}, {"SkylakeX", 5}, {"Cooperlake", 6}, {"SapphireRapids", 7}};

static int family_rank(const char* name) {
    for (size_t i = 0; i < sizeof families / sizeof families[0]; i++)
        if (name && strcasecmp(name, families[i].name) == 0) return families[i].rank;
    return -1;
}

const char* mlb_blas_coretype_for(const char* current, const mlb_cpu_info* f) {
    const char* best = NULL;
    if (f->avx512f && f->avx512bw && f->avx512vl && f->avx512dq && f->avx512cd)
        best = f->avx512_bf16 ? "Cooperlake" : "SkylakeX";
    else if (f->avx2 && f->fma)
        best = "Haswell";
    int have = family_rank(current);
    if (!best || have < 0) return NULL;   // nothing better, or a family this table does not know
    return have < family_rank(best) ? best : NULL;
}
