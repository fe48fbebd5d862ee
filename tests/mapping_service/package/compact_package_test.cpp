// Drive package format 2: the compact gridmap and candidates.bin written, validated and read
// back; the landmarks-only form; archives whose members do not match their manifest.
#include <gdal_priv.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "mapping_service/package_fixture.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {

namespace fs = std::filesystem;
using testing::make_synthetic_drive;

class CompactPackageTest : public ::testing::Test {
 protected:
  void SetUp() override {
    GDALAllRegister();
    root_ = polmap::test::unique_test_dir("compact_pkg");
  }
  void TearDown() override { fs::remove_all(root_); }
  /// The fixture's drive with covariances scaled to 0..40 dB over a noise power of 1e-6.
  static testing::SyntheticDrive drive() {
    testing::SyntheticDrive d = make_synthetic_drive();
    d.raster.noise_power = 1e-6 / 3.0;
    return d;
  }
  static PackageWriteOptions v2(bool landmarks_only = false) {
    PackageWriteOptions o;
    o.format_version = 2;
    o.landmarks_only = landmarks_only;
    return o;
  }
  fs::path root_;
};

TEST_F(CompactPackageTest, CompactGridmapRoundTripsWithinItsBounds) {
  const auto d = drive();
  const DriveManifest m = write_drive_package(d.pkg, d.raster, root_ / "p", v2());
  EXPECT_EQ(m.format_version, 2U);
  ASSERT_EQ(m.files.size(), 2U);
  EXPECT_EQ(m.files[0].name, kGridmapFileName);
  EXPECT_EQ(m.files[1].name, kCandidatesBinFileName);
  const DrivePackage back = read_and_validate_package(root_ / "p");
  EXPECT_TRUE(back.manifest.gridmap.compact);
  EXPECT_EQ(back.points.size(), d.pkg.points.size());
  const GridmapRaster g = read_gridmap(back);
  ASSERT_EQ(g.count.size(), d.raster.count.size());
  EXPECT_DOUBLE_EQ(g.noise_power, d.raster.noise_power);
  const double floor = 3.0 * d.raster.noise_power * std::pow(10.0, -0.3);
  std::size_t strong = 0;
  for (std::size_t k = 0; k < g.count.size(); ++k) {
    const std::uint32_t n = d.raster.count[k];
    EXPECT_EQ(g.count[k] == 0, n == 0);
    if (n == 0) continue;
    double tr = 0.0, tr_g = 0.0;
    for (int i = 0; i < 3; ++i) {
      tr += d.raster.layers[GridmapRaster::layer_index(3, i, i)][k].real();
      tr_g += g.layers[GridmapRaster::layer_index(3, i, i)][k].real();
    }
    if (tr < floor) {
      EXPECT_EQ(g.hits[k], 0U);  // the noise-floor mask
      EXPECT_EQ(tr_g, 0.0);
      continue;
    }
    ++strong;
    EXPECT_EQ(g.count[k], n);
    EXPECT_EQ(g.hits[k], n);  // the fixture has no hits: every look counts
    EXPECT_NEAR(tr_g / tr, 1.0, 1e-3);
  }
  EXPECT_GT(strong, 1000U);
  // GDAL reads it as a plain UInt16 GeoTIFF (GIS tools open it).
  GDALDatasetUniquePtr ds(GDALDataset::Open((root_ / "p" / kGridmapFileName).c_str(),
                                            GDAL_OF_RASTER | GDAL_OF_READONLY));
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetRasterCount(), 12);
  EXPECT_EQ(ds->GetRasterBand(1)->GetRasterDataType(), GDT_UInt16);
  EXPECT_STREQ(ds->GetRasterBand(3)->GetDescription(), "P");
}

TEST_F(CompactPackageTest, LandmarksOnlyPackageHasNoGridmapAndValidates) {
  const auto d = drive();
  const DriveManifest m = write_drive_package(d.pkg, d.raster, root_ / "p", v2(true));
  EXPECT_FALSE(m.has_gridmap);
  ASSERT_EQ(m.files.size(), 1U);
  EXPECT_FALSE(fs::exists(root_ / "p" / kGridmapFileName));
  const std::string tar = pack_drive_package(root_ / "p");
  const auto members = read_ustar(tar);
  ASSERT_EQ(members.size(), 2U);
  EXPECT_EQ(members[1].name, kCandidatesBinFileName);
  const DrivePackage back = validate_package_bytes(tar);
  EXPECT_FALSE(back.manifest.has_gridmap);
  EXPECT_EQ(back.lines.size(), d.pkg.lines.size());
  EXPECT_EQ(back.trajectory.front().time_s, d.pkg.trajectory.front().time_s);
  EXPECT_LT(tar.size(), 16'000U);
  const DrivePackage dir = read_and_validate_package(root_ / "p");
  EXPECT_THROW((void)read_gridmap(dir), NotFoundError);
  int blocks = 0;
  for_each_gridmap_block(dir, [&](const GridmapRaster&) { ++blocks; });
  EXPECT_EQ(blocks, 0);
}

TEST_F(CompactPackageTest, ArchiveMembersMustMatchTheManifest) {
  const auto d = drive();
  (void)write_drive_package(d.pkg, d.raster, root_ / "p", v2(true));
  const auto members = read_ustar(pack_drive_package(root_ / "p"));
  // A gridmap.tif the landmarks-only manifest does not list.
  std::vector<TarMember> extra{members[0], members[1], {kGridmapFileName, "II*\0"}};
  try {
    (void)validate_package_bytes(write_ustar(extra));
    FAIL() << "accepted an unlisted member";
  } catch (const PackageValidationError& e) {
    EXPECT_EQ(e.error().file, "archive");
    EXPECT_NE(e.error().message.find("not listed"), std::string::npos);
  }
  // The manifest must come first.
  std::vector<TarMember> swapped{members[1], members[0]};
  EXPECT_THROW((void)validate_package_bytes(write_ustar(swapped)), PackageValidationError);
}

TEST_F(CompactPackageTest, TrajectoryIsSimplifiedWithinItsErrorBound) {
  const auto d = drive();
  PackageWriteOptions o = v2(true);
  const DriveManifest m = write_drive_package(d.pkg, d.raster, root_ / "p", o);
  EXPECT_LT(m.counts.trajectory_samples, d.pkg.trajectory.size());
  const DrivePackage back = read_and_validate_package(root_ / "p");
  const tiles::LocalFrame frame(m.origin);
  // Every original sample lies within the bound of the kept ones' linear interpolation.
  const auto& kept = back.trajectory;
  std::size_t j = 0;
  for (const auto& s : d.pkg.trajectory) {
    while (j + 1 < kept.size() && kept[j + 1].time_s < s.time_s) ++j;
    const auto& a = kept[j];
    const auto& b = kept[std::min(j + 1, kept.size() - 1)];
    const double f = b.time_s > a.time_s ? (s.time_s - a.time_s) / (b.time_s - a.time_s) : 0.0;
    const Eigen::Vector2d pa = frame.to_local(a.lat_deg, a.lon_deg);
    const Eigen::Vector2d pb = frame.to_local(b.lat_deg, b.lon_deg);
    EXPECT_LE((pa + f * (pb - pa) - frame.to_local(s.lat_deg, s.lon_deg)).norm(),
              o.trajectory_max_error_m + 0.005);
    EXPECT_LE(b.time_s - a.time_s, o.trajectory_max_gap_s + 1e-9);
  }
}

TEST_F(CompactPackageTest, SimplifiedTrajectoryKeepsTheOdometry) {
  // A turn with a yaw rate that is not linear in time and a speed that changes: between
  // every two kept samples, the trapezoid of yaw rate and of speed over those two alone
  // reproduces the full-rate integral within its bound (the map builder's drive alignment
  // integrates this odometry).
  auto d = drive();
  for (std::size_t i = 0; i < d.pkg.trajectory.size(); ++i) {
    auto& s = d.pkg.trajectory[i];
    const double t = s.time_s - d.pkg.trajectory.front().time_s;
    s.yaw_rate_rps = 0.3 * std::pow(std::sin(0.2 * t), 4);
    s.speed_mps = 8.0 + 2.0 * std::sin(0.3 * t);
  }
  PackageWriteOptions o = v2(true);
  write_drive_package(d.pkg, d.raster, root_ / "p", o);
  const DrivePackage back = read_and_validate_package(root_ / "p");
  const auto& full = d.pkg.trajectory;
  std::size_t j = 0;
  double worst_yaw = 0.0, worst_dist = 0.0;
  for (std::size_t k = 0; k + 1 < back.trajectory.size(); ++k) {
    const auto& a = back.trajectory[k];
    const auto& b = back.trajectory[k + 1];
    double yaw = 0.0, dist = 0.0;
    while (j + 1 < full.size() && full[j + 1].time_s <= b.time_s + 1e-9) {
      if (full[j].time_s >= a.time_s - 1e-9) {
        const double dt = full[j + 1].time_s - full[j].time_s;
        yaw += 0.5 * (full[j].yaw_rate_rps + full[j + 1].yaw_rate_rps) * dt;
        dist += 0.5 * (full[j].speed_mps + full[j + 1].speed_mps) * dt;
      }
      ++j;
    }
    const double span = b.time_s - a.time_s;
    worst_yaw = std::max(worst_yaw, std::abs(0.5 * (a.yaw_rate_rps + b.yaw_rate_rps) * span - yaw));
    worst_dist = std::max(worst_dist, std::abs(0.5 * (a.speed_mps + b.speed_mps) * span - dist));
  }
  // Stored yaw rate is quantized to 1 urad/s, speed to 1 mm/s.
  EXPECT_LE(worst_yaw, o.trajectory_max_yaw_integral_error_rad + 1e-5);
  EXPECT_LE(worst_dist, o.trajectory_max_distance_error_m + 0.005);
  EXPECT_LT(back.trajectory.size(), full.size());
}

TEST_F(CompactPackageTest, FormatOneIsStillWrittenAndRead) {
  const auto d = drive();
  const DriveManifest m = write_drive_package(d.pkg, d.raster, root_ / "p");  // default: 1
  EXPECT_EQ(m.format_version, 1U);
  EXPECT_EQ(m.files[1].name, kCandidatesFileName);
  const DrivePackage back = read_and_validate_package(root_ / "p");
  EXPECT_FALSE(back.manifest.gridmap.compact);
  EXPECT_TRUE(read_gridmap(back).hits.empty());
}

}  // namespace
}  // namespace polmap::mapping
