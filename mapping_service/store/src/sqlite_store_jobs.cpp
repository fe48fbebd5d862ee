// SqliteMapStore: build jobs of partitioned map builds (schema/build_jobs.md). Workers of
// one SQLite store share its host, so leases run on the host's wall clock; a claim is one
// BEGIN IMMEDIATE transaction (SQLite serializes writers; no row locks to skip).
#include "sqlite_store_impl.hpp"

namespace polmap::mapping {
namespace {

constexpr const char* kJobColumns =
    "job_id, version, kind, z, x, y, spec_json, state, attempt, worker, lease_until - ?1, "
    "result_json, error";

/// The job's state and attempt, or nullopt when it does not exist.
std::optional<std::pair<std::string, int>> job_state(Connection& c, std::int64_t job) {
  auto s = c.stmt("SELECT state, attempt FROM build_jobs WHERE job_id = ?1");
  s.bind(1, job);
  if (!s.step()) return std::nullopt;
  return std::make_pair(s.text(0), static_cast<int>(s.i64(1)));
}

/// Fencing: the job is running under this attempt and its version is still Building.
bool holds(Connection& c, std::int64_t job, int attempt) {
  const auto st = job_state(c, job);
  if (!st || st->first != "running" || st->second != attempt) return false;
  auto s = c.stmt(
      "SELECT v.status FROM build_jobs j JOIN map_versions v ON v.version = j.version WHERE "
      "j.job_id = ?1");
  s.bind(1, job);
  return s.step() && s.text(0) == "building";
}

}  // namespace

BuildJob SqliteMapStore::Impl::build_job_from_row(Stmt& s) {
  BuildJob j;
  j.id = s.i64(0);
  j.version = s.i64(1);
  j.kind = s.text(2);
  j.region = tiles::TileKey{static_cast<int>(s.i64(3)), static_cast<int>(s.i64(4)),
                            static_cast<int>(s.i64(5))};
  j.spec = nlohmann::json::parse(s.text(6), nullptr, false);
  j.state = parse_build_job_state(s.text(7));
  j.attempt = static_cast<int>(s.i64(8));
  j.worker = s.text(9);
  j.lease_left_s = j.state == BuildJobState::Running ? s.f64(10) : 0.0;
  if (!s.is_null(11)) j.result = nlohmann::json::parse(s.text(11), nullptr, false);
  j.error = s.text(12);
  return j;
}

void SqliteMapStore::enqueue_build_jobs(std::int64_t version, std::span<const BuildJobSpec> jobs) {
  check_build_job_specs(jobs);
  impl_->write([&](Connection& c) {
    Impl::require_building(c, version);
    for (const auto& j : jobs) {
      c.stmt(
           "INSERT INTO build_jobs(version, kind, z, x, y, spec_json, state) VALUES (?1, ?2, ?3, "
           "?4, ?5, ?6, 'pending')")
          .bind(1, version)
          .bind(2, j.kind)
          .bind(3, j.region.z)
          .bind(4, j.region.x)
          .bind(5, j.region.y)
          .bind(6, j.spec.dump())
          .run();
    }
  });
}

std::optional<BuildJob> SqliteMapStore::claim_build_job(std::string_view worker, double lease_s,
                                                        std::optional<std::int64_t> version) {
  if (!(lease_s > 0.0)) throw ValidationError("claim_build_job: lease_s must be positive");
  return impl_->write([&](Connection& c) -> std::optional<BuildJob> {
    const double now = epoch_seconds_now();
    std::int64_t id = 0;
    {
      auto s = c.stmt(
          "SELECT j.job_id FROM build_jobs j JOIN map_versions v ON v.version = j.version AND "
          "v.status = 'building' WHERE (j.state = 'pending' OR (j.state = 'running' AND "
          "j.lease_until < ?1)) AND (j.kind <> 'publish' OR NOT EXISTS (SELECT 1 FROM "
          "build_jobs o WHERE o.version = j.version AND o.kind <> 'publish' AND o.state <> "
          "'done')) AND (?2 IS NULL OR j.version = ?2) ORDER BY j.job_id LIMIT 1");
      s.bind(1, now);
      if (version) {
        s.bind(2, *version);
      } else {
        s.bind_null(2);
      }
      if (!s.step()) return std::nullopt;
      id = s.i64(0);
    }
    c.stmt(
         "UPDATE build_jobs SET state = 'running', attempt = attempt + 1, worker = ?1, "
         "lease_until = ?2 WHERE job_id = ?3")
        .bind(1, worker)
        .bind(2, now + lease_s)
        .bind(3, id)
        .run();
    auto s = c.stmt(std::string("SELECT ") + kJobColumns + " FROM build_jobs WHERE job_id = ?2");
    s.bind(1, now).bind(2, id);
    s.step();
    return Impl::build_job_from_row(s);
  });
}

bool SqliteMapStore::renew_build_job(std::int64_t job, int attempt, double lease_s) {
  return impl_->write([&](Connection& c) {
    if (!holds(c, job, attempt)) return false;
    c.stmt("UPDATE build_jobs SET lease_until = ?1 WHERE job_id = ?2")
        .bind(1, epoch_seconds_now() + lease_s)
        .bind(2, job)
        .run();
    return true;
  });
}

bool SqliteMapStore::complete_build_job(std::int64_t job, int attempt, const BuildJobOutput& out) {
  return impl_->write([&](Connection& c) {
    if (!holds(c, job, attempt)) return false;
    std::int64_t version = 0;
    {
      auto s = c.stmt("SELECT version FROM build_jobs WHERE job_id = ?1");
      s.bind(1, job);
      s.step();
      version = s.i64(0);
    }
    if (!out.points.empty() || !out.lines.empty()) {
      Impl::put_landmarks_tx(c, version, out.points, out.lines);
    }
    if (!out.changes.empty()) Impl::put_landmark_changes_tx(c, version, out.changes);
    if (!out.localization_tiles.empty()) {
      Impl::put_tiles_tx(c, version, TileLayer::Localization, out.localization_tiles);
    }
    c.stmt(
         "UPDATE build_jobs SET state = 'done', result_json = ?1, lease_until = 0 WHERE job_id "
         "= ?2")
        .bind(1, out.result.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace))
        .bind(2, job)
        .run();
    return true;
  });
}

bool SqliteMapStore::fail_build_job(std::int64_t job, int attempt, std::string_view error) {
  return impl_->write([&](Connection& c) {
    const auto st = job_state(c, job);
    if (!st || st->first != "running" || st->second != attempt) return false;
    c.stmt("UPDATE build_jobs SET state = 'failed', error = ?1, lease_until = 0 WHERE job_id = ?2")
        .bind(1, error)
        .bind(2, job)
        .run();
    return true;
  });
}

std::vector<BuildJob> SqliteMapStore::build_jobs(std::int64_t version) const {
  return impl_->read([&](Connection& c) {
    std::vector<BuildJob> out;
    auto s = c.stmt(std::string("SELECT ") + kJobColumns +
                    " FROM build_jobs WHERE version = ?2 ORDER BY job_id");
    s.bind(1, epoch_seconds_now()).bind(2, version);
    while (s.step()) out.push_back(Impl::build_job_from_row(s));
    return out;
  });
}

}  // namespace polmap::mapping
