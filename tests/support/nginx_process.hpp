#pragma once
// A real nginx for tests (tools/setup installs it): configured by one of our render
// scripts into a temporary prefix and run in the foreground as the test's child.
#include <sys/wait.h>

#include <csignal>
#include <functional>
#include <sstream>
#include <string>
#include <vector>

#include "mapping_service/server/net_helpers.hpp"

// Last: httplib pulls in <resolv.h>, whose `_res` macro breaks Eigen templates.
#include <httplib.h>

namespace polmap::mapping::testing {

/// The nginx executable: PATH, then where Debian puts it (not on a user's PATH).
inline std::string nginx_executable() {
  std::vector<std::filesystem::path> dirs;
  if (const char* path = std::getenv("PATH")) {
    std::stringstream s(path);
    for (std::string d; std::getline(s, d, ':');) dirs.emplace_back(d);
  }
  dirs.emplace_back("/usr/sbin");
  dirs.emplace_back("/usr/local/sbin");
  for (const auto& d : dirs) {
    if (::access((d / "nginx").c_str(), X_OK) == 0) return (d / "nginx").string();
  }
  return {};
}

/// nginx configured by a render command into `prefix` and started in the foreground
/// (`daemon off`, our child), listening on a free loopback port. Stopped on destruction.
/// `render(port)` is the command line that writes prefix/nginx.conf for that port.
class Nginx {
 public:
  Nginx(const std::filesystem::path& prefix,
        const std::function<std::vector<std::string>(int port)>& render_command)
      : prefix_(prefix) {
    const std::string nginx = nginx_executable();
    if (nginx.empty()) {
      ADD_FAILURE() << "nginx is not installed (tools/setup installs it)";
      return;
    }
    // The port is free a moment before nginx binds it; another process may win the race.
    for (int attempt = 0; attempt < 3 && pid_ < 0; ++attempt) {
      port_ = free_loopback_port();
      const std::vector<std::string> render = render_command(port_);
      const int rc = run_process(render, prefix_.parent_path() / "render.log");
      if (rc != 0) {
        ADD_FAILURE() << render.front()
                      << " failed: " << read_text(prefix_.parent_path() / "render.log");
        return;
      }
      const auto conf = prefix_ / "nginx.conf";
      const pid_t pid = spawn_process({nginx, "-p", prefix_.string(), "-c", conf.string(), "-e",
                                       error_log().string(), "-g", "daemon off;"},
                                      prefix_.parent_path() / "nginx.out");
      if (pid < 0) break;
      // Accepting, or exited (the port was taken, or the configuration is bad).
      for (int i = 0; i < 200; ++i) {
        int status = 0;
        if (::waitpid(pid, &status, WNOHANG) == pid) break;
        const int fd = connect_loopback(port_);
        if (fd >= 0) {
          ::close(fd);
          pid_ = pid;
          break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
      }
    }
    if (pid_ < 0) ADD_FAILURE() << "nginx did not start: " << read_text(error_log());
  }
  ~Nginx() {
    if (pid_ < 0) return;
    ::kill(pid_, SIGTERM);  // fast shutdown of the master and its workers
    for (int i = 0; i < 200; ++i) {
      int status = 0;
      if (::waitpid(pid_, &status, WNOHANG) == pid_) return;
      std::this_thread::sleep_for(std::chrono::milliseconds(25));
    }
    ::kill(pid_, SIGKILL);
    ::waitpid(pid_, nullptr, 0);
  }
  Nginx(const Nginx&) = delete;
  Nginx& operator=(const Nginx&) = delete;

  [[nodiscard]] bool running() const { return pid_ > 0; }
  [[nodiscard]] int port() const { return port_; }
  [[nodiscard]] std::filesystem::path error_log() const { return prefix_ / "logs/error.log"; }
  [[nodiscard]] std::string access_log() const { return read_text(prefix_ / "logs/access.log"); }
  [[nodiscard]] httplib::Client client() const {
    httplib::Client c("127.0.0.1", port_);
    c.set_read_timeout(120, 0);
    c.set_write_timeout(120, 0);
    return c;
  }

 private:
  std::filesystem::path prefix_;
  int port_ = -1;
  pid_t pid_ = -1;
};

}  // namespace polmap::mapping::testing
