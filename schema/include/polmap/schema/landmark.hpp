#pragma once
/// @file landmark.hpp
/// Landmark candidates (one drive or one localization window) and consensus
/// map landmarks. Positions are metres in a local metric frame named by the
/// container (a drive package's frame, a map region's frame, a client's map
/// frame); all such frames are transverse Mercator frames of tiles/.
#include <Eigen/Core>
#include <cstdint>
#include <string_view>
#include <vector>

namespace polmap {

/// Dominant scattering mechanism of a point (from its LR-basis covariance).
enum class ScatteringClass : std::uint8_t { Unknown = 0, Odd = 1, Even = 2, Mixed = 3 };

inline std::string_view to_string(ScatteringClass c) {
  switch (c) {
    case ScatteringClass::Odd:
      return "odd";
    case ScatteringClass::Even:
      return "even";
    case ScatteringClass::Mixed:
      return "mixed";
    default:
      return "unknown";
  }
}

/// A point-shaped landmark candidate (pCFAR centroid).
struct PointCandidate {
  Eigen::Vector2d position_m = Eigen::Vector2d::Zero();
  double strength = 0.0;  ///< peak Wishart distance of the component
  double power_db = 0.0;  ///< trace(C) at the centroid, dB
  ScatteringClass scattering = ScatteringClass::Unknown;
  std::uint32_t num_cells = 0;
};

/// A line-shaped landmark candidate (Hough segment).
struct LineCandidate {
  Eigen::Vector2d start_m = Eigen::Vector2d::Zero();
  Eigen::Vector2d end_m = Eigen::Vector2d::Zero();
  double strength = 0.0;  ///< mean ridgeness along the segment
};

/// A consensus point landmark of a map.
struct PointLandmark {
  std::int64_t id = 0;
  Eigen::Vector2d position_m = Eigen::Vector2d::Zero();
  ScatteringClass scattering = ScatteringClass::Unknown;
  std::uint32_t support_drives = 0;  ///< number of distinct drives that saw it
  double spread_m = 0.0;             ///< RMS distance of members to the mean
};

/// A consensus line landmark: a polyline (two points for a straight segment).
struct LineLandmark {
  std::int64_t id = 0;
  std::vector<Eigen::Vector2d> polyline_m;
  std::uint32_t support_drives = 0;
  double spread_m = 0.0;
};

}  // namespace polmap
