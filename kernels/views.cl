/* Operators on holograms (HOLOGRAPHY.md section 5): the per-pixel work of the pupil view and of
 * the STFT light field. The FFTs are clholo.fft's; frame accumulation of the pupil view is
 * elementwise.cl's accumulate_intensity.
 *
 * TF_REAL is double on devices with fp64 (the mask edge is then decided exactly as the NumPy
 * reference decides it), else float.
 */
#include "clholo_complex.h"

#ifndef TF_REAL
#define TF_REAL float
#endif

/* out[c] = tf[c] * A_c(fx, fy): the refocus transfer function times the pupil, on the padded
 * grid in unshifted fftfreq order. Frequencies are in bins: kx = fftfreq index of column x
 * (x for x < Wp/2, x - Wp above), likewise ky. Per channel c, pupil[4c..4c+3] =
 * (centre kx, centre ky, half-size in x bins, half-size in y bins); disc: the ellipse
 * ((kx-cx)/rx)^2 + ((ky-cy)/ry)^2 <= 1 (a circle in frequency), square: |kx-cx| <= rx and
 * |ky-cy| <= ry.
 * Global size (Wp, Hp, C).
 */
__kernel void pupil_transfer_function(__global const float2 *tf, __global float2 *out,
                                      __global const TF_REAL *pupil, const uint Hp,
                                      const uint Wp, const int square)
{
    const uint x = get_global_id(0);
    const uint y = get_global_id(1);
    const uint c = get_global_id(2);
    const TF_REAL kx = (TF_REAL)((int)x - (x >= (Wp + 1u) / 2u ? (int)Wp : 0));
    const TF_REAL ky = (TF_REAL)((int)y - (y >= (Hp + 1u) / 2u ? (int)Hp : 0));
    const TF_REAL ux = (kx - pupil[4 * c]) / pupil[4 * c + 2];
    const TF_REAL uy = (ky - pupil[4 * c + 1]) / pupil[4 * c + 3];
    int inside;
    if (square)
        inside = fabs(ux) <= (TF_REAL)1 && fabs(uy) <= (TF_REAL)1;
    else
        inside = ux * ux + uy * uy <= (TF_REAL)1;
    const size_t i = ((size_t)c * Hp + y) * Wp + x;
    out[i] = inside ? tf[i] : (float2)(0.0f, 0.0f);
}

/* Windows of the STFT: out[b][n][i][j] = u[b][y0 + i][x0 + j] * t(i) t(j) with window
 * n = wy * Nx + wx at (y0, x0) = (wy * hop, wx * hop), t = 1 (rect) or the periodic Hann
 * 0.5 - 0.5 cos(2 pi i / w).
 * u starts u_offset elements into u_base (a chunk of frames of a larger array).
 * Global size (w * w, Ny * Nx, B).
 */
__kernel void stft_windows(__global const float2 *u_base, const ulong u_offset,
                           __global float2 *out, const uint H,
                           const uint W, const uint Nx, const uint w, const uint hop,
                           const int hann)
{
    const uint ij = get_global_id(0);
    const uint n = get_global_id(1);
    const uint b = get_global_id(2);
    const uint i = ij / w;
    const uint j = ij - i * w;
    const uint wy = n / Nx;
    const uint wx = n - wy * Nx;
    const uint y = wy * hop + i;
    const uint x = wx * hop + j;
    float t = 1.0f;
    if (hann) {
        const float k = 6.28318530717958647692f / (float)w;
        t = (0.5f - 0.5f * cos(k * (float)i)) * (0.5f - 0.5f * cos(k * (float)j));
    }
    __global const float2 *u = u_base + u_offset;
    const float2 v = u[((size_t)b * H + y) * W + x];
    out[((size_t)b * get_global_size(1) + n) * (size_t)(w * w) + ij] = t * v;
}

/* acc[m][ky'][kx'] += weight * sum_t |spec[t][m][(ky' + h) % w][(kx' + h) % w]|^2, h = (w+1)/2:
 * frame sum of the windows' power spectra, fftshifted as np.fft.fftshift does (bin w/2, rounded
 * down, is angle zero; for odd w the shift is (w+1)/2, not w/2). m runs over per_frame / (w w)
 * (colours x windows); w is any FFT size (2^a 3^b 5^c). Global size (w * w, per_frame / (w w)).
 */
__kernel void stft_accumulate(__global const float2 *spec, __global float *acc,
                              const float weight, const uint w, const uint n_frames)
{
    const uint ij = get_global_id(0);
    const uint m = get_global_id(1);
    const uint i = ij / w;
    const uint j = ij - i * w;
    const uint h = (w + 1u) / 2u;
    const uint si = (i + h < w) ? i + h : i + h - w;
    const uint sj = (j + h < w) ? j + h : j + h - w;
    const uint src = si * w + sj;
    const size_t per_frame = (size_t)get_global_size(1) * w * w;
    __global const float2 *p = spec + (size_t)m * w * w + src;
    float s = 0.0f;
    for (uint t = 0; t < n_frames; ++t)
        s += cabs2(p[t * per_frame]);
    acc[(size_t)m * w * w + ij] += weight * s;
}
