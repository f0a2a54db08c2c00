/* clholo FFT, CPU variant: one work-item owns a strip of LANES lines and runs every stage on
 * them without barriers.
 *
 * Why this shape (measured on PoCL 3.0, see issue 3): PoCL does not vectorize across work-items
 * when a kernel has loops, but it does compile explicit vector types to SIMD. So a "line" of the
 * working set is one vector `vt` holding LANES interleaved complex numbers (float16 = 8 complex =
 * one 64-byte cache line), one per line of the strip; every butterfly then works on LANES lines
 * at once and all lanes share the same twiddle (broadcast). A strip is copied into work-group
 * local memory (on a CPU: a per-thread scratch that stays in L1/L2) in natural order, the Stockham
 * stages ping-pong between two local halves, and the last pass writes back. No barriers, no
 * transposes in global memory. The same kernel does column passes (lines are adjacent columns:
 * line stride 1, vector loads of whole cache lines) and row passes (lines are rows: gathered into
 * lanes by an in-register transpose where the geometry allows, else element by element).
 *
 * Build defines: FFT_DOUBLE (see fft_common.h), VW = 2 * LANES = reals per vector
 * (2, 4, 8 or 16).
 *
 * Pass arguments (shared with fft_gpu.cl), all strides and offsets in complex elements:
 *   src, src_off, src_bs (batch), src_ls (line), src_es (element), src_nl, src_ne:
 *       line l, element k of batch b is src[src_off + b src_bs + l src_ls + k src_es] when
 *       l < src_nl and k < src_ne, else 0 (zero padding without a copy)
 *   dst, dst_off, dst_bs, dst_ls, dst_es, nlines, nstore: lines l < nlines, elements k < nstore
 *       are written (cropping without a copy)
 *   mul ...: optional pointwise factor mul[mul_off + (b % mul_m) mul_bs + (l % mul_lmod) mul_ls + k mul_es],
 *       applied at load (mul_mode 1, before conj_in) or at store (mul_mode 2, after conj_out
 *       and scale)
 *   conj_in, conj_out, scale: the inverse transform as conj(FFT(conj x)) / N
 *   mid_n, mid_conj_a, mid_conj_b, mid_scale: the round trip's step between its transforms
 *       (FFT_ROUND_TRIP 1, see fft_common.h; mul_mode 3 multiplies there, mul_mode 4 by an even
 *       factor frame read in its quarter)
 */
#include "fft_common.h"
#include "fft_mid_acc.h"
#include "transpose8.h"
#include "cpu_wide.h"

/* NEXT_PF 1: the strips prefetch the next work-item's lines (NEXT_PREFETCH below; nothing
 * where CLHOLO_PREFETCH is empty: GPUs, Oclgrind). 0 turns it off, to compare. */
#ifndef NEXT_PF
#define NEXT_PF 1
#endif

#define LANES (VW / 2)

#if VW == 16
#define VCAT(a) a##16
#define VSWAP(x) ((x).s1032547698badcfe)
#define VEVEN(x) ((x).s0022446688aaccee)
#define VODD(x) ((x).s1133557799bbddff)
#define VPAT(a, b) ((vt)(a, b, a, b, a, b, a, b, a, b, a, b, a, b, a, b))
#define VPAIR(w) ((vt)(w, w, w, w, w, w, w, w)) /* one complex number in every lane */
#define VREV(x) ((x).sefcdab8967452301) /* the complex lanes in reverse order */
#elif VW == 8
#define VCAT(a) a##8
#define VSWAP(x) ((x).s10325476)
#define VEVEN(x) ((x).s00224466)
#define VODD(x) ((x).s11335577)
#define VPAT(a, b) ((vt)(a, b, a, b, a, b, a, b))
#define VPAIR(w) ((vt)(w, w, w, w))
#define VREV(x) ((x).s67452301)
#elif VW == 4
#define VCAT(a) a##4
#define VSWAP(x) ((x).s1032)
#define VEVEN(x) ((x).s0022)
#define VODD(x) ((x).s1133)
#define VPAT(a, b) ((vt)(a, b, a, b))
#define VPAIR(w) ((vt)(w, w))
#define VREV(x) ((x).s2301)
#elif VW == 2
#define VCAT(a) a##2
#define VSWAP(x) ((x).s10)
#define VEVEN(x) ((x).s00)
#define VODD(x) ((x).s11)
#define VPAT(a, b) ((vt)(a, b))
#define VPAIR(w) ((vt)(w))
#define VREV(x) (x)
#else
#error "VW must be 2, 4, 8 or 16"
#endif

#if FFT_DOUBLE
typedef VCAT(double) vt;
#else
typedef VCAT(float) vt;
#endif
/* Global vector access through an under-aligned vector type rather than vloadN/vstoreN: for
 * 16-wide vectors PoCL (AVX2) emits those builtins as out-of-line calls with the vector passed
 * in memory. Element alignment is all a strip start guarantees. */
typedef vt vt_unaligned __attribute__((aligned(sizeof(real2))));
#define VLOAD(p) (*(__global const vt_unaligned *)(p))
#define VSTORE(v, p) (*(__global vt_unaligned *)(p) = (v))

/* In-register transpose of LANES x LANES complex numbers (LANES vectors): after it, vector m
 * holds element m of every input vector (transpose8.h for LANES 8; butterfly swaps of 1 and 2
 * complex numbers for LANES 4). Used to gather rows into lanes from whole-cache-line loads
 * instead of one 8-byte load per element. */
#if VW == 16
#define HAVE_TRANSPOSE 1
#define TRANSPOSE(v) CLHOLO_TRANSPOSE8(vt, v)
#elif VW == 8
#define HAVE_TRANSPOSE 1
#define TSWAP1(a, b) { vt t_ = (vt)((a).s01, (b).s01, (a).s45, (b).s45);                         \
                       (b) = (vt)((a).s23, (b).s23, (a).s67, (b).s67); (a) = t_; }
#define TSWAP2(a, b) { vt t_ = (vt)((a).lo, (b).lo); (b) = (vt)((a).hi, (b).hi); (a) = t_; }
#define TRANSPOSE(v) {                                                                       \
        TSWAP1(v[0], v[1]); TSWAP1(v[2], v[3]); TSWAP2(v[0], v[2]); TSWAP2(v[1], v[3]); }
#else
#define HAVE_TRANSPOSE 0
#endif

/* x * (-i) on every lane: swap re/im, then a constant sign vector (no run-time shuffles) */
#define V_NEGI(x) (VSWAP(x) * VPAT(1, -1))
/* x * w with one twiddle w broadcast to all lanes. Plain a*b + c: PoCL contracts it to an FMA,
 * while the fma() builtin on vectors became an out-of-line call (issue 3). */
#define V_CMULB(v_, w_) ((v_) * (vt)((w_).x) + VSWAP(v_) * ((vt)((w_).y) * VPAT(-1, 1)))
/* x * tw[i] with the table's second half (clholo/fft.py _twiddle_table: tw[N + i] =
 * (-Im tw[i], Im tw[i])): both factors are broadcast loads, no sign pattern built per
 * butterfly; the same products as V_CMULB, bit for bit */
#define V_CMULT(v_, i_) ((v_) * (vt)(tw[i_].x) + VSWAP(v_) * VPAIR(tw[N + (i_)]))
/* x * m lane by lane (m holds LANES complex factors) */
#define V_CMULV(x, m) ((x) * VEVEN(m) + VSWAP(x) * (VODD(m) * VPAT(-1, 1)))

static CPU_WIDE
void stage2(__local const vt *in, __local vt *out, int N, int p, __global const real2 *tw)
{
    const int T = N >> 1, ts = N / (p * 2);
    for (int i = 0; i < T; ++i) {
        const int k = i & (p - 1), j = ((i - k) << 1) + k;
        vt a0 = in[i], a1 = in[i + T];
        if (p > 1) a1 = V_CMULT(a1, k * ts);
        DFT2(vt, a0, a1);
        out[j] = a0; out[j + p] = a1;
    }
}

static CPU_WIDE
void stage4(__local const vt *in, __local vt *out, int N, int p, __global const real2 *tw)
{
    const int T = N >> 2, ts = N / (p * 4);
    for (int i = 0; i < T; ++i) {
        const int k = i & (p - 1), j = ((i - k) << 2) + k;
        vt a0 = in[i], a1 = in[i + T], a2 = in[i + 2 * T], a3 = in[i + 3 * T];
        if (p > 1) {
            const int t = k * ts;
            a1 = V_CMULT(a1, t); a2 = V_CMULT(a2, 2 * t); a3 = V_CMULT(a3, 3 * t);
        }
        DFT4(vt, V_NEGI, a0, a1, a2, a3);
        out[j] = a0; out[j + p] = a1; out[j + 2 * p] = a2; out[j + 3 * p] = a3;
    }
}

/* A radix-8 butterfly's inputs in[i + r T] into a0 .. a7, times the twiddles of t = k ts
 * (none when p == 1): stage8 and stage8_low_output. */
#define STAGE8_INPUTS(i, T, p, t)                                                       \
        vt a0 = in[i], a1 = in[(i) + (T)], a2 = in[(i) + 2 * (T)], a3 = in[(i) + 3 * (T)];  \
        vt a4 = in[(i) + 4 * (T)], a5 = in[(i) + 5 * (T)], a6 = in[(i) + 6 * (T)];        \
        vt a7 = in[(i) + 7 * (T)];                                                      \
        if ((p) > 1) {                                                                  \
            a1 = V_CMULT(a1, t);     a2 = V_CMULT(a2, 2 * (t));                         \
            a3 = V_CMULT(a3, 3 * (t)); a4 = V_CMULT(a4, 4 * (t));                       \
            a5 = V_CMULT(a5, 5 * (t)); a6 = V_CMULT(a6, 6 * (t));                       \
            a7 = V_CMULT(a7, 7 * (t));                                                  \
        }

static CPU_WIDE
void stage8(__local const vt *in, __local vt *out, int N, int p, __global const real2 *tw)
{
    const int T = N >> 3, ts = N / (p * 8);
    for (int i = 0; i < T; ++i) {
        const int k = i & (p - 1), j = ((i - k) << 3) + k;
        STAGE8_INPUTS(i, T, p, k * ts);
        DFT8(vt, V_NEGI, a0, a1, a2, a3, a4, a5, a6, a7);
        out[j] = a0;         out[j + p] = a1;     out[j + 2 * p] = a2; out[j + 3 * p] = a3;
        out[j + 4 * p] = a4; out[j + 5 * p] = a5; out[j + 6 * p] = a6; out[j + 7 * p] = a7;
    }
}

/* Radix-3 and radix-5 stages run after the power-of-two ones, so p is any 2^a 3^b 5^c: k = i mod p
 * and the output base (i - k) R advance by counters instead of an integer modulo per butterfly. */
static CPU_WIDE
void stage3(__local const vt *in, __local vt *out, int N, int p, __global const real2 *tw)
{
    const int T = N / 3, ts = N / (p * 3);
    int k = 0, jb = 0;
    for (int i = 0; i < T; ++i) {
        const int j = jb + k;
        vt a0 = in[i], a1 = in[i + T], a2 = in[i + 2 * T];
        if (p > 1) {
            const int t = k * ts;
            a1 = V_CMULT(a1, t); a2 = V_CMULT(a2, 2 * t);
        }
        DFT3(vt, V_NEGI, a0, a1, a2);
        out[j] = a0; out[j + p] = a1; out[j + 2 * p] = a2;
        if (++k == p) { k = 0; jb += 3 * p; }
    }
}

static CPU_WIDE
void stage5(__local const vt *in, __local vt *out, int N, int p, __global const real2 *tw)
{
    const int T = N / 5, ts = N / (p * 5);
    int k = 0, jb = 0;
    for (int i = 0; i < T; ++i) {
        const int j = jb + k;
        vt a0 = in[i], a1 = in[i + T], a2 = in[i + 2 * T], a3 = in[i + 3 * T], a4 = in[i + 4 * T];
        if (p > 1) {
            const int t = k * ts;
            a1 = V_CMULT(a1, t);     a2 = V_CMULT(a2, 2 * t);
            a3 = V_CMULT(a3, 3 * t); a4 = V_CMULT(a4, 4 * t);
        }
        DFT5(vt, V_NEGI, a0, a1, a2, a3, a4);
        out[j] = a0; out[j + p] = a1; out[j + 2 * p] = a2; out[j + 3 * p] = a3; out[j + 4 * p] = a4;
        if (++k == p) { k = 0; jb += 5 * p; }
    }
}

/* Radix 9 as 3 x 3 (a length-9 DFT: three DFT3 of stride 3, the twiddles w9^(n2 k1), three
 * DFT3 again; outputs transposed): one pass over the strip where two radix-3 stages made two.
 * On CPUs the strip's stages stream through L2 (a 1944-point strip of complex64 lanes is
 * 124 KB), so fewer passes are fewer bytes; the arithmetic stays that of two radix-3 stages.
 * 1944 = 8 9 9 3 and 1125 = 9 5 5 5: four stages where there were six and five. */
#define W9_1 ((real2)(RL(0.76604444311897803520), RL(-0.64278760968653932632)))
#define W9_2 ((real2)(RL(0.17364817766693034885), RL(-0.98480775301220805936)))
#define W9_4 ((real2)(RL(-0.93969262078590838405), RL(-0.34202014332566873304)))
static CPU_WIDE
void stage9(__local const vt *in, __local vt *out, int N, int p, __global const real2 *tw)
{
    const int T = N / 9, ts = N / (p * 9);
    int k = 0, jb = 0;
    for (int i = 0; i < T; ++i) {
        const int j = jb + k;
        vt a0 = in[i], a1 = in[i + T], a2 = in[i + 2 * T], a3 = in[i + 3 * T];
        vt a4 = in[i + 4 * T], a5 = in[i + 5 * T], a6 = in[i + 6 * T], a7 = in[i + 7 * T];
        vt a8 = in[i + 8 * T];
        if (p > 1) {
            const int t = k * ts;
            a1 = V_CMULT(a1, t);     a2 = V_CMULT(a2, 2 * t);
            a3 = V_CMULT(a3, 3 * t); a4 = V_CMULT(a4, 4 * t);
            a5 = V_CMULT(a5, 5 * t); a6 = V_CMULT(a6, 6 * t);
            a7 = V_CMULT(a7, 7 * t); a8 = V_CMULT(a8, 8 * t);
        }
        DFT3(vt, V_NEGI, a0, a3, a6);
        DFT3(vt, V_NEGI, a1, a4, a7);
        DFT3(vt, V_NEGI, a2, a5, a8);
        a4 = V_CMULB(a4, W9_1); a7 = V_CMULB(a7, W9_2);
        a5 = V_CMULB(a5, W9_2); a8 = V_CMULB(a8, W9_4);
        DFT3(vt, V_NEGI, a0, a1, a2);   /* X0, X3, X6 */
        DFT3(vt, V_NEGI, a3, a4, a5);   /* X1, X4, X7 */
        DFT3(vt, V_NEGI, a6, a7, a8);   /* X2, X5, X8 */
        out[j] = a0;         out[j + p] = a3;     out[j + 2 * p] = a6;
        out[j + 3 * p] = a1; out[j + 4 * p] = a4; out[j + 5 * p] = a7;
        out[j + 6 * p] = a2; out[j + 7 * p] = a5; out[j + 8 * p] = a8;
        if (++k == p) { k = 0; jb += 9 * p; }
    }
}

/* The CPU strips' stage order: fft_next_radix's (fft_common.h), with two radix-3 stages
 * merged into one radix 9 wherever the rest of the length has the factor 9 (the GPU variant
 * and the host's plans keep radix 3). */
static CPU_WIDE int cpu_next_radix(int N, int p)
{
    if (p >= (N & -N) && (N / p) % 9 == 0) return 9;
    return fft_next_radix(N, p);
}

/* FFT_PRUNE 1: a transform whose input is zero from element N / 2 on (zero padding: the column
 * round trip's first transform at pad 2, the row round trip's second one after the crop) runs
 * its first stage on the nonzero half alone (stage_half_input), and nobody writes the zeros of
 * the upper half; one whose outputs from N / 2 on nobody reads (the crop) leaves them out of
 * its last stage where that is radix 8 (stage8_low_output). Why: on CPUs a strip's stages
 * stream through L2, so the half not read or written is time (the 1024^2 pad-2 render
 * 1.05-1.09x on a Zen 4, docs/benchmarks.md). 0 keeps every stage whole, to compare; the same bits. */
#ifndef FFT_PRUNE
#define FFT_PRUNE 1
#endif

/* Whether a length-N transform whose input elements from nz on are zero runs the pruned first
 * stage: N even (its first stage is then radix 2, 4 or 8 with p = 1, reading elements
 * i + r N / R) and nz <= N / 2. */
static CPU_WIDE int upper_half_zero(int N, int nz)
{
    return FFT_PRUNE && (N & 1) == 0 && 2 * nz <= N;
}

/* How far a strip whose elements from nz on are zero must be zero-filled for run_stages. */
static CPU_WIDE int zero_fill_end(int N, int nz)
{
    return upper_half_zero(N, nz) ? N / 2 : N;
}

/* The first stage (p = 1, radix R = 2, 4 or 8, no twiddles) of a transform whose input is zero
 * from element N / 2 on: each butterfly reads its R / 2 inputs below N / 2 (in[i + r T],
 * r < R / 2) and writes R outputs, as stage2/4/8 would with the zeros. Radix 2 is a copy. */
static CPU_WIDE
void stage_half_input(__local const vt *in, __local vt *out, int N, int R)
{
    const int T = N / R;
    if (R == 2) {
        for (int i = 0; i < T; ++i) {
            const vt a0 = in[i];
            out[2 * i] = a0; out[2 * i + 1] = a0;
        }
    } else if (R == 4) {
        for (int i = 0; i < T; ++i) {
            vt a0 = in[i], a1 = in[i + T], a2, a3;
            DFT4_HALF(vt, V_NEGI, a0, a1, a2, a3);
            const int j = i << 2;
            out[j] = a0; out[j + 1] = a1; out[j + 2] = a2; out[j + 3] = a3;
        }
    } else {
        for (int i = 0; i < T; ++i) {
            vt a0 = in[i], a1 = in[i + T], a2 = in[i + 2 * T], a3 = in[i + 3 * T];
            vt a4, a5, a6, a7;
            DFT8_HALF(vt, V_NEGI, a0, a1, a2, a3, a4, a5, a6, a7);
            const int j = i << 3;
            out[j] = a0;     out[j + 1] = a1; out[j + 2] = a2; out[j + 3] = a3;
            out[j + 4] = a4; out[j + 5] = a5; out[j + 6] = a6; out[j + 7] = a7;
        }
    }
}

/* The last stage of a power-of-two length N when radix 8 (p = N / 8) and only outputs below
 * N / 2 are read: stage8's butterflies, each storing its outputs r < 4 (out[i + r p]). */
static CPU_WIDE
void stage8_low_output(__local const vt *in, __local vt *out, int N, __global const real2 *tw)
{
    const int T = N >> 3;
    for (int i = 0; i < T; ++i) {
        STAGE8_INPUTS(i, T, T, i); /* p = T, k = i, ts = 1 */
        DFT8(vt, V_NEGI, a0, a1, a2, a3, a4, a5, a6, a7); /* a4 .. a7 unused: dropped */
        out[i] = a0; out[i + T] = a1; out[i + 2 * T] = a2; out[i + 3 * T] = a3;
    }
}

/* All stages of a length-N transform of the strip in `in`, ping-ponging with `out`; returns the
 * buffer holding the result (one of the two). Radix 8 wherever possible (fewest passes over the
 * scratch); the odd radix 2 or 4 goes first, where p == 1 and it needs no twiddles; then the
 * radix-3 and radix-5 stages (fft_common.h). Input elements from nz on are zero; when
 * upper_half_zero(N, nz), only those below N / 2 are read (and need to be written). Only
 * outputs below nout are read after; when that is at most N / 2 and the last stage is radix 8
 * with p = N / 8, the upper half is not written (stage8_low_output). */
static CPU_WIDE
__local vt *run_stages(__local vt *in, __local vt *out, int N, int nz, int nout,
                       __global const real2 *tw)
{
    __local vt *t;
    int p = 1;
    if (upper_half_zero(N, nz)) {
        p = cpu_next_radix(N, 1);
        stage_half_input(in, out, N, p);
        t = in; in = out; out = t;
    }
    while (p < N) {
        const int R = cpu_next_radix(N, p);
        if (R == 2) stage2(in, out, N, p, tw);
        else if (R == 4) stage4(in, out, N, p, tw);
        else if (R == 8 && FFT_PRUNE && 8 * p == N && 2 * nout <= N)
            stage8_low_output(in, out, N, tw);
        else if (R == 8) stage8(in, out, N, p, tw);
        else if (R == 9) stage9(in, out, N, p, tw);
        else if (R == 3) stage3(in, out, N, p, tw);
        else stage5(in, out, N, p, tw);
        p *= R; t = in; in = out; out = t;
    }
    return in;
}

/* The multiply's factors for element k of the strip's lines line0 .. line0 + nsl - 1. When the
 * lines are adjacent in the multiply (columns of a row-major array, as in the last pass of a
 * rows-first 2D plan) and do not wrap, they are one contiguous vector: a single load instead of
 * LANES gathers with an integer modulo each (that gather cost more than a separate multiply
 * pass over the whole array).
 *
 * mirror > 0 (the round trip's mul_mode 4, factors even across the frame's `mirror` lines):
 * line c reads line min(c, (mirror - c) % mirror), never one beyond mirror / 2. A strip wholly
 * in the upper half is the lower half's lines in reverse order: one contiguous load and a lane
 * reversal. */
static CPU_WIDE
void mul_factors(vt *f, __global const real2 *m, int k, int line0, int nsl, long mul_ls,
                        int mul_lmod, long mul_es, int mirror)
{
    /* *f by pointer, not a return value: see finish() below (16-wide vectors by value change the
     * calling convention on CPUs without AVX-512, and clang says so in every build log) */
    const int first = line0 % mul_lmod;
    if (nsl == LANES && mul_ls == 1 && first + LANES <= mul_lmod) {
        if (mirror <= 0 || first + LANES - 1 <= mirror / 2) {
            *f = VLOAD(m + first + k * mul_es);
            return;
        }
        if (first >= (mirror + 1) / 2 && first + LANES <= mirror) {
            *f = VREV(VLOAD(m + (mirror - first - (LANES - 1)) + k * mul_es));
            return;
        }
    }
    for (int l = 0; l < LANES; ++l) {
        int c = (line0 + l) % mul_lmod;
        if (mirror > 0) c = FFT_EVEN_INDEX(c, mirror);
        ((real2 *)f)[l] = (l < nsl) ? m[c * mul_ls + k * mul_es] : (real2)(0, 0);
    }
}

/* conj_out, scale and the output multiply of element k of the strip's lines. The value goes
 * by pointer: 16-wide vectors by value hit a non-AVX-512 calling convention (compiler warning,
 * and a spill if not inlined). */
static CPU_WIDE void finish(vt *pv, int k, int line0, int nsl, __global const real2 *m, long mul_ls,
                   int mul_lmod, long mul_es, int mul_mode, int conj_out, real scale)
{
    vt v = *pv;
    if (conj_out) v *= VPAT(1, -1);
    v *= scale;
    if (mul_mode == 2) {
        vt f;
        mul_factors(&f, m, k, line0, nsl, mul_ls, mul_lmod, mul_es, 0);
        v = V_CMULV(v, f);
    }
    *pv = v;
}

/* Callbacks that take eight adjacent elements of a row at once (clholo_load8, clholo_store8:
 * see fft_common.h), where the strips hold such runs: float32 strips of eight lines only. */
#if FFT_LOAD_CB && defined(FFT_LOAD_CB_OCT) && LANES == 8 && !FFT_DOUBLE
#define LOAD_OCT 1
#else
#define LOAD_OCT 0
#endif
#if FFT_STORE_CB && defined(FFT_STORE_CB_OCT) && LANES == 8 && !FFT_DOUBLE
#define STORE_OCT 1
#else
#define STORE_OCT 0
#endif

/* load callback, input multiply and conj_in on the nve loaded elements of the strip's nvl valid
 * lines (the other lanes are zero padding and stay zero); cb_done: load_strip has already run
 * the load callback (clholo_load8) */
static CPU_WIDE void prepare(__local vt *buf, int nve, int line0, int nvl, long b,
                    __global const real2 *m, long mul_ls, int mul_lmod, long mul_es,
                    int mul_mode, int conj_in, int cb_done FFT_LOAD_CB_PARAMS)
{
#if FFT_LOAD_CB
    if (mul_mode != 1 && !conj_in && cb_done) return;
#else
    if (mul_mode != 1 && !conj_in) return;
#endif
    for (int k = 0; k < nve; ++k) {
        vt v = buf[k];
#if FFT_LOAD_CB
        if (!cb_done)
            for (int l = 0; l < min(nvl, LANES); ++l)
                ((real2 *)&v)[l] = clholo_load(((real2 *)&v)[l], FFT_CB_POS(b, line0 + l, k)
                                               FFT_LOAD_CB_ARGS);
#endif
        if (mul_mode == 1) {
            vt f;
            mul_factors(&f, m, k, line0, nvl, mul_ls, mul_lmod, mul_es, 0);
            v = V_CMULV(v, f);
        }
        if (conj_in) v *= VPAT(1, -1);
        buf[k] = v;
    }
}

/* NEXT_PREFETCH(p, off): as a strip loads p, a software prefetch of p + off, the same place
 * in the source window of the work-item this CPU thread most likely runs next (off from
 * next_window_offset; 0: none).
 *
 * Why: a strip's loads stalled on memory. Its lines are read once, so the caches never hold
 * them: the SLM-size round trips' loads took 55-64 % of their kernels' own samples (perf),
 * the column round trip's rows 15.5 KB apart (a new page each, which no hardware prefetcher
 * crosses). The next work-item's lines, fetched while this one computes (the FFTs take tens
 * of microseconds a strip), are in the cache when it loads them. */
#if NEXT_PF
#define NEXT_PREFETCH(p, off) do { if (off) CLHOLO_PREFETCH((p) + (off), 0); } while (0)
#else
#define NEXT_PREFETCH(p, off) do { } while (0)
#endif

/* buf[k] lane l = line (line0 + l), element k of s (pointing at line0); zero outside the window.
 * Returns bit 1 when it has applied the input multiply itself (mul_mode 1; only called so when
 * no load callback runs first): rows read whole cache lines of the factors beside the data's,
 * in the same order, instead of prepare()'s LANES gathers per element. Returns bit 2 when it
 * has run the load callback itself (LOAD_OCT: clholo_load8 on the rows' eight-element runs
 * before the transpose, whole vectors instead of one element at a time). */
static CPU_WIDE int load_strip(__local vt *buf, __global const real2 *s, long src_ls, long src_es,
                      int nvl, int nve, int N, int line0, __global const real2 *m, long mul_ls,
                      int mul_lmod, long mul_es, int mul_mode, long pf_off,
                      long b FFT_LOAD_CB_PARAMS)
{
    __local real2 *bs = (__local real2 *)buf;
    int done = 0;
    if (nvl == LANES && src_ls == 1) {
        /* lines are adjacent: every element is one full vector load */
        for (int k = 0; k < nve; ++k) {
            NEXT_PREFETCH(s + k * src_es, pf_off);
            buf[k] = VLOAD(s + k * src_es);
        }
#if HAVE_TRANSPOSE
    } else if (nvl == LANES && src_es == 1 && (nve & (LANES - 1)) == 0) {
        /* lines are rows: LANES consecutive elements of each row in one vector, transposed
         * in registers into LANES elements of all rows */
        if (mul_mode == 1 && mul_es == 1) {
            __global const real2 *mrow[LANES];
            for (int l = 0; l < LANES; ++l) mrow[l] = m + ((line0 + l) % mul_lmod) * mul_ls;
            for (int k = 0; k < nve; k += LANES) {
                vt v[LANES];
                for (int l = 0; l < LANES; ++l) {
                    const vt f = VLOAD(mrow[l] + k);
                    NEXT_PREFETCH(s + l * src_ls + k, pf_off);
                    v[l] = V_CMULV(VLOAD(s + l * src_ls + k), f);
                }
                TRANSPOSE(v);
                for (int l = 0; l < LANES; ++l) buf[k + l] = v[l];
            }
            done = 1;
        } else {
            for (int k = 0; k < nve; k += LANES) {
                vt v[LANES];
                for (int l = 0; l < LANES; ++l) {
                    NEXT_PREFETCH(s + l * src_ls + k, pf_off);
                    v[l] = VLOAD(s + l * src_ls + k);
#if LOAD_OCT
                    clholo_load8(&v[l], FFT_CB_POS(b, line0 + l, k) FFT_LOAD_CB_ARGS);
#endif
                }
                TRANSPOSE(v);
                for (int l = 0; l < LANES; ++l) buf[k + l] = v[l];
            }
            done = LOAD_OCT ? 2 : 0;
        }
#endif
    } else {
        for (int k = 0; k < nve; ++k)
            for (int l = 0; l < LANES; ++l)
                bs[k * LANES + l] = (l < nvl) ? s[l * src_ls + k * src_es] : (real2)(0, 0);
    }
    for (int k = max(nve, 0); k < zero_fill_end(N, nve); ++k) buf[k] = (vt)(0);
    return done;
}

#if FFT_STORE_CB
/* LANES adjacent output elements of one row, (b, row, col0 ..), held in *pv, through the store
 * callback: in groups of four (clholo_store4, col0 + q a multiple of 4) when the callback
 * defines FFT_STORE_CB_QUAD, else one by one. Callers pass runs that start at a multiple of
 * LANES. */
static CPU_WIDE
void store_run(__global real2 *p, vt *pv, long b, int row, int col0 FFT_STORE_CB_PARAMS)
{
#if STORE_OCT
    clholo_store8(p, pv, b, row, col0 FFT_STORE_CB_ARGS);
#elif defined(FFT_STORE_CB_QUAD) && LANES >= 4
    for (int q = 0; q < LANES; q += 4)
        clholo_store4(p + q, ((real2 *)pv)[q], ((real2 *)pv)[q + 1], ((real2 *)pv)[q + 2],
                      ((real2 *)pv)[q + 3], b, row, col0 + q FFT_STORE_CB_ARGS);
#else
    for (int l = 0; l < LANES; ++l)
        clholo_store(p + l, ((real2 *)pv)[l], b, row, col0 + l FFT_STORE_CB_ARGS);
#endif
}
#endif

/* lines < nsl (relative), elements < nse of the result res to d (pointing at line0) */
static CPU_WIDE void store_strip(__local const vt *res, __global real2 *d, long dst_ls, long dst_es,
                        int nsl, int nse, int line0, __global const real2 *m, long mul_ls,
                        int mul_lmod, long mul_es, int mul_mode, int conj_out, real scale,
                        long b FFT_STORE_CB_PARAMS)
{
#if FFT_STORE_CB
#if HAVE_TRANSPOSE
    if (nsl == LANES && dst_es == 1 && dst_ls != 1 && (nse & (LANES - 1)) == 0) {
        /* lines are rows: after the transpose v[l] holds LANES adjacent elements of row l */
        for (int k = 0; k < nse; k += LANES) {
            vt v[LANES];
            for (int e = 0; e < LANES; ++e) {
                v[e] = res[k + e];
                finish(&v[e], k + e, line0, nsl, m, mul_ls, mul_lmod, mul_es, mul_mode,
                       conj_out, scale);
            }
            TRANSPOSE(v);
            for (int l = 0; l < LANES; ++l)
                store_run(d + l * dst_ls + k, &v[l], FFT_CB_POS(b, line0 + l, k)
                          FFT_STORE_CB_ARGS);
        }
        return;
    }
#endif
    for (int k = 0; k < nse; ++k) {
        vt v = res[k];
        finish(&v, k, line0, nsl, m, mul_ls, mul_lmod, mul_es, mul_mode, conj_out, scale);
        if (nsl == LANES && dst_ls == 1) {
            /* lines are adjacent columns: the lanes are LANES adjacent elements of row k */
            store_run(d + k * dst_es, &v, FFT_CB_POS(b, line0, k) FFT_STORE_CB_ARGS);
        } else {
            for (int l = 0; l < nsl; ++l)
                clholo_store(d + l * dst_ls + k * dst_es, ((real2 *)&v)[l],
                             FFT_CB_POS(b, line0 + l, k) FFT_STORE_CB_ARGS);
        }
    }
    return;
#endif
#if HAVE_TRANSPOSE
    if (nsl == LANES && dst_es == 1 && dst_ls != 1 && (nse & (LANES - 1)) == 0) {
        /* lines are rows: transpose LANES elements of all rows back into row vectors */
        for (int k = 0; k < nse; k += LANES) {
            vt v[LANES];
            for (int e = 0; e < LANES; ++e) {
                v[e] = res[k + e];
                finish(&v[e], k + e, line0, nsl, m, mul_ls, mul_lmod, mul_es, mul_mode,
                       conj_out, scale);
            }
            TRANSPOSE(v);
            for (int l = 0; l < LANES; ++l) VSTORE(v[l], d + l * dst_ls + k);
        }
        return;
    }
#endif
    for (int k = 0; k < nse; ++k) {
        vt v = res[k];
        finish(&v, k, line0, nsl, m, mul_ls, mul_lmod, mul_es, mul_mode, conj_out, scale);
        if (nsl == LANES && dst_ls == 1) {
            VSTORE(v, d + k * dst_es);
        } else {
            for (int l = 0; l < nsl; ++l) d[l * dst_ls + k * dst_es] = ((real2 *)&v)[l];
        }
    }
}

#if FFT_ROUND_TRIP
/* The round trip's mid operation before any callback (fft_common.h): conj, scale and the mid
 * multiply (mul_mode 3; mul_mode 4 reads only the quarter of an even multiply, the element
 * k as min(k, N - k) and the lines mirrored across the frame's nlines; mul_mode 5 reads an
 * even multiply laid out strip by strip, fft_even_strips) of element k of the strip's lines.
 * Strips start at multiples of LANES lines. */
static CPU_WIDE
void mid_pre(vt *pv, int k, int N, int nlines, int line0, int nvl, __global const real2 *m,
                    long mul_ls, int mul_lmod, long mul_es, int mul_mode, int mid_conj_a,
                    real mid_scale)
{
    vt v = *pv;
    if (mid_conj_a) v *= VPAT(1, -1);
    v *= mid_scale;
    if (mul_mode == 5) {
        /* the strip's own run of the factors (fft_even_strips): one aligned load from a
         * sequence the strip reads forward, then back (k and N - k share a row); a strip past
         * the last line (the last work-item's spare ones) has none */
        if (nvl > 0) {
            const int row = FFT_EVEN_INDEX(k, N);
            const vt f = VLOAD(m + ((long)(line0 / LANES) * (N / 2 + 1) + row) * LANES);
            v = V_CMULV(v, f);
        }
    } else if (mul_mode >= 3) {
        vt f;
        const int even = mul_mode == 4;
        mul_factors(&f, m, even ? FFT_EVEN_INDEX(k, N) : k, line0, nvl, mul_ls, mul_lmod, mul_es,
                    even ? nlines : 0);
        v = V_CMULV(v, f);
    }
    *pv = v;
}

#if VW == 16 && !FFT_DOUBLE
/* The eight-row mid callbacks' float8 form (clholo_mid_rows8, clholo_mid_acc_rows8): elements
 * k .. k + 7 of the strip's eight lines after mid_pre, split into real and imaginary parts
 * (re[j], im[j]: element k + j, lane l = line l), and back (mid_rows8_join: interleaved,
 * conj when mid_conj_b, into res[0 .. 7]). A macro for the split: it reads mid_strip's own
 * arguments. */
#define MID_ROWS8_SPLIT(re, im)                                                              \
    for (int j = 0; j < 8; ++j) {                                                            \
        vt v_ = res[k + j];                                                                  \
        mid_pre(&v_, k + j, N, nlines, line0, LANES, m, mul_ls, mul_lmod, mul_es, mul_mode,  \
                mid_conj_a, mid_scale);                                                      \
        (re)[j] = v_.even;                                                                   \
        (im)[j] = v_.odd;                                                                    \
    }

static CPU_WIDE void mid_rows8_join(__local vt *res, const float8 *re, const float8 *im,
                                    int mid_conj_b)
{
    for (int j = 0; j < 8; ++j) {
        vt w = shuffle2(re[j], im[j], (uint16)(0, 8, 1, 9, 2, 10, 3, 11, 4, 12, 5, 13, 6, 14,
                                               7, 15));
        if (mid_conj_b) w *= VPAT(1, -1);
        res[j] = w;
    }
}
#endif

/* Between the round trip's two transforms, in place on the strip's result res: mid_pre, the
 * mid callback on elements k < mid_n of the nvl valid lines, conj (mid_conj_b); elements
 * k >= mid_n become zero (the crop and zero padding of the second transform's input). The
 * callback gets runs of four adjacent pixels of one row where the strip holds them: lanes of
 * adjacent columns as they are, rows after an in-register transpose of LANES x LANES blocks
 * (as store_strip does for the store callback). */
static CPU_WIDE
void mid_strip(__local vt *res, int N, int nlines, int line0, int nvl, long b,
                      __global const real2 *m,
                      long mul_ls, int mul_lmod, long mul_es, int mul_mode, int mid_n,
                      int mid_conj_a, int mid_conj_b, real mid_scale
                      FFT_MID_ACC_PARAM FFT_MID_CB_PARAMS)
{
    const int nm = min(mid_n, N);
    int k = 0;
#if FFT_MID_CB && defined(FFT_MID_CB_SUMS)
    /* a callback that adds up: eight rows by eight elements at a time where it has that form
     * (its own running sums, added to the strip's at the end), else one element at a time
     * (fft_common.h) */
#if FFT_CB_LAYOUT == 0 && defined(FFT_MID_CB_SUMS_ROWS8) && VW == 16 && !FFT_DOUBLE
    if (nvl >= LANES) {
        float8 acc8[4] = {(float8)(0), (float8)(0), (float8)(0), (float8)(0)};
        for (; k + 8 <= nm; k += 8) {
            float8 re[8], im[8];
            MID_ROWS8_SPLIT(re, im);
            clholo_mid_acc_rows8(re, im, FFT_CB_POS(b, line0, k), acc8 FFT_MID_CB_ARGS);
            mid_rows8_join(res + k, re, im, mid_conj_b);
        }
        real4 s = (real4)(0, 0, 0, 0);
        for (int j = 0; j < 8; ++j)
            s += (real4)(acc8[0][j], acc8[1][j], acc8[2][j], acc8[3][j]);
        *mid_acc += s;
    }
#endif
#elif FFT_MID_CB && FFT_CB_LAYOUT == 0 && defined(FFT_MID_CB_ROWS8) && VW == 16 && !FFT_DOUBLE
    /* eight rows in the lanes, eight elements at a time: the callback's float8 form */
    if (nvl >= LANES) {
        for (; k + 8 <= nm; k += 8) {
            float8 re[8], im[8];
            MID_ROWS8_SPLIT(re, im);
            clholo_mid_rows8(re, im, FFT_CB_POS(b, line0, k) FFT_MID_CB_ARGS);
            mid_rows8_join(res + k, re, im, mid_conj_b);
        }
    }
#elif FFT_MID_CB && HAVE_TRANSPOSE && FFT_CB_LAYOUT != 1 && defined(FFT_MID_CB_QUAD)
    if (nvl >= LANES) {
        for (; k + LANES <= nm; k += LANES) {
            vt v[LANES];
            for (int e = 0; e < LANES; ++e) {
                v[e] = res[k + e];
                mid_pre(&v[e], k + e, N, nlines, line0, LANES, m, mul_ls, mul_lmod, mul_es,
                        mul_mode, mid_conj_a, mid_scale);
            }
            TRANSPOSE(v);
            for (int l = 0; l < LANES; ++l)
                for (int q = 0; q < LANES; q += 4)
                    clholo_mid4((real2 *)&v[l] + q, FFT_CB_POS(b, line0 + l, k + q)
                                FFT_MID_CB_ARGS);
            TRANSPOSE(v);
            for (int e = 0; e < LANES; ++e) {
                if (mid_conj_b) v[e] *= VPAT(1, -1);
                res[k + e] = v[e];
            }
        }
    }
#endif
    for (; k < nm; ++k) {
        vt v = res[k];
        mid_pre(&v, k, N, nlines, line0, nvl, m, mul_ls, mul_lmod, mul_es, mul_mode, mid_conj_a,
                mid_scale);
#if FFT_MID_CB && defined(FFT_MID_CB_SUMS)
        for (int l = 0; l < min(nvl, LANES); ++l)
            ((real2 *)&v)[l] = clholo_mid_acc(((real2 *)&v)[l], FFT_CB_POS(b, line0 + l, k),
                                              mid_acc FFT_MID_CB_ARGS);
#elif FFT_MID_CB
#if FFT_CB_LAYOUT == 1 && defined(FFT_MID_CB_QUAD) && LANES >= 4
        if (nvl >= LANES) {
            for (int q = 0; q < LANES; q += 4)
                clholo_mid4((real2 *)&v + q, FFT_CB_POS(b, line0 + q, k) FFT_MID_CB_ARGS);
        } else
#endif
        for (int l = 0; l < min(nvl, LANES); ++l)
            ((real2 *)&v)[l] = clholo_mid(((real2 *)&v)[l], FFT_CB_POS(b, line0 + l, k)
                                          FFT_MID_CB_ARGS);
#endif
        if (mid_conj_b) v *= VPAT(1, -1);
        res[k] = v;
    }
    for (; k < zero_fill_end(N, nm); ++k) res[k] = (vt)(0);
}
#define MID_STRIP(res, line0, nvl) mid_strip((res), N, nlines, (line0), (nvl), b, m, mul_ls, \
        mul_lmod, mul_es, mul_mode, mid_n, mid_conj_a, mid_conj_b, mid_scale                  \
        FFT_MID_ACC_ARG(&mid_acc) FFT_MID_CB_ARGS)
#endif
/* Which global index is the batch element: FFT_BATCH_FAST 1 (the round trips on CPUs) puts it
 * in dimension 0, so that PoCL runs the batch's fields of one strip of lines one after the
 * other: the fields of a render's frames and colours read the same rows of the layer's colour
 * and alpha in their mid callback, and the same transfer function in the column round trip,
 * while those are still in the caches (the SLM-size render's row round trip 1.33x, its column
 * round trip 1.09x on PoCL; docs/benchmarks.md, 2026-11-27). */
#ifndef FFT_BATCH_FAST
#define FFT_BATCH_FAST 0
#endif
#define STRIP_ID() ((int)get_global_id(FFT_BATCH_FAST ? 1 : 0))
#define BATCH_ID() ((long)get_global_id(FFT_BATCH_FAST ? 0 : 1))
/* a FFT_MID_CB_SUMS callback's running sum, one part per work-item (fft_common.h) */
#if FFT_ROUND_TRIP && FFT_MID_CB && defined(FFT_MID_CB_SUMS)
#define MID_SUMS_DECL real4 mid_acc = (real4)(0, 0, 0, 0);
#define MID_SUMS_STORE() clholo_mid_sums_store(mid_acc, b, STRIP_ID() FFT_MID_CB_ARGS)
#else
#define MID_SUMS_DECL
#define MID_SUMS_STORE()
#endif

#define MAX_SUB 4

/* Outputs of a strip's first transform that are read: a round trip's mid step reads those below
 * mid_n, a single transform's store those below nstore. */
#if FFT_ROUND_TRIP
#define FIRST_NOUT min(mid_n, N)
#else
#define FIRST_NOUT nse
#endif

/* Where the source window of the work-item after this one starts, relative to this one's
 * (elements; 0 where there is none): PoCL's threads run the work-groups (one work-item each
 * here) of a chunk in order, dimension 0 fastest; with FFT_BATCH_FAST that is the next field
 * of the same strip, then the first field of the next strip. For NEXT_PREFETCH. */
static long next_window_offset(long b, int lineW, int width, int src_nl, long src_ls,
                               long src_bs)
{
#if NEXT_PF
#if FFT_BATCH_FAST
    if (b + 1 < (long)get_global_size(0))
        return src_bs;
    if (lineW + width < src_nl)
        return (long)width * src_ls - b * src_bs;
#else
    if (lineW + width < src_nl)
        return (long)width * src_ls;
    if (b + 1 < (long)get_global_size(1))
        return src_bs - (long)lineW * src_ls;
#endif
#endif
    return 0;
}

/* `sub` strips of LANES lines per work-item (local memory: (sub + 1) N vectors when sub > 1,
 * else 2 N). With adjacent lines (column passes) and sub > 1 every row is visited once for
 * sub * 64 contiguous bytes instead of sub times for 64: half or a quarter of the page and
 * cache-set traffic of power-of-two strides; the strips then run one after the other, each
 * result freeing a buffer for the next. */
/* declared once with CPU_WIDE (cpu_wide.h) */
__kernel CPU_WIDE void fft_strip(FFT_PASS_ARGS, FFT_STRIP_ARGS FFT_CB_PARAMS);
__kernel void fft_strip(FFT_PASS_ARGS, FFT_STRIP_ARGS FFT_CB_PARAMS)
{
    const int lineW = STRIP_ID() * LANES * sub;
    const long b = BATCH_ID();
    __global const real2 *sW = src + src_off + b * src_bs + lineW * src_ls;
    __global real2 *dW = dst + dst_off + b * dst_bs + lineW * dst_ls;
    __global const real2 *m = mul + mul_off + (b % mul_m) * mul_bs;
    const int nve = min(src_ne, N); /* valid source elements per line */
    const int nse = min(nstore, N);
    const int width = LANES * sub;
    const long pf_off = next_window_offset(b, lineW, width, src_nl, src_ls, src_bs);
    MID_SUMS_DECL

    if (sub > 1 && src_ls == 1 && dst_ls == 1 && lineW + width <= src_nl &&
        lineW + width <= nlines) {
        for (int k = 0; k < nve; ++k)
            for (int t = 0; t < sub; ++t) {
                NEXT_PREFETCH(sW + t * LANES + k * src_es, pf_off);
                buf[t * N + k] = VLOAD(sW + t * LANES + k * src_es);
            }
        for (int t = 0; t < sub; ++t) {
            for (int k = nve; k < zero_fill_end(N, nve); ++k) buf[t * N + k] = (vt)(0);
            prepare(buf + t * N, nve, lineW + t * LANES, LANES, b, m, mul_ls, mul_lmod, mul_es,
                    mul_mode, conj_in, 0 FFT_LOAD_CB_ARGS);
        }
        __local vt *res[MAX_SUB];
        __local vt *spare = buf + sub * N;
        for (int t = 0; t < sub; ++t) {
            res[t] = run_stages(buf + t * N, spare, N, nve, FIRST_NOUT, tw);
            if (res[t] == spare) spare = buf + t * N;
#if FFT_ROUND_TRIP
            MID_STRIP(res[t], lineW + t * LANES, LANES);
            __local vt *r2 = run_stages(res[t], spare, N, min(mid_n, N), nse, tw);
            if (r2 == spare) spare = res[t];
            res[t] = r2;
#endif
        }
        for (int k = 0; k < nse; ++k)
            for (int t = 0; t < sub; ++t) {
                vt v = res[t][k];
                finish(&v, k, lineW + t * LANES, LANES, m, mul_ls, mul_lmod, mul_es, mul_mode,
                       conj_out, scale);
#if FFT_STORE_CB
                store_run(dW + t * LANES + k * dst_es, &v, FFT_CB_POS(b, lineW + t * LANES, k)
                          FFT_STORE_CB_ARGS);
#else
                VSTORE(v, dW + t * LANES + k * dst_es);
#endif
            }
        MID_SUMS_STORE();
        return;
    }
    for (int t = 0; t < sub; ++t) {
        const int line0 = lineW + t * LANES;
        /* with a load callback, the multiply comes after it (in prepare) */
        const int loaded = load_strip(buf, sW + t * LANES * src_ls, src_ls, src_es,
                                      min(src_nl - line0, LANES), nve, N, line0, m, mul_ls,
                                      mul_lmod, mul_es, FFT_LOAD_CB ? 0 : mul_mode, pf_off,
                                      b FFT_LOAD_CB_ARGS);
        prepare(buf, nve, line0, min(src_nl - line0, LANES), b, m, mul_ls, mul_lmod, mul_es,
                (loaded & 1) ? 0 : mul_mode, conj_in, (loaded & 2) != 0 FFT_LOAD_CB_ARGS);
        __local vt *res = run_stages(buf, buf + N, N, nve, FIRST_NOUT, tw);
#if FFT_ROUND_TRIP
        MID_STRIP(res, line0, min(src_nl - line0, LANES));
        res = run_stages(res, res == buf ? buf + N : buf, N, min(mid_n, N), nse, tw);
#endif
        const int nsl = min(nlines - line0, LANES);
        if (nsl > 0)
            store_strip(res, dW + t * LANES * dst_ls, dst_ls, dst_es, nsl, nse, line0, m, mul_ls,
                        mul_lmod, mul_es, mul_mode, conj_out, scale, b FFT_STORE_CB_ARGS);
    }
    MID_SUMS_STORE();
}

/* An even multiply (mul_mode 4's frames) laid out for mul_mode 5: the factors of strip s
 * (lines s LANES .. s LANES + LANES - 1), element k <= N / 2, in one vector at
 * dst[((f S + s) (N / 2 + 1) + k) LANES], folded as mul_mode 4 folds them (line c reads line
 * FFT_EVEN_INDEX(c, nlines)); lines from nlines on are 0. Frame f's line c, element k is
 * src[src_off + f frame + c ls + k es]. A strip then reads its factors in order, k up to N / 2
 * and back, where mul_mode 4 read one vector per row of the frame (a column strip: at the
 * frame's row stride, a miss of its own each, half of them across two cache lines).
 * Global size (S LANES, N / 2 + 1, M). */
__kernel void fft_even_strips(__global const real2 *src, const long src_off, const long frame,
                              const long ls, const long es, const int nlines,
                              __global real2 *dst)
{
    const int c = get_global_id(0), k = get_global_id(1), f = get_global_id(2);
    const int S = get_global_size(0) / LANES, K = get_global_size(1);
    const int s = c / LANES, l = c % LANES;
    const long o = (((long)f * S + s) * K + k) * LANES + l;
    dst[o] = c < nlines ? src[src_off + f * frame + FFT_EVEN_INDEX(c, nlines) * ls + k * es]
                        : (real2)(0, 0);
}
