// The manifest's crs_proj is checked without PROJ (detail::is_local_frame_proj): exactly
// the terms of LocalFrame::proj_string, in any order, origin within 1e-9°; anything else
// is rejected at once, including the name that made PROJ search its database for
// seconds (found by fuzz_package), file paths, URLs and EPSG codes.
#include <gtest/gtest.h>

#include <chrono>
#include <string>
#include <vector>

#include "polmap/mapping_service/detail/gdal.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::mapping::detail {
namespace {

const GeoPoint kOrigin{35.224, 138.8045, 0.0};

TEST(LocalFrameCrs, AcceptsTheDriveFrameInAnyTermOrder) {
  const std::string canonical = tiles::LocalFrame(kOrigin).proj_string();
  EXPECT_TRUE(is_local_frame_proj(canonical, kOrigin));
  EXPECT_TRUE(is_local_frame_proj(
      "+no_defs +units=m  +ellps=WGS84 +y_0=0 +x_0=0 +k=1 +lon_0=138.8045 +lat_0=35.224 "
      "+proj=tmerc",
      kOrigin));
}

TEST(LocalFrameCrs, RejectsOtherFramesAndHostileText) {
  const std::string canonical = tiles::LocalFrame(kOrigin).proj_string();
  EXPECT_FALSE(is_local_frame_proj(canonical, GeoPoint{35.224 + 1e-7, 138.8045, 0.0}));
  for (const std::string& bad : std::vector<std::string>{
           std::string("EPSG:4326"),
           std::string("/etc/passwd"),
           std::string("http://example.com/crs.wkt"),
           // The fuzz finding: PROJ took > 10 s resolving this "name".
           std::string("+proj;tmerc +lat_0=35.224000000000 +lon_0=138.804500000000 +k=1 +x_0=0 "
                       "+y_0=0 +ellps=WGS84 +units=m +no_defs"),
           canonical + " +towgs84=0,0,0",  // extra term
           canonical + " +k=1",            // repeated term
           "+proj=tmerc +lat_0=35.224 +lon_0=138.8045 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m",
           "+proj=utm +lat_0=35.224 +lon_0=138.8045 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m "
           "+no_defs",
           "+proj=tmerc +lat_0=1e999 +lon_0=138.8045 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m "
           "+no_defs",
           "+proj=tmerc +lat_0=nan +lon_0=138.8045 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m "
           "+no_defs",
           "+proj=tmerc +lat_0=35.224x +lon_0=138.8045 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m "
           "+no_defs",
           "+proj=tmerc +lat_0=35.224 +lon_0=138.8045 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m "
           "+no_defs=1",
           std::string(600, ' ') + canonical,  // over the length cap
           std::string(),
       }) {
    const auto t0 = std::chrono::steady_clock::now();
    EXPECT_FALSE(is_local_frame_proj(bad, kOrigin)) << bad.substr(0, 120);
    // No database lookups, no I/O: far below any budget.
    EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::milliseconds(50));
  }
}

}  // namespace
}  // namespace polmap::mapping::detail
