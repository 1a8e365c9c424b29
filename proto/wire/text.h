// Untrusted text on its way into a status message or a log line: bounded and
// escaped, so a megabyte id cannot overflow gRPC's metadata limit or the log,
// and a newline or terminal escape in a client name cannot forge a log line.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>

namespace hapticpd::wire {

/// Default length kept by Printable (bytes of the original text).
inline constexpr std::size_t kMaxEchoedText = 64;

/// `s` with control characters, backslash and bytes >= 0x7f escaped
/// (\n, \t, \r, \\, \xHH), cut after `max` bytes of the original with
/// "...(N bytes)" appended when longer. Never longer than 4 * max + 32.
std::string Printable(std::string_view s, std::size_t max = kMaxEchoedText);

/// Status messages and log lines assembled from several parts are cut here
/// as a last line of defence (bytes); gRPC clients refuse trailers over 8 KiB.
inline constexpr std::size_t kMaxStatusMessage = 1024;
/// `msg` cut to kMaxStatusMessage bytes (with "...(N bytes)"); control
/// characters escaped.
std::string BoundedMessage(std::string_view msg);

}  // namespace hapticpd::wire
