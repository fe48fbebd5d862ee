#include "polmap/radar/drive_processor.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <limits>
#include <map>

namespace polmap::radar {
namespace {
using Clock = std::chrono::steady_clock;
double since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}
}  // namespace

TrajectoryInterpolator::TrajectoryInterpolator(tiles::LocalFrame frame, double max_gap_s,
                                               double max_extrapolation_s,
                                               double max_extrapolation_before_s)
    : frame_(std::move(frame)),
      max_gap_s_(max_gap_s),
      max_extrapolation_s_(max_extrapolation_s),
      max_extrapolation_before_s_(max_extrapolation_before_s) {}

bool TrajectoryInterpolator::add(const TrajectorySample& s) {
  if (samples_.size() > first_ && !(s.time_s > samples_.back().t)) return false;
  const Eigen::Vector2d xy = frame_.to_local(s.lat_deg, s.lon_deg);
  const double yaw = wrap_angle_rad(s.yaw_enu_rad + frame_.convergence_rad(xy));
  samples_.push_back({s.time_s, {xy.x(), xy.y(), yaw}, s.speed_mps, s.yaw_rate_rps});
  return true;
}

double TrajectoryInterpolator::last_time_s() const {
  return samples_.size() > first_ ? samples_.back().t : -std::numeric_limits<double>::infinity();
}

void TrajectoryInterpolator::forget_before(double time_s) {
  while (first_ + 1 < samples_.size() && samples_[first_ + 1].t <= time_s) ++first_;
  // Compact now and then so memory stays bounded on long drives.
  if (first_ > 4096 && first_ * 2 > samples_.size()) {
    samples_.erase(samples_.begin(), samples_.begin() + static_cast<std::ptrdiff_t>(first_));
    first_ = 0;
  }
}

std::optional<std::size_t> TrajectoryInterpolator::bracket(double t) const {
  if (samples_.size() <= first_ + 1) return std::nullopt;
  auto it = std::upper_bound(samples_.begin() + static_cast<std::ptrdiff_t>(first_), samples_.end(),
                             t, [](double x, const Sample& s) { return x < s.t; });
  if (it == samples_.begin() + static_cast<std::ptrdiff_t>(first_) || it == samples_.end()) {
    return std::nullopt;
  }
  const std::size_t i = static_cast<std::size_t>(it - samples_.begin()) - 1;
  if (samples_[i + 1].t - samples_[i].t > max_gap_s_) return std::nullopt;
  return i;
}

std::optional<Pose2> TrajectoryInterpolator::T_frame_vehicle(double t) const {
  if (samples_.size() <= first_) return std::nullopt;
  const Sample& last = samples_.back();
  if (t >= last.t) {
    if (t - last.t > max_extrapolation_s_) return std::nullopt;
    // Constant speed and yaw rate beyond the last sample (arc model, zero side slip).
    return last.T * integrate_motion(last.v, last.w, t - last.t);
  }
  // Likewise before the first sample: a calibrated time offset moves the drive's first
  // frames a fraction of a millisecond before the trajectory's start.
  const Sample& first = samples_[first_];
  if (t < first.t) {
    if (first.t - t > max_extrapolation_before_s_) return std::nullopt;
    return first.T * integrate_motion(first.v, first.w, t - first.t);
  }
  const auto i = bracket(t);
  if (!i) return std::nullopt;
  const Sample& a = samples_[*i];
  const Sample& b = samples_[*i + 1];
  const double w = (t - a.t) / (b.t - a.t);
  return Pose2{a.T.x_m + w * (b.T.x_m - a.T.x_m), a.T.y_m + w * (b.T.y_m - a.T.y_m),
               wrap_angle_rad(a.T.yaw_rad + w * wrap_angle_rad(b.T.yaw_rad - a.T.yaw_rad))};
}

std::optional<std::pair<double, double>> TrajectoryInterpolator::motion(double t) const {
  if (samples_.size() <= first_) return std::nullopt;
  const Sample& last = samples_.back();
  if (t >= last.t) {
    if (t - last.t > max_extrapolation_s_) return std::nullopt;
    return std::make_pair(last.v, last.w);
  }
  const Sample& first = samples_[first_];
  if (t < first.t) {
    if (first.t - t > max_extrapolation_before_s_) return std::nullopt;
    return std::make_pair(first.v, first.w);
  }
  const auto i = bracket(t);
  if (!i) return std::nullopt;
  const Sample& a = samples_[*i];
  const Sample& b = samples_[*i + 1];
  const double w = (t - a.t) / (b.t - a.t);
  return std::make_pair(a.v + w * (b.v - a.v), a.w + w * (b.w - a.w));
}

DriveProcessingResult process_drive(RecordSource& source, const DriveProcessingConfig& cfg,
                                    const std::function<void(double time_s)>& progress) {
  const auto t_start = Clock::now();
  GridmapConfig gcfg = cfg.gridmap;
  gcfg.window_s = 0.0;
  DriveProcessingResult res{source.header(),
                            tiles::LocalFrame(source.header().origin),
                            CovarianceGridmap(gcfg),
                            {},
                            {},
                            {},
                            {},
                            std::nullopt};
  DriveProcessingStats& st = res.stats;
  std::map<std::uint8_t, SensorMount> mounts;
  for (const SensorMount& m : res.header.sensors) mounts[m.sensor_id] = m;

  TrajectoryInterpolator traj(res.frame, cfg.max_interpolation_gap_s, cfg.max_extrapolation_s,
                              cfg.max_extrapolation_before_s);
  std::deque<SensorFrame> pending;
  Eigen::Vector2d last_xy = Eigen::Vector2d::Zero();
  bool have_xy = false;

  // Calibration against the trajectory (config comment): frames wait in `held` until it
  // freezes; then `mounts` and `time_offset_s` hold the calibrated values.
  std::optional<ReferenceMountCalibrator> calibrator;
  if (cfg.mount_calibration.enabled) calibrator.emplace(res.header.sensors, cfg.mount_calibration);
  bool frozen = !calibrator.has_value();
  std::map<std::uint8_t, double> time_offset_s;
  std::deque<SensorFrame> held;
  const double h = cfg.motion_difference_s;

  auto map_frame = [&](const SensorFrame& f) {
    const auto mit = mounts.find(f.sensor_id);
    if (mit == mounts.end()) {
      ++st.frames_unknown_sensor;
      return;
    }
    const auto dt_it = time_offset_s.find(f.sensor_id);
    const double t_true = f.time_s + (dt_it == time_offset_s.end() ? 0.0 : dt_it->second);
    const std::optional<Pose2> T = traj.T_frame_vehicle(t_true);
    if (!T) {
      ++st.frames_without_pose;
      return;
    }
    const Pose2 T_frame_sensor = *T * mit->second.T_vehicle_sensor;
    const auto vw = traj.motion(t_true);
    if (vw && std::abs(vw->first) < cfg.min_speed_mps) {
      ++st.frames_standstill;
      return;
    }
    const auto t0 = Clock::now();
    if (cfg.use_cube && f.cube && vw) {
      StaticReductionConfig sr = cfg.static_reduction;
      if (sr.azimuth_bins_rad.empty()) sr.azimuth_bins_rad = f.spectrum.azimuth_bins_rad;
      if (!(sr.noise_sigma > 0.0) && f.spectrum.noise_sigma > 0.0F)
        sr.noise_sigma = f.spectrum.noise_sigma;
      const PolSpectrum s = static_reduce(*f.cube, mit->second, vw->first, vw->second, sr);
      res.gridmap.add(s, T_frame_sensor, f.time_s);
      ++st.frames_from_cube;
    } else {
      if (f.spectrum.azimuth_bins_rad.size() < 2) {
        ++st.frames_without_spectrum;
        return;
      }
      res.gridmap.add(f.spectrum, T_frame_sensor, f.time_s);
    }
    st.gridmap_seconds += since(t0);
    ++st.frames_mapped;
    if (progress) progress(f.time_s);
  };
  // The vehicle's motion at t from the trajectory (vehicle frame of the heading at t).
  auto reference_motion = [&](double t) -> std::optional<ReferenceMotion> {
    const auto p0 = traj.T_frame_vehicle(t - 2 * h), p1 = traj.T_frame_vehicle(t - h),
               p2 = traj.T_frame_vehicle(t), p3 = traj.T_frame_vehicle(t + h),
               p4 = traj.T_frame_vehicle(t + 2 * h);
    if (!p0 || !p1 || !p2 || !p3 || !p4) return std::nullopt;
    auto velocity = [&](const Pose2& a, const Pose2& b, double yaw_rad) {
      const Eigen::Vector2d v_frame = (b.translation() - a.translation()) / (2 * h);
      return Eigen::Vector2d(Pose2{0.0, 0.0, yaw_rad}.rotation().transpose() * v_frame);
    };
    const Eigen::Vector2d v = velocity(*p1, *p3, p2->yaw_rad);
    const Eigen::Vector2d v_before = velocity(*p0, *p2, p1->yaw_rad);
    const Eigen::Vector2d v_after = velocity(*p2, *p4, p3->yaw_rad);
    const double w = wrap_angle_rad(p3->yaw_rad - p1->yaw_rad) / (2 * h);
    const double w_before = wrap_angle_rad(p2->yaw_rad - p0->yaw_rad) / (2 * h);
    const double w_after = wrap_angle_rad(p4->yaw_rad - p2->yaw_rad) / (2 * h);
    ReferenceMotion m;
    m.v_x_mps = v.x();
    m.v_y_mps = v.y();
    m.yaw_rate_rps = w;
    m.a_x_mps2 = (v_after.x() - v_before.x()) / (2 * h);
    m.a_y_mps2 = (v_after.y() - v_before.y()) / (2 * h);
    m.yaw_accel_rps2 = (w_after - w_before) / (2 * h);
    return m;
  };
  auto freeze = [&] {
    frozen = true;
    const ReferenceMountCalibration c = calibrator->result();
    for (const auto& e : c.sensors) time_offset_s[e.sensor_id] = e.time_offset_s;
    for (const SensorMount& m : calibrator->calibrated_mounts()) mounts[m.sensor_id] = m;
    res.mount_calibration = c;
    while (!held.empty()) {
      map_frame(held.front());
      held.pop_front();
    }
  };
  // Frames whose pose is decided (a trajectory sample 2h after their time exists) enter the
  // calibration while it runs and wait in `held`, or are mapped.
  auto drain = [&](bool at_end) {
    while (!pending.empty() && (at_end || pending.front().time_s + 2 * h <= traj.last_time_s())) {
      SensorFrame f = std::move(pending.front());
      pending.pop_front();
      if (frozen) {
        map_frame(f);
        continue;
      }
      if (const auto m = reference_motion(f.time_s)) calibrator->add_frame(f, *m);
      held.push_back(std::move(f));
      ++st.frames_held_for_calibration;
      if (calibrator->result().status == ReferenceMountCalibration::Status::Converged ||
          held.back().time_s - held.front().time_s > cfg.max_calibration_hold_s) {
        freeze();
      }
    }
    if (at_end && !frozen) freeze();
    double oldest = pending.empty() ? traj.last_time_s() : pending.front().time_s;
    if (!held.empty()) oldest = std::min(oldest, held.front().time_s);
    if (!pending.empty() || !held.empty()) traj.forget_before(oldest - 1.0 - 2 * h);
  };

  while (auto rec = source.next()) {
    if (auto* s = std::get_if<TrajectorySample>(&*rec)) {
      if (!traj.add(*s)) continue;
      const Eigen::Vector2d xy = res.frame.to_local(s->lat_deg, s->lon_deg);
      if (have_xy) st.distance_m += (xy - last_xy).norm();
      last_xy = xy;
      have_xy = true;
      if (st.trajectory_samples == 0) st.start_time_s = s->time_s;
      st.end_time_s = s->time_s;
      ++st.trajectory_samples;
      res.trajectory.push_back(*s);
      drain(false);
    } else {
      ++st.sensor_frames;
      pending.push_back(std::move(std::get<SensorFrame>(*rec)));
      drain(false);
    }
  }
  drain(true);

  if (cfg.extract_points) {
    const auto t0 = Clock::now();
    res.points = extract_points(res.gridmap, cfg.points);
    st.points_seconds = since(t0);
  }
  if (cfg.extract_lines) {
    const auto t0 = Clock::now();
    res.lines = extract_lines(res.gridmap, cfg.lines);
    st.lines_seconds = since(t0);
  }
  st.total_seconds = since(t_start);
  return res;
}

}  // namespace polmap::radar
