#include "polmap/util/text.hpp"

#include <gtest/gtest.h>

#include <cctype>
#include <string>

namespace polmap::util {
namespace {

TEST(Trim, StripsAsciiWhitespaceOnBothEndsOnly) {
  EXPECT_EQ(trim("  a b \t\r\n"), "a b");
  EXPECT_EQ(trim("\v\fkey\f"), "key");
  EXPECT_EQ(trim(""), "");
  EXPECT_EQ(trim(" \t "), "");
  EXPECT_EQ(trim("x"), "x");
}

TEST(Trim, AgreesWithCLocaleIsspaceForEveryByte) {
  for (int c = 0; c < 256; ++c) {
    const char ch = static_cast<char>(c);
    EXPECT_EQ(is_ascii_space(ch), std::isspace(c) != 0) << c;
  }
}

TEST(SplitTrimmed, KeepsEmptyFieldsAndTrimsEach) {
  const auto f = split_trimmed(" a , b,,c ,", ',');
  ASSERT_EQ(f.size(), 5U);
  EXPECT_EQ(f[0], "a");
  EXPECT_EQ(f[1], "b");
  EXPECT_EQ(f[2], "");
  EXPECT_EQ(f[3], "c");
  EXPECT_EQ(f[4], "");
  EXPECT_EQ(split_trimmed("", ',').size(), 1U);
}

TEST(IsLowerHex, AcceptsOnlyLowerCaseHexDigits) {
  EXPECT_TRUE(is_lower_hex("0123456789abcdef"));
  EXPECT_FALSE(is_lower_hex(""));
  EXPECT_FALSE(is_lower_hex("ABCDEF"));
  EXPECT_FALSE(is_lower_hex("12g4"));
  EXPECT_FALSE(is_lower_hex("12 4"));
}

}  // namespace
}  // namespace polmap::util
