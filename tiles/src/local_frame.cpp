#include "polmap/tiles/local_frame.hpp"

#include <GeographicLib/Constants.hpp>
#include <GeographicLib/TransverseMercator.hpp>
#include <cstdio>
#include <numbers>

namespace polmap::tiles {
namespace {
const GeographicLib::TransverseMercator& projection() {
  // Scale 1 on the central meridian: the frame is metric at its origin.
  static const GeographicLib::TransverseMercator tm(GeographicLib::Constants::WGS84_a(),
                                                    GeographicLib::Constants::WGS84_f(), 1.0);
  return tm;
}
}  // namespace

LocalFrame::LocalFrame(const GeoPoint& origin) : origin_(origin) {
  double x = 0, y = 0;
  projection().Forward(origin.lon_deg, origin.lat_deg, origin.lon_deg, x, y);
  northing_offset_m_ = y;
}

Eigen::Vector2d LocalFrame::to_local(double lat_deg, double lon_deg) const {
  double x = 0, y = 0;
  projection().Forward(origin_.lon_deg, lat_deg, lon_deg, x, y);
  return {x, y - northing_offset_m_};
}

GeoPoint LocalFrame::to_geo(const Eigen::Vector2d& xy_m) const {
  double lat = 0, lon = 0;
  projection().Reverse(origin_.lon_deg, xy_m.x(), xy_m.y() + northing_offset_m_, lat, lon);
  return {lat, lon, origin_.alt_m};
}

double LocalFrame::convergence_rad(const Eigen::Vector2d& xy_m) const {
  double lat = 0, lon = 0, gamma_deg = 0, k = 0;
  projection().Reverse(origin_.lon_deg, xy_m.x(), xy_m.y() + northing_offset_m_, lat, lon,
                       gamma_deg, k);
  // GeographicLib's gamma is the bearing of grid north from true north (clockwise);
  // a yaw measured from true east rotates by the same amount, counter-clockwise.
  return gamma_deg * std::numbers::pi / 180.0;
}

std::string LocalFrame::proj_string() const {
  char buf[256];
  std::snprintf(buf, sizeof(buf),
                "+proj=tmerc +lat_0=%.12f +lon_0=%.12f +k=1 +x_0=0 +y_0=0 +ellps=WGS84 "
                "+units=m +no_defs",
                origin_.lat_deg, origin_.lon_deg);
  return buf;
}

}  // namespace polmap::tiles
