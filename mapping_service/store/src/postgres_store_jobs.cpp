// PostgresMapStore: build jobs of partitioned map builds (schema/build_jobs.md). Workers on
// any host claim jobs with SELECT ... FOR UPDATE SKIP LOCKED outside the store's write lock
// (a claim never queues behind a long write); leases run on the database server's clock.
// A job's output is written under the write lock, as every other write, with the job row
// locked so that no claim can take it over meanwhile.
#include "postgres_store_impl.hpp"

namespace polmap::mapping {
namespace {

constexpr const char* kNow = "extract(epoch from clock_timestamp())::float8";

std::string job_columns() {
  return std::string("job_id, version, kind, z, x, y, spec_json, state, attempt, worker, ") +
         "lease_until - " + kNow + ", result_json, error";
}

/// Fencing, with the job row locked until the transaction ends: the job is running under
/// this attempt and its version is still Building. Returns the version, or 0.
std::int64_t hold(Connection& c, std::int64_t job, int attempt) {
  const Result r = c.run(
      "SELECT j.version FROM build_jobs j JOIN map_versions v ON v.version = j.version WHERE "
      "j.job_id = $1 AND j.state = 'running' AND j.attempt = $2 AND v.status = 'building' FOR "
      "UPDATE OF j",
      job, attempt);
  return r.empty() ? 0 : r.i64(0, 0);
}

}  // namespace

BuildJob PostgresMapStore::Impl::build_job_from_row(const Result& r, int i) {
  BuildJob j;
  j.id = r.i64(i, 0);
  j.version = r.i64(i, 1);
  j.kind = r.text(i, 2);
  j.region = tiles::TileKey{static_cast<int>(r.i64(i, 3)), static_cast<int>(r.i64(i, 4)),
                            static_cast<int>(r.i64(i, 5))};
  j.spec = nlohmann::json::parse(r.text(i, 6), nullptr, false);
  j.state = parse_build_job_state(r.text(i, 7));
  j.attempt = static_cast<int>(r.i64(i, 8));
  j.worker = r.text(i, 9);
  j.lease_left_s = j.state == BuildJobState::Running ? r.f64(i, 10) : 0.0;
  if (!r.is_null(i, 11)) j.result = nlohmann::json::parse(r.text(i, 11), nullptr, false);
  j.error = r.text(i, 12);
  return j;
}

void PostgresMapStore::enqueue_build_jobs(std::int64_t version,
                                          std::span<const BuildJobSpec> jobs) {
  check_build_job_specs(jobs);
  impl_->write([&](Connection& c) {
    Impl::require_building(c, version);
    std::int64_t id = Impl::next_id(c, "build_jobs", "job_id");
    for (const auto& j : jobs) {
      c.run(
          "INSERT INTO build_jobs(job_id, version, kind, z, x, y, spec_json, state) VALUES ($1, "
          "$2, $3, $4, $5, $6, $7::jsonb, 'pending')",
          id++, version, j.kind, j.region.z, j.region.x, j.region.y, j.spec.dump());
    }
  });
}

std::optional<BuildJob> PostgresMapStore::claim_build_job(std::string_view worker, double lease_s,
                                                          std::optional<std::int64_t> version) {
  if (!(lease_s > 0.0)) throw ValidationError("claim_build_job: lease_s must be positive");
  return impl_->transact([&](Connection& c) -> std::optional<BuildJob> {
    const Result r = c.run(
        std::string("WITH j AS (SELECT b.job_id FROM build_jobs b JOIN map_versions v ON "
                    "v.version = b.version AND v.status = 'building' WHERE (b.state = "
                    "'pending' OR (b.state = 'running' AND b.lease_until < ") +
            kNow +
            ")) AND (b.kind <> 'publish' OR NOT EXISTS (SELECT 1 FROM build_jobs o WHERE "
            "o.version = b.version AND o.kind <> 'publish' AND o.state <> 'done')) AND ($3::bigint "
            "IS NULL OR b.version = $3) ORDER BY "
            "b.job_id LIMIT 1 FOR UPDATE OF b SKIP LOCKED) UPDATE build_jobs SET state = "
            "'running', attempt = attempt + 1, worker = $1, lease_until = " +
            kNow + " + $2 FROM j WHERE build_jobs.job_id = j.job_id RETURNING build_jobs.job_id",
        std::string(worker), lease_s, version);
    if (r.empty()) return std::nullopt;
    const Result row =
        c.run("SELECT " + job_columns() + " FROM build_jobs WHERE job_id = $1", r.i64(0, 0));
    return Impl::build_job_from_row(row, 0);
  });
}

bool PostgresMapStore::renew_build_job(std::int64_t job, int attempt, double lease_s) {
  return impl_->transact([&](Connection& c) {
    const Result r =
        c.run(std::string("UPDATE build_jobs j SET lease_until = ") + kNow +
                  " + $3 FROM map_versions v WHERE j.job_id = $1 AND j.attempt = $2 AND j.state = "
                  "'running' AND v.version = j.version AND v.status = 'building'",
              job, attempt, lease_s);
    return r.affected() == 1;
  });
}

bool PostgresMapStore::complete_build_job(std::int64_t job, int attempt,
                                          const BuildJobOutput& out) {
  return impl_->write([&](Connection& c) {
    const std::int64_t version = hold(c, job, attempt);
    if (version == 0) return false;
    if (!out.points.empty() || !out.lines.empty()) {
      Impl::put_landmarks_tx(c, version, out.points, out.lines);
    }
    if (!out.changes.empty()) Impl::put_landmark_changes_tx(c, version, out.changes);
    if (!out.localization_tiles.empty()) {
      Impl::put_tiles_tx(c, version, TileLayer::Localization, out.localization_tiles);
    }
    c.run(
        "UPDATE build_jobs SET state = 'done', result_json = $1::jsonb, lease_until = 0 WHERE "
        "job_id = $2",
        out.result.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace), job);
    return true;
  });
}

bool PostgresMapStore::fail_build_job(std::int64_t job, int attempt, std::string_view error) {
  return impl_->transact([&](Connection& c) {
    const Result r = c.run(
        "UPDATE build_jobs SET state = 'failed', error = $3, lease_until = 0 WHERE job_id = $1 "
        "AND attempt = $2 AND state = 'running'",
        job, attempt, std::string(error));
    return r.affected() == 1;
  });
}

std::vector<BuildJob> PostgresMapStore::build_jobs(std::int64_t version) const {
  return impl_->read([&](Connection& c) {
    std::vector<BuildJob> out;
    const Result r = c.run(
        "SELECT " + job_columns() + " FROM build_jobs WHERE version = $1 ORDER BY job_id", version);
    for (int i = 0; i < r.rows(); ++i) out.push_back(Impl::build_job_from_row(r, i));
    return out;
  });
}

}  // namespace polmap::mapping
