#pragma once
// A TCP proxy on 127.0.0.1 in front of a loopback server, for dropped connections and slow
// links: every accepted connection is forwarded to the target port on its own thread, its
// bytes are recorded both ways, and the one connection picked by the cut rule (the n-th
// whose request starts with a given prefix) is cut after K client-to-server bytes: both
// sockets are closed mid-stream, as a lost link would. An optional throttle bounds each
// direction of each connection to a rate. Used by the server and e2e tests and by
// bench/upload_resume.cpp (which includes it by path: no gtest in here).
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace polmap::test {

class TcpProxy {
 public:
  struct Options {
    int target_port = 0;
    /// The connection to cut: the cut_nth-th (1-based; 0 = none) whose first client bytes
    /// start with cut_prefix, after cut_after_bytes client-to-server bytes (headers count).
    int cut_nth = 0;
    std::string cut_prefix = "PATCH ";
    std::uint64_t cut_after_bytes = 0;
    /// Instead: the chosen connection carries the whole request and is cut when the server's
    /// answer begins (the server did the work; the client never hears of it).
    bool cut_before_answer = false;
    /// Bytes per second per direction and connection; 0 = unthrottled.
    double bytes_per_s = 0.0;
  };
  /// What one connection carried.
  struct Record {
    std::string upstream;    ///< client -> server bytes forwarded
    std::string downstream;  ///< server -> client bytes forwarded
    bool cut = false;        ///< cut by the rule
  };

  explicit TcpProxy(Options o) : opt_(std::move(o)) {
    listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    const int one = 1;
    ::setsockopt(listen_fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    sockaddr_in a = loopback(0);
    socklen_t len = sizeof a;
    if (::bind(listen_fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
        ::listen(listen_fd_, 64) != 0 ||
        ::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&a), &len) != 0) {
      ::close(listen_fd_);
      listen_fd_ = -1;
      return;
    }
    port_ = ntohs(a.sin_port);
    accept_thread_ = std::thread([this] { accept_loop(); });
  }
  ~TcpProxy() {
    stopping_ = true;
    if (listen_fd_ >= 0) ::shutdown(listen_fd_, SHUT_RDWR);
    if (accept_thread_.joinable()) accept_thread_.join();
    if (listen_fd_ >= 0) ::close(listen_fd_);
    for (auto& t : workers_) t.join();
  }
  TcpProxy(const TcpProxy&) = delete;
  TcpProxy& operator=(const TcpProxy&) = delete;

  /// The proxy's port (0 if it could not listen).
  [[nodiscard]] int port() const { return port_; }
  /// What every connection carried so far, in accept order.
  [[nodiscard]] std::vector<Record> records() const {
    std::lock_guard lock(mu_);
    std::vector<Record> out;
    for (const auto& r : records_) out.push_back(*r);
    return out;
  }

 private:
  static sockaddr_in loopback(int port) {
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<std::uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    return a;
  }

  void accept_loop() {
    for (;;) {
      pollfd p{listen_fd_, POLLIN, 0};
      if (::poll(&p, 1, 100) <= 0) {
        if (stopping_) return;
        continue;
      }
      const int client = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
      if (client < 0) {
        if (stopping_) return;
        continue;
      }
      auto rec = std::make_shared<Record>();
      {
        std::lock_guard lock(mu_);
        records_.push_back(rec);
      }
      workers_.emplace_back([this, client, rec] { pump(client, rec); });
    }
  }

  // Sleeps so that `done` bytes since `start` stay within the rate.
  void throttle(std::chrono::steady_clock::time_point start, std::uint64_t done) const {
    if (opt_.bytes_per_s <= 0.0) return;
    const auto due = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                 std::chrono::duration<double>(done / opt_.bytes_per_s));
    std::this_thread::sleep_until(due);
  }

  static bool send_all(int fd, const char* data, std::size_t n) {
    while (n > 0) {
      const ssize_t w = ::send(fd, data, n, MSG_NOSIGNAL);
      if (w <= 0) return false;
      data += w;
      n -= static_cast<std::size_t>(w);
    }
    return true;
  }

  void pump(int client, const std::shared_ptr<Record>& rec) {
    const int server = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    const sockaddr_in a = loopback(opt_.target_port);
    if (::connect(server, reinterpret_cast<const sockaddr*>(&a), sizeof a) != 0) {
      ::close(server);
      ::close(client);
      return;
    }
    const auto start = std::chrono::steady_clock::now();
    std::uint64_t up = 0, down = 0;
    bool decided = false, cut_this = false;
    // The throttle paces in pieces of at most 16 KiB, so a rate is kept within a piece.
    const std::size_t piece = opt_.bytes_per_s > 0.0 ? (16u << 10) : (256u << 10);
    std::vector<char> buf(piece);
    bool client_open = true, server_open = true;
    while (client_open || server_open) {
      if (stopping_) break;
      pollfd p[2] = {{client, static_cast<short>(client_open ? POLLIN : 0), 0},
                     {server, static_cast<short>(server_open ? POLLIN : 0), 0}};
      if (::poll(p, 2, 100) < 0) break;
      if (p[0].revents & (POLLIN | POLLHUP | POLLERR)) {
        std::size_t want = buf.size();
        const bool limit = cut_this && !opt_.cut_before_answer;
        if (limit) want = std::min<std::uint64_t>(want, opt_.cut_after_bytes - up);
        const ssize_t r = want == 0 ? 0 : ::recv(client, buf.data(), want, 0);
        if (r <= 0 && want != 0) {
          client_open = false;
          ::shutdown(server, SHUT_WR);
        } else {
          if (!decided && r > 0) {
            decided = true;
            const std::string head(buf.data(), static_cast<std::size_t>(r));
            if (opt_.cut_nth > 0 && head.starts_with(opt_.cut_prefix) &&
                ++matched_ == opt_.cut_nth) {
              cut_this = true;
            }
          }
          std::size_t n = static_cast<std::size_t>(std::max<ssize_t>(r, 0));
          if (cut_this && !opt_.cut_before_answer) {
            n = std::min<std::uint64_t>(n, opt_.cut_after_bytes - up);
          }
          if (n > 0) {
            throttle(start, up + n);
            if (!send_all(server, buf.data(), n)) break;
            std::lock_guard lock(mu_);
            rec->upstream.append(buf.data(), n);
          }
          up += n;
          if (cut_this && !opt_.cut_before_answer && up >= opt_.cut_after_bytes) {
            std::lock_guard lock(mu_);
            rec->cut = true;
            break;  // the link is lost: both sides closed below
          }
        }
      }
      if (p[1].revents & (POLLIN | POLLHUP | POLLERR)) {
        const ssize_t r = ::recv(server, buf.data(), buf.size(), 0);
        if (r > 0 && cut_this && opt_.cut_before_answer) {
          std::lock_guard lock(mu_);
          rec->cut = true;
          break;  // the answer is lost on the way
        }
        if (r <= 0) {
          server_open = false;
          ::shutdown(client, SHUT_WR);
        } else {
          throttle(start, down + static_cast<std::uint64_t>(r));
          if (!send_all(client, buf.data(), static_cast<std::size_t>(r))) break;
          down += static_cast<std::uint64_t>(r);
          std::lock_guard lock(mu_);
          rec->downstream.append(buf.data(), static_cast<std::size_t>(r));
        }
      }
    }
    ::close(server);
    ::close(client);
  }

  Options opt_;
  int listen_fd_ = -1;
  int port_ = 0;
  std::atomic<bool> stopping_{false};
  std::atomic<int> matched_{0};
  std::thread accept_thread_;
  std::vector<std::thread> workers_;  // joined on destruction (accept thread only appends)
  mutable std::mutex mu_;
  std::vector<std::shared_ptr<Record>> records_;
};

}  // namespace polmap::test
