#pragma once
/// @file lanelet2_osm.hpp
/// The Lanelet2 OSM document: nodes with WGS84 positions, ways with node references,
/// relations with members, each with its `type` / `subtype` tags. What a way or a
/// relation means (a curb, a lanelet) is for the reader's caller to decide.
#include <cstdint>
#include <filesystem>
#include <string>
#include <unordered_map>
#include <vector>

#include "polmap/schema/geo.hpp"

namespace polmap::hdmap {

struct OsmNode {
  std::int64_t id = 0;
  GeoPoint position;   ///< lat/lon from the attributes (local_x/local_y ignored); alt_m = 0
  double ele_m = 0.0;  ///< the `ele` tag, 0 when absent
  std::string type;    ///< `type` tag ("" when absent)
  std::string subtype;
};

struct OsmWay {
  std::int64_t id = 0;
  std::vector<std::int64_t> node_refs;  ///< as in the file; may name nodes that do not exist
  std::string type;
  std::string subtype;
};

struct OsmMember {
  std::string type;  ///< node, way, relation
  std::int64_t ref = 0;
  std::string role;
};

struct OsmRelation {
  std::int64_t id = 0;
  std::vector<OsmMember> members;
  std::string type;
  std::string subtype;
};

/// A parsed file; vectors keep the file order.
struct Lanelet2Osm {
  std::vector<OsmNode> nodes;
  std::vector<OsmWay> ways;
  std::vector<OsmRelation> relations;
  std::unordered_map<std::int64_t, std::size_t> node_index;  ///< node id -> index in nodes

  /// The node with this id, or nullptr.
  [[nodiscard]] const OsmNode* node(std::int64_t id) const {
    const auto it = node_index.find(id);
    return it == node_index.end() ? nullptr : &nodes[it->second];
  }
};

/// Reads a Lanelet2 OSM file. Throws IoError if it cannot be read, FormatError naming
/// the file (and the element) for malformed XML, a missing <osm> root, or a node whose
/// lat/lon is missing, not a number or out of range.
[[nodiscard]] Lanelet2Osm read_lanelet2_osm_file(const std::filesystem::path& path);

}  // namespace polmap::hdmap
