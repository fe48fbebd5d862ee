#include "polmap/localization_client/tile_source.hpp"

#include <algorithm>

#include "polmap/tiles/local_frame.hpp"

namespace polmap::loc {

std::vector<tiles::TileKey> tiles_around(const GeoPoint& p, double radius_m, int z) {
  const tiles::LocalFrame f(p);
  const GeoPoint sw = f.to_geo({-radius_m, -radius_m});
  const GeoPoint ne = f.to_geo({radius_m, radius_m});
  tiles::GeoBox box;
  box.min_lat_deg = std::min(sw.lat_deg, ne.lat_deg);
  box.max_lat_deg = std::max(sw.lat_deg, ne.lat_deg);
  // Across the antimeridian min_lon > max_lon, which tiles_covering handles.
  box.min_lon_deg = sw.lon_deg;
  box.max_lon_deg = ne.lon_deg;
  return tiles::tiles_covering(box, z);
}

}  // namespace polmap::loc
