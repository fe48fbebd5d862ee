#include "polmap/util/file.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "polmap/schema/errors.hpp"

namespace polmap::util {
namespace {
namespace fs = std::filesystem;

TEST(ScopedTempDir, RemovesItsDirectoryUnlessReleased) {
  fs::path kept;
  fs::path removed;
  {
    ScopedTempDir a = ScopedTempDir::create("polmap-util-test");
    ScopedTempDir b = ScopedTempDir::create("polmap-util-test");
    ASSERT_TRUE(fs::is_directory(a.path()));
    ASSERT_NE(a.path(), b.path());  // unique names
    write_file_bytes(a.path() / "f", "x");
    fs::create_directories(b.path() / "sub" / "deeper");
    write_file_bytes(b.path() / "sub" / "deeper" / "g", "y");
    removed = a.path();
    kept = b.release();
    EXPECT_TRUE(b.path().empty());
  }
  EXPECT_FALSE(fs::exists(removed));
  EXPECT_TRUE(fs::exists(kept / "sub" / "deeper" / "g"));
  fs::remove_all(kept);
}

TEST(ScopedTempDir, RemovesOnExceptionAndMovesOwnership) {
  fs::path p;
  try {
    ScopedTempDir a = ScopedTempDir::create("polmap-util-test");
    p = a.path();
    ScopedTempDir b = std::move(a);  // b owns it now, a nothing
    EXPECT_TRUE(
        a.path().empty());  // NOLINT(bugprone-use-after-move): checking the moved-from state
    throw IoError("boom");
  } catch (const IoError&) {
  }
  EXPECT_FALSE(fs::exists(p));
  ScopedTempDir adopted(fs::path("/nonexistent/polmap/never-created"));
  adopted.remove();  // a missing directory is not an error
}

TEST(FileBytes, RoundTripAndErrorsNameTheFile) {
  const ScopedTempDir d = ScopedTempDir::create("polmap-util-test");
  std::string bytes;
  for (int i = 0; i < 300; ++i) bytes.push_back(static_cast<char>(i));
  write_file_bytes(d.path() / "b.bin", bytes);
  EXPECT_EQ(read_file_bytes(d.path() / "b.bin"), bytes);
  try {
    (void)read_file_bytes(d.path() / "missing.bin");
    ADD_FAILURE();
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("missing.bin"), std::string::npos) << e.what();
  }
  EXPECT_THROW(write_file_bytes(d.path() / "no" / "dir" / "x", "a"), IoError);
  // A full file system is told apart (the server answers it 507): /dev/full answers every
  // write with ENOSPC.
  try {
    write_file_bytes("/dev/full", bytes);
    ADD_FAILURE() << "wrote to /dev/full";
  } catch (const StorageFullError& e) {
    EXPECT_NE(std::string(e.what()).find("/dev/full"), std::string::npos) << e.what();
  }
}

TEST(Sync, FilesAndDirectoriesAndErrors) {
  const ScopedTempDir d = ScopedTempDir::create("polmap-util-test");
  fs::create_directories(d.path() / "a" / "b");
  write_file_bytes(d.path() / "a" / "b" / "f", "x");
  EXPECT_NO_THROW(sync_tree(d.path()));
  EXPECT_NO_THROW(sync_file(d.path() / "a" / "b" / "f"));
  EXPECT_THROW(sync_file(d.path() / "missing"), IoError);
  EXPECT_THROW(sync_directory(d.path() / "a" / "b" / "f"), IoError);  // not a directory
}

TEST(FileLock, ExclusiveUntilReleased) {
  const ScopedTempDir d = ScopedTempDir::create("polmap-util-test");
  const fs::path p = d.path() / "x.lock";
  {
    FileLock a(p);
    EXPECT_TRUE(a.try_acquire());
    FileLock b(p);  // a second open file description, like another process
    EXPECT_FALSE(b.try_acquire());
    EXPECT_FALSE(b.held());
  }
  FileLock c(p);
  EXPECT_TRUE(c.try_acquire());
}

}  // namespace
}  // namespace polmap::util
