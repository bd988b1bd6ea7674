// The entries of one op table of backend.c, generated from the op list (backend_ops.def) by name,
// so that no two ops can trade places; included inside the table's initialiser, no include guard
// on purpose. A CPU table: every op is cpu_<op> but the GEMM ops, CPU_GEMM(op) (the includer's,
// #undef'd at the end). With TABLE_CUDA defined, a CUDA table: an op of the list points at its
// CUDA function, a GEMM op at the wrapper cuda_<op> (at the table's precision), a memory or light
// op at the hand-written cuda_<op>.
#ifdef TABLE_CUDA
#define MLB_OP(name, cuda_fn, params) .name = cuda_fn,
#define MLB_GEMM_OP(name, cuda_fn, params, args) .name = cuda_##name,
#define MLB_DEVICE_OP(ret, name, params) .name = cuda_##name,
#else
#define MLB_OP(name, cuda_fn, params) .name = cpu_##name,
#define MLB_GEMM_OP(name, cuda_fn, params, args) .name = CPU_GEMM(name),
#define MLB_DEVICE_OP(ret, name, params) .name = cpu_##name,
#endif
#include "matlaber/backend_ops.def"
#undef CPU_GEMM
