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
 *
 * -D CLHOLO_NO_OCCLUSION: transmission 1 instead of sqrt(1 - a), u <- u + sqrt(c a) exp(i phi):
 * the RGB-D layer-sum baseline (HOLOGRAPHY.md section 7) through the same recursion.
 */
#include "random_phase.h"
#include "fast_sincos.h"

#ifdef CLHOLO_NO_OCCLUSION
#define CLHOLO_TRANSMISSION(a) 1.0f
#else
#define CLHOLO_TRANSMISSION(a) sqrt(1.0f - (a))
#endif

/* One pixel, for the ragged end of the field (at most three per batch row). */
static inline void composite_pixel(__global float2 *field, __global const float *color,
                                   __global const float *alpha, uint p, uint n_channels,
                                   uint channel, float phi, int farthest)
{
    const float a = alpha[p];
    const float amp = sqrt(color[(size_t)p * n_channels + channel] * a);
    float4 co;
    const float4 si = clholo_sincos4((float4)(phi), &co);   /* the same values as the body's */
    float2 v = (float2)(amp * co.x, amp * si.x);
    if (!farthest)
        v += CLHOLO_TRANSMISSION(a) * field[p];
    field[p] = v;
}

/* The body is straight-line vector code on purpose: PoCL only vectorizes across work-items
 * when a kernel has no loops, and explicit float4/float8 math maps onto SIMD either way. */
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
    const float4 phi = clholo_phase_block(block, layer, frame0 + f, channel, key_lo, key_hi);
    __global float2 *field = u + ((size_t)f * colours + c) * npix;
    if (p0 + 4u <= npix) {
        const float4 a = vload4(0, alpha + p0);
        float4 col;
        if (n_channels == 1u) {
            col = vload4(0, color + p0);
        } else {
            __global const float *src = color + (size_t)p0 * n_channels + channel;
            col = (float4)(src[0], src[n_channels], src[2 * n_channels], src[3 * n_channels]);
        }
        const float4 amp = sqrt(col * a);
        float4 co;
        const float4 si = clholo_sincos4(phi, &co);
        /* interleave (re, im) pairs of the four pixels */
        float8 v = shuffle2(amp * co, amp * si, (uint8)(0, 4, 1, 5, 2, 6, 3, 7));
        __global float *dst = (__global float *)(field + p0);
        if (!farthest) {
            const float4 keep = CLHOLO_TRANSMISSION(a);
            v += shuffle(keep, (uint8)(0, 0, 1, 1, 2, 2, 3, 3)) * vload8(0, dst);
        }
        vstore8(v, 0, dst);
    } else {
        composite_pixel(field, color, alpha, p0, n_channels, channel, phi.s0, farthest);
        if (p0 + 1u < npix)
            composite_pixel(field, color, alpha, p0 + 1u, n_channels, channel, phi.s1, farthest);
        if (p0 + 2u < npix)
            composite_pixel(field, color, alpha, p0 + 2u, n_channels, channel, phi.s2, farthest);
    }
}
