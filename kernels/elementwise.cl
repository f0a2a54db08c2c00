/* Complex elementwise kernels. Built with -DREAL=float (complex64) or -DREAL=double
 * (complex128). Arrays are flat; a second operand of n_b elements broadcasts over the
 * leading (batch) axes of the first: element i uses b[i % n_b].
 */
#include "clholo_complex.h"

/* out = a * b  (complex), b broadcast over a's batch */
__kernel void complex_multiply(__global const REAL2 *a, __global const REAL2 *b,
                               __global REAL2 *out, const ulong n_b)
{
    const size_t i = get_global_id(0);
    out[i] = cmul(a[i], b[i % n_b]);
}

/* out = s * a  (complex scalar s) */
__kernel void complex_scale(__global const REAL2 *a, const REAL2 s, __global REAL2 *out)
{
    const size_t i = get_global_id(0);
    out[i] = cmul(a[i], s);
}

/* acc += weight * |u|^2, acc of n_acc elements broadcast back over u's batch:
 * work-item j sums u[j], u[j + n_acc], ... (n_batch terms) so no two work-items write
 * the same acc element and no atomics are needed. */
__kernel void accumulate_intensity(__global const REAL2 *u, __global REAL *acc,
                                   const REAL weight, const ulong n_acc, const uint n_batch)
{
    const size_t j = get_global_id(0);
    REAL s = 0;
    for (uint b = 0; b < n_batch; ++b)
        s += cabs2(u[j + b * n_acc]);
    acc[j] += weight * s;
}
