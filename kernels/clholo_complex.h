/* Complex arithmetic on float2/double2 (x = real, y = imaginary).
 *
 * REAL selects the precision of the including program: -DREAL=double builds the complex128
 * variant (the host only asks for it on devices with fp64). Plain a*b + c is written out
 * instead of fma(): PoCL turns fma() on vectors into out-of-line calls, while a*b + c
 * contracts to fused multiply-adds under -cl-mad-enable.
 */
#ifndef CLHOLO_COMPLEX_H
#define CLHOLO_COMPLEX_H

#ifndef REAL
#define REAL float
#endif

#if defined(CLHOLO_FP64) || defined(cl_khr_fp64)
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif

#define CONCAT_(a, b) a##b
#define CONCAT(a, b) CONCAT_(a, b)
#define REAL2 CONCAT(REAL, 2)
#define REAL4 CONCAT(REAL, 4)
#define REAL8 CONCAT(REAL, 8)
#define REAL16 CONCAT(REAL, 16)
/* the signed integer vector that select() and comparisons use with REAL4 */
#define REAL_INTV_float int4
#define REAL_INTV_double long4

static inline REAL2 cmul(REAL2 a, REAL2 b)
{
    return (REAL2)(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

static inline REAL2 cconj(REAL2 a) { return (REAL2)(a.x, -a.y); }

static inline REAL cabs2(REAL2 a) { return a.x * a.x + a.y * a.y; }

/* exp(i phi) */
static inline REAL2 cexpi(REAL phi)
{
    REAL c;
    REAL s = sincos(phi, &c);
    return (REAL2)(c, s);
}

#endif
