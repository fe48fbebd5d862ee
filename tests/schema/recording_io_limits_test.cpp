// Recording reader: a record header's claimed lengths are checked against the file and
// deflate's expansion bound before memory is reserved for them (found by the recording
// fuzzer: a 38-byte file made the reader reserve ~1 GiB). The binary tracks its largest
// single allocation (tests/support/largest_allocation.hpp).
#include <gtest/gtest.h>
#include <unistd.h>
#include <zlib.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "polmap/schema/errors.hpp"
#include "polmap/schema/recording_io.hpp"
#include "support/largest_allocation.hpp"

namespace polmap {
namespace {

namespace fs = std::filesystem;

fs::path temp_file(const std::string& name) {
  std::string leaf = "polmap-recording-limits-";  // appended: GCC 12 -Wrestrict on a + b + c
  leaf += std::to_string(::getpid());
  leaf += '-';
  leaf += name;
  const fs::path dir = fs::temp_directory_path() / leaf;
  fs::create_directories(dir);
  return dir / "r.pmrec";
}

/// The first record's 20-byte header (after the 16-byte preamble) of a small valid
/// recording, rewritten with the given lengths and encoding, its header CRC recomputed.
std::vector<unsigned char> with_first_record(std::uint32_t stored_len, std::uint32_t raw_len,
                                             std::uint8_t enc, const fs::path& path) {
  {
    RecordingHeader h;
    h.drive_id = "drive_0";
    h.vehicle_id = "test-vehicle";
    h.sensors = default_front_mounts();
    RecordingWriter w(path, h);
    w.close();
  }
  std::ifstream in(path, std::ios::binary);
  std::vector<unsigned char> b((std::istreambuf_iterator<char>(in)),
                               std::istreambuf_iterator<char>());
  EXPECT_GT(b.size(), 36U);
  unsigned char* h = b.data() + 16;
  h[1] = enc;
  for (int i = 0; i < 4; ++i) {
    h[4 + i] = static_cast<unsigned char>(stored_len >> (8 * i));
    h[8 + i] = static_cast<unsigned char>(raw_len >> (8 * i));
  }
  const auto crc = static_cast<std::uint32_t>(crc32(crc32(0L, Z_NULL, 0), h, 16));
  for (int i = 0; i < 4; ++i) h[16 + i] = static_cast<unsigned char>(crc >> (8 * i));
  std::ofstream(path, std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
  return b;
}

/// Reads the file to its end; returns the FormatError message and the largest allocation.
std::pair<std::string, std::size_t> read(const fs::path& path) {
  test::reset_largest_allocation();
  std::string msg;
  try {
    RecordingReader r(path);
    while (r.next()) {
    }
  } catch (const FormatError& e) {
    msg = e.what();
  }
  return {msg, test::largest_allocation()};
}

TEST(RecordingIoLimits, PayloadLongerThanTheFileIsRejectedBeforeItIsReserved) {
  const fs::path path = temp_file("stored");
  with_first_record(512u << 20, 512u << 20, 0, path);  // raw, 512 MiB claimed
  const auto [msg, largest] = read(path);
  EXPECT_NE(msg.find("file truncated: record payload needs 536870912 bytes"), std::string::npos)
      << msg;
  EXPECT_NE(msg.find(path.string()), std::string::npos) << msg;
  EXPECT_LT(largest, 1U << 20) << msg;
  fs::remove_all(path.parent_path());
}

TEST(RecordingIoLimits, ZlibLengthBeyondDeflatesBoundIsRejectedBeforeItIsReserved) {
  const fs::path path = temp_file("zlib");
  // 8 stored bytes cannot inflate to 256 MiB; the stored bytes do exist in the file.
  with_first_record(8, 256u << 20, 1, path);
  const auto [msg, largest] = read(path);
  EXPECT_NE(msg.find("zlib payload of 8 bytes cannot expand to 268435456 bytes"), std::string::npos)
      << msg;
  EXPECT_LT(largest, 1U << 20) << msg;
  fs::remove_all(path.parent_path());
}

TEST(RecordingIoLimits, LengthsWithinTheBoundsStillReadToTheirOwnErrors) {
  // A plausible zlib length (within 1032:1 of what is stored) passes the length checks and
  // fails at the payload checksum (the header's CRC is the original payload's): the bound
  // does not reject what deflate could have produced.
  const fs::path path = temp_file("plausible");
  with_first_record(8, 8 * 1000, 1, path);
  const auto [msg, largest] = read(path);
  EXPECT_NE(msg.find("checksum mismatch"), std::string::npos) << msg;
  EXPECT_LT(largest, 1U << 20) << msg;
  fs::remove_all(path.parent_path());
}

}  // namespace
}  // namespace polmap
