/* 8-bit upload of phase patterns on the device (HOLOGRAPHY.md section 8), bit for bit the host's
 * clholo.encode.quantize.PhaseLUT.to_gray. Reference: clholo.reference.quantize.
 *
 * The host quantises in float64 (wrap, then the nearest usable level on the circle); float32
 * arithmetic here would differ from it at near-ties. So the level comes from comparisons only:
 * for colour c the host tabulates its own function g_c(p) = to_gray(p) over the float32 inputs
 * p in [lo_c, hi_c] (clholo.reference.step_table):
 *
 *     bp[off_c .. off_c + n_c)     the float32 values where g_c changes, ascending
 *     lv[loff_c .. loff_c + n_c]   lv[loff_c] = g_c(lo_c), lv[loff_c + k + 1] = g_c(bp[off_c + k])
 *
 * and the kernel takes gray = lv[loff_c + a], a = #{k : bp[off_c + k] <= p}.
 *
 * Finding a: a bucket table gives a first guess, guess[goff_c + j] = #{k : bp[off_c + k] <=
 * lo_c + j (hi_c - lo_c) / nb_c} for bucket j = (int)((p - lo_c) * scale_c) (clamped to
 * 0 .. nb_c - 1; about four buckets per breakpoint, so the guess is mostly right or one off).
 * That float arithmetic only picks where to start: the two scans after it move a up while
 * bp[a] <= p and down while bp[a - 1] > p, which ends at the count whatever the guess (bp is
 * ascending), so the result is exact even where the bucket is wrong.
 *
 * Layouts: phase float [B][n], gray uchar [B][n] (n = H*W pixels per field; field b is colour
 * b % n_channels); table uint [n_channels][5] = (off_c, n_c, loff_c, goff_c, nb_c); range float
 * [n_channels][3] = (lo_c, hi_c, scale_c). A phase outside [lo_c, hi_c] (NaN and +-inf included)
 * gets gray 0 and ORs its reason into flags[c] (QUANTIZE_NAN, _INF, _BELOW, _ABOVE: the values
 * of clholo.reference.quantize); the host reads the flags and raises, so such a pattern is never
 * shown. Global size (n, B).
 */

#define QUANTIZE_NAN 1u
#define QUANTIZE_INF 2u
#define QUANTIZE_BELOW 4u
#define QUANTIZE_ABOVE 8u

__kernel void quantize_phase(__global const float *phase, __global uchar *gray,
                             __global const float *bp, __global const uchar *lv,
                             __global const uint *guess, __global const uint *table,
                             __global const float *range, const uint n_channels,
                             __global uint *flags)
{
    const size_t i = get_global_id(0);
    const size_t b = get_global_id(1);
    const size_t k = b * get_global_size(0) + i;
    const uint c = (uint)(b % n_channels);
    const float p = phase[k];
    const float lo = range[3 * c], hi = range[3 * c + 1], scale = range[3 * c + 2];
    if (!(p >= lo && p <= hi)) {
        const uint why = isnan(p) ? QUANTIZE_NAN : isinf(p) ? QUANTIZE_INF
                         : p < lo ? QUANTIZE_BELOW : QUANTIZE_ABOVE;
        atomic_or(flags + c, why);
        gray[k] = 0;
        return;
    }
    __global const uint *tc = table + 5 * c;
    const uint n = tc[1], nb = tc[4];
    __global const float *t = bp + tc[0];
    const int j = clamp((int)((p - lo) * scale), 0, (int)nb - 1);
    uint a = guess[tc[3] + j];
    while (a < n && t[a] <= p)
        ++a;
    while (a > 0 && t[a - 1] > p)
        --a;
    gray[k] = lv[tc[2] + a];
}
