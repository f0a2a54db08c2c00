/* composite_layer (composite.cl) for CPUs: the same "over" of one MPI layer onto the field, by
 * blocks of 8 rows x 8 columns through the CPU row round trip's own composite
 * (composite_store.h's clholo_mid_rows8: sixteen Philox blocks and float16 sin/cos at once).
 *
 * Why: composite_layer's four pixels per work-item take about 6-7 ns a sample on PoCL (float4
 * sin/cos, one Philox block per work-item); these blocks 2.5-3 ns, a pass over the field
 * included (the composite fused in the row round trip, in fast memory, about 1.7). The
 * farthest layer of a two-kernel render took 130 ms of a 5.6 s render at 1080x1920 RGB, T=3,
 * L=32 before this kernel (docs/benchmarks.md).
 *
 * u      float2 [frames][n_channels][height][width]   (in/out; not read when farthest)
 * color  float  [height * width][n_channels]          this layer, straight linear colour
 * alpha  float  [height * width]
 * Global size (ceil(width / 8), ceil(height / 8), frames * n_channels): field b is frame
 * frame0 + b / n_channels of the stream, channel b % n_channels (every channel in the batch).
 * Blocks cut by the field's edge go pixel by pixel (composite_value, the same values).
 */
typedef float2 real2;
#include "composite_store.h"
#include "transpose8.h"

__kernel void composite_layer_rows8(__global float2 *u, __global const float *color,
                                    __global const float *alpha, const uint height,
                                    const uint width, const uint n_channels, const uint layer,
                                    const uint frame0, const uint key_lo, const uint key_hi,
                                    const int farthest)
{
    const int col = get_global_id(0) * 8, row0 = get_global_id(1) * 8;
    const long b = get_global_id(2);
    __global float2 *field = u + (size_t)b * height * width;
    if (col + 8 <= (int)width && row0 + 8 <= (int)height) {
        /* lane l of re[j] / im[j]: pixel (row0 + l, col + j) */
        float8 re[8], im[8];
        float16 v[8];
        if (farthest) {
            for (int j = 0; j < 8; ++j)
                re[j] = im[j] = (float8)(0.0f);
        } else {
            for (int l = 0; l < 8; ++l)
                v[l] = vload16(0, (__global const float *)(field + (size_t)(row0 + l) * width
                                                           + col));
            CLHOLO_TRANSPOSE8(float16, v);   /* v[j]: column col + j of the eight rows */
            for (int j = 0; j < 8; ++j) {
                re[j] = v[j].even;
                im[j] = v[j].odd;
            }
        }
        clholo_mid_rows8(re, im, b, row0, col, color, alpha, width, n_channels, layer, frame0,
                         key_lo, key_hi);
        for (int j = 0; j < 8; ++j)
            v[j] = shuffle2(re[j], im[j], (uint16)(0, 8, 1, 9, 2, 10, 3, 11, 4, 12, 5, 13, 6, 14,
                                                   7, 15));
        CLHOLO_TRANSPOSE8(float16, v);
        for (int l = 0; l < 8; ++l)
            vstore16(v[l], 0, (__global float *)(field + (size_t)(row0 + l) * width + col));
        return;
    }
    for (int row = row0; row < min(row0 + 8, (int)height); ++row)
        for (int c = col; c < min(col + 8, (int)width); ++c) {
            __global float2 *p = field + (size_t)row * width + c;
            *p = composite_value(farthest ? (float2)(0.0f) : *p, b, row, c, color, alpha, width,
                                 n_channels, layer, frame0, key_lo, key_hi);
        }
}

/* A layer as the CPU composites read it with CLHOLO_LAYER_BLOCKS (composite_store.h): eight
 * rows to a block, rows in the lanes, the composite's own products made once per renderer
 * instead of once per frame and colour:
 *
 * amp   float [S][n_channels][width][8]   sqrt(color * alpha) of pixel (8 s + l, x) at [s][c][x][l]
 * keep  float [S][width][8]               sqrt(1 - alpha)     of pixel (8 s + l, x) at [s][x][l]
 *
 * S = ceil(height / 8); rows past the last are transparent (amp 0, keep 1). The same
 * correctly rounded products as the row-major composites', so the same bits. Reference:
 * clholo.reference.layer_blocks. Global size (width, S).
 */
__kernel void layer_blocks(__global const float *color, __global const float *alpha,
                           __global float *amp, __global float *keep, const uint height,
                           const uint width, const uint n_channels)
{
    const uint x = get_global_id(0), s = get_global_id(1);
    if (x >= width)
        return;
    const uint rows = min(8u, height - 8u * s);
    float lanes[8] = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    for (uint l = 0; l < rows; ++l)
        lanes[l] = alpha[(size_t)(8u * s + l) * width + x];
    const float8 a = vload8(0, lanes);
    vstore8(sqrt(1.0f - a), 0, keep + ((size_t)s * width + x) * 8);
    for (uint c = 0; c < n_channels; ++c) {
        for (uint l = 0; l < rows; ++l)
            lanes[l] = color[((size_t)(8u * s + l) * width + x) * n_channels + c];
        vstore8(sqrt(vload8(0, lanes) * a), 0,
                amp + (((size_t)s * n_channels + c) * width + x) * 8);
    }
}
