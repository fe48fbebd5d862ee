// The store contract, resumable upload sessions, on every backend (store_backends.hpp):
// create, get, the offset's compare-and-set, delete, per-owner quota (also under concurrent
// creates), the sweep of expired sessions (and only those), and crash leftovers.
#include <gtest/gtest.h>

#include <atomic>
#include <fstream>
#include <thread>

#include "mapping_service/store/contract_packages.hpp"
#include "mapping_service/store/store_backends.hpp"

namespace polmap::mapping::testing {
namespace {
namespace fs = std::filesystem;
using Clock = std::chrono::system_clock;
using Status = CreateUploadSessionResult::Status;

using StoreUploads = StoreContract;

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

TEST_P(StoreUploads, CreateGetAdvanceAndDelete) {
  MapStore& store = this->store();
  UploadSessionRequest r = request("owner-a", 1000);
  r.sha256 = std::string(64, 'a');
  const auto c = store.create_upload_session(r);
  ASSERT_EQ(c.status, Status::Created);
  const UploadSession& s = c.session;
  EXPECT_EQ(s.id.size(), 32U);
  EXPECT_EQ(s.id.find_first_not_of("0123456789abcdef"), std::string::npos) << s.id;
  EXPECT_EQ(s.file, upload_dir() / s.id);
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
  EXPECT_EQ(got->created_at, s.created_at);
  EXPECT_EQ(got->expires_at, s.expires_at);
  EXPECT_EQ(got->file, s.file);
  EXPECT_FALSE(store.get_upload_session(std::string(32, '0')));
  const auto plain = store.create_upload_session(request("owner-a", 10)).session;
  EXPECT_EQ(store.get_upload_session(plain.id)->sha256, "");

  // The offset moves only from the value the caller saw, forward, within the length.
  EXPECT_TRUE(store.advance_upload_offset(s.id, 0, 400));
  EXPECT_FALSE(store.advance_upload_offset(s.id, 0, 500));  // someone else moved it
  EXPECT_EQ(store.get_upload_session(s.id)->offset_bytes, 400U);
  EXPECT_THROW((void)store.advance_upload_offset(s.id, 400, 1001), ValidationError);
  EXPECT_THROW((void)store.advance_upload_offset(s.id, 400, 400), ValidationError);
  EXPECT_TRUE(store.advance_upload_offset(s.id, 400, 1000));
  EXPECT_EQ(store.get_upload_session(s.id)->offset_bytes, 1000U);
  EXPECT_FALSE(store.advance_upload_offset(std::string(32, '0'), 0, 1));

  // A second store object on the same storage (another replica) sees the same session.
  {
    const auto replica = open();
    EXPECT_EQ(replica->get_upload_session(s.id)->offset_bytes, 1000U);
  }

  EXPECT_TRUE(store.delete_upload_session(s.id));
  EXPECT_FALSE(store.get_upload_session(s.id));
  EXPECT_FALSE(fs::exists(s.file));
  EXPECT_FALSE(store.delete_upload_session(s.id));
}

TEST_P(StoreUploads, RequestsAreValidated) {
  MapStore& store = this->store();
  EXPECT_THROW((void)store.create_upload_session(request("", 10)), ValidationError);
  EXPECT_THROW((void)store.create_upload_session(request("o", 0)), ValidationError);
  EXPECT_THROW((void)store.create_upload_session(request("o", ~0ULL)), ValidationError);
  EXPECT_THROW((void)store.create_upload_session(request("o", 10, kT0, 0)), ValidationError);
  UploadSessionRequest bad_sha = request("o", 10);
  bad_sha.sha256 = std::string(64, 'A');
  EXPECT_THROW((void)store.create_upload_session(bad_sha), ValidationError);
  bad_sha.sha256 = "abc";
  EXPECT_THROW((void)store.create_upload_session(bad_sha), ValidationError);
  EXPECT_TRUE(fs::is_empty(upload_dir()));  // no file for a refused request
}

TEST_P(StoreUploads, QuotaCountsTheOwnersUnexpiredSessions) {
  MapStore& store = this->store();
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
  EXPECT_EQ(std::distance(fs::directory_iterator(upload_dir()), {}), 3);
  // Expired sessions (not yet swept) no longer count.
  const auto later = kT0 + std::chrono::hours(2);
  EXPECT_EQ(store.create_upload_session(with_limits(request("a", 1000, later))).status,
            Status::Created);
}

TEST_P(StoreUploads, ConcurrentCreatesOnTwoStoreObjectsStayWithinTheQuota) {
  const auto one = open();
  const auto two = open();
  std::atomic<int> created{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 6; ++t) {
    MapStore& s = t % 2 == 0 ? *one : *two;
    threads.emplace_back([&s, &created] {
      UploadSessionRequest r = request("same-key", 10);
      r.max_sessions_per_owner = 3;
      if (s.create_upload_session(r).status == Status::Created) ++created;
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(created, 3);
  EXPECT_EQ(std::distance(fs::directory_iterator(upload_dir()), {}), 3);
}

TEST_P(StoreUploads, TheSweepRemovesExpiredSessionsOnly) {
  MapStore& store = this->store();
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
  EXPECT_TRUE(fs::is_empty(upload_dir()));
}

TEST_P(StoreUploads, ACompletedSessionKeepsItsAnswerUntilItExpiresAndFreesItsQuota) {
  MapStore& store = this->store();
  UploadSessionRequest r = request("a", 10);
  r.max_sessions_per_owner = 1;
  const auto s = store.create_upload_session(r).session;
  ASSERT_TRUE(store.advance_upload_offset(s.id, 0, 5));
  EXPECT_EQ(store.create_upload_session(r).status, Status::TooManySessions);
  EXPECT_FALSE(store.get_upload_session(s.id)->outcome);

  const UploadOutcome o{201, "/v1/drives/d1", R"({"drive_id":"d1","status":"inserted"})"};
  ASSERT_TRUE(store.complete_upload_session(s.id, o));
  const auto got = store.get_upload_session(s.id);
  ASSERT_TRUE(got && got->outcome);
  EXPECT_EQ(got->outcome->http_status, 201);
  EXPECT_EQ(got->outcome->location, o.location);
  EXPECT_EQ(got->outcome->body, o.body);
  EXPECT_EQ(got->offset_bytes, 5U);
  EXPECT_FALSE(fs::exists(s.file));  // the bytes are no longer needed
  // Complete once: no second outcome, no more bytes.
  EXPECT_FALSE(store.complete_upload_session(s.id, {200, "", "{}"}));
  EXPECT_EQ(store.get_upload_session(s.id)->outcome->http_status, 201);
  EXPECT_FALSE(store.advance_upload_offset(s.id, 5, 10));
  EXPECT_EQ(store.get_upload_session(s.id)->offset_bytes, 5U);
  EXPECT_FALSE(store.complete_upload_session(std::string(32, '0'), o));
  EXPECT_THROW((void)store.complete_upload_session(s.id, {500, "", "{}"}), ValidationError);
  EXPECT_THROW((void)store.complete_upload_session(s.id, {199, "", "{}"}), ValidationError);
  // It no longer counts against its owner's limit.
  const auto next = store.create_upload_session(r);
  EXPECT_EQ(next.status, Status::Created);
  // The sweep removes it when it expires, as any session.
  EXPECT_EQ(store.sweep_expired_upload_sessions(kT0 + std::chrono::seconds(3600)), 2U);
  EXPECT_FALSE(store.get_upload_session(s.id));
  EXPECT_TRUE(fs::is_empty(upload_dir()));
}

TEST_P(StoreUploads, ReopenRemovesSessionFilesWithoutARow) {
  ContractOpenOptions o;
  o.orphan_grace_s = 0;
  UploadSession live;
  fs::path orphan;
  {
    const auto store = open(o);
    live = store->create_upload_session(request("a", 10, Clock::now())).session;
    // What a crash between creating the file and committing its row leaves.
    orphan = upload_dir() / std::string(32, 'f');
    std::ofstream(orphan) << "partial";
    std::ofstream(upload_dir() / "not-ours.txt") << "x";
  }
  const auto reopened = open(o);
  EXPECT_FALSE(fs::exists(orphan));
  EXPECT_TRUE(fs::exists(live.file));
  EXPECT_TRUE(fs::exists(upload_dir() / "not-ours.txt"));
  EXPECT_TRUE(reopened->get_upload_session(live.id));
}

POLMAP_STORE_CONTRACT_BACKENDS(StoreUploads);

}  // namespace
}  // namespace polmap::mapping::testing
