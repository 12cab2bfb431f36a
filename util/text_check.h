// Free text that people read: a promotion's reason (the audit log), a token's label, a capture's
// source name, a device's sensor model. These reach terminals (imucal's tables, journalctl, a
// psql prompt), so they must not carry what a terminal acts on or a reader mistakes for a line
// break: the C0 controls (U+0000-U+001F: ESC starts a terminal escape), DEL (U+007F), and the C1
// controls (U+0080-U+009F: U+009B is CSI, as ESC [ is, to terminals that honour C1; U+0085 is a
// line break to many readers). Nor bytes that are not UTF-8: a lone 0x9B or 0x85 byte is the
// same C1 control to a reader in Latin-1, and protobuf and PostgreSQL refuse such text anyway.
#ifndef IMUCAL_UTIL_TEXT_CHECK_H_
#define IMUCAL_UTIL_TEXT_CHECK_H_

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace imucal {

struct UnreadableChar {
  size_t byte = 0;   // 1-based position of the character's first byte in the text
  std::string what;  // "a control character", "a byte that is not UTF-8"
  std::string code;  // "U+0085" (a control character), "0xFF" (the byte)

  // "<field>: a control character at byte 9 (U+0085)": for an InvalidArgument naming the field.
  std::string Message(std::string_view field) const {
    return std::string(field) + ": " + what + " at byte " + std::to_string(byte) + " (" + code +
           ")";
  }
};

namespace text_check_internal {

inline std::string Hex(uint32_t value, int digits) {
  static constexpr char kDigits[] = "0123456789ABCDEF";
  std::string out(static_cast<size_t>(digits), '0');
  for (int i = digits - 1; i >= 0; --i, value >>= 4)
    out[static_cast<size_t>(i)] = kDigits[value & 0xF];
  return out;
}

inline UnreadableChar Control(size_t at, uint32_t code_point) {
  return {at + 1, "a control character", "U+" + Hex(code_point, 4)};
}

inline UnreadableChar NotUtf8(size_t at, unsigned char byte) {
  return {at + 1, "a byte that is not UTF-8", "0x" + Hex(byte, 2)};
}

}  // namespace text_check_internal

// The first character of `text` that is not readable text: a C0 control other than those in
// `allowed_c0` (e.g. "\t\n" for a paragraph), DEL, a C1 control, or a byte that does not belong
// to a well-formed UTF-8 sequence (overlong forms, UTF-16 surrogates and code points beyond
// U+10FFFF included). nullopt when the whole text is readable.
inline std::optional<UnreadableChar> FindUnreadableChar(std::string_view text,
                                                        std::string_view allowed_c0 = {}) {
  using text_check_internal::Control;
  using text_check_internal::NotUtf8;
  for (size_t i = 0; i < text.size();) {
    const auto lead = static_cast<unsigned char>(text[i]);
    if (lead < 0x80) {
      if ((lead < 0x20 && allowed_c0.find(static_cast<char>(lead)) == std::string_view::npos) ||
          lead == 0x7F)
        return Control(i, lead);
      ++i;
      continue;
    }
    // The sequence's length, the lead byte's payload, and the least code point of that length
    // (a smaller one is an overlong form). RFC 3629: leads C0, C1 and F5-FF never occur.
    size_t length = 0;
    uint32_t code_point = 0, least = 0;
    if (lead >= 0xC2 && lead <= 0xDF) {
      length = 2, code_point = lead & 0x1Fu, least = 0x80;
    } else if (lead >= 0xE0 && lead <= 0xEF) {
      length = 3, code_point = lead & 0x0Fu, least = 0x800;
    } else if (lead >= 0xF0 && lead <= 0xF4) {
      length = 4, code_point = lead & 0x07u, least = 0x10000;
    } else {
      return NotUtf8(i, lead);
    }
    if (i + length > text.size()) return NotUtf8(i, lead);
    for (size_t k = 1; k < length; ++k) {
      const auto next = static_cast<unsigned char>(text[i + k]);
      if ((next & 0xC0u) != 0x80u) return NotUtf8(i, lead);
      code_point = (code_point << 6) | (next & 0x3Fu);
    }
    if (code_point < least || code_point > 0x10FFFF ||
        (code_point >= 0xD800 && code_point <= 0xDFFF))
      return NotUtf8(i, lead);
    if (code_point <= 0x9F) return Control(i, code_point);  // C1: U+0080-U+009F
    i += length;
  }
  return std::nullopt;
}

}  // namespace imucal

#endif  // IMUCAL_UTIL_TEXT_CHECK_H_
