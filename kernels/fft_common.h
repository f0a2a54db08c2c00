/* Shared definitions of clholo's FFT kernels (fft_cpu.cl, fft_gpu.cl).
 *
 * Build defines:
 *   FFT_DOUBLE  0: complex64 (float2), 1: complex128 (double2; needs cl_khr_fp64).
 *
 * Conventions: every transform is a *forward* DFT, X[k] = sum_n x[n] exp(-2 pi i k n / N)
 * (NumPy's sign). The host runs an inverse as conj(FFT(conj(x))) / N, folding both
 * conjugations and the 1/N into the first load and the last store, so the butterflies exist in
 * one direction only and the twiddle table is shared by both directions.
 *
 * Stockham autosort stage (radix R, sub-transform size p before the stage, T = N / R):
 *   for i in [0, T):  k = i mod p
 *       u[r] = in[i + r T] * w^(r k),   w = exp(-2 pi i / (p R))  (table index r k N / (p R))
 *       u    = DFT_R(u)
 *       out[(i - k) R + k + r p] = u[r]
 * After the last stage (p R == N) the result is in natural order: no bit reversal pass.
 */
#ifndef CLHOLO_FFT_COMMON_H
#define CLHOLO_FFT_COMMON_H

#if FFT_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
typedef double2 real2;
#define REAL_SQRT1_2 0.70710678118654752440
#else
typedef float real;
typedef float2 real2;
#define REAL_SQRT1_2 0.70710678118654752440f
#endif

/* scalar complex helpers (GPU kernel and the odd scalar path of the CPU kernel) */
inline real2 c_mul(real2 a, real2 b)
{
    return (real2)(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}
#define S_NEGI(a) ((real2)((a).y, -(a).x)) /* a * (-i) */
#define S_CONJ(a) ((real2)((a).x, -(a).y))

/* Butterflies, written once for any complex type TY whose "times -i" is NEGI(x). They use only
 * +, - and multiplication by real scalars, so vector types (several interleaved complex numbers
 * per vector) work as they are. Outputs overwrite inputs in natural order. */
#define DFT2(TY, a0, a1) { TY t_ = (a0) - (a1); (a0) = (a0) + (a1); (a1) = t_; }

#define DFT4(TY, NEGI, a0, a1, a2, a3) {                                   \
        TY t0_ = (a0) + (a2), t1_ = (a0) - (a2);                               \
        TY t2_ = (a1) + (a3), t3_ = NEGI((a1) - (a3));                         \
        (a0) = t0_ + t2_; (a2) = t0_ - t2_;                                    \
        (a1) = t1_ + t3_; (a3) = t1_ - t3_; }

/* radix 8 as 2 x radix 4 (decimation in time); w8 = exp(-i pi / 4) */
#define DFT8(TY, NEGI, a0, a1, a2, a3, a4, a5, a6, a7) {                   \
        DFT4(TY, NEGI, a0, a2, a4, a6);                                        \
        DFT4(TY, NEGI, a1, a3, a5, a7);                                        \
        TY o1_ = ((a3) + NEGI(a3)) * REAL_SQRT1_2;   /* * w8   */              \
        TY o2_ = NEGI(a5);                           /* * w8^2 */              \
        TY o3_ = (NEGI(a7) - (a7)) * REAL_SQRT1_2;   /* * w8^3 */              \
        TY e0_ = (a0), e1_ = (a2), e2_ = (a4), e3_ = (a6), o0_ = (a1);         \
        (a0) = e0_ + o0_; (a4) = e0_ - o0_;                                    \
        (a1) = e1_ + o1_; (a5) = e1_ - o1_;                                    \
        (a2) = e2_ + o2_; (a6) = e2_ - o2_;                                    \
        (a3) = e3_ + o3_; (a7) = e3_ - o3_; }

/* The arguments every pass kernel starts with, in the order clholo/fft.py sets them: source and
 * destination geometry, the transform length and twiddles, the optional pointwise multiply,
 * conjugations and scale (see fft_cpu.cl's header comment for their meaning). */
#define FFT_PASS_ARGS                                                                         \
    __global const real2 *src, long src_off, long src_bs, long src_ls, long src_es,          \
    int src_nl, int src_ne,                                                                   \
    __global real2 *dst, long dst_off, long dst_bs, long dst_ls, long dst_es,                 \
    int nlines, int nstore,                                                                   \
    int N, __global const real2 *tw,                                                          \
    __global const real2 *mul, long mul_off, long mul_bs, int mul_m, long mul_ls,             \
    int mul_lmod, long mul_es,                                                                \
    int mul_mode, int conj_in, int conj_out, real scale

#endif
