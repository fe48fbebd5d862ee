// Upload sessions of SqliteMapStore against a real SQLite file in a temp dir: create, get,
// the offset's compare-and-set, delete, per-owner quota, the sweep of expired sessions (and
// only those), crash leftovers, and the migration that adds the table to an older store.
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

TEST(UploadSessions, CreateGetAdvanceAndDelete) {
  const test::TestDir tmp("uploads");
  SqliteMapStore store(tmp.path() / "map.db");
  UploadSessionRequest r = request("owner-a", 1000);
  r.sha256 = std::string(64, 'a');
  const auto c = store.create_upload_session(r);
  ASSERT_EQ(c.status, Status::Created);
  const UploadSession& s = c.session;
  EXPECT_EQ(s.id.size(), 32U);
  EXPECT_EQ(s.id.find_first_not_of("0123456789abcdef"), std::string::npos) << s.id;
  EXPECT_EQ(s.file, store.upload_session_dir() / s.id);
  ASSERT_TRUE(fs::is_regular_file(s.file));
  EXPECT_EQ(fs::file_size(s.file), 0U);
  EXPECT_EQ(s.created_at, "2026-01-01T00:00:00Z");
  EXPECT_EQ(s.expires_at, "2026-01-01T01:00:00Z");

  auto got = store.get_upload_session(s.id);
  ASSERT_TRUE(got);
  EXPECT_EQ(got->owner, "owner-a");
  EXPECT_EQ(got->length_bytes, 1000U);
  EXPECT_EQ(got->offset_bytes, 0U);
  EXPECT_EQ(got->sha256, std::string(64, 'a'));
  EXPECT_EQ(got->expires_at, s.expires_at);
  EXPECT_FALSE(store.get_upload_session(std::string(32, '0')));

  // The offset moves only from the value the caller saw, forward, within the length.
  EXPECT_TRUE(store.advance_upload_offset(s.id, 0, 400));
  EXPECT_FALSE(store.advance_upload_offset(s.id, 0, 500));  // someone else moved it
  EXPECT_EQ(store.get_upload_session(s.id)->offset_bytes, 400U);
  EXPECT_THROW((void)store.advance_upload_offset(s.id, 400, 1001), ValidationError);
  EXPECT_THROW((void)store.advance_upload_offset(s.id, 400, 400), ValidationError);
  EXPECT_TRUE(store.advance_upload_offset(s.id, 400, 1000));
  EXPECT_EQ(store.get_upload_session(s.id)->offset_bytes, 1000U);
  EXPECT_FALSE(store.advance_upload_offset(std::string(32, '0'), 0, 1));

  // A second store object on the same files (another replica) sees the same session.
  {
    SqliteMapStore replica(tmp.path() / "map.db");
    EXPECT_EQ(replica.get_upload_session(s.id)->offset_bytes, 1000U);
  }

  EXPECT_TRUE(store.delete_upload_session(s.id));
  EXPECT_FALSE(store.get_upload_session(s.id));
  EXPECT_FALSE(fs::exists(s.file));
  EXPECT_FALSE(store.delete_upload_session(s.id));
}

TEST(UploadSessions, RequestsAreValidated) {
  const test::TestDir tmp("uploads");
  SqliteMapStore store(tmp.path() / "map.db");
  EXPECT_THROW((void)store.create_upload_session(request("", 10)), ValidationError);
  EXPECT_THROW((void)store.create_upload_session(request("o", 0)), ValidationError);
  EXPECT_THROW((void)store.create_upload_session(request("o", ~0ULL)), ValidationError);
  EXPECT_THROW((void)store.create_upload_session(request("o", 10, kT0, 0)), ValidationError);
  UploadSessionRequest bad_sha = request("o", 10);
  bad_sha.sha256 = std::string(64, 'A');
  EXPECT_THROW((void)store.create_upload_session(bad_sha), ValidationError);
  bad_sha.sha256 = "abc";
  EXPECT_THROW((void)store.create_upload_session(bad_sha), ValidationError);
  EXPECT_TRUE(fs::is_empty(store.upload_session_dir()));  // no file for a refused request
}

TEST(UploadSessions, QuotaCountsTheOwnersUnexpiredSessions) {
  const test::TestDir tmp("uploads");
  SqliteMapStore store(tmp.path() / "map.db");
  auto with_limits = [](UploadSessionRequest r) {
    r.max_sessions_per_owner = 2;
    r.max_bytes_per_owner = 1000;
    return r;
  };
  EXPECT_EQ(store.create_upload_session(with_limits(request("a", 300))).status, Status::Created);
  EXPECT_EQ(store.create_upload_session(with_limits(request("a", 300))).status, Status::Created);
  const auto third = store.create_upload_session(with_limits(request("a", 10)));
  EXPECT_EQ(third.status, Status::TooManySessions);
  EXPECT_EQ(third.open_sessions, 2U);
  EXPECT_EQ(third.open_bytes, 600U);
  // Another owner has its own quota; its bytes are limited too.
  EXPECT_EQ(store.create_upload_session(with_limits(request("b", 900))).status, Status::Created);
  const auto over = store.create_upload_session(with_limits(request("b", 101)));
  EXPECT_EQ(over.status, Status::TooManyBytes);
  EXPECT_EQ(over.open_bytes, 900U);
  EXPECT_EQ(std::distance(fs::directory_iterator(store.upload_session_dir()), {}), 3);
  // Expired sessions (not yet swept) no longer count.
  const auto later = kT0 + std::chrono::hours(2);
  EXPECT_EQ(store.create_upload_session(with_limits(request("a", 1000, later))).status,
            Status::Created);
}

TEST(UploadSessions, TheSweepRemovesExpiredSessionsOnly) {
  const test::TestDir tmp("uploads");
  SqliteMapStore store(tmp.path() / "map.db");
  const auto short_lived = store.create_upload_session(request("a", 10, kT0, 60)).session;
  const auto long_lived = store.create_upload_session(request("a", 10, kT0, 3600)).session;
  ASSERT_TRUE(store.advance_upload_offset(long_lived.id, 0, 5));

  EXPECT_EQ(store.sweep_expired_upload_sessions(kT0 + std::chrono::seconds(59)), 0U);
  EXPECT_TRUE(store.get_upload_session(short_lived.id));
  EXPECT_TRUE(fs::exists(short_lived.file));

  EXPECT_EQ(store.sweep_expired_upload_sessions(kT0 + std::chrono::seconds(60)), 1U);
  EXPECT_FALSE(store.get_upload_session(short_lived.id));
  EXPECT_FALSE(fs::exists(short_lived.file));
  const auto kept = store.get_upload_session(long_lived.id);
  ASSERT_TRUE(kept);  // unexpired: untouched, offset and file kept
  EXPECT_EQ(kept->offset_bytes, 5U);
  EXPECT_TRUE(fs::exists(long_lived.file));

  EXPECT_EQ(store.sweep_expired_upload_sessions(kT0 + std::chrono::seconds(3600)), 1U);
  EXPECT_TRUE(fs::is_empty(store.upload_session_dir()));
}

TEST(UploadSessions, ReopenRemovesSessionFilesWithoutARow) {
  const test::TestDir tmp("uploads");
  const fs::path db = tmp.path() / "map.db";
  SqliteStoreOptions o;
  o.orphan_grace_s = 0;
  UploadSession live;
  fs::path orphan;
  {
    SqliteMapStore store(db, o);
    live = store.create_upload_session(request("a", 10, Clock::now())).session;
    // What a crash between creating the file and committing its row leaves.
    orphan = store.upload_session_dir() / std::string(32, 'f');
    std::ofstream(orphan) << "partial";
    std::ofstream(store.upload_session_dir() / "not-ours.txt") << "x";
  }
  SqliteMapStore reopened(db, o);
  EXPECT_FALSE(fs::exists(orphan));
  EXPECT_TRUE(fs::exists(live.file));
  EXPECT_TRUE(fs::exists(reopened.upload_session_dir() / "not-ours.txt"));
  EXPECT_TRUE(reopened.get_upload_session(live.id));
}

TEST(UploadSessions, MigrationAddsTheTableToASchema2Store) {
  const test::TestDir tmp("uploads");
  const fs::path db = tmp.path() / "map.db";
  { SqliteMapStore store(db); }
  // What a build before resumable uploads left: schema 2, no upload_sessions.
  exec_sql(db,
           "DROP TABLE gridmap_sum_cover; DROP TABLE gridmap_sum_inputs; DROP TABLE gridmap_sums; "
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
