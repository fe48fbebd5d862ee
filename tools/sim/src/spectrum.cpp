#include "polmap/sim/spectrum.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <unordered_map>

#include "polmap/schema/errors.hpp"
#include "polmap/sim/scattering.hpp"

namespace polmap::sim {

namespace {
constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180.0;

inline double sinc_pi(double x) {
  if (std::abs(x) < 1e-9) return 1.0;
  return std::sin(kPi * x) / (kPi * x);
}
}  // namespace

SpectrumSynthesizer::SpectrumSynthesizer(const RadarSimConfig& cfg, const RadarSpec& spec)
    : cfg_(cfg), spec_(spec) {
  POLMAP_EXPECT(cfg.range_bin_m > 0 && cfg.max_range_m > cfg.range_bin_m);
  POLMAP_EXPECT(cfg.beam_spacing_deg > 0 && cfg.fov_half_deg > 0 && cfg.array_elements >= 2);
  dr_ = cfg.range_bin_m;
  num_range_ = static_cast<int>(std::floor(cfg.max_range_m / dr_ + 1e-9)) + 1;
  POLMAP_EXPECT(num_range_ <= 65535);
  num_beams_ = static_cast<int>(std::lround(2.0 * cfg.fov_half_deg / cfg.beam_spacing_deg)) + 1;
  for (int b = 0; b < num_beams_; ++b) {
    const double az = (-cfg.fov_half_deg + b * cfg.beam_spacing_deg) * kDeg;
    beam_az_.push_back(az);
    beam_sin_.push_back(std::sin(az));
    beam_az_f_.push_back(static_cast<float>(az));
  }
  v_ua_ = spec.v_unambiguous_mps;
  lambda_ = spec.wavelength_m();
  k_radar_ = std::pow(10.0, cfg.snr_ref_db / 10.0) * std::pow(cfg.r_ref_m, 4);

  // Array taper and factor table (real: symmetric taper, phase centre in the middle).
  const int n = cfg.array_elements;
  double sw = 0, sw2 = 0;
  for (int i = 0; i < n; ++i) {
    const double x = (i - 0.5 * (n - 1)) / (n - 1);
    const double c = std::cos(kPi * x);
    const double w = cfg.taper_pedestal + (1.0 - cfg.taper_pedestal) * c * c;
    taper_.push_back(w);
    sw += w;
    sw2 += w * w;
  }
  const auto na = static_cast<int>(std::lround(af_max_ / af_step_));
  af_table_.resize(2 * na + 1);
  for (int k = -na; k <= na; ++k) {
    const double du = k * af_step_;
    double s = 0;
    for (int i = 0; i < n; ++i) {
      s += taper_[i] *
           std::cos(2.0 * kPi * cfg.element_spacing_wavelengths * (i - 0.5 * (n - 1)) * du);
    }
    af_table_[k + na] = s / sw;
  }
  // Doppler window (Hann, sin^2((c+1/2) pi / C)) and its response table.
  const int nc = cfg.num_chirps;
  double dw = 0;
  for (int c = 0; c < nc; ++c) {
    const double s = std::sin(kPi * (c + 0.5) / nc);
    doppler_window_.push_back(s * s);
    dw += s * s;
  }
  const double dop_bin = 2.0 * v_ua_ / nc;
  dop_max_ = 2.0 * dop_bin;
  const auto nd = static_cast<int>(std::ceil(dop_max_ / dop_step_));
  dop_table_.resize(2 * nd + 1);
  for (int k = -nd; k <= nd; ++k) {
    const double dv = k * dop_step_;
    double s = 0;
    for (int c = 0; c < nc; ++c) {
      s += doppler_window_[c] * std::cos(kPi * dv * (c - 0.5 * (nc - 1)) / v_ua_);
    }
    dop_table_[k + nd] = std::abs(dv) >= dop_max_ ? 0.0 : s / dw;
  }

  // Ground clutter per range ring: sigma0 * area, area = r * (az. PSF energy) * (range PSF
  // energy 1.5 dr), seen through a Gaussian two-way elevation pattern from height h.
  clutter_.assign(num_range_, 0.0);
  clutter_frac_ = DistributedModel::surface().channel_power();
  if (cfg.ground_clutter) {
    const double az_energy = sw2 / (sw * sw) / cfg.element_spacing_wavelengths;
    const double sigma0 = std::pow(10.0, cfg.ground_sigma0_db / 10.0);
    const double th = cfg.elevation_beamwidth_deg * kDeg;
    for (int i = 1; i < num_range_; ++i) {
      const double r = i * dr_;
      if (r < cfg.min_range_m) continue;
      const double psi = std::atan2(cfg.sensor_height_m, r);
      const double el = std::exp(-8.0 * std::log(2.0) * (psi / th) * (psi / th));
      const double area = r * az_energy * 1.5 * dr_;
      clutter_[i] = snr_linear_sigma(sigma0 * area, r) * el;
    }
  }
  const double s2 = cfg.noise_sigma * cfg.noise_sigma;
  const double k2 = cfg.floor_sigmas * cfg.floor_sigmas;
  const double fmax = *std::max_element(clutter_frac_.begin(), clutter_frac_.end());
  floor_.resize(num_range_);
  exceed_cdf_.resize(num_range_);
  double acc = 0;
  for (int i = 0; i < num_range_; ++i) {
    floor_[i] = k2 * (s2 + (cfg.floor_includes_clutter ? clutter_[i] * fmax : 0.0));
    double p = 0;
    for (int c = 0; c < 4; ++c) p += std::exp(-floor_[i] / (s2 + clutter_[i] * clutter_frac_[c]));
    acc += std::min(1.0, p) * num_beams_;
    exceed_cdf_[i] = acc;
  }
  exceed_total_ = acc;
  // Detection reference level per ring (CFAR-like: thermal noise, optionally + ring clutter)
  // and the rate of ground-clutter peaks over the threshold. Ground cell power (noise
  // included) is exponential with mean mu = (sigma^2 + g)/ref; a cell is a detection if it
  // exceeds T and is the maximum of its N-cell suppression neighbourhood. For N i.i.d.
  // exponentials P(centre is the max and max > T) = (1 - (1 - e^{-T/mu})^N) / N.
  ref_.resize(num_range_);
  ground_det_cdf_.assign(num_range_, 0.0);
  const double thr_g = std::pow(10.0, cfg.ground_detection_threshold_db / 10.0);
  const int nnb = (2 * std::max(0, cfg.detection_suppress_range_bins) + 1) *
                  (2 * std::max(0, cfg.detection_suppress_beams) + 1);
  double gacc = 0;
  for (int i = 0; i < num_range_; ++i) {
    ref_[i] = s2 + (cfg.detection_reference_includes_clutter ? clutter_[i] : 0.0);
    if (cfg.ground_clutter && cfg.ground_detections && clutter_[i] > 0) {
      const double mu = (s2 + clutter_[i]) / ref_[i];
      const double p = std::exp(-thr_g / mu);
      gacc += (1.0 - std::pow(1.0 - p, nnb)) / nnb * num_beams_;
    }
    ground_det_cdf_[i] = gacc;
  }
  ground_det_total_ = gacc;
  thr_ground_ = thr_g;
  image_.assign(static_cast<std::size_t>(num_range_) * num_beams_, {});
  touched_flag_.assign(image_.size(), 0);
  static_vr_beam_.assign(num_beams_, 0.0);
}

int SpectrumSynthesizer::nearest_beam(double az) const {
  const int b =
      static_cast<int>(std::lround((az / kDeg + cfg_.fov_half_deg) / cfg_.beam_spacing_deg));
  return std::clamp(b, 0, num_beams_ - 1);
}

double SpectrumSynthesizer::range_response(double x) {
  const double d = 1.0 - x * x;
  if (std::abs(d) < 1e-9) return 0.5;
  return sinc_pi(x) / d;
}

double SpectrumSynthesizer::beam_response(double du) const {
  const double f = (du + af_max_) / af_step_;
  if (f < 0 || f >= static_cast<double>(af_table_.size() - 1)) return 0.0;
  const auto i = static_cast<std::size_t>(f);
  const double t = f - static_cast<double>(i);
  return af_table_[i] + t * (af_table_[i + 1] - af_table_[i]);
}

double SpectrumSynthesizer::alias(double v) const {
  const double p = 2.0 * v_ua_;
  double w = std::fmod(v + v_ua_, p);
  if (w < 0) w += p;
  return w - v_ua_;
}

double SpectrumSynthesizer::doppler_response(double dv) const {
  dv = alias(dv);
  if (std::abs(dv) >= dop_max_) return 0.0;
  const double f = (dv + dop_max_) / dop_step_;
  const auto i = static_cast<std::size_t>(f);
  if (i + 1 >= dop_table_.size()) return 0.0;
  const double t = f - static_cast<double>(i);
  return dop_table_[i] + t * (dop_table_[i + 1] - dop_table_[i]);
}

double SpectrumSynthesizer::snr_linear(double rcs_dbsm, double range_m) const {
  return snr_linear_sigma(std::pow(10.0, rcs_dbsm / 10.0), range_m);
}

void SpectrumSynthesizer::begin(const Eigen::Vector2d& vs, bool with_cube, std::uint64_t key) {
  vs_ = vs;
  scene_key_ = key;
  for (int b = 0; b < num_beams_; ++b) static_vr_beam_[b] = static_velocity(beam_az_[b]);
  with_cube_ = with_cube;
  cands_.clear();
  cube_echoes_.clear();
  explicit_ground_bins_ = 0;
}

double SpectrumSynthesizer::static_velocity(double az) const {
  return -(vs_.x() * std::cos(az) + vs_.y() * std::sin(az));
}

void SpectrumSynthesizer::touch(int idx) {
  if (!touched_flag_[idx]) {
    touched_flag_[idx] = 1;
    touched_.push_back(idx);
  }
}

void SpectrumSynthesizer::add_psf(const ScatteringVector& a, double x, double sin_phi, double v_r,
                                  int rh, int bh) {
  double amax2 = 0;
  for (const auto& c : a) amax2 = std::max(amax2, std::norm(c));
  const double amax = std::sqrt(amax2);
  const double skip = cfg_.psf_skip_below_sigma * cfg_.noise_sigma;
  if (amax * 1.0 < skip) return;
  const int i0 = static_cast<int>(std::lround(x));
  const double phi = std::asin(std::clamp(sin_phi, -1.0, 1.0));
  const int b0 = nearest_beam(phi);
  const std::array<cfloat, 4> af{cfloat(a[0]), cfloat(a[1]), cfloat(a[2]), cfloat(a[3])};
  double wr[32];
  const int rlo = std::max(0, i0 - rh), rhi = std::min(num_range_ - 1, i0 + rh);
  for (int i = rlo; i <= rhi; ++i) wr[i - rlo] = range_response(i - x);
  for (int b = std::max(0, b0 - bh); b <= std::min(num_beams_ - 1, b0 + bh); ++b) {
    const double gb =
        beam_response(beam_sin_[b] - sin_phi) * doppler_response(v_r - static_vr_beam_[b]);
    if (std::abs(gb) * amax < skip) continue;
    for (int i = rlo; i <= rhi; ++i) {
      const double g = gb * wr[i - rlo];
      if (std::abs(g) * amax < skip) continue;
      const int idx = b * num_range_ + i;
      touch(idx);
      auto& cell = image_[idx];
      const auto gf = static_cast<float>(g);
      for (int c = 0; c < 4; ++c) cell[c] += af[c] * gf;
    }
  }
}

void SpectrumSynthesizer::add_echo(const Echo& e) {
  if (e.range_m < cfg_.min_range_m || e.range_m > cfg_.max_range_m + 3 * dr_) return;
  const double x = e.range_m / dr_;
  const int ri = std::clamp(static_cast<int>(std::lround(x)), 0, num_range_ - 1);
  cands_.push_back(
      {e.range_m, e.azimuth_rad, e.radial_velocity_mps, half_span(e.amplitude) / ref_[ri], false});
  const double sp = std::sin(e.azimuth_rad);
  add_psf(e.amplitude, x, sp, e.radial_velocity_mps, cfg_.point_psf_range_half_taps,
          cfg_.point_psf_beam_half_taps);
  if (with_cube_) {
    cube_echoes_.push_back(
        {e.amplitude, x, sp, e.radial_velocity_mps, cfg_.point_psf_range_half_taps});
  }
}

void SpectrumSynthesizer::add_cell(int i, int b, const ScatteringVector& a) {
  if (i < 0 || i >= num_range_ || b < 0 || b >= num_beams_) return;
  cands_.push_back({i * dr_, beam_az_[b], static_vr_beam_[b], half_span(a) / ref_[i], true});
  add_psf(a, i, beam_sin_[b], static_vr_beam_[b], cfg_.cell_psf_range_half_taps,
          cfg_.cell_psf_beam_half_taps);
  if (with_cube_) {
    cube_echoes_.push_back({a, static_cast<double>(i), beam_sin_[b], static_vr_beam_[b],
                            cfg_.cell_psf_range_half_taps});
  }
}

void SpectrumSynthesizer::add_explicit_ground(Rng& rng, double max_range_m) {
  if (!cfg_.ground_clutter) return;
  const int n = std::min(num_range_, static_cast<int>(std::lround(max_range_m / dr_)) + 1);
  // Energy of the truncated cell PSF at boresight: keeps E|cell|^2 = g per cell.
  double er = 0, eb = 0;
  for (int k = -cfg_.cell_psf_range_half_taps; k <= cfg_.cell_psf_range_half_taps; ++k) {
    er += range_response(k) * range_response(k);
  }
  for (int k = -cfg_.cell_psf_beam_half_taps; k <= cfg_.cell_psf_beam_half_taps; ++k) {
    const double a = beam_response(std::sin(k * cfg_.beam_spacing_deg * kDeg));
    eb += a * a;
  }
  const double norm = 1.0 / std::sqrt(er * eb);
  const DistributedModel model = DistributedModel::surface();
  for (int i = 1; i < n; ++i) {
    if (clutter_[i] <= 0) continue;
    const double amp = std::sqrt(clutter_[i]) * norm;
    for (int b = 0; b < num_beams_; ++b) {
      ScatteringVector s = model.sample(rng);
      for (auto& c : s) c *= amp;
      add_psf(s, i, beam_sin_[b], static_vr_beam_[b], cfg_.cell_psf_range_half_taps,
              cfg_.cell_psf_beam_half_taps);
      if (with_cube_) {
        cube_echoes_.push_back({s, static_cast<double>(i), beam_sin_[b], static_vr_beam_[b],
                                cfg_.cell_psf_range_half_taps});
      }
    }
  }
  explicit_ground_bins_ = n;
}

void SpectrumSynthesizer::finish(Rng& rng, SensorFrame& out) {
  const double s2 = cfg_.noise_sigma * cfg_.noise_sigma;
  const DistributedModel ground = DistributedModel::surface();
  std::vector<int> stored;
  stored.reserve(touched_.size() / 2 + 64);
  // 1. Cells with echoes: + noise (+ ring clutter) then the floor.
  for (int idx : touched_) {
    const int i = idx % num_range_;
    auto& cell = image_[idx];
    if (cfg_.ground_clutter && i >= explicit_ground_bins_ && clutter_[i] > 0) {
      HashRng cell_rng(seed_of(scene_key_, 0x67726f756e64ULL, static_cast<std::uint64_t>(idx)));
      const ScatteringVector g = ground.sample(cell_rng);
      const double a = std::sqrt(clutter_[i]);
      for (int c = 0; c < 4; ++c) cell[c] += cfloat(g[c] * a);
    }
    double m = 0;
    for (int c = 0; c < 4; ++c) {
      if (cfg_.thermal_noise) cell[c] += cfloat(rng.cnormal(s2));
      m = std::max(m, static_cast<double>(std::norm(cell[c])));
    }
    if (m > floor_[i]) stored.push_back(idx);
  }
  // 2. Cells without echoes: only noise + clutter; draw their floor exceedances directly
  //    (Poisson count, ring by its rate, value conditioned on exceeding: memoryless tail).
  std::vector<int> extra_touched;
  const int k = cfg_.thermal_noise ? rng.poisson(exceed_total_) : 0;
  for (int n = 0; n < k; ++n) {
    const double u = rng.uniform() * exceed_total_;
    const int i = static_cast<int>(std::lower_bound(exceed_cdf_.begin(), exceed_cdf_.end(), u) -
                                   exceed_cdf_.begin());
    if (i >= num_range_ || i < explicit_ground_bins_) continue;
    const int b = static_cast<int>(rng.index(num_beams_));
    const int idx = b * num_range_ + i;
    if (touched_flag_[idx]) continue;
    touched_flag_[idx] = 1;
    extra_touched.push_back(idx);
    const double g = clutter_[i];
    std::array<double, 4> v{}, p{};
    double ps = 0;
    for (int c = 0; c < 4; ++c) {
      v[c] = s2 + g * clutter_frac_[c];
      p[c] = std::exp(-floor_[i] / v[c]);
      ps += p[c];
    }
    double pick = rng.uniform() * ps;
    int ch = 0;
    while (ch < 3 && pick >= p[ch]) pick -= p[ch++];
    std::array<cdouble, 4> s{};
    const cdouble sc = std::sqrt(floor_[i] + v[ch] * rng.exponential()) * rng.phasor();
    const double gx = g * clutter_frac_[1];
    if (ch == 1 || ch == 2) {
      // LR and RL share the clutter term x: partner | s ~ CN(s gx/v, gx s2/v + s2).
      s[ch] = sc;
      s[3 - ch] = sc * (gx / v[ch]) + rng.cnormal(gx * s2 / v[ch] + s2);
      s[0] = rng.cnormal(v[0]);
      s[3] = rng.cnormal(v[3]);
    } else {
      s[ch] = sc;
      s[3 - ch] = rng.cnormal(v[3 - ch]);
      const cdouble x = rng.cnormal(gx);
      s[1] = x + rng.cnormal(s2);
      s[2] = x + rng.cnormal(s2);
    }
    auto& cell = image_[idx];
    for (int c = 0; c < 4; ++c) cell[c] = cfloat(s[c]);
    stored.push_back(idx);
  }
  std::sort(stored.begin(), stored.end());
  PolSpectrum& sp = out.spectrum;
  sp.range_bin_m = dr_;
  sp.num_range_bins = static_cast<std::uint16_t>(num_range_);
  sp.azimuth_bins_rad = beam_az_f_;
  sp.noise_sigma = static_cast<float>(cfg_.noise_sigma);
  sp.cells.clear();
  sp.cells.reserve(stored.size());
  for (int idx : stored) {
    SpectrumCell c;
    c.range_bin = static_cast<std::uint16_t>(idx % num_range_);
    c.azimuth_bin = static_cast<std::uint16_t>(idx / num_range_);
    c.s = image_[idx];
    sp.cells.push_back(c);
  }
  make_detections(rng, out);
  if (with_cube_) make_cube(rng, out);
  for (int idx : touched_) {
    image_[idx] = {};
    touched_flag_[idx] = 0;
  }
  for (int idx : extra_touched) {
    image_[idx] = {};
    touched_flag_[idx] = 0;
  }
  touched_.clear();
}

void SpectrumSynthesizer::make_detections(Rng& rng, SensorFrame& out) {
  const double thr = std::pow(10.0, cfg_.detection_threshold_db / 10.0);
  const double dv_sep = cfg_.detection_suppress_doppler_bins * (2.0 * v_ua_ / cfg_.num_chirps);
  const int sr = std::max(0, cfg_.detection_suppress_range_bins);
  const int sb = std::max(0, cfg_.detection_suppress_beams);
  const double s2 = cfg_.noise_sigma * cfg_.noise_sigma;
  struct Pick {
    double snr;
    std::size_t cand;
  };
  std::vector<Pick> picks;
  const std::size_t num_echo_cands = cands_.size();
  for (std::size_t k = 0; k < num_echo_cands; ++k) {
    // Measured power: the echo plus the cell's noise and ground clutter (Rician near threshold).
    const int ri =
        std::clamp(static_cast<int>(std::lround(cands_[k].range_m / dr_)), 0, num_range_ - 1);
    const auto z = std::sqrt(cands_[k].snr) + rng.cnormal((s2 + clutter_[ri]) / ref_[ri]);
    const double snr = std::norm(z);
    if (snr >= thr) picks.push_back({snr, k});
  }
  // Ground-clutter peaks over the threshold (cells without echoes, statistically): Poisson
  // count, ring by its rate, beam uniform, power T + mu Exp(1) (memoryless tail), static
  // Doppler of the beam centre. They go through the same peak suppression as the rest.
  // Drawn from the scene-keyed generator: ground speckle is frozen while the sensor stands
  // still, so are its peaks (thermal noise, ~20 dB below them, is neglected here).
  if (ground_det_total_ > 0) {
    HashRng grng(seed_of(scene_key_, 0x6764657473ULL));
    int ng = 0;
    if (ground_det_total_ > 50) {
      ng = std::max(0, static_cast<int>(std::lround(ground_det_total_ +
                                                    std::sqrt(ground_det_total_) * grng.normal())));
    } else {
      for (double p = grng.uniform(), l = std::exp(-ground_det_total_); p > l; p *= grng.uniform())
        ++ng;
    }
    for (int n = 0; n < ng; ++n) {
      const double u = grng.uniform() * ground_det_total_;
      const int i = std::min(
          num_range_ - 1,
          static_cast<int>(std::lower_bound(ground_det_cdf_.begin(), ground_det_cdf_.end(), u) -
                           ground_det_cdf_.begin()));
      const int b = std::min(num_beams_ - 1, static_cast<int>(grng.uniform() * num_beams_));
      const double mu = (s2 + clutter_[i]) / ref_[i];
      const double snr = thr_ground_ - mu * std::log1p(-grng.uniform());
      picks.push_back({snr, cands_.size()});
      cands_.push_back({i * dr_, beam_az_[b], static_vr_beam_[b], snr, true});
    }
  }
  std::sort(picks.begin(), picks.end(), [](const Pick& a, const Pick& b) {
    return a.snr > b.snr || (a.snr == b.snr && a.cand < b.cand);
  });
  // Local maxima in (range, azimuth, Doppler): suppress weaker candidates within sr range
  // bins, sb beams and the Doppler separation of an accepted one.
  struct Acc {
    int rb, bb;
    double v;
  };
  std::vector<Acc> acc;
  std::unordered_map<int, std::vector<int>> grid;
  std::vector<Detection> dets;
  const auto limit = static_cast<std::size_t>(std::max(0, cfg_.max_detections));
  // Gross Doppler errors (realism.hpp) come from their own generator: the ideal stream of
  // `rng` is untouched, so the ideal preset stays bit-identical.
  const bool doppler_outliers = cfg_.doppler_outlier_share > 0;
  Rng outlier_rng(seed_of(scene_key_, 0x6f75746cULL, out.cycle_index, out.sensor_id));
  for (const Pick& p : picks) {
    if (dets.size() >= limit) break;
    const DetectionCandidate& c = cands_[p.cand];
    const int rb = static_cast<int>(std::lround(c.range_m / dr_));
    const int bb = nearest_beam(c.azimuth_rad);
    const double va = alias(c.radial_velocity_mps);
    bool suppressed = false;
    for (int dr = -sr; dr <= sr && !suppressed; ++dr) {
      for (int db = -sb; db <= sb && !suppressed; ++db) {
        auto it = grid.find((bb + db) * 70000 + rb + dr);
        if (it == grid.end()) continue;
        for (int a : it->second) {
          if (std::abs(alias(acc[a].v - va)) < dv_sep) {
            suppressed = true;
            break;
          }
        }
      }
    }
    if (suppressed) continue;
    grid[bb * 70000 + rb].push_back(static_cast<int>(acc.size()));
    acc.push_back({rb, bb, va});
    double r = c.range_m, az = c.azimuth_rad;
    if (c.distributed) {  // true sub-scatterer position unknown within the cell
      r += rng.uniform(-0.5, 0.5) * dr_;
      az += rng.uniform(-0.5, 0.5) * cfg_.beam_spacing_deg * kDeg;
    }
    Detection d;
    d.range_m = static_cast<float>(r + rng.normal(0.0, cfg_.det_sigma_range_m));
    double sigma_az_rad = cfg_.det_sigma_azimuth_deg * kDeg;
    if (cfg_.det_sigma_azimuth_grows_off_boresight) {  // aperture shrinks as cos(phi)
      sigma_az_rad = std::min(cfg_.det_sigma_azimuth_max_deg * kDeg,
                              sigma_az_rad / std::max(1e-3, std::cos(c.azimuth_rad)));
    }
    d.azimuth_rad = static_cast<float>(az + rng.normal(0.0, sigma_az_rad));
    double vr = c.radial_velocity_mps + rng.normal(0.0, cfg_.det_sigma_vr_mps);
    if (doppler_outliers && outlier_rng.uniform() < cfg_.doppler_outlier_share) {
      vr += outlier_rng.normal(0.0, cfg_.doppler_outlier_sigma_mps);
    }
    d.radial_velocity_mps = static_cast<float>(alias(vr));
    d.snr_db = static_cast<float>(10.0 * std::log10(p.snr));
    dets.push_back(d);
  }
  const int nfa = rng.poisson(cfg_.false_alarms_per_frame);
  for (int k = 0; k < nfa; ++k) {
    Detection d;
    d.range_m = static_cast<float>(rng.uniform(cfg_.min_range_m, cfg_.max_range_m));
    d.azimuth_rad = static_cast<float>(rng.uniform(-cfg_.fov_half_deg, cfg_.fov_half_deg) * kDeg);
    d.radial_velocity_mps = static_cast<float>(rng.uniform(-v_ua_, v_ua_));
    d.snr_db = static_cast<float>(cfg_.detection_threshold_db + 2.0 * rng.exponential());
    dets.push_back(d);
  }
  std::stable_sort(dets.begin(), dets.end(),
                   [](const Detection& a, const Detection& b) { return a.snr_db > b.snr_db; });
  if (dets.size() > limit) dets.resize(limit);
  out.detections = std::move(dets);
}

void SpectrumSynthesizer::make_cube(Rng& rng, SensorFrame& out) {
  const int nr =
      std::min(num_range_, static_cast<int>(std::lround(cfg_.cube_max_range_m / dr_)) + 1);
  const int nv = cfg_.array_elements, nc = cfg_.num_chirps;
  const std::size_t block = static_cast<std::size_t>(4) * nv * nc;  // per range bin
  // Accumulate as [r][pol][v][c] (contiguous per range bin), transpose at the end.
  std::vector<float> acc(2 * block * nr, 0.0F);
  std::vector<float> ph_re(static_cast<std::size_t>(nv) * nc), ph_im(ph_re.size());
  const double d = cfg_.element_spacing_wavelengths;
  for (const CubeEcho& e : cube_echoes_) {
    const int i0 = static_cast<int>(std::lround(e.x_bins));
    if (i0 - e.rh >= nr) continue;
    // Outer product of array and Doppler phasors (times relative to the chirp-train centre).
    for (int v = 0; v < nv; ++v) {
      const double pa = 2.0 * kPi * d * (v - 0.5 * (nv - 1)) * e.sin_phi;
      for (int c = 0; c < nc; ++c) {
        const double pd = -kPi * e.v_r * (c - 0.5 * (nc - 1)) / v_ua_;
        ph_re[v * nc + c] = static_cast<float>(std::cos(pa + pd));
        ph_im[v * nc + c] = static_cast<float>(std::sin(pa + pd));
      }
    }
    for (int i = std::max(0, i0 - e.rh); i <= std::min(nr - 1, i0 + e.rh); ++i) {
      const double w = range_response(i - e.x_bins);
      float* base = acc.data() + 2 * block * i;
      for (int p = 0; p < 4; ++p) {
        const auto ar = static_cast<float>(e.a[p].real() * w),
                   ai = static_cast<float>(e.a[p].imag() * w);
        float* dst = base + 2 * static_cast<std::size_t>(p) * nv * nc;
        for (int k = 0; k < nv * nc; ++k) {
          dst[2 * k] += ar * ph_re[k] - ai * ph_im[k];
          dst[2 * k + 1] += ar * ph_im[k] + ai * ph_re[k];
        }
      }
    }
  }
  // Noise per cube sample such that the normalised static reduction has noise_sigma.
  double sw = 0, sw2 = 0, cw = 0, cw2 = 0;
  for (double w : taper_) sw += w, sw2 += w * w;
  for (double w : doppler_window_) cw += w, cw2 += w * w;
  const double gain = (sw2 / (sw * sw)) * (cw2 / (cw * cw));
  const double var = cfg_.noise_sigma * cfg_.noise_sigma / gain;
  DataCube cube;
  cube.num_range_bins = static_cast<std::uint16_t>(nr);
  cube.num_chirps = static_cast<std::uint16_t>(nc);
  cube.num_virtual_channels = static_cast<std::uint16_t>(nv);
  cube.range_bin_m = dr_;
  cube.chirp_interval_s = lambda_ / (4.0 * v_ua_);
  cube.element_spacing_wavelengths = d;
  cube.data.resize(block * nr);
  for (int p = 0; p < 4; ++p) {
    for (int v = 0; v < nv; ++v) {
      for (int c = 0; c < nc; ++c) {
        for (int i = 0; i < nr; ++i) {
          const std::size_t src = 2 * (block * i + (static_cast<std::size_t>(p) * nv + v) * nc + c);
          const auto n = cfg_.thermal_noise ? rng.cnormal(var) : cdouble{};
          cube.data[((static_cast<std::size_t>(p) * nv + v) * nc + c) * nr + i] = cfloat(
              acc[src] + static_cast<float>(n.real()), acc[src + 1] + static_cast<float>(n.imag()));
        }
      }
    }
  }
  out.cube = std::move(cube);
}

}  // namespace polmap::sim
