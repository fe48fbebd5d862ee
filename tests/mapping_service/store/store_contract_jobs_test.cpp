// The store contract, build jobs of partitioned builds, on every backend
// (store_backends.hpp): claims in order, each job to one worker at a time (also under
// concurrent claims from two store objects), the publish job last, re-claim after an expired
// lease with the old holder fenced off, output committed with the completion, a failed
// version failing its jobs, and queued builds surviving the sweep of a reopen.
#include <gtest/gtest.h>

#include <atomic>
#include <set>
#include <thread>

#include "mapping_service/store/contract_packages.hpp"
#include "mapping_service/store/store_backends.hpp"

namespace polmap::mapping::testing {
namespace {

using StoreJobs = StoreContract;

std::vector<BuildJobSpec> three_regions_and_publish() {
  return {{"region", {16, 1, 1}, {{"n", 1}}},
          {"region", {16, 1, 2}, {{"n", 2}}},
          {"region", {16, 2, 1}, {{"n", 3}}},
          {"publish", {0, 0, 0}, {{"n", 4}}}};
}

TEST_P(StoreJobs, JobsAreClaimedInOrderOnceEachAndThePublishJobLast) {
  MapStore& store = this->store();
  const auto v = store.begin_map_version({{"notes", "partitioned"}});
  store.enqueue_build_jobs(v, three_regions_and_publish());
  const auto a = store.claim_build_job("a", 30.0, std::nullopt);
  const auto b = store.claim_build_job("b", 30.0, v);
  const auto c = store.claim_build_job("c", 30.0, std::nullopt);
  ASSERT_TRUE(a && b && c);
  EXPECT_EQ(a->kind, "region");
  EXPECT_EQ(a->region, (tiles::TileKey{16, 1, 1}));
  EXPECT_EQ(a->spec.value("n", 0), 1);
  EXPECT_EQ(b->spec.value("n", 0), 2);
  EXPECT_EQ(c->spec.value("n", 0), 3);
  EXPECT_EQ(a->attempt, 1);
  EXPECT_EQ(a->state, BuildJobState::Running);
  EXPECT_GT(a->lease_left_s, 25.0);
  // The publish job waits for the others.
  EXPECT_FALSE(store.claim_build_job("d", 30.0, std::nullopt).has_value());
  EXPECT_TRUE(store.complete_build_job(a->id, a->attempt, {}));
  EXPECT_TRUE(store.complete_build_job(b->id, b->attempt, {}));
  EXPECT_FALSE(store.claim_build_job("d", 30.0, std::nullopt).has_value());
  BuildJobOutput out;
  out.result = {{"point_landmarks", 7}};
  EXPECT_TRUE(store.complete_build_job(c->id, c->attempt, out));
  EXPECT_FALSE(store.complete_build_job(c->id, c->attempt, out));  // done already
  const auto p = store.claim_build_job("d", 30.0, v);
  ASSERT_TRUE(p);
  EXPECT_EQ(p->kind, "publish");
  // Publishing the version completes its publish job in the same transaction.
  store.publish_map_version(v, {});
  const auto jobs = store.build_jobs(v);
  ASSERT_EQ(jobs.size(), 4U);
  for (const auto& j : jobs) EXPECT_EQ(j.state, BuildJobState::Done) << j.kind;
  EXPECT_EQ(jobs[2].result.value("point_landmarks", 0), 7);
  EXPECT_EQ(jobs[0].worker, "a");
  EXPECT_FALSE(store.claim_build_job("e", 30.0, std::nullopt).has_value());
}

TEST_P(StoreJobs, AnExpiredLeaseIsClaimedAgainAndTheOldHolderCannotCommit) {
  MapStore& store = this->store();
  (void)put_with_archive(store, tmp(), make_package("a", 5, 0, 1), "a", "A");
  const auto v = store.begin_map_version({});
  store.enqueue_build_jobs(v, three_regions_and_publish());
  const auto stale = store.claim_build_job("slow", 0.2, v);
  ASSERT_TRUE(stale);
  std::this_thread::sleep_for(std::chrono::milliseconds(350));
  EXPECT_FALSE(store.renew_build_job(stale->id, stale->attempt + 1, 30.0));  // not its attempt
  const auto again = store.claim_build_job("fast", 30.0, v);
  ASSERT_TRUE(again);
  EXPECT_EQ(again->id, stale->id);
  EXPECT_EQ(again->attempt, 2);
  EXPECT_EQ(again->worker, "fast");
  EXPECT_FALSE(store.renew_build_job(stale->id, stale->attempt, 30.0));
  EXPECT_TRUE(store.renew_build_job(again->id, again->attempt, 30.0));
  BuildJobOutput late;
  StoredPointLandmark p;
  p.key = 1;
  p.position = kOrigin;
  late.points.push_back(p);
  late.localization_tiles.push_back(
      {tiles::tile_at(kOrigin.lat_deg, kOrigin.lon_deg, 16), "", "late tile", false, 1, 0});
  EXPECT_FALSE(store.complete_build_job(stale->id, stale->attempt, late));
  EXPECT_FALSE(store.fail_build_job(stale->id, stale->attempt, "late failure"));
  EXPECT_TRUE(store.list_tiles(v, TileLayer::Localization).empty());  // nothing written
  // The current holder's output lands with its completion.
  EXPECT_TRUE(store.complete_build_job(again->id, again->attempt, late));
  EXPECT_EQ(store.list_tiles(v, TileLayer::Localization).size(), 1U);
}

TEST_P(StoreJobs, ConcurrentClaimsFromTwoStoreObjectsNeverShareAJob) {
  MapStore& one = this->store();
  const auto two = open();
  const auto v = one.begin_map_version({});
  std::vector<BuildJobSpec> specs;
  for (int i = 0; i < 40; ++i) specs.push_back({"region", {16, i, 7}, {}});
  one.enqueue_build_jobs(v, specs);
  std::mutex mu;
  std::multiset<std::int64_t> claimed;
  std::vector<std::thread> ts;
  for (int t = 0; t < 4; ++t) {
    ts.emplace_back([&, t] {
      MapStore& s = t % 2 == 0 ? one : *two;
      for (;;) {
        const auto j = s.claim_build_job("t", 30.0, v);
        if (!j) return;
        {
          std::lock_guard lock(mu);
          claimed.insert(j->id);
        }
        EXPECT_TRUE(s.complete_build_job(j->id, j->attempt, {}));
      }
    });
  }
  for (auto& t : ts) t.join();
  EXPECT_EQ(claimed.size(), 40U);
  EXPECT_EQ(std::set<std::int64_t>(claimed.begin(), claimed.end()).size(), 40U);
}

TEST_P(StoreJobs, AFailedVersionFailsItsJobsAndAQueuedBuildSurvivesAReopen) {
  MapStore& store = this->store();
  const auto failing = store.begin_map_version({});
  store.enqueue_build_jobs(failing, three_regions_and_publish());
  const auto held = store.claim_build_job("w", 30.0, failing);
  store.fail_map_version(failing, "a region job failed");
  for (const auto& j : store.build_jobs(failing)) EXPECT_EQ(j.state, BuildJobState::Failed);
  EXPECT_FALSE(store.claim_build_job("w", 30.0, std::nullopt).has_value());
  EXPECT_FALSE(store.complete_build_job(held->id, held->attempt, {}));

  const auto queued = store.begin_map_version({});
  store.enqueue_build_jobs(queued, three_regions_and_publish());
  close();
  // The owner's open sweeps builds left building; one with jobs left is queued, not dead.
  ContractOpenOptions no_grace;
  no_grace.orphan_grace_s = 0.0;
  const auto reopened = open(no_grace);
  ASSERT_TRUE(owns(*reopened));
  EXPECT_EQ(reopened->get_map_version(queued)->status, MapVersionStatus::Building);
  EXPECT_TRUE(reopened->claim_build_job("w", 30.0, queued).has_value());
  EXPECT_THROW(
      reopened->enqueue_build_jobs(queued, std::vector<BuildJobSpec>{{"nonsense", {}, {}}}),
      ValidationError);
}

POLMAP_STORE_CONTRACT_BACKENDS(StoreJobs);

}  // namespace
}  // namespace polmap::mapping::testing
