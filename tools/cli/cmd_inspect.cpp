// `polmap inspect RECORDING [--json]`: validates a whole recording (every
// record is read, checksummed and decoded) and summarizes it.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdio>
#include <exception>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <string>

#include "command.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/schema/json.hpp"
#include "polmap/schema/recording_io.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "progress.hpp"

namespace polmap::cli {
namespace {

/// Distance is summed over chords of at least this length: summing every
/// 50-100 Hz GNSS step would add the position noise (14-86 mm per sample) to
/// the distance, several % at urban speeds. The chord error on a 10 m radius
/// curve is d^2 / (24 R^2) = 0.2 %.
constexpr double kDistanceChord_m = 2.0;

struct InspectOptions {
  std::string path;
  bool json = false;
};

struct RecordingSummary {
  std::optional<RecordingHeader> header;
  std::uint64_t bytes = 0;
  std::uint64_t frames = 0;
  std::uint64_t cube_frames = 0;
  std::uint64_t trajectory_samples = 0;
  std::uint64_t carrier_phase_fixed = 0;
  std::uint64_t detections = 0;
  std::uint64_t cells = 0;
  std::set<int> sensors_seen;
  double t_min = std::numeric_limits<double>::infinity();
  double t_max = -std::numeric_limits<double>::infinity();
  double speed_min = std::numeric_limits<double>::infinity();
  double speed_max = -std::numeric_limits<double>::infinity();
  double distance_m = 0.0;
  bool valid = false;
  std::string error;
  std::exception_ptr exception;  // the original error, rethrown in text mode

  [[nodiscard]] double duration_s() const { return t_max > t_min ? t_max - t_min : 0.0; }
  [[nodiscard]] std::optional<double> bytes_per_minute() const {
    if (duration_s() <= 0.0) return std::nullopt;
    return static_cast<double>(bytes) / (duration_s() / 60.0);
  }
  [[nodiscard]] std::optional<double> per_frame(std::uint64_t n) const {
    if (frames == 0) return std::nullopt;
    return static_cast<double>(n) / static_cast<double>(frames);
  }
};

RecordingSummary summarize(const std::string& path) {
  RecordingSummary s;
  std::error_code ec;
  s.bytes = std::filesystem::file_size(path, ec);
  try {
    RecordingReader reader(path);
    s.header = reader.header();
    s.bytes = reader.file_size();
    const tiles::LocalFrame frame(reader.header().origin);
    std::optional<Eigen::Vector2d> anchor;
    Eigen::Vector2d last = Eigen::Vector2d::Zero();
    Progress progress("inspect " + path, static_cast<double>(s.bytes));
    while (auto rec = reader.next()) {
      progress.update(static_cast<double>(reader.offset()));
      if (const auto* f = std::get_if<SensorFrame>(&*rec)) {
        ++s.frames;
        s.cube_frames += f->cube ? 1 : 0;
        s.detections += f->detections.size();
        s.cells += f->spectrum.cells.size();
        s.sensors_seen.insert(f->sensor_id);
        s.t_min = std::min(s.t_min, f->time_s);
        s.t_max = std::max(s.t_max, f->time_s);
      } else {
        const auto& t = std::get<TrajectorySample>(*rec);
        ++s.trajectory_samples;
        s.carrier_phase_fixed += t.solution == GnssSolution::CarrierPhaseFixed ? 1 : 0;
        s.t_min = std::min(s.t_min, t.time_s);
        s.t_max = std::max(s.t_max, t.time_s);
        s.speed_min = std::min(s.speed_min, t.speed_mps);
        s.speed_max = std::max(s.speed_max, t.speed_mps);
        last = frame.to_local(t.lat_deg, t.lon_deg);
        if (!anchor) {
          anchor = last;
        } else if ((last - *anchor).norm() >= kDistanceChord_m) {
          s.distance_m += (last - *anchor).norm();
          anchor = last;
        }
      }
    }
    if (anchor) s.distance_m += (last - *anchor).norm();
    s.valid = true;
  } catch (const Error& e) {
    s.error = e.what();
    s.exception = std::current_exception();
  }
  return s;
}

nlohmann::json to_json_summary(const std::string& path, const RecordingSummary& s) {
  auto opt = [](std::optional<double> v) { return v ? nlohmann::json(*v) : nlohmann::json(); };
  nlohmann::json j;
  j["file"] = path;
  j["valid"] = s.valid;
  j["error"] = s.valid ? nlohmann::json() : nlohmann::json(s.error);
  j["format_version"] = s.header ? nlohmann::json(s.header->format_version) : nlohmann::json();
  j["drive_id"] = s.header ? nlohmann::json(s.header->drive_id) : nlohmann::json();
  j["world"] = s.header ? nlohmann::json(s.header->world) : nlohmann::json();
  j["frames"] = s.frames;
  j["cube_frames"] = s.cube_frames;
  j["sensors"] = s.header ? s.header->sensors.size() : std::size_t{0};
  j["trajectory_samples"] = s.trajectory_samples;
  j["duration_s"] = s.duration_s();
  j["distance_m"] = s.distance_m;
  j["speed_min_mps"] = s.trajectory_samples ? nlohmann::json(s.speed_min) : nlohmann::json();
  j["speed_max_mps"] = s.trajectory_samples ? nlohmann::json(s.speed_max) : nlohmann::json();
  j["carrier_phase_share"] = s.trajectory_samples
                                 ? nlohmann::json(static_cast<double>(s.carrier_phase_fixed) /
                                                  static_cast<double>(s.trajectory_samples))
                                 : nlohmann::json();
  j["detections_per_frame"] = opt(s.per_frame(s.detections));
  j["cells_per_frame"] = opt(s.per_frame(s.cells));
  j["bytes"] = s.bytes;
  // Only a fully read recording has a meaningful duration to divide by.
  j["bytes_per_minute"] = s.valid ? opt(s.bytes_per_minute()) : nlohmann::json();
  return j;
}

void print_text(const std::string& path, const RecordingSummary& s) {
  const RecordingHeader& h = *s.header;
  std::printf("recording            %s\n", path.c_str());
  std::printf("format               v%u, drive '%s', vehicle '%s', world '%s'\n", h.format_version,
              h.drive_id.c_str(), h.vehicle_id.c_str(), h.world.c_str());
  std::printf("producer             %s\n", h.producer.c_str());
  std::printf("origin               %.8f, %.8f, %.2f m\n", h.origin.lat_deg, h.origin.lon_deg,
              h.origin.alt_m);
  std::string names;
  for (const SensorMount& m : h.sensors) {
    names += (names.empty() ? "" : ", ") + std::to_string(m.sensor_id) + ":" + m.name;
  }
  std::printf("sensors              %zu (%s)\n", h.sensors.size(), names.c_str());
  std::printf("frames               %llu sensor frames (%llu with data cube)\n",
              static_cast<unsigned long long>(s.frames),
              static_cast<unsigned long long>(s.cube_frames));
  std::printf("trajectory           %llu samples\n",
              static_cast<unsigned long long>(s.trajectory_samples));
  std::printf("duration             %.2f s\n", s.duration_s());
  std::printf("distance             %.1f m\n", s.distance_m);
  if (s.trajectory_samples > 0) {
    std::printf("speed                %.2f .. %.2f m/s\n", s.speed_min, s.speed_max);
    std::printf("carrier-phase share  %.1f %%\n", 100.0 *
                                                      static_cast<double>(s.carrier_phase_fixed) /
                                                      static_cast<double>(s.trajectory_samples));
  }
  if (s.frames > 0) {
    std::printf("detections / frame   %.1f\n", *s.per_frame(s.detections));
    std::printf("spectrum cells/frame %.1f\n", *s.per_frame(s.cells));
  }
  std::printf("size                 %llu bytes", static_cast<unsigned long long>(s.bytes));
  if (const auto bpm = s.bytes_per_minute()) std::printf(" (%.2f MB per minute)", *bpm / 1e6);
  std::printf("\nvalid                yes\n");
}

void run_inspect(const InspectOptions& o) {
  const RecordingSummary s = summarize(o.path);
  if (o.json) {
    std::printf("%s\n", to_json_summary(o.path, s).dump().c_str());
    if (!s.valid) {
      std::fprintf(stderr, "polmap: error: %s\n", s.error.c_str());
      set_exit_code(1);
    }
    return;
  }
  // Text mode: the one-line error of main() (file and byte offset are in the message).
  if (!s.valid) std::rethrow_exception(s.exception);
  print_text(o.path, s);
}

void setup_inspect(CLI::App& app) {
  auto opts = std::make_shared<InspectOptions>();
  auto* cmd = app.add_subcommand(
      "inspect",
      "Validate a recording (reads and checksums every record) and print frames, sensors, "
      "duration, distance, speed range, carrier-phase share, detections and spectrum cells per "
      "frame, bytes per minute. Exit code 1 and a one-line error naming file and byte offset "
      "when the recording is invalid.");
  cmd->add_option("RECORDING", opts->path, "recording file (.pmrec, schema/recording.md)")
      ->required();
  cmd->add_flag("--json", opts->json,
                "print one JSON object (frames, sensors, duration_s, distance_m, speed_min_mps, "
                "speed_max_mps, carrier_phase_share, bytes, bytes_per_minute, valid, error, ...)");
  cmd->callback([opts] { run_inspect(*opts); });
}

}  // namespace
}  // namespace polmap::cli

POLMAP_REGISTER_COMMAND(inspect, polmap::cli::setup_inspect);
