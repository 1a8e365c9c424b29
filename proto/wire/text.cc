#include "proto/wire/text.h"

#include <cstdio>

namespace hapticpd::wire {
namespace {

void Escape(std::string_view s, std::string* out) {
  for (const char ch : s) {
    const auto c = static_cast<unsigned char>(ch);
    switch (c) {
      case '\n':
        *out += "\\n";
        break;
      case '\r':
        *out += "\\r";
        break;
      case '\t':
        *out += "\\t";
        break;
      case '\\':
        *out += "\\\\";
        break;
      default:
        if (c < 0x20 || c >= 0x7f) {
          char buf[5];
          std::snprintf(buf, sizeof buf, "\\x%02x", c);
          *out += buf;
        } else {
          *out += ch;
        }
    }
  }
}

}  // namespace

std::string Printable(std::string_view s, std::size_t max) {
  std::string out;
  out.reserve(std::min(s.size(), max) + 16);
  Escape(s.substr(0, max), &out);
  if (s.size() > max) out += "...(" + std::to_string(s.size()) + " bytes)";
  return out;
}

std::string BoundedMessage(std::string_view msg) {
  // Escaping may grow the text 4x: cut the input first, then the output.
  std::string out = Printable(msg, kMaxStatusMessage);
  if (out.size() > 4 * kMaxStatusMessage + 32) out.resize(4 * kMaxStatusMessage + 32);
  return out;
}

}  // namespace hapticpd::wire
