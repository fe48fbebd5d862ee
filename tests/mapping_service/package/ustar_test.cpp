// The ustar reader is strict: what it accepts is a plain archive of flat regular files
// that any other tar reader lists the same way.
#include "polmap/mapping_service/ustar.hpp"

#include <gtest/gtest.h>

#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "polmap/schema/errors.hpp"

namespace polmap::mapping {
namespace {

constexpr std::size_t kSizeOff = 124, kChksumOff = 148, kNameOff = 0;

std::string archive() { return write_ustar({{"a.json", "{}"}, {"b.bin", std::string(700, 'b')}}); }

/// Rewrites the header checksum of the header block at `off` after an edit.
void fix_checksum(std::string& tar, std::size_t off) {
  unsigned sum = 0;
  for (std::size_t i = 0; i < 512; ++i) {
    sum += (i >= kChksumOff && i < kChksumOff + 8) ? ' ' : static_cast<unsigned char>(tar[off + i]);
  }
  char buf[8];
  std::snprintf(buf, sizeof buf, "%06o", sum);
  std::memcpy(&tar[off + kChksumOff], buf, 7);
  tar[off + kChksumOff + 7] = ' ';
}

std::string error_of(const std::string& tar) {
  try {
    (void)read_ustar(tar, "x.tar");
  } catch (const FormatError& e) {
    return e.what();
  }
  return "accepted";
}

TEST(Ustar, RoundTripAndTrailingZeroPadding) {
  const std::string tar = archive();
  const auto m = read_ustar(tar, "x.tar");
  ASSERT_EQ(m.size(), 2U);
  EXPECT_EQ(m[0].name, "a.json");
  EXPECT_EQ(m[1].data, std::string(700, 'b'));
  // tar pads archives to its 10240-byte record with zeros: still the same archive.
  EXPECT_EQ(read_ustar(tar + std::string(10240, '\0'), "x.tar").size(), 2U);
}

TEST(Ustar, RejectsDataAfterTheEndMarker) {
  const std::string tar = archive() + std::string(512, '\0');
  std::string bad = tar;
  bad[bad.size() - 100] = 'x';
  EXPECT_NE(error_of(bad).find("after the end-of-archive marker"), std::string::npos)
      << error_of(bad);
  // A whole hidden member after the marker, too.
  const std::string hidden = archive() + write_ustar({{"evil.vrt", "<OGRVRTDataSource/>"}});
  EXPECT_NE(error_of(hidden).find("after the end-of-archive marker"), std::string::npos);
}

TEST(Ustar, NumericFieldsAreDigitsOnly) {
  std::string tar = archive();
  // size "00000000002" followed by garbage instead of NUL padding.
  tar[kSizeOff + 11] = 'x';
  fix_checksum(tar, 0);
  EXPECT_NE(error_of(tar).find("unreadable size field"), std::string::npos) << error_of(tar);
  tar = archive();
  tar[kSizeOff + 3] = '9';  // not octal
  fix_checksum(tar, 0);
  EXPECT_NE(error_of(tar).find("size"), std::string::npos) << error_of(tar);
}

TEST(Ustar, NumericFieldsEndWithATerminator) {
  // The second member's mode as eight digits, no NUL: the bytes shuffled so that the header
  // checksum still holds (found by the ustar fuzzer: GDAL's /vsitar/ stops listing at such a
  // header, so it would have seen one member where we saw two).
  constexpr std::size_t kModeOff = 100;
  const std::string good = archive();
  const std::size_t second = 1024;  // a.json's header and one data block before it
  std::string tar = good;
  ASSERT_EQ(tar.substr(second + kModeOff, 8), std::string("0000644\0", 8));
  std::memcpy(&tar[second + kModeOff], "00006440", 8);
  tar[second + 108 + 6] = '\0';  // uid "000000\0\0": the NUL the mode lost
  EXPECT_EQ(error_of(tar).find("unreadable mode field") != std::string::npos, true)
      << error_of(tar);
  EXPECT_EQ(read_ustar(good, "x.tar").size(), 2U);
}

TEST(Ustar, NamesAreFlatAndPrintable) {
  for (const std::string& name : std::vector<std::string>{"a\nb", "dir/file", "..", "a\x7f"}) {
    std::string tar = archive();
    std::memset(&tar[kNameOff], 0, 100);
    std::memcpy(&tar[kNameOff], name.data(), name.size());
    fix_checksum(tar, 0);
    EXPECT_NE(error_of(tar).find("flat, printable"), std::string::npos) << name << error_of(tar);
  }
}

}  // namespace
}  // namespace polmap::mapping
