#include "polmap/sim/drive_simulator.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numbers>
#include <numeric>

#include "polmap/schema/errors.hpp"
#include "polmap/sim/scattering.hpp"

namespace polmap::sim {

namespace {
constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180.0;
constexpr double kFovMarginRad = 6.0 * kDeg;  // echoes just outside the FoV leak into edge beams

inline double cross(const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return a.x() * b.y() - a.y() * b.x();
}

/// Range along the ray at azimuth az to segment (a, b); +inf if it misses.
inline double ray_hit(const Eigen::Vector2d& a, const Eigen::Vector2d& b, double az) {
  const Eigen::Vector2d d(std::cos(az), std::sin(az));
  const Eigen::Vector2d e = b - a;
  const double den = cross(d, e);
  if (std::abs(den) < 1e-12) return std::numeric_limits<double>::infinity();
  const double rho = cross(a, e) / den;
  const double t = cross(a, d) / den;
  if (t < -1e-6 || t > 1.0 + 1e-6 || rho <= 0) return std::numeric_limits<double>::infinity();
  return rho;
}

const ScatteringVector& odd_ref() {
  static const ScatteringVector o = odd_bounce();
  return o;
}
}  // namespace

namespace {
SimConfig with_realistic_noise(SimConfig cfg) {
  cfg.radar = apply_radar_noise(cfg.radar, cfg.realism.radar_noise);
  return cfg;
}
}  // namespace

FrameRenderer::FrameRenderer(std::shared_ptr<const World> world, const SimConfig& cfg)
    : world_(std::move(world)),
      cfg_(with_realistic_noise(cfg)),
      synth_(cfg_.radar, cfg.sensors.empty() ? RadarSpec{} : cfg.sensors.front().spec),
      overhead_(overhead_structures(*world_, cfg.realism.elevation, cfg.seed)) {
  occ_step_rad_ = cfg.radar.occlusion_bin_deg * kDeg;
  occ_lo_rad_ = -(cfg.radar.fov_half_deg * kDeg + kFovMarginRad + occ_step_rad_);
  const int n = static_cast<int>(std::ceil(-2.0 * occ_lo_rad_ / occ_step_rad_)) + 1;
  occ_opaque_.assign(n, -1);
  occ_veg_.assign(n, -1);
  occ_opaque_r_.assign(n, std::numeric_limits<float>::infinity());
  occ_veg_r_.assign(n, std::numeric_limits<float>::infinity());
}

int FrameRenderer::occ_bin(double az) const {
  const int b = static_cast<int>(std::floor((az - occ_lo_rad_) / occ_step_rad_));
  return std::clamp(b, 0, static_cast<int>(occ_opaque_.size()) - 1);
}

void FrameRenderer::add_occluder(const Eigen::Vector2d& a0, const Eigen::Vector2d& b0, bool veg) {
  // Clip to the half plane in front of the sensor.
  constexpr double kXmin = 0.05;
  Eigen::Vector2d a = a0, b = b0;
  if (a.x() < kXmin && b.x() < kXmin) return;
  if (a.x() < kXmin) a = a + (b - a) * ((kXmin - a.x()) / (b.x() - a.x()));
  if (b.x() < kXmin) b = b + (a - b) * ((kXmin - b.x()) / (a.x() - b.x()));
  if (std::min(a.norm(), b.norm()) > cfg_.radar.max_range_m + 1.0) return;
  const double pa = std::atan2(a.y(), a.x()), pb = std::atan2(b.y(), b.x());
  const int lo = occ_bin(std::min(pa, pb)), hi = occ_bin(std::max(pa, pb));
  const int idx = static_cast<int>(segs_.size());
  segs_.push_back({a, b});
  auto& ids = veg ? occ_veg_ : occ_opaque_;
  auto& rs = veg ? occ_veg_r_ : occ_opaque_r_;
  for (int k = lo; k <= hi; ++k) {
    const double az = occ_lo_rad_ + (k + 0.5) * occ_step_rad_;
    double r = ray_hit(a, b, az);
    if (!std::isfinite(r)) {
      if (lo != hi) continue;
      r = std::min(a.norm(), b.norm());  // sub-bin segment: still occludes its bin
    }
    if (r < rs[k]) {
      rs[k] = static_cast<float>(r);
      ids[k] = idx;
    }
  }
}

double FrameRenderer::occlusion_loss(double r, double az) const {
  const int k = occ_bin(az);
  const double margin = cfg_.radar.occlusion_margin_m;
  if (occ_opaque_[k] >= 0) {
    const OccSeg& s = segs_[occ_opaque_[k]];
    double h = ray_hit(s.a, s.b, az);
    if (!std::isfinite(h)) h = occ_opaque_r_[k];
    if (r > h + margin) return 0.0;
  }
  if (occ_veg_[k] >= 0) {
    const OccSeg& s = segs_[occ_veg_[k]];
    double h = ray_hit(s.a, s.b, az);
    if (!std::isfinite(h)) h = occ_veg_r_[k];
    if (r > h + margin) return std::pow(10.0, -cfg_.radar.vegetation_loss_db / 10.0);
  }
  return 1.0;
}

SensorFrame FrameRenderer::render(const SensorMount& mount, const ExactState& st,
                                  const DrivePlan* plan, std::uint32_t cycle, bool with_cube,
                                  std::uint64_t frame_seed, const std::vector<Mover>* extra) {
  const World& w = *world_;
  const RadarSimConfig& rc = cfg_.radar;
  Rng rng(frame_seed);
  // Sensor pose in the world and its velocity (zero side slip: v_s = (v - w y_m, w x_m)).
  const double cy = std::cos(st.yaw_rad), sy = std::sin(st.yaw_rad);
  const Pose2& m = mount.T_vehicle_sensor;
  const Eigen::Vector2d ps(st.x_m + cy * m.x_m - sy * m.y_m, st.y_m + sy * m.x_m + cy * m.y_m);
  const double psi = st.yaw_rad + m.yaw_rad;
  const double cps = std::cos(psi), sps = std::sin(psi);
  Eigen::Vector2d v_veh(st.v_mps - st.yaw_rate_rps * m.y_m, st.yaw_rate_rps * m.x_m);
  if (st.side_slip_rad != 0.0) {  // rear-axle velocity v (cos beta, sin beta) (realism.hpp)
    v_veh = Eigen::Vector2d(st.v_mps * std::cos(st.side_slip_rad) - st.yaw_rate_rps * m.y_m,
                            st.v_mps * std::sin(st.side_slip_rad) + st.yaw_rate_rps * m.x_m);
  }
  const double cm = std::cos(m.yaw_rad), sm = std::sin(m.yaw_rad);
  const Eigen::Vector2d v_sens(cm * v_veh.x() + sm * v_veh.y(), -sm * v_veh.x() + cm * v_veh.y());
  const Eigen::Vector2d v_world(cy * v_veh.x() - sy * v_veh.y(), sy * v_veh.x() + cy * v_veh.y());
  auto to_sensor = [&](const Eigen::Vector2d& p) {
    const Eigen::Vector2d d = p - ps;
    return Eigen::Vector2d(cps * d.x() + sps * d.y(), -sps * d.x() + cps * d.y());
  };
  auto is_present = [&](std::uint32_t id) { return plan == nullptr || plan->present(id); };
  // Temporary objects stand somewhere else in each drive (DrivePlan::shift_m).
  const Eigen::Vector2d no_shift = Eigen::Vector2d::Zero();
  auto shift_of = [&](std::uint32_t id) -> const Eigen::Vector2d& {
    return plan == nullptr ? no_shift : plan->shift_m(id);
  };

  // Speckle (distributed targets, ground, bark) is a function of the exact sensor pose:
  // frozen while standing, independent once the sensor moved a few millimetres.
  auto bits = [](double d) {
    std::uint64_t u;
    std::memcpy(&u, &d, sizeof u);
    return u;
  };
  const std::uint64_t scene_key =
      seed_of(cfg_.seed, 0x7370656bULL, mount.sensor_id, bits(ps.x()), bits(ps.y()), bits(psi));
  synth_.begin(v_sens, with_cube, scene_key);
  const double fov = rc.fov_half_deg * kDeg + kFovMarginRad;
  const double rmax = rc.max_range_m + 0.5;

  // 1. Occlusion buffer: opaque surfaces, vegetation, car bodies (static and moving).
  std::fill(occ_opaque_.begin(), occ_opaque_.end(), -1);
  std::fill(occ_veg_.begin(), occ_veg_.end(), -1);
  std::fill(occ_opaque_r_.begin(), occ_opaque_r_.end(), std::numeric_limits<float>::infinity());
  std::fill(occ_veg_r_.begin(), occ_veg_r_.end(), std::numeric_limits<float>::infinity());
  segs_.clear();
  w.query(ps, rmax, q_points_, q_lines_, q_occ_);
  for (std::uint32_t i : q_lines_) {
    const LineScatterer& l = w.lines[i];
    if ((l.opaque || l.vegetation) && is_present(l.object)) {
      add_occluder(to_sensor(l.p0_m), to_sensor(l.p1_m), l.vegetation && !l.opaque);
    }
  }
  for (std::uint32_t i : q_occ_) {
    const OccluderSegment& o = w.occluders[i];
    if (!is_present(o.object)) continue;
    const Eigen::Vector2d& sh = shift_of(o.object);
    add_occluder(to_sensor(o.p0_m + sh), to_sensor(o.p1_m + sh), o.vegetation);
  }
  struct MoverNow {
    const Mover* m;
    Eigen::Vector2d centre, ex, ey, vel;
    std::uint64_t index;
  };
  std::vector<MoverNow> movers;
  std::vector<const Mover*> all_movers;
  if (plan != nullptr) {
    for (const Mover& mv : plan->movers()) all_movers.push_back(&mv);
  }
  if (extra != nullptr) {
    for (const Mover& mv : *extra) all_movers.push_back(&mv);
  }
  {
    const double len = w.route.length_m();
    for (std::size_t mi = 0; mi < all_movers.size(); ++mi) {
      const Mover& mv = *all_movers[mi];
      const double s = mv.station(st.time_s);
      if (s < 0 || s > len) continue;
      const PathPoint p = w.route.at(s);
      const Eigen::Vector2d c = w.route.offset_point(s, mv.lateral_m);
      if ((c - ps).squaredNorm() > (rmax + 5) * (rmax + 5)) continue;
      const double yaw = p.yaw_rad + (mv.direction < 0 ? kPi : 0.0);
      const Eigen::Vector2d ex(std::cos(yaw), std::sin(yaw)), ey(-ex.y(), ex.x());
      movers.push_back({&mv, c, ex, ey, mv.speed_mps * ex, mi});
      const double hl = 0.5 * mv.length_m, hw = 0.5 * mv.width_m;
      const Eigen::Vector2d k[4] = {c + hl * ex + hw * ey, c - hl * ex + hw * ey,
                                    c - hl * ex - hw * ey, c + hl * ex - hw * ey};
      for (int j = 0; j < 4; ++j) add_occluder(to_sensor(k[j]), to_sensor(k[(j + 1) % 4]), false);
    }
  }

  const double lambda = synth_.wavelength_m();
  const double k4pi = 4.0 * kPi / lambda;
  const double noise = rc.noise_sigma;
  const DistributedModel volume = DistributedModel::volume();

  // Realism (realism.hpp): ground bounce per scattering centre (height drawn per centre),
  // multipath ghosts of strong isotropic centres and movers.
  const ElevationRealism& el = cfg_.realism.elevation;
  const MultipathRealism& mp = cfg_.realism.multipath;
  const bool bounce = el.enabled && el.ground_bounce;
  const bool ghosts = mp.enabled && (mp.mirror_ghosts || mp.mixed_paths);
  auto bounce_gain = [&](double r, std::uint64_t centre) {
    const double h =
        el.target_height_min_m + (el.target_height_max_m - el.target_height_min_m) *
                                     hash_uniform(seed_of(cfg_.seed, 0x68676874ULL, centre));
    return ground_bounce_gain(r, rc.sensor_height_m, h, el.ground_reflection, lambda);
  };
  struct GhostTarget {
    Eigen::Vector2d pos_w, vel_w;
    double rcs_dbsm, phase_rad;
    ScatteringVector omega;
    std::uint64_t key;
  };
  std::vector<GhostTarget> ghost_targets;

  // 2. Point scatterers.
  for (std::uint32_t i : q_points_) {
    const PointScatterer& p = w.points[i];
    if (!is_present(p.object)) continue;
    const Eigen::Vector2d pos_m = p.pos_m + shift_of(p.object);
    const Eigen::Vector2d q = to_sensor(pos_m);
    const double r = q.norm();
    if (r < rc.min_range_m || r > rmax) continue;
    const double az = std::atan2(q.y(), q.x());
    if (std::abs(az) > fov) continue;
    double gain = occlusion_loss(r, az);
    if (gain <= 0) continue;
    if (p.aspect != Aspect::Isotropic) {
      const double beta = std::atan2(ps.y() - pos_m.y(), ps.x() - pos_m.x());
      double a = std::abs(wrap_angle_rad(beta - p.normal_rad));
      const double back = std::pow(10.0, p.back_gain_db / 10.0);
      if (p.aspect == Aspect::Specular) {
        if (p.two_sided) a = std::min(a, kPi - a);
        gain *= std::max(std::exp(-0.5 * a * a / (p.lobe_rad * p.lobe_rad)), back);
      } else {
        gain *= a <= p.lobe_rad ? 1.0 : back;
      }
    }
    if (bounce) gain *= bounce_gain(r, i);
    if (ghosts && p.aspect == Aspect::Isotropic && p.rcs_dbsm >= mp.min_target_rcs_dbsm) {
      ghost_targets.push_back(
          {pos_m, Eigen::Vector2d::Zero(), p.rcs_dbsm, p.phase_rad, p.omega, i});
    }
    const double amp = noise * std::sqrt(synth_.snr_linear(p.rcs_dbsm, r) * gain);
    const double ph = -k4pi * r + p.phase_rad;
    const cdouble z = amp * cdouble(std::cos(ph), std::sin(ph));
    Echo e;
    e.range_m = r;
    e.azimuth_rad = az;
    e.radial_velocity_mps = synth_.static_velocity(az);
    if (p.diffuse_fraction > 0) {
      HashRng prng(seed_of(scene_key, 0x70ULL, i));
      const ScatteringVector vs = volume.sample(prng);
      const double a = std::sqrt(1.0 - p.diffuse_fraction), b = std::sqrt(p.diffuse_fraction);
      for (int c = 0; c < 4; ++c) e.amplitude[c] = z * a * p.omega[c] + amp * b * vs[c];
    } else {
      for (int c = 0; c < 4; ++c) e.amplitude[c] = z * p.omega[c];
    }
    synth_.add_echo(e);
  }

  // 3. Extended objects: walk the sub-scatterer chain, aggregate per resolution cell into one
  //    complex Gaussian sample with the summed power (statistically equivalent speckle).
  const double step = rc.extended_step_m;
  const double dr = rc.range_bin_m;
  for (std::uint32_t li : q_lines_) {
    const LineScatterer& l = w.lines[li];
    if (!is_present(l.object)) continue;
    const Eigen::Vector2d a = to_sensor(l.p0_m), b = to_sensor(l.p1_m);
    const Eigen::Vector2d e = b - a;
    const double len = e.norm();
    if (len < 1e-6) continue;
    // Distance from the sensor to the segment: skip pieces beyond range.
    const double t0 = std::clamp(-a.dot(e) / (len * len), 0.0, 1.0);
    if ((a + t0 * e).norm() > rmax) continue;
    if (a.x() < 0 && b.x() < 0) continue;
    const Eigen::Vector2d nrm(-e.y() / len, e.x() / len);
    const int n = std::max(1, static_cast<int>(std::ceil(len / step)));
    const double sl = len / n;
    const double sig = std::pow(10.0, l.rcs_per_m_dbsm / 10.0) * sl;
    const double gspec = l.specular_gain_db > -50 ? std::pow(10.0, l.specular_gain_db / 10.0) : 0.0;
    const double w2 = 2.0 * l.specular_width_rad * l.specular_width_rad;
    ScatteringVector even{};
    if (l.model == ExtendedModel::EvenDihedral) even = dihedral(l.theta_rad);
    const DistributedModel model = l.model == ExtendedModel::Volume ? DistributedModel::volume()
                                   : l.model == ExtendedModel::MixedRandom
                                       ? DistributedModel::mixed()
                                       : DistributedModel::surface();
    int run_r = -1, run_b = -1, run_k = 0;
    double pd = 0, psp = 0;
    auto flush = [&]() {
      if (run_r >= 0 && (pd > 0 || psp > 0)) {
        HashRng cell_rng(seed_of(scene_key, 0x6cULL, li, static_cast<std::uint64_t>(run_k)));
        ScatteringVector s{};
        if (pd > 0) {
          if (l.model == ExtendedModel::EvenDihedral) {
            const cdouble z = cell_rng.cnormal(pd);
            for (int c = 0; c < 4; ++c) s[c] = z * even[c];
          } else {
            s = model.sample(cell_rng);
            const double k = std::sqrt(pd);
            for (auto& c : s) c *= k;
          }
        }
        if (psp > 0) {
          const cdouble z = cell_rng.cnormal(psp);
          for (int c = 0; c < 4; ++c) s[c] += z * odd_ref()[c];
        }
        synth_.add_cell(run_r, run_b, s);
      }
      run_r = -1;
      pd = psp = 0;
    };
    for (int k = 0; k < n; ++k) {
      const Eigen::Vector2d q = a + ((k + 0.5) / n) * e;
      const double r = q.norm();
      if (r < rc.min_range_m || r > rmax) {
        flush();
        continue;
      }
      const double az = std::atan2(q.y(), q.x());
      if (std::abs(az) > fov) {
        flush();
        continue;
      }
      const double occ = occlusion_loss(r, az);
      if (occ <= 0) {
        flush();
        continue;
      }
      const double cos_a = std::min(1.0, std::abs(nrm.dot(q)) / r);
      const double snr = synth_.snr_linear_sigma(sig, r) * occ * noise * noise;
      const double diff = snr * std::pow(cos_a, l.grazing_exponent);
      double spec = 0;
      if (gspec > 0 && cos_a > 0.9) {
        const double al = std::acos(cos_a);
        spec = snr * gspec * std::exp(-al * al / w2);
      }
      const int rb = static_cast<int>(std::lround(r / dr));
      const int bb = synth_.nearest_beam(az);
      if (rb != run_r || bb != run_b) {
        flush();
        run_r = rb;
        run_b = bb;
        run_k = k;
      }
      pd += diff;
      psp += spec;
    }
    flush();
  }

  // 4. Moving traffic: echoes with their own Doppler (vanish from the static spectrum unless
  //    their aliased Doppler coincides with the static one of the beam).
  for (const MoverNow& mn : movers) {
    for (const PointScatterer& c : mn.m->centres) {
      const Eigen::Vector2d pw = mn.centre + c.pos_m.x() * mn.ex + c.pos_m.y() * mn.ey;
      const Eigen::Vector2d q = to_sensor(pw);
      const double r = q.norm();
      if (r < rc.min_range_m || r > rmax) continue;
      const double az = std::atan2(q.y(), q.x());
      if (std::abs(az) > fov) continue;
      const double gain = occlusion_loss(r, az);
      if (gain <= 0) continue;
      const Eigen::Vector2d u = (pw - ps) / r;  // world frame, sensor -> target
      const auto centre_key =
          static_cast<std::uint64_t>(&c - mn.m->centres.data()) + (mn.index << 8) + (1ULL << 40);
      double g = gain;
      if (bounce) g *= bounce_gain(r, centre_key);
      if (ghosts && c.rcs_dbsm >= mp.min_target_rcs_dbsm) {
        ghost_targets.push_back({pw, mn.vel, c.rcs_dbsm, c.phase_rad, c.omega, centre_key});
      }
      const double amp = noise * std::sqrt(synth_.snr_linear(c.rcs_dbsm, r) * g);
      const double ph = -k4pi * r + c.phase_rad;
      const cdouble z = amp * cdouble(std::cos(ph), std::sin(ph));
      Echo e;
      e.range_m = r;
      e.azimuth_rad = az;
      e.radial_velocity_mps = (mn.vel - v_world).dot(u);
      for (int ch = 0; ch < 4; ++ch) e.amplitude[ch] = z * c.omega[ch];
      synth_.add_echo(e);
    }
  }

  // 5. Multipath (realism.hpp): specular bounces at walls, facades and guardrail beams.
  if (ghosts && !ghost_targets.empty()) {
    const double wall_loss = std::pow(10.0, -mp.wall_loss_db / 10.0);
    const double rail_loss = std::pow(10.0, -mp.guardrail_loss_db / 10.0);
    const double r2max = mp.max_reflector_range_m * mp.max_reflector_range_m;
    for (std::uint32_t li : q_lines_) {
      const LineScatterer& l = w.lines[li];
      if (l.specular_gain_db <= -50 || !is_present(l.object)) continue;
      const Eigen::Vector2d e = l.p1_m - l.p0_m;
      const double t0 =
          std::clamp((ps - l.p0_m).dot(e) / std::max(1e-12, e.squaredNorm()), 0.0, 1.0);
      if ((l.p0_m + t0 * e - ps).squaredNorm() > r2max) continue;
      const bool rail = w.objects[l.object].cls == ObjectClass::GuardrailBeam;
      const double loss = rail ? rail_loss : wall_loss;
      // The wall moves with the world: its mirror of the sensor velocity is the ghost's.
      const Eigen::Vector2d dir = e.normalized();
      auto mirror_vel = [&](const Eigen::Vector2d& v) {
        return Eigen::Vector2d(2.0 * dir * v.dot(dir) - v);
      };
      for (const GhostTarget& gt : ghost_targets) {
        const auto sp = specular_point(ps, gt.pos_w, l.p0_m, l.p1_m);
        if (!sp) continue;
        const Eigen::Vector2d qs = to_sensor(*sp);
        const double rs = qs.norm();
        if (rs < rc.min_range_m || occlusion_loss(rs, std::atan2(qs.y(), qs.x())) <= 0) continue;
        const Eigen::Vector2d img = mirror_point(gt.pos_w, l.p0_m, l.p1_m);
        const Eigen::Vector2d qi = to_sensor(img), qd = to_sensor(gt.pos_w);
        const double ri = qi.norm(), rd = qd.norm();
        const double azi = std::atan2(qi.y(), qi.x()), azd = std::atan2(qd.y(), qd.x());
        const Eigen::Vector2d ui = (img - ps) / ri, ud = (gt.pos_w - ps) / rd;
        const double vr_img = (mirror_vel(gt.vel_w) - v_world).dot(ui);
        const double vr_dir = (gt.vel_w - v_world).dot(ud);
        auto add = [&](double r, double az, double vr, double power_gain, std::uint64_t tag) {
          if (r > rmax || std::abs(az) > fov) return;
          const double amp = noise * std::sqrt(synth_.snr_linear(gt.rcs_dbsm, r) * power_gain);
          const double ph = -k4pi * r + gt.phase_rad + 2.0 * kPi * hash_uniform(tag);
          const cdouble z = amp * cdouble(std::cos(ph), std::sin(ph));
          Echo ge;
          ge.range_m = r;
          ge.azimuth_rad = az;
          ge.radial_velocity_mps = vr;
          for (int ch = 0; ch < 4; ++ch) ge.amplitude[ch] = z * gt.omega[ch];
          synth_.add_echo(ge);
        };
        const std::uint64_t key = seed_of(cfg_.seed, 0x6768ULL, li, gt.key);
        // Mirror ghost: out and back via the wall (two bounces), a virtual target at img.
        if (mp.mirror_ghosts) add(ri, azi, vr_img, loss * loss, key);
        // Mixed paths (one bounce each way round): range and Doppler the mean of both paths,
        // arriving from the mirror direction or directly; the direct leg must be visible.
        if (mp.mixed_paths && occlusion_loss(rd, azd) > 0) {
          const double rm = 0.5 * (ri + rd), vm = 0.5 * (vr_img + vr_dir);
          add(rm, azi, vm, loss, key + 1);
          add(rm, azd, vm, loss, key + 2);
        }
      }
    }
  }

  // 6. Overhead structures (realism.hpp): slant range, Doppler of the 3-D direction (cos of
  //    the elevation angle), two-way elevation pattern of the sensor.
  if (!overhead_.empty()) {
    const double th = rc.elevation_beamwidth_deg * kDeg;
    constexpr double kStepM = 0.25;
    const double sigma = std::pow(10.0, el.overhead_rcs_per_m_dbsm / 10.0) * kStepM;
    for (std::size_t oi = 0; oi < overhead_.size(); ++oi) {
      const OverheadStructure& o = overhead_[oi];
      const Eigen::Vector2d a = to_sensor(o.p0_m), b = to_sensor(o.p1_m);
      if (std::min(a.norm(), b.norm()) > rmax + 20.0 || (a.x() < 0 && b.x() < 0)) continue;
      const double dh = o.height_m - rc.sensor_height_m;
      const int n = std::max(1, static_cast<int>(std::ceil((b - a).norm() / kStepM)));
      for (int k = 0; k < n; ++k) {
        const Eigen::Vector2d q = a + ((k + 0.5) / n) * (b - a);
        const double rg = q.norm();
        if (q.x() <= 0) continue;
        const double az = std::atan2(q.y(), q.x());
        if (std::abs(az) > fov) continue;
        const double r = std::hypot(rg, dh);
        if (r > rmax || r < rc.min_range_m) continue;
        const double psi = std::atan2(dh, rg);
        const double gel = std::exp(-8.0 * std::log(2.0) * (psi / th) * (psi / th));
        const double amp = noise * std::sqrt(synth_.snr_linear_sigma(sigma, r) * gel);
        const double ph =
            -k4pi * r + 2.0 * kPi * hash_uniform(seed_of(cfg_.seed, 0x6f76ULL, oi, k));
        const cdouble z = amp * cdouble(std::cos(ph), std::sin(ph));
        Echo oe;
        oe.range_m = r;
        oe.azimuth_rad = az;
        oe.radial_velocity_mps = synth_.static_velocity(az) * std::cos(psi);
        for (int ch = 0; ch < 4; ++ch) oe.amplitude[ch] = z * odd_ref()[ch];
        synth_.add_echo(oe);
      }
    }
  }

  if (with_cube) synth_.add_explicit_ground(rng, rc.cube_max_range_m + 3 * dr);

  SensorFrame frame;
  frame.cycle_index = cycle;
  frame.sensor_id = mount.sensor_id;
  frame.time_s = st.time_s;
  synth_.finish(rng, frame);
  return frame;
}

// ---------------------------------------------------------------------------

DriveSimulator::DriveSimulator(std::shared_ptr<const World> world, const SimConfig& cfg,
                               int drive_index)
    : world_(std::move(world)),
      cfg_(cfg),
      drive_(drive_index),
      plan_(*world_, cfg, drive_index),
      gnss_(cfg.gnss, plan_.duration_s(),
            seed_of(cfg.seed, 0x676e7373ULL, static_cast<std::uint64_t>(drive_index)),
            cfg.realism.ins, cfg.realism.slip),
      renderer_(world_, cfg),
      true_mounts_(sim::true_mounts(cfg.sensors, cfg.realism.mounts, cfg.seed, drive_index)),
      time_offsets_s_(
          sensor_time_offsets_s(cfg.sensors.size(), cfg.realism.timing, cfg.seed, drive_index)) {
  if (cfg.sensors.empty()) throw ValidationError("simulation needs at least one sensor mount");
  if (!(cfg.gnss.rate_hz >= 1.0)) throw ValidationError("GNSS rate must be >= 1 Hz");
  if (cfg.gnss.grade == GnssGrade::Consumer) {
    // One field per world and seed, so every drive meets the same multipath in a canyon.
    gnss_.set_multipath(
        std::make_shared<CanyonMultipathField>(*world_, cfg.gnss.consumer, cfg.seed));
  }
  header_.drive_id = "drive_" + std::to_string(drive_index);
  header_.vehicle_id = "sim";
  header_.world = world_->name;
  header_.origin = world_->origin();
  header_.sensors = cfg.sensors;  // the stored (nominal) calibration, not true_mounts_
  header_.start_time_s = 0.0;
  header_.has_cube = cfg.cube;
  header_.producer = "polmap simulate 0.1.0 seed=" + std::to_string(cfg.seed) +
                     " drive=" + std::to_string(drive_index);
  // The simulated car's side-slip gradient, a vehicle parameter its recording declares (the
  // nominal value, like the nominal mounts); absent without slip, so ideal recordings stay
  // byte for byte as before.
  if (cfg.realism.slip.enabled) {
    header_.side_slip_gradient_rad_per_mps2 =
        cfg.realism.slip.side_slip_gradient_deg_per_mps2 * std::numbers::pi / 180.0;
  }
  sensor_order_.resize(cfg.sensors.size());
  std::iota(sensor_order_.begin(), sensor_order_.end(), 0);
  std::stable_sort(sensor_order_.begin(), sensor_order_.end(), [&](std::size_t a, std::size_t b) {
    return cfg.sensors[a].trigger_offset_s < cfg.sensors[b].trigger_offset_s;
  });
  frame_period_s_ = 1.0 / cfg.sensors.front().spec.frame_rate_hz;
}

std::optional<RecordingRecord> DriveSimulator::next() {
  const double dur = plan_.duration_s();
  const double t_traj = static_cast<double>(next_traj_) / cfg_.gnss.rate_hz;
  const SensorMount& mount = cfg_.sensors[sensor_order_[next_sensor_]];
  const double t_frame = next_cycle_ * frame_period_s_ + mount.trigger_offset_s;
  const bool traj_ok = t_traj <= dur + 1e-9;
  const bool frame_ok = t_frame <= dur + 1e-9;
  if (!traj_ok && !frame_ok) return std::nullopt;
  if (traj_ok && (!frame_ok || t_traj <= t_frame)) {
    ++next_traj_;
    last_time_ = t_traj;
    return RecordingRecord{trajectory_sample(gnss_, t_traj)};
  }
  const std::size_t sensor_index = sensor_order_[next_sensor_];
  const std::uint32_t cycle = next_cycle_;
  if (++next_sensor_ >= sensor_order_.size()) {
    next_sensor_ = 0;
    ++next_cycle_;
  }
  last_time_ = t_frame;
  const bool cube = cfg_.cube && t_frame < cfg_.cube_seconds;
  const std::uint64_t seed = seed_of(cfg_.seed, 0x6672616d65ULL, static_cast<std::uint64_t>(drive_),
                                     cycle, mount.sensor_id);
  if (!cfg_.realism.mounts.enabled && !cfg_.realism.timing.enabled) {
    return RecordingRecord{
        renderer_.render(mount, plan_.state(t_frame), &plan_, cycle, cube, seed)};
  }
  // Realism: the sensor measures at its true mount and at stamp + offset + jitter; the frame
  // keeps the nominal stamp and the header the nominal mount.
  const double t_true =
      t_frame + time_offsets_s_[sensor_index] +
      trigger_jitter_s(cfg_.realism.timing, cfg_.seed, drive_, cycle, mount.sensor_id);
  SensorFrame f =
      renderer_.render(true_mounts_[sensor_index], plan_.state(t_true), &plan_, cycle, cube, seed);
  f.time_s = t_frame;
  return RecordingRecord{std::move(f)};
}

TrajectorySample DriveSimulator::trajectory_sample(GnssErrorModel& gnss, double t_s) const {
  if (gnss.latency_s() != 0.0) {  // INS stamps late or early (realism.hpp)
    ExactState st = plan_.state(t_s - gnss.latency_s());
    st.time_s = t_s;
    return gnss.sample(st, world_->frame);
  }
  return gnss.sample(plan_.state(t_s), world_->frame);
}

std::vector<TrajectorySample> DriveSimulator::recorded_trajectory() const {
  POLMAP_EXPECT(next_traj_ == 0);  // gnss_ still holds the state before the first record
  GnssErrorModel gnss = gnss_;
  std::vector<TrajectorySample> out;
  const double dur = plan_.duration_s();
  for (std::uint64_t k = 0;; ++k) {
    const double t = static_cast<double>(k) / cfg_.gnss.rate_hz;
    if (t > dur + 1e-9) break;
    out.push_back(trajectory_sample(gnss, t));
  }
  return out;
}

std::vector<ExactState> DriveSimulator::exact_trajectory() const {
  std::vector<ExactState> out;
  const double dur = plan_.duration_s();
  for (std::uint64_t k = 0;; ++k) {
    const double t = static_cast<double>(k) / cfg_.gnss.rate_hz;
    if (t > dur + 1e-9) break;
    out.push_back(plan_.state(t));
  }
  return out;
}

}  // namespace polmap::sim
