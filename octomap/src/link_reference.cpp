// SPDX-License-Identifier: BSD-3-Clause
// Compiled into every target that links iwlomap::octomap (an interface source of the target):
// the reference below makes the linker keep the OctoMap layer, whose start-up code registers the
// "OctoMap" backend with make_backend(), even when the program calls nothing of the layer
// directly. `used` keeps the reference through optimisation; the anonymous namespace keeps one
// copy per target from clashing with another's.

extern "C" bool iwlomap_octomap_backend_registered() noexcept;

namespace {
[[maybe_unused]] __attribute__((used)) bool (*const iwlomap_octomap_link_reference)() noexcept =
    &iwlomap_octomap_backend_registered;
}  // namespace
