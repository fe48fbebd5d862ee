// Drive package writer, archive packing/unpacking, manifest JSON, candidates GeoPackage.
#include "polmap/mapping_service/drive_package_io.hpp"

#include <gdal_priv.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>
#include <openssl/evp.h>
#include <stdlib.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "package_internal.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/schema/json.hpp"

namespace polmap::mapping {

namespace fs = std::filesystem;
using nlohmann::json;

// ------------------------------------------------------------------------ errors

namespace {
std::string format_error_message(const std::string& file, const std::string& field,
                                 const std::string& message) {
  if (field.empty()) return file + ": " + message;
  return file + ": field '" + field + "': " + message;
}
}  // namespace

std::string PackageError::what() const { return format_error_message(file, field, message); }

PackageFormatError::PackageFormatError(std::string file, std::string field, std::string message)
    : FormatError(format_error_message(file, field, message)),
      error_{std::move(file), std::move(field), std::move(message), 400} {}

PackageValidationError::PackageValidationError(std::string file, std::string field,
                                               std::string message)
    : ValidationError(format_error_message(file, field, message)),
      error_{std::move(file), std::move(field), std::move(message), 422} {}

// ------------------------------------------------------------------------ hashing

detail::Sha256::Sha256() {
  EVP_MD_CTX* ctx = EVP_MD_CTX_new();
  if (ctx == nullptr || EVP_DigestInit_ex(ctx, EVP_sha256(), nullptr) != 1) {
    EVP_MD_CTX_free(ctx);
    throw Error("OpenSSL: SHA-256 initialisation failed");
  }
  ctx_ = ctx;
}
detail::Sha256::~Sha256() { EVP_MD_CTX_free(static_cast<EVP_MD_CTX*>(ctx_)); }
void detail::Sha256::update(std::string_view bytes) {
  if (EVP_DigestUpdate(static_cast<EVP_MD_CTX*>(ctx_), bytes.data(), bytes.size()) != 1) {
    throw Error("OpenSSL: SHA-256 update failed");
  }
}
std::string detail::Sha256::hex() {
  std::array<unsigned char, EVP_MAX_MD_SIZE> md{};
  unsigned int len = 0;
  if (EVP_DigestFinal_ex(static_cast<EVP_MD_CTX*>(ctx_), md.data(), &len) != 1) {
    throw Error("OpenSSL: SHA-256 final failed");
  }
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out;
  out.reserve(2 * len);
  for (unsigned int i = 0; i < len; ++i) {
    out.push_back(kHex[md[i] >> 4U]);
    out.push_back(kHex[md[i] & 15U]);
  }
  return out;
}

std::string sha256_hex(std::string_view bytes) {
  detail::Sha256 h;
  h.update(bytes);
  return h.hex();
}

namespace detail {

// ------------------------------------------------------------------------ files

std::string read_file_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IoError(path.string() + ": cannot open for reading");
  std::string data;
  in.seekg(0, std::ios::end);
  const auto size = in.tellg();
  if (size < 0) throw IoError(path.string() + ": cannot determine size");
  data.resize(static_cast<std::size_t>(size));
  in.seekg(0);
  in.read(data.data(), static_cast<std::streamsize>(data.size()));
  if (!in) throw IoError(path.string() + ": read failed");
  return data;
}

void write_file_bytes(const fs::path& path, std::string_view bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw IoError(path.string() + ": cannot open for writing");
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  out.flush();
  if (!out) throw IoError(path.string() + ": write failed");
}

fs::path make_unique_dir(const fs::path& parent, const std::string& stem) {
  const fs::path base = parent.empty() ? fs::temp_directory_path() : parent;
  std::string templ = (base / (stem + "-XXXXXX")).string();
  if (mkdtemp(templ.data()) == nullptr) {
    throw IoError(base.string() + ": cannot create a temporary directory");
  }
  return templ;
}

// ------------------------------------------------------------------------ manifest JSON

json manifest_to_json(const DriveManifest& m) {
  json files = json::array();
  for (const auto& f : m.files) {
    files.push_back({{"name", f.name}, {"size_bytes", f.size_bytes}, {"sha256", f.sha256}});
  }
  const int q = pol_dimension(m.pol_level);
  return json{{"format", "polmap.drive_package"},
              {"format_version", m.format_version},
              {"drive_id", m.drive_id},
              {"vehicle_id", m.vehicle_id},
              {"world", m.world},
              {"producer", m.producer},
              {"start_time_s", m.start_time_s},
              {"end_time_s", m.end_time_s},
              {"distance_m", m.distance_m},
              {"origin", m.origin},
              {"crs_proj", m.crs_proj},
              {"sensors", m.sensors},
              {"pol_level", std::string(to_string(m.pol_level))},
              {"q", q},
              {"cell_size_m", m.cell_size_m},
              {"gridmap",
               {{"file", kGridmapFileName},
                {"width", m.gridmap.width},
                {"height", m.gridmap.height},
                {"origin_x_m", m.gridmap.origin_x_m},
                {"origin_y_m", m.gridmap.origin_y_m},
                {"num_bands", m.gridmap.num_bands},
                {"block_size", m.gridmap.block_size},
                {"mantissa_bits", m.gridmap.mantissa_bits},
                {"bands", gridmap_band_names(m.pol_level)}}},
              {"counts",
               {{"points", m.counts.points},
                {"lines", m.counts.lines},
                {"trajectory_samples", m.counts.trajectory_samples}}},
              {"files", files}};
}

namespace {

constexpr const char* kManifest = "manifest.json";

/// Strict field access for manifest.json: missing required fields are schema violations
/// (422), wrong JSON types are format errors (400); `prefix` builds the dotted field path.
class Fields {
 public:
  Fields(const json& j, std::string prefix) : j_(j), prefix_(std::move(prefix)) {}

  [[nodiscard]] std::string path(const std::string& key) const {
    return prefix_.empty() ? key : prefix_ + "." + key;
  }
  [[nodiscard]] const json* find(const std::string& key) const {
    const auto it = j_.find(key);
    return it == j_.end() ? nullptr : &*it;
  }
  const json& require(const std::string& key) const {
    const json* v = find(key);
    if (v == nullptr) throw PackageValidationError(kManifest, path(key), "missing required field");
    return *v;
  }
  [[nodiscard]] std::string type_error(const std::string& expected, const json& v) const {
    return std::string("expected ") + expected + ", got " + v.type_name();
  }
  double number(const std::string& key, bool required = true, double def = 0.0) const {
    const json* v = required ? &require(key) : find(key);
    if (v == nullptr) return def;
    if (!v->is_number()) throw PackageFormatError(kManifest, path(key), type_error("number", *v));
    const double d = v->get<double>();
    if (!std::isfinite(d)) throw PackageValidationError(kManifest, path(key), "not finite");
    return d;
  }
  std::int64_t integer(const std::string& key) const {
    const json& v = require(key);
    if (!v.is_number_integer()) {
      throw PackageFormatError(kManifest, path(key), type_error("integer", v));
    }
    if (v.is_number_unsigned() && v.get<std::uint64_t>() > static_cast<std::uint64_t>(INT64_MAX)) {
      throw PackageValidationError(kManifest, path(key), "integer out of range");
    }
    return v.get<std::int64_t>();
  }
  std::uint64_t count(const std::string& key) const {
    const std::int64_t v = integer(key);
    if (v < 0) throw PackageValidationError(kManifest, path(key), "negative count");
    return static_cast<std::uint64_t>(v);
  }
  std::string string(const std::string& key, bool required = true) const {
    const json* v = required ? &require(key) : find(key);
    if (v == nullptr) return {};
    if (!v->is_string()) throw PackageFormatError(kManifest, path(key), type_error("string", *v));
    return v->get<std::string>();
  }
  const json& object(const std::string& key) const {
    const json& v = require(key);
    if (!v.is_object()) throw PackageFormatError(kManifest, path(key), type_error("object", v));
    return v;
  }
  const json& array(const std::string& key) const {
    const json& v = require(key);
    if (!v.is_array()) throw PackageFormatError(kManifest, path(key), type_error("array", v));
    return v;
  }

 private:
  const json& j_;
  std::string prefix_;
};

bool valid_id(const std::string& s) {
  if (s.empty() || s.size() > 128 || s.front() == '.') return false;
  return std::all_of(s.begin(), s.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' ||
           c == '_' || c == '-';
  });
}

bool is_hex64(const std::string& s) {
  return s.size() == 64 && std::all_of(s.begin(), s.end(), [](char c) {
           return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f');
         });
}

}  // namespace

DriveManifest manifest_from_json(const json& j) {
  if (!j.is_object()) {
    throw PackageFormatError(kManifest, "",
                             std::string("expected a JSON object, got ") + j.type_name());
  }
  const Fields f(j, "");
  DriveManifest m;
  {
    const std::string format = f.string("format");
    if (format != "polmap.drive_package") {
      throw PackageValidationError(kManifest, "format",
                                   "expected 'polmap.drive_package', got '" + format + "'");
    }
  }
  const std::int64_t version = f.integer("format_version");
  if (version != kDrivePackageFormatVersion) {
    throw PackageValidationError(kManifest, "format_version",
                                 "unsupported version " + std::to_string(version) +
                                     " (this build reads " +
                                     std::to_string(kDrivePackageFormatVersion) + ")");
  }
  m.format_version = static_cast<std::uint32_t>(version);
  m.drive_id = f.string("drive_id");
  if (!valid_id(m.drive_id)) {
    throw PackageValidationError(kManifest, "drive_id",
                                 "'" + m.drive_id +
                                     "' is not 1..128 characters of [A-Za-z0-9._-] "
                                     "(not starting with '.')");
  }
  m.vehicle_id = f.string("vehicle_id");
  if (!valid_id(m.vehicle_id)) {
    throw PackageValidationError(
        kManifest, "vehicle_id",
        "'" + m.vehicle_id + "' is not 1..128 characters of [A-Za-z0-9._-]");
  }
  m.world = f.string("world", false);
  m.producer = f.string("producer", false);
  m.start_time_s = f.number("start_time_s");
  m.end_time_s = f.number("end_time_s");
  if (m.end_time_s < m.start_time_s) {
    throw PackageValidationError(kManifest, "end_time_s", "before start_time_s");
  }
  m.distance_m = f.number("distance_m");
  if (m.distance_m < 0) throw PackageValidationError(kManifest, "distance_m", "negative");

  {
    const Fields o(f.object("origin"), "origin");
    m.origin.lat_deg = o.number("lat_deg");
    m.origin.lon_deg = o.number("lon_deg");
    m.origin.alt_m = o.number("alt_m", false);
    if (std::abs(m.origin.lat_deg) > 85.0) {
      throw PackageValidationError(kManifest, "origin.lat_deg", "outside [-85, 85] degrees");
    }
    if (std::abs(m.origin.lon_deg) > 180.0) {
      throw PackageValidationError(kManifest, "origin.lon_deg", "outside [-180, 180] degrees");
    }
  }
  m.crs_proj = f.string("crs_proj");
  if (!same_crs(m.crs_proj, tiles::LocalFrame(m.origin).proj_string())) {
    throw PackageValidationError(
        kManifest, "crs_proj",
        "'" + m.crs_proj + "' is not the drive frame (LocalFrame) of 'origin'");
  }

  {
    const json& sensors = f.array("sensors");
    if (sensors.empty()) throw PackageValidationError(kManifest, "sensors", "no sensors");
    std::vector<int> ids;
    for (std::size_t i = 0; i < sensors.size(); ++i) {
      const std::string p = "sensors[" + std::to_string(i) + "]";
      if (!sensors[i].is_object()) {
        throw PackageFormatError(kManifest, p,
                                 std::string("expected object, got ") + sensors[i].type_name());
      }
      const Fields s(sensors[i], p);
      s.integer("sensor_id");
      s.object("T_vehicle_sensor");
      SensorMount mount;
      try {
        from_json(sensors[i], mount);
      } catch (const JsonFieldError& e) {
        throw PackageFormatError(kManifest, p + "." + e.path(), e.reason());
      }
      if (std::find(ids.begin(), ids.end(), mount.sensor_id) != ids.end()) {
        throw PackageValidationError(kManifest, p + ".sensor_id",
                                     "duplicate sensor id " + std::to_string(mount.sensor_id));
      }
      ids.push_back(mount.sensor_id);
      m.sensors.push_back(std::move(mount));
    }
  }

  {
    const std::string level = f.string("pol_level");
    const auto parsed = parse_pol_level(level);
    if (!parsed) {
      std::string names;
      for (const auto& n : pol_level_names()) names += (names.empty() ? "" : ", ") + n;
      throw PackageValidationError(kManifest, "pol_level",
                                   "unknown level '" + level + "' (expected one of " + names + ")");
    }
    m.pol_level = *parsed;
    const std::int64_t q = f.integer("q");
    if (q != pol_dimension(m.pol_level)) {
      throw PackageValidationError(kManifest, "q",
                                   std::to_string(q) + " does not match pol_level '" + level +
                                       "' (q = " + std::to_string(pol_dimension(m.pol_level)) +
                                       ")");
    }
  }
  m.cell_size_m = f.number("cell_size_m");
  if (!(m.cell_size_m >= 0.01 && m.cell_size_m <= 10.0)) {
    throw PackageValidationError(kManifest, "cell_size_m", "outside [0.01, 10] m");
  }

  {
    const Fields g(f.object("gridmap"), "gridmap");
    if (g.string("file") != kGridmapFileName) {
      throw PackageValidationError(kManifest, "gridmap.file",
                                   std::string("expected '") + kGridmapFileName + "'");
    }
    const auto w = g.integer("width");
    const auto h = g.integer("height");
    if (w < 1 || h < 1 || w > 1'000'000 || h > 1'000'000) {
      throw PackageValidationError(kManifest,
                                   w < 1 || w > 1'000'000 ? "gridmap.width" : "gridmap.height",
                                   "outside [1, 1000000] cells");
    }
    m.gridmap.width = static_cast<int>(w);
    m.gridmap.height = static_cast<int>(h);
    m.gridmap.origin_x_m = g.number("origin_x_m");
    m.gridmap.origin_y_m = g.number("origin_y_m");
    const auto bands = g.integer("num_bands");
    const int q = pol_dimension(m.pol_level);
    if (bands != 1 + q * q) {
      throw PackageValidationError(kManifest, "gridmap.num_bands",
                                   std::to_string(bands) + " bands, pol_level '" +
                                       std::string(to_string(m.pol_level)) + "' needs " +
                                       std::to_string(1 + q * q));
    }
    m.gridmap.num_bands = static_cast<int>(bands);
    const auto block = g.integer("block_size");
    if (block != kGridmapBlockSize) {
      throw PackageValidationError(kManifest, "gridmap.block_size",
                                   "expected " + std::to_string(kGridmapBlockSize));
    }
    m.gridmap.block_size = static_cast<int>(block);
    // Optional (absent in packages written before it existed: lossless).
    if (g.find("mantissa_bits") != nullptr) {
      const auto bits = g.integer("mantissa_bits");
      if (bits < 1 || bits > 23) {
        throw PackageValidationError(kManifest, "gridmap.mantissa_bits", "outside [1, 23]");
      }
      m.gridmap.mantissa_bits = static_cast<int>(bits);
    }
    const json& names = g.array("bands");
    if (names != json(gridmap_band_names(m.pol_level))) {
      throw PackageValidationError(
          kManifest, "gridmap.bands",
          "band names do not match pol_level '" + std::string(to_string(m.pol_level)) + "'");
    }
  }
  {
    const Fields c(f.object("counts"), "counts");
    m.counts.points = c.count("points");
    m.counts.lines = c.count("lines");
    m.counts.trajectory_samples = c.count("trajectory_samples");
  }
  {
    const json& files = f.array("files");
    const std::vector<std::string> expected{kGridmapFileName, kCandidatesFileName};
    for (std::size_t i = 0; i < files.size(); ++i) {
      const std::string p = "files[" + std::to_string(i) + "]";
      if (!files[i].is_object()) {
        throw PackageFormatError(kManifest, p,
                                 std::string("expected object, got ") + files[i].type_name());
      }
      const Fields fe(files[i], p);
      PackageFileEntry e;
      e.name = fe.string("name");
      e.size_bytes = fe.count("size_bytes");
      e.sha256 = fe.string("sha256");
      if (!is_hex64(e.sha256)) {
        throw PackageValidationError(kManifest, p + ".sha256", "not 64 lower-case hex digits");
      }
      m.files.push_back(std::move(e));
    }
    for (std::size_t i = 0; i < std::max(files.size(), expected.size()); ++i) {
      if (i >= m.files.size()) {
        throw PackageValidationError(kManifest, "files", "entry for '" + expected[i] + "' missing");
      }
      if (i >= expected.size() || m.files[i].name != expected[i]) {
        throw PackageValidationError(
            kManifest, "files[" + std::to_string(i) + "].name",
            "unexpected file '" + m.files[i].name + "' (expected " +
                (i < expected.size() ? "'" + expected[i] + "'" : std::string("no more entries")) +
                ")");
      }
    }
  }
  return m;
}

// ------------------------------------------------------------------------ candidates.gpkg

namespace {

OGRLayer* create_layer(GDALDataset& ds, const char* name, OGRSpatialReference& srs,
                       OGRwkbGeometryType type, const char* description,
                       const std::vector<std::pair<const char*, OGRFieldType>>& fields,
                       const std::string& path) {
  const std::string desc = std::string("DESCRIPTION=") + description;
  const char* opts[] = {desc.c_str(), nullptr};
  OGRLayer* layer = ds.CreateLayer(name, &srs, type, const_cast<char**>(opts));
  if (layer == nullptr) throw IoError(path + ": cannot create layer " + name);
  for (const auto& [fname, ftype] : fields) {
    OGRFieldDefn def(fname, ftype);
    if (layer->CreateField(&def) != OGRERR_NONE) {
      throw IoError(path + ": cannot create field " + name + "." + fname);
    }
  }
  return layer;
}

void create_feature(OGRLayer* layer, OGRFeature& f, const std::string& path) {
  if (layer->CreateFeature(&f) != OGRERR_NONE) {
    throw IoError(path + ": cannot write a feature of layer " + layer->GetName());
  }
}

}  // namespace

void write_candidates_gpkg(const std::string& path, const tiles::LocalFrame& frame,
                           const std::vector<PointCandidate>& points,
                           const std::vector<LineCandidate>& lines,
                           const std::vector<TrajectorySample>& trajectory) {
  ensure_gdal();
  GdalErrorCapture capture;
  // Fixed gpkg_contents.last_change: the same candidates give the same bytes.
  ScopedGdalConfig fixed_date("OGR_CURRENT_DATE", "2000-01-01T00:00:00.000Z");
  ScopedGdalConfig no_pam("GDAL_PAM_ENABLED", "NO");
  GDALDriver* drv = GetGDALDriverManager()->GetDriverByName("GPKG");
  if (drv == nullptr) throw IoError("GDAL has no GPKG driver");
  GDALDatasetUniquePtr ds(drv->Create(path.c_str(), 0, 0, 0, GDT_Unknown, nullptr));
  if (!ds) throw IoError(path + ": cannot create GeoPackage: " + capture.last_message());
  OGRSpatialReference wgs84;
  wgs84.importFromEPSG(4326);
  wgs84.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);

  OGRLayer* lp = create_layer(*ds, "points", wgs84, wkbPoint,
                              "pCFAR point candidates; x_m/y_m in the drive frame",
                              {{"strength", OFTReal},
                               {"power_db", OFTReal},
                               {"scattering", OFTString},
                               {"num_cells", OFTInteger64},
                               {"x_m", OFTReal},
                               {"y_m", OFTReal}},
                              path);
  OGRLayer* ll = create_layer(*ds, "lines", wgs84, wkbLineString,
                              "line candidates; x0_m..y1_m in the drive frame",
                              {{"strength", OFTReal},
                               {"x0_m", OFTReal},
                               {"y0_m", OFTReal},
                               {"x1_m", OFTReal},
                               {"y1_m", OFTReal},
                               {"length_m", OFTReal}},
                              path);
  OGRLayer* lt = create_layer(*ds, "trajectory", wgs84, wkbPoint,
                              "GNSS/IMU trajectory samples; x_m/y_m in the drive frame",
                              {{"time_s", OFTReal},
                               {"yaw_enu_rad", OFTReal},
                               {"speed_mps", OFTReal},
                               {"yaw_rate_rps", OFTReal},
                               {"std_east_m", OFTReal},
                               {"std_north_m", OFTReal},
                               {"std_yaw_rad", OFTReal},
                               {"solution", OFTString},
                               {"x_m", OFTReal},
                               {"y_m", OFTReal}},
                              path);

  if (ds->StartTransaction() != OGRERR_NONE) throw IoError(path + ": cannot start transaction");
  {
    OGRFeature f(lp->GetLayerDefn());
    for (const auto& p : points) {
      const GeoPoint g = frame.to_geo(p.position_m);
      f.SetFID(OGRNullFID);
      f.SetField("strength", p.strength);
      f.SetField("power_db", p.power_db);
      f.SetField("scattering", std::string(to_string(p.scattering)).c_str());
      f.SetField("num_cells", static_cast<GIntBig>(p.num_cells));
      f.SetField("x_m", p.position_m.x());
      f.SetField("y_m", p.position_m.y());
      OGRPoint pt(g.lon_deg, g.lat_deg);
      f.SetGeometry(&pt);
      create_feature(lp, f, path);
    }
  }
  {
    OGRFeature f(ll->GetLayerDefn());
    for (const auto& l : lines) {
      const GeoPoint a = frame.to_geo(l.start_m);
      const GeoPoint b = frame.to_geo(l.end_m);
      f.SetFID(OGRNullFID);
      f.SetField("strength", l.strength);
      f.SetField("x0_m", l.start_m.x());
      f.SetField("y0_m", l.start_m.y());
      f.SetField("x1_m", l.end_m.x());
      f.SetField("y1_m", l.end_m.y());
      f.SetField("length_m", (l.end_m - l.start_m).norm());
      OGRLineString ls;
      ls.addPoint(a.lon_deg, a.lat_deg);
      ls.addPoint(b.lon_deg, b.lat_deg);
      f.SetGeometry(&ls);
      create_feature(ll, f, path);
    }
  }
  {
    OGRFeature f(lt->GetLayerDefn());
    for (const auto& s : trajectory) {
      const Eigen::Vector2d xy = frame.to_local(s.lat_deg, s.lon_deg);
      f.SetFID(OGRNullFID);
      f.SetField("time_s", s.time_s);
      f.SetField("yaw_enu_rad", s.yaw_enu_rad);
      f.SetField("speed_mps", s.speed_mps);
      f.SetField("yaw_rate_rps", s.yaw_rate_rps);
      f.SetField("std_east_m", static_cast<double>(s.std_east_m));
      f.SetField("std_north_m", static_cast<double>(s.std_north_m));
      f.SetField("std_yaw_rad", static_cast<double>(s.std_yaw_rad));
      f.SetField("solution", std::string(to_string(s.solution)).c_str());
      f.SetField("x_m", xy.x());
      f.SetField("y_m", xy.y());
      OGRPoint pt(s.lon_deg, s.lat_deg);
      f.SetGeometry(&pt);
      create_feature(lt, f, path);
    }
  }
  if (ds->CommitTransaction() != OGRERR_NONE) {
    throw IoError(path + ": cannot commit: " + capture.last_message());
  }
  GDALDataset* raw = ds.release();
  CPLErrorReset();
  GDALClose(raw);
  if (CPLGetLastErrorType() >= CE_Failure) {
    throw IoError(path + ": cannot finish GeoPackage: " + capture.last_message());
  }
}

}  // namespace detail

// ------------------------------------------------------------------------ writer

namespace {

using detail::GridmapTiffSpec;

PackageFileEntry file_entry(const fs::path& dir, const char* name) {
  const std::string bytes = detail::read_file_bytes(dir / name);
  return {name, bytes.size(), sha256_hex(bytes)};
}

void check_empty_or_absent(const fs::path& dir, bool overwrite) {
  std::error_code ec;
  if (!fs::exists(dir, ec)) return;
  if (!fs::is_directory(dir, ec)) {
    throw IoError(dir.string() + ": exists and is not a directory");
  }
  if (!overwrite && !fs::is_empty(dir, ec)) {
    throw IoError(dir.string() + ": exists and is not empty (overwrite not requested)");
  }
}

/// ".NAME.SUFFIX" for temporary siblings of `dir` (appended piecewise: GCC 12 warns
/// falsely on `"." + string`).
std::string hidden_stem(const fs::path& dir, const char* suffix) {
  std::string stem(1, '.');
  stem += dir.filename().string();
  stem += suffix;
  return stem;
}

/// Moves the finished temporary directory into place (replacing `dir`).
void commit_dir(const fs::path& tmp, const fs::path& dir) {
  std::error_code ec;
  if (fs::exists(dir, ec)) {
    const fs::path old = detail::make_unique_dir(dir.parent_path(), hidden_stem(dir, ".old"));
    fs::rename(dir, old / "pkg", ec);
    if (ec) throw IoError(dir.string() + ": cannot replace: " + ec.message());
    fs::rename(tmp, dir, ec);
    if (ec) throw IoError(dir.string() + ": cannot move package into place: " + ec.message());
    fs::remove_all(old, ec);
    return;
  }
  fs::rename(tmp, dir, ec);
  if (ec) throw IoError(dir.string() + ": cannot move package into place: " + ec.message());
}

fs::path parent_for_temp(const fs::path& dir) {
  fs::path parent = fs::absolute(dir).parent_path();
  std::error_code ec;
  fs::create_directories(parent, ec);
  if (ec) throw IoError(parent.string() + ": cannot create: " + ec.message());
  return parent;
}

}  // namespace

namespace detail {

void check_package_destination(const fs::path& dir, bool overwrite) {
  check_empty_or_absent(dir, overwrite);
}

fs::path make_package_temp_dir(const fs::path& dir) {
  return make_unique_dir(parent_for_temp(dir), hidden_stem(dir, ".tmp"));
}

/// Shared tail of both writers: the gridmap.tif is already in `tmp`; writes the
/// candidates, the manifest, validates, and moves `tmp` into place.
DriveManifest finish_package(DriveManifest m, const DrivePackage& values, const fs::path& tmp,
                             const fs::path& dir, const PackageWriteOptions& options) {
  const tiles::LocalFrame frame(m.origin);
  write_candidates_gpkg((tmp / kCandidatesFileName).string(), frame, values.points, values.lines,
                        values.trajectory);
  m.format_version = kDrivePackageFormatVersion;
  m.counts = {values.points.size(), values.lines.size(), values.trajectory.size()};
  m.files = {file_entry(tmp, kGridmapFileName), file_entry(tmp, kCandidatesFileName)};
  write_file_bytes(tmp / kManifestFileName, manifest_to_json(m).dump(2) + "\n");
  if (options.validate_after_write) (void)read_and_validate_package(tmp);
  commit_dir(tmp, dir);
  return m;
}

/// Common manifest preparation of both writers (drive metadata, CRS, producer).
DriveManifest prepare_manifest(DriveManifest m, const PackageWriteOptions& options) {
  const std::string frame_proj = tiles::LocalFrame(m.origin).proj_string();
  if (m.crs_proj.empty()) {
    m.crs_proj = frame_proj;
  } else if (!same_crs(m.crs_proj, frame_proj)) {
    throw ValidationError("write_drive_package: manifest.crs_proj '" + m.crs_proj +
                          "' is not the LocalFrame of manifest.origin");
  }
  if (!options.producer.empty()) m.producer = options.producer;
  return m;
}

std::vector<std::pair<std::string, std::string>> tiff_metadata(const DriveManifest& m) {
  return {{"POLMAP_FORMAT", "polmap.drive_package gridmap"},
          {"POLMAP_FORMAT_VERSION", std::to_string(kDrivePackageFormatVersion)},
          {"POLMAP_DRIVE_ID", m.drive_id},
          {"POLMAP_POL_LEVEL", std::string(to_string(m.pol_level))},
          {"POLMAP_BAND_1", "N: observation count (0 = no data)"},
          {"POLMAP_LAYERS", "covariance C = 1/N sum Omega Omega^H, upper triangle, row-major"},
          {"POLMAP_MANTISSA_BITS", std::to_string(m.gridmap.mantissa_bits)}};
}

}  // namespace detail

DriveManifest write_drive_package(const DrivePackage& pkg, const GridmapRaster& raster,
                                  const fs::path& dir, const PackageWriteOptions& options) {
  detail::ensure_gdal();
  DriveManifest m = detail::prepare_manifest(pkg.manifest, options);
  const int q = pol_dimension(m.pol_level);
  if (raster.q != q) {
    throw ValidationError("write_drive_package: raster q = " + std::to_string(raster.q) +
                          ", pol_level '" + std::string(to_string(m.pol_level)) + "' needs " +
                          std::to_string(q));
  }
  if (std::abs(raster.cell_size_m - m.cell_size_m) > 1e-9 * m.cell_size_m) {
    throw ValidationError(
        "write_drive_package: raster cell size differs from manifest.cell_size_m");
  }
  const std::size_t cells = static_cast<std::size_t>(std::max(raster.width, 0)) *
                            static_cast<std::size_t>(std::max(raster.height, 0));
  if (raster.width < 0 || raster.height < 0 || raster.count.size() != cells ||
      raster.layers.size() != static_cast<std::size_t>(raster.num_layers()) ||
      std::any_of(raster.layers.begin(), raster.layers.end(),
                  [&](const auto& l) { return l.size() != cells; })) {
    throw ValidationError(
        "write_drive_package: raster buffers do not match width x height x layers");
  }
  check_empty_or_absent(dir, options.overwrite);
  // An empty drive still gets a valid 1x1 raster (N = 0).
  GridmapRaster empty;
  const GridmapRaster* r = &raster;
  if (cells == 0) {
    empty = raster;
    empty.width = empty.height = 1;
    empty.count.assign(1, 0);
    empty.layers.assign(static_cast<std::size_t>(raster.num_layers()), std::vector<cdouble>(1));
    r = &empty;
  }
  m.gridmap = {r->width,
               r->height,
               r->origin_x_m,
               r->origin_y_m,
               1 + q * q,
               detail::kGridmapBlockSize,
               std::clamp(options.mantissa_bits, 1, 23)};

  const fs::path tmp = detail::make_unique_dir(parent_for_temp(dir), hidden_stem(dir, ".tmp"));
  try {
    GridmapTiffSpec spec;
    spec.width = r->width;
    spec.height = r->height;
    spec.origin_x_m = r->origin_x_m;
    spec.origin_y_m = r->origin_y_m;
    spec.cell_size_m = m.cell_size_m;
    spec.level = m.pol_level;
    spec.crs_proj = m.crs_proj;
    spec.deflate_level = options.deflate_level;
    spec.mantissa_bits = std::clamp(options.mantissa_bits, 1, 23);
    spec.metadata = detail::tiff_metadata(m);
    detail::write_gridmap_tiff(*r, spec, (tmp / kGridmapFileName).string());
    return detail::finish_package(std::move(m), pkg, tmp, dir, options);
  } catch (...) {
    std::error_code ec;
    fs::remove_all(tmp, ec);
    throw;
  }
}

// ------------------------------------------------------------------------ archive

std::string pack_drive_package(const fs::path& dir) {
  std::vector<TarMember> members;
  for (const char* name : {kManifestFileName, kGridmapFileName, kCandidatesFileName}) {
    members.push_back({name, detail::read_file_bytes(dir / name)});
  }
  return write_ustar(members);
}

void write_drive_package_archive(const fs::path& dir, const fs::path& tar_path) {
  // Streams the same bytes pack_drive_package returns (memory: one 1 MiB buffer).
  fs::path tmp = tar_path;
  tmp += ".tmp-" + std::to_string(::getpid());
  std::error_code ec;
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw IoError(tmp.string() + ": cannot open for writing");
    std::string buf(1 << 20, '\0');
    for (const char* name : {kManifestFileName, kGridmapFileName, kCandidatesFileName}) {
      const fs::path src = dir / name;
      const auto size = fs::file_size(src, ec);
      if (ec) throw IoError(src.string() + ": " + ec.message());
      out << ustar_header(name, size);
      std::ifstream in(src, std::ios::binary);
      if (!in) throw IoError(src.string() + ": cannot open for reading");
      std::uint64_t copied = 0;
      while (in) {
        in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
        const auto got = in.gcount();
        out.write(buf.data(), got);
        copied += static_cast<std::uint64_t>(got);
      }
      if (copied != size) throw IoError(src.string() + ": changed while being archived");
      out << std::string(ustar_padding(size), '\0');
    }
    out << std::string(kUstarEndBytes, '\0');
    out.flush();
    if (!out) {
      fs::remove(tmp, ec);
      throw IoError(tmp.string() + ": write failed");
    }
  }
  fs::rename(tmp, tar_path, ec);
  if (ec) {
    fs::remove(tmp, ec);
    throw IoError(tar_path.string() + ": cannot write: " + ec.message());
  }
}

namespace detail {
/// Parses the archive and checks the member set (exactly the three package files).
std::vector<TarMemberView> read_package_members(std::string_view tar_bytes) {
  std::vector<TarMemberView> members;
  try {
    members = read_ustar_views(tar_bytes, "archive");
  } catch (const FormatError& e) {
    // Re-throw as a package error naming the archive, keeping the byte offset.
    std::string msg = e.what();
    const std::string prefix = "archive at byte " + std::to_string(e.offset()) + ": ";
    if (msg.starts_with(prefix)) msg = msg.substr(prefix.size());
    throw PackageFormatError("archive", "", msg + " (at byte " + std::to_string(e.offset()) + ")");
  }
  const std::vector<std::string> expected{kManifestFileName, kGridmapFileName, kCandidatesFileName};
  for (const auto& mb : members) {
    if (std::find(expected.begin(), expected.end(), mb.name) == expected.end()) {
      throw PackageValidationError("archive", "", "unexpected member '" + mb.name + "'");
    }
  }
  for (const auto& name : expected) {
    if (std::none_of(members.begin(), members.end(),
                     [&](const TarMemberView& mb) { return mb.name == name; })) {
      throw PackageValidationError(name, "", "missing from the archive");
    }
  }
  return members;
}
}  // namespace detail

void unpack_drive_package(std::string_view tar_bytes, const fs::path& dir) {
  const auto members = detail::read_package_members(tar_bytes);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw IoError(dir.string() + ": cannot create: " + ec.message());
  if (!fs::is_empty(dir, ec)) throw IoError(dir.string() + ": not empty");
  for (const auto& mb : members) detail::write_file_bytes(dir / mb.name, mb.data);
}

fs::path unpack_drive_package_to_temp(std::string_view tar_bytes) {
  const auto members = detail::read_package_members(tar_bytes);
  const fs::path dir = detail::make_unique_dir({}, "polmap_pkg");
  try {
    for (const auto& mb : members) detail::write_file_bytes(dir / mb.name, mb.data);
  } catch (...) {
    std::error_code ec;
    fs::remove_all(dir, ec);
    throw;
  }
  return dir;
}

std::string package_member_gdal_path(const fs::path& location, const std::string& name) {
  std::error_code ec;
  if (fs::is_directory(location, ec)) return (location / name).string();
  return "/vsitar/" + location.string() + "/" + name;
}

}  // namespace polmap::mapping
