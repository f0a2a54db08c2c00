/* The random phase stream of HOLOGRAPHY.md section 4, shared by every kernel that draws phases.
 *
 * Pixel p = y*W + x; Philox4x32-10 counter (p / 4, layer, frame, colour); key (seed low, seed
 * high); word p % 4 is x; phase = 2 pi ((x >> 8) + 0.5) 2^-24 in float32. Each float step is a
 * single correctly rounded operation in the same order as clholo.reference.phase_from_word, so
 * NumPy reproduces it bit for bit; keep it free of anything a compiler could contract.
 */
#ifndef CLHOLO_RANDOM_PHASE_H
#define CLHOLO_RANDOM_PHASE_H

#include <pyopencl-random123/philox.cl>

#define CLHOLO_TWO_PI_F 6.28318548202514648438f /* float32(2 pi) */

static inline float clholo_phase_from_word(uint x)
{
    float t = (float)(x >> 8) + 0.5f;
    t = t * 0x1p-24f;
    return t * CLHOLO_TWO_PI_F;
}

/* The four phases of pixels 4*block .. 4*block+3 */
static inline float4 clholo_phase_block(uint block, uint layer, uint frame, uint colour,
                                        uint key_lo, uint key_hi)
{
    philox4x32_ctr_t ctr = {{block, layer, frame, colour}};
    philox4x32_key_t key = {{key_lo, key_hi}};
    philox4x32_ctr_t r = philox4x32(ctr, key);
    return (float4)(clholo_phase_from_word(r.v[0]), clholo_phase_from_word(r.v[1]),
                    clholo_phase_from_word(r.v[2]), clholo_phase_from_word(r.v[3]));
}

/* Phase of one pixel p (recomputes the whole Philox block; use clholo_phase_block when a
 * work-item owns four consecutive pixels). */
static inline float clholo_phase(uint p, uint layer, uint frame, uint colour, uint key_lo,
                                  uint key_hi)
{
    philox4x32_ctr_t ctr = {{p >> 2, layer, frame, colour}};
    philox4x32_key_t key = {{key_lo, key_hi}};
    philox4x32_ctr_t r = philox4x32(ctr, key);
    /* the block's word p & 3 by selects, not r.v[p & 3]: an index known only at run time puts
     * the block in a GPU's stack memory (16 bytes a work-item, read back per pixel; clang's
     * NVPTX build, benchmarks/gpu_registers.py --render). Two levels of selects: Debian's
     * Oclgrind 21.10 gave other work-items' words for a chain i == 0 ? .. : i == 1 ? .. */
    const uint i = p & 3u;
    const uint lo = (i & 1u) ? r.v[1] : r.v[0], hi = (i & 1u) ? r.v[3] : r.v[2];
    return clholo_phase_from_word((i & 2u) ? hi : lo);
}

/* Philox4x32-10 of eight or sixteen counters (block[i], layer, frame, colour) at once, in
 * uint8 / uint16 arithmetic (lane i of each output word is counter i's word): the rounds and
 * key schedule of Random123's philox4x32 above, written out so that a CPU runs the blocks as
 * SIMD. PoCL's CPU driver lowers a vector mul_hi lane by lane, so the rounds' 32 x 32 -> 64-bit
 * products come from 64-bit multiplies (clholo_mulhilo8/16): 2.5x (eight) and 4.4x (sixteen)
 * the blocks per second of mul_hi on an AVX-512 Xeon. The same words bit for bit
 * (tests/test_phase_stream.py). */

/* eight products: one ulong8 multiply, split into high and low words */
static inline void clholo_mulhilo8(uint m, uint8 c, uint8 *hi, uint8 *lo)
{
    const ulong8 p = convert_ulong8(c) * (ulong8)(m);
    *hi = convert_uint8(p >> 32);
    *lo = convert_uint8(p);
}

/* sixteen products: the lanes as eight 64-bit pairs, the even lanes' products from the low
 * halves, the odd lanes' from the high halves, then the high and low words blended back (two
 * 64-bit multiplies for sixteen products). Needs a little-endian device (as_ulong8 of a uint16
 * puts lane 2k in the low half of pair k); others take mul_hi. */
static inline void clholo_mulhilo16(uint m, uint16 c, uint16 *hi, uint16 *lo)
{
#if defined(__ENDIAN_LITTLE__)
    const ulong8 x = as_ulong8(c);
    const ulong8 even = (x & (ulong8)(0xFFFFFFFFul)) * (ulong8)(m);
    const ulong8 odd = (x >> 32) * (ulong8)(m);
    *hi = as_uint16((even >> 32) | (odd & (ulong8)(0xFFFFFFFF00000000ul)));
    *lo = as_uint16((even & (ulong8)(0xFFFFFFFFul)) | (odd << 32));
#else
    *hi = mul_hi((uint16)(m), c);
    *lo = c * (uint16)(m);
#endif
}

/* The rounds and the phases, once for both widths (N = 8 or 16) */
#define CLHOLO_PHILOX_N(N)                                                                   \
static inline void clholo_philox##N(uint##N block, uint layer, uint frame, uint colour,     \
                                    uint key_lo, uint key_hi, uint##N *w0, uint##N *w1,     \
                                    uint##N *w2, uint##N *w3)                               \
{                                                                                            \
    uint##N c0 = block, c1 = (uint##N)(layer), c2 = (uint##N)(frame);                       \
    uint##N c3 = (uint##N)(colour);                                                          \
    uint k0 = key_lo, k1 = key_hi;                                                           \
    for (int r = 0; r < 10; ++r) {                                                           \
        if (r > 0) { k0 += 0x9E3779B9u; k1 += 0xBB67AE85u; }                                 \
        uint##N hi0, lo0, hi1, lo1;                                                          \
        clholo_mulhilo##N(0xD2511F53u, c0, &hi0, &lo0);                                      \
        clholo_mulhilo##N(0xCD9E8D57u, c2, &hi1, &lo1);                                      \
        const uint##N n0 = hi1 ^ c1 ^ (uint##N)(k0), n2 = hi0 ^ c3 ^ (uint##N)(k1);          \
        c0 = n0; c1 = lo1; c2 = n2; c3 = lo0;                                                \
    }                                                                                        \
    *w0 = c0; *w1 = c1; *w2 = c2; *w3 = c3;                                                  \
}                                                                                            \
                                                                                             \
/* clholo_phase_from_word on N words: the same three correctly rounded steps (the result by \
 * pointer, as every 16-wide helper's) */                                                    \
static inline void clholo_phase_from_word##N(uint##N x, float##N *phase)                    \
{                                                                                            \
    float##N t = convert_float##N(x >> 8) + 0.5f;                                            \
    t = t * 0x1p-24f;                                                                        \
    *phase = t * CLHOLO_TWO_PI_F;                                                            \
}                                                                                            \
                                                                                             \
/* The phases of pixels 4 block[i] + j (j = 0..3) as ph[j] lane i: N Philox blocks at once */\
static inline void clholo_phase_blocks##N(uint##N block, uint layer, uint frame, uint colour,\
                                          uint key_lo, uint key_hi, float##N *ph)           \
{                                                                                            \
    uint##N w0, w1, w2, w3;                                                                  \
    clholo_philox##N(block, layer, frame, colour, key_lo, key_hi, &w0, &w1, &w2, &w3);      \
    clholo_phase_from_word##N(w0, &ph[0]); clholo_phase_from_word##N(w1, &ph[1]);            \
    clholo_phase_from_word##N(w2, &ph[2]); clholo_phase_from_word##N(w3, &ph[3]);            \
}

CLHOLO_PHILOX_N(8)
CLHOLO_PHILOX_N(16)

#endif
