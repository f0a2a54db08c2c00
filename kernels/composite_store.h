/* The next layer's wave-domain "over", as an FFT callback (clholo.fft.FFTCallback) in two
 * places: the store callback of the inverse transform that finishes the previous propagation
 * (clholo_store/clholo_store4: the four-pass layer, host/scheduler.py's COMPOSITE_STORE) and the
 * mid callback of the row round trip (clholo_mid/clholo_mid4: the two-pass layer,
 * clholo.fft.RoundTripPlan), where it sits between the row inverse and the row forward FFT:
 *
 *   v <- sqrt(1 - a) v + sqrt(c a) exp(i phi)      (transmission 1 with CLHOLO_NO_OCCLUSION)
 *
 * where v is the propagated field at pixel p = row W + col of batch field b = f C + c (frame
 * frame0 + f, colour c), a and c the layer's alpha and colour at p, and phi is pixel p's phase
 * of the Philox stream (random_phase.h) for this layer, frame and colour: the same values as
 * composite.cl's composite_layer, so frames match the unfused loop. Both places share
 * composite_value/composite_value4 below.
 *
 * Every form (one pixel, four, eight rows; composite.cl's) writes the "over" as
 * fma(keep, v, amp cos) and fma(keep, v, amp sin): OpenCL C contracts a * b + c * d into an
 * fma by default (FP_CONTRACT ON), and which product a compiler fused differed between the
 * scalar and the vector forms (PoCL: 537 of 1536 words). Spelled out, every form and every
 * device that rounds fma correctly (as OpenCL requires) gives the same bits.
 *
 * color  float [npix][n_channels]   alpha  float [npix]
 *
 * With CLHOLO_LAYER_BLOCKS (the CPU strips' layout, composite_cpu.cl's layer_blocks) the two
 * arrays hold the layer as the composite uses it, eight rows to a block, rows in the lanes:
 *
 * color  float [S][n_channels][width][8]   amp  = sqrt(c a) of pixel (8 s + l, x) at [s][c][x][l]
 * alpha  float [S][width][8]               keep = sqrt(1 - a) of pixel (8 s + l, x) at [s][x][l]
 *
 * S = ceil(height / 8); rows past the last have amp 0 and keep 1. The same products as the
 * row-major form, made once when a renderer is built (as PyTorch's peer makes its amp and
 * keep once): so the same bits, without the eight-row composite's gather of one colour
 * channel, its two 8x8 transposes and its two square roots per pixel and frame.
 *
 * With CLHOLO_LAYER_ROWS 1 as well, a block is one row: the planes the GPU kernels read
 * (composite.cl's layer_planes; HologramRenderer's layer_layout "planes"),
 *
 * color  float [height][n_channels][width]  amp  of pixel (y, x) at [y][c][x]
 * alpha  float [height][width]              keep of pixel (y, x) at [y][x]
 *
 * so that a row of one colour's amp is contiguous: adjacent work-items read adjacent words
 * (a GPU's coalesced load) instead of one channel of every third.
 */
#include "random_phase.h"
#include "fast_sincos.h"
#include "transpose8.h"
#include "cpu_wide.h"

/* Pixels ahead that the CPU strips' eight-row composite prefetches its rows of alpha and colour
 * by (CLHOLO_PREFETCH) */
#ifndef COMPOSITE_PF
#define COMPOSITE_PF 128
#endif

#ifdef CLHOLO_LAYER_BLOCKS
#ifndef CLHOLO_LAYER_ROWS
#define CLHOLO_LAYER_ROWS 8
#endif
#if CLHOLO_LAYER_ROWS != 8 && CLHOLO_LAYER_ROWS != 1
#error "CLHOLO_LAYER_ROWS: rows per block, 8 (CPU strips) or 1 (planes)"
#endif
/* Where pixel (row, col) of plane `plane` (of `planes`) lies in a layer's blocks
 * [S][planes][width][R], R = CLHOLO_LAYER_ROWS: amp has n_channels planes, keep one */
static inline size_t layer_block_at(int row, int col, uint width, uint planes, uint plane)
{
    const uint R = CLHOLO_LAYER_ROWS;
    return (((size_t)((uint)row / R) * planes + plane) * width + (uint)col) * R
           + ((uint)row % R);
}
#endif

real2 composite_value(real2 v, long b, int row, int col, __global const float *color,
                      __global const float *alpha, uint width, uint n_channels, uint layer,
                      uint frame0, uint key_lo, uint key_hi)
{
    const uint p = (uint)row * width + (uint)col;
    const uint c = (uint)b % n_channels, f = (uint)b / n_channels;
#ifdef CLHOLO_LAYER_BLOCKS
    const size_t k = layer_block_at(row, col, width, 1u, 0u);
    const float amp = color[layer_block_at(row, col, width, n_channels, c)];
#else
    const float a = alpha[p];
    const float amp = sqrt(color[(size_t)p * n_channels + c] * a);
#endif
    float4 co4;
    const float4 si4 = clholo_sincos4((float4)(clholo_phase(p, layer, frame0 + f, c, key_lo,
                                                            key_hi)), &co4);
    const float co = co4.x, si = si4.x;   /* the same values as composite.cl's */
#ifdef CLHOLO_NO_OCCLUSION
    const float keep = 1.0f;
#elif defined(CLHOLO_LAYER_BLOCKS)
    const float keep = alpha[k];
#else
    const float keep = sqrt(1.0f - a);
#endif
    return fma((real2)(keep), v, (real2)(amp * co, amp * si));
}

void clholo_store(__global real2 *ptr, real2 v, long b, int row, int col,
                  __global const float *color, __global const float *alpha, uint width,
                  uint n_channels, uint layer, uint frame0, uint key_lo, uint key_hi)
{
    *ptr = composite_value(v, b, row, col, color, alpha, width, n_channels, layer, frame0,
                           key_lo, key_hi);
}

real2 clholo_mid(real2 v, long b, int row, int col, __global const float *color,
                 __global const float *alpha, uint width, uint n_channels, uint layer,
                 uint frame0, uint key_lo, uint key_hi)
{
    return composite_value(v, b, row, col, color, alpha, width, n_channels, layer, frame0,
                           key_lo, key_hi);
}

/* Four adjacent pixels p .. p + 3 of one row (p = row W + col, col a multiple of 4), v[0..3] in
 * private memory, updated in place: when p is a multiple of 4 they are one Philox block, drawn
 * once, and the body is float4 code like composite.cl's; otherwise (W not a multiple of 4)
 * pixel by pixel. */
void composite_value4(real2 *v, long b, int row, int col, __global const float *color,
                      __global const float *alpha, uint width, uint n_channels, uint layer,
                      uint frame0, uint key_lo, uint key_hi)
{
    const uint p = (uint)row * width + (uint)col;
    if (p & 3u) {
        /* pixel by pixel, v rotated so that every index into it is a constant: a GPU keeps v
         * in registers (v[q] in a loop the compiler leaves rolled would put it in stack
         * memory, on every path) */
        for (int q = 0; q < 4; ++q) {
            const real2 t = v[0];
            v[0] = v[1]; v[1] = v[2]; v[2] = v[3];
            v[3] = composite_value(t, b, row, col + q, color, alpha, width, n_channels, layer,
                                   frame0, key_lo, key_hi);
        }
        return;
    }
    const uint c = (uint)b % n_channels, f = (uint)b / n_channels;
#if defined(CLHOLO_LAYER_BLOCKS) && CLHOLO_LAYER_ROWS == 1
    /* four adjacent words of a plane's row */
    const size_t k = layer_block_at(row, col, width, 1u, 0u);
    const float4 amp = vload4(0, color + layer_block_at(row, col, width, n_channels, c));
#elif defined(CLHOLO_LAYER_BLOCKS)
    /* four lanes of a block's rows, eight floats apart */
    const size_t k = layer_block_at(row, col, width, 1u, 0u);
    __global const float *ap = color + layer_block_at(row, col, width, n_channels, c);
    const float4 amp = (float4)(ap[0], ap[8], ap[16], ap[24]);
#else
    const float4 a = vload4(0, alpha + p);
    float4 col4;
    if (n_channels == 1u) {
        col4 = vload4(0, color + p);
    } else {
        __global const float *src = color + (size_t)p * n_channels + c;
        col4 = (float4)(src[0], src[n_channels], src[2 * n_channels], src[3 * n_channels]);
    }
    const float4 amp = sqrt(col4 * a);
#endif
    float4 co;
    const float4 si = clholo_sincos4(clholo_phase_block(p >> 2, layer, frame0 + f, c, key_lo,
                                                        key_hi), &co);
#ifdef CLHOLO_NO_OCCLUSION
    const float4 keep = (float4)(1.0f);
#elif defined(CLHOLO_LAYER_BLOCKS) && CLHOLO_LAYER_ROWS == 1
    const float4 keep = vload4(0, alpha + k);
#elif defined(CLHOLO_LAYER_BLOCKS)
    const float4 keep = (float4)(alpha[k], alpha[k + 8], alpha[k + 16], alpha[k + 24]);
#else
    const float4 keep = sqrt(1.0f - a);
#endif
    const float4 re = fma(keep, (float4)(v[0].x, v[1].x, v[2].x, v[3].x), amp * co);
    const float4 im = fma(keep, (float4)(v[0].y, v[1].y, v[2].y, v[3].y), amp * si);
    v[0] = (real2)(re.x, im.x); v[1] = (real2)(re.y, im.y);
    v[2] = (real2)(re.z, im.z); v[3] = (real2)(re.w, im.w);
}

#define FFT_STORE_CB_QUAD 1
void clholo_store4(__global real2 *ptr, real2 v0, real2 v1, real2 v2, real2 v3, long b,
                   int row, int col, __global const float *color,
                   __global const float *alpha, uint width, uint n_channels, uint layer,
                   uint frame0, uint key_lo, uint key_hi)
{
    real2 v[4] = {v0, v1, v2, v3};
    composite_value4(v, b, row, col, color, alpha, width, n_channels, layer, frame0, key_lo,
                     key_hi);
    ptr[0] = v[0]; ptr[1] = v[1]; ptr[2] = v[2]; ptr[3] = v[3];
}

#define FFT_MID_CB_QUAD 1
void clholo_mid4(real2 *v, long b, int row, int col, __global const float *color,
                 __global const float *alpha, uint width, uint n_channels, uint layer,
                 uint frame0, uint key_lo, uint key_hi)
{
    composite_value4(v, b, row, col, color, alpha, width, n_channels, layer, frame0, key_lo,
                     key_hi);
}

/* Eight rows row0 .. row0 + 7 by eight columns col .. col + 7 (col a multiple of 8), lane l
 * of re[j] / im[j] = pixel (row0 + l, col + j), updated in place: the CPU round trip's strips
 * hold the rows of a strip in the lanes of one vector, so with W a multiple of 4 the eight
 * rows' two Philox blocks each are one uint16 computation (clholo_phase_blocks16: lanes 0-7
 * the blocks of columns col .. col + 3, lanes 8-15 those of col + 4 .. col + 7) and the rest is
 * float16 code (columns j and j + 4 side by side), the same operations as composite_value4
 * lane by lane; otherwise pixel by pixel. With CLHOLO_LAYER_BLOCKS (row0 a multiple of 8) the
 * layer's amp and keep of column j are one aligned float8 load each (planes: a row's eight
 * words each, then 8x8 transposes); else its rows come through 8x8 transposes in registers
 * (transpose8.h). */
#define FFT_MID_CB_ROWS8 1
void clholo_mid_rows8(float8 *re, float8 *im, long b, int row0, int col,
                      __global const float *color, __global const float *alpha, uint width,
                      uint n_channels, uint layer, uint frame0, uint key_lo, uint key_hi)
{
    if (width & 3u) {
        for (int j = 0; j < 8; ++j)
            for (int l = 0; l < 8; ++l) {
                const real2 v = composite_value(
                    (real2)(((float *)&re[j])[l], ((float *)&im[j])[l]), b, row0 + l, col + j,
                    color, alpha, width, n_channels, layer, frame0, key_lo, key_hi);
                ((float *)&re[j])[l] = v.x;
                ((float *)&im[j])[l] = v.y;
            }
        return;
    }
    const uint c = (uint)b % n_channels, f = (uint)b / n_channels;
    const uint p0 = (uint)row0 * width + (uint)col;
    /* A block with alpha 0 everywhere leaves the field as it is (amplitude 0, transmission
     * 1: v = 0 cos + 1 v, up to the sign of a zero): no phases to draw. Real MPIs are mostly
     * transparent in their near layers (the Stereo Magnification scene in ../shared/data: a
     * quarter of all 8x8 blocks, most of the nearest layers'). */
#ifdef CLHOLO_LAYER_BLOCKS
    /* a[j], co[j]: keep and amp of column col + j, the eight rows in the lanes; the block is
     * left as it is where every amp is 0 and every keep 1 (alpha 0, or an amplitude and an
     * absorption both below float's resolution: the same values either way) */
    float8 a[8], co[8];
#if CLHOLO_LAYER_ROWS == 8
    __global const float *kp = alpha + layer_block_at(row0, col, width, 1u, 0u);
    __global const float *ap = color + layer_block_at(row0, col, width, n_channels, c);
    for (int j = 0; j < 8; ++j) {
        a[j] = vload8(j, kp);
        co[j] = vload8(j, ap);
    }
#else
    /* planes: the eight rows' words, then rows into lanes (transpose8.h) */
    for (int l = 0; l < 8; ++l) {
        a[l] = vload8(0, alpha + layer_block_at(row0 + l, col, width, 1u, 0u));
        co[l] = vload8(0, color + layer_block_at(row0 + l, col, width, n_channels, c));
    }
    CLHOLO_TRANSPOSE8_REAL(float8, a);
    CLHOLO_TRANSPOSE8_REAL(float8, co);
#endif
    float8 visible = (float8)(0.0f);
    for (int j = 0; j < 8; ++j) {
#ifdef CLHOLO_NO_OCCLUSION
        visible = fmax(visible, co[j]);
#else
        visible = fmax(visible, fmax(co[j], 1.0f - a[j]));
#endif
    }
    if (all(visible == (float8)(0.0f)))
        return;
#else
    float8 arow[8];
    float8 any_alpha = (float8)(0.0f);
#if COMPOSITE_PF > 0
    if ((uint)col + COMPOSITE_PF + 8 <= width)
        for (int l = 0; l < 8; ++l) {
            const uint q = p0 + (uint)l * width + COMPOSITE_PF;
            CLHOLO_PREFETCH(alpha + q, 0);
            CLHOLO_PREFETCH(color + (size_t)q * n_channels, 0);
            if (n_channels > 1u)
                CLHOLO_PREFETCH(color + (size_t)q * n_channels + 16, 0);
        }
#endif
    for (int l = 0; l < 8; ++l) {
        arow[l] = vload8(0, alpha + p0 + (uint)l * width);
        any_alpha = fmax(any_alpha, arow[l]);
    }
    if (all(any_alpha == (float8)(0.0f)))
        return;
#endif
    const uint8 first = (uint8)(p0 >> 2) + (uint8)(0, 1, 2, 3, 4, 5, 6, 7) * (width >> 2);
    float16 ph[4];
    clholo_phase_blocks16((uint16)(first, first + 1u), layer, frame0 + f, c, key_lo, key_hi,
                          ph);
#ifndef CLHOLO_LAYER_BLOCKS
    /* rows into lanes: a[j], co[j] = column col + j of the eight rows (8x8 transposes in
     * registers, transpose8.h) */
    float8 co[8];
    for (int l = 0; l < 8; ++l) {
        const uint p = p0 + (uint)l * width;
        if (n_channels == 1u) {
            co[l] = vload8(0, color + p);
        } else {
            __global const float *src = color + (size_t)p * n_channels + c;
            const uint n = n_channels;
            co[l] = (float8)(src[0], src[n], src[2 * n], src[3 * n], src[4 * n], src[5 * n],
                             src[6 * n], src[7 * n]);
        }
    }
    float8 *a = arow;
    CLHOLO_TRANSPOSE8_REAL(float8, a);
    CLHOLO_TRANSPOSE8_REAL(float8, co);
#endif
    for (int j = 0; j < 4; ++j) {
#ifdef CLHOLO_LAYER_BLOCKS
        const float16 amp = (float16)(co[j], co[j + 4]);
#else
        const float16 al = (float16)(a[j], a[j + 4]);
        const float16 amp = sqrt((float16)(co[j], co[j + 4]) * al);
#endif
        float16 sn, cs;
        clholo_sincos16_phase(ph[j], &sn, &cs);
#ifdef CLHOLO_NO_OCCLUSION
        const float16 keep = (float16)(1.0f);
#elif defined(CLHOLO_LAYER_BLOCKS)
        const float16 keep = (float16)(a[j], a[j + 4]);
#else
        const float16 keep = sqrt(1.0f - al);
#endif
        const float16 r = fma(keep, (float16)(re[j], re[j + 4]), amp * cs);
        const float16 i = fma(keep, (float16)(im[j], im[j + 4]), amp * sn);
        re[j] = r.lo; re[j + 4] = r.hi;
        im[j] = i.lo; im[j + 4] = i.hi;
    }
}
