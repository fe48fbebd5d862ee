// The ENOSPC write shim (see enospc_shim.hpp). The interposers only look at the file
// descriptor's path while armed; they never allocate, so the C library's internals and
// the allocator cannot recurse into them.
#include "support/enospc_shim.hpp"

#include <dlfcn.h>
#include <stdio.h>
#include <sys/types.h>
#include <sys/uio.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <mutex>
#include <stdexcept>
#include <string>

namespace polmap::test::enospc {
namespace {

constexpr std::size_t kMaxPaths = 8;
constexpr std::size_t kMaxPathBytes = 4096;

std::atomic<bool> g_armed{false};
std::atomic<std::uint64_t> g_refused{0};
std::mutex g_mutex;  // guards g_paths (constexpr-constructed, trivially destroyed)
std::array<std::array<char, kMaxPathBytes>, kMaxPaths> g_paths{};
std::size_t g_num_paths = 0;

/// Next definition of `name` after this executable's: the C library's (or a sanitizer's).
template <class F>
F next(const char* name) {
  void* f = dlsym(RTLD_NEXT, name);
  if (f == nullptr) std::abort();  // cannot forward: nothing sensible to do
  return reinterpret_cast<F>(f);
}

}  // namespace

/// True if a write to `fd` is to be refused now (and counts it).
bool refuse(int fd) {
  if (!g_armed.load(std::memory_order_acquire) || fd < 0) return false;
  char link[48];
  std::snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
  char target[kMaxPathBytes];
  const ssize_t n = ::readlink(link, target, sizeof target - 1);
  if (n <= 0) return false;
  target[n] = '\0';
  std::lock_guard lock(g_mutex);
  if (!g_armed.load(std::memory_order_relaxed)) return false;
  for (std::size_t i = 0; i < g_num_paths; ++i) {
    const char* p = g_paths[i].data();
    const std::size_t len = std::strlen(p);
    if (std::strncmp(target, p, len) == 0 && (target[len] == '\0' || target[len] == '/' ||
                                              std::strcmp(target + len, " (deleted)") == 0)) {
      g_refused.fetch_add(1);
      return true;
    }
  }
  return false;
}

/// Bytes of an n-byte write at `offset` of a refused file that still fit: the disk had a
/// few blocks left, so the first write into a file stores part of its bytes (a short
/// count, as on a real full file system); every later write fails with ENOSPC.
std::size_t room(long long offset, std::size_t n) {
  if (offset != 0 || n < 2) return 0;
  return std::min<std::size_t>(n / 2, std::size_t{64} << 10);
}

/// The file offset of `fd` (-1 when it has none, e.g. a pipe).
long long offset_of(int fd) { return static_cast<long long>(::lseek(fd, 0, SEEK_CUR)); }

void arm(const std::vector<std::filesystem::path>& paths) {
  if (paths.empty() || paths.size() > kMaxPaths) {
    throw std::invalid_argument("enospc::arm: 1 to 8 paths");
  }
  std::lock_guard lock(g_mutex);
  g_num_paths = 0;
  for (const auto& p : paths) {
    std::error_code ec;
    std::string s = std::filesystem::weakly_canonical(p, ec).string();
    if (ec || s.empty()) s = p.string();
    while (s.size() > 1 && s.back() == '/') s.pop_back();
    if (s.front() != '/' || s.size() >= kMaxPathBytes) {
      throw std::invalid_argument("enospc::arm: not an absolute path: " + p.string());
    }
    std::memcpy(g_paths[g_num_paths].data(), s.c_str(), s.size() + 1);
    ++g_num_paths;
  }
  g_armed.store(true, std::memory_order_release);
}

void disarm() {
  std::lock_guard lock(g_mutex);
  g_armed.store(false, std::memory_order_release);
  g_num_paths = 0;
}

std::uint64_t refused_writes() { return g_refused.load(); }

}  // namespace polmap::test::enospc

using polmap::test::enospc::next;
using polmap::test::enospc::offset_of;
using polmap::test::enospc::refuse;
using polmap::test::enospc::room;

// The interposers. Declarations of sendfile and fallocate are our own (their headers
// declare them with exception specifications this definition need not repeat).
extern "C" {

ssize_t write(int fd, const void* buf, size_t n) {
  static const auto real = next<ssize_t (*)(int, const void*, size_t)>("write");
  if (n > 0 && refuse(fd)) {
    if (const std::size_t part = room(offset_of(fd), n); part > 0) return real(fd, buf, part);
    errno = ENOSPC;
    return -1;
  }
  return real(fd, buf, n);
}

ssize_t pwrite(int fd, const void* buf, size_t n, off_t off) {
  static const auto real = next<ssize_t (*)(int, const void*, size_t, off_t)>("pwrite");
  if (n > 0 && refuse(fd)) {
    if (const std::size_t part = room(off, n); part > 0) return real(fd, buf, part, off);
    errno = ENOSPC;
    return -1;
  }
  return real(fd, buf, n, off);
}

ssize_t pwrite64(int fd, const void* buf, size_t n, off64_t off) {
  static const auto real = next<ssize_t (*)(int, const void*, size_t, off64_t)>("pwrite64");
  if (n > 0 && refuse(fd)) {
    if (const std::size_t part = room(off, n); part > 0) return real(fd, buf, part, off);
    errno = ENOSPC;
    return -1;
  }
  return real(fd, buf, n, off);
}

ssize_t writev(int fd, const struct iovec* iov, int count) {
  static const auto real = next<ssize_t (*)(int, const struct iovec*, int)>("writev");
  if (count > 0 && refuse(fd)) {
    if (const std::size_t part = room(offset_of(fd), iov[0].iov_len); part > 0) {
      const struct iovec first { iov[0].iov_base, part };
      return real(fd, &first, 1);
    }
    errno = ENOSPC;
    return -1;
  }
  return real(fd, iov, count);
}

ssize_t sendfile(int out_fd, int in_fd, off_t* offset, size_t count) {
  static const auto real = next<ssize_t (*)(int, int, off_t*, size_t)>("sendfile");
  if (count > 0 && refuse(out_fd)) {
    if (const std::size_t part = room(offset_of(out_fd), count); part > 0) {
      return real(out_fd, in_fd, offset, part);
    }
    errno = ENOSPC;
    return -1;
  }
  return real(out_fd, in_fd, offset, count);
}

ssize_t sendfile64(int out_fd, int in_fd, off64_t* offset, size_t count) {
  static const auto real = next<ssize_t (*)(int, int, off64_t*, size_t)>("sendfile64");
  if (count > 0 && refuse(out_fd)) {
    if (const std::size_t part = room(offset_of(out_fd), count); part > 0) {
      return real(out_fd, in_fd, offset, part);
    }
    errno = ENOSPC;
    return -1;
  }
  return real(out_fd, in_fd, offset, count);
}

ssize_t copy_file_range(int in_fd, off64_t* in_off, int out_fd, off64_t* out_off, size_t len,
                        unsigned int flags) {
  static const auto real =
      next<ssize_t (*)(int, off64_t*, int, off64_t*, size_t, unsigned int)>("copy_file_range");
  if (len > 0 && refuse(out_fd)) {
    const long long at = out_off != nullptr ? static_cast<long long>(*out_off) : offset_of(out_fd);
    if (const std::size_t part = room(at, len); part > 0) {
      return real(in_fd, in_off, out_fd, out_off, part, flags);
    }
    errno = ENOSPC;
    return -1;
  }
  return real(in_fd, in_off, out_fd, out_off, len, flags);
}

int fallocate(int fd, int mode, off_t off, off_t len) {
  constexpr int kPunchHole = 0x02;  // FALLOC_FL_PUNCH_HOLE frees space: never refused
  if ((mode & kPunchHole) == 0 && refuse(fd)) {
    errno = ENOSPC;
    return -1;
  }
  static const auto real = next<int (*)(int, int, off_t, off_t)>("fallocate");
  return real(fd, mode, off, len);
}

int fallocate64(int fd, int mode, off64_t off, off64_t len) {
  constexpr int kPunchHole = 0x02;
  if ((mode & kPunchHole) == 0 && refuse(fd)) {
    errno = ENOSPC;
    return -1;
  }
  static const auto real = next<int (*)(int, int, off64_t, off64_t)>("fallocate64");
  return real(fd, mode, off, len);
}

int posix_fallocate(int fd, off_t off, off_t len) {
  if (refuse(fd)) return ENOSPC;  // returns the error, errno untouched
  static const auto real = next<int (*)(int, off_t, off_t)>("posix_fallocate");
  return real(fd, off, len);
}

int posix_fallocate64(int fd, off64_t off, off64_t len) {
  if (refuse(fd)) return ENOSPC;
  static const auto real = next<int (*)(int, off64_t, off64_t)>("posix_fallocate64");
  return real(fd, off, len);
}

size_t fwrite(const void* ptr, size_t size, size_t n, FILE* stream) {
  static const auto real = next<size_t (*)(const void*, size_t, size_t, FILE*)>("fwrite");
  if (size > 0 && n > 0 && refuse(fileno(stream))) {
    const std::size_t part = room(static_cast<long long>(ftello(stream)), size * n) / size;
    if (part > 0) return real(ptr, size, part, stream);
    errno = ENOSPC;
    return 0;
  }
  return real(ptr, size, n, stream);
}

int fputs(const char* s, FILE* stream) {
  if (*s != '\0' && refuse(fileno(stream))) {
    errno = ENOSPC;
    return EOF;
  }
  static const auto real = next<int (*)(const char*, FILE*)>("fputs");
  return real(s, stream);
}

int fputc(int c, FILE* stream) {
  if (refuse(fileno(stream))) {
    errno = ENOSPC;
    return EOF;
  }
  static const auto real = next<int (*)(int, FILE*)>("fputc");
  return real(c, stream);
}

}  // extern "C"
