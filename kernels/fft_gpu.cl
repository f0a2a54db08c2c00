/* clholo FFT, GPU variant.
 *
 * fft_lines: a work-group owns L lines of length N, loads them into local memory (coalesced:
 * with line_fast the work-items of a group walk across adjacent lines, which is how column
 * passes get contiguous reads), runs every Stockham stage there with a barrier between stages,
 * and stores once: one global read and one global write per pass. Used when 2 L N complex fit in
 * the local-memory budget chosen by the host. With FFT_INPLACE (lines longer than that budget
 * allows, up to the device's whole local memory: 2250, 3888, 4096 points of complex64 in
 * 48 KiB) the buffer holds L N complex once and every stage runs in place through registers
 * (lines_stages_inplace), still one launch per pass. Built for one geometry (FFT_STAGE_LIST)
 * a stage's radix may be the product of two butterfly radices, its DFT in registers
 * (fused_butterfly); and the two-buffer plan's first stage reads the source, its last writes
 * the destination (DIRECT_STAGE), with no local-memory pass of their own (the in-place plan
 * too, with FFT_INPLACE_DIRECT). With FFT_SPLIT (lines the local memory holds one component
 * of, not complex values: 7680 and 8192 points of complex64 in 48 KiB) the values stay in
 * registers between stages and pass from one stage to the next through local memory one
 * component at a time (SPLIT_STAGE), still one launch per pass.
 *
 * fft_stage: one radix-R Stockham stage from global to global memory, one butterfly per
 * work-item; for lines too long for local memory. The first stage applies the source window,
 * conj_in and the input multiply, the last stage the crop, conj_out, scale and output multiply.
 *
 * With FFT_ROUND_TRIP (clholo.fft.RoundTripPlan) fft_lines runs every stage, the mid step
 * (fft_common.h) and every stage again between its load and its store; fft_stage has no round
 * trip (lines beyond even the split plan take two plain passes instead).
 *
 * Pass arguments are those of fft_cpu.cl (see there); FFT_DOUBLE as in fft_common.h.
 */
#include "fft_common.h"
#include "fft_mid_acc.h"

/* FFT_SPLIT 1: lines whose complex values the local memory cannot hold at once, only one of
 * their components (see SPLIT_STAGE); with FFT_INPLACE (its bound on butterflies per
 * work-item) and FFT_SPLIT_STAGES */
#ifndef FFT_SPLIT
#define FFT_SPLIT 0
#endif

/* element k of line l (absolute indices; s points at line 0), zero outside the window */
static inline real2 load_src(__global const real2 *s, long ls, long es, int nl, int ne, int l,
                             int k, __global const real2 *m, long mul_ls, int mul_lmod,
                             long mul_es, int mul_mode, int conj_in, long b FFT_LOAD_CB_PARAMS)
{
    real2 v = (real2)(0, 0);
    if (l < nl && k < ne) {
        v = s[l * ls + k * es];
#if FFT_LOAD_CB
        v = clholo_load(v, FFT_CB_POS(b, l, k) FFT_LOAD_CB_ARGS);
#endif
        if (mul_mode == 1) v = c_mul(v, m[FFT_LINE_WRAP(l, mul_lmod) * mul_ls + k * mul_es]);
        if (conj_in) v = S_CONJ(v);
    }
    return v;
}

static inline real2 finish_dst(real2 v, int l, int k, __global const real2 *m, long mul_ls,
                               int mul_lmod, long mul_es, int mul_mode, int conj_out, real scale)
{
    if (conj_out) v = S_CONJ(v);
    v *= scale;
    if (mul_mode == 2) v = c_mul(v, m[FFT_LINE_WRAP(l, mul_lmod) * mul_ls + k * mul_es]);
    return v;
}

/* the last pass's store of element (l, k) of batch b: plain, or through the store callback */
#if FFT_STORE_CB
#define STORE_DST(ptr, v, b, l, k) clholo_store((ptr), (v), FFT_CB_POS(b, l, k) FFT_STORE_CB_ARGS)
#else
#define STORE_DST(ptr, v, b, l, k) (*(ptr) = (v))
#endif

/* One radix-R butterfly of a Stockham stage (see fft_common.h), in registers. */
#define GPU_BUTTERFLY(LOAD, STORE) {                                                 \
    const int T = N / R, k_ = i % p, j = (i - k_) * R + k_, ts = N / (p * R);        \
    real2 u0 = LOAD(i), u1 = LOAD(i + T);                                            \
    if (R == 2) {                                                                    \
        if (p > 1) u1 = c_mul(u1, tw[k_ * ts]);                                      \
        DFT2(real2, u0, u1);                                                         \
        STORE(j, u0); STORE(j + p, u1);                                              \
    } else if (R == 3) {                                                             \
        real2 u2 = LOAD(i + 2 * T);                                                  \
        if (p > 1) { const int t = k_ * ts;                                          \
            u1 = c_mul(u1, tw[t]); u2 = c_mul(u2, tw[2 * t]); }                      \
        DFT3(real2, S_NEGI, u0, u1, u2);                                             \
        STORE(j, u0); STORE(j + p, u1); STORE(j + 2 * p, u2);                        \
    } else if (R == 5) {                                                             \
        real2 u2 = LOAD(i + 2 * T), u3 = LOAD(i + 3 * T), u4 = LOAD(i + 4 * T);      \
        if (p > 1) { const int t = k_ * ts;                                          \
            u1 = c_mul(u1, tw[t]); u2 = c_mul(u2, tw[2 * t]);                        \
            u3 = c_mul(u3, tw[3 * t]); u4 = c_mul(u4, tw[4 * t]); }                  \
        DFT5(real2, S_NEGI, u0, u1, u2, u3, u4);                                     \
        STORE(j, u0); STORE(j + p, u1); STORE(j + 2 * p, u2);                        \
        STORE(j + 3 * p, u3); STORE(j + 4 * p, u4);                                  \
    } else if (R == 4) {                                                             \
        real2 u2 = LOAD(i + 2 * T), u3 = LOAD(i + 3 * T);                            \
        if (p > 1) { const int t = k_ * ts;                                          \
            u1 = c_mul(u1, tw[t]); u2 = c_mul(u2, tw[2 * t]); u3 = c_mul(u3, tw[3 * t]); } \
        DFT4(real2, S_NEGI, u0, u1, u2, u3);                                         \
        STORE(j, u0); STORE(j + p, u1); STORE(j + 2 * p, u2); STORE(j + 3 * p, u3);  \
    } else {                                                                         \
        real2 u2 = LOAD(i + 2 * T), u3 = LOAD(i + 3 * T), u4 = LOAD(i + 4 * T);      \
        real2 u5 = LOAD(i + 5 * T), u6 = LOAD(i + 6 * T), u7 = LOAD(i + 7 * T);      \
        if (p > 1) { const int t = k_ * ts;                                          \
            u1 = c_mul(u1, tw[t]);     u2 = c_mul(u2, tw[2 * t]);                    \
            u3 = c_mul(u3, tw[3 * t]); u4 = c_mul(u4, tw[4 * t]);                    \
            u5 = c_mul(u5, tw[5 * t]); u6 = c_mul(u6, tw[6 * t]);                    \
            u7 = c_mul(u7, tw[7 * t]); }                                             \
        DFT8(real2, S_NEGI, u0, u1, u2, u3, u4, u5, u6, u7);                         \
        STORE(j, u0);         STORE(j + p, u1);     STORE(j + 2 * p, u2);            \
        STORE(j + 3 * p, u3); STORE(j + 4 * p, u4); STORE(j + 5 * p, u5);            \
        STORE(j + 6 * p, u6); STORE(j + 7 * p, u7);                                  \
    } }

/* One radix-R Stockham stage of L lines of length N, from in to out, then a barrier (the
 * generic program's; R and p are run-time values there). */
static inline void lines_stage(__local const real2 *in, __local real2 *out, const int N,
                               const int L, const int R, const int p, int lid, int nthr,
                               __global const real2 *tw)
{
    const int nb = N / R;
    for (int idx = lid; idx < L * nb; idx += nthr) {
        const int l = idx / nb, i = idx % nb;
        __local const real2 *li = in + l * N;
        __local real2 *lo = out + l * N;
#define LLOAD(e) li[e]
#define LSTORE(e, v) lo[e] = (v)
        GPU_BUTTERFLY(LLOAD, LSTORE)
#undef LLOAD
#undef LSTORE
    }
    barrier(CLK_LOCAL_MEM_FENCE);
}

/* The DFT of the R points v[0], v[s], .., v[(R - 1) s] in registers, in place, natural order;
 * R a butterfly radix and s a stride (constants where this is inlined: the branches fold). */
static inline void small_dft(real2 *v, const int R, const int s)
{
    if (R == 2) DFT2(real2, v[0], v[s])
    else if (R == 3) DFT3(real2, S_NEGI, v[0], v[s], v[2 * s])
    else if (R == 4) DFT4(real2, S_NEGI, v[0], v[s], v[2 * s], v[3 * s])
    else if (R == 5) DFT5(real2, S_NEGI, v[0], v[s], v[2 * s], v[3 * s], v[4 * s])
    else if (R == 8) DFT8(real2, S_NEGI, v[0], v[s], v[2 * s], v[3 * s], v[4 * s], v[5 * s],
                          v[6 * s], v[7 * s])
}

/* The largest radix a fused_butterfly of this build runs: the plan's (FFT_INPLACE_R) in the
 * in-place plan, else 64 (two butterfly radices of 8) */
#if FFT_INPLACE && defined(FFT_INPLACE_R)
#define FUSED_R_MAX FFT_INPLACE_R
#else
#define FUSED_R_MAX 64
#endif

/* Where fused_butterfly leaves output r = c + R2 d: in u[R1 c + d] (R2 == 1: in u[r]). */
#define FUSED_AT(r, R1, R2) (((r) % (R2)) * (R1) + (r) / (R2))

/* The butterfly of a Stockham stage of radix R = R1 R2 (a fused stage: fewer stages per line,
 * so fewer local-memory round trips and barriers) on u[0..R) in registers, in place: the outer
 * twiddles W^(r k) (p > 1), then the R-point DFT as R1 DFTs of R2 points, a twiddle W_R^(a c),
 * and R2 DFTs of R1 points:
 *   X[c + R2 d] = sum_a W_R1^(a d) W_R^(a c) sum_b W_R2^(b c) u[a + R1 b],
 * left in u[FUSED_AT(c + R2 d)] = u[R1 c + d] (the DFTs run in place on strided elements of u,
 * so no value is copied through another array: a compiler that leaves such copy loops rolled
 * keeps the arrays in memory, as clang's NVPTX target did; benchmarks/gpu_registers.py).
 * W_R^m is the table's entry m N / R. With the stage list fixed at build every loop bound and
 * index is a constant, so u lives in registers. */
static inline void fused_butterfly(real2 *u, const int N, const int R1, const int R2, const int p,
                                   const int k_, __global const real2 *tw)
{
    const int R = R1 * R2, ts = N / (p * R), tr = N / R;
    /* loop bounds are the largest radices (FUSED_R_MAX, 8), the radices guards: the trip
     * counts are constants even before this is inlined, so every loop unrolls and u stays in
     * registers (bounds R, R1, R2 left some loops rolled in clang's build, and bound 64 made
     * the in-place stage's loop too large to unroll there: benchmarks/gpu_registers.py) */
    if (p > 1) {
#pragma unroll
        for (int r = 1; r < FUSED_R_MAX; r++)
            if (r < R) u[r] = c_mul(u[r], tw[r * k_ * ts]);
    }
    if (R2 == 1) {
        small_dft(u, R1, 1);
        return;
    }
#pragma unroll
    for (int a = 0; a < 8; a++) {
        if (a < R1) {
            small_dft(u + a, R2, R1);  /* u[a + R1 b], b < R2 */
#pragma unroll
            for (int c = 1; c < 8; c++)
                if (a > 0 && c < R2)
                    u[a + R1 * c] = c_mul(u[a + R1 * c], tw[((a * c) % R) * tr]);
        }
    }
#pragma unroll
    for (int c = 0; c < 8; c++)
        if (c < R2) small_dft(u + R1 * c, R1, 1);
}

/* Every Stockham stage of L lines of length N in local memory, ping-ponging between in and
 * out, for the generic program (no FFT_STAGE_LIST: a plan fixed at build runs DIRECT_STAGE
 * instead). Returns the buffer holding the result. */
static inline __local real2 *lines_stages(__local real2 *in, __local real2 *out, const int N,
                                          const int L, int lid, int nthr, __global const real2 *tw)
{
    __local real2 *t;
    /* odd power-of-two radix first, where p == 1 needs no twiddles, radix 8, then 3 and 5 */
    for (int p = 1, R; p < N; p *= R) {
        R = fft_next_radix(N, p);
        lines_stage(in, out, N, L, R, p, lid, nthr, tw);
        t = in; in = out; out = t;
    }
    return in;
}

#if FFT_INPLACE
#ifndef FFT_INPLACE_R
#define FFT_INPLACE_R 8 /* the largest radix of the plan's stages */
#endif
/* INPLACE_EACH_Q(M): M(0) M(1) .. M(FFT_INPLACE - 1), a work-item's butterflies of a stage
 * written out one by one, so that each index into its registers u[q] is a constant whether or
 * not a compiler unrolls a loop over them (clang's NVPTX build would not unroll the loop of
 * the 4K grid's rows, three radix-9 butterflies a work-item: u went on the stack, 216 bytes;
 * PoCL's left the in-place direct stages' loops rolled, "loop not unrolled") */
#define INPLACE_Q1(M) M(0)
#define INPLACE_Q2(M) INPLACE_Q1(M) M(1)
#define INPLACE_Q3(M) INPLACE_Q2(M) M(2)
#define INPLACE_Q4(M) INPLACE_Q3(M) M(3)
#define INPLACE_Q5(M) INPLACE_Q4(M) M(4)
#define INPLACE_Q6(M) INPLACE_Q5(M) M(5)
#define INPLACE_Q7(M) INPLACE_Q6(M) M(6)
#define INPLACE_Q8(M) INPLACE_Q7(M) M(7)
#define INPLACE_PASTE_(a, b) a##b
#define INPLACE_PASTE(a, b) INPLACE_PASTE_(a, b)
#define INPLACE_EACH_Q(M) INPLACE_PASTE(INPLACE_Q, FFT_INPLACE)(M)
/* INPLACE_EACH_QA(M, A): M(0, A) M(1, A) .. M(FFT_INPLACE - 1, A), the same with an argument
 * passed on (the split plan's statement for each point of a butterfly, SPLIT_EACH) */
#define INPLACE_QA1(M, A) M(0, A)
#define INPLACE_QA2(M, A) INPLACE_QA1(M, A) M(1, A)
#define INPLACE_QA3(M, A) INPLACE_QA2(M, A) M(2, A)
#define INPLACE_QA4(M, A) INPLACE_QA3(M, A) M(3, A)
#define INPLACE_QA5(M, A) INPLACE_QA4(M, A) M(4, A)
#define INPLACE_QA6(M, A) INPLACE_QA5(M, A) M(5, A)
#define INPLACE_QA7(M, A) INPLACE_QA6(M, A) M(6, A)
#define INPLACE_QA8(M, A) INPLACE_QA7(M, A) M(7, A)
#define INPLACE_EACH_QA(M, A) INPLACE_PASTE(INPLACE_QA, FFT_INPLACE)(M, A)
#if FFT_INPLACE > 8
#error "FFT_INPLACE is at most 8 (clholo.fft._INPLACE_MAX_PER_ITEM)"
#endif
/* One stage of radix R1 R2 in ONE buffer of L lines (lines too long for two buffers in local
 * memory): each work-item reads the inputs of its butterflies (Q of this stage, at most
 * FFT_INPLACE, radix <= FFT_INPLACE_R) into registers, a barrier, then computes them and writes
 * the outputs in place, a barrier. With R, p and the work-group size constants (FFT_STAGE_LIST,
 * FFT_WG) Q is one too and so is every index into u: the stage holds Q R values in registers,
 * about L N / work-items whatever its radix (3888 points, 256 work-items: 18 complex values in
 * a radix-9 stage as in a radix-3 one). */
static inline void lines_stage_inplace(__local real2 *buf, const int N, const int L, const int R1,
                                       const int R2, const int p, int lid, int nthr,
                                       __global const real2 *tw)
{
    const int R = R1 * R2, nb = N / R;
    const int Q = min(FFT_INPLACE, (L * nb + nthr - 1) / nthr);
    real2 u[FFT_INPLACE][FFT_INPLACE_R];
    /* loops bounded by the constants FFT_INPLACE and FFT_INPLACE_R, guarded by Q and R (see
     * fused_butterfly) */
#pragma unroll
    for (int q = 0; q < FFT_INPLACE; q++) {
        const int idx = lid + q * nthr;
        if (q < Q && idx < L * nb) {
            __local real2 *li = buf + (idx / nb) * N + idx % nb;
#pragma unroll
            for (int r = 0; r < FFT_INPLACE_R; r++)
                if (r < R) u[q][r] = li[r * nb];
        }
    }
    barrier(CLK_LOCAL_MEM_FENCE);
#ifdef FFT_STAGE_LIST
    /* a plan fixed at build: its butterflies written out one by one (INPLACE_EACH_Q) */
#define INPLACE_Q(q) {                                                                       \
        const int idx = lid + (q) * nthr;                                                      \
        if ((q) < Q && idx < L * nb) {                                                         \
            const int i = idx % nb, k_ = i % p, j = (i - k_) * R + k_;                         \
            __local real2 *lo = buf + (idx / nb) * N;                                          \
            fused_butterfly(u[q], N, R1, R2, p, k_, tw);                                       \
            _Pragma("unroll")                                                                  \
            for (int r = 0; r < FFT_INPLACE_R; r++)                                            \
                if (r < R) lo[j + r * p] = u[q][FUSED_AT(r, R1, R2)];                          \
        } }
    INPLACE_EACH_Q(INPLACE_Q)
#undef INPLACE_Q
#else
#pragma unroll
    for (int q = 0; q < FFT_INPLACE; q++) {
        const int idx = lid + q * nthr;
        if (q < Q && idx < L * nb) {
            const int i = idx % nb;
            __local real2 *lo = buf + (idx / nb) * N;
#ifndef FFT_STAGE_LIST
            /* the generic program (radix known at run time): the radix branches of
             * GPU_BUTTERFLY; a fixed stage list takes fused_butterfly for every radix (the same
             * operations for R2 == 1, with constant indices into u) */
            if (R2 == 1) {
#define RLOAD(e) u[q][((e) - i) / T]
#define LSTORE(e, v) lo[e] = (v)
                GPU_BUTTERFLY(RLOAD, LSTORE)
#undef RLOAD
#undef LSTORE
            } else
#endif
            {
                const int k_ = i % p, j = (i - k_) * R + k_;
                fused_butterfly(u[q], N, R1, R2, p, k_, tw);
#pragma unroll
                for (int r = 0; r < FFT_INPLACE_R; r++)
                    if (r < R) lo[j + r * p] = u[q][FUSED_AT(r, R1, R2)];
            }
        }
    }
#endif
    barrier(CLK_LOCAL_MEM_FENCE);
}

/* Every stage in place. Returns buf. */
static inline __local real2 *lines_stages_inplace(__local real2 *buf, const int N, const int L,
                                                  int lid, int nthr, __global const real2 *tw)
{
#ifdef FFT_STAGE_LIST
#define FFT_STAGE(R1_, R2_, P_) lines_stage_inplace(buf, N, L, (R1_), (R2_), (P_), lid, nthr, tw);
    FFT_STAGE_LIST
#undef FFT_STAGE
#else
    for (int p = 1, R; p < N; p *= R) {
        R = fft_next_radix(N, p);
        lines_stage_inplace(buf, N, L, R, 1, p, lid, nthr, tw);
    }
#endif
    return buf;
}
#define LINES_STAGES(in) lines_stages_inplace((in), LINE_N, LINE_L, lid, nthr, tw)
#else
#define LINES_STAGES(in) lines_stages((in), (in) == buf ? buf + total : buf, LINE_N, LINE_L, \
                                      lid, nthr, tw)
#endif

#if FFT_ROUND_TRIP
/* The round trip's step before its callback for element k of line l (absolute) of a length-N
 * transform: conj, scale and the multiply (fft_common.h) */
static inline real2 mid_pre(real2 v, int l, int k, int N, int nl, __global const real2 *m,
                            long mul_ls, int mul_lmod, long mul_es, int mul_mode,
                            int mid_conj_a, real mid_scale)
{
    if (mid_conj_a) v = S_CONJ(v);
    v *= mid_scale;
    if (mul_mode == 3) {
        v = c_mul(v, m[FFT_LINE_WRAP(l, mul_lmod) * mul_ls + k * mul_es]);
    } else if (mul_mode == 4) {
        /* an even multiply (fft_common.h): only its quarter is read */
        v = c_mul(v, m[FFT_EVEN_INDEX(FFT_LINE_WRAP(l, mul_lmod), nl) * mul_ls
                       + FFT_EVEN_INDEX(k, N) * mul_es]);
    }
    return v;
}

/* The round trip's step between its transforms (fft_common.h) for element k of line l
 * (absolute) of a length-N transform; lines >= nl (beyond the stored ones) and elements
 * >= mid_n become zero. */
static inline real2 mid_value(real2 v, int l, int k, int N, int nl, long b,
                              __global const real2 *m,
                              long mul_ls, int mul_lmod, long mul_es, int mul_mode, int mid_n,
                              int mid_conj_a, int mid_conj_b, real mid_scale
                              FFT_MID_ACC_PARAM FFT_MID_CB_PARAMS)
{
    if (l >= nl || k >= mid_n) return (real2)(0, 0);
    v = mid_pre(v, l, k, N, nl, m, mul_ls, mul_lmod, mul_es, mul_mode, mid_conj_a, mid_scale);
#if FFT_MID_CB && defined(FFT_MID_CB_SUMS)
    v = clholo_mid_acc(v, FFT_CB_POS(b, l, k), mid_acc FFT_MID_CB_ARGS);
#elif FFT_MID_CB
    v = clholo_mid(v, FFT_CB_POS(b, l, k) FFT_MID_CB_ARGS);
#endif
    if (mid_conj_b) v = S_CONJ(v);
    return v;
}
#endif

/* FFT_MID_QUADS 1 (clholo.fft._GPU_MID_QUADS): a mid callback that has a four-element form
 * (FFT_MID_CB_QUAD; not one that adds up, FFT_MID_CB_SUMS) gets four elements adjacent along
 * a row of the frame at a time, in a sweep over local memory after the first transform, as
 * the CPU strips call it. Why: clholo_mid draws the Philox block of its pixel for that pixel
 * alone (composite_store.h), so element by element each block is drawn four times (about 100
 * integer operations a pixel, colour, frame and layer); a quad draws it once. The cost is the
 * sweep's pass over local memory and its barrier, where the step was folded into the first
 * transform's last stage: a GPU decides (benchmarks/fft_variants.py "mid-quads"). */
#if FFT_ROUND_TRIP && FFT_MID_CB && defined(FFT_MID_CB_QUAD) && !defined(FFT_MID_CB_SUMS) \
    && defined(FFT_MID_QUADS) && FFT_MID_QUADS && !FFT_SPLIT
#define MID_QUADS 1
/* the quad's direction in the local lines: along the lines where they are columns of the
 * frame (FFT_CB_LAYOUT 1: row = k, col = l), else along a line */
#define MID_QUAD_DL (FFT_CB_LAYOUT == 1 ? 1 : 0)
/* Four elements (l + e dl, k + e dk), e = 0..3, of the local lines (l relative to line0, the
 * group's first line), in place: the callback's quad form where all four lie inside the
 * stored lines and below mid_n, else each as mid_value does it. The same operations either
 * way: clholo_mid4 gives clholo_mid's values (fft_common.h). */
static inline void mid_quad(__local real2 *in, int line_n, int l, int k, int line0, int N,
                            int nl, long b, __global const real2 *m, long mul_ls, int mul_lmod,
                            long mul_es, int mul_mode, int mid_n, int mid_conj_a,
                            int mid_conj_b, real mid_scale FFT_MID_CB_PARAMS)
{
    const int dl = MID_QUAD_DL, dk = 1 - MID_QUAD_DL;
    real2 v[4];
    int inside = 1;
    for (int e = 0; e < 4; ++e) {
        const int la = line0 + l + e * dl, ka = k + e * dk;
        v[e] = in[(l + e * dl) * line_n + k + e * dk];
        if (la < nl && ka < mid_n)
            v[e] = mid_pre(v[e], la, ka, N, nl, m, mul_ls, mul_lmod, mul_es, mul_mode,
                           mid_conj_a, mid_scale);
        else
            inside = 0;
    }
    if (inside) {
        clholo_mid4(v, FFT_CB_POS(b, line0 + l, k) FFT_MID_CB_ARGS);
    } else {
        for (int e = 0; e < 4; ++e) {
            const int la = line0 + l + e * dl, ka = k + e * dk;
            v[e] = (la < nl && ka < mid_n) ? clholo_mid(v[e], FFT_CB_POS(b, la, ka)
                                                        FFT_MID_CB_ARGS)
                                           : (real2)(0, 0);
        }
    }
    for (int e = 0; e < 4; ++e) {
        const int la = line0 + l + e * dl, ka = k + e * dk;
        in[(l + e * dl) * line_n + k + e * dk] =
            (mid_conj_b && la < nl && ka < mid_n) ? S_CONJ(v[e]) : v[e];
    }
}
/* The sweep by quads where a group's lines split into them (line_l lines of line_n elements;
 * work-items walk the quads in the element loop's order), else 0 and the caller sweeps
 * element by element */
#define MID_QUADS_FIT(line_n, line_l) ((MID_QUAD_DL ? (line_l) : (line_n)) % 4 == 0)
#define MID_QUAD_SWEEP(in, line_n, line_l)                                                    \
    for (int qi = lid; qi < (line_n) * (line_l) / 4; qi += nthr) {                         \
        const int nq_ = (MID_QUAD_DL ? (line_l) : (line_n)) / 4;                             \
        const int l = MID_QUAD_DL ? 4 * (qi % nq_) : qi / nq_;                              \
        const int k = MID_QUAD_DL ? qi / nq_ : 4 * (qi % nq_);                              \
        mid_quad((in), (line_n), l, k, line0, N, nlines, b, m, mul_ls, mul_lmod, mul_es,      \
                 mul_mode, mid_n, mid_conj_a, mid_conj_b, mid_scale FFT_MID_CB_ARGS);         \
    }
#else
#define MID_QUADS 0
#endif

/* Which work-group index is the batch element: FFT_BATCH_FAST 1 puts it in dimension 0, so that
 * the batch's fields of one group of lines are dispatched one after another and share what
 * their multiply and mid callback read (a render's colour, alpha and transfer function) in
 * the caches, as the CPU strips do (fft_cpu.cl). Off by default on GPUs until measured
 * (clholo.fft._GPU_BATCH_FAST; benchmarks/fft_variants.py "batch-fast"). */
#ifndef FFT_BATCH_FAST
#define FFT_BATCH_FAST 0
#endif
#define LINE_GROUP_ID() ((int)get_group_id(FFT_BATCH_FAST ? 1 : 0))
#define BATCH_GROUP_ID() ((long)get_group_id(FFT_BATCH_FAST ? 0 : 1))

#if FFT_ROUND_TRIP && FFT_MID_CB && defined(FFT_MID_CB_SUMS)
#ifndef FFT_WG
#error "FFT_MID_CB_SUMS needs a plan fixed at build (FFT_WG)"
#endif
/* The work-group's sum of its work-items' running sums (a tree over FFT_WG entries of
 * `scratch`, in an order fixed by FFT_WG), handed to the callback by work-item 0 as part
 * LINE_GROUP_ID() of batch element b. Every work-item calls it. */
static inline void mid_sums_store(real4 acc, __local real4 *scratch, int lid, long b
                                  FFT_MID_CB_PARAMS)
{
    scratch[lid] = acc;
    barrier(CLK_LOCAL_MEM_FENCE);
    int stride = 1;
    while (2 * stride < FFT_WG) stride *= 2;
    for (; stride > 0; stride /= 2) {
        if (lid < stride && lid + stride < FFT_WG) scratch[lid] += scratch[lid + stride];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    if (lid == 0) clholo_mid_sums_store(scratch[0], b, LINE_GROUP_ID() FFT_MID_CB_ARGS);
}
#define MID_SUMS_STORE() mid_sums_store(mid_acc, mid_sums_scratch, lid, b FFT_MID_CB_ARGS)
#else
#define MID_SUMS_STORE()
#endif

/* DIRECT_STAGE: plans fixed at build whose first stage reads the source and last stage writes
 * the destination: the two-buffer plan, and the in-place plan where the host asks for it
 * (FFT_INPLACE_DIRECT); lines of one point have no stage. */
#if defined(FFT_STAGE_LIST) && FFT_N > 1 && (!FFT_INPLACE || FFT_INPLACE_DIRECT) && !FFT_SPLIT
#define FFT_DIRECT 1
#else
#define FFT_DIRECT 0
#endif
#if FFT_DIRECT || FFT_SPLIT
/* DIRECT_STAGE's reads of the source window and writes to the destination window, element k of
 * line l of the group (fft_lines' arguments in scope) */
#define SRC_ELEM(l, k) load_src(s0, src_ls, src_es, src_nl, src_ne, line0 + (l), (k), m, mul_ls,  \
                                mul_lmod, mul_es, mul_mode, conj_in, b FFT_LOAD_CB_ARGS)
#define DST_ELEM(v, l, k) {                                                                   \
    if ((l) < nsl && (k) < nse)                                                                \
        STORE_DST(d + (l) * dst_ls + (k) * dst_es,                                             \
                  finish_dst((v), line0 + (l), (k), m, mul_ls, mul_lmod, mul_es, mul_mode,     \
                             conj_out, scale), b, line0 + (l), (k)); }
/* butterfly idx of a stage of nb_ per line: its line l in the group and index i in the line,
 * adjacent lines first where lf_ (stages on global memory, lines are columns) */
#define BUTTERFLY_PLACE(idx) const int l = lf_ ? (idx) % LINE_L : (idx) / nb_;                 \
                             const int i = lf_ ? (idx) / LINE_L : (idx) % nb_;
/* after the first stage every read of the source is done: the global fence orders those reads
 * before the last stage's writes where the pass runs in place (src == dst) */
#define STAGE_BARRIER(FROM_SRC) barrier((FROM_SRC) ? CLK_LOCAL_MEM_FENCE | CLK_GLOBAL_MEM_FENCE  \
                                                   : CLK_LOCAL_MEM_FENCE)
#endif
#if FFT_DIRECT && !FFT_INPLACE
/* One stage (radix R1 R2 at sub-transform size P, fused_butterfly) of the fixed two-buffer
 * plan inside fft_lines, whose arguments it reads: inputs from local memory `in`, or from the
 * source window (FROM_SRC, the first stage: load_src zero-pads and applies the load callback,
 * the input multiply and conj_in); outputs to local memory `out`, through the round trip's
 * step (TO_MID), or to the destination window (TO_DST, the last stage: finish_dst and the
 * store callback). Stages that touch global memory walk adjacent lines first where lines are
 * columns (LINE_FAST), so that a row's elements are read and written together; stages in
 * local memory walk along the lines. */
#define DIRECT_STAGE(R1, R2, P, FROM_SRC, TO_MID, TO_DST) {                                  \
    const int R_ = (R1) * (R2), nb_ = LINE_N / R_;                                             \
    const int lf_ = LINE_FAST && ((FROM_SRC) || (TO_MID) || (TO_DST));                         \
    for (int idx = lid; idx < LINE_L * nb_; idx += nthr) {                                     \
        BUTTERFLY_PLACE(idx)                                                                   \
        const int k_ = i % (P), j = (i - k_) * R_ + k_;                                        \
        real2 u[64];                                                                           \
        _Pragma("unroll")                                                                      \
        for (int r = 0; r < R_; r++)                                                           \
            u[r] = (FROM_SRC) ? SRC_ELEM(l, i + r * nb_) : in[l * LINE_N + i + r * nb_];       \
        fused_butterfly(u, LINE_N, (R1), (R2), (P), k_, tw);                                   \
        _Pragma("unroll")                                                                      \
        for (int r = 0; r < R_; r++) {                                                         \
            const int k = j + r * (P);                                                         \
            const real2 fv_ = u[FUSED_AT(r, (R1), (R2))];                                      \
            if (TO_DST) DST_ELEM(fv_, l, k)                                                    \
            else out[l * LINE_N + k] = (TO_MID) ? MID_VALUE(fv_, line0 + l, k) : fv_;          \
        }                                                                                      \
    }                                                                                          \
    if (!(TO_DST)) STAGE_BARRIER(FROM_SRC); }
#elif FFT_DIRECT
/* The same for the in-place plan (FFT_INPLACE_DIRECT): as lines_stage_inplace, each work-item
 * first reads the inputs of its Q butterflies into registers, from the source window
 * (FROM_SRC) or from `buf`, then computes them and writes the outputs to `buf`, through the
 * round trip's step (TO_MID), or to the destination window (TO_DST). The barrier between the
 * reads and the writes is needed only where both are in `buf`. The butterflies are written
 * out one by one (INPLACE_EACH_Q, guarded by Q_): as loops, bounded by Q_ (no constant where
 * the work-group size is not) and later by FFT_INPLACE, PoCL's clang left them rolled and
 * said so in build logs ("loop not unrolled", a warning users see). */
/* butterfly q of DIRECT_STAGE's in-place form: its inputs into u[q], then (below) computed and
 * its outputs written (the stage's radices, P and roles in r1_, r2_, p_, from_, mid_, dst_) */
#define DIRECT_LOAD_Q(q) {                                                                   \
    const int idx = lid + (q) * nthr;                                                          \
    if ((q) < Q_ && idx < LINE_L * nb_) {                                                      \
        BUTTERFLY_PLACE(idx)                                                                   \
        _Pragma("unroll")                                                                      \
        for (int r = 0; r < FFT_INPLACE_R; r++)                                                \
            if (r < R_)                                                                        \
                u[q][r] = from_ ? SRC_ELEM(l, i + r * nb_) : buf[l * LINE_N + i + r * nb_];    \
    } }
#define DIRECT_COMPUTE_Q(q) {                                                                \
    const int idx = lid + (q) * nthr;                                                          \
    if ((q) < Q_ && idx < LINE_L * nb_) {                                                      \
        BUTTERFLY_PLACE(idx)                                                                   \
        const int k_ = i % p_, j = (i - k_) * R_ + k_;                                         \
        fused_butterfly(u[q], LINE_N, r1_, r2_, p_, k_, tw);                                   \
        _Pragma("unroll")                                                                      \
        for (int r = 0; r < FFT_INPLACE_R; r++) {                                              \
            if (r < R_) {                                                                      \
                const int k = j + r * p_;                                                      \
                const real2 fv_ = u[q][FUSED_AT(r, r1_, r2_)];                                 \
                if (dst_) DST_ELEM(fv_, l, k)                                                  \
                else buf[l * LINE_N + k] = mid_ ? MID_VALUE(fv_, line0 + l, k) : fv_;          \
            }                                                                                  \
        }                                                                                      \
    } }
#define DIRECT_STAGE(R1, R2, P, FROM_SRC, TO_MID, TO_DST) {                                  \
    const int r1_ = (R1), r2_ = (R2), p_ = (P);                                                \
    const int from_ = (FROM_SRC), mid_ = (TO_MID), dst_ = (TO_DST);                            \
    const int R_ = r1_ * r2_, nb_ = LINE_N / R_;                                               \
    const int Q_ = min(FFT_INPLACE, (LINE_L * nb_ + nthr - 1) / nthr);                         \
    const int lf_ = LINE_FAST && (from_ || mid_ || dst_);                                      \
    real2 u[FFT_INPLACE][FFT_INPLACE_R];                                                       \
    INPLACE_EACH_Q(DIRECT_LOAD_Q)                                                              \
    if (!from_ && !dst_) barrier(CLK_LOCAL_MEM_FENCE);                                         \
    INPLACE_EACH_Q(DIRECT_COMPUTE_Q)                                                           \
    if (!dst_) STAGE_BARRIER(from_); }
#endif
#if FFT_SPLIT
/* The split plan (FFT_SPLIT): lines that local memory cannot hold as complex values but can as
 * one component of them (7680 or 8192 points of complex64 in 48 KiB: the rows of a 4K grid at
 * pad 2, an 8192^2 grid; complex128 up to about 6000), otherwise one global-memory launch per radix
 * stage. Between stages the values stay in registers, each work-item's Q butterflies of the
 * stage (at most FFT_INPLACE, radix at most FFT_INPLACE_R; the in-place plan's bounds), and
 * go from one stage's outputs to the next stage's inputs through local memory one component
 * at a time: real parts out, a barrier, real parts in, a barrier, imaginary parts out, a
 * barrier, imaginary parts in. The butterflies are the in-place plan's, so the same bits. The
 * first stage reads the source and the last writes the destination (as DIRECT_STAGE). The
 * round trip's step runs on the first transform's last outputs in registers (MID_VALUE), or,
 * with a mid callback (SPLIT_MID_SWEEP), in a sweep over local memory half a line at a time
 * (SPLIT_HALF_SWEEP): inlined at each of the stage's outputs, a callback such as the composite
 * made clang leave those loops rolled and u on the stack (benchmarks/gpu_registers.py).
 *
 * SPLIT_STAGE(R1, R2, P, PR1, PR2, PP, ...): the stage of radix R1 R2 at sub-transform size
 * P; PR1 PR2 and PP are the stage before it (for the first stage the last one: the stage
 * before the round trip's second transform), whose outputs u holds when FROM_SRC is not set.
 * Butterfly idx of a stage of nb_ per line sits in line idx % LINE_L, index idx / LINE_L of
 * the line where lines are columns (LINE_FAST: adjacent columns read and written together),
 * else line idx / nb_, index idx % nb_; every loop is bounded by the constants FFT_INPLACE and
 * FFT_INPLACE_R and guarded (see lines_stage_inplace), so u stays in registers. */
#define SPLIT_PLACE(idx, NB) const int l = LINE_FAST ? (idx) % LINE_L : (idx) / (NB);       \
                             const int i = LINE_FAST ? (idx) / LINE_L : (idx) % (NB);
/* For each butterfly of the stage (R1 R2, P) this work-item holds and each of its R1 R2
 * points r: the statement DO, which sees q and r (u[q][r] an input, u[q][FUSED_AT(r, R1, R2)]
 * output r), the butterfly's line l in the group, its index i (input r at i + r nb_) and j
 * (output r at j + r P) */
#define SPLIT_EACH(R1, R2, P, DO) {                                                          \
    const int R_ = (R1) * (R2), nb_ = LINE_N / R_, p_ = (P);                                   \
    const int Q_ = min(FFT_INPLACE, (LINE_L * nb_ + nthr - 1) / nthr);                         \
    INPLACE_EACH_QA(SPLIT_Q, (DO)) }
/* butterfly Q of SPLIT_EACH, written out (INPLACE_EACH_QA): as a loop over q, clang left it
 * rolled where a work-item holds many butterflies (PoCL: "loop not unrolled"; u in memory).
 * DO comes in parentheses (SPLIT_UNWRAP takes them off): expanded, a statement's commas would
 * split it into arguments on the way down */
#define SPLIT_UNWRAP(...) __VA_ARGS__
#define SPLIT_Q(Q, DO) {                                                                     \
    const int q = (Q), idx = lid + q * nthr;                                                   \
    if (q < Q_ && idx < LINE_L * nb_) {                                                        \
        SPLIT_PLACE(idx, nb_)                                                                  \
        const int k_ = i % p_, j = (i - k_) * R_ + k_;                                         \
        _Pragma("unroll")                                                                      \
        for (int r = 0; r < FFT_INPLACE_R; r++)                                                \
            if (r < R_) { SPLIT_UNWRAP DO }                                                    \
    } }
/* component C of the stage (R1 R2, P) before's outputs from u to local memory */
#define SPLIT_OUT(C, R1, R2, P)                                                              \
    SPLIT_EACH((R1), (R2), (P), sbuf[l * LINE_N + j + r * (P)] = u[q][FUSED_AT(r, (R1), (R2))].C;)
/* the stage's inputs go into the components the exchange has already taken out: the real
 * parts into u's real parts once they are all in local memory (the imaginary parts, still the
 * stage before's, go out next from the same u), so no second array is live */
#define SPLIT_IN(C, R1, R2, P)                                                               \
    SPLIT_EACH((R1), (R2), (P), u[q][r].C = sbuf[l * LINE_N + i + r * nb_];)
#if FFT_ROUND_TRIP && FFT_MID_CB
#define SPLIT_MID_SWEEP 1
#else
#define SPLIT_MID_SWEEP 0
#endif
/* elements of a half line: local memory holds L lines of SPLIT_HALF complex values */
#define SPLIT_HALF ((LINE_N + 1) / 2)
/* output r of the stage (R1 R2, P) where it lies at [k0, k0 + SPLIT_HALF) of its line, between
 * u and local memory (cbuf, complex): TO_LOCAL out of u, else back into u */
#define SPLIT_HALF_ONE(R1, R2, P, k0, TO_LOCAL) {                                            \
    const int kh = j + r * (P) - (k0);                                                         \
    if (kh >= 0 && kh < SPLIT_HALF) {                                                          \
        if (TO_LOCAL) cbuf[l * SPLIT_HALF + kh] = u[q][FUSED_AT(r, (R1), (R2))];               \
        else u[q][FUSED_AT(r, (R1), (R2))] = cbuf[l * SPLIT_HALF + kh];                        \
    } }
/* The round trip's step on the outputs of the first transform's last stage (R1 R2, P), half
 * a line at a time: out to local memory, the step element by element (work-items walk
 * adjacent lines first where lines are columns, as the other plans' sweeps), back into u */
#define SPLIT_HALF_SWEEP(R1, R2, P) {                                                        \
    __local real2 *cbuf = buf;                                                                 \
    _Pragma("unroll")                                                                          \
    for (int h = 0; h < 2; h++) {                                                              \
        const int k0 = h * SPLIT_HALF, len = min(LINE_N - k0, SPLIT_HALF);                     \
        barrier(CLK_LOCAL_MEM_FENCE);                                                          \
        SPLIT_EACH((R1), (R2), (P), SPLIT_HALF_ONE((R1), (R2), (P), k0, 1))                    \
        barrier(CLK_LOCAL_MEM_FENCE);                                                          \
        for (int idx = lid; idx < LINE_L * len; idx += nthr) {                                 \
            const int l = LINE_FAST ? idx % LINE_L : idx / len;                                \
            const int kh = LINE_FAST ? idx / LINE_L : idx % len;                               \
            cbuf[l * SPLIT_HALF + kh] = MID_VALUE(cbuf[l * SPLIT_HALF + kh], line0 + l, k0 + kh); \
        }                                                                                      \
        barrier(CLK_LOCAL_MEM_FENCE);                                                          \
        SPLIT_EACH((R1), (R2), (P), SPLIT_HALF_ONE((R1), (R2), (P), k0, 0))                    \
    } }
/* output r of the stage (R1 R2, P), the butterfly computed at r == 0: to the destination
 * (TO_DST), through the round trip's step (TO_MID), or left in u */
#define SPLIT_COMPUTE_ONE(R1, R2, P, TO_MID, TO_DST) {                                       \
    if (r == 0) fused_butterfly(u[q], LINE_N, (R1), (R2), (P), k_, tw);                        \
    const int k = j + r * (P), at = FUSED_AT(r, (R1), (R2));                                   \
    if (TO_DST) DST_ELEM(u[q][at], l, k)                                                       \
    else if (TO_MID) u[q][at] = MID_VALUE(u[q][at], line0 + l, k); }
#define SPLIT_STAGE(R1, R2, P, PR1, PR2, PP, FROM_SRC, TO_MID, TO_DST) {                      \
    if (FROM_SRC) {                                                                            \
        SPLIT_EACH((R1), (R2), (P), u[q][r] = SRC_ELEM(l, i + r * nb_);)                       \
    } else {                                                                                   \
        /* the first barrier also orders every read of the source before the last stage's    \
         * writes, where a pass runs in place (src == dst) */                                  \
        barrier(CLK_LOCAL_MEM_FENCE | CLK_GLOBAL_MEM_FENCE);                                   \
        SPLIT_OUT(x, (PR1), (PR2), (PP))                                                       \
        barrier(CLK_LOCAL_MEM_FENCE);                                                          \
        SPLIT_IN(x, (R1), (R2), (P))                                                           \
        barrier(CLK_LOCAL_MEM_FENCE);                                                          \
        SPLIT_OUT(y, (PR1), (PR2), (PP))                                                       \
        barrier(CLK_LOCAL_MEM_FENCE);                                                          \
        SPLIT_IN(y, (R1), (R2), (P))                                                           \
    }                                                                                          \
    SPLIT_EACH((R1), (R2), (P), SPLIT_COMPUTE_ONE((R1), (R2), (P), (TO_MID), (TO_DST))) }
#endif
#if FFT_DIRECT || FFT_SPLIT
/* The round trip's step folded into the forward's last stage, or (a callback that defines
 * FFT_MID_CB_SWEEP: too heavy to repeat at each of a butterfly's outputs) a sweep after it */
#if FFT_ROUND_TRIP && FFT_MID_CB && (defined(FFT_MID_CB_SWEEP) || MID_QUADS) && !FFT_SPLIT
#define FFT_MID_FOLDED 0
#else
#define FFT_MID_FOLDED FFT_ROUND_TRIP
#endif
#if FFT_ROUND_TRIP
#define MID_VALUE(v, l, k) mid_value((v), (l), (k), N, nlines, b, m, mul_ls, mul_lmod, mul_es,    \
                                     mul_mode, mid_n, mid_conj_a, mid_conj_b,                 \
                                     mid_scale FFT_MID_ACC_ARG(&mid_acc) FFT_MID_CB_ARGS)
#else
#define MID_VALUE(v, l, k) (v)
#endif
#endif

/* The line length, lines per group and work-group size, fixed per build where the plan gives
 * them (FFT_N, FFT_L, FFT_WG: one program per size, as VkFFT and cuFFT generate theirs), else
 * the arguments N and L. A fixed work-group size also tells the compiler how many registers
 * each work-item may have. */
#ifdef FFT_N
#define LINE_N FFT_N
#define LINE_L FFT_L
#define LINE_FAST FFT_LINE_FAST
#else
#define LINE_N N
#define LINE_L L
#define LINE_FAST line_fast
#endif

#ifdef FFT_WG
__kernel __attribute__((reqd_work_group_size(FFT_WG, 1, 1)))
void fft_lines(FFT_PASS_ARGS, FFT_LINES_ARGS FFT_CB_PARAMS)
#else
__kernel void fft_lines(FFT_PASS_ARGS, FFT_LINES_ARGS FFT_CB_PARAMS)
#endif
{
#ifdef FFT_WG
    const int lid = get_local_id(0), nthr = FFT_WG;
#else
    const int lid = get_local_id(0), nthr = get_local_size(0);
#endif
    const int line0 = LINE_GROUP_ID() * LINE_L;
    const long b = BATCH_GROUP_ID();
    __global const real2 *s0 = src + src_off + b * src_bs; /* line 0 of this batch element */
    __global real2 *d = dst + dst_off + b * dst_bs + line0 * dst_ls;
    __global const real2 *m = mul + mul_off + (b % mul_m) * mul_bs;
    const int total = LINE_L * LINE_N;
    const int nsl = min(nlines - line0, LINE_L), nse = min(nstore, LINE_N);
#if FFT_ROUND_TRIP && FFT_MID_CB && defined(FFT_MID_CB_SUMS)
    __local real4 mid_sums_scratch[FFT_WG];
    real4 mid_acc = (real4)(0, 0, 0, 0);
#endif

#if FFT_SPLIT
    /* the split plan (SPLIT_STAGE): values in registers between stages, one component at a
     * time through local memory */
    __local real *sbuf = (__local real *)buf;
    real2 u[FFT_INPLACE][FFT_INPLACE_R];
#define FFT_SSTAGE(R1_, R2_, P_, PR1_, PR2_, PP_)                                            \
    SPLIT_STAGE((R1_), (R2_), (P_), (PR1_), (PR2_), (PP_), from_src && (P_) == 1,              \
                to_mid && (P_) * (R1_) * (R2_) == LINE_N,                                      \
                to_dst && (P_) * (R1_) * (R2_) == LINE_N)
    {
        const int from_src = 1, to_mid = FFT_ROUND_TRIP * (1 - SPLIT_MID_SWEEP);
        const int to_dst = !FFT_ROUND_TRIP;
        FFT_SPLIT_STAGES
    }
#if FFT_ROUND_TRIP
#if SPLIT_MID_SWEEP
    SPLIT_HALF_SWEEP(FFT_SPLIT_LAST_R1, FFT_SPLIT_LAST_R2, FFT_SPLIT_LAST_P)
#endif
    MID_SUMS_STORE();
    {
        const int from_src = 0, to_mid = 0, to_dst = 1;
        FFT_SPLIT_STAGES
    }
#endif
#undef FFT_SSTAGE
#elif FFT_DIRECT
    /* The plan fixed at build, two buffers: the first stage reads its butterflies' inputs from
     * the source window and the last writes its outputs to the destination window, with the
     * round trip's step between the transforms folded into the forward's last stage, so the
     * elements pass through local memory once per stage, not once more for the load, the step
     * and the store (and three barriers fewer). */
#if FFT_INPLACE
    __local real2 *in = buf, *out = buf, *t; /* (unused: the stages work in buf) */
#else
    __local real2 *in = buf, *out = buf + total, *t;
#endif
#define FFT_STAGE(R1_, R2_, P_)                                                              \
    DIRECT_STAGE((R1_), (R2_), (P_), from_src && (P_) == 1,                                    \
                 to_mid && (P_) * (R1_) * (R2_) == LINE_N,                                     \
                 to_dst && (P_) * (R1_) * (R2_) == LINE_N)                                     \
    t = in; in = out; out = t;
    {
        const int from_src = 1, to_mid = FFT_MID_FOLDED, to_dst = !FFT_ROUND_TRIP;
        FFT_STAGE_LIST
    }
#if FFT_ROUND_TRIP
#if !FFT_MID_FOLDED
    /* a heavy mid callback in a sweep of its own over local memory: inlined into the last
     * stage's unrolled outputs (R of them) it made clang leave that loop rolled and the
     * butterfly's values on the stack (SGD's Adam step: 512 bytes at 1200 points) */
#if MID_QUADS
    if (MID_QUADS_FIT(LINE_N, LINE_L)) {
        MID_QUAD_SWEEP(in, LINE_N, LINE_L)
    } else
#endif
    for (int idx = lid; idx < total; idx += nthr) {
        const int l = LINE_FAST ? idx % LINE_L : idx / LINE_N;
        const int k = LINE_FAST ? idx / LINE_L : idx % LINE_N;
        in[l * LINE_N + k] = MID_VALUE(in[l * LINE_N + k], line0 + l, k);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
#endif
    MID_SUMS_STORE();
    {
        const int from_src = 0, to_mid = 0, to_dst = 1;
        FFT_STAGE_LIST
    }
#endif
#undef FFT_STAGE
#else
    /* the generic program, the in-place plan and 1-point lines: load, every stage, store */
    for (int idx = lid; idx < total; idx += nthr) {
        const int l = LINE_FAST ? idx % LINE_L : idx / LINE_N;
        const int k = LINE_FAST ? idx / LINE_L : idx % LINE_N;
        buf[l * LINE_N + k] = load_src(s0, src_ls, src_es, src_nl, src_ne, line0 + l, k,
                                       m, mul_ls, mul_lmod, mul_es, mul_mode, conj_in,
                                       b FFT_LOAD_CB_ARGS);
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    __local real2 *in = LINES_STAGES(buf);
#if FFT_ROUND_TRIP
    /* the step between the transforms, in local memory, then every stage again; work-items
     * walk the lines as the load does (line_fast: adjacent columns, so that a transfer
     * function's row is read coalesced) */
#if MID_QUADS
    if (MID_QUADS_FIT(LINE_N, LINE_L)) {
        MID_QUAD_SWEEP(in, LINE_N, LINE_L)
    } else
#endif
    for (int idx = lid; idx < total; idx += nthr) {
        const int l = LINE_FAST ? idx % LINE_L : idx / LINE_N;
        const int k = LINE_FAST ? idx / LINE_L : idx % LINE_N;
        in[l * LINE_N + k] = mid_value(in[l * LINE_N + k], line0 + l, k, N, nlines, b, m, mul_ls,
                                       mul_lmod, mul_es, mul_mode, mid_n, mid_conj_a,
                                       mid_conj_b, mid_scale FFT_MID_ACC_ARG(&mid_acc)
                                       FFT_MID_CB_ARGS);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    MID_SUMS_STORE();
    in = LINES_STAGES(in);
#endif

    for (int idx = lid; idx < total; idx += nthr) {
        const int l = LINE_FAST ? idx % LINE_L : idx / LINE_N;
        const int k = LINE_FAST ? idx / LINE_L : idx % LINE_N;
        if (l < nsl && k < nse)
            STORE_DST(d + l * dst_ls + k * dst_es,
                      finish_dst(in[l * LINE_N + k], line0 + l, k, m, mul_ls, mul_lmod, mul_es,
                                 mul_mode, conj_out, scale), b, line0 + l, k);
    }
#endif
}

__kernel void fft_stage(FFT_PASS_ARGS, FFT_STAGE_ARGS FFT_CB_PARAMS)
{
    /* line_fast: global id 0 walks lines (column passes: adjacent addresses), else butterflies */
    const int l = line_fast ? get_global_id(0) : get_global_id(1);
    const int i = line_fast ? get_global_id(1) : get_global_id(0);
    const long b = get_global_id(2);
    if (l >= nlines || i >= N / R) return;
    __global const real2 *s0 = src + src_off + b * src_bs; /* line 0 of this batch element */
    __global real2 *d = dst + dst_off + b * dst_bs + l * dst_ls;
    __global const real2 *m = mul + mul_off + (b % mul_m) * mul_bs;
    const int nse = min(nstore, N);
#define GLOAD(e) (first ? load_src(s0, src_ls, src_es, src_nl, src_ne, l, (e), m, mul_ls,    \
                                   mul_lmod, mul_es, mul_mode, conj_in, b FFT_LOAD_CB_ARGS)     \
                        : s0[l * src_ls + (e) * src_es])
#define GSTORE(e, v) { if (!last) d[(e) * dst_es] = (v);                                    \
                       else if ((e) < nse) STORE_DST(d + (e) * dst_es, finish_dst((v), l, (e), m,  \
                                   mul_ls, mul_lmod, mul_es, mul_mode, conj_out, scale), b, l, (e)); }
    GPU_BUTTERFLY(GLOAD, GSTORE)
#undef GLOAD
#undef GSTORE
}
