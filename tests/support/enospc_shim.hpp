#pragma once
/// @file enospc_shim.hpp
/// A full disk for tests, without root and without a small file system: while armed, the
/// writes of this process to a file at or below one of the armed paths fail as on a full
/// file system with a few blocks left: the first write into a file (at offset 0) stores part
/// of its bytes and returns a short count, every other write fails with ENOSPC.
///
/// The shim's definitions of write(2), pwrite(2), writev(2), sendfile(2), copy_file_range(2),
/// fallocate(2), posix_fallocate(3) and the stdio writers (fwrite, fputs, fputc) are linked
/// into the test executable. An executable's symbols come first in the dynamic linker's
/// lookup, so libsqlite3, libgdal and libstdc++ call them too: SQLite reports SQLITE_FULL,
/// GDAL a short write, std::filesystem::copy_file EIO (libstdc++'s word for a sendfile that
/// stopped short), as they do on a full tmpfs.
/// Unarmed, each call goes straight to the C library's (dlsym RTLD_NEXT); armed, the fd's
/// path is looked up in /proc/self/fd. Reads, opens and directory operations are never
/// refused: a full file system still lets a process create empty files and read.
///
/// Link it only into a test binary that wants it (tests/CMakeLists.txt), never into a
/// library.
#include <cstdint>
#include <filesystem>
#include <vector>

namespace polmap::test::enospc {

/// Refuses writes to files at or below each path (absolute; made canonical where it
/// exists) from now on, replacing the previously armed paths. At most 8 paths.
void arm(const std::vector<std::filesystem::path>& paths);
/// Writes succeed again ("space returned").
void disarm();
/// Writes refused since the process started.
[[nodiscard]] std::uint64_t refused_writes();

/// Disarms when it goes out of scope (a failing assertion cannot leave the disk "full").
class ScopedFull {
 public:
  explicit ScopedFull(const std::vector<std::filesystem::path>& paths) { arm(paths); }
  ~ScopedFull() { disarm(); }
  ScopedFull(const ScopedFull&) = delete;
  ScopedFull& operator=(const ScopedFull&) = delete;
};

}  // namespace polmap::test::enospc
