/* Angular spectrum transfer functions on the padded grid, unshifted (fftfreq) order.
 *
 *   H = exp(i (carrier + rest)) inside the band, 0 outside (evanescent or band-limited)
 *   carrier = 2 pi dz / lambda mod 2 pi           (host, double)
 *   rest    = -2 pi dz f^2 / (1/lambda + sqrt(1/lambda^2 - f^2))
 *
 * The phase itself reaches 1e5-1e6 rad at centimetres, where float32 has no digits left for
 * it; the rest stays small enough (about 1e3 rad at 20 cm) and is computed in TF_REAL, double
 * where the device has fp64 (the host asks for it), else float. REAL is the output precision.
 * One work-item per frequency; the y index of the global range runs over colours * Hp rows so
 * all colours of a step come from one launch. consts is [4][C]: 1/lambda, the carrier,
 * and the band limits in y and x (infinity when the band limit is off).
 */
#include "clholo_complex.h"

#ifndef TF_REAL
#define TF_REAL float
#endif

/* H depends on |fx| and |fy| only, so the quarter 0 <= x <= Wp/2, 0 <= y <= Hp/2 is computed
 * and each value written to its up to four mirror images: a quarter of the square roots,
 * divisions and sines. Each work-item takes four consecutive x with explicit vector types and
 * no branches in the arithmetic: PoCL does not vectorize the scalar form of this kernel, and the
 * vector form is several times faster there. Global size (ceil((Wp/2 + 1) / 4), C * (Hp/2 + 1)).
 */
#define TF_REAL4 CONCAT(TF_REAL, 4)
#define TF_INT4 CONCAT(TF_INTV_, TF_REAL)
#define TF_INTV_float int4
#define TF_INTV_double long4

__kernel void asm_transfer_function(
    __global REAL2 *H, const uint Hp, const uint Wp,
    const TF_REAL df_y, const TF_REAL df_x,           /* 1/(Hp p), 1/(Wp p) */
    __global const TF_REAL *consts, const uint C, const TF_REAL two_pi_dz)
{
    const uint x0 = 4u * get_global_id(0);
    const uint rows = Hp / 2u + 1u;
    const uint c = get_global_id(1) / rows;
    const uint y = get_global_id(1) - c * rows;
    const uint half_w = Wp / 2u;
    if (x0 > half_w)
        return;
    /* |fx| of x0..x0+3: the quarter holds non-negative frequency indices 0..Wp/2 */
    const TF_REAL4 kx = (TF_REAL4)((TF_REAL)x0, (TF_REAL)(x0 + 1u), (TF_REAL)(x0 + 2u),
                                   (TF_REAL)(x0 + 3u));
    const TF_REAL fy = (TF_REAL)y * df_y;
    const TF_REAL4 fx = kx * df_x;
    const TF_REAL il = consts[c];
    const TF_REAL il2 = il * il;
    const TF_REAL4 f2 = fx * fx + fy * fy;
    const TF_INT4 inside = (f2 < il2) & (fx < consts[3 * C + c]) &
                           (TF_INT4)(fy < consts[2 * C + c] ? -1 : 0);
    const TF_REAL4 root = sqrt(fmax(il2 - f2, (TF_REAL)0));
    TF_REAL4 phase = consts[C + c] - two_pi_dz * f2 / (il + root);
    /* reduce to [-pi, pi] in TF_REAL; the sine itself then needs no more than REAL */
    phase = phase - rint(phase * (TF_REAL)0.15915494309189533577) * (TF_REAL)6.28318530717958647693;
    const REAL4 ph = CONCAT(convert_, REAL4)(phase);
    REAL4 co;
    const REAL4 si = sincos(ph, &co);
    const REAL4 zero = (REAL4)(0);
    const REAL4 re = select(zero, co, CONCAT(convert_, CONCAT(REAL_INTV_, REAL))(inside));
    const REAL4 im = select(zero, si, CONCAT(convert_, CONCAT(REAL_INTV_, REAL))(inside));
    const REAL re_[4] = {re.s0, re.s1, re.s2, re.s3};
    const REAL im_[4] = {im.s0, im.s1, im.s2, im.s3};
    __global REAL2 *plane = H + (size_t)c * Hp * Wp;
    const uint ym = (y == 0u) ? y : Hp - y;  /* mirror row (may equal y) */
    for (uint k = 0; k < 4u && x0 + k <= half_w; ++k) {
        const uint x = x0 + k;
        const uint xm = (x == 0u) ? x : Wp - x;
        const REAL2 h = (REAL2)(re_[k], im_[k]);
        plane[(size_t)y * Wp + x] = h;
        plane[(size_t)y * Wp + xm] = h;
        plane[(size_t)ym * Wp + x] = h;
        plane[(size_t)ym * Wp + xm] = h;
    }
}
