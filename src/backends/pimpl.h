// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The backends keep their state behind a pointer to an implementation, so that moving a backend
// is cheap and its header needs no internal type. A moved-from backend has none.

#include <memory>
#include <stdexcept>
#include <string>

namespace iwlomap::detail {

/// *impl, or std::logic_error naming \p type when \p impl is empty (the backend was moved from).
template <class Impl>
Impl& checked_impl(const std::unique_ptr<Impl>& impl, const char* type) {
  if (!impl) throw std::logic_error(std::string("iwlomap: ") + type + " used after it was moved from");
  return *impl;
}

}  // namespace iwlomap::detail

/// Defines a backend's destructor and moves (defaulted where Impl is complete) and its impl()
/// accessors (checked_impl()), the same for every backend: use once in its .cpp, at namespace
/// iwlomap scope.
#define IWLOMAP_DEFINE_PIMPL_MEMBERS(Class)                                                         \
  Class::~Class() = default;                                                                      \
  Class::Class(Class&&) noexcept = default;                                                       \
  Class& Class::operator=(Class&&) noexcept = default;                                            \
  Class::Impl& Class::impl() { return detail::checked_impl(impl_, #Class); }                      \
  const Class::Impl& Class::impl() const { return detail::checked_impl(impl_, #Class); }
