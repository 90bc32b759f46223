// SPDX-License-Identifier: BSD-3-Clause
#include "console_capture.h"

#include <unistd.h>

#include <iostream>

namespace iwlomap::detail {

namespace {

std::mutex& capture_mutex() {
  static std::mutex m;
  return m;
}

void flush_all() {
  std::cout.flush();
  std::cerr.flush();
  std::clog.flush();
  std::fflush(stdout);
  std::fflush(stderr);
}

void put_back(int saved, int fd) {
  if (saved >= 0) {
    ::dup2(saved, fd);
    ::close(saved);
  } else {
    ::close(fd);  // the descriptor was closed before the capture: close it again
  }
}

}  // namespace

ConsoleCapture::ConsoleCapture() : lock_(capture_mutex()) {
  flush_all();
  sink_ = std::tmpfile();
  if (sink_ == nullptr) return;  // nowhere to capture: OctoMap's messages stay visible
  saved_out_ = ::dup(STDOUT_FILENO);
  saved_err_ = ::dup(STDERR_FILENO);
  ::dup2(::fileno(sink_), STDOUT_FILENO);
  ::dup2(::fileno(sink_), STDERR_FILENO);
  redirected_ = true;
}

ConsoleCapture::~ConsoleCapture() {
  restore();
  if (sink_ != nullptr) std::fclose(sink_);
}

std::string ConsoleCapture::finish() {
  restore();
  if (sink_ == nullptr) return {};
  std::string text(2048, '\0');
  std::rewind(sink_);
  text.resize(std::fread(text.data(), 1, text.size(), sink_));
  for (char& c : text)
    if (c == '\n' || c == '\r') c = ' ';
  const auto first = text.find_first_not_of(' ');
  if (first == std::string::npos) return {};
  const auto last = text.find_last_not_of(' ');
  return text.substr(first, last - first + 1);
}

void ConsoleCapture::restore() {
  if (!redirected_) return;
  flush_all();
  put_back(saved_out_, STDOUT_FILENO);
  put_back(saved_err_, STDERR_FILENO);
  redirected_ = false;
}

std::string octomap_said(const std::string& text) { return text.empty() ? std::string() : " (OctoMap: " + text + ")"; }

}  // namespace iwlomap::detail
