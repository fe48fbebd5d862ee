#pragma once
// GDAL output helpers shared by the GIS exports (private to polmap_gis).
#include <cpl_conv.h>
#include <gdal_priv.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "polmap/mapping_service/detail/gdal.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::mapping::gis_detail {
namespace fs = std::filesystem;
using detail::GdalErrorCapture;

/// A GDAL driver by name; IoError if this GDAL lacks it.
inline GDALDriver* driver(const char* name) {
  detail::ensure_gdal();
  GDALDriver* d = GetGDALDriverManager()->GetDriverByName(name);
  if (d == nullptr) throw IoError(std::string("GDAL has no ") + name + " driver");
  return d;
}

/// Closes (flushes) a dataset; IoError naming `out` if GDAL reported a failure.
inline void close_dataset(GDALDatasetUniquePtr ds, const GdalErrorCapture& capture,
                          const std::string& out) {
  CPLErrorReset();
  GDALClose(ds.release());
  if (CPLGetLastErrorType() >= CE_Failure) {
    throw IoError(out + ": cannot finish: " + capture.last_message());
  }
}

/// Removes a file that is to be replaced (absent is fine).
inline void remove_file(const fs::path& p) {
  std::error_code ec;
  fs::remove(p, ec);
  if (ec) throw IoError(p.string() + ": cannot replace: " + ec.message());
}

/// Total size of the files that exist.
inline std::uint64_t total_size(const std::vector<fs::path>& files) {
  std::uint64_t n = 0;
  for (const auto& f : files) {
    std::error_code ec;
    const auto s = fs::file_size(f, ec);
    if (!ec) n += s;
  }
  return n;
}

}  // namespace polmap::mapping::gis_detail
