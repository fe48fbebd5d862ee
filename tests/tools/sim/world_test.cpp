// Procedural worlds: object classes and densities per preset, spatial index,
// occlusion, temporary objects per drive, 10 km routes.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <map>

#include "polmap/sim/drive_simulator.hpp"
#include "sim_test_util.hpp"

namespace polmap::sim {
namespace {

std::map<ObjectClass, int> class_counts(const World& w) {
  std::map<ObjectClass, int> c;
  for (const auto& o : w.objects) ++c[o.cls];
  return c;
}

TEST(World, UrbanHasDenseInfrastructure) {
  auto w = load_world("urban", 1000.0, 1);
  auto c = class_counts(*w);
  EXPECT_GT(c[ObjectClass::Facade], 20);
  EXPECT_GT(c[ObjectClass::FacadeRecess], 50);
  EXPECT_GT(c[ObjectClass::FacadeCorner], 40);
  EXPECT_GT(c[ObjectClass::LampPole], 40);
  EXPECT_GT(c[ObjectClass::SignPlate], 8);
  EXPECT_EQ(c[ObjectClass::SignPlate], c[ObjectClass::SignPole]);
  EXPECT_GT(c[ObjectClass::Curbstone], 10);
  EXPECT_GT(c[ObjectClass::ParkedCar], 10);
  EXPECT_NEAR(w->route.length_m(), 1000.0, 0.2);
  for (const auto& o : w->objects) {
    if (o.cls == ObjectClass::ParkedCar || o.cls == ObjectClass::Bin) {
      EXPECT_FALSE(o.permanent);
    }
    if (o.cls == ObjectClass::LampPole) {
      EXPECT_TRUE(o.permanent);
    }
  }
}

TEST(World, IndustrialHasFencesWithPostsAndWalls) {
  auto w = load_world("industrial", 1500.0, 2);
  auto c = class_counts(*w);
  EXPECT_GT(c[ObjectClass::FenceMesh], 3);
  EXPECT_GT(c[ObjectClass::FencePost], 100);
  EXPECT_GT(c[ObjectClass::Wall], 1);
  EXPECT_TRUE(w->road.has_same_dir_lane);
}

TEST(World, RuralGuidePostsEvery50mAndGuardrailPostsEvery2To4m) {
  const double len = 3000.0;
  auto w = load_world("rural", len, 3);
  auto c = class_counts(*w);
  EXPECT_EQ(c[ObjectClass::GuidePost], 2 * static_cast<int>((len - 25.0) / 50.0 + 1));
  ASSERT_GT(c[ObjectClass::GuardrailBeam], 0);
  EXPECT_GT(c[ObjectClass::TreeTrunk], 20);
  EXPECT_GT(c[ObjectClass::Vegetation], 20);
  // Post spacing along each guardrail: total beam length / posts within [2, 4] m.
  double beam_len = 0;
  for (const auto& o : w->objects) {
    if (o.cls != ObjectClass::GuardrailBeam) continue;
    for (std::size_t i = 1; i < o.geometry_m.size(); ++i)
      beam_len += (o.geometry_m[i] - o.geometry_m[i - 1]).norm();
  }
  const double spacing = beam_len / c[ObjectClass::GuardrailPost];
  EXPECT_GE(spacing, 1.9);
  EXPECT_LE(spacing, 4.1);
  // Low vegetation in front of guide posts differs between drives.
  int differing = 0;
  for (const auto& o : w->objects) {
    if (o.cls == ObjectClass::Vegetation && !o.permanent)
      differing += w->present(o.id, 0, 3) != w->present(o.id, 1, 3);
  }
  EXPECT_GT(differing, 5);
}

TEST(World, TenKilometreRouteIsCompactAndQueriesAreLocal) {
  const auto t0 = std::chrono::steady_clock::now();
  auto w = load_world("urban", 10000.0, 9);
  const double build_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_LT(build_s, 10.0);
  EXPECT_NEAR(w->route.length_m(), 10000.0, 1.0);
  std::vector<std::uint32_t> p, l, o;
  const PathPoint mid = w->route.at(5000.0);
  w->query({mid.x_m, mid.y_m}, 80.0, p, l, o);
  EXPECT_LT(p.size(), w->points.size() / 10);
  EXPECT_GT(p.size(), 10U);
  // Every point within 80 m is returned (brute-force reference).
  std::size_t within = 0;
  for (const auto& s : w->points)
    within += (s.pos_m - Eigen::Vector2d(mid.x_m, mid.y_m)).norm() <= 80.0;
  std::size_t found = 0;
  for (auto i : p) found += (w->points[i].pos_m - Eigen::Vector2d(mid.x_m, mid.y_m)).norm() <= 80.0;
  EXPECT_EQ(found, within);
}

TEST(World, WallOccludesPoleBehindIt) {
  auto w = test::empty_world();
  const std::uint32_t pole = test::add_point(*w, {3.7 + 30.0, 0.0}, odd_bounce(), 10.0);
  (void)pole;
  LineScatterer l;
  l.p0_m = {3.7 + 20.0, -3.0};
  l.p1_m = {3.7 + 20.0, 3.0};
  l.opaque = true;
  l.rcs_per_m_dbsm = -30.0F;  // weak so it does not mask the pole's range anyway
  l.object = test::add_object(*w, ObjectClass::Wall, {l.p0_m, l.p1_m});
  w->lines.push_back(l);
  w->build_index();
  SimConfig cfg = test::quiet_config();
  FrameRenderer rend(w, cfg);
  const SensorFrame f = test::render_standing_at_origin(rend, cfg);
  for (const auto& c : f.spectrum.cells) {
    EXPECT_FALSE(std::abs(c.range_bin * 0.075 - 30.0) < 0.3 && std::norm(c.s[1]) > 100.0);
  }
  // Without the wall the pole is there (SNR ~ 20 + 10 + 8 = 38 dB).
  auto w2 = test::empty_world();
  test::add_point(*w2, {3.7 + 30.0, 0.0}, odd_bounce(), 10.0);
  w2->build_index();
  FrameRenderer rend2(w2, cfg);
  const SensorFrame f2 = test::render_standing_at_origin(rend2, cfg);
  const SpectrumCell* pk = test::peak_cell(f2.spectrum);
  ASSERT_NE(pk, nullptr);
  EXPECT_NEAR(pk->range_bin * 0.075, 30.0, 0.1);
  EXPECT_GT(std::norm(pk->s[1]), 3000.0);
}

TEST(World, TemporaryObjectsStandElsewhereInEachDrive) {
  // A parked car is a different car in the same space from one drive to the next: the
  // echo of a temporary centre comes from its place shifted along the object's axis by
  // the drive's draw, within +-drive_shift_max_m; permanent objects never move.
  auto w = test::empty_world();
  const std::uint32_t car =
      test::add_point(*w, {3.7 + 30.0, 0.0}, odd_bounce(), 10.0, ObjectClass::ParkedCar);
  w->objects[car].permanent = false;
  w->objects[car].presence_probability = 1.0;
  w->objects[car].drive_shift_axis = Eigen::Vector2d::UnitX();
  w->objects[car].drive_shift_max_m = 1.0;
  const std::uint32_t pole = test::add_point(*w, {3.7 + 20.0, 0.0}, odd_bounce(), -20.0);
  w->build_index();
  const SimConfig cfg = test::noise_free_config();
  FrameRenderer rend(w, cfg);
  double lo = 1e9, hi = -1e9;
  for (int d = 0; d < 8; ++d) {
    const Eigen::Vector2d shift = w->drive_shift_m(car, d, cfg.seed);
    EXPECT_LE(std::abs(shift.x()), 1.0);
    EXPECT_EQ(shift.y(), 0.0);
    EXPECT_TRUE(w->drive_shift_m(pole, d, cfg.seed).isZero());
    const DrivePlan plan(*w, cfg, d);
    EXPECT_EQ(plan.shift_m(car), shift);
    const SensorFrame f =
        rend.render(cfg.sensors[0], test::state_at(0, 0, 0, 0.0), &plan, 0, false, 1);
    const SpectrumCell* pk = test::peak_cell(f.spectrum);
    ASSERT_NE(pk, nullptr);
    EXPECT_NEAR(pk->range_bin * 0.075, 30.0 + shift.x(), 0.06) << "drive " << d;
    lo = std::min(lo, shift.x());
    hi = std::max(hi, shift.x());
  }
  EXPECT_GT(hi - lo, 0.8);  // 8 uniform draws on [-1, 1] spread (fails only if all collide)
}

TEST(World, SignPlateIsSpecular) {
  // Plate facing the sensor vs turned by 30 deg: >= 18 dB difference.
  double p[2];
  for (int k = 0; k < 2; ++k) {
    auto w = test::empty_world();
    PointScatterer s;
    s.pos_m = {3.7 + 25.0, 0.0};
    s.omega = odd_bounce();
    s.rcs_dbsm = 15.0F;
    s.aspect = Aspect::Specular;
    s.normal_rad = static_cast<float>(M_PI + (k == 0 ? 0.0 : 30.0 * test::kDeg));
    s.lobe_rad = static_cast<float>(3.3 * test::kDeg);
    s.back_gain_db = -20.0F;
    s.two_sided = true;
    s.object = test::add_object(*w, ObjectClass::SignPlate, {s.pos_m});
    w->points.push_back(s);
    const SensorFrame f = test::render_noise_free_at_origin(w);
    p[k] = std::norm(test::peak_cell(f.spectrum)->s[1]);
  }
  EXPECT_NEAR(10 * std::log10(p[0] / p[1]), 20.0, 0.5);
}

TEST(World, VegetationAttenuatesWhatIsBehindIt) {
  double peak[2];
  for (int k = 0; k < 2; ++k) {
    auto w = test::empty_world();
    test::add_point(*w, {3.7 + 20.0, 2.0}, odd_bounce(), 0.0, ObjectClass::GuidePost);
    if (k == 1) {
      LineScatterer l;
      l.p0_m = {3.7 + 19.4, 0.0};
      l.p1_m = {3.7 + 19.4, 4.0};
      l.model = ExtendedModel::Volume;
      l.rcs_per_m_dbsm = -80.0F;  // scattering negligible here: measure the loss only
      l.vegetation = true;
      l.object = test::add_object(*w, ObjectClass::Vegetation, {l.p0_m, l.p1_m});
      w->lines.push_back(l);
    }
    const SensorFrame f = test::render_noise_free_at_origin(w);
    peak[k] = std::norm(test::peak_cell(f.spectrum)->s[1]);
  }
  EXPECT_NEAR(10 * std::log10(peak[0] / peak[1]), 15.0, 0.1);
}

TEST(World, ExtendedObjectsShowRayleighSpeckle) {
  // A diffuse wall: the complex amplitude of a fixed cell over frames from (slightly)
  // different sensor positions is circular Gaussian, so E|s|^4 / (E|s|^2)^2 = 2 (a constant
  // target would give 1). Standing still, the speckle is frozen (only noise changes).
  auto w = test::empty_world();
  const std::vector<Eigen::Vector2d> wall_m = {{3.7 + 5.0, 6.0}, {3.7 + 25.0, 6.0}};
  LineScatterer proto;
  proto.model = ExtendedModel::Surface;
  proto.rcs_per_m_dbsm = 0.0F;
  proto.object = test::add_object(*w, ObjectClass::Wall, wall_m);
  w->add_line_pieces(wall_m, proto);
  w->build_index();
  SimConfig cfg = test::quiet_config();
  FrameRenderer rend(w, cfg);
  // Cell looking at the wall: range 10 m, azimuth atan(6 / 8) = 36.9 deg -> beam 65 (37.5 deg).
  const int rb = static_cast<int>(std::lround(std::hypot(8.0, 6.0) / 0.075));
  double m2 = 0, m4 = 0;
  int n = 0;
  for (int k = 0; k < 600; ++k) {
    const SensorFrame f = rend.render(cfg.sensors[0], test::state_at(0.002 * k, 0, 0, 0.0), nullptr,
                                      k, false, 5000 + k);
    for (const auto& c : f.spectrum.cells) {
      if (c.range_bin == rb && c.azimuth_bin == 65) {
        const double p = std::norm(c.s[1]);
        m2 += p;
        m4 += p * p;
        ++n;
      }
    }
  }
  ASSERT_GT(n, 500);  // strong cell: stored almost always
  m2 /= n;
  m4 /= n;
  EXPECT_NEAR(m4 / (m2 * m2), 2.0, 0.35);
  // Frozen at standstill: same pose, different frames -> differences are noise only.
  double diff = 0, pow = 0;
  int same = 0;
  for (int k = 0; k < 50; ++k) {
    const SensorFrame a = test::render_standing_at_origin(rend, cfg);
    const SensorFrame b =
        rend.render(cfg.sensors[0], test::state_at(0, 0, 0, 0.0), nullptr, 1, false, 2 + k);
    for (const auto& ca : a.spectrum.cells) {
      if (ca.range_bin != rb || ca.azimuth_bin != 65) continue;
      for (const auto& cb : b.spectrum.cells) {
        if (cb.range_bin == rb && cb.azimuth_bin == 65) {
          diff += std::norm(ca.s[1] - cb.s[1]);
          pow += std::norm(ca.s[1]);
          ++same;
        }
      }
    }
  }
  ASSERT_GT(same, 40);
  EXPECT_NEAR(diff / same, 2.0, 0.8);  // two independent noise draws, sigma = 1 each
  EXPECT_GT(pow / same, 100.0);
}

}  // namespace
}  // namespace polmap::sim
