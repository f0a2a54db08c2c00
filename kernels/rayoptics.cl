/* Ray-optics views of an MPI: warp every layer, then composite with "over"; average views.
 *
 * Each work-item handles one output pixel and KC channels (global size W, H, NC / KC). For each
 * of V views it walks the L layers front to back (layer 0 is the nearest), maps the output pixel
 * through the layer's 3x3 homography to a source position, samples the layer bilinearly (pixel
 * centres at integer coordinates; taps outside the layer are transparent: colour 0, alpha 0),
 * and composites with "over": out += T * c * a, T *= 1 - a (T the transmission of the layers
 * in front), which is  out = out * (1 - a) + c * a  back to front; it stops where T reaches
 * exactly 0 (behind an opaque layer nothing shows, so the result is unchanged).
 * The result is the mean over the V views.
 *
 * Defines:
 *   NC                number of colour channels
 *   PER_CHANNEL_MAPS  each channel has its own maps (per-wavelength pupils): one work-item per
 *                     pixel and channel (KC = 1). Otherwise one set of maps drives every channel
 *                     and a work-item does all NC channels, sharing coordinates and alpha taps.
 *   PREMULTIPLIED     interpolate c*a and a (the light and the absorber) rather than c and a.
 * Loop bounds are compile-time constants so that the per-channel arrays stay in registers.
 *
 * Layouts (float32, C-contiguous):
 *   color  [L, H, W, NC]     straight colour
 *   alpha  [L, H, W]
 *   homog  [n_maps, V, L, 9] row-major 3x3 maps from output (x, y, 1) to source (x, y, w);
 *                            n_maps = NC with PER_CHANNEL_MAPS, else 1
 *   out    [H, W, NC]
 */

#ifdef PER_CHANNEL_MAPS
#define KC 1
#else
#define KC NC
#endif

__kernel void warp_over_mean(__global const float *color, __global const float *alpha,
                             __global const float *homog, __global float *out,
                             const int L, const int H, const int W, const int V)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    if (x >= W || y >= H)
        return;
#ifdef PER_CHANNEL_MAPS
    const int c0 = get_global_id(2);  /* this work-item's channel, and its maps */
    __global const float *hm = homog + (size_t)c0 * V * L * 9;
#else
    const int c0 = 0;
    __global const float *hm = homog;
#endif
    const float fx = (float)x, fy = (float)y;
    const size_t plane = (size_t)H * W;
    float total[KC];
    for (int k = 0; k < KC; ++k)
        total[k] = 0.0f;
    for (int v = 0; v < V; ++v) {
        float acc[KC];
        for (int k = 0; k < KC; ++k)
            acc[k] = 0.0f;
        float trans = 1.0f;  /* light that gets through the layers in front of l */
        __global const float *hv = hm + (size_t)v * L * 9;
        for (int l = 0; l < L && trans > 0.0f; ++l) {
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
            __global const float *co = color + (size_t)l * plane * NC + c0;
            float a = 0.0f;
            float ca[KC];
            for (int k = 0; k < KC; ++k)
                ca[k] = 0.0f;
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
                for (int k = 0; k < KC; ++k)
                    ca[k] += wc * co[p * NC + k];
                a += wt * at;
            }
            for (int k = 0; k < KC; ++k) {
#ifdef PREMULTIPLIED
                acc[k] += trans * ca[k];
#else
                acc[k] += trans * (ca[k] * a);  /* straight colour times alpha */
#endif
            }
            trans *= 1.0f - a;
        }
        for (int k = 0; k < KC; ++k)
            total[k] += acc[k];
    }
    __global float *o = out + ((size_t)y * W + x) * NC + c0;
    for (int k = 0; k < KC; ++k)
        o[k] = total[k] / (float)V;
}
