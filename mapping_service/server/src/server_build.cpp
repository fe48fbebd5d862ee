#include "server_build.hpp"

#include "polmap/mapping_service/map_builder.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::mapping {
namespace {

MapBuildRequest to_request(const nlohmann::json& j) {
  MapBuildRequest r;
  if (j.contains("region")) {
    const auto& g = j["region"];
    r.region = tiles::GeoBox{g.at("min_lat_deg").get<double>(), g.at("min_lon_deg").get<double>(),
                             g.at("max_lat_deg").get<double>(), g.at("max_lon_deg").get<double>()};
  }
  if (j.contains("exclude_drives")) {
    r.excluded_drive_ids = j["exclude_drives"].get<std::vector<std::string>>();
  }
  if (j.contains("notes")) r.notes = j["notes"].get<std::string>();
  if (j.contains("partition")) {  // from the server's configuration, not from the client
    BuildPartition p;
    p.zoom = j["partition"].at("zoom").get<int>();
    p.halo_m = j["partition"].at("halo_m").get<double>();
    r.partition = p;
  }
  return r;
}

const MapBuilder& builder() {
  static const MapBuilder b{};
  return b;
}

}  // namespace

std::int64_t begin_build(MapStore& store, const nlohmann::json& request) {
  return builder().begin(store, to_request(request));
}

nlohmann::json execute_build(MapStore& store, std::int64_t version, const nlohmann::json& request,
                             const std::atomic<bool>& stop, bool run_jobs,
                             const std::function<void(std::string_view, double)>& progress) {
  BuildControl control;
  control.cancel = &stop;
  control.run_jobs = run_jobs;
  control.progress = progress;
  const MapBuildResult r = builder().run(store, version, to_request(request), control);
  if (r.status != MapBuildResult::Status::Published) {
    const std::string status(to_string(r.status));
    throw Error(r.error.empty() || r.error == status ? status : status + ": " + r.error);
  }
  return to_json(r.stats);
}

}  // namespace polmap::mapping
