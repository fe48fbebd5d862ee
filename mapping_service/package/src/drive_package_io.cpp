// Drive package writer, archive packing/unpacking, manifest JSON, candidates GeoPackage.
#include "polmap/mapping_service/drive_package_io.hpp"

#include <gdal_priv.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>
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

util::ScopedTempDir make_package_temp_dir(const fs::path& dir) {
  return util::ScopedTempDir::create(parent_for_temp(dir), hidden_stem(dir, ".tmp"));
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
  } else if (!is_local_frame_proj(m.crs_proj, m.origin)) {
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

  const util::ScopedTempDir staging = detail::make_package_temp_dir(dir);
  const fs::path& tmp = staging.path();
  {
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
    return detail::finish_package(std::move(m), pkg, tmp, dir, options);  // renames tmp
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
  util::ScopedTempDir dir = util::ScopedTempDir::create("polmap_pkg");
  for (const auto& mb : members) detail::write_file_bytes(dir.path() / mb.name, mb.data);
  return dir.release();
}

std::string package_member_gdal_path(const fs::path& location, const std::string& name) {
  std::error_code ec;
  if (fs::is_directory(location, ec)) return (location / name).string();
  return "/vsitar/" + location.string() + "/" + name;
}

}  // namespace polmap::mapping
