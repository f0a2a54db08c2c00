/* Random phase maps for a batch of frames and colours of one layer.
 *
 * out: float [frames][colours][npix], phase of pixel p of (frame0 + f, colour0 + c, layer).
 * Global size (ceil(npix / 4), colours, frames): one Philox call gives four pixels.
 */
#include "random_phase.h"

__kernel void random_phase(__global float *out, const uint npix, const uint layer,
                           const uint frame0, const uint colour0, const uint key_lo,
                           const uint key_hi)
{
    const uint block = get_global_id(0);
    const uint c = get_global_id(1);
    const uint f = get_global_id(2);
    const uint colours = get_global_size(1);
    const uint p0 = block * 4u;
    if (p0 >= npix)
        return;
    float4 phi = clholo_phase_block(block, layer, frame0 + f, colour0 + c, key_lo, key_hi);
    __global float *dst = out + ((size_t)f * colours + c) * npix;
    if (p0 + 4u <= npix) {
        vstore4(phi, 0, dst + p0);
    } else {
        float w[4] = {phi.s0, phi.s1, phi.s2, phi.s3};
        for (uint k = 0; p0 + k < npix; ++k)
            dst[p0 + k] = w[k];
    }
}

/* Raw Philox4x32-10 output, for the known-answer tests: one counter/key per work-item. */
__kernel void philox_raw(__global const uint4 *counters, __global const uint2 *keys,
                         __global uint4 *out)
{
    const size_t i = get_global_id(0);
    uint4 c = counters[i];
    uint2 k = keys[i];
    philox4x32_ctr_t ctr = {{c.x, c.y, c.z, c.w}};
    philox4x32_key_t key = {{k.x, k.y}};
    philox4x32_ctr_t r = philox4x32(ctr, key);
    out[i] = (uint4)(r.v[0], r.v[1], r.v[2], r.v[3]);
}
