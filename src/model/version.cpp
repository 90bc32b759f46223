// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/version.h"

namespace iwlomap {

const char* version() noexcept { return IWLOMAP_VERSION_STRING; }

}  // namespace iwlomap
