#pragma once
#include <functional>
#include <string_view>
// Internal: the server's adapter to MapBuilder (map_builder.hpp). Kept apart so the
// HTTP side does not depend on the builder's request/result types.
#include <atomic>
#include <cstdint>
#include <nlohmann/json.hpp>

#include "polmap/mapping_service/store.hpp"

namespace polmap::mapping {

/// Creates the Building version for a validated POST /v1/maps request
/// ({"region": {...}?, "exclude_drives": [...], "notes"?}) and returns its number.
std::int64_t begin_build(MapStore& store, const nlohmann::json& request);

/// Runs the build of a version created by begin_build: consensus, tiles, publish.
/// Returns the build statistics; throws on failure (the caller fails the version).
/// A partitioned build ({"partition": {"zoom", "halo_m"}} in the request) runs its jobs
/// here when run_jobs, else waits for `polmap build-worker` processes to run them.
/// `progress` (may be empty) receives the stage and the fraction done.
nlohmann::json execute_build(MapStore& store, std::int64_t version, const nlohmann::json& request,
                             const std::atomic<bool>& stop, bool run_jobs,
                             const std::function<void(std::string_view, double)>& progress);

}  // namespace polmap::mapping
