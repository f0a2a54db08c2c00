/* In-register transpose of 8 x 8 complex numbers held in eight 16-wide vectors of type TY
 * (float16 or double16: eight interleaved complex numbers each): afterwards v[m] holds complex
 * number m of every input vector. Butterfly swaps of off-diagonal blocks of 1, 2 and 4
 * complex numbers; constant swizzles only. The CPU FFT strips (fft_cpu.cl: rows gathered into
 * lanes from whole-cache-line loads) and the CPU composite (composite_cpu.cl) use it. */
#ifndef CLHOLO_TRANSPOSE8_H
#define CLHOLO_TRANSPOSE8_H

#define CLHOLO_TSWAP1(TY, a, b) {                                                         \
        TY t_ = (TY)((a).s01, (b).s01, (a).s45, (b).s45, (a).s89, (b).s89, (a).scd, (b).scd); \
        (b) = (TY)((a).s23, (b).s23, (a).s67, (b).s67, (a).sab, (b).sab, (a).sef, (b).sef);  \
        (a) = t_; }
#define CLHOLO_TSWAP2(TY, a, b) {                                                         \
        TY t_ = (TY)((a).s0123, (b).s0123, (a).s89ab, (b).s89ab);                         \
        (b) = (TY)((a).s4567, (b).s4567, (a).scdef, (b).scdef); (a) = t_; }
#define CLHOLO_TSWAP4(TY, a, b) { TY t_ = (TY)((a).lo, (b).lo); (b) = (TY)((a).hi, (b).hi); \
                                  (a) = t_; }
#define CLHOLO_TRANSPOSE8(TY, v) {                                                        \
        CLHOLO_TSWAP1(TY, v[0], v[1]); CLHOLO_TSWAP1(TY, v[2], v[3]);                     \
        CLHOLO_TSWAP1(TY, v[4], v[5]); CLHOLO_TSWAP1(TY, v[6], v[7]);                     \
        CLHOLO_TSWAP2(TY, v[0], v[2]); CLHOLO_TSWAP2(TY, v[1], v[3]);                     \
        CLHOLO_TSWAP2(TY, v[4], v[6]); CLHOLO_TSWAP2(TY, v[5], v[7]);                     \
        CLHOLO_TSWAP4(TY, v[0], v[4]); CLHOLO_TSWAP4(TY, v[1], v[5]);                     \
        CLHOLO_TSWAP4(TY, v[2], v[6]); CLHOLO_TSWAP4(TY, v[3], v[7]); }

/* The same for 8 x 8 real numbers in eight 8-wide vectors (float8): afterwards v[m] holds
 * element m of every input vector. */
#define CLHOLO_RSWAP1(TY, a, b) {                                                         \
        TY t_ = (TY)((a).s0, (b).s0, (a).s2, (b).s2, (a).s4, (b).s4, (a).s6, (b).s6);     \
        (b) = (TY)((a).s1, (b).s1, (a).s3, (b).s3, (a).s5, (b).s5, (a).s7, (b).s7);       \
        (a) = t_; }
#define CLHOLO_RSWAP2(TY, a, b) {                                                         \
        TY t_ = (TY)((a).s01, (b).s01, (a).s45, (b).s45);                                 \
        (b) = (TY)((a).s23, (b).s23, (a).s67, (b).s67); (a) = t_; }
#define CLHOLO_RSWAP4(TY, a, b) { TY t_ = (TY)((a).lo, (b).lo); (b) = (TY)((a).hi, (b).hi); \
                                  (a) = t_; }
#define CLHOLO_TRANSPOSE8_REAL(TY, v) {                                                   \
        CLHOLO_RSWAP1(TY, v[0], v[1]); CLHOLO_RSWAP1(TY, v[2], v[3]);                     \
        CLHOLO_RSWAP1(TY, v[4], v[5]); CLHOLO_RSWAP1(TY, v[6], v[7]);                     \
        CLHOLO_RSWAP2(TY, v[0], v[2]); CLHOLO_RSWAP2(TY, v[1], v[3]);                     \
        CLHOLO_RSWAP2(TY, v[4], v[6]); CLHOLO_RSWAP2(TY, v[5], v[7]);                     \
        CLHOLO_RSWAP4(TY, v[0], v[4]); CLHOLO_RSWAP4(TY, v[1], v[5]);                     \
        CLHOLO_RSWAP4(TY, v[2], v[6]); CLHOLO_RSWAP4(TY, v[3], v[7]); }

#endif
