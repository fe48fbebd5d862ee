// `polmap process --recording R --out PKG [--pol LEVEL] [--cell-size M] [--tar] [--overwrite]
//  [--json]`: runs the mapping front end over one recording (radar::process_drive:
// GNSS-posed PreCFAR covariance gridmap, pCFAR points, ridge/Hough lines) and writes the
// drive package (schema/drive_package.md): a directory, or with --tar the single ustar
// archive that `polmap upload` / POST /v1/drives take. Prints a summary (frames, distance,
// candidates, package size and bytes per km).
#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <numbers>
#include <string>

#include "command.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/radar/drive_processor.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/schema/recording_io.hpp"
#include "polmap/util/file.hpp"
#include "progress.hpp"

namespace polmap::cli {
namespace {

namespace fs = std::filesystem;

struct ProcessOptions {
  std::string recording;
  std::string out;
  std::string pol = "full";
  double cell_size_m = 0.1;
  int mantissa_bits = 23;
  int format = 2;
  bool landmarks_only = false;
  bool tar = false;
  bool overwrite = false;
  bool json = false;
};

std::uint64_t dir_bytes(const fs::path& dir) {
  std::uint64_t n = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.is_regular_file()) n += e.file_size();
  }
  return n;
}

void run(const ProcessOptions& o) {
  const auto level = parse_pol_level(o.pol);
  if (!level) {
    throw ValidationError("--pol '" + o.pol + "': expected full, ll-lr, hh-vv, lr, rr or hh");
  }
  if (!(o.cell_size_m >= 0.01 && o.cell_size_m <= 10.0)) {
    throw ValidationError("--cell-size must be within [0.01, 10] m");
  }
  const fs::path out(o.out);
  std::error_code ec;
  if (fs::exists(out, ec) && !o.overwrite &&
      (!fs::is_directory(out, ec) || !fs::is_empty(out, ec))) {
    throw IoError("--out " + o.out + ": exists (use --overwrite to replace it)");
  }

  RecordingReader reader(o.recording);
  radar::DriveProcessingConfig cfg;
  cfg.gridmap.level = *level;
  cfg.gridmap.cell_size_m = o.cell_size_m;
  mapping::PackageWriteOptions wopts;
  wopts.overwrite = o.overwrite;
  wopts.mantissa_bits = o.mantissa_bits;
  wopts.format_version = static_cast<std::uint32_t>(o.format);
  wopts.landmarks_only = o.landmarks_only;
  if (o.landmarks_only && o.format < 2) throw ValidationError("--landmarks-only needs --format 2");
  char producer[128];
  std::snprintf(producer, sizeof(producer), "polmap process 0.1.0 (pol %s, cell %g m)",
                o.pol.c_str(), o.cell_size_m);
  wopts.producer = producer;
  const double t0 = reader.header().start_time_s;
  radar::DriveProcessingResult result = [&] {
    Progress progress("process " + fs::path(o.recording).filename().string(), 0.0);
    // A compact package's candidates come from the gridmap as it is sent.
    return mapping::process_drive_for_package(reader, cfg, wopts, [&](double time_s) {
      char note[64];
      std::snprintf(note, sizeof(note), "s of drive processed");
      progress.update(time_s - t0, note);
    });
  }();

  std::uint64_t package_bytes = 0;
  mapping::DriveManifest manifest;
  if (o.tar) {
    // Build the directory beside the archive, pack it, remove the directory.
    const fs::path parent = fs::absolute(out).parent_path();
    std::string tmp_name(1, '.');
    tmp_name += out.filename().string() + ".pkgdir";
    const util::ScopedTempDir tmp(parent / tmp_name);  // removed however this block ends
    fs::remove_all(tmp.path(), ec);                    // a leftover of an interrupted run
    manifest = mapping::write_drive_package(result, tmp.path(), wopts);
    mapping::write_drive_package_archive(tmp.path(), out);
    package_bytes = fs::file_size(out);
  } else {
    manifest = mapping::write_drive_package(result, out, wopts);
    package_bytes = dir_bytes(out);
  }

  std::uint64_t gridmap_bytes = 0, candidates_bytes = 0;
  for (const auto& f : manifest.files) {
    (f.name == mapping::kGridmapFileName ? gridmap_bytes : candidates_bytes) = f.size_bytes;
  }
  const std::string candidates_name = manifest.files.back().name;
  const auto& st = result.stats;
  const double km = st.distance_m / 1000.0;
  const double per_km = km > 0 ? static_cast<double>(package_bytes) / km : 0.0;
  if (o.json) {
    nlohmann::json j{{"drive_id", manifest.drive_id},
                     {"package", o.out},
                     {"archive", o.tar},
                     {"pol_level", o.pol},
                     {"cell_size_m", o.cell_size_m},
                     {"mantissa_bits", o.mantissa_bits},
                     {"sensor_frames", st.sensor_frames},
                     {"frames_mapped", st.frames_mapped},
                     {"frames_without_pose", st.frames_without_pose},
                     {"trajectory_samples", manifest.counts.trajectory_samples},
                     {"duration_s", manifest.end_time_s - manifest.start_time_s},
                     {"distance_m", st.distance_m},
                     {"points", manifest.counts.points},
                     {"lines", manifest.counts.lines},
                     {"gridmap_width", manifest.gridmap.width},
                     {"gridmap_height", manifest.gridmap.height},
                     {"format_version", manifest.format_version},
                     {"landmarks_only", !manifest.has_gridmap},
                     {"gridmap_bytes", gridmap_bytes},
                     {"candidates_bytes", candidates_bytes},
                     {"package_bytes", package_bytes},
                     {"package_bytes_per_km", per_km},
                     {"seconds", st.total_seconds}};
    if (result.mount_calibration) {
      nlohmann::json& c = j["mount_calibration"];
      c["status"] = radar::to_string(result.mount_calibration->status);
      for (const auto& e : result.mount_calibration->sensors) {
        c["sensors"].push_back({{"sensor_id", e.sensor_id},
                                {"yaw_offset_deg", e.yaw_offset_rad * 180.0 / std::numbers::pi},
                                {"yaw_sigma_deg", e.yaw_sigma_rad * 180.0 / std::numbers::pi},
                                {"time_offset_ms", 1e3 * e.time_offset_s},
                                {"time_sigma_ms", 1e3 * e.time_sigma_s}});
      }
    }
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  std::printf("drive %s: %zu sensor frames (%zu mapped, %zu without pose), %.1f s, %.3f km\n",
              manifest.drive_id.c_str(), st.sensor_frames, st.frames_mapped, st.frames_without_pose,
              manifest.end_time_s - manifest.start_time_s, km);
  std::printf(
      "candidates: %llu points, %llu lines; gridmap %d x %d cells of %.2f m (%s, %d bands)\n",
      static_cast<unsigned long long>(manifest.counts.points),
      static_cast<unsigned long long>(manifest.counts.lines), manifest.gridmap.width,
      manifest.gridmap.height, manifest.cell_size_m, o.pol.c_str(), manifest.gridmap.num_bands);
  std::printf("package %s%s (format %u%s): %.3f MB (gridmap.tif %.3f MB, %s %.3f MB)",
              o.out.c_str(), o.tar ? " (ustar archive)" : "", manifest.format_version,
              manifest.has_gridmap ? "" : ", landmarks only", package_bytes / 1e6,
              gridmap_bytes / 1e6, candidates_name.c_str(), candidates_bytes / 1e6);
  if (km > 0) std::printf(", %.3f MB/km (%.1f kB/km)", per_km / 1e6, per_km / 1e3);
  std::printf("; processing %.1f s\n", st.total_seconds);
  if (result.mount_calibration) {
    std::printf("mounts calibrated against the trajectory (%s):",
                radar::to_string(result.mount_calibration->status));
    for (const auto& e : result.mount_calibration->sensors) {
      std::printf(" sensor %d yaw %+.3f +- %.3f deg, time %+.2f ms;", e.sensor_id,
                  e.yaw_offset_rad * 180.0 / std::numbers::pi,
                  e.yaw_sigma_rad * 180.0 / std::numbers::pi, 1e3 * e.time_offset_s);
    }
    std::printf("\n");
  }
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<ProcessOptions>();
  CLI::App* cmd = app.add_subcommand(
      "process", "Process a recording into a drive package (gridmap, candidates, trajectory)");
  cmd->add_option("--recording", opts->recording, "Recording (.pmrec)")->required();
  cmd->add_option("--out", opts->out, "Package directory (or archive file with --tar)")->required();
  cmd->add_option("--pol", opts->pol, "Polarimetric level: full, ll-lr, hh-vv, lr, rr, hh")
      ->capture_default_str();
  cmd->add_option("--cell-size", opts->cell_size_m, "Gridmap cell size, metres")
      ->capture_default_str();
  cmd->add_option("--mantissa-bits", opts->mantissa_bits,
                  "Float32 mantissa bits kept in the covariance bands (23 = lossless; 10 keeps "
                  "5e-4 relative precision and shrinks the gridmap)")
      ->check(CLI::Range(1, 23))
      ->capture_default_str();
  cmd->add_option("--format", opts->format,
                  "Package format: 2 = compact (gridmap codes + candidates.bin, a few MB/km), "
                  "1 = Float32 gridmap + GeoPackage (lossless, ~85 MB/km)")
      ->check(CLI::Range(1, 2))
      ->capture_default_str();
  cmd->add_flag("--landmarks-only", opts->landmarks_only,
                "Format 2 without the gridmap: candidates and trajectory only (~15 kB/km)");
  cmd->add_flag("--tar", opts->tar, "Write the single-file ustar archive instead of a directory");
  cmd->add_flag("--overwrite", opts->overwrite, "Replace an existing package");
  cmd->add_flag("--json", opts->json, "Print the summary as JSON");
  cmd->callback([opts] { run(*opts); });
}

}  // namespace
POLMAP_REGISTER_COMMAND(process, setup);
}  // namespace polmap::cli
