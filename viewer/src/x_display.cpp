// SPDX-License-Identifier: BSD-3-Clause
#include "x_display.h"

#include "iwlomap/viewer/snapshot_renderer.h"

#include <X11/Xlib.h>

#include <cstdlib>
#include <string>
#include <utility>

namespace iwlomap::viewer::detail {

XDisplay XDisplay::open() {
  const char* name = std::getenv("DISPLAY");
  Display* display = XOpenDisplay(nullptr);
  if (display == nullptr) {
    const std::string which = (name == nullptr || *name == '\0') ? std::string("(DISPLAY is not set)")
                                                                 : "DISPLAY='" + std::string(name) + "'";
    throw DisplayError(
        "iwlomap viewer: cannot open an X display " + which +
        ". VTK 9.1 renders off-screen only through an X server; on a machine without a screen run the "
        "program under a virtual one: xvfb-run -a -s \"-screen 0 1280x1024x24 -noreset\" <command>");
  }
  return XDisplay(display);
}

XDisplay::~XDisplay() {
  if (display_ != nullptr) XCloseDisplay(static_cast<Display*>(display_));
}

XDisplay::XDisplay(XDisplay&& other) noexcept : display_(std::exchange(other.display_, nullptr)) {}

XDisplay& XDisplay::operator=(XDisplay&& other) noexcept {
  if (this != &other) {
    if (display_ != nullptr) XCloseDisplay(static_cast<Display*>(display_));
    display_ = std::exchange(other.display_, nullptr);
  }
  return *this;
}

}  // namespace iwlomap::viewer::detail
