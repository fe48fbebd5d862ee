// Drive placements in the merged gridmap (drive_placement.hpp).
#include "polmap/mapping_service/drive_placement.hpp"

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <optional>

#include "polmap/schema/errors.hpp"

namespace polmap::mapping {
namespace {

constexpr int kPlacementFormat = 1;

double rounded(double v, double unit) { return std::round(v / unit) * unit; }

// A flat array of finite numbers in groups of `per` (at most kMaxPlacementNodes groups), and
// exactly `groups` of them unless that is 0.
std::vector<double> numbers(const nlohmann::json& j, const char* key, std::size_t per,
                            const std::string& source, std::size_t groups = 0) {
  const auto it = j.find(key);
  if (it == j.end() || !it->is_array() || it->size() % per != 0 ||
      it->size() / per > kMaxPlacementNodes || (groups > 0 && it->size() != groups * per)) {
    throw ValidationError(
        source + ": placement field '" + key + "' must be an array of " +
        (groups > 0 ? std::to_string(groups) : "at most " + std::to_string(kMaxPlacementNodes)) +
        " groups of " + std::to_string(per) + " numbers");
  }
  std::vector<double> out;
  out.reserve(it->size());
  for (const auto& v : *it) {
    if (!v.is_number() || !std::isfinite(v.get<double>())) {
      throw ValidationError(source + ": placement field '" + key + "' holds a non-finite value");
    }
    out.push_back(v.get<double>());
  }
  return out;
}

void require_ordered(const std::vector<double>& s, const char* key, const std::string& source) {
  if (!std::is_sorted(s.begin(), s.end())) {
    throw ValidationError(source + ": placement field '" + key + "' must not decrease");
  }
}

}  // namespace

DrivePlacement drive_placement(const tiles::LocalFrame& build_frame,
                               const DriveCorrection& correction) {
  return {build_frame.origin(), correction};
}

std::string encode_drive_placement(const DrivePlacement& p) {
  if (p.as_uploaded()) return {};
  const DriveCorrection& c = p.correction;
  nlohmann::json j;
  j["format"] = kPlacementFormat;
  j["frame_origin"] = {p.frame_origin->lat_deg, p.frame_origin->lon_deg, p.frame_origin->alt_m};
  j["candidate_lead_m"] = c.candidate_lead_m;
  auto& ns = j["node_s_m"] = nlohmann::json::array();
  auto& nxy = j["node_xy_m"] = nlohmann::json::array();
  auto& nc = j["node_correction"] = nlohmann::json::array();
  for (std::size_t k = 0; k < c.node_s_m.size(); ++k) {
    ns.push_back(rounded(c.node_s_m[k], 1e-3));
    nxy.push_back(rounded(c.node_position_m[k].x(), 1e-3));
    nxy.push_back(rounded(c.node_position_m[k].y(), 1e-3));
    nc.push_back(rounded(c.node_correction[k].x(), 1e-3));
    nc.push_back(rounded(c.node_correction[k].y(), 1e-3));
    nc.push_back(rounded(c.node_correction[k].z(), 1e-6));
  }
  auto& ps = j["path_s_m"] = nlohmann::json::array();
  auto& pxy = j["path_xy_m"] = nlohmann::json::array();
  for (std::size_t i = 0; i < c.path_m.size(); ++i) {
    ps.push_back(rounded(c.path_s_m[i], 1e-3));
    pxy.push_back(rounded(c.path_m[i].x(), 1e-3));
    pxy.push_back(rounded(c.path_m[i].y(), 1e-3));
  }
  return j.dump();
}

DrivePlacement decode_drive_placement(std::string_view text, const std::string& source) {
  DrivePlacement p;
  if (text.empty()) return p;
  const nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
  if (j.is_discarded() || !j.is_object()) {
    throw ValidationError(source + ": placement is not a JSON object");
  }
  const auto format = j.find("format");
  if (format == j.end() || !format->is_number_integer() || format->get<int>() != kPlacementFormat) {
    throw ValidationError(source + ": placement format must be " +
                          std::to_string(kPlacementFormat));
  }
  const std::vector<double> o = numbers(j, "frame_origin", 3, source, 1);
  if (std::abs(o[0]) > 90.0 || std::abs(o[1]) > 180.0) {
    throw ValidationError(source + ": placement frame_origin is not a WGS84 position");
  }
  p.frame_origin = GeoPoint{o[0], o[1], o[2]};
  DriveCorrection& c = p.correction;
  const auto lead = j.find("candidate_lead_m");
  if (lead == j.end() || !lead->is_number() || !std::isfinite(lead->get<double>())) {
    throw ValidationError(source + ": placement field 'candidate_lead_m' must be a finite number");
  }
  c.candidate_lead_m = lead->get<double>();
  c.node_s_m = numbers(j, "node_s_m", 1, source);
  c.path_s_m = numbers(j, "path_s_m", 1, source);
  const std::size_t n = c.node_s_m.size(), m = c.path_s_m.size();
  if (n == 0 || m == 0) throw ValidationError(source + ": placement has no nodes or no path");
  require_ordered(c.node_s_m, "node_s_m", source);
  require_ordered(c.path_s_m, "path_s_m", source);
  const std::vector<double> nxy = numbers(j, "node_xy_m", 2, source, n);
  const std::vector<double> nc = numbers(j, "node_correction", 3, source, n);
  for (std::size_t k = 0; k < n; ++k) {
    c.node_position_m.emplace_back(nxy[2 * k], nxy[2 * k + 1]);
    c.node_correction.emplace_back(nc[3 * k], nc[3 * k + 1], nc[3 * k + 2]);
  }
  const std::vector<double> pxy = numbers(j, "path_xy_m", 2, source, m);
  for (std::size_t i = 0; i < m; ++i) c.path_m.emplace_back(pxy[2 * i], pxy[2 * i + 1]);
  return p;
}

namespace {

// Where p puts g, with p's frame already built (none: as uploaded).
GeoPoint placed_in(const DrivePlacement& p, const std::optional<tiles::LocalFrame>& frame,
                   const GeoPoint& g) {
  if (!frame) return g;
  return frame->to_geo(p.correction.apply(frame->to_local(g), true));
}

std::optional<tiles::LocalFrame> frame_of(const DrivePlacement& p) {
  return p.as_uploaded() ? std::nullopt : std::optional<tiles::LocalFrame>(*p.frame_origin);
}

}  // namespace

GeoPoint placed(const DrivePlacement& p, const GeoPoint& g) { return placed_in(p, frame_of(p), g); }

double placement_difference_m(const DrivePlacement& a, const DrivePlacement& b) {
  const DrivePlacement& ref = a.as_uploaded() ? b : a;
  if (ref.as_uploaded()) return 0.0;
  const tiles::LocalFrame frame(*ref.frame_origin);
  const std::optional<tiles::LocalFrame> fa = frame_of(a), fb = frame_of(b);
  const auto& path = ref.correction.path_m;
  double worst = 0.0;
  for (std::size_t i = 0; i < path.size(); i += 5) {
    const std::size_t j = std::min(i + 1, path.size() - 1);
    const std::size_t h = i > 0 ? i - 1 : 0;
    Eigen::Vector2d t = path[j] - path[h];
    if (t.norm() < 1e-9) t = Eigen::Vector2d::UnitX();
    const Eigen::Vector2d normal = Eigen::Vector2d(-t.y(), t.x()).normalized();
    for (const double side_m : {-30.0, 0.0, 30.0}) {
      const GeoPoint g = frame.to_geo(path[i] + side_m * normal);
      const Eigen::Vector2d qa = frame.to_local(placed_in(a, fa, g));
      const Eigen::Vector2d qb = frame.to_local(placed_in(b, fb, g));
      worst = std::max(worst, (qa - qb).norm());
    }
  }
  return worst;
}

GridmapWarp placement_warp(const DrivePlacement& p, const tiles::LocalFrame& drive_frame) {
  if (p.as_uploaded()) return {};
  const tiles::LocalFrame frame(*p.frame_origin);
  return [c = p.correction, frame, drive_frame](const Eigen::Vector2d& xy_m) {
    const Eigen::Vector2d in_build = frame.to_local(drive_frame.to_geo(xy_m));
    return drive_frame.to_local(frame.to_geo(c.apply(in_build, true)));
  };
}

}  // namespace polmap::mapping
