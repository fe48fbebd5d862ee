#pragma once
/// @file geo.hpp
/// Geodetic values (WGS84). Projections live in tiles/ (GeographicLib).

namespace polmap {

/// A WGS84 position in degrees; altitude above the ellipsoid in metres.
struct GeoPoint {
  double lat_deg = 0.0;
  double lon_deg = 0.0;
  double alt_m = 0.0;
};

/// Georeferenced planar pose. yaw_enu_rad is the yaw of the vehicle x axis,
/// counter-clockwise from east (ENU convention, as in all local metric frames;
/// GNSS heading clockwise from north converts as yaw = pi/2 - heading).
struct GeoPose {
  GeoPoint position;
  double yaw_enu_rad = 0.0;
};

}  // namespace polmap
