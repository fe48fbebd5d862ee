// Reading and whole-package validation of drive packages (directory, archive file, bytes).
#include <cpl_vsi.h>
#include <gdal_priv.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <map>
#include <optional>

#include "candidates_schema.hpp"
#include "gpkg_screen.hpp"
#include "package_internal.hpp"
#include "polmap/mapping_service/candidates_codec.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/schema/json.hpp"

namespace polmap::mapping {

namespace fs = std::filesystem;
using nlohmann::json;

namespace detail {
std::vector<TarMemberView> read_package_members(std::string_view tar_bytes);
}

namespace {

constexpr const char* kGpkg = "candidates.gpkg";
constexpr const char* kTif = "gridmap.tif";

// ------------------------------------------------------------------------ sources

/// The files of a package, wherever they are.
class PackageSource {
 public:
  virtual ~PackageSource() = default;
  [[nodiscard]] virtual bool has(const std::string& name) const = 0;
  /// The file's bytes; `storage` holds them when they must be read (directories).
  [[nodiscard]] virtual std::string_view bytes(const std::string& name,
                                               std::string& storage) const = 0;
  [[nodiscard]] virtual std::uint64_t size(const std::string& name) const = 0;
  /// Passes the file's bytes to fn in pieces (memory: one piece).
  virtual void for_each_chunk(const std::string& name,
                              const std::function<void(std::string_view)>& fn) const = 0;
  [[nodiscard]] virtual std::string gdal_path(const std::string& name) const = 0;
  /// Members that must all be accounted for (archives); directories may hold other files.
  [[nodiscard]] virtual std::vector<std::string> names() const { return {}; }
};

class DirSource final : public PackageSource {
 public:
  explicit DirSource(fs::path dir) : dir_(std::move(dir)) {}
  [[nodiscard]] bool has(const std::string& name) const override {
    std::error_code ec;
    return fs::is_regular_file(dir_ / name, ec);
  }
  [[nodiscard]] std::string_view bytes(const std::string& name,
                                       std::string& storage) const override {
    storage = detail::read_file_bytes(dir_ / name);
    return storage;
  }
  [[nodiscard]] std::uint64_t size(const std::string& name) const override {
    std::error_code ec;
    const auto n = fs::file_size(dir_ / name, ec);
    if (ec) throw IoError((dir_ / name).string() + ": " + ec.message());
    return n;
  }
  void for_each_chunk(const std::string& name,
                      const std::function<void(std::string_view)>& fn) const override {
    std::ifstream in(dir_ / name, std::ios::binary);
    if (!in) throw IoError((dir_ / name).string() + ": cannot open for reading");
    std::string buf(1 << 20, '\0');
    while (in) {
      in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
      const auto got = in.gcount();
      if (got > 0) fn(std::string_view(buf.data(), static_cast<std::size_t>(got)));
    }
    if (in.bad()) throw IoError((dir_ / name).string() + ": read failed");
  }
  [[nodiscard]] std::string gdal_path(const std::string& name) const override {
    return (dir_ / name).string();
  }

 private:
  fs::path dir_;
};

/// Archive members exposed to GDAL through /vsimem/ (no copies, no disk). The archive
/// bytes must outlive the source.
class MemSource final : public PackageSource {
 public:
  explicit MemSource(std::vector<TarMemberView> members) : members_(std::move(members)) {
    detail::ensure_gdal();
    static std::atomic<std::uint64_t> counter{0};
    prefix_ = "/vsimem/polmap_pkg_" + std::to_string(counter++) + "/";
    for (auto& m : members_) {
      // Read-only use: GDAL never writes through a buffer it does not own.
      VSILFILE* f = VSIFileFromMemBuffer((prefix_ + m.name).c_str(),
                                         reinterpret_cast<GByte*>(const_cast<char*>(m.data.data())),
                                         static_cast<vsi_l_offset>(m.data.size()), FALSE);
      if (f != nullptr) VSIFCloseL(f);
    }
  }
  ~MemSource() override {
    for (const auto& m : members_) VSIUnlink((prefix_ + m.name).c_str());
  }
  MemSource(const MemSource&) = delete;
  MemSource& operator=(const MemSource&) = delete;

  [[nodiscard]] bool has(const std::string& name) const override { return find(name) != nullptr; }
  [[nodiscard]] std::string_view bytes(const std::string& name,
                                       std::string& /*storage*/) const override {
    const TarMemberView* m = find(name);
    return m == nullptr ? std::string_view() : m->data;
  }
  [[nodiscard]] std::uint64_t size(const std::string& name) const override {
    const TarMemberView* m = find(name);
    return m == nullptr ? 0 : m->data.size();
  }
  void for_each_chunk(const std::string& name,
                      const std::function<void(std::string_view)>& fn) const override {
    const TarMemberView* m = find(name);
    if (m != nullptr) fn(m->data);
  }
  [[nodiscard]] std::string gdal_path(const std::string& name) const override {
    return prefix_ + name;
  }
  [[nodiscard]] std::vector<std::string> names() const override {
    std::vector<std::string> out;
    for (const auto& m : members_) out.push_back(m.name);
    return out;
  }

 private:
  [[nodiscard]] const TarMemberView* find(const std::string& name) const {
    for (const auto& m : members_) {
      if (m.name == name) return &m;
    }
    return nullptr;
  }
  std::vector<TarMemberView> members_;
  std::string prefix_;
};

[[noreturn]] void invalid(const std::string& file, const std::string& field,
                          const std::string& message) {
  throw PackageValidationError(file, field, message);
}

std::string fmt(double v) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.9g", v);
  return buf;
}

// ------------------------------------------------------------------------ GeoTIFF

/// True if no band stores block (bx, by): a sparse GeoTIFF block reads as zeros, which is
/// a valid unobserved block, so it needs no reading (a 1 MB file can declare 36 GB of
/// them; reading each would take minutes).
bool block_unwritten(GDALDataset& ds, int bx, int by) {
  const std::string item = "BLOCK_OFFSET_" + std::to_string(bx) + "_" + std::to_string(by);
  for (int b = 1; b <= ds.GetRasterCount(); ++b) {
    const char* offset = ds.GetRasterBand(b)->GetMetadataItem(item.c_str(), "TIFF");
    if (offset != nullptr && std::strtoull(offset, nullptr, 10) != 0) return false;
  }
  return true;
}

struct GridmapScan {
  std::uint64_t observed_cells = 0;
};

GDALDatasetUniquePtr open_raster(const std::string& path, const std::string& file) {
  detail::GdalErrorCapture capture;
  detail::ScopedGdalConfig no_pam("GDAL_PAM_ENABLED", "NO");
  const char* drivers[] = {"GTiff", nullptr};
  GDALDatasetUniquePtr ds(GDALDataset::FromHandle(
      GDALOpenEx(path.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY, drivers, nullptr, nullptr)));
  if (!ds) {
    throw PackageFormatError(file, "", "not a readable GeoTIFF (" + capture.last_message() + ")");
  }
  return ds;
}

/// Blocks are read into fixed 256 × 256 float buffers (detail::GridmapBlockBuffer): a band
/// must be Float32 in such tiles, checked by validation and again wherever blocks are read.
void check_band_storage(GDALRasterBand& band, const std::string& file, const std::string& bname,
                        bool compact) {
  const GDALDataType want = compact ? GDT_UInt16 : GDT_Float32;
  if (band.GetRasterDataType() != want) {
    invalid(file, bname,
            std::string("data type ") + GDALGetDataTypeName(band.GetRasterDataType()) +
                ", expected " + GDALGetDataTypeName(want));
  }
  int bx = 0, by = 0;
  band.GetBlockSize(&bx, &by);
  if (bx != detail::kGridmapBlockSize || by != detail::kGridmapBlockSize) {
    invalid(
        file, bname,
        "block size " + std::to_string(bx) + "x" + std::to_string(by) + ", expected 256x256 tiles");
  }
}

/// Reads block (bx, by) of a band into a float buffer (UInt16 codes convert exactly);
/// the band's type and block size were checked by check_band_storage.
CPLErr read_band_block(GDALRasterBand& band, int bx, int by, float* out, bool compact) {
  if (!compact) return band.ReadBlock(bx, by, out);
  constexpr std::size_t kCells = std::size_t{detail::kGridmapBlockSize} * detail::kGridmapBlockSize;
  // One buffer per thread: this runs for every band of every block (validation, builds).
  thread_local std::vector<std::uint16_t> codes(kCells);
  const CPLErr e = band.ReadBlock(bx, by, codes.data());
  for (std::size_t k = 0; k < kCells; ++k) out[k] = codes[k];
  return e;
}

GridmapScan validate_gridmap(const std::string& path, const DriveManifest& m,
                             const PackageValidationConfig& cfg, const util::Deadline& deadline) {
  auto ds = open_raster(path, kTif);
  const GridmapInfo& g = m.gridmap;
  if (ds->GetRasterXSize() != g.width) {
    invalid(kTif, "width",
            std::to_string(ds->GetRasterXSize()) + " columns, manifest.json says " +
                std::to_string(g.width));
  }
  if (ds->GetRasterYSize() != g.height) {
    invalid(kTif, "height",
            std::to_string(ds->GetRasterYSize()) + " rows, manifest.json says " +
                std::to_string(g.height));
  }
  if (static_cast<std::int64_t>(g.width) * g.height > cfg.max_raster_cells) {
    invalid(kTif, "width",
            "raster of " + std::to_string(g.width) + " x " + std::to_string(g.height) +
                " cells exceeds the limit");
  }
  const bool compact = g.compact;
  const auto names =
      compact ? compact_gridmap_band_names(m.pol_level) : gridmap_band_names(m.pol_level);
  if (ds->GetRasterCount() != static_cast<int>(names.size())) {
    invalid(kTif, "bands",
            "has " + std::to_string(ds->GetRasterCount()) + " bands, pol_level '" +
                std::string(to_string(m.pol_level)) + "' needs " + std::to_string(names.size()));
  }
  for (int b = 0; b < ds->GetRasterCount(); ++b) {
    GDALRasterBand* band = ds->GetRasterBand(b + 1);
    const std::string bname = "band " + std::to_string(b + 1);
    check_band_storage(*band, kTif, bname, compact);
    if (names[b] != band->GetDescription()) {
      invalid(
          kTif, bname,
          std::string("description '") + band->GetDescription() + "', expected '" + names[b] + "'");
    }
  }
  double gt[6];
  if (ds->GetGeoTransform(gt) != CE_None) invalid(kTif, "geotransform", "missing");
  const double cs = m.cell_size_m;
  const double tol = 1e-6;
  if (std::abs(gt[1] - cs) > tol || std::abs(gt[5] + cs) > tol || gt[2] != 0.0 || gt[4] != 0.0) {
    invalid(kTif, "geotransform",
            "pixel size (" + fmt(gt[1]) + ", " + fmt(gt[5]) + ") rotation (" + fmt(gt[2]) + ", " +
                fmt(gt[4]) + "), expected north-up (" + fmt(cs) + ", " + fmt(-cs) + ")");
  }
  if (std::abs(gt[0] - g.origin_x_m) > tol || std::abs(gt[3] - g.origin_y_m) > tol) {
    invalid(kTif, "geotransform",
            "origin (" + fmt(gt[0]) + ", " + fmt(gt[3]) + "), manifest.json gridmap says (" +
                fmt(g.origin_x_m) + ", " + fmt(g.origin_y_m) + ")");
  }
  if (std::abs(g.origin_x_m) > cfg.max_abs_coordinate_m ||
      std::abs(g.origin_y_m) > cfg.max_abs_coordinate_m ||
      std::abs(g.origin_x_m + g.width * cs) > cfg.max_abs_coordinate_m ||
      std::abs(g.origin_y_m - g.height * cs) > cfg.max_abs_coordinate_m) {
    invalid(kTif, "geotransform",
            "extent reaches beyond " + fmt(cfg.max_abs_coordinate_m) + " m from the drive origin");
  }
  const OGRSpatialReference* srs = ds->GetSpatialRef();
  if (srs == nullptr) invalid(kTif, "crs", "missing");
  {
    // The canonical string of the validated origin, never the manifest's text.
    OGRSpatialReference expected;
    expected.importFromProj4(tiles::LocalFrame(m.origin).proj_string().c_str());
    if (!srs->IsSame(&expected)) {
      char* proj = nullptr;
      srs->exportToProj4(&proj);
      const std::string got = proj != nullptr ? proj : "?";
      CPLFree(proj);
      invalid(kTif, "crs", "'" + got + "' is not manifest.json crs_proj '" + m.crs_proj + "'");
    }
  }

  GridmapScan scan;
  if (!cfg.check_gridmap_values) return scan;
  const int q = pol_dimension(m.pol_level);
  const int nb = ds->GetRasterCount();
  detail::GridmapBlockBuffer block(nb);
  const int bs = detail::kGridmapBlockSize;
  const int nbx = (g.width + bs - 1) / bs;
  const int nby = (g.height + bs - 1) / bs;
  detail::GdalErrorCapture capture;
  // Band index of diagonal element i and of the (re, im) pair of (i, j).
  std::vector<int> diag(q);
  std::vector<std::vector<int>> off(q, std::vector<int>(q, -1));
  {
    int band = 1;
    for (int i = 0; i < q; ++i) {
      for (int j = i; j < q; ++j) {
        if (i == j) {
          diag[i] = band++;
        } else {
          off[i][j] = band;
          band += 2;
        }
      }
    }
  }
  std::optional<GridmapCodec> codec;
  if (compact) codec.emplace(q, g.noise_power, g.codec);
  std::vector<std::uint16_t> cell_codes(static_cast<std::size_t>(nb));
  // Float rounding of the sums, plus the writer's mantissa rounding of each factor.
  const double cs_tolerance = 1.0 + 1e-3 + 8.0 * std::ldexp(1.0, -g.mantissa_bits);
  for (int by = 0; by < nby; ++by) {
    for (int bx = 0; bx < nbx; ++bx) {
      if (deadline.expired()) detail::budget_exceeded(kTif, deadline.budget_s());
      if (block_unwritten(*ds, bx, by)) continue;
      for (int b = 0; b < nb; ++b) {
        if (read_band_block(*ds->GetRasterBand(b + 1), bx, by, block.band(b), compact) != CE_None) {
          throw PackageFormatError(kTif, names[b],
                                   "cannot read block (" + std::to_string(bx) + ", " +
                                       std::to_string(by) + "): " + capture.last_message());
        }
      }
      const int cols = std::min(bs, g.width - bx * bs);
      const int rows = std::min(bs, g.height - by * bs);
      if (compact) {
        for (int r = 0; r < rows; ++r) {
          for (int c = 0; c < cols; ++c) {
            const std::size_t k = static_cast<std::size_t>(r) * bs + c;
            for (int b = 0; b < nb; ++b)
              cell_codes[b] = static_cast<std::uint16_t>(block.band(b)[k]);
            if (!codec->valid_codes(cell_codes)) {
              invalid(kTif, "codes",
                      "inconsistent cell codes at column " + std::to_string(bx * bs + c) + " row " +
                          std::to_string(by * bs + r) +
                          " (N = 0 with data, hits > N, or a code out of range)");
            }
            if (cell_codes[0] > 0) ++scan.observed_cells;
          }
        }
        continue;
      }
      for (int r = 0; r < rows; ++r) {
        for (int c = 0; c < cols; ++c) {
          const std::size_t k = static_cast<std::size_t>(r) * bs + c;
          const auto where = [&] {
            return "at column " + std::to_string(bx * bs + c) + " row " +
                   std::to_string(by * bs + r);
          };
          const float n = block.band(0)[k];
          if (!std::isfinite(n) || n < 0.0F || n != std::floor(n)) {
            invalid(kTif, "N",
                    "count " + fmt(n) + " " + where() + " is not a non-negative integer");
          }
          for (int b = 1; b < nb; ++b) {
            const float v = block.band(b)[k];
            if (!std::isfinite(v)) invalid(kTif, names[b], "non-finite value " + where());
            if (n == 0.0F && v != 0.0F) {
              invalid(kTif, names[b], "value " + fmt(v) + " " + where() + " where N = 0");
            }
          }
          if (n == 0.0F) continue;
          ++scan.observed_cells;
          for (int i = 0; i < q; ++i) {
            const float cii = block.band(diag[i])[k];
            if (cii < 0.0F) {
              invalid(kTif, names[diag[i]], "negative power " + fmt(cii) + " " + where());
            }
            for (int j = i + 1; j < q; ++j) {
              // A covariance matrix obeys |C_ij|^2 <= C_ii C_jj (float rounding allowed).
              const double re = block.band(off[i][j])[k];
              const double im = block.band(off[i][j] + 1)[k];
              const double bound = static_cast<double>(cii) * block.band(diag[j])[k];
              if (re * re + im * im > bound * cs_tolerance + 1e-30) {
                invalid(kTif, names[off[i][j]],
                        "|C_ij|^2 exceeds C_ii C_jj " + where() + " (not a covariance)");
              }
            }
          }
        }
      }
    }
  }
  return scan;
}

// ------------------------------------------------------------------------ GeoPackage

OGRLayer* require_layer(GDALDataset& ds, const detail::GpkgLayerSchema& schema) {
  const char* name = schema.name;
  const OGRwkbGeometryType geom = schema.geometry;
  OGRLayer* layer = ds.GetLayerByName(name);
  if (layer == nullptr) invalid(kGpkg, name, "layer missing");
  if (wkbFlatten(layer->GetGeomType()) != geom) {
    invalid(kGpkg, name,
            std::string("geometry type ") + OGRGeometryTypeToName(layer->GetGeomType()) +
                ", expected " + OGRGeometryTypeToName(geom));
  }
  const OGRSpatialReference* srs = layer->GetSpatialRef();
  OGRSpatialReference wgs84;
  wgs84.importFromEPSG(4326);
  const char* const ignore_axis[] = {"IGNORE_DATA_AXIS_TO_SRS_AXIS_MAPPING=YES", nullptr};
  if (srs == nullptr || !srs->IsSame(&wgs84, ignore_axis)) {
    invalid(kGpkg, name, "SRS is not WGS84 (EPSG:4326)");
  }
  OGRFeatureDefn* defn = layer->GetLayerDefn();
  for (const auto& f : schema.fields) {
    const int idx = defn->GetFieldIndex(f.name);
    if (idx < 0) invalid(kGpkg, std::string(name) + "." + f.name, "field missing");
    const OGRFieldType t = defn->GetFieldDefn(idx)->GetType();
    const bool ok = t == f.type || (f.type == OFTInteger64 && t == OFTInteger);
    if (!ok) {
      invalid(kGpkg, std::string(name) + "." + f.name,
              std::string("type ") + OGRFieldDefn::GetFieldTypeName(t) + ", expected " +
                  OGRFieldDefn::GetFieldTypeName(f.type));
    }
  }
  return layer;
}

/// Reads one feature's fields with per-field error messages.
class FeatureReader {
 public:
  FeatureReader(const char* layer, const OGRFeature& f, std::uint64_t index)
      : layer_(layer), f_(f), index_(index) {}
  [[nodiscard]] std::string field_path(const char* name) const {
    return std::string(layer_) + "." + name;
  }
  [[nodiscard]] std::string where() const { return "feature " + std::to_string(index_); }
  [[nodiscard]] double real(const char* name) const {
    const int idx = f_.GetFieldIndex(name);
    if (!f_.IsFieldSetAndNotNull(idx)) invalid(kGpkg, field_path(name), where() + ": null");
    const double v = f_.GetFieldAsDouble(idx);
    if (!std::isfinite(v)) invalid(kGpkg, field_path(name), where() + ": not finite");
    return v;
  }
  [[nodiscard]] double coordinate(const char* name, double limit) const {
    const double v = real(name);
    if (std::abs(v) > limit) {
      invalid(
          kGpkg, field_path(name),
          where() + ": " + fmt(v) + " m is more than " + fmt(limit) + " m from the drive origin");
    }
    return v;
  }
  [[nodiscard]] std::int64_t integer(const char* name) const {
    const int idx = f_.GetFieldIndex(name);
    if (!f_.IsFieldSetAndNotNull(idx)) invalid(kGpkg, field_path(name), where() + ": null");
    return f_.GetFieldAsInteger64(idx);
  }
  [[nodiscard]] std::string string(const char* name) const {
    const int idx = f_.GetFieldIndex(name);
    if (!f_.IsFieldSetAndNotNull(idx)) invalid(kGpkg, field_path(name), where() + ": null");
    return f_.GetFieldAsString(idx);
  }
  /// Checks a WGS84 vertex: finite, in range, and at the drive-frame position (x, y).
  void check_vertex(double lon, double lat, const Eigen::Vector2d& xy,
                    const tiles::LocalFrame& frame, const char* xfield) const {
    const std::string geom = std::string(layer_) + ".geom";
    if (!std::isfinite(lon) || !std::isfinite(lat)) {
      invalid(kGpkg, geom, where() + ": non-finite coordinate");
    }
    if (std::abs(lat) > 90.0 || std::abs(lon) > 180.0) {
      invalid(kGpkg, geom, where() + ": (" + fmt(lon) + ", " + fmt(lat) + ") outside WGS84 range");
    }
    const Eigen::Vector2d p = frame.to_local(lat, lon);
    if ((p - xy).norm() > 0.05) {
      invalid(kGpkg, field_path(xfield),
              where() + ": geometry lies " + fmt((p - xy).norm()) +
                  " m from the drive-frame position (x, y)");
    }
  }

 private:
  const char* layer_;
  const OGRFeature& f_;
  std::uint64_t index_;
};

std::optional<ScatteringClass> parse_scattering(const std::string& s) {
  for (auto c : {ScatteringClass::Unknown, ScatteringClass::Odd, ScatteringClass::Even,
                 ScatteringClass::Mixed}) {
    if (to_string(c) == s) return c;
  }
  return std::nullopt;
}

std::optional<GnssSolution> parse_solution(const std::string& s) {
  for (auto c : {GnssSolution::CarrierPhaseFixed, GnssSolution::CarrierPhaseFloat,
                 GnssSolution::Standalone}) {
    if (to_string(c) == s) return c;
  }
  return std::nullopt;
}

/// Counts the layer's features by reading them, stopping past `limit`: the count in
/// gpkg_ogr_contents (what GetFeatureCount returns) is the uploader's claim, not a fact.
void check_count(const char* layer, OGRLayer* l, std::uint64_t expected, std::uint64_t limit,
                 const util::Deadline& deadline) {
  std::uint64_t n = 0;
  l->ResetReading();
  while (OGRFeature* f = l->GetNextFeature()) {
    OGRFeature::DestroyFeature(f);
    if (n % 4096 == 0 && deadline.expired()) detail::budget_exceeded(kGpkg, deadline.budget_s());
    if (++n > limit) {
      invalid(kGpkg, layer,
              "more than " + std::to_string(limit) + " features (the plausible maximum)");
    }
  }
  if (n != expected) {
    invalid(kGpkg, layer,
            std::to_string(n) + " features, manifest.json counts say " + std::to_string(expected));
  }
}

void read_candidates(const std::string& path, const DriveManifest& m,
                     const PackageValidationConfig& cfg, const GridmapScan& scan,
                     const util::Deadline& deadline, DrivePackage& out) {
  detail::GdalErrorCapture capture;
  const char* drivers[] = {"GPKG", nullptr};
  GDALDatasetUniquePtr ds(GDALDataset::FromHandle(
      GDALOpenEx(path.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY, drivers, nullptr, nullptr)));
  if (!ds) {
    throw PackageFormatError(kGpkg, "",
                             "not a readable GeoPackage (" + capture.last_message() + ")");
  }
  const tiles::LocalFrame frame(m.origin);
  const double lim = cfg.max_abs_coordinate_m;
  const GridmapInfo& g = m.gridmap;
  const double margin = cfg.extent_margin_m;
  const auto inside_gridmap = [&](const Eigen::Vector2d& p) {
    return p.x() >= g.origin_x_m - margin &&
           p.x() <= g.origin_x_m + g.width * m.cell_size_m + margin &&
           p.y() <= g.origin_y_m + margin &&
           p.y() >= g.origin_y_m - g.height * m.cell_size_m - margin;
  };

  OGRLayer* lp = require_layer(*ds, detail::kPointsLayer);
  OGRLayer* ll = require_layer(*ds, detail::kLinesLayer);
  OGRLayer* lt = require_layer(*ds, detail::kTrajectoryLayer);
  std::uint64_t max_points = cfg.max_points;
  if (cfg.check_gridmap_values) max_points = std::min(max_points, scan.observed_cells);
  check_count("points", lp, m.counts.points, max_points, deadline);
  check_count("lines", ll, m.counts.lines, cfg.max_lines, deadline);
  check_count("trajectory", lt, m.counts.trajectory_samples, cfg.max_trajectory_samples, deadline);
  if (m.counts.trajectory_samples < 2) {
    invalid(kGpkg, "trajectory", "fewer than 2 samples");
  }

  std::uint64_t i = 0;
  lp->ResetReading();
  for (auto& feat : *lp) {
    if ((i & 4095) == 0 && deadline.expired()) detail::budget_exceeded(kGpkg, deadline.budget_s());
    const FeatureReader r("points", *feat, i++);
    PointCandidate p;
    p.position_m = {r.coordinate("x_m", lim), r.coordinate("y_m", lim)};
    p.strength = r.real("strength");
    p.power_db = r.real("power_db");
    const auto sc = parse_scattering(r.string("scattering"));
    if (!sc) {
      invalid(kGpkg, "points.scattering",
              r.where() + ": unknown class '" + r.string("scattering") +
                  "' (expected unknown, odd, even, mixed)");
    }
    p.scattering = *sc;
    const std::int64_t nc = r.integer("num_cells");
    if (nc < 0 || nc > 100'000'000) {
      invalid(kGpkg, "points.num_cells", r.where() + ": " + std::to_string(nc) + " out of range");
    }
    p.num_cells = static_cast<std::uint32_t>(nc);
    const OGRGeometry* geom = feat->GetGeometryRef();
    if (geom == nullptr || wkbFlatten(geom->getGeometryType()) != wkbPoint) {
      invalid(kGpkg, "points.geom", r.where() + ": missing or not a point");
    }
    const auto* pt = geom->toPoint();
    r.check_vertex(pt->getX(), pt->getY(), p.position_m, frame, "x_m");
    if (!inside_gridmap(p.position_m)) {
      invalid(kGpkg, "points.x_m",
              r.where() + ": (" + fmt(p.position_m.x()) + ", " + fmt(p.position_m.y()) +
                  ") outside the gridmap extent");
    }
    out.points.push_back(p);
  }
  i = 0;
  ll->ResetReading();
  for (auto& feat : *ll) {
    if ((i & 4095) == 0 && deadline.expired()) detail::budget_exceeded(kGpkg, deadline.budget_s());
    const FeatureReader r("lines", *feat, i++);
    LineCandidate l;
    l.start_m = {r.coordinate("x0_m", lim), r.coordinate("y0_m", lim)};
    l.end_m = {r.coordinate("x1_m", lim), r.coordinate("y1_m", lim)};
    l.strength = r.real("strength");
    const OGRGeometry* geom = feat->GetGeometryRef();
    if (geom == nullptr || wkbFlatten(geom->getGeometryType()) != wkbLineString ||
        geom->toLineString()->getNumPoints() != 2) {
      invalid(kGpkg, "lines.geom", r.where() + ": missing or not a 2-point line string");
    }
    const auto* ls = geom->toLineString();
    r.check_vertex(ls->getX(0), ls->getY(0), l.start_m, frame, "x0_m");
    r.check_vertex(ls->getX(1), ls->getY(1), l.end_m, frame, "x1_m");
    if (!inside_gridmap(l.start_m) || !inside_gridmap(l.end_m)) {
      invalid(kGpkg, "lines.x0_m", r.where() + ": end point outside the gridmap extent");
    }
    out.lines.push_back(l);
  }
  i = 0;
  lt->ResetReading();
  for (auto& feat : *lt) {
    if ((i & 4095) == 0 && deadline.expired()) detail::budget_exceeded(kGpkg, deadline.budget_s());
    const FeatureReader r("trajectory", *feat, i++);
    TrajectorySample s;
    s.time_s = r.real("time_s");
    s.yaw_enu_rad = r.real("yaw_enu_rad");
    s.speed_mps = r.real("speed_mps");
    s.yaw_rate_rps = r.real("yaw_rate_rps");
    s.std_east_m = static_cast<float>(r.real("std_east_m"));
    s.std_north_m = static_cast<float>(r.real("std_north_m"));
    s.std_yaw_rad = static_cast<float>(r.real("std_yaw_rad"));
    if (std::abs(s.speed_mps) > cfg.max_speed_mps) {
      invalid(kGpkg, "trajectory.speed_mps",
              r.where() + ": " + fmt(s.speed_mps) + " m/s implausible");
    }
    if (s.std_east_m < 0 || s.std_north_m < 0 || s.std_yaw_rad < 0) {
      invalid(kGpkg, "trajectory.std_east_m", r.where() + ": negative standard deviation");
    }
    // Finite as a double but not as the float it is kept in (found by fuzz_package).
    if (!std::isfinite(s.std_east_m) || !std::isfinite(s.std_north_m) ||
        !std::isfinite(s.std_yaw_rad)) {
      invalid(kGpkg, "trajectory.std_east_m",
              r.where() + ": standard deviation beyond the float range");
    }
    const auto sol = parse_solution(r.string("solution"));
    if (!sol) {
      invalid(kGpkg, "trajectory.solution",
              r.where() + ": unknown solution '" + r.string("solution") + "'");
    }
    s.solution = *sol;
    const Eigen::Vector2d xy{r.coordinate("x_m", lim), r.coordinate("y_m", lim)};
    const OGRGeometry* geom = feat->GetGeometryRef();
    if (geom == nullptr || wkbFlatten(geom->getGeometryType()) != wkbPoint) {
      invalid(kGpkg, "trajectory.geom", r.where() + ": missing or not a point");
    }
    const auto* pt = geom->toPoint();
    r.check_vertex(pt->getX(), pt->getY(), xy, frame, "x_m");
    s.lon_deg = pt->getX();
    s.lat_deg = pt->getY();
    if (!out.trajectory.empty() && !(s.time_s > out.trajectory.back().time_s)) {
      invalid(kGpkg, "trajectory.time_s",
              r.where() + ": time " + fmt(s.time_s) + " s not after the previous sample (" +
                  fmt(out.trajectory.back().time_s) + " s)");
    }
    if (s.time_s < m.start_time_s - cfg.time_span_tolerance_s ||
        s.time_s > m.end_time_s + cfg.time_span_tolerance_s) {
      invalid(kGpkg, "trajectory.time_s",
              r.where() + ": time " + fmt(s.time_s) + " s outside the manifest time span");
    }
    out.trajectory.push_back(s);
  }
}

/// Format 2: decodes candidates.bin and applies the rules of the GeoPackage reader to the
/// values (counts, plausible coordinates, extent, trajectory order and span).
void read_candidates_bin(std::string_view bytes, const DriveManifest& m,
                         const PackageValidationConfig& cfg, const GridmapScan& scan,
                         DrivePackage& out) {
  constexpr const char* kBin = "candidates.bin";
  CandidatesDecodeLimits lim;
  lim.max_points = cfg.max_points;
  if (m.has_gridmap && cfg.check_gridmap_values) {
    lim.max_points = std::min(lim.max_points, scan.observed_cells);
  }
  lim.max_lines = cfg.max_lines;
  lim.max_trajectory_samples = cfg.max_trajectory_samples;
  CandidatesContent c = decode_candidates(bytes, lim);
  const auto count = [&](const char* layer, std::size_t got, std::uint64_t want) {
    if (got != want) {
      invalid(kBin, layer,
              std::to_string(got) + " features, manifest.json counts say " + std::to_string(want));
    }
  };
  count("points", c.points.size(), m.counts.points);
  count("lines", c.lines.size(), m.counts.lines);
  count("trajectory", c.trajectory.size(), m.counts.trajectory_samples);
  if (c.trajectory.size() < 2) invalid(kBin, "trajectory", "fewer than 2 samples");
  const double lim_m = cfg.max_abs_coordinate_m;
  const GridmapInfo& g = m.gridmap;
  const double margin = cfg.extent_margin_m;
  const auto check_xy = [&](const Eigen::Vector2d& p, const char* field, std::size_t i) {
    if (!(std::abs(p.x()) <= lim_m && std::abs(p.y()) <= lim_m)) {
      invalid(kBin, field,
              "feature " + std::to_string(i) + ": farther than " + fmt(lim_m) +
                  " m from the drive origin");
    }
    if (m.has_gridmap && !(p.x() >= g.origin_x_m - margin &&
                           p.x() <= g.origin_x_m + g.width * m.cell_size_m + margin &&
                           p.y() <= g.origin_y_m + margin &&
                           p.y() >= g.origin_y_m - g.height * m.cell_size_m - margin)) {
      invalid(kBin, field, "feature " + std::to_string(i) + ": outside the gridmap extent");
    }
  };
  for (std::size_t i = 0; i < c.points.size(); ++i) {
    check_xy(c.points[i].position_m, "points.x", i);
    if (c.points[i].num_cells > 100'000'000) invalid(kBin, "points.num_cells", "out of range");
  }
  for (std::size_t i = 0; i < c.lines.size(); ++i) {
    check_xy(c.lines[i].start_m, "lines.x0", i);
    check_xy(c.lines[i].end_m, "lines.x1", i);
  }
  const tiles::LocalFrame frame(m.origin);
  for (std::size_t i = 0; i < c.trajectory.size(); ++i) {
    const TrajectorySample& s = c.trajectory[i];
    const std::string where = "sample " + std::to_string(i);
    if (!(std::abs(s.lat_deg) <= 90.0 && std::abs(s.lon_deg) <= 180.0)) {
      invalid(kBin, "trajectory.lat", where + ": not a WGS84 position");
    }
    const Eigen::Vector2d xy = frame.to_local(s.lat_deg, s.lon_deg);
    if (!(xy.norm() <= lim_m)) {
      invalid(kBin, "trajectory.lat",
              where + ": farther than " + fmt(lim_m) + " m from the origin");
    }
    if (std::abs(s.speed_mps) > cfg.max_speed_mps) {
      invalid(kBin, "trajectory.speed", where + ": " + fmt(s.speed_mps) + " m/s implausible");
    }
    if (i > 0 && !(s.time_s > c.trajectory[i - 1].time_s)) {
      invalid(kBin, "trajectory.time", where + ": not after the previous sample");
    }
    if (s.time_s < m.start_time_s - cfg.time_span_tolerance_s ||
        s.time_s > m.end_time_s + cfg.time_span_tolerance_s) {
      invalid(kBin, "trajectory.time", where + ": outside the manifest time span");
    }
  }
  out.points = std::move(c.points);
  out.lines = std::move(c.lines);
  out.trajectory = std::move(c.trajectory);
}

// ------------------------------------------------------------------------ whole package

/// Validates everything; if `archive_hash` is given, feeds it the canonical archive
/// (members manifest, gridmap, candidates) while each file is read once.
DrivePackage validate(const PackageSource& src, const PackageValidationConfig& cfg,
                      detail::Sha256* archive_hash) {
  const util::Deadline deadline = util::Deadline::after_s(cfg.max_validation_s);
  if (!src.has(kManifestFileName)) invalid(kManifestFileName, "", "missing");
  if (src.size(kManifestFileName) > cfg.max_manifest_bytes) {
    invalid(
        kManifestFileName, "",
        "larger than " + std::to_string(cfg.max_manifest_bytes) + " bytes (the plausible maximum)");
  }
  std::string storage;
  json j;
  {
    const std::string_view manifest_bytes = src.bytes(kManifestFileName, storage);
    try {
      j = json::parse(manifest_bytes);
    } catch (const json::parse_error& e) {
      throw PackageFormatError(kManifestFileName, "",
                               "not valid JSON (byte " + std::to_string(e.byte) + ")");
    } catch (const json::exception& e) {  // e.g. out_of_range: a number overflow like 1e400
      throw PackageFormatError(kManifestFileName, "", std::string("not valid JSON: ") + e.what());
    }
    if (archive_hash != nullptr) {
      archive_hash->update(ustar_header(kManifestFileName, manifest_bytes.size()));
      archive_hash->update(manifest_bytes);
      archive_hash->update(std::string(ustar_padding(manifest_bytes.size()), '\0'));
    }
  }
  DrivePackage pkg;
  pkg.manifest = detail::manifest_from_json(j);
  const DriveManifest& m = pkg.manifest;
  for (std::size_t i = 0; i < m.files.size(); ++i) {
    const auto& f = m.files[i];
    if (!src.has(f.name)) invalid(f.name, "", "missing (listed in manifest.json files)");
    const std::uint64_t size = src.size(f.name);
    if (size != f.size_bytes) {
      invalid(f.name, "size_bytes",
              std::to_string(size) + " bytes, manifest.json files[" + std::to_string(i) +
                  "].size_bytes says " + std::to_string(f.size_bytes));
    }
    // One pass over the file feeds its own hash and the archive hash.
    detail::Sha256 file_hash;
    if (archive_hash != nullptr) archive_hash->update(ustar_header(f.name, size));
    std::uint64_t seen = 0;
    src.for_each_chunk(f.name, [&](std::string_view chunk) {
      seen += chunk.size();
      file_hash.update(chunk);
      if (archive_hash != nullptr) archive_hash->update(chunk);
    });
    if (seen != size) invalid(f.name, "size_bytes", "file changed while being read");
    if (archive_hash != nullptr) archive_hash->update(std::string(ustar_padding(size), '\0'));
    const std::string actual = file_hash.hex();
    if (actual != f.sha256) {
      invalid(f.name, "sha256",
              actual + " does not match manifest.json files[" + std::to_string(i) + "].sha256 " +
                  f.sha256);
    }
  }
  storage.clear();
  storage.shrink_to_fit();
  if (archive_hash != nullptr) archive_hash->update(std::string(kUstarEndBytes, '\0'));
  for (const std::string& name : src.names()) {
    if (name != kManifestFileName && std::none_of(m.files.begin(), m.files.end(),
                                                  [&](const auto& f) { return f.name == name; })) {
      invalid("archive", "", "member '" + name + "' is not listed in manifest.json files");
    }
  }
  GridmapScan scan;
  if (m.has_gridmap) scan = validate_gridmap(src.gdal_path(kTif), m, cfg, deadline);
  if (m.format_version >= 2) {
    read_candidates_bin(src.bytes(kCandidatesBinFileName, storage), m, cfg, scan, pkg);
    return pkg;
  }
  // SQLite screens the GeoPackage before GDAL may open it.
  detail::screen_candidates_gpkg(src.bytes(kGpkg, storage), deadline);
  storage.clear();
  storage.shrink_to_fit();
  read_candidates(src.gdal_path(kGpkg), m, cfg, scan, deadline, pkg);
  return pkg;
}

PackageError to_package_error(const std::exception& e) {
  if (const auto* pf = dynamic_cast<const PackageFormatError*>(&e)) return pf->error();
  if (const auto* pv = dynamic_cast<const PackageValidationError*>(&e)) return pv->error();
  if (dynamic_cast<const ValidationError*>(&e) != nullptr) return {"", "", e.what(), 422};
  return {"", "", e.what(), 400};
}

}  // namespace

DrivePackage read_and_validate_package(const fs::path& dir_or_tar,
                                       const PackageValidationConfig& cfg) {
  detail::ensure_gdal();
  std::error_code ec;
  if (fs::is_directory(dir_or_tar, ec)) {
    detail::Sha256 archive_hash;
    DrivePackage pkg = validate(DirSource(dir_or_tar), cfg, &archive_hash);
    pkg.location = dir_or_tar;
    pkg.content_sha256 = archive_hash.hex();
    return pkg;
  }
  if (!fs::is_regular_file(dir_or_tar, ec)) {
    throw IoError(dir_or_tar.string() + ": no such package (neither a directory nor a file)");
  }
  DrivePackage pkg = validate_package_bytes(detail::read_file_bytes(dir_or_tar), cfg);
  pkg.location = dir_or_tar;
  return pkg;
}

DrivePackage validate_package_bytes(std::string_view tar_bytes,
                                    const PackageValidationConfig& cfg) {
  const MemSource src(detail::read_package_members(tar_bytes));
  DrivePackage pkg = validate(src, cfg, nullptr);
  pkg.content_sha256 = sha256_hex(tar_bytes);
  return pkg;
}

std::expected<DrivePackage, PackageError> try_read_and_validate_package(
    const fs::path& dir_or_tar, const PackageValidationConfig& cfg) {
  try {
    return read_and_validate_package(dir_or_tar, cfg);
  } catch (const Error& e) {
    PackageError err = to_package_error(e);
    if (err.file.empty()) err.file = dir_or_tar.filename().string();
    return std::unexpected(std::move(err));
  }
}

std::expected<DrivePackage, PackageError> try_validate_package_bytes(
    std::string_view tar_bytes, const PackageValidationConfig& cfg) {
  try {
    return validate_package_bytes(tar_bytes, cfg);
  } catch (const Error& e) {
    PackageError err = to_package_error(e);
    if (err.file.empty()) err.file = "archive";
    return std::unexpected(std::move(err));
  }
}

// ------------------------------------------------------------------------ gridmap reading

namespace {

struct RasterLayout {
  int q = 0;
  double gt[6] = {0, 1, 0, 0, 0, -1};
  std::optional<GridmapCodec> codec;  ///< set for a compact (format 2) gridmap
  double noise_power = 0.0;
};

/// The layout of an opened gridmap; `info` (the validated manifest's) says whether it is
/// compact and how to decode it. Without it only format 1 files are read.
RasterLayout raster_layout(GDALDataset& ds, const std::string& file, const GridmapInfo* info) {
  RasterLayout l;
  const bool compact = info != nullptr && info->compact;
  const int fixed = compact ? 3 : 1;
  const int nb = ds.GetRasterCount();
  const int q = static_cast<int>(std::lround(std::sqrt(std::max(nb - fixed, 0))));
  if (q < 1 || q > 3 || fixed + q * q != nb) {
    invalid(file, "bands",
            std::to_string(nb) + " bands is not " + std::to_string(fixed) + " + q^2 for q in 1..3");
  }
  l.q = q;
  // Re-checked where the blocks are read, not only by the validation that admitted the file.
  for (int b = 1; b <= nb; ++b)
    check_band_storage(*ds.GetRasterBand(b), file, "band " + std::to_string(b), compact);
  if (ds.GetGeoTransform(l.gt) != CE_None) invalid(file, "geotransform", "missing");
  if (compact) {
    l.codec.emplace(q, info->noise_power, info->codec);
    l.noise_power = info->noise_power;
  }
  return l;
}

void block_to_raster(detail::GridmapBlockBuffer& block, const RasterLayout& l, int cols, int rows,
                     GridmapRaster& out, int col0, int row0) {
  const int bs = detail::kGridmapBlockSize;
  const int q = l.q;
  std::vector<std::uint16_t> codes(l.codec ? static_cast<std::size_t>(l.codec->codes_per_cell())
                                           : 0);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const std::size_t k = static_cast<std::size_t>(r) * bs + c;
      const std::size_t dst = static_cast<std::size_t>(row0 + r) * out.width + (col0 + c);
      if (l.codec) {
        for (std::size_t b = 0; b < codes.size(); ++b) {
          codes[b] = static_cast<std::uint16_t>(block.band(static_cast<int>(b))[k]);
        }
        // Re-checked here too: what is decoded is what validation admitted.
        if (!l.codec->valid_codes(codes)) {
          invalid(kTif, "codes", "inconsistent cell codes (the file changed after validation?)");
        }
        const GridmapCodec::Cell cell = l.codec->decode_cell(codes);
        out.count[dst] = cell.n;
        out.hits[dst] = cell.hits;
        for (int layer = 0; layer < q * (q + 1) / 2; ++layer)
          out.layers[layer][dst] = cell.layers[layer];
        continue;
      }
      out.count[dst] = static_cast<std::uint32_t>(std::max(0.0F, block.band(0)[k]));
      int band = 1;
      for (int i = 0; i < q; ++i) {
        for (int j = i; j < q; ++j) {
          auto& layer = out.layers[GridmapRaster::layer_index(q, i, j)];
          if (i == j) {
            layer[dst] = {block.band(band++)[k], 0.0};
          } else {
            layer[dst] = {block.band(band)[k], block.band(band + 1)[k]};
            band += 2;
          }
        }
      }
    }
  }
}

/// Reads all bands of block (bx, by); returns false if the N band is all zero.
bool read_block(GDALDataset& ds, int bx, int by, detail::GridmapBlockBuffer& block,
                const std::string& file, bool compact) {
  if (block_unwritten(ds, bx, by)) return false;
  detail::GdalErrorCapture capture;
  if (read_band_block(*ds.GetRasterBand(1), bx, by, block.band(0), compact) != CE_None) {
    throw PackageFormatError(file, "N", "cannot read block: " + capture.last_message());
  }
  const float* n = block.band(0);
  if (std::all_of(n, n + detail::kGridmapBlockSize * detail::kGridmapBlockSize,
                  [](float v) { return v == 0.0F; })) {
    return false;
  }
  for (int b = 1; b < ds.GetRasterCount(); ++b) {
    if (read_band_block(*ds.GetRasterBand(b + 1), bx, by, block.band(b), compact) != CE_None) {
      throw PackageFormatError(file, "band " + std::to_string(b + 1),
                               "cannot read block: " + capture.last_message());
    }
  }
  return true;
}

GridmapRaster empty_raster(const RasterLayout& l, int w, int h, double x0, double y0, double cs) {
  GridmapRaster r;
  r.q = l.q;
  r.width = w;
  r.height = h;
  r.origin_x_m = x0;
  r.origin_y_m = y0;
  r.cell_size_m = cs;
  r.noise_power = l.noise_power;
  const std::size_t cells = static_cast<std::size_t>(w) * h;
  r.count.assign(cells, 0);
  if (l.codec) r.hits.assign(cells, 0);
  r.layers.assign(static_cast<std::size_t>(l.q * (l.q + 1) / 2), std::vector<cdouble>(cells));
  return r;
}

GridmapRaster read_gridmap_file(const std::string& gdal_path, const GridmapInfo* info) {
  auto ds = open_raster(gdal_path, kTif);
  const RasterLayout l = raster_layout(*ds, kTif, info);
  GridmapRaster out =
      empty_raster(l, ds->GetRasterXSize(), ds->GetRasterYSize(), l.gt[0], l.gt[3], l.gt[1]);
  const int bs = detail::kGridmapBlockSize;
  detail::GridmapBlockBuffer block(ds->GetRasterCount());
  for (int by = 0; by * bs < out.height; ++by) {
    for (int bx = 0; bx * bs < out.width; ++bx) {
      if (!read_block(*ds, bx, by, block, kTif, l.codec.has_value())) continue;
      block_to_raster(block, l, std::min(bs, out.width - bx * bs),
                      std::min(bs, out.height - by * bs), out, bx * bs, by * bs);
    }
  }
  return out;
}

void require_gridmap(const DrivePackage& pkg, const char* what) {
  if (pkg.location.empty()) {
    throw NotFoundError(std::string(what) + ": the package has no location (validated from bytes)");
  }
  if (!pkg.manifest.has_gridmap) {
    throw NotFoundError(std::string(what) + ": the package has no gridmap (landmarks only)");
  }
}

}  // namespace

GridmapRaster read_gridmap(const std::string& gdal_path) {
  return read_gridmap_file(gdal_path, nullptr);
}

GridmapRaster read_gridmap(const DrivePackage& pkg) {
  require_gridmap(pkg, "read_gridmap");
  return read_gridmap_file(package_member_gdal_path(pkg.location, kTif), &pkg.manifest.gridmap);
}

void for_each_gridmap_block(const DrivePackage& pkg,
                            const std::function<void(const GridmapRaster& block)>& fn) {
  if (pkg.location.empty()) {
    throw NotFoundError("for_each_gridmap_block: the package has no location");
  }
  if (!pkg.manifest.has_gridmap) return;  // landmarks only: no blocks
  auto ds = open_raster(package_member_gdal_path(pkg.location, kTif), kTif);
  const RasterLayout l = raster_layout(*ds, kTif, &pkg.manifest.gridmap);
  const int w = ds->GetRasterXSize();
  const int h = ds->GetRasterYSize();
  const int bs = detail::kGridmapBlockSize;
  const double cs = l.gt[1];
  detail::GridmapBlockBuffer block(ds->GetRasterCount());
  for (int by = 0; by * bs < h; ++by) {
    for (int bx = 0; bx * bs < w; ++bx) {
      if (!read_block(*ds, bx, by, block, kTif, l.codec.has_value())) continue;
      const int cols = std::min(bs, w - bx * bs);
      const int rows = std::min(bs, h - by * bs);
      GridmapRaster r =
          empty_raster(l, cols, rows, l.gt[0] + bx * bs * cs, l.gt[3] - by * bs * cs, cs);
      block_to_raster(block, l, cols, rows, r, 0, 0);
      fn(r);
    }
  }
}

}  // namespace polmap::mapping
