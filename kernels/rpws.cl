/* Random-phase wave splatting (RPWS): the wave-domain "over" of ONE screen-parallel 2-D
 * Gaussian onto the field arriving from behind it, for every frame and colour of a batch,
 * over the Gaussian's bounding box only (outside it alpha = 0 and the field is unchanged):
 *
 *   alpha = min(alpha_max, o exp(-1/2 (a dx^2 + c dy^2) - b dx dy)),  0 where < alpha_min
 *   u    <- sqrt(1 - alpha) u + sqrt(col alpha) exp(i phi)
 *
 * (dx, dy) = (mx - x, my - y), pixel (row y, column x) has its centre at (y, x); (a, b, c) is
 * the inverse 2-D covariance in px^-2 (the "conic" of clholo.io.splats.project).
 *
 * Phase stream (docs/rpws.md): the MPI stream of HOLOGRAPHY.md section 4 with the layer word
 * of the Philox counter set to the primitive's index k in the depth-sorted order (0 = nearest,
 * like MPI layer 0): counter (p / 4, k, frame, colour), p = y W + x over the WHOLE image, so
 * RPWS of K primitives at distinct depths draws exactly the phases of a K-layer MPI.
 *
 * u       float2 [B][npix], B = frames x colours (batch element f * colours + c)
 * params  float8 [K]: (mx, my, a, b, c, opacity, -, -)
 * colors  float  [K][colours]  linear colour of each primitive
 * Global size (box width, box height, B), box corner (x0, y0) given by the host.
 */
#include "random_phase.h"

__kernel void rpws_composite(__global float2 *u, __global const float8 *params,
                             __global const float *colors, const uint k, const int x0,
                             const int y0, const uint box_w, const uint box_h, const uint W,
                             const uint npix, const uint colours, const uint frame0,
                             const uint key_lo, const uint key_hi, const float alpha_max,
                             const float alpha_min)
{
    const uint i = get_global_id(0);
    const uint j = get_global_id(1);
    const uint b = get_global_id(2);
    if (i >= box_w || j >= box_h)
        return;
    const uint x = (uint)x0 + i;
    const uint y = (uint)y0 + j;
    const float8 g = params[k];
    const float dx = g.s0 - (float)x;
    const float dy = g.s1 - (float)y;
    const float power = -0.5f * (g.s2 * dx * dx + g.s4 * dy * dy) - g.s3 * dx * dy;
    const float alpha = fmin(alpha_max, g.s5 * exp(power));
    if (!(alpha >= alpha_min))
        return; /* alpha = 0: sqrt(1 - 0) u + 0 = u */
    const uint c = b % colours;
    const uint f = b / colours;
    const uint p = y * W + x;
    const float phi = clholo_phase(p, k, frame0 + f, c, key_lo, key_hi);
    const float amp = sqrt(colors[(size_t)k * colours + c] * alpha);
    float co;
    const float si = sincos(phi, &co);
    __global float2 *dst = u + (size_t)b * npix + p;
    *dst = sqrt(1.0f - alpha) * (*dst) + (float2)(amp * co, amp * si);
}
