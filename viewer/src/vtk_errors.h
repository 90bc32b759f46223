// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Turns VTK's error reports into exceptions. vtkErrorMacro prints to stderr and carries on; an
// object with an ErrorEvent observer hands the message to the observer instead, so the renderer
// can throw it with the rest of the context.

#include <vtkCommand.h>
#include <vtkObject.h>

#include <string>

namespace iwlomap::viewer::detail {

class VtkErrorCollector : public vtkCommand {
 public:
  static VtkErrorCollector* New() { return new VtkErrorCollector; }

  void Execute(vtkObject* caller, unsigned long event, void* call_data) override {
    (void)caller;
    (void)event;
    if (!messages_.empty()) messages_ += "; ";
    messages_ += call_data != nullptr ? essence(static_cast<const char*>(call_data)) : "unknown VTK error";
  }

  /// "ERROR: In file.cxx, line 254\nvtkPNGWriter (0x55...): Unable to open file x\n\n" -> "Unable
  /// to open file x": the source location and object address mean nothing to our users.
  [[nodiscard]] static std::string essence(std::string m) {
    if (const auto nl = m.find('\n'); m.rfind("ERROR: In ", 0) == 0 && nl != std::string::npos) m.erase(0, nl + 1);
    if (const auto tag = m.find("): "); tag != std::string::npos && m.find('\n') > tag) m.erase(0, tag + 3);
    while (!m.empty() && (m.back() == '\n' || m.back() == ' ')) m.pop_back();
    return m;
  }

  /// Observes the ErrorEvent of \p object.
  void watch(vtkObject* object) { object->AddObserver(vtkCommand::ErrorEvent, this); }

  [[nodiscard]] bool failed() const { return !messages_.empty(); }
  [[nodiscard]] const std::string& messages() const { return messages_; }

 private:
  VtkErrorCollector() = default;
  std::string messages_;
};

}  // namespace iwlomap::viewer::detail
