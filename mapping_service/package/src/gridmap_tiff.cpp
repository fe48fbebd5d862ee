// Gridmap GeoTIFF writer and GDAL plumbing shared by the package, export and validation code.
#include <gdal_priv.h>
#include <ogr_spatialref.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <map>
#include <mutex>
#include <set>

#include "package_internal.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::mapping {

std::vector<std::string> pol_component_names(PolLevel level) {
  switch (level) {
    case PolLevel::Full:
      return {"LL", "LR", "RR"};
    case PolLevel::DualLLLR:
      return {"LL", "LR"};
    case PolLevel::DualHHVV:
      return {"HH", "VV"};
    case PolLevel::SingleLR:
      return {"LR"};
    case PolLevel::SingleRR:
      return {"RR"};
    case PolLevel::SingleHH:
      return {"HH"};
  }
  return {};
}

std::vector<std::string> gridmap_band_names(PolLevel level) {
  const auto comps = pol_component_names(level);
  const int q = static_cast<int>(comps.size());
  std::vector<std::string> names{"N"};
  for (int i = 0; i < q; ++i) {
    for (int j = i; j < q; ++j) {
      const std::string base = "C_" + comps[i] + "_" + comps[j];
      if (i == j) {
        names.push_back(base);
      } else {
        names.push_back(base + ".re");
        names.push_back(base + ".im");
      }
    }
  }
  return names;
}

std::vector<std::string> compact_gridmap_band_names(PolLevel level) {
  std::vector<std::string> names = gridmap_band_names(level);
  for (std::size_t i = 1; i < names.size(); ++i) names[i][0] = 'U';  // C_A_B -> U_A_B
  names.insert(names.begin() + 1, {"hits", "P"});
  return names;
}

namespace detail {

void ensure_gdal() {
  static std::once_flag once;
  std::call_once(once, [] {
    GDALAllRegister();
    // GDAL's raster block cache defaults to 5 % of physical memory (1.2 GB on a 24 GiB
    // machine), which a long-running server fills with gridmap blocks of map builds.
    // GDAL_CACHEMAX in the environment still wins.
    if (CPLGetConfigOption("GDAL_CACHEMAX", nullptr) == nullptr) {
      GDALSetCacheMax64(kDefaultGdalCacheBytes);
    }
  });
}

GdalErrorCapture::GdalErrorCapture() {
  ensure_gdal();
  CPLPushErrorHandlerEx(
      [](CPLErr eclass, CPLErrorNum code, const char* msg) {
        GdalErrorCapture::handler(static_cast<int>(eclass), code, msg);
      },
      this);
  CPLErrorReset();
}
GdalErrorCapture::~GdalErrorCapture() { CPLPopErrorHandler(); }

void GdalErrorCapture::handler(int eclass, int /*code*/, const char* msg) {
  auto* self = static_cast<GdalErrorCapture*>(CPLGetErrorHandlerUserData());
  if (self != nullptr && eclass >= CE_Failure && msg != nullptr) self->message_ = msg;
}

std::string GdalErrorCapture::last_message() const {
  if (!message_.empty()) return message_;
  const char* m = CPLGetLastErrorMsg();
  return (m != nullptr && *m != '\0') ? std::string(m) : std::string("unknown GDAL error");
}

ScopedGdalConfig::ScopedGdalConfig(const char* key, const char* value) : key_(key) {
  const char* old = CPLGetThreadLocalConfigOption(key, nullptr);
  if (old != nullptr) {
    had_old_ = true;
    old_ = old;
  }
  CPLSetThreadLocalConfigOption(key, value);
}
ScopedGdalConfig::~ScopedGdalConfig() {
  CPLSetThreadLocalConfigOption(key_.c_str(), had_old_ ? old_.c_str() : nullptr);
}

bool is_local_frame_proj(std::string_view proj, const GeoPoint& origin) {
  if (proj.size() > 512) return false;
  // The terms of LocalFrame::proj_string(); lat_0/lon_0 are compared as numbers.
  std::map<std::string, std::string, std::less<>> want{
      {"proj", "tmerc"}, {"lat_0", ""},      {"lon_0", ""},  {"k", "1"},     {"x_0", "0"},
      {"y_0", "0"},      {"ellps", "WGS84"}, {"units", "m"}, {"no_defs", ""}};
  std::set<std::string, std::less<>> seen;
  std::size_t i = 0;
  while (i < proj.size()) {
    if (proj[i] == ' ') {
      ++i;
      continue;
    }
    const std::size_t end = std::min(proj.find(' ', i), proj.size());
    const std::string_view term = proj.substr(i, end - i);
    i = end;
    if (term.size() < 2 || term[0] != '+') return false;
    const std::size_t eq = term.find('=');
    const std::string_view key = term.substr(1, eq == std::string_view::npos ? term.npos : eq - 1);
    const std::string_view value = eq == std::string_view::npos ? "" : term.substr(eq + 1);
    const auto it = want.find(key);
    if (it == want.end() || !seen.insert(std::string(key)).second) return false;
    if (key == "lat_0" || key == "lon_0") {
      double v = 0.0;
      const auto [ptr, ec] = std::from_chars(value.data(), value.data() + value.size(), v);
      if (ec != std::errc() || ptr != value.data() + value.size()) return false;
      const double expected = key == "lat_0" ? origin.lat_deg : origin.lon_deg;
      if (!(std::abs(v - expected) <= 1e-9)) return false;
    } else if (value != it->second || (key == "no_defs") != (eq == std::string_view::npos)) {
      return false;
    }
  }
  return seen.size() == want.size();
}

// ------------------------------------------------------------------------ writer

GridmapTiffWriter::GridmapTiffWriter(const std::string& path, const GridmapTiffSpec& spec)
    : path_(path), spec_(spec) {
  ensure_gdal();
  POLMAP_EXPECT(spec.width > 0 && spec.height > 0 && spec.cell_size_m > 0);
  const int q = pol_dimension(spec.level);
  num_bands_ = (spec.compact ? 3 : 1) + q * q;
  const auto names =
      spec.compact ? compact_gridmap_band_names(spec.level) : gridmap_band_names(spec.level);
  POLMAP_EXPECT(static_cast<int>(names.size()) == num_bands_);

  GdalErrorCapture capture;
  // No .aux.xml side files: everything must live inside the TIFF.
  ScopedGdalConfig no_pam("GDAL_PAM_ENABLED", "NO");
  GDALDriver* drv = GetGDALDriverManager()->GetDriverByName("GTiff");
  if (drv == nullptr) throw IoError("GDAL has no GTiff driver");
  const std::string zlevel = "ZLEVEL=" + std::to_string(std::clamp(spec.deflate_level, 1, 9));
  const std::string bx = "BLOCKXSIZE=" + std::to_string(kGridmapBlockSize);
  const std::string by = "BLOCKYSIZE=" + std::to_string(kGridmapBlockSize);
  const std::string zstd = "ZSTD_LEVEL=" + std::to_string(std::clamp(spec.zstd_level, 1, 22));
  const char* float_opts[] = {"TILED=YES",           bx.c_str(),       by.c_str(),
                              "COMPRESS=DEFLATE",    zlevel.c_str(),   "PREDICTOR=3",
                              "INTERLEAVE=BAND",     "SPARSE_OK=TRUE", "BIGTIFF=IF_SAFER",
                              "GEOTIFF_VERSION=1.1", nullptr};
  // No predictor for the codes: most cells of a code band are 0 (empty, or no phase), and
  // horizontal differencing turns every isolated value into two (urban 1 km drive, full
  // level: 5.78 MB with PREDICTOR=2, 4.97 MB without; schema/drive_package.md).
  const char* code_opts[] = {"TILED=YES",           bx.c_str(),       by.c_str(),
                             "COMPRESS=ZSTD",       zstd.c_str(),     "PREDICTOR=1",
                             "INTERLEAVE=BAND",     "SPARSE_OK=TRUE", "BIGTIFF=IF_SAFER",
                             "GEOTIFF_VERSION=1.1", nullptr};
  ds_ = drv->Create(path.c_str(), spec.width, spec.height, num_bands_,
                    spec.compact ? GDT_UInt16 : GDT_Float32,
                    const_cast<char**>(spec.compact ? code_opts : float_opts));
  if (ds_ == nullptr) {
    throw IoError(path + ": cannot create GeoTIFF: " + capture.last_message());
  }
  double gt[6] = {spec.origin_x_m, spec.cell_size_m, 0.0, spec.origin_y_m, 0.0, -spec.cell_size_m};
  ds_->SetGeoTransform(gt);
  OGRSpatialReference srs;
  if (srs.SetFromUserInput(spec.crs_proj.c_str()) != OGRERR_NONE) {
    GDALClose(ds_);
    ds_ = nullptr;
    throw ValidationError(path + ": invalid CRS '" + spec.crs_proj + "'");
  }
  ds_->SetSpatialRef(&srs);
  for (int b = 0; b < num_bands_; ++b) ds_->GetRasterBand(b + 1)->SetDescription(names[b].c_str());
  for (const auto& [k, v] : spec.metadata) ds_->SetMetadataItem(k.c_str(), v.c_str());
}

GridmapTiffWriter::~GridmapTiffWriter() {
  if (ds_ != nullptr) {
    GdalErrorCapture quiet;
    GDALClose(ds_);
  }
}

int GridmapTiffWriter::blocks_x() const {
  return (spec_.width + kGridmapBlockSize - 1) / kGridmapBlockSize;
}
int GridmapTiffWriter::blocks_y() const {
  return (spec_.height + kGridmapBlockSize - 1) / kGridmapBlockSize;
}

namespace {
/// Rounds a finite float to nearest with `bits` mantissa bits (ties away from zero).
inline float round_mantissa(float v, int bits) {
  std::uint32_t u = 0;
  std::memcpy(&u, &v, 4);
  if ((u & 0x7f800000U) == 0x7f800000U) return v;  // inf/nan untouched
  const int drop = 23 - bits;
  const std::uint32_t half = 1U << (drop - 1);
  const std::uint32_t mask = ~((1U << drop) - 1U);
  // A carry out of the mantissa increments the exponent: still the correct rounding.
  u = (u + half) & mask;
  std::memcpy(&v, &u, 4);
  return v;
}
}  // namespace

void GridmapTiffWriter::write_block(int bx, int by, GridmapBlockBuffer& block) {
  POLMAP_EXPECT(ds_ != nullptr && block.num_bands == num_bands_);
  const float* n = block.band(0);
  constexpr std::size_t kCells = static_cast<std::size_t>(kGridmapBlockSize) * kGridmapBlockSize;
  if (std::all_of(n, n + kCells, [](float v) { return v == 0.0F; })) return;
  if (spec_.mantissa_bits < 23 && !spec_.compact) {
    const int bits = std::max(1, spec_.mantissa_bits);
    for (int b = 1; b < num_bands_; ++b) {
      float* d = block.band(b);
      for (std::size_t k = 0; k < kCells; ++k) d[k] = round_mantissa(d[k], bits);
    }
  }
  GdalErrorCapture capture;
  std::vector<std::uint16_t> codes(spec_.compact ? kCells : 0);
  for (int b = 0; b < num_bands_; ++b) {
    void* data = block.band(b);
    if (spec_.compact) {  // the buffer holds integer codes 0..65535
      const float* f = block.band(b);
      for (std::size_t k = 0; k < kCells; ++k) codes[k] = static_cast<std::uint16_t>(f[k]);
      data = codes.data();
    }
    if (ds_->GetRasterBand(b + 1)->WriteBlock(bx, by, data) != CE_None) {
      throw IoError(path_ + ": cannot write block (" + std::to_string(bx) + ", " +
                    std::to_string(by) + ") of band " + std::to_string(b + 1) + ": " +
                    capture.last_message());
    }
  }
}

void GridmapTiffWriter::close() {
  if (ds_ == nullptr) return;
  GdalErrorCapture capture;
  ScopedGdalConfig no_pam("GDAL_PAM_ENABLED", "NO");
  CPLErrorReset();
  GDALClose(ds_);
  ds_ = nullptr;
  if (CPLGetLastErrorType() >= CE_Failure) {
    throw IoError(path_ + ": cannot finish GeoTIFF: " + capture.last_message());
  }
}

void fill_block_from_raster(const GridmapRaster& r, int bx, int by, GridmapBlockBuffer& block) {
  block.clear();
  const int q = r.q;
  const int col0 = bx * kGridmapBlockSize;
  const int row0 = by * kGridmapBlockSize;
  const int cols = std::min(kGridmapBlockSize, r.width - col0);
  const int rows = std::min(kGridmapBlockSize, r.height - row0);
  for (int rr = 0; rr < rows; ++rr) {
    for (int cc = 0; cc < cols; ++cc) {
      const std::size_t src = static_cast<std::size_t>(row0 + rr) * r.width + (col0 + cc);
      const std::size_t dst = static_cast<std::size_t>(rr) * kGridmapBlockSize + cc;
      block.band(0)[dst] = static_cast<float>(std::min(r.count[src], kMaxExactCount));
      int band = 1;
      for (int i = 0; i < q; ++i) {
        for (int j = i; j < q; ++j) {
          const cdouble v = r.layers[GridmapRaster::layer_index(q, i, j)][src];
          block.band(band++)[dst] = static_cast<float>(v.real());
          if (i != j) block.band(band++)[dst] = static_cast<float>(v.imag());
        }
      }
    }
  }
}

void write_gridmap_tiff(const GridmapRaster& raster, const GridmapTiffSpec& spec,
                        const std::string& path) {
  GridmapTiffWriter writer(path, spec);
  GridmapBlockBuffer block(writer.num_bands());
  for (int by = 0; by < writer.blocks_y(); ++by) {
    for (int bx = 0; bx < writer.blocks_x(); ++bx) {
      fill_block_from_raster(raster, bx, by, block);
      writer.write_block(bx, by, block);
    }
  }
  writer.close();
}

}  // namespace detail
}  // namespace polmap::mapping
