// SPDX-License-Identifier: BSD-3-Clause
#include "integrate/batch_apply.h"

#include <memory>

namespace iwlomap::detail {

BatchScratch& batch_scratch() {
  // On the heap (its arrays take about 330 KiB), allocated on a thread's first batch.
  thread_local const std::unique_ptr<BatchScratch> scratch = std::make_unique<BatchScratch>();
  return *scratch;
}

}  // namespace iwlomap::detail
