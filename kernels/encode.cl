/* Phase-only SLM encodings (HOLOGRAPHY.md section 8): SGD phase retrieval and double-phase
 * amplitude coding. References: clholo.reference.encode.
 *
 * Built with -DREAL=float|double and -DFIELD_SUMS_LOCAL=<work-group size of the two-stage
 * per-field reductions field_sums / fit_scale and field_max_abs2 / field_max_abs> (a power of
 * two; the host chooses it per device: clholo.host.phase_retrieval.sum_plan). Fields are
 * [B, H, W] flat (n = H*W pixels per field); masks [H, W] broadcast over the batch.
 *
 * SGD loss per field b (the scale s_b fitted in closed form each iteration), with w the
 * region-of-interest weights (each multiplies its pixel's squared error; all ones without):
 *     L_b = sum w |s_b y_b - t_b|^2 / sum w |t_b|^2,    y_b = ASM(exp(i P_b), z)
 * with s_b = sum w conj(y_b) t_b / sum w |y_b|^2 the weighted least-squares scale, so that
 *     L_b = 1 - |sum w conj(y) t|^2 / (sum w |y|^2 sum w |t|^2)      (in [0, 1]).
 * Because s_b minimises L_b, dL_b/dP_b = the partial derivative at fixed s_b (envelope
 * theorem): 2 Im(g conj(x)) with g = ASM^H(conj(s_b) w (s_b y - t)) / sum w |t|^2.
 */
#include "clholo_complex.h"
#include "fast_sincos.h"
#include "sgd_step.h"

#ifndef FIELD_SUMS_LOCAL
#define FIELD_SUMS_LOCAL 64
#endif

/* The element-wise SGD kernels take four elements per work-item in float4 code (REAL must be
 * float), with clholo_sincos4 (fast_sincos.h): PoCL calls a scalar libm sincos per element
 * otherwise, which cost seven times the rest of the Adam step. Global size ceil(n / 4); the
 * last work-item takes the ragged end (n % 4 elements) one by one. */

/* CLHOLO_INTERLEAVE4 and CLHOLO_INTERLEAVE8: sgd_step.h */

/* x = exp(i P) for n elements */
__kernel void phase_to_field(__global const REAL *phase, __global REAL2 *field, const uint n)
{
    const uint i = get_global_id(0) * 4u;
    if (i + 4u <= n) {
        REAL4 c;
        const REAL4 s = clholo_sincos4(vload4(0, phase + i), &c);
        vstore8(CLHOLO_INTERLEAVE4(c, s), 0, (__global REAL *)(field + i));
    } else {
        for (uint k = i; k < n; ++k) {
            REAL4 c;
            const REAL4 s = clholo_sincos4((REAL4)(phase[k]), &c);
            field[k] = (REAL2)(c.x, s.x);
        }
    }
}

/* The tree of a work-group's FIELD_SUMS_LOCAL values in local memory: scratch[0] is their sum,
 * added in an order fixed by FIELD_SUMS_LOCAL alone. Every work-item of the group calls it. */
static inline void clholo_sum_tree4(__local REAL4 *scratch, const uint lid)
{
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint s = FIELD_SUMS_LOCAL / 2; s > 0; s >>= 1) {
        if (lid < s)
            scratch[lid] += scratch[lid + s];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
}

/* field_sums' terms of pixels whose real and imaginary parts are yr, yi (y) and tr, ti (t),
 * weights w, added to the running sums re, im (conj(y) t), yy, tt: one expression for every
 * vector width, so that field_sums and field_sums_lanes add the same bits. */
#define FIELD_SUMS_TERMS(w, yr, yi, tr, ti, re, im, yy, tt) {                                \
        re += (w) * ((yr) * (tr) + (yi) * (ti));                                             \
        im += (w) * ((yr) * (ti) - (yi) * (tr));                                             \
        yy += (w) * ((yr) * (yr) + (yi) * (yi));                                             \
        tt += (w) * ((tr) * (tr) + (ti) * (ti)); }

/* acc plus the n % 4 pixels past the last quad, one at a time (work-item 0 of group 0 adds
 * them to its sums) */
static inline REAL4 field_sums_tail(REAL4 acc, __global const REAL *yf, __global const REAL *tf,
                                    __global const REAL *mask, const uint has_mask,
                                    const uint nq, const uint n)
{
    for (uint i = 4 * nq; i < n; ++i) {
        const REAL2 yv = (REAL2)(yf[2 * i], yf[2 * i + 1]);
        const REAL2 tv = (REAL2)(tf[2 * i], tf[2 * i + 1]);
        const REAL m = has_mask ? mask[i] : (REAL)1;
        const REAL2 c = cmul(cconj(yv), tv);
        acc += m * (REAL4)(c.x, c.y, cabs2(yv), cabs2(tv));
    }
    return acc;
}

/* Stage 1 of the per-field sums: work-group (g, b) of FIELD_SUMS_LOCAL work-items adds the terms
 * conj(y) t (re, im), |y|^2, |t|^2 times the weight w (mask: region-of-interest weights, or
 * NULL-equivalent all ones when has_mask == 0) over field b's pixels in quads: work-item lid
 * takes quads q = g*FIELD_SUMS_LOCAL + lid stepping by G*FIELD_SUMS_LOCAL (float4 code, one
 * lane per pixel of the quad: PoCL vectorises it, a GPU reads 32 bytes a work-item), adds its
 * four lanes, and work-item 0 of group 0 adds the n % 4 pixels past the last quad; then the
 * tree. partial[b*G + g] = (Re, Im, yy, tt). G (work-groups per field) comes from the device's
 * compute units (sum_plan). */
__kernel __attribute__((reqd_work_group_size(FIELD_SUMS_LOCAL, 1, 1)))
void field_sums(__global const REAL2 *y, __global const REAL2 *t, __global const REAL *mask,
                const uint has_mask, const uint n, __global REAL4 *partial)
{
    const uint lid = get_local_id(0);
    const uint g = get_group_id(0);
    const uint G = get_num_groups(0);
    const size_t b = get_global_id(1);
    __local REAL4 scratch[FIELD_SUMS_LOCAL];
    __global const REAL *yf = (__global const REAL *)(y + b * (size_t)n);
    __global const REAL *tf = (__global const REAL *)(t + b * (size_t)n);
    REAL4 re = 0, im = 0, yy = 0, tt = 0;
    const uint nq = n / 4;
    for (uint q = g * FIELD_SUMS_LOCAL + lid; q < nq; q += G * FIELD_SUMS_LOCAL) {
        const REAL8 yv = vload8(q, yf);     /* (re, im) of 4 pixels */
        const REAL8 tv = vload8(q, tf);
        const REAL4 m = has_mask ? vload4(q, mask) : (REAL4)(1);
        FIELD_SUMS_TERMS(m, yv.even, yv.odd, tv.even, tv.odd, re, im, yy, tt)
    }
    REAL4 acc = (REAL4)(re.x + re.y + re.z + re.w, im.x + im.y + im.z + im.w,
                        yy.x + yy.y + yy.z + yy.w, tt.x + tt.y + tt.z + tt.w);
    if (g == 0 && lid == 0)
        acc = field_sums_tail(acc, yf, tf, mask, has_mask, nq, n);
    scratch[lid] = acc;
    clholo_sum_tree4(scratch, lid);
    if (lid == 0)
        partial[b * G + g] = scratch[0];
}

/* field_sums for CPUs, the same bits: work-item (g, b), one a work-group, runs the
 * FIELD_SUMS_LOCAL work-items of field_sums' group g side by side, four of them (sixteen lanes)
 * per REAL16 of each running sum, so that each pass reads FIELD_SUMS_LOCAL quads in a row:
 * every lane adds the same terms in the same order as its work-item does there, then the lanes
 * and the tree are added as clholo_sum_tree4 adds them. On PoCL, field_sums' work-items each
 * ran their whole loop in turn, one 32-byte quad at a stride of G * FIELD_SUMS_LOCAL quads
 * (128 KiB at 64 x 64): 0.5 ms at 1024^2 on a 2-core Zen 5, four times its bytes' time from
 * cache. Global size (G, B), local (1, 1). REAL must be float. */
#if FIELD_SUMS_LOCAL >= 4
#define FIELD_SUMS_VECS (FIELD_SUMS_LOCAL / 4)
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void field_sums_lanes(__global const REAL *y, __global const REAL *t, __global const REAL *mask,
                      const uint has_mask, const uint n, __global REAL4 *partial)
{
    const uint g = get_global_id(0);
    const uint G = get_global_size(0);
    const size_t b = get_global_id(1);
    __global const REAL *yf = y + 2 * b * (size_t)n;
    __global const REAL *tf = t + 2 * b * (size_t)n;
    REAL16 re[FIELD_SUMS_VECS], im[FIELD_SUMS_VECS], yy[FIELD_SUMS_VECS], tt[FIELD_SUMS_VECS];
    for (uint j = 0; j < FIELD_SUMS_VECS; ++j)
        re[j] = im[j] = yy[j] = tt[j] = (REAL16)(0);
    const uint nq = n / 4;
    uint q0 = g * FIELD_SUMS_LOCAL;
    /* the passes where all FIELD_SUMS_LOCAL work-items have a quad */
    for (; q0 + FIELD_SUMS_LOCAL <= nq; q0 += G * FIELD_SUMS_LOCAL) {
#pragma unroll
        for (uint j = 0; j < FIELD_SUMS_VECS; ++j) {
            const uint q = q0 + 4 * j;          /* the quad of work-item 4 j */
            const REAL16 ya = vload16(0, yf + 8 * q), yb = vload16(1, yf + 8 * q);
            const REAL16 ta = vload16(0, tf + 8 * q), tb = vload16(1, tf + 8 * q);
            const REAL16 yr = (REAL16)(ya.even, yb.even), yi = (REAL16)(ya.odd, yb.odd);
            const REAL16 tr = (REAL16)(ta.even, tb.even), ti = (REAL16)(ta.odd, tb.odd);
            const REAL16 m = has_mask ? vload16(0, mask + 4 * q) : (REAL16)(1);
            FIELD_SUMS_TERMS(m, yr, yi, tr, ti, re[j], im[j], yy[j], tt[j])
        }
    }
    /* a last pass where only some have (at most one: the passes step by G L quads) */
    for (uint w = 0; q0 < nq && w < FIELD_SUMS_LOCAL && q0 + w < nq; ++w) {
        const REAL8 yv = vload8(q0 + w, yf);
        const REAL8 tv = vload8(q0 + w, tf);
        const REAL4 mv = has_mask ? vload4(q0 + w, mask) : (REAL4)(1);
        FIELD_SUMS_TERMS(mv, yv.even, yv.odd, tv.even, tv.odd, ((REAL4 *)re)[w],
                         ((REAL4 *)im)[w], ((REAL4 *)yy)[w], ((REAL4 *)tt)[w])
    }
    REAL4 acc[FIELD_SUMS_LOCAL];
    for (uint lid = 0; lid < FIELD_SUMS_LOCAL; ++lid) {
        const REAL4 r = ((REAL4 *)re)[lid], i = ((REAL4 *)im)[lid];
        const REAL4 a = ((REAL4 *)yy)[lid], c = ((REAL4 *)tt)[lid];
        acc[lid] = (REAL4)(r.x + r.y + r.z + r.w, i.x + i.y + i.z + i.w,
                           a.x + a.y + a.z + a.w, c.x + c.y + c.z + c.w);
    }
    if (g == 0)
        acc[0] = field_sums_tail(acc[0], yf, tf, mask, has_mask, nq, n);
    for (uint s = FIELD_SUMS_LOCAL / 2; s > 0; s >>= 1)
        for (uint lid = 0; lid < s; ++lid)
            acc[lid] += acc[lid + s];
    partial[b * G + g] = acc[0];
}
#endif

/* Stage 2, on the device: one work-group of FIELD_SUMS_LOCAL work-items per field (global size
 * (FIELD_SUMS_LOCAL, B)) adds its G partial sums, work-item lid those at lid, lid + LOCAL, ...
 * in order, then the tree; work-item 0 writes the least-squares scale s_b = <y, t> / ||y||^2
 * (0 where y vanishes), the weight w_b = 1 / sum m |t|^2 and the loss L_b. */
__kernel __attribute__((reqd_work_group_size(FIELD_SUMS_LOCAL, 1, 1)))
void fit_scale(__global const REAL4 *partial, const uint G, __global REAL2 *scale,
               __global REAL *weight, __global REAL *loss)
{
    const uint lid = get_local_id(0);
    const size_t b = get_global_id(1);
    __local REAL4 scratch[FIELD_SUMS_LOCAL];
    REAL4 acc = (REAL4)(0, 0, 0, 0);
    for (uint g = lid; g < G; g += FIELD_SUMS_LOCAL)
        acc += partial[b * G + g];
    scratch[lid] = acc;
    clholo_sum_tree4(scratch, lid);
    if (lid != 0)
        return;
    const REAL4 s = scratch[0];
    const REAL yy = s.z, tt = s.w;
    const REAL2 c = (REAL2)(s.x, s.y);
    scale[b] = yy > 0 ? c / yy : (REAL2)(0, 0);
    weight[b] = tt > 0 ? 1 / tt : (REAL)0;
    /* the loss of the fitted scale, clamped at 0 against rounding */
    loss[b] = (tt > 0 && yy > 0) ? fmax((REAL)0, 1 - cabs2(c) / (yy * tt)) : (REAL)1;
}

/* y <- conj(s_b) w_b m (s_b y - t), m the ROI weight, in place: the residual the adjoint propagates.
 * n pixels a field, eight per work-item in float8 code, as the adjoint's load callback does
 * them (sgd_callbacks.h clholo_load8: the same bits); the last work-item of a field takes the
 * ragged end one by one. Global size (ceil(n / 8), B). One pixel per work-item took 1.44 ms
 * at 1024^2 on PoCL (2-core Zen 5), four times its bytes' copy time. */
__kernel void scaled_residual(__global REAL2 *y, __global const REAL2 *t,
                              __global const REAL *mask, const uint has_mask,
                              __global const REAL2 *scale, __global const REAL *weight,
                              const uint n)
{
    const uint i0 = get_global_id(0) * 8u;
    const size_t b = get_global_id(1);
    const size_t k0 = b * n + i0;
    const REAL2 s = scale[b];
    const REAL w = weight[b];
    if (i0 + 8u <= n) {
        __global REAL *yp = (__global REAL *)(y + k0);
        const REAL16 yv = vload16(0, yp), tv = vload16(0, (__global const REAL *)(t + k0));
        const REAL8 mw = (has_mask ? vload8(0, mask + i0) : (REAL8)(1)) * w;
        SGD_RESIDUAL(REAL8, yv.even, yv.odd, tv.even, tv.odd, s.x, s.y, mw, re, im)
        vstore16(CLHOLO_INTERLEAVE8(re, im), 0, yp);
        return;
    }
    for (uint i = i0; i < n; ++i) {
        const REAL m = has_mask ? mask[i] : (REAL)1;
        y[b * n + i] = sgd_residual(y[b * n + i], t[b * n + i], s, m * w);
    }
}

/* The phase gradient grad = 2 Im(g conj(x)) and one Adam step on the phase (ADAM_STEP,
 * sgd_step.h), fused, then x <- exp(i P) for the next forward pass. grad is written out (tests,
 * diagnostics). n elements, sixteen per work-item in float16 code (global size ceil(n / 16), the
 * last work-item takes the ragged end one by one): on PoCL 3.0 against 5.0 ms at 1024^2 with
 * four per work-item, mostly clholo_sincos16 against clholo_sincos4 (the same bits). */
__kernel void phase_gradient_adam(__global const REAL2 *g, __global REAL2 *x,
                                  __global REAL *phase, __global REAL *adam_m,
                                  __global REAL *adam_v, __global REAL *grad,
                                  const REAL lr, const REAL b1, const REAL b2,
                                  const REAL one_minus_b1, const REAL one_minus_b2,
                                  const REAL eps, const REAL bc1, const REAL bc2, const uint n)
{
    const uint i0 = get_global_id(0) * 16u;
    if (i0 + 16u <= n) {
        __global const REAL *gp = (__global const REAL *)(g + i0);
        __global REAL *xp = (__global REAL *)(x + i0);
        const REAL16 ga = vload16(0, gp), gb = vload16(1, gp);
        const REAL16 xa = vload16(0, xp), xb = vload16(1, xp);
        /* 2 Im(g conj(x)) */
        const REAL16 gre = (REAL16)(ga.even, gb.even), gim = (REAL16)(ga.odd, gb.odd);
        const REAL16 d = SGD_PHASE_GRADIENT(gre, gim, (REAL16)(xa.even, xb.even),
                                            (REAL16)(xa.odd, xb.odd));
        vstore16(d, 0, grad + i0);
        ADAM_STEP(REAL16, d, vload16(0, adam_m + i0), vload16(0, adam_v + i0),
                  vload16(0, phase + i0), m, v, p)
        vstore16(m, 0, adam_m + i0);
        vstore16(v, 0, adam_v + i0);
        vstore16(p, 0, phase + i0);
        REAL16 s, c;
        clholo_sincos16(p, &s, &c);
        vstore16(CLHOLO_INTERLEAVE8(c.lo, s.lo), 0, xp);
        vstore16(CLHOLO_INTERLEAVE8(c.hi, s.hi), 1, xp);
        return;
    }
    for (uint k = i0; k < n; ++k)
        sgd_adam_pixel(g[k], k, x, phase, adam_m, adam_v, grad, lr, b1, b2, one_minus_b1,
                       one_minus_b2, eps, bc1, bc2);
}

/* Double-phase amplitude coding: a = min(|u| / amax_b, 1), phi = arg u, and
 * P = phi + acos(a) where (x + y) is even, phi - acos(a) where it is odd, so that the mean of
 * two neighbours exp(i(phi + acos a)) + exp(i(phi - acos a)) over 2 is a exp(i phi).
 * Global size (W, H, B). */
__kernel void dpac_encode(__global const REAL2 *u, __global const REAL *amax,
                          __global REAL *phase)
{
    const size_t xi = get_global_id(0);
    const size_t yi = get_global_id(1);
    const size_t b = get_global_id(2);
    const size_t W = get_global_size(0);
    const size_t k = (b * get_global_size(1) + yi) * W + xi;
    const REAL2 uv = u[k];
    const REAL am = amax[b];
    /* a field of zeros (amax 0) codes as a flat amplitude of 0 */
    const REAL a = am > 0 ? fmin(sqrt(cabs2(uv)) / am, (REAL)1) : (REAL)0;
    const REAL phi = atan2(uv.y, uv.x);
    const REAL d = acos(a);
    phase[k] = ((xi + yi) & 1) ? phi - d : phi + d;
}

/* The tree of a work-group's FIELD_SUMS_LOCAL values in local memory: scratch[0] is their
 * largest (fmax: a NaN loses to any number). Every work-item of the group calls it. */
static inline void clholo_max_tree(__local REAL *scratch, const uint lid)
{
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint s = FIELD_SUMS_LOCAL / 2; s > 0; s >>= 1) {
        if (lid < s)
            scratch[lid] = fmax(scratch[lid], scratch[lid + s]);
        barrier(CLK_LOCAL_MEM_FENCE);
    }
}

/* Largest |u| of each field, in two stages split like field_sums / fit_scale (sum_plan).
 * Stage 1: work-group (g, b) of FIELD_SUMS_LOCAL work-items takes the largest cabs2(u) = |u|^2
 * of field b's pixels in quads: work-item lid takes quads q = g*FIELD_SUMS_LOCAL + lid stepping
 * by G*FIELD_SUMS_LOCAL (float4 code, one lane per pixel), work-item 0 of group 0 also the
 * n % 4 pixels past the last quad; then the tree. partial[b*G + g] = that |u|^2 (0 for a group
 * with no pixels). A maximum is exact in any order, so the result does not depend on the
 * split; |u|^2 is rounded as cabs2 rounds it (dpac_encode's sqrt(cabs2(u)) of the largest
 * pixel is then exactly amax). NaN pixels are skipped (fmax returns the number), as the
 * one-group kernel before did: a field of NaNs gives 0, which dpac_encode codes as a = 0. */
__kernel __attribute__((reqd_work_group_size(FIELD_SUMS_LOCAL, 1, 1)))
void field_max_abs2(__global const REAL2 *u, const uint n, __global REAL *partial)
{
    const uint lid = get_local_id(0);
    const uint g = get_group_id(0);
    const uint G = get_num_groups(0);
    const size_t b = get_global_id(1);
    __local REAL scratch[FIELD_SUMS_LOCAL];
    __global const REAL *uf = (__global const REAL *)(u + b * (size_t)n);
    REAL4 m = 0;
    const uint nq = n / 4;
    for (uint q = g * FIELD_SUMS_LOCAL + lid; q < nq; q += G * FIELD_SUMS_LOCAL) {
        const REAL8 v = vload8(q, uf);      /* (re, im) of 4 pixels */
        m = fmax(m, v.even * v.even + v.odd * v.odd);
    }
    REAL acc = fmax(fmax(m.x, m.y), fmax(m.z, m.w));
    if (g == 0 && lid == 0) {
        for (uint i = 4 * nq; i < n; ++i)
            acc = fmax(acc, cabs2((REAL2)(uf[2 * i], uf[2 * i + 1])));
    }
    scratch[lid] = acc;
    clholo_max_tree(scratch, lid);
    if (lid == 0)
        partial[b * G + g] = scratch[0];
}

/* Stage 2, on the device: one work-group of FIELD_SUMS_LOCAL work-items per field (global size
 * (FIELD_SUMS_LOCAL, B)) takes the largest of its G partials, then out[b] = sqrt of it, taken
 * once: the largest |u| of field b. */
__kernel __attribute__((reqd_work_group_size(FIELD_SUMS_LOCAL, 1, 1)))
void field_max_abs(__global const REAL *partial, const uint G, __global REAL *out)
{
    const uint lid = get_local_id(0);
    const size_t b = get_global_id(1);
    __local REAL scratch[FIELD_SUMS_LOCAL];
    REAL m = 0;
    for (uint g = lid; g < G; g += FIELD_SUMS_LOCAL)
        m = fmax(m, partial[b * G + g]);
    scratch[lid] = m;
    clholo_max_tree(scratch, lid);
    if (lid == 0)
        out[b] = sqrt(scratch[0]);
}

/* phase = arg(u) in (-pi, pi] */
__kernel void field_angle(__global const REAL2 *u, __global REAL *phase)
{
    const size_t i = get_global_id(0);
    phase[i] = atan2(u[i].y, u[i].x);
}
