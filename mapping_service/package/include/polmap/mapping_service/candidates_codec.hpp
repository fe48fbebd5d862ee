#pragma once
/// @file candidates_codec.hpp
/// candidates.bin, the compact candidates file of drive package format 2
/// (schema/drive_package.md, "candidates.bin"): point and line candidates and the
/// trajectory as quantized, delta-coded columns in one zlib stream — a few bytes per
/// feature instead of the GeoPackage's ~400 (and no ~100 kB fixed structure), so a
/// landmarks-only package of an urban kilometre is ~15 kB. Pure: bytes in, values out.
///
/// Quantization (stated in the format document): drive-frame point positions 1 mm, line
/// ends 1 cm, lat/lon 1e-8° (1.1 mm), speed 1 mm/s, std east/north 1 mm; in version 2
/// strength 2 % relative (50·ln(1 + s)), power 0.25 dB, trajectory time 100 µs, yaw and yaw
/// rate 10 µrad(/s), std yaw 10 µrad (version 1, still read: 0.5 % (200·ln(1 + s)), 0.05 dB,
/// 1 µs, 1 µrad(/s), 1 µrad).
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/schema/landmark.hpp"
#include "polmap/schema/recording.hpp"

namespace polmap::mapping {

/// What candidates.bin holds (drive-frame positions; trajectory in WGS84).
struct CandidatesContent {
  std::vector<PointCandidate> points;
  std::vector<LineCandidate> lines;
  std::vector<TrajectorySample> trajectory;
};

/// Caps checked before any memory is reserved.
struct CandidatesDecodeLimits {
  std::uint64_t max_points = 2'000'000;
  std::uint64_t max_lines = 500'000;
  std::uint64_t max_trajectory_samples = 10'000'000;
  /// Largest inflated body (bytes) and largest inflation ratio accepted.
  std::uint64_t max_body_bytes = 256u << 20;
  std::uint64_t max_inflation_ratio = 1032;  // zlib's own maximum
};

/// The version encode_candidates writes by default; decode_candidates reads 1 and 2.
inline constexpr std::uint32_t kCandidatesBinVersion = 2;

/// Encodes (deterministic: the same values give the same bytes). Values are rounded to
/// the quantization above; contract: finite values, |position| ≤ 1e5 km, version 1 or 2
/// (1: for tests and fuzz seeds of what older vehicles send).
[[nodiscard]] std::string encode_candidates(const CandidatesContent& content,
                                            std::uint32_t version = kCandidatesBinVersion);

/// Decodes; throws PackageFormatError naming candidates.bin and the field for anything
/// malformed (bad magic/version, truncated or trailing bytes, counts over the limits,
/// an inflated size that does not match, varints out of range, unknown enums).
[[nodiscard]] CandidatesContent decode_candidates(std::string_view bytes,
                                                  const CandidatesDecodeLimits& limits = {});

}  // namespace polmap::mapping
