// Internal: whether the CPU's AVX-512 fp32 kernels (groupnorm_avx512.c, softmax_avx512.c) run here.
#ifndef MATLABER_NN_AVX512_GATE_H
#define MATLABER_NN_AVX512_GATE_H

// A CPU with AVX-512 F/BW/VL/DQ, and not forced off (mlb_avx512_force_scalar, or
// $MATLABER_CPU_AVX512=0, read once): then the float passes of group norm and of the attention's
// softmax take the vectorised loops; else their scalar ones.
int mlb_avx512_kernels(void);
void mlb_avx512_force_scalar(int on);   // tests: run the scalar loops (1) or the default again (0)
#endif
