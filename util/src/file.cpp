#include "polmap/util/file.hpp"

#include <stdlib.h>

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

void write_file_bytes(const fs::path& path, std::string_view bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw IoError(path.string() + ": cannot open for writing");
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  out.flush();
  if (!out) throw IoError(path.string() + ": write failed");
}

fs::path make_unique_dir(const fs::path& parent, std::string_view stem) {
  const fs::path base = parent.empty() ? fs::temp_directory_path() : parent;
  std::string templ = (base / (std::string(stem) + "-XXXXXX")).string();
  if (mkdtemp(templ.data()) == nullptr) {
    throw IoError(base.string() + ": cannot create a temporary directory");
  }
  return templ;
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
