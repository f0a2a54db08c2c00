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
 * Stockham autosort stage (radix R in {2, 3, 4, 5, 8}, sub-transform size p before the stage,
 * T = N / R; p R divides N, so every N = 2^a 3^b 5^c works):
 *   for i in [0, T):  k = i mod p
 *       u[r] = in[i + r T] * w^(r k),   w = exp(-2 pi i / (p R))  (table index r k N / (p R))
 *       u    = DFT_R(u)
 *       out[(i - k) R + k + r p] = u[r]
 * After the last stage (p R == N) the result is in natural order: no bit reversal pass.
 * Stage order: the power-of-two part first (its odd radix 2 or 4 at p == 1, then radix 8), then
 * every radix 3, then every radix 5 (fft_next_radix). Radix-2/4/8 stages thus always see a
 * power-of-two p (k = i & (p - 1)); radix-3/5 stages step k with a counter instead of a modulo.
 */
#ifndef CLHOLO_FFT_COMMON_H
#define CLHOLO_FFT_COMMON_H

#if FFT_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
typedef double2 real2;
typedef double4 real4;
#define REAL_SQRT1_2 0.70710678118654752440
#define RL(x) x
#else
typedef float real;
typedef float2 real2;
typedef float4 real4;
#define REAL_SQRT1_2 0.70710678118654752440f
#define RL(x) x##f
#endif
/* cos and sin of 2 pi / 3, 2 pi / 5 and 4 pi / 5 (radix-3 and radix-5 butterflies) */
#define C3_S1 RL(0.86602540378443864676)
#define C5_C1 RL(0.30901699437494742410)
#define C5_C2 RL(-0.80901699437494742410)
#define C5_S1 RL(0.95105651629515357212)
#define C5_S2 RL(0.58778525229247312917)

/* scalar complex helpers (GPU kernel and the odd scalar path of the CPU kernel) */
static inline real2 c_mul(real2 a, real2 b)
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

/* radix 8 as 2 x radix 4 (decimation in time); w8 = exp(-i pi / 4). DFT8_JOIN: the last step,
 * the two DFT4 of the even and odd inputs (in a0 a2 a4 a6 and a1 a3 a5 a7) into the DFT8. */
#define DFT8_JOIN(TY, NEGI, a0, a1, a2, a3, a4, a5, a6, a7) {              \
        TY o1_ = ((a3) + NEGI(a3)) * REAL_SQRT1_2;   /* * w8   */              \
        TY o2_ = NEGI(a5);                           /* * w8^2 */              \
        TY o3_ = (NEGI(a7) - (a7)) * REAL_SQRT1_2;   /* * w8^3 */              \
        TY e0_ = (a0), e1_ = (a2), e2_ = (a4), e3_ = (a6), o0_ = (a1);         \
        (a0) = e0_ + o0_; (a4) = e0_ - o0_;                                    \
        (a1) = e1_ + o1_; (a5) = e1_ - o1_;                                    \
        (a2) = e2_ + o2_; (a6) = e2_ - o2_;                                    \
        (a3) = e3_ + o3_; (a7) = e3_ - o3_; }
#define DFT8(TY, NEGI, a0, a1, a2, a3, a4, a5, a6, a7) {                   \
        DFT4(TY, NEGI, a0, a2, a4, a6);                                        \
        DFT4(TY, NEGI, a1, a3, a5, a7);                                        \
        DFT8_JOIN(TY, NEGI, a0, a1, a2, a3, a4, a5, a6, a7); }

/* DFT4 and DFT8 of inputs whose second half is zero (a2 = a3 = 0; a4 .. a7 = 0): they read
 * only the first half and do DFT4's / DFT8's operations less the additions of those zeros, so
 * the same bits (but for the sign of a zero result). For the zero-padded half of a transform's
 * input (fft_cpu.cl, stage_half_input). */
#define DFT4_HALF(TY, NEGI, a0, a1, a2, a3) {                              \
        TY x_ = (a0), n_ = NEGI(a1);                                           \
        (a0) = x_ + (a1); (a2) = x_ - (a1);                                    \
        (a1) = x_ + n_; (a3) = x_ - n_; }
#define DFT8_HALF(TY, NEGI, a0, a1, a2, a3, a4, a5, a6, a7) {              \
        DFT4_HALF(TY, NEGI, a0, a2, a4, a6);                                   \
        DFT4_HALF(TY, NEGI, a1, a3, a5, a7);                                   \
        DFT8_JOIN(TY, NEGI, a0, a1, a2, a3, a4, a5, a6, a7); }

/* radix 3: y_r = sum_m a_m w^(r m), w = exp(-2 pi i / 3) = -1/2 - i sin(2 pi / 3) */
#define DFT3(TY, NEGI, a0, a1, a2) {                                       \
        TY s_ = (a1) + (a2), d_ = NEGI(((a1) - (a2)) * C3_S1);                 \
        TY m_ = (a0) - s_ * RL(0.5);                                           \
        (a0) = (a0) + s_; (a1) = m_ + d_; (a2) = m_ - d_; }

/* radix 5, w = exp(-2 pi i / 5): pairs (1, 4) and (2, 3) share cosines and flip sines */
#define DFT5(TY, NEGI, a0, a1, a2, a3, a4) {                               \
        TY s14_ = (a1) + (a4), d14_ = (a1) - (a4);                             \
        TY s23_ = (a2) + (a3), d23_ = (a2) - (a3);                             \
        TY m1_ = (a0) + s14_ * C5_C1 + s23_ * C5_C2;                           \
        TY m2_ = (a0) + s14_ * C5_C2 + s23_ * C5_C1;                           \
        TY n1_ = NEGI(d14_ * C5_S1 + d23_ * C5_S2);                            \
        TY n2_ = NEGI(d14_ * C5_S2 - d23_ * C5_S1);                            \
        (a0) = (a0) + s14_ + s23_;                                             \
        (a1) = m1_ + n1_; (a4) = m1_ - n1_;                                    \
        (a2) = m2_ + n2_; (a3) = m2_ - n2_; }

/* Radix of the stage that follows sub-transform size p of a length-N transform (see the stage
 * order above); n2 = the largest power of two dividing N. */
static inline int fft_next_radix(int N, int p)
{
    const int n2 = N & -N;
    if (p < n2) {
        const int rem = (31 - clz(n2)) - (31 - clz(p));
        return (p == 1 && rem % 3 == 1) ? 2 : (p == 1 && rem % 3 == 2) ? 4 : 8;
    }
    return ((N / p) % 3 == 0) ? 3 : 5;
}

/* The arguments every pass kernel starts with (FFT_PASS_ARGS: source and destination geometry,
 * the transform length and twiddles, the optional pointwise multiply, conjugations and scale;
 * see fft_cpu.cl's header comment) and each kernel's own (FFT_STRIP_ARGS, FFT_LINES_ARGS,
 * FFT_STAGE_ARGS) are declared once, in clholo/fft.py (FFT_PASS_ARGS, FFT_KERNEL_ARGS), which
 * prepends their #defines to the program source and sets the host dtypes from the same table. */
#ifndef FFT_PASS_ARGS
#error "FFT_PASS_ARGS is defined by clholo/fft.py (kernel_arg_macros); build through FFTPlan"
#endif

/* Load and store callbacks (clholo.fft.FFTCallback). The host prepends the callback's source
 * and defines, per pass program:
 *   FFT_LOAD_CB    1: the first pass calls clholo_load(v, b, row, col, extra...) on every element
 *                  of the input window as it loads it (before the fused multiply and conj_in);
 *                  elements of the zero padding stay zero and are not passed.
 *   FFT_STORE_CB   1: the last pass calls clholo_store(ptr, v, b, row, col, extra...) for every
 *                  element of the output window instead of *ptr = v (after conj_out, scale and
 *                  the fused multiply); the callback writes *ptr, or something else, or nothing.
 *   FFT_LOAD_CB_PARAMS / FFT_LOAD_CB_ARGS (and STORE): ", type cbl0, ..." kernel parameters
 *                  and ", cbl0, ..." arguments of the extra buffers and scalars.
 *   FFT_STORE_CB_QUAD  defined by a store callback's source when it also has
 *                  clholo_store4(ptr, v0, v1, v2, v3, b, row, col, extra...) for the four
 *                  adjacent elements (row, col .. col + 3), col a multiple of 4: the CPU variant
 *                  calls it wherever it holds such runs (its vectors), clholo_store elsewhere.
 *   FFT_LOAD_CB_OCT / FFT_STORE_CB_OCT  defined by a float32 callback's source when it also
 *                  has clholo_load8(float16 *v, b, row, col, extra...) / clholo_store8(ptr,
 *                  const float16 *v, b, row, col, extra...) for the eight adjacent elements
 *                  (row, col .. col + 7), col a multiple of 8, interleaved (re, im) in *v
 *                  (private memory; clholo_load8 updates it in place): the CPU strips call
 *                  them where they hold such runs (rows loaded or stored whole), the scalar
 *                  forms elsewhere.
 *   FFT_CB_LAYOUT  0: lines are rows (row = l, col = k); 1: lines are columns (row = k,
 *                  col = l); 2: 1D plan (b = line, row = 0, col = k).
 *   FFT_MID_CB     1: a round-trip pass (FFT_ROUND_TRIP) calls clholo_mid(v, b, row, col, extra...)
 *                  on every element k < mid_n between its two transforms (after mid_conj_a,
 *                  mid_scale and a mid multiply, before mid_conj_b) and uses its return value;
 *                  elements k >= mid_n are set to zero and not passed. When the callback's
 *                  source defines FFT_MID_CB_QUAD it also has clholo_mid4(real2 *v, b, row,
 *                  col, extra...) for v[0..3] at (row, col .. col + 3), col a multiple of 4,
 *                  updated in place (private memory): the CPU variant calls it wherever it
 *                  holds such runs. A source that defines FFT_MID_CB_SWEEP is run by the GPU
 *                  kernels' fixed plans in a sweep over local memory after the first
 *                  transform, not folded into its last stage's outputs (a heavy callback).
 *   FFT_MID_CB_SUMS    defined by a mid callback's source that also adds something up over
 *                  the elements it sees: the kernels then call clholo_mid_acc(v, b, row, col,
 *                  real4 *acc, extra...) (one element at a time, no quad or row forms)
 *                  instead of clholo_mid, with acc a private running sum, and hand the sums to
 *                  clholo_mid_sums_store(real4 sum, b, part, extra...) once per part: a GPU
 *                  work-group (its work-items' sums added in a tree in local memory, part =
 *                  the group's index along the lines) or a CPU work-item (part = its index).
 *                  RoundTripPlan.mid_parts says how many parts a batch element has; the order
 *                  of every addition is fixed by the plan.
 * b is the flattened batch index, row/col the element's position in the transform frame.
 *
 * Round trip (FFT_ROUND_TRIP 1, clholo.fft.RoundTripPlan): the pass runs every stage of a line,
 * then the mid operation in fast memory (conj if mid_conj_a, times mid_scale, the multiply with
 * mul_mode 3 or 4 and the mid callback on elements < mid_n, zero beyond, conj if mid_conj_b), then
 * every stage again, and stores once: a forward and an inverse transform (either order) with a
 * pointwise step between them for one global read and one global write. mul_mode 4 is the
 * multiply of a factor frame that is even in both indices (f[l, k] == f[(nlines - l) % nlines,
 * (N - k) % N]: the ASM transfer functions, which depend on fx^2 and fy^2): element k and
 * line l read k' = min(k, N - k), l' = min(l, (nlines - l) % nlines), a quarter of the
 * frame's bytes for the same products (a column round trip at 2048^2 read 32 MB of H per
 * layer and waited on it: 1.19x the render on PoCL with the quarter). FFT_EVEN_INDEX(i, n) is
 * that fold, the one both kernel variants use, for 0 <= i < n (an element or a stored line:
 * every caller): min(i, (n - i) % n), whose modulo only mattered at i = 0 (min(0, n) is 0
 * either way), so without the integer division that a GPU computes in a few dozen
 * instructions where n is not a constant (per element of a column round trip). */
#define FFT_EVEN_INDEX(i, n) min((i), (n) - (i))
/* l % m for a line l >= 0 and a line period m (mul_lmod: a multiply's frames wrap every m
 * lines, or never, _NO_LINE_WRAP): no integer division while l < m, where every line of an
 * unwrapped multiply lies */
#define FFT_LINE_WRAP(l, m) ((l) < (m) ? (l) : (l) % (m))
#ifndef FFT_LOAD_CB
#define FFT_LOAD_CB 0
#endif
#ifndef FFT_STORE_CB
#define FFT_STORE_CB 0
#endif
#ifndef FFT_MID_CB
#define FFT_MID_CB 0
#endif
#ifndef FFT_ROUND_TRIP
#define FFT_ROUND_TRIP 0
#endif
#if !FFT_MID_CB
#define FFT_MID_CB_PARAMS
#define FFT_MID_CB_ARGS
#endif

#if !FFT_LOAD_CB
#define FFT_LOAD_CB_PARAMS
#define FFT_LOAD_CB_ARGS
#endif
#if !FFT_STORE_CB
#define FFT_STORE_CB_PARAMS
#define FFT_STORE_CB_ARGS
#endif
#ifndef FFT_CB_LAYOUT
#define FFT_CB_LAYOUT 0
#endif
#if FFT_CB_LAYOUT == 0
#define FFT_CB_POS(b, l, k) (long)(b), (int)(l), (int)(k)
#elif FFT_CB_LAYOUT == 1
#define FFT_CB_POS(b, l, k) (long)(b), (int)(k), (int)(l)
#else
#define FFT_CB_POS(b, l, k) (long)(l), 0, (int)(k)
#endif
/* every callback parameter a pass kernel takes, after its own (leading comma included) */
#define FFT_CB_PARAMS FFT_LOAD_CB_PARAMS FFT_STORE_CB_PARAMS FFT_MID_CB_PARAMS

#endif
