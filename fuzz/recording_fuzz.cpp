// Fuzzer: the recording reader. Any file either throws FormatError (naming file and
// offset) or yields records, and never reads beyond the file or loops.
#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "fuzz_seeds.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/schema/recording_io.hpp"

using namespace polmap;

namespace {

std::filesystem::path scratch() {
  static const std::filesystem::path p = std::filesystem::temp_directory_path() /
                                         ("polmap-fuzz-recording-" + std::to_string(::getpid()));
  return p;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  if (const auto dir = fuzz::seed_dir(); !dir.empty()) {
    const auto path = scratch();
    {
      RecordingHeader h;
      h.drive_id = "fuzz";
      h.vehicle_id = "v";
      SensorMount m;
      m.sensor_id = 0;
      m.name = "front";
      h.sensors.push_back(m);
      h.side_slip_gradient_rad_per_mps2 = 0.004;  // the optional vehicle key, too
      RecordingWriter w(path, h);
      for (int i = 0; i < 3; ++i) {
        TrajectorySample t;
        t.time_s = 0.1 * i;
        t.lat_deg = 48.0;
        t.lon_deg = 9.0 + 1e-5 * i;
        w.write(t);
        SensorFrame f;
        f.cycle_index = static_cast<std::uint32_t>(i);
        f.time_s = 0.1 * i;
        Detection d;
        d.range_m = 10.0 + i;
        f.detections.push_back(d);
        w.write(f);
      }
      w.close();
    }
    std::ifstream in(path, std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    fuzz::write_seed(dir, "small.pmrec", bytes);
    std::filesystem::remove(path);
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto path = scratch();
  std::ofstream(path, std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  try {
    RecordingReader r(path);
    std::size_t n = 0;
    while (r.next()) {
      if (r.offset() > r.file_size() || ++n > size) std::abort();  // progress, inside the file
    }
  } catch (const FormatError&) {
  } catch (const ValidationError&) {
  }
  return 0;
}
