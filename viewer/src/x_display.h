// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The X display the renderer hands to VTK. Opening it ourselves lets a missing display become a
// DisplayError; VTK 9.1 would print "bad X server connection" and abort() the process instead.
// Xlib is not included here: its macros (None, Status, Bool, ...) clash with VTK and user code.

namespace iwlomap::viewer::detail {

class XDisplay {
 public:
  /// Opens $DISPLAY; throws DisplayError (naming $DISPLAY and the xvfb-run command) on failure.
  [[nodiscard]] static XDisplay open();

  ~XDisplay();
  XDisplay(XDisplay&& other) noexcept;
  XDisplay& operator=(XDisplay&& other) noexcept;
  XDisplay(const XDisplay&) = delete;
  XDisplay& operator=(const XDisplay&) = delete;

  /// The Xlib `Display*`, as VTK's vtkRenderWindow::SetDisplayId(void*) takes it. Every VTK object
  /// using it must be destroyed before this XDisplay.
  [[nodiscard]] void* get() const { return display_; }

 private:
  explicit XDisplay(void* display) : display_(display) {}
  void* display_ = nullptr;
};

}  // namespace iwlomap::viewer::detail
