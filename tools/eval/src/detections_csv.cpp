#include "polmap/eval/detections_csv.hpp"

#include <array>
#include <charconv>
#include <cmath>
#include <map>
#include <nlohmann/json.hpp>
#include <numbers>
#include <sstream>

#include "csv_text.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::eval {

namespace {

using detail::blank_or_comment;
using detail::split_commas;

enum Col { kTime = 0, kSensor, kRange, kAzimuth, kVr, kAmp, kNumCols };

}  // namespace

struct DetectionsCsvReader::Impl {
  std::unique_ptr<std::istream> in;
  std::string source;
  std::uint64_t line_no = 0;
  std::array<int, kNumCols> col{};  // field index of each required column
  std::size_t min_fields = 0;
  bool header_read = false;
  // One row of lookahead: the first row of the next frame.
  struct Row {
    double time_s;
    int sensor_id;
    Detection det;
    std::uint64_t line;
  };
  std::optional<Row> pending;
  bool eof = false;
  double last_time_s = -std::numeric_limits<double>::infinity();
  std::map<int, std::uint32_t> frames_per_sensor;
  std::map<int, double> last_frame_time;  // per sensor

  [[noreturn]] void fail(std::uint64_t line, int field, std::string_view name,
                         const std::string& what) const {
    std::string msg = source + ": line " + std::to_string(line);
    if (field >= 0) {
      msg += ", column " + std::to_string(field + 1);
      if (!name.empty()) msg += " (" + std::string(name) + ")";
    }
    throw FormatError(msg + ": " + what);
  }

  bool getline(std::string& line) {
    if (!std::getline(*in, line)) return false;
    ++line_no;
    return true;
  }

  void read_header() {
    header_read = true;
    std::string line;
    while (getline(line)) {
      if (blank_or_comment(line)) continue;
      const auto fields = split_commas(line);
      col.fill(-1);
      for (std::size_t i = 0; i < fields.size(); ++i) {
        for (int c = 0; c < kNumCols; ++c) {
          if (fields[i] != kDetectionsCsvColumns[c]) continue;
          if (col[c] >= 0) fail(line_no, static_cast<int>(i), fields[i], "duplicate column");
          col[c] = static_cast<int>(i);
        }
      }
      for (int c = 0; c < kNumCols; ++c) {
        if (col[c] < 0) {
          fail(line_no, -1, {},
               "header lacks column '" + std::string(kDetectionsCsvColumns[c]) +
                   "' (expected timestamp_s,sensor_id,range_m,azimuth_rad,radial_velocity_mps,"
                   "amplitude_db)");
        }
        min_fields = std::max(min_fields, static_cast<std::size_t>(col[c] + 1));
      }
      return;
    }
    fail(line_no == 0 ? 1 : line_no, -1, {}, "empty file (no header row)");
  }

  double number(const std::vector<std::string_view>& f, int c) const {
    const std::string_view s = f[col[c]];
    const std::optional<double> v = detail::parse_double(s);
    if (!v) {
      fail(line_no, col[c], kDetectionsCsvColumns[c], "'" + std::string(s) + "' is not a number");
    }
    if (!std::isfinite(*v)) fail(line_no, col[c], kDetectionsCsvColumns[c], "value is not finite");
    return *v;
  }

  std::optional<Row> read_row() {
    if (!header_read) read_header();
    std::string line;
    while (getline(line)) {
      if (blank_or_comment(line)) continue;
      const auto f = split_commas(line);
      if (f.size() < min_fields) {
        fail(line_no, static_cast<int>(f.size()), {},
             "row has " + std::to_string(f.size()) + " fields, header needs " +
                 std::to_string(min_fields));
      }
      Row r{};
      r.line = line_no;
      r.time_s = number(f, kTime);
      {
        const std::string_view s = f[col[kSensor]];
        int id = -1;
        const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), id);
        if (s.empty() || ec != std::errc{} || p != s.data() + s.size() || id < 0 || id > 255) {
          fail(line_no, col[kSensor], "sensor_id",
               "'" + std::string(s) + "' is not an integer in 0..255");
        }
        r.sensor_id = id;
      }
      const double range = number(f, kRange);
      if (range < 0) fail(line_no, col[kRange], "range_m", "negative range");
      const double az = number(f, kAzimuth);
      if (std::abs(az) > std::numbers::pi) {
        fail(line_no, col[kAzimuth], "azimuth_rad", "outside [-pi, pi] (radians expected)");
      }
      r.det.range_m = static_cast<float>(range);
      r.det.azimuth_rad = static_cast<float>(az);
      r.det.radial_velocity_mps = static_cast<float>(number(f, kVr));
      r.det.snr_db = static_cast<float>(number(f, kAmp));
      if (r.time_s < last_time_s) {
        fail(line_no, col[kTime], "timestamp_s", "rows are not in time order");
      }
      last_time_s = r.time_s;
      return r;
    }
    return std::nullopt;
  }

  std::optional<SensorFrame> next() {
    if (!pending && !eof) {
      pending = read_row();
      if (!pending) eof = true;
    }
    if (!pending) return std::nullopt;
    SensorFrame frame;
    frame.sensor_id = static_cast<std::uint8_t>(pending->sensor_id);
    frame.time_s = pending->time_s;
    const auto prev = last_frame_time.find(pending->sensor_id);
    if (prev != last_frame_time.end() && prev->second == pending->time_s) {
      fail(pending->line, col[kTime], "timestamp_s",
           "frame (timestamp " + std::to_string(pending->time_s) + ", sensor " +
               std::to_string(pending->sensor_id) +
               ") continues after rows of another frame; rows of a frame must be consecutive");
    }
    last_frame_time[pending->sensor_id] = pending->time_s;
    frame.cycle_index = frames_per_sensor[pending->sensor_id]++;
    frame.detections.push_back(pending->det);
    pending.reset();
    while (auto r = read_row()) {
      if (r->sensor_id != frame.sensor_id || r->time_s != frame.time_s) {
        pending = r;
        return frame;
      }
      frame.detections.push_back(r->det);
    }
    eof = true;
    return frame;
  }
};

DetectionsCsvReader::DetectionsCsvReader(const std::filesystem::path& path)
    : impl_(std::make_unique<Impl>()) {
  auto f = std::make_unique<std::ifstream>(path);
  if (!*f) throw IoError("cannot open detections CSV " + path.string());
  impl_->in = std::move(f);
  impl_->source = path.string();
}

DetectionsCsvReader::DetectionsCsvReader(std::unique_ptr<std::istream> in, std::string source_name)
    : impl_(std::make_unique<Impl>()) {
  impl_->in = std::move(in);
  impl_->source = std::move(source_name);
}

DetectionsCsvReader::~DetectionsCsvReader() = default;

std::optional<SensorFrame> DetectionsCsvReader::next() { return impl_->next(); }

std::vector<SensorFrame> parse_detections_csv(std::string_view text,
                                              const std::string& source_name) {
  DetectionsCsvReader reader(std::make_unique<std::istringstream>(std::string(text)), source_name);
  std::vector<SensorFrame> frames;
  while (auto f = reader.next()) frames.push_back(std::move(*f));
  return frames;
}

std::vector<SensorFrame> read_detections_csv(const std::filesystem::path& path) {
  DetectionsCsvReader reader(path);
  std::vector<SensorFrame> frames;
  while (auto f = reader.next()) frames.push_back(std::move(*f));
  return frames;
}

std::string format_detections_csv(const std::vector<SensorFrame>& frames) {
  std::string out = "timestamp_s,sensor_id,range_m,azimuth_rad,radial_velocity_mps,amplitude_db\n";
  char buf[256];
  for (const SensorFrame& f : frames) {
    for (const Detection& d : f.detections) {
      // %.17g for the time (double), %.9g for the float fields: exact round trip.
      std::snprintf(buf, sizeof buf, "%.17g,%d,%.9g,%.9g,%.9g,%.9g\n", f.time_s,
                    static_cast<int>(f.sensor_id), static_cast<double>(d.range_m),
                    static_cast<double>(d.azimuth_rad), static_cast<double>(d.radial_velocity_mps),
                    static_cast<double>(d.snr_db));
      out += buf;
    }
  }
  return out;
}

void write_detections_csv(const std::filesystem::path& path,
                          const std::vector<SensorFrame>& frames) {
  std::ofstream f(path, std::ios::binary);
  if (!f) throw IoError("cannot write " + path.string());
  f << format_detections_csv(frames);
  if (!f) throw IoError("write failed: " + path.string());
}

// ---------------------------------------------------------------- mounts JSON

namespace {

using nlohmann::json;

[[noreturn]] void json_fail(const std::string& source, const std::string& path,
                            const std::string& what) {
  throw FormatError(source + ": " + path + ": " + what);
}

double json_number(const json& o, const std::string& key, const std::string& source,
                   const std::string& path, std::optional<double> fallback) {
  const auto it = o.find(key);
  if (it == o.end()) {
    if (fallback) return *fallback;
    json_fail(source, path + "." + key, "missing required number");
  }
  if (!it->is_number())
    json_fail(source, path + "." + key, "expected a number, got " + std::string(it->type_name()));
  return it->get<double>();
}

}  // namespace

std::vector<SensorMount> parse_sensor_mounts_json(std::string_view text,
                                                  const std::string& source_name) {
  json doc;
  try {
    doc = json::parse(text);
  } catch (const json::parse_error& e) {
    // Byte offset -> line/column (1-based) for the message.
    const std::size_t byte = std::min<std::size_t>(e.byte == 0 ? 0 : e.byte - 1, text.size());
    std::size_t line = 1, column = 1;
    for (std::size_t i = 0; i < byte; ++i) {
      if (text[i] == '\n') {
        ++line;
        column = 1;
      } else {
        ++column;
      }
    }
    throw FormatError(source_name + ": line " + std::to_string(line) + ", column " +
                      std::to_string(column) + ": JSON syntax error: " + e.what());
  }
  if (!doc.is_array()) json_fail(source_name, "(top level)", "expected an array of sensor mounts");
  static const std::vector<std::string> known = {"sensor_id",
                                                 "name",
                                                 "x_m",
                                                 "y_m",
                                                 "yaw_rad",
                                                 "v_unambiguous_mps",
                                                 "trigger_offset_s",
                                                 "fov_half_rad",
                                                 "max_range_m",
                                                 "frame_rate_hz",
                                                 "azimuth_resolution_rad",
                                                 "velocity_resolution_mps"};
  std::vector<SensorMount> mounts;
  for (std::size_t i = 0; i < doc.size(); ++i) {
    const json& o = doc[i];
    const std::string path = "[" + std::to_string(i) + "]";
    if (!o.is_object()) json_fail(source_name, path, "expected an object");
    for (const auto& [key, value] : o.items()) {
      if (std::find(known.begin(), known.end(), key) == known.end()) {
        json_fail(source_name, path + "." + key,
                  "unknown field (known: sensor_id, name, x_m, y_m, yaw_rad, v_unambiguous_mps, "
                  "trigger_offset_s, fov_half_rad, max_range_m, frame_rate_hz, "
                  "azimuth_resolution_rad, velocity_resolution_mps)");
      }
    }
    SensorMount m;
    const auto id_it = o.find("sensor_id");
    if (id_it == o.end()) json_fail(source_name, path + ".sensor_id", "missing required integer");
    if (!id_it->is_number_integer() || id_it->get<std::int64_t>() < 0 ||
        id_it->get<std::int64_t>() > 255) {
      json_fail(source_name, path + ".sensor_id", "expected an integer in 0..255");
    }
    m.sensor_id = static_cast<std::uint8_t>(id_it->get<int>());
    for (const SensorMount& prev : mounts) {
      if (prev.sensor_id == m.sensor_id) {
        json_fail(source_name, path + ".sensor_id",
                  "duplicate sensor_id " + std::to_string(m.sensor_id));
      }
    }
    if (const auto it = o.find("name"); it != o.end()) {
      if (!it->is_string()) json_fail(source_name, path + ".name", "expected a string");
      m.name = it->get<std::string>();
    } else {
      m.name = "sensor_" + std::to_string(m.sensor_id);
    }
    m.T_vehicle_sensor.x_m = json_number(o, "x_m", source_name, path, std::nullopt);
    m.T_vehicle_sensor.y_m = json_number(o, "y_m", source_name, path, std::nullopt);
    m.T_vehicle_sensor.yaw_rad = json_number(o, "yaw_rad", source_name, path, std::nullopt);
    if (std::abs(m.T_vehicle_sensor.yaw_rad) > 2 * std::numbers::pi) {
      json_fail(source_name, path + ".yaw_rad", "outside [-2pi, 2pi] (radians expected)");
    }
    m.spec.v_unambiguous_mps = json_number(o, "v_unambiguous_mps", source_name, path, std::nullopt);
    if (m.spec.v_unambiguous_mps < 0) {
      json_fail(source_name, path + ".v_unambiguous_mps", "negative (0 = not aliased)");
    }
    m.trigger_offset_s = json_number(o, "trigger_offset_s", source_name, path, 0.0);
    m.spec.fov_half_rad = json_number(o, "fov_half_rad", source_name, path, m.spec.fov_half_rad);
    m.spec.max_range_m = json_number(o, "max_range_m", source_name, path, m.spec.max_range_m);
    m.spec.frame_rate_hz = json_number(o, "frame_rate_hz", source_name, path, m.spec.frame_rate_hz);
    m.spec.azimuth_resolution_rad =
        json_number(o, "azimuth_resolution_rad", source_name, path, m.spec.azimuth_resolution_rad);
    m.spec.velocity_resolution_mps = json_number(o, "velocity_resolution_mps", source_name, path,
                                                 m.spec.velocity_resolution_mps);
    mounts.push_back(std::move(m));
  }
  if (mounts.empty()) json_fail(source_name, "(top level)", "no sensor mounts");
  return mounts;
}

std::vector<SensorMount> read_sensor_mounts_json(const std::filesystem::path& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw IoError("cannot open sensor mounts JSON " + path.string());
  std::stringstream ss;
  ss << f.rdbuf();
  return parse_sensor_mounts_json(ss.str(), path.string());
}

std::string format_sensor_mounts_json(const std::vector<SensorMount>& mounts) {
  json arr = json::array();
  for (const SensorMount& m : mounts) {
    arr.push_back(json{{"sensor_id", m.sensor_id},
                       {"name", m.name},
                       {"x_m", m.T_vehicle_sensor.x_m},
                       {"y_m", m.T_vehicle_sensor.y_m},
                       {"yaw_rad", m.T_vehicle_sensor.yaw_rad},
                       {"v_unambiguous_mps", m.spec.v_unambiguous_mps},
                       {"trigger_offset_s", m.trigger_offset_s},
                       {"fov_half_rad", m.spec.fov_half_rad},
                       {"max_range_m", m.spec.max_range_m}});
  }
  return arr.dump(2) + "\n";
}

}  // namespace polmap::eval
