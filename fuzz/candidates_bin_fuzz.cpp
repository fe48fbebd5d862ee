// Fuzzer: the candidates.bin decoder (package format 2). Any input either throws
// PackageFormatError naming candidates.bin or decodes to bounded counts and finite
// values; an accepted input is a fixed point of the quantization (decoding what encoding
// the decoded values gives returns the same values, byte for byte once re-encoded).
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "fuzz_seeds.hpp"
#include "polmap/mapping_service/candidates_codec.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"

using namespace polmap;
using namespace polmap::mapping;

#define FUZZ_CHECK(cond)                                                          \
  do {                                                                            \
    if (!(cond)) {                                                                \
      std::fprintf(stderr, "fuzz_candidates_bin: invariant failed: %s\n", #cond); \
      std::abort();                                                               \
    }                                                                             \
  } while (0)

namespace {
CandidatesDecodeLimits limits() {
  CandidatesDecodeLimits l;  // small caps keep one input cheap
  l.max_points = 100'000;
  l.max_lines = 100'000;
  l.max_trajectory_samples = 100'000;
  l.max_body_bytes = 8u << 20;
  return l;
}
}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  if (const auto dir = fuzz::seed_dir(); !dir.empty()) {
    CandidatesContent c;
    for (int i = 0; i < 5; ++i) {
      PointCandidate p;
      p.position_m = {1.5 * i, -2.0 * i};
      p.strength = 3.0 + i;
      p.power_db = 20.0 + i;
      p.num_cells = 3;
      c.points.push_back(p);
      LineCandidate l;
      l.start_m = {i * 1.0, 2.0};
      l.end_m = {i * 1.0 + 3.0, 2.5};
      l.strength = 2.0;
      c.lines.push_back(l);
      TrajectorySample s;
      s.time_s = 10.0 + i;
      s.lat_deg = 48.8;
      s.lon_deg = 9.2 + 1e-5 * i;
      s.speed_mps = 8.0;
      c.trajectory.push_back(s);
    }
    fuzz::write_seed(dir, "small.bin", encode_candidates(c));
    fuzz::write_seed(dir, "empty.bin", encode_candidates({}));
    fuzz::write_seed(dir, "small_v1.bin", encode_candidates(c, 1));  // older vehicles' files
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  const CandidatesDecodeLimits lim = limits();
  CandidatesContent c;
  try {
    c = decode_candidates(bytes, lim);
  } catch (const PackageFormatError& e) {
    FUZZ_CHECK(e.error().file == "candidates.bin" && !e.error().message.empty());
    return 0;
  }
  FUZZ_CHECK(c.points.size() <= lim.max_points && c.lines.size() <= lim.max_lines &&
             c.trajectory.size() <= lim.max_trajectory_samples);
  for (const auto& p : c.points) {
    FUZZ_CHECK(std::isfinite(p.position_m.x()) && std::isfinite(p.position_m.y()));
    FUZZ_CHECK(std::isfinite(p.strength) && p.strength >= 0.0 && std::isfinite(p.power_db));
    FUZZ_CHECK(static_cast<int>(p.scattering) <= 3);
  }
  for (const auto& s : c.trajectory) {
    FUZZ_CHECK(std::isfinite(s.time_s) && std::isfinite(s.lat_deg) && std::isfinite(s.lon_deg));
    FUZZ_CHECK(s.std_east_m >= 0.0F && s.std_north_m >= 0.0F && s.std_yaw_rad >= 0.0F);
    FUZZ_CHECK(static_cast<int>(s.solution) <= 2);
  }
  // Re-encoding what was decoded reproduces the same values (the quantization's fixed point).
  const std::string again = encode_candidates(c);
  FUZZ_CHECK(encode_candidates(decode_candidates(again, lim)) == again);
  return 0;
}
