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
        v = fma((float2)(CLHOLO_TRANSMISSION(a)), field[p], v);   /* composite_store.h */
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
            v = fma(shuffle(keep, (uint8)(0, 0, 1, 1, 2, 2, 3, 3)), vload8(0, dst), v);
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

/* The composite of one layer as the round trips' callback computes it (composite_store.h's
 * composite_value4: any layout of the layers, CLHOLO_LAYER_BLOCKS / CLHOLO_LAYER_ROWS), four
 * pixels of one row a work-item: the farthest layer of a render whose layers composite.cl's
 * composite_layer cannot read (HologramRenderer's layer_layout "planes" on GPUs).
 *
 * u      float2 [frames][n_channels][height][width]   (in/out; not read when farthest)
 * color, alpha: the layer in the layout of the build's defines (composite_store.h)
 * Global size (ceil(width / 4), height, frames * n_channels): field b is frame
 * frame0 + b / n_channels of the stream, channel b % n_channels. A row's last pixels past a
 * multiple of four go one by one (composite_value, the same values).
 */
typedef float2 real2;
#include "composite_store.h"

__kernel void composite_layer_rows4(__global float2 *u, __global const float *color,
                                    __global const float *alpha, const uint height,
                                    const uint width, const uint n_channels, const uint layer,
                                    const uint frame0, const uint key_lo, const uint key_hi,
                                    const int farthest)
{
    const int col = get_global_id(0) * 4, row = get_global_id(1);
    const long b = get_global_id(2);
    if (col >= (int)width)
        return;
    __global float2 *line = u + ((size_t)b * height + (uint)row) * width;
    if (col + 4 <= (int)width) {
        float2 v[4];
        for (int q = 0; q < 4; ++q)
            v[q] = farthest ? (float2)(0.0f) : line[col + q];
        composite_value4(v, b, row, col, color, alpha, width, n_channels, layer, frame0,
                         key_lo, key_hi);
        for (int q = 0; q < 4; ++q)
            line[col + q] = v[q];
        return;
    }
    for (int c = col; c < (int)width; ++c)
        line[c] = composite_value(farthest ? (float2)(0.0f) : line[c], b, row, c, color, alpha,
                                  width, n_channels, layer, frame0, key_lo, key_hi);
}

/* A layer as the GPU composites read it with CLHOLO_LAYER_BLOCKS and CLHOLO_LAYER_ROWS 1
 * (composite_store.h): the composite's own products made once per renderer instead of once
 * per frame and colour, each colour's rows contiguous,
 *
 * amp   float [height][n_channels][width]   sqrt(color * alpha) of pixel (y, x) at [y][c][x]
 * keep  float [height][width]               sqrt(1 - alpha)     of pixel (y, x) at [y][x]
 *
 * The same correctly rounded products as the row-major composites', so the same bits.
 * Reference: clholo.reference.layer_blocks(..., rows=1). Global size (width, height).
 */
__kernel void layer_planes(__global const float *color, __global const float *alpha,
                           __global float *amp, __global float *keep, const uint height,
                           const uint width, const uint n_channels)
{
    const uint x = get_global_id(0), y = get_global_id(1);
    if (x >= width || y >= height)
        return;
    const size_t p = (size_t)y * width + x;
    const float a = alpha[p];
    keep[p] = sqrt(1.0f - a);
    for (uint c = 0; c < n_channels; ++c)
        amp[((size_t)y * n_channels + c) * width + x] = sqrt(color[p * n_channels + c] * a);
}
