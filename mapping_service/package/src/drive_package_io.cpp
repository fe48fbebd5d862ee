// Drive package writer, archive packing/unpacking, manifest JSON, candidates GeoPackage.
#include "polmap/mapping_service/drive_package_io.hpp"

#include <gdal_priv.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "package_internal.hpp"
#include "polmap/mapping_service/candidates_codec.hpp"
#include "polmap/mapping_service/trajectory_odometry.hpp"
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

std::vector<std::pair<std::string, std::string>> tiff_metadata(const DriveManifest& m);

/// Format 2 trajectory: greedy simplification — from each kept sample, the next kept one
/// is the farthest whose linear interpolation reproduces every sample in between within
/// the position and yaw bounds, whose trapezoid odometry (yaw rate, speed) reproduces the
/// full-rate integrals within their bounds, and which is at most max_gap_s later (first and
/// last kept).
std::vector<TrajectorySample> simplify_trajectory(const std::vector<TrajectorySample>& t,
                                                  const tiles::LocalFrame& frame,
                                                  const PackageWriteOptions& o) {
  if (t.size() <= 2 || o.trajectory_max_gap_s <= 0.0) return t;
  std::vector<Eigen::Vector2d> xy(t.size());
  for (std::size_t i = 0; i < t.size(); ++i) xy[i] = frame.to_local(t[i].lat_deg, t[i].lon_deg);
  const TrajectoryOdometry odometry(t);
  const auto fits = [&](std::size_t a, std::size_t b) {
    const double span = t[b].time_s - t[a].time_s;
    if (span > o.trajectory_max_gap_s) return false;
    // The odometry over the kept pair alone must match the full-rate one.
    if (!odometry.kept_by(a, b, o.trajectory_max_yaw_integral_error_rad,
                          o.trajectory_max_distance_error_m)) {
      return false;
    }
    double dyaw = std::remainder(t[b].yaw_enu_rad - t[a].yaw_enu_rad, 2.0 * M_PI);
    for (std::size_t k = a + 1; k < b; ++k) {
      const double f = (t[k].time_s - t[a].time_s) / span;
      if ((xy[a] + f * (xy[b] - xy[a]) - xy[k]).norm() > o.trajectory_max_error_m) return false;
      const double yaw = t[a].yaw_enu_rad + f * dyaw;
      if (std::abs(std::remainder(yaw - t[k].yaw_enu_rad, 2.0 * M_PI)) >
          o.trajectory_max_yaw_error_rad) {
        return false;
      }
    }
    return true;
  };
  std::vector<TrajectorySample> out{t.front()};
  std::size_t a = 0;
  while (a + 1 < t.size()) {
    std::size_t b = a + 1;
    while (b + 1 < t.size() && fits(a, b + 1)) ++b;
    out.push_back(t[b]);
    a = b;
  }
  return out;
}

/// Shared tail of both writers: the gridmap.tif (if any) is already in `tmp`; writes the
/// candidates, the manifest, validates, and moves `tmp` into place.
DriveManifest finish_package(DriveManifest m, const DrivePackage& values, const fs::path& tmp,
                             const fs::path& dir, const PackageWriteOptions& options) {
  const tiles::LocalFrame frame(m.origin);
  m.format_version = options.format_version;
  m.files.clear();
  if (m.has_gridmap) m.files.push_back(file_entry(tmp, kGridmapFileName));
  if (options.format_version >= 2) {
    CandidatesContent c{values.points, values.lines,
                        simplify_trajectory(values.trajectory, frame, options)};
    // Sorted by position, the delta-coded columns stay small (consensus ignores order).
    const auto by_position = [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
      return a.y() != b.y() ? a.y() < b.y() : a.x() < b.x();
    };
    std::stable_sort(c.points.begin(), c.points.end(), [&](const auto& a, const auto& b) {
      return by_position(a.position_m, b.position_m);
    });
    std::stable_sort(c.lines.begin(), c.lines.end(), [&](const auto& a, const auto& b) {
      return by_position(a.start_m, b.start_m);
    });
    m.counts = {c.points.size(), c.lines.size(), c.trajectory.size()};
    write_file_bytes(tmp / kCandidatesBinFileName, encode_candidates(c));
    m.files.push_back(file_entry(tmp, kCandidatesBinFileName));
  } else {
    write_candidates_gpkg((tmp / kCandidatesFileName).string(), frame, values.points, values.lines,
                          values.trajectory);
    m.counts = {values.points.size(), values.lines.size(), values.trajectory.size()};
    m.files.push_back(file_entry(tmp, kCandidatesFileName));
  }
  // Format 2 manifests are one line (a landmarks-only package is ~15 kB; indentation
  // would be a tenth of it); format 1 keeps its indented bytes.
  write_file_bytes(tmp / kManifestFileName,
                   manifest_to_json(m).dump(options.format_version >= 2 ? -1 : 2) + "\n");
  if (options.validate_after_write) (void)read_and_validate_package(tmp);
  commit_dir(tmp, dir);
  return m;
}

/// The manifest's gridmap description for a raster of the given geometry.
GridmapInfo gridmap_info(int width, int height, double origin_x_m, double origin_y_m, int q,
                         double noise_power, const PackageWriteOptions& options) {
  GridmapInfo g;
  g.width = width;
  g.height = height;
  g.origin_x_m = origin_x_m;
  g.origin_y_m = origin_y_m;
  g.block_size = kGridmapBlockSize;
  g.compact = options.format_version >= 2;
  g.num_bands = (g.compact ? 3 : 1) + q * q;
  g.mantissa_bits = g.compact ? 23 : std::clamp(options.mantissa_bits, 1, 23);
  if (g.compact) {
    // An empty drive has no noise figure; any positive σ² decodes its all-zero codes.
    g.noise_power = noise_power > 0.0 ? noise_power : 1.0;
    g.codec = options.codec;
  }
  return g;
}

GridmapTiffSpec tiff_spec(const DriveManifest& m, const PackageWriteOptions& options) {
  GridmapTiffSpec spec;
  spec.width = m.gridmap.width;
  spec.height = m.gridmap.height;
  spec.origin_x_m = m.gridmap.origin_x_m;
  spec.origin_y_m = m.gridmap.origin_y_m;
  spec.cell_size_m = m.cell_size_m;
  spec.level = m.pol_level;
  spec.crs_proj = m.crs_proj;
  spec.deflate_level = options.deflate_level;
  spec.mantissa_bits = m.gridmap.mantissa_bits;
  spec.compact = m.gridmap.compact;
  spec.zstd_level = options.zstd_level;
  spec.metadata = tiff_metadata(m);
  return spec;
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
  if (m.gridmap.compact) {
    return {{"POLMAP_FORMAT", "polmap.drive_package gridmap"},
            {"POLMAP_FORMAT_VERSION", "2"},
            {"POLMAP_DRIVE_ID", m.drive_id},
            {"POLMAP_POL_LEVEL", std::string(to_string(m.pol_level))},
            {"POLMAP_ENCODING",
             "compact codes (schema/drive_package.md): N, hits, P = power code, U = Cholesky "
             "factor codes; decode with the manifest's gridmap.codec and noise_power"}};
  }
  return {{"POLMAP_FORMAT", "polmap.drive_package gridmap"},
          {"POLMAP_FORMAT_VERSION", "1"},
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
  const bool compact = options.format_version >= 2;
  if (compact && !options.landmarks_only && !(raster.noise_power > 0.0) && cells > 0) {
    throw ValidationError("write_drive_package: format 2 needs the raster's noise_power (> 0)");
  }
  if (!raster.hits.empty() && raster.hits.size() != cells) {
    throw ValidationError("write_drive_package: raster hits do not match width x height");
  }
  m.has_gridmap = !(compact && options.landmarks_only);
  m.gridmap = detail::gridmap_info(r->width, r->height, r->origin_x_m, r->origin_y_m, q,
                                   raster.noise_power, options);
  const util::ScopedTempDir staging = detail::make_package_temp_dir(dir);
  const fs::path& tmp = staging.path();
  if (m.has_gridmap) {
    const GridmapTiffSpec spec = detail::tiff_spec(m, options);
    if (compact) {
      const GridmapCodec codec(q, m.gridmap.noise_power, m.gridmap.codec);
      detail::GridmapTiffWriter writer((tmp / kGridmapFileName).string(), spec);
      detail::GridmapBlockBuffer block(writer.num_bands());
      std::vector<std::uint16_t> codes(static_cast<std::size_t>(codec.codes_per_cell()));
      std::vector<std::complex<float>> layers(static_cast<std::size_t>(r->num_layers()));
      const int bs = detail::kGridmapBlockSize;
      for (int by = 0; by < writer.blocks_y(); ++by) {
        for (int bx = 0; bx < writer.blocks_x(); ++bx) {
          block.clear();
          for (int rr = 0; rr < std::min(bs, r->height - by * bs); ++rr) {
            for (int cc = 0; cc < std::min(bs, r->width - bx * bs); ++cc) {
              const std::size_t src =
                  static_cast<std::size_t>(by * bs + rr) * r->width + bx * bs + cc;
              for (int l = 0; l < r->num_layers(); ++l) {
                layers[l] = std::complex<float>(r->layers[l][src]);
              }
              const std::uint32_t n = r->count[src];
              codec.encode_cell(n, raster.hits.empty() ? n : raster.hits[src], layers, codes);
              for (int b = 0; b < codec.codes_per_cell(); ++b) {
                block.band(b)[static_cast<std::size_t>(rr) * bs + cc] = codes[b];
              }
            }
          }
          writer.write_block(bx, by, block);
        }
      }
      writer.close();
    } else {
      detail::write_gridmap_tiff(*r, spec, (tmp / kGridmapFileName).string());
    }
  }
  return detail::finish_package(std::move(m), pkg, tmp, dir, options);  // renames tmp
}

// ------------------------------------------------------------------------ archive

namespace {
/// Archive members of a package directory: the manifest, then its listed files in order.
std::vector<std::string> member_names(const fs::path& dir) {
  const std::string text = detail::read_file_bytes(dir / kManifestFileName);
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {
    throw PackageFormatError(kManifestFileName, "", std::string("not valid JSON: ") + e.what());
  }
  std::vector<std::string> names{kManifestFileName};
  for (const auto& f : detail::manifest_from_json(j).files) names.push_back(f.name);
  return names;
}
}  // namespace

std::string pack_drive_package(const fs::path& dir) {
  std::vector<TarMember> members;
  for (const std::string& name : member_names(dir)) {
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
    for (const std::string& name : member_names(dir)) {
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
  // Which members a package has depends on its manifest (format 1: gridmap.tif and
  // candidates.gpkg; format 2: candidates.bin and, unless landmarks-only, gridmap.tif);
  // validation checks the set against the manifest. Here: only known names, manifest first.
  const std::vector<std::string> known{kManifestFileName, kGridmapFileName, kCandidatesFileName,
                                       kCandidatesBinFileName};
  for (const auto& mb : members) {
    if (std::find(known.begin(), known.end(), mb.name) == known.end()) {
      throw PackageValidationError("archive", "", "unexpected member '" + mb.name + "'");
    }
  }
  if (members.empty() || members.front().name != kManifestFileName) {
    throw PackageValidationError(kManifestFileName, "", "missing from the archive (or not first)");
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
