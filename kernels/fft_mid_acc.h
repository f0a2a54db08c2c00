/* The running sum a FFT_MID_CB_SUMS mid callback adds to (fft_common.h): the mid step's extra
 * parameter and argument. Included by the kernel files, which come after the callbacks'
 * source (fft_common.h comes before it, so it cannot see FFT_MID_CB_SUMS). */
#ifndef CLHOLO_FFT_MID_ACC_H
#define CLHOLO_FFT_MID_ACC_H
#if FFT_MID_CB && defined(FFT_MID_CB_SUMS)
#define FFT_MID_ACC_PARAM , real4 *mid_acc
#define FFT_MID_ACC_ARG(acc) , (acc)
#else
#define FFT_MID_ACC_PARAM
#define FFT_MID_ACC_ARG(acc)
#endif
#endif
