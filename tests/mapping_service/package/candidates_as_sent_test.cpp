// A compact package's candidates are extracted from the gridmap as the package sends it
// (process_drive_for_package): the backend, decoding the package, finds exactly the
// vehicle's candidates. Before, the vehicle extracted from the exact gridmap and the
// codec's 0.002 dB power step flipped a few of the line extractor's threshold decisions
// (dual and single polarization: 0.98-0.99 of the candidates reproduced).
#include <gtest/gtest.h>

#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/radar/drive_processor.hpp"
#include "polmap/radar/line_extractor.hpp"
#include "polmap/radar/point_extractor.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/world.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {

radar::DriveProcessingResult simulated_drive(PolLevel level, const PackageWriteOptions& options) {
  sim::SimConfig scfg;
  sim::WorldSpec spec;
  spec.preset = "urban";
  spec.length_m = 250.0;
  spec.seed = 4;  // exact-gridmap extraction reproduced 0.98 of its points, 0.74 of its lines
  auto world = sim::make_world(spec, scfg);
  sim::DriveSimulator drive(world, scfg, 0);
  radar::DriveProcessingConfig cfg;
  cfg.gridmap.level = level;
  return process_drive_for_package(drive, cfg, options);
}

TEST(CandidatesAsSent, TheBackendReExtractsExactlyTheVehiclesCandidates) {
  const test::TestDir dir("candidates_as_sent");
  PackageWriteOptions options;
  options.format_version = 2;
  ASSERT_TRUE(sends_compact_gridmap(options));
  const radar::DriveProcessingResult r = simulated_drive(PolLevel::DualHHVV, options);
  ASSERT_GT(r.points.size(), 30U);
  ASSERT_GT(r.lines.size(), 5U);
  (void)write_drive_package(r, dir.path() / "pkg", options);
  const DrivePackage pkg = read_and_validate_package(dir.path() / "pkg");
  const radar::CovarianceGridmap decoded = read_covariance_gridmap(pkg);

  // The in-memory round trip is the decoded package, cell for cell and bit for bit.
  const radar::CovarianceGridmap sent = compact_round_trip(r.gridmap, options.codec);
  EXPECT_EQ(sent.noise_power(), decoded.noise_power());
  ASSERT_EQ(sent.tile_indices(), decoded.tile_indices());
  std::size_t cells = 0;
  for (const auto& [tx, ty] : sent.tile_indices()) {
    const radar::CellBox box{tx * radar::kTileSizeCells, ty * radar::kTileSizeCells,
                             (tx + 1) * radar::kTileSizeCells, (ty + 1) * radar::kTileSizeCells};
    const radar::CovarianceRaster a = sent.raster(box), b = decoded.raster(box);
    ASSERT_EQ(a.count, b.count) << "tile " << tx << "," << ty;
    ASSERT_EQ(a.hits, b.hits) << "tile " << tx << "," << ty;
    ASSERT_EQ(a.layers, b.layers) << "tile " << tx << "," << ty;
    for (const auto n : a.count) cells += n > 0;
  }
  EXPECT_GT(cells, 10000U);

  // The detectors on the decoded package give the candidates the package carries.
  const auto points = radar::extract_points(decoded, radar::PointExtractorConfig{});
  const auto lines = radar::extract_lines(decoded, radar::LineExtractorConfig{});
  ASSERT_EQ(points.size(), r.points.size());
  for (std::size_t i = 0; i < points.size(); ++i) {
    EXPECT_EQ(points[i].position_m, r.points[i].position_m) << "point " << i;
    EXPECT_EQ(points[i].strength, r.points[i].strength) << "point " << i;
  }
  ASSERT_EQ(lines.size(), r.lines.size());
  for (std::size_t i = 0; i < lines.size(); ++i) {
    EXPECT_EQ(lines[i].start_m, r.lines[i].start_m) << "line " << i;
    EXPECT_EQ(lines[i].end_m, r.lines[i].end_m) << "line " << i;
  }
  // And what the package stored is what was extracted (candidates.bin keeps 1 mm / 1 cm).
  ASSERT_EQ(pkg.points.size(), r.points.size());
  ASSERT_EQ(pkg.lines.size(), r.lines.size());
}

TEST(CandidatesAsSent, PackagesWithoutTheCompactGridmapKeepTheExactCandidates) {
  PackageWriteOptions options;
  options.format_version = 1;
  EXPECT_FALSE(sends_compact_gridmap(options));
  options.format_version = 2;
  options.landmarks_only = true;
  EXPECT_FALSE(sends_compact_gridmap(options));
  // No gridmap sent: nothing to reproduce, the candidates come from the exact gridmap.
  const radar::DriveProcessingResult r = simulated_drive(PolLevel::SingleHH, options);
  EXPECT_EQ(r.points.size(), radar::extract_points(r.gridmap, {}).size());
  EXPECT_EQ(r.lines.size(), radar::extract_lines(r.gridmap, {}).size());
}

TEST(CandidatesAsSent, AGridmapWithoutNoisePowerCannotBeCoded) {
  radar::GridmapConfig cfg;
  cfg.window_s = 0.0;
  const radar::CovarianceGridmap empty(cfg);
  EXPECT_THROW((void)compact_round_trip(empty), ValidationError);
}

}  // namespace
}  // namespace polmap::mapping
