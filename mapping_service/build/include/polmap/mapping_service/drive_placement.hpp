#pragma once
/// @file drive_placement.hpp
/// Where a drive's gridmap goes into the merged gridmap sums (gridmap_sums.hpp): where the
/// drive reported it (as uploaded), or moved by its alignment correction
/// (drive_alignment.hpp) when its positioning was consumer-grade. The store keeps the
/// placement with the drive's sum input (GridmapSumInput::placement, opaque text), so that a
/// drive whose alignment moves is taken out of the sums the way it went in and added again
/// where it now belongs.
#include <optional>
#include <string>
#include <string_view>

#include "polmap/mapping_service/drive_alignment.hpp"
#include "polmap/mapping_service/gridmap_sums.hpp"
#include "polmap/schema/geo.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::mapping {

/// A drive's placement: its correction and the origin of the frame the correction was
/// computed in (the build frame). Without a frame origin: as uploaded.
struct DrivePlacement {
  std::optional<GeoPoint> frame_origin;
  DriveCorrection correction;
  [[nodiscard]] bool as_uploaded() const { return !frame_origin || correction.node_s_m.empty(); }
};

/// The placement of a drive aligned in `build_frame`.
[[nodiscard]] DrivePlacement drive_placement(const tiles::LocalFrame& build_frame,
                                             const DriveCorrection& correction);

/// Text for the store: "" for as uploaded, else versioned JSON (positions rounded to 1 mm,
/// headings to 1 µrad).
[[nodiscard]] std::string encode_drive_placement(const DrivePlacement& p);

/// Parses encode_drive_placement's text; throws ValidationError naming `source` when it is
/// not a placement (wrong version, inconsistent sizes, non-finite values, unordered arc
/// lengths, more than kMaxPlacementNodes nodes or path points).
[[nodiscard]] DrivePlacement decode_drive_placement(std::string_view text,
                                                    const std::string& source);
inline constexpr std::size_t kMaxPlacementNodes = 1'000'000;

/// Where `p` puts a point of the drive's gridmap (geodetic in, geodetic out), by the rule a
/// candidate follows (DriveCorrection::apply): the correction where the drive saw it.
[[nodiscard]] GeoPoint placed(const DrivePlacement& p, const GeoPoint& g);

/// The largest distance between where `a` and `b` put the drive's gridmap, sampled along the
/// corrected drive's path every ~5 m and 30 m to either side of it (metres; 0 when both are
/// as uploaded).
[[nodiscard]] double placement_difference_m(const DrivePlacement& a, const DrivePlacement& b);

/// The warp splat_gridmap applies to a drive with frame `drive_frame` (empty: as uploaded).
[[nodiscard]] GridmapWarp placement_warp(const DrivePlacement& p,
                                         const tiles::LocalFrame& drive_frame);

}  // namespace polmap::mapping
