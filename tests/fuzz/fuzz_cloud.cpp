// SPDX-License-Identifier: BSD-3-Clause
// Fuzz target: the tool's cloud reading path (header check, then PCL's reader, then the field
// conversion), on .pcd and .ply files. The first byte of the input picks the extension; the rest
// is the file. Every input must end in a cloud or in std::runtime_error naming the file: a crash,
// a hang (-timeout) or a huge allocation (-malloc_limit_mb) is a finding.

#include "cloud_io.h"

#include <pcl/console/print.h>

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <stdexcept>
#include <string>

namespace {

std::string path_for(bool ply) {
  const char* dir = std::getenv("TMPDIR");
  return std::string(dir != nullptr ? dir : "/tmp") + "/iwlomap_fuzz_cloud_" + std::to_string(getpid()) +
         (ply ? ".ply" : ".pcd");
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS);  // as the tool: no reader chatter
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  const bool ply = (data[0] & 1) != 0;
  const std::string path = path_for(ply);
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr) return 0;
  const bool written = std::fwrite(data + 1, 1, size - 1, f) == size - 1;
  std::fclose(f);
  if (!written) return 0;
  try {
    const iwlomap::tool::LoadedCloud cloud = iwlomap::tool::load_cloud(path, 255.0f);
    (void)cloud;
  } catch (const std::runtime_error&) {
    // The expected answer to a bad file.
  }
  std::remove(path.c_str());
  return 0;
}
