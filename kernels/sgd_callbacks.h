/* SGD's element-wise steps as callbacks of the adjoint propagation (clholo.fft.FFTCallback;
 * host/phase_retrieval.py, PhaseRetrieval(fused=True)): the scaled residual where the adjoint's
 * first pass loads the field, the phase gradient and the Adam step where its last pass stores
 * it. They replace encode.cl's scaled_residual and phase_gradient_adam launches and the field
 * they wrote and read back (issue 23: fewer passes over memory, fewer launches); the arithmetic
 * is sgd_step.h's, the same as theirs.
 *
 * Both see (b, row, col) as clholo.propagation.ASMPropagator gives it in either form: b the
 * field of the batch, (row, col) the pixel of the H x W field, so pixel k of the flattened
 * [B, H, W] arrays is (b H + row) W + col. float32 only (SGD runs in complex64). A program
 * takes one of them: SGD_RESIDUAL_LOAD or SGD_ADAM_STORE defined before the include. Each comes
 * one pixel at a time (GPUs), and eight (the CPU strips' rows, clholo_load8 / clholo_store8 in
 * float8 code: four at a time cost the fused iteration a third more than the separate
 * kernels on PoCL).
 */
#if FFT_DOUBLE
#error "sgd_callbacks.h is float32 only (PhaseRetrieval runs in complex64)"
#endif
#define REAL float
#include "sgd_step.h"

#ifdef SGD_RESIDUAL_LOAD
/* the load: conj(s_b) w_b m (s_b y - t) of the forward field y (encode.cl's scaled_residual).
 * t [B, H, W], mask [H, W] (read when has_mask), scale [B], weight [B] */
#define SGD_RESIDUAL_LOAD_PARAMS                                                             \
    __global const real2 *t, __global const real *mask, uint has_mask,                       \
    __global const real2 *scale, __global const real *weight, uint height, uint width

real2 clholo_load(real2 y, long b, int row, int col, SGD_RESIDUAL_LOAD_PARAMS)
{
    const size_t p = (size_t)row * width + (uint)col;
    const size_t k = (size_t)b * height * width + p;
    const real m = has_mask ? mask[p] : (real)1;
    return sgd_residual(y, t[k], scale[b], m * weight[b]);
}

#define FFT_LOAD_CB_OCT 1
void clholo_load8(float16 *v, long b, int row, int col, SGD_RESIDUAL_LOAD_PARAMS)
{
    const size_t p = (size_t)row * width + (uint)col;
    const size_t k = (size_t)b * height * width + p;
    const float8 m = has_mask ? vload8(0, mask + p) : (float8)(1);
    const float8 mw = m * weight[b];
    const float16 y = *v, tv = vload16(0, (__global const real *)(t + k));
    const real2 s = scale[b];
    SGD_RESIDUAL(float8, y.even, y.odd, tv.even, tv.odd, s.x, s.y, mw, re, im)
    *v = CLHOLO_INTERLEAVE8(re, im);
}
#endif

#ifdef SGD_ADAM_STORE
/* the store: grad = 2 Im(g conj(x)) of the propagated residual g, Adam on the phase, and
 * x = exp(i P) for the next forward pass (encode.cl's phase_gradient_adam; g itself is not
 * stored). x [B, H, W] complex, phase, adam_m, adam_v, grad [B, H, W] */
#define SGD_ADAM_STORE_PARAMS                                                                \
    __global real2 *x, __global real *phase, __global real *adam_m, __global real *adam_v,   \
    __global real *grad, real lr, real b1, real b2, real one_minus_b1, real one_minus_b2,    \
    real eps, real bc1, real bc2, uint height, uint width

void clholo_store(__global real2 *ptr, real2 g, long b, int row, int col, SGD_ADAM_STORE_PARAMS)
{
    sgd_adam_pixel(g, ((size_t)b * height + (uint)row) * width + (uint)col, x, phase, adam_m,
                   adam_v, grad, lr, b1, b2, one_minus_b1, one_minus_b2, eps, bc1, bc2);
}

#define FFT_STORE_CB_OCT 1
void clholo_store8(__global real2 *ptr, const float16 *g, long b, int row, int col,
                   SGD_ADAM_STORE_PARAMS)
{
    const size_t k = ((size_t)b * height + (uint)row) * width + (uint)col;
    __global real *xp = (__global real *)(x + k);
    const float16 gv = *g, xv = vload16(0, xp);
    const float8 d = SGD_PHASE_GRADIENT(gv.even, gv.odd, xv.even, xv.odd);
    vstore8(d, 0, grad + k);
    ADAM_STEP(float8, d, vload8(0, adam_m + k), vload8(0, adam_v + k), vload8(0, phase + k),
              m, v, p)
    vstore8(m, 0, adam_m + k);
    vstore8(v, 0, adam_v + k);
    vstore8(p, 0, phase + k);
    float8 c;
    const float8 s = clholo_sincos8(p, &c);
    vstore16(CLHOLO_INTERLEAVE8(c, s), 0, xp);
}
#endif
