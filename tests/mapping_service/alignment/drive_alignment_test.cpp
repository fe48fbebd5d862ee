// Multi-drive alignment of consumer-grade GNSS drives: a synthetic world of point landmarks
// along a curved road, drives whose reported positions carry a smooth metre-level error
// (bias + slow drift, as the simulator's consumer GNSS), candidates with 5 cm noise and
// single-drive clutter. The aligned candidates of all drives must agree to centimetres,
// and survey-grade drives must pin the absolute position.
#include "polmap/mapping_service/drive_alignment.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

namespace polmap::mapping {
namespace {

constexpr double kRouteM = 1200.0;

Eigen::Vector2d road(double s) {  // a gentle S-curve
  return {s, 40.0 * std::sin(s / 300.0)};
}
double road_slope(double s) { return 40.0 / 300.0 * std::cos(s / 300.0); }
double road_yaw_rad(double s) { return std::atan(road_slope(s)); }

/// Canyon multipath: an error of the place, the same for every drive passing there.
Eigen::Vector2d shared_error(double s, double amplitude_m) {
  return amplitude_m *
         Eigen::Vector2d(std::sin(2 * M_PI * s / 170.0), std::cos(2 * M_PI * s / 130.0 + 1.0));
}

struct World {
  std::vector<Eigen::Vector2d> landmarks;
  /// Per landmark: x of the road point nearest to it (where a drive sees it abeam and
  /// where its GNSS error is taken).
  std::vector<double> station;
};

double nearest_station(const Eigen::Vector2d& l) {
  double best = l.x(), best_d = std::numeric_limits<double>::infinity();
  for (double x = l.x() - 30.0; x <= l.x() + 30.0; x += 0.05) {
    const double d = (road(x) - l).squaredNorm();
    if (d < best_d) best_d = d, best = x;
  }
  return best;
}

World make_world(std::mt19937_64& rng) {
  World w;
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (double s = 5.0; s < kRouteM - 5.0; s += 4.0 + 8.0 * u(rng)) {
    const double side = u(rng) < 0.5 ? -1.0 : 1.0;
    const Eigen::Vector2d t = (road(s + 0.5) - road(s - 0.5)).normalized();
    const Eigen::Vector2d n(-t.y(), t.x());
    w.landmarks.push_back(road(s) + side * (4.0 + 20.0 * u(rng)) * n);
    w.station.push_back(nearest_station(w.landmarks.back()));
  }
  return w;
}

/// A drive's smooth error at arc length s: a bias plus a slow sinusoidal drift.
struct DriveError {
  Eigen::Vector2d bias;
  Eigen::Vector2d amp;
  double wavelength_m, phase;
  double shared_m = 0.0;        ///< amplitude of the place's shared error (survey-grade: none)
  double shared_stretch = 0.0;  ///< a shared error that stretches the route along x
  Eigen::Vector2d at(double s) const {
    return bias + amp * std::sin(2 * M_PI * s / wavelength_m + phase) + shared_error(s, shared_m) +
           Eigen::Vector2d(shared_stretch * (s - 0.5 * kRouteM), 0.0);
  }
};

struct Fleet {
  std::vector<AlignmentDrive> drives;
  std::vector<DriveError> errors;
  /// A candidate carries the drive's error from this far before the landmark's station:
  /// forward-looking radars see an object mostly before the car passes it.
  double seen_before_m = 10.0;
  [[nodiscard]] Eigen::Vector2d error_of(std::size_t d, double station) const {
    return errors[d].at(station - seen_before_m);
  }
};

/// n drives, the first `survey` survey-grade; consumer-grade ones also carry the place's
/// shared error of amplitude shared_m. Samples carry the exact heading, speed and yaw rate
/// (the vehicle's odometry) unless without_odometry.
Fleet make_fleet(const World& w, int n, int survey, std::mt19937_64& rng, double shared_m = 0.0,
                 bool without_odometry = false, double seen_before_m = 10.0,
                 double shared_stretch = 0.0) {
  Fleet f;
  f.seen_before_m = seen_before_m;
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int d = 0; d < n; ++d) {
    const bool rtk = d < survey;
    DriveError e{rtk ? Eigen::Vector2d(0.01 * g(rng), 0.01 * g(rng))
                     : Eigen::Vector2d(1.5 * g(rng), 1.5 * g(rng)),
                 rtk ? Eigen::Vector2d::Zero() : Eigen::Vector2d(0.5 * g(rng), 0.5 * g(rng)),
                 600.0 + 600.0 * u(rng),
                 2 * M_PI * u(rng),
                 rtk ? 0.0 : shared_m,
                 rtk ? 0.0 : shared_stretch};
    AlignmentDrive a;
    a.drive = 100 + d;
    for (double s = 0.0; s <= kRouteM; s += 0.5) {
      AlignmentSample smp;
      smp.time_s = s / 10.0;
      smp.position_m = road(s) + e.at(s);
      smp.std_m = rtk ? 0.014 : 2.0;
      smp.std_yaw_rad = rtk ? 0.001 : 0.005;
      if (!without_odometry) {  // 10 m/s along x
        const double k = road_slope(s);
        smp.yaw_rad = road_yaw_rad(s);
        smp.speed_mps = 10.0 * std::sqrt(1.0 + k * k);
      }
      a.trajectory.push_back(smp);
    }
    for (std::size_t i = 0; i < w.landmarks.size(); ++i) {
      if (u(rng) > 0.8) continue;  // missed in this drive
      a.points_m.push_back(w.landmarks[i] + e.at(w.station[i] - seen_before_m) +
                           Eigen::Vector2d(0.05 * g(rng), 0.05 * g(rng)));
    }
    for (int c = 0; c < 60; ++c) {  // single-drive clutter
      const double s = kRouteM * u(rng);
      a.points_m.push_back(road(s) + Eigen::Vector2d(30 * (u(rng) - 0.5), 30 * (u(rng) - 0.5)));
    }
    f.drives.push_back(std::move(a));
    f.errors.push_back(e);
  }
  return f;
}

/// The map's relative geometry as the issue measures it: per 200 m window of the route,
/// the RMS distance of every drive's (corrected) view of the landmarks from truth after
/// removing that window's mean offset (a translation fit; the windows' rotations are
/// below a milliradian here). Also returns the mean offset over the route (absolute part).
std::pair<double, Eigen::Vector2d> landmark_rms(const World& w, const Fleet& f,
                                                const DriveAlignmentResult* r) {
  constexpr double kWindowM = 200.0;
  const int windows = static_cast<int>(std::ceil(kRouteM / kWindowM));
  std::vector<std::vector<Eigen::Vector2d>> diffs(static_cast<std::size_t>(windows));
  Eigen::Vector2d mean_all = Eigen::Vector2d::Zero();
  int n_all = 0;
  for (std::size_t d = 0; d < f.drives.size(); ++d) {
    for (std::size_t i = 0; i < w.landmarks.size(); ++i) {
      const Eigen::Vector2d& l = w.landmarks[i];
      Eigen::Vector2d seen = l + f.error_of(d, w.station[i]);
      if (r) seen = r->corrections[d].apply(seen);
      diffs[static_cast<std::size_t>(
                std::clamp(static_cast<int>(l.x() / kWindowM), 0, windows - 1))]
          .push_back(seen - l);
      mean_all += seen - l;
      ++n_all;
    }
  }
  double s2 = 0;
  for (const auto& win : diffs) {
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (const auto& x : win) mean += x;
    mean /= static_cast<double>(std::max<std::size_t>(1, win.size()));
    for (const auto& x : win) s2 += (x - mean).squaredNorm();
  }
  return {std::sqrt(s2 / n_all), mean_all / n_all};
}

/// RMS over landmarks and drives of the distance of a drive's corrected view of a landmark
/// from the mean of all drives' views: how well the drives agree with each other.
double inter_drive_rms(const World& w, const Fleet& f, const DriveAlignmentResult& r) {
  double s2 = 0;
  int n = 0;
  for (std::size_t i = 0; i < w.landmarks.size(); ++i) {
    std::vector<Eigen::Vector2d> seen;
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (std::size_t d = 0; d < f.drives.size(); ++d) {
      seen.push_back(r.corrections[d].apply(w.landmarks[i] + f.error_of(d, w.station[i])));
      mean += seen.back();
    }
    mean /= static_cast<double>(seen.size());
    for (const auto& x : seen) s2 += (x - mean).squaredNorm();
    n += static_cast<int>(seen.size());
  }
  return std::sqrt(s2 / n);
}

TEST(DriveAlignment, ConsumerDrivesAgreeToCentimetresAfterAlignment) {
  std::mt19937_64 rng(11);
  const World w = make_world(rng);
  const Fleet f = make_fleet(w, 12, 0, rng);
  const auto [rms_before, off_before] = landmark_rms(w, f, nullptr);
  const DriveAlignmentResult r = align_drives(f.drives);
  ASSERT_EQ(r.status, DriveAlignmentResult::Status::Aligned);
  EXPECT_EQ(r.consumer_grade_drives, 12);
  EXPECT_EQ(r.survey_grade_drives, 0);
  EXPECT_GT(r.clusters, static_cast<int>(w.landmarks.size() / 2));
  EXPECT_EQ(r.odometry_drives, 12);
  const auto [rms_after, off_after] = landmark_rms(w, f, &r);
  EXPECT_GT(rms_before, 1.0);
  EXPECT_LT(inter_drive_rms(w, f, r), 0.06);
  // Within 200 m windows: the odometry fixes each drive's shape, so the fleet's mean GNSS
  // drift (12 drives, 0.5 m sinusoidal drift each) does not bend the map.
  EXPECT_LT(rms_after, 0.05) << "before " << rms_before;
  // Without anchors the absolute offset is what the GNSS priors average to: within a few
  // sigma of 1.5 m / sqrt(12), not pinned.
  EXPECT_LT(off_after.norm(), 3.0 * 1.5 * std::sqrt(2.0 / 12.0) + 0.3);
}

TEST(DriveAlignment, TheSharedCanyonErrorNeedsTheVehiclesOdometry) {
  // Every consumer drive meets the same 0.8 m error at the same place (canyon multipath):
  // landmark associations cannot see it (all drives agree), only the vehicle's own motion
  // can. With odometry the map keeps the road's shape; without, it inherits the error.
  std::mt19937_64 rng(21);
  const World w = make_world(rng);
  const Fleet with = make_fleet(w, 12, 0, rng, 0.8);
  std::mt19937_64 rng2(21);
  (void)make_world(rng2);
  const Fleet without = make_fleet(w, 12, 0, rng2, 0.8, true);
  const DriveAlignmentResult a = align_drives(with.drives);
  const DriveAlignmentResult b = align_drives(without.drives);
  ASSERT_EQ(a.status, DriveAlignmentResult::Status::Aligned);
  ASSERT_EQ(b.status, DriveAlignmentResult::Status::Aligned);
  EXPECT_EQ(a.odometry_drives, 12);
  EXPECT_EQ(b.odometry_drives, 0);
  const double rms_with = landmark_rms(w, with, &a).first;
  const double rms_without = landmark_rms(w, without, &b).first;
  EXPECT_LT(rms_with, 0.05);
  EXPECT_GT(rms_without, 0.3);
  EXPECT_LT(inter_drive_rms(w, with, a), 0.06);
  // The same drives with odometry switched off in the configuration: as without.
  DriveAlignmentConfig off;
  off.use_odometry = false;
  const DriveAlignmentResult c = align_drives(with.drives, off);
  EXPECT_EQ(c.odometry_drives, 0);
  EXPECT_GT(landmark_rms(w, with, &c).first, 0.3);
}

TEST(DriveAlignment, ACandidateTakesTheCorrectionOfWhereItWasSeen) {
  // The place's shared error changes by up to 0.04 m per metre; candidates carry it from
  // where the car saw them, 10 m before it passed. Taking each candidate's correction at its
  // nearest trajectory point instead (lead 0) bends the map by that error's change over
  // 10 m, which no association can see (every drive shares it).
  std::mt19937_64 rng(41);
  const World w = make_world(rng);
  const Fleet f = make_fleet(w, 12, 0, rng, 0.8);
  const DriveAlignmentResult seen = align_drives(f.drives);
  DriveAlignmentConfig abeam;
  abeam.candidate_lead_m = 0.0;
  const DriveAlignmentResult nearest = align_drives(f.drives, abeam);
  ASSERT_EQ(seen.status, DriveAlignmentResult::Status::Aligned);
  ASSERT_EQ(nearest.status, DriveAlignmentResult::Status::Aligned);
  const double rms_seen = landmark_rms(w, f, &seen).first;
  const double rms_nearest = landmark_rms(w, f, &nearest).first;
  EXPECT_LT(rms_seen, 0.05);
  EXPECT_GT(rms_nearest, 2.0 * rms_seen);
  // A trajectory point keeps its own correction: the lead is for candidates only.
  const DriveCorrection& c = seen.corrections[3];
  const Eigen::Vector2d p = c.path_m[c.path_m.size() / 2];
  const Eigen::Vector3d own = c.at(c.path_s_m[c.path_m.size() / 2]);
  EXPECT_LT((c.apply(p, false) - (p + own.head<2>())).norm(), 1e-9);
  EXPECT_GT((c.apply(p, true) - c.apply(p, false)).norm(), 1e-4);
}

TEST(DriveAlignment, OdometryScaleErrorIsEstimated) {
  // Each car's wheel speed is off by up to 0.6 % (tyre wear, pressure; what a series car's
  // calibrated odometry leaves): the per-drive scale parameter absorbs it and the map
  // keeps its shape.
  std::mt19937_64 rng(31);
  const World w = make_world(rng);
  Fleet f = make_fleet(w, 10, 0, rng, 0.5);
  std::uniform_real_distribution<double> u(-0.006, 0.006);
  std::vector<double> truth;  // wheel speed read / true speed - 1, per drive
  for (auto& d : f.drives) {
    truth.push_back(u(rng));
    for (auto& smp : d.trajectory) smp.speed_mps *= 1.0 + truth.back();
  }
  const DriveAlignmentResult r = align_drives(f.drives);
  ASSERT_EQ(r.status, DriveAlignmentResult::Status::Aligned);
  EXPECT_LT(landmark_rms(w, f, &r).first, 0.06);
  EXPECT_LT(inter_drive_rms(w, f, r), 0.06);
  // The estimate (1 + e) (1 + truth) = 1 per drive. The landmarks the drives share observe
  // the differences between drives; the common part only the GNSS and the prior.
  ASSERT_EQ(r.corrections.size(), truth.size());
  double mean_truth = 0.0, mean_est = 0.0;
  for (std::size_t d = 0; d < truth.size(); ++d) {
    mean_truth += truth[d] / static_cast<double>(truth.size());
    mean_est += r.corrections[d].odometry_scale_error / static_cast<double>(truth.size());
  }
  for (std::size_t d = 0; d < truth.size(); ++d) {
    const DriveCorrection& c = r.corrections[d];
    EXPECT_NEAR(c.odometry_scale_error - mean_est, -(truth[d] - mean_truth), 0.001) << d;
    EXPECT_GT(c.odometry_steps, 0);
    EXPECT_EQ(c.odometry_steps_rejected, 0);
  }
}

TEST(DriveAlignment, WheelParametersAreHeldInCoarseRounds) {
  // Coarse rounds associate neighbouring objects wrongly; the wheel scale and yaw-rate bias
  // are estimated only from rounds with a gate of odometry_parameters_gate_m or finer.
  std::mt19937_64 rng(37);
  const World w = make_world(rng);
  Fleet f = make_fleet(w, 6, 0, rng, 0.5);
  for (auto& smp : f.drives[0].trajectory) smp.speed_mps *= 1.005;
  DriveAlignmentConfig cfg;
  cfg.gates_m = {2.0, 1.0, 0.5};
  cfg.odometry_parameters_gate_m = 0.3;  // finer than every round: never estimated
  const DriveAlignmentResult held = align_drives(f.drives, cfg);
  ASSERT_EQ(held.status, DriveAlignmentResult::Status::Aligned);
  for (const DriveCorrection& c : held.corrections) {
    EXPECT_EQ(c.odometry_scale_error, 0.0);
    EXPECT_EQ(c.gyro_bias_rps, 0.0);
  }
  cfg.odometry_parameters_gate_m = 0.5;  // the last round estimates them
  const DriveAlignmentResult last = align_drives(f.drives, cfg);
  ASSERT_EQ(last.status, DriveAlignmentResult::Status::Aligned);
  double others = 0.0;
  for (std::size_t d = 1; d < last.corrections.size(); ++d) {
    others += last.corrections[d].odometry_scale_error / 5.0;
  }
  // (1 + e) (1 + 0.005) = 1 relative to the others.
  EXPECT_NEAR(last.corrections[0].odometry_scale_error - others, -0.005, 0.001);
}

TEST(DriveAlignment, TheFleetsMeanWheelScaleHoldsTheMapsLength) {
  // A GNSS error every drive shares that stretches the route by 0.5 % (what a street
  // canyon's repeating multipath can do over a stretch), exact wheel speeds. Associations
  // tie the drives together but cannot see a common stretch; each drive's own scale prior
  // lets all of them follow it together, the fleet's mean scale factor does not.
  std::mt19937_64 rng(41);
  const World w = make_world(rng);
  const Fleet f = make_fleet(w, 10, 0, rng, 0.0, false, 10.0, 0.005);
  auto mean_scale = [](const DriveAlignmentResult& r) {
    double sum = 0.0;
    for (const DriveCorrection& c : r.corrections) sum += c.odometry_scale_error;
    return sum / static_cast<double>(r.corrections.size());
  };
  DriveAlignmentConfig cfg;
  cfg.fleet_scale_sigma = 0.0;
  const DriveAlignmentResult free = align_drives(f.drives, cfg);
  cfg.fleet_scale_sigma = DriveAlignmentConfig{}.fleet_scale_sigma;
  const DriveAlignmentResult held = align_drives(f.drives, cfg);
  ASSERT_EQ(free.status, DriveAlignmentResult::Status::Aligned);
  ASSERT_EQ(held.status, DriveAlignmentResult::Status::Aligned);
  EXPECT_GT(mean_scale(free), 0.0015);  // the odometry stretched to follow the GNSS
  EXPECT_LT(std::abs(mean_scale(held)), 0.0012);
  EXPECT_NEAR(held.scale_error_mean, mean_scale(held), 1e-12);
  // Per 200 m window the stretch is +-0.5 m along the road.
  const double rms_free = landmark_rms(w, f, &free).first;
  const double rms_held = landmark_rms(w, f, &held).first;
  // Measured: 0.148 m free (scale +0.24 %), 0.065 m held (+0.09 %).
  EXPECT_LT(rms_held, 0.08);
  EXPECT_LT(rms_held, 0.6 * rms_free);
}

TEST(DriveAlignment, StepsAcrossASampleGapOfAMovingCarAreNotOdometry) {
  // The store keeps a sample per metre and at least one per 5 s: after a stop, the next
  // sample may come seconds later at speed. Integrating speed across such a gap (here
  // 3 s, from 0.5 to 10 m/s: 16 m instead of 30 m) is no odometry; the step is skipped.
  std::mt19937_64 rng(41);
  const World w = make_world(rng);
  Fleet f = make_fleet(w, 8, 0, rng, 0.5);
  for (std::size_t d = 0; d < 4; ++d) {
    auto& tr = f.drives[d].trajectory;
    std::vector<AlignmentSample> kept;
    for (const auto& smp : tr) {
      const double x = smp.time_s * 10.0;
      if (x > 300.0 && x < 330.0) continue;
      kept.push_back(smp);
      if (x <= 300.0 && x > 299.0) kept.back().speed_mps = 0.5;
    }
    tr = std::move(kept);
  }
  const DriveAlignmentResult r = align_drives(f.drives);
  ASSERT_EQ(r.status, DriveAlignmentResult::Status::Aligned);
  EXPECT_EQ(r.odometry_drives, 8);
  for (std::size_t d = 0; d < 8; ++d) {  // the step across the gap, in the drives that have it
    EXPECT_EQ(r.corrections[d].odometry_steps_rejected, d < 4 ? 1 : 0) << d;
  }
  EXPECT_LT(landmark_rms(w, f, &r).first, 0.06);
  EXPECT_LT(inter_drive_rms(w, f, r), 0.06);
}

TEST(DriveAlignment, SurveyGradeDrivesAnchorTheAbsolutePosition) {
  std::mt19937_64 rng(12);
  const World w = make_world(rng);
  const Fleet f = make_fleet(w, 12, 2, rng);
  const DriveAlignmentResult r = align_drives(f.drives);
  ASSERT_EQ(r.status, DriveAlignmentResult::Status::Aligned);
  EXPECT_EQ(r.survey_grade_drives, 2);
  const auto [rms_after, off_after] = landmark_rms(w, f, &r);
  EXPECT_LT(rms_after, 0.08);
  EXPECT_LT(off_after.norm(), 0.05);
  for (std::size_t d = 0; d < 2; ++d) {  // the anchors hardly move
    for (const auto& n : r.corrections[d].node_correction) EXPECT_LT(n.head<2>().norm(), 0.05);
  }
}

TEST(DriveAlignment, OneSurveyGradeDriveOutweighsConsumerDrivesThatAgree) {
  // Five consumer drives that share a 2.4 m error (the place's multipath, the same in every
  // drive) agree with each other, not with the one RTK drive: the RTK drive must still win,
  // or the map keeps the consumer drives' common offset.
  std::mt19937_64 rng(13);
  const World w = make_world(rng);
  Fleet f = make_fleet(w, 6, 1, rng);
  const Eigen::Vector2d common(2.0, -1.3);
  std::normal_distribution<double> g(0.0, 0.05);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (std::size_t d = 1; d < f.drives.size(); ++d) {  // consumer drives: only the shared error
    AlignmentDrive& a = f.drives[d];
    for (std::size_t k = 0; k < a.trajectory.size(); ++k) {
      a.trajectory[k].position_m = road(0.5 * static_cast<double>(k)) + common;
    }
    a.points_m.clear();
    for (const Eigen::Vector2d& l : w.landmarks) {
      if (u(rng) < 0.8) a.points_m.push_back(l + common + Eigen::Vector2d(g(rng), g(rng)));
    }
  }
  const DriveAlignmentResult r = align_drives(f.drives);
  ASSERT_EQ(r.status, DriveAlignmentResult::Status::Aligned);
  EXPECT_EQ(r.survey_grade_drives, 1);
  // Where each consumer drive now puts the landmarks, against truth.
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  int n = 0;
  for (std::size_t d = 1; d < f.drives.size(); ++d) {
    for (const Eigen::Vector2d& p : f.drives[d].points_m) {
      const Eigen::Vector2d q = r.corrections[d].apply(p);
      double best = 0.5;
      const Eigen::Vector2d* t = nullptr;
      for (const auto& l : w.landmarks) {
        if ((l - q).norm() < best) best = (l - q).norm(), t = &l;
      }
      if (t != nullptr) mean += q - *t, ++n;
    }
  }
  ASSERT_GT(n, 200);  // most candidates sit on a landmark again
  EXPECT_LT((mean / n).norm(), 0.1);
}

TEST(DriveAlignment, SurveyGradeFleetIsLeftAlone) {
  std::mt19937_64 rng(13);
  const World w = make_world(rng);
  const Fleet f = make_fleet(w, 4, 4, rng);
  const DriveAlignmentResult r = align_drives(f.drives);
  EXPECT_EQ(r.status, DriveAlignmentResult::Status::NotNeeded);
  const Eigen::Vector2d p(300.0, 12.0);
  for (const auto& c : r.corrections) EXPECT_EQ(c.apply(p), p);
}

TEST(DriveAlignment, CorrectionInterpolatesBetweenNodesAndRotatesAboutThePath) {
  DriveCorrection c;
  c.node_s_m = {0.0, 10.0};
  c.node_position_m = {{0.0, 0.0}, {10.0, 0.0}};
  c.node_correction = {{1.0, 0.0, 0.0}, {3.0, 2.0, 0.0}};
  for (int i = 0; i <= 10; ++i) {
    c.path_m.emplace_back(i, 0.0);
    c.path_s_m.push_back(i);
  }
  EXPECT_TRUE(c.at(5.0).isApprox(Eigen::Vector3d(2.0, 1.0, 0.0)));
  EXPECT_TRUE(c.apply({5.0, 7.0}).isApprox(Eigen::Vector2d(7.0, 8.0)));
  // A pure rotation of 90 degrees about the path point nearest to p.
  c.node_correction = {{0.0, 0.0, M_PI / 2}, {0.0, 0.0, M_PI / 2}};
  EXPECT_TRUE(c.apply({4.0, 3.0}).isApprox(Eigen::Vector2d(1.0, 0.0), 1e-12));
}

TEST(DriveAlignment, ACandidateTurnsAboutWhereItWasSeenFrom) {
  // A heading error turns what the car saw about the car: a candidate seen 5 m before its
  // nearest trajectory point turns about that earlier point; the trajectory point itself
  // about itself.
  DriveCorrection c;
  c.node_s_m = {0.0, 20.0};
  c.node_position_m = {{0.0, 0.0}, {20.0, 0.0}};
  const double th = 0.01;
  c.node_correction = {{0.0, 0.0, th}, {0.0, 0.0, th}};
  for (int i = 0; i <= 20; ++i) {
    c.path_m.emplace_back(i, 0.0);
    c.path_s_m.push_back(i);
  }
  c.candidate_lead_m = -5.0;
  const Eigen::Vector2d p(12.0, 4.0);
  auto turned = [&](const Eigen::Vector2d& pivot) {
    const Eigen::Vector2d r = p - pivot;
    return Eigen::Vector2d(pivot.x() + std::cos(th) * r.x() - std::sin(th) * r.y(),
                           pivot.y() + std::sin(th) * r.x() + std::cos(th) * r.y());
  };
  EXPECT_TRUE(c.apply(p, true).isApprox(turned({7.0, 0.0}), 1e-12));
  EXPECT_TRUE(c.apply(p, false).isApprox(turned({12.0, 0.0}), 1e-12));
  // The two differ by th x 5 m across the road.
  EXPECT_NEAR((c.apply(p, true) - c.apply(p, false)).norm(), th * 5.0, 1e-6);
}

}  // namespace
}  // namespace polmap::mapping
