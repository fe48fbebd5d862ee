#pragma once
/// @file gdal.hpp
/// GDAL adapter helpers shared by the package and GIS targets (not part of the public
/// API: detail/ headers may change without notice).
#include <cstdint>
#include <string>
#include <string_view>

#include "polmap/schema/geo.hpp"

namespace polmap::mapping::detail {

/// GDAL's raster block cache when GDAL_CACHEMAX is not set (see ensure_gdal).
inline constexpr std::int64_t kDefaultGdalCacheBytes = 64ll << 20;

/// GDALAllRegister() once per process; bounds GDAL's block cache to
/// kDefaultGdalCacheBytes unless GDAL_CACHEMAX is set.
void ensure_gdal();

/// While alive, GDAL errors of this thread are captured (not printed); last_message()
/// returns the most recent one.
class GdalErrorCapture {
 public:
  GdalErrorCapture();
  ~GdalErrorCapture();
  GdalErrorCapture(const GdalErrorCapture&) = delete;
  GdalErrorCapture& operator=(const GdalErrorCapture&) = delete;
  [[nodiscard]] std::string last_message() const;

 private:
  std::string message_;
  static void handler(int eclass, int code, const char* msg);
};

/// Sets a GDAL config option for this thread for the scope's lifetime.
class ScopedGdalConfig {
 public:
  ScopedGdalConfig(const char* key, const char* value);
  ~ScopedGdalConfig();
  ScopedGdalConfig(const ScopedGdalConfig&) = delete;
  ScopedGdalConfig& operator=(const ScopedGdalConfig&) = delete;

 private:
  std::string key_;
  std::string old_;
  bool had_old_ = false;
};

/// True if `proj` is the PROJ string of the drive frame at `origin`
/// (tiles::LocalFrame::proj_string): exactly its +key=value terms, in any order, with
/// lat_0/lon_0 within 1e-9° of the origin. Parsed here without PROJ: a manifest is
/// hostile, and PROJ's user-input parser resolves names against its database, reads
/// files and URLs, and can take seconds on a crafted name (fuzz_package found one).
bool is_local_frame_proj(std::string_view proj, const GeoPoint& origin);

}  // namespace polmap::mapping::detail
