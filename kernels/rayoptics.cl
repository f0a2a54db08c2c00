/* Ray-optics views of an MPI: warp every layer, then composite with "over"; average views.
 *
 * One work-item per output pixel and channel (global size W, H, C). For each of V views it
 * walks the L layers back to front (layer 0 is the nearest), maps the output pixel through the
 * layer's 3x3 homography to a source position, samples the layer bilinearly (pixel centres at
 * integer coordinates; taps outside the layer are transparent: colour 0, alpha 0), and
 * composites  out = out * (1 - a) + c * a.  The result is the mean over the V views.
 *
 * Defines:
 *   PREMULTIPLIED  interpolate c*a and a (the light and the absorber) rather than c and a.
 *
 * Layouts (float32, C-contiguous):
 *   color  [L, H, W, C]   straight colour
 *   alpha  [L, H, W]
 *   homog  [C, V, L, 9]   row-major 3x3 maps from output (x, y, 1) to source (x, y, w)
 *   out    [H, W, C]
 */

__kernel void warp_over_mean(__global const float *color, __global const float *alpha,
                             __global const float *homog, __global float *out,
                             const int L, const int H, const int W, const int C, const int V)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int c = get_global_id(2);
    if (x >= W || y >= H || c >= C)
        return;
    const float fx = (float)x, fy = (float)y;
    const size_t plane = (size_t)H * W;
    float total = 0.0f;
    for (int v = 0; v < V; ++v) {
        float acc = 0.0f;
        for (int l = L - 1; l >= 0; --l) {
            __global const float *h = homog + ((size_t)(c * V + v) * L + l) * 9;
            const float w = h[6] * fx + h[7] * fy + h[8];
            const float sx = (h[0] * fx + h[1] * fy + h[2]) / w;
            const float sy = (h[3] * fx + h[4] * fy + h[5]) / w;
            const float x0f = floor(sx), y0f = floor(sy);
            const float tx = sx - x0f, ty = sy - y0f;
            /* source positions far outside the layer: nothing to sample (and no int overflow) */
            if (!(x0f >= -1.0f && x0f <= (float)W - 1.0f && y0f >= -1.0f && y0f <= (float)H - 1.0f))
                continue;
            const int x0 = (int)x0f, y0 = (int)y0f;
            __global const float *al = alpha + (size_t)l * plane;
            __global const float *co = color + (size_t)l * plane * C + c;
            float a = 0.0f, ca = 0.0f;
            for (int j = 0; j < 4; ++j) {
                const int xi = x0 + (j & 1), yi = y0 + (j >> 1);
                if (xi < 0 || xi >= W || yi < 0 || yi >= H)
                    continue;
                const float wt = ((j & 1) ? tx : 1.0f - tx) * ((j >> 1) ? ty : 1.0f - ty);
                const size_t p = (size_t)yi * W + xi;
                const float at = al[p];
#ifdef PREMULTIPLIED
                ca += wt * co[p * C] * at;
#else
                ca += wt * co[p * C];
#endif
                a += wt * at;
            }
#ifndef PREMULTIPLIED
            ca *= a;  /* straight: interpolated colour times interpolated alpha */
#endif
            acc = acc * (1.0f - a) + ca;
        }
        total += acc;
    }
    out[((size_t)y * W + x) * C + c] = total / (float)V;
}
