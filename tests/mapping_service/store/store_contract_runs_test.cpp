// The store contract, localization run reports, on every backend (store_backends.hpp): put
// with cells in one transaction, list newest first (per vehicle), the canonical bytes back
// unchanged, keep-the-newest pruning, delete with cells, and the cells summed over runs.
#include <gtest/gtest.h>

#include "mapping_service/store/store_backends.hpp"

namespace polmap::mapping::testing {
namespace {

using StoreRuns = StoreContract;

LocalizationRunRecord record(const std::string& vehicle, const std::string& label) {
  LocalizationRunRecord r;
  r.vehicle_id = vehicle;
  r.label = label;
  r.map_version = 3;
  r.samples = 42;
  r.bounds = GeoBox{48.4, 9.99, 48.41, 10.0};
  r.summary = {{"lat_rmse_m", 0.05}, {"label", label}};
  return r;
}

LocalizationRunCell cell(int x, int y, std::int64_t samples, std::int64_t degraded,
                         double err_max) {
  LocalizationRunCell c;
  c.z = 20;
  c.x = x;
  c.y = y;
  c.samples = samples;
  c.degraded = degraded;
  c.evaluated = samples / 2;
  c.sum_sigma_lat_m = 0.1 * static_cast<double>(samples);
  c.sum_err_lat2_m2 = 0.01 * static_cast<double>(samples);
  c.max_abs_err_lat_m = err_max;
  return c;
}

TEST_P(StoreRuns, PutListGetBodyAndDelete) {
  MapStore& store = this->store();
  EXPECT_TRUE(store.list_localization_runs(10).empty());
  // Bytes with a NUL and high bytes: the body is kept as bytes.
  const std::string body_a = std::string("{\"a\":1}\0\xff", 9);
  const std::vector<LocalizationRunCell> cells_a{cell(100, 200, 10, 2, 0.3)};
  const std::int64_t a = store.put_localization_run(record("veh-1", "first"), body_a, cells_a, 10);
  const std::int64_t b = store.put_localization_run(record("veh-2", "second"), "{}", {}, 10);
  EXPECT_GT(b, a);

  const auto all = store.list_localization_runs(10);
  ASSERT_EQ(all.size(), 2u);
  EXPECT_EQ(all[0].id, b);  // newest first
  EXPECT_EQ(all[1].id, a);
  EXPECT_EQ(all[1].vehicle_id, "veh-1");
  EXPECT_EQ(all[1].label, "first");
  EXPECT_EQ(all[1].map_version, 3);
  EXPECT_EQ(all[1].samples, 42);
  EXPECT_DOUBLE_EQ(all[1].bounds.max_lon_deg, 10.0);
  EXPECT_EQ(all[1].summary["label"], "first");
  EXPECT_EQ(all[1].received_at.size(), 20u);  // ISO 8601 UTC, whole seconds
  EXPECT_EQ(store.list_localization_runs(1).size(), 1u);
  const auto mine = store.list_localization_runs(10, "veh-1");
  ASSERT_EQ(mine.size(), 1u);
  EXPECT_EQ(mine[0].id, a);

  EXPECT_EQ(store.localization_run_body(a), body_a);
  EXPECT_EQ(store.get_localization_run(b)->label, "second");
  EXPECT_FALSE(store.get_localization_run(b + 100));
  EXPECT_FALSE(store.localization_run_body(b + 100));

  EXPECT_EQ(store.localization_run_cells(20, 0, 0, 1000, 1000, 100, RunCellRuns::All).size(), 1u);
  EXPECT_TRUE(store.delete_localization_run(a));
  EXPECT_FALSE(store.delete_localization_run(a));
  EXPECT_FALSE(store.get_localization_run(a));
  // Its cells went with it.
  EXPECT_TRUE(store.localization_run_cells(20, 0, 0, 1000, 1000, 100, RunCellRuns::All).empty());
}

TEST_P(StoreRuns, KeepsOnlyTheNewestRuns) {
  MapStore& store = this->store();
  std::vector<std::int64_t> ids;
  for (int i = 0; i < 5; ++i) {
    ids.push_back(store.put_localization_run(record("v", "run " + std::to_string(i)), "{}",
                                             std::vector{cell(i, i, 1, 0, 0.0)}, 3));
  }
  const auto kept = store.list_localization_runs(100);
  ASSERT_EQ(kept.size(), 3u);
  EXPECT_EQ(kept[0].id, ids[4]);
  EXPECT_EQ(kept[2].id, ids[2]);
  EXPECT_FALSE(store.localization_run_body(ids[1]));
  EXPECT_EQ(store.localization_run_cells(20, 0, 0, 10, 10, 100, RunCellRuns::All).size(), 3u);
  EXPECT_THROW(store.put_localization_run(record("v", "x"), "{}", {}, 0), ValidationError);
  LocalizationRunRecord bad = record("v", "x");
  bad.bounds.min_lat_deg = std::nan("");
  EXPECT_THROW(store.put_localization_run(bad, "{}", {}, 3), ValidationError);
  EXPECT_THROW(store.put_localization_run(record("v", "x"), "{}",
                                          std::vector{cell(1 << 20, 0, 1, 0, 0.0)}, 3),
               ValidationError);
  EXPECT_EQ(store.list_localization_runs(100).size(), 3u);  // refused writes left nothing
}

TEST_P(StoreRuns, CellsAreSummedOverRunsWithinTheBox) {
  MapStore& store = this->store();
  (void)store.put_localization_run(
      record("v", "a"), "{}", std::vector{cell(10, 20, 10, 1, 0.2), cell(11, 20, 4, 4, 0.9)}, 10);
  (void)store.put_localization_run(
      record("w", "b"), "{}", std::vector{cell(10, 20, 6, 3, 0.5), cell(50, 50, 1, 0, 0.0)}, 10);
  const auto cells = store.localization_run_cells(20, 0, 0, 20, 30, 100, RunCellRuns::All);
  ASSERT_EQ(cells.size(), 2u);  // (50, 50) is outside the box
  const auto& c = cells[0];
  EXPECT_EQ(c.x, 10);
  EXPECT_EQ(c.y, 20);
  EXPECT_EQ(c.z, 20);
  EXPECT_EQ(c.samples, 16);
  EXPECT_EQ(c.degraded, 4);
  EXPECT_EQ(c.evaluated, 5 + 3);
  EXPECT_NEAR(c.sum_sigma_lat_m, 1.6, 1e-12);
  EXPECT_NEAR(c.sum_err_lat2_m2, 0.16, 1e-12);
  EXPECT_DOUBLE_EQ(c.max_abs_err_lat_m, 0.5);
  EXPECT_EQ(c.runs, 2);
  EXPECT_EQ(cells[1].x, 11);
  EXPECT_EQ(cells[1].runs, 1);
  EXPECT_EQ(store.localization_run_cells(20, 0, 0, 100, 100, 1, RunCellRuns::All).size(),
            1u);  // limit
  EXPECT_TRUE(store.localization_run_cells(19, 0, 0, 100, 100, 100, RunCellRuns::All)
                  .empty());  // other zoom
}

TEST_P(StoreRuns, ACellCanBeJudgedByTheRunsAgainstItsNewestMapVersion) {
  MapStore& store = this->store();
  auto at_version = [](std::int64_t v, const std::string& label) {
    LocalizationRunRecord r = record("v", label);
    r.map_version = v;
    return r;
  };
  // Cell (10, 20): two bad runs against version 3, then one good run against version 4
  // (the map was fixed there). Cell (11, 20): version 3 only.
  (void)store.put_localization_run(
      at_version(3, "a"), "{}", std::vector{cell(10, 20, 10, 8, 0.9), cell(11, 20, 5, 5, 0.9)}, 10);
  (void)store.put_localization_run(at_version(3, "b"), "{}", std::vector{cell(10, 20, 10, 6, 0.8)},
                                   10);
  (void)store.put_localization_run(at_version(4, "c"), "{}", std::vector{cell(10, 20, 10, 0, 0.1)},
                                   10);
  const auto all = store.localization_run_cells(20, 0, 0, 20, 30, 100, RunCellRuns::All);
  ASSERT_EQ(all.size(), 2u);
  EXPECT_EQ(all[0].runs, 3);
  EXPECT_EQ(all[0].samples, 30);
  EXPECT_EQ(all[0].degraded, 14);
  EXPECT_EQ(all[0].map_version, 4);
  const auto now =
      store.localization_run_cells(20, 0, 0, 20, 30, 100, RunCellRuns::NewestMapVersion);
  ASSERT_EQ(now.size(), 2u);
  EXPECT_EQ(now[0].runs, 1);  // only the run against version 4
  EXPECT_EQ(now[0].samples, 10);
  EXPECT_EQ(now[0].degraded, 0);
  EXPECT_DOUBLE_EQ(now[0].max_abs_err_lat_m, 0.1);
  EXPECT_EQ(now[0].map_version, 4);
  EXPECT_EQ(now[1].x, 11);  // a cell no later run passed keeps its runs
  EXPECT_EQ(now[1].runs, 1);
  EXPECT_EQ(now[1].map_version, 3);
}

POLMAP_STORE_CONTRACT_BACKENDS(StoreRuns);

}  // namespace
}  // namespace polmap::mapping::testing
