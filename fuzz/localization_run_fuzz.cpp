// Fuzzer: the localization run report parser (schema/localization_run.hpp; what a vehicle
// posts to /v1/runs). Any input either is refused with a field, a message and a 400/413/422
// status, or parses to a run within the documented bounds whose canonical encoding parses
// to the same encoding (the server stores and serves that copy).
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "fuzz_seeds.hpp"
#include "polmap/schema/localization_run.hpp"

using namespace polmap;

#define FUZZ_CHECK(cond)                                                            \
  do {                                                                              \
    if (!(cond)) {                                                                  \
      std::fprintf(stderr, "fuzz_localization_run: invariant failed: %s\n", #cond); \
      std::abort();                                                                 \
    }                                                                               \
  } while (0)

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  if (const auto dir = fuzz::seed_dir(); !dir.empty()) {
    LocalizationRun r;
    r.label = "drive_1";
    r.map_version = 3;
    r.reference = RunReference::SimulatorTruth;
    r.realtime_factor = 9.5;
    for (int i = 0; i < 4; ++i) {
      LocalizationRunSample s;
      s.t_s = 1.0 + 0.2 * i;
      s.lat_deg = 48.4 + 1e-5 * i;
      s.lon_deg = 9.99;
      s.yaw_enu_deg = 90.0;
      s.status = i == 0 ? RunStatus::Initializing : RunStatus::Tracking;
      s.cov_xx_m2 = 0.01;
      s.cov_yy_m2 = 0.02;
      s.cov_xy_m2 = 0.001;
      s.cov_yaw_rad2 = 1e-4;
      if (i > 0) s.error = RunSampleError{0.02, -0.01, 0.1};
      r.samples.push_back(s);
    }
    fuzz::write_seed(dir, "run.json", encode_localization_run(r));
    r.reference = RunReference::None;
    for (auto& s : r.samples) s.error.reset();
    r.label.clear();
    fuzz::write_seed(dir, "run_plain.json", encode_localization_run(r));
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  LocalizationRunLimits lim;
  lim.max_samples = 1000;
  const auto r = parse_localization_run(bytes, lim);
  if (!r) {
    const auto& e = r.error();
    FUZZ_CHECK(!e.field.empty() && !e.message.empty());
    FUZZ_CHECK(e.http_status == 400 || e.http_status == 413 || e.http_status == 422);
    return 0;
  }
  FUZZ_CHECK(r->samples.size() >= 2 && r->samples.size() <= lim.max_samples);
  FUZZ_CHECK(r->label.size() <= LocalizationRunLimits::kMaxLabelBytes);
  for (std::size_t i = 0; i < r->samples.size(); ++i) {
    const auto& s = r->samples[i];
    FUZZ_CHECK(std::isfinite(s.t_s) && std::abs(s.lat_deg) <= 85.0 && std::abs(s.lon_deg) <= 180.0);
    FUZZ_CHECK(s.yaw_enu_deg > -180.0 && s.yaw_enu_deg <= 180.0);
    FUZZ_CHECK(s.cov_xx_m2 >= 0 && s.cov_yy_m2 >= 0 && s.cov_yaw_rad2 >= 0);
    if (i > 0) FUZZ_CHECK(s.t_s > r->samples[i - 1].t_s);
  }
  const std::string canonical = encode_localization_run(*r);
  const auto again = parse_localization_run(canonical, lim);
  FUZZ_CHECK(again.has_value());
  FUZZ_CHECK(encode_localization_run(*again) == canonical);
  return 0;
}
