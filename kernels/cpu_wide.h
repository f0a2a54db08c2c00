/* CPU_WIDE: 512-bit vectors in a function, where the CPU has them (AVX-512).
 *
 * Why: LLVM's x86 targets of AVX-512 CPUs (skylake-avx512, icelake-*: what PoCL builds for)
 * prefer 256-bit vectors, so every float16 of the FFT strips (their vt) became two ymm halves.
 * With the function's minimum legal vector width at 512 it runs in zmm registers: on a Zen 5
 * EPYC (Debian's PoCL 3.1, LLVM 15) the SLM-size render 1.17x faster, 1024^2 at pad 2 1.07x
 * (docs/benchmarks.md, 2026-11-27); on a Zen 4, which runs 512-bit operations in two
 * halves, 1.07x and 1.03x (2026-11-29). The same arithmetic, so the
 * same bits. Elsewhere (GPUs, CPUs without AVX-512) it is nothing. A build that defines
 * CLHOLO_CPU_256 keeps 256-bit halves (clholo.fft._CPU_WIDE = False, to compare). SGD's Adam
 * kernel, memory-bound, did not gain and does not use it. A kernel takes it from a prior
 * declaration, so that its definition keeps the plain form host/kernel_args.py reads. */
#ifndef CLHOLO_CPU_WIDE_H
#define CLHOLO_CPU_WIDE_H

#if defined(__AVX512F__) && !defined(CLHOLO_CPU_256)
#define CPU_WIDE __attribute__((min_vector_width(512)))
#else
#define CPU_WIDE
#endif

/* CLHOLO_PREFETCH(p, rw): a software prefetch of the cache line at p (rw 1: to be written)
 * where the kernel is compiled for a CPU (PoCL: its x86 or Arm target macros); nothing
 * elsewhere (GPU compilers, and Oclgrind, which knows no llvm.prefetch). For the CPU strips'
 * eight-row mid callbacks: eight rows of several arrays at once are more streams than a
 * CPU's prefetchers follow. */
#if defined(__SSE2__) || defined(__aarch64__)
#define CLHOLO_PREFETCH(p, rw) __builtin_prefetch((p), (rw), 3)
#else
#define CLHOLO_PREFETCH(p, rw)
#endif

#endif
