#pragma once
// Every test owns a unique temporary directory (mkdtemp below the system temporary
// directory), so tests running in parallel, or two checkouts testing on one machine,
// never share a path.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "polmap/util/file.hpp"

namespace polmap::test {

/// A new, empty, unique directory "polmap-<stem>-<test name>-XXXXXX". The caller removes
/// it (or holds it in a util::ScopedTempDir).
inline std::filesystem::path unique_test_dir(const std::string& stem) {
  std::string name = "polmap-" + stem;
  if (const auto* info = ::testing::UnitTest::GetInstance()->current_test_info()) {
    name += "-";
    name += info->name();
  }
  for (char& c : name) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '-' || c == '_';
    if (!ok) c = '_';
  }
  return util::make_unique_dir({}, name);
}

/// A unique test directory that is removed when the test (or fixture) ends.
class TestDir : public util::ScopedTempDir {
 public:
  explicit TestDir(const std::string& stem = "test") : util::ScopedTempDir(unique_test_dir(stem)) {}
};

}  // namespace polmap::test
