#pragma once
// The layers of candidates.gpkg: written by candidates_gpkg.cpp, required field for
// field by package_validation.cpp. One definition, so writer and validator cannot drift.
#include <ogr_core.h>

#include <span>

namespace polmap::mapping::detail {

struct GpkgField {
  const char* name;
  OGRFieldType type;
};

struct GpkgLayerSchema {
  const char* name;
  OGRwkbGeometryType geometry;
  const char* description;  ///< gpkg_contents.description
  std::span<const GpkgField> fields;
};

inline constexpr GpkgField kPointFields[] = {{"strength", OFTReal},     {"power_db", OFTReal},
                                             {"scattering", OFTString}, {"num_cells", OFTInteger64},
                                             {"x_m", OFTReal},          {"y_m", OFTReal}};
inline constexpr GpkgField kLineFields[] = {{"strength", OFTReal}, {"x0_m", OFTReal},
                                            {"y0_m", OFTReal},     {"x1_m", OFTReal},
                                            {"y1_m", OFTReal},     {"length_m", OFTReal}};
inline constexpr GpkgField kTrajectoryFields[] = {
    {"time_s", OFTReal},       {"yaw_enu_rad", OFTReal}, {"speed_mps", OFTReal},
    {"yaw_rate_rps", OFTReal}, {"std_east_m", OFTReal},  {"std_north_m", OFTReal},
    {"std_yaw_rad", OFTReal},  {"solution", OFTString},  {"x_m", OFTReal},
    {"y_m", OFTReal}};

inline constexpr GpkgLayerSchema kPointsLayer{
    "points", wkbPoint, "pCFAR point candidates; x_m/y_m in the drive frame", kPointFields};
inline constexpr GpkgLayerSchema kLinesLayer{
    "lines", wkbLineString, "line candidates; x0_m..y1_m in the drive frame", kLineFields};
inline constexpr GpkgLayerSchema kTrajectoryLayer{
    "trajectory", wkbPoint, "GNSS/IMU trajectory samples; x_m/y_m in the drive frame",
    kTrajectoryFields};

}  // namespace polmap::mapping::detail
