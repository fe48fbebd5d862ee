#pragma once
/// @file landmark_diff.hpp
/// What changed between two map versions: landmarks added, moved or retired.
/// Pure core (values in, values out). Used by the MapBuilder, which records each
/// change with its reason when it publishes a version, and by the server's
/// `GET /v1/maps/{v}/diff?from=U`, which compares any two published versions and
/// attaches the recorded reasons.
///
/// Matching (distances in metres, in a local frame at the first landmark):
///  1. same stable key (landmark_key: identical quantized geometry) -> unchanged;
///  2. otherwise, nearest pairs first, one-to-one, within match_radius_m (points:
///     position distance; lines: mean distance of the new line's samples to the
///     old polyline, symmetric) -> refined when closer than moved_min_m (the
///     estimate improved with more drives; not listed), moved otherwise;
///  3. new landmarks left over are added, old ones left over retired.
///
/// Usage:
///   LandmarkDiff d = diff_landmarks(store.landmarks_in(u, box, false),
///                                   store.landmarks_in(v, box, false));
///   for (const LandmarkChange& c : d.changes) ...
#include <vector>

#include "polmap/mapping_service/store.hpp"

namespace polmap::mapping {

struct LandmarkDiffConfig {
  /// Farther apart than this, an old and a new landmark are different objects.
  double match_radius_m = 1.0;
  /// Closer than this they are the same object, re-estimated (not a move).
  double moved_min_m = 0.1;
  /// Line samples every this many metres for the line distance.
  double line_sample_m = 0.5;
};

struct LandmarkDiff {
  std::vector<LandmarkChange> changes;  ///< points first, then lines; each by key
  std::int64_t unchanged = 0;           ///< same key in both
  std::int64_t refined = 0;             ///< matched, moved less than moved_min_m
};

/// Changes from `from` to `to` (see the file comment). `reason` is left empty.
LandmarkDiff diff_landmarks(const LandmarkSet& from, const LandmarkSet& to,
                            const LandmarkDiffConfig& cfg = {});

}  // namespace polmap::mapping
