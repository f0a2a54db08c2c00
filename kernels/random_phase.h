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

inline float clholo_phase_from_word(uint x)
{
    float t = (float)(x >> 8) + 0.5f;
    t = t * 0x1p-24f;
    return t * CLHOLO_TWO_PI_F;
}

/* The four phases of pixels 4*block .. 4*block+3 */
inline float4 clholo_phase_block(uint block, uint layer, uint frame, uint colour, uint key_lo,
                                 uint key_hi)
{
    philox4x32_ctr_t ctr = {{block, layer, frame, colour}};
    philox4x32_key_t key = {{key_lo, key_hi}};
    philox4x32_ctr_t r = philox4x32(ctr, key);
    return (float4)(clholo_phase_from_word(r.v[0]), clholo_phase_from_word(r.v[1]),
                    clholo_phase_from_word(r.v[2]), clholo_phase_from_word(r.v[3]));
}

/* Phase of one pixel p (recomputes the whole Philox block; use clholo_phase_block when a
 * work-item owns four consecutive pixels). */
inline float clholo_phase(uint p, uint layer, uint frame, uint colour, uint key_lo, uint key_hi)
{
    philox4x32_ctr_t ctr = {{p >> 2, layer, frame, colour}};
    philox4x32_key_t key = {{key_lo, key_hi}};
    philox4x32_ctr_t r = philox4x32(ctr, key);
    return clholo_phase_from_word(r.v[p & 3u]);
}

/* Philox4x32-10 of eight counters (block[i], layer, frame, colour) at once, in uint8
 * arithmetic (lane i of each output word is counter i's word): the rounds and key schedule of
 * Random123's philox4x32 above, written out so that a CPU runs eight blocks as SIMD. Each
 * round's 32 x 32 -> 64-bit products are one ulong8 multiply, split into high and low words:
 * PoCL's CPU driver lowers a vector mul_hi lane by lane, and this form ran 2.5x faster on an
 * AVX-512 Xeon (the same words: tests/test_random_phase.py). */
inline void clholo_philox8(uint8 block, uint layer, uint frame, uint colour, uint key_lo,
                           uint key_hi, uint8 *w0, uint8 *w1, uint8 *w2, uint8 *w3)
{
    uint8 c0 = block, c1 = (uint8)(layer), c2 = (uint8)(frame), c3 = (uint8)(colour);
    uint k0 = key_lo, k1 = key_hi;
    for (int r = 0; r < 10; ++r) {
        if (r > 0) { k0 += 0x9E3779B9u; k1 += 0xBB67AE85u; }
        const ulong8 p0 = convert_ulong8(c0) * (ulong8)(0xD2511F53u);
        const ulong8 p1 = convert_ulong8(c2) * (ulong8)(0xCD9E8D57u);
        const uint8 hi0 = convert_uint8(p0 >> 32), lo0 = convert_uint8(p0);
        const uint8 hi1 = convert_uint8(p1 >> 32), lo1 = convert_uint8(p1);
        const uint8 n0 = hi1 ^ c1 ^ (uint8)(k0), n2 = hi0 ^ c3 ^ (uint8)(k1);
        c0 = n0; c1 = lo1; c2 = n2; c3 = lo0;
    }
    *w0 = c0; *w1 = c1; *w2 = c2; *w3 = c3;
}

/* clholo_phase_from_word on eight words: the same three correctly rounded steps */
inline float8 clholo_phase_from_word8(uint8 x)
{
    float8 t = convert_float8(x >> 8) + 0.5f;
    t = t * 0x1p-24f;
    return t * CLHOLO_TWO_PI_F;
}

/* The phases of pixels 4 block[i] + j (j = 0..3) as ph[j] lane i: eight Philox blocks at once */
inline void clholo_phase_blocks8(uint8 block, uint layer, uint frame, uint colour, uint key_lo,
                                 uint key_hi, float8 *ph)
{
    uint8 w0, w1, w2, w3;
    clholo_philox8(block, layer, frame, colour, key_lo, key_hi, &w0, &w1, &w2, &w3);
    ph[0] = clholo_phase_from_word8(w0); ph[1] = clholo_phase_from_word8(w1);
    ph[2] = clholo_phase_from_word8(w2); ph[3] = clholo_phase_from_word8(w3);
}

#endif
