/* Rasterise depth-sorted screen-space Gaussians into D depth slabs (clholo.io.splats).
 *
 * One work-group per TILE x TILE tile of pixels, one work-item per pixel. The host has already
 * projected the splats (EWA, 0.3 px dilation), sorted them by depth and listed, per tile, the
 * splats whose 3-sigma square overlaps the tile, in depth order. The group loads the list in
 * batches of TILE*TILE splats into local memory (one load per work-item) and every pixel walks
 * the batch front to back, exactly like the 3D Gaussian Splatting rasteriser, except that the
 * blending state is flushed to a slab whenever the splat's slab index changes:
 *
 *   alpha_d = 1 - prod_k (1 - alpha_k),   c_d = sum_k alpha_k c_k prod_{j<k} (1 - alpha_j) / alpha_d
 *
 * (products within the slab). The 3DGS rules are kept bit for bit in spirit: alpha is clamped to
 * 0.99, contributions below 1/255 are skipped, and a pixel stops when the transmittance through
 * everything in front would fall below t_min. With those rules the "over" of the slabs equals
 * ordinary 3DGS blending of the same splats.
 *
 * Outputs must be zero-filled by the host: only slabs that receive a splat are written.
 */

#ifndef TILE
#define TILE 16
#endif
#define BATCH (TILE * TILE)

__kernel __attribute__((reqd_work_group_size(TILE, TILE, 1)))
void splat_raster(__global const float2 *xy,        /* N: mean, pixel coordinates (x, y) */
                  __global const float4 *conic_o,   /* N: inverse 2-D covariance a, b, c; opacity */
                  __global const float4 *rgb,       /* N: colour r, g, b; log(1/(255 opacity)) */
                  __global const int *slab,         /* N: slab index, nondecreasing in depth order */
                  __global const uint *list,        /* per-tile splat indices, depth order */
                  __global const int2 *ranges,      /* per tile: [start, end) into list */
                  const int width, const int height, const float t_min,
                  __global float *out_alpha,        /* D x H x W */
                  __global float *out_color)        /* D x H x W x 3 */
{
    const int tiles_x = get_num_groups(0);
    const int lx = get_local_id(0), ly = get_local_id(1);
    const int tid = ly * TILE + lx;
    const int px = get_group_id(0) * TILE + lx;
    const int py = get_group_id(1) * TILE + ly;
    const bool inside = px < width && py < height;
    const int2 range = ranges[get_group_id(1) * tiles_x + get_group_id(0)];
    const size_t npix = (size_t)width * (size_t)height;
    const size_t pix = (size_t)py * (size_t)width + (size_t)px;

    __local float2 s_xy[BATCH];
    __local float4 s_co[BATCH];
    __local float4 s_rgb[BATCH];
    __local int s_slab[BATCH];

    bool done = !inside;
    float T = 1.0f;    /* transmittance through every splat so far */
    float Ts = 1.0f;   /* transmittance within the current slab */
    float3 C = (float3)(0.0f);
    int cur = -1;
    const float2 pf = (float2)((float)px, (float)py);

    for (int start = range.x; start < range.y; start += BATCH) {
        /* every work-item reaches both barriers, finished or not */
        barrier(CLK_LOCAL_MEM_FENCE);
        const int k = start + tid;
        if (k < range.y) {
            const uint g = list[k];
            s_xy[tid] = xy[g];
            s_co[tid] = conic_o[g];
            s_rgb[tid] = rgb[g];
            s_slab[tid] = slab[g];
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        const int n = min(BATCH, range.y - start);
        for (int j = 0; j < n && !done; j++) {
            const float2 d = s_xy[j] - pf;
            const float4 co = s_co[j];
            const float power = -0.5f * (co.x * d.x * d.x + co.z * d.y * d.y) - co.y * d.x * d.y;
            /* rgb.w = log(1 / (255 opacity)): below it alpha < 1/255 anyway, so most pixels of
             * a tile, outside the splat's footprint, skip the exp */
            if (power > 0.0f || power < s_rgb[j].w)
                continue;
            const float alpha = fmin(0.99f, co.w * exp(power));
            if (alpha < 1.0f / 255.0f)
                continue;
            const float test_T = T * (1.0f - alpha);
            if (test_T < t_min) {
                done = true;
                break;
            }
            const int s = s_slab[j];
            if (s != cur) {
                if (cur >= 0) {
                    const float a = 1.0f - Ts;
                    out_alpha[cur * npix + pix] = a;
                    vstore3(C / a, cur * npix + pix, out_color);
                }
                cur = s;
                Ts = 1.0f;
                C = (float3)(0.0f);
            }
            C += s_rgb[j].xyz * (alpha * Ts);
            Ts *= 1.0f - alpha;
            T = test_T;
        }
    }
    if (inside && cur >= 0) {
        const float a = 1.0f - Ts;
        out_alpha[cur * npix + pix] = a;
        vstore3(C / a, cur * npix + pix, out_color);
    }
}
