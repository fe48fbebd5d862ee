#include "polmap/sim/truth.hpp"

#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>

#include "polmap/schema/errors.hpp"

namespace polmap::sim {

namespace {
nlohmann::json geo_xy(const World& w, const Eigen::Vector2d& p) {
  const GeoPoint g = w.frame.to_geo(p);
  return {{"lat_deg", g.lat_deg}, {"lon_deg", g.lon_deg}, {"x_m", p.x()}, {"y_m", p.y()}};
}
}  // namespace

std::string world_truth_json(const World& w, int num_drives, std::uint64_t seed) {
  nlohmann::json j;
  j["format"] = "polmap-sim-world-truth";
  j["version"] = 1;
  j["world"] = w.name;
  j["origin"] = {{"lat_deg", w.origin().lat_deg},
                 {"lon_deg", w.origin().lon_deg},
                 {"alt_m", w.origin().alt_m}};
  j["frame"] = "transverse Mercator at origin (x east, y north, metres), as tiles::LocalFrame";
  j["seed"] = seed;
  j["num_drives"] = num_drives;
  nlohmann::json route = nlohmann::json::array();
  for (double s = 0; s <= w.route.length_m(); s += 1.0) {
    const PathPoint p = w.route.at(s);
    route.push_back({p.x_m, p.y_m});
  }
  j["route"] = {{"length_m", w.route.length_m()}, {"xy", route}};
  nlohmann::json lights = nlohmann::json::array();
  for (double s : w.light_stations_m) lights.push_back(s);
  j["route"]["light_stations_m"] = lights;
  nlohmann::json objs = nlohmann::json::array();
  for (const WorldObject& o : w.objects) {
    nlohmann::json jo;
    jo["id"] = o.id;
    jo["class"] = std::string(to_string(o.cls));
    jo["mechanism"] = std::string(to_string(o.mechanism));
    jo["permanent"] = o.permanent;
    jo["presence_probability"] = o.presence_probability;
    nlohmann::json dp = nlohmann::json::array();
    for (int d = 0; d < num_drives; ++d) {
      if (w.present(o.id, d, seed)) dp.push_back(d);
    }
    jo["drives_present"] = dp;
    jo["rcs_dbsm"] = o.rcs_dbsm;
    jo["rcs_unit"] = o.geometry_m.size() > 1 ? "dBsm per metre" : "dBsm";
    jo["source"] = o.source;
    if (o.geometry_m.size() == 1) {
      jo["position"] = geo_xy(w, o.geometry_m.front());
      if (!o.permanent && o.drive_shift_max_m > 0.0) {
        nlohmann::json pd = nlohmann::json::array();
        for (int d : dp)
          pd.push_back(geo_xy(w, o.geometry_m.front() + w.drive_shift_m(o.id, d, seed)));
        jo["positions_by_drive"] = pd;
      }
    } else {
      nlohmann::json pl = nlohmann::json::array();
      for (const auto& p : o.geometry_m) pl.push_back(geo_xy(w, p));
      jo["polyline"] = pl;
    }
    objs.push_back(std::move(jo));
  }
  j["objects"] = std::move(objs);
  return j.dump(1);
}

void write_world_truth(const std::filesystem::path& dir, const World& world, int num_drives,
                       std::uint64_t seed) {
  const std::filesystem::path tdir = dir / "truth";
  std::error_code ec;
  std::filesystem::create_directories(tdir, ec);
  if (ec) throw IoError("cannot create " + tdir.string() + ": " + ec.message());
  const std::filesystem::path f = tdir / "world.json";
  std::ofstream out(f, std::ios::binary);
  if (!out) throw IoError("cannot write " + f.string());
  out << world_truth_json(world, num_drives, seed) << '\n';
  if (!out) throw IoError("write failed: " + f.string());
}

void write_trajectory_csv(const std::filesystem::path& file, const std::vector<ExactState>& states,
                          const tiles::LocalFrame& frame) {
  std::error_code ec;
  if (file.has_parent_path()) std::filesystem::create_directories(file.parent_path(), ec);
  std::ofstream out(file, std::ios::binary);
  if (!out) throw IoError("cannot write " + file.string());
  out << "time_s,lat_deg,lon_deg,yaw_enu_rad,v_mps,yaw_rate_rps\n";
  char buf[256];
  for (const ExactState& s : states) {
    const GeoTruth g = to_geo_truth(s, frame);
    std::snprintf(buf, sizeof buf, "%.4f,%.10f,%.10f,%.8f,%.6f,%.8f\n", s.time_s, g.lat_deg,
                  g.lon_deg, g.yaw_enu_rad, s.v_mps, s.yaw_rate_rps);
    out << buf;
  }
  if (!out) throw IoError("write failed: " + file.string());
}

void write_calibration_truth(const std::filesystem::path& file,
                             const std::vector<SensorMount>& nominal,
                             const std::vector<SensorMount>& true_mounts,
                             const std::vector<double>& time_offsets_s) {
  if (nominal.size() != true_mounts.size() || nominal.size() != time_offsets_s.size()) {
    throw ContractViolation("write_calibration_truth: sizes differ");
  }
  nlohmann::json j{{"format", "polmap-sim-calibration-truth"}, {"version", 1}};
  auto pose = [](const Pose2& T) {
    return nlohmann::json{{"x_m", T.x_m}, {"y_m", T.y_m}, {"yaw_rad", T.yaw_rad}};
  };
  nlohmann::json sensors = nlohmann::json::array();
  for (std::size_t i = 0; i < nominal.size(); ++i) {
    sensors.push_back({{"sensor_id", nominal[i].sensor_id},
                       {"nominal", pose(nominal[i].T_vehicle_sensor)},
                       {"true", pose(true_mounts[i].T_vehicle_sensor)},
                       {"yaw_offset_rad", true_mounts[i].T_vehicle_sensor.yaw_rad -
                                              nominal[i].T_vehicle_sensor.yaw_rad},
                       {"time_offset_s", time_offsets_s[i]}});
  }
  j["sensors"] = sensors;
  std::error_code ec;
  if (file.has_parent_path()) std::filesystem::create_directories(file.parent_path(), ec);
  std::ofstream out(file, std::ios::binary);
  if (!out) throw IoError("cannot write " + file.string());
  out << j.dump(2) << '\n';
  if (!out) throw IoError("write failed: " + file.string());
}

}  // namespace polmap::sim
