/* sin and cos of four or eight floats at once, in straight-line vector code.
 *
 * Why: PoCL's CPU driver calls a scalar libm routine for sincos wherever the argument is a
 * scalar (about 40 ns an element on a 2-core EPYC: seven times the rest of SGD's Adam kernel),
 * and its float4 builtin is still twice this. Written as plain float4 arithmetic the work
 * vectorises like any multiply-add. GPUs have fast sincos either way; this costs them nothing.
 *
 * Method (Cephes sinf/cosf): j = rint(x * 2/pi); r = x - j pi/2 with pi/2 split into three
 * floats (Cody-Waite: j * the first part is exact for |j| < 2^16, so r keeps its accuracy for
 * |x| up to about 8192 pi/2); minimax polynomials of sin and cos on [-pi/4, pi/4]; the quadrant
 * j mod 4 swaps and negates them. Outside |x| <= CLHOLO_SINCOS_FAST_MAX the builtin takes over
 * (exact range reduction), for the whole vector.
 *
 * Accuracy: absolute error 9.5e-8 at most (the builtin's: 9.4e-8), checked against float64 on
 * every phase of the Philox stream and on random arguments up to 1e5 in
 * tests/test_fast_sincos.py; the rounding differs from the builtin's, so results are not bit
 * for bit those of sincos().
 */
#ifndef CLHOLO_FAST_SINCOS_H
#define CLHOLO_FAST_SINCOS_H

#define CLHOLO_SINCOS_FAST_MAX 12000.0f

/* rint(y) for |y| < 2^22, any float type (see below) */
#define CLHOLO_QUADRANT(y) (((y) + 12582912.0f) - 12582912.0f)

/* The reduction and polynomials, once for float4, float8 and float16 (TY, its int type ITY,
 * convert_ITY): the same operations lane by lane, so every width gives the same bits. Exact
 * for |x| <= CLHOLO_SINCOS_FAST_MAX. Results through sin_out and cos_out.
 *
 * The quadrant j = rint(y) is CLHOLO_QUADRANT(y) = (y + 1.5 2^23) - 1.5 2^23: for |y| < 2^22
 * the sum lies in [2^23, 2^24), where floats are the integers, so the add rounds y to the
 * nearest integer, ties to even (1.5 2^23 is even), as rint does; the subtraction is exact.
 * y is its own statement, so the product is not contracted into the add. PoCL's CPU library
 * lowered rint to 17 instructions of compares and masks. */
#define CLHOLO_SINCOS_REDUCED(TY, ITY, x, sin_out, cos_out)                              \
    {                                                                                    \
        const TY y = x * 0.636619772367581343f;                                          \
        const TY j = CLHOLO_QUADRANT(y);                                                 \
        TY r = x - j * 1.5703125f;                                                       \
        r = r - j * 4.837512969970703125e-4f;                                            \
        r = r - j * 7.549789954891882e-8f;                                               \
        const TY z = r * r;                                                              \
        const TY s = r + r * z * (-1.6666654611e-1f + z * (8.3321608736e-3f              \
                                                          + z * -1.9515295891e-4f));     \
        const TY c = 1.0f - 0.5f * z + z * z * (4.166664568298827e-2f                    \
                                                + z * (-1.388731625493765e-3f            \
                                                       + z * 2.443315711809948e-5f));    \
        const ITY q = convert_##ITY(j);                                                  \
        const ITY odd = (q & 1) != 0;       /* quadrants 1 and 3: sin and cos swap */    \
        TY sv = select(s, c, odd);                                                       \
        TY cv = select(c, s, odd);                                                       \
        sv = select(sv, -sv, (q & 2) != 0); /* quadrants 2 and 3: sin < 0 */             \
        cv = select(cv, -cv, ((q + 1) & 2) != 0); /* quadrants 1 and 2: cos < 0 */       \
        *(cos_out) = cv;                                                                 \
        *(sin_out) = sv;                                                                 \
    }

/* Any argument: the builtin for the whole vector where a lane lies beyond the fast range */
#define CLHOLO_SINCOS_BODY(TY, ITY, x, sin_out, cos_out)                                 \
    if (any(fabs(x) > CLHOLO_SINCOS_FAST_MAX)) {                                         \
        *(sin_out) = sincos(x, cos_out);                                                 \
    } else                                                                               \
        CLHOLO_SINCOS_REDUCED(TY, ITY, x, sin_out, cos_out)

static inline float4 clholo_sincos4(float4 x, float4 *cos_out)
{
    float4 sin_x;
    CLHOLO_SINCOS_BODY(float4, int4, x, &sin_x, cos_out)
    return sin_x;
}

/* Eight at once: on PoCL (AVX-512 Xeon) 0.83 ns an element against 1.6 for two float4 calls,
 * because a 256-bit vector is what the CPU's shuffles and selects handle best. */
static inline float8 clholo_sincos8(float8 x, float8 *cos_out)
{
    float8 sin_x;
    CLHOLO_SINCOS_BODY(float8, int8, x, &sin_x, cos_out)
    return sin_x;
}

/* Sixteen at once (the CPU round trip's composite: eight rows by two columns; SGD's Adam
 * step): 0.70 ns an element. Both results by pointer, as every 16-wide helper's (a 16-wide
 * value changes the calling convention on CPUs without AVX-512). */
static inline void clholo_sincos16(float16 x, float16 *sin_out, float16 *cos_out)
{
    CLHOLO_SINCOS_BODY(float16, int16, x, sin_out, cos_out)
}

/* Sixteen phases of the Philox stream (random_phase.h: every one in (0, 2 pi), far inside the
 * fast range): clholo_sincos16's bits without its test of the range, which took a compare, a
 * mask move and a horizontal reduction of every vector (the SLM-size row round trip with the
 * composite 1.04x faster on PoCL, docs/benchmarks.md). Only for arguments known to lie
 * within +-CLHOLO_SINCOS_FAST_MAX. */
static inline void clholo_sincos16_phase(float16 x, float16 *sin_out, float16 *cos_out)
{
    CLHOLO_SINCOS_REDUCED(float16, int16, x, sin_out, cos_out)
}

#endif
