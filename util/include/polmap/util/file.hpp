#pragma once
/// @file file.hpp
/// Whole-file reads and writes and scoped temporary directories (the one rollback
/// helper: a directory that is removed unless the code that filled it commits it).
#include <filesystem>
#include <string>
#include <string_view>

namespace polmap::util {

/// The whole file as bytes. Throws IoError naming the file.
[[nodiscard]] std::string read_file_bytes(const std::filesystem::path& path);

/// Writes all of `bytes` to the open file `fd` (retrying after EINTR and short writes).
/// Returns 0, or the errno of the failure (ENOSPC when the file system takes no more).
[[nodiscard]] int write_all(int fd, std::string_view bytes);

/// Writes bytes to path (truncating). Throws IoError naming the file, StorageFullError when
/// the file system is full (ENOSPC, EDQUOT).
void write_file_bytes(const std::filesystem::path& path, std::string_view bytes);

/// A new, unique directory `<parent>/<stem>-XXXXXX` (mkdtemp; the system temporary
/// directory when `parent` is empty). Throws IoError.
[[nodiscard]] std::filesystem::path make_unique_dir(const std::filesystem::path& parent,
                                                    std::string_view stem);

/// fsync(2) of a regular file, so its bytes survive a crash. Throws IoError.
void sync_file(const std::filesystem::path& path);
/// fsync(2) of a directory, so the names created or renamed in it survive a crash.
void sync_directory(const std::filesystem::path& dir);
/// sync_file of every regular file below `dir`, then sync_directory of every directory.
void sync_tree(const std::filesystem::path& dir);

/// An exclusive advisory lock (flock) on `path` (created if missing), held while the
/// object lives. try_acquire() tells whether this process got it.
class FileLock {
 public:
  explicit FileLock(const std::filesystem::path& path);
  ~FileLock();
  FileLock(const FileLock&) = delete;
  FileLock& operator=(const FileLock&) = delete;
  /// Non-blocking; true if the lock is (now) held by this object.
  bool try_acquire();
  [[nodiscard]] bool held() const { return held_; }

 private:
  int fd_ = -1;
  bool held_ = false;
};

/// Owns a directory and removes it (recursively, errors ignored) when destroyed, unless
/// release() was called: the guard of every "build in a temporary directory, then
/// commit by rename" sequence, and of the test fixtures.
class ScopedTempDir {
 public:
  /// A new unique directory (see make_unique_dir).
  [[nodiscard]] static ScopedTempDir create(const std::filesystem::path& parent,
                                            std::string_view stem);
  /// A new unique directory below the system temporary directory.
  [[nodiscard]] static ScopedTempDir create(std::string_view stem) { return create({}, stem); }

  /// Adopts `path` (which may not exist yet): it is removed on destruction.
  explicit ScopedTempDir(std::filesystem::path path) : path_(std::move(path)) {}
  ~ScopedTempDir() { remove(); }
  ScopedTempDir(ScopedTempDir&& other) noexcept : path_(std::move(other.path_)) {
    other.path_.clear();
  }
  ScopedTempDir& operator=(ScopedTempDir&& other) noexcept;
  ScopedTempDir(const ScopedTempDir&) = delete;
  ScopedTempDir& operator=(const ScopedTempDir&) = delete;

  [[nodiscard]] const std::filesystem::path& path() const { return path_; }
  /// Keeps the directory (it was committed or handed on); returns its path.
  std::filesystem::path release() {
    std::filesystem::path p = std::move(path_);
    path_.clear();
    return p;
  }
  /// Removes the directory now (no-op after release()).
  void remove() noexcept;

 private:
  std::filesystem::path path_;
};

}  // namespace polmap::util
