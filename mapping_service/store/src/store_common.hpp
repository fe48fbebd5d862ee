#pragma once
// What the store backends (SQLite, PostgreSQL) share: ISO times, box tests, the drive's
// derived data (manifest JSON, decimated trajectory, packed path), package staging with
// "no space" detection, landmark-change geometry JSON and upload session ids. Internal to
// polmap_store; every backend computes these the same way, so both return identical
// results for the same calls.
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "polmap/mapping_service/store.hpp"

namespace polmap::mapping::store_detail {

/// Trajectory decimation for drive_trajectories: a sample is kept when it is
/// this far from the last kept one (or kTrajectoryMaxGapS later).
inline constexpr double kTrajectorySpacingM = 1.0;
/// The decimated trajectory also keeps a sample where skipping it would change the
/// trapezoid integral of yaw rate or speed by more than these (drive alignment odometry).
inline constexpr double kTrajectoryMaxYawIntegralErrorRad = 0.0005;
inline constexpr double kTrajectoryMaxDistanceErrorM = 0.02;
inline constexpr double kTrajectoryMaxGapS = 5.0;

/// UTC now as ISO 8601 ("2024-05-01T12:00:00Z").
std::string now_iso();
/// A time point as ISO 8601 UTC, whole seconds (truncated).
std::string iso_utc(std::chrono::system_clock::time_point t);
/// Splits an antimeridian-crossing box into two ordinary ones.
std::vector<GeoBox> split_box(const GeoBox& b);
bool box_contains(const GeoBox& b, double lat, double lon);
bool box_intersects(const GeoBox& b, double lat0, double lon0, double lat1, double lon1);
/// What the store keeps of a validated package's manifest (DriveRecord::manifest), with
/// "positioning" derived from its validated trajectory: median reported 1-sigma horizontal
/// accuracy (max of east and north) and heading accuracy, and the most common solution
/// type. Map builds use it to tell survey-grade from consumer-grade drives.
nlohmann::json manifest_json(const DrivePackage& package);
/// Bytes of a file, or of all regular files below a directory.
std::int64_t dir_bytes(const std::filesystem::path& p);
/// The table of a tile layer (the same names in every backend's schema).
const char* tile_table(TileLayer layer);
MapVersionStatus parse_status(const std::string& s);

/// Geodetic coordinates of a package's candidates and the bounding box of candidates and
/// trajectory (the manifest origin when there is neither).
struct PackageGeo {
  std::vector<GeoPoint> points;
  std::vector<std::pair<GeoPoint, GeoPoint>> lines;
  GeoBox bbox;
};
PackageGeo package_geo(const DrivePackage& package);

/// Douglas–Peucker to kDrivePathToleranceM in windows of 1024 edges.
std::vector<GeoPoint> simplify_path(const std::vector<GeoPoint>& pl);
/// The trajectory's positions simplified to kDrivePathToleranceM, packed as little-endian
/// float64 (lat, lon) pairs (drive_trajectories.path_blob).
std::string packed_path(const std::vector<TrajectorySample>& trajectory);
std::vector<GeoPoint> unpack_path(std::string_view blob);
/// drive_trajectories.samples_json: [[time_s, lat_deg, lon_deg, yaw_enu_rad, speed_mps], ...]
nlohmann::json decimated_trajectory_json(const std::vector<TrajectorySample>& trajectory);
/// samples_json back to samples.
std::vector<TrajectorySample> trajectory_from_json(const nlohmann::json& samples);
/// The path from samples_json (drives stored before paths were kept).
std::vector<GeoPoint> path_from_samples_json(const nlohmann::json& samples);

/// True if a file system error means "no space" (ENOSPC, EDQUOT).
bool no_space(const std::error_code& ec);
/// Puts the package's files into `dir` (existing): a package directory's regular files are
/// copied (read/write, so a full disk is told as StorageFullError), an archive is unpacked by
/// our ustar reader. Then syncs them. Throws StorageFullError, IoError, FormatError.
void stage_package_files(const std::filesystem::path& package_location,
                         const std::filesystem::path& dir);

/// Landmark change geometry as [[lat, lon], ...] and back (malformed entries skipped).
nlohmann::json geometry_json(const std::vector<GeoPoint>& g);
std::vector<GeoPoint> geometry_from_json(const nlohmann::json& j);

/// The checks of put_localization_run shared by the backends (ValidationError).
void check_localization_run(const LocalizationRunRecord& record,
                            std::span<const LocalizationRunCell> cells, std::size_t keep_newest);
/// 128 bits from the kernel's CSPRNG as 32 lower-case hex digits.
std::string random_session_id();
/// Creates the empty session file (O_EXCL, mode 0600). StorageFullError on ENOSPC/EDQUOT.
void create_session_file(const std::filesystem::path& path);
/// The checks of create_upload_session shared by the backends (ValidationError).
void validate_upload_request(const UploadSessionRequest& r);
/// The checks of complete_upload_session (ValidationError).
void validate_upload_outcome(const UploadOutcome& o);
/// Build jobs: state names, the checks of enqueue_build_jobs, the lease clock (SQLite: the
/// host's wall clock in seconds since the epoch; PostgreSQL uses the server's).
BuildJobState parse_build_job_state(std::string_view s);
void check_build_job_specs(std::span<const BuildJobSpec> jobs);
double epoch_seconds_now();

/// landmark_detail's history walk, the same in every backend. `latest(key, upto)`: the
/// newest recorded change (any kind) of that key in a published version <= upto (version
/// and published_at filled in); `first_version(key, upto)`: the earliest published version
/// <= upto holding a landmark with that key (with its published_at). Moved changes lead to
/// their previous_key one version earlier; where the walk ends, the first version holding
/// the last key becomes an inferred "added" entry when no change recorded it. Newest first.
std::vector<LandmarkHistoryEntry> walk_landmark_history(
    std::int64_t key, std::int64_t version, bool is_line,
    const std::function<std::optional<LandmarkHistoryEntry>(std::int64_t, std::int64_t)>& latest,
    const std::function<std::optional<std::pair<std::int64_t, std::string>>(
        std::int64_t, std::int64_t)>& first_version);

}  // namespace polmap::mapping::store_detail
