/* Ray-optics views of an MPI: warp every layer, then composite with "over"; average views.
 *
 * One work-item per output pixel (global size W, H) computes all NC channels. For each of V
 * views it walks the L layers back to front (layer 0 is the nearest), maps the output pixel
 * through the layer's 3x3 homography to a source position, samples the layer bilinearly (pixel
 * centres at integer coordinates; taps outside the layer are transparent: colour 0, alpha 0),
 * and composites  out = out * (1 - a) + c * a.  The result is the mean over the V views.
 * With one set of maps (n_maps = 1) the channels share the coordinates and the alpha taps;
 * with n_maps = NC each channel has its own maps (per-wavelength pupils).
 *
 * Defines:
 *   NC             number of colour channels (1..4)
 *   PREMULTIPLIED  interpolate c*a and a (the light and the absorber) rather than c and a.
 *
 * Layouts (float32, C-contiguous):
 *   color  [L, H, W, NC]     straight colour
 *   alpha  [L, H, W]
 *   homog  [n_maps, V, L, 9] row-major 3x3 maps from output (x, y, 1) to source (x, y, w)
 *   out    [H, W, NC]
 */

__kernel void warp_over_mean(__global const float *color, __global const float *alpha,
                             __global const float *homog, __global float *out,
                             const int L, const int H, const int W, const int V,
                             const int n_maps)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    if (x >= W || y >= H)
        return;
    const float fx = (float)x, fy = (float)y;
    const size_t plane = (size_t)H * W;
    float total[NC];
    for (int c = 0; c < NC; ++c)
        total[c] = 0.0f;
    for (int m = 0; m < n_maps; ++m) {
        /* shared maps drive every channel; per-channel maps drive channel m only */
        const int c_lo = (n_maps == 1) ? 0 : m;
        const int c_hi = (n_maps == 1) ? NC : m + 1;
        for (int v = 0; v < V; ++v) {
            float acc[NC];
            for (int c = 0; c < NC; ++c)
                acc[c] = 0.0f;
            __global const float *hv = homog + (size_t)(m * V + v) * L * 9;
            for (int l = L - 1; l >= 0; --l) {
                __global const float *h = hv + l * 9;
                const float w = h[6] * fx + h[7] * fy + h[8];
                const float sx = (h[0] * fx + h[1] * fy + h[2]) / w;
                const float sy = (h[3] * fx + h[4] * fy + h[5]) / w;
                const float x0f = floor(sx), y0f = floor(sy);
                /* far outside the layer (or w = 0): nothing to sample, and no int overflow */
                if (!(x0f >= -1.0f && x0f <= (float)(W - 1) && y0f >= -1.0f
                      && y0f <= (float)(H - 1)))
                    continue;
                const float tx = sx - x0f, ty = sy - y0f;
                const int x0 = (int)x0f, y0 = (int)y0f;
                __global const float *al = alpha + (size_t)l * plane;
                __global const float *co = color + (size_t)l * plane * NC;
                float a = 0.0f;
                float ca[NC];
                for (int c = 0; c < NC; ++c)
                    ca[c] = 0.0f;
                for (int j = 0; j < 4; ++j) {
                    const int xi = x0 + (j & 1), yi = y0 + (j >> 1);
                    if (xi < 0 || xi >= W || yi < 0 || yi >= H)
                        continue;
                    const float wt = ((j & 1) ? tx : 1.0f - tx) * ((j >> 1) ? ty : 1.0f - ty);
                    const size_t p = (size_t)yi * W + xi;
                    const float at = al[p];
#ifdef PREMULTIPLIED
                    const float wc = wt * at;
#else
                    const float wc = wt;
#endif
                    for (int c = c_lo; c < c_hi; ++c)
                        ca[c] += wc * co[p * NC + c];
                    a += wt * at;
                }
                for (int c = c_lo; c < c_hi; ++c) {
#ifdef PREMULTIPLIED
                    acc[c] = acc[c] * (1.0f - a) + ca[c];
#else
                    acc[c] = acc[c] * (1.0f - a) + ca[c] * a;  /* straight colour times alpha */
#endif
                }
            }
            for (int c = c_lo; c < c_hi; ++c)
                total[c] += acc[c];
        }
    }
    __global float *o = out + ((size_t)y * W + x) * NC;
    for (int c = 0; c < NC; ++c)
        o[c] = total[c] / (float)V;
}
