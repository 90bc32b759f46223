// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Repetitions of a test that repeats the same code on many random inputs: the full count in a
// build without sanitizers, fewer under AddressSanitizer, UBSan or ThreadSanitizer (the test
// command's sanitizer stages define IWLOMAP_TEST_UNDER_SANITIZER through IWLOMAP_SANITIZE and
// IWLOMAP_TSAN). Every repetition runs the same code; what a sanitizer looks for (a bad access, a
// race) shows in the first few, while rates and rare cases are the optimised build's to count,
// at several times the speed.

namespace iwlomap::test_support {

[[nodiscard]] constexpr int repetitions(int full, int under_sanitizer) noexcept {
#ifdef IWLOMAP_TEST_UNDER_SANITIZER
  (void)full;
  return under_sanitizer;
#else
  (void)under_sanitizer;
  return full;
#endif
}

}  // namespace iwlomap::test_support
