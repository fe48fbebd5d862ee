// The store contract, the merged gridmap's sum tiles, on every backend (store_backends.hpp):
// a commit writes tiles and records the input (with its cover) atomically, a drive cannot be
// added twice, range and "changed since" queries return exactly the matching tiles, and
// removing an input takes its cover with it while its tiles stay as written.
#include <gtest/gtest.h>

#include "mapping_service/store/store_backends.hpp"

namespace polmap::mapping::testing {
namespace {

using StoreGridmapSums = StoreContract;

GridmapSumRow row(int level, int x, int y, std::string data) {
  return {level, x, y, std::move(data), 0};
}

GridmapSumInputChange add(std::string hash, std::vector<std::array<int, 3>> cover) {
  GridmapSumInputChange c;
  c.kind = GridmapSumInputChange::Kind::Add;
  c.content_hash = std::move(hash);
  c.cover = std::move(cover);
  return c;
}

TEST_P(StoreGridmapSums, CommitWritesTilesAndRecordsTheInputWithItsCover) {
  MapStore& store = this->store();
  const std::vector<GridmapSumRow> tiles{row(0, 10, 20, "t1"), row(0, 11, 20, "t2"),
                                         row(3, 10, 20, std::string("t3\0bytes", 8))};
  store.commit_gridmap_sums(5, tiles, add("h1", {{0, 10, 20}, {0, 11, 20}, {3, 10, 20}}));
  const auto inputs = store.gridmap_sum_inputs();
  ASSERT_EQ(inputs.size(), 1U);
  EXPECT_EQ(inputs[0].content_hash, "h1");
  EXPECT_EQ(inputs[0].tiles, 3);
  EXPECT_EQ(store.gridmap_sum_cover("h1").size(), 3U);
  EXPECT_EQ(store.gridmap_sum_contributors(0, 11, 20), std::vector<std::string>{"h1"});
  EXPECT_TRUE(store.gridmap_sum_contributors(0, 12, 20).empty());
  // Range query: all levels, inclusive bounds.
  const auto in = store.gridmap_sums_in(10, 20, 10, 20);
  ASSERT_EQ(in.size(), 2U);
  EXPECT_EQ(in[0].level, 0);
  EXPECT_EQ(in[0].data, "t1");
  EXPECT_EQ(in[0].updated_by, 5);
  EXPECT_EQ(in[1].level, 3);
  EXPECT_EQ(in[1].data, std::string("t3\0bytes", 8));  // bytes, not text
  EXPECT_EQ(store.gridmap_sums_in(0, 0, 9, 100).size(), 0U);
  EXPECT_EQ(store.gridmap_sums_in(10, 20, 11, 21).size(), 3U);
}

TEST_P(StoreGridmapSums, AnInputKeepsHowItsGridmapWasPlaced) {
  MapStore& store = this->store();
  GridmapSumInputChange moved = add("aligned", {{0, 2, 2}});
  moved.placement = std::string("{\"v\":1,\"nodes\":[0.25,-1.5]}\n\t\"x\"", 32);
  const std::vector<GridmapSumRow> t1{row(0, 2, 2, "a")};
  store.commit_gridmap_sums(1, t1, moved);
  const std::vector<GridmapSumRow> t2{row(0, 3, 2, "b")};
  store.commit_gridmap_sums(1, t2, add("as-uploaded", {{0, 3, 2}}));
  const auto inputs = store.gridmap_sum_inputs();
  ASSERT_EQ(inputs.size(), 2U);
  EXPECT_EQ(inputs[0].content_hash, "aligned");
  EXPECT_EQ(inputs[0].placement, moved.placement);
  EXPECT_EQ(inputs[1].content_hash, "as-uploaded");
  EXPECT_EQ(inputs[1].placement, "");
}

TEST_P(StoreGridmapSums, AddingADriveTwiceIsAConflictAndWritesNothing) {
  MapStore& store = this->store();
  const std::vector<GridmapSumRow> first{row(0, 1, 1, "one")};
  store.commit_gridmap_sums(1, first, add("h", {{0, 1, 1}}));
  const std::vector<GridmapSumRow> again{row(0, 1, 1, "twice")};
  EXPECT_THROW(store.commit_gridmap_sums(2, again, add("h", {{0, 1, 1}})), ConflictError);
  EXPECT_EQ(store.gridmap_sums_in(1, 1, 1, 1).at(0).data, "one");  // the transaction rolled back
  GridmapSumInputChange nameless;
  nameless.kind = GridmapSumInputChange::Kind::Add;
  EXPECT_THROW(store.commit_gridmap_sums(2, again, nameless), ValidationError);
}

TEST_P(StoreGridmapSums, KeysChangedAfterAVersionAndRemovalOfAnInput) {
  MapStore& store = this->store();
  const std::vector<GridmapSumRow> a{row(0, 1, 1, "a1"), row(0, 2, 1, "a2")};
  store.commit_gridmap_sums(3, a, add("ha", {{0, 1, 1}, {0, 2, 1}}));
  const std::vector<GridmapSumRow> b{row(0, 2, 1, "a2+b"), row(0, 3, 1, "b")};
  store.commit_gridmap_sums(7, b, add("hb", {{0, 2, 1}, {0, 3, 1}}));
  EXPECT_EQ(store.gridmap_sum_keys(std::nullopt).size(), 3U);
  const auto changed = store.gridmap_sum_keys(3);
  ASSERT_EQ(changed.size(), 2U);
  EXPECT_EQ(changed[0].x, 2);
  EXPECT_EQ(changed[1].x, 3);
  EXPECT_TRUE(changed[0].data.empty());  // keys only
  EXPECT_EQ(store.gridmap_sum_contributors(0, 2, 1), (std::vector<std::string>{"ha", "hb"}));
  // Remove b: its tiles rewritten by the caller, its cover gone.
  GridmapSumInputChange rm;
  rm.kind = GridmapSumInputChange::Kind::Remove;
  rm.content_hash = "hb";
  const std::vector<GridmapSumRow> back{row(0, 2, 1, "a2"), row(0, 3, 1, "")};
  store.commit_gridmap_sums(9, back, rm);
  EXPECT_EQ(store.gridmap_sum_inputs().size(), 1U);
  EXPECT_TRUE(store.gridmap_sum_cover("hb").empty());
  EXPECT_EQ(store.gridmap_sum_contributors(0, 2, 1), std::vector<std::string>{"ha"});
  EXPECT_EQ(store.gridmap_sums_in(2, 1, 2, 1).at(0).data, "a2");
  EXPECT_EQ(store.gridmap_sum_keys(7).size(), 2U);  // both rewritten by version 9
}

POLMAP_STORE_CONTRACT_BACKENDS(StoreGridmapSums);

}  // namespace
}  // namespace polmap::mapping::testing
