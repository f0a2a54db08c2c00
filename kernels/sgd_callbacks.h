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
#include "transpose8.h"
#include "cpu_wide.h"

/* Elements ahead that the CPU strips' eight-row mid callbacks prefetch their rows by: eight
 * rows of five arrays at once are more streams than a CPU's prefetchers follow (the Adam
 * round trip at 1024^2 on PoCL: 3.7 -> 2.9 ms; 64-256 alike) */
#ifndef SGD_PF
#define SGD_PF 128
#endif

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

/* The iteration in four passes (PhaseRetrieval(fuse="round-trips")): two column round trips
 * (the forward and the adjoint transfer functions) and two row round trips, whose mid steps are
 * these callbacks. The residual is linear in the forward field y once the scale is known:
 *     A^H(conj(s) w m (s y - t)) = |s|^2 w A^H(m y) - conj(s) w A^H(m t),
 * and A^H(m t) is the same every iteration (computed once), so the adjoint propagates m y,
 * which needs no scale, and the loss sums run between the two row round trips. */

#ifdef SGD_FORWARD_MID
/* The forward's row inverse meets the adjoint's row FFT: the loss sums of the forward field y
 * (field_sums' terms w conj(y) t, w |y|^2, w |t|^2, added up by the kernel per part:
 * FFT_MID_CB_SUMS), and m y passed on; y itself is never stored. t [B, H, W], mask [H, W]
 * (read when has_mask), partial [B, nparts] (Re, Im, yy, tt) for fit_scale. */
#define FFT_MID_CB_SUMS 1
#define SGD_FORWARD_MID_PARAMS                                                               \
    __global const real2 *t, __global const real *mask, uint has_mask,                       \
    __global real4 *partial, uint nparts, uint height, uint width

real2 clholo_mid_acc(real2 y, long b, int row, int col, real4 *acc, SGD_FORWARD_MID_PARAMS)
{
    const size_t p = (size_t)row * width + (uint)col;
    const real2 tv = t[(size_t)b * height * width + p];
    const real roi = has_mask ? mask[p] : (real)1;
    *acc += roi * (real4)(y.x * tv.x + y.y * tv.y, y.x * tv.y - y.y * tv.x,
                          y.x * y.x + y.y * y.y, tv.x * tv.x + tv.y * tv.y);
    return has_mask ? roi * y : y;
}

/* Eight rows row0 .. row0 + 7 by eight columns col .. col + 7, lane l of re[j] / im[j] =
 * pixel (row0 + l, col + j), as the CPU round trip's strips hold them (fft_cpu.cl,
 * FFT_MID_CB_SUMS_ROWS8): after an 8x8 transpose each float8 is eight pixels of a row, t and
 * the mask are read in runs of a row, and the terms go to acc[0..3] (running sums of
 * Re conj(y) t, Im conj(y) t, |y|^2, |t|^2, one lane per column of the run: independent
 * chains where the one-pixel form added every term to one sum in turn, and read t at the
 * strip's eight rows for each column: 1.8 ms of a 2.9 ms round trip at 1024^2 on PoCL). */
#define FFT_MID_CB_SUMS_ROWS8 1
void clholo_mid_acc_rows8(float8 *re, float8 *im, long b, int row0, int col, float8 *acc,
                          SGD_FORWARD_MID_PARAMS)
{
    CLHOLO_TRANSPOSE8_REAL(float8, re);
    CLHOLO_TRANSPOSE8_REAL(float8, im);
    for (int l = 0; l < 8; ++l) {
        const size_t p = (size_t)(row0 + l) * width + (uint)col;
        __global const real *tp = (__global const real *)(t + (size_t)b * height * width + p);
#if SGD_PF > 0
        /* eight rows of t and the mask at once are more streams than the prefetchers follow */
        if ((uint)col + SGD_PF + 8 <= width) {
            CLHOLO_PREFETCH(tp + 2 * SGD_PF, 0);
            if (has_mask)
                CLHOLO_PREFETCH(mask + p + SGD_PF, 0);
        }
#endif
        const float16 tv = vload16(0, tp);
        const float8 tr = tv.even, ti = tv.odd, yr = re[l], yi = im[l];
        const float8 w = has_mask ? vload8(0, mask + p) : (float8)(1);
        acc[0] += w * (yr * tr + yi * ti);
        acc[1] += w * (yr * ti - yi * tr);
        acc[2] += w * (yr * yr + yi * yi);
        acc[3] += w * (tr * tr + ti * ti);
        if (has_mask) {
            re[l] = w * yr;
            im[l] = w * yi;
        }
    }
    CLHOLO_TRANSPOSE8_REAL(float8, re);
    CLHOLO_TRANSPOSE8_REAL(float8, im);
}

void clholo_mid_sums_store(real4 sum, long b, int part, SGD_FORWARD_MID_PARAMS)
{
    partial[(size_t)b * nparts + (uint)part] = sum;
}
#endif

#ifdef SGD_ADAM_MID
/* The adjoint's row inverse meets the next forward's row FFT: from u = A^H(m y) the gradient
 * field g = |s|^2 w u - conj(s) w gt (gt = A^H(m t)), the phase gradient 2 Im(g conj(x)) at
 * x = exp(i P) of the phase before the step, Adam on the phase, and exp(i P) of the new phase
 * passed on (the next iteration's field: x is never stored). gt [B, H, W] complex; phase,
 * adam_m, adam_v, grad [B, H, W]; scale, weight [B] from fit_scale. */
#define SGD_ADAM_MID_PARAMS                                                                  \
    __global const real2 *gt, __global real *phase, __global real *adam_m,                    \
    __global real *adam_v, __global real *grad, __global const real2 *scale,                   \
    __global const real *weight, real lr, real b1, real b2, real one_minus_b1,               \
    real one_minus_b2, real eps, real bc1, real bc2, uint height, uint width

/* g = a u - conj(s) w t (a = |s|^2 w) on real and imaginary parts */
#define SGD_GRADIENT_FIELD(TY, ur, ui, tr, ti, a, swx, swy, gr, gi)                         \
    const TY gr = (a) * (ur) - ((swx) * (tr) + (swy) * (ti));                                \
    const TY gi = (a) * (ui) - ((swx) * (ti) - (swy) * (tr));

/* four adjacent pixels from element k of field b (the one-pixel form takes lane 0) */
static inline void sgd_adam_quad(float4 ur, float4 ui, float4 *xr, float4 *xi, long b, size_t k,
                                 int lanes, SGD_ADAM_MID_PARAMS)
{
    const real2 s = scale[b];
    const real w = weight[b];
    const real a = (s.x * s.x + s.y * s.y) * w;
    float4 tr, ti, p0, m0, v0;
    if (lanes == 4) {
        const float8 tv = vload8(0, (__global const real *)(gt + k));
        tr = tv.even;
        ti = tv.odd;
        p0 = vload4(0, phase + k);
        m0 = vload4(0, adam_m + k);
        v0 = vload4(0, adam_v + k);
    } else {
        tr = (float4)(gt[k].x);
        ti = (float4)(gt[k].y);
        p0 = (float4)(phase[k]);
        m0 = (float4)(adam_m[k]);
        v0 = (float4)(adam_v[k]);
    }
    SGD_GRADIENT_FIELD(float4, ur, ui, tr, ti, a, s.x * w, s.y * w, gr, gi)
    float4 c0;
    const float4 s0 = clholo_sincos4(p0, &c0);
    const float4 d = SGD_PHASE_GRADIENT(gr, gi, c0, s0);
    ADAM_STEP(float4, d, m0, v0, p0, m, v, p)
    if (lanes == 4) {
        vstore4(d, 0, grad + k);
        vstore4(m, 0, adam_m + k);
        vstore4(v, 0, adam_v + k);
        vstore4(p, 0, phase + k);
    } else {
        grad[k] = d.x;
        adam_m[k] = m.x;
        adam_v[k] = v.x;
        phase[k] = p.x;
    }
    *xi = clholo_sincos4(p, xr);
}

/* the GPU kernels run it in a sweep of its own, not at each output of the last butterfly */
#define FFT_MID_CB_SWEEP 1
real2 clholo_mid(real2 v, long b, int row, int col, SGD_ADAM_MID_PARAMS)
{
    float4 xr, xi;
    sgd_adam_quad((float4)(v.x), (float4)(v.y), &xr, &xi, b,
                  ((size_t)b * height + (uint)row) * width + (uint)col, 1, gt, phase, adam_m,
                  adam_v, grad, scale, weight, lr, b1, b2, one_minus_b1, one_minus_b2, eps, bc1,
                  bc2, height, width);
    return (real2)(xr.x, xi.x);
}

#define FFT_MID_CB_QUAD 1
void clholo_mid4(real2 *v, long b, int row, int col, SGD_ADAM_MID_PARAMS)
{
    const float8 u = vload8(0, (const real *)v);
    float4 xr, xi;
    sgd_adam_quad(u.even, u.odd, &xr, &xi, b,
                  ((size_t)b * height + (uint)row) * width + (uint)col, 4, gt, phase, adam_m,
                  adam_v, grad, scale, weight, lr, b1, b2, one_minus_b1, one_minus_b2, eps, bc1,
                  bc2, height, width);
    vstore8(CLHOLO_INTERLEAVE4(xr, xi), 0, (real *)v);
}

/* Eight rows row0 .. row0 + 7 by eight columns col .. col + 7, lane l of re[j] / im[j] = pixel
 * (row0 + l, col + j), as the CPU round trip's strips hold them (fft_cpu.cl, FFT_MID_CB_ROWS8):
 * two 8x8 transposes in registers turn them into rows, so every array is read and written in
 * float8 runs of a row, and the arithmetic is float16 code on two rows at once, the same
 * operations as the quad form lane by lane. On PoCL at 1024^2 the round trip took 19 ms with
 * a call per four pixels, 12-15 ms with float8 code a row, 8.6-9.7 ms so (the two sin/cos are
 * most of it: 4.7 ms without them; the round trip alone 2.8 ms, the Adam kernel 2.1 ms). */
#define FFT_MID_CB_ROWS8 1
void clholo_mid_rows8(float8 *re, float8 *im, long b, int row0, int col, SGD_ADAM_MID_PARAMS)
{
    const real2 s = scale[b];
    const real w = weight[b];
    const real a = (s.x * s.x + s.y * s.y) * w;
    const real swx = s.x * w, swy = s.y * w;
    CLHOLO_TRANSPOSE8_REAL(float8, re);
    CLHOLO_TRANSPOSE8_REAL(float8, im);
    for (int l = 0; l < 8; l += 2) {
        const size_t k = ((size_t)b * height + (uint)(row0 + l)) * width + (uint)col;
        const size_t k2 = k + width;
#if SGD_PF > 0
        if ((uint)col + SGD_PF + 8 <= width) {
            CLHOLO_PREFETCH(phase + k + SGD_PF, 1);
            CLHOLO_PREFETCH(phase + k2 + SGD_PF, 1);
            CLHOLO_PREFETCH(adam_m + k + SGD_PF, 1);
            CLHOLO_PREFETCH(adam_m + k2 + SGD_PF, 1);
            CLHOLO_PREFETCH(adam_v + k + SGD_PF, 1);
            CLHOLO_PREFETCH(adam_v + k2 + SGD_PF, 1);
            CLHOLO_PREFETCH(grad + k + SGD_PF, 1);
            CLHOLO_PREFETCH(grad + k2 + SGD_PF, 1);
            CLHOLO_PREFETCH(gt + k + SGD_PF, 0);
            CLHOLO_PREFETCH(gt + k2 + SGD_PF, 0);
        }
#endif
        const float16 p0 = (float16)(vload8(0, phase + k), vload8(0, phase + k2));
        const float16 ta = vload16(0, (__global const real *)(gt + k));
        const float16 tb = vload16(0, (__global const real *)(gt + k2));
        const float16 ur = (float16)(re[l], re[l + 1]), ui = (float16)(im[l], im[l + 1]);
        const float16 tr = (float16)(ta.even, tb.even), ti = (float16)(ta.odd, tb.odd);
        SGD_GRADIENT_FIELD(float16, ur, ui, tr, ti, a, swx, swy, gr, gi)
        float16 s0, c0;
        clholo_sincos16(p0, &s0, &c0);
        const float16 d = SGD_PHASE_GRADIENT(gr, gi, c0, s0);
        const float16 m0 = (float16)(vload8(0, adam_m + k), vload8(0, adam_m + k2));
        const float16 v0 = (float16)(vload8(0, adam_v + k), vload8(0, adam_v + k2));
        ADAM_STEP(float16, d, m0, v0, p0, m1, v1, p1)
        vstore8(d.lo, 0, grad + k); vstore8(d.hi, 0, grad + k2);
        vstore8(m1.lo, 0, adam_m + k); vstore8(m1.hi, 0, adam_m + k2);
        vstore8(v1.lo, 0, adam_v + k); vstore8(v1.hi, 0, adam_v + k2);
        vstore8(p1.lo, 0, phase + k); vstore8(p1.hi, 0, phase + k2);
        float16 xs, xc;
        clholo_sincos16(p1, &xs, &xc);
        re[l] = xc.lo; re[l + 1] = xc.hi;
        im[l] = xs.lo; im[l + 1] = xs.hi;
    }
    CLHOLO_TRANSPOSE8_REAL(float8, re);
    CLHOLO_TRANSPOSE8_REAL(float8, im);
}
#endif

#ifdef SGD_MASK_LOAD
/* m t, the target the adjoint propagates once (A^H(m t) of the four-pass iteration). mask
 * [H, W] (read when has_mask) */
real2 clholo_load(real2 v, long b, int row, int col, __global const real *mask, uint has_mask,
                  uint width)
{
    return has_mask ? mask[(size_t)row * width + (uint)col] * v : v;
}
#endif
