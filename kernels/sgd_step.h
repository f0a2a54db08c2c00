/* SGD's element-wise steps, shared by kernels/encode.cl (scaled_residual, phase_gradient_adam:
 * one launch each) and kernels/sgd_callbacks.h (the same steps as callbacks of the adjoint
 * propagation's first load and last store: host/phase_retrieval.py, fused=True), so both forms
 * do the same arithmetic. Needs REAL (clholo_complex.h). */
#ifndef CLHOLO_SGD_STEP_H
#define CLHOLO_SGD_STEP_H

#include "clholo_complex.h"

/* conj(s) w m (s y - t): the residual the adjoint propagates (w = 1 / sum w |t|^2 of the field,
 * m the pixel's ROI weight) */
inline REAL2 sgd_residual(REAL2 y, REAL2 t, REAL2 s, REAL mw)
{
    const REAL2 r = cmul(s, y) - t;
    return mw * cmul(cconj(s), r);
}

/* One Adam step on the phase p_old with gradient d (PyTorch's form):
 *     m <- b1 m + (1 - b1) d,  v <- b2 v + (1 - b2) d^2
 *     p <- p - lr (m / bc1) / (sqrt(v / bc2) + eps),   bc1 = 1 - b1^k, bc2 = 1 - b2^k
 * 1 - b1 and 1 - b2 come from the host (in double: float32(1 - 0.999) is 1.3e-5 off). TY is
 * REAL or a vector of it; declares m, v, p. */
#define ADAM_STEP(TY, d, m_old, v_old, p_old, m, v, p)                                   \
    const TY m = b1 * (m_old) + one_minus_b1 * (d);                                      \
    const TY v = b2 * (v_old) + one_minus_b2 * (d) * (d);                                \
    const TY p = (p_old) - lr * (m / bc1) / (sqrt(v / bc2) + eps);

#endif
