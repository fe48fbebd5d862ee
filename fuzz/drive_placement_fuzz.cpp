// Fuzzer: the stored placement of a drive's gridmap in the merged gridmap sums
// (drive_placement.hpp; text the store keeps with each sum input, the builder's own, but a
// store file can be damaged or planted). Any input either throws ValidationError naming the
// source or decodes to a placement with finite values whose text re-encodes to a fixed point
// and whose warp gives finite positions.
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "fuzz_seeds.hpp"
#include "polmap/mapping_service/drive_placement.hpp"
#include "polmap/schema/errors.hpp"

using namespace polmap;
using namespace polmap::mapping;

#define FUZZ_CHECK(cond)                                                           \
  do {                                                                             \
    if (!(cond)) {                                                                 \
      std::fprintf(stderr, "fuzz_drive_placement: invariant failed: %s\n", #cond); \
      std::abort();                                                                \
    }                                                                              \
  } while (0)

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  if (const auto dir = fuzz::seed_dir(); !dir.empty()) {
    DriveCorrection c;
    for (int k = 0; k <= 6; ++k) {
      c.node_s_m.push_back(10.0 * k);
      c.node_position_m.emplace_back(10.0 * k, 0.5 * k);
      c.node_correction.emplace_back(0.3, -0.2 + 0.05 * k, 0.001 * k);
    }
    for (int i = 0; i <= 60; ++i) {
      c.path_s_m.push_back(i);
      c.path_m.emplace_back(i, 0.05 * i);
    }
    c.candidate_lead_m = -10.0;
    fuzz::write_seed(dir, "placement.json",
                     encode_drive_placement(
                         drive_placement(tiles::LocalFrame(GeoPoint{48.7758, 9.1829, 250.0}), c)));
    fuzz::write_seed(dir, "empty.json", "");
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  DrivePlacement p;
  try {
    p = decode_drive_placement(text, "fuzz placement");
  } catch (const ValidationError& e) {
    FUZZ_CHECK(std::string_view(e.what()).find("fuzz placement") != std::string_view::npos);
    return 0;
  }
  if (p.as_uploaded()) return 0;
  const std::string again = encode_drive_placement(p);
  FUZZ_CHECK(encode_drive_placement(decode_drive_placement(again, "again")) == again);
  // The warp is evaluated at a few points when the frame is a usable one.
  if (std::abs(p.frame_origin->lat_deg) < 80.0 && std::abs(p.frame_origin->alt_m) < 1e5 &&
      p.correction.path_m.size() <= 4096) {
    bool small = true;
    for (const auto& n : p.correction.node_correction)
      small = small && n.cwiseAbs().maxCoeff() < 1e4;
    for (const auto& q : p.correction.path_m) small = small && q.cwiseAbs().maxCoeff() < 1e5;
    if (small) {
      const tiles::LocalFrame drive(*p.frame_origin);
      const GridmapWarp warp = placement_warp(p, drive);
      for (const Eigen::Vector2d xy : {Eigen::Vector2d(0.0, 0.0), Eigen::Vector2d(25.0, -40.0)}) {
        const Eigen::Vector2d w = warp(xy);
        FUZZ_CHECK(std::isfinite(w.x()) && std::isfinite(w.y()));
      }
    }
  }
  return 0;
}
