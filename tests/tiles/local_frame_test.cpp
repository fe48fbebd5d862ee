#include "polmap/tiles/local_frame.hpp"

#include <gtest/gtest.h>

#include <GeographicLib/Geodesic.hpp>
#include <cmath>
#include <numbers>

namespace polmap::tiles {
namespace {

TEST(LocalFrame, OriginMapsToZero) {
  const LocalFrame frame({48.4, 9.98, 500.0});
  const Eigen::Vector2d xy = frame.to_local(48.4, 9.98);
  EXPECT_NEAR(xy.norm(), 0.0, 1e-9);
}

TEST(LocalFrame, RoundTripIsSubMillimetreWithinTenKilometres) {
  const LocalFrame frame({35.22, 138.80, 0.0});
  for (double dx : {-10000.0, -1234.5, 0.0, 777.7, 10000.0}) {
    for (double dy : {-10000.0, 3.3, 10000.0}) {
      const GeoPoint g = frame.to_geo({dx, dy});
      const Eigen::Vector2d back = frame.to_local(g);
      EXPECT_NEAR(back.x(), dx, 1e-6);
      EXPECT_NEAR(back.y(), dy, 1e-6);
    }
  }
}

TEST(LocalFrame, DistancesMatchGeodesicsToScaleErrorBound) {
  const GeoPoint origin{52.5, 13.4, 0.0};
  const LocalFrame frame(origin);
  const auto& geod = GeographicLib::Geodesic::WGS84();
  for (double az : {0.0, 45.0, 90.0, 200.0}) {
    double lat2 = 0, lon2 = 0;
    geod.Direct(origin.lat_deg, origin.lon_deg, az, 5000.0, lat2, lon2);
    const double d = frame.to_local(lat2, lon2).norm();
    EXPECT_NEAR(d, 5000.0, 5000.0 * 1.3e-6) << "azimuth " << az;
  }
}

TEST(LocalFrame, ConvergenceTurnsTrueEastIntoFrameYaw) {
  const LocalFrame frame({60.0, 10.0, 0.0});
  const Eigen::Vector2d p = frame.to_local(60.05, 10.3);  // well off the central meridian
  const GeoPoint g = frame.to_geo(p);
  // Step 10 m true east (geodesic azimuth 90°) and read its direction in the frame.
  double lat2 = 0, lon2 = 0;
  GeographicLib::Geodesic::WGS84().Direct(g.lat_deg, g.lon_deg, 90.0, 10.0, lat2, lon2);
  const Eigen::Vector2d d = frame.to_local(lat2, lon2) - p;
  const double yaw_frame = std::atan2(d.y(), d.x());
  EXPECT_NEAR(yaw_frame, 0.0 + frame.convergence_rad(p), 2e-5);
  EXPECT_GT(std::abs(frame.convergence_rad(p)), 1e-3);  // the test is not trivial
}

}  // namespace
}  // namespace polmap::tiles
