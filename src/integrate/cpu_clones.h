// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Functions with copies compiled for the x86-64-v4 (AVX-512) and x86-64-v3 (AVX2, BMI2, POPCNT)
// levels beside the baseline one, chosen at load time on x86-64: their vectorised loops run 4 or
// 8 doubles wide. Every copy gives the same results (integer arithmetic, and the library's
// floating-point flags forbid contraction into fused multiply-adds).
//
// Only leaf passes that cannot fail carry copies, and they are noexcept: GCC 12 compiles a call
// through the loader's choice as one that cannot throw, so an exception leaving a copy would end
// the program wherever the caller has something to clean up. Not under ThreadSanitizer: the
// loader runs the chooser (an ifunc resolver) before the sanitizer's runtime is up, and an
// instrumented chooser crashes the program at start.
#if defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define IWLOMAP_NO_CLONES 1
#endif
#endif
#if defined(__SANITIZE_THREAD__)
#define IWLOMAP_NO_CLONES 1
#endif
// Not with Clang: it takes the attribute only on a function's first declaration, and the class
// members that carry it are declared in headers without it; Clang builds run the baseline copy.
#if defined(__clang__)
#define IWLOMAP_NO_CLONES 1
#endif
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__)) && !defined(IWLOMAP_NO_CLONES)
#define IWLOMAP_CPU_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define IWLOMAP_CPU_CLONES
#endif
