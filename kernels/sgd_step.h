/* SGD's element-wise steps, shared by kernels/encode.cl (scaled_residual, phase_gradient_adam:
 * one launch each) and kernels/sgd_callbacks.h (the same steps as callbacks of the adjoint
 * propagation's first load and last store: host/phase_retrieval.py, fused=True), one pixel or a
 * vector of them at a time, so every form does the same arithmetic. Needs REAL
 * (clholo_complex.h). TY is REAL or a vector of it; the macros declare their outputs. */
#ifndef CLHOLO_SGD_STEP_H
#define CLHOLO_SGD_STEP_H

#include "clholo_complex.h"
#include "fast_sincos.h"

/* conj(s) mw (s y - t), the residual the adjoint propagates (mw = m w: the pixel's ROI weight
 * times 1 / sum w |t|^2 of the field), on real and imaginary parts: cmul(s, y) - t, then
 * cmul(cconj(s), r) written out */
#define SGD_RESIDUAL(TY, yr, yi, tr, ti, sx, sy, mw, out_r, out_i)                       \
    const TY out_r##_r = ((sx) * (yr) - (sy) * (yi)) - (tr);                             \
    const TY out_r##_i = ((sx) * (yi) + (sy) * (yr)) - (ti);                             \
    const TY out_r = (mw) * ((sx) * out_r##_r - (-(sy)) * out_r##_i);                    \
    const TY out_i = (mw) * ((sx) * out_r##_i + (-(sy)) * out_r##_r);

static inline REAL2 sgd_residual(REAL2 y, REAL2 t, REAL2 s, REAL mw)
{
    SGD_RESIDUAL(REAL, y.x, y.y, t.x, t.y, s.x, s.y, mw, re, im)
    return (REAL2)(re, im);
}

/* the phase gradient 2 Im(g conj(x)) of the propagated residual g at x = exp(i P) */
#define SGD_PHASE_GRADIENT(gr, gi, xr, xi) (2 * ((gi) * (xr) - (gr) * (xi)))

/* One Adam step on the phase p_old with gradient d (PyTorch's form):
 *     m <- b1 m + (1 - b1) d,  v <- b2 v + (1 - b2) d^2
 *     p <- p - lr (m / bc1) / (sqrt(v / bc2) + eps),   bc1 = 1 - b1^k, bc2 = 1 - b2^k
 * 1 - b1 and 1 - b2 come from the host (in double: float32(1 - 0.999) is 1.3e-5 off). */
#define ADAM_STEP(TY, d, m_old, v_old, p_old, m, v, p)                                   \
    const TY m = b1 * (m_old) + one_minus_b1 * (d);                                      \
    const TY v = b2 * (v_old) + one_minus_b2 * (d) * (d);                                \
    const TY p = (p_old) - lr * (m / bc1) / (sqrt(v / bc2) + eps);

/* The gradient, Adam and x = exp(i P) of pixel k, one pixel at a time (encode.cl's ragged end,
 * the fused store's one-pixel form). clholo_sincos4 gives the bits of the wider forms. */
static inline void sgd_adam_pixel(REAL2 g, size_t k, __global REAL2 *x, __global REAL *phase,
                                  __global REAL *adam_m, __global REAL *adam_v, __global REAL *grad,
                                  REAL lr, REAL b1, REAL b2, REAL one_minus_b1, REAL one_minus_b2,
                                  REAL eps, REAL bc1, REAL bc2)
{
    const REAL2 xv = x[k];
    const REAL d = SGD_PHASE_GRADIENT(g.x, g.y, xv.x, xv.y);
    grad[k] = d;
    ADAM_STEP(REAL, d, adam_m[k], adam_v[k], phase[k], m, v, p)
    adam_m[k] = m;
    adam_v[k] = v;
    phase[k] = p;
    REAL4 c;
    const REAL4 s = clholo_sincos4((REAL4)(p), &c);
    x[k] = (REAL2)(c.x, s.x);
}

/* (c0, s0, c1, s1, ...): four complex values from their real and imaginary parts */
#define CLHOLO_INTERLEAVE4(re, im) shuffle2((re), (im), (uint8)(0, 4, 1, 5, 2, 6, 3, 7))
/* (c0, s0, c1, s1, ...): eight complex values from their real and imaginary parts */
#define CLHOLO_INTERLEAVE8(re, im) shuffle2((re), (im), (uint16)(0, 8, 1, 9, 2, 10, 3, 11, 4, \
                                                                12, 5, 13, 6, 14, 7, 15))

#endif
