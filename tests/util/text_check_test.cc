// util/text_check.h: which characters free text may not carry, and where they are named.
#include "util/text_check.h"

#include <string>

#include "gtest/gtest.h"

namespace imucal {
namespace {

std::string Found(std::string_view text, std::string_view allowed_c0 = {}) {
  const std::optional<UnreadableChar> u = FindUnreadableChar(text, allowed_c0);
  return u ? u->Message("text") : "none";
}

TEST(TextCheckTest, ReadableTextPasses) {
  EXPECT_EQ(Found(""), "none");
  EXPECT_EQ(Found("line 3 laptop ~!@#$%^&*()"), "none");
  EXPECT_EQ(Found("Kalibrierung für Gerät ß, 校准, 🤖"), "none");
  EXPECT_EQ(Found("\u00a0no-break space, U+00A0: the first after C1"), "none");
  EXPECT_EQ(Found("\U0010FFFF"), "none");  // the last code point
  EXPECT_EQ(Found("tab\tand\nnewline", "\t\n"), "none");
}

TEST(TextCheckTest, C0ControlsAndDelAreNamedWithTheirByte) {
  EXPECT_EQ(Found(std::string("ab\0c", 4)), "text: a control character at byte 3 (U+0000)");
  EXPECT_EQ(Found("x\x1b[31mred"), "text: a control character at byte 2 (U+001B)");
  EXPECT_EQ(Found("tab\there"), "text: a control character at byte 4 (U+0009)");
  EXPECT_EQ(Found("a\rb", "\t\n"), "text: a control character at byte 2 (U+000D)");
  EXPECT_EQ(Found("del\x7f"), "text: a control character at byte 4 (U+007F)");
}

// U+0080-U+009F, encoded as UTF-8 (C2 80 - C2 9F): the U+0085 (NEL) among them.
TEST(TextCheckTest, C1ControlsAreRefusedLikeC0) {
  EXPECT_EQ(Found("ok\u0085then"), "text: a control character at byte 3 (U+0085)");
  EXPECT_EQ(Found("\u009b31m"), "text: a control character at byte 1 (U+009B)");
  EXPECT_EQ(Found("é\u0080"), "text: a control character at byte 3 (U+0080)");
  EXPECT_EQ(Found("\u009f"), "text: a control character at byte 1 (U+009F)");
  EXPECT_EQ(Found("\u0085", "\t\n"), "text: a control character at byte 1 (U+0085)");
}

TEST(TextCheckTest, BytesThatAreNotUtf8AreRefused) {
  EXPECT_EQ(Found("a\x85"), "text: a byte that is not UTF-8 at byte 2 (0x85)");  // C1 in Latin-1
  EXPECT_EQ(Found("\x9b"
                  "31m"),
            "text: a byte that is not UTF-8 at byte 1 (0x9B)");
  EXPECT_EQ(Found("\xc0\x80"), "text: a byte that is not UTF-8 at byte 1 (0xC0)");  // overlong NUL
  EXPECT_EQ(Found("\xe0\x80\xaf"), "text: a byte that is not UTF-8 at byte 1 (0xE0)");  // overlong
  EXPECT_EQ(Found("\xed\xa0\x80"), "text: a byte that is not UTF-8 at byte 1 (0xED)");  // surrogate
  EXPECT_EQ(Found("\xf4\x90\x80\x80"), "text: a byte that is not UTF-8 at byte 1 (0xF4)");
  EXPECT_EQ(Found("ab\xc3"), "text: a byte that is not UTF-8 at byte 3 (0xC3)");  // cut short
  EXPECT_EQ(Found("\xc3(x"), "text: a byte that is not UTF-8 at byte 1 (0xC3)");
  EXPECT_EQ(Found("\xff"), "text: a byte that is not UTF-8 at byte 1 (0xFF)");
}

}  // namespace
}  // namespace imucal
