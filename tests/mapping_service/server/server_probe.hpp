#pragma once
// Probes for the server's hostile-input and full-disk tests: one raw HTTP exchange on its
// own connection (timed), a digest of everything the store holds, and the process's
// resident memory.
#include <arpa/inet.h>
#include <malloc.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>

#include "polmap/mapping_service/sqlite_store.hpp"

namespace polmap::mapping::testing {

/// What came back for one raw request.
struct RawReply {
  int status = 0;          ///< 0: no parsable status line (connection refused, timeout, reset)
  std::string bytes;       ///< everything the server sent
  double seconds = 0.0;    ///< from connect to the end of the reply
  bool timed_out = false;  ///< the server neither finished nor closed within the timeout
  [[nodiscard]] std::string body() const {
    const auto p = bytes.find("\r\n\r\n");
    return p == std::string::npos ? std::string() : bytes.substr(p + 4);
  }
};

/// Sends `request` on a new loopback connection, then reads until the server closes the
/// connection or has sent a complete response (status line, headers and Content-Length
/// bytes of body), or until `timeout_s` passes. Requests should say `Connection: close`.
inline RawReply raw_request(int port, const std::string& request, double timeout_s = 30.0) {
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  RawReply r;
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (fd < 0 || ::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    if (fd >= 0) ::close(fd);
    return r;
  }
  const auto deadline = t0 + std::chrono::duration<double>(timeout_s);
  auto ms_left = [&] {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    return static_cast<int>(std::max<long long>(0, left.count()));
  };
  // Send while reading: a server that answers before the body (a refusal) stops the send.
  std::size_t off = 0;
  bool done = false;
  char buf[16384];
  while (!done) {
    pollfd p{fd, static_cast<short>(POLLIN | (off < request.size() ? POLLOUT : 0)), 0};
    const int ready = ::poll(&p, 1, std::min(ms_left(), 1000));
    if (ms_left() == 0) {
      r.timed_out = true;
      break;
    }
    if (ready <= 0) continue;
    if ((p.revents & POLLOUT) != 0 && off < request.size()) {
      const ssize_t w =
          ::send(fd, request.data() + off, std::min<std::size_t>(request.size() - off, 1 << 20),
                 MSG_NOSIGNAL | MSG_DONTWAIT);
      if (w > 0) {
        off += static_cast<std::size_t>(w);
      } else if (w < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
        off = request.size();  // the server closed its side: read what it said
      }
    }
    if ((p.revents & (POLLIN | POLLHUP | POLLERR)) == 0) continue;
    const ssize_t n = ::recv(fd, buf, sizeof buf, MSG_DONTWAIT);
    if (n == 0) break;
    if (n < 0) {
      if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) continue;
      break;  // reset
    }
    r.bytes.append(buf, static_cast<std::size_t>(n));
    const auto end = r.bytes.find("\r\n\r\n");
    if (end == std::string::npos) continue;
    const auto cl = r.bytes.find("\r\nContent-Length: ");
    if (cl != std::string::npos && cl < end) {
      const std::size_t len = std::strtoull(r.bytes.c_str() + cl + 18, nullptr, 10);
      done = r.bytes.size() >= end + 4 + len;
    }
  }
  ::close(fd);
  r.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  if (r.bytes.size() >= 12 && r.bytes.starts_with("HTTP/1.")) {
    r.status = std::atoi(r.bytes.substr(9, 3).c_str());
  }
  return r;
}

/// Everything the store holds, as text: drive rows (id, hash, counts), map versions
/// (number, status, current), localization runs, and every file below the drive store with
/// its size.
inline std::string store_digest(const SqliteMapStore& store) {
  std::string s;
  for (const DriveRecord& d : store.list_drives()) {
    s += "drive " + d.drive_id + " " + d.content_hash + " " + std::to_string(d.num_points) + " " +
         std::to_string(d.num_lines) + "\n";
  }
  for (const MapVersionInfo& v : store.list_map_versions()) {
    s += "version " + std::to_string(v.version) + " " + std::string(to_string(v.status)) +
         (v.current ? " current" : "") + "\n";
  }
  for (const LocalizationRunRecord& r : store.list_localization_runs(1u << 20)) {
    s += "run " + std::to_string(r.id) + " " + std::to_string(r.samples) + "\n";
  }
  std::set<std::string> files;  // directory order is not stable
  for (const auto& e : std::filesystem::recursive_directory_iterator(store.drive_store_dir())) {
    std::string line = std::filesystem::relative(e.path(), store.drive_store_dir()).string();
    if (e.is_regular_file()) line += " " + std::to_string(e.file_size());
    files.insert(line);
  }
  for (const auto& f : files) s += "file " + f + "\n";
  return s;
}

/// Entries of a directory (the upload directory must be empty between requests).
inline std::size_t directory_entries(const std::filesystem::path& dir) {
  std::size_t n = 0;
  for ([[maybe_unused]] const auto& e : std::filesystem::directory_iterator(dir)) ++n;
  return n;
}

/// The process's resident set (VmRSS of /proc/self/status) in bytes, after returning
/// the allocator's free memory to the system (so the figure is what is in use).
inline std::size_t resident_bytes() {
  ::malloc_trim(0);
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.starts_with("VmRSS:")) return std::stoull(line.substr(6)) * 1024;  // kB
  }
  return 0;
}

/// Bytes the allocator has handed out and not got back (all arenas, mmapped chunks
/// included): unlike the resident set, free memory an arena keeps does not count. 0 where
/// the allocator does not tell (sanitizers).
inline std::size_t live_heap_bytes() {
  const struct mallinfo2 m = ::mallinfo2();
  return m.uordblks + m.hblkhd;
}

}  // namespace polmap::mapping::testing
