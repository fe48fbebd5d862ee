// Fuzzer: whole-package validation from bytes (try_validate_package_bytes), what the server
// runs on every upload: ustar, manifest.json, gridmap.tif (GDAL GTiff) and candidates.gpkg
// (the SQLite pre-screen, then GDAL GPKG). Any input is either rejected with a 400/422 PackageError
// naming a file, or accepted, and an accepted package must be what the validator promises: counts
// equal to the manifest's, every listed file present with its size and SHA-256, coordinates finite
// and within the config's bound and the gridmap extent, trajectory times strictly increasing inside
// the time span, content_sha256 the SHA-256 of the bytes (both hashes recomputed here with OpenSSL,
// independent of the validator's own).
//
// The manifest lists each file's SHA-256, so almost every mutation of gridmap.tif or
// candidates.gpkg would stop at the hash check and GDAL would never see it. When an input
// fails only there, the harness also validates a copy whose manifest carries the correct
// sizes and hashes of the mutated members, so the GeoTIFF and GeoPackage readers are
// fuzzed too.
//
// Seeds: three tiny real packages written by the package writer (tests/mapping_service/
// package_fixture.hpp's synthetic drive, 24 x 24 cells) at full, dual and single-channel
// levels, their GeoPackage re-paged to 512-byte pages (see seed_package).
#include <cpl_error.h>
#include <openssl/evp.h>
#include <sqlite3.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "fuzz_seeds.hpp"
#include "mapping_service/package_fixture.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/schema/errors.hpp"

using namespace polmap;
using namespace polmap::mapping;

namespace {

/// The defaults, with the raster limited to 16 GeoTIFF blocks so that one input never
/// costs seconds of block scanning (a fuzzed manifest may claim any raster size), and no
/// wall-clock budget: a 413 would depend on the machine's load (the fuzzer must be
/// deterministic); libFuzzer's -timeout reports slow inputs instead.
PackageValidationConfig fuzz_config() {
  PackageValidationConfig c;
  c.max_raster_cells = 1 << 20;
  c.max_validation_s = 0.0;
  return c;
}

const PackageValidationConfig kCfg = fuzz_config();

#define FUZZ_CHECK(cond)                                                   \
  do {                                                                     \
    if (!(cond)) {                                                         \
      std::fprintf(stderr, "fuzz_package: invariant failed: %s\n", #cond); \
      std::abort();                                                        \
    }                                                                      \
  } while (0)

std::string openssl_sha256(std::string_view bytes) {
  unsigned char md[EVP_MAX_MD_SIZE];
  unsigned int n = 0;
  if (EVP_Digest(bytes.data(), bytes.size(), md, &n, EVP_sha256(), nullptr) != 1) std::abort();
  static const char* hex = "0123456789abcdef";
  std::string out;
  for (unsigned int i = 0; i < n; ++i) {
    out += hex[md[i] >> 4];
    out += hex[md[i] & 15];
  }
  return out;
}

bool finite(const Eigen::Vector2d& p) { return std::isfinite(p.x()) && std::isfinite(p.y()); }

void check_accepted(const DrivePackage& pkg, std::string_view bytes) {
  const DriveManifest& m = pkg.manifest;
  FUZZ_CHECK(pkg.location.empty());
  FUZZ_CHECK(pkg.content_sha256 == openssl_sha256(bytes));
  // Every listed file is a member with the listed size and hash.
  const auto members = read_ustar_views(bytes, "accepted");
  // Format 1: gridmap.tif + candidates.gpkg; format 2: [gridmap.tif +] candidates.bin.
  if (m.format_version == 1) {
    FUZZ_CHECK(m.has_gridmap && m.files.size() == 2 && m.files[0].name == kGridmapFileName &&
               m.files[1].name == kCandidatesFileName);
  } else {
    FUZZ_CHECK(m.format_version == 2);
    FUZZ_CHECK(m.files.size() == (m.has_gridmap ? 2U : 1U));
    FUZZ_CHECK(m.files.back().name == kCandidatesBinFileName);
    FUZZ_CHECK(!m.has_gridmap || (m.files[0].name == kGridmapFileName && m.gridmap.compact));
  }
  FUZZ_CHECK(members.size() == m.files.size() + 1);
  for (const auto& f : m.files) {
    bool found = false;
    for (const auto& mem : members) {
      if (mem.name != f.name) continue;
      found = true;
      FUZZ_CHECK(mem.data.size() == f.size_bytes);
      FUZZ_CHECK(openssl_sha256(mem.data) == f.sha256);
    }
    FUZZ_CHECK(found);
  }
  // Counts, limits.
  FUZZ_CHECK(pkg.points.size() == m.counts.points);
  FUZZ_CHECK(pkg.lines.size() == m.counts.lines);
  FUZZ_CHECK(pkg.trajectory.size() == m.counts.trajectory_samples);
  FUZZ_CHECK(pkg.points.size() <= kCfg.max_points);
  FUZZ_CHECK(pkg.lines.size() <= kCfg.max_lines);
  FUZZ_CHECK(pkg.trajectory.size() >= 2 && pkg.trajectory.size() <= kCfg.max_trajectory_samples);
  const GridmapInfo& g = m.gridmap;
  FUZZ_CHECK(!m.has_gridmap || (g.width > 0 && g.height > 0));
  FUZZ_CHECK(static_cast<std::int64_t>(g.width) * g.height <= kCfg.max_raster_cells);
  FUZZ_CHECK(std::isfinite(m.cell_size_m) && m.cell_size_m > 0.0);
  // Coordinates: finite, within the bound, inside the gridmap extent plus the margin.
  const double lim = kCfg.max_abs_coordinate_m;
  const double margin = kCfg.extent_margin_m + 1e-9;
  const auto bounded = [&](const Eigen::Vector2d& p) {
    if (!m.has_gridmap) return finite(p) && std::abs(p.x()) <= lim && std::abs(p.y()) <= lim;
    return finite(p) && std::abs(p.x()) <= lim && std::abs(p.y()) <= lim &&
           p.x() >= g.origin_x_m - margin &&
           p.x() <= g.origin_x_m + g.width * m.cell_size_m + margin &&
           p.y() <= g.origin_y_m + margin &&
           p.y() >= g.origin_y_m - g.height * m.cell_size_m - margin;
  };
  for (const auto& p : pkg.points) {
    FUZZ_CHECK(bounded(p.position_m));
    FUZZ_CHECK(std::isfinite(p.strength) && std::isfinite(p.power_db));
  }
  for (const auto& l : pkg.lines) {
    FUZZ_CHECK(bounded(l.start_m) && bounded(l.end_m));
    FUZZ_CHECK(std::isfinite(l.strength));
  }
  // Trajectory: strictly increasing times inside the span, plausible values.
  for (std::size_t i = 0; i < pkg.trajectory.size(); ++i) {
    const TrajectorySample& s = pkg.trajectory[i];
    FUZZ_CHECK(std::isfinite(s.time_s));
    if (i > 0) FUZZ_CHECK(s.time_s > pkg.trajectory[i - 1].time_s);
    FUZZ_CHECK(s.time_s >= m.start_time_s - kCfg.time_span_tolerance_s &&
               s.time_s <= m.end_time_s + kCfg.time_span_tolerance_s);
    FUZZ_CHECK(std::isfinite(s.speed_mps) && std::abs(s.speed_mps) <= kCfg.max_speed_mps);
    FUZZ_CHECK(std::isfinite(s.lat_deg) && std::abs(s.lat_deg) <= 90.0);
    FUZZ_CHECK(std::isfinite(s.lon_deg) && std::abs(s.lon_deg) <= 180.0);
    FUZZ_CHECK(std::isfinite(s.yaw_enu_rad) && std::isfinite(s.yaw_rate_rps));
    FUZZ_CHECK(std::isfinite(s.std_east_m) && s.std_east_m >= 0.0F);
    FUZZ_CHECK(std::isfinite(s.std_north_m) && s.std_north_m >= 0.0F);
    FUZZ_CHECK(std::isfinite(s.std_yaw_rad) && s.std_yaw_rad >= 0.0F);
  }
}

/// Validates; checks the invariants of an accepted package or the shape of the error.
std::expected<DrivePackage, PackageError> validate(std::string_view bytes) {
  auto r = try_validate_package_bytes(bytes, kCfg);
  if (r) {
    check_accepted(*r, bytes);
  } else {
    const PackageError& e = r.error();
    FUZZ_CHECK(e.http_status == 400 || e.http_status == 422);  // 413 only with a budget
    FUZZ_CHECK(!e.file.empty() && !e.message.empty());
  }
  return r;
}

/// The archive with the manifest's files[].size_bytes and sha256 set to those of the
/// members present; empty if it has no parsable archive or manifest to rewrite.
std::string with_correct_hashes(std::string_view bytes) {
  std::vector<TarMemberView> views;
  try {
    views = read_ustar_views(bytes, "fuzz");
  } catch (const FormatError&) {
    return {};
  }
  std::vector<TarMember> members;
  nlohmann::json* files = nullptr;
  nlohmann::json manifest;
  for (const auto& v : views) {
    members.push_back({v.name, std::string(v.data)});
    if (v.name == kManifestFileName) {
      manifest = nlohmann::json::parse(v.data.begin(), v.data.end(), nullptr, false);
      if (manifest.is_object() && manifest.contains("files") && manifest["files"].is_array()) {
        files = &manifest["files"];
      }
    }
  }
  if (files == nullptr) return {};
  for (auto& f : *files) {
    if (!f.is_object() || !f.contains("name") || !f["name"].is_string()) continue;
    for (const auto& v : views) {
      if (v.name != f["name"].get<std::string>()) continue;
      f["size_bytes"] = v.data.size();
      f["sha256"] = openssl_sha256(v.data);
    }
  }
  for (auto& mem : members) {
    if (mem.name == kManifestFileName) {
      // As the writer formats it, so an unchanged manifest gives unchanged bytes.
      mem.data = manifest.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
    }
  }
  return write_ustar(members);
}

/// A package written by the package writer from the synthetic drive (24 x 24 cells).
/// `compact`: candidates.gpkg re-paged by SQLite to 512-byte pages (VACUUM; the writer's
/// 4096-byte pages make 140 kB of mostly empty pages) and the manifest's hash updated, so
/// the whole package is ~25 kB and fuzzing spends its mutations on content.
std::string seed_package(const std::filesystem::path& scratch, const std::string& name,
                         PolLevel level, int num_points, int num_lines, bool compact,
                         std::uint32_t format = 1, bool landmarks_only = false) {
  auto d = testing::make_synthetic_drive(name, level, 24, 24, 11, num_points, num_lines, 12);
  d.raster.noise_power = 1e-6;
  const auto dir = scratch / name;
  PackageWriteOptions opt;
  opt.mantissa_bits = 10;
  opt.format_version = format;
  opt.landmarks_only = landmarks_only;
  if (format >= 2) compact = false;  // no GeoPackage to re-page
  (void)write_drive_package(d.pkg, d.raster, dir, opt);
  std::string tar = pack_drive_package(dir);
  if (compact) {
    sqlite3* db = nullptr;
    const std::string gpkg = (dir / kCandidatesFileName).string();
    if (sqlite3_open(gpkg.c_str(), &db) != SQLITE_OK ||
        sqlite3_exec(db, "PRAGMA page_size = 512; VACUUM;", nullptr, nullptr, nullptr) !=
            SQLITE_OK ||
        sqlite3_close(db) != SQLITE_OK) {
      std::abort();
    }
    tar = with_correct_hashes(pack_drive_package(dir));
  }
  // A seed the validator rejects would fuzz nothing past the first error.
  const auto r = try_validate_package_bytes(tar, kCfg);
  if (!r) {
    std::fprintf(stderr, "fuzz_package: seed %s rejected: %s\n", name.c_str(),
                 r.error().what().c_str());
    std::abort();
  }
  return tar;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  CPLSetErrorHandler(CPLQuietErrorHandler);
  if (const auto dir = fuzz::seed_dir(); !dir.empty()) {
    const auto scratch = std::filesystem::temp_directory_path() /
                         ("polmap-fuzz-package-" + std::to_string(::getpid()));
    std::filesystem::remove_all(scratch);
    fuzz::write_seed(dir, "full.tar",
                     seed_package(scratch, "drive_full", PolLevel::Full, 4, 2, true));
    fuzz::write_seed(dir, "dual.tar",
                     seed_package(scratch, "drive_dual", PolLevel::DualHHVV, 3, 1, true));
    fuzz::write_seed(dir, "lr.tar",
                     seed_package(scratch, "drive_lr", PolLevel::SingleLR, 1, 0, true));
    fuzz::write_seed(dir, "v2_full.tar",
                     seed_package(scratch, "drive_v2", PolLevel::Full, 4, 2, false, 2));
    fuzz::write_seed(dir, "v2_landmarks.tar",
                     seed_package(scratch, "drive_v2l", PolLevel::Full, 4, 2, false, 2, true));
    std::filesystem::remove_all(scratch);
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  const auto r = validate(bytes);
  if (!r && (r.error().field == "sha256" || r.error().field == "size_bytes")) {
    const std::string fixed = with_correct_hashes(bytes);
    if (!fixed.empty() && fixed != bytes) (void)validate(fixed);
  }
  return 0;
}
