// bench_package_size: drive package size per km and what the compact format keeps.
//
// Simulates one drive (tools/sim), processes it in mapping mode at each polarimetric level,
// writes it as format 1 (Float32 + GeoPackage), format 2 (compact) and format 2
// landmarks-only, and for the compact gridmap re-runs the vehicle's detectors on the
// decoded gridmap (read_covariance_gridmap): recall of the vehicle's point candidates within
// 1 cm, of its line candidates (a decoded line within 1 cm of both ends, same direction
// within 2°, covering half of it), and the error of cells above 3σ of the noise (every
// diagonal component ≥ 9σ²: power in dB; off-diagonals with coherence ≥ 0.3: phase).
// The vehicle extracts a compact package's candidates from the gridmap as sent
// (process_drive_for_package); "exact" columns: the share of the candidates of the exact
// gridmap that are among them (what the quantization changes in the candidate set).
//
//   bench_package_size [--world urban] [--length-m 1000] [--seed 1] [--pol full,hh-vv,hh]
#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/radar/drive_processor.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/realism.hpp"
#include "polmap/sim/world.hpp"
#include "polmap/util/file.hpp"
#include "polmap/util/text.hpp"

using namespace polmap;
namespace fs = std::filesystem;

namespace {

double point_recall(const std::vector<PointCandidate>& want,
                    const std::vector<PointCandidate>& got) {
  std::size_t hit = 0;
  for (const auto& p : want) {
    for (const auto& g : got) {
      if ((g.position_m - p.position_m).norm() <= 0.01) {
        ++hit;
        break;
      }
    }
  }
  return want.empty() ? 1.0 : double(hit) / want.size();
}

double line_recall(const std::vector<LineCandidate>& want, const std::vector<LineCandidate>& got) {
  std::size_t hit = 0;
  for (const auto& l : want) {
    const Eigen::Vector2d d = (l.end_m - l.start_m).normalized();
    const double len = (l.end_m - l.start_m).norm();
    for (const auto& g : got) {
      const double lg = (g.end_m - g.start_m).norm();
      const Eigen::Vector2d e = (g.end_m - g.start_m) / lg;
      if (std::abs(d.dot(e)) < std::cos(2.0 * M_PI / 180.0)) continue;
      const Eigen::Vector2d n(-e.y(), e.x());
      if (std::max(std::abs(n.dot(l.start_m - g.start_m)), std::abs(n.dot(l.end_m - g.start_m))) >
          0.01) {
        continue;
      }
      const double a0 = e.dot(l.start_m - g.start_m), a1 = e.dot(l.end_m - g.start_m);
      if (std::min(std::max(a0, a1), lg) - std::max(std::min(a0, a1), 0.0) >= 0.5 * len) {
        ++hit;
        break;
      }
    }
  }
  return want.empty() ? 1.0 : double(hit) / want.size();
}

struct CellErrors {
  std::size_t strong = 0;
  double max_db = 0.0;
  double max_phase_deg = 0.0;
};

/// Errors of the decoded cells against the exact map (cells above 3σ of the noise).
CellErrors cell_errors(const radar::CovarianceGridmap& exact, const radar::CovarianceGridmap& dec) {
  CellErrors e;
  const double s2 = exact.noise_power();
  const int q = exact.q();
  for (const auto& [tx, ty] : exact.tile_indices()) {
    for (int r = 0; r < radar::kTileSizeCells; ++r) {
      for (int c = 0; c < radar::kTileSizeCells; ++c) {
        const int ix = tx * radar::kTileSizeCells + c, iy = ty * radar::kTileSizeCells + r;
        if (exact.power(ix, iy) < 9.0 * q * s2) continue;
        const Eigen::MatrixXcd a = exact.covariance(ix, iy), b = dec.covariance(ix, iy);
        ++e.strong;
        for (int i = 0; i < q; ++i) {
          const double ai = a(i, i).real();
          if (ai < 9.0 * s2) continue;
          e.max_db = std::max(e.max_db, std::abs(10.0 * std::log10(b(i, i).real() / ai)));
          for (int j = i + 1; j < q; ++j) {
            const double aj = a(j, j).real();
            if (aj < 9.0 * s2 || std::abs(a(i, j)) < 0.3 * std::sqrt(ai * aj)) continue;
            e.max_phase_deg = std::max(
                e.max_phase_deg, std::abs(std::arg(b(i, j) * std::conj(a(i, j)))) * 180.0 / M_PI);
          }
        }
      }
    }
  }
  return e;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Drive package size per km and fidelity of the compact format"};
  std::string world_name = "urban", pols = "full,hh-vv,hh";
  double length_m = 1000.0;
  std::uint64_t seed = 1;
  app.add_option("--world", world_name)->capture_default_str();
  app.add_option("--length-m", length_m)->capture_default_str();
  app.add_option("--seed", seed)->capture_default_str();
  app.add_option("--pol", pols, "comma-separated levels")->capture_default_str();
  mapping::GridmapCodecConfig codec;
  app.add_option("--floor-db", codec.floor_snr_db, "compact codec: empty below (dB over q sigma^2)")
      ->capture_default_str();
  app.add_option("--offdiag-db", codec.offdiag_min_snr_db, "compact codec: diagonal only below")
      ->capture_default_str();
  app.add_option("--relative-step", codec.relative_step, "compact codec: factor step")
      ->capture_default_str();
  app.add_option("--power-step", codec.power_step, "compact codec: relative step of trace(C)")
      ->capture_default_str();
  app.add_option("--empty-count-bits", codec.empty_count_bits,
                 "compact codec: significant bits of N kept in empty cells")
      ->capture_default_str();
  app.add_option("--zero-step-noise", codec.zero_step_noise,
                 "compact codec: step of the factor entries at zero (noise sigmas)")
      ->capture_default_str();
  std::string realism = "realistic";
  app.add_option("--realism", realism,
                 "simulated drive's error sources: realistic (default) | ideal "
                 "(tools/sim/README.md)")
      ->check(CLI::IsMember({"ideal", "realistic"}));
  CLI11_PARSE(app, argc, argv);

  const util::ScopedTempDir tmp = util::ScopedTempDir::create("bench_package_size");
  std::printf("world %s, %.0f m, seed %llu, realism %s\n", world_name.c_str(), length_m,
              static_cast<unsigned long long>(seed), realism.c_str());
  std::printf("%-6s %8s %11s %11s %13s %9s %9s %9s %9s %8s %9s %10s\n", "level", "km", "v1 MB/km",
              "v2 MB/km", "lm-only kB/km", "pts rec", "line rec", "pts exact", "line exact",
              "strong", "max dB", "max phase");
  for (const std::string_view pol_view : util::split_trimmed(pols, ',')) {
    const std::string pol(pol_view);
    const auto level = parse_pol_level(pol);
    if (!level) {
      std::fprintf(stderr, "unknown level '%s'\n", pol.c_str());
      return 2;
    }
    sim::SimConfig scfg;
    scfg.seed = seed;
    scfg.realism = sim::realism_preset(realism);
    auto world = sim::load_world(world_name, length_m, seed, scfg);
    sim::DriveSimulator source(world, scfg, 0);
    radar::DriveProcessingConfig pcfg;
    pcfg.gridmap.level = *level;
    radar::DriveProcessingResult r = radar::process_drive(source, pcfg);
    const std::vector<PointCandidate> exact_points = r.points;
    const std::vector<LineCandidate> exact_lines = r.lines;
    // The compact package's candidates, as `polmap process` extracts them
    // (process_drive_for_package): from the gridmap as the package sends it.
    mapping::extract_candidates_as_sent(r, pcfg, codec);
    const double km = r.stats.distance_m / 1000.0;
    std::uint64_t bytes[3] = {0, 0, 0};
    for (int v = 0; v < 3; ++v) {
      mapping::PackageWriteOptions o;
      o.format_version = v == 0 ? 1 : 2;
      o.landmarks_only = v == 2;
      o.codec = codec;
      const fs::path dir = tmp.path() / (pol + std::to_string(v));
      (void)mapping::write_drive_package(r, dir, o);
      bytes[v] = static_cast<std::uint64_t>(mapping::pack_drive_package(dir).size());
    }
    const mapping::DrivePackage pkg = mapping::read_and_validate_package(tmp.path() / (pol + "1"));
    const radar::CovarianceGridmap dec = mapping::read_covariance_gridmap(pkg);
    const auto pts = radar::extract_points(dec, pcfg.points);
    const auto lines = radar::extract_lines(dec, pcfg.lines);
    const CellErrors e = cell_errors(r.gridmap, dec);
    std::printf("%-6s %8.3f %11.2f %11.3f %13.1f %9.4f %9.4f %9.4f %9.4f %8zu %9.3f %10.2f\n",
                pol.c_str(), km, bytes[0] / 1e6 / km, bytes[1] / 1e6 / km, bytes[2] / 1e3 / km,
                point_recall(r.points, pts), line_recall(r.lines, lines),
                point_recall(exact_points, r.points), line_recall(exact_lines, r.lines), e.strong,
                e.max_db, e.max_phase_deg);
    std::fflush(stdout);
  }
  return 0;
}
