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
TEST(EscapeForLog, KeepsPrintableAsciiAndEscapesEveryOtherByte) {
  EXPECT_EQ(escape_for_log("GET /tiles/1/2/3"), "GET /tiles/1/2/3");
  EXPECT_EQ(escape_for_log("a\r\nb\\c"), "a\\x0d\\x0ab\\x5cc");
  EXPECT_EQ(escape_for_log(std::string("\x00\x7f\xff", 3)), "\\x00\\x7f\\xff");
  // Every byte value: the result is one printable line, and unescaping gives the input.
  std::string all;
  for (int c = 0; c < 256; ++c) all.push_back(static_cast<char>(c));
  const std::string e = escape_for_log(all);
  std::string back;
  for (std::size_t i = 0; i < e.size(); ++i) {
    const auto c = static_cast<unsigned char>(e[i]);
    ASSERT_TRUE(c >= 0x20 && c < 0x7f) << i;
    if (e[i] == '\\') {
      back.push_back(static_cast<char>(std::stoi(e.substr(i + 2, 2), nullptr, 16)));
      i += 3;
    } else {
      back.push_back(e[i]);
    }
  }
  EXPECT_EQ(back, all);
}

TEST(EscapeForLog, CutsAtTheByteLimit) {
  EXPECT_EQ(escape_for_log(std::string(100, 'a'), 10), std::string(10, 'a') + "...");
  EXPECT_EQ(escape_for_log(std::string(10, 'a'), 10), std::string(10, 'a'));
}

}  // namespace polmap::util
