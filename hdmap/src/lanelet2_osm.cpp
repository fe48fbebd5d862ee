#include "polmap/hdmap/lanelet2_osm.hpp"

#include <cmath>
#include <cstdlib>
#include <limits>
#include <pugixml.hpp>

#include "polmap/schema/errors.hpp"

namespace polmap::hdmap {
namespace {

template <typename T>
void read_tags(const pugi::xml_node& n, T& element) {
  for (const auto& tag : n.children("tag")) {
    const std::string_view k = tag.attribute("k").as_string();
    if (k == "type") element.type = tag.attribute("v").as_string();
    if (k == "subtype") element.subtype = tag.attribute("v").as_string();
  }
}

/// The attribute as a number; NaN when missing or not entirely numeric (pugixml's
/// as_double would read "x" as 0).
double parse_number(const pugi::xml_attribute& a) {
  const char* s = a.value();
  if (!a || *s == '\0') return std::numeric_limits<double>::quiet_NaN();
  char* end = nullptr;
  const double v = std::strtod(s, &end);
  while (end != nullptr && (*end == ' ' || *end == '\t')) ++end;
  return (end != nullptr && *end == '\0') ? v : std::numeric_limits<double>::quiet_NaN();
}

}  // namespace

Lanelet2Osm read_lanelet2_osm_file(const std::filesystem::path& path) {
  const std::string name = path.string();
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw IoError(name + ": cannot open HD map");
  pugi::xml_document doc;
  const pugi::xml_parse_result r = doc.load_file(path.c_str());
  if (!r) {
    throw FormatError(name, static_cast<std::uint64_t>(r.offset),
                      std::string("not valid XML: ") + r.description());
  }
  const pugi::xml_node osm = doc.child("osm");
  if (!osm) throw FormatError(name, 0, "no <osm> root element (not a Lanelet2 OSM file)");

  Lanelet2Osm out;
  for (const auto& n : osm.children("node")) {
    OsmNode node;
    node.id = n.attribute("id").as_llong();
    node.position.lat_deg = parse_number(n.attribute("lat"));
    node.position.lon_deg = parse_number(n.attribute("lon"));
    if (!std::isfinite(node.position.lat_deg) || !std::isfinite(node.position.lon_deg) ||
        std::abs(node.position.lat_deg) > 90.0 || std::abs(node.position.lon_deg) > 180.0) {
      throw FormatError(name + ": node " + std::to_string(node.id) +
                        ": missing or invalid lat/lon");
    }
    for (const auto& t : n.children("tag")) {
      if (std::string_view(t.attribute("k").as_string()) == "ele")
        node.ele_m = t.attribute("v").as_double();
    }
    read_tags(n, node);
    out.node_index[node.id] = out.nodes.size();
    out.nodes.push_back(std::move(node));
  }
  for (const auto& w : osm.children("way")) {
    OsmWay way;
    way.id = w.attribute("id").as_llong();
    for (const auto& nd : w.children("nd")) way.node_refs.push_back(nd.attribute("ref").as_llong());
    read_tags(w, way);
    out.ways.push_back(std::move(way));
  }
  for (const auto& rel : osm.children("relation")) {
    OsmRelation r2;
    r2.id = rel.attribute("id").as_llong();
    for (const auto& m : rel.children("member")) {
      r2.members.push_back({m.attribute("type").as_string(), m.attribute("ref").as_llong(),
                            m.attribute("role").as_string()});
    }
    read_tags(rel, r2);
    out.relations.push_back(std::move(r2));
  }
  return out;
}

}  // namespace polmap::hdmap
