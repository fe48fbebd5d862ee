#include "polmap/radar/egomotion.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include "doppler_inliers.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::radar {

const char* to_string(MotionEstimate::Status s) {
  switch (s) {
    case MotionEstimate::Status::Ok:
      return "ok";
    case MotionEstimate::Status::TooFewDetections:
      return "too_few_detections";
    case MotionEstimate::Status::Rejected:
      return "rejected";
  }
  return "unknown";
}

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Axis-aligned box of admissible (v, ω).
struct MotionBox {
  double v_lo, v_hi, w_lo, w_hi;
  [[nodiscard]] bool contains(double v, double w) const {
    return v >= v_lo && v <= v_hi && w >= w_lo && w <= w_hi;
  }
  [[nodiscard]] MotionBox intersect(const MotionBox& o) const {
    return {std::max(v_lo, o.v_lo), std::min(v_hi, o.v_hi), std::max(w_lo, o.w_lo),
            std::min(w_hi, o.w_hi)};
  }
  [[nodiscard]] bool empty() const { return v_lo > v_hi || w_lo > w_hi; }
};

/// The combined detections of one estimate: one entry per original detection
/// (model rows) and the Nyquist-zone augmented copies as flat arrays (SoA) so
/// the scoring loop is a plain vectorizable pass.
struct Problem {
  // per original detection
  std::vector<double> h0, h1;     // v_r = h0·v + h1·ω
  std::vector<double> g0, g1;     // ∂v_r/∂θ = g0·v + g1·ω
  std::vector<double> vr;         // measured (time-corrected) radial velocity
  std::vector<double> tau;        // frame time − estimate time (≤ 0)
  std::vector<double> ext;        // extrapolation variance / σ_vr² (unknown acceleration error)
  std::vector<int> first, count;  // its copies in the augmented arrays
  // augmented copies
  std::vector<double> a_h0, a_h1, a_g0, a_g1, a_vr, a_ext;
  std::vector<int> a_det;
};

struct Hypothesis {
  double v = 0.0, w = 0.0;
  int inliers = -1;
  double cost = std::numeric_limits<double>::infinity();  // Σ min(r²/thr², 1), tie-break
};

/// Gaussian prior on (v, ω) at the estimate time: the previous estimate
/// extrapolated, its covariance grown by the process noise.
struct MotionPrior {
  Eigen::Vector2d mean;
  Eigen::Matrix2d information;  // inverse covariance
};

struct Fit {
  bool ok = false;
  double v = 0.0, w = 0.0;
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  Eigen::Matrix2d cov_data = Eigen::Matrix2d::Zero();  // without the motion prior
  int inliers = 0;
  std::vector<char> inlier;  // per original detection
};

class Ransac {
 public:
  Ransac(const Problem& p, const EgoMotionConfig& cfg) : p_(p), cfg_(cfg) {
    const double ratio = cfg.vr_sigma_mps > 0 ? cfg.azimuth_sigma_rad / cfg.vr_sigma_mps : 0.0;
    az2_ = ratio * ratio;
    thr2_ = cfg.inlier_threshold_mps * cfg.inlier_threshold_mps;
  }

  /// Scores hypothesis (v, w) over all augmented copies: a copy is an inlier
  /// when |v_r − h·m| < thr·σ_i/σ_vr. Copies of one detection are 2·v_ua
  /// apart, so at most one copy per detection can be an inlier.
  void score(Hypothesis& h) const { score(h, -1); }

  /// As score(h), but gives up (h.inliers = −1) as soon as h can no longer reach
  /// `to_beat` inliers: the remaining copies could not make up the difference, so
  /// better(h, best) would be false anyway. Checked per block of copies.
  void score(Hypothesis& h, int to_beat) const {
    const detail::DopplerRows rows{p_.a_vr.data(), p_.a_h0.data(),  p_.a_h1.data(), p_.a_g0.data(),
                                   p_.a_g1.data(), p_.a_ext.data(), p_.a_vr.size()};
    const detail::DopplerSupport s = detail::doppler_support(rows, h.v, h.w, thr2_, az2_, to_beat);
    h.inliers = s.inliers;
    h.cost = s.cost;
  }

  static bool better(const Hypothesis& a, const Hypothesis& b) {
    return a.inliers > b.inliers || (a.inliers == b.inliers && a.cost < b.cost);
  }

  /// RANSAC drawing minimal samples from `pool` (augmented indices) and
  /// accepting only hypotheses inside `box`.
  /// `seed` (the predicted motion, if any) is scored as an extra hypothesis:
  /// with few detections at nearly one azimuth no well-conditioned minimal
  /// sample may exist, but the prediction can still gather their support.
  Hypothesis run(const std::vector<int>& pool, const MotionBox& box, std::mt19937_64& rng,
                 const std::optional<Eigen::Vector2d>& seed = std::nullopt) const {
    Hypothesis best;
    if (seed && box.contains((*seed)(0), (*seed)(1))) {
      best.v = (*seed)(0);
      best.w = (*seed)(1);
      score(best);
    }
    if (pool.size() < 2 || box.empty()) return best;
    std::uniform_int_distribution<std::size_t> pick(0, pool.size() - 1);
    const double log_fail = std::log(1.0 - cfg_.ransac_confidence);
    int needed = cfg_.max_iterations;
    // Draw attempts are bounded separately: degenerate or implausible samples
    // are cheap and do not count as iterations, but must not loop forever.
    const int max_draws = 20 * cfg_.max_iterations;
    int iterations = 0;
    for (int draw = 0; draw < max_draws && iterations < std::max(needed, cfg_.min_iterations) &&
                       iterations < cfg_.max_iterations;
         ++draw) {
      const int ja = pool[pick(rng)];
      const int jb = pool[pick(rng)];
      if (p_.a_det[ja] == p_.a_det[jb]) continue;
      const double a0 = p_.a_h0[ja], a1 = p_.a_h1[ja], b0 = p_.a_h0[jb], b1 = p_.a_h1[jb];
      const double det = a0 * b1 - a1 * b0;
      // Rows must not be near-parallel (same direction, same lever arm).
      if (std::abs(det) < 0.05 * std::hypot(a0, a1) * std::hypot(b0, b1)) continue;
      Hypothesis h;
      h.v = (p_.a_vr[ja] * b1 - a1 * p_.a_vr[jb]) / det;
      h.w = (a0 * p_.a_vr[jb] - b0 * p_.a_vr[ja]) / det;
      if (!box.contains(h.v, h.w)) continue;
      ++iterations;
      score(h, best.inliers);
      if (better(h, best)) {
        best = h;
        const double frac = static_cast<double>(best.inliers) / static_cast<double>(pool.size());
        const double p_good = std::min(frac * frac, 1.0 - 1e-12);
        if (p_good > 0.0) {
          needed = static_cast<int>(std::ceil(log_fail / std::log(1.0 - p_good)));
        }
      }
    }
    return best;
  }

  /// Weighted least squares on inliers, starting from (v, w). Each round picks
  /// per detection its best-matching copy, keeps it if within the threshold,
  /// and re-solves. Unknowns: (v, ω) at the estimate time and the correction
  /// (δa, δα) of the acceleration used to shift older frames, with the prior
  /// δa ~ N(0, σ_a²), δα ~ N(0, σ_α²) (frames spread over time make it
  /// observable; a single frame leaves it at the prior, i.e. 0). The
  /// covariance is s²·[N⁻¹]₂ₓ₂ (marginal of (v, ω)), s² = Σ w r² / (n − 2).
  Fit refine(double v, double w, const std::optional<MotionPrior>& prior) const {
    Fit fit;
    const std::size_t n_det = p_.vr.size();
    std::vector<double> chosen(n_det, 0.0);  // chosen copy's v_r
    fit.inlier.assign(n_det, 0);
    const double s_vr2 = cfg_.vr_sigma_mps * cfg_.vr_sigma_mps;
    const double prior_a =
        1.0 / std::max(cfg_.accel_uncertainty_mps2 * cfg_.accel_uncertainty_mps2, 1e-12);
    const double prior_alpha =
        1.0 / std::max(cfg_.yaw_accel_uncertainty_rps2 * cfg_.yaw_accel_uncertainty_rps2, 1e-12);
    using Vec4 = Eigen::Matrix<double, 4, 1>;
    using Mat4 = Eigen::Matrix<double, 4, 4>;
    Vec4 x(v, w, 0.0, 0.0);
    auto row = [&](std::size_t i) {
      return Vec4(p_.h0[i], p_.h1[i], p_.h0[i] * p_.tau[i], p_.h1[i] * p_.tau[i]);
    };
    auto select = [&](const Vec4& xs) {
      int n = 0;
      for (std::size_t i = 0; i < n_det; ++i) {
        const double pred = row(i).dot(xs);
        const double d = p_.g0[i] * xs(0) + p_.g1[i] * xs(1);
        const double t2 = thr2_ * (1.0 + az2_ * d * d + p_.ext[i]);
        double best_r2 = std::numeric_limits<double>::infinity();
        for (int c = 0; c < p_.count[i]; ++c) {
          const int j = p_.first[i] + c;
          const double r = p_.a_vr[j] - pred;
          if (r * r < best_r2) {
            best_r2 = r * r;
            chosen[i] = p_.a_vr[j];
          }
        }
        fit.inlier[i] = best_r2 < t2 ? 1 : 0;
        n += fit.inlier[i];
      }
      return n;
    };
    // Normal equations, weights fixed at xs (the azimuth term depends on m).
    auto normal = [&](const Vec4& xs, Mat4& N, Vec4& b) {
      N.setZero();
      b.setZero();
      for (std::size_t i = 0; i < n_det; ++i) {
        if (!fit.inlier[i]) continue;
        const double d = p_.g0[i] * xs(0) + p_.g1[i] * xs(1);
        const double wgt = 1.0 / (s_vr2 * (1.0 + az2_ * d * d));
        const Vec4 h = row(i);
        N.noalias() += wgt * h * h.transpose();
        b.noalias() += wgt * h * chosen[i];
      }
      N(2, 2) += prior_a;
      N(3, 3) += prior_alpha;
    };
    auto add_motion_prior = [&](Mat4& N, Vec4& b) {
      if (!prior) return;
      N.topLeftCorner<2, 2>() += prior->information;
      b.head<2>() += prior->information * prior->mean;
    };
    // Marginal information of (v, ω) must be well-conditioned (inliers not
    // all along one direction).
    auto marginal_ok = [](const Mat4& N) {
      const Eigen::Matrix2d S = N.topLeftCorner<2, 2>() -
                                N.topRightCorner<2, 2>() * N.bottomRightCorner<2, 2>().inverse() *
                                    N.bottomLeftCorner<2, 2>();
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(S);
      return es.eigenvalues()(0) > 1e-9 * std::max(es.eigenvalues()(1), 1e-300);
    };
    Mat4 N;
    Vec4 b;
    for (int round = 0; round < cfg_.refinement_rounds; ++round) {
      if (select(x) < 3) return fit;
      normal(x, N, b);
      if (!marginal_ok(N)) return fit;  // data alone must not be degenerate
      add_motion_prior(N, b);
      const Vec4 xn = N.ldlt().solve(b);
      const bool converged = (xn - x).cwiseAbs().maxCoeff() < 1e-8;
      x = xn;
      if (converged) break;
    }
    const int n = select(x);
    if (n < 3) return fit;
    normal(x, N, b);
    if (!marginal_ok(N)) return fit;
    // Residual variance factor from the data alone (without the prior), then
    // the posterior: data information scaled by 1/s², plus the prior's.
    const Vec4 x_data = N.ldlt().solve(b);
    Mat4 N_post = N;
    Vec4 b_post = b;
    double chi2 = 0.0;
    for (std::size_t i = 0; i < n_det; ++i) {
      if (!fit.inlier[i]) continue;
      const double d = p_.g0[i] * x(0) + p_.g1[i] * x(1);
      const double wgt = 1.0 / (s_vr2 * (1.0 + az2_ * d * d));
      const double r = chosen[i] - row(i).dot(x_data);
      chi2 += wgt * r * r;
    }
    const double s2 = std::max(chi2 / static_cast<double>(n - 2), 1e-6);
    if (prior) {
      // Data rows scaled by 1/s² (the prior terms on δa, δα stay as they are).
      N_post.topLeftCorner<2, 4>() /= s2;
      N_post.bottomLeftCorner<2, 2>() /= s2;
      N_post(2, 2) = (N(2, 2) - prior_a) / s2 + prior_a;
      N_post(3, 3) = (N(3, 3) - prior_alpha) / s2 + prior_alpha;
      N_post(2, 3) /= s2;
      N_post(3, 2) /= s2;
      b_post /= s2;
      add_motion_prior(N_post, b_post);
    }
    const Mat4 N_inv = N_post.inverse();
    const Vec4 xf = N_inv * b_post;
    fit.cov_data = s2 * Mat4(N.inverse()).topLeftCorner<2, 2>();
    fit.ok = true;
    fit.v = xf(0);
    fit.w = xf(1);
    fit.inliers = n;
    fit.cov = prior ? Eigen::Matrix2d(N_inv.topLeftCorner<2, 2>())
                    : Eigen::Matrix2d(s2 * N_inv.topLeftCorner<2, 2>());
    return fit;
  }

 private:
  const Problem& p_;
  const EgoMotionConfig& cfg_;
  double az2_ = 0.0;
  double thr2_ = 0.0;
};

}  // namespace

EgoMotionEstimator::EgoMotionEstimator(std::vector<SensorMount> mounts, EgoMotionConfig cfg)
    : mounts_(std::move(mounts)), cfg_(cfg) {
  POLMAP_EXPECT(!mounts_.empty());
  POLMAP_EXPECT(cfg_.min_inliers >= 3 && cfg_.min_inliers_with_prior >= 3);
  POLMAP_EXPECT(cfg_.max_speed_mps > cfg_.min_speed_mps);
  POLMAP_EXPECT(cfg_.inlier_threshold_mps > 0 && cfg_.vr_sigma_mps > 0);
  POLMAP_EXPECT(cfg_.ransac_confidence > 0 && cfg_.ransac_confidence < 1);
  for (std::size_t i = 0; i < mounts_.size(); ++i) {
    for (std::size_t j = i + 1; j < mounts_.size(); ++j) {
      POLMAP_EXPECT(mounts_[i].sensor_id != mounts_[j].sensor_id);
    }
  }
}

void EgoMotionEstimator::set_mount_corrections(std::vector<double> yaw_offsets_rad,
                                               std::vector<double> time_offsets_s) {
  POLMAP_EXPECT(yaw_offsets_rad.empty() || yaw_offsets_rad.size() == mounts_.size());
  POLMAP_EXPECT(time_offsets_s.empty() || time_offsets_s.size() == mounts_.size());
  yaw_offsets_rad_ = std::move(yaw_offsets_rad);
  time_offsets_s_ = std::move(time_offsets_s);
}

void EgoMotionEstimator::reset() {
  history_.clear();
  accepted_.clear();
  static_mask_.clear();
  calls_ = 0;
  last_time_s_ = -1e300;
  last_corrected_time_s_ = -1e300;
}

std::optional<Eigen::Vector2d> EgoMotionEstimator::acceleration(double time_s) const {
  // Least-squares slope of v(t) and ω(t) over the recent accepted estimates.
  int n = 0;
  double st = 0, sv = 0, sw = 0;
  double t_min = std::numeric_limits<double>::infinity(), t_max = -t_min;
  for (const auto& a : accepted_) {
    if (time_s - a.time_s > cfg_.accel_window_s || a.time_s > time_s) continue;
    ++n;
    st += a.time_s;
    sv += a.v_mps;
    sw += a.yaw_rate_rps;
    t_min = std::min(t_min, a.time_s);
    t_max = std::max(t_max, a.time_s);
  }
  if (n < cfg_.accel_min_estimates || t_max - t_min < cfg_.accel_window_s / 3.0) {
    return std::nullopt;
  }
  const double tm = st / n, vm = sv / n, wm = sw / n;
  double stt = 0, stv = 0, stw = 0;
  for (const auto& a : accepted_) {
    if (time_s - a.time_s > cfg_.accel_window_s || a.time_s > time_s) continue;
    const double dt = a.time_s - tm;
    stt += dt * dt;
    stv += dt * (a.v_mps - vm);
    stw += dt * (a.yaw_rate_rps - wm);
  }
  if (stt <= 0) return std::nullopt;
  return Eigen::Vector2d(std::clamp(stv / stt, -cfg_.max_accel_mps2, cfg_.max_accel_mps2),
                         std::clamp(stw / stt, -cfg_.max_yaw_accel_rps2, cfg_.max_yaw_accel_rps2));
}

MotionEstimate EgoMotionEstimator::process(const SensorFrame& frame) {
  POLMAP_EXPECT(frame.time_s >= last_time_s_);
  std::size_t new_idx = mounts_.size();
  for (std::size_t i = 0; i < mounts_.size(); ++i) {
    if (mounts_[i].sensor_id == frame.sensor_id) new_idx = i;
  }
  POLMAP_EXPECT(new_idx < mounts_.size());  // frame of a sensor without mount
  last_time_s_ = frame.time_s;
  // Calibrated measurement time; offsets are milliseconds, frames 33 ms apart, but keep the
  // history ordered whatever the calibration says.
  const double t =
      std::max(frame.time_s + (time_offsets_s_.empty() ? 0.0 : time_offsets_s_[new_idx]),
               last_corrected_time_s_);
  last_corrected_time_s_ = t;
  while (!history_.empty() && t - history_.front().time_s > cfg_.combine_window_s) {
    history_.pop_front();
  }
  history_.push_back(StoredFrame{new_idx, t, frame.detections});
  std::mt19937_64 rng(cfg_.seed ^ (0x9E3779B97F4A7C15ULL * ++calls_));

  MotionEstimate est;
  est.time_s = t;
  est.v_mps = kNaN;
  est.yaw_rate_rps = kNaN;
  est.covariance.setConstant(kNaN);
  static_mask_.assign(frame.detections.size(), false);

  // --- combine the new frame with the latest frames of the other sensors ---
  const std::optional<Eigen::Vector2d> accel =
      cfg_.combine_window_s > 0 ? acceleration(t) : std::nullopt;
  // The new frame first (its detections start at index 0), then older frames.
  std::vector<const StoredFrame*> order{&history_.back()};
  for (std::size_t k = 0; k + 1 < history_.size(); ++k) order.push_back(&history_[k]);

  // Plausible motion box (global) and the prior's box (acceleration limits).
  const MotionBox global{cfg_.min_speed_mps, cfg_.max_speed_mps, -cfg_.max_yaw_rate_rps,
                         cfg_.max_yaw_rate_rps};
  std::optional<MotionBox> prior_box;
  if (!accepted_.empty() && t - accepted_.back().time_s <= cfg_.max_prior_age_s) {
    const auto& p = accepted_.back();
    const double dt = t - p.time_s;
    const double dv = cfg_.max_accel_mps2 * dt + cfg_.accel_slack_mps;
    const double dw = cfg_.max_yaw_accel_rps2 * dt + cfg_.yaw_accel_slack_rps;
    prior_box = MotionBox{p.v_mps - dv, p.v_mps + dv, p.yaw_rate_rps - dw, p.yaw_rate_rps + dw};
  }

  // Motion prior: the last accepted estimate extrapolated to t.
  std::optional<MotionPrior> motion_prior;
  if (prior_box && cfg_.prior_accel_sigma_mps2 > 0 && cfg_.prior_yaw_accel_sigma_rps2 > 0) {
    const auto& p = accepted_.back();
    const double dt = t - p.time_s;
    const Eigen::Vector2d acc = acceleration(t).value_or(Eigen::Vector2d::Zero());
    Eigen::Matrix2d P = static_cast<double>(std::max(p.num_frames, 1)) * p.covariance;
    P(0, 0) += std::pow(cfg_.prior_accel_sigma_mps2 * dt, 2) + 1e-12;
    P(1, 1) += std::pow(cfg_.prior_yaw_accel_sigma_rps2 * dt, 2) + 1e-12;
    motion_prior = MotionPrior{Eigen::Vector2d(p.v_mps, p.yaw_rate_rps) + acc * dt, P.inverse()};
  }

  Problem prob;
  const double sa2 = cfg_.accel_uncertainty_mps2 * cfg_.accel_uncertainty_mps2;
  const double salpha2 = cfg_.yaw_accel_uncertainty_rps2 * cfg_.yaw_accel_uncertainty_rps2;
  const double thr_margin = 3.0 * cfg_.inlier_threshold_mps;
  // Side slip (config): v_y = −k v̂² ω shortens every sensor's lever arm for ω by k v̂², with
  // v̂ the last accepted speed (the model stays linear in (v, ω)).
  const double v_hat = prior_box ? accepted_.back().v_mps : 0.0;
  const double slip_lever_m = cfg_.side_slip_gradient_rad_per_mps2 * v_hat * v_hat;
  for (std::size_t fi = 0; fi < order.size(); ++fi) {
    const StoredFrame& sf = *order[fi];
    const SensorMount& mount = mounts_[sf.mount_index];
    const double xm = mount.T_vehicle_sensor.x_m, ym = mount.T_vehicle_sensor.y_m;
    const double vua = mount.spec.v_unambiguous_mps;
    const double age = t - sf.time_s;
    for (const Detection& d : sf.detections) {
      const double th = static_cast<double>(d.azimuth_rad) + mount.T_vehicle_sensor.yaw_rad +
                        (yaw_offsets_rad_.empty() ? 0.0 : yaw_offsets_rad_[sf.mount_index]);
      const double c = std::cos(th), s = std::sin(th);
      const double xw = xm - slip_lever_m;  // lever arm of ω in the lateral velocity
      const double h0 = -c, h1 = ym * c - xw * s;
      const double g0 = s, g1 = -ym * s - xw * c;
      double vr = d.radial_velocity_mps;
      if (accel && age > 0) vr += (h0 * (*accel)(0) + h1 * (*accel)(1)) * age;
      // Variance (relative to σ_vr²) of the shift's error, unknown acceleration error.
      const double ext =
          age * age * (h0 * h0 * sa2 + h1 * h1 * salpha2) / (cfg_.vr_sigma_mps * cfg_.vr_sigma_mps);
      const int i = static_cast<int>(prob.vr.size());
      prob.h0.push_back(h0);
      prob.h1.push_back(h1);
      prob.g0.push_back(g0);
      prob.g1.push_back(g1);
      prob.vr.push_back(vr);
      prob.tau.push_back(-age);
      prob.ext.push_back(ext);
      prob.first.push_back(static_cast<int>(prob.a_vr.size()));
      // Radial velocities this direction can show for any motion in the global
      // box (linear in (v, ω): extremes at the corners), plus a noise margin.
      const double c1 = h0 * global.v_lo + h1 * global.w_lo,
                   c2 = h0 * global.v_lo + h1 * global.w_hi;
      const double c3 = h0 * global.v_hi + h1 * global.w_lo,
                   c4 = h0 * global.v_hi + h1 * global.w_hi;
      const double lo = std::min({c1, c2, c3, c4}) - thr_margin;
      const double hi = std::max({c1, c2, c3, c4}) + thr_margin;
      int k_lo = 0, k_hi = 0;
      if (vua > 0) {
        k_lo = static_cast<int>(std::ceil((lo - vr) / (2.0 * vua)));
        k_hi = static_cast<int>(std::floor((hi - vr) / (2.0 * vua)));
      } else if (vr < lo || vr > hi) {
        k_lo = 1;  // unaliased sensor, physically impossible value: no copy
      }
      for (int k = k_lo; k <= k_hi; ++k) {
        prob.a_h0.push_back(h0);
        prob.a_h1.push_back(h1);
        prob.a_g0.push_back(g0);
        prob.a_g1.push_back(g1);
        prob.a_vr.push_back(vr + 2.0 * k * vua);
        prob.a_ext.push_back(ext);
        prob.a_det.push_back(i);
      }
      prob.count.push_back(static_cast<int>(prob.a_vr.size()) - prob.first.back());
    }
  }
  est.num_detections = static_cast<int>(prob.vr.size());
  est.num_frames = 0;  // frames that contributed detections
  for (const StoredFrame* f : order) est.num_frames += f->detections.empty() ? 0 : 1;
  est.time_corrected = accel.has_value() && order.size() > 1;
  // With a motion prior the fit is regularized, so fewer static inliers
  // suffice in sparse scenes, provided they are a fair share of the
  // detections (not a handful of coincidences among many moving ones).
  const int n_required =
      motion_prior
          ? std::min(cfg_.min_inliers,
                     std::max(cfg_.min_inliers_with_prior,
                              static_cast<int>(std::ceil(cfg_.min_inlier_fraction_with_prior *
                                                         static_cast<double>(prob.vr.size())))))
          : cfg_.min_inliers;
  if (est.num_detections < n_required) {
    est.status = MotionEstimate::Status::TooFewDetections;
    return est;
  }

  const Ransac ransac(prob, cfg_);
  std::vector<int> pool(prob.a_vr.size());
  for (std::size_t j = 0; j < pool.size(); ++j) pool[j] = static_cast<int>(j);

  auto consistent = [&](double v, double w) { return !prior_box || prior_box->contains(v, w); };
  auto well_constrained = [&](const Fit& f) {
    // The detections themselves must roughly determine both v and ω: the prior
    // may sharpen an estimate, never supply a whole direction of it.
    if (f.ok &&
        (f.cov_data(0, 0) > cfg_.max_data_v_std_mps * cfg_.max_data_v_std_mps ||
         f.cov_data(1, 1) > cfg_.max_data_yaw_rate_std_rps * cfg_.max_data_yaw_rate_std_rps)) {
      return false;
    }
    return f.ok && f.inliers >= n_required &&
           f.cov(0, 0) <= cfg_.max_v_std_mps * cfg_.max_v_std_mps &&
           f.cov(1, 1) <= cfg_.max_yaw_rate_std_rps * cfg_.max_yaw_rate_std_rps;
  };

  // With acceleration limits (a previous estimate), every acceptable motion lies in
  // prior_box: search there first, on the copies such a motion can explain. This finds
  // what the global search would accept (its best hypothesis must lie in the box too)
  // at a fraction of the cost: about one copy per detection instead of one per Nyquist
  // zone, hence a higher inlier share and fewer adaptive iterations.
  Fit fit;
  bool accepted = false;
  const std::optional<Eigen::Vector2d> seed =
      motion_prior ? std::optional<Eigen::Vector2d>(motion_prior->mean) : std::nullopt;
  if (prior_box) {
    const MotionBox box = prior_box->intersect(global);
    const double dv = 0.5 * (box.v_hi - box.v_lo), dw = 0.5 * (box.w_hi - box.w_lo);
    const double vc = 0.5 * (box.v_hi + box.v_lo), wc = 0.5 * (box.w_hi + box.w_lo);
    // A copy is kept if some motion in the box could make it an inlier: its residual
    // there is at most the box's spread plus the largest inlier threshold in the box
    // (the threshold grows with the azimuth term |g·m|, largest at a corner).
    const double ratio = cfg_.vr_sigma_mps > 0 ? cfg_.azimuth_sigma_rad / cfg_.vr_sigma_mps : 0.0;
    Problem sub;
    for (std::size_t j = 0; j < prob.a_vr.size(); ++j) {
      const double pred = prob.a_h0[j] * vc + prob.a_h1[j] * wc;
      const double dmax = std::abs(prob.a_g0[j] * vc + prob.a_g1[j] * wc) +
                          std::abs(prob.a_g0[j]) * dv + std::abs(prob.a_g1[j]) * dw;
      const double thr =
          cfg_.inlier_threshold_mps * std::sqrt(1.0 + ratio * ratio * dmax * dmax + prob.a_ext[j]);
      const double tol = std::abs(prob.a_h0[j]) * dv + std::abs(prob.a_h1[j]) * dw + thr;
      if (std::abs(prob.a_vr[j] - pred) > tol * (1.0 + 1e-9)) continue;
      sub.a_h0.push_back(prob.a_h0[j]);
      sub.a_h1.push_back(prob.a_h1[j]);
      sub.a_g0.push_back(prob.a_g0[j]);
      sub.a_g1.push_back(prob.a_g1[j]);
      sub.a_vr.push_back(prob.a_vr[j]);
      sub.a_ext.push_back(prob.a_ext[j]);
      sub.a_det.push_back(prob.a_det[j]);
    }
    std::vector<int> sub_pool(sub.a_vr.size());
    for (std::size_t j = 0; j < sub_pool.size(); ++j) sub_pool[j] = static_cast<int>(j);
    const Hypothesis best = Ransac(sub, cfg_).run(sub_pool, box, rng, seed);
    if (best.inliers >= n_required) {
      fit = ransac.refine(best.v, best.w, motion_prior);
      accepted = well_constrained(fit) && consistent(fit.v, fit.w);
    }
    if (!accepted) {
      // Rare: tell "too few static detections for any motion" from "the motion they
      // show violates the limits" by the global search.
      const Hypothesis global_best = ransac.run(pool, global, rng, seed);
      est.status = global_best.inliers < n_required ? MotionEstimate::Status::TooFewDetections
                                                    : MotionEstimate::Status::Rejected;
      return est;
    }
    est.searched_within_limits = true;
  } else {
    // No limits yet: global RANSAC over the whole augmented set.
    const Hypothesis best = ransac.run(pool, global, rng, seed);
    if (best.inliers < n_required) {
      est.status = MotionEstimate::Status::TooFewDetections;
      return est;
    }
    fit = ransac.refine(best.v, best.w, motion_prior);
    accepted = well_constrained(fit);
  }
  if (!accepted) {
    est.status = MotionEstimate::Status::TooFewDetections;  // unconstrained or degenerate
    return est;
  }

  est.status = MotionEstimate::Status::Ok;
  est.v_mps = fit.v;
  est.yaw_rate_rps = fit.w;
  est.covariance = fit.cov;
  est.num_inliers = fit.inliers;
  for (std::size_t i = 0; i < frame.detections.size(); ++i) static_mask_[i] = fit.inlier[i] != 0;

  est.used_motion_prior = motion_prior.has_value();
  accepted_.push_back({t, fit.v, fit.w, fit.cov, est.num_frames});
  const double keep_s = std::max(cfg_.accel_window_s, 0.0);
  while (accepted_.size() > 1 && t - accepted_.front().time_s > keep_s) accepted_.pop_front();
  return est;
}

}  // namespace polmap::radar
