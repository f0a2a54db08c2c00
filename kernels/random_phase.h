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

#endif
