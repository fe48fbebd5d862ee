// Landmark vector-tile layers (landmark_mvt.hpp).
#include "polmap/mapping_service/landmark_mvt.hpp"

#include <algorithm>
#include <string>

namespace polmap::mapping {

LandmarkMvtLayers landmark_mvt_layers(const LandmarkSet& lm, std::int64_t version) {
  LandmarkMvtLayers out;
  for (const StoredPointLandmark& p : lm.points) {
    out.points.features.push_back({static_cast<std::uint64_t>(p.key),
                                   tiles::MvtGeometryType::Point,
                                   {{p.position}},
                                   {{"id", std::int64_t{p.key}},
                                    {"key", std::to_string(p.key)},
                                    {"class", std::string(to_string(p.scattering))},
                                    {"support_drives", std::uint64_t{p.support_drives}},
                                    {"spread_m", p.spread_m},
                                    {"map_version", version}}});
  }
  for (const StoredLineLandmark& l : lm.lines) {
    out.lines.features.push_back({static_cast<std::uint64_t>(l.key),
                                  tiles::MvtGeometryType::LineString,
                                  {l.polyline},
                                  {{"id", std::int64_t{l.key}},
                                   {"key", std::to_string(l.key)},
                                   {"support_drives", std::uint64_t{l.support_drives}},
                                   {"spread_m", l.spread_m},
                                   {"map_version", version}}});
  }
  return out;
}

nlohmann::json landmark_vector_layers_json() {
  nlohmann::json landmark_fields{{"id", "Number: stable landmark id"},
                                 {"key",
                                  "String: the stable id in decimal (exact where a Number is a "
                                  "double, e.g. in JavaScript)"},
                                 {"support_drives", "Number: distinct drives that saw it"},
                                 {"spread_m", "Number: RMS distance of members to the mean, m"},
                                 {"map_version", "Number: map version"}};
  nlohmann::json point_fields = landmark_fields;
  point_fields["class"] = "String: scattering class (odd, even, mixed, unknown)";
  return {{{"id", "points"}, {"description", "point landmarks"}, {"fields", point_fields}},
          {{"id", "lines"}, {"description", "line landmarks"}, {"fields", landmark_fields}}};
}

tiles::GeoBox buffered_tile_bounds(const tiles::TileKey& key, double fraction) {
  tiles::GeoBox b = tiles::tile_bounds(key);
  const double dlat = (b.max_lat_deg - b.min_lat_deg) * fraction;
  const double dlon = (b.max_lon_deg - b.min_lon_deg) * fraction;
  b.min_lat_deg = std::max(-90.0, b.min_lat_deg - dlat);
  b.max_lat_deg = std::min(90.0, b.max_lat_deg + dlat);
  // The store does not take antimeridian-crossing boxes: clamp instead of wrapping.
  b.min_lon_deg = std::max(-180.0, b.min_lon_deg - dlon);
  b.max_lon_deg = std::min(180.0, b.max_lon_deg + dlon);
  return b;
}

}  // namespace polmap::mapping
