// SPDX-License-Identifier: BSD-3-Clause
// make_backend(): the registry of backends by name. The RAM and Disk backends are built in; the
// layers register theirs (OctoMap).
#include "iwlomap/mapper_backend.h"

#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"

#include <algorithm>
#include <cctype>
#include <mutex>
#include <stdexcept>
#include <utility>

namespace iwlomap {

namespace {

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

struct Registry {
  Registry() {
    entries.emplace_back("RAM", [](double resolution, const BackendOptions&) {
      return std::unique_ptr<IMapperBackend>(std::make_unique<ProbabilityUpdater>(resolution));
    });
    entries.emplace_back("Disk", [](double resolution, const BackendOptions& o) {
      if (o.directory.empty())
        throw std::invalid_argument("iwlomap: the Disk backend needs BackendOptions::directory (the map directory), got an empty path");
      return std::unique_ptr<IMapperBackend>(
          std::make_unique<OutofcoreTileMapper>(o.directory, resolution, o.tile_size, o.cache_tiles));
    });
  }
  std::mutex mutex;
  std::vector<std::pair<std::string, BackendFactory>> entries;  // display name, factory
};

Registry& registry() {
  static Registry r;
  return r;
}

}  // namespace

void register_backend(const std::string& type, BackendFactory factory) {
  if (type.empty() || !factory) throw std::invalid_argument("iwlomap: register_backend needs a name and a factory");
  Registry& r = registry();
  std::lock_guard<std::mutex> lock(r.mutex);
  for (auto& [name, f] : r.entries) {
    if (lower(name) == lower(type)) {
      f = std::move(factory);
      return;
    }
  }
  r.entries.emplace_back(type, std::move(factory));
}

std::vector<std::string> available_backends() {
  Registry& r = registry();
  std::lock_guard<std::mutex> lock(r.mutex);
  std::vector<std::string> names;
  for (const auto& e : r.entries) names.push_back(e.first);
  return names;
}

std::unique_ptr<IMapperBackend> make_backend(const std::string& type, double resolution,
                                             const BackendOptions& options) {
  BackendFactory factory;
  std::string known;
  {
    Registry& r = registry();
    std::lock_guard<std::mutex> lock(r.mutex);
    for (const auto& [name, f] : r.entries) {
      if (lower(name) == lower(type)) factory = f;
      known += (known.empty() ? "" : ", ") + name;
    }
  }
  if (!factory)
    throw std::invalid_argument("iwlomap: unknown backend type '" + type + "' (available in this build: " + known +
                                ")");
  return factory(resolution, options);
}

}  // namespace iwlomap
