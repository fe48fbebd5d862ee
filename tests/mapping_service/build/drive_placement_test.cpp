// Drive placements in the merged gridmap: the stored text round-trips (to its rounding),
// "" is as uploaded, malformed text is rejected naming its source, the difference of two
// placements is the distance between where they put the drive, and the warp moves a
// drive-frame point by the correction.
#include "polmap/mapping_service/drive_placement.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>

#include "polmap/schema/errors.hpp"

namespace polmap::mapping {
namespace {

const GeoPoint kOrigin{48.7758, 9.1829, 250.0};

// A straight 100 m drive along the build frame's x axis, nodes every 10 m, all corrected by
// (dx, dy, dyaw).
DrivePlacement straight(double dx, double dy, double dyaw = 0.0) {
  DriveCorrection c;
  c.drive = 7;
  for (int k = 0; k <= 10; ++k) {
    c.node_s_m.push_back(10.0 * k);
    c.node_position_m.emplace_back(10.0 * k, 0.0);
    c.node_correction.emplace_back(dx, dy, dyaw);
  }
  for (int i = 0; i <= 100; ++i) {
    c.path_s_m.push_back(i);
    c.path_m.emplace_back(i, 0.0);
  }
  c.candidate_lead_m = -10.0;
  return drive_placement(tiles::LocalFrame(kOrigin), c);
}

TEST(DrivePlacement, RoundTripsThroughItsText) {
  DrivePlacement p = straight(0.4123456, -1.25, 0.0012345678);
  p.correction.node_correction[3] = {0.1, 0.2, -0.003};
  const std::string text = encode_drive_placement(p);
  const DrivePlacement q = decode_drive_placement(text, "test");
  ASSERT_TRUE(q.frame_origin.has_value());
  EXPECT_EQ(q.frame_origin->lat_deg, kOrigin.lat_deg);
  EXPECT_EQ(q.frame_origin->lon_deg, kOrigin.lon_deg);
  EXPECT_EQ(q.correction.candidate_lead_m, -10.0);
  ASSERT_EQ(q.correction.node_s_m.size(), p.correction.node_s_m.size());
  ASSERT_EQ(q.correction.path_m.size(), p.correction.path_m.size());
  for (std::size_t k = 0; k < p.correction.node_s_m.size(); ++k) {
    EXPECT_NEAR(q.correction.node_s_m[k], p.correction.node_s_m[k], 5e-4);
    EXPECT_LT((q.correction.node_position_m[k] - p.correction.node_position_m[k]).norm(), 1e-3);
    EXPECT_LT((q.correction.node_correction[k] - p.correction.node_correction[k])
                  .head<2>()
                  .cwiseAbs()
                  .maxCoeff(),
              5e-4 + 1e-12);
    EXPECT_NEAR(q.correction.node_correction[k].z(), p.correction.node_correction[k].z(),
                5e-7 + 1e-15);
  }
  EXPECT_LT(placement_difference_m(p, q), 2e-3);
  // The text is its own fixed point.
  EXPECT_EQ(encode_drive_placement(q), text);
}

TEST(DrivePlacement, EmptyTextIsAsUploaded) {
  EXPECT_TRUE(decode_drive_placement("", "test").as_uploaded());
  EXPECT_EQ(encode_drive_placement(DrivePlacement{}), "");
  EXPECT_EQ(placement_difference_m(DrivePlacement{}, DrivePlacement{}), 0.0);
  const GeoPoint g{48.78, 9.19, 0.0};
  const GeoPoint h = placed(DrivePlacement{}, g);
  EXPECT_EQ(h.lat_deg, g.lat_deg);
  EXPECT_EQ(h.lon_deg, g.lon_deg);
  EXPECT_FALSE(placement_warp(DrivePlacement{}, tiles::LocalFrame(kOrigin)));
}

TEST(DrivePlacement, MalformedTextIsRejectedNamingItsSource) {
  const std::string good = encode_drive_placement(straight(0.5, 0.0));
  auto with = [&](const std::string& key, const nlohmann::json& value) {
    nlohmann::json j = nlohmann::json::parse(good);
    if (value.is_null()) {
      j.erase(key);
    } else {
      j[key] = value;
    }
    return j.dump();
  };
  const std::vector<std::string> bad = {
      "not json",
      "[1, 2]",
      with("format", 2),
      with("format", "1"),
      with("frame_origin", nlohmann::json::array({48.0, 9.0})),
      with("frame_origin", nlohmann::json::array({91.0, 9.0, 0.0})),
      with("candidate_lead_m", nullptr),
      with("candidate_lead_m", "x"),
      with("node_s_m", nlohmann::json::array({0.0, 20.0, 10.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0,
                                              90.0, 100.0})),  // not ordered
      with("node_xy_m", nlohmann::json::array({0.0, 0.0})),    // too few
      with("node_correction", nullptr),
      with("path_s_m", nlohmann::json::array()),
      with("path_xy_m", nlohmann::json::array({"a"})),
  };
  for (const std::string& text : bad) {
    try {
      (void)decode_drive_placement(text, "gridmap sum input abc");
      ADD_FAILURE() << "accepted: " << text.substr(0, 120);
    } catch (const ValidationError& e) {
      EXPECT_NE(std::string(e.what()).find("gridmap sum input abc"), std::string::npos) << e.what();
    }
  }
}

TEST(DrivePlacement, DifferenceIsWhereTheyPutTheDriveApart) {
  const DrivePlacement a = straight(0.2, 0.0);
  EXPECT_NEAR(placement_difference_m(a, straight(0.2, 0.0)), 0.0, 1e-6);
  EXPECT_NEAR(placement_difference_m(a, straight(0.2, 0.3)), 0.3, 1e-3);
  EXPECT_NEAR(placement_difference_m(a, DrivePlacement{}), 0.2, 1e-3);
  EXPECT_NEAR(placement_difference_m(DrivePlacement{}, a), 0.2, 1e-3);
  // A heading correction turns the gridmap about where it was seen from (10 m back along
  // the drive): a point 30 m to the side moves by |(10, 30)| m x 1 mrad.
  EXPECT_NEAR(placement_difference_m(straight(0.0, 0.0, 0.001), straight(0.0, 0.0)),
              std::sqrt(10.0 * 10.0 + 30.0 * 30.0) * 0.001, 1e-4);
}

TEST(DrivePlacement, TheWarpMovesDriveFramePointsByTheCorrection) {
  const DrivePlacement p = straight(0.5, -0.25);
  // The drive's own frame 40 m east of the build frame's origin.
  const tiles::LocalFrame build(kOrigin);
  const tiles::LocalFrame drive(build.to_geo(Eigen::Vector2d(40.0, 0.0)));
  const GridmapWarp warp = placement_warp(p, drive);
  ASSERT_TRUE(warp);
  for (const Eigen::Vector2d& xy : {Eigen::Vector2d(0.0, 5.0), Eigen::Vector2d(20.0, -12.0)}) {
    EXPECT_LT((warp(xy) - (xy + Eigen::Vector2d(0.5, -0.25))).norm(), 1e-3);
  }
}

}  // namespace
}  // namespace polmap::mapping
