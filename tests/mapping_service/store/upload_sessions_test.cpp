// Upload sessions in SqliteMapStore files of older builds: the migration that adds the table
// to a schema-2 store. Upload sessions themselves are tested on every backend in
// store_contract_uploads_test.cpp.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <fstream>

#include "mapping_service/store/exec_sql.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {
using testing::exec_sql;
namespace fs = std::filesystem;
using Clock = std::chrono::system_clock;
using Status = CreateUploadSessionResult::Status;

/// 2026-01-01T00:00:00Z: tests pass their own clock.
const Clock::time_point kT0 = Clock::from_time_t(1767225600);

UploadSessionRequest request(const std::string& owner, std::uint64_t bytes,
                             Clock::time_point now = kT0, std::int64_t ttl_s = 3600) {
  UploadSessionRequest r;
  r.owner = owner;
  r.length_bytes = bytes;
  r.now = now;
  r.ttl_s = ttl_s;
  return r;
}

TEST(UploadSessions, MigrationAddsTheTableToASchema2Store) {
  const test::TestDir tmp("uploads");
  const fs::path db = tmp.path() / "map.db";
  { SqliteMapStore store(db); }
  // What a build before resumable uploads left: schema 2, no upload_sessions.
  exec_sql(db,
           "DROP TABLE hdmap_comparisons; DROP INDEX landmarks_key; "
           "DROP TABLE localization_run_cells; DROP TABLE localization_runs; "
           "DROP TABLE build_jobs; DROP TABLE gridmap_sum_cover; DROP TABLE gridmap_sum_inputs; "
           "DROP TABLE gridmap_sums; "
           "DROP TABLE gridmap_mechanism_tiles; "
           "DROP TABLE upload_sessions; DROP TABLE landmark_changes; DROP INDEX "
           "landmarks_support_of; ALTER TABLE landmarks DROP COLUMN support_of; ALTER TABLE "
           "drive_trajectories DROP COLUMN path_blob; DELETE FROM schema_migrations WHERE "
           "version >= 3;");
  SqliteMapStore store(db);
  EXPECT_EQ(store.schema_version(), sqlite_store_migrations().back().version);
  EXPECT_EQ(sqlite_store_migrations().at(3).name, "resumable upload sessions");
  const auto c = store.create_upload_session(request("a", 10));
  ASSERT_EQ(c.status, Status::Created);
  EXPECT_TRUE(store.get_upload_session(c.session.id));
}

}  // namespace
}  // namespace polmap::mapping
