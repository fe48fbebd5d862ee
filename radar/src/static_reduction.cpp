#include "polmap/radar/static_reduction.hpp"

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

#include "polmap/schema/errors.hpp"

namespace polmap::radar {

double static_radial_velocity(const SensorMount& mount, double v_mps, double yaw_rate_rps,
                              double azimuth_rad) {
  const Pose2& m = mount.T_vehicle_sensor;
  // Sensor velocity in the vehicle frame, then in the sensor frame.
  const double vx = v_mps - yaw_rate_rps * m.y_m, vy = yaw_rate_rps * m.x_m;
  const double c = std::cos(m.yaw_rad), s = std::sin(m.yaw_rad);
  const double sx = c * vx + s * vy, sy = -s * vx + c * vy;
  return -(sx * std::cos(azimuth_rad) + sy * std::sin(azimuth_rad));
}

PolSpectrum static_reduce(const DataCube& cube, const SensorMount& mount, double v_mps,
                          double yaw_rate_rps, const StaticReductionConfig& cfg) {
  const int R = cube.num_range_bins, C = cube.num_chirps, V = cube.num_virtual_channels;
  if (R == 0 || C == 0 || V == 0) throw ValidationError("DataCube: a dimension is zero");
  const std::size_t expect = static_cast<std::size_t>(4) * V * C * R;
  if (cube.data.size() != expect) {
    throw ValidationError("DataCube: data has " + std::to_string(cube.data.size()) +
                          " samples, dimensions give " + std::to_string(expect));
  }
  if (!(cube.chirp_interval_s > 0.0))
    throw ValidationError("DataCube: chirp_interval_s must be > 0");

  std::vector<float> beams = cfg.azimuth_bins_rad;
  if (beams.empty()) {
    const double half = mount.spec.fov_half_rad;
    const int n = static_cast<int>(std::floor(2.0 * half / cfg.beam_spacing_rad + 1e-9)) + 1;
    const double start = -0.5 * (n - 1) * cfg.beam_spacing_rad;
    for (int b = 0; b < n; ++b)
      beams.push_back(static_cast<float>(start + b * cfg.beam_spacing_rad));
  }
  const int B = static_cast<int>(beams.size());
  const double lambda = mount.spec.wavelength_m();
  const double d = cube.element_spacing_wavelengths;

  // Tapers (array: raised cosine on a pedestal; slow time: Hann), normalised so a
  // matched static echo returns its amplitude.
  std::vector<double> wv(V), wc(C);
  double swv = 0.0, swc = 0.0;
  for (int v = 0; v < V; ++v) {
    const double x = V > 1 ? double(v) / (V - 1) - 0.5 : 0.0;
    const double c = std::cos(std::numbers::pi * x);
    wv[v] = cfg.taper_pedestal + (1.0 - cfg.taper_pedestal) * c * c;
    swv += wv[v];
  }
  for (int c = 0; c < C; ++c) {
    const double s = std::sin(std::numbers::pi * (c + 0.5) / C);
    wc[c] = s * s;
    swc += wc[c];
  }
  // Weights W(b, v·C + c) of the combined beamforming + Doppler demodulation.
  using CMat = Eigen::Matrix<std::complex<float>, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  CMat W(B, static_cast<Eigen::Index>(V) * C);
  for (int b = 0; b < B; ++b) {
    const double sphi = std::sin(beams[b]);
    const double vr = static_radial_velocity(mount, v_mps, yaw_rate_rps, beams[b]);
    const double f_tc = 2.0 * vr / lambda * cube.chirp_interval_s;  // cycles per chirp
    for (int v = 0; v < V; ++v) {
      const double pa = -2.0 * std::numbers::pi * d * (v - 0.5 * (V - 1)) * sphi;
      for (int c = 0; c < C; ++c) {
        const double pd = 2.0 * std::numbers::pi * f_tc * (c - 0.5 * (C - 1));
        const double w = wv[v] * wc[c] / (swv * swc);
        W(b, static_cast<Eigen::Index>(v) * C + c) = std::complex<float>(
            static_cast<float>(w * std::cos(pa + pd)), static_cast<float>(w * std::sin(pa + pd)));
      }
    }
  }
  // One GEMM per polarization: (B × V·C) · (V·C × R).
  std::vector<CMat> img(4);
  for (int p = 0; p < 4; ++p) {
    const Eigen::Map<const CMat> X(cube.data.data() + static_cast<std::size_t>(p) * V * C * R,
                                   static_cast<Eigen::Index>(V) * C, R);
    img[p] = W * X;
  }

  PolSpectrum out;
  out.range_bin_m = cube.range_bin_m;
  out.num_range_bins = static_cast<std::uint16_t>(R);
  out.azimuth_bins_rad = beams;
  double sigma = cfg.noise_sigma;
  if (!(sigma > 0.0)) {
    std::vector<float> pw;
    pw.reserve(static_cast<std::size_t>(4) * B * R);
    for (int p = 0; p < 4; ++p) {
      for (Eigen::Index i = 0; i < img[p].size(); ++i) pw.push_back(std::norm(img[p].data()[i]));
    }
    std::nth_element(pw.begin(), pw.begin() + pw.size() / 2, pw.end());
    sigma = std::sqrt(pw[pw.size() / 2] / std::log(2.0));
  }
  out.noise_sigma = static_cast<float>(sigma);
  const double floor2 = cfg.floor_sigmas * cfg.floor_sigmas * sigma * sigma;
  for (int b = 0; b < B; ++b) {
    for (int r = 0; r < R; ++r) {
      SpectrumCell cell;
      cell.azimuth_bin = static_cast<std::uint16_t>(b);
      cell.range_bin = static_cast<std::uint16_t>(r);
      double peak = 0.0;
      for (int p = 0; p < 4; ++p) {
        cell.s[p] = img[p](b, r);
        peak = std::max(peak, double(std::norm(cell.s[p])));
      }
      if (cfg.floor_sigmas > 0.0 && !(peak > floor2)) continue;
      out.cells.push_back(cell);
    }
  }
  return out;
}

}  // namespace polmap::radar
