// A version's parameters (request_json) read back by a build worker (request_from_json)
// describe the same request: a worker builds what the one-process build would. Every
// setting is given a value other than its default, so a field the reader forgets shows.
#include <gtest/gtest.h>

#include "build_steps.hpp"

namespace polmap::mapping {
namespace {

MapBuildRequest unusual_request() {
  MapBuildRequest r;
  r.excluded_drive_ids.emplace_back("drive_a");
  r.notes = "unusual";
  r.make_current = false;
  r.incremental = false;
  r.build_gridmap = false;
  r.points.max_pair_distance_m = 0.41;
  r.points.support.min_drives = 3;
  r.points.support.min_view_fraction = 0.37;
  r.points.support.recent_passes = 7;
  r.points.support.retire_min_misses = 4;
  r.points.support.retire_min_vehicles = 3;
  PointFilterConfig& f = r.points.filter;
  f.line_peaks = {true, 0.17, 1.7, 0.07};
  f.surface_peaks = {false, 0.27, 1.3, 0.66};
  f.co_presence = {false, 2.5, 0.03, 0.45, 7, 3, 0.85};
  f.sliding = {false, 6, 0.15, 1.6, 0.8};
  f.out_of_view = {false, 0.45};
  f.mirror_ghosts = {false, 18.0, 7.0, 1.5, 0.25, 3, 0.3};
  r.lines.max_hull_distance_m = 0.6;
  r.lines.max_projection_distance_m = 1.1;
  r.lines.polyline_max_error_m = 0.09;
  r.lines.snap_max_gap_m = 1.7;
  r.lines.support.min_drives = 4;
  r.lines.filter.overhead = {false, 0.7, 3};
  r.lines.filter.range_streaks = {false, 12.0, 0.4, 1.5, 0.5, 0.8};
  r.lines.filter.out_of_view = {false, 0.6};
  r.visibility.default_view_range_m = 33.0;
  r.visibility.min_view_range_m = 6.0;
  r.visibility.max_view_range_m = 77.0;
  r.visibility.range_quantile = 0.85;
  r.visibility.range_margin = 1.3;
  r.partition = BuildPartition{15, 130.0, 0.7};
  return r;
}

TEST(BuildRequestJson, AWorkerReadsBackEverySettingTheVersionRecorded) {
  const MapBuilderConfig cfg;
  const nlohmann::json recorded = detail::request_json(unusual_request(), cfg);
  const MapBuildRequest back = detail::request_from_json(recorded);
  EXPECT_EQ(detail::request_json(back, cfg), recorded)
      << "recorded: " << recorded.dump()
      << "\nread back: " << detail::request_json(back, cfg).dump();
  // And the defaults stay the defaults.
  const nlohmann::json plain = detail::request_json(MapBuildRequest{}, cfg);
  EXPECT_EQ(detail::request_json(detail::request_from_json(plain), cfg), plain);
  EXPECT_NE(plain, recorded);
}

}  // namespace
}  // namespace polmap::mapping
