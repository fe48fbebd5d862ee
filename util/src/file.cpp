#include "polmap/util/file.hpp"

#include <fcntl.h>
#include <stdlib.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>

#include "polmap/schema/errors.hpp"

namespace polmap::util {
namespace fs = std::filesystem;

std::string read_file_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IoError(path.string() + ": cannot open for reading");
  std::string data;
  in.seekg(0, std::ios::end);
  const auto size = in.tellg();
  if (size < 0) throw IoError(path.string() + ": cannot determine size");
  data.resize(static_cast<std::size_t>(size));
  in.seekg(0);
  in.read(data.data(), static_cast<std::streamsize>(data.size()));
  if (!in) throw IoError(path.string() + ": read failed");
  return data;
}

int write_all(int fd, std::string_view bytes) {
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t w = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (w < 0 && errno == EINTR) continue;
    if (w < 0) return errno;
    if (w == 0) return ENOSPC;  // no progress: the file system takes no more
    done += static_cast<std::size_t>(w);
  }
  return 0;
}

void write_file_bytes(const fs::path& path, std::string_view bytes) {
  // write(2), not a stream: a full disk must be told apart (StorageFullError, HTTP 507).
  auto fail = [&](const char* what, int err) {
    const std::string msg = path.string() + ": " + what + ": " + std::strerror(err);
    if (err == ENOSPC || err == EDQUOT) throw StorageFullError(msg);
    throw IoError(msg);
  };
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) fail("cannot open for writing", errno);
  if (const int err = write_all(fd, bytes); err != 0) {
    ::close(fd);
    fail("write failed", err);
  }
  if (::close(fd) != 0) fail("write failed", errno);
}

fs::path make_unique_dir(const fs::path& parent, std::string_view stem) {
  const fs::path base = parent.empty() ? fs::temp_directory_path() : parent;
  std::string templ = (base / (std::string(stem) + "-XXXXXX")).string();
  if (mkdtemp(templ.data()) == nullptr) {
    throw IoError(base.string() + ": cannot create a temporary directory");
  }
  return templ;
}

namespace {

void sync_path(const fs::path& path, int flags) {
  const int fd = ::open(path.c_str(), flags | O_CLOEXEC);
  if (fd < 0) throw IoError(path.string() + ": cannot open to sync: " + std::strerror(errno));
  const int rc = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  if (rc != 0) throw IoError(path.string() + ": fsync failed: " + std::strerror(err));
}

}  // namespace

void sync_file(const fs::path& path) { sync_path(path, O_RDONLY); }

void sync_directory(const fs::path& dir) { sync_path(dir, O_RDONLY | O_DIRECTORY); }

void sync_tree(const fs::path& dir) {
  std::error_code ec;
  for (auto it = fs::recursive_directory_iterator(dir, ec); !ec && it != fs::end(it);
       it.increment(ec)) {
    if (it->is_regular_file(ec)) sync_file(it->path());
    if (it->is_directory(ec)) sync_directory(it->path());
  }
  if (ec) throw IoError(dir.string() + ": cannot list to sync: " + ec.message());
  sync_directory(dir);
}

FileLock::FileLock(const fs::path& path) {
  fd_ = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd_ < 0) throw IoError(path.string() + ": cannot open lock file: " + std::strerror(errno));
}

FileLock::~FileLock() {
  if (fd_ >= 0) ::close(fd_);  // closing releases the flock
}

bool FileLock::try_acquire() {
  if (!held_) held_ = ::flock(fd_, LOCK_EX | LOCK_NB) == 0;
  return held_;
}

ScopedTempDir ScopedTempDir::create(const fs::path& parent, std::string_view stem) {
  return ScopedTempDir(make_unique_dir(parent, stem));
}

ScopedTempDir& ScopedTempDir::operator=(ScopedTempDir&& other) noexcept {
  if (this != &other) {
    remove();
    path_ = std::move(other.path_);
    other.path_.clear();
  }
  return *this;
}

void ScopedTempDir::remove() noexcept {
  if (path_.empty()) return;
  std::error_code ec;
  fs::remove_all(path_, ec);
  path_.clear();
}

}  // namespace polmap::util
