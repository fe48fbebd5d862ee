#pragma once
// Seeds written by the fuzzers themselves (tools/fuzz sets POLMAP_FUZZ_WRITE_SEEDS=DIR on
// a first run): valid inputs made by our own encoders, so the corpus always matches the
// current format and nothing binary is committed.
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>

namespace polmap::fuzz {

/// The seed directory requested by the environment, or an empty path.
inline std::filesystem::path seed_dir() {
  const char* d = std::getenv("POLMAP_FUZZ_WRITE_SEEDS");
  return d == nullptr ? std::filesystem::path() : std::filesystem::path(d);
}

inline void write_seed(const std::filesystem::path& dir, const std::string& name,
                       std::string_view bytes) {
  std::filesystem::create_directories(dir);
  std::ofstream(dir / name, std::ios::binary)
      .write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

}  // namespace polmap::fuzz
