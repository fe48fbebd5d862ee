#include "polmap/mapping_service/drive_alignment.hpp"

#include <ceres/ceres.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <nanoflann.hpp>
#include <numeric>
#include <opencv2/imgproc.hpp>

#include "polmap/schema/errors.hpp"

namespace polmap::mapping {

std::string_view to_string(DriveAlignmentResult::Status s) {
  switch (s) {
    case DriveAlignmentResult::Status::Aligned:
      return "aligned";
    case DriveAlignmentResult::Status::NotNeeded:
      return "not_needed";
    case DriveAlignmentResult::Status::NoOverlap:
      return "no_overlap";
  }
  return "unknown";
}

Eigen::Vector3d DriveCorrection::at(double s_m) const {
  if (node_s_m.empty()) return Eigen::Vector3d::Zero();
  if (node_s_m.size() == 1 || s_m <= node_s_m.front()) return node_correction.front();
  if (s_m >= node_s_m.back()) return node_correction.back();
  const auto it = std::upper_bound(node_s_m.begin(), node_s_m.end(), s_m);
  const std::size_t k = static_cast<std::size_t>(it - node_s_m.begin()) - 1;
  const double w = (s_m - node_s_m[k]) / (node_s_m[k + 1] - node_s_m[k]);
  return (1.0 - w) * node_correction[k] + w * node_correction[k + 1];
}

double DriveCorrection::nearest_s_m(const Eigen::Vector2d& p_m) const {
  double best = std::numeric_limits<double>::infinity(), s = 0.0;
  for (std::size_t i = 0; i < path_m.size(); ++i) {
    const double d2 = (path_m[i] - p_m).squaredNorm();
    if (d2 < best) {
      best = d2;
      s = path_s_m[i];
    }
  }
  return s;
}

namespace {

// The trajectory position at arc length s (linear between the resampled points).
Eigen::Vector2d path_at(const DriveCorrection& c, double s_m) {
  if (c.path_m.empty()) return Eigen::Vector2d::Zero();
  if (s_m <= c.path_s_m.front()) return c.path_m.front();
  if (s_m >= c.path_s_m.back()) return c.path_m.back();
  const auto it = std::upper_bound(c.path_s_m.begin(), c.path_s_m.end(), s_m);
  const std::size_t k = static_cast<std::size_t>(it - c.path_s_m.begin()) - 1;
  const double span = c.path_s_m[k + 1] - c.path_s_m[k];
  const double w = span > 0 ? (s_m - c.path_s_m[k]) / span : 0.0;
  return (1.0 - w) * c.path_m[k] + w * c.path_m[k + 1];
}

// q = pivot + R(dyaw) (p - pivot) + (dx, dy), with (dx, dy, dyaw) interpolated between two
// nodes with weight w. Shared by apply() and the Ceres residual.
template <typename T>
void corrected(const T* n0, const T* n1, double w, const Eigen::Vector2d& pivot,
               const Eigen::Vector2d& p, T* q) {
  const T dx = (1.0 - w) * n0[0] + w * n1[0];
  const T dy = (1.0 - w) * n0[1] + w * n1[1];
  const T th = (1.0 - w) * n0[2] + w * n1[2];
  const T c = cos(th), s = sin(th);
  const double rx = p.x() - pivot.x(), ry = p.y() - pivot.y();
  q[0] = pivot.x() + c * rx - s * ry + dx;
  q[1] = pivot.y() + s * rx + c * ry + dy;
}

}  // namespace

Eigen::Vector2d DriveCorrection::apply(const Eigen::Vector2d& p_m, bool candidate) const {
  if (node_s_m.empty()) return p_m;
  const double s0 = nearest_s_m(p_m);
  const double s = candidate ? std::clamp(s0 + candidate_lead_m, 0.0, path_s_m.back()) : s0;
  const Eigen::Vector3d n = at(s);
  double q[2];
  corrected(n.data(), n.data(), 0.0, path_at(*this, s), p_m, q);
  return {q[0], q[1]};
}

namespace {

// A point candidate tied to its drive's correction nodes (fixed during the solve).
struct Attached {
  std::size_t drive = 0;  // index into the input
  std::size_t k0 = 0, k1 = 0;
  double w = 0.0;
  Eigen::Vector2d pivot = Eigen::Vector2d::Zero();
  Eigen::Vector2d p = Eigen::Vector2d::Zero();
};

struct Cloud {
  const std::vector<Eigen::Vector2d>* pts;
  [[nodiscard]] std::size_t kdtree_get_point_count() const { return pts->size(); }
  [[nodiscard]] double kdtree_get_pt(std::size_t i, std::size_t d) const {
    return (*pts)[i][static_cast<int>(d)];
  }
  template <class B>
  bool kdtree_get_bbox(B&) const {
    return false;
  }
};
using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, Cloud>, Cloud,
                                                 2, std::size_t>;

struct MemberResidual {
  MemberResidual(const Attached& a, double sigma) : a_(a), inv_sigma_(1.0 / sigma) {}
  template <typename T>
  bool operator()(const T* n0, const T* n1, const T* lm, T* r) const {
    T q[2];
    corrected(n0, n1, a_.w, a_.pivot, a_.p, q);
    r[0] = (q[0] - lm[0]) * inv_sigma_;
    r[1] = (q[1] - lm[1]) * inv_sigma_;
    return true;
  }
  Attached a_;
  double inv_sigma_;
};

// The same when both interpolation nodes are one parameter block (Ceres forbids a block
// twice in one residual).
struct MemberResidualOneNode {
  MemberResidualOneNode(const Attached& a, double sigma) : a_(a), inv_sigma_(1.0 / sigma) {}
  template <typename T>
  bool operator()(const T* n, const T* lm, T* r) const {
    T q[2];
    corrected(n, n, 0.0, a_.pivot, a_.p, q);
    r[0] = (q[0] - lm[0]) * inv_sigma_;
    r[1] = (q[1] - lm[1]) * inv_sigma_;
    return true;
  }
  Attached a_;
  double inv_sigma_;
};

struct Smoothness {
  double inv_m, inv_rad;
  template <typename T>
  bool operator()(const T* a, const T* b, T* r) const {
    r[0] = (b[0] - a[0]) * inv_m;
    r[1] = (b[1] - a[1]) * inv_m;
    r[2] = (b[2] - a[2]) * inv_rad;
    return true;
  }
};

// The vehicle's odometry between two nodes of a drive (see DriveAlignmentConfig): node
// positions and headings as the GNSS reported them, and the displacement integrated from
// wheel speed, expressed in the frame of node k's reported heading. With the yaw rate
// (gyro), the heading inside the step and its change come from the gyro, so the step's
// shape does not depend on the navigation solution's heading error at all; without it,
// from the reported heading (whose error then bends the map where drives share it).
struct OdometryStep {
  Eigen::Vector2d p0 = Eigen::Vector2d::Zero(), p1 = Eigen::Vector2d::Zero();
  double yaw0_rad = 0.0;
  double reported_dyaw_rad = 0.0;  // wrapped reported yaw(k+1) - yaw(k)
  Eigen::Vector2d body_m = Eigen::Vector2d::Zero();
  bool gyro = false;
  double gyro_dyaw_rad = 0.0;  // integrated yaw rate (gyro mode)
  double dt_s = 0.0;
  // Bound of the gyro integration's error over samples a simplified trajectory kept:
  // sum over intervals of |change of yaw rate| x dt / 2 (the trapezoid is exact for a yaw
  // rate linear between samples, off by up to this when it is not, as in turns).
  double gyro_integration_rad = 0.0;
  bool valid = true;
};

struct OdometryFactor {
  OdometryStep o;
  double inv_m, inv_rad;
  // a, b: the nodes' corrections (dx, dy, dyaw); odo: the drive's (wheel-speed scale
  // error, yaw-rate bias in rad/s).
  template <typename T>
  bool operator()(const T* a, const T* b, const T* odo, T* r) const {
    // A yaw-rate bias turns the step by half its accumulated heading error.
    const T bias_turn = o.gyro ? T(-0.5 * o.dt_s) * odo[1] : T(0.0);
    const T th = o.yaw0_rad + a[2] + bias_turn;
    const T sc = 1.0 + odo[0];
    const T c = cos(th), s = sin(th);
    const T px = sc * (c * o.body_m.x() - s * o.body_m.y());
    const T py = sc * (s * o.body_m.x() + c * o.body_m.y());
    r[0] = ((o.p1.x() + b[0]) - (o.p0.x() + a[0]) - px) * inv_m;
    r[1] = ((o.p1.y() + b[1]) - (o.p0.y() + a[1]) - py) * inv_m;
    // The corrected heading changes as the gyro says; without a gyro, the correction (the
    // heading error) changes slowly.
    r[2] = o.gyro
               ? (o.reported_dyaw_rad + b[2] - a[2] - (o.gyro_dyaw_rad - odo[1] * o.dt_s)) * inv_rad
               : (b[2] - a[2]) * inv_rad;
    return true;
  }
};

// The mean wheel-scale error of the consumer-grade drives (cars' errors are independent).
struct FleetMeanScale {
  double inv_n_sigma;
  int n = 0;
  template <typename T>
  bool operator()(T const* const* odo, T* r) const {
    T sum(0.0);
    for (int i = 0; i < n; ++i) sum += odo[i][0];
    r[0] = sum * inv_n_sigma;
    return true;
  }
};

struct OdometryPrior {
  double inv_scale, inv_bias;
  template <typename T>
  bool operator()(const T* odo, T* r) const {
    r[0] = odo[0] * inv_scale;
    r[1] = odo[1] * inv_bias;
    return true;
  }
};

double wrap_rad(double a) { return std::remainder(a, 2.0 * M_PI); }

// Odometry steps between the nodes of a drive (node k at trajectory sample node_sample[k]):
// speed along the heading (from the yaw rate when every sample has one, else the reported
// heading), midpoint rule. Empty when a sample lacks heading or speed; a step is not valid
// when two samples of a moving vehicle in it are further apart than max_gap_s (a standing
// vehicle's samples may be sparse: it does not move in between) or its length disagrees
// with the GNSS displacement beyond the mismatch bound.
std::vector<OdometryStep> odometry_steps(const std::vector<AlignmentSample>& tr,
                                         const std::vector<std::size_t>& node_sample,
                                         const DriveAlignmentConfig& cfg) {
  std::vector<OdometryStep> out;
  bool gyro = true;
  for (const auto& smp : tr) {
    if (!std::isfinite(smp.yaw_rad) || !std::isfinite(smp.speed_mps)) return {};
    gyro = gyro && std::isfinite(smp.yaw_rate_rps);
  }
  constexpr double kStandingMps = 0.1;
  constexpr double kGravityMps2 = 9.80665;
  for (std::size_t k = 0; k + 1 < node_sample.size(); ++k) {
    OdometryStep o;
    const std::size_t i0 = node_sample[k], i1 = node_sample[k + 1];
    o.p0 = tr[i0].position_m;
    o.p1 = tr[i1].position_m;
    o.yaw0_rad = tr[i0].yaw_rad;
    o.reported_dyaw_rad = wrap_rad(tr[i1].yaw_rad - tr[i0].yaw_rad);
    o.gyro = gyro;
    double h = 0.0;  // gyro heading relative to node k's
    for (std::size_t j = i0; j < i1; ++j) {
      const double dt = tr[j + 1].time_s - tr[j].time_s;
      if (!(dt > 0.0)) return {};
      double v = 0.5 * (tr[j].speed_mps + tr[j + 1].speed_mps);
      if (cfg.odometry_slip_stiffness > 0.0) {  // longitudinal slip of the wheels
        const double a_x = (tr[j + 1].speed_mps - tr[j].speed_mps) / dt;
        v /= std::max(0.5, 1.0 + a_x / (kGravityMps2 * cfg.odometry_slip_stiffness));
      }
      if (dt > cfg.odometry_max_gap_s &&
          std::max(tr[j].speed_mps, tr[j + 1].speed_mps) > kStandingMps) {
        o.valid = false;  // this step gets the smoothness prior
      }
      double mid = 0.0;
      if (gyro) {
        const double w = 0.5 * (tr[j].yaw_rate_rps + tr[j + 1].yaw_rate_rps);
        // The axle moves at the side-slip angle to the heading the gyro integrates.
        mid = h + 0.5 * w * dt - cfg.odometry_side_slip_gradient_rad_per_mps2 * v * w;
        h += w * dt;
        o.gyro_integration_rad += 0.5 * std::abs(tr[j + 1].yaw_rate_rps - tr[j].yaw_rate_rps) * dt;
      } else {  // reported heading relative to node k's, halfway between the samples
        const double dyaw = wrap_rad(tr[j + 1].yaw_rad - tr[j].yaw_rad);
        mid = wrap_rad(tr[j].yaw_rad - o.yaw0_rad) + 0.5 * dyaw -
              cfg.odometry_side_slip_gradient_rad_per_mps2 * v * (dyaw / dt);
      }
      o.body_m += v * dt * Eigen::Vector2d(std::cos(mid), std::sin(mid));
      o.dt_s += dt;
    }
    o.gyro_dyaw_rad = h;
    // The step's length must agree with the GNSS displacement (whose error changes little
    // over a step); integrating across a gap that hides an acceleration does not.
    const double mismatch = std::abs(o.body_m.norm() - (o.p1 - o.p0).norm());
    if (mismatch > cfg.odometry_max_length_mismatch_m +
                       cfg.odometry_max_length_mismatch_share * o.body_m.norm()) {
      o.valid = false;
    }
    out.push_back(o);
  }
  return out;
}

struct Prior {
  double inv_m, inv_rad;
  template <typename T>
  bool operator()(const T* a, T* r) const {
    r[0] = a[0] * inv_m;
    r[1] = a[1] * inv_m;
    r[2] = a[2] * inv_rad;
    return true;
  }
};

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

// Current positions of all attached candidates.
std::vector<Eigen::Vector2d> positions(const std::vector<Attached>& att,
                                       const std::vector<DriveCorrection>& corr) {
  std::vector<Eigen::Vector2d> q(att.size());
  for (std::size_t i = 0; i < att.size(); ++i) {
    const auto& a = att[i];
    const auto& n = corr[a.drive].node_correction;
    double out[2];
    corrected(n[a.k0].data(), n[a.k1].data(), a.w, a.pivot, a.p, out);
    q[i] = {out[0], out[1]};
  }
  return q;
}

// Coarse start: per node of every consumer-grade drive, the displacement to the other
// drives' candidates nearby that most of its candidates agree on (the peak of a blurred
// vote image), applied to all drives at once.
void vote_round(const std::vector<Attached>& att, std::vector<DriveCorrection>& corr,
                const DriveAlignmentConfig& cfg) {
  const std::vector<Eigen::Vector2d> q = positions(att, corr);
  Cloud cloud{&q};
  Tree tree(2, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(16));
  tree.buildIndex();
  const int half = static_cast<int>(std::ceil(cfg.vote_radius_m / cfg.vote_cell_m));
  const int size = 2 * half + 1;
  // Per drive and node: the candidates attached to it.
  std::vector<std::vector<std::vector<std::size_t>>> of_node(corr.size());
  for (std::size_t d = 0; d < corr.size(); ++d) of_node[d].resize(corr[d].node_s_m.size());
  for (std::size_t i = 0; i < att.size(); ++i) {
    of_node[att[i].drive][att[i].w < 0.5 ? att[i].k0 : att[i].k1].push_back(i);
  }
  const double r2 = cfg.vote_radius_m * cfg.vote_radius_m;
  std::vector<std::pair<std::size_t, double>> hits;
  nanoflann::SearchParams sp;
  sp.sorted = false;
  // Displacement votes of each candidate, computed once per round. A vote towards a
  // survey-grade drive's candidate weighs as much as all consumer-grade drives together:
  // the consumer drives share the place's multipath, so without it they outvote the one
  // drive that knows where the place is (a leave-one-out map of 1 RTK + 4 consumer drives
  // kept the consumer drives' common 2.2 m offset).
  int consumer_drives = 0;
  for (const auto& c : corr) consumer_drives += c.survey_grade || c.node_s_m.empty() ? 0 : 1;
  const float survey_weight = static_cast<float>(std::max(1, consumer_drives));
  struct Vote {
    int x, y;
    float weight;
  };
  std::vector<std::vector<Vote>> votes(att.size());
  for (std::size_t i = 0; i < att.size(); ++i) {
    if (corr[att[i].drive].survey_grade) continue;
    hits.clear();
    const double qq[2] = {q[i].x(), q[i].y()};
    tree.radiusSearch(qq, r2, hits, sp);
    for (const auto& [j, d2] : hits) {
      if (att[j].drive == att[i].drive) continue;
      const Eigen::Vector2d d = q[j] - q[i];
      votes[i].push_back({static_cast<int>(std::lround(d.x() / cfg.vote_cell_m)) + half,
                          static_cast<int>(std::lround(d.y() / cfg.vote_cell_m)) + half,
                          corr[att[j].drive].survey_grade ? survey_weight : 1.0F});
    }
  }
  std::vector<std::vector<Eigen::Vector2d>> update(corr.size());
  for (std::size_t d = 0; d < corr.size(); ++d) {
    update[d].assign(corr[d].node_s_m.size(), Eigen::Vector2d::Zero());
    if (corr[d].survey_grade) continue;
    const int nn = static_cast<int>(corr[d].node_s_m.size());
    for (int k = 0; k < nn; ++k) {
      cv::Mat img(size, size, CV_32F, cv::Scalar(0));
      int count = 0;
      for (int m = std::max(0, k - cfg.vote_window_nodes);
           m <= std::min(nn - 1, k + cfg.vote_window_nodes); ++m) {
        for (const std::size_t i : of_node[d][static_cast<std::size_t>(m)]) {
          for (const auto& [x, y, weight] : votes[i]) {
            if (x >= 0 && y >= 0 && x < size && y < size) {
              img.at<float>(y, x) += weight;
              ++count;
            }
          }
        }
      }
      if (count < 20) continue;  // too little evidence here: keep the GNSS position
      cv::GaussianBlur(img, img, cv::Size(0, 0), 1.5);
      cv::Point peak;
      cv::minMaxLoc(img, nullptr, nullptr, nullptr, &peak);
      update[d][static_cast<std::size_t>(k)] = {(peak.x - half) * cfg.vote_cell_m,
                                                (peak.y - half) * cfg.vote_cell_m};
    }
  }
  for (std::size_t d = 0; d < corr.size(); ++d) {
    for (std::size_t k = 0; k < update[d].size(); ++k) {
      corr[d].node_correction[k].head<2>() += update[d][k];
    }
  }
}

struct Clusters {
  std::vector<std::vector<std::size_t>> members;
  std::vector<Eigen::Vector2d> centre;
};

// Greedy clustering of the current positions: seeds in order of neighbourhood density, at
// most one candidate per drive (the nearest to the centre), at least min_drives drives.
Clusters cluster(const std::vector<Attached>& att, const std::vector<Eigen::Vector2d>& q,
                 double gate_m, int min_drives) {
  Clusters out;
  if (q.empty()) return out;
  Cloud cloud{&q};
  Tree tree(2, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(16));
  tree.buildIndex();
  const double r2 = gate_m * gate_m;
  nanoflann::SearchParams sp;
  sp.sorted = false;
  std::vector<std::pair<std::size_t, double>> hits;
  std::vector<std::size_t> density(q.size());
  for (std::size_t i = 0; i < q.size(); ++i) {
    hits.clear();
    const double qq[2] = {q[i].x(), q[i].y()};
    density[i] = tree.radiusSearch(qq, r2, hits, sp);
  }
  std::vector<std::size_t> order(q.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return density[a] > density[b]; });
  std::vector<char> used(q.size(), 0);
  auto gather = [&](const Eigen::Vector2d& c) {
    hits.clear();
    const double qq[2] = {c.x(), c.y()};
    tree.radiusSearch(qq, r2, hits, sp);
    std::vector<std::pair<std::size_t, double>> best;  // (index, d2) per drive
    std::vector<std::size_t> drive_of;
    for (const auto& [j, d2] : hits) {
      if (used[j]) continue;
      const auto it = std::find(drive_of.begin(), drive_of.end(), att[j].drive);
      if (it == drive_of.end()) {
        drive_of.push_back(att[j].drive);
        best.emplace_back(j, d2);
      } else {
        auto& b = best[static_cast<std::size_t>(it - drive_of.begin())];
        if (d2 < b.second || (d2 == b.second && j < b.first)) b = {j, d2};
      }
    }
    std::vector<std::size_t> m;
    for (const auto& b : best) m.push_back(b.first);
    std::sort(m.begin(), m.end());
    return m;
  };
  for (const std::size_t i : order) {
    if (used[i]) continue;
    std::vector<std::size_t> m = gather(q[i]);
    if (static_cast<int>(m.size()) < min_drives) continue;
    Eigen::Vector2d c = Eigen::Vector2d::Zero();
    for (const std::size_t j : m) c += q[j];
    c /= static_cast<double>(m.size());
    m = gather(c);  // once more around the centre
    if (static_cast<int>(m.size()) < min_drives) continue;
    c.setZero();
    for (const std::size_t j : m) {
      c += q[j];
      used[j] = 1;
    }
    out.centre.push_back(c / static_cast<double>(m.size()));
    out.members.push_back(std::move(m));
  }
  return out;
}

}  // namespace

DriveAlignmentResult align_drives(std::span<const AlignmentDrive> drives,
                                  const DriveAlignmentConfig& cfg) {
  POLMAP_EXPECT(cfg.node_spacing_m > 0.0 && cfg.candidate_sigma_m > 0.0);
  POLMAP_EXPECT(cfg.vote_cell_m > 0.0 && cfg.vote_radius_m > cfg.vote_cell_m);
  const auto t0 = std::chrono::steady_clock::now();
  DriveAlignmentResult res;
  res.corrections.resize(drives.size());
  std::vector<double> drive_std(drives.size(), 0.0), drive_std_yaw(drives.size(), 0.0);
  std::vector<std::vector<OdometryStep>> steps(drives.size());
  // Per drive: wheel-odometry scale error and yaw-rate bias (estimated with the corrections).
  std::vector<Eigen::Vector2d> odo_params(drives.size(), Eigen::Vector2d::Zero());
  bool any_consumer = false;
  for (std::size_t d = 0; d < drives.size(); ++d) {
    DriveCorrection& c = res.corrections[d];
    c.drive = drives[d].drive;
    const auto& tr = drives[d].trajectory;
    if (tr.empty()) continue;
    std::vector<double> stds, yaws;
    for (const auto& s : tr) {
      stds.push_back(s.std_m);
      yaws.push_back(s.std_yaw_rad);
    }
    drive_std[d] = median(stds);
    drive_std_yaw[d] = median(yaws);
    c.survey_grade = drive_std[d] <= cfg.survey_grade_std_m;
    any_consumer = any_consumer || drive_std[d] >= cfg.consumer_grade_std_m;
    (c.survey_grade ? res.survey_grade_drives : res.consumer_grade_drives) += 1;
    // Resample the trajectory every ~1 m; nodes at the first sample past each multiple of
    // the node spacing, and at the last sample.
    double s = 0.0;
    c.path_m.push_back(tr.front().position_m);
    c.path_s_m.push_back(0.0);
    std::vector<std::size_t> node_sample{0};
    c.node_s_m.push_back(0.0);
    c.node_position_m.push_back(tr.front().position_m);
    for (std::size_t i = 1; i < tr.size(); ++i) {
      s += (tr[i].position_m - tr[i - 1].position_m).norm();
      if (s - c.path_s_m.back() >= 1.0 || i + 1 == tr.size()) {
        c.path_m.push_back(tr[i].position_m);
        c.path_s_m.push_back(s);
      }
      if (s >= c.node_s_m.back() + cfg.node_spacing_m ||
          (i + 1 == tr.size() && s > c.node_s_m.back())) {
        node_sample.push_back(i);
        c.node_s_m.push_back(s);
        c.node_position_m.push_back(tr[i].position_m);
      }
    }
    c.node_correction.assign(c.node_s_m.size(), Eigen::Vector3d::Zero());
    c.candidate_lead_m = cfg.candidate_lead_m;
    if (cfg.use_odometry) steps[d] = odometry_steps(tr, node_sample, cfg);
    if (!c.survey_grade && !steps[d].empty()) ++res.odometry_drives;
  }
  if (!any_consumer) {
    for (auto& c : res.corrections) {  // identity everywhere
      std::fill(c.node_correction.begin(), c.node_correction.end(), Eigen::Vector3d::Zero());
    }
    res.status = DriveAlignmentResult::Status::NotNeeded;
    return res;
  }

  // Tie every point candidate to its drive's nodes.
  std::vector<Attached> att;
  for (std::size_t d = 0; d < drives.size(); ++d) {
    const DriveCorrection& c = res.corrections[d];
    if (c.node_s_m.empty()) continue;
    for (const Eigen::Vector2d& p : drives[d].points_m) {
      Attached a;
      a.drive = d;
      a.p = p;
      const double s = std::clamp(c.nearest_s_m(p) + cfg.candidate_lead_m, 0.0, c.path_s_m.back());
      // A pose error moves what the vehicle saw by rotating it about the vehicle: the
      // heading part of the correction turns the candidate about where it was seen from.
      a.pivot = path_at(c, s);
      const auto it = std::upper_bound(c.node_s_m.begin(), c.node_s_m.end(), s);
      const std::size_t k =
          it == c.node_s_m.begin() ? 0 : static_cast<std::size_t>(it - c.node_s_m.begin()) - 1;
      a.k0 = k;
      a.k1 = std::min(k + 1, c.node_s_m.size() - 1);
      a.w = a.k1 == a.k0
                ? 0.0
                : std::clamp((s - c.node_s_m[k]) / (c.node_s_m[a.k1] - c.node_s_m[k]), 0.0, 1.0);
      if (a.w == 0.0) a.k1 = a.k0;
      att.push_back(a);
    }
  }

  for (int r = 0; r < cfg.vote_rounds; ++r) vote_round(att, res.corrections, cfg);

  Clusters cl;
  for (const double gate : cfg.gates_m) {
    cl = cluster(att, positions(att, res.corrections), gate, cfg.min_cluster_drives);
    if (cl.members.empty()) continue;
    ceres::Problem problem;
    // Priors and smoothness of every drive's nodes.
    for (std::size_t d = 0; d < drives.size(); ++d) {
      DriveCorrection& c = res.corrections[d];
      const std::size_t n = c.node_s_m.size();
      if (n == 0) continue;
      const double inflate =
          std::sqrt(std::max(1.0, cfg.gnss_correlation_length_m / cfg.node_spacing_m));
      const double sp = std::max(drive_std[d], 0.005) * inflate;
      const double sy = std::max(drive_std_yaw[d], 1e-4) * inflate;
      for (std::size_t k = 0; k < n; ++k) {
        problem.AddResidualBlock(
            new ceres::AutoDiffCostFunction<Prior, 3, 3>(new Prior{1.0 / sp, 1.0 / sy}), nullptr,
            c.node_correction[k].data());
        if (k + 1 < n && !steps[d].empty() && steps[d][k].valid) {
          const OdometryStep& o = steps[d][k];
          const double len = o.body_m.norm();
          const double yaw_sigma =
              o.gyro ? cfg.gyro_sigma_rad + cfg.gyro_sigma_per_m * len + o.gyro_integration_rad
                     : cfg.odometry_yaw_sigma_rad + cfg.odometry_yaw_sigma_per_m * len;
          problem.AddResidualBlock(
              new ceres::AutoDiffCostFunction<OdometryFactor, 3, 3, 3, 2>(new OdometryFactor{
                  o, 1.0 / (cfg.odometry_sigma_m + cfg.odometry_sigma_per_m * len),
                  1.0 / yaw_sigma}),
              nullptr, c.node_correction[k].data(), c.node_correction[k + 1].data(),
              odo_params[d].data());
        } else if (k + 1 < n) {
          const double step =
              std::max(1e-3, (c.node_s_m[k + 1] - c.node_s_m[k]) / cfg.node_spacing_m);
          problem.AddResidualBlock(
              new ceres::AutoDiffCostFunction<Smoothness, 3, 3, 3>(
                  new Smoothness{1.0 / (cfg.smoothness_sigma_m * std::sqrt(step)),
                                 1.0 / (cfg.smoothness_yaw_sigma_rad * std::sqrt(step))}),
              nullptr, c.node_correction[k].data(), c.node_correction[k + 1].data());
        }
      }
    }
    for (std::size_t d = 0; d < drives.size(); ++d) {
      if (steps[d].empty()) continue;
      problem.AddResidualBlock(
          new ceres::AutoDiffCostFunction<OdometryPrior, 2, 2>(
              new OdometryPrior{1.0 / cfg.odometry_scale_sigma, 1.0 / cfg.gyro_bias_sigma_rps}),
          nullptr, odo_params[d].data());
      if (gate > cfg.odometry_parameters_gate_m) {
        problem.SetParameterBlockConstant(odo_params[d].data());
      }
    }
    if (cfg.fleet_scale_sigma > 0.0 && gate <= cfg.odometry_parameters_gate_m) {
      std::vector<double*> blocks;
      for (std::size_t d = 0; d < drives.size(); ++d) {
        if (!steps[d].empty() && !res.corrections[d].survey_grade) {
          blocks.push_back(odo_params[d].data());
        }
      }
      if (blocks.size() >= 2) {
        const auto n = static_cast<double>(blocks.size());
        auto* cost = new ceres::DynamicAutoDiffCostFunction<FleetMeanScale, 4>(
            new FleetMeanScale{1.0 / (n * cfg.fleet_scale_sigma), static_cast<int>(blocks.size())});
        for (std::size_t i = 0; i < blocks.size(); ++i) cost->AddParameterBlock(2);
        cost->SetNumResiduals(1);
        problem.AddResidualBlock(cost, nullptr, blocks);
      }
    }
    std::vector<Eigen::Vector2d> lm = cl.centre;
    for (std::size_t j = 0; j < cl.members.size(); ++j) {
      for (const std::size_t i : cl.members[j]) {
        const Attached& a = att[i];
        auto& n = res.corrections[a.drive].node_correction;
        auto* loss = new ceres::HuberLoss(2.0);
        if (a.k0 == a.k1) {
          problem.AddResidualBlock(new ceres::AutoDiffCostFunction<MemberResidualOneNode, 2, 3, 2>(
                                       new MemberResidualOneNode(a, cfg.candidate_sigma_m)),
                                   loss, n[a.k0].data(), lm[j].data());
        } else {
          problem.AddResidualBlock(new ceres::AutoDiffCostFunction<MemberResidual, 2, 3, 3, 2>(
                                       new MemberResidual(a, cfg.candidate_sigma_m)),
                                   loss, n[a.k0].data(), n[a.k1].data(), lm[j].data());
        }
      }
    }
    ceres::Solver::Options opt;
    opt.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
    opt.max_num_iterations = cfg.max_iterations;
    opt.num_threads = 2;
    opt.logging_type = ceres::SILENT;
    ceres::Solver::Summary summary;
    ceres::Solve(opt, &problem, &summary);
    cl.centre = lm;
  }
  if (cl.members.empty()) {
    res.status = DriveAlignmentResult::Status::NoOverlap;
    for (auto& c : res.corrections) {
      std::fill(c.node_correction.begin(), c.node_correction.end(), Eigen::Vector3d::Zero());
    }
  } else {
    res.status = DriveAlignmentResult::Status::Aligned;
    const std::vector<Eigen::Vector2d> q = positions(att, res.corrections);
    double s2 = 0.0;
    for (std::size_t j = 0; j < cl.members.size(); ++j) {
      for (const std::size_t i : cl.members[j]) s2 += (q[i] - cl.centre[j]).squaredNorm();
      res.associations += static_cast<int>(cl.members[j].size());
    }
    res.clusters = static_cast<int>(cl.members.size());
    res.residual_rms_m = std::sqrt(s2 / std::max(1, res.associations));
  }
  double scale_sum = 0.0, scale_sum2 = 0.0, bias_sum = 0.0, bias_sum2 = 0.0;
  for (std::size_t d = 0; d < drives.size(); ++d) {
    DriveCorrection& c = res.corrections[d];
    for (const OdometryStep& o : steps[d])
      (o.valid ? c.odometry_steps : c.odometry_steps_rejected) += 1;
    c.odometry_scale_error = odo_params[d].x();
    c.gyro_bias_rps = odo_params[d].y();
    if (c.survey_grade || steps[d].empty()) continue;  // the drives odometry_drives counts
    res.odometry_steps_rejected += c.odometry_steps_rejected;
    scale_sum += c.odometry_scale_error;
    scale_sum2 += c.odometry_scale_error * c.odometry_scale_error;
    bias_sum += c.gyro_bias_rps;
    bias_sum2 += c.gyro_bias_rps * c.gyro_bias_rps;
  }
  if (res.odometry_drives > 0) {
    res.scale_error_mean = scale_sum / res.odometry_drives;
    res.scale_error_rms = std::sqrt(scale_sum2 / res.odometry_drives);
    res.gyro_bias_mean_rps = bias_sum / res.odometry_drives;
    res.gyro_bias_rms_rps = std::sqrt(bias_sum2 / res.odometry_drives);
  }
  double sum = 0.0;
  int count = 0;
  for (const auto& c : res.corrections) {
    if (c.survey_grade) continue;
    for (const auto& n : c.node_correction) {
      sum += n.head<2>().norm();
      ++count;
    }
  }
  res.mean_correction_m = count > 0 ? sum / count : 0.0;
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

}  // namespace polmap::mapping
