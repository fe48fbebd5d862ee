#pragma once
/// @file polyline_simplify.hpp
/// Douglas–Peucker simplification of polylines (MVT trajectories, stored drive paths),
/// with the distance to the chord *segment*, so paths that turn back keep their ends.
/// Iterative with an explicit stack: the depth of the recursion it replaces grows with
/// the number of vertices on hostile input (a zig-zag), the stack here lives on the heap.
#include <Eigen/Core>
#include <vector>

#include "polmap/schema/geo.hpp"

namespace polmap::tiles {

/// Which vertices of `points_m` (metric, one frame) Douglas–Peucker keeps at tolerance
/// `tol_m` > 0: every dropped vertex is within tol_m of the kept polyline (segment distance). The
/// first and last vertex are always kept. O(n log n) typical, O(n^2) worst case, O(n) memory.
/// `window` > 0: the polyline is simplified in pieces of that many edges, each piece's
/// ends kept; the worst case (a hostile zig-zag) is then O(n · window) — for whole drive
/// paths. 0: one piece.
[[nodiscard]] std::vector<bool> douglas_peucker_keep(const std::vector<Eigen::Vector2d>& points_m,
                                                     double tol_m, std::size_t window = 0);

/// A geodetic polyline simplified to `tol_m` metres (in the local frame of its first
/// vertex); `window` as for douglas_peucker_keep.
[[nodiscard]] std::vector<GeoPoint> simplify_polyline(const std::vector<GeoPoint>& polyline,
                                                      double tol_m, std::size_t window = 0);

}  // namespace polmap::tiles
