#pragma once
// Helpers of the exposure tests (nginx front, TLS): child processes, throw-away
// certificates, free ports and slow-loris sockets.
#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

extern char** environ;

namespace polmap::mapping::testing {

/// Starts argv[0] (looked up in PATH) with stdout and stderr appended to `output`;
/// returns its pid (-1 when it cannot be started).
inline pid_t spawn_process(const std::vector<std::string>& argv,
                           const std::filesystem::path& output) {
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, output.c_str(), O_WRONLY | O_CREAT | O_APPEND,
                                   0644);
  posix_spawn_file_actions_adddup2(&actions, 1, 2);
  posix_spawn_file_actions_addclose(&actions, 0);
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  pid_t pid = -1;
  const int rc = posix_spawnp(&pid, args[0], &actions, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  return rc == 0 ? pid : -1;
}

/// Runs argv to completion (output appended to `output`); returns its exit status
/// (-1 when it could not be started or did not exit normally).
inline int run_process(const std::vector<std::string>& argv, const std::filesystem::path& output) {
  const pid_t pid = spawn_process(argv, output);
  if (pid < 0) return -1;
  int status = 0;
  if (::waitpid(pid, &status, 0) != pid || !WIFEXITED(status)) return -1;
  return WEXITSTATUS(status);
}

inline std::string read_text(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

/// A self-signed certificate (P-256, one day) and its unencrypted key, written by the
/// openssl command line tool (tools/setup installs it).
struct SelfSignedCert {
  std::filesystem::path cert;
  std::filesystem::path key;
};
inline SelfSignedCert make_self_signed_cert(const std::filesystem::path& dir,
                                            const std::string& name,
                                            const std::string& subject_alt_names) {
  SelfSignedCert c{dir / (name + ".crt"), dir / (name + ".key")};
  const auto log = dir / "openssl.log";
  const int rc = run_process(
      {"openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
       "-nodes", "-days", "1", "-subj", "/CN=" + name, "-addext",
       "subjectAltName=" + subject_alt_names, "-keyout", c.key.string(), "-out", c.cert.string()},
      log);
  EXPECT_EQ(rc, 0) << "openssl req failed: " << read_text(log);
  return c;
}

/// A TCP port on 127.0.0.1 that was free a moment ago (bound to port 0, then released).
inline int free_loopback_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof addr;
  int port = -1;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0 &&
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len) == 0) {
    port = ntohs(addr.sin_port);
  }
  ::close(fd);
  return port;
}

/// A blocking connection to 127.0.0.1:port (-1 if refused).
inline int connect_loopback(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

/// Slow-loris clients: `count` sockets that each send the start of a request header and
/// then one more header byte per second, forever. A socket the server closes is reopened
/// (counted in reopened()), so the pressure stays on.
class SlowLoris {
 public:
  SlowLoris(int port, int count) : port_(port), fds_(static_cast<std::size_t>(count), -1) {
    for (int& fd : fds_) {
      fd = open_one();
      if (fd >= 0) ++open_;
    }
    thread_ = std::thread([this] { drip(); });
  }
  ~SlowLoris() { stop(); }
  SlowLoris(const SlowLoris&) = delete;
  SlowLoris& operator=(const SlowLoris&) = delete;

  void stop() {
    stopping_ = true;
    if (thread_.joinable()) thread_.join();
    for (int& fd : fds_) {
      if (fd >= 0) ::close(fd);
      fd = -1;
    }
  }
  /// Sockets connected right now.
  [[nodiscard]] int open() const { return open_; }
  [[nodiscard]] int reopened() const { return reopened_; }

 private:
  int open_one() {
    const int fd = connect_loopback(port_);
    if (fd < 0) return -1;
    const std::string start = "GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ";
    if (::send(fd, start.data(), start.size(), MSG_NOSIGNAL) !=
        static_cast<ssize_t>(start.size())) {
      ::close(fd);
      return -1;
    }
    return fd;
  }
  void drip() {
    while (!stopping_) {
      int open = 0;
      for (int& fd : fds_) {
        // The server gave up on this socket when it answered (e.g. 408) or closed it.
        char peek = 0;
        const bool closed = fd >= 0 && ::recv(fd, &peek, 1, MSG_PEEK | MSG_DONTWAIT) >= 0;
        if (fd >= 0 && !closed && ::send(fd, "a", 1, MSG_NOSIGNAL | MSG_DONTWAIT) == 1) {
          ++open;
          continue;
        }
        if (fd >= 0) {
          ::close(fd);
          ++reopened_;
        }
        fd = open_one();
        if (fd >= 0) ++open;
      }
      open_ = open;
      for (int i = 0; i < 10 && !stopping_; ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
      }
    }
  }

  int port_;
  std::vector<int> fds_;
  std::atomic<bool> stopping_{false};
  std::atomic<int> open_{0};
  std::atomic<int> reopened_{0};
  std::thread thread_;
};

}  // namespace polmap::mapping::testing
