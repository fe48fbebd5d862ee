#pragma once
/// @file truth.hpp
/// World truth beside the recordings, for evaluation only (never read by the
/// processing): DIR/truth/world.json and DIR/truth/drive_<k>_trajectory.csv.
#include <filesystem>
#include <string>
#include <vector>

#include "polmap/sim/config.hpp"
#include "polmap/sim/drive.hpp"
#include "polmap/sim/world.hpp"

namespace polmap::sim {

/// JSON text of world.json: {"format": "polmap-sim-world-truth", "version": 1, "world",
/// "origin": {lat_deg, lon_deg, alt_m}, "frame": "transverse Mercator at origin (x east,
/// y north, m)", "seed", "num_drives", "route": {"length_m", "xy": [[x,y],...] every 1 m},
/// "objects": [{id, class, mechanism, permanent, presence_probability, drives_present,
/// rcs_dbsm, source, and either "position": {lat_deg, lon_deg, x_m, y_m} or "polyline":
/// [{lat_deg, lon_deg, x_m, y_m}, ...]}]}. A temporary point object that stands somewhere
/// else in each drive (WorldObject::drive_shift_max_m) also has "positions_by_drive": its
/// position in each drive of drives_present, in that order.
std::string world_truth_json(const World& world, int num_drives, std::uint64_t seed);

/// Writes DIR/truth/world.json (creates DIR/truth). Throws IoError naming the file.
void write_world_truth(const std::filesystem::path& dir, const World& world, int num_drives,
                       std::uint64_t seed);

/// Writes the exact trajectory as CSV: time_s,lat_deg,lon_deg,yaw_enu_rad,v_mps,yaw_rate_rps.
void write_trajectory_csv(const std::filesystem::path& file, const std::vector<ExactState>& states,
                          const tiles::LocalFrame& frame);

/// Writes the true sensor calibration of a drive (DIR/truth/drive_<k>_calibration.json, for
/// evaluating the online mount calibration only): {format: "polmap-sim-calibration-truth",
/// version: 1, sensors: [{sensor_id, nominal {x_m, y_m, yaw_rad}, true {x_m, y_m, yaw_rad},
/// yaw_offset_rad (true − nominal), time_offset_s (true measurement time − stamp)}]}.
void write_calibration_truth(const std::filesystem::path& file,
                             const std::vector<SensorMount>& nominal,
                             const std::vector<SensorMount>& true_mounts,
                             const std::vector<double>& time_offsets_s);

}  // namespace polmap::sim
