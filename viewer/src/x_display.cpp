// SPDX-License-Identifier: BSD-3-Clause
#include "x_display.h"

#include "iwlomap/viewer/snapshot_renderer.h"

#include <X11/Xlib.h>

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap::viewer::detail {

namespace {

// A virtual X server of this process's own, started the first time a render finds no display
// and stopped when the process ends (the server also dies with the process if it is killed).
// Xvfb picks a free display number itself (-displayfd) and reports it when it accepts clients,
// so there is no guessing and no race with other servers.
class PrivateXServer {
 public:
  // The display name (":N") of the running server, or "" with \p why set.
  static std::string display(std::string& why) {
    static std::mutex mutex;
    static std::unique_ptr<PrivateXServer> server;
    static std::string failure;
    const std::lock_guard<std::mutex> lock(mutex);
    if (!server && failure.empty()) {
      auto started = std::unique_ptr<PrivateXServer>(new PrivateXServer());
      if (started->name_.empty())
        failure = started->why_;
      else
        server = std::move(started);
    }
    why = failure;
    return server ? server->name_ : std::string();
  }

  ~PrivateXServer() {
    if (pid_ <= 0) return;
    kill(pid_, SIGTERM);
    int status = 0;
    while (waitpid(pid_, &status, 0) < 0 && errno == EINTR) {
    }
  }
  PrivateXServer(const PrivateXServer&) = delete;
  PrivateXServer& operator=(const PrivateXServer&) = delete;

 private:
  PrivateXServer() {
    const char* configured = std::getenv("IWLOMAP_XVFB");
    const std::string program = configured != nullptr && *configured != '\0' ? configured : "Xvfb";
    int fds[2];
    if (pipe2(fds, O_CLOEXEC) != 0) {
      why_ = std::string("pipe: ") + std::strerror(errno);
      return;
    }
    // Everything the child needs is made before fork(): after it, only async-signal-safe calls.
    std::vector<std::string> args = {program, "-displayfd", std::to_string(fds[1]), "-screen", "0", "1280x1024x24",
                                     "-nolisten", "tcp", "-noreset"};
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    const pid_t parent = getpid();
    const pid_t pid = fork();
    if (pid < 0) {
      why_ = std::string("fork: ") + std::strerror(errno);
      close(fds[0]);
      close(fds[1]);
      return;
    }
    if (pid == 0) {
      // The child: dies with the parent; stdout/stderr quiet; the write end of the pipe kept open.
      prctl(PR_SET_PDEATHSIG, SIGTERM);
      if (getppid() != parent) _exit(1);
      const int null = open("/dev/null", O_RDWR);
      if (null >= 0) {
        dup2(null, 0);
        dup2(null, 1);
        dup2(null, 2);
      }
      fcntl(fds[1], F_SETFD, 0);  // the pipe's write end survives exec
      execvp(argv[0], argv.data());
      _exit(127);
    }
    pid_ = pid;
    close(fds[1]);
    // Xvfb writes the display number and a newline once it accepts clients.
    // The pipe closes without a number when the child exits (exec failed, or Xvfb gave up).
    std::string number;
    bool timed_out = false;
    pollfd p{fds[0], POLLIN, 0};
    for (;;) {
      const int ready = poll(&p, 1, 20000);
      if (ready < 0 && errno == EINTR) continue;
      if (ready == 0) timed_out = true;
      char c = 0;
      if (ready <= 0 || read(fds[0], &c, 1) != 1 || c == '\n') break;
      number += c;
    }
    close(fds[0]);
    if (number.empty() || number.find_first_not_of("0123456789") != std::string::npos) {
      if (timed_out) kill(pid_, SIGKILL);
      int status = 0;
      while (waitpid(pid_, &status, 0) < 0 && errno == EINTR) {
      }
      pid_ = -1;
      if (timed_out)
        why_ = "'" + program + "' did not report a display within 20 s";
      else if (WIFEXITED(status) && WEXITSTATUS(status) == 127)
        why_ = "'" + program + "' was not found (Debian: apt-get install xvfb)";
      else
        why_ = "'" + program + "' stopped without reporting a display";
      return;
    }
    name_ = ":" + number;
  }

  pid_t pid_ = -1;
  std::string name_;
  std::string why_;
};

}  // namespace

XDisplay XDisplay::open() {
  const char* name = std::getenv("DISPLAY");
  if (Display* display = XOpenDisplay(nullptr)) return XDisplay(display);
  const std::string which =
      (name == nullptr || *name == '\0') ? std::string("DISPLAY is not set") : "DISPLAY='" + std::string(name) + "'";
  std::string why;
  const std::string private_display = PrivateXServer::display(why);
  if (!private_display.empty()) {
    if (Display* display = XOpenDisplay(private_display.c_str())) return XDisplay(display);
    why = "cannot open its display " + private_display;
  }
  throw DisplayError("iwlomap viewer: no X display to render with (" + which +
                     ") and no private virtual X server: " + why +
                     ". VTK 9.1 renders off-screen only through an X server; install Xvfb, or run the program "
                     "under one: xvfb-run -a -s \"-screen 0 1280x1024x24 -noreset\" <command>");
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
