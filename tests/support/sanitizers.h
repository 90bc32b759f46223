// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// IWLOMAP_TEST_UNDER_SANITIZER is 1 in a build instrumented by AddressSanitizer or ThreadSanitizer,
// with GCC (__SANITIZE_*__) or Clang (__has_feature), else 0.

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define IWLOMAP_TEST_UNDER_SANITIZER 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define IWLOMAP_TEST_UNDER_SANITIZER 1
#endif
#endif
#ifndef IWLOMAP_TEST_UNDER_SANITIZER
#define IWLOMAP_TEST_UNDER_SANITIZER 0
#endif
