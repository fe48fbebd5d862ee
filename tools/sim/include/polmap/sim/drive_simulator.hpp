#pragma once
/// @file drive_simulator.hpp
/// Streams one simulated drive as a time-ordered record stream (trajectory
/// samples at the GNSS rate, sensor frames at their trigger times) without
/// touching disk: processing stages consume it as a RecordSource.
#include <memory>
#include <optional>
#include <vector>

#include "polmap/schema/recording.hpp"
#include "polmap/sim/config.hpp"
#include "polmap/sim/drive.hpp"
#include "polmap/sim/spectrum.hpp"
#include "polmap/sim/world.hpp"

namespace polmap::sim {

/// Renders one sensor frame of a world: occlusion, aspect, radar equation, extended objects,
/// moving traffic -> spectrum, detections (and cube). Exposed for tests and benchmarks.
class FrameRenderer {
 public:
  FrameRenderer(std::shared_ptr<const World> world, const SimConfig& cfg);
  /// Renders the frame of `mount` at the exact vehicle state; `plan` supplies presence and
  /// traffic (nullptr: everything present, no traffic); extra_movers are added (tests).
  SensorFrame render(const SensorMount& mount, const ExactState& vehicle, const DrivePlan* plan,
                     std::uint32_t cycle_index, bool with_cube, std::uint64_t frame_seed,
                     const std::vector<Mover>* extra_movers = nullptr);
  [[nodiscard]] const SpectrumSynthesizer& synthesizer() const { return synth_; }

 private:
  struct OccSeg {
    Eigen::Vector2d a, b;
  };
  void add_occluder(const Eigen::Vector2d& a, const Eigen::Vector2d& b, bool vegetation);
  [[nodiscard]] double occlusion_loss(double range_m, double azimuth_rad) const;
  [[nodiscard]] int occ_bin(double az) const;

  std::shared_ptr<const World> world_;
  SimConfig cfg_;
  SpectrumSynthesizer synth_;
  // per-frame scratch
  std::vector<std::uint32_t> q_points_, q_lines_, q_occ_;
  std::vector<OccSeg> segs_;
  std::vector<int> occ_opaque_, occ_veg_;
  std::vector<float> occ_opaque_r_, occ_veg_r_;
  double occ_lo_rad_ = 0, occ_step_rad_ = 0;
  std::vector<OverheadStructure> overhead_;  ///< realism: elevation (empty when ideal)
};

class DriveSimulator final : public RecordSource {
 public:
  DriveSimulator(std::shared_ptr<const World> world, const SimConfig& cfg, int drive_index);

  [[nodiscard]] const RecordingHeader& header() const override { return header_; }
  std::optional<RecordingRecord> next() override;

  [[nodiscard]] const DrivePlan& plan() const { return plan_; }
  [[nodiscard]] const World& world() const { return *world_; }
  [[nodiscard]] double duration_s() const { return plan_.duration_s(); }
  /// Simulated time of the last record returned.
  [[nodiscard]] double time_s() const { return last_time_; }
  [[nodiscard]] const GnssErrorModel& gnss() const { return gnss_; }
  /// Exact states at the trajectory sample times (truth CSV).
  [[nodiscard]] std::vector<ExactState> exact_trajectory() const;
  /// The trajectory samples next() returns (the positioning solution with its errors, same
  /// times as exact_trajectory()) without rendering a frame: for analyses of the GNSS
  /// errors of many drives. Call it before next().
  [[nodiscard]] std::vector<TrajectorySample> recorded_trajectory() const;
  /// The mounts the sensors really have in this drive (== header().sensors when ideal).
  [[nodiscard]] const std::vector<SensorMount>& true_mounts() const { return true_mounts_; }
  /// Per-sensor time offsets (true time = stamp + offset), indexed like header().sensors.
  [[nodiscard]] const std::vector<double>& time_offsets_s() const { return time_offsets_s_; }

 private:
  /// The trajectory sample at t_s drawn from gnss (next() and recorded_trajectory()).
  TrajectorySample trajectory_sample(GnssErrorModel& gnss, double t_s) const;

  std::shared_ptr<const World> world_;
  SimConfig cfg_;
  int drive_;
  DrivePlan plan_;
  GnssErrorModel gnss_;
  FrameRenderer renderer_;
  RecordingHeader header_;
  /// Realism (realism.hpp): mounts the sensors really have (the header keeps the nominal
  /// ones) and per-sensor time offsets, both indexed like cfg.sensors.
  std::vector<SensorMount> true_mounts_;
  std::vector<double> time_offsets_s_;
  std::vector<std::size_t> sensor_order_;  ///< mounts by trigger offset
  double frame_period_s_ = 0.1;
  std::uint64_t next_traj_ = 0;
  std::uint32_t next_cycle_ = 0;
  std::size_t next_sensor_ = 0;
  double last_time_ = 0.0;
};

}  // namespace polmap::sim
