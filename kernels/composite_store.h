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

void clholo_store(__global real2 *ptr, real2 v, long b, int row, int col,
                  __global const float *color, __global const float *alpha, uint width,
                  uint n_channels, uint layer, uint frame0, uint key_lo, uint key_hi)
{
    const uint p = (uint)row * width + (uint)col;
    const uint c = (uint)b % n_channels, f = (uint)b / n_channels;
    const float a = alpha[p];
    const float amp = sqrt(color[(size_t)p * n_channels + c] * a);
    float co;
    const float si = sincos(clholo_phase(p, layer, frame0 + f, c, key_lo, key_hi), &co);
#ifdef CLHOLO_NO_OCCLUSION
    const float keep = 1.0f;
#else
    const float keep = sqrt(1.0f - a);
#endif
    *ptr = (real2)(amp * co, amp * si) + keep * v;
}
