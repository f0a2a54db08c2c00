/* Wave-domain "over" of one MPI layer onto the field arriving from behind it, for every frame
 * and colour of a batch (HOLOGRAPHY.md section 4):
 *
 *   u <- sqrt(1 - a) u + sqrt(c a) exp(i phi)
 *
 * phi is drawn in place from the Philox stream (no phase buffer): one work-item owns four
 * consecutive pixels, which is exactly one Philox call.
 *
 * u      float2 [frames][colours][npix]      (in/out; not read for the farthest layer)
 * color  float  [npix][n_channels]           this layer, straight linear colour
 * alpha  float  [npix]
 * Global size (ceil(npix / 4), colours, frames); colour c of the batch is channel colour0 + c
 * and frame f is frame0 + f of the stream.
 */
#include "random_phase.h"

__kernel void composite_layer(__global float2 *u, __global const float *color,
                              __global const float *alpha, const uint npix,
                              const uint n_channels, const uint layer, const uint frame0,
                              const uint colour0, const uint key_lo, const uint key_hi,
                              const int farthest)
{
    const uint block = get_global_id(0);
    const uint c = get_global_id(1);
    const uint f = get_global_id(2);
    const uint colours = get_global_size(1);
    const uint p0 = block * 4u;
    if (p0 >= npix)
        return;
    const uint channel = colour0 + c;
    const float4 phi4 = clholo_phase_block(block, layer, frame0 + f, channel, key_lo, key_hi);
    const float phi[4] = {phi4.s0, phi4.s1, phi4.s2, phi4.s3};
    __global float2 *field = u + ((size_t)f * colours + c) * npix;
    const uint n = min(4u, npix - p0);
    for (uint k = 0; k < n; ++k) {
        const uint p = p0 + k;
        const float a = alpha[p];
        const float amp = sqrt(color[(size_t)p * n_channels + channel] * a);
        float co;
        const float s = sincos(phi[k], &co);
        float2 v = (float2)(amp * co, amp * s);
        if (!farthest) {
            const float keep = sqrt(1.0f - a);
            v += keep * field[p];
        }
        field[p] = v;
    }
}
