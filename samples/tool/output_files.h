// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The files one run of a command writes, handled as a set: every path is checked before any work
// (a known extension, an existing and writable folder, not a folder itself, not one of the run's
// inputs, also through a link), each file is written
// to a temporary in its own folder, and commit() renames the temporaries over the targets only
// after every writer succeeded. A run that fails (an exception before commit()) removes its
// temporaries, so it leaves no output at all, neither new nor torn; so does a run ended by
// SIGINT, SIGTERM or SIGHUP (a handler removes the temporaries, then the signal ends the process
// as it would have). A writer's error names the target and says when the file system is full.

#include <functional>
#include <initializer_list>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap::tool {

class Args;

class OutputFiles {
 public:
  /// The outputs of the run whose command line is \p args: its positional arguments and the
  /// values of its other options are the paths an output may not be.
  explicit OutputFiles(const Args& args);
  OutputFiles(const OutputFiles&) = delete;
  OutputFiles& operator=(const OutputFiles&) = delete;
  /// Removes the temporaries of an uncommitted run.
  ~OutputFiles();

  /// Adds \p path, given by \p option (named in errors), to the set and checks it now. Throws
  /// UsageError when its extension is not one of \p extensions (lower case, with the dot), it
  /// is given twice, or it is the same file as an input (a positional argument or another
  /// option's value: the same path, or the same file through a symbolic or hard link), and
  /// std::runtime_error naming the path when its folder does not exist or is not writable or the
  /// path is a folder.
  void add(const std::string& option, const std::string& path, std::initializer_list<const char*> extensions);

  /// Creates \p folder (with its parents) for outputs to go in, unless it exists; a run that does
  /// not commit removes it again (when empty), also when a signal ends it. One per run.
  void make_folder(const std::string& folder);

  /// The temporary to write \p path into: a hidden file in the same folder with the same
  /// extension (writers that choose the format by extension keep working). \p path must have
  /// been added.
  [[nodiscard]] std::string temporary(const std::string& path) const;

  /// Runs \p writer on the temporary of \p path; an exception it throws is rethrown as
  /// std::runtime_error with the temporary's name replaced by \p path in its message.
  void write(const std::string& path, const std::function<void(const std::string& file)>& writer) const;

  /// Renames every temporary that was written over its target. Throws std::runtime_error naming
  /// the path when a temporary is missing (its writer did not run) or a rename fails; the
  /// temporaries not yet renamed are removed.
  void commit();

  [[nodiscard]] const std::vector<std::string>& paths() const { return targets_; }

 private:
  std::vector<std::pair<std::string, std::string>> inputs_;  // (where it was given, path)
  std::vector<std::string> targets_;
  std::vector<std::string> temporaries_;
  std::vector<int> slots_;  // of each temporary in the signal handler's list, -1 when none
  std::string made_folder_;
  int folder_slot_ = -1;
  bool committed_ = false;
};

}  // namespace iwlomap::tool
