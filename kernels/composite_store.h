/* The next layer's wave-domain "over" fused into the store of the inverse transform that
 * finishes the previous propagation (clholo.fft.FFTCallback store callback; the host scheduler
 * builds it with host/scheduler.py's COMPOSITE_STORE):
 *
 *   *ptr = sqrt(1 - a) v + sqrt(c a) exp(i phi)      (transmission 1 with CLHOLO_NO_OCCLUSION)
 *
 * where v is the propagated field at pixel p = row W + col of batch field b = f C + c (frame
 * frame0 + f, colour c), a and c the layer's alpha and colour at p, and phi is pixel p's phase
 * of the Philox stream (random_phase.h) for this layer, frame and colour: the same values as
 * composite.cl's composite_layer, so frames match the unfused loop (up to contraction of
 * a * b + c into an fma).
 *
 * color  float [npix][n_channels]   alpha  float [npix]
 */
#include "random_phase.h"
#include "fast_sincos.h"

void clholo_store(__global real2 *ptr, real2 v, long b, int row, int col,
                  __global const float *color, __global const float *alpha, uint width,
                  uint n_channels, uint layer, uint frame0, uint key_lo, uint key_hi)
{
    const uint p = (uint)row * width + (uint)col;
    const uint c = (uint)b % n_channels, f = (uint)b / n_channels;
    const float a = alpha[p];
    const float amp = sqrt(color[(size_t)p * n_channels + c] * a);
    float4 co4;
    const float4 si4 = clholo_sincos4((float4)(clholo_phase(p, layer, frame0 + f, c, key_lo,
                                                            key_hi)), &co4);
    const float co = co4.x, si = si4.x;   /* the same values as composite.cl's */
#ifdef CLHOLO_NO_OCCLUSION
    const float keep = 1.0f;
#else
    const float keep = sqrt(1.0f - a);
#endif
    *ptr = (real2)(amp * co, amp * si) + keep * v;
}

/* Four adjacent pixels p .. p + 3 of one row (p = row W + col, col a multiple of 4): when p is
 * a multiple of 4 they are one Philox block, drawn once, and the body is float4 code like
 * composite.cl's; otherwise (W not a multiple of 4) pixel by pixel. */
#define FFT_STORE_CB_QUAD 1
void clholo_store4(__global real2 *ptr, real2 v0, real2 v1, real2 v2, real2 v3, long b,
                   int row, int col, __global const float *color,
                   __global const float *alpha, uint width, uint n_channels, uint layer,
                   uint frame0, uint key_lo, uint key_hi)
{
    const uint p = (uint)row * width + (uint)col;
    if (p & 3u) {
        clholo_store(ptr, v0, b, row, col, color, alpha, width, n_channels, layer, frame0,
                     key_lo, key_hi);
        clholo_store(ptr + 1, v1, b, row, col + 1, color, alpha, width, n_channels, layer,
                     frame0, key_lo, key_hi);
        clholo_store(ptr + 2, v2, b, row, col + 2, color, alpha, width, n_channels, layer,
                     frame0, key_lo, key_hi);
        clholo_store(ptr + 3, v3, b, row, col + 3, color, alpha, width, n_channels, layer,
                     frame0, key_lo, key_hi);
        return;
    }
    const uint c = (uint)b % n_channels, f = (uint)b / n_channels;
    const float4 a = vload4(0, alpha + p);
    float4 col4;
    if (n_channels == 1u) {
        col4 = vload4(0, color + p);
    } else {
        __global const float *src = color + (size_t)p * n_channels + c;
        col4 = (float4)(src[0], src[n_channels], src[2 * n_channels], src[3 * n_channels]);
    }
    const float4 amp = sqrt(col4 * a);
    float4 co;
    const float4 si = clholo_sincos4(clholo_phase_block(p >> 2, layer, frame0 + f, c, key_lo,
                                                        key_hi), &co);
#ifdef CLHOLO_NO_OCCLUSION
    const float4 keep = (float4)(1.0f);
#else
    const float4 keep = sqrt(1.0f - a);
#endif
    const float4 re = amp * co + keep * (float4)(v0.x, v1.x, v2.x, v3.x);
    const float4 im = amp * si + keep * (float4)(v0.y, v1.y, v2.y, v3.y);
    vstore8(shuffle2(re, im, (uint8)(0, 4, 1, 5, 2, 6, 3, 7)), 0, (__global float *)ptr);
}
